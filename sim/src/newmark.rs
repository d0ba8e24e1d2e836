//! Newmark (average acceleration) and HHT-α with Newton on the **unreduced** sparse model: the
//! implicit baseline of general-purpose FE codes (Nastran SOL 129/400 style).
//!
//! Equilibrium at `t_{n+1}`, HHT form with `α ∈ [−1/3, 0]` (`α = 0` is Newmark's trapezoidal
//! rule, `γ = 1/2`, `β = 1/4`; otherwise `γ = (1 − 2α)/2`, `β = (1 − α)²/4`):
//!
//! `M a_{n+1} + (1+α) p(d_{n+1}, v_{n+1}) − α p(d_n, v_n) = (1+α) f_{n+1} − α f_n`,
//! `p = V v + K q + Σ_e w_e g_e(w_eᵀ q, w_eᵀ v)`,
//!
//! with `a_{n+1} = (d_{n+1} − d_n − h v_n)/(β h²) − (1/(2β) − 1) a_n` and
//! `v_{n+1} = v_n + h ((1−γ) a_n + γ a_{n+1})`. Newton on `d_{n+1}`: the tangent is the
//! constant effective stiffness `K_eff = M/(βh²) + (1+α)(K + γ/(βh) V)`, factorised once, plus
//! the element tangents `(1+α) W diag(κ) Wᵀ` of rank `n_NL`, applied by the Woodbury identity
//! with `Y = K_eff⁻¹ W` computed once: `Δ = x − Y (I + κ WᵀY)⁻¹ κ Wᵀ x`, `x = K_eff⁻¹ r`.

use crate::feedback::NewtonConfig;
use crate::history::{InitialState, LoadCase, Progress, RunStats, Series, TimeHistory};
use faer::Mat;
use faer::linalg::solvers::Solve;
use faer::sparse::linalg::solvers::Llt;
use nlsim_kernel::{
    Coupling, Damping, Error, Model, NonlinearElement, Quantity, Result, SparseSym, Status,
};

/// Settings of the Newmark/HHT reference.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewmarkConfig {
    /// Sample interval (s).
    pub dt: f64,
    /// Integration steps per sample interval.
    pub substeps: usize,
    /// HHT parameter `α ∈ [−1/3, 0]`; 0 is Newmark average acceleration.
    pub alpha: f64,
    /// Newton settings: convergence when `‖Δd‖∞ ≤ rtol ‖d‖∞`, or when the residual is at the
    /// rounding floor of its own evaluation (then no correction can improve `d`).
    pub newton: NewtonConfig,
}

impl NewmarkConfig {
    /// Average acceleration with step `dt`.
    pub fn new(dt: f64) -> Self {
        NewmarkConfig {
            dt,
            substeps: 1,
            alpha: 0.0,
            newton: NewtonConfig {
                max_iterations: 30,
                rtol: 1e-10,
            },
        }
    }
}

enum DampingOp {
    None,
    Rayleigh(f64, f64),
    Matrix(SparseSym),
}

/// The factorised Newmark/HHT integrator of an unreduced model.
pub struct Newmark {
    m: SparseSym,
    k: SparseSym,
    damping: DampingOp,
    elements: Vec<NonlinearElement>,
    /// `(element, coordinate)` of every loop coordinate (one per coordinate of each law).
    channels: Vec<(usize, usize)>,
    inputs: Vec<(String, Coupling)>,
    outputs: Vec<(String, Coupling, Quantity)>,
    cfg: NewmarkConfig,
    gamma: f64,
    beta: f64,
    keff: Llt<usize, f64>,
    /// `K_eff⁻¹ W` (n × n_NL), one column of `W` per element coordinate.
    y: Mat<f64>,
    /// `Wᵀ K_eff⁻¹ W` (n_NL × n_NL).
    wty: Mat<f64>,
    /// `‖M‖∞`, `‖K‖∞` and `‖V‖∞`: the scales of the residual's rounding floor.
    norms: [f64; 3],
    /// Seconds spent forming and factorising `K_eff` and `Y`.
    pub setup_seconds: f64,
}

