//! Reduced receptances against the full `(K − ω²M + iωV)⁻¹` (dense complex solve), residual
//! flexibility, and the two constructions of the diagonal state-space form against each other.

use faer::{Mat, c64};
use nlsim_kernel::{Damping, Model, SparseSym};
use nlsim_reduction::{
    EigenConfig, ModalSystem, ModeSelection, ReductionConfig, Response, effective_masses, reduce,
};

/// `H = Wᵀ (K − ω²M + iωV)⁻¹ W` of the full model at the ports of `sys`.
fn full_receptance(model: &Model, v: &SparseSym, sys: &ModalSystem, omega: f64) -> Mat<c64> {
    let n = model.n_dofs();
    let (k, m, vd) = (
        model.stiffness().to_dense(),
        model.mass().to_dense(),
        v.to_dense(),
    );
    let a = Mat::from_fn(n, n, |i, j| {
        c64::new(k[(i, j)] - omega * omega * m[(i, j)], omega * vd[(i, j)])
    });
    let np = sys.ports.len();
    let w = Mat::from_fn(n, np, |i, p| {
        let port = &sys.ports[p];
        let w: f64 = port
            .dofs
            .iter()
            .zip(&port.weights)
            .filter(|(d, _)| **d == i)
            .map(|(_, w)| *w)
            .sum();
        c64::new(w, 0.0)
    });
    let x = faer::linalg::solvers::Solve::solve(&a.partial_piv_lu(), &w);
    w.transpose() * &x
}

fn rayleigh_matrix(model: &Model) -> SparseSym {
    match model.damping() {
        Damping::Rayleigh { alpha, beta } => {
            SparseSym::linear_combination("V", *alpha, model.mass(), *beta, model.stiffness())
                .unwrap()
        }
        _ => panic!("the ECL beam has Rayleigh damping"),
    }
}

fn reduced(model: &Model, n_modes: usize, residual: bool, lanczos: bool) -> ModalSystem {
    let cfg = ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(n_modes),
            dense_below: if lanczos { 0 } else { 10_000 },
            ..EigenConfig::default()
        },
        residual_flexibility: residual,
        extra_dofs: vec![],
    };
    ModalSystem::new(&reduce(model, &cfg).unwrap()).unwrap()
}

fn rel_err(a: c64, b: c64) -> f64 {
    (a - b).norm() / b.norm()
}

#[test]
fn receptances_converge_and_residual_flexibility_is_far_better_than_truncation() {
    let fx = nlsim_fixtures::ecl_beam();
    let model = &fx.model;
    let v = rayleigh_matrix(model);
    let probe = reduced(model, 4, true, true);
    let tip = probe
        .port_index("tip_spring")
        .unwrap_or_else(|_| probe.port_index("shaker").unwrap());
    let omegas: Vec<f64> = [5.0, 60.0, 100.0, 260.0]
        .iter()
        .map(|f| 2.0 * std::f64::consts::PI * f)
        .collect();
    let fulls: Vec<Mat<c64>> = omegas
        .iter()
        .map(|&w| full_receptance(model, &v, &probe, w))
        .collect();
    let mut last_plain = f64::INFINITY;
    let mut last_resid = f64::INFINITY;
    for (n_modes, lanczos) in [(8, true), (16, true), (32, false)] {
        let plain = reduced(model, n_modes, false, lanczos);
        let resid = reduced(model, n_modes, true, lanczos);
        let (mut ep, mut er) = (0.0f64, 0.0f64);
        for (w, full) in omegas.iter().zip(&fulls) {
            let hp = plain.receptance(*w).unwrap();
            let hr = resid.receptance(*w).unwrap();
            ep = ep.max(rel_err(hp[(tip, tip)], full[(tip, tip)]));
            er = er.max(rel_err(hr[(tip, tip)], full[(tip, tip)]));
        }
        // Both converge as modes are added ...
        assert!(
            ep < last_plain && er < last_resid,
            "{n_modes} modes: {ep:e} {er:e}"
        );
        // ... and the residual flexibility is far better than plain truncation.
        assert!(
            er < 0.05 * ep,
            "{n_modes} modes: with residual {er:e}, plain {ep:e}"
        );
        last_plain = ep;
        last_resid = er;
    }
    // 32 modes with residual flexibility: close to the full model.
    assert!(last_resid < 1e-4, "{last_resid:e}");
}

