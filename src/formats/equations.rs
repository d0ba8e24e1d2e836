//! The node and DOF of each equation of a matrix file that numbers its equations only
//! (Matrix Market, HDF5, OUTPUT4, 3-column Abaqus `FORMAT=COORDINATE` output, Harwell–Boeing
//! without its mapping), from what a model file's `[matrices] dofs` names: a labels file
//! (one `NODE:DOF` per equation), the Abaqus job's input file (`.inp`,
//! [`crate::formats::abaqus::inp_equation_labels`]), or the DOF mapping vector Ansys exports
//! beside `*EXPORT, ..., MMF` matrices ([`parse_ansys_mapping_vector`]).

use crate::error::{Error, Result};
use crate::formats::fe_matrices::label;
use crate::formats::files::quoted;
use nlsim_kernel::DofLabel;
use std::collections::HashMap;
use std::path::Path;

/// Largest labels, input or mapping file read (bytes).
pub const MAX_EQUATIONS_FILE_BYTES: u64 = 4 << 30;

/// The labels of the `n` equations of a matrix (`n`: its order) from the file `path`, by its
/// kind: `.inp` → the Abaqus job's equations; a Matrix Market integer array → Ansys's DOF
/// mapping vector; anything else → a labels file. Every label distinct.
pub fn equation_labels(path: &Path, n: usize) -> Result<Vec<DofLabel>> {
    let bytes = crate::formats::files::read_bytes_up_to(path, Some(MAX_EQUATIONS_FILE_BYTES))?;
    // Titles and comments may be in any 8-bit code page: decoded lossily, and data lines
    // are checked by the parsers.
    let text = String::from_utf8_lossy(&bytes);
    let inp = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("inp"));
    let labels = if inp {
        crate::formats::abaqus::inp_equation_labels(&text, path)?
    } else if is_mapping_vector(&text) {
        parse_ansys_mapping_vector(&text, path, n)?
    } else {
        crate::formats::matrices::parse_dof_labels(&text, path)?
    };
    distinct(&labels, path)?;
    Ok(labels)
}

/// Whether `text` is a Matrix Market integer array (the form of Ansys's mapping vector).
pub fn is_mapping_vector(text: &str) -> bool {
    let head: Vec<String> = text
        .lines()
        .next()
        .unwrap_or("")
        .split_whitespace()
        .map(str::to_ascii_lowercase)
        .collect();
    head.len() >= 4 && head[0] == "%%matrixmarket" && head[2] == "array" && head[3] == "integer"
}

/// Refuses a label given to two equations, naming both.
fn distinct(labels: &[DofLabel], path: &Path) -> Result<()> {
    let mut seen: HashMap<DofLabel, usize> = HashMap::with_capacity(labels.len());
    for (k, l) in labels.iter().enumerate() {
        if let Some(first) = seen.insert(*l, k) {
            return Err(Error::Usage(format!(
                "{}: DOF {l} labels equations {} and {}: each equation needs its own DOF",
                path.display(),
                first + 1,
                k + 1
            )));
        }
    }
    Ok(())
}

/// The equation labels of an Ansys DOF mapping vector (`*SMAT`/`*DMAT` mapping exported with
/// `*EXPORT, ..., MMF`: a Matrix Market `array integer` file of one column), for a matrix of
/// order `n`: entry k is the node whose DOFs are the matrix's equations `d·k + 1 … d·k + d`,
/// `d = n / entries` — 3 (UX, UY, UZ), 6 (UX … ROTZ) or 2 (UX, UY). Other ratios are refused
/// (the vector does not say which DOFs a node has then: give a labels file).
pub fn parse_ansys_mapping_vector(text: &str, path: &Path, n: usize) -> Result<Vec<DofLabel>> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let mut size: Option<(usize, usize)> = None;
    let mut nodes: Vec<(i64, usize)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let t = raw.trim();
        if t.is_empty() || t.starts_with('%') {
            continue;
        }
        let f: Vec<&str> = t.split_whitespace().collect();
        match size {
            None => {
                let dims: Vec<usize> = f.iter().filter_map(|x| x.parse().ok()).collect();
                if f.len() != 2 || dims.len() != 2 || dims[1] != 1 || dims[0] == 0 {
                    return Err(err(
                        ln,
                        format!(
                            "expected the size line 'ROWS 1' of a one-column mapping vector, \
                             found {}",
                            quoted(t)
                        ),
                    ));
                }
                if dims[0] > n {
                    return Err(err(
                        ln,
                        format!(
                            "the vector maps {} nodes, more than the matrix's {n} equations",
                            dims[0]
                        ),
                    ));
                }
                size = Some((dims[0], ln));
                nodes.reserve(dims[0]);
            }
            Some((rows, _)) => {
                if f.len() != 1 {
                    return Err(err(
                        ln,
                        format!("expected one node number per line, found {}", quoted(t)),
                    ));
                }
                if nodes.len() == rows {
                    return Err(err(
                        ln,
                        format!("more than the {rows} entries the size line announces"),
                    ));
                }
                let node = f[0].parse::<i64>().ok().filter(|&v| v > 0).ok_or_else(|| {
                    err(
                        ln,
                        format!("node {} is not a positive integer", quoted(f[0])),
                    )
                })?;
                nodes.push((node, ln));
            }
        }
    }
    let Some((rows, size_line)) = size else {
        return Err(err(
            1,
            "no size line: the file holds no mapping vector".into(),
        ));
    };
    if nodes.len() != rows {
        return Err(err(
            text.lines().count().max(1),
            format!(
                "the size line (line {size_line}) announces {rows} entries, the file holds {}",
                nodes.len()
            ),
        ));
    }
    let d = n / rows;
    let comps: &[i64] = match (n % rows, d) {
        (0, 3) => &[1, 2, 3],
        (0, 6) => &[1, 2, 3, 4, 5, 6],
        (0, 2) => &[1, 2],
        _ => {
            return Err(err(
                size_line,
                format!(
                    "{rows} nodes for a matrix of {n} equations: nlsim reads mapping vectors \
                     of 2, 3 or 6 DOFs per node (UX, UY[, UZ][, ROTX, ROTY, ROTZ]); give the \
                     equations' labels as a dofs file"
                ),
            ));
        }
    };
    let mut out = Vec::with_capacity(n);
    for (node, ln) in nodes {
        for &c in comps {
            out.push(label(node, c).map_err(|m| err(ln, m))?);
        }
    }
    Ok(out)
}
