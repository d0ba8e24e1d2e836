//! nlsim time domain (thesis §3.1, papers II and III).
//!
//! - [`hold`]: zero-, first- and Lagrange second-order hold discretisation of a diagonal mode
//!   and the closed-form bias errors of paper III.
//! - [`Simulator`]: the exponential hold integrator on the reduced model's diagonal
//!   state-space form, with the nonlinear element forces as implicit feedback on their ports
//!   and contact events located inside steps.
//! - [`run_batch`]: many load cases or parameter sets in parallel, bit-identical for any
//!   thread count.
//! - References: [`rk`] (Dormand–Prince RK45 with ODE45's error control, classic RK4) on the
//!   same diagonal system, and [`newmark`] (Newmark average acceleration and HHT-α with Newton)
//!   on the unreduced sparse model, the nonlinear tangent applied as a low-rank update of one
//!   factorised effective stiffness.
//!
//! Units: SI throughout (s, N, m). Nothing here prints, reads files or exits.

pub mod batch;
mod feedback;
pub mod foh;
pub mod history;
pub mod hold;
pub mod newmark;
pub mod plant;
pub mod rk;
pub mod signal;

pub use batch::run_batch;
pub use feedback::NewtonConfig;
pub use foh::{FohConfig, OutputSensitivities, Simulator};
pub use history::{
    ContactEvent, InitialState, LoadCase, RunStats, Series, TimeHistory,
    add_kinked_residual_accelerations,
};
pub use hold::{Hold, bias_error, reconstruction_gain, step_coefficients};
pub use newmark::{Newmark, NewmarkConfig};
pub use plant::{ElementPort, OutputSpec, Plant, PlantBuilder};
pub use rk::{Rk4Config, Rk45Config, auto_atol, rk4, rk4_with_progress, rk45, rk45_with_progress};
pub use signal::{Harmonic, Signal};
