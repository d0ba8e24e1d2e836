//! Harmonics of one stepped-sine dwell from its time histories: what a test lab's recorder
//! holds turned into the multi-harmonic step of [`crate::Step`] (thesis §4.2, Fig. 11).
//!
//! For a dwell of the drive at frequency `f`, sampled at `f_s`, every channel is fitted in
//! the least-squares sense by a mean and harmonics `k = 1..=H`:
//!
//! `x[n] ≈ X₀ + Re Σ_k X_k e^{ikθ(n − o)}`,  `θ = 2π f / f_s` (rad per sample),
//!
//! (`X_k = c_k − i s_k` for `c_k cos + s_k sin`, the convention of the test data). On a window
//! centred on sample `c` the cosine and sine columns are orthogonal to each other, and their
//! Gram matrices have closed forms in the Dirichlet kernel `D(q) = Σ_m cos(qθm) =
//! sin(qθL/2)/sin(qθ/2)`, so a fit costs one pass over the samples (a rotating phasor per
//! harmonic) and two `(H+1)`- and `H`-square Cholesky solves, whatever the number of samples
//! per period: a window of a non-integer number of periods leaks nothing into the estimate.
//!
//! The frequency, when not given exactly, is refined from the drift of the drive's
//! fundamental phase across periods (its slope is `θ_true − θ`), three passes. The steady
//! state is found per period: the fundamental amplitude of every signal, period by period,
//! against its mean over the second half of the dwell (`|A_b − Ā| ≤ tol Ā + 3 s`, `s` the
//! noise's period-to-period scatter there, from successive differences, which a slow
//! transient does not inflate); the periods before the last one outside that band are
//! discarded, and a dwell whose fitted halves still differ beyond `tol` and the noise is not
//! settled. The harmonics are then fitted on the largest integer number of periods at the
//! end of the dwell, and their standard deviations are the period-to-period scatter of the
//! real and imaginary parts over `√(periods)`. Every harmonic is finally turned so that the
//! drive's fundamental is real and positive (`X_k ← X_k e^{−ikφ₁}`): a shift of the time
//! origin, which a periodic response does not see.

use faer::{Mat, c64};
use nlsim_kernel::{Error, Result};
use std::f64::consts::PI;

/// Settings of [`extract_dwell`].
#[derive(Debug, Clone, PartialEq)]
pub struct DwellConfig {
    /// Harmonics `H` estimated (`k = 1..=H`, the mean besides); every one must lie below
    /// the Nyquist frequency.
    pub harmonics: usize,
    /// Relative tolerance of the steady state: a period whose fundamental amplitude differs
    /// from the settled mean by more than this fraction (beyond 3 times the period-to-period
    /// scatter) is still in the transient (default 1e-3).
    pub settle_tolerance: f64,
    /// Fewest settled periods a dwell needs to count as settled (default 4).
    pub min_periods: usize,
    /// Refine the given frequency from the drive's phase drift (default true); false takes
    /// it as exact (a generator's own frequency).
    pub estimate_frequency: bool,
}

impl Default for DwellConfig {
    fn default() -> Self {
        DwellConfig {
            harmonics: 3,
            settle_tolerance: 1e-3,
            min_periods: 4,
            estimate_frequency: true,
        }
    }
}

