//! The error type of the nlsim facade: file and command-line problems, wrapping the numeric
//! crates' [`nlsim_kernel::Error`].

use std::path::PathBuf;
use thiserror::Error;

/// Result alias of the facade.
pub type Result<T, E = Error> = core::result::Result<T, E>;

/// What went wrong, with the file, line and key where that applies.
#[derive(Debug, Error)]
#[non_exhaustive]
pub enum Error {
    /// A model file is malformed or inconsistent.
    #[error("{}:{line}: {}{message}", file.display(), key_prefix(key))]
    Spec {
        /// The model file.
        file: PathBuf,
        /// 1-based line of the offending key or value.
        line: usize,
        /// Dotted key path, e.g. `element[2].dof`.
        key: String,
        /// What is wrong.
        message: String,
    },
    /// A Matrix Market or DOF-label file is malformed.
    #[error("{}:{line}: {message}", file.display())]
    DataFile {
        /// The file.
        file: PathBuf,
        /// 1-based line.
        line: usize,
        /// What is wrong.
        message: String,
    },
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The system error.
        source: std::io::Error,
    },
    /// The model argument names neither a file nor a fixture.
    #[error("model '{0}' is neither a model file nor a built-in model; built-in models: {1}")]
    UnknownModel(String, String),
    /// The model itself is invalid (numbers, not syntax).
    #[error("{0}")]
    Model(#[from] nlsim_kernel::Error),
    /// An HDF5 file could not be written or read.
    #[error("{}: HDF5: {message}", path.display())]
    Hdf5 {
        /// The file.
        path: PathBuf,
        /// What the HDF5 library reported.
        message: String,
    },
    /// Part of a run failed and the rest was written (exit code 1), e.g. some batch jobs.
    #[error("{0}")]
    Failed(String),
    /// A command-line value is unusable (exit code 2).
    #[error("{0}")]
    Usage(String),
    /// A stop signal (Ctrl-C, SIGTERM) ended the run at a safe point after it wrote what was
    /// complete; the message says what was kept (exit code 128 + the signal, 130 for Ctrl-C).
    #[error("{0}")]
    Interrupted(String),
}

/// `key: ` before a message, or nothing for an error of the file as a whole (a key that the
/// parser could not name, e.g. an empty one: the message says what it found).
fn key_prefix(key: &str) -> String {
    if key.is_empty() {
        String::new()
    } else {
        format!("{key}: ")
    }
}
