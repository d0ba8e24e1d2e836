//! Nonlinear modes by the extended periodic motion concept (EPMC, Krack 2015): the
//! periodic free motions of the structure with an artificial mass-proportional damping
//! `−ξ M` that cancels the dissipation over a period, followed in amplitude. Undamped
//! conservative structures give `ξ = 0` and their backbone; dissipative ones an
//! amplitude-dependent frequency `ω(a)` and modal damping ratio `ζ(a) = ξ / 2ω`.
//!
//! On the modal harmonics `η` of the reduced model (the full formulation of
//! [`HbSystem::modal_residual`], no forcing), the unknowns `(η, ω, ξ)` solve
//!
//! `[Z(kω) − i kω ξ I] η_k + Φᵀ G_k(Φ η) = 0` for every harmonic `k`,
//! `c₁(η_N) = a`, `s₁(η_N) = 0`,
//!
//! the last two fixing the amplitude `a` (m √kg, the fundamental's cosine coefficient of the
//! mass-normalised coordinate of mode `N`) and the phase. Newton from the previous amplitude
//! (from the linear mode at the first), the amplitude step halved when it fails.

use crate::dense::{Lu, norm_inf};
use crate::system::{HbSystem, expand};
use crate::{HarmonicSet, HbConfig};
use faer::{Mat, c64};
use nlsim_kernel::{Error, Excitation, Model, Quantity, Result, Site, Status};
use nlsim_reduction::ReducedModel;

/// Most amplitudes of one nonlinear mode: a backbone needs tens to hundreds; 10⁴ is about a
/// minute and a half on the ECL beam (7 ms a point), where 10⁵ would be a quarter of an hour.
pub const MAX_NNM_POINTS: usize = 10_000;

/// Most unknowns `modes · (2H + 1)` of the modal harmonic balance behind a nonlinear mode:
/// its Newton matrix is dense, and a handful of them are alive at once (4 000 unknowns:
/// 128 MB each, a 2·10¹⁰-flop factorisation per iteration).
pub const MAX_NNM_UNKNOWNS: usize = 4_000;

/// `points` modal amplitudes from `from` to `to` (m √kg), evenly spaced in their logarithm:
/// the amplitudes a nonlinear mode is followed at (`points ≥ 2`).
pub fn log_amplitudes(from: f64, to: f64, points: usize) -> Vec<f64> {
    let (a, b) = (from.ln(), to.ln());
    let last = points.saturating_sub(1).max(1) as f64;
    (0..points)
        .map(|i| (a + (b - a) * i as f64 / last).exp())
        .collect()
}

/// A point of a nonlinear mode.
#[derive(Debug, Clone)]
pub struct NnmPoint {
    /// Modal amplitude `a` of the mode followed (the cosine coefficient of its
    /// mass-normalised coordinate at the fundamental; m √kg).
    pub amplitude: f64,
    /// Frequency `ω` of the periodic motion (rad/s).
    pub omega: f64,
    /// The artificial damping `ξ` (1/s) that makes the motion periodic.
    pub xi: f64,
    /// Modal harmonics `η` (modes × (2H+1), real layout of [`crate::HarmonicSet`]).
    pub eta: Vec<f64>,
    /// Newton iterations it took.
    pub iterations: usize,
}

impl NnmPoint {
    /// The modal damping ratio `ζ = ξ / 2ω` (1).
    pub fn damping_ratio(&self) -> f64 {
        self.xi / (2.0 * self.omega)
    }
}

/// The outcome of [`nonlinear_mode`]: the points computed, in amplitude order, and how the
/// run ended.
#[derive(Debug, Clone)]
pub struct NnmReport {
    /// [`Status::Converged`] when every amplitude was reached, otherwise why it stopped
    /// (the points before are kept).
    pub status: Status,
    /// The points.
    pub points: Vec<NnmPoint>,
    /// Where and why it stopped short; empty when converged.
    pub detail: String,
}

/// Halvings of an amplitude step before the run stops.
pub const MAX_HALVINGS: usize = 12;

