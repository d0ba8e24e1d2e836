//! Node coordinates (issue 45 part 5, datasets 15/2411): a model's `[geometry]` (inline or a
//! CSV file), the built-in beams' own, carried by `nlsim export --modal`, and written as
//! universal dataset 2411 before the functions and shapes, read back by pyuff.

use super::*;

/// `(node, [x, y, z])` per node.
type Nodes = Vec<(u64, [f64; 3])>;

/// The coordinates pyuff reads from the dataset 2411 of `file` (in `dir`), as
/// `node x y z` lines; the types of every dataset on a first line.
fn pyuff_nodes(dir: &Path, file: &str) -> String {
    python_output(
        &format!(
            r#"
import sys, pyuff
sets = pyuff.UFF(sys.argv[1] + "/{file}").read_sets()
sets = sets if isinstance(sets, list) else [sets]
print(" ".join(str(s["type"]) for s in sets))
for s in sets:
    if s["type"] == 2411:
        for n, x, y, z in zip(s["node_nums"], s["x"], s["y"], s["z"]):
            print(int(n), repr(float(x)), repr(float(y)), repr(float(z)))
"#
        ),
        dir,
    )
}

/// The ECL beam's model file with `[geometry] nodes = NODES` (a TOML value, as written).
fn beam_with_nodes(nodes: &str) -> String {
    format!("[matrices]\nfixture = \"ecl_beam\"\n\n[geometry]\nnodes = {nodes}\n")
}

/// The one-line error of reading `text` as the model file `path`.
fn refusal(text: &str, path: &Path) -> String {
    let e = nlsim::parse_model_file(text, path)
        .err()
        .unwrap_or_else(|| panic!("accepted:\n{text}"))
        .to_string();
    assert_eq!(e.lines().count(), 1, "{e}");
    e
}

/// Asserts that a model file `m.toml` in `dir` whose `[geometry] nodes` names each file of
/// `cases` is refused in one line containing the case's text.
fn refuses_node_files(dir: &Path, cases: &[(&str, &str)]) {
    for (file, says) in cases {
        let e = refusal(
            &beam_with_nodes(&format!("\"{file}\"")),
            &dir.join("m.toml"),
        );
        assert!(e.contains(says), "{file}: {e}");
    }
}

/// `(node, [x, y, z])` of every line after the first of [`pyuff_nodes`].
fn parse_nodes(text: &str) -> Nodes {
    text.lines()
        .skip(1)
        .map(|l| {
            let w: Vec<&str> = l.split_whitespace().collect();
            (
                w[0].parse().unwrap(),
                [
                    w[1].parse().unwrap(),
                    w[2].parse().unwrap(),
                    w[3].parse().unwrap(),
                ],
            )
        })
        .collect()
}

