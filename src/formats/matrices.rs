//! Matrix Market (`.mtx`) coordinate files and DOF-label lists.
//!
//! Reads `%%MatrixMarket matrix coordinate real|integer general|symmetric` (1-based indices;
//! a symmetric file holds one triangle). Errors name the file and line.

use crate::error::{Error, Result};
use nlsim_kernel::{DofLabel, SparseSym};
use std::path::Path;

/// Parses Matrix Market text into a square sparse matrix; `file` names the source in errors.
pub fn parse_matrix_market(text: &str, file: &Path, name: &str) -> Result<SparseSym> {
    let err = |line: usize, message: String| Error::DataFile {
        file: file.to_path_buf(),
        line,
        message,
    };
    let mut lines = text.lines().enumerate().map(|(i, l)| (i + 1, l));
    let (l0, header) = lines
        .next()
        .ok_or_else(|| err(1, "empty file; expected a %%MatrixMarket header".into()))?;
    let h: Vec<String> = header
        .split_whitespace()
        .map(|s| s.to_ascii_lowercase())
        .collect();
    if h.len() != 5 || h[0] != "%%matrixmarket" || h[1] != "matrix" {
        return Err(err(
            l0,
            format!(
                "expected '%%MatrixMarket matrix coordinate real symmetric|general', found {}",
                crate::formats::files::quoted(header)
            ),
        ));
    }
    if h[2] != "coordinate" {
        return Err(err(
            l0,
            format!(
                "only the coordinate format is supported, not {}",
                crate::formats::files::quoted(&h[2])
            ),
        ));
    }
    if h[3] != "real" && h[3] != "integer" {
        return Err(err(
            l0,
            format!(
                "field {} is not supported (use real or integer)",
                crate::formats::files::quoted(&h[3])
            ),
        ));
    }
    let symmetric = match h[4].as_str() {
        "symmetric" => true,
        "general" => false,
        other => {
            return Err(err(
                l0,
                format!(
                    "symmetry {} is not supported (use symmetric or general)",
                    crate::formats::files::quoted(other)
                ),
            ));
        }
    };
    let mut size: Option<(usize, usize)> = None;
    let mut trip = Vec::new();
    let mut n = 0;
    for (ln, line) in lines {
        let t = line.trim();
        if t.is_empty() || t.starts_with('%') {
            continue;
        }
        let f: Vec<&str> = t.split_whitespace().collect();
        match size {
            None => {
                if f.len() != 3 {
                    return Err(err(
                        ln,
                        format!(
                            "expected the size line 'ROWS COLS ENTRIES', found {}",
                            crate::formats::files::quoted(t)
                        ),
                    ));
                }
                let p = |s: &str| {
                    s.parse::<usize>().map_err(|_| {
                        err(
                            ln,
                            format!(
                                "{} is not a non-negative integer",
                                crate::formats::files::quoted(s)
                            ),
                        )
                    })
                };
                let (r, c, nz) = (p(f[0])?, p(f[1])?, p(f[2])?);
                if r != c {
                    return Err(err(
                        ln,
                        format!("{name} must be square, the file says {r} x {c}"),
                    ));
                }
                if r > MAX_DIM {
                    return Err(err(
                        ln,
                        format!(
                            "{r} rows: more than {MAX_DIM} DOFs, which no workstation can \
                             reduce"
                        ),
                    ));
                }
                // Each entry takes a line of at least 6 bytes ("i j v\n").
                let room = text.len() / 6 + 1;
                if nz > room {
                    return Err(err(
                        ln,
                        format!(
                            "the size line announces {nz} entries; a file of {} bytes holds \
                             at most {room}",
                            text.len()
                        ),
                    ));
                }
                n = r;
                size = Some((r, nz));
                trip.reserve(nz);
            }
            Some(_) => {
                if f.len() != 3 {
                    return Err(err(
                        ln,
                        format!(
                            "expected 'ROW COL VALUE', found {}",
                            crate::formats::files::quoted(t)
                        ),
                    ));
                }
                let idx = |s: &str| match s.parse::<usize>() {
                    Ok(i) if i >= 1 && i <= n => Ok(i - 1),
                    _ => Err(err(
                        ln,
                        format!(
                            "index {} is outside 1..={n}",
                            crate::formats::files::quoted(s)
                        ),
                    )),
                };
                let (i, j) = (idx(f[0])?, idx(f[1])?);
                let v: f64 = f[2].parse().map_err(|_| {
                    err(
                        ln,
                        format!(
                            "value {} is not a number",
                            crate::formats::files::quoted(f[2])
                        ),
                    )
                })?;
                if !v.is_finite() {
                    return Err(err(ln, format!("value {v} is not finite")));
                }
                if symmetric && i < j {
                    return Err(err(
                        ln,
                        format!(
                            "entry ({}, {}) lies above the diagonal of a symmetric file (give the lower triangle)",
                            i + 1,
                            j + 1
                        ),
                    ));
                }
                trip.push((i, j, v));
            }
        }
    }
    let (_, nz) = size.ok_or_else(|| err(l0, "no size line".into()))?;
    if trip.len() != nz {
        return Err(err(
            text.lines().count(),
            format!(
                "the size line announces {nz} entries, the file has {}",
                trip.len()
            ),
        ));
    }
    let m = if symmetric {
        SparseSym::from_lower_triplets(name, n, &trip)?
    } else {
        SparseSym::from_triplets(name, n, &trip)?
    };
    // Assembly sums repeated entries: fewer stored entries than given means a repeat. Its
    // lines are found only then (a sort of the entries).
    let given: usize = trip
        .iter()
        .map(|&(i, j, _)| if symmetric && i != j { 2 } else { 1 })
        .sum();
    if m.nnz() < given
        && let Some((first, again)) = repeated_entry(&trip)
    {
        let (i, j, _) = trip[again];
        let line = |k: usize| entry_line(text, k).unwrap_or(0);
        return Err(err(
            line(again),
            format!(
                "entry ({}, {}) repeats line {}; a Matrix Market file lists each entry once (sum \
                 repeated entries before writing it, as an assembly does)",
                i + 1,
                j + 1,
                line(first)
            ),
        ));
    }
    Ok(m)
}

