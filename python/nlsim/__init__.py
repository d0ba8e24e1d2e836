"""nlsim: simulation and calibration of large linear structures with local nonlinearities.

The Python face of the nlsim engine (Y. Chen, *Model calibration methods for mechanical
systems with local nonlinearities*, Linnaeus University, 2016). Build a :class:`Model` from
scipy.sparse mass and stiffness matrices or load a model file, then compute

- :func:`modes` -- natural frequencies, mass-normalised shapes, effective masses;
- :func:`reduce` -- the modal reduction with residual flexibility that the runs use;
- :func:`simulate` -- time histories by the exponential first-order hold;
- :func:`frf` -- multi-harmonic frequency responses by harmonic balance, followed through
  folds, with Hill stability;
- :func:`frf` with ``mode="step-up"`` -- stepped sines that jump at folds as a test does;
- :func:`nnm` -- nonlinear modes (backbone frequency and damping against amplitude);
- :class:`TestData` -- stepped-sine test data from numpy arrays or files;
- :func:`calibrate` -- parameters fitted to a stepped-sine test, with Cramer-Rao bounds and
  k-fold cross validation; :func:`calibrate_modal` -- FE-level parameters from measured modes;
  :func:`calibrate_time` -- element laws fitted to raw time records (sweeps, chirps, decays);
- :func:`virtual_test` and :func:`plan` -- the virtual test through a shaker model and the
  ranking of candidate test designs by their Fisher information.

Every function runs the same code as the ``nlsim`` command line with the same defaults, so the
numbers equal the command's to the last bit. Results are numpy arrays, time or frequency
first; frequencies are in Hz. Computations release the GIL, run on ``threads`` threads
(default: one per core; the numbers do not depend on it) and stop at Ctrl-C with
``KeyboardInterrupt``; a :func:`calibrate` interrupted so carries what it completed as
``args[1]`` (a :class:`PartialCalibration`), and ``calibrate(..., resume=partial)`` goes on
from it to the uninterrupted call's estimates. Errors are :class:`Error` subclasses with the command line's
one-line messages. See ``docs/python.md`` for a worked example.
"""

from __future__ import annotations

from typing import Any, Optional, Sequence

import numpy as np

from . import _native
from ._native import (
    Balance,
    BalancePoint,
    Calibration,
    ComputationError,
    Error,
    FileError,
    Frf,
    History,
    InputError,
    ModalCalibration,
    Model,
    Modes,
    Nnm,
    PartialCalibration,
    Plan,
    Reduced,
    TestData,
    TimeCalibration,
    VirtualTest,
    builtin_models,
    calibrate,
    calibrate_modal,
    frf,
    modes,
    nnm,
    reduce,
    simulate,
)

__version__: str = _native.__version__

__all__ = [
    "Balance",
    "BalancePoint",
    "Calibration",
    "ComputationError",
    "Error",
    "FileError",
    "Frf",
    "History",
    "InputError",
    "ModalCalibration",
    "Model",
    "Modes",
    "Nnm",
    "PartialCalibration",
    "Plan",
    "Reduced",
    "TestData",
    "TimeCalibration",
    "VirtualTest",
    "builtin_models",
    "calibrate",
    "calibrate_modal",
    "calibrate_time",
    "frf",
    "from_matrices",
    "load",
    "modes",
    "nnm",
    "plan",
    "reduce",
    "simulate",
    "virtual_test",
]


def _csr(name: str, a: Any, n: Optional[int]):
    """The CSR arrays of matrix ``a`` (scipy.sparse or a dense 2-D array) as contiguous
    numpy arrays, without a copy where they already are."""
    if hasattr(a, "tocsr"):
        a = a.tocsr()
        shape = a.shape
        indptr, indices, data = a.indptr, a.indices, a.data
    else:
        dense = np.asarray(a)
        if dense.ndim != 2:
            raise InputError(
                f"{name}: expected a scipy.sparse matrix or a 2-D array, got {dense.ndim} dimension(s)"
            )
        shape = dense.shape
        rows, cols = np.nonzero(dense)
        indptr = np.searchsorted(rows, np.arange(shape[0] + 1)).astype(np.int64)
        indices = cols.astype(np.int64)
        data = dense[rows, cols]
    if shape[0] != shape[1]:
        raise InputError(f"{name}: shape {shape[0]} x {shape[1]} is not square")
    if n is not None and shape[0] != n:
        raise InputError(f"{name}: shape {shape[0]} x {shape[1]}; the model has {n} DOFs")
    if not np.issubdtype(np.asarray(data).dtype, np.floating) and not np.issubdtype(
        np.asarray(data).dtype, np.integer
    ):
        raise InputError(f"{name}: dtype {np.asarray(data).dtype} is not real (float64 expected)")
    data = np.ascontiguousarray(data, dtype=np.float64)
    indptr = np.ascontiguousarray(indptr)
    indices = np.ascontiguousarray(indices)
    if indptr.dtype not in (np.int32, np.int64):
        indptr = indptr.astype(np.int64)
    if indices.dtype not in (np.int32, np.int64):
        indices = indices.astype(np.int64)
    return shape[0], indptr, indices, data


