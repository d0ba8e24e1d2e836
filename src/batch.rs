//! `nlsim batch`: many runs of one command described in a jobs file (TOML), split into shards
//! for cluster job arrays, each shard written atomically to its own HDF5 file, and merged.
//!
//! The jobs file (`docs/batch.md`):
//!
//! ```toml
//! name = "duffing-k3"           # names the output directory and the SLURM job
//! command = "frf"               # frf | simulate | calibrate-candidates | calibrate-folds
//! model = "duffing_fig3"        # model file or built-in model
//! seed = 7                      # seed of the Latin hypercube (recorded in every file)
//! set = { "spring.c" = 0.5 }    # fixed element-parameter overrides
//!
//! [frf]                         # the options of `nlsim frf` (or [simulate] for simulate)
//! from = 80.0
//! to = 140.0
//!
//! [[sweep]]                     # sweeps are crossed with each other and with [lhs]
//! set = "spring.k3"             # an element parameter ...
//! values = [1e3, 2e3]
//! [[sweep]]
//! option = "force"              # ... or an option: force (frf), excitation (simulate), model
//! values = [0.5, 1.0]
//!
//! [lhs]                         # Latin-hypercube candidates of several parameters
//! samples = 8
//! params = [{ set = "spring.k3", min = 1e3, max = 1e4, log = true }]
//! ```
//!
//! A calibration spreads over a cluster in two batches of the same `[calibrate]` table (the
//! keys of a calibration file, [`crate::calibration`], without `model`):
//! `calibrate-candidates` evaluates candidate `i` (0: the model's values, then the Latin
//! hypercube) in job `i`, and `nlsim calibrate --candidates merged.h5` goes on from them;
//! `calibrate-folds` runs fold `f` of the cross validation in job `f`, from the top-level
//! `estimate = { "tip.k3" = 1.2e9 }`, and the merge adds the fold statistics.
//!
//! Job `i` belongs to shard `i mod T` of `T`. A shard computes its jobs in parallel (rayon),
//! each job single-threaded inside, so results do not depend on the thread count or on the
//! number of shards; it writes each finished job to a temporary file and renames the file into
//! place only when every job is in it. A shard file that exists is therefore complete; a
//! resubmitted shard whose file exists for the same jobs file is skipped.

use crate::calibration::{CalibrationRequest, Prepared};
use crate::error::{Error, Result};
use crate::output::{h5err, provenance, str_attr};
use crate::run::{FrfRequest, Method, SimRequest, SweepMode, run_frf, run_simulation};
use hdf5_metno as hdf5;
use nlsim_kernel::Parameterized;
use nlsim_kernel::param::parse_known;
use rayon::prelude::*;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// The `[frf]` table: the options of `nlsim frf`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct FrfTable {
    from: f64,
    to: f64,
    harmonics: Option<usize>,
    subharmonic: Option<usize>,
    force: Option<f64>,
    mode: Option<String>,
    points: Option<usize>,
    modes: Option<usize>,
    residual: Option<bool>,
    stability: Option<bool>,
}

/// The `[simulate]` table: the options of `nlsim simulate`.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SimTable {
    duration: f64,
    rate: f64,
    method: Option<String>,
    excitation: Option<Vec<String>>,
    modes: Option<usize>,
    residual: Option<bool>,
    events: Option<bool>,
    rtol: Option<f64>,
    atol: Option<f64>,
    substeps: Option<usize>,
    hht_alpha: Option<f64>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SweepTable {
    set: Option<String>,
    option: Option<String>,
    values: Vec<toml::Value>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LhsParam {
    set: String,
    min: f64,
    max: f64,
    #[serde(default)]
    log: bool,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LhsTable {
    samples: usize,
    params: Vec<LhsParam>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct JobsFile {
    name: String,
    command: String,
    model: String,
    output: Option<String>,
    seed: Option<u64>,
    #[serde(default)]
    set: BTreeMap<String, f64>,
    frf: Option<FrfTable>,
    simulate: Option<SimTable>,
    #[serde(default)]
    sweep: Vec<SweepTable>,
    lhs: Option<LhsTable>,
    calibrate: Option<crate::calibration::CalibrationTable>,
    estimate: Option<BTreeMap<String, f64>>,
}

/// The command every job of a batch runs, with its base options.
#[derive(Debug, Clone)]
pub enum BatchCommand {
    /// `nlsim frf`.
    Frf(FrfRequest),
    /// `nlsim simulate`.
    Simulate(SimRequest),
    /// The candidates of a calibration: job `i` evaluates the cost at candidate `i`.
    CalibrateCandidates(Box<CalibrationRequest>),
    /// The cross validation of a calibration: job `f` runs fold `f` from the estimate
    /// (parameter values in the request's order).
    CalibrateFolds(Box<CalibrationRequest>, Vec<f64>),
}

impl BatchCommand {
    /// `frf` or `simulate`.
    pub fn name(&self) -> &'static str {
        match self {
            BatchCommand::Frf(_) => "frf",
            BatchCommand::Simulate(_) => "simulate",
            BatchCommand::CalibrateCandidates(_) => "calibrate-candidates",
            BatchCommand::CalibrateFolds(..) => "calibrate-folds",
        }
    }
}

/// One change a job makes to the base run.
#[derive(Debug, Clone, PartialEq)]
pub enum Assignment {
    /// An element parameter, `element.param = value`.
    Set(String, f64),
    /// The force amplitude of an FRF (N).
    Force(f64),
    /// The excitation spec of a time response.
    Excitation(String),
    /// The model.
    Model(String),
    /// Candidate `i` of a calibration (0: the model's values, then the Latin hypercube).
    Candidate(usize),
    /// Fold `f` of a calibration's cross validation (0-based).
    Fold(usize),
}

impl std::fmt::Display for Assignment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Assignment::Set(n, v) => write!(f, "{n}={v:e}"),
            Assignment::Force(v) => write!(f, "force={v:e}"),
            Assignment::Excitation(s) => write!(f, "excitation={s}"),
            Assignment::Model(s) => write!(f, "model={s}"),
            Assignment::Candidate(i) => write!(f, "candidate={i}"),
            Assignment::Fold(i) => write!(f, "fold={}", i + 1),
        }
    }
}

/// One run of a batch.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    /// Position in the batch (0-based).
    pub index: usize,
    /// What it changes, in sweep order.
    pub assignments: Vec<Assignment>,
}

/// A parsed jobs file.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The jobs file.
    pub file: PathBuf,
    /// The batch name.
    pub name: String,
    /// The command and its base options.
    pub command: BatchCommand,
    /// The base model spec.
    pub model: String,
    /// Fixed overrides `element.param=value`.
    pub sets: Vec<String>,
    /// The output directory (shards and the merged file).
    pub output: PathBuf,
    /// The seed of the Latin hypercube (0 when not given).
    pub seed: u64,
    /// Every job, in order.
    pub jobs: Vec<Job>,
    /// FNV-1a hash of the jobs file's text: shards written for another text are not reused.
    pub hash: u64,
}

/// FNV-1a, 64 bit: a hash that is the same on every machine and Rust version.
fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

/// 1-based line of byte `offset` in `text`.
fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

