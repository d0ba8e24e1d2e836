//! Analytic eigen-sensitivities with respect to FE-level parameters (group stiffness and mass
//! scales, boundary springs), for the linear stage of calibration (thesis §4.5) on models too
//! large to refactorise for every Jacobian column.
//!
//! For a mass-normalised mode `(λ_r, φ_r)` of `K φ = λ M φ` and a parameter `p`:
//!
//! - eigenvalue: `∂λ_r/∂p = φ_rᵀ (∂K/∂p − λ_r ∂M/∂p) φ_r` (exact);
//! - mode shape: with `g_r = −(∂K/∂p − λ_r ∂M/∂p) φ_r`,
//!   `∂φ_r/∂p = Σ_{s≠r} φ_s (φ_sᵀ g_r) / (λ_s − λ_r) − ½ (φ_rᵀ ∂M/∂p φ_r) φ_r`.
//!   The sum over the retained modes is taken term by term. The sum over the truncated
//!   modes, which are not known, is evaluated with the Cholesky factor of `K − σM` that the
//!   eigen solve already holds, as the series
//!   `Σ_k (λ_r − σ)^k (P (K − σM)⁻¹ M)^k P (K − σM)⁻¹ g_r`, where `P = I − Φ Φᵀ M` removes
//!   the retained modes. On the truncated subspace `(K − σM)⁻¹ M` has eigenvalues
//!   `1/(λ_s − σ)`, so the series is the expansion of `1/(λ_s − λ_r)` and converges at the
//!   rate `(λ_r − σ)/(λ_{m+1} − σ)`: a few solves for the low modes, more for a retained mode
//!   close to the first truncated one. Its first term alone is the static (modified modal)
//!   correction of Wang (1991).
//!
//! No new factorisation is made: one eigen solve serves every parameter. A cluster of
//! (nearly) repeated eigenvalues has no unique shape derivative within the cluster; such
//! pairs are listed and their mutual term is left out.

use crate::eigen::{EigenSolver, Modes};
use crate::factor::{ShiftFactor, ShiftedPencil};
use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::{Accum, Mat, MatRef, Par};
use nlsim_kernel::{Damping, Error, Model, Param, Result, SparseSym, Status};
use std::f64::consts::PI;

/// Settings of [`eigen_sensitivities`].
#[derive(Debug, Clone, PartialEq)]
pub struct SensitivityConfig {
    /// DOF indices at which the mode-shape derivatives are kept (sensor DOFs); empty: none
    /// are computed (eigenvalue derivatives only, no solves).
    pub shape_dofs: Vec<usize>,
    /// Stop the truncated-mode series when its last term is below `tolerance` times the sum
    /// (relative, 2-norm over all DOFs).
    pub tolerance: f64,
    /// Most terms of the truncated-mode series (each one block solve).
    pub max_terms: usize,
    /// Relative gap `|λ_s − λ_r| / max(λ_r, λ_s)` below which two modes count as repeated.
    pub repeated_gap: f64,
    /// Parallelism of the block solves and sparse products.
    pub par: Par,
}

impl Default for SensitivityConfig {
    fn default() -> Self {
        SensitivityConfig {
            shape_dofs: Vec::new(),
            tolerance: 1e-12,
            max_terms: 200,
            repeated_gap: 1e-8,
            par: Par::Seq,
        }
    }
}

