//! The sparse eigen solver against the dense generalized eigen solver (the oracle).

use faer::Mat;
use nlsim_fixtures::bracket::BracketConfig;
use nlsim_kernel::linalg::dense_generalized_eigen_low as dense_generalized_eigen;
use nlsim_kernel::{Error, SparseSym, Status};
use nlsim_reduction::{EigenConfig, EigenMethod, EigenSolver, ModeSelection, Modes};

fn lanczos(selection: ModeSelection) -> EigenConfig {
    EigenConfig {
        selection,
        dense_below: 0,
        ..EigenConfig::default()
    }
}

fn bracket(refinement: usize, clamped: bool) -> (SparseSym, SparseSym) {
    let cfg = BracketConfig {
        refinement,
        clamped,
        lumped_mass: false,
    };
    let f = nlsim_fixtures::bracket_fixture(&cfg, "none").unwrap();
    (f.model.stiffness().clone(), f.model.mass().clone())
}

fn ecl() -> (SparseSym, SparseSym) {
    let f = nlsim_fixtures::ecl_beam();
    (f.model.stiffness().clone(), f.model.mass().clone())
}

/// Eigenvalues to `rtol` relative (with `atol` for rigid-body modes at zero), and mode shapes
/// up to sign: for every cluster of (numerically) equal eigenvalues, the sparse vectors span the
/// dense ones, checked by `‖Φ_sᵀ M Φ_d‖` being orthogonal on the cluster.
fn compare(k: &SparseSym, m: &SparseSym, modes: &Modes, rtol: f64, atol: f64) {
    let dense = dense_generalized_eigen(k.to_dense().as_ref(), m.to_dense().as_ref()).unwrap();
    let n_modes = modes.len();
    for r in 0..n_modes {
        let (a, b) = (modes.eigenvalues[r], dense.values[r]);
        assert!(
            (a - b).abs() <= rtol * b.abs() + atol,
            "mode {}: λ = {a:e} against dense {b:e} (rel {:.2e})",
            r + 1,
            (a - b).abs() / b.abs()
        );
    }
    // Clusters: consecutive dense eigenvalues within 1e-8 relative (or both rigid).
    let md = m.to_dense();
    let cross = modes.vectors.transpose() * &md * &dense.vectors; // n_modes × n
    let mut start = 0;
    while start < n_modes {
        let mut end = start + 1;
        while end < dense.values.len()
            && (dense.values[end] - dense.values[start]).abs()
                <= 1e-8 * dense.values[start].abs() + atol
        {
            end += 1;
        }
        // Within the cluster (restricted to the sparse modes we have), the overlap with the
        // dense cluster must be a full-norm projection: Σ_j c_ij² = 1 for each sparse mode.
        for i in start..end.min(n_modes) {
            let s: f64 = (start..end).map(|j| cross[(i, j)].powi(2)).sum();
            assert!(
                (s - 1.0).abs() < 1e-7,
                "mode {} is not in the span of dense modes {}..{}: overlap {s}",
                i + 1,
                start + 1,
                end
            );
        }
        start = end;
    }
    // Mass normalisation.
    let g = modes.vectors.transpose() * &md * &modes.vectors;
    let eye = Mat::<f64>::identity(n_modes, n_modes);
    assert!(
        (&g - &eye).norm_max() < 1e-10,
        "ΦᵀMΦ ≠ I: {:e}",
        (&g - &eye).norm_max()
    );
}

