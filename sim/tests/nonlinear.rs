//! Nonlinear checks: FOH against tight RK45 references (order of convergence, steady states
//! on both stable Duffing branches), contact events on the bump-stop beam, batches.

use faer::c64;
use nlsim_fixtures::{DUFFING_FIG3, duffing_fig3, duffing_first_order_amplitudes, ecl_beam};
use nlsim_kernel::{Damping, Model, Quantity};
use nlsim_reduction::modal::{ReducedModel, ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection};
use nlsim_sim::{
    FohConfig, InitialState, LoadCase, OutputSpec, Plant, Rk45Config, Signal, Simulator,
    TimeHistory, rk45, run_batch,
};
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

/// The model's plant plus the element coordinate as a displacement output `u`.
fn plant_of(model: &Model, red: &ReducedModel) -> Plant {
    let sys = ModalSystem::new(red).unwrap();
    let mut p = Plant::from_model(model, &sys).unwrap();
    let port = p.elements[0].port;
    p.outputs.push(OutputSpec {
        name: "u".into(),
        port,
        quantity: Quantity::Displacement,
    });
    p
}

fn tight() -> Rk45Config {
    Rk45Config {
        rtol: 1e-12,
        atol: 1e-18,
        ..Rk45Config::default()
    }
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

fn peak(a: &[f64]) -> f64 {
    a.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

/// Samples of `h`'s output `name` at every `stride`-th sample.
fn every(h: &TimeHistory, name: &str, stride: usize) -> Vec<f64> {
    h.output(name)
        .unwrap()
        .values
        .iter()
        .step_by(stride)
        .copied()
        .collect()
}

/// Errors of FOH at T, T/2, T/4, T/8 against the reference sampled at T/8, on a common grid.
fn convergence(plant: &Plant, case: &LoadCase, dt: f64, n: usize) -> Vec<f64> {
    let reference = rk45(plant, case, dt / 8.0, 8 * n, &tight()).unwrap();
    let r = every(&reference, "u", 8);
    let scale = peak(&r);
    assert!(scale > 0.0);
    [1usize, 2, 4, 8]
        .iter()
        .map(|&d| {
            let sim = Simulator::new(plant, &FohConfig::new(dt / d as f64)).unwrap();
            let h = sim.run(case, n * d).unwrap();
            max_diff(&every(&h, "u", d), &r) / scale
        })
        .collect()
}

fn assert_second_order(errs: &[f64], what: &str) {
    for w in errs.windows(2).skip(1) {
        let order = (w[0] / w[1]).log2();
        assert!(
            (1.8..2.3).contains(&order),
            "{what}: observed order {order:.2} (errors {errs:?})"
        );
    }
}

#[test]
fn duffing_foh_converges_at_second_order_to_rk45() {
    let fx = duffing_fig3();
    let red = reduced(&fx.model, 1);
    let plant = plant_of(&fx.model, &red);
    let case = LoadCase::new("sine", vec![Signal::sine(2.0, 29.5)]);
    // 0.4 s of the transient from rest, T = 1/(29.5 · 32).
    let dt = 1.0 / (29.5 * 32.0);
    let errs = convergence(&plant, &case, dt, (0.4 / dt) as usize);
    assert_second_order(&errs, "Duffing");
    assert!(errs[3] < 1e-4, "finest error {:e}", errs[3]);
}

#[test]
fn cubic_tip_beam_foh_converges_at_second_order_to_rk45() {
    let fx = ecl_beam();
    let red = reduced(&fx.model, 6);
    let plant = plant_of(&fx.model, &red);
    // Near the first bending mode, strong enough for the cubic spring to matter.
    let case = LoadCase::new("sine", vec![Signal::sine(2.0, 24.0)]);
    let dt = 1.0 / 4000.0;
    let errs = convergence(&plant, &case, dt, 800);
    assert_second_order(&errs, "cubic-tip beam");
    // The spring is active: its force is a sizeable part of the drive.
    let sim = Simulator::new(&plant, &FohConfig::new(dt)).unwrap();
    let h = sim.run(&case, 800).unwrap();
    assert!(
        peak(&h.element_forces[0]) > 0.05,
        "cubic force {}",
        peak(&h.element_forces[0])
    );
}

/// Steady-state amplitude of `u` over the last `periods` periods.
fn steady_amplitude(h: &TimeHistory, samples_per_period: usize, periods: usize) -> f64 {
    let v = &h.output("u").unwrap().values;
    peak(&v[v.len() - samples_per_period * periods..])
}

#[test]
fn duffing_steady_states_on_both_stable_branches_agree_with_rk45() {
    let (m, c, k, p) = DUFFING_FIG3;
    let fx = duffing_fig3();
    let red = reduced(&fx.model, 1);
    let plant = plant_of(&fx.model, &red);
    let f_hz = 30.0;
    let w = 2.0 * PI * f_hz;
    let roots = duffing_first_order_amplitudes(m, c, k, p, 2.0, w);
    assert_eq!(
        roots.len(),
        3,
        "30 Hz is inside the three-solution region: {roots:?}"
    );
    let spp = 128;
    let dt = 1.0 / (f_hz * spp as f64);
    // 25 s: the free transient decays by e^{−ζ ω_n t} = e^{−7}.
    let n = (25.0 / dt) as usize;
    for (branch, &a) in [(0usize, &roots[0]), (2, &roots[2])] {
        // Start on the first-order HB solution q = Re(Q e^{iωt}) of the sine force −2i.
        let q = c64::new(0.0, -2.0) / c64::new(k - m * w * w + 0.75 * p * a * a, w * c);
        let (q0, v0) = (q.re, (c64::new(0.0, w) * q).re);
        let eta = red.modal_coordinates(fx.model.mass(), &[q0]).unwrap();
        let eta_dot = red.modal_coordinates(fx.model.mass(), &[v0]).unwrap();
        let mut case = LoadCase::new("sine", vec![Signal::sine(2.0, f_hz)]);
        case.initial = InitialState::Modal {
            displacement: eta,
            velocity: eta_dot,
        };
        let foh = Simulator::new(&plant, &FohConfig::new(dt))
            .unwrap()
            .run(&case, n)
            .unwrap();
        let rk = rk45(&plant, &case, dt, n, &tight()).unwrap();
        let (af, ar) = (
            steady_amplitude(&foh, spp, 5),
            steady_amplitude(&rk, spp, 5),
        );
        // FOH bias at θ = 2π/128: ≈ θ²/12 = 2e-4, amplified near resonance.
        assert!(
            (af - ar).abs() <= 2e-3 * ar,
            "branch {branch}: FOH {af:e} vs RK45 {ar:e}"
        );
        // Both stay on the branch they started on (first-order HB neglects the 3rd harmonic).
        assert!(
            (ar - a).abs() <= 0.03 * a,
            "branch {branch}: RK45 {ar:e} vs HB1 {a:e}"
        );
    }
}

fn bumpstop(damped: bool) -> (Model, ReducedModel, Plant) {
    let mut model = nlsim_fixtures::build("bumpstop_cantilever", &[])
        .unwrap()
        .model;
    if !damped {
        model.set_damping(Damping::None).unwrap();
    }
    let red = reduced(&model, 8);
    let plant = plant_of(&model, &red);
    (model, red, plant)
}

#[test]
fn bumpstop_contact_onset_is_located() {
    let (_, _, plant) = bumpstop(true);
    let sys = &plant.system;
    let f1 = sys.poles[0].im / (2.0 * PI);
    let amp = 0.4;
    let case = LoadCase::new("sine", vec![Signal::sine(amp, f1)]);
    // Exact linear response until the first contact: for sin ωt from rest,
    // z_s(t) = b̃ F/(2i) [(e^{iωt} − e^{λt})/(iω − λ) − (e^{−iωt} − e^{λt})/(−iω − λ)].
    let w = 2.0 * PI * f1;
    let (shaker, tip) = (plant.inputs[0].1, plant.elements[0].port);
    let gap = 1e-3;
    let y = |t: f64| -> f64 {
        let mut y = sys.feedthrough[(tip, shaker)] * amp * (w * t).sin();
        for s in 0..sys.n_states() {
            let l = sys.poles[s];
            let iw = c64::new(0.0, w);
            let el = (l * t).exp();
            let z = sys.input[(s, shaker)] * amp / c64::new(0.0, 2.0)
                * (((iw * t).exp() - el) / (iw - l) - ((-iw * t).exp() - el) / (-iw - l));
            y += sys.weights[s] * (sys.output[(tip, s)] * z).re;
        }
        y
    };
    let mut t = 0.0;
    let step = 1e-4;
    while y(t) < gap {
        t += step;
        assert!(t < 5.0, "no contact within 5 s");
    }
    let (mut lo, mut hi) = (t - step, t);
    for _ in 0..60 {
        let mid = 0.5 * (lo + hi);
        if y(mid) < gap { lo = mid } else { hi = mid }
    }
    let t_exact = 0.5 * (lo + hi);
    let mut errs = Vec::new();
    for spp in [40.0, 80.0, 160.0] {
        let dt = 1.0 / (f1 * spp);
        let sim = Simulator::new(&plant, &FohConfig::new(dt)).unwrap();
        let h = sim.run(&case, ((t_exact + 0.05) / dt) as usize).unwrap();
        let first = h.stats.events.first().expect("a contact event");
        assert!(first.closing);
        errs.push((first.time - t_exact).abs() / dt);
    }
    // The event time inherits the FOH's O(T²) response error: in units of T it falls as T.
    assert!(errs[2] < 0.01, "onset error {errs:?} (in steps)");
    assert!(
        errs[0] / errs[2] > 2.5,
        "onset error falls with T: {errs:?}"
    );
}

#[test]
fn bumpstop_events_restore_second_order() {
    let (_, _, plant) = bumpstop(true);
    let f1 = plant.system.poles[0].im / (2.0 * PI);
    let case = LoadCase::new("sine", vec![Signal::sine(0.6, f1)]);
    let dt = 1.0 / (f1 * 50.0);
    let n = (0.5 / dt) as usize;
    let reference = rk45(&plant, &case, dt / 8.0, 8 * n, &tight()).unwrap();
    let r = every(&reference, "u", 8);
    let scale = peak(&r);
    assert!(scale > 1.1e-3, "the stop (gap 1 mm) is hit: peak {scale:e}");
    let errs = |events: bool| -> Vec<f64> {
        [1usize, 2, 4, 8]
            .iter()
            .map(|&d| {
                let mut cfg = FohConfig::new(dt / d as f64);
                cfg.locate_events = events;
                let h = Simulator::new(&plant, &cfg)
                    .unwrap()
                    .run(&case, n * d)
                    .unwrap();
                max_diff(&every(&h, "u", d), &r) / scale
            })
            .collect()
    };
    let with = errs(true);
    let without = errs(false);
    assert_second_order(&with, "bump stop with events");
    // The contact force is continuous (a kink in stiffness), so a fixed step keeps second
    // order too, with a larger constant; locating the events is never worse and clearly
    // better on the coarse step.
    for (w, wo) in with.iter().zip(&without) {
        assert!(*w <= 1.05 * wo, "with {with:?}, without {without:?}");
    }
    assert!(
        with[0] < 0.8 * without[0],
        "with {with:?}, without {without:?}"
    );
}

#[test]
fn bumpstop_energy_is_conserved_without_damping() {
    let (_, red, plant) = bumpstop(false);
    let sys = &plant.system;
    let tip = plant.elements[0].port;
    let m = red.n_modes();
    // A tip impulse of 0.05 N s: η̇ = Φ_tip · I. The tip then hits the stop about twice a
    // period, exciting the higher modes at every impact.
    let eta_dot: Vec<f64> = (0..m).map(|r| red.participation[(tip, r)] * 0.05).collect();
    let f1 = sys.poles[0].im / (2.0 * PI);
    let (k, gap) = (2e5, 1e-3);
    let d = sys.feedthrough[(tip, tip)];
    // Conserved: Σ ½(η̇² + ω²η²) + ½ k (u − gap)₊² + ½ D g², with u = y − D g the port
    // displacement and g the contact force (undamped proportional form: one state per mode,
    // η = 2 Re z, η̇ = 2 Re(λ z)).
    let energy = |z: &[c64]| -> f64 {
        let mut e = 0.0;
        for r in 0..m {
            let (eta, etad) = (2.0 * z[r].re, 2.0 * (sys.poles[r] * z[r]).re);
            e += 0.5 * (etad * etad + sys.poles[r].im.powi(2) * eta * eta);
        }
        let y0 = plant.modal_response(tip, Quantity::Displacement, z);
        let g = (k * (y0 - gap) / (1.0 + k * d)).max(0.0);
        let u = y0 - d * g;
        e + 0.5 * k * (u - gap).max(0.0).powi(2) + 0.5 * d * g * g
    };
    let z0 = sys.initial_states(&vec![0.0; m], &eta_dot).unwrap();
    let e0 = energy(&z0);
    let mut drifts = Vec::new();
    for spp in [100usize, 200, 400, 800] {
        let sim = Simulator::new(&plant, &FohConfig::new(1.0 / (f1 * spp as f64))).unwrap();
        let mut z = z0.clone();
        let mut contacts = 0;
        let mut worst = 0.0f64;
        // 40 periods, restarted from the final state every period to read the energy.
        for _ in 0..40 {
            let mut case = LoadCase::new("free", vec![Signal::Zero]);
            case.initial = InitialState::States(z.clone());
            let h = sim.run(&case, spp).unwrap();
            contacts += h.stats.events.iter().filter(|e| e.closing).count();
            assert!(h.stats.max_newton_iterations <= 10);
            z = h.final_state.clone();
            worst = worst.max((energy(&z) - e0).abs() / e0);
        }
        assert!(contacts >= 40, "the tip hits the stop: {contacts} contacts");
        drifts.push(worst);
    }
    // The drift comes from the held contact force over the impacts: it falls with the step
    // (about as T²) and stays bounded, no energy is pumped in.
    for w in drifts.windows(2) {
        assert!(w[1] < 0.5 * w[0], "energy drift falls with T: {drifts:?}");
    }
    assert!(
        drifts[3] < 2e-3,
        "energy drift at 800 samples per period: {drifts:?}"
    );
}

#[test]
fn bumpstop_forced_run_has_no_chattering() {
    let (_, _, plant) = bumpstop(true);
    let f1 = plant.system.poles[0].im / (2.0 * PI);
    let case = LoadCase::new("sine", vec![Signal::sine(1.0, f1)]);
    let dt = 1.0 / (f1 * 64.0);
    let periods = 150;
    let h = Simulator::new(&plant, &FohConfig::new(dt))
        .unwrap()
        .run(&case, 64 * periods)
        .unwrap();
    let closings = h.stats.events.iter().filter(|e| e.closing).count();
    assert!(closings >= periods / 2, "it hits the stop: {closings}");
    assert!(
        closings <= 2 * periods,
        "no chattering: {closings} closings in {periods} periods"
    );
    assert!(h.stats.max_newton_iterations <= 10);
    let u = &h.output("u").unwrap().values;
    assert!(peak(u) < 5e-3, "bounded: {:e}", peak(u));
}

#[test]
fn batch_is_bit_identical_for_any_thread_count() {
    let fx = ecl_beam();
    let red = reduced(&fx.model, 6);
    let plant = plant_of(&fx.model, &red);
    let sim = Simulator::new(&plant, &FohConfig::new(1.0 / 4000.0)).unwrap();
    let cases: Vec<LoadCase> = (0..6)
        .map(|i| {
            let mut c = LoadCase::new(
                format!("k3 #{i}"),
                vec![Signal::sine(1.0 + 0.2 * i as f64, 24.0)],
            );
            c.parameters
                .push(("tip_spring.k3".parse().unwrap(), 6e9 * (1.0 + i as f64)));
            c
        })
        .collect();
    let run = |threads: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap()
            .install(|| run_batch(&sim, &cases, 2000))
    };
    let (a, b) = (run(1), run(3));
    for (x, y) in a.iter().zip(&b) {
        let (x, y) = (x.as_ref().unwrap(), y.as_ref().unwrap());
        assert_eq!(x.outputs, y.outputs);
        assert_eq!(x.element_forces, y.element_forces);
    }
    // The parameter reached the runs: a stiffer spring, a smaller tip response.
    let single = sim.run(&cases[5], 2000).unwrap();
    assert_eq!(single.outputs, a[5].as_ref().unwrap().outputs);
    assert_ne!(
        a[0].as_ref().unwrap().outputs,
        a[1].as_ref().unwrap().outputs
    );
}

#[test]
fn accelerations_with_residual_flexibility_do_not_depend_on_the_output_rate() {
    // RK45 is converged at both rates and its dense output gives the same states at common
    // samples; the residual flexibility's rate terms used to differentiate the element force's
    // contact kink over the output step (1.1 % apart at the peak between 8 and 64 kHz).
    let (_, _, plant) = bumpstop(true);
    assert!(
        plant.system.feedthrough.norm_max() > 0.0,
        "residual flexibility on"
    );
    let f1 = plant.system.poles[0].im / (2.0 * PI);
    let case = LoadCase::new("sine", vec![Signal::sine(1.0, f1)]);
    let cfg = Rk45Config {
        rtol: 1e-9,
        atol: 1e-16,
        ..Rk45Config::default()
    };
    let duration = 0.3;
    let run =
        |rate: f64| rk45(&plant, &case, 1.0 / rate, (duration * rate) as usize, &cfg).unwrap();
    let (slow, fast) = (run(8000.0), run(64000.0));
    let g = &slow.element_forces[0];
    assert!(
        g.iter().filter(|&&x| x != 0.0).count() > 10,
        "the stop is hit"
    );
    for name in ["tip", "mid"] {
        let a = every(&slow, name, 1);
        let b = every(&fast, name, 8);
        let e = max_diff(&a, &b) / peak(&b);
        // Both within rtol of the same solution: far below the 1e-2 of the old difference.
        assert!(e < 1e-5, "{name}: {e:e}");
    }
}

/// A recorder's accelerations through the residual flexibility of a contact: the second
/// difference of the sampled contact force `g = k (sin θ − sin 0.2π)₊` (a kink where the stop
/// closes and opens) that `add_kinked_residual_accelerations` adds gives harmonics equal to
/// `−D (ikω)² G_k`, the term of the harmonic balance, with an error second order in the
/// step (the difference's factor `sinc²(kω dt/2)` and the sampled kink's aliasing: 4 times
/// smaller per halving, asserted); the oracle `G_k` is a 2²⁰-point sum of the force over one
/// period. Only accelerations get the term, and a polynomial law none (its `D g̈` comes with
/// the run).
#[test]
fn kinked_residual_accelerations_carry_the_contact_harmonics() {
    use nlsim_sim::add_kinked_residual_accelerations;
    let (_, _, mut plant) = bumpstop(true);
    let port = plant.elements[0].port;
    plant.outputs.push(OutputSpec {
        name: "a".into(),
        port,
        quantity: Quantity::Acceleration,
    });
    let d = plant.system.feedthrough[(port, port)];
    assert!(d > 0.0, "residual flexibility on");
    let f = 24.0;
    let w = 2.0 * PI * f;
    // The stop closes at θ = 0.2π and opens at 0.8π: on a sample of every grid below, so
    // that each grid meets the kinks alike and the error falls exactly at second order.
    let c = (0.2 * PI).sin();
    let contact = |th: f64| 2e5 * (th.sin() - c).max(0.0);
    // Harmonic k of x over one period of `len` samples.
    let fourier = |x: &dyn Fn(usize) -> f64, len: usize, k: usize| {
        (0..len)
            .map(|i| x(i) * c64::cis(-2.0 * PI * (k * i) as f64 / len as f64))
            .sum::<c64>()
            * (2.0 / len as f64)
    };
    let fine = 1 << 20;
    // a = −D g̈: harmonic k is −D (ikω)² G_k = D (kω)² G_k.
    let want: Vec<c64> = (1..=9)
        .map(|k| {
            let gk = fourier(&|i| contact(2.0 * PI * i as f64 / fine as f64), fine, k);
            d * (k as f64 * w).powi(2) * gk
        })
        .collect();
    let top = want.iter().map(|x| x.norm()).fold(0.0, f64::max);
    let mut errors = Vec::new();
    for per in [650usize, 1300, 2600] {
        let dt = 1.0 / (f * per as f64);
        let n = 3 * per;
        let g: Vec<f64> = (0..n).map(|i| contact(w * i as f64 * dt)).collect();
        let mut outs: Vec<Vec<f64>> = vec![vec![0.0; n]; plant.outputs.len()];
        {
            let mut views: Vec<&mut [f64]> = outs.iter_mut().map(|o| o.as_mut_slice()).collect();
            add_kinked_residual_accelerations(&plant, std::slice::from_ref(&g), dt, &mut views);
        }
        // Displacement outputs get nothing.
        let u = plant.outputs.iter().position(|o| o.name == "u").unwrap();
        assert!(outs[u].iter().all(|&x| x == 0.0));
        let a = outs.last().unwrap();
        // The middle period (the ends are one-sided differences).
        let err = (1..=9)
            .map(|k| (fourier(&|i| a[i + per], per, k) - want[k - 1]).norm() / top)
            .fold(0.0, f64::max);
        errors.push(err);
    }
    eprintln!(
        "harmonics 1-9 of −D g̈ against the oracle, 650/1300/2600 samples per period: {errors:?}"
    );
    for w in errors.windows(2) {
        assert!((w[0] / w[1] - 4.0).abs() < 0.5, "second order: {errors:?}");
    }
    assert!(errors[2] < 1e-5, "{errors:?}");
    // A polynomial law's term comes with the run: none added here.
    let mut cubic = plant.clone();
    cubic.elements[0].element = nlsim_kernel::NonlinearElement::new(
        "cubic",
        nlsim_kernel::Law::Cubic { k3: 1e9 },
        cubic.elements[0].element.coupling().clone(),
    )
    .unwrap();
    let g: Vec<f64> = (0..300).map(|i| contact(w * i as f64 / 1e4)).collect();
    let mut outs: Vec<Vec<f64>> = vec![vec![0.0; 300]; plant.outputs.len()];
    {
        let mut views: Vec<&mut [f64]> = outs.iter_mut().map(|o| o.as_mut_slice()).collect();
        add_kinked_residual_accelerations(&cubic, std::slice::from_ref(&g), 1e-4, &mut views);
    }
    assert!(outs.iter().flatten().all(|&x| x == 0.0));
}

/// NLvib's example 6 (a mass on two orthogonal springs under large deflection, in its two
/// modal coordinates) with its geometric nonlinearity as one coupled polynomial element:
/// `g1 = a1/2 (3q1² + q2²) + a2 q1q2 + c q1 (q1² + q2²)`,
/// `g2 = a2/2 (3q2² + q1²) + a1 q1q2 + c q2 (q1² + q2²)`, `a_i = ω_i²`, `c = (a1 + a2)/2`.
fn geometric_2dof() -> Model {
    use nlsim_kernel::{
        Coupling, DofMap, Excitation, Law, MonomialTerm, NonlinearElement, Sensor, SparseSym,
    };
    let (w1, w2, z1, z2) = (1.13f64, 2.0f64, 1e-3, 5e-3);
    let (a1, a2) = (w1 * w1, w2 * w2);
    let c = (a1 + a2) / 2.0;
    let mut m = Model::new(
        "geometric_2dof",
        DofMap::scalar(2),
        SparseSym::diagonal("M", &[1.0, 1.0]).unwrap(),
        SparseSym::diagonal("K", &[a1, a2]).unwrap(),
    )
    .unwrap();
    m.set_damping(Damping::Matrix(
        SparseSym::diagonal("C", &[2.0 * z1 * w1, 2.0 * z2 * w2]).unwrap(),
    ))
    .unwrap();
    // (output, powers of q1 and q2, coefficient)
    let terms = [
        (0, [2, 0], 1.5 * a1),
        (0, [0, 2], a1 / 2.0),
        (0, [1, 1], a2),
        (0, [3, 0], c),
        (0, [1, 2], c),
        (1, [0, 2], 1.5 * a2),
        (1, [2, 0], a2 / 2.0),
        (1, [1, 1], a1),
        (1, [0, 3], c),
        (1, [2, 1], c),
    ]
    .iter()
    .map(|&(o, p, k)| MonomialTerm::new(o, &p, k))
    .collect();
    m.add_element(
        NonlinearElement::coupled(
            "geometry",
            Law::CoupledPolynomial { inputs: 2, terms },
            vec![Coupling::single(0), Coupling::single(1)],
        )
        .unwrap(),
    )
    .unwrap();
    for d in 0..2 {
        m.add_excitation(Excitation {
            name: format!("f{}", d + 1),
            at: nlsim_kernel::Site::Dof(d),
            amplitude: 1.0,
            harmonics: Vec::new(),
        })
        .unwrap();
        m.add_sensor(Sensor {
            name: format!("q{}", d + 1),
            at: nlsim_kernel::Site::Dof(d),
            quantity: Quantity::Displacement,
        })
        .unwrap();
    }
    m
}

/// The geometric forces of [`geometric_2dof`] written out by hand.
fn geometric_forces(q1: f64, q2: f64) -> [f64; 2] {
    let (a1, a2) = (1.13f64 * 1.13, 4.0);
    let c = (a1 + a2) / 2.0;
    let r2 = q1 * q1 + q2 * q2;
    [
        a1 / 2.0 * (3.0 * q1 * q1 + q2 * q2) + a2 * q1 * q2 + c * q1 * r2,
        a2 / 2.0 * (3.0 * q2 * q2 + q1 * q1) + a1 * q1 * q2 + c * q2 * r2,
    ]
}

/// `(q1, q2)` of [`geometric_2dof`] under `amp · sin(Ω t)` on both coordinates, from rest, by
/// classical RK4 on the equations of motion written out (`q̈ = f − D q̇ − K q − g(q)`), sampled
/// every `every` steps of `h`.
fn geometric_rk4(amp: f64, omega: f64, h: f64, steps: usize, every: usize) -> [Vec<f64>; 2] {
    let (w1, w2, z1, z2) = (1.13f64, 2.0f64, 1e-3, 5e-3);
    let rhs = |t: f64, z: [f64; 4]| -> [f64; 4] {
        let g = geometric_forces(z[0], z[1]);
        let f = amp * (omega * t).sin();
        [
            z[2],
            z[3],
            f - 2.0 * z1 * w1 * z[2] - w1 * w1 * z[0] - g[0],
            f - 2.0 * z2 * w2 * z[3] - w2 * w2 * z[1] - g[1],
        ]
    };
    let mut z = [0.0; 4];
    let mut out = [vec![0.0], vec![0.0]];
    for i in 0..steps {
        let t = i as f64 * h;
        let k1 = rhs(t, z);
        let at = |k: &[f64; 4], s: f64| std::array::from_fn::<f64, 4, _>(|j| z[j] + s * k[j]);
        let k2 = rhs(t + h / 2.0, at(&k1, h / 2.0));
        let k3 = rhs(t + h / 2.0, at(&k2, h / 2.0));
        let k4 = rhs(t + h, at(&k3, h));
        for j in 0..4 {
            z[j] += h / 6.0 * (k1[j] + 2.0 * k2[j] + 2.0 * k3[j] + k4[j]);
        }
        if (i + 1) % every == 0 {
            out[0].push(z[0]);
            out[1].push(z[1]);
        }
    }
    out
}

/// The case of the coupled-element checks: `0.03 sin(1.1 t)` on both coordinates of
/// [`geometric_2dof`], near its first mode, 300 samples of 0.05 s (15 s, 2.6 periods) from
/// rest, with its RK4 reference at a 64 times finer step.
struct GeometricCase {
    case: LoadCase,
    dt: f64,
    n: usize,
    reference: [Vec<f64>; 2],
    scale: f64,
}

impl GeometricCase {
    fn new() -> Self {
        let (amp, omega) = (0.03, 1.1);
        let sig = Signal::Sine {
            amplitude: amp,
            freq_hz: omega / (2.0 * PI),
            phase: 0.0,
        };
        let (dt, n) = (0.05, 300);
        let reference = geometric_rk4(amp, omega, dt / 64.0, 64 * n, 64);
        let scale = peak(&reference[0]).max(peak(&reference[1]));
        GeometricCase {
            case: LoadCase::new("sine", vec![sig.clone(), sig]),
            dt,
            n,
            reference,
            scale,
        }
    }

    /// The largest deviation of `h`'s `q1`, `q2` (every `stride`-th sample) from the
    /// reference, relative to its peak.
    fn error(&self, h: &TimeHistory, stride: usize) -> f64 {
        (0..2)
            .map(|c| {
                max_diff(
                    &every(h, &format!("q{}", c + 1), stride),
                    &self.reference[c],
                )
            })
            .fold(0.0, f64::max)
            / self.scale
    }
}

/// A law on two coordinates in the time domain: FOH (and RK45) on the reduced plant against
/// RK4 on the equations of motion written out independently of the element, with the
/// geometric forces reaching a third of the linear ones.
#[test]
fn coupled_geometric_element_matches_its_written_out_equations() {
    let model = geometric_2dof();
    let red = reduced(&model, 2);
    let sys = ModalSystem::new(&red).unwrap();
    let plant = Plant::from_model(&model, &sys).unwrap();
    assert_eq!(plant.elements.len(), 2, "one entry per coordinate");
    assert_eq!(
        nlsim_kernel::Parameterized::parameters(&plant).len(),
        10,
        "the coupled element's ten coefficients, listed once"
    );
    let g = GeometricCase::new();
    let (case, dt, n) = (&g.case, g.dt, g.n);
    let err = |h: &TimeHistory, stride: usize| g.error(h, stride);
    let errs: Vec<f64> = [1usize, 2, 4, 8]
        .iter()
        .map(|&d| {
            let sim = Simulator::new(&plant, &FohConfig::new(dt / d as f64)).unwrap();
            err(&sim.run(case, n * d).unwrap(), d)
        })
        .collect();
    eprintln!("coupled geometric 2-DOF, FOH errors at dt/1, /2, /4, /8: {errs:?}");
    assert_second_order(&errs, "coupled geometric 2-DOF");
    assert!(errs[3] < 1e-4, "finest error {:e}", errs[3]);
    // The nonlinearity matters: the geometric forces reach a third of the linear restoring
    // force (0.35 at q1 = 0.16).
    let h = Simulator::new(&plant, &FohConfig::new(dt / 8.0))
        .unwrap()
        .run(case, 8 * n)
        .unwrap();
    assert_eq!(h.element_names, ["geometry[1]", "geometry[2]"]);
    let (q1, q2) = (&h.element_displacements[0], &h.element_displacements[1]);
    let g_peak = peak(&h.element_forces[0]);
    let lin_peak = 1.13f64 * 1.13 * peak(q1);
    assert!(g_peak > 0.3 * lin_peak, "g1 {g_peak:e}, a1 q1 {lin_peak:e}");
    // Each recorded force is the law at the recorded coordinates.
    for k in 0..q1.len() {
        let g = geometric_forces(q1[k], q2[k]);
        for c in 0..2 {
            let x = h.element_forces[c][k];
            assert!(
                (x - g[c]).abs() <= 1e-10 * g_peak,
                "sample {k}, force {}: {x:e} vs {:e}",
                c + 1,
                g[c]
            );
        }
    }
    // RK45 on the same plant, tight, agrees with the written-out equations too.
    let r = rk45(&plant, case, dt, n, &tight()).unwrap();
    assert!(err(&r, 1) < 1e-8, "RK45 {:e}", err(&r, 1));
}

/// A coupled element whose terms do not mix its coordinates is its scalar elements: the
/// 2-DOF chain's two cubic springs (one to ground, one between the masses) as one element
/// on two coordinates gives their time histories, by FOH and by RK45.
#[test]
fn a_separable_coupled_element_equals_its_scalar_elements() {
    use nlsim_kernel::{Law, MonomialTerm, NonlinearElement};
    let fx = nlsim_fixtures::build("chain_2dof", &[]).unwrap();
    let scalar = fx.model;
    let mut coupled = scalar.clone();
    let (ground, link) = (&scalar.elements()[0], &scalar.elements()[1]);
    let k3 = |e: &NonlinearElement| match e.law() {
        Law::Cubic { k3 } => *k3,
        other => panic!("the fixture's springs are cubic, not {}", other.kind()),
    };
    let terms = vec![
        MonomialTerm::new(0, &[3, 0], k3(ground)),
        MonomialTerm::new(1, &[0, 3], k3(link)),
    ];
    let both = NonlinearElement::coupled(
        "springs",
        Law::CoupledPolynomial { inputs: 2, terms },
        vec![ground.coupling().clone(), link.coupling().clone()],
    )
    .unwrap();
    coupled.clear_elements();
    coupled.add_element(both).unwrap();
    let plant = |m: &Model| {
        let red = reduced(m, 2);
        Plant::from_model(m, &ModalSystem::new(&red).unwrap()).unwrap()
    };
    let (ps, pc) = (plant(&scalar), plant(&coupled));
    // Near the first mode, hard enough for both springs to stiffen the response.
    let case = LoadCase::new("sine", vec![Signal::sine(30.0, 10.0)]);
    let dt = 1.0 / 2000.0;
    let runs = |p: &Plant| {
        [
            Simulator::new(p, &FohConfig::new(dt))
                .unwrap()
                .run(&case, 2000)
                .unwrap(),
            rk45(p, &case, dt, 2000, &tight()).unwrap(),
        ]
    };
    for (s, c) in runs(&ps).iter().zip(&runs(&pc)) {
        for name in ["mass1", "mass2"] {
            let (a, b) = (every(s, name, 1), every(c, name, 1));
            let d = max_diff(&a, &b) / peak(&a);
            assert!(d < 1e-10, "{} {name}: {d:e}", s.method);
        }
        for e in 0..2 {
            let (a, b) = (&s.element_forces[e], &c.element_forces[e]);
            let d = max_diff(a, b) / peak(a);
            assert!(d < 1e-10, "{} force {e}: {d:e}", s.method);
            assert!(peak(a) > 0.1 * 30.0, "spring {e} is active: {:e}", peak(a));
        }
    }
}

/// Element entries that do not form whole groups are refused, naming the element.
#[test]
fn a_coupled_element_needs_all_its_ports() {
    let model = geometric_2dof();
    let red = reduced(&model, 2);
    let sys = ModalSystem::new(&red).unwrap();
    let full = Plant::from_model(&model, &sys).unwrap();
    let el = full.elements[0].element.clone();
    let (p0, p1) = (full.elements[0].port, full.elements[1].port);
    let err = |b: nlsim_sim::PlantBuilder| b.build().unwrap_err().to_string();
    let one = err(Plant::builder(sys.clone()).coupled_element(el.clone(), &[p0]));
    assert!(
        one.contains("'geometry'") && one.contains("2 coordinates"),
        "{one}"
    );
    let scalar = err(Plant::builder(sys.clone()).element(el.clone(), p0));
    assert!(scalar.contains("'geometry'"), "{scalar}");
    let ok = Plant::builder(sys)
        .coupled_element(el, &[p0, p1])
        .input("f1", full.inputs[0].1)
        .input("f2", full.inputs[1].1)
        .build()
        .unwrap();
    assert_eq!(ok.elements.len(), 2);
}

/// The unreduced Newmark reference takes the coupled element too (its Woodbury update with the
/// element's `2 × 2` tangent block): second order against RK4 on the written-out equations,
/// and its forces are the law at its coordinates.
#[test]
fn newmark_takes_a_coupled_element() {
    use nlsim_sim::{Newmark, NewmarkConfig};
    let model = geometric_2dof();
    let g = GeometricCase::new();
    let (case, dt, n) = (&g.case, g.dt, g.n);
    let mut last = None;
    let errs: Vec<f64> = [1usize, 2, 4, 8]
        .iter()
        .map(|&substeps| {
            let cfg = NewmarkConfig {
                substeps,
                ..NewmarkConfig::new(dt)
            };
            let h = Newmark::new(&model, &cfg).unwrap().run(case, n).unwrap();
            let e = g.error(&h, 1);
            last = Some(h);
            e
        })
        .collect();
    eprintln!("coupled geometric 2-DOF, Newmark errors at 1, 2, 4, 8 substeps: {errs:?}");
    assert_second_order(&errs, "Newmark, coupled geometric 2-DOF");
    let h = last.unwrap();
    // Newton on the exact block tangent converges quadratically.
    eprintln!(
        "Newton: at most {} iterations per step",
        h.stats.max_newton_iterations
    );
    assert!(h.stats.max_newton_iterations <= 4, "{:?}", h.stats);
    assert_eq!(h.element_names, ["geometry[1]", "geometry[2]"]);
    let g_peak = peak(&h.element_forces[0]);
    for k in 0..=n {
        let g = geometric_forces(h.element_displacements[0][k], h.element_displacements[1][k]);
        for c in 0..2 {
            let x = h.element_forces[c][k];
            assert!(
                (x - g[c]).abs() <= 1e-12 * g_peak,
                "sample {k}: {x:e} vs {:e}",
                g[c]
            );
        }
    }
}
