//! Following solution branches (thesis §3.2, Fig. 3).
//!
//! - [`continuation`]: pseudo-arclength continuation in the frequency `Ω` or the force level
//!   `λ`, in scaled variables (`x` by the largest amplitude met so far, the parameter by the
//!   span of the sweep). Predictor along the tangent of `[R_x R_p]`, corrector by Newton on
//!   `R = 0` plus the arclength condition, steps grown after easy corrections and halved after
//!   hard or failed ones or a sharp turn (ripple pairs of turning points on non-smooth
//!   branches are dismissed, [`WIGGLE_PARAMETER`]). Folds are where the tangent's parameter component
//!   changes sign (located by the Illinois method along the arc); simple branch points are
//!   where `det [R_x R_p; tᵀ]` changes sign.
//! - [`stepped_sine`]: what a test does: frequency after frequency, each solved from the last
//!   solution, so that past a fold the response jumps to the other branch.

use crate::dense::{LuInPlace, norm_inf};
use crate::stability::Stability;
use crate::system::{HbSystem, NewtonReport, PathBuffers};
use faer::Mat;
use nlsim_kernel::{Error, Result, Status};
use std::cell::RefCell;
use std::f64::consts::PI;

/// Scaled arclength below which a converged step that turns the tangent sharply (but not
/// backwards) is accepted as a kink of a non-smooth branch: over so short an arc the corrector
/// cannot reach another branch.
const KINK_STEP: f64 = 1e-6;

/// The continuation parameter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Parameter {
    /// The fundamental frequency `Ω` (rad/s), at a fixed force level.
    Frequency,
    /// The force level `λ` (a factor on the forcing), at a fixed frequency.
    ForceLevel,
}

/// What a solution point is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PointKind {
    /// An ordinary point.
    Regular,
    /// A fold (turning point): the parameter is extremal along the branch.
    Fold,
    /// The end of the range.
    End,
    /// A stepped-sine point where the response left the branch it was on (past a fold):
    /// the jump a test sees.
    Jump,
}

/// A converged periodic solution.
#[derive(Debug, Clone)]
pub struct SolutionPoint {
    /// Fundamental frequency `Ω` (rad/s).
    pub omega: f64,
    /// Force level `λ`.
    pub scale: f64,
    /// Condensed unknowns (element coefficients, real layout).
    pub x: Vec<f64>,
    /// Hill stability, when computed.
    pub stability: Option<Stability>,
    /// Fold, end or regular.
    pub kind: PointKind,
    /// Newton (corrector) iterations it took.
    pub iterations: usize,
}

impl SolutionPoint {
    /// `Some(true)` when stable, `None` when stability was not computed.
    pub fn stable(&self) -> Option<bool> {
        self.stability.as_ref().map(|s| s.stable)
    }
}

/// A simple branch point between two solution points.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BranchPoint {
    /// Indices of the points around it.
    pub between: (usize, usize),
    /// Interpolated frequency (rad/s).
    pub omega: f64,
    /// Interpolated force level.
    pub scale: f64,
}

/// A followed branch.
#[derive(Debug, Clone)]
pub struct Branch {
    /// The continuation parameter (frequency for stepped sines).
    pub parameter: Parameter,
    /// The points in order along the branch.
    pub points: Vec<SolutionPoint>,
    /// Simple branch points detected.
    pub branch_points: Vec<BranchPoint>,
    /// Bifurcations read from the Floquet exponents (continuation with stability).
    pub bifurcations: Vec<Bifurcation>,
}

/// What a change of stability between two points is (thesis §3.2: Floquet multipliers
/// `μ = e^{sT}` leaving the unit circle).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BifurcationKind {
    /// A real multiplier through +1 where the branch turns: a fold.
    Fold,
    /// A real multiplier through +1 where the branch does not turn: a branch point.
    BranchPoint,
    /// A real multiplier through −1 (an exponent with imaginary part `ω0/2`): period
    /// doubling.
    PeriodDoubling,
    /// A complex pair through the unit circle: Neimark–Sacker (a quasi-periodic branch
    /// starts).
    NeimarkSacker,
}

impl BifurcationKind {
    /// `fold`, `branch point`, `period doubling` or `Neimark–Sacker`.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Fold => "fold",
            Self::BranchPoint => "branch point",
            Self::PeriodDoubling => "period doubling",
            Self::NeimarkSacker => "Neimark–Sacker",
        }
    }
}

/// A bifurcation between two solution points, located where the largest real part of its
/// class of Floquet exponents crosses zero.
#[derive(Debug, Clone)]
pub struct Bifurcation {
    /// Its kind.
    pub kind: BifurcationKind,
    /// Indices of the points around it.
    pub between: (usize, usize),
    /// Fundamental frequency (rad/s).
    pub omega: f64,
    /// Force level.
    pub scale: f64,
    /// Condensed unknowns there.
    pub x: Vec<f64>,
    /// `true` when located by the corrector (Illinois on the exponents along the chord),
    /// `false` when interpolated linearly between the two points.
    pub located: bool,
}

/// Counters of a continuation or stepped sine.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ContinuationStats {
    /// Accepted points (folds and the end point included).
    pub n_points: usize,
    /// Steps rejected (corrector failed or turned too sharply) and retried shorter.
    pub n_rejected: usize,
    /// Newton iterations over all accepted points.
    pub n_newton: usize,
    /// Pairs of turning points dismissed as ripples of a non-smooth branch
    /// ([`WIGGLE_PARAMETER`]).
    pub n_wiggles: usize,
    /// Stepped sines: steps the branch of the last point could not be followed across (a
    /// non-smooth point), whose point may or may not be a jump; a finer grid tells.
    pub n_unverified: usize,
}

/// Two successive turning points closer than this share of the parameter range, between
/// which the response changes by less than [`WIGGLE_RESPONSE`], are a ripple of the branch,
/// not a pair of folds: near a contact grazing, the truncated harmonics of a non-smooth force
/// make the branch wiggle over a few 1e-3 of the range (NLvib's example 3 at H = 21 shows
/// four such pairs at its frequency maximum). Both points are then reported as regular ones.
pub const WIGGLE_PARAMETER: f64 = 2e-3;

/// Largest relative change of `‖x‖∞` between the two turning points of a ripple.
pub const WIGGLE_RESPONSE: f64 = 0.1;

/// Dismisses ripples among the folds of `branch`: successive turning points within
/// [`WIGGLE_PARAMETER`]` · span` of each other with the response within [`WIGGLE_RESPONSE`]
/// form a cluster; a cluster across which the branch turns (read from the directions it
/// enters and leaves in, a ripple band away) keeps one fold, at the extreme parameter in the
/// direction the branch entered it, and one across which it does not turn keeps none.
/// Returns the number of turning points dismissed, over 2 (the ripple pairs).
fn dismiss_wiggles(branch: &mut Branch, span: f64) -> usize {
    let param = |p: &SolutionPoint| match branch.parameter {
        Parameter::Frequency => p.omega,
        Parameter::ForceLevel => p.scale,
    };
    let folds = branch.folds();
    let mut dismissed = 0;
    let mut c = 0;
    while c < folds.len() {
        let mut e = c;
        while e + 1 < folds.len() {
            let (a, b) = (&branch.points[folds[e]], &branch.points[folds[e + 1]]);
            let (na, nb) = (norm_inf(&a.x), norm_inf(&b.x));
            let close = (param(a) - param(b)).abs() <= WIGGLE_PARAMETER * span
                && (na - nb).abs() <= WIGGLE_RESPONSE * na.max(nb).max(1e-300);
            if !close {
                break;
            }
            e += 1;
        }
        if e > c {
            let (first, last) = (folds[c], folds[e]);
            let n = branch.points.len();
            let at = |i: usize| param(&branch.points[i]);
            // The directions the branch enters and leaves the cluster in, taken a ripple band
            // away from its first and last turning points: a turning point is flagged a step
            // late when a step passes the extreme, and one that falls between two steps is
            // not flagged at all, so neither the step before the first nor the parity of the
            // count is reliable. The parity serves when the branch starts or ends in the band.
            let band = WIGGLE_PARAMETER * span;
            let entry = (0..first).rev().find(|&i| (at(i) - at(first)).abs() > band);
            let exit = (last + 1..n).find(|&i| (at(i) - at(last)).abs() > band);
            let sign_in = match entry {
                Some(i) => (at(first) - at(i)).signum(),
                None => (at(first) - at(first.saturating_sub(1))).signum(),
            };
            let turns = match (entry, exit) {
                (Some(_), Some(j)) => (at(j) - at(last)).signum() != sign_in,
                _ => (e - c).is_multiple_of(2),
            };
            // The fold kept is the point of the branch between entry and exit with the
            // extreme parameter (a regular point between ripples may pass the flagged ones).
            let stretch = entry.map_or(0, |i| i + 1)..=exit.map_or(n - 1, |j| j - 1);
            let by = |i: &usize, j: &usize| (sign_in * at(*i)).total_cmp(&(sign_in * at(*j)));
            let keep = if turns { stretch.max_by(by) } else { None };
            for &i in &folds[c..=e] {
                branch.points[i].kind = PointKind::Regular;
            }
            dismissed += e - c + 1 - usize::from(keep.is_some());
            if let Some(k) = keep
                && branch.points[k].kind != PointKind::End
            {
                branch.points[k].kind = PointKind::Fold;
            }
        }
        c = e + 1;
    }
    dismissed / 2
}

