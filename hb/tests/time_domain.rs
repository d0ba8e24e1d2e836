//! Harmonic balance against time integration (the sim crate's FOH integrator) of the same
//! reduced model: started on the periodic orbit that HB predicts, integrated over whole
//! periods; the harmonics of the last period must be HB's, harmonic by harmonic.

use faer::c64;
use nlsim_fixtures::{build, duffing_fig3};
use nlsim_hb::{ForceTerm, Forcing, HarmonicSet, HbConfig, HbSystem, stepped_sine};
use nlsim_kernel::Model;
use nlsim_reduction::modal::{ReducedModel, ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection};
use nlsim_sim::{FohConfig, Harmonic, InitialState, LoadCase, Plant, Signal, Simulator};
use std::f64::consts::PI;

fn reduced(model: &Model, modes: usize) -> ReducedModel {
    let cfg = ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(modes),
            ..EigenConfig::default()
        },
        ..ReductionConfig::default()
    };
    reduce(model, &cfg).unwrap()
}

/// The force of `sys.forcing` at level `scale` as time signals, one per input.
fn signals(sys: &HbSystem, omega: f64, scale: f64) -> Vec<Signal> {
    (0..sys.inputs().len())
        .map(|i| Signal::MultiSine {
            fundamental_hz: sys.harmonics().base(omega) / (2.0 * PI),
            harmonics: (0..=sys.harmonics().h)
                .filter_map(|k| {
                    let f = sys.forcing().amplitude(i, k) * scale;
                    (f != c64::new(0.0, 0.0)).then_some(Harmonic {
                        ratio: k as f64,
                        amplitude: f,
                    })
                })
                .collect(),
        })
        .collect()
}

/// Integrates `periods` base periods with `spp` samples each from the HB orbit `x`, and
/// returns per sensor the complex harmonics `0..=H` of the last period.
#[allow(clippy::too_many_arguments)]
fn time_harmonics(
    model: &Model,
    red: &ReducedModel,
    sys: &HbSystem,
    x: &[f64],
    omega: f64,
    scale: f64,
    periods: usize,
    spp: usize,
) -> Vec<Vec<c64>> {
    let plant = Plant::from_model(model, &ModalSystem::new(red).unwrap()).unwrap();
    let w0 = sys.harmonics().base(omega);
    let eta = sys.modal_amplitudes(x, omega, scale);
    let m = red.n_modes();
    let displacement: Vec<f64> = (0..m)
        .map(|r| (0..=sys.harmonics().h).map(|k| eta[(r, k)].re).sum())
        .collect();
    let velocity: Vec<f64> = (0..m)
        .map(|r| {
            (0..=sys.harmonics().h)
                .map(|k| (c64::new(0.0, k as f64 * w0) * eta[(r, k)]).re)
                .sum()
        })
        .collect();
    let mut case = LoadCase::new("hb", signals(sys, omega, scale));
    case.initial = InitialState::Modal {
        displacement,
        velocity,
    };
    let dt = 2.0 * PI / w0 / spp as f64;
    let h = Simulator::new(&plant, &FohConfig::new(dt))
        .unwrap()
        .run(&case, periods * spp)
        .unwrap();
    sys.sensors()
        .iter()
        .map(|s| {
            let v = &h.output(&s.name).unwrap().values;
            let last = &v[v.len() - 1 - spp..v.len() - 1];
            (0..=sys.harmonics().h)
                .map(|k| {
                    let c: c64 = last
                        .iter()
                        .enumerate()
                        .map(|(n, y)| {
                            let a = -2.0 * PI * (k * n) as f64 / spp as f64;
                            c64::new(y * a.cos(), y * a.sin())
                        })
                        .sum();
                    c * if k == 0 { 1.0 } else { 2.0 } / spp as f64
                })
                .collect()
        })
        .collect()
}

/// Largest harmonic difference relative to the largest harmonic, per sensor.
fn compare(sys: &HbSystem, x: &[f64], omega: f64, scale: f64, t: &[Vec<c64>]) -> f64 {
    let y = sys.sensor_response(x, omega, scale);
    let mut worst = 0.0f64;
    for (s, ts) in t.iter().enumerate() {
        let peak = (0..=sys.harmonics().h).fold(0.0f64, |m, k| m.max(y[(s, k)].norm()));
        for k in 0..=sys.harmonics().h {
            worst = worst.max((y[(s, k)] - ts[k]).norm() / peak);
        }
    }
    worst
}