#[test]
fn all_modes_reproduce_the_full_model_exactly() {
    // With every mode kept, the reduced receptance is the full one (no residual left).
    let fx = nlsim_fixtures::ecl_beam();
    let model = &fx.model;
    let v = rayleigh_matrix(model);
    let sys = reduced(model, model.n_dofs(), true, false);
    assert!(
        sys.feedthrough.norm_max() < 1e-12 * 1e-3,
        "{:e}",
        sys.feedthrough.norm_max()
    );
    for f in [3.0, 23.0, 150.0, 1000.0] {
        let w = 2.0 * std::f64::consts::PI * f;
        let h = sys.receptance(w).unwrap();
        let full = full_receptance(model, &v, &sys, w);
        for i in 0..h.nrows() {
            for j in 0..h.ncols() {
                assert!(
                    (h[(i, j)] - full[(i, j)]).norm() < 1e-8 * full.norm_max(),
                    "{f} Hz ({i}, {j}): {} vs {}",
                    h[(i, j)],
                    full[(i, j)]
                );
            }
        }
    }
}

#[test]
fn matrix_damping_eigendecomposition_matches_the_closed_form() {
    // The same Rayleigh damping given as an explicit matrix takes the dense complex
    // eigendecomposition path; both forms must give the same poles and receptances.
    let fx = nlsim_fixtures::ecl_beam();
    let mut model = fx.model.clone();
    let closed = reduced(&model, 12, true, true);
    let v = rayleigh_matrix(&model);
    model.set_damping(Damping::Matrix(v)).unwrap();
    let coupled = reduced(&model, 12, true, true);
    assert_eq!(closed.n_states(), coupled.n_states());
    let mut a: Vec<c64> = closed.poles.clone();
    let mut b: Vec<c64> = coupled.poles.clone();
    a.sort_by(|x, y| x.im.total_cmp(&y.im));
    b.sort_by(|x, y| x.im.total_cmp(&y.im));
    for (x, y) in a.iter().zip(&b) {
        assert!((x - y).norm() < 1e-9 * x.norm(), "{x} vs {y}");
    }
    for f in [10.0, 23.66, 148.0, 400.0] {
        let w = 2.0 * std::f64::consts::PI * f;
        let (h1, h2) = (
            closed.receptance(w).unwrap(),
            coupled.receptance(w).unwrap(),
        );
        assert!(
            (&h1 - &h2).norm_max() < 1e-9 * h1.norm_max(),
            "{f} Hz: {:?} vs {:?}",
            h1.col(0),
            h2.col(0)
        );
        let (a1, a2) = (
            closed.frf(w, &[0], &[0], Response::Acceleration).unwrap(),
            coupled.frf(w, &[0], &[0], Response::Acceleration).unwrap(),
        );
        assert!((a1[(0, 0)] - a2[(0, 0)]).norm() < 1e-9 * a1[(0, 0)].norm());
    }
    // The acceleration feedthrough is Σ w Re(c̃ λ b̃) = Φ_P Φ_Pᵀ in both forms.
    for sys in [&closed, &coupled] {
        let np = sys.ports.len();
        for p in 0..np {
            for q in 0..np {
                let s: f64 = (0..sys.n_states())
                    .map(|r| {
                        sys.weights[r] * (sys.output[(p, r)] * sys.poles[r] * sys.input[(r, q)]).re
                    })
                    .sum();
                let d = sys.accel_feedthrough[(p, q)];
                assert!(
                    (s - d).abs() < 1e-8 * sys.accel_feedthrough.norm_max(),
                    "{s} vs {d}"
                );
            }
        }
    }
}