/// The outcome of [`continuation`] or [`stepped_sine`]: the branch computed so far, how the
/// run ended and its counters. A run that stops short keeps every point it found.
#[derive(Debug, Clone)]
pub struct ContinuationReport {
    /// [`Status::Converged`]: the whole range was followed (or the branch turned back out
    /// of it). [`Status::IterationLimit`]: `max_points` reached first.
    /// [`Status::StepTooSmall`]: the corrector failed down to `ds_min` (or a stepped-sine
    /// point converged from no start). Otherwise the start point's Newton status.
    pub status: Status,
    /// The points found, in order.
    pub branch: Branch,
    /// Counters.
    pub stats: ContinuationStats,
    /// Where and why the run stopped short; empty when converged.
    pub detail: String,
    /// Stepped sines: the frequencies (rad/s) where no start converged, left out of the
    /// branch (a gap); empty for a continuation.
    pub skipped: Vec<f64>,
}

impl ContinuationReport {
    /// `true` when the whole range was followed.
    pub fn is_complete(&self) -> bool {
        self.status.is_converged()
    }

    /// The branch when the run followed the range or stopped at the point limit; an
    /// [`Error::Numerical`] with the report's detail otherwise, for callers that need the
    /// whole branch or nothing.
    pub fn into_branch(self) -> Result<Branch> {
        match self.status {
            Status::Converged | Status::IterationLimit => Ok(self.branch),
            _ => Err(Error::Numerical {
                what: self.detail_what(),
                detail: self.detail_why(),
            }),
        }
    }

    fn detail_what(&self) -> String {
        self.detail
            .split_once('\n')
            .map_or_else(|| self.detail.clone(), |(w, _)| w.to_string())
    }

    fn detail_why(&self) -> String {
        self.detail
            .split_once('\n')
            .map_or_else(|| self.status.to_string(), |(_, d)| d.to_string())
    }

    fn stopped(
        status: Status,
        branch: Branch,
        stats: ContinuationStats,
        what: String,
        why: String,
    ) -> Self {
        Self {
            status,
            branch,
            stats,
            detail: format!("{what}\n{why}"),
            skipped: Vec::new(),
        }
    }
}

impl Branch {
    /// Indices of the fold points.
    pub fn folds(&self) -> Vec<usize> {
        self.points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.kind == PointKind::Fold)
            .map(|(i, _)| i)
            .collect()
    }
}

/// Settings of [`continuation`].
#[derive(Debug, Clone, PartialEq)]
pub struct ContinuationConfig {
    /// The parameter followed.
    pub parameter: Parameter,
    /// Start of the range (rad/s or level).
    pub from: f64,
    /// End of the range (rad/s or level); may be below `from` (downward).
    pub to: f64,
    /// The other quantity, held fixed: the force level for a frequency sweep, the frequency
    /// (rad/s) for a force-level sweep.
    pub fixed: f64,
    /// First step, in scaled arclength (the parameter span is 1).
    pub ds: f64,
    /// Smallest step before giving up.
    pub ds_min: f64,
    /// Largest step.
    pub ds_max: f64,
    /// Most points (the branch is returned incomplete beyond).
    pub max_points: usize,
    /// Compute Hill stability at every point.
    pub stability: bool,
    /// Corrector iterations before the step is cut.
    pub max_corrector: usize,
}

impl ContinuationConfig {
    /// A frequency sweep from `from_hz` to `to_hz` at force level 1, with stability.
    pub fn frequency(from_hz: f64, to_hz: f64) -> Self {
        Self {
            parameter: Parameter::Frequency,
            from: 2.0 * PI * from_hz,
            to: 2.0 * PI * to_hz,
            fixed: 1.0,
            ds: 5e-3,
            ds_min: 1e-9,
            ds_max: 0.02,
            max_points: 5000,
            stability: true,
            max_corrector: 12,
        }
    }
}

/// A point in scaled variables with its tangent.
struct State {
    y: Vec<f64>,
    t: Vec<f64>,
    det_sign: f64,
    iterations: usize,
}

struct Tracker<'a> {
    sys: &'a HbSystem,
    cfg: &'a ContinuationConfig,
    xs: f64,
    ps: f64,
    /// The buffers of the evaluations and of the bordered solves: a corrector iteration
    /// allocates nothing once they are sized.
    work: RefCell<TrackWork>,
}

/// Buffers of [`Tracker`].
struct TrackWork {
    path: PathBuffers,
    /// Unscaled unknowns of the evaluation.
    x: Vec<f64>,
    /// The bordered matrix `[R_x̂ R_p̂; tᵀ]`.
    aug: Mat<f64>,
    lu: LuInPlace,
    rhs: Vec<f64>,
}

impl Default for TrackWork {
    fn default() -> Self {
        Self {
            path: PathBuffers::default(),
            x: Vec::new(),
            aug: Mat::new(),
            lu: LuInPlace::default(),
            rhs: Vec::new(),
        }
    }
}

impl<'a> Tracker<'a> {
    fn new(sys: &'a HbSystem, cfg: &'a ContinuationConfig, xs: f64) -> Self {
        Self {
            sys,
            cfg,
            xs,
            ps: cfg.to - cfg.from,
            work: RefCell::default(),
        }
    }
}

impl<'a> Tracker<'a> {
    /// A tracker in the scaled variables of `cfg` with `x` scaled by the largest `‖x‖∞`
    /// along `branch`: for work between the points of a computed branch.
    fn for_branch(sys: &'a HbSystem, cfg: &'a ContinuationConfig, branch: &Branch) -> Self {
        let xs = branch
            .points
            .iter()
            .map(|p| norm_inf(&p.x))
            .fold(0.0f64, f64::max)
            .max(1e-300);
        Self::new(sys, cfg, xs)
    }

    /// Point `p` in the scaled variables `(x / xs, (p − from) / ps)`.
    fn scaled(&self, p: &SolutionPoint) -> Vec<f64> {
        let par = match self.cfg.parameter {
            Parameter::Frequency => p.omega,
            Parameter::ForceLevel => p.scale,
        };
        let mut v: Vec<f64> = p.x.iter().map(|x| x / self.xs).collect();
        v.push((par - self.cfg.from) / self.ps);
        v
    }

