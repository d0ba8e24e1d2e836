//! The jobs file: its TOML tables, parsed and checked into a [`Batch`].

use crate::commands::frf::request::FrfRequest;
use crate::commands::frf::request::FrfStart;
use crate::commands::frf::request::SweepMode;
use crate::commands::simulate::request::Drive;
use crate::commands::simulate::request::Method;
use crate::commands::simulate::request::SimRequest;
use crate::error::{Error, Result};
use nlsim_kernel::Parameterized;
use nlsim_kernel::param::parse_known;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use super::{Assignment, Batch, BatchCommand, Job, latin_hypercube};
use crate::formats::files::line_of;

/// Most samples of a jobs file's `[lhs]` table.
pub const MAX_LHS_SAMPLES: usize = nlsim_calib::MAX_LHS_SAMPLES;

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
    max_step: Option<f64>,
    start: Option<String>,
    modes: Option<usize>,
    residual: Option<bool>,
    stability: Option<bool>,
    basis: Option<usize>,
    restarts: Option<usize>,
    ordering: Option<String>,
    memory_budget: Option<f64>,
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
    basis: Option<usize>,
    restarts: Option<usize>,
    ordering: Option<String>,
    memory_budget: Option<f64>,
}

/// The reduction's Lanczos keys of `[frf]` and `[simulate]` (as `--basis`, `--restarts`,
/// `--ordering` and `--memory-budget GB` of the command line); `Err((key, message))` names the
/// bad one.
fn lanczos_keys(
    basis: Option<usize>,
    restarts: Option<usize>,
    ordering: Option<&str>,
    memory_budget_gb: Option<f64>,
) -> std::result::Result<crate::commands::setup::Lanczos, (&'static str, String)> {
    let d = crate::commands::setup::Lanczos::default();
    let ordering = match ordering {
        None => d.ordering,
        Some(o) => nlsim_reduction::Ordering::parse(o).ok_or((
            "ordering",
            format!("{}: use auto, amd or nd", crate::formats::files::quoted(o)),
        ))?,
    };
    let memory_budget = match memory_budget_gb {
        None => d.memory_budget,
        Some(gb) if gb.is_finite() && gb > 0.0 => Some((gb * 1e9) as usize),
        Some(gb) => {
            return Err((
                "memory_budget",
                format!("{gb}: give a positive number of GB"),
            ));
        }
    };
    if restarts == Some(0) {
        return Err(("restarts", "0: give at least 1".into()));
    }
    Ok(crate::commands::setup::Lanczos {
        basis: basis.or(d.basis),
        restarts: restarts.unwrap_or(d.restarts),
        ordering,
        memory_budget,
    })
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
    calibrate: Option<crate::commands::calibrate::request::CalibrationTable>,
    estimate: Option<BTreeMap<String, f64>>,
    plan: Option<crate::commands::plan::request::PlanTable>,
}

/// FNV-1a, 64 bit: a hash that is the same on every machine and Rust version.
pub(super) fn fnv1a(bytes: &[u8]) -> u64 {
    bytes.iter().fold(0xcbf2_9ce4_8422_2325, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    })
}