#[test]
fn ecl_beam_with_symmetric_section_pairs() {
    let (k, m) = ecl();
    let mut s = EigenSolver::new();
    let modes = s
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(24)))
        .unwrap();
    assert_eq!(modes.stats.method, EigenMethod::Lanczos);
    compare(&k, &m, &modes, 1e-10, 0.0);
    // The square section gives equal bending pairs: both members present.
    let f = modes.frequencies_hz();
    assert!(
        (f[0] - f[1]).abs() < 1e-6 * f[0],
        "first bending pair {} {}",
        f[0],
        f[1]
    );
    // Backward error bound from the Ritz tolerance: the residual is controlled in the M norm,
    // so ρ ≤ tol · √κ(M) (κ(M) from the dense eigenvalues of M).
    let (mv, _) = nlsim_kernel::linalg::symmetric_eigen(m.to_dense().as_ref()).unwrap();
    let kappa = mv.last().unwrap() / mv[0];
    let bound = EigenConfig::default().tol * kappa.sqrt();
    assert!(
        modes.stats.max_residual < bound,
        "{:?} > {bound:e}",
        modes.stats
    );
    let (count, _) = modes.stats.sturm.unwrap();
    assert!(count >= 24);
}

#[test]
fn single_vector_blocks_do_not_miss_multiple_eigenvalues() {
    // With block size 1 a repeated eigenvalue can only appear through round-off; the Sturm
    // check must detect any miss and the solver enlarge the block until none is missed.
    let (k, m) = ecl();
    let cfg = EigenConfig {
        block_size: 1,
        ..lanczos(ModeSelection::Lowest(12))
    };
    let modes = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
    compare(&k, &m, &modes, 1e-10, 0.0);
}

#[test]
fn clamped_bracket_against_dense() {
    let (k, m) = bracket(1, true);
    let modes = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(40)))
        .unwrap();
    compare(&k, &m, &modes, 1e-10, 0.0);
    assert_eq!(modes.stats.shift, 0.0);
}

#[test]
fn free_free_bracket_finds_six_rigid_body_modes() {
    let (k, m) = bracket(1, false);
    let modes = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(16)))
        .unwrap();
    assert!(
        modes.stats.shift < 0.0,
        "a singular K needs a negative shift"
    );
    // Rigid-body eigenvalues are zero to round-off of the largest eigenvalue scale.
    let dense = dense_generalized_eigen(k.to_dense().as_ref(), m.to_dense().as_ref()).unwrap();
    let lmax = dense.values.last().copied().unwrap();
    compare(&k, &m, &modes, 1e-10, 1e-12 * lmax);
    let elastic = dense.values[6];
    for r in 0..6 {
        assert!(
            modes.eigenvalues[r].abs() < 1e-9 * elastic,
            "rigid mode {r}"
        );
    }
    assert!(modes.eigenvalues[6] > 0.5 * elastic);
}

#[test]
fn all_modes_below_a_frequency() {
    let (k, m) = bracket(1, true);
    let dense = dense_generalized_eigen(k.to_dense().as_ref(), m.to_dense().as_ref()).unwrap();
    // Midway between modes 17 and 18.
    let lim = 0.5 * (dense.values[16] + dense.values[17]);
    let f_max_hz = lim.sqrt() / (2.0 * std::f64::consts::PI);
    let modes = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Below { f_max_hz }))
        .unwrap();
    assert_eq!(modes.len(), 17);
    compare(&k, &m, &modes, 1e-10, 0.0);
    // The dense path agrees on the count.
    let cfg = EigenConfig {
        selection: ModeSelection::Below { f_max_hz },
        dense_below: 10_000,
        ..EigenConfig::default()
    };
    let d = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
    assert_eq!(d.stats.method, EigenMethod::Dense);
    assert_eq!(d.len(), 17);
}

#[test]
fn parameter_study_reuses_the_symbolic_analysis() {
    let (k, m) = bracket(1, true);
    let mut s = EigenSolver::new();
    let cfg = lanczos(ModeSelection::Lowest(8));
    let a = s.solve(&k, &m, &cfg).unwrap();
    assert!(!a.stats.reused_analysis);
    // Stiffer material: same pattern, eigenvalues scale exactly.
    let b = s.solve(&k.scaled(1.21), &m, &cfg).unwrap();
    assert!(b.stats.reused_analysis);
    assert_eq!(s.pencil().unwrap().analyses(), 1);
    for r in 0..8 {
        let want = 1.21 * a.eigenvalues[r];
        assert!((b.eigenvalues[r] - want).abs() < 1e-10 * want);
    }
}

