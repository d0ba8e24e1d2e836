//! `nlsim.calibrate`: parameters fitted to a stepped-sine test (thesis §4.5–4.6) as `nlsim
//! calibrate MODEL DATA --param …` does it — maximin Latin-hypercube candidates, bounded
//! Levenberg–Marquardt from the best starts, Cramér–Rao bounds at the optimum, k-fold cross
//! validation — with the command's defaults, so the estimates are the command's to the bit.

use crate::data::TestData;
use crate::model::Model;
use crate::runs::{Ended, Stop, run_keeping};
use crate::{input, py_err};
use nlsim::calib::{
    BranchChoice, CalibrationConfig, FeReduction, FeReductionStats, Form, FrfObjective,
    ObjectiveConfig, ParamSpec, ParametricConfig,
};
use nlsim::hb::HbConfig;
use nlsim::kernel::{Param, Parameterized};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::Arc;

/// The result of a calibration (`nlsim.calibrate`); arrays are per parameter in the order of
/// `params` unless noted.
#[pyclass(module = "nlsim._native", name = "Calibration", frozen)]
pub struct Calibration {
    c: nlsim::calib::Calibration,
    fe: Option<FeReductionStats>,
}

fn vec1<'py>(py: Python<'py>, v: Vec<f64>) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_vec(py, v)
}

/// The `#[pymethods]` of a calibration result class `$ty` (whose result is `self.c`, with
/// `params`, `estimate`, `status`, `cost`, `cramer_rao`, `at_bound` and `candidates`): the
/// getters every calibration shares — `params`, `estimate`, `status`, `cost`,
/// `reduced_chi2`, `cramer_rao_std`, `chi2_scaled_std`, `covariance`, `at_bound`,
/// `candidates`, `candidate_cost` — and `__repr__` naming `$name`, then the class's own
/// methods `$extra`.
macro_rules! calibration_result {
    ($ty:ident, $name:literal, { $($extra:tt)* }) => {
        #[pyo3::pymethods]
        impl $ty {
            /// The calibrated parameters' names, in the order of every array.
            #[getter]
            fn params(&self) -> Vec<String> {
                self.c.params.iter().map(ToString::to_string).collect()
            }

            /// The estimate, shape `(param,)`, in each parameter's unit.
            #[getter]
            fn estimate<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::Bound<'py, numpy::PyArray1<f64>> {
                $crate::runs::vec1(py, self.c.estimate.clone())
            }

            /// `"converged"`, or why the best Levenberg–Marquardt run stopped.
            #[getter]
            fn status(&self) -> &'static str {
                self.c.status.as_str()
            }

            /// The cost `½ Σ r²` of the residuals (each over its standard deviation) at the
            /// estimate.
            #[getter]
            fn cost(&self) -> f64 {
                self.c.cost
            }

            /// Reduced χ² at the estimate (1 when the noise model fits the misfit).
            #[getter]
            fn reduced_chi2(&self) -> f64 {
                self.c.cramer_rao.reduced_chi2
            }

            /// Cramér–Rao standard deviations (the Fisher information's inverse; thesis
            /// eq. 36), shape `(param,)`.
            #[getter]
            fn cramer_rao_std<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::Bound<'py, numpy::PyArray1<f64>> {
                $crate::runs::vec1(py, self.c.cramer_rao.std.clone())
            }

            /// Cramér–Rao standard deviations scaled by √(reduced χ²): the spread when the
            /// residuals exceed the noise model, shape `(param,)` (docs/calibration.md).
            #[getter]
            fn chi2_scaled_std<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::Bound<'py, numpy::PyArray1<f64>> {
                $crate::runs::vec1(py, self.c.cramer_rao.scaled_std.clone())
            }

            /// The Cramér–Rao covariance, shape `(param, param)`.
            #[getter]
            fn covariance<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::Bound<'py, numpy::PyArray2<f64>> {
                $crate::calibration::covariance_array(py, &self.c.cramer_rao)
            }

            /// Whether each estimate sits at a bound.
            #[getter]
            fn at_bound(&self) -> Vec<bool> {
                self.c.at_bound.clone()
            }

            /// The candidates' values, shape `(candidate, param)`: the model's own values
            /// first, then the Latin hypercube.
            #[getter]
            fn candidates<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::Bound<'py, numpy::PyArray2<f64>> {
                $crate::calibration::candidates_array(py, &self.c.candidates, self.c.params.len())
            }

            /// The candidates' costs, shape `(candidate,)` (infinite where a model run failed).
            #[getter]
            fn candidate_cost<'py>(
                &self,
                py: pyo3::Python<'py>,
            ) -> pyo3::Bound<'py, numpy::PyArray1<f64>> {
                $crate::runs::vec1(py, self.c.candidates.iter().map(|c| c.cost).collect())
            }

            fn __repr__(&self) -> String {
                $crate::calibration::estimates_repr(
                    $name,
                    &self.c.params,
                    &self.c.estimate,
                    &self.c.cramer_rao,
                    self.c.status,
                )
            }

            $($extra)*
        }
    };
}
pub(crate) use calibration_result;

