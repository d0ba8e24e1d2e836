//! The core of the FE codes' matrix files, which carry the node and DOF labels of the model
//! that wrote them: a matrix read from one is a [`LabelledMatrix`] (its entries by label, with
//! the file line of each) until [`LabelledMatrix::onto`] places it on a model's DOFs, where
//! symmetric storage is resolved (one triangle, or both when the two agree to the bit) and
//! every repeat is refused with both lines named.
//!
//! Node `G` with component `C` (1–6: translations x, y, z, rotations about x, y, z; 0: a
//! scalar point) becomes the label `G:ux` … `G:rz` (`G:u` for a scalar point), so a model's
//! elements, excitations and sensors name the engineer's own grid numbers. The readers:
//! [`crate::formats::dmig`] (Nastran DMIG), [`crate::formats::abaqus`] (Abaqus `*MATRIX
//! GENERATE` coordinate output), [`crate::formats::harwell_boeing`] (Ansys `HBMAT` with its
//! mapping file); [`crate::formats::fe_read`] picks one by format; Nastran OUTPUT4, which has
//! no labels, is [`crate::formats::op4`].

use crate::error::{Error, Result};
use nlsim_kernel::{Component, DofLabel, DofMap, SparseSym};
use std::collections::{BTreeSet, HashMap};
use std::path::{Path, PathBuf};

/// Largest FE matrix file read (bytes): 16 GiB, a 10⁶-DOF model's stiffness with room.
pub const MAX_FE_FILE_BYTES: u64 = 16 << 30;

/// The FE-code formats [`crate::formats::fe_read::read`] takes (`format =` in a model file's `[matrices]`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FeFormat {
    /// Nastran DMIG entries (punch or bulk data).
    Dmig,
    /// Abaqus `*MATRIX GENERATE` coordinate output.
    Abaqus,
    /// Harwell–Boeing (Ansys `HBMAT`), labelled by the `.mapping` file beside it.
    HarwellBoeing,
}

impl FeFormat {
    /// The format's name in model files: `dmig` or `abaqus`.
    pub fn as_str(self) -> &'static str {
        match self {
            FeFormat::Dmig => "dmig",
            FeFormat::Abaqus => "abaqus",
            FeFormat::HarwellBoeing => "harwell-boeing",
        }
    }

    /// The format of a name as model files give it.
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "dmig" | "nastran-dmig" | "punch" => Some(FeFormat::Dmig),
            "abaqus" | "abaqus-mtx" => Some(FeFormat::Abaqus),
            "harwell-boeing" | "hb" | "hbmat" | "ansys" => Some(FeFormat::HarwellBoeing),
            _ => None,
        }
    }
}

/// A fast hasher for DOF labels (a node number and a component): multiply–rotate mixing of
/// the integers hashed (not DoS-resistant; the keys come from a file the user chose).
#[derive(Default, Clone, Copy)]
struct LabelHasher(u64);

impl std::hash::Hasher for LabelHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(u64::from(b));
        }
    }
    fn write_u64(&mut self, x: u64) {
        self.0 = (self.0.rotate_left(5) ^ x).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
    fn write_u8(&mut self, x: u8) {
        self.write_u64(u64::from(x));
    }
    fn write_u32(&mut self, x: u32) {
        self.write_u64(u64::from(x));
    }
    fn write_usize(&mut self, x: usize) {
        self.write_u64(x as u64);
    }
    fn write_isize(&mut self, x: isize) {
        self.write_u64(x as u64);
    }
}

/// The distinct labels of a file in the order first met, each with its index.
#[derive(Default)]
pub(crate) struct Interner {
    index: HashMap<DofLabel, usize, std::hash::BuildHasherDefault<LabelHasher>>,
    /// The labels in the order first met.
    pub(crate) list: Vec<DofLabel>,
}

impl Interner {
    /// The index of `l`, given it if new.
    pub(crate) fn id(&mut self, l: DofLabel) -> usize {
        let next = self.list.len();
        let id = *self.index.entry(l).or_insert(next);
        if id == next {
            self.list.push(l);
        }
        id
    }
}

/// A square matrix read from an FE code's file, by node/DOF label.
#[derive(Debug, Clone)]
pub struct LabelledMatrix {
    /// The file.
    pub path: PathBuf,
    /// The matrix's name in the file (DMIG name; the file name for Abaqus and Harwell–Boeing).
    pub name: String,
    /// The distinct DOF labels the entries name (each once, in the order the file first
    /// names them).
    pub labels: Vec<DofLabel>,
    /// The entries as stored (one triangle or both): `(row, col, value, line)` with `row` and
    /// `col` indices into [`labels`](Self::labels), the value in SI units (kg for mass, N/m
    /// for stiffness) and the 1-based line it was read from (the card's first line for DMIG).
    pub entries: Vec<(usize, usize, f64, usize)>,
}