/// The harmonics of one dwell ([`extract_dwell`]).
#[derive(Debug, Clone, PartialEq)]
pub struct Dwell {
    /// The drive frequency (Hz): refined, or as given.
    pub frequency_hz: f64,
    /// Harmonics `k = 1..=H` (index `k − 1`) of each signal (rows, in the order given;
    /// row 0 the drive), turned so that the drive's fundamental is real and positive; the
    /// signals' units.
    pub harmonics: Mat<c64>,
    /// Standard deviations of the harmonics like [`Dwell::harmonics`]: the real part that of
    /// the real part, the imaginary part that of the imaginary part; NaN when fewer than two
    /// periods were fitted.
    pub sigma: Mat<c64>,
    /// Each signal's mean `X₀` over the fitted periods.
    pub mean: Vec<f64>,
    /// First sample of the fitted periods (the samples before it were discarded as the
    /// transient, or did not make up a whole period).
    pub first_sample: usize,
    /// Number of samples fitted.
    pub samples: usize,
    /// Whole periods fitted.
    pub periods: usize,
    /// Periods discarded as unsettled at the start of the dwell.
    pub unsettled_periods: usize,
    /// The largest change of a fundamental amplitude between the two halves of the fitted
    /// periods, relative to it: what is left of the transient (and of the noise).
    pub drift: f64,
    /// Whether the dwell reached a steady state: at least [`DwellConfig::min_periods`]
    /// settled periods, and no trend left over the second half of the dwell.
    pub settled: bool,
}

/// Samples between exact re-seeds of the rotating phasor (its rounding error grows linearly
/// in between: 256 steps keep it below 1e-13).
const RESEED: usize = 256;

/// The Gram matrices of the cosine columns (`0..=H`) and of the sine columns (`1..=H`) on a
/// centred window of `len` samples, factored.
struct Gram {
    cos: faer::linalg::solvers::Llt<f64>,
    sin: Option<faer::linalg::solvers::Llt<f64>>,
}

impl Gram {
    fn new(theta: f64, len: usize, h: usize) -> Option<Self> {
        let l = len as f64;
        let d = |q: usize| -> f64 {
            if q == 0 {
                return l;
            }
            let half = 0.5 * q as f64 * theta;
            (half * l).sin() / half.sin()
        };
        let cos = Mat::from_fn(h + 1, h + 1, |a, b| 0.5 * (d(a.abs_diff(b)) + d(a + b)));
        let cos = cos.llt(faer::Side::Lower).ok()?;
        let sin = if h == 0 {
            None
        } else {
            let s = Mat::from_fn(h, h, |a, b| 0.5 * (d(a.abs_diff(b)) - d(a + b + 2)));
            Some(s.llt(faer::Side::Lower).ok()?)
        };
        Some(Gram { cos, sin })
    }
}

/// A least-squares fit of one window ([`fit`]).
struct Fit {
    /// The mean `X₀`.
    mean: f64,
    /// `X_1..X_h`, time origin as asked.
    harmonics: Vec<c64>,
    /// The standard deviation the noise gives an amplitude fitted on this window:
    /// `σ √(2/L)` with `σ` the residual's per-sample standard deviation. A transient near
    /// the drive frequency is fitted into the harmonics, not the residual, so this stays the
    /// noise's.
    amplitude_sd: f64,
}

/// Least-squares mean and harmonics `1..=h` of `x[start..start + len]` at `theta` rad per
/// sample, with the time origin at sample `origin`.
fn fit(x: &[f64], theta: f64, h: usize, start: usize, len: usize, origin: f64, gram: &Gram) -> Fit {
    use faer::linalg::solvers::Solve as _;
    let centre = start as f64 + 0.5 * (len as f64 - 1.0);
    let m0 = start as f64 - centre;
    let mut acc = vec![c64::new(0.0, 0.0); h + 1];
    let mut squares = 0.0;
    let mut z = c64::new(0.0, 0.0);
    let step = c64::new(theta.cos(), theta.sin());
    for (i, &v) in x[start..start + len].iter().enumerate() {
        if i % RESEED == 0 {
            let a = theta * (m0 + i as f64);
            z = c64::new(a.cos(), a.sin());
        }
        acc[0].re += v;
        squares += v * v;
        let mut zk = z;
        for a in acc.iter_mut().skip(1) {
            *a += zk * v;
            zk *= z;
        }
        z *= step;
    }
    let pc = Mat::from_fn(h + 1, 1, |a, _| acc[a].re);
    let ps = Mat::from_fn(h, 1, |a, _| acc[a + 1].im);
    let alpha = gram.cos.solve(&pc);
    let beta = match &gram.sin {
        Some(s) => s.solve(&ps),
        None => Mat::zeros(0, 1),
    };
    // Residual sum of squares: xᵀx − bᵀ G⁻¹ b for each block of the normal equations.
    let explained: f64 = (0..=h).map(|a| pc[(a, 0)] * alpha[(a, 0)]).sum::<f64>()
        + (0..h).map(|a| ps[(a, 0)] * beta[(a, 0)]).sum::<f64>();
    let dof = len.saturating_sub(2 * h + 1).max(1) as f64;
    let amplitude_sd = ((squares - explained).max(0.0) / dof).sqrt() * (2.0 / len as f64).sqrt();
    let shift = centre - origin;
    let harmonics = (1..=h)
        .map(|k| {
            let local = c64::new(alpha[(k, 0)], -beta[(k - 1, 0)]);
            let a = -(k as f64) * theta * shift;
            local * c64::new(a.cos(), a.sin())
        })
        .collect();
    Fit {
        mean: alpha[(0, 0)],
        harmonics,
        amplitude_sd,
    }
}

