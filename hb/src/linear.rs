//! Receptances of the reduced model (thesis eq. 9–10 in the frequency domain):
//!
//! `H(ω) = Φ_P Z(ω)⁻¹ Φ_Pᵀ + D`,  `Z(ω) = Ω² − ω² I + iω C̃`
//!
//! with `Φ_P` the modal participation at the ports, `Ω²` the retained eigenvalues, `C̃` the
//! modal damping matrix (diagonal for proportional damping) and `D` the residual flexibility
//! of the truncated modes. Derivatives with respect to `ω` (continuation) and to the linear
//! parameters (sensitivities) are analytic.

use faer::linalg::solvers::Solve;
use faer::{Mat, c64};
use nlsim_kernel::{Error, Result};
use nlsim_reduction::ReducedModel;
use std::f64::consts::PI;

/// A linear model parameter whose sensitivity can be computed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LinearParam {
    /// Natural frequency `f_r` (Hz) of retained mode `r` (0-based), its damping ratio held.
    ModalFrequency(usize),
    /// Damping ratio `ζ_r` of retained mode `r`, `c̃_rr = 2 ζ_r ω_r`.
    DampingRatio(usize),
    /// Scaling `κ` of the stiffness (nominal 1): `Ω² → κ Ω²`, `D → D/κ`, damping held.
    StiffnessScale,
}

impl LinearParam {
    /// A display name: `mode3.f`, `mode3.zeta`, `stiffness_scale` (modes 1-based).
    pub fn name(&self) -> String {
        match self {
            LinearParam::ModalFrequency(r) => format!("mode{}.f", r + 1),
            LinearParam::DampingRatio(r) => format!("mode{}.zeta", r + 1),
            LinearParam::StiffnessScale => "stiffness_scale".into(),
        }
    }
}

/// The linear part of the reduced model as seen from its ports.
#[derive(Debug, Clone)]
pub struct LinearPart {
    /// Retained eigenvalues `ω_r²` (rad²/s²).
    pub w2: Vec<f64>,
    /// Modal damping matrix `C̃` (modes × modes; 1/s).
    pub damping: Mat<f64>,
    /// True when `C̃` is diagonal (proportional damping): receptances are then a plain sum.
    pub diagonal: bool,
    /// Modal participation `Φ_P` (ports × modes; m/√kg).
    pub phi: Mat<f64>,
    /// Residual flexibility `D` (ports × ports; m/N).
    pub residual: Mat<f64>,
}

/// `Z(ω)⁻¹ Φ_Pᵀ` restricted to some ports, for a full (non-diagonal) `C̃`.
enum ModalSolve {
    Diagonal(Vec<c64>),
    Full(faer::linalg::solvers::PartialPivLu<c64>),
}

impl LinearPart {
    /// The linear part of `reduced`. Errors on a rigid-body mode (the static harmonic needs a
    /// supported structure) or non-finite data.
    pub fn from_reduced(reduced: &ReducedModel) -> Result<Self> {
        let w2 = reduced.modes.eigenvalues.clone();
        let lmax = w2.iter().fold(0.0f64, |a, l| a.max(l.abs()));
        if let Some(r) = w2.iter().position(|&l| l <= 1e-9 * lmax) {
            return Err(Error::invalid(
                "harmonic balance",
                format!(
                    "mode {} is a rigid-body mode (ω² = {:.3e}); the static harmonic of a \
                     periodic response needs a supported structure",
                    r + 1,
                    w2[r]
                ),
            ));
        }
        let damping = reduced.modal_damping_matrix();
        let m = w2.len();
        let diagonal = (0..m).all(|r| (0..m).all(|s| r == s || damping[(r, s)] == 0.0));
        Ok(Self {
            w2,
            damping,
            diagonal,
            phi: reduced.participation.clone(),
            residual: reduced.residual.clone(),
        })
    }

    /// Number of retained modes.
    pub fn n_modes(&self) -> usize {
        self.w2.len()
    }

    /// Damping ratio `ζ_r = c̃_rr / (2 ω_r)` of mode `r`.
    pub fn zeta(&self, r: usize) -> f64 {
        self.damping[(r, r)] / (2.0 * self.w2[r].sqrt())
    }

    /// The modal dynamic stiffness `Z(ω)` (modes × modes).
    pub fn dynamic_stiffness(&self, omega: f64) -> Mat<c64> {
        let m = self.n_modes();
        Mat::from_fn(m, m, |r, s| {
            let d = c64::new(0.0, omega * self.damping[(r, s)]);
            if r == s {
                d + c64::new(self.w2[r] - omega * omega, 0.0)
            } else {
                d
            }
        })
    }

