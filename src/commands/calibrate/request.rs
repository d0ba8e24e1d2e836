//! The request of `nlsim calibrate`, from the command line or a calibration file (TOML,
//! `docs/calibration.md`), checked before the run.
use crate::error::{Error, Result};
use crate::formats::settings::SettingsFile;
use crate::formats::test_data::DataOptions;
use nlsim_calib::{
    BranchChoice, CalibrationConfig, FeReduction, Form, LmConfig, ParamSpec, ParametricConfig,
    Spacing,
};
use nlsim_kernel::Param;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

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
    /// What the data file does not say: the noise of data without a noise model (UFF 58,
    /// amplitude-and-phase tables) and the phase convention.
    pub data_options: DataOptions,
    /// The sweeps calibrated on (labels, `*` patterns or 1-based indices; empty: all). The
    /// others are held out: written into the result for `nlsim validate` to predict.
    pub train: Vec<String>,
    /// Standard deviation of one component of a unit-normalised measured mode shape, for
    /// modal data ([`crate::commands::calibrate::modal`]).
    pub shape_noise: f64,
    /// The search: candidates, starts, folds, seed, Levenberg–Marquardt settings.
    pub config: CalibrationConfig,
    /// How FE-level parameters (group scales, boundary springs) reduce the model: the
    /// parametric reduced model with its certificate tolerance, or a full reduction per
    /// evaluation.
    pub fe: FeReduction,
    /// Estimates and statistics as CSV.
    pub out: Option<PathBuf>,
    /// Report folder: tables, plots and the summary.
    pub report: Option<PathBuf>,
    /// The calibration (or jobs) file this request was read from, if any: an input no output
    /// may name.
    pub source: Option<PathBuf>,
    /// The `[result]` table of a calibration's result file (`calibration.toml`), which
    /// `nlsim validate` reads; a calibration run ignores it.
    pub result: Option<StoredResult>,
    /// The shaker a voltage-driven test's record drives the model through (`[shaker]`);
    /// `None`: the recorded drive times the input gain is the force.
    pub shaker: Option<nlsim_calib::Shaker>,
    /// `data` holds raw time records (a force and the sensors' responses from rest),
    /// calibrated in the time domain ([`crate::commands::calibrate::time`]); the noise of each
    /// channel is `data_options.noise` times its rms.
    pub time_domain: bool,
}

/// Whether a `NAME=VALUE` override names a gain of the test data (`input_gain`,
/// `sensor_gain:NAME`).
fn is_gain_set(kv: &str) -> bool {
    kv.split_once('=')
        .and_then(|(k, _)| k.trim().parse::<Param>().ok())
        .is_some_and(|p| p.is_gain())
}

impl CalibrationRequest {
    /// The `set` overrides of the model: every one but the gains of the test data.
    pub fn model_sets(&self) -> Vec<String> {
        self.set
            .iter()
            .filter(|s| !is_gain_set(s))
            .cloned()
            .collect()
    }

