//! The time histories a virtual stepped-sine test would have recorded (issue 45 part 3): the
//! structure coupled to the electrodynamic shaker of [`crate::coupling`] in the time domain,
//! driven by each step's voltage, integrated by the first-order hold (thesis §3.1) with the
//! transients between steps, and measured with seeded noise. With `nlsim harmonics` this
//! closes the chain raw records → harmonics → calibration on data whose truth is known.
//!
//! **The coupled plant** ([`shaker_plant`]). The shaker (coil current `i`, armature
//! displacement `x_a` and velocity `v_a`; without inductance the current is algebraic) obeys
//!
//! `L i̇ = V − R i − Bl v_a`, `m_a v̇_a = Bl i − k_a x_a − c_a v_a − F`, `F = k_s (x_a − x_d)`,
//!
//! the equations of [`crate::coupling`] in time. The structure's diagonal system
//! (`ż = Λz + b̃u`, `y = Σ w Re(c̃ z) + D u`, thesis eq. 10) written in real states, the
//! stinger force `F` acting at the drive port `d` with the drive's own feedthrough
//! `x_d = c_d x + D_dd F + …` solved for first, `F = κ (x_a − c_d x − D_d· u)` with
//! `κ = k_s / (1 + k_s D_dd)`, closes a linear system of the structure's and the shaker's
//! states. Its eigen decomposition `A = U S U⁻¹` gives the diagonal form the hold integrator
//! runs: poles `S`, `b̃ = U⁻¹ B`, `c̃ = C U`, one state per conjugate pair (weight 2). The
//! plant's inputs are the structure's with the drive replaced by the coil voltage (V); its
//! outputs are the structure's and, last, the stinger force `F` (N), read as the
//! "displacement" of an added port whose input is the voltage.
//!
//! **The records** ([`raw_records`]). Each step holds its voltage harmonics
//! `V(t) = V₀ + Σ_k Re(V_k e^{ikθ(t)})` for `dwell_s`, the phase `θ` running on continuously
//! from step to step (a sine generator changing its frequency), sampled at `rate_hz`; one
//! hold run over the whole record (the structure never restarts from rest), at `oversample`
//! steps per recorded sample. The hold is exact
//! for an input linear between samples, and carries a sampled sine `e^{iωt}` with the gain
//! `K̂(ωh) = sinc²(ωh/2)` (paper III; `(ωh)²/12` short at small `ωh`): the voltage it
//! integrates has each harmonic divided by that gain, so that the structure feels the
//! generator's sine (only the images at the sampling rate's multiples remain), while the
//! records hold the generator's own samples. The element forces are held linearly between
//! the hold's steps too, which carries their harmonic `k` with the same gain (`(kωh)²/12`
//! short): the oversampling keeps that below what the records resolve.

use crate::coupling::Shaker;
use crate::data::Noise;
use crate::shaker::VirtualTest;
use crate::synthetic::Gaussian;
use faer::{Mat, c64};
use nlsim_kernel::{Error, Quantity, Result, Status};
use nlsim_reduction::ModalSystem;
use nlsim_sim::{
    FohConfig, Hold, LoadCase, OutputSpec, Plant, Signal, Simulator, reconstruction_gain,
};
use std::f64::consts::PI;

/// Most samples of a raw record (every signal together: samples × signals), 2²⁷ — the
/// budget the HDF5 records reader accepts, so that what is written reads back.
pub const MAX_RAW_VALUES: usize = 1 << 27;

/// Fewest samples per period of the highest recorded harmonic at the highest step frequency.
pub const MIN_SAMPLES_PER_PERIOD: f64 = 10.0;

