//! The `[geometry]` table: node coordinates for the files that carry geometry (universal
//! dataset 2411 beside the functions and shapes nlsim writes). No analysis uses them.
//!
//! `nodes` is inline, `[[1, 0.0, 0.0, 0.0], [2, 0.07, 0.0, 0.0]]` (node id, x, y, z in m), or
//! the path of a file (relative to the model file): a Nastran bulk-data deck (`.bdf`, `.dat`,
//! `.nas`, `.blk`, `.pch`: its `GRID` cards, [`crate::formats::dmig::parse_grids`]), an Abaqus
//! input file (`.inp`: its `*NODE` blocks, [`crate::formats::abaqus::parse_inp_nodes`]), or
//! else a CSV file with one node per line, `node,x,y,z` (a first line that is not numbers is
//! a header, lines starting with `#` are comments).

use super::toml::{Tab, number};
use crate::error::{Error, Result};
use crate::formats::fe_matrices::MAX_GEOMETRY_NODES as MAX_NODES;
use std::path::Path;
use toml::de::DeValue;

/// The most bytes a file of nodes may have: 10⁷ lines of about 100 characters.
const MAX_FILE_BYTES: u64 = 1 << 30;

/// Reads `[geometry]`: `nodes` inline or from a CSV file beside the model file.
pub(super) fn read_geometry(t: &mut Tab<'_, '_>, base_dir: &Path) -> Result<Vec<(u64, [f64; 3])>> {
    let v = t.get("nodes").ok_or_else(|| {
        t.missing(
            "nodes",
            "the node coordinates: nodes = [[1, 0.0, 0.0, 0.0], ...] (id, x, y, z in m) or the \
             path of a CSV file node,x,y,z",
        )
    })?;
    match v.get_ref() {
        DeValue::String(s) => read_file(&base_dir.join(s.as_ref())),
        DeValue::Array(rows) => {
            if rows.len() > MAX_NODES {
                return Err(t.err(
                    v,
                    "nodes",
                    format!("{} nodes exceed the limit of {MAX_NODES}", rows.len()),
                ));
            }
            let mut out = Vec::with_capacity(rows.len());
            for (i, row) in rows.iter().enumerate() {
                let bad = || {
                    t.err(
                        row,
                        "nodes",
                        format!(
                            "entry {}: expected [node id, x, y, z] (a positive integer id, \
                             three finite coordinates in m)",
                            i + 1
                        ),
                    )
                };
                let DeValue::Array(cells) = row.get_ref() else {
                    return Err(bad());
                };
                if cells.len() != 4 {
                    return Err(bad());
                }
                let id = match cells[0].get_ref() {
                    DeValue::Integer(n) => n.as_str().parse::<u64>().ok().filter(|&n| n > 0),
                    _ => None,
                }
                .ok_or_else(bad)?;
                let mut xyz = [0.0; 3];
                for (x, c) in xyz.iter_mut().zip(&cells[1..]) {
                    *x = number(c).ok_or_else(bad)?;
                }
                out.push((id, xyz));
            }
            Ok(out)
        }
        _ => Err(t.err(
            v,
            "nodes",
            "expected a list of [node id, x, y, z] or the path of a CSV file",
        )),
    }
}

/// Reads the nodes of a file by its extension: Nastran bulk data, an Abaqus input file, or
/// CSV.
fn read_file(path: &Path) -> Result<Vec<(u64, [f64; 3])>> {
    let text = crate::formats::files::read_text_bounded(path, MAX_FILE_BYTES)?;
    let ext = path
        .extension()
        .map(|e| e.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "bdf" | "dat" | "nas" | "blk" | "pch" => crate::formats::dmig::parse_grids(&text, path),
        "inp" => crate::formats::abaqus::parse_inp_nodes(&text, path),
        _ => read_csv(&text, path),
    }
}

/// Reads a CSV text of `node,x,y,z` lines (header and `#` comments allowed) from `path`.
fn read_csv(text: &str, path: &Path) -> Result<Vec<(u64, [f64; 3])>> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.trim();
        if l.is_empty() || l.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = l.split(',').map(str::trim).collect();
        let parsed = (cells.len() == 4)
            .then(|| {
                let id = cells[0].parse::<u64>().ok().filter(|&n| n > 0)?;
                let mut xyz = [0.0; 3];
                for (x, c) in xyz.iter_mut().zip(&cells[1..]) {
                    *x = c.parse::<f64>().ok().filter(|v| v.is_finite())?;
                }
                Some((id, xyz))
            })
            .flatten();
        match parsed {
            Some(n) => {
                if out.len() == MAX_NODES {
                    return Err(Error::Usage(format!(
                        "{}:{}: more than {MAX_NODES} nodes",
                        path.display(),
                        i + 1
                    )));
                }
                out.push(n);
            }
            // A header: the first line that is not a node.
            None if out.is_empty() && i == first_line(text) => {}
            None => {
                return Err(Error::Usage(format!(
                    "{}:{}: expected node,x,y,z (a positive integer id, three finite \
                     coordinates in m), found '{}'",
                    path.display(),
                    i + 1,
                    l.chars().take(60).collect::<String>()
                )));
            }
        }
    }
    if out.is_empty() {
        return Err(Error::Usage(format!(
            "{}: no node lines (node,x,y,z)",
            path.display()
        )));
    }
    Ok(out)
}

/// The index of the first line that is neither empty nor a comment.
fn first_line(text: &str) -> usize {
    text.lines()
        .position(|l| {
            let l = l.trim();
            !l.is_empty() && !l.starts_with('#')
        })
        .unwrap_or(0)
}
