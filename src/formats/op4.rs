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

/// Reads matrix `name` (the first of the file when `None`) of the OUTPUT4 file `path`, ASCII
/// or binary (told from the first record's length).
pub fn read_op4(path: &Path, name: Option<&str>) -> Result<Op4Matrix> {
    let bytes = crate::formats::files::read_bytes_up_to(path, Some(MAX_OP4_BYTES))?;
    parse_op4_bytes(&bytes, path, name)
}

/// Matrix `name` (the first when `None`) of an OUTPUT4 file's bytes read from `path`, ASCII
/// or binary (told from the first record's length).
pub fn parse_op4_bytes(bytes: &[u8], path: &Path, name: Option<&str>) -> Result<Op4Matrix> {
    if binary_order(bytes).is_some() {
        return parse_op4_binary(bytes, path, name);
    }
    let text = std::str::from_utf8(bytes).map_err(|_| {
        Error::Usage(format!(
            "{}: neither an ASCII OUTPUT4 file nor a binary one (whose first record is the \
             24-byte header)",
            path.display()
        ))
    })?;
    parse_op4(text, path, name)
}

/// The byte order of a binary OUTPUT4 file (`Some(true)`: little-endian), from its first
/// record's length (24 bytes; 48 for the 64-bit-word variant, refused by the parser with its
/// own message), or `None` for text.
fn binary_order(bytes: &[u8]) -> Option<bool> {
    let head: [u8; 4] = bytes.get(..4)?.try_into().ok()?;
    let (le, be) = (u32::from_le_bytes(head), u32::from_be_bytes(head));
    if le == 24 || le == 48 {
        Some(true)
    } else if be == 24 || be == 48 {
        Some(false)
    } else {
        None
    }
}

