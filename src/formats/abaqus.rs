//! Abaqus `*MATRIX GENERATE` output (`.mtx`, told from Matrix Market by its content) in both
//! layouts Abaqus writes: `FORMAT=COORDINATE` (`ROW, COLUMN, VALUE` by global equation
//! number, what `*MATRIX OUTPUT, ..., FORMAT=COORDINATE` gives) and the node/DOF layout of
//! `FORMAT=MATRIX INPUT` (`NODE_I, DOF_I, NODE_J, DOF_J, VALUE`); and the two things nlsim
//! reads from a job's input file (`.inp`): node coordinates, and the node and DOF of each
//! global equation ([`inp_equation_labels`]).

use crate::error::{Error, Result};
use crate::formats::fe_matrices::{FeMatrix, Interner, LabelledMatrix, NumberedMatrix, label};
use crate::formats::files::quoted;
use nlsim_kernel::{Component, DofLabel};
use std::collections::HashMap;
use std::path::Path;

/// The matrix of an Abaqus `*MATRIX GENERATE` file, in the layout its first entry shows:
/// three fields (`ROW, COLUMN, VALUE`, 1-based global equations: [`FeMatrix::Numbered`]) or
/// five (`NODE_I, DOF_I, NODE_J, DOF_J, VALUE`: [`FeMatrix::Labelled`]); commas or blanks
/// between fields, `**` comments. Errors name the file and line.
pub fn parse_abaqus(text: &str, path: &Path) -> Result<FeMatrix> {
    let err = |line: usize, m: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message: m,
    };
    let mut entries = Vec::new();
    let mut labels = Interner::default();
    // The layout (3 or 5 fields) and the line that set it.
    let mut layout: Option<(usize, usize)> = None;
    let mut highest = 0usize;
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
                    "keyword line {}: this reader takes the output of *MATRIX GENERATE \
                     (ROW, COLUMN, VALUE or NODE, DOF, NODE, DOF, VALUE per line)",
                    quoted(t)
                ),
            ));
        }
        let f: Vec<&str> = t
            .split(|c: char| c == ',' || c.is_whitespace())
            .filter(|s| !s.is_empty())
            .collect();
        let (fields, first) = *layout.get_or_insert((f.len(), ln));
        if f.len() != fields || !(fields == 3 || fields == 5) {
            let why = if fields == 3 || fields == 5 {
                format!(
                    "the file's first entry (line {first}) has {fields}, so every line has \
                     {fields}"
                )
            } else {
                "expected 3 (ROW, COLUMN, VALUE: FORMAT=COORDINATE) or 5 (NODE_I, DOF_I, \
                 NODE_J, DOF_J, VALUE)"
                    .to_string()
            };
            return Err(err(ln, format!("{} fields, {why}: {}", f.len(), quoted(t))));
        }
        let int = |k: usize| -> Result<i64> {
            f[k].parse::<i64>().map_err(|_| {
                err(
                    ln,
                    format!("field {}: {} is not an integer", k + 1, quoted(f[k])),
                )
            })
        };
        let value = f[fields - 1]
            .replace(['D', 'd'], "E")
            .parse::<f64>()
            .ok()
            .filter(|v| v.is_finite())
            .ok_or_else(|| {
                err(
                    ln,
                    format!("value {} is not a finite number", quoted(f[fields - 1])),
                )
            })?;
        if fields == 3 {
            let eq = |k: usize| -> Result<usize> {
                let e = int(k)?;
                usize::try_from(e)
                    .ok()
                    .filter(|e| (1..=crate::formats::matrices::MAX_DIM).contains(e))
                    .ok_or_else(|| {
                        err(
                            ln,
                            format!(
                                "equation {e} in field {}: Abaqus numbers equations from 1 \
                                 (at most {})",
                                k + 1,
                                crate::formats::matrices::MAX_DIM
                            ),
                        )
                    })
            };
            let (r, c) = (eq(0)?, eq(1)?);
            highest = highest.max(r).max(c);
            entries.push((r - 1, c - 1, value, ln));
            continue;
        }
        let row = label(int(0)?, int(1)?).map_err(|m| err(ln, m))?;
        let col = label(int(2)?, int(3)?).map_err(|m| err(ln, m))?;
        if row.component == Component::U || col.component == Component::U {
            return Err(err(
                ln,
                "DOF 0: Abaqus numbers the DOFs of a node 1 to 6".to_string(),
            ));
        }
        entries.push((labels.id(row), labels.id(col), value, ln));
    }
    match layout {
        None => Err(err(1, "no matrix entry".into())),
        Some((3, _)) => Ok(FeMatrix::Numbered(NumberedMatrix {
            path: path.to_path_buf(),
            n: highest,
            entries,
            kind: "Abaqus COORDINATE output (ROW, COLUMN, VALUE by global equation)".into(),
        })),
        Some(_) => Ok(FeMatrix::Labelled(LabelledMatrix::named_by_file(
            path,
            labels.list,
            entries,
        ))),
    }
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
            let name = keyword_name(kw);
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

