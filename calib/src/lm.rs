//! Levenberg–Marquardt for bounded nonlinear least squares (thesis §4.5, paper IV).
//!
//! Minimises `½‖r(u)‖²` over a box `lo ≤ u ≤ hi` with a scaled trust region in the manner of
//! Moré (1978): each step solves `min ‖r + J p‖` subject to `‖D p‖ ≤ Δ` exactly through a
//! singular value decomposition of `J D⁻¹`, where `D` holds the largest column norms of `J`
//! seen so far (so parameters of any magnitude are treated alike); the radius `Δ` grows or
//! shrinks with the ratio of actual to predicted reduction. Bounds hold at every iterate: a
//! parameter on a bound whose gradient pushes outward is held there for the step, and the
//! trial point is projected onto the box.
//!
//! A model evaluation that fails (a harmonic balance point that does not converge) is a
//! rejected step that shrinks the radius, not an error; the report counts them.

use crate::linalg::Svd;
use faer::Mat;
use nlsim_kernel::{Error, Result, Status};

/// One evaluation of the residual vector and its Jacobian.
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// Residuals `r(u)` (dimensionless: weighted by the noise).
    pub residuals: Vec<f64>,
    /// `∂r/∂u` (residuals × parameters).
    pub jacobian: Mat<f64>,
}

/// A least-squares problem in internal (scaled) parameters `u`.
pub trait LeastSquares {
    /// Number of parameters.
    fn n_params(&self) -> usize;

    /// Residuals and Jacobian at `u`. `Ok(None)` when the model cannot be evaluated there
    /// (e.g. a solver did not converge): the optimiser treats it as a failed trial. `Err` is
    /// for invalid input only.
    fn evaluate(&mut self, u: &[f64]) -> Result<Option<Evaluation>>;
}

/// Settings of [`levenberg_marquardt`].
#[derive(Debug, Clone, PartialEq)]
pub struct LmConfig {
    /// Most iterations (accepted or rejected trial steps).
    pub max_iterations: usize,
    /// Stop when both the actual and the predicted relative reduction of the cost are below
    /// this.
    pub ftol: f64,
    /// Stop when the trust radius falls below `xtol · ‖D u‖`.
    pub xtol: f64,
    /// Stop when the largest scaled projected gradient component is below this.
    pub gtol: f64,
    /// Initial radius `Δ₀ = factor · ‖D u₀‖` (or `factor` when `u₀ = 0`).
    pub initial_radius_factor: f64,
}

impl Default for LmConfig {
    fn default() -> Self {
        Self {
            max_iterations: 100,
            ftol: 1e-12,
            xtol: 1e-12,
            gtol: 1e-12,
            initial_radius_factor: 100.0,
        }
    }
}

impl LmConfig {
    /// Checks the settings.
    pub fn validate(&self) -> Result<()> {
        let pos = |v: f64| v.is_finite() && v >= 0.0;
        if !(pos(self.ftol) && pos(self.xtol) && pos(self.gtol)) {
            return Err(Error::invalid(
                "Levenberg–Marquardt settings",
                "ftol, xtol and gtol must be finite and non-negative",
            ));
        }
        if !(self.initial_radius_factor.is_finite() && self.initial_radius_factor > 0.0) {
            return Err(Error::invalid(
                "Levenberg–Marquardt settings",
                "initial_radius_factor must be positive",
            ));
        }
        Ok(())
    }
}

/// Why the optimiser stopped.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopReason {
    /// The relative reduction of the cost (actual and predicted) fell below `ftol`.
    CostReduction,
    /// The trust radius fell below `xtol` relative to the parameters.
    StepSize,
    /// The projected gradient fell below `gtol`.
    Gradient,
    /// The residual is exactly zero.
    ZeroResidual,
    /// `max_iterations` were taken.
    IterationLimit,
    /// The model could not be evaluated at the start point.
    StartFailed,
    /// The trust radius collapsed because the model failed to evaluate around the iterate.
    EvaluationFailures,
}

impl StopReason {
    /// The kernel status this reason maps to.
    pub fn status(self) -> Status {
        match self {
            StopReason::CostReduction
            | StopReason::StepSize
            | StopReason::Gradient
            | StopReason::ZeroResidual => Status::Converged,
            StopReason::IterationLimit => Status::IterationLimit,
            StopReason::StartFailed => Status::NonFinite,
            StopReason::EvaluationFailures => Status::StepTooSmall,
        }
    }
}