/// The upward crossings of `x` through its mean, as fractional sample indices (linear
/// interpolation between the samples around each).
fn mean_crossings(x: &[f64]) -> Vec<f64> {
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let mut crossings = Vec::new();
    for n in 1..x.len() {
        let (a, b) = (x[n - 1] - mean, x[n] - mean);
        if a < 0.0 && b >= 0.0 {
            crossings.push((n - 1) as f64 + a / (a - b));
        }
    }
    crossings
}

/// The drive frequency from its upward mean crossings (Hz), when none is given: good to
/// about the period-to-period jitter, refined afterwards.
fn crossing_frequency(drive: &[f64], rate_hz: f64) -> Option<f64> {
    let c = mean_crossings(drive);
    let (&first, &last) = (c.first()?, c.last()?);
    (c.len() >= 3 && last > first).then(|| (c.len() - 1) as f64 / (last - first) * rate_hz)
}

/// Per-period fits of every signal over `[start, end)`, origin at `origin`: `(block start,
/// [fit per signal])` for each whole period.
fn period_fits(
    signals: &[&[f64]],
    theta: f64,
    h: usize,
    start: usize,
    end: usize,
    origin: f64,
) -> Vec<(usize, Vec<Fit>)> {
    let period = 2.0 * PI / theta;
    let count = ((end - start) as f64 / period).floor() as usize;
    let mut out = Vec::with_capacity(count);
    for b in 0..count {
        let s = start + (b as f64 * period).round() as usize;
        let e = (start + ((b + 1) as f64 * period).round() as usize).min(end);
        let Some(gram) = Gram::new(theta, e - s, h) else {
            continue;
        };
        let fits = signals
            .iter()
            .map(|x| fit(x, theta, h, s, e - s, origin, &gram))
            .collect();
        out.push((s, fits));
    }
    out
}

/// `θ` refined from the drift of the drive's fundamental phase across the periods of
/// `[start, end)` (fitted with `h` harmonics, so that they leak nothing into it): three
/// passes of the least-squares slope.
fn refine(drive: &[f64], mut theta: f64, h: usize, start: usize, end: usize) -> f64 {
    for _ in 0..3 {
        let origin = 0.5 * (start + end) as f64;
        let blocks = period_fits(&[drive], theta, h, start, end, origin);
        if blocks.len() < 3 {
            return theta;
        }
        let mut phases = Vec::with_capacity(blocks.len());
        let mut prev: Option<f64> = None;
        for (s, fits) in &blocks {
            let mut p = fits[0].harmonics[0].arg();
            if let Some(q) = prev {
                p = q + (p - q + PI).rem_euclid(2.0 * PI) - PI;
            }
            prev = Some(p);
            let width = 2.0 * PI / theta;
            phases.push((*s as f64 + 0.5 * (width - 1.0), p));
        }
        let n = phases.len() as f64;
        let mt = phases.iter().map(|p| p.0).sum::<f64>() / n;
        let mp = phases.iter().map(|p| p.1).sum::<f64>() / n;
        let sxy: f64 = phases.iter().map(|p| (p.0 - mt) * (p.1 - mp)).sum();
        let sxx: f64 = phases.iter().map(|p| (p.0 - mt).powi(2)).sum();
        if sxx <= 0.0 {
            return theta;
        }
        let slope = sxy / sxx;
        theta += slope;
        if slope.abs() <= 1e-15 * theta {
            break;
        }
    }
    theta
}

