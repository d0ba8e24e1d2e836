//! FE-level parameters (group scales, a boundary spring) in the nonlinear calibration on
//! multi-harmonic FRFs, next to an element law parameter: the grouped chain fixture (60
//! DOFs, first mode 1.08 Hz) with a cubic spring at its free end, driven and measured there.

use nlsim_calib::{
    CalibrationConfig, FeReduction, Form, FrfObjective, LeastSquares, Noise, ObjectiveConfig,
    ParamSpec, ParametricConfig, Status, SweepPlan, TestData, calibrate, synthesize,
};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{
    Coupling, Damping, Excitation, Law, ModalDamping, Model, NonlinearElement, Param,
    Parameterized, Quantity, Sensor,
};
use nlsim_reduction::{ReductionConfig, reduce};
use std::sync::Arc;

fn chain(damping: Damping) -> Model {
    let mut m = nlsim_fixtures::grouped_chain(60).unwrap();
    m.set_damping(damping).unwrap();
    let cubic = NonlinearElement::new("tip", Law::Cubic { k3: 5e8 }, Coupling::single(59));
    m.add_element(cubic.unwrap()).unwrap();
    m.add_excitation(Excitation {
        name: "shaker".into(),
        at: nlsim_kernel::Site::Dof(59),
        amplitude: 1.0,
        harmonics: Vec::new(),
    })
    .unwrap();
    for (name, dof, quantity) in [
        ("tip", 59, Quantity::Displacement),
        ("mid", 30, Quantity::Acceleration),
    ] {
        m.add_sensor(Sensor {
            name: name.into(),
            at: nlsim_kernel::Site::Dof(dof),
            quantity,
        })
        .unwrap();
    }
    m
}

fn modal() -> Damping {
    Damping::Modal(ModalDamping::uniform(0.02))
}

fn rayleigh() -> Damping {
    Damping::Rayleigh {
        alpha: 0.2,
        beta: 2e-4,
    }
}

fn specs() -> Vec<ParamSpec> {
    let p = |s: &str| s.parse::<Param>().unwrap();
    vec![
        ParamSpec::new(p("group:mid.k_scale"), 0.5, 2.0),
        ParamSpec::new(p("group:tip.m_scale"), 0.5, 1.5),
        ParamSpec::new(p("spring:60:u.k"), 200.0, 2e4),
        ParamSpec::new(p("tip.k3"), 1e7, 1e10),
    ]
}

const TRUTH: [f64; 4] = [1.3, 0.85, 3500.0, 8e8];

/// Sweeps over the first mode at 0.3 N (mildly nonlinear) and 1 N (the peak falls by a
/// third, and the third harmonic reaches 13 % of the fundamental).
fn plans() -> Vec<SweepPlan> {
    vec![
        SweepPlan::linear("0.3 N up", 0.95, 1.3, 15, 0.3),
        SweepPlan::linear("1 N down", 1.3, 0.95, 15, 1.0),
    ]
}

fn reduction(lanczos: bool) -> ReductionConfig {
    let mut r = ReductionConfig::lowest(6);
    if lanczos {
        r.eigen.dense_below = 0;
        r.eigen.tol = 1e-13;
    }
    r
}

fn hb(rtol: f64) -> HbConfig {
    HbConfig {
        rtol,
        ..HbConfig::default()
    }
}

/// Noise-free data of the model at the true values, with a 1 % weight per value.
fn data(damping: Damping, rtol: f64) -> TestData {
    let mut truth = chain(damping);
    for (s, v) in specs().iter().zip(TRUTH) {
        truth.set_param(&s.param, v).unwrap();
    }
    let red = reduce(&truth, &reduction(false)).unwrap();
    let set = HarmonicSet::new(3, 1).unwrap();
    let sys = HbSystem::from_model(&truth, &red, set, hb(rtol)).unwrap();
    let mut d = synthesize(&sys, "shaker", &plans(), 3, Noise::relative(0.0), 1).unwrap();
    for c in &mut d.channels {
        c.noise = Noise::relative(0.01);
    }
    d
}

