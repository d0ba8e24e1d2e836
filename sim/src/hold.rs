//! Hold (input reconstruction) methods and the exact discretisation of a scalar mode under
//! them (thesis §3.1, paper III; `docs/time-domain.md` has the derivations).
//!
//! Between samples `t_k = kT` the input is reconstructed as a polynomial in `s = (t − t_k)/T`,
//! `ũ(t_k + sT) = Σ_j L_j(s) u[k + j]`:
//!
//! | hold | taps `j` | `L_j(s)` |
//! |---|---|---|
//! | zero-order (ZOH) | 0 | `1` |
//! | first-order / triangle (FOH) | 0, 1 | `1 − s`, `s` |
//! | Lagrange second-order (LSOH) | −1, 0, 1 | `s(s−1)/2`, `1 − s²`, `s(s+1)/2` |
//!
//! A mode `ż = λz + b u` is then integrated exactly over the step:
//! `z[k+1] = e^{λT} z[k] + Σ_j g_j b u[k+j]` with
//! `g_j = ∫_0^T e^{λ(T−τ)} L_j(τ/T) dτ = T Σ_n c_{jn} n! φ_{n+1}(λT)` for `L_j(s) = Σ_n c_{jn} sⁿ`,
//! where `φ_k` are the exponential-integrator functions `φ_0(x) = eˣ`,
//! `φ_{k+1}(x) = (φ_k(x) − 1/k!)/x`. For FOH these are the `Γ0 = (γa − γb) B̃`, `Γ1 = γb B̃` of
//! the design (`γa = T φ_1`, `γb = T φ_2`).

use faer::c64;

/// How the sampled input is held between samples.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Hold {
    /// Zero-order hold: the input is constant over a step (explicit; large bias, paper III).
    Zoh,
    /// First-order (triangle) hold: the input is linear between samples. Exact for piecewise
    /// linear input; the default.
    Foh,
    /// Lagrange second-order hold: a parabola through `u[k−1], u[k], u[k+1]`.
    Lsoh,
}

impl Hold {
    /// Lower-case name (`zoh`, `foh`, `lsoh`).
    pub fn as_str(self) -> &'static str {
        match self {
            Hold::Zoh => "zoh",
            Hold::Foh => "foh",
            Hold::Lsoh => "lsoh",
        }
    }

    /// The taps `j` (sample offsets) the hold reads over the step `[t_k, t_{k+1}]`.
    pub fn taps(self) -> &'static [i32] {
        match self {
            Hold::Zoh => &[0],
            Hold::Foh => &[0, 1],
            Hold::Lsoh => &[-1, 0, 1],
        }
    }

    /// Polynomial coefficients `c_{jn}` (`n = 0, 1, 2`) of `L_j(s)`, one row per tap.
    pub fn basis(self) -> &'static [[f64; 3]] {
        match self {
            Hold::Zoh => &[[1.0, 0.0, 0.0]],
            Hold::Foh => &[[1.0, -1.0, 0.0], [0.0, 1.0, 0.0]],
            Hold::Lsoh => &[[0.0, -0.5, 0.5], [1.0, 0.0, -1.0], [0.0, 0.5, 0.5]],
        }
    }
}

impl std::fmt::Display for Hold {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.as_str())
    }
}

const FACTORIAL: [f64; 4] = [1.0, 1.0, 2.0, 6.0];

/// `1/(22 − j)!` for `j = 0, 1, …, 19`: the coefficients of `φ_3`'s Taylor series in Horner
/// order, highest power first. (Factorials beyond 18! are rounded in f64, by an ulp that the
/// series does not notice.)
const PHI3_HORNER: [f64; 20] = {
    let mut c = [0.0; 20];
    let mut j = 0;
    while j < 20 {
        let mut p = 1.0;
        let mut i = 2;
        while i <= 22 - j {
            p *= i as f64;
            i += 1;
        }
        c[j] = 1.0 / p;
        j += 1;
    }
    c
};

