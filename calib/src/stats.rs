//! Parameter statistics (thesis §4.6, paper V): the Cramér–Rao bound from the final Jacobian
//! and the noise model, identifiability flags, and the summary of k-fold estimates.

use crate::linalg::Svd;
use faer::Mat;

/// Cramér–Rao bound of the estimates: `Cov ≥ (Jᵀ J)⁻¹` for residuals already weighted by the
/// noise (`J` in physical parameter units), with diagnostics.
#[derive(Debug, Clone)]
pub struct CramerRao {
    /// Covariance bound (parameter units squared); infinite on the diagonal of a parameter in
    /// an unidentifiable direction.
    pub covariance: Mat<f64>,
    /// Standard deviations `√Cov_jj` (parameter units).
    pub std: Vec<f64>,
    /// Relative standard deviations `std_j / |p_j|`.
    pub relative_std: Vec<f64>,
    /// Collinearity index `γ = 1/√λ_min(ĴᵀĴ)` of the Jacobian with unit-norm columns
    /// (Brun et al. 2001): 1 for orthogonal sensitivities; above about 15 the parameters
    /// cannot be told apart.
    pub collinearity: f64,
    /// The pair of parameters with the most correlated estimates and their correlation.
    pub most_correlated: Option<(usize, usize, f64)>,
    /// `2·cost/(m − n)`: about 1 when the noise model is right.
    pub reduced_chi2: f64,
    /// Standard deviations with the noise scaled to the misfit, `std_j · √χ²_red`: the
    /// covariance `s² (JᵀJ)⁻¹`, `s² = χ²_red`, of least squares with an unknown noise level.
    /// Equal to [`CramerRao::std`] in expectation when the noise model is right; the honest
    /// spread when the residuals exceed the noise model (understated noise), though not a
    /// cure for a wrong model.
    pub scaled_std: Vec<f64>,
}

/// A reduced χ² above this says the residuals are well beyond the noise model (σ
/// understated by 40 % or more, or a model that cannot follow the data), and
/// [`CramerRao::misfit_warning`] says so. With the right noise model χ²_red has mean 1 and
/// standard deviation √(2/ν): 2 is more than 7 of them away for ν ≥ 100 points.
pub const CHI2_WARN: f64 = 2.0;

impl CramerRao {
    /// The bound at estimate `p` from `jacobian` (weighted residuals × parameters, physical
    /// units) and the weighted residuals `r`.
    pub fn new(jacobian: &Mat<f64>, r: &[f64], p: &[f64]) -> Self {
        let (m, n) = (jacobian.nrows(), jacobian.ncols());
        // Relative sensitivities J diag(|p|) keep the decomposition well scaled.
        let scale: Vec<f64> = p
            .iter()
            .map(|v| if *v != 0.0 { v.abs() } else { 1.0 })
            .collect();
        let jr = Mat::from_fn(m, n, |i, j| jacobian[(i, j)] * scale[j]);
        let cov_rel = Svd::new(&jr).normal_inverse(1e-12);
        let covariance = Mat::from_fn(n, n, |i, j| cov_rel[(i, j)] * scale[i] * scale[j]);
        let std: Vec<f64> = (0..n).map(|j| covariance[(j, j)].sqrt()).collect();
        let relative_std = (0..n).map(|j| std[j] / scale[j]).collect();
        let norms: Vec<f64> = (0..n)
            .map(|j| (0..m).map(|i| jr[(i, j)] * jr[(i, j)]).sum::<f64>().sqrt())
            .collect();
        let jn = Mat::from_fn(m, n, |i, j| {
            if norms[j] > 0.0 {
                jr[(i, j)] / norms[j]
            } else {
                0.0
            }
        });
        let smin = Svd::new(&jn).s.iter().fold(f64::INFINITY, |a, &b| a.min(b));
        let collinearity = if smin > 0.0 {
            1.0 / smin
        } else {
            f64::INFINITY
        };
        let mut most_correlated = None;
        for i in 0..n {
            for j in i + 1..n {
                let c = cov_rel[(i, j)] / (cov_rel[(i, i)] * cov_rel[(j, j)]).sqrt();
                if c.is_finite()
                    && most_correlated
                        .is_none_or(|(_, _, b): (usize, usize, f64)| c.abs() > b.abs())
                {
                    most_correlated = Some((i, j, c));
                }
            }
        }
        let cost2: f64 = r.iter().map(|v| v * v).sum();
        let reduced_chi2 = if m > n {
            cost2 / (m - n) as f64
        } else {
            f64::NAN
        };
        let scaled_std = std.iter().map(|s| s * reduced_chi2.sqrt()).collect();
        Self {
            covariance,
            std,
            relative_std,
            collinearity,
            most_correlated,
            reduced_chi2,
            scaled_std,
        }
    }

