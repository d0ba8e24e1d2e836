//! Small dense helpers: LU with the determinant's sign, norms.

use faer::Mat;
use faer::linalg::solvers::{PartialPivLu, Solve};
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
