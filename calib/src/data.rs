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

/// What a test recorded at its drive point.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Drive {
    /// The force on the structure (N), from a force gauge: what the model is driven with,
    /// times the input gain (1 unless set or calibrated).
    #[default]
    Force,
    /// A voltage (V): the signal sent to the shaker's amplifier, when no force gauge was
    /// fitted. The model is driven with the input gain times it — the gain in N/V when the
    /// shaker counts as a force source, or in V at the coil per recorded volt when the
    /// calibration models the shaker ([`crate::Shaker`]).
    Voltage,
}

impl Drive {
    /// `force` or `voltage`.
    pub fn as_str(self) -> &'static str {
        match self {
            Drive::Force => "force",
            Drive::Voltage => "voltage",
        }
    }

    /// The recorded unit: `N` or `V`.
    pub fn unit(self) -> &'static str {
        match self {
            Drive::Force => "N",
            Drive::Voltage => "V",
        }
    }

    /// The drive of a name (`force`, `voltage`), if it is one.
    pub fn parse(name: &str) -> Option<Self> {
        match name {
            "force" => Some(Drive::Force),
            "voltage" => Some(Drive::Voltage),
            _ => None,
        }
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
    /// Measured drive harmonics `k = 1..=H` at the drive point, index `k − 1`: the force (N)
    /// or, for [`Drive::Voltage`] data, the voltage (V).
    pub force: Vec<c64>,
    /// Measured response harmonics: channels (rows) × `k = 1..=H` (columns), in each
    /// channel's unit; NaN where a harmonic was not measured.
    pub response: Mat<c64>,
    /// Measured standard deviations of the response harmonics, channels × `k = 1..=H` like
    /// `response`: the real part of each entry is the standard deviation of the harmonic's
    /// real part, the imaginary part that of its imaginary part (the channel's unit), e.g.
    /// the scatter over the periods of the dwell. NaN where the channel's [`Noise`] model
    /// applies; empty (0 × 0) when the data give none.
    pub sigma: Mat<c64>,
}

impl Step {
    /// The standard deviations `(σ_re, σ_im)` of the real and imaginary parts of channel
    /// `c`'s harmonic `k` (1-based) measured as `y`: the step's own where it gives them,
    /// otherwise `noise` of `y` for both.
    pub fn sigma_parts(&self, c: usize, k: usize, y: c64, noise: &Noise) -> (f64, f64) {
        if c < self.sigma.nrows() && k >= 1 && k <= self.sigma.ncols() {
            let s = self.sigma[(c, k - 1)];
            if !s.re.is_nan() {
                return (s.re, s.im);
            }
        }
        let s = noise.sigma(y);
        (s, s)
    }
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
    /// What was recorded at the drive point: force or voltage.
    pub drive: Drive,
    /// Response channels.
    pub channels: Vec<Channel>,
    /// Harmonics `H` held per step (1 = fundamental only).
    pub harmonics: usize,
    /// The sweeps.
    pub sweeps: Vec<Sweep>,
}

/// Largest step frequency test data may hold (Hz): far above any structural test, and low
/// enough that `Ω` and its harmonics stay finite in every product the residuals form.
pub const MAX_FREQUENCY_HZ: f64 = 1e9;

/// Largest force or response amplitude test data may hold (SI units: N, m, m/s, m/s²):
/// no measurement comes near it, and the noise model squares amplitudes
/// (`σ² = σ_abs² + (ε |Y|)²`), which overflows above about 1e154.
pub const MAX_AMPLITUDE: f64 = 1e100;

/// Largest relative noise of a channel (standard deviation over amplitude): beyond 10 a
/// measurement carries no information, and a larger ε only hides a unit mistake. Shared by
/// test data, virtual tests and planning.
pub const MAX_RELATIVE_NOISE: f64 = 10.0;

