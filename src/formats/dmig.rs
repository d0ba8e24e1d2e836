//! Nastran DMIG entries (punch files `.pch` and bulk data `.bdf`/`.dat`; small, large
//! (`DMIG*`) and free (comma) field, `+`/`*`/blank continuations, `D` and implicit exponents),
//! one matrix chosen by name (`KAAX`, `MAAX`, …). Header `DMIG NAME 0 IFO TIN TOUT POLAR –
//! NCOL`; columns `DMIG NAME GJ CJ – G1 C1 A1 B1 …` in groups of four fields.

use crate::error::{Error, Result};
use crate::formats::fe_matrices::{Interner, LabelledMatrix, label, nastran_real};
use crate::formats::files::quoted;
use std::borrow::Cow;
use std::collections::BTreeSet;
use std::path::Path;

/// Splits a physical line: its first field is returned, its data fields are appended to
/// `out` (borrowed from the line unless tabs had to be expanded). `overflow` is set to the
/// number of fields a free-field line holds beyond the nine a card line has room for (a
/// tenth that is a number, or any non-blank field after it), which would otherwise be lost.
fn split_line<'a>(raw: &'a str, out: &mut Vec<Cow<'a, str>>, overflow: &mut usize) -> Cow<'a, str> {
    if raw.contains('\t') {
        // Tabs stop at multiples of 8, as Nastran reads them.
        let mut l = String::with_capacity(raw.len() + 8);
        for c in raw.chars() {
            if c == '\t' {
                let pad = 8 - l.chars().count() % 8;
                l.extend(std::iter::repeat_n(' ', pad));
            } else {
                l.push(c);
            }
        }
        let mut fields = Vec::new();
        let first = split_expanded(&l, &mut fields, overflow).into_owned();
        out.extend(fields.into_iter().map(|f| Cow::Owned(f.into_owned())));
        return Cow::Owned(first);
    }
    split_expanded(raw, out, overflow)
}

/// [`split_line`] of a line without tabs.
fn split_expanded<'a>(
    line: &'a str,
    out: &mut Vec<Cow<'a, str>>,
    overflow: &mut usize,
) -> Cow<'a, str> {
    *overflow = 0;
    if line.contains(',') {
        let mut it = line.split(',').map(|s| Cow::Borrowed(s.trim()));
        let first = it.next().unwrap_or_default();
        // A free-field card holds at most 8 data fields per line; a ninth is the
        // continuation marker (a name, never a number), and nothing may follow it.
        out.extend(it.by_ref().take(8));
        let marker = it.next();
        let data_in_marker = marker
            .as_deref()
            .is_some_and(|m| crate::formats::fe_matrices::nastran_real(m).is_some());
        let after = it.filter(|f| !f.is_empty()).count();
        *overflow = after + usize::from(data_in_marker);
        return first;
    }
    // Fields are columns of characters (bytes when the line is ASCII, as it nearly always is).
    let ascii = line.is_ascii();
    let field = |from: usize, width: usize| -> Cow<'a, str> {
        if ascii {
            let end = (from + width).min(line.len());
            Cow::Borrowed(line.get(from.min(end)..end).unwrap_or("").trim())
        } else {
            Cow::Owned(
                line.chars()
                    .skip(from)
                    .take(width)
                    .collect::<String>()
                    .trim()
                    .to_string(),
            )
        }
    };
    let first = field(0, 8);
    if first.ends_with('*') {
        out.extend((0..4).map(|k| field(8 + 16 * k, 16)));
    } else {
        out.extend((0..8).map(|k| field(8 + 8 * k, 8)));
    }
    first
}

/// One logical bulk-data card: its data fields (fields 2–9 of each physical line, in order,
/// continuation markers dropped) and the line it starts on.
struct Card<'c, 'a> {
    fields: &'c [Cow<'a, str>],
    line: usize,
    /// The physical line of each field (continuation lines follow the card's first).
    lines: &'c [usize],
}

impl Card<'_, '_> {
    /// The line field `k` (0-based data field) was read from; the card's first line for a
    /// field past its end.
    fn line_of(&self, k: usize) -> usize {
        self.lines.get(k).copied().unwrap_or(self.line)
    }
}

