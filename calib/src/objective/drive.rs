//! How the objective drives the model with a step's recorded drive, and the gains of the
//! test data (issue: voltage-driven tests and unknown sensor sensitivities).
//!
//! - Force record ([`Drive::Force`]), or a voltage record with the shaker taken as a force
//!   source: the model is forced with `F_k = g D_k`, `D_k` the recorded drive harmonics and
//!   `g` the input gain ([`Param::InputGain`], N per recorded unit).
//! - Voltage record through a modelled shaker ([`FrfObjective::set_shaker`]): the coil
//!   voltage is `V_k = g D_k` (`g` in V per recorded volt) and the force on the structure
//!   solves the coupling `F = G(s) V − Z(s) X_d(F)` of [`crate::coupling`] at every step, the
//!   same Newton as the virtual test.
//! - Each channel records `s_c Y_c`, `Y_c` the model's response and `s_c` the channel's
//!   gain ([`Param::SensorGain`], 1 unless set or calibrated).
//!
//! The parameter sensitivities follow the force where it depends on them (implicit
//! differentiation of the coupling): `dY/dp = ∂Y/∂p|_F + (∂Y/∂F) dF/dp` with
//! `dF/dp = −J_Q⁻¹ Z ∂X_d/∂p|_F` for a structural parameter, `J_Q⁻¹ G D` for the gain of a
//! shaker's voltage and `D` for the gain of a force; `∂Y/∂F` from
//! [`HbSystem::sensor_force_jacobian`](nlsim_hb::HbSystem::sensor_force_jacobian).

use super::{FrfObjective, solve_step};
use crate::coupling::{Coupled, Rig, Shaker, block_diag, real_of, set_force, solve_dense};
use crate::data::{Drive, Step};
use faer::{Mat, c64};
use nlsim_hb::{ForceTerm, Forcing};
use nlsim_kernel::{Error, Param, Quantity, Result, Status};

/// The name of the displacement sensor the objective adds at the drive point when it models
/// a shaker (no model sensor can take it: names have letters, digits, `_` and `-` only).
pub(crate) const DRIVE_SENSOR: &str = "<drive>";

/// The gains of the test data: fixed values, or the nominal ones of calibrated gains.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Gains {
    /// Input gain `g`.
    pub input: f64,
    /// Gain of each model sensor (its data channel's), by sensor index.
    pub sensors: Vec<f64>,
}

/// The previous step's solution a sweep continues from.
#[derive(Debug, Clone)]
pub(crate) struct Previous {
    /// Harmonic balance unknowns and the angular frequency (rad/s) they solve.
    pub state: (Vec<f64>, f64),
    /// The shaker's force coefficients (real layout), when a shaker is modelled.
    pub phi: Option<Vec<f64>>,
}

/// The solution at one step.
pub(crate) struct Solved {
    /// Harmonic balance unknowns.
    pub x: Vec<f64>,
    /// The coupled shaker state, when a shaker is modelled.
    pub coupled: Option<Coupled>,
}

impl FrfObjective {
    /// Fixes gain `p` ([`Param::InputGain`], [`Param::SensorGain`] of a data channel) at
    /// `value`: used as it is when the gain is not calibrated, as its nominal value (the
    /// first candidate's) when it is. Gains must be positive and finite (a sensor mounted
    /// the other way round is a phase convention: `phase_offset_deg`).
    pub fn set_gain(&mut self, p: &Param, value: f64) -> Result<()> {
        let slot = self.gain_slot(p)?;
        if !(value.is_finite() && value > 0.0) {
            return Err(Error::InvalidParameter {
                name: p.to_string(),
                value,
                reason: "a gain must be positive and finite".into(),
            });
        }
        match slot {
            None => self.gains.input = value,
            Some(s) => self.gains.sensors[s] = value,
        }
        Ok(())
    }

    /// The fixed (or nominal) value of gain `p`.
    pub fn gain(&self, p: &Param) -> Result<f64> {
        Ok(match self.gain_slot(p)? {
            None => self.gains.input,
            Some(s) => self.gains.sensors[s],
        })
    }

