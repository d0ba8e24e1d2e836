//! Harmonic balance benchmarks: time per FRF point and per full FRF (400 points, H = 7) on
//! the ECL beam and on the hexahedral bracket after reduction (20 modes + residual
//! flexibility), next to a lower bound for a full-DOF harmonic balance on the same model.
//!
//! The full-DOF bound: a Newton iteration of HB on the unreduced model (as NLvib does it)
//! needs the dynamic stiffness `K − (kΩ)² M + ikΩ C` factorised for every harmonic
//! `k = 0..H` (its nonlinear coupling is low-rank). We time one sparse `L D Lᵀ` of the real,
//! undamped `K − Ω² M` (faer, the same symbolic analysis reused), a quarter or less of a
//! complex factorisation, and count two Newton iterations per point: the bound
//! `2 (H+1) t_LDLᵀ` flatters the full-DOF method.
//!
//! The thesis Duffing curve (`duffing_fig3`, 25–35 Hz by arclength continuation, as
//! `nlsim frf duffing_fig3 --from 25 --to 35 --harmonics H` runs it) is timed beside the
//! references of issue 18, measured on this machine: NLvib in Octave ≈ 25 s CPU per curve,
//! an independent numpy HB with Hill stability 1.0–1.8 s (0.7–1.0 s without).
//!
//! Run with `cargo bench -p nlsim-bench --bench hb -- --quick --noplot`; the 10⁵-DOF bracket
//! with `NLSIM_BENCH_LARGE=1`.

use criterion::{Criterion, criterion_group, criterion_main};
use nlsim_hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, continuation, stepped_sine};
use nlsim_kernel::Model;
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModeSelection, ShiftedPencil};
use std::hint::black_box;
use std::time::{Duration, Instant};

const H: usize = 7;
const POINTS: usize = 400;

