//! The request of `nlsim test` and its test file (TOML, `docs/planning.md`): sweeps, sensors,
//! shaker, force control, noise, seed, where the data go.
use crate::commands::plan::request::PointSpec;
use crate::commands::plan::request::PointTable;
use crate::error::{Error, Result};
use crate::formats::settings::{SettingsFile, ShakerTable};
use nlsim_calib::{ControlConfig, Noise, Shaker, SweepPlan};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Largest relative measurement noise of a virtual test (standard deviation over amplitude),
/// the same as test data's.
pub use nlsim_calib::data::MAX_RELATIVE_NOISE;

/// Most steps of one virtual test (all sweeps).
pub const MAX_TEST_STEPS: usize = 1_000_000;

/// Everything a virtual test needs. Paths are as given (relative to the working directory).
#[derive(Debug, Clone)]
pub struct TestRequest {
    /// Model file or built-in model.
    pub model: String,
    /// Fixed overrides `NAME=VALUE` applied first.
    pub set: Vec<String>,
    /// The model's excitation the shaker drives (`None`: its first, or `drive_dof`).
    pub drive: Option<String>,
    /// A DOF label where the shaker is attached instead (an input `shaker` is added there).
    pub drive_dof: Option<String>,
    /// The stepped sines.
    pub sweeps: Vec<SweepPlan>,
    /// Measured harmonics `1..=harmonics` (also the harmonic balance's `H`).
    pub harmonics: usize,
    /// Retained modes.
    pub modes: usize,
    /// The shaker.
    pub shaker: Shaker,
    /// The force controller.
    pub control: ControlConfig,
    /// Also run the test voltage-driven (the voltage of each sweep's first step held) to
    /// show the force drop-out beside the controlled test.
    pub compare_open_loop: bool,
    /// Response measurement noise: `relative` of the response with an absolute floor of
    /// `noise.absolute` (the sensors' unit) or `noise_floor` times the sensor's largest
    /// noise-free fundamental response over the test, whichever is larger.
    pub noise: Noise,
    /// The response noise floor relative to each sensor's largest noise-free fundamental
    /// response over the test (10⁻³ by default: a 60 dB range, in the sensor's own scale);
    /// 0 when an absolute floor is given alone.
    pub noise_floor: f64,
    /// Force measurement noise.
    pub force_noise: Noise,
    /// Seed of the noise.
    pub seed: u64,
    /// The test data (`.csv` or `.h5`).
    pub out: PathBuf,
    /// Report folder.
    pub report: Option<PathBuf>,
    /// Sensors added to the model's (by DOF label) before the test.
    pub sensors: Vec<PointSpec>,
    /// The sensors recorded in the data, by name; empty: every sensor.
    pub channels: Vec<String>,
    /// The test file this request was read from, if any: an input no output may name.
    pub source: Option<PathBuf>,
    /// What the data record at the drive point: the force (a force gauge), or the voltage
    /// into the amplifier when the lab has no force gauge.
    pub record: nlsim_calib::Drive,
    /// The amplifier's gain (V at the coil per V in) a voltage record is divided by.
    pub amplifier_gain: f64,
    /// Also write the time histories the test would have recorded.
    pub raw: Option<RawRequest>,
}

/// The raw records of a virtual test (`[raw]` in the test file, `--raw FILE`): the time
/// histories its recorder would hold, the shaker coupled in the time domain
/// ([`nlsim_calib::raw_records`]).
#[derive(Debug, Clone, PartialEq)]
pub struct RawRequest {
    /// Where they go: `.csv`, `.h5` or `.uff`/`.unv`; the step table beside it
    /// ([`raw_steps_path`]).
    pub out: PathBuf,
    /// Sampling rate (Hz) [default: [`DEFAULT_SAMPLES_PER_PERIOD`] samples per period of the
    /// highest harmonic at the highest step frequency, rounded up to 100 Hz].
    pub rate_hz: Option<f64>,
    /// Length of every step (s) [default: the settling time of the slowest mode around the
    /// swept band to [`DEFAULT_SETTLE`] of its amplitude, then [`DEFAULT_MEASURED_PERIODS`]
    /// periods of the lowest step frequency, rounded up to 0.1 s].
    pub dwell_s: Option<f64>,
    /// Hold steps per recorded sample [default: enough for [`DEFAULT_HOLD_SAMPLES_PER_PERIOD`]
    /// hold steps per period of the highest harmonic at the highest step frequency].
    pub oversample: Option<usize>,
}

/// Default hold steps per period of the highest harmonic at the highest step frequency (the
/// integration's rate, [`RawRequest::oversample`] times the recording's): the hold carries an
/// element force's harmonic `k` with the gain `sinc²(kωh/2)`, 1.3e-5 short at the highest
/// harmonic and 1.4e-6 at the fundamental of a 3-harmonic test.
pub const DEFAULT_HOLD_SAMPLES_PER_PERIOD: f64 = 512.0;

