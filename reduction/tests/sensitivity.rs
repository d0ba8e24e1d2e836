//! Analytic eigen-sensitivities against central differences of re-solved eigenproblems (the
//! dense generalized eigen solver as the oracle).

use faer::Mat;
use nlsim_kernel::linalg::dense_generalized_eigen_low as dense_eigen;
use nlsim_kernel::{Error, Model, Param, Parameterized, Status};
use nlsim_reduction::{
    EigenConfig, EigenSolver, ModeSelection, SensitivityConfig, eigen_sensitivities,
};

const N: usize = 60;

fn chain() -> Model {
    nlsim_fixtures::grouped_chain(N).unwrap()
}

fn params() -> Vec<Param> {
    [
        "group:mid.k_scale",
        "group:tip.m_scale",
        "group:root.k_scale",
        "group:root.m_scale",
        "spring:60:u.k",
    ]
    .iter()
    .map(|s| s.parse().unwrap())
    .collect()
}

/// Dense modes of the model with `p` set to `v`: eigenvalues and mass-normalised shapes with
/// the sign of `reference` (column by column).
fn dense_modes(model: &Model, p: &Param, v: f64, reference: &Mat<f64>) -> (Vec<f64>, Mat<f64>) {
    let mut m = model.clone();
    m.set_param(p, v).unwrap();
    let d = dense_eigen(
        m.stiffness().to_dense().as_ref(),
        m.mass().to_dense().as_ref(),
    )
    .unwrap();
    let mut vecs = d.vectors.clone();
    for r in 0..reference.ncols() {
        let dot: f64 = (0..N).map(|i| vecs[(i, r)] * reference[(i, r)]).sum();
        if dot < 0.0 {
            for i in 0..N {
                vecs[(i, r)] = -vecs[(i, r)];
            }
        }
    }
    (d.values, vecs)
}

#[test]
fn eigenvalue_and_shape_derivatives_match_central_differences() {
    let model = chain();
    let n_modes = 8;
    let cfg = EigenConfig {
        selection: ModeSelection::Lowest(n_modes),
        dense_below: 0,
        par: faer::Par::Seq,
        ..EigenConfig::default()
    };
    let mut solver = EigenSolver::new();
    let modes = solver.solve(model.stiffness(), model.mass(), &cfg).unwrap();
    let shape_dofs = vec![0, 17, 33, 46, 59];
    let sens = eigen_sensitivities(
        &model,
        &modes,
        &solver,
        &params(),
        &SensitivityConfig {
            shape_dofs: shape_dofs.clone(),
            ..SensitivityConfig::default()
        },
    )
    .unwrap();
    assert_eq!(sens.status, Status::Converged, "{sens:?}");
    assert!(sens.repeated.is_empty());
    // The static correction alone (one term) is not enough at this accuracy: the series is.
    let one = eigen_sensitivities(
        &model,
        &modes,
        &solver,
        &params(),
        &SensitivityConfig {
            shape_dofs: shape_dofs.clone(),
            max_terms: 1,
            ..SensitivityConfig::default()
        },
    )
    .unwrap();
    assert_eq!(one.status, Status::IterationLimit);
    assert!(one.truncation > 1e-3, "{}", one.truncation);
    eprintln!(
        "series terms {} (truncation {:.1e})",
        sens.terms, sens.truncation
    );
    for (j, p) in params().iter().enumerate() {
        let v0 = model.param(p).unwrap();
        // Relative step 1e-5: truncation O(h²) ≈ 1e-10 relative, round-off ≈ 1e-16/1e-5.
        let h = 1e-5 * v0;
        let (lp, vp) = dense_modes(&model, p, v0 + h, &modes.vectors);
        let (lm, vm) = dense_modes(&model, p, v0 - h, &modes.vectors);
        for r in 0..n_modes {
            let fd = (lp[r] - lm[r]) / (2.0 * h);
            let an = sens.eigenvalue[(r, j)];
            let scale = modes.eigenvalues[r] / v0;
            assert!(
                (an - fd).abs() <= 1e-7 * scale,
                "{p} mode {}: dλ/dp {an:e} vs FD {fd:e}",
                r + 1
            );
            let f = modes.eigenvalues[r].sqrt() / (2.0 * std::f64::consts::PI);
            let df_fd = ((lp[r].sqrt() - lm[r].sqrt()) / (2.0 * std::f64::consts::PI)) / (2.0 * h);
            assert!(
                (sens.frequency_hz[(r, j)] - df_fd).abs() <= 1e-7 * f / v0,
                "{p} mode {}: df/dp",
                r + 1
            );
            // Shapes: the scale of φ is 1/√(total mass) ≈ 0.18 m/√kg.
            let shape_scale = modes.vectors.col(r).norm_max() / v0;
            for (a, &d) in shape_dofs.iter().enumerate() {
                let fd = (vp[(d, r)] - vm[(d, r)]) / (2.0 * h);
                let an = sens.shapes[j][(a, r)];
                assert!(
                    (an - fd).abs() <= 1e-6 * shape_scale,
                    "{p} mode {} DOF {d}: dφ/dp {an:e} vs FD {fd:e}",
                    r + 1
                );
            }
        }
    }
}

