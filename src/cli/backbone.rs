//! `nlsim backbone`: its arguments and their request.

use crate::commands;
use crate::commands::backbone::{BackboneRequest, Source};
use crate::present::console::Console;
use clap::Args;
use nlsim_calib::backbone::{DecayConfig, ResonanceConfig};
use nlsim_kernel::Quantity;

/// What a decay's channels measure.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum QuantityArg {
    /// m.
    Displacement,
    /// m/s.
    Velocity,
    /// m/s².
    Acceleration,
}

impl From<QuantityArg> for Quantity {
    fn from(q: QuantityArg) -> Self {
        match q {
            QuantityArg::Displacement => Quantity::Displacement,
            QuantityArg::Velocity => Quantity::Velocity,
            QuantityArg::Acceleration => Quantity::Acceleration,
        }
    }
}

/// The arguments of `nlsim backbone`.
#[derive(Args, Debug)]
pub struct BackboneArgs {
    /// Time records of a free decay (with --decay: CSV with a time column, HDF5 or universal
    /// file datasets 58), or stepped-sine test data (any layout `nlsim calibrate` reads; one
    /// level per sweep).
    input: std::path::PathBuf,
    /// The input holds free decays (ring-downs) in time records.
    #[arg(long)]
    decay: bool,
    /// The response: a record column (--decay; repeat it with --shape to combine several
    /// sensors into the mode's coordinate) or the test data's channel.
    #[arg(long)]
    channel: Vec<String>,
    /// --decay: the mode's shape at each --channel, in order (weights of the modal signal
    /// Σ w y / Σ w²).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    shape: Vec<f64>,
    /// --decay: what the channel measures (for the displacement column; default: unstated).
    #[arg(long, value_enum)]
    quantity: Option<QuantityArg>,
    /// --decay: the mode's frequency (Hz) the band pass is centred on (default: the
    /// record's largest spectral peak).
    #[arg(long)]
    frequency: Option<f64>,
    /// --decay: relative half-width b of the band pass f(1 ± b).
    #[arg(long, default_value_t = 0.3)]
    band: f64,
    /// --decay: window length in periods.
    #[arg(long, default_value_t = 8.0)]
    window_periods: f64,
    /// --decay: hop between windows in periods.
    #[arg(long, default_value_t = 4.0)]
    step_periods: f64,
    /// --decay: smallest amplitude kept, in multiples of the in-band noise.
    #[arg(long, default_value_t = 10.0)]
    min_snr: f64,
    /// --decay: where the decay starts (s, the records' clock; default: at the envelope's
    /// largest value).
    #[arg(long)]
    start: Option<f64>,
    /// Stepped sines: the sweeps (levels) taken, by label or pattern (`force-*`;
    /// repeatable; default all).
    #[arg(long)]
    sweeps: Vec<String>,
    /// Stepped sines: added to every response phase (degrees), e.g. 180 for acceleration
    /// amplitudes recorded with a displacement's phase.
    #[arg(long, default_value_t = 0.0, allow_negative_numbers = true)]
    phase_offset_deg: f64,
    /// Stepped sines: the modal constant φ_s φ_d (1/kg) of the mode at the sensor and the
    /// drive, for the energy-balance damping (default: the mean of the level fits).
    #[arg(long)]
    modal_constant: Option<f64>,
    /// Stepped sines: steps each side of the −90° crossing in its local lines.
    #[arg(long, default_value_t = 2)]
    neighbours: usize,
    /// The table written: .csv or .h5.
    #[arg(long)]
    out: Option<std::path::PathBuf>,
    /// Plot of the frequency against the amplitude, FILE.svg or .png (default: beside
    /// --out); the damping ratio in FILE-damping.svg.
    #[arg(long)]
    plot: Option<std::path::PathBuf>,
}

impl BackboneArgs {
    /// The request of `nlsim backbone`; a usage error for options of the other kind.
    pub fn request(&self) -> crate::Result<BackboneRequest> {
        let usage = |m: &str| crate::Error::Usage(format!("backbone: {m}"));
        let source = if self.decay {
            if !self.sweeps.is_empty() || self.modal_constant.is_some() {
                return Err(usage(
                    "--sweeps and --modal-constant are for stepped sines, not --decay",
                ));
            }
            Source::Decay {
                channels: self.channel.clone(),
                shape: self.shape.clone(),
                quantity: self.quantity.map(Into::into),
                config: DecayConfig {
                    frequency_hz: self.frequency,
                    band: self.band,
                    filter_order: 4,
                    window_periods: self.window_periods,
                    step_periods: self.step_periods,
                    min_snr: self.min_snr,
                    start_s: self.start,
                },
            }
        } else {
            if !self.shape.is_empty() || self.frequency.is_some() || self.start.is_some() {
                return Err(usage(
                    "--shape, --frequency and --start are for free decays: add --decay",
                ));
            }
            if self.channel.len() > 1 {
                return Err(usage("stepped sines take one --channel"));
            }
            Source::Stepped {
                channel: self.channel.first().cloned(),
                sweeps: self.sweeps.clone(),
                phase_offset_deg: self.phase_offset_deg,
                config: ResonanceConfig {
                    quantity: Quantity::Acceleration,
                    modal_constant: self.modal_constant,
                    neighbours: self.neighbours,
                },
            }
        };
        Ok(BackboneRequest {
            input: self.input.clone(),
            source,
            out: self.out.clone(),
            plot: self.plot.clone(),
        })
    }

    /// `nlsim backbone`.
    pub fn execute(&self, console: &Console) -> crate::Result<()> {
        commands::backbone::execute(&self.request()?, console)
    }
}
