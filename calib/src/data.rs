//! Stepped-sine test data (thesis §4.1, eq. 14): per frequency step the measured complex
//! harmonics of the force at the drive point and of the response at every sensor channel.
//!
//! Conventions: a harmonic `k` of excitation frequency `Ω` has complex amplitude `Z` with
//! `z(t) = Re(Z e^{ikΩt})`; force and responses share one time origin (so only their
//! relative phase matters). The measured force is what the calibration applies to the model
//! at each step, not the nominal level: a shaker's force drops near resonance.
//!
//! The file formats (CSV, HDF5, Universal File Format 58) are read by the `nlsim` facade into
//! these types; this module only holds and checks them.

use faer::{Mat, c64};
use nlsim_kernel::{Error, Quantity, Result};

/// The order in which the steps of a sweep were measured: a stepped sine starts each step
/// from the state of the previous one, so a jump happens where the sweep direction puts it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SweepDirection {
    /// Increasing frequency.
    Up,
    /// Decreasing frequency.
    Down,
}

impl SweepDirection {
    /// `up` or `down`.
    pub fn as_str(self) -> &'static str {
        match self {
            SweepDirection::Up => "up",
            SweepDirection::Down => "down",
        }
    }
}

/// The noise model of a channel: standard deviation `σ = √(σ_abs² + (ε |Y|)²)` of each
/// complex harmonic amplitude `Y` (per real and imaginary part), in the channel's unit.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Noise {
    /// Absolute part `σ_abs` (the channel's unit: m, m/s or m/s²).
    pub absolute: f64,
    /// Relative part `ε` (fraction of the amplitude).
    pub relative: f64,
}

impl Noise {
    /// Relative noise only (`ε`, e.g. 0.01 for 1 %).
    pub fn relative(eps: f64) -> Self {
        Self {
            absolute: 0.0,
            relative: eps,
        }
    }

    /// The standard deviation for a measured amplitude `y`.
    pub fn sigma(&self, y: c64) -> f64 {
        let r = self.relative * y.norm();
        (self.absolute * self.absolute + r * r).sqrt()
    }
}

/// A response channel.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    /// The channel's name: the sensor of the model it is compared with.
    pub name: String,
    /// What it measures.
    pub quantity: Quantity,
    /// Its noise model.
    pub noise: Noise,
}

/// One frequency step.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    /// Excitation frequency `Ω/2π` (Hz).
    pub frequency_hz: f64,
    /// Measured force harmonics `k = 1..=H` at the drive point (N), index `k − 1`.
    pub force: Vec<c64>,
    /// Measured response harmonics: channels (rows) × `k = 1..=H` (columns), in each
    /// channel's unit; NaN where a harmonic was not measured.
    pub response: Mat<c64>,
}

/// One stepped-sine sweep (one excitation level or one test run).
#[derive(Debug, Clone, PartialEq)]
pub struct Sweep {
    /// Its label (`force-1`, `5 m/s²`, …).
    pub label: String,
    /// The order the steps were measured in.
    pub direction: SweepDirection,
    /// The steps, in the order measured.
    pub steps: Vec<Step>,
}

/// A stepped-sine test: one drive point, several response channels, several sweeps.
#[derive(Debug, Clone, PartialEq)]
pub struct TestData {
    /// Name of the drive point: the model input it is compared with.
    pub input: String,
    /// Response channels.
    pub channels: Vec<Channel>,
    /// Harmonics `H` held per step (1 = fundamental only).
    pub harmonics: usize,
    /// The sweeps.
    pub sweeps: Vec<Sweep>,
}

/// A point of the data: sweep index and step index within it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct PointId {
    /// Sweep index.
    pub sweep: usize,
    /// Step index within the sweep (in measured order).
    pub step: usize,
}

