//! A virtual stepped-sine test (thesis §4.4, Fig. 11; paper V): the structure driven through
//! an electrodynamic shaker on a stinger, by voltage, as in a lab; optionally with an
//! off-line force controller that iterates the voltage harmonics at each step until the
//! measured force harmonics meet their targets. The output is test data in the calibration's
//! format ([`TestData`]).
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
//! drive displacement `X_d(F)` are solved together by Newton on the force harmonics, with
//! `∂X_d/∂F` from [`HbSystem::input_response_jacobian`]. Near a resonance the structure moves
//! freely, the back-EMF and the armature's inertia take the force away — the force drop-out a
//! voltage-driven test shows — and the nonlinearity's harmonics in `X_d` come back as force
//! harmonics.

use crate::data::{Noise, Step, Sweep, TestData};
use crate::objective::solve_step;
use crate::synthetic::{Gaussian, SweepPlan};
use faer::{Mat, c64};
use nlsim_hb::{ForceTerm, Forcing, HbSystem, HbWorkspace};
use nlsim_kernel::{Error, Result, Status};
use std::f64::consts::PI;

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

/// The off-line force controller.
#[derive(Debug, Clone, PartialEq)]
pub struct ControlConfig {
    /// `false`: open loop — the voltage of the first step (set there so that the fundamental
    /// force meets its target) is held for the whole sweep, as a plain voltage-driven test.
    pub enabled: bool,
    /// Every controlled force harmonic within `tolerance · |F*₁|` of its target.
    pub tolerance: f64,
    /// Controller iterations per step.
    pub max_iterations: usize,
    /// Also drive the static force to zero with a DC voltage (the suspension otherwise pushes
    /// on a structure whose nonlinearity shifts its mean position).
    pub static_force: bool,
}

impl Default for ControlConfig {
    /// Control on, 1 % tolerance, 20 iterations, static force controlled.
    fn default() -> Self {
        Self {
            enabled: true,
            tolerance: 0.01,
            max_iterations: 20,
            static_force: true,
        }
    }
}

/// What happened at one step of a virtual test.
#[derive(Debug, Clone, PartialEq)]
pub struct StepControl {
    /// Excitation frequency (Hz).
    pub frequency_hz: f64,
    /// Controller iterations (0: the voltage met the targets as it came).
    pub iterations: usize,
    /// [`Status::Converged`] when the force met its targets (always, open loop, when the
    /// coupled solve converged); [`Status::IterationLimit`] when the controller stopped short;
    /// the harmonic balance's status when the structure could not be solved (the step is then
    /// missing from the data).
    pub status: Status,
    /// Voltage harmonics `k = 0..=H` (V).
    pub voltage: Vec<c64>,
    /// Force harmonics `k = 0..=H` (N) on the structure, before measurement noise.
    pub force: Vec<c64>,
    /// `max_k |F_k − F*_k| / |F*₁|` over the controlled harmonics.
    pub force_error: f64,
}

/// A virtual test: its data and the record of every step.
#[derive(Debug, Clone)]
pub struct VirtualTest {
    /// The measured data (force and response harmonics with noise).
    pub data: TestData,
    /// Per sweep, per step: the control record (steps that failed included).
    pub steps: Vec<Vec<StepControl>>,
}

/// The structure's unknowns, the coupling residual `Q` and its Jacobian at one force.
type Residual = (Vec<f64>, Vec<f64>, Mat<f64>);

/// The coupled structure–shaker solution at one frequency for one voltage.
struct Coupled {
    x: Vec<f64>,
    /// Real force coefficients (2H+1).
    phi: Vec<f64>,
    /// `∂φ/∂v` (real layout, (2H+1) × (2H+1)).
    dphi_dv: Mat<f64>,
}

/// The voltage-driven shaker on `sys` at input `input`.
struct Rig<'a> {
    sys: HbSystem,
    ws: HbWorkspace,
    shaker: &'a Shaker,
    input: usize,
}

fn real_of(set: &nlsim_hb::HarmonicSet, z: &[c64]) -> Vec<f64> {
    let mut v = vec![0.0; set.len()];
    for (k, z) in z.iter().enumerate() {
        set.set_complex(&mut v, k, *z);
    }
    v
}

fn complex_of(set: &nlsim_hb::HarmonicSet, v: &[f64]) -> Vec<c64> {
    (0..=set.h).map(|k| set.complex(v, k)).collect()
}