#[test]
fn results_do_not_depend_on_the_seed_beyond_tolerance() {
    let (k, m) = bracket(1, true);
    let a = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(10)))
        .unwrap();
    let cfg = EigenConfig {
        seed: 99,
        block_size: 3,
        ..lanczos(ModeSelection::Lowest(10))
    };
    let b = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
    for r in 0..10 {
        assert!((a.eigenvalues[r] - b.eigenvalues[r]).abs() < 1e-11 * a.eigenvalues[r]);
    }
}

#[test]
fn bad_input_is_named() {
    let (k, m) = bracket(1, true);
    // A massless DOF (semi-definite mass, as in a speaker-box model with pressure DOFs).
    let n = m.n();
    let mut d = m.diag();
    d[17] = 0.0;
    let lumped = SparseSym::diagonal("M", &d).unwrap();
    let e = EigenSolver::new()
        .solve(&k, &lumped, &lanczos(ModeSelection::Lowest(5)))
        .unwrap_err();
    assert!(matches!(e, Error::MasslessDofs { count: 1, .. }), "{e}");
    assert!(e.to_string().contains("DOF index 17"), "{e}");
    // An indefinite stiffness.
    let neg = SparseSym::diagonal("K", &vec![-1e9; n]).unwrap();
    let bad = SparseSym::linear_combination("K", 1.0, &k, 1.0, &neg).unwrap();
    let e = EigenSolver::new()
        .solve(&bad, &m, &lanczos(ModeSelection::Lowest(5)))
        .unwrap_err();
    assert!(matches!(e, Error::NotDefinite { .. }), "{e}");
    // Non-finite values, wrong orders, impossible selections.
    let nan = SparseSym::diagonal("K", &vec![f64::NAN; n]).unwrap();
    let e = EigenSolver::new()
        .solve(&nan, &m, &lanczos(ModeSelection::Lowest(5)))
        .unwrap_err();
    assert!(matches!(e, Error::NonFinite { .. }), "{e}");
    let small = SparseSym::diagonal("M", &[1.0; 3]).unwrap();
    let e = EigenSolver::new()
        .solve(&k, &small, &lanczos(ModeSelection::Lowest(5)))
        .unwrap_err();
    assert!(matches!(e, Error::DimensionMismatch { .. }), "{e}");
    for sel in [
        ModeSelection::Lowest(0),
        ModeSelection::Lowest(n + 1),
        ModeSelection::Below { f_max_hz: -1.0 },
        ModeSelection::Below { f_max_hz: 1e-3 },
    ] {
        let e = EigenSolver::new().solve(&k, &m, &lanczos(sel)).unwrap_err();
        assert!(matches!(e, Error::InvalidInput { .. }), "{sel:?}: {e}");
    }
}

#[test]
fn sturm_check_catches_a_missed_multiple_eigenvalue_and_the_retry_finds_it() {
    // λ = 10 four times (DOFs 9..12), the last wanted modes. A single-vector Krylov space sees
    // one combination of the four; the Sturm count shows the miss and the solver retries with
    // a larger block.
    let n = 400;
    let mut d: Vec<f64> = (1..=n).map(|i| i as f64).collect();
    d[10] = 10.0;
    d[11] = 10.0;
    d[12] = 10.0;
    let k = SparseSym::diagonal("K", &d).unwrap();
    let m = SparseSym::diagonal("M", &vec![1.0; n]).unwrap();
    let cfg = EigenConfig {
        block_size: 1,
        ..lanczos(ModeSelection::Lowest(12))
    };
    let modes = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
    assert!(
        modes.stats.block_size > 1,
        "the miss must be detected: {:?}",
        modes.stats
    );
    let want = [
        1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0, 10.0, 10.0, 10.0,
    ];
    for (a, b) in modes.eigenvalues.iter().zip(want) {
        assert!((a - b).abs() < 1e-12 * b, "{a} vs {b}");
    }
    let (count, _) = modes.stats.sturm.unwrap();
    assert_eq!(count, 13);
}

