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

use crate::eigen::{EigenSolver, Modes, factor_below_spectrum};
use crate::factor::{ShiftFactor, ShiftedPencil};
use faer::sparse::linalg::matmul::sparse_dense_matmul;
use faer::{Accum, Mat, MatRef, Par};
use nlsim_kernel::{Error, Model, Param, Result, SparseSym, Status};
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

    // The factor of the eigen solve, or one made here.
    let own;
    let (pencil, factor): (&ShiftedPencil, &ShiftFactor) = match solver.pencil_and_factor() {
        Some(pf) if pf.0.n() == n => pf,
        _ => {
            let mut p = ShiftedPencil::new(model.stiffness(), model.mass())?;
            p.set_par(cfg.par);
            let f = factor_below_spectrum(&p, model.stiffness(), model.mass(), None)?;
            own = (p, f);
            (&own.0, &own.1)
        }
    };
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
