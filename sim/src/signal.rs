//! Force signals `f(t)` (N) applied at the excitation points.

use faer::c64;
use nlsim_kernel::{Error, Result};
use std::f64::consts::PI;

/// One harmonic `Re{F e^{i r Ω t}}` of a multi-sine: `ratio` is `ν` for a super-harmonic
/// (`ν ≥ 1`, the fundamental is `ν = 1`) or `1/ν` for a sub-harmonic (thesis eq. 12).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Harmonic {
    /// Frequency as a multiple of the fundamental `Ω`.
    pub ratio: f64,
    /// Complex amplitude `F` (N): magnitude and phase.
    pub amplitude: c64,
}

/// A force signal of time (N).
#[derive(Debug, Clone, PartialEq)]
pub enum Signal {
    /// No force.
    Zero,
    /// `amplitude · sin(2π f t + phase)`.
    Sine {
        /// Amplitude (N).
        amplitude: f64,
        /// Frequency (Hz).
        freq_hz: f64,
        /// Phase (rad).
        phase: f64,
    },
    /// Thesis eq. (12): `Re{Σ F_ν e^{iνΩt} + Σ F_{1/ν} e^{iΩt/ν}}` with `Ω = 2π fundamental_hz`.
    MultiSine {
        /// Fundamental frequency `Ω/2π` (Hz).
        fundamental_hz: f64,
        /// The harmonics carrying force.
        harmonics: Vec<Harmonic>,
    },
    /// Swept sine `amplitude · sin(ψ(t))` from `f0_hz` at `t = 0` to `f1_hz` at `duration`,
    /// linear (`ψ̇/2π = f0 + (f1 − f0) t / D`) or exponential (`f0 (f1/f0)^{t/D}`) in frequency;
    /// zero after `duration`.
    Sweep {
        /// Amplitude (N).
        amplitude: f64,
        /// Start frequency (Hz).
        f0_hz: f64,
        /// End frequency (Hz).
        f1_hz: f64,
        /// Sweep duration (s).
        duration: f64,
        /// Exponential (logarithmic) instead of linear sweep rate.
        logarithmic: bool,
    },
    /// Samples `values[i]` at `t = i / rate_hz`, linearly interpolated, zero after the last.
    Sampled {
        /// Sample rate (Hz).
        rate_hz: f64,
        /// Samples (N).
        values: Vec<f64>,
    },
}

impl Signal {
    /// A sine of amplitude `amplitude` (N) at `freq_hz` starting at zero phase.
    pub fn sine(amplitude: f64, freq_hz: f64) -> Self {
        Signal::Sine {
            amplitude,
            freq_hz,
            phase: 0.0,
        }
    }

    /// This signal with every force multiplied by `s`.
    pub fn scaled(&self, s: f64) -> Self {
        match self {
            Signal::Zero => Signal::Zero,
            Signal::Sine {
                amplitude,
                freq_hz,
                phase,
            } => Signal::Sine {
                amplitude: amplitude * s,
                freq_hz: *freq_hz,
                phase: *phase,
            },
            Signal::MultiSine {
                fundamental_hz,
                harmonics,
            } => Signal::MultiSine {
                fundamental_hz: *fundamental_hz,
                harmonics: harmonics
                    .iter()
                    .map(|h| Harmonic {
                        ratio: h.ratio,
                        amplitude: h.amplitude * s,
                    })
                    .collect(),
            },
            Signal::Sweep {
                amplitude,
                f0_hz,
                f1_hz,
                duration,
                logarithmic,
            } => Signal::Sweep {
                amplitude: amplitude * s,
                f0_hz: *f0_hz,
                f1_hz: *f1_hz,
                duration: *duration,
                logarithmic: *logarithmic,
            },
            Signal::Sampled { rate_hz, values } => Signal::Sampled {
                rate_hz: *rate_hz,
                values: values.iter().map(|v| v * s).collect(),
            },
        }
    }

