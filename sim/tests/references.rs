//! The references against each other and bad input: Newmark/HHT on the unreduced model vs FOH
//! on the reduced one, RK4, and the error paths.

use nlsim_fixtures::ecl_beam;
use nlsim_kernel::{Damping, Model, Quantity, Sensor};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection};
use nlsim_sim::{
    FohConfig, Hold, LoadCase, Newmark, NewmarkConfig, NewtonConfig, Plant, Rk4Config, Rk45Config,
    Signal, Simulator, TimeHistory, rk4, rk4_with_progress, rk45, rk45_with_progress,
};

fn beam_with_tip_displacement() -> Model {
    with_tip_displacement(ecl_beam().model)
}

/// `model` with a displacement sensor `tip_d` at its excitation point.
fn with_tip_displacement(mut model: Model) -> Model {
    let tip = model.excitation()[0].at.clone();
    model
        .add_sensor(Sensor {
            name: "tip_d".into(),
            at: tip,
            quantity: Quantity::Displacement,
        })
        .unwrap();
    model
}

fn foh_plant(model: &Model, modes: usize) -> Plant {
    let cfg = ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(modes),
            ..EigenConfig::default()
        },
        ..ReductionConfig::default()
    };
    let red = reduce(model, &cfg).unwrap();
    Plant::from_model(model, &ModalSystem::new(&red).unwrap()).unwrap()
}

fn max_rel(a: &[f64], b: &[f64]) -> f64 {
    let p = b.iter().fold(0.0f64, |m, x| m.max(x.abs()));
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
        / p
}

#[test]
fn newmark_on_the_full_model_converges_to_foh_on_the_reduced_one() {
    let model = beam_with_tip_displacement();
    // 20 modes + residual flexibility: the reduced model is converged far below the 24 Hz drive.
    let plant = foh_plant(&model, 20);
    let case = LoadCase::new("sine", vec![Signal::sine(2.0, 24.0)]);
    let dt = 1.0 / 24_000.0;
    let n = 2400;
    let foh = Simulator::new(&plant, &FohConfig::new(dt))
        .unwrap()
        .run(&case, n)
        .unwrap();
    let reference = &foh.output("tip_d").unwrap().values;
    let mut errs = Vec::new();
    for sub in [1usize, 2, 4] {
        let mut cfg = NewmarkConfig::new(dt * 10.0);
        cfg.substeps = sub;
        let nm = Newmark::new(&model, &cfg).unwrap();
        let h = nm.run(&case, n / 10).unwrap();
        assert!(
            h.stats.max_newton_iterations >= 2,
            "the cubic spring needs Newton"
        );
        let r: Vec<f64> = reference.iter().step_by(10).copied().collect();
        errs.push(max_rel(&h.output("tip_d").unwrap().values, &r));
    }
    // Newmark's period error is O((ωh)²): second order.
    for w in errs.windows(2) {
        let order = (w[0] / w[1]).log2();
        assert!(
            (1.8..2.3).contains(&order),
            "Newmark order {order:.2}: {errs:?}"
        );
    }
    assert!(errs[2] < 2e-3, "{errs:?}");
    // HHT-α (α = −0.1) is second order too and agrees to the same level.
    let mut cfg = NewmarkConfig::new(dt * 10.0);
    cfg.substeps = 4;
    cfg.alpha = -0.1;
    let h = Newmark::new(&model, &cfg)
        .unwrap()
        .run(&case, n / 10)
        .unwrap();
    let r: Vec<f64> = reference.iter().step_by(10).copied().collect();
    assert!(max_rel(&h.output("tip_d").unwrap().values, &r) < 3e-3);
    assert_eq!(h.method, "hht");
}

#[test]
fn rk4_agrees_with_foh() {
    let model = beam_with_tip_displacement();
    let plant = foh_plant(&model, 6);
    let case = LoadCase::new("sine", vec![Signal::sine(2.0, 24.0)]);
    let dt = 1.0 / 20_000.0;
    let foh = Simulator::new(&plant, &FohConfig::new(dt / 4.0))
        .unwrap()
        .run(&case, 8000)
        .unwrap();
    let r = rk4(&plant, &case, dt, 2000, &Rk4Config::default()).unwrap();
    let a: Vec<f64> = foh
        .output("tip_d")
        .unwrap()
        .values
        .iter()
        .step_by(4)
        .copied()
        .collect();
    assert!(max_rel(&a, &r.output("tip_d").unwrap().values) < 1e-4);
    // Beyond its stability limit (|λ h| ≈ 2.8 for the fastest mode) RK4 says so.
    let fast = plant
        .system
        .poles
        .iter()
        .fold(0.0f64, |m, l| m.max(l.norm()));
    let err = rk4(&plant, &case, 4.0 / fast, 2000, &Rk4Config::default()).unwrap_err();
    assert!(err.to_string().contains("stability limit"), "{err}");
}