/// One accepted iterate, for the convergence history.
#[derive(Debug, Clone, PartialEq)]
pub struct LmStep {
    /// Iteration number (trial steps counted from 1; 0 is the start).
    pub iteration: usize,
    /// Cost `½‖r‖²` after the step.
    pub cost: f64,
    /// Trust radius after the step.
    pub radius: f64,
    /// Internal parameters after the step.
    pub u: Vec<f64>,
}

/// The outcome of [`levenberg_marquardt`]: the best point found, with its status and counts.
#[derive(Debug, Clone)]
pub struct LmReport {
    /// [`Status::Converged`] or why it stopped short.
    pub status: Status,
    /// The detailed reason.
    pub reason: StopReason,
    /// The best internal parameters found (the start when nothing was accepted).
    pub u: Vec<f64>,
    /// The final evaluation at `u` (`None` only when the start failed).
    pub evaluation: Option<Evaluation>,
    /// Cost `½‖r‖²` at `u` (infinite when the start failed).
    pub cost: f64,
    /// Trial steps taken.
    pub iterations: usize,
    /// Model evaluations (each with its Jacobian).
    pub evaluations: usize,
    /// Trial steps rejected (cost did not decrease enough).
    pub rejected: usize,
    /// Trial points where the model failed to evaluate.
    pub failed_evaluations: usize,
    /// Parameters held on a bound at the end.
    pub active_bounds: Vec<bool>,
    /// Accepted iterates, starting with the start point.
    pub history: Vec<LmStep>,
}