#[test]
fn many_modes_converge_in_few_restarts() {
    // Regression: with `M V` kept by updates instead of recomputed, round-off built up in the
    // stored `M V` and 200 modes of the 30 600-DOF bracket never converged. 150 modes of the
    // 4 680-DOF bracket exercise the same large basis.
    let (k, m) = bracket(2, true);
    let modes = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(150)))
        .unwrap();
    assert!(modes.stats.restarts <= 6, "{:?}", modes.stats);
    assert_eq!(modes.stats.sturm.unwrap().0, 150);
    assert!(modes.stats.max_residual < 1e-9, "{:?}", modes.stats);
}

#[test]
fn a_restart_limit_returns_the_ritz_approximations_with_a_status() {
    // 40 modes of the clamped bracket with a small basis and no restart: not all converge.
    let (k, m) = bracket(1, true);
    let cfg = EigenConfig {
        basis_size: Some(56),
        max_restarts: 0,
        ..lanczos(ModeSelection::Lowest(40))
    };
    let modes = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
    assert_eq!(modes.stats.method, EigenMethod::Lanczos);
    assert_eq!(modes.stats.status, Status::IterationLimit);
    assert!(!modes.is_converged());
    assert_eq!(modes.len(), 40, "every wanted Ritz pair is returned");
    assert!(
        modes
            .stats
            .detail
            .contains("of 40 modes converged after 0 restarts"),
        "{}",
        modes.stats.detail
    );
    // The lowest pairs converge first: they already match the converged solve.
    let full = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(40)))
        .unwrap();
    assert!(full.is_converged(), "{}", full.stats.detail);
    let rel = (modes.eigenvalues[0] - full.eigenvalues[0]).abs() / full.eigenvalues[0];
    assert!(rel < 1e-8, "lowest Ritz value off by {rel:e}");
    // A caller that needs converged modes gets the detail as an error.
    let e = modes.into_converged().unwrap_err().to_string();
    assert!(
        e.contains("shift-invert Lanczos") && e.contains("raise the basis"),
        "{e}"
    );
}

/// A clamped planar Euler–Bernoulli beam (steel, 1 m, 20 × 10 mm) of `n` elements with
/// consistent mass: `2 n` DOFs (deflection and rotation per free node).
fn planar_beam(n: usize) -> (SparseSym, SparseSym) {
    let (e, rho, b, h) = (2.1e11, 7800.0, 0.02, 0.01);
    let (area, inertia, le) = (b * h, b * h * h * h / 12.0, 1.0 / n as f64);
    let ke = [
        [12.0, 6.0 * le, -12.0, 6.0 * le],
        [6.0 * le, 4.0 * le * le, -6.0 * le, 2.0 * le * le],
        [-12.0, -6.0 * le, 12.0, -6.0 * le],
        [6.0 * le, 2.0 * le * le, -6.0 * le, 4.0 * le * le],
    ];
    let me = [
        [156.0, 22.0 * le, 54.0, -13.0 * le],
        [22.0 * le, 4.0 * le * le, 13.0 * le, -3.0 * le * le],
        [54.0, 13.0 * le, 156.0, -22.0 * le],
        [-13.0 * le, -3.0 * le * le, -22.0 * le, 4.0 * le * le],
    ];
    let (kc, mc) = (e * inertia / le.powi(3), rho * area * le / 420.0);
    let (mut kt, mut mt) = (Vec::new(), Vec::new());
    for el in 0..n {
        // DOFs of the element's nodes el and el + 1; node 0 is clamped.
        let dofs = [
            2 * el as isize - 2,
            2 * el as isize - 1,
            2 * el as isize,
            2 * el as isize + 1,
        ];
        for a in 0..4 {
            for c in 0..4 {
                if dofs[a] >= 0 && dofs[c] >= 0 {
                    let (i, j) = (dofs[a] as usize, dofs[c] as usize);
                    kt.push((i, j, kc * ke[a][c]));
                    mt.push((i, j, mc * me[a][c]));
                }
            }
        }
    }
    (
        SparseSym::from_triplets("K", 2 * n, &kt).unwrap(),
        SparseSym::from_triplets("M", 2 * n, &mt).unwrap(),
    )
}

