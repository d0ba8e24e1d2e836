//! A parametric reduced model for FE-level parameters (group stiffness and mass scales,
//! boundary springs): the reduction of [`crate::reduce`] at any parameter values without a new
//! eigen solve of the full model, certified against the full sparse matrices.
//!
//! `K(p)` and `M(p)` are affine in these parameters (`K = K(p₀) + Σ_j (p_j − p₀,j) ∂K/∂p_j`,
//! likewise `M`), so a basis `B` (`n × b`, `Bᵀ M(p₀) B = I`) projects them once:
//! `K_B(p) = Bᵀ K(p₀) B + Σ_j Δp_j Bᵀ ∂K/∂p_j B`. The basis holds the nominal modes, the
//! static responses `X₀ = (K − σM)⁻¹ W` at the ports `W`, their first-order derivative
//! directions `(K − σM)⁻¹ (∂K/∂p_j − λ_r ∂M/∂p_j) φ_r` and `(K − σM)⁻¹ (∂K/∂p_j − σ ∂M/∂p_j) X₀`
//! (one block solve per parameter on the eigen solve's factor), and the modes and static
//! responses of full reductions at the points where it was enriched.
//!
//! An evaluation at `p` is a Rayleigh–Ritz solve `K_B ψ = λ M_B ψ` of size `b` (thesis eq. 9
//! projected): the lowest Ritz pairs are the retained modes `φ_r = B ψ_r`, the participation
//! `Φ_P = Wᵀ B Ψ`, and the residual flexibility of the truncated modes at the shift `σ` of the
//! nominal reduction (thesis eq. 10, `D = Wᵀ (K − σM)⁻¹ W − Σ_r Φ_P,r Φ_P,rᵀ / (λ_r − σ)`) is its
//! Galerkin form `W_Bᵀ (K_B − σ M_B)⁻¹ W_B − Σ_r …`, exact while `(K(p) − σM(p))⁻¹ W` lies in the
//! basis.
//!
//! **Certificate.** Each evaluation checks the lifted pairs against the full sparse matrices
//! (sparse products, no factorisation): for mode `r`, `ρ_r = ‖K(p)φ_r − λ_r M(p)φ_r‖ /
//! ‖λ_r M(p)φ_r‖`, and the indicator `e_r = ρ_r λ_r / g_r` with `g_r` the distance of `λ_r` to
//! the nearest other Ritz value (the first-order size of the mode-shape error, hence of the
//! participation's); for the static responses `e_X = ‖W − (K − σM) X‖_F / ‖W‖_F`. When
//! `max(e_r, e_X)` passes [`ParametricConfig::tolerance`] the model is reduced in full at `p`
//! (the eigen solver keeps its symbolic analysis), its modes and static responses join the
//! basis, and the Ritz solve is repeated: the result then equals the full reduction to the
//! eigen solver's accuracy.
//!
//! **Sensitivities** come from the same projected matrices, exactly for the Ritz model:
//! `∂λ_r = ψ_rᵀ (∂K_B − λ_r ∂M_B) ψ_r`, `∂ψ_r = Σ_{s≠r} ψ_s ψ_sᵀ(∂K_B − λ_r ∂M_B)ψ_r /
//! (λ_r − λ_s) − ½ (ψ_rᵀ ∂M_B ψ_r) ψ_r` over all `b` Ritz pairs (no truncated-mode series), and
//! `∂(W_Bᵀ A⁻¹ W_B) = −Yᵀ ∂A Y` with `A = K_B − σ M_B`, `Y = A⁻¹ W_B`.

use crate::eigen::{EigenMethod, EigenSolver, EigenStats, ModeSelection, Modes};
use crate::modal::{Port, ReducedModel, ReductionConfig, port_loads, reduce_with};
use crate::products::symmetric_times;
use faer::linalg::solvers::Solve;
use faer::{Mat, MatRef, Par, Side};
use nlsim_kernel::linalg::{dense_generalized_eigen_low, symmetric_eigen};
use nlsim_kernel::{Damping, Error, MatrixDerivative, Model, Param, Parameterized, Result, Status};
use std::f64::consts::PI;
use std::sync::Arc;

/// Settings of a [`ParametricReduction`].
#[derive(Debug, Clone, PartialEq)]
pub struct ParametricConfig {
    /// Largest certificate indicator (relative, see the module documentation) accepted
    /// without a full reduction. The default, 1e-6, keeps the receptances within about 1e-6
    /// of a full re-reduction on the bracket (measured in `calib/tests/parametric.rs`).
    pub tolerance: f64,
    /// Add the first-order derivative directions of the nominal modes and static responses
    /// to the basis (one block solve per parameter).
    pub derivative_vectors: bool,
    /// Most full reductions the training of [`ParametricReduction::new`] makes.
    pub max_training: usize,
}

impl Default for ParametricConfig {
    fn default() -> Self {
        ParametricConfig {
            tolerance: 1e-6,
            derivative_vectors: true,
            max_training: 16,
        }
    }
}

