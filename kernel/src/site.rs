//! Where a force acts and a sensor reads, and the parts of a test-based modal model.
//!
//! An FE model's forces and sensors sit on one DOF each. A test-based modal model (thesis §2.2,
//! eq. 9 with the modes taken from a test) has no physical DOFs: its coordinates are the modal
//! amplitudes `q_r`, and a measured point `p` moves as `u_p = Σ_r φ_pr q_r` with its row of
//! mode-shape entries. A [`Site`] is either.

use crate::dof::{DofLabel, DofMap};
use crate::element::Coupling;
use crate::error::{Error, Result};

/// A force's or sensor's location: one DOF, or a measured point of a test-based modal model.
#[derive(Debug, Clone, PartialEq)]
pub enum Site {
    /// DOF index of the model.
    Dof(usize),
    /// A point named like a DOF (`31:uz`) whose motion is a combination of the model's
    /// coordinates, `u = Σ wᵢ q_{dofᵢ}` (for a modal model: the point's mode-shape entries,
    /// m/√kg).
    Point {
        /// The point's label, as the test names it.
        label: DofLabel,
        /// Its motion in the model's coordinates.
        coupling: Coupling,
    },
}

impl Default for Site {
    fn default() -> Self {
        Site::Dof(0)
    }
}

impl Site {
    /// The site as a generalized coordinate: a force `f` here does the virtual work `f δu`
    /// with `u = Σ wᵢ q_{dofᵢ}`, and a sensor here reads `u`.
    pub fn coupling(&self) -> Coupling {
        match self {
            Site::Dof(d) => Coupling::single(*d),
            Site::Point { coupling, .. } => coupling.clone(),
        }
    }

    /// The DOF index, for a site on one DOF.
    pub fn dof(&self) -> Option<usize> {
        match self {
            Site::Dof(d) => Some(*d),
            Site::Point { .. } => None,
        }
    }

    /// The site's label: the DOF's (`dofs` must hold it) or the point's.
    pub fn label(&self, dofs: &DofMap) -> DofLabel {
        match self {
            Site::Dof(d) => dofs.label(*d),
            Site::Point { label, .. } => *label,
        }
    }

    /// The label as text, `#i` for a DOF index outside `dofs`.
    pub fn describe(&self, dofs: &DofMap) -> String {
        match self {
            Site::Dof(d) => dofs.describe(*d),
            Site::Point { label, .. } => label.to_string(),
        }
    }
}

/// One mode of a test-based modal model (see [`crate::Model::modal`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TestMode {
    /// Undamped natural frequency `f_r` (Hz, ≥ 0; 0 is a rigid-body or residual-mass mode).
    pub frequency_hz: f64,
    /// Modal damping ratio `ζ_r` in `[0, 1)`: `c̃_rr = 2 ζ_r ω_r`.
    pub zeta: f64,
}

impl TestMode {
    /// Checks mode `r` (0-based) of a modal model: finite, `f ≥ 0`, `0 ≤ ζ < 1`, and not below
    /// the `previous` mode (modes ascend, so that mode `r` of a file is `mode{r+1}` of every
    /// parameter and table).
    pub fn check(&self, r: usize, previous: Option<&TestMode>) -> Result<()> {
        let location = format!("mode {}", r + 1);
        for (what, v) in [
            ("frequency", self.frequency_hz),
            ("damping ratio", self.zeta),
        ] {
            if !v.is_finite() {
                return Err(Error::NonFinite {
                    what: what.into(),
                    location,
                    value: v,
                });
            }
        }
        if self.frequency_hz < 0.0 {
            return Err(Error::invalid(
                location,
                format!("frequency {} Hz is negative", self.frequency_hz),
            ));
        }
        if !(0.0..1.0).contains(&self.zeta) {
            return Err(Error::invalid(
                location,
                format!("damping ratio {} must lie in [0, 1)", self.zeta),
            ));
        }
        if let Some(p) = previous
            && self.frequency_hz < p.frequency_hz
        {
            return Err(Error::invalid(
                location,
                format!(
                    "{} Hz is below mode {}'s {} Hz: give the modes in ascending frequency \
                     (mode r of the file is mode r of every parameter)",
                    self.frequency_hz, r, p.frequency_hz
                ),
            ));
        }
        Ok(())
    }
}

/// Why a test-based modal model refuses FE-level parts (element groups, boundary springs).
pub const NO_FE_MATRICES: &str = "a test-based modal model has no FE matrices to scale or add \
                                  a spring to; calibrate its modes (modeN.f, modeN.zeta, \
                                  modeN.m) instead";

/// A measured residual flexibility between two ports of a test-based modal model, added to
/// the reduction's residual (`D_ab = D_ba += flexibility`, m/N): the static share of the modes
/// above the test's band (thesis eq. 10, measured instead of computed).
#[derive(Debug, Clone, PartialEq)]
pub struct ResidualTerm {
    /// Name of the first port (an element, excitation or sensor).
    pub a: String,
    /// Name of the second port (equal to `a` for a driving-point term).
    pub b: String,
    /// Flexibility (m/N).
    pub flexibility: f64,
}

impl ResidualTerm {
    /// A checked term: finite flexibility, non-negative on a driving point (a residual
    /// flexibility matrix is positive semi-definite, so its diagonal is ≥ 0).
    pub fn new(a: impl Into<String>, b: impl Into<String>, flexibility: f64) -> Result<Self> {
        let (a, b) = (a.into(), b.into());
        let location = format!("residual flexibility between '{a}' and '{b}'");
        if !flexibility.is_finite() {
            return Err(Error::NonFinite {
                what: "residual flexibility".into(),
                location,
                value: flexibility,
            });
        }
        if a == b && flexibility < 0.0 {
            return Err(Error::invalid(
                location,
                format!(
                    "{flexibility:e} m/N is negative: a driving-point residual flexibility is \
                     the static share of the modes above the band, ≥ 0"
                ),
            ));
        }
        Ok(ResidualTerm { a, b, flexibility })
    }
}
