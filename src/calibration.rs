//! `nlsim calibrate` as library calls: a typed [`CalibrationRequest`] (from the command line
//! or a calibration file), [`run_calibration`] on it, and [`write_report`] with the tables,
//! the plots and the summary of the result.
//!
//! A calibration file (`docs/calibration.md`) holds everything the command line can say,
//! and the settings it cannot:
//!
//! ```toml
//! model = "ecl_beam"              # model file or built-in model
//! data = "test.csv"               # CSV, HDF5, UFF 58 or modal CSV (relative to this file)
//! set = { "tip.c" = 0.5 }         # fixed overrides before calibrating
//! harmonics = 3                   # harmonics H of the harmonic balance
//! compare = [1, 3]                # harmonics compared with the data
//! form = "complex"                # complex | log-magnitude
//! branch = "nearest"              # nearest | continuation (multi-valued responses)
//! modes = 20                      # retained modes
//! lhs = 64                        # Latin-hypercube candidates
//! starts = 3                      # Levenberg–Marquardt runs from the best candidates
//! folds = 10                      # cross-validation folds (0: none)
//! seed = 1                        # Latin hypercube and fold assignment
//! report = "calibration-report"   # report folder (relative to this file)
//!
//! [[param]]
//! name = "tip.k3"
//! lower = 1e8
//! upper = 1e11
//! spacing = "log"                 # log | linear (default: log over more than a decade)
//!
//! [lm]                            # Levenberg–Marquardt settings
//! max_iterations = 100
//! ```

use crate::error::{Error, Result};
use crate::plot::{BarGroup, Bars, Lines};
use nlsim_calib::{
    BranchChoice, Calibration, CalibrationConfig, Candidate, Form, FrfObjective, LmConfig, Noise,
    ObjectiveConfig, ParamSpec, Progress, Spacing, StartRun, TestData,
};
use nlsim_hb::{HarmonicSet, HbConfig};
use nlsim_kernel::{Model, Param};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::Instant;

/// Everything a calibration needs: model, data, parameters with bounds, what is compared
/// and the search settings. Paths are as given (relative to the working directory).
#[derive(Debug, Clone)]
pub struct CalibrationRequest {
    /// Model file or built-in model.
    pub model: String,
    /// Fixed overrides `NAME=VALUE` applied before calibrating.
    pub set: Vec<String>,
    /// Test data: CSV, HDF5 (`docs/file-formats.md`) or UFF dataset 58.
    pub data: PathBuf,
    /// The calibrated parameters and their bounds.
    pub params: Vec<ParamSpec>,
    /// Harmonics compared with the data (1 = fundamental).
    pub compare: Vec<usize>,
    /// Residual form.
    pub form: Form,
    /// The branch the model is compared on where the response is multi-valued.
    pub branch: BranchChoice,
    /// Harmonics `H` kept by the harmonic balance.
    pub harmonics: usize,
    /// Retained modes of the reduced model.
    pub modes: usize,
    /// Relative noise assumed for linear FRFs read from UFF 58 (which carry none).
    pub uff_noise: f64,
    /// Standard deviation of one component of a unit-normalised measured mode shape, for
    /// modal data ([`crate::modal_calibration`]).
    pub shape_noise: f64,
    /// The search: candidates, starts, folds, seed, Levenberg–Marquardt settings.
    pub config: CalibrationConfig,
    /// Estimates and statistics as CSV.
    pub out: Option<PathBuf>,
    /// Report folder: tables, plots and the summary.
    pub report: Option<PathBuf>,
}

impl CalibrationRequest {
    /// A request with the default settings: compare the fundamental as complex
    /// differences, H = 3, 20 modes, 1 % UFF noise, shape noise 0.02,
    /// [`CalibrationConfig::default`].
    pub fn new(model: impl Into<String>, data: impl Into<PathBuf>, params: Vec<ParamSpec>) -> Self {
        Self {
            model: model.into(),
            set: Vec::new(),
            data: data.into(),
            params,
            compare: vec![1],
            form: Form::Complex,
            branch: BranchChoice::NearestToData,
            harmonics: 3,
            modes: 20,
            uff_noise: 0.01,
            shape_noise: 0.02,
            config: CalibrationConfig::default(),
            out: None,
            report: None,
        }
    }

