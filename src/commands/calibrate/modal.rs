//! `nlsim calibrate` on measured modal data (the linear stage, thesis §4.5): FE-level
//! parameters — group stiffness and mass scales, boundary springs — from natural frequencies
//! and mode shapes ([`crate::formats::modal_data`]), with analytic eigen-sensitivities
//! ([`nlsim_calib::ModalObjective`]).
//!
//! The request is the same [`CalibrationRequest`] as for stepped-sine data; `data` names a
//! modal CSV, `shape_noise` is the standard deviation of one component of a unit-normalised
//! measured shape, `modes` the computed modes the pairing chooses from. The harmonic balance
//! settings (`harmonics`, `compare`, `form`) and the folds do not apply.

use crate::commands::calibrate::request::CalibrationRequest;

use crate::error::{Error, Result};
use crate::formats::modal_data::ModalFile;
use crate::formats::modal_data::read_modal_csv;
use nlsim_calib::{ModalCalibration, ModalObjective};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// A finished modal calibration with what it ran on.
pub struct ModalRun {
    /// The request.
    pub request: CalibrationRequest,
    /// The model's name.
    pub model_name: String,
    /// The measured modes.
    pub file: ModalFile,
    /// Computed modes the pairing chose from.
    pub modes: usize,
    /// The result.
    pub calibration: ModalCalibration,
    /// What the evaluations of the modes did (parametric model or full eigen solves).
    pub fe: nlsim_calib::FeReductionStats,
    /// Wall time of loading the model and the data (s).
    pub setup_seconds: f64,
    /// Wall time of the candidates and the optimisations (s).
    pub seconds: f64,
    /// The candidates file whose costs were reused (`--candidates`), if any.
    pub candidates_from: Option<PathBuf>,
}

/// The modal calibration of a request, built: the model loaded, the data read, the objective
/// (with the parametric reduced model unless `fe_reduction = "full"`).
struct PreparedModal {
    model_name: String,
    file: ModalFile,
    modes: usize,
    objective: ModalObjective,
    seconds: f64,
}