impl ParametricConfig {
    /// Checks the settings: a finite positive tolerance.
    pub fn check(&self) -> Result<()> {
        if !(self.tolerance.is_finite() && self.tolerance > 0.0) {
            return Err(Error::invalid(
                "parametric reduction tolerance",
                format!("must be a finite positive number, not {}", self.tolerance),
            ));
        }
        Ok(())
    }
}

/// Counters of a [`ParametricReduction`] (this copy's, since it was made or cloned).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct ParametricStats {
    /// Basis vectors.
    pub basis_size: usize,
    /// Full reductions made: the nominal one, the training's and the refreshes.
    pub full_reductions: usize,
    /// Full reductions made by the training of [`ParametricReduction::new`].
    pub training: usize,
    /// Evaluations.
    pub evaluations: usize,
    /// Evaluations whose certificate failed, so that the model was reduced in full there.
    pub refreshes: usize,
    /// Largest certificate indicator of an accepted evaluation (after its refresh, if any).
    pub worst_indicator: f64,
    /// Seconds in full reductions.
    pub full_seconds: f64,
}

/// Derivatives of an evaluation's port data with respect to the parameters (the same
/// quantities as [`crate::ReducedSensitivities`], for the Ritz model).
#[derive(Debug, Clone)]
pub struct ParametricDerivatives {
    /// `∂λ_r/∂p_j` (modes × parameters; rad²/s² per unit of the parameter).
    pub eigenvalues: Mat<f64>,
    /// `∂Φ_P/∂p_j` (ports × modes; m/√kg per unit), one per parameter.
    pub participation: Vec<Mat<f64>>,
    /// `∂D/∂p_j` (ports × ports; m/N per unit), one per parameter.
    pub residual: Vec<Mat<f64>>,
    /// `∂C̃/∂p_j` (modes × modes; 1/s per unit), one per parameter.
    pub damping: Vec<Mat<f64>>,
}

/// One evaluation of a [`ParametricReduction`].
#[derive(Debug, Clone)]
pub struct ParametricPoint {
    /// The reduced model at the parameter values (the lifted Ritz modes; their
    /// [`Modes::residuals`] hold the relative residuals `ρ_r`).
    pub reduced: ReducedModel,
    /// The derivatives, when asked for.
    pub derivatives: Option<ParametricDerivatives>,
    /// The certificate indicator of the result.
    pub indicator: f64,
    /// Whether the certificate failed first and the model was reduced in full here.
    pub refreshed: bool,
}

/// The basis and the matrices projected on it.
#[derive(Debug, Clone)]
struct Projection {
    /// `B` (DOFs × b), `Bᵀ M(p₀) B = I`.
    basis: Mat<f64>,
    /// `Bᵀ K(p₀) B`.
    k: Mat<f64>,
    /// `Bᵀ M(p₀) B`.
    m: Mat<f64>,
    /// `Bᵀ ∂K/∂p_j B` (None where the parameter leaves `K`).
    dk: Vec<Option<Mat<f64>>>,
    /// `Bᵀ ∂M/∂p_j B`.
    dm: Vec<Option<Mat<f64>>>,
    /// `Bᵀ W` (b × ports).
    w: Mat<f64>,
    /// `Bᵀ V B` for a damping matrix `V`.
    v: Option<Mat<f64>>,
}

/// The Ritz solution at some parameter values.
struct Ritz {
    values: Vec<f64>,
    /// `Ψ` (b × b), `Ψᵀ M_B Ψ = I`, signs as the lifted modes'.
    vectors: Mat<f64>,
    retained: usize,
    /// `K_B(p)`, `M_B(p)`.
    k: Mat<f64>,
    m: Mat<f64>,
}

/// The certificate of a Ritz solution: its indicator, the modes' relative residuals `ρ_r`
/// and the Galerkin static responses `Y = (K_B − σ M_B)⁻¹ W_B` (with residual flexibility).
struct Certificate {
    indicator: f64,
    rho: Vec<f64>,
    y: Option<Mat<f64>>,
}

/// The reduction of a model at any values of some FE-level parameters, from one basis.
#[derive(Debug)]
pub struct ParametricReduction {
    model: Arc<Model>,
    /// The model at the values of the last full reduction (made on first need).
    work: Option<Model>,
    params: Vec<Param>,
    nominal: Vec<f64>,
    config: ReductionConfig,
    settings: ParametricConfig,
    ports: Vec<Port>,
    shift: f64,
    stiffness_scale: f64,
    rigid_threshold: f64,
    projection: Arc<Projection>,
    solver: EigenSolver,
    stats: ParametricStats,
}

impl Clone for ParametricReduction {
    /// A copy sharing the basis (copied on its first enrichment) with a fresh eigen solver.
    fn clone(&self) -> Self {
        Self {
            model: Arc::clone(&self.model),
            work: None,
            params: self.params.clone(),
            nominal: self.nominal.clone(),
            config: self.config.clone(),
            settings: self.settings.clone(),
            ports: self.ports.clone(),
            shift: self.shift,
            stiffness_scale: self.stiffness_scale,
            rigid_threshold: self.rigid_threshold,
            projection: Arc::clone(&self.projection),
            solver: EigenSolver::new(),
            stats: self.stats,
        }
    }
}

