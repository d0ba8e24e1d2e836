//! The request of `nlsim frf`: range, harmonics, forcing, sweep mode, start, retained modes;
//! checked before the (possibly long) run.
use crate::commands::setup::Lanczos;
use crate::error::{Error, Result};
use crate::present::frf_plot::Magnitude;
use nlsim_hb::HarmonicSet;

/// How an FRF is swept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum SweepMode {
    /// Pseudo-arclength continuation: every branch through the folds, stability per point.
    Continuation,
    /// Stepped sine upwards, each point from the last (jumps down past the upper fold).
    StepUp,
    /// Stepped sine downwards (jumps up past the lower fold).
    StepDown,
}

impl SweepMode {
    /// `continuation`, `step-up` or `step-down`.
    pub fn as_str(self) -> &'static str {
        match self {
            SweepMode::Continuation => "continuation",
            SweepMode::StepUp => "step-up",
            SweepMode::StepDown => "step-down",
        }
    }

    /// Parses [`SweepMode::as_str`].
    pub fn parse(s: &str) -> Option<Self> {
        [Self::Continuation, Self::StepUp, Self::StepDown]
            .into_iter()
            .find(|m| m.as_str() == s)
    }
}

/// Most points of one FRF (a stepped sweep's steps, a continuation's points).
pub const MAX_FRF_POINTS: usize = 1_000_000;

/// Most harmonics `H` of one FRF.
pub const MAX_FRF_HARMONICS: usize = 256;

/// Parses a force harmonic `K=AMP[@DEG]` or `1/K=AMP[@DEG]` (`--force-harmonic`): `AMP cos(K
/// Ω t + DEG)`, the cosine convention of `docs/model-files.md`.
pub fn parse_force_harmonic(text: &str) -> Result<nlsim_kernel::ForceHarmonic> {
    let usage = |m: String| Error::Usage(format!("force harmonic '{text}': {m}"));
    let (order, value) = text
        .split_once('=')
        .ok_or_else(|| usage("expected K=AMP[@DEG], e.g. 2=1.5 or 3=2@90".into()))?;
    let (numerator, denominator) =
        nlsim_kernel::ForceHarmonic::parse_ratio(order).map_err(usage)?;
    let (amp, deg) = match value.split_once('@') {
        Some((a, d)) => (a, Some(d)),
        None => (value, None),
    };
    let num = |what: &str, v: &str| -> Result<f64> {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| usage(format!("{what} '{v}' is not a finite number")))
    };
    let amplitude = num("amplitude", amp)?;
    let phase = deg.map(|d| num("phase", d)).transpose()?.unwrap_or(0.0);
    if numerator == denominator {
        return Err(usage(
            "order 1 is the fundamental: set it with --force (the phase reference)".into(),
        ));
    }
    Ok(nlsim_kernel::ForceHarmonic {
        numerator,
        denominator,
        amplitude,
        phase: phase.to_radians(),
    })
}

/// Frequencies of a stepped sine when the request gives no point count.
pub const DEFAULT_STEPS: usize = 400;

/// Frequencies searched for a sub-harmonic start (evenly over the range).
pub const SUBHARMONIC_SEARCH: usize = 41;

/// How an FRF continuation starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrfStart {
    /// From rest at the start frequency, or, with a sub-harmonic order `ν ≥ 2`, from a
    /// sub-harmonic solution searched over the range (the primary branch from rest when
    /// none is found, with a note).
    #[default]
    Auto,
    /// From rest at the start frequency (the primary branch).
    Rest,
    /// From a sub-harmonic solution searched over the range; an error when none is found.
    Subharmonic,
}

impl FrfStart {
    /// Parses `auto`, `rest` or `subharmonic`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "auto" => Some(Self::Auto),
            "rest" => Some(Self::Rest),
            "subharmonic" => Some(Self::Subharmonic),
            _ => None,
        }
    }

    /// The name of [`FrfStart::parse`].
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Rest => "rest",
            Self::Subharmonic => "subharmonic",
        }
    }
}

