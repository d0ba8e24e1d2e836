//! The linear stage of calibration (thesis §4.5): FE-level parameters — stiffness and mass
//! scales of labelled element groups, boundary springs — from measured modal data (natural
//! frequencies, and mode shapes at the sensors when measured).
//!
//! Two ways to evaluate the model at parameter values ([`FeReduction`], as for stepped-sine
//! data): by default the parametric reduced model ([`nlsim_reduction::ParametricReduction`],
//! built once with the sensor DOFs as ports) solves a small dense eigenproblem per evaluation,
//! certified against the full sparse matrices and refreshed by a full eigen solve where the
//! certificate fails, with the Jacobian from the same projected matrices; with
//! [`FeReduction::Full`] each evaluation solves the full eigenproblem (the symbolic analysis
//! kept) and takes the Jacobian from the analytic eigen-sensitivities on the same factor
//! ([`nlsim_reduction::sensitivity`]).
//!
//! Residuals, weighted by the noise model:
//!
//! - frequency of measured mode `i` paired with computed mode `r`:
//!   `(f_r − f̃_i) / σ_f,i`;
//! - mode shape (when measured): `(φ̂_r − ψ̂_i) / σ_φ` per sensor, both shapes normalised to
//!   unit length over the sensors and the computed one signed to agree with the measured one.
//!
//! Pairing: a measured mode with a shape takes the free computed mode of largest MAC
//! (`MAC = (φᵀψ)² / (φᵀφ ψᵀψ)`), in measured order; one without a shape takes the free
//! computed mode nearest in frequency (by ratio). It is redone at every evaluation (mode
//! tracking), and reported.

use crate::CalibrationConfig;
use crate::calibrate::{
    Candidate, Interrupted, Outcome, Phase, Progress, StartRun, Stop, best_candidates,
    candidates_until, per_value, run_starts_until, start_points,
};
use crate::lm::{Evaluation, LeastSquares};
use crate::objective::{
    FeCounters, FeReduction, FeReductionStats, ParamSpec, specs_to_internal, specs_to_values,
    training_points,
};
use crate::stats::CramerRao;
use faer::{Mat, Par};
use nlsim_kernel::{Error, Model, Param, Parameterized, Result, Status};
use nlsim_reduction::{
    EigenConfig, EigenSolver, ModeSelection, ParametricReduction, ReductionConfig,
    SensitivityConfig, eigen_sensitivities,
};
use std::f64::consts::PI;
use std::sync::Arc;

/// One measured mode.
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredMode {
    /// Natural frequency (Hz).
    pub frequency_hz: f64,
    /// Standard deviation of the frequency (Hz), the weight of its residual.
    pub frequency_std_hz: f64,
    /// Mode shape at [`ModalData::dofs`] (any scale and sign), when measured.
    pub shape: Option<Vec<f64>>,
}

impl MeasuredMode {
    /// What is wrong with this mode's values, if anything: a frequency that is not positive or
    /// above [`crate::data::MAX_FREQUENCY_HZ`], a standard deviation that is not positive and
    /// finite, a shape that is not finite, all zero, or whose largest component is outside
    /// 1e-100..1e100. (Its length against the sensor DOFs is [`ModalData::validate`]'s.)
    pub fn fault(&self) -> Option<String> {
        if !(self.frequency_hz > 0.0 && self.frequency_hz <= crate::data::MAX_FREQUENCY_HZ) {
            return Some(format!(
                "frequency must be positive and at most {:e} Hz, not {:e} Hz",
                crate::data::MAX_FREQUENCY_HZ,
                self.frequency_hz
            ));
        }
        if !(self.frequency_std_hz > 0.0 && self.frequency_std_hz.is_finite()) {
            return Some(format!(
                "frequency standard deviation must be positive, not {} Hz",
                self.frequency_std_hz
            ));
        }
        let s = self.shape.as_ref()?;
        if s.iter().any(|v| !v.is_finite()) || s.iter().all(|v| *v == 0.0) {
            return Some("shape must be finite and not all zero".into());
        }
        // Shapes are normalised and correlated through sums of squares: components beyond
        // 1e100 (or all below 1e-100) would overflow or underflow them.
        let largest = s.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        if !(1e-100..=1e100).contains(&largest) {
            return Some(format!(
                "the largest shape component {largest:e} is outside 1e-100..1e100; scale the shape"
            ));
        }
        None
    }
}

