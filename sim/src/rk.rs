//! Runge–Kutta references on the same diagonal system the hold integrator uses:
//! `ż = Λ z + b̃ u(t)`, with the element forces solved from the port responses at every
//! stage (`f = g(y(z) − D f)`, a loop only when the residual flexibility couples them).
//!
//! - [`rk45`]: Dormand–Prince 5(4) with MATLAB ODE45's error control (mixed test
//!   `|e_i| ≤ max(rtol·|y_i|, atol)` in the max norm, step factor `0.8 err^{−1/5}` within
//!   `[0.1, 5]`, max step a tenth of the span), and its free 4th-order dense output for the
//!   samples. The defaults are ODE45's (`rtol 1e-3`, `atol 1e-6`). `atol` applies to the
//!   diagonal states (about the modal displacement in √kg m): when the response is smaller
//!   than `atol` the defaults are off by tens of percent, so scale it to the response.
//! - [`rk4`]: classic fixed-step fourth order.
//!
//! The force signals are evaluated at the exact stage times (no hold).

use crate::feedback::{Feedback, NewtonConfig};
use crate::foh::loop_error;
use crate::history::{LoadCase, Progress, RunStats, Series, TimeHistory, add_residual_rates};
use crate::plant::{Plant, Responses};
use faer::c64;
use nlsim_kernel::{Error, Result, Status};

/// Settings of [`rk45`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rk45Config {
    /// Relative tolerance (ODE45 default 1e-3).
    pub rtol: f64,
    /// Absolute tolerance on the diagonal states (ODE45 default 1e-6).
    pub atol: f64,
    /// Largest step (s); `None` for a tenth of the time span (ODE45's default).
    pub max_step: Option<f64>,
    /// Step limit, after which the run fails.
    pub max_steps: usize,
    /// Newton settings of the element loop.
    pub newton: NewtonConfig,
}

impl Default for Rk45Config {
    fn default() -> Self {
        Rk45Config {
            rtol: 1e-3,
            atol: 1e-6,
            max_step: None,
            max_steps: 100_000_000,
            newton: NewtonConfig::default(),
        }
    }
}

/// Settings of [`rk4`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rk4Config {
    /// RK4 steps per sample interval.
    pub substeps: usize,
    /// Newton settings of the element loop.
    pub newton: NewtonConfig,
}

impl Default for Rk4Config {
    fn default() -> Self {
        Rk4Config {
            substeps: 1,
            newton: NewtonConfig::default(),
        }
    }
}

/// The right-hand side and the sampled outputs.
struct Rhs<'a> {
    plant: &'a Plant,
    elements: Vec<crate::plant::ElementPort>,
    case: &'a LoadCase,
    resp: Responses,
    /// `b̃` column of each loop port (excitation inputs, then elements), contiguous.
    input_cols: Vec<Vec<c64>>,
    fb: Feedback,
    f: Vec<f64>,
    u: Vec<f64>,
    dp: Vec<f64>,
    vp: Vec<f64>,
    states: Vec<Vec<f64>>,
    newton: NewtonConfig,
    iterations: usize,
    max_iterations: usize,
    evaluations: usize,
}

impl<'a> Rhs<'a> {
    fn new(
        plant: &'a Plant,
        elements: Vec<crate::plant::ElementPort>,
        case: &'a LoadCase,
        newton: NewtonConfig,
    ) -> Self {
        let nn = plant.elements.len();
        let resp = Responses::new(plant);
        let sys = &plant.system;
        let input_cols = resp
            .ports
            .iter()
            .map(|&p| (0..sys.n_states()).map(|s| sys.input[(s, p)]).collect())
            .collect();
        Rhs {
            input_cols,
            plant,
            elements,
            case,
            u: vec![0.0; resp.ports.len()],
            resp,
            fb: Feedback::new(plant),
            f: vec![0.0; nn],
            dp: vec![0.0; nn],
            vp: vec![0.0; nn],
            states: plant
                .elements
                .iter()
                .map(|e| vec![0.0; e.element.law().n_states()])
                .collect(),
            newton,
            iterations: 0,
            max_iterations: 0,
            evaluations: 0,
        }
    }

