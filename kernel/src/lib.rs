//! # nlsim-kernel
//!
//! The model layer of nlsim: a large linear finite-element structure
//! `M q̈ + V q̇ + K q + f_NL(q, q̇) = f(t)` (Chen 2016, eq. 4) with a handful of local nonlinear
//! elements. Everything else in nlsim builds on these types:
//!
//! - [`SparseSym`]: sparse symmetric mass/stiffness/damping matrices on faer, assembled from
//!   triplets;
//! - [`DofMap`] and [`DofLabel`]: human DOF labels such as `12:uz`;
//! - [`Damping`]: Rayleigh, modal (per mode or per band) or an explicit matrix;
//! - [`Law`] and [`NonlinearElement`]: the element library with force, state derivatives and
//!   parameter derivatives ([`iwan`]: Segalman's Iwan joint as parallel Jenkins sliders);
//! - [`Model`]: all of it together, with validation that names what is wrong and where;
//! - [`Param`] and [`Parameterized`]: one identity for every calibratable quantity, and
//!   [`Status`], the outcome of every iterative solver;
//! - [`Error`]: the one error type of the numeric crates (invalid input only).
//!
//! Units are SI throughout: m, kg, s, N, rad; frequencies in Hz where named `*_hz`, rad/s
//! otherwise.

pub mod adapters;
pub mod damping;
pub mod dof;
pub mod element;
pub mod error;
pub mod iwan;
pub mod linalg;
pub mod model;
pub mod names;
pub mod param;
pub mod site;
pub mod sparse;
#[cfg(any(test, feature = "test-util"))]
pub mod testing;

pub use adapters::Stored;
pub use damping::{Damping, DampingBand, ModalDamping};
pub use dof::{Component, DofLabel, DofMap};
pub use element::{Coupling, Law, LawEval, MonomialTerm, NonlinearElement, PolyTerm};
pub use error::{Error, Result};
pub use iwan::IwanGrid;
pub use model::{
    ElementGroup, Excitation, ForceHarmonic, MatrixDerivative, Model, ModelBuilder, Quantity,
    Sensor, ValidationConfig, ValidationReport,
};
pub use param::{Param, Parameterized, Status};
pub use site::{ResidualTerm, Site, TestMode};
pub use sparse::SparseSym;

/// faer, re-exported so that users of nlsim build matrices with the same version.
pub use faer;
/// The nalgebra-sparse crate the adapters take (feature `nalgebra-sparse`).
#[cfg(feature = "nalgebra-sparse")]
pub use nalgebra_sparse;
/// The sprs crate the adapters take (feature `sprs`).
#[cfg(feature = "sprs")]
pub use sprs;
