//! The typed command layer: one folder or file per `nlsim` command, each with one request
//! type (validated by `check`), one run function returning a value, and one writer of what the
//! command shows and writes. The binary only parses arguments into requests and dispatches;
//! library callers (the C ABI, a Python package, other programs) call the same functions.
//!
//! | command | request | run | report |
//! |---|---|---|---|
//! | `check`, `export` | [`check`] | | |
//! | `modes` | [`modes`] | | |
//! | `simulate` | [`simulate::request`], [`crate::formats::excitation`] | [`simulate::run`] | [`simulate::report`] |
//! | `frf` | [`frf::request`], [`frf::start`] | [`frf::run`] | [`frf::report`] |
//! | `nnm` | [`nnm`] | | |
//! | `calibrate` | [`calibrate::request`] | [`calibrate::run`], [`calibrate::modal`] | [`calibrate::report`] |
//! | `plan` | [`plan::request`] | [`plan::run`] | [`plan::report`] |
//! | `test` | [`test::request`] | [`test::run`] | [`test::report`] |
//! | `validate` | [`validate::run`] | [`validate::run`] | [`validate::report`] |
//! | `demo` | [`demo`] | [`demo::stages`], [`demo::planning`] | |
//!
//! [`setup`] holds what several commands share to set up a run (model loading with `--set`,
//! Lanczos settings, shared reductions).
//!
//! Belongs here: turning a request into a result and a result into lines, files and reports.
//! Does not: argument parsing (the binary), file formats (`crate::formats`), drawing and
//! HTML (`crate::present`), numerics (the numeric crates). Dependencies point down: commands
//! use formats, present and the numeric crates, never the binary or `crate::batch`.

#[cfg(feature = "io")]
pub mod backbone;
#[cfg(feature = "io")]
pub mod calibrate;
#[cfg(feature = "io")]
pub mod check;
#[cfg(feature = "io")]
pub mod demo;
#[cfg(feature = "io")]
pub mod frf;
#[cfg(feature = "io")]
pub mod harmonics;
#[cfg(feature = "io")]
pub mod modal_export;
#[cfg(feature = "io")]
pub mod modes;
#[cfg(feature = "io")]
pub mod nnm;
pub mod plan;
#[cfg(feature = "io")]
pub mod records;
pub mod setup;
#[cfg(feature = "io")]
pub mod simulate;
pub mod test;
#[cfg(feature = "io")]
pub mod validate;
