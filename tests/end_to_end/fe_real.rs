//! Real third-party FE matrix files (issue 73): `tests/data/fe_real` holds files written by
//! MSC and NX Nastran (from pyyeti's test folders, BSD-3-Clause; SOURCES.md), and
//! `reference.csv` what independent readers make of them (pyyeti 1.4.7 for the matrices,
//! scipy for the eigenvalues; `scripts/fe_real_reference.py`). Every stiffness/mass pair is
//! read by nlsim to the bit of the reference (the FNV-1a hash of its lower triangle) and its
//! eigenvalues agree with scipy's; the files nlsim cannot take are refused with the reason.

use super::*;

/// The directory of the corpus.
fn corpus() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/fe_real")
}

/// FNV-1a (64 bit) of `bytes` as 16 hex digits, as the reference script hashes.
fn fnv1a(bytes: &[u8]) -> String {
    let h = bytes.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    format!("{h:016x}")
}

/// FNV-1a of the nonzero entries of the lower triangle, column by column: row and column as
/// u64 and the value's bits, little-endian (as the reference script hashes them).
fn fnv(m: &nlsim::kernel::SparseSym) -> String {
    let d = m.to_dense();
    let mut bytes = Vec::new();
    for j in 0..d.ncols() {
        for i in j..d.nrows() {
            let v = d[(i, j)];
            if v != 0.0 {
                bytes.extend_from_slice(&(i as u64).to_le_bytes());
                bytes.extend_from_slice(&(j as u64).to_le_bytes());
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
    fnv1a(&bytes)
}

/// FNV-1a of the DOF labels in order as text, "NODE:DOF," each with DOF 1–6 (0 for a
/// scalar point: the UFF direction numbers), as the reference script hashes them.
fn labels_fnv(dofs: &nlsim::kernel::DofMap) -> String {
    let text: String = dofs
        .labels()
        .iter()
        .map(|&l| {
            let (node, dof) = nlsim::formats::uff_write::node_direction(l);
            format!("{node}:{dof},")
        })
        .collect();
    fnv1a(text.as_bytes())
}

/// A model file in `dir` reading `stiffness` and `mass` (corpus files, each with its
/// selector `:NAME` if any), labelled by `dofs`: "" (the files label their DOFs), "generic"
/// (`n` labels 1:ux … n:ux) or a corpus file; returns its path.
fn model_with(dir: &Path, stiffness: &str, mass: &str, dofs: &str, n: usize) -> PathBuf {
    let dofs = match dofs {
        "" => String::new(),
        "generic" => {
            let labels: String = (1..=n).map(|i| format!("{i}:ux\n")).collect();
            std::fs::write(dir.join("dofs.txt"), labels).unwrap();
            "dofs = \"dofs.txt\"\n".to_string()
        }
        file => format!("dofs = \"{}\"\n", corpus().join(file).display()),
    };
    let model = dir.join("m.toml");
    std::fs::write(
        &model,
        format!(
            "name = \"real\"\n[matrices]\nstiffness = \"{}\"\nmass = \"{}\"\n{dofs}",
            corpus().join(stiffness).display(),
            corpus().join(mass).display()
        ),
    )
    .unwrap();
    model
}

/// The stiffness `sel` (`FILE:NAME` of the corpus, OUTPUT4 or DMIG) of order `n` as a model
/// file reads it, with its DOFs (generic for OUTPUT4).
fn single(sel: &str, n: usize) -> (nlsim::kernel::SparseSym, nlsim::kernel::DofMap) {
    use nlsim::formats::fe_matrices as fe;
    let (file, name) = sel.rsplit_once(':').unwrap();
    let path = corpus().join(file);
    if file.ends_with(".op4") {
        let m = nlsim::formats::op4::read_op4(
            &path,
            Some(name),
            nlsim::formats::op4::Op4Role::Stiffness,
        )
        .unwrap();
        let dofs = nlsim::kernel::DofMap::scalar(n);
        let place = if m.binary {
            fe::Place::Record
        } else {
            fe::Place::Line
        };
        let k = fe::symmetric_from_entries(
            &path,
            name,
            &dofs,
            &m.entries,
            place,
            fe::SYMMETRY_TOLERANCE,
        )
        .unwrap();
        return (k, dofs);
    }
    let fe::FeMatrix::Labelled(m) =
        nlsim::formats::fe_read::read(&path, fe::FeFormat::Dmig, Some(name)).unwrap()
    else {
        panic!("{sel}: DMIG is labelled")
    };
    let dofs = fe::union_dofs(&[&m]).unwrap();
    (m.onto(&dofs, name, fe::SYMMETRY_TOLERANCE).unwrap(), dofs)
}

/// [`model_with`] for an OUTPUT4 file with generic labels: `stiffness`, `mass` the matrix
/// selectors ("" for none).
fn model_of(dir: &Path, file: &str, stiffness: &str, mass: &str, n: usize) -> PathBuf {
    let sel = |s: &str| {
        if s.is_empty() {
            file.to_string()
        } else {
            format!("{file}:{s}")
        }
    };
    model_with(dir, &sel(stiffness), &sel(mass), "generic", n)
}

/// Every pair of `reference.csv` reads to the bit; where scipy solved the eigenproblem,
/// `nlsim modes` finds the same eigenvalues: the elastic ones within 1e-9 relative, the
/// rigid-body ones (below 1e-9 of the largest) below 1e-9 of the largest too.
#[test]
fn real_fe_pairs_read_to_the_bit_and_give_scipys_eigenvalues() {
    let dir = scratch("fe-real");
    let text = std::fs::read_to_string(corpus().join("reference.csv")).unwrap();
    let mut pairs = 0;
    let mut labelled = 0;
    let mut singles = 0;
    let mut worst = 0.0f64;
    for line in text.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        let (ks, ms, dofs, n) = (f[0], f[1], f[2], f[3].parse::<usize>().unwrap());
        let file = ks;
        if ms == "-" {
            // A stiffness alone, read as a model file reads it.
            let k = single(ks, n);
            assert_eq!(fnv(&k.0), f[4], "{ks}: not the reference's values");
            if f[6] != "-" {
                assert_eq!(
                    labels_fnv(&k.1),
                    f[6],
                    "{ks}: not the reference's DOF labels"
                );
            }
            singles += 1;
            continue;
        }
        let model = model_with(&dir, ks, ms, dofs, n);
        let loaded = nlsim::formats::model_file::load_model(model.to_str().unwrap())
            .unwrap_or_else(|e| panic!("{file} {ks}/{ms}: {e}"));
        let m = &loaded.model;
        assert_eq!(m.n_dofs(), n, "{file}");
        assert_eq!(fnv(m.stiffness()), f[4], "{ks}: not the reference's values");
        assert_eq!(fnv(m.mass()), f[5], "{ms}: not the reference's values");
        if f[6] != "-" {
            assert_eq!(
                labels_fnv(m.dofs()),
                f[6],
                "{ks}: not the reference's DOF labels"
            );
            labelled += 1;
        }
        pairs += 1;
        if f[7] == "-" {
            continue;
        }
        let want: Vec<f64> = f[7].split(' ').map(|x| x.parse().unwrap()).collect();
        let out = dir.join("modes.csv");
        let (rc, _, e) = nlsim(&[
            "-q",
            "modes",
            model.to_str().unwrap(),
            "--count",
            &n.to_string(),
            "--out",
            out.to_str().unwrap(),
        ]);
        assert_eq!(rc, 0, "{file}: {e}");
        let got: Vec<f64> = std::fs::read_to_string(&out)
            .unwrap()
            .lines()
            .skip(1)
            .map(|l| l.split(',').nth(2).unwrap().parse().unwrap())
            .collect();
        assert_eq!(got.len(), want.len(), "{file}: modes found");
        let top = want.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
        for (k, (&g, &w)) in got.iter().zip(&want).enumerate() {
            if w.abs() <= 1e-9 * top {
                assert!(
                    g.abs() <= 1e-9 * top,
                    "{file} mode {}: {g} vs rigid {w}",
                    k + 1
                );
            } else {
                let rel = (g - w).abs() / w.abs();
                worst = worst.max(rel);
                assert!(
                    rel <= 1e-9,
                    "{file} mode {}: {g} vs scipy {w} ({rel:.1e})",
                    k + 1
                );
            }
        }
    }
    eprintln!("{pairs} pairs; largest relative eigenvalue difference {worst:.1e}");
    assert!(
        pairs >= 19 && labelled >= 4 && singles >= 2,
        "{pairs} pairs, {labelled} labelled, {singles} single matrices"
    );
}

/// What nlsim cannot take is refused with its reason; a file whose first matrix is the mass
/// is not read as K = M without names; repeated names are asked for by number.
#[test]
fn real_output4_files_it_cannot_take_are_refused_with_the_reason() {
    let dir = scratch("fe-real-refused");
    for (file, k, m, n, want) in [
        (
            "pyyeti/ascii_fabiola.op4",
            "LL",
            "MAA",
            240,
            "matrix 'LL' has form 4 (lower triangular, a factor)",
        ),
        (
            "pyyeti/binary_fabiola.op4",
            "LL",
            "MAA",
            240,
            "matrix 'LL' has form 4 (lower triangular, a factor)",
        ),
        (
            "pyyeti/ascii_fabiola.op4",
            "",
            "",
            240,
            "which matrix is the stiffness? The file holds MAA 240×240, LL 240×240, DD 240×240",
        ),
        (
            "pyyeti/double_nonbigmat_le.op4",
            "RMAT",
            "RMAT",
            25,
            "matrix 'RMAT' is 25 × 31: nlsim takes square matrices",
        ),
        (
            "pyyeti/double_bigmat_be.op4",
            "CMAT",
            "CMAT",
            25,
            "matrix 'CMAT' is 25 × 31",
        ),
        (
            "pyyeti/double_nonbigmat_ascii.op4",
            "RMAT",
            "RMAT",
            25,
            "double_nonbigmat_ascii.op4:1: matrix 'RMAT' is 25 × 31: nlsim takes square",
        ),
        (
            "pyyeti/single_dense_ascii.op4",
            "RMATS",
            "RMATS",
            25,
            "matrix 'RMATS' is 25 × 31",
        ),
        (
            "pyyeti/cdbin.op4",
            "C3",
            "C3",
            1,
            "matrix 'C3' has type 3: nlsim takes real matrices",
        ),
        (
            "pyyeti/nas2cam_csuper.op4",
            "KAA",
            "MAA",
            54,
            "3 matrices are named MAA (46×46 at record 74, 36×36 at record 176",
        ),
        (
            "pyyeti/nas2cam_csuper.op4",
            "KAA@4",
            "MAA@4",
            54,
            "matrix MAA@4: the file holds 3 matrices named MAA",
        ),
    ] {
        let model = model_of(&dir, file, k, m, n);
        let e = nlsim::formats::model_file::load_model(model.to_str().unwrap())
            .err()
            .unwrap_or_else(|| panic!("{file} {k}: read"))
            .to_string();
        assert!(e.contains(want), "{file} {k}: {e}");
        assert!(e.contains(file.rsplit('/').next().unwrap()), "{e}");
    }
    // Other formats and sources.
    for (k, m, dofs, n, want) in [
        (
            "fembeam/model_STIF1.mtx",
            "fembeam/model_MASS1.mtx",
            "",
            0,
            "model_MASS1.mtx:1: node -1 is not a positive node number (an internal",
        ),
        (
            "pynastran/bah_plane_qhh.op4:QHH",
            "pynastran/bah_plane_qhh.op4:QHH",
            "generic",
            10,
            "30 matrices are named QHH (10×10 at line 1, 10×10 at line 54, 10×10 at line 107, \
             10×10 at line 160, 26 more); name one as QHH@1 … QHH@30",
        ),
        (
            "pynastran/bah_plane_qhh.op4:QHH@2",
            "pynastran/bah_plane_qhh.op4:QHH@2",
            "generic",
            10,
            "matrix 'QHH' has type 4: nlsim takes real matrices",
        ),
        (
            "hrb/lock1074.pse",
            "hrb/lock1074.pse",
            "generic",
            1074,
            "lock1074.pse:3: matrix type 'PSE': nlsim reads real assembled matrices",
        ),
        (
            "hrb/young3c.csa",
            "hrb/young3c.csa",
            "generic",
            841,
            "young3c.csa:3: matrix type 'CSA'",
        ),
        (
            "hrb/mahindas.rua",
            "hrb/mahindas.rua",
            "generic",
            1258,
            "the matrix is not symmetric",
        ),
        (
            "exudyn/blockC3D8_STIF1.mtx",
            "exudyn/blockC3D8_MASS1.mtx",
            "",
            0,
            "blockC3D8_STIF1.mtx is Abaqus COORDINATE output (ROW, COLUMN, VALUE by global \
             equation): its equations need labels",
        ),
        (
            "exudyn/blockC3D8_STIF1.mtx",
            "exudyn/blockC3D8_MASS1.mtx",
            "exudyn/rotorDiscTest.inp",
            0,
            "equation 346 is past the 345 DOF labels of",
        ),
    ] {
        let model = model_with(&dir, k, m, dofs, n);
        let e = nlsim::formats::model_file::load_model(model.to_str().unwrap())
            .err()
            .unwrap_or_else(|| panic!("{k}: read"))
            .to_string();
        assert!(e.contains(want), "{k}: {e}");
    }
    // An indefinite stiffness: `modes` refuses it (exit 1) instead of printing a 0 Hz mode.
    let indefinite = dir.join("indefinite.toml");
    std::fs::write(
        &indefinite,
        "name = \"ind\"\n[matrices]\nmass = [[1.0, 0.0], [0.0, 1.0]]\n\
         stiffness = [[1.0, 2.0], [2.0, 1.0]]\n",
    )
    .unwrap();
    let (rc, out, e) = nlsim(&["modes", indefinite.to_str().unwrap()]);
    assert_eq!(rc, 1, "{out}");
    assert!(
        e.contains(
            "stiffness matrix is not positive semi-definite: mode 1 has eigenvalue ω² = -1.0000e0"
        ) && !out.contains("0.000000"),
        "{e}\n{out}"
    );
    // `check` says which matrices had their mirrors averaged, and by how much at most.
    let both = model_of(&dir, "pyyeti/outboard_cla.op4", "KXX", "MXX", 46);
    let (rc, out, e) = nlsim(&["check", both.to_str().unwrap()]);
    assert_eq!(rc, 0, "{e}");
    assert!(
        out.contains("stiffness matrix KXX (")
            && out.contains("both triangles stored; mirrors averaged, the largest differs by")
            && out.contains("(symmetry_tolerance 1e-12)"),
        "{out}"
    );
    let one = model_with(
        &dir,
        "exudyn/rotorAnsysStiffnessMatrixSparse.txt",
        "exudyn/rotorAnsysMassMatrixSparse.txt",
        "exudyn/rotorAnsysMatrixDofMappingVector.txt",
        0,
    );
    let (rc, out, e) = nlsim(&["check", one.to_str().unwrap()]);
    assert_eq!(rc, 0, "{e}");
    assert!(!out.contains("mirrors averaged"), "{out}");
    // The mass first, then the stiffness in square form: read without names, each is the
    // matrix of its standard name (as pyyeti reads KXX and MXX), never K = M.
    let named = model_of(&dir, "pyyeti/inboard_mk_csuper.op4", "KXX", "MXX", 32);
    let a = nlsim::formats::model_file::load_model(named.to_str().unwrap()).unwrap();
    let unnamed = model_of(&dir, "pyyeti/inboard_mk_csuper.op4", "", "", 32);
    let b = nlsim::formats::model_file::load_model(unnamed.to_str().unwrap()).unwrap();
    assert_eq!(fnv(a.model.stiffness()), fnv(b.model.stiffness()));
    assert_eq!(fnv(a.model.mass()), fnv(b.model.mass()));
    assert_ne!(fnv(b.model.stiffness()), fnv(b.model.mass()));
}