/// Minimises `½‖r(u)‖²` over `lo ≤ u ≤ hi` from `u0` (projected onto the box first).
///
/// `Err` only for invalid input (dimensions, inverted or non-finite bounds, bad settings) or
/// an `Err` from the problem; an evaluation failure or an iteration limit comes back as a
/// status in the report with the best point found.
pub fn levenberg_marquardt(
    problem: &mut dyn LeastSquares,
    u0: &[f64],
    lo: &[f64],
    hi: &[f64],
    config: &LmConfig,
) -> Result<LmReport> {
    config.validate()?;
    let n = problem.n_params();
    for (what, v) in [("start", u0), ("lower bounds", lo), ("upper bounds", hi)] {
        if v.len() != n {
            return Err(Error::DimensionMismatch {
                what: format!("Levenberg–Marquardt {what}"),
                expected: n,
                found: v.len(),
            });
        }
    }
    for j in 0..n {
        if u0[j].is_nan() || lo[j].is_nan() || hi[j].is_nan() || lo[j] > hi[j] {
            return Err(Error::invalid(
                "Levenberg–Marquardt bounds",
                format!(
                    "parameter {j}: start {} and bounds [{}, {}] must be numbers with lower ≤ upper",
                    u0[j], lo[j], hi[j]
                ),
            ));
        }
    }
    let project = |u: &mut [f64]| {
        for j in 0..n {
            u[j] = u[j].clamp(lo[j], hi[j]);
        }
    };
    let mut u = u0.to_vec();
    project(&mut u);
    let mut report = LmReport {
        status: Status::NonFinite,
        reason: StopReason::StartFailed,
        u: u.clone(),
        evaluation: None,
        cost: f64::INFINITY,
        iterations: 0,
        evaluations: 1,
        rejected: 0,
        failed_evaluations: 0,
        active_bounds: vec![false; n],
        history: Vec::new(),
    };
    let Some(mut ev) = checked(problem.evaluate(&u)?, n)? else {
        report.failed_evaluations = 1;
        return Ok(report);
    };
    let mut cost = half_norm2(&ev.residuals);
    let mut d: Vec<f64> = (0..n).map(|j| column_norm(&ev.jacobian, j)).collect();
    fix_zero_scales(&mut d);
    let dnorm =
        |d: &[f64], u: &[f64]| norm(&d.iter().zip(u).map(|(a, b)| a * b).collect::<Vec<_>>());
    let mut radius = config.initial_radius_factor * dnorm(&d, &u);
    if radius == 0.0 {
        radius = config.initial_radius_factor;
    }
    report.history.push(LmStep {
        iteration: 0,
        cost,
        radius,
        u: u.clone(),
    });
    let mut reason = StopReason::IterationLimit;
    let mut active = vec![false; n];
    let mut consecutive_failures = 0usize;
    for it in 1..=config.max_iterations {
        report.iterations = it;
        if cost == 0.0 {
            reason = StopReason::ZeroResidual;
            report.iterations = it - 1;
            break;
        }
        // Gradient g = Jᵀ r and the bounds that hold this step.
        let g: Vec<f64> = (0..n)
            .map(|j| {
                (0..ev.residuals.len())
                    .map(|i| ev.jacobian[(i, j)] * ev.residuals[i])
                    .sum()
            })
            .collect();
        for j in 0..n {
            let span = (hi[j] - lo[j]).abs().max(1.0) * 1e-14;
            active[j] =
                (u[j] <= lo[j] + span && g[j] > 0.0) || (u[j] >= hi[j] - span && g[j] < 0.0);
        }
        // Scaled projected gradient: |g_j| / (d_j ‖r‖) on the free parameters (MINPACK's
        // cosine between r and the columns of J).
        let rnorm = (2.0 * cost).sqrt();
        let gmax = (0..n)
            .filter(|&j| !active[j])
            .map(|j| g[j].abs() / (d[j] * rnorm))
            .fold(0.0f64, f64::max);
        if gmax <= config.gtol {
            reason = StopReason::Gradient;
            report.iterations = it - 1;
            break;
        }
        let free: Vec<usize> = (0..n).filter(|&j| !active[j]).collect();
        let step = trust_region_step(&ev, &free, &d, radius);
        let mut trial = u.clone();
        for (k, &j) in free.iter().enumerate() {
            trial[j] += step[k];
        }
        project(&mut trial);
        let p: Vec<f64> = (0..n).map(|j| trial[j] - u[j]).collect();
        let pnorm = dnorm(&d, &p);
        // Predicted reduction of the linear model for the projected step.
        let jp: Vec<f64> = (0..ev.residuals.len())
            .map(|i| (0..n).map(|j| ev.jacobian[(i, j)] * p[j]).sum())
            .collect();
        let lin: Vec<f64> = ev.residuals.iter().zip(&jp).map(|(r, q)| r + q).collect();
        let pred = cost - half_norm2(&lin);
        report.evaluations += 1;
        let outcome = if pnorm == 0.0 {
            None
        } else {
            checked(problem.evaluate(&trial)?, n)?
        };
        let (rho, new) = match outcome {
            Some(e) => {
                consecutive_failures = 0;
                let c = half_norm2(&e.residuals);
                let ared = cost - c;
                (
                    if pred > 0.0 { ared / pred } else { -1.0 },
                    Some((e, c, ared)),
                )
            }
            None => {
                if pnorm > 0.0 {
                    report.failed_evaluations += 1;
                    consecutive_failures += 1;
                }
                (f64::NEG_INFINITY, None)
            }
        };
        // Radius update (Moré 1978, with plain factors).
        if rho < 0.25 {
            radius = 0.25 * pnorm.max(f64::MIN_POSITIVE).min(radius);
        } else if rho > 0.75 {
            radius = radius.max(2.0 * pnorm);
        }
        let mut small_change = false;
        if rho > 1e-4 {
            let (e, c, ared) = new.expect("rho > 0 only after an evaluation");
            small_change = ared.abs() <= config.ftol * cost && pred <= config.ftol * cost;
            u = trial;
            ev = e;
            cost = c;
            for j in 0..n {
                d[j] = d[j].max(column_norm(&ev.jacobian, j));
            }
            fix_zero_scales(&mut d);
            report.history.push(LmStep {
                iteration: it,
                cost,
                radius,
                u: u.clone(),
            });
        } else {
            report.rejected += 1;
            if let Some((_, _, ared)) = &new {
                // A rejected step whose predicted and actual changes are both negligible:
                // the cost cannot be reduced further at this precision.
                if ared.abs() <= config.ftol * cost && pred <= config.ftol * cost {
                    small_change = true;
                }
            }
        }
        if small_change {
            reason = StopReason::CostReduction;
            break;
        }
        if radius <= config.xtol * dnorm(&d, &u).max(f64::MIN_POSITIVE) || pnorm == 0.0 {
            reason = if consecutive_failures > 0 {
                StopReason::EvaluationFailures
            } else {
                StopReason::StepSize
            };
            break;
        }
    }
    report.active_bounds = (0..n)
        .map(|j| {
            let span = (hi[j] - lo[j]).abs().max(1.0) * 1e-14;
            u[j] <= lo[j] + span || u[j] >= hi[j] - span
        })
        .collect();
    report.status = reason.status();
    report.reason = reason;
    report.u = u;
    report.cost = cost;
    report.evaluation = Some(ev);
    Ok(report)
}

