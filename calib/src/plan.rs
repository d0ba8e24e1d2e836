//! Pre-test planning by Fisher information (thesis §4.3–4.4, paper V): where to drive, where
//! to measure, at which level, over which band and with which measured harmonics, decided
//! before the test from the model alone.
//!
//! For a candidate test the Fisher information matrix is `F = Jᵀ Σ⁻¹ J + F_prior`, `J` the
//! derivatives of the measured complex harmonics (real and imaginary parts) with respect to
//! the relative parameter changes `p/p₀` (so `F` is free of units and `F⁻¹` holds squared
//! relative standard deviations), `Σ` the noise model evaluated on the predicted responses.
//! `J` comes from the analytic harmonic balance sensitivities along the predicted stepped
//! sine — the very Jacobian the calibration of the test data will use — never from finite
//! differences.
//!
//! Because every measured (channel, harmonic) adds its own term to `F`, one stepped-sine
//! simulation per (exciter, band) serves every sensor set and every choice of measured
//! harmonics: [`SweepInformation`] holds these terms; [`rank_designs`] sums them for each
//! candidate design in parallel and ranks the designs by a [`Criterion`];
//! [`greedy_placement`] chooses sensors among thousands of candidates by a greedy pass and
//! exchange passes on the D-criterion (in the spirit of Kammer's effective independence, on
//! the parameters' information instead of the mode shapes'); [`dof_information`] gives the
//! terms of every DOF of a large reduced model from its mode shapes.

use crate::data::{Channel, Noise, Step, Sweep, SweepDirection, TestData};
use crate::lhs::Spacing;
use crate::linalg::Svd;
use crate::objective::{BranchChoice, Form, FrfObjective, ObjectiveConfig, ParamSpec, solve_step};
use faer::{Mat, MatRef, c64};
use nlsim_hb::{ForceTerm, Forcing, HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Error, Model, Param, Parameterized, Quantity, Result, Status};
use nlsim_reduction::ReductionConfig;
use rayon::prelude::*;
use std::f64::consts::PI;
use std::sync::Arc;

/// How designs are ranked; every criterion is turned into a score where higher is better.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Criterion {
    /// D-optimality: `ln det F` (the volume of the confidence ellipsoid shrinks).
    D,
    /// T-optimality: `tr F`.
    T,
    /// A-optimality: `tr F⁻¹` (the sum of the relative variances), minimised.
    A,
    /// E-optimality: `λ_min(F)` (the worst direction), maximised.
    E,
    /// The thesis criterion: the largest diagonal entry of `F⁻¹` (the worst parameter's
    /// relative variance), minimised.
    MaxVariance,
}

impl Criterion {
    /// Every criterion, in the order of the report.
    pub const ALL: [Criterion; 5] = [
        Criterion::D,
        Criterion::T,
        Criterion::A,
        Criterion::E,
        Criterion::MaxVariance,
    ];

    /// The name used in plan files and reports: `D`, `T`, `A`, `E`, `max-variance`.
    pub fn as_str(self) -> &'static str {
        match self {
            Criterion::D => "D",
            Criterion::T => "T",
            Criterion::A => "A",
            Criterion::E => "E",
            Criterion::MaxVariance => "max-variance",
        }
    }

    /// Reads a name of [`Criterion::as_str`] (case-insensitive).
    pub fn parse(s: &str) -> Result<Self> {
        Criterion::ALL
            .into_iter()
            .find(|c| c.as_str().eq_ignore_ascii_case(s.trim()))
            .ok_or_else(|| {
                Error::invalid(
                    format!("planning criterion '{s}'"),
                    "expected D, T, A, E or max-variance",
                )
            })
    }
}

/// Eigenvalues of `F` below this fraction of the largest are taken as zero: a relative
/// sensitivity that is 10⁻⁶ of the strongest one is no information (the Jacobian `J`
/// behind `F` is known to ~10⁻⁸ relative at best).
const RANK_TOL: f64 = 1e-12;

/// What a Fisher information matrix says about the parameters it describes.
#[derive(Debug, Clone, PartialEq)]
pub struct FimSummary {
    /// `ln det F` (−∞ when rank deficient).
    pub log_det: f64,
    /// `tr F`.
    pub trace: f64,
    /// `tr F⁻¹` (∞ when rank deficient).
    pub trace_inverse: f64,
    /// `λ_min(F)`.
    pub min_eigenvalue: f64,
    /// `max_j (F⁻¹)_jj` (∞ when rank deficient).
    pub max_variance: f64,
    /// Numerical rank (eigenvalues above 10⁻¹² of the largest).
    pub rank: usize,
    /// Cramér–Rao relative standard deviations `√(F⁻¹)_jj` per parameter (∞ for a parameter
    /// in an unidentifiable direction).
    pub std: Vec<f64>,
    /// Collinearity index `γ = 1/√λ_min(F̂)` of the information with unit diagonal
    /// (Brun et al. 2001; as [`crate::CramerRao::collinearity`]): 1 for orthogonal
    /// sensitivities, above about 15 the parameters cannot be told apart, ∞ when a
    /// parameter has no sensitivity at all.
    pub collinearity: f64,
    /// The most nearly collinear pair of parameters and the cosine of the angle between
    /// their sensitivity vectors (`F̂_ij`; ±1 when they act identically).
    pub most_collinear: Option<(usize, usize, f64)>,
}