    fn solve(&self, omega: f64) -> ModalSolve {
        if self.diagonal {
            ModalSolve::Diagonal(
                (0..self.n_modes())
                    .map(|r| {
                        c64::new(self.w2[r] - omega * omega, omega * self.damping[(r, r)]).inv()
                    })
                    .collect(),
            )
        } else {
            ModalSolve::Full(self.dynamic_stiffness(omega).partial_piv_lu())
        }
    }

    /// `Z⁻¹ Φ_{cols}ᵀ` (modes × cols).
    fn zinv_phi(&self, z: &ModalSolve, cols: &[usize]) -> Mat<c64> {
        let m = self.n_modes();
        let pt = Mat::from_fn(m, cols.len(), |r, j| c64::new(self.phi[(cols[j], r)], 0.0));
        match z {
            ModalSolve::Diagonal(d) => Mat::from_fn(m, cols.len(), |r, j| d[r] * pt[(r, j)]),
            ModalSolve::Full(lu) => lu.solve(&pt),
        }
    }

    fn phi_rows(&self, rows: &[usize]) -> Mat<c64> {
        Mat::from_fn(rows.len(), self.n_modes(), |i, r| {
            c64::new(self.phi[(rows[i], r)], 0.0)
        })
    }

    /// Receptance `H(ω)` (m/N) between port `rows` and port `cols`, `omega` in rad/s.
    pub fn receptance(&self, omega: f64, rows: &[usize], cols: &[usize]) -> Mat<c64> {
        let z = self.solve(omega);
        let x = self.zinv_phi(&z, cols);
        let mut h = self.phi_rows(rows) * &x;
        for (i, &a) in rows.iter().enumerate() {
            for (j, &b) in cols.iter().enumerate() {
                h[(i, j)] += c64::new(self.residual[(a, b)], 0.0);
            }
        }
        h
    }

    /// `∂H/∂ω` (m s/N) between `rows` and `cols`: `−Φ Z⁻¹ (−2ω I + i C̃) Z⁻¹ Φᵀ`.
    pub fn receptance_domega(&self, omega: f64, rows: &[usize], cols: &[usize]) -> Mat<c64> {
        let m = self.n_modes();
        let dz = Mat::from_fn(m, m, |r, s| {
            let d = c64::new(0.0, self.damping[(r, s)]);
            if r == s {
                d - c64::new(2.0 * omega, 0.0)
            } else {
                d
            }
        });
        self.sandwich(omega, rows, cols, &dz, 0.0)
    }

    /// `∂H/∂θ` (m/N per unit of θ) for linear parameter `p` at `omega` (rad/s).
    pub fn receptance_dparam(
        &self,
        p: LinearParam,
        omega: f64,
        rows: &[usize],
        cols: &[usize],
    ) -> Result<Mat<c64>> {
        let m = self.n_modes();
        let mut dz = Mat::<c64>::zeros(m, m);
        let mut dd = 0.0;
        match p {
            LinearParam::ModalFrequency(r) | LinearParam::DampingRatio(r) if r >= m => {
                return Err(Error::invalid(
                    format!("parameter {}", p.name()),
                    format!("the model keeps {m} modes"),
                ));
            }
            LinearParam::ModalFrequency(r) => {
                // Z_rr = ω_r² − ω² + 2iζ_r ω_r ω with ζ_r held; ∂/∂f_r = 2π ∂/∂ω_r.
                let wr = self.w2[r].sqrt();
                dz[(r, r)] = c64::new(2.0 * wr, 2.0 * self.zeta(r) * omega) * (2.0 * PI);
            }
            LinearParam::DampingRatio(r) => {
                dz[(r, r)] = c64::new(0.0, 2.0 * self.w2[r].sqrt() * omega);
            }
            LinearParam::StiffnessScale => {
                for r in 0..m {
                    dz[(r, r)] = c64::new(self.w2[r], 0.0);
                }
                dd = -1.0;
            }
        }
        Ok(self.sandwich(omega, rows, cols, &dz, dd))
    }

