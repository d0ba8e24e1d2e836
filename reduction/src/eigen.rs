//! The lowest modes of `K φ = ω² M φ` for large sparse `K`, `M`: shift-invert block Lanczos
//! with thick (Krylov–Schur) restarts, on a sparse Cholesky factor of `K − σM`.
//!
//! # Method
//!
//! With `σ` below the spectrum, `K − σM` is positive definite and the operator
//! `Op = (K − σM)⁻¹ M` is self-adjoint in the `M` inner product, with eigenvalues
//! `θ = 1 / (λ − σ)`: the lowest `λ` become the largest, best separated `θ`. A block of `b`
//! vectors is expanded into an `M`-orthonormal basis `V` (classical Gram–Schmidt, twice, against
//! the whole basis), so that `Op V = V H + W B` with `H = Vᵀ M Op V` symmetric and `W` the next
//! block. When the basis is full, the Ritz pairs of `H` are computed; the best `k` Ritz vectors
//! are kept (`V ← V Y_k`, `H ← diag θ_k`, `B ← B Y_k`) and the expansion goes on. The residual
//! of a Ritz pair `(θ, V y)` is `‖B y‖₂` exactly, so convergence needs no extra solve.
//!
//! A block of `b ≥ 2` vectors finds repeated eigenvalues up to multiplicity `b` in exact
//! arithmetic (the symmetric-section pairs of a beam, the six rigid-body modes of a free–free
//! body with the default `b = 6`), and the Sturm sequence check (the inertia of `K − σ_c M`
//! just above the last wanted eigenvalue) proves that none was missed; if one was, the solve is
//! repeated with a larger block.
//!
//! Free–free structures: when `K` itself is singular, `σ` is taken slightly negative
//! (`−10⁻⁸ max_i K_ii/M_ii`), which keeps rigid-body modes (`λ ≈ 0`) in the spectrum.

use crate::factor::{ShiftFactor, ShiftedPencil};
use crate::ordering::Ordering;
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par};
use nlsim_kernel::{Error, Result, SparseSym, Status};
use std::time::Instant;

/// Which modes to compute.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ModeSelection {
    /// The lowest `n` modes.
    Lowest(usize),
    /// Every mode whose undamped frequency lies below `f_max_hz` (Hz); the count comes from a
    /// Sturm sequence check at `(2π f_max)²`.
    Below {
        /// Upper frequency (Hz, exclusive).
        f_max_hz: f64,
    },
}

/// Which algorithm solved the problem.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EigenMethod {
    /// Shift-invert block Lanczos with thick restarts on a sparse Cholesky factor.
    Lanczos,
    /// The dense generalized eigen solver (small models, or when most of the spectrum is wanted).
    Dense,
}

/// Settings of [`EigenSolver::solve`].
#[derive(Debug, Clone, PartialEq)]
pub struct EigenConfig {
    /// Which modes.
    pub selection: ModeSelection,
    /// Convergence tolerance on the Ritz residual: `‖Op x − θ x‖_M ≤ tol · θ`.
    pub tol: f64,
    /// Vectors per Lanczos block (the largest multiplicity found without relying on round-off).
    pub block_size: usize,
    /// Basis size before a restart; `None` chooses `max(2·nev, nev + 4·b)`.
    pub basis_size: Option<usize>,
    /// Most restarts before giving up.
    pub max_restarts: usize,
    /// Shift `σ` (rad²/s²); must lie below the lowest wanted eigenvalue. `None` picks 0, or a
    /// small negative value when `K` is singular.
    pub shift: Option<f64>,
    /// Seed of the random starting block.
    pub seed: u64,
    /// Verify with a Sturm sequence count that no mode below the last one returned was missed
    /// (one extra `L D Lᵀ` factorisation).
    pub sturm_check: bool,
    /// Models with at most this many DOFs are solved densely (exact, O(n³)).
    pub dense_below: usize,
    /// Parallelism of the factorisations, solves and block products (faer's `Par`; the
    /// default `Par::rayon(0)` uses the current rayon pool). Results are bit-identical for
    /// a given `par`; `Par::Seq` makes them independent of the machine's thread count.
    pub par: faer::Par,
    /// Fill-reducing ordering of the factor ([`Ordering::Auto`]: AMD or nested dissection,
    /// whichever leaves fewer values).
    pub ordering: Ordering,
    /// Bytes the numeric factors may take together (`None`: no limit). When the Sturm check's
    /// `L D Lᵀ` beside the operator's `L Lᵀ` would pass it, the check factorises into the
    /// operator factor's storage and the factor is released ([`EigenSolver::factor`] is then
    /// `None`, and the residual flexibility refactorises once at the same shift): the peak
    /// holds one factor instead of two. The Lanczos iteration keeps `M V` beside its basis
    /// only when the budget holds the factor, `V` and `M V` (else it recomputes the products
    /// with `M`, two more per block).
    pub memory_budget: Option<usize>,
}

impl Default for EigenConfig {
    fn default() -> Self {
        EigenConfig {
            selection: ModeSelection::Lowest(10),
            tol: 1e-10,
            block_size: 6,
            basis_size: None,
            max_restarts: 200,
            shift: None,
            seed: 0x5eed_0001,
            sturm_check: true,
            dense_below: 200,
            par: faer::Par::rayon(0),
            ordering: Ordering::Auto,
            memory_budget: None,
        }
    }
}

/// How a solve went: where the time went and what was checked.
#[derive(Debug, Clone, PartialEq)]
pub struct EigenStats {
    /// Algorithm used.
    pub method: EigenMethod,
    /// Shift `σ` (rad²/s²) of the factorisation.
    pub shift: f64,
    /// Lanczos block size.
    pub block_size: usize,
    /// Basis size at restart.
    pub basis_size: usize,
    /// Restarts performed.
    pub restarts: usize,
    /// Columns passed through `(K − σM)⁻¹ M`.
    pub operator_applications: usize,
    /// Values stored in the Cholesky factor (fill included).
    pub factor_nnz: usize,
    /// The fill-reducing ordering of the factor (`None` on the dense path).
    pub ordering: Option<Ordering>,
    /// Whether the Sturm check reused the operator factor's storage (the memory budget), so
    /// that the factor is no longer held.
    pub factor_released: bool,
    /// Whether the symbolic analysis of an earlier solve was reused.
    pub reused_analysis: bool,
    /// Seconds in symbolic analysis.
    pub analysis_seconds: f64,
    /// Seconds in numeric factorisation(s) of the operator.
    pub factor_seconds: f64,
    /// Seconds in the Lanczos iteration (solves, orthogonalisation, Ritz problems).
    pub iteration_seconds: f64,
    /// Seconds in the Sturm check and the residual check.
    pub check_seconds: f64,
    /// Number of eigenvalues below the check shift found by the Sturm count, and that shift.
    pub sturm: Option<(usize, f64)>,
    /// Largest backward error `‖Kφ − λMφ‖ / ((‖K‖ + |λ|‖M‖) ‖φ‖)` over the returned modes.
    pub max_residual: f64,
    /// [`Status::Converged`], or [`Status::IterationLimit`] when the restart limit came
    /// first or the Sturm count still found missed modes after the retries: the modes are
    /// then the current Ritz approximations (see [`Modes::into_converged`]).
    pub status: Status,
    /// Why the solve stopped short, naming the counts and the remedy; empty when converged.
    pub detail: String,
}

/// Progress of a long solve, reported after each restart.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EigenProgress {
    /// Restarts so far.
    pub restart: usize,
    /// Wanted modes converged so far.
    pub converged: usize,
    /// Wanted modes.
    pub wanted: usize,
}

