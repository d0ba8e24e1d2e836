//! Nastran OUTPUT4 (`.op4`) matrices in the ASCII form, dense and sparse (strings, and the
//! "bigmat" strings of matrices with more than 65 535 rows), single or double precision.
//!
//! A matrix is a header line (`NCOL NROW FORM TYPE` as four integers in 32 columns, the name
//! in the next 8, then the value format such as `1P,3E23.16`), then one record per stored
//! column: a line `ICOL IROW NW` followed by value lines in fixed-width fields. `IROW > 0`:
//! a dense column whose values start at row `IROW`; `IROW = 0`: a sparse column whose
//! strings each start with a line `IS` (row `IS mod 65536`) or, when `NROW < 0` (bigmat),
//! `L IROW`. A record with `ICOL > NCOL` (and one value) ends the matrix. An OUTPUT4 file
//! carries no DOF labels: they come from the model file's `dofs` (the USET/EQEXIN order of the
//! matrix's rows). The binary form is not read yet.

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
    /// Entries `(row, col, value, line)` as stored (both triangles for Nastran's own files).
    pub entries: Vec<(usize, usize, f64, usize)>,
}

/// Reads matrix `name` (the first of the file when `None`) of the ASCII OUTPUT4 file `path`.
pub fn read_op4(path: &Path, name: Option<&str>) -> Result<Op4Matrix> {
    let bytes = crate::formats::files::read_bytes_up_to(path, Some(MAX_OP4_BYTES))?;
    let text = std::str::from_utf8(&bytes).map_err(|_| {
        Error::Usage(format!(
            "{}: not an ASCII OUTPUT4 file (binary OUTPUT4 is not read yet: write it with \
             OUTPUT4 ... /2 for ASCII, or convert it to Matrix Market)",
            path.display()
        ))
    })?;
    parse_op4(text, path, name)
}

/// Whether a line holds integers only (a record or string header), not values.
fn integer_line(t: &str) -> bool {
    !t.is_empty()
        && t.bytes()
            .all(|b| b.is_ascii_digit() || b == b' ' || b == b'-' || b == b'+')
}

/// Whether a line holds values: neither integers alone (a record or string header) nor a
/// matrix header. The value lines of a record end at the first line that is not.
fn value_line(raw: &str) -> bool {
    let t = raw.trim();
    !t.is_empty() && !integer_line(t) && !header_line(raw)
}

/// Whether a line is a matrix header: four integers in its first 32 columns, then a name.
fn header_line(t: &str) -> bool {
    let head: String = t.chars().take(32).collect();
    t.chars().count() > 32
        && head.split_whitespace().count() >= 1
        && head
            .bytes()
            .all(|b| b.is_ascii_digit() || b == b' ' || b == b'-')
        && t.chars().skip(32).any(|c| c.is_ascii_alphabetic())
}

/// Values per line and field width of a Fortran format such as `1P,3E23.16` or `(5E16.9)`.
fn value_format(f: &str) -> Option<(usize, usize)> {
    let u = f.to_ascii_uppercase();
    let at = u.find(['E', 'D'])?;
    let count: usize = u[..at]
        .rsplit(|c: char| !c.is_ascii_digit())
        .next()
        .filter(|s| !s.is_empty())
        .map_or(Some(1), |s| s.parse().ok())?;
    let width: usize = u[at + 1..]
        .split(|c: char| !c.is_ascii_digit())
        .next()?
        .parse()
        .ok()?;
    (count >= 1 && (1..=64).contains(&width)).then_some((count, width))
}