impl LabelledMatrix {
    /// The only matrix of the file `path` (Abaqus, Harwell–Boeing): named by the file name.
    pub fn named_by_file(
        path: &Path,
        labels: Vec<DofLabel>,
        entries: Vec<(usize, usize, f64, usize)>,
    ) -> Self {
        LabelledMatrix {
            path: path.to_path_buf(),
            name: path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned()),
            labels,
            entries,
        }
    }

    /// Every DOF an entry names, in label order (node, then component).
    pub fn labels(&self) -> BTreeSet<DofLabel> {
        self.labels.iter().copied().collect()
    }

    /// The matrix on the DOFs of `dofs` (named `what` in errors): symmetric storage resolved
    /// (an entry and its mirror may both be given when they agree within `tolerance`,
    /// [`symmetric_from_entries`]), repeats refused,
    /// every label required to be one of `dofs` (else the DOF was constrained out of the
    /// model's other matrix, or the label is not the model's).
    pub fn onto(&self, dofs: &DofMap, what: &str, tolerance: f64) -> Result<SparseSym> {
        self.onto_measured(dofs, what, tolerance).map(|(m, _)| m)
    }

    /// [`onto`](Self::onto) with the largest relative difference of the mirrors averaged
    /// ([`symmetric_measured`]).
    pub fn onto_measured(
        &self,
        dofs: &DofMap,
        what: &str,
        tolerance: f64,
    ) -> Result<(SparseSym, f64)> {
        let err = |line: usize, m: String| Error::DataFile {
            file: self.path.clone(),
            line,
            message: format!("{what} {}: {m}", self.name),
        };
        let place: Vec<Option<usize>> = self.labels.iter().map(|l| dofs.index_of(l).ok()).collect();
        let mut indexed = Vec::with_capacity(self.entries.len());
        for &(r, c, value, line) in &self.entries {
            let index = |k: usize| {
                place.get(k).copied().flatten().ok_or_else(|| {
                    let l = self
                        .labels
                        .get(k)
                        .map_or_else(|| format!("#{k}"), |l| l.to_string());
                    err(
                        line,
                        format!(
                            "DOF {l} is not a DOF of the model (it is in none of its matrices' \
                             labels)"
                        ),
                    )
                })
            };
            indexed.push((index(r)?, index(c)?, value, line));
        }
        symmetric_measured(
            &self.path,
            &format!("{what} {}", self.name),
            dofs,
            &indexed,
            Place::Line,
            tolerance,
        )
    }
}

/// A matrix read from an FE code's file: labelled by the file itself (DMIG, 5-column Abaqus,
/// Harwell–Boeing with its `.mapping`), or numbered by equation only (3-column Abaqus
/// `FORMAT=COORDINATE` output, Harwell–Boeing without a mapping), whose labels come from a
/// model file's `dofs` ([`crate::formats::equations`]).
#[derive(Debug, Clone)]
pub enum FeMatrix {
    /// Entries by node/DOF label.
    Labelled(LabelledMatrix),
    /// Entries by equation number.
    Numbered(NumberedMatrix),
}

/// A square matrix whose file numbers its equations without saying which node and DOF each
/// is: Abaqus `*MATRIX OUTPUT, FORMAT=COORDINATE` (`ROW, COLUMN, VALUE` by global equation),
/// Harwell–Boeing without its mapping file.
#[derive(Debug, Clone)]
pub struct NumberedMatrix {
    /// The file.
    pub path: PathBuf,
    /// The highest equation an entry names (the matrix's order as far as the file shows).
    pub n: usize,
    /// The entries as stored: `(row, col, value, line)`, `row` and `col` 0-based equations.
    pub entries: Vec<(usize, usize, f64, usize)>,
    /// What the file is, for errors: e.g. "Abaqus COORDINATE output (…)".
    pub kind: String,
}

impl NumberedMatrix {
    /// The matrix labelled by `labels` (equation k is `labels[k]`), named `source` (the file
    /// or list the labels came from) in errors: every equation an entry names must have a
    /// label.
    pub fn labelled(self, labels: &[DofLabel], source: &str) -> Result<LabelledMatrix> {
        if self.n > labels.len() {
            let line = self
                .entries
                .iter()
                .find(|e| e.0.max(e.1) >= labels.len())
                .map_or(1, |e| e.3);
            return Err(Error::DataFile {
                file: self.path.clone(),
                line,
                message: format!(
                    "equation {} is past the {} DOF labels of {source} (the file numbers {} \
                     equations)",
                    labels.len() + 1,
                    labels.len(),
                    self.n
                ),
            });
        }
        Ok(LabelledMatrix::named_by_file(
            &self.path,
            labels.to_vec(),
            self.entries,
        ))
    }
}

