//! Segalman's four-parameter Iwan joint as a finite set of parallel Jenkins sliders.
//!
//! Segalman (2005) writes the tangential force of a lap joint as a parallel Iwan system,
//! `F(t) = ∫₀^∞ ρ(φ) [u(t) − x(t, φ)] dφ`, slider `φ` of unit stiffness slipping when
//! `|u − x| = φ`, with the population
//!
//! `ρ(φ) = R φ^χ [H(φ) − H(φ − φ_max)] + S δ(φ − φ_max)`,
//!
//! a power law up to the macroslip displacement `φ_max` plus a Dirac at `φ_max`. Its four
//! parameters are the macroslip force `F_S`, the stiffness `K_T` of the stuck joint, the
//! exponent `χ ∈ (−1, 1]` (−1 < χ ≤ 0 for measured lap joints) and `β ≥ 0` (the share of
//! the Dirac), from which (with `D = β + (χ+1)/(χ+2)`)
//!
//! `φ_max = F_S (1 + β) / (K_T D)`, `R = F_S (χ+1) / (φ_max^{χ+2} D)`, `S = K_T β / (1 + β) / φ_max`.
//!
//! Below macroslip, under a displacement amplitude `A < φ_max`, it dissipates
//! `4 R A^{χ+3} / ((χ+2)(χ+3))` per cycle (the power law the microslip of bolted joints
//! shows); beyond it the force is `F_S`.
//!
//! **Discretisation.** The continuous part is cut at `φ_i = φ_max c_i`, `c_0 = 0` and
//! `c_1 … c_n` geometric from `10^{−decades}` to 1 (`n` the number of sliders, `c_1 = 1` when
//! `n = 1`); the sliders of `[φ_{i−1}, φ_i]` become one Jenkins slider with their total
//! stiffness and total slip force,
//!
//! `k_i = K_T/(1+β) (c_i^{χ+1} − c_{i−1}^{χ+1})`, `f_i = F_S (χ+1)/((χ+2) D) (c_i^{χ+2} − c_{i−1}^{χ+2})`,
//!
//! and the Dirac one more slider `k = K_T β/(1+β)`, `f = F_S β/D`. The stuck stiffness `K_T`
//! and the macroslip force `F_S` are exact for any `n`; the dissipation is piecewise linear
//! in the amplitude between the sliders' slip displacements `f_i/k_i`, and its error is
//! second order in the grid's log spacing `decades ln 10/(n − 1)`: over the top two decades
//! below `φ_max` at most 0.8 % (χ = 0) to 0.5 % (χ = −0.8) with the default 80 sliders over
//! 4 decades, 4× less per doubling (the kernel's test `iwan_dissipation_converges…`). Near the
//! bottom of the grid the first slider lumps the population below it, and below its slip
//! displacement the joint is linear (as every discrete Iwan model is): give the grid enough
//! decades to reach below the smallest amplitude of interest.

use crate::error::{Error, Result};

/// Default number of sliders of the continuous part.
pub const DEFAULT_SLIDERS: usize = 80;
/// Default span of the slip displacements below `φ_max`, in decades.
pub const DEFAULT_DECADES: f64 = 4.0;

/// The sliders of a discretised Iwan joint: each one's stiffness (N/m) and slip force (N),
/// the continuous part's `n` first and the Dirac's last. Built by [`IwanGrid::new`] from the
/// four parameters; kept consistent with them by [`crate::Law::set_param`].
#[derive(Debug, Clone, PartialEq)]
pub struct IwanGrid {
    sliders: usize,
    decades: f64,
    k: Vec<f64>,
    f: Vec<f64>,
}

impl IwanGrid {
    /// The sliders of the joint `[fs, kt, chi, beta]` (N, N/m, 1, 1) on `sliders` intervals
    /// spanning `decades` decades below `φ_max`. Checks the discretisation (the parameters
    /// are checked by [`crate::Law::validate`]; out of range, they leave the sliders zero).
    /// `element` names the joint in errors.
    pub fn new(
        element: &str,
        sliders: usize,
        decades: f64,
        [fs, kt, chi, beta]: [f64; 4],
    ) -> Result<Self> {
        check_grid(element, sliders, decades)?;
        let mut g = IwanGrid {
            sliders,
            decades,
            k: vec![0.0; sliders + 1],
            f: vec![0.0; sliders + 1],
        };
        if fs.is_finite() && kt.is_finite() && chi > -1.0 && beta.is_finite() && beta >= 0.0 {
            g.refresh(fs, kt, chi, beta);
        }
        Ok(g)
    }

    /// Number of sliders of the continuous part (the joint has one more, the Dirac's).
    pub fn sliders(&self) -> usize {
        self.sliders
    }

    /// Span of the continuous part's slip displacements, in decades below `φ_max`.
    pub fn decades(&self) -> f64 {
        self.decades
    }

    /// Stiffness (N/m) and slip force (N) of slider `s` (`s ≤ sliders`, the last the Dirac's).
    #[inline]
    pub fn slider(&self, s: usize) -> (f64, f64) {
        (self.k[s], self.f[s])
    }