#[test]
fn bad_input_gets_clear_errors() {
    let model = beam_with_tip_displacement();
    let plant = foh_plant(&model, 6);
    let msg = |e: nlsim_kernel::Error| e.to_string();
    assert!(msg(Simulator::new(&plant, &FohConfig::new(0.0)).unwrap_err()).contains("time step"));
    assert!(
        msg(Simulator::new(&plant, &FohConfig::new(f64::NAN)).unwrap_err()).contains("time step")
    );
    let sim = Simulator::new(&plant, &FohConfig::new(1e-4)).unwrap();
    // Wrong number of signals.
    let e = msg(sim
        .run(&LoadCase::new("two", vec![Signal::Zero, Signal::Zero]), 10)
        .unwrap_err());
    assert!(e.contains("one per input: shaker"), "{e}");
    // NaN in a signal names the sample.
    let bad = LoadCase::new(
        "nan",
        vec![Signal::Sampled {
            rate_hz: 1e4,
            values: vec![0.0, 1.0, f64::NAN],
        }],
    );
    let e = msg(sim.run(&bad, 10).unwrap_err());
    assert!(e.contains("sample 2"), "{e}");
    // Unknown parameter.
    let mut c = LoadCase::new("p", vec![Signal::Zero]);
    c.parameters.push(("tip_spring.k9".parse().unwrap(), 1.0));
    let e = msg(sim.run(&c, 10).unwrap_err());
    assert!(e.contains("has parameters k3"), "{e}");
    // A Newton that cannot converge names the step and time.
    let mut cfg = FohConfig::new(1e-4);
    cfg.newton = NewtonConfig {
        max_iterations: 1,
        rtol: 1e-15,
    };
    let sim = Simulator::new(&plant, &cfg).unwrap();
    // It is an outcome, not an error: the samples before the failing step come back with
    // the status and the reason.
    let h = sim
        .run(&LoadCase::new("hard", vec![Signal::sine(50.0, 24.0)]), 2000)
        .unwrap();
    assert_eq!(h.status, nlsim_kernel::Status::IterationLimit);
    assert!(h.n_samples() < 2001 && h.n_samples() == h.stats.steps + 1);
    for s in h.outputs.iter().map(|o| &o.values).chain(&h.element_forces) {
        assert_eq!(s.len(), h.n_samples());
        assert!(s.iter().all(|v| v.is_finite()));
    }
    let e = msg(h.into_complete().unwrap_err());
    assert!(
        e.contains("step") && e.contains("t = ") && e.contains("tip_spring"),
        "{e}"
    );
    // Modal damping has no matrix for the unreduced reference.
    let mut m2 = model.clone();
    m2.set_damping(Damping::Modal(nlsim_kernel::ModalDamping::uniform(0.01)))
        .unwrap();
    let e = Newmark::new(&m2, &NewmarkConfig::new(1e-4))
        .err()
        .map(msg)
        .unwrap_or_default();
    assert!(e.contains("modal damping"), "{e}");
    // ZOH/LSOH are accepted but do not locate events.
    let mut cfg = FohConfig::new(1e-4);
    cfg.hold = Hold::Lsoh;
    assert!(Simulator::new(&plant, &cfg).is_ok());
}

/// A progress callback.
type Progress<'a> = &'a mut dyn FnMut(usize, usize);

/// Every integrator reports progress about 200 times, in order, ending at the last sample, and
/// reporting does not change the result.
#[test]
fn every_method_reports_progress_without_changing_the_result() {
    let model = beam_with_tip_displacement();
    let plant = foh_plant(&model, 12);
    let case = LoadCase::new("sine", vec![Signal::sine(2.0, 24.0)]);
    let (dt, n) = (1.0 / 24_000.0, 1000);
    let check = |name: &str, quiet: TimeHistory, run: &dyn Fn(Progress<'_>) -> TimeHistory| {
        let mut calls = Vec::new();
        let loud = run(&mut |done, total| calls.push((done, total)));
        assert_eq!(calls.len(), 200, "{name}: {} progress calls", calls.len());
        assert!(calls.iter().all(|&(_, total)| total == n), "{name}");
        assert!(
            calls.windows(2).all(|w| w[0].0 < w[1].0),
            "{name}: not increasing"
        );
        assert_eq!(calls.last().unwrap().0, n, "{name}");
        assert_eq!(
            quiet.output("tip_d").unwrap().values,
            loud.output("tip_d").unwrap().values,
            "{name}: progress changed the result"
        );
    };
    let sim = Simulator::new(&plant, &FohConfig::new(dt)).unwrap();
    check("foh", sim.run(&case, n).unwrap(), &|p| {
        sim.run_with_progress(&case, n, p).unwrap()
    });
    let rk = Rk45Config::default();
    check("rk45", rk45(&plant, &case, dt, n, &rk).unwrap(), &|p| {
        rk45_with_progress(&plant, &case, dt, n, &rk, p).unwrap()
    });
    let r4 = Rk4Config::default();
    check("rk4", rk4(&plant, &case, dt, n, &r4).unwrap(), &|p| {
        rk4_with_progress(&plant, &case, dt, n, &r4, p).unwrap()
    });
    let nm = Newmark::new(&model, &NewmarkConfig::new(dt)).unwrap();
    check("newmark", nm.run(&case, n).unwrap(), &|p| {
        nm.run_with_progress(&case, n, p).unwrap()
    });
}

