//! The exponential hold integrator with implicit nonlinear feedback (thesis §3.1, paper II).
//!
//! Every diagonal state is advanced exactly for the held input (see [`crate::hold`]):
//! `z[k+1] = φ z[k] + Σ_j Γ_j u[k+j]`. The element forces at `t_{k+1}` enter through the
//! `j = 1` tap, so each step has an algebraic loop on the nonlinear ports only. To keep one
//! pass over the states per step, the stored state is `ẑ[k] = z[k] − Γ1 u_NL[k]` (the part
//! that does not depend on the unknown forces):
//!
//! `ẑ[k+1] = φ ẑ[k] + Σ_j Γ_j^ext u_ext[k+j] + (Γ0 + φ Γ1) u_NL[k] + Γ−1 u_NL[k−1]`,
//!
//! and a port response at `t_{k+1}` is `Σ w Re(c̃ ẑ[k+1]) + (Σ w Re(c̃ Γ1 b̃_NL) + D_NL) u_NL[k+1]
//! + D_ext u_ext[k+1]`: a prediction plus a small precomputed matrix `G` times the unknown
//! forces. The loop `f = g(y_pred − G f)` is solved by damped Newton; then the next step.
//!
//! The state update is one loop over blocks of 8 states in split real/imaginary arrays that
//! also accumulates every port response; it is compiled for the best SIMD instruction set
//! found at run time (AVX-512, AVX2+FMA, …) through `pulp`.
//!
//! **Events.** A clearance makes the force non-smooth; a fixed step across the kink would
//! lose the FOH's second order. When an element's gap function changes sign over a step, the
//! crossing instant is found by the Illinois method on exact FOH sub-steps and the step is
//! split there, so that each piece sees a smooth force.

use crate::feedback::{Feedback, LoopFailure, NewtonConfig};
use crate::history::{
    ContactEvent, LoadCase, Progress, RunStats, Series, TimeHistory, add_residual_rates,
};
use crate::hold::{Hold, step_coefficients};
use crate::plant::{ElementPort, Plant, Responses};
use faer::c64;
use nlsim_kernel::{Error, Law, Result, Status};
use pulp::{Arch, Simd, WithSimd};

mod sensitivity;
pub use sensitivity::OutputSensitivities;

/// Settings of the hold integrator.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FohConfig {
    /// Hold method (FOH unless studying bias errors).
    pub hold: Hold,
    /// Step = sample interval `T` (s).
    pub dt: f64,
    /// Locate clearance contact instants inside steps (FOH only).
    pub locate_events: bool,
    /// Newton settings of the nonlinear loop.
    pub newton: NewtonConfig,
}

impl FohConfig {
    /// FOH with step `dt` (s), event location on.
    pub fn new(dt: f64) -> Self {
        FohConfig {
            hold: Hold::Foh,
            dt,
            locate_events: true,
            newton: NewtonConfig::default(),
        }
    }
}

const LANES: usize = 8;
type Block = [f64; LANES];

#[derive(Debug, Clone, Copy)]
enum Column {
    /// Excitation input `i` at tap `j`.
    Input(usize, i32),
    /// Element `n`'s port force at tap `j`.
    Element(usize, i32),
}

/// The precomputed discretisation ("auxiliary matrices") of a plant for one step size.
#[derive(Debug, Clone)]
pub struct Simulator {
    plant: Plant,
    cfg: FohConfig,
    ns: usize,
    nblocks: usize,
    stride: usize,
    coeffs: Vec<Block>,
    cols: Vec<Column>,
    /// Distinct response rows accumulated in the state pass.
    n_kernel_rows: usize,
    /// The state-pass accumulator of each response row.
    row_slot: Vec<usize>,
    /// Port responses: rows, modal coefficients, feedthrough, `t = 0` loop sensitivities.
    resp: Responses,
    /// `Σ_s Re(row_c Γ1 b̃_NL)` (rows × elements).
    corr: Vec<f64>,
    /// `Γ1 b̃_NL` (states × elements).
    g1n: Vec<c64>,
    /// Loop sensitivities of a step (elements × elements): displacement and velocity.
    sd: Vec<f64>,
    sv: Vec<f64>,
    arch: Arch,
}