    /// `None` for the input gain, the model sensor of a channel's gain; an error for
    /// anything else.
    pub(crate) fn gain_slot(&self, p: &Param) -> Result<Option<usize>> {
        match p {
            Param::InputGain => Ok(None),
            Param::SensorGain(name) => self
                .data
                .channels
                .iter()
                .position(|c| &c.name == name)
                .map(|c| Some(self.sensor_of[c]))
                .ok_or_else(|| {
                    Error::invalid(
                        format!("parameter '{p}'"),
                        format!(
                            "the test data have no channel '{name}' (they have: {})",
                            self.data
                                .channels
                                .iter()
                                .map(|c| c.name.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        ),
                    )
                }),
            _ => Err(Error::invalid(
                format!("parameter '{p}'"),
                "is not a gain of the test data",
            )),
        }
    }

    /// Drives the model through `shaker` with the test data's voltage record (`None`: the
    /// recorded drive is the force, times the input gain). The input gain is then the
    /// amplifier's: volts at the coil per recorded unit. Errors unless the data recorded a
    /// voltage, or when the shaker's values are invalid.
    pub fn set_shaker(&mut self, shaker: Option<Shaker>) -> Result<()> {
        if let Some(sh) = &shaker {
            sh.check()?;
            if self.data.drive != Drive::Voltage {
                return Err(Error::invalid(
                    "shaker",
                    format!(
                        "the test data recorded the {} at '{}': a shaker model needs the \
                         voltage it was driven with",
                        self.data.drive.as_str(),
                        self.data.input
                    ),
                ));
            }
            if !self.sys.sensors().iter().any(|s| s.name == DRIVE_SENSOR) {
                let port = self.sys.inputs()[self.input].1;
                self.sys
                    .add_sensor(DRIVE_SENSOR, port, Quantity::Displacement)?;
                self.gains.sensors.push(1.0);
            }
        }
        self.shaker = shaker;
        Ok(())
    }

    /// The shaker the voltage record drives, if modelled.
    pub fn shaker(&self) -> Option<&Shaker> {
        self.shaker.as_ref()
    }

    /// The gains at parameter values `values`: the fixed ones, with the calibrated ones
    /// replaced by their values.
    pub(crate) fn gains_at(&self, values: &[f64]) -> Result<Gains> {
        let mut g = self.gains.clone();
        for (s, &v) in self.specs.iter().zip(values) {
            if s.param.is_gain() {
                if !(v.is_finite() && v > 0.0) {
                    return Err(Error::InvalidParameter {
                        name: s.param.to_string(),
                        value: v,
                        reason: "a gain must be positive and finite".into(),
                    });
                }
                match self.gain_slot(&s.param)? {
                    None => g.input = v,
                    Some(k) => g.sensors[k] = v,
                }
            }
        }
        Ok(g)
    }

    /// The recorded drive of step `st` as harmonics `k = 0..=H` of the model (zero beyond
    /// the data's and at `k = 0`).
    fn recorded_drive(&self, st: &Step) -> Vec<c64> {
        let h = self.sys.harmonics().h;
        (0..=h)
            .map(|k| {
                if k >= 1 && k <= st.force.len() {
                    st.force[k - 1]
                } else {
                    c64::new(0.0, 0.0)
                }
            })
            .collect()
    }

    /// Solves step `st` at `omega` (rad/s) from `prev` (`None`: from the low-amplitude
    /// response) with the drive the objective models; the forcing of the solution is left
    /// set on the system. `Ok(Err(status))` when the solve did not converge.
    pub(crate) fn solve_driven(
        &mut self,
        st: &Step,
        omega: f64,
        gains: &Gains,
        prev: Option<&Previous>,
    ) -> Result<std::result::Result<Solved, Status>> {
        let drive = self.recorded_drive(st);
        match self.shaker {
            None => {
                let terms = drive
                    .iter()
                    .enumerate()
                    .filter(|(_, d)| d.norm() > 0.0)
                    .map(|(k, &d)| ForceTerm {
                        input: self.input,
                        harmonic: k,
                        amplitude: d * gains.input,
                    })
                    .collect();
                self.sys.set_forcing(Forcing { terms })?;
                let start = prev.map(|p| &p.state);
                let (x, status) = solve_step(&self.sys, &mut self.ws, omega, start)?;
                Ok(if status.is_converged() {
                    Ok(Solved { x, coupled: None })
                } else {
                    Err(status)
                })
            }
            Some(shaker) => {
                let volt: Vec<c64> = drive.iter().map(|d| d * gains.input).collect();
                let mut rig = Rig {
                    sys: &mut self.sys,
                    ws: &mut self.ws,
                    shaker: &shaker,
                    input: self.input,
                };
                let start = prev.and_then(|p| {
                    p.phi
                        .as_ref()
                        .map(|phi| (phi.as_slice(), p.state.0.as_slice(), p.state.1))
                });
                let mut outcome = rig.solve_coupled(omega, &volt, start)?;
                if outcome.is_err()
                    && let Some((phi0, x0, w0)) = start
                {
                    // Through four intermediate frequencies from the previous step.
                    let mut state = (phi0.to_vec(), x0.to_vec(), w0);
                    for j in 1..=4 {
                        let w = w0 + (omega - w0) * j as f64 / 4.0;
                        let warm = Some((state.0.as_slice(), state.1.as_slice(), state.2));
                        match rig.solve_coupled(w, &volt, warm)? {
                            Ok(c) if j == 4 => outcome = Ok(c),
                            Ok(c) => state = (c.phi, c.x, w),
                            Err(_) => break,
                        }
                    }
                }
                if outcome.is_err() {
                    // The voltage ramped up in eight steps from the low-amplitude response,
                    // as a test starting at this frequency would.
                    let mut state: Option<Coupled> = None;
                    for j in 1..=8 {
                        let v: Vec<c64> = volt.iter().map(|v| v * (j as f64 / 8.0)).collect();
                        let warm = state
                            .as_ref()
                            .map(|c| (c.phi.as_slice(), c.x.as_slice(), omega));
                        match rig.solve_coupled(omega, &v, warm)? {
                            Ok(c) if j == 8 => outcome = Ok(c),
                            Ok(c) => state = Some(c),
                            Err(_) => break,
                        }
                    }
                }
                Ok(match outcome {
                    Ok(c) => {
                        rig.set_force(&c.phi)?;
                        Ok(Solved {
                            x: c.x.clone(),
                            coupled: Some(c),
                        })
                    }
                    Err(status) => Err(status),
                })
            }
        }
    }

    /// Sets the forcing of solution `solved` on the system again (after another solve).
    pub(crate) fn set_solved_force(&mut self, solved: &Solved) -> Result<()> {
        if let Some(c) = &solved.coupled {
            set_force(&mut self.sys, self.input, &c.phi)?;
        }
        // Force drive: the forcing depends on the step alone, the same for both solves.
        Ok(())
    }

    /// The data channels' harmonics `1..=H_data` (channels × harmonics) from the model
    /// sensors' response `y` (sensors × `k = 0..=H`, [`HbSystem::sensor_response`]) at
    /// `omega`, times each channel's gain; NaN beyond the model's harmonics.
    ///
    /// [`HbSystem::sensor_response`]: nlsim_hb::HbSystem::sensor_response
    pub(crate) fn channel_response(&self, y: &Mat<c64>, omega: f64, gains: &Gains) -> Mat<c64> {
        let h_data = self.data.harmonics;
        let h = h_data.min(self.sys.harmonics().h);
        Mat::from_fn(self.data.channels.len(), h_data, |c, j| {
            if j < h {
                let s = self.sensor_of[c];
                y[(s, j + 1)] * self.quantity_factor(c, j + 1, omega) * gains.sensors[s]
            } else {
                c64::new(f64::NAN, f64::NAN)
            }
        })
    }

    /// Every calibrated parameter's `dY/dp` (model sensors × `k = 0..=H`, in spec order) at
    /// solution `solved` of step `st`: `d` holds the sensitivities at a fixed force of the
    /// system's and FE-level parameters (`None` for the gains); here the force's own
    /// dependence is added, the gains' columns formed and every row scaled by its sensor's
    /// gain. `y` is the model sensors' response (without gains).
    pub(crate) fn complete_sensitivities(
        &self,
        st: &Step,
        omega: f64,
        solved: &Solved,
        y: &Mat<c64>,
        gains: &Gains,
        mut d: Vec<Option<Mat<c64>>>,
    ) -> Result<Vec<Mat<c64>>> {
        let set = *self.sys.harmonics();
        let nh = set.len();
        let (ns, nk) = (y.nrows(), y.ncols());
        let drive = real_of(&set, &self.recorded_drive(st));
        // dφ/dp of the force coefficients, per spec.
        let mut dphi: Vec<Option<Vec<f64>>> = vec![None; d.len()];
        match (&solved.coupled, self.shaker) {
            (Some(c), Some(shaker)) => {
                let ds = self
                    .sys
                    .sensors()
                    .iter()
                    .position(|s| s.name == DRIVE_SENSOR)
                    .ok_or_else(|| Error::invalid("shaker", "the drive sensor is missing"))?;
                let z: Vec<c64> = (0..=set.h)
                    .map(|k| shaker.coupling(k as f64 * omega).1)
                    .collect();
                let zr = block_diag(&set, &z);
                for (j, spec) in self.specs.iter().enumerate() {
                    let rhs: Vec<f64> = if spec.param == Param::InputGain {
                        // J_Q dφ = G D: dφ/dv D with dφ/dv = J_Q⁻¹ G.
                        (0..nh)
                            .map(|i| (0..nh).map(|l| c.dphi_dv[(i, l)] * drive[l]).sum())
                            .collect()
                    } else if let Some(dy) = &d[j] {
                        let row: Vec<c64> = (0..=set.h).map(|k| dy[(ds, k)]).collect();
                        let dxd = real_of(&set, &row);
                        let zx: Vec<f64> = (0..nh)
                            .map(|i| -(0..nh).map(|l| zr[(i, l)] * dxd[l]).sum::<f64>())
                            .collect();
                        solve_dense(&c.jq, &zx).ok_or_else(|| Error::Numerical {
                            what: "shaker coupling sensitivity".into(),
                            detail: format!(
                                "the coupling Jacobian is singular at {} Hz",
                                st.frequency_hz
                            ),
                        })?
                    } else {
                        continue;
                    };
                    dphi[j] = Some(rhs);
                }
            }
            _ => {
                for (j, spec) in self.specs.iter().enumerate() {
                    if spec.param == Param::InputGain {
                        dphi[j] = Some(drive.clone());
                    }
                }
            }
        }
        if dphi.iter().any(Option::is_some) {
            let jf = self
                .sys
                .sensor_force_jacobian(&solved.x, omega, 1.0, self.input)?;
            for (j, dp) in dphi.iter().enumerate() {
                let Some(dp) = dp else { continue };
                let m = d[j].get_or_insert_with(|| Mat::zeros(ns, nk));
                for (c, &v) in dp.iter().enumerate() {
                    if v != 0.0 {
                        for s in 0..ns {
                            for k in 0..nk {
                                m[(s, k)] += jf[c][(s, k)] * v;
                            }
                        }
                    }
                }
            }
        }
        let mut out = Vec::with_capacity(d.len());
        for (spec, dj) in self.specs.iter().zip(d) {
            if let Param::SensorGain(_) = &spec.param {
                // d(s Y)/ds = Y on its own sensor's row.
                let s0 = self.gain_slot(&spec.param)?.unwrap_or(usize::MAX);
                out.push(Mat::from_fn(ns, nk, |s, k| {
                    if s == s0 {
                        y[(s, k)]
                    } else {
                        c64::new(0.0, 0.0)
                    }
                }));
            } else {
                let m = dj.unwrap_or_else(|| Mat::zeros(ns, nk));
                out.push(Mat::from_fn(ns, nk, |s, k| m[(s, k)] * gains.sensors[s]));
            }
        }
        Ok(out)
    }
}