impl FimSummary {
    /// The summary of a symmetric positive semi-definite `fim` (relative units).
    pub fn new(fim: &Mat<f64>) -> Self {
        let n = fim.nrows();
        let svd = Svd::new(fim);
        // For a symmetric PSD matrix the singular values are the eigenvalues.
        let lmax = svd.s.iter().fold(0.0f64, |a, &b| a.max(b));
        let rank = svd
            .s
            .iter()
            .filter(|&&l| l > RANK_TOL * lmax && l > 0.0)
            .count();
        let full = rank == n && n > 0;
        let log_det = if full {
            svd.s.iter().map(|l| l.ln()).sum()
        } else {
            f64::NEG_INFINITY
        };
        let trace = (0..n).map(|i| fim[(i, i)]).sum();
        let min_eigenvalue = if full {
            svd.s.iter().fold(f64::INFINITY, |a, &b| a.min(b))
        } else {
            0.0
        };
        let inv = pseudo_inverse(&svd, lmax);
        let std: Vec<f64> = (0..n).map(|j| inv[(j, j)].sqrt()).collect();
        let trace_inverse = (0..n).map(|j| inv[(j, j)]).sum();
        let max_variance = (0..n).fold(0.0f64, |a, j| a.max(inv[(j, j)]));
        let d: Vec<f64> = (0..n).map(|i| fim[(i, i)].max(0.0).sqrt()).collect();
        let (collinearity, most_collinear) = if d.contains(&0.0) {
            (f64::INFINITY, None)
        } else {
            let fh = Mat::from_fn(n, n, |i, j| fim[(i, j)] / (d[i] * d[j]));
            let lmin = Svd::new(&fh).s.iter().fold(f64::INFINITY, |a, &b| a.min(b));
            let gamma = if lmin > RANK_TOL {
                1.0 / lmin.sqrt()
            } else {
                f64::INFINITY
            };
            let mut pair: Option<(usize, usize, f64)> = None;
            for i in 0..n {
                for j in i + 1..n {
                    let c = fh[(i, j)];
                    if pair.is_none_or(|(_, _, b)| c.abs() > b.abs()) {
                        pair = Some((i, j, c));
                    }
                }
            }
            (gamma, pair)
        };
        Self {
            log_det,
            trace,
            trace_inverse: if full { trace_inverse } else { f64::INFINITY },
            min_eigenvalue,
            max_variance: if full { max_variance } else { f64::INFINITY },
            rank,
            std,
            collinearity,
            most_collinear,
        }
    }

    /// The score of `criterion` (higher is better).
    pub fn score(&self, criterion: Criterion) -> f64 {
        match criterion {
            Criterion::D => self.log_det,
            Criterion::T => self.trace,
            Criterion::A => -self.trace_inverse,
            Criterion::E => self.min_eigenvalue,
            Criterion::MaxVariance => -self.max_variance,
        }
    }

    /// The value of `criterion` as reported (`ln det`, `tr`, `tr F⁻¹`, `λ_min`, max variance).
    pub fn value(&self, criterion: Criterion) -> f64 {
        match criterion {
            Criterion::D => self.log_det,
            Criterion::T => self.trace,
            Criterion::A => self.trace_inverse,
            Criterion::E => self.min_eigenvalue,
            Criterion::MaxVariance => self.max_variance,
        }
    }
}

/// `F⁺` of a symmetric PSD matrix from its SVD, infinite on the diagonal of every parameter
/// a null direction touches.
fn pseudo_inverse(svd: &Svd, lmax: f64) -> Mat<f64> {
    let n = svd.s.len();
    let mut out = Mat::<f64>::zeros(n, n);
    for k in 0..n {
        if svd.s[k] <= RANK_TOL * lmax || svd.s[k] == 0.0 {
            for i in 0..n {
                if svd.v[(i, k)].abs() > 1e-8 {
                    out[(i, i)] = f64::INFINITY;
                }
            }
            continue;
        }
        let w = 1.0 / svd.s[k];
        for i in 0..n {
            for j in 0..n {
                if out[(i, i)].is_finite() || i != j {
                    out[(i, j)] += svd.v[(i, k)] * w * svd.v[(j, k)];
                }
            }
        }
    }
    out
}

/// A side tone of a multi-sine excitation (thesis eq. 12): harmonic `harmonic` of the
/// excitation frequency with amplitude `fraction` of the fundamental's and phase `phase`
/// (rad).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SideTone {
    /// Harmonic `k ≥ 2` of the excitation frequency.
    pub harmonic: usize,
    /// Amplitude as a fraction of the fundamental force amplitude.
    pub fraction: f64,
    /// Phase (rad) relative to the fundamental.
    pub phase: f64,
}

/// How the structure is driven in a candidate test.
#[derive(Debug, Clone, PartialEq)]
pub struct Exciter {
    /// The drive point: an input of the system.
    pub input: String,
    /// Fundamental force amplitude (N).
    pub level: f64,
    /// Side tones (empty: a pure sine).
    pub side: Vec<SideTone>,
}

impl Exciter {
    /// A pure sine of `level` N at input `input`.
    pub fn sine(input: impl Into<String>, level: f64) -> Self {
        Self {
            input: input.into(),
            level,
            side: Vec::new(),
        }
    }

    /// Force harmonics `k = 1..=h` (N) of one step.
    fn force(&self, h: usize) -> Vec<c64> {
        let mut f = vec![c64::new(0.0, 0.0); h];
        f[0] = c64::new(self.level, 0.0);
        for t in &self.side {
            if t.harmonic <= h {
                f[t.harmonic - 1] += c64::from_polar(t.fraction * self.level, t.phase);
            }
        }
        f
    }

    /// A short description: `tip 0.2 N` or `tip 0.2 N + 3×(5 %)`.
    pub fn describe(&self) -> String {
        let mut s = format!("{} {} N", self.input, self.level);
        for t in &self.side {
            s.push_str(&format!(" + {}x({:.3} %)", t.harmonic, 100.0 * t.fraction));
        }
        s
    }
}