/// Matrix `name` (or the first) of an ASCII OUTPUT4 text read from `path`. Errors name the
/// file, line and what was wrong.
pub fn parse_op4(text: &str, path: &Path, name: Option<&str>) -> Result<Op4Matrix> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let lines: Vec<&str> = text.lines().map(|l| l.trim_end_matches('\r')).collect();
    let mut at = 0usize;
    let mut names = Vec::new();
    // Integers in I8 fields: separated by blanks, or touching when a number fills its field.
    let ints = |ln: usize, t: &str, want: usize| -> Result<Vec<i64>> {
        let split: Option<Vec<i64>> = t
            .split_whitespace()
            .map(|s| s.parse::<i64>().ok())
            .collect::<Option<Vec<i64>>>()
            .filter(|v| v.len() == want);
        let fixed = || -> Option<Vec<i64>> {
            let b = t.trim_end().as_bytes();
            if b.len() > 8 * want || !t.is_ascii() {
                return None;
            }
            (0..want)
                .map(|k| {
                    let f = &t[(8 * k).min(b.len())..(8 * k + 8).min(b.len())];
                    f.trim().parse::<i64>().ok()
                })
                .collect()
        };
        split
            .or_else(fixed)
            .ok_or_else(|| err(ln, format!("expected {want} integers, found {}", quoted(t))))
    };
    while at < lines.len() {
        if lines[at].trim().is_empty() {
            at += 1;
            continue;
        }
        // The header.
        let hl = at + 1;
        let h = lines[at];
        let head: String = h.chars().take(32).collect();
        let v = ints(hl, &head, 4).map_err(|_| {
            err(
                hl,
                format!(
                    "expected a matrix header (NCOL NROW FORM TYPE in 32 columns, the name, the \
                     format), found {}",
                    quoted(h)
                ),
            )
        })?;
        let (ncol, nrow, _form, ty) = (v[0], v[1], v[2], v[3]);
        let bigmat = nrow < 0;
        let mname: String = h
            .chars()
            .skip(32)
            .take(8)
            .collect::<String>()
            .trim()
            .to_string();
        let fmt: String = h.chars().skip(40).collect();
        let (per_line, width) = value_format(&fmt).ok_or_else(|| {
            err(
                hl,
                format!(
                    "value format {} is not a Fortran E or D format such as 1P,3E23.16",
                    quoted(fmt.trim())
                ),
            )
        })?;
        let n = nrow.unsigned_abs() as usize;
        if ncol < 1 || nrow == 0 || ncol.unsigned_abs() as usize != n {
            return Err(err(
                hl,
                format!("matrix {mname} is {n} × {ncol}: nlsim takes square matrices"),
            ));
        }
        if n > crate::formats::matrices::MAX_DIM {
            return Err(err(
                hl,
                format!(
                    "matrix {mname} declares {n} rows, more than {} DOFs",
                    crate::formats::matrices::MAX_DIM
                ),
            ));
        }
        if ty != 1 && ty != 2 {
            return Err(err(
                hl,
                format!(
                    "matrix {mname} has type {ty}: nlsim takes real matrices (1 single, 2 double \
                     precision)"
                ),
            ));
        }
        names.push(mname.clone());
        let wanted = name.is_none_or(|w| w.eq_ignore_ascii_case(&mname));
        at += 1;
        let mut entries = Vec::new();
        // Values of the value lines from `at` on, until an integer line or the end.
        let values = |at: &mut usize| -> Result<Vec<(f64, usize)>> {
            let mut out = Vec::new();
            while *at < lines.len() && value_line(lines[*at]) {
                let l = lines[*at];
                let ln = *at + 1;
                if !l.is_ascii() {
                    return Err(err(ln, "a non-ASCII character in a value line".into()));
                }
                let mut k = 0;
                while k < l.len() {
                    let f = l[k..(k + width).min(l.len())].trim();
                    k += width;
                    if f.is_empty() {
                        continue;
                    }
                    let v: f64 = f
                        .replace(['D', 'd'], "E")
                        .parse()
                        .ok()
                        .filter(|v: &f64| v.is_finite())
                        .ok_or_else(|| {
                            err(ln, format!("value {} is not a finite number", quoted(f)))
                        })?;
                    out.push((v, ln));
                }
                if l.trim().len() > per_line * width {
                    return Err(err(
                        ln,
                        format!("a value line wider than {per_line} fields of {width}"),
                    ));
                }
                *at += 1;
            }
            Ok(out)
        };
        loop {
            let Some(l) = lines.get(at) else {
                return Err(err(
                    lines.len(),
                    format!("matrix {mname} ends without its closing record (ICOL > NCOL)"),
                ));
            };
            let rl = at + 1;
            let r = ints(rl, l, 3)?;
            at += 1;
            let (icol, irow, nw) = (r[0], r[1], r[2]);
            if icol > ncol {
                // The closing record and its one value.
                values(&mut at)?;
                break;
            }
            if icol < 1 || irow < 0 || nw < 0 {
                return Err(err(
                    rl,
                    format!(
                        "column record {icol} {irow} {nw}: expected ICOL 1..={ncol}, IROW ≥ 0, NW ≥ 0"
                    ),
                ));
            }
            let col = (icol - 1) as usize;
            // A dense column stores every row from its first to its last nonzero: its zeros
            // are fill, not entries. A sparse string's zeros are stored entries (kept).
            let keep_zeros = irow == 0;
            let mut put = |row0: usize, vals: Vec<(f64, usize)>| -> Result<()> {
                for (k, (v, ln)) in vals.into_iter().enumerate() {
                    let row = row0 + k;
                    if row >= n {
                        return Err(err(
                            ln,
                            format!(
                                "column {icol}: row {} is past the matrix's {n} rows",
                                row + 1
                            ),
                        ));
                    }
                    if wanted && (keep_zeros || v != 0.0) {
                        entries.push((row, col, v, ln));
                    }
                }
                Ok(())
            };
            if irow > 0 {
                let vals = values(&mut at)?;
                let count = vals.len() as i64;
                if count != nw && !(ty == 2 && 2 * count == nw) {
                    return Err(err(
                        rl,
                        format!(
                            "column {icol}: NW = {nw} announces {} values, {count} follow",
                            if ty == 2 {
                                format!("{nw} or {}", nw / 2)
                            } else {
                                nw.to_string()
                            }
                        ),
                    ));
                }
                put((irow - 1) as usize, vals)?;
            } else {
                // Sparse strings until the next column record (three integers).
                while let Some(s) = lines.get(at) {
                    let t = s.trim();
                    let fields = t.split_whitespace().count();
                    if !integer_line(t) || fields == 3 {
                        break;
                    }
                    let sl = at + 1;
                    let row = if bigmat {
                        ints(sl, t, 2)?[1]
                    } else {
                        let is = ints(sl, t, 1)?[0];
                        if is < 65536 {
                            return Err(err(
                                sl,
                                format!("string header {is}: expected IROW + 65536·(L + 1)"),
                            ));
                        }
                        is % 65536
                    };
                    if row < 1 {
                        return Err(err(sl, format!("string starts at row {row}")));
                    }
                    at += 1;
                    let vals = values(&mut at)?;
                    if vals.is_empty() {
                        return Err(err(sl, "a string without values".into()));
                    }
                    put((row - 1) as usize, vals)?;
                }
            }
        }
        if wanted {
            return Ok(Op4Matrix {
                name: mname,
                n,
                entries,
            });
        }
    }
    Err(Error::Usage(format!(
        "{}: no OUTPUT4 matrix {} (matrices in the file: {})",
        path.display(),
        quoted(name.unwrap_or("")),
        if names.is_empty() {
            "none".into()
        } else {
            names.join(", ")
        }
    )))
}

