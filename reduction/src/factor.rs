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
    factorize_symbolic_cholesky,
};
use faer::sparse::{SparseColMatRef, SymbolicSparseColMatRef};
use faer::{Conj, MatMut, Par, Side};
use nlsim_kernel::{Error, Result, SparseSym};

use crate::ordering::{Ordering, nested_dissection};

/// `K − σM` on the union of the patterns of `K` and `M` (lower triangle), with its symbolic
/// Cholesky analysis.
#[derive(Debug)]
pub struct ShiftedPencil {
    n: usize,
    col_ptr: Vec<usize>,
    row_idx: Vec<usize>,
    k_vals: Vec<f64>,
    m_vals: Vec<f64>,
    symbolic: SymbolicCholesky<usize>,
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

/// Union pattern (lower triangle) of two symmetric matrices of the same order, with each one's
/// values scattered onto it (zero where it has no entry).
fn union_lower(k: &SparseSym, m: &SparseSym) -> (Vec<usize>, Vec<usize>, Vec<f64>, Vec<f64>) {
    let n = k.n();
    let mut col_ptr = Vec::with_capacity(n + 1);
    let mut row_idx = Vec::new();
    let mut kv = Vec::new();
    let mut mv = Vec::new();
    // slot[i] = position of row i in the current column, or usize::MAX.
    let mut slot = vec![usize::MAX; n];
    col_ptr.push(0);
    let mut rows: Vec<usize> = Vec::new();
    for j in 0..n {
        rows.clear();
        let (kr, _) = k.col(j);
        let (mr, _) = m.col(j);
        for &i in kr.iter().chain(mr.iter()) {
            if i >= j && slot[i] == usize::MAX {
                slot[i] = 0;
                rows.push(i);
            }
        }
        rows.sort_unstable();
        let start = row_idx.len();
        for (p, &i) in rows.iter().enumerate() {
            slot[i] = start + p;
            row_idx.push(i);
            kv.push(0.0);
            mv.push(0.0);
        }
        let (kr, kx) = k.col(j);
        for (&i, &v) in kr.iter().zip(kx) {
            if i >= j {
                kv[slot[i]] += v;
            }
        }
        let (mr, mx) = m.col(j);
        for (&i, &v) in mr.iter().zip(mx) {
            if i >= j {
                mv[slot[i]] += v;
            }
        }
        for &i in &rows {
            slot[i] = usize::MAX;
        }
        col_ptr.push(row_idx.len());
    }
    (col_ptr, row_idx, kv, mv)
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
            let a = amd(params)?;
            let mut predicted = vec![(Ordering::Amd, a.len_val())];
            // Small patterns: AMD is near optimal and METIS's setup dominates.
            if n < AUTO_ND_MIN {
                return Ok((a, Ordering::Amd, predicted));
            }
            // AMD is a valid ordering: when dissection cannot be had (a graph beyond METIS's
            // indices, or METIS out of memory), the run goes on with it.
            match nd(params) {
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
        let (col_ptr, row_idx, k_vals, m_vals) = union_lower(k, m);
        let (symbolic, used, predicted) = analyse(n, &col_ptr, &row_idx, ordering, params)?;
        Ok(ShiftedPencil {
            par: Par::rayon(0),
            n,
            col_ptr,
            row_idx,
            k_vals,
            m_vals,
            symbolic,
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
        let (col_ptr, row_idx, k_vals, m_vals) = union_lower(k, m);
        if col_ptr == self.col_ptr && row_idx == self.row_idx {
            self.k_vals = k_vals;
            self.m_vals = m_vals;
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

    fn shifted(&self, sigma: f64) -> Vec<f64> {
        self.k_vals
            .iter()
            .zip(&self.m_vals)
            .map(|(k, m)| k - sigma * m)
            .collect()
    }

    fn matrix<'a>(&'a self, vals: &'a [f64]) -> SparseColMatRef<'a, usize, f64> {
        let pattern = SymbolicSparseColMatRef::new_checked(
            self.n,
            self.n,
            &self.col_ptr,
            None,
            &self.row_idx,
        );
        SparseColMatRef::new(pattern, vals)
    }

    /// Cholesky factor of `K − σM`; `Err(step)` when a pivot is not positive (the pencil is not
    /// positive definite at this shift), with the failing elimination step.
    pub fn cholesky(&self, sigma: f64) -> Result<core::result::Result<ShiftFactor, usize>> {
        let a_vals = self.shifted(sigma);
        let a = self.matrix(&a_vals);
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
        let mut mem = MemBuffer::new(
            self.symbolic
                .factorize_numeric_llt_scratch::<f64>(par, Default::default()),
        );
        let res = self.symbolic.factorize_numeric_llt(
            &mut values,
            a,
            Side::Lower,
            Default::default(),
            par,
            MemStack::new(&mut mem),
            Default::default(),
        );
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

    /// Solves `(K − σM) X = B` in place for all columns of `rhs`.
    pub fn solve_in_place(&self, factor: &ShiftFactor, rhs: MatMut<'_, f64>) {
        let par = self.par;
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
        let a_vals = self.shifted(sigma);
        let a = self.matrix(&a_vals);
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
        let mut mem = MemBuffer::new(
            self.symbolic
                .factorize_numeric_ldlt_scratch::<f64>(par, Default::default()),
        );
        self.symbolic
            .factorize_numeric_ldlt(
                &mut *values,
                a,
                Side::Lower,
                Default::default(),
                par,
                MemStack::new(&mut mem),
                Default::default(),
            )
            .map_err(|e| Error::Numerical {
                what: format!("Sturm count at shift {sigma:e} rad²/s²"),
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
