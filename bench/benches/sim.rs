//! Time-domain benchmarks.
//!
//! 1. `foh_loop`: the FOH state update alone, on synthetic diagonal systems of 64 to 16 384
//!    states with one cubic element, one input and one output. Throughput is reported in
//!    floating-point operations (`Simulator::flops_per_state_step` × states × steps), next to
//!    `peak_fma`: a register-resident FMA kernel compiled for the same instruction set, whose
//!    throughput is the core's measured peak. Their ratio is the fraction of peak.
//! 2. `methods_<n>dofs`: the hexahedral bracket with the cubic tip spring and Rayleigh damping
//!    (0.5 % at modes 1 and 3), driven by a 10 N sine at 0.9 f1 for two periods from rest. Every
//!    method is first tuned, outside the timing, to the coarsest setting that reaches 1e-3 of
//!    the peak tip displacement against its own converged solution: FOH (20 modes + residual
//!    flexibility) by samples per period against a tight RK45; RK45 (same reduced model) by
//!    tolerance; Newmark (the unreduced sparse model) by sub-steps, its error estimated from
//!    halving the step. Then each is timed. Sizes: 10³ and 10⁴ DOFs, and 10⁵ with
//!    `NLSIM_BENCH_LARGE=1` (Newmark then takes minutes per run).
//!
//! Run with `cargo bench -p nlsim-bench --bench sim -- --quick --noplot`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use faer::{Mat, c64};
use nlsim_kernel::{Coupling, Damping, Law, Model, NonlinearElement, Quantity};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection, Port, PortKind};
use nlsim_sim::{
    ElementPort, FohConfig, LoadCase, Newmark, NewmarkConfig, OutputSpec, Plant, Rk45Config,
    Signal, Simulator, TimeHistory, rk45,
};
use pulp::{Arch, Simd, WithSimd};
use std::f64::consts::PI;
use std::hint::black_box;
use std::time::{Duration, Instant};

/// A synthetic diagonal system: `ns` lightly damped modes from 10 Hz up, one port.
fn synthetic(ns: usize) -> Plant {
    let poles: Vec<c64> = (0..ns)
        .map(|s| {
            let w = 2.0 * PI * 10.0 * (1.0 + s as f64);
            c64::new(-0.01 * w, w)
        })
        .collect();
    let sys = ModalSystem {
        weights: vec![2.0; ns],
        input: Mat::from_fn(ns, 1, |s, _| (poles[s] - poles[s].conj()).inv()),
        output: Mat::from_fn(1, ns, |_, _| c64::new(1.0, 0.0)),
        feedthrough: Mat::zeros(1, 1),
        accel_feedthrough: Mat::zeros(1, 1),
        ports: vec![Port::dof("x", PortKind::Dof, 0)],
        initial: Vec::new(),
        n_modes: ns,
        poles,
    };
    let el = NonlinearElement::new("k3", Law::Cubic { k3: 1e6 }, Coupling::single(0)).unwrap();
    Plant::new(
        sys,
        vec![ElementPort {
            element: el,
            port: 0,
        }],
        vec![("x".into(), 0)],
        vec![OutputSpec {
            name: "x".into(),
            port: 0,
            quantity: Quantity::Acceleration,
        }],
    )
    .unwrap()
}

/// 16 independent FMA chains on register-resident vectors: `iters` × 16 × lanes FMAs.
struct PeakFma {
    iters: usize,
}

impl WithSimd for PeakFma {
    type Output = f64;
    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> f64 {
        let a = simd.splat_f64s(black_box(0.999_999_9));
        let b = simd.splat_f64s(black_box(1e-9));
        let mut acc = [simd.splat_f64s(black_box(1.0)); 16];
        for _ in 0..black_box(self.iters) {
            for x in acc.iter_mut() {
                *x = simd.mul_add_e_f64s(*x, a, b);
            }
        }
        let mut s = simd.splat_f64s(0.0);
        for x in acc {
            s = simd.add_f64s(s, x);
        }
        simd.reduce_sum_f64s(s)
    }
}

/// Lanes of the widest f64 vector pulp dispatches to here.
struct Lanes;
impl WithSimd for Lanes {
    type Output = usize;
    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) -> usize {
        std::mem::size_of::<S::f64s>() / 8
    }
}

