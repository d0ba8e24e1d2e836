//! The shifted pencil `K − σM` on a fixed sparsity pattern: one symbolic analysis (fill-reducing
//! ordering, elimination tree, supernodes), then as many numeric factorisations as shifts or
//! parameter values need.
//!
//! Two numeric factorisations share the symbolic analysis:
//! - `L Lᵀ` (sparse Cholesky) when `K − σM` is positive definite, the operator of shift-invert
//!   iterations below the spectrum and of the static solves of residual flexibility;
//! - `L D Lᵀ` without pivoting, only to count negative pivots: by Sylvester's law of inertia that
//!   count is the number of eigenvalues of `K φ = λ M φ` below `σ` (the Sturm sequence check).

use faer::dyn_stack::{MemBuffer, MemStack};
use faer::perm::PermRef;
use faer::sparse::linalg::cholesky::{
    CholeskySymbolicParams, LltRef, SymbolicCholesky, SymbolicCholeskyRaw, SymmetricOrdering,
    factorize_symbolic_cholesky, simplicial, supernodal,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nlsim_kernel::{Error, Result, SparseSym};

use crate::ordering::{Ordering, nested_dissection};

/// `K − σM` on the union of the patterns of `K` and `M`, with its symbolic Cholesky analysis.
///
/// The pencil holds no copy of the matrices: it refers to the storage of `K` and `M` (a
/// [`SparseSym`] clone shares it) and forms `K − σM` afresh for each factorisation, pattern and
/// values, directly in the factor's ordering and triangle, where faer would otherwise make a
/// permuted copy of its own (0.7 GB at 10⁶ DOFs, held only while a factorisation runs).
#[derive(Debug)]
pub struct ShiftedPencil {
    n: usize,
    k: SparseSym,
    m: SparseSym,
    symbolic: SymbolicCholesky<usize>,
    /// The supernodal tree's split for the parallel solve (`None` for a simplicial factor).
    tree: Option<crate::trisolve::Split>,
    ordering: Ordering,
    requested: Ordering,
    predicted: Vec<(Ordering, usize)>,
    analyses: usize,
    par: Par,
}

/// A numeric Cholesky factor `L Lᵀ = K − σM` of a [`ShiftedPencil`].
#[derive(Debug, Clone)]
pub struct ShiftFactor {
    shift: f64,
    values: Vec<f64>,
}

impl ShiftFactor {
    /// The shift `σ` (rad²/s²) this factor was computed at.
    pub fn shift(&self) -> f64 {
        self.shift
    }

    /// Number of stored values of `L`.
    pub fn nnz(&self) -> usize {
        self.values.len()
    }

    /// The factor's storage, for another factorisation of the same pencil to reuse
    /// ([`ShiftedPencil::count_below_in`]).
    pub fn into_storage(self) -> Vec<f64> {
        self.values
    }
}

/// Visits the lower triangle of the union of the patterns of `K` and `M`, column by column and
/// rows increasing, as `f(row, col, K_ij, M_ij)` (zero where a matrix has no entry).
fn for_each_lower(k: &SparseSym, m: &SparseSym, mut f: impl FnMut(usize, usize, f64, f64)) {
    let shared = k.shares_pattern(m);
    for j in 0..k.n() {
        if shared {
            // One pattern: the entries pair up by position.
            let ((kr, kx), (_, mx)) = (k.col(j), m.col(j));
            for p in kr.partition_point(|&i| i < j)..kr.len() {
                f(kr[p], j, kx[p], mx[p]);
            }
        } else {
            for (i, kv, mv) in k.merged_col(m, j, j) {
                f(i, j, kv, mv);
            }
        }
    }
}

/// The lower-triangle union pattern of `K` and `M` (for the symbolic analysis; not kept).
fn union_lower(k: &SparseSym, m: &SparseSym) -> (Vec<usize>, Vec<usize>) {
    // Counted first, then filled: a growing vector would leave freed copies behind (0.5 GB at
    // 10⁶ DOFs) that the allocator does not hand back at once.
    let n = k.n();
    let mut col_ptr = vec![0usize; n + 1];
    for_each_lower(k, m, |_, j, _, _| col_ptr[j + 1] += 1);
    for j in 0..n {
        col_ptr[j + 1] += col_ptr[j];
    }
    let mut row_idx = vec![0usize; col_ptr[n]];
    let mut next = 0;
    for_each_lower(k, m, |i, _, _, _| {
        row_idx[next] = i;
        next += 1;
    });
    (col_ptr, row_idx)
}

/// Visits the entries of `K − σM`'s lower union pattern (as [`for_each_lower`]) as
/// `f(col, row, K_ij, M_ij)` at their place in the permuted triangle the numeric kernel reads
/// (`P A Pᵀ`: lower for the supernodal kernel, upper for the simplicial one). The order of the
/// visits fixes where each entry is stored.
fn scatter(
    k: &SparseSym,
    m: &SparseSym,
    symbolic: &SymbolicCholesky<usize>,
    mut f: impl FnMut(usize, usize, f64, f64),
) {
    let inv = symbolic.perm().map(|p| p.arrays().1);
    let lower = matches!(symbolic.raw(), SymbolicCholeskyRaw::Supernodal(_));
    for_each_lower(k, m, |i, j, kv, mv| {
        let (pi, pj) = inv.map_or((i, j), |inv| (inv[i], inv[j]));
        let (lo, hi) = if pi < pj { (pi, pj) } else { (pj, pi) };
        if lower {
            f(lo, hi, kv, mv)
        } else {
            f(hi, lo, kv, mv)
        }
    });
}

/// `P (K − σM) Pᵀ` in the triangle the numeric kernel reads ([`ShiftedPencil::shifted`]).
struct Shifted {
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    vals: Vec<f64>,
}

impl Shifted {
    fn matrix(&self, n: usize) -> SparseColMatRef<'_, usize, f64> {
        let pattern =
            SymbolicSparseColMatRef::new_unsorted_checked(n, n, &self.col_ptr, None, &self.row_idx);
        SparseColMatRef::new(pattern, &self.vals)
    }
}