impl Batch {
    /// Reads and checks a jobs file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::parse(&text, path)
    }

    /// Parses jobs-file text; `path` names it in errors and anchors the output directory.
    pub fn parse(text: &str, path: &Path) -> Result<Self> {
        let err = |line: usize, key: &str, message: String| Error::Spec {
            file: path.to_path_buf(),
            line,
            key: key.to_string(),
            message,
        };
        let f: JobsFile = toml::from_str(text).map_err(|e| {
            let line = e.span().map_or(1, |s| line_of(text, s.start));
            err(line, "", e.message().to_string())
        })?;
        // Line of the first occurrence of `key` (for errors found after parsing).
        let at = |key: &str| {
            text.lines()
                .position(|l| {
                    l.trim_start().strip_prefix(key).is_some_and(|rest| {
                        key.starts_with('[') || rest.trim_start().starts_with('=')
                    })
                })
                .map_or(1, |i| i + 1)
        };
        if f.name.is_empty()
            || !f
                .name
                .chars()
                .all(|c| c.is_ascii_alphanumeric() || "-_.".contains(c))
        {
            return Err(err(
                at("name"),
                "name",
                format!(
                    "'{}' must be non-empty letters, digits, '-', '_' or '.'",
                    f.name
                ),
            ));
        }
        // The axes of the job grid: each sweep, then the Latin hypercube (or the candidates
        // or folds of a calibration).
        let mut axes: Vec<Vec<Vec<Assignment>>> = Vec::new();
        let command = match f.command.as_str() {
            "frf" => {
                if f.simulate.is_some() {
                    return Err(err(
                        at("[simulate]"),
                        "simulate",
                        "a [simulate] table in a batch of command 'frf'".into(),
                    ));
                }
                let t = f.frf.as_ref().ok_or_else(|| {
                    err(
                        at("command"),
                        "frf",
                        "command 'frf' needs an [frf] table with at least `from` and `to`".into(),
                    )
                })?;
                let d = FrfRequest::default();
                let mode = match &t.mode {
                    None => d.mode,
                    Some(m) => SweepMode::parse(m).ok_or_else(|| {
                        err(
                            at("mode"),
                            "frf.mode",
                            format!("'{m}': use continuation, step-up or step-down"),
                        )
                    })?,
                };
                let req = FrfRequest {
                    from_hz: t.from,
                    to_hz: t.to,
                    harmonics: t.harmonics.unwrap_or(d.harmonics),
                    subharmonic: t.subharmonic.unwrap_or(d.subharmonic),
                    force: t.force,
                    mode,
                    points: t.points.unwrap_or(d.points),
                    modes: t.modes.unwrap_or(d.modes),
                    residual: t.residual.unwrap_or(d.residual),
                    stability: t.stability.unwrap_or(d.stability),
                    // Jobs run in parallel, each sequential inside: results independent of
                    // the thread and shard count.
                    par: faer::Par::Seq,
                };
                req.check()
                    .map_err(|e| err(at("[frf]"), "frf", e.to_string()))?;
                BatchCommand::Frf(req)
            }
            "simulate" => {
                if f.frf.is_some() {
                    return Err(err(
                        at("[frf]"),
                        "frf",
                        "an [frf] table in a batch of command 'simulate'".into(),
                    ));
                }
                let t = f.simulate.as_ref().ok_or_else(|| {
                    err(
                        at("command"),
                        "simulate",
                        "command 'simulate' needs a [simulate] table with at least `duration` \
                         and `rate`"
                            .into(),
                    )
                })?;
                let d = SimRequest::default();
                let method = match &t.method {
                    None => d.method,
                    Some(m) => Method::parse(m).ok_or_else(|| {
                        err(
                            at("method"),
                            "simulate.method",
                            format!("'{m}': use foh, zoh, lsoh, rk45, rk4, newmark or hht"),
                        )
                    })?,
                };
                let req = SimRequest {
                    duration: t.duration,
                    rate: t.rate,
                    method,
                    excitation: t.excitation.clone().unwrap_or_default(),
                    modes: t.modes.unwrap_or(d.modes),
                    residual: t.residual.unwrap_or(d.residual),
                    events: t.events.unwrap_or(d.events),
                    rtol: t.rtol.unwrap_or(d.rtol),
                    atol: t.atol.unwrap_or(d.atol),
                    substeps: t.substeps.unwrap_or(d.substeps),
                    hht_alpha: t.hht_alpha.unwrap_or(d.hht_alpha),
                    par: faer::Par::Seq,
                };
                req.check()
                    .map_err(|e| err(at("[simulate]"), "simulate", e.to_string()))?;
                BatchCommand::Simulate(req)
            }
            c @ ("calibrate-candidates" | "calibrate-folds") => {
                for (present, key) in [
                    (f.frf.is_some(), "[frf]"),
                    (f.simulate.is_some(), "[simulate]"),
                    (!f.sweep.is_empty(), "[[sweep]]"),
                    (f.lhs.is_some(), "[lhs]"),
                    (!f.set.is_empty(), "set"),
                    (f.seed.is_some(), "seed"),
                ] {
                    if present {
                        return Err(err(
                            at(key),
                            key.trim_matches(['[', ']']),
                            format!(
                                "a batch of '{c}' takes its settings from [calibrate] (`set` and \
                                 `seed` there); its jobs are the candidates or folds"
                            ),
                        ));
                    }
                }
                let Some(t) = f.calibrate else {
                    return Err(err(
                        at("command"),
                        "calibrate",
                        format!(
                            "command '{c}' needs a [calibrate] table (the keys of a \
                             calibration file without `model`)"
                        ),
                    ));
                };
                if t.model.is_some() {
                    return Err(err(
                        at("model"),
                        "calibrate.model",
                        "the model of a batch is its top-level `model`".into(),
                    ));
                }
                let req = t.into_request(f.model.clone(), text, path)?;
                if c == "calibrate-candidates" {
                    if f.estimate.is_some() {
                        return Err(err(
                            at("estimate"),
                            "estimate",
                            "`estimate` is where the folds of 'calibrate-folds' start; \
                             candidates come from the Latin hypercube"
                                .into(),
                        ));
                    }
                    BatchCommand::CalibrateCandidates(Box::new(req))
                } else {
                    let Some(est) = &f.estimate else {
                        return Err(err(
                            at("command"),
                            "estimate",
                            "'calibrate-folds' needs `estimate = { NAME = VALUE, ... }`: the \
                             calibrated values the folds start from"
                                .into(),
                        ));
                    };
                    let mut values = Vec::with_capacity(req.params.len());
                    for p in &req.params {
                        let name = p.param.to_string();
                        let v = est.get(&name).copied().ok_or_else(|| {
                            err(
                                at("estimate"),
                                "estimate",
                                format!("no value for calibrated parameter {name}"),
                            )
                        })?;
                        if !(v.is_finite() && p.lower <= v && v <= p.upper) {
                            return Err(err(
                                at("estimate"),
                                "estimate",
                                format!(
                                    "{name} = {v} is outside its bounds [{}, {}]",
                                    p.lower, p.upper
                                ),
                            ));
                        }
                        values.push(v);
                    }
                    if let Some(extra) = est
                        .keys()
                        .find(|k| !req.params.iter().any(|p| p.param.to_string() == **k))
                    {
                        return Err(err(
                            at("estimate"),
                            "estimate",
                            format!("{extra} is not a calibrated parameter of [calibrate]"),
                        ));
                    }
                    if req.config.folds < 2 {
                        return Err(err(
                            at("folds"),
                            "calibrate.folds",
                            format!(
                                "'calibrate-folds' needs folds >= 2, not {}",
                                req.config.folds
                            ),
                        ));
                    }
                    BatchCommand::CalibrateFolds(Box::new(req), values)
                }
            }
            other => {
                return Err(err(
                    at("command"),
                    "command",
                    format!(
                        "unknown command '{other}'; a batch runs frf, simulate, \
                         calibrate-candidates or calibrate-folds"
                    ),
                ));
            }
        };
        match &command {
            BatchCommand::CalibrateCandidates(req) => {
                axes.push(
                    (0..=req.config.lhs_samples)
                        .map(|i| vec![Assignment::Candidate(i)])
                        .collect(),
                );
            }
            BatchCommand::CalibrateFolds(req, _) => {
                axes.push(
                    (0..req.config.folds)
                        .map(|i| vec![Assignment::Fold(i)])
                        .collect(),
                );
            }
            _ => {}
        }
        for (i, s) in f.sweep.iter().enumerate() {
            let key = format!("sweep[{i}]");
            let line = text
                .match_indices("[[sweep]]")
                .nth(i)
                .map_or(1, |(o, _)| line_of(text, o));
            if s.values.is_empty() {
                return Err(err(line, &key, "`values` is empty".into()));
            }
            let num = |v: &toml::Value| -> Result<f64> {
                v.as_float()
                    .or_else(|| v.as_integer().map(|i| i as f64))
                    .filter(|x| x.is_finite())
                    .ok_or_else(|| err(line, &key, format!("{v} is not a finite number")))
            };
            let txt = |v: &toml::Value| -> Result<String> {
                v.as_str()
                    .map(str::to_string)
                    .ok_or_else(|| err(line, &key, format!("{v} is not a string")))
            };
            let each = |f: &dyn Fn(&toml::Value) -> Result<Assignment>| {
                s.values
                    .iter()
                    .map(|v| Ok(vec![f(v)?]))
                    .collect::<Result<Vec<_>>>()
            };
            let axis = match (&s.set, s.option.as_deref()) {
                (Some(name), None) => each(&|v| Ok(Assignment::Set(name.clone(), num(v)?)))?,
                (None, Some("force")) if f.command == "frf" => {
                    each(&|v| Ok(Assignment::Force(num(v)?)))?
                }
                (None, Some("excitation")) if f.command == "simulate" => {
                    each(&|v| Ok(Assignment::Excitation(txt(v)?)))?
                }
                (None, Some("model")) => each(&|v| Ok(Assignment::Model(txt(v)?)))?,
                (None, Some(o)) => {
                    return Err(err(
                        line,
                        &key,
                        format!(
                            "option '{o}' cannot be swept in a batch of '{}'; sweep {} or model",
                            f.command,
                            if f.command == "frf" {
                                "force"
                            } else {
                                "excitation"
                            }
                        ),
                    ));
                }
                _ => {
                    return Err(err(
                        line,
                        &key,
                        "give exactly one of `set` (an element parameter) or `option`".into(),
                    ));
                }
            };
            axes.push(axis);
        }
        let seed = match &command {
            BatchCommand::CalibrateCandidates(r) | BatchCommand::CalibrateFolds(r, _) => {
                r.config.seed
            }
            _ => f.seed.unwrap_or(0),
        };
        if let Some(l) = &f.lhs {
            let line = at("[lhs]");
            if l.samples == 0 || l.params.is_empty() {
                return Err(err(
                    line,
                    "lhs",
                    "needs samples >= 1 and at least one entry in params".into(),
                ));
            }
            for p in &l.params {
                let ok = p.min.is_finite()
                    && p.max.is_finite()
                    && p.min < p.max
                    && (!p.log || p.min > 0.0);
                if !ok {
                    return Err(err(
                        line,
                        "lhs.params",
                        format!(
                            "'{}': need finite min < max (and min > 0 with log = true), got [{}, {}]",
                            p.set, p.min, p.max
                        ),
                    ));
                }
            }
            let unit = latin_hypercube(l.samples, l.params.len(), seed);
            axes.push(
                unit.iter()
                    .map(|row| {
                        row.iter()
                            .zip(&l.params)
                            .map(|(&u, p)| {
                                let v = if p.log {
                                    (p.min.ln() + u * (p.max.ln() - p.min.ln())).exp()
                                } else {
                                    p.min + u * (p.max - p.min)
                                };
                                Assignment::Set(p.set.clone(), v)
                            })
                            .collect()
                    })
                    .collect(),
            );
        }
        let n_jobs: usize = axes.iter().map(Vec::len).product();
        if n_jobs > 10_000_000 {
            return Err(err(
                1,
                "sweep",
                format!("{n_jobs} jobs: more than 10^7; split the batch"),
            ));
        }
        // Cartesian product, the first axis slowest.
        let jobs = (0..n_jobs)
            .map(|index| {
                let mut rest = index;
                let mut picks = vec![0; axes.len()];
                for (a, axis) in axes.iter().enumerate().rev() {
                    picks[a] = rest % axis.len();
                    rest /= axis.len();
                }
                Job {
                    index,
                    assignments: axes
                        .iter()
                        .zip(&picks)
                        .flat_map(|(axis, &p)| axis[p].iter().cloned())
                        .collect(),
                }
            })
            .collect();
        let base = path.parent().unwrap_or(Path::new("."));
        let output = base.join(f.output.unwrap_or_else(|| format!("{}-results", f.name)));
        Ok(Batch {
            file: path.to_path_buf(),
            name: f.name,
            command,
            model: f.model,
            sets: f.set.iter().map(|(k, v)| format!("{k}={v:e}")).collect(),
            output,
            seed,
            jobs,
            hash: fnv1a(text.as_bytes()),
        })
    }

    /// Loads every model the jobs use and applies every override once, so a misspelt
    /// parameter or model fails before any shard runs.
    pub fn check_models(&self) -> Result<()> {
        let mut models: Vec<String> = vec![self.model.clone()];
        for j in &self.jobs {
            for a in &j.assignments {
                if let Assignment::Model(m) = a
                    && !models.contains(m)
                {
                    models.push(m.clone());
                }
            }
        }
        let mut names: Vec<&str> = Vec::new();
        for j in &self.jobs {
            for a in &j.assignments {
                if let Assignment::Set(n, _) = a
                    && !names.contains(&n.as_str())
                {
                    names.push(n);
                }
            }
        }
        // Errors point at the first line of the jobs file that names the culprit.
        let text = std::fs::read_to_string(&self.file).unwrap_or_default();
        let err = |needle: &str, key: &str, e: Error| Error::Spec {
            file: self.file.clone(),
            line: text
                .lines()
                .position(|l| l.contains(needle))
                .map_or(1, |i| i + 1),
            key: key.to_string(),
            message: e.to_string(),
        };
        for m in &models {
            let model = crate::run::load_for_run(m, &self.sets).map_err(|e| err(m, "model", e))?;
            for n in &names {
                parse_known(n, &model.parameters())
                    .and_then(|p| model.param(&p))
                    .map_err(|e| err(n, "set", Error::Model(e)))?;
            }
        }
        Ok(())
    }

    /// The jobs of shard `task` of `count` (`i mod count == task`).
    pub fn shard_jobs(&self, task: usize, count: usize) -> impl Iterator<Item = &Job> {
        self.jobs.iter().filter(move |j| j.index % count == task)
    }

    /// The file of shard `task` of `count`.
    pub fn shard_path(&self, task: usize, count: usize) -> PathBuf {
        self.output
            .join(format!("shard-{task:05}-of-{count:05}.h5"))
    }

    /// The merged file.
    pub fn merged_path(&self) -> PathBuf {
        self.output.join("merged.h5")
    }
}

