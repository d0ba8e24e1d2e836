//! The parametric reduced model against full re-reduction (the oracle): receptances at the
//! ports over the parameters' box, the certificate firing where the basis cannot follow, and
//! the sensitivities against central differences of full re-reduction.

use faer::linalg::solvers::Solve;
use faer::{Mat, c64};
use nlsim_kernel::{
    Coupling, Damping, Excitation, Law, ModalDamping, Model, NonlinearElement, Param,
    Parameterized, Quantity, Sensor,
};
use nlsim_reduction::{
    ParametricConfig, ParametricReduction, ReducedModel, ReductionConfig, reduce,
};

/// The grouped chain (60 DOFs, three groups and a boundary spring) with a cubic element at
/// its end, a drive there and an acceleration sensor at its middle: three ports.
fn chain(damping: Damping) -> Model {
    let mut m = nlsim_fixtures::grouped_chain(60).unwrap();
    m.set_damping(damping).unwrap();
    m.add_element(
        NonlinearElement::new("tip", Law::Cubic { k3: 5e8 }, Coupling::single(59)).unwrap(),
    )
    .unwrap();
    m.add_excitation(Excitation {
        name: "shaker".into(),
        at: nlsim_kernel::Site::Dof(59),
        amplitude: 1.0,
        harmonics: Vec::new(),
    })
    .unwrap();
    m.add_sensor(Sensor {
        name: "mid".into(),
        at: nlsim_kernel::Site::Dof(30),
        quantity: Quantity::Acceleration,
    })
    .unwrap();
    m
}

fn params() -> Vec<Param> {
    [
        "group:mid.k_scale",
        "group:tip.m_scale",
        "group:root.k_scale",
        "spring:60:u.k",
    ]
    .iter()
    .map(|s| s.parse().unwrap())
    .collect()
}

/// Receptances `H(ω) = Φ_P Z⁻¹ Φ_Pᵀ + D` (thesis eq. 10) with the reduced model's modal
/// damping matrix, at the ports.
fn receptance(r: &ReducedModel, w: f64) -> Mat<c64> {
    let c = r.modal_damping_matrix();
    let m = r.n_modes();
    let z = Mat::from_fn(m, m, |i, j| {
        c64::new(
            if i == j {
                r.modes.eigenvalues[i] - w * w
            } else {
                0.0
            },
            w * c[(i, j)],
        )
    });
    let phi = Mat::from_fn(r.ports.len(), m, |i, j| {
        c64::new(r.participation[(i, j)], 0.0)
    });
    let zi = z.partial_piv_lu().solve(phi.transpose().to_owned());
    let d = Mat::from_fn(r.ports.len(), r.ports.len(), |i, j| {
        c64::new(r.residual[(i, j)], 0.0)
    });
    &phi * &zi + d
}

/// The largest receptance difference over 200 frequencies from 0.3 to 2.5 times the first
/// natural frequency, relative to the largest receptance there.
fn frf_difference(a: &ReducedModel, b: &ReducedModel) -> f64 {
    let w1 = b.modes.eigenvalues[0].sqrt();
    let (mut err, mut scale) = (0.0f64, 0.0f64);
    for s in 0..200 {
        let w = w1 * (0.3 + 2.2 * s as f64 / 199.0);
        let (ha, hb) = (receptance(a, w), receptance(b, w));
        err = err.max((&ha - &hb).norm_max());
        scale = scale.max(hb.norm_max());
    }
    err / scale
}

fn full_at(model: &Model, cfg: &ReductionConfig, params: &[Param], values: &[f64]) -> ReducedModel {
    let mut m = model.clone();
    for (p, &v) in params.iter().zip(values) {
        m.set_param(p, v).unwrap();
    }
    reduce(&m, cfg).unwrap()
}

fn lanczos(modes: usize) -> ReductionConfig {
    let mut cfg = ReductionConfig::lowest(modes);
    cfg.eigen.dense_below = 0;
    cfg.eigen.tol = 1e-13;
    cfg
}

