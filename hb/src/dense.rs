//! Small dense helpers: LU (in place, with the determinant's sign), norms.

use faer::dyn_stack::{MemBuffer, MemStack, StackReq};
use faer::linalg::lu::partial_pivoting::{factor, solve};
use faer::linalg::solvers::{PartialPivLu, Solve};
use faer::perm::PermRef;
use faer::{Mat, MatMut, Par};
use nlsim_kernel::{Error, Result};

/// A factorised square matrix.
pub(crate) struct Lu {
    lu: PartialPivLu<f64>,
    n: usize,
}

impl Lu {
    /// Factorises `a`; errors naming `what` when `a` is singular or not finite.
    pub(crate) fn new(a: &Mat<f64>, what: &dyn Fn() -> String) -> Result<Self> {
        let lu = a.partial_piv_lu();
        let u = lu.U();
        let scale = a.norm_max();
        if !scale.is_finite() || (0..a.nrows()).any(|i| !u[(i, i)].is_finite() || u[(i, i)] == 0.0)
        {
            return Err(Error::Numerical {
                what: what(),
                detail: "the Jacobian is singular or not finite".into(),
            });
        }
        Ok(Self { lu, n: a.nrows() })
    }

    /// `A⁻¹ b`.
    pub(crate) fn solve(&self, b: &[f64]) -> Vec<f64> {
        let rhs = Mat::from_fn(self.n, 1, |i, _| b[i]);
        let x = self.lu.solve(&rhs);
        (0..self.n).map(|i| x[(i, 0)]).collect()
    }
}

/// An LU with partial pivoting factorised in buffers it keeps: after the first matrix of an
/// order, factorising and solving allocate nothing. The same faer kernels as
/// [`PartialPivLu`], run sequentially.
pub(crate) struct LuInPlace {
    lu: Mat<f64>,
    fwd: Vec<usize>,
    bwd: Vec<usize>,
    stack: Option<MemBuffer>,
}

impl Default for LuInPlace {
    fn default() -> Self {
        Self {
            lu: Mat::new(),
            fwd: Default::default(),
            bwd: Default::default(),
            stack: Default::default(),
        }
    }
}

impl std::fmt::Debug for LuInPlace {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "LuInPlace({}×{})", self.lu.nrows(), self.lu.ncols())
    }
}

impl LuInPlace {
    /// Factorises `a`; `false` when it is singular or not finite (as [`Lu::new`] refuses).
    pub(crate) fn factor(&mut self, a: &Mat<f64>) -> bool {
        let n = a.nrows();
        if self.lu.nrows() != n || self.stack.is_none() {
            self.lu = Mat::zeros(n, n);
            self.fwd = vec![0; n];
            self.bwd = vec![0; n];
            let req = StackReq::or(
                factor::lu_in_place_scratch::<usize, f64>(n, n, Par::Seq, Default::default()),
                solve::solve_in_place_scratch::<usize, f64>(n, 1, Par::Seq),
            );
            self.stack = Some(MemBuffer::new(req));
        }
        let scale = a.norm_max();
        self.lu.copy_from(a);
        let stack = self.stack.as_mut().expect("sized above");
        factor::lu_in_place(
            self.lu.as_mut(),
            &mut self.fwd,
            &mut self.bwd,
            Par::Seq,
            MemStack::new(stack),
            Default::default(),
        );
        scale.is_finite() && (0..n).all(|i| self.lu[(i, i)].is_finite() && self.lu[(i, i)] != 0.0)
    }

    /// Sign of `det A` of the last matrix factorised: the signs of `U`'s diagonal times the
    /// parity of the row permutation (cycles counted in place: no allocation).
    pub(crate) fn det_sign(&self) -> f64 {
        let n = self.lu.nrows();
        let mut s = (0..n).fold(1.0, |s, i| s * self.lu[(i, i)].signum());
        // The parity of a permutation is that of n minus its number of cycles; a cycle is
        // counted at its smallest member.
        let mut cycles = 0usize;
        for i in 0..n {
            let mut j = self.fwd[i];
            while j > i {
                j = self.fwd[j];
            }
            if j == i {
                cycles += 1;
            }
        }
        if (n - cycles) % 2 == 1 {
            s = -s;
        }
        s
    }

