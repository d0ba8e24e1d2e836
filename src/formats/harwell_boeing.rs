//! Ansys `HBMAT` output: a matrix in the Harwell–Boeing layout (Duff, Grimes and Lewis: four
//! header lines, then column pointers, row indices and values in the fixed-width fields the
//! header's Fortran formats declare), `RSA` (one triangle) or `RUA` (both), labelled by the
//! mapping file `HBMAT` writes beside it (`NAME.mapping`: equation, node, DOF per line).

use crate::error::{Error, Result};
use crate::formats::fe_matrices::{label, nastran_real};
use crate::formats::files::quoted;
use nlsim_kernel::DofLabel;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// The mapping file of a Harwell–Boeing file: `NAME.mapping` beside `NAME.EXT` (HBMAT names it
/// after the matrix file's base name).
pub fn mapping_path(path: &Path) -> PathBuf {
    path.with_extension("mapping")
}

/// A Harwell–Boeing matrix's order and stored entries `(row, col, value, line)`, 0-based.
#[derive(Debug, Clone)]
pub struct HarwellBoeing {
    /// Order (rows = columns).
    pub n: usize,
    /// `RSA` (symmetric, one triangle stored) or `RUA` (both triangles).
    pub kind: String,
    /// The entries as stored, with the line of each value.
    pub entries: Vec<(usize, usize, f64, usize)>,
}

/// Count and width of the fields of a Fortran format such as `(20I4)`, `(1P,3E25.16)` or
/// `(4D20.12)`, for the letter `I` (integers) or `E`/`D` (reals).
fn fortran_fields(f: &str, integer: bool) -> Option<(usize, usize)> {
    let u = f
        .trim()
        .trim_start_matches('(')
        .trim_end_matches(')')
        .to_ascii_uppercase();
    let spec = u.rsplit(',').next()?.trim();
    // A scale factor may lead without a comma: `(1P5D16.8)` is `(1P,5D16.8)`.
    let spec = match spec.split_once('P') {
        Some((scale, rest)) if scale.chars().all(|c| c.is_ascii_digit() || c == '-') => rest,
        _ => spec,
    };
    let at = if integer {
        spec.find('I')?
    } else {
        spec.find(['E', 'D'])?
    };
    let count: usize = if at == 0 { 1 } else { spec[..at].parse().ok()? };
    let width: usize = spec[at + 1..].split('.').next()?.parse().ok()?;
    ((1..=1_000).contains(&count) && (1..=64).contains(&width)).then_some((count, width))
}

