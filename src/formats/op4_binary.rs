//! Nastran OUTPUT4 in the binary form: Fortran unformatted sequential records (a 4-byte
//! length before and after each), either byte order, with 4-byte words or the 64-bit-word
//! variant of MSC Nastran's 64-bit builds (a 48-byte header). The layout is told from the
//! first record's length; [`crate::formats::op4`] documents the records.

use crate::error::{Error, Result};
use crate::formats::files::quoted;
use crate::formats::op4_select::{Op4Header, Op4Matrix, Op4Role, choose};
use std::path::Path;

/// The layout of a binary OUTPUT4 file from its first record's length: `Some((true, 4))`
/// little-endian with 4-byte words (a 24-byte header), `(_, 8)` the 64-bit-word variant (a
/// 48-byte header); `None` for text.
pub(crate) fn binary_layout(bytes: &[u8]) -> Option<(bool, usize)> {
    let head: [u8; 4] = bytes.get(..4)?.try_into().ok()?;
    let (le, be) = (u32::from_le_bytes(head), u32::from_be_bytes(head));
    match (le, be) {
        (24, _) => Some((true, 4)),
        (48, _) => Some((true, 8)),
        (_, 24) => Some((false, 4)),
        (_, 48) => Some((false, 8)),
        _ => None,
    }
}