/// `∂K/∂p X` and `∂M/∂p X` (None where the parameter leaves the matrix).
fn derivative_times(
    d: &MatrixDerivative<'_>,
    x: MatRef<'_, f64>,
    par: Par,
) -> (Option<Mat<f64>>, Option<Mat<f64>>) {
    match *d {
        MatrixDerivative::Group { stiffness, mass } => (
            stiffness.map(|k| symmetric_times(k, x, par)),
            mass.map(|m| symmetric_times(m, x, par)),
        ),
        MatrixDerivative::Spring { dof } => {
            let mut y = Mat::zeros(x.nrows(), x.ncols());
            for c in 0..x.ncols() {
                y[(dof, c)] = x[(dof, c)];
            }
            (Some(y), None)
        }
    }
}

/// `Wᵀ X` without forming `W` (ports × columns of `x`).
fn ports_of(ports: &[Port], x: MatRef<'_, f64>) -> Mat<f64> {
    Mat::from_fn(ports.len(), x.ncols(), |p, c| {
        ports[p]
            .dofs
            .iter()
            .zip(&ports[p].weights)
            .map(|(&d, &w)| w * x[(d, c)])
            .sum()
    })
}

fn symmetrised(a: &Mat<f64>) -> Mat<f64> {
    Mat::from_fn(a.nrows(), a.ncols(), |i, j| 0.5 * (a[(i, j)] + a[(j, i)]))
}

/// `[[a, b], [bᵀ, c]]`.
fn grown(a: &Mat<f64>, b: &Mat<f64>, c: &Mat<f64>) -> Mat<f64> {
    let (n0, n1) = (a.nrows(), c.nrows());
    Mat::from_fn(n0 + n1, n0 + n1, |i, j| match (i < n0, j < n0) {
        (true, true) => a[(i, j)],
        (true, false) => b[(i, j - n0)],
        (false, true) => b[(j, i - n0)],
        (false, false) => c[(i - n0, j - n0)],
    })
}

/// Solves `A Y = R` for symmetric `A`: Cholesky, or LU when `A` is indefinite.
fn solve_symmetric(a: &Mat<f64>, r: &Mat<f64>) -> Result<Mat<f64>> {
    let y = match a.llt(Side::Lower) {
        Ok(llt) => llt.solve(r),
        Err(_) => a.partial_piv_lu().solve(r),
    };
    if y.col_iter().all(|c| c.iter().all(|v| v.is_finite())) {
        Ok(y)
    } else {
        Err(Error::Numerical {
            what: "parametric reduction".into(),
            detail: "the projected K − σM is singular at these parameter values".into(),
        })
    }
}

impl Projection {
    /// The projection on an empty basis of `n` DOFs.
    fn empty(n: usize, params: usize, ports: usize, damping_matrix: bool) -> Self {
        Projection {
            basis: Mat::zeros(n, 0),
            k: Mat::zeros(0, 0),
            m: Mat::zeros(0, 0),
            dk: vec![None; params],
            dm: vec![None; params],
            w: Mat::zeros(0, ports),
            v: damping_matrix.then(|| Mat::zeros(0, 0)),
        }
    }