fn prepare_modal(req: &CalibrationRequest) -> Result<PreparedModal> {
    req.check()?;
    let t = Instant::now();
    let model = crate::commands::setup::load_for_run(&req.model, &req.model_sets())?;
    let file = read_modal_csv(&req.data, &model, req.shape_noise)?;
    let measured = file.data.modes.len();
    if measured > model.n_dofs() {
        return Err(Error::Usage(format!(
            "{}: {measured} measured modes, but the model has {} DOFs",
            req.data.display(),
            model.n_dofs()
        )));
    }
    let modes = req.modes.clamp(measured, model.n_dofs());
    let model_name = model.name().to_string();
    let objective = ModalObjective::with_reduction(
        model,
        Arc::new(file.data.clone()),
        req.params.clone(),
        modes,
        faer::Par::Seq,
        &req.fe,
    )?;
    Ok(PreparedModal {
        model_name,
        file,
        modes,
        objective,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Runs `req` on modal data: Latin-hypercube candidates, Levenberg–Marquardt from the best,
/// the Cramér–Rao bound at the estimate. Every parameter must be FE-level. `progress` is
/// told of the candidates and optimisations done (from the worker threads). With
/// `candidates` (a file an interrupted run kept) the costs it holds are reused; the run stops
/// at the next safe point once `stop()` holds ([`nlsim_calib::calibrate_modal_until`]).
pub fn run_modal_calibration_until(
    req: &CalibrationRequest,
    candidates: Option<(PathBuf, Vec<nlsim_calib::Candidate>)>,
    progress: &(dyn Fn(nlsim_calib::Progress) + Sync),
    stop: nlsim_calib::Stop<'_>,
) -> Result<super::RunOutcome<ModalRun>> {
    let prepared = prepare_modal(req)?;
    let t = Instant::now();
    let (known, candidates_from) = match candidates {
        None => (Vec::new(), None),
        Some((path, c)) => {
            let expected = prepared.objective.candidate_points(&req.config)?;
            (super::known_costs(&path, &c, &expected)?, Some(path))
        }
    };
    let outcome = nlsim_calib::calibrate_modal_until(
        &prepared.objective,
        &req.config,
        &known,
        progress,
        stop,
    )?;
    let calibration = match outcome {
        nlsim_calib::Outcome::Finished(c) => *c,
        nlsim_calib::Outcome::Interrupted(kept) => {
            return Ok(super::RunOutcome::Interrupted(kept));
        }
    };
    Ok(super::RunOutcome::Finished(Box::new(ModalRun {
        request: req.clone(),
        model_name: prepared.model_name,
        file: prepared.file,
        modes: prepared.modes,
        fe: prepared.objective.fe_stats(),
        calibration,
        setup_seconds: prepared.seconds,
        seconds: t.elapsed().as_secs_f64(),
        candidates_from,
    })))
}

/// Builds the objective of a modal-data `req` and times one evaluation of each kind at the
/// first candidate (see [`super::CalibrationEstimate`]; no folds).
pub fn estimate_modal_calibration(req: &CalibrationRequest) -> Result<super::CalibrationEstimate> {
    let prepared = prepare_modal(req)?;
    let mut obj = prepared.objective.clone();
    let points = obj.candidate_points(&req.config)?;
    let t = Instant::now();
    obj.cost_values(&points[0])?;
    let cost_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    obj.fit_values(&points[0])?;
    let jacobian_seconds = t.elapsed().as_secs_f64();
    Ok(super::CalibrationEstimate {
        setup_seconds: prepared.seconds,
        candidates: points.len(),
        cost_seconds,
        jacobian_seconds,
        starts: req.config.starts.min(points.len()),
        folds: 0,
        max_iterations: req.config.lm.max_iterations,
        threads: rayon::current_num_threads(),
    })
}

impl ModalRun {
    /// The readable summary: what was calibrated on what, how the optimisation went, per
    /// parameter the estimate and its Cramér–Rao bound, per measured mode the calibrated
    /// frequency and MAC.
    pub fn summary(&self) -> Vec<String> {
        let c = &self.calibration;
        let d = &self.file.data;
        let best = &c.runs[0].report;
        let with_shape = d.modes.iter().filter(|m| m.shape.is_some()).count();
        let mut v = vec![
            format!(
                "calibrating {} of '{}' on {} ({} modes, {with_shape} with \
                 shapes at {} DOFs; pairing among {} computed modes); setup {:.2} s",
                crate::present::summary::counted(c.params.len(), "FE-level parameter"),
                self.model_name,
                self.request.data.display(),
                d.modes.len(),
                d.dofs.len(),
                self.modes,
                self.setup_seconds
            ),
            crate::commands::calibrate::report::optimisation_line(
                best,
                c.candidates.len(),
                &super::report::reused_costs(self.candidates_from.as_deref()),
                self.seconds,
            ),
            format!(
                "cost {:.6e}, reduced chi2 {:.3} (1 when the noise model fits), collinearity \
                 index {:.2}",
                c.cost, c.cramer_rao.reduced_chi2, c.cramer_rao.collinearity
            ),
        ];
        if let Some(w) = c.cramer_rao.misfit_warning() {
            v.push(format!("warning: {w}"));
        }
        v.push(super::report::fe_reduction_line(&self.fe, "eigen solve"));
        v.push(format!(
            "{:<22} {:>14} {:>14} {:>14}  flags",
            "parameter", "estimate", "Cramér–Rao", "chi2-scaled"
        ));
        for (j, p) in c.params.iter().enumerate() {
            v.push(format!(
                "{:<22} {:>14.6e} {:>14.3e} {:>14.3e}  {}",
                p.to_string(),
                c.estimate[j],
                c.cramer_rao.std[j],
                c.cramer_rao.scaled_std[j],
                if c.at_bound[j] { "at bound" } else { "" }
            ));
        }
        v.push(format!(
            "{:>6} {:>14} {:>14} {:>9} {:>9} {:>8}",
            "mode", "measured Hz", "calibrated Hz", "error %", "computed", "MAC"
        ));
        for (i, m) in d.modes.iter().enumerate() {
            let f = c.fit.frequencies_hz[i];
            v.push(format!(
                "{:>6} {:>14.6} {:>14.6} {:>9.4} {:>9} {:>8}",
                self.file.labels[i],
                m.frequency_hz,
                f,
                100.0 * (f - m.frequency_hz) / m.frequency_hz,
                c.fit.pairing[i] + 1,
                if c.fit.mac[i].is_nan() {
                    "-".to_string()
                } else {
                    format!("{:.5}", c.fit.mac[i])
                }
            ));
        }
        // A mode without a shape is paired by frequency alone: say when that is doubtful.
        for (i, m) in d.modes.iter().enumerate() {
            let f = c.fit.frequencies_hz[i];
            let off = (f - m.frequency_hz).abs() / m.frequency_hz;
            if c.fit.mac[i].is_nan() && off > 0.05 {
                v.push(format!(
                    "warning: measured mode {} ({:.6} Hz) has no shape and is paired by \
                     frequency with computed mode {} at {:.6} Hz, {:.1} % away: the pairing \
                     may be wrong; give its shape, or leave it out",
                    self.file.labels[i],
                    m.frequency_hz,
                    c.fit.pairing[i] + 1,
                    f,
                    100.0 * off
                ));
            }
        }
        v
    }

    /// Estimates and statistics, one row per parameter.
    pub fn estimates_csv(&self) -> String {
        let c = &self.calibration;
        let mut csv = String::from("param,estimate,cramer_rao_std,at_bound,chi2_scaled_std\n");
        for (j, p) in c.params.iter().enumerate() {
            let _ = writeln!(
                csv,
                "{p},{:?},{:?},{},{:?}",
                c.estimate[j], c.cramer_rao.std[j], c.at_bound[j], c.cramer_rao.scaled_std[j]
            );
        }
        csv
    }

    /// Measured against calibrated modes: frequencies, the paired computed mode and the MAC
    /// (empty where the shape was not measured).
    pub fn modes_csv(&self) -> String {
        let c = &self.calibration;
        let mut csv =
            String::from("mode,measured_hz,measured_std_hz,calibrated_hz,computed_mode,mac\n");
        for (i, m) in self.file.data.modes.iter().enumerate() {
            let _ = writeln!(
                csv,
                "{},{:?},{:?},{:?},{},{}",
                self.file.labels[i],
                m.frequency_hz,
                m.frequency_std_hz,
                c.fit.frequencies_hz[i],
                c.fit.pairing[i] + 1,
                if c.fit.mac[i].is_nan() {
                    String::new()
                } else {
                    format!("{:?}", c.fit.mac[i])
                }
            );
        }
        csv
    }
}

/// Writes the report of a modal calibration into `dir`: `summary.txt`, `estimates.csv`,
/// `modes.csv`, `candidates.csv`, `convergence.csv` and the convergence plot (SVG and PNG).
/// Returns the files written.
pub fn write_modal_report(dir: &Path, run: &ModalRun) -> Result<Vec<PathBuf>> {
    let c = &run.calibration;
    let (report, written) = crate::commands::calibrate::report::search_report(
        dir,
        &format!("nlsim calibrate (modal): {}", run.model_name),
        &run.request,
        &run.model_name,
        &run.summary(),
        &run.estimates_csv(),
        (&c.params, &c.candidates, &c.runs),
        vec![("modes.csv", run.modes_csv())],
    )?;
    report.table(
        "modes",
        crate::present::report::Table::from_csv("Measured and computed modes", &run.modes_csv()),
    )?;
    crate::commands::calibrate::report::finish_search_report(
        report,
        &run.model_name,
        &c.runs,
        written,
    )
}

/// Prints the summary of a modal calibration and writes the estimates CSV and the report
/// folder that `req` asks for.
pub fn write_modal_outputs(
    req: &CalibrationRequest,
    run: &ModalRun,
    console: &crate::present::console::Console,
) -> Result<()> {
    let report = |dir: &Path| write_modal_report(dir, run);
    let contents = "summary.txt, tables, convergence plot";
    let (summary, csv) = (run.summary(), run.estimates_csv());
    crate::commands::calibrate::report::write_calibration_outputs(
        req,
        &summary,
        &csv,
        (&report, contents),
        console,
    )
}
