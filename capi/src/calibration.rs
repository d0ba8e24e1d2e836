//! Calibration through the C ABI: stepped-sine test data from caller arrays, and the
//! calibration of a harmonic-balance system's parameters against it (thesis ch. 4).

use crate::{
    Done, Failure, NlsimCode, NlsimHb, NlsimStatus, NlsimTestData, Object, get_hb, get_testdata,
    guard, insert, out, out_opt, read, slice, slice_mut, text, texts, write,
};
use faer::c64;
use nlsim::calib::{
    CalibrationConfig, Channel, Drive, FrfObjective, Noise, ObjectiveConfig, Outcome, ParamSpec,
    Shaker, Step, Sweep, SweepDirection, TestData, calibrate_until,
};
use nlsim::kernel::{Param, Parameterized, param::parse_known};
use std::ffi::c_char;
use std::sync::{Arc, RwLock};

/// Test data being assembled: checked as a whole when a calibration uses it.
pub(crate) struct TestDataBuilder {
    data: TestData,
}

/// Settings of [`nlsim_calibrate`]; [`nlsim_calibration_settings_default`] gives the
/// defaults of the `nlsim calibrate` command.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct NlsimCalibrationSettings {
    /// Seed of the Latin hypercube and of the fold assignment (results are reproducible
    /// from it, for any thread count).
    pub seed: u64,
    /// Latin-hypercube candidates over the bounds (the current values are one more).
    pub lhs_samples: usize,
    /// Levenberg–Marquardt runs, from the best candidates.
    pub starts: usize,
    /// Folds of the cross validation (0: none; 2 or more otherwise).
    pub folds: usize,
    /// Levenberg–Marquardt iterations per run.
    pub max_iterations: usize,
    /// 1: the test data's voltage record ([`nlsim_testdata_set_record`]) drives the model
    /// through `shaker` (the coupling of the virtual test); 0: the recorded drive is taken as
    /// the force (times the input gain).
    pub model_shaker: i32,
    /// The shaker, when `model_shaker` is 1.
    pub shaker: NlsimShaker,
    /// Null, or a flag the caller may set to nonzero from another thread or a signal
    /// handler (a `volatile sig_atomic_t`-sized `int32_t`) to stop the calibration at its
    /// next safe point (before a candidate, before a Levenberg–Marquardt evaluation):
    /// [`nlsim_calibrate`] then returns `NLSIM_CODE_STOPPED_SHORT` with the best values so
    /// far in `estimate` and NaN in `std`. Read atomically; never written by nlsim.
    pub cancel: *const i32,
}

/// The caller's cancel flag, read atomically from the calibration's worker threads.
struct CancelFlag(*const std::sync::atomic::AtomicI32);

// SAFETY: the flag is only read, atomically; the caller keeps it alive for the call
// (`NlsimCalibrationSettings::cancel`).
#[allow(unsafe_code)]
unsafe impl Sync for CancelFlag {}

impl CancelFlag {
    #[allow(unsafe_code)]
    fn raised(&self) -> bool {
        // SAFETY: non-null by the check; the contract of `cancel` keeps it valid and
        // aligned for the call; an `AtomicI32` has the layout of an `int32_t`.
        !self.0.is_null() && unsafe { &*self.0 }.load(std::sync::atomic::Ordering::Relaxed) != 0
    }
}

/// An electrodynamic shaker on a stinger (SI units), as the virtual test couples it
/// (`nlsim_calib::Shaker`); [`nlsim_calibration_settings_default`] holds nlsim's default.
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct NlsimShaker {
    /// Armature mass (kg).
    pub armature_mass: f64,
    /// Suspension stiffness (N/m).
    pub suspension_stiffness: f64,
    /// Suspension damping (N s/m).
    pub suspension_damping: f64,
    /// Coil resistance (Ω), amplifier output included.
    pub resistance: f64,
    /// Coil inductance (H).
    pub inductance: f64,
    /// Force constant `Bl` (N/A).
    pub force_constant: f64,
    /// Axial stiffness of the stinger (N/m).
    pub stinger_stiffness: f64,
}