    /// Checks that every number is finite and every frequency, rate and duration positive.
    pub fn validate(&self, what: &str) -> Result<()> {
        let bad = |reason: String| Err(Error::invalid(what, reason));
        let finite = |name: &str, v: f64| -> Result<()> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(Error::NonFinite {
                    what: format!("{what}: {name}"),
                    location: "signal".into(),
                    value: v,
                })
            }
        };
        match self {
            Signal::Zero => Ok(()),
            Signal::Sine {
                amplitude,
                freq_hz,
                phase,
            } => {
                finite("amplitude", *amplitude)?;
                finite("phase", *phase)?;
                if !(*freq_hz >= 0.0 && freq_hz.is_finite()) {
                    return bad(format!("sine frequency {freq_hz} Hz must be ≥ 0"));
                }
                Ok(())
            }
            Signal::MultiSine {
                fundamental_hz,
                harmonics,
            } => {
                if !(*fundamental_hz > 0.0 && fundamental_hz.is_finite()) {
                    return bad(format!("fundamental {fundamental_hz} Hz must be > 0"));
                }
                for (i, h) in harmonics.iter().enumerate() {
                    if !(h.ratio > 0.0 && h.ratio.is_finite()) {
                        return bad(format!("harmonic {i}: ratio {} must be > 0", h.ratio));
                    }
                    finite(&format!("harmonic {i} amplitude (re)"), h.amplitude.re)?;
                    finite(&format!("harmonic {i} amplitude (im)"), h.amplitude.im)?;
                }
                Ok(())
            }
            Signal::Sweep {
                amplitude,
                f0_hz,
                f1_hz,
                duration,
                logarithmic,
            } => {
                finite("amplitude", *amplitude)?;
                if !(*f0_hz >= 0.0 && f0_hz.is_finite() && *f1_hz >= 0.0 && f1_hz.is_finite()) {
                    return bad(format!("sweep frequencies {f0_hz}, {f1_hz} Hz must be ≥ 0"));
                }
                if *logarithmic && (*f0_hz <= 0.0 || *f1_hz <= 0.0) {
                    return bad("a logarithmic sweep needs frequencies > 0".into());
                }
                if !(*duration > 0.0 && duration.is_finite()) {
                    return bad(format!("sweep duration {duration} s must be > 0"));
                }
                Ok(())
            }
            Signal::Sampled { rate_hz, values } => {
                if !(*rate_hz > 0.0 && rate_hz.is_finite()) {
                    return bad(format!("sample rate {rate_hz} Hz must be > 0"));
                }
                if let Some(i) = values.iter().position(|v| !v.is_finite()) {
                    return Err(Error::NonFinite {
                        what: format!("{what}: sampled force"),
                        location: format!("sample {i} (t = {} s)", i as f64 / rate_hz),
                        value: values[i],
                    });
                }
                Ok(())
            }
        }
    }

    /// The force at time `t` (s).
    pub fn eval(&self, t: f64) -> f64 {
        match self {
            Signal::Zero => 0.0,
            Signal::Sine {
                amplitude,
                freq_hz,
                phase,
            } => amplitude * (2.0 * PI * freq_hz * t + phase).sin(),
            Signal::MultiSine {
                fundamental_hz,
                harmonics,
            } => {
                let w = 2.0 * PI * fundamental_hz;
                harmonics
                    .iter()
                    .map(|h| {
                        let a = h.ratio * w * t;
                        h.amplitude.re * a.cos() - h.amplitude.im * a.sin()
                    })
                    .sum()
            }
            Signal::Sweep {
                amplitude,
                f0_hz,
                f1_hz,
                duration,
                logarithmic,
            } => {
                if t > *duration || t < 0.0 {
                    return 0.0;
                }
                let psi = if *logarithmic && (f1_hz - f0_hz).abs() > 1e-12 * f0_hz {
                    let k = (f1_hz / f0_hz).ln() / duration;
                    2.0 * PI * f0_hz * ((k * t).exp() - 1.0) / k
                } else {
                    2.0 * PI * (f0_hz * t + 0.5 * (f1_hz - f0_hz) * t * t / duration)
                };
                amplitude * psi.sin()
            }
            Signal::Sampled { rate_hz, values } => {
                let x = t * rate_hz;
                if x < 0.0 || values.is_empty() {
                    return 0.0;
                }
                let i = x.floor() as usize;
                if i + 1 >= values.len() {
                    return if i + 1 == values.len() && x == i as f64 {
                        values[i]
                    } else {
                        0.0
                    };
                }
                let s = x - i as f64;
                values[i] + s * (values[i + 1] - values[i])
            }
        }
    }

    /// Highest frequency in the signal (Hz); `None` for sampled data (its Nyquist frequency
    /// is the limit) and zero for [`Signal::Zero`].
    pub fn max_frequency_hz(&self) -> Option<f64> {
        match self {
            Signal::Zero => Some(0.0),
            Signal::Sine { freq_hz, .. } => Some(*freq_hz),
            Signal::MultiSine {
                fundamental_hz,
                harmonics,
            } => Some(harmonics.iter().fold(0.0, |a: f64, h| a.max(h.ratio)) * fundamental_hz),
            Signal::Sweep { f0_hz, f1_hz, .. } => Some(f0_hz.max(*f1_hz)),
            Signal::Sampled { .. } => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn multisine_matches_its_definition() {
        let s = Signal::MultiSine {
            fundamental_hz: 10.0,
            harmonics: vec![
                Harmonic {
                    ratio: 1.0,
                    amplitude: c64::new(2.0, -1.0),
                },
                Harmonic {
                    ratio: 1.0 / 3.0,
                    amplitude: c64::new(0.0, 0.5),
                },
            ],
        };
        for t in [0.0, 0.013, 0.41] {
            let w = 2.0 * PI * 10.0;
            let e1 = c64::new((w * t).cos(), (w * t).sin());
            let e3 = c64::new((w * t / 3.0).cos(), (w * t / 3.0).sin());
            let expect = (c64::new(2.0, -1.0) * e1 + c64::new(0.0, 0.5) * e3).re;
            assert!((s.eval(t) - expect).abs() < 1e-13);
        }
    }

    #[test]
    fn sweep_frequency_is_the_phase_rate() {
        for log in [false, true] {
            let s = Signal::Sweep {
                amplitude: 1.0,
                f0_hz: 5.0,
                f1_hz: 50.0,
                duration: 2.0,
                logarithmic: log,
            };
            // Instantaneous frequency at t = 1 from the zero crossings' spacing is awkward;
            // check the phase derivative through asin of nearby samples instead: compare with
            // a sine of the expected frequency over a very short window.
            let t = 1.0;
            let f = if log { 5.0 * 10f64.powf(0.5) } else { 27.5 };
            let h = 1e-7;
            let d = (s.eval(t + h) - s.eval(t - h)) / (2.0 * h);
            let (v, dv) = (s.eval(t), d / (2.0 * PI * f));
            assert!((v * v + dv * dv - 1.0).abs() < 1e-5, "log = {log}");
        }
    }

    #[test]
    fn sampled_interpolates_linearly() {
        let s = Signal::Sampled {
            rate_hz: 10.0,
            values: vec![0.0, 1.0, -1.0],
        };
        assert_eq!(s.eval(0.05), 0.5);
        assert!((s.eval(0.15) - 0.0).abs() < 1e-15);
        assert_eq!(s.eval(0.2), -1.0);
        assert_eq!(s.eval(0.25), 0.0);
        assert!(s.validate("x").is_ok());
        let bad = Signal::Sampled {
            rate_hz: 10.0,
            values: vec![0.0, f64::NAN],
        };
        assert!(
            bad.validate("x")
                .unwrap_err()
                .to_string()
                .contains("sample 1")
        );
    }
}
