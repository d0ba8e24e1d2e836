//! Nastran OUTPUT4 files written: [`to_op4`], ASCII or binary (either byte order), the form
//! `nlsim export --op4` writes and Nastran's `INPUTT4` and pyNastran read back.

use nlsim_kernel::SparseSym;

/// How [`to_op4`] writes an OUTPUT4 file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Op4Layout {
    /// ASCII, values as `1P,3E25.16` (17 significant digits: every value to the bit).
    Ascii,
    /// Binary, little-endian (x86, ARM).
    BinaryLittleEndian,
    /// Binary, big-endian (older Unix workstations).
    BinaryBigEndian,
}

impl Op4Layout {
    /// The layout of a name: `ascii`, `binary` (little-endian), `binary-le`, `binary-be`.
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "ascii" | "text" => Some(Op4Layout::Ascii),
            "binary" | "binary-le" | "little-endian" => Some(Op4Layout::BinaryLittleEndian),
            "binary-be" | "big-endian" => Some(Op4Layout::BinaryBigEndian),
            _ => None,
        }
    }
}

/// A value in a Fortran `E25.16` field: 17 significant digits and a signed exponent of at
/// least two digits (`-1.2345678901234567E+308`).
fn fortran_e(v: f64) -> String {
    let s = format!("{v:.16E}");
    let (mantissa, exp) = s.split_once('E').unwrap_or((&s, "0"));
    let e: i32 = exp.parse().unwrap_or(0);
    let sign = if e < 0 { '-' } else { '+' };
    format!(
        "{:>25}",
        format!("{mantissa}E{sign}{:02}", e.unsigned_abs())
    )
}

/// The runs of consecutive rows of a column's sorted row indices: (first index, count).
fn runs(rows: &[usize]) -> Vec<(usize, usize)> {
    let mut out: Vec<(usize, usize)> = Vec::new();
    for (k, &r) in rows.iter().enumerate() {
        match out.last_mut() {
            Some((s, c)) if rows[*s] + *c == r => *c += 1,
            _ => out.push((k, 1)),
        }
    }
    out
}