fn objective(damping: Damping, lanczos: bool, rtol: f64, form: Form) -> FrfObjective {
    FrfObjective::from_model(
        &chain(damping.clone()),
        &reduction(lanczos),
        HarmonicSet::new(3, 1).unwrap(),
        hb(rtol),
        Arc::new(data(damping, rtol)),
        specs(),
        ObjectiveConfig {
            harmonics: vec![1, 3],
            form,
            ..ObjectiveConfig::default()
        },
    )
    .unwrap()
}

#[test]
fn fe_level_jacobian_matches_central_differences() {
    // Newton to 1e-13 relative (as for the ECL objective): the residuals are weighted by
    // 1/(1 % of each value), so round-off of the default tolerance would be of the order of
    // the finite-difference signal. The eigen solves are exact to round-off (dense) or
    // converged to 1e-13 (Lanczos, whose residual flexibility is evaluated on its own
    // shift factor).
    for (damping, lanczos, form) in [
        (modal(), false, Form::Complex),
        (rayleigh(), false, Form::LogMagnitudePhase),
        (modal(), true, Form::Complex),
    ] {
        let mut obj = objective(damping.clone(), lanczos, 1e-13, form);
        // Away from the truth so that the residuals are not zero.
        let p = [1.1, 0.95, 2500.0, 5e8];
        let u = obj.to_internal(&p);
        let ev = obj.evaluate(&u).unwrap().unwrap();
        for k in 0..p.len() {
            // Central differences with a step of 1e-5 in the internal variable: truncation
            // ~1e-10 relative, round-off of the 1e-13 solves ~1e-8.
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
            let mut worst = 0.0f64;
            for i in 0..ra.len() {
                let fd = (ra[i] - rb[i]) / (2.0 * h);
                worst = worst.max((fd - ev.jacobian[(i, k)]).abs() / col_max);
            }
            eprintln!(
                "{damping:?} lanczos {lanczos} {form:?} {}: worst |J − FD| / max|J| = {worst:.2e}",
                specs()[k].param
            );
            assert!(worst <= 1e-5, "{}: {worst:e}", specs()[k].param);
        }
    }
}

#[test]
fn fe_level_and_law_parameters_come_back_on_any_thread_count() {
    let obj = objective(modal(), false, HbConfig::default().rtol, Form::Complex);
    let cfg = CalibrationConfig {
        lhs_samples: 16,
        starts: 2,
        folds: 0,
        ..CalibrationConfig::default()
    };
    let run = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| calibrate(&obj, &cfg).unwrap())
    };
    let (a, b) = (run(1), run(2));
    eprintln!(
        "estimate {:?}, status {:?}, cost {:e}, iterations {}",
        a.estimate, a.status, a.cost, a.runs[0].report.iterations
    );
    assert_eq!(a.status, Status::Converged);
    assert!(a.fit.failed.is_empty());
    for (e, t) in a.estimate.iter().zip(TRUTH) {
        assert!(((e - t) / t).abs() < 1e-6, "{:?} vs {TRUTH:?}", a.estimate);
    }
    assert_eq!(a.estimate, b.estimate);
    assert_eq!(
        a.candidates.iter().map(|c| c.cost).collect::<Vec<_>>(),
        b.candidates.iter().map(|c| c.cost).collect::<Vec<_>>()
    );
}

#[test]
fn modal_parameters_do_not_mix_with_fe_level_ones() {
    let mut mixed = specs();
    mixed.push(ParamSpec::new("mode1.zeta".parse().unwrap(), 0.001, 0.1));
    let e = FrfObjective::from_model(
        &chain(modal()),
        &reduction(false),
        HarmonicSet::new(3, 1).unwrap(),
        HbConfig::default(),
        Arc::new(data(modal(), 1e-10)),
        mixed,
        ObjectiveConfig::default(),
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("mode1.zeta") && e.contains("group:mid.k_scale"),
        "{e}"
    );
    // A damping matrix has no FE-level sensitivities by full re-reduction (they would need
    // the mode-shape derivatives at every DOF): refused when the Jacobian is first asked for,
    // naming the reason. The parametric model has them (its test is in parametric.rs).
    let n = 60;
    let v = nlsim_kernel::SparseSym::diagonal("C", &vec![0.1; n]).unwrap();
    let mut m = chain(Damping::Matrix(v));
    m.set_name("matrix-damped");
    let mut obj = FrfObjective::from_model_with(
        &m,
        &reduction(false),
        &FeReduction::Full,
        HarmonicSet::new(3, 1).unwrap(),
        HbConfig::default(),
        Arc::new(data(modal(), 1e-10)),
        specs(),
        ObjectiveConfig::default(),
    )
    .unwrap();
    let u = obj.to_internal(&TRUTH);
    let e = obj.evaluate(&u).unwrap_err().to_string();
    assert!(e.contains("damping matrix"), "{e}");
}

