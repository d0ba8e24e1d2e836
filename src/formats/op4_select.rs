//! Which matrix of a Nastran OUTPUT4 file a read takes: the headers both layouts list
//! ([`Op4Header`]), the standard names of stiffness and mass matrices ([`Op4Role`]), `NAME`
//! and `NAME@K`, and the matrix type every reader returns ([`Op4Matrix`]). The readers are
//! [`crate::formats::op4`] (ASCII, and the entry points) and [`crate::formats::op4_binary`].

use crate::error::{Error, Result};
use crate::formats::files::quoted;
use std::path::Path;

/// Largest OUTPUT4 file read (bytes).
pub const MAX_OP4_BYTES: u64 = crate::formats::fe_matrices::MAX_FE_FILE_BYTES;

/// The stored entries of one square real OUTPUT4 matrix: `(row, col, value, line)`, 0-based
/// indices, exact zeros dropped, and its order.
#[derive(Debug, Clone)]
pub struct Op4Matrix {
    /// The matrix's name in the file.
    pub name: String,
    /// Order (rows = columns).
    pub n: usize,
    /// Entries `(row, col, value, place)` as stored (both triangles for Nastran's own files);
    /// `place` is the 1-based line (ASCII) or record (binary) it was read from.
    pub entries: Vec<(usize, usize, f64, usize)>,
    /// Whether the file was binary (`place` counts records, not lines).
    pub binary: bool,
}

/// Which matrix of an OUTPUT4 file a model reads, when no name is given: the file's one
/// square real matrix, or the one with a standard name for its role.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op4Role {
    /// A stiffness matrix: `KAAX`, `KXX`, `KGG`, `KAA`, `KLL`, `KHH`, `KFF`, `KNN`, `KBB`,
    /// `KJJ` or `K`.
    Stiffness,
    /// A mass matrix: the same names with `M`.
    Mass,
    /// Any matrix: the file must hold one square real matrix only.
    Any,
}

/// The standard Nastran names of stiffness matrices (the set of DOFs after the letters):
/// an unnamed read picks the file's one matrix of these names.
const STIFFNESS_NAMES: [&str; 11] = [
    "KAAX", "KXX", "KGG", "KAA", "KLL", "KHH", "KFF", "KNN", "KBB", "KJJ", "K",
];

/// [`STIFFNESS_NAMES`] for mass matrices.
const MASS_NAMES: [&str; 11] = [
    "MAAX", "MXX", "MGG", "MAA", "MLL", "MHH", "MFF", "MNN", "MBB", "MJJ", "M",
];

/// A matrix header of an OUTPUT4 file, as listed by a scan.
#[derive(Debug, Clone)]
pub struct Op4Header {
    /// The name, trimmed.
    pub name: String,
    /// Columns.
    pub ncol: i64,
    /// Rows (negative: the "bigmat" sparse layout).
    pub nrow: i64,
    /// Nastran's form: 1 square, 2 rectangular, 3 diagonal, 4 lower triangular, 5 upper
    /// triangular, 6 symmetric, 8 identity, 9 pseudo-identity.
    pub form: i64,
    /// Nastran's type: 1 real single, 2 real double, 3 complex single, 4 complex double.
    pub ty: i64,
    /// Its 1-based line (ASCII) or record (binary).
    pub place: usize,
}

impl Op4Header {
    /// Whether it is a square real matrix of a form a stiffness or mass can take (square,
    /// rectangular with as many rows as columns, symmetric).
    pub(crate) fn usable(&self) -> bool {
        self.ncol >= 1
            && self.nrow.unsigned_abs() == self.ncol.unsigned_abs()
            && matches!(self.ty, 1 | 2)
            && matches!(self.form, 1 | 2 | 6)
    }

    /// Why it cannot be a stiffness or mass matrix, if it cannot.
    pub(crate) fn refusal(&self) -> Option<String> {
        let n = self.nrow.unsigned_abs();
        let what = quoted(&self.name);
        if self.ncol < 1 || n == 0 || n != self.ncol.unsigned_abs() {
            return Some(format!(
                "matrix {what} is {n} × {}: nlsim takes square matrices",
                self.ncol
            ));
        }
        if !matches!(self.ty, 1 | 2) {
            return Some(format!(
                "matrix {what} has type {}: nlsim takes real matrices (1 single, 2 double \
                 precision)",
                self.ty
            ));
        }
        let form = match self.form {
            1 | 2 | 6 => return None,
            3 => "3 (diagonal)",
            4 => "4 (lower triangular, a factor)",
            5 => "5 (upper triangular, a factor)",
            8 => "8 (identity)",
            9 => "9 (pseudo-identity)",
            _ => "not one Nastran defines",
        };
        Some(format!(
            "matrix {what} has form {form}: a stiffness or mass matrix is square (form 1) or \
             symmetric (form 6), stored in full"
        ))
    }
}