    /// The gains of the test data that `set` fixes (`input_gain=2.5`, `sensor_gain:tip=1.02`).
    pub fn gain_sets(&self) -> Result<Vec<(Param, f64)>> {
        self.set
            .iter()
            .filter(|s| is_gain_set(s))
            .map(|kv| {
                let (k, v) = kv.split_once('=').unwrap_or((kv, ""));
                let value: f64 = v.trim().parse().map_err(|_| {
                    Error::Usage(format!("--set '{kv}': '{}' is not a number", v.trim()))
                })?;
                Ok((k.trim().parse::<Param>()?, value))
            })
            .collect()
    }

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
            data_options: DataOptions::default(),
            train: Vec::new(),
            shape_noise: 0.02,
            config: CalibrationConfig::default(),
            fe: FeReduction::default(),
            out: None,
            report: None,
            source: None,
            result: None,
            shaker: None,
            time_domain: false,
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
        // Counted twice, a harmonic's residuals would weigh double and every Cramér–Rao std
        // would shrink by √2.
        if let Some(k) = self
            .compare
            .iter()
            .enumerate()
            .find_map(|(i, k)| self.compare[..i].contains(k).then_some(*k))
        {
            return bad(
                "compare",
                format!(
                    "{:?}: harmonic {k} is named twice; name each compared harmonic once",
                    self.compare
                ),
            );
        }
        if self.time_domain {
            // Options a time-domain calibration has no use for are refused, not ignored.
            let ignored = [
                (
                    !self.train.is_empty(),
                    "train",
                    "a raw record has no sweeps to select",
                ),
                (
                    self.config.fold_by == nlsim_calib::FoldBy::Sweeps,
                    "fold_by",
                    "\"sweeps\": a raw record's folds are contiguous blocks of samples",
                ),
                (
                    self.shaker.is_some(),
                    "shaker",
                    "the recorded drive is the force (times input_gain) in the time domain",
                ),
            ];
            if let Some((_, key, why)) = ignored.iter().find(|(on, _, _)| *on) {
                return bad(key, format!("not with --time-domain: {why}"));
            }
        }
        if self.modes == 0 {
            return bad("modes", "retain at least one mode".into());
        }
        if let Err((key, why)) = self.data_options.check() {
            return bad(key, why);
        }
        if let Some(t) = self.train.iter().find(|t| t.trim().is_empty()) {
            return bad(
                "train",
                format!("{t:?}: name a sweep label, a pattern or an index"),
            );
        }
        if !(self.shape_noise.is_finite() && self.shape_noise > 0.0) {
            return bad(
                "shape_noise",
                format!("{} must be positive", self.shape_noise),
            );
        }
        if let FeReduction::Parametric(p) = &self.fe
            && let Err(e) = p.check()
        {
            return bad("fe_tolerance", e.to_string());
        }
        let c = &self.config;
        for (key, value, max) in [
            ("lhs", c.lhs_samples, nlsim_calib::MAX_LHS_SAMPLES),
            (
                "maximin_swaps",
                c.maximin_swaps,
                nlsim_calib::MAX_MAXIMIN_SWAPS,
            ),
            ("folds", c.folds, nlsim_calib::MAX_FOLDS),
            ("starts", c.starts, nlsim_calib::MAX_STARTS),
        ] {
            if value > max {
                return bad(key, format!("{value} is beyond any budget (at most {max})"));
            }
        }
        if c.starts == 0 {
            return bad("starts", "give at least 1".into());
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
        let text = crate::formats::files::read_text(path)?;
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
    #[serde(alias = "uff_noise")]
    data_noise: Option<f64>,
    phase_offset_deg: Option<f64>,
    train: Option<Vec<String>>,
    shape_noise: Option<f64>,
    time_domain: Option<bool>,
    fe_reduction: Option<String>,
    fe_tolerance: Option<f64>,
    lhs: Option<usize>,
    starts: Option<usize>,
    folds: Option<usize>,
    fold_by: Option<String>,
    seed: Option<u64>,
    maximin_swaps: Option<usize>,
    lm: Option<LmTable>,
    out: Option<String>,
    report: Option<String>,
    result: Option<StoredResult>,
    shaker: Option<crate::formats::settings::ShakerTable>,
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
        let fold_by = match self.fold_by.as_deref() {
            None => nlsim_calib::FoldBy::default(),
            Some(s) => parse_fold_by(s).map_err(|m| err("fold_by", m))?,
        };
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
        let fe = parse_fe_reduction(self.fe_reduction.as_deref(), self.fe_tolerance)
            .map_err(|(key, m)| err(key, m))?;
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
            data_options: DataOptions {
                noise: self.data_noise.unwrap_or(d.data_options.noise),
                phase_offset_deg: self
                    .phase_offset_deg
                    .unwrap_or(d.data_options.phase_offset_deg),
            },
            train: self.train.unwrap_or_default(),
            shape_noise: self.shape_noise.unwrap_or(d.shape_noise),
            time_domain: self.time_domain.unwrap_or(false),
            config: CalibrationConfig {
                lhs_samples: self.lhs.unwrap_or(dc.lhs_samples),
                seed: self.seed.unwrap_or(dc.seed),
                maximin_swaps: self.maximin_swaps.unwrap_or(dc.maximin_swaps),
                starts: self.starts.unwrap_or(dc.starts),
                lm,
                folds: self.folds.unwrap_or(dc.folds),
                fold_by,
            },
            fe,
            out: self.out.as_deref().map(rel),
            report: self.report.as_deref().map(rel),
            source: Some(path.to_path_buf()),
            result: self.result,
            shaker: self
                .shaker
                .as_ref()
                .map(|t| crate::formats::settings::ShakerTable::shaker(Some(t))),
        };
        if let Some(r) = &req.result {
            r.check(&req.params).map_err(|(key, m)| err(key, m))?;
        }
        req.check().map_err(|e| file.located("calibration", e))?;
        Ok(req)
    }
}

