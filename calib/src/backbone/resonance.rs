//! Backbone and damping of one mode from stepped sines at several levels and from
//! phase-resonance (phase-locked-loop) tests.
//!
//! A level is a set of steps `(f_j, F_j, R_j)`: the force's and the response's first
//! harmonics. Each is turned into the displacement receptance `α_j = R_j/((iω_j)^d F_j)`
//! (`d` = 0, 1, 2 for a displacement, velocity or acceleration sensor), whose phase runs
//! from 0 through −π/2 to −π across a resonance whatever held the level.
//!
//! - **Phase resonance.** Where `arg α` crosses −π/2 between two steps, a straight line
//!   through the phases of the `2·neighbours` nearest steps gives the crossing `f*`, and
//!   lines (a parabola with four steps or more) through `ln|α|`, `ln|R|` and `ln|F|`
//!   their values there. At phase resonance the force balances the damping alone, and the
//!   energy it feeds in per cycle (`π F X sin(−arg α)`) equals what the equivalent linear
//!   oscillator of modal constant `K = φ_s φ_d` (1/kg) dissipates: `ζ = K sin(−arg α) /
//!   (2 ω² |α|)` — in acceleration `ζ = K |F| / 2|A|` at −π/2. A level of a single step
//!   (a phase-locked loop's dwell) is taken as it is when its phase is within 10° of −π/2.
//! - **Level fit.** `α(ω) ≈ K / (ω_n² − ω² + 2iζω_nω)` fitted to the level's steps in
//!   `ln α` (log-magnitude and phase), Levenberg–Marquardt: one mode's `ω_n`, `ζ` and `K`
//!   per level. For a response-controlled level (constant amplitude) this is the equivalent
//!   linear oscillator at that amplitude; for a force-controlled one the amplitude changes
//!   across the level and the fit averages over it.
//! - `K`, when not given, is the mean of the levels' fitted `ln K` (the mode shape does not
//!   change with amplitude), with the standard deviation of that mean from their scatter.
//!
//! Standard deviations: from each step's relative standard deviation when given, otherwise
//! from the scatter of the level fit about the steps (its rms residual in `ln α` taken as
//! every step's deviation in the local lines; the scatter of the few steps of a local line
//! alone when the level has no fit). A reduced χ² below one is not trusted to shrink them.

use super::{BackbonePoint, propagate};
use crate::lm::{Evaluation, LeastSquares, LmConfig, levenberg_marquardt};
use faer::{Mat, c64};
use nlsim_kernel::{Error, Quantity, Result, Status};
use std::f64::consts::PI;

/// One step of a level.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelStep {
    /// Frequency (Hz).
    pub frequency_hz: f64,
    /// Force's first harmonic (N), `F = c − i s` of `c cos + s sin`.
    pub force: c64,
    /// Response's first harmonic, the sensor's unit, same convention.
    pub response: c64,
    /// Relative standard deviation of the response harmonic (`σ/|R|`); NaN when unknown.
    pub sigma: f64,
}

/// The steps of one level (one sweep of a stepped sine, or one dwell of a phase-locked loop).
#[derive(Debug, Clone, PartialEq)]
pub struct StepLevel {
    /// The level's label.
    pub label: String,
    /// Its steps (any order).
    pub steps: Vec<LevelStep>,
}

/// Settings of [`identify_resonance`].
#[derive(Debug, Clone, PartialEq)]
pub struct ResonanceConfig {
    /// What the response measures.
    pub quantity: Quantity,
    /// The modal constant `K = φ_s φ_d` (1/kg) of the mode at the sensor and the drive
    /// (`1/m` of a unit-scaled shape); `None`: from the levels' fits.
    pub modal_constant: Option<f64>,
    /// Steps each side of a crossing in the local lines (default 2; at least 1).
    pub neighbours: usize,
}

impl Default for ResonanceConfig {
    fn default() -> Self {
        ResonanceConfig {
            quantity: Quantity::Acceleration,
            modal_constant: None,
            neighbours: 2,
        }
    }
}

/// A level's single-mode fit.
#[derive(Debug, Clone, PartialEq)]
pub struct SdofFit {
    /// `ω_n/2π` (Hz) and its standard deviation.
    pub frequency_hz: (f64, f64),
    /// `ζ` and its standard deviation.
    pub damping_ratio: (f64, f64),
    /// `K` (1/kg) and its standard deviation.
    pub modal_constant: (f64, f64),
    /// Root mean square of the fit's residuals in `ln α` (log-magnitude and phase, rad).
    pub rms: f64,
    /// How the fit ended.
    pub status: Status,
}