    /// The branch point on the hyperplane normal to the unit chord direction `d` at distance
    /// `s` from the scaled point `a`, solved by the corrector: `(x, Ω, λ)`.
    fn on_chord(&self, a: &[f64], d: &[f64], s: f64) -> Option<(Vec<f64>, f64, f64)> {
        let pred: Vec<f64> = a.iter().zip(d).map(|(a, d)| a + s * d).collect();
        let (y, _, _) = self.correct(&pred, d)?;
        let (x, par) = self.unscale(&y);
        let (om, sc) = self.omega_scale(par);
        Some((x, om, sc))
    }

    fn omega_scale(&self, p: f64) -> (f64, f64) {
        match self.cfg.parameter {
            Parameter::Frequency => (p, self.cfg.fixed),
            Parameter::ForceLevel => (self.cfg.fixed, p),
        }
    }

    fn unscale(&self, y: &[f64]) -> (Vec<f64>, f64) {
        let n = y.len() - 1;
        (
            y[..n].iter().map(|v| v * self.xs).collect(),
            self.cfg.from + y[n] * self.ps,
        )
    }

    /// The evaluation at scaled `y` into `w.path` (unscaled: `R` in `ev.r`, `R_x` in
    /// `ev.jac`, `R_p` in `rp`).
    fn fill(&self, y: &[f64], w: &mut TrackWork) {
        let n = y.len() - 1;
        w.x.clear();
        w.x.extend(y[..n].iter().map(|v| v * self.xs));
        let (omega, scale) = self.omega_scale(self.cfg.from + y[n] * self.ps);
        let frequency = self.cfg.parameter == Parameter::Frequency;
        self.sys
            .evaluate_along(&w.x, omega, scale, frequency, &mut w.path);
    }

    /// Entry `(i, k)` of the scaled Jacobian `[R_x̂ | R_p̂]` of evaluation `path`.
    fn scaled_jacobian(&self, path: &PathBuffers, i: usize, k: usize) -> f64 {
        if k < path.rp.len() {
            path.ev.jac[(i, k)]
        } else {
            path.rp[i] * (self.ps / self.xs)
        }
    }

    /// The scaled Jacobian `[R_x̂ | R_p̂]` (n × n+1) of the last [`Tracker::fill`].
    fn jacobian(&self, w: &TrackWork) -> Mat<f64> {
        let n = w.path.rp.len();
        Mat::from_fn(n, n + 1, |i, k| self.scaled_jacobian(&w.path, i, k))
    }

    /// Scaled residual, Jacobian `[R_x̂ | R_p̂]` (n × n+1).
    fn eval(&self, y: &[f64]) -> (Vec<f64>, Mat<f64>) {
        let w = &mut *self.work.borrow_mut();
        self.fill(y, w);
        let r = w.path.ev.r.iter().map(|r| r / self.xs).collect();
        (r, self.jacobian(w))
    }

    fn where_(&self, y: &[f64]) -> String {
        let (_, p) = self.unscale(y);
        let (omega, scale) = self.omega_scale(p);
        format!("{:.6} Hz, level {scale:.4}", omega / (2.0 * PI))
    }

    /// Tangent at a converged point, oriented along `prev` (or increasing parameter
    /// towards `to` without one), and the sign of `det [J; tᵀ]`.
    fn tangent(&self, a: &Mat<f64>, prev: Option<&[f64]>) -> Result<(Vec<f64>, f64)> {
        let n = a.nrows();
        let w = &mut *self.work.borrow_mut();
        let TrackWork { aug, lu, rhs, .. } = w;
        bordered(
            aug,
            n,
            |i, c| a[(i, c)],
            |c| prev.map_or(f64::from(u8::from(c == n)), |t| t[c]),
        );
        if !lu.factor(aug) {
            return Err(Error::Numerical {
                what: "continuation tangent".into(),
                detail: "the Jacobian is singular or not finite".into(),
            });
        }
        rhs.clear();
        rhs.resize(n + 1, 0.0);
        rhs[n] = 1.0;
        lu.solve_in_place(rhs);
        let norm = rhs.iter().map(|v| v * v).sum::<f64>().sqrt();
        let t: Vec<f64> = rhs.iter().map(|v| v / norm).collect();
        // det [J; tᵀ] has the sign of det [J; guideᵀ] since guide·t > 0.
        Ok((t, lu.det_sign()))
    }

    /// Corrector from `pred` on `R = 0`, `t·(y − pred) = 0`.
    fn correct(&self, pred: &[f64], t: &[f64]) -> Option<(Vec<f64>, Mat<f64>, usize)> {
        let n = pred.len() - 1;
        let mut y = pred.to_vec();
        let w = &mut *self.work.borrow_mut();
        for it in 0..=self.cfg.max_corrector {
            self.fill(&y, w);
            let r = &w.path.ev.r;
            if r.iter().any(|v| !v.is_finite()) {
                return None;
            }
            let rn = norm_inf(r) / self.xs;
            if rn <= self.sys.config.rtol * norm_inf(&y[..n]).max(1e-3) {
                return Some((y, self.jacobian(w), it));
            }
            if it == self.cfg.max_corrector {
                return None;
            }
            let TrackWork {
                path, aug, lu, rhs, ..
            } = w;
            bordered(aug, n, |i, k| self.scaled_jacobian(path, i, k), |k| t[k]);
            if !lu.factor(aug) {
                return None;
            }
            rhs.clear();
            rhs.extend(path.ev.r.iter().map(|v| -v / self.xs));
            rhs.push(-(0..=n).map(|i| t[i] * (y[i] - pred[i])).sum::<f64>());
            lu.solve_in_place(rhs);
            y.iter_mut().zip(rhs.iter()).for_each(|(a, b)| *a += b);
        }
        None
    }

    fn point(&self, s: &State, kind: PointKind) -> Result<SolutionPoint> {
        let (x, p) = self.unscale(&s.y);
        let (omega, scale) = self.omega_scale(p);
        let stability = if self.cfg.stability {
            Some(self.sys.stability(&x, omega)?)
        } else {
            None
        };
        Ok(SolutionPoint {
            omega,
            scale,
            x,
            stability,
            kind,
            iterations: s.iterations,
        })
    }
}

/// Follows the branch through `cfg.from` over `cfg.to`, from `start` (condensed unknowns at
/// `from`; the linear response when `None`).
///
/// Returns the branch with a status: a run that stops short (step below `ds_min`, point
/// limit, no converged start) keeps every point found. `Err` only for invalid settings.
pub fn continuation(
    sys: &HbSystem,
    cfg: &ContinuationConfig,
    start: Option<&[f64]>,
) -> Result<ContinuationReport> {
    continuation_with_progress(sys, cfg, start, &mut |_| {})
}

/// [`continuation`] with `progress` called on every accepted point.
pub fn continuation_with_progress(
    sys: &HbSystem,
    cfg: &ContinuationConfig,
    start: Option<&[f64]>,
    progress: &mut dyn FnMut(&SolutionPoint),
) -> Result<ContinuationReport> {
    let mut report = follow_smoothed(sys, cfg, start, progress)?;
    if cfg.stability {
        report.branch.bifurcations = label_bifurcations(sys, cfg, &report.branch)?;
    }
    Ok(report)
}

/// The branch with its ripple folds dismissed, not yet labelled.
fn follow_smoothed(
    sys: &HbSystem,
    cfg: &ContinuationConfig,
    start: Option<&[f64]>,
    progress: &mut dyn FnMut(&SolutionPoint),
) -> Result<ContinuationReport> {
    let mut report = follow(sys, cfg, start, progress)?;
    report.stats.n_wiggles = dismiss_wiggles(&mut report.branch, (cfg.to - cfg.from).abs());
    Ok(report)
}