/// Parses how the cross validation deals its folds: `points` or `sweeps`.
pub fn parse_fold_by(s: &str) -> std::result::Result<nlsim_calib::FoldBy, String> {
    match s {
        "points" => Ok(nlsim_calib::FoldBy::Points),
        "sweeps" => Ok(nlsim_calib::FoldBy::Sweeps),
        _ => Err(format!(
            "'{s}': use points (a seeded shuffle of the steps) or sweeps (each sweep held out)"
        )),
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

/// The branch choice named `s` (`nearest` or `continuation`, as in a calibration file and
/// `--branch`); the message says what is accepted.
pub fn parse_branch(s: &str) -> std::result::Result<BranchChoice, String> {
    match s {
        "nearest" => Ok(BranchChoice::NearestToData),
        "continuation" => Ok(BranchChoice::Continuation),
        _ => Err(format!("'{s}': use nearest or continuation")),
    }
}

/// The FE-level reduction named by `kind` (`parametric`, the default, or `full`, as in a
/// calibration file's `fe_reduction` and `--fe-reduction`) with the parametric model's
/// certificate `tolerance` (`fe_tolerance`, `--fe-tolerance`; default 1e-6). The error names
/// the key and says what is accepted.
pub fn parse_fe_reduction(
    kind: Option<&str>,
    tolerance: Option<f64>,
) -> std::result::Result<FeReduction, (&'static str, String)> {
    let settings = ParametricConfig {
        tolerance: tolerance.unwrap_or(ParametricConfig::default().tolerance),
        ..ParametricConfig::default()
    };
    settings
        .check()
        .map_err(|e| ("fe_tolerance", e.to_string()))?;
    match kind {
        None | Some("parametric") => Ok(FeReduction::Parametric(settings)),
        Some("full") if tolerance.is_some() => Err((
            "fe_tolerance",
            "a tolerance belongs to the parametric reduction, not to fe_reduction = full".into(),
        )),
        Some("full") => Ok(FeReduction::Full),
        Some(s) => Err(("fe_reduction", format!("'{s}': use parametric or full"))),
    }
}

/// The `[result]` table: what a calibration found.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StoredResult {
    /// How the best optimisation ended (`converged`, …).
    pub status: String,
    /// The estimates, in the order of the `[[param]]` entries (parameter units).
    pub estimate: Vec<f64>,
    /// The Cramér–Rao covariance bound (parameter units squared), rows in parameter order.
    pub covariance: Vec<Vec<f64>>,
    /// `2·cost/(m − n)` of the training fit.
    pub reduced_chi2: f64,
    /// Training points (steps).
    pub points: usize,
    /// Training residuals `m`.
    pub residuals: usize,
    /// The cross validation's mean square held-out weighted residual
    /// ([`nlsim_calib::KFold::held_out_mean_square`]), when folds ran: `nlsim validate
    /// --scale folds` scales the band by it.
    #[serde(default)]
    pub held_out_mean_square: Option<f64>,
}

impl StoredResult {
    /// Checks the result against the calibration's `params`: the sizes, every estimate
    /// within its parameter's bounds, a symmetric positive semi-definite covariance, and a
    /// held-out mean square that scales a band to finite numbers; the message names the key.
    pub fn check(&self, params: &[ParamSpec]) -> std::result::Result<(), (&'static str, String)> {
        let n = params.len();
        if self.estimate.len() != n {
            return Err((
                "result.estimate",
                format!("{} values for {n} parameters", self.estimate.len()),
            ));
        }
        if self.estimate.iter().any(|v| !v.is_finite()) {
            return Err(("result.estimate", "a value is not finite".into()));
        }
        if self.covariance.len() != n || self.covariance.iter().any(|r| r.len() != n) {
            return Err((
                "result.covariance",
                format!("must be {n} rows of {n} values (the parameters' order)"),
            ));
        }
        for (i, r) in self.covariance.iter().enumerate() {
            for (j, v) in r.iter().enumerate() {
                if v.is_nan() || (*v - self.covariance[j][i]).abs() > 1e-9 * v.abs().max(1e-300) {
                    return Err((
                        "result.covariance",
                        format!("entry ({}, {}) is NaN or not symmetric", i + 1, j + 1),
                    ));
                }
            }
            if r[i] < 0.0 {
                return Err((
                    "result.covariance",
                    format!("diagonal entry {} is negative", i + 1),
                ));
            }
        }
        // A calibration bounds its estimates: one outside the bounds was not computed by it.
        for (p, &v) in params.iter().zip(&self.estimate) {
            if !(p.lower..=p.upper).contains(&v) {
                return Err((
                    "result.estimate",
                    format!(
                        "{} = {} is outside its bounds [{}, {}]; a calibration's estimate lies \
                         within them",
                        p.param,
                        crate::formats::files::number(v),
                        crate::formats::files::number(p.lower),
                        crate::formats::files::number(p.upper)
                    ),
                ));
            }
        }
        // A covariance is positive semi-definite: the least eigenvalue of the correlation
        // matrix (scale-free) is not below rounding.
        if n > 0 {
            let d: Vec<f64> = (0..n).map(|i| self.covariance[i][i].sqrt()).collect();
            let corr = faer::Mat::from_fn(n, n, |i, j| {
                if d[i] > 0.0 && d[j] > 0.0 {
                    self.covariance[i][j] / (d[i] * d[j])
                } else if i == j {
                    1.0
                } else if self.covariance[i][j] == 0.0 {
                    0.0
                } else {
                    f64::NAN
                }
            });
            let least = corr
                .self_adjoint_eigenvalues(faer::Side::Lower)
                .ok()
                .and_then(|e| e.into_iter().reduce(f64::min));
            if least.is_none_or(|l| l.is_nan() || l < -1e-9 * n as f64) {
                return Err((
                    "result.covariance",
                    format!(
                        "not positive semi-definite (least eigenvalue of the correlation {}); \
                         a covariance bound never is",
                        least.map_or("not computable".into(), |l| format!("{l:.3e}"))
                    ),
                ));
            }
        }
        if !(self.reduced_chi2.is_finite() && self.reduced_chi2 >= 0.0) {
            return Err((
                "result.reduced_chi2",
                format!("{} is not a non-negative number", self.reduced_chi2),
            ));
        }
        // Weighted residuals are in noise deviations: beyond 1e30 (10¹⁵ σ) no fold predicted
        // anything, and a band scaled by it would span every number.
        if let Some(v) = self.held_out_mean_square
            && (v.is_nan() || v < 0.0 || (v.is_finite() && v > 1e30))
        {
            return Err((
                "result.held_out_mean_square",
                format!(
                    "{}: a mean square is a non-negative number up to 1e30 (inf where a fold \
                     failed)",
                    crate::formats::files::number(v)
                ),
            ));
        }
        Ok(())
    }

    /// The covariance as a matrix.
    pub fn covariance_matrix(&self) -> faer::Mat<f64> {
        let n = self.covariance.len();
        faer::Mat::from_fn(n, n, |i, j| self.covariance[i][j])
    }
}