/// `[φ_0(x), φ_1(x), φ_2(x), φ_3(x)]` with `φ_0 = eˣ`, `φ_k(x) = Σ_j x^j/(j+k)!`.
///
/// Relative accuracy near round-off for all `x`: below `|x| = 1/2` the Taylor series of `φ_3`
/// (Horner form) and `φ_k = 1/k! + x φ_{k+1}` downwards, where `|x φ_{k+1}| < 1/(2 k!)` so
/// nothing cancels; above, the recurrence `φ_{k+1} = (φ_k − 1/k!)/x` upwards.
pub fn phi_functions(x: c64) -> [c64; 4] {
    if x.norm() < 0.5 {
        // φ_3(x) = Σ_j x^j/(j+3)!, 20 terms: |x|^20/23! < 1e-28.
        let mut p3 = c64::new(PHI3_HORNER[0], 0.0);
        for &c in &PHI3_HORNER[1..] {
            p3 = p3 * x + c;
        }
        let p2 = p3 * x + 0.5;
        let p1 = p2 * x + 1.0;
        let p0 = p1 * x + 1.0;
        [p0, p1, p2, p3]
    } else {
        let e = x.exp();
        let p1 = (e - 1.0) / x;
        let p2 = (p1 - 1.0) / x;
        let p3 = (p2 - 0.5) / x;
        [e, p1, p2, p3]
    }
}

/// Exact one-step coefficients of the mode `ż = λz + b u` over a step `h` (s) under `hold`:
/// `z(t+h) = phi · z(t) + Σ_j gains[j] · b · u[k + taps[j]]`. Returns `(phi, gains)` with one
/// gain per tap of [`Hold::taps`] (s).
pub fn step_coefficients(hold: Hold, lambda: c64, h: f64) -> (c64, [c64; 3]) {
    let p = phi_functions(lambda * h);
    let mut gains = [c64::new(0.0, 0.0); 3];
    for (g, row) in gains.iter_mut().zip(hold.basis()) {
        let mut acc = c64::new(0.0, 0.0);
        for (n, &c) in row.iter().enumerate() {
            if c != 0.0 {
                acc += p[n + 1] * (c * FACTORIAL[n]);
            }
        }
        *g = acc * h;
    }
    (p[0], gains)
}

/// Paper III's bias of a hold: the gain `K̂(θ)` with which the reconstructed input carries a
/// sampled sinusoid `e^{iωt}` at its own frequency, `θ = ωT` (rad per sample).
///
/// `ũ(t) e^{−iωt}` is `T`-periodic; its mean is `K̂(θ) = ∫_0^1 P(s) e^{−iθs} ds` with
/// `P(s) = Σ_j L_j(s) e^{ijθ}`. Closed forms (derived in `docs/time-domain.md`):
/// ZOH `e^{−iθ/2} sin(θ/2)/(θ/2)`; FOH `(sin(θ/2)/(θ/2))²` (no phase error);
/// LSOH from the moments `∫_0^1 sⁿ e^{−iθs} ds = e^{−iθ} n! φ_{n+1}(iθ)`.
///
/// The amplitude error is `|K̂| − 1`, the phase error `arg K̂` (rad). The other Fourier
/// coefficients `K̂(θ + 2πm)` are the images that alias back onto the samples.
pub fn reconstruction_gain(hold: Hold, theta: f64) -> c64 {
    let p = phi_functions(c64::new(0.0, theta));
    let back = c64::new(theta.cos(), -theta.sin());
    let mu = [
        back * p[1] * FACTORIAL[0],
        back * p[2] * FACTORIAL[1],
        back * p[3] * FACTORIAL[2],
    ];
    let mut k = c64::new(0.0, 0.0);
    for (&j, row) in hold.taps().iter().zip(hold.basis()) {
        let shift = c64::new((j as f64 * theta).cos(), (j as f64 * theta).sin());
        let mut acc = c64::new(0.0, 0.0);
        for n in 0..3 {
            acc += mu[n] * row[n];
        }
        k += shift * acc;
    }
    k
}