/// The nodes pyuff reads from the universal file of a short stepped `nlsim frf` of `model`
/// (written to `dir/f.uff`).
fn frf_nodes(dir: &Path, model: &str) -> Nodes {
    let out = dir.join("f.uff");
    let (rc, o, e) = nlsim(&[
        "frf",
        model,
        "--from",
        "22",
        "--to",
        "24",
        "--mode",
        "step-up",
        "--points",
        "3",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(rc, 0, "{model}: {o}{e}");
    parse_nodes(&pyuff_nodes(dir, "f.uff"))
}

/// A model file's coordinates (CSV and inline) replace the fixture's and reach the universal
/// files of `frf` and `simulate` exactly (`1PD25.16` holds every bit of a double); the
/// modal model `export --modal` writes carries the coordinates of its points, and so do its
/// files; `modes` writes every node with a DOF.
#[test]
fn coordinates_reach_the_universal_files() {
    let dir = scratch("geometry");
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    // Rotated and shifted: every coordinate non-trivial.
    let xyz = |k: u64| {
        let x = (k - 1) as f64 * 0.035;
        [0.1 + 0.6 * x, -0.25 + 0.8 * x, 1.0 / 3.0]
    };
    let mut csv = String::from("# the ECL beam, rotated in the xy plane\nnode,x,y,z\n");
    for k in 1..=21u64 {
        let [x, y, z] = xyz(k);
        csv.push_str(&format!("{k},{x:e},{y:e},{z:e}\n"));
    }
    std::fs::write(dir.join("nodes.csv"), csv).unwrap();
    let inline: Vec<String> = [11u64, 21]
        .iter()
        .map(|&k| {
            let [x, y, z] = xyz(k);
            format!("[{k}, {x:e}, {y:e}, {z:e}]")
        })
        .collect();
    for (name, nodes) in [
        ("csv.toml", "\"nodes.csv\"".to_string()),
        ("inline.toml", format!("[{}]", inline.join(", "))),
    ] {
        std::fs::write(dir.join(name), beam_with_nodes(&nodes)).unwrap();
        for (cmd, out) in [
            (
                vec![
                    "frf",
                    &d(name),
                    "--from",
                    "22",
                    "--to",
                    "24",
                    "--mode",
                    "step-up",
                ],
                "f.uff",
            ),
            (
                vec!["simulate", &d(name), "--duration", "0.02", "--rate", "1000"],
                "s.uff",
            ),
        ] {
            let mut args = cmd.clone();
            let path = d(out);
            args.extend(["--points", "3", "--out", &path, "-q"]);
            if cmd[0] == "simulate" {
                args.retain(|a| *a != "--points" && *a != "3");
            }
            let (rc, o, e) = nlsim(&args);
            assert_eq!(rc, 0, "{args:?}: {o}{e}");
            let text = pyuff_nodes(&dir, out);
            let types = text.lines().next().unwrap();
            assert!(types.starts_with("2411 58 58"), "{name} {out}: {types}");
            let nodes = parse_nodes(&text);
            assert_eq!(nodes.iter().map(|n| n.0).collect::<Vec<_>>(), [11, 21]);
            for (k, got) in nodes {
                assert_eq!(got, xyz(k), "{name} {out}: node {k}");
            }
        }
    }
    let summary = nlsim(&["check", &d("csv.toml")]).1;
    assert!(
        summary.contains("geometry     21 nodes with coordinates (nodes 1 to 21)"),
        "{summary}"
    );
    // The built-in beam's own coordinates for every node with a DOF in `modes`.
    let (rc, _, e) = nlsim(&["modes", "ecl_beam", "--count", "3", "--out", &d("m.uff")]);
    assert_eq!(rc, 0, "{e}");
    let text = pyuff_nodes(&dir, "m.uff");
    assert!(text.starts_with("2411 55"), "{text}");
    let nodes = parse_nodes(&text);
    assert_eq!(nodes.len(), 20);
    for (k, p) in nodes {
        assert_eq!(p, [(k - 1) as f64 * (0.7 / 20.0), 0.0, 0.0], "node {k}");
    }
    // Export: the modal model holds its points' coordinates, and its files write them.
    let (rc, _, e) = nlsim(&["export", &d("csv.toml"), &d("modal"), "--modal", "4"]);
    assert_eq!(rc, 0, "{e}");
    let modal = std::fs::read_to_string(dir.join("modal/modal.toml")).unwrap();
    assert!(modal.contains("[geometry]"), "{modal}");
    let nodes = frf_nodes(&dir, &d("modal/modal.toml"));
    assert_eq!(nodes.len(), 2);
    for (k, got) in nodes {
        assert_eq!(got, xyz(k), "modal: node {k}");
    }
    // `export` writes them as nodes.csv; a model of its files reads them back bit for bit.
    let (rc, o, e) = nlsim(&["export", &d("csv.toml"), &d("fe")]);
    assert_eq!(rc, 0, "{e}");
    assert!(o.contains("K.mtx, M.mtx, dofs.txt, nodes.csv"), "{o}");
    std::fs::write(
        dir.join("fe/m.toml"),
        "[matrices]\nmass = \"M.mtx\"\nstiffness = \"K.mtx\"\ndofs = \"dofs.txt\"\n\n\
         [geometry]\nnodes = \"nodes.csv\"\n",
    )
    .unwrap();
    let back = nlsim::load_model(&d("fe/m.toml")).unwrap().model;
    assert_eq!(back.geometry().len(), 21);
    for &(k, p) in back.geometry() {
        assert_eq!(p, xyz(k), "exported node {k}");
    }
    // A model without coordinates writes the functions alone.
    let (rc, _, e) = nlsim(&[
        "frf",
        "duffing_fig3",
        "--from",
        "26",
        "--to",
        "30",
        "--out",
        &d("plain.uff"),
    ]);
    assert_eq!(rc, 0, "{e}");
    assert!(!pyuff_nodes(&dir, "plain.uff").starts_with("2411"));
    std::fs::remove_dir_all(&*dir).unwrap();
}

/// Bad `[geometry]` input is refused in one line naming the file, the line and the key (or
/// the CSV file and its line).
#[test]
fn bad_geometry_names_file_line_and_key() {
    let dir = scratch("geometry-bad");
    let head = "[matrices]\nfixture = \"ecl_beam\"\n\n[geometry]\n";
    std::fs::write(dir.join("bad.csv"), "node,x,y,z\n1,0,0,0\n2,0.1,zero,0\n").unwrap();
    std::fs::write(dir.join("empty.csv"), "# nothing\n").unwrap();
    let cases = [
        ("", "geometry.nodes", "node coordinates"),
        ("nodes = 3\n", "geometry.nodes", "expected a list"),
        ("nodes = [[1, 0.0, 0.0]]\n", "geometry.nodes", "entry 1"),
        (
            "nodes = [[0, 0.0, 0.0, 0.0]]\n",
            "geometry.nodes",
            "positive integer",
        ),
        (
            "nodes = [[1, 0.0, nan, 0.0]]\n",
            "geometry.nodes",
            "entry 1",
        ),
        (
            "nodes = [[1, 0.0, 0.0, 0.0], [1, 1.0, 0.0, 0.0]]\n",
            "geometry",
            "given twice",
        ),
        (
            "nodes = []\nunits = \"mm\"\n",
            "geometry.units",
            "unknown key",
        ),
    ];
    for (body, key, says) in cases {
        let path = dir.join("bad.toml");
        let text = format!("{head}{body}");
        let e = refusal(&text, &path);
        assert!(
            e.contains("bad.toml:") && e.contains(&format!(": {key}: ")),
            "expected key {key}: {e}"
        );
        assert!(e.contains(says), "expected '{says}': {e}");
    }
    refuses_node_files(
        &dir,
        &[
            ("bad.csv", "bad.csv:3: expected node,x,y,z"),
            ("empty.csv", "empty.csv: no node lines"),
            ("absent.csv", "absent.csv"),
        ],
    );
    std::fs::remove_dir_all(&*dir).unwrap();
}

/// Coordinates from the FE decks engineers hold: a Nastran bulk-data file with `GRID` cards
/// written by pyNastran (the independent writer) in small and large field, and an Abaqus
/// input file's `*NODE` blocks, reach the universal file equal to what pyNastran reads back
/// from its own deck (and to the `.inp`'s numbers); a grid in a local system and an input file
/// with parts are refused by line.
#[test]
fn coordinates_from_nastran_and_abaqus_decks() {
    let dir = scratch("geometry-decks");
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let script = r#"
import sys
from pyNastran.bdf.bdf import BDF, read_bdf
d = sys.argv[1]
for size, name in [(8, "small.bdf"), (16, "large.bdf")]:
    m = BDF(debug=None)
    for k in range(1, 22):
        x = (k - 1) * 0.035
        m.add_grid(k, [0.1 + 0.6 * x, -0.25 + 0.8 * x, 1.0 / 3.0])
    m.add_grid(100, [5.0, 6.0, 7.0], cp=0)
    m.write_bdf(d + "/" + name, size=size, is_double=(size == 16))
    back = read_bdf(d + "/" + name, debug=None, xref=False)
    with open(d + "/" + name + ".xyz", "w") as f:
        for k in (11, 21):
            f.write("%d %r %r %r\n" % ((k,) + tuple(float(v) for v in back.nodes[k].xyz)))
print("ok")
"#;
    python_checks(script, &dir);
    std::fs::write(
        dir.join("beam.inp"),
        "*Heading\n** a flat input file\n*Node, nset=all\n  11, 0.35, 0.25, -1e-3\n\
         21,0.7,0.5\n*Element, type=B31\n1, 11, 21\n*Node\n5, 1., 2., 3.\n",
    )
    .unwrap();
    let mut cases: Vec<(String, Nodes)> = ["small.bdf", "large.bdf"]
        .iter()
        .map(|f| {
            let text = std::fs::read_to_string(dir.join(format!("{f}.xyz"))).unwrap();
            (
                f.to_string(),
                text.lines()
                    .map(|l| {
                        let w: Vec<&str> = l.split_whitespace().collect();
                        let v = |i: usize| w[i].parse::<f64>().unwrap();
                        (w[0].parse().unwrap(), [v(1), v(2), v(3)])
                    })
                    .collect(),
            )
        })
        .collect();
    cases.push((
        "beam.inp".into(),
        vec![(11, [0.35, 0.25, -1e-3]), (21, [0.7, 0.5, 0.0])],
    ));
    for (deck, want) in &cases {
        std::fs::write(dir.join("m.toml"), beam_with_nodes(&format!("\"{deck}\""))).unwrap();
        assert_eq!(&frf_nodes(&dir, &d("m.toml")), want, "{deck}");
    }
    // Refused by line: a grid in a local system; an input file with parts.
    std::fs::write(
        dir.join("cp.bdf"),
        "BEGIN BULK\nGRID,1,,0.,0.,0.\nGRID,2,5,1.,0.,0.\nENDDATA\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("parts.inp"),
        "*Part, name=beam\n*Node\n1, 0., 0., 0.\n*End Part\n",
    )
    .unwrap();
    std::fs::write(dir.join("none.bdf"), "BEGIN BULK\nENDDATA\n").unwrap();
    refuses_node_files(
        &dir,
        &[
            (
                "cp.bdf",
                "cp.bdf:3: GRID: grid 2 gives its coordinates in system CP = 5",
            ),
            ("parts.inp", "parts.inp:1: *PART"),
            ("none.bdf", "none.bdf: no GRID cards"),
        ],
    );
    std::fs::remove_dir_all(&*dir).unwrap();
}