/// Eigenvalue, frequency and mode-shape derivatives of the retained modes.
#[derive(Debug, Clone)]
pub struct EigenSensitivities {
    /// The parameters, in column order.
    pub params: Vec<Param>,
    /// `∂λ_r/∂p_j` (modes × parameters; rad²/s² per unit of the parameter).
    pub eigenvalue: Mat<f64>,
    /// `∂f_r/∂p_j = ∂λ_r/∂p_j / (8π² f_r)` (modes × parameters; Hz per unit; 0 for a mode
    /// at zero frequency).
    pub frequency_hz: Mat<f64>,
    /// The DOFs at which shape derivatives are kept (rows of [`EigenSensitivities::shapes`]).
    pub shape_dofs: Vec<usize>,
    /// `∂φ_r/∂p_j` at [`EigenSensitivities::shape_dofs`]: one matrix per parameter (DOFs ×
    /// modes; m/√kg per unit of the parameter).
    pub shapes: Vec<Mat<f64>>,
    /// Pairs of retained modes `(r, s)`, `r < s`, treated as repeated.
    pub repeated: Vec<(usize, usize)>,
    /// Most series terms used for one parameter.
    pub terms: usize,
    /// Largest relative size of the last series term (the truncation estimate).
    pub truncation: f64,
    /// [`Status::Converged`], or [`Status::IterationLimit`] when a series stopped at
    /// `max_terms` before `tolerance`; the derivatives are then the partial sums.
    pub status: Status,
}

/// Derivatives of the retained `modes` of `model` with respect to FE-level `params`.
///
/// `solver` is the solver that computed `modes` from this model's current matrices: its
/// Cholesky factor of `K − σM` is reused (a cheap check refuses a factor of other
/// matrices). When it holds none (the dense path of small models), a factor is made here.
pub fn eigen_sensitivities(
    model: &Model,
    modes: &Modes,
    solver: &EigenSolver,
    params: &[Param],
    cfg: &SensitivityConfig,
) -> Result<EigenSensitivities> {
    let n = model.n_dofs();
    let m = modes.len();
    if modes.vectors.nrows() != n {
        return Err(Error::DimensionMismatch {
            what: "mode shapes for the eigen-sensitivities (rows = model DOFs)".into(),
            expected: n,
            found: modes.vectors.nrows(),
        });
    }
    if !modes.is_converged() {
        return Err(Error::invalid(
            "eigen-sensitivities",
            format!(
                "the modes did not converge ({}): derivatives of unconverged modes are \
                 meaningless",
                modes.stats.detail
            ),
        ));
    }
    if let Some(&d) = cfg.shape_dofs.iter().find(|&&d| d >= n) {
        return Err(Error::invalid(
            "eigen-sensitivity settings",
            format!("shape DOF index {d} is beyond the model's {n} DOFs"),
        ));
    }
    if !(cfg.tolerance > 0.0 && cfg.tolerance < 1.0) || cfg.max_terms == 0 {
        return Err(Error::invalid(
            "eigen-sensitivity settings",
            "tolerance must lie in (0, 1) and max_terms be at least 1",
        ));
    }
    let derivs = params
        .iter()
        .map(|p| model.matrix_derivative(p))
        .collect::<Result<Vec<_>>>()?;
    let lambda = &modes.eigenvalues;
    let phi = &modes.vectors;
    let col = |r: usize| -> Vec<f64> { phi.col(r).iter().copied().collect() };

    let mut eigenvalue = Mat::zeros(m, params.len());
    for (j, d) in derivs.iter().enumerate() {
        for r in 0..m {
            eigenvalue[(r, j)] = d.quadratic(lambda[r], &col(r));
        }
    }
    let frequency_hz = Mat::from_fn(m, params.len(), |r, j| {
        let f = lambda[r].max(0.0).sqrt() / (2.0 * PI);
        if f > 0.0 {
            eigenvalue[(r, j)] / (8.0 * PI * PI * f)
        } else {
            0.0
        }
    });
    let mut repeated = Vec::new();
    for r in 0..m {
        for s in r + 1..m {
            let scale = lambda[r].abs().max(lambda[s].abs()).max(f64::MIN_POSITIVE);
            if (lambda[s] - lambda[r]).abs() <= cfg.repeated_gap * scale {
                repeated.push((r, s));
            }
        }
    }
    let mut out = EigenSensitivities {
        params: params.to_vec(),
        eigenvalue,
        frequency_hz,
        shape_dofs: cfg.shape_dofs.clone(),
        shapes: Vec::new(),
        repeated,
        terms: 0,
        truncation: 0.0,
        status: Status::Converged,
    };
    if cfg.shape_dofs.is_empty() || m == 0 {
        out.shapes = vec![Mat::zeros(cfg.shape_dofs.len(), m); params.len()];
        return Ok(out);
    }

    let (mut own, mut own_factor) = (None, None);
    let (pencil, factor) = solver.operator(
        model.stiffness(),
        model.mass(),
        cfg.par,
        &mut own,
        &mut own_factor,
    )?;
    let sigma = factor.shift();
    let mass = model.mass();
    check_factor(pencil, factor, mass, modes, cfg.par)?;

    let mut shapes = Vec::with_capacity(params.len());
    for d in &derivs {
        // g_r = −(∂K − λ_r ∂M) φ_r, one column per mode.
        let mut g = Mat::<f64>::zeros(n, m);
        let mut y = vec![0.0; n];
        for r in 0..m {
            d.apply(lambda[r], &col(r), &mut y);
            for i in 0..n {
                g[(i, r)] = -y[i];
            }
        }
        // Retained part and the normalisation term.
        let proj = phi.transpose() * &g; // φ_sᵀ g_r (modes × modes)
        let mut dphi = Mat::<f64>::zeros(n, m);
        for r in 0..m {
            let half_mass = 0.5 * d.mass_quadratic(&col(r));
            for s in 0..m {
                let coef = if s == r {
                    -half_mass
                } else if out.repeated.contains(&(r.min(s), r.max(s))) {
                    0.0
                } else {
                    proj[(s, r)] / (lambda[s] - lambda[r])
                };
                if coef != 0.0 {
                    for i in 0..n {
                        dphi[(i, r)] += coef * phi[(i, s)];
                    }
                }
            }
        }
        // Truncated part: the projected series on the shift factor.
        let mut term = g;
        pencil.solve_in_place(factor, term.as_mut());
        project_out(&mut term, phi.as_ref(), mass, cfg.par);
        let mut sum = term.clone();
        let mut k = 1;
        let mut rel = vec![f64::INFINITY; m];
        loop {
            for r in 0..m {
                let tn = term.col(r).norm_l2();
                let sn = sum.col(r).norm_l2();
                rel[r] = if sn > 0.0 { tn / sn } else { 0.0 };
            }
            let worst = rel.iter().copied().fold(0.0, f64::max);
            if worst <= cfg.tolerance || k >= cfg.max_terms {
                out.terms = out.terms.max(k);
                out.truncation = out.truncation.max(worst);
                if worst > cfg.tolerance {
                    out.status = Status::IterationLimit;
                }
                break;
            }
            let mut next = sparse_times(mass, term.as_ref(), cfg.par);
            for r in 0..m {
                let a = lambda[r] - sigma;
                for i in 0..n {
                    next[(i, r)] *= a;
                }
            }
            pencil.solve_in_place(factor, next.as_mut());
            project_out(&mut next, phi.as_ref(), mass, cfg.par);
            sum += &next;
            term = next;
            k += 1;
        }
        dphi += &sum;
        shapes.push(Mat::from_fn(cfg.shape_dofs.len(), m, |a, r| {
            dphi[(cfg.shape_dofs[a], r)]
        }));
    }
    out.shapes = shapes;
    Ok(out)
}

