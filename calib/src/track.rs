//! Harmonics along a slow sine sweep by harmonic tracking: the continuous sweep a test lab
//! records turned into points of multi-harmonic test data ([`crate::Step`], thesis §4.2),
//! without stopping at steps.
//!
//! The drive's instantaneous phase comes from its upward crossings through its mean: the
//! `n`-th crossing is at phase `2πn` (a constant offset does not matter). Around an analysis
//! point at crossing `n` a window of `P` periods is taken (crossings `n − P/2 … n + P/2`), the
//! phase there fitted by least squares as `φ(τ) = a₀ + a₁τ + a₂τ²` (`τ` samples from the
//! centre: the local frequency `a₁` and sweep rate `2a₂`), and every signal fitted by
//!
//! `x(τ) ≈ c₀ + d₀ s + Σ_k (c_k + d_k s) cos kφ(τ) + (s_k + e_k s) sin kφ(τ)`,  `s = τ/(half width)`,
//!
//! a local least-squares harmonic tracker (a windowed Vold–Kalman estimate of order one):
//! the amplitudes may change linearly across the window, so a response growing or decaying
//! through a resonance leaves no first-order error in the harmonics at the centre,
//! `X_k = c_k − i s_k`. The standard deviations come from the residual's variance and the
//! inverse normal matrix (white noise), and every harmonic is finally turned so that the
//! drive's fundamental is real and positive, as for a dwell ([`crate::dwell`]).
//!
//! What the tracker cannot remove is the structure's own lag: a sweep does not wait for the
//! steady state. For a linear mode (mass-normalised, `ω_r`, `ζ_r`) driven at `Ω(t)` with
//! `Ω̇ = ρ`, the response is `q = A e^{iφ}` with `Z A − i Z′ Ȧ + iρ A + Ä = F`, `Z(Ω) = ω_r² −
//! Ω² + 2iζ_rω_rΩ`; to first order in `ρ` its amplitude differs from the steady state
//! `A₀ = F/Z` by `A₁/A₀ = −iρ (Z′²/Z + 1)/Z` ([`sweep_bias`]). At resonance this is
//! `iρ/(ζ_r ω_r)²`: the sweep-rate parameter `η = |ṙ|/(2π ζ_r² f_r²)` (`ṙ` in Hz/s)
//! is the relative error there, mainly in phase (the response lags by its group delay), and
//! its square the order of what the first-order formula leaves.

use crate::dwell::check_signals;
use faer::{Mat, c64};
use nlsim_kernel::{Error, Result};
use std::f64::consts::PI;

/// Settings of [`track_sweep`].
#[derive(Debug, Clone, PartialEq)]
pub struct TrackConfig {
    /// Harmonics `H` estimated (`k = 1..=H`, the mean besides); `H` times the highest
    /// frequency of the sweep must lie below the Nyquist frequency.
    pub harmonics: usize,
    /// Periods `P` of the drive in each analysis window, even, at least 4 (default 10).
    pub window_periods: usize,
    /// Analysis points, evenly spaced in frequency over the sweep (default 100); at most one
    /// per `P` periods of the record, so that the windows do not overlap and the points' noise
    /// is independent (fewer are taken when the record is shorter).
    pub points: usize,
}

impl Default for TrackConfig {
    fn default() -> Self {
        TrackConfig {
            harmonics: 3,
            window_periods: 10,
            points: 100,
        }
    }
}