    /// Adds the directions of `cols` not yet in the basis (M(p₀)-orthonormalised, numerically
    /// dependent directions dropped) and projects the matrices on them. Returns how many
    /// were added.
    fn extend(
        &mut self,
        model: &Model,
        params: &[Param],
        ports: &[Port],
        cols: Mat<f64>,
        par: Par,
    ) -> Result<usize> {
        let mass = model.mass();
        let mut c = cols;
        if c.ncols() == 0 {
            return Ok(0);
        }
        let norms: Vec<f64> = {
            let mc = symmetric_times(mass, c.as_ref(), par);
            (0..c.ncols())
                .map(|j| {
                    c.col(j)
                        .iter()
                        .zip(mc.col(j).iter())
                        .map(|(a, b)| a * b)
                        .sum::<f64>()
                        .max(0.0)
                        .sqrt()
                })
                .collect()
        };
        let scale = norms.iter().fold(0.0f64, |a, &b| a.max(b));
        if !scale.is_finite() {
            return Err(Error::Numerical {
                what: "parametric reduction basis".into(),
                detail: "a basis vector is not finite".into(),
            });
        }
        if scale == 0.0 {
            return Ok(0);
        }
        // Two passes of block Gram–Schmidt against the basis, then an eigen-decomposition of
        // the remaining Gram matrix: directions below 1e-8 of the largest column's M-norm are
        // (numerically) in the basis already and dropped.
        for _ in 0..2 {
            let mc = symmetric_times(mass, c.as_ref(), par);
            let coef = self.basis.transpose() * &mc;
            c -= &self.basis * &coef;
        }
        let mc = symmetric_times(mass, c.as_ref(), par);
        let g = symmetrised(&(c.transpose() * &mc));
        let (s, u) = symmetric_eigen(g.as_ref())?;
        let keep: Vec<usize> = (0..s.len())
            .filter(|&i| s[i] > 0.0 && s[i].sqrt() > 1e-8 * scale)
            .collect();
        if keep.is_empty() {
            return Ok(0);
        }
        let t = Mat::from_fn(c.ncols(), keep.len(), |i, j| {
            u[(i, keep[j])] / s[keep[j]].sqrt()
        });
        let mut q = &c * &t;
        // One more pass against the basis and within the new block (Cholesky of its Gram).
        let mq = symmetric_times(mass, q.as_ref(), par);
        let coef = self.basis.transpose() * &mq;
        q -= &self.basis * &coef;
        let mq = symmetric_times(mass, q.as_ref(), par);
        let g = symmetrised(&(q.transpose() * &mq));
        if let Ok(llt) = g.llt(Side::Lower) {
            let l = llt.L();
            let mut qt = q.transpose().to_owned();
            faer::linalg::triangular_solve::solve_lower_triangular_in_place(
                l,
                qt.as_mut(),
                Par::Seq,
            );
            q = qt.transpose().to_owned();
        }
        let added = q.ncols();
        let grow = |old: &Mat<f64>, aq: &Mat<f64>, basis: &Mat<f64>, q: &Mat<f64>| {
            let b = basis.transpose() * aq;
            let c = symmetrised(&(q.transpose() * aq));
            grown(old, &b, &c)
        };
        let kq = symmetric_times(model.stiffness(), q.as_ref(), par);
        self.k = grow(&self.k, &kq, &self.basis, &q);
        let mq = symmetric_times(mass, q.as_ref(), par);
        self.m = grow(&self.m, &mq, &self.basis, &q);
        for (j, p) in params.iter().enumerate() {
            let d = model.matrix_derivative(p)?;
            let (dkq, dmq) = derivative_times(&d, q.as_ref(), par);
            if let Some(a) = dkq {
                let old = self.dk[j]
                    .take()
                    .unwrap_or_else(|| Mat::zeros(self.basis.ncols(), self.basis.ncols()));
                self.dk[j] = Some(grow(&old, &a, &self.basis, &q));
            }
            if let Some(a) = dmq {
                let old = self.dm[j]
                    .take()
                    .unwrap_or_else(|| Mat::zeros(self.basis.ncols(), self.basis.ncols()));
                self.dm[j] = Some(grow(&old, &a, &self.basis, &q));
            }
        }
        if let (Some(v), Damping::Matrix(vm)) = (&mut self.v, model.damping()) {
            let vq = symmetric_times(vm, q.as_ref(), par);
            *v = grow(v, &vq, &self.basis, &q);
        }
        let wq = ports_of(ports, q.as_ref()).transpose().to_owned();
        let b0 = self.basis.ncols();
        self.w = Mat::from_fn(b0 + added, ports.len(), |i, p| {
            if i < b0 {
                self.w[(i, p)]
            } else {
                wq[(i - b0, p)]
            }
        });
        let n = self.basis.nrows();
        let basis = std::mem::replace(&mut self.basis, Mat::zeros(0, 0));
        self.basis = Mat::from_fn(n, b0 + added, |i, j| {
            if j < b0 {
                basis[(i, j)]
            } else {
                q[(i, j - b0)]
            }
        });
        Ok(added)
    }
}