impl Simulator {
    /// Discretises `plant` for `cfg` (step size and hold).
    pub fn new(plant: &Plant, cfg: &FohConfig) -> Result<Self> {
        if !(cfg.dt > 0.0 && cfg.dt.is_finite()) {
            return Err(Error::invalid(
                "time step",
                format!("{} s must be positive and finite", cfg.dt),
            ));
        }
        if cfg.newton.max_iterations == 0 || cfg.newton.rtol.is_nan() || cfg.newton.rtol <= 0.0 {
            return Err(Error::invalid(
                "Newton settings",
                "need at least one iteration and a positive tolerance",
            ));
        }
        let sys = &plant.system;
        let ns = sys.n_states();
        let ne = plant.inputs.len();
        let nn = plant.elements.len();
        let resp = Responses::new(plant);
        let ports = &resp.ports;
        let taps = cfg.hold.taps();
        let mut cols = Vec::new();
        for i in 0..ne {
            for &j in taps {
                cols.push(Column::Input(i, j));
            }
        }
        for n in 0..nn {
            for &j in taps.iter().filter(|&&j| j <= 0) {
                cols.push(Column::Element(n, j));
            }
        }
        let nr = resp.rows.len();
        // Rows with the same modal coefficients (a sensor on an element's port) share one
        // accumulator in the state pass.
        let mut kernel_rows: Vec<usize> = Vec::new();
        let row_slot: Vec<usize> = (0..nr)
            .map(|r| {
                let same = |&q: &usize| resp.coefficients(q) == resp.coefficients(r);
                kernel_rows.iter().position(same).unwrap_or_else(|| {
                    kernel_rows.push(r);
                    kernel_rows.len() - 1
                })
            })
            .collect();
        let nb = ns.div_ceil(LANES);
        let stride = 2 + 2 * cols.len() + 2 * kernel_rows.len();
        let mut coeffs = vec![[0.0; LANES]; nb * stride];
        let mut g1n = vec![c64::new(0.0, 0.0); ns * nn];
        let tap_index = |j: i32| taps.iter().position(|&t| t == j);
        for s in 0..ns {
            let lambda = sys.poles[s];
            let (phi, g) = step_coefficients(cfg.hold, lambda, cfg.dt);
            let g1 = tap_index(1).map_or(c64::new(0.0, 0.0), |t| g[t]);
            let (b, l) = (s / LANES, s % LANES);
            let blk = &mut coeffs[b * stride..(b + 1) * stride];
            blk[0][l] = phi.re;
            blk[1][l] = phi.im;
            for (c, col) in cols.iter().enumerate() {
                let v = match *col {
                    Column::Input(i, j) => g[tap_index(j).expect("tap")] * sys.input[(s, ports[i])],
                    Column::Element(n, 0) => {
                        (g[tap_index(0).expect("tap")] + phi * g1) * sys.input[(s, ports[ne + n])]
                    }
                    Column::Element(n, j) => {
                        g[tap_index(j).expect("tap")] * sys.input[(s, ports[ne + n])]
                    }
                };
                blk[2 + 2 * c][l] = v.re;
                blk[3 + 2 * c][l] = v.im;
            }
            for (k, &r) in kernel_rows.iter().enumerate() {
                let c = resp.coefficients(r)[s];
                blk[2 + 2 * cols.len() + 2 * k][l] = c.re;
                blk[3 + 2 * cols.len() + 2 * k][l] = -c.im;
            }
            for n in 0..nn {
                g1n[s * nn + n] = g1 * sys.input[(s, ports[ne + n])];
            }
        }
        let mut corr = vec![0.0; nr * nn];
        for r in 0..nr {
            for n in 0..nn {
                corr[r * nn + n] = resp
                    .coefficients(r)
                    .iter()
                    .enumerate()
                    .map(|(s, c)| (c * g1n[s * nn + n]).re)
                    .sum();
            }
        }
        // A step's loop sensitivities: the hold's Γ1 path plus the feedthrough.
        let sd: Vec<f64> = (0..nn * nn).map(|im| corr[im] + resp.sd0[im]).collect();
        let sv: Vec<f64> = (0..nn * nn)
            .map(|im| corr[nn * nn + im] + resp.sv0[im])
            .collect();
        Ok(Simulator {
            plant: plant.clone(),
            cfg: *cfg,
            ns,
            nblocks: nb,
            stride,
            coeffs,
            cols,
            n_kernel_rows: kernel_rows.len(),
            row_slot,
            resp,
            corr,
            g1n,
            sd,
            sv,
            arch: Arch::new(),
        })
    }

