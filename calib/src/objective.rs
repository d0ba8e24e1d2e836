//! The nonlinear calibration objective (thesis §4.5, paper IV): the weighted deviation
//! between measured and computed multi-harmonic responses along every stepped-sine sweep.
//!
//! At each step the model is forced with the *measured* force harmonics and solved by
//! harmonic balance from the previous step's solution, in the sweep's measured direction, so
//! that it follows a branch the way the test did. Where the test left a branch at another
//! step than the model folds (the rig, not the structure, decides that), the
//! [`BranchChoice`] of the configuration compares the model on the branch nearer to the
//! measurement. Residuals per measured harmonic `Y` of a channel
//! with noise `σ` (see [`Noise`](crate::data::Noise)):
//!
//! - [`Form::Complex`]: `(Y_model − Y_test)/σ`, real and imaginary parts;
//! - [`Form::LogMagnitudePhase`]: `(ln|Y_model| − ln|Y_test|)·|Y_test|/σ` and the wrapped
//!   phase difference `·|Y_test|/σ` (the same noise to first order, without the weight of
//!   the large amplitudes dominating).
//!
//! The Jacobian comes from the harmonic balance sensitivities `dY/dp` (implicit
//! differentiation of `R(x, p) = 0`), never from finite differences.

use crate::data::{PointId, TestData};
use crate::lhs::Spacing;
use crate::lm::{Evaluation, LeastSquares};
use faer::{Mat, c64};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem, HbWorkspace, LinearPart, LinearVariation};
use nlsim_kernel::{Error, Model, Param, Parameterized, Quantity, Result, Status};
use nlsim_reduction::{
    EigenSolver, ParametricConfig, ParametricReduction, ReductionConfig, SensitivityConfig,
    reduce_with, reduced_sensitivities,
};
use std::f64::consts::PI;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, AtomicUsize, Ordering};

mod drive;
pub(crate) use crate::step::solve_step;
use drive::{Gains, Previous};

/// A parameter to calibrate, with its box and how its range is sampled and scaled.
#[derive(Debug, Clone, PartialEq)]
pub struct ParamSpec {
    /// The parameter.
    pub param: Param,
    /// Lower bound (the parameter's unit).
    pub lower: f64,
    /// Upper bound.
    pub upper: f64,
    /// [`Spacing::Log`] for a parameter spanning decades (the optimiser then works on its
    /// logarithm); [`Spacing::Linear`] otherwise (it works on `p / max(|lower|, |upper|)`).
    pub spacing: Spacing,
}

impl ParamSpec {
    /// A parameter with bounds, log-spaced when both bounds are positive and more than a
    /// decade apart.
    pub fn new(param: Param, lower: f64, upper: f64) -> Self {
        let spacing = if lower > 0.0 && upper > 10.0 * lower {
            Spacing::Log
        } else {
            Spacing::Linear
        };
        Self {
            param,
            lower,
            upper,
            spacing,
        }
    }

    /// Checks the bounds: finite with `lower < upper`, and a positive lower bound for log
    /// spacing.
    pub fn check(&self) -> Result<()> {
        if !(self.lower.is_finite() && self.upper.is_finite() && self.lower < self.upper) {
            return Err(Error::invalid(
                format!("bounds of {}", self.param),
                format!(
                    "[{}, {}] must be finite with lower < upper",
                    self.lower, self.upper
                ),
            ));
        }
        if self.spacing == Spacing::Log && self.lower <= 0.0 {
            return Err(Error::invalid(
                format!("bounds of {}", self.param),
                format!(
                    "log scaling needs a positive lower bound, not {}",
                    self.lower
                ),
            ));
        }
        Ok(())
    }

    fn scale(&self) -> f64 {
        self.lower.abs().max(self.upper.abs())
    }

    /// Internal optimisation variable of value `p`.
    pub fn to_internal(&self, p: f64) -> f64 {
        match self.spacing {
            Spacing::Linear => p / self.scale(),
            Spacing::Log => p.ln(),
        }
    }

    /// Value of internal variable `u`.
    pub fn to_value(&self, u: f64) -> f64 {
        match self.spacing {
            Spacing::Linear => u * self.scale(),
            Spacing::Log => u.exp(),
        }
    }

    /// `dp/du` at internal `u`.
    pub fn dvalue(&self, u: f64) -> f64 {
        match self.spacing {
            Spacing::Linear => self.scale(),
            Spacing::Log => u.exp(),
        }
    }

    /// Internal bounds.
    pub fn internal_bounds(&self) -> (f64, f64) {
        (self.to_internal(self.lower), self.to_internal(self.upper))
    }
}

/// Internal variables of values `p` under `specs`.
pub(crate) fn specs_to_internal(specs: &[ParamSpec], p: &[f64]) -> Vec<f64> {
    specs
        .iter()
        .zip(p)
        .map(|(s, &v)| s.to_internal(v))
        .collect()
}

/// Values of internal variables `u` under `specs`.
pub(crate) fn specs_to_values(specs: &[ParamSpec], u: &[f64]) -> Vec<f64> {
    specs.iter().zip(u).map(|(s, &v)| s.to_value(v)).collect()
}

/// Residual form.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Form {
    /// Complex difference, real and imaginary parts.
    Complex,
    /// Log-magnitude and phase differences.
    LogMagnitudePhase,
}

/// Settings of the objective.
#[derive(Debug, Clone, PartialEq)]
pub struct ObjectiveConfig {
    /// Harmonics `k` (of the excitation frequency) compared: `[1]` is the fundamental-only
    /// metric, `[1, 2, 3]` adds the side harmonics (thesis §4.5 compares both).
    pub harmonics: Vec<usize>,
    /// Residual form.
    pub form: Form,
    /// Which solution the model is compared on where the response is multi-valued.
    pub branch: BranchChoice,
}

