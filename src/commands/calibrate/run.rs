//! The run of `nlsim calibrate` on stepped-sine data: the test data read and matched to the
//! model, the objective prepared, candidates → Levenberg–Marquardt → statistics → k-fold.
use crate::commands::calibrate::request::CalibrationRequest;
use crate::error::{Error, Result};
use nlsim_calib::{Calibration, Candidate, FrfObjective, ObjectiveConfig, Progress};
use nlsim_hb::{HarmonicSet, HbConfig};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

pub use crate::formats::test_data::read as read_test_data;

/// The objective of a request: the model loaded with its overrides, reduced, turned into a
/// harmonic balance system and compared with the data.
pub struct Prepared {
    /// The model's name.
    pub model_name: String,
    /// The objective.
    pub objective: FrfObjective,
    /// Wall time of loading and reduction (s).
    pub seconds: f64,
}

/// The test data `req` calibrates on: its data file read with its data options, restricted
/// to the sweeps of `train` (all without).
pub fn training_data(
    req: &CalibrationRequest,
    model: &nlsim_kernel::Model,
) -> Result<nlsim_calib::TestData> {
    let data = read_test_data(&req.data, model, &req.data_options)?;
    crate::formats::test_data::select_sweeps(&data, &req.train, "train")
        .map_err(|e| Error::Usage(format!("{}: {e}", req.data.display())))
}

/// Loads the model and the data of `req` and builds the objective.
pub fn prepare(req: &CalibrationRequest) -> Result<Prepared> {
    req.check()?;
    let t = Instant::now();
    let model = crate::commands::setup::load_for_run(&req.model, &req.model_sets())?;
    let data = Arc::new(training_data(req, &model)?);
    prepare_on(req, &model, data, t)
}