/// The symmetric matrices `matrices` (name, matrix; names of up to 8 characters) as one
/// OUTPUT4 file: square symmetric form (6), real double precision (type 2), both triangles
/// stored in sparse strings of consecutive rows (bigmat with `NROW < 0` from 65 536 rows on),
/// as Nastran writes `OUTPUT4 ... /-1/-2` (binary) or `/-1/2` (ASCII). The upper triangle is
/// the lower one mirrored, so the file is symmetric to the bit and equals the lower triangle
/// that `nlsim export` writes to Matrix Market.
pub fn to_op4(matrices: &[(&str, &SparseSym)], layout: Op4Layout) -> Vec<u8> {
    use std::fmt::Write as _;
    let little = layout == Op4Layout::BinaryLittleEndian;
    let mut out: Vec<u8> = Vec::new();
    let int = |x: i32| -> [u8; 4] {
        if little {
            x.to_le_bytes()
        } else {
            x.to_be_bytes()
        }
    };
    let real = |x: f64| -> [u8; 8] {
        if little {
            x.to_le_bytes()
        } else {
            x.to_be_bytes()
        }
    };
    // One binary record: its length, the payload, its length again.
    let record = |out: &mut Vec<u8>, payload: &[u8]| {
        let len = int(payload.len() as i32);
        out.extend_from_slice(&len);
        out.extend_from_slice(payload);
        out.extend_from_slice(&len);
    };
    for &(name, a) in matrices {
        let n = a.n();
        // Bigmat from 65 536 rows on, or when a string is too long for the one-word header.
        let longest = (0..n)
            .flat_map(|j| runs(a.col(j).0))
            .map(|(_, c)| c)
            .max()
            .unwrap_or(0);
        let bigmat = n >= 65536 || ((2 * longest + 1) << 16) + n > i32::MAX as usize;
        let nrow = if bigmat { -(n as i32) } else { n as i32 };
        let name8 = format!("{:<8}", name.chars().take(8).collect::<String>());
        if layout == Op4Layout::Ascii {
            let mut t = String::new();
            let _ = writeln!(t, "{n:8}{nrow:8}{:8}{:8}{name8}1P,3E25.16", 6, 2);
            out.extend_from_slice(t.as_bytes());
        } else {
            let mut h = Vec::with_capacity(24);
            for x in [n as i32, nrow, 6, 2] {
                h.extend_from_slice(&int(x));
            }
            h.extend_from_slice(name8.as_bytes());
            record(&mut out, &h);
        }
        for j in 0..n {
            let (rows, stored) = a.col(j);
            if rows.is_empty() {
                continue;
            }
            let vals: Vec<f64> = rows
                .iter()
                .zip(stored)
                .map(|(&i, &v)| if i < j { a.get(j, i) } else { v })
                .collect();
            let strings = runs(rows);
            let head = if bigmat { 2 } else { 1 };
            let nw: usize = strings.iter().map(|&(_, c)| head + 2 * c).sum();
            if layout == Op4Layout::Ascii {
                let mut t = String::new();
                let _ = writeln!(t, "{:8}{:8}{nw:8}", j + 1, 0);
                for &(s, c) in &strings {
                    let (row, l) = (rows[s] + 1, 2 * c);
                    if bigmat {
                        let _ = writeln!(t, "{:8}{row:8}", l + 1);
                    } else {
                        let _ = writeln!(t, "{:8}", row + ((l + 1) << 16));
                    }
                    for chunk in vals[s..s + c].chunks(3) {
                        for &v in chunk {
                            t.push_str(&fortran_e(v));
                        }
                        t.push('\n');
                    }
                }
                out.extend_from_slice(t.as_bytes());
            } else {
                let mut p = Vec::with_capacity(12 + 4 * nw);
                for x in [(j + 1) as i32, 0, nw as i32] {
                    p.extend_from_slice(&int(x));
                }
                for &(s, c) in &strings {
                    let (row, l) = (rows[s] + 1, 2 * c);
                    if bigmat {
                        p.extend_from_slice(&int(l as i32 + 1));
                        p.extend_from_slice(&int(row as i32));
                    } else {
                        p.extend_from_slice(&int((row + ((l + 1) << 16)) as i32));
                    }
                    for &v in &vals[s..s + c] {
                        p.extend_from_slice(&real(v));
                    }
                }
                record(&mut out, &p);
            }
        }
        // The closing record: column NCOL + 1 with one value.
        if layout == Op4Layout::Ascii {
            let mut t = String::new();
            let _ = writeln!(t, "{:8}{:8}{:8}", n + 1, 1, 2);
            t.push_str(&fortran_e(1.0));
            t.push('\n');
            out.extend_from_slice(t.as_bytes());
        } else {
            let mut p = Vec::with_capacity(20);
            for x in [n as i32 + 1, 1, 2] {
                p.extend_from_slice(&int(x));
            }
            p.extend_from_slice(&real(1.0));
            record(&mut out, &p);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::op4::{Op4Role, parse_op4_binary, parse_op4_bytes};
    use std::path::Path;

    fn sample() -> SparseSym {
        // A 5 × 5 symmetric matrix with gaps in its columns (several strings per column).
        let lower = [
            (0, 0, 4.0),
            (1, 0, -1.25e-300),
            (3, 0, 0.1),
            (1, 1, 1.0 / 3.0),
            (4, 1, -7.5e250),
            (2, 2, 2.0),
            (3, 2, -1.0),
            (4, 2, 3.0),
            (3, 3, 5.0),
            (4, 4, 6.0),
        ];
        SparseSym::from_lower_triplets("A", 5, &lower).unwrap()
    }

    fn both(a: &SparseSym) -> Vec<(usize, usize, u64)> {
        let mut v: Vec<_> = a.entries().map(|(i, j, x)| (i, j, x.to_bits())).collect();
        v.sort();
        v
    }

    fn read_back(bytes: &[u8], name: &str) -> Vec<(usize, usize, u64)> {
        let p = Path::new("a.op4");
        let m = parse_op4_bytes(bytes, p, Some(name), Op4Role::Any).unwrap();
        let mut v: Vec<_> = m
            .entries
            .iter()
            .map(|e| (e.0, e.1, e.2.to_bits()))
            .collect();
        v.sort();
        v
    }

    #[test]
    fn written_files_read_back_to_the_bit_in_every_layout() {
        let a = sample();
        let b = a.scaled(-2.0);
        for layout in [
            Op4Layout::Ascii,
            Op4Layout::BinaryLittleEndian,
            Op4Layout::BinaryBigEndian,
        ] {
            let bytes = to_op4(&[("KAAX", &a), ("MAAX", &b)], layout);
            assert_eq!(read_back(&bytes, "KAAX"), both(&a), "{layout:?}");
            assert_eq!(read_back(&bytes, "maax"), both(&b), "{layout:?}");
        }
        // Bigmat from 65 536 rows on: a diagonal with one coupling at the far end.
        let n = 65_540;
        let mut lower: Vec<(usize, usize, f64)> = (0..n).map(|i| (i, i, 1.0 + i as f64)).collect();
        lower.push((n - 1, 0, 0.5));
        let big = SparseSym::from_lower_triplets("B", n, &lower).unwrap();
        for layout in [Op4Layout::Ascii, Op4Layout::BinaryBigEndian] {
            let bytes = to_op4(&[("KAAX", &big)], layout);
            assert_eq!(read_back(&bytes, "KAAX"), both(&big), "{layout:?}");
        }
    }

    #[test]
    fn bad_binary_files_name_the_record() {
        let a = sample();
        let good = to_op4(&[("KAAX", &a)], Op4Layout::BinaryLittleEndian);
        let p = Path::new("k.op4");
        let e = |b: &[u8]| {
            parse_op4_binary(b, p, None, Op4Role::Stiffness)
                .unwrap_err()
                .to_string()
        };
        // Truncated inside the third record.
        let cut = &good[..good.len() - 30];
        assert!(e(cut).contains("truncated"), "{}", e(cut));
        // The header's closing length changed.
        let mut b = good.clone();
        b[28] = 99;
        assert!(
            e(&b).contains("record 1 (byte 0): the record's closing length"),
            "{}",
            e(&b)
        );
        // NW of the first column record one word too many.
        let mut b = good.clone();
        let nw = i32::from_le_bytes(b[44..48].try_into().unwrap());
        b[44..48].copy_from_slice(&(nw + 1).to_le_bytes());
        assert!(
            e(&b).contains("record 2 (byte 32): column record 1: NW"),
            "{}",
            e(&b)
        );
        // A string header pointing past the last row (row 1 → 9).
        let mut b = good.clone();
        let is = i32::from_le_bytes(b[48..52].try_into().unwrap());
        b[48..52].copy_from_slice(&(is + 8).to_le_bytes());
        assert!(
            e(&b).contains("row 9 is past the matrix's 5 rows"),
            "{}",
            e(&b)
        );
        // A size of 2·10⁹ rows.
        let mut b = good.clone();
        b[4..8].copy_from_slice(&2_000_000_000i32.to_le_bytes());
        b[8..12].copy_from_slice(&2_000_000_000i32.to_le_bytes());
        assert!(e(&b).contains("declares 2000000000 rows"), "{}", e(&b));
        // A 64-bit-word header alone (the variant is read; here its columns are missing).
        let mut b = vec![48, 0, 0, 0];
        b.extend_from_slice(&[0; 48]);
        b.extend_from_slice(&[48, 0, 0, 0]);
        assert!(
            e(&b).contains("ends without its closing record"),
            "{}",
            e(&b)
        );
    }
}