/// Why a sweep label or channel name cannot be written into test data and read back, if it
/// cannot: empty, or holding a comma, a quote, a `#` or a control character (the CSV
/// layout splits cells at commas and reads `#` lines as header), or longer than 200 bytes.
pub fn label_fault(label: &str) -> Option<String> {
    if label.trim().is_empty() {
        return Some("is empty".into());
    }
    if label.trim() != label {
        return Some(format!("'{label}' starts or ends with a space"));
    }
    if label.len() > 200 {
        return Some(format!("is {} bytes long (at most 200)", label.len()));
    }
    if let Some(c) = label
        .chars()
        .find(|&c| c == ',' || c == '"' || c == '#' || c.is_control())
    {
        return Some(format!(
            "'{}' holds {:?}, which the CSV layout of test data cannot hold",
            label.escape_default(),
            c
        ));
    }
    None
}

/// A point of the data: sweep index and step index within it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct PointId {
    /// Sweep index.
    pub sweep: usize,
    /// Step index within the sweep (in measured order).
    pub step: usize,
}

/// The largest fundamental amplitude `|Y_1|` of each of `channels` channels over
/// `responses` (each channels × harmonics, harmonic 1 in column 0; non-finite entries,
/// unmeasured ones, ignored): the scale of each channel's noise floor.
pub fn fundamental_peaks<'a>(
    channels: usize,
    responses: impl IntoIterator<Item = &'a Mat<c64>>,
) -> Vec<f64> {
    let mut peaks = vec![0.0f64; channels];
    for y in responses {
        for (c, p) in peaks.iter_mut().enumerate() {
            let a = y[(c, 0)].norm();
            if a.is_finite() {
                *p = p.max(a);
            }
        }
    }
    peaks
}