impl Batch {
    /// Reads and checks a jobs file.
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::formats::files::read_text(path)?;
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
            err(
                line,
                "",
                crate::formats::model_file::toml_message(e.message()),
            )
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
                    "{} must be non-empty letters, digits, '-', '_' or '.'",
                    crate::formats::files::quoted(&f.name)
                ),
            ));
        }
        // The axes of the job grid: each sweep, then the Latin hypercube (or the candidates
        // or folds of a calibration).
        let mut axes: Vec<Vec<Vec<Assignment>>> = Vec::new();
        let has_plan = f.plan.is_some();
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
                            format!(
                                "{}: use continuation, step-up or step-down",
                                crate::formats::files::quoted(m)
                            ),
                        )
                    })?,
                };
                let start = match &t.start {
                    None => d.start,
                    Some(m) => FrfStart::parse(m).ok_or_else(|| {
                        err(
                            at("start"),
                            "frf.start",
                            format!(
                                "{}: use auto, rest or subharmonic",
                                crate::formats::files::quoted(m)
                            ),
                        )
                    })?,
                };
                let req = FrfRequest {
                    from_hz: t.from,
                    to_hz: t.to,
                    harmonics: t.harmonics.unwrap_or(d.harmonics),
                    subharmonic: t.subharmonic.unwrap_or(d.subharmonic),
                    force: t.force,
                    force_harmonics: Vec::new(),
                    mode,
                    points: t.points,
                    max_step_hz: t.max_step,
                    start,
                    start_file: None,
                    modes: t.modes.unwrap_or(d.modes),
                    residual: t.residual.unwrap_or(d.residual),
                    stability: t.stability.unwrap_or(d.stability),
                    // Jobs run in parallel, each sequential inside: results independent of
                    // the thread and shard count.
                    par: faer::Par::Seq,
                    lanczos: lanczos_keys(
                        t.basis,
                        t.restarts,
                        t.ordering.as_deref(),
                        t.memory_budget,
                    )
                    .map_err(|(k, m)| err(at(k), &format!("frf.{k}"), m))?,
                    modal_sets: Vec::new(),
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
                            format!(
                                "{}: use foh, zoh, lsoh, rk45, rk4, newmark or hht",
                                crate::formats::files::quoted(m)
                            ),
                        )
                    })?,
                };
                let req = SimRequest {
                    duration: t.duration,
                    rate: t.rate,
                    method,
                    excitation: t
                        .excitation
                        .iter()
                        .flatten()
                        .map(|e| Drive::parse(e, t.duration, t.rate))
                        .collect::<Result<_>>()
                        .map_err(|e| err(at("excitation"), "simulate.excitation", e.to_string()))?,
                    modes: t.modes.unwrap_or(d.modes),
                    residual: t.residual.unwrap_or(d.residual),
                    events: t.events.unwrap_or(d.events),
                    rtol: t.rtol.unwrap_or(d.rtol),
                    atol: t.atol.or(d.atol),
                    substeps: t.substeps.unwrap_or(d.substeps),
                    hht_alpha: t.hht_alpha.unwrap_or(d.hht_alpha),
                    par: faer::Par::Seq,
                    lanczos: lanczos_keys(
                        t.basis,
                        t.restarts,
                        t.ordering.as_deref(),
                        t.memory_budget,
                    )
                    .map_err(|(k, m)| err(at(k), &format!("simulate.{k}"), m))?,
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
                    if req.config.fold_by == nlsim_calib::FoldBy::Sweeps {
                        return Err(err(
                            at("fold_by"),
                            "calibrate.fold_by",
                            "'calibrate-folds' deals folds by points; run `nlsim calibrate \
                             --fold-by sweeps` (one fold per sweep) in one process"
                                .to_string(),
                        ));
                    }
                    BatchCommand::CalibrateFolds(Box::new(req), values)
                }
            }
            "plan-candidates" => {
                for (present, key) in [
                    (f.frf.is_some(), "[frf]"),
                    (f.simulate.is_some(), "[simulate]"),
                    (!f.sweep.is_empty(), "[[sweep]]"),
                    (f.lhs.is_some(), "[lhs]"),
                    (!f.set.is_empty(), "set"),
                    (f.seed.is_some(), "seed"),
                    (f.calibrate.is_some(), "[calibrate]"),
                    (f.estimate.is_some(), "estimate"),
                ] {
                    if present {
                        return Err(err(
                            at(key),
                            key.trim_matches(['[', ']']),
                            "a batch of 'plan-candidates' takes its settings from [plan] (`set` \
                             there); its jobs are the candidate sweeps"
                                .into(),
                        ));
                    }
                }
                let Some(t) = f.plan else {
                    return Err(err(
                        at("command"),
                        "plan",
                        "command 'plan-candidates' needs a [plan] table (the keys of a plan \
                         file)"
                            .into(),
                    ));
                };
                let req = t.into_request(f.model.clone(), text, path)?;
                // The jobs are the candidate sweeps, which depend on the model's drive
                // points and force: load it (no reduction) to count them.
                let (_, c) = crate::commands::plan::run::plan_candidates(&req)
                    .map_err(|e| err(at("[plan]"), "plan", e.to_string()))?;
                axes.push(
                    (0..c.sweeps.len())
                        .map(|i| vec![Assignment::PlanSweep(i)])
                        .collect(),
                );
                BatchCommand::PlanCandidates(Box::new(req))
            }
            other => {
                return Err(err(
                    at("command"),
                    "command",
                    format!(
                        "unknown command {}; a batch runs frf, simulate, \
                         calibrate-candidates, calibrate-folds or plan-candidates",
                        crate::formats::files::quoted(other)
                    ),
                ));
            }
        };
        if has_plan && !matches!(command, BatchCommand::PlanCandidates(_)) {
            return Err(err(
                at("[plan]"),
                "plan",
                format!("a [plan] table in a batch of '{}'", f.command),
            ));
        }
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
        // What each axis sets, named once: a parameter or option set by two axes would
        // be written twice into every job (and one value would silently win).
        let mut claimed: Vec<(String, String)> = Vec::new();
        let mut claim = |what: String, by: String, line: usize, key: &str| -> Result<()> {
            if let Some((_, first)) = claimed.iter().find(|(w, _)| *w == what) {
                return Err(err(
                    line,
                    key,
                    format!("'{what}' is already set by {first}; set it in one place"),
                ));
            }
            claimed.push((what, by));
            Ok(())
        };
        for (i, s) in f.sweep.iter().enumerate() {
            let key = format!("sweep[{i}]");
            let line = text
                .match_indices("[[sweep]]")
                .nth(i)
                .map_or(1, |(o, _)| line_of(text, o));
            if let Some(what) = s.set.clone().or_else(|| s.option.clone()) {
                claim(what, format!("[[sweep]] {}", i + 1), line, &key)?;
            }
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
            if l.samples > MAX_LHS_SAMPLES {
                return Err(err(
                    line,
                    "lhs.samples",
                    format!(
                        "{} samples: at most {MAX_LHS_SAMPLES} (each sample is a job)",
                        l.samples
                    ),
                ));
            }
            for p in &l.params {
                claim(p.set.clone(), "[lhs]".into(), line, "lhs.params")?;
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
        let text = crate::formats::files::read_text(&self.file).unwrap_or_default();
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
            let model = crate::commands::setup::load_for_run(m, &self.sets)
                .map_err(|e| err(m, "model", e))?;
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