impl From<Shaker> for NlsimShaker {
    fn from(s: Shaker) -> Self {
        NlsimShaker {
            armature_mass: s.armature_mass,
            suspension_stiffness: s.suspension_stiffness,
            suspension_damping: s.suspension_damping,
            resistance: s.resistance,
            inductance: s.inductance,
            force_constant: s.force_constant,
            stinger_stiffness: s.stinger_stiffness,
        }
    }
}

impl From<NlsimShaker> for Shaker {
    fn from(s: NlsimShaker) -> Self {
        Shaker {
            armature_mass: s.armature_mass,
            suspension_stiffness: s.suspension_stiffness,
            suspension_damping: s.suspension_damping,
            resistance: s.resistance,
            inductance: s.inductance,
            force_constant: s.force_constant,
            stinger_stiffness: s.stinger_stiffness,
        }
    }
}

/// The outcome of [`nlsim_calibrate`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct NlsimCalibrationInfo {
    /// [`NlsimStatus`] of the best Levenberg–Marquardt run.
    pub status: i32,
    /// Cost `½‖r‖²` of the weighted residuals at the estimate.
    pub cost: f64,
    /// `2·cost/(m − n)`: about 1 when the noise model is right.
    pub reduced_chi2: f64,
    /// Collinearity index of the sensitivities (above about 15 the parameters cannot be
    /// told apart).
    pub collinearity: f64,
    /// Levenberg–Marquardt iterations of the best run.
    pub iterations: usize,
    /// Parameters whose estimate sits on a bound.
    pub n_at_bound: usize,
    /// Parameters poorly identified (relative standard deviation above 0.5, or collinear).
    pub n_poorly_identified: usize,
    /// `√reduced_chi2`: the Cramér–Rao `std` times this is the standard deviation with the
    /// noise scaled to the misfit (the command line's `chi2-scaled` column).
    pub chi2_scale: f64,
    /// 1 when the reduced χ² exceeds 2: the residuals exceed the noise model, the Cramér–Rao
    /// `std` is too small by `chi2_scale` (the command line prints a warning).
    pub misfit_warning: i32,
}

/// The defaults of the command line's `nlsim calibrate`: seed 1, 64 candidates, 3 starts,
/// 10 folds, 100 iterations, no shaker modelled (nlsim's default shaker filled in).
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_calibration_settings_default() -> NlsimCalibrationSettings {
    let d = CalibrationConfig::default();
    NlsimCalibrationSettings {
        seed: d.seed,
        lhs_samples: d.lhs_samples,
        starts: d.starts,
        folds: d.folds,
        max_iterations: d.lm.max_iterations,
        model_shaker: 0,
        shaker: Shaker::default().into(),
        cancel: std::ptr::null(),
    }
}

/// What the test data recorded at the drive: `record` 0 the force (N, the default), 1 the
/// voltage into the amplifier (V) — calibrated with the input gain `input_gain` (N per V
/// with the shaker taken as a force source, or V at the coil per V with the shaker modelled,
/// [`NlsimCalibrationSettings::model_shaker`]).
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_testdata_set_record(data: NlsimTestData, record: i32) -> NlsimCode {
    guard(|| {
        let drive = match record {
            0 => Drive::Force,
            1 => Drive::Voltage,
            r => {
                return Err(Failure::input(format!(
                    "record {r} is neither force (0) nor voltage (1)"
                )));
            }
        };
        let d = get_testdata(data)?;
        write(&d).data.drive = drive;
        Ok(Done::Complete)
    })
}