fn faer_error(what: &str, e: impl core::fmt::Debug) -> Error {
    Error::Numerical {
        what: what.into(),
        detail: format!("{e:?}"),
    }
}

/// A symbolic analysis, the ordering it used, and the factor size of each ordering tried.
type Analysis = (SymbolicCholesky<usize>, Ordering, Vec<(Ordering, usize)>);

/// Symbolic analysis of the pattern under `ordering`: for [`Ordering::Auto`] both AMD and nested
/// dissection are analysed and the one with the fewer factor values kept (AMD on a tie, or
/// when the graph is too large for METIS's 32-bit indices).
fn analyse(
    n: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
    ordering: Ordering,
    params: CholeskySymbolicParams<'_>,
) -> Result<Analysis> {
    let pattern = SymbolicSparseColMatRef::new_checked(n, n, col_ptr, None, row_idx);
    let amd = |params| {
        factorize_symbolic_cholesky(pattern, Side::Lower, SymmetricOrdering::Amd, params)
            .map_err(|e| faer_error("symbolic Cholesky analysis of K − σM (AMD ordering)", e))
    };
    let nd = |params| -> Result<Option<SymbolicCholesky<usize>>> {
        let Some((fwd, inv)) = nested_dissection(n, col_ptr, row_idx)? else {
            return Ok(None);
        };
        let perm = PermRef::new_checked(&fwd, &inv, n);
        factorize_symbolic_cholesky(
            pattern,
            Side::Lower,
            SymmetricOrdering::Custom(perm),
            params,
        )
        .map(Some)
        .map_err(|e| {
            faer_error(
                "symbolic Cholesky analysis of K − σM (nested-dissection ordering)",
                e,
            )
        })
    };
    match ordering {
        Ordering::Amd => {
            let s = amd(params)?;
            let p = vec![(Ordering::Amd, s.len_val())];
            Ok((s, Ordering::Amd, p))
        }
        Ordering::NestedDissection => match nd(params)? {
            Some(s) => {
                let p = vec![(Ordering::NestedDissection, s.len_val())];
                Ok((s, Ordering::NestedDissection, p))
            }
            None => Err(Error::invalid(
                "fill-reducing ordering",
                format!(
                    "nested dissection takes graphs of at most 2³¹ − 1 edge ends; this pencil \
                     of {n} DOFs has more: use the AMD ordering"
                ),
            )),
        },
        Ordering::Auto => {
            // Small patterns: AMD is near optimal and METIS's setup dominates.
            if n < AUTO_ND_MIN {
                let a = amd(params)?;
                let predicted = vec![(Ordering::Amd, a.len_val())];
                return Ok((a, Ordering::Amd, predicted));
            }
            // Both analyses at once (each is sequential); the choice depends on their results
            // only, not on how many threads ran them.
            let (a, d) = rayon::join(|| amd(params), || nd(params));
            let a = a?;
            let mut predicted = vec![(Ordering::Amd, a.len_val())];
            // AMD is a valid ordering: when dissection cannot be had (a graph beyond METIS's
            // indices, or METIS out of memory), the run goes on with it.
            match d {
                Ok(Some(d)) => {
                    predicted.push((Ordering::NestedDissection, d.len_val()));
                    if d.len_val() < a.len_val() {
                        Ok((d, Ordering::NestedDissection, predicted))
                    } else {
                        Ok((a, Ordering::Amd, predicted))
                    }
                }
                Ok(None) | Err(_) => Ok((a, Ordering::Amd, predicted)),
            }
        }
    }
}

