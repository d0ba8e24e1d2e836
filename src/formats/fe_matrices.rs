//! Matrices written by the FE codes engineers use, with the node and DOF labels those files
//! carry themselves:
//!
//! - **Nastran DMIG** entries (punch files `.pch` and bulk data `.bdf`/`.dat`; small, large
//!   (`DMIG*`) and free (comma) field, `+`/`*`/blank continuations, `D` and implicit
//!   exponents), one matrix chosen by name (`KAAX`, `MAAX`, …). Header `DMIG NAME 0 IFO TIN
//!   TOUT POLAR – NCOL`; columns `DMIG NAME GJ CJ – G1 C1 A1 B1 …` in groups of four fields.
//! - **Abaqus** `*MATRIX GENERATE` output in coordinate form (`.mtx`: one `NODE_I, DOF_I,
//!   NODE_J, DOF_J, VALUE` per line, `**` comments), told from Matrix Market by its content.
//!
//! Node `G` with component `C` (1–6: translations x, y, z, rotations about x, y, z; 0: a
//! scalar point) becomes the label `G:ux` … `G:rz` (`G:u` for a scalar point), so a model's
//! elements, excitations and sensors name the engineer's own grid numbers. A matrix read here
//! is a [`LabelledMatrix`]: its entries by label, with the file line of each, until
//! [`LabelledMatrix::onto`] places it on a model's DOFs — where symmetric storage is resolved
//! (one triangle, or both when the two agree to the bit) and every repeat is refused with both
//! lines named.

use crate::error::{Error, Result};
use crate::formats::files::quoted;
use nlsim_kernel::{Component, DofLabel, DofMap, SparseSym};
use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

/// Largest FE matrix file read (bytes): 16 GiB, a 10⁶-DOF model's stiffness with room.
pub const MAX_FE_FILE_BYTES: u64 = 16 << 30;

/// The FE-code formats [`read`] takes (`format =` in a model file's `[matrices]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeFormat {
    /// Nastran DMIG entries (punch or bulk data).
    Dmig,
    /// Abaqus `*MATRIX GENERATE` coordinate output.
    Abaqus,
}

impl FeFormat {
    /// The format's name in model files: `dmig` or `abaqus`.
    pub fn as_str(self) -> &'static str {
        match self {
            FeFormat::Dmig => "dmig",
            FeFormat::Abaqus => "abaqus",
        }
    }

    /// The format of a name as model files give it.
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "dmig" | "nastran-dmig" | "punch" => Some(FeFormat::Dmig),
            "abaqus" | "abaqus-mtx" => Some(FeFormat::Abaqus),
            _ => None,
        }
    }
}

/// One stored entry of a [`LabelledMatrix`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LabelledEntry {
    /// Row DOF.
    pub row: DofLabel,
    /// Column DOF.
    pub col: DofLabel,
    /// Value (SI units of the matrix: kg for mass, N/m for stiffness).
    pub value: f64,
    /// 1-based line of the file it was read from (the card's first line for DMIG).
    pub line: usize,
}

/// A square matrix read from an FE code's file, by node/DOF label.
#[derive(Debug, Clone)]
pub struct LabelledMatrix {
    /// The file.
    pub path: PathBuf,
    /// The matrix's name in the file (DMIG name; the file name for Abaqus).
    pub name: String,
    /// The entries as stored (one triangle or both).
    pub entries: Vec<LabelledEntry>,
}

impl LabelledMatrix {
    /// Every DOF an entry names, in label order (node, then component).
    pub fn labels(&self) -> BTreeSet<DofLabel> {
        self.entries.iter().flat_map(|e| [e.row, e.col]).collect()
    }