#[test]
fn most_of_the_spectrum_is_solved_densely_instead_of_hanging() {
    // Asking 199 of 400 modes left the Lanczos basis and the next block more than the space:
    // a fresh random vector could never be made independent, and the solver drew them forever.
    let (k, m) = planar_beam(200);
    for wanted in [199, 250, 400] {
        let modes = EigenSolver::new()
            .solve(&k, &m, &lanczos(ModeSelection::Lowest(wanted)))
            .unwrap();
        assert_eq!(modes.stats.method, EigenMethod::Dense);
        assert_eq!(modes.len(), wanted);
        assert!(modes.is_converged());
        // K is positive definite: no mode is rigid, however wide the spectrum
        // (λ_max / λ₁ ≈ 1e13 here).
        assert_eq!(modes.rigid_threshold, 0.0);
        assert!(modes.eigenvalues[wanted - 1] / modes.eigenvalues[0] > 1e9);
    }
    // The lowest modes against the Lanczos solution of a modest request.
    let few = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(10)))
        .unwrap();
    let many = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(250)))
        .unwrap();
    assert_eq!(few.stats.method, EigenMethod::Lanczos);
    for r in 0..10 {
        let (a, b) = (few.eigenvalues[r], many.eigenvalues[r]);
        // The dense path is accurate to ε λ_max in absolute terms, 1e-3 of λ₁ here at worst.
        assert!(
            (a - b).abs() <= 64.0 * f64::EPSILON * many.eigenvalues[249].max(a),
            "mode {r}: {a} vs {b}"
        );
    }
}

#[test]
fn a_singular_stiffness_sets_the_rigid_body_threshold_from_the_model() {
    let (k, m) = bracket(1, false);
    let lanczos_modes = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(10)))
        .unwrap();
    let dense_modes = EigenSolver::new()
        .solve(
            &k,
            &m,
            &EigenConfig {
                selection: ModeSelection::Lowest(10),
                ..EigenConfig::default()
            },
        )
        .unwrap();
    for modes in [&lanczos_modes, &dense_modes] {
        let scale = nlsim_reduction::stiffness_scale(&k, &m);
        assert_eq!(
            modes.rigid_threshold,
            nlsim_reduction::RIGID_RELATIVE * scale
        );
        let rigid = (0..10).filter(|&r| modes.is_rigid(r)).count();
        assert_eq!(rigid, 6, "{:?}", modes.eigenvalues);
    }
    let (k, m) = bracket(1, true);
    let clamped = EigenSolver::new()
        .solve(&k, &m, &lanczos(ModeSelection::Lowest(10)))
        .unwrap();
    assert_eq!(clamped.rigid_threshold, 0.0);
}

#[test]
fn a_degenerate_pair_is_not_split_at_the_cut_off() {
    // The ECL beam's symmetric section gives equal pairs: asking 3 modes returns 4 (the pair
    // 3–4 whole), on both paths, and the Sturm count agrees with the modes listed.
    let (k, m) = ecl();
    for dense in [false, true] {
        for (asked, kept) in [(3, 4), (4, 4), (1, 2)] {
            let cfg = EigenConfig {
                selection: ModeSelection::Lowest(asked),
                dense_below: if dense { 10_000 } else { 0 },
                sturm_check: true,
                ..EigenConfig::default()
            };
            let modes = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
            assert!(modes.is_converged(), "{}", modes.stats.detail);
            assert_eq!(modes.len(), kept, "dense {dense}, asked {asked}");
            assert_eq!(modes.vectors.ncols(), kept);
            let (l1, l2) = (modes.eigenvalues[kept - 2], modes.eigenvalues[kept - 1]);
            assert!((l1 - l2).abs() <= 1e-8 * l2, "{l1} {l2}");
            if let Some((count, _)) = modes.stats.sturm {
                assert_eq!(count, kept);
            }
        }
    }
}