/// Starts stepped-sine test data: the force is measured at the model input named `input`,
/// with `harmonics` harmonics held per step (1 = the fundamental only). Add channels, then
/// sweeps.
///
/// # Safety
/// `input` is a string; `data` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_testdata_new(
    input: *const c_char,
    harmonics: usize,
    data: *mut NlsimTestData,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let input = unsafe { text(input, "input")? };
        // SAFETY: the function's contract.
        let data = unsafe { out(data, "data")? };
        if harmonics == 0 || harmonics > 256 {
            return Err(Failure::input(format!(
                "harmonics is {harmonics}; use 1 to 256"
            )));
        }
        *data = insert(Object::TestData(Arc::new(RwLock::new(TestDataBuilder {
            data: TestData {
                input: input.into(),
                drive: nlsim::calib::Drive::Force,
                channels: Vec::new(),
                harmonics,
                sweeps: Vec::new(),
            },
        }))));
        Ok(Done::Complete)
    })
}

/// Adds a response channel named like the model sensor it is compared with, measuring
/// `quantity` ([`crate::NlsimQuantity`]), with noise standard deviation
/// `√(noise_abs² + (noise_rel·|Y|)²)` per real and imaginary part (the channel's unit).
/// Channels must all be added before the first sweep.
///
/// # Safety
/// `name` is a string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_testdata_add_channel(
    data: NlsimTestData,
    name: *const c_char,
    quantity: i32,
    noise_abs: f64,
    noise_rel: f64,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let name = unsafe { text(name, "name")? };
        let q = crate::quantity(quantity, "quantity")?;
        let d = get_testdata(data)?;
        let mut d = write(&d);
        if !d.data.sweeps.is_empty() {
            return Err(Failure::input(format!(
                "channel '{name}': add every channel before the first sweep"
            )));
        }
        d.data.channels.push(Channel {
            name: name.into(),
            quantity: q,
            noise: Noise {
                absolute: noise_abs,
                relative: noise_rel,
            },
        });
        Ok(Done::Complete)
    })
}

/// Adds a sweep of `n_steps` steps measured in the given order (`direction` 0 up, 1 down):
/// `freq_hz[n_steps]` (Hz), the measured force harmonics `force[n_steps][H][2]` (N, complex,
/// harmonics `1..=H`) and responses `response[n_steps][n_channels][H][2]` (each channel's
/// unit; NaN where a harmonic was not measured). The channels' noise models weigh them.
///
/// # Safety
/// `label` is a string; the arrays hold the sizes above.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_testdata_add_sweep(
    data: NlsimTestData,
    label: *const c_char,
    direction: i32,
    n_steps: usize,
    freq_hz: *const f64,
    force: *const f64,
    force_len: usize,
    response: *const f64,
    response_len: usize,
) -> NlsimCode {
    // SAFETY: the function's contract, with no standard deviations.
    unsafe {
        nlsim_testdata_add_sweep_sigma(
            data,
            label,
            direction,
            n_steps,
            freq_hz,
            force,
            force_len,
            response,
            response_len,
            std::ptr::null(),
            0,
        )
    }
}