/// Matrix `name` (or the one `role` picks, [`Op4Role`]) of a binary OUTPUT4 file's bytes
/// read from `path`: 4-byte words or the 64-bit-word variant (8-byte integers and values),
/// either byte order. The other matrices are skipped by their records, whatever their shape,
/// type or form. The closing record (`ICOL > NCOL`) is taken whatever it holds (Nastran
/// versions differ: one word, or a double announced as one word). The entries' `place` is
/// the 1-based record number; errors name the file, the record and its byte offset.
pub fn parse_op4_binary(
    bytes: &[u8],
    path: &Path,
    name: Option<&str>,
    role: Op4Role,
) -> Result<Op4Matrix> {
    let (little, w) = binary_layout(bytes).ok_or_else(|| {
        Error::Usage(format!(
            "{}: not a binary OUTPUT4 file (its first record is not the 24- or 48-byte header)",
            path.display()
        ))
    })?;
    let records = binary_records(bytes, path, little)?;
    let int = |b: &[u8]| -> i64 {
        if w == 4 {
            let a: [u8; 4] = [b[0], b[1], b[2], b[3]];
            i64::from(if little {
                i32::from_le_bytes(a)
            } else {
                i32::from_be_bytes(a)
            })
        } else {
            let a: [u8; 8] = b[..8].try_into().expect("8 bytes");
            if little {
                i64::from_le_bytes(a)
            } else {
                i64::from_be_bytes(a)
            }
        }
    };
    let err = |record: usize, offset: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line: record,
        message: format!("record {record} (byte {offset}): {m}"),
    };
    // The headers and the range of records of each matrix (header, then its columns to the
    // closing record).
    let mut headers = Vec::new();
    let mut spans = Vec::new();
    let mut k = 0;
    while k < records.len() {
        let (hr, ho, h) = records[k];
        if h.len() != 6 * w {
            return Err(err(
                hr,
                ho,
                format!(
                    "expected a matrix header of {} bytes (NCOL NROW FORM TYPE NAME), found {}",
                    6 * w,
                    h.len()
                ),
            ));
        }
        let header = Op4Header {
            ncol: int(&h[0..]),
            nrow: int(&h[w..]),
            form: int(&h[2 * w..]),
            ty: int(&h[3 * w..]),
            // Eight characters in two words: with 8-byte words each holds four characters
            // and four blanks.
            name: if w == 4 {
                String::from_utf8_lossy(&h[16..24]).trim().to_string()
            } else {
                format!(
                    "{}{}",
                    String::from_utf8_lossy(&h[32..36]),
                    String::from_utf8_lossy(&h[40..44])
                )
                .trim()
                .to_string()
            },
            place: hr,
        };
        let first = k + 1;
        k = first;
        loop {
            let Some(&(r, o, c)) = records.get(k) else {
                let n = header.nrow.unsigned_abs();
                let size = if n > crate::formats::matrices::MAX_DIM as u64 {
                    format!(
                        " (it declares {n} rows, more than {} DOFs)",
                        crate::formats::matrices::MAX_DIM
                    )
                } else {
                    String::new()
                };
                return Err(err(
                    hr,
                    ho,
                    format!(
                        "matrix {} (its header here) ends without its closing record (ICOL > \
                         NCOL): truncated{size}",
                        header.name
                    ),
                ));
            };
            if c.len() < 3 * w {
                return Err(err(
                    r,
                    o,
                    format!(
                        "a column record of {} bytes: expected ICOL IROW NW and NW words",
                        c.len()
                    ),
                ));
            }
            k += 1;
            if int(c) > header.ncol {
                break;
            }
        }
        spans.push(first..k - 1);
        headers.push(header);
    }
    let chosen = choose(path, &headers, name, role, "record")?;
    let h = &headers[chosen];
    if let Some(why) = h.refusal() {
        let (_, o, _) = records[h.place - 1];
        return Err(err(h.place, o, why));
    }
    let n = h.nrow.unsigned_abs() as usize;
    if n > crate::formats::matrices::MAX_DIM {
        let (_, o, _) = records[h.place - 1];
        return Err(err(
            h.place,
            o,
            format!(
                "matrix {} declares {n} rows, more than {} DOFs",
                quoted(&h.name),
                crate::formats::matrices::MAX_DIM
            ),
        ));
    }
    // A value: single precision takes one word (a float, or a double in 8-byte words),
    // double precision 8 bytes (two words, or one).
    let vbytes = if h.ty == 1 { w } else { 8 };
    let value = |b: &[u8]| -> f64 {
        if vbytes == 4 {
            let a: [u8; 4] = [b[0], b[1], b[2], b[3]];
            f64::from(f32::from_bits(if little {
                u32::from_le_bytes(a)
            } else {
                u32::from_be_bytes(a)
            }))
        } else {
            let a: [u8; 8] = b[..8].try_into().expect("8 bytes");
            if little {
                f64::from_le_bytes(a)
            } else {
                f64::from_be_bytes(a)
            }
        }
    };
    let bigmat = h.nrow < 0 || n >= 65536;
    let ncol = h.ncol;
    let mut entries = Vec::new();
    for &(r, o, c) in &records[spans[chosen].clone()] {
        let (icol, irow, nw) = (int(c), int(&c[w..]), int(&c[2 * w..]));
        let words = &c[3 * w..];
        if nw < 0 || nw as usize != words.len() / w || words.len() % w != 0 {
            return Err(err(
                r,
                o,
                format!(
                    "column record {icol}: NW = {nw} words announced, the record holds {}",
                    words.len() / w
                ),
            ));
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
            if !vals.len().is_multiple_of(vbytes) {
                return Err(err(
                    r,
                    o,
                    format!(
                        "column {icol}: {} bytes do not make whole values of {vbytes} bytes",
                        vals.len()
                    ),
                ));
            }
            for (k, b) in vals.chunks_exact(vbytes).enumerate() {
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
                let v = value(b);
                if !v.is_finite() {
                    return Err(err(
                        r,
                        o,
                        format!("column {icol}, row {}: value {v} is not finite", row + 1),
                    ));
                }
                if keep_zeros || v != 0.0 {
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
            let head = if bigmat { 2 * w } else { w };
            if k + head > words.len() {
                return Err(err(
                    r,
                    o,
                    format!("column {icol}: a string header cut off by the record's end"),
                ));
            }
            let (l, row) = if bigmat {
                (int(&words[k..]) - 1, int(&words[k + w..]))
            } else {
                let is = int(&words[k..]);
                ((is >> 16) - 1, is & 0xffff)
            };
            if l < 1 || row < 1 {
                return Err(err(
                    r,
                    o,
                    format!(
                        "column {icol}: a string of {l} words at row {row} (expected at least \
                         one word from row 1 on)"
                    ),
                ));
            }
            k += head;
            let end = usize::try_from(l)
                .ok()
                .and_then(|l| l.checked_mul(w))
                .and_then(|b| k.checked_add(b))
                .filter(|&e| e <= words.len())
                .ok_or_else(|| {
                    err(
                        r,
                        o,
                        format!("column {icol}: a string of {l} words runs past the record's end"),
                    )
                })?;
            put((row - 1) as usize, &words[k..end], true)?;
            k = end;
        }
    }
    Ok(Op4Matrix {
        name: h.name.clone(),
        n,
        entries,
        binary: true,
    })
}

/// The Fortran records of a binary OUTPUT4 file: `(1-based number, byte offset, payload)`,
/// each checked for its opening and closing lengths (4-byte markers in every variant).
fn binary_records<'a>(
    bytes: &'a [u8],
    path: &Path,
    little: bool,
) -> Result<Vec<(usize, usize, &'a [u8])>> {
    let err = |record: usize, offset: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line: record,
        message: format!("record {record} (byte {offset}): {m}"),
    };
    let len_at = |at: usize| -> Option<usize> {
        let a: [u8; 4] = bytes.get(at..at + 4)?.try_into().ok()?;
        let l = if little {
            i32::from_le_bytes(a)
        } else {
            i32::from_be_bytes(a)
        };
        usize::try_from(l).ok()
    };
    let mut out = Vec::new();
    let mut at = 0usize;
    while at < bytes.len() {
        let record = out.len() + 1;
        let len = len_at(at).ok_or_else(|| {
            err(
                record,
                at,
                "a record length that is cut off or negative".into(),
            )
        })?;
        let end = at
            .checked_add(4 + len)
            .filter(|&e| e + 4 <= bytes.len())
            .ok_or_else(|| {
                err(
                    record,
                    at,
                    format!(
                        "the record declares {len} bytes, the file has {} left: truncated",
                        bytes.len() - at - 4
                    ),
                )
            })?;
        if len_at(end) != Some(len) {
            return Err(err(
                record,
                at,
                format!("the record's closing length differs from its opening one ({len})"),
            ));
        }
        out.push((record, at, &bytes[at + 4..end]));
        at = end + 4;
    }
    Ok(out)
}