/// EPMC residual and Jacobian in `(η, ω, ξ)`, with the two normalisation rows of mode `n`.
fn augmented(sys: &HbSystem, n: usize, a: f64, u: &[f64]) -> (Vec<f64>, Mat<f64>) {
    let set = *sys.harmonics();
    let nh = set.len();
    let nu = u.len() - 2;
    let (eta, omega, xi) = (&u[..nu], u[nu], u[nu + 1]);
    let residual = |eta: &[f64], omega: f64, xi: f64| -> (Vec<f64>, Mat<f64>) {
        let (mut r, mut j) = sys.modal_residual(eta, omega, 0.0);
        // − i kω ξ on every mode and harmonic, in the real layout of `expand`.
        let m = nu / nh;
        let d: Vec<Mat<c64>> = (0..=set.h)
            .map(|k| {
                Mat::from_fn(m, m, |p, q| {
                    if p == q {
                        c64::new(0.0, -(k as f64) * set.base(omega) * xi)
                    } else {
                        c64::new(0.0, 0.0)
                    }
                })
            })
            .collect();
        let dx = expand(&set, &d);
        for i in 0..nu {
            r[i] += (0..nu).map(|c| dx[(i, c)] * eta[c]).sum::<f64>();
            for c in 0..nu {
                j[(i, c)] += dx[(i, c)];
            }
        }
        (r, j)
    };
    let (r, j) = residual(eta, omega, xi);
    let h = 1e-7 * omega.abs().max(1e-300);
    let (rp, _) = residual(eta, omega + h, xi);
    let (rm, _) = residual(eta, omega - h, xi);
    // R is linear in ξ: its derivative is exact from two evaluations.
    let (r1, _) = residual(eta, omega, xi + 1.0);
    let mut f = r;
    f.push(eta[n * nh + 1] - a);
    f.push(eta[n * nh + 2]);
    let mut jac = Mat::<f64>::zeros(nu + 2, nu + 2);
    for i in 0..nu {
        for c in 0..nu {
            jac[(i, c)] = j[(i, c)];
        }
        jac[(i, nu)] = (rp[i] - rm[i]) / (2.0 * h);
        jac[(i, nu + 1)] = r1[i] - f[i];
    }
    jac[(nu, n * nh + 1)] = 1.0;
    jac[(nu + 1, n * nh + 2)] = 1.0;
    (f, jac)
}

/// Newton on the EPMC system at amplitude `a` from `u0`.
fn solve_at(sys: &HbSystem, n: usize, a: f64, u0: &[f64]) -> (Vec<f64>, Status, usize) {
    let mut u = u0.to_vec();
    for it in 0..sys.config().max_iterations {
        let (f, jac) = augmented(sys, n, a, &u);
        if f.iter().any(|v| !v.is_finite()) {
            return (u, Status::NonFinite, it);
        }
        let Ok(lu) = Lu::new(&jac, &String::new) else {
            return (u, Status::Singular, it);
        };
        let neg: Vec<f64> = f.iter().map(|v| -v).collect();
        let d = lu.solve(&neg);
        u.iter_mut().zip(&d).for_each(|(x, y)| *x += y);
        let nu = u.len() - 2;
        let scale_eta = norm_inf(&u[..nu]).max(1e-300);
        let ok = norm_inf(&d[..nu]) <= sys.config().rtol * scale_eta
            && d[nu].abs() <= sys.config().rtol * u[nu].abs()
            && d[nu + 1].abs() <= sys.config().rtol * u[nu].abs();
        if ok {
            return (u, Status::Converged, it + 1);
        }
    }
    (u, Status::IterationLimit, sys.config().max_iterations)
}