/// Checks the signals: equal lengths, finite samples. `names[i]` names signal `i` in errors.
pub(crate) fn check_signals(names: &[&str], signals: &[&[f64]]) -> Result<usize> {
    let Some(n) = signals.first().map(|s| s.len()) else {
        return Err(Error::invalid(
            "dwell",
            "no signal given: the drive comes first",
        ));
    };
    for (i, s) in signals.iter().enumerate() {
        let name = names.get(i).copied().unwrap_or("?");
        if s.len() != n {
            return Err(Error::invalid(
                format!("dwell: signal '{name}'"),
                format!("{} samples, the drive has {n}", s.len()),
            ));
        }
        if let Some(k) = s.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(
                format!("dwell: signal '{name}', sample {}", k + 1),
                format!("{} is not a finite number", s[k]),
            ));
        }
    }
    Ok(n)
}

/// The harmonics of one dwell. `signals[0]` is the drive (force or voltage), the others the
/// responses; `names` name them in errors; `rate_hz` is the sampling rate; `frequency_hz`
/// the drive frequency if known (refined unless `cfg.estimate_frequency` is false), else
/// estimated from the drive's mean crossings and refined. `Err` for input no dwell can be
/// fitted to (unequal lengths, a non-finite sample, fewer samples than one period, a
/// harmonic at or above the Nyquist frequency); a dwell that does not settle is returned
/// with `settled = false`.
pub fn extract_dwell(
    names: &[&str],
    signals: &[&[f64]],
    rate_hz: f64,
    frequency_hz: Option<f64>,
    cfg: &DwellConfig,
) -> Result<Dwell> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(Error::invalid(
            "dwell: sampling rate",
            format!("{rate_hz} Hz; it must be positive"),
        ));
    }
    if cfg.harmonics == 0 {
        return Err(Error::invalid("dwell: harmonics", "0; estimate at least 1"));
    }
    if !(cfg.settle_tolerance.is_finite() && cfg.settle_tolerance > 0.0) {
        return Err(Error::invalid(
            "dwell: settle tolerance",
            format!("{}; it must be positive", cfg.settle_tolerance),
        ));
    }
    let n = check_signals(names, signals)?;
    let h = cfg.harmonics;
    let f0 = match frequency_hz {
        Some(f) if f.is_finite() && f > 0.0 => f,
        Some(f) => {
            return Err(Error::invalid(
                "dwell: frequency",
                format!("{f} Hz; it must be positive"),
            ));
        }
        None => crossing_frequency(signals[0], rate_hz).ok_or_else(|| {
            Error::invalid(
                format!("dwell: drive '{}'", names.first().copied().unwrap_or("?")),
                format!("fewer than 3 periods in its {n} samples: no frequency can be estimated"),
            )
        })?,
    };
    if h as f64 * f0 >= 0.5 * rate_hz {
        return Err(Error::invalid(
            "dwell: harmonics",
            format!(
                "harmonic {h} of {f0:.6} Hz is at or above the Nyquist frequency {:.6} Hz of \
                 the {rate_hz} Hz sampling",
                0.5 * rate_hz
            ),
        ));
    }
    let mut theta = 2.0 * PI * f0 / rate_hz;
    let period = 2.0 * PI / theta;
    if (n as f64) < period {
        return Err(Error::invalid(
            format!("dwell: drive '{}'", names.first().copied().unwrap_or("?")),
            format!("{n} samples, shorter than one period of {f0:.6} Hz ({period:.1} samples)"),
        ));
    }
    if cfg.estimate_frequency {
        theta = refine(signals[0], theta, h, n / 2, n);
    }
    // Steady state: each period's fundamental against the second half's.
    let blocks = period_fits(signals, theta, h, 0, n, 0.0);
    let nb = blocks.len();
    let amplitude = |b: usize, s: usize| blocks[b].1[s].harmonics[0].norm();
    let half = nb / 2;
    let reference = half..nb;
    let mut unsettled_from_end = None;
    let mut trending = false;
    let mut noise_sd = vec![0.0; signals.len()];
    if nb >= 2 {
        for s in 0..signals.len() {
            let vals: Vec<f64> = reference.clone().map(|b| amplitude(b, s)).collect();
            let m = vals.len() as f64;
            let mean = vals.iter().sum::<f64>() / m;
            // The noise's scatter of a period's amplitude, from the fits' residuals (median
            // over the reference half): a transient beating with the drive varies the
            // amplitudes from period to period but is fitted, not left in the residual.
            let mut sds: Vec<f64> = reference
                .clone()
                .map(|b| blocks[b].1[s].amplitude_sd)
                .collect();
            sds.sort_by(f64::total_cmp);
            let sd = sds[sds.len() / 2];
            noise_sd[s] = sd;
            let band = cfg.settle_tolerance * mean + 3.0 * sd;
            if let Some(b) = (0..nb)
                .rev()
                .find(|&b| (amplitude(b, s) - mean).abs() > band)
            {
                unsettled_from_end = Some(unsettled_from_end.map_or(b, |u: usize| u.max(b)));
            }
            // A trend over the reference half: its last quarter against its third.
            let q = vals.len() / 2;
            if q >= 2 {
                let first = vals[..q].iter().sum::<f64>() / q as f64;
                let second = vals[q..].iter().sum::<f64>() / (vals.len() - q) as f64;
                let scatter = 3.0 * sd * (2.0 / q as f64).sqrt();
                if (second - first).abs() > cfg.settle_tolerance * mean + scatter {
                    trending = true;
                }
            }
        }
    }
    let settled_block = unsettled_from_end.map_or(0, |b| b + 1);
    let start = if settled_block < nb {
        blocks[settled_block].0
    } else {
        n
    };
    if cfg.estimate_frequency && n - start >= 3 * period.ceil() as usize {
        theta = refine(signals[0], theta, h, start, n);
    }
    let period = 2.0 * PI / theta;
    let periods = ((n - start) as f64 / period).floor() as usize;
    // Too few settled periods: fit what there is (at least one period) and say so.
    let periods_fit = periods.max(1).min((n as f64 / period).floor() as usize);
    let len = ((periods_fit as f64 * period).round() as usize).min(n);
    let first = n - len;
    let origin = first as f64 + 0.5 * (len as f64 - 1.0);
    let gram = Gram::new(theta, len, h).ok_or_else(|| {
        Error::invalid(
            "dwell",
            format!("the {len}-sample window cannot separate {h} harmonics"),
        )
    })?;
    let fits: Vec<Fit> = signals
        .iter()
        .map(|x| fit(x, theta, h, first, len, origin, &gram))
        .collect();
    // Turn the time origin so that the drive's fundamental is real and positive.
    let phi = fits[0].harmonics[0].arg();
    let turn = |k: usize, z: c64| {
        let a = -(k as f64) * phi;
        z * c64::new(a.cos(), a.sin())
    };
    let harmonics = Mat::from_fn(signals.len(), h, |s, k| turn(k + 1, fits[s].harmonics[k]));
    // Scatter of the period fits over the fitted window.
    let per = period_fits(signals, theta, h, first, n, origin);
    let mut sigma = Mat::from_fn(signals.len(), h, |_, _| c64::new(f64::NAN, f64::NAN));
    if per.len() >= 2 {
        let m = per.len() as f64;
        for s in 0..signals.len() {
            for k in 0..h {
                let vals: Vec<c64> = per
                    .iter()
                    .map(|(_, f)| turn(k + 1, f[s].harmonics[k]))
                    .collect();
                let mean = vals.iter().sum::<c64>() / m;
                let var = |part: fn(c64) -> f64| {
                    vals.iter()
                        .map(|v| (part(*v) - part(mean)).powi(2))
                        .sum::<f64>()
                        / (m - 1.0)
                };
                sigma[(s, k)] = c64::new((var(|z| z.re) / m).sqrt(), (var(|z| z.im) / m).sqrt());
            }
        }
    }
    // What is left of the transient: the halves of the fitted window, beyond what the
    // noise moves them (each half the mean of P/2 periods).
    let mut drift = 0.0f64;
    if periods_fit >= 2 {
        let half = periods_fit / 2;
        let half_len = (half as f64 * period).round() as usize;
        if let Some(g) = Gram::new(theta, half_len, h) {
            for (s, x) in signals.iter().enumerate() {
                let a = fit(x, theta, h, first, half_len, origin, &g).harmonics[0];
                let b = fit(x, theta, h, n - half_len, half_len, origin, &g).harmonics[0];
                let full = a.norm().max(b.norm());
                if full > 0.0 {
                    let change = (a.norm() - b.norm()).abs();
                    drift = drift.max(change / full);
                    let noise = 3.0 * noise_sd[s] * (2.0 / half as f64).sqrt();
                    if change > cfg.settle_tolerance * full + noise {
                        trending = true;
                    }
                }
            }
        }
    }
    Ok(Dwell {
        frequency_hz: theta * rate_hz / (2.0 * PI),
        harmonics,
        sigma,
        mean: fits.iter().map(|f| f.mean).collect(),
        first_sample: first,
        samples: len,
        periods: periods_fit,
        unsettled_periods: settled_block.min(nb),
        drift,
        settled: periods >= cfg.min_periods && !trending,
    })
}

