//! `nlsim calibrate MODEL RECORDS --time-domain`: element law parameters fitted to raw time
//! records (issue 45 part 4) — for sweeps, chirps and decays that never settle into the steady
//! state a stepped sine needs. The records are read and mapped onto the model as
//! `nlsim harmonics` reads them ([`crate::commands::records`]); the model (reduced once, its
//! `modes` lowest modes with residual flexibility) is driven by the recorded force from rest
//! and simulated by the first-order hold at the record's sample interval
//! ([`nlsim_calib::TimeObjective`]), the Jacobian from the forward sensitivities of that
//! recursion. Each channel's noise standard deviation is `data_noise` times its rms. The
//! search is the stepped-sine calibration's: Latin-hypercube candidates, Levenberg–Marquardt
//! from the best, the Cramér–Rao bound, and k-fold cross validation over contiguous blocks of
//! samples.

use crate::commands::calibrate::report::{EstimateView, optimisation_line};
use crate::commands::calibrate::request::CalibrationRequest;
use crate::error::{Error, Result};
use crate::present::summary::counted;
use nlsim_calib::{TimeCalibration, TimeChannel, TimeObjective, TimeRecords};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Most points of a channel's plot in the report (the fit table holds every sample).
const MAX_PLOT_POINTS: usize = 4000;

/// A finished time-domain calibration with what it ran on.
pub struct TimeRun {
    /// The request.
    pub request: CalibrationRequest,
    /// The model's name.
    pub model_name: String,
    /// The record as calibrated on (force, channels with their noise).
    pub records: Arc<TimeRecords>,
    /// Time of the record's first sample (s), as written in the file.
    pub start_s: f64,
    /// Retained modes.
    pub modes: usize,
    /// The result.
    pub calibration: TimeCalibration,
    /// Wall time of loading, reading and reducing (s).
    pub setup_seconds: f64,
    /// Wall time of the candidates, optimisations and folds (s).
    pub seconds: f64,
    /// The candidates file whose costs were reused (`--candidates`), if any.
    pub candidates_from: Option<PathBuf>,
}

/// The objective of a time-domain request, built.
struct PreparedTime {
    model_name: String,
    records: Arc<TimeRecords>,
    start_s: f64,
    modes: usize,
    objective: TimeObjective,
    seconds: f64,
}

