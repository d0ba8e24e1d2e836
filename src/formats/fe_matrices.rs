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
use std::borrow::Cow;
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
struct Interner {
    index: HashMap<DofLabel, usize, std::hash::BuildHasherDefault<LabelHasher>>,
    list: Vec<DofLabel>,
}

impl Interner {
    fn id(&mut self, l: DofLabel) -> usize {
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
    /// Every DOF an entry names, in label order (node, then component).
    pub fn labels(&self) -> BTreeSet<DofLabel> {
        self.labels.iter().copied().collect()
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
        symmetric_from_entries(
            &self.path,
            &format!("{what} {}", self.name),
            dofs,
            &indexed,
            Place::Line,
        )
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

/// A symmetric matrix on `dofs` from stored entries `(row, col, value, place)` of `path`
/// (named `what` in errors; `place` a line or record number as `unit` says): one triangle, or
/// both when each entry and its mirror are equal to the bit; an entry given twice is refused
/// with both places.
pub fn symmetric_from_entries(
    path: &Path,
    what: &str,
    dofs: &DofMap,
    entries: &[(usize, usize, f64, usize)],
    unit: Place,
) -> Result<SparseSym> {
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
    let hi = |k: usize| entries[k].0.max(entries[k].1);
    let below = |k: usize| entries[k].0 >= entries[k].1;
    let mut lower = Vec::with_capacity(entries.len());
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
            lower.push((h, c, entries[f].2));
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
                    let (row, column) = names();
                    return Err(err(
                        here,
                        format!(
                            "entry ({row}, {column}) = {value:e} and its mirror on {at} {line} = \
                             {v:e} differ: the matrix is not symmetric"
                        ),
                    ));
                }
            }
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
    Ok(SparseSym::from_lower_triplets(what, dofs.len(), &lower)?)
}

/// The format of an FE matrix file by extension and content: `.pch`, `.bdf`, `.dat`, `.nas`
/// → DMIG; `.mtx` → Abaqus unless it starts with `%%MatrixMarket`; `.rsa`, `.rua`, `.hb`,
/// `.rb`, `.matrix` (HBMAT's default) → Harwell–Boeing (`None`: not an FE-code format, e.g.
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
        "rsa" | "rua" | "hb" | "rb" | "matrix" => Some(FeFormat::HarwellBoeing),
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
        FeFormat::HarwellBoeing => {
            let map_path = mapping_path(path);
            if !map_path.is_file() {
                return Err(Error::Usage(format!(
                    "{}: a Harwell-Boeing file carries no DOF labels: nlsim reads them from \
                     {}, which is missing (write it with HBMAT, ..., Mapping = YES)",
                    path.display(),
                    map_path.display()
                )));
            }
            let map_text = crate::formats::files::read_text_bounded(&map_path, MAX_FE_FILE_BYTES)?;
            let labels = parse_mapping(&map_text, &map_path)?;
            let hb = parse_harwell_boeing(&text, path)?;
            if labels.len() != hb.n {
                return Err(Error::Usage(format!(
                    "{} maps {} equations, the matrix {} has {}",
                    map_path.display(),
                    labels.len(),
                    path.display(),
                    hb.n
                )));
            }
            let name = path
                .file_name()
                .map_or_else(String::new, |n| n.to_string_lossy().into_owned());
            Ok(LabelledMatrix {
                path: path.to_path_buf(),
                name,
                labels,
                entries: hb.entries,
            })
        }
    }
}

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
    if let Some(k) = lines.iter().position(|l| !l.is_ascii()) {
        return Err(err(k + 1, "a non-ASCII character".into()));
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

/// Splits a physical line: its first field is returned, its data fields are appended to
/// `out` (borrowed from the line unless tabs had to be expanded).
fn split_line<'a>(raw: &'a str, out: &mut Vec<Cow<'a, str>>) -> Cow<'a, str> {
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
        let first = split_expanded(&l, &mut fields).into_owned();
        out.extend(fields.into_iter().map(|f| Cow::Owned(f.into_owned())));
        return Cow::Owned(first);
    }
    split_expanded(raw, out)
}

/// [`split_line`] of a line without tabs.
fn split_expanded<'a>(line: &'a str, out: &mut Vec<Cow<'a, str>>) -> Cow<'a, str> {
    if line.contains(',') {
        let mut it = line.split(',').map(|s| Cow::Borrowed(s.trim()));
        let first = it.next().unwrap_or_default();
        // A free-field card holds at most 8 data fields per line; a ninth is the marker.
        out.extend(it.take(8));
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
}

/// Calls `f(fields, line)` for each card of a bulk-data text (its data fields, continuations
/// appended, and the line it starts on), one card at a time; comments `$` and blank lines are
/// skipped, cards after `ENDDATA` ignored; `keep(name, fields of the first line)` decides
/// which cards are passed (others are skipped with their continuations, unsplit).
fn each_card<'a>(
    text: &'a str,
    mut keep: impl FnMut(&str, &[Cow<'a, str>]) -> bool,
    mut f: impl FnMut(&[Cow<'a, str>], usize) -> Result<()>,
) -> Result<()> {
    let mut cur: Vec<Cow<'a, str>> = Vec::new();
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
        let first = split_line(raw, &mut cur);
        let continuation = first.is_empty() || first.starts_with('+') || first.starts_with('*');
        if continuation {
            if !keeping {
                cur.truncate(at);
            }
            continue;
        }
        // A new card: the previous one is complete.
        let fields: Vec<Cow<'a, str>> = cur.drain(at..).collect();
        if keeping {
            f(&cur, cur_line)?;
        }
        cur.clear();
        cur.extend(fields);
        let name = first.trim_end_matches('*').to_ascii_uppercase();
        if name == "ENDDATA" {
            cur.clear();
            keeping = false;
            break;
        }
        keeping = keep(&name, &cur);
        cur_line = i + 1;
        if !keeping {
            cur.clear();
        }
    }
    if keeping {
        f(&cur, cur_line)?;
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
    each_card(text, keep, |fields, line| {
        let c = Card { fields, line };
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
            entries.push((labels.id(row), col_id, value, c.line));
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

/// The matrix of an Abaqus `*MATRIX GENERATE` coordinate file (`NODE_I, DOF_I, NODE_J, DOF_J,
/// VALUE` per line, commas or blanks between). Errors name the file and line.
pub fn parse_abaqus(text: &str, path: &Path) -> Result<LabelledMatrix> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let mut entries = Vec::new();
    let mut labels = Interner::default();
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
        entries.push((labels.id(row), labels.id(col), value, ln));
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
        labels: labels.list,
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
            let got: Vec<_> = m
                .entries
                .iter()
                .map(|e| (m.labels[e.0], m.labels[e.1], e.2))
                .collect();
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