/// Mass-normalised modes, ascending.
#[derive(Debug, Clone)]
pub struct Modes {
    /// Eigenvalues `λ_r = ω_r²` (rad²/s²), ascending.
    pub eigenvalues: Vec<f64>,
    /// Mode shapes as columns, `φ_rᵀ M φ_r = 1`, sign fixed so that the largest entry is
    /// positive.
    pub vectors: Mat<f64>,
    /// Backward error of each mode (see [`EigenStats::max_residual`]).
    pub residuals: Vec<f64>,
    /// The model's stiffness-to-mass scale `max_i K_ii / M_ii` over the DOFs with mass
    /// (rad²/s²; see [`stiffness_scale`]): a lower bound of the largest eigenvalue of the whole
    /// model, retained or not.
    pub stiffness_scale: f64,
    /// Eigenvalues `|λ| ≤ rigid_threshold` (rad²/s²) are rigid-body modes. It is 0 when `K`
    /// is positive definite (its Cholesky factor exists, so no mode is rigid however low), and
    /// [`RIGID_RELATIVE`]` × stiffness_scale` when `K` is singular. It is relative to the
    /// model, not to the largest retained eigenvalue, so keeping more (or all) modes never
    /// turns a flexible mode rigid.
    pub rigid_threshold: f64,
    /// How the solve went.
    pub stats: EigenStats,
}

/// Models up to this many DOFs are solved densely when the wanted modes would fill a Lanczos
/// basis (more than half the spectrum): about a minute of `O(n³)` work and `3 n²` doubles
/// (0.9 GB) at the limit.
pub const DENSE_FALLBACK_MAX: usize = 6000;

/// With a singular `K`, eigenvalues within this fraction of [`Modes::stiffness_scale`] of zero
/// are rigid-body modes: a computed rigid-body eigenvalue is rounding noise of order `ε λ_max`
/// (measured up to 3 ε of the scale on the free 924-DOF bracket, dense path, and 0.3 ε with
/// Lanczos).
pub const RIGID_RELATIVE: f64 = 1e3 * f64::EPSILON;

/// Relative gap below which two eigenvalues form one (degenerate) cluster, kept whole at the
/// mode cut-off: symmetric-section pairs of a beam agree to about 1e-12, physically distinct
/// modes differ by far more than 1e-8.
pub const CLUSTER_RELATIVE: f64 = 1e-8;

/// Whether eigenvalues (or inverse Ritz values) `a` and `b` belong to one cluster.
fn same_cluster(a: f64, b: f64) -> bool {
    (a - b).abs() <= CLUSTER_RELATIVE * a.abs().max(b.abs())
}

/// `max_i K_ii / M_ii` over the DOFs with `M_ii > 0` (rad²/s²): the model's stiffness-to-mass
/// scale. By the Rayleigh quotient of a unit vector it is at most the largest eigenvalue of
/// `K φ = λ M φ`; for finite-element models it is within a small factor of it. At least
/// `f64::MIN_POSITIVE`.
pub fn stiffness_scale(k: &SparseSym, m: &SparseSym) -> f64 {
    k.diag()
        .iter()
        .zip(&m.diag())
        .filter(|(_, b)| **b > 0.0)
        .map(|(a, b)| a.abs() / b)
        .fold(0.0f64, f64::max)
        .max(f64::MIN_POSITIVE)
}

impl Modes {
    /// `true` when every returned mode converged (and the Sturm check, when made, agreed).
    pub fn is_converged(&self) -> bool {
        self.stats.status.is_converged()
    }

    /// The modes when the solve converged; else an [`Error::Numerical`] with the solve's
    /// detail, for callers that need converged modes or nothing (the reduction).
    pub fn into_converged(self) -> Result<Self> {
        if self.is_converged() {
            return Ok(self);
        }
        Err(Error::Numerical {
            what: match self.stats.method {
                EigenMethod::Dense => "dense eigen solve".into(),
                EigenMethod::Lanczos => "shift-invert Lanczos".into(),
            },
            detail: self.stats.detail,
        })
    }

    /// Number of modes.
    pub fn len(&self) -> usize {
        self.eigenvalues.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.eigenvalues.is_empty()
    }

    /// Whether mode `r` (0-based) is a rigid-body mode (see [`Modes::rigid_threshold`]).
    pub fn is_rigid(&self, r: usize) -> bool {
        self.eigenvalues[r].abs() <= self.rigid_threshold
    }

    /// Circular frequencies `ω_r = √λ_r` (rad/s); eigenvalues at round-off level below zero
    /// (rigid-body modes) give 0.
    pub fn omega(&self) -> Vec<f64> {
        self.eigenvalues
            .iter()
            .map(|&l| l.max(0.0).sqrt())
            .collect()
    }

    /// Frequencies `f_r = ω_r / 2π` (Hz).
    pub fn frequencies_hz(&self) -> Vec<f64> {
        self.omega()
            .into_iter()
            .map(|w| w / (2.0 * std::f64::consts::PI))
            .collect()
    }
}

/// SplitMix64: a tiny deterministic generator for starting vectors (seeded, recorded).
pub(crate) struct SplitMix(u64);

impl SplitMix {
    pub(crate) fn new(seed: u64) -> Self {
        SplitMix(seed)
    }
    /// Uniform in `[-1, 1)`.
    pub(crate) fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^= z >> 31;
        (z >> 11) as f64 * (2.0 / (1u64 << 53) as f64) - 1.0
    }
}

/// The eigen solver; keeps the symbolic analysis and the last factor between solves, so that
/// a parameter study with new values on the same pattern only refactorises, and the residual
/// flexibility reuses the factor of the eigen solve.
#[derive(Debug, Default)]
pub struct EigenSolver {
    pencil: Option<ShiftedPencil>,
    factor: Option<ShiftFactor>,
    /// The shift of the last Lanczos solve (kept when its factor was released).
    shift: Option<f64>,
}

/// Checks shared by every entry point: sizes, finite values, mass on every DOF.
pub(crate) fn check_pencil(k: &SparseSym, m: &SparseSym) -> Result<()> {
    if k.n() != m.n() {
        return Err(Error::DimensionMismatch {
            what: "mass matrix order (must equal the stiffness matrix order)".into(),
            expected: k.n(),
            found: m.n(),
        });
    }
    if k.n() == 0 {
        return Err(Error::invalid("eigen problem", "the model has no DOFs"));
    }
    for (name, a) in [("stiffness matrix", k), ("mass matrix", m)] {
        if let Some((i, j, v)) = a.first_non_finite() {
            return Err(Error::NonFinite {
                what: name.into(),
                location: format!("entry ({i}, {j}) (0-based DOF indices)"),
                value: v,
            });
        }
    }
    // Only the lower triangle is factorised: an asymmetric matrix would be silently
    // symmetrised, so it is refused (the default tolerance of model validation).
    for (name, a) in [("stiffness matrix", k), ("mass matrix", m)] {
        if let Some(d) = a.symmetry_defect()
            && d.rel_diff > 1e-10
        {
            return Err(Error::NotSymmetric {
                matrix: name.into(),
                row: format!("DOF index {}", d.row),
                col: format!("DOF index {}", d.col),
                a_ij: d.a_ij,
                a_ji: d.a_ji,
                rel_diff: d.rel_diff,
                tolerance: 1e-10,
            });
        }
    }
    if let Some(e) = nlsim_kernel::model::mass_sign_error(k, m, |i| format!("DOF index {i}")) {
        return Err(e);
    }
    let massless: Vec<usize> = m
        .diag()
        .iter()
        .enumerate()
        .filter(|(_, d)| **d <= 0.0)
        .map(|(i, _)| i)
        .collect();
    if !massless.is_empty() {
        return Err(Error::MasslessDofs {
            count: massless.len(),
            listed: massless
                .iter()
                .take(10)
                .map(|i| format!("DOF index {i}"))
                .collect::<Vec<_>>()
                .join(", "),
        });
    }
    Ok(())
}