/// The frequency band of a candidate stepped sine: `steps` equally spaced frequencies from
/// `from_hz` to `to_hz`, in that order (a downward sweep when `to_hz < from_hz`).
#[derive(Debug, Clone, PartialEq)]
pub struct Band {
    /// Name in reports.
    pub label: String,
    /// First frequency (Hz).
    pub from_hz: f64,
    /// Last frequency (Hz).
    pub to_hz: f64,
    /// Number of steps (≥ 2).
    pub steps: usize,
}

impl Band {
    /// The frequencies in measured order (Hz).
    pub fn frequencies_hz(&self) -> Vec<f64> {
        (0..self.steps)
            .map(|i| {
                self.from_hz + (self.to_hz - self.from_hz) * i as f64 / (self.steps - 1) as f64
            })
            .collect()
    }

    fn check(&self) -> Result<()> {
        if !(self.from_hz > 0.0
            && self.to_hz > 0.0
            && self.from_hz.is_finite()
            && self.to_hz.is_finite())
            || self.from_hz == self.to_hz
            || self.steps < 2
        {
            return Err(Error::invalid(
                format!("planning band '{}'", self.label),
                format!(
                    "needs two distinct positive frequencies and at least 2 steps (got {} to {} \
                     Hz in {} steps)",
                    self.from_hz, self.to_hz, self.steps
                ),
            ));
        }
        Ok(())
    }
}

/// The information one predicted stepped sine carries, per measured channel and harmonic.
#[derive(Debug, Clone)]
pub struct SweepInformation {
    /// The excitation.
    pub exciter: Exciter,
    /// The band.
    pub band: Band,
    /// The candidate channels (the system's sensors, in its order).
    pub channels: Vec<String>,
    /// The harmonics the terms are given for.
    pub harmonics: Vec<usize>,
    /// `terms[c][h]`: the information (parameters × parameters, relative units) of channel
    /// `c` measured at harmonic `harmonics[h]` over the whole band.
    pub terms: Vec<Vec<Mat<f64>>>,
    /// The predicted responses (channels × harmonics `1..=max`) at each step, noise-free.
    pub responses: Vec<Mat<c64>>,
    /// Frequencies (Hz) where the predicted harmonic balance did not converge: they add no
    /// information (a test there would need other settings).
    pub failed_hz: Vec<f64>,
}

impl SweepInformation {
    /// The names of `design`'s channels (its indices into [`SweepInformation::channels`]).
    pub fn channel_names(&self, design: &Design) -> Vec<&str> {
        design
            .channels
            .iter()
            .map(|&c| self.channels[c].as_str())
            .collect()
    }

    /// The harmonic numbers `k` `design` measures (its indices into
    /// [`SweepInformation::harmonics`]).
    pub fn harmonic_numbers(&self, design: &Design) -> Vec<usize> {
        design
            .harmonics
            .iter()
            .map(|&h| self.harmonics[h])
            .collect()
    }

    /// `F = F_prior + Σ_{c ∈ channels} Σ_{h ∈ harmonics} terms[c][h]` (indices into
    /// [`SweepInformation::channels`] and [`SweepInformation::harmonics`]).
    pub fn fim(
        &self,
        channels: &[usize],
        harmonics: &[usize],
        prior: Option<&Mat<f64>>,
    ) -> Mat<f64> {
        let n = self.terms[0][0].nrows();
        let mut f = prior.cloned().unwrap_or_else(|| Mat::zeros(n, n));
        for &c in channels {
            for &h in harmonics {
                f += &self.terms[c][h];
            }
        }
        f
    }
}

/// The system and parameters a test is planned for, at their nominal values.
#[derive(Debug, Clone)]
pub struct Planner {
    prototype: FrfObjective,
    nominal: Vec<f64>,
    params: Vec<Param>,
}

/// Specs whose internal variables are the relative changes `ln(p/p₀)` (positive nominal),
/// or `p/|p₀|` (negative nominal), or `p` (zero nominal): the objective's Jacobian is then
/// in relative units.
fn relative_specs(params: &[Param], nominal: &[f64]) -> Vec<ParamSpec> {
    params
        .iter()
        .zip(nominal)
        .map(|(p, &v)| {
            if v > 0.0 {
                ParamSpec {
                    param: p.clone(),
                    lower: v / 10.0,
                    upper: v * 10.0,
                    spacing: Spacing::Log,
                }
            } else {
                let s = if v == 0.0 { 1.0 } else { v.abs() };
                ParamSpec {
                    param: p.clone(),
                    lower: -s,
                    upper: s,
                    spacing: Spacing::Linear,
                }
            }
        })
        .collect()
}

/// Test data of `channels` driven at `input`, one step at 1 Hz, responses unknown.
fn template(channels: Vec<Channel>, input: &str, harmonics: usize) -> TestData {
    let nan = c64::new(f64::NAN, f64::NAN);
    TestData {
        input: input.into(),
        drive: crate::data::Drive::Force,
        harmonics,
        sweeps: vec![Sweep {
            label: "template".into(),
            direction: SweepDirection::Up,
            steps: vec![Step {
                frequency_hz: 1.0,
                force: (0..harmonics)
                    .map(|k| c64::new(if k == 0 { 1.0 } else { 0.0 }, 0.0))
                    .collect(),
                response: Mat::from_fn(channels.len(), harmonics, |_, _| nan),
                sigma: Mat::new(),
            }],
        }],
        channels,
    }
}

