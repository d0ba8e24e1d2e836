//! # nlsim
//!
//! Simulation and calibration of large linear structures with local nonlinearities, after
//! Y. Chen, *Model calibration methods for mechanical systems with local nonlinearities*
//! (Linnaeus University, 2016). This crate is the facade: it re-exports the numeric crates
//! and holds what touches files — model files, Matrix Market, HDF5 results — and the `nlsim` command line
//! (feature `cli`, on by default; link with `default-features = false` to leave out clap).
//!
//! ```no_run
//! let loaded = nlsim::load_model("ecl_beam").unwrap();
//! let report = loaded.model.validate(&nlsim::kernel::ValidationConfig::default()).unwrap();
//! println!("{}", nlsim::summary::model_summary(&loaded.model, &loaded.source, Some(&report)));
//! ```

pub mod batch;
pub mod cache;
pub mod error;
pub mod frf;
pub mod modes;
pub mod mtx;
pub mod output;
pub mod plot;
pub mod run;
pub mod simulate;
pub mod spec;
pub mod summary;

pub use error::{Error, Result};
pub use nlsim_fixtures as fixtures;
pub use nlsim_hb as hb;
pub use nlsim_kernel as kernel;
pub use nlsim_reduction as reduction;
pub use nlsim_sim as sim;
pub use spec::{LoadedModel, load_model, parse_model_file};