/// The structure's plant `plant` with the shaker `shaker` on a stinger at its input `drive`,
/// driven by the coil voltage (see the module documentation): the same inputs in the same
/// order with `drive` now taking volts, the same elements and outputs, and one output more,
/// last, the stinger force on the structure (N, listed as a displacement of the added
/// port). Errors when `drive` is not an input of `plant`, the shaker's values are invalid, or
/// the coupled system has no diagonal form.
pub fn shaker_plant(plant: &Plant, drive: &str, shaker: &Shaker) -> Result<Plant> {
    shaker.check()?;
    let input = plant.input_index(drive)?;
    let sys = &plant.system;
    let d = plant.inputs[input].1;
    let np = sys.ports.len();
    let ns = sys.n_states();

    // The structure in real states: per diagonal state one real state where its inputs are
    // real up to one phase (a real pole), else two (the real and imaginary parts).
    // Per state: the column of its real part, that of its imaginary part if kept, and the
    // rotation that makes its inputs real.
    let mut real: Vec<(usize, Option<usize>, c64)> = Vec::with_capacity(ns);
    let mut nr = 0;
    for s in 0..ns {
        let big = (0..np)
            .map(|q| sys.input[(s, q)])
            .max_by(|a, b| a.norm().total_cmp(&b.norm()))
            .unwrap_or(c64::new(0.0, 0.0));
        let scale = big.norm();
        let rot = if scale > 0.0 {
            big.conj() / scale
        } else {
            c64::new(1.0, 0.0)
        };
        let one = sys.poles[s].im == 0.0
            && (0..np).all(|q| (sys.input[(s, q)] * rot).im.abs() <= 1e-13 * scale);
        real.push((nr, (!one).then_some(nr + 1), rot));
        nr += if one { 1 } else { 2 };
    }
    let inductive = shaker.inductance > 0.0;
    let (xi, xa, va) = if inductive {
        (Some(nr), nr + 1, nr + 2)
    } else {
        (None, nr, nr + 1)
    };
    let n = va + 1;
    // Inputs: the structure's ports, then the voltage. Outputs: its ports, then the force.
    let (nq, ny) = (np + 1, np + 1);
    let mut a = Mat::<f64>::zeros(n, n);
    let mut b = Mat::<f64>::zeros(n, nq);
    let mut cs = Mat::<f64>::zeros(np, n);
    for (s, &(re, im_col, rot)) in real.iter().enumerate() {
        // z' = rot·z: ż' = λ z' + rot b u, y = Σ w Re(c/rot · z').
        let lam = sys.poles[s];
        let w = sys.weights[s];
        a[(re, re)] = lam.re;
        if let Some(im) = im_col {
            a[(re, im)] = -lam.im;
            a[(im, re)] = lam.im;
            a[(im, im)] = lam.re;
        }
        for q in 0..np {
            let bq = sys.input[(s, q)] * rot;
            b[(re, q)] = bq.re;
            if let Some(im) = im_col {
                b[(im, q)] = bq.im;
            }
        }
        for p in 0..np {
            let cp = sys.output[(p, s)] * rot.conj() * w;
            cs[(p, re)] = cp.re;
            if let Some(im) = im_col {
                cs[(p, im)] = -cp.im;
            }
        }
    }
    let dm = &sys.feedthrough;
    let kappa = shaker.stinger_stiffness / (1.0 + shaker.stinger_stiffness * dm[(d, d)]);
    if !(kappa.is_finite() && kappa > 0.0) {
        return Err(Error::invalid(
            format!("shaker on '{drive}'"),
            format!(
                "the stinger ({} N/m) against the drive's residual flexibility ({:e} m/N) \
                 leaves no positive stiffness",
                shaker.stinger_stiffness,
                dm[(d, d)]
            ),
        ));
    }
    // F = κ (x_a − c_d x − D_d· u): as a row over the states and one over the inputs.
    let mut f_state = vec![0.0; n];
    for j in 0..nr {
        f_state[j] = -kappa * cs[(d, j)];
    }
    f_state[xa] = kappa;
    let mut f_input = vec![0.0; nq];
    for q in 0..np {
        f_input[q] = -kappa * dm[(d, q)];
    }
    // The structure feels F at its drive port: ẋ += b_d F.
    for i in 0..nr {
        let bd = b[(i, d)];
        for j in 0..n {
            a[(i, j)] += bd * f_state[j];
        }
        for q in 0..nq {
            b[(i, q)] += bd * f_input[q];
        }
    }
    let ma = shaker.armature_mass;
    let bl = shaker.force_constant;
    a[(xa, va)] = 1.0;
    // m_a v̇_a = Bl i − k_a x_a − c_a v_a − F
    a[(va, xa)] -= shaker.suspension_stiffness / ma;
    a[(va, va)] -= shaker.suspension_damping / ma;
    for j in 0..n {
        a[(va, j)] -= f_state[j] / ma;
    }
    for q in 0..nq {
        b[(va, q)] -= f_input[q] / ma;
    }
    match xi {
        Some(xi) => {
            // L i̇ = V − R i − Bl v_a
            let l = shaker.inductance;
            a[(va, xi)] += bl / ma;
            a[(xi, xi)] = -shaker.resistance / l;
            a[(xi, va)] = -bl / l;
            b[(xi, np)] = 1.0 / l;
        }
        None => {
            // i = (V − Bl v_a) / R
            let r = shaker.resistance;
            a[(va, va)] -= bl * bl / (r * ma);
            b[(va, np)] = bl / (r * ma);
        }
    }
    // Outputs: y_p = c_p x + D_p· u + D_pd F; the last row F itself.
    let mut c = Mat::<f64>::zeros(ny, n);
    let mut dc = Mat::<f64>::zeros(ny, nq);
    for p in 0..np {
        for j in 0..n {
            c[(p, j)] = cs[(p, j)] + dm[(p, d)] * f_state[j];
        }
        for q in 0..np {
            dc[(p, q)] = dm[(p, q)] + dm[(p, d)] * f_input[q];
        }
    }
    for j in 0..n {
        c[(np, j)] = f_state[j];
    }
    for q in 0..np {
        dc[(np, q)] = f_input[q];
    }

    let (poles, weights, u, w) = diagonalise(&a, drive)?;
    // Sequential products: the plant is the same bits whatever the thread count.
    let product = |l: &Mat<c64>, r: &Mat<c64>| {
        let mut out = Mat::<c64>::zeros(l.nrows(), r.ncols());
        faer::linalg::matmul::matmul(
            out.as_mut(),
            faer::Accum::Replace,
            l.as_ref(),
            r.as_ref(),
            c64::new(1.0, 0.0),
            faer::Par::Seq,
        );
        out
    };
    let complex =
        |m: &Mat<f64>| Mat::from_fn(m.nrows(), m.ncols(), |i, j| c64::new(m[(i, j)], 0.0));
    let input_c = product(&w, &complex(&b));
    let output_c = product(&complex(&c), &u);
    let keep: Vec<usize> = (0..poles.len()).filter(|&j| poles[j].im >= 0.0).collect();
    let k = keep.len();
    let mut system = ModalSystem {
        poles: keep.iter().map(|&j| poles[j]).collect(),
        weights: keep.iter().map(|&j| weights[j]).collect(),
        input: Mat::from_fn(k, nq, |s, q| input_c[(keep[s], q)]),
        output: Mat::from_fn(ny, k, |p, s| output_c[(p, keep[s])]),
        feedthrough: dc,
        accel_feedthrough: Mat::zeros(ny, nq),
        ports: sys.ports.clone(),
        initial: Vec::new(),
        n_modes: sys.n_modes,
    };
    let mut port = sys.ports[d].clone();
    port.name = format!("{drive} (shaker)");
    system.ports.push(port);
    // D_a = Σ w Re(c̃ λ b̃), as the structure's Φ_P Φ_Pᵀ.
    system.accel_feedthrough = Mat::from_fn(ny, nq, |p, q| {
        (0..k)
            .map(|s| {
                system.weights[s]
                    * (system.output[(p, s)] * system.poles[s] * system.input[(s, q)]).re
            })
            .sum()
    });
    let mut inputs = plant.inputs.clone();
    inputs[input].1 = np;
    let mut outputs = plant.outputs.clone();
    outputs.push(OutputSpec {
        name: format!("{drive} stinger force"),
        port: np,
        quantity: Quantity::Displacement,
    });
    Plant::new(system, plant.elements.clone(), inputs, outputs)
}