/// The nominal values of `params`: a gain of the test data ([`Param::is_gain`]) at 1 (the
/// sensor or force gauge reads as calibrated), any other from `value`.
fn nominal_values(params: &[Param], value: impl Fn(&Param) -> Result<f64>) -> Result<Vec<f64>> {
    params
        .iter()
        .map(|p| if p.is_gain() { Ok(1.0) } else { value(p) })
        .collect()
}

impl Planner {
    /// A planner for `params` of `sys` (element law parameters, `modeN.f`, `modeN.zeta`, ...)
    /// at their current values; gains of the test data (`input_gain`, `sensor_gain:NAME`
    /// of a candidate sensor) at 1, planned as calibrated along: a sensor gain is identified
    /// only by designs that measure its sensor. The system's sensors are the candidate channels and its
    /// inputs the candidate drive points. Errors as [`FrfObjective::new`] does.
    pub fn new(sys: &HbSystem, params: &[Param]) -> Result<Self> {
        let nominal = nominal_values(params, |p| sys.param(p))?;
        let input = first_input(sys)?;
        let prototype = FrfObjective::new(
            sys,
            Arc::new(template(
                crate::synthetic::sensor_channels(sys, Noise::relative(0.01)),
                &input,
                1,
            )),
            relative_specs(params, &nominal),
            ObjectiveConfig::default(),
        )?;
        Ok(Self {
            prototype,
            nominal,
            params: params.to_vec(),
        })
    }

    /// A planner on `model` reduced by `reduction`: as [`Planner::new`], and the parameters
    /// may be FE-level ones (group scales, boundary springs; see
    /// [`FrfObjective::from_model`]). Planning evaluates at the nominal values only, so their
    /// parametric reduced model is the nominal basis with its derivative directions, without
    /// training: one full reduction, and the sensitivities from the projected matrices.
    pub fn from_model(
        model: &Model,
        reduction: &ReductionConfig,
        set: HarmonicSet,
        hb: HbConfig,
        params: &[Param],
    ) -> Result<Self> {
        let Ok(nominal) = nominal_values(params, |p| model.param(p)) else {
            // Parameters of the reduced model (modal ones), which FE-level ones cannot join:
            // the planner of the reduced system.
            let red = nlsim_reduction::reduce(model, reduction)?;
            return Self::new(&HbSystem::from_model(model, &red, set, hb)?, params);
        };
        let input = model
            .excitation()
            .first()
            .map(|e| e.name.clone())
            .ok_or_else(|| Error::invalid("planning", "the model has no excitation to drive"))?;
        let channels = model
            .sensors()
            .iter()
            .map(|s| Channel {
                name: s.name.clone(),
                quantity: s.quantity,
                noise: Noise::relative(0.01),
            })
            .collect();
        let prototype = FrfObjective::from_model_with(
            model,
            reduction,
            &crate::objective::FeReduction::Parametric(nlsim_reduction::ParametricConfig {
                max_training: 0,
                ..nlsim_reduction::ParametricConfig::default()
            }),
            set,
            hb,
            Arc::new(template(channels, &input, 1)),
            relative_specs(params, &nominal),
            ObjectiveConfig::default(),
        )?;
        Ok(Self {
            prototype,
            nominal,
            params: params.to_vec(),
        })
    }

    /// The parameters planned for.
    pub fn params(&self) -> &[Param] {
        &self.params
    }

    /// Their nominal values.
    pub fn nominal(&self) -> &[f64] {
        &self.nominal
    }

    /// The harmonic balance system (sensors: candidate channels; inputs: drive points).
    pub fn system(&self) -> &HbSystem {
        self.prototype.system()
    }

    /// The information of the stepped sine `band` driven by `exciter`, with the channel noise
    /// `noise` (which needs an absolute floor: a relative noise alone would make a harmonic
    /// the model predicts as nearly zero infinitely informative), for the measured
    /// `harmonics` (of the excitation frequency, each at most the system's `H`).
    ///
    /// The predicted test is simulated as the calibration will simulate the real one (the
    /// sweep followed in its direction, the measured force harmonics applied), and the
    /// information is that calibration's `JᵀJ` at the nominal parameters.
    pub fn sweep_information(
        &self,
        exciter: &Exciter,
        band: &Band,
        noise: Noise,
        harmonics: &[usize],
    ) -> Result<SweepInformation> {
        let per_channel = vec![noise; self.system().sensors().len()];
        self.sweep_information_with(exciter, band, &per_channel, harmonics)
    }