#[test]
fn the_dense_path_makes_its_own_factor_and_agrees() {
    let model = chain();
    let mk = |dense_below| EigenConfig {
        selection: ModeSelection::Lowest(4),
        dense_below,
        par: faer::Par::Seq,
        ..EigenConfig::default()
    };
    let cfg = SensitivityConfig {
        shape_dofs: vec![10, 59],
        ..SensitivityConfig::default()
    };
    let mut lanczos = EigenSolver::new();
    let ml = lanczos
        .solve(model.stiffness(), model.mass(), &mk(0))
        .unwrap();
    let sl = eigen_sensitivities(&model, &ml, &lanczos, &params(), &cfg).unwrap();
    let mut dense = EigenSolver::new();
    let md = dense
        .solve(model.stiffness(), model.mass(), &mk(1000))
        .unwrap();
    let sd = eigen_sensitivities(&model, &md, &dense, &params(), &cfg).unwrap();
    for j in 0..params().len() {
        for r in 0..4 {
            let (a, b) = (sl.eigenvalue[(r, j)], sd.eigenvalue[(r, j)]);
            assert!((a - b).abs() <= 1e-8 * a.abs().max(1.0), "{a} vs {b}");
            for i in 0..2 {
                let (a, b) = (sl.shapes[j][(i, r)], sd.shapes[j][(i, r)]);
                assert!(
                    (a - b).abs() <= 1e-8 * ml.vectors.col(r).norm_max(),
                    "{a} vs {b}"
                );
            }
        }
    }
}