    /// Checks what can be checked without the model and the data: at least one parameter,
    /// bounds, harmonics, modes, noise and the output names.
    pub fn check(&self) -> Result<()> {
        let bad =
            |field: &str, why: String| Err(Error::Usage(format!("calibration {field}: {why}")));
        if self.params.is_empty() {
            return bad(
                "param",
                "name at least one parameter with its bounds".into(),
            );
        }
        for p in &self.params {
            if let Err(e) = p.check() {
                return bad("param", e.to_string());
            }
        }
        for (i, p) in self.params.iter().enumerate() {
            if self.params[..i].iter().any(|q| q.param == p.param) {
                return bad("param", format!("{} is named twice", p.param));
            }
        }
        if self.harmonics == 0 || self.harmonics > 64 {
            return bad("harmonics", format!("{} is not in 1..=64", self.harmonics));
        }
        if self.compare.is_empty() || self.compare.iter().any(|&k| k == 0 || k > self.harmonics) {
            return bad(
                "compare",
                format!(
                    "{:?}: compare harmonics between 1 and the harmonic balance's {}",
                    self.compare, self.harmonics
                ),
            );
        }
        if self.modes == 0 {
            return bad("modes", "retain at least one mode".into());
        }
        if !(self.uff_noise.is_finite() && self.uff_noise > 0.0) {
            return bad("uff_noise", format!("{} must be positive", self.uff_noise));
        }
        if !(self.shape_noise.is_finite() && self.shape_noise > 0.0) {
            return bad(
                "shape_noise",
                format!("{} must be positive", self.shape_noise),
            );
        }
        if let Some(o) = &self.out
            && o.extension().is_none_or(|e| e != "csv")
        {
            return bad("out", format!("{}: name a .csv file", o.display()));
        }
        Ok(())
    }

    /// Reads a calibration file (the module docs show one).
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::output::read_text(path)?;
        Self::parse(&text, path)
    }

    /// Parses calibration-file text; `path` names it in errors, and relative paths in it
    /// are taken from its folder.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let f: CalibrationTable = SettingsFile::parse(text, path)?;
        let dir = path.parent().unwrap_or(Path::new(""));
        let Some(model) = f.model.clone() else {
            return Err(Error::Spec {
                file: path.to_path_buf(),
                line: 1,
                key: "model".into(),
                message: "name the model (a model file or a built-in model)".into(),
            });
        };
        let model = if dir.join(&model).is_file() {
            dir.join(&model).display().to_string()
        } else {
            model
        };
        f.into_request(model, text, path)
    }
}

/// The key a TOML error is about (the field in backticks of "unknown field `x`" or
/// "missing field `x`"), else `toml`.
pub(crate) fn toml_key(message: &str) -> String {
    message
        .strip_prefix("unknown field `")
        .or_else(|| message.strip_prefix("missing field `"))
        .and_then(|r| r.split('`').next())
        .unwrap_or("toml")
        .to_string()
}

/// A settings file being read (calibration, plan, test): errors name the file, the line of
/// the key and the key; relative paths in it are taken from its folder.
pub(crate) struct SettingsFile<'a> {
    /// The file's text.
    pub(crate) text: &'a str,
    /// The file.
    pub(crate) path: &'a Path,
}

impl<'a> SettingsFile<'a> {
    /// Parses `text` as `T`, a TOML error located at its line and key.
    pub(crate) fn parse<T: serde::de::DeserializeOwned>(
        text: &'a str,
        path: &'a Path,
    ) -> Result<T> {
        toml::from_str(text).map_err(|e| Error::Spec {
            file: path.to_path_buf(),
            line: e
                .span()
                .map_or(1, |s| crate::output::line_of(text, s.start)),
            key: toml_key(e.message()),
            message: e.message().to_string(),
        })
    }

    /// An error about `key` (dotted: the line of its last part).
    pub(crate) fn err(&self, key: &str, message: String) -> Error {
        Error::Spec {
            file: self.path.to_path_buf(),
            line: line_of_key(self.text, key.rsplit('.').next().unwrap_or(key)),
            key: key.to_string(),
            message,
        }
    }