/// Matrix `name` (or the first) of a binary OUTPUT4 file's bytes read from `path`. The entries'
/// `line` is the 1-based record number; errors name the file, the record and its byte offset.
pub fn parse_op4_binary(bytes: &[u8], path: &Path, name: Option<&str>) -> Result<Op4Matrix> {
    let little = binary_order(bytes).ok_or_else(|| {
        Error::Usage(format!(
            "{}: not a binary OUTPUT4 file (its first record is not the 24-byte header)",
            path.display()
        ))
    })?;
    let word = |b: &[u8]| -> i32 {
        let a: [u8; 4] = [b[0], b[1], b[2], b[3]];
        if little {
            i32::from_le_bytes(a)
        } else {
            i32::from_be_bytes(a)
        }
    };
    // A content error: exit code 1, as the same error in the ASCII form (the "line" is the
    // record's number).
    let err = |record: usize, offset: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line: record,
        message: format!("record {record} (byte {offset}): {m}"),
    };
    // The records: (1-based number, byte offset, payload).
    let mut at = 0usize;
    let mut record = 0usize;
    let mut next = || -> Result<Option<(usize, usize, &[u8])>> {
        if at == bytes.len() {
            return Ok(None);
        }
        record += 1;
        let start = at;
        let len_of = |at: usize| -> Option<usize> {
            bytes
                .get(at..at + 4)
                .map(&word)
                .and_then(|l| usize::try_from(l).ok())
        };
        let len = len_of(at).ok_or_else(|| {
            err(
                record,
                start,
                "a record length that is cut off or negative".into(),
            )
        })?;
        let end = at
            .checked_add(4 + len)
            .filter(|&e| e + 4 <= bytes.len())
            .ok_or_else(|| {
                err(
                    record,
                    start,
                    format!(
                        "the record declares {len} bytes, the file has {} left: truncated",
                        bytes.len() - at - 4
                    ),
                )
            })?;
        if len_of(end) != Some(len) {
            return Err(err(
                record,
                start,
                format!("the record's closing length differs from its opening one ({len})"),
            ));
        }
        at = end + 4;
        Ok(Some((record, start, &bytes[start + 4..end])))
    };
    let mut names = Vec::new();
    while let Some((hr, ho, h)) = next()? {
        if h.len() == 48 {
            return Err(err(
                hr,
                ho,
                "a header of 64-bit words (written with 8-byte integers): nlsim reads the \
                 usual 4-byte-word OUTPUT4; write it without the 64-bit option"
                    .into(),
            ));
        }
        if h.len() != 24 {
            return Err(err(
                hr,
                ho,
                format!(
                    "expected a matrix header of 24 bytes (NCOL NROW FORM TYPE NAME), found {}",
                    h.len()
                ),
            ));
        }
        let (ncol, nrow, ty) = (word(&h[0..]), word(&h[4..]), word(&h[12..]));
        let mname = String::from_utf8_lossy(&h[16..24]).trim().to_string();
        let n = nrow.unsigned_abs() as usize;
        if ncol < 1 || nrow == 0 || ncol.unsigned_abs() as usize != n {
            return Err(err(
                hr,
                ho,
                format!(
                    "matrix {} is {n} × {ncol}: nlsim takes square matrices",
                    quoted(&mname)
                ),
            ));
        }
        if n > crate::formats::matrices::MAX_DIM {
            return Err(err(
                hr,
                ho,
                format!(
                    "matrix {} declares {n} rows, more than {} DOFs",
                    quoted(&mname),
                    crate::formats::matrices::MAX_DIM
                ),
            ));
        }
        let wper = match ty {
            1 => 1usize,
            2 => 2,
            _ => {
                return Err(err(
                    hr,
                    ho,
                    format!(
                        "matrix {} has type {ty}: nlsim takes real matrices (1 single, 2 double \
                         precision)",
                        quoted(&mname)
                    ),
                ));
            }
        };
        let bigmat = nrow < 0 || n >= 65536;
        names.push(mname.clone());
        let wanted = name.is_none_or(|w| w.eq_ignore_ascii_case(&mname));
        let value = |w: &[u8]| -> f64 {
            if wper == 1 {
                f32::from_bits(word(w) as u32) as f64
            } else {
                let a: [u8; 8] = w[..8].try_into().expect("8 bytes");
                if little {
                    f64::from_le_bytes(a)
                } else {
                    f64::from_be_bytes(a)
                }
            }
        };
        let mut entries = Vec::new();
        loop {
            let Some((r, o, c)) = next()? else {
                return Err(err(
                    hr,
                    ho,
                    format!(
                        "matrix {mname} (its header here) ends without its closing record \
                         (ICOL > NCOL): truncated"
                    ),
                ));
            };
            if c.len() < 12 || c.len() % 4 != 0 {
                return Err(err(
                    r,
                    o,
                    format!(
                        "a column record of {} bytes: expected ICOL IROW NW and NW words",
                        c.len()
                    ),
                ));
            }
            let (icol, irow, nw) = (word(&c[0..]), word(&c[4..]), word(&c[8..]));
            let words = &c[12..];
            if nw < 0 || nw as usize != words.len() / 4 {
                return Err(err(
                    r,
                    o,
                    format!(
                        "column record {icol}: NW = {nw} words announced, the record holds {}",
                        words.len() / 4
                    ),
                ));
            }
            if icol > ncol {
                break;
            }
            if icol < 1 || irow < 0 {
                return Err(err(
                    r,
                    o,
                    format!("column record {icol} {irow} {nw}: expected ICOL 1..={ncol}, IROW ≥ 0"),
                ));
            }
            let col = (icol - 1) as usize;
            let mut put = |row0: usize, vals: &[u8], keep_zeros: bool| -> Result<()> {
                if !vals.len().is_multiple_of(4 * wper) {
                    return Err(err(
                        r,
                        o,
                        format!(
                            "column {icol}: {} words do not make whole values of {wper} words",
                            vals.len() / 4
                        ),
                    ));
                }
                for (k, w) in vals.chunks_exact(4 * wper).enumerate() {
                    let row = row0 + k;
                    if row >= n {
                        return Err(err(
                            r,
                            o,
                            format!(
                                "column {icol}: row {} is past the matrix's {n} rows",
                                row + 1
                            ),
                        ));
                    }
                    let v = value(w);
                    if !v.is_finite() {
                        return Err(err(
                            r,
                            o,
                            format!("column {icol}, row {}: value {v} is not finite", row + 1),
                        ));
                    }
                    if wanted && (keep_zeros || v != 0.0) {
                        entries.push((row, col, v, r));
                    }
                }
                Ok(())
            };
            if irow > 0 {
                // Dense: the zeros between the first and last nonzero rows are fill.
                put((irow - 1) as usize, words, false)?;
                continue;
            }
            let mut k = 0usize;
            while k < words.len() {
                let head = if bigmat { 8 } else { 4 };
                if k + head > words.len() {
                    return Err(err(
                        r,
                        o,
                        format!("column {icol}: a string header cut off by the record's end"),
                    ));
                }
                let (l, row) = if bigmat {
                    (
                        i64::from(word(&words[k..])) - 1,
                        i64::from(word(&words[k + 4..])),
                    )
                } else {
                    let is = i64::from(word(&words[k..]));
                    ((is >> 16) - 1, is & 0xffff)
                };
                if l < 1 || row < 1 {
                    return Err(err(
                        r,
                        o,
                        format!(
                            "column {icol}: a string of {l} words at row {row} (expected at \
                             least one word from row 1 on)"
                        ),
                    ));
                }
                k += head;
                let end = k
                    .checked_add(4 * l as usize)
                    .filter(|&e| e <= words.len())
                    .ok_or_else(|| {
                        err(
                            r,
                            o,
                            format!(
                                "column {icol}: a string of {l} words runs past the record's \
                                 end"
                            ),
                        )
                    })?;
                put((row - 1) as usize, &words[k..end], true)?;
                k = end;
            }
        }
        if wanted {
            return Ok(Op4Matrix {
                name: mname,
                n,
                entries,
                binary: false,
            });
        }
    }
    Err(not_found(path, name, &names))
}

/// The error for a matrix `name` that is not among `names`, the matrices of the file.
fn not_found(path: &Path, name: Option<&str>, names: &[String]) -> Error {
    Error::Usage(format!(
        "{}: no OUTPUT4 matrix {} (matrices in the file: {})",
        path.display(),
        quoted(name.unwrap_or("")),
        if names.is_empty() {
            "none".into()
        } else {
            names.join(", ")
        }
    ))
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
        let bigmat = !(0..65536).contains(&nrow);
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
        if !wanted {
            // Another matrix: skipped unparsed to the next header (value lines hold a '.'
            // in their first 32 columns, record lines are shorter, so neither looks like one).
            while at < lines.len() && !header_line(lines[at]) {
                at += 1;
            }
            continue;
        }
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
                    // The string's length L in its header is not checked against the values
                    // that follow: writers count it differently (pyNastran's files and
                    // nlsim's own disagree); see issue 73 for real files.
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
                binary: true,
            });
        }
    }
    Err(not_found(path, name, &names))
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
        let m = parse_op4_binary(&f, Path::new("k.op4"), None).unwrap();
        assert_eq!(m.name, "K");
        let got: Vec<_> = m.entries.iter().map(|e| (e.0, e.1, e.2, e.3)).collect();
        assert_eq!(got, vec![(0, 0, 2.5, 2), (1, 1, 0.75, 3)]);
    }
}
