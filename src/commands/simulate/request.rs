//! The request of `nlsim simulate`: duration, sample rate, method, drives, tolerances;
//! checked before the run (sampling against the excitation's frequencies included).
use crate::commands::setup::Lanczos;
use crate::error::{Error, Result};
use nlsim_sim::Signal;

/// Time integration methods.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Method {
    /// Exponential first-order hold with nonlinear feedback (the fast method).
    Foh,
    /// Zero-order hold (bias studies).
    Zoh,
    /// Lagrange second-order hold (bias studies).
    Lsoh,
    /// Dormand-Prince RK45 with ODE45's error control on the reduced model.
    Rk45,
    /// Classic RK4 on the reduced model.
    Rk4,
    /// Newmark average acceleration with Newton on the unreduced model.
    Newmark,
    /// HHT-alpha with Newton on the unreduced model.
    Hht,
}

impl Method {
    /// Lower-case name, as on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Foh => "foh",
            Method::Zoh => "zoh",
            Method::Lsoh => "lsoh",
            Method::Rk45 => "rk45",
            Method::Rk4 => "rk4",
            Method::Newmark => "newmark",
            Method::Hht => "hht",
        }
    }

    /// Parses [`Method::as_str`].
    pub fn parse(s: &str) -> Option<Self> {
        use Method::*;
        [Foh, Zoh, Lsoh, Rk45, Rk4, Newmark, Hht]
            .into_iter()
            .find(|m| m.as_str() == s)
    }

    /// Whether the method integrates the unreduced sparse model.
    pub fn unreduced(self) -> bool {
        matches!(self, Method::Newmark | Method::Hht)
    }
}

/// What drives the excitation points of a simulation: a signal on one point or on all.
#[derive(Debug, Clone, PartialEq)]
pub struct Drive {
    /// The excitation point's name; `None` drives every point.
    pub point: Option<String>,
    /// The force (N); per unit of each point's nominal amplitude when `nominal`.
    pub signal: Signal,
    /// Scale `signal` by the point's nominal amplitude (a spec that gave no amplitude).
    pub nominal: bool,
    /// How reports and result files name the drive (the spec it was parsed from).
    pub label: String,
}

impl Drive {
    /// `signal` (N) on every excitation point.
    pub fn all(signal: Signal) -> Self {
        Self {
            point: None,
            label: crate::formats::excitation::describe_signal(&signal),
            signal,
            nominal: false,
        }
    }

    /// `signal` (N) on excitation point `name`.
    pub fn at(name: impl Into<String>, signal: Signal) -> Self {
        Self {
            point: Some(name.into()),
            ..Self::all(signal)
        }
    }

    /// Parses `SPEC` (every point) or `NAME=SPEC` (one point) in the grammar of
    /// [`crate::formats::excitation::parse_excitation`]; a sweep without `duration` lasts `duration_s`,
    /// a force file without `rate` is sampled at `rate_hz`.
    pub fn parse(text: &str, duration_s: f64, rate_hz: f64) -> Result<Self> {
        let (point, spec) = match text
            .split_once('=')
            .filter(|(n, _)| !n.contains(':') && !n.contains(','))
        {
            Some((name, spec)) => (Some(name.to_string()), spec),
            None => (None, text),
        };
        let (signal, nominal) =
            crate::formats::excitation::parse_signal(spec, 1.0, duration_s, rate_hz)?;
        Ok(Self {
            point,
            signal,
            nominal,
            label: spec.to_string(),
        })
    }
}