/// The residual's rounding floor is this many unit roundoffs of the magnitudes summed into it.
const FLOOR_ULPS: f64 = 16.0;

impl Newmark {
    /// Factorises the effective stiffness of `model` for `cfg`. Damping must be none,
    /// Rayleigh or an explicit matrix: modal damping has no sparse matrix on the unreduced
    /// model.
    pub fn new(model: &Model, cfg: &NewmarkConfig) -> Result<Self> {
        let t0 = std::time::Instant::now();
        if !(cfg.dt > 0.0 && cfg.dt.is_finite()) || cfg.substeps == 0 {
            return Err(Error::invalid(
                "Newmark step",
                format!(
                    "dt = {} s and {} substeps must be positive",
                    cfg.dt, cfg.substeps
                ),
            ));
        }
        if !(-1.0 / 3.0..=0.0).contains(&cfg.alpha) {
            return Err(Error::invalid(
                "HHT alpha",
                format!("{} is outside [-1/3, 0]", cfg.alpha),
            ));
        }
        let damping = match model.damping() {
            Damping::None => DampingOp::None,
            Damping::Rayleigh { alpha, beta } => DampingOp::Rayleigh(*alpha, *beta),
            Damping::Matrix(v) => DampingOp::Matrix(v.clone()),
            Damping::Modal(_) => {
                return Err(Error::invalid(
                    "Newmark on the unreduced model",
                    "modal damping has no sparse damping matrix; give Rayleigh damping (e.g. fitted \
                     to two modes) or an explicit matrix for this reference",
                ));
            }
        };
        let a = cfg.alpha;
        let (gamma, beta) = (0.5 - a, 0.25 * (1.0 - a) * (1.0 - a));
        let h = cfg.dt / cfg.substeps as f64;
        let c0 = 1.0 / (beta * h * h);
        let cv = gamma / (beta * h);
        let (m, k) = (model.mass(), model.stiffness());
        // K_eff = c0 M + (1+α)(K + cv V)
        let mut keff = SparseSym::linear_combination("effective stiffness", c0, m, 1.0 + a, k)?;
        match &damping {
            DampingOp::None => {}
            DampingOp::Rayleigh(ra, rb) => {
                keff = SparseSym::linear_combination(
                    "effective stiffness",
                    c0 + (1.0 + a) * cv * ra,
                    m,
                    (1.0 + a) * (1.0 + cv * rb),
                    k,
                )?;
            }
            DampingOp::Matrix(v) => {
                keff = SparseSym::linear_combination(
                    "effective stiffness",
                    1.0,
                    &keff,
                    (1.0 + a) * cv,
                    v,
                )?;
            }
        }
        let llt = keff.cholesky().map_err(|i| Error::NotDefinite {
            matrix: "Newmark effective stiffness".into(),
            required: "positive definite".into(),
            detail: format!(
                "Cholesky failed at DOF {}",
                if i == usize::MAX {
                    "?".to_string()
                } else {
                    model.dofs().describe(i)
                }
            ),
        })?;
        let n = model.n_dofs();
        let elements: Vec<NonlinearElement> = model.elements().to_vec();
        let channels: Vec<(usize, usize)> = elements
            .iter()
            .enumerate()
            .flat_map(|(e, el)| (0..el.couplings().len()).map(move |c| (e, c)))
            .collect();
        let coupling = |j: usize| &elements[channels[j].0].couplings()[channels[j].1];
        let nn = channels.len();
        let mut y = Mat::<f64>::zeros(n, nn);
        for j in 0..nn {
            let c = coupling(j);
            for (&d, &w) in c.dofs().iter().zip(c.weights()) {
                y[(d, j)] += w;
            }
        }
        llt.solve_in_place(y.as_mut());
        let wty = Mat::from_fn(nn, nn, |i, j| {
            coupling_dot(
                coupling(i),
                y.col(j).try_as_col_major().expect("contiguous").as_slice(),
            )
        });
        let inputs = model
            .excitation()
            .iter()
            .map(|x| (x.name.clone(), x.at.coupling()))
            .collect();
        let outputs = model
            .sensors()
            .iter()
            .map(|s| (s.name.clone(), s.at.coupling(), s.quantity))
            .collect();
        let norm_v = match &damping {
            DampingOp::None => 0.0,
            DampingOp::Rayleigh(ra, rb) => ra.abs() * m.norm_inf() + rb.abs() * k.norm_inf(),
            DampingOp::Matrix(v) => v.norm_inf(),
        };
        Ok(Newmark {
            norms: [m.norm_inf(), k.norm_inf(), norm_v],
            m: m.clone(),
            k: k.clone(),
            damping,
            elements,
            channels,
            inputs,
            outputs,
            cfg: *cfg,
            gamma,
            beta,
            keff: llt,
            y,
            wty,
            setup_seconds: t0.elapsed().as_secs_f64(),
        })
    }