impl ParametricReduction {
    /// Builds the parametric model of `model` (at its current values, the nominal point) for
    /// the FE-level `params`, reducing as `config` says: one full reduction, the basis of its
    /// modes, static port responses and (with [`ParametricConfig::derivative_vectors`]) their
    /// derivative directions, then a greedy training over `training` (parameter values, one
    /// per point, in `params` order): while the worst certificate among those points passes
    /// the tolerance, the model is reduced in full there and the basis enriched (at most
    /// [`ParametricConfig::max_training`] times). `progress` receives the eigen solver's
    /// progress of the nominal reduction.
    ///
    /// Errors: a parameter that is not FE-level or is listed twice, a training point of the
    /// wrong length or with values the model refuses, or a failed nominal reduction.
    pub fn new(
        model: &Model,
        config: &ReductionConfig,
        params: &[Param],
        settings: ParametricConfig,
        training: &[Vec<f64>],
        progress: &mut dyn FnMut(&crate::EigenProgress),
    ) -> Result<Self> {
        settings.check()?;
        if params.is_empty() {
            return Err(Error::invalid(
                "parametric reduction",
                "no FE-level parameters (a group scale or a boundary spring) to vary",
            ));
        }
        for (i, p) in params.iter().enumerate() {
            model.matrix_derivative(p)?;
            if params[..i].contains(p) {
                return Err(Error::invalid(
                    "parametric reduction",
                    format!("parameter {p} is listed twice"),
                ));
            }
        }
        for (i, t) in training.iter().enumerate() {
            if t.len() != params.len() {
                return Err(Error::DimensionMismatch {
                    what: format!("training point {i} of the parametric reduction"),
                    expected: params.len(),
                    found: t.len(),
                });
            }
        }
        let par = config.eigen.par;
        let nominal: Vec<f64> = params
            .iter()
            .map(|p| model.param(p))
            .collect::<Result<_>>()?;
        let mut solver = EigenSolver::new();
        let t = std::time::Instant::now();
        let reduced = reduce_with(model, config, &mut solver, progress)?;
        let full_seconds = t.elapsed().as_secs_f64();
        let n = model.n_dofs();
        let ports = reduced.ports.clone();
        let residual = config.residual_flexibility && !ports.is_empty();
        let shift = if residual {
            reduced.residual_shift
        } else {
            0.0
        };
        let mut cols = vec![reduced.modes.vectors.clone()];
        if residual || settings.derivative_vectors {
            let w = port_loads(n, &ports);
            let (mut own, mut own_factor) = (None, None);
            let (pencil, factor) = solver.operator(
                model.stiffness(),
                model.mass(),
                par,
                &mut own,
                &mut own_factor,
            )?;
            let sigma = factor.shift();
            let mut x0 = w.clone();
            pencil.solve_in_place(factor, x0.as_mut());
            if settings.derivative_vectors {
                let phi = &reduced.modes.vectors;
                let lambda = &reduced.modes.eigenvalues;
                for p in params {
                    let d = model.matrix_derivative(p)?;
                    let (dkp, dmp) = derivative_times(&d, phi.as_ref(), par);
                    let (dkx, dmx) = derivative_times(&d, x0.as_ref(), par);
                    let mut g = Mat::<f64>::zeros(n, phi.ncols() + x0.ncols());
                    for r in 0..phi.ncols() {
                        for i in 0..n {
                            g[(i, r)] = dkp.as_ref().map_or(0.0, |a| a[(i, r)])
                                - lambda[r] * dmp.as_ref().map_or(0.0, |a| a[(i, r)]);
                        }
                    }
                    for c in 0..x0.ncols() {
                        for i in 0..n {
                            g[(i, phi.ncols() + c)] = dkx.as_ref().map_or(0.0, |a| a[(i, c)])
                                - sigma * dmx.as_ref().map_or(0.0, |a| a[(i, c)]);
                        }
                    }
                    pencil.solve_in_place(factor, g.as_mut());
                    cols.push(g);
                }
            }
            cols.insert(1, x0);
        }
        let mut projection = Projection::empty(
            n,
            params.len(),
            ports.len(),
            matches!(model.damping(), Damping::Matrix(_)),
        );
        for c in cols {
            projection.extend(model, params, &ports, c, par)?;
        }
        let mut out = ParametricReduction {
            model: Arc::new(model.clone()),
            work: None,
            params: params.to_vec(),
            nominal,
            config: config.clone(),
            settings,
            ports,
            shift,
            stiffness_scale: reduced.modes.stiffness_scale,
            rigid_threshold: reduced.modes.rigid_threshold,
            projection: Arc::new(projection),
            solver,
            stats: ParametricStats {
                full_reductions: 1,
                full_seconds,
                ..ParametricStats::default()
            },
        };
        // Greedy training: enrich at the worst training point until all pass.
        let mut refreshed: Vec<usize> = Vec::new();
        while out.stats.training < out.settings.max_training && !training.is_empty() {
            let mut worst = (0usize, 0.0f64);
            for (i, t) in training.iter().enumerate() {
                let e = out
                    .checked(&out.projection, t)
                    .map_or(f64::INFINITY, |c| c.2.indicator);
                if e.is_nan() || e > worst.1 {
                    worst = (i, if e.is_nan() { f64::INFINITY } else { e });
                }
            }
            if worst.1 <= out.settings.tolerance || refreshed.contains(&worst.0) {
                break;
            }
            refreshed.push(worst.0);
            let cols = out.full_at(&training[worst.0])?;
            let proj = Arc::make_mut(&mut out.projection);
            proj.extend(&out.model, &out.params, &out.ports, cols, par)?;
            out.stats.training += 1;
        }
        out.stats.basis_size = out.projection.basis.ncols();
        Ok(out)
    }

    /// The parameters, in the order of the values passed to
    /// [`ParametricReduction::evaluate`].
    pub fn params(&self) -> &[Param] {
        &self.params
    }

    /// The parameter values of the nominal reduction.
    pub fn nominal(&self) -> &[f64] {
        &self.nominal
    }

    /// The counters.
    pub fn stats(&self) -> ParametricStats {
        self.stats
    }

    /// The settings.
    pub fn settings(&self) -> &ParametricConfig {
        &self.settings
    }

    /// The nominal model.
    pub fn model(&self) -> &Model {
        &self.model
    }