    /// [`Planner::sweep_information`] with a noise model per channel (`noise[c]` for the
    /// system's sensor `c`), e.g. floors in each sensor's own scale from
    /// [`Planner::response_peaks`].
    pub fn sweep_information_with(
        &self,
        exciter: &Exciter,
        band: &Band,
        noise: &[Noise],
        harmonics: &[usize],
    ) -> Result<SweepInformation> {
        band.check()?;
        let sensors = self.system().sensors();
        if noise.len() != sensors.len() {
            return Err(Error::invalid(
                "planning noise",
                format!(
                    "{} noise models given for {} channels",
                    noise.len(),
                    sensors.len()
                ),
            ));
        }
        for (n, sen) in noise.iter().zip(sensors) {
            if !(n.absolute > 0.0 && n.absolute.is_finite() && n.relative >= 0.0) {
                return Err(Error::invalid(
                    format!("planning noise of channel '{}'", sen.name),
                    format!(
                        "needs a positive absolute floor (got absolute {}, relative {}): \
                         without it a harmonic the model predicts as nearly zero would weigh \
                         without bound",
                        n.absolute, n.relative
                    ),
                ));
            }
        }
        if !(exciter.level.is_finite() && exciter.level > 0.0) {
            return Err(Error::invalid(
                format!("exciter at '{}'", exciter.input),
                format!("the force level must be positive, not {}", exciter.level),
            ));
        }
        let h_sys = self.system().harmonics().h;
        if harmonics.is_empty() {
            return Err(Error::invalid("planning", "no measured harmonics"));
        }
        for t in &exciter.side {
            if t.harmonic < 2 || t.harmonic > h_sys || !t.fraction.is_finite() {
                return Err(Error::invalid(
                    format!("side tone of the exciter at '{}'", exciter.input),
                    format!(
                        "harmonic {} must be from 2 to the harmonic balance's H = {h_sys}, with a \
                         finite amplitude",
                        t.harmonic
                    ),
                ));
            }
        }
        let (mut data, config, responses, failed_hz) =
            self.predict(exciter, band, noise, harmonics)?;
        for (st, y) in data.sweeps[0].steps.iter_mut().zip(&responses) {
            if !failed_hz.contains(&st.frequency_hz) {
                st.response = y.clone();
            }
        }
        let mut obj = self.prototype.with_data(Arc::new(data.clone()), config)?;
        let ev = obj.evaluate_values(&self.nominal, None, true)?;
        let jac = ev.jacobian.expect("asked for");
        let n = self.params.len();
        let nc = data.channels.len();
        let mut terms = vec![vec![Mat::<f64>::zeros(n, n); harmonics.len()]; nc];
        let mut row = 0usize;
        for pr in &ev.points {
            if pr.status != Status::Converged {
                continue;
            }
            let st = &data.sweeps[0].steps[pr.id.step];
            for (c, term) in terms.iter_mut().enumerate() {
                for (h, &k) in harmonics.iter().enumerate() {
                    if st.response[(c, k - 1)].re.is_nan() {
                        continue;
                    }
                    for r in row..row + 2 {
                        for a in 0..n {
                            for b in 0..n {
                                term[h][(a, b)] += jac[(r, a)] * jac[(r, b)];
                            }
                        }
                    }
                    row += 2;
                }
            }
        }
        debug_assert_eq!(row, jac.nrows());
        Ok(SweepInformation {
            exciter: exciter.clone(),
            band: band.clone(),
            channels: data.channels.iter().map(|c| c.name.clone()).collect(),
            harmonics: harmonics.to_vec(),
            terms,
            responses,
            failed_hz,
        })
    }
}

impl Planner {
    /// The noise-free predicted test of `band` driven by `exciter`: its template data
    /// (channels with `noise`, responses unknown), the objective settings for `harmonics`,
    /// the predicted responses per step (channels × harmonics `1..=max`) and the frequencies
    /// (Hz) where the harmonic balance failed.
    #[allow(clippy::type_complexity)]
    fn predict(
        &self,
        exciter: &Exciter,
        band: &Band,
        noise: &[Noise],
        harmonics: &[usize],
    ) -> Result<(TestData, ObjectiveConfig, Vec<Mat<c64>>, Vec<f64>)> {
        let h_data = harmonics
            .iter()
            .chain(exciter.side.iter().map(|t| &t.harmonic))
            .fold(1, |a, &b| a.max(b));
        let mut data = template(
            crate::synthetic::sensor_channels_with(self.system(), noise),
            &exciter.input,
            h_data,
        );
        let force = exciter.force(h_data);
        let nan = c64::new(f64::NAN, f64::NAN);
        let freqs = band.frequencies_hz();
        data.sweeps = vec![Sweep {
            label: band.label.clone(),
            direction: if band.to_hz > band.from_hz {
                SweepDirection::Up
            } else {
                SweepDirection::Down
            },
            steps: freqs
                .iter()
                .map(|&f| Step {
                    frequency_hz: f,
                    force: force.clone(),
                    response: Mat::from_fn(data.channels.len(), h_data, |_, _| nan),
                    sigma: Mat::new(),
                })
                .collect(),
        }];
        let config = ObjectiveConfig {
            harmonics: harmonics.to_vec(),
            form: Form::Complex,
            branch: BranchChoice::Continuation,
        };
        let mut obj = self
            .prototype
            .with_data(Arc::new(data.clone()), config.clone())?;
        let ev = obj.evaluate_values(&self.nominal, None, false)?;
        let mut failed_hz = Vec::new();
        let mut responses = Vec::with_capacity(freqs.len());
        for pr in &ev.points {
            if pr.status != Status::Converged {
                failed_hz.push(freqs[pr.id.step]);
            }
            responses.push(pr.response.clone());
        }
        Ok((data, config, responses, failed_hz))
    }

    /// The largest predicted fundamental amplitude `|Y_1|` of each channel (the sensor's
    /// unit) over the stepped sines `tests` (drive and band each) at the nominal parameters:
    /// the scale a test team sets each sensor's range for, and with it the noise floor in
    /// the sensor's own scale (e.g. 10⁻³ of it, a 60 dB range). Steps where the harmonic
    /// balance fails are left out; a channel no step reaches gets 0.
    pub fn response_peaks(&self, tests: &[(&Exciter, &Band)]) -> Result<Vec<f64>> {
        let nc = self.system().sensors().len();
        let noise = vec![Noise::relative(0.01); nc];
        let mut solved = Vec::new();
        for (exciter, band) in tests {
            band.check()?;
            let (_, _, responses, failed) = self.predict(exciter, band, &noise, &[1])?;
            let freqs = band.frequencies_hz();
            solved.extend(
                responses
                    .into_iter()
                    .zip(&freqs)
                    .filter(|(_, f)| !failed.contains(f))
                    .map(|(y, _)| y),
            );
        }
        Ok(crate::data::fundamental_peaks(nc, &solved))
    }
}

