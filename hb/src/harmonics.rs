//! Harmonic sets and multi-harmonic forcing (thesis eqs. 12–13).
//!
//! A coordinate's periodic motion is stored as `2H + 1` reals
//! `x = [c_0, c_1, s_1, …, c_H, s_H]`, `q(t) = c_0 + Σ c_k cos kω0t + s_k sin kω0t`, with
//! `ω0 = Ω/ν` the base frequency. The complex amplitude of harmonic `k` is
//! `Q_k = c_k − i s_k`, so that `q(t) = Re Σ_k Q_k e^{ikω0t}`; forces use the same phasor
//! convention.

pub use faer::c64;
use nlsim_kernel::{Error, Result};

/// The harmonics kept: `k ω0`, `k = 0..=H`, with base frequency `ω0 = Ω/ν`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct HarmonicSet {
    /// Highest harmonic index `H` of the base frequency.
    pub h: usize,
    /// Sub-harmonic order `ν ≥ 1`: the base frequency is `Ω/ν`, the fundamental `Ω` is
    /// harmonic `ν`.
    pub nu: usize,
}

impl HarmonicSet {
    /// `H` harmonics of `Ω/ν`. Errors when `H = 0`, `ν = 0` or `ν > H` (the fundamental
    /// would not be represented).
    pub fn new(h: usize, nu: usize) -> Result<Self> {
        if h == 0 || nu == 0 {
            return Err(Error::invalid(
                "harmonic set",
                format!("needs H ≥ 1 and ν ≥ 1 (got H = {h}, ν = {nu})"),
            ));
        }
        if nu > h {
            return Err(Error::invalid(
                "harmonic set",
                format!(
                    "the fundamental Ω is harmonic ν = {nu} of Ω/ν, above H = {h}; \
                     keep at least H = ν harmonics"
                ),
            ));
        }
        Ok(Self { h, nu })
    }

    /// Number of reals per coordinate, `2H + 1`.
    pub fn len(&self) -> usize {
        2 * self.h + 1
    }

    /// Never empty (`H ≥ 1`); present for the `len` convention.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Base frequency `ω0 = Ω/ν` (rad/s) of fundamental `omega` (rad/s).
    pub fn base(&self, omega: f64) -> f64 {
        omega / self.nu as f64
    }

    /// Complex amplitude of harmonic `k` from the real coefficients `x` of one coordinate.
    pub fn complex(&self, x: &[f64], k: usize) -> c64 {
        if k == 0 {
            c64::new(x[0], 0.0)
        } else {
            c64::new(x[2 * k - 1], -x[2 * k])
        }
    }

    /// Writes complex amplitude `z` of harmonic `k` into the real coefficients `x`
    /// (the imaginary part of `z` is ignored for `k = 0`).
    pub fn set_complex(&self, x: &mut [f64], k: usize, z: c64) {
        if k == 0 {
            x[0] = z.re;
        } else {
            x[2 * k - 1] = z.re;
            x[2 * k] = -z.im;
        }
    }
}

/// One forced harmonic of one input: `f(t) = Re(F e^{ikω0t})`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceTerm {
    /// Input index (into [`crate::HbSystem::inputs`]).
    pub input: usize,
    /// Harmonic index `k` of the base frequency `ω0 = Ω/ν` (the fundamental is `k = ν`).
    pub harmonic: usize,
    /// Complex amplitude `F` (N).
    pub amplitude: c64,
}

/// Forcing on any subset of inputs and harmonics (thesis eq. 12), scaled by a level `λ`
/// (1 by default; the parameter of force-level continuation).
#[derive(Debug, Clone, PartialEq)]
pub struct Forcing {
    /// The forced harmonics.
    pub terms: Vec<ForceTerm>,
}

impl Forcing {
    /// A single sine `F cos Ω t` on input `input`: harmonic `ν` of the set.
    pub fn fundamental(set: &HarmonicSet, input: usize, amplitude: f64) -> Self {
        Self {
            terms: vec![ForceTerm {
                input,
                harmonic: set.nu,
                amplitude: c64::new(amplitude, 0.0),
            }],
        }
    }

