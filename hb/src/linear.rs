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
use nlsim_kernel::param::{check_finite, unknown_param};
use nlsim_kernel::{Error, Param, Parameterized, Result};
use nlsim_reduction::ReducedModel;
use std::f64::consts::PI;

/// The linear part of the reduced model as seen from its ports.
#[derive(Debug, Clone)]
///
/// Its linear parameters ([`Param::ModalFrequency`], [`Param::ModalDamping`],
/// [`Param::ModalMass`], [`Param::StiffnessScale`], and a test-based modal model's measured
/// residual flexibilities [`Param::Residual`]) are read and set through [`Parameterized`]; the
/// fields stay consistent with them.
pub struct LinearPart {
    /// Retained eigenvalues `ω_r²` (rad²/s²), the stiffness scale included.
    pub(crate) w2: Vec<f64>,
    /// Modal damping matrix `C̃` (modes × modes; 1/s).
    pub(crate) damping: Mat<f64>,
    /// True when `C̃` is diagonal (proportional damping): receptances are then a plain sum.
    pub(crate) diagonal: bool,
    /// Modal participation `Φ_P` (ports × modes; m/√kg).
    pub(crate) phi: Mat<f64>,
    /// Residual flexibility `D` (ports × ports; m/N), the stiffness scale included.
    pub(crate) residual: Mat<f64>,
    /// The stiffness scale `κ` (nominal 1): `Ω² = κ Ω₀²`, `D = D₀/κ`.
    pub(crate) kappa: f64,
    /// Modal masses `m_r` (kg, nominal 1): column `r` of `Φ_P` is `Φ_P0,r / √m_r`.
    pub(crate) modal_mass: Vec<f64>,
    /// The measured residual flexibilities (a test-based modal model's), each with its
    /// parameter: a share of `D` (`D_ab = D_ba`) that is set as a whole.
    pub(crate) measured: Vec<MeasuredTerm>,
    /// The mode-shape entries of a test-based modal model's points, each with its
    /// parameter (`modeN.shape:POINT`).
    pub(crate) shapes: Vec<ShapeTerm>,
}

/// One mode-shape entry `φ_pd` of a [`LinearPart`]: the point's weight on modal coordinate
/// `d`. Port `i` on the point with weight `w` has `Φ_P(i, r) = … + w V_dr φ_pd / √m_r`, with
/// `V` the reduction's eigenvectors (unit vectors up to sign and order for a modal model).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ShapeTerm {
    /// `modeN.shape:POINT`.
    param: Param,
    /// `(port, weight)` of the ports on the point.
    ports: Vec<(usize, f64)>,
    /// `V_dr`, one per retained mode.
    dir: Vec<f64>,
    /// Its current value (m/√kg).
    value: f64,
}

/// One measured residual flexibility of a [`LinearPart`].
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct MeasuredTerm {
    /// `residual:A:B`.
    param: Param,
    /// Port indices (`a == b` on a driving point).
    a: usize,
    b: usize,
    /// Its current flexibility (m/N), included in `D` (divided by the stiffness scale there).
    flexibility: f64,
}

/// A first-order change of the linear part's data with respect to one parameter that acts
/// on the FE model (a group scale, a boundary spring): the derivatives of the eigenvalues,
/// the modal damping, the participation and the residual flexibility, e.g. from
/// `nlsim_reduction::reduced_sensitivities`. Harmonic balance differentiates its receptances
/// along it without reducing the model again.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearVariation {
    /// The parameter this is the derivative with respect to.
    pub param: Param,
    /// `∂ω_r²/∂p` (rad²/s² per unit of the parameter), one per retained mode.
    pub eigenvalues: Vec<f64>,
    /// `∂C̃/∂p` (modes × modes; 1/s per unit).
    pub damping: Mat<f64>,
    /// `∂Φ_P/∂p` (ports × modes; m/√kg per unit).
    pub participation: Mat<f64>,
    /// `∂D/∂p` (ports × ports; m/N per unit).
    pub residual: Mat<f64>,
}