/// `‖A‖_∞` (the largest absolute row sum; rows and columns agree for symmetric A).
fn norm_inf(a: &SparseSym) -> f64 {
    (0..a.n())
        .map(|j| a.col(j).1.iter().map(|v| v.abs()).sum::<f64>())
        .fold(0.0, f64::max)
}

fn sparse_times(a: &SparseSym, x: MatRef<'_, f64>, par: Par) -> Mat<f64> {
    crate::products::symmetric_times(a, x, par)
}

/// Finishes computed eigenpairs: the sign convention (largest entry positive), each
/// eigenvalue replaced by its vector's Rayleigh quotient `φᵀKφ / φᵀMφ` (from
/// error-free products and sums, `crate::rayleigh`: the best estimate the vector gives, with an error quadratic in the
/// vector's), and the backward errors `‖Kφ − λMφ‖ / ((‖K‖ + |λ|‖M‖)‖φ‖)`.
fn finish_vectors(
    k: &SparseSym,
    m: &SparseSym,
    values: &mut [f64],
    vectors: &mut Mat<f64>,
    par: faer::Par,
) -> Vec<f64> {
    for c in 0..vectors.ncols() {
        let col = vectors.col(c);
        let mut best = 0.0f64;
        let mut sign = 1.0;
        for i in 0..col.nrows() {
            if col[i].abs() > best {
                best = col[i].abs();
                sign = col[i].signum();
            }
        }
        if sign < 0.0 {
            for i in 0..vectors.nrows() {
                vectors[(i, c)] = -vectors[(i, c)];
            }
        }
    }
    let kq = crate::rayleigh::quadratic_forms(k, vectors.as_ref(), par);
    let mq = crate::rayleigh::quadratic_forms(m, vectors.as_ref(), par);
    for c in 0..vectors.ncols() {
        if mq[c] > 0.0 && (kq[c] / mq[c]).is_finite() {
            values[c] = kq[c] / mq[c];
        }
    }
    // A few columns at a time: `K Φ` and `M Φ` whole would be two more matrices of the size of
    // the modes (0.9 GB for 50 modes at 10⁶ DOFs).
    const COLUMNS: usize = 8;
    let (kn, mn) = (norm_inf(k), norm_inf(m));
    let mut residuals = Vec::with_capacity(vectors.ncols());
    for c0 in (0..vectors.ncols()).step_by(COLUMNS) {
        let w = COLUMNS.min(vectors.ncols() - c0);
        let x = vectors.subcols(c0, w);
        let kx = sparse_times(k, x, par);
        let mx = sparse_times(m, x, par);
        for c in 0..w {
            let l = values[c0 + c];
            let r = (kx.col(c) - mx.col(c) * faer::Scale(l)).norm_l2();
            residuals.push(r / ((kn + l.abs() * mn) * x.col(c).norm_l2()));
        }
    }
    residuals
}

/// The residual check of every finished solve, dense or Lanczos. A mode whose backward error
/// `‖Kφ − λMφ‖ / ((‖K‖ + |λ|‖M‖)‖φ‖)` is not finite, or above
/// `max(1e-8, 10·tol) · max(1, |λ − σ| / min_j |λ_j − σ|)`, is not an eigenpair of the pencil to
/// the accuracy the solve can give it. A stable solve of the inverted pencil `(K − σM)⁻¹M` leaves
/// each mode a backward error of about `ε |λ − σ| / min_j |λ_j − σ|` (relative to the largest
/// `1/(λ − σ)`), hence the ratio; a converged Ritz pair is within about `tol`. Returns the status
/// and a message naming the worst mode (1-based) against its limit, or `None` when all pass.
fn residual_failure(
    residuals: &[f64],
    values: &[f64],
    sigma: f64,
    tol: f64,
) -> Option<(Status, String)> {
    if let Some(i) = residuals.iter().position(|r| !r.is_finite()) {
        return Some((
            Status::NonFinite,
            format!(
                "mode {} has a non-finite backward error ({})",
                i + 1,
                residuals[i]
            ),
        ));
    }
    let base = (10.0 * tol).max(1e-8);
    let nearest = values
        .iter()
        .map(|v| (v - sigma).abs())
        .fold(f64::INFINITY, f64::min)
        .max(f64::MIN_POSITIVE);
    let (mut worst, mut worst_ratio, mut worst_limit) = (0, 0.0f64, base);
    for (i, (&r, &v)) in residuals.iter().zip(values).enumerate() {
        let limit = base * ((v - sigma).abs() / nearest).max(1.0);
        if r / limit > worst_ratio {
            (worst, worst_ratio, worst_limit) = (i, r / limit, limit);
        }
    }
    (worst_ratio > 1.0).then(|| {
        (
            Status::Singular,
            format!(
                "mode {} has backward error {:.2e} > {worst_limit:.1e}: the computed pair is not \
                 an eigenpair of K and M to that accuracy (the shifted pencil K − σM, σ = \
                 {sigma:e} rad²/s², is close to singular or the matrices are badly scaled)",
                worst + 1,
                residuals[worst]
            ),
        )
    })
}

/// Near-null modes: when the lowest computed eigenvalues lie below this fraction of the next
/// one, inverting the pencil at σ = 0 costs the others their accuracy (the inverse's rounding,
/// ε/λ₁ in absolute terms, is ε λ/λ₁ relative on λ: 1e-4 on a loudspeaker model whose
/// stiffness has a mode at 1.6e-8 rad²/s² under the next at 3.3e6), and the solve is redone at
/// σ = −[`NEAR_NULL_SHIFT`] times that next eigenvalue, where the loss is ε λ / (1e-3 λ_next).
pub const NEAR_NULL_GAP: f64 = 1e-8;

/// The shift (fraction of the lowest eigenvalue above a near-null cluster) a solve is redone at.
pub const NEAR_NULL_SHIFT: f64 = 1e-3;

/// The count of near-null eigenvalues at the bottom of `values` (ascending) and the first
/// eigenvalue above them: the last `j` with `values[j − 1] < NEAR_NULL_GAP · values[j]`
/// among the first `upto` values (`None` when there is no such gap).
fn near_null_gap(values: &[f64], upto: usize) -> Option<(usize, f64)> {
    (1..upto.min(values.len()))
        .rev()
        .find(|&j| values[j] > 0.0 && values[j - 1] < NEAR_NULL_GAP * values[j])
        .map(|j| (j, values[j]))
}

impl EigenSolver {
    /// A solver with nothing analysed yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// The analysed pencil of the last Lanczos solve.
    pub fn pencil(&self) -> Option<&ShiftedPencil> {
        self.pencil.as_ref()
    }

    /// The Cholesky factor of `K − σM` from the last Lanczos solve.
    pub fn factor(&self) -> Option<&ShiftFactor> {
        self.factor.as_ref()
    }

    /// The pencil and its factor, when a Lanczos solve has run and kept its factor.
    pub fn pencil_and_factor(&self) -> Option<(&ShiftedPencil, &ShiftFactor)> {
        Some((self.pencil.as_ref()?, self.factor.as_ref()?))
    }

    /// The shift `σ` (rad²/s²) of the last Lanczos solve, also when its factor was released
    /// under [`EigenConfig::memory_budget`].
    pub fn shift(&self) -> Option<f64> {
        self.shift
    }