    /// `−Φ_rows Z⁻¹ dZ Z⁻¹ Φ_colsᵀ + dd · D`.
    fn sandwich(
        &self,
        omega: f64,
        rows: &[usize],
        cols: &[usize],
        dz: &Mat<c64>,
        dd: f64,
    ) -> Mat<c64> {
        let z = self.solve(omega);
        let x = self.zinv_phi(&z, cols);
        // Z is symmetric, so Φ_rows Z⁻¹ = (Z⁻¹ Φ_rowsᵀ)ᵀ.
        let y = self.zinv_phi(&z, rows);
        let mut h = -(y.transpose() * (dz * &x));
        if dd != 0.0 {
            for (i, &a) in rows.iter().enumerate() {
                for (j, &b) in cols.iter().enumerate() {
                    h[(i, j)] += c64::new(dd * self.residual[(a, b)], 0.0);
                }
            }
        }
        h
    }

    /// Modal amplitudes `η = Z(ω)⁻¹ Φ_Pᵀ u` (√kg m) of port forces `u` (N) at `omega`.
    pub fn modal_response(&self, omega: f64, ports: &[usize], u: &[c64]) -> Vec<c64> {
        let z = self.solve(omega);
        let x = self.zinv_phi(&z, ports);
        (0..self.n_modes())
            .map(|r| (0..ports.len()).map(|j| x[(r, j)] * u[j]).sum())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn two_mode(full: bool) -> LinearPart {
        let mut damping = Mat::from_fn(2, 2, |r, s| if r == s { 0.5 + r as f64 } else { 0.0 });
        if full {
            damping[(0, 1)] = 0.2;
            damping[(1, 0)] = 0.2;
        }
        LinearPart {
            w2: vec![400.0, 2500.0],
            diagonal: !full,
            damping,
            phi: Mat::from_fn(3, 2, |p, r| 0.3 + 0.2 * p as f64 - 0.5 * r as f64),
            residual: Mat::from_fn(3, 3, |a, b| 1e-4 / (1.0 + (a + b) as f64)),
        }
    }

    #[test]
    fn derivatives_match_central_differences() {
        for full in [false, true] {
            let lp = two_mode(full);
            let (rows, cols) = ([0usize, 2], [1usize, 2]);
            let w = 31.0;
            let h = 1e-5;
            let fd = (lp.receptance(w + h, &rows, &cols) - lp.receptance(w - h, &rows, &cols))
                * faer::Scale(c64::new(1.0 / (2.0 * h), 0.0));
            let an = lp.receptance_domega(w, &rows, &cols);
            assert!((&fd - &an).norm_max() < 1e-7 * an.norm_max(), "full {full}");
            for p in [
                LinearParam::ModalFrequency(1),
                LinearParam::DampingRatio(0),
                LinearParam::StiffnessScale,
            ] {
                let eps = 1e-6;
                let perturbed = |sign: f64| {
                    let mut q = lp.clone();
                    match p {
                        LinearParam::ModalFrequency(r) => {
                            let zeta = q.zeta(r);
                            let f = q.w2[r].sqrt() / (2.0 * PI) + sign * eps;
                            q.w2[r] = (2.0 * PI * f).powi(2);
                            q.damping[(r, r)] = 2.0 * zeta * 2.0 * PI * f;
                        }
                        LinearParam::DampingRatio(r) => {
                            q.damping[(r, r)] += sign * eps * 2.0 * q.w2[r].sqrt();
                        }
                        LinearParam::StiffnessScale => {
                            let k = 1.0 + sign * eps;
                            q.w2.iter_mut().for_each(|x| *x *= k);
                            q.residual = &q.residual * faer::Scale(1.0 / k);
                        }
                    }
                    q.receptance(w, &rows, &cols)
                };
                let fd = (perturbed(1.0) - perturbed(-1.0))
                    * faer::Scale(c64::new(1.0 / (2.0 * eps), 0.0));
                let an = lp.receptance_dparam(p, w, &rows, &cols).unwrap();
                assert!(
                    (&fd - &an).norm_max() < 1e-6 * an.norm_max(),
                    "{} full {full}: {:?} vs {:?}",
                    p.name(),
                    fd,
                    an
                );
            }
        }
    }

    #[test]
    fn full_and_diagonal_paths_agree_without_coupling() {
        let a = two_mode(false);
        let mut b = a.clone();
        b.diagonal = false;
        let (r, c) = ([0usize, 1, 2], [0usize, 1, 2]);
        let d = a.receptance(17.0, &r, &c) - b.receptance(17.0, &r, &c);
        assert!(d.norm_max() < 1e-15);
    }
}