/// Measured modal data: modes, the DOFs their shapes were measured at, and the shape noise.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalData {
    /// Model DOF indices of the sensors (the rows of every measured shape).
    pub dofs: Vec<usize>,
    /// Standard deviation of one component of a unit-normalised measured shape.
    pub shape_std: f64,
    /// The measured modes.
    pub modes: Vec<MeasuredMode>,
}

impl ModalData {
    /// Checks the data against a model of `n_dofs` DOFs; errors name the mode (1-based).
    pub fn validate(&self, n_dofs: usize) -> Result<()> {
        if self.modes.is_empty() {
            return Err(Error::invalid("modal data", "has no modes"));
        }
        if let Some(&d) = self.dofs.iter().find(|&&d| d >= n_dofs) {
            return Err(Error::invalid(
                "modal data",
                format!("sensor DOF index {d} is beyond the model's {n_dofs} DOFs"),
            ));
        }
        let has_shape = self.modes.iter().any(|m| m.shape.is_some());
        if has_shape && !(self.shape_std > 0.0 && self.shape_std.is_finite()) {
            return Err(Error::invalid(
                "modal data",
                format!(
                    "shapes are given, so the shape noise must be positive, not {}",
                    self.shape_std
                ),
            ));
        }
        for (i, m) in self.modes.iter().enumerate() {
            let what = || format!("measured mode {}", i + 1);
            if let Some(s) = &m.shape
                && s.len() != self.dofs.len()
            {
                return Err(Error::DimensionMismatch {
                    what: format!("{}: shape components (one per sensor DOF)", what()),
                    expected: self.dofs.len(),
                    found: s.len(),
                });
            }
            if let Some(why) = m.fault() {
                return Err(Error::invalid(what(), why));
            }
        }
        Ok(())
    }

    fn n_residuals(&self) -> usize {
        self.modes
            .iter()
            .map(|m| 1 + m.shape.as_ref().map_or(0, Vec::len))
            .sum()
    }
}

/// The model against the modal data at one set of parameter values.
#[derive(Debug, Clone)]
pub struct ModalFit {
    /// Computed mode (0-based) paired with each measured mode.
    pub pairing: Vec<usize>,
    /// Computed frequency of each paired mode (Hz).
    pub frequencies_hz: Vec<f64>,
    /// MAC of each pair (NaN when the shape was not measured).
    pub mac: Vec<f64>,
    /// Weighted residuals.
    pub residuals: Vec<f64>,
    /// Jacobian with respect to the internal variables (residuals × parameters).
    pub jacobian: Mat<f64>,
    /// Status of the mode-shape derivative series ([`Status::Converged`] when exact).
    pub sensitivity_status: Status,
}

/// How a [`ModalObjective`] evaluates the model's modes.
#[derive(Debug)]
enum Engine {
    /// The full eigenproblem at every evaluation.
    Full {
        eigen: EigenConfig,
        solver: Box<EigenSolver>,
    },
    /// The parametric reduced model; the sensors are its last ports, from `offset`.
    Parametric {
        reduction: Box<ParametricReduction>,
        offset: usize,
    },
}

/// The modes of one evaluation at the sensors, with their derivatives when asked for.
struct ModesAt {
    /// Natural frequencies (Hz).
    frequencies_hz: Vec<f64>,
    /// Mass-normalised shapes at the sensor DOFs (sensors × modes).
    shapes: Mat<f64>,
    /// `∂f_r/∂p_j` (modes × parameters; Hz per unit of the parameter's value).
    frequency_derivatives: Option<Mat<f64>>,
    /// `∂φ/∂p_j` at the sensors (sensors × modes), one per parameter.
    shape_derivatives: Vec<Mat<f64>>,
    /// Status of the shape derivatives.
    status: Status,
}