/// A Harwell–Boeing file (Duff, Grimes and Lewis's layout; Ansys `HBMAT` writes it): four
/// header lines (title and key; card counts; type `RSA`/`RUA` and sizes; formats), a fifth
/// when right-hand sides follow, then the column pointers, row indices and values in the
/// fixed-width fields the formats give. Real assembled matrices only; sizes checked against
/// the file before allocating; errors name the file and line.
pub fn parse_harwell_boeing(text: &str, path: &Path) -> Result<HarwellBoeing> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let lines: Vec<&str> = text.lines().map(|l| l.trim_end_matches('\r')).collect();
    if lines.len() < 4 {
        return Err(err(
            lines.len().max(1),
            "a Harwell-Boeing file starts with four header lines".into(),
        ));
    }
    // The title (line 1) is free text in any code page; the rest is fixed-width ASCII.
    if let Some(k) = lines.iter().skip(1).position(|l| !l.is_ascii()) {
        return Err(err(
            k + 2,
            "a non-ASCII character (only the title line may hold one)".into(),
        ));
    }
    let ints = |ln: usize, t: &str, what: &str| -> Result<Vec<i64>> {
        t.split_whitespace()
            .map(|x| {
                x.parse::<i64>()
                    .map_err(|_| err(ln, format!("{what}: {} is not an integer", quoted(x))))
            })
            .collect()
    };
    let cards = ints(2, lines[1], "card counts")?;
    if cards.len() < 4 || cards.iter().any(|&c| c < 0) {
        return Err(err(
            2,
            format!(
                "expected the card counts TOTCRD PTRCRD INDCRD VALCRD [RHSCRD], found {}",
                quoted(lines[1])
            ),
        ));
    }
    let (ptrcrd, indcrd, valcrd) = (cards[1] as usize, cards[2] as usize, cards[3] as usize);
    let rhscrd = cards.get(4).copied().unwrap_or(0);
    let kind: String = lines[2]
        .chars()
        .take(3)
        .collect::<String>()
        .to_ascii_uppercase();
    if kind.len() < 3 || !kind.starts_with('R') || !kind.ends_with('A') {
        return Err(err(
            3,
            format!(
                "matrix type {}: nlsim reads real assembled matrices (RSA, RUA); complex, \
                 pattern-only and elemental ones are not stiffness or mass matrices",
                quoted(&kind)
            ),
        ));
    }
    let symmetric = match &kind[1..2] {
        "S" => true,
        "U" => false,
        _ => {
            return Err(err(
                3,
                format!(
                    "matrix type {}: a stiffness or mass matrix is symmetric (RSA) or stored \
                     with both triangles (RUA)",
                    quoted(&kind)
                ),
            ));
        }
    };
    let sizes = ints(3, lines[2].get(3..).unwrap_or(""), "sizes")?;
    if sizes.len() < 3 {
        return Err(err(
            3,
            "expected the type, then NROW NCOL NNZERO [NELTVL]".into(),
        ));
    }
    let (nrow, ncol, nnz) = (sizes[0], sizes[1], sizes[2]);
    if nrow < 1 || nrow != ncol {
        return Err(err(
            3,
            format!("the matrix is {nrow} × {ncol}: nlsim takes square matrices"),
        ));
    }
    let n = nrow as usize;
    if n > crate::formats::matrices::MAX_DIM {
        return Err(err(
            3,
            format!(
                "{n} rows, more than {} DOFs",
                crate::formats::matrices::MAX_DIM
            ),
        ));
    }
    // Each pointer, index and value takes at least one character of the file.
    if nnz < 1 || nnz as usize > text.len() || n + 1 > text.len() {
        return Err(err(
            3,
            format!(
                "NNZERO = {nnz} with {n} columns cannot fit in a file of {} bytes",
                text.len()
            ),
        ));
    }
    let nnz = nnz as usize;
    let fmt = lines[3];
    let field = |a: usize, b: usize| fmt.get(a..b.min(fmt.len())).unwrap_or("").trim();
    let (ptr_fmt, ind_fmt, val_fmt) = (field(0, 16), field(16, 32), field(32, 52));
    let ptr_f = fortran_fields(ptr_fmt, true);
    let ind_f = fortran_fields(ind_fmt, true);
    let val_f = fortran_fields(val_fmt, false);
    let (Some(ptr_f), Some(ind_f), Some(val_f)) = (ptr_f, ind_f, val_f) else {
        return Err(err(
            4,
            format!(
                "formats {}: expected an integer format such as (20I4) for the pointers and \
                 indices, a real one such as (3E25.16) for the values",
                quoted(fmt.trim())
            ),
        ));
    };
    let first = if rhscrd > 0 { 5 } else { 4 };
    let need = [ptrcrd, indcrd, valcrd]
        .iter()
        .try_fold(first, |a: usize, &c| a.checked_add(c))
        .unwrap_or(usize::MAX);
    if lines.len() < need {
        return Err(err(
            lines.len(),
            format!(
                "the header announces {} pointer, {} index and {} value lines after line \
                 {first}; the file ends at line {}: truncated",
                ptrcrd,
                indcrd,
                valcrd,
                lines.len()
            ),
        ));
    }
    // Fixed-width fields of `count` lines from `start` (0-based), with their line numbers.
    // Reals separated by blanks are taken as they stand (some writers, scipy's among them,
    // print narrower fields than their format declares); otherwise, and always for integers
    // (whose fields may touch), the declared fixed widths.
    let fields =
        |start: usize, count: usize, (per, width): (usize, usize), want: usize, real: bool| {
            let mut out: Vec<(&str, usize)> = Vec::with_capacity(want.min(text.len()));
            for (k, l) in lines[start..start + count].iter().enumerate() {
                let ln = start + k + 1;
                if real {
                    let tokens: Vec<&str> = l.split_whitespace().collect();
                    if tokens.len() <= per
                        && tokens.iter().all(|t| {
                            t.contains(['E', 'e', 'D', 'd'])
                                && t.replace(['D', 'd'], "E").parse::<f64>().is_ok()
                        })
                    {
                        out.extend(tokens.into_iter().map(|t| (t, ln)));
                        continue;
                    }
                }
                let mut at = 0;
                let mut here = 0;
                while at < l.len() && here < per {
                    let f = l[at..(at + width).min(l.len())].trim();
                    at += width;
                    here += 1;
                    if !f.is_empty() {
                        out.push((f, ln));
                    }
                }
                if !l[at.min(l.len())..].trim().is_empty() {
                    return Err(err(
                        ln,
                        format!("more than {per} fields of {width} characters on a line"),
                    ));
                }
            }
            if out.len() != want {
                return Err(err(
                    start + count,
                    format!("{} values on these lines, {want} announced", out.len()),
                ));
            }
            Ok(out)
        };
    let p0 = first;
    let int_of = |(f, ln): (&str, usize), what: &str| -> Result<usize> {
        f.parse::<usize>().map_err(|_| {
            err(
                ln,
                format!("{what} {} is not a positive integer", quoted(f)),
            )
        })
    };
    let ptr: Vec<usize> = fields(p0, ptrcrd, ptr_f, n + 1, false)?
        .into_iter()
        .map(|x| int_of(x, "column pointer"))
        .collect::<Result<_>>()?;
    if ptr[0] != 1 || ptr[n] != nnz + 1 || ptr.windows(2).any(|w| w[1] < w[0]) {
        return Err(err(
            p0 + 1,
            format!(
                "the column pointers must rise from 1 to NNZERO + 1 = {}; they run from {} to {}",
                nnz + 1,
                ptr[0],
                ptr[n]
            ),
        ));
    }
    let rows = fields(p0 + ptrcrd, indcrd, ind_f, nnz, false)?;
    let vals = fields(p0 + ptrcrd + indcrd, valcrd, val_f, nnz, true)?;
    let mut entries = Vec::with_capacity(nnz);
    for j in 0..n {
        for k in ptr[j] - 1..ptr[j + 1] - 1 {
            let row = int_of(rows[k], "row index")?;
            if row < 1 || row > n {
                return Err(err(
                    rows[k].1,
                    format!("row index {row} of column {} is outside 1..={n}", j + 1),
                ));
            }
            let (f, ln) = vals[k];
            let v = nastran_real(f)
                .ok_or_else(|| err(ln, format!("value {} is not a finite number", quoted(f))))?;
            if symmetric && row - 1 < j {
                return Err(err(
                    ln,
                    format!(
                        "entry ({row}, {}) is above the diagonal: an RSA file stores the lower \
                         triangle",
                        j + 1
                    ),
                ));
            }
            entries.push((row - 1, j, v, ln));
        }
    }
    Ok(HarwellBoeing { n, kind, entries })
}