calibration_result!(Calibration, "Calibration", {
    /// What the evaluations of FE-level parameters did (`None` without them): a dict of
    /// `fe_reduction` (`"parametric"` or `"full"`), `basis_size`, `setup_reductions`,
    /// `evaluations`, `refreshes`, `full_reductions` and `full_seconds`.
    #[getter]
    fn fe_stats<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        fe_stats_dict(py, self.fe.as_ref())
    }

    /// Whether each parameter is poorly identified (relative Cramér–Rao std above 0.5 or
    /// part of a collinear pair).
    #[getter]
    fn poorly_identified(&self) -> Vec<bool> {
        self.c.poorly_identified.clone()
    }

    /// Mean of the k-fold estimates, shape `(param,)`; `None` without cross validation.
    #[getter]
    fn kfold_mean<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.c.kfold.as_ref().map(|k| vec1(py, k.mean.clone()))
    }

    /// Standard deviation of the k-fold estimates, shape `(param,)`.
    #[getter]
    fn kfold_std<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.c.kfold.as_ref().map(|k| vec1(py, k.std.clone()))
    }

    /// Jackknife standard deviation from the folds, shape `(param,)`.
    #[getter]
    fn jackknife_std<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.c
            .kfold
            .as_ref()
            .map(|k| vec1(py, k.jackknife_std.clone()))
    }
});

/// The Cramér–Rao covariance of `cr` as a `(param, param)` array.
pub(crate) fn covariance_array<'py>(
    py: Python<'py>,
    cr: &nlsim::calib::CramerRao,
) -> Bound<'py, PyArray2<f64>> {
    let m = &cr.covariance;
    Array2::from_shape_fn((m.nrows(), m.ncols()), |(i, j)| m[(i, j)]).into_pyarray(py)
}

/// The values of `candidates` (each of `n_params`) as a `(candidate, param)` array.
pub(crate) fn candidates_array<'py>(
    py: Python<'py>,
    candidates: &[nlsim::calib::Candidate],
    n_params: usize,
) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((candidates.len(), n_params), |(i, j)| {
        candidates[i].values[j]
    })
    .into_pyarray(py)
}

/// `<nlsim.KIND: p = v ± s, …; reduced chi2 …, status>`.
pub(crate) fn estimates_repr(
    kind: &str,
    params: &[Param],
    estimate: &[f64],
    cr: &nlsim::calib::CramerRao,
    status: nlsim::calib::Status,
) -> String {
    let parts: Vec<String> = params
        .iter()
        .zip(estimate)
        .zip(&cr.std)
        .map(|((p, e), s)| format!("{p} = {e:.6e} ± {s:.2e}"))
        .collect();
    format!(
        "<nlsim.{kind}: {}; reduced chi2 {:.3}, {}>",
        parts.join(", "),
        cr.reduced_chi2,
        status.as_str()
    )
}

/// The candidate search and optimisation settings of `nlsim calibrate` (`--lhs`, `--seed`,
/// `--starts`, `--folds`), the rest at their defaults; refused as the command refuses them.
pub(crate) fn search_config(
    lhs: usize,
    seed: u64,
    starts: usize,
    folds: usize,
) -> PyResult<CalibrationConfig> {
    let config = CalibrationConfig {
        lhs_samples: lhs,
        seed,
        starts,
        folds,
        ..CalibrationConfig::default()
    };
    config
        .validate_settings()
        .map_err(|e| input(e.to_string()))?;
    Ok(config)
}