pub use nlsim_calib::latin_hypercube;

/// What happened to a shard.
#[derive(Debug, Clone, PartialEq)]
pub enum ShardOutcome {
    /// Its file was already complete for this jobs file: nothing was run.
    Skipped(PathBuf),
    /// It ran; `failed` lists the jobs that failed, with their errors (recorded in the file).
    Written {
        /// The shard file.
        path: PathBuf,
        /// Jobs run.
        jobs: usize,
        /// `(job index, error)` of the jobs that failed.
        failed: Vec<(usize, String)>,
        /// Wall time (s).
        seconds: f64,
    },
}

/// Progress of a shard, for the caller to show.
#[derive(Debug, Clone)]
pub enum ShardEvent {
    /// A stale shard file (another jobs file) or temporary files of a killed run were found.
    Note(String),
    /// A job finished (`done` of `total`).
    JobDone {
        /// Its index in the batch.
        index: usize,
        /// Jobs of this shard finished so far.
        done: usize,
        /// Jobs in this shard.
        total: usize,
        /// Its error, if it failed.
        error: Option<String>,
    },
}

/// Reads a `u64` root attribute, if present.
fn u64_attr(file: &hdf5::File, name: &str) -> Option<u64> {
    file.attr(name).ok()?.read_scalar::<u64>().ok()
}