/// What one level gave.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelResult {
    /// The level's label.
    pub label: String,
    /// The phase-resonance point with the energy-balance damping; `None` with a note when
    /// the phase does not cross −π/2.
    pub phase_resonance: Option<BackbonePoint>,
    /// The level's single-mode fit (four steps or more with a crossing).
    pub fit: Option<SdofFit>,
    /// Why a result is missing, or how many crossings there were; empty otherwise.
    pub note: String,
}

/// The outcome of [`identify_resonance`].
#[derive(Debug, Clone, PartialEq)]
pub struct Resonance {
    /// Per level, in the order given.
    pub levels: Vec<LevelResult>,
    /// The modal constant used (1/kg) and its standard deviation (0 when given).
    pub modal_constant: (f64, f64),
    /// Whether it was given (`false`: from the levels' fits).
    pub modal_constant_given: bool,
    /// Where the data break the method's assumptions (empty when nothing was found).
    pub checks: Vec<String>,
}

/// Weighted least-squares polynomial of degree `deg` in `x` (centred at `x0`): the
/// coefficients and their covariance scaled by the residual variance (or by the given
/// weights' when `known`).
fn poly(
    x: &[f64],
    y: &[f64],
    w: &[f64],
    x0: f64,
    deg: usize,
    known: bool,
) -> Option<(Vec<f64>, Vec<Vec<f64>>)> {
    let p = deg + 1;
    let mut a = vec![vec![0.0; p]; p];
    let mut b = vec![0.0; p];
    for ((xi, yi), wi) in x.iter().zip(y).zip(w) {
        let d = xi - x0;
        let basis: Vec<f64> = (0..p).map(|k| d.powi(k as i32)).collect();
        for r in 0..p {
            b[r] += wi * basis[r] * yi;
            for c in 0..p {
                a[r][c] += wi * basis[r] * basis[c];
            }
        }
    }
    let coef = super::solve_small(&a, &b)?;
    let inv = super::inverse_small(&a)?;
    let dof = x.len().saturating_sub(p);
    let chi2: f64 = x
        .iter()
        .zip(y)
        .zip(w)
        .map(|((xi, yi), wi)| {
            let d = xi - x0;
            let m: f64 = coef
                .iter()
                .enumerate()
                .map(|(k, c)| c * d.powi(k as i32))
                .sum();
            wi * (yi - m).powi(2)
        })
        .sum();
    let s2 = if dof == 0 {
        if known { 1.0 } else { f64::NAN }
    } else if known {
        (chi2 / dof as f64).max(1.0)
    } else {
        chi2 / dof as f64
    };
    let cov = inv
        .iter()
        .map(|r| r.iter().map(|v| v * s2).collect())
        .collect();
    Some((coef, cov))
}

/// The single-mode fit in `ln α`: parameters `(ln K, ω_n, ζ)`.
struct Sdof<'a> {
    omega: &'a [f64],
    ln_alpha: &'a [c64],
    weight: &'a [f64],
}

impl Sdof<'_> {
    fn model(u: &[f64], w: f64) -> (c64, [c64; 3]) {
        let (wn, z) = (u[1], u[2]);
        let d = c64::new(wn * wn - w * w, 2.0 * z * wn * w);
        let ln = c64::new(u[0], 0.0) - d.ln();
        let dwn = -c64::new(2.0 * wn, 2.0 * z * w) / d;
        let dz = -c64::new(0.0, 2.0 * wn * w) / d;
        (ln, [c64::new(1.0, 0.0), dwn, dz])
    }
}

impl LeastSquares for Sdof<'_> {
    fn n_params(&self) -> usize {
        3
    }

    fn evaluate(&mut self, u: &[f64]) -> Result<Option<Evaluation>> {
        let n = self.omega.len();
        let mut r = Vec::with_capacity(2 * n);
        let mut jac = Mat::<f64>::zeros(2 * n, 3);
        for (j, ((&w, la), &wt)) in self
            .omega
            .iter()
            .zip(self.ln_alpha)
            .zip(self.weight)
            .enumerate()
        {
            let (m, g) = Self::model(u, w);
            let d = m - la;
            let im = d.im - 2.0 * PI * (d.im / (2.0 * PI)).round();
            r.push(wt * d.re);
            r.push(wt * im);
            for k in 0..3 {
                jac[(2 * j, k)] = wt * g[k].re;
                jac[(2 * j + 1, k)] = wt * g[k].im;
            }
        }
        if r.iter().any(|v| !v.is_finite()) {
            return Ok(None);
        }
        Ok(Some(Evaluation {
            residuals: r,
            jacobian: jac,
        }))
    }
}

