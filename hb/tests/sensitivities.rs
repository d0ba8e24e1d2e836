//! Sensitivities `dQ/dp = −R_Q⁻¹ R_p` against central finite differences of re-solved FRFs.

use nlsim_fixtures::build;
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Model, Param, Parameterized};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModeSelection};

/// Re-solves with parameter `p` moved by `h` (on a copy) and returns the sensor response.
fn perturbed(
    sys: &HbSystem,
    p: &Param,
    h: f64,
    omega: f64,
    x0: &[f64],
) -> Option<faer::Mat<faer::c64>> {
    let mut s = sys.clone();
    let v = s.param(p).unwrap();
    // A contact exponent at its bound 1 cannot move down: None.
    s.set_param(p, v + h).ok()?;
    let (x, rep) = s.solve(omega, 1.0, x0).unwrap();
    assert!(rep.converged());
    Some(s.sensor_response(&x, omega, 1.0))
}

fn check(model: &Model, modes: usize, h: usize, at: f64) {
    let red = reduce(
        model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(modes),
                ..EigenConfig::default()
            },
            ..ReductionConfig::default()
        },
    )
    .unwrap();
    let sys = HbSystem::from_model(
        model,
        &red,
        HarmonicSet::new(h, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let omega = at * red.modes.omega()[0];
    let (x, _) = sys
        .solve_converged(omega, 1.0, &sys.linear_guess(omega, 1.0))
        .unwrap();
    let params = sys.parameters();
    let sens = sys.sensitivities(&x, omega, 1.0, &params).unwrap();
    for (p, s) in params.iter().zip(&sens) {
        assert_eq!(&s.param, p);
        let value = sys.param(p).unwrap();
        if value == 0.0 {
            // An absent side of the bump stop (k2 = 0, e2 = 0): no relative step exists.
            continue;
        }
        // Central differences with a relative step 1e-5: truncation ~1e-10 and the
        // solver's round-off (Newton to 1e-10 relative) / 1e-5 ~ 1e-5 of the response; a
        // forward difference (truncation ~1e-5) at a parameter bound.
        let step = 1e-5 * value.abs();
        let up = perturbed(&sys, p, step, omega, &x).unwrap();
        let fd = match perturbed(&sys, p, -step, omega, &x) {
            Some(down) => (up - down) * faer::Scale(faer::c64::new(1.0 / (2.0 * step), 0.0)),
            None => {
                (up - sys.sensor_response(&x, omega, 1.0))
                    * faer::Scale(faer::c64::new(1.0 / step, 0.0))
            }
        };
        let y = sys.sensor_response(&x, omega, 1.0);
        // Compare dY·p (the response change per relative parameter change) to the response.
        let scale =
            y.norm_max() * 1e-4 + (&fd * faer::Scale(faer::c64::new(value, 0.0))).norm_max() * 1e-4;
        // The element's main stiffness acts at this point (the bump stop is in contact).
        if matches!(p, Param::Element { .. }) && p == &sys.parameters()[0] {
            assert!(
                s.dy.norm_max() * value.abs() > 1e-3 * y.norm_max(),
                "{} has no effect",
                s.param
            );
        }
        let diff = (&fd - &s.dy).norm_max() * value.abs();
        assert!(
            diff <= scale,
            "{}: analytic {:?} vs finite difference {:?}",
            s.param,
            s.dy,
            fd
        );
    }
}

#[test]
fn duffing_sensitivities_match_finite_differences() {
    let model = build("duffing_fig3", &[]).unwrap().model;
    check(&model, 1, 5, 1.05);
}

#[test]
fn cubic_beam_sensitivities_match_finite_differences() {
    let model = build("ecl_beam", &[("elements".into(), "10".into())])
        .unwrap()
        .model;
    check(&model, 6, 5, 1.02);
}

#[test]
fn bump_stop_beam_sensitivities_match_finite_differences() {
    let model = build("bumpstop_cantilever", &[("elements".into(), "10".into())])
        .unwrap()
        .model;
    check(&model, 4, 5, 0.97);
}

/// Setting a parameter through [`Parameterized`] changes the residual exactly as building
/// the system from a model with the new value does (element parameters), and as the modal
/// formulas do (modal parameters, checked on the linear part's receptances in its unit test).
#[test]
fn setting_a_parameter_equals_rebuilding_the_system() {
    let model = build("ecl_beam", &[("elements".into(), "10".into())])
        .unwrap()
        .model;
    let red = reduce(
        &model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(4),
                ..EigenConfig::default()
            },
            ..ReductionConfig::default()
        },
    )
    .unwrap();
    let set = HarmonicSet::new(5, 1).unwrap();
    let mut sys = HbSystem::from_model(&model, &red, set, HbConfig::default()).unwrap();
    let p = model.parameters()[0].clone();
    let v = model.param(&p).unwrap() * 1.7;
    sys.set_param(&p, v).unwrap();
    let mut changed = model.clone();
    changed.set_param(&p, v).unwrap();
    let rebuilt = HbSystem::from_model(&changed, &red, set, HbConfig::default()).unwrap();
    let omega = 1.01 * red.modes.omega()[0];
    let x: Vec<f64> = rebuilt
        .linear_guess(omega, 1.0)
        .iter()
        .enumerate()
        .map(|(i, v)| v * (1.0 + 0.1 * i as f64))
        .collect();
    assert_eq!(
        sys.residual(&x, omega, 1.0).unwrap(),
        rebuilt.residual(&x, omega, 1.0).unwrap()
    );
    assert_eq!(sys.param(&p).unwrap(), v);
    // Round trip of every parameter's value: get, set the same value, nothing changes.
    let before = sys.residual(&x, omega, 1.0).unwrap();
    for q in sys.parameters() {
        let value = sys.param(&q).unwrap();
        sys.set_param(&q, value).unwrap();
    }
    let after = sys.residual(&x, omega, 1.0).unwrap();
    for (a, b) in after.iter().zip(&before) {
        assert!(
            (a - b).abs() <= 1e-13 * b.abs().max(1e-300) + 1e-300,
            "{a} vs {b}"
        );
    }
    // Unknown and out-of-range parameters are errors naming them.
    let e = sys
        .set_param(&"mode9.f".parse().unwrap(), 10.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("mode9.f") && e.contains("4 modes"), "{e}");
    let e = sys
        .set_param(&Param::GroupMass("web".into()), 1.0)
        .unwrap_err()
        .to_string();
    assert!(e.contains("group:web.m_scale"), "{e}");
}

