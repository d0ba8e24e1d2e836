//! Harmonic balance on the Duffing oscillator of thesis Fig. 3: the first-order closed form,
//! stability of the three branches, folds, the condensed against the modal formulation,
//! stepped sines with their jumps, force-level sweeps.

use nlsim_fixtures::{DUFFING_FIG3, duffing_fig3, duffing_first_order_amplitudes};
use nlsim_hb::{
    Branch, ContinuationConfig, HarmonicSet, HbConfig, HbSystem, Parameter, PointKind,
    continuation, stepped_sine,
};
use nlsim_kernel::Status;
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModeSelection};
use std::f64::consts::PI;

fn system(h: usize, nu: usize) -> HbSystem {
    let model = duffing_fig3().model;
    let cfg = ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(1),
            ..EigenConfig::default()
        },
        ..ReductionConfig::default()
    };
    let red = reduce(&model, &cfg).unwrap();
    HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(h, nu).unwrap(),
        HbConfig::default(),
    )
    .unwrap()
}

fn amplitude(sys: &HbSystem, x: &[f64], k: usize) -> f64 {
    sys.harmonics().complex(x, k).norm()
}

fn closed_form(omega: f64, force: f64) -> Vec<f64> {
    let (m, c, k, p) = DUFFING_FIG3;
    duffing_first_order_amplitudes(m, c, k, p, force, omega)
}

/// Fold frequencies of the closed form (rad/s): where the number of roots changes.
fn closed_form_folds(lo: f64, hi: f64, force: f64) -> Vec<f64> {
    let n = 4000;
    let count = |w: f64| closed_form(w, force).len();
    let mut folds = Vec::new();
    for i in 0..n {
        let (mut a, mut b) = (
            lo + (hi - lo) * i as f64 / n as f64,
            lo + (hi - lo) * (i + 1) as f64 / n as f64,
        );
        if count(a) != count(b) {
            let ca = count(a);
            for _ in 0..200 {
                let mid = 0.5 * (a + b);
                if count(mid) == ca {
                    a = mid;
                } else {
                    b = mid;
                }
            }
            folds.push(0.5 * (a + b));
        }
    }
    folds
}

fn sweep(sys: &HbSystem, from_hz: f64, to_hz: f64) -> Branch {
    let rep = continuation(sys, &ContinuationConfig::frequency(from_hz, to_hz), None).unwrap();
    assert!(rep.is_complete(), "{}", rep.detail);
    assert_eq!(rep.stats.n_points, rep.branch.points.len());
    rep.branch
}

#[test]
fn first_order_branch_matches_the_closed_form_with_stability_and_folds() {
    let sys = system(1, 1);
    let br = sweep(&sys, 26.0, 40.0);
    let mut seen_middle = 0;
    for p in &br.points {
        let a = amplitude(&sys, &p.x, 1);
        let roots = closed_form(p.omega, 2.0);
        let (i, err) = roots
            .iter()
            .enumerate()
            .map(|(i, r)| (i, (r - a).abs() / r))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap();
        // Newton stops at ‖R‖ ≤ 1e-10 of the amplitude; the closed form roots are exact to
        // round-off. At a fold the amplitude depends on Ω like a square root, so the fold's
        // location error (~1e-12 of the arclength) shows as its square root.
        let tol = if p.kind == PointKind::Fold {
            1e-6
        } else {
            1e-8
        };
        assert!(
            err < tol,
            "{:.4} Hz: A = {a:e}, roots {roots:?}",
            p.omega / (2.0 * PI)
        );
        let st = p.stability.as_ref().unwrap();
        if p.kind == PointKind::Fold {
            // Hill's exponent passes through zero at a fold.
            assert!(
                st.max_real.abs() < 1e-3 * p.omega,
                "fold exponent {}",
                st.max_real
            );
            continue;
        }
        if roots.len() == 3 {
            // Away from the folds: outer roots stable, the middle one unstable.
            let gap = (roots[1] - roots[0]).min(roots[2] - roots[1]) / roots[2];
            if gap > 1e-3 {
                assert_eq!(
                    st.stable,
                    i != 1,
                    "{:.4} Hz root {i}: {st:?}",
                    p.omega / (2.0 * PI)
                );
                seen_middle += usize::from(i == 1);
            }
        } else {
            assert!(
                st.stable,
                "{:.4} Hz single root unstable: {st:?}",
                p.omega / (2.0 * PI)
            );
            // On the stable branches the exponents' real parts are −c/(2m) (their sum is
            // the trace −c/m of the linear part).
            let (m, c, _, _) = DUFFING_FIG3;
            let sum: f64 = st.exponents.iter().map(|s| s.re).sum();
            assert!(
                (sum + c / m).abs() < 1e-6 * c / m,
                "trace {sum} vs {}",
                -c / m
            );
        }
    }
    assert!(
        seen_middle >= 3,
        "the continuation should pass the middle branch"
    );
    let folds: Vec<f64> = br.folds().iter().map(|&i| br.points[i].omega).collect();
    let want = closed_form_folds(2.0 * PI * 26.0, 2.0 * PI * 40.0, 2.0);
    assert_eq!(folds.len(), 2, "folds {folds:?}");
    assert_eq!(want.len(), 2);
    // The fold is located to 1e-12 of the arclength, the closed form bisected to round-off;
    // what is left is the corrector tolerance (1e-10), squared-root amplified at the fold.
    let mut folds = folds;
    folds.sort_by(f64::total_cmp);
    for (a, b) in folds.iter().zip(&want) {
        assert!((a - b).abs() < 1e-6 * b, "fold {a} vs closed form {b}");
    }
}