fn prepare_time(req: &CalibrationRequest) -> Result<PreparedTime> {
    req.check()?;
    let t = Instant::now();
    let model = crate::commands::setup::load_for_run(&req.model, &req.model_sets())?;
    let mut mapped =
        crate::commands::records::map_records(&model, &req.model, &req.data, None, false)?;
    // The columns move into the calibration's record (each is used once).
    let mut columns = std::mem::take(&mut mapped.records.columns);
    let channels = mapped
        .channels
        .iter()
        .zip(&mapped.columns[1..])
        .map(|((name, _), &j)| {
            let values = std::mem::take(&mut columns[j]);
            let rms = (values.iter().map(|v| v * v).sum::<f64>() / values.len() as f64).sqrt();
            if !(rms > 0.0 && rms.is_finite()) {
                return Err(Error::Usage(format!(
                    "{}: channel '{name}' is zero throughout: nothing to fit, and no noise \
                     level to scale by --data-noise",
                    req.data.display()
                )));
            }
            Ok(TimeChannel {
                name: name.clone(),
                values,
                sigma: req.data_options.noise * rms,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    let force = std::mem::take(&mut columns[mapped.drive_column]);
    if !force.iter().any(|f| *f != 0.0) {
        return Err(Error::Usage(format!(
            "{}: the drive '{}' is zero throughout: the model would rest, nothing to \
             calibrate",
            req.data.display(),
            mapped.drive
        )));
    }
    let records = Arc::new(TimeRecords {
        rate_hz: mapped.records.rate_hz,
        input: mapped.drive.clone(),
        force,
        channels,
    });
    let modes = req.modes.min(model.n_dofs());
    let reduction = nlsim_reduction::ReductionConfig::lowest(modes);
    let objective =
        TimeObjective::new(&model, &reduction, Arc::clone(&records), req.params.clone())
            .map_err(|e| Error::Usage(format!("{}: {e}", req.data.display())))?;
    Ok(PreparedTime {
        model_name: model.name().to_string(),
        records,
        start_s: mapped.records.start_s,
        modes,
        objective,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Runs a time-domain `req`; `progress` is told of the candidates, optimisations and folds
/// done (from the worker threads). With `candidates` (a file an interrupted run kept) the
/// costs it holds are reused; the run stops at the next safe point once `stop()` holds
/// ([`nlsim_calib::calibrate_time_until`]).
pub fn run_time_calibration_until(
    req: &CalibrationRequest,
    candidates: Option<(PathBuf, Vec<nlsim_calib::Candidate>)>,
    progress: &(dyn Fn(nlsim_calib::Progress) + Sync),
    stop: nlsim_calib::Stop<'_>,
) -> Result<super::RunOutcome<TimeRun>> {
    let p = prepare_time(req)?;
    let t = Instant::now();
    let (known, candidates_from) = match candidates {
        None => (Vec::new(), None),
        Some((path, c)) => {
            let expected = p.objective.candidate_points(&req.config)?;
            (super::known_costs(&path, &c, &expected)?, Some(path))
        }
    };
    let outcome =
        nlsim_calib::calibrate_time_until(&p.objective, &req.config, &known, progress, stop)?;
    let calibration = match outcome {
        nlsim_calib::Outcome::Finished(c) => *c,
        nlsim_calib::Outcome::Interrupted(kept) => {
            return Ok(super::RunOutcome::Interrupted(kept));
        }
    };
    Ok(super::RunOutcome::Finished(Box::new(TimeRun {
        request: req.clone(),
        model_name: p.model_name,
        records: p.records,
        start_s: p.start_s,
        modes: p.modes,
        calibration,
        setup_seconds: p.seconds,
        seconds: t.elapsed().as_secs_f64(),
        candidates_from,
    })))
}

/// Builds the objective of a time-domain `req` and times one evaluation of each kind at the
/// first candidate (`--dry-run`; folds are contiguous blocks of samples).
pub fn estimate_time_calibration(req: &CalibrationRequest) -> Result<super::CalibrationEstimate> {
    use nlsim_calib::LeastSquares;
    let p = prepare_time(req)?;
    let mut obj = p.objective.clone();
    // What the run refuses at its start, the dry run refuses too.
    nlsim_calib::check_time_folds(&obj, &req.config)?;
    let points = obj.candidate_points(&req.config)?;
    let t = Instant::now();
    obj.cost_values(&points[0])?;
    let cost_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    obj.evaluate(&obj.to_internal(&points[0]))?;
    let jacobian_seconds = t.elapsed().as_secs_f64();
    Ok(super::CalibrationEstimate {
        setup_seconds: p.seconds,
        candidates: points.len(),
        cost_seconds,
        jacobian_seconds,
        starts: req.config.starts.min(points.len()),
        folds: req.config.folds,
        max_iterations: req.config.lm.max_iterations,
        threads: rayon::current_num_threads(),
    })
}

impl TimeRun {
    /// The readable summary: what was calibrated on what, how the optimisation went, per
    /// parameter the estimate and its spreads, per channel the rms residual against its noise.
    pub fn summary(&self) -> Vec<String> {
        let c = &self.calibration;
        let r = &self.records;
        let best = &c.runs[0].report;
        let names: Vec<&str> = r.channels.iter().map(|c| c.name.as_str()).collect();
        let mut v = vec![
            format!(
                "calibrating {} of '{}' on {} in the time domain ({} at {:.6} Hz, {:.4} s; \
                 drive '{}', {} {}; {} modes); setup {:.2} s",
                counted(c.params.len(), "parameter"),
                self.model_name,
                self.request.data.display(),
                counted(r.len(), "sample"),
                r.rate_hz,
                (r.len() - 1) as f64 / r.rate_hz,
                r.input,
                if names.len() == 1 {
                    "channel"
                } else {
                    "channels"
                },
                names.join(", "),
                self.modes,
                self.setup_seconds
            ),
            optimisation_line(
                best,
                c.candidates.len(),
                &super::report::reused_costs(self.candidates_from.as_deref()),
                self.seconds,
            ),
            format!(
                "cost {:.6e}, reduced chi2 {:.3} (1 when the noise model fits: each channel's \
                 noise is {} of its rms), collinearity index {:.2}",
                c.cost,
                c.cramer_rao.reduced_chi2,
                self.request.data_options.noise,
                c.cramer_rao.collinearity
            ),
        ];
        if let Some(w) = c.cramer_rao.misfit_warning() {
            v.push(format!("warning: {w}"));
        }
        v.extend(self.estimates().lines());
        let per: Vec<String> = r
            .channels
            .iter()
            .zip(&c.fit.simulated)
            .map(|(ch, y)| {
                let rms = (ch
                    .values
                    .iter()
                    .zip(y)
                    .map(|(m, s)| (s - m).powi(2))
                    .sum::<f64>()
                    / ch.values.len() as f64)
                    .sqrt();
                format!("{} {:.3}", ch.name, rms / ch.sigma)
            })
            .collect();
        v.push(format!(
            "rms residual per channel at the estimate, in units of its noise: {}",
            per.join(", ")
        ));
        if let Some(k) = &c.kfold {
            let held: Vec<String> = k.held_out_rms.iter().map(|r| format!("{r:.3}")).collect();
            v.push(format!(
                "each of {} contiguous blocks held out and predicted from the others: rms \
                 weighted residual (1 = the noise level) {}",
                k.k,
                held.join(", ")
            ));
        }
        v
    }

    /// Estimates and statistics, one row per parameter (the stepped-sine calibration's
    /// columns).
    pub fn estimates_csv(&self) -> String {
        self.estimates().csv()
    }

    /// The estimate with its statistics.
    pub fn estimates(&self) -> EstimateView<'_> {
        let c = &self.calibration;
        EstimateView {
            params: &c.params,
            estimate: &c.estimate,
            cramer_rao: &c.cramer_rao,
            kfold: c.kfold.as_ref(),
            at_bound: &c.at_bound,
            poorly_identified: &c.poorly_identified,
        }
    }

    /// Every sample: its time, and per channel the measured and the calibrated response.
    pub fn fit_csv(&self) -> String {
        let r = &self.records;
        let mut s = String::from("time_s");
        for ch in &r.channels {
            let _ = write!(s, ",{0}_measured,{0}_model", ch.name);
        }
        s.push('\n');
        for k in 0..r.len() {
            let _ = write!(s, "{:?}", self.start_s + k as f64 / r.rate_hz);
            for (ch, y) in r.channels.iter().zip(&self.calibration.fit.simulated) {
                let _ = write!(
                    s,
                    ",{:?},{:?}",
                    ch.values[k],
                    y.get(k).copied().unwrap_or(f64::NAN)
                );
            }
            s.push('\n');
        }
        s
    }
}

/// Writes the report of a time-domain calibration into `dir`: `summary.txt`,
/// `estimates.csv`, `candidates.csv`, `convergence.csv`, `fit.csv` (every sample measured and
/// calibrated), per channel a plot of both over time (at most 4000 points drawn), the
/// convergence plot, and the page. Returns the files written.
pub fn write_time_report(dir: &Path, run: &TimeRun) -> Result<Vec<PathBuf>> {
    let c = &run.calibration;
    let (report, mut written) = crate::commands::calibrate::report::search_report(
        dir,
        &format!("nlsim calibrate (time domain): {}", run.model_name),
        &run.request,
        &run.model_name,
        &run.summary(),
        &run.estimates_csv(),
        (&c.params, &c.candidates, &c.runs),
        vec![("fit.csv", run.fit_csv())],
    )?;
    report.section("Measured and calibrated responses");
    let r = &run.records;
    let stride = r.len().div_ceil(MAX_PLOT_POINTS).max(1);
    for (ch, y) in r.channels.iter().zip(&c.fit.simulated) {
        let t = |k: usize| run.start_s + k as f64 / r.rate_hz;
        let series = vec![
            (
                "measured".to_string(),
                (0..r.len())
                    .step_by(stride)
                    .map(|k| (t(k), ch.values[k]))
                    .collect(),
            ),
            (
                "calibrated model".to_string(),
                (0..y.len()).step_by(stride).map(|k| (t(k), y[k])).collect(),
            ),
        ];
        let name = format!("fit_{}", crate::present::report::safe_name(&ch.name));
        written.extend(report.figure(
            &name,
            &crate::present::plot::Lines {
                title: format!("{}: {} measured and calibrated", run.model_name, ch.name),
                x_desc: "time (s)".into(),
                y_desc: format!("{} (SI)", ch.name),
                series,
            },
        )?);
    }
    crate::commands::calibrate::report::finish_search_report(
        report,
        &run.model_name,
        &c.runs,
        written,
    )
}

/// Prints the summary of a time-domain calibration and writes the estimates CSV and the
/// report folder that `req` asks for.
pub fn write_time_outputs(
    req: &CalibrationRequest,
    run: &TimeRun,
    console: &crate::present::console::Console,
) -> Result<()> {
    let report = |dir: &Path| write_time_report(dir, run);
    let contents = "summary.txt, tables, fit.csv, plots per channel";
    crate::commands::calibrate::report::write_calibration_outputs(
        req,
        &run.summary(),
        &run.estimates_csv(),
        (&report, contents),
        console,
    )
}