/// Below this order [`Ordering::Auto`] keeps AMD without trying nested dissection.
const AUTO_ND_MIN: usize = 2000;

impl ShiftedPencil {
    /// The parallelism of its factorisations and solves (default `Par::rayon(0)`: the
    /// current rayon pool).
    pub fn set_par(&mut self, par: Par) {
        self.par = par;
    }

    /// The parallelism in force.
    pub fn par(&self) -> Par {
        self.par
    }

    /// Builds the union pattern of `K` and `M` and runs the symbolic analysis (supernodal
    /// structure) with the ordering of fewer factor values of AMD and nested dissection
    /// ([`Ordering::Auto`]).
    pub fn new(k: &SparseSym, m: &SparseSym) -> Result<Self> {
        Self::with_ordering(k, m, Ordering::Auto)
    }

    /// As [`ShiftedPencil::new`], with the fill-reducing ordering chosen by the caller.
    pub fn with_ordering(k: &SparseSym, m: &SparseSym, ordering: Ordering) -> Result<Self> {
        Self::with_params(k, m, ordering, CholeskySymbolicParams::default())
    }

    /// As [`ShiftedPencil::with_ordering`], with faer's symbolic parameters (tests force the
    /// simplicial or the supernodal kernels with them).
    pub fn with_params(
        k: &SparseSym,
        m: &SparseSym,
        ordering: Ordering,
        params: CholeskySymbolicParams<'_>,
    ) -> Result<Self> {
        if k.n() != m.n() {
            return Err(Error::DimensionMismatch {
                what: "mass matrix order (must equal the stiffness matrix order)".into(),
                expected: k.n(),
                found: m.n(),
            });
        }
        let n = k.n();
        let (symbolic, used, predicted) = {
            let (col_ptr, row_idx) = union_lower(k, m);
            analyse(n, &col_ptr, &row_idx, ordering, params)?
        };
        let tree = match symbolic.raw() {
            SymbolicCholeskyRaw::Supernodal(s) => Some(crate::trisolve::split(s)),
            SymbolicCholeskyRaw::Simplicial(_) => None,
        };
        Ok(ShiftedPencil {
            par: Par::rayon(0),
            n,
            k: k.clone(),
            m: m.clone(),
            symbolic,
            tree,
            ordering: used,
            requested: ordering,
            predicted,
            analyses: 1,
        })
    }

    /// The ordering the symbolic analysis uses ([`Ordering::Amd`] or
    /// [`Ordering::NestedDissection`]; `Auto` is resolved).
    pub fn ordering(&self) -> Ordering {
        self.ordering
    }