/// [`nlsim_testdata_add_sweep`] with each step's measured standard deviations
/// `sigma[n_steps][n_channels][H][2]` (of the real and of the imaginary part, each channel's
/// unit; positive, or NaN where the harmonic was not measured) in place of the channels'
/// noise models; `sigma` null with `sigma_len` 0 uses the noise models.
///
/// # Safety
/// `label` is a string; the arrays hold the sizes above (`sigma` may be null with length 0).
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_testdata_add_sweep_sigma(
    data: NlsimTestData,
    label: *const c_char,
    direction: i32,
    n_steps: usize,
    freq_hz: *const f64,
    force: *const f64,
    force_len: usize,
    response: *const f64,
    response_len: usize,
    sigma: *const f64,
    sigma_len: usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY (every block below): the function's contract.
        let label = unsafe { text(label, "label")? };
        let freq = unsafe { slice(freq_hz, n_steps, "freq_hz")? };
        let force = unsafe { slice(force, force_len, "force")? };
        let response = unsafe { slice(response, response_len, "response")? };
        let sigma = if sigma.is_null() && sigma_len == 0 {
            None
        } else {
            Some(unsafe { slice(sigma, sigma_len, "sigma")? })
        };
        let direction = match direction {
            0 => SweepDirection::Up,
            1 => SweepDirection::Down,
            d => {
                return Err(Failure::input(format!(
                    "direction {d} is neither up (0) nor down (1)"
                )));
            }
        };
        let d = get_testdata(data)?;
        let mut d = write(&d);
        let h = d.data.harmonics;
        let nc = d.data.channels.len();
        if nc == 0 {
            return Err(Failure::input(format!(
                "sweep '{label}': add the channels first"
            )));
        }
        if force.len() != n_steps * h * 2 {
            return Err(Failure::size("force", n_steps * h * 2, force.len()));
        }
        if response.len() != n_steps * nc * h * 2 {
            return Err(Failure::size(
                "response",
                n_steps * nc * h * 2,
                response.len(),
            ));
        }
        if let Some(sg) = sigma
            && sg.len() != n_steps * nc * h * 2
        {
            return Err(Failure::size("sigma", n_steps * nc * h * 2, sg.len()));
        }
        let z = |v: &[f64], i: usize| c64::new(v[2 * i], v[2 * i + 1]);
        let steps = (0..n_steps)
            .map(|s| Step {
                frequency_hz: freq[s],
                force: (0..h).map(|k| z(force, s * h + k)).collect(),
                response: faer::Mat::from_fn(nc, h, |c, k| z(response, (s * nc + c) * h + k)),
                sigma: match sigma {
                    Some(sg) => faer::Mat::from_fn(nc, h, |c, k| z(sg, (s * nc + c) * h + k)),
                    None => faer::Mat::new(),
                },
            })
            .collect();
        d.data.sweeps.push(Sweep {
            label: label.into(),
            direction,
            steps,
        });
        Ok(Done::Complete)
    })
}

