//! NLvib's examples with their model data written out from the example definitions
//! (`../shared/data/reference-cases.md`).

use nlsim_hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, PointKind, continuation};
use nlsim_kernel::{
    Coupling, Damping, DofMap, Excitation, Law, Model, NonlinearElement, Quantity, Sensor,
    SparseSym,
};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use std::f64::consts::PI;

/// Both modes of a 2-DOF example.
fn both_modes(model: &Model) -> nlsim_reduction::modal::ReducedModel {
    reduce(model, &ReductionConfig::lowest(2)).unwrap()
}

/// Example 3: the chain `m = [1, 1]`, `k = [0, 1, 1]` (grounded-left, coupling,
/// grounded-right), `d = 0.03 k`, a unilateral spring of stiffness 100 beyond a gap of 1 on
/// DOF 1, a force of 0.1 on DOF 2.
fn example3() -> Model {
    let k = vec![vec![1.0, -1.0], vec![-1.0, 2.0]];
    let c: Vec<Vec<f64>> = k
        .iter()
        .map(|r| r.iter().map(|v| 0.03 * v).collect())
        .collect();
    let mut m = Model::new(
        "nlvib_ex3",
        DofMap::scalar(2),
        SparseSym::diagonal("M", &[1.0, 1.0]).unwrap(),
        SparseSym::from_dense_rows("K", &k).unwrap(),
    )
    .unwrap();
    m.set_damping(Damping::Matrix(
        SparseSym::from_dense_rows("C", &c).unwrap(),
    ))
    .unwrap();
    m.add_element(
        NonlinearElement::new("stop", Law::bump_stop(100.0, 1.0), Coupling::single(0)).unwrap(),
    )
    .unwrap();
    m.add_excitation(Excitation {
        name: "f".into(),
        dof: 1,
        amplitude: 0.1,
        harmonics: Vec::new(),
    })
    .unwrap();
    m.add_sensor(Sensor {
        name: "q1".into(),
        dof: 0,
        quantity: Quantity::Displacement,
    })
    .unwrap();
    m
}

