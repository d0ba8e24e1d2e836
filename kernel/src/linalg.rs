//! Dense helpers: the small generalized symmetric eigenproblem, used as the oracle for the
//! sparse solvers and for projected (Rayleigh–Ritz) problems.

use crate::error::{Error, Result};
use faer::{Mat, MatRef, Side};

/// Eigenpairs of `K φ = λ M φ` with `K` symmetric and `M` symmetric positive definite,
/// ascending `λ`, vectors mass-normalised (`φᵀ M φ = 1`).
#[derive(Debug, Clone)]
pub struct DenseEigen {
    /// Eigenvalues `λ = ω²` (rad²/s²), ascending.
    pub values: Vec<f64>,
    /// Mass-normalised eigenvectors as columns.
    pub vectors: Mat<f64>,
}

/// Solves the dense generalized symmetric eigenproblem by Cholesky reduction:
/// `M = L Lᵀ`, `C = L⁻¹ K L⁻ᵀ`, `C y = λ y`, `φ = L⁻ᵀ y`. O(n³): for n up to a few thousand.
pub fn dense_generalized_eigen(k: MatRef<'_, f64>, m: MatRef<'_, f64>) -> Result<DenseEigen> {
    let n = k.nrows();
    if k.ncols() != n || m.nrows() != n || m.ncols() != n {
        return Err(Error::DimensionMismatch {
            what: "dense generalized eigenproblem (K and M must be square and alike)".into(),
            expected: n,
            found: m.nrows(),
        });
    }
    let llt = m.llt(Side::Lower).map_err(|e| Error::NotDefinite {
        matrix: "mass matrix".into(),
        required: "positive definite".into(),
        detail: format!("dense Cholesky failed: {e:?}"),
    })?;
    let l = llt.L();
    // C = L⁻¹ K L⁻ᵀ, formed by two triangular solves.
    let mut c = k.to_owned();
    faer::linalg::triangular_solve::solve_lower_triangular_in_place(l, c.as_mut(), faer::Par::Seq);
    let mut ct = c.transpose().to_owned();
    faer::linalg::triangular_solve::solve_lower_triangular_in_place(l, ct.as_mut(), faer::Par::Seq);
    // Symmetrise against round-off.
    let cs = Mat::from_fn(n, n, |i, j| 0.5 * (ct[(i, j)] + ct[(j, i)]));
    let evd = cs
        .self_adjoint_eigen(Side::Lower)
        .map_err(|e| Error::Numerical {
            what: "dense symmetric eigen decomposition".into(),
            detail: format!("{e:?}"),
        })?;
    let values: Vec<f64> = (0..n).map(|i| evd.S()[i]).collect();
    let mut vectors = evd.U().to_owned();
    faer::linalg::triangular_solve::solve_upper_triangular_in_place(
        l.transpose(),
        vectors.as_mut(),
        faer::Par::Seq,
    );
    Ok(DenseEigen { values, vectors })
}
