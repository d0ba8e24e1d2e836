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
                "expected '%%MatrixMarket matrix coordinate real symmetric|general', found '{header}'"
            ),
        ));
    }
    if h[2] != "coordinate" {
        return Err(err(
            l0,
            format!("only the coordinate format is supported, not '{}'", h[2]),
        ));
    }
    if h[3] != "real" && h[3] != "integer" {
        return Err(err(
            l0,
            format!("field '{}' is not supported (use real or integer)", h[3]),
        ));
    }
    let symmetric = match h[4].as_str() {
        "symmetric" => true,
        "general" => false,
        other => {
            return Err(err(
                l0,
                format!("symmetry '{other}' is not supported (use symmetric or general)"),
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
                        format!("expected the size line 'ROWS COLS ENTRIES', found '{t}'"),
                    ));
                }
                let p = |s: &str| {
                    s.parse::<usize>()
                        .map_err(|_| err(ln, format!("'{s}' is not a non-negative integer")))
                };
                let (r, c, nz) = (p(f[0])?, p(f[1])?, p(f[2])?);
                if r != c {
                    return Err(err(
                        ln,
                        format!("{name} must be square, the file says {r} x {c}"),
                    ));
                }
                n = r;
                size = Some((r, nz));
                trip.reserve(nz);
            }
            Some(_) => {
                if f.len() != 3 {
                    return Err(err(ln, format!("expected 'ROW COL VALUE', found '{t}'")));
                }
                let idx = |s: &str| match s.parse::<usize>() {
                    Ok(i) if i >= 1 && i <= n => Ok(i - 1),
                    _ => Err(err(ln, format!("index '{s}' is outside 1..={n}"))),
                };
                let (i, j) = (idx(f[0])?, idx(f[1])?);
                let v: f64 = f[2]
                    .parse()
                    .map_err(|_| err(ln, format!("value '{}' is not a number", f[2])))?;
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
    Ok(m)
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
