//! # nlsim
//!
//! Simulation and calibration of large linear structures with local nonlinearities, after
//! Y. Chen, *Model calibration methods for mechanical systems with local nonlinearities*
//! (Linnaeus University, 2016). This crate is the facade: it re-exports the numeric crates
//! and holds what touches files — model files, Matrix Market, HDF5 results, plots, batches
//! (feature `io`) — and the `nlsim` command line (feature `cli`, which implies `io`; both on by
//! default). Link with `default-features = false` for the computation alone: no libhdf5, no
//! plotting, no file formats. [`prelude`] holds the names a workflow in code needs:
//!
//! ```
//! use nlsim::prelude::*;
//! # fn main() -> nlsim::kernel::Result<()> {
//! let k = SparseSym::from_triplets("K", 1, &[(0, 0, 1.5e7)])?;
//! let m = SparseSym::diagonal("M", &[450.0])?;
//! let spring = NonlinearElement::new("spring", Law::Cubic { k3: 1.7e15 }, Coupling::single(0))?;
//! let model = Model::builder("duffing", DofMap::scalar(1), m, k)
//!     .damping(Damping::Rayleigh { alpha: 250.0 / 450.0, beta: 0.0 })
//!     .element(spring)
//!     .excitation("force", "1:u", 2.0)
//!     .sensor("x", "1:u", Quantity::Displacement)
//!     .build()?;
//! assert_eq!(model.parameters(), vec![Param::element("spring", "k3")]);
//! # Ok(())
//! # }
//! ```
//!
//! With `io`, model files and built-in models load by name:
//!
//! ```no_run
//! # #[cfg(feature = "io")] {
//! let loaded = nlsim::load_model("ecl_beam").unwrap();
//! let report = loaded.model.validate(&nlsim::kernel::ValidationConfig::default()).unwrap();
//! println!("{}", nlsim::summary::model_summary(&loaded.model, &loaded.source, Some(&report)));
//! # }
//! ```

#[cfg(feature = "io")]
pub mod batch;
#[cfg(feature = "io")]
pub mod cache;
#[cfg(feature = "io")]
pub mod calibration;
#[cfg(feature = "io")]
pub mod demo;
pub mod error;
#[cfg(feature = "io")]
pub mod frf;
#[cfg(feature = "io")]
pub mod modal_calibration;
#[cfg(feature = "io")]
pub mod modaldata;
#[cfg(feature = "io")]
pub mod modes;
#[cfg(feature = "io")]
pub mod mtx;
#[cfg(feature = "io")]
pub mod nnm;
#[cfg(feature = "io")]
pub mod output;
#[cfg(feature = "io")]
pub mod planning;
#[cfg(feature = "io")]
pub mod plot;
pub mod prelude;
#[cfg(feature = "io")]
pub mod pretest;
#[cfg(feature = "io")]
pub mod report;
#[cfg(feature = "io")]
pub mod run;
#[cfg(feature = "io")]
pub mod simulate;
#[cfg(feature = "io")]
pub mod spec;
pub mod summary;
#[cfg(feature = "io")]
pub mod testdata;
#[cfg(feature = "io")]
pub mod uff;
#[cfg(feature = "io")]
pub mod vtest;

pub use error::{Error, Result};
pub use nlsim_calib as calib;
pub use nlsim_fixtures as fixtures;
pub use nlsim_hb as hb;
pub use nlsim_kernel as kernel;
pub use nlsim_reduction as reduction;
pub use nlsim_sim as sim;
#[cfg(feature = "io")]
pub use spec::{LoadedModel, load_model, parse_model_file};
