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
    let (values, mut vectors) = symmetric_eigen(cs.as_ref())?;
    faer::linalg::triangular_solve::solve_upper_triangular_in_place(
        l.transpose(),
        vectors.as_mut(),
        faer::Par::Seq,
    );
    Ok(DenseEigen { values, vectors })
}

/// Eigen decomposition `A = U diag(s) Uᵀ` of a dense symmetric matrix (lower triangle read),
/// ascending `s`.
///
/// The matrix is scaled to unit largest entry first: faer 0.24's `self_adjoint_eigen` loses
/// accuracy on matrices of large norm (measured: residual `‖AU − US‖ / ‖A‖ ≈ 1e-3` at
/// `‖A‖ ≈ 5e12`, 819 × 819, against `2e-15` after scaling), so every symmetric eigen solve of
/// nlsim goes through here.
pub fn symmetric_eigen(a: MatRef<'_, f64>) -> Result<(Vec<f64>, Mat<f64>)> {
    let n = a.nrows();
    if a.ncols() != n {
        return Err(Error::DimensionMismatch {
            what: "symmetric eigen decomposition (the matrix must be square)".into(),
            expected: n,
            found: a.ncols(),
        });
    }
    let mut scale = 0.0f64;
    for j in 0..n {
        for i in j..n {
            let v = a[(i, j)];
            if !v.is_finite() {
                return Err(Error::NonFinite {
                    what: "matrix of a symmetric eigen decomposition".into(),
                    location: format!("entry ({i}, {j})"),
                    value: v,
                });
            }
            scale = scale.max(v.abs());
        }
    }
    if scale == 0.0 {
        return Ok((vec![0.0; n], Mat::identity(n, n)));
    }
    let scaled = Mat::from_fn(n, n, |i, j| a[(i, j)] / scale);
    let evd = scaled
        .self_adjoint_eigen(Side::Lower)
        .map_err(|e| Error::Numerical {
            what: "dense symmetric eigen decomposition".into(),
            detail: format!("{e:?}"),
        })?;
    let values = (0..n).map(|i| evd.S()[i] * scale).collect();
    Ok((values, evd.U().to_owned()))
}

/// Eigenpairs of `K φ = λ M φ` as [`dense_generalized_eigen`], but accurate relative to each
/// eigenvalue at the low end of the spectrum when `K` is positive definite.
///
/// Reducing with `M = L Lᵀ` gives every eigenvalue an absolute error of about `ε λ_max`, so the
/// lowest modes of a stiff model (`λ_max / λ_1 ≈ 10⁹` for a frame) lose up to nine digits. With
/// `K` positive definite this solves the inverted pencil `M ψ = μ K ψ` instead (`μ = 1/λ`, errors
/// `ε μ_max = ε / λ_1`), and returns `λ = 1/μ` ascending with `φ = ψ √λ` mass-normalised. A
/// singular `K` (free–free) falls back to the direct reduction.
pub fn dense_generalized_eigen_low(k: MatRef<'_, f64>, m: MatRef<'_, f64>) -> Result<DenseEigen> {
    if k.nrows() != k.ncols() || k.llt(Side::Lower).is_err() {
        return dense_generalized_eigen(k, m);
    }
    let inv = dense_generalized_eigen(m, k)?;
    let n = inv.values.len();
    if inv.values.iter().any(|&mu| mu <= 0.0) {
        return dense_generalized_eigen(k, m);
    }
    let values: Vec<f64> = (0..n).rev().map(|i| 1.0 / inv.values[i]).collect();
    let vectors = Mat::from_fn(n, n, |r, c| {
        let src = n - 1 - c;
        inv.vectors[(r, src)] * values[c].sqrt()
    });
    Ok(DenseEigen { values, vectors })
}
