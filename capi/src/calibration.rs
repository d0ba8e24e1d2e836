//! Calibration through the C ABI: stepped-sine test data from caller arrays, and the
//! calibration of a harmonic-balance system's parameters against it (thesis ch. 4).

use crate::{
    Done, Failure, NlsimCode, NlsimHb, NlsimStatus, NlsimTestData, Object, get_hb, get_testdata,
    guard, insert, out, out_opt, params_of, read, slice, slice_mut, text, texts, write,
};
use faer::c64;
use nlsim::calib::{
    CalibrationConfig, Channel, FrfObjective, Noise, ObjectiveConfig, ParamSpec, Step, Sweep,
    SweepDirection, TestData, calibrate,
};
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
}

/// The defaults of the command line's `nlsim calibrate`: seed 1, 64 candidates, 3 starts,
/// 10 folds, 100 iterations.
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_calibration_settings_default() -> NlsimCalibrationSettings {
    let d = CalibrationConfig::default();
    NlsimCalibrationSettings {
        seed: d.seed,
        lhs_samples: d.lhs_samples,
        starts: d.starts,
        folds: d.folds,
        max_iterations: d.lm.max_iterations,
    }
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
/// unit; NaN where a harmonic was not measured).
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
    guard(|| {
        // SAFETY (every block below): the function's contract.
        let label = unsafe { text(label, "label")? };
        let freq = unsafe { slice(freq_hz, n_steps, "freq_hz")? };
        let force = unsafe { slice(force, force_len, "force")? };
        let response = unsafe { slice(response, response_len, "response")? };
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
        let z = |v: &[f64], i: usize| c64::new(v[2 * i], v[2 * i + 1]);
        let steps = (0..n_steps)
            .map(|s| Step {
                frequency_hz: freq[s],
                force: (0..h).map(|k| z(force, s * h + k)).collect(),
                response: faer::Mat::from_fn(nc, h, |c, k| z(response, (s * nc + c) * h + k)),
                sigma: faer::Mat::new(),
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
/// A best run that did not converge returns `NLSIM_CODE_STOPPED_SHORT` with its estimate.
///
/// # Safety
/// `names` holds `n_params` strings; `lower`, `upper`, `estimate` and `std` hold `n_params`
/// doubles (the last two writable); `settings` is null or readable; `info` null or writable.
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
        let params = params_of(&sys, &names)?;
        let specs: Vec<ParamSpec> = params
            .into_iter()
            .zip(lower.iter().zip(upper))
            .map(|(p, (&lo, &hi))| ParamSpec::new(p, lo, hi))
            .collect();
        let td = read(&*get_testdata(data)?).data.clone();
        td.validate()?;
        let objective = FrfObjective::new(
            &sys,
            Arc::new(td),
            specs,
            ObjectiveConfig {
                harmonics: vec![1],
                ..ObjectiveConfig::default()
            },
        )?;
        let mut cfg = CalibrationConfig {
            seed: settings.seed,
            lhs_samples: settings.lhs_samples,
            starts: settings.starts,
            folds: settings.folds,
            ..CalibrationConfig::default()
        };
        cfg.lm.max_iterations = settings.max_iterations;
        let cal = calibrate(&objective, &cfg)?;
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