    /// `p = V v + K d` (without elements) into `out`; uses `tmp` as scratch.
    fn linear_internal(&self, d: &[f64], v: &[f64], out: &mut [f64], tmp: &mut [f64]) {
        match &self.damping {
            DampingOp::None => self.k.mul_vec(d, out),
            DampingOp::Rayleigh(ra, rb) => {
                for i in 0..d.len() {
                    tmp[i] = d[i] + rb * v[i];
                }
                self.k.mul_vec(tmp, out);
                if *ra != 0.0 {
                    self.m.mul_vec(v, tmp);
                    for i in 0..d.len() {
                        out[i] += ra * tmp[i];
                    }
                }
            }
            DampingOp::Matrix(vm) => {
                self.k.mul_vec(d, out);
                vm.mul_vec(v, tmp);
                for i in 0..d.len() {
                    out[i] += tmp[i];
                }
            }
        }
    }

    /// Runs `case` (forces at the model's excitation points, from rest) for `n_steps` sample
    /// intervals.
    pub fn run(&self, case: &LoadCase, n_steps: usize) -> Result<TimeHistory> {
        self.run_with_progress(case, n_steps, &mut |_, _| {})
    }

    /// As [`Newmark::run`], calling `progress(samples done, n_steps)` about 200 times.
    pub fn run_with_progress(
        &self,
        case: &LoadCase,
        n_steps: usize,
        progress: &mut dyn FnMut(usize, usize),
    ) -> Result<TimeHistory> {
        let start = std::time::Instant::now();
        if case.initial != InitialState::Rest {
            return Err(Error::invalid(
                format!("load case '{}'", case.name),
                "the unreduced Newmark reference starts from rest only",
            ));
        }
        if case.forces.len() != self.inputs.len() {
            return Err(Error::DimensionMismatch {
                what: format!("force signals of load case '{}'", case.name),
                expected: self.inputs.len(),
                found: case.forces.len(),
            });
        }
        for (s, (name, _)) in case.forces.iter().zip(&self.inputs) {
            s.validate(&format!("load case '{}', input '{name}'", case.name))?;
        }
        let mut elements = self.elements.clone();
        for (p, v) in &case.parameters {
            nlsim_kernel::param::set_element_param(&mut elements, p, *v)?;
        }
        let n = self.m.n();
        let channels = &self.channels[..];
        let nn = channels.len();
        let coupling = |j: usize| &self.elements[channels[j].0].couplings()[channels[j].1];
        let alpha = self.cfg.alpha;
        let h = self.cfg.dt / self.cfg.substeps as f64;
        let (gamma, beta) = (self.gamma, self.beta);
        let c0 = 1.0 / (beta * h * h);
        let c3 = 1.0 / (2.0 * beta) - 1.0;
        let cv = gamma / (beta * h);
        let ns = n_steps + 1;
        let force_at = |t: f64, out: &mut [f64]| {
            out.iter_mut().for_each(|x| *x = 0.0);
            for (s, (_, at)) in case.forces.iter().zip(&self.inputs) {
                let f = s.eval(t);
                for (&d, &w) in at.dofs().iter().zip(at.weights()) {
                    out[d] += w * f;
                }
            }
        };
        let mut d = vec![0.0; n];
        let mut v = vec![0.0; n];
        let mut a = vec![0.0; n];
        let mut f_now = vec![0.0; n];
        let mut f_next = vec![0.0; n];
        let mut tmp = vec![0.0; n];
        let mut r = vec![0.0; n];
        let mut p_old = vec![0.0; n];
        let mut p_new = vec![0.0; n];
        let mut ma = vec![0.0; n];
        let mut dn = vec![0.0; n];
        let mut vn = vec![0.0; n];
        let mut an = vec![0.0; n];
        let mut states: Vec<Vec<f64>> = elements
            .iter()
            .map(|e| vec![0.0; e.law().n_states()])
            .collect();
        let mut stats = RunStats::default();
        force_at(0.0, &mut f_now);
        if f_now.iter().any(|&x| x != 0.0) {
            // M a0 = f(0) at rest.
            let lm = self.m.cholesky().map_err(|_| Error::NotDefinite {
                matrix: "mass matrix".into(),
                required: "positive definite".into(),
                detail: "needed for the initial acceleration".into(),
            })?;
            let mut col = Mat::from_fn(n, 1, |i, _| f_now[i]);
            lm.solve_in_place(col.as_mut());
            for i in 0..n {
                a[i] = col[(i, 0)];
            }
        }
        // p at rest is zero (elements at u = 0 may carry force only if g(0) ≠ 0).
        let mut g = vec![0.0; nn];
        // Per coordinate: the rows of (1+α)(∂g/∂u + cv ∂g/∂u̇) over its element's coordinates.
        let mut tangent = vec![
            0.0;
            channels
                .iter()
                .map(|&(e, _)| elements[e].couplings().len())
                .sum()
        ];
        let mut wtx = vec![0.0; nn];
        let mut xw = vec![0.0; nn];
        let mut small = Mat::<f64>::zeros(nn, nn);
        let mut scratch = Scratch::new(&elements);
        eval_elements(
            &elements,
            &states,
            &d,
            &v,
            &mut g,
            None,
            &mut p_old,
            &mut scratch,
        );
        let mut rec_out = vec![vec![0.0; ns]; self.outputs.len()];
        let mut rec_in = vec![vec![0.0; ns]; self.inputs.len()];
        let mut rec_d = vec![vec![0.0; ns]; nn];
        let mut rec_v = vec![vec![0.0; ns]; nn];
        let mut rec_f = vec![vec![0.0; ns]; nn];
        let mut record = |k: usize, d: &[f64], v: &[f64], a: &[f64], g: &[f64]| {
            let t = k as f64 * self.cfg.dt;
            for (o, (_, at, q)) in self.outputs.iter().enumerate() {
                rec_out[o][k] = match q {
                    Quantity::Displacement => at.coordinate(d),
                    Quantity::Velocity => at.coordinate(v),
                    Quantity::Acceleration => at.coordinate(a),
                };
            }
            for (i, s) in case.forces.iter().enumerate() {
                rec_in[i][k] = s.eval(t);
            }
            for j in 0..nn {
                rec_d[j][k] = coupling(j).coordinate(d);
                rec_v[j][k] = coupling(j).coordinate(v);
                rec_f[j][k] = g[j];
            }
        };
        record(0, &d, &v, &a, &g);
        // Newmark's a_{n+1}, v_{n+1} from d_{n+1} and the previous step.
        let kinematics =
            |d: &[f64], dn: &[f64], vn: &[f64], an: &[f64], a: &mut [f64], v: &mut [f64]| {
                for i in 0..d.len() {
                    a[i] = c0 * (d[i] - dn[i]) - c0 * h * vn[i] - c3 * an[i];
                    v[i] = vn[i] + h * ((1.0 - gamma) * an[i] + gamma * a[i]);
                }
            };
        // The rounding floor of the residual: unit roundoffs of the magnitudes summed into it,
        // with the rounding of `a` and `v` (formed from differences of displacements scaled by
        // c0 and cv) carried through `M` and `V`.
        let inf = |x: &[f64]| x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let [norm_m, norm_k, norm_v] = self.norms;
        let wmax: Vec<f64> = (0..nn)
            .map(|j| {
                coupling(j)
                    .weights()
                    .iter()
                    .fold(0.0f64, |m, w| m.max(w.abs()))
            })
            .collect();
        // Per step: the span of displacements that a and v are formed from (minus the
        // iterate's own), and the terms that stay fixed while Newton iterates.
        let step_terms = |dn: &[f64], vn: &[f64], an: &[f64], f: [&[f64]; 3]| {
            let [f_now, f_next, p_old] = f;
            let fixed = (1.0 + alpha) * inf(f_next)
                + alpha.abs() * (inf(f_now) + inf(p_old))
                + norm_m * c3 * inf(an);
            (inf(dn) + h * inf(vn), fixed)
        };
        // Per iteration: the floor at the iterate (d, v, a) with element forces g.
        let floor = |d: &[f64], v: &[f64], a: &[f64], g: &[f64], (span0, fixed): (f64, f64)| {
            let span = inf(d) + span0;
            let elem: f64 = g.iter().zip(&wmax).map(|(g, w)| g.abs() * w).sum();
            FLOOR_ULPS
                * f64::EPSILON
                * (fixed
                    + (1.0 + alpha) * (norm_k * inf(d) + elem)
                    + norm_m * (inf(a) + c0 * span)
                    + (1.0 + alpha) * norm_v * (inf(v) + cv * span))
        };
        let mut col = Mat::<f64>::zeros(n, 1);
        let mut progress = Progress::new(progress, n_steps);
        let mut stop: Option<(Status, Error, usize)> = None;
        'steps: for step in 0..n_steps {
            for sub in 0..self.cfg.substeps {
                let t1 = step as f64 * self.cfg.dt + (sub + 1) as f64 * h;
                force_at(t1 - h, &mut f_now);
                force_at(t1, &mut f_next);
                dn.copy_from_slice(&d);
                vn.copy_from_slice(&v);
                an.copy_from_slice(&a);
                let terms = step_terms(&dn, &vn, &an, [&f_now, &f_next, &p_old]);
                // Predictor: d_{n+1} = d_n (a constant-displacement start).
                let mut converged = false;
                for it in 0..self.cfg.newton.max_iterations {
                    kinematics(&d, &dn, &vn, &an, &mut a, &mut v);
                    self.linear_internal(&d, &v, &mut p_new, &mut tmp);
                    eval_elements(
                        &elements,
                        &states,
                        &d,
                        &v,
                        &mut g,
                        Some((&mut tangent, 1.0 + alpha, cv)),
                        &mut p_new,
                        &mut scratch,
                    );
                    self.m.mul_vec(&a, &mut ma);
                    for i in 0..n {
                        r[i] = (1.0 + alpha) * f_next[i]
                            - alpha * f_now[i]
                            - ma[i]
                            - (1.0 + alpha) * p_new[i]
                            + alpha * p_old[i];
                    }
                    // A residual at the rounding floor of its own evaluation is solved: a
                    // further correction would only be noise amplified by K_eff⁻¹ (on stiff
                    // models ‖Δd‖ then stalls far above any relative tolerance, and the step
                    // used to fail although the first iteration was exact).
                    if it > 0 && inf(&r) <= floor(&d, &v, &a, &g, terms) {
                        converged = true;
                        break;
                    }
                    // Δ = K_t⁻¹ r by Woodbury on K_eff.
                    for i in 0..n {
                        col[(i, 0)] = r[i];
                    }
                    self.keff.solve_in_place(col.as_mut());
                    stats.evaluations += 1;
                    if nn > 0 && tangent.iter().any(|&k| k != 0.0) {
                        // Woodbury with the block-diagonal element tangent G:
                        // (K_eff + W G Wᵀ)⁻¹ r = x − Y (I + G Wᵀ Y)⁻¹ G Wᵀ x.
                        let xs = col
                            .col(0)
                            .try_as_col_major()
                            .expect("contiguous")
                            .as_slice();
                        for (j, w) in xw.iter_mut().enumerate() {
                            *w = coupling_dot(coupling(j), xs);
                        }
                        let mut at = 0;
                        for j in 0..nn {
                            let (e, c) = channels[j];
                            let first = j - c;
                            let row = &tangent[at..at + elements[e].couplings().len()];
                            at += row.len();
                            wtx[j] = row.iter().zip(&xw[first..]).map(|(k, x)| k * x).sum();
                            for m in 0..nn {
                                small[(j, m)] = f64::from(u8::from(j == m))
                                    + row
                                        .iter()
                                        .enumerate()
                                        .map(|(b, k)| k * self.wty[(first + b, m)])
                                        .sum::<f64>();
                            }
                        }
                        let lu = small.partial_piv_lu();
                        let mut rhs = Mat::from_fn(nn, 1, |j, _| wtx[j]);
                        lu.solve_in_place(rhs.as_mut());
                        for i in 0..n {
                            let mut s = 0.0;
                            for j in 0..nn {
                                s += self.y[(i, j)] * rhs[(j, 0)];
                            }
                            col[(i, 0)] -= s;
                        }
                    }
                    let mut dmax = 0.0f64;
                    let mut xmax = 0.0f64;
                    for i in 0..n {
                        let dx = col[(i, 0)];
                        d[i] += dx;
                        dmax = dmax.max(dx.abs());
                        xmax = xmax.max(d[i].abs());
                    }
                    stats.newton_iterations += 1;
                    stats.max_newton_iterations = stats.max_newton_iterations.max(it + 1);
                    if !dmax.is_finite() {
                        break;
                    }
                    // A linear model is solved exactly by the first iteration.
                    if nn == 0 || dmax <= self.cfg.newton.rtol * xmax.max(1e-300) {
                        converged = true;
                        break;
                    }
                }
                if !converged {
                    let err = Error::Numerical {
                        what: format!(
                            "Newmark Newton at step {} (t = {t1:.6e} s)",
                            step * self.cfg.substeps + sub + 1
                        ),
                        detail: format!(
                            "no convergence in {} iterations; try a smaller step",
                            self.cfg.newton.max_iterations
                        ),
                    };
                    stop = Some((Status::IterationLimit, err, step + 1));
                    break 'steps;
                }
                // Final kinematics and internal force at the converged d.
                kinematics(&d, &dn, &vn, &an, &mut a, &mut v);
                self.linear_internal(&d, &v, &mut p_old, &mut tmp);
                eval_elements(
                    &elements,
                    &states,
                    &d,
                    &v,
                    &mut g,
                    None,
                    &mut p_old,
                    &mut scratch,
                );
                for (e, el) in elements.iter().enumerate() {
                    if !el.is_coupled() {
                        let c = el.coupling();
                        let (u, ud) = (c.coordinate(&d), c.coordinate(&v));
                        el.law().commit_state(u, ud, &mut states[e]);
                    }
                }
                stats.steps += 1;
            }
            record(step + 1, &d, &v, &a, &g);
            progress.tick(step + 1);
        }
        stats.seconds = start.elapsed().as_secs_f64();
        let (status, stopped) = match stop {
            Some((st, err, samples)) => {
                for v in rec_out
                    .iter_mut()
                    .chain(&mut rec_in)
                    .chain(&mut rec_d)
                    .chain(&mut rec_v)
                    .chain(&mut rec_f)
                {
                    v.truncate(samples);
                }
                (st, Some(err))
            }
            None => (Status::Converged, None),
        };
        Ok(TimeHistory {
            method: if alpha == 0.0 { "newmark" } else { "hht" }.into(),
            case: case.name.clone(),
            dt: self.cfg.dt,
            outputs: self
                .outputs
                .iter()
                .zip(rec_out)
                .map(|((name, _, q), values)| Series {
                    name: name.clone(),
                    quantity: *q,
                    values,
                })
                .collect(),
            inputs: self
                .inputs
                .iter()
                .map(|(n, _)| n.clone())
                .zip(rec_in)
                .collect(),
            element_names: channels
                .iter()
                .map(|&(e, c)| nlsim_reduction::modal::element_port_name(&elements[e], c))
                .collect(),
            element_displacements: rec_d,
            element_velocities: rec_v,
            element_forces: rec_f,
            final_state: Vec::new(),
            stats,
            status,
            stopped,
        })
    }
}