    /// The ordering asked for when the pencil was made (`Auto` included).
    pub fn requested_ordering(&self) -> Ordering {
        self.requested
    }

    /// The factor sizes (values of `L`) the analysis predicted for each ordering it tried.
    pub fn predicted_factor_nnz(&self) -> &[(Ordering, usize)] {
        &self.predicted
    }

    /// Replaces the values of `K` and `M` (a parameter study). The symbolic analysis is kept
    /// when the union pattern is unchanged and redone otherwise; returns whether it was kept.
    pub fn set_values(&mut self, k: &SparseSym, m: &SparseSym) -> Result<bool> {
        if k.n() != self.n || m.n() != self.n {
            return Err(Error::DimensionMismatch {
                what: "order of the new K and M (must equal the analysed pencil)".into(),
                expected: self.n,
                found: if k.n() != self.n { k.n() } else { m.n() },
            });
        }
        let same = (k.same_pattern(&self.k) && m.same_pattern(&self.m))
            || union_lower(k, m) == union_lower(&self.k, &self.m);
        if same {
            self.k = k.clone();
            self.m = m.clone();
            Ok(true)
        } else {
            let (analyses, par) = (self.analyses, self.par);
            *self = Self::with_ordering(k, m, self.requested)?;
            self.par = par;
            self.analyses = analyses + 1;
            Ok(false)
        }
    }

    /// Order of the pencil.
    pub fn n(&self) -> usize {
        self.n
    }

    /// How many symbolic analyses this pencil has run (1 unless [`ShiftedPencil::set_values`]
    /// met a new pattern).
    pub fn analyses(&self) -> usize {
        self.analyses
    }

    /// Number of values a numeric factor stores (`nnz(L)`, fill included).
    pub fn factor_nnz(&self) -> usize {
        self.symbolic.len_val()
    }

    /// `P (K − σM) Pᵀ`, the triangle the numeric kernel reads: column pointers, row indices
    /// (unsorted within a column, in [`scatter`]'s order) and values; `what` names the
    /// factorisation in an out-of-memory error.
    fn shifted(&self, sigma: f64, what: &str) -> Result<Shifted> {
        let n = self.n;
        let mut col_ptr = vec![0usize; n + 1];
        scatter(&self.k, &self.m, &self.symbolic, |c, _, _, _| {
            col_ptr[c + 1] += 1
        });
        for c in 0..n {
            col_ptr[c + 1] += col_ptr[c];
        }
        let nnz = col_ptr[n];
        let (mut row_idx, mut vals) = (Vec::new(), Vec::new());
        row_idx
            .try_reserve_exact(nnz)
            .and_then(|_| vals.try_reserve_exact(nnz))
            .map_err(|_| Error::Numerical {
                what: what.into(),
                detail: format!(
                    "out of memory allocating {nnz} entries of K − σM ({:.2} GB)",
                    nnz as f64 * 16e-9
                ),
            })?;
        row_idx.resize(nnz, 0);
        vals.resize(nnz, 0.0);
        let mut cursor = col_ptr[..n].to_vec();
        scatter(&self.k, &self.m, &self.symbolic, |c, r, kv, mv| {
            row_idx[cursor[c]] = r;
            vals[cursor[c]] = kv - sigma * mv;
            cursor[c] += 1;
        });
        Ok(Shifted {
            col_ptr,
            row_idx,
            vals,
        })
    }