/// The eigen decomposition of the real matrix `a`: poles, weights (2 for a pole with a
/// positive imaginary part, whose conjugate is dropped by the caller; 1 for a real one),
/// eigenvectors `U` and `U⁻¹`. Errors when the eigenvectors are too close to dependent for
/// the diagonal form to hold (a defective coupled system).
type Diagonal = (Vec<c64>, Vec<f64>, Mat<c64>, Mat<c64>);

fn diagonalise(a: &Mat<f64>, drive: &str) -> Result<Diagonal> {
    use faer::linalg::solvers::Solve;
    let n = a.nrows();
    let what = || format!("shaker on '{drive}'");
    // The structure's modal states (√kg m) and the shaker's (A, m, m/s) differ by orders of
    // magnitude: balance first (Parlett–Reinsch, powers of 2, exact), `A_b = S⁻¹ A S`.
    let scale = balance(a);
    let ab = Mat::from_fn(n, n, |i, j| a[(i, j)] * scale[j] / scale[i]);
    let evd = ab
        .eigen()
        .map_err(|e| Error::invalid(what(), format!("eigen decomposition failed: {e:?}")))?;
    let ub = evd.U();
    let u = Mat::from_fn(n, n, |i, j| ub[(i, j)] * scale[i]);
    let s = evd.S();
    let mut poles: Vec<c64> = (0..n).map(|j| s[j]).collect();
    let scale = poles.iter().map(|p| p.norm()).fold(0.0, f64::max);
    for p in &mut poles {
        // An undamped structure mode stays undamped where the shaker does not reach it;
        // rounding must not make it grow.
        if p.re > 0.0 && p.re <= 1e-12 * scale {
            p.re = 0.0;
        }
    }
    let (up, down) = (
        poles.iter().filter(|p| p.im > 0.0).count(),
        poles.iter().filter(|p| p.im < 0.0).count(),
    );
    if up != down {
        return Err(Error::invalid(
            what(),
            format!("the coupled system's poles are not in conjugate pairs ({up} against {down})"),
        ));
    }
    let w = u.partial_piv_lu().solve(Mat::<c64>::identity(n, n));
    // U⁻¹U = I to a tolerance that allows for the conditioning of the structure's modes.
    let mut err = 0.0f64;
    let prod = &w * &u;
    for i in 0..n {
        for j in 0..n {
            let target = if i == j { 1.0 } else { 0.0 };
            err = err.max((prod[(i, j)] - c64::new(target, 0.0)).norm());
        }
    }
    if !err.is_finite() || err > 1e-6 {
        return Err(Error::invalid(
            what(),
            format!(
                "the coupled structure and shaker have no diagonal form (eigenvectors \
                 dependent to {err:.1e}); change the shaker's values slightly"
            ),
        ));
    }
    let weights = poles
        .iter()
        .map(|p| if p.im > 0.0 { 2.0 } else { 1.0 })
        .collect();
    Ok((poles, weights, u, w))
}

