//! Time-domain calibration (issue 45 part 4): element law parameters from measured time
//! histories — sweeps, chirps, free decays, records that never reach a steady state — against
//! first-order-hold simulations of the reduced model driven by the measured force (thesis
//! §3.1: the hold integrator is exact for a force that varies linearly between samples, the
//! way a sampled record is read).
//!
//! Residuals, one per channel and sample: `r = (y_sim(t_k) − ỹ(t_k)) / σ_c`, `σ_c` the
//! channel's noise standard deviation. The Jacobian comes from the forward sensitivities of
//! the hold recursion ([`nlsim_sim::Simulator::run_with_sensitivities`]: one linear pass per
//! parameter beside the run, no finite differences). Contact events are not located inside
//! steps here (the sensitivities follow the fixed-step map), so a clearance's kink is resolved
//! to the sample interval; sample finely enough for it.
//!
//! The search is the stepped-sine calibration's: maximin Latin-hypercube candidates (cost only,
//! in parallel), bounded Levenberg–Marquardt from the best, the Cramér–Rao bound at the
//! estimate and k-fold cross validation over contiguous blocks of samples (the simulation
//! always runs the whole record; a fold leaves its block out of the residuals). Bit-identical
//! for any thread count.

use crate::CalibrationConfig;
use crate::calibrate::{
    Candidate, FoldResult, Interrupted, KFold, Outcome, Phase, Progress, StartRun, Stop,
    best_candidates, candidates_until, lm_until, per_value, start_points,
};
use crate::lm::{Evaluation, LeastSquares};
use crate::objective::{ParamSpec, specs_to_internal, specs_to_values};
use crate::stats::CramerRao;
use faer::Mat;
use nlsim_kernel::{Error, Model, Param, Parameterized, Result, Status};
use nlsim_reduction::{ModalSystem, ReductionConfig, reduce};
use nlsim_sim::{FohConfig, LoadCase, Plant, Signal, Simulator};
use rayon::prelude::*;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};

/// Most samples of a record: the Jacobian holds one row per channel and sample.
pub const MAX_TIME_SAMPLES: usize = 10_000_000;

/// One measured response channel of a record.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeChannel {
    /// The model's sensor it is compared with.
    pub name: String,
    /// Its samples (the sensor's unit), at the record's sample times.
    pub values: Vec<f64>,
    /// The standard deviation of its noise (the sensor's unit), the weight of its residuals.
    pub sigma: f64,
}

/// A measured time record: the drive force and the responses, evenly sampled from `t = 0`.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeRecords {
    /// Sample rate (Hz).
    pub rate_hz: f64,
    /// The model's excitation the force drives.
    pub input: String,
    /// The measured force (N), one sample per time.
    pub force: Vec<f64>,
    /// The measured responses.
    pub channels: Vec<TimeChannel>,
}

impl TimeRecords {
    /// Checks the record: a positive finite rate, at least 3 samples and at most
    /// [`MAX_TIME_SAMPLES`], every channel as long as the force, finite samples (the first
    /// bad one named by channel and sample), positive finite noise, distinct channel names.
    pub fn validate(&self) -> Result<()> {
        if !(self.rate_hz > 0.0 && self.rate_hz.is_finite()) {
            return Err(Error::invalid(
                "time record",
                format!(
                    "the sample rate must be positive and finite, not {} Hz",
                    self.rate_hz
                ),
            ));
        }
        let n = self.force.len();
        if !(3..=MAX_TIME_SAMPLES).contains(&n) {
            return Err(Error::invalid(
                "time record",
                format!("{n} samples: give 3 to {MAX_TIME_SAMPLES}"),
            ));
        }
        if let Some(k) = self.force.iter().position(|v| !v.is_finite()) {
            return Err(Error::invalid(
                format!("time record, drive '{}'", self.input),
                format!(
                    "sample {k} (t = {:e} s) is not finite",
                    k as f64 / self.rate_hz
                ),
            ));
        }
        if self.channels.is_empty() {
            return Err(Error::invalid("time record", "has no response channel"));
        }
        for (i, c) in self.channels.iter().enumerate() {
            let what = || format!("time record, channel '{}'", c.name);
            if self.channels[..i].iter().any(|o| o.name == c.name) {
                return Err(Error::invalid(what(), "is given twice"));
            }
            if c.values.len() != n {
                return Err(Error::DimensionMismatch {
                    what: format!("{}: samples (one per drive sample)", what()),
                    expected: n,
                    found: c.values.len(),
                });
            }
            if let Some(k) = c.values.iter().position(|v| !v.is_finite()) {
                return Err(Error::invalid(
                    what(),
                    format!(
                        "sample {k} (t = {:e} s) is not finite",
                        k as f64 / self.rate_hz
                    ),
                ));
            }
            if !(c.sigma > 0.0 && c.sigma.is_finite()) {
                return Err(Error::invalid(
                    what(),
                    format!("noise standard deviation must be positive, not {}", c.sigma),
                ));
            }
        }
        Ok(())
    }