/// The first repeated `(row, col)` of `trip`: the indices of its first and second occurrence.
fn repeated_entry(trip: &[(usize, usize, f64)]) -> Option<(usize, usize)> {
    let mut order: Vec<usize> = (0..trip.len()).collect();
    order.sort_by_key(|&k| (trip[k].0, trip[k].1, k));
    order
        .windows(2)
        .filter(|w| (trip[w[0]].0, trip[w[0]].1) == (trip[w[1]].0, trip[w[1]].1))
        .map(|w| (w[0], w[1]))
        .min_by_key(|&(_, again)| again)
}

/// The line (1-based) of entry `k` (0-based) of Matrix Market `text`: the header, comments,
/// blank lines and the size line are skipped as the parser skips them.
fn entry_line(text: &str, k: usize) -> Option<usize> {
    text.lines()
        .enumerate()
        .skip(1)
        .filter(|(_, l)| {
            let t = l.trim();
            !t.is_empty() && !t.starts_with('%')
        })
        .nth(k + 1)
        .map(|(i, _)| i + 1)
}

/// Writes a symmetric matrix as Matrix Market (lower triangle), e.g. to export a fixture.
pub fn to_matrix_market(m: &SparseSym) -> String {
    let lower: Vec<(usize, usize, f64)> = m.entries().filter(|(i, j, _)| i >= j).collect();
    let mut s = format!(
        "%%MatrixMarket matrix coordinate real symmetric\n% written by nlsim\n{} {} {}\n",
        m.n(),
        m.n(),
        lower.len()
    );
    for (i, j, v) in lower {
        s.push_str(&format!("{} {} {:e}\n", i + 1, j + 1, v));
    }
    s
}

/// Parses a DOF-label list: one `NODE:COMP` per line, `#` starts a comment.
pub fn parse_dof_labels(text: &str, file: &Path) -> Result<Vec<DofLabel>> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let t = line.split('#').next().unwrap_or("").trim();
        if t.is_empty() {
            continue;
        }
        out.push(t.parse::<DofLabel>().map_err(|e| Error::DataFile {
            file: file.to_path_buf(),
            line: i + 1,
            message: e.to_string(),
        })?);
    }
    Ok(out)
}

/// Most rows a matrix file may declare (a model of more DOFs is refused before anything is
/// allocated).
pub const MAX_DIM: usize = 50_000_000;

/// Most values one HDF5 dataset of a matrix may declare (2 GiB of `f64`).
pub const MAX_HDF5_VALUES: usize = 1 << 28;

/// Largest dense HDF5 matrix (n × n ≤ [`MAX_HDF5_VALUES`]).
pub const MAX_DENSE_DIM: usize = 16_384;