#[test]
fn parametric_jacobian_matches_central_differences_of_full_re_reduction() {
    // The same objective twice: the parametric reduced model (default) and a full reduction
    // per evaluation. Their residuals must agree to the parametric model's accuracy, and the
    // parametric Jacobian must match central differences of the full one (steps as in
    // fe_level_jacobian_matches_central_differences; the parametric derivatives miss the
    // part of the derivative directions outside the basis, ~1e-5 of a column at most, see
    // reduction/tests/parametric.rs).
    for damping in [
        modal(),
        Damping::Matrix(nlsim_kernel::SparseSym::diagonal("C", &[0.1; 60]).unwrap()),
    ] {
        let model = chain(damping.clone());
        let make = |fe: FeReduction| {
            FrfObjective::from_model_with(
                &model,
                &reduction(true),
                &fe,
                HarmonicSet::new(3, 1).unwrap(),
                hb(1e-13),
                Arc::new(data(damping.clone(), 1e-13)),
                specs(),
                ObjectiveConfig {
                    harmonics: vec![1, 3],
                    ..ObjectiveConfig::default()
                },
            )
            .unwrap()
        };
        let mut prom = make(FeReduction::default());
        let mut full = make(FeReduction::Full);
        let p = [1.1, 0.95, 2500.0, 5e8];
        let u = prom.to_internal(&p);
        let ev = prom.evaluate(&u).unwrap().unwrap();
        let base = full.evaluate_values(&p, None, false).unwrap().residuals;
        let rmax = base.iter().fold(0.0f64, |a, r| a.max(r.abs()));
        let dr = ev
            .residuals
            .iter()
            .zip(&base)
            .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
        eprintln!(
            "{}: residuals differ by {:.1e} of the largest",
            damping.kind(),
            dr / rmax
        );
        assert!(dr <= 1e-6 * rmax, "{dr:e} vs {rmax:e}");
        for k in 0..p.len() {
            let h = 1e-5 * u[k].abs().max(1e-3);
            let (mut a, mut b) = (u.clone(), u.clone());
            a[k] += h;
            b[k] -= h;
            let ra = full
                .evaluate_values(&full.to_values(&a), None, false)
                .unwrap()
                .residuals;
            let rb = full
                .evaluate_values(&full.to_values(&b), None, false)
                .unwrap()
                .residuals;
            let col_max = (0..ra.len())
                .map(|i| ev.jacobian[(i, k)].abs())
                .fold(0.0, f64::max);
            assert!(col_max > 0.0);
            let worst = (0..ra.len())
                .map(|i| ((ra[i] - rb[i]) / (2.0 * h) - ev.jacobian[(i, k)]).abs() / col_max)
                .fold(0.0, f64::max);
            eprintln!(
                "{}: {}: |J − FD(full)| / max|J| = {worst:.1e}",
                damping.kind(),
                specs()[k].param
            );
            assert!(worst <= 1e-5, "{}: {worst:e}", specs()[k].param);
        }
        let st = prom.fe_stats().unwrap();
        assert!(st.parametric && st.basis_size > 6, "{st:?}");
        assert_eq!(
            full.fe_stats().unwrap().refreshes,
            full.fe_stats().unwrap().evaluations
        );
    }
}