    /// The plant being simulated.
    pub fn plant(&self) -> &Plant {
        &self.plant
    }

    /// The settings.
    pub fn config(&self) -> &FohConfig {
        &self.cfg
    }

    /// Floating-point operations of one state update per state (for rate reports): the
    /// complex product `φ z` (6), 4 per input column and 4 per accumulated response (rows
    /// with equal modal coefficients, such as a sensor on an element's port, count once).
    pub fn flops_per_state_step(&self) -> usize {
        6 + 4 * self.cols.len() + 4 * self.n_kernel_rows
    }

    /// One state update `ẑ_out = φ ẑ_in + Σ_c Γ_c vals_c` over every block (SIMD), with the
    /// port responses of the updated states accumulated into `rp` (one per response row).
    #[allow(clippy::too_many_arguments)]
    fn state_pass(
        &self,
        zr_in: &[Block],
        zi_in: &[Block],
        zr_out: &mut [Block],
        zi_out: &mut [Block],
        vals: &[f64],
        acc: &mut [Block],
        rp: &mut [f64],
    ) {
        for a in acc.iter_mut() {
            *a = [0.0; LANES];
        }
        self.arch.dispatch(StepKernel {
            coeffs: &self.coeffs,
            stride: self.stride,
            ncols: self.cols.len(),
            zr_in,
            zi_in,
            zr_out,
            zi_out,
            vals,
            acc,
        });
        for (r, v) in rp.iter_mut().enumerate() {
            *v = acc[self.row_slot[r]].iter().sum();
        }
    }

    /// Runs `case` for `n_steps` steps (`n_steps + 1` samples).
    pub fn run(&self, case: &LoadCase, n_steps: usize) -> Result<TimeHistory> {
        self.run_with_progress(case, n_steps, &mut |_, _| {})
    }