#[cfg(test)]
mod tests {
    use super::*;

    const DENSE: &str = "       3       3       6       2KAAX    1P,3E23.16
       1       1       2
 2.0000000000000000E+00-1.0000000000000000E+00
       2       1       3
-1.0000000000000000E+00 2.0000000000000000E+00-1.0000000000000000E+00
       3       2       2
-1.0000000000000000E+00 1.0000000000000000E+00
       4       1       1
 1.0000000000000000E+00
";

    #[test]
    fn dense_and_sparse_give_the_same_entries() {
        let sparse = "       3       3       6       2KAAX    1P,3E23.16
       1       0       7
  458753
 2.0000000000000000E+00-1.0000000000000000E+00
       2       0       7
  458753
-1.0000000000000000E+00 2.0000000000000000E+00-1.0000000000000000E+00
       3       0       5
  327682
-1.0000000000000000E+00 1.0000000000000000E+00
       4       1       1
 1.0000000000000000E+00
";
        let big = "       3      -3       6       2KAAX    1P,3E23.16
       1       0       7
       3       1
 2.0000000000000000E+00-1.0000000000000000E+00
       2       0       7
       4       1
-1.0000000000000000E+00 2.0000000000000000E+00-1.0000000000000000E+00
       3       0       5
       3       2
-1.0000000000000000E+00 1.0000000000000000E+00
       4       1       1
 1.0000000000000000E+00
";
        let p = Path::new("k.op4");
        let want = parse_op4(DENSE, p, Some("kaax")).unwrap().entries;
        assert_eq!(want.len(), 7);
        assert_eq!((want[1].0, want[1].1, want[1].2), (1, 0, -1.0));
        for t in [sparse, big] {
            let got = parse_op4(t, p, None).unwrap();
            let strip = |v: &[(usize, usize, f64, usize)]| -> Vec<(usize, usize, f64)> {
                v.iter().map(|e| (e.0, e.1, e.2)).collect()
            };
            assert_eq!(strip(&got.entries), strip(&want), "{t}");
        }
    }

    #[test]
    fn bad_files_name_the_line() {
        let p = Path::new("k.op4");
        for (t, want) in [
            (
                DENSE.replace("       2       1       3\n", "       2       3       3\n"),
                "k.op4:5: column 2: row 4 is past".to_string(),
            ),
            (
                DENSE.replace("       3       2       2\n", "       3       2       5\n"),
                "k.op4:6: column 3: NW = 5".to_string(),
            ),
            (
                DENSE.replace("       4       1       1\n 1.0000000000000000E+00\n", ""),
                "ends without its closing record".to_string(),
            ),
            (DENSE.replace("2KAAX", "4KAAX"), "type 4".to_string()),
            (
                DENSE.replace("       3       3       6", "       399999999       6"),
                "nlsim takes square matrices".to_string(),
            ),
            (
                DENSE.replace("-1.0000000000000000E+00 1.0", "-1.00000000000000x0E+00 1.0"),
                "k.op4:7: value".to_string(),
            ),
        ] {
            let e = parse_op4(&t, p, None).unwrap_err().to_string();
            assert!(e.contains(&want), "{t}: {e}");
        }
        let e = parse_op4(DENSE, p, Some("MAAX")).unwrap_err().to_string();
        assert!(
            e.contains("no OUTPUT4 matrix 'MAAX' (matrices in the file: KAAX)"),
            "{e}"
        );
    }
}