/// The evaluation of FE-level parameters named by `fe_reduction` (`"parametric"`, the
/// default, or `"full"`) with the parametric model's certificate `fe_tolerance` (default
/// 1e-6; refused with `"full"`).
pub(crate) fn fe_reduction(kind: &str, tolerance: Option<f64>) -> PyResult<FeReduction> {
    match (kind, tolerance) {
        ("parametric", tol) => {
            let settings = ParametricConfig {
                tolerance: tol.unwrap_or(ParametricConfig::default().tolerance),
                ..ParametricConfig::default()
            };
            settings
                .check()
                .map_err(|e| input(format!("fe_tolerance: {e}")))?;
            Ok(FeReduction::Parametric(settings))
        }
        ("full", None) => Ok(FeReduction::Full),
        ("full", Some(_)) => Err(input(
            "fe_tolerance: a tolerance belongs to fe_reduction='parametric', not 'full'",
        )),
        (other, _) => Err(input(format!(
            "fe_reduction: '{other}'; use 'parametric' or 'full'"
        ))),
    }
}

/// What the FE-level evaluations did, as a dict (`None` without FE-level parameters).
pub(crate) fn fe_stats_dict<'py>(
    py: Python<'py>,
    fe: Option<&FeReductionStats>,
) -> PyResult<Option<Bound<'py, PyDict>>> {
    let Some(fe) = fe else { return Ok(None) };
    let d = PyDict::new(py);
    d.set_item(
        "fe_reduction",
        if fe.parametric { "parametric" } else { "full" },
    )?;
    d.set_item("basis_size", fe.basis_size)?;
    d.set_item("setup_reductions", fe.setup_reductions)?;
    d.set_item("evaluations", fe.evaluations)?;
    d.set_item("refreshes", fe.refreshes)?;
    d.set_item("full_reductions", fe.full_reductions)?;
    d.set_item("full_seconds", fe.full_seconds)?;
    Ok(Some(d))
}

/// The test data a calibration runs on: given as `TestData`, or a file read for the model.
enum Source {
    Given(Arc<nlsim::calib::TestData>),
    File(PathBuf),
}

impl Source {
    fn of(data: &Bound<'_, PyAny>) -> PyResult<Self> {
        if let Ok(d) = data.cast::<TestData>() {
            return Ok(Source::Given(d.get().data.clone()));
        }
        data.extract::<PathBuf>()
            .map(Source::File)
            .map_err(|_| input("data: expected an nlsim.TestData or the path of a test data file"))
    }

    fn read(
        self,
        m: &nlsim::kernel::Model,
        uff_noise: f64,
    ) -> nlsim::Result<Arc<nlsim::calib::TestData>> {
        match self {
            Source::Given(d) => Ok(d),
            Source::File(path) => {
                let options = nlsim::formats::test_data::DataOptions {
                    noise: uff_noise,
                    ..Default::default()
                };
                Ok(Arc::new(nlsim::formats::test_data::read(
                    &path, m, &options,
                )?))
            }
        }
    }
}

/// Fixed gains `{name: value}` of `gains` (gain parameters only, checked by the objective).
fn fixed_gains(gains: Option<&Bound<'_, PyDict>>) -> PyResult<Vec<(Param, f64)>> {
    let mut out = Vec::new();
    for (k, v) in gains.into_iter().flat_map(|g| g.iter()) {
        let name: String = k
            .extract()
            .map_err(|_| input("gains: keys are gain names, e.g. 'input_gain'"))?;
        let p: Param = name.parse().ok().filter(Param::is_gain).ok_or_else(|| {
            input(format!(
                "gains: '{name}' is no gain; use 'input_gain' or 'sensor_gain:CHANNEL'"
            ))
        })?;
        let value: f64 = v
            .extract()
            .map_err(|_| input(format!("gains['{name}']: expected a number")))?;
        out.push((p, value));
    }
    Ok(out)
}