/// One analysis point of a tracked sweep.
#[derive(Debug, Clone, PartialEq)]
pub struct TrackPoint {
    /// The drive's instantaneous frequency at the window's centre (Hz).
    pub frequency_hz: f64,
    /// The sweep rate there `ṙ` (Hz/s; negative sweeping down).
    pub rate_hz_per_s: f64,
    /// The window's centre (sample index, fractional: a crossing of the drive).
    pub centre: f64,
    /// Harmonics `k = 1..=H` (index `k − 1`) of each signal (rows, in the order given; row 0
    /// the drive) at the centre, turned so that the drive's fundamental is real and
    /// positive; the signals' units.
    pub harmonics: Mat<c64>,
    /// Standard deviations like [`TrackPoint::harmonics`]: the real part that of the real
    /// part, the imaginary part that of the imaginary part (white noise of the fit's
    /// residual variance).
    pub sigma: Mat<c64>,
    /// Each signal's mean at the centre.
    pub mean: Vec<f64>,
}

/// A tracked sweep ([`track_sweep`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Track {
    /// Whether the frequency rises.
    pub rising: bool,
    /// The points, in time order.
    pub points: Vec<TrackPoint>,
    /// Crossings of the drive found (its periods plus one).
    pub crossings: usize,
}

/// The first-order relative sweep bias of a linear mode's response (module docs):
/// `A₁/A₀ = −iρ (Z′²/Z + 1)/Z` at drive frequency `f_hz` swept at `rate_hz_per_s`, for a mode
/// of natural frequency `mode_hz` and damping ratio `zeta`; `ρ = 2π ṙ`, `Z = ω_r² − Ω² +
/// 2iζω_rΩ`, `Z′ = −2Ω + 2iζω_r`. Its modulus at resonance is the sweep-rate parameter
/// [`sweep_rate_parameter`].
pub fn sweep_bias(f_hz: f64, rate_hz_per_s: f64, mode_hz: f64, zeta: f64) -> c64 {
    let (w, wr, rho) = (
        2.0 * PI * f_hz,
        2.0 * PI * mode_hz,
        2.0 * PI * rate_hz_per_s,
    );
    let z = c64::new(wr * wr - w * w, 2.0 * zeta * wr * w);
    let dz = c64::new(-2.0 * w, 2.0 * zeta * wr);
    let i_rho = c64::new(0.0, -rho);
    i_rho * (dz * dz / z + 1.0) / z
}

/// The sweep-rate parameter `η = |ṙ|/(2π ζ² f_r²)` of a mode (`ṙ` Hz/s, `f_r` Hz): the
/// relative first-order error of a tracked response at the mode's resonance
/// ([`sweep_bias`]). Below about 1e-2 a sweep is slow for that mode.
pub fn sweep_rate_parameter(rate_hz_per_s: f64, mode_hz: f64, zeta: f64) -> f64 {
    rate_hz_per_s.abs() / (2.0 * PI * zeta * zeta * mode_hz * mode_hz)
}

/// The upward crossings of `x` through its mean (fractional sample indices), with
/// hysteresis: after a crossing the signal must fall below the mean by a quarter of its last
/// half-period's peak before the next one counts, so that noise near the mean gives no
/// double crossing while the amplitude may change along the sweep.
fn crossings(x: &[f64]) -> Vec<f64> {
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let mut out = Vec::new();
    let mut armed = false;
    let (mut peak, mut last_peak) = (0.0f64, 0.0f64);
    for n in 1..x.len() {
        let (a, b) = (x[n - 1] - mean, x[n] - mean);
        if !armed {
            peak = peak.max(b);
            if b < -0.25 * last_peak.max(0.0) && b < 0.0 {
                armed = true;
                last_peak = peak;
                peak = 0.0;
            }
        } else {
            peak = peak.max(-b);
            if a < 0.0 && b >= 0.0 {
                out.push((n - 1) as f64 + refine_crossing(x, n, mean, a / (a - b)));
                armed = false;
                last_peak = peak;
                peak = 0.0;
            }
        }
    }
    out
}