/// A continuation start read from an earlier `nlsim frf` HDF5 file (`--start-file`): a
/// solution point whose branch the continuation follows through the range, e.g. an isolated
/// sub-harmonic branch found once, or a branch to redo with more harmonics.
#[derive(Debug, Clone, PartialEq)]
pub struct StartFile {
    /// The file (written by `nlsim frf --out FILE.h5`).
    pub path: std::path::PathBuf,
    /// The file's point nearest this fundamental frequency (Hz) is taken. `None`: among the
    /// points within the range, the one with the most sub-harmonic content (harmonics of
    /// `Ω/ν` that are not harmonics of `Ω`) when `ν ≥ 2`, otherwise the largest response.
    pub at_hz: Option<f64>,
}

/// A multi-harmonic FRF to compute (the options of `nlsim frf`).
#[derive(Debug, Clone)]
pub struct FrfRequest {
    /// Start frequency (Hz).
    pub from_hz: f64,
    /// End frequency (Hz).
    pub to_hz: f64,
    /// Harmonics `H` of the base frequency `Ω/ν`.
    pub harmonics: usize,
    /// Sub-harmonic order `ν`.
    pub subharmonic: usize,
    /// Force amplitude (N) at the fundamental on every excitation point; `None`: the model's
    /// nominal amplitudes.
    pub force: Option<f64>,
    /// Further force harmonics on every excitation point, replacing the model's
    /// `[[excitation.harmonic]]` when not empty (cosine convention, `docs/model-files.md`).
    pub force_harmonics: Vec<nlsim_kernel::ForceHarmonic>,
    /// Continuation or stepped sine.
    pub mode: SweepMode,
    /// Frequencies of a stepped sine (default [`DEFAULT_STEPS`]); for a continuation, the
    /// fewest points over the range: the step in frequency is at most the range over
    /// `points − 1` (default: the continuation's own step control).
    pub points: Option<usize>,
    /// Largest continuation step in frequency (Hz); `None`: 2 % of the range.
    pub max_step_hz: Option<f64>,
    /// How a continuation starts.
    pub start: FrfStart,
    /// A continuation start from a point of an earlier FRF file instead (`--start-file`).
    pub start_file: Option<StartFile>,
    /// Retained modes.
    pub modes: usize,
    /// Residual flexibility of the truncated modes.
    pub residual: bool,
    /// Hill stability per point.
    pub stability: bool,
    /// Parallelism of the reduction (faer's `Par`; `Par::rayon(0)` uses the current pool).
    pub par: faer::Par,
    /// Lanczos settings of the reduction.
    pub lanczos: Lanczos,
    /// Parameters of the reduced model set after the reduction (`modeN.f`, `modeN.zeta`,
    /// `modeN.m`, `stiffness_scale`), from `--set` ([`crate::commands::setup::apply_sets_deferred`]).
    pub modal_sets: Vec<(nlsim_kernel::Param, f64)>,
}

impl Default for FrfRequest {
    fn default() -> Self {
        Self {
            from_hz: 0.0,
            to_hz: 0.0,
            harmonics: 7,
            subharmonic: 1,
            force: None,
            force_harmonics: Vec::new(),
            mode: SweepMode::Continuation,
            points: None,
            max_step_hz: None,
            start: FrfStart::Auto,
            start_file: None,
            modes: 20,
            residual: true,
            stability: true,
            par: faer::Par::rayon(0),
            lanczos: Lanczos::default(),
            modal_sets: Vec::new(),
        }
    }
}