#[test]
fn duffing_seven_harmonics_match_time_integration_on_both_stable_branches() {
    let model = duffing_fig3().model;
    let red = reduced(&model, 1);
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(7, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let target = 2.0 * PI * 30.5;
    let up: Vec<f64> = (0..=40)
        .map(|i| 2.0 * PI * 28.0 + (target - 2.0 * PI * 28.0) * i as f64 / 40.0)
        .collect();
    let down: Vec<f64> = (0..=40)
        .map(|i| 2.0 * PI * 33.0 + (target - 2.0 * PI * 33.0) * i as f64 / 40.0)
        .collect();
    let high = stepped_sine(&sys, &up, 1.0, true)
        .unwrap()
        .into_branch()
        .unwrap();
    let low = stepped_sine(&sys, &down, 1.0, true)
        .unwrap()
        .into_branch()
        .unwrap();
    let (xh, xl) = (
        &high.points.last().unwrap().x,
        &low.points.last().unwrap().x,
    );
    let (ah, al) = (
        sys.harmonics().complex(xh, 1).norm(),
        sys.harmonics().complex(xl, 1).norm(),
    );
    assert!(ah > 3.0 * al, "two distinct branches: {ah:e} vs {al:e}");
    for x in [xh, xl] {
        // 20 periods at 1024 samples: the FOH error (second order in the feedback) is
        // ~1e-6 of the response here; a perturbation of the orbit decays like e^{−c t/2m}.
        let t = time_harmonics(&model, &red, &sys, x, target, 1.0, 20, 1024);
        let e = compare(&sys, x, target, 1.0, &t);
        assert!(e < 2e-5, "HB vs FOH: {e:e}");
    }
}

#[test]
fn multi_harmonic_forcing_gives_the_frfs_of_time_integration() {
    let model = duffing_fig3().model;
    let red = reduced(&model, 1);
    let mut sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(7, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    // Thesis eq. 12: force on the fundamental and its 2nd and 3rd harmonics at once.
    sys.set_forcing(Forcing {
        terms: vec![
            ForceTerm {
                input: 0,
                harmonic: 1,
                amplitude: c64::new(2.0, 0.0),
            },
            ForceTerm {
                input: 0,
                harmonic: 2,
                amplitude: c64::new(0.0, 1.5),
            },
            ForceTerm {
                input: 0,
                harmonic: 3,
                amplitude: c64::new(-1.0, 0.5),
            },
        ],
    })
    .unwrap();
    let omega = 2.0 * PI * 12.0;
    let (x, _) = sys
        .solve_converged(omega, 1.0, &sys.linear_guess(omega, 1.0))
        .unwrap();
    let frf = sys.frf(&x, omega, 1.0, 0);
    let t = time_harmonics(&model, &red, &sys, &x, omega, 1.0, 20, 1024);
    for k in 1..=3 {
        let ht = t[0][k] / sys.forcing().amplitude(0, k);
        let err = (frf[(0, k)] - ht).norm() / frf[(0, k)].norm();
        assert!(err < 1e-4, "H_{k}: HB {:?} vs time {ht:?}", frf[(0, k)]);
    }
    // Unforced harmonics have no FRF.
    assert!(frf[(0, 4)].re.is_nan());
}

#[test]
fn bump_stop_beam_seven_harmonics_match_time_integration() {
    let model = build("bumpstop_cantilever", &[]).unwrap().model;
    let red = reduced(&model, 8);
    let f1 = red.modes.omega()[0];
    // Near resonance: the tip closes the gap for part of each period.
    let omegas: Vec<f64> = (0..=30)
        .map(|i| f1 * (0.85 + 0.15 * i as f64 / 30.0))
        .collect();
    let solve = |h: usize| {
        let sys = HbSystem::from_model(
            &model,
            &red,
            HarmonicSet::new(h, 1).unwrap(),
            HbConfig::default(),
        )
        .unwrap();
        let br = stepped_sine(&sys, &omegas, 1.0, h == 7)
            .unwrap()
            .into_branch()
            .unwrap();
        let p = br.points.last().unwrap().clone();
        (sys, p)
    };
    let (sys7, p7) = solve(7);
    let (sys31, p31) = solve(31);
    let e = sys7.element_index("stop").unwrap();
    let nh = sys7.harmonics().len();
    let xe = &p7.x[e * nh..(e + 1) * nh];
    let peak = xe[0]
        + (1..=7)
            .map(|k| sys7.harmonics().complex(xe, k).norm())
            .sum::<f64>();
    assert!(
        peak > 1e-3,
        "the tip should reach the stop (peak bound {peak:e})"
    );
    assert_eq!(p7.stable(), Some(true));
    // Time integration from the H = 31 orbit, 250 periods: the first mode's transient decays
    // by e^{−2π ζ 250} < 1e-6 at ζ = 1 %.
    let t = time_harmonics(&model, &red, &sys31, &p31.x, p31.omega, 1.0, 250, 4096);
    let t7: Vec<Vec<c64>> = t.iter().map(|s| s[..=7].to_vec()).collect();
    let err7 = compare(&sys7, &p7.x, p7.omega, 1.0, &t7);
    // With 7 harmonics the contact kink's higher harmonics are cut: the 6th (near the second
    // bending mode, 6.27 f1) moves by a few % of the largest harmonic of the tip acceleration.
    assert!(
        err7 < 5e-2,
        "HB (H = 7) vs FOH on the bump-stop beam: {err7:e}"
    );
    // That difference is truncation: with 31 harmonics the first 8 agree to 3e-3.
    let y31 = sys31.sensor_response(&p31.x, p31.omega, 1.0);
    let mut err31 = 0.0f64;
    for (s, ts) in t.iter().enumerate() {
        let pk = (0..=31).fold(0.0f64, |m, k| m.max(y31[(s, k)].norm()));
        for k in 0..=7 {
            err31 = err31.max((y31[(s, k)] - ts[k]).norm() / pk);
        }
    }
    assert!(err31 < 3e-3, "HB (H = 31) vs FOH: {err31:e}");
}

#[test]
fn duffing_one_third_subharmonic_at_200_n_is_found_and_confirmed_in_time() {
    let model = build("duffing_fig3", &[("force".into(), "200".into())])
        .unwrap()
        .model;
    let red = reduced(&model, 1);
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(9, 3).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    // Start on the backbone: the free response at ω0 with amplitude A has
    // ω0² = k/m + ¾ p A²/m; force at Ω = 3 ω0.
    let (m, _, k, p) = nlsim_fixtures::DUFFING_FIG3;
    let a = 6e-5;
    let w0 = (k / m + 0.75 * p * a * a / m).sqrt();
    let omega = 3.0 * w0;
    let mut guess = sys.linear_guess(omega, 1.0);
    guess[1] = a;
    let (x, _) = sys.solve_converged(omega, 1.0, &guess).unwrap();
    let sub = sys.harmonics().complex(&x, 1).norm();
    let forced = sys.harmonics().complex(&x, 3).norm();
    assert!(
        sub > 10.0 * forced,
        "a 1/3 sub-harmonic response: {sub:e} vs {forced:e}"
    );
    let st = sys.stability(&x, omega).unwrap();
    assert!(st.stable, "{st:?}");
    let t = time_harmonics(&model, &red, &sys, &x, omega, 1.0, 40, 1024);
    let err = compare(&sys, &x, omega, 1.0, &t);
    assert!(err < 1e-4, "sub-harmonic HB vs FOH: {err:e}");
}

/// The 2-DOF chain of `examples/models/two_dof.toml` (1 kg and 0.5 kg, springs 2·10⁴ and 10⁴
/// N/m) with a relative clearance 50× stiffer than the structure between the masses, a
/// quadratic damper (20 N s²/m²) on mass 1, 2 % modal damping and 5 N on mass 2.
fn impacting_chain() -> Model {
    use nlsim_kernel::{
        Coupling, Damping, DofMap, Excitation, Law, ModalDamping, NonlinearElement, Quantity,
        Sensor, SparseSym,
    };
    let mass = SparseSym::diagonal("mass matrix", &[1.0, 0.5]).unwrap();
    let stiff = SparseSym::from_dense_rows(
        "stiffness matrix",
        &[vec![2.0e4, -1.0e4], vec![-1.0e4, 1.0e4]],
    )
    .unwrap();
    let mut model = Model::new("impacting_chain", DofMap::scalar(2), mass, stiff).unwrap();
    model
        .set_damping(Damping::Modal(ModalDamping::uniform(0.02)))
        .unwrap();
    let law = Law::Clearance {
        k1: 5e5,
        k2: 5e5,
        e1: 1e-3,
        e2: 2e-3,
        r: 1.0,
        s: 1.0,
    };
    model
        .add_element(NonlinearElement::new("stop", law, Coupling::relative(1, 0)).unwrap())
        .unwrap();
    let damper = Law::QuadraticDamping { c2: 20.0 };
    model
        .add_element(NonlinearElement::new("damper", damper, Coupling::single(0)).unwrap())
        .unwrap();
    model
        .add_excitation(Excitation {
            name: "shaker".into(),
            at: nlsim_kernel::Site::Dof(1),
            amplitude: 5.0,
            harmonics: Vec::new(),
        })
        .unwrap();
    model
        .add_sensor(Sensor {
            name: "m2".into(),
            at: nlsim_kernel::Site::Dof(1),
            quantity: Quantity::Displacement,
        })
        .unwrap();
    model
}

#[test]
fn continuation_passes_a_stiff_contact_grazing_and_stays_on_a_periodic_orbit() {
    use nlsim_hb::{ContinuationConfig, continuation};
    let model = impacting_chain();
    let red = reduced(&model, 2);
    let sys = |h: usize| {
        HbSystem::from_model(
            &model,
            &red,
            HarmonicSet::new(h, 1).unwrap(),
            HbConfig::default(),
        )
        .unwrap()
    };
    let sys7 = sys(7);
    // The tangent turns sharply where the gap first closes (about 9.85 Hz); before kinks were
    // accepted, the step was halved down to its minimum there and the run stopped.
    let rep = continuation(&sys7, &ContinuationConfig::frequency(5.0, 30.0), None).unwrap();
    assert!(rep.status.is_converged(), "{}", rep.detail);
    let br = rep.branch;
    let last = br.points.last().unwrap().omega / (2.0 * PI);
    assert!((last - 30.0).abs() < 1e-9, "ends at {last} Hz");
    // No gap along the branch: neighbouring points are close in every harmonic, relative to
    // the largest amplitude met (the scaled step is at most 0.02).
    // Peak bound of the gap coordinate (element 0, the first 2H + 1 unknowns).
    let amp = |x: &[f64]| -> f64 { (1..=7).map(|k| sys7.harmonics().complex(x, k).norm()).sum() };
    let xmax = br.points.iter().map(|p| amp(&p.x)).fold(0.0f64, f64::max);
    for w in br.points.windows(2) {
        let d: f64 = w[0]
            .x
            .iter()
            .zip(&w[1].x)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        assert!(
            d < 0.1 * xmax,
            "jump of {d:e} at {} Hz",
            w[1].omega / (2.0 * PI)
        );
    }
    // The first stable point past the grazing with the gap well closed: solved again with 31
    // harmonics from it, then checked against time integration from that orbit.
    let p = br
        .points
        .iter()
        .find(|p| p.stable() == Some(true) && amp(&p.x) > 1.3e-3)
        .expect("a stable point in contact");
    let sys31 = sys(31);
    let (n7, n31) = (sys7.harmonics().len(), sys31.harmonics().len());
    let mut x31 = vec![0.0; sys31.n_unknowns()];
    for e in 0..2 {
        let (from, to) = (&p.x[e * n7..(e + 1) * n7], &mut x31[e * n31..(e + 1) * n31]);
        for k in 0..=7 {
            sys31
                .harmonics()
                .set_complex(to, k, sys7.harmonics().complex(from, k));
        }
    }
    let (x31, _) = sys31.solve_converged(p.omega, 1.0, &x31).unwrap();
    // 400 periods: the slowest transient (2 % damping at 12 Hz, 10 Hz forcing) decays by
    // e^{−2π·0.02·12/10·400} ≈ 1e-26.
    let t = time_harmonics(&model, &red, &sys31, &x31, p.omega, 1.0, 400, 4096);
    let e31 = compare(&sys31, &x31, p.omega, 1.0, &t);
    // Both sides are converged to a few 1e-4 of the response (the FOH error at 4096 samples
    // per period on the contact kink, HB truncation at 31 harmonics).
    assert!(
        e31 < 3e-3,
        "HB (H = 31) vs FOH at {} Hz: {e31:e}",
        p.omega / (2.0 * PI)
    );
}

/// One mass on a spring (1 kg, 4·10⁴ N/m, 31.8 Hz, 1 % modal damping) held by an Iwan joint
/// to ground (macroslip at 2 N, stuck stiffness 2·10⁴ N/m, χ = −0.5, β = 0.1, the default 80
/// sliders) or by a Jenkins slider (`jenkins`: 2·10⁴ N/m, slipping at 1 N), driven at
/// `force` N.
fn friction_oscillator(force: f64, jenkins: bool) -> Model {
    use nlsim_kernel::{
        Coupling, Damping, DofMap, Excitation, Law, ModalDamping, NonlinearElement, Quantity,
        Sensor, SparseSym,
    };
    let mass = SparseSym::diagonal("mass matrix", &[1.0]).unwrap();
    let stiff = SparseSym::diagonal("stiffness matrix", &[4e4]).unwrap();
    let mut model = Model::new("iwan_oscillator", DofMap::scalar(1), mass, stiff).unwrap();
    model
        .set_damping(Damping::Modal(ModalDamping::uniform(0.01)))
        .unwrap();
    let joint = if jenkins {
        Law::Jenkins { kt: 2e4, fs: 1.0 }
    } else {
        Law::iwan(2.0, 2e4, -0.5, 0.1).unwrap()
    };
    model
        .add_element(NonlinearElement::new("joint", joint, Coupling::single(0)).unwrap())
        .unwrap();
    model
        .add_excitation(Excitation {
            name: "shaker".into(),
            at: nlsim_kernel::Site::Dof(0),
            amplitude: force,
            harmonics: Vec::new(),
        })
        .unwrap();
    model
        .add_sensor(Sensor {
            name: "mass".into(),
            at: nlsim_kernel::Site::Dof(0),
            quantity: Quantity::Displacement,
        })
        .unwrap();
    model
}

/// The Iwan joint in microslip (0.3 N: peak 36.4 Hz, amplitude 0.41 φ_max) and in
/// macroslip (1.5 N: 34.0 Hz, 1.3 φ_max) at the resonance peak, and a Jenkins slider at the
/// same levels: the harmonics of HB (H = 15) equal those of the FOH integration started on
/// the orbit (its sliders at rest, so the hysteresis settles within the first cycle) to 1e-4
/// of the fundamental (measured: 6e-7 and 4e-7 for the joint), and every point of the
/// stepped sine is stable — FOH stays on the peak's orbit for 300 periods. Hill's method on
/// the local tangent of the sliders called the peaks unstable (4 to 12 of the 31 points).
#[test]
fn friction_joint_harmonics_and_stability_match_time_integration() {
    for jenkins in [false, true] {
        for force in [0.3, 1.5] {
            let model = friction_oscillator(force, jenkins);
            let red = reduced(&model, 1);
            let sys = HbSystem::from_model(
                &model,
                &red,
                HarmonicSet::new(15, 1).unwrap(),
                HbConfig::default(),
            )
            .unwrap();
            let omegas: Vec<f64> = (0..=30)
                .map(|i| 2.0 * PI * (30.0 + 0.4 * i as f64))
                .collect();
            let run = stepped_sine(&sys, &omegas, 1.0, true).unwrap();
            let branch = run.into_branch().unwrap();
            let what = if jenkins { "Jenkins" } else { "Iwan" };
            for q in &branch.points {
                assert_eq!(
                    q.stable(),
                    Some(true),
                    "{what}, {force} N at {:.2} Hz",
                    q.omega / (2.0 * PI)
                );
            }
            // The point of largest response: the joint slips most there.
            let p = branch
                .points
                .iter()
                .max_by(|a, b| {
                    let amp = |x: &[f64]| sys.harmonics().complex(x, 1).norm();
                    amp(&a.x).total_cmp(&amp(&b.x))
                })
                .unwrap();
            // 300 periods at 4096 samples: the transient (at least 1 % damping at 31 Hz)
            // decays by e^{−2π·0.01·300} ≈ 7e-9.
            let t = time_harmonics(&model, &red, &sys, &p.x, p.omega, 1.0, 300, 4096);
            let e = compare(&sys, &p.x, p.omega, 1.0, &t);
            assert!(
                e < 1e-4,
                "{what}, {force} N at {:.2} Hz: HB vs FOH {e:e}",
                p.omega / (2.0 * PI)
            );
        }
    }
}