/// Whether `path` is a complete shard or merged file written for a jobs file of hash `hash`.
fn complete_for(path: &Path, hash: u64) -> Result<bool> {
    if !path.is_file() {
        return Ok(false);
    }
    let file = hdf5::File::open(path).map_err(h5err(path))?;
    Ok(u64_attr(&file, "jobs_hash") == Some(hash) && u64_attr(&file, "complete") == Some(1))
}

/// Removes `NAME.tmp-*` files beside `path`: what killed runs left.
fn remove_stale_temporaries(path: &Path) -> Vec<PathBuf> {
    let (Some(dir), Some(name)) = (path.parent(), path.file_name().and_then(|n| n.to_str())) else {
        return Vec::new();
    };
    let prefix = format!("{name}.tmp-");
    let mut removed = Vec::new();
    if let Ok(rd) = std::fs::read_dir(dir) {
        for e in rd.flatten() {
            if e.file_name()
                .to_str()
                .is_some_and(|n| n.starts_with(&prefix))
                && std::fs::remove_file(e.path()).is_ok()
            {
                removed.push(e.path());
            }
        }
    }
    removed
}

/// Writes a scalar `u64` attribute.
fn u64_attr_write(loc: &hdf5::Location, name: &str, v: u64) -> hdf5::Result<()> {
    loc.new_attr::<u64>().create(name)?.write_scalar(&v)
}

fn write_root_attrs(root: &hdf5::Group, b: &Batch) -> hdf5::Result<()> {
    provenance(root, b.command.name(), &b.model, &b.model, Some(b.seed))?;
    str_attr(root, "batch", &b.name)?;
    u64_attr_write(root, "jobs_hash", b.hash)?;
    u64_attr_write(root, "n_jobs", b.jobs.len() as u64)
}

/// The result of one job, ready to be written.
enum JobResult {
    Frf(Box<crate::run::FrfRun>),
    Simulate(Box<crate::run::SimRun>),
    /// A calibration candidate: its values and cost.
    Candidate(Vec<f64>, f64),
    /// A fold of a calibration's cross validation.
    Fold(nlsim_calib::FoldResult),
}

/// What the jobs of a calibration shard share: the objective (model loaded and reduced once)
/// and the candidate points.
struct CalibContext {
    prepared: Prepared,
    candidates: Vec<Vec<f64>>,
}

/// The shared part of a calibration batch's jobs (`None` for other batches).
fn calib_context(b: &Batch) -> Result<Option<CalibContext>> {
    let req = match &b.command {
        BatchCommand::CalibrateCandidates(r) | BatchCommand::CalibrateFolds(r, _) => r,
        _ => return Ok(None),
    };
    let prepared = crate::calibration::prepare(req)?;
    let candidates = match &b.command {
        BatchCommand::CalibrateCandidates(_) => {
            nlsim_calib::candidate_points(&prepared.objective, &req.config)?
        }
        _ => Vec::new(),
    };
    Ok(Some(CalibContext {
        prepared,
        candidates,
    }))
}

fn run_job(b: &Batch, job: &Job, ctx: Option<&CalibContext>) -> Result<JobResult> {
    let mut spec = b.model.clone();
    let mut sets = b.sets.clone();
    let mut force = None;
    let mut excitation = None;
    for a in &job.assignments {
        match a {
            Assignment::Set(n, v) => sets.push(format!("{n}={v:e}")),
            Assignment::Force(v) => force = Some(*v),
            Assignment::Excitation(s) => excitation = Some(s.clone()),
            Assignment::Model(m) => spec = m.clone(),
            &Assignment::Candidate(i) => {
                let ctx = ctx.ok_or_else(|| Error::Failed("no calibration context".into()))?;
                let values = ctx.candidates.get(i).cloned().ok_or_else(|| {
                    Error::Failed(format!(
                        "candidate {i} is beyond the {} candidates",
                        ctx.candidates.len()
                    ))
                })?;
                let cost = ctx.prepared.objective.clone().cost_values(&values)?;
                return Ok(JobResult::Candidate(values, cost));
            }
            &Assignment::Fold(f) => {
                let (Some(ctx), BatchCommand::CalibrateFolds(req, estimate)) = (ctx, &b.command)
                else {
                    return Err(Error::Failed("no calibration context".into()));
                };
                let r = nlsim_calib::fold(&ctx.prepared.objective, estimate, &req.config, f)?;
                return Ok(JobResult::Fold(r));
            }
        }
    }
    let model = crate::run::load_for_run(&spec, &sets)?;
    match &b.command {
        BatchCommand::Frf(req) => {
            let mut req = req.clone();
            if force.is_some() {
                req.force = force;
            }
            Ok(JobResult::Frf(Box::new(run_frf(
                &model,
                &req,
                &mut |_| {},
            )?)))
        }
        BatchCommand::Simulate(req) => {
            let mut req = req.clone();
            if let Some(e) = excitation {
                req.excitation = vec![e];
            }
            Ok(JobResult::Simulate(Box::new(run_simulation(
                &model,
                &req,
                &mut |_, _| {},
            )?)))
        }
        BatchCommand::CalibrateCandidates(_) | BatchCommand::CalibrateFolds(..) => Err(
            Error::Failed(format!("job {} names no candidate or fold", job.index)),
        ),
    }
}

