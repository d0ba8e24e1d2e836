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
    data: Union[str, "os.PathLike[str]"],
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
    threads: Optional[int] = None,
) -> Calibration: ...
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
    threads: Optional[int] = None,
) -> Frf: ...
def builtin_models() -> List[Tuple[str, str]]: ...