fn follow(
    sys: &HbSystem,
    cfg: &ContinuationConfig,
    start: Option<&[f64]>,
    progress: &mut dyn FnMut(&SolutionPoint),
) -> Result<ContinuationReport> {
    for (what, v) in [("from", cfg.from), ("to", cfg.to), ("fixed", cfg.fixed)] {
        if !v.is_finite() {
            return Err(Error::NonFinite {
                what: "continuation range".into(),
                location: what.into(),
                value: v,
            });
        }
    }
    if cfg.from == cfg.to {
        return Err(Error::invalid(
            "continuation range",
            "from and to are equal",
        ));
    }
    if !(cfg.ds_min > 0.0 && cfg.ds_min <= cfg.ds && cfg.ds <= cfg.ds_max) {
        return Err(Error::invalid(
            "continuation steps",
            format!(
                "need 0 < ds_min ≤ ds ≤ ds_max (got {}, {}, {})",
                cfg.ds_min, cfg.ds, cfg.ds_max
            ),
        ));
    }
    let (om0, sc0) = match cfg.parameter {
        Parameter::Frequency => (cfg.from, cfg.fixed),
        Parameter::ForceLevel => (cfg.fixed, cfg.from),
    };
    let (x0, rep) = match start {
        Some(x) => sys.solve(om0, sc0, x)?,
        None => sys.solve_from_rest(om0, sc0)?,
    };
    let mut stats = ContinuationStats::default();
    let mut branch = Branch {
        parameter: cfg.parameter,
        points: Vec::new(),
        branch_points: Vec::new(),
        bifurcations: Vec::new(),
    };
    if !rep.converged() {
        let e = sys.not_converged(om0, sc0, &rep);
        let (what, why) = match e {
            Error::Numerical { what, detail } => (what, detail),
            e => (String::from("continuation start"), e.to_string()),
        };
        return Ok(ContinuationReport::stopped(
            rep.status, branch, stats, what, why,
        ));
    }
    let mut tr = Tracker::new(
        sys,
        cfg,
        norm_inf(&x0)
            .max(norm_inf(&sys.linear_guess(om0, sc0)))
            .max(1e-300),
    );
    let n = x0.len();
    let mut y0: Vec<f64> = x0.iter().map(|v| v / tr.xs).collect();
    y0.push(0.0);
    let (_, a0) = tr.eval(&y0);
    let Ok((t0, d0)) = tr.tangent(&a0, None) else {
        let what = format!("continuation at {}", tr.where_(&y0));
        let why = "the branch tangent is singular at the start".to_string();
        return Ok(ContinuationReport::stopped(
            Status::Singular,
            branch,
            stats,
            what,
            why,
        ));
    };
    let mut cur = State {
        y: y0,
        t: t0,
        det_sign: d0,
        iterations: rep.iterations,
    };
    let mut push = |branch: &mut Branch, stats: &mut ContinuationStats, p: SolutionPoint| {
        stats.n_points += 1;
        stats.n_newton += p.iterations;
        progress(&p);
        branch.points.push(p);
    };
    push(&mut branch, &mut stats, tr.point(&cur, PointKind::Regular)?);
    let done = |status, branch, stats| ContinuationReport {
        status,
        branch,
        stats,
        detail: String::new(),
        skipped: Vec::new(),
    };
    // A point past the start of the range (the branch may leave it a little before it
    // turns back in) is followed but not kept: the branch reports the range asked for.
    let inside = |y: &[f64]| y[n] >= -1e-9;
    let mut ds = cfg.ds;
    loop {
        if branch.points.len() >= cfg.max_points {
            let what = format!("continuation at {}", tr.where_(&cur.y));
            let why = format!("stopped at the point limit ({})", cfg.max_points);
            return Ok(ContinuationReport::stopped(
                Status::IterationLimit,
                branch,
                stats,
                what,
                why,
            ));
        }
        let pred: Vec<f64> = cur.y.iter().zip(&cur.t).map(|(y, t)| y + ds * t).collect();
        let attempt = tr.correct(&pred, &cur.t).and_then(|(y, a, it)| {
            let (t, d) = tr.tangent(&a, Some(&cur.t)).ok()?;
            let cos: f64 = t.iter().zip(&cur.t).map(|(a, b)| a * b).sum();
            // A turn of the tangent that persists at a tiny step is a kink of the branch (a
            // contact grazing, sharpened by the AFT sampling), not a jump to another branch.
            (cos > 0.95 || ds <= KINK_STEP).then_some(State {
                y,
                t,
                det_sign: d,
                iterations: it,
            })
        });
        let Some(next) = attempt else {
            stats.n_rejected += 1;
            ds *= 0.5;
            if ds < cfg.ds_min {
                let what = format!("continuation at {}", tr.where_(&cur.y));
                let why = format!(
                    "the corrector failed down to the smallest step {:.1e}; the branch may \
                     have a non-smooth point there that more harmonics (or AFT samples) may resolve",
                    cfg.ds_min
                );
                return Ok(ContinuationReport::stopped(
                    Status::StepTooSmall,
                    branch,
                    stats,
                    what,
                    why,
                ));
            }
            continue;
        };
        // Past the end of the range: finish on it exactly.
        if next.y[n] >= 1.0 {
            let frac = (1.0 - cur.y[n]) / (next.y[n] - cur.y[n]);
            let guess: Vec<f64> = (0..n)
                .map(|i| (cur.y[i] + frac * (next.y[i] - cur.y[i])) * tr.xs)
                .collect();
            let (om, sc) = tr.omega_scale(cfg.to);
            let (x, rep) = sys.solve(om, sc, &guess)?;
            if !rep.converged() {
                let e = sys.not_converged(om, sc, &rep).to_string();
                let what = format!("continuation at {}", tr.where_(&cur.y));
                return Ok(ContinuationReport::stopped(
                    rep.status, branch, stats, what, e,
                ));
            }
            let mut y: Vec<f64> = x.iter().map(|v| v / tr.xs).collect();
            y.push(1.0);
            let end = State {
                y,
                t: next.t.clone(),
                det_sign: next.det_sign,
                iterations: rep.iterations,
            };
            push(&mut branch, &mut stats, tr.point(&end, PointKind::End)?);
            return Ok(done(Status::Converged, branch, stats));
        }
        if next.y[n] < -0.05 {
            // The branch turned back out of the range: it ends at its start side.
            return Ok(done(Status::Converged, branch, stats));
        }
        if next.t[n].signum() != cur.t[n].signum() && cur.t[n] != 0.0 {
            let Some(fold) = locate_fold(&tr, &cur, ds) else {
                let what = format!("fold location near {}", tr.where_(&cur.y));
                let why = "the corrector failed".to_string();
                return Ok(ContinuationReport::stopped(
                    Status::StepTooSmall,
                    branch,
                    stats,
                    what,
                    why,
                ));
            };
            if inside(&fold.y) {
                push(&mut branch, &mut stats, tr.point(&fold, PointKind::Fold)?);
            }
        } else if next.det_sign != cur.det_sign && inside(&cur.y) && inside(&next.y) {
            let i = branch.points.len() - 1;
            let (_, p0) = tr.unscale(&cur.y);
            let (_, p1) = tr.unscale(&next.y);
            let (om, sc) = tr.omega_scale(0.5 * (p0 + p1));
            branch.branch_points.push(BranchPoint {
                between: (i, i + 1),
                omega: om,
                scale: sc,
            });
        }
        if next.iterations <= 3 {
            ds = (ds * 1.5).min(cfg.ds_max);
        } else if next.iterations > 6 {
            ds *= 0.7;
        }
        // Rescale x when the amplitude grows, keeping the geometry of the step.
        let amp = norm_inf(&next.y[..n]);
        let mut next = next;
        if amp > 1.0 {
            for v in next.y[..n].iter_mut() {
                *v /= amp;
            }
            tr.xs *= amp;
            let (_, a) = tr.eval(&next.y);
            let mut guide: Vec<f64> = next.t.clone();
            guide[..n].iter_mut().for_each(|v| *v /= amp);
            let Ok((t, d)) = tr.tangent(&a, Some(&guide)) else {
                let what = format!("continuation at {}", tr.where_(&next.y));
                let why = "the branch tangent is singular".to_string();
                return Ok(ContinuationReport::stopped(
                    Status::Singular,
                    branch,
                    stats,
                    what,
                    why,
                ));
            };
            next.t = t;
            next.det_sign = d;
        }
        if inside(&next.y) {
            push(
                &mut branch,
                &mut stats,
                tr.point(&next, PointKind::Regular)?,
            );
        }
        cur = next;
    }
}