/// Example 3's FRF from Ω = 0.8 down to 0.5 rad/s at H = 21: the branch turns twice, where
/// the first DOF starts to touch the stop (Ω ≈ 0.6534, amplitude at the gap) and at its
/// frequency maximum Ω ≈ 0.7556. The truncated harmonics of the contact force ripple the
/// branch near that maximum (nine turning points within 2e-3 rad/s): exactly one fold is
/// reported there, at the largest frequency of the branch, and none elsewhere.
#[test]
fn example3_has_two_folds_and_no_ripple_folds() {
    let model = example3();
    let red = both_modes(&model);
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(21, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let mut cc = ContinuationConfig::frequency(0.8 / (2.0 * PI), 0.5 / (2.0 * PI));
    cc.stability = false;
    let rep = continuation(&sys, &cc, None).unwrap();
    assert!(rep.is_complete(), "{}", rep.detail);
    let b = &rep.branch;
    let folds: Vec<f64> = b.folds().iter().map(|&i| b.points[i].omega).collect();
    assert_eq!(folds.len(), 2, "folds at {folds:?} rad/s");
    assert!(
        rep.stats.n_wiggles >= 1,
        "the ripples were there to dismiss"
    );
    let (low, high) = (folds[0].min(folds[1]), folds[0].max(folds[1]));
    assert!((low - 0.6534).abs() < 1e-3, "{low}");
    assert!((high - 0.7556).abs() < 1e-3, "{high}");
    // The fold kept is the branch's frequency maximum after the lower fold.
    let first = b.folds()[0];

    let top = b.points[first..]
        .iter()
        .map(|p| p.omega)
        .fold(0.0f64, f64::max);
    assert!(
        high >= top - 1e-9,
        "fold {high} below the branch's maximum {top}"
    );
    let i = b
        .folds()
        .into_iter()
        .find(|&i| b.points[i].omega == low)
        .unwrap();
    let a = sys.sensor_response(&b.points[i].x, low, 1.0)[(0, 1)].norm();
    assert!(
        (a - 1.0).abs() < 0.02,
        "amplitude {a} at the lower fold: the gap"
    );
    assert!(b.points.iter().all(|p| p.kind != PointKind::Jump));
}

/// Example 4: the chain `m = [1, 1]`, `k = [1, 1, 1]`, undamped, a cubic spring of 0.5 on
/// DOF 1; its first nonlinear mode at H = 9 by the extended periodic motion concept against
/// shooting on the free conservative ODE (RK4): the motion through the HB state at `t = 0`
/// (velocities zero by the phase normalisation and time reversibility) returns to rest at
/// half its period; its frequency equals HB's.
#[test]
fn example4_backbone_matches_shooting() {
    let k = vec![vec![2.0, -1.0], vec![-1.0, 2.0]];
    let mut model = Model::new(
        "nlvib_ex4",
        DofMap::scalar(2),
        SparseSym::diagonal("M", &[1.0, 1.0]).unwrap(),
        SparseSym::from_dense_rows("K", &k).unwrap(),
    )
    .unwrap();
    model
        .add_element(
            NonlinearElement::new("cubic", Law::Cubic { k3: 0.5 }, Coupling::single(0)).unwrap(),
        )
        .unwrap();
    model
        .add_excitation(Excitation {
            name: "f".into(),
            dof: 0,
            amplitude: 1.0,
            harmonics: Vec::new(),
        })
        .unwrap();
    for d in 0..2 {
        model
            .add_sensor(Sensor {
                name: format!("q{}", d + 1),
                dof: d,
                quantity: Quantity::Displacement,
            })
            .unwrap();
    }
    let red = both_modes(&model);
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(9, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let amps: Vec<f64> = (0..=20)
        .map(|i| 10f64.powf(-2.0 + 2.3 * i as f64 / 20.0))
        .collect();
    let rep = nlsim_hb::nnm::nonlinear_mode(&sys, 0, &amps, &mut |_| {}).unwrap();
    assert!(rep.status.is_converged(), "{}", rep.detail);
    assert_eq!(rep.points.len(), amps.len());
    let first = &rep.points[0];
    assert!((first.omega - 1.0).abs() < 1e-3, "{}", first.omega);
    let nh = 19;
    let phi = &red.participation; // ports × modes; the ports are the DOFs here
    let ports = &red.ports;
    let dof_row = |d: usize| {
        ports
            .iter()
            .position(|p| p.dofs == [d] && p.weights == [1.0])
            .unwrap()
    };
    let mut worst = 0.0f64;
    for p in rep.points.iter().step_by(4) {
        assert!(p.xi.abs() < 1e-9 * p.omega, "conservative: ξ = {}", p.xi);
        // Physical state at t = 0.
        let x0: Vec<f64> = (0..2)
            .map(|d| {
                let row = dof_row(d);
                (0..2)
                    .map(|r| {
                        phi[(row, r)]
                            * (0..nh)
                                .filter(|j| j % 2 == 1 || *j == 0)
                                .map(|j| p.eta[r * nh + j])
                                .sum::<f64>()
                    })
                    .sum()
            })
            .collect();
        // Shooting: x1(0) fixed, x2(0) and T free; v(T/2) = 0.
        let rhs = |z: [f64; 4]| -> [f64; 4] {
            [
                z[2],
                z[3],
                -(2.0 * z[0] - z[1]) - 0.5 * z[0].powi(3),
                -(2.0 * z[1] - z[0]),
            ]
        };
        let half = |x2: f64, t: f64| -> [f64; 2] {
            let n = 4000;
            let h = 0.5 * t / n as f64;
            let mut z = [x0[0], x2, 0.0, 0.0];
            for _ in 0..n {
                let add = |a: [f64; 4], b: [f64; 4], s: f64| -> [f64; 4] {
                    std::array::from_fn(|j| a[j] + s * b[j])
                };
                let k1 = rhs(z);
                let k2 = rhs(add(z, k1, 0.5 * h));
                let k3 = rhs(add(z, k2, 0.5 * h));
                let k4 = rhs(add(z, k3, h));
                z = std::array::from_fn(|j| {
                    z[j] + h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j])
                });
            }
            [z[2], z[3]]
        };
        let (mut x2, mut t) = (x0[1], 2.0 * PI / p.omega);
        for _ in 0..20 {
            let f = half(x2, t);
            let (hx, ht) = (1e-7 * x2.abs().max(1e-9), 1e-7 * t);
            let fx = half(x2 + hx, t);
            let ft = half(x2, t + ht);
            let j = [
                [(fx[0] - f[0]) / hx, (ft[0] - f[0]) / ht],
                [(fx[1] - f[1]) / hx, (ft[1] - f[1]) / ht],
            ];
            let det = j[0][0] * j[1][1] - j[0][1] * j[1][0];
            let dx = -(j[1][1] * f[0] - j[0][1] * f[1]) / det;
            let dt = -(-j[1][0] * f[0] + j[0][0] * f[1]) / det;
            x2 += dx;
            t += dt;
            if dt.abs() < 1e-15 * t && dx.abs() < 1e-14 * x2.abs().max(1e-9) {
                break;
            }
        }
        let exact = 2.0 * PI / t;
        worst = worst.max((p.omega - exact).abs() / exact);
        eprintln!(
            "a = {:.3e}: HB ω = {:.12}, shooting {exact:.12} (x2(0) {:.3e} vs {x2:.3e})",
            p.amplitude, p.omega, x0[1]
        );
    }
    assert!(worst < 1e-8, "{worst:e}");
    // The backbone hardens: ω grows with the amplitude.
    assert!(rep.points.windows(2).all(|w| w[1].omega > w[0].omega));
}

