//! nlsim frequency domain: multi-harmonic balance (thesis §3.2, §4.2, paper I).
//!
//! The periodic response at the base frequency `ω0 = Ω/ν` is written as
//! `q(t) = c_0 + Σ_{k=1..H} c_k cos kω0t + s_k sin kω0t` (thesis eq. 13), so that both the
//! sub-harmonics `Ω/ν` and the super-harmonics of `Ω` are represented (eq. 12).
//!
//! - [`HarmonicSet`], [`Forcing`]: the harmonics kept and the force on any subset of them.
//! - [`LinearPart`]: receptances `H(ω) = Φ_P (Ω² − ω² + iω C̃)⁻¹ Φ_Pᵀ + D` of the reduced
//!   model (modal sum + residual flexibility), with their derivatives.
//! - [`aft`]: alternating frequency–time evaluation of the element forces and their
//!   analytic Jacobians, with a sample count chosen per element law.
//! - [`HbSystem`]: the residual condensed on the nonlinear DOFs,
//!   `R(x) = x + H_NL,NL G(x) − H_NL,ext F` in `n_NL × (2H+1)` reals, Newton with step
//!   control, recovery of any sensor, multi-harmonic FRFs `H_ijν = Q_ν/F_ν` (eq. 14), the full
//!   formulation on the modal coordinates as a cross-check, and parameter sensitivities
//!   `dx/dp = −R_x⁻¹ R_p`.
//! - [`stability`]: Hill's method, the Floquet exponents taken as one representative per
//!   multiplier in the band `|Im s| ≤ ω0/2`; its small companion matrices are solved by a
//!   Francis QR of this crate, split into even and odd harmonics when the tangents have
//!   half-wave symmetry.
//! - [`mod@continuation`]: pseudo-arclength continuation through folds with fold and
//!   branch-point detection, stepped-sine sweeps up or down, force-level sweeps, branches
//!   followed from an inner point to both ends, peaks located between points.
//! - [`start`]: starts for isolated (sub-harmonic) branches from a single-mode backbone.
//! - [`nnm`]: nonlinear modes (backbones, amplitude-dependent frequency and damping) by the
//!   extended periodic motion concept.
//!
//! Units: SI (s, rad/s, N, m); frequencies given to users in Hz are named `_hz`.
//! Nothing here prints, reads files or exits.

pub mod aft;
pub mod continuation;
mod dense;
mod eigs;
pub mod harmonics;
pub mod linear;
pub mod nnm;
pub mod stability;
pub mod start;
pub mod system;

pub use continuation::{
    Bifurcation, BifurcationKind, Branch, BranchPoint, ContinuationConfig, ContinuationReport,
    ContinuationStats, Parameter, Peak, PointKind, SolutionPoint, continuation,
    continuation_through, continuation_with_progress, label_bifurcations, locate_peaks,
    stepped_sine, stepped_sine_with_progress,
};
pub use harmonics::{ForceTerm, Forcing, HarmonicSet};
pub use linear::{LinearPart, LinearVariation};
pub use stability::Stability;
pub use start::{SubharmonicStart, find_subharmonic, subharmonic_content};
pub use system::{
    HbConfig, HbSystem, HbSystemBuilder, HbWorkspace, InputCoupling, NewtonReport, Sensitivity,
    SensorSpec,
};
