//! Time-domain benchmarks.
//!
//! 1. `foh_loop`: the FOH state update alone, on synthetic diagonal systems of 64 to 16 384
//!    states with one cubic element, one input and one output. Throughput is reported in
//!    floating-point operations (`Simulator::flops_per_state_step` × states × steps), next to
//!    `peak_fma`: a register-resident FMA kernel compiled for the same instruction set, whose
//!    throughput is the core's measured peak. Their ratio is the fraction of peak.
//! 2. `methods_<n>dofs`: the hexahedral bracket with the cubic tip spring and Rayleigh damping
//!    (0.5 % at modes 1 and 3), driven by a 10 N sine at 0.9 f1 for two periods from rest,
//!    reduced to 20, 60 and 150 modes + residual flexibility. Every method is first tuned,
//!    outside the timing, to the coarsest setting that reaches 1e-3 of the peak tip
//!    displacement: the hold integrators (FOH and LSOH) by samples per period against a tight
//!    RK45 of the same reduced model; RK45 by tolerance against the same reference; Newmark
//!    (the unreduced sparse model) by sub-steps, its error estimated from halving the step.
//!    Then each is timed; set-up (reduction, discretisation, factorisation) is not counted.
//!    Sizes: 10³ and 10⁴ DOFs, and 10⁵ with `NLSIM_BENCH_LARGE=1`. Above 2·10⁴ DOFs Newmark
//!    reuses the sub-steps tuned at 10⁴ and is timed over a few samples and scaled: its line
//!    says "(estimate)".
//!
//! Run with `cargo bench -p nlsim-bench --bench sim -- --quick --noplot`.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use faer::{Mat, c64};
use nlsim_kernel::{Coupling, Damping, Law, Model, NonlinearElement, Quantity};
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection, Port, PortKind};
use nlsim_sim::{
    ElementPort, FohConfig, Hold, LoadCase, Newmark, NewmarkConfig, OutputSpec, Plant, Rk45Config,
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
        vec![ElementPort::new(el, 0)],
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
/// stability limit, the hold integrators' is not, so the RK45/FOH ratio grows with the mode
/// count.
const MODES: [usize; 3] = [20, 60, 150];

/// Samples per period of the tight reference. Every entry of [`LADDER`] divides it, so each
/// candidate is compared with the reference at every one of its own samples.
const BASE: usize = 1152;

/// Samples per period tried for the hold integrators, in steps of 1.5 and 4/3.
const LADDER: [usize; 12] = [8, 12, 16, 24, 32, 48, 64, 96, 128, 192, 288, 576];

/// Above this size Newmark is not tuned (hours at 10⁵ DOFs): it reuses the sub-step count
/// tuned on the largest smaller model and is timed over [`NEWMARK_PROBE`] output samples.
const NEWMARK_TUNE_MAX_DOFS: usize = 20_000;

/// Output samples of the Newmark timing probe on large models.
const NEWMARK_PROBE: usize = 4;

/// The hold integrators and RK45 tuned to [`TARGET`] on one reduced plant.
struct Tuned {
    modes: usize,
    /// Highest retained natural frequency (Hz).
    f_max: f64,
    /// `(hold, samples per period, error)` for FOH and LSOH.
    holds: Vec<(Hold, usize, f64)>,
    /// Samples per period of the RK45 output grid: the coarsest hold grid.
    rk_spp: usize,
    rk_cfg: Rk45Config,
    rk_err: f64,
    rk_steps: usize,
}

fn hold_config(hold: Hold, dt: f64) -> FohConfig {
    FohConfig {
        hold,
        ..FohConfig::new(dt)
    }
}

/// Tunes FOH and LSOH (samples per period) and RK45 (tolerance) on `plant` against a tight
/// RK45 of the same plant sampled [`BASE`] times per period.
fn tune(s: &Setup, modes: usize, plant: &Plant) -> Tuned {
    let grid = |spp: usize| (1.0 / (s.f * spp as f64), s.n_periods * spp);
    let (dt_ref, n_ref) = grid(BASE);
    let tight = Rk45Config {
        rtol: 1e-11,
        atol: 1e-20,
        ..Rk45Config::default()
    };
    let reference = rk45(plant, &s.case, dt_ref, n_ref, &tight).unwrap();
    let holds: Vec<(Hold, usize, f64)> = [Hold::Foh, Hold::Lsoh]
        .into_iter()
        .map(|hold| {
            LADDER
                .into_iter()
                .find_map(|spp| {
                    let (dt, steps) = grid(spp);
                    let h = Simulator::new(plant, &hold_config(hold, dt))
                        .unwrap()
                        .run(&s.case, steps)
                        .unwrap();
                    let e = rel_err(tip(&h), 1, tip(&reference), BASE / spp);
                    (e <= TARGET).then_some((hold, spp, e))
                })
                .expect("the hold integrator reaches the target")
        })
        .collect();
    let rk_spp = holds.iter().map(|h| h.1).min().unwrap();
    let (rk_cfg, rk_err, rk_steps) = (2..=10)
        .find_map(|k| {
            let rtol = 10f64.powi(-k);
            let cfg = Rk45Config {
                rtol,
                atol: rtol * 1e-9,
                ..Rk45Config::default()
            };
            let (dt, steps) = grid(rk_spp);
            let h = rk45(plant, &s.case, dt, steps, &cfg).unwrap();
            let e = rel_err(tip(&h), 1, tip(&reference), BASE / rk_spp);
            (e <= TARGET).then_some((cfg, e, h.stats.steps))
        })
        .expect("RK45 reaches the target");
    let f_max = plant
        .system
        .poles
        .iter()
        .fold(0.0f64, |m, p| m.max(p.norm()))
        / (2.0 * PI);
    Tuned {
        modes,
        f_max,
        holds,
        rk_spp,
        rk_cfg,
        rk_err,
        rk_steps,
    }
}

/// Wall time of one call (s).
fn time(f: &dyn Fn()) -> f64 {
    let t = Instant::now();
    f();
    t.elapsed().as_secs_f64()
}

/// Time per call (s): the best of five batches, each of as many calls as fill 20 ms, so that
/// runs of tens of microseconds are not timer noise.
fn best(f: &dyn Fn()) -> f64 {
    let once = time(f).max(1e-7);
    let reps = ((0.02 / once).ceil() as usize).max(1);
    (0..5)
        .map(|_| {
            time(&|| {
                for _ in 0..reps {
                    f();
                }
            }) / reps as f64
        })
        .fold(f64::INFINITY, f64::min)
}

fn methods(c: &mut Criterion) {
    let mut sizes = vec![1_000usize, 10_000];
    if std::env::var("NLSIM_BENCH_LARGE").is_ok() {
        sizes.push(100_000);
    }
    // Newmark sub-steps tuned on the largest model so far, reused above the tuning limit.
    let mut tuned_sub = None;
    for target in sizes {
        let t_setup = Instant::now();
        let s = bracket_setup(target);
        let n = s.model.n_dofs();
        let duration = s.n_periods as f64 / s.f;
        let grid = |spp: usize| (1.0 / (s.f * spp as f64), s.n_periods * spp);
        let tuned: Vec<Tuned> = s.plants.iter().map(|(m, p)| tune(&s, *m, p)).collect();
        // Newmark: output every 1/64 period, sub-steps doubled until the halving estimate
        // (4/3)|N(s) − N(2s)| meets the target.
        let out_spp = 64;
        let (dt_out, steps_out) = grid(out_spp);
        let newmark = |sub: usize| {
            let mut cfg = NewmarkConfig::new(dt_out);
            cfg.substeps = sub;
            Newmark::new(&s.model, &cfg).unwrap()
        };
        let tune_newmark = n <= NEWMARK_TUNE_MAX_DOFS;
        let (sub, nm_err) = if tune_newmark {
            let mut sub = 1;
            let mut prev = newmark(sub).run(&s.case, steps_out).unwrap();
            let err = loop {
                let next = newmark(2 * sub).run(&s.case, steps_out).unwrap();
                let e = 4.0 / 3.0 * rel_err(tip(&prev), 1, tip(&next), 1);
                if e <= TARGET || sub >= 64 {
                    break e;
                }
                sub *= 2;
                prev = next;
            };
            tuned_sub = Some(sub);
            (sub, Some(err))
        } else {
            (tuned_sub.unwrap_or(4), None)
        };
        let nm = newmark(sub);
        let nm_how = match nm_err {
            Some(e) => format!("estimated error {e:.2e}"),
            None => format!(
                "sub-steps taken from the tuned smaller model (not tuned here); timed over {NEWMARK_PROBE} output samples and scaled"
            ),
        };
        eprintln!(
            "\n  bracket {n} DOFs, {duration:.4} s simulated (2 periods at {:.1} Hz), target {TARGET:e} of peak tip displacement (set-up and tuning {:.0} s):\n    Newmark unreduced, {} steps/period ({} steps), {nm_how}; K_eff factorised in {:.2} s",
            s.f,
            t_setup.elapsed().as_secs_f64(),
            out_spp * sub,
            s.n_periods * out_spp * sub,
            nm.setup_seconds
        );
        for t in &tuned {
            let holds: Vec<String> = t
                .holds
                .iter()
                .map(|(h, spp, e)| format!("{h} {spp} samples/period (error {e:.2e})"))
                .collect();
            eprintln!(
                "    {:>3} modes + residual (f_max {:.0} Hz): {}; RK45 rtol {:.0e} atol {:.0e}, {} steps, error {:.2e} on {} samples/period",
                t.modes,
                t.f_max,
                holds.join(", "),
                t.rk_cfg.rtol,
                t.rk_cfg.atol,
                t.rk_steps,
                t.rk_err,
                t.rk_spp
            );
        }
        let mut g = c.benchmark_group(format!("methods_{n}dofs"));
        g.sample_size(10);
        g.warm_up_time(Duration::from_millis(1));
        g.measurement_time(Duration::from_secs(2));
        // (hold, simulator, steps) per tuned plant, in `tuned` order.
        let sims: Vec<Vec<(Hold, Simulator, usize)>> = tuned
            .iter()
            .zip(&s.plants)
            .map(|(t, (_, plant))| {
                t.holds
                    .iter()
                    .map(|&(hold, spp, _)| {
                        let (dt, steps) = grid(spp);
                        let sim = Simulator::new(plant, &hold_config(hold, dt)).unwrap();
                        (hold, sim, steps)
                    })
                    .collect()
            })
            .collect();
        for ((t, (_, plant)), hs) in tuned.iter().zip(&s.plants).zip(&sims) {
            for (hold, sim, steps) in hs {
                g.bench_function(format!("{hold}_{}modes", t.modes), |b| {
                    b.iter(|| black_box(sim.run(&s.case, *steps).unwrap()))
                });
            }
            let (dt, steps) = grid(t.rk_spp);
            g.bench_function(format!("rk45_{}modes", t.modes), |b| {
                b.iter(|| black_box(rk45(plant, &s.case, dt, steps, &t.rk_cfg).unwrap()))
            });
        }
        g.finish();
        // Timed runs for the ratio table, in the same process, back to back: `best` for the
        // reduced methods, one Newmark run (seconds to minutes each).
        let t_nm = if tune_newmark {
            time(&|| drop(black_box(nm.run(&s.case, steps_out).unwrap()))) / duration
        } else {
            let probe = time(&|| drop(black_box(nm.run(&s.case, NEWMARK_PROBE).unwrap())));
            probe * steps_out as f64 / NEWMARK_PROBE as f64 / duration
        };
        let label = if tune_newmark { "" } else { " (estimate)" };
        for ((t, (_, plant)), hs) in tuned.iter().zip(&s.plants).zip(&sims) {
            let (dt, steps) = grid(t.rk_spp);
            let t_rk = best(&|| {
                drop(black_box(
                    rk45(plant, &s.case, dt, steps, &t.rk_cfg).unwrap(),
                ))
            }) / duration;
            let mut line = format!("  {:>3} modes, per simulated second:", t.modes);
            for (hold, sim, steps) in hs {
                let t_h = best(&|| drop(black_box(sim.run(&s.case, *steps).unwrap()))) / duration;
                line += &format!(
                    " {hold} {t_h:.3e} s (RK45/{hold} {:.0}x, Newmark/{hold} {:.0}x{label});",
                    t_rk / t_h,
                    t_nm / t_h
                );
            }
            eprintln!("{line} RK45 {t_rk:.3e} s; Newmark {t_nm:.3e} s{label}");
        }
        eprintln!();
    }
}

criterion_group!(benches, foh_loop, methods);
criterion_main!(benches);