/// The parameter values of a calibration job, as dataset `values`.
fn write_values(g: &hdf5::Group, values: &[f64]) -> hdf5::Result<()> {
    g.new_dataset::<f64>()
        .shape(values.len())
        .create("values")?
        .write_raw(values)
}

fn job_group_name(index: usize) -> String {
    format!("job-{index:08}")
}

fn write_job(
    jobs: &hdf5::Group,
    b: &Batch,
    job: &Job,
    result: &Result<JobResult>,
) -> hdf5::Result<()> {
    let g = jobs.create_group(&job_group_name(job.index))?;
    u64_attr_write(&g, "index", job.index as u64)?;
    let desc: Vec<String> = job.assignments.iter().map(|a| a.to_string()).collect();
    str_attr(&g, "assignments", &desc.join("; "))?;
    for a in &job.assignments {
        if let Assignment::Set(n, v) = a {
            g.new_attr::<f64>()
                .create(format!("set:{n}").as_str())?
                .write_scalar(v)?;
        }
    }
    match result {
        Err(e) => {
            g.new_attr::<u8>().create("ok")?.write_scalar(&0u8)?;
            str_attr(&g, "error", &e.to_string())
        }
        Ok(r) => {
            g.new_attr::<u8>().create("ok")?.write_scalar(&1u8)?;
            match r {
                JobResult::Frf(run) => {
                    crate::frf::write_group(&g, &run.system, &run.branch, &run.responses)
                }
                JobResult::Candidate(values, cost) => {
                    write_values(&g, values)?;
                    g.new_attr::<f64>().create("cost")?.write_scalar(cost)
                }
                JobResult::Fold(r) => {
                    write_values(&g, &r.values)?;
                    str_attr(&g, "status", r.status.as_str())?;
                    for (name, v) in [
                        ("held_out_rms", r.held_out_rms),
                        ("training_rms", r.training_rms),
                    ] {
                        g.new_attr::<f64>().create(name)?.write_scalar(&v)?;
                    }
                    Ok(())
                }
                JobResult::Simulate(run) => {
                    let info = crate::simulate::RunInfo {
                        model_spec: b.model.clone(),
                        method: match &b.command {
                            BatchCommand::Simulate(r) => r.method.as_str().into(),
                            _ => String::new(),
                        },
                        excitation: run.excitation.clone(),
                        modes: run.modes,
                    };
                    crate::simulate::write_group(&g, &run.history, &info)
                }
            }
        }
    }
}

/// Runs shard `task` of `count`: skips it when its file is complete for this jobs file,
/// otherwise computes its jobs (in parallel, `rayon::current_num_threads()` at a time, each
/// single-threaded inside so that the numbers do not depend on the thread count), appends each
/// to a temporary file as it finishes and renames the file into place at the end. A job that
/// fails is recorded with its error and the others go on.
pub fn run_shard(
    b: &Batch,
    task: usize,
    count: usize,
    event: &mut dyn FnMut(ShardEvent),
) -> Result<ShardOutcome> {
    if count == 0 || task >= count {
        return Err(Error::Usage(format!(
            "task index {task} is not below the task count {count}"
        )));
    }
    let path = b.shard_path(task, count);
    if complete_for(&path, b.hash)? {
        return Ok(ShardOutcome::Skipped(path));
    }
    if path.exists() {
        event(ShardEvent::Note(format!(
            "{} was written for another version of {}; recomputing it",
            path.display(),
            b.file.display()
        )));
    }
    std::fs::create_dir_all(&b.output).map_err(|source| Error::Io {
        path: b.output.clone(),
        source,
    })?;
    for p in remove_stale_temporaries(&path) {
        event(ShardEvent::Note(format!(
            "removed {} (left by a run that was killed)",
            p.display()
        )));
    }
    let start = Instant::now();
    let ctx = calib_context(b)?;
    let mine: Vec<&Job> = b.shard_jobs(task, count).collect();
    let total = mine.len();
    let mut failed = Vec::new();
    crate::output::write_atomically(&path, ".h5", |tmp, _| {
        let err = h5err(tmp);
        let file = hdf5::File::create(tmp).map_err(&err)?;
        let root = file.as_group().map_err(&err)?;
        write_root_attrs(&root, b).map_err(&err)?;
        for (name, v) in [("task_index", task), ("task_count", count)] {
            u64_attr_write(&root, name, v as u64).map_err(&err)?;
        }
        let jobs = file.create_group("jobs").map_err(&err)?;
        let width = rayon::current_num_threads().max(1);
        let mut done = 0;
        let mut outcome = Ok(());
        for chunk in mine.chunks(width) {
            let results: Vec<Result<JobResult>> = chunk
                .par_iter()
                .map(|j| run_job(b, j, ctx.as_ref()))
                .collect();
            for (job, r) in chunk.iter().zip(&results) {
                if let Err(e) = write_job(&jobs, b, job, r).map_err(&err) {
                    outcome = Err(e);
                    break;
                }
                done += 1;
                let error = r.as_ref().err().map(|e| e.to_string());
                if let Some(e) = &error {
                    failed.push((job.index, e.clone()));
                }
                event(ShardEvent::JobDone {
                    index: job.index,
                    done,
                    total,
                    error,
                });
            }
            if outcome.is_err() {
                break;
            }
            file.flush().map_err(&err)?;
        }
        outcome?;
        u64_attr_write(&root, "complete", 1).map_err(&err)?;
        file.flush().map_err(&err)?;
        Ok(())
    })?;
    Ok(ShardOutcome::Written {
        path,
        jobs: total,
        failed,
        seconds: start.elapsed().as_secs_f64(),
    })
}

/// The result of a merge.
#[derive(Debug, Clone)]
pub struct MergeOutcome {
    /// The merged file.
    pub path: PathBuf,
    /// Shards joined.
    pub shards: usize,
    /// Jobs in it.
    pub jobs: usize,
    /// Jobs that had failed.
    pub failed: usize,
    /// What a calibration batch found (best candidates, or the fold statistics), one line
    /// each; empty for other batches.
    pub summary: Vec<String>,
}

