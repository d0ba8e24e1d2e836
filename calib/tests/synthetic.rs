//! Calibration on synthetic data from known parameters (the thesis' check, §4.5–4.6): the ECL
//! beam's cubic tip spring and first-mode damping come back from a stepped-sine test.

use nlsim_calib::{
    CalibrationConfig, FoldBy, Form, FrfObjective, LeastSquares, Noise, ObjectiveConfig, Outcome,
    ParamSpec, Phase, Progress, Status, SweepPlan, TestData, calibrate, calibrate_until,
    synthesize,
};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Param, Parameterized};
use nlsim_reduction::{ReductionConfig, reduce};
use std::sync::Arc;

fn ecl_with(h: usize, rtol: f64) -> HbSystem {
    let fx = nlsim_fixtures::ecl_beam();
    let red = reduce(&fx.model, &ReductionConfig::lowest(4)).unwrap();
    let cfg = HbConfig {
        rtol,
        ..HbConfig::default()
    };
    HbSystem::from_model(&fx.model, &red, HarmonicSet::new(h, 1).unwrap(), cfg).unwrap()
}

fn ecl(h: usize) -> HbSystem {
    ecl_with(h, HbConfig::default().rtol)
}

fn plans() -> Vec<SweepPlan> {
    vec![
        SweepPlan::linear("0.05 N up", 22.0, 26.0, 17, 0.05),
        SweepPlan::linear("0.2 N up", 22.0, 27.0, 21, 0.2),
    ]
}

/// The bending mode near 23.7 Hz that the tip force drives. The square section makes the
/// two bending planes degenerate, so the mode with the larger participation at the tip
/// (the `uz` plane) is picked rather than assumed to be mode 1.
fn driven_mode(sys: &HbSystem) -> usize {
    sys.linear()
        .dominant_mode(sys.sensors()[0].port, 0..2)
        .unwrap()
}

fn params(sys: &HbSystem) -> Vec<Param> {
    vec![
        Param::element("tip_spring", "k3"),
        Param::ModalDamping(driven_mode(sys)),
    ]
}

fn specs_of(sys: &HbSystem) -> Vec<ParamSpec> {
    let p = params(sys);
    vec![
        ParamSpec::new(p[0].clone(), 1e8, 1e11),
        ParamSpec::new(p[1].clone(), 0.002, 0.05),
    ]
}

/// Data without noise, weighted as if it had `eps` relative noise.
fn data(sys: &HbSystem, noise: f64, seed: u64, weight: f64) -> TestData {
    let mut d = synthesize(sys, "shaker", &plans(), 3, Noise::relative(noise), seed).unwrap();
    for c in &mut d.channels {
        c.noise = Noise::relative(weight);
    }
    d
}

#[test]
fn objective_jacobian_matches_central_differences() {
    // Newton to 1e-13 relative: the third harmonic at 0.05 N is ~1e-5 of the fundamental and
    // its residual is weighted by 1/(1 % of itself), so the default 1e-10 (relative to the
    // fundamental) would leave round-off of the order of the finite-difference signal.
    let sys = ecl_with(3, 1e-13);
    let truth = sys.param_values(&params(&sys)).unwrap();
    let d = Arc::new(data(&sys, 0.0, 1, 0.01));
    for form in [Form::Complex, Form::LogMagnitudePhase] {
        let cfg = ObjectiveConfig {
            harmonics: vec![1, 3],
            form,
            ..ObjectiveConfig::default()
        };
        let mut obj = FrfObjective::new(&sys, d.clone(), specs_of(&sys), cfg).unwrap();
        // Away from the truth so that residuals are not zero.
        let p = [truth[0] * 1.7, truth[1] * 0.8];
        let u = obj.to_internal(&p);
        let ev = obj.evaluate(&u).unwrap().unwrap();
        for k in 0..2 {
            // Central differences in the internal variable with step 1e-5: truncation
            // ~1e-10 relative; the Newton tolerance 1e-10 gives round-off ~1e-5 relative.
            let h = 1e-5 * u[k].abs().max(1e-3);
            let (mut a, mut b) = (u.clone(), u.clone());
            a[k] += h;
            b[k] -= h;
            let ra = obj.evaluate(&a).unwrap().unwrap().residuals;
            let rb = obj.evaluate(&b).unwrap().unwrap().residuals;
            let col_max = (0..ra.len())
                .map(|i| ev.jacobian[(i, k)].abs())
                .fold(0.0, f64::max);
            assert!(col_max > 0.0);
            for i in 0..ra.len() {
                let fd = (ra[i] - rb[i]) / (2.0 * h);
                let an = ev.jacobian[(i, k)];
                assert!(
                    (fd - an).abs() <= 1e-4 * col_max,
                    "{form:?} J[{i},{k}] = {an} vs {fd}"
                );
            }
        }
    }
}

