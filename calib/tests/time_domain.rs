//! Time-domain calibration (issue 45 part 4) on virtual sine sweeps: the clearance of the
//! bump-stop cantilever (contact stiffness and gap) and the cubic spring of the ECL beam,
//! recovered from records with 2 % noise within their Cramér–Rao bounds, starting from model
//! values away from the truth (the model's values are the first candidate); the Jacobian from
//! the forward sensitivities against central differences of the residuals; bad records named.

use nlsim_calib::{
    CalibrationConfig, LeastSquares, ParamSpec, TimeObjective, TimeRecords, calibrate_time,
    synthesize_time,
};
use nlsim_kernel::{Model, Param, Parameterized};
use nlsim_reduction::ReductionConfig;
use nlsim_sim::Signal;
use std::sync::Arc;

/// A linear sine sweep of `amplitude` N from `f0` to `f1` Hz over `seconds`, sampled at
/// `rate` Hz, and the model's responses to it at `truth` with noise of `noise` times their
/// rms drawn from `seed`.
fn record(
    model: &Model,
    specs: &[ParamSpec],
    truth: &[f64],
    sweep: (f64, f64, f64, f64),
    rate: f64,
    noise: f64,
    seed: u64,
) -> TimeRecords {
    let (amplitude, f0, f1, seconds) = sweep;
    let s = Signal::Sweep {
        amplitude,
        f0_hz: f0,
        f1_hz: f1,
        duration: seconds,
        logarithmic: false,
    };
    let n = (seconds * rate) as usize + 1;
    let force: Vec<f64> = (0..n).map(|k| s.eval(k as f64 / rate)).collect();
    synthesize_time(
        model,
        &ReductionConfig::lowest(8),
        specs,
        truth,
        &model.excitation()[0].name,
        force,
        rate,
        noise,
        seed,
    )
    .unwrap()
}

fn bumpstop() -> (Model, Vec<ParamSpec>, Vec<f64>, f64) {
    let model = nlsim_fixtures::build("bumpstop_cantilever", &[])
        .unwrap()
        .model;
    let specs = vec![
        ParamSpec::new(Param::element("stop", "k1"), 5e4, 1e6),
        ParamSpec::new(Param::element("stop", "e1"), 5e-4, 2e-3),
    ];
    let red = nlsim_reduction::reduce(&model, &ReductionConfig::lowest(8)).unwrap();
    let f1 = red.modes.frequencies_hz()[0];
    (model, specs, vec![2e5, 1e-3], f1)
}

/// The bump-stop cantilever's record of a 3-s sweep at 0.6 N over ±20 % of its first
/// natural frequency, 80 samples per period of it, 2 % noise drawn from `seed`.
fn bumpstop_sweep(seed: u64) -> (Model, Vec<ParamSpec>, Vec<f64>, f64, TimeRecords) {
    let (model, specs, truth, f1) = bumpstop();
    let sweep = (0.6, 0.8 * f1, 1.2 * f1, 3.0);
    let rec = record(&model, &specs, &truth, sweep, 80.0 * f1, 0.02, seed);
    (model, specs, truth, f1, rec)
}

fn objective(model: &Model, specs: &[ParamSpec], rec: TimeRecords) -> TimeObjective {
    TimeObjective::new(
        model,
        &ReductionConfig::lowest(8),
        Arc::new(rec),
        specs.to_vec(),
    )
    .unwrap()
}

#[test]
fn the_jacobian_matches_central_differences_of_the_residuals() {
    let (model, specs, _, _, rec) = bumpstop_sweep(3);
    let mut obj = objective(&model, &specs, rec);
    let u = obj.to_internal(&[3e5, 1.2e-3]);
    let ev = obj.evaluate(&u).unwrap().unwrap();
    for j in 0..u.len() {
        // Internal variables are ln k1 and e1 (m). Steps of 1e-5 relative: each step's
        // element loop is solved by Newton to 1e-12 relative, which a difference quotient
        // divides by the relative step (1e-7 of a column); truncation is ~1e-10.
        let h = if j == 0 { 1e-5 } else { 1.2e-8 };
        let (mut a, mut b) = (u.clone(), u.clone());
        a[j] += h;
        b[j] -= h;
        let ra = obj.evaluate(&a).unwrap().unwrap().residuals;
        let rb = obj.evaluate(&b).unwrap().unwrap().residuals;
        let top = (0..ra.len())
            .map(|i| ev.jacobian[(i, j)].abs())
            .fold(0.0, f64::max);
        let worst = (0..ra.len())
            .map(|i| ((ra[i] - rb[i]) / (2.0 * h) - ev.jacobian[(i, j)]).abs())
            .fold(0.0, f64::max);
        eprintln!(
            "{}: |J − FD| ≤ {:.1e} of max |J| = {top:.3e}",
            specs[j].param,
            worst / top
        );
        assert!(
            worst <= 1e-6 * top,
            "{}: {worst:e} vs {top:e}",
            specs[j].param
        );
    }
}

