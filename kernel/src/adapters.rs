//! Matrices from other Rust sparse crates, for solvers that already hold their mass and
//! stiffness there: `nalgebra-sparse` CSC, CSR and COO (feature `nalgebra-sparse`) and `sprs`
//! compressed and triplet matrices (feature `sprs`). Each becomes a [`SparseSym`], the
//! matrix type of [`crate::Model::new`]; the model's validation then checks symmetry,
//! definiteness and finite values as for any other source.
//!
//! A symmetric matrix is stored either whole ([`Stored::Both`], what FE assembly gives) or as
//! one triangle ([`Stored::OneTriangle`], as many symmetric solvers keep it). Repeated
//! entries (COO, triplets) are summed, as assembly expects.

use crate::error::{Error, Result};
use crate::sparse::SparseSym;

/// Which part of a symmetric matrix the source holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stored {
    /// Both triangles (every off-diagonal pair given twice).
    Both,
    /// One triangle, upper or lower: each off-diagonal entry is mirrored. An entry on the
    /// other side is refused (it would be counted twice).
    OneTriangle,
}

impl SparseSym {
    /// The matrix `name` from the `(row, col, value)` entries (0-based, repeats summed) of a
    /// `rows × cols` source holding `stored`: what every adapter does, for any other source.
    /// Errors name a non-square shape, a non-finite entry, or entries on both sides of the
    /// diagonal of a one-triangle source.
    pub fn from_entries(
        name: &str,
        shape: (usize, usize),
        stored: Stored,
        entries: impl Iterator<Item = (usize, usize, f64)>,
    ) -> Result<SparseSym> {
        from_entries(name, shape, stored, entries)
    }
}

/// [`SparseSym::from_entries`].
fn from_entries(
    name: &str,
    (rows, cols): (usize, usize),
    stored: Stored,
    entries: impl Iterator<Item = (usize, usize, f64)>,
) -> Result<SparseSym> {
    if rows != cols {
        return Err(Error::DimensionMismatch {
            what: format!("{name} columns (a mass or stiffness matrix is square)"),
            expected: rows,
            found: cols,
        });
    }
    let entries: Vec<(usize, usize, f64)> = entries.collect();
    if let Some(&(r, c, v)) = entries.iter().find(|e| !e.2.is_finite()) {
        return Err(Error::NonFinite {
            what: name.to_string(),
            location: format!("entry (row {r}, column {c}), 0-based"),
            value: v,
        });
    }
    match stored {
        Stored::Both => SparseSym::from_triplets(name, rows, &entries),
        Stored::OneTriangle => {
            let lower = entries.iter().find(|e| e.0 > e.1);
            let upper = entries.iter().find(|e| e.0 < e.1);
            if let (Some(l), Some(u)) = (lower, upper) {
                return Err(Error::invalid(
                    name,
                    format!(
                        "stored as one triangle, but it has entries below the diagonal (row \
                         {}, column {}) and above it (row {}, column {}); pass Stored::Both \
                         for a whole matrix",
                        l.0, l.1, u.0, u.1
                    ),
                ));
            }
            SparseSym::from_lower_triplets(name, rows, &entries)
        }
    }
}

#[cfg(feature = "nalgebra-sparse")]
mod nalgebra_impl {
    use super::{Stored, from_entries};
    use crate::error::Result;
    use crate::sparse::SparseSym;
    use nalgebra_sparse::{CooMatrix, CscMatrix, CsrMatrix};

    /// `SparseSym::$fn` from a `nalgebra-sparse` matrix of type `$ty` (all three share
    /// `nrows`, `ncols` and `triplet_iter`, but no trait).
    macro_rules! from_nalgebra {
        ($fn:ident, $ty:ident, $what:literal) => {
            impl SparseSym {
                #[doc = concat!("The matrix `name` from a `nalgebra-sparse` ", $what, ".")]
                pub fn $fn(name: &str, a: &$ty<f64>, stored: Stored) -> Result<Self> {
                    from_entries(
                        name,
                        (a.nrows(), a.ncols()),
                        stored,
                        a.triplet_iter().map(|(r, c, &v)| (r, c, v)),
                    )
                }
            }
        };
    }

    from_nalgebra!(from_nalgebra_csc, CscMatrix, "CSC matrix");
    from_nalgebra!(from_nalgebra_csr, CsrMatrix, "CSR matrix");
    from_nalgebra!(
        from_nalgebra_coo,
        CooMatrix,
        "COO matrix (repeated entries summed)"
    );
}

#[cfg(feature = "sprs")]
mod sprs_impl {
    use super::{Stored, from_entries};
    use crate::error::Result;
    use crate::sparse::SparseSym;
    use sprs::{CsMatI, SpIndex, TriMatI};

    impl SparseSym {
        /// The matrix `name` from a `sprs` compressed matrix (CSC or CSR, any index type).
        pub fn from_sprs<I: SpIndex, Iptr: SpIndex>(
            name: &str,
            a: &CsMatI<f64, I, Iptr>,
            stored: Stored,
        ) -> Result<Self> {
            from_entries(
                name,
                (a.rows(), a.cols()),
                stored,
                a.iter().map(|(&v, (r, c))| (r.index(), c.index(), v)),
            )
        }

        /// The matrix `name` from a `sprs` triplet matrix (repeated entries summed).
        pub fn from_sprs_triplets<I: SpIndex>(
            name: &str,
            a: &TriMatI<f64, I>,
            stored: Stored,
        ) -> Result<Self> {
            from_entries(
                name,
                (a.rows(), a.cols()),
                stored,
                a.triplet_iter()
                    .map(|(&v, (r, c))| (r.index(), c.index(), v)),
            )
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_triangle_is_mirrored_and_mixed_sides_are_refused() {
        let a = from_entries(
            "K",
            (3, 3),
            Stored::OneTriangle,
            [
                (0, 0, 2.0),
                (1, 0, -1.0),
                (1, 1, 2.0),
                (2, 1, -1.0),
                (2, 2, 1.0),
            ]
            .into_iter(),
        )
        .unwrap();
        assert_eq!(a.get(0, 1), -1.0);
        assert_eq!(a.get(1, 0), -1.0);
        let e = from_entries(
            "K",
            (2, 2),
            Stored::OneTriangle,
            [(1, 0, -1.0), (0, 1, -1.0)].into_iter(),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("below the diagonal (row 1, column 0)"), "{e}");
        let e = from_entries("M", (2, 3), Stored::Both, std::iter::empty())
            .unwrap_err()
            .to_string();
        assert!(e.contains("M columns"), "{e}");
        let e = from_entries("M", (2, 2), Stored::Both, [(1, 1, f64::NAN)].into_iter())
            .unwrap_err()
            .to_string();
        assert!(e.contains("row 1, column 1"), "{e}");
    }
}
