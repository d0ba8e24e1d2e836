//! The coupling of a structure to an electrodynamic shaker on a stinger, driven by voltage
//! (thesis §4.4, Fig. 11; paper V): what the virtual test ([`crate::shaker`]) runs and what
//! the calibration objective drives a voltage record through.
//!
//! The shaker (armature mass `m_a`, suspension `k_a`, `c_a`, coil resistance `R` and
//! inductance `L`, force constant `Bl`, stinger stiffness `k_s`) is linear; per harmonic
//! `s = ikΩ` its equations
//!
//! `L s I + R I + Bl s X_a = V`, `(m_a s² + c_a s + k_a) X_a = Bl I − k_s (X_a − X_d)`
//!
//! leave the stinger force on the structure as `F = G(s) V − Z(s) X_d`, with
//! `D = m_a s² + c_a s + k_a + k_s + Bl² s/(L s + R)`, `G = k_s Bl/((L s + R) D)` and
//! `Z = k_s − k_s²/D`: the shaker's drive-point impedance. `F` and the nonlinear structure's
//! drive displacement `X_d(F)` are solved together: by Newton on the force harmonics, with
//! `∂X_d/∂F` from [`HbSystem::input_response_jacobian`], and where the force-driven
//! structure folds by Newton on the structure's unknowns and the force at once
//! ([`HbSystem::input_coupling`]). Near a resonance the structure moves freely, the back-EMF
//! and the armature's inertia take the force away — the force drop-out a voltage-driven test
//! shows — and the nonlinearity's harmonics in `X_d` come back as force harmonics.

use crate::step::solve_step;
use faer::{Mat, c64};
use nlsim_hb::{ForceTerm, Forcing, HbSystem, HbWorkspace};
use nlsim_kernel::{Error, Result, Status};

/// An electrodynamic shaker on a stinger (SI units).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Shaker {
    /// Armature (moving coil and table) mass `m_a` (kg).
    pub armature_mass: f64,
    /// Suspension (flexure) stiffness `k_a` (N/m).
    pub suspension_stiffness: f64,
    /// Suspension damping `c_a` (N s/m).
    pub suspension_damping: f64,
    /// Coil resistance `R` (Ω), amplifier output included.
    pub resistance: f64,
    /// Coil inductance `L` (H).
    pub inductance: f64,
    /// Force constant `Bl` (N/A = V s/m).
    pub force_constant: f64,
    /// Axial stiffness of the stinger `k_s` (N/m).
    pub stinger_stiffness: f64,
}

impl Default for Shaker {
    /// A small modal shaker (values chosen by nlsim, of the order of catalogue data for a
    /// 100 N shaker): `m_a` 0.03 kg, `k_a` 3 kN/m, `c_a` 2 N s/m, `R` 1.5 Ω, `L` 0.2 mH,
    /// `Bl` 4 N/A, stinger 200 kN/m.
    fn default() -> Self {
        Self {
            armature_mass: 0.03,
            suspension_stiffness: 3e3,
            suspension_damping: 2.0,
            resistance: 1.5,
            inductance: 2e-4,
            force_constant: 4.0,
            stinger_stiffness: 2e5,
        }
    }
}

/// Smallest non-zero value of a shaker field (SI units).
pub const SHAKER_MIN: f64 = 1e-12;
/// Largest value of a shaker field (SI units).
pub const SHAKER_MAX: f64 = 1e12;

