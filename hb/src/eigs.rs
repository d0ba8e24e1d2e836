//! Eigenvalues of small dense real matrices (Hill's companion matrices, orders 2–200):
//! Householder reduction to Hessenberg form, then Francis double-shift QR on the active
//! window only (eigenvalues, no Schur vectors), in one column-major buffer the caller keeps.
//!
//! For these orders faer's general driver spends most of its time in the set-up of its
//! vectorised Householder kernels (3-vectors in the QR sweeps); this plain version is about
//! twice as fast on a 30 × 30 Hill matrix and allocates nothing once its buffer is sized.
//! Both are backward stable; a test compares them on random and companion matrices.

use faer::{Mat, c64};

/// Sweeps (Francis steps) allowed per eigenvalue before giving up.
const SWEEPS_PER_EIGENVALUE: usize = 40;

/// Eigenvalues of the `n × n` matrix `a`, appended to `out` (any order). `work` holds a copy
/// (resized to `n²`). `Err` when QR does not converge (the caller falls back to another
/// solver) or when `a` is not finite.
///
/// The work runs through `pulp`'s dispatch, compiled for the best instruction set found at
/// run time. The arithmetic is the same scalar arithmetic (no fused multiply–add, the same
/// rounding), but in VEX encoding: faer's matrix-product kernels return with the upper
/// halves of the vector registers dirty, and legacy-encoded SSE code that runs after them
/// (the baseline target's) is then about 2.8× slower on this machine until the next
/// `vzeroupper` (see `AftPlan::project`, which clears them after its products). Measured on the Duffing Hill blocks of order 16: 15.6 µs each on a clean
/// state, 44 µs after one faer product of 15 × 30 by 30 × 15; compiled for the native target
/// (VEX throughout), 15 µs in both cases.
pub(crate) fn eigenvalues_into(
    a: &Mat<f64>,
    work: &mut Vec<f64>,
    out: &mut Vec<c64>,
) -> Result<(), String> {
    pulp::Arch::new().dispatch(Eigenvalues { a, work, out })
}

/// [`eigenvalues_into`] as a `pulp` kernel.
struct Eigenvalues<'a> {
    a: &'a Mat<f64>,
    work: &'a mut Vec<f64>,
    out: &'a mut Vec<c64>,
}

impl pulp::WithSimd for Eigenvalues<'_> {
    type Output = Result<(), String>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) -> Self::Output {
        let Self { a, work, out } = self;
        let n = a.nrows();
        work.clear();
        work.reserve(n * n + 2 * n);
        for c in 0..n {
            work.extend_from_slice(a.col_as_slice(c));
        }
        if work.iter().any(|v| !v.is_finite()) {
            return Err("the matrix has a non-finite entry".into());
        }
        work.resize(n * n + 2 * n, 0.0);
        let (h, scratch) = work.split_at_mut(n * n);
        balance(h, n);
        hessenberg(h, n, scratch);
        francis(h, n, out)
    }
}

/// `h[(i, j)]` of a column-major `n × n` buffer.
#[inline(always)]
fn at(i: usize, j: usize, n: usize) -> usize {
    i + j * n
}

/// Balances the column-major `n × n` matrix in `h` in place by a diagonal similarity of
/// powers of two (exact in floating point: the eigenvalues are unchanged), making each
/// row's and column's off-diagonal norms comparable. Hill's companion matrices have an
/// identity block beside blocks of order `H²`; balanced, they are closer to normal, and QR
/// both converges in fewer sweeps and loses less accuracy.
#[inline(always)]
fn balance(h: &mut [f64], n: usize) {
    for _pass in 0..32 {
        let mut changed = false;
        for i in 0..n {
            let mut c = 0.0;
            let mut r = 0.0;
            for j in 0..n {
                if j != i {
                    c += h[at(j, i, n)].abs();
                    r += h[at(i, j, n)].abs();
                }
            }
            if c == 0.0 || r == 0.0 {
                continue;
            }
            // D⁻¹ A D with d_i = f scales column i by f and row i by 1/f: the off-diagonal
            // norms become c f and r / f, least at f = √(r/c), taken as a power of two.
            let e = (0.5 * (r / c).log2()).round();
            if e == 0.0 || !e.is_finite() {
                continue;
            }
            let f = e.exp2();
            if c * f + r / f >= 0.95 * (c + r) {
                continue;
            }
            changed = true;
            for j in 0..n {
                h[at(j, i, n)] *= f;
                h[at(i, j, n)] /= f;
            }
        }
        if !changed {
            break;
        }
    }
}