    /// Whether each parameter is poorly identifiable: its relative standard deviation above
    /// 0.5 (or undefined), or it belongs to the most correlated pair while the collinearity
    /// index exceeds 15.
    pub fn poorly_identified(&self) -> Vec<bool> {
        (0..self.std.len())
            .map(|j| {
                self.relative_std[j].is_nan()
                    || self.relative_std[j] > 0.5
                    || (self.collinearity > 15.0
                        && self
                            .most_correlated
                            .is_some_and(|(a, b, _)| a == j || b == j))
            })
            .collect()
    }

    /// A one-line warning when the reduced χ² exceeds [`CHI2_WARN`]: the Cramér–Rao std
    /// assumes the noise model and is `√χ²_red` times smaller than the spread the misfit
    /// implies.
    pub fn misfit_warning(&self) -> Option<String> {
        let c = self.reduced_chi2;
        (c > CHI2_WARN).then(|| {
            format!(
                "reduced chi2 {c:.3} >> 1: the residuals are {:.2}x the noise model (noise \
                 understated, or a model that cannot follow the data); the Cramér–Rao std \
                 assumes the noise model and is {:.2}x smaller than the chi2-scaled std",
                c.sqrt(),
                c.sqrt()
            )
        })
    }
}

/// Mean and covariance of a set of estimates (rows: runs; columns: parameters).
pub fn mean_and_covariance(estimates: &[Vec<f64>]) -> (Vec<f64>, Mat<f64>) {
    let k = estimates.len();
    let n = estimates.first().map_or(0, Vec::len);
    let mean: Vec<f64> = (0..n)
        .map(|j| estimates.iter().map(|e| e[j]).sum::<f64>() / k.max(1) as f64)
        .collect();
    let cov = Mat::from_fn(n, n, |a, b| {
        if k < 2 {
            return f64::NAN;
        }
        estimates
            .iter()
            .map(|e| (e[a] - mean[a]) * (e[b] - mean[b]))
            .sum::<f64>()
            / (k - 1) as f64
    });
    (mean, cov)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn linear_regression_bound_is_the_textbook_one() {
        // y = a + b t with unit noise: Cov = (XᵀX)⁻¹.
        let t = [0.0, 1.0, 2.0, 3.0, 4.0];
        let j = Mat::from_fn(5, 2, |i, c| if c == 0 { 1.0 } else { t[i] });
        let cr = CramerRao::new(&j, &[0.0; 5], &[2.0, 3.0]);
        // XᵀX = [[5, 10], [10, 30]], det 50: inverse [[0.6, −0.2], [−0.2, 0.1]].
        assert!((cr.covariance[(0, 0)] - 0.6).abs() < 1e-12);
        assert!((cr.covariance[(0, 1)] + 0.2).abs() < 1e-12);
        assert!((cr.covariance[(1, 1)] - 0.1).abs() < 1e-12);
        let (i, k, c) = cr.most_correlated.unwrap();
        assert_eq!((i, k), (0, 1));
        assert!((c + 0.2 / (0.6f64 * 0.1).sqrt()).abs() < 1e-12);
        assert!(cr.collinearity > 1.0 && cr.collinearity.is_finite());
        // Zero residuals: χ² 0, no warning, scaled std 0.
        assert_eq!(cr.reduced_chi2, 0.0);
        assert!(cr.misfit_warning().is_none() && cr.scaled_std == vec![0.0, 0.0]);
        // Residuals r = 3 each over 3 degrees of freedom: χ²_red = 15, std scaled by √15.
        let cr = CramerRao::new(&j, &[3.0; 5], &[2.0, 3.0]);
        assert!((cr.reduced_chi2 - 15.0).abs() < 1e-12);
        assert!((cr.scaled_std[1] - (0.1f64 * 15.0).sqrt()).abs() < 1e-12);
        let w = cr.misfit_warning().unwrap();
        assert!(
            w.contains("reduced chi2 15.000") && w.contains("3.87x"),
            "{w}"
        );
    }

    #[test]
    fn identical_columns_are_flagged() {
        let j = Mat::from_fn(4, 2, |i, _| 1.0 + i as f64);
        let cr = CramerRao::new(&j, &[0.0; 4], &[1.0, 1.0]);
        assert!(cr.collinearity > 1e6);
        assert!(cr.std.iter().all(|s| s.is_infinite()));
    }
}