impl Default for ObjectiveConfig {
    fn default() -> Self {
        Self {
            harmonics: vec![1],
            form: Form::Complex,
            branch: BranchChoice::NearestToData,
        }
    }
}

/// Which branch of a multi-valued response the model is compared on.
///
/// A measured stepped sine follows one stable branch and jumps at a frequency that depends
/// on the rig as much as on the structure: the shaker's interaction and the force
/// controller can make the test leave a branch before its fold, and a different step size
/// shifts the jump by a step. The model's continuation knows none of this.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BranchChoice {
    /// The continuation from the previous step only: the model jumps where it folds.
    Continuation,
    /// Where the continued solution is far from the measurement (mean squared normalised
    /// residual of the step above [`BRANCH_CHECK`]), the solve is repeated from the linear
    /// response and the solution nearer to the measurement is kept, and followed from
    /// there. Where the two agree, or the continued solution fits, nothing changes.
    NearestToData,
}

/// The mean squared normalised residual of a step (over its channels and compared
/// harmonics) above which [`BranchChoice::NearestToData`] looks for another branch: a
/// 5σ misfit on average, which noise alone gives with negligible probability.
pub const BRANCH_CHECK: f64 = 25.0;

/// The model at one point of the data.
#[derive(Debug, Clone)]
pub struct PointResult {
    /// The point.
    pub id: PointId,
    /// How the harmonic balance solve went.
    pub status: Status,
    /// Computed harmonics `k = 1..=H_data` per channel (channels × harmonics) in each
    /// channel's quantity; NaN where the solve failed or the model holds fewer harmonics.
    pub response: Mat<c64>,
    /// Per calibrated parameter (in spec order), `∂response/∂p` in the channel's unit per
    /// parameter unit (channels × harmonics, the analytic HB sensitivities of thesis eq. 32
    /// carried to the sensors); filled only by
    /// [`FrfObjective::evaluate_with_sensitivities`], else empty.
    pub sensitivity: Vec<Mat<c64>>,
}

/// Everything computed at one parameter vector.
#[derive(Debug, Clone)]
pub struct SweepEvaluation {
    /// Residuals of the training points (empty when a point failed).
    pub residuals: Vec<f64>,
    /// Their Jacobian with respect to the internal variables (when asked for).
    pub jacobian: Option<Mat<f64>>,
    /// Every point of the data, trained on or not.
    pub points: Vec<PointResult>,
    /// Points where the harmonic balance did not converge.
    pub failed: Vec<PointId>,
}

/// Memory an objective may spend on cached receptances (bytes): the data's frequencies and
/// the sub-steps between them, each `n_x (n_x + inputs (2H+1))` values.
const RECEPTANCE_BUDGET: usize = 64 << 20;

/// How an objective with FE-level parameters (group scales, boundary springs) reduces the
/// model at each evaluation.
#[derive(Debug, Clone, PartialEq)]
pub enum FeReduction {
    /// The parametric reduced model ([`ParametricReduction`]): one basis built with the
    /// objective, a small dense eigen solve per evaluation, certified against the full
    /// matrices and refreshed by a full reduction where the certificate fails.
    Parametric(ParametricConfig),
    /// A full reduction of the model at every evaluation (the reference; slow on large
    /// models).
    Full,
}

impl Default for FeReduction {
    fn default() -> Self {
        FeReduction::Parametric(ParametricConfig::default())
    }
}

/// Counters of the FE-level reductions, shared by every copy of an objective (the copies
/// the calibration runs in parallel included).
#[derive(Debug, Default)]
pub(crate) struct FeCounters {
    evaluations: AtomicUsize,
    refreshes: AtomicUsize,
    full_reductions: AtomicUsize,
    full_micros: AtomicU64,
}

impl FeCounters {
    /// Counts one evaluation of the linear part; `refreshed` when the parametric model's
    /// certificate failed, with the full reductions made (and their seconds) from the
    /// reduction's counters `before` and `after` the evaluation.
    pub(crate) fn count(&self, refreshed: bool, full_reductions: usize, full_seconds: f64) {
        self.evaluations.fetch_add(1, Ordering::Relaxed);
        if refreshed {
            self.refreshes.fetch_add(1, Ordering::Relaxed);
        }
        self.full_reductions
            .fetch_add(full_reductions, Ordering::Relaxed);
        self.full_micros
            .fetch_add((full_seconds * 1e6) as u64, Ordering::Relaxed);
    }

    /// `prom.evaluate(values, derivatives, keep)`, counted.
    pub(crate) fn evaluate(
        &self,
        prom: &mut ParametricReduction,
        values: &[f64],
        derivatives: bool,
        keep: bool,
    ) -> Result<nlsim_reduction::ParametricPoint> {
        let before = prom.stats();
        let point = prom.evaluate(values, derivatives, keep);
        let after = prom.stats();
        self.count(
            after.refreshes > before.refreshes,
            after.full_reductions - before.full_reductions,
            after.full_seconds - before.full_seconds,
        );
        point
    }

    /// The counters over `setup` (what building the objective did).
    pub(crate) fn stats(&self, setup: FeReductionStats) -> FeReductionStats {
        FeReductionStats {
            evaluations: self.evaluations.load(Ordering::Relaxed),
            refreshes: self.refreshes.load(Ordering::Relaxed),
            full_reductions: self.full_reductions.load(Ordering::Relaxed),
            full_seconds: self.full_micros.load(Ordering::Relaxed) as f64 * 1e-6,
            ..setup
        }
    }
}

