//! Backbone and damping of one mode from a free decay.
//!
//! 1. The mode's frequency `f₀` is given or taken as the largest peak of the record's
//!    spectrum; a zero-phase Butterworth band pass `f₀(1 ± b)` isolates it
//!    ([`BandPass`]), and twice the settling length of its and the demodulation's filters
//!    ([`BandPass::settle_samples`]) is trimmed at both ends and after the start of the
//!    decay (the envelope's largest value, or a given time).
//! 2. The analytic signal `z = y + i H[y]` of the filtered record (by complex demodulation
//!    at `f₀`, [`super::signal::analytic_signal`]) gives the envelope
//!    `A = |z|` and the unwrapped phase `φ = arg z`. On windows of `W` periods (hop `W/2`
//!    by default):
//!    - **Hilbert**: straight lines through `ln A(t)` and `φ(t)`: their slopes are `−σ` and
//!      `ω_d`, the intercept at the window's centre its amplitude;
//!    - **fit**: `y(τ) ≈ e^{−στ}(a cos θ + b sin θ)`, `θ = ω_d τ + βτ²/2`, `τ` from the
//!      window's centre, by Gauss–Newton from the Hilbert values; amplitude `√(a² + b²)`;
//!      the chirp `β` follows the frequency as it moves with the amplitude.
//!
//!    Either gives `ω_n = √(ω_d² + σ²)` and `ζ = σ/ω_n` ([`super::BackbonePoint`]); the
//!    amplitude is divided by the filter's gain `G = |H(f)|²` at the mode, and the decay
//!    rate gets back the part the gain took as the frequency moved (`σ += d ln G/df ·
//!    df/dt`, `df/dt` through five neighbouring windows).
//! 3. Standard deviations: the regressions' and the fit's covariance from their residuals,
//!    each residual variance at least the record's noise (step 4; a window's own residual
//!    has only a few independent samples).
//!    The residual of a filtered record is band-limited noise, correlated over `f_s/2B`
//!    samples (`B` the filter's noise bandwidth): its variance per independent sample is
//!    scaled by `f_s/2B` for the real fit, `f_s/B` for the envelope and phase (a complex
//!    baseband signal of bandwidth `B`) — the factor that makes the covariance of a fit on a
//!    filtered record that of the fit on white noise in the band.
//! 4. The noise floor: the in-band noise's standard deviation is the rms residual of the
//!    fit over the quarter of the windows at the smallest amplitudes; windows whose amplitude
//!    is below `min_snr` times it are dropped (the Hilbert envelope is biased up by noise
//!    there).
//!
//! Checks (returned as text): an envelope that rises between windows by more than three
//! deviations (beating: a second mode in the band, or not a free decay), a fit whose residual
//! is more than three times the noise and 1 % of the amplitude (harmonics or a second mode
//! in the band), damping
//! ratios above 0.1 (the single-mode, lightly damped reading no longer holds).

use super::signal::{BandPass, analytic_signal, demodulation_filter, spectral_peak};
use super::{BackbonePoint, inverse_small, natural, propagate, solve_small};
use nlsim_kernel::{Error, Result};
use std::f64::consts::PI;

/// Most samples of one free decay (2·10⁸: 1.6 GB as doubles, with the filtered copy and
/// the analytic signal about 6 GB).
pub const MAX_DECAY_SAMPLES: usize = 200_000_000;

/// Settings of [`identify_decay`].
#[derive(Debug, Clone, PartialEq)]
pub struct DecayConfig {
    /// The mode's frequency (Hz) the band is centred on; `None`: the largest peak of the
    /// record's spectrum.
    pub frequency_hz: Option<f64>,
    /// Relative half-width `b` of the pass band `f₀(1 ± b)` (default 0.3; from 0.01 to 0.9).
    pub band: f64,
    /// Order of each band edge, one pass (2 or 4; default 4).
    pub filter_order: usize,
    /// Window length in periods of `f₀` (default 8; at least 2).
    pub window_periods: f64,
    /// Hop between windows in periods (default 4).
    pub step_periods: f64,
    /// Smallest amplitude kept, as a multiple of the in-band noise's standard deviation
    /// (default 10).
    pub min_snr: f64,
    /// Where the decay starts (s from the first sample); `None`: at the envelope's largest
    /// value.
    pub start_s: Option<f64>,
}

impl Default for DecayConfig {
    fn default() -> Self {
        DecayConfig {
            frequency_hz: None,
            band: 0.3,
            filter_order: 4,
            window_periods: 8.0,
            step_periods: 4.0,
            min_snr: 10.0,
            start_s: None,
        }
    }
}