/// The objective of `req` on `model` (loaded with its overrides) and `data`; `t` is when the
/// loading started.
pub fn prepare_on(
    req: &CalibrationRequest,
    model: &nlsim_kernel::Model,
    data: Arc<nlsim_calib::TestData>,
    t: Instant,
) -> Result<Prepared> {
    let cfg = nlsim_reduction::ReductionConfig::lowest(req.modes.min(model.n_dofs()));
    let mut objective = FrfObjective::from_model_with(
        model,
        &cfg,
        &req.fe,
        HarmonicSet::new(req.harmonics, 1)?,
        HbConfig::default(),
        data,
        req.params.clone(),
        ObjectiveConfig {
            harmonics: req.compare.clone(),
            form: req.form,
            branch: req.branch,
        },
    )?;
    apply_drive(req, &mut objective)?;
    Ok(Prepared {
        model_name: model.name().to_string(),
        objective,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Sets the gains `req` fixes and its shaker on `objective`; a voltage record needs its
/// gain stated, set or calibrated.
fn apply_drive(req: &CalibrationRequest, objective: &mut FrfObjective) -> Result<()> {
    let at = |e: nlsim_kernel::Error| Error::Usage(format!("{}: {e}", req.data.display()));
    let gains = req.gain_sets()?;
    for (p, v) in &gains {
        objective.set_gain(p, *v).map_err(at)?;
    }
    objective.set_shaker(req.shaker).map_err(at)?;
    let gain_given = gains
        .iter()
        .any(|(p, _)| *p == nlsim_kernel::Param::InputGain)
        || req
            .params
            .iter()
            .any(|s| s.param == nlsim_kernel::Param::InputGain);
    if objective.data().drive == nlsim_calib::Drive::Voltage && !gain_given {
        let unit = if req.shaker.is_some() {
            "V at the coil per recorded V"
        } else {
            "N/V"
        };
        return Err(Error::Usage(format!(
            "{}: the drive '{}' was recorded as a voltage: calibrate its gain \
             (--param input_gain=LOWER:UPPER) or fix it (--set input_gain=VALUE), in {unit}",
            req.data.display(),
            objective.data().input
        )));
    }
    Ok(())
}

/// A finished calibration with what it ran on.
pub struct CalibrationRun {
    /// The request.
    pub request: CalibrationRequest,
    /// Model, data and objective.
    pub prepared: Prepared,
    /// The result.
    pub calibration: Calibration,
    /// Wall time of the search, optimisation and cross validation (s).
    pub seconds: f64,
    /// Where the candidates came from, when not computed here (a merged batch file).
    pub candidates_from: Option<PathBuf>,
}

/// Runs `req`: candidates, Levenberg–Marquardt, Cramér–Rao, k-fold. With `candidates`
/// (evaluated elsewhere, e.g. by a `calibrate-candidates` batch, [`crate::batch`]) the
/// candidate phase is skipped; they must be the request's own candidate points.
pub fn run_calibration(
    req: &CalibrationRequest,
    candidates: Option<(PathBuf, Vec<Candidate>)>,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<CalibrationRun> {
    match run_calibration_until(req, candidates, progress, &|| false)? {
        RunOutcome::Finished(run) => Ok(*run),
        RunOutcome::Interrupted(_) => unreachable!("nothing stops a run without a stop"),
    }
}

/// How a calibration run that can be stopped ended ([`run_calibration_until`],
/// [`super::run_modal_calibration_until`], [`super::run_time_calibration_until`]).
pub enum RunOutcome<R = CalibrationRun> {
    /// The calibration ran to its end.
    Finished(Box<R>),
    /// Stopped at a safe point: what was complete.
    Interrupted(Box<nlsim_calib::Interrupted>),
}

/// The costs a candidates file holds for a calibration whose candidate points are
/// `expected`, `None` where the file says not evaluated (an interrupted run's NaN); refused
/// when its points are not `expected` bit for bit.
pub fn known_costs(
    path: &std::path::Path,
    candidates: &[Candidate],
    expected: &[Vec<f64>],
) -> Result<Vec<Option<f64>>> {
    let given = candidates.iter().map(|c| c.values.as_slice());
    if !nlsim_calib::Interrupted::same_points(expected, given) {
        return Err(Error::Usage(format!(
            "{}: its {} candidates are not the {} of this calibration (parameters, bounds, \
             lhs, seed and the model's values must match the run that wrote it)",
            path.display(),
            candidates.len(),
            expected.len()
        )));
    }
    Ok(candidates
        .iter()
        .map(|c| Some(c.cost).filter(|c| !c.is_nan()))
        .collect())
}

/// [`run_calibration`] that stops at the next safe point once `stop()` holds
/// ([`nlsim_calib::calibrate_until`]). `candidates` may come from an interrupted run (NaN
/// costs where not evaluated): those are evaluated here, the others reused, and the
/// estimates are those of one uninterrupted run, bit for bit.
pub fn run_calibration_until(
    req: &CalibrationRequest,
    candidates: Option<(PathBuf, Vec<Candidate>)>,
    progress: &(dyn Fn(Progress) + Sync),
    stop: nlsim_calib::Stop<'_>,
) -> Result<RunOutcome> {
    let prepared = prepare(req)?;
    let t = Instant::now();
    let mut known = Vec::new();
    let candidates_from = match candidates {
        None => None,
        Some((path, c)) => {
            let expected = nlsim_calib::candidate_points(&prepared.objective, &req.config)?;
            known = known_costs(&path, &c, &expected)?;
            Some(path)
        }
    };
    let outcome =
        nlsim_calib::calibrate_until(&prepared.objective, &req.config, &known, progress, stop)?;
    Ok(match outcome {
        nlsim_calib::Outcome::Finished(calibration) => {
            RunOutcome::Finished(Box::new(CalibrationRun {
                request: req.clone(),
                prepared,
                calibration: *calibration,
                seconds: t.elapsed().as_secs_f64(),
                candidates_from,
            }))
        }
        nlsim_calib::Outcome::Interrupted(kept) => RunOutcome::Interrupted(kept),
    })
}

/// What a calibration will cost, before it runs (`nlsim calibrate --dry-run`): the objective
/// is built (the reduction, and the parametric model's training with FE-level parameters)
/// and one evaluation of each kind is timed at the first candidate (the model's current
/// values clamped to the bounds).
#[derive(Debug, Clone)]
pub struct CalibrationEstimate {
    /// Seconds to load, reduce and build the objective.
    pub setup_seconds: f64,
    /// Candidate evaluations (cost only), run in parallel.
    pub candidates: usize,
    /// Seconds of one cost evaluation.
    pub cost_seconds: f64,
    /// Seconds of one evaluation with its Jacobian (one per Levenberg–Marquardt iteration).
    pub jacobian_seconds: f64,
    /// Levenberg–Marquardt runs from the best candidates.
    pub starts: usize,
    /// Cross-validation folds (each a Levenberg–Marquardt run from the estimate).
    pub folds: usize,
    /// Most iterations of one Levenberg–Marquardt run.
    pub max_iterations: usize,
    /// Worker threads of the parallel phases.
    pub threads: usize,
}

impl CalibrationEstimate {
    /// Wall-time estimate (s) with `iterations` Levenberg–Marquardt iterations per run:
    /// the candidates and the runs spread over the threads.
    pub fn seconds(&self, iterations: usize) -> f64 {
        let t = self.threads.max(1) as f64;
        let waves = |n: usize| (n as f64 / t).ceil();
        self.setup_seconds
            + waves(self.candidates) * self.cost_seconds
            + (waves(self.starts) + waves(self.folds)) * iterations as f64 * self.jacobian_seconds
    }

    /// The estimate as lines for people.
    pub fn lines(&self) -> Vec<String> {
        use crate::present::console::duration_text;
        vec![
            format!(
                "objective built in {} (loading, reduction)",
                duration_text(self.setup_seconds)
            ),
            format!(
                "candidates: {} cost evaluations of {} each, on {} threads",
                self.candidates,
                duration_text(self.cost_seconds),
                self.threads
            ),
            format!(
                "optimisations: {} starts and {} folds, one evaluation with Jacobian ({}) per \
                 iteration, at most {} iterations each",
                self.starts,
                self.folds,
                duration_text(self.jacobian_seconds),
                self.max_iterations
            ),
            format!(
                "estimated wall time: about {} with 10 iterations per run, at most {}",
                duration_text(self.seconds(10)),
                duration_text(self.seconds(self.max_iterations))
            ),
        ]
    }
}

/// Builds the objective of `req` and times one evaluation of each kind (see
/// [`CalibrationEstimate`]).
pub fn estimate_calibration(req: &CalibrationRequest) -> Result<CalibrationEstimate> {
    let prepared = prepare(req)?;
    let mut obj = prepared.objective.clone();
    // What the run refuses at its start, the dry run refuses too.
    nlsim_calib::fold_plan(obj.data(), &req.config)?;
    let points = nlsim_calib::candidate_points(&obj, &req.config)?;
    let first = points[0].clone();
    let t = Instant::now();
    obj.cost_values(&first)?;
    let cost_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    obj.evaluate_values(&first, None, true)?;
    let jacobian_seconds = t.elapsed().as_secs_f64();
    Ok(CalibrationEstimate {
        setup_seconds: prepared.seconds,
        candidates: points.len(),
        cost_seconds,
        jacobian_seconds,
        starts: req.config.starts.min(points.len()),
        // One fold per sweep when folding by sweeps (the settings are checked by the run).
        folds: match req.config.fold_by {
            nlsim_calib::FoldBy::Sweeps if req.config.folds > 0 => obj.data().sweeps.len(),
            _ => req.config.folds,
        },
        max_iterations: req.config.lm.max_iterations,
        threads: rayon::current_num_threads(),
    })
}