/// The certificate fires on the bracket (the hexahedral solid of the FE benchmarks, refinement
/// 2, consistent mass) with a grounded spring at the upright's tip whose range, 1e3 to 1e9 N/m,
/// moves the first mode out of the band the sweeps cover (±8 % about it): on the nominal
/// basis alone (no training) an evaluation at 1e8 N/m fails the certificate, is refreshed by a
/// full reduction, and its residuals equal those of a full re-reduction there; the default
/// training enriches the basis at the box's corners while the objective is built, and then
/// matches too.
#[test]
fn the_certificate_fires_on_the_bracket_when_the_tip_spring_moves_a_mode_out_of_the_band() {
    use nlsim_fixtures::bracket::BracketConfig;
    let cfg = BracketConfig {
        refinement: 2,
        lumped_mass: false,
        ..BracketConfig::default()
    };
    let mut model = nlsim_fixtures::bracket_fixture(&cfg, "cubic")
        .unwrap()
        .model;
    let tip = model.excitation()[0].at.clone();
    let dof = tip.dof().unwrap();
    model
        .add_sensor(Sensor {
            name: "tip_d".into(),
            at: tip,
            quantity: Quantity::Displacement,
        })
        .unwrap();
    model.add_boundary_spring(dof, 1e4).unwrap();
    model.set_param(&Param::element("tip", "k3"), 1e12).unwrap();
    let spring: Param = format!("spring:{}.k", model.dofs().labels()[dof])
        .parse()
        .unwrap();
    let specs = vec![
        ParamSpec::new(spring.clone(), 1e3, 1e9),
        ParamSpec::new(Param::element("tip", "k3"), 1e11, 1e13),
    ];
    let red = ReductionConfig::lowest(10);
    let nominal = reduce(&model, &red).unwrap();
    let f1 = nominal.modes.frequencies_hz()[0];
    let set = HarmonicSet::new(3, 1).unwrap();
    let sys = HbSystem::from_model(&model, &nominal, set, HbConfig::default()).unwrap();
    let plans = [
        SweepPlan::linear("0.5 N up", 0.92 * f1, 1.08 * f1, 8, 0.5),
        SweepPlan::linear("4 N down", 1.08 * f1, 0.92 * f1, 8, 4.0),
    ];
    let data = Arc::new(synthesize(&sys, "shaker", &plans, 3, Noise::relative(0.01), 7).unwrap());
    let make = |fe: FeReduction| {
        FrfObjective::from_model_with(
            &model,
            &red,
            &fe,
            set,
            HbConfig::default(),
            Arc::clone(&data),
            specs.clone(),
            ObjectiveConfig::default(),
        )
        .unwrap()
    };
    let far = [1e8, 1e12];
    // The mode did leave the band.
    let mut stiff = model.clone();
    stiff.set_param(&spring, far[0]).unwrap();
    let f1_far = reduce(&stiff, &red).unwrap().modes.frequencies_hz()[0];
    eprintln!(
        "{} DOFs: f1 {f1:.2} Hz at 1e4 N/m, {f1_far:.2} Hz at 1e8 N/m",
        model.n_dofs()
    );
    assert!(f1_far > 1.08 * f1, "{f1_far} vs {f1}");
    let mut full = make(FeReduction::Full);
    let base = full.evaluate_values(&far, None, false).unwrap().residuals;
    let rmax = base.iter().fold(0.0f64, |a, r| a.max(r.abs()));
    let untrained = FeReduction::Parametric(ParametricConfig {
        max_training: 0,
        ..ParametricConfig::default()
    });
    for (what, fe) in [
        ("untrained", untrained),
        ("trained", FeReduction::default()),
    ] {
        let mut prom = make(fe);
        let setup = prom.fe_stats().unwrap();
        let got = prom.evaluate_values(&far, None, false).unwrap().residuals;
        let st = prom.fe_stats().unwrap();
        let d = got
            .iter()
            .zip(&base)
            .fold(0.0f64, |a, (x, y)| a.max((x - y).abs()));
        eprintln!(
            "{what}: {setup:?}; after: {st:?}; residuals differ by {:.1e}",
            d / rmax
        );
        if what == "untrained" {
            assert_eq!((setup.setup_reductions, st.refreshes), (1, 1), "{st:?}");
        } else {
            assert!(setup.setup_reductions > 1, "{setup:?}");
        }
        assert!(d <= 1e-6 * rmax, "{what}: {d:e} vs {rmax:e}");
    }
}