/// Diagonal scaling `s` (powers of 2) that makes the off-diagonal row and column norms of
/// `S⁻¹ A S` about equal.
fn balance(a: &Mat<f64>) -> Vec<f64> {
    let n = a.nrows();
    let mut s = vec![1.0f64; n];
    for _ in 0..100 {
        let mut done = true;
        for i in 0..n {
            let (mut c, mut r) = (0.0f64, 0.0f64);
            for j in 0..n {
                if j != i {
                    c += (a[(j, i)] * s[i] / s[j]).abs();
                    r += (a[(i, j)] * s[j] / s[i]).abs();
                }
            }
            if c == 0.0 || r == 0.0 {
                continue;
            }
            let mut f = 1.0f64;
            let total = c + r;
            let (mut c2, mut r2) = (c, r);
            while c2 < r2 / 2.0 {
                c2 *= 2.0;
                r2 /= 2.0;
                f *= 2.0;
            }
            while c2 >= r2 * 2.0 {
                c2 /= 2.0;
                r2 *= 2.0;
                f /= 2.0;
            }
            if c2 + r2 < 0.95 * total {
                s[i] *= f;
                done = false;
            }
        }
        if done {
            break;
        }
    }
    s
}

/// How the raw records are sampled.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RawConfig {
    /// Sampling rate (Hz).
    pub rate_hz: f64,
    /// Length of every step (s), its transient included.
    pub dwell_s: f64,
    /// The start of every step left out of its measured window (s): the settling a stepped-
    /// sine controller waits before it measures. At most the dwell less 4 periods.
    pub settle_s: f64,
    /// Hold steps per recorded sample (at least 1): the integration runs at `oversample ×
    /// rate_hz` and the records keep every `oversample`-th sample, as a recorder samples the
    /// continuous motion.
    pub oversample: usize,
}