    /// The reduced model at parameter `values` (in [`ParametricReduction::params`] order),
    /// with its derivatives when `derivatives`. When the certificate fails, the model is
    /// reduced in full at `values` and the Ritz solve repeated on the basis enriched with
    /// that reduction's modes and static responses; with `keep` the enrichment stays in this
    /// copy's basis for later evaluations, otherwise it serves this evaluation only (so that
    /// the result depends on `values` and the basis this copy started from alone).
    ///
    /// Errors: values of the wrong count or refused by the model; `Error::Numerical` when the
    /// full reduction fails at these values.
    pub fn evaluate(
        &mut self,
        values: &[f64],
        derivatives: bool,
        keep: bool,
    ) -> Result<ParametricPoint> {
        if values.len() != self.params.len() {
            return Err(Error::DimensionMismatch {
                what: "parametric reduction values".into(),
                expected: self.params.len(),
                found: values.len(),
            });
        }
        for (p, &v) in self.params.iter().zip(values) {
            nlsim_kernel::param::check_finite(p, v)?;
        }
        self.stats.evaluations += 1;
        if let Ok(checked) = self.checked(&self.projection, values)
            && checked.2.indicator <= self.settings.tolerance
        {
            self.stats.worst_indicator = self.stats.worst_indicator.max(checked.2.indicator);
            let proj = Arc::clone(&self.projection);
            return self.point(&proj, checked, derivatives, false);
        }
        self.stats.refreshes += 1;
        let cols = self.full_at(values)?;
        let par = self.config.eigen.par;
        let proj = if keep {
            let proj = Arc::make_mut(&mut self.projection);
            proj.extend(&self.model, &self.params, &self.ports, cols, par)?;
            self.stats.basis_size = proj.basis.ncols();
            Arc::clone(&self.projection)
        } else {
            let mut proj = (*self.projection).clone();
            proj.extend(&self.model, &self.params, &self.ports, cols, par)?;
            Arc::new(proj)
        };
        let checked = self.checked(&proj, values)?;
        self.stats.worst_indicator = self.stats.worst_indicator.max(checked.2.indicator);
        self.point(&proj, checked, derivatives, true)
    }

    /// The full reduction at `values`: its modes and static port responses as columns.
    fn full_at(&mut self, values: &[f64]) -> Result<Mat<f64>> {
        let t = std::time::Instant::now();
        let work = self.work.get_or_insert_with(|| (*self.model).clone());
        for (p, &v) in self.params.iter().zip(values) {
            work.set_param(p, v)?;
        }
        let reduced = reduce_with(work, &self.config, &mut self.solver, &mut |_| {})?;
        let n = work.n_dofs();
        let mut cols = reduced.modes.vectors;
        if !self.ports.is_empty() {
            let (mut own, mut own_factor) = (None, None);
            let (pencil, factor) = self.solver.operator(
                work.stiffness(),
                work.mass(),
                self.config.eigen.par,
                &mut own,
                &mut own_factor,
            )?;
            let mut x = port_loads(n, &self.ports);
            pencil.solve_in_place(factor, x.as_mut());
            let m = cols.ncols();
            cols = Mat::from_fn(n, m + x.ncols(), |i, j| {
                if j < m { cols[(i, j)] } else { x[(i, j - m)] }
            });
        }
        self.stats.full_reductions += 1;
        self.stats.full_seconds += t.elapsed().as_secs_f64();
        Ok(cols)
    }

    fn deltas(&self, values: &[f64]) -> Vec<f64> {
        values
            .iter()
            .zip(&self.nominal)
            .map(|(v, n)| v - n)
            .collect()
    }

    /// The Ritz pairs at `values` on `proj`.
    fn ritz(&self, proj: &Projection, values: &[f64]) -> Result<Ritz> {
        let b = proj.basis.ncols();
        let dp = self.deltas(values);
        let mut k = proj.k.clone();
        let mut m = proj.m.clone();
        for (j, &d) in dp.iter().enumerate() {
            if let Some(a) = &proj.dk[j] {
                k += a * faer::Scale(d);
            }
            if let Some(a) = &proj.dm[j] {
                m += a * faer::Scale(d);
            }
        }
        let eig = dense_generalized_eigen_low(k.as_ref(), m.as_ref())?;
        let retained = match self.config.eigen.selection {
            ModeSelection::Lowest(r) => r,
            ModeSelection::Below { f_max_hz } => {
                let l = (2.0 * PI * f_max_hz).powi(2);
                eig.values.iter().filter(|&&v| v < l).count()
            }
        };
        if retained > b {
            return Err(Error::invalid(
                "parametric reduction",
                format!("{retained} modes are wanted from a basis of {b} vectors"),
            ));
        }
        Ok(Ritz {
            values: eig.values,
            vectors: eig.vectors,
            retained,
            k,
            m,
        })
    }