    /// The factor of `K − σM` of the last Lanczos solve for `k`, `m` (the held one, or one
    /// computed again at the same shift on the same analysis when it was released), or one
    /// made from nothing for a model this solver has not analysed (the dense path); what is
    /// made here is kept in `own` / `own_factor`.
    pub fn operator<'a>(
        &'a self,
        k: &SparseSym,
        m: &SparseSym,
        par: Par,
        own: &'a mut Option<ShiftedPencil>,
        own_factor: &'a mut Option<ShiftFactor>,
    ) -> Result<(&'a ShiftedPencil, &'a ShiftFactor)> {
        match (&self.pencil, &self.factor, self.shift) {
            (Some(p), Some(f), _) if p.n() == k.n() => Ok((p, f)),
            (Some(p), None, Some(sigma)) if p.n() == k.n() => {
                let f = p.cholesky(sigma)?.map_err(|step| Error::Numerical {
                    what: "factor of K − σM (released by the eigen solve's memory budget)".into(),
                    detail: format!("no longer factors at σ = {sigma:e} (pivot {step})"),
                })?;
                Ok((p, own_factor.insert(f)))
            }
            _ => {
                let mut p = ShiftedPencil::new(k, m)?;
                p.set_par(par);
                let f = factor_below_spectrum(&p, k, m, None)?;
                let p = own.insert(p);
                Ok((p, own_factor.insert(f)))
            }
        }
    }

    /// Solves `K φ = λ M φ` for the modes `cfg.selection` asks for.
    pub fn solve(&mut self, k: &SparseSym, m: &SparseSym, cfg: &EigenConfig) -> Result<Modes> {
        self.solve_with_progress(k, m, cfg, &mut |_| {})
    }

    /// As [`EigenSolver::solve`], calling `progress` after each restart.
    pub fn solve_with_progress(
        &mut self,
        k: &SparseSym,
        m: &SparseSym,
        cfg: &EigenConfig,
        progress: &mut dyn FnMut(&EigenProgress),
    ) -> Result<Modes> {
        check_pencil(k, m)?;
        check_config(cfg)?;
        let n = k.n();
        if n <= cfg.dense_below {
            return solve_dense(k, m, cfg, None);
        }
        let t0 = Instant::now();
        self.factor = None;
        self.shift = None;
        let reused = match self.pencil.as_mut() {
            Some(p) if p.n() == n && p.requested_ordering() == cfg.ordering => {
                p.set_values(k, m)?
            }
            _ => {
                // Free the old analysis before making the new one.
                self.pencil = None;
                self.pencil = Some(ShiftedPencil::with_ordering(k, m, cfg.ordering)?);
                false
            }
        };
        if let Some(p) = self.pencil.as_mut() {
            p.set_par(cfg.par);
        }
        let pencil = self.pencil.as_ref().expect("set above");
        let analysis_seconds = if reused {
            0.0
        } else {
            t0.elapsed().as_secs_f64()
        };

        // A basis the caller sized is reserved once before the factorisations: out of memory
        // is then refused before the (long) factorisation instead of after it, and before
        // its own per-thread workspaces take what is left.
        if let Some(b) = cfg.basis_size {
            drop(basis_zeros_reserved(n, b.min(n), b)?);
        }

        // Shift and operator factor.
        let t1 = Instant::now();
        let mut factor = Some(factor_below_spectrum(pencil, k, m, cfg.shift)?);
        let sigma = factor.as_ref().map_or(0.0, ShiftFactor::shift);
        let factor_nnz = pencil.factor_nnz();
        // Whether K itself is positive definite (then no mode is rigid): known from the shift
        // search, else one more factorisation at σ = 0 for a negative shift given by the user.
        let definite = match cfg.shift {
            None => sigma == 0.0,
            Some(s) if s >= 0.0 => true,
            Some(_) => pencil.cholesky(0.0)?.is_ok(),
        };
        let scale = stiffness_scale(k, m);
        let factor_seconds = t1.elapsed().as_secs_f64();

        let mut check_seconds = 0.0;
        let nev = match cfg.selection {
            ModeSelection::Lowest(c) => c,
            ModeSelection::Below { f_max_hz } => {
                let t = Instant::now();
                let s = (2.0 * std::f64::consts::PI * f_max_hz).powi(2);
                let c = pencil.count_below(s)?;
                check_seconds += t.elapsed().as_secs_f64();
                if c == 0 {
                    return Err(Error::invalid(
                        "mode selection",
                        format!(
                            "no mode lies below {f_max_hz} Hz (Sturm count at that frequency is 0)"
                        ),
                    ));
                }
                c
            }
        };
        if nev > n {
            return Err(Error::invalid(
                "mode selection",
                format!("{nev} modes asked for, but the model has only {n} DOFs"),
            ));
        }

        let mut block = cfg.block_size;
        let mut attempt = 0;
        loop {
            attempt += 1;
            let t2 = Instant::now();
            let basis = cfg
                .basis_size
                .unwrap_or((2 * nev).max(nev + 4 * block))
                .min(n);
            if let Some(b) = cfg.basis_size
                && b < nev + block
                && nev + block <= n
            {
                return Err(Error::invalid(
                    "eigen configuration",
                    format!(
                        "a basis of {b} vectors cannot hold {nev} modes and a block of {block}; \
                         give at least {}",
                        nev + block
                    ),
                ));
            }
            let crowded = basis < nev + block || basis + block > n || 2 * nev > n;
            if crowded && n <= DENSE_FALLBACK_MAX {
                // The basis (and the next block) would fill the space, or most of the spectrum
                // is wanted: Lanczos has no room. Solve densely.
                let mut modes = solve_dense(k, m, cfg, Some(definite))?;
                modes.stats.factor_seconds += factor_seconds;
                return Ok(modes);
            }
            let basis = if crowded {
                basis.min(n.saturating_sub(block))
            } else {
                basis
            };
            if basis < nev + block {
                return Err(Error::invalid(
                    "mode selection",
                    format!(
                        "{nev} modes of a {n}-DOF model leave no room for a Lanczos basis with \
                         blocks of {block}; ask for at most {} modes (models of at most \
                         {DENSE_FALLBACK_MAX} DOFs are solved densely instead)",
                        n.saturating_sub(2 * block)
                    ),
                ));
            }
            let ks = KrylovSchur {
                pencil,
                factor: factor.as_ref().expect("held during the iteration"),
                m,
                nev,
                block,
                basis,
                tol: cfg.tol,
                max_restarts: cfg.max_restarts,
                seed: cfg.seed.wrapping_add(attempt as u64 - 1),
                // `M V` beside `V` when the budget holds the factor and both.
                keep_mv: cfg.memory_budget.is_none_or(|budget| {
                    (factor_nnz + 2 * n * basis) * core::mem::size_of::<f64>() <= budget
                }),
            };
            let ritz = ks.run(progress)?;
            let iteration_seconds = t2.elapsed().as_secs_f64();

            let t3 = Instant::now();
            let Ritz {
                theta,
                converged,
                basis: ritz_basis,
                coefficients,
                restarts,
                applications,
                mut stopped,
            } = ritz;
            let kept = coefficients.ncols();
            let mut values: Vec<f64> = theta[..kept].iter().map(|t| sigma + 1.0 / t).collect();
            // A near-null K (it factored at 0, but with a mode far below the rest): redo at a
            // shift from the spectrum just found.
            // (Unconverged Ritz values are estimates enough for a gap of 1e8.)
            if sigma == 0.0
                && cfg.shift.is_none()
                && let Some((_, next)) = near_null_gap(&values, kept)
            {
                let mut again = cfg.clone();
                again.shift = Some(-NEAR_NULL_SHIFT * next);
                return self.solve_with_progress(k, m, &again, progress);
            }
            // The Ritz vectors are formed in the basis's storage, which is then freed: the Sturm
            // check below holds them (half the basis) beside the factor, not the whole basis.
            let mut vectors = ritz_vectors(ritz_basis, &coefficients, cfg.par);
            // Sturm check: eigenvalues below a point just above the last wanted one, against
            // the converged Ritz values there.
            let mut sturm = None;
            let mut missed = false;
            // Under a memory budget that two factors would pass, the check factorises into the
            // operator factor's storage (refactorised only if the iteration must run again).
            let release = cfg
                .memory_budget
                .is_some_and(|b| 2 * pencil.factor_nnz() * core::mem::size_of::<f64>() > b);
            let mut storage = Vec::new();
            let check = stopped.is_none()
                && match cfg.selection {
                    ModeSelection::Lowest(_) => cfg.sturm_check,
                    ModeSelection::Below { .. } => true,
                };
            if check {
                let last = values[kept - 1];
                let scale = values
                    .iter()
                    .fold(0.0f64, |a, v| a.max(v.abs()))
                    .max(1e-300);
                let mut sc = last + 1e-8 * last.abs().max(scale * 1e-6);
                if release && let Some(f) = factor.take() {
                    storage = f.into_storage();
                }
                let count = loop {
                    match pencil.count_below_in(sc, &mut storage) {
                        Ok(c) => break c,
                        Err(_) => sc += 1e-8 * scale,
                    }
                };
                drop(core::mem::take(&mut storage));
                let found = theta
                    .iter()
                    .zip(&converged)
                    .filter(|(t, c)| **c && sigma + 1.0 / **t < sc)
                    .count();
                sturm = Some((count, sc));
                // More eigenvalues below than converged: a mode was missed (often the partner of
                // a degenerate pair). Fewer: a spurious copy converged. Either way, try again.
                missed = count != found || count != kept;
                if let ModeSelection::Below { f_max_hz } = cfg.selection {
                    // All wanted modes must lie below f_max (the count said so).
                    let lim = (2.0 * std::f64::consts::PI * f_max_hz).powi(2);
                    missed |= values.iter().any(|&v| v >= lim);
                }
            }
            if missed && attempt < 3 && block < n / 4 {
                block *= 2;
                if factor.is_none() {
                    factor = Some(pencil.cholesky(sigma)?.map_err(|step| Error::Numerical {
                        what: "shift-invert Lanczos".into(),
                        detail: format!("K − σM no longer factors at σ = {sigma:e} (pivot {step})"),
                    })?);
                }
                check_seconds += t3.elapsed().as_secs_f64();
                continue;
            }
            if missed {
                let (count, sc) = sturm.expect("set when missed");
                stopped = Some(format!(
                    "the Sturm count finds {count} eigenvalues below {:.6} Hz but {} modes \
                     converged there after {attempt} attempts (block size up to {block}){}",
                    sc.max(0.0).sqrt() / (2.0 * std::f64::consts::PI),
                    kept,
                    if count > kept {
                        "; raise the block size"
                    } else {
                        ": a mode converged twice; try another seed or block size"
                    }
                ));
            }
            let residuals = finish_vectors(k, m, &mut values, &mut vectors, cfg.par);
            check_seconds += t3.elapsed().as_secs_f64();
            let max_residual = residuals.iter().fold(0.0f64, |a, &r| a.max(r));
            let failed = residual_failure(&residuals, &values, sigma, cfg.tol);
            let modes = Modes {
                eigenvalues: values,
                vectors,
                residuals,
                stiffness_scale: scale,
                rigid_threshold: if definite {
                    0.0
                } else {
                    RIGID_RELATIVE * scale
                },
                stats: EigenStats {
                    method: EigenMethod::Lanczos,
                    shift: sigma,
                    block_size: block,
                    basis_size: basis,
                    restarts,
                    operator_applications: applications,
                    factor_nnz,
                    ordering: Some(pencil.ordering()),
                    factor_released: factor.is_none(),
                    reused_analysis: reused,
                    analysis_seconds,
                    factor_seconds,
                    iteration_seconds,
                    check_seconds,
                    sturm,
                    max_residual,
                    status: match (&stopped, &failed) {
                        (Some(_), _) => Status::IterationLimit,
                        (None, Some((status, _))) => *status,
                        (None, None) => Status::Converged,
                    },
                    detail: stopped.or(failed.map(|f| f.1)).unwrap_or_default(),
                },
            };
            self.factor = factor;
            self.shift = Some(sigma);
            return Ok(modes);
        }
    }
}