/// Example 5: `m = [0.02, 1]`, `k = [0, 40, 600]`, no viscous damping, regularised dry
/// friction `5 tanh(u̇/0.05)` on DOF 1. Its first nonlinear mode goes from the stuck joint
/// (DOF 1 held: `ω² = 640`, 4.0263 Hz) to full slip (the free structure's first mode,
/// `ω² = 583.5`, 3.8446 Hz) with a damping peak between (microslip), and the damping falls
/// back as the friction force becomes small against the elastic forces: checked against
/// those closed-form limits.
#[test]
fn example5_friction_mode_runs_from_stuck_to_slipping() {
    let k = vec![vec![40.0, -40.0], vec![-40.0, 640.0]];
    let mut model = Model::new(
        "nlvib_ex5",
        DofMap::scalar(2),
        SparseSym::diagonal("M", &[0.02, 1.0]).unwrap(),
        SparseSym::from_dense_rows("K", &k).unwrap(),
    )
    .unwrap();
    model
        .add_element(
            NonlinearElement::new(
                "friction",
                Law::Coulomb {
                    fc: 5.0,
                    v_reg: 0.05,
                },
                Coupling::single(0),
            )
            .unwrap(),
        )
        .unwrap();
    model
        .add_excitation(Excitation {
            name: "f".into(),
            dof: 1,
            amplitude: 0.0,
            harmonics: Vec::new(),
        })
        .unwrap();
    let red = both_modes(&model);
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(7, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let amps: Vec<f64> = (0..=40)
        .map(|i| 10f64.powf(-3.0 + 4.0 * i as f64 / 40.0))
        .collect();
    let rep = nlsim_hb::nnm::nonlinear_mode(&sys, 0, &amps, &mut |_| {}).unwrap();
    assert!(rep.status.is_converged(), "{}", rep.detail);
    let hz = |p: &nlsim_hb::nnm::NnmPoint| p.omega / (2.0 * PI);
    let (first, last) = (&rep.points[0], rep.points.last().unwrap());
    let stuck = 640f64.sqrt() / (2.0 * PI);
    // Free structure: det(K − ω² M) = 0, the lower root.
    let (a, b, c): (f64, f64, f64) = (0.02, -(40.0 + 0.02 * 640.0), 40.0 * 640.0 - 1600.0);
    let slip = ((-b - (b * b - 4.0 * a * c).sqrt()) / (2.0 * a)).sqrt() / (2.0 * PI);
    assert!(
        (hz(first) - stuck).abs() < 1e-4 * stuck,
        "{} vs {stuck}",
        hz(first)
    );
    assert!(
        (hz(last) - slip).abs() < 1e-4 * slip,
        "{} vs {slip}",
        hz(last)
    );
    let peak = rep
        .points
        .iter()
        .map(|p| p.damping_ratio())
        .fold(0.0f64, f64::max);
    assert!(peak > 0.02, "microslip damping {peak}");
    assert!(first.damping_ratio() < 0.1 * peak && last.damping_ratio() < 0.1 * peak);
    assert!(
        rep.points.iter().all(|p| p.xi > 0.0),
        "friction only dissipates"
    );
}