/// Joins the complete shard files of `b` (all `count` of one split) into `merged.h5`, jobs in
/// index order with a `parameters` table (job × swept parameter). Fails naming the missing
/// shards when a split is incomplete.
pub fn merge(b: &Batch) -> Result<MergeOutcome> {
    let entries: Vec<std::fs::DirEntry> = match std::fs::read_dir(&b.output) {
        Ok(rd) => rd.flatten().collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(source) => {
            return Err(Error::Io {
                path: b.output.clone(),
                source,
            });
        }
    };
    // Shard files by task count.
    let mut splits: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for e in entries {
        let name = e.file_name();
        let Some(n) = name.to_str() else { continue };
        let Some(rest) = n.strip_prefix("shard-").and_then(|r| r.strip_suffix(".h5")) else {
            continue;
        };
        let Some((t, c)) = rest.split_once("-of-") else {
            continue;
        };
        if let (Ok(t), Ok(c)) = (t.parse::<usize>(), c.parse::<usize>())
            && complete_for(&e.path(), b.hash)?
        {
            splits.entry(c).or_default().push(t);
        }
    }
    let Some((&count, _)) = splits.iter().find(|(c, ts)| ts.len() == **c) else {
        let msg = match splits.iter().max_by_key(|(_, ts)| ts.len()) {
            None => format!(
                "no complete shard of {} in {}: run `nlsim batch {}` first",
                b.file.display(),
                b.output.display(),
                b.file.display()
            ),
            Some((c, ts)) => {
                let missing: Vec<String> = (0..*c)
                    .filter(|t| !ts.contains(t))
                    .map(|t| t.to_string())
                    .collect();
                format!(
                    "shards {} of {c} are missing or incomplete in {}: run them with \
                     `nlsim batch {} --task-count {c} --task-index N` (complete shards are skipped)",
                    missing.join(", "),
                    b.output.display(),
                    b.file.display()
                )
            }
        };
        return Err(Error::Usage(msg));
    };
    let path = b.merged_path();
    let calib_req = match &b.command {
        BatchCommand::CalibrateCandidates(r) | BatchCommand::CalibrateFolds(r, _) => Some(r),
        _ => None,
    };
    // Swept parameter names, in order of first appearance (a calibration's parameters).
    let mut names: Vec<String> = calib_req
        .map(|r| r.params.iter().map(|p| p.param.to_string()).collect())
        .unwrap_or_default();
    // Per job of a calibration: its values and its cost or fold result.
    let mut calib_rows: Vec<Option<CalibRow>> = Vec::new();
    for j in &b.jobs {
        for a in &j.assignments {
            if let Assignment::Set(n, _) = a
                && !names.contains(n)
            {
                names.push(n.clone());
            }
        }
    }
    let mut failed = 0;
    let mut summary = Vec::new();
    crate::output::write_atomically(&path, ".h5", |tmp, _| {
        let err = h5err(tmp);
        let out = hdf5::File::create(tmp).map_err(&err)?;
        let root = out.as_group().map_err(&err)?;
        write_root_attrs(&root, b).map_err(&err)?;
        let jobs = out.create_group("jobs").map_err(&err)?;
        let shards: Vec<hdf5::File> = (0..count)
            .map(|t| {
                let p = b.shard_path(t, count);
                hdf5::File::open(&p).map_err(h5err(&p))
            })
            .collect::<Result<_>>()?;
        for j in &b.jobs {
            let name = job_group_name(j.index);
            let p = b.shard_path(j.index % count, count);
            let src = shards[j.index % count]
                .group(&format!("jobs/{name}"))
                .map_err(|e| Error::Hdf5 {
                    path: p.clone(),
                    message: format!("job {} is missing: {e}", j.index),
                })?;
            if src.attr("ok").and_then(|a| a.read_scalar::<u8>()).ok() != Some(1) {
                failed += 1;
            }
            let dst = jobs.create_group(&name).map_err(&err)?;
            copy_group(&src, &dst).map_err(h5err(&p))?;
            if calib_req.is_some() {
                calib_rows.push(read_calib_job(&src));
            }
        }
        // The parameter table: NaN where a job does not set the parameter.
        let mut table = vec![f64::NAN; b.jobs.len() * names.len()];
        for (j, row) in calib_rows.iter().enumerate() {
            if let Some((v, _, _)) = row
                && v.len() == names.len()
            {
                table[j * names.len()..(j + 1) * names.len()].copy_from_slice(v);
            }
        }
        if calib_req.is_some() {
            summary = write_calib_summary(&out, b, &names, &calib_rows).map_err(&err)?;
        }
        for j in &b.jobs {
            for a in &j.assignments {
                if let Assignment::Set(n, v) = a {
                    let c = names.iter().position(|x| x == n).expect("collected above");
                    table[j.index * names.len() + c] = *v;
                }
            }
        }
        let d = out
            .new_dataset::<f64>()
            .shape((b.jobs.len(), names.len()))
            .create("parameters")
            .map_err(&err)?;
        d.write_raw(&table).map_err(&err)?;
        str_attr(&d, "columns", &names.join(",")).map_err(&err)?;
        str_attr(&d, "dims", "job x parameter (NaN: not set by the job)").map_err(&err)?;
        str_attr(&d, "unit", "SI, per parameter").map_err(&err)?;
        u64_attr_write(&root, "complete", 1).map_err(&err)?;
        out.flush().map_err(&err)?;
        Ok(())
    })?;
    Ok(MergeOutcome {
        path,
        shards: count,
        jobs: b.jobs.len(),
        failed,
        summary,
    })
}

/// A calibration job read back: values, `[cost, NaN]` (a candidate) or `[held-out rms,
/// training rms]` and the status (a fold).
type CalibRow = (Vec<f64>, [f64; 2], String);

/// The values and `[cost, NaN]` (a candidate) or `[held-out rms, training rms]` and status
/// (a fold) of a calibration job group; `None` for a job that failed.
fn read_calib_job(g: &hdf5::Group) -> Option<CalibRow> {
    if g.attr("ok").and_then(|a| a.read_scalar::<u8>()).ok() != Some(1) {
        return None;
    }
    let values = g.dataset("values").ok()?.read_raw::<f64>().ok()?;
    let f = |n: &str| g.attr(n).and_then(|a| a.read_scalar::<f64>()).ok();
    if let Some(c) = f("cost") {
        return Some((values, [c, f64::NAN], String::new()));
    }
    let status: hdf5::types::VarLenUnicode = g.attr("status").ok()?.read_scalar().ok()?;
    Some((
        values,
        [f("held_out_rms")?, f("training_rms")?],
        status.as_str().to_string(),
    ))
}