/// What the FE-level reductions of an objective (and of all its copies) did so far.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FeReductionStats {
    /// Whether the parametric reduced model is used (else a full reduction per evaluation).
    pub parametric: bool,
    /// Basis vectors of the parametric model as built.
    pub basis_size: usize,
    /// Full reductions made while the objective was built (the nominal one and the
    /// parametric model's training).
    pub setup_reductions: usize,
    /// Evaluations of the linear part.
    pub evaluations: usize,
    /// Evaluations where the parametric model's certificate failed and the model was reduced
    /// in full (always every evaluation with [`FeReduction::Full`]).
    pub refreshes: usize,
    /// Full reductions made by the evaluations.
    pub full_reductions: usize,
    /// Seconds of those full reductions (summed over the threads).
    pub full_seconds: f64,
}

/// The reduction behind FE-level parameters.
#[derive(Debug)]
enum FeModel {
    Parametric(ParametricReduction),
    Full {
        model: Model,
        reduction: ReductionConfig,
        solver: EigenSolver,
    },
}

/// The FE model behind an objective with FE-level parameters (group scales, boundary
/// springs): each evaluation sets them on the parametric reduced model (or reduces the model
/// again with [`FeReduction::Full`]); their Jacobian columns come from the same model's
/// analytic sensitivities.
#[derive(Debug)]
struct FeLink {
    model: FeModel,
    /// Indices (in the specs) of the FE-level parameters.
    fe: Vec<usize>,
    counters: Arc<FeCounters>,
    setup: FeReductionStats,
}

impl Clone for FeLink {
    /// A copy with a fresh eigen solver (its symbolic analysis is redone on first need); the
    /// parametric basis is shared until the copy enriches it.
    fn clone(&self) -> Self {
        Self {
            model: match &self.model {
                FeModel::Parametric(p) => FeModel::Parametric(p.clone()),
                FeModel::Full {
                    model, reduction, ..
                } => FeModel::Full {
                    model: model.clone(),
                    reduction: reduction.clone(),
                    solver: EigenSolver::new(),
                },
            },
            fe: self.fe.clone(),
            counters: Arc::clone(&self.counters),
            setup: self.setup,
        }
    }
}

impl FeLink {
    fn param(&self, p: &Param) -> Result<f64> {
        match &self.model {
            FeModel::Parametric(r) => {
                let i = r
                    .params()
                    .iter()
                    .position(|q| q == p)
                    .ok_or_else(|| nlsim_kernel::param::unknown_param(p, r.params()))?;
                Ok(r.nominal()[i])
            }
            FeModel::Full { model, .. } => model.param(p),
        }
    }

    fn fe_parameters(&self) -> Vec<Param> {
        let model = match &self.model {
            FeModel::Parametric(r) => r.model(),
            FeModel::Full { model, .. } => model,
        };
        model
            .parameters()
            .into_iter()
            .filter(|p| !matches!(p, Param::Element { .. }))
            .collect()
    }
}

/// True for the parameters of the reduced model's linear part, which an FE-level parameter
/// would overwrite when the model is reduced again.
fn is_linear_part_param(p: &Param) -> bool {
    matches!(
        p,
        Param::ModalFrequency(_)
            | Param::ModalDamping(_)
            | Param::ModalMass(_)
            | Param::StiffnessScale
            | Param::Residual(..)
            | Param::ModeShape { .. }
    )
}

/// The objective: a harmonic balance system, test data, parameters and which points are
/// trained on. Cloning is cheap enough for one clone per parallel task.
#[derive(Debug, Clone)]
pub struct FrfObjective {
    sys: HbSystem,
    /// Newton buffers and the receptances at the data's frequencies, reused from one
    /// evaluation to the next while the linear part is unchanged.
    ws: HbWorkspace,
    fe: Option<FeLink>,
    data: Arc<TestData>,
    specs: Vec<ParamSpec>,
    config: ObjectiveConfig,
    /// Model sensor index of each data channel.
    sensor_of: Vec<usize>,
    /// Model input index of the drive point.
    input: usize,
    /// Training mask per point (in [`TestData::points`] order).
    training: Vec<bool>,
    /// Every point of the data, in [`TestData::points`] order.
    points: Vec<PointId>,
    /// The data's gains: fixed values, or the nominal ones of calibrated gains.
    gains: Gains,
    /// The shaker a voltage record drives the model through, when modelled.
    shaker: Option<crate::coupling::Shaker>,
}

fn exponent(q: Quantity) -> i32 {
    match q {
        Quantity::Displacement => 0,
        Quantity::Velocity => 1,
        Quantity::Acceleration => 2,
    }
}

impl FrfObjective {
    /// The objective of `data` on `sys` over `specs`. Errors when a data channel or the
    /// drive point has no model counterpart, a parameter is unknown to the system or its
    /// bounds are invalid, a compared harmonic is absent from the data, or the system uses
    /// sub-harmonics.
    pub fn new(
        sys: &HbSystem,
        data: Arc<TestData>,
        specs: Vec<ParamSpec>,
        config: ObjectiveConfig,
    ) -> Result<Self> {
        Self::build(sys, None, data, specs, config)
    }

    /// The objective of `data` on `model` reduced by `reduction` and balanced with the
    /// harmonics `set`: as [`FrfObjective::new`], and the parameters may also be FE-level
    /// ones of the model (`group:NAME.k_scale`, `group:NAME.m_scale`, `spring:NODE:COMP.k`),
    /// next to element law parameters. These go through the parametric reduced model with
    /// its default settings ([`FrfObjective::from_model_with`]).
    pub fn from_model(
        model: &Model,
        reduction: &ReductionConfig,
        set: HarmonicSet,
        hb: HbConfig,
        data: Arc<TestData>,
        specs: Vec<ParamSpec>,
        config: ObjectiveConfig,
    ) -> Result<Self> {
        Self::from_model_with(
            model,
            reduction,
            &FeReduction::default(),
            set,
            hb,
            data,
            specs,
            config,
        )
    }