/// The shaker of `shaker`: `None`/`False` none, `True` nlsim's default, or a dict of fields.
pub(crate) fn shaker_of(
    shaker: Option<&Bound<'_, PyAny>>,
) -> PyResult<Option<nlsim::calib::Shaker>> {
    let Some(s) = shaker else { return Ok(None) };
    if let Ok(on) = s.extract::<bool>() {
        return Ok(on.then(nlsim::calib::Shaker::default));
    }
    let d = s
        .cast::<PyDict>()
        .map_err(|_| input("shaker: True, or a dict of the shaker's fields"))?;
    let mut sh = nlsim::calib::Shaker::default();
    for (k, v) in d.iter() {
        let name: String = k
            .extract()
            .map_err(|_| input("shaker: keys are field names, e.g. 'resistance'"))?;
        let value: f64 = v
            .extract()
            .map_err(|_| input(format!("shaker['{name}']: expected a number")))?;
        let field = match name.as_str() {
            "armature_mass" => &mut sh.armature_mass,
            "suspension_stiffness" => &mut sh.suspension_stiffness,
            "suspension_damping" => &mut sh.suspension_damping,
            "resistance" => &mut sh.resistance,
            "inductance" => &mut sh.inductance,
            "force_constant" => &mut sh.force_constant,
            "stinger_stiffness" => &mut sh.stinger_stiffness,
            other => {
                return Err(input(format!(
                    "shaker: '{other}' is no field; use armature_mass, suspension_stiffness, \
                     suspension_damping, resistance, inductance, force_constant or \
                     stinger_stiffness"
                )));
            }
        };
        *field = value;
    }
    sh.check().map_err(|e| input(format!("shaker: {e}")))?;
    Ok(Some(sh))
}