/// One step of a level as the identification uses it.
#[derive(Debug, Clone, Copy)]
struct Receptance {
    /// `ω` (rad/s).
    w: f64,
    /// The displacement receptance `α = R/((iω)^d F)`.
    alpha: c64,
    /// Relative standard deviation of the response (NaN when unknown).
    sigma: f64,
    /// `|R|` (the sensor's unit).
    response: f64,
    /// `|F|` (N).
    force: f64,
    /// `arg α`, unwrapped along the level (rad).
    phase: f64,
}

/// The steps of a level as [`Receptance`]s, sorted by frequency, with `arg α` unwrapped
/// along frequency (the first in (−3π/2, π/2]).
fn receptances(level: &StepLevel, quantity: Quantity) -> Result<Vec<Receptance>> {
    let d = match quantity {
        Quantity::Displacement => 0,
        Quantity::Velocity => 1,
        Quantity::Acceleration => 2,
    };
    let mut out = Vec::with_capacity(level.steps.len());
    for (i, s) in level.steps.iter().enumerate() {
        let ok = |v: c64| v.re.is_finite() && v.im.is_finite();
        if !(s.frequency_hz.is_finite() && s.frequency_hz > 0.0 && ok(s.force) && ok(s.response)) {
            return Err(Error::invalid(
                format!("level '{}', step {}", level.label, i + 1),
                format!(
                    "frequency {} Hz, force {}, response {}: needs a positive frequency and \
                     finite harmonics",
                    s.frequency_hz, s.force, s.response
                ),
            ));
        }
        if s.force.norm() == 0.0 || s.response.norm() == 0.0 {
            continue;
        }
        let w = 2.0 * PI * s.frequency_hz;
        let iw = c64::new(0.0, w);
        let mut den = s.force;
        for _ in 0..d {
            den *= iw;
        }
        let alpha = s.response / den;
        out.push(Receptance {
            w,
            alpha,
            sigma: s.sigma,
            response: s.response.norm(),
            force: s.force.norm(),
            phase: alpha.arg(),
        });
    }
    out.sort_by(|a, b| a.w.total_cmp(&b.w));
    let mut prev: Option<f64> = None;
    for e in out.iter_mut() {
        let mut p = e.phase;
        match prev {
            None => {
                if p > PI / 2.0 {
                    p -= 2.0 * PI;
                }
            }
            Some(q) => p = q + (p - q) - 2.0 * PI * ((p - q) / (2.0 * PI)).round(),
        }
        e.phase = p;
        prev = Some(p);
    }
    Ok(out)
}