/// The modal least-squares problem over FE-level parameters.
#[derive(Debug)]
pub struct ModalObjective {
    model: Model,
    data: Arc<ModalData>,
    specs: Vec<ParamSpec>,
    engine: Engine,
    counters: Arc<FeCounters>,
    setup: FeReductionStats,
}

impl Clone for ModalObjective {
    /// A copy with a fresh eigen solver (the symbolic analysis is redone on first need); the
    /// parametric basis is shared until the copy enriches it. The counters are shared.
    fn clone(&self) -> Self {
        Self {
            model: self.model.clone(),
            data: self.data.clone(),
            specs: self.specs.clone(),
            engine: match &self.engine {
                Engine::Full { eigen, .. } => Engine::Full {
                    eigen: eigen.clone(),
                    solver: Box::default(),
                },
                Engine::Parametric { reduction, offset } => Engine::Parametric {
                    reduction: reduction.clone(),
                    offset: *offset,
                },
            },
            counters: Arc::clone(&self.counters),
            setup: self.setup,
        }
    }
}

impl ModalObjective {
    /// The problem for `specs` (FE-level parameters of `model`) against `data`, retaining
    /// `modes` computed modes (at least as many as measured; a few more let the pairing
    /// follow modes that change order). `par` is the parallelism of the eigen solves. The
    /// modes come from the parametric reduced model ([`FeReduction::default`]); see
    /// [`ModalObjective::with_reduction`].
    pub fn new(
        model: Model,
        data: Arc<ModalData>,
        specs: Vec<ParamSpec>,
        modes: usize,
        par: Par,
    ) -> Result<Self> {
        Self::with_reduction(model, data, specs, modes, par, &FeReduction::default())
    }

    /// [`ModalObjective::new`] with the evaluation of the modes chosen by `fe`. With
    /// [`FeReduction::Parametric`] the parametric reduced model is built here, with the sensor
    /// DOFs as ports and no residual flexibility: the nominal eigen solve (the model's current
    /// values), its modes' and the sensors' static responses' derivative directions, then a
    /// greedy training over the centre and the corners of the parameters' box (internal
    /// coordinates; face centres beyond four parameters). An evaluation then solves a dense
    /// eigenproblem of the basis's size, checks the lifted modes against the full matrices
    /// and, where the certificate fails, solves the full eigenproblem there and enriches the
    /// basis: kept by an evaluation with a Jacobian (an optimisation, sequential on its own
    /// copy), not by a cost-only one (the candidates, in parallel), so results do not depend
    /// on the thread count. With [`FeReduction::Full`] every evaluation solves the full
    /// eigenproblem.
    pub fn with_reduction(
        model: Model,
        data: Arc<ModalData>,
        specs: Vec<ParamSpec>,
        modes: usize,
        par: Par,
        fe: &FeReduction,
    ) -> Result<Self> {
        data.validate(model.n_dofs())?;
        if specs.is_empty() {
            return Err(Error::invalid(
                "modal calibration",
                "no parameters to calibrate",
            ));
        }
        for s in &specs {
            s.check()?;
            model.matrix_derivative(&s.param)?;
        }
        if modes < data.modes.len() || modes > model.n_dofs() {
            return Err(Error::invalid(
                "modal calibration",
                format!(
                    "retain between {} (the measured modes) and {} (the DOFs) modes, not {modes}",
                    data.modes.len(),
                    model.n_dofs()
                ),
            ));
        }
        let eigen = EigenConfig {
            selection: ModeSelection::Lowest(modes),
            par,
            ..EigenConfig::default()
        };
        let (engine, setup) = match fe {
            FeReduction::Full => (
                Engine::Full {
                    eigen,
                    solver: Box::default(),
                },
                FeReductionStats::default(),
            ),
            FeReduction::Parametric(settings) => {
                let config = ReductionConfig {
                    eigen,
                    residual_flexibility: false,
                    extra_dofs: data.dofs.clone(),
                };
                let params: Vec<Param> = specs.iter().map(|s| s.param.clone()).collect();
                let training = training_points(&specs.iter().collect::<Vec<_>>());
                let reduction = ParametricReduction::new(
                    &model,
                    &config,
                    &params,
                    settings.clone(),
                    &training,
                    &mut |_| {},
                )?;
                let offset = nlsim_reduction::model_ports(&model, &[])?.len();
                let st = reduction.stats();
                let setup = FeReductionStats {
                    parametric: true,
                    basis_size: st.basis_size,
                    setup_reductions: st.full_reductions,
                    ..FeReductionStats::default()
                };
                (
                    Engine::Parametric {
                        reduction: Box::new(reduction),
                        offset,
                    },
                    setup,
                )
            }
        };
        Ok(Self {
            model,
            data,
            specs,
            engine,
            counters: Arc::new(FeCounters::default()),
            setup,
        })
    }

