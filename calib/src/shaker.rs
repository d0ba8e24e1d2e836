//! A virtual stepped-sine test (thesis §4.4, Fig. 11; paper V): the structure driven through
//! an electrodynamic shaker on a stinger, by voltage, as in a lab; optionally with an
//! off-line force controller that iterates the voltage harmonics at each step until the
//! measured force harmonics meet their targets. The output is test data in the calibration's
//! format ([`TestData`]).
//!
//! The shaker and its coupling to the structure are in [`crate::coupling`].

use crate::coupling::{Coupled, Rig, complex_of, real_of, solve_dense};
pub use crate::coupling::{SHAKER_MAX, SHAKER_MIN, Shaker};
use crate::data::{Drive, Noise, Step, Sweep, TestData};
use crate::synthetic::{Gaussian, SweepPlan};
use faer::{Mat, c64};
use nlsim_hb::HbSystem;
use nlsim_kernel::{Error, Result, Status};
use std::f64::consts::PI;

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

impl VirtualTest {
    /// The test as a voltage-driven lab records it: the data with the drive column holding
    /// the voltage of each step divided by `amplifier_gain` (the signal into an amplifier of
    /// that gain, V at the coil per V in; [`Drive::Voltage`]) instead of the measured force.
    /// The generator's voltage is known exactly: no noise is added to it. Errors when the
    /// gain is not positive and finite.
    pub fn voltage_data(&self, amplifier_gain: f64) -> Result<TestData> {
        if !(amplifier_gain.is_finite() && amplifier_gain > 0.0) {
            return Err(Error::invalid(
                "amplifier gain",
                format!("must be positive and finite, not {amplifier_gain}"),
            ));
        }
        let mut data = self.data.clone();
        data.drive = Drive::Voltage;
        let mut records = self
            .steps
            .iter()
            .filter(|r| r.iter().any(|s| s.force[1].re.is_finite()));
        for sweep in &mut data.sweeps {
            let rec: Vec<&StepControl> = records
                .next()
                .map(|r| r.iter().filter(|s| s.force[1].re.is_finite()).collect())
                .unwrap_or_default();
            if rec.len() != sweep.steps.len() {
                return Err(Error::invalid(
                    "virtual test",
                    format!(
                        "sweep '{}': its record does not match its data",
                        sweep.label
                    ),
                ));
            }
            for (step, r) in sweep.steps.iter_mut().zip(rec) {
                for (k, f) in step.force.iter_mut().enumerate() {
                    *f = r.voltage[k + 1] / amplifier_gain;
                }
            }
        }
        Ok(data)
    }
}

impl Rig<'_> {
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
        let mut outcome = self.solve_nested(omega, &volt, start)?;
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
                let trial = self.solve_nested(omega, &v, Some((&here.0, &here.1, omega)))?;
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
    let mut own_sys = sys.clone();
    let mut own_ws = sys.workspace(16 << 20);
    let mut rig = Rig {
        sys: &mut own_sys,
        ws: &mut own_ws,
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
        drive: Drive::Force,
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