/// One step of a raw record: samples `start..end` at `frequency_hz`, measured from
/// `measured` on (after the settling).
#[derive(Debug, Clone, PartialEq)]
pub struct RawStep {
    /// Label of its sweep.
    pub sweep: String,
    /// Excitation frequency (Hz).
    pub frequency_hz: f64,
    /// First sample.
    pub start: usize,
    /// First sample of the measured window.
    pub measured: usize,
    /// One past the last sample.
    pub end: usize,
}

/// The time histories of a virtual test, sampled evenly from `t = 0`.
#[derive(Debug, Clone, PartialEq)]
pub struct RawRecord {
    /// Sampling rate (Hz).
    pub rate_hz: f64,
    /// The coil voltage (V).
    pub voltage: Vec<f64>,
    /// The stinger force on the structure (N), as a force gauge there measures it.
    pub force: Vec<f64>,
    /// Every sensor: name, quantity, samples (m, m/s or m/s²).
    pub responses: Vec<(String, Quantity, Vec<f64>)>,
    /// The steps, in time order.
    pub steps: Vec<RawStep>,
    /// [`Status::Converged`], or why the integration stopped short (the record then ends
    /// there, its steps cut to it).
    pub status: Status,
    /// What stopped it, when it stopped short.
    pub stopped: Option<String>,
}

/// The steps of `test` whose voltage is known, in test order: (sweep label, frequency Hz,
/// voltage harmonics `0..=H`).
fn voltage_steps(test: &VirtualTest) -> Vec<(String, f64, Vec<c64>)> {
    // The data's sweeps carry the labels; a sweep the structure could not be solved on at
    // any step has no data sweep and is passed over with its records.
    let mut labels = test.data.sweeps.iter().map(|s| s.label.clone());
    let mut out = Vec::new();
    for rec in &test.steps {
        let solved = rec.iter().any(|s| s.force[1].re.is_finite());
        if !solved {
            continue;
        }
        let label = labels.next().unwrap_or_default();
        for st in rec {
            // As in the data: a step whose structure was not solved is left out.
            let known = st
                .voltage
                .iter()
                .all(|v| v.re.is_finite() && v.im.is_finite());
            if known && st.force[1].re.is_finite() {
                out.push((label.clone(), st.frequency_hz, st.voltage.clone()));
            }
        }
    }
    out
}

/// The settling time (s) of `plant` around `band_hz`: `ln(1/to)` over the slowest decay rate
/// `|Re λ|` of its poles within half the band's lower end and twice its upper one (the modes
/// a step change of the drive there sets ringing), or 0 when none lies there.
pub fn settle_time(plant: &Plant, band_hz: (f64, f64), to: f64) -> f64 {
    let slowest = plant
        .system
        .poles
        .iter()
        .filter(|p| {
            let f = p.im / (2.0 * PI);
            f >= 0.5 * band_hz.0 && f <= 2.0 * band_hz.1 && p.re < 0.0
        })
        .map(|p| -p.re)
        .fold(f64::INFINITY, f64::min);
    if slowest.is_finite() {
        (1.0 / to).ln() / slowest
    } else {
        0.0
    }
}