#[test]
fn receptances_match_full_re_reduction_over_the_box() {
    // Scales 0.5–2, the spring 200–2e4 N/m: the first six frequencies move by up to 40 %.
    // The training (corners and centre) and the certificate at the default tolerance must
    // keep every receptance within 1e-6 of a full reduction at the same values, which is
    // the promise of the default.
    for damping in [
        Damping::Modal(ModalDamping::uniform(0.02)),
        Damping::Rayleigh {
            alpha: 0.2,
            beta: 2e-4,
        },
        Damping::Matrix(nlsim_kernel::SparseSym::diagonal("V", &[0.05; 60]).unwrap()),
    ] {
        let model = chain(damping);
        let cfg = lanczos(6);
        let p = params();
        let (lo, hi) = ([0.5, 0.5, 0.5, 200.0], [2.0, 2.0, 2.0, 2e4]);
        let mut training = vec![];
        for mask in 0..16usize {
            training.push(
                (0..4)
                    .map(|j| if mask >> j & 1 == 1 { hi[j] } else { lo[j] })
                    .collect(),
            );
        }
        let mut prom = ParametricReduction::new(
            &model,
            &cfg,
            &p,
            ParametricConfig::default(),
            &training,
            &mut |_| {},
        )
        .unwrap();
        // Points inside the box, none of them a training point.
        let points = [
            [1.0, 1.0, 1.0, 2e3],
            [0.7, 1.6, 1.3, 600.0],
            [1.8, 0.6, 0.8, 1.5e4],
            [1.25, 1.9, 0.55, 5e3],
        ];
        for v in points {
            let pt = prom.evaluate(&v, false, false).unwrap();
            let full = full_at(&model, &cfg, &p, &v);
            let d = frf_difference(&pt.reduced, &full);
            let de = pt
                .reduced
                .modes
                .eigenvalues
                .iter()
                .zip(&full.modes.eigenvalues)
                .map(|(a, b)| ((a - b) / b).abs())
                .fold(0.0, f64::max);
            eprintln!(
                "{:?} at {v:?}: indicator {:.1e} refreshed {} FRF {d:.1e} λ {de:.1e}",
                model.damping().kind(),
                pt.indicator,
                pt.refreshed
            );
            assert!(pt.indicator <= prom.settings().tolerance);
            assert!(d <= 1e-6, "FRF difference {d:e} at {v:?}");
            assert!(de <= 1e-9, "eigenvalue difference {de:e} at {v:?}");
        }
        eprintln!("{:?}", prom.stats());
    }
}

#[test]
fn certificate_fires_when_a_mode_crosses_the_band_and_the_refresh_matches() {
    // No training and no derivative directions: the basis is the nominal reduction. The
    // middle group stiffened 30 times moves the retained modes far (the third one leaves
    // the lowest four and a higher mode takes its place): the Ritz answer on the nominal
    // basis is wrong, the certificate must say so, and the refreshed answer must equal the
    // full reduction.
    let model = chain(Damping::Modal(ModalDamping::uniform(0.02)));
    let cfg = lanczos(4);
    let p: Vec<Param> = vec!["group:mid.k_scale".parse().unwrap()];
    let settings = ParametricConfig {
        derivative_vectors: false,
        ..ParametricConfig::default()
    };
    let mut prom = ParametricReduction::new(&model, &cfg, &p, settings, &[], &mut |_| {}).unwrap();
    let near = prom.evaluate(&[1.0], false, false).unwrap();
    assert!(
        !near.refreshed,
        "indicator {:e} at the nominal point",
        near.indicator
    );
    let far = prom.evaluate(&[30.0], false, true).unwrap();
    let full = full_at(&model, &cfg, &p, &[30.0]);
    let f = |r: &ReducedModel| -> Vec<f64> {
        r.modes
            .eigenvalues
            .iter()
            .map(|l| l.sqrt() / (2.0 * std::f64::consts::PI))
            .collect()
    };
    eprintln!(
        "nominal {:?}\nfull at 30 {:?}\nparametric {:?} (indicator {:.1e})",
        f(&near.reduced),
        f(&full),
        f(&far.reduced),
        far.indicator
    );
    assert!(far.refreshed);
    assert_eq!(prom.stats().refreshes, 1);
    let d = frf_difference(&far.reduced, &full);
    assert!(d <= 1e-8, "refreshed FRF difference {d:e}");
    // Kept: the next evaluation there passes without a refresh.
    let again = prom.evaluate(&[30.0], false, true).unwrap();
    assert!(!again.refreshed);
    assert_eq!(prom.stats().refreshes, 1);
}