/// A chain of `n` unit masses on unit springs, held to the ground by `k0` at its first mass
/// only: for `k0 = 1e-14` the stiffness is positive definite (its Cholesky succeeds) but
/// nearly singular, with one mode at about `k0 / n` rad²/s² and the next at about `(π/2n)²`.
fn nearly_free_chain(n: usize, k0: f64) -> (SparseSym, SparseSym) {
    let mut kt = vec![(0, 0, k0)];
    for i in 0..n - 1 {
        kt.extend([(i, i, 1.0), (i + 1, i + 1, 1.0), (i + 1, i, -1.0)]);
    }
    // Masses vary so that no eigenvalue is degenerate.
    let mt: Vec<(usize, usize, f64)> = (0..n).map(|i| (i, i, 1.0 + 0.01 * i as f64)).collect();
    (
        SparseSym::from_lower_triplets("K", n, &kt).unwrap(),
        SparseSym::from_lower_triplets("M", n, &mt).unwrap(),
    )
}

/// A stiffness with a near-null mode (positive definite, a pivot 1e-16 of the others): the
/// pencil is not inverted at σ = 0, where the other eigenvalues lose their accuracy (8.7e-6
/// relative on the dense path before), but at a shift chosen from the pencil; the others match the dense solve of `K φ = λ M φ` itself (absolute accuracy ε λ_max ≈ 1e-15, so
/// 1e-10 relative of λ₂ ≈ 2e-3 is a real check), on the dense path and on Lanczos, with
/// eigenvalues that are the vectors' Rayleigh quotients.
#[test]
fn a_near_null_stiffness_mode_is_shifted_away() {
    let (k, m) = nearly_free_chain(40, 1e-14);
    let oracle =
        nlsim_kernel::linalg::dense_generalized_eigen(k.to_dense().as_ref(), m.to_dense().as_ref())
            .unwrap();
    for (path, cfg) in [
        (
            "dense",
            EigenConfig {
                selection: ModeSelection::Lowest(8),
                ..EigenConfig::default()
            },
        ),
        ("lanczos", lanczos(ModeSelection::Lowest(8))),
    ] {
        let modes = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
        assert!(modes.is_converged(), "{path}: {}", modes.stats.detail);
        // Redone at 1e-3 of the first eigenvalue above the near-null one.
        let shift = modes.stats.shift;
        assert!(
            (shift + 1e-3 * oracle.values[1]).abs() < 1e-6 * oracle.values[1],
            "{path}: shift {shift:e}"
        );
        let mut worst = 0.0f64;
        for r in 1..8 {
            worst = worst.max((modes.eigenvalues[r] - oracle.values[r]).abs() / oracle.values[r]);
            let (a, b) = (modes.eigenvalues[r], oracle.values[r]);
            assert!(
                (a - b).abs() <= 1e-10 * b,
                "{path}: mode {}: {a:e} against {b:e} ({:.1e})",
                r + 1,
                (a - b).abs() / b
            );
        }
        eprintln!("{path}: modes 2-8 within {worst:.1e} of the dense solve");
        // K is definite, so the near-null mode is elastic (no rigid-body threshold); its
        // eigenvalue, k0 / Σm to first order, is what the vector's Rayleigh quotient gives,
        // to a few ε of the stiffness scale.
        assert_eq!(modes.rigid_threshold, 0.0, "{path}");
        let first = 1e-14 / (0..40).map(|i| 1.0 + 0.01 * i as f64).sum::<f64>();
        assert!(
            (modes.eigenvalues[0] - first).abs() < 1e-16,
            "{path}: λ₁ = {:e} against {first:e}",
            modes.eigenvalues[0]
        );
    }
}