fn foh_loop(c: &mut Criterion) {
    let arch = Arch::new();
    let lanes = arch.dispatch(Lanes);
    let mut g = c.benchmark_group("foh_loop");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(300));
    g.measurement_time(Duration::from_secs(2));
    let iters = 1_000_000;
    g.throughput(Throughput::Elements((iters * 16 * lanes * 2) as u64));
    g.bench_function(format!("peak_fma_{lanes}lanes"), |b| {
        b.iter(|| black_box(arch.dispatch(PeakFma { iters })))
    });
    for ns in [64usize, 256, 1024, 4096, 16384] {
        let plant = synthetic(ns);
        let sim = Simulator::new(&plant, &FohConfig::new(1e-4)).unwrap();
        let steps = (4_000_000 / ns).max(200);
        let case = LoadCase::new("sine", vec![Signal::sine(1.0, 15.0)]);
        g.throughput(Throughput::Elements(
            (sim.flops_per_state_step() * ns * steps) as u64,
        ));
        g.bench_function(format!("states_{ns}"), |b| {
            b.iter(|| black_box(sim.run(&case, steps).unwrap()))
        });
        let t = Instant::now();
        let reps = 3;
        for _ in 0..reps {
            black_box(sim.run(&case, steps).unwrap());
        }
        let per = t.elapsed().as_secs_f64() / reps as f64 / (ns * steps) as f64;
        eprintln!(
            "  {ns} states: {:.3} ns per mode-step, {:.2} GFLOP/s ({} flops per mode-step)",
            per * 1e9,
            sim.flops_per_state_step() as f64 / per * 1e-9,
            sim.flops_per_state_step()
        );
    }
    g.finish();
}

struct Setup {
    model: Model,
    /// `(retained modes, plant)`: the same model reduced to each mode count in [`MODES`].
    plants: Vec<(usize, Plant)>,
    case: LoadCase,
    f: f64,
    n_periods: usize,
}

fn bracket_setup(target: usize) -> Setup {
    let mut model = nlsim_bench::bracket_with_tip_sensor(target);
    let rc = |m| ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(m),
            ..EigenConfig::default()
        },
        ..ReductionConfig::default()
    };
    let probe = reduce(&model, &rc(3)).unwrap();
    let w = probe.modes.omega();
    model
        .set_damping(Damping::rayleigh_from_two_modes(w[0], 0.005, w[2], 0.005).unwrap())
        .unwrap();
    let plants = MODES
        .iter()
        .map(|&m| {
            let red = reduce(&model, &rc(m)).unwrap();
            (
                m,
                Plant::from_model(&model, &ModalSystem::new(&red).unwrap()).unwrap(),
            )
        })
        .collect();
    let f = 0.9 * w[0] / (2.0 * PI);
    let case = LoadCase::new("sine", vec![Signal::sine(10.0, f)]);
    Setup {
        model,
        plants,
        case,
        f,
        n_periods: 2,
    }
}

fn tip(h: &TimeHistory) -> &[f64] {
    &h.output("tip_d").unwrap().values
}

/// Max difference on the common grid (`a` every `sa`-th, `b` every `sb`-th sample) over the
/// peak of `b`.
fn rel_err(a: &[f64], sa: usize, b: &[f64], sb: usize) -> f64 {
    let x: Vec<f64> = a.iter().step_by(sa).copied().collect();
    let y: Vec<f64> = b.iter().step_by(sb).copied().collect();
    let p = y.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    x.iter()
        .zip(&y)
        .fold(0.0f64, |m, (u, v)| m.max((u - v).abs()))
        / p
}

const TARGET: f64 = 1e-3;

/// Retained mode counts compared: RK45's step is bounded by the highest retained mode's
/// stability limit, FOH's is not, so the RK45/FOH ratio grows with the mode count.
const MODES: [usize; 2] = [20, 60];

/// A method tuned to [`TARGET`] on one reduced plant.
struct Tuned {
    modes: usize,
    spp: usize,
    foh_err: f64,
    rk_cfg: Rk45Config,
    rk_err: f64,
    rk_steps: usize,
}

/// Tunes FOH (samples per period) and RK45 (tolerance) on `plant` against a tight RK45 of the
/// same plant sampled at `base` per period.
fn tune(s: &Setup, modes: usize, plant: &Plant) -> Tuned {
    let base = 512;
    let grid = |spp: usize| (1.0 / (s.f * spp as f64), s.n_periods * spp);
    let (dt_ref, n_ref) = grid(base);
    let tight = Rk45Config {
        rtol: 1e-11,
        atol: 1e-20,
        ..Rk45Config::default()
    };
    let reference = rk45(plant, &s.case, dt_ref, n_ref, &tight).unwrap();
    let (spp, foh_err) = [8usize, 16, 32, 64, 128, 256, 512]
        .into_iter()
        .find_map(|spp| {
            let (dt, steps) = grid(spp);
            let h = Simulator::new(plant, &FohConfig::new(dt))
                .unwrap()
                .run(&s.case, steps)
                .unwrap();
            let e = rel_err(tip(&h), 1, tip(&reference), base / spp);
            (e <= TARGET).then_some((spp, e))
        })
        .expect("FOH reaches the target");
    let (rk_cfg, rk_err, rk_steps) = (3..=10)
        .find_map(|k| {
            let rtol = 10f64.powi(-k);
            let cfg = Rk45Config {
                rtol,
                atol: rtol * 1e-9,
                ..Rk45Config::default()
            };
            let (dt, steps) = grid(spp);
            let h = rk45(plant, &s.case, dt, steps, &cfg).unwrap();
            let e = rel_err(tip(&h), 1, tip(&reference), base / spp);
            (e <= TARGET).then_some((cfg, e, h.stats.steps))
        })
        .expect("RK45 reaches the target");
    Tuned {
        modes,
        spp,
        foh_err,
        rk_cfg,
        rk_err,
        rk_steps,
    }
}