    /// `p` relative to the file's folder (absolute paths as they are).
    pub(crate) fn rel(&self, p: &str) -> PathBuf {
        let p = Path::new(p);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.path.parent().unwrap_or(Path::new("")).join(p)
        }
    }

    /// A request's `check` error `"{prefix} KEY: ..."` located at `KEY`.
    pub(crate) fn located(&self, prefix: &str, e: Error) -> Error {
        let msg = e.to_string();
        let key = msg
            .strip_prefix(prefix)
            .and_then(|m| m.strip_prefix(' '))
            .and_then(|m| m.split(':').next())
            .unwrap_or("")
            .to_string();
        self.err(&key, msg)
    }
}

/// Line of the first `key = ` (or `[key]`) in `text`, for errors found after parsing.
pub(crate) fn line_of_key(text: &str, key: &str) -> usize {
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            l.strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('='))
                || l.starts_with(&format!("[{key}]"))
                || l.starts_with(&format!("[[{key}]]"))
        })
        .map_or(1, |i| i + 1)
}

/// A `[[param]]` entry.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ParamTable {
    name: String,
    lower: f64,
    upper: f64,
    spacing: Option<String>,
}

/// The `[lm]` table.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct LmTable {
    max_iterations: Option<usize>,
    ftol: Option<f64>,
    xtol: Option<f64>,
    gtol: Option<f64>,
    initial_radius_factor: Option<f64>,
}

/// A calibration file, or the `[calibrate]` table of a jobs file (which takes the model
/// from the jobs file).
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct CalibrationTable {
    pub(crate) model: Option<String>,
    data: String,
    #[serde(default)]
    set: BTreeMap<String, f64>,
    #[serde(default)]
    param: Vec<ParamTable>,
    compare: Option<Vec<usize>>,
    form: Option<String>,
    branch: Option<String>,
    harmonics: Option<usize>,
    modes: Option<usize>,
    uff_noise: Option<f64>,
    shape_noise: Option<f64>,
    lhs: Option<usize>,
    starts: Option<usize>,
    folds: Option<usize>,
    seed: Option<u64>,
    maximin_swaps: Option<usize>,
    lm: Option<LmTable>,
    out: Option<String>,
    report: Option<String>,
}

impl CalibrationTable {
    /// The request, with `model` and relative paths taken from `path`'s folder; errors
    /// name `path`, the line and the key.
    pub(crate) fn into_request(
        self,
        model: String,
        text: &str,
        path: &Path,
    ) -> Result<CalibrationRequest> {
        let file = SettingsFile { text, path };
        let err = |key: &str, message: String| file.err(key, message);
        let rel = |p: &str| file.rel(p);
        let mut params = Vec::with_capacity(self.param.len());
        for t in &self.param {
            let param: Param = t
                .name
                .parse()
                .map_err(|e: nlsim_kernel::Error| err("param.name", e.to_string()))?;
            let mut spec = ParamSpec::new(param, t.lower, t.upper);
            match t.spacing.as_deref() {
                None => {}
                Some("log") => spec.spacing = Spacing::Log,
                Some("linear") => spec.spacing = Spacing::Linear,
                Some(s) => {
                    return Err(err("param.spacing", format!("'{s}': use log or linear")));
                }
            }
            params.push(spec);
        }
        let form = match self.form.as_deref() {
            None | Some("complex") => Form::Complex,
            Some("log-magnitude") => Form::LogMagnitudePhase,
            Some(s) => return Err(err("form", format!("'{s}': use complex or log-magnitude"))),
        };
        let d = CalibrationRequest::new("", "", Vec::new());
        let branch = match self.branch.as_deref() {
            None => d.branch,
            Some(s) => parse_branch(s).map_err(|m| err("branch", m))?,
        };
        let dl = LmConfig::default();
        let lm = match &self.lm {
            None => dl,
            Some(t) => LmConfig {
                max_iterations: t.max_iterations.unwrap_or(dl.max_iterations),
                ftol: t.ftol.unwrap_or(dl.ftol),
                xtol: t.xtol.unwrap_or(dl.xtol),
                gtol: t.gtol.unwrap_or(dl.gtol),
                initial_radius_factor: t.initial_radius_factor.unwrap_or(dl.initial_radius_factor),
            },
        };
        lm.validate().map_err(|e| err("lm", e.to_string()))?;
        let dc = CalibrationConfig::default();
        let req = CalibrationRequest {
            model,
            set: self.set.iter().map(|(k, v)| format!("{k}={v:e}")).collect(),
            data: rel(&self.data),
            params,
            compare: self.compare.unwrap_or(d.compare),
            form,
            branch,
            harmonics: self.harmonics.unwrap_or(d.harmonics),
            modes: self.modes.unwrap_or(d.modes),
            uff_noise: self.uff_noise.unwrap_or(d.uff_noise),
            shape_noise: self.shape_noise.unwrap_or(d.shape_noise),
            config: CalibrationConfig {
                lhs_samples: self.lhs.unwrap_or(dc.lhs_samples),
                seed: self.seed.unwrap_or(dc.seed),
                maximin_swaps: self.maximin_swaps.unwrap_or(dc.maximin_swaps),
                starts: self.starts.unwrap_or(dc.starts),
                lm,
                folds: self.folds.unwrap_or(dc.folds),
            },
            out: self.out.as_deref().map(rel),
            report: self.report.as_deref().map(rel),
        };
        req.check().map_err(|e| file.located("calibration", e))?;
        Ok(req)
    }
}