/// Default recorded samples per period of the highest harmonic at the highest step
/// frequency (the hold integrates more finely: [`DEFAULT_HOLD_SAMPLES_PER_PERIOD`]).
pub const DEFAULT_SAMPLES_PER_PERIOD: f64 = 128.0;

/// Default settling of a step before its measured periods: the slowest mode's transient
/// decays to this fraction of its start.
pub const DEFAULT_SETTLE: f64 = 1e-4;

/// Default periods measured after the settling, at the lowest step frequency.
pub const DEFAULT_MEASURED_PERIODS: f64 = 40.0;

/// The step table beside raw records `out`: `STEM_steps.csv` in its folder.
pub fn raw_steps_path(out: &Path) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "raw".into());
    out.with_file_name(format!("{stem}_steps.csv"))
}

impl TestRequest {
    /// A test of `model` along `sweeps` with the defaults: the model's first excitation, 3
    /// harmonics, 20 modes, [`Shaker::default`], force control at 1 %, the open loop run
    /// too, 2 % response noise with a floor of 10⁻³ of each sensor's largest response, no
    /// force noise, seed 1, data to `virtual_test.csv`.
    pub fn new(model: impl Into<String>, sweeps: Vec<SweepPlan>) -> Self {
        Self {
            model: model.into(),
            set: Vec::new(),
            drive: None,
            drive_dof: None,
            sweeps,
            harmonics: 3,
            modes: 20,
            shaker: Shaker::default(),
            control: ControlConfig::default(),
            compare_open_loop: true,
            noise: Noise::relative(0.02),
            noise_floor: crate::commands::plan::request::DEFAULT_NOISE_FLOOR,
            force_noise: Noise::relative(0.0),
            seed: 1,
            out: PathBuf::from("virtual_test.csv"),
            report: None,
            sensors: Vec::new(),
            channels: Vec::new(),
            source: None,
            record: nlsim_calib::Drive::Force,
            amplifier_gain: 1.0,
            raw: None,
        }
    }