/// Follows the nonlinear mode `mode` (0-based, of the reduced model) through the modal
/// amplitudes `amplitudes` (m √kg, increasing or decreasing, positive), calling `progress`
/// after every point. The first point starts from the linear mode (`ω_N`, `ξ = C̃_NN`, the
/// mode's own damping); each next from the last, scaled to the new amplitude. A failed
/// point is retried from halfway, down to [`MAX_HALVINGS`] halvings; then the run stops
/// with the points computed and a status. `Err` only for invalid input: the system must
/// have `ν = 1`, the mode must exist, the amplitudes be finite and positive.
pub fn nonlinear_mode(
    sys: &HbSystem,
    mode: usize,
    amplitudes: &[f64],
    progress: &mut dyn FnMut(&NnmPoint),
) -> Result<NnmReport> {
    let set = *sys.harmonics();
    if set.nu != 1 {
        return Err(Error::invalid(
            "nonlinear mode",
            format!("needs harmonics of Ω itself (ν = 1), not of Ω/{}", set.nu),
        ));
    }
    let lin = sys.linear();
    let m = lin.n_modes();
    if mode >= m {
        return Err(Error::invalid(
            "nonlinear mode",
            format!("mode {} does not exist ({m} retained modes)", mode + 1),
        ));
    }
    if let Some(a) = amplitudes.iter().find(|a| !(a.is_finite() && **a > 0.0)) {
        return Err(Error::invalid(
            "nonlinear mode",
            format!("amplitude {a} must be a positive number"),
        ));
    }
    let nh = set.len();
    let nu = m * nh;
    let w = lin.eigenvalues()[mode].sqrt();
    let mut u = vec![0.0; nu + 2];
    u[nu] = w;
    u[nu + 1] = lin.damping()[(mode, mode)];
    let mut points: Vec<NnmPoint> = Vec::new();
    let mut last_a: Option<f64> = None;
    for &target in amplitudes {
        let mut a = target;
        let mut halvings = 0;
        loop {
            let mut guess = u.clone();
            match last_a {
                Some(prev) => guess[..nu].iter_mut().for_each(|v| *v *= a / prev),
                None => guess[mode * nh + 1] = a,
            }
            let (sol, status, iterations) = solve_at(sys, mode, a, &guess);
            if status.is_converged() {
                u = sol;
                last_a = Some(a);
                let p = NnmPoint {
                    amplitude: a,
                    omega: u[nu],
                    xi: u[nu + 1],
                    eta: u[..nu].to_vec(),
                    iterations,
                };
                progress(&p);
                points.push(p);
                if a == target {
                    break;
                }
                a = target;
                continue;
            }
            halvings += 1;
            let from = last_a.unwrap_or(0.0);
            if halvings > MAX_HALVINGS || last_a.is_none() && halvings > 1 {
                return Ok(NnmReport {
                    status,
                    points,
                    detail: format!(
                        "nonlinear mode {}: Newton failed ({}) at amplitude {a:.4e} after {} \
                         step halvings from {from:.4e}",
                        mode + 1,
                        status.as_str(),
                        halvings - 1
                    ),
                });
            }
            a = if last_a.is_some() {
                from + 0.5 * (a - from)
            } else {
                a
            };
        }
    }
    Ok(NnmReport {
        status: Status::Converged,
        points,
        detail: String::new(),
    })
}

/// The model a nonlinear mode of `model` is computed on: `model` itself when it has an
/// excitation point, otherwise with an unused input of zero amplitude at its first
/// element's first DOF (the harmonic-balance system needs one; the free motion uses none of
/// it). Refused when `model` has no nonlinear element.
pub fn free_model(model: &Model) -> Result<Model> {
    let Some(first) = model.elements().first() else {
        return Err(Error::invalid(
            format!("model '{}'", model.name()),
            "has no nonlinear element: its modes are linear",
        ));
    };
    let mut free = model.clone();
    if free.excitation().is_empty() {
        let dof = first.coupling().dofs()[0];
        free.add_excitation(Excitation {
            name: "unused".into(),
            at: Site::Dof(dof),
            amplitude: 0.0,
            harmonics: Vec::new(),
        })?;
    }
    Ok(free)
}