fn system(model: &Model, modes: usize) -> (HbSystem, f64, f64) {
    let t = Instant::now();
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
    let secs = t.elapsed().as_secs_f64();
    let w1 = red.modes.omega()[0];
    let sys = HbSystem::from_model(
        model,
        &red,
        HarmonicSet::new(H, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    (sys, w1, secs)
}

fn grid(w1: f64) -> Vec<f64> {
    (0..POINTS)
        .map(|i| w1 * (0.8 + 0.5 * i as f64 / (POINTS - 1) as f64))
        .collect()
}

fn bench_model(c: &mut Criterion, name: &str, model: &Model) {
    let (sys, w1, red_s) = system(model, 20);
    let omegas = grid(w1);
    let mut g = c.benchmark_group(format!("hb_{name}"));
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(200));
    g.measurement_time(Duration::from_secs(3));
    // One point: Newton from the previous grid point's solution, as in a sweep.
    let sweep = stepped_sine(&sys, &omegas, 1.0, false)
        .unwrap()
        .into_branch()
        .unwrap();
    let x_prev = sweep.points[199].x.clone();
    g.bench_function("point", |b| {
        b.iter(|| black_box(sys.solve(omegas[200], 1.0, &x_prev).unwrap()))
    });
    // The same point through a warm workspace: cached receptances, no allocation (what a
    // calibration re-solving the test's frequencies does).
    let mut ws = sys.workspace(64 << 20);
    let mut xw = x_prev.clone();
    sys.solve_with(&mut ws, omegas[200], 1.0, &mut xw).unwrap();
    g.bench_function("point_warm_workspace", |b| {
        b.iter(|| {
            xw.copy_from_slice(&x_prev);
            black_box(sys.solve_with(&mut ws, omegas[200], 1.0, &mut xw).unwrap())
        })
    });
    let (x200, _) = sys.solve(omegas[200], 1.0, &x_prev).unwrap();
    g.bench_function("stability", |b| {
        b.iter(|| black_box(sys.stability(&x200, omegas[200]).unwrap()))
    });
    g.bench_function("frf_400_points", |b| {
        b.iter(|| {
            black_box(
                stepped_sine(&sys, &omegas, 1.0, false)
                    .unwrap()
                    .into_branch()
                    .unwrap(),
            )
        })
    });
    g.bench_function("frf_400_points_with_stability", |b| {
        b.iter(|| {
            black_box(
                stepped_sine(&sys, &omegas, 1.0, true)
                    .unwrap()
                    .into_branch()
                    .unwrap(),
            )
        })
    });
    g.finish();
    // Ratio table, same process.
    let t = Instant::now();
    let br = stepped_sine(&sys, &omegas, 1.0, false)
        .unwrap()
        .into_branch()
        .unwrap();
    let t_frf = t.elapsed().as_secs_f64();
    let iters: usize = br.points.iter().map(|p| p.iterations).sum();
    let pencil = ShiftedPencil::new(model.stiffness(), model.mass()).unwrap();
    let sigma = (1.05 * w1).powi(2);
    pencil.count_below(sigma).unwrap();
    let reps = 3;
    let t = Instant::now();
    for _ in 0..reps {
        black_box(pencil.count_below(sigma).unwrap());
    }
    let t_ldlt = t.elapsed().as_secs_f64() / reps as f64;
    let full_point = 2.0 * (H + 1) as f64 * t_ldlt;
    eprintln!(
        "\n  {name}: {} DOFs, 20 modes + residual (reduced in {red_s:.2} s), H = {H}, {} unknowns, AFT {:?}\n    \
         FRF of {POINTS} points: {:.3} s ({:.3} ms per point, {:.2} Newton iterations per point)\n    \
         full-DOF HB lower bound: L D Lᵀ of K − Ω²M {:.3e} s → ≥ {:.3e} s per point, ≥ {:.1} s per FRF\n    \
         ratio full-DOF / condensed: ≥ {:.0}x per FRF ({:.0}x including the one-off reduction)\n",
        model.n_dofs(),
        sys.n_unknowns(),
        sys.aft_samples(),
        t_frf,
        1e3 * t_frf / POINTS as f64,
        iters as f64 / POINTS as f64,
        t_ldlt,
        full_point,
        full_point * POINTS as f64,
        full_point * POINTS as f64 / t_frf,
        full_point * POINTS as f64 / (t_frf + red_s),
    );
}

/// NLvib (Octave) CPU seconds per Duffing curve, measured when issue 18 was filed.
const NLVIB_CURVE_S: f64 = 25.0;
/// The numpy HB with Hill stability, fastest measured CPU seconds per curve (with, without
/// stability).
const NUMPY_CURVE_S: [f64; 2] = [1.0, 0.7];

/// The thesis Duffing curve, 25–35 Hz, at H = 1 and 7, with and without stability.
fn duffing_curve(c: &mut Criterion) {
    let model = nlsim_fixtures::build("duffing_fig3", &[]).unwrap().model;
    let red = reduce(&model, &ReductionConfig::lowest(1)).unwrap();
    let mut g = c.benchmark_group("hb_duffing_curve");
    g.sample_size(20);
    g.warm_up_time(Duration::from_millis(300));
    g.measurement_time(Duration::from_secs(3));
    let mut table = Vec::new();
    for h in [1, 7] {
        let sys = HbSystem::from_model(
            &model,
            &red,
            HarmonicSet::new(h, 1).unwrap(),
            HbConfig::default(),
        )
        .unwrap();
        for stability in [true, false] {
            let mut cfg = ContinuationConfig::frequency(25.0, 35.0);
            cfg.stability = stability;
            let run = || {
                continuation(&sys, &cfg, None)
                    .unwrap()
                    .into_branch()
                    .unwrap()
            };
            let points = run().points.len();
            let label = if stability {
                "with_stability"
            } else {
                "no_stability"
            };
            g.bench_function(format!("h{h}_{label}"), |b| b.iter(|| black_box(run())));
            let reps = 20;
            let t = Instant::now();
            for _ in 0..reps {
                black_box(run());
            }
            let s = t.elapsed().as_secs_f64() / reps as f64;
            table.push((h, stability, points, s));
        }
    }
    g.finish();
    eprintln!("\n  Duffing curve 25–35 Hz (thesis fig. 3), one thread:");
    for (h, stability, points, s) in table {
        let numpy = NUMPY_CURVE_S[usize::from(!stability)];
        eprintln!(
            "    H = {h}, stability {stability:5}: {points} points, {:.1} ms per curve, \
             {:.0}x NLvib, {:.0}x numpy HB",
            1e3 * s,
            NLVIB_CURVE_S / s,
            numpy / s
        );
    }
}

fn hb(c: &mut Criterion) {
    // As the CLI runs it: faer's own parallelism off (the work here is small matrices).
    faer::set_global_parallelism(faer::Par::Seq);
    duffing_curve(c);
    let ecl = nlsim_fixtures::build("ecl_beam", &[]).unwrap().model;
    bench_model(c, "ecl_beam", &ecl);
    let mut sizes = vec![10_000usize];
    if std::env::var("NLSIM_BENCH_LARGE").is_ok() {
        sizes.push(100_000);
    }
    for target in sizes {
        let model = nlsim_bench::bracket_with_tip_sensor(target);
        bench_model(c, &format!("bracket_{}dofs", model.n_dofs()), &model);
    }
}

criterion_group!(benches, hb);
criterion_main!(benches);