/// Fills `aug` (resized to `n+1` square) with the bordered matrix `[J; bᵀ]`: `J(i, k)` in its
/// first `n` rows, `b(k)` in the last.
fn bordered(
    aug: &mut Mat<f64>,
    n: usize,
    j: impl Fn(usize, usize) -> f64,
    b: impl Fn(usize) -> f64,
) {
    if aug.nrows() != n + 1 {
        *aug = Mat::zeros(n + 1, n + 1);
    }
    for k in 0..=n {
        for i in 0..n {
            aug[(i, k)] = j(i, k);
        }
        aug[(n, k)] = b(k);
    }
}

/// Finds the fold between `cur` and the point `ds` further along by the Illinois method on
/// the tangent's parameter component.
fn locate_fold(tr: &Tracker<'_>, cur: &State, ds: f64) -> Option<State> {
    let n = cur.y.len() - 1;
    let at = |s: f64| -> Option<State> {
        let pred: Vec<f64> = cur.y.iter().zip(&cur.t).map(|(y, t)| y + s * t).collect();
        let (y, a, it) = tr.correct(&pred, &cur.t)?;
        let (t, d) = tr.tangent(&a, Some(&cur.t)).ok()?;
        Some(State {
            y,
            t,
            det_sign: d,
            iterations: it,
        })
    };
    let (mut a, mut fa) = (0.0, cur.t[n]);
    let mut b = ds;
    let mut best = at(b)?;
    let mut fb = best.t[n];
    let mut side = 0;
    for _ in 0..60 {
        if (b - a).abs() <= 1e-12 * ds.max(1e-300) || fb.abs() <= 1e-12 {
            break;
        }
        let c = (a * fb - b * fa) / (fb - fa);
        let Some(sc) = at(c) else { break };
        let fc = sc.t[n];
        if fc.signum() == fb.signum() {
            b = c;
            fb = fc;
            if side == -1 {
                fa *= 0.5;
            }
            side = -1;
        } else {
            a = c;
            fa = fc;
            if side == 1 {
                fb *= 0.5;
            }
            side = 1;
        }
        best = sc;
    }
    Some(best)
}

/// A stepped sine over `omegas` (rad/s, in test order, up or down) at force level `scale`:
/// every point is solved from the previous solution, as a test dwells at each frequency.
///
/// Each step first tries Newton from the last solution (split into 2, 4, … 16 sub-steps
/// when it fails directly). When that fails, or when its solution lies off the tangent
/// prediction `x + (dx/dΩ) ΔΩ` by more than half its distance from `x` (a step over a fold,
/// or only a coarse step near a resonance), the step is decided by following the branch of
/// the last solution across it by pseudo-arclength continuation:
///
/// - the branch reaches the new frequency without turning: the point is the branch's there,
///   a regular one (whatever Newton found);
/// - the branch folds inside the step (ripples of a non-smooth branch dismissed as in
///   [`continuation`]): the branch ends and the point is a [`PointKind::Jump`], solved from
///   other starts — Newton's own solution, the linear response, the last solution scaled
///   down and up, and last a continuation in the force level from `scale`/1000 at the new
///   frequency;
/// - the continuation cannot follow the step (a non-smooth point): the point is found from
///   the same starts, kept regular and counted in [`ContinuationStats::n_unverified`] —
///   refine the grid there to tell.
///
/// With stability, a test cannot dwell on an unstable solution: an unstable point of the
/// branch ends it as a fold does (a jump), and a stable solution is preferred among the
/// starts (an unstable one is kept, flagged, when none is stable).
///
/// A frequency where no start converges is skipped: it is listed in
/// [`ContinuationReport::skipped`] and the sweep goes on from the last solution, so that the
/// sweep has a gap there rather than an end.
pub fn stepped_sine(
    sys: &HbSystem,
    omegas: &[f64],
    scale: f64,
    stability: bool,
) -> Result<ContinuationReport> {
    stepped_sine_with_progress(sys, omegas, scale, stability, &mut |_| {})
}

/// How the branch of the last stepped-sine point crosses a step.
enum Across {
    /// It reaches the new frequency: its solution there and the corrector's iterations.
    Reached(Vec<f64>, usize),
    /// It turns back inside the step: the response leaves it.
    Folded,
    /// The continuation stopped short.
    Failed,
}

/// Follows the branch through `x` at `from` (rad/s, level `scale`) to `to` by
/// pseudo-arclength continuation, turning points within `span` ripples dismissed. Steps fine
/// on the scale of the step come first; when they cannot get across (the ripples of a
/// contact grazing trap them), the steps of a continuation over the whole sweep `span`
/// (those of [`ContinuationConfig::frequency`]), which pass over ripples as that one does.
fn follow_across(
    sys: &HbSystem,
    from: f64,
    to: f64,
    scale: f64,
    x: &[f64],
    span: f64,
) -> Result<Across> {
    let ratio = (span / (to - from).abs()).max(1.0);
    let sweep = ContinuationConfig::frequency(0.0, 1.0);
    let tries = [(0.1, 0.25), (sweep.ds * ratio, sweep.ds_max * ratio)];
    for (k, &(ds, ds_max)) in tries.iter().enumerate() {
        if k > 0 && ds_max <= tries[0].1 {
            break;
        }
        let cfg = ContinuationConfig {
            parameter: Parameter::Frequency,
            from,
            to,
            fixed: scale,
            ds: ds.min(ds_max),
            ds_min: 1e-8,
            ds_max,
            max_points: 200,
            stability: false,
            max_corrector: 12,
        };
        let mut rep = follow(sys, &cfg, Some(x), &mut |_| {})?;
        if !rep.status.is_converged() {
            continue;
        }
        dismiss_wiggles(&mut rep.branch, span);
        let points = &rep.branch.points;
        if points.iter().any(|p| p.kind == PointKind::Fold) {
            return Ok(Across::Folded);
        }
        return Ok(match points.last() {
            Some(p) if p.kind == PointKind::End => Across::Reached(p.x.clone(), p.iterations),
            _ => Across::Folded,
        });
    }
    Ok(Across::Failed)
}

/// The solution at `omega` (rad/s) and level `scale` reached by continuation in the force
/// level from `scale`/1000 (where the response is close to linear), or `None`.
fn by_force_level(sys: &HbSystem, omega: f64, scale: f64) -> Result<Option<(Vec<f64>, usize)>> {
    if scale == 0.0 || !scale.is_finite() {
        return Ok(None);
    }
    let cfg = ContinuationConfig {
        parameter: Parameter::ForceLevel,
        from: 1e-3 * scale,
        to: scale,
        fixed: omega,
        ds: 5e-3,
        ds_min: 1e-8,
        ds_max: 0.05,
        max_points: 2000,
        stability: false,
        max_corrector: 12,
    };
    let rep = follow(sys, &cfg, None, &mut |_| {})?;
    Ok(match rep.branch.points.last() {
        Some(p) if rep.status.is_converged() && p.kind == PointKind::End => {
            Some((p.x.clone(), p.iterations))
        }
        _ => None,
    })
}