/// Amplitude error `|K̂(θ)| − 1` and phase error `arg K̂(θ)` (rad) of a hold at `θ = ωT`.
pub fn bias_error(hold: Hold, theta: f64) -> (f64, f64) {
    let k = reconstruction_gain(hold, theta);
    (k.norm() - 1.0, k.arg())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn phi_functions_match_their_series_near_zero() {
        // The defining series summed term by term, smallest terms first (60 terms).
        let series = |x: c64, k: usize| {
            let mut terms = Vec::new();
            let mut t = c64::new(1.0 / FACTORIAL[k], 0.0);
            for j in 0..60 {
                terms.push(t);
                t = t * x / (j + 1 + k) as f64;
            }
            terms.iter().rev().fold(c64::new(0.0, 0.0), |a, &t| a + t)
        };
        for (r, ang) in [
            (1e-9, 0.3),
            (1e-3, 2.0),
            (0.1, -1.2),
            (0.3, 3.0),
            (0.49, 1.4),
        ] {
            let x = c64::new(r * f64::cos(ang), r * f64::sin(ang));
            let p = phi_functions(x);
            for k in 0..4 {
                let want = series(x, k);
                assert!(
                    (p[k] - want).norm() <= 4.0 * f64::EPSILON * want.norm(),
                    "φ_{k}({x}) = {} against {want}",
                    p[k]
                );
            }
        }
    }

    #[test]
    fn phi_functions_agree_across_the_switch() {
        // Both branches at |x| = 0.5 ± tiny, in several directions.
        for ang in [0.0, 0.7, 1.6, 2.5, 3.1] {
            let d = c64::new(f64::cos(ang), f64::sin(ang));
            let a = phi_functions(d * 0.4999999);
            let b = phi_functions(d * 0.5000001);
            for k in 0..4 {
                assert!(
                    (a[k] - b[k]).norm() <= 1e-6 * a[k].norm(),
                    "φ_{k} at angle {ang}"
                );
            }
        }
        // φ_2(x) = (eˣ − 1 − x)/x² for a large x.
        let x = c64::new(-3.0, 40.0);
        let p = phi_functions(x);
        let direct = (x.exp() - 1.0 - x) / (x * x);
        assert!((p[2] - direct).norm() <= 1e-14 * direct.norm());
    }

    #[test]
    fn closed_forms_of_zoh_and_foh() {
        for theta in [0.01f64, 0.3, 1.0, 2.0, 3.0] {
            let sinc = (theta / 2.0).sin() / (theta / 2.0);
            let zoh = reconstruction_gain(Hold::Zoh, theta);
            let expect = c64::new((theta / 2.0).cos(), -(theta / 2.0).sin()) * sinc;
            assert!((zoh - expect).norm() < 1e-14, "ZOH at {theta}");
            let foh = reconstruction_gain(Hold::Foh, theta);
            assert!(
                (foh - c64::new(sinc * sinc, 0.0)).norm() < 1e-14,
                "FOH at {theta}"
            );
        }
    }

    #[test]
    fn lsoh_leading_errors() {
        // K̂ = 1 − iθ³/24 − θ⁴/60 + O(θ⁵) (docs/time-domain.md).
        for theta in [0.05f64, 0.1, 0.2] {
            let k = reconstruction_gain(Hold::Lsoh, theta);
            let expect = c64::new(1.0 - theta.powi(4) / 60.0, -theta.powi(3) / 24.0);
            assert!(
                (k - expect).norm() < 0.1 * theta.powi(5),
                "θ = {theta}: {k} vs {expect}"
            );
        }
    }

    #[test]
    fn step_coefficients_match_quadrature() {
        // g_j = ∫_0^h e^{λ(h−τ)} L_j(τ/h) dτ by composite Simpson with 2000 panels.
        for hold in [Hold::Zoh, Hold::Foh, Hold::Lsoh] {
            for lambda in [
                c64::new(-0.3, 150.0),
                c64::new(-2000.0, 0.0),
                c64::new(-1e-3, 1e-3),
            ] {
                let h = 1e-3;
                let (phi, g) = step_coefficients(hold, lambda, h);
                assert!((phi - (lambda * h).exp()).norm() < 1e-15);
                for (t, row) in hold.basis().iter().enumerate() {
                    let n = 2000;
                    let f = |s: f64| {
                        (lambda * (h - s * h)).exp() * (row[0] + row[1] * s + row[2] * s * s) * h
                    };
                    let mut acc = f(0.0) + f(1.0);
                    for i in 1..n {
                        let w = if i % 2 == 1 { 4.0 } else { 2.0 };
                        acc += f(i as f64 / n as f64) * w;
                    }
                    let quad = acc / (3.0 * n as f64);
                    assert!(
                        (g[t] - quad).norm() <= 1e-12 * h,
                        "{hold} tap {t} at λ = {lambda}: {} vs {quad}",
                        g[t]
                    );
                }
            }
        }
    }
}