/// The matrix a read takes among the `headers` of file `path`: `name`'s (any case), or the
/// one `role` picks; errors list the file's matrices.
pub(crate) fn choose(
    path: &Path,
    headers: &[Op4Header],
    name: Option<&str>,
    role: Op4Role,
    unit: &str,
) -> Result<usize> {
    let listing = || {
        headers
            .iter()
            .map(|h| format!("{} {}×{}", h.name, h.nrow.unsigned_abs(), h.ncol))
            .collect::<Vec<_>>()
            .join(", ")
    };
    if let Some(w) = name {
        // `NAME@K`: the K-th matrix of that name (a file of several superelements repeats
        // KAA, MAA, …).
        let (base, nth) = match w.rsplit_once('@') {
            Some((b, k)) => match k.parse::<usize>() {
                Ok(k) if k >= 1 => (b, Some(k)),
                _ => {
                    return Err(Error::Usage(format!(
                        "{}: matrix {}: the number after '@' counts the matrices of that name \
                         from 1",
                        path.display(),
                        quoted(w)
                    )));
                }
            },
            None => (w, None),
        };
        let same: Vec<usize> = (0..headers.len())
            .filter(|&k| headers[k].name.eq_ignore_ascii_case(base))
            .collect();
        return match (same.as_slice(), nth) {
            ([], _) => Err(not_found(path, Some(base), headers)),
            ([k], None) => Ok(*k),
            (_, Some(k)) if k <= same.len() => Ok(same[k - 1]),
            (_, Some(k)) => Err(Error::Usage(format!(
                "{}: matrix {base}@{k}: the file holds {} matrices named {base}",
                path.display(),
                same.len()
            ))),
            (_, None) => Err(Error::Usage(format!(
                "{}: {} matrices are named {base} ({}); name one as {base}@1 … {base}@{}",
                path.display(),
                same.len(),
                {
                    // The first few, then how many more: a file of 30 same-named matrices
                    // (a QHH per Mach number and frequency) would flood the line.
                    let mut shown: Vec<String> = same
                        .iter()
                        .take(4)
                        .map(|&k| {
                            let h = &headers[k];
                            format!("{}×{} at {unit} {}", h.nrow.unsigned_abs(), h.ncol, h.place)
                        })
                        .collect();
                    if same.len() > 4 {
                        shown.push(format!("{} more", same.len() - 4));
                    }
                    shown.join(", ")
                },
                same.len()
            ))),
        };
    }
    let usable: Vec<usize> = (0..headers.len())
        .filter(|&k| headers[k].usable())
        .collect();
    let (names, other): (&[&str], &[&str]) = match role {
        Op4Role::Stiffness => (&STIFFNESS_NAMES, &MASS_NAMES),
        Op4Role::Mass => (&MASS_NAMES, &STIFFNESS_NAMES),
        Op4Role::Any => (&[], &[]),
    };
    // Of a standard name for the role, usable or not (a complex KAA is refused for what it
    // is, not skipped).
    let standard: Vec<usize> = (0..headers.len())
        .filter(|&k| {
            names
                .iter()
                .any(|n| n.eq_ignore_ascii_case(&headers[k].name))
        })
        .collect();
    let role_name = match role {
        Op4Role::Stiffness => "stiffness",
        Op4Role::Mass => "mass",
        Op4Role::Any => "matrix",
    };
    let of_other = |k: usize| {
        other
            .iter()
            .any(|n| n.eq_ignore_ascii_case(&headers[k].name))
    };
    match (standard.as_slice(), usable.as_slice()) {
        ([k], _) => Ok(*k),
        ([], [k]) if !of_other(*k) => Ok(*k),
        // A file of one matrix: that one, refused below for what it is if it cannot serve.
        ([], _) if headers.len() == 1 && !of_other(0) => Ok(0),
        ([], []) => Err(Error::Usage(format!(
            "{}: no square real matrix to read as the {role_name} (matrices in the file: {})",
            path.display(),
            if headers.is_empty() {
                "none".into()
            } else {
                listing()
            }
        ))),
        _ => Err(Error::Usage(format!(
            "{}: which matrix is the {role_name}? The file holds {} (standard names: {}); name \
             it as FILE.op4:NAME (NAME@K for the K-th of a repeated name)",
            path.display(),
            listing(),
            names.join(", ")
        ))),
    }
}

/// The error for a matrix `name` that is not among the file's `headers`.
pub(crate) fn not_found(path: &Path, name: Option<&str>, headers: &[Op4Header]) -> Error {
    Error::Usage(format!(
        "{}: no OUTPUT4 matrix {} (matrices in the file: {})",
        path.display(),
        quoted(name.unwrap_or("")),
        if headers.is_empty() {
            "none".into()
        } else {
            headers
                .iter()
                .map(|h| h.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        }
    ))
}
