//! Quadratic forms `xᵀ A x` of sparse symmetric matrices, accurate where the terms cancel.
//!
//! A Rayleigh quotient `φᵀKφ / φᵀMφ` of a low mode of a stiff structure sums terms many orders
//! of magnitude larger than the result (`xᵀ|K|x ≫ xᵀKx`); a rounded product `xᵀ(Kx)` is off by
//! up to `ε xᵀ|K|x`. Here every term `a_ij x_i x_j` is formed with error-free products (fused
//! multiply–add) and summed with error-free additions (TwoSum), the rounding errors gathered in a
//! second accumulator — Ogita, Rump and Oishi's `Dot2`, whose result is as accurate as a sum in
//! twice the working precision: `|error| ≤ ε|xᵀAx| + O(n ε²) xᵀ|A|x`.
//!
//! Speed: the lower triangle only (`xᵀAx = Σ a_jj x_j² + 2 Σ_{i>j} a_ij x_i x_j`, the factor 2
//! exact), several vectors per pass over the matrix, the lanes vectorised with fused
//! multiply–add where the processor has it (through `pulp`), and the columns of `A` split into
//! fixed chunks summed in parallel and combined in chunk order: the same bits for any thread
//! count.

use faer::{MatRef, Par};
use nlsim_kernel::SparseSym;
use pulp::{Arch, Simd, WithSimd};
use rayon::prelude::*;

/// Vectors per pass over the matrix.
const LANES: usize = 8;
/// Matrix columns per chunk (the unit of parallel work; fixed, for bit-identical results).
const CHUNK: usize = 2048;

/// A double-double partial sum per lane: `hi + lo`.
#[derive(Clone, Copy)]
struct Acc {
    hi: [f64; LANES],
    lo: [f64; LANES],
}

impl Acc {
    const ZERO: Acc = Acc {
        hi: [0.0; LANES],
        lo: [0.0; LANES],
    };

    /// Adds another partial sum (TwoSum on the high parts).
    fn merge(&mut self, o: &Acc) {
        for l in 0..LANES {
            let (s, t) = two_sum(self.hi[l], o.hi[l]);
            self.hi[l] = s;
            self.lo[l] += t + o.lo[l];
        }
    }
}

#[inline(always)]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

/// One chunk of columns of the lower triangle against `LANES` vectors stored row-major in `xt`.
struct Chunk<'a> {
    a: &'a SparseSym,
    xt: &'a [f64],
    cols: core::ops::Range<usize>,
}

impl WithSimd for Chunk<'_> {
    type Output = Acc;

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) -> Acc {
        let mut acc = Acc::ZERO;
        for j in self.cols {
            let (rows, vals) = self.a.col(j);
            let xj: &[f64; LANES] = self.xt[j * LANES..(j + 1) * LANES]
                .try_into()
                .expect("LANES values per row");
            for (&i, &v) in rows.iter().zip(vals) {
                if i < j {
                    continue;
                }
                // Off-diagonal terms count twice (exactly: a power of two).
                let v = if i == j { v } else { 2.0 * v };
                let xi: &[f64; LANES] = self.xt[i * LANES..(i + 1) * LANES]
                    .try_into()
                    .expect("LANES values per row");
                for l in 0..LANES {
                    // v·x_i = p + e and p·x_j = q + f exactly; e·x_j rounded, far below.
                    let p = v * xi[l];
                    let e = v.mul_add(xi[l], -p);
                    let q = p * xj[l];
                    let f = p.mul_add(xj[l], -q);
                    let (s, t) = two_sum(acc.hi[l], q);
                    acc.hi[l] = s;
                    acc.lo[l] += t + e.mul_add(xj[l], f);
                }
            }
        }
        acc
    }
}

/// `x_cᵀ A x_c` for every column `c` of `x` (A symmetric, both triangles stored; only the lower
/// one is read), each accurate to a few units in the last place of the result.
pub(crate) fn quadratic_forms(a: &SparseSym, x: MatRef<'_, f64>, par: Par) -> Vec<f64> {
    let n = a.n();
    debug_assert_eq!(x.nrows(), n);
    let arch = Arch::new();
    let mut out = Vec::with_capacity(x.ncols());
    let mut xt = vec![0.0f64; n * LANES];
    for c0 in (0..x.ncols()).step_by(LANES) {
        let width = LANES.min(x.ncols() - c0);
        for i in 0..n {
            for l in 0..LANES {
                xt[i * LANES + l] = if l < width { x[(i, c0 + l)] } else { 0.0 };
            }
        }
        let chunks = n.div_ceil(CHUNK);
        let run = |k: usize| {
            arch.dispatch(Chunk {
                a,
                xt: &xt,
                cols: k * CHUNK..((k + 1) * CHUNK).min(n),
            })
        };
        let parts: Vec<Acc> = if par.degree() > 1 && chunks > 1 {
            (0..chunks).into_par_iter().map(run).collect()
        } else {
            (0..chunks).map(run).collect()
        };
        let mut total = Acc::ZERO;
        for p in &parts {
            total.merge(p);
        }
        out.extend((0..width).map(|l| total.hi[l] + total.lo[l]));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stiff chain (`2²⁷` springs) with a soft diagonal (`2⁻¹⁰`), against vectors near the
    /// chain's null mode: every value, product and the reference sum below are exact binary
    /// numbers (the vectors carry 22 bits, their squares 44, the sum of 4096 squares 53), so
    /// the reference is exact to the last three roundings.
    #[test]
    fn cancelling_terms_keep_their_small_sum() {
        let n = 4096;
        let (big, soft) = (2f64.powi(27), 2f64.powi(-10));
        let mut t = Vec::new();
        for i in 0..n {
            let d = if i == 0 || i == n - 1 { big } else { 2.0 * big };
            t.push((i, i, d + soft));
            if i + 1 < n {
                t.push((i + 1, i, -big));
            }
        }
        let a = SparseSym::from_lower_triplets("A", n, &t).unwrap();
        let h = 2f64.powi(-20);
        let x = faer::Mat::from_fn(n, 11, |i, c| 1.0 + ((c % 3) as f64) * h * i as f64);
        let q = quadratic_forms(&a, x.as_ref(), Par::Seq);
        let exact = |c: usize| {
            let dx = (c % 3) as f64 * h;
            let sq: f64 = (0..n).map(|i| (1.0 + dx * i as f64).powi(2)).sum();
            big * (n - 1) as f64 * dx * dx + soft * sq
        };
        for c in 0..11 {
            let e = exact(c);
            assert!(
                ((q[c] - e) / e).abs() < 1e-15,
                "column {c}: {} vs {e}",
                q[c]
            );
        }
        // The rounded product loses digits: xᵀ|A|x ≈ 2²⁹ n against a sum near 6.
        let ax = a.as_faer() * x.col(2);
        let naive = x.col(2).transpose() * &ax;
        assert!(
            ((naive - exact(2)) / exact(2)).abs() > 1e-10,
            "naive {naive}"
        );
        // Any thread count, the same bits.
        assert_eq!(q, quadratic_forms(&a, x.as_ref(), Par::rayon(2)));
    }
}