/// Calibrates the parameters `names[0..n_params]` of the harmonic-balance system `hb`
/// against `data` within `[lower, upper]` (SI units): candidates from a maximin Latin
/// hypercube, Levenberg–Marquardt from the best, the Cramér–Rao bound at the estimate and a
/// k-fold cross validation (thesis §4.3–4.5). Writes the estimate and its standard
/// deviations (Cramér–Rao, parameter units) into `estimate` and `std` (`n_params` each).
/// The system's own parameter values are the first candidate and are not changed; set the
/// estimate with [`crate::nlsim_set_param`] to use it. `settings` null means the defaults.
/// A best run that did not converge returns `NLSIM_CODE_STOPPED_SHORT` with its estimate; so
/// does a calibration stopped by `settings.cancel`, with the best values so far (the
/// system's own where no candidate was evaluated), NaN standard deviations, `info.cost` the
/// best cost so far, and [`crate::nlsim_last_error`] saying where it stopped.
///
/// # Safety
/// `names` holds `n_params` strings; `lower`, `upper`, `estimate` and `std` hold `n_params`
/// doubles (the last two writable); `settings` is null or readable, its `cancel` null or an
/// aligned `int32_t` alive for the call; `info` null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_calibrate(
    hb: NlsimHb,
    data: NlsimTestData,
    names: *const *const c_char,
    n_params: usize,
    lower: *const f64,
    upper: *const f64,
    settings: *const NlsimCalibrationSettings,
    estimate: *mut f64,
    std: *mut f64,
    info: *mut NlsimCalibrationInfo,
) -> NlsimCode {
    guard(|| {
        // SAFETY (every block below): the function's contract.
        let names = unsafe { texts(names, n_params, "names")? };
        let lower = unsafe { slice(lower, n_params, "lower")? };
        let upper = unsafe { slice(upper, n_params, "upper")? };
        let estimate = unsafe { slice_mut(estimate, n_params, "estimate")? };
        let std = unsafe { slice_mut(std, n_params, "std")? };
        let settings = if settings.is_null() {
            nlsim_calibration_settings_default()
        } else {
            *unsafe { out(settings.cast_mut(), "settings")? }
        };
        let info = unsafe { out_opt(info, "info")? };
        if n_params == 0 {
            return Err(Failure::input(
                "n_params is 0: name a parameter to calibrate",
            ));
        }
        let h = get_hb(hb)?;
        let sys = read(&h).clone();
        let td = read(&*get_testdata(data)?).data.clone();
        td.validate()?;
        // The system's parameters and the test data's gains.
        let mut known = sys.parameters();
        known.push(Param::InputGain);
        known.extend(
            td.channels
                .iter()
                .map(|c| Param::SensorGain(c.name.clone())),
        );
        let params = names
            .iter()
            .map(|n| parse_known(n, &known).map_err(Failure::from))
            .collect::<Result<Vec<_>, Failure>>()?;
        let specs: Vec<ParamSpec> = params
            .into_iter()
            .zip(lower.iter().zip(upper))
            .map(|(p, (&lo, &hi))| ParamSpec::new(p, lo, hi))
            .collect();
        let mut objective = FrfObjective::new(
            &sys,
            Arc::new(td),
            specs,
            ObjectiveConfig {
                harmonics: vec![1],
                ..ObjectiveConfig::default()
            },
        )?;
        match settings.model_shaker {
            0 => {}
            1 => objective.set_shaker(Some(settings.shaker.into()))?,
            m => {
                return Err(Failure::input(format!(
                    "settings.model_shaker {m} is neither 0 nor 1"
                )));
            }
        }
        let mut cfg = CalibrationConfig {
            seed: settings.seed,
            lhs_samples: settings.lhs_samples,
            starts: settings.starts,
            folds: settings.folds,
            ..CalibrationConfig::default()
        };
        cfg.lm.max_iterations = settings.max_iterations;
        let cancel = CancelFlag(settings.cancel.cast());
        let cal = match calibrate_until(&objective, &cfg, &[], &|_| {}, &|| cancel.raised())? {
            Outcome::Finished(c) => *c,
            Outcome::Interrupted(kept) => {
                let best = match kept.best() {
                    Some((v, c)) => (v.to_vec(), c),
                    None => (
                        objective
                            .specs()
                            .iter()
                            .map(|s| objective.param_value(&s.param))
                            .collect::<Result<Vec<_>, _>>()?,
                        f64::NAN,
                    ),
                };
                estimate.copy_from_slice(&best.0);
                std.fill(f64::NAN);
                if let Some(info) = info {
                    *info = NlsimCalibrationInfo {
                        status: NlsimStatus::IterationLimit as i32,
                        cost: best.1,
                        reduced_chi2: f64::NAN,
                        collinearity: f64::NAN,
                        chi2_scale: f64::NAN,
                        ..NlsimCalibrationInfo::default()
                    };
                }
                return Ok(Done::Short(format!(
                    "cancelled in the {} phase: {} of {} candidates evaluated, {} \
                     optimisations finished; `estimate` holds the best values so far (not a \
                     calibration: `std` is NaN)",
                    kept.phase.as_str(),
                    kept.evaluated(),
                    kept.points.len(),
                    kept.runs.len()
                )));
            }
        };
        estimate.copy_from_slice(&cal.estimate);
        std.copy_from_slice(&cal.cramer_rao.std);
        if let Some(info) = info {
            *info = NlsimCalibrationInfo {
                status: NlsimStatus::from(cal.status) as i32,
                cost: cal.cost,
                reduced_chi2: cal.cramer_rao.reduced_chi2,
                collinearity: cal.cramer_rao.collinearity,
                iterations: cal.runs.first().map_or(0, |r| r.report.iterations),
                n_at_bound: cal.at_bound.iter().filter(|&&b| b).count(),
                n_poorly_identified: cal.poorly_identified.iter().filter(|&&b| b).count(),
                chi2_scale: cal.cramer_rao.reduced_chi2.sqrt(),
                misfit_warning: i32::from(cal.cramer_rao.misfit_warning().is_some()),
            };
        }
        Ok(if cal.status.is_converged() {
            Done::Complete
        } else {
            Done::Short(format!(
                "the best Levenberg–Marquardt run stopped: {}",
                cal.status.as_str()
            ))
        })
    })
}
