//! Mode shapes as Universal File Format dataset 55 ("data at nodes", analysis type 2 =
//! normal mode), the form in which test software (and pyuff) exchanges modes.
//!
//! One dataset per mode: ID line 1 names the mode and its frequency, ID line 2 the model and
//! `nlsim VERSION`; record 6 says structural data (model type 1), normal mode (2), a 3-DOF
//! translation vector (characteristic 2, 3 values per node) or, when any DOF of the model is
//! a rotation, a 6-DOF translation and rotation vector (3, 6 values), displacement (specific
//! type 8), real (data type 2); record 7 the load case (1) and the mode number; record 8 the
//! frequency (Hz), the modal mass (1 kg: the shapes are mass-normalised, `φᵀMφ = 1`), the
//! viscous damping ratio and a hysteretic ratio of 0. Then per node its number (`I10`) and
//! its values (`E13.5`, the DOFs the model lacks at that node written as 0), nodes in
//! ascending order. A model of scalar coordinates (`N:u` only) is written as scalar data
//! (characteristic 1, one value per node); scalar and vector DOFs in one model are refused.
use crate::error::{Error, Result};
use nlsim_kernel::{Component, Model};
use nlsim_reduction::Modes;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// A number in Fortran `Ew.d` form (`-1.23450E-03` for `E13.5`): `d` digits after the point,
/// a signed exponent of at least two digits, right-aligned in `w` columns. Universal-file
/// readers cut fixed columns, so the field never grows past `w` for exponents of up to three
/// digits at `w ≥ d + 8`.
pub fn fortran_e(v: f64, w: usize, d: usize) -> String {
    let s = format!("{:.*e}", d, v);
    let (mantissa, exponent) = s.split_once('e').unwrap_or((s.as_str(), "0"));
    let e: i32 = exponent.parse().unwrap_or(0);
    let sign = if e < 0 { '-' } else { '+' };
    format!("{:>w$}", format!("{mantissa}E{sign}{:02}", e.abs()))
}

/// The component's place (0..6) in a 6-value translation-and-rotation vector, `None` for a
/// scalar coordinate.
fn slot(c: Component) -> Option<usize> {
    match c {
        Component::Ux => Some(0),
        Component::Uy => Some(1),
        Component::Uz => Some(2),
        Component::Rx => Some(3),
        Component::Ry => Some(4),
        Component::Rz => Some(5),
        Component::U => None,
    }
}

/// The text of datasets 55 for every one of `modes` on `model`'s DOFs, with the viscous
/// damping ratio `damping[r]` of mode `r` (0 where absent); `path` names the destination in
/// errors.
pub fn modes_text(path: &Path, model: &Model, modes: &Modes, damping: &[f64]) -> Result<String> {
    let labels = model.dofs().labels();
    let shapes = &modes.vectors;
    if shapes.nrows() != labels.len() {
        return Err(Error::Usage(format!(
            "{}: the modes hold {} entries per shape for the model's {} DOFs; a universal \
             file needs a shape entry at every DOF",
            path.display(),
            shapes.nrows(),
            labels.len()
        )));
    }
    let scalar = labels
        .iter()
        .filter(|l| slot(l.component).is_none())
        .count();
    if scalar > 0 && scalar < labels.len() {
        let first = labels
            .iter()
            .find(|l| slot(l.component).is_none())
            .map_or_else(String::new, ToString::to_string);
        return Err(Error::Usage(format!(
            "{}: the model mixes scalar coordinates (DOF {first}) with translations and \
             rotations; dataset 55 holds one kind per file: write .h5 instead",
            path.display()
        )));
    }
    let rotations = labels
        .iter()
        .any(|l| matches!(slot(l.component), Some(3..)));
    let (characteristic, per_node) = match (scalar > 0, rotations) {
        (true, _) => (1, 1),
        (false, false) => (2, 3),
        (false, true) => (3, 6),
    };
    // Node → (value slot, DOF index), nodes ascending.
    let mut nodes: BTreeMap<u64, Vec<(usize, usize)>> = BTreeMap::new();
    for (i, l) in labels.iter().enumerate() {
        let s = slot(l.component).unwrap_or(0);
        nodes.entry(l.node).or_default().push((s, i));
    }
    for &node in nodes.keys() {
        let node = i64::try_from(node).unwrap_or(i64::MAX);
        check_node(path, node, "a mode shape's node")?;
    }
    let freq = modes.frequencies_hz();
    let e13 = |v: f64| fortran_e(v, 13, 5);
    let mut out = String::new();
    for r in 0..modes.len() {
        let _ = writeln!(out, "{:>6}\n{:>6}", -1, 55);
        let id1 = format!("Mode {} at {:.6} Hz", r + 1, freq[r]);
        let id2 = format!("{} / nlsim {}", model.name(), env!("CARGO_PKG_VERSION"));
        for id in [id1.as_str(), id2.as_str(), "NONE", "NONE", "NONE"] {
            let id: String = id.chars().take(80).collect();
            let _ = writeln!(out, "{id:<80}");
        }
        let _ = writeln!(
            out,
            "{:>10}{:>10}{:>10}{:>10}{:>10}{:>10}",
            1, 2, characteristic, 8, 2, per_node
        );
        let _ = writeln!(out, "{:>10}{:>10}{:>10}{:>10}", 2, 4, 1, r + 1);
        let zeta = damping.get(r).copied().unwrap_or(0.0);
        let _ = writeln!(out, "{}{}{}{}", e13(freq[r]), e13(1.0), e13(zeta), e13(0.0));
        for (node, dofs) in &nodes {
            let mut values = vec![0.0; per_node];
            for &(s, i) in dofs {
                values[s] = shapes[(i, r)];
            }
            let _ = writeln!(out, "{node:>10}");
            for v in values {
                out.push_str(&e13(v));
            }
            out.push('\n');
        }
        let _ = writeln!(out, "{:>6}", -1);
    }
    Ok(out)
}

/// Largest node number a universal file holds: its node fields are 10 characters (`I10`),
/// read as 32-bit integers by the programs that read these files.
pub const UFF_MAX_NODE: i64 = i32::MAX as i64;

/// Refuses a node number a universal file's `I10` fields cannot hold (beyond
/// [`UFF_MAX_NODE`], or negative): written anyway it would run into the next field and the
/// file would be corrupt. `what` names the function or shape for the message.
pub fn check_node(path: &Path, node: i64, what: &str) -> Result<()> {
    if (0..=UFF_MAX_NODE).contains(&node) {
        return Ok(());
    }
    Err(Error::Usage(format!(
        "{}: node {node} ({what}) does not fit the 10-character node fields of a universal \
         file (0 to {UFF_MAX_NODE}); renumber the nodes or write .h5 or .csv instead",
        path.display()
    )))
}

#[cfg(test)]
mod tests {
    use super::fortran_e;

    #[test]
    fn fortran_fields_keep_their_width() {
        assert_eq!(fortran_e(1234.5, 13, 5), "  1.23450E+03");
        assert_eq!(fortran_e(-0.00123456, 13, 5), " -1.23456E-03");
        assert_eq!(fortran_e(0.0, 13, 5), "  0.00000E+00");
        assert_eq!(fortran_e(-1.5e-300, 13, 5), "-1.50000E-300");
        assert_eq!(fortran_e(2.5e100, 13, 5), " 2.50000E+100");
    }
}