    /// The forcing of a model's excitation points (inputs in their order): each point's
    /// fundamental `amplitude · cos Ωt` and its further harmonics `a cos(rΩt + φ)` (thesis
    /// eq. 12). A ratio `r = p/q` is harmonic `k = p ν / q` of the base `Ω/ν`; an error names
    /// the point and order when `k` is not a whole number (a sub-harmonic force `Ω/q` needs
    /// a sub-harmonic order `ν` that `q` divides) or is above `H`.
    pub fn from_excitation(
        set: &HarmonicSet,
        excitation: &[nlsim_kernel::Excitation],
    ) -> Result<Self> {
        let mut terms = Vec::new();
        for (i, x) in excitation.iter().enumerate() {
            terms.push(ForceTerm {
                input: i,
                harmonic: set.nu,
                amplitude: c64::new(x.amplitude, 0.0),
            });
            for h in &x.harmonics {
                let (p, q) = (h.numerator as usize, h.denominator as usize);
                let at = || format!("excitation '{}', harmonic {}", x.name, h.ratio_text());
                if !(p * set.nu).is_multiple_of(q) {
                    return Err(Error::invalid(
                        at(),
                        format!(
                            "a force at {}Ω is not a harmonic of the base Ω/{}: the \
                             sub-harmonic order must be a multiple of {q}",
                            h.ratio_text(),
                            set.nu
                        ),
                    ));
                }
                let k = p * set.nu / q;
                if k > set.h {
                    return Err(Error::invalid(
                        at(),
                        format!(
                            "it is harmonic {k} of the base Ω/{}, above the H = {} kept: \
                             raise the harmonics to at least {k}",
                            set.nu, set.h
                        ),
                    ));
                }
                terms.push(ForceTerm {
                    input: i,
                    harmonic: k,
                    amplitude: h.complex(),
                });
            }
        }
        Ok(Self { terms })
    }

    /// Checks inputs, harmonics and amplitudes against `set` and `n_inputs`.
    pub fn validate(&self, set: &HarmonicSet, n_inputs: usize) -> Result<()> {
        if self.terms.is_empty() {
            return Err(Error::invalid("forcing", "no forced harmonic"));
        }
        for (i, t) in self.terms.iter().enumerate() {
            if t.input >= n_inputs {
                return Err(Error::invalid(
                    format!("forcing term {}", i + 1),
                    format!("input {} does not exist ({n_inputs} inputs)", t.input),
                ));
            }
            if t.harmonic > set.h {
                return Err(Error::invalid(
                    format!("forcing term {}", i + 1),
                    format!(
                        "harmonic {} is above the highest kept harmonic H = {}",
                        t.harmonic, set.h
                    ),
                ));
            }
            if !(t.amplitude.re.is_finite() && t.amplitude.im.is_finite()) {
                return Err(Error::NonFinite {
                    what: "force amplitude".into(),
                    location: format!("forcing term {}", i + 1),
                    value: t.amplitude.re + t.amplitude.im,
                });
            }
            if t.harmonic == 0 && t.amplitude.im != 0.0 {
                return Err(Error::invalid(
                    format!("forcing term {}", i + 1),
                    "a static (k = 0) force must be real",
                ));
            }
        }
        Ok(())
    }

    /// The complex force amplitude on `input` at harmonic `k`.
    pub fn amplitude(&self, input: usize, k: usize) -> c64 {
        self.terms
            .iter()
            .filter(|t| t.input == input && t.harmonic == k)
            .map(|t| t.amplitude)
            .sum()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn complex_layout_round_trips_and_matches_the_time_signal() {
        let set = HarmonicSet::new(3, 1).unwrap();
        let mut x = vec![0.0; set.len()];
        let z = c64::new(0.3, -0.7);
        set.set_complex(&mut x, 2, z);
        assert_eq!(set.complex(&x, 2), z);
        // q(t) = Re(Z e^{i2t}) = c cos 2t + s sin 2t
        let t = 0.37f64;
        let direct = (z * c64::new((2.0 * t).cos(), (2.0 * t).sin())).re;
        let coeff = x[3] * (2.0 * t).cos() + x[4] * (2.0 * t).sin();
        assert!((direct - coeff).abs() < 1e-15);
    }

    #[test]
    fn bad_sets_and_forcing_are_refused() {
        assert!(HarmonicSet::new(0, 1).is_err());
        assert!(HarmonicSet::new(2, 3).is_err());
        let set = HarmonicSet::new(3, 1).unwrap();
        let f = Forcing {
            terms: vec![ForceTerm {
                input: 0,
                harmonic: 5,
                amplitude: c64::new(1.0, 0.0),
            }],
        };
        assert!(
            f.validate(&set, 1)
                .unwrap_err()
                .to_string()
                .contains("H = 3")
        );
        assert!(
            Forcing::fundamental(&set, 1, 1.0)
                .validate(&set, 1)
                .is_err()
        );
    }
}
