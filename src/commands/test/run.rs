//! The run of `nlsim test`: the stepped sines through the shaker model, open loop or with the
//! off-line force controller, and the test data they give.
use crate::commands::test::request::TestRequest;
use crate::error::{Error, Result};
use nlsim_calib::{ControlConfig, Noise, VirtualTest, virtual_test_with};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::Excitation;
use std::time::Instant;

/// A finished virtual test.
pub struct TestRun {
    /// The request.
    pub request: TestRequest,
    /// The model's name.
    pub model_name: String,
    /// The input the shaker drives.
    pub drive: String,
    /// The absolute response noise floor of each recorded channel (name, the channel's
    /// unit): the request's, or its floor relative to the channel's largest response.
    pub floors: Vec<(String, f64)>,
    /// Floors that bury a channel's response (at least a tenth of its largest).
    pub warnings: Vec<String>,
    /// The test as asked (controlled, unless control is off).
    pub test: VirtualTest,
    /// The same test voltage-driven, when compared.
    pub open_loop: Option<VirtualTest>,
    /// Wall time of loading and reduction (s).
    pub setup_seconds: f64,
    /// Wall time of the tests (s).
    pub seconds: f64,
    /// The raw records, when asked for.
    pub raw: Option<RawRun>,
}

/// The raw records of a virtual test and how they were made.
#[derive(Debug, Clone)]
pub struct RawRun {
    /// The records (noise added).
    pub record: nlsim_calib::RawRecord,
    /// Hold steps per recorded sample.
    pub oversample: usize,
    /// Length of every step (s).
    pub dwell_s: f64,
    /// The settling time (s) at the start of every step, left out of its measured window in
    /// the step table (at most the dwell less 4 periods).
    pub settle_s: f64,
    /// Standard deviation of each sensor's noise (its unit), the force's last (N).
    pub sigmas: Vec<f64>,
    /// Wall time of the time integration (s).
    pub seconds: f64,
    /// Universal-file node and direction of each sensor and of the drive, by name.
    pub sites: Vec<(String, (i64, i64))>,
    /// The model's node coordinates (m), for dataset 2411 of a universal file.
    pub geometry: Vec<(u64, [f64; 3])>,
}

/// Runs `req`: the model loaded and reduced, the stepped sines through the shaker (and
/// again voltage-driven when compared), the data written to `req.out`.
/// `progress(sweep, sweeps)` before each sweep of the test.
pub fn run_test(req: &TestRequest, progress: &mut dyn FnMut(usize, usize)) -> Result<TestRun> {
    req.check()?;
    let t = Instant::now();
    let model = crate::commands::setup::load_for_run(&req.model, &req.set)?;
    let load_seconds = t.elapsed().as_secs_f64();
    let mut run = run_test_on(model, req, progress)?;
    run.setup_seconds += load_seconds;
    write_test_data(&req.out, &run.test.data)?;
    if let (Some(raw), Some(r)) = (&run.raw, &req.raw) {
        let info = crate::formats::raw_records::RawInfo {
            model_name: &run.model_name,
            sites: &raw.sites,
            geometry: &raw.geometry,
            model_spec: &req.model,
            drive: &run.drive,
            record: req.record,
            amplifier_gain: req.amplifier_gain,
            channels: &req.channels,
            noise: raw_noise_line(req),
        };
        crate::formats::raw_records::write_raw(&r.out, &raw.record, &info)?;
        crate::formats::raw_records::write_step_table(
            &crate::commands::test::request::raw_steps_path(&r.out),
            &raw.record,
        )?;
    }
    Ok(run)
}

/// Writes virtual test data to `out`: HDF5 for `.h5`/`.hdf5` (with the `hdf5` feature), CSV
/// otherwise.
pub fn write_test_data(out: &std::path::Path, data: &nlsim_calib::TestData) -> Result<()> {
    match out.extension().and_then(|e| e.to_str()) {
        #[cfg(feature = "hdf5")]
        Some("h5" | "hdf5") => crate::formats::test_data::write_h5(out, data),
        #[cfg(not(feature = "hdf5"))]
        Some("h5" | "hdf5") => Err(Error::Usage(format!(
            "{}: HDF5 test data need nlsim's `hdf5` feature; name a .csv file",
            out.display()
        ))),
        _ => crate::formats::test_data::write_csv(out, data),
    }
}

/// What the raw records' noise is, for their header.
fn raw_noise_line(req: &TestRequest) -> String {
    format!(
        "noise per sample: sensors {} of their rms (at least {:e}), force {} of its rms (at \
         least {:e}), voltage exact; seed {}",
        req.noise.relative,
        req.noise.absolute,
        req.force_noise.relative,
        req.force_noise.absolute,
        req.seed
    )
}