    /// As [`FrfObjective::from_model`], with the FE-level parameters reduced as `fe` says.
    ///
    /// With [`FeReduction::Parametric`] the parametric reduced model
    /// ([`ParametricReduction`]) is built here: the nominal reduction, then a greedy
    /// training over the corners and the centre of the FE-level parameters' box (their
    /// internal, possibly logarithmic, coordinates; the centre and the face centres beyond
    /// four parameters). Each evaluation then solves a dense eigenproblem of the basis's size
    /// and checks the result against the full matrices; where that certificate fails the
    /// model is reduced in full there, and an evaluation with a Jacobian keeps the enrichment
    /// in its copy of the objective (the optimisations and folds run sequentially on their
    /// own copies, so the estimates do not depend on the thread count). The Jacobian columns
    /// come from the same projected matrices. With [`FeReduction::Full`] the model is reduced
    /// again at every evaluation (one eigen solve; the symbolic analysis kept) and the
    /// Jacobian columns come from [`nlsim_reduction::reduced_sensitivities`]. Either way
    /// these reductions run on one thread (`Par::Seq`), so that the results do not depend on
    /// the thread count. Modal parameters (`modeN.f`, ...) cannot be mixed with FE-level
    /// ones, which define them.
    #[allow(clippy::too_many_arguments)]
    pub fn from_model_with(
        model: &Model,
        reduction: &ReductionConfig,
        fe: &FeReduction,
        set: HarmonicSet,
        hb: HbConfig,
        data: Arc<TestData>,
        specs: Vec<ParamSpec>,
        config: ObjectiveConfig,
    ) -> Result<Self> {
        let fe_idx: Vec<usize> = specs
            .iter()
            .enumerate()
            .filter(|(_, s)| model.matrix_derivative(&s.param).is_ok())
            .map(|(i, _)| i)
            .collect();
        if fe_idx.is_empty() {
            let mut solver = EigenSolver::new();
            let reduced = reduce_with(model, reduction, &mut solver, &mut |_| {})?;
            let sys = HbSystem::from_model(model, &reduced, set, hb)?;
            return Self::build(&sys, None, data, specs, config);
        }
        if let Some(s) = specs.iter().find(|s| is_linear_part_param(&s.param)) {
            return Err(Error::invalid(
                "calibration",
                format!(
                    "{} is a parameter of the reduced model, which the FE-level parameter {} \
                     changes: calibrate one kind or the other",
                    s.param, specs[fe_idx[0]].param
                ),
            ));
        }
        for &i in &fe_idx {
            specs[i].check()?;
        }
        let mut reduction = reduction.clone();
        reduction.eigen.par = faer::Par::Seq;
        let (fe_model, reduced, setup) = match fe {
            FeReduction::Parametric(settings) => {
                let params: Vec<Param> = fe_idx.iter().map(|&i| specs[i].param.clone()).collect();
                let fe_specs: Vec<&ParamSpec> = fe_idx.iter().map(|&i| &specs[i]).collect();
                let training = training_points(&fe_specs);
                let mut prom = ParametricReduction::new(
                    model,
                    &reduction,
                    &params,
                    settings.clone(),
                    &training,
                    &mut |_| {},
                )?;
                let nominal = prom.nominal().to_vec();
                let point = prom.evaluate(&nominal, false, true)?;
                let st = prom.stats();
                let setup = FeReductionStats {
                    parametric: true,
                    basis_size: st.basis_size,
                    setup_reductions: st.full_reductions,
                    ..FeReductionStats::default()
                };
                (FeModel::Parametric(prom), point.reduced, setup)
            }
            FeReduction::Full => {
                let mut solver = EigenSolver::new();
                let reduced = reduce_with(model, &reduction, &mut solver, &mut |_| {})?;
                let setup = FeReductionStats {
                    setup_reductions: 1,
                    ..FeReductionStats::default()
                };
                (
                    FeModel::Full {
                        model: model.clone(),
                        reduction,
                        solver,
                    },
                    reduced,
                    setup,
                )
            }
        };
        let sys = HbSystem::from_model(model, &reduced, set, hb)?;
        let link = FeLink {
            model: fe_model,
            fe: fe_idx,
            counters: Arc::new(FeCounters::default()),
            setup,
        };
        Self::build(&sys, Some(link), data, specs, config)
    }

    /// What the FE-level reductions did so far, over every copy of this objective; `None`
    /// without FE-level parameters.
    pub fn fe_stats(&self) -> Option<FeReductionStats> {
        self.fe.as_ref().map(|l| l.counters.stats(l.setup))
    }