/// Parses `NAME=LOWER:UPPER` (e.g. `tip.k3=1e8:1e11`) into a parameter with bounds.
pub fn parse_param_bounds(text: &str) -> Result<ParamSpec> {
    let bad = || {
        Error::Usage(format!(
            "parameter '{text}': expected NAME=LOWER:UPPER, e.g. tip_spring.k3=1e8:1e11"
        ))
    };
    let (name, range) = text.split_once('=').ok_or_else(bad)?;
    let (lo, hi) = range.split_once(':').ok_or_else(bad)?;
    let lo: f64 = lo.trim().parse().map_err(|_| bad())?;
    let hi: f64 = hi.trim().parse().map_err(|_| bad())?;
    let param: Param = name.trim().parse()?;
    Ok(ParamSpec::new(param, lo, hi))
}

/// Test data by file extension: CSV, HDF5 (`.h5`, `.hdf5`) or linear FRFs in universal
/// file dataset 58 (`.uff`, `.unv`, `.uf`; ASCII or binary), whose drive point is the
/// model's single excitation and whose noise is `uff_noise` of each value.
pub fn read_test_data(path: &Path, model: &Model, uff_noise: f64) -> Result<TestData> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "csv" if crate::modaldata::is_modal_csv(path)? => Err(Error::Usage(format!(
            "{}: this is modal data (mode,frequency_hz,...), not a stepped-sine test: \
             `nlsim calibrate` runs it on its own (crate::modal_calibration); it has no \
             batch kinds and no harmonic balance",
            path.display()
        ))),
        "csv" => crate::testdata::read_csv(path),
        "h5" | "hdf5" => crate::testdata::read_h5(path),
        "uff" | "unv" | "uf" => {
            let records = crate::uff::read(path)?;
            let inputs: Vec<&str> = model.excitation().iter().map(|e| e.name.as_str()).collect();
            let [input] = inputs.as_slice() else {
                return Err(Error::Usage(format!(
                    "{}: FRFs name no drive point in the model's terms, so the model needs \
                     exactly one excitation (it has: {})",
                    path.display(),
                    inputs.join(", ")
                )));
            };
            crate::uff::to_test_data(&records, input, Noise::relative(uff_noise))
        }
        _ => Err(Error::Usage(format!(
            "{}: test data must be .csv, .h5/.hdf5 or universal file dataset 58 \
             (.uff/.unv/.uf)",
            path.display()
        ))),
    }
}

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