    /// What the evaluations of the modes did so far, over every copy of this objective
    /// (the parametric model's basis, its training and refreshes, or the full eigen solves).
    pub fn fe_stats(&self) -> FeReductionStats {
        self.counters.stats(self.setup)
    }

    /// The parameters with their bounds.
    pub fn specs(&self) -> &[ParamSpec] {
        &self.specs
    }

    /// The model: at the values last evaluated with [`FeReduction::Full`], at its nominal
    /// values with the parametric model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// Internal variables of values `p`.
    pub fn to_internal(&self, p: &[f64]) -> Vec<f64> {
        specs_to_internal(&self.specs, p)
    }

    /// Values of internal variables `u`.
    pub fn to_values(&self, u: &[f64]) -> Vec<f64> {
        specs_to_values(&self.specs, u)
    }

    /// Internal bounds (lower, upper).
    pub fn internal_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        self.specs.iter().map(ParamSpec::internal_bounds).unzip()
    }

    /// The model against the data at parameter `values`, with its Jacobian. `Ok(None)` when
    /// the eigen solve fails numerically there; `Err` for invalid values. A refresh of the
    /// parametric model serves this evaluation only.
    pub fn fit_values(&mut self, values: &[f64]) -> Result<Option<ModalFit>> {
        self.fit(values, true, false)
    }

    /// The points [`calibrate_modal`] evaluates as candidates: the model's values (clamped to
    /// the bounds), then the Latin hypercube of `config`.
    pub fn candidate_points(&self, config: &CalibrationConfig) -> Result<Vec<Vec<f64>>> {
        let current = self
            .specs
            .iter()
            .map(|s| self.model.param(&s.param))
            .collect::<Result<Vec<_>>>()?;
        start_points(&self.specs, &current, config)
    }

    /// Cost `½‖r‖²` at `values` (no Jacobian; a refresh of the parametric model serves this
    /// evaluation only); infinite where the eigen solve fails.
    pub fn cost_values(&mut self, values: &[f64]) -> Result<f64> {
        Ok(self.fit(values, false, false)?.map_or(f64::INFINITY, |f| {
            0.5 * f.residuals.iter().map(|r| r * r).sum::<f64>()
        }))
    }

    /// The modes at `values`, at the sensors, with derivatives when `derivatives`; `keep`
    /// keeps a refresh of the parametric model's basis in this copy.
    fn modes_at(
        &mut self,
        values: &[f64],
        derivatives: bool,
        keep: bool,
    ) -> Result<Option<ModesAt>> {
        let dofs = &self.data.dofs;
        match &mut self.engine {
            Engine::Full { eigen, solver } => {
                for (s, &v) in self.specs.iter().zip(values) {
                    self.model.set_param(&s.param, v)?;
                }
                let t = std::time::Instant::now();
                let solved = solver.solve(self.model.stiffness(), self.model.mass(), eigen);
                self.counters.count(true, 1, t.elapsed().as_secs_f64());
                let modes = match solved {
                    Ok(m) if m.is_converged() => m,
                    Ok(_) | Err(Error::Numerical { .. }) => return Ok(None),
                    Err(e) => return Err(e),
                };
                let shapes =
                    Mat::from_fn(dofs.len(), modes.len(), |k, r| modes.vectors[(dofs[k], r)]);
                let mut at = ModesAt {
                    frequencies_hz: modes.frequencies_hz(),
                    shapes,
                    frequency_derivatives: None,
                    shape_derivatives: Vec::new(),
                    status: Status::Converged,
                };
                if derivatives {
                    let params: Vec<Param> = self.specs.iter().map(|s| s.param.clone()).collect();
                    let sens = eigen_sensitivities(
                        &self.model,
                        &modes,
                        solver,
                        &params,
                        &SensitivityConfig {
                            shape_dofs: dofs.clone(),
                            par: eigen.par,
                            ..SensitivityConfig::default()
                        },
                    )?;
                    at.frequency_derivatives = Some(sens.frequency_hz);
                    at.shape_derivatives = sens.shapes;
                    at.status = sens.status;
                }
                Ok(Some(at))
            }
            Engine::Parametric { reduction, offset } => {
                let point = self.counters.evaluate(reduction, values, derivatives, keep);
                let point = match point {
                    Ok(p) => p,
                    Err(Error::Numerical { .. }) => return Ok(None),
                    Err(e) => return Err(e),
                };
                let red = &point.reduced;
                let frequencies_hz = red.modes.frequencies_hz();
                let rows =
                    |p: &Mat<f64>| Mat::from_fn(dofs.len(), p.ncols(), |k, r| p[(*offset + k, r)]);
                let mut at = ModesAt {
                    shapes: rows(&red.participation),
                    frequency_derivatives: None,
                    shape_derivatives: Vec::new(),
                    status: Status::Converged,
                    frequencies_hz,
                };
                if let Some(d) = &point.derivatives {
                    // f = √λ / 2π, so ∂f = ∂λ / (8π² f).
                    let f = &at.frequencies_hz;
                    at.frequency_derivatives = Some(Mat::from_fn(
                        d.eigenvalues.nrows(),
                        d.eigenvalues.ncols(),
                        |r, j| {
                            if f[r] > 0.0 {
                                d.eigenvalues[(r, j)] / (8.0 * PI * PI * f[r])
                            } else {
                                0.0
                            }
                        },
                    ));
                    at.shape_derivatives = d.participation.iter().map(rows).collect();
                }
                Ok(Some(at))
            }
        }
    }

    /// The model against the data at `values`; the Jacobian when `derivatives` (else an
    /// empty matrix); `keep` as in [`ModalObjective::modes_at`].
    fn fit(&mut self, values: &[f64], derivatives: bool, keep: bool) -> Result<Option<ModalFit>> {
        if values.len() != self.specs.len() {
            return Err(Error::DimensionMismatch {
                what: "modal calibration parameter values".into(),
                expected: self.specs.len(),
                found: values.len(),
            });
        }
        for (s, &v) in self.specs.iter().zip(values) {
            nlsim_kernel::param::check_finite(&s.param, v)?;
        }
        let Some(modes) = self.modes_at(values, derivatives, keep)? else {
            return Ok(None);
        };
        let data = self.data.clone();
        let freqs = &modes.frequencies_hz;
        let n_modes = freqs.len();
        let at = |r: usize| -> Vec<f64> { modes.shapes.col(r).iter().copied().collect() };
        // Pairing.
        let mut taken = vec![false; n_modes];
        let mut pairing = Vec::with_capacity(data.modes.len());
        let mut mac = Vec::with_capacity(data.modes.len());
        for m in &data.modes {
            let r = match &m.shape {
                Some(psi) => {
                    let mut best = (usize::MAX, -1.0);
                    for r in (0..n_modes).filter(|&r| !taken[r]) {
                        let c = mac_of(&at(r), psi);
                        if c > best.1 {
                            best = (r, c);
                        }
                    }
                    mac.push(best.1);
                    best.0
                }
                None => {
                    // No shape: the free computed mode nearest in frequency (ratio), not
                    // the next in order, which pairs a measured fifth mode with a computed
                    // third when modes between were not measured.
                    mac.push(f64::NAN);
                    let gap = |r: usize| (freqs[r] / m.frequency_hz).ln().abs();
                    (0..n_modes)
                        .filter(|&r| !taken[r])
                        .min_by(|&a, &b| gap(a).total_cmp(&gap(b)))
                        .unwrap_or(0)
                }
            };
            taken[r] = true;
            pairing.push(r);
        }
        // Residuals and Jacobian (per internal variable: dp/du on every column).
        let n = self.specs.len();
        let du: Vec<f64> = self
            .specs
            .iter()
            .zip(values)
            .map(|(s, &v)| s.dvalue(s.to_internal(v)))
            .collect();
        let mut residuals = Vec::with_capacity(data.n_residuals());
        let mut jacobian = match modes.frequency_derivatives {
            Some(_) => Mat::zeros(data.n_residuals(), n),
            None => Mat::zeros(0, 0),
        };
        let mut frequencies_hz = Vec::with_capacity(pairing.len());
        for (m, &r) in data.modes.iter().zip(&pairing) {
            let row = residuals.len();
            residuals.push((freqs[r] - m.frequency_hz) / m.frequency_std_hz);
            if let Some(df) = &modes.frequency_derivatives {
                for j in 0..n {
                    jacobian[(row, j)] = df[(r, j)] * du[j] / m.frequency_std_hz;
                }
            }
            frequencies_hz.push(freqs[r]);
            if let Some(psi) = &m.shape {
                let a = at(r);
                let na = norm(&a);
                let npsi = norm(psi);
                let sign = if dot(&a, psi) < 0.0 { -1.0 } else { 1.0 };
                let b: Vec<f64> = a.iter().map(|v| v / na).collect();
                for (&bi, &pi) in b.iter().zip(psi) {
                    residuals.push((sign * bi - pi / npsi) / data.shape_std);
                }
                if modes.frequency_derivatives.is_none() {
                    continue;
                }
                // ∂b = (∂a − b (bᵀ∂a)) / ‖a‖, with ∂a the shape derivative at the sensors.
                let da: Vec<Vec<f64>> = modes
                    .shape_derivatives
                    .iter()
                    .map(|d| d.col(r).iter().copied().collect())
                    .collect();
                let btda: Vec<f64> = da.iter().map(|d| dot(&b, d)).collect();
                for (i, &bi) in b.iter().enumerate() {
                    for j in 0..n {
                        jacobian[(row + 1 + i, j)] =
                            sign * (da[j][i] - bi * btda[j]) / na * du[j] / data.shape_std;
                    }
                }
            }
        }
        Ok(Some(ModalFit {
            pairing,
            frequencies_hz,
            mac,
            residuals,
            jacobian,
            sensitivity_status: modes.status,
        }))
    }
}