    /// Checks what can be checked without the model.
    pub fn check(&self) -> Result<()> {
        let bad = |field: &str, why: String| Err(Error::Usage(format!("test {field}: {why}")));
        if self.sweeps.is_empty() {
            return bad("sweep", "give at least one [[sweep]]".into());
        }
        let mut steps = 0usize;
        for (i, s) in self.sweeps.iter().enumerate() {
            if let Some(why) = nlsim_calib::data::label_fault(&s.label) {
                return bad("sweep", format!("{}: label {why}", i + 1));
            }
            if self.sweeps[..i].iter().any(|o| o.label == s.label) {
                return bad(
                    "sweep",
                    format!(
                        "'{}' is the label of two sweeps; label each once (the data name sweeps by it)",
                        s.label
                    ),
                );
            }
            if let Some(w) = s.frequencies_hz.windows(2).find(|w| w[0] == w[1]) {
                return bad(
                    "sweep",
                    format!(
                        "'{}': two steps at {} Hz; a sweep goes up or down (from != to)",
                        s.label, w[0]
                    ),
                );
            }
            if let Some(f) = s
                .frequencies_hz
                .iter()
                .find(|f| **f > nlsim_calib::data::MAX_FREQUENCY_HZ)
            {
                return bad(
                    "sweep",
                    format!(
                        "'{}': {f:e} Hz is above {:e} Hz",
                        s.label,
                        nlsim_calib::data::MAX_FREQUENCY_HZ
                    ),
                );
            }
            let ok_f = s.frequencies_hz.iter().all(|f| f.is_finite() && *f > 0.0);
            if !ok_f || s.frequencies_hz.len() < 2 || !(s.force.is_finite() && s.force > 0.0) {
                return bad(
                    "sweep",
                    format!(
                        "'{}': needs positive frequencies, at least 2 steps and a positive force \
                         (got {} steps, {} N)",
                        s.label,
                        s.frequencies_hz.len(),
                        s.force
                    ),
                );
            }
            steps = steps.saturating_add(s.frequencies_hz.len());
        }
        if steps > MAX_TEST_STEPS {
            return bad(
                "sweep",
                format!("{steps} steps in all, more than {MAX_TEST_STEPS}"),
            );
        }
        if self.harmonics == 0 || self.harmonics > 64 {
            return bad("harmonics", format!("{} is not in 1..=64", self.harmonics));
        }
        if self.modes == 0 {
            return bad("modes", "retain at least one mode".into());
        }
        if self.drive.is_some() && self.drive_dof.is_some() {
            return bad(
                "drive",
                "give `drive` (an excitation) or `drive_dof` (a DOF), not both".into(),
            );
        }
        if let Err(e) = self.shaker.check() {
            return bad("shaker", e.to_string());
        }
        if !(self.amplifier_gain.is_finite() && self.amplifier_gain > 0.0) {
            return bad(
                "amplifier_gain",
                format!("{} must be positive and finite", self.amplifier_gain),
            );
        }
        let c = &self.control;
        if !(c.tolerance.is_finite() && c.tolerance > 0.0) || c.max_iterations == 0 {
            return bad(
                "control",
                format!(
                    "needs a positive tolerance and max_iterations >= 1 (got {} and {})",
                    c.tolerance, c.max_iterations
                ),
            );
        }
        if !(self.noise_floor.is_finite() && (0.0..=1.0).contains(&self.noise_floor)) {
            return bad(
                "noise",
                format!(
                    "floor {} (of each sensor's largest response) must be within 0..=1",
                    self.noise_floor
                ),
            );
        }
        for (name, n) in [("noise", self.noise), ("force_noise", self.force_noise)] {
            if !(n.absolute.is_finite()
                && n.relative.is_finite()
                && n.absolute >= 0.0
                && n.relative >= 0.0)
            {
                return bad(
                    name,
                    format!(
                        "absolute {} and relative {} must be non-negative",
                        n.absolute, n.relative
                    ),
                );
            }
            // Noise larger than this is no measurement (and would overflow the data).
            if n.relative > MAX_RELATIVE_NOISE || n.absolute > nlsim_calib::data::MAX_AMPLITUDE {
                return bad(
                    name,
                    format!(
                        "absolute {:e} and relative {:e}: at most {:e} and {MAX_RELATIVE_NOISE} (a standard deviation {MAX_RELATIVE_NOISE} times the amplitude)",
                        n.absolute,
                        n.relative,
                        nlsim_calib::data::MAX_AMPLITUDE
                    ),
                );
            }
        }
        let ext = self.out.extension().and_then(|e| e.to_str()).unwrap_or("");
        if !matches!(ext, "csv" | "h5" | "hdf5") {
            return bad(
                "out",
                format!("{}: name a .csv or .h5 file", self.out.display()),
            );
        }
        if let Some(raw) = &self.raw {
            let ext = raw
                .out
                .extension()
                .and_then(|e| e.to_str())
                .map(str::to_ascii_lowercase);
            if !matches!(ext.as_deref(), Some("csv" | "h5" | "hdf5" | "uff" | "unv")) {
                return bad(
                    "raw",
                    format!(
                        "out {}: name a {}",
                        raw.out.display(),
                        crate::formats::raw_records::HINT
                    ),
                );
            }
            if let Some(m) = raw.oversample
                && !(1..=1024).contains(&m)
            {
                return bad(
                    "raw",
                    format!("oversample {m}: give 1 to 1024 hold steps per sample"),
                );
            }
            for (what, v) in [("rate", raw.rate_hz), ("dwell", raw.dwell_s)] {
                if let Some(v) = v
                    && !(v.is_finite() && v > 0.0)
                {
                    return bad("raw", format!("{what} {v} must be positive and finite"));
                }
            }
            if raw.out == self.out || raw_steps_path(&raw.out) == self.out {
                return bad(
                    "raw",
                    format!(
                        "out {}: the raw records and their step table need names of their own \
                         (the test data go to {})",
                        raw.out.display(),
                        self.out.display()
                    ),
                );
            }
        }
        Ok(())
    }

    /// Reads a test file for `model` (the module docs show one).
    pub fn load(path: &Path, model: &str) -> Result<Self> {
        let text = crate::formats::files::read_text_bounded(
            path,
            crate::commands::plan::request::MAX_SETTINGS_BYTES,
        )?;
        Self::parse(&text, path, model)
    }

