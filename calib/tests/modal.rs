//! The linear stage: FE-level parameters from modal data, on the grouped chain fixture
//! (60 DOFs, groups `mid`, `tip`, `root`, a boundary spring at DOF 60).

use faer::Par;
use nlsim_calib::{
    CalibrationConfig, FeReduction, Gaussian, LeastSquares, MeasuredMode, ModalData,
    ModalObjective, ParamSpec, ParametricConfig, Spacing, calibrate_modal,
};
use nlsim_kernel::{Error, Param, Parameterized, Status};
use nlsim_reduction::{EigenConfig, EigenSolver, ModeSelection};
use std::sync::Arc;

const SENSORS: [usize; 7] = [0, 10, 20, 30, 40, 50, 59];
const MEASURED: usize = 6;

fn specs() -> Vec<ParamSpec> {
    let p = |s: &str| s.parse::<Param>().unwrap();
    vec![
        ParamSpec::new(p("group:mid.k_scale"), 0.5, 2.0),
        ParamSpec::new(p("group:tip.m_scale"), 0.5, 1.5),
        ParamSpec::new(p("group:root.k_scale"), 0.5, 2.0),
        ParamSpec::new(p("spring:60:u.k"), 200.0, 2e4),
    ]
}

const TRUTH: [f64; 4] = [1.3, 0.85, 0.9, 3500.0];

/// The modes of the chain at the true values: frequencies and shapes at the sensors, with
/// relative frequency noise `f_noise` and shape noise `s_noise` (per component of the
/// unit-normalised shape) drawn from `seed`.
fn measured(f_noise: f64, s_noise: f64, seed: u64) -> ModalData {
    let mut truth = nlsim_fixtures::grouped_chain(60).unwrap();
    for (s, v) in specs().iter().zip(TRUTH) {
        truth.set_param(&s.param, v).unwrap();
    }
    let modes = EigenSolver::new()
        .solve(
            truth.stiffness(),
            truth.mass(),
            &EigenConfig {
                selection: ModeSelection::Lowest(MEASURED),
                par: Par::Seq,
                ..EigenConfig::default()
            },
        )
        .unwrap();
    let mut g = Gaussian::new(seed);
    let f = modes.frequencies_hz();
    let modes = (0..MEASURED)
        .map(|r| {
            let shape: Vec<f64> = SENSORS.iter().map(|&d| modes.vectors[(d, r)]).collect();
            let norm = shape.iter().map(|v| v * v).sum::<f64>().sqrt();
            MeasuredMode {
                frequency_hz: f[r] * (1.0 + f_noise * g.sample()),
                frequency_std_hz: f[r] * f_noise.max(1e-4),
                shape: Some(
                    shape
                        .iter()
                        .map(|v| v / norm + s_noise * g.sample())
                        .collect(),
                ),
            }
        })
        .collect();
    ModalData {
        dofs: SENSORS.to_vec(),
        shape_std: s_noise.max(1e-3),
        modes,
    }
}

fn objective(data: ModalData) -> ModalObjective {
    ModalObjective::new(
        nlsim_fixtures::grouped_chain(60).unwrap(),
        Arc::new(data),
        specs(),
        MEASURED + 3,
        Par::Seq,
    )
    .unwrap()
}

/// The objective with the modes from `fe`.
fn objective_with(data: ModalData, specs: Vec<ParamSpec>, fe: &FeReduction) -> ModalObjective {
    ModalObjective::with_reduction(
        nlsim_fixtures::grouped_chain(60).unwrap(),
        Arc::new(data),
        specs,
        MEASURED + 3,
        Par::Seq,
        fe,
    )
    .unwrap()
}

/// Interior points of the box of [`specs`] (values).
const INTERIOR: [[f64; 4]; 4] = [
    [1.1, 0.95, 1.2, 1500.0],
    [0.6, 1.4, 0.55, 250.0],
    [1.9, 0.55, 1.8, 1.8e4],
    [1.3, 0.85, 0.9, 3500.0],
];