    /// As [`Simulator::run`], calling `progress(done, total)` about 200 times.
    pub fn run_with_progress(
        &self,
        case: &LoadCase,
        n_steps: usize,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<TimeHistory> {
        let start = std::time::Instant::now();
        let (z0, elements) = case.prepare(&self.plant)?;
        let elements = &elements[..];
        let plant = &self.plant;
        let dt = self.cfg.dt;
        let (ns, nb) = (self.ns, self.nblocks);
        let ne = plant.inputs.len();
        let nn = elements.len();
        let nq = ne + nn;
        let nr = self.resp.rows.len();
        let no = plant.outputs.len();
        let n = n_steps + 1;
        let events_on = self.cfg.locate_events && self.cfg.hold == Hold::Foh && plant.has_events();

        // Input samples; e_minus is the value at t = −dt (the LSOH's first step).
        let e: Vec<Vec<f64>> = case
            .forces
            .iter()
            .map(|s| (0..n).map(|k| s.eval(k as f64 * dt)).collect())
            .collect();
        let e_minus: Vec<f64> = case.forces.iter().map(|s| s.eval(-dt)).collect();
        let mut f_hist = vec![vec![0.0; n]; nn];
        let mut d_hist = vec![vec![0.0; n]; nn];
        let mut v_hist = vec![vec![0.0; n]; nn];
        let mut out = vec![vec![0.0; n]; no];
        let mut states: Vec<Vec<f64>> = elements
            .iter()
            .map(|e| vec![0.0; e.element.law().n_states()])
            .collect();
        let mut fb = Feedback::new(plant);
        let mut stats = RunStats::default();
        let mut f = vec![0.0; nn];
        let mut d_pred = vec![0.0; nn];
        let mut v_pred = vec![0.0; nn];
        let mut rp = vec![0.0; nr];
        let mut u_next = vec![0.0; nq];
        let mut d_new = vec![0.0; nn];
        let mut v_new = vec![0.0; nn];
        let mut d_old = vec![0.0; nn];
        // Why and at which sample the run stopped short, if it did (samples 0..=last valid).
        let mut stop: Option<(Status, Error)> = None;
        let mut last = n_steps;

        // t = 0: the loop with the feedthrough only.
        let resp = &self.resp;
        for q in 0..ne {
            u_next[q] = e[q][0];
        }
        for r in 0..nr {
            rp[r] = resp.modal(r, &z0);
        }
        for i in 0..nn {
            d_pred[i] = rp[i] + resp.feed_ext(i, &u_next);
            v_pred[i] = rp[nn + i] + resp.feed_ext(nn + i, &u_next);
        }
        let it = fb
            .solve(
                elements,
                &states,
                &d_pred,
                &v_pred,
                &resp.sd0,
                &resp.sv0,
                &mut f,
                &self.cfg.newton,
            )
            .unwrap_or_else(|e| {
                stop = Some((Status::IterationLimit, loop_error(e, elements, 0, 0.0)));
                0
            });
        stats.newton_iterations += it;
        stats.max_newton_iterations = stats.max_newton_iterations.max(it);
        for i in 0..nn {
            f_hist[i][0] = f[i];
            d_hist[i][0] = fb.last_d[i];
            v_hist[i][0] = fb.last_v[i];
            let law = elements[i].element.law();
            law.commit_state(fb.last_d[i], fb.last_v[i], &mut states[i]);
        }
        for i in 0..nn {
            u_next[ne + i] = -f[i];
        }
        for o in 0..no {
            let r = 2 * nn + o;
            out[o][0] = rp[r] + resp.feed(r, &u_next);
        }

        // ẑ0 = z0 − Γ1 u_NL(0) = z0 + Γ1 b̃ f0, in blocks.
        let mut zr = vec![[0.0; LANES]; nb];
        let mut zi = vec![[0.0; LANES]; nb];
        for s in 0..ns {
            let mut z = z0[s];
            for i in 0..nn {
                z += self.g1n[s * nn + i] * f[i];
            }
            zr[s / LANES][s % LANES] = z.re;
            zi[s / LANES][s % LANES] = z.im;
        }
        let mut zr2 = zr.clone();
        let mut zi2 = zi.clone();
        let mut acc = vec![[0.0; LANES]; self.n_kernel_rows];
        let mut vals = vec![0.0; self.cols.len()];
        let mut ev = EventScratch::new(ns, nn);
        let mut progress = Progress::new(progress, n_steps);

        if stop.is_some() {
            last = 0;
        }
        for k in 0..n_steps {
            if stop.is_some() {
                break;
            }
            for (c, col) in self.cols.iter().enumerate() {
                vals[c] = match *col {
                    Column::Input(i, j) => {
                        let idx = k as i64 + j as i64;
                        if idx < 0 {
                            e_minus[i]
                        } else {
                            e[i][idx as usize]
                        }
                    }
                    Column::Element(i, j) => {
                        let idx = (k as i64 + j as i64).max(0) as usize;
                        -f_hist[i][idx]
                    }
                };
            }
            self.state_pass(&zr, &zi, &mut zr2, &mut zi2, &vals, &mut acc, &mut rp);
            for q in 0..ne {
                u_next[q] = e[q][k + 1];
            }
            for i in 0..nn {
                d_pred[i] = rp[i] + resp.feed_ext(i, &u_next);
                v_pred[i] = rp[nn + i] + resp.feed_ext(nn + i, &u_next);
            }
            let t1 = (k + 1) as f64 * dt;
            // Newton from the extrapolated force, then once more from the last one.
            let mut solved = Ok(0);
            for guess in 0..2 {
                for i in 0..nn {
                    f[i] = if guess == 0 && k > 0 {
                        2.0 * f_hist[i][k] - f_hist[i][k - 1]
                    } else {
                        f_hist[i][k]
                    };
                }
                solved = fb.solve(
                    elements,
                    &states,
                    &d_pred,
                    &v_pred,
                    &self.sd,
                    &self.sv,
                    &mut f,
                    &self.cfg.newton,
                );
                if solved.is_ok() {
                    break;
                }
            }
            let it = match solved {
                Ok(it) => it,
                Err(e) => {
                    stop = Some((Status::IterationLimit, loop_error(e, elements, k + 1, t1)));
                    last = k;
                    break;
                }
            };
            stats.newton_iterations += it;
            stats.max_newton_iterations = stats.max_newton_iterations.max(it);
            d_new.copy_from_slice(&fb.last_d);
            v_new.copy_from_slice(&fb.last_v);
            for i in 0..nn {
                d_old[i] = d_hist[i][k];
            }
            if events_on && crossing(elements, &d_old, &d_new).is_some() {
                if let Err(err) = self.event_step(
                    k, &e, &f_hist, &d_hist, &zr, &zi, &mut zr2, &mut zi2, &mut f, &mut d_new,
                    &mut v_new, &states, &mut ev, &mut fb, &mut stats, elements,
                ) {
                    stop = Some((Status::IterationLimit, err));
                    last = k;
                    break;
                }
                // event_step leaves ẑ[k+1] in ev.za.
                for r in 0..nr {
                    rp[r] = resp.modal(r, &ev.za);
                }
            }
            for i in 0..nn {
                u_next[ne + i] = -f[i];
                f_hist[i][k + 1] = f[i];
                d_hist[i][k + 1] = d_new[i];
                v_hist[i][k + 1] = v_new[i];
                elements[i]
                    .element
                    .law()
                    .commit_state(d_new[i], v_new[i], &mut states[i]);
            }
            for o in 0..no {
                let r = 2 * nn + o;
                let mut y = rp[r] + resp.feed(r, &u_next);
                for i in 0..nn {
                    y += self.corr[r * nn + i] * u_next[ne + i];
                }
                out[o][k + 1] = y;
            }
            if let Some(bad) = (0..nn).find(|&i| !d_new[i].is_finite()) {
                let err = Error::Numerical {
                    what: format!(
                        "{} integration at step {} (t = {t1:.6e} s)",
                        self.cfg.hold,
                        k + 1
                    ),
                    detail: format!(
                        "the response of element '{}' is not finite: the run diverged",
                        elements[bad].coordinate_name()
                    ),
                };
                stop = Some((Status::NonFinite, err));
                last = k;
                break;
            }
            std::mem::swap(&mut zr, &mut zr2);
            std::mem::swap(&mut zi, &mut zi2);
            progress.tick(k + 1);
        }
        stats.steps = last;
        // The true state at the last valid sample: z = ẑ − Γ1 b̃ f.
        let final_state: Vec<c64> = (0..ns)
            .map(|s| {
                let mut z = c64::new(zr[s / LANES][s % LANES], zi[s / LANES][s % LANES]);
                for i in 0..nn {
                    z -= self.g1n[s * nn + i] * f_hist[i][last];
                }
                z
            })
            .collect();
        let mut e = e;
        if last < n_steps {
            for v in out
                .iter_mut()
                .chain(e.iter_mut())
                .chain(&mut f_hist)
                .chain(&mut d_hist)
                .chain(&mut v_hist)
            {
                v.truncate(last + 1);
            }
        }
        let (status, stopped) = match stop {
            Some((st, err)) => (st, Some(err)),
            None => (Status::Converged, None),
        };
        stats.seconds = start.elapsed().as_secs_f64();
        let mut h = TimeHistory {
            method: self.cfg.hold.as_str().into(),
            case: case.name.clone(),
            dt,
            outputs: plant
                .outputs
                .iter()
                .zip(out)
                .map(|(o, v)| Series {
                    name: o.name.clone(),
                    quantity: o.quantity,
                    values: v,
                })
                .collect(),
            inputs: plant.inputs.iter().map(|(n, _)| n.clone()).zip(e).collect(),
            element_names: elements.iter().map(ElementPort::coordinate_name).collect(),
            element_displacements: d_hist,
            element_velocities: v_hist,
            element_forces: f_hist,
            final_state,
            stats,
            status,
            stopped,
        };
        add_residual_rates(plant, &mut h);
        Ok(h)
    }

    /// Re-integrates step `k → k+1` in FOH sub-steps split at every contact event, writing
    /// `ẑ[k+1]` into `zr_out`/`zi_out` and the end forces, displacements and velocities.
    #[allow(clippy::too_many_arguments)]
    fn event_step(
        &self,
        k: usize,
        e: &[Vec<f64>],
        f_hist: &[Vec<f64>],
        d_hist: &[Vec<f64>],
        zr_in: &[Block],
        zi_in: &[Block],
        zr_out: &mut [Block],
        zi_out: &mut [Block],
        f: &mut [f64],
        d_new: &mut [f64],
        v_new: &mut [f64],
        states: &[Vec<f64>],
        ev: &mut EventScratch,
        fb: &mut Feedback,
        stats: &mut RunStats,
        elements: &[ElementPort],
    ) -> Result<()> {
        let (ns, nn) = (self.ns, elements.len());
        let ne = e.len();
        let dt = self.cfg.dt;
        let t0 = k as f64 * dt;
        // True state at t_k and the inputs there.
        for s in 0..ns {
            let mut z = c64::new(zr_in[s / LANES][s % LANES], zi_in[s / LANES][s % LANES]);
            for i in 0..nn {
                z -= self.g1n[s * nn + i] * f_hist[i][k];
            }
            ev.za[s] = z;
        }
        let mut ua: Vec<f64> = (0..ne).map(|q| e[q][k]).collect();
        ua.extend((0..nn).map(|i| -f_hist[i][k]));
        let mut da: Vec<f64> = (0..nn).map(|i| d_hist[i][k]).collect();
        let mut tau = 0.0;
        let e_at = |q: usize, t: f64| e[q][k] + (t / dt) * (e[q][k + 1] - e[q][k]);
        let e_end: Vec<f64> = (0..ne).map(|q| e[q][k + 1]).collect();
        let mut guess: Vec<f64> = f.to_vec();
        for _event in 0..8 {
            let h_full = dt - tau;
            let end = self.substep(
                ev, fb, elements, states, &ua, h_full, &e_end, &guess, stats, k,
            )?;
            let Some(_) = crossing(elements, &da, &end.d) else {
                break;
            };
            // Locate the earliest crossing among all (element, side) pairs.
            let mut best: Option<(f64, usize, bool)> = None;
            for (i, el) in elements.iter().enumerate() {
                for side in sides(el.element.law()) {
                    let (pa, pb) = (side.psi(da[i]), side.psi(end.d[i]));
                    if (pa > 0.0) == (pb > 0.0) {
                        continue;
                    }
                    let mut lo = (0.0, pa);
                    let mut hi = (h_full, pb);
                    let mut last_side = 0i8;
                    for _ in 0..100 {
                        if hi.0 - lo.0 <= 1e-11 * dt {
                            break;
                        }
                        let mut h = (lo.0 * hi.1 - hi.0 * lo.1) / (hi.1 - lo.1);
                        if !(h > lo.0 && h < hi.0) {
                            h = 0.5 * (lo.0 + hi.0);
                        }
                        let eh: Vec<f64> = (0..ne).map(|q| e_at(q, tau + h)).collect();
                        let r =
                            self.substep(ev, fb, elements, states, &ua, h, &eh, &guess, stats, k)?;
                        let p = side.psi(r.d[i]);
                        if (p > 0.0) == (pa > 0.0) {
                            lo = (h, p);
                            if last_side == -1 {
                                hi.1 *= 0.5;
                            }
                            last_side = -1;
                        } else {
                            hi = (h, p);
                            if last_side == 1 {
                                lo.1 *= 0.5;
                            }
                            last_side = 1;
                        }
                    }
                    if best.is_none_or(|b| hi.0 < b.0) {
                        best = Some((hi.0, i, pb > 0.0));
                    }
                }
            }
            let Some((h_ev, elem, closing)) = best else {
                break;
            };
            let eh: Vec<f64> = (0..ne).map(|q| e_at(q, tau + h_ev)).collect();
            let r = self.substep(ev, fb, elements, states, &ua, h_ev, &eh, &guess, stats, k)?;
            stats.events.push(ContactEvent {
                time: t0 + tau + h_ev,
                element: elem,
                closing,
            });
            ev.za.copy_from_slice(&ev.zb);
            tau += h_ev;
            ua.clear();
            ua.extend_from_slice(&eh);
            ua.extend(r.f.iter().map(|x| -x));
            da.copy_from_slice(&r.d);
            guess.copy_from_slice(&r.f);
            if dt - tau <= 1e-11 * dt {
                break;
            }
        }
        // Final piece to t_{k+1}.
        let h_last = dt - tau;
        let end = if h_last > 1e-11 * dt {
            self.substep(
                ev, fb, elements, states, &ua, h_last, &e_end, &guess, stats, k,
            )?
        } else {
            SubstepEnd {
                f: ua[ne..].iter().map(|x| -x).collect(),
                d: da.clone(),
                v: fb.last_v.clone(),
            }
        };
        if h_last <= 1e-11 * dt {
            ev.zb.copy_from_slice(&ev.za);
        }
        f.copy_from_slice(&end.f);
        d_new.copy_from_slice(&end.d);
        v_new.copy_from_slice(&end.v);
        // ẑ[k+1] = z[k+1] + Γ1 b̃ f[k+1], into the blocks and ev.za.
        for s in 0..ns {
            let mut z = ev.zb[s];
            for i in 0..nn {
                z += self.g1n[s * nn + i] * f[i];
            }
            ev.za[s] = z;
            zr_out[s / LANES][s % LANES] = z.re;
            zi_out[s / LANES][s % LANES] = z.im;
        }
        Ok(())
    }

    /// One exact FOH sub-step of length `h` from `ev.za` (inputs `ua` at its start, external
    /// inputs `e_to` at its end), solving the loop at its end; the state goes to `ev.zb`.
    #[allow(clippy::too_many_arguments)]
    fn substep(
        &self,
        ev: &mut EventScratch,
        fb: &mut Feedback,
        elements: &[ElementPort],
        states: &[Vec<f64>],
        ua: &[f64],
        h: f64,
        e_to: &[f64],
        guess: &[f64],
        stats: &mut RunStats,
        k: usize,
    ) -> Result<SubstepEnd> {
        let sys = &self.plant.system;
        let (ns, nn) = (self.ns, elements.len());
        let ne = e_to.len();
        let nq = ne + nn;
        let ports = &self.resp.ports;
        for s in 0..ns {
            let (phi, g) = step_coefficients(Hold::Foh, sys.poles[s], h);
            let mut bu = c64::new(0.0, 0.0);
            for q in 0..nq {
                bu += sys.input[(s, ports[q])] * ua[q];
            }
            let mut be = c64::new(0.0, 0.0);
            for q in 0..ne {
                be += sys.input[(s, ports[q])] * e_to[q];
            }
            ev.zb[s] = phi * ev.za[s] + g[0] * bu + g[1] * be;
            for i in 0..nn {
                ev.g1b[s * nn + i] = g[1] * sys.input[(s, ports[ne + i])];
            }
        }
        let mut sd = vec![0.0; nn * nn];
        let mut sv = vec![0.0; nn * nn];
        let mut dp = vec![0.0; nn];
        let mut vp = vec![0.0; nn];
        for i in 0..nn {
            for (row, pred, sens) in [(i, &mut dp, &mut sd), (nn + i, &mut vp, &mut sv)] {
                let rc = self.resp.coefficients(row);
                pred[i] = self.resp.modal(row, &ev.zb) + self.resp.feed_ext(row, e_to);
                for m in 0..nn {
                    sens[i * nn + m] = rc
                        .iter()
                        .enumerate()
                        .map(|(s, c)| (c * ev.g1b[s * nn + m]).re)
                        .sum::<f64>()
                        + self.resp.feed[row * nq + ne + m];
                }
            }
        }
        let mut f = guess.to_vec();
        let it = fb
            .solve(
                elements,
                states,
                &dp,
                &vp,
                &sd,
                &sv,
                &mut f,
                &self.cfg.newton,
            )
            .map_err(|e| loop_error(e, elements, k + 1, k as f64 * self.cfg.dt + h))?;
        stats.newton_iterations += it;
        for s in 0..ns {
            for i in 0..nn {
                ev.zb[s] -= ev.g1b[s * nn + i] * f[i];
            }
        }
        Ok(SubstepEnd {
            f,
            d: fb.last_d.clone(),
            v: fb.last_v.clone(),
        })
    }
}

struct SubstepEnd {
    f: Vec<f64>,
    d: Vec<f64>,
    v: Vec<f64>,
}

struct EventScratch {
    za: Vec<c64>,
    zb: Vec<c64>,
    g1b: Vec<c64>,
}

impl EventScratch {
    fn new(ns: usize, nn: usize) -> Self {
        EventScratch {
            za: vec![c64::new(0.0, 0.0); ns],
            zb: vec![c64::new(0.0, 0.0); ns],
            g1b: vec![c64::new(0.0, 0.0); ns * nn],
        }
    }
}

/// A gap function `ψ(u)` of a clearance side: positive in contact.
#[derive(Debug, Clone, Copy)]
struct Side {
    sign: f64,
    gap: f64,
}

impl Side {
    fn psi(self, u: f64) -> f64 {
        self.sign * u - self.gap
    }
}

fn sides(law: &Law) -> impl Iterator<Item = Side> {
    let v: [Option<Side>; 2] = match law {
        Law::Clearance { k1, k2, e1, e2, .. } => [
            (*k1 != 0.0).then_some(Side {
                sign: 1.0,
                gap: *e1,
            }),
            (*k2 != 0.0).then_some(Side {
                sign: -1.0,
                gap: *e2,
            }),
        ],
        _ => [None, None],
    };
    v.into_iter().flatten()
}

/// The first element whose gap function changes sign between `a` and `b`.
fn crossing(elements: &[ElementPort], a: &[f64], b: &[f64]) -> Option<usize> {
    elements.iter().enumerate().find_map(|(i, e)| {
        sides(e.element.law())
            .any(|s| (s.psi(a[i]) > 0.0) != (s.psi(b[i]) > 0.0))
            .then_some(i)
    })
}

pub(crate) fn loop_error(e: LoopFailure, elements: &[ElementPort], step: usize, t: f64) -> Error {
    Error::Numerical {
        what: if step == usize::MAX {
            format!("nonlinear feedback loop at t = {t:.6e} s")
        } else {
            format!("nonlinear feedback loop at step {step} (t = {t:.6e} s)")
        },
        detail: format!(
            "Newton did not converge in {} iterations: force residual {:.3e} N at element '{}' \
             (u = {:.6e} m); try a smaller time step",
            e.iterations,
            e.residual,
            elements
                .get(e.element)
                .map_or_else(|| "?".into(), ElementPort::coordinate_name),
            e.displacement
        ),
    }
}

/// The fused state update over all blocks:
/// `z_out = φ z_in + Σ_c a_c v_c` and `acc_r += Re(row_r · z_out)` (split re/im arrays).
struct StepKernel<'a> {
    coeffs: &'a [Block],
    stride: usize,
    ncols: usize,
    zr_in: &'a [Block],
    zi_in: &'a [Block],
    zr_out: &'a mut [Block],
    zi_out: &'a mut [Block],
    vals: &'a [f64],
    acc: &'a mut [Block],
}