/// The harmonic-balance system of the free motions of `free` ([`free_model`]) on its
/// reduction `reduced` (made without residual flexibility), `set` harmonics.
///
/// Within a cluster of equal frequencies (the two bending directions of a symmetric
/// section) any basis is a basis of modes; the free motion needs the one where the
/// cluster's members beyond the rank of its participation at the elements do not move
/// them: those are then linear modes the EPMC leaves at rest instead of a singular
/// direction of its Newton matrix. The clusters are rotated so before the system is built.
pub fn free_motion_system(
    free: &Model,
    reduced: &ReducedModel,
    set: HarmonicSet,
) -> Result<HbSystem> {
    let aligned = aligned_reduction(free, reduced)?;
    HbSystem::from_model(free, &aligned, set, HbConfig::default())
}

/// The reduction [`free_motion_system`] builds its system on: `reduced` with each cluster
/// of equal frequencies rotated so that its members beyond the rank of their participation
/// at the elements of `free` do not move them. A time simulation that starts from a
/// nonlinear mode's state (modal coordinates of the system) must use this basis.
pub fn aligned_reduction(free: &Model, reduced: &ReducedModel) -> Result<ReducedModel> {
    let mut aligned = reduced.clone();
    let element_ports: Vec<usize> = nlsim_reduction::model_port_map(free, &reduced.ports)?
        .element_coordinates
        .into_iter()
        .flatten()
        .collect();
    align_clusters(&mut aligned, &element_ports);
    Ok(aligned)
}

/// Rotates each cluster of equal eigenvalues (to 1e-8) of `reduced` by the orthogonal `Q`
/// of the QR factorisation of its participation at `element_ports` (transposed), so that the
/// cluster's last columns do not move the elements; vectors and participation alike (the
/// modal damping of a cluster is a multiple of the identity for Rayleigh and modal damping).
fn align_clusters(reduced: &mut ReducedModel, element_ports: &[usize]) {
    let lambda = reduced.modes.eigenvalues.clone();
    let top = lambda
        .iter()
        .fold(0.0f64, |a, l| a.max(l.abs()))
        .max(1e-300);
    let m = lambda.len();
    let mut i = 0;
    while i < m {
        let mut j = i + 1;
        while j < m && (lambda[j] - lambda[i]).abs() <= 1e-8 * top {
            j += 1;
        }
        let c = j - i;
        if c >= 2 && !element_ports.is_empty() {
            let pt = Mat::from_fn(c, element_ports.len(), |r, e| {
                reduced.participation[(element_ports[e], i + r)]
            });
            let q = pt.qr().compute_Q();
            let rotate = |a: &mut Mat<f64>| {
                let block = Mat::from_fn(a.nrows(), c, |r, k| a[(r, i + k)]);
                let rot = &block * &q;
                for r in 0..a.nrows() {
                    for k in 0..c {
                        a[(r, i + k)] = rot[(r, k)];
                    }
                }
            };
            rotate(&mut reduced.participation);
            rotate(&mut reduced.modes.vectors);
        }
        i = j;
    }
}

/// Sensor harmonics of point `p` of a nonlinear mode of `sys` (sensors × `H + 1`, complex, in
/// each sensor's quantity: m, m/s or m/s²): `Y_k = Φ_s (c_k − i s_k)` times `(ikω)^d` for
/// velocity (`d = 1`) and acceleration (`d = 2`), in the cosine convention of eq. 13.
pub fn sensor_harmonics(sys: &HbSystem, p: &NnmPoint) -> Mat<c64> {
    let set = *sys.harmonics();
    let nh = set.len();
    let phi = sys.linear().participation();
    let m = sys.linear().n_modes();
    Mat::from_fn(sys.sensors().len(), set.h + 1, |s, k| {
        let port = sys.sensors()[s].port;
        let q: c64 = (0..m)
            .map(|r| {
                let z = if k == 0 {
                    c64::new(p.eta[r * nh], 0.0)
                } else {
                    c64::new(p.eta[r * nh + 2 * k - 1], -p.eta[r * nh + 2 * k])
                };
                z * phi[(port, r)]
            })
            .sum();
        let iw = c64::new(0.0, k as f64 * p.omega);
        match sys.sensors()[s].quantity {
            Quantity::Displacement => q,
            Quantity::Velocity => iw * q,
            Quantity::Acceleration => iw * iw * q,
        }
    })
}