    /// The joint's force (N) and `∂g/∂u` (N/m) at displacement `u` (m) with the sliders at
    /// `state` (m, one per slider). Kept out of line: the loop would otherwise be inlined
    /// into every law's evaluation and slow the memoryless ones' hot loops.
    #[inline(never)]
    pub fn force(&self, u: f64, state: &[f64]) -> (f64, f64) {
        let (mut g, mut d) = (0.0, 0.0);
        for (s, &z) in state.iter().enumerate().take(self.sliders + 1) {
            let (gs, ds) = slider_force(self.k[s], self.f[s], u, z);
            g += gs;
            d += ds;
        }
        (g, d)
    }

    /// The cut `c_i` (fraction of `φ_max`), `i = 0..=n`.
    fn cut(&self, i: usize) -> f64 {
        let n = self.sliders;
        if i == 0 {
            0.0
        } else if n == 1 {
            1.0
        } else {
            10f64.powf(-self.decades * (n - i) as f64 / (n - 1) as f64)
        }
    }

    /// Recomputes the sliders from valid parameters.
    pub(crate) fn refresh(&mut self, fs: f64, kt: f64, chi: f64, beta: f64) {
        let (a, b) = (chi + 1.0, chi + 2.0);
        let d = beta + a / b;
        let (kc, fc) = (kt / (1.0 + beta), fs * a / (b * d));
        for i in 1..=self.sliders {
            let (lo, hi) = (self.cut(i - 1), self.cut(i));
            self.k[i - 1] = kc * (hi.powf(a) - lo.powf(a));
            self.f[i - 1] = fc * (hi.powf(b) - lo.powf(b));
        }
        self.k[self.sliders] = kt * beta / (1.0 + beta);
        self.f[self.sliders] = fs * beta / d;
    }

    /// `∂k_s/∂p` and `∂f_s/∂p` of slider `s` for `p = (fs, kt, chi, beta)` into `dk`, `df`
    /// (4 each).
    pub(crate) fn dslider(&self, s: usize, p: [f64; 4], dk: &mut [f64], df: &mut [f64]) {
        let [fs, kt, chi, beta] = p;
        let (a, b) = (chi + 1.0, chi + 2.0);
        let den = b * beta + a;
        if s == self.sliders {
            dk.copy_from_slice(&[0.0, beta / (1.0 + beta), 0.0, kt / (1.0 + beta).powi(2)]);
            df.copy_from_slice(&[
                b * beta / den,
                0.0,
                -fs * beta / (den * den),
                fs * a * b / (den * den),
            ]);
            return;
        }
        let (lo, hi) = (self.cut(s), self.cut(s + 1));
        let pw = |c: f64, e: f64| if c > 0.0 { c.powf(e) } else { 0.0 };
        let pl = |c: f64, e: f64| if c > 0.0 { c.powf(e) * c.ln() } else { 0.0 };
        let (da, db) = (pw(hi, a) - pw(lo, a), pw(hi, b) - pw(lo, b));
        let (dla, dlb) = (pl(hi, a) - pl(lo, a), pl(hi, b) - pl(lo, b));
        let q = a / den;
        dk.copy_from_slice(&[
            0.0,
            da / (1.0 + beta),
            kt / (1.0 + beta) * dla,
            -kt * da / (1.0 + beta).powi(2),
        ]);
        df.copy_from_slice(&[
            q * db,
            0.0,
            fs * (beta / (den * den) * db + q * dlb),
            -fs * db * a * b / (den * den),
        ]);
    }
}

/// Checks the discretisation: 1 to 1000 sliders over a span of (0, 12] decades.
pub(crate) fn check_grid(element: &str, sliders: usize, decades: f64) -> Result<()> {
    if !(1..=1000).contains(&sliders) {
        return Err(Error::InvalidParameter {
            name: format!("{element}.sliders"),
            value: sliders as f64,
            reason: "the number of sliders must be an integer from 1 to 1000".into(),
        });
    }
    if !(decades > 0.0 && decades <= 12.0) {
        return Err(Error::InvalidParameter {
            name: format!("{element}.decades"),
            value: decades,
            reason: "the span of the slip displacements must be in (0, 12] decades".into(),
        });
    }
    Ok(())
}

/// One Jenkins slider of stiffness `k` (N/m) and slip force `f` (N) at displacement `u` (m)
/// with its slider at `z` (m): the force and `∂g/∂u` (stick: `k (u − z)`, `k`; slip: `±f`, 0).
#[inline]
pub fn slider_force(k: f64, f: f64, u: f64, z: f64) -> (f64, f64) {
    let trial = k * (u - z);
    if trial.abs() <= f {
        (trial, k)
    } else {
        (f.copysign(trial), 0.0)
    }
}

/// Commits slider `(k, f)` after a converged step at `u`: moves `z` to keep the spring at
/// the slip limit when the trial force exceeds it. True when it slipped.
#[inline]
pub fn slider_commit(k: f64, f: f64, u: f64, z: &mut f64) -> bool {
    let trial = k * (u - *z);
    if trial.abs() > f {
        *z = u - f.copysign(trial) / k;
        true
    } else {
        false
    }
}