def from_matrices(
    M: Any,
    K: Any,
    dofs: Optional[Sequence[str]] = None,
    name: str = "model",
) -> Model:
    """A :class:`Model` from its mass ``M`` (kg) and stiffness ``K`` (N/m) matrices.

    ``M`` and ``K`` are scipy.sparse matrices (any format; taken through ``.tocsr()``, with
    no further copy on the Python side) or dense 2-D arrays, symmetric, of the same order
    ``n``. ``dofs`` gives one label ``NODE:COMPONENT`` per row (``"12:uz"``, ``"3:rx"``) or is
    ``None`` for ``1:u`` ... ``n:u``. Raises :class:`InputError` naming the argument for a
    non-square, non-symmetric or non-finite matrix, or a wrong number of labels.
    """
    n, mp, mi, md = _csr("M", M, None)
    _, kp, ki, kd = _csr("K", K, n)
    labels = None if dofs is None else [str(d) for d in dofs]
    return Model.from_csr(name, n, mp, mi, md, kp, ki, kd, labels)


def load(spec: str) -> Model:
    """Loads a model file (``.toml``) or a built-in model by name (``"ecl_beam"``,
    ``"bracket:dofs=20000"``; see :func:`builtin_models`)."""
    return Model.load(spec)


def _toml_key(k: Any) -> str:
    return _toml_value("key", str(k))


def _toml_value(key: str, v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, np.integer)):
        return str(int(v))
    if isinstance(v, (float, np.floating)):
        return repr(float(v))
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, dict):
        items = (f"{_toml_key(k)} = {_toml_value(f'{key}.{k}', x)}" for k, x in v.items())
        return "{ " + ", ".join(items) + " }"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "[" + ", ".join(_toml_value(key, x) for x in v) + "]"
    raise InputError(f"{key}: {type(v).__name__} is not a value a test or plan file holds")


def _toml(arg: str, spec: Any) -> Any:
    """A test or plan given as a dict, as the TOML text of the file it stands for: scalars,
    lists and inline tables as keys; a list of dicts as an array of tables (``sweep=[{...}]``
    is ``[[sweep]]``), a dict of scalars under a table name as that table (``shaker={...}``
    is ``[shaker]``). Paths and TOML text pass unchanged."""
    if not isinstance(spec, dict):
        return spec
    head, tables = [], []
    for key, v in spec.items():
        if not isinstance(key, str):
            raise InputError(f"{arg}: keys are str, not {type(key).__name__}")
        if isinstance(v, (list, tuple)) and v and all(isinstance(x, dict) for x in v):
            for x in v:
                tables.append(f"[[{key}]]")
                tables.extend(
                    f"{_toml_key(k)} = {_toml_value(f'{key}.{k}', y)}" for k, y in x.items()
                )
        elif isinstance(v, dict) and key in ("shaker", "control"):
            tables.append(f"[{key}]")
            tables.extend(f"{_toml_key(k)} = {_toml_value(f'{key}.{k}', y)}" for k, y in v.items())
        else:
            head.append(f"{_toml_key(key)} = {_toml_value(key, v)}")
    return "\n".join(head + tables) + "\n"


def virtual_test(model: Model, test: Any, threads: Optional[int] = None) -> VirtualTest:
    """Runs a virtual stepped-sine test through the shaker model, as ``nlsim test MODEL
    TEST``. ``test`` is a test file's path, its TOML text, or a dict of its keys
    (``{"drive": "tip", "sweep": [{"from": 30.0, "to": 36.0, "steps": 21, "force": 0.2}]}``;
    docs/planning.md lists them). Nothing is written: ``result.data`` is a :class:`TestData`
    (``.save("test.csv")`` writes it, :func:`calibrate` takes it)."""
    return _native.virtual_test(model, _toml("test", test), threads=threads)


def plan(model: Model, plan: Any, threads: Optional[int] = None) -> Plan:
    """Ranks candidate test designs by the Fisher information of ``plan["params"]``, as
    ``nlsim plan MODEL PLAN``. ``plan`` is a plan file's path, its TOML text or a dict of its
    keys (``{"params": ["tip.k3"], "levels": [0.1, 0.2], "band": [{"from": 30.0, "to":
    36.0, "steps": 15}]}``; docs/planning.md lists them). Returns a :class:`Plan`, best
    design first."""
    return _native.plan(model, _toml("plan", plan), threads=threads)


def _frame(columns: dict):
    try:
        import pandas as pd
    except ImportError as e:  # pragma: no cover - depends on the environment
        raise ImportError("to_dataframe() needs pandas: pip install pandas") from e
    return pd.DataFrame(columns)


def _modes_frame(self: Modes):
    cols = {
        "frequency_hz": self.frequency_hz,
        "damping_ratio": self.damping_ratio,
    }
    for k, v in self.effective_mass.items():
        cols[f"effective_mass_{k}_kg"] = v
    cols["residual"] = self.residual
    df = _frame(cols)
    df.index = np.arange(1, len(df) + 1)
    df.index.name = "mode"
    return df