/// Calls `f(fields, line, lines)` for each card of a bulk-data text (its data fields,
/// continuations appended, the line it starts on and each field's line), one card at a time; comments `$` and blank lines are
/// skipped, cards after `ENDDATA` ignored; `keep(name, fields of the first line)` decides
/// which cards are passed (others are skipped with their continuations, unsplit).
fn each_card<'a>(
    text: &'a str,
    path: &Path,
    mut keep: impl FnMut(&str, &[Cow<'a, str>]) -> bool,
    mut f: impl FnMut(&[Cow<'a, str>], usize, &[usize]) -> Result<()>,
) -> Result<()> {
    let mut cur: Vec<Cow<'a, str>> = Vec::new();
    let mut lines: Vec<usize> = Vec::new();
    let mut cur_line = 0usize;
    let mut keeping = false;
    for (i, raw) in text.lines().enumerate() {
        let raw = raw.trim_end_matches('\r');
        let t = raw.trim_start();
        if t.is_empty() || t.starts_with('$') {
            continue;
        }
        // A continuation of a card not kept is skipped unsplit: its first field (before a
        // comma, or the first 8 columns) is blank or starts with `+` or `*`.
        if !keeping && !raw.contains('\t') {
            let first = match raw.find(',') {
                Some(c) => raw[..c].trim(),
                None => raw.get(..8.min(raw.len())).map_or("", str::trim),
            };
            if first.is_empty() || first.starts_with(['+', '*']) {
                continue;
            }
        }
        let at = cur.len();
        let mut overflow = 0;
        let first = split_line(raw, &mut cur, &mut overflow);
        lines.resize(cur.len(), i + 1);
        let continuation = first.is_empty() || first.starts_with('+') || first.starts_with('*');
        let lost = || Error::DataFile {
            file: path.to_path_buf(),
            line: i + 1,
            message: format!(
                "a free-field line holds the card's name, 8 data fields and a continuation \
                 marker; this one has {overflow} more field(s), which would be lost: put them \
                 on a continuation line (`+,…`)"
            ),
        };
        if continuation {
            if !keeping {
                cur.truncate(at);
                lines.truncate(at);
            } else if overflow > 0 {
                return Err(lost());
            }
            continue;
        }
        // A new card: the previous one is complete.
        if keeping {
            f(&cur[..at], cur_line, &lines[..at])?;
        }
        cur.drain(..at);
        lines.drain(..at);
        let name = first.trim_end_matches('*').to_ascii_uppercase();
        if name == "ENDDATA" {
            cur.clear();
            lines.clear();
            keeping = false;
            break;
        }
        keeping = keep(&name, &cur);
        if keeping && overflow > 0 {
            return Err(lost());
        }
        cur_line = i + 1;
        if !keeping {
            cur.clear();
            lines.clear();
        }
    }
    if keeping {
        f(&cur, cur_line, &lines)?;
    }
    Ok(())
}

/// Matrix `name` of the DMIG entries in `text` (read from `path`): a square real matrix, its
/// rows and columns labelled by grid and component. Errors name the file, the card's line and
/// the field.
pub fn parse_dmig(text: &str, path: &Path, name: &str) -> Result<LabelledMatrix> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: format!("DMIG {}: {m}", quoted(name)),
    };
    let want = name.trim().to_ascii_uppercase();
    // Only the wanted matrix's cards are kept; the names of all are noted for the error that
    // names none.
    let mut names: BTreeSet<String> = BTreeSet::new();
    let mut header: Option<usize> = None;
    let mut entries = Vec::new();
    let mut labels = Interner::default();
    let keep = |n: &str, fields: &[Cow<'_, str>]| {
        if n != "DMIG" {
            return false;
        }
        let f = fields.first().map_or("", |f| f.as_ref());
        if f.eq_ignore_ascii_case(&want) {
            return true;
        }
        if !names.iter().any(|k| k.eq_ignore_ascii_case(f)) {
            names.insert(f.to_ascii_uppercase());
        }
        false
    };
    each_card(text, path, keep, |fields, line, lines| {
        let c = Card {
            fields,
            line,
            lines,
        };
        let field = |k: usize| c.fields.get(k).map_or("", |f| f.as_ref());
        let int = |k: usize, what: &str, blank: Option<i64>| -> Result<i64> {
            let f = field(k);
            if f.is_empty()
                && let Some(b) = blank
            {
                return Ok(b);
            }
            f.parse::<i64>().map_err(|_| {
                err(
                    c.line_of(k),
                    format!("field {} ({what}): {} is not an integer", k + 2, quoted(f)),
                )
            })
        };
        if field(1) == "0" {
            if let Some(h) = header {
                return Err(err(
                    c.line,
                    format!("a second header (the first is on line {h})"),
                ));
            }
            let ifo = int(2, "IFO, the matrix form", None)?;
            let tin = int(3, "TIN, the input type", None)?;
            if ifo != 6 && ifo != 1 {
                return Err(err(
                    c.line,
                    format!(
                        "form IFO = {ifo}: nlsim takes square matrices (IFO 1) and symmetric ones \
                         (IFO 6)"
                    ),
                ));
            }
            if tin != 1 && tin != 2 {
                return Err(err(
                    c.line,
                    format!("type TIN = {tin}: nlsim takes real matrices (TIN 1 or 2)"),
                ));
            }
            header = Some(c.line);
            return Ok(());
        }
        if header.is_none() {
            return Err(err(
                c.line,
                "a column entry before the header (GJ = 0)".into(),
            ));
        }
        let gj = int(1, "GJ", None)?;
        let cj = int(2, "CJ", Some(0))?;
        let col = label(gj, cj).map_err(|m| err(c.line, m))?;
        let col_id = labels.id(col);
        // Groups of four fields from field 6: G, C, A, B (B blank for real matrices).
        let data = &c.fields[4.min(c.fields.len())..];
        let mut k = 0;
        let mut any = false;
        while k < data.len() {
            if data[k..(k + 4).min(data.len())]
                .iter()
                .all(|f| f.is_empty())
            {
                k += 4;
                continue;
            }
            let at = 4 + k;
            let g = int(at, "G", None)?;
            let ci = int(at + 1, "C", Some(0))?;
            let here = c.line_of(at + 2);
            let row = label(g, ci).map_err(|m| err(c.line_of(at), m))?;
            let a = field(at + 2);
            let value = nastran_real(a).ok_or_else(|| {
                err(
                    here,
                    format!(
                        "field {} (A, the value of row {row}, column {col}): {} is not a finite \
                         number",
                        at + 4,
                        quoted(a)
                    ),
                )
            })?;
            if !field(at + 3).is_empty() {
                return Err(err(
                    c.line_of(at + 3),
                    format!(
                        "field {} (B) holds {}: an imaginary part in a real matrix",
                        at + 5,
                        quoted(field(at + 3))
                    ),
                ));
            }
            // The entry's place is the line of its value, so that a repeat or an asymmetry
            // names the line holding it, not its column's header.
            entries.push((labels.id(row), col_id, value, here));
            any = true;
            k += 4;
        }
        if !any {
            return Err(err(c.line, format!("column {col} holds no entry")));
        }
        Ok(())
    })?;
    if header.is_none() {
        let known: Vec<&str> = names.iter().map(String::as_str).collect();
        return Err(Error::Usage(format!(
            "{}: no DMIG matrix {} (matrices in the file: {})",
            path.display(),
            quoted(name),
            if known.is_empty() {
                "none".to_string()
            } else {
                known.join(", ")
            }
        )));
    }
    if entries.is_empty() {
        return Err(err(header.unwrap_or(1), "the matrix has no entry".into()));
    }
    Ok(LabelledMatrix {
        path: path.to_path_buf(),
        name: want,
        labels: labels.list,
        entries,
    })
}

/// The coordinates of the `GRID` cards of a Nastran bulk-data text (read from `path`):
/// `GRID ID CP X1 X2 X3 CD PS SEID` in small, large or free field, `(id, [x1, x2, x3])` in
/// file order (m, as the deck's units are taken to be SI). A blank coordinate is 0. Only the
/// basic system is read: a grid with `CP` other than blank or 0 is refused by line, since
/// its coordinates are in a local system nlsim does not transform. Other cards are skipped.
pub fn parse_grids(text: &str, path: &Path) -> Result<Vec<(u64, [f64; 3])>> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: format!("GRID: {m}"),
    };
    let mut out = Vec::new();
    each_card(
        text,
        path,
        |n, _| n == "GRID",
        |fields, line, _| {
            let field = |k: usize| fields.get(k).map_or("", |f| f.as_ref()).trim();
            let id = field(0)
                .parse::<u64>()
                .ok()
                .filter(|&n| n > 0)
                .ok_or_else(|| {
                    err(
                        line,
                        format!("field 2 (ID) '{}' is not a positive integer", field(0)),
                    )
                })?;
            let cp = field(1);
            if !(cp.is_empty() || cp == "0") {
                return Err(err(
                    line,
                    format!(
                        "grid {id} gives its coordinates in system CP = {cp}; only the basic \
                         system (CP blank or 0) is read: write the deck with basic coordinates"
                    ),
                ));
            }
            let mut xyz = [0.0; 3];
            for (k, x) in xyz.iter_mut().enumerate() {
                let f = field(2 + k);
                if !f.is_empty() {
                    *x = nastran_real(f).ok_or_else(|| {
                        err(
                            line,
                            format!(
                                "grid {id}: field {} (X{}) '{f}' is not a number",
                                4 + k,
                                k + 1
                            ),
                        )
                    })?;
                }
            }
            if out.len() == crate::formats::fe_matrices::MAX_GEOMETRY_NODES {
                return Err(err(line, format!("more than {} grids", out.len())));
            }
            out.push((id, xyz));
            Ok(())
        },
    )?;
    if out.is_empty() {
        return Err(Error::Usage(format!(
            "{}: no GRID cards (node coordinates)",
            path.display()
        )));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::abaqus::parse_abaqus;
    use crate::formats::fe_matrices::union_dofs;
    use nlsim_kernel::{Component, DofLabel};

    #[test]
    fn a_free_field_line_with_more_fields_than_a_card_holds_is_refused() {
        // DMIG,NAME,GJ,CJ,,G1,C1,A1,,G2 — the 10th field a number: the off-diagonal term
        // would vanish. Field 10 as a marker and trailing blanks are fine.
        let p = Path::new("k.pch");
        let head = "DMIG,KAAX,0,6,2,0,,,2\n";
        let lost =
            format!("{head}DMIG,KAAX,1,3,,1,3,2.0E6,,2,3,-1.0E6\nDMIG,KAAX,2,3,,2,3,1.0E6\n");
        let e = parse_dmig(&lost, p, "KAAX").unwrap_err().to_string();
        assert!(
            e.contains("k.pch") && e.contains(":2") && e.contains("would be lost"),
            "{e}"
        );
        let marked = format!(
            "{head}DMIG,KAAX,1,3,,1,3,2.0E6,,+A,,\n+A,2,3,-1.0E6\nDMIG,KAAX,2,3,,2,3,1.0E6\n"
        );
        let m = parse_dmig(&marked, p, "KAAX").unwrap();
        assert_eq!(m.entries.len(), 3, "{:?}", m.entries);
    }

    #[test]
    fn an_entry_is_placed_on_the_line_of_its_value() {
        // Column 1:uz's card spans lines 3-5; its mirror entry (2:uz, 1:uz) on line 5
        // disagrees with column 2:uz's (1:uz, 2:uz) on line 7: the error names both value
        // lines, not the cards' first lines.
        let text = "DMIG*   KAAX                           0               6               2\n\
                    *                      2               0                               2\n\
                    DMIG*   KAAX                           1               3\n\
                    *                      1               32.000000000D+06\n\
                    *                      2               3-1.00000000D+06\n\
                    DMIG*   KAAX                           2               3\n\
                    *                      1               3-1.50000000D+06\n\
                    *                      2               31.000000000D+06\n";
        let p = Path::new("k.pch");
        let m = parse_dmig(text, p, "KAAX").unwrap();
        let lines: Vec<usize> = m.entries.iter().map(|e| e.3).collect();
        assert_eq!(lines, [4, 5, 7, 8]);
        let dofs = union_dofs(&[&m]).unwrap();
        let e = m.onto(&dofs, "K", 1e-12).unwrap_err().to_string();
        assert!(e.contains("k.pch:7") && e.contains("on line 5"), "{e}");
    }

    #[test]
    fn dmig_small_large_and_free_field_give_one_matrix() {
        let small = "DMIG    KAAX    0       6       2       0                       2\n\
                     DMIG    KAAX    1       3               1       3       2.0+6\n\
                     DMIG    KAAX    1       3               2       3       -1.0+6\n\
                     DMIG    KAAX    2       3               2       3       1.0+6\n";
        let large = "DMIG*   KAAX                           0               6               2\n\
                     *                      2               0                               2\n\
                     DMIG*   KAAX                           1               3\n\
                     *                      1               32.000000000D+06\n\
                     *                      2               3-1.00000000D+06\n\
                     DMIG*   KAAX                           2               3\n\
                     *                      2               31.000000000D+06\n";
        let free = "DMIG,KAAX,0,6,2,0,,,2\nDMIG,KAAX,1,3,,1,3,2.0E6,,\n+,2,3,-1.0E6\n\
                    DMIG,KAAX,2,3,,2,3,1.0E6\n";
        let p = Path::new("k.pch");
        let want = [
            (
                DofLabel::new(1, Component::Uz),
                DofLabel::new(1, Component::Uz),
                2e6,
            ),
            (
                DofLabel::new(2, Component::Uz),
                DofLabel::new(1, Component::Uz),
                -1e6,
            ),
            (
                DofLabel::new(2, Component::Uz),
                DofLabel::new(2, Component::Uz),
                1e6,
            ),
        ];
        for text in [small, large, free] {
            let m = parse_dmig(text, p, "kaax").unwrap();
            let got: Vec<_> = m
                .entries
                .iter()
                .map(|e| (m.labels[e.0], m.labels[e.1], e.2))
                .collect();
            assert_eq!(got, want, "{text}");
            let dofs = union_dofs(&[&m]).unwrap();
            let k = m.onto(&dofs, "stiffness matrix", 0.0).unwrap().to_dense();
            assert_eq!(k[(0, 1)], -1e6);
            assert_eq!(k[(1, 0)], -1e6);
        }
    }

    #[test]
    fn bad_entries_name_line_and_field() {
        let p = Path::new("m.mtx");
        for (text, want) in [
            (
                "1,3,1,3\n",
                "m.mtx:1: 4 fields, expected 3 (ROW, COLUMN, VALUE",
            ),
            (
                "1 1 2.0\n1,1,2,1,1.0\n",
                "m.mtx:2: 5 fields, the file's first entry (line 1) has 3",
            ),
            ("0 1 2.0\n", "m.mtx:1: equation 0 in field 1"),
            ("1,9,1,3,1.0\n", "component 9 of node 1"),
            ("-4,1,1,3,1.0\n", "node -4 is not a positive node number"),
            ("1,3,1,3,1e999\n", "is not a finite number"),
            ("*MATRIX GENERATE\n", "keyword line"),
            ("", "no matrix entry"),
        ] {
            let e = parse_abaqus(text, p).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
        let p = Path::new("k.pch");
        for (text, want) in [
            ("DMIG    KAAX    0       6       3       0\n", "TIN = 3"),
            ("DMIG    KAAX    0       9       2       0\n", "IFO = 9"),
            (
                "DMIG    KAAX    1       3               1       3       2.0\n",
                "before the header",
            ),
            (
                "DMIG    KAAX    0       6       2       0\nDMIG    KAAX    1       3               1       3       x\n",
                "k.pch:2: DMIG 'KAAX': field 8",
            ),
            (
                "DMIG    MAAX    0       6       2       0\n",
                "no DMIG matrix 'KAAX' (matrices in the file: MAAX)",
            ),
        ] {
            let e = parse_dmig(text, p, "KAAX").unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }
}