/// Per-channel noise models with floors in each sensor's own scale: `relative` of the
/// response, and an absolute floor of `floor` times the channel's `peaks` entry (from
/// [`Planner::response_peaks`]), or `absolute` where that is larger. A channel with no
/// predicted response keeps `absolute` (which must then be positive to plan).
pub fn scaled_noise(relative: f64, absolute: f64, floor: f64, peaks: &[f64]) -> Vec<Noise> {
    peaks
        .iter()
        .map(|&p| Noise {
            absolute: absolute.max(floor * p),
            relative,
        })
        .collect()
}

fn first_input(sys: &HbSystem) -> Result<String> {
    sys.inputs()
        .first()
        .map(|(n, _)| n.clone())
        .ok_or_else(|| Error::invalid("planning", "the system has no input to drive"))
}

/// One candidate design: a predicted sweep, the channels measured and the harmonics used.
#[derive(Debug, Clone, PartialEq)]
pub struct Design {
    /// Index of the sweep (into the informations given to [`rank_designs`]).
    pub sweep: usize,
    /// Measured channels (indices into [`SweepInformation::channels`]).
    pub channels: Vec<usize>,
    /// Harmonics used (indices into [`SweepInformation::harmonics`]).
    pub harmonics: Vec<usize>,
}

/// A design with its information summary.
#[derive(Debug, Clone, PartialEq)]
pub struct RankedDesign {
    /// The design.
    pub design: Design,
    /// What its information says.
    pub summary: FimSummary,
}

/// Every design of `sweeps × channel_sets × harmonic_sets`, scored in parallel (on the
/// calling rayon pool; the order of the result does not depend on the thread count) and
/// sorted by `criterion`, best first (ties: enumeration order). Sets index into each
/// sweep's channels and harmonics.
pub fn rank_designs(
    sweeps: &[SweepInformation],
    channel_sets: &[Vec<usize>],
    harmonic_sets: &[Vec<usize>],
    prior: Option<&Mat<f64>>,
    criterion: Criterion,
) -> Result<Vec<RankedDesign>> {
    for (i, sw) in sweeps.iter().enumerate() {
        for set in channel_sets {
            if let Some(&c) = set.iter().find(|&&c| c >= sw.channels.len()) {
                return Err(Error::invalid(
                    "planning channel set",
                    format!(
                        "channel {c} does not exist in sweep {i} ({} channels)",
                        sw.channels.len()
                    ),
                ));
            }
        }
        for set in harmonic_sets {
            if let Some(&h) = set.iter().find(|&&h| h >= sw.harmonics.len()) {
                return Err(Error::invalid(
                    "planning harmonic set",
                    format!("harmonic index {h} does not exist in sweep {i}"),
                ));
            }
        }
        if let Some(p) = prior {
            let n = sw.terms[0][0].nrows();
            if p.nrows() != n || p.ncols() != n {
                return Err(Error::DimensionMismatch {
                    what: "prior Fisher information (parameters × parameters)".into(),
                    expected: n * n,
                    found: p.nrows() * p.ncols(),
                });
            }
        }
    }
    let designs: Vec<Design> = (0..sweeps.len())
        .flat_map(|s| {
            channel_sets.iter().flat_map(move |c| {
                harmonic_sets.iter().map(move |h| Design {
                    sweep: s,
                    channels: c.clone(),
                    harmonics: h.clone(),
                })
            })
        })
        .collect();
    let mut ranked: Vec<(usize, RankedDesign)> = designs
        .into_par_iter()
        .enumerate()
        .map(|(i, d)| {
            let f = sweeps[d.sweep].fim(&d.channels, &d.harmonics, prior);
            (
                i,
                RankedDesign {
                    summary: FimSummary::new(&f),
                    design: d,
                },
            )
        })
        .collect();
    ranked.sort_by(|(i, a), (j, b)| {
        b.summary
            .score(criterion)
            .total_cmp(&a.summary.score(criterion))
            .then(i.cmp(j))
    });
    Ok(ranked.into_iter().map(|(_, r)| r).collect())
}

/// Every subset of `0..n` with `k` elements, in lexicographic order.
pub fn subsets(n: usize, k: usize) -> Vec<Vec<usize>> {
    let mut out = Vec::new();
    if k > n {
        return out;
    }
    let mut idx: Vec<usize> = (0..k).collect();
    loop {
        out.push(idx.clone());
        let Some(i) = (0..k).rev().find(|&i| idx[i] != i + n - k) else {
            return out;
        };
        idx[i] += 1;
        for j in i + 1..k {
            idx[j] = idx[j - 1] + 1;
        }
    }
}

/// Sensors chosen by [`greedy_placement`].
#[derive(Debug, Clone, PartialEq)]
pub struct Placement {
    /// The chosen candidates, in the order the greedy pass chose them (exchanges replace in
    /// place).
    pub chosen: Vec<usize>,
    /// `ln det F` of the greedy pass alone.
    pub greedy_log_det: f64,
    /// `ln det F` after the exchange passes.
    pub log_det: f64,
    /// Exchanges made.
    pub exchanges: usize,
    /// Exchange passes run (the last finds no improving exchange unless the limit stopped it).
    pub passes: usize,
    /// [`Status::Converged`], or [`Status::IterationLimit`] when the pass limit stopped the
    /// exchanges.
    pub status: Status,
}

