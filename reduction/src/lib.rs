//! # nlsim-reduction
//!
//! Turns a large sparse finite-element model into the small diagonal system that the time
//! integrator and harmonic balance work on (Chen 2016, §3.1 and eq. 10):
//!
//! - [`eigen`]: the lowest modes of `K φ = ω² M φ` by shift-invert block Lanczos with thick
//!   restarts on a sparse Cholesky factor of `K − σM` (symbolic analysis reused across parameter
//!   values), checked by residuals and a Sturm sequence count;
//! - [`factor`]: the shifted pencil `K − σM` with its reusable symbolic analysis;
//! - [`ordering`]: the fill-reducing orderings of that analysis (AMD, METIS nested dissection);
//! - [`modal`]: ports (elements, excitation, sensors), modal participation and the residual
//!   flexibility of the truncated modes at the ports (the feedthrough `D_L`, `D_NL` of eq. 10);
//! - [`parametric`]: the reduction at any values of FE-level parameters from one projected
//!   basis, certified against the full matrices and enriched by full reductions where needed;
//! - [`sensitivity`]: analytic eigenvalue and mode-shape derivatives with respect to FE-level
//!   parameters, on the eigen solve's factor (no refactorisation per parameter);
//! - [`state_space`]: the diagonal complex-modal state-space form ([`ModalSystem`]) and the
//!   receptances evaluated from it.
//!
//! Units are SI; eigenvalues `λ = ω²` in rad²/s², frequencies in Hz where named `*_hz`.

pub mod eigen;
pub mod factor;
pub mod modal;
pub mod ordering;
pub mod parametric;
mod products;
mod rayleigh;
pub mod sensitivity;
pub mod state_space;
mod trisolve;

pub use eigen::{
    EigenConfig, EigenMethod, EigenProgress, EigenSolver, EigenStats, ModeSelection, Modes,
    RIGID_RELATIVE, stiffness_scale,
};
pub use factor::{ShiftFactor, ShiftedPencil};
pub use modal::{
    EffectiveMass, ModelPortMap, Port, PortKind, ReducedModel, ReductionConfig, damping_ratios,
    effective_masses, model_port_map, model_ports, reduce, reduce_with,
};
pub use ordering::Ordering;
pub use parametric::{
    ParametricConfig, ParametricDerivatives, ParametricPoint, ParametricReduction, ParametricStats,
};
pub use sensitivity::{
    EigenSensitivities, ReducedSensitivities, SensitivityConfig, eigen_sensitivities,
    reduced_sensitivities,
};
pub use state_space::{ModalSystem, Response};