    fn build(
        sys: &HbSystem,
        fe: Option<FeLink>,
        data: Arc<TestData>,
        specs: Vec<ParamSpec>,
        config: ObjectiveConfig,
    ) -> Result<Self> {
        data.validate()?;
        if specs.is_empty() {
            return Err(Error::invalid("calibration", "no parameters to calibrate"));
        }
        let mut known = sys.parameters();
        if let Some(link) = &fe {
            known.extend(link.fe_parameters());
        }
        known.push(Param::InputGain);
        known.extend(
            data.channels
                .iter()
                .map(|c| Param::SensorGain(c.name.clone())),
        );
        for (i, s) in specs.iter().enumerate() {
            s.check()?;
            if fe.as_ref().is_some_and(|l| l.fe.contains(&i)) {
                continue;
            }
            if s.param.is_gain() {
                if !known.contains(&s.param) {
                    return Err(Error::UnknownParameter {
                        name: s.param.to_string(),
                        known: known
                            .iter()
                            .map(ToString::to_string)
                            .collect::<Vec<_>>()
                            .join(", "),
                    });
                }
                if s.lower.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                    return Err(Error::invalid(
                        format!("parameter '{}'", s.param),
                        format!(
                            "a gain is positive: its lower bound {} must be > 0",
                            s.lower
                        ),
                    ));
                }
                continue;
            }
            sys.param(&s.param)?;
            if !known.contains(&s.param) {
                return Err(nlsim_kernel::param::unknown_param(&s.param, &known));
            }
        }
        for (i, a) in specs.iter().enumerate() {
            if specs[..i].iter().any(|b| b.param == a.param) {
                return Err(Error::invalid(
                    "calibration",
                    format!("parameter {} is listed twice", a.param),
                ));
            }
        }
        if sys.harmonics().nu != 1 {
            return Err(Error::invalid(
                "calibration",
                "stepped-sine data are harmonics of the excitation: use a harmonic set with ν = 1",
            ));
        }
        if config.harmonics.is_empty() {
            return Err(Error::invalid("calibration", "no harmonics to compare"));
        }
        for &k in &config.harmonics {
            if k == 0 || k > data.harmonics {
                return Err(Error::invalid(
                    "calibration",
                    format!(
                        "harmonic {k} is not in the test data (it holds 1..={})",
                        data.harmonics
                    ),
                ));
            }
            if k > sys.harmonics().h {
                return Err(Error::invalid(
                    "calibration",
                    format!(
                        "harmonic {k} is above the model's H = {}",
                        sys.harmonics().h
                    ),
                ));
            }
        }
        let names = |v: Vec<&str>| v.join(", ");
        let sensor_of = data
            .channels
            .iter()
            .map(|c| {
                sys.sensors()
                    .iter()
                    .position(|s| s.name == c.name)
                    .ok_or_else(|| {
                        Error::invalid(
                            format!("test data channel '{}'", c.name),
                            format!(
                                "the model has no sensor of that name (it has: {})",
                                names(sys.sensors().iter().map(|s| s.name.as_str()).collect())
                            ),
                        )
                    })
            })
            .collect::<Result<Vec<_>>>()?;
        let input = sys
            .inputs()
            .iter()
            .position(|(n, _)| n == &data.input)
            .ok_or_else(|| {
                Error::invalid(
                    format!("test data drive point '{}'", data.input),
                    format!(
                        "the model has no input of that name (it has: {})",
                        names(sys.inputs().iter().map(|(n, _)| n.as_str()).collect())
                    ),
                )
            })?;
        let points = data.points();
        Ok(Self {
            ws: sys.workspace(RECEPTANCE_BUDGET),
            sys: sys.clone(),
            fe,
            training: vec![true; points.len()],
            points,
            data,
            specs,
            config,
            gains: Gains {
                input: 1.0,
                sensors: vec![1.0; sys.sensors().len()],
            },
            shaker: None,
            sensor_of,
            input,
        })
    }

    /// The same system, FE link and parameters on other test data with other settings
    /// (the data's channels and drive point checked as in [`FrfObjective::new`]): what the
    /// test planner uses to evaluate candidate tests.
    pub fn with_data(&self, data: Arc<TestData>, config: ObjectiveConfig) -> Result<Self> {
        let mut obj = Self::build(&self.sys, self.fe.clone(), data, self.specs.clone(), config)?;
        obj.gains = self.gains.clone();
        obj.set_shaker(self.shaker)?;
        Ok(obj)
    }

    /// The parameters.
    pub fn specs(&self) -> &[ParamSpec] {
        &self.specs
    }

    /// The test data.
    pub fn data(&self) -> &TestData {
        &self.data
    }

    /// The settings.
    pub fn config(&self) -> &ObjectiveConfig {
        &self.config
    }

    /// The harmonic balance system (with the parameters last evaluated).
    pub fn system(&self) -> &HbSystem {
        &self.sys
    }

    /// Restricts the residuals to the points `training[i]` (in [`TestData::points`] order).
    pub fn set_training(&mut self, training: Vec<bool>) -> Result<()> {
        if training.len() != self.points.len() {
            return Err(Error::DimensionMismatch {
                what: "training mask".into(),
                expected: self.points.len(),
                found: training.len(),
            });
        }
        self.training = training;
        Ok(())
    }

    /// The training mask.
    pub fn training(&self) -> &[bool] {
        &self.training
    }

    /// Internal variables of parameter values `p`.
    pub fn to_internal(&self, p: &[f64]) -> Vec<f64> {
        specs_to_internal(&self.specs, p)
    }

    /// Parameter values of internal variables `u`.
    pub fn to_values(&self, u: &[f64]) -> Vec<f64> {
        specs_to_values(&self.specs, u)
    }

    /// Internal bounds `(lower, upper)`.
    pub fn internal_bounds(&self) -> (Vec<f64>, Vec<f64>) {
        self.specs.iter().map(ParamSpec::internal_bounds).unzip()
    }

    /// The residuals (and with `jacobian` their derivatives) of the points in `mask`, at
    /// parameter values `values`.
    ///
    /// Every point is solved (the sweeps are followed through the held-out points too);
    /// points that fail are listed in [`SweepEvaluation::failed`].
    pub fn evaluate_values(
        &mut self,
        values: &[f64],
        mask: Option<&[bool]>,
        jacobian: bool,
    ) -> Result<SweepEvaluation> {
        self.evaluate(values, mask, jacobian, false)
    }

    /// [`FrfObjective::evaluate_values`] at `values` with no residuals, and with every
    /// converged point's [`PointResult::sensitivity`]: what a prediction's band is propagated
    /// through (`nlsim validate`).
    pub fn evaluate_with_sensitivities(&mut self, values: &[f64]) -> Result<SweepEvaluation> {
        let none = vec![false; self.points.len()];
        self.evaluate(values, Some(&none), false, true)
    }

    /// The evaluation behind [`FrfObjective::evaluate_values`]; with `point_sensitivities`
    /// every converged point carries its response sensitivities.
    fn evaluate(
        &mut self,
        values: &[f64],
        mask: Option<&[bool]>,
        jacobian: bool,
        point_sensitivities: bool,
    ) -> Result<SweepEvaluation> {
        if values.len() != self.specs.len() {
            return Err(Error::DimensionMismatch {
                what: "calibration parameter values".into(),
                expected: self.specs.len(),
                found: values.len(),
            });
        }
        let params: Vec<Param> = self.specs.iter().map(|s| s.param.clone()).collect();
        let fe_idx: Vec<usize> = self.fe.as_ref().map_or(Vec::new(), |l| l.fe.clone());
        let sys_idx: Vec<usize> = (0..params.len())
            .filter(|i| !fe_idx.contains(i) && !params[*i].is_gain())
            .collect();
        let sys_params: Vec<Param> = sys_idx.iter().map(|&i| params[i].clone()).collect();
        let sys_values: Vec<f64> = sys_idx.iter().map(|&i| values[i]).collect();
        self.sys.set_params(&sys_params, &sys_values)?;
        let gains = self.gains_at(values)?;
        let variations = match self.update_fe(values, jacobian || point_sensitivities)? {
            Some(v) => v,
            None => return Ok(self.all_failed(Status::NonFinite)),
        };
        let dvalue: Vec<f64> = self
            .specs
            .iter()
            .zip(values)
            .map(|(s, &v)| s.dvalue(s.to_internal(v)))
            .collect();
        let mask = mask.unwrap_or(&self.training).to_vec();
        let data = Arc::clone(&self.data);
        let h_data = data.harmonics;
        let h_model = self.sys.harmonics().h;
        let mut residuals = Vec::new();
        let mut rows: Vec<Vec<f64>> = Vec::new();
        let mut points = Vec::with_capacity(self.points.len());
        let mut failed = Vec::new();
        let mut index = 0usize;
        for (s, sw) in data.sweeps.iter().enumerate() {
            let mut prev: Option<Previous> = None;
            for (i, st) in sw.steps.iter().enumerate() {
                let id = PointId { sweep: s, step: i };
                let train = mask[index];
                index += 1;
                let omega = 2.0 * PI * st.frequency_hz;
                let solved = self.solve_driven(st, omega, &gains, prev.as_ref())?;
                let (solved, status) = match solved {
                    Ok(v) => (v, Status::Converged),
                    Err(status) => {
                        failed.push(id);
                        points.push(PointResult {
                            id,
                            status,
                            response: Mat::from_fn(data.channels.len(), h_data, |_, _| {
                                c64::new(f64::NAN, f64::NAN)
                            }),
                            sensitivity: Vec::new(),
                        });
                        prev = None;
                        continue;
                    }
                };
                let mut solved = solved;
                let mut y = self.sys.sensor_response(&solved.x, omega, 1.0);
                let mut response = self.channel_response(&y, omega, &gains);
                if self.config.branch == BranchChoice::NearestToData {
                    let misfit = self.misfit(st, &response);
                    if misfit > BRANCH_CHECK {
                        // Far from the measurement: the test may sit on another branch
                        // (it jumped earlier or later than the model's continuation).
                        if let Ok(other) = self.solve_driven(st, omega, &gains, None)? {
                            let y2 = self.sys.sensor_response(&other.x, omega, 1.0);
                            let r = self.channel_response(&y2, omega, &gains);
                            if self.misfit(st, &r) < misfit {
                                solved = other;
                                y = y2;
                                response = r;
                            }
                        }
                        // The forcing of the solution kept.
                        self.set_solved_force(&solved)?;
                    }
                }
                let sens = if (jacobian && train) || point_sensitivities {
                    let a = self.sys.sensitivities(&solved.x, omega, 1.0, &sys_params)?;
                    let b = self
                        .sys
                        .variation_sensitivities(&solved.x, omega, 1.0, &variations)?;
                    let mut d: Vec<Option<Mat<c64>>> = vec![None; params.len()];
                    for (sv, &j) in a.into_iter().zip(&sys_idx) {
                        d[j] = Some(sv.dy);
                    }
                    for (sv, &j) in b.into_iter().zip(&fe_idx) {
                        d[j] = Some(sv.dy);
                    }
                    Some(self.complete_sensitivities(st, omega, &solved, &y, &gains, d)?)
                } else {
                    None
                };
                if train {
                    for c in 0..data.channels.len() {
                        for &k in &self.config.harmonics {
                            let yd = st.response[(c, k - 1)];
                            if yd.re.is_nan() {
                                continue;
                            }
                            let (s_re, s_im) = st.sigma_parts(c, k, yd, &data.channels[c].noise);
                            if s_re <= 0.0 || s_im <= 0.0 {
                                return Err(Error::invalid(
                                    format!(
                                        "test data channel '{}', sweep '{}' step {} ({} Hz), \
                                         harmonic {k}",
                                        data.channels[c].name,
                                        sw.label,
                                        i + 1,
                                        st.frequency_hz
                                    ),
                                    "the noise estimate is zero here (a relative noise on a \
                                     zero response): give an absolute noise floor",
                                ));
                            }
                            let ym = response[(c, k - 1)];
                            let f = self.quantity_factor(c, k, omega);
                            let dy: Vec<c64> = sens
                                .as_ref()
                                .map(|ss| {
                                    ss.iter().map(|d| d[(self.sensor_of[c], k)] * f).collect()
                                })
                                .unwrap_or_default();
                            match self.config.form {
                                Form::Complex => {
                                    residuals.push((ym.re - yd.re) / s_re);
                                    residuals.push((ym.im - yd.im) / s_im);
                                    if jacobian {
                                        rows.push(
                                            dy.iter()
                                                .zip(&dvalue)
                                                .map(|(d, dv)| d.re * dv / s_re)
                                                .collect(),
                                        );
                                        rows.push(
                                            dy.iter()
                                                .zip(&dvalue)
                                                .map(|(d, dv)| d.im * dv / s_im)
                                                .collect(),
                                        );
                                    }
                                }
                                Form::LogMagnitudePhase => {
                                    // The noise along Y (its amplitude) and across it (its
                                    // phase) from that of the real and imaginary parts.
                                    let (cos, sin) = (yd.re / yd.norm(), yd.im / yd.norm());
                                    let (sr2, si2) = (s_re * s_re, s_im * s_im);
                                    let s_amp = (sr2 * cos * cos + si2 * sin * sin).sqrt();
                                    let s_phase = (sr2 * sin * sin + si2 * cos * cos).sqrt();
                                    let (wa, wp) = (yd.norm() / s_amp, yd.norm() / s_phase);
                                    let dphase = wrap(ym.arg() - yd.arg());
                                    residuals.push((ym.norm().ln() - yd.norm().ln()) * wa);
                                    residuals.push(dphase * wp);
                                    if jacobian {
                                        let rel: Vec<c64> = dy.iter().map(|d| *d / ym).collect();
                                        rows.push(
                                            rel.iter()
                                                .zip(&dvalue)
                                                .map(|(d, dv)| d.re * dv * wa)
                                                .collect(),
                                        );
                                        rows.push(
                                            rel.iter()
                                                .zip(&dvalue)
                                                .map(|(d, dv)| d.im * dv * wp)
                                                .collect(),
                                        );
                                    }
                                }
                            }
                        }
                    }
                }
                let sensitivity = match (&sens, point_sensitivities) {
                    (Some(ss), true) => {
                        let h = h_data.min(h_model);
                        ss.iter()
                            .map(|d| {
                                Mat::from_fn(data.channels.len(), h_data, |c, j| {
                                    if j < h {
                                        d[(self.sensor_of[c], j + 1)]
                                            * self.quantity_factor(c, j + 1, omega)
                                    } else {
                                        c64::new(f64::NAN, f64::NAN)
                                    }
                                })
                            })
                            .collect()
                    }
                    _ => Vec::new(),
                };
                points.push(PointResult {
                    id,
                    status,
                    response,
                    sensitivity,
                });
                prev = Some(Previous {
                    state: (solved.x, omega),
                    phi: solved.coupled.map(|c| c.phi),
                });
            }
        }
        let jac = jacobian.then(|| Mat::from_fn(rows.len(), self.specs.len(), |i, j| rows[i][j]));
        Ok(SweepEvaluation {
            residuals,
            jacobian: jac,
            points,
            failed,
        })
    }

    /// The factor from a model sensor's quantity to data channel `c`'s at harmonic `k` of
    /// `omega` (rad/s): `(i k ω)^(p_data − p_model)` with `p` 0, 1, 2 for displacement,
    /// velocity, acceleration.
    fn quantity_factor(&self, c: usize, k: usize, omega: f64) -> c64 {
        let pm = exponent(self.sys.sensors()[self.sensor_of[c]].quantity);
        let pd = exponent(self.data.channels[c].quantity);
        let iw = c64::new(0.0, k as f64 * omega);
        let mut f = c64::new(1.0, 0.0);
        for _ in 0..(pd - pm).abs() {
            f *= iw;
        }
        if pd >= pm { f } else { f.inv() }
    }

    /// The mean squared normalised complex residual of `response` against step `st` over
    /// the channels and compared harmonics with a measurement and a positive noise (0 when
    /// there is none).
    fn misfit(&self, st: &crate::data::Step, response: &Mat<c64>) -> f64 {
        let mut sum = 0.0;
        let mut n = 0usize;
        for (c, ch) in self.data.channels.iter().enumerate() {
            for &k in &self.config.harmonics {
                if k == 0 || k > st.response.ncols() || k > response.ncols() {
                    continue;
                }
                let (yd, ym) = (st.response[(c, k - 1)], response[(c, k - 1)]);
                let (s_re, s_im) = st.sigma_parts(c, k, yd, &ch.noise);
                if yd.re.is_nan() || ym.re.is_nan() || s_re <= 0.0 || s_im <= 0.0 {
                    continue;
                }
                let d = ym - yd;
                sum += (d.re / s_re).powi(2) + (d.im / s_im).powi(2);
                n += 1;
            }
        }
        if n == 0 { 0.0 } else { sum / n as f64 }
    }

    /// Sets the FE-level parameters of `values` on the parametric model (or the full model,
    /// reduced again) and puts the new linear part into the system; with `jacobian`, the
    /// variations of the linear part along each FE-level parameter (in their spec order).
    /// `Ok(None)` when the reduction fails numerically at these values. Nothing to do (an
    /// empty list) without FE-level parameters.
    fn update_fe(
        &mut self,
        values: &[f64],
        jacobian: bool,
    ) -> Result<Option<Vec<LinearVariation>>> {
        let Some(link) = &mut self.fe else {
            return Ok(Some(Vec::new()));
        };
        let params: Vec<Param> = link
            .fe
            .iter()
            .map(|&i| self.specs[i].param.clone())
            .collect();
        let fe_values: Vec<f64> = link.fe.iter().map(|&i| values[i]).collect();
        match &mut link.model {
            FeModel::Parametric(prom) => {
                // An evaluation with a Jacobian (an optimisation step, sequential on its own
                // copy) keeps an enrichment; a cost-only one (the candidates, run in parallel
                // on shared copies) does not, so that no result depends on the scheduling.
                let point = link.counters.evaluate(prom, &fe_values, jacobian, jacobian);
                let point = match point {
                    Ok(p) => p,
                    Err(Error::Numerical { .. }) => return Ok(None),
                    Err(e) => return Err(e),
                };
                self.sys
                    .set_linear(LinearPart::from_reduced(&point.reduced)?)?;
                let Some(d) = point.derivatives else {
                    return Ok(Some(Vec::new()));
                };
                Ok(Some(variations(
                    params,
                    &d.eigenvalues,
                    d.damping,
                    d.participation,
                    d.residual,
                )))
            }
            FeModel::Full {
                model,
                reduction,
                solver,
            } => {
                for (p, &v) in params.iter().zip(&fe_values) {
                    model.set_param(p, v)?;
                }
                let t = std::time::Instant::now();
                let reduced = reduce_with(model, reduction, solver, &mut |_| {});
                link.counters.count(true, 1, t.elapsed().as_secs_f64());
                let reduced = match reduced {
                    Ok(r) => r,
                    Err(Error::Numerical { .. }) => return Ok(None),
                    Err(e) => return Err(e),
                };
                self.sys.set_linear(LinearPart::from_reduced(&reduced)?)?;
                if !jacobian {
                    return Ok(Some(Vec::new()));
                }
                let d = reduced_sensitivities(
                    model,
                    &reduced,
                    solver,
                    &params,
                    &SensitivityConfig {
                        par: reduction.eigen.par,
                        ..SensitivityConfig::default()
                    },
                )?;
                Ok(Some(variations(
                    params,
                    &d.eigen.eigenvalue,
                    d.damping,
                    d.participation,
                    d.residual,
                )))
            }
        }
    }

    /// Every point failed with `status` (the model could not be set up at these values).
    fn all_failed(&self, status: Status) -> SweepEvaluation {
        let h = self.data.harmonics;
        let nc = self.data.channels.len();
        SweepEvaluation {
            residuals: Vec::new(),
            jacobian: None,
            points: self
                .points
                .iter()
                .map(|&id| PointResult {
                    id,
                    status,
                    response: Mat::from_fn(nc, h, |_, _| c64::new(f64::NAN, f64::NAN)),
                    sensitivity: Vec::new(),
                })
                .collect(),
            failed: self.points.clone(),
        }
    }

    /// The current value of a calibrated parameter: on the FE model for an FE-level one,
    /// else on the system.
    pub fn param_value(&self, p: &Param) -> Result<f64> {
        if p.is_gain() {
            return self.gain(p);
        }
        match &self.fe {
            Some(link) if link.fe.iter().any(|&i| self.specs[i].param == *p) => link.param(p),
            _ => self.sys.param(p),
        }
    }

    /// Cost `½‖r‖²` of the training points at values `values`; infinite when a point fails.
    pub fn cost_values(&mut self, values: &[f64]) -> Result<f64> {
        let ev = self.evaluate_values(values, None, false)?;
        if !ev.failed.is_empty() {
            return Ok(f64::INFINITY);
        }
        Ok(0.5 * ev.residuals.iter().map(|r| r * r).sum::<f64>())
    }
}

