//! Abaqus `*MATRIX GENERATE` output in coordinate form (`.mtx`: one `NODE_I, DOF_I, NODE_J,
//! DOF_J, VALUE` per line, `**` comments), told from Matrix Market by its content.

use crate::error::{Error, Result};
use crate::formats::fe_matrices::{Interner, LabelledMatrix, label};
use crate::formats::files::quoted;
use nlsim_kernel::Component;
use std::path::Path;

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
    Ok(LabelledMatrix::named_by_file(path, labels.list, entries))
}

/// The coordinates of the `*NODE` blocks of an Abaqus input file (read from `path`): data
/// lines `id, x, y[, z]` (m; a missing z is 0) up to the next keyword, `**` comments skipped,
/// `(id, [x, y, z])` in file order. A file with `*PART` or `*INSTANCE` is refused: its node
/// numbers are per part and its instances move them, which nlsim does not follow.
pub fn parse_inp_nodes(text: &str, path: &Path) -> Result<Vec<(u64, [f64; 3])>> {
    let err = |line: usize, message: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message,
    };
    let mut out = Vec::new();
    let mut in_nodes = false;
    for (i, raw) in text.lines().enumerate() {
        let l = raw.trim();
        if l.is_empty() || l.starts_with("**") {
            continue;
        }
        if let Some(kw) = l.strip_prefix('*') {
            let name = kw
                .split(',')
                .next()
                .unwrap_or("")
                .trim()
                .to_ascii_uppercase();
            if name == "PART" || name == "INSTANCE" {
                return Err(err(
                    i + 1,
                    format!(
                        "*{name}: node numbers of parts and instances are not read; write the \
                         input file flat (without parts), or give the coordinates as CSV"
                    ),
                ));
            }
            if name == "SYSTEM" {
                return Err(err(
                    i + 1,
                    "*SYSTEM: nodes in a local coordinate system are not transformed; give \
                     global coordinates (or the coordinates as CSV)"
                        .into(),
                ));
            }
            in_nodes = name == "NODE";
            if in_nodes {
                // Parameters: SYSTEM=R (rectangular, the default) only; INPUT= reads the
                // nodes from another file, which is not followed.
                for param in kw.split(',').skip(1) {
                    let (key, value) = param.split_once('=').unwrap_or((param, ""));
                    let (key, value) = (key.trim().to_ascii_uppercase(), value.trim());
                    let refused = match key.as_str() {
                        "SYSTEM" if !value.eq_ignore_ascii_case("R") => Some(format!(
                            "SYSTEM={value}: cylindrical or spherical coordinates are not \
                             converted; give rectangular (global x, y, z) coordinates"
                        )),
                        "INPUT" => Some(format!(
                            "INPUT={value}: nodes read from another file are not followed; \
                             put them in this file or give the coordinates as CSV"
                        )),
                        _ => None,
                    };
                    if let Some(why) = refused {
                        return Err(err(i + 1, format!("*NODE, {why}")));
                    }
                }
            }
            continue;
        }
        if !in_nodes {
            continue;
        }
        let cells: Vec<&str> = l.trim_end_matches(',').split(',').map(str::trim).collect();
        let bad = || {
            err(
                i + 1,
                format!(
                    "*NODE: expected 'id, x, y[, z]', found '{}'",
                    l.chars().take(60).collect::<String>()
                ),
            )
        };
        if !(3..=4).contains(&cells.len()) {
            return Err(bad());
        }
        let id = cells[0]
            .parse::<u64>()
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(bad)?;
        let mut xyz = [0.0; 3];
        for (x, c) in xyz.iter_mut().zip(&cells[1..]) {
            *x = c
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(bad)?;
        }
        if out.len() == crate::formats::fe_matrices::MAX_GEOMETRY_NODES {
            return Err(err(i + 1, format!("more than {} nodes", out.len())));
        }
        out.push((id, xyz));
    }
    if out.is_empty() {
        return Err(Error::Usage(format!(
            "{}: no *NODE data lines (node coordinates)",
            path.display()
        )));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::fe_matrices::union_dofs;

    #[test]
    fn nodes_outside_global_rectangular_coordinates_are_refused() {
        let p = Path::new("m.inp");
        let plain = "*NODE, NSET=ALL, SYSTEM=R\n1, 0.0, 0.5, 1.0\n2, 1.0, 0.0\n*ELEMENT\n";
        let nodes = parse_inp_nodes(plain, p).unwrap();
        assert_eq!(nodes, vec![(1, [0.0, 0.5, 1.0]), (2, [1.0, 0.0, 0.0])]);
        for (text, want) in [
            (
                "*NODE, SYSTEM=C\n1, 1.0, 90.0, 0.0\n",
                "m.inp:1: *NODE, SYSTEM=C",
            ),
            ("*Node, system=s\n1, 1.0, 90.0, 0.0\n", "SYSTEM=s"),
            ("*NODE, INPUT=nodes.inp\n", "INPUT=nodes.inp"),
            (
                "*SYSTEM\n0,0,1\n*NODE\n1, 1.0, 0.0, 0.0\n",
                "m.inp:1: *SYSTEM",
            ),
        ] {
            let e = parse_inp_nodes(text, p).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn symmetric_storage_is_checked() {
        let p = Path::new("k.mtx");
        let both = "1,3,1,3,2.0\n1,3,2,3,-1.0\n2,3,1,3,-1.0\n2,3,2,3,1.0\n";
        let m = parse_abaqus(both, p).unwrap();
        let dofs = union_dofs(&[&m]).unwrap();
        assert_eq!(m.onto(&dofs, "K", 0.0).unwrap().get(0, 1), -1.0);
        let differ = "1,3,1,3,2.0\n1,3,2,3,-1.0\n2,3,1,3,-1.5\n";
        let e = parse_abaqus(differ, p)
            .unwrap()
            .onto(&dofs, "K", 0.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("k.mtx:3") && e.contains("differ"), "{e}");
        let again = "1,3,1,3,2.0\n1,3,1,3,2.0\n";
        let e = parse_abaqus(again, p)
            .unwrap()
            .onto(&dofs, "K", 0.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("k.mtx:2") && e.contains("first on line 1"),
            "{e}"
        );
    }
}