/// The keyword of an input-file line after its `*`, upper case (`NODE` of `*Node, nset=a`).
fn keyword_name(kw: &str) -> String {
    kw.split(',')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_uppercase()
}

/// The DOFs (bit k−1 for Abaqus DOF k, 1–6) an element type gives its nodes, for the
/// types whose nodes carry displacements and rotations only; `Err` says why another type is
/// not taken.
fn element_dofs(kind: &str) -> std::result::Result<u8, String> {
    const XYZ: u8 = 0b000_111;
    const XY: u8 = 0b000_011;
    const ALL: u8 = 0b111_111;
    const PLANE_BEAM: u8 = 0b100_011;
    let k = kind.to_ascii_uppercase();
    let digits_then = |prefix: &str| -> Option<&str> {
        let rest = k.strip_prefix(prefix)?;
        let tail = rest.trim_start_matches(|c: char| c.is_ascii_digit());
        (tail.len() < rest.len()).then_some(tail)
    };
    // Suffixes that add DOFs other than displacements at the nodes or inside the element.
    let extra = |tail: &str| -> Option<String> {
        if tail.contains('H') {
            Some("a hybrid element adds pressure (Lagrange multiplier) equations".into())
        } else if tail.contains('T') {
            Some("a coupled temperature-displacement element adds temperature DOF 11".into())
        } else if tail.contains('P') {
            Some("a pore-pressure element adds pore-pressure DOF 8".into())
        } else if tail.contains('E') {
            Some("a piezoelectric element adds electric potential DOF 9".into())
        } else {
            None
        }
    };
    let plain = |tail: &str, dofs: u8| match extra(tail) {
        Some(why) => Err(why),
        None => Ok(dofs),
    };
    if let Some(tail) = digits_then("C3D") {
        return plain(tail, XYZ);
    }
    for p in ["CPS", "CPE", "CPEG", "CAX"] {
        if let Some(tail) = digits_then(p) {
            return plain(tail, XY);
        }
    }
    if let Some(tail) = digits_then("SC") {
        return plain(tail, XYZ);
    }
    if k.starts_with("STRI") || k == "S3" || k == "S3R" || k == "S4" || k == "S4R" || k == "S8R" {
        return Ok(ALL);
    }
    if digits_then("S").is_some_and(|t| t.ends_with("R5")) {
        return Err("a five-DOF shell has two rotations in a local frame per node".into());
    }
    for (p, dofs) in [
        ("B3", ALL),
        ("PIPE3", ALL),
        ("B2", PLANE_BEAM),
        ("PIPE2", PLANE_BEAM),
        ("T3D", XYZ),
        ("T2D", XY),
    ] {
        if let Some(tail) = digits_then(p) {
            if tail.contains("OS") {
                return Err("an open-section beam adds warping DOF 7".into());
            }
            return plain(tail, dofs);
        }
    }
    match k.as_str() {
        "MASS" | "SPRINGA" | "DASHPOTA" => Ok(XYZ),
        "ROTARYI" => Ok(0b111_000),
        "CONN3D2" => Ok(ALL),
        "CONN2D2" => Ok(PLANE_BEAM),
        _ => Err("its nodes' DOFs are not in nlsim's table of element types".into()),
    }
}