    /// Solves the element loop at `(t, z)`; leaves the port forces in `self.u`.
    fn forces(&mut self, t: f64, z: &[c64]) -> Result<()> {
        let ne = self.plant.inputs.len();
        let nn = self.plant.elements.len();
        for q in 0..ne {
            self.u[q] = self.case.forces[q].eval(t);
        }
        for i in 0..nn {
            self.dp[i] = self.resp.modal(i, z) + self.resp.feed_ext(i, &self.u);
            self.vp[i] = self.resp.modal(nn + i, z) + self.resp.feed_ext(nn + i, &self.u);
        }
        let it = self
            .fb
            .solve(
                &self.elements,
                &self.states,
                &self.dp,
                &self.vp,
                &self.resp.sd0,
                &self.resp.sv0,
                &mut self.f,
                &self.newton,
            )
            .map_err(|e| loop_error(e, &self.elements, usize::MAX, t))?;
        self.iterations += it;
        self.max_iterations = self.max_iterations.max(it);
        for i in 0..nn {
            self.u[ne + i] = -self.f[i];
        }
        Ok(())
    }

    /// `dz = Λ z + b̃ u(t, z)`.
    fn eval(&mut self, t: f64, z: &[c64], dz: &mut [c64]) -> Result<()> {
        self.evaluations += 1;
        self.forces(t, z)?;
        for ((d, p), z) in dz.iter_mut().zip(&self.plant.system.poles).zip(z) {
            *d = p * z;
        }
        for (col, &u) in self.input_cols.iter().zip(&self.u) {
            for (d, b) in dz.iter_mut().zip(col) {
                *d += b * u;
            }
        }
        Ok(())
    }

    /// Writes sample `k` at `(t, z)` and commits element history.
    fn sample(&mut self, k: usize, t: f64, z: &[c64], rec: &mut Record) -> Result<()> {
        self.forces(t, z)?;
        let ne = self.plant.inputs.len();
        let nn = self.plant.elements.len();
        for q in 0..ne {
            rec.inputs[q][k] = self.u[q];
        }
        for i in 0..nn {
            rec.f[i][k] = self.f[i];
            rec.d[i][k] = self.fb.last_d[i];
            rec.v[i][k] = self.fb.last_v[i];
            let (d, v) = (self.fb.last_d[i], self.fb.last_v[i]);
            self.elements[i]
                .element
                .law()
                .commit_state(d, v, &mut self.states[i]);
        }
        for o in 0..self.plant.outputs.len() {
            let r = 2 * nn + o;
            rec.out[o][k] = self.resp.modal(r, z) + self.resp.feed(r, &self.u);
        }
        Ok(())
    }
}

struct Record {
    inputs: Vec<Vec<f64>>,
    f: Vec<Vec<f64>>,
    d: Vec<Vec<f64>>,
    v: Vec<Vec<f64>>,
    out: Vec<Vec<f64>>,
}