/// The equation → DOF labels of an Ansys `HBMAT` mapping file: heading lines, then one line
/// per equation with its number, node and DOF label (`UX`, `UY`, `UZ`, `ROTX`, `ROTY`,
/// `ROTZ`). Every equation 1..=n must appear once.
pub fn parse_mapping(text: &str, path: &Path) -> Result<Vec<DofLabel>> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let mut rows: Vec<(usize, DofLabel, usize)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let f: Vec<&str> = raw.split_whitespace().collect();
        if f.is_empty() || f[0].parse::<i64>().is_err() {
            if rows.is_empty() {
                continue; // a heading
            }
            if f.is_empty() {
                continue;
            }
            return Err(err(
                ln,
                format!("expected EQUATION NODE DOF, found {}", quoted(raw)),
            ));
        }
        if f.len() != 3 {
            return Err(err(
                ln,
                format!(
                    "{} fields, expected EQUATION NODE DOF: {}",
                    f.len(),
                    quoted(raw)
                ),
            ));
        }
        let eq: usize = f[0]
            .parse()
            .ok()
            .filter(|e| (1..=crate::formats::matrices::MAX_DIM).contains(e))
            .ok_or_else(|| err(ln, format!("equation {} is not 1 or more", quoted(f[0]))))?;
        let node: i64 = f[1]
            .parse()
            .map_err(|_| err(ln, format!("node {} is not an integer", quoted(f[1]))))?;
        let c = match f[2].to_ascii_uppercase().as_str() {
            "UX" => 1,
            "UY" => 2,
            "UZ" => 3,
            "ROTX" => 4,
            "ROTY" => 5,
            "ROTZ" => 6,
            other => {
                return Err(err(
                    ln,
                    format!(
                        "DOF {} of node {node}: nlsim takes the structural DOFs UX, UY, UZ, \
                         ROTX, ROTY, ROTZ",
                        quoted(other)
                    ),
                ));
            }
        };
        rows.push((eq, label(node, c).map_err(|m| err(ln, m))?, ln));
    }
    if rows.is_empty() {
        return Err(err(1, "no EQUATION NODE DOF line".into()));
    }
    let n = rows.len();
    let mut out: Vec<Option<(DofLabel, usize)>> = vec![None; n];
    let mut seen: HashMap<DofLabel, usize> = HashMap::with_capacity(n);
    for (eq, l, ln) in rows {
        let slot = out.get_mut(eq - 1).ok_or_else(|| {
            err(
                ln,
                format!("equation {eq} is past the {n} equations the file maps"),
            )
        })?;
        if let Some((_, first)) = slot {
            return Err(err(
                ln,
                format!("equation {eq} is mapped again (first on line {first})"),
            ));
        }
        if let Some(first) = seen.insert(l, ln) {
            return Err(err(
                ln,
                format!("DOF {l} is mapped again (first on line {first})"),
            ));
        }
        *slot = Some((l, ln));
    }
    Ok(out
        .into_iter()
        .map(|o| o.expect("every slot filled").0)
        .collect())
}