#[test]
fn condensed_and_modal_formulations_agree() {
    let sys = system(5, 1);
    let om = 2.0 * PI * 31.0;
    let (x, _) = sys
        .solve_converged(om, 1.0, &sys.linear_guess(om, 1.0))
        .unwrap();
    // η = Z⁻¹ Φᵀ(F − G) from the condensed solution, then the modal Newton from a perturbed
    // copy must return to it.
    let eta = sys.modal_amplitudes(&x, om, 1.0);
    let nh = sys.harmonics().len();
    let mut e0 = vec![0.0; nh];
    for k in 0..=sys.harmonics().h {
        sys.harmonics().set_complex(&mut e0, k, eta[(0, k)]);
    }
    let (r, _) = sys.modal_residual(&e0, om, 1.0);
    let scale = e0.iter().fold(0.0f64, |m, v| m.max(v.abs())) * sys.linear().eigenvalues()[0];
    assert!(r.iter().all(|v| v.abs() < 1e-9 * scale), "{r:?}");
    let pert: Vec<f64> = e0.iter().map(|v| v * 1.05).collect();
    let (back, rep) = sys.solve_modal(om, 1.0, &pert).unwrap();
    assert!(rep.converged(), "{rep:?}");
    for (a, b) in back.iter().zip(&e0) {
        assert!((a - b).abs() < 1e-9 * scale / sys.linear().eigenvalues()[0]);
    }
}

#[test]
fn stepped_sines_jump_at_the_folds() {
    let sys = system(3, 1);
    let n = 300;
    let up: Vec<f64> = (0..n)
        .map(|i| 2.0 * PI * (27.0 + 9.0 * i as f64 / (n - 1) as f64))
        .collect();
    let down: Vec<f64> = up.iter().rev().copied().collect();
    let bu = stepped_sine(&sys, &up, 1.0, true)
        .unwrap()
        .into_branch()
        .unwrap();
    let bd = stepped_sine(&sys, &down, 1.0, true)
        .unwrap()
        .into_branch()
        .unwrap();
    let folds = closed_form_folds(2.0 * PI * 27.0, 2.0 * PI * 36.0, 2.0);
    let biggest_drop = |b: &Branch| {
        b.points
            .windows(2)
            .map(|w| {
                let (a0, a1) = (amplitude(&sys, &w[0].x, 1), amplitude(&sys, &w[1].x, 1));
                (a0 / a1, 0.5 * (w[0].omega + w[1].omega))
            })
            .max_by(|a, b| a.0.total_cmp(&b.0))
            .unwrap()
    };
    // Upward the response stays on the resonant branch to the upper fold, then drops.
    let (ratio, at) = biggest_drop(&bu);
    assert!(ratio > 3.0, "no jump down in the upward sweep");
    let step = 2.0 * PI * 9.0 / (n - 1) as f64;
    // H = 3 moves the fold slightly from the first-order one.
    assert!(
        (at - folds[1]).abs() < 0.01 * folds[1] + step,
        "jump at {at}, fold {}",
        folds[1]
    );
    // Downward it stays low to the lower fold, then jumps up.
    let rev: Branch = Branch {
        points: bd.points.iter().rev().cloned().collect(),
        ..bd.clone()
    };
    let (ratio, at) = biggest_drop(&rev);
    assert!(ratio > 2.0, "no jump up in the downward sweep");
    assert!(
        (at - folds[0]).abs() < 0.01 * folds[0] + step,
        "jump at {at}, fold {}",
        folds[0]
    );
    // Each sweep jumps exactly once, and says so.
    for b in [&bu, &bd] {
        assert_eq!(
            b.points
                .iter()
                .filter(|p| p.kind == PointKind::Jump)
                .count(),
            1
        );
    }
    // Every stepped-sine point is stable: a test can only dwell on stable solutions.
    assert!(
        bu.points
            .iter()
            .chain(&bd.points)
            .all(|p| p.stable() == Some(true))
    );
}

#[test]
fn force_level_sweep_follows_the_closed_form() {
    let sys = system(1, 1);
    let om = 2.0 * PI * 31.0;
    let cfg = ContinuationConfig {
        parameter: Parameter::ForceLevel,
        from: 0.1,
        to: 2.0,
        fixed: om,
        ..ContinuationConfig::frequency(1.0, 2.0)
    };
    let rep = continuation(&sys, &cfg, None).unwrap();
    assert!(rep.is_complete(), "{}", rep.detail);
    let br = rep.branch;
    // At 31 Hz the level sweep passes a fold pair (the jump onto the resonant branch).
    for p in &br.points {
        let a = amplitude(&sys, &p.x, 1);
        let roots = closed_form(om, 2.0 * p.scale);
        assert!(
            roots.iter().any(|r| (r - a).abs() < 1e-8 * r),
            "level {}: {a} vs {roots:?}",
            p.scale
        );
    }
}