/// Loads the model and the data of `req` and builds the objective.
pub fn prepare(req: &CalibrationRequest) -> Result<Prepared> {
    req.check()?;
    let t = Instant::now();
    let model = crate::run::load_for_run(&req.model, &req.set)?;
    let data = Arc::new(read_test_data(&req.data, &model, req.uff_noise)?);
    let cfg = nlsim_reduction::ReductionConfig::lowest(req.modes.min(model.n_dofs()));
    let objective = FrfObjective::from_model(
        &model,
        &cfg,
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
    Ok(Prepared {
        model_name: model.name().to_string(),
        objective,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// The branch choice named `s` (`nearest` or `continuation`, as in a calibration file and
/// `--branch`); the message says what is accepted.
pub fn parse_branch(s: &str) -> std::result::Result<BranchChoice, String> {
    match s {
        "nearest" => Ok(BranchChoice::NearestToData),
        "continuation" => Ok(BranchChoice::Continuation),
        _ => Err(format!("'{s}': use nearest or continuation")),
    }
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
    let prepared = prepare(req)?;
    let t = Instant::now();
    let (calibration, candidates_from) = match candidates {
        None => (
            nlsim_calib::calibrate_with_progress(&prepared.objective, &req.config, progress)?,
            None,
        ),
        Some((path, c)) => {
            let expected = nlsim_calib::candidate_points(&prepared.objective, &req.config)?;
            let same = expected.len() == c.len()
                && expected.iter().zip(&c).all(|(e, c)| {
                    e.len() == c.values.len()
                        && e.iter()
                            .zip(&c.values)
                            .all(|(a, b)| a.to_bits() == b.to_bits())
                });
            if !same {
                return Err(Error::Usage(format!(
                    "{}: its {} candidates are not the {} of this calibration (parameters, \
                     bounds, lhs, seed and the model's values must match the batch's)",
                    path.display(),
                    c.len(),
                    expected.len()
                )));
            }
            (
                nlsim_calib::calibrate_from_candidates(
                    &prepared.objective,
                    c,
                    &req.config,
                    progress,
                )?,
                Some(path),
            )
        }
    };
    Ok(CalibrationRun {
        request: req.clone(),
        prepared,
        calibration,
        seconds: t.elapsed().as_secs_f64(),
        candidates_from,
    })
}

impl CalibrationRun {
    /// The readable summary: what was calibrated on what, how the optimisation went, and
    /// per parameter the estimate, its Cramér–Rao bound, the k-fold jackknife spread and
    /// flags (on a bound, poorly identified).
    pub fn summary(&self) -> Vec<String> {
        let c = &self.calibration;
        let d = self.prepared.objective.data();
        let best = &c.runs[0].report;
        let mut v = vec![
            format!(
                "calibrating {} parameters of '{}' on {} ({} sweeps, {} steps, {} channels); \
                 reduction {:.2} s",
                c.params.len(),
                self.prepared.model_name,
                self.request.data.display(),
                d.sweeps.len(),
                d.n_points(),
                d.channels.len(),
                self.prepared.seconds
            ),
            format!(
                "{} in {} LM iterations ({} evaluations, {} rejected, {} failed) from the best \
                 of {} candidates{}; {:.2} s",
                c.status,
                best.iterations,
                best.evaluations,
                best.rejected,
                best.failed_evaluations,
                c.candidates.len(),
                self.candidates_from
                    .as_ref()
                    .map_or(String::new(), |p| format!(
                        " (evaluated in {})",
                        p.display()
                    )),
                self.seconds
            ),
            format!(
                "cost {:.6e}, reduced chi2 {:.3} (1 when the noise model fits), collinearity \
                 index {:.2}",
                c.cost, c.cramer_rao.reduced_chi2, c.cramer_rao.collinearity
            ),
        ];
        if !c.fit.failed.is_empty() {
            let at: Vec<String> = c
                .fit
                .failed
                .iter()
                .take(5)
                .map(|p| {
                    format!(
                        "sweep {} step {} ({} Hz)",
                        p.sweep + 1,
                        p.step + 1,
                        d.step(*p).frequency_hz
                    )
                })
                .collect();
            v.push(format!(
                "{} points did not converge at the estimate: {}{}",
                c.fit.failed.len(),
                at.join(", "),
                if c.fit.failed.len() > 5 { ", …" } else { "" }
            ));
        }
        v.push(format!(
            "{:<22} {:>14} {:>14} {:>14}  flags",
            "parameter", "estimate", "Cramér–Rao", "k-fold (jk)"
        ));
        for (j, p) in c.params.iter().enumerate() {
            v.push(format!(
                "{:<22} {:>14.6e} {:>14.3e} {:>14.3e}  {}",
                p.to_string(),
                c.estimate[j],
                c.cramer_rao.std[j],
                c.kfold.as_ref().map_or(f64::NAN, |k| k.jackknife_std[j]),
                self.flags(j)
            ));
        }
        v
    }

    /// `at bound`, `poorly identified`, both or nothing for parameter `j`.
    fn flags(&self, j: usize) -> String {
        let c = &self.calibration;
        [
            (c.at_bound[j], "at bound"),
            (c.poorly_identified[j], "poorly identified"),
        ]
        .iter()
        .filter(|f| f.0)
        .map(|f| f.1)
        .collect::<Vec<_>>()
        .join(", ")
    }

    /// Estimates and statistics, one row per parameter.
    pub fn estimates_csv(&self) -> String {
        let c = &self.calibration;
        let mut csv = String::from(
            "param,estimate,cramer_rao_std,kfold_mean,kfold_std,jackknife_std,at_bound,poorly_identified\n",
        );
        for (j, p) in c.params.iter().enumerate() {
            let kf = c.kfold.as_ref();
            let _ = writeln!(
                csv,
                "{p},{:?},{:?},{:?},{:?},{:?},{},{}",
                c.estimate[j],
                c.cramer_rao.std[j],
                kf.map_or(f64::NAN, |k| k.mean[j]),
                kf.map_or(f64::NAN, |k| k.std[j]),
                kf.map_or(f64::NAN, |k| k.jackknife_std[j]),
                c.at_bound[j],
                c.poorly_identified[j]
            );
        }
        csv
    }

    fn param_header(&self) -> String {
        param_header(&self.calibration.params)
    }

    /// Every candidate: index (0 = the model's values), values, cost.
    pub fn candidates_csv(&self) -> String {
        candidates_table(&self.calibration.params, &self.calibration.candidates)
    }

    /// The convergence history of every Levenberg–Marquardt run (best first): accepted
    /// iterates with cost and trust radius (internal units).
    pub fn convergence_csv(&self) -> String {
        convergence_table(&self.request.params, &self.calibration.runs)
    }

    /// The folds: estimate, status, held-out and training rms (empty without folds).
    pub fn kfold_csv(&self) -> String {
        let Some(k) = &self.calibration.kfold else {
            return String::new();
        };
        let mut s = format!(
            "fold,{},status,held_out_rms,training_rms\n",
            self.param_header()
        );
        for f in 0..k.k {
            let _ = writeln!(
                s,
                "{},{},{},{:?},{:?}",
                f + 1,
                values_row(&k.estimates[f]),
                k.status[f],
                k.held_out_rms[f],
                k.training_rms[f]
            );
        }
        s
    }

    /// Measured and calibrated harmonics at every point, channel and harmonic, with the
    /// status of the harmonic balance there.
    pub fn fit_csv(&self) -> String {
        let d = self.prepared.objective.data();
        let mut s = String::from(
            "sweep,label,direction,step,frequency_hz,force1_re,force1_im,channel,harmonic,\
             measured_re,measured_im,model_re,model_im,status\n",
        );
        for p in &self.calibration.fit.points {
            let sw = &d.sweeps[p.id.sweep];
            let st = &sw.steps[p.id.step];
            for (c, ch) in d.channels.iter().enumerate() {
                for k in 0..d.harmonics {
                    let y = st.response[(c, k)];
                    let m = p.response[(c, k)];
                    let _ = writeln!(
                        s,
                        "{},{},{},{},{:?},{:?},{:?},{},{},{:?},{:?},{:?},{:?},{}",
                        p.id.sweep + 1,
                        csv_field(&sw.label),
                        sw.direction.as_str(),
                        p.id.step + 1,
                        st.frequency_hz,
                        st.force[0].re,
                        st.force[0].im,
                        csv_field(&ch.name),
                        k + 1,
                        y.re,
                        y.im,
                        m.re,
                        m.im,
                        p.status
                    );
                }
            }
        }
        s
    }
}

fn param_header(params: &[Param]) -> String {
    params
        .iter()
        .map(|p| p.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

fn values_row(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:?}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// The candidates table: index (0 = the model's values), values of `params`, cost.
pub(crate) fn candidates_table(params: &[Param], candidates: &[Candidate]) -> String {
    let mut s = format!("candidate,{},cost\n", param_header(params));
    for (i, c) in candidates.iter().enumerate() {
        let _ = writeln!(s, "{i},{},{:?}", values_row(&c.values), c.cost);
    }
    s
}

/// The convergence table of `runs` (best first): accepted iterates with cost, trust radius
/// (internal units) and the parameter values.
pub(crate) fn convergence_table(specs: &[ParamSpec], runs: &[StartRun]) -> String {
    let params: Vec<Param> = specs.iter().map(|s| s.param.clone()).collect();
    let mut s = format!("run,iteration,cost,radius,{}\n", param_header(&params));
    for (r, run) in runs.iter().enumerate() {
        for st in &run.report.history {
            let v: Vec<f64> = specs
                .iter()
                .zip(&st.u)
                .map(|(p, &u)| p.to_value(u))
                .collect();
            let _ = writeln!(
                s,
                "{r},{},{:?},{:?},{}",
                st.iteration,
                st.cost,
                st.radius,
                values_row(&v)
            );
        }
    }
    s
}

/// The cost along each optimisation of `runs` as a plot `convergence` (SVG and PNG) in
/// `dir`; nothing when no run has a positive cost. Returns the files written.
pub(crate) fn convergence_plot(
    report: &crate::report::Report,
    model_name: &str,
    runs: &[StartRun],
) -> Result<Vec<PathBuf>> {
    let history: Vec<(String, Vec<(f64, f64)>)> = runs
        .iter()
        .enumerate()
        .map(|(r, run)| {
            (
                format!("start {} ({})", r + 1, run.report.status),
                run.report
                    .history
                    .iter()
                    .filter(|s| s.cost > 0.0)
                    .map(|s| (s.iteration as f64, s.cost.log10()))
                    .collect(),
            )
        })
        .filter(|(_, p): &(String, Vec<(f64, f64)>)| !p.is_empty())
        .collect();
    if history.is_empty() {
        return Ok(Vec::new());
    }
    let files = report.figure(
        "convergence",
        &Lines {
            title: format!("{model_name}: Levenberg–Marquardt convergence"),
            x_desc: "iteration".into(),
            y_desc: "log10 cost ½‖r‖² (1)".into(),
            series: history,
        },
    )?;
    Ok(files.to_vec())
}

/// A CSV field, quoted when it holds a comma or a quote.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Most FRF plots a report draws (channels × compared harmonics); the fit table holds all.
pub const MAX_FRF_PLOTS: usize = 24;

/// Writes the report of `run` into `dir` (created if needed): `summary.txt`,
/// `estimates.csv`, `candidates.csv`, `convergence.csv`, `kfold.csv`, `fit.csv`, and plots
/// (SVG and PNG) — per channel and compared harmonic the measured and calibrated response per unit
/// fundamental force along each sweep (`frf_CHANNEL_hK`, at most [`MAX_FRF_PLOTS`]),
/// the fold estimates normalised by the estimate with the Cramér–Rao band (`kfold`,
/// thesis Fig. 14) and the cost along each optimisation (`convergence`). Returns the
/// files written.
pub fn write_report(dir: &Path, run: &CalibrationRun) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let report = crate::report::Report::create(
        dir,
        &format!("nlsim calibrate: {}", run.prepared.model_name),
        &crate::report::command_line(),
        &run.request.model,
    )?;
    report.seed("Latin hypercube and k-fold split", run.request.config.seed)?;
    report.section_with("Summary", &run.summary());
    report.table(
        "estimates",
        crate::report::Table::from_csv("Estimates and uncertainties", &run.estimates_csv()),
    )?;
    if run.calibration.kfold.is_some() {
        report.table(
            "kfold",
            crate::report::Table::from_csv("k-fold cross validation", &run.kfold_csv()),
        )?;
    }
    report.section("Test vs calibrated model");
    let mut written = Vec::new();
    let mut text = |name: &str, body: String| -> Result<()> {
        if !body.is_empty() {
            let p = dir.join(name);
            crate::output::write_text_atomically(&p, &body)?;
            written.push(p);
        }
        Ok(())
    };
    let mut summary = run.summary().join("\n");
    summary.push('\n');
    text("summary.txt", summary)?;
    text("estimates.csv", run.estimates_csv())?;
    text("candidates.csv", run.candidates_csv())?;
    text("convergence.csv", run.convergence_csv())?;
    text("kfold.csv", run.kfold_csv())?;
    text("fit.csv", run.fit_csv())?;
    let c = &run.calibration;
    let d = run.prepared.objective.data();
    let mut plots = 0;
    'channels: for (ci, ch) in d.channels.iter().enumerate() {
        for &k in &run.request.compare {
            if k > d.harmonics {
                continue;
            }
            if plots == MAX_FRF_PLOTS {
                break 'channels;
            }
            let mut series = Vec::new();
            for (s, sw) in d.sweeps.iter().enumerate() {
                let pts = |model: bool| -> Vec<(f64, f64)> {
                    c.fit
                        .points
                        .iter()
                        .filter(|p| p.id.sweep == s)
                        .filter_map(|p| {
                            let st = &sw.steps[p.id.step];
                            let y = if model {
                                p.response[(ci, k - 1)]
                            } else {
                                st.response[(ci, k - 1)]
                            };
                            let v = y.norm() / st.force[0].norm();
                            v.is_finite().then_some((st.frequency_hz, v))
                        })
                        .collect()
                };
                series.push((format!("test, {}", sw.label), pts(false)));
                series.push((format!("model, {}", sw.label), pts(true)));
            }
            series.retain(|(_, p)| !p.is_empty());
            if series.is_empty() {
                continue;
            }
            let fig = Lines {
                title: format!(
                    "{}: test vs calibrated model, {} harmonic {k}",
                    run.prepared.model_name, ch.name
                ),
                x_desc: "frequency (Hz)".into(),
                y_desc: format!(
                    "|{} h{k}| / |F1| ({}/N)",
                    ch.quantity.as_str(),
                    crate::output::unit(ch.quantity)
                ),
                series,
            };
            let safe: String = ch
                .name
                .chars()
                .map(|c| {
                    if c.is_ascii_alphanumeric() || "-_".contains(c) {
                        c
                    } else {
                        '_'
                    }
                })
                .collect();
            written.extend(report.figure(&format!("frf_{safe}_h{k}"), &fig)?);
            plots += 1;
        }
    }
    report.section("Optimisation and cross validation");
    written.extend(convergence_plot(
        &report,
        &run.prepared.model_name,
        &c.runs,
    )?);
    if let Some(k) = &c.kfold {
        let groups = c
            .params
            .iter()
            .enumerate()
            .map(|(j, p)| {
                let e = c.estimate[j];
                let rel = c.cramer_rao.std[j] / e.abs();
                BarGroup {
                    label: p.to_string(),
                    values: k.estimates.iter().map(|v| v[j] / e).collect(),
                    band: rel.is_finite().then_some((1.0 - rel, 1.0 + rel)),
                }
            })
            .collect();
        written.extend(report.figure(
            "kfold",
            &Bars {
                title: format!(
                    "{}: {}-fold estimates / full-data estimate",
                    run.prepared.model_name, k.k
                ),
                bar_desc: "fold".into(),
                y_desc: "fold estimate / estimate (1)".into(),
                baseline: 1.0,
                band_desc: "Cramér–Rao ±1σ".into(),
                groups,
            },
        )?);
    }
    written.push(report.finish()?);
    written.push(dir.join(crate::report::DATA));
    Ok(written)
}
