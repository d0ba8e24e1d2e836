//! Linear checks of the hold integrators: exactness of FOH for piecewise-linear input, and the
//! bias errors of ZOH/FOH/LSOH against their closed forms (paper III).

use faer::{Mat, c64};
use nlsim_fixtures::ecl_beam;
use nlsim_kernel::Quantity;
use nlsim_reduction::modal::{ReductionConfig, reduce};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection, Port, PortKind};
use nlsim_sim::{
    FohConfig, Hold, LoadCase, OutputSpec, Plant, Signal, Simulator, reconstruction_gain,
};
use std::f64::consts::PI;

fn beam_system(modes: usize) -> ModalSystem {
    let fx = ecl_beam();
    let cfg = ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(modes),
            ..EigenConfig::default()
        },
        ..ReductionConfig::default()
    };
    let red = reduce(&fx.model, &cfg).unwrap();
    ModalSystem::new(&red).unwrap()
}

/// The linear beam (no element) with the shaker as input and the tip displacement and
/// acceleration as outputs.
fn linear_beam_plant(modes: usize) -> Plant {
    let sys = beam_system(modes);
    let shaker = sys.port_index("shaker").unwrap();
    let tip = sys.port_index("tip").unwrap();
    Plant::new(
        sys,
        Vec::new(),
        vec![("shaker".into(), shaker)],
        vec![
            OutputSpec {
                name: "tip_d".into(),
                port: tip,
                quantity: Quantity::Displacement,
            },
            OutputSpec {
                name: "tip_v".into(),
                port: tip,
                quantity: Quantity::Velocity,
            },
        ],
    )
    .unwrap()
}

#[test]
fn foh_is_exact_for_piecewise_linear_input() {
    let plant = linear_beam_plant(10);
    let sys = &plant.system;
    let dt = 2e-4;
    let n = 3000;
    // A force made of ramps that start at sample instants: 0 → 1 N over 40 steps, down to
    // −0.5 N over 60 steps, back to 0 over 30 steps, then zero.
    let kinks = [
        (0usize, 1.0 / 40.0),
        (40, -1.5 / 60.0 - 1.0 / 40.0),
        (100, 0.5 / 30.0 + 1.5 / 60.0),
        (130, -0.5 / 30.0),
    ];
    let mut values = vec![0.0; n + 1];
    for (k, v) in values.iter_mut().enumerate() {
        *v = kinks
            .iter()
            .map(|&(j, slope)| if k > j { slope * (k - j) as f64 } else { 0.0 })
            .sum();
    }
    assert!(values[130].abs() < 1e-14 && (values[40] - 1.0).abs() < 1e-14);
    let case = LoadCase::new(
        "ramps",
        vec![Signal::Sampled {
            rate_hz: 1.0 / dt,
            values: values.clone(),
        }],
    );
    let sim = Simulator::new(&plant, &FohConfig::new(dt)).unwrap();
    let h = sim.run(&case, n).unwrap();
    // Exact: each ramp β (t − t_j)₊ (β in N per step) drives state s with
    // z_s = b̃_s β/T (e^{λτ} − 1 − λτ)/λ², τ = t − t_j.
    let shaker = plant.inputs[0].1;
    let tip = plant.outputs[0].port;
    let mut worst = 0.0f64;
    let mut peak = 0.0f64;
    for k in 0..=n {
        let t = k as f64 * dt;
        let mut y = 0.0;
        let mut v = 0.0;
        for s in 0..sys.n_states() {
            let l = sys.poles[s];
            let mut z = c64::new(0.0, 0.0);
            let mut zd = c64::new(0.0, 0.0);
            for &(j, slope) in &kinks {
                let tau = t - j as f64 * dt;
                if tau > 0.0 {
                    let e = (l * tau).exp();
                    z += sys.input[(s, shaker)] * (slope / dt) * (e - 1.0 - l * tau) / (l * l);
                    zd += sys.input[(s, shaker)] * (slope / dt) * (e - 1.0) / l;
                }
            }
            y += sys.weights[s] * (sys.output[(tip, s)] * z).re;
            v += sys.weights[s] * (sys.output[(tip, s)] * zd).re;
        }
        y += sys.feedthrough[(tip, shaker)] * values[k];
        let _ = v;
        worst = worst.max((h.outputs[0].values[k] - y).abs());
        peak = peak.max(y.abs());
    }
    assert!(peak > 1e-6, "the test drives the beam: peak {peak}");
    assert!(
        worst <= 1e-11 * peak,
        "FOH vs exact: {worst:e} of peak {peak:e}"
    );
}

