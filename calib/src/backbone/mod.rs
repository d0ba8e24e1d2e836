//! Amplitude-dependent modal properties of one mode from measured data: the backbone
//! (natural frequency vs amplitude) and the damping ratio vs amplitude that engineers of
//! jointed structures measure instead of a full FRF at every level.
//!
//! - [`decay`]: free decays (ring-downs, the tail after a burst or a shaker cut-off): the
//!   mode isolated by a zero-phase band pass, then per window of a few periods the
//!   instantaneous amplitude, frequency and decay rate by the Hilbert transform and by a
//!   least-squares fit of a decaying sinusoid, each with its standard deviation;
//! - [`resonance`]: stepped sines and phase-resonance (phase-locked-loop) tests: per level
//!   the frequency where the displacement lags the force by 90° and the damping from the
//!   energy balance there, and the level's single-mode fit;
//! - [`virtual_decay`]: the virtual ring-down — the model released from a state of its
//!   nonlinear mode and simulated — whose records the identification reads like a test's.
//!
//! Both give [`BackbonePoint`]s with the same meaning: `ω_n` is the undamped natural
//! frequency of the equivalent linear oscillator at that amplitude and `ζ` its damping
//! ratio — the quantities of a nonlinear mode by the extended periodic motion concept
//! ([`nlsim_hb::nnm`]: `ω` and `ζ = ξ/2ω`), so a measured and a computed backbone are
//! compared point for point. A free decay `e^{−σt} cos ω_d t` gives `ω_n = √(ω_d² + σ²)`,
//! `ζ = σ/ω_n`. Both assume a single mode in the band and light damping; the checks they
//! return name where the data break that.

pub mod decay;
pub mod resonance;
pub mod signal;
pub mod virtual_decay;

pub use decay::{Decay, DecayConfig, identify_decay};
pub use resonance::{
    LevelResult, LevelStep, Resonance, ResonanceConfig, SdofFit, StepLevel, identify_resonance,
};
pub use signal::BandPass;
pub use virtual_decay::{nnm_release_state, virtual_ringdown};

#[cfg(test)]
mod tests;

use faer::Mat;
use nlsim_kernel::Quantity;
use std::f64::consts::PI;

/// One point of a measured backbone.
#[derive(Debug, Clone, PartialEq)]
pub struct BackbonePoint {
    /// Where it comes from: the window's centre time (s) of a free decay, NaN for a level.
    pub time_s: f64,
    /// The level's label (stepped sines), empty for a free decay.
    pub level: String,
    /// Response amplitude of the fundamental in the sensor's unit (m, m/s, m/s², or the
    /// modal coordinate's when sensors were combined by a shape).
    pub amplitude: f64,
    /// Its standard deviation.
    pub amplitude_sigma: f64,
    /// Natural frequency `ω_n/2π` of the equivalent linear oscillator (Hz).
    pub frequency_hz: f64,
    /// Its standard deviation (Hz).
    pub frequency_sigma_hz: f64,
    /// Damping ratio `ζ` (1).
    pub damping_ratio: f64,
    /// Its standard deviation.
    pub damping_sigma: f64,
    /// Force amplitude there (N; NaN for a free decay).
    pub force: f64,
}

impl BackbonePoint {
    /// The amplitude as a displacement (m or the modal unit): the sensor's amplitude divided
    /// by `ω^d`, `d` = 1 for velocity and 2 for acceleration, at the point's frequency.
    pub fn displacement(&self, quantity: Quantity) -> f64 {
        let w = 2.0 * PI * self.frequency_hz;
        match quantity {
            Quantity::Displacement => self.amplitude,
            Quantity::Velocity => self.amplitude / w,
            Quantity::Acceleration => self.amplitude / (w * w),
        }
    }
}

/// `Σ_ij g_i C_ij g_j`: the variance of a function with gradient `g` of estimates with
/// covariance `c` (delta method).
fn propagate(g: &[f64], c: &[Vec<f64>]) -> f64 {
    let mut v = 0.0;
    for (i, gi) in g.iter().enumerate() {
        for (j, gj) in g.iter().enumerate() {
            v += gi * c[i][j] * gj;
        }
    }
    v.max(0.0)
}

/// Solves the small dense system `a x = b` ([`crate::coupling::solve_dense`]); `None` when
/// singular.
fn solve_small(a: &[Vec<f64>], b: &[f64]) -> Option<Vec<f64>> {
    crate::coupling::solve_dense(&Mat::from_fn(b.len(), b.len(), |i, j| a[i][j]), b)
}

/// The inverse of a small dense matrix (one LU factorisation,
/// [`crate::coupling::solve_dense_many`]); `None` when singular.
fn inverse_small(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = a.len();
    let x = crate::coupling::solve_dense_many(
        &Mat::from_fn(n, n, |i, j| a[i][j]),
        Mat::identity(n, n),
    )?;
    Some(
        (0..n)
            .map(|i| (0..n).map(|j| x[(i, j)]).collect())
            .collect(),
    )
}

/// Natural frequency (Hz) and damping ratio of `e^{−σt} cos ω_d t` with their gradients in
/// `(σ, ω_d)`: `ω_n = √(ω_d² + σ²)`, `ζ = σ/ω_n`.
fn natural(sigma: f64, omega_d: f64) -> ((f64, [f64; 2]), (f64, [f64; 2])) {
    let wn = (omega_d * omega_d + sigma * sigma).sqrt();
    let f = wn / (2.0 * PI);
    let gf = [sigma / wn / (2.0 * PI), omega_d / wn / (2.0 * PI)];
    let z = sigma / wn;
    let w3 = wn * wn * wn;
    let gz = [omega_d * omega_d / w3, -sigma * omega_d / w3];
    ((f, gf), (z, gz))
}
