//! Calibration benchmarks on the ECL beam (cubic tip spring and the driven mode's damping,
//! two stepped sweeps of 17 and 21 steps, harmonics 1 and 3, 3 % noise):
//!
//! - `full`: the whole calibration of the goal — 200 maximin Latin-hypercube
//!   candidates evaluated in parallel, Levenberg–Marquardt from the best 3, Cramér–Rao bound
//!   and 10-fold cross validation (goal: under 10 s on 2 cores);
//! - `jacobian/sensitivities` against `jacobian/central_differences`: one residual-and-Jacobian
//!   evaluation from the HB sensitivities, beside the `2n + 1` sweep evaluations a
//!   central-difference Jacobian needs (the ratio is what LM saves per iteration).
//!
//! - `bracket_fe_30600dofs/…`: FE-level parameters (a grounded spring at the tip and the
//!   cubic tip element's `k3`) of the 30 600-DOF bracket ([`nlsim_bench::bracket_fe_case`]):
//!   one residual-and-Jacobian evaluation on the parametric reduced model beside the same
//!   with a full reduction per evaluation (`evaluation/parametric`, `evaluation/full`), and
//!   the whole default calibration on the parametric model (`calibration/parametric`: 65
//!   candidates, 3 starts, 10 folds; goal under 20 s).
//!
//! - `dwell/…`: harmonics of one stepped-sine dwell from its time histories
//!   ([`nlsim_calib::extract_dwell`]): 10⁵ samples of a drive and three responses (4·10⁵
//!   samples in all), 3 harmonics, 41.37 samples per period, the frequency refined and the
//!   transient found; throughput in samples (of every channel) per second (goal ≥ 10⁷ per
//!   core).
//! - `track/…`: harmonics tracked along a sine sweep ([`nlsim_calib::track_sweep`]): 4·10⁵
//!   samples of a drive and three responses (1.6·10⁶ in all), 20 → 30 Hz, 3 harmonics,
//!   windows of 10 periods, 100 points (every sample of the sweep's windows is fitted once);
//!   throughput in samples of every channel per second.
//!
//! - `time_domain/…`: time-domain calibration ([`nlsim_calib::calibrate_time`]) of the
//!   bump-stop cantilever's contact stiffness and gap on a virtual linear sine sweep of 10⁵
//!   samples (0.8 → 1.2 × the first natural frequency at 0.6 N, 80 samples per period of
//!   it, 2 % noise, 8 modes): the default calibration (65 candidates, 3 starts, 10 folds;
//!   goal under 5 s), and one residual-and-Jacobian evaluation by the forward sensitivities.
//!
//! Run with `cargo bench -p nlsim-bench --bench calib -- --quick --noplot`.

use criterion::{Criterion, criterion_group, criterion_main};
use nlsim_calib::{CalibrationConfig, FrfObjective, LeastSquares, SweepPlan, calibrate};
use std::hint::black_box;
use std::time::Duration;

fn objective() -> FrfObjective {
    nlsim_bench::ecl_calibration_objective(&[
        SweepPlan::linear("0.05 N", 22.0, 26.0, 17, 0.05),
        SweepPlan::linear("0.2 N", 22.0, 27.0, 21, 0.2),
    ])
}

fn bench(c: &mut Criterion) {
    let obj = objective();
    let cfg = CalibrationConfig {
        lhs_samples: 200,
        seed: 1,
        starts: 3,
        folds: 10,
        ..Default::default()
    };
    let mut g = c.benchmark_group("calib_ecl");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    g.bench_function("full", |b| {
        b.iter(|| black_box(calibrate(&obj, &cfg).unwrap()))
    });
    let u = obj.to_internal(&[8e9, 0.012]);
    g.bench_function("jacobian/sensitivities", |b| {
        let mut o = obj.clone();
        b.iter(|| black_box(o.evaluate(&u).unwrap().unwrap()))
    });
    g.bench_function("jacobian/central_differences", |b| {
        let mut o = obj.clone();
        b.iter(|| {
            let p = o.to_values(&u);
            let base = o.evaluate_values(&p, None, false).unwrap();
            let mut cols = Vec::new();
            for k in 0..u.len() {
                let (mut a, mut m) = (u.clone(), u.clone());
                a[k] += 1e-6;
                m[k] -= 1e-6;
                let ra = o.evaluate_values(&o.to_values(&a), None, false).unwrap();
                let rm = o.evaluate_values(&o.to_values(&m), None, false).unwrap();
                cols.push(
                    ra.residuals
                        .iter()
                        .zip(&rm.residuals)
                        .map(|(x, y)| (x - y) / 2e-6)
                        .collect::<Vec<_>>(),
                );
            }
            black_box((base, cols))
        })
    });
    g.finish();
}

fn bracket_fe(c: &mut Criterion) {
    use nlsim_calib::FeReduction;
    let case = nlsim_bench::bracket_fe_case(30_000);
    let prom = case.objective(&FeReduction::default());
    let full = case.objective(&FeReduction::Full);
    let mut g = c.benchmark_group(format!("bracket_fe_{}dofs", case.model.n_dofs()));
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    // Away from the nominal point and from the truth, inside the box.
    let u = prom.to_internal(&[3e4, 3e12]);
    for (name, obj) in [("parametric", &prom), ("full", &full)] {
        g.bench_function(format!("evaluation/{name}"), |b| {
            let mut o = obj.clone();
            b.iter(|| black_box(o.evaluate(&u).unwrap().unwrap()))
        });
    }
    let cfg = CalibrationConfig::default();
    g.bench_function("calibration/parametric", |b| {
        b.iter(|| black_box(calibrate(&prom, &cfg).unwrap()))
    });
    g.finish();
}