impl Shaker {
    /// Checks that every value is finite, 0 or within [`SHAKER_MIN`]..[`SHAKER_MAX`], masses, resistance, force constant and stinger
    /// stiffness positive, the others non-negative.
    pub fn check(&self) -> Result<()> {
        let fields = [
            ("armature_mass", self.armature_mass, true),
            ("suspension_stiffness", self.suspension_stiffness, false),
            ("suspension_damping", self.suspension_damping, false),
            ("resistance", self.resistance, true),
            ("inductance", self.inductance, false),
            ("force_constant", self.force_constant, true),
            ("stinger_stiffness", self.stinger_stiffness, true),
        ];
        for (name, v, positive) in fields {
            // Beyond these the coupling's products (`Bl²`, `k_s²`, `s² m`) over- or
            // underflow at structural frequencies: no shaker is built that way.
            if v != 0.0 && !(SHAKER_MIN..=SHAKER_MAX).contains(&v) {
                return Err(Error::InvalidParameter {
                    name: format!("shaker.{name}"),
                    value: v,
                    reason: format!(
                        "must be 0 or within {SHAKER_MIN:e}..{SHAKER_MAX:e} (SI units)"
                    ),
                });
            }
            if !v.is_finite() || v < 0.0 || (positive && v == 0.0) {
                return Err(Error::InvalidParameter {
                    name: format!("shaker.{name}"),
                    value: v,
                    reason: if positive {
                        "must be positive and finite".into()
                    } else {
                        "must be non-negative and finite".into()
                    },
                });
            }
        }
        Ok(())
    }

    /// `(G, Z)` at angular frequency `w` (rad/s): the stinger force is `F = G V − Z X_d`
    /// (`G` in N/V, `Z` in N/m).
    pub fn coupling(&self, w: f64) -> (c64, c64) {
        let s = c64::new(0.0, w);
        let e = s * self.inductance + self.resistance;
        let bl = self.force_constant;
        let d = s * s * self.armature_mass
            + s * self.suspension_damping
            + self.suspension_stiffness
            + self.stinger_stiffness
            + s * (bl * bl) / e;
        let ks = self.stinger_stiffness;
        (
            c64::new(ks * bl, 0.0) / (e * d),
            c64::new(ks, 0.0) - (ks * ks) / d,
        )
    }
}
/// The structure's unknowns, the coupling residual `Q` and its Jacobian at one force.
type Residual = (Vec<f64>, Vec<f64>, Mat<f64>);

/// The coupled structure–shaker solution at one frequency for one voltage.
pub(crate) struct Coupled {
    /// The structure's harmonic balance unknowns.
    pub x: Vec<f64>,
    /// Real force coefficients (2H+1).
    pub phi: Vec<f64>,
    /// `∂φ/∂v` (real layout, (2H+1) × (2H+1)).
    pub dphi_dv: Mat<f64>,
    /// The coupling residual's Jacobian `I + Z ∂X_d/∂φ` at the solution (real layout).
    pub jq: Mat<f64>,
}

/// The voltage-driven shaker on `sys` at input `input`.
pub(crate) struct Rig<'a> {
    pub sys: &'a mut HbSystem,
    pub ws: &'a mut HbWorkspace,
    pub shaker: &'a Shaker,
    pub input: usize,
}

pub(crate) fn real_of(set: &nlsim_hb::HarmonicSet, z: &[c64]) -> Vec<f64> {
    let mut v = vec![0.0; set.len()];
    for (k, z) in z.iter().enumerate() {
        set.set_complex(&mut v, k, *z);
    }
    v
}

pub(crate) fn complex_of(set: &nlsim_hb::HarmonicSet, v: &[f64]) -> Vec<c64> {
    (0..=set.h).map(|k| set.complex(v, k)).collect()
}

/// Real-layout matrix of multiplying harmonic `k` by `z[k]`.
pub(crate) fn block_diag(set: &nlsim_hb::HarmonicSet, z: &[c64]) -> Mat<f64> {
    let nh = set.len();
    let mut a = Mat::<f64>::zeros(nh, nh);
    a[(0, 0)] = z[0].re;
    for k in 1..=set.h {
        let (r, c) = (2 * k - 1, 2 * k - 1);
        a[(r, c)] = z[k].re;
        a[(r, c + 1)] = z[k].im;
        a[(r + 1, c)] = -z[k].im;
        a[(r + 1, c + 1)] = z[k].re;
    }
    a
}