/// The identification of one free decay ([`identify_decay`]).
#[derive(Debug, Clone)]
pub struct Decay {
    /// The frequency the band is centred on (Hz): given, or the spectrum's peak.
    pub centre_hz: f64,
    /// The band pass used.
    pub filter: BandPass,
    /// First and one-past-last sample analysed (after the start and the trims).
    pub samples: (usize, usize),
    /// Standard deviation of the in-band noise of the filtered record (the signal's unit).
    pub noise: f64,
    /// Amplitudes below this were dropped (`min_snr · noise`).
    pub floor: f64,
    /// The backbone by the Hilbert transform, in time order.
    pub hilbert: Vec<BackbonePoint>,
    /// The backbone by the windowed fit, in time order.
    pub fit: Vec<BackbonePoint>,
    /// Windows dropped below the noise floor.
    pub below_floor: usize,
    /// Where the data break the method's assumptions (empty when nothing was found).
    pub checks: Vec<String>,
}

/// One window's estimates and covariance in `(A, σ, ω_d)`.
struct WindowEstimate {
    centre: usize,
    amplitude: f64,
    sigma: f64,
    omega_d: f64,
    /// Covariance of `(A, σ, ω_d)`.
    cov: [[f64; 3]; 3],
    /// Residual standard deviation of the fit (filtered unit); NaN for the Hilbert lines.
    residual: f64,
    /// The residual variances behind `cov`: the fit's (twice), or those of `ln A` and `φ`.
    var: [f64; 2],
}

impl WindowEstimate {
    /// Scales the covariance so that no residual variance behind it is below the record's
    /// in-band noise `noise` (a window's own residual has only a few independent samples:
    /// alone it would make intervals too narrow as often as too wide).
    fn at_least_noise(&mut self, noise: f64) {
        let n2 = noise * noise;
        if self.residual.is_finite() {
            let f = (n2 / self.var[0]).max(1.0);
            self.cov.iter_mut().flatten().for_each(|v| *v *= f);
        } else {
            let a2 = self.amplitude * self.amplitude;
            let fa = (n2 / (a2 * self.var[0])).max(1.0);
            let fp = (n2 / (a2 * self.var[1])).max(1.0);
            self.cov[0][0] *= fa;
            self.cov[1][1] *= fa;
            self.cov[2][2] *= fp;
        }
    }
}

fn point(e: &WindowEstimate, rate_hz: f64, gain: f64) -> BackbonePoint {
    let ((f, gf), (z, gz)) = natural(e.sigma, e.omega_d);
    let c: Vec<Vec<f64>> = e.cov.iter().map(|r| r.to_vec()).collect();
    BackbonePoint {
        time_s: e.centre as f64 / rate_hz,
        level: String::new(),
        amplitude: e.amplitude / gain,
        amplitude_sigma: c[0][0].max(0.0).sqrt() / gain,
        frequency_hz: f,
        frequency_sigma_hz: propagate(&[0.0, gf[0], gf[1]], &c).sqrt(),
        damping_ratio: z,
        damping_sigma: propagate(&[0.0, gz[0], gz[1]], &c).sqrt(),
        force: f64::NAN,
    }
}

/// Least-squares line `y ≈ c₀ + c₁ τ` with `τ` centred: `(c₀, c₁, residual variance)`.
fn line(tau: &[f64], y: &[f64]) -> (f64, f64, f64) {
    let n = tau.len() as f64;
    let ty = tau.iter().zip(y).map(|(t, v)| t * v).sum::<f64>();
    let tt = tau.iter().map(|t| t * t).sum::<f64>();
    let c0 = y.iter().sum::<f64>() / n;
    let c1 = ty / tt;
    let rss: f64 = tau
        .iter()
        .zip(y)
        .map(|(t, v)| (v - c0 - c1 * t).powi(2))
        .sum();
    (c0, c1, rss / (n - 2.0))
}