/// [`stepped_sine`] with `progress` called on every point.
pub fn stepped_sine_with_progress(
    sys: &HbSystem,
    omegas: &[f64],
    scale: f64,
    stability: bool,
    progress: &mut dyn FnMut(&SolutionPoint),
) -> Result<ContinuationReport> {
    let Some(&first) = omegas.first() else {
        return Err(Error::invalid("stepped sine", "no frequency"));
    };
    // The sweep's span: ripples are judged on it, as in a continuation over the range.
    let (lo, hi) = omegas
        .iter()
        .fold((first, first), |(a, b), &w| (a.min(w), b.max(w)));
    let span = (hi - lo).max(f64::MIN_POSITIVE);
    let mut x = match sys.solve_from_rest(first, scale)? {
        (x, rep) if rep.converged() => x,
        _ => sys.linear_guess(first, scale),
    };
    let mut prev = first;
    let mut ws = sys.workspace(64 << 20);
    let mut solve = |w: f64, start: &[f64]| -> Result<(Vec<f64>, NewtonReport)> {
        let mut xs = start.to_vec();
        let rep = sys.solve_with(&mut ws, w, scale, &mut xs)?;
        Ok((xs, rep))
    };
    let mut points: Vec<SolutionPoint> = Vec::with_capacity(omegas.len());
    let mut stats = ContinuationStats::default();
    let mut skipped = Vec::new();
    let accept = |x: &[f64], om: f64| -> Result<Option<Option<Stability>>> {
        if !stability {
            return Ok(Some(None));
        }
        let st = sys.stability(x, om)?;
        Ok(st.stable.then_some(Some(st)))
    };
    for &om in omegas {
        // Newton from the last solution, in sub-steps when needed.
        let mut direct: Option<(Vec<f64>, usize)> = None;
        let mut sub = 1usize;
        while sub <= 16 && direct.is_none() {
            let mut xt = x.clone();
            let mut iterations = None;
            for i in 1..=sub {
                let w = prev + (om - prev) * i as f64 / sub as f64;
                match solve(w, &xt) {
                    Ok((xs, r)) if r.converged() => {
                        xt = xs;
                        iterations = Some(r.iterations);
                    }
                    _ => {
                        stats.n_rejected += 1;
                        iterations = None;
                        break;
                    }
                }
            }
            if let Some(it) = iterations {
                direct = Some((xt, it));
            }
            sub *= 2;
        }
        // Is it the branch of the last point? Checked by continuation across the step when
        // Newton failed or landed off the tangent prediction.
        let suspect = !points.is_empty()
            && match &direct {
                None => true,
                Some((xn, _)) => match sys.dx_domega(&x, prev, scale) {
                    Ok(t) => {
                        let off: f64 = xn
                            .iter()
                            .zip(x.iter().zip(&t))
                            .map(|(a, (b, d))| (a - b - d * (om - prev)).powi(2))
                            .sum();
                        let step: f64 = xn.iter().zip(&x).map(|(a, b)| (a - b).powi(2)).sum();
                        off > 0.25 * step && step > (1e-3 * norm_inf(xn)).powi(2)
                    }
                    Err(_) => true,
                },
            };
        let mut left = false;
        let on_branch = if suspect {
            match follow_across(sys, prev, om, scale, &x, span)? {
                Across::Reached(xc, it) => Some((xc, it)),
                Across::Folded => {
                    left = true;
                    None
                }
                Across::Failed => {
                    stats.n_unverified += 1;
                    direct.clone()
                }
            }
        } else {
            direct.clone()
        };
        let mut found = None;
        let mut fallback = None;
        if let Some((xc, it)) = on_branch {
            match accept(&xc, om)? {
                Some(st) => found = Some((xc, it, st, PointKind::Regular)),
                None => {
                    // Unstable: a test cannot dwell there, the response leaves the branch.
                    left = true;
                    fallback = Some((xc, it, PointKind::Regular));
                }
            }
        }
        // Off the branch: the jump, to a solution from other starts.
        if found.is_none() {
            let kind = if left {
                PointKind::Jump
            } else {
                PointKind::Regular
            };
            let newton = direct.filter(|_| left).map(|(xn, _)| xn);
            let starts = newton
                .into_iter()
                .chain(std::iter::once(sys.linear_guess(om, scale)))
                .chain(
                    [0.5, 2.0, 0.25, 4.0, 0.1, 10.0]
                        .iter()
                        .map(|f| x.iter().map(|v| v * f).collect()),
                );
            for start in starts {
                if let Ok((xs, r)) = solve(om, &start)
                    && r.converged()
                {
                    match accept(&xs, om)? {
                        Some(st) => {
                            found = Some((xs, r.iterations, st, kind));
                            break;
                        }
                        None => {
                            fallback.get_or_insert((xs, r.iterations, kind));
                        }
                    }
                }
            }
            if found.is_none()
                && fallback.is_none()
                && let Some((xs, it)) = by_force_level(sys, om, scale)?
            {
                match accept(&xs, om)? {
                    Some(st) => found = Some((xs, it, st, kind)),
                    None => fallback = Some((xs, it, kind)),
                }
            }
        }
        // No stable solution anywhere: keep the converged one, flagged unstable, rather than
        // lose the point.
        if found.is_none()
            && let Some((xs, it, kind)) = fallback
        {
            let st = sys.stability(&xs, om)?;
            found = Some((xs, it, Some(st), kind));
        }
        let Some((xn, iterations, st, kind)) = found else {
            skipped.push(om);
            continue;
        };
        x = xn;
        prev = om;
        let p = SolutionPoint {
            omega: om,
            scale,
            stability: st,
            x: x.clone(),
            kind,
            iterations,
        };
        stats.n_points += 1;
        stats.n_newton += p.iterations;
        progress(&p);
        points.push(p);
    }
    Ok(ContinuationReport {
        status: Status::Converged,
        branch: Branch {
            parameter: Parameter::Frequency,
            points,
            branch_points: Vec::new(),
            bifurcations: Vec::new(),
        },
        stats,
        detail: String::new(),
        skipped,
    })
}

/// A response maximum of one sensor and harmonic along a branch, located between the
/// computed points.
#[derive(Debug, Clone)]
pub struct Peak {
    /// Sensor index (into [`HbSystem::sensors`]).
    pub sensor: usize,
    /// Harmonic index `k` of the base `Ω/ν`.
    pub harmonic: usize,
    /// Index of the largest computed point.
    pub near: usize,
    /// Fundamental frequency `Ω` at the maximum (rad/s).
    pub omega: f64,
    /// Force level `λ` at the maximum.
    pub scale: f64,
    /// `|Y_k|` at the maximum (the sensor's unit).
    pub value: f64,
    /// Condensed unknowns at the maximum.
    pub x: Vec<f64>,
    /// `true` when located between the neighbours of the largest computed point; `false`
    /// when that point is an end of the branch (the maximum may lie outside the range) or
    /// the location failed — then the values are the computed point's.
    pub located: bool,
}