    /// The matrix on the DOFs of `dofs` (named `what` in errors): symmetric storage resolved
    /// (an entry and its mirror may both be given only with the same value), repeats refused,
    /// every label required to be one of `dofs` (else the DOF was constrained out of the
    /// model's other matrix, or the label is not the model's).
    pub fn onto(&self, dofs: &DofMap, what: &str) -> Result<SparseSym> {
        let err = |line: usize, m: String| Error::DataFile {
            file: self.path.clone(),
            line,
            message: format!("{what} {}: {m}", self.name),
        };
        let mut indexed = Vec::with_capacity(self.entries.len());
        for e in &self.entries {
            let index = |l: &DofLabel| {
                dofs.index_of(l).map_err(|_| {
                    err(
                        e.line,
                        format!(
                            "DOF {l} is not a DOF of the model (it is in none of its matrices' \
                             labels)"
                        ),
                    )
                })
            };
            indexed.push((index(&e.row)?, index(&e.col)?, e.value, e.line));
        }
        symmetric_from_entries(&self.path, &format!("{what} {}", self.name), dofs, &indexed)
    }
}

/// A symmetric matrix on `dofs` from stored entries `(row, col, value, line)` of `path`
/// (named `what` in errors): one triangle, or both when each entry and its mirror are equal to
/// the bit; an entry given twice is refused with both lines.
pub fn symmetric_from_entries(
    path: &Path,
    what: &str,
    dofs: &DofMap,
    entries: &[(usize, usize, f64, usize)],
) -> Result<SparseSym> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: format!("{what}: {m}"),
    };
    // (higher index, lower index) → (value, line, given as (row ≥ col))
    let mut seen: HashMap<(usize, usize), (f64, usize, bool)> =
        HashMap::with_capacity(entries.len());
    let mut lower = Vec::with_capacity(entries.len());
    for &(i, j, value, line_here) in entries {
        let key = (i.max(j), i.min(j));
        let lower_side = i >= j;
        let names = || (dofs.describe(i), dofs.describe(j));
        match seen.get(&key) {
            None => {
                seen.insert(key, (value, line_here, lower_side));
                lower.push((key.0, key.1, value));
            }
            Some(&(v, line, side)) => {
                let (row, col) = names();
                if side == lower_side || i == j {
                    return Err(err(
                        line_here,
                        format!("entry ({row}, {col}) is given again (first on line {line})"),
                    ));
                }
                if v.to_bits() != value.to_bits() {
                    return Err(err(
                        line_here,
                        format!(
                            "entry ({row}, {col}) = {value:e} and its mirror on line {line} = \
                             {v:e} differ: the matrix is not symmetric"
                        ),
                    ));
                }
            }
        }
    }
    Ok(SparseSym::from_lower_triplets(what, dofs.len(), &lower)?)
}

/// The format of an FE matrix file by extension and content: `.pch`, `.bdf`, `.dat`, `.nas`
/// → DMIG; `.mtx` → Abaqus unless it starts with `%%MatrixMarket` (`None`: not an FE-code
/// format, e.g. Matrix Market or HDF5).
pub fn detect(path: &Path) -> Result<Option<FeFormat>> {
    if dmig_extension(path) {
        return Ok(Some(FeFormat::Dmig));
    }
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    Ok(match ext.as_str() {
        "mtx" => {
            use std::io::Read;
            crate::formats::files::regular_file(path)?;
            let io = |source| Error::Io {
                path: path.to_path_buf(),
                source,
            };
            let mut head = Vec::with_capacity(14);
            std::fs::File::open(path)
                .map_err(io)?
                .take(14)
                .read_to_end(&mut head)
                .map_err(io)?;
            if head.eq_ignore_ascii_case(b"%%MatrixMarket") {
                None
            } else {
                Some(FeFormat::Abaqus)
            }
        }
        _ => None,
    })
}

/// Whether `path` has an extension of Nastran bulk data or punch files (`.pch`, `.bdf`,
/// `.dat`, `.nas`, `.blk`), whose DMIG entries [`detect`] takes it to hold (no file is read).
pub fn dmig_extension(path: &Path) -> bool {
    path.extension().and_then(|e| e.to_str()).is_some_and(|e| {
        ["pch", "bdf", "dat", "nas", "blk"]
            .iter()
            .any(|d| e.eq_ignore_ascii_case(d))
    })
}