impl WithSimd for StepKernel<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let nc = self.ncols;
        let rows = self.acc.len();
        for ((((cb, zr), zi), zro), zio) in self
            .coeffs
            .chunks_exact(self.stride)
            .zip(self.zr_in)
            .zip(self.zi_in)
            .zip(self.zr_out.iter_mut())
            .zip(self.zi_out.iter_mut())
        {
            let (pr, pi) = (&cb[0], &cb[1]);
            let mut nr = [0.0; LANES];
            let mut ni = [0.0; LANES];
            for l in 0..LANES {
                nr[l] = pr[l].mul_add(zr[l], -(pi[l] * zi[l]));
                ni[l] = pr[l].mul_add(zi[l], pi[l] * zr[l]);
            }
            for (c, &v) in self.vals[..nc].iter().enumerate() {
                let (ar, ai) = (&cb[2 + 2 * c], &cb[3 + 2 * c]);
                for l in 0..LANES {
                    nr[l] = ar[l].mul_add(v, nr[l]);
                    ni[l] = ai[l].mul_add(v, ni[l]);
                }
            }
            *zro = nr;
            *zio = ni;
            let rb = &cb[2 + 2 * nc..2 + 2 * nc + 2 * rows];
            for (a, rc) in self.acc.iter_mut().zip(rb.chunks_exact(2)) {
                for l in 0..LANES {
                    a[l] = rc[0][l].mul_add(nr[l], rc[1][l].mul_add(ni[l], a[l]));
                }
            }
        }
    }
}