    /// The lifted retained modes (signs fixed: largest entry positive; `ritz`'s vectors
    /// flipped alike).
    fn lift(&self, proj: &Projection, ritz: &mut Ritz) -> Mat<f64> {
        let m = ritz.retained;
        let mut phi = &proj.basis * ritz.vectors.subcols(0, m);
        for c in 0..m {
            let mut best = 0.0f64;
            let mut sign = 1.0;
            for i in 0..phi.nrows() {
                if phi[(i, c)].abs() > best {
                    best = phi[(i, c)].abs();
                    sign = phi[(i, c)].signum();
                }
            }
            if sign < 0.0 {
                for i in 0..phi.nrows() {
                    phi[(i, c)] = -phi[(i, c)];
                }
                for i in 0..ritz.vectors.nrows() {
                    ritz.vectors[(i, c)] = -ritz.vectors[(i, c)];
                }
            }
        }
        phi
    }

    /// `(K(p) X, M(p) X)` from the nominal matrices and the derivatives.
    fn products(&self, values: &[f64], x: MatRef<'_, f64>) -> Result<(Mat<f64>, Mat<f64>)> {
        let par = self.config.eigen.par;
        let mut kx = symmetric_times(self.model.stiffness(), x, par);
        let mut mx = symmetric_times(self.model.mass(), x, par);
        for (p, d) in self.params.iter().zip(self.deltas(values)) {
            if d == 0.0 {
                continue;
            }
            let der = self.model.matrix_derivative(p)?;
            let (a, b) = derivative_times(&der, x, par);
            if let Some(a) = a {
                kx += &a * faer::Scale(d);
            }
            if let Some(b) = b {
                mx += &b * faer::Scale(d);
            }
        }
        Ok((kx, mx))
    }

    /// The certificate at `values` of `ritz` with its lifted modes `phi`.
    fn certificate(
        &self,
        proj: &Projection,
        values: &[f64],
        ritz: &Ritz,
        phi: &Mat<f64>,
    ) -> Result<Certificate> {
        let m = ritz.retained;
        let (kp, mp) = self.products(values, phi.as_ref())?;
        let mut worst = 0.0f64;
        let mut rho = Vec::with_capacity(m);
        for r in 0..m {
            let l = ritz.values[r];
            let res = (kp.col(r) - mp.col(r) * faer::Scale(l)).norm_l2();
            let scale = (mp.col(r) * faer::Scale(l)).norm_l2();
            let rr = if scale > 0.0 {
                res / scale
            } else {
                f64::INFINITY
            };
            rho.push(rr);
            let gap = ritz
                .values
                .iter()
                .enumerate()
                .filter(|&(s, _)| s != r)
                .map(|(_, &v)| (v - l).abs())
                .fold(f64::INFINITY, f64::min);
            let e = if gap > 0.0 {
                rr * l.abs() / gap
            } else {
                f64::INFINITY
            };
            worst = worst.max(if e.is_nan() { f64::INFINITY } else { e });
        }
        let mut y_out = None;
        if self.config.residual_flexibility && !self.ports.is_empty() {
            let a = &ritz.k - &ritz.m * faer::Scale(self.shift);
            let y = solve_symmetric(&a, &proj.w)?;
            let x = &proj.basis * &y;
            let (kx, mx) = self.products(values, x.as_ref())?;
            let mut r = &kx - &mx * faer::Scale(self.shift);
            let mut wn = 0.0;
            for (p, port) in self.ports.iter().enumerate() {
                for (&d, &w) in port.dofs.iter().zip(&port.weights) {
                    r[(d, p)] -= w;
                    wn += w * w;
                }
            }
            let e = r.norm_l2() / wn.sqrt();
            worst = worst.max(if e.is_nan() { f64::INFINITY } else { e });
            y_out = Some(y);
        }
        Ok(Certificate {
            indicator: worst,
            rho,
            y: y_out,
        })
    }

    /// The Ritz solution at `values` on `proj`, its lifted modes (signs fixed) and its
    /// certificate.
    fn checked(&self, proj: &Projection, values: &[f64]) -> Result<(Ritz, Mat<f64>, Certificate)> {
        let mut ritz = self.ritz(proj, values)?;
        let phi = self.lift(proj, &mut ritz);
        let cert = self.certificate(proj, values, &ritz, &phi)?;
        Ok((ritz, phi, cert))
    }