/// The parametric model's residuals against a full eigen solve at every point (the
/// oracle): the certificate (1e-6) bounds the error of a shape component, relative, to first
/// order, and a frequency's to second order; measured ≤ 1e-9 of the largest residual.
#[test]
fn parametric_residuals_and_jacobian_match_full_eigen_solves() {
    let data = measured(2e-3, 1e-2, 5);
    let mut prom = objective_with(data.clone(), specs(), &FeReduction::default());
    let mut full = objective_with(data, specs(), &FeReduction::Full);
    let setup = prom.fe_stats();
    assert!(
        setup.parametric && setup.basis_size > MEASURED + 3,
        "{setup:?}"
    );
    for p in INTERIOR {
        let a = prom.fit_values(&p).unwrap().unwrap();
        let b = full.fit_values(&p).unwrap().unwrap();
        assert_eq!(a.pairing, b.pairing, "at {p:?}");
        let scale = b.residuals.iter().fold(1.0f64, |m, r| m.max(r.abs()));
        let worst = a
            .residuals
            .iter()
            .zip(&b.residuals)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        eprintln!(
            "at {p:?}: residuals differ by {:.1e} of the largest",
            worst / scale
        );
        for (i, (x, y)) in a.residuals.iter().zip(&b.residuals).enumerate() {
            assert!(
                (x - y).abs() <= 1e-6 * scale,
                "at {p:?}: residual {i}: {x} vs {y}"
            );
        }
        // The parametric Jacobian (exact for the Ritz model) against the full model's
        // analytic eigen-sensitivities.
        for j in 0..p.len() {
            let norm = (0..b.residuals.len())
                .map(|i| b.jacobian[(i, j)].powi(2))
                .sum::<f64>()
                .sqrt();
            for i in 0..b.residuals.len() {
                assert!(
                    (a.jacobian[(i, j)] - b.jacobian[(i, j)]).abs() <= 1e-5 * norm,
                    "at {p:?}: d r{i} / d {}: {} vs {}",
                    specs()[j].param,
                    a.jacobian[(i, j)],
                    b.jacobian[(i, j)]
                );
            }
        }
    }
    let st = full.fe_stats();
    assert!(
        !st.parametric && st.full_reductions == INTERIOR.len(),
        "{st:?}"
    );
}

/// The parametric Jacobian against central differences of the full re-solve's residuals
/// (step 1e-5 on internal variables of order 1: truncation ≈ 1e-10, round-off ≈ 1e-11 of
/// the residuals; the basis's missing derivative directions are first order in its own
/// error, ≤ 1e-5 of a column).
#[test]
fn parametric_jacobian_matches_central_differences_of_full_eigen_solves() {
    let data = measured(0.0, 0.0, 1);
    let mut prom = objective_with(data.clone(), specs(), &FeReduction::default());
    let mut full = objective_with(data, specs(), &FeReduction::Full);
    let u = prom.to_internal(&INTERIOR[1]);
    let jacobian = prom.evaluate(&u).unwrap().unwrap().jacobian;
    assert_matches_central_differences(&jacobian, &mut full, &u, 1e-5);
}

/// Asserts that every entry of `jacobian` (at `u`) is within `tol` of its column's norm of
/// the central differences (step 1e-5) of `obj`'s residuals.
fn assert_matches_central_differences(
    jacobian: &faer::Mat<f64>,
    obj: &mut ModalObjective,
    u: &[f64],
    tol: f64,
) {
    for j in 0..u.len() {
        let h = 1e-5;
        let mut up = u.to_vec();
        up[j] += h;
        let mut um = u.to_vec();
        um[j] -= h;
        let rp = obj.evaluate(&up).unwrap().unwrap().residuals;
        let rm = obj.evaluate(&um).unwrap().unwrap().residuals;
        let col_norm = (0..rp.len())
            .map(|i| jacobian[(i, j)].powi(2))
            .sum::<f64>()
            .sqrt();
        for i in 0..rp.len() {
            let fd = (rp[i] - rm[i]) / (2.0 * h);
            assert!(
                (jacobian[(i, j)] - fd).abs() <= tol * col_norm,
                "{}: residual {i}: {} vs FD {fd}",
                specs()[j].param,
                jacobian[(i, j)]
            );
        }
    }
}