/// Solves `a y = b` for a small dense square `a`; `None` when singular.
pub(crate) fn solve_dense(a: &Mat<f64>, b: &[f64]) -> Option<Vec<f64>> {
    let x = solve_dense_many(a, Mat::from_fn(b.len(), 1, |i, _| b[i]))?;
    Some((0..b.len()).map(|i| x[(i, 0)]).collect())
}

/// Solves `a Y = B` for a small dense square `a` and the columns of `b` (one LU
/// factorisation); `None` when singular.
pub(crate) fn solve_dense_many(a: &Mat<f64>, b: Mat<f64>) -> Option<Mat<f64>> {
    use faer::linalg::solvers::Solve;
    let lu = a.partial_piv_lu();
    let u = lu.U();
    if (0..a.nrows()).any(|i| u[(i, i)] == 0.0 || !u[(i, i)].is_finite()) {
        return None;
    }
    Some(lu.solve(b))
}

/// Sets the force coefficients `phi` (real layout) on input `input` as the forcing of `sys`.
pub(crate) fn set_force(sys: &mut HbSystem, input: usize, phi: &[f64]) -> Result<()> {
    let set = *sys.harmonics();
    let f = complex_of(&set, phi);
    sys.set_forcing(Forcing {
        terms: f
            .iter()
            .enumerate()
            .map(|(k, &amplitude)| ForceTerm {
                input,
                harmonic: k,
                amplitude: if k == 0 {
                    c64::new(amplitude.re, 0.0)
                } else {
                    amplitude
                },
            })
            .collect(),
    })
}

/// The shaker's terms at one frequency and voltage: `G_k`, `Z_k` per harmonic, their
/// real-layout matrices and `G v` (real layout).
struct Terms {
    g: Vec<c64>,
    z: Vec<c64>,
    gr: Mat<f64>,
    zr: Mat<f64>,
    gv: Vec<f64>,
}

/// The coupling residual's Jacobian `I + Z ∂X_d/∂φ` from `jx`, the input ports' `∂X/∂φ`
/// of [`HbSystem::input_response_jacobian`] (rows of input `input`), `nh = 2H+1`.
fn coupling_jacobian(zr: &Mat<f64>, jx: &Mat<f64>, input: usize, nh: usize) -> Mat<f64> {
    Mat::from_fn(nh, nh, |i, j| {
        (i == j) as u8 as f64
            + (0..nh)
                .map(|l| zr[(i, l)] * jx[(input * nh + l, j)])
                .sum::<f64>()
    })
}

/// The coupled solution `(x, φ)` with its Jacobian `jq`, and `dφ/dv = J_Q⁻¹ G`;
/// [`Status::Singular`] when `jq` is.
fn coupled(
    x: Vec<f64>,
    phi: Vec<f64>,
    jq: Mat<f64>,
    gr: &Mat<f64>,
) -> std::result::Result<Coupled, Status> {
    let nh = gr.nrows();
    let mut dphi_dv = Mat::<f64>::zeros(nh, nh);
    for c in 0..nh {
        let col: Vec<f64> = (0..nh).map(|i| gr[(i, c)]).collect();
        let sol = solve_dense(&jq, &col).ok_or(Status::Singular)?;
        for i in 0..nh {
            dphi_dv[(i, c)] = sol[i];
        }
    }
    Ok(Coupled {
        x,
        phi,
        dphi_dv,
        jq,
    })
}