    /// The evaluation's result on `proj`, from its checked Ritz solution.
    fn point(
        &self,
        proj: &Projection,
        (ritz, vectors, cert): (Ritz, Mat<f64>, Certificate),
        derivatives: bool,
        refreshed: bool,
    ) -> Result<ParametricPoint> {
        let Certificate { indicator, rho, y } = cert;
        let m = ritz.retained;
        let np = self.ports.len();
        let psi_m = ritz.vectors.subcols(0, m).to_owned();
        let phi_all = proj.w.transpose() * &ritz.vectors; // ports × b
        let participation = phi_all.subcols(0, m).to_owned();
        let lambda = &ritz.values;
        let sigma = self.shift;
        let residual = match &y {
            Some(y) => {
                let mut d = proj.w.transpose() * y;
                for r in 0..m {
                    let s = 1.0 / (lambda[r] - sigma);
                    for p in 0..np {
                        for q in 0..np {
                            d[(p, q)] -= participation[(p, r)] * participation[(q, r)] * s;
                        }
                    }
                }
                symmetrised(&d)
            }
            None => Mat::zeros(np, np),
        };
        let model = &self.model;
        let derivs = if derivatives {
            let b = ritz.values.len();
            let k = self.params.len();
            let mut eigenvalues = Mat::zeros(m, k);
            let mut dpart = Vec::with_capacity(k);
            let mut dres = Vec::with_capacity(k);
            let mut ddamp = Vec::with_capacity(k);
            for j in 0..k {
                let kj = proj.dk[j]
                    .as_ref()
                    .map(|a| ritz.vectors.transpose() * a * &psi_m);
                let mj = proj.dm[j]
                    .as_ref()
                    .map(|a| ritz.vectors.transpose() * a * &psi_m);
                let at = |x: &Option<Mat<f64>>, s: usize, r: usize| {
                    x.as_ref().map_or(0.0, |x| x[(s, r)])
                };
                // Coefficients of ∂ψ_r in the Ritz vectors (b × m).
                let mut c = Mat::<f64>::zeros(b, m);
                for r in 0..m {
                    eigenvalues[(r, j)] = at(&kj, r, r) - lambda[r] * at(&mj, r, r);
                    for s in 0..b {
                        if s == r {
                            c[(s, r)] = -0.5 * at(&mj, r, r);
                            continue;
                        }
                        let gap = lambda[r] - lambda[s];
                        if gap.abs() <= 1e-8 * lambda[r].abs().max(lambda[s].abs()) {
                            continue;
                        }
                        // From (K − λ_r M)∂ψ_r = −(∂K − λ_r ∂M)ψ_r + ∂λ_r M ψ_r.
                        c[(s, r)] = (at(&kj, s, r) - lambda[r] * at(&mj, s, r)) / gap;
                    }
                }
                let dphi = &phi_all * &c;
                let dd = match &y {
                    Some(y) => {
                        let mut da = Mat::<f64>::zeros(b, b);
                        if let Some(a) = &proj.dk[j] {
                            da += a;
                        }
                        if let Some(a) = &proj.dm[j] {
                            da -= a * faer::Scale(sigma);
                        }
                        let mut dd = -(y.transpose() * &da * y);
                        for r in 0..m {
                            let s = 1.0 / (lambda[r] - sigma);
                            let dl = eigenvalues[(r, j)] * s * s;
                            for p in 0..np {
                                for q in 0..np {
                                    dd[(p, q)] +=
                                        participation[(p, r)] * participation[(q, r)] * dl
                                            - (dphi[(p, r)] * participation[(q, r)]
                                                + participation[(p, r)] * dphi[(q, r)])
                                                * s;
                                }
                            }
                        }
                        symmetrised(&dd)
                    }
                    None => Mat::zeros(np, np),
                };
                let dc = match (model.damping(), &proj.v) {
                    (Damping::Matrix(_), Some(v)) => {
                        let dpsi = &ritz.vectors * &c;
                        let t = dpsi.transpose() * v * &psi_m;
                        Mat::from_fn(m, m, |r, s| t[(r, s)] + t[(s, r)])
                    }
                    (damping, _) => Mat::from_fn(m, m, |r, s| {
                        if r != s {
                            return 0.0;
                        }
                        crate::sensitivity::proportional_damping_derivative(
                            damping,
                            r,
                            lambda[r],
                            eigenvalues[(r, j)],
                        )
                    }),
                };
                dpart.push(dphi);
                dres.push(dd);
                ddamp.push(dc);
            }
            Some(ParametricDerivatives {
                eigenvalues,
                participation: dpart,
                residual: dres,
                damping: ddamp,
            })
        } else {
            None
        };
        let max_rho = rho.iter().fold(0.0f64, |a, &b| a.max(b));
        let modes = Modes {
            eigenvalues: lambda[..m].to_vec(),
            vectors,
            residuals: rho,
            stiffness_scale: self.stiffness_scale,
            rigid_threshold: self.rigid_threshold,
            stats: EigenStats {
                method: EigenMethod::Dense,
                shift: sigma,
                block_size: 0,
                basis_size: proj.basis.ncols(),
                restarts: 0,
                operator_applications: 0,
                factor_nnz: 0,
                ordering: None,
                factor_released: false,
                reused_analysis: true,
                analysis_seconds: 0.0,
                factor_seconds: 0.0,
                iteration_seconds: 0.0,
                check_seconds: 0.0,
                sturm: None,
                max_residual: max_rho,
                status: Status::Converged,
                detail: String::new(),
            },
        };
        Ok(ParametricPoint {
            reduced: ReducedModel {
                modes,
                ports: self.ports.clone(),
                participation,
                residual,
                residual_shift: sigma,
                damping: model.damping().clone(),
                residual_seconds: 0.0,
                measured: Vec::new(),
                points: Vec::new(),
            },
            derivatives: derivs,
            indicator,
            refreshed,
        })
    }
}
