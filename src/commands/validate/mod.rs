//! `nlsim validate`: a calibration's result predicts sweeps it was not trained on (by
//! default the ones its `train` selection held out), with a band from the parameter
//! covariance propagated through the analytic harmonic-balance sensitivities plus the
//! data's noise model, and scores every sweep (thesis §4.6, the validation step of papers
//! IV and V): rms log-amplitude and phase errors, the fraction of points inside the band,
//! the reduced χ² of the prediction, the peak measured and predicted.
//!
//! `run.rs` holds the request and the run, `report.rs` the table, the CSVs and the report
//! folder.

pub mod report;
pub mod run;

pub use report::*;
pub use run::*;

/// `nlsim validate`: the run, the summary printed, and the report folder when asked for.
pub fn execute(
    req: &ValidateRequest,
    console: &crate::present::console::Console,
) -> crate::Result<()> {
    crate::formats::files::check_outputs(
        &[Some(req.calibration.as_path()), req.data.as_deref()],
        &[req.out.as_deref()],
        &[req.report.as_deref()],
    )?;
    if let Some(out) = &req.out {
        out_format(out)?;
    }
    console.progress("predicting (harmonic balance with sensitivities at every step)");
    let run = run_validation(req);
    console.progress_end();
    let run = run?;
    for line in run.summary() {
        console.say(&line);
    }
    if let Some(out) = &req.out {
        write_prediction(out, &run)?;
        console.say(&format!("prediction written to {}", out.display()));
    }
    if let Some(dir) = &req.report {
        let files = crate::formats::guard::write_folder(dir, |d| write_report(d, &run))?;
        console.say(&format!(
            "report: {} files in {} (summary.txt, scores.csv, prediction.csv, plots as SVG and PNG)",
            files.len(),
            dir.display()
        ));
    }
    Ok(())
}
