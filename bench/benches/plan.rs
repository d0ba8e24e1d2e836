//! Planning benchmarks:
//!
//! - `ecl_designs`: the ECL beam (20 elements, 6 modes, H = 3) with ten candidate
//!   accelerometers (every second node's uz), 4 force levels × 3 bands × 2 excitations (a
//!   pure sine, and one with a 5 % third-harmonic side tone) = 24 predicted stepped sines of
//!   15 steps, and every set of 1 to 3 sensors × 3 sets of measured harmonics: 12 600
//!   candidate tests ranked by D-optimality (the sweeps' information and the ranking timed
//!   together);
//! - `bracket_placement`: the hexahedral bracket of about 10⁵ DOFs reduced to 20 modes (the
//!   reduction outside the timing), the information of every DOF as a candidate
//!   accelerometer along a 15-step sweep, then 10 sensors by the greedy and exchange passes.
//!
//! Run with `cargo bench -p nlsim-bench --bench plan -- --quick --noplot`.

use criterion::{Criterion, criterion_group, criterion_main};
use nlsim_calib::{
    Band, Criterion as Crit, Exciter, Noise, Planner, SideTone, dof_information, greedy_placement,
    rank_designs, subsets,
};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Component, DofLabel, Param, Quantity, Sensor};
use nlsim_reduction::{ReductionConfig, reduce};
use std::hint::black_box;
use std::time::Duration;

fn ecl_designs(c: &mut Criterion) {
    let mut model = nlsim_fixtures::ecl_beam().model;
    for node in (3..=21).step_by(2) {
        let dof = model
            .dofs()
            .index_of(&DofLabel::new(node, Component::Uz))
            .unwrap();
        model
            .add_sensor(Sensor {
                name: format!("n{node}"),
                at: nlsim_kernel::Site::Dof(dof),
                quantity: Quantity::Acceleration,
            })
            .unwrap();
    }
    let red = reduce(&model, &ReductionConfig::lowest(6)).unwrap();
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(3, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let driven = sys
        .linear()
        .dominant_mode(sys.sensors()[0].port, 0..2)
        .unwrap();
    let params = [
        Param::element("tip_spring", "k3"),
        Param::ModalDamping(driven),
    ];
    let f = sys.linear().frequency_hz(driven);
    let planner = Planner::new(&sys, &params).unwrap();
    let noise = Noise {
        absolute: 1e-3,
        relative: 0.01,
    };
    let bands: Vec<Band> = [(0.85, 0.97), (0.92, 1.12), (1.05, 1.25)]
        .iter()
        .map(|&(a, b)| Band {
            label: format!("{a}-{b}"),
            from_hz: a * f,
            to_hz: b * f,
            steps: 15,
        })
        .collect();
    let mut exciters = Vec::new();
    for level in [0.05, 0.1, 0.2, 0.4] {
        exciters.push(Exciter::sine("shaker", level));
        exciters.push(Exciter {
            side: vec![SideTone {
                harmonic: 3,
                fraction: 0.05,
                phase: 0.0,
            }],
            ..Exciter::sine("shaker", level)
        });
    }
    let nc = sys.sensors().len();
    let channel_sets: Vec<Vec<usize>> = (1..=3).flat_map(|k| subsets(nc, k)).collect();
    let harmonic_sets = vec![vec![0], vec![0, 2], vec![0, 1, 2]];
    let mut g = c.benchmark_group("plan");
    g.measurement_time(Duration::from_secs(10));
    g.sample_size(10);
    g.bench_function("ecl_designs", |b| {
        b.iter(|| {
            let sweeps: Vec<_> = exciters
                .iter()
                .flat_map(|ex| {
                    bands
                        .iter()
                        .map(|band| {
                            planner
                                .sweep_information(ex, band, noise, &[1, 2, 3])
                                .unwrap()
                        })
                        .collect::<Vec<_>>()
                })
                .collect();
            let ranked =
                rank_designs(&sweeps, &channel_sets, &harmonic_sets, None, Crit::D).unwrap();
            assert!(ranked.len() >= 10_000);
            black_box(ranked.len())
        })
    });
    g.finish();
}

fn bracket_placement(c: &mut Criterion) {
    let model = nlsim_bench::bracket_with_tip_sensor(100_000);
    let red = reduce(&model, &ReductionConfig::lowest(20)).unwrap();
    let sys = HbSystem::from_model(
        &model,
        &red,
        HarmonicSet::new(3, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let el = sys.elements()[0].name().to_string();
    let params = [Param::element(&el, "k3"), Param::ModalDamping(0)];
    let f = sys.linear().frequency_hz(0);
    let input = sys.inputs()[0].0.clone();
    let shapes = red.modes.vectors.as_ref();
    let band = Band {
        label: "mode 1".into(),
        from_hz: 0.95 * f,
        to_hz: 1.05 * f,
        steps: 15,
    };
    let noise = Noise {
        absolute: 1e-3,
        relative: 0.01,
    };
    let mut g = c.benchmark_group("plan");
    g.measurement_time(Duration::from_secs(20));
    g.sample_size(10);
    g.bench_function(format!("bracket_placement_{}dofs", model.n_dofs()), |b| {
        b.iter(|| {
            let (terms, _) = dof_information(
                &sys,
                shapes,
                Quantity::Acceleration,
                &Exciter::sine(&input, 1.0),
                &band,
                &params,
                noise,
                &[1, 3],
            )
            .unwrap();
            black_box(greedy_placement(&terms, 10, None, 20).unwrap())
        })
    });
    g.finish();
}

criterion_group!(benches, ecl_designs, bracket_placement);
criterion_main!(benches);