#[test]
fn overdamped_and_non_proportional_chain() {
    // A 2-DOF chain with a discrete damper between ground and mass 1 (non-proportional), and
    // one so strong that a mode is overdamped (real poles).
    let fx = nlsim_fixtures::build("chain_2dof", &[]).unwrap();
    for c in [3.0, 800.0] {
        let mut model = fx.model.clone();
        let v = SparseSym::from_triplets("V", 2, &[(0, 0, c)]).unwrap();
        model.set_damping(Damping::Matrix(v.clone())).unwrap();
        let sys = reduced(&model, 2, true, false);
        let real = sys.weights.iter().filter(|&&w| w == 1.0).count();
        if c > 400.0 {
            assert!(real >= 2, "heavy damping gives real poles: {:?}", sys.poles);
        } else {
            assert_eq!(real, 0);
        }
        for f in [1.0, 10.0, 16.0, 25.0, 100.0] {
            let w = 2.0 * std::f64::consts::PI * f;
            let h = sys.receptance(w).unwrap();
            let full = full_receptance(&model, &v, &sys, w);
            assert!(
                (&h - &full).norm_max() < 1e-10 * full.norm_max(),
                "c = {c}, {f} Hz: {h:?} vs {full:?}"
            );
        }
    }
}

#[test]
fn rigid_body_modes_without_damping_have_no_diagonal_form() {
    let cfg = nlsim_fixtures::bracket::BracketConfig {
        refinement: 1,
        clamped: false,
        lumped_mass: true,
    };
    let mut model = nlsim_fixtures::bracket_fixture(&cfg, "none").unwrap().model;
    model.set_damping(Damping::None).unwrap();
    let red = reduce(
        &model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(8),
                dense_below: 0,
                ..EigenConfig::default()
            },
            ..ReductionConfig::default()
        },
    )
    .unwrap();
    let e = ModalSystem::new(&red).unwrap_err().to_string();
    assert!(e.contains("mode 1") && e.contains("rigid-body"), "{e}");
    // Mass-proportional damping makes the rigid-body poles real and distinct (0 and −α).
    let mut red = red;
    red.damping = Damping::Rayleigh {
        alpha: 2.0,
        beta: 0.0,
    };
    let sys = ModalSystem::new(&red).unwrap();
    assert!(
        sys.poles
            .iter()
            .any(|p| (p.re + 2.0).abs() < 1e-9 && p.im == 0.0)
    );
}

#[test]
fn effective_masses_sum_to_the_total_with_all_modes() {
    let fx = nlsim_fixtures::ecl_beam();
    let model = &fx.model;
    let red = reduce(
        model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(model.n_dofs()),
                ..EigenConfig::default()
            },
            ..ReductionConfig::default()
        },
    )
    .unwrap();
    let em = effective_masses(model, &red.modes);
    assert_eq!(em.len(), 3);
    for e in &em {
        let s: f64 = e.per_mode.iter().sum();
        assert!(
            (s - e.total).abs() < 1e-9 * e.total,
            "{:?}: {s} vs {}",
            e.component,
            e.total
        );
    }
    // The first uz-bending mode carries 61.3 % of the beam's mass ρAL (the classical value for
    // the first mode of a uniform Euler–Bernoulli cantilever).
    let uz = em
        .iter()
        .find(|e| e.component == nlsim_kernel::Component::Uz)
        .unwrap();
    let rho_a_l = 7800.0 * 0.014 * 0.014 * 0.7;
    let first = uz.per_mode.iter().copied().fold(0.0, f64::max) / rho_a_l;
    assert!((first - 0.613).abs() < 0.01, "{first}");
}