def _history_frame(self: History):
    cols = {"time_s": self.time}
    out = self.outputs
    for j, s in enumerate(self.sensors):
        cols[s] = out[:, j]
    return _frame(cols)


def _frf_frame(self: Frf):
    cols = {
        "frequency_hz": self.frequency_hz,
        "level": self.level,
        "stable": self.stable,
        "kind": self.kind,
    }
    y = self.response
    for j, s in enumerate(self.sensors):
        for k, h in enumerate(self.harmonics):
            label = f"{h:g}"
            cols[f"{s}_h{label}"] = y[:, j, k]
    return _frame(cols)


def _calibration_frame(self: Calibration):
    cols = {
        "estimate": self.estimate,
        "cramer_rao_std": self.cramer_rao_std,
        "chi2_scaled_std": self.chi2_scaled_std,
    }
    if self.kfold_mean is not None:
        cols["kfold_mean"] = self.kfold_mean
        cols["kfold_std"] = self.kfold_std
        cols["jackknife_std"] = self.jackknife_std
    cols["at_bound"] = self.at_bound
    cols["poorly_identified"] = self.poorly_identified
    df = _frame(cols)
    df.index = self.params
    df.index.name = "param"
    return df


def _nnm_frame(self: Nnm):
    cols = {
        "amplitude": self.amplitude,
        "frequency_hz": self.frequency_hz,
        "damping_ratio": self.damping_ratio,
    }
    y = self.response
    for j, s in enumerate(self.sensors):
        for k in range(1, y.shape[2]):
            cols[f"{s}_h{k}"] = y[:, j, k]
    return _frame(cols)


def _test_data_frame(self: TestData):
    rows: dict = {"sweep": [], "step": [], "frequency_hz": [], "force": []}
    for c in self.channels:
        rows[c] = []
    for s in self.sweeps:
        for i, f in enumerate(s["frequency_hz"]):
            rows["sweep"].append(s["label"])
            rows["step"].append(i + 1)
            rows["frequency_hz"].append(f)
            rows["force"].append(s["force"][i, 0])
            for j, c in enumerate(self.channels):
                rows[c].append(s["response"][i, j, 0])
    return _frame(rows)


def _modal_frame(self: ModalCalibration):
    df = _frame(
        {
            "estimate": self.estimate,
            "cramer_rao_std": self.cramer_rao_std,
            "chi2_scaled_std": self.chi2_scaled_std,
            "at_bound": self.at_bound,
        }
    )
    df.index = self.params
    df.index.name = "param"
    return df


def _plan_frame(self: Plan):
    d = self.designs
    cols = {
        "drive": [x[0] for x in d],
        "level_n": [float(x[1]) for x in d],
        "signal": [x[2] for x in d],
        "band": [x[3] for x in d],
        "sensors": [x[4] for x in d],
        "harmonics": [x[5] for x in d],
        "log_det": self.log_det,
        "max_variance": self.max_variance,
        "collinearity": self.collinearity,
    }
    std = self.relative_std
    for j, p in enumerate(self.params):
        cols[f"std_{p}"] = std[:, j]
    df = _frame(cols)
    df.index = np.arange(1, len(df) + 1)
    df.index.name = "rank"
    return df


Nnm.to_dataframe = _nnm_frame  # type: ignore[attr-defined]
TestData.to_dataframe = _test_data_frame  # type: ignore[attr-defined]
ModalCalibration.to_dataframe = _modal_frame  # type: ignore[attr-defined]
Plan.to_dataframe = _plan_frame  # type: ignore[attr-defined]
Calibration.to_dataframe = _calibration_frame  # type: ignore[attr-defined]
Modes.to_dataframe = _modes_frame  # type: ignore[attr-defined]
History.to_dataframe = _history_frame  # type: ignore[attr-defined]
Frf.to_dataframe = _frf_frame  # type: ignore[attr-defined]
Model.from_matrices = staticmethod(from_matrices)  # type: ignore[attr-defined]


def calibrate_time(
    model: Model,
    force: Any,
    responses: Any,
    rate_hz: float,
    params: Any,
    **options: Any,
) -> TimeCalibration:
    """Element law parameters fitted to a raw time record, as ``nlsim calibrate MODEL RECORDS
    --time-domain`` does it: ``force`` (N) at the excitation ``drive`` (default: the model's
    first) and ``responses`` ``{sensor: samples}``, sampled at ``rate_hz`` from rest; each
    channel's noise is ``data_noise`` (default 0.01) times its rms. Other options: ``modes``
    (20), ``lhs`` (64), ``seed`` (1), ``starts`` (3), ``folds`` (10, contiguous blocks of
    samples), ``threads``. Any array-like is taken (copied to contiguous float64 only where
    it is not already)."""
    return _native.calibrate_time(
        model,
        np.ascontiguousarray(force, dtype=np.float64),
        {k: np.ascontiguousarray(v, dtype=np.float64) for k, v in dict(responses).items()},
        rate_hz,
        params,
        **options,
    )