    /// Samples per channel.
    pub fn len(&self) -> usize {
        self.force.len()
    }

    /// Whether the record has no samples.
    pub fn is_empty(&self) -> bool {
        self.force.is_empty()
    }
}

/// The time-domain least-squares problem over element law parameters.
#[derive(Debug, Clone)]
pub struct TimeObjective {
    sim: Arc<Simulator>,
    case: LoadCase,
    data: Arc<TimeRecords>,
    specs: Vec<ParamSpec>,
    /// The plant output of each channel.
    outputs: Vec<usize>,
    /// The samples whose residuals count.
    mask: Vec<bool>,
    /// The model's values of the parameters.
    current: Vec<f64>,
}

/// The model against a record at one set of values.
#[derive(Debug, Clone)]
pub struct TimeFit {
    /// Simulated responses, channels × samples (fewer samples when the run stopped short).
    pub simulated: Vec<Vec<f64>>,
    /// Weighted residuals of the counted samples, channel by channel.
    pub residuals: Vec<f64>,
    /// Jacobian with respect to the internal variables (residuals × parameters), when asked.
    pub jacobian: Option<Mat<f64>>,
}

impl TimeObjective {
    /// The problem for `specs` (element law parameters of `model`) against `data`: the model
    /// reduced once as `reduction` says, its excitation `data.input` driven by the measured
    /// force (every other excitation idle), its sensors compared with the channels of the
    /// same names, simulated by the first-order hold at the record's sample interval
    /// without event location.
    pub fn new(
        model: &Model,
        reduction: &ReductionConfig,
        data: Arc<TimeRecords>,
        specs: Vec<ParamSpec>,
    ) -> Result<Self> {
        data.validate()?;
        if specs.is_empty() {
            return Err(Error::invalid(
                "time-domain calibration",
                "no parameters to calibrate",
            ));
        }
        for s in &specs {
            s.check()?;
            if !matches!(s.param, Param::Element { .. }) {
                return Err(Error::invalid(
                    "time-domain calibration",
                    format!(
                        "{} is not a parameter of a nonlinear element's law; the time-domain \
                         calibration fits element laws (calibrate the linear part on \
                         stepped-sine or modal data first)",
                        s.param
                    ),
                ));
            }
        }
        let current = specs
            .iter()
            .map(|s| model.param(&s.param))
            .collect::<Result<Vec<_>>>()?;
        let red = reduce(model, reduction)?;
        let sys = ModalSystem::new(&red)?;
        let plant = Plant::from_model(model, &sys)?;
        if !plant.inputs.iter().any(|(n, _)| *n == data.input) {
            return Err(Error::invalid(
                "time-domain calibration",
                format!(
                    "the record drives '{}', which is not an excitation of the model ({})",
                    data.input,
                    plant
                        .inputs
                        .iter()
                        .map(|(n, _)| n.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            ));
        }
        let outputs = data
            .channels
            .iter()
            .map(|c| {
                plant
                    .outputs
                    .iter()
                    .position(|o| o.name == c.name)
                    .ok_or_else(|| {
                        Error::invalid(
                            "time-domain calibration",
                            format!(
                                "channel '{}' is not a sensor of the model ({})",
                                c.name,
                                plant
                                    .outputs
                                    .iter()
                                    .map(|o| o.name.as_str())
                                    .collect::<Vec<_>>()
                                    .join(", ")
                            ),
                        )
                    })
            })
            .collect::<Result<Vec<_>>>()?;
        let forces = plant
            .inputs
            .iter()
            .map(|(n, _)| {
                if *n == data.input {
                    Signal::Sampled {
                        rate_hz: data.rate_hz,
                        values: data.force.clone(),
                    }
                } else {
                    Signal::Zero
                }
            })
            .collect();
        let cfg = FohConfig {
            locate_events: false,
            ..FohConfig::new(1.0 / data.rate_hz)
        };
        let sim = Simulator::new(&plant, &cfg)?;
        let n = data.len();
        Ok(Self {
            sim: Arc::new(sim),
            case: LoadCase::new("record", forces),
            data,
            specs,
            outputs,
            mask: vec![true; n],
            current,
        })
    }

    /// The parameters with their bounds.
    pub fn specs(&self) -> &[ParamSpec] {
        &self.specs
    }

    /// The record.
    pub fn data(&self) -> &TimeRecords {
        &self.data
    }

    /// Internal variables of values `p`.
    pub fn to_internal(&self, p: &[f64]) -> Vec<f64> {
        specs_to_internal(&self.specs, p)
    }

    /// Values of internal variables `u`.
    pub fn to_values(&self, u: &[f64]) -> Vec<f64> {
        specs_to_values(&self.specs, u)
    }

    /// Counts only the samples where `mask` is true (one entry per sample).
    pub fn set_mask(&mut self, mask: Vec<bool>) -> Result<()> {
        if mask.len() != self.data.len() {
            return Err(Error::DimensionMismatch {
                what: "time-domain calibration sample mask".into(),
                expected: self.data.len(),
                found: mask.len(),
            });
        }
        self.mask = mask;
        Ok(())
    }

    /// The model against the record at `values`, the Jacobian when `jacobian`; `mask`
    /// replaces the objective's own for this evaluation. `Ok(None)` when the simulation
    /// stops short (diverges, or the element loop fails); `Err` for invalid values.
    pub fn fit_values(
        &self,
        values: &[f64],
        mask: Option<&[bool]>,
        jacobian: bool,
    ) -> Result<Option<TimeFit>> {
        if values.len() != self.specs.len() {
            return Err(Error::DimensionMismatch {
                what: "time-domain calibration parameter values".into(),
                expected: self.specs.len(),
                found: values.len(),
            });
        }
        let mut case = self.case.clone();
        case.parameters = self
            .specs
            .iter()
            .zip(values)
            .map(|(s, &v)| (s.param.clone(), v))
            .collect();
        let n = self.data.len();
        let params: Vec<Param> = self.specs.iter().map(|s| s.param.clone()).collect();
        let (h, sens) = if jacobian {
            let (h, s) = self.sim.run_with_sensitivities(&case, n - 1, &params)?;
            (h, Some(s))
        } else {
            (self.sim.run(&case, n - 1)?, None)
        };
        if !h.status.is_converged() {
            return Ok(None);
        }
        let mask = mask.unwrap_or(&self.mask);
        let rows = mask.iter().filter(|&&m| m).count() * self.outputs.len();
        let mut residuals = Vec::with_capacity(rows);
        let mut jac = sens.as_ref().map(|_| Mat::zeros(rows, self.specs.len()));
        let du: Vec<f64> = self
            .specs
            .iter()
            .zip(values)
            .map(|(s, &v)| s.dvalue(s.to_internal(v)))
            .collect();
        let mut outputs = h.outputs;
        let mut simulated = Vec::with_capacity(self.outputs.len());
        for (c, &o) in self.outputs.iter().enumerate() {
            let ch = &self.data.channels[c];
            // Each channel has its own output (names are distinct): moved, not copied.
            let y = std::mem::take(&mut outputs[o].values);
            for k in (0..n).filter(|&k| mask[k]) {
                if let (Some(j), Some(s)) = (jac.as_mut(), sens.as_ref()) {
                    let row = residuals.len();
                    for (p, d) in du.iter().enumerate() {
                        j[(row, p)] = s.outputs[p][o][k] * d / ch.sigma;
                    }
                }
                residuals.push((y[k] - ch.values[k]) / ch.sigma);
            }
            simulated.push(y);
        }
        Ok(Some(TimeFit {
            simulated,
            residuals,
            jacobian: jac,
        }))
    }

    /// Cost `½‖r‖²` at `values` (the objective's mask); infinite where the run stops short.
    pub fn cost_values(&self, values: &[f64]) -> Result<f64> {
        Ok(self
            .fit_values(values, None, false)?
            .map_or(f64::INFINITY, |f| {
                0.5 * f.residuals.iter().map(|r| r * r).sum::<f64>()
            }))
    }

    /// The points [`calibrate_time`] evaluates as candidates: the model's values (clamped to
    /// the bounds), then the Latin hypercube of `config`.
    pub fn candidate_points(&self, config: &CalibrationConfig) -> Result<Vec<Vec<f64>>> {
        start_points(&self.specs, &self.current, config)
    }
}

impl LeastSquares for TimeObjective {
    fn n_params(&self) -> usize {
        self.specs.len()
    }

    fn evaluate(&mut self, u: &[f64]) -> Result<Option<Evaluation>> {
        let values = self.to_values(u);
        Ok(self.fit_values(&values, None, true)?.map(|f| Evaluation {
            residuals: f.residuals,
            jacobian: f.jacobian.expect("asked for"),
        }))
    }
}

/// The outcome of [`calibrate_time`].
#[derive(Debug, Clone)]
pub struct TimeCalibration {
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
    /// Parameters that are poorly identifiable ([`CramerRao::poorly_identified`]).
    pub poorly_identified: Vec<bool>,
    /// The model against the record at the estimate.
    pub fit: TimeFit,
    /// Cost `½‖r‖²` at the estimate.
    pub cost: f64,
    /// The cross validation over contiguous blocks of samples, when `config.folds ≥ 2`
    /// (`fold_of` per sample).
    pub kfold: Option<KFold>,
}

/// Fold of every sample: `k` contiguous blocks of (nearly) equal length.
pub fn time_blocks(n: usize, k: usize) -> Vec<usize> {
    (0..n).map(|i| i * k / n.max(1)).collect()
}

/// Fewest samples of the first horizon of [`horizon_lm`].
const FIRST_HORIZON: usize = 64;

/// Levenberg–Marquardt over growing horizons (continuation in the record's length): from
/// `u0`, fitted on the samples of `mask` in the first eighth of the record (at least
/// [`FIRST_HORIZON`] samples), then the first quarter, half, and the whole record, each from
/// the last one's optimum. A response that drifts in phase with the parameters over a long
/// record makes the whole record's cost oscillate in them (many local minima); over a short
/// horizon it is nearly quadratic, and each doubling starts inside the next basin. Returns the
/// whole record's report, with the iterations and evaluations of every horizon counted and
/// their histories joined; `None` when `stop()` held before an evaluation.
fn horizon_lm(
    objective: &TimeObjective,
    u0: &[f64],
    mask: &[bool],
    lm: &crate::LmConfig,
    stop: Stop<'_>,
) -> Result<Option<crate::LmReport>> {
    let (lo, hi): (Vec<f64>, Vec<f64>) = objective
        .specs
        .iter()
        .map(ParamSpec::internal_bounds)
        .unzip();
    let n = mask.len();
    let mut obj = objective.clone();
    let mut u = u0.to_vec();
    let mut end = (n / 8).max(FIRST_HORIZON).min(n);
    let (mut iterations, mut evaluations, mut rejected, mut failed) = (0, 0, 0, 0);
    let mut history = Vec::new();
    loop {
        obj.set_mask((0..n).map(|k| mask[k] && k < end).collect())?;
        let Some(mut rep) = lm_until(&mut obj, &u, &lo, &hi, lm, stop)? else {
            return Ok(None);
        };
        iterations += rep.iterations;
        evaluations += rep.evaluations;
        rejected += rep.rejected;
        failed += rep.failed_evaluations;
        u.clone_from(&rep.u);
        if end == n {
            rep.iterations = iterations;
            rep.evaluations = evaluations;
            rep.rejected = rejected;
            rep.failed_evaluations = failed;
            history.append(&mut rep.history);
            rep.history = history;
            return Ok(Some(rep));
        }
        history.append(&mut rep.history);
        end = (2 * end).min(n);
    }
}

/// Refuses a cross validation the record cannot hold: `config.folds` contiguous blocks of
/// at least 2 samples each. Run at the start of [`calibrate_time`] and by the
/// CLI's `--dry-run`.
pub fn check_time_folds(objective: &TimeObjective, config: &CalibrationConfig) -> Result<()> {
    let (k, n) = (config.folds, objective.data.len());
    if k >= 2 && n < 2 * k {
        return Err(Error::invalid(
            "time-domain calibration",
            format!("folds = {k}: the record's {n} samples do not make {k} blocks of 2"),
        ));
    }
    Ok(())
}

/// Calibrates `objective`'s parameters on its record: Latin-hypercube candidates (in
/// parallel), Levenberg–Marquardt from the best `config.starts`, the Cramér–Rao bound at the
/// optimum and, with `config.folds ≥ 2`, the cross validation over that many contiguous
/// blocks of samples (each block left out in turn, the rest calibrated from the estimate).
/// `progress` is called as candidates, optimisations and folds finish.
pub fn calibrate_time(
    objective: &TimeObjective,
    config: &CalibrationConfig,
    progress: &(dyn Fn(Progress) + Sync),
) -> Result<TimeCalibration> {
    Ok(calibrate_time_until(objective, config, &[], progress, &|| false)?.unstopped())
}

/// [`calibrate_time`] that reuses the candidate costs in `known` (one per point of
/// [`TimeObjective::candidate_points`], `None` where not evaluated; empty for none) and stops at the
/// next safe point once `stop()` holds — before a candidate, before a Levenberg–Marquardt
/// evaluation of any horizon or fold — with what was complete. Run again with the kept costs
/// as `known` it reaches the uninterrupted run's estimates bit for bit.
pub fn calibrate_time_until(
    objective: &TimeObjective,
    config: &CalibrationConfig,
    known: &[Option<f64>],
    progress: &(dyn Fn(Progress) + Sync),
    stop: Stop<'_>,
) -> Result<Outcome<TimeCalibration>> {
    config.validate_settings()?;
    config.lm.validate()?;
    // Refused at the start, not after the candidates and the optimisation.
    check_time_folds(objective, config)?;
    let specs = objective.specs.clone();
    let params: Vec<Param> = specs.iter().map(|s| s.param.clone()).collect();
    let points = objective.candidate_points(config)?;
    let cost = |obj: &mut TimeObjective, v: &[f64]| obj.cost_values(v);
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
            what: "time-domain calibration".into(),
            detail: "the simulation stopped short at every candidate".into(),
        });
    }
    let finished = AtomicUsize::new(0);
    let runs: Vec<Result<Option<StartRun>>> = order
        .par_iter()
        .map(|&i| {
            let start = candidates[i].values.clone();
            let Some(report) = horizon_lm(
                objective,
                &objective.to_internal(&start),
                &objective.mask,
                &config.lm,
                stop,
            )?
            else {
                return Ok(None);
            };
            let values = objective.to_values(&report.u);
            progress(Progress::Start {
                done: finished.fetch_add(1, Ordering::Relaxed) + 1,
                total: order.len(),
            });
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
    let estimate = runs[0].values.clone();
    let fit = objective
        .fit_values(&estimate, None, true)?
        .ok_or_else(|| Error::Numerical {
            what: "time-domain calibration".into(),
            detail: "the simulation stopped short at the estimate".into(),
        })?;
    let jac = fit.jacobian.as_ref().expect("asked for");
    let cost = 0.5 * fit.residuals.iter().map(|r| r * r).sum::<f64>();
    let cramer_rao = CramerRao::new(
        &per_value(&specs, &estimate, jac),
        &fit.residuals,
        &estimate,
    );
    let kfold = if config.folds >= 2 {
        let k = config.folds;
        let n = objective.data.len();
        let fold_of = time_blocks(n, k);
        let done = AtomicUsize::new(0);
        let rms = |r: &[f64]| (r.iter().map(|v| v * v).sum::<f64>() / r.len().max(1) as f64).sqrt();
        let folds: Vec<Result<Option<FoldResult>>> = (0..k)
            .into_par_iter()
            .map(|f| {
                let obj = objective;
                let train: Vec<bool> = fold_of.iter().map(|&g| g != f).collect();
                let held: Vec<bool> = train.iter().map(|t| !t).collect();
                let Some(rep) =
                    horizon_lm(obj, &obj.to_internal(&estimate), &train, &config.lm, stop)?
                else {
                    return Ok(None);
                };
                let values = obj.to_values(&rep.u);
                let training_rms = rep
                    .evaluation
                    .as_ref()
                    .map_or(f64::NAN, |e| rms(&e.residuals));
                let held_out_rms = obj
                    .fit_values(&values, Some(&held), false)?
                    .map_or(f64::INFINITY, |h| rms(&h.residuals));
                let d = done.fetch_add(1, Ordering::Relaxed) + 1;
                progress(Progress::Fold { done: d, total: k });
                Ok(Some(FoldResult {
                    values,
                    status: rep.status,
                    held_out_rms,
                    training_rms,
                }))
            })
            .collect();
        let folds = folds.into_iter().collect::<Result<Option<Vec<_>>>>()?;
        let Some(folds) = folds else {
            return interrupted(runs, candidates, Phase::CrossValidation);
        };
        Some(KFold::from_folds(fold_of, folds)?)
    } else {
        None
    };
    Ok(Outcome::Finished(Box::new(TimeCalibration {
        params,
        status: runs[0].report.status,
        at_bound: runs[0].report.active_bounds.clone(),
        poorly_identified: cramer_rao.poorly_identified(),
        estimate,
        candidates,
        runs,
        cramer_rao,
        fit,
        cost,
        kfold,
    })))
}

/// A virtual time record: `model` (reduced as `reduction` says) with `specs`' parameters at
/// `values`, driven at its excitation `input` by `force` (N, sampled at `rate_hz`), its
/// sensors' responses simulated as [`TimeObjective`] does and given Gaussian noise of `noise`
/// times each channel's rms (drawn from `seed`; the same `σ` stated as the channel's noise).
/// The time-domain counterpart of [`crate::synthesize`].
#[allow(clippy::too_many_arguments)]
pub fn synthesize_time(
    model: &Model,
    reduction: &ReductionConfig,
    specs: &[ParamSpec],
    values: &[f64],
    input: &str,
    force: Vec<f64>,
    rate_hz: f64,
    noise: f64,
    seed: u64,
) -> Result<TimeRecords> {
    if !(noise > 0.0 && noise.is_finite()) {
        return Err(Error::invalid(
            "virtual time record",
            format!("the relative noise must be positive, not {noise}"),
        ));
    }
    let n = force.len();
    let mut rec = TimeRecords {
        rate_hz,
        input: input.to_string(),
        force,
        channels: model
            .sensors()
            .iter()
            .map(|s| TimeChannel {
                name: s.name.clone(),
                values: vec![0.0; n],
                sigma: 1.0,
            })
            .collect(),
    };
    let obj = TimeObjective::new(model, reduction, Arc::new(rec.clone()), specs.to_vec())?;
    let fit = obj
        .fit_values(values, None, false)?
        .ok_or_else(|| Error::Numerical {
            what: "virtual time record".into(),
            detail: "the simulation stopped short".into(),
        })?;
    let mut g = crate::Gaussian::new(seed);
    for (c, y) in rec.channels.iter_mut().zip(fit.simulated) {
        let rms = (y.iter().map(|v| v * v).sum::<f64>() / n as f64).sqrt();
        c.sigma = noise * rms;
        if !(c.sigma > 0.0 && c.sigma.is_finite()) {
            return Err(Error::invalid(
                "virtual time record",
                format!("sensor '{}' does not respond to the force", c.name),
            ));
        }
        c.values = y.iter().map(|v| v + c.sigma * g.sample()).collect();
    }
    Ok(rec)
}