/// A continuation whose step falls below `ds_min` returns the branch it computed with
/// `Status::StepTooSmall`, every kept point a converged solution.
#[test]
fn continuation_below_ds_min_keeps_its_partial_branch() {
    let sys = system(1, 1);
    let cfg = ContinuationConfig {
        ds: 0.02,
        ds_min: 0.02,
        ds_max: 0.02,
        // Two corrector iterations at a fixed step: enough on the smooth part of the branch,
        // too few around the fold region, where the run must stop and keep what it found.
        max_corrector: 2,
        stability: false,
        ..ContinuationConfig::frequency(26.0, 40.0)
    };
    let rep = continuation(&sys, &cfg, None).unwrap();
    assert_eq!(rep.status, Status::StepTooSmall, "{}", rep.detail);
    assert!(!rep.is_complete());
    assert!(rep.detail.contains("smallest step"), "{}", rep.detail);
    let pts = &rep.branch.points;
    assert!(pts.len() > 1, "{} points", pts.len());
    assert!(rep.stats.n_rejected >= 1);
    let last = pts.last().unwrap();
    assert!(last.omega > pts[0].omega && last.omega < 2.0 * PI * 40.0);
    for p in pts {
        let r = sys.residual(&p.x, p.omega, 1.0).unwrap();
        let rn = r.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let xn = p.x.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        // The corrector's own test (`‖R‖ ≤ rtol · ‖x‖`, scaled variables, rtol 1e-10).
        assert!(rn <= 1e-9 * xn, "{rn:e} at {} Hz", p.omega / (2.0 * PI));
    }
    // The all-or-nothing form turns it into an error naming where it stopped.
    let e = rep.into_branch().unwrap_err().to_string();
    assert!(e.contains("continuation at") && e.contains("Hz"), "{e}");
}

/// A coarse stepped sine over the resonance of a practically linear oscillator (force
/// level 1/400: the cubic term shifts the peak by about 1e-4) is single-valued: it reports
/// no jump, although the tangent prediction misses the points near the peak by far more
/// than half a step (the old test took those for jumps). At the full level every jump
/// reported lies within one step past a fold of the continuation over the same range.
#[test]
fn stepped_sine_jumps_only_past_a_fold() {
    let sys = system(3, 1);
    let (lo, hi) = (27.0, 36.0);
    let n = 21;
    let grid = |a: f64, b: f64| -> Vec<f64> {
        (0..n)
            .map(|i| 2.0 * PI * (a + (b - a) * i as f64 / (n - 1) as f64))
            .collect()
    };
    for omegas in [grid(lo, hi), grid(hi, lo)] {
        let r = stepped_sine(&sys, &omegas, 1.0 / 400.0, true).unwrap();
        assert!(r.skipped.is_empty() && r.stats.n_unverified == 0);
        let jumps: Vec<f64> = r
            .branch
            .points
            .iter()
            .filter(|p| p.kind == PointKind::Jump)
            .map(|p| p.omega / (2.0 * PI))
            .collect();
        assert!(
            jumps.is_empty(),
            "jumps at {jumps:?} Hz on a linear response"
        );
        assert_eq!(r.branch.points.len(), n);
    }
    let cont = continuation(&sys, &ContinuationConfig::frequency(lo, hi), None)
        .unwrap()
        .into_branch()
        .unwrap();
    let folds: Vec<f64> = cont.folds().iter().map(|&i| cont.points[i].omega).collect();
    assert_eq!(folds.len(), 2);
    let step = 2.0 * PI * (hi - lo) / (n - 1) as f64;
    for omegas in [grid(lo, hi), grid(hi, lo)] {
        let r = stepped_sine(&sys, &omegas, 1.0, true).unwrap();
        assert!(r.skipped.is_empty());
        let jumps: Vec<f64> = r
            .branch
            .points
            .iter()
            .filter(|p| p.kind == PointKind::Jump)
            .map(|p| p.omega)
            .collect();
        assert_eq!(jumps.len(), 1, "one jump per sweep, got {jumps:?}");
        let up = omegas[1] > omegas[0];
        // Upward the jump follows the upper fold, downward the lower one.
        let fold = if up {
            folds.iter().copied().fold(f64::MIN, f64::max)
        } else {
            folds.iter().copied().fold(f64::MAX, f64::min)
        };
        let past = if up { jumps[0] - fold } else { fold - jumps[0] };
        assert!(
            past > 0.0 && past <= step * (1.0 + 1e-9),
            "jump at {} Hz, fold at {} Hz",
            jumps[0] / (2.0 * PI),
            fold / (2.0 * PI)
        );
    }
}
