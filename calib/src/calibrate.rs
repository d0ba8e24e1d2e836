//! The calibration workflow (thesis §4.5–4.6): Latin-hypercube candidates evaluated in
//! parallel, Levenberg–Marquardt from the best few, the Cramér–Rao bound at the optimum, and
//! k-fold cross validation started from the optimum.
//!
//! Every random draw comes from the recorded seed, and every parallel task is independent and
//! sequential inside, so the estimates are bit-identical for any number of threads.

use crate::data::TestData;
use crate::lhs::{maximin_latin_hypercube, to_range};
use crate::lm::{LeastSquares, LmConfig, LmReport, levenberg_marquardt};
use crate::objective::{
    FrfObjective, ParamSpec, SweepEvaluation, specs_to_internal, specs_to_values,
};
use crate::stats::{CramerRao, mean_and_covariance};
use faer::Mat;
use nlsim_kernel::{Error, Param, Result, Status};
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Settings of [`calibrate`].
#[derive(Debug, Clone, PartialEq)]
pub struct CalibrationConfig {
    /// Latin-hypercube candidates over the bounds (the model's current values are a further
    /// candidate).
    pub lhs_samples: usize,
    /// Seed of the Latin hypercube and of the fold assignment.
    pub seed: u64,
    /// Maximin improvement swaps of the Latin hypercube.
    pub maximin_swaps: usize,
    /// Levenberg–Marquardt runs, from the best candidates.
    pub starts: usize,
    /// Levenberg–Marquardt settings.
    pub lm: LmConfig,
    /// Folds of the cross validation (0: none; at least 2 otherwise). With
    /// [`FoldBy::Sweeps`] any non-zero value means one fold per sweep.
    pub folds: usize,
    /// How points are dealt into folds.
    pub fold_by: FoldBy,
}

/// How the cross validation deals the data into folds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FoldBy {
    /// A seeded shuffle of all points dealt round-robin: every fold holds steps of every
    /// sweep (the statistics of the parameters).
    #[default]
    Points,
    /// One fold per sweep: each sweep (force level) is held out whole and predicted from
    /// the others — the validation of a model on a level it was not trained on (thesis §4.6).
    Sweeps,
}

impl Default for CalibrationConfig {
    fn default() -> Self {
        Self {
            lhs_samples: 64,
            seed: 1,
            maximin_swaps: 2000,
            starts: 3,
            lm: LmConfig::default(),
            folds: 10,
            fold_by: FoldBy::Points,
        }
    }
}

/// Most Latin-hypercube candidates of one calibration (each costs a harmonic-balance sweep
/// over the data; the command line, calibration files and batch kinds share it).
pub const MAX_LHS_SAMPLES: usize = 1_000_000;

/// Most pair swaps of the maximin improvement of the Latin hypercube (each costs one
/// distance update over the candidates; the default 2000 is plenty).
pub const MAX_MAXIMIN_SWAPS: usize = 10_000_000;

/// Most folds of a cross validation (at most the data points as well).
pub const MAX_FOLDS: usize = 100_000;

/// Most Levenberg–Marquardt starts (at most the candidates as well).
pub const MAX_STARTS: usize = 10_000;

impl CalibrationConfig {
    /// Checks the settings that do not depend on the data: the limits above, at least one
    /// start, and the Levenberg–Marquardt settings. What a batch kind checks before it
    /// makes its jobs.
    pub fn validate_settings(&self) -> Result<()> {
        self.lm.validate()?;
        let bad = |what: String| Err(Error::invalid("calibration settings", what));
        if self.lhs_samples > MAX_LHS_SAMPLES {
            return bad(format!(
                "{} Latin-hypercube samples is beyond any budget (at most {MAX_LHS_SAMPLES})",
                self.lhs_samples
            ));
        }
        if self.maximin_swaps > MAX_MAXIMIN_SWAPS {
            return bad(format!(
                "maximin_swaps {} is beyond any budget (at most {MAX_MAXIMIN_SWAPS}; the default 2000 is plenty)",
                self.maximin_swaps
            ));
        }
        if self.folds > MAX_FOLDS {
            return bad(format!(
                "folds {} is beyond any budget (at most {MAX_FOLDS}, and at most the data points)",
                self.folds
            ));
        }
        if self.starts > MAX_STARTS {
            return bad(format!(
                "starts {} is beyond any budget (at most {MAX_STARTS})",
                self.starts
            ));
        }
        Ok(())
    }

