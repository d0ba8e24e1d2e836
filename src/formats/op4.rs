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
//! matrix's rows).
//!
//! The binary form (Fortran unformatted sequential records: a 4-byte length before and after
//! each record, either byte order, told from the header record's length 24) carries the same
//! records: the header (`NCOL NROW FORM TYPE` as 4-byte integers and the 8-byte name), then
//! per column `ICOL IROW NW` and `NW` 4-byte words of values (single precision: one word per
//! value; double: two). A sparse column's strings start with the word `IS = IROW + 65536·(L +
//! 1)` (L: the string's words) or, for bigmat (`NROW < 0` or ≥ 65 536), the two words `L + 1`
//! and `IROW`. [`crate::formats::op4_write::to_op4`] writes both forms for `nlsim export`.

use crate::error::{Error, Result};
use crate::formats::files::quoted;
use crate::formats::op4_binary::binary_layout;
pub use crate::formats::op4_binary::parse_op4_binary;
use crate::formats::op4_select::choose;
pub use crate::formats::op4_select::{MAX_OP4_BYTES, Op4Header, Op4Matrix, Op4Role};
use std::path::Path;

/// Reads the OUTPUT4 file `path` (ASCII or binary, told from the first record's length) and
/// returns matrix `name` (any case), or without a name the one `role` picks
/// ([`Op4Role`]).
pub fn read_op4(path: &Path, name: Option<&str>, role: Op4Role) -> Result<Op4Matrix> {
    let bytes = crate::formats::files::read_bytes_up_to(path, Some(MAX_OP4_BYTES))?;
    parse_op4_bytes(&bytes, path, name, role)
}