    /// Cholesky factor of `K − σM`; `Err(step)` when a pivot is not positive (the pencil is not
    /// positive definite at this shift), with the failing elimination step.
    pub fn cholesky(&self, sigma: f64) -> Result<core::result::Result<ShiftFactor, usize>> {
        let shifted = self.shifted(sigma, "sparse Cholesky of K − σM")?;
        let a = shifted.matrix(self.n);
        let par = self.par;
        let mut values = Vec::new();
        values
            .try_reserve_exact(self.symbolic.len_val())
            .map_err(|_| Error::Numerical {
                what: "sparse Cholesky of K − σM".into(),
                detail: format!(
                    "out of memory allocating {} factor values ({:.1} GB)",
                    self.symbolic.len_val(),
                    self.symbolic.len_val() as f64 * 8e-9
                ),
            })?;
        values.resize(self.symbolic.len_val(), 0.0);
        // The numeric kernels read the permuted triangle directly (faer's own entry point
        // would first copy A into that form).
        let res = match self.symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => {
                let mut mem =
                    MemBuffer::new(simplicial::factorize_simplicial_numeric_llt_scratch::<
                        usize,
                        f64,
                    >(self.n));
                simplicial::factorize_simplicial_numeric_llt(
                    &mut values,
                    a,
                    Default::default(),
                    s,
                    MemStack::new(&mut mem),
                )
            }
            SymbolicCholeskyRaw::Supernodal(s) => {
                let mut mem =
                    MemBuffer::new(supernodal::factorize_supernodal_numeric_llt_scratch::<
                        usize,
                        f64,
                    >(s, par, Default::default()));
                supernodal::factorize_supernodal_numeric_llt(
                    &mut values,
                    a,
                    Default::default(),
                    s,
                    par,
                    MemStack::new(&mut mem),
                    Default::default(),
                )
            }
        };
        match res {
            Ok(_) => Ok(Ok(ShiftFactor {
                shift: sigma,
                values,
            })),
            Err(faer::linalg::cholesky::llt::factor::LltError::NonPositivePivot { index }) => {
                Ok(Err(index))
            }
        }
    }

    /// Solves `(K − σM) X = B` in place for all columns of `rhs`. With a supernodal factor the
    /// independent subtrees of the elimination tree run in parallel under the pencil's `Par`,
    /// and the result is the same for any thread count.
    pub fn solve_in_place(&self, factor: &ShiftFactor, rhs: MatMut<'_, f64>) {
        let par = self.par;
        if let (SymbolicCholeskyRaw::Supernodal(s), Some(tree)) =
            (self.symbolic.raw(), self.tree.as_ref())
        {
            let fwd = self.symbolic.perm().map(|p| p.arrays().0);
            crate::trisolve::solve_llt(s, tree, fwd, &factor.values, rhs, par);
            return;
        }
        let llt = LltRef::<'_, usize, f64>::new(&self.symbolic, &factor.values);
        let mut mem = MemBuffer::new(
            self.symbolic
                .solve_in_place_scratch::<f64>(rhs.ncols(), par),
        );
        llt.solve_in_place_with_conj(Conj::No, rhs, par, MemStack::new(&mut mem));
    }

    /// Number of eigenvalues of `K φ = λ M φ` strictly below `σ` (rad²/s²), from the signs of
    /// the pivots of `L D Lᵀ = K − σM` (Sylvester's law of inertia). `Err` when a pivot is
    /// exactly zero (σ is an eigenvalue to working precision: move it).
    pub fn count_below(&self, sigma: f64) -> Result<usize> {
        self.count_below_in(sigma, &mut Vec::new())
    }

    /// As [`ShiftedPencil::count_below`], factorising into `storage` (resized to the factor's
    /// length; the storage of a released [`ShiftFactor`] holds it without a new allocation).
    pub fn count_below_in(&self, sigma: f64, storage: &mut Vec<f64>) -> Result<usize> {
        let what = format!("Sturm count at shift {sigma:e} rad²/s²");
        let shifted = self.shifted(sigma, &what)?;
        let a = shifted.matrix(self.n);
        let par = self.par;
        let len = self.symbolic.len_val();
        if storage.len() < len {
            storage
                .try_reserve_exact(len - storage.len())
                .map_err(|_| Error::Numerical {
                    what: format!("Sturm count at shift {sigma:e} rad²/s²"),
                    detail: format!(
                        "out of memory allocating {len} factor values ({:.1} GB)",
                        len as f64 * 8e-9
                    ),
                })?;
        }
        storage.resize(len, 0.0);
        let values = &mut storage[..];
        let res = match self.symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => {
                let mut mem =
                    MemBuffer::new(simplicial::factorize_simplicial_numeric_ldlt_scratch::<
                        usize,
                        f64,
                    >(self.n));
                simplicial::factorize_simplicial_numeric_ldlt(
                    &mut *values,
                    a,
                    Default::default(),
                    s,
                    MemStack::new(&mut mem),
                )
            }
            SymbolicCholeskyRaw::Supernodal(s) => {
                let mut mem =
                    MemBuffer::new(supernodal::factorize_supernodal_numeric_ldlt_scratch::<
                        usize,
                        f64,
                    >(s, par, Default::default()));
                supernodal::factorize_supernodal_numeric_ldlt(
                    &mut *values,
                    a,
                    Default::default(),
                    s,
                    par,
                    MemStack::new(&mut mem),
                    Default::default(),
                )
            }
        };
        res.map_err(|e| Error::Numerical {
            what,
            detail: format!("L D Lᵀ met a zero pivot ({e:?}): the shift is an eigenvalue"),
        })?;
        let mut negative = 0;
        match self.symbolic.raw() {
            SymbolicCholeskyRaw::Simplicial(s) => {
                // Column j of the simplicial factor stores D_jj in its diagonal slot.
                let cp = s.col_ptr();
                let ri = s.row_idx();
                for j in 0..self.n {
                    for p in cp[j]..cp[j + 1] {
                        if ri[p] == j && values[p] < 0.0 {
                            negative += 1;
                        }
                    }
                }
            }
            SymbolicCholeskyRaw::Supernodal(s) => {
                let sn = faer::sparse::linalg::cholesky::supernodal::SupernodalLdltRef::<
                    '_,
                    usize,
                    f64,
                >::new(s, values);
                for k in 0..s.n_supernodes() {
                    let node = sn.supernode(k);
                    let v = node.val();
                    for c in 0..v.ncols() {
                        if v[(c, c)] < 0.0 {
                            negative += 1;
                        }
                    }
                }
            }
        }
        Ok(negative)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::sparse::linalg::SupernodalThreshold;

    /// A 1-D chain of springs with a mass matrix that is not diagonal.
    fn chain(n: usize) -> (SparseSym, SparseSym) {
        let mut kt = Vec::new();
        let mut mt = Vec::new();
        for i in 0..n {
            kt.push((i, i, 2.0 + 0.1 * i as f64));
            mt.push((i, i, 1.0 + 0.01 * i as f64));
            if i + 1 < n {
                kt.push((i + 1, i, -1.0));
                mt.push((i + 1, i, 0.1));
            }
        }
        (
            SparseSym::from_lower_triplets("K", n, &kt).unwrap(),
            SparseSym::from_lower_triplets("M", n, &mt).unwrap(),
        )
    }

    #[test]
    fn sturm_count_matches_dense_eigenvalues_in_both_kernels() {
        let (k, m) = chain(60);
        let dense = nlsim_kernel::linalg::dense_generalized_eigen(
            k.to_dense().as_ref(),
            m.to_dense().as_ref(),
        )
        .unwrap();
        for threshold in [
            SupernodalThreshold::FORCE_SIMPLICIAL,
            SupernodalThreshold::FORCE_SUPERNODAL,
        ] {
            let params = CholeskySymbolicParams {
                supernodal_flop_ratio_threshold: threshold,
                ..Default::default()
            };
            for ordering in [Ordering::Amd, Ordering::NestedDissection] {
                let p = ShiftedPencil::with_params(&k, &m, ordering, params).unwrap();
                assert_eq!(p.ordering(), ordering);
                for w in dense.values.windows(2).step_by(7) {
                    let sigma = 0.5 * (w[0] + w[1]);
                    let expected = dense.values.iter().filter(|&&l| l < sigma).count();
                    assert_eq!(p.count_below(sigma).unwrap(), expected, "σ = {sigma}");
                }
                // Positive definite below the spectrum, not above its first eigenvalue.
                assert!(p.cholesky(0.5 * dense.values[0]).unwrap().is_ok());
                assert!(p.cholesky(1.5 * dense.values[1]).unwrap().is_err());
                // The check in a released factor's storage counts alike.
                let f = p.cholesky(0.5 * dense.values[0]).unwrap().unwrap();
                let mut storage = f.into_storage();
                let sigma = 0.5 * (dense.values[10] + dense.values[11]);
                assert_eq!(p.count_below_in(sigma, &mut storage).unwrap(), 11);
            }
        }
    }

    /// `K` and `M` on different patterns (a lumped mass; a mass with an entry `K` lacks) and on
    /// one shared pattern: factor, solve and Sturm count agree with the dense pencil in both
    /// kernels.
    #[test]
    fn pencils_on_different_or_shared_patterns_match_dense() {
        let (k, m_chain) = chain(50);
        let lumped = SparseSym::diagonal("M", &vec![1.5; 50]).unwrap();
        let extra = SparseSym::from_lower_triplets("M", 50, &[(40, 3, 0.05)]).unwrap();
        let wider = SparseSym::linear_combination("M", 1.0, &m_chain, 1.0, &extra).unwrap();
        let mut shared = m_chain.clone();
        assert!(shared.share_pattern(&k));
        for m in [lumped, wider, shared] {
            let dense = nlsim_kernel::linalg::dense_generalized_eigen(
                k.to_dense().as_ref(),
                m.to_dense().as_ref(),
            )
            .unwrap();
            for threshold in [
                SupernodalThreshold::FORCE_SIMPLICIAL,
                SupernodalThreshold::FORCE_SUPERNODAL,
            ] {
                let params = CholeskySymbolicParams {
                    supernodal_flop_ratio_threshold: threshold,
                    ..Default::default()
                };
                let p = ShiftedPencil::with_params(&k, &m, Ordering::Amd, params).unwrap();
                let sigma = 0.5 * (dense.values[4] + dense.values[5]);
                assert_eq!(p.count_below(sigma).unwrap(), 5);
                let sigma = 0.3 * dense.values[0];
                let f = p.cholesky(sigma).unwrap().unwrap();
                let b = faer::Mat::from_fn(50, 2, |i, j| ((i * 5 + j) % 7) as f64 - 3.0);
                let mut x = b.clone();
                p.solve_in_place(&f, x.as_mut());
                let a = k.to_dense() - m.to_dense() * faer::Scale(sigma);
                assert!((&a * &x - &b).norm_max() < 1e-12 * b.norm_max());
            }
        }
    }

    /// A 7-point Laplacian on an `n³` grid (one DOF per node) and a consistent-like mass.
    fn grid(n: usize) -> (SparseSym, SparseSym) {
        let id = |i: usize, j: usize, k: usize| (i * n + j) * n + k;
        let (mut kt, mut mt) = (Vec::new(), Vec::new());
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let a = id(i, j, k);
                    kt.push((a, a, 6.0 + 0.01 * (a % 5) as f64));
                    mt.push((a, a, 1.0));
                    for b in [
                        (i + 1 < n).then(|| id(i + 1, j, k)),
                        (j + 1 < n).then(|| id(i, j + 1, k)),
                        (k + 1 < n).then(|| id(i, j, k + 1)),
                    ]
                    .into_iter()
                    .flatten()
                    {
                        kt.push((b, a, -1.0));
                        mt.push((b, a, 0.05));
                    }
                }
            }
        }
        let n3 = n * n * n;
        (
            SparseSym::from_lower_triplets("K", n3, &kt).unwrap(),
            SparseSym::from_lower_triplets("M", n3, &mt).unwrap(),
        )
    }

    /// Two uncoupled copies of a pencil: an elimination forest with more than one root.
    fn two_copies(k: &SparseSym, m: &SparseSym) -> (SparseSym, SparseSym) {
        let n = k.n();
        let twice = |a: &SparseSym, name: &str| {
            let t: Vec<_> = a
                .entries()
                .filter(|(i, j, _)| i >= j)
                .flat_map(|(i, j, v)| [(i, j, v), (i + n, j + n, 1.5 * v)])
                .collect();
            SparseSym::from_lower_triplets(name, 2 * n, &t).unwrap()
        };
        (twice(k, "K"), twice(m, "M"))
    }

    /// The supernodal solve against faer's own and against the dense matrix, for block widths
    /// on both sides of the sweep's group of 8 columns, with nested dissection (subtrees solved
    /// in parallel) and AMD, on a connected grid and on two uncoupled ones (several roots);
    /// the same bits with one thread and with two.
    #[test]
    fn supernodal_solve_matches_faer_and_dense_for_any_thread_count() {
        let (k, m) = grid(11);
        check_supernodal_solve(&k, &m);
        let (k, m) = grid(6);
        let (k2, m2) = two_copies(&k, &m);
        check_supernodal_solve(&k2, &m2);
    }

    fn check_supernodal_solve(k: &SparseSym, m: &SparseSym) {
        let n = k.n();
        let params = CholeskySymbolicParams {
            supernodal_flop_ratio_threshold: SupernodalThreshold::FORCE_SUPERNODAL,
            ..Default::default()
        };
        let sigma = -0.5;
        let a = k.to_dense() - m.to_dense() * faer::Scale(sigma);
        for ordering in [Ordering::NestedDissection, Ordering::Amd] {
            let mut p = ShiftedPencil::with_params(k, m, ordering, params).unwrap();
            let tree = p.tree.as_ref().expect("supernodal forced");
            if ordering == Ordering::NestedDissection {
                assert!(
                    tree.subtrees() >= 2,
                    "dissection gives independent subtrees"
                );
            }
            let f = p.cholesky(sigma).unwrap().unwrap();
            for cols in [1, 3, 6, 8, 11] {
                let b = faer::Mat::from_fn(n, cols, |i, j| ((i * 7 + j * 13) % 17) as f64 - 8.0);
                let mut x = b.clone();
                p.set_par(Par::Seq);
                p.solve_in_place(&f, x.as_mut());
                let mut x2 = b.clone();
                p.set_par(Par::rayon(2));
                p.solve_in_place(&f, x2.as_mut());
                assert!(
                    x == x2,
                    "{ordering:?}, {cols} columns: thread count changed bits"
                );
                // faer's solve on the same factor.
                let mut reference = b.clone();
                let llt = LltRef::<'_, usize, f64>::new(&p.symbolic, &f.values);
                let mut mem =
                    MemBuffer::new(p.symbolic.solve_in_place_scratch::<f64>(cols, Par::Seq));
                llt.solve_in_place_with_conj(
                    Conj::No,
                    reference.as_mut(),
                    Par::Seq,
                    MemStack::new(&mut mem),
                );
                // The condition number of A is below 20: both solves agree to a few ulps of x.
                let scale = reference.norm_max();
                assert!(
                    (&x - &reference).norm_max() <= 1e-13 * scale,
                    "{ordering:?}, {cols} columns: {:e}",
                    (&x - &reference).norm_max() / scale
                );
                assert!((&a * &x - &b).norm_max() <= 1e-12 * b.norm_max());
            }
        }
    }

    #[test]
    fn solve_matches_dense_and_values_reuse_the_analysis() {
        let (k, m) = chain(40);
        let mut p = ShiftedPencil::new(&k, &m).unwrap();
        let sigma = -0.3;
        let f = p.cholesky(sigma).unwrap().unwrap();
        let b = faer::Mat::from_fn(40, 3, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
        let mut x = b.clone();
        p.solve_in_place(&f, x.as_mut());
        let a = k.to_dense() - m.to_dense() * faer::Scale(sigma);
        let r = &a * &x - &b;
        assert!(r.norm_max() < 1e-12 * b.norm_max());
        // Same pattern, new values: the analysis is kept.
        let k2 = k.scaled(2.0);
        assert!(p.set_values(&k2, &m).unwrap());
        assert_eq!(p.analyses(), 1);
        let (k3, _) = chain(40);
        let extra = SparseSym::from_lower_triplets("K", 40, &[(39, 0, -0.01)]).unwrap();
        let k3 = SparseSym::linear_combination("K", 1.0, &k3, 1.0, &extra).unwrap();
        assert!(!p.set_values(&k3, &m).unwrap());
        assert_eq!(p.analyses(), 2);
    }
}