/// The node and DOF of each global equation of an Abaqus job, as `*MATRIX OUTPUT,
/// FORMAT=COORDINATE` numbers them, from its input file: the nodes in the order the `*NODE`
/// lines give them, each with the DOFs its elements use (the union over its elements' types:
/// continuum 1–3, plane and axisymmetric 1–2, shells and 3-D beams 1–6,
/// plane beams 1, 2, 6, trusses, point masses, rotary inertia 4–6, connectors), in increasing
/// order; a node on no element has no equation. Limits, each refused by name with the line:
/// node labels not increasing in file order (Abaqus's internal order is not known then), more
/// than one part instance, `*INCLUDE` and `*NODE, INPUT=` (not followed), element types
/// outside the table (hybrid, coupled-field, open-section, five-DOF shells, user elements).
/// A `dofs` labels file is the way for those.
pub fn inp_equation_labels(text: &str, path: &Path) -> Result<Vec<DofLabel>> {
    let err = |line: usize, message: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message,
    };
    enum Block {
        Other,
        Nodes,
        Elements(u8),
    }
    let mut block = Block::Other;
    // Nodes in file order, each with its line and DOF mask.
    let mut nodes: Vec<(u64, usize, u8)> = Vec::new();
    let mut index: HashMap<u64, usize> = HashMap::new();
    let mut instances = 0usize;
    // An element's node list continues on the next line when a line ends with a comma.
    let mut continues = false;
    // Element references to nodes not (yet) defined: resolved at the end.
    let mut pending: Vec<(u64, u8, usize)> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let l = raw.trim();
        if l.is_empty() || l.starts_with("**") {
            continue;
        }
        if let Some(kw) = l.strip_prefix('*') {
            continues = false;
            let name = keyword_name(kw);
            let param = |key: &str| {
                kw.split(',').skip(1).find_map(|p| {
                    let (k, v) = p.split_once('=')?;
                    k.trim()
                        .eq_ignore_ascii_case(key)
                        .then(|| v.trim().to_string())
                })
            };
            block = Block::Other;
            match name.as_str() {
                "INCLUDE" => {
                    return Err(err(
                        ln,
                        "*INCLUDE: included files are not followed; give the job's whole \
                         input file, or the equations' labels as a dofs file"
                            .into(),
                    ));
                }
                "INSTANCE" => {
                    instances += 1;
                    if instances > 1 {
                        return Err(err(
                            ln,
                            "a second *INSTANCE: Abaqus numbers the equations of several \
                             instances in an order nlsim does not follow; give the equations' \
                             labels as a dofs file"
                                .into(),
                        ));
                    }
                }
                "NODE" => {
                    if let Some(f) = param("INPUT") {
                        return Err(err(
                            ln,
                            format!(
                                "*NODE, INPUT={f}: nodes read from another file are not \
                                 followed; put them in this file or give a dofs file"
                            ),
                        ));
                    }
                    block = Block::Nodes;
                }
                "ELEMENT" => {
                    let kind = param("TYPE").ok_or_else(|| {
                        err(
                            ln,
                            "*ELEMENT without TYPE=: the element type is needed".into(),
                        )
                    })?;
                    let dofs = element_dofs(&kind).map_err(|why| {
                        err(
                            ln,
                            format!(
                                "*ELEMENT, TYPE={kind}: {why}; give the equations' labels as \
                                 a dofs file (one NODE:DOF per equation)"
                            ),
                        )
                    })?;
                    block = Block::Elements(dofs);
                }
                _ => {}
            }
            continue;
        }
        match block {
            Block::Other => {}
            Block::Nodes => {
                let first = l.split(',').next().unwrap_or("").trim();
                let id = first
                    .parse::<u64>()
                    .ok()
                    .filter(|&n| n > 0)
                    .ok_or_else(|| {
                        err(
                            ln,
                            format!(
                                "*NODE: node label {} is not a positive integer",
                                quoted(first)
                            ),
                        )
                    })?;
                if let Some(&(last, last_line, _)) = nodes.last()
                    && id <= last
                {
                    return Err(err(
                        ln,
                        format!(
                            "node {id} follows node {last} (line {last_line}): with node labels \
                             not increasing, Abaqus's equation order is not known from the \
                             input file; give the equations' labels as a dofs file"
                        ),
                    ));
                }
                if nodes.len() == crate::formats::fe_matrices::MAX_GEOMETRY_NODES {
                    return Err(err(ln, format!("more than {} nodes", nodes.len())));
                }
                index.insert(id, nodes.len());
                nodes.push((id, ln, 0));
            }
            Block::Elements(dofs) => {
                let mut cells = l.trim_end_matches(',').split(',').map(str::trim);
                if !continues {
                    cells.next(); // the element label
                }
                for c in cells.filter(|c| !c.is_empty()) {
                    let node = c.parse::<u64>().ok().filter(|&n| n > 0).ok_or_else(|| {
                        err(
                            ln,
                            format!("*ELEMENT: node {} is not a positive integer", quoted(c)),
                        )
                    })?;
                    match index.get(&node) {
                        Some(&k) => nodes[k].2 |= dofs,
                        None => pending.push((node, dofs, ln)),
                    }
                }
                continues = l.ends_with(',');
            }
        }
    }
    for (node, dofs, ln) in pending {
        let k = *index.get(&node).ok_or_else(|| {
            err(
                ln,
                format!("*ELEMENT: node {node} is not defined by a *NODE line"),
            )
        })?;
        nodes[k].2 |= dofs;
    }
    let mut out = Vec::new();
    for &(id, ln, mask) in &nodes {
        for d in 1..=6i64 {
            if mask & (1 << (d - 1)) != 0 {
                out.push(label(id as i64, d).map_err(|m| err(ln, m))?);
            }
        }
    }
    if out.is_empty() {
        return Err(Error::Usage(format!(
            "{}: no node on an element (no *NODE and *ELEMENT data): the equations' labels \
             cannot be derived from it",
            path.display()
        )));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::formats::fe_matrices::union_dofs;

    fn labelled(text: &str, p: &Path) -> LabelledMatrix {
        match parse_abaqus(text, p).unwrap() {
            FeMatrix::Labelled(m) => m,
            FeMatrix::Numbered(_) => panic!("5-column file read as numbered"),
        }
    }

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
    fn equations_follow_the_nodes_and_the_dofs_their_elements_use() {
        let p = Path::new("job.inp");
        // Node 1 on a plane beam (1, 2, 6) and a truss (1, 2); node 2 on both; node 3 on the
        // truss only; node 4 on no element; a 20-node brick's list continued on a second line.
        let text = "*Heading\n** comment\n*NODE, NSET=ALL\n1, 0., 0.\n2, 1., 0.\n3, 2., 0.\n\
                    4, 3., 0.\n5, 0., 1., 1.\n*ELEMENT, TYPE=B21, ELSET=BEAM\n1, 1, 2\n\
                    *Element, type=T2D2\n2, 2, 3\n3, 1, 3\n*ELEMENT, TYPE=C3D20R\n\
                    4, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5,\n5, 5, 5, 5, 5, 5, 5, 5, 5, 5\n*STEP\n";
        let got: Vec<String> = inp_equation_labels(text, p)
            .unwrap()
            .iter()
            .map(|l| l.to_string())
            .collect();
        assert_eq!(
            got,
            [
                "1:ux", "1:uy", "1:rz", "2:ux", "2:uy", "2:rz", "3:ux", "3:uy", "5:ux", "5:uy",
                "5:uz"
            ]
        );
        for (text, want) in [
            (
                "*NODE\n2, 0., 0.\n1, 1., 0.\n",
                "job.inp:3: node 1 follows node 2 (line 2)",
            ),
            (
                "*NODE\n1, 0., 0.\n*ELEMENT, TYPE=C3D8H\n1, 1\n",
                "job.inp:3: *ELEMENT, TYPE=C3D8H: a hybrid element",
            ),
            (
                "*NODE\n1, 0., 0.\n*ELEMENT, TYPE=S4R5\n1, 1\n",
                "five-DOF shell",
            ),
            (
                "*NODE\n1, 0., 0.\n*ELEMENT, TYPE=B31OS\n1, 1\n",
                "warping DOF 7",
            ),
            ("*NODE\n1, 0., 0.\n*ELEMENT, TYPE=U1\n1, 1\n", "TYPE=U1"),
            (
                "*NODE\n1, 0., 0.\n*ELEMENT, TYPE=T3D2\n1, 1, 7\n",
                "job.inp:4: *ELEMENT: node 7 is not defined",
            ),
            (
                "*Instance, name=a, part=p\n*End Instance\n*Instance, name=b, part=p\n",
                "job.inp:3: a second *INSTANCE",
            ),
            ("*INCLUDE, INPUT=mesh.inp\n", "job.inp:1: *INCLUDE"),
            ("*NODE\n1, 0., 0.\n", "no node on an element"),
        ] {
            let e = inp_equation_labels(text, p).unwrap_err().to_string();
            assert!(e.contains(want), "{text:?}: {e}");
        }
    }

    #[test]
    fn symmetric_storage_is_checked() {
        let p = Path::new("k.mtx");
        let both = "1,3,1,3,2.0\n1,3,2,3,-1.0\n2,3,1,3,-1.0\n2,3,2,3,1.0\n";
        let m = labelled(both, p);
        let dofs = union_dofs(&[&m]).unwrap();
        assert_eq!(m.onto(&dofs, "K", 0.0).unwrap().get(0, 1), -1.0);
        let differ = "1,3,1,3,2.0\n1,3,2,3,-1.0\n2,3,1,3,-1.5\n";
        let e = labelled(differ, p)
            .onto(&dofs, "K", 0.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("k.mtx:3") && e.contains("differ"), "{e}");
        let again = "1,3,1,3,2.0\n1,3,1,3,2.0\n";
        let e = labelled(again, p)
            .onto(&dofs, "K", 0.0)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("k.mtx:2") && e.contains("first on line 1"),
            "{e}"
        );
    }
}
