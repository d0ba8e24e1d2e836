//! `nlsim._native`: the compiled part of the Python package `nlsim` (see `docs/python.md`).
//!
//! Each function takes plain Python values and contiguous numpy arrays, runs the same library
//! calls as the `nlsim` command line (so a result equals the command's to the last bit where
//! the same path runs) with the GIL released, and hands back numpy arrays. The Python layer
//! (`python/nlsim/__init__.py`) turns scipy.sparse matrices into the CSR arrays taken here,
//! wraps the results in documented classes and adds `to_dataframe()`.
//!
//! Errors are `nlsim.Error` subclasses carrying the command line's one-line messages:
//! [`InputError`] for what the caller gave (a wrong shape, an unknown DOF or parameter, a
//! model that is not symmetric), [`FileError`] for files that cannot be read, and
//! [`ComputationError`] for a numerical failure on valid input. A solver that stops short is
//! not an error: its result carries `status` and `detail`, as in the Rust library.

mod balance;
mod calibration;
mod data;
mod history;
mod modal;
mod model;
mod nnm;
mod runs;
mod testing;
mod time_domain;

use pyo3::create_exception;
use pyo3::exceptions::PyException;
use pyo3::prelude::*;

create_exception!(
    _native,
    Error,
    PyException,
    "Base class of every error nlsim raises; its message is the command line's one line."
);
create_exception!(
    _native,
    InputError,
    Error,
    "What was passed in is unusable: a wrong shape or dtype, a non-symmetric matrix, a NaN, \
     an unknown DOF label or parameter name. The message names the argument."
);
create_exception!(
    _native,
    FileError,
    Error,
    "A file could not be read or written (the message names the file, line and key)."
);
create_exception!(
    _native,
    ComputationError,
    Error,
    "A numerical failure on valid input (a singular factorisation, an eigensolver that \
     did not converge)."
);

/// An nlsim error as the Python exception of its kind, with the one-line message the
/// command line prints.
pub(crate) fn py_err(e: nlsim::Error) -> PyErr {
    let message = nlsim::formats::files::one_line(&e.to_string());
    match e {
        nlsim::Error::Io { .. }
        | nlsim::Error::Hdf5 { .. }
        | nlsim::Error::DataFile { .. }
        | nlsim::Error::Spec { .. } => FileError::new_err(message),
        nlsim::Error::Model(nlsim::kernel::Error::Numerical { .. }) | nlsim::Error::Failed(_) => {
            ComputationError::new_err(message)
        }
        _ => InputError::new_err(message),
    }
}

/// A kernel (numeric crate) error as a Python exception.
pub(crate) fn kernel_err(e: nlsim::kernel::Error) -> PyErr {
    py_err(nlsim::Error::Model(e))
}

/// Most harmonics a harmonic balance takes from Python, as `nlsim frf --harmonics` takes
/// (the Jacobian and the AFT grid grow with the square of H; 5000 took gigabytes before it
/// failed).
pub(crate) const MAX_HARMONICS: usize = 256;

/// Most harmonics a calibration takes (`nlsim calibrate`'s bound: every evaluation is a
/// continuation of the harmonic balance).
pub(crate) const MAX_CALIBRATION_HARMONICS: usize = 64;

/// The harmonic set `1..=harmonics`, refused in one line beyond `max`.
pub(crate) fn harmonic_set(harmonics: usize, max: usize) -> PyResult<nlsim::hb::HarmonicSet> {
    if harmonics == 0 || harmonics > max {
        return Err(input(format!(
            "harmonics={harmonics}: give 1 to {max} (the Jacobian and the AFT grid grow with \
             the square of the harmonics)"
        )));
    }
    nlsim::hb::HarmonicSet::new(harmonics, 1).map_err(|e| input(format!("harmonics: {e}")))
}

/// An [`InputError`] with `message`.
pub(crate) fn input(message: impl Into<String>) -> PyErr {
    InputError::new_err(message.into())
}

#[pymodule]
fn _native(m: &Bound<'_, PyModule>) -> PyResult<()> {
    let py = m.py();
    // As the `nlsim` binary: faer's implicit parallelism (dense decompositions that take no
    // `Par`) stays sequential, so the numbers do not depend on the thread count.
    faer::set_global_parallelism(faer::Par::Seq);
    m.add("Error", py.get_type::<Error>())?;
    m.add("InputError", py.get_type::<InputError>())?;
    m.add("FileError", py.get_type::<FileError>())?;
    m.add("ComputationError", py.get_type::<ComputationError>())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<model::Model>()?;
    m.add_class::<runs::Modes>()?;
    m.add_class::<runs::Reduced>()?;
    m.add_class::<history::History>()?;
    m.add_class::<runs::Frf>()?;
    m.add_function(wrap_pyfunction!(runs::modes, m)?)?;
    m.add_function(wrap_pyfunction!(runs::reduce, m)?)?;
    m.add_function(wrap_pyfunction!(history::simulate, m)?)?;
    m.add_function(wrap_pyfunction!(runs::frf, m)?)?;
    m.add_function(wrap_pyfunction!(runs::builtin_models, m)?)?;
    m.add_class::<calibration::Calibration>()?;
    m.add_class::<calibration::PartialCalibration>()?;
    m.add_function(wrap_pyfunction!(calibration::calibrate, m)?)?;
    m.add_class::<data::TestData>()?;
    m.add_class::<modal::ModalCalibration>()?;
    m.add_function(wrap_pyfunction!(modal::calibrate_modal, m)?)?;
    m.add_class::<nnm::Nnm>()?;
    m.add_function(wrap_pyfunction!(nnm::nnm, m)?)?;
    m.add_class::<balance::Balance>()?;
    m.add_class::<balance::BalancePoint>()?;
    m.add_class::<testing::VirtualTest>()?;
    m.add_function(wrap_pyfunction!(testing::virtual_test, m)?)?;
    m.add_class::<testing::Plan>()?;
    m.add_function(wrap_pyfunction!(testing::plan, m)?)?;
    m.add_class::<time_domain::TimeCalibration>()?;
    m.add_function(wrap_pyfunction!(time_domain::calibrate_time, m)?)?;
    Ok(())
}
