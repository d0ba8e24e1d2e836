//! Starts for branches that a sweep from rest does not reach: sub-harmonic responses
//! (thesis eq. 12, `ν ≥ 2`), which are isolated from the primary branch.
//!
//! A sub-harmonic response at `Ω` oscillates mainly at `Ω/ν` near a nonlinear mode whose
//! frequency has moved there with amplitude. [`find_subharmonic`] estimates that amplitude
//! from a single-mode backbone — the describing function of every element, `k_eq(a) =
//! G_c1(a cos θ)/a`, on the mass-normalised mode `r`: `ω²(q) = ω_r² + Σ_e φ_er² k_eq,e(φ_er
//! q)`, solved for `ω(q) = Ω/ν` — and starts Newton from the linear response plus that modal
//! motion at `Ω/ν` at several phases (the `ν` copies of a sub-harmonic orbit differ by a
//! shift of one forcing period, `2π/ν` in the phase of the base harmonic).

use crate::aft::{AftPlan, samples_for};
use crate::system::HbSystem;
use nlsim_kernel::Result;

/// A sub-harmonic solution found by [`find_subharmonic`].
#[derive(Debug, Clone)]
pub struct SubharmonicStart {
    /// Fundamental frequency `Ω` (rad/s).
    pub omega: f64,
    /// Condensed unknowns of the converged solution.
    pub x: Vec<f64>,
    /// The mode (0-based) whose backbone gave the start.
    pub mode: usize,
    /// Its [`subharmonic_content`].
    pub content: f64,
    /// Newton solves tried before it (this one included).
    pub attempts: usize,
}

/// The share of the response carried by the harmonics of the base `Ω/ν` that are not
/// harmonics of `Ω` (`k` not a multiple of `ν`): `‖x_sub‖₂ / ‖x‖₂` over the element
/// coefficients, 0 for `ν = 1` or a zero response.
pub fn subharmonic_content(sys: &HbSystem, x: &[f64]) -> f64 {
    let set = sys.harmonics();
    let nh = set.len();
    if set.nu == 1 {
        return 0.0;
    }
    let (mut sub, mut all) = (0.0, 0.0);
    for (i, v) in x.iter().enumerate() {
        let j = i % nh;
        let k = j.div_ceil(2);
        all += v * v;
        if !k.is_multiple_of(set.nu) {
            sub += v * v;
        }
    }
    if all > 0.0 { (sub / all).sqrt() } else { 0.0 }
}

/// Share of [`subharmonic_content`] above which a converged solution counts as
/// sub-harmonic.
pub const SUBHARMONIC_SHARE: f64 = 1e-2;

/// Phases of the base harmonic tried per backbone amplitude.
pub const PHASES: usize = 8;

/// Searches the frequencies `omegas` (rad/s, in the order given) for a sub-harmonic
/// solution at force level `scale`: at each, for the (at most three) modes whose linear
/// frequency is nearest `Ω/ν`, every backbone amplitude `q` with `ω(q) = Ω/ν` gives
/// [`PHASES`] starts; the first converged solution whose [`subharmonic_content`] exceeds
/// [`SUBHARMONIC_SHARE`] is returned. `Ok(None)` when no start converged to one (also for
/// `ν = 1`); `Err` only for invalid input (a non-positive frequency).
pub fn find_subharmonic(
    sys: &HbSystem,
    omegas: &[f64],
    scale: f64,
) -> Result<Option<SubharmonicStart>> {
    let set = *sys.harmonics();
    if set.nu < 2 || set.h < 1 {
        return Ok(None);
    }
    let nh = set.len();
    let lin = sys.linear();
    let w2 = lin.eigenvalues();
    let phi = lin.participation();
    let ports = sys.element_ports();
    let plans: Vec<AftPlan> = sys
        .elements()
        .iter()
        .map(|el| AftPlan::new(set, samples_for(el.law(), &set)))
        .collect::<Result<_>>()?;
    let mut attempts = 0usize;
    for &omega in omegas {
        let w0 = set.base(omega);
        let mut modes: Vec<usize> = (0..w2.len()).collect();
        modes.sort_by(|&a, &b| {
            (w2[a].sqrt() - w0)
                .abs()
                .total_cmp(&(w2[b].sqrt() - w0).abs())
        });
        modes.truncate(3);
        let base = sys.linear_guess(omega, scale);
        let s0 = base.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-12);
        for &r in &modes {
            let amp: Vec<f64> = ports.iter().map(|&p| phi[(p, r)]).collect();
            let top = amp.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            if top == 0.0 {
                continue;
            }
            // ω²(q) − ω0², q the modal amplitude, with the element coordinates φ_e q: the
            // first harmonic of the modal force Σ_e φ_e G_e,1 / q.
            let gap = |q: f64| -> f64 {
                let mut k = w2[r];
                for (e, el) in sys.elements().iter().enumerate() {
                    let c = sys.coordinates(e);
                    if c.clone().all(|j| amp[j] == 0.0) || q == 0.0 {
                        continue;
                    }
                    let mut xe = vec![0.0; c.len() * nh];
                    for (a, j) in c.clone().enumerate() {
                        xe[a * nh + 1] = amp[j] * q;
                    }
                    let g = plans[e].evaluate_element(el.law(), &xe, w0, false).force;
                    k += c
                        .enumerate()
                        .map(|(a, j)| amp[j] * g[a * nh + 1])
                        .sum::<f64>()
                        / q;
                }
                k - w0 * w0
            };
            // Amplitudes of the element coordinate from 1e-3 to 1e6 times the linear
            // response, 10 per decade: every sign change of the backbone gap, bisected.
            let grid: Vec<f64> = (0..=90)
                .map(|i| s0 * 10f64.powf(-3.0 + i as f64 / 10.0) / top)
                .collect();
            let mut roots = Vec::new();
            let mut prev = (grid[0], gap(grid[0]));
            for &q in &grid[1..] {
                let g = gap(q);
                if !g.is_finite() {
                    break;
                }
                if g.signum() != prev.1.signum() {
                    let (mut lo, mut hi, glo) = (prev.0, q, prev.1);
                    for _ in 0..40 {
                        let mid = (lo * hi).sqrt();
                        if gap(mid).signum() == glo.signum() {
                            lo = mid;
                        } else {
                            hi = mid;
                        }
                    }
                    roots.push((lo * hi).sqrt());
                    if roots.len() == 3 {
                        break;
                    }
                }
                prev = (q, g);
            }
            for &q in &roots {
                for j in 0..PHASES {
                    let th = 2.0 * std::f64::consts::PI * j as f64 / PHASES as f64;
                    let mut x0 = base.clone();
                    for (e, a) in amp.iter().enumerate() {
                        x0[e * nh + 1] += a * q * th.cos();
                        x0[e * nh + 2] += a * q * th.sin();
                    }
                    attempts += 1;
                    let (x, rep) = sys.solve(omega, scale, &x0)?;
                    if !rep.converged() {
                        continue;
                    }
                    let content = subharmonic_content(sys, &x);
                    if content > SUBHARMONIC_SHARE {
                        return Ok(Some(SubharmonicStart {
                            omega,
                            x,
                            mode: r,
                            content,
                            attempts,
                        }));
                    }
                }
            }
        }
    }
    Ok(None)
}