impl Record {
    fn new(plant: &Plant, n: usize) -> Self {
        let nn = plant.elements.len();
        Record {
            inputs: vec![vec![0.0; n]; plant.inputs.len()],
            f: vec![vec![0.0; n]; nn],
            d: vec![vec![0.0; n]; nn],
            v: vec![vec![0.0; n]; nn],
            out: vec![vec![0.0; n]; plant.outputs.len()],
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn finish(
        self,
        plant: &Plant,
        method: &str,
        case: &LoadCase,
        dt: f64,
        final_state: Vec<c64>,
        stats: RunStats,
        stop: Option<(Status, Error, usize)>,
    ) -> TimeHistory {
        let mut rec = self;
        let (status, stopped) = match stop {
            Some((st, err, samples)) => {
                for v in rec
                    .out
                    .iter_mut()
                    .chain(&mut rec.inputs)
                    .chain(&mut rec.d)
                    .chain(&mut rec.v)
                    .chain(&mut rec.f)
                {
                    v.truncate(samples);
                }
                (st, Some(err))
            }
            None => (Status::Converged, None),
        };
        let rec = rec;
        let mut h = TimeHistory {
            method: method.into(),
            case: case.name.clone(),
            dt,
            outputs: plant
                .outputs
                .iter()
                .zip(rec.out)
                .map(|(o, v)| Series {
                    name: o.name.clone(),
                    quantity: o.quantity,
                    values: v,
                })
                .collect(),
            inputs: plant
                .inputs
                .iter()
                .map(|(n, _)| n.clone())
                .zip(rec.inputs)
                .collect(),
            element_names: plant
                .elements
                .iter()
                .map(crate::plant::ElementPort::coordinate_name)
                .collect(),
            element_displacements: rec.d,
            element_velocities: rec.v,
            element_forces: rec.f,
            final_state,
            stats,
            status,
            stopped,
        };
        add_residual_rates(plant, &mut h);
        h
    }
}

fn check_grid(dt: f64) -> Result<()> {
    if !(dt > 0.0 && dt.is_finite()) {
        return Err(Error::invalid(
            "sample interval",
            format!("{dt} s must be positive and finite"),
        ));
    }
    Ok(())
}

// Dormand–Prince 5(4) coefficients.
const C: [f64; 7] = [0.0, 0.2, 0.3, 0.8, 8.0 / 9.0, 1.0, 1.0];
const A: [[f64; 6]; 7] = [
    [0.0; 6],
    [0.2, 0.0, 0.0, 0.0, 0.0, 0.0],
    [3.0 / 40.0, 9.0 / 40.0, 0.0, 0.0, 0.0, 0.0],
    [44.0 / 45.0, -56.0 / 15.0, 32.0 / 9.0, 0.0, 0.0, 0.0],
    [
        19372.0 / 6561.0,
        -25360.0 / 2187.0,
        64448.0 / 6561.0,
        -212.0 / 729.0,
        0.0,
        0.0,
    ],
    [
        9017.0 / 3168.0,
        -355.0 / 33.0,
        46732.0 / 5247.0,
        49.0 / 176.0,
        -5103.0 / 18656.0,
        0.0,
    ],
    [
        35.0 / 384.0,
        0.0,
        500.0 / 1113.0,
        125.0 / 192.0,
        -2187.0 / 6784.0,
        11.0 / 84.0,
    ],
];
/// Error weights `b − b̂`.
const E: [f64; 7] = [
    71.0 / 57600.0,
    0.0,
    -71.0 / 16695.0,
    71.0 / 1920.0,
    -17253.0 / 339200.0,
    22.0 / 525.0,
    -1.0 / 40.0,
];
/// Dense output weights.
const D: [f64; 7] = [
    -12715105075.0 / 11282082432.0,
    0.0,
    87487479700.0 / 32700410799.0,
    -10690763975.0 / 1880347072.0,
    701980252875.0 / 199316789632.0,
    -1453857185.0 / 822651844.0,
    69997945.0 / 29380423.0,
];

/// `y += c x`, skipped when `c = 0` (the tableau's zeros).
fn axpy(y: &mut [c64], c: f64, x: &[c64]) {
    if c != 0.0 {
        for (y, x) in y.iter_mut().zip(x) {
            *y += x * c;
        }
    }
}

/// Dormand–Prince RK45 on the plant's diagonal system, sampled every `dt` for `n_steps`
/// intervals. `stats.steps`/`rejected_steps` count the adaptive steps.
pub fn rk45(
    plant: &Plant,
    case: &LoadCase,
    dt: f64,
    n_steps: usize,
    cfg: &Rk45Config,
) -> Result<TimeHistory> {
    rk45_with_progress(plant, case, dt, n_steps, cfg, &mut |_, _| {})
}

/// As [`rk45`], calling `progress(samples done, n_steps)` about 200 times.
pub fn rk45_with_progress(
    plant: &Plant,
    case: &LoadCase,
    dt: f64,
    n_steps: usize,
    cfg: &Rk45Config,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<TimeHistory> {
    check_grid(dt)?;
    if !(cfg.rtol > 0.0 && cfg.atol > 0.0) {
        return Err(Error::invalid(
            "RK45 tolerances",
            format!("rtol {} and atol {} must be positive", cfg.rtol, cfg.atol),
        ));
    }
    let start = std::time::Instant::now();
    let (z0, elements) = case.prepare(plant)?;
    let ns = plant.n_states();
    let n = n_steps + 1;
    let t_end = n_steps as f64 * dt;
    let hmax = cfg.max_step.unwrap_or(0.1 * t_end).max(1e-300);
    let mut rhs = Rhs::new(plant, elements, case, cfg.newton);
    let mut rec = Record::new(plant, n);
    let mut stats = RunStats::default();
    let mut z = z0;
    rhs.sample(0, 0.0, &z, &mut rec)?;
    let mut k = vec![vec![c64::new(0.0, 0.0); ns]; 7];
    let mut ytmp = vec![c64::new(0.0, 0.0); ns];
    let mut ynew = vec![c64::new(0.0, 0.0); ns];
    // The error estimate, then the dense-output term `h Σ_j d_j k_j`.
    let mut evec = vec![c64::new(0.0, 0.0); ns];
    let mut t = 0.0;
    rhs.eval(t, &z, &mut k[0])?;
    // ODE45's initial step.
    let threshold = cfg.atol / cfg.rtol;
    let rh = z
        .iter()
        .zip(&k[0])
        .map(|(y, f)| {
            (f.re.abs() / y.re.abs().max(threshold)).max(f.im.abs() / y.im.abs().max(threshold))
        })
        .fold(0.0, f64::max)
        / (0.8 * cfg.rtol.powf(0.2));
    let mut h = hmax;
    if h * rh > 1.0 {
        h = 1.0 / rh;
    }
    let mut progress = Progress::new(progress, n_steps);
    let mut next = 1;
    let mut stop: Option<(Status, Error, usize)> = None;
    while next < n {
        if stats.steps + stats.rejected_steps >= cfg.max_steps {
            let err = Error::Numerical {
                what: format!("RK45 at t = {t:.6e} s"),
                detail: format!(
                    "step limit {} reached (step {h:.3e} s); the problem is stiff for an explicit \
                     method or the tolerances are too tight",
                    cfg.max_steps
                ),
            };
            stop = Some((Status::IterationLimit, err, next));
            break;
        }
        let hmin = 16.0 * f64::EPSILON * t.abs().max(1e-300);
        h = h.min(hmax).min(t_end - t).max(hmin);
        let mut stage_failed = None;
        for st in 1..7 {
            // ytmp = z + h Σ_j a_j k_j, one contiguous pass per stage (vectorised).
            ytmp.copy_from_slice(&z);
            for (j, kj) in k.iter().enumerate().take(st) {
                axpy(&mut ytmp, h * A[st][j], kj);
            }
            let tt = t + C[st] * h;
            let (_, tail) = k.split_at_mut(st);
            // A trial step far too long can drive a stage so far out that the element loop
            // has no solution nearby: that is a rejected step, not a failed run.
            if let Err(e) = rhs.eval(tt, &ytmp, &mut tail[0]) {
                stage_failed = Some(e);
                break;
            }
            if st == 6 {
                ynew.copy_from_slice(&ytmp);
            }
        }
        if let Some(e) = stage_failed {
            stats.rejected_steps += 1;
            if h <= hmin {
                stop = Some((Status::StepTooSmall, e, next));
                break;
            }
            h *= 0.25;
            continue;
        }
        // Error estimate, ODE45's mixed test in the max norm.
        evec.iter_mut().for_each(|e| *e = c64::new(0.0, 0.0));
        for (j, kj) in k.iter().enumerate() {
            axpy(&mut evec, h * E[j], kj);
        }
        let mut err = 0.0f64;
        for s in 0..ns {
            let e = evec[s];
            let sc_re = (cfg.rtol * z[s].re.abs().max(ynew[s].re.abs())).max(cfg.atol);
            let sc_im = (cfg.rtol * z[s].im.abs().max(ynew[s].im.abs())).max(cfg.atol);
            err = err.max(e.re.abs() / sc_re).max(e.im.abs() / sc_im);
        }
        if !err.is_finite() {
            let err = Error::Numerical {
                what: format!("RK45 at t = {t:.6e} s"),
                detail: "the error estimate is not finite: the run diverged".into(),
            };
            stop = Some((Status::NonFinite, err, next));
            break;
        }
        if err > 1.0 {
            stats.rejected_steps += 1;
            if h <= hmin {
                let err = Error::Numerical {
                    what: format!("RK45 at t = {t:.6e} s"),
                    detail: "the step fell below the round-off limit".into(),
                };
                stop = Some((Status::StepTooSmall, err, next));
                break;
            }
            h *= (0.8 * err.powf(-0.2)).max(0.1);
            continue;
        }
        stats.steps += 1;
        let t_new = t + h;
        // Samples inside (t, t_new]: 4th-order dense output.
        while next < n && (next as f64 * dt) <= t_new * (1.0 + 1e-14) {
            let ts = next as f64 * dt;
            let th = ((ts - t) / h).clamp(0.0, 1.0);
            evec.iter_mut().for_each(|e| *e = c64::new(0.0, 0.0));
            for (j, kj) in k.iter().enumerate() {
                axpy(&mut evec, h * D[j], kj);
            }
            for s in 0..ns {
                let r2 = ynew[s] - z[s];
                let r3 = k[0][s] * h - r2;
                let r4 = r2 - k[6][s] * h - r3;
                let r5 = evec[s];
                ytmp[s] = z[s] + (r2 + (r3 + (r4 + r5 * (1.0 - th)) * th) * (1.0 - th)) * th;
            }
            if let Err(e) = rhs.sample(next, ts, &ytmp, &mut rec) {
                stop = Some((Status::IterationLimit, e, next));
                break;
            }
            progress.tick(next);
            next += 1;
        }
        if stop.is_some() {
            break;
        }
        t = t_new;
        z.copy_from_slice(&ynew);
        // First-same-as-last.
        let (first, rest) = k.split_at_mut(1);
        first[0].copy_from_slice(&rest[5]);
        let grow = if err == 0.0 {
            5.0
        } else {
            (0.8 * err.powf(-0.2)).clamp(0.1, 5.0)
        };
        h *= grow;
    }
    stats.evaluations = rhs.evaluations;
    stats.newton_iterations = rhs.iterations;
    stats.max_newton_iterations = rhs.max_iterations;
    stats.seconds = start.elapsed().as_secs_f64();
    Ok(rec.finish(plant, "rk45", case, dt, z, stats, stop))
}

/// Classic fourth-order Runge–Kutta with `cfg.substeps` steps per sample interval `dt`.
pub fn rk4(
    plant: &Plant,
    case: &LoadCase,
    dt: f64,
    n_steps: usize,
    cfg: &Rk4Config,
) -> Result<TimeHistory> {
    rk4_with_progress(plant, case, dt, n_steps, cfg, &mut |_, _| {})
}

/// As [`rk4`], calling `progress(samples done, n_steps)` about 200 times.
pub fn rk4_with_progress(
    plant: &Plant,
    case: &LoadCase,
    dt: f64,
    n_steps: usize,
    cfg: &Rk4Config,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<TimeHistory> {
    check_grid(dt)?;
    if cfg.substeps == 0 {
        return Err(Error::invalid("RK4 substeps", "must be at least 1"));
    }
    let start = std::time::Instant::now();
    let h = dt / cfg.substeps as f64;
    // RK4's stability region reaches |λh| = 2√2 on the imaginary axis (and about 2.78 along
    // it for light damping): refuse a step beyond it rather than diverge.
    if let Some(l) = plant.system.poles.iter().find(|l| (**l * h).norm() > 2.78) {
        return Err(Error::invalid(
            "RK4 step",
            format!(
                "h = {h:.3e} s exceeds the stability limit 2.78/|λ| = {:.3e} s of the pole at                  {:.1} Hz; use more substeps or fewer modes",
                2.78 / l.norm(),
                l.norm() / (2.0 * std::f64::consts::PI)
            ),
        ));
    }
    let (z0, elements) = case.prepare(plant)?;
    let ns = plant.n_states();
    let n = n_steps + 1;
    let mut rhs = Rhs::new(plant, elements, case, cfg.newton);
    let mut rec = Record::new(plant, n);
    let mut stats = RunStats::default();
    let mut z = z0;
    rhs.sample(0, 0.0, &z, &mut rec)?;
    let mut k = vec![vec![c64::new(0.0, 0.0); ns]; 4];
    let mut y = vec![c64::new(0.0, 0.0); ns];
    let mut progress = Progress::new(progress, n_steps);
    let mut stop: Option<(Status, Error, usize)> = None;
    'steps: for step in 0..n_steps {
        let z_step = z.clone();
        for sub in 0..cfg.substeps {
            let t = step as f64 * dt + sub as f64 * h;
            let mut stages = || -> Result<()> {
                rhs.eval(t, &z, &mut k[0])?;
                for (st, (cf, tf)) in [(0.5, 0.5), (0.5, 0.5), (1.0, 1.0)].into_iter().enumerate() {
                    for s in 0..ns {
                        y[s] = z[s] + k[st][s] * (h * cf);
                    }
                    let (_, tail) = k.split_at_mut(st + 1);
                    rhs.eval(t + tf * h, &y, &mut tail[0])?;
                }
                Ok(())
            };
            if let Err(e) = stages() {
                z = z_step;
                stop = Some((Status::IterationLimit, e, step + 1));
                break 'steps;
            }
            for s in 0..ns {
                z[s] += (k[0][s] + (k[1][s] + k[2][s]) * 2.0 + k[3][s]) * (h / 6.0);
            }
            stats.steps += 1;
        }
        if z.iter().any(|v| !(v.re.is_finite() && v.im.is_finite())) {
            let err = Error::Numerical {
                what: format!(
                    "RK4 at step {} (t = {:.6e} s)",
                    step + 1,
                    (step + 1) as f64 * dt
                ),
                detail: "the state is not finite: the run diverged".into(),
            };
            z = z_step;
            stop = Some((Status::NonFinite, err, step + 1));
            break;
        }
        if let Err(e) = rhs.sample(step + 1, (step + 1) as f64 * dt, &z, &mut rec) {
            z = z_step;
            stop = Some((Status::IterationLimit, e, step + 1));
            break;
        }
        progress.tick(step + 1);
    }
    stats.evaluations = rhs.evaluations;
    stats.newton_iterations = rhs.iterations;
    stats.max_newton_iterations = rhs.max_iterations;
    stats.seconds = start.elapsed().as_secs_f64();
    Ok(rec.finish(plant, "rk4", case, dt, z, stats, stop))
}

/// RK45's absolute tolerance scaled to the response (√kg m): `10⁻³ rtol z_ref`, with
/// `z_ref = max_s Σ_i |b̃_{s,i}| F_i / |λ_s|` the largest static amplitude of a modal state
/// under the peak excitation forces `F_i` (sampled over the run). ODE45's fixed default 1e-6
/// is as large as the states of a typical structure (10⁻⁶–10⁻⁴ √kg m) and was measured 17 % and
/// 89 % off on the clearance beams; relative to the response, `rtol` governs. Rigid-body states
/// (`λ = 0`) are left out; with no force at all the floor is 1e-15.
pub fn auto_atol(
    plant: &Plant,
    forces: &[crate::Signal],
    dt: f64,
    n_steps: usize,
    rtol: f64,
) -> f64 {
    let peaks: Vec<f64> = forces
        .iter()
        .map(|f| {
            (0..=n_steps)
                .map(|k| f.eval(k as f64 * dt).abs())
                .fold(0.0, f64::max)
        })
        .collect();
    let sys = &plant.system;
    let z_ref = (0..sys.n_states())
        .filter(|&s| sys.poles[s].norm() > 0.0)
        .map(|s| {
            plant
                .inputs
                .iter()
                .zip(&peaks)
                .map(|((_, p), f)| sys.input[(s, *p)].norm() * f)
                .sum::<f64>()
                / sys.poles[s].norm()
        })
        .fold(0.0, f64::max);
    (1e-3 * rtol * z_ref).max(1e-15)
}