fn dwell(c: &mut Criterion) {
    use std::f64::consts::PI;
    let n = 100_000;
    let (f, rate) = (24.17, 24.17 * 41.37);
    let signal = |amp: f64, lag: f64, decay: f64| -> Vec<f64> {
        (0..n)
            .map(|i| {
                let t = i as f64 / rate;
                let w = 2.0 * PI * f * t;
                amp * (w - lag).sin()
                    + 0.05 * amp * (3.0 * w).cos()
                    + decay * (-t / 0.3).exp() * (2.0 * PI * 31.0 * t).sin()
            })
            .collect()
    };
    let signals = [
        signal(0.2, 0.0, 0.0),
        signal(3.0, 0.4, 1.0),
        signal(1.0, 0.5, 0.3),
        signal(0.1, 2.0, 0.05),
    ];
    let refs: Vec<&[f64]> = signals.iter().map(Vec::as_slice).collect();
    let names = ["drive", "a", "b", "c"];
    let cfg = nlsim_calib::DwellConfig::default();
    let mut g = c.benchmark_group("dwell");
    g.throughput(criterion::Throughput::Elements((4 * n) as u64));
    g.bench_function("extract_4x100k", |b| {
        b.iter(|| {
            black_box(
                nlsim_calib::extract_dwell(&names, &refs, rate, Some(f * 1.01), &cfg).unwrap(),
            )
        })
    });
    g.finish();
}

fn track(c: &mut Criterion) {
    use std::f64::consts::PI;
    let (n, rate, f0, r) = (400_000, 2000.0, 20.0, 0.05);
    let signal = |amp: f64, lag: f64| -> Vec<f64> {
        (0..n)
            .map(|i| {
                let t = i as f64 / rate;
                let w = 2.0 * PI * (f0 * t + 0.5 * r * t * t);
                amp * (1.0 + 0.001 * t) * (w - lag).sin() + 0.05 * amp * (3.0 * w).cos()
            })
            .collect()
    };
    let signals = [
        signal(0.2, 0.0),
        signal(3.0, 0.4),
        signal(1.0, 0.5),
        signal(0.1, 2.0),
    ];
    let refs: Vec<&[f64]> = signals.iter().map(Vec::as_slice).collect();
    let names = ["drive", "a", "b", "c"];
    let cfg = nlsim_calib::TrackConfig::default();
    let mut g = c.benchmark_group("track");
    g.throughput(criterion::Throughput::Elements((4 * n) as u64));
    g.bench_function("sweep_4x400k", |b| {
        b.iter(|| black_box(nlsim_calib::track_sweep(&names, &refs, rate, &cfg).unwrap()))
    });
    g.finish();
}

fn time_domain(c: &mut Criterion) {
    use nlsim_calib::{ParamSpec, TimeObjective, calibrate_time, synthesize_time};
    use nlsim_kernel::Param;
    let model = nlsim_fixtures::build("bumpstop_cantilever", &[])
        .expect("the bump-stop cantilever")
        .model;
    let reduction = nlsim_reduction::ReductionConfig::lowest(8);
    let f1 = nlsim_reduction::reduce(&model, &reduction)
        .expect("it reduces")
        .modes
        .frequencies_hz()[0];
    let specs = vec![
        ParamSpec::new(Param::element("stop", "k1"), 5e4, 1e6),
        ParamSpec::new(Param::element("stop", "e1"), 5e-4, 2e-3),
    ];
    let (n, rate) = (100_000, 80.0 * f1);
    let seconds = (n - 1) as f64 / rate;
    let sweep = nlsim_sim::Signal::Sweep {
        amplitude: 0.6,
        f0_hz: 0.8 * f1,
        f1_hz: 1.2 * f1,
        duration: seconds,
        logarithmic: false,
    };
    let force: Vec<f64> = (0..n).map(|k| sweep.eval(k as f64 / rate)).collect();
    let record = synthesize_time(
        &model,
        &reduction,
        &specs,
        &[2e5, 1e-3],
        "shaker",
        force,
        rate,
        0.02,
        7,
    )
    .expect("the virtual record");
    let obj = TimeObjective::new(&model, &reduction, std::sync::Arc::new(record), specs)
        .expect("the objective");
    let mut g = c.benchmark_group("time_domain");
    g.sample_size(10).measurement_time(Duration::from_secs(20));
    g.bench_function("evaluation_1e5", |b| {
        let mut o = obj.clone();
        let u = o.to_internal(&[3e5, 1.2e-3]);
        b.iter(|| black_box(o.evaluate(&u).unwrap()))
    });
    g.bench_function("calibration_1e5", |b| {
        b.iter(|| black_box(calibrate_time(&obj, &CalibrationConfig::default(), &|_| {}).unwrap()))
    });
    g.finish();
}

criterion_group!(benches, bench, bracket_fe, dwell, track, time_domain);
criterion_main!(benches);