/// Reads matrix `name` (DMIG; ignored for Abaqus, whose files hold one matrix) of `path` in
/// `format`, size-bounded by [`MAX_FE_FILE_BYTES`].
pub fn read(path: &Path, format: FeFormat, name: Option<&str>) -> Result<LabelledMatrix> {
    let text = crate::formats::files::read_text_bounded(path, MAX_FE_FILE_BYTES)?;
    match format {
        FeFormat::Dmig => {
            let name = name.ok_or_else(|| {
                Error::Usage(format!(
                    "{}: a DMIG file can hold several matrices: name one, e.g. \
                     \"{}:KAAX\"",
                    path.display(),
                    path.display()
                ))
            })?;
            parse_dmig(&text, path, name)
        }
        FeFormat::Abaqus => parse_abaqus(&text, path),
    }
}

/// A label from an FE code's node and component numbers (component 0: scalar point).
fn label(node: i64, component: i64) -> std::result::Result<DofLabel, String> {
    if node < 1 {
        return Err(format!(
            "node {node} is not a positive node number (an internal or Lagrange-multiplier \
             node? nlsim takes structural DOFs of real nodes)"
        ));
    }
    let c = match component {
        0 => Component::U,
        1 => Component::Ux,
        2 => Component::Uy,
        3 => Component::Uz,
        4 => Component::Rx,
        5 => Component::Ry,
        6 => Component::Rz,
        _ => {
            return Err(format!(
                "component {component} of node {node} is not 0 (scalar) or 1–6 (a \
                 temperature, pressure or warping DOF is not a structural DOF)"
            ));
        }
    };
    Ok(DofLabel::new(node as u64, c))
}

/// A real in Nastran's notation: `1.5`, `1.5E+3`, `1.5D+3`, `1.5+3`, `-.5-2`.
pub fn nastran_real(s: &str) -> Option<f64> {
    let t = s.trim();
    if t.is_empty() || t.len() > 40 {
        return None;
    }
    let t = t.replace(['D', 'd'], "E");
    if t.contains(['E', 'e']) {
        return t.parse().ok().filter(|v: &f64| v.is_finite());
    }
    // An implicit exponent: a sign after the mantissa's first character.
    let b = t.as_bytes();
    let at = (1..b.len()).find(|&i| (b[i] == b'+' || b[i] == b'-') && b[i - 1] != b'E');
    let v: f64 = match at {
        Some(i) => format!("{}E{}", &t[..i], &t[i..]).parse().ok()?,
        None => t.parse().ok()?,
    };
    v.is_finite().then_some(v)
}

/// One logical bulk-data card of a kept name: its data fields (fields 2–9 of each physical
/// line, in order, continuation markers dropped) and the line it starts on.
struct Card {
    fields: Vec<String>,
    line: usize,
}

/// Splits a physical line into its first field and its data fields.
fn split_line(raw: &str) -> (String, Vec<String>) {
    // Tabs stop at multiples of 8, as Nastran reads them.
    let expanded;
    let line: &str = if raw.contains('\t') {
        let mut l = String::with_capacity(raw.len() + 8);
        for c in raw.chars() {
            if c == '\t' {
                let pad = 8 - l.chars().count() % 8;
                l.extend(std::iter::repeat_n(' ', pad));
            } else {
                l.push(c);
            }
        }
        expanded = l;
        &expanded
    } else {
        raw
    };
    if line.contains(',') {
        let mut it = line.split(',').map(|s| s.trim().to_string());
        let first = it.next().unwrap_or_default();
        let mut rest: Vec<String> = it.collect();
        // A free-field card holds at most 8 data fields per line; a ninth is the marker.
        rest.truncate(8);
        return (first, rest);
    }
    // Fields are columns of characters (bytes when the line is ASCII, as it nearly always is).
    let ascii = line.is_ascii();
    let chars: Vec<char> = if ascii {
        Vec::new()
    } else {
        line.chars().collect()
    };
    let field = |from: usize, width: usize| -> String {
        if ascii {
            let end = (from + width).min(line.len());
            line.get(from.min(end)..end)
                .unwrap_or("")
                .trim()
                .to_string()
        } else {
            chars
                .iter()
                .skip(from)
                .take(width)
                .collect::<String>()
                .trim()
                .to_string()
        }
    };
    let first = field(0, 8);
    let large = first.ends_with('*');
    let fields = if large {
        (0..4).map(|k| field(8 + 16 * k, 16)).collect()
    } else {
        (0..8).map(|k| field(8 + 8 * k, 8)).collect()
    };
    (first, fields)
}