fn coupling_dot(c: &Coupling, x: &[f64]) -> f64 {
    c.dofs()
        .iter()
        .zip(c.weights())
        .map(|(&d, &w)| w * x[d])
        .sum()
}

/// Work buffers of [`eval_elements`] for the largest law.
struct Scratch {
    u: Vec<f64>,
    f: Vec<f64>,
    jac: Vec<f64>,
}

impl Scratch {
    fn new(elements: &[NonlinearElement]) -> Self {
        let m = elements
            .iter()
            .map(|e| e.couplings().len())
            .max()
            .unwrap_or(1);
        Scratch {
            u: vec![0.0; m],
            f: vec![0.0; m],
            jac: vec![0.0; m * m],
        }
    }
}

/// Evaluates every element at displacements `d` and velocities `v`: the force of each
/// coordinate into `g` (one entry per coordinate, elements in order), scattered along its
/// coupling into `p`. With `tangent = (buf, s, cv)`, also each coordinate's row of
/// `s (∂g/∂u + cv ∂g/∂u̇)` over its element's coordinates, rows in order, into `buf`.
#[allow(clippy::too_many_arguments)]
fn eval_elements(
    elements: &[NonlinearElement],
    states: &[Vec<f64>],
    d: &[f64],
    v: &[f64],
    g: &mut [f64],
    mut tangent: Option<(&mut [f64], f64, f64)>,
    p: &mut [f64],
    w: &mut Scratch,
) {
    let (mut j, mut at) = (0, 0);
    for (e, el) in elements.iter().enumerate() {
        let cs = el.couplings();
        let m = cs.len();
        if el.is_coupled() {
            for (u, c) in w.u[..m].iter_mut().zip(cs) {
                *u = c.coordinate(d);
            }
            el.law()
                .eval_coupled(&w.u[..m], &mut w.f[..m], &mut w.jac[..m * m]);
            for (a, c) in cs.iter().enumerate() {
                g[j + a] = w.f[a];
                c.scatter_add(w.f[a], p);
            }
            if let Some((buf, s, _)) = tangent.as_mut() {
                for (t, k) in buf[at..at + m * m].iter_mut().zip(&w.jac[..m * m]) {
                    *t = *s * k;
                }
            }
        } else {
            let c = el.coupling();
            let ev = el.law().eval(c.coordinate(d), c.coordinate(v), &states[e]);
            g[j] = ev.force;
            c.scatter_add(ev.force, p);
            if let Some((buf, s, cv)) = tangent.as_mut() {
                buf[at] = *s * (ev.df_du + *cv * ev.df_dv);
            }
        }
        j += m;
        at += m * m;
    }
}
