//! NLvib's examples with their model data written out from the example definitions
//! (`../shared/data/reference-cases.md`).

use nlsim_hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, PointKind, continuation};
use nlsim_kernel::{
    Coupling, Damping, DofMap, Excitation, Law, Model, NonlinearElement, Quantity, Sensor,
    SparseSym,
};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModeSelection};
use std::f64::consts::PI;

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
    let cfg = ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(2),
            ..EigenConfig::default()
        },
        ..ReductionConfig::default()
    };
    let red = reduce(&model, &cfg).unwrap();
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