/// The cards of a bulk-data text (comments `$` and blank lines skipped; cards after
/// `ENDDATA` ignored), with `keep` deciding which card names are kept (others are skipped with
/// their continuations).
fn cards(text: &str, keep: impl Fn(&str) -> bool) -> Vec<Card> {
    let mut out: Vec<Card> = Vec::new();
    let mut keeping = false;
    for (i, raw) in text.lines().enumerate() {
        let raw = raw.trim_end_matches('\r');
        if raw.trim().is_empty() || raw.trim_start().starts_with('$') {
            continue;
        }
        let (first, fields) = split_line(raw);
        let continuation = first.is_empty() || first.starts_with('+') || first.starts_with('*');
        if continuation {
            if keeping && let Some(c) = out.last_mut() {
                c.fields.extend(fields);
            }
            continue;
        }
        let name = first.trim_end_matches('*').to_ascii_uppercase();
        if name == "ENDDATA" {
            break;
        }
        keeping = keep(&name);
        if keeping {
            out.push(Card {
                fields,
                line: i + 1,
            });
        }
    }
    out
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
    let all = cards(text, |n| n == "DMIG");
    let mut names: BTreeSet<String> = BTreeSet::new();
    let mut header: Option<usize> = None;
    let mut entries = Vec::new();
    for c in &all {
        let card_name = c
            .fields
            .first()
            .map(|s| s.to_ascii_uppercase())
            .unwrap_or_default();
        names.insert(card_name.clone());
        if card_name != want {
            continue;
        }
        let field = |k: usize| c.fields.get(k).map(String::as_str).unwrap_or("");
        let int = |k: usize, what: &str, blank: Option<i64>| -> Result<i64> {
            let f = field(k);
            if f.is_empty()
                && let Some(b) = blank
            {
                return Ok(b);
            }
            f.parse::<i64>().map_err(|_| {
                err(
                    c.line,
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
            continue;
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
        // Groups of four fields from field 6: G, C, A, B (B blank for real matrices).
        let data = &c.fields[4.min(c.fields.len())..];
        let mut k = 0;
        let mut any = false;
        while k < data.len() {
            if data[k..(k + 4).min(data.len())]
                .iter()
                .all(String::is_empty)
            {
                k += 4;
                continue;
            }
            let at = 4 + k;
            let g = int(at, "G", None)?;
            let ci = int(at + 1, "C", Some(0))?;
            let row = label(g, ci).map_err(|m| err(c.line, m))?;
            let a = field(at + 2);
            let value = nastran_real(a).ok_or_else(|| {
                err(
                    c.line,
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
                    c.line,
                    format!(
                        "field {} (B) holds {}: an imaginary part in a real matrix",
                        at + 5,
                        quoted(field(at + 3))
                    ),
                ));
            }
            entries.push(LabelledEntry {
                row,
                col,
                value,
                line: c.line,
            });
            any = true;
            k += 4;
        }
        if !any {
            return Err(err(c.line, format!("column {col} holds no entry")));
        }
    }
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
        entries,
    })
}

/// The matrix of an Abaqus `*MATRIX GENERATE` coordinate file (`NODE_I, DOF_I, NODE_J, DOF_J,
/// VALUE` per line, commas or blanks between). Errors name the file and line.
pub fn parse_abaqus(text: &str, path: &Path) -> Result<LabelledMatrix> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let mut entries = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let t = raw.trim();
        if t.is_empty() || t.starts_with("**") {
            continue;
        }
        if t.starts_with('*') {
            return Err(err(
                ln,
                format!(
                    "keyword line {}: this reader takes the coordinate output of *MATRIX \
                     GENERATE (NODE, DOF, NODE, DOF, VALUE per line)",
                    quoted(t)
                ),
            ));
        }
        let f: Vec<&str> = t
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        if f.len() != 5 {
            return Err(err(
                ln,
                format!(
                    "{} fields, expected 5 (NODE_I, DOF_I, NODE_J, DOF_J, VALUE): {}",
                    f.len(),
                    quoted(t)
                ),
            ));
        }
        let int = |k: usize| -> Result<i64> {
            f[k].parse::<i64>().map_err(|_| {
                err(
                    ln,
                    format!("field {}: {} is not an integer", k + 1, quoted(f[k])),
                )
            })
        };
        let row = label(int(0)?, int(1)?).map_err(|m| err(ln, m))?;
        let col = label(int(2)?, int(3)?).map_err(|m| err(ln, m))?;
        if row.component == Component::U || col.component == Component::U {
            return Err(err(
                ln,
                "DOF 0: Abaqus numbers the DOFs of a node 1 to 6".to_string(),
            ));
        }
        let value = f[4]
            .replace(['D', 'd'], "E")
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| err(ln, format!("value {} is not a finite number", quoted(f[4]))))?;
        entries.push(LabelledEntry {
            row,
            col,
            value,
            line: ln,
        });
    }
    if entries.is_empty() {
        return Err(err(1, "no matrix entry".into()));
    }
    let name = path
        .file_name()
        .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
    Ok(LabelledMatrix {
        path: path.to_path_buf(),
        name,
        entries,
    })
}

