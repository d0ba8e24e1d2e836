//! # nlsim-reduction
//!
//! Turns a large sparse finite-element model into the small diagonal system that the time
//! integrator and harmonic balance work on (Chen 2016, §3.1 and eq. 10):
//!
//! - [`eigen`]: the lowest modes of `K φ = ω² M φ` by shift-invert block Lanczos with thick
//!   restarts on a sparse Cholesky factor of `K − σM` (symbolic analysis reused across parameter
//!   values), checked by residuals and a Sturm sequence count;
//! - [`factor`]: the shifted pencil `K − σM` with its reusable symbolic analysis;
//!
//! Units are SI; eigenvalues `λ = ω²` in rad²/s², frequencies in Hz where named `*_hz`.

pub mod eigen;
pub mod factor;

pub use eigen::{EigenConfig, EigenMethod, EigenProgress, EigenSolver, EigenStats, ModeSelection, Modes};
pub use factor::{ShiftFactor, ShiftedPencil};
