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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::fe_matrices::union_dofs;

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
}