/// Locates, for every sensor and harmonic of `sys` carrying response along `branch` (its
/// largest `|Y_k|` above `1e-9` of the sensor's largest harmonic), the maximum of `|Y_k|`
/// along the branch: between the neighbours `i ± 1` of the largest computed point `i`, the
/// branch is parametrised by the hyperplanes normal to the chord `y_{i+1} − y_{i−1}` (in the
/// scaled variables of `cfg`, which must be the configuration the branch was computed
/// with), each point solved by the continuation's corrector, and `|Y_k|` is maximised along
/// it by Brent's method (parabolic steps with golden-section safeguards) to `1e-9` of the
/// chord. Since `|Y_k|` is quadratic at its maximum, the located value is as accurate as the
/// solution of `R = 0` (tolerance [`crate::HbConfig::rtol`]). `y` holds the sensor
/// responses of the points ([`HbSystem::sensor_response`]), computed once by the caller.
pub fn locate_peaks(
    sys: &HbSystem,
    cfg: &ContinuationConfig,
    branch: &Branch,
    y: &[Mat<faer::c64>],
) -> Vec<Peak> {
    let n_pts = branch.points.len().min(y.len());
    if n_pts == 0 {
        return Vec::new();
    }
    let nk = sys.harmonics().h + 1;
    let tr = Tracker::for_branch(sys, cfg, branch);
    let scaled = |p: &SolutionPoint| tr.scaled(p);
    let mut out = Vec::new();
    for s in 0..sys.sensors().len() {
        let top = (0..nk)
            .flat_map(|k| y.iter().map(move |m| m[(s, k)].norm()))
            .fold(0.0f64, f64::max);
        for k in 0..nk {
            let (i, v) = y
                .iter()
                .enumerate()
                .map(|(i, m)| (i, m[(s, k)].norm()))
                .fold((0, 0.0f64), |a, b| if b.1 > a.1 { b } else { a });
            if !(v > 0.0 && v > 1e-9 * top) {
                continue;
            }
            let p = &branch.points[i];
            let mut peak = Peak {
                sensor: s,
                harmonic: k,
                near: i,
                omega: p.omega,
                scale: p.scale,
                value: v,
                x: p.x.clone(),
                located: false,
            };
            if i > 0 && i + 1 < n_pts {
                let (a, c) = (scaled(&branch.points[i - 1]), scaled(&branch.points[i + 1]));
                let b = scaled(p);
                let chord: Vec<f64> = c.iter().zip(&a).map(|(c, a)| c - a).collect();
                let len = chord.iter().map(|v| v * v).sum::<f64>().sqrt();
                if len > 0.0 {
                    let d: Vec<f64> = chord.iter().map(|v| v / len).collect();
                    let at = |t: f64| -> Option<(f64, Vec<f64>, f64, f64)> {
                        let (x, om, sc) = tr.on_chord(&a, &d, t * len)?;
                        let val = sys.sensor_response(&x, om, sc)[(s, k)].norm();
                        val.is_finite().then_some((val, x, om, sc))
                    };
                    let tb = (0..b.len()).map(|j| (b[j] - a[j]) * d[j]).sum::<f64>() / len;
                    let mut best: Option<(f64, Vec<f64>, f64, f64)> = None;
                    let mut failed = false;
                    let mut f = |t: f64| -> f64 {
                        match at(t) {
                            Some(r) => {
                                let val = r.0;
                                if best.as_ref().is_none_or(|b| val > b.0) {
                                    best = Some(r);
                                }
                                -val
                            }
                            None => {
                                failed = true;
                                0.0
                            }
                        }
                    };
                    brent_min(&mut f, 0.0, tb.clamp(1e-3, 1.0 - 1e-3), 1.0, 1e-9);
                    if let Some((val, x, om, sc)) = best
                        && !failed
                        && val >= v
                    {
                        peak.value = val;
                        peak.x = x;
                        peak.omega = om;
                        peak.scale = sc;
                        peak.located = true;
                    }
                }
            }
            out.push(peak);
        }
    }
    out
}

/// Brent's minimisation of `f` on `[a, b]` from the interior point `x0`, to an absolute
/// tolerance `tol` on the abscissa (parabolic interpolation, golden-section safeguard).
fn brent_min(f: &mut dyn FnMut(f64) -> f64, a: f64, x0: f64, b: f64, tol: f64) -> f64 {
    const GOLD: f64 = 0.381_966_011_250_105_1;
    let (mut a, mut b) = (a, b);
    let (mut x, mut w, mut v) = (x0, x0, x0);
    let fx0 = f(x0);
    let (mut fx, mut fw, mut fv) = (fx0, fx0, fx0);
    let (mut d, mut e) = (0.0f64, 0.0f64);
    for _ in 0..100 {
        let m = 0.5 * (a + b);
        let tol1 = tol + 1e-12 * x.abs();
        let tol2 = 2.0 * tol1;
        if (x - m).abs() <= tol2 - 0.5 * (b - a) {
            break;
        }
        let mut golden = true;
        if e.abs() > tol1 {
            let r = (x - w) * (fx - fv);
            let q = (x - v) * (fx - fw);
            let mut p = (x - v) * q - (x - w) * r;
            let mut q = 2.0 * (q - r);
            if q > 0.0 {
                p = -p;
            }
            q = q.abs();
            if p.abs() < (0.5 * q * e).abs() && p > q * (a - x) && p < q * (b - x) {
                e = d;
                d = p / q;
                let u = x + d;
                if u - a < tol2 || b - u < tol2 {
                    d = if x < m { tol1 } else { -tol1 };
                }
                golden = false;
            }
        }
        if golden {
            e = if x < m { b - x } else { a - x };
            d = GOLD * e;
        }
        let u = if d.abs() >= tol1 {
            x + d
        } else {
            x + tol1.copysign(d)
        };
        let fu = f(u);
        if fu <= fx {
            if u < x {
                b = x;
            } else {
                a = x;
            }
            (v, fv, w, fw, x, fx) = (w, fw, x, fx, u, fu);
        } else {
            if u < x {
                a = u;
            } else {
                b = u;
            }
            if fu <= fw || w == x {
                (v, fv, w, fw) = (w, fw, u, fu);
            } else if fu <= fv || v == x || v == w {
                (v, fv) = (u, fu);
            }
        }
    }
    x
}

/// Follows the branch through the converged solution `x` at parameter `p0` (rad/s or level,
/// inside the range of `cfg`) to both ends of the range: one leg from `p0` towards `cfg.to`
/// and one towards `cfg.from`, each continued from its last point towards the other end when
/// the branch turns back inside the range (the fold of an isolated sub-harmonic branch).
/// The points come in order along the branch, from the `cfg.to` side (steps scaled so that
/// each leg keeps `cfg`'s steps in the parameter). The status is the first leg's that
/// stopped short (its detail kept), else converged.
pub fn continuation_through(
    sys: &HbSystem,
    cfg: &ContinuationConfig,
    p0: f64,
    x: &[f64],
    progress: &mut dyn FnMut(&SolutionPoint),
) -> Result<ContinuationReport> {
    if !(p0 - cfg.from).is_finite() || (p0 - cfg.from) * (cfg.to - p0) < 0.0 {
        return Err(Error::invalid(
            "continuation start",
            format!(
                "the start parameter {p0} is outside the range {} to {}",
                cfg.from, cfg.to
            ),
        ));
    }
    let span = (cfg.to - cfg.from).abs();
    let param = |p: &SolutionPoint| match cfg.parameter {
        Parameter::Frequency => p.omega,
        Parameter::ForceLevel => p.scale,
    };
    // A leg from `a` (with its start `xa`) towards `b`; `None` when `a` is `b`.
    let mut leg = |a: f64, b: f64, xa: &[f64]| -> Result<Option<ContinuationReport>> {
        let width = (b - a).abs();
        if width <= 1e-9 * span {
            return Ok(None);
        }
        let f = (span / width).min(1e6);
        let mut c = cfg.clone();
        c.from = a;
        c.to = b;
        c.ds = (cfg.ds * f).min(0.5);
        c.ds_max = (cfg.ds_max * f).min(0.5).max(c.ds);
        c.ds_min = (cfg.ds_min * f).min(c.ds);
        // Labelled once, on the assembled branch.
        follow_smoothed(sys, &c, Some(xa), progress).map(Some)
    };
    let turned = |r: &ContinuationReport| {
        r.status.is_converged()
            && r.branch
                .points
                .last()
                .is_some_and(|p| p.kind != PointKind::End)
    };
    let mut legs: Vec<(ContinuationReport, bool)> = Vec::new(); // (leg, reversed)
    let up = leg(p0, cfg.to, x)?;
    let mut up_more = None;
    if let Some(r) = &up
        && turned(r)
        && let Some(last) = r.branch.points.last()
    {
        up_more = leg(param(last), cfg.from, &last.x.clone())?;
    }
    let down = leg(p0, cfg.from, x)?;
    let mut down_more = None;
    if let Some(r) = &down
        && turned(r)
        && let Some(last) = r.branch.points.last()
    {
        down_more = leg(param(last), cfg.to, &last.x.clone())?;
    }
    if let Some(r) = up_more {
        legs.push((r, true));
    }
    if let Some(r) = up {
        legs.push((r, true));
    }
    if let Some(r) = down {
        legs.push((r, false));
    }
    if let Some(r) = down_more {
        legs.push((r, false));
    }
    let mut branch = Branch {
        parameter: cfg.parameter,
        points: Vec::new(),
        branch_points: Vec::new(),
        bifurcations: Vec::new(),
    };
    let mut stats = ContinuationStats::default();
    let mut status = Status::Converged;
    let mut detail = String::new();
    for (r, reversed) in legs {
        stats.n_rejected += r.stats.n_rejected;
        stats.n_wiggles += r.stats.n_wiggles;
        if status.is_converged() && !r.status.is_converged() {
            status = r.status;
            detail = r.detail.clone();
        }
        let n = r.branch.points.len();
        let skip = usize::from(!branch.points.is_empty());
        let offset = branch.points.len();
        // Every leg after the first starts where the assembled branch ends: skip that point.
        let order: Vec<usize> = if reversed {
            (0..n).rev().skip(skip).collect()
        } else {
            (skip..n).collect()
        };
        for &i in &order {
            let p = r.branch.points[i].clone();
            stats.n_points += 1;
            stats.n_newton += p.iterations;
            branch.points.push(p);
        }
        for bp in &r.branch.branch_points {
            let (i, j) = bp.between;
            let map = |k: usize| -> Option<usize> {
                order.iter().position(|&o| o == k).map(|pos| offset + pos)
            };
            if let (Some(a), Some(b)) = (map(i), map(j)) {
                branch.branch_points.push(BranchPoint {
                    between: (a.min(b), a.max(b)),
                    ..*bp
                });
            }
        }
    }
    if cfg.stability {
        branch.bifurcations = label_bifurcations(sys, cfg, &branch)?;
    }
    Ok(ContinuationReport {
        status,
        branch,
        stats,
        detail,
        skipped: Vec::new(),
    })
}