/// Reduces the column-major `n × n` matrix in `h` to upper Hessenberg form by Householder
/// similarity transformations (entries below the subdiagonal are set to zero); `scratch`
/// holds `2n` values.
#[inline(always)]
fn hessenberg(h: &mut [f64], n: usize, scratch: &mut [f64]) {
    if n < 3 {
        return;
    }
    let (v, w) = scratch.split_at_mut(n);
    for k in 0..n - 2 {
        // The reflector I − τ v vᵀ maps h[k+1.., k] to (α, 0, …).
        let len = n - k - 1;
        let col = &h[at(k + 1, k, n)..at(n, k, n)];
        let tail: f64 = col[1..].iter().map(|x| x * x).sum();
        if tail == 0.0 {
            continue;
        }
        let x0 = col[0];
        let norm = (x0 * x0 + tail).sqrt();
        let alpha = if x0 > 0.0 { -norm } else { norm };
        v[..len].copy_from_slice(col);
        v[0] = x0 - alpha;
        let vv = v[0] * v[0] + tail;
        let tau = 2.0 / vv;
        let v = &v[..len];
        // Left: rows k+1.. of columns k+1.. (column k becomes (α, 0, …)).
        for j in k + 1..n {
            let c = &mut h[at(k + 1, j, n)..at(n, j, n)];
            let s = tau * c.iter().zip(v).map(|(a, b)| a * b).sum::<f64>();
            c.iter_mut().zip(v).for_each(|(a, b)| *a -= s * b);
        }
        h[at(k + 1, k, n)] = alpha;
        for i in k + 2..n {
            h[at(i, k, n)] = 0.0;
        }
        // Right: columns k+1.. of every row.
        let w = &mut w[..n];
        w.fill(0.0);
        for (l, &vl) in v.iter().enumerate() {
            let c = &h[at(0, k + 1 + l, n)..at(n, k + 1 + l, n)];
            w.iter_mut().zip(c).for_each(|(a, b)| *a += vl * b);
        }
        for (l, &vl) in v.iter().enumerate() {
            let c = &mut h[at(0, k + 1 + l, n)..at(n, k + 1 + l, n)];
            c.iter_mut()
                .zip(w.iter())
                .for_each(|(a, b)| *a -= tau * vl * b);
        }
    }
}

/// The eigenvalues of the 2 × 2 matrix `[[a, b], [c, d]]`.
#[inline(always)]
fn two_by_two(a: f64, b: f64, c: f64, d: f64) -> [c64; 2] {
    let p = 0.5 * (a - d);
    let bc = b * c;
    let disc = p * p + bc;
    if disc >= 0.0 {
        let z = p + disc.sqrt().copysign(p);
        if z == 0.0 {
            [c64::new(d, 0.0), c64::new(d, 0.0)]
        } else {
            [c64::new(d + z, 0.0), c64::new(d - bc / z, 0.0)]
        }
    } else {
        let (re, im) = (d + p, (-disc).sqrt());
        [c64::new(re, im), c64::new(re, -im)]
    }
}