/// Calibrations on noisy data with the parametric model and with full eigen solves agree
/// within 1e-3 of their Cramér–Rao bounds (the criterion), for any thread count.
#[test]
fn parametric_and_full_calibrations_agree_within_a_thousandth_of_the_bound() {
    let data = measured(2e-3, 1e-2, 11);
    let cfg = CalibrationConfig {
        lhs_samples: 8,
        starts: 2,
        ..CalibrationConfig::default()
    };
    let prom = objective_with(data.clone(), specs(), &FeReduction::default());
    let full = objective_with(data, specs(), &FeReduction::Full);
    let a = calibrate_modal(&prom, &cfg).unwrap();
    let b = calibrate_modal(&full, &cfg).unwrap();
    for j in 0..TRUTH.len() {
        let d = (a.estimate[j] - b.estimate[j]).abs() / b.cramer_rao.std[j];
        eprintln!("{}: {:e} of the bound", specs()[j].param, d);
        assert!(
            d <= 1e-3,
            "{}: {} vs {}",
            specs()[j].param,
            a.estimate[j],
            b.estimate[j]
        );
        let s = (a.cramer_rao.std[j] / b.cramer_rao.std[j] - 1.0).abs();
        assert!(
            s <= 1e-4,
            "{}: bound {} vs {}",
            specs()[j].param,
            a.cramer_rao.std[j],
            b.cramer_rao.std[j]
        );
    }
    assert_eq!(a.fit.pairing, b.fit.pairing);
}

/// The certificate fires: the mid group's stiffness scale over 0.05..40 moves the second to
/// fourth modes across the measured band (1.3 → 0.05 or 40 × the nominal stiffness of a third
/// of the chain). On the nominal basis alone (no training) an evaluation there fails the
/// certificate and is refreshed by a full eigen solve, and its residuals equal the full
/// solve's; with the default training the box's corners enrich the basis while it is built.
#[test]
fn the_certificate_refreshes_where_a_mode_moves_across_the_band() {
    let p = |s: &str| s.parse::<Param>().unwrap();
    let wide = vec![
        ParamSpec::new(p("group:mid.k_scale"), 0.05, 40.0),
        ParamSpec::new(p("spring:60:u.k"), 200.0, 2e4),
    ];
    let data = measured(0.0, 0.0, 1);
    let untrained = FeReduction::Parametric(ParametricConfig {
        max_training: 0,
        ..ParametricConfig::default()
    });
    let mut prom = objective_with(data.clone(), wide.clone(), &untrained);
    let mut full = objective_with(data.clone(), wide.clone(), &FeReduction::Full);
    let far = [30.0, 2000.0];
    let a = prom.fit_values(&far).unwrap().unwrap();
    let b = full.fit_values(&far).unwrap().unwrap();
    let st = prom.fe_stats();
    assert_eq!(
        (st.setup_reductions, st.refreshes, st.full_reductions),
        (1, 1, 1),
        "{st:?}"
    );
    // The modes did move: the nominal frequencies against those at the far point.
    let nominal = objective_with(data.clone(), wide.clone(), &FeReduction::Full)
        .fit_values(&[1.0, 2000.0])
        .unwrap()
        .unwrap();
    eprintln!(
        "nominal {:?}\nfar     {:?}",
        nominal.frequencies_hz, b.frequencies_hz
    );
    assert!(b.frequencies_hz[1] > 1.2 * nominal.frequencies_hz[1]);
    assert_eq!(a.pairing, b.pairing);
    let scale = b.residuals.iter().fold(1.0f64, |m, r| m.max(r.abs()));
    let worst = a
        .residuals
        .iter()
        .zip(&b.residuals)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    eprintln!(
        "refreshed: residuals differ by {:.1e} of the largest",
        worst / scale
    );
    for (x, y) in a.residuals.iter().zip(&b.residuals) {
        assert!((x - y).abs() <= 1e-6 * scale, "{x} vs {y}");
    }
    // Not kept by a cost-only evaluation: the next one there refreshes again.
    prom.fit_values(&far).unwrap().unwrap();
    assert_eq!(prom.fe_stats().refreshes, 2);
    // Kept by an optimisation step: the second one there does not.
    let u = prom.to_internal(&far);
    prom.evaluate(&u).unwrap().unwrap();
    prom.evaluate(&u).unwrap().unwrap();
    assert_eq!(prom.fe_stats().refreshes, 3);
    // The default training enriches at the box's corners while the objective is built.
    let trained = objective_with(data, wide, &FeReduction::default());
    assert!(
        trained.fe_stats().setup_reductions > 1,
        "{:?}",
        trained.fe_stats()
    );
}