/// Root datasets of a merged calibration batch: `cost` per candidate, or per fold
/// `held_out_rms`, `training_rms` and the fold statistics `kfold_mean`, `kfold_std`,
/// `jackknife_std`, `kfold_covariance` (when every fold ran). Returns summary lines.
fn write_calib_summary(
    out: &hdf5::File,
    b: &Batch,
    names: &[String],
    rows: &[Option<CalibRow>],
) -> hdf5::Result<Vec<String>> {
    let col = |i: usize| -> Vec<f64> {
        rows.iter()
            .map(|r| r.as_ref().map_or(f64::NAN, |r| r.1[i]))
            .collect()
    };
    let put = |name: &str, v: &[f64], dims: &str| -> hdf5::Result<()> {
        let d = out.new_dataset::<f64>().shape(v.len()).create(name)?;
        d.write_raw(v)?;
        str_attr(&d, "dims", dims)
    };
    let mut lines = Vec::new();
    match &b.command {
        BatchCommand::CalibrateCandidates(req) => {
            let cost = col(0);
            put(
                "cost",
                &cost,
                "job (= candidate; NaN: failed); cost ½‖r‖², infinite where a point failed",
            )?;
            let mut order: Vec<usize> = (0..cost.len()).filter(|&i| cost[i].is_finite()).collect();
            order.sort_by(|&a, &c| cost[a].total_cmp(&cost[c]).then(a.cmp(&c)));
            for &i in order.iter().take(req.config.starts) {
                let v = rows[i].as_ref().map(|r| &r.0[..]).unwrap_or(&[]);
                let vals: Vec<String> = names
                    .iter()
                    .zip(v)
                    .map(|(n, x)| format!("{n} = {x:.6e}"))
                    .collect();
                lines.push(format!(
                    "candidate {i}: cost {:.6e} at {}",
                    cost[i],
                    vals.join(", ")
                ));
            }
            lines.push(format!(
                "{} of {} candidates with a finite cost; go on with `nlsim calibrate --config \
                 FILE --candidates {}`",
                order.len(),
                cost.len(),
                b.merged_path().display()
            ));
        }
        BatchCommand::CalibrateFolds(req, estimate) => {
            put("held_out_rms", &col(0), "job (= fold)")?;
            put("training_rms", &col(1), "job (= fold)")?;
            let folds: Option<Vec<nlsim_calib::FoldResult>> = rows
                .iter()
                .map(|r| {
                    let (values, [h, t], status) = r.as_ref()?;
                    Some(nlsim_calib::FoldResult {
                        values: values.clone(),
                        status: status.parse().ok()?,
                        held_out_rms: *h,
                        training_rms: *t,
                    })
                })
                .collect();
            let n_points = req_points(req);
            match (folds, n_points) {
                (Some(folds), Some(n_points)) => {
                    let fold_of =
                        nlsim_calib::fold_assignment(n_points, req.config.folds, req.config.seed);
                    if let Ok(k) = nlsim_calib::KFold::from_folds(fold_of, folds) {
                        put("kfold_mean", &k.mean, "parameter")?;
                        put("kfold_std", &k.std, "parameter")?;
                        put("jackknife_std", &k.jackknife_std, "parameter")?;
                        let n = k.mean.len();
                        let cov: Vec<f64> =
                            (0..n * n).map(|i| k.covariance[(i / n, i % n)]).collect();
                        let d = out
                            .new_dataset::<f64>()
                            .shape((n, n))
                            .create("kfold_covariance")?;
                        d.write_raw(&cov)?;
                        for (j, name) in names.iter().enumerate() {
                            lines.push(format!(
                                "{name}: estimate {:.6e}, {}-fold mean {:.6e}, jackknife std \
                                 {:.3e} ({:.3} % of the estimate)",
                                estimate[j],
                                k.k,
                                k.mean[j],
                                k.jackknife_std[j],
                                100.0 * k.jackknife_std[j] / estimate[j].abs()
                            ));
                        }
                        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
                        lines.push(format!(
                            "mean rms weighted residual: training {:.3}, held out {:.3}",
                            mean(&k.training_rms),
                            mean(&k.held_out_rms)
                        ));
                    }
                }
                _ => lines.push(
                    "fold statistics left out: a fold failed or the test data cannot be read"
                        .into(),
                ),
            }
        }
        _ => {}
    }
    Ok(lines)
}

/// Data points of a calibration request's test data (`None` if it cannot be read now).
fn req_points(req: &CalibrationRequest) -> Option<usize> {
    let model = crate::run::load_for_run(&req.model, &req.set).ok()?;
    crate::calibration::read_test_data(&req.data, &model, req.uff_noise)
        .ok()
        .map(|d| d.n_points())
}

/// Most values a merged candidates file may declare (parameters × candidates): 2²⁶.
const CANDIDATE_BUDGET: usize = 1 << 26;

/// The evaluated candidates of a merged `calibrate-candidates` batch (for
/// `nlsim calibrate --candidates`): values from `parameters`, costs from `cost`. Fails on
/// another kind of file, an incomplete merge or a failed candidate.
pub fn read_candidates(path: &Path) -> Result<Vec<nlsim_calib::Candidate>> {
    let err = h5err(path);
    let bad = |m: String| Error::Usage(format!("{}: {m}", path.display()));
    let file = hdf5::File::open(path).map_err(&err)?;
    let command: Option<hdf5::types::VarLenUnicode> =
        file.attr("command").and_then(|a| a.read_scalar()).ok();
    if command.as_ref().map(|c| c.as_str()) != Some("calibrate-candidates") {
        return Err(bad(format!(
            "not a merged 'calibrate-candidates' batch (command: {})",
            command.as_ref().map_or("none", |c| c.as_str())
        )));
    }
    if u64_attr(&file, "complete") != Some(1) {
        return Err(bad("the merge did not complete".into()));
    }
    let table = file.dataset("parameters").map_err(&err)?;
    let cost = file.dataset("cost").map_err(&err)?;
    let shape = table.shape();
    let (Some(&rows), Some(&cols)) = (shape.first(), shape.get(1)) else {
        return Err(bad(format!(
            "`parameters` has shape {shape:?}, not jobs × parameters"
        )));
    };
    if rows.saturating_mul(cols) > CANDIDATE_BUDGET || cost.shape() != [rows] {
        return Err(bad(format!(
            "`parameters` {rows}×{cols} and `cost` {:?} do not agree or exceed 2^26 values",
            cost.shape()
        )));
    }
    let values = table.read_raw::<f64>().map_err(&err)?;
    let costs = cost.read_raw::<f64>().map_err(&err)?;
    let mut out = Vec::with_capacity(rows);
    for (i, c) in costs.iter().enumerate() {
        let v = values[i * cols..(i + 1) * cols].to_vec();
        if c.is_nan() || v.iter().any(|x| x.is_nan()) {
            return Err(bad(format!(
                "candidate {i} failed (see jobs/{}/error); rerun its shard",
                job_group_name(i)
            )));
        }
        out.push(nlsim_calib::Candidate {
            values: v,
            cost: *c,
        });
    }
    Ok(out)
}

/// Copies the attributes of `src` onto `dst` (the types nlsim writes).
fn copy_attrs(src: &hdf5::Location, dst: &hdf5::Location) -> hdf5::Result<()> {
    use hdf5::types::{FloatSize, IntSize, TypeDescriptor as T, VarLenUnicode};
    for name in src.attr_names()? {
        let a = src.attr(&name)?;
        if !a.is_scalar() {
            continue;
        }
        match a.dtype()?.to_descriptor()? {
            T::Float(FloatSize::U8) => dst
                .new_attr::<f64>()
                .create(name.as_str())?
                .write_scalar(&a.read_scalar::<f64>()?)?,
            T::Unsigned(IntSize::U8) => dst
                .new_attr::<u64>()
                .create(name.as_str())?
                .write_scalar(&a.read_scalar::<u64>()?)?,
            T::Unsigned(IntSize::U1) => dst
                .new_attr::<u8>()
                .create(name.as_str())?
                .write_scalar(&a.read_scalar::<u8>()?)?,
            T::VarLenUnicode => {
                let s: VarLenUnicode = a.read_scalar()?;
                dst.new_attr::<VarLenUnicode>()
                    .create(name.as_str())?
                    .write_scalar(&s)?
            }
            other => {
                return Err(hdf5::Error::from(format!(
                    "attribute '{name}' has a type nlsim does not write ({other:?})"
                )));
            }
        }
    }
    Ok(())
}

/// Copies a dataset of element type `E`, keeping its shape and its chunking/compression.
fn copy_dataset<E: hdf5::H5Type>(
    src: &hdf5::Dataset,
    dst: &hdf5::Group,
    name: &str,
) -> hdf5::Result<hdf5::Dataset> {
    let data = src.read_raw::<E>()?;
    let b = dst.new_dataset::<E>().shape(src.shape());
    let d = match src.chunk() {
        Some(c) => b.chunk(c).shuffle().deflate(4).create(name)?,
        None => b.create(name)?,
    };
    d.write_raw(&data)?;
    Ok(d)
}