    /// Parses test-file text for `model`; `path` names it in errors, and relative paths in
    /// it are taken from its folder.
    pub fn parse(text: &str, path: &Path, model: &str) -> Result<Self> {
        let t: TestTable = SettingsFile::parse(text, path)?;
        t.into_request(model.to_string(), text, path)
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct NoiseTable {
    relative: Option<f64>,
    absolute: Option<f64>,
    floor: Option<f64>,
}

impl NoiseTable {
    fn get(t: &Option<NoiseTable>, d: Noise) -> Noise {
        t.as_ref().map_or(d, |n| Noise {
            absolute: n.absolute.unwrap_or(0.0),
            relative: n.relative.unwrap_or(0.0),
        })
    }

    /// The floor relative to the response: as given; else 0 beside an absolute floor, the
    /// default `d` otherwise.
    fn floor(t: &Option<NoiseTable>, d: f64) -> f64 {
        t.as_ref().map_or(d, |n| {
            n.floor
                .unwrap_or(if n.absolute.is_some() { 0.0 } else { d })
        })
    }
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct SweepTable {
    label: Option<String>,
    from: f64,
    to: f64,
    steps: usize,
    force: f64,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawTable {
    out: Option<String>,
    rate: Option<f64>,
    dwell: Option<f64>,
    oversample: Option<usize>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ControlTable {
    enabled: Option<bool>,
    tolerance: Option<f64>,
    max_iterations: Option<usize>,
    static_force: Option<bool>,
    compare_open_loop: Option<bool>,
}

/// A test file.
#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TestTable {
    #[serde(default)]
    set: BTreeMap<String, f64>,
    drive: Option<String>,
    drive_dof: Option<String>,
    harmonics: Option<usize>,
    modes: Option<usize>,
    seed: Option<u64>,
    noise: Option<NoiseTable>,
    force_noise: Option<NoiseTable>,
    out: Option<String>,
    report: Option<String>,
    shaker: Option<ShakerTable>,
    control: Option<ControlTable>,
    #[serde(default)]
    sweep: Vec<SweepTable>,
    #[serde(default)]
    sensor: Vec<PointTable>,
    #[serde(default)]
    channels: Vec<String>,
    record: Option<String>,
    amplifier_gain: Option<f64>,
    raw: Option<RawTable>,
}

impl TestTable {
    fn into_request(self, model: String, text: &str, path: &Path) -> Result<TestRequest> {
        let file = SettingsFile { text, path };
        let err = |key: &str, message: String| file.err(key, message);
        let rel = |p: &str| file.rel(p);
        let d = TestRequest::new("", Vec::new());
        let shaker = ShakerTable::shaker(self.shaker.as_ref());
        let dc = ControlConfig::default();
        let (control, compare) = match &self.control {
            None => (dc, d.compare_open_loop),
            Some(c) => (
                ControlConfig {
                    enabled: c.enabled.unwrap_or(dc.enabled),
                    tolerance: c.tolerance.unwrap_or(dc.tolerance),
                    max_iterations: c.max_iterations.unwrap_or(dc.max_iterations),
                    static_force: c.static_force.unwrap_or(dc.static_force),
                },
                c.compare_open_loop.unwrap_or(d.compare_open_loop),
            ),
        };
        let enabled = control.enabled;
        let sensors = self
            .sensor
            .iter()
            .map(|p| p.spec(&file, "sensor"))
            .collect::<Result<Vec<_>>>()?;
        let mut sweeps = Vec::with_capacity(self.sweep.len());
        for (i, s) in self.sweep.iter().enumerate() {
            if !(2..=100_000).contains(&s.steps) {
                return Err(err(
                    "steps",
                    format!("sweep {}: {} steps, expected 2 to 100000", i + 1, s.steps),
                ));
            }
            let label = s
                .label
                .clone()
                .unwrap_or_else(|| format!("{} N {:.6}-{:.6} Hz", s.force, s.from, s.to));
            sweeps.push(SweepPlan::linear(label, s.from, s.to, s.steps, s.force));
        }
        let record = match self.record.as_deref() {
            None => d.record,
            Some(r) => nlsim_calib::Drive::parse(r).ok_or_else(|| {
                err(
                    "record",
                    format!("'{r}': the drive is recorded as force or voltage"),
                )
            })?,
        };
        let req = TestRequest {
            model,
            set: self.set.iter().map(|(k, v)| format!("{k}={v:e}")).collect(),
            drive: self.drive,
            drive_dof: self.drive_dof,
            sweeps,
            harmonics: self.harmonics.unwrap_or(d.harmonics),
            modes: self.modes.unwrap_or(d.modes),
            shaker,
            control,
            compare_open_loop: compare && enabled,
            noise: NoiseTable::get(&self.noise, d.noise),
            noise_floor: NoiseTable::floor(&self.noise, d.noise_floor),
            force_noise: NoiseTable::get(&self.force_noise, d.force_noise),
            seed: self.seed.unwrap_or(d.seed),
            out: rel(self.out.as_deref().unwrap_or("virtual_test.csv")),
            report: self.report.as_deref().map(rel),
            sensors,
            channels: self.channels,
            source: Some(path.to_path_buf()),
            record,
            amplifier_gain: self.amplifier_gain.unwrap_or(d.amplifier_gain),
            raw: self.raw.as_ref().map(|r| RawRequest {
                out: rel(r.out.as_deref().unwrap_or("raw.csv")),
                rate_hz: r.rate,
                dwell_s: r.dwell,
                oversample: r.oversample,
            }),
        };
        req.check().map_err(|e| file.located("test", e))?;
        Ok(req)
    }
}