#[test]
fn jacobian_matches_central_differences_of_the_residuals() {
    let mut obj = objective(measured(0.0, 0.0, 1));
    let u = obj.to_internal(&[1.1, 0.95, 1.2, 1500.0]);
    let jacobian = obj.evaluate(&u).unwrap().unwrap().jacobian;
    // Step 1e-5 on internal variables of order 1: truncation ≈ 1e-10, round-off ≈ 1e-11.
    assert_matches_central_differences(&jacobian, &mut obj, &u, 1e-6);
}

#[test]
fn noise_free_modal_data_returns_the_parameters_from_far_starts() {
    let obj = objective(measured(0.0, 0.0, 1));
    let cal = calibrate_modal(
        &obj,
        &CalibrationConfig {
            lhs_samples: 32,
            starts: 2,
            ..CalibrationConfig::default()
        },
    )
    .unwrap();
    assert_eq!(cal.status, Status::Converged);
    for (j, (&e, t)) in cal.estimate.iter().zip(TRUTH).enumerate() {
        assert!((e - t).abs() <= 1e-6 * t, "{}: {e} vs {t}", cal.params[j]);
    }
    assert_eq!(cal.fit.pairing, (0..MEASURED).collect::<Vec<_>>());
    assert!(cal.fit.mac.iter().all(|&m| m > 1.0 - 1e-12));
    assert_eq!(cal.fit.sensitivity_status, Status::Converged);
    // The spring is log-scaled (200..2e4 spans two decades): the optimiser works on ln k.
    assert_eq!(specs()[3].spacing, Spacing::Log);
    // Threads change nothing.
    let run = |threads| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| {
                calibrate_modal(
                    &obj,
                    &CalibrationConfig {
                        lhs_samples: 8,
                        starts: 2,
                        ..CalibrationConfig::default()
                    },
                )
                .unwrap()
                .estimate
            })
    };
    assert_eq!(run(1), run(2));
}

/// With noise, the spread of the estimates over independent noise draws matches the
/// Cramér–Rao bound of the weighted least-squares fit: for 40 draws the sample standard
/// deviation is within about ±11 % (1σ) of the true one, so [0.65, 1.5] is a 3σ band.
#[test]
fn noisy_estimates_scatter_as_the_cramer_rao_bound_says() {
    let draws = 40;
    let mut estimates = Vec::new();
    let mut bound = Vec::new();
    for seed in 0..draws {
        let obj = objective(measured(2e-3, 1e-2, 100 + seed));
        let cal = calibrate_modal(
            &obj,
            &CalibrationConfig {
                lhs_samples: 0,
                starts: 1,
                ..CalibrationConfig::default()
            },
        )
        .unwrap();
        assert!(cal.status.is_converged(), "seed {seed}: {:?}", cal.status);
        estimates.push(cal.estimate.clone());
        bound = cal.cramer_rao.std.clone();
    }
    let (mean, cov) = nlsim_calib::stats::mean_and_covariance(&estimates);
    for j in 0..TRUTH.len() {
        let spread = cov[(j, j)].sqrt();
        let ratio = spread / bound[j];
        eprintln!(
            "{}: mean {:.6} spread {spread:.3e} Cramér–Rao {:.3e} ratio {ratio:.2}",
            specs()[j].param,
            mean[j],
            bound[j]
        );
        assert!(
            (0.65..=1.5).contains(&ratio),
            "{}: spread {spread:e} vs Cramér–Rao {:e} (ratio {ratio:.2})",
            specs()[j].param,
            bound[j]
        );
        // Unbiased to within 4 standard errors of the mean.
        assert!(
            (mean[j] - TRUTH[j]).abs() <= 4.0 * spread / (draws as f64).sqrt(),
            "{}: mean {} vs truth {}",
            specs()[j].param,
            mean[j],
            TRUTH[j]
        );
    }
}