fn dot(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

fn norm(a: &[f64]) -> f64 {
    dot(a, a).sqrt()
}

/// Modal assurance criterion of two real shapes (1: parallel, 0: orthogonal).
pub fn mac_of(a: &[f64], b: &[f64]) -> f64 {
    let d = dot(a, a) * dot(b, b);
    if d > 0.0 { dot(a, b).powi(2) / d } else { 0.0 }
}

impl LeastSquares for ModalObjective {
    fn n_params(&self) -> usize {
        self.specs.len()
    }

    fn evaluate(&mut self, u: &[f64]) -> Result<Option<Evaluation>> {
        let values = self.to_values(u);
        // An optimisation step (sequential on its own copy) keeps a refresh of the basis.
        Ok(self.fit(&values, true, true)?.map(|f| Evaluation {
            residuals: f.residuals,
            jacobian: f.jacobian,
        }))
    }
}

/// The outcome of [`calibrate_modal`].
#[derive(Debug, Clone)]
pub struct ModalCalibration {
    /// The calibrated parameters.
    pub params: Vec<Param>,
    /// The estimate.
    pub estimate: Vec<f64>,
    /// Status of the best optimisation.
    pub status: Status,
    /// Every candidate: the model's values first, then the Latin hypercube.
    pub candidates: Vec<Candidate>,
    /// The optimisations, best first.
    pub runs: Vec<StartRun>,
    /// Cramér–Rao bound at the estimate.
    pub cramer_rao: CramerRao,
    /// Parameters whose estimate sits on a bound.
    pub at_bound: Vec<bool>,
    /// The model against the data at the estimate.
    pub fit: ModalFit,
    /// Cost `½‖r‖²` at the estimate.
    pub cost: f64,
}

/// Calibrates FE-level parameters on modal data: Latin-hypercube candidates (in parallel,
/// each worker with its own copy of the model), Levenberg–Marquardt from the best
/// `config.starts`, and the Cramér–Rao bound at the optimum. `config.folds` is not used (a
/// handful of modes does not split into folds). Bit-identical for any thread count.
pub fn calibrate_modal(
    objective: &ModalObjective,
    config: &CalibrationConfig,
) -> Result<ModalCalibration> {
    calibrate_modal_with_progress(objective, config, &|_| {})
}

/// [`calibrate_modal`] with `progress` called as candidates are evaluated and optimisations
/// finish (from the worker threads; the numbers do not depend on it).
pub fn calibrate_modal_with_progress(
    objective: &ModalObjective,
    config: &CalibrationConfig,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<ModalCalibration> {
    Ok(calibrate_modal_until(objective, config, &[], progress, &|| false)?.unstopped())
}

/// [`calibrate_modal_with_progress`] that reuses the candidate costs in `known` (one per
/// point of [`ModalObjective::candidate_points`], `None` where not evaluated; empty for none)
/// and stops at the next safe point once `stop()` holds — before a candidate, before a
/// Levenberg–Marquardt evaluation — with what was complete. Each cost depends on its point
/// alone, so run again with the kept costs as `known` it reaches the uninterrupted run's
/// estimates bit for bit (as [`crate::calibrate_until`] does for stepped sines).
pub fn calibrate_modal_until(
    objective: &ModalObjective,
    config: &CalibrationConfig,
    known: &[Option<f64>],
    progress: &(dyn Fn(Progress) + Sync),
    stop: Stop<'_>,
) -> Result<Outcome<ModalCalibration>> {
    config.lm.validate()?;
    let specs = objective.specs.clone();
    let params: Vec<Param> = specs.iter().map(|s| s.param.clone()).collect();
    let points = objective.candidate_points(config)?;
    let cost = |obj: &mut ModalObjective, v: &[f64]| obj.cost_values(v);
    let candidates = match candidates_until(
        objective,
        params.clone(),
        points,
        known,
        cost,
        progress,
        stop,
    )? {
        Ok(c) => c,
        Err(kept) => return Ok(Outcome::Interrupted(kept)),
    };
    let order = best_candidates(&candidates, config.starts.max(1));
    if order.is_empty() {
        return Err(Error::Numerical {
            what: "modal calibration".into(),
            detail: "the eigen solve failed for every candidate".into(),
        });
    }
    let (runs, all) = run_starts_until(
        objective,
        &specs,
        &candidates,
        &order,
        &config.lm,
        &|done, total| progress(Progress::Start { done, total }),
        stop,
    )?;
    if !all {
        return Ok(Outcome::Interrupted(Box::new(Interrupted::evaluated_all(
            params,
            candidates,
            runs,
            Phase::Optimisation,
        ))));
    }
    let estimate = runs[0].values.clone();
    let mut obj = objective.clone();
    let fit = obj.fit_values(&estimate)?.ok_or_else(|| Error::Numerical {
        what: "modal calibration".into(),
        detail: "the eigen solve failed at the estimate".into(),
    })?;
    let cost = 0.5 * fit.residuals.iter().map(|r| r * r).sum::<f64>();
    let cramer_rao = CramerRao::new(
        &per_value(&specs, &estimate, &fit.jacobian),
        &fit.residuals,
        &estimate,
    );
    Ok(Outcome::Finished(Box::new(ModalCalibration {
        params,
        status: runs[0].report.status,
        at_bound: runs[0].report.active_bounds.clone(),
        estimate,
        candidates,
        runs,
        cramer_rao,
        fit,
        cost,
    })))
}