/// The Hilbert estimates on samples `lo..hi` of the envelope and phase; `kappa` the
/// correlation length of their noise in samples.
fn hilbert_window(
    env: &[f64],
    phase: &[f64],
    lo: usize,
    hi: usize,
    rate_hz: f64,
    kappa: f64,
) -> WindowEstimate {
    let c = (lo + hi - 1) as f64 / 2.0;
    let tau: Vec<f64> = (lo..hi).map(|i| (i as f64 - c) / rate_hz).collect();
    let la: Vec<f64> = env[lo..hi].iter().map(|a| a.max(1e-300).ln()).collect();
    let (a0, a1, va) = line(&tau, &la);
    let (_, p1, vp) = line(&tau, &phase[lo..hi]);
    let tt: f64 = tau.iter().map(|t| t * t).sum();
    let n = tau.len() as f64;
    let amp = a0.exp();
    let mut cov = [[0.0; 3]; 3];
    cov[0][0] = amp * amp * kappa * va / n;
    cov[1][1] = kappa * va / tt;
    cov[2][2] = kappa * vp / tt;
    WindowEstimate {
        centre: (lo + hi) / 2,
        amplitude: amp,
        sigma: -a1,
        omega_d: p1,
        cov,
        residual: f64::NAN,
        var: [va, vp],
    }
}

/// The decaying-sinusoid fit on samples `lo..hi` of `y` from the Hilbert estimate `h` and
/// the phase `phi_c` at the window's centre; `kappa` the noise's correlation length in
/// samples. `None` when Gauss–Newton meets a singular matrix.
fn fit_window(
    y: &[f64],
    lo: usize,
    hi: usize,
    rate_hz: f64,
    h: &WindowEstimate,
    phi_c: f64,
    kappa: f64,
) -> Option<WindowEstimate> {
    let c = (lo + hi - 1) as f64 / 2.0;
    let tau: Vec<f64> = (lo..hi).map(|i| (i as f64 - c) / rate_hz).collect();
    let ys = &y[lo..hi];
    // p = (a, b, σ, ω, β): y = e^{−στ}(a cos θ + b sin θ), θ = ωτ + βτ²/2 — the chirp β
    // (rad/s²) of a mode whose frequency moves with the decaying amplitude; without it the
    // fit's decay rate would take a share of the chirp that depends on the window's phase.
    let mut p = [
        h.amplitude * phi_c.cos(),
        -h.amplitude * phi_c.sin(),
        h.sigma,
        h.omega_d,
        0.0,
    ];
    let eval = |p: &[f64; 5], jac: bool| -> (f64, [[f64; 5]; 5], [f64; 5]) {
        let mut jtj = [[0.0; 5]; 5];
        let mut jtr = [0.0; 5];
        let mut rss = 0.0;
        for (t, v) in tau.iter().zip(ys) {
            let e = (-p[2] * t).exp();
            let (s, co) = (p[3] * t + 0.5 * p[4] * t * t).sin_cos();
            let m = e * (p[0] * co + p[1] * s);
            let r = v - m;
            rss += r * r;
            if jac {
                let dth = e * (-p[0] * s + p[1] * co);
                let g = [e * co, e * s, -t * m, t * dth, 0.5 * t * t * dth];
                for i in 0..5 {
                    jtr[i] += g[i] * r;
                    for j in 0..5 {
                        jtj[i][j] += g[i] * g[j];
                    }
                }
            }
        }
        (rss, jtj, jtr)
    };
    let (mut rss, mut jtj, mut jtr) = eval(&p, true);
    for _ in 0..30 {
        let a: Vec<Vec<f64>> = jtj.iter().map(|r| r.to_vec()).collect();
        let d = solve_small(&a, &jtr)?;
        let mut beta = 1.0;
        let mut moved = false;
        while beta > 1e-4 {
            let trial = [
                p[0] + beta * d[0],
                p[1] + beta * d[1],
                p[2] + beta * d[2],
                p[3] + beta * d[3],
                p[4] + beta * d[4],
            ];
            let (r2, _, _) = eval(&trial, false);
            if r2 <= rss {
                p = trial;
                moved = true;
                break;
            }
            beta *= 0.5;
        }
        let small = d[3].abs() <= 1e-12 * p[3].abs() && d[2].abs() <= 1e-12 * p[3].abs();
        (rss, jtj, jtr) = eval(&p, true);
        if !moved || small {
            break;
        }
    }
    let n = tau.len() as f64;
    let s2 = rss / (n - 5.0);
    let a: Vec<Vec<f64>> = jtj.iter().map(|r| r.to_vec()).collect();
    let inv = inverse_small(&a)?;
    let cp: Vec<Vec<f64>> = inv
        .iter()
        .map(|r| r.iter().map(|v| v * s2 * kappa).collect())
        .collect();
    let amp = (p[0] * p[0] + p[1] * p[1]).sqrt();
    // (A, σ, ω) from (a, b, σ, ω, β).
    let g = [
        [p[0] / amp, p[1] / amp, 0.0, 0.0, 0.0],
        [0.0, 0.0, 1.0, 0.0, 0.0],
        [0.0, 0.0, 0.0, 1.0, 0.0],
    ];
    let mut cov = [[0.0; 3]; 3];
    for i in 0..3 {
        for j in 0..3 {
            let mut v = 0.0;
            for k in 0..5 {
                for l in 0..5 {
                    v += g[i][k] * cp[k][l] * g[j][l];
                }
            }
            cov[i][j] = v;
        }
    }
    Some(WindowEstimate {
        centre: (lo + hi) / 2,
        amplitude: amp,
        sigma: p[2],
        omega_d: p[3],
        cov,
        residual: s2.sqrt(),
        var: [s2, s2],
    })
}

