//! Small dense helpers: LU with the determinant's sign, norms.

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

    /// Sign of `det A`: the signs of `U`'s diagonal times the parity of the row permutation.
    pub(crate) fn det_sign(&self) -> f64 {
        let u = self.lu.U();
        let mut s = (0..self.n).fold(1.0, |s, i| s * u[(i, i)].signum());
        let (fwd, _) = self.lu.P().arrays();
        let mut seen = vec![false; self.n];
        for i in 0..self.n {
            if seen[i] {
                continue;
            }
            let mut len = 0;
            let mut j = i;
            while !seen[j] {
                seen[j] = true;
                j = fwd[j];
                len += 1;
            }
            if len % 2 == 0 {
                s = -s;
            }
        }
        s
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
    v.iter().fold(0.0f64, |m, x| m.max(x.abs()))
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(lu.det_sign(), -1.0);
        let x = lu.solve(&[2.0, -1.0, 3.0]);
        assert!(
            (x[0] - 1.0).abs() < 1e-15 && (x[1] - 1.0).abs() < 1e-15 && (x[2] - 1.0).abs() < 1e-15
        );
    }
}