/// A single mode `q̈ + 2ζω q̇ + ω² q = u` in diagonal form.
fn sdof_plant(f_hz: f64, zeta: f64) -> Plant {
    let w = 2.0 * PI * f_hz;
    let l = c64::new(-zeta * w, w * (1.0 - zeta * zeta).sqrt());
    let sys = ModalSystem {
        poles: vec![l],
        weights: vec![2.0],
        input: Mat::from_fn(1, 1, |_, _| (l - l.conj()).inv()),
        output: Mat::from_fn(1, 1, |_, _| c64::new(1.0, 0.0)),
        feedthrough: Mat::zeros(1, 1),
        accel_feedthrough: Mat::zeros(1, 1),
        ports: vec![Port::dof("x", PortKind::Dof, 0)],
        initial: Vec::new(),
        n_modes: 1,
    };
    Plant::new(
        sys,
        Vec::new(),
        vec![("x".into(), 0)],
        vec![OutputSpec {
            name: "x".into(),
            port: 0,
            quantity: Quantity::Displacement,
        }],
    )
    .unwrap()
}

/// Steady-state complex amplitude `Y` of `y[k] = Re(Y e^{iθk})` by least squares over the last
/// `m` samples.
fn fit(y: &[f64], theta: f64, m: usize) -> c64 {
    let n = y.len();
    let (mut cc, mut ss, mut cs, mut yc, mut ys) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for k in n - m..n {
        let (c, s) = ((theta * k as f64).cos(), (theta * k as f64).sin());
        cc += c * c;
        ss += s * s;
        cs += c * s;
        yc += y[k] * c;
        ys += y[k] * s;
    }
    // y ≈ a cos − b sin with Y = a + ib.
    let det = cc * ss - cs * cs;
    let a = (yc * ss - ys * cs) / det;
    let b = -(ys * cc - yc * cs) / det;
    c64::new(a, b)
}

#[test]
fn hold_bias_errors_match_the_closed_forms() {
    let (fn_hz, zeta) = (10.0, 0.05);
    let plant = sdof_plant(fn_hz, zeta);
    let wn = 2.0 * PI * fn_hz;
    let h = |w: f64| c64::new(wn * wn - w * w, 2.0 * zeta * wn * w).inv();
    let dt = 1e-3;
    for hold in [Hold::Zoh, Hold::Foh, Hold::Lsoh] {
        let mut cfg = FohConfig::new(dt);
        cfg.hold = hold;
        let sim = Simulator::new(&plant, &cfg).unwrap();
        for theta in [0.1, 0.3, 0.6, 1.0] {
            let w = theta / dt;
            let case = LoadCase::new("sine", vec![Signal::sine(1.0, w / (2.0 * PI))]);
            // 12 s: transients decay by e^{−ζ ω_n t} = e^{−37}.
            let n = 12_000;
            let run = sim.run(&case, n).unwrap();
            let y = fit(&run.outputs[0].values, theta, 2000);
            // sin = Re(−i e^{iωt}).
            let e_meas = y / (c64::new(0.0, -1.0) * h(w));
            // Oracle 1 (exact, with the images): Σ_m H(ω_m) K̂(θ + 2πm) / H(ω).
            let mut e_alias = c64::new(0.0, 0.0);
            let mut images = 0.0;
            for m in -20000i64..=20000 {
                let wm = w + 2.0 * PI * m as f64 / dt;
                let term = h(wm) * reconstruction_gain(hold, theta + 2.0 * PI * m as f64) / h(w);
                e_alias += term;
                if m != 0 {
                    images += term.norm();
                }
            }
            assert!(
                (e_meas - e_alias).norm() < 1e-7,
                "{hold} θ = {theta}: simulated {e_meas} vs aliased closed form {e_alias}"
            );
            // Oracle 2 (paper III): the reconstruction gain K̂(θ), up to the images.
            let k = reconstruction_gain(hold, theta);
            assert!(
                (e_meas - k).norm() <= images + 1e-7,
                "{hold} θ = {theta}: {e_meas} vs K̂ {k} (images {images:e})"
            );
        }
    }
    // FOH has no phase error and the amplitude error −θ²/12 + O(θ⁴); ZOH lags by θ/2; LSOH's
    // amplitude error is the smallest.
    let th = 0.3;
    let (zoh, foh, lsoh) = (
        reconstruction_gain(Hold::Zoh, th),
        reconstruction_gain(Hold::Foh, th),
        reconstruction_gain(Hold::Lsoh, th),
    );
    assert!(foh.im.abs() < 1e-15 && (foh.re - 1.0 + th * th / 12.0).abs() < th.powi(4) / 100.0);
    assert!((zoh.arg() + th / 2.0).abs() < 1e-14);
    assert!((lsoh.norm() - 1.0).abs() < (foh.norm() - 1.0).abs());
}
