//! The result of a stepped-sine calibration as a file, `calibration.toml` in the report
//! folder: the calibration file that reproduces the run (model, data, data options, the
//! trained sweeps, parameters with bounds, settings) with a `[result]` table of the
//! estimates, their Cramér–Rao covariance and the reduced χ². `nlsim validate` reads it and
//! predicts the sweeps held out of the training; `nlsim calibrate --config` runs it again
//! (the `[result]` table is then ignored).
//!
//! ```toml
//! [result]
//! status = "converged"
//! estimate = [80.12, 0.0021]        # in [[param]] order
//! covariance = [[1e-4, 0.0], [0.0, 1e-8]]
//! reduced_chi2 = 1.3
//! points = 164                      # training points
//! residuals = 328
//! held_out_mean_square = 24.5       # the cross validation's, when it ran
//! ```

use crate::commands::calibrate::request::{CalibrationRequest, StoredResult};
use crate::commands::calibrate::run::CalibrationRun;
use crate::error::{Error, Result};
use crate::formats::files::toml_string;
use nlsim_calib::{BranchChoice, FeReduction, Form, Spacing};
use std::fmt::Write as _;
use std::path::Path;

/// An `f64` as TOML (shortest round-trip digits; `inf`, `nan`).
fn num(v: f64) -> String {
    if v.is_nan() {
        "nan".into()
    } else if v.is_infinite() {
        if v > 0.0 { "inf".into() } else { "-inf".into() }
    } else {
        format!("{v:?}")
    }
}

/// A path as written in the result: absolute (the result file may be read from anywhere),
/// or a built-in model's name as given.
fn path_text(p: &str) -> String {
    let path = Path::new(p);
    if path.is_file() {
        std::fs::canonicalize(path)
            .or_else(|_| std::path::absolute(path))
            .unwrap_or_else(|_| path.to_path_buf())
            .display()
            .to_string()
    } else {
        p.to_string()
    }
}

/// The text of `calibration.toml` for `run` (module docs).
pub fn result_toml(run: &CalibrationRun) -> String {
    let req: &CalibrationRequest = &run.request;
    let c = &run.calibration;
    let mut s = String::from(
        "# nlsim calibration result: `nlsim validate THIS_FILE` predicts the sweeps held out of\n\
         # the training with a band; `nlsim calibrate --config THIS_FILE` runs the calibration\n\
         # again (the [result] table is then ignored).\n",
    );
    let _ = writeln!(s, "model = {}", toml_string(&path_text(&req.model)));
    let _ = writeln!(
        s,
        "data = {}",
        toml_string(&path_text(&req.data.display().to_string()))
    );
    let list = |v: &[String]| {
        v.iter()
            .map(|t| toml_string(t))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if !req.train.is_empty() {
        let _ = writeln!(s, "train = [{}]", list(&req.train));
    }
    let _ = writeln!(s, "data_noise = {}", num(req.data_options.noise));
    let _ = writeln!(
        s,
        "phase_offset_deg = {}",
        num(req.data_options.phase_offset_deg)
    );
    let _ = writeln!(s, "harmonics = {}", req.harmonics);
    let _ = writeln!(
        s,
        "compare = [{}]",
        req.compare
            .iter()
            .map(|k| k.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    );
    let form = match req.form {
        Form::Complex => "complex",
        Form::LogMagnitudePhase => "log-magnitude",
    };
    let _ = writeln!(s, "form = \"{form}\"");
    let branch = match req.branch {
        BranchChoice::NearestToData => "nearest",
        BranchChoice::Continuation => "continuation",
    };
    let _ = writeln!(s, "branch = \"{branch}\"");
    let _ = writeln!(s, "modes = {}", req.modes);
    if req.time_domain {
        s.push_str("time_domain = true\n");
    }
    match &req.fe {
        FeReduction::Full => s.push_str("fe_reduction = \"full\"\n"),
        FeReduction::Parametric(p) => {
            let _ = writeln!(s, "fe_tolerance = {}", num(p.tolerance));
        }
    }
    let cfg = &req.config;
    let _ = writeln!(
        s,
        "lhs = {}\nstarts = {}\nfolds = {}\nseed = {}",
        cfg.lhs_samples, cfg.starts, cfg.folds, cfg.seed
    );
    if cfg.fold_by == nlsim_calib::FoldBy::Sweeps {
        s.push_str("fold_by = \"sweeps\"\n");
    }
    if let Some(sh) = &req.shaker {
        let _ = writeln!(
            s,
            "\n[shaker]\narmature_mass = {}\nsuspension_stiffness = {}\nsuspension_damping = {}\n\
             resistance = {}\ninductance = {}\nforce_constant = {}\nstinger_stiffness = {}",
            num(sh.armature_mass),
            num(sh.suspension_stiffness),
            num(sh.suspension_damping),
            num(sh.resistance),
            num(sh.inductance),
            num(sh.force_constant),
            num(sh.stinger_stiffness)
        );
    }
    if !req.set.is_empty() {
        s.push_str("\n[set]\n");
        for kv in &req.set {
            if let Some((k, v)) = kv.split_once('=') {
                let _ = writeln!(s, "{} = {}", toml_string(k.trim()), v.trim());
            }
        }
    }
    for p in &req.params {
        let spacing = match p.spacing {
            Spacing::Log => "log",
            Spacing::Linear => "linear",
        };
        let _ = write!(
            s,
            "\n[[param]]\nname = {}\nlower = {}\nupper = {}\nspacing = \"{spacing}\"\n",
            toml_string(&p.param.to_string()),
            num(p.lower),
            num(p.upper)
        );
    }
    let n = c.params.len();
    let rows: Vec<String> = (0..n)
        .map(|i| {
            let r: Vec<String> = (0..n)
                .map(|j| num(c.cramer_rao.covariance[(i, j)]))
                .collect();
            format!("  [{}]", r.join(", "))
        })
        .collect();
    let _ = write!(
        s,
        "\n[result]\nstatus = {}\nestimate = [{}]\ncovariance = [\n{}\n]\nreduced_chi2 = {}\npoints = {}\nresiduals = {}\n",
        toml_string(&c.status.to_string()),
        c.estimate
            .iter()
            .map(|v| num(*v))
            .collect::<Vec<_>>()
            .join(", "),
        rows.join(",\n"),
        num(c.cramer_rao.reduced_chi2),
        run.prepared.objective.data().n_points(),
        c.fit.residuals.len()
    );
    if let Some(kf) = &c.kfold {
        let _ = writeln!(
            s,
            "held_out_mean_square = {}",
            num(kf.held_out_mean_square())
        );
    }
    s
}

/// The calibration request and stored result of a `calibration.toml` (`nlsim validate`'s
/// input); `Err` naming the file when it holds no `[result]` table.
pub fn load_result(path: &Path) -> Result<(CalibrationRequest, StoredResult)> {
    let mut req = CalibrationRequest::load(path)?;
    let result = req.result.take().ok_or_else(|| {
        Error::Usage(format!(
            "{}: no [result] table: this is a calibration file, not a calibration's result; \
             run `nlsim calibrate --config {} --report DIR` and validate DIR/calibration.toml",
            path.display(),
            path.display()
        ))
    })?;
    Ok((req, result))
}