/// A Householder reflector `I − τ w wᵀ` with `w = (1, w1, w2)` that maps `(x, y, z)` onto
/// the first axis: `(w1, w2, τ)`, or `None` when `(y, z)` is already zero.
///
/// With `α = ∓‖(x, y, z)‖` (the sign opposite to `x`) and `v0 = x − α`: `w = (1, y, z)/v0`
/// and `τ = 2/‖w‖² = (α − x)/α`, since `v0² + y² + z² = 2α(α − x)`. The two divisions are
/// independent: the reflector is on the critical path of every bulge step, so the chain of
/// dependent divisions (about 20 cycles each) sets the speed of QR on small matrices. The
/// vector is scaled by a power of two only when its entries could over- or underflow when
/// squared.
#[inline(always)]
fn reflector3(x: f64, y: f64, z: f64) -> Option<(f64, f64, f64)> {
    if y == 0.0 && z == 0.0 {
        return None;
    }
    let s = x.abs().max(y.abs()).max(z.abs());
    let (x, y, z) = if (1e-150..=1e150).contains(&s) {
        (x, y, z)
    } else {
        // An exact power-of-two scale near 1/s (≠ 0: y or z is nonzero).
        let f = (-s.log2().round()).exp2();
        (x * f, y * f, z * f)
    };
    let norm = (x * x + y * y + z * z).sqrt();
    let alpha = if x > 0.0 { -norm } else { norm };
    let r = 1.0 / (x - alpha);
    let tau = (alpha - x) / alpha;
    Some((y * r, z * r, tau))
}

/// Whether the subdiagonal entry `h[k, k−1]` of the window ending at `u` can be set to zero.
/// The test of Ahues and Tisseur (the one LAPACK uses): the perturbation it makes is below
/// the rounding of the 2 × 2 block `h[k−1..=k, k−1..=k]` itself, measured by its diagonal
/// difference as well as its diagonal, so that a block with (near) zero diagonal (a
/// companion matrix's) still deflates instead of driving its subdiagonal into the
/// subnormal range, where each sweep is many times slower. With a zero diagonal the
/// neighbouring subdiagonal entries give the scale.
#[inline(always)]
fn negligible(h: &[f64], n: usize, k: usize, u: usize) -> bool {
    let sub = h[at(k, k - 1, n)].abs();
    if sub <= f64::MIN_POSITIVE / f64::EPSILON {
        return true;
    }
    let (a, d) = (h[at(k - 1, k - 1, n)], h[at(k, k, n)]);
    let mut tst = a.abs() + d.abs();
    if tst == 0.0 {
        if k >= 2 {
            tst += h[at(k - 1, k - 2, n)].abs();
        }
        if k < u {
            tst += h[at(k + 1, k, n)].abs();
        }
    }
    if sub > f64::EPSILON * tst {
        return false;
    }
    let sup = h[at(k - 1, k, n)].abs();
    let (ab, ba) = (sub.max(sup), sub.min(sup));
    let diff = (a - d).abs();
    let (aa, bb) = (d.abs().max(diff), d.abs().min(diff));
    let s = aa + ab;
    ba * (ab / s) <= (f64::MIN_POSITIVE / f64::EPSILON).max(f64::EPSILON * (bb * (aa / s)))
}