/// Real-layout matrix of multiplying harmonic `k` by `z[k]`.
fn block_diag(set: &nlsim_hb::HarmonicSet, z: &[c64]) -> Mat<f64> {
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
fn solve_dense(a: &Mat<f64>, b: &[f64]) -> Option<Vec<f64>> {
    use faer::linalg::solvers::Solve;
    let lu = a.partial_piv_lu();
    let u = lu.U();
    if (0..a.nrows()).any(|i| u[(i, i)] == 0.0 || !u[(i, i)].is_finite()) {
        return None;
    }
    let x = lu.solve(Mat::from_fn(b.len(), 1, |i, _| b[i]));
    Some((0..b.len()).map(|i| x[(i, 0)]).collect())
}

impl Rig<'_> {
    fn set_force(&mut self, phi: &[f64]) -> Result<()> {
        let set = *self.sys.harmonics();
        let f = complex_of(&set, phi);
        self.sys.set_forcing(Forcing {
            terms: f
                .iter()
                .enumerate()
                .map(|(k, &amplitude)| ForceTerm {
                    input: self.input,
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

    /// The controller at one step: Newton on the voltage coefficients `active` with the
    /// coupled system's `∂F/∂V`, each change halved until the force error decreases, from
    /// `volt` and the coupled state `start` (`None`: the low-amplitude branch). Returns the
    /// last measurement (the best found: each accepted change lowers the error), its voltage
    /// and the iterations made.
    #[allow(clippy::type_complexity)]
    fn control(
        &mut self,
        omega: f64,
        mut volt: Vec<c64>,
        start: Option<(&[f64], &[f64], f64)>,
        active: &[usize],
        target: &[c64],
        control: &ControlConfig,
    ) -> Result<(std::result::Result<Coupled, Status>, Vec<c64>, usize)> {
        let set = *self.sys.harmonics();
        let tr = real_of(&set, target);
        let mut outcome = self.solve(omega, &volt, start)?;
        let mut iterations = 0;
        while let Ok(c) = &outcome {
            let ferr = force_error(&set, &c.phi, target, active);
            if ferr <= control.tolerance
                || active.is_empty()
                || iterations == control.max_iterations
            {
                break;
            }
            iterations += 1;
            let err: Vec<f64> = active.iter().map(|&j| tr[j] - c.phi[j]).collect();
            let jac = Mat::from_fn(active.len(), active.len(), |a, b| {
                c.dphi_dv[(active[a], active[b])]
            });
            let Some(dv) = solve_dense(&jac, &err) else {
                break;
            };
            let here = (c.phi.clone(), c.x.clone());
            // Halve the voltage change until the force error decreases (near a fold the
            // structure may jump to another branch at the full change).
            let v0 = real_of(&set, &volt);
            let mut beta = 1.0;
            let mut accepted = None;
            while beta >= 1.0 / 64.0 {
                let mut vr = v0.clone();
                for (a, &j) in active.iter().enumerate() {
                    vr[j] += beta * dv[a];
                }
                let v = complex_of(&set, &vr);
                let trial = self.solve(omega, &v, Some((&here.0, &here.1, omega)))?;
                if trial
                    .as_ref()
                    .is_ok_and(|t| force_error(&set, &t.phi, target, active) < ferr)
                {
                    accepted = Some((trial, v));
                    break;
                }
                beta *= 0.5;
            }
            let Some((trial, v)) = accepted else { break };
            outcome = trial;
            volt = v;
        }
        Ok((outcome, volt, iterations))
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

    /// Force and structure for voltage harmonics `volt` at `omega`, from `start` (force
    /// coefficients, structure unknowns and the frequency they belong to). `Ok(Err(status))`
    /// when the structure or the coupling does not converge.
    fn solve(
        &mut self,
        omega: f64,
        volt: &[c64],
        start: Option<(&[f64], &[f64], f64)>,
    ) -> Result<std::result::Result<Coupled, Status>> {
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
                let (mut x, status) = solve_step(&rig.sys, &mut rig.ws, omega, Some(prev))?;
                if !status.is_converged() {
                    // A ramp of the force level from the linear response.
                    x = rig.sys.linear_guess(omega, 0.125);
                    for j in 1..=8 {
                        let level = j as f64 / 8.0;
                        let rep = rig.sys.solve_with(&mut rig.ws, omega, level, &mut x)?;
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
                let q: Vec<f64> = (0..nh)
                    .map(|i| phi[i] - gv[i] + (0..nh).map(|j| zr[(i, j)] * xd[j]).sum::<f64>())
                    .collect();
                let jq = Mat::from_fn(nh, nh, |i, j| {
                    (i == j) as u8 as f64
                        + (0..nh)
                            .map(|l| zr[(i, l)] * jac[(rig.input * nh + l, j)])
                            .sum::<f64>()
                });
                Ok(Some((x, q, jq)))
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
                // dφ/dv = Jq⁻¹ G.
                let mut dphi_dv = Mat::<f64>::zeros(nh, nh);
                for c in 0..nh {
                    let col: Vec<f64> = (0..nh).map(|i| gr[(i, c)]).collect();
                    let Some(s) = solve_dense(&jq, &col) else {
                        return Ok(Err(Status::Singular));
                    };
                    for i in 0..nh {
                        dphi_dv[(i, c)] = s[i];
                    }
                }
                return Ok(Ok(Coupled { x, phi, dphi_dv }));
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

/// Runs the stepped sines `plans` on `sys` through `shaker` at input `input`, measuring
/// harmonics `1..=harmonics` of every sensor with `noise` (and of the force with
/// `force_noise`), the noise drawn from `seed`. The force targets of a step are the plan's
/// force on the fundamental and zero on the other harmonics. With control the controller
/// runs at every step (Newton on the voltage harmonics with the coupled system's own
/// `∂F/∂V`); without it the voltage found at each sweep's first step is held.
///
/// Steps where the structure cannot be solved are left out of the data and recorded with
/// their status; `Err` only for invalid input.
#[allow(clippy::too_many_arguments)]
pub fn virtual_test(
    sys: &HbSystem,
    input: &str,
    shaker: &Shaker,
    plans: &[SweepPlan],
    harmonics: usize,
    control: &ControlConfig,
    noise: Noise,
    force_noise: Noise,
    seed: u64,
) -> Result<VirtualTest> {
    let per_channel = vec![noise; sys.sensors().len()];
    virtual_test_with(
        sys,
        input,
        shaker,
        plans,
        harmonics,
        control,
        &per_channel,
        force_noise,
        seed,
    )
}

/// [`virtual_test`] with a noise model per sensor (`noise[c]` for the system's sensor `c`,
/// e.g. floors in each sensor's own scale); the same draws as [`virtual_test`] when every
/// entry is the same.
#[allow(clippy::too_many_arguments)]
pub fn virtual_test_with(
    sys: &HbSystem,
    input: &str,
    shaker: &Shaker,
    plans: &[SweepPlan],
    harmonics: usize,
    control: &ControlConfig,
    noise: &[Noise],
    force_noise: Noise,
    seed: u64,
) -> Result<VirtualTest> {
    if noise.len() != sys.sensors().len() {
        return Err(Error::invalid(
            "virtual test noise",
            format!(
                "{} noise models given for {} sensors",
                noise.len(),
                sys.sensors().len()
            ),
        ));
    }
    shaker.check()?;
    let set = *sys.harmonics();
    if set.nu != 1 {
        return Err(Error::invalid(
            "virtual test",
            "stepped-sine data are harmonics of the excitation: use a harmonic set with ν = 1",
        ));
    }
    if harmonics == 0 || harmonics > set.h {
        return Err(Error::invalid(
            "virtual test",
            format!(
                "measured harmonics 1..={harmonics} must be within the harmonic balance's H = {}",
                set.h
            ),
        ));
    }
    if !(control.tolerance > 0.0 && control.tolerance.is_finite()) || control.max_iterations == 0 {
        return Err(Error::invalid(
            "force control",
            format!(
                "needs a positive tolerance and at least one iteration (got {} and {})",
                control.tolerance, control.max_iterations
            ),
        ));
    }
    let input_idx = sys
        .inputs()
        .iter()
        .position(|(n, _)| n == input)
        .ok_or_else(|| {
            Error::invalid(
                format!("virtual test drive point '{input}'"),
                format!(
                    "the model has no input of that name (it has: {})",
                    sys.inputs()
                        .iter()
                        .map(|(n, _)| n.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )
        })?;
    for p in plans {
        if !(p.force.is_finite() && p.force > 0.0)
            || p.frequencies_hz.is_empty()
            || p.frequencies_hz
                .iter()
                .any(|f| !(f.is_finite() && *f > 0.0))
        {
            return Err(Error::invalid(
                format!("virtual test sweep '{}'", p.label),
                "needs a positive force and at least one positive frequency",
            ));
        }
    }
    let nh = set.len();
    let mut rig = Rig {
        ws: sys.workspace(16 << 20),
        sys: sys.clone(),
        shaker,
        input: input_idx,
    };
    // Controlled coefficients: harmonics 1..=H (and the static one).
    let controlled: Vec<usize> = (if control.static_force { 0 } else { 1 }..nh).collect();
    let mut gauss = Gaussian::new(seed);
    let mut sweeps = Vec::with_capacity(plans.len());
    let mut records = Vec::with_capacity(plans.len());
    for plan in plans {
        let mut target = vec![c64::new(0.0, 0.0); set.h + 1];
        target[1] = c64::new(plan.force, 0.0);
        let mut steps = Vec::new();
        let mut record = Vec::new();
        // Start: the linear shaker-structure response decides the first voltage.
        let mut volt = vec![c64::new(0.0, 0.0); set.h + 1];
        let mut state: Option<(Vec<f64>, Vec<f64>, f64)> = None;
        for (i, &f) in plan.frequencies_hz.iter().enumerate() {
            let omega = 2.0 * PI * f;
            let first = i == 0;
            if first {
                let (g, _) = shaker.coupling(omega);
                volt[1] = target[1] / g;
            }
            // Open loop: only the first step is controlled (fundamental only, no DC).
            let active: Vec<usize> = if control.enabled {
                controlled.clone()
            } else if first {
                vec![1, 2]
            } else {
                Vec::new()
            };
            let warm = state
                .as_ref()
                .map(|(p, x, w)| (p.as_slice(), x.as_slice(), *w));
            let (mut outcome, mut v, mut iterations) =
                rig.control(omega, volt.clone(), warm, &active, &target, control)?;
            let err = |o: &std::result::Result<Coupled, Status>| {
                o.as_ref().map_or(f64::INFINITY, |c| {
                    force_error(&set, &c.phi, &target, &active)
                })
            };
            if err(&outcome) > control.tolerance && !active.is_empty() {
                // Stopped short from the previous step's state (a fold: the branch it was on
                // ends here). Again from the low-amplitude branch, at the voltage the linear
                // structure would need.
                let port = rig.sys.inputs()[input_idx].1;
                let v_lin: Vec<c64> = (0..=set.h)
                    .map(|k| {
                        let w = k as f64 * omega;
                        let h = rig.sys.linear().receptance(w, &[port], &[port])[(0, 0)];
                        let (g, z) = shaker.coupling(w);
                        target[k] * (c64::new(1.0, 0.0) + z * h) / g
                    })
                    .collect();
                let (o2, v2, it2) = rig.control(omega, v_lin, None, &active, &target, control)?;
                iterations += it2;
                if err(&o2) < err(&outcome) {
                    (outcome, v) = (o2, v2);
                }
            }
            volt = v;
            match outcome {
                Ok(c) => {
                    let ferr = force_error(&set, &c.phi, &target, &controlled);
                    let status = if !control.enabled || ferr <= control.tolerance {
                        Status::Converged
                    } else {
                        Status::IterationLimit
                    };
                    let force = complex_of(&set, &c.phi);
                    // The measurement.
                    rig.set_force(&c.phi)?;
                    let y = rig.sys.sensor_response(&c.x, omega, 1.0);
                    let mut normal = || gauss.sample();
                    let response = Mat::from_fn(y.nrows(), harmonics, |s, k| y[(s, k + 1)]);
                    let response = Mat::from_fn(response.nrows(), harmonics, |s, k| {
                        let v = response[(s, k)];
                        let sg = noise[s].sigma(v);
                        v + c64::new(sg * normal(), sg * normal())
                    });
                    let measured_force = (1..=harmonics)
                        .map(|k| {
                            let v = force[k];
                            let sg = force_noise.sigma(v);
                            v + c64::new(sg * normal(), sg * normal())
                        })
                        .collect();
                    steps.push(Step {
                        frequency_hz: f,
                        force: measured_force,
                        response,
                        sigma: Mat::new(),
                    });
                    record.push(StepControl {
                        frequency_hz: f,
                        iterations,
                        status,
                        voltage: volt.clone(),
                        force,
                        force_error: ferr,
                    });
                    state = Some((c.phi, c.x, omega));
                }
                Err(status) => {
                    record.push(StepControl {
                        frequency_hz: f,
                        iterations,
                        status,
                        voltage: volt.clone(),
                        force: vec![c64::new(f64::NAN, f64::NAN); set.h + 1],
                        force_error: f64::NAN,
                    });
                    state = None;
                }
            }
        }
        sweeps.push(Sweep {
            label: plan.label.clone(),
            direction: plan.direction,
            steps,
        });
        records.push(record);
    }
    let channels = crate::synthetic::sensor_channels_with(sys, noise);
    let data = TestData {
        input: input.into(),
        channels,
        harmonics,
        sweeps: sweeps.into_iter().filter(|s| !s.steps.is_empty()).collect(),
    };
    if data.sweeps.is_empty() {
        return Err(Error::Numerical {
            what: "virtual test".into(),
            detail: "no step of any sweep could be solved".into(),
        });
    }
    Ok(VirtualTest {
        data,
        steps: records,
    })
}

/// `max |F_k − F*_k| / |F*₁|` over the real coefficients `active` (pairs of a harmonic
/// counted by their complex difference).
fn force_error(set: &nlsim_hb::HarmonicSet, phi: &[f64], target: &[c64], active: &[usize]) -> f64 {
    let f = complex_of(set, phi);
    let scale = target[1].norm().max(1e-300);
    active
        .iter()
        .map(|&j| if j == 0 { 0 } else { j.div_ceil(2) })
        .map(|k| (f[k] - target[k]).norm() / scale)
        .fold(0.0f64, f64::max)
}
