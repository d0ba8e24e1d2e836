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

/// [`run_test`] on `model` as given (loaded, `req.set` not applied): the test run, nothing
/// written (`req.out` and `req.model` are not used).
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
    let mut test = keep(run(&req.control, &noise, req.force_noise, progress)?)?;
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
