//! `nlsim plan MODEL PLAN` as library calls: a typed [`PlanRequest`] read from a plan file,
//! [`run_plan`] on it (thesis §4.3: the Fisher information `F = Jᵀ Σ⁻¹ J` of every
//! candidate test from the analytic harmonic-balance sensitivities), and
//! [`write_plan_report`] with the ranked table, the Cramér–Rao bounds and the plots.
//!
//! A plan file (`docs/planning.md`) names the parameters the test should identify and the
//! candidates: drive points, force levels, excitation signals, frequency bands, sensor sets
//! and measured harmonics. Every combination is one candidate design.
//!
//! ```toml
//! params = ["tip.k3", "mode1.zeta"]   # what the test should identify
//! criterion = "D"                     # D | T | A | E | max-variance
//! levels = [0.05, 0.1, 0.2]           # fundamental force amplitudes (N)
//! measured = [[1], [1, 3]]            # candidate sets of measured harmonics
//! sensor_counts = [1, 2]              # sizes of the candidate sensor sets
//! noise = { relative = 0.01, absolute = 1e-3 }
//!
//! [[actuator]]                        # drive points beside the model's excitations
//! name = "mid"
//! dof = "11:uz"
//!
//! [[band]]
//! label = "across"
//! from = 30.0
//! to = 36.0
//! steps = 15
//! ```

use crate::calibration::SettingsFile;
use crate::error::{Error, Result};
use crate::output::write_text_atomically as write_text;
use crate::plot::{BarGroup, Bars, Lines};
use faer::Mat;
use nlsim_calib::{
    Band, Criterion, Exciter, Noise, Planner, RankedDesign, SideTone, SweepInformation,
    rank_designs, subsets,
};
use nlsim_hb::{HarmonicSet, HbConfig};
use nlsim_kernel::{Excitation, Model, Param, Quantity, Sensor};
use rayon::prelude::*;
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// Largest plan, test or prior file read (bytes).
pub const MAX_SETTINGS_BYTES: u64 = 1 << 20;
/// Most candidate designs one plan ranks (each keeps its information summary, ~0.3 kB with
/// a few parameters): more is a batch (`plan-candidates`, docs/batch.md) or a greedy search.
pub const MAX_DESIGNS: usize = 2_000_000;
/// Most predicted stepped-sine steps of one plan (candidate sweeps × steps).
pub const MAX_STEPS: usize = 1_000_000;
/// Most parameters planned for.
pub const MAX_PARAMS: usize = 64;

/// A candidate excitation signal: a pure sine, or a multi-sine with side tones (thesis
/// eq. 12).
#[derive(Debug, Clone, PartialEq)]
pub struct Signal {
    /// Name in reports.
    pub label: String,
    /// Side tones (empty: a pure sine).
    pub side: Vec<SideTone>,
}

/// A candidate sensor or drive point added to the model for planning.
#[derive(Debug, Clone, PartialEq)]
pub struct PointSpec {
    /// Name (a sensor's channel name, an actuator's input name).
    pub name: String,
    /// DOF label, e.g. `11:uz`.
    pub dof: String,
    /// Measured quantity (sensors).
    pub quantity: Quantity,
}

/// Everything a plan needs. Paths are as given (relative to the working directory).
#[derive(Debug, Clone)]
pub struct PlanRequest {
    /// Model file or built-in model.
    pub model: String,
    /// Fixed overrides `NAME=VALUE` applied first.
    pub set: Vec<String>,
    /// The parameters the test should identify, at their model values.
    pub params: Vec<Param>,
    /// Candidate drive points added to the model's excitations.
    pub actuators: Vec<PointSpec>,
    /// Candidate sensors added to the model's sensors.
    pub sensors: Vec<PointSpec>,
    /// Fundamental force amplitudes (N); empty: the model's first excitation amplitude.
    pub levels: Vec<f64>,
    /// Candidate signals; empty: one pure sine.
    pub signals: Vec<Signal>,
    /// Candidate stepped sines (at least one).
    pub bands: Vec<Band>,
    /// Candidate sets of measured harmonics (1 = fundamental).
    pub measured: Vec<Vec<usize>>,
    /// Sizes of the candidate sensor sets; empty: `1..=min(4, sensors)`.
    pub sensor_counts: Vec<usize>,
    /// Harmonics `H` of the harmonic balance.
    pub harmonics: usize,
    /// Retained modes.
    pub modes: usize,
    /// Measurement noise of every channel (with an absolute floor).
    pub noise: Noise,
    /// Ranking criterion.
    pub criterion: Criterion,
    /// Information of an earlier test (CSV written by a plan report as `fim_best.csv`).
    pub prior: Option<PathBuf>,
    /// Rows of the summary table.
    pub top: usize,
    /// Report folder.
    pub report: Option<PathBuf>,
}

impl PlanRequest {
    /// A plan of `params` of `model` over `bands` with the defaults: the model's drive points,
    /// sensors and force, a pure sine, the fundamental measured, noise 1 % with a floor of
    /// 10⁻³ of the sensors' unit, H = 3, 20 modes, D-optimality, 10 rows.
    pub fn new(model: impl Into<String>, params: Vec<Param>, bands: Vec<Band>) -> Self {
        Self {
            model: model.into(),
            set: Vec::new(),
            params,
            actuators: Vec::new(),
            sensors: Vec::new(),
            levels: Vec::new(),
            signals: Vec::new(),
            bands,
            measured: vec![vec![1]],
            sensor_counts: Vec::new(),
            harmonics: 3,
            modes: 20,
            noise: Noise {
                absolute: 1e-3,
                relative: 0.01,
            },
            criterion: Criterion::D,
            prior: None,
            top: 10,
            report: None,
        }
    }