#[test]
fn noise_free_data_gives_the_parameters_back_from_far_starts() {
    let sys = ecl(3);
    let truth = sys.param_values(&params(&sys)).unwrap();
    let d = Arc::new(data(&sys, 0.0, 1, 0.01));
    // The model starts far from the truth: k3 a hundred times too large, damping 3x.
    let mut start = sys.clone();
    start
        .set_param(&Param::element("tip_spring", "k3"), 6e11)
        .unwrap();
    start.set_param(&params(&sys)[1], truth[1] * 3.0).unwrap();
    for harmonics in [vec![1], vec![1, 3]] {
        let obj = FrfObjective::new(
            &start,
            d.clone(),
            specs_of(&sys),
            ObjectiveConfig {
                harmonics,
                form: Form::Complex,
                ..ObjectiveConfig::default()
            },
        )
        .unwrap();
        let cfg = CalibrationConfig {
            lhs_samples: 16,
            starts: 2,
            folds: 0,
            ..Default::default()
        };
        let cal = calibrate(&obj, &cfg).unwrap();
        assert_eq!(cal.status, Status::Converged);
        for (e, t) in cal.estimate.iter().zip(&truth) {
            assert!(
                ((e - t) / t).abs() < 1e-6,
                "{:?} vs {truth:?}",
                cal.estimate
            );
        }
        assert!(cal.fit.failed.is_empty());
        assert!(cal.cost < 1e-10, "cost {}", cal.cost);
    }
}

#[test]
fn with_noise_the_kfold_spread_matches_the_cramer_rao_bound_and_side_harmonics_help() {
    let sys = ecl(3);
    let truth = sys.param_values(&params(&sys)).unwrap();
    let eps = 0.03;
    let d = Arc::new(data(&sys, eps, 7, eps));
    let mut cr_std = Vec::new();
    for harmonics in [vec![1], vec![1, 3]] {
        let obj = FrfObjective::new(
            &sys,
            d.clone(),
            specs_of(&sys),
            ObjectiveConfig {
                harmonics,
                form: Form::Complex,
                ..ObjectiveConfig::default()
            },
        )
        .unwrap();
        let cfg = CalibrationConfig {
            lhs_samples: 8,
            starts: 1,
            folds: 10,
            seed: 3,
            ..Default::default()
        };
        let cal = calibrate(&obj, &cfg).unwrap();
        let kf = cal.kfold.as_ref().unwrap();
        assert!(
            kf.status.iter().all(|s| s.is_converged()),
            "{:?}",
            kf.status
        );
        // With the right noise model the weighted residual is ~1 per degree of freedom.
        assert!(
            (0.7..1.3).contains(&cal.cramer_rao.reduced_chi2),
            "χ²/ν = {}",
            cal.cramer_rao.reduced_chi2
        );
        for j in 0..2 {
            let cr = cal.cramer_rao.std[j];
            let jk = kf.jackknife_std[j];
            // The jackknife std from 10 folds has ~25 % relative spread (χ with 9 degrees
            // of freedom), so agreement within a factor 2.5 is a 3-σ band.
            assert!(
                jk / cr > 0.4 && jk / cr < 2.5,
                "param {j}: jackknife {jk:e} vs Cramér–Rao {cr:e}"
            );
            // The estimate is within 4 Cramér–Rao deviations of the truth.
            assert!(
                (cal.estimate[j] - truth[j]).abs() < 4.0 * cr,
                "param {j}: {} vs {} ± {cr}",
                cal.estimate[j],
                truth[j]
            );
        }
        cr_std.push(cal.cramer_rao.std[0]);
    }
    // The third harmonic carries information on k3 that the fundamental does not (thesis).
    assert!(cr_std[1] < cr_std[0], "{cr_std:?}");
}

/// The ECL beam's k3 and damping on 2 % noise data, 12 candidates, 2 starts, 4 folds.
fn small_calibration() -> (FrfObjective, CalibrationConfig) {
    let sys = ecl(3);
    let d = Arc::new(data(&sys, 0.02, 5, 0.02));
    let obj = FrfObjective::new(&sys, d, specs_of(&sys), ObjectiveConfig::default()).unwrap();
    let cfg = CalibrationConfig {
        lhs_samples: 12,
        starts: 2,
        folds: 4,
        ..Default::default()
    };
    (obj, cfg)
}