    /// Checks the settings against `n_points` data points.
    pub fn validate(&self, n_points: usize) -> Result<()> {
        self.validate_settings()?;
        if self.starts == 0 {
            return Err(Error::invalid(
                "calibration settings",
                "starts must be at least 1",
            ));
        }
        if self.fold_by == FoldBy::Sweeps {
            return Ok(());
        }
        if self.folds == 1 || self.folds > n_points {
            return Err(Error::invalid(
                "calibration settings",
                if n_points < 2 {
                    format!(
                        "folds = {}: cross-validation needs at least 2 data points and the data \
                         has {n_points}; set folds = 0",
                        self.folds
                    )
                } else {
                    format!(
                        "folds = {}: give 0 (no cross-validation) or 2 to {n_points} (the data \
                         points)",
                        self.folds
                    )
                },
            ));
        }
        Ok(())
    }
}

/// A Latin-hypercube candidate and its cost.
#[derive(Debug, Clone, PartialEq)]
pub struct Candidate {
    /// Parameter values.
    pub values: Vec<f64>,
    /// Cost `½‖r‖²` (infinite where a point failed).
    pub cost: f64,
}

/// One Levenberg–Marquardt run.
#[derive(Debug, Clone)]
pub struct StartRun {
    /// Start values.
    pub start: Vec<f64>,
    /// Final values.
    pub values: Vec<f64>,
    /// Its report.
    pub report: LmReport,
}

/// The k-fold cross validation.
#[derive(Debug, Clone)]
pub struct KFold {
    /// Number of folds.
    pub k: usize,
    /// Fold of every data point (in [`TestData::points`](crate::data::TestData::points) order).
    pub fold_of: Vec<usize>,
    /// The estimate of each fold (trained on the other folds).
    pub estimates: Vec<Vec<f64>>,
    /// Status of each fold's optimisation.
    pub status: Vec<Status>,
    /// Root-mean-square weighted residual on each fold's held-out points.
    pub held_out_rms: Vec<f64>,
    /// Root-mean-square weighted residual on each fold's training points.
    pub training_rms: Vec<f64>,
    /// Mean of the estimates.
    pub mean: Vec<f64>,
    /// Covariance of the estimates.
    pub covariance: Mat<f64>,
    /// Standard deviation of the fold estimates.
    pub std: Vec<f64>,
    /// Delete-a-group jackknife standard deviation `(k−1)/√k · std`: the spread expected of
    /// an estimate from all the data, comparable with the Cramér–Rao bound.
    pub jackknife_std: Vec<f64>,
}

/// The outcome of [`calibrate`].
#[derive(Debug, Clone)]
pub struct Calibration {
    /// The calibrated parameters.
    pub params: Vec<Param>,
    /// The estimate.
    pub estimate: Vec<f64>,
    /// The status of the best optimisation.
    pub status: Status,
    /// Every candidate: the model's values first, then the Latin hypercube in sample order.
    pub candidates: Vec<Candidate>,
    /// The optimisations, best first.
    pub runs: Vec<StartRun>,
    /// Cramér–Rao bound at the estimate.
    pub cramer_rao: CramerRao,
    /// Parameters whose estimate sits on a bound.
    pub at_bound: Vec<bool>,
    /// Parameters that are poorly identifiable (relative Cramér–Rao std above 0.5 or part of
    /// a collinear set).
    pub poorly_identified: Vec<bool>,
    /// The model at the estimate, at every data point.
    pub fit: SweepEvaluation,
    /// Cost at the estimate.
    pub cost: f64,
    /// The cross validation, when asked for.
    pub kfold: Option<KFold>,
}

/// Progress of a calibration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Progress {
    /// Candidates evaluated so far.
    Candidates {
        /// Done.
        done: usize,
        /// Total.
        total: usize,
    },
    /// An optimisation finished.
    Start {
        /// Done.
        done: usize,
        /// Total.
        total: usize,
    },
    /// A fold finished.
    Fold {
        /// Done.
        done: usize,
        /// Total.
        total: usize,
    },
}

/// Calibrates `objective`'s parameters ([`calibrate_with_progress`] without a callback).
pub fn calibrate(objective: &FrfObjective, config: &CalibrationConfig) -> Result<Calibration> {
    calibrate_with_progress(objective, config, &|_| {})
}

