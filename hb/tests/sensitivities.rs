//! Sensitivities `dQ/dp = −R_Q⁻¹ R_p` against central finite differences of re-solved FRFs.

use nlsim_fixtures::build;
use nlsim_hb::system::ModelParam;
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem, LinearParam};
use nlsim_kernel::Model;
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModeSelection};

/// Re-solves with parameter `p` moved by `h` (on a copy) and returns the sensor response.
fn perturbed(
    sys: &HbSystem,
    p: ModelParam,
    h: f64,
    omega: f64,
    x0: &[f64],
) -> Option<faer::Mat<faer::c64>> {
    let mut s = sys.clone();
    match p {
        ModelParam::Element { element, param } => {
            let v = s.elements[element].law().param(param);
            // A contact exponent at its bound 1 cannot move down: None.
            s.elements[element].set_param(param, v + h).ok()?;
        }
        ModelParam::Linear(LinearParam::ModalFrequency(r)) => {
            let zeta = s.linear.zeta(r);
            let w = s.linear.w2[r].sqrt() + 2.0 * std::f64::consts::PI * h;
            s.linear.w2[r] = w * w;
            s.linear.damping[(r, r)] = 2.0 * zeta * w;
        }
        ModelParam::Linear(LinearParam::DampingRatio(r)) => {
            s.linear.damping[(r, r)] += 2.0 * h * s.linear.w2[r].sqrt();
        }
        ModelParam::Linear(LinearParam::StiffnessScale) => {
            s.linear.w2.iter_mut().for_each(|w| *w *= 1.0 + h);
            s.linear.residual = &s.linear.residual * faer::Scale(1.0 / (1.0 + h));
        }
    }
    let (x, _) = s.solve(omega, 1.0, x0).unwrap();
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
        .solve(omega, 1.0, &sys.linear_guess(omega, 1.0))
        .unwrap();
    let params = sys.all_parameters();
    let sens = sys.sensitivities(&x, omega, 1.0, &params).unwrap();
    for (p, s) in params.iter().zip(&sens) {
        let value = match *p {
            ModelParam::Element { element, param } => sys.elements[element].law().param(param),
            ModelParam::Linear(LinearParam::ModalFrequency(r)) => {
                sys.linear.w2[r].sqrt() / (2.0 * std::f64::consts::PI)
            }
            ModelParam::Linear(LinearParam::DampingRatio(r)) => sys.linear.zeta(r),
            ModelParam::Linear(LinearParam::StiffnessScale) => 1.0,
        };
        if value == 0.0 {
            // An absent side of the bump stop (k2 = 0, e2 = 0): no relative step exists.
            continue;
        }
        // Central differences with a relative step 1e-5: truncation ~1e-10 and the
        // solver's round-off (Newton to 1e-10 relative) / 1e-5 ~ 1e-5 of the response; a
        // forward difference (truncation ~1e-5) at a parameter bound.
        let step = 1e-5 * value.abs();
        let up = perturbed(&sys, *p, step, omega, &x).unwrap();
        let fd = match perturbed(&sys, *p, -step, omega, &x) {
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
        if matches!(p, ModelParam::Element { param: 0, .. }) {
            assert!(
                s.dy.norm_max() * value.abs() > 1e-3 * y.norm_max(),
                "{} has no effect",
                s.name
            );
        }
        let diff = (&fd - &s.dy).norm_max() * value.abs();
        assert!(
            diff <= scale,
            "{}: analytic {:?} vs finite difference {:?}",
            s.name,
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