/// One dwell found by [`detect_steps`]: samples `start..end` of the record, at about
/// `frequency_hz`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepWindow {
    /// First sample of the dwell.
    pub start: usize,
    /// One past its last sample.
    pub end: usize,
    /// The drive frequency over it (Hz), from its mean crossings: a start for
    /// [`extract_dwell`]'s refinement.
    pub frequency_hz: f64,
}

/// The dwells of a stepped-sine record, found from the drive alone: the period between
/// consecutive upward mean crossings, smoothed by a running median of 5 periods, and a new
/// step wherever that frequency changes by more than `tolerance` (relative) from one period
/// to the next. Dwells shorter than 3 periods (the switching between steps) are left out.
/// Steps closer than the crossing jitter of a noisy drive (about its noise-to-amplitude
/// ratio over 2π per period) need a step table instead.
pub fn detect_steps(drive: &[f64], rate_hz: f64, tolerance: f64) -> Vec<StepWindow> {
    if drive.len() < 3 || rate_hz.is_nan() || rate_hz <= 0.0 {
        return Vec::new();
    }
    let crossings = mean_crossings(drive);
    if crossings.len() < 4 {
        return Vec::new();
    }
    let freq: Vec<f64> = crossings
        .windows(2)
        .map(|w| rate_hz / (w[1] - w[0]))
        .collect();
    let median = |s: &[f64]| {
        let mut v = s.to_vec();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let smooth: Vec<f64> = (0..freq.len())
        .map(|j| median(&freq[j.saturating_sub(2)..(j + 3).min(freq.len())]))
        .collect();
    let mut windows = Vec::new();
    let mut first = 0usize;
    for j in 1..=smooth.len() {
        let cut =
            j == smooth.len() || (smooth[j] - smooth[j - 1]).abs() > tolerance * smooth[j - 1];
        if cut {
            // Periods first..j, from crossing `first` to crossing `j`.
            if j - first >= 3 {
                windows.push(StepWindow {
                    start: crossings[first].ceil() as usize,
                    end: (crossings[j].floor() as usize + 1).min(drive.len()),
                    frequency_hz: median(&freq[first..j]),
                });
            }
            first = j;
        }
    }
    windows
}