/// The crossing of `x − mean` between samples `n − 1` and `n` (offset in `[0, 1]` from
/// `n − 1`), from the linear guess `u` by Newton steps on the cubic through samples `n − 2 ..=
/// n + 1`: linear interpolation misplaces a crossing by up to ~1e-3 sample where the signal
/// bends (a harmonic), which would jitter the tracked frequency by ~1e-6.
fn refine_crossing(x: &[f64], n: usize, mean: f64, u: f64) -> f64 {
    if n < 2 || n + 1 >= x.len() {
        return u;
    }
    let y = [
        x[n - 2] - mean,
        x[n - 1] - mean,
        x[n] - mean,
        x[n + 1] - mean,
    ];
    // Lagrange cubic on nodes −1, 0, 1, 2 and its derivative, at u.
    let p = |u: f64| {
        let l = [
            -u * (u - 1.0) * (u - 2.0) / 6.0,
            (u + 1.0) * (u - 1.0) * (u - 2.0) / 2.0,
            -(u + 1.0) * u * (u - 2.0) / 2.0,
            (u + 1.0) * u * (u - 1.0) / 6.0,
        ];
        let dl = [
            -(3.0 * u * u - 6.0 * u + 2.0) / 6.0,
            (3.0 * u * u - 4.0 * u - 1.0) / 2.0,
            -(3.0 * u * u - 2.0 * u - 2.0) / 2.0,
            (3.0 * u * u - 1.0) / 6.0,
        ];
        (
            (0..4).map(|i| l[i] * y[i]).sum::<f64>(),
            (0..4).map(|i| dl[i] * y[i]).sum::<f64>(),
        )
    };
    let mut v = u;
    for _ in 0..4 {
        let (f, df) = p(v);
        if df <= 0.0 {
            return u;
        }
        v -= f / df;
    }
    if (0.0..=1.0).contains(&v) { v } else { u }
}

/// Least-squares quadratic through the points `(t, y)`: `[a₀, a₁, a₂]`.
fn quadratic(t: &[f64], y: &[f64]) -> Option<[f64; 3]> {
    let mut g = Mat::<f64>::zeros(3, 3);
    let mut r = Mat::<f64>::zeros(3, 1);
    for (&t, &y) in t.iter().zip(y) {
        let b = [1.0, t, t * t];
        for i in 0..3 {
            r[(i, 0)] += b[i] * y;
            for j in 0..3 {
                g[(i, j)] += b[i] * b[j];
            }
        }
    }
    use faer::linalg::solvers::Solve as _;
    let a = g.llt(faer::Side::Lower).ok()?.solve(&r);
    Some([a[(0, 0)], a[(1, 0)], a[(2, 0)]])
}