/// The variations of the linear part along `params` from their derivatives: eigenvalues
/// (modes × parameters), and per parameter the modal damping, participation and residual.
fn variations(
    params: Vec<Param>,
    eigenvalues: &Mat<f64>,
    damping: Vec<Mat<f64>>,
    participation: Vec<Mat<f64>>,
    residual: Vec<Mat<f64>>,
) -> Vec<LinearVariation> {
    params
        .into_iter()
        .zip(damping.into_iter().zip(participation).zip(residual))
        .enumerate()
        .map(
            |(j, (param, ((damping, participation), residual)))| LinearVariation {
                param,
                eigenvalues: eigenvalues.col(j).iter().copied().collect(),
                damping,
                participation,
                residual,
            },
        )
        .collect()
}

/// The parametric model's training points over the box of `specs` (values, in their
/// order): the centre and the corners of the box in the internal coordinates (the centre and
/// the face centres beyond four parameters).
pub(crate) fn training_points(specs: &[&ParamSpec]) -> Vec<Vec<f64>> {
    let n = specs.len();
    let (lo, hi): (Vec<f64>, Vec<f64>) = specs.iter().map(|s| s.internal_bounds()).unzip();
    let centre: Vec<f64> = (0..n).map(|j| 0.5 * (lo[j] + hi[j])).collect();
    let mut internal = vec![centre.clone()];
    if n <= 4 {
        for mask in 0..(1usize << n) {
            internal.push(
                (0..n)
                    .map(|j| if mask >> j & 1 == 1 { hi[j] } else { lo[j] })
                    .collect(),
            );
        }
    } else {
        for j in 0..n {
            for end in [lo[j], hi[j]] {
                let mut p = centre.clone();
                p[j] = end;
                internal.push(p);
            }
        }
    }
    internal
        .into_iter()
        .map(|u| specs.iter().zip(u).map(|(s, v)| s.to_value(v)).collect())
        .collect()
}

/// Wraps an angle to `(−π, π]`.
pub fn wrap(a: f64) -> f64 {
    let mut w = a.rem_euclid(2.0 * PI);
    if w > PI {
        w -= 2.0 * PI;
    }
    w
}

impl LeastSquares for FrfObjective {
    fn n_params(&self) -> usize {
        self.specs.len()
    }

    fn evaluate(&mut self, u: &[f64]) -> Result<Option<Evaluation>> {
        let values = self.to_values(u);
        let ev = self.evaluate_values(&values, None, true)?;
        if !ev.failed.is_empty() {
            return Ok(None);
        }
        Ok(Some(Evaluation {
            residuals: ev.residuals,
            jacobian: ev.jacobian.expect("asked for"),
        }))
    }
}