/// Derivatives of a reduced model's port data (thesis eq. 10 in the frequency domain,
/// `H(ω) = Φ_P Z(ω)⁻¹ Φ_Pᵀ + D`) with respect to FE-level parameters: what harmonic balance
/// needs to differentiate its receptances without reducing the model again.
#[derive(Debug, Clone)]
pub struct ReducedSensitivities {
    /// The eigen-sensitivities, with the shape derivatives at every port DOF.
    pub eigen: EigenSensitivities,
    /// `∂Φ_P/∂p_j` (ports × modes; m/√kg per unit of the parameter), one per parameter.
    pub participation: Vec<Mat<f64>>,
    /// `∂D/∂p_j` (ports × ports, symmetric; m/N per unit), one per parameter.
    pub residual: Vec<Mat<f64>>,
    /// `∂C̃/∂p_j` (modes × modes; 1/s per unit), one per parameter.
    pub damping: Vec<Mat<f64>>,
}

/// Derivatives of `reduced` (made from `model` by `solver`) with respect to FE-level
/// `params`:
///
/// - `∂Φ_P` from the mode-shape derivatives at the port DOFs ([`eigen_sensitivities`];
///   `cfg.shape_dofs` is replaced by those DOFs);
/// - `∂D` of the residual flexibility `D = Wᵀ (K − σM)⁻¹ W − Σ_r Φ_P,r Φ_P,rᵀ / (λ_r − σ)`
///   at its shift `σ` held,
///   `−Xᵀ (∂K − σ ∂M) X − Σ_r (∂Φ_P,r Φ_P,rᵀ + Φ_P,r ∂Φ_P,rᵀ)/(λ_r − σ) +
///   Σ_r Φ_P,r Φ_P,rᵀ ∂λ_r / (λ_r − σ)²` with `X = (K − σM)⁻¹ W` (one block solve on the
///   eigen solve's factor);
/// - `∂C̃` of the damping law: Rayleigh `β ∂λ_r`, modal ratios held `ζ_r ∂λ_r / ω_r`, none 0.
///   A damping matrix `V` would need `∂Φ` at every DOF (`∂Φᵀ V Φ + Φᵀ V ∂Φ`) and is refused.
pub fn reduced_sensitivities(
    model: &Model,
    reduced: &crate::ReducedModel,
    solver: &EigenSolver,
    params: &[Param],
    cfg: &SensitivityConfig,
) -> Result<ReducedSensitivities> {
    let n = model.n_dofs();
    let ports = &reduced.ports;
    let np = ports.len();
    let m = reduced.n_modes();
    if matches!(model.damping(), Damping::Matrix(_)) && m > 0 {
        return Err(Error::invalid(
            "sensitivities of the reduced model",
            "FE-level parameters with a damping matrix are not supported (the modal damping \
             would need the mode-shape derivatives at every DOF); use modal or Rayleigh damping",
        ));
    }
    let mut dofs: Vec<usize> = ports.iter().flat_map(|p| p.dofs.iter().copied()).collect();
    dofs.sort_unstable();
    dofs.dedup();
    let eigen = eigen_sensitivities(
        model,
        &reduced.modes,
        solver,
        params,
        &SensitivityConfig {
            shape_dofs: dofs.clone(),
            ..cfg.clone()
        },
    )?;
    let row = |d: usize| dofs.binary_search(&d).expect("a port DOF");
    let participation: Vec<Mat<f64>> = eigen
        .shapes
        .iter()
        .map(|sh| {
            Mat::from_fn(np, m, |p, r| {
                ports[p]
                    .dofs
                    .iter()
                    .zip(&ports[p].weights)
                    .map(|(&d, &w)| w * sh[(row(d), r)])
                    .sum()
            })
        })
        .collect();
    let lambda = &reduced.modes.eigenvalues;
    let damping = (0..params.len())
        .map(|j| {
            Mat::from_fn(m, m, |r, s| {
                if r != s {
                    return 0.0;
                }
                proportional_damping_derivative(
                    model.damping(),
                    r,
                    lambda[r],
                    eigen.eigenvalue[(r, j)],
                )
            })
        })
        .collect();
    let phi = &reduced.participation;
    let residual = if reduced.residual.norm_max() == 0.0 || np == 0 {
        vec![Mat::zeros(np, np); params.len()]
    } else {
        let (mut own, mut own_factor) = (None, None);
        let (pencil, factor) = solver.operator(
            model.stiffness(),
            model.mass(),
            cfg.par,
            &mut own,
            &mut own_factor,
        )?;
        let sigma = reduced.residual_shift;
        if factor.shift() != sigma {
            return Err(Error::invalid(
                "sensitivities of the reduced model",
                format!(
                    "the solver's shift {:.6e} is not the residual flexibility's {sigma:.6e}: \
                     pass the solver that reduced this model",
                    factor.shift()
                ),
            ));
        }
        let mut x = crate::modal::port_loads(n, ports);
        pencil.solve_in_place(factor, x.as_mut());
        let mut y = vec![0.0; n];
        let mut out = Vec::with_capacity(params.len());
        for (j, p) in params.iter().enumerate() {
            let d = model.matrix_derivative(p)?;
            let mut dx = Mat::<f64>::zeros(n, np);
            for b in 0..np {
                let xb: Vec<f64> = x.col(b).iter().copied().collect();
                d.apply(sigma, &xb, &mut y);
                for i in 0..n {
                    dx[(i, b)] = y[i];
                }
            }
            let mut dd = -(x.transpose() * &dx);
            let dphi = &participation[j];
            for r in 0..m {
                let s = 1.0 / (lambda[r] - sigma);
                let dl = eigen.eigenvalue[(r, j)] * s * s;
                for a in 0..np {
                    for b in 0..np {
                        dd[(a, b)] += phi[(a, r)] * phi[(b, r)] * dl
                            - (dphi[(a, r)] * phi[(b, r)] + phi[(a, r)] * dphi[(b, r)]) * s;
                    }
                }
            }
            out.push(Mat::from_fn(np, np, |a, b| 0.5 * (dd[(a, b)] + dd[(b, a)])));
        }
        out
    };
    Ok(ReducedSensitivities {
        eigen,
        participation,
        residual,
        damping,
    })
}