impl Rig<'_> {
    /// Sets the force coefficients `phi` (real layout) as the forcing of the system.
    pub(crate) fn set_force(&mut self, phi: &[f64]) -> Result<()> {
        set_force(self.sys, self.input, phi)
    }

    /// The shaker's terms at `omega` (rad/s) for voltage harmonics `volt`.
    fn terms(&self, omega: f64, volt: &[c64]) -> Terms {
        let set = *self.sys.harmonics();
        let nh = set.len();
        let (g, z): (Vec<c64>, Vec<c64>) = (0..=set.h)
            .map(|k| self.shaker.coupling(k as f64 * omega))
            .unzip();
        let gr = block_diag(&set, &g);
        let zr = block_diag(&set, &z);
        let vr = real_of(&set, volt);
        let gv: Vec<f64> = (0..nh)
            .map(|i| (0..nh).map(|j| gr[(i, j)] * vr[j]).sum())
            .collect();
        Terms { g, z, gr, zr, gv }
    }
    /// The force coefficients of the shaker on the linear structure (the nonlinear elements
    /// left out): `F_k = G_k V_k / (1 + Z_k H_dd(kΩ))`; also sets it as the forcing.
    fn linear_force(&mut self, omega: f64, g: &[c64], z: &[c64], volt: &[c64]) -> Result<Vec<f64>> {
        let set = *self.sys.harmonics();
        let port = self.sys.inputs()[self.input].1;
        let f: Vec<c64> = (0..=set.h)
            .map(|k| {
                let h = self
                    .sys
                    .linear()
                    .receptance(k as f64 * omega, &[port], &[port])[(0, 0)];
                g[k] * volt[k] / (c64::new(1.0, 0.0) + z[k] * h)
            })
            .collect();
        let phi = real_of(&set, &f);
        self.set_force(&phi)?;
        Ok(phi)
    }

    /// As [`Rig::solve_nested`] from `start` (force coefficients and structure unknowns), by
    /// Newton on the structure's unknowns and the force together: `R(x, φ) = 0`,
    /// `Q = φ − G v + Z X_d(x, φ) = 0` ([`HbSystem::input_coupling`]). Unlike the solve for
    /// the structure at each force, this stays regular where the force-driven structure
    /// folds — where a voltage-driven test often sits. Each step is halved until the
    /// scaled residual decreases.
    pub(crate) fn solve_joint(
        &mut self,
        omega: f64,
        volt: &[c64],
        start: (&[f64], &[f64]),
    ) -> Result<std::result::Result<Coupled, Status>> {
        let set = *self.sys.harmonics();
        let nh = set.len();
        let n = self.sys.n_unknowns();
        let rtol = self.sys.config().rtol;
        let Terms { gr, zr, gv, .. } = self.terms(omega, volt);
        let norm = |q: &[f64]| q.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        let q_scale = norm(&gv).max(1e-300);
        let (mut phi, mut x) = (start.0.to_vec(), start.1.to_vec());
        let x_scale = norm(&x).max(1e-300);
        let input = self.input;
        // The residuals [R; Q], their Jacobian, the merit max(‖R‖/s_x, ‖Q‖/s_Q) and
        // whether they meet the tolerances.
        let eval =
            |rig: &mut Self, x: &[f64], phi: &[f64]| -> Result<(Vec<f64>, Mat<f64>, f64, bool)> {
                rig.set_force(phi)?;
                let c = rig.sys.input_coupling(x, omega, 1.0, input)?;
                let zx: Vec<f64> = (0..nh)
                    .map(|i| (0..nh).map(|j| zr[(i, j)] * c.xd[j]).sum::<f64>())
                    .collect();
                let q: Vec<f64> = (0..nh).map(|i| phi[i] - gv[i] + zx[i]).collect();
                let mut f = c.r.clone();
                f.extend_from_slice(&q);
                let jac = Mat::from_fn(n + nh, n + nh, |i, j| match (i < n, j < n) {
                    (true, true) => c.r_x[(i, j)],
                    (true, false) => c.r_f[(i, j - n)],
                    (false, true) => (0..nh).map(|l| zr[(i - n, l)] * c.xd_x[(l, j)]).sum(),
                    (false, false) => {
                        (i == j) as u8 as f64
                            + (0..nh)
                                .map(|l| zr[(i - n, l)] * c.xd_f[(l, j - n)])
                                .sum::<f64>()
                    }
                });
                let (rn, qn) = (norm(&c.r), norm(&q));
                let sx = norm(x).max(x_scale * 1e-6);
                let done = rn <= rtol * sx && qn <= 1e-10 * q_scale + 10.0 * rtol * norm(&zx);
                Ok((f, jac, (rn / sx).max(qn / q_scale), done))
            };
        let (mut f, mut jac, mut merit, mut done) = eval(self, &x, &phi)?;
        for _ in 0..50 {
            if !merit.is_finite() {
                return Ok(Err(Status::NonFinite));
            }
            if done {
                // The force's derivatives through the structure, as the nested solve gives.
                let (_, jx) = self.sys.input_response_jacobian(&x, omega, 1.0, input)?;
                let jq = coupling_jacobian(&zr, &jx, input, nh);
                return Ok(coupled(x, phi, jq, &gr));
            }
            let Some(step) = solve_dense(&jac, &f) else {
                return Ok(Err(Status::Singular));
            };
            let mut alpha = 1.0;
            let mut taken = None;
            for _ in 0..12 {
                let xt: Vec<f64> = (0..n).map(|i| x[i] - alpha * step[i]).collect();
                let pt: Vec<f64> = (0..nh).map(|i| phi[i] - alpha * step[n + i]).collect();
                let r = eval(self, &xt, &pt)?;
                if r.2.is_finite() && (r.3 || r.2 < (1.0 - 1e-4 * alpha) * merit) {
                    taken = Some((xt, pt, r));
                    break;
                }
                alpha *= 0.5;
            }
            let Some((xt, pt, r)) = taken else {
                return Ok(Err(Status::StepTooSmall));
            };
            (x, phi) = (xt, pt);
            (f, jac, merit, done) = r;
        }
        Ok(Err(Status::IterationLimit))
    }

    /// Force and structure for voltage harmonics `volt` at `omega`, from `start` (force
    /// coefficients, structure unknowns and the frequency they belong to). `Ok(Err(status))`
    /// when the structure or the coupling does not converge.
    ///
    /// First by Newton on the force with the structure solved at each force
    /// ([`Rig::solve_nested`]); where that fails — the coupled state lies where the
    /// force-driven structure folds — by Newton on both together ([`Rig::solve_joint`]) from
    /// `start`, then from the coupled linear response. The joint solve does not check the
    /// coupled state's stability: the calibration objective uses it to evaluate a model
    /// between the data's states; the virtual test keeps to [`Rig::solve_nested`], which
    /// follows the structure's own branches, and leaves out the steps it cannot solve.
    pub(crate) fn solve_coupled(
        &mut self,
        omega: f64,
        volt: &[c64],
        start: Option<(&[f64], &[f64], f64)>,
    ) -> Result<std::result::Result<Coupled, Status>> {
        let nested = self.solve_nested(omega, volt, start)?;
        if nested.is_ok() {
            return Ok(nested);
        }
        if let Some((phi, x, _)) = start
            && let Ok(c) = self.solve_joint(omega, volt, (phi, x))?
        {
            return Ok(Ok(c));
        }
        let Terms { g, z, .. } = self.terms(omega, volt);
        let phi = self.linear_force(omega, &g, &z, volt)?;
        let x = self.sys.linear_guess(omega, 1.0);
        if let Ok(c) = self.solve_joint(omega, volt, (&phi, &x))? {
            return Ok(Ok(c));
        }
        Ok(nested)
    }

    /// [`Rig::solve_coupled`] by Newton on the force coefficients alone, the structure
    /// solved at each force from the last.
    pub(crate) fn solve_nested(
        &mut self,
        omega: f64,
        volt: &[c64],
        start: Option<(&[f64], &[f64], f64)>,
    ) -> Result<std::result::Result<Coupled, Status>> {
        let set = *self.sys.harmonics();
        let nh = set.len();
        let Terms { g, z, gr, zr, gv } = self.terms(omega, volt);
        let mut cold = start.is_none();
        let (mut phi, x0, w0) = match start {
            Some((p, x, w)) => (p.to_vec(), x.to_vec(), w),
            None => (
                self.linear_force(omega, &g, &z, volt)?,
                self.sys.linear_guess(omega, 1.0),
                omega,
            ),
        };
        let scale = gv.iter().fold(0.0f64, |a, v| a.max(v.abs())).max(1e-300);
        let norm = |q: &[f64]| q.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        // Q(φ) = φ − G v + Z X_d(φ) and its Jacobian I + Z ∂X_d/∂φ, the structure solved
        // from `prev`.
        let eval =
            |rig: &mut Self, phi: &[f64], prev: &(Vec<f64>, f64)| -> Result<Option<Residual>> {
                rig.set_force(phi)?;
                let (mut x, status) = solve_step(rig.sys, rig.ws, omega, Some(prev))?;
                if !status.is_converged() {
                    // A ramp of the force level from the linear response.
                    x = rig.sys.linear_guess(omega, 0.125);
                    for j in 1..=8 {
                        let level = j as f64 / 8.0;
                        let rep = rig.sys.solve_with(rig.ws, omega, level, &mut x)?;
                        if !rep.converged() {
                            return Ok(None);
                        }
                    }
                }
                let (disp, jac) = rig.sys.input_response_jacobian(&x, omega, 1.0, rig.input)?;
                let xd = real_of(
                    &set,
                    &(0..=set.h)
                        .map(|k| disp[(rig.input, k)])
                        .collect::<Vec<_>>(),
                );
                let zx: Vec<f64> = (0..nh)
                    .map(|i| (0..nh).map(|j| zr[(i, j)] * xd[j]).sum::<f64>())
                    .collect();
                let q: Vec<f64> = (0..nh).map(|i| phi[i] - gv[i] + zx[i]).collect();
                Ok(Some((x, q, coupling_jacobian(&zr, &jac, rig.input, nh))))
            };
        let first = match eval(self, &phi, &(x0, w0))? {
            Some(r) => r,
            // The warm start's force has no solution near the previous one (a jump past a
            // fold): start from the coupled linear response instead.
            None if !cold => {
                cold = true;
                phi = self.linear_force(omega, &g, &z, volt)?;
                let lin = self.sys.linear_guess(omega, 1.0);
                match eval(self, &phi, &(lin, omega))? {
                    Some(r) => r,
                    None => return Ok(Err(Status::NonFinite)),
                }
            }
            None => return Ok(Err(Status::NonFinite)),
        };
        let (mut x, mut q, mut jq) = first;
        for _ in 0..60 {
            if norm(&q) <= 1e-10 * scale {
                return Ok(coupled(x, phi, jq, &gr));
            }
            let Some(step) = solve_dense(&jq, &q) else {
                return Ok(Err(Status::Singular));
            };
            // Halve the step until ‖Q‖ decreases (the structure may jump between branches
            // when the force changes much).
            let prev = (x.clone(), omega);
            let mut alpha = 1.0;
            let mut taken = None;
            for _ in 0..12 {
                let trial: Vec<f64> = phi.iter().zip(&step).map(|(p, s)| p - alpha * s).collect();
                if let Some(r) = eval(self, &trial, &prev)?
                    && norm(&r.1) < (1.0 - 1e-4 * alpha) * norm(&q)
                {
                    taken = Some((trial, r));
                    break;
                }
                alpha *= 0.5;
            }
            let Some((trial, r)) = taken else {
                if cold {
                    return Ok(Err(Status::StepTooSmall));
                }
                // No branch near the warm start (a fold was passed): start again from the
                // coupled linear response, the low-amplitude branch.
                cold = true;
                phi = self.linear_force(omega, &g, &z, volt)?;
                let lin = self.sys.linear_guess(omega, 1.0);
                let Some(r) = eval(self, &phi, &(lin, omega))? else {
                    return Ok(Err(Status::NonFinite));
                };
                (x, q, jq) = r;
                continue;
            };
            phi = trial;
            (x, q, jq) = r;
        }
        Ok(Err(Status::IterationLimit))
    }
}