/// Where an entry of an FE file was read: a text line or a binary record.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Place {
    /// 1-based line of a text file.
    Line,
    /// 1-based record of a binary file.
    Record,
}

/// How far an entry and its mirror may differ and still be one symmetric entry (their mean),
/// relative to the larger of the largest magnitudes in their two columns: FE codes that
/// store both triangles (Nastran's OUTPUT4 of KAA/MAA, reduced EXTSEOUT matrices) write
/// mirrors that differ in the last bits (6e-16 of the column's largest in the files of
/// `tests/data/fe_real`). A model file's `[matrices] symmetry_tolerance` sets another.
pub const SYMMETRY_TOLERANCE: f64 = 1e-12;

/// A symmetric matrix on `dofs` from stored entries `(row, col, value, place)` of `path`
/// (named `what` in errors; `place` a line or record number as `unit` says): one triangle, or
/// both when each entry and its mirror agree within `tolerance` of the larger of their two
/// columns' largest magnitudes (the mean is taken; [`SYMMETRY_TOLERANCE`]); beyond it the
/// matrix is refused with both values. An entry given twice is refused with both places.
pub fn symmetric_from_entries(
    path: &Path,
    what: &str,
    dofs: &DofMap,
    entries: &[(usize, usize, f64, usize)],
    unit: Place,
    tolerance: f64,
) -> Result<SparseSym> {
    symmetric_measured(path, what, dofs, entries, unit, tolerance).map(|(m, _)| m)
}

/// [`symmetric_from_entries`] with the largest difference between an entry and its mirror
/// that was averaged, relative to the larger of their columns' largest magnitudes (0 when
/// one triangle was stored or every mirror agreed to the bit): what `nlsim check` reports.
pub fn symmetric_measured(
    path: &Path,
    what: &str,
    dofs: &DofMap,
    entries: &[(usize, usize, f64, usize)],
    unit: Place,
    tolerance: f64,
) -> Result<(SparseSym, f64)> {
    let err = |line: usize, m: String| match unit {
        Place::Line => Error::DataFile {
            file: path.to_path_buf(),
            line,
            message: format!("{what}: {m}"),
        },
        Place::Record => Error::Usage(format!("{}: record {line}: {what}: {m}", path.display())),
    };
    let at = match unit {
        Place::Line => "line",
        Place::Record => "record",
    };
    let n = dofs.len();
    // The entries bucketed by their lower-triangle column min(i, j) (a counting sort), then
    // each column's by row max(i, j) and file order: an entry and its mirror, or a repeat,
    // become neighbours. O(entries) but for the short per-column sorts.
    let mut start = vec![0usize; n + 1];
    for &(i, j, _, line) in entries {
        if i >= n || j >= n {
            return Err(err(
                line,
                format!("entry ({}, {}) is outside the {n} DOFs", i + 1, j + 1),
            ));
        }
        start[i.min(j) + 1] += 1;
    }
    for c in 0..n {
        start[c + 1] += start[c];
    }
    let mut next = start.clone();
    let mut order = vec![0usize; entries.len()];
    for (k, &(i, j, _, _)) in entries.iter().enumerate() {
        let c = i.min(j);
        order[next[c]] = k;
        next[c] += 1;
    }
    // The largest magnitude of each column (a symmetric matrix's row i is its column i).
    let mut largest = vec![0.0f64; n];
    for &(i, j, v, _) in entries {
        largest[i] = largest[i].max(v.abs());
        largest[j] = largest[j].max(v.abs());
    }
    let hi = |k: usize| entries[k].0.max(entries[k].1);
    let below = |k: usize| entries[k].0 >= entries[k].1;
    let mut lower = Vec::with_capacity(entries.len());
    let mut worst = 0.0f64;
    for c in 0..n {
        let col = &mut order[start[c]..start[c + 1]];
        col.sort_unstable_by_key(|&k| (hi(k), k));
        let mut g = 0;
        while g < col.len() {
            let h = hi(col[g]);
            let mut e = g + 1;
            while e < col.len() && hi(col[e]) == h {
                e += 1;
            }
            // In file order: the first, its mirror (the only other entry allowed), then repeats.
            let f = col[g];
            let mut value_here = entries[f].2;
            if e - g >= 2 {
                let k = col[g + 1];
                let (i, j, value, here) = entries[k];
                let (_, _, v, line) = entries[f];
                let names = || (dofs.describe(i), dofs.describe(j));
                if below(f) == below(k) || i == j {
                    let (row, column) = names();
                    return Err(err(
                        here,
                        format!("entry ({row}, {column}) is given again (first on {at} {line})"),
                    ));
                }
                if v.to_bits() != value.to_bits() {
                    let scale = largest[i].max(largest[j]);
                    if (v - value).abs() > tolerance * scale {
                        let (row, column) = names();
                        return Err(err(
                            here,
                            format!(
                                "entry ({row}, {column}) = {value:e} and its mirror on {at} \
                                 {line} = {v:e} differ by {:.1e} of the columns' largest \
                                 magnitude, more than the symmetry tolerance {tolerance:e}: the \
                                 matrix is not symmetric ([matrices] symmetry_tolerance sets \
                                 another)",
                                (v - value).abs() / scale
                            ),
                        ));
                    }
                    value_here = 0.5 * (v + value);
                    worst = worst.max((v - value).abs() / scale);
                }
            }
            lower.push((h, c, value_here));
            if e - g >= 3 {
                let k = col[g + 2];
                let (i, j, _, here) = entries[k];
                let same = if below(col[g]) == below(k) {
                    col[g]
                } else {
                    col[g + 1]
                };
                return Err(err(
                    here,
                    format!(
                        "entry ({}, {}) is given again (first on {at} {})",
                        dofs.describe(i),
                        dofs.describe(j),
                        entries[same].3
                    ),
                ));
            }
            g = e;
        }
    }
    Ok((
        SparseSym::from_lower_triplets(what, dofs.len(), &lower)?,
        worst,
    ))
}