/// Recursively copies the groups, datasets and attributes under `src` into `dst`.
fn copy_group(src: &hdf5::Group, dst: &hdf5::Group) -> hdf5::Result<()> {
    use hdf5::types::{FloatSize, IntSize, TypeDescriptor as T};
    copy_attrs(src, dst)?;
    for name in src.member_names()? {
        if let Ok(g) = src.group(&name) {
            let d = dst.create_group(&name)?;
            copy_group(&g, &d)?;
            continue;
        }
        let ds = src.dataset(&name)?;
        let d = match ds.dtype()?.to_descriptor()? {
            T::Float(FloatSize::U8) => copy_dataset::<f64>(&ds, dst, &name)?,
            T::Integer(IntSize::U1) => copy_dataset::<i8>(&ds, dst, &name)?,
            T::Unsigned(IntSize::U1) => copy_dataset::<u8>(&ds, dst, &name)?,
            T::Unsigned(IntSize::U4) => copy_dataset::<u32>(&ds, dst, &name)?,
            T::Compound(c) if c.fields.len() == 2 => copy_dataset::<faer::c64>(&ds, dst, &name)?,
            other => {
                return Err(hdf5::Error::from(format!(
                    "dataset '{name}' has a type nlsim does not write ({other:?})"
                )));
            }
        };
        copy_attrs(&ds, &d)?;
    }
    Ok(())
}

/// Options of the SLURM job-array script.
#[derive(Debug, Clone, Default)]
pub struct SbatchOptions {
    /// Array size: shards.
    pub tasks: usize,
    /// CPUs per task (`--cpus-per-task`); the shard runs that many jobs at once.
    pub cpus_per_task: usize,
    /// `--partition`, if any.
    pub partition: Option<String>,
    /// `--time` limit (`HH:MM:SS`), if any.
    pub time: Option<String>,
    /// `--mem` per node (e.g. `4G`), if any.
    pub mem: Option<String>,
}

/// The job-array script that runs every shard of `b` with the nlsim executable `exe`; logs go
/// to `OUTPUT/logs/`.
pub fn sbatch_script(b: &Batch, exe: &Path, o: &SbatchOptions) -> Result<String> {
    if o.tasks == 0 {
        return Err(Error::Usage("--tasks must be at least 1".into()));
    }
    let abs = |p: &Path| -> Result<PathBuf> {
        std::path::absolute(p).map_err(|source| Error::Io {
            path: p.to_path_buf(),
            source,
        })
    };
    let q = |p: &Path| -> Result<String> {
        let s = abs(p)?.display().to_string();
        Ok(format!("'{}'", s.replace('\'', r"'\''")))
    };
    let logs = b.output.join("logs");
    let mut s = String::from("#!/bin/bash\n");
    s += &format!("#SBATCH --job-name=nlsim-{}\n", b.name);
    s += &format!("#SBATCH --array=0-{}\n", o.tasks - 1);
    s += &format!("#SBATCH --output={}/%x-%A_%a.out\n", abs(&logs)?.display());
    s += &format!("#SBATCH --cpus-per-task={}\n", o.cpus_per_task.max(1));
    for (k, v) in [
        ("partition", &o.partition),
        ("time", &o.time),
        ("mem", &o.mem),
    ] {
        if let Some(v) = v {
            s += &format!("#SBATCH --{k}={v}\n");
        }
    }
    s += &format!(
        "# Written by nlsim {} for {} ({} jobs in {} shards). A shard whose file is complete is\n\
         # skipped, so resubmitting this script redoes only what is missing. Then run:\n\
         #   nlsim batch merge {}\n",
        env!("CARGO_PKG_VERSION"),
        abs(&b.file)?.display(),
        b.jobs.len(),
        o.tasks,
        abs(&b.file)?.display()
    );
    s += "set -euo pipefail\n";
    s += &format!(
        "exec {} batch {} --output {} --task-index \"$SLURM_ARRAY_TASK_ID\" --task-count {} \
         --threads \"${{SLURM_CPUS_PER_TASK:-1}}\"\n",
        q(exe)?,
        q(&b.file)?,
        q(&b.output)?,
        o.tasks
    );
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRF: &str = r#"
name = "t"
command = "frf"
model = "duffing_fig3"
seed = 3

[frf]
from = 80.0
to = 140.0
mode = "step-up"
points = 10

[[sweep]]
set = "spring.k3"
values = [1e3, 2e3, 3e3]

[[sweep]]
option = "force"
values = [0.5, 1]

[lhs]
samples = 4
params = [{ set = "spring.c", min = 0.1, max = 10.0, log = true }]
"#;

    #[test]
    fn grid_is_the_cartesian_product_first_axis_slowest() {
        let b = Batch::parse(FRF, Path::new("/x/jobs.toml")).unwrap();
        assert_eq!(b.jobs.len(), 3 * 2 * 4);
        assert_eq!(b.output, Path::new("/x/t-results"));
        let j = &b.jobs[4 * 2 + 4 + 1]; // k3 = 2e3, force = 1, sample 1
        assert_eq!(j.assignments[0], Assignment::Set("spring.k3".into(), 2e3));
        assert_eq!(j.assignments[1], Assignment::Force(1.0));
        // Shards partition the jobs.
        let mut seen: Vec<usize> = (0..5)
            .flat_map(|t| b.shard_jobs(t, 5).map(|j| j.index).collect::<Vec<_>>())
            .collect();
        seen.sort_unstable();
        assert_eq!(seen, (0..b.jobs.len()).collect::<Vec<_>>());
    }

    #[test]
    fn latin_hypercube_fills_every_stratum_once_and_is_seeded() {
        let (n, d) = (37, 3);
        let a = latin_hypercube(n, d, 11);
        for c in 0..d {
            let mut s: Vec<usize> = a.iter().map(|r| (r[c] * n as f64) as usize).collect();
            s.sort_unstable();
            assert_eq!(s, (0..n).collect::<Vec<_>>());
        }
        assert_eq!(a, latin_hypercube(n, d, 11));
        assert_ne!(a, latin_hypercube(n, d, 12));
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let cases = [
            (
                "name = \"a\"\ncommand = \"frf\"\nmodel = \"m\"\nbogus = 1\n",
                4,
                "bogus",
            ),
            (
                "name = \"a\"\ncommand = \"fft\"\nmodel = \"m\"\n",
                2,
                "unknown command 'fft'",
            ),
            (
                "name = \"a\"\ncommand = \"frf\"\nmodel = \"m\"\n[frf]\nfrom = 1.0\nto = 2.0\n\
                 [[sweep]]\nset = \"s.k\"\nvalues = []\n",
                7,
                "`values` is empty",
            ),
            (
                "name = \"a\"\ncommand = \"frf\"\nmodel = \"m\"\n[frf]\nfrom = 1.0\nto = 2.0\n\
                 mode = \"sideways\"\n",
                7,
                "'sideways'",
            ),
        ];
        for (text, line, what) in cases {
            let e = Batch::parse(text, Path::new("jobs.toml")).unwrap_err();
            let msg = e.to_string();
            assert!(
                msg.starts_with(&format!("jobs.toml:{line}:")) && msg.contains(what),
                "{msg}"
            );
        }
    }

    #[test]
    fn the_hash_is_stable() {
        // FNV-1a test vector.
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
    }
}
