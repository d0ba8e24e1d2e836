//! Calibration of the other synthetic cases of the thesis: the bump-stop beam (gap and
//! contact stiffness) and the hardening–softening beam (k2 and k3). Noise-free data from
//! known parameters must give them back from far starts.

use nlsim_calib::{
    CalibrationConfig, Form, FrfObjective, Noise, ObjectiveConfig, ParamSpec, Status, SweepPlan,
    calibrate, synthesize,
};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Param, Parameterized};
use nlsim_reduction::{ReductionConfig, reduce};
use std::sync::Arc;

fn system(name: &str, h: usize) -> HbSystem {
    let fx = nlsim_fixtures::build(name, &[]).unwrap();
    let red = reduce(&fx.model, &ReductionConfig::lowest(4)).unwrap();
    HbSystem::from_model(
        &fx.model,
        &red,
        HarmonicSet::new(h, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap()
}

/// Synthesises noise-free data from `sys`, moves the model to `start`, and calibrates from
/// a Latin hypercube over `specs`; returns the estimate and the truth.
fn recover(
    sys: &HbSystem,
    plans: &[SweepPlan],
    specs: Vec<ParamSpec>,
    start: &[f64],
    harmonics: Vec<usize>,
) -> (Vec<f64>, Vec<f64>) {
    let params: Vec<Param> = specs.iter().map(|s| s.param.clone()).collect();
    let truth = sys.param_values(&params).unwrap();
    let h = *harmonics.iter().max().unwrap();
    let mut data = synthesize(sys, "shaker", plans, h, Noise::relative(0.0), 1).unwrap();
    // 1 % of each response with a floor of 1e-8 m: below the stop's contact the even and
    // higher harmonics are exactly zero.
    for c in &mut data.channels {
        c.noise = Noise {
            absolute: 1e-8,
            relative: 0.01,
        };
    }
    let mut model = sys.clone();
    for (p, &v) in params.iter().zip(start) {
        model.set_param(p, v).unwrap();
    }
    let obj = FrfObjective::new(
        &model,
        Arc::new(data),
        specs,
        ObjectiveConfig {
            harmonics,
            form: Form::Complex,
            ..ObjectiveConfig::default()
        },
    )
    .unwrap();
    let cal = calibrate(
        &obj,
        &CalibrationConfig {
            lhs_samples: 24,
            starts: 2,
            folds: 0,
            ..CalibrationConfig::default()
        },
    )
    .unwrap();
    eprintln!(
        "{:?}: estimate {:?} truth {truth:?}, status {:?}, cost {:e}, failed {}, iterations {}",
        params.iter().map(ToString::to_string).collect::<Vec<_>>(),
        cal.estimate,
        cal.status,
        cal.cost,
        cal.fit.failed.len(),
        cal.runs[0].report.iterations
    );
    assert_eq!(cal.status, Status::Converged);
    assert!(cal.fit.failed.is_empty());
    (cal.estimate, truth)
}

#[test]
fn bump_stop_gap_and_contact_stiffness_come_back() {
    // Gap 1 mm, contact 2e5 N/m; at 0.05 N the tip stays clear of the stop (linear), at
    // 0.15 N and 0.3 N it closes the gap near resonance.
    let sys = system("bumpstop_cantilever", 7);
    let plans = vec![
        SweepPlan::linear("0.15 N up", 21.0, 27.0, 25, 0.15),
        SweepPlan::linear("0.3 N up", 21.0, 29.0, 33, 0.3),
    ];
    let specs = vec![
        ParamSpec::new(Param::element("stop", "k1"), 2e4, 2e6),
        ParamSpec::new(Param::element("stop", "e1"), 2e-4, 3e-3),
    ];
    let (est, truth) = recover(&sys, &plans, specs, &[1e6, 2.5e-3], vec![1, 2, 3]);
    for (e, t) in est.iter().zip(&truth) {
        assert!(((e - t) / t).abs() < 1e-6, "{est:?} vs {truth:?}");
    }
}

#[test]
fn hardening_softening_k2_and_k3_come_back() {
    let sys = system("hardening_softening_beam", 3);
    let plans = vec![
        SweepPlan::linear("0.01 N up", 21.0, 26.0, 21, 0.01),
        SweepPlan::linear("0.03 N down", 26.0, 21.0, 21, 0.03),
    ];
    let specs = vec![
        ParamSpec::new(Param::element("tip", "k2"), -5e7, 5e7),
        ParamSpec::new(Param::element("tip", "k3"), 1e8, 1e11),
    ];
    let (est, truth) = recover(&sys, &plans, specs, &[3e7, 5e10], vec![1, 2, 3]);
    for (e, t) in est.iter().zip(&truth) {
        assert!(((e - t) / t).abs() < 1e-6, "{est:?} vs {truth:?}");
    }
}