/// A time response to compute (the options of `nlsim simulate`).
#[derive(Debug, Clone)]
pub struct SimRequest {
    /// Simulated time (s).
    pub duration: f64,
    /// Sample rate (Hz).
    pub rate: f64,
    /// Integration method.
    pub method: Method,
    /// Drives in order (a later one replaces an earlier one on the points it names); a point
    /// no drive names gets a sine at the first natural frequency of its nominal amplitude.
    pub excitation: Vec<Drive>,
    /// Retained modes (reduced methods).
    pub modes: usize,
    /// Residual flexibility of the truncated modes.
    pub residual: bool,
    /// Locate contact events inside steps (FOH).
    pub events: bool,
    /// RK45 relative tolerance.
    pub rtol: f64,
    /// RK45 absolute tolerance on the modal states (√kg m); `None` scales it to the response
    /// (see [`nlsim_sim::auto_atol`]).
    pub atol: Option<f64>,
    /// Integration steps per sample (RK4, Newmark, HHT).
    pub substeps: usize,
    /// HHT α in `[−1/3, 0]`.
    pub hht_alpha: f64,
    /// Parallelism of the reduction (faer's `Par`; `Par::rayon(0)` uses the current pool).
    pub par: faer::Par,
    /// Lanczos settings of the reduction.
    pub lanczos: Lanczos,
}

impl Default for SimRequest {
    fn default() -> Self {
        Self {
            duration: 0.0,
            rate: 0.0,
            method: Method::Foh,
            excitation: Vec::new(),
            modes: 20,
            residual: true,
            events: true,
            rtol: 1e-3,
            atol: None,
            substeps: 1,
            hht_alpha: -0.05,
            par: faer::Par::rayon(0),
            lanczos: Lanczos::default(),
        }
    }
}

impl SimRequest {
    /// Checks the values that do not need the model and returns the number of steps.
    pub fn check(&self) -> Result<usize> {
        let usage = |m: String| Error::Usage(format!("simulation request: {m}"));
        if !(self.duration > 0.0 && self.duration.is_finite()) {
            return Err(usage(format!(
                "duration {} must be a positive number of seconds",
                self.duration
            )));
        }
        if !(self.rate > 0.0 && self.rate.is_finite()) {
            return Err(usage(format!(
                "rate {} must be a positive frequency in Hz",
                self.rate
            )));
        }
        if self.modes == 0 {
            return Err(usage("modes must be at least 1".into()));
        }
        let n_steps = (self.duration * self.rate).round() as usize;
        if n_steps == 0 || n_steps > 200_000_000 {
            return Err(usage(format!(
                "duration x rate gives {n_steps} steps; it must be between 1 and 2e8"
            )));
        }
        for d in &self.excitation {
            crate::formats::excitation::nyquist_check(&d.label, &d.signal, self.rate)?;
        }
        Ok(n_steps)
    }

    /// Notes on drives that stop before the run ends (a force file shorter than the run: the
    /// force is zero after its last sample, as for a hammer blow).
    pub fn notes(&self) -> Vec<String> {
        self.excitation
            .iter()
            .filter_map(|d| match &d.signal {
                Signal::Sampled { rate_hz, values } => {
                    let end = values.len().saturating_sub(1) as f64 / rate_hz;
                    (end < self.duration - 0.5 / self.rate).then(|| {
                        format!(
                            "note: the force '{}' ends at {end} s ({} samples at {rate_hz} Hz) \
                             and is zero for the rest of the {} s run",
                            d.label,
                            values.len(),
                            self.duration
                        )
                    })
                }
                _ => None,
            })
            .collect()
    }
}

/// Where `nlsim simulate` writes.
#[derive(Debug, Clone, Default)]
pub struct SimOutputs {
    /// The history file (`.h5` or `.csv`).
    pub out: Option<std::path::PathBuf>,
    /// The report folder.
    pub report: Option<std::path::PathBuf>,
    /// Whether HDF5 datasets are compressed (shuffle + deflate).
    pub compress: bool,
}

impl SimOutputs {
    /// Refuses an unknown output format before the run.
    pub fn check(&self) -> Result<()> {
        if let Some(path) = &self.out {
            crate::formats::files::Format::of_any(path, crate::formats::history_file::HINT, true)?;
        }
        Ok(())
    }
}