/// The types a parallel caller (LHS candidates, k-fold runs) shares across threads.
#[test]
fn shared_types_are_send_and_sync() {
    fn send_sync<T: Send + Sync>() {}
    send_sync::<HbSystem>();
    send_sync::<nlsim_hb::ContinuationReport>();
    send_sync::<Param>();
    send_sync::<Model>();
    send_sync::<nlsim_reduction::ReducedModel>();
    send_sync::<nlsim_sim::Plant>();
    send_sync::<nlsim_sim::Simulator>();
}

/// A three-mass chain with a geometric coupling of its end masses (a law on two coordinates:
/// `g1 = 3e9 u1² u2 + 2e7 u1²`, `g2 = 1e9 u1³ + 4e12 u2³`): the sensitivities to every
/// coefficient go through the coupled element's parameter derivatives.
#[test]
fn coupled_polynomial_sensitivities_match_finite_differences() {
    use nlsim_kernel::{
        Coupling, Damping, DofMap, Excitation, Law, MonomialTerm, NonlinearElement, Quantity,
        Sensor, SparseSym,
    };
    let k = 1e5;
    let kk = vec![
        vec![2.0 * k, -k, 0.0],
        vec![-k, 2.0 * k, -k],
        vec![0.0, -k, 2.0 * k],
    ];
    let mut model = Model::new(
        "coupled_chain",
        DofMap::scalar(3),
        SparseSym::diagonal("M", &[1.0, 1.5, 1.0]).unwrap(),
        SparseSym::from_dense_rows("K", &kk).unwrap(),
    )
    .unwrap();
    model
        .set_damping(Damping::Rayleigh {
            alpha: 2.0,
            beta: 1e-5,
        })
        .unwrap();
    let term = MonomialTerm::new;
    let law = Law::CoupledPolynomial {
        inputs: 2,
        terms: vec![
            term(0, &[2, 1], 3e9),
            term(0, &[2, 0], 2e7),
            term(1, &[3, 0], 1e9),
            term(1, &[0, 3], 4e12),
        ],
    };
    model
        .add_element(
            NonlinearElement::coupled(
                "geometry",
                law,
                vec![Coupling::single(0), Coupling::single(2)],
            )
            .unwrap(),
        )
        .unwrap();
    model
        .add_excitation(Excitation {
            name: "f".into(),
            at: nlsim_kernel::Site::Dof(0),
            amplitude: 20.0,
            harmonics: Vec::new(),
        })
        .unwrap();
    for d in [0, 2] {
        model
            .add_sensor(Sensor {
                name: format!("q{d}"),
                at: nlsim_kernel::Site::Dof(d),
                quantity: Quantity::Displacement,
            })
            .unwrap();
    }
    check(&model, 3, 5, 1.03);
}