    /// Checks what can be checked without the model: parameters, bands, harmonics, levels,
    /// signals, noise and the sizes against the budgets.
    pub fn check(&self) -> Result<()> {
        let bad = |field: &str, why: String| Err(Error::Usage(format!("plan {field}: {why}")));
        if self.params.is_empty() || self.params.len() > MAX_PARAMS {
            return bad(
                "params",
                format!(
                    "name 1 to {MAX_PARAMS} parameters (got {})",
                    self.params.len()
                ),
            );
        }
        for (i, p) in self.params.iter().enumerate() {
            if self.params[..i].contains(p) {
                return bad("params", format!("{p} is named twice"));
            }
        }
        if self.harmonics == 0 || self.harmonics > 64 {
            return bad("harmonics", format!("{} is not in 1..=64", self.harmonics));
        }
        if self.modes == 0 {
            return bad("modes", "retain at least one mode".into());
        }
        if self.bands.is_empty() {
            return bad("band", "give at least one [[band]]".into());
        }
        for b in &self.bands {
            let ok = b.from_hz.is_finite()
                && b.to_hz.is_finite()
                && b.from_hz > 0.0
                && b.to_hz > 0.0
                && b.from_hz != b.to_hz
                && (2..=100_000).contains(&b.steps);
            if !ok {
                return bad(
                    "band",
                    format!(
                        "'{}': needs two distinct positive frequencies and 2 to 100000 steps \
                         (got {} to {} Hz, {} steps)",
                        b.label, b.from_hz, b.to_hz, b.steps
                    ),
                );
            }
        }
        if self.measured.is_empty() {
            return bad("measured", "give at least one set of harmonics".into());
        }
        for m in &self.measured {
            if m.is_empty() || m.iter().any(|&k| k == 0 || k > self.harmonics) {
                return bad(
                    "measured",
                    format!(
                        "{m:?}: harmonics between 1 and the harmonic balance's {}",
                        self.harmonics
                    ),
                );
            }
        }
        if let Some(l) = self.levels.iter().find(|l| !(l.is_finite() && **l > 0.0)) {
            return bad("levels", format!("{l} N is not a positive force"));
        }
        for s in &self.signals {
            for t in &s.side {
                if t.harmonic < 2
                    || t.harmonic > self.harmonics
                    || !t.fraction.is_finite()
                    || !t.phase.is_finite()
                {
                    return bad(
                        "signal",
                        format!(
                            "'{}': side tone harmonic {} must be from 2 to H = {}, with a \
                             finite fraction and phase",
                            s.label, t.harmonic, self.harmonics
                        ),
                    );
                }
            }
        }
        let n = &self.noise;
        if !(n.absolute.is_finite() && n.absolute > 0.0 && n.relative.is_finite())
            || n.relative < 0.0
        {
            return bad(
                "noise",
                format!(
                    "absolute {} must be positive (a floor: without it a harmonic the model \
                     predicts as nearly zero would weigh without bound) and relative {} \
                     non-negative",
                    n.absolute, n.relative
                ),
            );
        }
        if self.sensor_counts.contains(&0) {
            return bad(
                "sensor_counts",
                "a sensor set holds at least one sensor".into(),
            );
        }
        if self.top == 0 {
            return bad("top", "show at least one row".into());
        }
        Ok(())
    }

    /// Reads a plan file for `model` (the module docs show one).
    pub fn load(path: &Path, model: &str) -> Result<Self> {
        let text = crate::output::read_text_bounded(path, MAX_SETTINGS_BYTES)?;
        Self::parse(&text, path, model)
    }