impl LinearVariation {
    /// Checks the shapes against a linear part of `modes` modes and `ports` ports, and that
    /// every entry is finite.
    pub fn check(&self, modes: usize, ports: usize) -> Result<()> {
        let what = |part: &str| format!("variation along {}: {part}", self.param);
        for (part, (r, c), (er, ec)) in [
            ("eigenvalues", (self.eigenvalues.len(), 1), (modes, 1)),
            (
                "damping",
                (self.damping.nrows(), self.damping.ncols()),
                (modes, modes),
            ),
            (
                "participation",
                (self.participation.nrows(), self.participation.ncols()),
                (ports, modes),
            ),
            (
                "residual",
                (self.residual.nrows(), self.residual.ncols()),
                (ports, ports),
            ),
        ] {
            if (r, c) != (er, ec) {
                return Err(Error::DimensionMismatch {
                    what: format!("{} (rows × columns = {r} × {c})", what(part)),
                    expected: er * ec,
                    found: r * c,
                });
            }
        }
        let finite = self.eigenvalues.iter().all(|v| v.is_finite())
            && [&self.damping, &self.participation, &self.residual]
                .iter()
                .all(|m| m.col_iter().all(|c| c.iter().all(|v| v.is_finite())));
        if !finite {
            return Err(Error::invalid(what("entries"), "must be finite"));
        }
        Ok(())
    }
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
            kappa: 1.0,
            modal_mass: vec![1.0; m],
            measured: reduced
                .measured
                .iter()
                .map(|t| MeasuredTerm {
                    param: Param::residual(&reduced.ports[t.a].name, &reduced.ports[t.b].name),
                    a: t.a,
                    b: t.b,
                    flexibility: t.flexibility,
                })
                .collect(),
            shapes: shape_terms(reduced),
        })
    }

    /// Retained eigenvalues `ω_r²` (rad²/s²).
    pub fn eigenvalues(&self) -> &[f64] {
        &self.w2
    }

    /// Modal damping matrix `C̃` (modes × modes; 1/s).
    pub fn damping(&self) -> &Mat<f64> {
        &self.damping
    }

    /// Modal participation `Φ_P` (ports × modes; m/√kg).
    pub fn participation(&self) -> &Mat<f64> {
        &self.phi
    }

    /// The mode among `modes` with the largest participation `|Φ_P(port, r)|` at `port`
    /// (ties to the lower mode): the one a drive or sensor at that port sees most, e.g. the
    /// bending mode a tip force drives when two bending planes share one frequency. `None`
    /// when the range holds no retained mode or the port does not exist.
    pub fn dominant_mode(&self, port: usize, modes: std::ops::Range<usize>) -> Option<usize> {
        if port >= self.phi.nrows() {
            return None;
        }
        (modes.start..modes.end.min(self.phi.ncols())).fold(None, |best, r| match best {
            Some(b) if self.phi[(port, b)].abs() >= self.phi[(port, r)].abs() => Some(b),
            _ => Some(r),
        })
    }

    /// Residual flexibility `D` (ports × ports; m/N).
    pub fn residual(&self) -> &Mat<f64> {
        &self.residual
    }

    /// Natural frequency of mode `r` (Hz).
    pub fn frequency_hz(&self, r: usize) -> f64 {
        self.w2[r].sqrt() / (2.0 * PI)
    }

    fn mode_of(&self, p: &Param) -> Result<usize> {
        match p {
            Param::ModalFrequency(r) | Param::ModalDamping(r) | Param::ModalMass(r)
                if *r < self.n_modes() =>
            {
                Ok(*r)
            }
            Param::ModalFrequency(_) | Param::ModalDamping(_) | Param::ModalMass(_) => {
                Err(Error::invalid(
                    format!("parameter {p}"),
                    format!("the model keeps {} modes", self.n_modes()),
                ))
            }
            _ => Err(unknown_param(p, &self.parameters())),
        }
    }

    /// The measured residual term of parameter `p` (either spelling of the pair).
    fn term_of(&self, p: &Param) -> Result<usize> {
        let Param::Residual(a, b) = p else {
            return Err(unknown_param(p, &self.parameters()));
        };
        let want = Param::residual(a, b);
        self.measured
            .iter()
            .position(|t| t.param == want)
            .ok_or_else(|| unknown_param(p, &self.parameters()))
    }

    /// The shape entry of parameter `p`.
    fn shape_of(&self, p: &Param) -> Result<usize> {
        self.shapes
            .iter()
            .position(|t| t.param == *p)
            .ok_or_else(|| unknown_param(p, &self.parameters()))
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

    /// `∂H/∂θ` (m/N per unit of θ) for linear parameter `p` ([`Param::ModalFrequency`],
    /// [`Param::ModalDamping`], [`Param::ModalMass`], [`Param::StiffnessScale`],
    /// [`Param::Residual`]) at `omega` (rad/s). A measured residual flexibility enters `H`
    /// as `D/κ`, so its derivative is `(E_ab + E_ba)/κ` (one `E_aa/κ` on a driving point),
    /// independent of `ω`.
    pub fn receptance_dparam(
        &self,
        p: &Param,
        omega: f64,
        rows: &[usize],
        cols: &[usize],
    ) -> Result<Mat<c64>> {
        let m = self.n_modes();
        let mut dz = Mat::<c64>::zeros(m, m);
        let mut dd = 0.0;
        match p {
            Param::ModalFrequency(_) => {
                let r = self.mode_of(p)?;
                // Z_rr = ω_r² − ω² + 2iζ_r ω_r ω with ζ_r held; ∂/∂f_r = 2π ∂/∂ω_r.
                let wr = self.w2[r].sqrt();
                dz[(r, r)] = c64::new(2.0 * wr, 2.0 * self.zeta(r) * omega) * (2.0 * PI);
            }
            Param::ModalDamping(_) => {
                let r = self.mode_of(p)?;
                dz[(r, r)] = c64::new(0.0, 2.0 * self.w2[r].sqrt() * omega);
            }
            Param::ModalMass(_) => {
                // Φ_r = Φ_r0/√m_r: ∂H/∂m_r = −(Φ_rows E_r Z⁻¹ Φ_colsᵀ + Φ_rows Z⁻¹ E_r Φ_colsᵀ)/(2 m_r).
                let r = self.mode_of(p)?;
                let z = self.solve(omega);
                let x = self.zinv_phi(&z, cols);
                let y = self.zinv_phi(&z, rows);
                let c = -0.5 / self.modal_mass[r];
                return Ok(Mat::from_fn(rows.len(), cols.len(), |i, j| {
                    (x[(r, j)] * self.phi[(rows[i], r)] + y[(r, i)] * self.phi[(cols[j], r)]) * c
                }));
            }
            Param::StiffnessScale => {
                // Ω² = κ Ω₀², D = D₀/κ: ∂Z/∂κ = Ω²/κ, ∂D/∂κ = −D/κ.
                for r in 0..m {
                    dz[(r, r)] = c64::new(self.w2[r] / self.kappa, 0.0);
                }
                dd = -1.0 / self.kappa;
            }
            Param::ModeShape { .. } => {
                // ∂Φ_P = v uᵀ (v: the point's port weights, u_r = V_dr/√m_r):
                // ∂H = v_rows uᵀ Z⁻¹ Φ_colsᵀ + Φ_rows Z⁻¹ u v_colsᵀ.
                let t = &self.shapes[self.shape_of(p)?];
                let weight = |port: usize| -> f64 {
                    t.ports.iter().filter(|x| x.0 == port).map(|x| x.1).sum()
                };
                let u: Vec<f64> = (0..m)
                    .map(|r| t.dir[r] / self.modal_mass[r].sqrt())
                    .collect();
                let z = self.solve(omega);
                let x = self.zinv_phi(&z, cols);
                let y = self.zinv_phi(&z, rows);
                let ux =
                    |mat: &Mat<c64>, j: usize| -> c64 { (0..m).map(|r| mat[(r, j)] * u[r]).sum() };
                return Ok(Mat::from_fn(rows.len(), cols.len(), |i, j| {
                    ux(&x, j) * weight(rows[i]) + ux(&y, i) * weight(cols[j])
                }));
            }
            Param::Residual(..) => {
                let t = &self.measured[self.term_of(p)?];
                let (a, b, k) = (t.a, t.b, 1.0 / self.kappa);
                return Ok(Mat::from_fn(rows.len(), cols.len(), |i, j| {
                    let hit = (rows[i] == a && cols[j] == b) || (rows[i] == b && cols[j] == a);
                    c64::new(if hit { k } else { 0.0 }, 0.0)
                }));
            }
            _ => return Err(unknown_param(p, &self.parameters())),
        }
        Ok(self.sandwich(omega, rows, cols, &dz, dd))
    }

    /// `∂H/∂p` (m/N per unit of `p`) between `rows` and `cols` at `omega` (rad/s) along a
    /// variation of the data (checked with [`LinearVariation::check`] by the caller):
    /// `∂Φ_rows Z⁻¹ Φ_colsᵀ + Φ_rows Z⁻¹ ∂Φ_colsᵀ − Φ_rows Z⁻¹ ∂Z Z⁻¹ Φ_colsᵀ + ∂D`, with
    /// `∂Z = diag(∂ω_r²) + iω ∂C̃`.
    pub fn receptance_dvariation(
        &self,
        v: &LinearVariation,
        omega: f64,
        rows: &[usize],
        cols: &[usize],
    ) -> Mat<c64> {
        let m = self.n_modes();
        let dz = Mat::from_fn(m, m, |r, s| {
            let d = c64::new(0.0, omega * v.damping[(r, s)]);
            if r == s {
                d + c64::new(v.eigenvalues[r], 0.0)
            } else {
                d
            }
        });
        let z = self.solve(omega);
        let x = self.zinv_phi(&z, cols);
        let y = self.zinv_phi(&z, rows);
        let mut h = -(y.transpose() * (&dz * &x));
        let dphi = |ports: &[usize]| {
            Mat::from_fn(ports.len(), m, |i, r| {
                c64::new(v.participation[(ports[i], r)], 0.0)
            })
        };
        h += dphi(rows) * &x;
        h += y.transpose() * dphi(cols).transpose();
        for (i, &a) in rows.iter().enumerate() {
            for (j, &b) in cols.iter().enumerate() {
                h[(i, j)] += c64::new(v.residual[(a, b)], 0.0);
            }
        }
        h
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

    /// `Z(ω)⁻¹ f` of modal forces `f` (one per retained mode; N/√kg) at `omega` (rad/s).
    pub fn modal_solve(&self, omega: f64, f: &[c64]) -> Vec<c64> {
        match self.solve(omega) {
            ModalSolve::Diagonal(d) => d.iter().zip(f).map(|(a, b)| a * b).collect(),
            ModalSolve::Full(lu) => {
                let rhs = Mat::from_fn(f.len(), 1, |i, _| f[i]);
                let x = lu.solve(&rhs);
                (0..f.len()).map(|i| x[(i, 0)]).collect()
            }
        }
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

/// `modeN.f` (Hz), `modeN.zeta` and `modeN.m` (kg) of every retained mode, then
/// `stiffness_scale`, then a test-based modal model's measured residual flexibilities
/// `residual:A:B` (m/N, the model's order) and mode-shape entries `modeN.shape:POINT`
/// (m/√kg; mode by mode, points in the model's order).
impl Parameterized for LinearPart {
    fn parameters(&self) -> Vec<Param> {
        let mut p =
            Vec::with_capacity(3 * self.n_modes() + 1 + self.measured.len() + self.shapes.len());
        for r in 0..self.n_modes() {
            p.push(Param::ModalFrequency(r));
            p.push(Param::ModalDamping(r));
            p.push(Param::ModalMass(r));
        }
        p.push(Param::StiffnessScale);
        p.extend(self.measured.iter().map(|t| t.param.clone()));
        p.extend(self.shapes.iter().map(|t| t.param.clone()));
        p
    }

    fn param(&self, p: &Param) -> Result<f64> {
        match p {
            Param::ModalFrequency(_) => Ok(self.frequency_hz(self.mode_of(p)?)),
            Param::ModalDamping(_) => Ok(self.zeta(self.mode_of(p)?)),
            Param::ModalMass(_) => Ok(self.modal_mass[self.mode_of(p)?]),
            Param::StiffnessScale => Ok(self.kappa),
            Param::Residual(..) => Ok(self.measured[self.term_of(p)?].flexibility),
            Param::ModeShape { .. } => Ok(self.shapes[self.shape_of(p)?].value),
            _ => Err(unknown_param(p, &self.parameters())),
        }
    }

    fn set_param(&mut self, p: &Param, value: f64) -> Result<()> {
        check_finite(p, value)?;
        let positive = |what: &str| {
            Err(Error::InvalidParameter {
                name: p.to_string(),
                value,
                reason: format!("{what} must be positive"),
            })
        };
        match p {
            Param::ModalFrequency(_) => {
                let r = self.mode_of(p)?;
                if value <= 0.0 {
                    return positive("a natural frequency");
                }
                let zeta = self.zeta(r);
                let w = 2.0 * PI * value;
                self.w2[r] = w * w;
                self.damping[(r, r)] = 2.0 * zeta * w;
            }
            Param::ModalDamping(_) => {
                let r = self.mode_of(p)?;
                if value < 0.0 {
                    return Err(Error::InvalidParameter {
                        name: p.to_string(),
                        value,
                        reason: "a damping ratio must be non-negative".into(),
                    });
                }
                self.damping[(r, r)] = 2.0 * value * self.w2[r].sqrt();
            }
            Param::ModalMass(_) => {
                let r = self.mode_of(p)?;
                if value <= 0.0 {
                    return positive("a modal mass");
                }
                let f = (self.modal_mass[r] / value).sqrt();
                for i in 0..self.phi.nrows() {
                    self.phi[(i, r)] *= f;
                }
                self.modal_mass[r] = value;
            }
            Param::StiffnessScale => {
                if value <= 0.0 {
                    return positive("a stiffness scale");
                }
                let ratio = value / self.kappa;
                self.w2.iter_mut().for_each(|w| *w *= ratio);
                self.residual = &self.residual * faer::Scale(1.0 / ratio);
                self.kappa = value;
            }
            Param::Residual(..) => {
                let i = self.term_of(p)?;
                let t = &mut self.measured[i];
                if t.a == t.b && value < 0.0 {
                    return Err(Error::InvalidParameter {
                        name: p.to_string(),
                        value,
                        reason: "a driving-point residual flexibility is the static share of \
                                 the modes above the band, ≥ 0"
                            .into(),
                    });
                }
                let delta = (value - t.flexibility) / self.kappa;
                self.residual[(t.a, t.b)] += delta;
                if t.a != t.b {
                    self.residual[(t.b, t.a)] += delta;
                }
                t.flexibility = value;
            }
            Param::ModeShape { .. } => {
                let i = self.shape_of(p)?;
                let t = &mut self.shapes[i];
                let delta = value - t.value;
                for &(port, w) in &t.ports {
                    for r in 0..self.w2.len() {
                        self.phi[(port, r)] += w * t.dir[r] * delta / self.modal_mass[r].sqrt();
                    }
                }
                t.value = value;
            }
            _ => return Err(unknown_param(p, &self.parameters())),
        }
        Ok(())
    }
}

/// The shape-entry parameters of a reduced test-based modal model: one per point and modal
/// coordinate, mode by mode (none for an FE model).
fn shape_terms(reduced: &ReducedModel) -> Vec<ShapeTerm> {
    let v = &reduced.modes.vectors;
    let mut out = Vec::with_capacity(reduced.points.len() * v.nrows());
    for d in 0..v.nrows() {
        for pt in &reduced.points {
            out.push(ShapeTerm {
                param: Param::ModeShape {
                    mode: d,
                    point: pt.label,
                },
                ports: pt.ports.clone(),
                dir: (0..v.ncols()).map(|r| v[(d, r)]).collect(),
                value: pt.shape.iter().find(|s| s.0 == d).map_or(0.0, |s| s.1),
            });
        }
    }
    out
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
            kappa: 1.0,
            // A calibrated modal mass on mode 2 (`phi` holds its scaled column).
            modal_mass: vec![1.0, 1.7],
            measured: vec![
                MeasuredTerm {
                    param: Param::residual("p0", "p2"),
                    a: 0,
                    b: 2,
                    flexibility: 1e-4 / 3.0,
                },
                MeasuredTerm {
                    param: Param::residual("p2", "p2"),
                    a: 2,
                    b: 2,
                    flexibility: 1e-4 / 3.0,
                },
            ],
            shapes: vec![ShapeTerm {
                param: Param::ModeShape {
                    mode: 0,
                    point: "7:uz".parse().unwrap(),
                },
                // A drive-and-sensor point (ports 0, 2) and a relative element's second end.
                ports: vec![(0, 1.0), (2, 1.0), (1, -1.0)],
                dir: vec![0.6, -0.8],
                value: 0.3,
            }],
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
            for kappa in [1.0, 1.3] {
                let mut lp = lp.clone();
                lp.set_param(&Param::StiffnessScale, kappa).unwrap();
                for p in [
                    Param::ModalFrequency(1),
                    Param::ModalDamping(0),
                    Param::ModalMass(1),
                    Param::StiffnessScale,
                    Param::residual("p2", "p0"),
                    Param::residual("p2", "p2"),
                    Param::ModeShape {
                        mode: 0,
                        point: "7:uz".parse().unwrap(),
                    },
                ] {
                    // H is linear in a residual term, so its step needs no scaling.
                    let eps = 1e-6;
                    // By hand, independently of `set_param`.
                    let by_hand = |sign: f64| {
                        let mut q = lp.clone();
                        match p {
                            Param::ModalFrequency(r) => {
                                let zeta = q.zeta(r);
                                let f = q.w2[r].sqrt() / (2.0 * PI) + sign * eps;
                                q.w2[r] = (2.0 * PI * f).powi(2);
                                q.damping[(r, r)] = 2.0 * zeta * 2.0 * PI * f;
                            }
                            Param::ModalDamping(r) => {
                                q.damping[(r, r)] += sign * eps * 2.0 * q.w2[r].sqrt();
                            }
                            Param::ModalMass(r) => {
                                let m = q.modal_mass[r];
                                let f = (m / (m + sign * eps)).sqrt();
                                for i in 0..q.phi.nrows() {
                                    q.phi[(i, r)] *= f;
                                }
                                q.modal_mass[r] = m + sign * eps;
                            }
                            Param::ModeShape { .. } => {
                                // Φ_P(i, r) = Σ_ports w V_dr φ / √m_r, by hand.
                                let t = &mut q.shapes[0];
                                t.value += sign * eps;
                                for &(port, w) in &t.ports.clone() {
                                    for r in 0..2 {
                                        q.phi[(port, r)] +=
                                            w * t.dir[r] * sign * eps / q.modal_mass[r].sqrt();
                                    }
                                }
                            }
                            Param::Residual(..) => {
                                let i = q.term_of(&p).unwrap();
                                let t = &mut q.measured[i];
                                t.flexibility += sign * eps;
                                let (a, b) = (t.a, t.b);
                                q.residual[(a, b)] += sign * eps / kappa;
                                if a != b {
                                    q.residual[(b, a)] += sign * eps / kappa;
                                }
                            }
                            _ => {
                                let k = (kappa + sign * eps) / kappa;
                                q.w2.iter_mut().for_each(|x| *x *= k);
                                q.residual = &q.residual * faer::Scale(1.0 / k);
                            }
                        }
                        q
                    };
                    let through_trait = |sign: f64| {
                        let mut q = lp.clone();
                        let v = q.param(&p).unwrap();
                        q.set_param(&p, v + sign * eps).unwrap();
                        q
                    };
                    for sign in [-1.0, 1.0] {
                        let (a, b) = (by_hand(sign), through_trait(sign));
                        let d = a.receptance(w, &rows, &cols) - b.receptance(w, &rows, &cols);
                        assert!(d.norm_max() <= 1e-13 * a.receptance(w, &rows, &cols).norm_max());
                    }
                    let fd = (by_hand(1.0).receptance(w, &rows, &cols)
                        - by_hand(-1.0).receptance(w, &rows, &cols))
                        * faer::Scale(c64::new(1.0 / (2.0 * eps), 0.0));
                    let an = lp.receptance_dparam(&p, w, &rows, &cols).unwrap();
                    assert!(
                        (&fd - &an).norm_max() < 1e-6 * an.norm_max(),
                        "{p} full {full} kappa {kappa}: {fd:?} vs {an:?}"
                    );
                }
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
