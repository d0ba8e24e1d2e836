//! `Y = A X` for a sparse symmetric `A` (both triangles stored) and a block of a few vectors:
//! the products with `M` of every Lanczos step and the residuals of the finished modes.
//!
//! Symmetry makes column `j` of `A` its row `j`, so row `j` of `Y` is a gather
//! `Σ_i a_ij X[i, :]` that one thread computes alone. With `X` copied row-major, each stored
//! value is read once and multiplies a contiguous row of the block; rows of `Y` are split into
//! fixed chunks run in parallel, each summed in the stored order: the same bits for any thread
//! count. (faer's general product scatters column by column into a column-major block, about
//! three times slower on the mass matrices of solid meshes with 6-vector blocks.)

use faer::{Mat, MatRef, Par};
use nlsim_kernel::SparseSym;
use pulp::{Arch, Simd, WithSimd};
use rayon::prelude::*;

/// Rows of `Y` per parallel chunk.
const CHUNK: usize = 1024;

struct Rows<'a> {
    a: &'a SparseSym,
    xt: &'a [f64],
    b: usize,
    first: usize,
    out: &'a mut [f64],
}

impl WithSimd for Rows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        // Fixed widths for the usual block sizes: whole vector operations on each row.
        match self.b {
            1 => self.fixed::<1>(),
            2 => self.fixed::<2>(),
            3 => self.fixed::<3>(),
            4 => self.fixed::<4>(),
            5 => self.fixed::<5>(),
            6 => self.fixed::<6>(),
            7 => self.fixed::<7>(),
            8 => self.fixed::<8>(),
            b => {
                for (r, y) in self.out.chunks_exact_mut(b).enumerate() {
                    let (rows, vals) = self.a.col(self.first + r);
                    y.fill(0.0);
                    for (&i, &v) in rows.iter().zip(vals) {
                        let x = &self.xt[i * b..(i + 1) * b];
                        for (yc, &xc) in y.iter_mut().zip(x) {
                            *yc = v.mul_add(xc, *yc);
                        }
                    }
                }
            }
        }
    }
}

impl Rows<'_> {
    #[inline(always)]
    fn fixed<const B: usize>(self) {
        let (xt, _) = self.xt.as_chunks::<B>();
        let (out, _) = self.out.as_chunks_mut::<B>();
        for (r, y) in out.iter_mut().enumerate() {
            let (rows, vals) = self.a.col(self.first + r);
            let mut acc = [0.0f64; B];
            for (&i, &v) in rows.iter().zip(vals) {
                let x = &xt[i];
                for k in 0..B {
                    acc[k] = v.mul_add(x[k], acc[k]);
                }
            }
            *y = acc;
        }
    }
}

/// `A X` for symmetric `A` (`n × n`, both triangles stored) and `X` (`n × b`).
pub(crate) fn symmetric_times(a: &SparseSym, x: MatRef<'_, f64>, par: Par) -> Mat<f64> {
    let (n, b) = (x.nrows(), x.ncols());
    debug_assert_eq!(a.n(), n);
    if b == 0 || n == 0 {
        return Mat::zeros(n, b);
    }
    let mut xt = vec![0.0f64; n * b];
    for c in 0..b {
        let col = x.col(c);
        for i in 0..n {
            xt[i * b + c] = col[i];
        }
    }
    let mut yt = vec![0.0f64; n * b];
    let arch = Arch::new();
    let run = |(k, out): (usize, &mut [f64])| {
        arch.dispatch(Rows {
            a,
            xt: &xt,
            b,
            first: k * CHUNK,
            out,
        })
    };
    if par.degree() > 1 && n > CHUNK {
        yt.par_chunks_mut(CHUNK * b).enumerate().for_each(run);
    } else {
        yt.chunks_mut(CHUNK * b).enumerate().for_each(run);
    }
    Mat::from_fn(n, b, |i, c| yt[i * b + c])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matches_the_general_product_and_any_thread_count() {
        let n = 3000;
        let mut t = Vec::new();
        for i in 0..n {
            t.push((i, i, 4.0 + (i % 7) as f64));
            if i + 1 < n {
                t.push((i + 1, i, -1.0 - 0.25 * (i % 3) as f64));
            }
            if i + 37 < n {
                t.push((i + 37, i, 0.25));
            }
        }
        let a = SparseSym::from_lower_triplets("A", n, &t).unwrap();
        for b in [1, 6, 13] {
            let x = Mat::from_fn(n, b, |i, c| ((i * 31 + c * 17) % 23) as f64 - 11.0);
            let y = symmetric_times(&a, x.as_ref(), Par::Seq);
            // Integer data: both products are exact.
            let reference = a.as_faer() * &x;
            assert_eq!((&y - &reference).norm_max(), 0.0, "b = {b}");
            let y2 = symmetric_times(&a, x.as_ref(), Par::rayon(2));
            assert_eq!(y, y2);
        }
    }
}