/// Identifies the phase resonance and the single-mode fit of every level (module docs).
/// `Err` for invalid input: no level, a step with a non-positive frequency or non-finite
/// harmonics, a modal constant that is not positive, no neighbours.
pub fn identify_resonance(levels: &[StepLevel], config: &ResonanceConfig) -> Result<Resonance> {
    if levels.is_empty() {
        return Err(Error::invalid("stepped-sine backbone", "no level given"));
    }
    if config.neighbours == 0 {
        return Err(Error::invalid(
            "stepped-sine backbone",
            "needs at least one neighbour step each side of a crossing",
        ));
    }
    if let Some(k) = config.modal_constant
        && !(k.is_finite() && k > 0.0)
    {
        return Err(Error::invalid(
            "stepped-sine backbone",
            format!("modal constant {k} 1/kg must be positive"),
        ));
    }
    let data: Vec<_> = levels
        .iter()
        .map(|l| receptances(l, config.quantity))
        .collect::<Result<_>>()?;
    let mut checks = Vec::new();
    // Level fits first: they give K when it is not given.
    let mut fits: Vec<Option<SdofFit>> = Vec::with_capacity(levels.len());
    let mut crossings: Vec<Vec<usize>> = Vec::with_capacity(levels.len());
    for d in &data {
        let cross: Vec<usize> = (0..d.len().saturating_sub(1))
            .filter(|&j| {
                let (a, b) = (d[j].phase + PI / 2.0, d[j + 1].phase + PI / 2.0);
                a == 0.0 || a.signum() != b.signum()
            })
            .collect();
        fits.push(if d.len() >= 4 && !cross.is_empty() {
            fit_level(d)
        } else {
            None
        });
        crossings.push(cross);
    }
    let (k, k_sigma) = match config.modal_constant {
        Some(k) => (k, 0.0),
        None => {
            let lk: Vec<f64> = fits
                .iter()
                .flatten()
                .filter(|f| f.status.is_converged())
                .map(|f| f.modal_constant.0.ln())
                .collect();
            if lk.is_empty() {
                (f64::NAN, f64::NAN)
            } else {
                let n = lk.len() as f64;
                let mean = lk.iter().sum::<f64>() / n;
                let sd = if lk.len() > 1 {
                    (lk.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt()
                } else {
                    fits.iter()
                        .flatten()
                        .map(|f| f.modal_constant.1 / f.modal_constant.0)
                        .next()
                        .unwrap_or(f64::NAN)
                        * n.sqrt()
                };
                if lk.len() > 2 {
                    let worst = lk.iter().fold(0.0f64, |a, v| a.max((v - mean).abs()));
                    if worst > 0.2 {
                        checks.push(format!(
                            "the levels' fitted modal constants differ by up to {:.0} % from \
                             their mean: the mode's shape or a second mode changes the \
                             receptance across levels (give the modal constant if it is known)",
                            100.0 * (worst.exp() - 1.0)
                        ));
                    }
                }
                (mean.exp(), mean.exp() * sd / n.sqrt())
            }
        }
    };
    if !k.is_finite() {
        checks.push(
            "no level could be fitted (four steps or more across the resonance): no modal \
             constant, so no energy-balance damping; give the modal constant"
                .into(),
        );
    }
    let mut out = Vec::with_capacity(levels.len());
    for (((level, d), cross), fit) in levels.iter().zip(&data).zip(&crossings).zip(fits) {
        let mut note = String::new();
        let point = if d.len() == 1 {
            let Receptance {
                w,
                alpha: a,
                sigma: s,
                response: r,
                force: f,
                phase: ph,
            } = d[0];
            if (ph + PI / 2.0).abs() <= 10f64.to_radians() {
                let sin = (-ph).sin();
                let z = k * sin / (2.0 * w * w * a.norm());
                let rel = (s * s + (k_sigma / k).powi(2)).sqrt();
                Some(BackbonePoint {
                    time_s: f64::NAN,
                    level: level.label.clone(),
                    amplitude: r,
                    amplitude_sigma: s * r,
                    frequency_hz: w / (2.0 * PI),
                    frequency_sigma_hz: f64::NAN,
                    damping_ratio: z,
                    damping_sigma: rel * z,
                    force: f,
                })
            } else {
                note = format!(
                    "one step at {:.1}°: a phase-resonance dwell must be within 10° of −90°",
                    ph.to_degrees()
                );
                None
            }
        } else if let Some(&j) = cross.iter().max_by(|&&a, &&b| {
            (d[a].alpha.norm() + d[a + 1].alpha.norm())
                .total_cmp(&(d[b].alpha.norm() + d[b + 1].alpha.norm()))
        }) {
            if cross.len() > 1 {
                note = format!(
                    "the phase crosses −90° {} times (noise or a jump); the crossing at the \
                     largest response taken",
                    cross.len()
                );
            }
            // Steps without their own deviations take the scatter of the level's fit about
            // them (its many residuals), not that of the few steps of the local lines.
            let fallback = fit.as_ref().map(|f| f.rms);
            let p = crossing(level, d, j, config.neighbours, (k, k_sigma), fallback);
            if p.is_none() {
                note = format!(
                    "the local line through the phases near {:.4} Hz does not fall through \
                     −90° (noise larger than the phase change between steps)",
                    d[j].w / (2.0 * PI)
                );
            }
            p
        } else if d.is_empty() {
            note = "no step with a force and a response".into();
            None
        } else {
            let (a, b) = (d[0].phase.to_degrees(), d[d.len() - 1].phase.to_degrees());
            note = format!(
                "the phase runs from {a:.1}° to {b:.1}° and does not cross −90°: the level \
                 does not reach the resonance"
            );
            None
        };
        out.push(LevelResult {
            label: level.label.clone(),
            phase_resonance: point,
            fit,
            note,
        });
    }
    Ok(Resonance {
        levels: out,
        modal_constant: (k, k_sigma),
        modal_constant_given: config.modal_constant.is_some(),
        checks,
    })
}

/// The phase-resonance point of a level between its steps `j` and `j + 1`.
fn crossing(
    level: &StepLevel,
    d: &[Receptance],
    j: usize,
    neighbours: usize,
    (k, k_sigma): (f64, f64),
    fallback: Option<f64>,
) -> Option<BackbonePoint> {
    let lo = (j + 1).saturating_sub(neighbours);
    let hi = (j + 1 + neighbours).min(d.len());
    let pts = &d[lo..hi];
    let own = pts.iter().all(|p| p.sigma.is_finite() && p.sigma > 0.0);
    let fallback = fallback.filter(|s| s.is_finite() && *s > 0.0);
    let known = own || fallback.is_some();
    let w: Vec<f64> = pts
        .iter()
        .map(|p| match (own, fallback) {
            (true, _) => 1.0 / (p.sigma * p.sigma),
            (false, Some(s)) => 1.0 / (s * s),
            (false, None) => 1.0,
        })
        .collect();
    let x: Vec<f64> = pts.iter().map(|p| p.w).collect();
    let x0 = 0.5 * (d[j].w + d[j + 1].w);
    let ph: Vec<f64> = pts.iter().map(|p| p.phase + PI / 2.0).collect();
    let (c, cov) = poly(&x, &ph, &w, x0, 1, known)?;
    if c[1] >= 0.0 {
        return None;
    }
    let ws = x0 - c[0] / c[1];
    let var_w = propagate(&[-1.0 / c[1], c[0] / (c[1] * c[1])], &cov);
    let deg = if pts.len() >= 4 { 2 } else { 1 };
    let at = |y: Vec<f64>| -> Option<(f64, f64)> {
        let (c, cov) = poly(&x, &y, &w, x0, deg, known)?;
        let dx = ws - x0;
        let g: Vec<f64> = (0..=deg).map(|p| dx.powi(p as i32)).collect();
        let v: f64 = g.iter().zip(&c).map(|(a, b)| a * b).sum();
        Some((v, propagate(&g, &cov).sqrt()))
    };
    let (la, sla) = at(pts.iter().map(|p| p.alpha.norm().ln()).collect())?;
    let (lr, slr) = at(pts.iter().map(|p| p.response.ln()).collect())?;
    let (lf, _) = at(pts.iter().map(|p| p.force.ln()).collect())?;
    let alpha = la.exp();
    // At the crossing sin(−arg α) = 1.
    let z = k / (2.0 * ws * ws * alpha);
    let rel = (sla * sla + (k_sigma / k).powi(2) + 4.0 * var_w / (ws * ws)).sqrt();
    let amp = lr.exp();
    Some(BackbonePoint {
        time_s: f64::NAN,
        level: level.label.clone(),
        amplitude: amp,
        amplitude_sigma: amp * slr,
        frequency_hz: ws / (2.0 * PI),
        frequency_sigma_hz: var_w.sqrt() / (2.0 * PI),
        damping_ratio: z,
        damping_sigma: z * rel,
        force: lf.exp(),
    })
}

/// The single-mode fit of a level's receptances.
fn fit_level(d: &[Receptance]) -> Option<SdofFit> {
    let omega: Vec<f64> = d.iter().map(|p| p.w).collect();
    let ln_alpha: Vec<c64> = d
        .iter()
        .map(|p| c64::new(p.alpha.norm().ln(), p.phase))
        .collect();
    let known = d.iter().all(|p| p.sigma.is_finite() && p.sigma > 0.0);
    let weight: Vec<f64> = d
        .iter()
        .map(|p| if known { 1.0 / p.sigma } else { 1.0 })
        .collect();
    // Start: the step nearest −π/2 gives ω_n, the phase slope there ζ (dφ/dω = −1/ζω_n),
    // the magnitude there K = 2ζω_n²|α|.
    let j = (0..d.len()).min_by(|&a, &b| {
        (d[a].phase + PI / 2.0)
            .abs()
            .total_cmp(&(d[b].phase + PI / 2.0).abs())
    })?;
    let (a, b) = (j.saturating_sub(1), (j + 1).min(d.len() - 1));
    let wn = d[j].w;
    let slope = (d[b].phase - d[a].phase) / (d[b].w - d[a].w);
    let z0 = if slope < 0.0 {
        (-1.0 / (slope * wn)).clamp(1e-5, 0.5)
    } else {
        0.01
    };
    let k0 = 2.0 * z0 * wn * wn * d[j].alpha.norm();
    let mut prob = Sdof {
        omega: &omega,
        ln_alpha: &ln_alpha,
        weight: &weight,
    };
    let u0 = [k0.ln(), wn, z0];
    let lo = [f64::NEG_INFINITY, 0.5 * omega[0], 1e-7];
    let hi = [f64::INFINITY, 2.0 * omega[omega.len() - 1], 1.0];
    let rep = levenberg_marquardt(&mut prob, &u0, &lo, &hi, &LmConfig::default()).ok()?;
    let ev = rep.evaluation.as_ref()?;
    let n = ev.residuals.len();
    let chi2: f64 = ev.residuals.iter().map(|r| r * r).sum();
    let dof = n.saturating_sub(3).max(1) as f64;
    let s2 = if known {
        (chi2 / dof).max(1.0)
    } else {
        chi2 / dof
    };
    let jac = &ev.jacobian;
    let jtj: Vec<Vec<f64>> = (0..3)
        .map(|a| {
            (0..3)
                .map(|b| (0..n).map(|i| jac[(i, a)] * jac[(i, b)]).sum())
                .collect()
        })
        .collect();
    let inv = super::inverse_small(&jtj)?;
    let u = &rep.u;
    let kk = u[0].exp();
    let rms = {
        let s: f64 = ev
            .residuals
            .iter()
            .zip(weight.iter().flat_map(|w| [w, w]))
            .map(|(r, w)| (r / w).powi(2))
            .sum();
        (s / n as f64).sqrt()
    };
    Some(SdofFit {
        frequency_hz: (u[1] / (2.0 * PI), (inv[1][1] * s2).sqrt() / (2.0 * PI)),
        damping_ratio: (u[2], (inv[2][2] * s2).sqrt()),
        modal_constant: (kk, kk * (inv[0][0] * s2).sqrt()),
        rms,
        status: rep.status,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Steps of a linear oscillator `K/(ω_n² − ω² + 2iζω_nω)` in acceleration give back its
    /// ω_n, ζ and K by both methods, to the interpolation error of the local lines.
    #[test]
    fn linear_levels_give_their_mode() {
        let (fnat, zeta, kk) = (80.0, 0.004, 0.5);
        let wn = 2.0 * PI * fnat;
        let steps: Vec<LevelStep> = (0..41)
            .map(|i| {
                let f = 79.0 + 0.05 * i as f64;
                let w = 2.0 * PI * f;
                let alpha = kk / c64::new(wn * wn - w * w, 2.0 * zeta * wn * w);
                let force = c64::new(1.3, 0.0);
                LevelStep {
                    frequency_hz: f,
                    force,
                    response: alpha * force * (-(w * w)),
                    sigma: f64::NAN,
                }
            })
            .collect();
        let levels = vec![
            StepLevel {
                label: "a".into(),
                steps: steps.clone(),
            },
            StepLevel {
                label: "b".into(),
                steps,
            },
        ];
        let r = identify_resonance(&levels, &ResonanceConfig::default()).unwrap();
        assert!(
            (r.modal_constant.0 / kk - 1.0).abs() < 1e-8,
            "{:?}",
            r.modal_constant
        );
        let l = &r.levels[0];
        let fit = l.fit.as_ref().unwrap();
        assert!((fit.frequency_hz.0 / fnat - 1.0).abs() < 1e-10, "{fit:?}");
        assert!((fit.damping_ratio.0 / zeta - 1.0).abs() < 1e-8, "{fit:?}");
        let p = l.phase_resonance.as_ref().unwrap();
        // The phase is nearly linear over ±0.1 Hz of a 0.64 Hz half-power band: the line's
        // crossing is within a few mHz, the damping within a percent.
        assert!((p.frequency_hz - fnat).abs() < 2e-3, "{p:?}");
        assert!((p.damping_ratio / zeta - 1.0).abs() < 1e-2, "{p:?}");
        assert!((p.force - 1.3).abs() < 1e-12);
    }
}