#[test]
fn bad_requests_are_errors_that_name_the_problem() {
    let model = chain();
    let cfg = EigenConfig {
        selection: ModeSelection::Lowest(3),
        dense_below: 0,
        par: faer::Par::Seq,
        ..EigenConfig::default()
    };
    let mut solver = EigenSolver::new();
    let modes = solver.solve(model.stiffness(), model.mass(), &cfg).unwrap();
    // An element or modal parameter has no matrix derivative.
    let e = eigen_sensitivities(
        &model,
        &modes,
        &solver,
        &["mode1.f".parse().unwrap()],
        &SensitivityConfig::default(),
    )
    .unwrap_err();
    assert!(matches!(e, Error::UnknownParameter { .. }), "{e}");
    assert!(e.to_string().contains("group:mid.k_scale"), "{e}");
    // A shape DOF outside the model.
    let e = eigen_sensitivities(
        &model,
        &modes,
        &solver,
        &params(),
        &SensitivityConfig {
            shape_dofs: vec![N],
            ..SensitivityConfig::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("shape DOF index 60"), "{e}");
    // A solver whose factor belongs to other matrices.
    let mut other = model.clone();
    other.set_param(&params()[0], 1.5).unwrap();
    let mut other_solver = EigenSolver::new();
    other_solver
        .solve(other.stiffness(), other.mass(), &cfg)
        .unwrap();
    let e = eigen_sensitivities(
        &model,
        &modes,
        &other_solver,
        &params(),
        &SensitivityConfig {
            shape_dofs: vec![1],
            ..SensitivityConfig::default()
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("does not belong"), "{e}");
}

/// The chain with ports: an element between DOFs 21 and 41 (weights ±1), a force at DOF 60,
/// a sensor at DOF 31, and DOF 1 as an extra port; Rayleigh damping.
fn chain_with_ports() -> Model {
    use nlsim_kernel::{Coupling, Damping, Excitation, Law, NonlinearElement, Quantity, Sensor};
    let mut m = chain();
    m.set_damping(Damping::Rayleigh {
        alpha: 0.3,
        beta: 1e-4,
    })
    .unwrap();
    let link = NonlinearElement::new("link", Law::Cubic { k3: 1e6 }, Coupling::relative(20, 40));
    m.add_element(link.unwrap()).unwrap();
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

#[test]
fn reduced_model_derivatives_match_central_differences() {
    use nlsim_reduction::{ReductionConfig, reduce_with, reduced_sensitivities};
    let model = chain_with_ports();
    let mut cfg = ReductionConfig::lowest(6);
    cfg.extra_dofs = vec![0];
    cfg.eigen.dense_below = 0;
    cfg.eigen.tol = 1e-13;
    cfg.eigen.par = faer::Par::Seq;
    let reduce_at = |p: &Param, v: f64| {
        let mut m = model.clone();
        m.set_param(p, v).unwrap();
        let mut solver = EigenSolver::new();
        let r = reduce_with(&m, &cfg, &mut solver, &mut |_| {}).unwrap();
        (r, m.damping().clone())
    };
    let mut solver = EigenSolver::new();
    let base = reduce_with(&model, &cfg, &mut solver, &mut |_| {}).unwrap();
    let d = reduced_sensitivities(
        &model,
        &base,
        &solver,
        &params(),
        &SensitivityConfig::default(),
    )
    .unwrap();
    assert_eq!(d.eigen.status, Status::Converged);
    let (np, m) = (base.ports.len(), base.n_modes());
    assert_eq!(np, 4);
    // The residual flexibility's shift is 0 for this supported chain, at every value.
    assert_eq!(base.residual_shift, 0.0);
    for (j, p) in params().iter().enumerate() {
        let v0 = model.param(p).unwrap();
        // Relative step 1e-5: truncation ≈ 1e-10, round-off of the 1e-13 eigen solves ≈ 1e-8.
        let h = 1e-5 * v0;
        let (rp, _) = reduce_at(p, v0 + h);
        let (rm, _) = reduce_at(p, v0 - h);
        assert_eq!(rp.residual_shift, 0.0);
        // ∂D: the residual flexibility at the ports.
        let d_scale = base.residual.norm_max() / v0;
        for a in 0..np {
            for b in 0..np {
                let fd = (rp.residual[(a, b)] - rm.residual[(a, b)]) / (2.0 * h);
                let an = d.residual[j][(a, b)];
                assert!(
                    (an - fd).abs() <= 1e-6 * d_scale,
                    "{p} ∂D[{a},{b}] {an:e} vs FD {fd:e} (scale {d_scale:e})"
                );
            }
        }
        // ∂Φ_P with each mode's sign aligned to the base.
        for r in 0..m {
            let sign = |x: &Mat<f64>| {
                let dot: f64 = (0..np)
                    .map(|a| x[(a, r)] * base.participation[(a, r)])
                    .sum();
                dot.signum()
            };
            let (sp, sm) = (sign(&rp.participation), sign(&rm.participation));
            let scale = base.participation.col(r).norm_max() / v0;
            for a in 0..np {
                let fd =
                    (sp * rp.participation[(a, r)] - sm * rm.participation[(a, r)]) / (2.0 * h);
                let an = d.participation[j][(a, r)];
                assert!(
                    (an - fd).abs() <= 1e-6 * scale,
                    "{p} ∂Φ_P[{a},{r}] {an:e} vs FD {fd:e}"
                );
            }
            // ∂C̃ of Rayleigh damping: β ∂λ_r on the diagonal.
            let c = |x: &nlsim_reduction::ReducedModel| x.modal_damping_matrix()[(r, r)];
            let fd = (c(&rp) - c(&rm)) / (2.0 * h);
            assert!(
                (d.damping[j][(r, r)] - fd).abs() <= 1e-7 * c(&base) / v0,
                "{p} ∂C̃[{r},{r}]"
            );
        }
    }
}