    /// Parses plan-file text for `model`; `path` names it in errors, and relative paths in
    /// it are taken from its folder.
    pub fn parse(text: &str, path: &Path, model: &str) -> Result<Self> {
        let t: PlanTable = SettingsFile::parse(text, path)?;
        t.into_request(model.to_string(), text, path)
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PointTable {
    name: String,
    dof: String,
    quantity: Option<String>,
}

impl PointTable {
    /// The point, with the quantity parsed (acceleration when not given); errors name
    /// `key` in `file`.
    pub(crate) fn spec(&self, file: &SettingsFile<'_>, key: &str) -> Result<PointSpec> {
        let quantity = match &self.quantity {
            None => Quantity::Acceleration,
            Some(q) => Quantity::parse(q).map_err(|e| file.err(key, e.to_string()))?,
        };
        Ok(PointSpec {
            name: self.name.clone(),
            dof: self.dof.clone(),
            quantity,
        })
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SideTable {
    harmonic: usize,
    fraction: f64,
    #[serde(default)]
    phase: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SignalTable {
    label: String,
    #[serde(default)]
    side: Vec<SideTable>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct BandTable {
    label: Option<String>,
    from: f64,
    to: f64,
    steps: usize,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NoiseTable {
    relative: Option<f64>,
    absolute: Option<f64>,
}

/// A plan file, or the `[plan]` table of a jobs file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct PlanTable {
    params: Vec<String>,
    #[serde(default)]
    set: BTreeMap<String, f64>,
    criterion: Option<String>,
    #[serde(default)]
    levels: Vec<f64>,
    measured: Option<Vec<Vec<usize>>>,
    #[serde(default)]
    sensor_counts: Vec<usize>,
    harmonics: Option<usize>,
    modes: Option<usize>,
    noise: Option<NoiseTable>,
    prior: Option<String>,
    top: Option<usize>,
    report: Option<String>,
    #[serde(default)]
    actuator: Vec<PointTable>,
    #[serde(default)]
    sensor: Vec<PointTable>,
    #[serde(default)]
    signal: Vec<SignalTable>,
    #[serde(default)]
    band: Vec<BandTable>,
}

impl PlanTable {
    /// The request for `model`, relative paths from `path`'s folder; errors name `path`,
    /// the line and the key.
    pub(crate) fn into_request(
        self,
        model: String,
        text: &str,
        path: &Path,
    ) -> Result<PlanRequest> {
        let file = SettingsFile { text, path };
        let err = |key: &str, message: String| file.err(key, message);
        let rel = |p: &str| file.rel(p);
        let params = self
            .params
            .iter()
            .map(|n| n.parse::<Param>())
            .collect::<std::result::Result<Vec<_>, _>>()
            .map_err(|e| err("params", e.to_string()))?;
        let point = |p: &PointTable, key: &str| p.spec(&file, key);
        let d = PlanRequest::new("", Vec::new(), Vec::new());
        let noise = match &self.noise {
            None => d.noise,
            Some(n) => Noise {
                absolute: n.absolute.unwrap_or(d.noise.absolute),
                relative: n.relative.unwrap_or(d.noise.relative),
            },
        };
        let criterion = match &self.criterion {
            None => d.criterion,
            Some(c) => Criterion::parse(c).map_err(|e| err("criterion", e.to_string()))?,
        };
        let req = PlanRequest {
            model,
            set: self.set.iter().map(|(k, v)| format!("{k}={v:e}")).collect(),
            params,
            actuators: self
                .actuator
                .iter()
                .map(|p| point(p, "actuator"))
                .collect::<Result<_>>()?,
            sensors: self
                .sensor
                .iter()
                .map(|p| point(p, "sensor"))
                .collect::<Result<_>>()?,
            levels: self.levels,
            signals: self
                .signal
                .iter()
                .map(|s| Signal {
                    label: s.label.clone(),
                    side: s
                        .side
                        .iter()
                        .map(|t| SideTone {
                            harmonic: t.harmonic,
                            fraction: t.fraction,
                            phase: t.phase,
                        })
                        .collect(),
                })
                .collect(),
            bands: self
                .band
                .iter()
                .enumerate()
                .map(|(i, b)| Band {
                    label: b.label.clone().unwrap_or_else(|| format!("band{}", i + 1)),
                    from_hz: b.from,
                    to_hz: b.to,
                    steps: b.steps,
                })
                .collect(),
            measured: self.measured.unwrap_or(d.measured),
            sensor_counts: self.sensor_counts,
            harmonics: self.harmonics.unwrap_or(d.harmonics),
            modes: self.modes.unwrap_or(d.modes),
            noise,
            criterion,
            prior: self.prior.as_deref().map(rel),
            top: self.top.unwrap_or(d.top),
            report: self.report.as_deref().map(rel),
        };
        req.check().map_err(|e| file.located("plan", e))?;
        Ok(req)
    }
}

/// One candidate stepped sine: where and how the structure is driven, over which band.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateSweep {
    /// Drive point, level and signal.
    pub exciter: Exciter,
    /// The signal's label.
    pub signal: String,
    /// The band.
    pub band: Band,
}

/// The candidates of a plan: sweeps, sensor sets and harmonic sets, and the prior.
#[derive(Debug, Clone)]
pub struct PlanCandidates {
    /// The model's name.
    pub model_name: String,
    /// The candidate channels: the model's sensors, then the plan's `[[sensor]]` entries.
    pub channels: Vec<String>,
    /// Every candidate stepped sine: drives × levels × signals × bands, the last fastest.
    pub sweeps: Vec<CandidateSweep>,
    /// Every candidate sensor set (indices into the planner's channels).
    pub channel_sets: Vec<Vec<usize>>,
    /// The harmonics the information is computed for (sorted, distinct).
    pub harmonics: Vec<usize>,
    /// Every candidate set of measured harmonics (indices into `harmonics`).
    pub harmonic_sets: Vec<Vec<usize>>,
    /// The prior information (relative units), if any.
    pub prior: Option<Mat<f64>>,
}

/// A plan ready to run: its candidates and the planner.
pub struct PlanSetup {
    /// The candidates.
    pub candidates: PlanCandidates,
    /// The planner (its system's sensors are the candidate channels).
    pub planner: Planner,
    /// Wall time of loading and reduction (s).
    pub seconds: f64,
}

impl PlanCandidates {
    /// Candidate designs: sweeps × sensor sets × harmonic sets.
    pub fn n_designs(&self) -> usize {
        self.sweeps.len() * self.channel_sets.len() * self.harmonic_sets.len()
    }
}

/// `n choose k`, `None` above `usize`.
fn binomial(n: usize, k: usize) -> Option<usize> {
    let k = k.min(n - k.min(n));
    (0..k).try_fold(1usize, |acc, i| acc.checked_mul(n - i).map(|v| v / (i + 1)))
}

/// Loads the model of `req`, adds its candidate points, reduces it and builds the planner
/// and the candidates.
pub fn prepare_plan(req: &PlanRequest) -> Result<PlanSetup> {
    let t = Instant::now();
    let (model, candidates) = plan_candidates(req)?;
    // Sequential reduction: the modes, and with them every number of the plan, are then
    // bit-identical whatever the thread count.
    let mut reduction = nlsim_reduction::ReductionConfig::lowest(req.modes.min(model.n_dofs()));
    reduction.eigen.par = faer::Par::Seq;
    let planner = Planner::from_model(
        &model,
        &reduction,
        HarmonicSet::new(req.harmonics, 1)?,
        HbConfig::default(),
        &req.params,
    )?;
    Ok(PlanSetup {
        candidates,
        planner,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// The model of `req` with its candidate points, and the candidates, every size checked
/// against the budgets before anything is allocated (no reduction).
pub fn plan_candidates(req: &PlanRequest) -> Result<(Model, PlanCandidates)> {
    req.check()?;
    let mut model = crate::run::load_for_run(&req.model, &req.set)?;
    add_points(&mut model, req)?;
    if model.excitation().is_empty() {
        return Err(Error::Usage(format!(
            "plan: '{}' has no excitation; add candidate drive points as [[actuator]]",
            model.name()
        )));
    }
    if model.sensors().is_empty() {
        return Err(Error::Usage(format!(
            "plan: '{}' has no sensor; add candidate sensors as [[sensor]]",
            model.name()
        )));
    }
    let levels = if req.levels.is_empty() {
        let a = model.excitation()[0].amplitude;
        if !(a.is_finite() && a > 0.0) {
            return Err(Error::Usage(format!(
                "plan: give `levels`; the model's excitation amplitude {a} N is no force level"
            )));
        }
        vec![a]
    } else {
        req.levels.clone()
    };
    let signals = if req.signals.is_empty() {
        vec![Signal {
            label: "sine".into(),
            side: Vec::new(),
        }]
    } else {
        req.signals.clone()
    };
    let drives: Vec<String> = model.excitation().iter().map(|e| e.name.clone()).collect();
    let n_sweeps = drives.len() * levels.len() * signals.len() * req.bands.len();
    let steps: usize = req.bands.iter().map(|b| b.steps).sum::<usize>()
        * drives.len()
        * levels.len()
        * signals.len();
    if steps > MAX_STEPS {
        return Err(Error::Usage(format!(
            "plan: {n_sweeps} candidate sweeps with {steps} steps in all, more than {MAX_STEPS}; \
             split it into a plan-candidates batch (docs/batch.md) or use fewer candidates"
        )));
    }
    let nc = model.sensors().len();
    let counts: Vec<usize> = if req.sensor_counts.is_empty() {
        (1..=nc.min(4)).collect()
    } else {
        req.sensor_counts.clone()
    };
    if let Some(&k) = counts.iter().find(|&&k| k > nc) {
        return Err(Error::Usage(format!(
            "plan sensor_counts: a set of {k} sensors, but the model has {nc} (with the \
             [[sensor]] candidates)"
        )));
    }
    let n_sets = counts
        .iter()
        .try_fold(0usize, |a, &k| a.checked_add(binomial(nc, k)?));
    let n_designs = n_sets
        .and_then(|s| s.checked_mul(n_sweeps))
        .and_then(|s| s.checked_mul(req.measured.len()));
    match n_designs {
        Some(n) if n <= MAX_DESIGNS => {}
        _ => {
            return Err(Error::Usage(format!(
                "plan: {} candidate designs ({n_sweeps} sweeps × {} sensor sets × {} harmonic \
                 sets), more than {MAX_DESIGNS}: enumerate fewer sensor-set sizes, or place \
                 sensors greedily (nlsim_calib::greedy_placement)",
                n_designs.map_or("over 2^64".into(), |n| n.to_string()),
                n_sets.map_or("over 2^64".into(), |n| n.to_string()),
                req.measured.len()
            )));
        }
    }
    let channel_sets: Vec<Vec<usize>> = counts.iter().flat_map(|&k| subsets(nc, k)).collect();
    let mut harmonics: Vec<usize> = req.measured.iter().flatten().copied().collect();
    harmonics.sort_unstable();
    harmonics.dedup();
    let harmonic_sets = req
        .measured
        .iter()
        .map(|m| {
            let mut s: Vec<usize> = m
                .iter()
                .map(|k| harmonics.iter().position(|h| h == k).expect("collected"))
                .collect();
            s.sort_unstable();
            s.dedup();
            s
        })
        .collect();
    let mut sweeps = Vec::with_capacity(n_sweeps);
    for d in &drives {
        for &level in &levels {
            for s in &signals {
                for b in &req.bands {
                    sweeps.push(CandidateSweep {
                        exciter: Exciter {
                            input: d.clone(),
                            level,
                            side: s.side.clone(),
                        },
                        signal: s.label.clone(),
                        band: b.clone(),
                    });
                }
            }
        }
    }
    let prior = match &req.prior {
        None => None,
        Some(p) => Some(read_fim_csv(p, &req.params)?),
    };
    let candidates = PlanCandidates {
        model_name: model.name().to_string(),
        channels: model.sensors().iter().map(|s| s.name.clone()).collect(),
        sweeps,
        channel_sets,
        harmonics,
        harmonic_sets,
        prior,
    };
    Ok((model, candidates))
}

/// Adds the request's candidate actuators (as excitations of zero nominal amplitude) and
/// sensors to `model`; errors name the point and its DOF.
fn add_points(model: &mut Model, req: &PlanRequest) -> Result<()> {
    for a in &req.actuators {
        let d = point_dof(model, a, "plan actuator")?;
        model.add_excitation(Excitation {
            name: a.name.clone(),
            dof: d,
            amplitude: 0.0,
            harmonics: Vec::new(),
        })?;
    }
    add_sensors(model, &req.sensors, "plan sensor")
}

/// Adds `sensors` to `model` (a plan's or a test file's `[[sensor]]` entries); an unknown
/// DOF is named with `what` (e.g. `plan sensor`) and the point.
pub(crate) fn add_sensors(model: &mut Model, sensors: &[PointSpec], what: &str) -> Result<()> {
    for s in sensors {
        let d = point_dof(model, s, what)?;
        model.add_sensor(Sensor {
            name: s.name.clone(),
            dof: d,
            quantity: s.quantity,
        })?;
    }
    Ok(())
}

/// The DOF of point `p` in `model`; the error names `what`, the point and its DOF.
fn point_dof(model: &Model, p: &PointSpec, what: &str) -> Result<usize> {
    model.dofs().find(&p.dof).map_err(|e| {
        Error::Usage(format!(
            "{what} '{}': DOF '{}' is not in '{}': {e}",
            p.name,
            p.dof,
            model.name()
        ))
    })
}

/// The information of candidate sweep `i` of `setup`.
pub fn sweep_information(setup: &PlanSetup, i: usize, noise: Noise) -> Result<SweepInformation> {
    let c = &setup.candidates;
    let s = c.sweeps.get(i).ok_or_else(|| {
        Error::Usage(format!(
            "candidate sweep {i} is beyond the plan's {}",
            c.sweeps.len()
        ))
    })?;
    Ok(setup
        .planner
        .sweep_information(&s.exciter, &s.band, noise, &c.harmonics)?)
}

/// A finished plan.
pub struct PlanRun {
    /// The request.
    pub request: PlanRequest,
    /// The candidates.
    pub candidates: PlanCandidates,
    /// The parameters planned for.
    pub params: Vec<Param>,
    /// Their nominal values.
    pub nominal: Vec<f64>,
    /// Wall time of loading and reduction (s).
    pub setup_seconds: f64,
    /// The information of every candidate sweep.
    pub sweeps: Vec<SweepInformation>,
    /// Every design, best first.
    pub ranked: Vec<RankedDesign>,
    /// Wall time of the predicted sweeps (s).
    pub sweep_seconds: f64,
    /// Wall time of the ranking (s).
    pub rank_seconds: f64,
}

/// Runs `req`: every candidate sweep predicted with its information (in parallel on the
/// calling rayon pool; each sweep is independent, so the numbers do not depend on the
/// thread count), then every design ranked. `progress(done, total)` after each sweep.
pub fn run_plan(req: &PlanRequest, progress: &(dyn Fn(usize, usize) + Sync)) -> Result<PlanRun> {
    let setup = prepare_plan(req)?;
    let t = Instant::now();
    let done = AtomicUsize::new(0);
    let total = setup.candidates.sweeps.len();
    let sweeps = (0..total)
        .into_par_iter()
        .map(|i| {
            let r = sweep_information(&setup, i, req.noise);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            r
        })
        .collect::<Result<Vec<_>>>()?;
    let sweep_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let ranked = rank(&setup.candidates, &sweeps, req.criterion)?;
    Ok(PlanRun {
        request: req.clone(),
        params: setup.planner.params().to_vec(),
        nominal: setup.planner.nominal().to_vec(),
        setup_seconds: setup.seconds,
        candidates: setup.candidates,
        sweeps,
        ranked,
        sweep_seconds,
        rank_seconds: t.elapsed().as_secs_f64(),
    })
}

/// Every design of `setup` over the informations `sweeps`, best first.
pub fn rank(
    setup: &PlanCandidates,
    sweeps: &[SweepInformation],
    criterion: Criterion,
) -> Result<Vec<RankedDesign>> {
    Ok(rank_designs(
        sweeps,
        &setup.channel_sets,
        &setup.harmonic_sets,
        setup.prior.as_ref(),
        criterion,
    )?)
}

/// One design in words: drive, level, signal, band, sensors, harmonics.
pub fn describe_design(
    setup: &PlanCandidates,
    sweeps: &[SweepInformation],
    r: &RankedDesign,
) -> [String; 6] {
    let c = &setup.sweeps[r.design.sweep];
    let sw = &sweeps[r.design.sweep];
    let ch = sw.channel_names(&r.design);
    let hk: Vec<String> = sw
        .harmonic_numbers(&r.design)
        .iter()
        .map(usize::to_string)
        .collect();
    [
        c.exciter.input.clone(),
        format!("{}", c.exciter.level),
        c.signal.clone(),
        format!("{} ({}-{} Hz)", c.band.label, c.band.from_hz, c.band.to_hz),
        ch.join("+"),
        hk.join("+"),
    ]
}

/// Reads an information matrix written as `fim_best.csv` (header `param,NAME...`, one row
/// `NAME,F_i1,...` per parameter, relative units) for `params` (rows and columns taken by
/// name, so their order may differ); it must be symmetric with a non-negative diagonal.
pub fn read_fim_csv(path: &Path, params: &[Param]) -> Result<Mat<f64>> {
    let text = crate::output::read_text_bounded(path, MAX_SETTINGS_BYTES)?;
    let bad = |line: usize, m: String| Error::Usage(format!("{}:{line}: {m}", path.display()));
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        return Err(bad(
            1,
            "empty; expected `param,NAME,...` and one row per parameter".into(),
        ));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    if names.first() != Some(&"param") || names.len() < 2 {
        return Err(bad(
            1,
            format!("header '{header}': expected `param,NAME,...`"),
        ));
    }
    let cols = &names[1..];
    let index = |name: &str, line: usize| -> Result<usize> {
        params
            .iter()
            .position(|p| p.to_string() == name)
            .ok_or_else(|| bad(line, format!("{name} is not a planned parameter")))
    };
    let col_idx: Vec<usize> = cols.iter().map(|c| index(c, 1)).collect::<Result<_>>()?;
    let n = params.len();
    if cols.len() != n {
        return Err(bad(
            1,
            format!("{} columns for {n} planned parameters", cols.len()),
        ));
    }
    let mut f = Mat::<f64>::from_fn(n, n, |_, _| f64::NAN);
    let mut rows = 0;
    for (i, line) in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != n + 1 {
            return Err(bad(
                i + 1,
                format!("{} fields, expected {}", cells.len(), n + 1),
            ));
        }
        let r = index(cells[0], i + 1)?;
        for (c, v) in cells[1..].iter().enumerate() {
            let x: f64 = v
                .parse()
                .ok()
                .filter(|x: &f64| x.is_finite())
                .ok_or_else(|| bad(i + 1, format!("'{v}' is not a finite number")))?;
            f[(r, col_idx[c])] = x;
        }
        rows += 1;
    }
    if rows != n || (0..n).any(|i| (0..n).any(|j| f[(i, j)].is_nan())) {
        return Err(bad(1, format!("needs one row per planned parameter ({n})")));
    }
    for i in 0..n {
        if f[(i, i)] < 0.0 {
            return Err(bad(1, format!("diagonal of {} is negative", params[i])));
        }
        for j in 0..i {
            let tol = 1e-9 * (f[(i, i)] * f[(j, j)]).sqrt().max(f64::MIN_POSITIVE);
            if (f[(i, j)] - f[(j, i)]).abs() > tol {
                return Err(bad(
                    1,
                    format!("not symmetric at ({}, {})", params[i], params[j]),
                ));
            }
        }
    }
    Ok(f)
}

/// An information matrix as `read_fim_csv` reads it.
pub fn fim_csv(params: &[Param], f: &Mat<f64>) -> String {
    let mut s = String::from("param");
    for p in params {
        let _ = write!(s, ",{p}");
    }
    s.push('\n');
    for (i, p) in params.iter().enumerate() {
        let _ = write!(s, "{p}");
        for j in 0..params.len() {
            let _ = write!(s, ",{:?}", f[(i, j)]);
        }
        s.push('\n');
    }
    s
}

impl PlanRun {
    /// The test file (`nlsim test`, docs/planning.md) that runs design `r`: its drive
    /// (`drive_dof` for a plan actuator), level and band as one `[[sweep]]`, its sensors
    /// as `channels` (with `[[sensor]]` entries for the plan's added sensors), the plan's
    /// harmonics, modes, overrides and noise, the data written to `virtual_test.csv`
    /// beside the file. The compared harmonics are named in a comment (they are
    /// `nlsim calibrate --compare`). `nlsim test` drives a pure sine: a design's side
    /// tones are named in a comment and left out.
    pub fn test_file(&self, r: &RankedDesign) -> String {
        let req = &self.request;
        let c = &self.candidates.sweeps[r.design.sweep];
        let sw = &self.sweeps[r.design.sweep];
        let q = |s: &str| toml_string(s);
        let mut t = String::new();
        let [drive, level, signal, band, sensors, harm] =
            describe_design(&self.candidates, &self.sweeps, r);
        let _ = writeln!(
            t,
            "# nlsim test file of a planned design of '{}': drive {drive}, {level} N, {signal}, \
             {band}, sensors {sensors}, harmonics {harm}",
            self.candidates.model_name
        );
        let compare: Vec<String> = sw
            .harmonic_numbers(&r.design)
            .iter()
            .map(usize::to_string)
            .collect();
        let _ = writeln!(
            t,
            "# calibrate the data with: nlsim calibrate MODEL virtual_test.csv --compare {} \
             --param ...",
            compare.join(",")
        );
        if !c.exciter.side.is_empty() {
            let _ = writeln!(
                t,
                "# the design's side tones ({signal}) are left out: nlsim test drives a pure sine"
            );
        }
        match req.actuators.iter().find(|a| a.name == c.exciter.input) {
            Some(a) => {
                let _ = writeln!(t, "drive_dof = {}", q(&a.dof));
            }
            None => {
                let _ = writeln!(t, "drive = {}", q(&c.exciter.input));
            }
        }
        let _ = writeln!(t, "harmonics = {}", req.harmonics);
        let _ = writeln!(t, "modes = {}", req.modes);
        let _ = writeln!(
            t,
            "noise = {{ relative = {:e}, absolute = {:e} }}",
            req.noise.relative, req.noise.absolute
        );
        let _ = writeln!(t, "out = \"virtual_test.csv\"");
        let names: Vec<String> = sw.channel_names(&r.design).into_iter().map(q).collect();
        let _ = writeln!(t, "channels = [{}]", names.join(", "));
        if !req.set.is_empty() {
            let pairs: Vec<String> = req
                .set
                .iter()
                .filter_map(|kv| kv.split_once('='))
                .map(|(k, v)| format!("{} = {}", q(k.trim()), v.trim()))
                .collect();
            let _ = writeln!(t, "set = {{ {} }}", pairs.join(", "));
        }
        let added: Vec<&PointSpec> = sw
            .channel_names(&r.design)
            .into_iter()
            .filter_map(|name| req.sensors.iter().find(|p| p.name == name))
            .collect();
        if !added.is_empty() {
            let _ = writeln!(
                t,
                "\n# the sensors below are not in the model: calibrate the data with a model \
                 file that declares them"
            );
        }
        for p in added {
            let _ = write!(
                t,
                "\n[[sensor]]\nname = {}\ndof = {}\nquantity = {}\n",
                q(&p.name),
                q(&p.dof),
                q(p.quantity.as_str())
            );
        }
        let _ = write!(
            t,
            "\n[[sweep]]\nlabel = {}\nfrom = {:?}\nto = {:?}\nsteps = {}\nforce = {:?}\n",
            q(&format!("{} N {}", c.exciter.level, c.band.label)),
            c.band.from_hz,
            c.band.to_hz,
            c.band.steps,
            c.exciter.level
        );
        t
    }

    /// The information of design `r` (prior included).
    pub fn fim(&self, r: &RankedDesign) -> Mat<f64> {
        self.sweeps[r.design.sweep].fim(
            &r.design.channels,
            &r.design.harmonics,
            self.candidates.prior.as_ref(),
        )
    }

    /// The readable summary: what was planned, the best designs and the worst, and how much
    /// better the best is.
    pub fn summary(&self) -> Vec<String> {
        let req = &self.request;
        let s = &self.candidates;
        let names: Vec<String> = self.params.iter().map(|p| p.to_string()).collect();
        let mut v = vec![
            format!(
                "planning a test of '{}' for {} (nominal {}); Fisher information from the \
                 analytic harmonic-balance sensitivities, relative units (d/d ln p), noise {} % \
                 + {:e}{}",
                s.model_name,
                names.join(", "),
                self.nominal
                    .iter()
                    .map(|x| format!("{x:.4e}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                100.0 * req.noise.relative,
                req.noise.absolute,
                if s.prior.is_some() {
                    ", prior information added"
                } else {
                    ""
                }
            ),
            format!(
                "{} candidate designs = {} sweeps (drives x levels x signals x bands) x {} \
                 sensor sets x {} harmonic sets, ranked by {}; reduction {:.2} s, sweeps \
                 {:.2} s, ranking {:.2} s",
                self.ranked.len(),
                s.sweeps.len(),
                s.channel_sets.len(),
                s.harmonic_sets.len(),
                criterion_desc(req.criterion),
                self.setup_seconds,
                self.sweep_seconds,
                self.rank_seconds
            ),
        ];
        for (i, sw) in self.sweeps.iter().enumerate() {
            if !sw.failed_hz.is_empty() {
                v.push(format!(
                    "sweep {} ({} at {}): the prediction did not converge at {} of {} steps \
                     (from {:.4} Hz); they add no information",
                    i + 1,
                    s.sweeps[i].band.label,
                    sw.exciter.describe(),
                    sw.failed_hz.len(),
                    sw.band.steps,
                    sw.failed_hz[0]
                ));
            }
        }
        let std_head: Vec<String> = names.iter().map(|n| format!("{n:>14}")).collect();
        v.push(format!(
            "{:>6}  {:<10} {:>9} {:<10} {:<26} {:<16} {:<6} {:>12}  {}  {:>8}  most collinear",
            "rank",
            "drive",
            "level N",
            "signal",
            "band",
            "sensors",
            "harm.",
            req.criterion.as_str(),
            std_head.join(" "),
            "gamma"
        ));
        let n = self.ranked.len();
        for (i, r) in self.ranked.iter().enumerate() {
            if i < req.top || i + 1 == n {
                if i == req.top && n > req.top + 1 {
                    v.push("   ...".into());
                }
                v.push(self.row(i, r));
            }
        }
        if let (Some(b), Some(w)) = (self.ranked.first(), self.ranked.last()) {
            let pct = |x: f64| {
                if x.is_finite() {
                    format!("{:.4} %", 100.0 * x)
                } else {
                    "unidentifiable".into()
                }
            };
            let each: Vec<String> = names
                .iter()
                .enumerate()
                .map(|(j, nm)| {
                    format!(
                        "{nm} {} -> {}",
                        pct(b.summary.std[j]),
                        pct(w.summary.std[j])
                    )
                })
                .collect();
            v.push(format!(
                "Cramér–Rao std (of the nominal value), best design -> worst: {}",
                each.join(", ")
            ));
        }
        v
    }

    fn row(&self, i: usize, r: &RankedDesign) -> String {
        let [drive, level, signal, band, sensors, harm] =
            describe_design(&self.candidates, &self.sweeps, r);
        let std: Vec<String> = r
            .summary
            .std
            .iter()
            .map(|s| format!("{:>13.4}%", 100.0 * s))
            .collect();
        let pair = r.summary.most_collinear.map_or(String::new(), |(a, b, c)| {
            format!("{} ~ {} ({c:+.3})", self.params[a], self.params[b])
        });
        format!(
            "{:>6}  {:<10} {:>9} {:<10} {:<26} {:<16} {:<6} {:>12.5e}  {}  {:>8.2}  {}",
            i + 1,
            drive,
            level,
            signal,
            band,
            sensors,
            harm,
            r.summary.value(self.request.criterion),
            std.join(" "),
            r.summary.collinearity,
            pair
        )
    }

    /// Every design, best first: what it is, every criterion, rank, the Cramér–Rao relative
    /// standard deviations and the collinearity.
    pub fn ranking_csv(&self) -> String {
        let params = &self.params;
        let mut s = String::from(
            "rank,sweep,drive,level_n,signal,band,from_hz,to_hz,steps,sensors,harmonics,\
             log_det,trace,trace_inverse,min_eigenvalue,max_variance,fim_rank,collinearity,\
             most_collinear,cosine",
        );
        for p in params {
            let _ = write!(s, ",std_{p}");
        }
        s.push('\n');
        for (i, r) in self.ranked.iter().enumerate() {
            let c = &self.candidates.sweeps[r.design.sweep];
            let [drive, level, signal, _, sensors, harm] =
                describe_design(&self.candidates, &self.sweeps, r);
            let m = &r.summary;
            let (pair, cos) = m
                .most_collinear
                .map_or((String::new(), f64::NAN), |(a, b, c)| {
                    (format!("{}~{}", params[a], params[b]), c)
                });
            let _ = write!(
                s,
                "{},{},{},{},{},{},{:?},{:?},{},{},{},{:?},{:?},{:?},{:?},{:?},{},{:?},{},{:?}",
                i + 1,
                r.design.sweep + 1,
                csv_field(&drive),
                level,
                csv_field(&signal),
                csv_field(&c.band.label),
                c.band.from_hz,
                c.band.to_hz,
                c.band.steps,
                csv_field(&sensors),
                harm,
                m.log_det,
                m.trace,
                m.trace_inverse,
                m.min_eigenvalue,
                m.max_variance,
                m.rank,
                m.collinearity,
                pair,
                cos
            );
            for x in &m.std {
                let _ = write!(s, ",{x:?}");
            }
            s.push('\n');
        }
        s
    }
}

fn criterion_desc(c: Criterion) -> &'static str {
    match c {
        Criterion::D => "D-optimality (ln det F, larger is better)",
        Criterion::T => "T-optimality (tr F, larger is better)",
        Criterion::A => "A-optimality (tr F^-1, smaller is better)",
        Criterion::E => "E-optimality (smallest eigenvalue, larger is better)",
        Criterion::MaxVariance => "the largest relative variance max diag F^-1 (smaller is better)",
    }
}

/// A CSV field, quoted when it holds a comma or a quote.
fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// Writes the report of `run` into `dir` (created if needed): `summary.txt`,
/// `ranking.csv` (every design), `fim_best.csv` (the best design's information, readable
/// as the `prior` of the next plan), `best_test.toml` (the best design as an `nlsim test`
/// file, [`PlanRun::test_file`]) and plots (SVG and PNG): the criterion along the
/// ranking (`ranking`), the Cramér–Rao standard deviations of the best five designs and
/// the worst (`crb`), and the best design's predicted responses (`best_prediction`).
/// Returns the files written.
pub fn write_plan_report(dir: &Path, run: &PlanRun) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut written = Vec::new();
    let mut text = |name: &str, body: String| -> Result<()> {
        let p = dir.join(name);
        write_text(&p, &body)?;
        written.push(p);
        Ok(())
    };
    let report = crate::report::Report::create(
        dir,
        &format!("nlsim plan: {}", run.candidates.model_name),
        &crate::report::command_line(),
        &run.request.model,
    )?;
    report.section_with("Summary", &run.summary());
    report.table(
        "ranking",
        crate::report::Table::from_csv("Candidate tests, best first", &run.ranking_csv()),
    )?;
    report.section("Figures");
    let mut summary = run.summary().join("\n");
    summary.push('\n');
    text("summary.txt", summary)?;
    text("ranking.csv", run.ranking_csv())?;
    let params = &run.params;
    let Some(best) = run.ranked.first() else {
        written.push(report.finish()?);
        written.push(dir.join(crate::report::DATA));
        return Ok(written);
    };
    text("fim_best.csv", fim_csv(params, &run.fim(best)))?;
    text("best_test.toml", run.test_file(best))?;
    let crit = run.request.criterion;
    written.extend(report.figure(
        "ranking",
        &Lines {
            title: format!(
                "{}: {} candidate tests ranked by {}",
                run.candidates.model_name,
                run.ranked.len(),
                crit.as_str()
            ),
            x_desc: "rank".into(),
            y_desc: format!("{} criterion (relative units)", crit.as_str()),
            series: vec![(
                crit.as_str().into(),
                run.ranked
                    .iter()
                    .enumerate()
                    .map(|(i, r)| ((i + 1) as f64, r.summary.value(crit)))
                    .filter(|p| p.1.is_finite())
                    .collect(),
            )],
        },
    )?);
    let mut shown: Vec<&RankedDesign> = run.ranked.iter().take(5).collect();
    if run.ranked.len() > 5 {
        shown.push(run.ranked.last().expect("non-empty"));
    }
    let groups = params
        .iter()
        .enumerate()
        .map(|(j, p)| BarGroup {
            label: p.to_string(),
            values: shown
                .iter()
                .map(|r| {
                    let s = 100.0 * r.summary.std[j];
                    if s.is_finite() { s } else { f64::NAN }
                })
                .collect(),
            band: None,
        })
        .collect();
    written.extend(report.figure(
        "crb",
        &Bars {
            title: format!(
                "{}: Cramér–Rao std of the best {} designs{}",
                run.candidates.model_name,
                shown.len().min(5),
                if run.ranked.len() > 5 {
                    " and the worst (right)"
                } else {
                    ""
                }
            ),
            bar_desc: "design".into(),
            y_desc: "std (% of the nominal value)".into(),
            baseline: 0.0,
            band_desc: String::new(),
            groups,
        },
    )?);
    let sw = &run.sweeps[best.design.sweep];
    let freqs = sw.band.frequencies_hz();
    let mut series = Vec::new();
    for &c in &best.design.channels {
        for &h in &best.design.harmonics {
            let k = sw.harmonics[h];
            series.push((
                format!("{} h{k}", sw.channels[c]),
                freqs
                    .iter()
                    .zip(&sw.responses)
                    .filter_map(|(&f, y)| {
                        let v = y[(c, k - 1)].norm();
                        (v.is_finite() && !sw.failed_hz.contains(&f)).then_some((f, v))
                    })
                    .collect(),
            ));
        }
    }
    series.retain(|(_, p): &(String, Vec<(f64, f64)>)| !p.is_empty());
    if !series.is_empty() {
        written.extend(report.figure(
            "best_prediction",
            &Lines {
                title: format!(
                    "{}: predicted responses of the best test ({})",
                    run.candidates.model_name,
                    sw.exciter.describe()
                ),
                x_desc: "frequency (Hz)".into(),
                y_desc: "|response harmonic| (sensor units)".into(),
                series,
            },
        )?);
    }
    written.push(report.finish()?);
    written.push(dir.join(crate::report::DATA));
    Ok(written)
}

/// Writes the information of one candidate sweep into a batch job's group: datasets
/// `terms` (channels × harmonics × parameters × parameters, relative units), `failed_hz`
/// and `nominal` (the parameters' values), attributes `exciter` and `band`.
pub(crate) fn write_sweep_group(
    g: &hdf5_metno::Group,
    info: &SweepInformation,
    nominal: &[f64],
) -> hdf5_metno::Result<()> {
    let nc = info.terms.len();
    let nh = info.harmonics.len();
    let np = nominal.len();
    let mut flat = Vec::with_capacity(nc * nh * np * np);
    for c in &info.terms {
        for m in c {
            for i in 0..np {
                for j in 0..np {
                    flat.push(m[(i, j)]);
                }
            }
        }
    }
    let d = g
        .new_dataset::<f64>()
        .shape((nc, nh, np, np))
        .create("terms")?;
    d.write_raw(&flat)?;
    crate::output::str_attr(
        &d,
        "dims",
        "channel x measured harmonic x parameter x parameter (relative units)",
    )?;
    g.new_dataset::<f64>()
        .shape(info.failed_hz.len())
        .create("failed_hz")?
        .write_raw(&info.failed_hz)?;
    g.new_dataset::<f64>()
        .shape(np)
        .create("nominal")?
        .write_raw(nominal)?;
    crate::output::str_attr(g, "exciter", &info.exciter.describe())?;
    crate::output::str_attr(g, "band", &info.band.label)
}

/// Reads back candidate sweep `i` of `c` from a batch job's group (shapes checked against
/// the plan before reading); `None` when the job failed or does not match.
fn read_sweep_group(
    g: &hdf5_metno::Group,
    c: &PlanCandidates,
    i: usize,
    np: usize,
) -> Option<(SweepInformation, Vec<f64>)> {
    if g.attr("ok").and_then(|a| a.read_scalar::<u8>()).ok() != Some(1) {
        return None;
    }
    let (nc, nh) = (c.channels.len(), c.harmonics.len());
    let terms = g.dataset("terms").ok()?;
    if terms.shape() != [nc, nh, np, np] {
        return None;
    }
    let failed = g.dataset("failed_hz").ok()?;
    let nominal = g.dataset("nominal").ok()?;
    let sw = c.sweeps.get(i)?;
    if failed.shape().first().copied().unwrap_or(0) > sw.band.steps || nominal.shape() != [np] {
        return None;
    }
    let flat = terms.read_raw::<f64>().ok()?;
    let mut at = 0;
    let terms = (0..nc)
        .map(|_| {
            (0..nh)
                .map(|_| {
                    let m = Mat::from_fn(np, np, |a, b| flat[at + a * np + b]);
                    at += np * np;
                    m
                })
                .collect()
        })
        .collect();
    Some((
        SweepInformation {
            exciter: sw.exciter.clone(),
            band: sw.band.clone(),
            channels: c.channels.clone(),
            harmonics: c.harmonics.clone(),
            terms,
            responses: Vec::new(),
            failed_hz: failed.read_raw::<f64>().ok()?,
        },
        nominal.read_raw::<f64>().ok()?,
    ))
}

/// The plan of a merged `plan-candidates` batch: every job's sweep read back from `jobs`
/// (`jobs[i]` the group of job `i`) and every design ranked. `Err` names the first job
/// that failed.
pub(crate) fn merged_plan(req: &PlanRequest, jobs: &[hdf5_metno::Group]) -> Result<PlanRun> {
    let t = Instant::now();
    let (_, candidates) = plan_candidates(req)?;
    let np = req.params.len();
    if jobs.len() != candidates.sweeps.len() {
        return Err(Error::Failed(format!(
            "{} jobs for {} candidate sweeps",
            jobs.len(),
            candidates.sweeps.len()
        )));
    }
    let mut sweeps = Vec::with_capacity(jobs.len());
    let mut nominal = Vec::new();
    for (i, g) in jobs.iter().enumerate() {
        let (info, nom) = read_sweep_group(g, &candidates, i, np).ok_or_else(|| {
            Error::Failed(format!(
                "job {i} (sweep {}) failed or does not match the plan; rerun its shard",
                i + 1
            ))
        })?;
        sweeps.push(info);
        nominal = nom;
    }
    let setup_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let ranked = rank(&candidates, &sweeps, req.criterion)?;
    Ok(PlanRun {
        request: req.clone(),
        candidates,
        params: req.params.clone(),
        nominal,
        setup_seconds,
        sweeps,
        ranked,
        sweep_seconds: 0.0,
        rank_seconds: t.elapsed().as_secs_f64(),
    })
}

/// Writes the ranking of a merged plan into `out`: group `ranking` with, per design best
/// first, `sweep` (job index), `value` (of the criterion, attribute `criterion`),
/// `log_det`, `collinearity` and `std` (designs × parameters, relative).
pub(crate) fn write_ranking(out: &hdf5_metno::Group, run: &PlanRun) -> hdf5_metno::Result<()> {
    let g = out.create_group("ranking")?;
    crate::output::str_attr(&g, "criterion", run.request.criterion.as_str())?;
    let names: Vec<String> = run.params.iter().map(|p| p.to_string()).collect();
    crate::output::str_attr(&g, "parameters", &names.join(","))?;
    let n = run.ranked.len();
    let sweep: Vec<u64> = run.ranked.iter().map(|r| r.design.sweep as u64).collect();
    g.new_dataset::<u64>()
        .shape(n)
        .create("sweep")?
        .write_raw(&sweep)?;
    let crit = run.request.criterion;
    for (name, f) in [
        (
            "value",
            &(|r: &RankedDesign| r.summary.value(crit)) as &dyn Fn(&RankedDesign) -> f64,
        ),
        ("log_det", &|r: &RankedDesign| r.summary.log_det),
        ("collinearity", &|r: &RankedDesign| r.summary.collinearity),
    ] {
        let v: Vec<f64> = run.ranked.iter().map(f).collect();
        g.new_dataset::<f64>()
            .shape(n)
            .create(name)?
            .write_raw(&v)?;
    }
    let np = run.params.len();
    let std: Vec<f64> = run
        .ranked
        .iter()
        .flat_map(|r| r.summary.std.iter().copied())
        .collect();
    g.new_dataset::<f64>()
        .shape((n, np))
        .create("std")?
        .write_raw(&std)?;
    Ok(())
}

/// `s` as a TOML basic string (quotes, backslashes and control characters escaped).
fn toml_string(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for ch in s.chars() {
        match ch {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            c if c.is_control() => {
                let _ = write!(o, "\\u{:04X}", c as u32);
            }
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

#[cfg(test)]
mod tests {
    use super::*;

    const PLAN: &str = r#"
params = ["tip.k3", "mode1.zeta"]
levels = [0.1, 0.2]
measured = [[1], [1, 3]]

[[band]]
label = "across"
from = 30.0
to = 36.0
steps = 5
"#;

    #[test]
    fn a_plan_file_reads_into_its_request() {
        let r = PlanRequest::parse(PLAN, Path::new("/p/plan.toml"), "ecl_beam").unwrap();
        assert_eq!(r.params.len(), 2);
        assert_eq!(r.levels, vec![0.1, 0.2]);
        assert_eq!(r.measured, vec![vec![1], vec![1, 3]]);
        assert_eq!(r.bands[0].steps, 5);
        assert_eq!(r.criterion, Criterion::D);
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let cases = [
            (PLAN.replace("steps = 5", "steps = 5\nbogus = 1"), "bogus"),
            (
                PLAN.replace("levels = [0.1, 0.2]", "levels = [0.1, -2.0]"),
                "levels",
            ),
            (PLAN.replace("[[1], [1, 3]]", "[[1], [1, 5]]"), "measured"),
            (
                PLAN.replace("levels", "criterion = \"Q\"\nlevels"),
                "criterion",
            ),
            (
                PLAN.replace("levels", "noise = { absolute = 0.0 }\nlevels"),
                "noise",
            ),
        ];
        for (text, key) in cases {
            let e = PlanRequest::parse(&text, Path::new("plan.toml"), "m").unwrap_err();
            let msg = e.to_string();
            let line = text
                .lines()
                .position(|l| l.trim_start().starts_with(key))
                .unwrap()
                + 1;
            assert!(
                msg.starts_with(&format!("plan.toml:{line}:")) && msg.contains(key),
                "{key}: {msg}"
            );
        }
    }

    #[test]
    fn binomial_counts_subsets_and_overflows_to_none() {
        for (n, k) in [(5, 2), (7, 0), (7, 7), (10, 3)] {
            assert_eq!(binomial(n, k), Some(subsets(n, k).len()));
        }
        assert_eq!(binomial(10_000, 5000), None);
    }

    #[test]
    fn a_prior_reads_back_by_name_and_must_be_symmetric() {
        let params: Vec<Param> = vec!["a.k".parse().unwrap(), "b.c".parse().unwrap()];
        let f = Mat::from_fn(2, 2, |i, j| [[4.0, 1.0], [1.0, 3.0]][i][j]);
        let dir = std::env::temp_dir().join(format!("nlsim-prior-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("fim.csv");
        std::fs::write(&p, fim_csv(&params, &f)).unwrap();
        // The parameters in the other order: the matrix is permuted by name.
        let swapped = [params[1].clone(), params[0].clone()];
        let g = read_fim_csv(&p, &swapped).unwrap();
        assert_eq!((g[(0, 0)], g[(1, 1)], g[(0, 1)]), (3.0, 4.0, 1.0));
        std::fs::write(&p, "param,a.k,b.c\na.k,4,1\nb.c,2,3\n").unwrap();
        let e = read_fim_csv(&p, &params).unwrap_err().to_string();
        assert!(e.contains("not symmetric"), "{e}");
        std::fs::write(&p, "param,a.k,b.c\na.k,4,1\n").unwrap();
        let e = read_fim_csv(&p, &params).unwrap_err().to_string();
        assert!(e.contains("one row per planned parameter"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn toml_strings_round_trip() {
        #[derive(serde::Deserialize)]
        struct T {
            s: String,
        }
        for text in [
            "plain",
            "a \"quoted\" name",
            "back\\slash",
            "tab\tand\nnewline",
            "é ü",
        ] {
            let t: T = toml::from_str(&format!("s = {}", toml_string(text))).unwrap();
            assert_eq!(t.s, text);
        }
    }
}