/// `∂c̃_rr/∂p` of a proportional damping law for mode `r` of eigenvalue `lambda`
/// (rad²/s²) whose eigenvalue moves by `dl` per unit of `p`: Rayleigh `β ∂λ_r`, modal ratios
/// held `ζ_r ∂λ_r / ω_r`; 0 without damping or for a damping matrix (which is not diagonal
/// and needs the mode-shape derivatives).
pub(crate) fn proportional_damping_derivative(
    damping: &Damping,
    r: usize,
    lambda: f64,
    dl: f64,
) -> f64 {
    match damping {
        Damping::None | Damping::Matrix(_) => 0.0,
        Damping::Rayleigh { beta, .. } => beta * dl,
        Damping::Modal(md) => {
            let w = lambda.max(0.0).sqrt();
            if w > 0.0 {
                md.zeta(r, w / (2.0 * PI)) * dl / w
            } else {
                0.0
            }
        }
    }
}

fn sparse_times(a: &SparseSym, x: MatRef<'_, f64>, par: Par) -> Mat<f64> {
    let mut y = Mat::zeros(x.nrows(), x.ncols());
    sparse_dense_matmul(y.as_mut(), Accum::Replace, a.as_faer(), x, 1.0, par);
    y
}

/// `X ← (I − Φ Φᵀ M) X`.
fn project_out(x: &mut Mat<f64>, phi: MatRef<'_, f64>, mass: &SparseSym, par: Par) {
    let mx = sparse_times(mass, x.as_ref(), par);
    let c = phi.transpose() * &mx;
    *x -= phi * &c;
}

/// Refuses a factor that does not belong to the modes' matrices: for the lowest mode,
/// `(K − σM)⁻¹ M φ₀` must equal `φ₀ / (λ₀ − σ)`.
fn check_factor(
    pencil: &ShiftedPencil,
    factor: &ShiftFactor,
    mass: &SparseSym,
    modes: &Modes,
    par: Par,
) -> Result<()> {
    let phi0 = modes.vectors.subcols(0, 1);
    let mut x = sparse_times(mass, phi0, par);
    pencil.solve_in_place(factor, x.as_mut());
    let s = modes.eigenvalues[0] - factor.shift();
    let err = (&x * faer::Scale(s) - phi0).norm_l2() / phi0.norm_l2();
    if err.is_nan() || err > 1e-6 {
        return Err(Error::invalid(
            "eigen-sensitivities",
            format!(
                "the solver's factor does not belong to these modes (relative defect {err:.1e}): \
                 pass the solver that computed them from the model's current matrices"
            ),
        ));
    }
    Ok(())
}