/// `ln det(a)` of a small symmetric matrix by Cholesky; −∞ unless positive definite.
fn log_det_spd(a: &Mat<f64>) -> f64 {
    let n = a.nrows();
    let mut l = a.clone();
    let mut s = 0.0;
    for j in 0..n {
        let mut d = l[(j, j)];
        for k in 0..j {
            d -= l[(j, k)] * l[(j, k)];
        }
        if d <= 0.0 || !d.is_finite() {
            return f64::NEG_INFINITY;
        }
        let d = d.sqrt();
        l[(j, j)] = d;
        s += 2.0 * d.ln();
        for i in j + 1..n {
            let mut v = l[(i, j)];
            for k in 0..j {
                v -= l[(i, k)] * l[(j, k)];
            }
            l[(i, j)] = v / d;
        }
    }
    s
}

/// Chooses `k` of the candidates whose information terms are `terms` (one parameters ×
/// parameters matrix each, e.g. summed over the measured harmonics) to maximise
/// `ln det(F_prior + Σ terms)`: a greedy pass (each step adds the candidate that raises the
/// criterion most; a ridge of 10⁻⁹ of the mean candidate trace lets it start from nothing),
/// then exchange passes (Fedorov) that swap a chosen candidate for an unchosen one while
/// that raises `ln det F`, at most `max_passes` passes. Candidates are scored in parallel on
/// the calling rayon pool; ties go to the lowest index, so the result does not depend on the
/// thread count.
pub fn greedy_placement(
    terms: &[Mat<f64>],
    k: usize,
    prior: Option<&Mat<f64>>,
    max_passes: usize,
) -> Result<Placement> {
    let Some(first) = terms.first() else {
        return Err(Error::invalid("sensor placement", "no candidates"));
    };
    let n = first.nrows();
    if k == 0 || k > terms.len() {
        return Err(Error::invalid(
            "sensor placement",
            format!("cannot choose {k} of {} candidates", terms.len()),
        ));
    }
    if let Some(i) = terms.iter().position(|t| t.nrows() != n || t.ncols() != n) {
        return Err(Error::DimensionMismatch {
            what: format!("information term of candidate {i}"),
            expected: n * n,
            found: terms[i].nrows() * terms[i].ncols(),
        });
    }
    let mean_trace = terms
        .iter()
        .map(|t| (0..n).map(|i| t[(i, i)]).sum::<f64>())
        .sum::<f64>()
        / terms.len() as f64;
    let ridge = 1e-9 * mean_trace / n as f64;
    let mut base = prior.cloned().unwrap_or_else(|| Mat::zeros(n, n));
    for i in 0..n {
        base[(i, i)] += ridge;
    }
    // Best candidate by score, lowest index on ties (a parallel reduction independent of
    // the split).
    let best = |score: &(dyn Fn(usize) -> f64 + Sync)| -> Option<(usize, f64)> {
        (0..terms.len())
            .into_par_iter()
            .map(|i| (i, score(i)))
            .filter(|(_, s)| !s.is_nan())
            .reduce_with(|a, b| {
                if b.1 > a.1 || (b.1 == a.1 && b.0 < a.0) {
                    b
                } else {
                    a
                }
            })
    };
    let mut chosen: Vec<usize> = Vec::with_capacity(k);
    let mut taken = vec![false; terms.len()];
    let mut f = base.clone();
    for _ in 0..k {
        let (i, _) = best(&|i| {
            if taken[i] {
                f64::NAN
            } else {
                log_det_spd(&(&f + &terms[i]))
            }
        })
        .expect("an unchosen candidate remains");
        chosen.push(i);
        taken[i] = true;
        f += &terms[i];
    }
    let unridged = |f: &Mat<f64>| {
        let mut g = f.clone();
        for i in 0..n {
            g[(i, i)] -= ridge;
        }
        log_det_spd(&g)
    };
    let greedy_log_det = unridged(&f);
    let mut exchanges = 0;
    let mut passes = 0;
    let mut status = Status::Converged;
    loop {
        if passes == max_passes {
            status = Status::IterationLimit;
            break;
        }
        passes += 1;
        let current = log_det_spd(&f);
        let mut improved = false;
        for slot in 0..k {
            let out = chosen[slot];
            let without = &f - &terms[out];
            if let Some((i, v)) = best(&|i| {
                if taken[i] {
                    f64::NAN
                } else {
                    log_det_spd(&(&without + &terms[i]))
                }
            }) && v > current + 1e-12 * current.abs().max(1.0)
            {
                taken[out] = false;
                taken[i] = true;
                chosen[slot] = i;
                f = &without + &terms[i];
                exchanges += 1;
                improved = true;
                break;
            }
        }
        if !improved {
            break;
        }
    }
    Ok(Placement {
        log_det: unridged(&f),
        chosen,
        greedy_log_det,
        exchanges,
        passes,
        status,
    })
}

