//! `nlsim test MODEL TEST` as library calls: a virtual stepped-sine test through an
//! electrodynamic shaker model (thesis §4.4, Fig. 11), voltage-driven or with the off-line
//! force controller, written as test data in the format `nlsim calibrate` reads.
//!
//! A test file (`docs/planning.md`):
//!
//! ```toml
//! drive = "tip"                # the model's excitation the shaker drives (or drive_dof)
//! harmonics = 3                # measured harmonics (and the harmonic balance's H)
//! seed = 1                     # measurement noise
//! noise = { relative = 0.02 }  # response noise
//! out = "virtual_test.csv"     # .csv or .h5
//! channels = ["tip", "n7"]     # the sensors recorded [default: every sensor]
//!
//! [[sensor]]                   # sensors beside the model's
//! name = "n7"
//! dof = "7:uz"
//! quantity = "acceleration"
//!
//! [shaker]                     # any of the fields of nlsim_calib::Shaker
//! armature_mass = 0.03
//!
//! [control]                    # the off-line force controller
//! enabled = true
//! tolerance = 0.01
//!
//! [[sweep]]
//! label = "0.2 N up"
//! from = 30.0
//! to = 36.0
//! steps = 21
//! force = 0.2
//! ```

use crate::calibration::SettingsFile;
use crate::error::{Error, Result};
use crate::output::write_text_atomically as write_text;
use crate::plot::Lines;
use crate::pretest::{PointSpec, PointTable};
use nlsim_calib::{ControlConfig, Noise, Shaker, SweepPlan, VirtualTest, virtual_test};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Excitation, Status};
use serde::Deserialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

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
    /// Response measurement noise.
    pub noise: Noise,
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
}

impl TestRequest {
    /// A test of `model` along `sweeps` with the defaults: the model's first excitation, 3
    /// harmonics, 20 modes, [`Shaker::default`], force control at 1 %, the open loop run
    /// too, 2 % response noise, no force noise, seed 1, data to `virtual_test.csv`.
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
            force_noise: Noise::relative(0.0),
            seed: 1,
            out: PathBuf::from("virtual_test.csv"),
            report: None,
            sensors: Vec::new(),
            channels: Vec::new(),
        }
    }

    /// Checks what can be checked without the model.
    pub fn check(&self) -> Result<()> {
        let bad = |field: &str, why: String| Err(Error::Usage(format!("test {field}: {why}")));
        if self.sweeps.is_empty() {
            return bad("sweep", "give at least one [[sweep]]".into());
        }
        let mut steps = 0usize;
        for s in &self.sweeps {
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
        }
        let ext = self.out.extension().and_then(|e| e.to_str()).unwrap_or("");
        if !matches!(ext, "csv" | "h5" | "hdf5") {
            return bad(
                "out",
                format!("{}: name a .csv or .h5 file", self.out.display()),
            );
        }
        Ok(())
    }

    /// Reads a test file for `model` (the module docs show one).
    pub fn load(path: &Path, model: &str) -> Result<Self> {
        let text = crate::output::read_text_bounded(path, crate::pretest::MAX_SETTINGS_BYTES)?;
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
}