impl FrfRequest {
    /// Checks the values that do not need the model; errors are usage errors naming the
    /// request field.
    pub fn check(&self) -> Result<HarmonicSet> {
        let usage = |m: String| Error::Usage(format!("FRF request: {m}"));
        for (what, v) in [("from_hz", self.from_hz), ("to_hz", self.to_hz)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(usage(format!(
                    "{what} {v} must be a positive frequency in Hz"
                )));
            }
        }
        if self.from_hz == self.to_hz {
            return Err(usage("from_hz and to_hz are equal".into()));
        }
        let upward = self.from_hz < self.to_hz;
        match self.mode {
            SweepMode::StepUp if !upward => {
                return Err(usage(format!(
                    "a step-up sweep goes up, but from_hz {} is above to_hz {} (swap them, or \
                     step down)",
                    self.from_hz, self.to_hz
                )));
            }
            SweepMode::StepDown if upward => {
                return Err(usage(format!(
                    "a step-down sweep goes down, but from_hz {} is below to_hz {} (swap them, \
                     or step up)",
                    self.from_hz, self.to_hz
                )));
            }
            _ => {}
        }
        if let Some(p) = self.points
            && !(2..=MAX_FRF_POINTS).contains(&p)
        {
            return Err(usage(format!(
                "points {p} must be from 2 to {MAX_FRF_POINTS} (each point keeps its solution)"
            )));
        }
        if let Some(h) = self.max_step_hz {
            if !(h > 0.0 && h.is_finite()) {
                return Err(usage(format!(
                    "max_step_hz {h} must be a positive frequency step in Hz"
                )));
            }
            let needed = (self.to_hz - self.from_hz).abs() / h;
            if needed > MAX_FRF_POINTS as f64 {
                return Err(usage(format!(
                    "max_step_hz {h} over {} Hz needs {needed:.3e} points, more than \
                     {MAX_FRF_POINTS}",
                    (self.to_hz - self.from_hz).abs()
                )));
            }
        }
        if self.mode != SweepMode::Continuation
            && (self.max_step_hz.is_some() || self.start != FrfStart::Auto)
        {
            return Err(usage(format!(
                "max_step_hz and start apply to a continuation, not to a {} sweep (its \
                 frequencies are the points)",
                self.mode.as_str()
            )));
        }
        if let Some(sf) = &self.start_file {
            if self.mode != SweepMode::Continuation {
                return Err(usage(format!(
                    "a start file ({}) starts a continuation; a {} sweep starts every \
                     frequency from the last (drop one of them)",
                    sf.path.display(),
                    self.mode.as_str()
                )));
            }
            if self.start != FrfStart::Auto {
                return Err(usage(format!(
                    "start = {} and a start file ({}) are two starts: give one",
                    self.start.as_str(),
                    sf.path.display()
                )));
            }
            if let Some(hz) = sf.at_hz {
                let (lo, hi) = (self.from_hz.min(self.to_hz), self.from_hz.max(self.to_hz));
                if !(hz >= lo && hz <= hi) {
                    return Err(usage(format!(
                        "start frequency {hz} Hz is outside the range {lo} to {hi} Hz"
                    )));
                }
            }
        }
        if self.start == FrfStart::Subharmonic && self.subharmonic < 2 {
            return Err(usage(
                "a sub-harmonic start needs a sub-harmonic order of at least 2".into(),
            ));
        }
        if self.harmonics > MAX_FRF_HARMONICS {
            return Err(usage(format!(
                "harmonics {} is more than {MAX_FRF_HARMONICS} (the Jacobian and the AFT grow \
                 as H²; contact rarely needs more than 50)",
                self.harmonics
            )));
        }
        if self.modes == 0 {
            return Err(usage("modes must be at least 1".into()));
        }
        if let Some(f) = self.force
            && !f.is_finite()
        {
            return Err(usage(format!("force {f} is not a finite number")));
        }
        HarmonicSet::new(self.harmonics, self.subharmonic)
            .map_err(|e| usage(format!("harmonics/subharmonic: {e}")))
    }
}

/// Where `nlsim frf` writes and how it plots.
#[derive(Debug, Clone, Default)]
pub struct FrfOutputs {
    /// The FRF file (`.h5` or `.csv`).
    pub out: Option<std::path::PathBuf>,
    /// The plot (`.svg` or `.png`); default: beside `out` as `.svg`.
    pub plot: Option<std::path::PathBuf>,
    /// The magnitude axis of the plot.
    pub magnitude: Magnitude,
    /// Whether the plot has phase panels.
    pub phase: bool,
    /// The report folder.
    pub report: Option<std::path::PathBuf>,
}

impl FrfOutputs {
    /// The plot's path: the given one, else beside the FRF file as `.svg`.
    pub fn plot_path(&self) -> Option<std::path::PathBuf> {
        self.plot
            .clone()
            .or_else(|| self.out.as_ref().map(|p| p.with_extension("svg")))
    }

    /// Refuses unknown output formats before the (possibly long) solve.
    pub fn check(&self) -> Result<()> {
        if let Some(path) = &self.out {
            crate::formats::files::Format::of_any(path, crate::formats::frf_file::HINT, true)?;
        }
        if let Some(p) = self.plot_path() {
            crate::present::plot::check_path(&p)?;
        }
        Ok(())
    }
}