/// Identifies the backbone and damping of one mode from the free decay `x` sampled at
/// `rate_hz` (module docs). `Err` for invalid input: a rate or sample that is not finite,
/// settings out of range, a band past the Nyquist frequency, or a record too short for two
/// windows after the trims.
pub fn identify_decay(x: &[f64], rate_hz: f64, config: &DecayConfig) -> Result<Decay> {
    let what = "free decay";
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(Error::invalid(
            what,
            format!("sampling rate {rate_hz} Hz must be positive"),
        ));
    }
    if x.len() > MAX_DECAY_SAMPLES {
        return Err(Error::invalid(
            what,
            format!(
                "{} samples, more than {MAX_DECAY_SAMPLES}: cut the record to the decay",
                x.len()
            ),
        ));
    }
    if let Some(i) = x.iter().position(|v| !v.is_finite()) {
        return Err(Error::NonFinite {
            what: what.into(),
            location: format!("sample {}", i + 1),
            value: x[i],
        });
    }
    let c = config;
    if !(0.01..=0.9).contains(&c.band) {
        return Err(Error::invalid(
            what,
            format!(
                "band {} must be from 0.01 to 0.9 (relative half-width)",
                c.band
            ),
        ));
    }
    if c.filter_order != 2 && c.filter_order != 4 {
        return Err(Error::invalid(
            what,
            format!("filter order {} must be 2 or 4", c.filter_order),
        ));
    }
    if !(c.window_periods.is_finite() && c.window_periods >= 2.0) {
        return Err(Error::invalid(
            what,
            format!("window of {} periods: needs at least 2", c.window_periods),
        ));
    }
    if !(c.step_periods.is_finite() && c.step_periods > 0.0) {
        return Err(Error::invalid(
            what,
            format!("step of {} periods must be positive", c.step_periods),
        ));
    }
    if !(c.min_snr.is_finite() && c.min_snr >= 0.0) {
        return Err(Error::invalid(
            what,
            format!("min_snr {} must be non-negative", c.min_snr),
        ));
    }
    let nyquist = rate_hz / 2.0;
    let n = x.len();
    let centre = match c.frequency_hz {
        Some(f) => {
            if !(f.is_finite() && f > 0.0 && f < nyquist) {
                return Err(Error::invalid(
                    what,
                    format!("mode frequency {f} Hz must be within 0 and Nyquist ({nyquist} Hz)"),
                ));
            }
            f
        }
        None => {
            let lo = 4.0 * rate_hz / n.max(1) as f64;
            spectral_peak(x, rate_hz, lo, 0.45 * rate_hz).ok_or_else(|| {
                Error::invalid(what, "the record has no spectral peak (constant?)")
            })?
        }
    };
    let (lo_hz, hi_hz) = (centre * (1.0 - c.band), centre * (1.0 + c.band));
    if hi_hz >= 0.98 * nyquist {
        return Err(Error::invalid(
            what,
            format!(
                "band {lo_hz:.4}–{hi_hz:.4} Hz reaches the Nyquist frequency {nyquist} Hz: \
                 narrow it or sample faster"
            ),
        ));
    }
    let filter = BandPass::new(lo_hz, hi_hz, rate_hz, c.filter_order);
    let window = (c.window_periods * rate_hz / centre).round() as usize;
    let hop = ((c.step_periods * rate_hz / centre).round() as usize).max(1);
    // Twice the longer of the band pass's and the demodulating low pass's settling lengths
    // (a transient falls to 10⁻³ in one, to 10⁻⁶ in two).
    let settle = 2 * filter
        .settle_samples
        .max(demodulation_filter(rate_hz, centre, c.band).settle_samples);
    if window < 8 || n < window + 3 * settle {
        return Err(Error::invalid(
            what,
            format!(
                "{n} samples: too short for a window of {} periods ({window} samples) after \
                 trimming {settle} samples of the filter's transient at the start, the end \
                 and after the decay's start",
                c.window_periods
            ),
        ));
    }
    let y = filter.filtfilt(x);
    let z = analytic_signal(&y, rate_hz, centre, c.band);
    let env: Vec<f64> = z.iter().map(|v| v.norm()).collect();
    let mut phase: Vec<f64> = z.iter().map(|v| v.arg()).collect();
    for i in 1..n {
        let d = phase[i] - phase[i - 1];
        phase[i] = phase[i - 1] + d - 2.0 * PI * (d / (2.0 * PI)).round();
    }
    let start = match c.start_s {
        Some(t) => {
            if !(t.is_finite() && t >= 0.0 && t * rate_hz < n as f64) {
                return Err(Error::invalid(
                    what,
                    format!(
                        "start {t} s is not within the record (0 to {} s)",
                        n as f64 / rate_hz
                    ),
                ));
            }
            (t * rate_hz).round() as usize
        }
        None => (settle..n - settle)
            .max_by(|&a, &b| env[a].total_cmp(&env[b]))
            .unwrap_or(0),
    };
    let first = start.max(settle) + settle;
    let last = n - settle;
    if last < first + window {
        return Err(Error::invalid(
            what,
            format!(
                "the decay from sample {} leaves {} samples after the filter's transients \
                 ({settle} at each end), fewer than one window ({window})",
                start + 1,
                last.saturating_sub(first)
            ),
        ));
    }
    let kappa_fit = (rate_hz / (2.0 * filter.noise_bandwidth_hz)).max(1.0);
    let kappa_env = (rate_hz / filter.noise_bandwidth_hz).max(1.0);
    let mut hil = Vec::new();
    let mut fits = Vec::new();
    let mut lo = first;
    while lo + window <= last {
        let h = hilbert_window(&env, &phase, lo, lo + window, rate_hz, kappa_env);
        let mid = lo + window / 2;
        // The phase at the fit's centre τ = 0 (between samples for an even window).
        let phi_c = if window.is_multiple_of(2) {
            0.5 * (phase[mid - 1] + phase[mid])
        } else {
            phase[mid]
        };
        if let Some(f) = fit_window(&y, lo, lo + window, rate_hz, &h, phi_c, kappa_fit) {
            fits.push(f);
            hil.push(h);
        }
        lo += hop;
    }
    // The noise: the rms residual of the quarter of the windows at the smallest amplitudes
    // (where a decaying sinusoid fits best: the nonlinearity fades with the amplitude).
    let mut by_amp: Vec<(f64, f64)> = fits.iter().map(|f| (f.amplitude, f.residual)).collect();
    by_amp.sort_by(|a, b| a.0.total_cmp(&b.0));
    let quarter = by_amp.len().div_ceil(4);
    let noise = if quarter == 0 {
        0.0
    } else {
        (by_amp[..quarter].iter().map(|v| v.1 * v.1).sum::<f64>() / quarter as f64).sqrt()
    };
    hil.iter_mut().for_each(|h| h.at_least_noise(noise));
    fits.iter_mut().for_each(|f| f.at_least_noise(noise));
    let floor = c.min_snr * noise;
    let mut checks = Vec::new();
    let mut below = 0;
    let mut hilbert = Vec::new();
    let mut fit = Vec::new();
    let mut poor = Vec::new();
    // The band pass's gain changes with the frequency, and a nonlinear mode's frequency
    // changes as it decays: the envelope read through the filter decays at `σ − d ln G/dt`.
    // Each window's `σ` gets `d ln G/df · df/dt` back, `df/dt` from a line through the
    // frequencies of the window and its two neighbours each side.
    let times: Vec<f64> = fits.iter().map(|f| f.centre as f64 / rate_hz).collect();
    let freqs: Vec<f64> = fits.iter().map(|f| f.omega_d / (2.0 * PI)).collect();
    for i in 0..fits.len() {
        let (a, b) = (i.saturating_sub(2), (i + 3).min(fits.len()));
        if b - a < 2 {
            break;
        }
        let tm = times[a..b].iter().sum::<f64>() / (b - a) as f64;
        let fm = freqs[a..b].iter().sum::<f64>() / (b - a) as f64;
        let (num, den) = (a..b).fold((0.0, 0.0), |(n, d), k| {
            (
                n + (times[k] - tm) * (freqs[k] - fm),
                d + (times[k] - tm).powi(2),
            )
        });
        let dfdt = num / den;
        let f = freqs[i];
        let df = 1e-4 * f;
        let dlng = (filter.gain(f + df).max(1e-300).ln() - filter.gain(f - df).max(1e-300).ln())
            / (2.0 * df);
        fits[i].sigma += dlng * dfdt;
        hil[i].sigma += dlng * dfdt;
    }
    for (h, f) in hil.iter().zip(&fits) {
        if f.amplitude < floor {
            below += 1;
            continue;
        }
        if f.residual > 3.0 * noise && f.residual > 1e-2 * f.amplitude {
            poor.push((f.centre, f.residual / noise));
        }
        let gain = filter.gain(f.omega_d / (2.0 * PI)).max(1e-300);
        hilbert.push(point(h, rate_hz, gain));
        fit.push(point(f, rate_hz, gain));
    }
    for w in fit.windows(2) {
        let rise = w[1].amplitude - w[0].amplitude;
        let s = (w[0].amplitude_sigma.powi(2) + w[1].amplitude_sigma.powi(2)).sqrt();
        if rise > 3.0 * s && rise > 1e-3 * w[0].amplitude {
            checks.push(format!(
                "the envelope rises from {:.4e} at {:.4} s to {:.4e} at {:.4} s: beating (a \
                 second mode in the band?) or not a free decay",
                w[0].amplitude, w[0].time_s, w[1].amplitude, w[1].time_s
            ));
            break;
        }
    }
    if let Some(&(at, ratio)) = poor.iter().max_by(|a, b| a.1.total_cmp(&b.1)) {
        checks.push(format!(
            "{} windows fit a decaying sinusoid poorly (worst at {:.4} s: residual {ratio:.1} \
             times the noise): harmonics or a second mode in the band, or the frequency \
             changes within a window (shorten it)",
            poor.len(),
            at as f64 / rate_hz
        ));
    }
    if let Some(p) = fit.iter().find(|p| p.damping_ratio > 0.1) {
        checks.push(format!(
            "damping ratio {:.3} at {:.4} s: above 0.1 a free decay is not a single lightly \
             damped mode",
            p.damping_ratio, p.time_s
        ));
    }
    if fit.len() < 2 {
        checks.push(format!(
            "only {} windows above the noise floor {floor:.3e}: lengthen the record or \
             shorten the window",
            fit.len()
        ));
    }
    Ok(Decay {
        centre_hz: centre,
        filter,
        samples: (first, last),
        noise,
        floor,
        hilbert,
        fit,
        below_floor: below,
        checks,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A linear decay `A e^{−ζω_n t} cos(ω_d t)` is identified at every window with the
    /// same ω_n and ζ, noise-free to far below a percent.
    #[test]
    fn linear_decay_gives_its_frequency_and_damping() {
        let (fs, fnat, zeta): (f64, f64, f64) = (1000.0, 23.0, 0.01);
        let wn = 2.0 * PI * fnat;
        let wd = wn * (1.0 - zeta * zeta).sqrt();
        let x: Vec<f64> = (0..8000)
            .map(|i| {
                let t = i as f64 / fs;
                2.0 * (-zeta * wn * t).exp() * (wd * t + 0.4).cos()
            })
            .collect();
        let d = identify_decay(&x, fs, &DecayConfig::default()).unwrap();
        assert!(d.fit.len() > 10, "{}", d.fit.len());
        assert!(d.checks.is_empty(), "{:?}", d.checks);
        for p in d.fit.iter().chain(&d.hilbert) {
            assert!((p.frequency_hz / fnat - 1.0).abs() < 1e-4, "{p:?}");
            assert!((p.damping_ratio / zeta - 1.0).abs() < 5e-3, "{p:?}");
            let exact = 2.0 * (-zeta * wn * p.time_s).exp();
            assert!((p.amplitude / exact - 1.0).abs() < 5e-3, "{p:?} vs {exact}");
        }
    }

    #[test]
    fn bad_settings_are_refused_by_name() {
        let x = vec![0.0; 100];
        let cfg = DecayConfig {
            band: 2.0,
            ..DecayConfig::default()
        };
        let e = identify_decay(&x, 100.0, &cfg).unwrap_err().to_string();
        assert!(e.contains("band 2"), "{e}");
        let mut y = vec![1.0; 100];
        y[7] = f64::NAN;
        let e = identify_decay(&y, 100.0, &DecayConfig::default())
            .unwrap_err()
            .to_string();
        assert!(e.contains("sample 8"), "{e}");
    }
}
