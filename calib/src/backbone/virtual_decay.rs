//! A virtual ring-down: the structure released from a state of one of its nonlinear modes
//! and left to decay, simulated by the hold integrator ([`nlsim_sim::Simulator`], FOH). Its
//! records are what a ring-down test gives; [`super::identify_decay`] on them closes the
//! loop from the model's nonlinear modes (EPMC, [`nlsim_hb::nnm`]) to the identified
//! backbone, so a test can be planned and its identification checked end to end.
//!
//! The release state of an EPMC point with modal harmonics `η` (real layout of
//! [`nlsim_hb::HarmonicSet`]: mean, then `c_k, s_k` of `c_k cos kωt + s_k sin kωt`) is its
//! motion at `t = 0`: `η(0) = c₀ + Σ_k c_k`, `η̇(0) = Σ_k kω s_k`, for every retained mode.
//! The plant must be built on the same reduction as the harmonic-balance system
//! ([`nlsim_hb::nnm::aligned_reduction`] for a free-motion system).

use nlsim_hb::HbSystem;
use nlsim_hb::nnm::NnmPoint;
use nlsim_kernel::{Error, Result};
use nlsim_sim::{FohConfig, InitialState, LoadCase, Plant, Signal, Simulator, TimeHistory};

/// The modal displacements (√kg m) and velocities (√kg m/s) of the nonlinear-mode point
/// `p` of `sys` at `t = 0`.
pub fn nnm_release_state(sys: &HbSystem, p: &NnmPoint) -> (Vec<f64>, Vec<f64>) {
    let set = *sys.harmonics();
    let nh = set.len();
    let m = sys.linear().n_modes();
    let w = set.base(p.omega);
    let mut q = vec![0.0; m];
    let mut v = vec![0.0; m];
    for r in 0..m {
        let eta = &p.eta[r * nh..(r + 1) * nh];
        q[r] = eta[0];
        for k in 1..=set.h {
            q[r] += eta[2 * k - 1];
            v[r] += k as f64 * w * eta[2 * k];
        }
    }
    (q, v)
}

/// Releases the structure of `plant` from the nonlinear-mode point `p` of `sys` with no
/// force and simulates `steps` steps of `dt` seconds by FOH. `Err` for invalid input: a
/// point that does not belong to `sys` (its length), a plant whose retained modes differ
/// from the system's, a non-positive step.
pub fn virtual_ringdown(
    plant: &Plant,
    sys: &HbSystem,
    p: &NnmPoint,
    dt: f64,
    steps: usize,
) -> Result<TimeHistory> {
    let nh = sys.harmonics().len();
    let m = sys.linear().n_modes();
    if p.eta.len() != m * nh {
        return Err(Error::DimensionMismatch {
            what: "nonlinear-mode point (modes × harmonic coefficients)".into(),
            expected: m * nh,
            found: p.eta.len(),
        });
    }
    let (q, v) = nnm_release_state(sys, p);
    let mut case = LoadCase::new(
        "ring-down",
        plant
            .inputs
            .iter()
            .map(|_| Signal::sine(0.0, 1.0))
            .collect(),
    );
    case.initial = InitialState::Modal {
        displacement: q,
        velocity: v,
    };
    let sim = Simulator::new(plant, &FohConfig::new(dt))?;
    sim.run(&case, steps)
}