/// Calibrates: candidates from a maximin Latin hypercube over the bounds (and the model's
/// current values) in parallel, Levenberg–Marquardt from the best `starts`, statistics at the
/// best optimum, then k-fold cross validation from it. Runs in the caller's rayon pool.
///
/// The phases are public for callers that spread them over a cluster:
/// [`candidate_points`] and [`FrfObjective::cost_values`] for the candidates,
/// [`calibrate_from_candidates`] for the rest, [`fold`] and [`KFold::from_folds`] for the
/// cross validation; run that way the estimates are bit-identical to this function's.
pub fn calibrate_with_progress(
    objective: &FrfObjective,
    config: &CalibrationConfig,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<Calibration> {
    Ok(calibrate_until(objective, config, &[], progress, &|| false)?.unstopped())
}

/// [`calibrate_with_progress`] that reuses the candidate costs in `known` (one per point of
/// [`candidate_points`], `None` where not evaluated; empty for none) and stops at the next
/// safe point once `stop()` returns `true` — before a candidate, before a
/// Levenberg–Marquardt evaluation — with what was complete ([`Outcome::Interrupted`]).
/// Run again with the interrupted run's costs as `known`, it reaches bit-identical
/// estimates to one uninterrupted run.
pub fn calibrate_until(
    objective: &FrfObjective,
    config: &CalibrationConfig,
    known: &[Option<f64>],
    progress: &(dyn Fn(Progress) + Sync),
    stop: Stop<'_>,
) -> Result<Outcome> {
    // The folds are planned first: a setting the data cannot meet (folds by sweeps of one
    // sweep) is refused before the candidates, not after them.
    fold_plan(objective.data(), config)?;
    let points = candidate_points(objective, config)?;
    let params: Vec<Param> = objective.specs().iter().map(|s| s.param.clone()).collect();
    let cost = |obj: &mut FrfObjective, v: &[f64]| obj.cost_values(v);
    let candidates = match candidates_until(objective, params, points, known, cost, progress, stop)?
    {
        Ok(c) => c,
        Err(kept) => return Ok(Outcome::Interrupted(kept)),
    };
    calibrate_from_candidates_until(objective, candidates, config, progress, stop)
}

/// The start candidates of a calibration: the model's current values clamped to the bounds,
/// then the maximin Latin hypercube of `config` (seed, samples, swaps) over the bounds.
pub fn candidate_points(
    objective: &FrfObjective,
    config: &CalibrationConfig,
) -> Result<Vec<Vec<f64>>> {
    let specs = objective.specs();
    let current = specs
        .iter()
        .map(|s| objective.param_value(&s.param))
        .collect::<Result<Vec<_>>>()?;
    start_points(specs, &current, config)
}

/// The calibration after the candidates: Levenberg–Marquardt from the best `config.starts`
/// of `candidates` (evaluated costs, infinite where a point failed), the Cramér–Rao bound at
/// the best optimum and, when `config.folds ≥ 2`, the k-fold cross validation.
pub fn calibrate_from_candidates(
    objective: &FrfObjective,
    candidates: Vec<Candidate>,
    config: &CalibrationConfig,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<Calibration> {
    Ok(
        calibrate_from_candidates_until(objective, candidates, config, progress, &|| false)?
            .unstopped(),
    )
}

/// [`calibrate_from_candidates`] that stops at the next Levenberg–Marquardt evaluation once
/// `stop()` returns `true` ([`calibrate_until`]).
pub fn calibrate_from_candidates_until(
    objective: &FrfObjective,
    candidates: Vec<Candidate>,
    config: &CalibrationConfig,
    progress: &(dyn Fn(Progress) + Sync),
    stop: Stop<'_>,
) -> Result<Outcome> {
    config.validate(objective.data().n_points())?;
    let specs = objective.specs().to_vec();
    let n = specs.len();
    if let Some((i, c)) = candidates
        .iter()
        .enumerate()
        .find(|(_, c)| c.values.len() != n)
    {
        return Err(Error::invalid(
            format!("candidate {i}"),
            format!("holds {} values for {n} parameters", c.values.len()),
        ));
    }
    let params: Vec<Param> = specs.iter().map(|s| s.param.clone()).collect();
    let total = candidates.len();
    let order = best_candidates(&candidates, config.starts);
    if order.is_empty() {
        return Err(Error::Numerical {
            what: "calibration".into(),
            detail: format!(
                "the harmonic balance failed at some data point for every one of the {total} \
                 candidates: check the bounds, the harmonics and the data's frequency range"
            ),
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
    let interrupted = |runs: Vec<StartRun>, candidates: Vec<Candidate>, phase| {
        Ok(Outcome::Interrupted(Box::new(Interrupted::evaluated_all(
            params.clone(),
            candidates,
            runs,
            phase,
        ))))
    };
    if !all {
        return interrupted(runs, candidates, Phase::Optimisation);
    }
    let best = &runs[0];
    let estimate = best.values.clone();
    let mut obj = objective.clone();
    let fit = obj.evaluate_values(&estimate, None, true)?;
    let cost = 0.5 * fit.residuals.iter().map(|r| r * r).sum::<f64>();
    let cramer_rao = match (&fit.jacobian, fit.failed.is_empty()) {
        (Some(j), true) => {
            CramerRao::new(&per_value(&specs, &estimate, j), &fit.residuals, &estimate)
        }
        _ => CramerRao::new(&Mat::zeros(0, n), &[], &estimate),
    };
    let at_bound: Vec<bool> = best.report.active_bounds.clone();
    let poorly_identified = cramer_rao.poorly_identified();
    let status = best.report.status;
    let kfold = if config.folds > 0 {
        match kfold_until(objective, &estimate, config, progress, stop)? {
            Some(k) => Some(k),
            None => return interrupted(runs, candidates, Phase::CrossValidation),
        }
    } else {
        None
    };
    Ok(Outcome::Finished(Box::new(Calibration {
        params,
        estimate,
        status,
        candidates,
        runs,
        cramer_rao,
        at_bound,
        poorly_identified,
        fit,
        cost,
        kfold,
    })))
}

/// The fold of every point of `data` and the number of folds, as `config` deals them
/// ([`FoldBy`]); `k = 0` when `config.folds` is 0.
pub fn fold_plan(data: &TestData, config: &CalibrationConfig) -> Result<(Vec<usize>, usize)> {
    let n_points = data.n_points();
    config.validate(n_points)?;
    if config.folds == 0 {
        return Ok((vec![0; n_points], 0));
    }
    match config.fold_by {
        FoldBy::Points => Ok((
            fold_assignment(n_points, config.folds, config.seed),
            config.folds,
        )),
        FoldBy::Sweeps => {
            if data.sweeps.len() < 2 {
                return Err(Error::invalid(
                    "calibration settings",
                    format!(
                        "fold_by = sweeps holds each sweep out in turn and the data has {} \
                         sweep(s); give at least 2, or fold by points",
                        data.sweeps.len()
                    ),
                ));
            }
            Ok((
                data.points().iter().map(|p| p.sweep).collect(),
                data.sweeps.len(),
            ))
        }
    }
}

/// Fold of every data point: a seeded shuffle of the points dealt round-robin into `k` folds.
pub fn fold_assignment(n_points: usize, k: usize, seed: u64) -> Vec<usize> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed ^ 0x006b_666f_6c64);
    let mut idx: Vec<usize> = (0..n_points).collect();
    for i in (1..n_points).rev() {
        let j = rng.random_range(0..=i);
        idx.swap(i, j);
    }
    let mut fold = vec![0; n_points];
    for (pos, &p) in idx.iter().enumerate() {
        fold[p] = pos % k.max(1);
    }
    fold
}

/// One fold of the cross validation.
#[derive(Debug, Clone, PartialEq)]
pub struct FoldResult {
    /// The fold's estimate (trained on the other folds).
    pub values: Vec<f64>,
    /// Status of its optimisation.
    pub status: Status,
    /// Root-mean-square weighted residual on its held-out points (infinite where the
    /// harmonic balance failed at one of them).
    pub held_out_rms: f64,
    /// Root-mean-square weighted residual on its training points.
    pub training_rms: f64,
}

/// Fold `f` of `config.folds` (assignment [`fold_assignment`] from `config.seed`): the
/// other folds calibrated by Levenberg–Marquardt from `estimate`, the held-out error
/// measured. Sequential inside.
pub fn fold(
    objective: &FrfObjective,
    estimate: &[f64],
    config: &CalibrationConfig,
    f: usize,
) -> Result<FoldResult> {
    fold_until(objective, estimate, config, f, &|| false)
        .map(|r| r.expect("nothing stops a fold without a stop"))
}

/// [`fold`] that stops at the next Levenberg–Marquardt evaluation once `stop()` holds.
fn fold_until(
    objective: &FrfObjective,
    estimate: &[f64],
    config: &CalibrationConfig,
    f: usize,
    stop: Stop<'_>,
) -> Result<Option<FoldResult>> {
    let (fold_of, k) = fold_plan(objective.data(), config)?;
    if f >= k {
        return Err(Error::invalid(
            "cross validation",
            format!("fold {f} is not below the fold count {k}"),
        ));
    }
    if estimate.len() != objective.specs().len() {
        return Err(Error::invalid(
            "cross validation",
            format!(
                "the estimate holds {} values for {} parameters",
                estimate.len(),
                objective.specs().len()
            ),
        ));
    }
    let (lo, hi) = objective.internal_bounds();
    let rms = |r: &[f64]| (r.iter().map(|v| v * v).sum::<f64>() / r.len().max(1) as f64).sqrt();
    let mut obj = objective.clone();
    let train: Vec<bool> = fold_of.iter().map(|&g| g != f).collect();
    let held: Vec<bool> = train.iter().map(|t| !t).collect();
    obj.set_training(train)?;
    let u0 = obj.to_internal(estimate);
    let Some(rep) = lm_until(&mut obj, &u0, &lo, &hi, &config.lm, stop)? else {
        return Ok(None);
    };
    let values = obj.to_values(&rep.u);
    let training_rms = rep
        .evaluation
        .as_ref()
        .map_or(f64::NAN, |e| rms(&e.residuals));
    let ho = obj.evaluate_values(&values, Some(&held), false)?;
    let held_out_rms = if ho.failed.is_empty() {
        rms(&ho.residuals)
    } else {
        f64::INFINITY
    };
    Ok(Some(FoldResult {
        values,
        status: rep.status,
        held_out_rms,
        training_rms,
    }))
}

/// k-fold cross validation from `estimate`: each fold is held out in turn ([`fold`], in
/// parallel), the others are calibrated from `estimate`, and the held-out error is measured.
pub fn kfold(
    objective: &FrfObjective,
    estimate: &[f64],
    config: &CalibrationConfig,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<KFold> {
    kfold_until(objective, estimate, config, progress, &|| false)
        .map(|k| k.expect("nothing stops a cross validation without a stop"))
}

/// [`kfold`] that stops at the next Levenberg–Marquardt evaluation once `stop()` holds
/// (`Ok(None)` then).
fn kfold_until(
    objective: &FrfObjective,
    estimate: &[f64],
    config: &CalibrationConfig,
    progress: &(dyn Fn(Progress) + Sync),
    stop: Stop<'_>,
) -> Result<Option<KFold>> {
    let (fold_of, k) = fold_plan(objective.data(), config)?;
    let done = AtomicUsize::new(0);
    let results: Vec<Result<Option<FoldResult>>> = (0..k)
        .into_par_iter()
        .map(|f| {
            let r = fold_until(objective, estimate, config, f, stop);
            let d = done.fetch_add(1, Ordering::Relaxed) + 1;
            progress(Progress::Fold { done: d, total: k });
            r
        })
        .collect();
    let folds = results.into_iter().collect::<Result<Option<Vec<_>>>>()?;
    folds.map(|f| KFold::from_folds(fold_of, f)).transpose()
}

impl KFold {
    /// Mean square of the weighted residuals over every fold's held-out points, each fold
    /// weighted by its point count (1 when the model and the noise model predict data they
    /// were not trained on; infinite when the harmonic balance failed at a held-out point).
    /// Folds that leave whole sweeps out measure how the model predicts another run,
    /// run-to-run differences included, which the training reduced χ² does not hold.
    pub fn held_out_mean_square(&self) -> f64 {
        let mut count = vec![0usize; self.k];
        for &g in &self.fold_of {
            count[g] += 1;
        }
        let total: usize = count.iter().sum();
        if total == 0 {
            return f64::NAN;
        }
        let sum: f64 = self
            .held_out_rms
            .iter()
            .zip(&count)
            .map(|(r, &n)| r * r * n as f64)
            .sum();
        sum / total as f64
    }

    /// The statistics of the folds `folds` (fold `f` at index `f`) of the assignment
    /// `fold_of`: mean, covariance, standard deviation and the jackknife spread.
    pub fn from_folds(fold_of: Vec<usize>, folds: Vec<FoldResult>) -> Result<Self> {
        let k = folds.len();
        let n = folds.first().map_or(0, |f| f.values.len());
        if k < 2 || folds.iter().any(|f| f.values.len() != n) || fold_of.iter().any(|&g| g >= k) {
            return Err(Error::invalid(
                "cross validation",
                format!(
                    "needs at least 2 folds of equal parameter count covering the assignment \
                     ({k} folds given)"
                ),
            ));
        }
        let mut estimates = Vec::with_capacity(k);
        let mut status = Vec::with_capacity(k);
        let mut held_out_rms = Vec::with_capacity(k);
        let mut training_rms = Vec::with_capacity(k);
        for r in folds {
            estimates.push(r.values);
            status.push(r.status);
            held_out_rms.push(r.held_out_rms);
            training_rms.push(r.training_rms);
        }
        let (mean, covariance) = mean_and_covariance(&estimates);
        let std: Vec<f64> = (0..mean.len()).map(|j| covariance[(j, j)].sqrt()).collect();
        let jk = (k as f64 - 1.0) / (k as f64).sqrt();
        let jackknife_std = std.iter().map(|s| s * jk).collect();
        Ok(KFold {
            k,
            fold_of,
            estimates,
            status,
            held_out_rms,
            training_rms,
            mean,
            covariance,
            std,
            jackknife_std,
        })
    }
}

/// The start candidates: the model's `current` values clamped to the bounds, then the
/// maximin Latin hypercube of `config` mapped onto the ranges of `specs`.
pub(crate) fn start_points(
    specs: &[ParamSpec],
    current: &[f64],
    config: &CalibrationConfig,
) -> Result<Vec<Vec<f64>>> {
    let mut starts = Vec::with_capacity(config.lhs_samples + 1);
    starts.push(
        current
            .iter()
            .zip(specs)
            .map(|(x, s)| x.clamp(s.lower, s.upper))
            .collect(),
    );
    for t in maximin_latin_hypercube(
        config.lhs_samples,
        specs.len(),
        config.seed,
        config.maximin_swaps,
    ) {
        starts.push(
            t.iter()
                .zip(specs)
                .map(|(&t, s)| to_range(t, s.lower, s.upper, s.spacing))
                .collect::<Result<Vec<_>>>()?,
        );
    }
    Ok(starts)
}

/// The cost of every point, in parallel, each on a fresh copy of `objective` (setting
/// parameters in place rounds differently after different earlier values, e.g. a mode's
/// damping ratio recovered from `2ζω` when its frequency changes, so a copy reused across
/// the candidates one worker happens to take would make the costs depend on the thread
/// count), in the order given; `done(finished, total)` after each. The costs in `known` (one
/// per point, or empty for none) are reused, and a point is left unevaluated (`None`) once
/// `stop()` returns `true`: each point's cost depends on that point alone, so costs kept
/// from an interrupted run and the rest evaluated later are bit-identical to one
/// uninterrupted evaluation.
pub(crate) fn evaluate_costs<O: Clone + Send + Sync>(
    objective: &O,
    points: &[Vec<f64>],
    known: &[Option<f64>],
    cost: impl Fn(&mut O, &[f64]) -> Result<f64> + Sync,
    done: &(dyn Fn(usize, usize) + Sync),
    stop: Stop<'_>,
) -> Result<Vec<Option<f64>>> {
    if !known.is_empty() && known.len() != points.len() {
        return Err(Error::DimensionMismatch {
            what: "known candidate costs".into(),
            expected: points.len(),
            found: known.len(),
        });
    }
    let known_at = |i: usize| known.get(i).copied().flatten();
    let total = (0..points.len()).filter(|&i| known_at(i).is_none()).count();
    let finished = AtomicUsize::new(0);
    let costs: Vec<Result<Option<f64>>> = points
        .par_iter()
        .enumerate()
        .map(|(i, v)| {
            if let Some(c) = known_at(i) {
                return Ok(Some(c));
            }
            if stop() {
                return Ok(None);
            }
            let mut obj = objective.clone();
            let c = cost(&mut obj, v);
            done(finished.fetch_add(1, Ordering::Relaxed) + 1, total);
            c.map(Some)
        })
        .collect();
    costs.into_iter().collect()
}

/// The candidates at `points` with their costs (those in `known` reused, the rest evaluated
/// by `cost` in parallel with `progress` told as they finish, [`evaluate_costs`]), or the
/// stop in the candidate phase with the costs evaluated so far.
pub(crate) fn candidates_until<O: Clone + Send + Sync>(
    objective: &O,
    params: Vec<Param>,
    points: Vec<Vec<f64>>,
    known: &[Option<f64>],
    cost: impl Fn(&mut O, &[f64]) -> Result<f64> + Sync,
    progress: &(dyn Fn(Progress) + Sync),
    stop: Stop<'_>,
) -> Result<std::result::Result<Vec<Candidate>, Box<Interrupted>>> {
    let costs = evaluate_costs(
        objective,
        &points,
        known,
        cost,
        &|done, total| progress(Progress::Candidates { done, total }),
        stop,
    )?;
    Ok(Interrupted::unless_evaluated(params, points, costs))
}

/// Asked between units of work (a candidate, a Levenberg–Marquardt evaluation): `true`
/// stops the calibration at that point ([`calibrate_until`]). The numeric crates read no
/// signal; a caller sets a flag from its own (a Ctrl-C handler, a cancel call).
pub type Stop<'a> = &'a (dyn Fn() -> bool + Sync);

/// A calibration's end: finished, or stopped at a safe point with what was complete. `C` is
/// the finished result: [`Calibration`] (stepped sines), [`ModalCalibration`](crate::ModalCalibration)
/// or [`TimeCalibration`](crate::TimeCalibration).
#[derive(Debug, Clone)]
pub enum Outcome<C = Calibration> {
    /// Ran to its end.
    Finished(Box<C>),
    /// Stopped by [`Stop`] before its end.
    Interrupted(Box<Interrupted>),
}

/// A finished calibration's search — what [`Interrupted::finished`] keeps of it.
pub trait Searched {
    /// The parameters, every candidate with its cost, and the optimisations (best first).
    fn into_search(self) -> (Vec<Param>, Vec<Candidate>, Vec<StartRun>);
}

impl Searched for Calibration {
    fn into_search(self) -> (Vec<Param>, Vec<Candidate>, Vec<StartRun>) {
        (self.params, self.candidates, self.runs)
    }
}

impl Searched for crate::ModalCalibration {
    fn into_search(self) -> (Vec<Param>, Vec<Candidate>, Vec<StartRun>) {
        (self.params, self.candidates, self.runs)
    }
}

impl Searched for crate::TimeCalibration {
    fn into_search(self) -> (Vec<Param>, Vec<Candidate>, Vec<StartRun>) {
        (self.params, self.candidates, self.runs)
    }
}

impl<C> Outcome<C> {
    /// The result of a run whose stop never fires (the `_until` forms called by the plain
    /// ones): it cannot have been interrupted.
    pub(crate) fn unstopped(self) -> C {
        match self {
            Outcome::Finished(c) => *c,
            Outcome::Interrupted(_) => unreachable!("nothing stops a calibration without a stop"),
        }
    }
}

/// The phase a calibration was stopped in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Phase {
    /// Evaluating the candidates.
    Candidates,
    /// The Levenberg–Marquardt runs from the best candidates.
    Optimisation,
    /// The cross validation (the estimate was complete).
    CrossValidation,
}

impl Phase {
    /// Lower-case name, as messages print it.
    pub fn as_str(self) -> &'static str {
        match self {
            Phase::Candidates => "candidates",
            Phase::Optimisation => "optimisation",
            Phase::CrossValidation => "cross validation",
        }
    }
}

/// What an interrupted calibration had completed.
#[derive(Debug, Clone)]
pub struct Interrupted {
    /// The calibrated parameters.
    pub params: Vec<Param>,
    /// Every candidate point of the calibration ([`candidate_points`]), in order.
    pub points: Vec<Vec<f64>>,
    /// The cost `½‖r‖²` of each point; `None` where it was not evaluated. Given back to
    /// [`calibrate_until`] as `known`, the calibration goes on to the same estimates as an
    /// uninterrupted run.
    pub costs: Vec<Option<f64>>,
    /// The Levenberg–Marquardt runs that finished, best first.
    pub runs: Vec<StartRun>,
    /// Where it stopped.
    pub phase: Phase,
}

impl Interrupted {
    /// The candidates when every point has its cost, else the stop in the candidate phase
    /// with the costs evaluated so far.
    pub(crate) fn unless_evaluated(
        params: Vec<Param>,
        points: Vec<Vec<f64>>,
        costs: Vec<Option<f64>>,
    ) -> std::result::Result<Vec<Candidate>, Box<Interrupted>> {
        if costs.iter().any(Option::is_none) {
            return Err(Box::new(Interrupted {
                params,
                points,
                costs,
                runs: Vec::new(),
                phase: Phase::Candidates,
            }));
        }
        Ok(points
            .into_iter()
            .zip(costs)
            .map(|(values, c)| Candidate {
                values,
                cost: c.unwrap_or(f64::NAN),
            })
            .collect())
    }

    /// A stop after every one of `candidates` was evaluated, with the finished `runs`.
    pub fn evaluated_all(
        params: Vec<Param>,
        candidates: Vec<Candidate>,
        runs: Vec<StartRun>,
        phase: Phase,
    ) -> Interrupted {
        let (points, costs) = candidates
            .into_iter()
            .map(|c| (c.values, Some(c.cost)))
            .unzip();
        Interrupted {
            params,
            points,
            costs,
            runs,
            phase,
        }
    }

    /// A calibration that finished as it was asked to stop, kept as one stopped at its end
    /// (every candidate and run, [`Phase::CrossValidation`]): the caller that asked to
    /// stop gets what it can resume from, not a result it did not wait for.
    pub fn finished(c: impl Searched) -> Interrupted {
        let (params, candidates, runs) = c.into_search();
        Interrupted::evaluated_all(params, candidates, runs, Phase::CrossValidation)
    }

    /// Whether `given` are these `points` (the candidates of a calibration,
    /// [`candidate_points`]) bit for bit: a file of kept costs belongs to this calibration
    /// only then.
    pub fn same_points<'a>(
        points: &[Vec<f64>],
        mut given: impl ExactSizeIterator<Item = &'a [f64]>,
    ) -> bool {
        given.len() == points.len()
            && points.iter().all(|p| {
                given.next().is_some_and(|g| {
                    g.len() == p.len() && g.iter().zip(p).all(|(a, b)| a.to_bits() == b.to_bits())
                })
            })
    }

    /// Candidates evaluated.
    pub fn evaluated(&self) -> usize {
        self.costs.iter().filter(|c| c.is_some()).count()
    }

    /// The best values so far and their cost: the best finished optimisation, else the
    /// evaluated candidate of lowest finite cost; `None` when nothing finite was evaluated.
    pub fn best(&self) -> Option<(&[f64], f64)> {
        if let Some(r) = self.runs.first() {
            return Some((&r.values, r.report.cost));
        }
        self.points
            .iter()
            .zip(&self.costs)
            .filter_map(|(p, c)| c.filter(|c| c.is_finite()).map(|c| (p.as_slice(), c)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }
}

/// A [`LeastSquares`] problem that refuses to evaluate once `stop()` holds: the optimiser
/// then returns at once with that `Err`, which the caller reads as the interruption.
struct Stoppable<'a, O> {
    inner: &'a mut O,
    stop: Stop<'a>,
}

impl<O: LeastSquares> LeastSquares for Stoppable<'_, O> {
    fn n_params(&self) -> usize {
        self.inner.n_params()
    }

    fn evaluate(&mut self, u: &[f64]) -> Result<Option<crate::lm::Evaluation>> {
        if (self.stop)() {
            return Err(Error::Numerical {
                what: "calibration".into(),
                detail: "interrupted".into(),
            });
        }
        self.inner.evaluate(u)
    }
}

/// [`levenberg_marquardt`] on `problem` that stops when `stop()` holds: `Ok(None)` then.
pub(crate) fn lm_until<O: LeastSquares>(
    problem: &mut O,
    u0: &[f64],
    lo: &[f64],
    hi: &[f64],
    lm: &LmConfig,
    stop: Stop<'_>,
) -> Result<Option<LmReport>> {
    let mut s = Stoppable {
        inner: problem,
        stop,
    };
    match levenberg_marquardt(&mut s, u0, lo, hi, lm) {
        Err(_) if stop() => Ok(None),
        r => r.map(Some),
    }
}

/// Indices of the `starts` candidates of lowest finite cost, best first (ties by index).
pub(crate) fn best_candidates(candidates: &[Candidate], starts: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..candidates.len())
        .filter(|&i| candidates[i].cost.is_finite())
        .collect();
    order.sort_by(|&a, &b| {
        candidates[a]
            .cost
            .total_cmp(&candidates[b].cost)
            .then(a.cmp(&b))
    });
    order.truncate(starts);
    order
}