#[test]
fn a_semi_definite_mass_is_refused_with_the_dof_labels() {
    // A speaker-box-like model: DOFs without mass (here the rotations of the frame, as a
    // lumped translational mass would leave them). No condensation is attempted: the error
    // names the DOFs and the remedies.
    let fx = nlsim_fixtures::ecl_beam();
    let model = &fx.model;
    let d: Vec<f64> = (0..model.n_dofs())
        .map(|i| {
            let c = model.dofs().label(i).component;
            if matches!(
                c,
                nlsim_kernel::Component::Rx
                    | nlsim_kernel::Component::Ry
                    | nlsim_kernel::Component::Rz
            ) {
                0.0
            } else {
                model.mass().get(i, i)
            }
        })
        .collect();
    let lumped = SparseSym::diagonal("mass matrix", &d).unwrap();
    let m2 = Model::new(
        "speaker",
        model.dofs().clone(),
        lumped,
        model.stiffness().clone(),
    )
    .unwrap();
    let e = reduce(&m2, &ReductionConfig::default())
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("60 DOF(s) have no mass") && e.contains("2:rx"),
        "{e}"
    );
    assert!(e.contains("condense them statically"), "{e}");
}

#[test]
fn all_modes_of_a_396_dof_beam_match_the_full_model_and_100_modes() {
    // 66 elements: λ₁/λ_max = 1.8e-10, below the old rigid-body threshold of 1e-9·λ_max that
    // turned the 23.7 Hz bending pair rigid once more than 106 modes were kept.
    let model = nlsim_fixtures::build("ecl_beam", &[("elements".into(), "66".into())])
        .unwrap()
        .model;
    assert_eq!(model.n_dofs(), 396);
    let v = rayleigh_matrix(&model);
    let all = reduced(&model, model.n_dofs(), true, false);
    let hundred = reduced(&model, 100, true, true);
    // No flexible mode is taken for a rigid one: every pole is at least the first bending
    // mode (23.66 Hz, damping 1 %) away from the origin.
    let slowest = all.poles.iter().fold(f64::INFINITY, |m, p| m.min(p.norm()));
    assert!(
        slowest > 2.0 * std::f64::consts::PI * 23.0,
        "slowest pole {slowest} rad/s"
    );
    let tip = all.port_index("tip_spring").unwrap();
    // Both the dense solve and the modal sum are accurate to about ε κ, κ = λ_max / λ₁ = 5.5e9.
    let modes = &reduce(
        &model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(model.n_dofs()),
                ..EigenConfig::default()
            },
            ..ReductionConfig::default()
        },
    )
    .unwrap()
    .modes;
    let kappa = modes.eigenvalues[model.n_dofs() - 1] / modes.eigenvalues[0];
    let attainable = 2.0 * f64::EPSILON * kappa;
    assert!((1e-6..1e-5).contains(&attainable), "{attainable:e}");
    for f in [3.0, 23.66, 150.0, 1000.0] {
        let w = 2.0 * std::f64::consts::PI * f;
        let full = full_receptance(&model, &v, &all, w);
        let h = all.receptance(w).unwrap();
        // All modes: the full model up to the attainable accuracy.
        for i in 0..h.nrows() {
            for j in 0..h.ncols() {
                assert!(
                    (h[(i, j)] - full[(i, j)]).norm() < attainable * full.norm_max(),
                    "all modes, {f} Hz ({i}, {j}): {} vs {}",
                    h[(i, j)],
                    full[(i, j)]
                );
            }
        }
        // 100 modes and the residual flexibility of the other 296: the quasi-static residual
        // misses the truncated modes' dynamics by (ω / ω₁₀₁)² of their share, itself below the
        // whole response away from antiresonances; and never beats the attainable accuracy.
        let e = rel_err(hundred.receptance(w).unwrap()[(tip, tip)], full[(tip, tip)]);
        let bound = (w * w / modes.eigenvalues[100]).max(attainable);
        assert!(e < bound, "100 modes at {f} Hz: {e:e} (bound {bound:e})");
    }
}
