//! Forward sensitivities of the hold recursion (`Simulator::run_with_sensitivities`) against
//! central differences of the run itself (the oracle: the same discrete map at p ± h), on the
//! cubic-tip ECL beam and the bump-stop cantilever (contact stiffness and gap, with event
//! location off), and what they refuse.

use nlsim_kernel::{Model, Param, Quantity};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection};
use nlsim_sim::{FohConfig, LoadCase, OutputSpec, Plant, Signal, Simulator};

/// The model's plant (8 modes) plus the element coordinate as a displacement output `u`.
fn plant_of(model: &Model) -> Plant {
    let cfg = ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(8),
            ..EigenConfig::default()
        },
        ..ReductionConfig::default()
    };
    let red = reduce(model, &cfg).unwrap();
    let sys = ModalSystem::new(&red).unwrap();
    let mut p = Plant::from_model(model, &sys).unwrap();
    let port = p.elements[0].port;
    p.outputs.push(OutputSpec {
        name: "u".into(),
        port,
        quantity: Quantity::Displacement,
    });
    p
}

/// The largest difference between the sensitivities of every output and the central
/// differences of the run at `value·(1 ± h)`, relative to the largest sensitivity of that
/// output, over the parameters.
fn worst_against_central_differences(
    sim: &Simulator,
    case: &LoadCase,
    n: usize,
    params: &[(Param, f64)],
) -> f64 {
    let mut case = case.clone();
    case.parameters = params.to_vec();
    let names: Vec<Param> = params.iter().map(|p| p.0.clone()).collect();
    let (h, s) = sim.run_with_sensitivities(&case, n, &names).unwrap();
    assert!(h.status.is_converged());
    let mut worst = 0.0f64;
    for (j, (p, v)) in params.iter().enumerate() {
        // Relative step 1e-5: truncation ~1e-10, round-off ~1e-16/1e-5 of the outputs.
        let step = 1e-5 * v.abs();
        let run = |x: f64| {
            let mut c = case.clone();
            c.parameters[j] = (p.clone(), x);
            sim.run(&c, n).unwrap()
        };
        let (up, down) = (run(v + step), run(v - step));
        for (o, series) in s.outputs[j].iter().enumerate() {
            assert_eq!(series.len(), n + 1);
            let top = series.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            assert!(top > 0.0, "{p}: output {o} does not depend on it");
            let err = series
                .iter()
                .zip(&up.outputs[o].values)
                .zip(&down.outputs[o].values)
                .map(|((d, a), b)| (d - (a - b) / (2.0 * step)).abs())
                .fold(0.0f64, f64::max);
            eprintln!(
                "{p}: output {}: |S − FD| ≤ {:.1e} of max |S| = {top:.3e}",
                h.outputs[o].name,
                err / top
            );
            worst = worst.max(err / top);
        }
    }
    worst
}

#[test]
fn cubic_sensitivities_match_central_differences() {
    let fx = nlsim_fixtures::ecl_beam();
    let plant = plant_of(&fx.model);
    let f1 = plant.system.poles[0].im.abs() / (2.0 * std::f64::consts::PI);
    let case = LoadCase::new("sine", vec![Signal::sine(2.0, 0.98 * f1)]);
    let dt = 1.0 / (60.0 * f1);
    let sim = Simulator::new(&plant, &FohConfig::new(dt)).unwrap();
    let w = worst_against_central_differences(
        &sim,
        &case,
        3000,
        &[(Param::element("tip_spring", "k3"), 6e9)],
    );
    assert!(w <= 1e-6, "{w:e}");
}

#[test]
fn clearance_sensitivities_match_central_differences_without_event_location() {
    let model = nlsim_fixtures::build("bumpstop_cantilever", &[])
        .unwrap()
        .model;
    let plant = plant_of(&model);
    let f1 = plant.system.poles[0].im.abs() / (2.0 * std::f64::consts::PI);
    // Near the first resonance with enough force to close the gap every period.
    let case = LoadCase::new("sine", vec![Signal::sine(0.6, f1)]);
    let dt = 1.0 / (80.0 * f1);
    let cfg = FohConfig {
        locate_events: false,
        ..FohConfig::new(dt)
    };
    let sim = Simulator::new(&plant, &cfg).unwrap();
    let params = [
        (Param::element("stop", "k1"), 2e5),
        (Param::element("stop", "e1"), 1e-3),
    ];
    let (h, _) = sim
        .run_with_sensitivities(
            &LoadCase {
                parameters: params.to_vec(),
                ..case.clone()
            },
            4000,
            &[],
        )
        .unwrap();
    let contact = h.element_displacements[0]
        .iter()
        .filter(|&&u| u > 1e-3)
        .count();
    eprintln!("{contact} of 4001 samples in contact");
    assert!(
        contact > 100,
        "the stop must be hit: {contact} samples in contact"
    );
    let w = worst_against_central_differences(&sim, &case, 4000, &params);
    assert!(w <= 1e-6, "{w:e}");
}

#[test]
fn sensitivities_refuse_what_they_cannot_follow() {
    let model = nlsim_fixtures::build("bumpstop_cantilever", &[])
        .unwrap()
        .model;
    let plant = plant_of(&model);
    let case = LoadCase::new("sine", vec![Signal::sine(0.6, 10.0)]);
    // Event location moves the sub-steps with the parameters.
    let sim = Simulator::new(&plant, &FohConfig::new(1e-3)).unwrap();
    let e = sim
        .run_with_sensitivities(&case, 10, &[Param::element("stop", "k1")])
        .unwrap_err();
    assert!(e.to_string().contains("event location off"), "{e}");
    let sim = Simulator::new(
        &plant,
        &FohConfig {
            locate_events: false,
            ..FohConfig::new(1e-3)
        },
    )
    .unwrap();
    for p in [
        Param::element("stop", "k9"),
        Param::element("nothing", "k1"),
        Param::ModalDamping(0),
    ] {
        let e = sim
            .run_with_sensitivities(&case, 10, std::slice::from_ref(&p))
            .unwrap_err();
        assert!(e.to_string().contains(&p.to_string()), "{p}: {e}");
    }
}