/// A structure (the chain) beside an acoustic-like block stored with the opposite sign (negative
/// stiffness and mass diagonals), uncoupled, as public matrix collections hold some
/// loudspeaker models: refused with what was found and what to do (not "no mass … condense");
/// after the advised negation the lowest modes are the union of the two blocks' spectra from
/// dense solves, to 1e-10. A coupled negative block is refused as such.
#[test]
fn a_negative_signed_block_is_described_and_its_negation_solves() {
    let (ns, nf) = (30, 12);
    let (ks, ms) = nearly_free_chain(ns, 1.0);
    // The fluid block: a chain too (different masses), then negated.
    let (kf, mf) = nearly_free_chain(nf, 0.5);
    let n = ns + nf;
    let block = |s: &SparseSym, f: &SparseSym, sign: f64| -> Vec<(usize, usize, f64)> {
        let mut t: Vec<(usize, usize, f64)> = s.entries().filter(|e| e.0 >= e.1).collect();
        t.extend(
            f.entries()
                .filter(|e| e.0 >= e.1)
                .map(|(i, j, v)| (i + ns, j + ns, sign * 3.0 * v)),
        );
        t
    };
    let k_neg = SparseSym::from_lower_triplets("K", n, &block(&ks, &kf, -1.0)).unwrap();
    let m_neg = SparseSym::from_lower_triplets("M", n, &block(&ms, &mf, -1.0)).unwrap();
    let cfg = EigenConfig {
        selection: ModeSelection::Lowest(10),
        ..EigenConfig::default()
    };
    let e = EigenSolver::new().solve(&k_neg, &m_neg, &cfg).unwrap_err();
    let text = e.to_string();
    assert!(
        matches!(e, Error::NegativeMassDofs { count: 12, .. })
            && text.contains("not coupled to the other 30 DOFs")
            && text.contains("negate its rows and columns"),
        "{text}"
    );
    // Negated as advised: the same spectrum, positive.
    let k = SparseSym::from_lower_triplets("K", n, &block(&ks, &kf, 1.0)).unwrap();
    let m = SparseSym::from_lower_triplets("M", n, &block(&ms, &mf, 1.0)).unwrap();
    let mut union: Vec<f64> = [(&ks, &ms), (&kf, &mf)]
        .iter()
        .flat_map(|(a, b)| {
            nlsim_kernel::linalg::dense_generalized_eigen(
                a.to_dense().as_ref(),
                b.to_dense().as_ref(),
            )
            .unwrap()
            .values
        })
        .collect();
    union.sort_by(f64::total_cmp);
    for cfg in [cfg.clone(), lanczos(ModeSelection::Lowest(10))] {
        let modes = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
        for r in 0..10 {
            let (a, b) = (modes.eigenvalues[r], union[r]);
            assert!((a - b).abs() <= 1e-10 * b, "mode {}: {a:e} vs {b:e}", r + 1);
        }
    }
    // Coupled: one entry between the blocks.
    let mut t = block(&ks, &kf, -1.0);
    t.push((ns, ns - 1, -0.1));
    let k_coupled = SparseSym::from_lower_triplets("K", n, &t).unwrap();
    let e = EigenSolver::new()
        .solve(&k_coupled, &m_neg, &cfg)
        .unwrap_err();
    assert!(
        e.to_string().contains("is coupled to the other DOFs"),
        "{e}"
    );
}

#[test]
fn nested_dissection_orders_a_solid_with_less_fill_and_the_same_modes() {
    use nlsim_reduction::{Ordering, ShiftedPencil};
    // A 3-D solid mesh: dissection leaves markedly less fill than minimum degree.
    let (k3, m3) = bracket(3, true);
    let p = ShiftedPencil::new(&k3, &m3).unwrap();
    let predicted = p.predicted_factor_nnz().to_vec();
    let amd = predicted
        .iter()
        .find(|(o, _)| *o == Ordering::Amd)
        .unwrap()
        .1;
    let nd = predicted
        .iter()
        .find(|(o, _)| *o == Ordering::NestedDissection)
        .unwrap()
        .1;
    assert_eq!(p.ordering(), Ordering::NestedDissection, "{predicted:?}");
    assert_eq!(p.factor_nnz(), nd);
    assert!((nd as f64) < 0.9 * amd as f64, "{predicted:?}");
    // Both orderings give the dense solver's modes, and the same Sturm counts.
    let (k, m) = bracket(1, true);
    for ordering in [Ordering::Amd, Ordering::NestedDissection] {
        let cfg = EigenConfig {
            ordering,
            ..lanczos(ModeSelection::Lowest(30))
        };
        let modes = EigenSolver::new().solve(&k, &m, &cfg).unwrap();
        assert_eq!(modes.stats.ordering, Some(ordering));
        compare(&k, &m, &modes, 1e-10, 0.0);
        assert_eq!(modes.stats.sturm.unwrap().0, 30);
    }
}