#[test]
fn estimates_are_identical_on_one_and_two_threads() {
    let (obj, cfg) = small_calibration();
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| calibrate(&obj, &cfg).unwrap())
    };
    let (a, b) = (run(1), run(2));
    assert_eq!(a.estimate, b.estimate);
    assert_eq!(a.kfold.unwrap().estimates, b.kfold.unwrap().estimates);
    assert_eq!(
        a.candidates.iter().map(|c| c.cost).collect::<Vec<_>>(),
        b.candidates.iter().map(|c| c.cost).collect::<Vec<_>>()
    );
}

/// A calibration stopped at a safe point in each phase — after 5 candidates, after the first
/// optimisation, after the first fold — keeps what was complete, and resumed from the costs
/// it kept reaches the uninterrupted estimates, statistics and folds bit for bit. The stop is
/// raised from the progress callback (as a signal handler's flag would be, between units of
/// work), on one thread so that the count at which it lands is fixed.
#[test]
fn a_stopped_calibration_resumes_to_the_uninterrupted_result_bit_for_bit() {
    use std::sync::atomic::{AtomicBool, Ordering};
    let (obj, cfg) = small_calibration();
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(1)
        .build()
        .unwrap();
    let whole = pool.install(|| calibrate(&obj, &cfg).unwrap());
    type Trigger = fn(Progress) -> bool;
    let cases: [(&str, Trigger, Phase); 3] = [
        (
            "after 5 candidates",
            |p| matches!(p, Progress::Candidates { done: 5, .. }),
            Phase::Candidates,
        ),
        (
            "after the first optimisation",
            |p| matches!(p, Progress::Start { done: 1, .. }),
            Phase::Optimisation,
        ),
        (
            "after the first fold",
            |p| matches!(p, Progress::Fold { done: 1, .. }),
            Phase::CrossValidation,
        ),
    ];
    for (when, trigger, phase) in cases {
        let stop = AtomicBool::new(false);
        let outcome = pool.install(|| {
            calibrate_until(
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
            panic!("{when}: the calibration was not stopped");
        };
        assert_eq!(kept.phase, phase, "{when}");
        let expected_costs: Vec<f64> = whole.candidates.iter().map(|c| c.cost).collect();
        for (i, c) in kept.costs.iter().enumerate() {
            if let Some(c) = c {
                assert_eq!(
                    c.to_bits(),
                    expected_costs[i].to_bits(),
                    "{when}: candidate {i}"
                );
            }
        }
        if phase == Phase::Candidates {
            assert_eq!(kept.evaluated(), 5, "{when}");
            assert!(kept.runs.is_empty());
        } else {
            assert_eq!(kept.evaluated(), kept.points.len(), "{when}");
        }
        let best = kept.best().expect("a finite cost was reached");
        assert!(best.1.is_finite());
        let resumed =
            pool.install(|| calibrate_until(&obj, &cfg, &kept.costs, &|_| {}, &|| false).unwrap());
        let Outcome::Finished(c) = resumed else {
            panic!("{when}: the resumed calibration stopped");
        };
        assert_eq!(c.estimate, whole.estimate, "{when}");
        assert_eq!(c.cramer_rao.std, whole.cramer_rao.std, "{when}");
        assert_eq!(
            c.kfold.as_ref().unwrap().estimates,
            whole.kfold.as_ref().unwrap().estimates,
            "{when}"
        );
    }
}

#[test]
fn bad_settings_and_unknown_names_are_errors() {
    let sys = ecl(3);
    let d = data(&sys, 0.0, 1, 0.01);
    let mut renamed = d.clone();
    renamed.channels[0].name = "nowhere".into();
    let e = FrfObjective::new(
        &sys,
        Arc::new(renamed),
        specs_of(&sys),
        ObjectiveConfig::default(),
    )
    .unwrap_err();
    assert!(
        e.to_string().contains("nowhere") && e.to_string().contains("tip"),
        "{e}"
    );
    let bad = vec![ParamSpec::new(Param::element("tip_spring", "k9"), 1.0, 2.0)];
    assert!(FrfObjective::new(&sys, Arc::new(d.clone()), bad, ObjectiveConfig::default()).is_err());
    let inverted = vec![ParamSpec::new(Param::element("tip_spring", "k3"), 2.0, 1.0)];
    assert!(
        FrfObjective::new(
            &sys,
            Arc::new(d.clone()),
            inverted,
            ObjectiveConfig::default()
        )
        .is_err()
    );
    let h5 = ObjectiveConfig {
        harmonics: vec![5],
        form: Form::Complex,
        ..ObjectiveConfig::default()
    };
    assert!(FrfObjective::new(&sys, Arc::new(d.clone()), specs_of(&sys), h5).is_err());
    let obj = FrfObjective::new(
        &sys,
        Arc::new(d),
        specs_of(&sys),
        ObjectiveConfig::default(),
    )
    .unwrap();
    let cfg = CalibrationConfig {
        folds: 1,
        ..Default::default()
    };
    assert!(calibrate(&obj, &cfg).is_err());
}

/// The objective of `data` on harmonics 1 and 3, complex residuals.
fn complex_h13(sys: &HbSystem, data: TestData) -> FrfObjective {
    FrfObjective::new(
        sys,
        Arc::new(data),
        specs_of(sys),
        ObjectiveConfig {
            harmonics: vec![1, 3],
            form: Form::Complex,
            ..ObjectiveConfig::default()
        },
    )
    .unwrap()
}

/// Noise understated 10× (3 % noise weighted as 0.3 %): the reduced χ² is about 100, the
/// Cramér–Rao std 10× smaller than with the right weights (it assumes the stated noise),
/// the χ²-scaled std 10× the Cramér–Rao std and equal to the right-noise bound within the
/// sampling spread of χ², and the warning is given; with the right weights it is not.
#[test]
fn understated_noise_is_flagged_and_the_scaled_std_restores_the_spread() {
    let sys = ecl(3);
    let fit = |weight: f64| {
        let obj = complex_h13(&sys, data(&sys, 0.03, 11, weight));
        let cfg = CalibrationConfig {
            lhs_samples: 8,
            starts: 1,
            seed: 3,
            ..Default::default()
        };
        calibrate(&obj, &cfg).unwrap().cramer_rao
    };
    let right = fit(0.03);
    let under = fit(0.003);
    // ν = 2·(17 + 21)·2·2 − 2 = 302 points: χ²_red = 1 ± 0.08 with the right weights.
    assert!(
        (0.75..1.25).contains(&right.reduced_chi2),
        "{}",
        right.reduced_chi2
    );
    assert!(right.misfit_warning().is_none());
    assert!(
        (75.0..125.0).contains(&under.reduced_chi2),
        "{}",
        under.reduced_chi2
    );
    let w = under.misfit_warning().expect("a warning");
    assert!(w.contains("the residuals are"), "{w}");
    for j in 0..2 {
        let ratio = under.scaled_std[j] / under.std[j];
        assert!((ratio - under.reduced_chi2.sqrt()).abs() < 1e-9 * ratio);
        assert!((8.6..11.2).contains(&ratio), "param {j}: scaled/CR {ratio}");
        // The same estimate up to the optimiser's tolerance, so the bound scales with σ.
        let cr = under.std[j] / right.std[j];
        assert!((cr - 0.1).abs() < 2e-3, "param {j}: CR ratio {cr}");
        // The scaled std is the right-noise bound within χ²'s sampling spread (√χ² ± 8 %).
        let back = under.scaled_std[j] / right.std[j];
        assert!((0.85..1.15).contains(&back), "param {j}: {back}");
        let agree = right.scaled_std[j] / right.std[j];
        assert!((0.85..1.15).contains(&agree), "param {j}: {agree}");
    }
}

/// Leave-sweeps-out cross validation (`FoldBy::Sweeps`): four force levels, each held out
/// whole and predicted from the other three. The folds are the sweeps; with the right noise
/// model each held-out level is predicted at the noise level (rms weighted residual about
/// 1), and the jackknife spread of the four fold estimates agrees with the Cramér–Rao
/// bound within its sampling spread (3 degrees of freedom: a factor 0.3–2.6 is a 2.5-σ band
/// of χ₃/√3).
#[test]
fn leaving_sweeps_out_predicts_each_level_from_the_others() {
    let sys = ecl(3);
    let truth = sys.param_values(&params(&sys)).unwrap();
    let plans: Vec<SweepPlan> = [0.05, 0.1, 0.15, 0.2]
        .iter()
        .map(|&f| SweepPlan::linear(format!("{f} N up"), 22.0, 26.5, 19, f))
        .collect();
    let d = synthesize(&sys, "shaker", &plans, 3, Noise::relative(0.03), 5).unwrap();
    let obj = complex_h13(&sys, d);
    let cfg = CalibrationConfig {
        lhs_samples: 8,
        starts: 1,
        folds: 1,
        fold_by: FoldBy::Sweeps,
        seed: 3,
        ..Default::default()
    };
    let cal = calibrate(&obj, &cfg).unwrap();
    let kf = cal.kfold.as_ref().unwrap();
    assert_eq!(kf.k, 4);
    let want: Vec<usize> = (0..4).flat_map(|s| std::iter::repeat_n(s, 19)).collect();
    assert_eq!(kf.fold_of, want);
    assert!(
        kf.status.iter().all(|s| s.is_converged()),
        "{:?}",
        kf.status
    );
    for (f, &r) in kf.held_out_rms.iter().enumerate() {
        assert!((0.7..1.4).contains(&r), "sweep {f} held out: rms {r}");
    }
    for j in 0..2 {
        let cr = cal.cramer_rao.std[j];
        let jk = kf.jackknife_std[j];
        assert!(
            jk / cr > 0.3 && jk / cr < 2.6,
            "param {j}: jackknife {jk:e} vs Cramér–Rao {cr:e}"
        );
        assert!((cal.estimate[j] - truth[j]).abs() < 4.0 * cr);
    }
    // One sweep cannot be held out against the rest.
    let one = synthesize(&sys, "shaker", &plans[..1], 3, Noise::relative(0.03), 5).unwrap();
    let obj1 = FrfObjective::new(
        &sys,
        Arc::new(one),
        specs_of(&sys),
        ObjectiveConfig::default(),
    )
    .unwrap();
    let e = calibrate(&obj1, &cfg).unwrap_err().to_string();
    assert!(
        e.contains("fold_by = sweeps") && e.contains("1 sweep"),
        "{e}"
    );
}

/// Per-step noise: data whose real and imaginary parts carry different noise that changes
/// from step to step (σ_re from 1 % to 6 % of |Y| in a cycle of steps, σ_im = 0.3 σ_re),
/// with those standard deviations given per step (`Step::sigma`, the CSV's `_re_std`,
/// `_im_std` columns). Weighted by them the reduced χ² is 1 within its sampling spread, in
/// the complex and in the log-magnitude/phase form (whose amplitude and phase weights are
/// the given σ projected along and across Y), and the estimates lie within 3 Cramér–Rao
/// deviations of the truth.
#[test]
fn per_step_standard_deviations_weight_real_and_imaginary_parts() {
    use faer::{Mat, c64};
    use rand::{RngExt, SeedableRng};
    let sys = ecl(3);
    let truth = sys.param_values(&params(&sys)).unwrap();
    let mut d = synthesize(&sys, "shaker", &plans(), 3, Noise::relative(0.0), 1).unwrap();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(29);
    let mut normal = move || {
        let (u1, u2): (f64, f64) = (1.0 - rng.random::<f64>(), rng.random::<f64>());
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    };
    let mut n = 0usize;
    for sw in &mut d.sweeps {
        for st in &mut sw.steps {
            let (nc, h) = (st.response.nrows(), st.response.ncols());
            st.sigma = Mat::from_fn(nc, h, |_, _| c64::new(f64::NAN, f64::NAN));
            for c in 0..nc {
                for k in 0..h {
                    let y = st.response[(c, k)];
                    let s_re = (0.01 + 0.01 * (n % 6) as f64) * y.norm();
                    let s_im = 0.3 * s_re;
                    st.response[(c, k)] = y + c64::new(s_re * normal(), s_im * normal());
                    st.sigma[(c, k)] = c64::new(s_re, s_im);
                }
            }
            n += 1;
        }
    }
    d.validate_measured().unwrap();
    let fit = |data: TestData, form: Form| {
        let obj = FrfObjective::new(
            &sys,
            Arc::new(data),
            specs_of(&sys),
            ObjectiveConfig {
                harmonics: vec![1, 3],
                form,
                ..ObjectiveConfig::default()
            },
        )
        .unwrap();
        let cfg = CalibrationConfig {
            lhs_samples: 8,
            starts: 1,
            seed: 3,
            ..Default::default()
        };
        calibrate(&obj, &cfg).unwrap()
    };
    // ν = 2·(17 + 21)·2·2 − 2 = 302: χ²_red = 1 ± 0.08 (one σ).
    for form in [Form::Complex, Form::LogMagnitudePhase] {
        let cal = fit(d.clone(), form);
        let cr = &cal.cramer_rao;
        assert!(
            (0.75..1.25).contains(&cr.reduced_chi2),
            "{form:?}: reduced chi2 {}",
            cr.reduced_chi2
        );
        for j in 0..2 {
            let e = (cal.estimate[j] - truth[j]).abs() / cr.std[j];
            assert!(e < 3.0, "{form:?} param {j}: {e} Cramér–Rao deviations");
        }
    }
}