#[test]
fn bad_modal_inputs_are_named() {
    let model = || nlsim_fixtures::grouped_chain(60).unwrap();
    let mut data = measured(0.0, 0.0, 1);
    data.dofs[2] = 60;
    let e = ModalObjective::new(model(), Arc::new(data), specs(), 9, Par::Seq).unwrap_err();
    assert!(e.to_string().contains("sensor DOF index 60"), "{e}");

    let mut data = measured(0.0, 0.0, 1);
    data.modes[3].frequency_hz = f64::NAN;
    let e = ModalObjective::new(model(), Arc::new(data), specs(), 9, Par::Seq).unwrap_err();
    assert!(e.to_string().contains("measured mode 4"), "{e}");

    let mut data = measured(0.0, 0.0, 1);
    data.modes[1].shape.as_mut().unwrap().pop();
    let e = ModalObjective::new(model(), Arc::new(data), specs(), 9, Par::Seq).unwrap_err();
    assert!(e.to_string().contains("measured mode 2"), "{e}");

    // A parameter that is not FE-level.
    let mut with_element = specs();
    with_element.push(ParamSpec::new("tip.k3".parse().unwrap(), 1.0, 2.0));
    let e = ModalObjective::new(
        model(),
        Arc::new(measured(0.0, 0.0, 1)),
        with_element,
        9,
        Par::Seq,
    )
    .unwrap_err();
    assert!(matches!(e, Error::UnknownParameter { .. }), "{e}");

    // Fewer retained than measured modes.
    let e = ModalObjective::new(
        model(),
        Arc::new(measured(0.0, 0.0, 1)),
        specs(),
        3,
        Par::Seq,
    )
    .unwrap_err();
    assert!(e.to_string().contains("retain between 6"), "{e}");
}

/// A measured mode without a shape is paired with the computed mode nearest in frequency:
/// with modes 1, 2 and 5 measured (shapes not measured) the pairing is 1, 2, 5 and every
/// frequency residual vanishes at the true parameters; pairing by order took computed mode 3
/// for measured mode 5.
#[test]
fn shapeless_modes_pair_by_frequency() {
    let full = measured(0.0, 0.0, 1);
    let picked = [0usize, 1, 4];
    let data = ModalData {
        dofs: full.dofs.clone(),
        shape_std: full.shape_std,
        modes: picked
            .iter()
            .map(|&r| MeasuredMode {
                shape: None,
                ..full.modes[r].clone()
            })
            .collect(),
    };
    let mut obj = objective(data);
    let fit = obj.fit_values(&TRUTH).unwrap().unwrap();
    assert_eq!(fit.pairing, picked);
    for (i, &r) in picked.iter().enumerate() {
        let f = full.modes[r].frequency_hz;
        // The truth's own modes from the same solver: equal to round-off of the eigensolve.
        assert!((fit.frequencies_hz[i] - f).abs() <= 1e-9 * f, "mode {r}");
    }
}

/// A modal calibration stopped after 4 candidates, and one stopped in its first
/// optimisation, resume with the kept costs to the uninterrupted estimate, bit for bit.
#[test]
fn a_stopped_modal_calibration_resumes_bit_for_bit() {
    use nlsim_calib::{Outcome, Phase, Progress, calibrate_modal_until};
    use std::sync::atomic::{AtomicBool, Ordering};
    let obj = objective(measured(2e-3, 1e-2, 11));
    let cfg = CalibrationConfig {
        lhs_samples: 8,
        starts: 2,
        ..CalibrationConfig::default()
    };
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let whole = pool.install(|| calibrate_modal(&obj, &cfg).unwrap());
    type Trigger = fn(Progress) -> bool;
    let cases: [(Trigger, Phase); 2] = [
        (
            |p| matches!(p, Progress::Candidates { done: 4, .. }),
            Phase::Candidates,
        ),
        (
            |p| matches!(p, Progress::Start { done: 1, .. }),
            Phase::Optimisation,
        ),
    ];
    for (trigger, phase) in cases {
        let stop = AtomicBool::new(false);
        let outcome = pool.install(|| {
            calibrate_modal_until(
                &obj,
                &cfg,
                &[],
                &|p| {
                    if trigger(p) {
                        stop.store(true, Ordering::SeqCst);
                    }
                },
                &|| stop.load(Ordering::SeqCst),
            )
            .unwrap()
        });
        let Outcome::Interrupted(kept) = outcome else {
            panic!("{phase:?}: not stopped");
        };
        assert_eq!(kept.phase, phase);
        let resumed =
            match calibrate_modal_until(&obj, &cfg, &kept.costs, &|_| {}, &|| false).unwrap() {
                Outcome::Finished(c) => c,
                Outcome::Interrupted(_) => panic!("stopped without a stop"),
            };
        let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        assert_eq!(bits(&resumed.estimate), bits(&whole.estimate), "{phase:?}");
        assert_eq!(resumed.cost.to_bits(), whole.cost.to_bits(), "{phase:?}");
    }
}