/// Francis double-shift QR on the upper Hessenberg `h` (column-major `n × n`): its
/// eigenvalues appended to `out`.
#[inline(always)]
fn francis(h: &mut [f64], n: usize, out: &mut Vec<c64>) -> Result<(), String> {
    let mut hi = n; // the active window is rows/columns lo..hi
    let mut sweeps = 0usize;
    let mut since = 0usize; // sweeps since the last deflation
    while hi > 0 {
        let u = hi - 1;
        // The lowest negligible subdiagonal entry splits the window.
        let mut lo = u;
        while lo > 0 {
            if negligible(h, n, lo, u) {
                h[at(lo, lo - 1, n)] = 0.0;
                break;
            }
            lo -= 1;
        }
        if lo == u {
            out.push(c64::new(h[at(u, u, n)], 0.0));
            hi -= 1;
            since = 0;
            continue;
        }
        if lo + 1 == u {
            out.extend(two_by_two(
                h[at(u - 1, u - 1, n)],
                h[at(u - 1, u, n)],
                h[at(u, u - 1, n)],
                h[at(u, u, n)],
            ));
            hi -= 2;
            since = 0;
            continue;
        }
        sweeps += 1;
        since += 1;
        if sweeps > SWEEPS_PER_EIGENVALUE * n {
            return Err(format!(
                "the QR iteration did not converge ({sweeps} sweeps, {} of {n} eigenvalues found)",
                out.len()
            ));
        }
        // Shifts: the eigenvalues of the trailing 2 × 2 block (sum s, product t), or an
        // ad hoc pair after 10 sweeps without a deflation.
        let (s, t) = if since % 11 == 10 {
            let w = h[at(u, u - 1, n)].abs() + h[at(u - 1, u - 2, n)].abs();
            let d = h[at(u, u, n)] + 0.75 * w;
            (2.0 * d, d * d - 0.4375 * w * w)
        } else {
            let (a, b, c, d) = (
                h[at(u - 1, u - 1, n)],
                h[at(u - 1, u, n)],
                h[at(u, u - 1, n)],
                h[at(u, u, n)],
            );
            (a + d, a * d - b * c)
        };
        // First column of (H − σ1)(H − σ2) restricted to the window.
        let (h00, h01, h10) = (h[at(lo, lo, n)], h[at(lo, lo + 1, n)], h[at(lo + 1, lo, n)]);
        let (h11, h21) = (h[at(lo + 1, lo + 1, n)], h[at(lo + 2, lo + 1, n)]);
        let mut x = h00 * h00 + h01 * h10 - s * h00 + t;
        let mut y = h10 * (h00 + h11 - s);
        let mut z = h10 * h21;
        // Chase the bulge down the window.
        for k in lo..u - 1 {
            if let Some((w1, w2, tau)) = reflector3(x, y, z) {
                // Left: rows k..k+2, columns max(lo, k−1)..=u.
                for j in k.max(lo + 1) - 1..=u {
                    let c: &mut [f64; 3] = (&mut h[at(k, j, n)..at(k + 3, j, n)])
                        .try_into()
                        .expect("three rows");
                    let p = tau * (c[0] + w1 * c[1] + w2 * c[2]);
                    c[0] -= p;
                    c[1] -= p * w1;
                    c[2] -= p * w2;
                }
                // Right: columns k..k+2, rows lo..=min(k+3, u).
                let rows = lo..(k + 4).min(u + 1);
                let (c0, rest) = h[at(0, k, n)..at(0, k + 3, n)].split_at_mut(n);
                let (c1, c2) = rest.split_at_mut(n);
                for ((a0, a1), a2) in c0[rows.clone()]
                    .iter_mut()
                    .zip(&mut c1[rows.clone()])
                    .zip(&mut c2[rows])
                {
                    let p = tau * (*a0 + w1 * *a1 + w2 * *a2);
                    *a0 -= p;
                    *a1 -= p * w1;
                    *a2 -= p * w2;
                }
                if k > lo {
                    // The reflector zeroed the bulge below the subdiagonal exactly.
                    h[at(k + 1, k - 1, n)] = 0.0;
                    h[at(k + 2, k - 1, n)] = 0.0;
                }
            }
            x = h[at(k + 1, k, n)];
            y = h[at(k + 2, k, n)];
            z = if k + 3 <= u { h[at(k + 3, k, n)] } else { 0.0 };
        }
        // The last 2-vector (x, y) at rows u−1, u.
        let k = u - 1;
        if let Some((w1, _, tau)) = reflector3(x, y, 0.0) {
            for j in k - 1..=u {
                let (a0, a1) = (h[at(k, j, n)], h[at(k + 1, j, n)]);
                let p = tau * (a0 + w1 * a1);
                h[at(k, j, n)] = a0 - p;
                h[at(k + 1, j, n)] = a1 - p * w1;
            }
            for i in lo..=u {
                let (a0, a1) = (h[at(i, k, n)], h[at(i, k + 1, n)]);
                let p = tau * (a0 + w1 * a1);
                h[at(i, k, n)] = a0 - p;
                h[at(i, k + 1, n)] = a1 - p * w1;
            }
            h[at(k + 1, k - 1, n)] = 0.0;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::test_util::matched_distance as distance;
    use faer::linalg::solvers::DenseSolveCore;

    /// Against faer's general eigenvalue driver (an independent implementation): random
    /// matrices of orders 1–40 with well separated spectra, companion matrices of damped
    /// oscillator chains (the structure of Hill's matrix), and matrices with known
    /// eigenvalues (a similarity of a block diagonal with complex pairs).
    #[test]
    fn eigenvalues_match_faer_and_known_spectra() {
        let mut next = crate::dense::test_util::uniform(0x9e37_79b9_7f4a_7c15);
        let (mut work, mut out) = (Vec::new(), Vec::new());
        for trial in 0..120 {
            let n = 1 + trial % 40;
            let a = Mat::from_fn(n, n, |_, _| next());
            out.clear();
            eigenvalues_into(&a, &mut work, &mut out).unwrap();
            let reference = a.eigenvalues().unwrap();
            let d = distance(&out, &reference, a.norm_max() * n as f64);
            // Random matrices have condition numbers of eigenvalues up to ~1e3: both
            // backward stable solvers then agree to ~1e3 ε.
            assert!(d < 1e-10, "random trial {trial}, n = {n}: {d:e}");
        }
        // Known spectra: V diag-blocks V⁻¹ with blocks [[σ, ω], [−ω, σ]].
        for trial in 0..20 {
            let pairs = 1 + trial % 8;
            let n = 2 * pairs;
            let mut d = Mat::<f64>::zeros(n, n);
            let mut known = Vec::new();
            for p in 0..pairs {
                let (s, w) = (-0.01 * (p + 1) as f64, 0.3 + 0.7 * p as f64);
                d[(2 * p, 2 * p)] = s;
                d[(2 * p + 1, 2 * p + 1)] = s;
                d[(2 * p, 2 * p + 1)] = w;
                d[(2 * p + 1, 2 * p)] = -w;
                known.extend([c64::new(s, w), c64::new(s, -w)]);
            }
            let v = Mat::from_fn(n, n, |i, j| f64::from(u8::from(i == j)) + 0.2 * next());
            let vinv = v.partial_piv_lu().inverse();
            let a = &v * &d * &vinv;
            out.clear();
            eigenvalues_into(&a, &mut work, &mut out).unwrap();
            let dist = distance(&out, &known, 1.0);
            assert!(dist < 1e-12, "known trial {trial}: {dist:e}");
        }
        // Companion matrices [[0, I], [−K, −C]] of oscillator chains: eigenvalues near the
        // imaginary axis over a wide range of frequencies.
        for m in [1, 3, 8, 20] {
            let n = 2 * m;
            let mut a = Mat::<f64>::zeros(n, n);
            for i in 0..m {
                a[(i, m + i)] = 1.0;
                let k = (1.0 + i as f64).powi(2);
                a[(m + i, i)] = -2.0 * k;
                if i > 0 {
                    a[(m + i, i - 1)] = k;
                    a[(m + i - 1, i)] = k;
                }
                a[(m + i, m + i)] = -0.02;
            }
            out.clear();
            eigenvalues_into(&a, &mut work, &mut out).unwrap();
            let reference = a.eigenvalues().unwrap();
            let d = distance(&out, &reference, a.norm_max());
            assert!(d < 1e-12, "companion m = {m}: {d:e}");
        }
        // Degenerate: zero, identity, a Jordan block, a non-finite entry.
        for a in [
            Mat::<f64>::zeros(5, 5),
            Mat::<f64>::identity(6, 6),
            Mat::from_fn(4, 4, |i, j| {
                f64::from(u8::from(j == i + 1)) + 2.0 * f64::from(u8::from(i == j))
            }),
        ] {
            out.clear();
            eigenvalues_into(&a, &mut work, &mut out).unwrap();
            assert_eq!(out.len(), a.nrows());
            let reference = a.eigenvalues().unwrap();
            // A Jordan block of order 4: eigenvalues perturbed by ε^(1/4).
            assert!(distance(&out, &reference, 1.0) < 1e-3);
        }
        let mut bad = Mat::<f64>::identity(3, 3);
        bad[(1, 2)] = f64::NAN;
        assert!(eigenvalues_into(&bad, &mut work, &mut out).is_err());
    }
}