#[cfg(feature = "hdf5")]
/// Reads a square matrix from an HDF5 file: `object` is either a group holding compressed
/// sparse rows in scipy's convention (`data`, `indices`, `indptr`, 0-based, and a `shape`
/// attribute or dataset; repeated entries are summed) or a 2-D dense dataset.
pub fn read_hdf5_matrix(file: &Path, object: &str, name: &str) -> Result<SparseSym> {
    use hdf5_metno as hdf5;
    let err = |message: String| Error::Hdf5 {
        path: file.to_path_buf(),
        message: format!("{object}: {message}"),
    };
    let h5 = |e: hdf5::Error| err(e.to_string());
    crate::formats::files::input_file(file)?;
    let f = hdf5::File::open(file).map_err(|e| Error::Hdf5 {
        path: file.to_path_buf(),
        message: e.to_string(),
    })?;
    // Declared sizes are checked before reading: a small chunked file can declare a
    // dataset of any size.
    let bounded = |d: &hdf5::Dataset, k: &str| -> Result<()> {
        if d.size() > MAX_HDF5_VALUES {
            return Err(err(format!(
                "dataset '{k}' declares {} values, more than {MAX_HDF5_VALUES} ({} GiB)",
                d.size(),
                (MAX_HDF5_VALUES * 8) >> 30
            )));
        }
        Ok(())
    };
    if let Ok(g) = f.group(object) {
        let read_i = |k: &str| -> Result<Vec<i64>> {
            let d = g
                .dataset(k)
                .map_err(|e| err(format!("dataset '{k}' of a CSR group: {e}")))?;
            bounded(&d, k)?;
            let integer = d.dtype().and_then(|t| t.to_descriptor()).is_ok_and(|t| {
                matches!(
                    t,
                    hdf5::types::TypeDescriptor::Integer(_)
                        | hdf5::types::TypeDescriptor::Unsigned(_)
                )
            });
            if !integer {
                return Err(err(format!(
                    "dataset '{k}' of a CSR group must hold integers (it would be truncated)"
                )));
            }
            d.read_raw::<i64>()
                .map_err(|e| err(format!("dataset '{k}' of a CSR group: {e}")))
        };
        let indptr = read_i("indptr")?;
        let indices = read_i("indices")?;
        let data = g
            .dataset("data")
            .map_err(h5)
            .and_then(|d| {
                bounded(&d, "data")?;
                d.read_raw::<f64>().map_err(h5)
            })
            .map_err(|e| err(format!("dataset 'data' of a CSR group: {e}")))?;
        let shape: Vec<i64> = match g.attr("shape") {
            Ok(a) => a.read_raw::<i64>().map_err(h5)?,
            Err(_) => read_i("shape")?,
        };
        if shape.len() != 2 || shape[0] != shape[1] || shape[0] < 0 {
            return Err(err(format!("shape {shape:?} is not square")));
        }
        let n = shape[0] as usize;
        if indptr.len() != n + 1 || indices.len() != data.len() {
            return Err(err(format!(
                "indptr has {} entries (n + 1 = {}), indices {} and data {}",
                indptr.len(),
                n + 1,
                indices.len(),
                data.len()
            )));
        }
        let mut t = Vec::with_capacity(data.len());
        for i in 0..n {
            let (a, b) = (indptr[i], indptr[i + 1]);
            if a < 0 || b < a || b as usize > data.len() {
                return Err(err(format!(
                    "indptr[{i}..{}] = {a}..{b} is out of order",
                    i + 1
                )));
            }
            for k in a as usize..b as usize {
                let j = indices[k];
                if j < 0 || j as usize >= n {
                    return Err(err(format!("row {i}: column index {j} outside 0..{n}")));
                }
                t.push((i, j as usize, data[k]));
            }
        }
        return Ok(SparseSym::from_triplets(name, n, &t)?);
    }
    let d = f
        .dataset(object)
        .map_err(|_| err("no such group (CSR) or dataset (dense) in the file".into()))?;
    let shape = d.shape();
    if shape.len() != 2 || shape[0] != shape[1] {
        return Err(err(format!(
            "a dense matrix must be square and 2-D, this one is {shape:?}"
        )));
    }
    if shape[0] > MAX_DENSE_DIM {
        return Err(err(format!(
            "a dense {0} x {0} matrix is larger than {MAX_DENSE_DIM} x {MAX_DENSE_DIM}: store it \
             as compressed sparse rows (data, indices, indptr)",
            shape[0]
        )));
    }
    let v = d.read_raw::<f64>().map_err(h5)?;
    let rows: Vec<Vec<f64>> = v.chunks(shape[1].max(1)).map(<[f64]>::to_vec).collect();
    Ok(SparseSym::from_dense_rows(name, &rows)?)
}
