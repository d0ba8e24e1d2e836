//! Prediction of test data with a band, and its scores: the validation step of thesis §4.6
//! (papers IV and V) — a calibrated model predicts sweeps it was not trained on, and the
//! misfit is judged against what the parameter uncertainty and the measurement noise allow.
//!
//! The band is linearised: at every point, channel and compared harmonic the log-amplitude
//! `ln|Y|` and phase `arg Y` of the prediction have the parameter variances
//! `gᵀ Σ g` with `g = Re(∂Y/∂p / Y)` (log-amplitude) and `Im(∂Y/∂p / Y)` (phase) from the
//! analytic harmonic-balance sensitivities, and the measurement adds the data's noise model
//! (its amplitude and phase parts, as the log-magnitude residual weighs them). Both are
//! multiplied by a scale `s²` (the reduced χ² of the calibration when it exceeds 1: least
//! squares with the noise level estimated from the misfit). The band at level `α` is
//! `± z σ` with `z = Φ⁻¹((1 + α)/2)`.

use crate::data::{PointId, TestData};
use crate::objective::{FrfObjective, wrap};
use faer::{Mat, c64};
use nlsim_kernel::{Error, Result, Status};

/// `Φ⁻¹(p)`, the standard normal quantile, for `0 < p < 1` (Acklam's rational approximation,
/// relative error below 1.2e-9).
pub fn normal_quantile(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    let tail = |q: f64| {
        let q = (-2.0 * q.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.02425 {
        tail(p)
    } else if p > 1.0 - 0.02425 {
        -tail(1.0 - p)
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// The settings of a prediction.
#[derive(Debug, Clone, PartialEq)]
pub struct BandConfig {
    /// Two-sided coverage of the band, in (0, 1) (0.95: ±1.96σ).
    pub level: f64,
    /// Variance scale `s² > 0` applied to the parameter covariance and to the noise model
    /// (1: as given; the calibration's reduced χ² when the noise model understates the
    /// misfit).
    pub scale: f64,
}

impl Default for BandConfig {
    fn default() -> Self {
        Self {
            level: 0.95,
            scale: 1.0,
        }
    }
}

impl BandConfig {
    /// `z = Φ⁻¹((1 + level)/2)`; `Err` for a level outside (0, 1) or a scale that is not a
    /// finite non-negative number.
    pub fn z(&self) -> Result<f64> {
        if !(self.level > 0.0 && self.level < 1.0) {
            return Err(Error::invalid(
                "band level",
                format!("{} is not in (0, 1) (e.g. 0.95)", self.level),
            ));
        }
        if !(self.scale.is_finite() && self.scale > 0.0) {
            return Err(Error::invalid(
                "band scale",
                format!("{} is not a finite positive variance scale", self.scale),
            ));
        }
        Ok(normal_quantile(0.5 * (1.0 + self.level)))
    }
}

/// The prediction of one measured value (a channel's harmonic at one step) with its
/// standard deviations (already scaled by [`BandConfig::scale`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PredictedValue {
    /// The point.
    pub id: PointId,
    /// Channel index in the data.
    pub channel: usize,
    /// Harmonic `k` (1 = fundamental).
    pub harmonic: usize,
    /// Excitation frequency (Hz).
    pub frequency_hz: f64,
    /// Fundamental force amplitude `|F₁|` (N).
    pub force: f64,
    /// Measured complex harmonic (channel unit).
    pub measured: c64,
    /// Predicted complex harmonic (channel unit); NaN where the solve failed.
    pub predicted: c64,
    /// Standard deviation of `ln|Y|` from the parameters (1).
    pub sd_log_param: f64,
    /// Standard deviation of `arg Y` from the parameters (rad).
    pub sd_phase_param: f64,
    /// Standard deviation of the measured `ln|Y|` from the noise model (1).
    pub sd_log_noise: f64,
    /// Standard deviation of the measured `arg Y` from the noise model (rad).
    pub sd_phase_noise: f64,
}

impl PredictedValue {
    /// `ln|Y_pred| − ln|Y_meas|`.
    pub fn log_error(&self) -> f64 {
        self.predicted.norm().ln() - self.measured.norm().ln()
    }

    /// `arg Y_pred − arg Y_meas` wrapped to (−π, π] (rad).
    pub fn phase_error(&self) -> f64 {
        wrap(self.predicted.arg() - self.measured.arg())
    }

    /// Total standard deviation of the log-amplitude difference (parameters and noise).
    pub fn sd_log(&self) -> f64 {
        self.sd_log_param.hypot(self.sd_log_noise)
    }

    /// Total standard deviation of the phase difference (rad).
    pub fn sd_phase(&self) -> f64 {
        self.sd_phase_param.hypot(self.sd_phase_noise)
    }

    /// Whether the prediction was computed.
    pub fn is_predicted(&self) -> bool {
        self.predicted.re.is_finite() && self.predicted.im.is_finite()
    }
}

/// The scores of one sweep (over its channels and compared harmonics).
#[derive(Debug, Clone, PartialEq)]
pub struct SweepScore {
    /// The sweep's label.
    pub label: String,
    /// Measured values compared.
    pub values: usize,
    /// Values where the harmonic balance did not converge (left out of every score).
    pub failed: usize,
    /// Root-mean-square `ln|Y_pred| − ln|Y_meas|` (1).
    pub rms_log: f64,
    /// Root-mean-square phase error (rad).
    pub rms_phase: f64,
    /// Fraction of values whose measured amplitude lies in the band.
    pub inside_amplitude: f64,
    /// Fraction of values whose measured phase lies in the band.
    pub inside_phase: f64,
    /// `Σ (r/σ)² / n` over log-amplitude and phase residuals normalised by the data's noise
    /// model as given (no parameter term, no scale): about 1 when the model follows the data
    /// to their noise, comparable with the training's reduced χ².
    pub chi2: f64,
    /// The first channel's compared harmonic with the largest measured `|Y|/|F₁|`:
    /// `(frequency Hz, |Y|/|F₁|)`.
    pub peak_measured: (f64, f64),
    /// The same of the prediction, with the band of its amplitude from the parameters
    /// `(frequency Hz, |Y|/|F₁|, lower, upper)`.
    pub peak_predicted: (f64, f64, f64, f64),
}

/// A prediction of test data with its band and scores.
#[derive(Debug, Clone)]
pub struct Prediction {
    /// The band's settings.
    pub band: BandConfig,
    /// The band's half-width in standard deviations.
    pub z: f64,
    /// Harmonics compared.
    pub harmonics: Vec<usize>,
    /// Every measured value of every compared harmonic, in data order (sweep, step,
    /// channel, harmonic).
    pub values: Vec<PredictedValue>,
    /// One score per sweep, in data order.
    pub sweeps: Vec<SweepScore>,
}

/// Predicts `obj`'s test data at parameter values `values` (the objective's parameters, in
/// spec order) with parameter covariance `covariance` (parameter units squared; zero for a
/// prediction without parameter uncertainty) and scores every sweep.
///
/// `Err` for values or a covariance of the wrong size or not finite, or a band setting out
/// of range; points where the harmonic balance fails are predictions of NaN, counted in
/// [`SweepScore::failed`].
pub fn predict(
    obj: &mut FrfObjective,
    values: &[f64],
    covariance: &Mat<f64>,
    band: &BandConfig,
) -> Result<Prediction> {
    let z = band.z()?;
    let n = obj.specs().len();
    if covariance.nrows() != n || covariance.ncols() != n {
        return Err(Error::DimensionMismatch {
            what: "parameter covariance".into(),
            expected: n,
            found: covariance.nrows().max(covariance.ncols()),
        });
    }
    for i in 0..n {
        for j in 0..n {
            if !covariance[(i, j)].is_finite() {
                return Err(Error::invalid(
                    "parameter covariance",
                    format!("entry ({}, {}) is {}", i + 1, j + 1, covariance[(i, j)]),
                ));
            }
        }
    }
    let ev = obj.evaluate_with_sensitivities(values)?;
    let data: &TestData = obj.data();
    let harmonics = obj.config().harmonics.clone();
    let s = band.scale.sqrt();
    let mut out = Vec::new();
    for p in &ev.points {
        let sw = &data.sweeps[p.id.sweep];
        let st = &sw.steps[p.id.step];
        for (c, ch) in data.channels.iter().enumerate() {
            for &k in &harmonics {
                let yd = st.response[(c, k - 1)];
                if yd.re.is_nan() {
                    continue;
                }
                let (s_re, s_im) = st.sigma_parts(c, k, yd, &ch.noise);
                let (cos, sin) = (yd.re / yd.norm(), yd.im / yd.norm());
                let s_amp = (s_re * s_re * cos * cos + s_im * s_im * sin * sin).sqrt();
                let s_ph = (s_re * s_re * sin * sin + s_im * s_im * cos * cos).sqrt();
                let ym = p.response[(c, k - 1)];
                let (mut var_log, mut var_ph) = (0.0, 0.0);
                if p.status == Status::Converged && !p.sensitivity.is_empty() {
                    let g: Vec<c64> = p.sensitivity.iter().map(|d| d[(c, k - 1)] / ym).collect();
                    for i in 0..n {
                        for j in 0..n {
                            var_log += g[i].re * covariance[(i, j)] * g[j].re;
                            var_ph += g[i].im * covariance[(i, j)] * g[j].im;
                        }
                    }
                }
                out.push(PredictedValue {
                    id: p.id,
                    channel: c,
                    harmonic: k,
                    frequency_hz: st.frequency_hz,
                    force: st.force[0].norm(),
                    measured: yd,
                    predicted: ym,
                    sd_log_param: s * var_log.max(0.0).sqrt(),
                    sd_phase_param: s * var_ph.max(0.0).sqrt(),
                    sd_log_noise: s * s_amp / yd.norm(),
                    sd_phase_noise: s * s_ph / yd.norm(),
                });
            }
        }
    }
    let sweeps = data
        .sweeps
        .iter()
        .enumerate()
        .map(|(i, sw)| score(&sw.label, out.iter().filter(|v| v.id.sweep == i), z, s))
        .collect();
    Ok(Prediction {
        band: band.clone(),
        z,
        harmonics,
        values: out,
        sweeps,
    })
}

/// The scores of one sweep's values.
fn score<'a>(
    label: &str,
    values: impl Iterator<Item = &'a PredictedValue>,
    z: f64,
    s: f64,
) -> SweepScore {
    let (mut n, mut failed) = (0usize, 0usize);
    let (mut la, mut ph, mut chi) = (0.0, 0.0, 0.0);
    let (mut in_a, mut in_p) = (0usize, 0usize);
    let mut peak_m = (f64::NAN, f64::NEG_INFINITY);
    let mut peak_p = (f64::NAN, f64::NEG_INFINITY, f64::NAN, f64::NAN);
    let mut first: Option<(usize, usize)> = None;
    for v in values {
        let key = *first.get_or_insert((v.channel, v.harmonic));
        if key == (v.channel, v.harmonic) {
            let m = v.measured.norm() / v.force;
            if m > peak_m.1 {
                peak_m = (v.frequency_hz, m);
            }
        }
        if !v.is_predicted() {
            failed += 1;
            continue;
        }
        n += 1;
        let (ea, ep) = (v.log_error(), v.phase_error());
        la += ea * ea;
        ph += ep * ep;
        // Against the data's noise model as given (the band's scale undone).
        chi += (s * ea / v.sd_log_noise).powi(2) + (s * ep / v.sd_phase_noise).powi(2);
        in_a += usize::from(ea.abs() <= z * v.sd_log());
        in_p += usize::from(ep.abs() <= z * v.sd_phase());
        if key == (v.channel, v.harmonic) {
            let a = v.predicted.norm() / v.force;
            if a > peak_p.1 {
                let w = (z * v.sd_log_param).exp();
                peak_p = (v.frequency_hz, a, a / w, a * w);
            }
        }
    }
    let mean = |x: f64| if n == 0 { f64::NAN } else { x / n as f64 };
    if !peak_p.1.is_finite() {
        peak_p.1 = f64::NAN;
    }
    if !peak_m.1.is_finite() {
        peak_m.1 = f64::NAN;
    }
    SweepScore {
        label: label.to_string(),
        values: n + failed,
        failed,
        rms_log: mean(la).sqrt(),
        rms_phase: mean(ph).sqrt(),
        inside_amplitude: mean(in_a as f64),
        inside_phase: mean(in_p as f64),
        chi2: if n == 0 {
            f64::NAN
        } else {
            chi / (2 * n) as f64
        },
        peak_measured: peak_m,
        peak_predicted: peak_p,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_quantiles_match_tabulated_values() {
        // Φ⁻¹ at standard levels (to 16 digits, from the inverse error function).
        for (p, q) in [
            (0.975, 1.959_963_984_540_054),
            (0.995, 2.575_829_303_548_901),
            (0.841_344_746_068_542_9, 1.0),
            (0.5, 0.0),
            (0.001, -3.090_232_306_167_814),
        ] {
            assert!(
                (normal_quantile(p) - q).abs() < 5e-9 * q.abs().max(1.0),
                "Φ⁻¹({p}) = {} vs {q}",
                normal_quantile(p)
            );
        }
        assert!((normal_quantile(0.2) + normal_quantile(0.8)).abs() < 1e-12);
    }

    #[test]
    fn band_settings_are_checked() {
        assert!(
            BandConfig {
                level: 1.0,
                scale: 1.0
            }
            .z()
            .is_err()
        );
        assert!(
            BandConfig {
                level: 0.9,
                scale: f64::NAN
            }
            .z()
            .is_err()
        );
    }
}