/// The time histories of `test` replayed through `coupled` ([`shaker_plant`] of the plant the
/// test ran on, the voltage at input `voltage_input`): every step whose voltage is known held
/// for `cfg.dwell_s` at `cfg.rate_hz`, one first-order-hold run from rest over them all,
/// noise-free ([`add_raw_noise`] adds it). `progress(done, total)` about 200 times. Errors
/// for a rate or dwell out of range (named), a record of more than [`MAX_RAW_VALUES`] values,
/// or a test with no step.
pub fn raw_records(
    coupled: &Plant,
    voltage_input: usize,
    test: &VirtualTest,
    cfg: &RawConfig,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RawRecord> {
    let steps = voltage_steps(test);
    if steps.is_empty() {
        return Err(Error::invalid(
            "raw records",
            "the test has no step with a known voltage",
        ));
    }
    let h = test.data.harmonics;
    let f_hi = steps.iter().map(|s| s.1).fold(0.0, f64::max);
    let f_lo = steps.iter().map(|s| s.1).fold(f64::INFINITY, f64::min);
    if !(cfg.rate_hz.is_finite() && cfg.rate_hz >= MIN_SAMPLES_PER_PERIOD * h as f64 * f_hi) {
        return Err(Error::invalid(
            "raw rate",
            format!(
                "{} Hz: at least {MIN_SAMPLES_PER_PERIOD} samples per period of harmonic {h} \
                 at {f_hi} Hz ({:.6e} Hz)",
                cfg.rate_hz,
                MIN_SAMPLES_PER_PERIOD * h as f64 * f_hi
            ),
        ));
    }
    if !(cfg.settle_s.is_finite() && cfg.settle_s >= 0.0) {
        return Err(Error::invalid(
            "raw settle",
            format!("{} s must be zero or positive", cfg.settle_s),
        ));
    }
    if !(cfg.dwell_s.is_finite() && cfg.dwell_s * f_lo >= 4.0) {
        return Err(Error::invalid(
            "raw dwell",
            format!(
                "{} s holds fewer than 4 periods at {f_lo} Hz (at least {:.6e} s)",
                cfg.dwell_s,
                4.0 / f_lo
            ),
        ));
    }
    let m = cfg.oversample;
    if !(1..=1024).contains(&m) {
        return Err(Error::invalid(
            "raw oversample",
            format!("{m} hold steps per sample: give 1 to 1024"),
        ));
    }
    let per_step = (cfg.dwell_s * cfg.rate_hz).round();
    // The hold run keeps every output, element displacement, velocity and force and input
    // at each of its steps.
    let signals = coupled.outputs.len() + 3 * coupled.elements.len() + coupled.inputs.len();
    let total = per_step * steps.len() as f64;
    if total * (m * signals.max(1)) as f64 > MAX_RAW_VALUES as f64 {
        return Err(Error::invalid(
            "raw records",
            format!(
                "{} steps of {per_step} samples, {m} hold steps each, × {signals} signals \
                 exceed {MAX_RAW_VALUES} values; lower the rate, the dwell or the oversampling, \
                 or record fewer steps",
                steps.len()
            ),
        ));
    }
    let per_step = per_step as usize;
    let n = per_step * steps.len();
    let dt = 1.0 / cfg.rate_hz;
    let h = dt / m as f64;
    let mut voltage = Vec::with_capacity(n);
    // What the hold integrates: each harmonic over the hold's reconstruction gain at it, so
    // that the linear interpolant between samples carries the generator's harmonics exactly.
    let mut held = Vec::with_capacity(n);
    let mut raw_steps = Vec::with_capacity(steps.len());
    let mut theta = 0.0f64;
    for (label, f, v) in &steps {
        let start = voltage.len();
        let w = 2.0 * PI * f;
        let gains: Vec<c64> = (0..v.len())
            .map(|k| reconstruction_gain(Hold::Foh, k as f64 * w * h))
            .collect();
        for i in 0..per_step * m {
            let th = theta + w * i as f64 * h;
            let (mut x, mut y) = (v[0].re, v[0].re);
            for (k, vk) in v.iter().enumerate().skip(1) {
                let e = vk * c64::cis(k as f64 * th);
                x += e.re;
                y += (e / gains[k]).re;
            }
            if i % m == 0 {
                voltage.push(x);
            }
            held.push(y);
        }
        theta = (theta + w * per_step as f64 * dt).rem_euclid(2.0 * PI);
        // At least 4 periods measured.
        let settle = cfg.settle_s.min(cfg.dwell_s - 4.0 / f).max(0.0);
        let measured = start + ((settle * cfg.rate_hz).round() as usize).min(per_step - 1);
        raw_steps.push(RawStep {
            sweep: label.clone(),
            frequency_hz: *f,
            start,
            measured,
            end: voltage.len(),
        });
    }
    let mut forces = vec![Signal::Zero; coupled.inputs.len()];
    forces[voltage_input] = Signal::Sampled {
        rate_hz: cfg.rate_hz * m as f64,
        values: held,
    };
    let sim = Simulator::new(coupled, &FohConfig::new(h))?;
    let hist = sim.run_with_progress(&LoadCase::new("raw", forces), n * m - 1, progress)?;
    // The recorder's samples: every m-th of the run's (a run stopped short keeps those it
    // reached).
    let kept = hist.n_samples().div_ceil(m);
    let mut outputs: Vec<(String, Quantity, Vec<f64>)> = hist
        .outputs
        .into_iter()
        .map(|s| {
            (
                s.name,
                s.quantity,
                s.values.into_iter().step_by(m).collect(),
            )
        })
        .collect();
    // The clearance's (any kinked law's) `D g̈` from the recorder's own samples.
    let element_forces: Vec<Vec<f64>> = hist
        .element_forces
        .iter()
        .map(|g| g.iter().copied().step_by(m).collect())
        .collect();
    {
        let mut outs: Vec<&mut [f64]> = outputs.iter_mut().map(|o| o.2.as_mut_slice()).collect();
        nlsim_sim::add_kinked_residual_accelerations(coupled, &element_forces, dt, &mut outs);
    }
    let force = outputs.pop().map(|s| s.2).unwrap_or_default();
    voltage.truncate(kept);
    for s in &mut raw_steps {
        s.end = s.end.min(kept);
    }
    raw_steps.retain(|s| s.end > s.measured);
    Ok(RawRecord {
        rate_hz: cfg.rate_hz,
        voltage,
        force,
        responses: outputs,
        steps: raw_steps,
        status: hist.status,
        stopped: hist.stopped.map(|e| e.to_string()),
    })
}

/// Root mean square of `x`.
fn rms(x: &[f64]) -> f64 {
    (x.iter().map(|v| v * v).sum::<f64>() / x.len().max(1) as f64).sqrt()
}

/// Adds measurement noise to `record`: per sample a normal draw of standard deviation
/// `relative × rms` of the channel over the record, or `absolute` (the channel's unit),
/// whichever is larger — `response` for every sensor, `force` for the force gauge; the
/// voltage (the generator's own signal) is exact. Seeded by `seed`: the sensors in order,
/// then the force, sample by sample. Returns each channel's standard deviation, the force's
/// last.
pub fn add_raw_noise(record: &mut RawRecord, response: Noise, force: Noise, seed: u64) -> Vec<f64> {
    let mut g = Gaussian::new(seed);
    let mut sigmas = Vec::with_capacity(record.responses.len() + 1);
    let mut add = |x: &mut [f64], n: Noise| {
        let sigma = (n.relative * rms(x)).max(n.absolute);
        if sigma > 0.0 {
            for v in x.iter_mut() {
                *v += sigma * g.sample();
            }
        }
        sigmas.push(sigma);
    };
    for (_, _, x) in &mut record.responses {
        add(x, response);
    }
    add(&mut record.force, force);
    sigmas
}