/// Matrix `name` (or the one `role` picks) of an OUTPUT4 file's bytes read from `path`,
/// ASCII or binary.
pub fn parse_op4_bytes(
    bytes: &[u8],
    path: &Path,
    name: Option<&str>,
    role: Op4Role,
) -> Result<Op4Matrix> {
    if binary_layout(bytes).is_some() {
        return parse_op4_binary(bytes, path, name, role);
    }
    let text = std::str::from_utf8(bytes).map_err(|_| {
        Error::Usage(format!(
            "{}: neither an ASCII OUTPUT4 file nor a binary one (whose first record is the \
             24- or 48-byte header)",
            path.display()
        ))
    })?;
    parse_op4(text, path, name, role)
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
    let b = t.as_bytes();
    b.len() > 32
        && b[..32].iter().any(|c| c.is_ascii_digit())
        && b[..32]
            .iter()
            .all(|&c| c.is_ascii_digit() || c == b' ' || c == b'-')
        && b[32..].iter().any(|c| c.is_ascii_alphabetic())
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

/// Matrix `name` (or the one `role` picks, [`Op4Role`]) of an ASCII OUTPUT4 text read from
/// `path`. The other matrices are skipped to the next header, whatever their shape, type or
/// form. Errors name the file, line and what was wrong.
pub fn parse_op4(text: &str, path: &Path, name: Option<&str>, role: Op4Role) -> Result<Op4Matrix> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let lines: Vec<&str> = text.lines().map(|l| l.trim_end_matches('\r')).collect();
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
    // The headers (with their value formats); each matrix runs to the next header line
    // (value lines hold a '.' in their first 32 columns, record lines are shorter, so
    // neither looks like one).
    let mut headers = Vec::new();
    let mut formats = Vec::new();
    let mut at = 0usize;
    while at < lines.len() {
        if lines[at].trim().is_empty() {
            at += 1;
            continue;
        }
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
        let mname: String = h
            .chars()
            .skip(32)
            .take(8)
            .collect::<String>()
            .trim()
            .to_string();
        let fmt: String = h.chars().skip(40).collect();
        headers.push(Op4Header {
            ncol: v[0],
            nrow: v[1],
            form: v[2],
            ty: v[3],
            name: mname,
            place: hl,
        });
        formats.push(fmt);
        at += 1;
        while at < lines.len() && !header_line(lines[at]) {
            at += 1;
        }
    }
    let chosen = choose(path, &headers, name, role, "line")?;
    let h = &headers[chosen];
    let (ncol, nrow, ty, hl) = (h.ncol, h.nrow, h.ty, h.place);
    let mname = h.name.clone();
    let fmt = &formats[chosen];
    let (per_line, width) = value_format(fmt).ok_or_else(|| {
        err(
            hl,
            format!(
                "value format {} is not a Fortran E or D format such as 1P,3E23.16",
                quoted(fmt.trim())
            ),
        )
    })?;
    if let Some(why) = h.refusal() {
        return Err(err(hl, why));
    }
    let bigmat = !(0..65536).contains(&nrow);
    let n = nrow.unsigned_abs() as usize;
    if n > crate::formats::matrices::MAX_DIM {
        return Err(err(
            hl,
            format!(
                "matrix {mname} declares {n} rows, more than {} DOFs",
                crate::formats::matrices::MAX_DIM
            ),
        ));
    }
    let mut at = hl;
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
                let v: f64 = crate::formats::fe_matrices::nastran_real(f).ok_or_else(|| {
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
                if keep_zeros || v != 0.0 {
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
                // The header: `IROW + 65536·(L + 1)`, or `L + 1` and `IROW` (bigmat),
                // with L the words of values that follow (Nastran: two per double).
                let (l, row) = if bigmat {
                    let v = ints(sl, t, 2)?;
                    (v[0] - 1, v[1])
                } else {
                    let is = ints(sl, t, 1)?[0];
                    if is < 65536 {
                        return Err(err(
                            sl,
                            format!("string header {is}: expected IROW + 65536·(L + 1)"),
                        ));
                    }
                    ((is >> 16) - 1, is % 65536)
                };
                if row < 1 {
                    return Err(err(sl, format!("string starts at row {row}")));
                }
                at += 1;
                let vals = values(&mut at)?;
                if vals.is_empty() {
                    return Err(err(sl, "a string without values".into()));
                }
                // Nastran's count, or pyNastran 1.4's (the column's words, NW − 1, in
                // every string header); any other is a damaged file.
                let words = vals.len() as i64 * if ty == 2 { 2 } else { 1 };
                if l != words && l != nw - 1 {
                    return Err(err(
                        sl,
                        format!(
                            "column {icol}: the string header announces {l} words, {} \
                                 values ({words} words) follow",
                            vals.len()
                        ),
                    ));
                }
                put((row - 1) as usize, vals)?;
            }
        }
    }
    Ok(Op4Matrix {
        name: mname,
        n,
        entries,
        binary: false,
    })
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
       1       0       6
       5       1
 2.0000000000000000E+00-1.0000000000000000E+00
       2       0       8
       7       1
-1.0000000000000000E+00 2.0000000000000000E+00-1.0000000000000000E+00
       3       0       6
       5       2
-1.0000000000000000E+00 1.0000000000000000E+00
       4       1       1
 1.0000000000000000E+00
";
        let p = Path::new("k.op4");
        // A string header whose L is neither Nastran's count nor pyNastran's.
        let e = parse_op4(
            &sparse.replace("  458753\n", "  393217\n"),
            p,
            None,
            Op4Role::Any,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains(
                "k.op4:3: column 1: the string header announces 5 words, 2 values (4 words)"
            ),
            "{e}"
        );
        let want = parse_op4(DENSE, p, Some("kaax"), Op4Role::Any)
            .unwrap()
            .entries;
        assert_eq!(want.len(), 7);
        assert_eq!((want[1].0, want[1].1, want[1].2), (1, 0, -1.0));
        for t in [sparse, big] {
            let got = parse_op4(t, p, None, Op4Role::Stiffness).unwrap();
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
            let e = parse_op4(&t, p, None, Op4Role::Stiffness)
                .unwrap_err()
                .to_string();
            assert!(e.contains(&want), "{t}: {e}");
        }
        let e = parse_op4(DENSE, p, Some("MAAX"), Op4Role::Mass)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("no OUTPUT4 matrix 'MAAX' (matrices in the file: KAAX)"),
            "{e}"
        );
    }

    #[test]
    fn single_precision_and_dense_binary_columns() {
        // A hand-made little-endian single-precision file, dense columns (fill zero dropped).
        let mut f = Vec::new();
        let rec = |f: &mut Vec<u8>, words: &[[u8; 4]]| {
            let len = (4 * words.len() as u32).to_le_bytes();
            f.extend_from_slice(&len);
            for w in words {
                f.extend_from_slice(w);
            }
            f.extend_from_slice(&len);
        };
        let i = |x: i32| x.to_le_bytes();
        let r = |x: f32| x.to_le_bytes();
        rec(&mut f, &[i(2), i(2), i(6), i(1), *b"K   ", *b"    "]);
        rec(&mut f, &[i(1), i(1), i(2), r(2.5), r(0.0)]);
        rec(&mut f, &[i(2), i(2), i(1), r(0.75)]);
        rec(&mut f, &[i(3), i(1), i(1), r(1.0)]);
        let m = parse_op4_binary(&f, Path::new("k.op4"), None, Op4Role::Stiffness).unwrap();
        assert_eq!(m.name, "K");
        let got: Vec<_> = m.entries.iter().map(|e| (e.0, e.1, e.2, e.3)).collect();
        assert_eq!(got, vec![(0, 0, 2.5, 2), (1, 1, 0.75, 3)]);
    }
}