/// Tracks the harmonics of a sine sweep. `signals[0]` is the drive (force or voltage), the
/// others the responses; `names` name them in errors; `rate_hz` is the sampling rate. The
/// record holds one sweep whose frequency rises or falls throughout.
///
/// `Err` for input no sweep can be tracked in: unequal lengths or a non-finite sample, fewer
/// than `P + 2` periods of the drive, a drive whose frequency turns or hardly changes (a
/// dwell: [`crate::extract_dwell`]), a harmonic at or above the Nyquist frequency, settings
/// out of range.
pub fn track_sweep(
    names: &[&str],
    signals: &[&[f64]],
    rate_hz: f64,
    cfg: &TrackConfig,
) -> Result<Track> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(Error::invalid(
            "sweep: sampling rate",
            format!("{rate_hz} Hz: must be positive and finite"),
        ));
    }
    let p = cfg.window_periods;
    if p < 4 || !p.is_multiple_of(2) || p > 10_000 {
        return Err(Error::invalid(
            "sweep: window periods",
            format!("{p}: must be even, 4 to 10000"),
        ));
    }
    if cfg.harmonics == 0 || cfg.harmonics > 64 {
        return Err(Error::invalid(
            "sweep: harmonics",
            format!("{}: must be 1 to 64", cfg.harmonics),
        ));
    }
    if cfg.points == 0 {
        return Err(Error::invalid("sweep: points", "must be at least 1"));
    }
    let n = check_signals(names, signals)?;
    let c = crossings(signals[0]);
    let drive = names.first().copied().unwrap_or("drive");
    if c.len() < p + 2 {
        return Err(Error::invalid(
            format!("sweep: drive '{drive}'"),
            format!(
                "{} period(s) found in {n} samples; the tracker needs at least {} (window of \
                 {p} periods)",
                c.len().saturating_sub(1),
                p + 1
            ),
        ));
    }
    // The frequency at each crossing (Hz), from the P periods around it.
    let half = p / 2;
    let local: Vec<(usize, f64)> = (half..c.len() - half)
        .map(|j| (j, p as f64 / (c[j + half] - c[j - half]) * rate_hz))
        .collect();
    let (f_first, f_last) = (local[0].1, local[local.len() - 1].1);
    let (lo, hi) = local
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(a, b), &(_, f)| {
            (a.min(f), b.max(f))
        });
    let span = hi - lo;
    if span < 1e-3 * hi {
        return Err(Error::invalid(
            format!("sweep: drive '{drive}'"),
            format!(
                "its frequency stays within {lo:.6}–{hi:.6} Hz: a dwell, not a sweep (fit it \
                 as a stepped sine, without the sweep option)"
            ),
        ));
    }
    // The direction: where the frequency first leaves the start by 2 % of the span.
    let rising = local
        .iter()
        .find(|&&(_, f)| (f - f_first).abs() > 0.02 * span)
        .is_none_or(|&(_, f)| f > f_first);
    // Monotonic to within 2 % of the span (the crossing frequency's jitter): a turn means
    // two sweeps in one record.
    let mut extreme = f_first;
    for &(j, f) in &local {
        let back = if rising { extreme - f } else { f - extreme };
        if back > 0.02 * span {
            return Err(Error::invalid(
                format!("sweep: drive '{drive}'"),
                format!(
                    "its frequency turns near sample {} ({f:.4} Hz after {extreme:.4} Hz): \
                     give each direction as a window of its own",
                    c[j].round() as usize + 1
                ),
            ));
        }
        extreme = if rising {
            extreme.max(f)
        } else {
            extreme.min(f)
        };
    }
    let h = cfg.harmonics;
    if h as f64 * hi * 1.02 >= 0.5 * rate_hz {
        return Err(Error::invalid(
            "sweep: harmonics",
            format!(
                "harmonic {h} of {hi:.4} Hz reaches the Nyquist frequency {} Hz: fewer \
                 harmonics or a faster sampling",
                0.5 * rate_hz
            ),
        ));
    }
    // Centres: evenly spaced in frequency, at most one per P periods.
    let count = cfg.points.min(local.len().div_ceil(p)).max(1);
    let mut centres: Vec<usize> = Vec::with_capacity(count);
    for i in 0..count {
        let target = if count == 1 {
            0.5 * (f_first + f_last)
        } else {
            f_first + (f_last - f_first) * i as f64 / (count - 1) as f64
        };
        // The first crossing at or past the target in the sweep's direction.
        let at = local
            .iter()
            .position(|&(_, f)| if rising { f >= target } else { f <= target })
            .unwrap_or(local.len() - 1);
        // Windows apart: a centre too close to the last moves on to the next free one.
        let j = match centres.last() {
            Some(&last) => local[at].0.max(last + p),
            None => local[at].0,
        };
        if j + half < c.len() {
            centres.push(j);
        }
    }
    let np = 2 + 4 * h;
    let mut points = Vec::with_capacity(centres.len());
    for &j in &centres {
        let t0 = c[j];
        let (ts, ys): (Vec<f64>, Vec<f64>) = (j - half..=j + half)
            .map(|m| (c[m] - t0, 2.0 * PI * (m as f64 - j as f64)))
            .unzip();
        let Some([a0, a1, a2]) = quadratic(&ts, &ys) else {
            continue;
        };
        let first = c[j - half].ceil() as usize;
        let last = (c[j + half].floor() as usize).min(n - 1);
        if last <= first + np {
            continue;
        }
        let width = 0.5 * (c[j + half] - c[j - half]);
        // Normal equations, one basis row per sample.
        let mut g = Mat::<f64>::zeros(np, np);
        let mut rhs = Mat::<f64>::zeros(np, signals.len());
        let mut row = vec![0.0; np];
        let basis = |m: usize, row: &mut [f64]| {
            let tau = m as f64 - t0;
            let s = tau / width;
            let phi = a0 + a1 * tau + a2 * tau * tau;
            let (s1, c1) = phi.sin_cos();
            row[0] = 1.0;
            row[1] = s;
            let (mut ck, mut sk) = (c1, s1);
            for k in 0..h {
                row[2 + 4 * k] = ck;
                row[3 + 4 * k] = sk;
                row[4 + 4 * k] = ck * s;
                row[5 + 4 * k] = sk * s;
                (ck, sk) = (ck * c1 - sk * s1, sk * c1 + ck * s1);
            }
        };
        for m in first..=last {
            basis(m, &mut row);
            for a in 0..np {
                for b in a..np {
                    g[(a, b)] += row[a] * row[b];
                }
                for (q, x) in signals.iter().enumerate() {
                    rhs[(a, q)] += row[a] * x[m];
                }
            }
        }
        for a in 0..np {
            for b in 0..a {
                g[(a, b)] = g[(b, a)];
            }
        }
        let Ok(llt) = g.llt(faer::Side::Lower) else {
            continue;
        };
        use faer::linalg::solvers::{DenseSolveCore as _, Solve as _};
        let coef = llt.solve(&rhs);
        let ginv = llt.inverse();
        // Residual variance per signal.
        let dof = (last + 1 - first - np) as f64;
        let mut rss = vec![0.0; signals.len()];
        for m in first..=last {
            basis(m, &mut row);
            for (q, x) in signals.iter().enumerate() {
                let fit: f64 = (0..np).map(|a| row[a] * coef[(a, q)]).sum();
                rss[q] += (x[m] - fit).powi(2);
            }
        }
        // The drive's fundamental phase: every harmonic turned by −kψ.
        let psi = c64::new(coef[(2, 0)], -coef[(3, 0)]).arg();
        let ns = signals.len();
        let mut harmonics = Mat::<c64>::zeros(ns, h);
        let mut sigma = Mat::<c64>::zeros(ns, h);
        for q in 0..ns {
            let var = rss[q] / dof;
            for k in 0..h {
                let (ic, is) = (2 + 4 * k, 3 + 4 * k);
                let x = c64::new(coef[(ic, q)], -coef[(is, q)]);
                let (sn, cs) = (-((k + 1) as f64) * psi).sin_cos();
                harmonics[(q, k)] = x * c64::new(cs, sn);
                // (c − i s)(cos + i sin) = (c cos + s sin) + i (c sin − s cos), with
                // (cos, sin) of the turn −kψ: the variances of both parts.
                let (vcc, vss, vcs) = (ginv[(ic, ic)], ginv[(is, is)], ginv[(ic, is)]);
                let v_re = var * (cs * cs * vcc + sn * sn * vss + 2.0 * cs * sn * vcs);
                let v_im = var * (sn * sn * vcc + cs * cs * vss - 2.0 * cs * sn * vcs);
                sigma[(q, k)] = c64::new(v_re.max(0.0).sqrt(), v_im.max(0.0).sqrt());
            }
        }
        points.push(TrackPoint {
            frequency_hz: a1 * rate_hz / (2.0 * PI),
            rate_hz_per_s: 2.0 * a2 * rate_hz * rate_hz / (2.0 * PI),
            centre: t0,
            harmonics,
            sigma,
            mean: (0..ns).map(|q| coef[(0, q)]).collect(),
        });
    }
    Ok(Track {
        rising,
        points,
        crossings: c.len(),
    })
}