#[test]
fn clearance_gap_and_stiffness_come_back_from_a_noisy_sweep() {
    let (model, specs, truth, f1, rec) = bumpstop_sweep(11);
    eprintln!(
        "{} samples at {:.1} Hz, f1 {f1:.2} Hz",
        rec.len(),
        rec.rate_hz
    );
    // The model's own values (the first candidate) away from the truth.
    let mut model = model;
    model.set_param(&specs[0].param, 4e5).unwrap();
    model.set_param(&specs[1].param, 1.5e-3).unwrap();
    let obj = objective(&model, &specs, rec);
    let cfg = CalibrationConfig {
        lhs_samples: 8,
        starts: 2,
        folds: 4,
        ..CalibrationConfig::default()
    };
    let cal = calibrate_time(&obj, &cfg, &|_| {}).unwrap();
    assert!(cal.status.is_converged(), "{:?}", cal.status);
    for j in 0..2 {
        let z = (cal.estimate[j] - truth[j]) / cal.cramer_rao.std[j];
        eprintln!(
            "{}: {:.6e} ± {:.2e} (truth {:e}, {z:+.2} σ); k-fold {:.6e} ± {:.2e}",
            specs[j].param,
            cal.estimate[j],
            cal.cramer_rao.std[j],
            truth[j],
            cal.kfold.as_ref().unwrap().mean[j],
            cal.kfold.as_ref().unwrap().jackknife_std[j]
        );
        // Within 3 Cramér–Rao standard deviations (the noise is the model's own: the
        // estimate is unbiased to first order).
        assert!(z.abs() <= 3.0, "{}: {z} σ", specs[j].param);
    }
    // The noise model is right: reduced χ² near 1 (ν ≈ 2·10⁴ residuals: ±0.01 at 1σ).
    assert!(
        (cal.cramer_rao.reduced_chi2 - 1.0).abs() < 0.05,
        "{}",
        cal.cramer_rao.reduced_chi2
    );
    // Threads change nothing.
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| calibrate_time(&obj, &cfg, &|_| {}).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.estimate, b.estimate);
    assert_eq!(a.kfold.unwrap().estimates, b.kfold.unwrap().estimates);
}

#[test]
fn a_cubic_coefficient_comes_back_from_a_noisy_sweep() {
    let model = nlsim_fixtures::ecl_beam().model;
    let specs = vec![ParamSpec::new(
        Param::element("tip_spring", "k3"),
        1e8,
        1e11,
    )];
    let truth = [model.param(&specs[0].param).unwrap()];
    let red = nlsim_reduction::reduce(&model, &ReductionConfig::lowest(8)).unwrap();
    let f1 = red.modes.frequencies_hz()[0];
    let rec = record(
        &model,
        &specs,
        &truth,
        (2.0, 0.8 * f1, 1.2 * f1, 3.0),
        60.0 * f1,
        0.02,
        5,
    );
    // The model's own value (the first candidate) away from the truth.
    let mut model = model;
    model.set_param(&specs[0].param, 2e10).unwrap();
    let obj = objective(&model, &specs, rec);
    let cfg = CalibrationConfig {
        lhs_samples: 8,
        starts: 2,
        folds: 0,
        ..CalibrationConfig::default()
    };
    let cal = calibrate_time(&obj, &cfg, &|_| {}).unwrap();
    let z = (cal.estimate[0] - truth[0]) / cal.cramer_rao.std[0];
    eprintln!(
        "k3: {:.6e} ± {:.2e} (truth {:e}, {z:+.2} σ), reduced chi2 {:.3}",
        cal.estimate[0], cal.cramer_rao.std[0], truth[0], cal.cramer_rao.reduced_chi2
    );
    assert!(z.abs() <= 3.0, "{z} σ");
}

#[test]
fn bad_records_are_named() {
    let (model, specs, truth, f1) = bumpstop();
    let good = record(
        &model,
        &specs,
        &truth,
        (0.6, f1, f1, 0.2),
        40.0 * f1,
        0.02,
        1,
    );
    let fails = |edit: &dyn Fn(&mut TimeRecords), says: &str| {
        let mut r = good.clone();
        edit(&mut r);
        let e = TimeObjective::new(
            &model,
            &ReductionConfig::lowest(8),
            Arc::new(r),
            specs.clone(),
        )
        .unwrap_err();
        assert!(e.to_string().contains(says), "expected '{says}' in: {e}");
    };
    fails(
        &|r| r.channels[1].values[17] = f64::NAN,
        "channel 'mid': sample 17",
    );
    fails(&|r| r.force[3] = f64::INFINITY, "drive 'shaker': sample 3");
    fails(
        &|r| {
            r.channels[0].values.pop();
        },
        "channel 'tip': samples",
    );
    fails(
        &|r| r.channels[0].sigma = 0.0,
        "noise standard deviation must be positive",
    );
    fails(
        &|r| r.channels[0].name = "nowhere".into(),
        "channel 'nowhere' is not a sensor",
    );
    fails(
        &|r| r.input = "hammer".into(),
        "'hammer', which is not an excitation",
    );
    fails(&|r| r.rate_hz = -1.0, "sample rate must be positive");
    let e = TimeObjective::new(
        &model,
        &ReductionConfig::lowest(8),
        Arc::new(good.clone()),
        vec![ParamSpec::new(Param::ModalDamping(0), 0.001, 0.1)],
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains("not a parameter of a nonlinear element"),
        "{e}"
    );
}