/// [`run_test`] on `model` as given (loaded, `req.set` not applied): the test run, nothing
/// written (`req.out` and `req.model` are not used). With `req.raw` the run holds the raw
/// records too; `progress(done, total)` then counts the time integration as much as the
/// sweeps.
pub fn run_test_on(
    mut model: nlsim_kernel::Model,
    req: &TestRequest,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<TestRun> {
    req.check()?;
    let t = Instant::now();
    let drive = match (&req.drive, &req.drive_dof) {
        (_, Some(dof)) => {
            let at = model.site(dof).map_err(|e| {
                Error::Usage(format!(
                    "test drive_dof '{dof}' is not in '{}': {e}",
                    model.name()
                ))
            })?;
            model.add_excitation(Excitation {
                name: "shaker".into(),
                at,
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
    crate::commands::plan::run::add_sensors(&mut model, &req.sensors, "test sensor")?;
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
    // Progress in hundredths of a sweep; the raw records count as much as the sweeps.
    let n_sweeps = req.sweeps.len();
    let total = 100 * n_sweeps * if req.raw.is_some() { 2 } else { 1 };
    let mut sweep_progress = |s: usize, _: usize| progress(100 * s, total);
    // One sweep at a time (for progress); the noise seed of sweep `s` is `seed + s`, so a
    // test of several sweeps is the same whichever are run.
    let run = |control: &ControlConfig,
               noise: &[Noise],
               force_noise: Noise,
               progress: &mut dyn FnMut(usize, usize)| {
        let mut out: Option<VirtualTest> = None;
        for (s, plan) in req.sweeps.iter().enumerate() {
            progress(s, req.sweeps.len());
            let one = virtual_test_with(
                &sys,
                &drive,
                &req.shaker,
                std::slice::from_ref(plan),
                req.harmonics,
                control,
                noise,
                force_noise,
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
    // The noise floor in each sensor's own scale: from the noise-free test (the controller
    // does not see the noise, so the run with noise reaches the same structure states).
    let n_sensors = sys.sensors().len();
    let (noise, peaks) = if req.noise_floor > 0.0 {
        let quiet = run(
            &req.control,
            &vec![Noise::relative(0.0); n_sensors],
            Noise::relative(0.0),
            &mut |_, _| {},
        )?;
        let peaks = quiet.data.fundamental_peaks();
        let noise = nlsim_calib::scaled_noise(
            req.noise.relative,
            req.noise.absolute,
            req.noise_floor,
            &peaks,
        );
        (noise, peaks)
    } else {
        (vec![req.noise; n_sensors], vec![f64::NAN; n_sensors])
    };
    let mut test = keep(run(
        &req.control,
        &noise,
        req.force_noise,
        &mut sweep_progress,
    )?)?;
    if req.record == nlsim_calib::Drive::Voltage {
        test.data = test.voltage_data(req.amplifier_gain)?;
    }
    let open_loop = if req.compare_open_loop {
        let open = ControlConfig {
            enabled: false,
            ..req.control
        };
        Some(keep(run(&open, &noise, req.force_noise, &mut |_, _| {})?)?)
    } else {
        None
    };
    let seconds = t.elapsed().as_secs_f64();
    if test.data.sweeps.iter().all(|s| s.steps.is_empty()) {
        return Err(Error::Failed(
            "virtual test: the structure could not be solved at any step; nothing to write".into(),
        ));
    }
    let raw = match &req.raw {
        None => None,
        Some(r) => {
            let done = 100 * n_sweeps;
            Some(raw_run(
                &model,
                &reduced,
                &drive,
                req,
                r,
                &test,
                &mut |k, n| progress(done + done * k / n.max(1), total),
            )?)
        }
    };
    let recorded = |name: &String| req.channels.is_empty() || req.channels.contains(name);
    let floors = sys
        .sensors()
        .iter()
        .zip(&noise)
        .filter(|(sen, _)| recorded(&sen.name))
        .map(|(sen, n)| (sen.name.clone(), n.absolute))
        .collect();
    let warnings = sys
        .sensors()
        .iter()
        .zip(noise.iter().zip(&peaks))
        .filter(|(sen, _)| recorded(&sen.name))
        .filter_map(|(sen, (n, &p))| {
            crate::commands::plan::run::floor_warning(
                &sen.name,
                sen.quantity,
                n.absolute,
                p,
                "largest response",
                "the data carry little of it",
            )
        })
        .collect();
    Ok(TestRun {
        request: req.clone(),
        model_name: model.name().to_string(),
        floors,
        warnings,
        drive,
        test,
        open_loop,
        setup_seconds,
        seconds,
        raw,
    })
}

/// The raw records of `test` (run on `model` reduced to `reduced`, the shaker at `drive`):
/// the coupled plant, the default rate and dwell where `r` gives none, one hold run, the
/// noise of `req`.
fn raw_run(
    model: &nlsim_kernel::Model,
    reduced: &nlsim_reduction::ReducedModel,
    drive: &str,
    req: &TestRequest,
    r: &crate::commands::test::request::RawRequest,
    test: &VirtualTest,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RawRun> {
    use crate::commands::test::request::{
        DEFAULT_HOLD_SAMPLES_PER_PERIOD, DEFAULT_MEASURED_PERIODS, DEFAULT_SAMPLES_PER_PERIOD,
        DEFAULT_SETTLE,
    };
    let t = Instant::now();
    let system = nlsim_reduction::ModalSystem::new(reduced)?;
    let plant = nlsim_sim::Plant::from_model(model, &system)?;
    let coupled = nlsim_calib::shaker_plant(&plant, drive, &req.shaker)?;
    let input = coupled.input_index(drive)?;
    let freqs = req
        .sweeps
        .iter()
        .flat_map(|s| s.frequencies_hz.iter().copied());
    let (lo, hi) = freqs.fold((f64::INFINITY, 0.0f64), |(a, b), f| (a.min(f), b.max(f)));
    let rate_hz = r.rate_hz.unwrap_or_else(|| {
        (DEFAULT_SAMPLES_PER_PERIOD * req.harmonics as f64 * hi / 100.0).ceil() * 100.0
    });
    let settle_s = nlsim_calib::settle_time(&coupled, (lo, hi), DEFAULT_SETTLE);
    let dwell_s = r.dwell_s.unwrap_or_else(|| {
        let d = settle_s + DEFAULT_MEASURED_PERIODS / lo;
        (d * 10.0).ceil() / 10.0
    });
    let oversample = r.oversample.unwrap_or_else(|| {
        let want = DEFAULT_HOLD_SAMPLES_PER_PERIOD * req.harmonics as f64 * hi;
        ((want / rate_hz).ceil() as usize).clamp(1, 1024)
    });
    let cfg = nlsim_calib::RawConfig {
        rate_hz,
        dwell_s,
        settle_s,
        oversample,
    };
    let mut record = nlsim_calib::raw_records(&coupled, input, test, &cfg, progress)
        .map_err(|e| Error::Usage(format!("test raw: {e}")))?;
    // The noise stream of its own beside the harmonics' (sweep s uses seed + s there).
    let sigmas = nlsim_calib::add_raw_noise(
        &mut record,
        req.noise,
        req.force_noise,
        req.seed ^ RAW_SEED_STREAM,
    );
    let labels = model.dofs();
    let at = |l| crate::formats::uff_write::node_direction(l);
    let mut sites: Vec<(String, (i64, i64))> = model
        .sensors()
        .iter()
        .map(|s| (s.name.clone(), at(s.at.label(labels))))
        .collect();
    sites.extend(
        model
            .excitation()
            .iter()
            .map(|x| (x.name.clone(), at(x.at.label(labels)))),
    );
    Ok(RawRun {
        record,
        oversample,
        dwell_s,
        settle_s,
        sigmas,
        sites,
        geometry: model.geometry().to_vec(),
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Mixed into the test's seed for the raw records' noise, so that it is not the stream of any
/// sweep's harmonics.
pub const RAW_SEED_STREAM: u64 = 0x7261_775f_7265_6373;

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

/// The steps of a sweep's records whose structure was not solved (left out of the data),
/// each as `STEP (FREQUENCY Hz, STATUS)`, the step 1-based and the frequency with `digits`
/// decimals.
pub fn unsolved_steps(steps: &[nlsim_calib::StepControl], digits: usize) -> Vec<String> {
    steps
        .iter()
        .enumerate()
        .filter(|(_, st)| !st.force[1].norm().is_finite())
        .map(|(k, st)| {
            format!(
                "{} ({:.*} Hz, {})",
                k + 1,
                digits,
                st.frequency_hz,
                st.status
            )
        })
        .collect()
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

#[cfg(feature = "io")]
/// `sqrt(Σ_{k≥2} |F_k|²) / |F_1|`: the harmonic distortion of a force record.
pub(crate) fn distortion(force: &[faer::c64]) -> f64 {
    let hi: f64 = force.iter().skip(2).map(|f| f.norm_sqr()).sum();
    hi.sqrt() / force[1].norm()
}
