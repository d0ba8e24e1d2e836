"""Type stubs of nlsim's compiled module (python/src). Shapes are noted as (axis, ...);
frequencies in Hz, times in s, forces in N, responses in the sensor's quantity."""

import os
from typing import Any, Dict, List, Mapping, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

__version__: str

class Error(Exception):
    """Base class of every error nlsim raises."""

class InputError(Error):
    """What was passed in is unusable; the message names the argument."""

class FileError(Error):
    """A file could not be read or written; the message names the file, line and key."""

class ComputationError(Error):
    """A numerical failure on valid input."""

class Model:
    """Mass, stiffness and damping, nonlinear elements, excitation points and sensors."""

    @staticmethod
    def load(spec: str) -> Model: ...
    @staticmethod
    def from_csr(
        name: str,
        n: int,
        m_indptr: npt.NDArray[Any],
        m_indices: npt.NDArray[Any],
        m_data: npt.NDArray[np.float64],
        k_indptr: npt.NDArray[Any],
        k_indices: npt.NDArray[Any],
        k_data: npt.NDArray[np.float64],
        dofs: Optional[Sequence[str]] = None,
    ) -> Model: ...
    @staticmethod
    def from_matrices(
        M: Any, K: Any, dofs: Optional[Sequence[str]] = None, name: str = "model"
    ) -> Model: ...
    def set_rayleigh(self, alpha: float, beta: float) -> None: ...
    def set_modal_damping(self, zeta: float) -> None: ...
    def add_element(self, name: str, law: str, dof: str, dof2: Optional[str] = None) -> None: ...
    def add_excitation(self, name: str, dof: str, amplitude: float) -> None: ...
    def add_sensor(self, name: str, dof: str, quantity: str = "displacement") -> None: ...
    @property
    def name(self) -> str: ...
    @property
    def source(self) -> str: ...
    @property
    def n_dofs(self) -> int: ...
    @property
    def dofs(self) -> List[str]: ...
    @property
    def elements(self) -> List[str]: ...
    @property
    def excitations(self) -> List[str]: ...
    @property
    def sensors(self) -> List[str]: ...
    @property
    def parameters(self) -> List[str]: ...
    def get(self, name: str) -> float: ...
    def set(self, name: str, value: float) -> None: ...
    def copy(self) -> Model: ...

class Modes:
    """Modes as `nlsim modes` computes them."""

    @property
    def frequency_hz(self) -> npt.NDArray[np.float64]:
        """(mode,)"""
    @property
    def eigenvalues(self) -> npt.NDArray[np.float64]:
        """(mode,) in rad^2/s^2"""
    @property
    def damping_ratio(self) -> npt.NDArray[np.float64]:
        """(mode,)"""
    @property
    def shapes(self) -> npt.NDArray[np.float64]:
        """(dof, mode), mass-normalised (1/sqrt(kg))"""
    @property
    def residual(self) -> npt.NDArray[np.float64]:
        """(mode,)"""
    @property
    def effective_mass(self) -> Dict[str, npt.NDArray[np.float64]]:
        """direction -> (mode,) in kg"""
    @property
    def dofs(self) -> List[str]: ...
    def __len__(self) -> int: ...
    def to_dataframe(self) -> Any: ...

class Reduced:
    """A reduced model: retained modes with residual flexibility at the ports."""

    @property
    def frequency_hz(self) -> npt.NDArray[np.float64]:
        """(mode,)"""
    @property
    def shapes(self) -> npt.NDArray[np.float64]:
        """(dof, mode)"""
    @property
    def n_modes(self) -> int: ...
    @property
    def residual_flexibility(self) -> bool: ...
    @property
    def model(self) -> Model: ...

class History:
    """A time history, time first."""

    @property
    def time(self) -> npt.NDArray[np.float64]:
        """(sample,) in s"""
    @property
    def outputs(self) -> npt.NDArray[np.float64]:
        """(sample, sensor)"""
    @property
    def sensors(self) -> List[str]: ...
    @property
    def forces(self) -> npt.NDArray[np.float64]:
        """(sample, excitation point) in N"""
    @property
    def element_forces(self) -> npt.NDArray[np.float64]:
        """(sample, element) in N"""
    @property
    def elements(self) -> List[str]: ...
    @property
    def excitation(self) -> List[str]: ...
    @property
    def modes(self) -> int: ...
    @property
    def status(self) -> str: ...
    @property
    def detail(self) -> Optional[str]: ...
    @property
    def dt(self) -> float: ...
    def to_dataframe(self) -> Any: ...