fn check_config(cfg: &EigenConfig) -> Result<()> {
    match cfg.selection {
        ModeSelection::Lowest(0) => {
            return Err(Error::invalid("mode selection", "asks for 0 modes"));
        }
        ModeSelection::Below { f_max_hz } if !(f_max_hz.is_finite() && f_max_hz > 0.0) => {
            return Err(Error::invalid(
                "mode selection",
                format!("the upper frequency must be positive and finite (got {f_max_hz} Hz)"),
            ));
        }
        _ => {}
    }
    if !(cfg.tol > 0.0 && cfg.tol < 1.0) {
        return Err(Error::invalid(
            "eigen solver tolerance",
            format!("must lie in (0, 1) (got {})", cfg.tol),
        ));
    }
    if cfg.block_size == 0 {
        return Err(Error::invalid(
            "eigen solver block size",
            "must be at least 1",
        ));
    }
    if let Some(s) = cfg.shift
        && !s.is_finite()
    {
        return Err(Error::invalid(
            "eigen solver shift",
            format!("must be finite (got {s})"),
        ));
    }
    Ok(())
}

/// Factor `K − σM` at the requested shift, at 0, or at a small negative shift when `K` is
/// singular; a clear error when `K` is indefinite.
pub(crate) fn factor_below_spectrum(
    pencil: &ShiftedPencil,
    k: &SparseSym,
    m: &SparseSym,
    shift: Option<f64>,
) -> Result<ShiftFactor> {
    if let Some(s) = shift {
        return pencil.cholesky(s)?.map_err(|step| Error::invalid(
            "eigen solver shift",
            format!(
                "K − σM is not positive definite at σ = {s:e} rad²/s² (pivot {step}): the shift \
                 must lie below the lowest eigenvalue"
            ),
        ));
    }
    if let Ok(f) = pencil.cholesky(0.0)? {
        return Ok(f);
    }
    let scale = stiffness_scale(k, m);
    let mut last = 0;
    for e in [1e-8, 1e-6, 1e-4] {
        match pencil.cholesky(-e * scale)? {
            Ok(f) => return Ok(f),
            Err(step) => last = step,
        }
    }
    Err(Error::NotDefinite {
        matrix: "stiffness matrix".into(),
        required: "positive semi-definite".into(),
        detail: format!(
            "K + sM stays indefinite for s up to {:.3e} rad²/s² (pivot {last} of the \
             reordered matrix): K has negative eigenvalues",
            1e-4 * scale
        ),
    })
}