/// The DOF map of a model whose mass and stiffness come as `mats`: every label any of them
/// names, in label order (node, then component: the order Nastran's and Abaqus's own DOF
/// numbering follows).
pub fn union_dofs(mats: &[&LabelledMatrix]) -> Result<DofMap> {
    let all: BTreeSet<DofLabel> = mats.iter().flat_map(|m| m.labels()).collect();
    Ok(DofMap::new(all.into_iter().collect())?)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nastran_reals_in_every_notation() {
        for (s, v) in [
            ("1.5", 1.5),
            ("1.5E+3", 1500.0),
            ("1.5D+03", 1500.0),
            ("1.5+3", 1500.0),
            ("-.5-2", -0.005),
            ("7.", 7.0),
            ("-2.5-05", -2.5e-5),
        ] {
            assert_eq!(nastran_real(s), Some(v), "{s}");
        }
        for s in ["", "x", "1.5E+400", "1..2", "nan", "inf"] {
            assert_eq!(nastran_real(s), None, "{s}");
        }
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
            let got: Vec<_> = m.entries.iter().map(|e| (e.row, e.col, e.value)).collect();
            assert_eq!(got, want, "{text}");
            let dofs = union_dofs(&[&m]).unwrap();
            let k = m.onto(&dofs, "stiffness matrix").unwrap().to_dense();
            assert_eq!(k[(0, 1)], -1e6);
            assert_eq!(k[(1, 0)], -1e6);
        }
    }

    #[test]
    fn symmetric_storage_is_checked() {
        let p = Path::new("k.mtx");
        let both = "1,3,1,3,2.0\n1,3,2,3,-1.0\n2,3,1,3,-1.0\n2,3,2,3,1.0\n";
        let m = parse_abaqus(both, p).unwrap();
        let dofs = union_dofs(&[&m]).unwrap();
        assert_eq!(m.onto(&dofs, "K").unwrap().get(0, 1), -1.0);
        let differ = "1,3,1,3,2.0\n1,3,2,3,-1.0\n2,3,1,3,-1.5\n";
        let e = parse_abaqus(differ, p)
            .unwrap()
            .onto(&dofs, "K")
            .unwrap_err()
            .to_string();
        assert!(e.contains("k.mtx:3") && e.contains("differ"), "{e}");
        let again = "1,3,1,3,2.0\n1,3,1,3,2.0\n";
        let e = parse_abaqus(again, p)
            .unwrap()
            .onto(&dofs, "K")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("k.mtx:2") && e.contains("first on line 1"),
            "{e}"
        );
    }

    #[test]
    fn bad_entries_name_line_and_field() {
        let p = Path::new("m.mtx");
        for (text, want) in [
            ("1,3,1,3\n", "m.mtx:1: 4 fields"),
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