/// The format of an FE matrix file by extension and content: `.pch`, `.bdf`, `.dat`, `.nas`
/// → DMIG; `.mtx` → Abaqus unless it starts with `%%MatrixMarket`; `.hb`, `.rb`, `.matrix`
/// (HBMAT's default) and the Harwell–Boeing types (`.rsa`, `.rua`, `.pse`, `.csa`, …) →
/// Harwell–Boeing (`None`: not an FE-code format, e.g.
/// Matrix Market or HDF5).
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
        "hb" | "rb" | "matrix" => Some(FeFormat::HarwellBoeing),
        // The collection's names: the type as the extension (RSA, RUA, PSE, CSA, ...).
        t if t.len() == 3
            && matches!(t.as_bytes()[0], b'r' | b'c' | b'p')
            && matches!(t.as_bytes()[1], b's' | b'u' | b'h' | b'z' | b'r')
            && matches!(t.as_bytes()[2], b'a' | b'e') =>
        {
            Some(FeFormat::HarwellBoeing)
        }
        "mtx" => {
            use std::io::Read;
            crate::formats::files::input_file(path)?;
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

/// A label from an FE code's node and component numbers (component 0: scalar point).
pub(crate) fn label(node: i64, component: i64) -> std::result::Result<DofLabel, String> {
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

/// The most nodes a geometry may hold, from a model file's `[geometry]` or an FE deck's node
/// coordinates (10⁷: a mesh of 3·10⁷ DOFs).
pub const MAX_GEOMETRY_NODES: usize = 10_000_000;

/// A real in Nastran's notation: `1.5`, `1.5E+3`, `1.5D+3`, `1.5+3`, `-.5-2`.
pub fn nastran_real(s: &str) -> Option<f64> {
    let t = s.trim();
    if t.is_empty() || t.len() > 40 {
        return None;
    }
    // `D` exponents as `E`, on the stack (no allocation per value).
    let mut buf = [0u8; 40];
    for (k, &b) in t.as_bytes().iter().enumerate() {
        buf[k] = if b == b'D' || b == b'd' { b'E' } else { b };
    }
    let t = std::str::from_utf8(&buf[..t.len()]).ok()?;
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

/// The DOF map of a model whose mass and stiffness come as `mats`: every label any of them
/// names, in label order (node, then component: the order Nastran's and Abaqus's own DOF
/// numbering follows).
pub fn union_dofs(mats: &[&LabelledMatrix]) -> Result<DofMap> {
    let all: BTreeSet<DofLabel> = mats.iter().flat_map(|m| m.labels()).collect();
    Ok(DofMap::new(all.into_iter().collect())?)
}

/// The line `nlsim check` prints for a matrix whose two stored triangles were averaged
/// (`None` when nothing was: one triangle stored, or mirrors equal to the bit).
pub fn asymmetry_note(what: &str, path: &Path, largest: f64, tolerance: f64) -> Option<String> {
    (largest > 0.0).then(|| {
        format!(
            "{what} ({}): both triangles stored; mirrors averaged, the largest differs by \
             {largest:.1e} of its columns' largest magnitude (symmetry_tolerance {tolerance:e})",
            path.display()
        )
    })
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
}