/// The parameters `{name: (lower, upper)}` of `params`, each a parameter of `model`.
pub(crate) fn param_specs(model: &Model, params: &Bound<'_, PyDict>) -> PyResult<Vec<ParamSpec>> {
    let mut specs = Vec::new();
    for (k, v) in params.iter() {
        let name: String = k
            .extract()
            .map_err(|_| input("params: keys are parameter names (str), e.g. 'tip_spring.k3'"))?;
        let (lo, hi): (f64, f64) = v.extract().map_err(|_| {
            input(format!(
                "params['{name}']: expected bounds (lower, upper) as two numbers"
            ))
        })?;
        let p: Param = name.parse().map_err(|_| {
            let known = model.inner.parameters();
            input(format!(
                "params: '{name}' is not a parameter name; the model's: {}",
                known
                    .iter()
                    .map(ToString::to_string)
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })?;
        if !(lo.is_finite() && hi.is_finite() && lo < hi) {
            return Err(input(format!(
                "params['{name}']: bounds ({lo}, {hi}) must be finite with lower < upper"
            )));
        }
        specs.push(ParamSpec::new(p, lo, hi));
    }
    if specs.is_empty() {
        return Err(input("params: name at least one parameter with its bounds"));
    }
    Ok(specs)
}

/// Calibrates parameters of `model` on the stepped-sine test `data`: an `nlsim.TestData` (from
/// arrays, e.g. read with h5py) or a file (nlsim's CSV, an amplitude-and-phase table or
/// universal file datasets 58). `params` maps each
/// parameter's text form to its bounds `(lower, upper)`. The other arguments are `nlsim
/// calibrate`'s options with its defaults: `compare` the harmonics compared (1 = the
/// fundamental), `form` `"complex"` or `"log"` (log-magnitude and phase), `branch`
/// `"nearest"` or `"continuation"`, `harmonics` the H of the harmonic balance, `modes`
/// retained, `uff_noise` the relative noise of UFF FRFs, `lhs` candidates, `seed`, `starts`,
/// `folds` (0: no cross validation). `gains` fixes gains of the data
/// (`{"input_gain": 2.5, "sensor_gain:tip": 1.02}`; a calibrated gain starts there);
/// `shaker` drives a voltage record through a modelled shaker: `True` for nlsim's default
/// shaker, or a dict of its fields (`armature_mass`, `suspension_stiffness`,
/// `suspension_damping`, `resistance`, `inductance`, `force_constant`, `stinger_stiffness`;
/// the others default), as a calibration file's `[shaker]`.
#[pyfunction]
#[pyo3(signature = (model, data, params, compare=vec![1], form="complex", branch="nearest", harmonics=3, modes=20, uff_noise=0.01, lhs=64, seed=1, starts=3, folds=10, fe_reduction="parametric", fe_tolerance=None, gains=None, shaker=None, threads=None, resume=None))]
#[allow(clippy::too_many_arguments)]
pub fn calibrate(
    py: Python<'_>,
    model: &Model,
    data: &Bound<'_, PyAny>,
    params: &Bound<'_, PyDict>,
    compare: Vec<usize>,
    form: &str,
    branch: &str,
    harmonics: usize,
    modes: usize,
    uff_noise: f64,
    lhs: usize,
    seed: u64,
    starts: usize,
    folds: usize,
    fe_reduction: &str,
    fe_tolerance: Option<f64>,
    gains: Option<&Bound<'_, PyDict>>,
    shaker: Option<&Bound<'_, PyAny>>,
    threads: Option<usize>,
    resume: Option<&PartialCalibration>,
) -> PyResult<Calibration> {
    let fe = self::fe_reduction(fe_reduction, fe_tolerance)?;
    let resumed = resume.map(PartialCalibration::kept);
    let fixed = fixed_gains(gains)?;
    let shaker = shaker_of(shaker)?;
    let data = Source::of(data)?;
    let specs = param_specs(model, params)?;
    let form = match form {
        "complex" => Form::Complex,
        "log" => Form::LogMagnitudePhase,
        other => return Err(input(format!("form: '{other}'; use 'complex' or 'log'"))),
    };
    let branch = match branch {
        "nearest" => BranchChoice::NearestToData,
        "continuation" => BranchChoice::Continuation,
        other => {
            return Err(input(format!(
                "branch: '{other}'; use 'nearest' or 'continuation'"
            )));
        }
    };
    if compare.is_empty() || compare.contains(&0) {
        return Err(input(format!(
            "compare: {compare:?}; give harmonics 1 (the fundamental) or above"
        )));
    }
    if let Some(k) = compare
        .iter()
        .enumerate()
        .find_map(|(i, k)| compare[..i].contains(k).then_some(*k))
    {
        // Counted twice, its residuals would weigh double (the std shrinks by √2).
        return Err(input(format!(
            "compare: {compare:?}; harmonic {k} is named twice, name each once"
        )));
    }
    if modes == 0 {
        return Err(input("modes: 0; keep at least one mode"));
    }
    if !(uff_noise > 0.0 && uff_noise.is_finite()) {
        return Err(input(format!(
            "uff_noise: {uff_noise}; give a positive fraction"
        )));
    }
    let set = crate::harmonic_set(harmonics, crate::MAX_CALIBRATION_HARMONICS)?;
    let config = search_config(lhs, seed, starts, folds)?;
    let m = model.inner.clone();
    let job = move |stop: &Stop| -> nlsim::Result<_> {
        let data = data.read(&m, uff_noise)?;
        let reduction = nlsim::reduction::ReductionConfig::lowest(modes.min(m.n_dofs()));
        let objective = FrfObjective::from_model_with(
            &m,
            &reduction,
            &fe,
            set,
            HbConfig::default(),
            data,
            specs,
            ObjectiveConfig {
                harmonics: compare,
                form,
                branch,
            },
        )?;
        let mut objective = objective;
        for (p, v) in &fixed {
            objective.set_gain(p, *v)?;
        }
        objective.set_shaker(shaker)?;
        let points = nlsim::calib::candidate_points(&objective, &config)?;
        let known = resumed_costs(resumed.as_deref(), &points)?;
        let outcome = nlsim::calib::calibrate_until(&objective, &config, &known, &|_| {}, &|| {
            stop.requested()
        })?;
        Ok((outcome, objective.fe_stats()))
    };
    let (c, fe) = finished_or_raise(py, run_keeping(py, threads, job)?)?;
    Ok(Calibration { c, fe })
}

/// The costs of `resumed` (a [`PartialCalibration`] given back) for a calibration whose
/// candidate points are `points`: none without one; refused when its points are not these
/// bit for bit.
pub(crate) fn resumed_costs(
    resumed: Option<&nlsim::calib::Interrupted>,
    points: &[Vec<f64>],
) -> nlsim::Result<Vec<Option<f64>>> {
    let Some(r) = resumed else {
        return Ok(Vec::new());
    };
    let given = r.points.iter().map(Vec::as_slice);
    if !nlsim::calib::Interrupted::same_points(points, given) {
        return Err(nlsim::Error::Usage(
            "resume: its candidates are not this calibration's (params, bounds, lhs, seed and \
             the model's values must be those of the interrupted call)"
                .into(),
        ));
    }
    Ok(r.costs.clone())
}

/// A stoppable calibration's end in Python: the finished result (with what the job returned
/// beside it), or after Ctrl-C the `KeyboardInterrupt` carrying a [`PartialCalibration`]
/// (`err.args[1]`) with what was complete — a calibration that finished as the interrupt
/// came is kept whole, the caller asked to stop.
pub(crate) fn finished_or_raise<C: nlsim::calib::Searched, X>(
    py: Python<'_>,
    ended: Ended<nlsim::Result<(nlsim::calib::Outcome<C>, X)>>,
) -> PyResult<(C, X)> {
    let result = match ended {
        Ended::Done(r) => r.map_err(py_err)?,
        Ended::Interrupted(interrupt, kept) => {
            let Some(Ok((outcome, _))) = kept else {
                return Err(interrupt);
            };
            let kept = match outcome {
                nlsim::calib::Outcome::Interrupted(k) => *k,
                nlsim::calib::Outcome::Finished(c) => nlsim::calib::Interrupted::finished(*c),
            };
            let partial = PartialCalibration {
                kept: Arc::new(kept),
            };
            let line = partial.__repr__();
            return Err(pyo3::exceptions::PyKeyboardInterrupt::new_err((
                line,
                Py::new(py, partial)?,
            )));
        }
    };
    match result {
        (nlsim::calib::Outcome::Finished(c), x) => Ok((*c, x)),
        (nlsim::calib::Outcome::Interrupted(_), _) => Err(crate::ComputationError::new_err(
            "the calibration stopped without an interrupt (an internal error; please report it)",
        )),
    }
}

/// What a calibration interrupted by Ctrl-C had completed: carried by the
/// `KeyboardInterrupt` it raises (`err.args[1]`) and given back to `calibrate(...,
/// resume=partial)` with the same arguments, which goes on to the estimates of an
/// uninterrupted call, bit for bit.
#[pyclass(module = "nlsim._native", name = "PartialCalibration", frozen)]
pub struct PartialCalibration {
    kept: Arc<nlsim::calib::Interrupted>,
}

impl PartialCalibration {
    /// What was kept, shared (handed to the job that resumes from it).
    pub(crate) fn kept(&self) -> Arc<nlsim::calib::Interrupted> {
        Arc::clone(&self.kept)
    }
}

#[pymethods]
impl PartialCalibration {
    /// The calibrated parameters' names, in the order of every array.
    #[getter]
    fn params(&self) -> Vec<String> {
        self.kept.params.iter().map(ToString::to_string).collect()
    }

    /// Every candidate point, shape `(candidate, param)`.
    #[getter]
    fn candidates<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let p = &self.kept.points;
        let n = self.kept.params.len();
        Array2::from_shape_fn((p.len(), n), |(i, j)| p[i][j]).into_pyarray(py)
    }

    /// Each candidate's cost `½ Σ r²`, shape `(candidate,)`; NaN where not evaluated.
    #[getter]
    fn candidate_cost<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.kept
                .costs
                .iter()
                .map(|c| c.unwrap_or(f64::NAN))
                .collect(),
        )
    }

    /// Candidates evaluated.
    #[getter]
    fn evaluated(&self) -> usize {
        self.kept.evaluated()
    }

    /// `"candidates"`, `"optimisation"` or `"cross validation"`: where it stopped.
    #[getter]
    fn phase(&self) -> &'static str {
        self.kept.phase.as_str()
    }

    /// Levenberg–Marquardt runs that finished.
    #[getter]
    fn optimisations(&self) -> usize {
        self.kept.runs.len()
    }

    /// The best values so far (the best finished optimisation, else the best evaluated
    /// candidate), shape `(param,)`; `None` when nothing finite was evaluated. Not a
    /// calibration result: no statistics come with it.
    #[getter]
    fn best<'py>(&self, py: Python<'py>) -> Option<Bound<'py, PyArray1<f64>>> {
        self.kept.best().map(|(v, _)| vec1(py, v.to_vec()))
    }

    /// The cost of [`best`](Self::best); `None` with it.
    #[getter]
    fn best_cost(&self) -> Option<f64> {
        self.kept.best().map(|(_, c)| c)
    }

    fn __repr__(&self) -> String {
        format!(
            "PartialCalibration(stopped in the {} phase, {} of {} candidates evaluated, {} \
             optimisations finished; resume with calibrate(..., resume=this))",
            self.kept.phase.as_str(),
            self.kept.evaluated(),
            self.kept.points.len(),
            self.kept.runs.len()
        )
    }
}
