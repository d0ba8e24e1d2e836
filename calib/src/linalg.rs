//! A small dense singular value decomposition for the tall, thin matrices of calibration
//! (residuals × a few parameters): one-sided Jacobi (Hestenes), accurate to the relative
//! precision of each singular value and sequential, so results do not depend on the thread
//! count.

use faer::Mat;

/// Thin SVD `A = U diag(s) Vᵀ` of an `m × n` matrix (`m ≥ n` or not): `u` is `m × n`,
/// `v` is `n × n`; singular values are not sorted.
#[derive(Debug, Clone)]
pub struct Svd {
    /// Left singular vectors (columns; zero for a zero singular value).
    pub u: Mat<f64>,
    /// Singular values.
    pub s: Vec<f64>,
    /// Right singular vectors (columns).
    pub v: Mat<f64>,
}

impl Svd {
    /// Decomposes `a`.
    pub fn new(a: &Mat<f64>) -> Self {
        let (m, n) = (a.nrows(), a.ncols());
        let mut w = a.clone();
        let mut v = Mat::<f64>::identity(n, n);
        for _sweep in 0..60 {
            let mut rotated = false;
            for p in 0..n {
                for q in p + 1..n {
                    let (mut alpha, mut beta, mut gamma) = (0.0, 0.0, 0.0);
                    for i in 0..m {
                        alpha += w[(i, p)] * w[(i, p)];
                        beta += w[(i, q)] * w[(i, q)];
                        gamma += w[(i, p)] * w[(i, q)];
                    }
                    if gamma == 0.0 || gamma.abs() <= 1e-15 * (alpha * beta).sqrt() {
                        continue;
                    }
                    rotated = true;
                    let zeta = (beta - alpha) / (2.0 * gamma);
                    let t = zeta.signum() / (zeta.abs() + (1.0 + zeta * zeta).sqrt());
                    let t = if zeta == 0.0 { 1.0 } else { t };
                    let c = 1.0 / (1.0 + t * t).sqrt();
                    let s = c * t;
                    for i in 0..m {
                        let (x, y) = (w[(i, p)], w[(i, q)]);
                        w[(i, p)] = c * x - s * y;
                        w[(i, q)] = s * x + c * y;
                    }
                    for i in 0..n {
                        let (x, y) = (v[(i, p)], v[(i, q)]);
                        v[(i, p)] = c * x - s * y;
                        v[(i, q)] = s * x + c * y;
                    }
                }
            }
            if !rotated {
                break;
            }
        }
        let s: Vec<f64> = (0..n)
            .map(|j| (0..m).map(|i| w[(i, j)] * w[(i, j)]).sum::<f64>().sqrt())
            .collect();
        let u = Mat::from_fn(m, n, |i, j| if s[j] > 0.0 { w[(i, j)] / s[j] } else { 0.0 });
        Self { u, s, v }
    }

    /// `(AᵀA)⁺ = V diag(1/s²) Vᵀ`, singular values below `rcond · max s` treated as zero
    /// (their directions get an infinite variance: returned as `f64::INFINITY` on the
    /// diagonal of every parameter they touch).
    pub fn normal_inverse(&self, rcond: f64) -> Mat<f64> {
        let n = self.s.len();
        let smax = self.s.iter().fold(0.0f64, |a, &b| a.max(b));
        let mut out = Mat::<f64>::zeros(n, n);
        for k in 0..n {
            if self.s[k] <= rcond * smax || self.s[k] == 0.0 {
                for i in 0..n {
                    if self.v[(i, k)].abs() > 1e-8 {
                        out[(i, i)] = f64::INFINITY;
                    }
                }
                continue;
            }
            let w = 1.0 / (self.s[k] * self.s[k]);
            for i in 0..n {
                for j in 0..n {
                    out[(i, j)] += self.v[(i, k)] * w * self.v[(j, k)];
                }
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reconstructs_and_is_orthogonal() {
        let a = Mat::from_fn(7, 3, |i, j| {
            ((i * 3 + j * 5) % 7) as f64 - 2.5 + (i == j) as u8 as f64
        });
        let svd = Svd::new(&a);
        for i in 0..7 {
            for j in 0..3 {
                let r: f64 = (0..3)
                    .map(|k| svd.u[(i, k)] * svd.s[k] * svd.v[(j, k)])
                    .sum();
                assert!(
                    (r - a[(i, j)]).abs() < 1e-13,
                    "({i},{j}) {r} vs {}",
                    a[(i, j)]
                );
            }
        }
        for p in 0..3 {
            for q in 0..3 {
                let d: f64 = (0..7).map(|i| svd.u[(i, p)] * svd.u[(i, q)]).sum();
                let e: f64 = (0..3).map(|i| svd.v[(i, p)] * svd.v[(i, q)]).sum();
                let want = (p == q) as u8 as f64;
                assert!((d - want).abs() < 1e-13 && (e - want).abs() < 1e-13);
            }
        }
    }

    #[test]
    fn normal_inverse_equals_the_inverse_of_the_normal_matrix() {
        let a = Mat::from_fn(5, 2, |i, j| 1.0 + (i as f64) * (j as f64 + 0.5));
        let ata = a.transpose() * &a;
        let inv = Svd::new(&a).normal_inverse(1e-14);
        let id = &ata * &inv;
        for i in 0..2 {
            for j in 0..2 {
                assert!((id[(i, j)] - (i == j) as u8 as f64).abs() < 1e-10);
            }
        }
    }
}