fn methods(c: &mut Criterion) {
    let mut sizes = vec![1_000usize, 10_000];
    if std::env::var("NLSIM_BENCH_LARGE").is_ok() {
        sizes.push(100_000);
    }
    for target in sizes {
        let s = bracket_setup(target);
        let n = s.model.n_dofs();
        let duration = s.n_periods as f64 / s.f;
        let grid = |spp: usize| (1.0 / (s.f * spp as f64), s.n_periods * spp);
        let tuned: Vec<Tuned> = s.plants.iter().map(|(m, p)| tune(&s, *m, p)).collect();
        // Newmark: output every 1/64 period, sub-steps doubled until the halving estimate
        // (4/3)|N(s) − N(2s)| meets the target.
        let out_spp = 64;
        let (dt_out, steps_out) = grid(out_spp);
        let run_nm = |sub: usize| {
            let mut cfg = NewmarkConfig::new(dt_out);
            cfg.substeps = sub;
            let nm = Newmark::new(&s.model, &cfg).unwrap();
            let h = nm.run(&s.case, steps_out).unwrap();
            (nm, h)
        };
        let mut sub = 1;
        let (_, mut prev) = run_nm(sub);
        let nm_err = loop {
            let (_, next) = run_nm(2 * sub);
            let e = 4.0 / 3.0 * rel_err(tip(&prev), 1, tip(&next), 1);
            if e <= TARGET || sub >= 64 {
                break e;
            }
            sub *= 2;
            prev = next;
        };
        let (nm, _) = run_nm(sub);
        let large = n > 50_000;
        eprintln!(
            "\n  bracket {n} DOFs, {duration:.4} s simulated (2 periods at {:.1} Hz), target {TARGET:e} of peak tip displacement:\n    Newmark unreduced, {} steps/period ({} steps), estimated error {nm_err:.2e}, K_eff factorised in {:.2} s",
            s.f,
            out_spp * sub,
            s.n_periods * out_spp * sub,
            nm.setup_seconds
        );
        for t in &tuned {
            eprintln!(
                "    {:>2} modes + residual: FOH {} samples/period, error {:.2e}; RK45 rtol {:.0e} atol {:.0e}, {} steps, error {:.2e}",
                t.modes, t.spp, t.foh_err, t.rk_cfg.rtol, t.rk_cfg.atol, t.rk_steps, t.rk_err
            );
        }
        let mut g = c.benchmark_group(format!("methods_{n}dofs"));
        g.sample_size(10);
        g.warm_up_time(Duration::from_millis(1));
        g.measurement_time(Duration::from_secs(2));
        let sims: Vec<(Simulator, f64, usize)> = tuned
            .iter()
            .zip(&s.plants)
            .map(|(t, (_, plant))| {
                let (dt, steps) = grid(t.spp);
                (
                    Simulator::new(plant, &FohConfig::new(dt)).unwrap(),
                    dt,
                    steps,
                )
            })
            .collect();
        for ((t, (_, plant)), (sim, dt, steps)) in tuned.iter().zip(&s.plants).zip(&sims) {
            g.bench_function(format!("foh_{}modes", t.modes), |b| {
                b.iter(|| black_box(sim.run(&s.case, *steps).unwrap()))
            });
            g.bench_function(format!("rk45_{}modes", t.modes), |b| {
                b.iter(|| black_box(rk45(plant, &s.case, *dt, *steps, &t.rk_cfg).unwrap()))
            });
        }
        // At 10⁵ DOFs one Newmark run takes minutes: it is timed once below instead.
        if !large {
            g.bench_function("newmark", |b| {
                b.iter(|| black_box(nm.run(&s.case, steps_out).unwrap()))
            });
        }
        g.finish();
        // Timed runs for the ratio table (same process, back to back; best of five for the
        // fast methods, one Newmark run).
        let time = |f: &dyn Fn()| {
            let t = Instant::now();
            f();
            t.elapsed().as_secs_f64()
        };
        let best = |f: &dyn Fn()| (0..5).map(|_| time(f)).fold(f64::INFINITY, f64::min);
        let t_nm = time(&|| drop(black_box(nm.run(&s.case, steps_out).unwrap())));
        for ((t, (_, plant)), (sim, dt, steps)) in tuned.iter().zip(&s.plants).zip(&sims) {
            let t_foh = best(&|| drop(black_box(sim.run(&s.case, *steps).unwrap())));
            let t_rk = best(&|| {
                drop(black_box(
                    rk45(plant, &s.case, *dt, *steps, &t.rk_cfg).unwrap(),
                ))
            });
            eprintln!(
                "  {:>2} modes, per simulated second: FOH {:.3e} s, RK45 {:.3e} s, Newmark {:.3e} s; RK45/FOH {:.0}x, Newmark/FOH {:.0}x",
                t.modes,
                t_foh / duration,
                t_rk / duration,
                t_nm / duration,
                t_rk / t_foh,
                t_nm / t_foh
            );
        }
        eprintln!();
    }
}

criterion_group!(benches, foh_loop, methods);
criterion_main!(benches);