class Frf:
    """A frequency response by harmonic balance, points in order along the branch."""

    @property
    def frequency_hz(self) -> npt.NDArray[np.float64]:
        """(point,)"""
    @property
    def level(self) -> npt.NDArray[np.float64]:
        """(point,)"""
    @property
    def response(self) -> npt.NDArray[np.complex128]:
        """(point, sensor, harmonic), cosine convention"""
    @property
    def harmonics(self) -> npt.NDArray[np.float64]:
        """(harmonic,) as multiples of the fundamental"""
    @property
    def stable(self) -> npt.NDArray[np.int8]:
        """(point,): 1 stable, 0 unstable, -1 not computed"""
    @property
    def kind(self) -> List[str]: ...
    @property
    def folds(self) -> List[int]: ...
    @property
    def bifurcations(self) -> List[Tuple[str, float, int, int]]: ...
    @property
    def sensors(self) -> List[str]: ...
    @property
    def status(self) -> str: ...
    @property
    def detail(self) -> str: ...
    def __len__(self) -> int: ...
    def to_dataframe(self) -> Any: ...

class Calibration:
    """Parameters fitted to a stepped-sine test, per parameter in the order of `params`."""

    @property
    def params(self) -> List[str]: ...
    @property
    def fe_stats(self) -> Optional[Dict[str, Any]]:
        """fe_reduction, basis_size, setup_reductions, evaluations, refreshes, full_reductions,
        full_seconds; None without FE-level parameters"""
    @property
    def estimate(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def status(self) -> str: ...
    @property
    def cost(self) -> float: ...
    @property
    def reduced_chi2(self) -> float: ...
    @property
    def cramer_rao_std(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def chi2_scaled_std(self) -> npt.NDArray[np.float64]:
        """(param,): cramer_rao_std * sqrt(reduced_chi2)"""
    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """(param, param)"""
    @property
    def at_bound(self) -> List[bool]: ...
    @property
    def poorly_identified(self) -> List[bool]: ...
    @property
    def kfold_mean(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def kfold_std(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def jackknife_std(self) -> Optional[npt.NDArray[np.float64]]: ...
    @property
    def candidates(self) -> npt.NDArray[np.float64]:
        """(candidate, param)"""
    @property
    def candidate_cost(self) -> npt.NDArray[np.float64]:
        """(candidate,)"""
    def to_dataframe(self) -> Any: ...

def calibrate(
    model: Model,
    data: Union[str, "os.PathLike[str]", TestData],
    params: Mapping[str, Tuple[float, float]],
    compare: Sequence[int] = ...,
    form: str = "complex",
    branch: str = "nearest",
    harmonics: int = 3,
    modes: int = 20,
    uff_noise: float = 0.01,
    lhs: int = 64,
    seed: int = 1,
    starts: int = 3,
    folds: int = 10,
    fe_reduction: str = "parametric",
    fe_tolerance: Optional[float] = None,
    gains: Optional[Mapping[str, float]] = None,
    shaker: Union[None, bool, Mapping[str, float]] = None,
    threads: Optional[int] = None,
    resume: Optional[PartialCalibration] = None,
) -> Calibration: ...

class PartialCalibration:
    """What a calibration stopped by Ctrl-C had completed (KeyboardInterrupt's args[1])."""

    @property
    def params(self) -> List[str]: ...
    @property
    def candidates(self) -> npt.NDArray[np.float64]:
        """(candidate, param)"""
    @property
    def candidate_cost(self) -> npt.NDArray[np.float64]:
        """(candidate,); NaN where not evaluated"""
    @property
    def evaluated(self) -> int: ...
    @property
    def phase(self) -> str: ...
    @property
    def optimisations(self) -> int: ...
    @property
    def best(self) -> Optional[npt.NDArray[np.float64]]:
        """(param,)"""
    @property
    def best_cost(self) -> Optional[float]: ...
def modes(
    model: Model,
    count: Optional[int] = None,
    fmax_hz: Optional[float] = None,
    threads: Optional[int] = None,
) -> Modes: ...
def reduce(
    model: Model,
    modes: int = 20,
    residual_flexibility: bool = True,
    threads: Optional[int] = None,
) -> Reduced: ...
def simulate(
    model: Union[Model, Reduced],
    duration: float,
    rate_hz: float,
    excitation: Optional[Mapping[str, Union[str, npt.NDArray[np.float64]]]] = None,
    method: str = "foh",
    modes: int = 20,
    residual_flexibility: bool = True,
    locate_events: bool = True,
    rtol: float = 1e-3,
    atol: Optional[float] = None,
    substeps: int = 1,
    hht_alpha: float = -0.05,
    threads: Optional[int] = None,
) -> History: ...
def frf(
    model: Union[Model, Reduced],
    from_hz: float,
    to_hz: float,
    harmonics: int = 7,
    level: float = 1.0,
    stability: bool = True,
    modes: int = 20,
    residual_flexibility: bool = True,
    max_points: Optional[int] = None,
    mode: str = "continuation",
    points: Optional[int] = None,
    threads: Optional[int] = None,
) -> Frf: ...
def builtin_models() -> List[Tuple[str, str]]: ...

class Nnm:
    """A nonlinear mode, amplitudes first, in increasing amplitude."""

    @property
    def amplitude(self) -> npt.NDArray[np.float64]:
        """(point,) modal amplitude, m sqrt(kg)"""
    @property
    def frequency_hz(self) -> npt.NDArray[np.float64]:
        """(point,)"""
    @property
    def damping_ratio(self) -> npt.NDArray[np.float64]:
        """(point,)"""
    @property
    def xi(self) -> npt.NDArray[np.float64]:
        """(point,) artificial damping, 1/s"""
    @property
    def response(self) -> npt.NDArray[np.complex128]:
        """(point, sensor, harmonic 0..H), cosine convention"""
    @property
    def iterations(self) -> List[int]: ...
    @property
    def sensors(self) -> List[str]: ...
    @property
    def mode(self) -> int: ...
    @property
    def modes(self) -> int: ...
    @property
    def status(self) -> str: ...
    @property
    def detail(self) -> str: ...
    def __len__(self) -> int: ...
    def to_dataframe(self) -> Any: ...

def nnm(
    model: Model,
    from_amplitude: float,
    to_amplitude: float,
    mode: int = 1,
    points: int = 50,
    harmonics: int = 7,
    modes: int = 10,
    threads: Optional[int] = None,
) -> Nnm: ...

class TestData:
    """Stepped-sine test data: one drive point, response channels, sweeps of steps."""

    def __init__(
        self,
        input: str,
        channels: Mapping[str, str],
        sweeps: Sequence[Mapping[str, Any]],
        noise: Union[float, Sequence[float], None] = None,
        noise_absolute: Union[float, Sequence[float], None] = None,
        drive: str = "force",
    ) -> None: ...
    @staticmethod
    def load(
        path: Union[str, "os.PathLike[str]"],
        model: Model,
        noise: float = 0.01,
        phase_offset_deg: float = 0.0,
    ) -> TestData: ...
    def save(self, path: Union[str, "os.PathLike[str]"]) -> None: ...
    @property
    def input(self) -> str: ...
    @property
    def drive(self) -> str: ...
    @property
    def channels(self) -> List[str]: ...
    @property
    def quantities(self) -> List[str]: ...
    @property
    def noise(self) -> List[Tuple[float, float]]:
        """(absolute, relative) per channel"""
    @property
    def harmonics(self) -> int: ...
    @property
    def n_points(self) -> int: ...
    @property
    def sweeps(self) -> List[Dict[str, Any]]:
        """each: label, direction, frequency_hz (step,), force (step, harmonic),
        response (step, channel, harmonic), sigma (as response) or None"""
    def __len__(self) -> int: ...
    def to_dataframe(self) -> Any: ...

class ModalCalibration:
    """FE-level parameters fitted to measured modes."""

    @property
    def params(self) -> List[str]: ...
    @property
    def fe_stats(self) -> Dict[str, Any]:
        """fe_reduction, basis_size, setup_reductions, evaluations, refreshes, full_reductions
        (full eigen solves), full_seconds"""
    @property
    def estimate(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def status(self) -> str: ...
    @property
    def cost(self) -> float: ...
    @property
    def reduced_chi2(self) -> float: ...
    @property
    def cramer_rao_std(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def chi2_scaled_std(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """(param, param)"""
    @property
    def at_bound(self) -> List[bool]: ...
    @property
    def pairing(self) -> List[int]: ...
    @property
    def frequency_hz(self) -> npt.NDArray[np.float64]:
        """(measured mode,) computed at the estimate"""
    @property
    def mac(self) -> npt.NDArray[np.float64]:
        """(measured mode,)"""
    @property
    def candidates(self) -> npt.NDArray[np.float64]:
        """(candidate, param)"""
    @property
    def candidate_cost(self) -> npt.NDArray[np.float64]:
        """(candidate,)"""
    def to_dataframe(self) -> Any: ...

def calibrate_modal(
    model: Model,
    data: Union[str, "os.PathLike[str]", Mapping[str, Any]],
    params: Mapping[str, Tuple[float, float]],
    shape_noise: float = 0.02,
    modes: int = 20,
    lhs: int = 64,
    seed: int = 1,
    starts: int = 3,
    fe_reduction: str = "parametric",
    fe_tolerance: Optional[float] = None,
    threads: Optional[int] = None,
    resume: Optional[PartialCalibration] = None,
) -> ModalCalibration: ...

class TimeCalibration:
    """Element law parameters fitted to a raw time record."""

    @property
    def params(self) -> List[str]: ...
    @property
    def estimate(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def status(self) -> str: ...
    @property
    def cost(self) -> float: ...
    @property
    def reduced_chi2(self) -> float: ...
    @property
    def cramer_rao_std(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def chi2_scaled_std(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def covariance(self) -> npt.NDArray[np.float64]:
        """(param, param)"""
    @property
    def at_bound(self) -> List[bool]: ...
    @property
    def poorly_identified(self) -> List[bool]: ...
    @property
    def kfold(
        self,
    ) -> Optional[
        Tuple[npt.NDArray[np.float64], npt.NDArray[np.float64], npt.NDArray[np.float64]]
    ]:
        """(mean, std, jackknife_std) of the fold estimates, each (param,)"""
    @property
    def simulated(self) -> Dict[str, npt.NDArray[np.float64]]:
        """{channel: (sample,)} the calibrated model's response"""
    @property
    def candidates(self) -> npt.NDArray[np.float64]:
        """(candidate, param)"""

def calibrate_time(
    model: Model,
    force: npt.NDArray[np.float64],
    responses: Mapping[str, npt.NDArray[np.float64]],
    rate_hz: float,
    params: Mapping[str, Tuple[float, float]],
    drive: Optional[str] = None,
    data_noise: float = 0.01,
    modes: int = 20,
    lhs: int = 64,
    seed: int = 1,
    starts: int = 3,
    folds: int = 10,
    threads: Optional[int] = None,
    resume: Optional[PartialCalibration] = None,
) -> TimeCalibration: ...

class VirtualTest:
    """A virtual stepped-sine test through the shaker model."""

    @property
    def data(self) -> TestData: ...
    @property
    def open_loop(self) -> Optional[TestData]: ...
    @property
    def drive(self) -> str: ...
    @property
    def frequency_hz(self) -> npt.NDArray[np.float64]:
        """(step,)"""
    @property
    def voltage(self) -> npt.NDArray[np.complex128]:
        """(step, harmonic 0..H), V"""
    @property
    def force(self) -> npt.NDArray[np.complex128]:
        """(step, harmonic 0..H), N"""
    @property
    def force_error(self) -> npt.NDArray[np.float64]:
        """(step,)"""
    @property
    def noise_floors(self) -> List[Tuple[str, float]]: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def raw(self) -> Optional[Dict[str, Any]]:
        """The raw time histories (`[raw]` in the test file): rate_hz, time_s, voltage,
        force, responses, noise_std, steps, dwell_s, settle_s, oversample, status."""
        ...

def virtual_test(
    model: Model,
    test: Union[str, "os.PathLike[str]"],
    threads: Optional[int] = None,
) -> VirtualTest: ...

class Plan:
    """Candidate test designs, best first."""

    @property
    def params(self) -> List[str]: ...
    @property
    def nominal(self) -> npt.NDArray[np.float64]:
        """(param,)"""
    @property
    def criterion(self) -> str: ...
    @property
    def designs(self) -> List[Tuple[str, str, str, str, str, str]]:
        """(drive, level N, signal, band, sensors, harmonics) per design"""
    @property
    def log_det(self) -> npt.NDArray[np.float64]:
        """(design,)"""
    @property
    def max_variance(self) -> npt.NDArray[np.float64]:
        """(design,)"""
    @property
    def relative_std(self) -> npt.NDArray[np.float64]:
        """(design, param)"""
    @property
    def collinearity(self) -> npt.NDArray[np.float64]:
        """(design,)"""
    @property
    def warnings(self) -> List[str]: ...
    def __len__(self) -> int: ...
    def to_dataframe(self) -> Any: ...

def plan(
    model: Model,
    plan: Union[str, "os.PathLike[str]"],
    threads: Optional[int] = None,
) -> Plan: ...

class BalancePoint:
    """One solved harmonic-balance point."""

    @property
    def x(self) -> npt.NDArray[np.float64]:
        """(unknown,): the start of the next solve"""
    @property
    def response(self) -> npt.NDArray[np.complex128]:
        """(sensor, harmonic 0..H), cosine convention"""
    @property
    def status(self) -> str: ...
    @property
    def iterations(self) -> int: ...
    @property
    def residual(self) -> float: ...
    @property
    def seconds(self) -> float:
        """wall time of the library's Newton solve alone"""

class Balance:
    """A harmonic-balance system built once, solved at any frequency and level."""

    def __init__(
        self,
        model: Union[Model, Reduced],
        harmonics: int = 7,
        modes: int = 20,
        residual_flexibility: bool = True,
        threads: Optional[int] = None,
    ) -> None: ...
    @property
    def n_unknowns(self) -> int: ...
    def solve(
        self,
        freq_hz: float,
        level: float = 1.0,
        start: Optional[npt.NDArray[np.float64]] = None,
    ) -> BalancePoint: ...