impl NoiseTable {
    fn get(t: &Option<NoiseTable>, d: Noise) -> Noise {
        t.as_ref().map_or(d, |n| Noise {
            absolute: n.absolute.unwrap_or(0.0),
            relative: n.relative.unwrap_or(0.0),
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
struct ShakerTable {
    armature_mass: Option<f64>,
    suspension_stiffness: Option<f64>,
    suspension_damping: Option<f64>,
    resistance: Option<f64>,
    inductance: Option<f64>,
    force_constant: Option<f64>,
    stinger_stiffness: Option<f64>,
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
}

impl TestTable {
    fn into_request(self, model: String, text: &str, path: &Path) -> Result<TestRequest> {
        let file = SettingsFile { text, path };
        let err = |key: &str, message: String| file.err(key, message);
        let rel = |p: &str| file.rel(p);
        let d = TestRequest::new("", Vec::new());
        let ds = Shaker::default();
        let shaker = match &self.shaker {
            None => ds,
            Some(s) => Shaker {
                armature_mass: s.armature_mass.unwrap_or(ds.armature_mass),
                suspension_stiffness: s.suspension_stiffness.unwrap_or(ds.suspension_stiffness),
                suspension_damping: s.suspension_damping.unwrap_or(ds.suspension_damping),
                resistance: s.resistance.unwrap_or(ds.resistance),
                inductance: s.inductance.unwrap_or(ds.inductance),
                force_constant: s.force_constant.unwrap_or(ds.force_constant),
                stinger_stiffness: s.stinger_stiffness.unwrap_or(ds.stinger_stiffness),
            },
        };
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
            force_noise: NoiseTable::get(&self.force_noise, d.force_noise),
            seed: self.seed.unwrap_or(d.seed),
            out: rel(self.out.as_deref().unwrap_or("virtual_test.csv")),
            report: self.report.as_deref().map(rel),
            sensors,
            channels: self.channels,
        };
        req.check().map_err(|e| file.located("test", e))?;
        Ok(req)
    }
}

/// A finished virtual test.
pub struct TestRun {
    /// The request.
    pub request: TestRequest,
    /// The model's name.
    pub model_name: String,
    /// The input the shaker drives.
    pub drive: String,
    /// The test as asked (controlled, unless control is off).
    pub test: VirtualTest,
    /// The same test voltage-driven, when compared.
    pub open_loop: Option<VirtualTest>,
    /// Wall time of loading and reduction (s).
    pub setup_seconds: f64,
    /// Wall time of the tests (s).
    pub seconds: f64,
}

/// Runs `req`: the model loaded and reduced, the stepped sines through the shaker (and
/// again voltage-driven when compared), the data written to `req.out`.
/// `progress(sweep, sweeps)` before each sweep of the test.
pub fn run_test(req: &TestRequest, progress: &mut dyn FnMut(usize, usize)) -> Result<TestRun> {
    req.check()?;
    let t = Instant::now();
    let mut model = crate::run::load_for_run(&req.model, &req.set)?;
    let drive = match (&req.drive, &req.drive_dof) {
        (_, Some(dof)) => {
            let d = model.dofs().find(dof).map_err(|e| {
                Error::Usage(format!(
                    "test drive_dof '{dof}' is not in '{}': {e}",
                    model.name()
                ))
            })?;
            model.add_excitation(Excitation {
                name: "shaker".into(),
                dof: d,
                amplitude: 0.0,
                harmonics: Vec::new(),
            })?;
            "shaker".to_string()
        }
        (Some(name), None) => name.clone(),
        (None, None) => model
            .excitation()
            .first()
            .map(|e| e.name.clone())
            .ok_or_else(|| {
                Error::Usage(format!(
                    "test: '{}' has no excitation; give drive_dof = \"NODE:DIR\"",
                    model.name()
                ))
            })?,
    };
    crate::pretest::add_sensors(&mut model, &req.sensors, "test sensor")?;
    if model.sensors().is_empty() {
        return Err(Error::Usage(format!(
            "test: '{}' has no sensor to measure",
            model.name()
        )));
    }
    for name in &req.channels {
        if !model.sensors().iter().any(|s| &s.name == name) {
            let have: Vec<&str> = model.sensors().iter().map(|s| s.name.as_str()).collect();
            return Err(Error::Usage(format!(
                "test channels: '{name}' is not a sensor of '{}' (it has {}; add one with \
                 [[sensor]])",
                model.name(),
                have.join(", ")
            )));
        }
    }
    // Sequential reduction: the test data are bit-identical whatever the thread count.
    let mut reduction = nlsim_reduction::ReductionConfig::lowest(req.modes.min(model.n_dofs()));
    reduction.eigen.par = faer::Par::Seq;
    let reduced = nlsim_reduction::reduce(&model, &reduction)?;
    let sys = HbSystem::from_model(
        &model,
        &reduced,
        HarmonicSet::new(req.harmonics, 1)?,
        HbConfig::default(),
    )?;
    let setup_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    // One sweep at a time (for progress); the noise seed of sweep `s` is `seed + s`, so a
    // test of several sweeps is the same whichever are run.
    let run = |control: &ControlConfig, progress: &mut dyn FnMut(usize, usize)| {
        let mut out: Option<VirtualTest> = None;
        for (s, plan) in req.sweeps.iter().enumerate() {
            progress(s, req.sweeps.len());
            let one = virtual_test(
                &sys,
                &drive,
                &req.shaker,
                std::slice::from_ref(plan),
                req.harmonics,
                control,
                req.noise,
                req.force_noise,
                req.seed.wrapping_add(s as u64),
            )?;
            match &mut out {
                None => out = Some(one),
                Some(o) => {
                    o.data.sweeps.extend(one.data.sweeps);
                    o.steps.extend(one.steps);
                }
            }
        }
        Ok::<_, Error>(out.expect("at least one sweep"))
    };
    // Every sensor is simulated; the data keep the recorded channels.
    let keep = |mut t: VirtualTest| -> Result<VirtualTest> {
        if !req.channels.is_empty() {
            let names: Vec<&str> = req.channels.iter().map(String::as_str).collect();
            t.data = t.data.select_channels(&names)?;
        }
        Ok(t)
    };
    let test = keep(run(&req.control, progress)?)?;
    let open_loop = if req.compare_open_loop {
        let open = ControlConfig {
            enabled: false,
            ..req.control
        };
        Some(keep(run(&open, &mut |_, _| {})?)?)
    } else {
        None
    };
    let seconds = t.elapsed().as_secs_f64();
    if test.data.sweeps.iter().all(|s| s.steps.is_empty()) {
        return Err(Error::Failed(
            "virtual test: the structure could not be solved at any step; nothing to write".into(),
        ));
    }
    match req.out.extension().and_then(|e| e.to_str()) {
        Some("h5" | "hdf5") => crate::testdata::write_h5(&req.out, &test.data)?,
        _ => crate::testdata::write_csv(&req.out, &test.data)?,
    }
    Ok(TestRun {
        request: req.clone(),
        model_name: model.name().to_string(),
        drive,
        test,
        open_loop,
        setup_seconds,
        seconds,
    })
}

/// What the force controller did along one sweep.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ControlStats {
    /// Mean controller iterations per step.
    pub mean_iterations: f64,
    /// Most controller iterations at one step.
    pub max_iterations: usize,
    /// Largest force error of a step (fraction of the fundamental target; steps whose
    /// structure was not solved left out).
    pub max_force_error: f64,
    /// Steps that met the tolerance.
    pub converged: usize,
    /// Steps.
    pub steps: usize,
}

impl ControlStats {
    /// The statistics of the step records `steps`.
    pub fn of(steps: &[nlsim_calib::StepControl]) -> Self {
        let total: usize = steps.iter().map(|st| st.iterations).sum();
        Self {
            mean_iterations: total as f64 / steps.len().max(1) as f64,
            max_iterations: steps.iter().map(|st| st.iterations).max().unwrap_or(0),
            max_force_error: steps
                .iter()
                .map(|st| st.force_error)
                .filter(|x| x.is_finite())
                .fold(0.0f64, f64::max),
            converged: steps.iter().filter(|st| st.status.is_converged()).count(),
            steps: steps.len(),
        }
    }
}

/// The smallest `|F1| / target` along a sweep's step records: the force drop-out of a
/// voltage-driven test.
pub fn min_force_ratio(steps: &[nlsim_calib::StepControl], target: f64) -> f64 {
    steps
        .iter()
        .map(|st| st.force[1].norm() / target)
        .filter(|x| x.is_finite())
        .fold(f64::INFINITY, f64::min)
}

/// `sqrt(Σ_{k≥2} |F_k|²) / |F_1|`: the harmonic distortion of a force record.
fn distortion(force: &[faer::c64]) -> f64 {
    let hi: f64 = force.iter().skip(2).map(|f| f.norm_sqr()).sum();
    hi.sqrt() / force[1].norm()
}

impl TestRun {
    /// The readable summary: the test, then per sweep the force drop-out and distortion of
    /// the voltage-driven test and the controller's iterations, error and converged steps.
    pub fn summary(&self) -> Vec<String> {
        let r = &self.request;
        let s = &r.shaker;
        let mut v = vec![
            format!(
                "virtual test of '{}' at '{}' through a shaker (armature {} kg, suspension {} \
                 N/m, coil {} ohm {} H, Bl {} N/A, stinger {:e} N/m), {}; {} sweeps, {} \
                 harmonics, noise {} % + {:e} (seed {}); reduction {:.2} s, test {:.2} s",
                self.model_name,
                self.drive,
                s.armature_mass,
                s.suspension_stiffness,
                s.resistance,
                s.inductance,
                s.force_constant,
                s.stinger_stiffness,
                if r.control.enabled {
                    format!("force-controlled to {} %", 100.0 * r.control.tolerance)
                } else {
                    "voltage-driven".into()
                },
                r.sweeps.len(),
                r.harmonics,
                100.0 * r.noise.relative,
                r.noise.absolute,
                r.seed,
                self.setup_seconds,
                self.seconds
            ),
            format!(
                "{:<24} {:>22} {:>16}   {:>20} {:>16} {:>10}",
                "sweep",
                "open loop: min |F1|/F*",
                "max distortion",
                "iterations mean/max",
                "max force error",
                "converged"
            ),
        ];
        for (i, plan) in r.sweeps.iter().enumerate() {
            let c = &self.test.steps[i];
            let (min_ratio, dist) = match &self.open_loop {
                Some(o) => (
                    min_force_ratio(&o.steps[i], plan.force),
                    o.steps[i]
                        .iter()
                        .map(|st| distortion(&st.force))
                        .filter(|x| x.is_finite())
                        .fold(0.0f64, f64::max),
                ),
                None => (f64::NAN, f64::NAN),
            };
            let cs = ControlStats::of(c);
            let shown = |x: f64, f: &dyn Fn(f64) -> String| {
                if x.is_nan() { "-".to_string() } else { f(x) }
            };
            v.push(format!(
                "{:<24} {:>22} {:>16}   {:>16.1}/{:<3} {:>14.3} % {:>6}/{}",
                plan.label,
                shown(min_ratio, &|x| format!("{x:.3}")),
                shown(dist, &|x| format!("{x:.3e}")),
                cs.mean_iterations,
                cs.max_iterations,
                100.0 * cs.max_force_error,
                cs.converged,
                cs.steps
            ));
            for st in c.iter().filter(|st| !st.status.is_converged()).take(3) {
                v.push(format!(
                    "  {:.4} Hz: {}{}",
                    st.frequency_hz,
                    st.status,
                    if matches!(st.status, Status::IterationLimit) {
                        format!(
                            " (force error {:.2} %, kept in the data)",
                            100.0 * st.force_error
                        )
                    } else {
                        " (structure not solved; left out of the data)".into()
                    }
                ));
            }
        }
        v.push(format!(
            "test data: {} ({} steps, {} channels); calibrate with `nlsim calibrate MODEL {} \
             --param ...`",
            r.out.display(),
            self.test.data.n_points(),
            self.test.data.channels.len(),
            r.out.display()
        ));
        v
    }

    /// Every step of the test (and of the open loop): sweep, frequency, status,
    /// iterations, force error, force and voltage harmonics.
    pub fn control_csv(&self) -> String {
        let h = self.request.harmonics;
        let mut s = String::from("run,sweep,label,step,frequency_hz,status,iterations,force_error");
        for k in 0..=h {
            let _ = write!(s, ",force{k}_re,force{k}_im");
        }
        for k in 0..=h {
            let _ = write!(s, ",voltage{k}_re,voltage{k}_im");
        }
        s.push('\n');
        let runs = std::iter::once(("test", &self.test))
            .chain(self.open_loop.as_ref().map(|o| ("open-loop", o)));
        for (name, t) in runs {
            for (i, steps) in t.steps.iter().enumerate() {
                for (j, st) in steps.iter().enumerate() {
                    let _ = write!(
                        s,
                        "{name},{},\"{}\",{},{:?},{},{},{:?}",
                        i + 1,
                        self.request.sweeps[i].label.replace('"', "\"\""),
                        j + 1,
                        st.frequency_hz,
                        st.status,
                        st.iterations,
                        st.force_error
                    );
                    for f in st.force.iter().chain(&st.voltage) {
                        let _ = write!(s, ",{:?},{:?}", f.re, f.im);
                    }
                    s.push('\n');
                }
            }
        }
        s
    }
}

/// Writes the report of `run` into `dir` (created if needed): `summary.txt`, `control.csv`
/// and plots (SVG and PNG, thesis Fig. 11): the fundamental force and the distortion at
/// the drive point per sweep, controlled and voltage-driven (`force`), and the first
/// channel's fundamental response (`response`). Returns the files written.
pub fn write_test_report(dir: &Path, run: &TestRun) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let report = crate::report::Report::create(
        dir,
        &format!("nlsim test: {}", run.model_name),
        &crate::report::command_line(),
        &run.request.model,
    )?;
    report.seed("measurement noise", run.request.seed)?;
    report.section_with("Summary", &run.summary());
    report.section("Force and response");
    let mut written = Vec::new();
    for (name, body) in [
        ("summary.txt", run.summary().join("\n") + "\n"),
        ("control.csv", run.control_csv()),
    ] {
        let p = dir.join(name);
        write_text(&p, &body)?;
        written.push(p);
    }
    let ctl = if run.request.control.enabled {
        "force-controlled"
    } else {
        "voltage-driven"
    };
    let mut tests = vec![(ctl, &run.test)];
    if let Some(o) = &run.open_loop {
        tests.push(("voltage-driven", o));
    }
    let mut force = Vec::new();
    for (what, t) in &tests {
        for (i, plan) in run.request.sweeps.iter().enumerate() {
            let pts = |f: &dyn Fn(&[faer::c64]) -> f64| -> Vec<(f64, f64)> {
                t.steps[i]
                    .iter()
                    .filter(|st| st.status.is_converged() || st.force[1].norm().is_finite())
                    .map(|st| (st.frequency_hz, f(&st.force)))
                    .filter(|p| p.1.is_finite())
                    .collect()
            };
            force.push((
                format!("{}, {what}, |F1|", plan.label),
                pts(&|f| f[1].norm()),
            ));
            if run.request.harmonics >= 2 {
                force.push((
                    format!("{}, {what}, |F2..FH|", plan.label),
                    pts(&|f| distortion(f) * f[1].norm()),
                ));
            }
        }
    }
    force.retain(|(_, p)| !p.is_empty());
    written.extend(report.figure(
        "force",
        &Lines {
            title: format!(
                "{}: force at the drive point '{}'",
                run.model_name, run.drive
            ),
            x_desc: "frequency (Hz)".into(),
            y_desc: "force harmonic amplitude (N)".into(),
            series: force,
        },
    )?);
    let ch = &run.test.data.channels[0];
    let mut resp = Vec::new();
    for (what, t) in &tests {
        for sw in &t.data.sweeps {
            resp.push((
                format!("{}, {what}", sw.label),
                sw.steps
                    .iter()
                    .map(|st| (st.frequency_hz, st.response[(0, 0)].norm()))
                    .filter(|p| p.1.is_finite())
                    .collect::<Vec<_>>(),
            ));
        }
    }
    resp.retain(|(_, p)| !p.is_empty());
    written.extend(report.figure(
        "response",
        &Lines {
            title: format!("{}: response at '{}', harmonic 1", run.model_name, ch.name),
            x_desc: "frequency (Hz)".into(),
            y_desc: format!(
                "|{}| {} ({})",
                ch.name,
                ch.quantity.as_str(),
                crate::output::unit(ch.quantity)
            ),
            series: resp,
        },
    )?);
    written.push(report.finish()?);
    written.push(dir.join(crate::report::DATA));
    Ok(written)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEST: &str = r#"
drive = "tip"
seed = 4
noise = { relative = 0.01 }

[shaker]
armature_mass = 0.05

[control]
tolerance = 0.02

[[sweep]]
from = 30.0
to = 36.0
steps = 7
force = 0.1
"#;

    #[test]
    fn a_test_file_reads_into_its_request() {
        let r = TestRequest::parse(TEST, Path::new("/t/test.toml"), "ecl_beam").unwrap();
        assert_eq!(r.drive.as_deref(), Some("tip"));
        assert_eq!(r.seed, 4);
        assert_eq!(r.noise.relative, 0.01);
        assert_eq!(r.shaker.armature_mass, 0.05);
        assert_eq!(r.shaker.resistance, Shaker::default().resistance);
        assert_eq!(r.control.tolerance, 0.02);
        assert_eq!(r.sweeps[0].frequencies_hz.len(), 7);
        assert_eq!(r.out, Path::new("/t/virtual_test.csv"));
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let cases = [
            (
                TEST.replace("force = 0.1", "force = 0.1\nspeed = 2"),
                "speed",
            ),
            (TEST.replace("force = 0.1", "force = -1.0"), "sweep"),
            (
                TEST.replace("armature_mass = 0.05", "armature_mass = 0.0"),
                "shaker",
            ),
            (
                TEST.replace("tolerance = 0.02", "tolerance = 0.0"),
                "control",
            ),
            (TEST.replace("seed = 4", "seed = 4\nout = \"x.txt\""), "out"),
        ];
        for (text, key) in cases {
            let e = TestRequest::parse(&text, Path::new("test.toml"), "m").unwrap_err();
            let msg = e.to_string();
            let line = text
                .lines()
                .position(|l| {
                    let l = l.trim_start();
                    l.starts_with(key)
                        || l.starts_with(&format!("[{key}]"))
                        || l.starts_with(&format!("[[{key}]]"))
                })
                .unwrap()
                + 1;
            assert!(
                msg.starts_with(&format!("test.toml:{line}:")) && msg.contains(key),
                "{key}: {msg}"
            );
        }
    }
}