impl TestData {
    /// Checks the data: at least one sweep, step and channel, positive finite frequencies,
    /// finite forces with a non-zero fundamental, the declared dimensions, non-negative
    /// finite noise, and frequencies monotone in each sweep's direction. Errors name the
    /// sweep, step and channel.
    pub fn validate(&self) -> Result<()> {
        let bad = |what: String, why: String| Err(Error::invalid(what, why));
        if self.channels.is_empty() || self.sweeps.is_empty() || self.harmonics == 0 {
            return bad(
                "test data".into(),
                "needs at least one channel, one sweep and one harmonic".into(),
            );
        }
        for c in &self.channels {
            let n = c.noise;
            let ok = |v: f64| v.is_finite() && v >= 0.0;
            if !ok(n.absolute) || !ok(n.relative) {
                return bad(
                    format!("test data channel '{}'", c.name),
                    format!(
                        "noise must be finite and non-negative (absolute {}, relative {})",
                        n.absolute, n.relative
                    ),
                );
            }
        }
        for (s, sw) in self.sweeps.iter().enumerate() {
            let at =
                |i: usize| format!("test data sweep {} ('{}') step {}", s + 1, sw.label, i + 1);
            if sw.steps.is_empty() {
                return bad(
                    format!("test data sweep {} ('{}')", s + 1, sw.label),
                    "has no steps".into(),
                );
            }
            for (i, st) in sw.steps.iter().enumerate() {
                if !(st.frequency_hz.is_finite() && st.frequency_hz > 0.0) {
                    return bad(
                        at(i),
                        format!("frequency {} Hz is not positive", st.frequency_hz),
                    );
                }
                if st.force.len() != self.harmonics
                    || st.response.nrows() != self.channels.len()
                    || st.response.ncols() != self.harmonics
                {
                    return bad(
                        at(i),
                        format!(
                            "holds {} force harmonics and {}×{} responses; the test declares {} harmonics and {} channels",
                            st.force.len(),
                            st.response.nrows(),
                            st.response.ncols(),
                            self.harmonics,
                            self.channels.len()
                        ),
                    );
                }
                if st
                    .force
                    .iter()
                    .any(|f| !(f.re.is_finite() && f.im.is_finite()))
                {
                    return bad(at(i), "force is not finite".into());
                }
                if st.force[0].norm() == 0.0 {
                    return bad(at(i), "the fundamental force is zero".into());
                }
                for c in 0..self.channels.len() {
                    for k in 0..self.harmonics {
                        let y = st.response[(c, k)];
                        if y.re.is_infinite()
                            || y.im.is_infinite()
                            || (y.re.is_nan() != y.im.is_nan())
                        {
                            return bad(
                                format!("{}, channel '{}', harmonic {}", at(i), self.channels[c].name, k + 1),
                                "response is not finite (use NaN + NaN i for a harmonic not measured)".into(),
                            );
                        }
                    }
                }
                if i > 0 {
                    let prev = sw.steps[i - 1].frequency_hz;
                    let ok = match sw.direction {
                        SweepDirection::Up => st.frequency_hz > prev,
                        SweepDirection::Down => st.frequency_hz < prev,
                    };
                    if !ok {
                        return bad(
                            at(i),
                            format!(
                                "frequency {} Hz after {} Hz does not follow the sweep direction '{}'",
                                st.frequency_hz,
                                prev,
                                sw.direction.as_str()
                            ),
                        );
                    }
                }
            }
        }
        Ok(())
    }

    /// Every point, sweep by sweep in measured order.
    pub fn points(&self) -> Vec<PointId> {
        self.sweeps
            .iter()
            .enumerate()
            .flat_map(|(s, sw)| (0..sw.steps.len()).map(move |i| PointId { sweep: s, step: i }))
            .collect()
    }

    /// Number of points (steps over all sweeps).
    pub fn n_points(&self) -> usize {
        self.sweeps.iter().map(|s| s.steps.len()).sum()
    }

    /// The step of a point.
    pub fn step(&self, p: PointId) -> &Step {
        &self.sweeps[p.sweep].steps[p.step]
    }

    /// The same test with only the sweeps `keep` (by index, in that order).
    pub fn select_sweeps(&self, keep: &[usize]) -> Result<TestData> {
        let mut sweeps = Vec::with_capacity(keep.len());
        for &s in keep {
            sweeps.push(
                self.sweeps
                    .get(s)
                    .ok_or_else(|| {
                        Error::invalid(
                            "test data",
                            format!("no sweep {} (it has {})", s + 1, self.sweeps.len()),
                        )
                    })?
                    .clone(),
            );
        }
        Ok(TestData {
            sweeps,
            ..self.clone()
        })
    }

    /// The same test with only the channels named in `keep` (in that order): what a test
    /// that recorded only those sensors would hold. Errors name a channel that is not in
    /// the data or is named twice.
    pub fn select_channels(&self, keep: &[&str]) -> Result<TestData> {
        let mut idx = Vec::with_capacity(keep.len());
        for name in keep {
            let i = self
                .channels
                .iter()
                .position(|c| c.name == *name)
                .ok_or_else(|| {
                    let have: Vec<&str> = self.channels.iter().map(|c| c.name.as_str()).collect();
                    Error::invalid(
                        "test data",
                        format!("no channel '{name}' (it has {})", have.join(", ")),
                    )
                })?;
            if idx.contains(&i) {
                return Err(Error::invalid(
                    "test data",
                    format!("channel '{name}' is named twice"),
                ));
            }
            idx.push(i);
        }
        if idx.is_empty() {
            return Err(Error::invalid("test data", "keep at least one channel"));
        }
        let sweeps = self
            .sweeps
            .iter()
            .map(|sw| Sweep {
                steps: sw
                    .steps
                    .iter()
                    .map(|st| Step {
                        response: Mat::from_fn(idx.len(), st.response.ncols(), |r, k| {
                            st.response[(idx[r], k)]
                        }),
                        ..st.clone()
                    })
                    .collect(),
                ..sw.clone()
            })
            .collect();
        Ok(TestData {
            channels: idx.iter().map(|&i| self.channels[i].clone()).collect(),
            sweeps,
            ..self.clone()
        })
    }
}