/// Checks an evaluation's dimensions; a non-finite one counts as a failed evaluation.
fn checked(ev: Option<Evaluation>, n: usize) -> Result<Option<Evaluation>> {
    let Some(ev) = ev else { return Ok(None) };
    if ev.jacobian.nrows() != ev.residuals.len() || ev.jacobian.ncols() != n {
        return Err(Error::DimensionMismatch {
            what: "least-squares Jacobian (residuals × parameters)".into(),
            expected: ev.residuals.len() * n,
            found: ev.jacobian.nrows() * ev.jacobian.ncols(),
        });
    }
    let finite = ev.residuals.iter().all(|v| v.is_finite())
        && (0..n).all(|j| (0..ev.residuals.len()).all(|i| ev.jacobian[(i, j)].is_finite()));
    Ok(finite.then_some(ev))
}

/// The step `p` (free parameters) minimising `‖r + J_F p‖` with `‖D_F p‖ ≤ Δ`, from the SVD
/// of `J_F D_F⁻¹ = U S Vᵀ`: `q(λ) = −V diag(s/(s²+λ)) Uᵀ r`, `p = D⁻¹ q`, with `λ ≥ 0` the
/// smallest value for which `‖q‖ ≤ Δ` (found by Newton's method on the secular equation
/// `1/‖q(λ)‖ = 1/Δ`).
fn trust_region_step(ev: &Evaluation, free: &[usize], d: &[f64], radius: f64) -> Vec<f64> {
    let m = ev.residuals.len();
    if free.is_empty() {
        return Vec::new();
    }
    let a = Mat::from_fn(m, free.len(), |i, k| ev.jacobian[(i, free[k])] / d[free[k]]);
    let svd = Svd::new(&a);
    let b: Vec<f64> = (0..free.len())
        .map(|k| {
            if svd.s[k] > 0.0 {
                (0..m).map(|i| svd.u[(i, k)] * ev.residuals[i]).sum::<f64>()
            } else {
                0.0
            }
        })
        .collect();
    let smax = svd.s.iter().fold(0.0f64, |a, &s| a.max(s));
    let cutoff = smax * 1e-13 * (m.max(free.len()) as f64);
    // Coefficients of q in the V basis: c_k(λ) = −s_k b_k / (s_k² + λ).
    let coef = |lambda: f64| -> Vec<f64> {
        (0..free.len())
            .map(|k| {
                let s = svd.s[k];
                if s <= cutoff && lambda == 0.0 {
                    0.0
                } else {
                    -s * b[k] / (s * s + lambda)
                }
            })
            .collect()
    };
    let qnorm = |c: &[f64]| norm(c);
    let mut c = coef(0.0);
    if qnorm(&c) > radius {
        // φ(λ) = 1/Δ − 1/‖q(λ)‖ is increasing and nearly linear in λ: Newton from λ = 0
        // converges monotonically from below.
        let mut lambda = 0.0f64;
        for _ in 0..60 {
            c = coef(lambda);
            let qn = qnorm(&c);
            if (qn - radius).abs() <= 1e-3 * radius {
                break;
            }
            // d‖q‖/dλ = −Σ c_k² / (s_k² + λ) / ‖q‖.
            let dq: f64 = -(0..free.len())
                .map(|k| c[k] * c[k] / (svd.s[k] * svd.s[k] + lambda))
                .sum::<f64>()
                / qn;
            // φ'(λ) = dq/‖q‖²; Newton step Δλ = −φ/φ'.
            let phi = 1.0 / radius - 1.0 / qn;
            let next = lambda - phi * qn * qn / dq;
            lambda = if next.is_finite() && next > lambda {
                next
            } else {
                (2.0 * lambda).max(cutoff * cutoff + f64::MIN_POSITIVE)
            };
        }
    }
    (0..free.len())
        .map(|j| (0..free.len()).map(|k| svd.v[(j, k)] * c[k]).sum::<f64>() / d[free[j]])
        .collect()
}

fn half_norm2(r: &[f64]) -> f64 {
    0.5 * r.iter().map(|v| v * v).sum::<f64>()
}

fn norm(v: &[f64]) -> f64 {
    // Scaled to avoid overflow for parameters like 1e200.
    let m = v.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    if m == 0.0 || !m.is_finite() {
        return m;
    }
    m * v.iter().map(|x| (x / m) * (x / m)).sum::<f64>().sqrt()
}

fn column_norm(j: &Mat<f64>, c: usize) -> f64 {
    norm(&(0..j.nrows()).map(|i| j[(i, c)]).collect::<Vec<_>>())
}

/// A parameter with a zero Jacobian column keeps unit scale.
fn fix_zero_scales(d: &mut [f64]) {
    for v in d.iter_mut() {
        if *v == 0.0 || !v.is_finite() {
            *v = 1.0;
        }
    }
}