/// Classes of Floquet exponents by their imaginary part (band `|Im s| ≤ ω0/2`): real
/// (multiplier real positive), on the band edge (real negative), complex. Per class, the
/// number with a real part above the stability threshold `1e-6 ω0` and the largest real
/// part (`−∞` for an empty class), whose zero is the bifurcation.
fn exponent_classes(st: &Stability, w0: f64) -> [(usize, f64); 3] {
    let tol = 1e-6 * w0;
    let mut out = [(0usize, f64::NEG_INFINITY); 3];
    for s in &st.exponents {
        let im = s.im.abs();
        let c = if im <= 1e-6 * w0 {
            0
        } else if (im - 0.5 * w0).abs() <= crate::stability::EDGE * w0 {
            1
        } else {
            2
        };
        out[c].0 += usize::from(s.re > tol);
        out[c].1 = out[c].1.max(s.re);
    }
    out
}

/// The function whose zero locates a change of class `class` ([`exponent_classes`]): the
/// class's largest real part, except for the band edge, where the window `|Im s| ≥ 0.45 ω0`
/// is used: a complex pair near `−1` that collides on the negative real axis and leaves the
/// unit circle through `−1` between two points has no edge exponent at one of them, and
/// the largest real part over the window is continuous through the collision.
fn class_locator(st: &Stability, w0: f64, class: usize) -> f64 {
    if class != 1 {
        return exponent_classes(st, w0)[class].1;
    }
    st.exponents
        .iter()
        .filter(|s| s.im.abs() >= 0.45 * w0)
        .fold(f64::NEG_INFINITY, |m, s| m.max(s.re))
}

/// Labels the bifurcations of `branch` (computed with stability under `cfg`): every fold
/// point, and between successive points every change in the number of unstable exponents
/// of a class — real ones away from a fold (a branch point), ones on the band edge `ω0/2`
/// (period doubling), complex ones (Neimark–Sacker) — located where the largest real part
/// of that class crosses zero, by the Illinois method along the chord
/// between the two points (each point solved by the corrector, its exponents by Hill's
/// method); linearly interpolated when the corrector fails or the class changes on the way.
pub fn label_bifurcations(
    sys: &HbSystem,
    cfg: &ContinuationConfig,
    branch: &Branch,
) -> Result<Vec<Bifurcation>> {
    let pts = &branch.points;
    let mut out = Vec::new();
    let tr = Tracker::for_branch(sys, cfg, branch);
    let scaled = |p: &SolutionPoint| tr.scaled(p);
    for (i, p) in pts.iter().enumerate() {
        if p.kind == PointKind::Fold {
            out.push(Bifurcation {
                kind: BifurcationKind::Fold,
                between: (i.saturating_sub(1), (i + 1).min(pts.len() - 1)),
                omega: p.omega,
                scale: p.scale,
                x: p.x.clone(),
                located: true,
            });
        }
    }
    for i in 0..pts.len().saturating_sub(1) {
        let (a, b) = (&pts[i], &pts[i + 1]);
        let (Some(sa), Some(sb)) = (&a.stability, &b.stability) else {
            continue;
        };
        let (wa, wb) = (sys.set.base(a.omega), sys.set.base(b.omega));
        let (ca, cb) = (exponent_classes(sa, wa), exponent_classes(sb, wb));
        let near_fold = [a.kind, b.kind].contains(&PointKind::Fold);
        for (class, kind) in [
            (0, BifurcationKind::BranchPoint),
            (1, BifurcationKind::PeriodDoubling),
            (2, BifurcationKind::NeimarkSacker),
        ] {
            if ca[class].0 == cb[class].0 || (class == 0 && near_fold) {
                continue;
            }
            let (ya, yb) = (scaled(a), scaled(b));
            let chord: Vec<f64> = yb.iter().zip(&ya).map(|(b, a)| b - a).collect();
            let len = chord.iter().map(|v| v * v).sum::<f64>().sqrt();
            let lin = |t: f64| -> Bifurcation {
                Bifurcation {
                    kind,
                    between: (i, i + 1),
                    omega: a.omega + t * (b.omega - a.omega),
                    scale: a.scale + t * (b.scale - a.scale),
                    x: a.x.iter().zip(&b.x).map(|(u, v)| u + t * (v - u)).collect(),
                    located: false,
                }
            };
            let (fa, fb) = (class_locator(sa, wa, class), class_locator(sb, wb, class));
            let t_lin = if fa.is_finite() && fb.is_finite() && fa != fb {
                (fa / (fa - fb)).clamp(0.0, 1.0)
            } else {
                0.5
            };
            if !(len > 0.0 && fa.is_finite() && fb.is_finite() && fa * fb < 0.0) {
                out.push(lin(t_lin));
                continue;
            }
            let d: Vec<f64> = chord.iter().map(|v| v / len).collect();
            let at = |t: f64| -> Option<(f64, Vec<f64>, f64, f64)> {
                let (x, om, sc) = tr.on_chord(&ya, &d, t * len)?;
                let st = sys.stability(&x, om).ok()?;
                let f = class_locator(&st, sys.set.base(om), class);
                f.is_finite().then_some((f, x, om, sc))
            };
            let (mut lo, mut flo, mut hi, mut fhi) = (0.0, fa, 1.0, fb);
            let mut best = None;
            let mut side = 0;
            for _ in 0..60 {
                if hi - lo <= 1e-10 {
                    break;
                }
                let t = (lo * fhi - hi * flo) / (fhi - flo);
                let Some((f, x, om, sc)) = at(t) else {
                    best = None;
                    break;
                };
                best = Some((x, om, sc));
                if f == 0.0 {
                    break;
                }
                if f.signum() == fhi.signum() {
                    (hi, fhi) = (t, f);
                    if side == -1 {
                        flo *= 0.5;
                    }
                    side = -1;
                } else {
                    (lo, flo) = (t, f);
                    if side == 1 {
                        fhi *= 0.5;
                    }
                    side = 1;
                }
            }
            out.push(match best {
                Some((x, omega, scale)) => Bifurcation {
                    kind,
                    between: (i, i + 1),
                    omega,
                    scale,
                    x,
                    located: true,
                },
                None => lin(t_lin),
            });
        }
    }
    out.sort_by_key(|b| b.between);
    Ok(out)
}
