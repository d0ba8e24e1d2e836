//! The one error type of the numeric crates.
//!
//! Every variant says what was wrong and where: which matrix entry (by DOF label), which
//! element parameter, which DOF. Outcomes of solvers that ran on valid input (a Newton that did
//! not converge, a continuation that stopped) are reported by status values in the crates that
//! own them, not by this type, except where the caller cannot go on without the result.

use thiserror::Error;

/// Result alias used across nlsim's numeric crates.
pub type Result<T, E = Error> = core::result::Result<T, E>;

/// Everything that can be wrong with the input of a numeric nlsim routine.
#[derive(Debug, Clone, PartialEq, Error)]
#[non_exhaustive]
pub enum Error {
    /// Two sizes that must agree do not.
    #[error("dimension mismatch in {what}: expected {expected}, found {found}")]
    DimensionMismatch {
        /// What was being checked, e.g. `"stiffness matrix rows"`.
        what: String,
        /// The size it must have.
        expected: usize,
        /// The size it has.
        found: usize,
    },

    /// A matrix entry addresses a row or column outside the matrix.
    #[error("{matrix}: entry ({row}, {col}) lies outside the {n}x{n} matrix (0-based indices)")]
    IndexOutOfRange {
        /// Matrix name.
        matrix: String,
        /// 0-based row.
        row: usize,
        /// 0-based column.
        col: usize,
        /// Matrix order.
        n: usize,
    },

    /// A value is NaN or infinite.
    #[error("{what} is not finite ({value}) at {location}")]
    NonFinite {
        /// What holds the value, e.g. `"stiffness matrix"`.
        what: String,
        /// Where: DOF labels of the entry, a parameter name, a step.
        location: String,
        /// The offending value.
        value: f64,
    },

    /// A matrix that must be symmetric is not, beyond the relative tolerance.
    #[error(
        "{matrix} is not symmetric: entry ({row}, {col}) = {a_ij:e} but ({col}, {row}) = {a_ji:e} \
         (relative difference {rel_diff:.3e} > tolerance {tolerance:.1e})"
    )]
    NotSymmetric {
        /// Matrix name.
        matrix: String,
        /// Row DOF label.
        row: String,
        /// Column DOF label.
        col: String,
        /// Entry (row, col).
        a_ij: f64,
        /// Entry (col, row).
        a_ji: f64,
        /// `|a_ij − a_ji| / max|A|`.
        rel_diff: f64,
        /// The tolerance in force.
        tolerance: f64,
    },

    /// The mass matrix has DOFs without mass (zero or negative diagonal).
    #[error(
        "mass matrix is not positive definite: {count} DOF(s) have no mass ({listed}); \
         remove them, give them mass, or condense them statically before reduction"
    )]
    MasslessDofs {
        /// How many DOFs have a non-positive diagonal mass.
        count: usize,
        /// Up to ten of their labels, comma separated.
        listed: String,
    },

    /// The mass matrix has DOFs with negative diagonal mass: what they are and how they sit
    /// in the pencil (e.g. an acoustic fluid block written with the opposite sign).
    #[error(
        "mass matrix is not positive definite: {count} DOF(s) have negative mass diagonals \
         ({listed}); {detail}"
    )]
    NegativeMassDofs {
        /// How many DOFs have a negative diagonal mass.
        count: usize,
        /// Up to ten of their labels, comma separated.
        listed: String,
        /// What was found about them and what to do.
        detail: String,
    },

    /// A matrix that must be positive (semi-)definite is not.
    #[error("{matrix} is not {required}: {detail}")]
    NotDefinite {
        /// Matrix name.
        matrix: String,
        /// `"positive definite"` or `"positive semi-definite"`.
        required: String,
        /// What the factorisation found.
        detail: String,
    },

    /// A DOF label does not parse.
    #[error("invalid DOF label '{label}': {reason}")]
    InvalidDofLabel {
        /// The text given.
        label: String,
        /// Why it does not parse.
        reason: String,
    },

    /// A DOF label parses but the model has no such DOF.
    #[error("unknown DOF '{label}': the model has no such DOF{hint}")]
    UnknownDof {
        /// The label asked for.
        label: String,
        /// A hint such as the nodes that do exist.
        hint: String,
    },

    /// The same DOF label was given twice.
    #[error("DOF '{label}' is defined twice (positions {first} and {second})")]
    DuplicateDof {
        /// The repeated label.
        label: String,
        /// First 0-based position.
        first: usize,
        /// Second 0-based position.
        second: usize,
    },

    /// A DOF index is outside the model.
    #[error("{what} refers to DOF index {index}, but the model has {n} DOFs")]
    DofIndexOutOfRange {
        /// What refers to it.
        what: String,
        /// The index.
        index: usize,
        /// Number of DOFs.
        n: usize,
    },

    /// A parameter value is out of its admissible range.
    #[error("parameter '{name}' = {value:e} is out of range: {reason}")]
    InvalidParameter {
        /// Full parameter name, e.g. `tip_spring.k3`.
        name: String,
        /// The value given.
        value: f64,
        /// The admissible range and why.
        reason: String,
    },

    /// A parameter name that no element or damping model has.
    #[error("unknown parameter '{name}'; known parameters: {known}")]
    UnknownParameter {
        /// The name asked for.
        name: String,
        /// The names that exist, comma separated.
        known: String,
    },

    /// Two things that must have distinct names do not.
    #[error("duplicate {what} name '{name}'")]
    DuplicateName {
        /// What kind of thing, e.g. `"element"`.
        what: String,
        /// The repeated name.
        name: String,
    },

    /// Any other malformed input, with what and why.
    #[error("invalid {what}: {reason}")]
    InvalidInput {
        /// What was malformed.
        what: String,
        /// Why.
        reason: String,
    },

    /// A numerical factorisation or decomposition failed on input that passed validation.
    #[error("{what} failed: {detail}")]
    Numerical {
        /// The operation.
        what: String,
        /// What went wrong.
        detail: String,
    },
}

impl Error {
    /// Shorthand for [`Error::InvalidInput`].
    pub fn invalid(what: impl Into<String>, reason: impl Into<String>) -> Self {
        Error::InvalidInput {
            what: what.into(),
            reason: reason.into(),
        }
    }
}