/// The dense path: exact for small models. `definite`: whether `K` is positive definite, when the caller knows (else a Cholesky of `K`
/// decides).
/// The exact modes of a diagonal pencil with positive masses (a test-based modal model, or a
/// lumped model of uncoupled DOFs): `λ_i = K_ii / M_ii`, `φ_i = e_i / √M_ii`, ascending with
/// ties in DOF order, so that equal frequencies keep their own shapes instead of any
/// rotation of them. `None` when either matrix has an off-diagonal entry.
fn diagonal_eigen(k: &SparseSym, m: &SparseSym) -> Option<nlsim_kernel::linalg::DenseEigen> {
    let n = k.n();
    let diag = |a: &SparseSym| -> Option<Vec<f64>> {
        let mut d = vec![0.0; n];
        for j in 0..n {
            let (rows, vals) = a.col(j);
            for (&i, &v) in rows.iter().zip(vals) {
                if i != j {
                    if v != 0.0 {
                        return None;
                    }
                } else {
                    d[j] = v;
                }
            }
        }
        Some(d)
    };
    let (kd, md) = (diag(k)?, diag(m)?);
    if md.iter().any(|&x| x <= 0.0) {
        return None;
    }
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| (kd[a] / md[a]).total_cmp(&(kd[b] / md[b])));
    Some(nlsim_kernel::linalg::DenseEigen {
        values: order.iter().map(|&i| kd[i] / md[i]).collect(),
        vectors: Mat::from_fn(n, n, |r, c| {
            if r == order[c] {
                1.0 / md[r].sqrt()
            } else {
                0.0
            }
        }),
    })
}

fn solve_dense(
    k: &SparseSym,
    m: &SparseSym,
    cfg: &EigenConfig,
    definite: Option<bool>,
) -> Result<Modes> {
    let t = Instant::now();
    let (kd, md) = (k.to_dense(), m.to_dense());
    let n = k.n();
    let exact = diagonal_eigen(k, m);
    let diagonal = exact.is_some();
    let mut d = match exact {
        Some(d) => d,
        None => nlsim_kernel::linalg::dense_generalized_eigen_low(kd.as_ref(), md.as_ref())?,
    };
    let wanted = match cfg.selection {
        ModeSelection::Lowest(c) => c.min(n),
        ModeSelection::Below { .. } => n,
    };
    // A near-null K inverted at 0 (as `dense_generalized_eigen_low` does when K factors):
    // redo at a shift from the spectrum, as the sparse path does.
    let mut sigma = 0.0;
    if let Some((_, next)) = near_null_gap(&d.values, wanted + 1).filter(|_| !diagonal) {
        let s = -NEAR_NULL_SHIFT * next;
        let ks = &kd - &md * faer::Scale(s);
        if ks.llt(faer::Side::Lower).is_ok() {
            d = nlsim_kernel::linalg::dense_generalized_eigen_low(ks.as_ref(), md.as_ref())?;
            for v in &mut d.values {
                *v += s;
            }
            sigma = s;
        }
    }
    let count = match cfg.selection {
        ModeSelection::Lowest(c) => {
            if c > n {
                return Err(Error::invalid(
                    "mode selection",
                    format!("{c} modes asked for, but the model has only {n} DOFs"),
                ));
            }
            c
        }
        ModeSelection::Below { f_max_hz } => {
            let lim = (2.0 * std::f64::consts::PI * f_max_hz).powi(2);
            let c = d.values.iter().filter(|&&v| v < lim).count();
            if c == 0 {
                return Err(Error::invalid(
                    "mode selection",
                    format!("no mode lies below {f_max_hz} Hz"),
                ));
            }
            c
        }
    };
    // A degenerate cluster is not split at the cut-off.
    let mut count = count;
    if let ModeSelection::Lowest(_) = cfg.selection {
        while count < n && same_cluster(d.values[count], d.values[count - 1]) {
            count += 1;
        }
    }
    let mut values = d.values[..count].to_vec();
    let mut vectors = d.vectors.subcols(0, count).to_owned();
    let iteration_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let residuals = finish_vectors(k, m, &mut values, &mut vectors, cfg.par);
    let max_residual = residuals.iter().fold(0.0f64, |a, &r| a.max(r));
    let failed = residual_failure(&residuals, &values, sigma, cfg.tol);
    let scale = stiffness_scale(k, m);
    Ok(Modes {
        eigenvalues: values,
        vectors,
        residuals,
        stiffness_scale: scale,
        rigid_threshold: if definite.unwrap_or_else(|| k.cholesky().is_ok()) {
            0.0
        } else {
            RIGID_RELATIVE * scale
        },
        stats: EigenStats {
            method: EigenMethod::Dense,
            shift: sigma,
            block_size: 0,
            basis_size: n,
            restarts: 0,
            operator_applications: 0,
            factor_nnz: n * (n + 1) / 2,
            ordering: None,
            factor_released: false,
            reused_analysis: false,
            analysis_seconds: 0.0,
            factor_seconds: 0.0,
            iteration_seconds,
            check_seconds: t.elapsed().as_secs_f64(),
            sturm: None,
            max_residual,
            status: failed.as_ref().map_or(Status::Converged, |f| f.0),
            detail: failed.map(|f| f.1).unwrap_or_default(),
        },
    })
}

/// One run of the thick-restart block Lanczos iteration.
struct KrylovSchur<'a> {
    pencil: &'a ShiftedPencil,
    factor: &'a ShiftFactor,
    m: &'a SparseSym,
    nev: usize,
    block: usize,
    basis: usize,
    tol: f64,
    max_restarts: usize,
    seed: u64,
    /// Whether `M V` is stored beside the basis (two products with `M` per block instead of
    /// four), which the memory budget decides.
    keep_mv: bool,
}

/// Ritz pairs of the final basis, largest `θ` first.
struct Ritz {
    theta: Vec<f64>,
    converged: Vec<bool>,
    /// The final basis `V` (its first columns) and the coefficients `Y` of the kept Ritz vectors
    /// in it (the first `nev`, and those of converged Ritz values in the cluster of the last
    /// wanted one): the vectors are `V Y`, formed in `V`'s storage by [`ritz_vectors`].
    basis: Mat<f64>,
    coefficients: Mat<f64>,
    restarts: usize,
    applications: usize,
    /// Why the iteration stopped before every wanted pair converged (the restart limit).
    stopped: Option<String>,
}

/// The kept Ritz vectors `V Y` ([`Ritz`]'s basis and coefficients), formed in the basis's storage.
fn ritz_vectors(mut basis: Mat<f64>, coefficients: &Mat<f64>, par: Par) -> Mat<f64> {
    rotate_in_place(basis.as_mut(), coefficients.as_ref(), par);
    basis.subcols(0, coefficients.ncols()).to_owned()
}

/// A zero `rows × cols` matrix of the Lanczos iteration (`basis` vectors): out of memory is an
/// error naming the basis size, not an abort (a `--basis` near the model's order asks for an
/// `n × n` basis).
fn basis_zeros(rows: usize, cols: usize, basis: usize) -> Result<Mat<f64>> {
    let mut a = basis_zeros_reserved(rows, cols, basis)?;
    a.resize_with(rows, cols, |_, _| 0.0);
    Ok(a)
}

/// An empty matrix with room for `rows × cols` (nothing written, so no page is touched); the
/// error of [`basis_zeros`] when the room cannot be had.
fn basis_zeros_reserved(rows: usize, cols: usize, basis: usize) -> Result<Mat<f64>> {
    let mut a = Mat::<f64>::new();
    a.try_reserve(rows, cols).map_err(|_| Error::Numerical {
        what: "shift-invert Lanczos".into(),
        detail: format!(
            "out of memory allocating a {rows} × {cols} matrix ({:.1} GB) for a basis of {basis} \
             vectors: give a smaller basis (`--basis`, or `basis` in a jobs file)",
            (rows as f64) * (cols as f64) * 8e-9
        ),
    })?;
    Ok(a)
}