/// A displacement sensor on the element's port shares the element's accumulator in the state
/// pass (one response row fewer), and still reads the element's displacement.
#[test]
fn a_sensor_on_an_element_port_shares_its_row() {
    let model = beam_with_tip_displacement();
    let plant = foh_plant(&model, 12);
    let case = LoadCase::new("sine", vec![Signal::sine(2.0, 24.0)]);
    let sim = Simulator::new(&plant, &FohConfig::new(1.0 / 2400.0)).unwrap();
    // Columns: the force at k and k+1, the element at k. Rows: element displacement and
    // velocity, tip and mid accelerations, tip_d (shared with the element displacement).
    assert_eq!(sim.flops_per_state_step(), 6 + 4 * 3 + 4 * 4);
    let h = sim.run(&case, 2400).unwrap();
    let tip = &h.output("tip_d").unwrap().values;
    let d = &h.element_displacements[0];
    assert!(max_rel(tip, d) < 1e-12, "{}", max_rel(tip, d));
}

/// The ECL beam with `elements` elements, a tip displacement sensor, and the tip spring made
/// linear (`k3 = 0`) for the load case built by [`linear_case`].
fn long_beam(elements: usize) -> Model {
    with_tip_displacement(
        nlsim_fixtures::build("ecl_beam", &[("elements".into(), elements.to_string())])
            .unwrap()
            .model,
    )
}

fn linear_case() -> LoadCase {
    let mut case = LoadCase::new("sine", vec![Signal::sine(2.0, 24.0)]);
    case.parameters.push((
        nlsim_kernel::Param::Element {
            element: "tip_spring".into(),
            param: "k3".into(),
        },
        0.0,
    ));
    case
}

#[test]
fn all_modes_of_a_396_dof_beam_give_the_response_of_100_modes() {
    // Every mode of the 396-DOF beam (λ_max / λ₁ = 5.5e9) against 100 modes plus residual
    // flexibility: the same response, where keeping more than 106 modes used to turn the first
    // bending pair rigid and put the tip 240 % off.
    let model = long_beam(66);
    let case = linear_case();
    let dt = 1.0 / 24_000.0;
    let run = |modes: usize| {
        let h = Simulator::new(&foh_plant(&model, modes), &FohConfig::new(dt))
            .unwrap()
            .run(&case, 2400)
            .unwrap();
        h.output("tip_d").unwrap().values.clone()
    };
    let all = run(model.n_dofs());
    let hundred = run(100);
    // The residual flexibility misses the truncated modes' dynamics by (ω / ω₁₀₁)² ≈ 5e-7 at
    // 24 Hz; the two runs agree far below the 1e-4 a wrong mode would show.
    let e = max_rel(&hundred, &all);
    assert!(e < 1e-6, "{e:e}");
}

#[test]
fn newmark_and_hht_on_a_4002_dof_beam_converge_to_foh_with_all_modes() {
    // A stiff 4002-DOF Rayleigh beam, linear: Newmark's Newton used to stall at step 1 (its
    // corrections were rounding noise amplified by K_eff⁻¹, 1e-8 of ‖d‖, above rtol 1e-10).
    let model = long_beam(667);
    assert_eq!(model.n_dofs(), 4002);
    let case = linear_case();
    let dt = 1.0 / 24_000.0;
    let n = 2400;
    let foh = Simulator::new(&foh_plant(&model, model.n_dofs()), &FohConfig::new(dt))
        .unwrap()
        .run(&case, n)
        .unwrap();
    let reference: Vec<f64> = foh
        .output("tip_d")
        .unwrap()
        .values
        .iter()
        .step_by(10)
        .copied()
        .collect();
    for alpha in [0.0, -0.05] {
        let mut errs = Vec::new();
        for sub in [1usize, 2, 4] {
            let mut cfg = NewmarkConfig::new(dt * 10.0);
            cfg.substeps = sub;
            cfg.alpha = alpha;
            let h = Newmark::new(&model, &cfg)
                .unwrap()
                .run(&case, n / 10)
                .unwrap();
            assert!(h.status.is_converged(), "α = {alpha}: {:?}", h.stopped);
            // A linear model: the first Newton iteration is exact, the second only confirms
            // that the residual is at its rounding floor.
            assert_eq!(h.stats.max_newton_iterations, 1, "α = {alpha}");
            errs.push(max_rel(&h.output("tip_d").unwrap().values, &reference));
        }
        // Second order in the step (HHT's α only adds damping of O(α h) at high frequency).
        for w in errs.windows(2) {
            let order = (w[0] / w[1]).log2();
            assert!(
                (1.8..2.3).contains(&order),
                "α = {alpha}: order {order:.2}: {errs:?}"
            );
        }
    }
}