/// Levenberg–Marquardt from each candidate in `order`, in parallel (each run on its own copy
/// of `objective`), best first; `done(finished, total)` after each. Stops when `stop()`
/// holds: the finished runs, best first, and whether every run finished.
pub(crate) fn run_starts_until<O: LeastSquares + Clone + Sync>(
    objective: &O,
    specs: &[ParamSpec],
    candidates: &[Candidate],
    order: &[usize],
    lm: &LmConfig,
    done: &(dyn Fn(usize, usize) + Sync),
    stop: Stop<'_>,
) -> Result<(Vec<StartRun>, bool)> {
    let (lo, hi): (Vec<f64>, Vec<f64>) = specs.iter().map(ParamSpec::internal_bounds).unzip();
    let finished = AtomicUsize::new(0);
    let runs: Vec<Result<Option<StartRun>>> = order
        .par_iter()
        .map(|&i| {
            let mut obj = objective.clone();
            let start = candidates[i].values.clone();
            let u0 = specs_to_internal(specs, &start);
            let Some(report) = lm_until(&mut obj, &u0, &lo, &hi, lm, stop)? else {
                return Ok(None);
            };
            let values = specs_to_values(specs, &report.u);
            done(finished.fetch_add(1, Ordering::Relaxed) + 1, order.len());
            Ok(Some(StartRun {
                start,
                values,
                report,
            }))
        })
        .collect();
    let runs = runs.into_iter().collect::<Result<Vec<_>>>()?;
    let all = runs.iter().all(Option::is_some);
    let mut runs: Vec<StartRun> = runs.into_iter().flatten().collect();
    runs.sort_by(|a, b| a.report.cost.total_cmp(&b.report.cost));
    Ok((runs, all))
}

/// A Jacobian per internal variable (the optimiser's) turned per parameter value at
/// `values`: column `j` divided by `dp_j/du_j`.
pub(crate) fn per_value(specs: &[ParamSpec], values: &[f64], jacobian: &Mat<f64>) -> Mat<f64> {
    let du: Vec<f64> = specs
        .iter()
        .zip(values)
        .map(|(s, &v)| s.dvalue(s.to_internal(v)))
        .collect();
    Mat::from_fn(jacobian.nrows(), jacobian.ncols(), |i, c| {
        jacobian[(i, c)] / du[c]
    })
}