#[test]
fn derivatives_match_central_differences_of_full_re_reduction() {
    // Central differences of full reductions (Lanczos to 1e-13) with a relative step of
    // 1e-5: truncation ~1e-10, round-off ~1e-13/1e-5 = 1e-8 of each quantity. The parametric
    // derivatives are exact for the Ritz model; they differ from the full model's by the
    // part of the exact derivative directions at these values that the basis lacks (only the
    // nominal point's directions are in it), which is first order in that miss where the
    // values are second order: measured 9e-6 relative at most here (the middle group), so
    // 2e-5 — a Jacobian that good moves a Cramér–Rao bound by as little.
    for damping in [
        Damping::Modal(ModalDamping::uniform(0.02)),
        Damping::Rayleigh {
            alpha: 0.2,
            beta: 2e-4,
        },
    ] {
        let model = chain(damping);
        let cfg = lanczos(6);
        let p = params();
        let v = [1.2, 0.9, 1.1, 3000.0];
        let mut prom = ParametricReduction::new(
            &model,
            &cfg,
            &p,
            ParametricConfig::default(),
            &[v.to_vec()],
            &mut |_| {},
        )
        .unwrap();
        let pt = prom.evaluate(&v, true, false).unwrap();
        let d = pt.derivatives.unwrap();
        for j in 0..p.len() {
            let h = 1e-5 * v[j];
            let (mut a, mut b) = (v, v);
            a[j] += h;
            b[j] -= h;
            let (ra, rb) = (full_at(&model, &cfg, &p, &a), full_at(&model, &cfg, &p, &b));
            let rel = |an: f64, fd: f64, scale: f64| (an - fd).abs() / scale;
            // Eigenvalues.
            let mut worst = 0.0f64;
            for r in 0..6 {
                let fd = (ra.modes.eigenvalues[r] - rb.modes.eigenvalues[r]) / (2.0 * h);
                worst = worst.max(rel(
                    d.eigenvalues[(r, j)],
                    fd,
                    pt.reduced.modes.eigenvalues[r] / v[j],
                ));
            }
            // Participation (signs fixed alike by the largest entry), residual, damping.
            let np = pt.reduced.ports.len();
            let pscale = pt.reduced.participation.norm_max() / v[j];
            let dscale = pt.reduced.residual.norm_max() / v[j];
            let cscale = pt.reduced.modal_damping_matrix().norm_max() / v[j];
            let (ca, cb) = (ra.modal_damping_matrix(), rb.modal_damping_matrix());
            for r in 0..6 {
                for q in 0..np {
                    let fd = (ra.participation[(q, r)] - rb.participation[(q, r)]) / (2.0 * h);
                    worst = worst.max(rel(d.participation[j][(q, r)], fd, pscale));
                }
                let fd = (ca[(r, r)] - cb[(r, r)]) / (2.0 * h);
                worst = worst.max(rel(d.damping[j][(r, r)], fd, cscale));
            }
            for q in 0..np {
                for s in 0..np {
                    let fd = (ra.residual[(q, s)] - rb.residual[(q, s)]) / (2.0 * h);
                    worst = worst.max(rel(d.residual[j][(q, s)], fd, dscale));
                }
            }
            eprintln!(
                "{:?} {}: worst relative difference {worst:.1e}",
                model.damping().kind(),
                p[j]
            );
            assert!(worst <= 2e-5, "{}: {worst:e}", p[j]);
        }
    }
}

#[test]
fn bad_settings_and_parameters_are_refused() {
    let model = chain(Damping::Modal(ModalDamping::uniform(0.02)));
    let cfg = ReductionConfig::lowest(4);
    let k3: Param = "tip.k3".parse().unwrap();
    let e = ParametricReduction::new(
        &model,
        &cfg,
        &[k3],
        ParametricConfig::default(),
        &[],
        &mut |_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("tip.k3"), "{e}");
    let p = params();
    let e = ParametricReduction::new(
        &model,
        &cfg,
        &p,
        ParametricConfig {
            tolerance: 0.0,
            ..ParametricConfig::default()
        },
        &[],
        &mut |_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("tolerance"), "{e}");
    let e = ParametricReduction::new(
        &model,
        &cfg,
        &p,
        ParametricConfig::default(),
        &[vec![1.0]],
        &mut |_| {},
    )
    .unwrap_err()
    .to_string();
    assert!(e.contains("training point 0"), "{e}");
    let mut prom = ParametricReduction::new(
        &model,
        &cfg,
        &p,
        ParametricConfig::default(),
        &[],
        &mut |_| {},
    )
    .unwrap();
    let e = prom
        .evaluate(&[1.0, 1.0, f64::NAN, 2e3], false, false)
        .unwrap_err()
        .to_string();
    assert!(e.contains("root"), "{e}");
    let e = prom
        .evaluate(&[1.0, 1.0, -1.0, 2e3], false, false)
        .unwrap_err()
        .to_string();
    assert!(e.contains("root"), "{e}");
}
