//! Synthetic stepped-sine tests from a model: what a lab would measure, with seeded noise.
//! Used to check that calibration returns known parameters, and by the demo when no measured
//! data is given.

use crate::data::{Channel, Noise, Step, Sweep, SweepDirection, TestData};
use crate::lhs::Spacing;
use crate::objective::FrfObjective;
use crate::objective::{ObjectiveConfig, ParamSpec};
use faer::{Mat, c64};
use nlsim_hb::HbSystem;
use nlsim_kernel::{Error, Param, Parameterized, Quantity, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::sync::Arc;

/// One sweep to synthesise.
#[derive(Debug, Clone, PartialEq)]
pub struct SweepPlan {
    /// Label.
    pub label: String,
    /// Frequencies in measured order (Hz).
    pub frequencies_hz: Vec<f64>,
    /// Force amplitude of the fundamental (N), phase 0.
    pub force: f64,
    /// Direction of `frequencies_hz`.
    pub direction: SweepDirection,
}

impl SweepPlan {
    /// `n` equally spaced steps from `from_hz` to `to_hz` (in that order) at force `force`.
    pub fn linear(
        label: impl Into<String>,
        from_hz: f64,
        to_hz: f64,
        n: usize,
        force: f64,
    ) -> Self {
        let frequencies_hz = (0..n)
            .map(|i| from_hz + (to_hz - from_hz) * i as f64 / (n.max(2) - 1) as f64)
            .collect();
        Self {
            label: label.into(),
            frequencies_hz,
            force,
            direction: if to_hz >= from_hz {
                SweepDirection::Up
            } else {
                SweepDirection::Down
            },
        }
    }
}

/// The stepped-sine test of `sys` (its current parameters) driven at input `input` along
/// `plans`, measuring `harmonics` harmonics of every model sensor; each complex amplitude
/// gets Gaussian noise of standard deviation `noise.sigma(Y)` per real and imaginary part,
/// drawn from `seed`. Points where the harmonic balance fails are an error (the model that
/// generates data must be solvable there).
pub fn synthesize(
    sys: &HbSystem,
    input: &str,
    plans: &[SweepPlan],
    harmonics: usize,
    noise: Noise,
    seed: u64,
) -> Result<TestData> {
    let channels: Vec<Channel> = crate::synthetic::sensor_channels(sys, noise);
    // Noise-free data as a template: the objective's own sweep following then computes the
    // model response at the measured force.
    let nan = c64::new(f64::NAN, f64::NAN);
    let sweeps = plans
        .iter()
        .map(|p| Sweep {
            label: p.label.clone(),
            direction: p.direction,
            steps: p
                .frequencies_hz
                .iter()
                .map(|&f| Step {
                    frequency_hz: f,
                    force: (1..=harmonics)
                        .map(|k| c64::new(if k == 1 { p.force } else { 0.0 }, 0.0))
                        .collect(),
                    response: Mat::from_fn(channels.len(), harmonics, |_, _| nan),
                    sigma: Mat::new(),
                })
                .collect(),
        })
        .collect();
    let mut data = TestData {
        input: input.into(),
        drive: crate::data::Drive::Force,
        channels,
        harmonics,
        sweeps,
    };
    // Any one parameter serves to build the objective; it is set to its own value.
    let p = sys
        .parameters()
        .into_iter()
        .next()
        .unwrap_or(Param::StiffnessScale);
    let v = sys.param(&p)?;
    let spec = ParamSpec {
        param: p,
        lower: v - 1.0 - v.abs(),
        upper: v + 1.0 + v.abs(),
        spacing: Spacing::Linear,
    };
    let mut obj = FrfObjective::new(
        sys,
        Arc::new(data.clone()),
        vec![spec],
        ObjectiveConfig::default(),
    )?;
    let ev = obj.evaluate_values(&[v], None, false)?;
    if let Some(id) = ev.failed.first() {
        return Err(Error::Numerical {
            what: "synthetic test".into(),
            detail: format!(
                "the harmonic balance failed at sweep '{}' step {} ({} Hz)",
                data.sweeps[id.sweep].label,
                id.step + 1,
                data.step(*id).frequency_hz
            ),
        });
    }
    let mut gauss = Gaussian::new(seed);
    let mut normal = || gauss.sample();
    for pr in &ev.points {
        let st = &mut data.sweeps[pr.id.sweep].steps[pr.id.step];
        for c in 0..st.response.nrows() {
            for k in 0..harmonics {
                let y = pr.response[(c, k)];
                let s = noise.sigma(y);
                st.response[(c, k)] = y + c64::new(s * normal(), s * normal());
            }
        }
    }
    Ok(data)
}

/// One channel per sensor of `sys` (its name and quantity) with noise `noise`.
pub(crate) fn sensor_channels(sys: &HbSystem, noise: Noise) -> Vec<Channel> {
    sensor_channels_with(sys, &vec![noise; sys.sensors().len()])
}

/// The channels of `sys`'s sensors, sensor `c` with `noise[c]` (`noise` as long as the
/// sensors).
pub(crate) fn sensor_channels_with(sys: &HbSystem, noise: &[Noise]) -> Vec<Channel> {
    sys.sensors()
        .iter()
        .zip(noise)
        .map(|(s, &noise)| Channel {
            name: s.name.clone(),
            quantity: s.quantity,
            noise,
        })
        .collect()
}

/// Seeded standard normal draws (ChaCha8 and the Box–Muller transform): the noise of every
/// synthetic test, reproducible from its seed on any machine.
#[derive(Debug, Clone)]
pub struct Gaussian(ChaCha8Rng);

impl Gaussian {
    /// The stream of seed `seed`.
    pub fn new(seed: u64) -> Self {
        Self(ChaCha8Rng::seed_from_u64(seed))
    }

    /// The next draw of `N(0, 1)`.
    pub fn sample(&mut self) -> f64 {
        let u1: f64 = 1.0 - self.0.random::<f64>();
        let u2: f64 = self.0.random::<f64>();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }
}

/// The quantity's unit, as text.
pub fn unit(q: Quantity) -> &'static str {
    match q {
        Quantity::Displacement => "m",
        Quantity::Velocity => "m/s",
        Quantity::Acceleration => "m/s²",
    }
}
