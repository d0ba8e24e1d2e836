//! The request of `nlsim plan` and its plan file (TOML, `docs/planning.md`): parameters,
//! criterion, candidate drive points, levels, signals, bands, sensor sets, harmonics, noise.
use crate::error::{Error, Result};
use crate::formats::settings::SettingsFile;
use nlsim_calib::{Band, Criterion, Noise, SideTone};
use nlsim_kernel::{Param, Quantity};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Largest plan, test or prior file read (bytes).
pub const MAX_SETTINGS_BYTES: u64 = 1 << 20;
/// Most candidate designs one plan ranks (each keeps its information summary, ~0.3 kB with
/// a few parameters): more is a batch (`plan-candidates`, docs/batch.md) or a greedy search.
pub const MAX_DESIGNS: usize = 2_000_000;
/// Most predicted stepped-sine steps of one plan (candidate sweeps × steps).
pub const MAX_STEPS: usize = 1_000_000;
/// Most parameters planned for.
pub const MAX_PARAMS: usize = 64;

/// Default noise floor of a plan: 10⁻³ of each channel's largest predicted response.
pub const DEFAULT_NOISE_FLOOR: f64 = 1e-3;

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
    /// Measurement noise of every channel: `relative` of the response, with an absolute
    /// floor of `noise.absolute` (the sensors' unit) or `noise_floor` times the channel's
    /// largest predicted response, whichever is larger.
    pub noise: Noise,
    /// The noise floor relative to each channel's largest predicted fundamental response
    /// over the candidate tests at the largest level (10⁻³: a 60 dB range): the floor in
    /// the sensor's own scale whatever its quantity. 0 when an absolute floor is given alone.
    pub noise_floor: f64,
    /// Ranking criterion.
    pub criterion: Criterion,
    /// Information of an earlier test (CSV written by a plan report as `fim_best.csv`).
    pub prior: Option<PathBuf>,
    /// Rows of the summary table.
    pub top: usize,
    /// Report folder.
    pub report: Option<PathBuf>,
    /// The plan (or jobs) file this request was read from, if any: an input no output
    /// may name.
    pub source: Option<PathBuf>,
}

impl PlanRequest {
    /// A plan of `params` of `model` over `bands` with the defaults: the model's drive points,
    /// sensors and force, a pure sine, the fundamental measured, noise 1 % with a floor of
    /// 10⁻³ of each channel's largest predicted response, H = 3, 20 modes, D-optimality,
    /// 10 rows.
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
                absolute: 0.0,
                relative: 0.01,
            },
            noise_floor: DEFAULT_NOISE_FLOOR,
            criterion: Criterion::D,
            prior: None,
            top: 10,
            report: None,
            source: None,
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
        let max = nlsim_calib::data::MAX_AMPLITUDE;
        if let Some(l) = self.levels.iter().find(|l| !(1.0 / max..=max).contains(*l)) {
            return bad(
                "levels",
                format!("{l:e} N is outside {:e} to {max:e} N", 1.0 / max),
            );
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
        let f = self.noise_floor;
        if !(n.absolute.is_finite() && n.absolute >= 0.0 && n.relative.is_finite())
            || n.relative < 0.0
            || n.absolute > nlsim_calib::data::MAX_AMPLITUDE
            || n.relative > nlsim_calib::data::MAX_RELATIVE_NOISE
            || !(f.is_finite() && (0.0..=1.0).contains(&f))
            || (n.absolute == 0.0 && f == 0.0)
        {
            return bad(
                "noise",
                format!(
                    "needs a floor: absolute {:e} (the sensors' unit, at most {:e}) or floor \
                     {:e} (of each channel's largest predicted response, 0 to 1), one of them \
                     positive — without a floor a harmonic the model predicts as nearly zero \
                     would weigh without bound; relative {:e} within 0..={}",
                    n.absolute,
                    nlsim_calib::data::MAX_AMPLITUDE,
                    f,
                    n.relative,
                    nlsim_calib::data::MAX_RELATIVE_NOISE
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
        let text = crate::formats::files::read_text_bounded(path, MAX_SETTINGS_BYTES)?;
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
    floor: Option<f64>,
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
        let (noise, noise_floor) = match &self.noise {
            None => (d.noise, d.noise_floor),
            Some(n) => (
                Noise {
                    absolute: n.absolute.unwrap_or(d.noise.absolute),
                    relative: n.relative.unwrap_or(d.noise.relative),
                },
                // An absolute floor given alone is the floor; a relative one joins it only
                // when given too.
                n.floor.unwrap_or(if n.absolute.is_some() {
                    0.0
                } else {
                    d.noise_floor
                }),
            ),
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
            noise_floor,
            criterion,
            prior: self.prior.as_deref().map(rel),
            top: self.top.unwrap_or(d.top),
            report: self.report.as_deref().map(rel),
            source: Some(path.to_path_buf()),
        };
        req.check().map_err(|e| file.located("plan", e))?;
        Ok(req)
    }
}