impl TestData {
    /// Each channel's largest measured fundamental amplitude over every step
    /// ([`fundamental_peaks`]).
    pub fn fundamental_peaks(&self) -> Vec<f64> {
        fundamental_peaks(
            self.channels.len(),
            self.sweeps
                .iter()
                .flat_map(|s| &s.steps)
                .map(|st| &st.response),
        )
    }

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
        if let Some(why) = label_fault(&self.input) {
            return bad("test data input".into(), format!("name {why}"));
        }
        // First index of each name: duplicates found in one pass (10⁴ channels are allowed).
        let mut first: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
        for (i, c) in self.channels.iter().enumerate() {
            if let Some(&j) = first.get(c.name.as_str()) {
                return bad(
                    format!("test data channel {} ('{}')", i + 1, c.name),
                    format!(
                        "has the name of channel {}: each channel is named once",
                        j + 1
                    ),
                );
            }
            if let Some(why) = label_fault(&c.name) {
                return bad(
                    format!("test data channel {}", i + 1),
                    format!("name {why}"),
                );
            }
            first.insert(c.name.as_str(), i);
            let n = c.noise;
            let ok = |v: f64, max: f64| v.is_finite() && v >= 0.0 && v <= max;
            if !ok(n.absolute, MAX_AMPLITUDE) || !ok(n.relative, MAX_RELATIVE_NOISE) {
                return bad(
                    format!("test data channel '{}'", c.name),
                    format!(
                        "noise must be finite and non-negative, absolute at most \
                         {MAX_AMPLITUDE:e} and relative at most {MAX_RELATIVE_NOISE} \
                         (absolute {:e}, relative {:e})",
                        n.absolute, n.relative
                    ),
                );
            }
        }
        let mut first: std::collections::HashMap<&str, usize> = std::collections::HashMap::new();
        for (s, sw) in self.sweeps.iter().enumerate() {
            if let Some(why) = label_fault(&sw.label) {
                return bad(format!("test data sweep {}", s + 1), format!("label {why}"));
            }
            if let Some(&t) = first.get(sw.label.as_str()) {
                return bad(
                    format!("test data sweep {} ('{}')", s + 1, sw.label),
                    format!(
                        "has the label of sweep {}: each sweep (level, run) is labelled once",
                        t + 1
                    ),
                );
            }
            first.insert(sw.label.as_str(), s);
            let at =
                |i: usize| format!("test data sweep {} ('{}') step {}", s + 1, sw.label, i + 1);
            let value = |i: usize, c: usize, k: usize| {
                format!(
                    "{}, channel '{}', harmonic {}",
                    at(i),
                    self.channels[c].name,
                    k + 1
                )
            };
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
                        format!("frequency {:e} Hz is not positive", st.frequency_hz),
                    );
                }
                if st.frequency_hz > MAX_FREQUENCY_HZ {
                    return bad(
                        at(i),
                        format!(
                            "frequency {:e} Hz is above {MAX_FREQUENCY_HZ:e} Hz (is the column in Hz?)",
                            st.frequency_hz
                        ),
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
                if st.sigma.nrows() * st.sigma.ncols() > 0
                    && (st.sigma.nrows() != self.channels.len()
                        || st.sigma.ncols() != self.harmonics)
                {
                    return bad(
                        at(i),
                        format!(
                            "holds {}×{} standard deviations for {}×{} responses",
                            st.sigma.nrows(),
                            st.sigma.ncols(),
                            self.channels.len(),
                            self.harmonics
                        ),
                    );
                }
                for c in 0..st.sigma.nrows() {
                    for k in 0..st.sigma.ncols() {
                        let v = st.sigma[(c, k)];
                        let ok = (v.re.is_nan() && v.im.is_nan())
                            || (v.re > 0.0
                                && v.im > 0.0
                                && v.re <= MAX_AMPLITUDE
                                && v.im <= MAX_AMPLITUDE);
                        if !ok {
                            return bad(
                                value(i, c, k),
                                format!(
                                    "standard deviations ({:e}, {:e}) of the real and imaginary \
                                     parts must both be positive and finite (or both empty: the \
                                     channel's noise model)",
                                    v.re, v.im
                                ),
                            );
                        }
                    }
                }
                if st
                    .force
                    .iter()
                    .any(|f| !(f.re.is_finite() && f.im.is_finite()))
                {
                    return bad(at(i), "force is not finite".into());
                }
                if let Some(k) = st.force.iter().position(|f| f.norm() > MAX_AMPLITUDE) {
                    return bad(
                        at(i),
                        format!(
                            "force harmonic {} of {:e} N is above {MAX_AMPLITUDE:e} (no measured force is; is the unit right?)",
                            k + 1,
                            st.force[k].norm()
                        ),
                    );
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
                                value(i, c, k),
                                "response is not finite (use NaN + NaN i for a harmonic not measured)".into(),
                            );
                        }
                        if y.norm() > MAX_AMPLITUDE {
                            return bad(
                                value(i, c, k),
                                format!(
                                    "response of {:e} is above {MAX_AMPLITUDE:e} (no measured response is in SI units; is the unit right?)",
                                    y.norm()
                                ),
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

    /// [`validate`](Self::validate), and at least one response harmonic measured (not NaN):
    /// what a file of test data must hold (the readers and writers check it; a prediction
    /// template, all NaN, passes `validate` alone).
    pub fn validate_measured(&self) -> Result<()> {
        self.validate()?;
        let measured = self.sweeps.iter().any(|sw| {
            sw.steps.iter().any(|st| {
                (0..st.response.nrows())
                    .any(|c| (0..st.response.ncols()).any(|k| !st.response[(c, k)].re.is_nan()))
            })
        });
        if measured {
            Ok(())
        } else {
            Err(Error::invalid(
                "test data",
                "holds no measured response (every response cell is empty or NaN)",
            ))
        }
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
                        sigma: if st.sigma.nrows() == 0 {
                            Mat::new()
                        } else {
                            Mat::from_fn(idx.len(), st.sigma.ncols(), |r, k| st.sigma[(idx[r], k)])
                        },
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
