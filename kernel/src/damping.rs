//! Viscous damping models of the underlying linear structure (the `V` of thesis eq. 2).

use crate::error::{Error, Result};
use crate::sparse::SparseSym;

/// How the damping matrix `V` of `M q'' + V q' + K q = f` is given.
#[derive(Debug, Clone)]
pub enum Damping {
    /// No viscous damping.
    None,
    /// Rayleigh damping `V = α M + β K`; `alpha` in 1/s, `beta` in s. Mode `r` then has
    /// `ζ_r = α / (2 ω_r) + β ω_r / 2`.
    Rayleigh {
        /// Mass-proportional coefficient α (1/s).
        alpha: f64,
        /// Stiffness-proportional coefficient β (s).
        beta: f64,
    },
    /// Modal damping: a viscous ratio `ζ_r` per mode, applied in modal coordinates.
    Modal(ModalDamping),
    /// An explicit sparse symmetric damping matrix (N s/m), e.g. discrete dampers.
    Matrix(SparseSym),
}

/// Per-mode damping ratios: an explicit list for the lowest modes, then frequency bands,
/// then a default.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalDamping {
    /// `ζ` of modes 1, 2, … in ascending frequency order (dimensionless).
    pub per_mode: Vec<f64>,
    /// Bands `[f_min, f_max)` in Hz with their `ζ`, for modes past `per_mode`.
    pub bands: Vec<DampingBand>,
    /// `ζ` of every other mode.
    pub default: f64,
}

/// A frequency band `[f_min_hz, f_max_hz)` whose modes share one damping ratio.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DampingBand {
    /// Lower band edge (Hz, inclusive).
    pub f_min_hz: f64,
    /// Upper band edge (Hz, exclusive).
    pub f_max_hz: f64,
    /// Damping ratio in the band (dimensionless).
    pub zeta: f64,
}

impl ModalDamping {
    /// The same ratio `zeta` for every mode.
    pub fn uniform(zeta: f64) -> Self {
        ModalDamping {
            per_mode: Vec::new(),
            bands: Vec::new(),
            default: zeta,
        }
    }

    /// `ζ` of mode `index` (0-based, ascending frequency) whose undamped frequency is `freq_hz`.
    pub fn zeta(&self, index: usize, freq_hz: f64) -> f64 {
        if let Some(&z) = self.per_mode.get(index) {
            return z;
        }
        self.bands
            .iter()
            .find(|b| freq_hz >= b.f_min_hz && freq_hz < b.f_max_hz)
            .map_or(self.default, |b| b.zeta)
    }

    fn validate(&self) -> Result<()> {
        let check = |name: String, z: f64| {
            if !(0.0..1.0).contains(&z) {
                Err(Error::InvalidParameter {
                    name,
                    value: z,
                    reason: "a modal damping ratio must lie in [0, 1)".into(),
                })
            } else {
                Ok(())
            }
        };
        for (i, &z) in self.per_mode.iter().enumerate() {
            check(format!("damping.zeta[mode {}]", i + 1), z)?;
        }
        for (i, b) in self.bands.iter().enumerate() {
            check(format!("damping.bands[{}].zeta", i + 1), b.zeta)?;
            if !(b.f_min_hz.is_finite()
                && b.f_max_hz.is_finite()
                && b.f_min_hz >= 0.0
                && b.f_max_hz > b.f_min_hz)
            {
                return Err(Error::InvalidParameter {
                    name: format!("damping.bands[{}]", i + 1),
                    value: b.f_min_hz,
                    reason: format!(
                        "band edges must be finite with 0 <= f_min < f_max (got [{}, {}) Hz)",
                        b.f_min_hz, b.f_max_hz
                    ),
                });
            }
        }
        check("damping.default".into(), self.default)
    }
}

impl Damping {
    /// Rayleigh coefficients that give ratio `zeta1` at `omega1` and `zeta2` at `omega2` (rad/s):
    /// solves `ζ_i = α/(2ω_i) + β ω_i/2`.
    pub fn rayleigh_from_two_modes(
        omega1: f64,
        zeta1: f64,
        omega2: f64,
        zeta2: f64,
    ) -> Result<Self> {
        if !(omega1 > 0.0 && omega2 > 0.0 && omega1 != omega2) {
            return Err(Error::invalid(
                "Rayleigh damping fit",
                format!(
                    "needs two distinct positive frequencies (got {omega1} and {omega2} rad/s)"
                ),
            ));
        }
        let det = omega2 / omega1 - omega1 / omega2;
        let alpha = 2.0 * (zeta1 * omega2 - zeta2 * omega1) / det;
        let beta = 2.0 * (zeta2 / omega1 - zeta1 / omega2) / det;
        Ok(Damping::Rayleigh { alpha, beta })
    }

    /// Checks coefficients and ratios for range and finiteness (matrix damping is checked by
    /// the model, which knows the DOF labels).
    pub fn validate(&self) -> Result<()> {
        match self {
            Damping::None | Damping::Matrix(_) => Ok(()),
            Damping::Rayleigh { alpha, beta } => {
                for (name, v) in [("damping.alpha", *alpha), ("damping.beta", *beta)] {
                    if !(v.is_finite() && v >= 0.0) {
                        return Err(Error::InvalidParameter {
                            name: name.into(),
                            value: v,
                            reason: "Rayleigh coefficients must be finite and non-negative".into(),
                        });
                    }
                }
                Ok(())
            }
            Damping::Modal(m) => m.validate(),
        }
    }

    /// A one-word description: `none`, `rayleigh`, `modal`, `matrix`.
    pub fn kind(&self) -> &'static str {
        match self {
            Damping::None => "none",
            Damping::Rayleigh { .. } => "rayleigh",
            Damping::Modal(_) => "modal",
            Damping::Matrix(_) => "matrix",
        }
    }
}