#[test]
fn a_memory_budget_checks_in_the_factors_storage_with_identical_results() {
    use nlsim_reduction::{ReductionConfig, reduce};
    let f = nlsim_fixtures::bracket_fixture(
        &BracketConfig {
            refinement: 1,
            clamped: true,
            lumped_mass: false,
        },
        "bump_stop",
    )
    .unwrap();
    let (k, m) = (f.model.stiffness(), f.model.mass());
    let free = lanczos(ModeSelection::Lowest(20));
    let mut s = EigenSolver::new();
    let a = s.solve(k, m, &free).unwrap();
    assert!(!a.stats.factor_released && s.factor().is_some());
    // Room for two factors, not for the factor and `M V` beside the basis (the basis is the
    // larger here): the factor is kept, the products with `M` are recomputed.
    let factor_bytes = 8 * a.stats.factor_nnz;
    assert!(16 * k.n() * a.stats.basis_size > factor_bytes);
    let no_mv = EigenConfig {
        memory_budget: Some(2 * factor_bytes),
        ..free.clone()
    };
    // Two factors never fit in 1 byte: the check reuses the operator factor's storage.
    let tight = EigenConfig {
        memory_budget: Some(1),
        ..free.clone()
    };
    let b = s.solve(k, m, &no_mv).unwrap();
    assert!(!b.stats.factor_released && s.factor().is_some());
    let c = s.solve(k, m, &tight).unwrap();
    assert!(c.stats.factor_released && s.factor().is_none());
    // Releasing the factor changes nothing.
    assert_eq!(b.stats.sturm, c.stats.sturm);
    assert_eq!(b.eigenvalues, c.eigenvalues);
    assert_eq!(b.vectors, c.vectors);
    // Recomputed rather than updated products with `M`: the same modes to round-off
    // (eigenvalues) and to the tolerance over the gaps (vectors).
    let ((ca, pa), (cb, pb)) = (a.stats.sturm.unwrap(), b.stats.sturm.unwrap());
    assert!(
        ca == cb && (pa - pb).abs() <= 1e-12 * pa,
        "{ca} below {pa}, {cb} below {pb}"
    );
    for (x, y) in a.eigenvalues.iter().zip(&b.eigenvalues) {
        assert!((x - y).abs() <= 1e-12 * x.abs(), "{x} against {y}");
    }
    // Up to sign: the largest-entry-positive convention can flip a mode (here the 18th) whose
    // two largest entries are equal by symmetry.
    for col in 0..a.vectors.ncols() {
        let (x, y) = (a.vectors.col(col), b.vectors.col(col));
        let d = (x - y).norm_max().min((x + y).norm_max());
        assert!(d <= 1e-10 * x.norm_max(), "mode {}: {d:e}", col + 1);
    }
    // A generous budget keeps the factor.
    let roomy = EigenConfig {
        memory_budget: Some(usize::MAX / 4),
        ..free.clone()
    };
    assert!(!s.solve(k, m, &roomy).unwrap().stats.factor_released);
    // The reduction refactorises at the same shift for its residual flexibility: the same
    // reduced model to the bit.
    let reduced = |eigen: EigenConfig| {
        reduce(
            &f.model,
            &ReductionConfig {
                eigen,
                residual_flexibility: true,
                ..Default::default()
            },
        )
        .unwrap()
    };
    let (ra, rb) = (reduced(no_mv), reduced(tight));
    assert!(ra.residual.norm_max() > 0.0);
    assert_eq!(ra.residual, rb.residual);
    assert_eq!(ra.residual_shift, rb.residual_shift);
}