/// The information terms of every DOF of a reduced model as a candidate sensor, for the
/// stepped sine `band` driven by `exciter` on `sys`: the response at candidate `i` is
/// `Σ_r φ_ir/√m_r η_r` with `shapes` the mass-normalised mode shapes at the candidates
/// (candidates × retained modes, e.g. every row of the reduction's mode matrix), without
/// the residual flexibility of the truncated modes (the mode-displacement approximation;
/// a candidate next to a nonlinear element or the drive point is better planned as a model
/// sensor through [`Planner`]); in the candidates' `quantity`, with `noise` on each.
/// `params` are element parameters, `modeN.f`, `modeN.zeta` or `stiffness_scale`, taken in
/// relative units at their current values. Returns one term per candidate, summed over the
/// band and the measured `harmonics`, and the frequencies where the harmonic balance failed.
/// Candidates are processed in blocks of 4096 rows.
#[allow(clippy::too_many_arguments)]
pub fn dof_information(
    sys: &HbSystem,
    shapes: MatRef<'_, f64>,
    quantity: Quantity,
    exciter: &Exciter,
    band: &Band,
    params: &[Param],
    noise: Noise,
    harmonics: &[usize],
) -> Result<(Vec<Mat<f64>>, Vec<f64>)> {
    band.check()?;
    let m = sys.linear().n_modes();
    if shapes.ncols() != m {
        return Err(Error::DimensionMismatch {
            what: "candidate mode shapes (columns: retained modes)".into(),
            expected: m,
            found: shapes.ncols(),
        });
    }
    if noise.absolute.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return Err(Error::invalid(
            "placement noise",
            "needs a positive absolute floor",
        ));
    }
    let set = sys.harmonics();
    if set.nu != 1 {
        return Err(Error::invalid("placement", "use a harmonic set with ν = 1"));
    }
    if let Some(&k) = harmonics.iter().find(|&&k| k == 0 || k > set.h) {
        return Err(Error::invalid(
            "placement",
            format!("harmonic {k} is outside 1..={}", set.h),
        ));
    }
    let input = sys
        .inputs()
        .iter()
        .position(|(n, _)| n == &exciter.input)
        .ok_or_else(|| {
            Error::invalid(format!("drive point '{}'", exciter.input), "no such input")
        })?;
    let nominal = sys.param_values(params)?;
    let rel: Vec<f64> = nominal
        .iter()
        .map(|v| if *v == 0.0 { 1.0 } else { v.abs() })
        .collect();
    let mut sys = sys.clone();
    let force = exciter.force(set.h);
    sys.set_forcing(Forcing {
        terms: (1..=set.h)
            .filter(|&k| force[k - 1].norm() > 0.0)
            .map(|k| ForceTerm {
                input,
                harmonic: k,
                amplitude: force[k - 1],
            })
            .collect(),
    })?;
    let mut ws = sys.workspace(64 << 20);
    let mass: Vec<f64> = (0..m)
        .map(|r| sys.param(&Param::ModalMass(r)).map(|v| 1.0 / v.sqrt()))
        .collect::<Result<_>>()?;
    // Per converged step and measured harmonic: the modal amplitudes and their relative
    // derivatives (modes × (1 + parameters)), in the candidates' quantity.
    let np = params.len();
    let mut blocks: Vec<Mat<c64>> = Vec::new();
    let mut failed = Vec::new();
    let mut prev: Option<(Vec<f64>, f64)> = None;
    for f in band.frequencies_hz() {
        let omega = 2.0 * PI * f;
        let (x, status) = solve_step(&sys, &mut ws, omega, prev.as_ref())?;
        if !status.is_converged() {
            failed.push(f);
            prev = None;
            continue;
        }
        let sens = sys.sensitivities(&x, omega, 1.0, params)?;
        let deta = sys.modal_sensitivities(&x, omega, 1.0, &sens)?;
        let eta = sys.modal_amplitudes(&x, omega, 1.0);
        for &k in harmonics {
            let iw = c64::new(0.0, k as f64 * omega);
            let q = match quantity {
                Quantity::Displacement => c64::new(1.0, 0.0),
                Quantity::Velocity => iw,
                Quantity::Acceleration => iw * iw,
            };
            blocks.push(Mat::from_fn(m, 1 + np, |r, j| {
                let v = if j == 0 {
                    eta[(r, k)]
                } else {
                    deta[j - 1][(r, k)] * rel[j - 1]
                };
                v * q * mass[r]
            }));
        }
        prev = Some((x, omega));
    }
    let nb = blocks.len();
    let width = nb * (1 + np);
    let bre = Mat::from_fn(m, width, |r, c| blocks[c / (1 + np)][(r, c % (1 + np))].re);
    let bim = Mat::from_fn(m, width, |r, c| blocks[c / (1 + np)][(r, c % (1 + np))].im);
    let ncand = shapes.nrows();
    const BLOCK: usize = 4096;
    let starts: Vec<usize> = (0..ncand).step_by(BLOCK).collect();
    let terms: Vec<Vec<Mat<f64>>> = starts
        .par_iter()
        .map(|&s0| {
            let rows = BLOCK.min(ncand - s0);
            let phi = shapes.subrows(s0, rows);
            let mut yre = Mat::<f64>::zeros(rows, width);
            let mut yim = Mat::<f64>::zeros(rows, width);
            faer::linalg::matmul::matmul(
                yre.as_mut(),
                faer::Accum::Replace,
                phi,
                bre.as_ref(),
                1.0,
                faer::Par::Seq,
            );
            faer::linalg::matmul::matmul(
                yim.as_mut(),
                faer::Accum::Replace,
                phi,
                bim.as_ref(),
                1.0,
                faer::Par::Seq,
            );
            (0..rows)
                .map(|i| {
                    let mut t = Mat::<f64>::zeros(np, np);
                    for b in 0..nb {
                        let c0 = b * (1 + np);
                        let y = c64::new(yre[(i, c0)], yim[(i, c0)]);
                        let s = noise.sigma(y);
                        let w = 1.0 / (s * s);
                        for a in 0..np {
                            for bb in 0..np {
                                t[(a, bb)] += w
                                    * (yre[(i, c0 + 1 + a)] * yre[(i, c0 + 1 + bb)]
                                        + yim[(i, c0 + 1 + a)] * yim[(i, c0 + 1 + bb)]);
                            }
                        }
                    }
                    t
                })
                .collect()
        })
        .collect();
    Ok((terms.into_iter().flatten().collect(), failed))
}