/// `V[:, ..keep] ← V[:, ..j] Y` for `Y` of `j × keep` (`keep ≤ j`), a block of rows at a time:
/// the basis is rotated without a second basis-sized matrix (0.7 GB at 10⁶ DOFs). Each row
/// block's product is the same whatever the thread count.
fn rotate_in_place(mut v: MatMut<'_, f64>, y: MatRef<'_, f64>, par: Par) {
    const ROWS: usize = 2048;
    let (n, j, keep) = (v.nrows(), y.nrows(), y.ncols());
    let mut tmp = Mat::<f64>::zeros(ROWS.min(n), keep);
    let mut r0 = 0;
    while r0 < n {
        let rows = ROWS.min(n - r0);
        let mut t = tmp.as_mut().subrows_mut(0, rows);
        matmul(
            t.as_mut(),
            Accum::Replace,
            v.as_ref().submatrix(r0, 0, rows, j),
            y,
            1.0,
            par,
        );
        v.as_mut()
            .submatrix_mut(r0, 0, rows, keep)
            .copy_from(t.as_ref());
        r0 += rows;
    }
}

impl KrylovSchur<'_> {
    fn solve(&self, mut y: Mat<f64>) -> Mat<f64> {
        self.pencil.solve_in_place(self.factor, y.as_mut());
        y
    }

    /// `x ← x − V (Vᵀ M x)` twice (`mx` holds `M x` on entry and on exit); returns the
    /// coefficients `Vᵀ M x`. With `mv` (`M V`) the product is updated alike; without it (a
    /// memory budget that leaves no room for a second basis-sized matrix) `M x` is recomputed
    /// after each pass.
    fn orth_against(
        &self,
        v: MatRef<'_, f64>,
        mv: Option<MatRef<'_, f64>>,
        mut x: MatMut<'_, f64>,
        mx: &mut Mat<f64>,
        par: Par,
    ) -> Mat<f64> {
        let mut coef = Mat::<f64>::zeros(v.ncols(), x.ncols());
        if v.ncols() == 0 {
            return coef;
        }
        for _ in 0..2 {
            // With `M V`, the coefficients come from `x` itself: the updated `M x` carries the
            // cancellation of the pass, `(M V)ᵀ x` does not.
            let c = match mv {
                Some(mv) => mv.transpose() * x.as_ref(),
                None => v.transpose() * mx.as_ref(),
            };
            matmul(x.as_mut(), Accum::Add, v, c.as_ref(), -1.0, par);
            match mv {
                Some(mv) => matmul(mx.as_mut(), Accum::Add, mv, c.as_ref(), -1.0, par),
                None => *mx = sparse_times(self.m, x.as_ref(), par),
            }
            coef += &c;
        }
        coef
    }

    /// `‖x_c‖_M` of every column from `x` and `M x`.
    fn block_norms(x: MatRef<'_, f64>, mx: MatRef<'_, f64>) -> Result<Vec<f64>> {
        (0..x.ncols())
            .map(|c| {
                let s: f64 = (0..x.nrows()).map(|i| x[(i, c)] * mx[(i, c)]).sum();
                if s < 0.0 {
                    Err(Error::NotDefinite {
                        matrix: "mass matrix".into(),
                        required: "positive definite".into(),
                        detail: format!("a Lanczos vector has xᵀMx = {s:e} < 0"),
                    })
                } else {
                    Ok(s.sqrt())
                }
            })
            .collect()
    }

    /// M-orthonormalises the columns of `x` (already orthogonal to `V`) among themselves by
    /// Cholesky QR, twice, in the `M` inner product: `G = Xᵀ M X = L Lᵀ`, `X ← X L⁻ᵀ` (and
    /// `M X` alike). Returns `R` (upper triangular) with `x_in = x_out R`. When the block is
    /// close to rank deficient (a column keeps less than 10⁻⁶ of its norm) it falls back to
    /// column-by-column Gram–Schmidt with deflation, and recomputes `M X`.
    #[allow(clippy::too_many_arguments)]
    fn orthonormalize(
        &self,
        v: MatRef<'_, f64>,
        mv: Option<MatRef<'_, f64>>,
        x: &mut Mat<f64>,
        mx: &mut Mat<f64>,
        norms_in: &[f64],
        rng: &mut SplitMix,
        par: Par,
    ) -> Result<Mat<f64>> {
        let b = x.ncols();
        let x0 = x.clone();
        let mut r_total = Mat::<f64>::identity(b, b);
        let mut ok = true;
        for pass in 0..2 {
            let g = x.transpose() * &*mx;
            let gs = Mat::from_fn(b, b, |i, j| 0.5 * (g[(i, j)] + g[(j, i)]));
            let Ok(llt) = gs.llt(faer::Side::Lower) else {
                ok = false;
                break;
            };
            let l = llt.L();
            if pass == 0 && (0..b).any(|c| l[(c, c)].is_nan() || l[(c, c)] <= 1e-6 * norms_in[c]) {
                ok = false;
                break;
            }
            // X ← X L⁻ᵀ  (solve L Yᵀ = Xᵀ), and M X alike.
            for y in [&mut *x, &mut *mx] {
                let mut yt = y.transpose().to_owned();
                faer::linalg::triangular_solve::solve_lower_triangular_in_place(
                    l,
                    yt.as_mut(),
                    par,
                );
                y.copy_from(yt.transpose());
            }
            let lt = Mat::from_fn(b, b, |i, j| if j >= i { l[(j, i)] } else { 0.0 });
            r_total = &lt * &r_total;
        }
        if ok {
            return Ok(r_total);
        }
        x.copy_from(&x0);
        let r = self.orthonormalize_columns(v, mv, x, norms_in, rng, par)?;
        *mx = sparse_times(self.m, x.as_ref(), par);
        Ok(r)
    }

    fn m_norm(&self, x: MatRef<'_, f64>, par: Par) -> Result<f64> {
        let mx = sparse_times(self.m, x, par);
        Ok(Self::block_norms(x, mx.as_ref())?[0])
    }

    /// Column-by-column M-Gram–Schmidt with deflation: a numerically dependent column is
    /// replaced by a fresh random direction orthogonal to everything, with a zero diagonal in `R`.
    fn orthonormalize_columns(
        &self,
        v: MatRef<'_, f64>,
        mv: Option<MatRef<'_, f64>>,
        x: &mut Mat<f64>,
        norms_in: &[f64],
        rng: &mut SplitMix,
        par: Par,
    ) -> Result<Mat<f64>> {
        let b = x.ncols();
        let n = x.nrows();
        let mut r = Mat::<f64>::zeros(b, b);
        for c in 0..b {
            let mut fresh = false;
            loop {
                for _ in 0..2 {
                    if c > 0 {
                        let prev = x.subcols(0, c).to_owned();
                        let mut xc = x.subcols_mut(c, 1);
                        let mx = sparse_times(self.m, xc.as_ref(), par);
                        let s = prev.transpose() * &mx;
                        matmul(
                            xc.as_mut(),
                            Accum::Add,
                            prev.as_ref(),
                            s.as_ref(),
                            -1.0,
                            par,
                        );
                        if !fresh {
                            for d in 0..c {
                                r[(d, c)] += s[(d, 0)];
                            }
                        }
                    }
                }
                let nrm = self.m_norm(x.subcols(c, 1), par)?;
                let reference = if fresh { 1.0 } else { norms_in[c] };
                if nrm > 1e-10 * reference && nrm > 0.0 {
                    if !fresh {
                        r[(c, c)] = nrm;
                    }
                    for i in 0..n {
                        x[(i, c)] /= nrm;
                    }
                    break;
                }
                // Deflation: the block has lost rank (an invariant subspace was found). A fresh
                // random vector that is still (nearly) in the span means the basis fills the
                // space: no further direction exists, and drawing again would never end.
                if fresh && nrm <= 1e-10 {
                    return Err(Error::Numerical {
                        what: "shift-invert Lanczos".into(),
                        detail: "cannot extend the basis: the Krylov space is exhausted".into(),
                    });
                }
                fresh = true;
                for i in 0..n {
                    x[(i, c)] = rng.next();
                }
                let mut xc = x.subcols_mut(c, 1);
                let mut mxc = sparse_times(self.m, xc.as_ref(), par);
                let _ = self.orth_against(v, mv, xc.as_mut(), &mut mxc, par);
                let nrm0 = self.m_norm(xc.as_ref(), par)?;
                for i in 0..n {
                    xc[(i, 0)] /= nrm0.max(f64::MIN_POSITIVE);
                }
            }
        }
        Ok(r)
    }

    fn run(&self, progress: &mut dyn FnMut(&EigenProgress)) -> Result<Ritz> {
        let par = self.pencil.par();
        let (n, b, nv, nev) = (self.pencil.n(), self.block, self.basis, self.nev);
        let mut rng = SplitMix::new(self.seed);
        // The basis V, the projection H = Vᵀ M Op V and the coupling B of V to the next block W:
        // Op V = V H + W B.
        let mut v = basis_zeros(n, nv, nv)?;
        let mut mv = if self.keep_mv {
            Some(basis_zeros(n, nv, nv)?)
        } else {
            None
        };
        let mut h = basis_zeros(nv, nv, nv)?;
        let mut bc = Mat::<f64>::zeros(b, nv);
        let mut applications = 0;

        // Starting block: Op applied to a random block (purges directions Op cannot reach).
        let x0 = Mat::from_fn(n, b, |_, _| rng.next());
        let mut w = self.solve(sparse_times(self.m, x0.as_ref(), par));
        applications += b;
        let mut mw = sparse_times(self.m, w.as_ref(), par);
        let norms = Self::block_norms(w.as_ref(), mw.as_ref())?;
        let empty = v.subcols(0, 0);
        let no_mv = mv.as_ref().map(|m| m.subcols(0, 0));
        self.orthonormalize(empty, no_mv, &mut w, &mut mw, &norms, &mut rng, par)?;
        mw = sparse_times(self.m, w.as_ref(), par);
        let mut j = 0;
        let mut restarts = 0;
        loop {
            // Expand to the full basis.
            while j + b <= nv {
                v.subcols_mut(j, b).copy_from(&w);
                if let Some(mv) = mv.as_mut() {
                    mv.subcols_mut(j, b).copy_from(&mw);
                }
                // Rows of H for the new block against the old columns: the old coupling.
                for r in 0..b {
                    for c in 0..j {
                        h[(j + r, c)] = bc[(r, c)];
                    }
                }
                let mut x = self.solve(mw.clone());
                applications += b;
                let mut mx = sparse_times(self.m, x.as_ref(), par);
                let norms = Self::block_norms(x.as_ref(), mx.as_ref())?;
                let mvj = mv.as_ref().map(|m| m.subcols(0, j + b));
                let coef = self.orth_against(v.subcols(0, j + b), mvj, x.as_mut(), &mut mx, par);
                h.submatrix_mut(0, j, j + b, b).copy_from(&coef);
                let r = self.orthonormalize(
                    v.subcols(0, j + b),
                    mvj,
                    &mut x,
                    &mut mx,
                    &norms,
                    &mut rng,
                    par,
                )?;
                bc.fill(0.0);
                bc.submatrix_mut(0, j, b, b).copy_from(&r);
                // `M W` enters every later orthogonalisation: compute it afresh rather than keep
                // the updated `M X`, whose round-off grows with the condition of the block's
                // Cholesky factor.
                drop(mx);
                mw = sparse_times(self.m, x.as_ref(), par);
                w = x;
                j += b;
            }
            // Rayleigh–Ritz on the symmetric projection.
            let hs = Mat::from_fn(j, j, |a, c| 0.5 * (h[(a, c)] + h[(c, a)]));
            let (s, u) = nlsim_kernel::linalg::symmetric_eigen(hs.as_ref())?;
            // Largest θ first.
            let theta: Vec<f64> = (0..j).rev().map(|i| s[i]).collect();
            let y = Mat::from_fn(j, j, |a, c| u[(a, j - 1 - c)]);
            let resid = bc.subcols(0, j) * &y;
            let converged: Vec<bool> = (0..j)
                .map(|c| resid.col(c).norm_l2() <= self.tol * theta[c].abs())
                .collect();
            let nconv = converged[..nev].iter().filter(|c| **c).count();
            progress(&EigenProgress {
                restart: restarts,
                converged: nconv,
                wanted: nev,
            });
            if nconv == nev || restarts >= self.max_restarts {
                let stopped = (nconv < nev).then(|| {
                    let worst = (0..nev)
                        .map(|c| resid.col(c).norm_l2() / theta[c].abs())
                        .fold(0.0f64, f64::max);
                    format!(
                        "{nconv} of {nev} modes converged after {restarts} restarts (worst \
                         relative Ritz residual {worst:.2e} > tolerance {:.1e}); raise the basis \
                         size or the restart limit (`--basis`, `--restarts` of `nlsim modes`, `simulate`, \
                         `frf` and `nnm`)",
                        self.tol
                    )
                });
                // A degenerate cluster is not split at the cut-off: converged Ritz values equal
                // to the last wanted one join it.
                let mut keep = nev;
                if nconv == nev {
                    while keep < j
                        && converged[keep]
                        && same_cluster(1.0 / theta[keep], 1.0 / theta[nev - 1])
                    {
                        keep += 1;
                    }
                }
                v.truncate(n, j);
                return Ok(Ritz {
                    theta,
                    converged,
                    basis: v,
                    coefficients: y.subcols(0, keep).to_owned(),
                    restarts,
                    applications,
                    stopped,
                });
            }
            // Thick restart: keep the best `keep` Ritz vectors.
            let keep = ((nev + j) / 2).max(nev).min(j - b);
            rotate_in_place(v.subcols_mut(0, j), y.subcols(0, keep), par);
            if let Some(mv) = mv.as_mut() {
                rotate_in_place(mv.subcols_mut(0, j), y.subcols(0, keep), par);
            }
            h.fill(0.0);
            for c in 0..keep {
                h[(c, c)] = theta[c];
            }
            let bk = bc.subcols(0, j) * y.subcols(0, keep);
            bc.fill(0.0);
            bc.subcols_mut(0, keep).copy_from(&bk);
            j = keep;
            restarts += 1;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residual_check_scales_with_each_modes_distance_from_the_shift() {
        let values = [1.0, 4.0, 1e6];
        assert_eq!(
            residual_failure(&[1e-14, 3e-13, 1e-9], &values, 0.0, 1e-10),
            None
        );
        // Mode 2 (λ/λ₁ = 4) may have 4e-8, not 2e-6.
        let (status, msg) = residual_failure(&[1e-14, 2e-6, 1e-4], &values, -0.5, 1e-10).unwrap();
        assert_eq!(status, Status::Singular);
        assert!(
            msg.starts_with("mode 2 has backward error 2.00e-6 > 3.0e-8"),
            "{msg}"
        );
        assert!(msg.contains("σ = -5e-1"), "{msg}");
        // The highest mode, 10⁶ times farther from the shift, passes with 1e-4 alone.
        assert_eq!(
            residual_failure(&[1e-14, 1e-9, 1e-4], &values, 0.0, 1e-10),
            None
        );
        // A looser tolerance moves the limit with it.
        assert_eq!(residual_failure(&[2e-6], &[1.0], 0.0, 1e-6), None);
        let (status, msg) = residual_failure(&[1e-14, f64::NAN], &values[..2], 0.0, 1e-10).unwrap();
        assert_eq!(status, Status::NonFinite);
        assert!(msg.starts_with("mode 2 has a non-finite"), "{msg}");
    }
}
