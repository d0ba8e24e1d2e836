//! # nlsim
//!
//! Simulation and calibration of large linear structures with local nonlinearities, after
//! Y. Chen, *Model calibration methods for mechanical systems with local nonlinearities*
//! (Linnaeus University, 2016). This crate is the facade: it re-exports the numeric crates
//! ([`kernel`], [`reduction`], [`sim`], [`hb`], [`calib`], [`fixtures`]) and adds, in layers
//! whose dependencies point down:
//!
//! | layer | holds | feature |
//! |---|---|---|
//! | [`formats`] | file formats in and out: model files, matrices, test data, universal files, result files | `formats` (`.h5` files: `hdf5`) |
//! | [`present`] | summaries, plots, the HTML report, the terminal | `io` (summaries always) |
//! | [`commands`] | one request, one run, one report writer per `nlsim` command | `io` |
//! | [`batch`] | jobs files, shards, merge, SLURM job arrays | `io` |
//! | [`cli`] | the command line: options and help texts, arguments into requests, dispatch | `cli` |
//! | `src/bin/nlsim/` | the `nlsim` binary: parse, thread pool, dispatch, exit code | `cli` |
//!
//! `cli` implies `io`, which implies `hdf5` and `formats`; `cli` is on by default. Link with
//! `default-features = false` for the computation alone (no libhdf5, no plotting, no file
//! formats), with `features = ["formats"]` to read and write nlsim's text and binary files
//! without any system library (the Python package does), or `features = ["hdf5"]` for the
//! HDF5 files too, still without the plotting and command layers. [`prelude`] holds the names a workflow in code needs:
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
//! println!("{}", nlsim::present::summary::model_summary(&loaded.model, &loaded.source, Some(&report)));
//! # }
//! ```

#[cfg(feature = "io")]
pub mod batch;
#[cfg(feature = "cli")]
pub mod cli;
#[cfg(feature = "formats")]
pub mod commands;
pub mod error;
#[cfg(feature = "formats")]
pub mod formats;
pub mod prelude;
pub mod present;

pub use error::{Error, Result};
#[cfg(feature = "formats")]
pub use formats::model_file::{LoadedModel, load_model, parse_model_file};
pub use nlsim_calib as calib;
pub use nlsim_fixtures as fixtures;
pub use nlsim_hb as hb;
pub use nlsim_kernel as kernel;
pub use nlsim_reduction as reduction;
pub use nlsim_sim as sim;