    /// `A⁻¹ b` in place, `A` the last matrix factorised.
    pub(crate) fn solve_in_place(&mut self, b: &mut [f64]) {
        let n = self.lu.nrows();
        let perm = PermRef::new_checked(&self.fwd, &self.bwd, n);
        let rhs = MatMut::from_column_major_slice_mut(b, n, 1);
        let stack = self.stack.as_mut().expect("factorised first");
        solve::solve_in_place(
            self.lu.as_ref(),
            self.lu.as_ref(),
            perm,
            rhs,
            Par::Seq,
            MemStack::new(stack),
        );
    }
}

/// Largest absolute entry.
pub(crate) fn norm_inf(v: &[f64]) -> f64 {
    // NaN propagates (`f64::max` would drop it): a residual holding NaN is not small.
    v.iter().fold(0.0f64, |m, x| {
        if x.is_nan() || m.is_nan() {
            f64::NAN
        } else {
            m.max(x.abs())
        }
    })
}

/// Helpers of this crate's unit tests.
#[cfg(test)]
pub(crate) mod test_util {
    use faer::c64;

    /// Uniform draws in `[−1/2, 1/2)` from a xorshift generator with `seed` (non-zero).
    pub(crate) fn uniform(mut seed: u64) -> impl FnMut() -> f64 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        }
    }

    /// Each value of `a` matched to its nearest in `b` (removed once matched; the order of
    /// a pair with rounding-level imaginary parts is arbitrary): the largest distance over
    /// `scale`. The lengths must agree.
    pub(crate) fn matched_distance(a: &[c64], b: &[c64], scale: f64) -> f64 {
        assert_eq!(a.len(), b.len());
        let mut left = b.to_vec();
        let mut worst = 0.0f64;
        for x in a {
            let (i, d) = left
                .iter()
                .enumerate()
                .map(|(i, y)| (i, (x - y).norm()))
                .min_by(|p, q| p.1.total_cmp(&q.1))
                .unwrap();
            worst = worst.max(d / scale);
            left.swap_remove(i);
        }
        worst
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::c64;

    #[test]
    fn determinant_sign_matches_a_permutation_and_signs() {
        // [[0, 2, 0], [0, 0, -1], [3, 0, 0]]: det = 0·… expanded = 3·(2·(-1) − 0) = −6
        let a = Mat::from_fn(3, 3, |i, j| match (i, j) {
            (0, 1) => 2.0,
            (1, 2) => -1.0,
            (2, 0) => 3.0,
            _ => 0.0,
        });
        let lu = Lu::new(&a, &|| "test".into()).unwrap();
        let x = lu.solve(&[2.0, -1.0, 3.0]);
        assert!(
            (x[0] - 1.0).abs() < 1e-15 && (x[1] - 1.0).abs() < 1e-15 && (x[2] - 1.0).abs() < 1e-15
        );
        let mut ip = LuInPlace::default();
        assert!(ip.factor(&a));
        assert_eq!(ip.det_sign(), -1.0);
    }

    /// The in-place LU's determinant sign against the product of the eigenvalues' (a dense
    /// oracle) on random matrices of orders 1–9, pivoting through every kind of permutation.
    #[test]
    fn in_place_determinant_sign_matches_the_eigenvalue_product() {
        let mut next = test_util::uniform(0x2545_f491_4f6c_dd1d);
        let mut ip = LuInPlace::default();
        for trial in 0..200 {
            let n = 1 + trial % 9;
            let a = Mat::from_fn(n, n, |_, _| next());
            let ev = a.eigenvalues().unwrap();
            let prod = ev.iter().fold(c64::new(1.0, 0.0), |p, z| p * z);
            assert!(prod.re.abs() > 1e-9 * prod.norm(), "trial {trial}");
            assert!(ip.factor(&a));
            assert_eq!(ip.det_sign(), prod.re.signum(), "trial {trial} (n = {n})");
        }
    }
}
