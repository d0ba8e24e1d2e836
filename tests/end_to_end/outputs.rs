//! No run destroys an input (issue 72): an output that is one of the run's inputs — named
//! directly, spelt with `./` or `../`, or reached through a hard link — and an output folder
//! that holds an input are refused in one line before anything is computed; the input's bytes
//! stay as they were and nothing is created. The inputs include what the command line does
//! not name: the matrices and node file a model file reads, the test data a calibration's
//! result names, an excitation file.

use super::*;
use std::collections::BTreeMap;

/// Every file below `dir` (hidden ones included) with its bytes, by path.
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            let meta = std::fs::symlink_metadata(&p).unwrap();
            if meta.is_dir() {
                out.insert(p.clone(), Vec::new());
                stack.push(p);
            } else if meta.file_type().is_symlink() {
                out.insert(
                    p.clone(),
                    std::fs::read_link(&p)
                        .unwrap()
                        .into_os_string()
                        .into_encoded_bytes(),
                );
            } else {
                out.insert(p.clone(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// A model file that takes the ECL beam's matrices and elements and reads its node
/// coordinates from `nodes.csv` beside it.
const BEAM: &str = "[matrices]\nfixture = \"ecl_beam\"\n\n[geometry]\nnodes = \"nodes.csv\"\n";

/// A short virtual stepped-sine test of the beam, its data written to `OUT`.
fn test_file(out: &str) -> String {
    format!(
        "harmonics = 1\nmodes = 8\nnoise = {{ relative = 0.02 }}\nout = \"{out}\"\n\
         [[sweep]]\nlabel = \"low\"\nfrom = 21.0\nto = 30.0\nsteps = 5\nforce = 0.2\n"
    )
}

#[test]
fn no_output_replaces_an_input_by_any_name() {
    let dir = scratch("outputs-guard");
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    // The inputs: an exported model folder with a model file of its own files, the beam with
    // its node file, test data, a calibration's result naming them, an excitation file, a
    // raw record, and a folder of nlsim's that holds data.
    let (rc, _, e) = nlsim(&["export", "ecl_beam", &d("fe")]);
    assert_eq!(rc, 0, "{e}");
    std::fs::write(
        dir.join("fe/m.toml"),
        "[matrices]\nmass = \"M.mtx\"\nstiffness = \"K.mtx\"\ndofs = \"dofs.txt\"\n\n\
         [geometry]\nnodes = \"nodes.csv\"\n",
    )
    .unwrap();
    std::fs::copy(dir.join("fe/nodes.csv"), dir.join("nodes.csv")).unwrap();
    std::fs::write(dir.join("beam.toml"), BEAM).unwrap();
    std::fs::write(dir.join("test.toml"), test_file("vt.csv")).unwrap();
    std::fs::write(dir.join("test_nodes.toml"), test_file("nodes.csv")).unwrap();
    let (rc, _, e) = nlsim(&["test", &d("beam.toml"), &d("test.toml"), "-q"]);
    assert_eq!(rc, 0, "{e}");
    std::fs::write(
        dir.join("cal.toml"),
        format!(
            "model = \"{}\"\ndata = \"{}\"\nharmonics = 1\nmodes = 8\n\n[[param]]\n\
             name = \"tip_spring.k3\"\nlower = 6e7\nupper = 6e11\n\n[result]\n\
             status = \"converged\"\nestimate = [6e9]\ncovariance = [[1e16]]\n\
             reduced_chi2 = 1.0\npoints = 5\nresiduals = 10\n",
            d("beam.toml"),
            d("vt.csv")
        ),
    )
    .unwrap();
    std::fs::write(dir.join("f.csv"), "0.1\n0.2\n0.0\n-0.1\n").unwrap();
    let (rc, _, e) = nlsim(&[
        "simulate",
        "ecl_beam",
        "--duration",
        "0.05",
        "--rate",
        "2000",
        "--excitation",
        "sine:freq=25,amp=0.1",
        "-q",
        "--out",
        &d("rec.csv"),
    ]);
    assert_eq!(rc, 0, "{e}");
    std::fs::create_dir(dir.join("data")).unwrap();
    std::fs::write(dir.join("data/.nlsim-report"), "nlsim calibrate …\n").unwrap();
    std::fs::copy(dir.join("vt.csv"), dir.join("data/vt.csv")).unwrap();
    std::fs::hard_link(dir.join("nodes.csv"), dir.join("nodes-hard.csv")).unwrap();
    std::fs::hard_link(dir.join("vt.csv"), dir.join("vt-hard.csv")).unwrap();
    std::fs::create_dir(dir.join("sub")).unwrap();
    let calibrate = |data: &str, opt: &str, out: &str| -> Vec<String> {
        vec![
            "calibrate".into(),
            d("beam.toml"),
            d(data),
            "--param".into(),
            "tip_spring.k3=6e7:6e11".into(),
            "--harmonics".into(),
            "1".into(),
            opt.into(),
            out.into(),
        ]
    };
    let strs = |v: &[&str]| -> Vec<String> { v.iter().map(|s| s.to_string()).collect() };
    // (what, the command, the input it would have replaced)
    let rows: Vec<(&str, Vec<String>, &str)> = vec![
        (
            "export into the model's own folder",
            strs(&["export", &d("fe/m.toml"), &d("fe")]),
            "fe/m.toml",
        ),
        (
            "modes --report: a folder holding the model",
            strs(&[
                "modes",
                &d("fe/m.toml"),
                "--count",
                "2",
                "--report",
                &d("fe"),
            ]),
            "fe/m.toml",
        ),
        (
            "modes --out the node file",
            strs(&[
                "modes",
                &d("beam.toml"),
                "--count",
                "2",
                "--out",
                &d("nodes.csv"),
            ]),
            "nodes.csv",
        ),
        (
            "frf --out ./ the node file",
            strs(&[
                "frf",
                &d("beam.toml"),
                "--from",
                "20",
                "--to",
                "21",
                "--out",
                &d("./nodes.csv"),
            ]),
            "nodes.csv",
        ),
        (
            "simulate --out a hard link to the node file",
            strs(&[
                "simulate",
                &d("beam.toml"),
                "--duration",
                "0.01",
                "--rate",
                "1000",
                "--excitation",
                "sine:freq=20,amp=0.1",
                "--out",
                &d("nodes-hard.csv"),
            ]),
            "nodes.csv",
        ),
        (
            "nnm --out ../ the node file",
            strs(&[
                "nnm",
                &d("beam.toml"),
                "--from",
                "1e-5",
                "--to",
                "1e-4",
                "--out",
                &d("sub/../nodes.csv"),
            ]),
            "nodes.csv",
        ),
        (
            "harmonics --out the node file",
            strs(&[
                "harmonics",
                &d("beam.toml"),
                &d("rec.csv"),
                "--out",
                &d("nodes.csv"),
            ]),
            "nodes.csv",
        ),
        (
            "calibrate --out the node file",
            calibrate("vt.csv", "--out", &d("nodes.csv")),
            "nodes.csv",
        ),
        (
            "calibrate --out a hard link to the data",
            calibrate("vt.csv", "--out", &d("vt-hard.csv")),
            "vt.csv",
        ),
        (
            "calibrate --report the data's folder",
            calibrate("data/vt.csv", "--report", &d("data")),
            "data/vt.csv",
        ),
        (
            "test writes its data over the node file",
            strs(&["test", &d("beam.toml"), &d("test_nodes.toml"), "-q"]),
            "nodes.csv",
        ),
        (
            "validate --out the data the result names",
            strs(&["validate", &d("cal.toml"), "--out", &d("vt.csv")]),
            "vt.csv",
        ),
        (
            "simulate --out its excitation file",
            strs(&[
                "simulate",
                "ecl_beam",
                "--duration",
                "0.01",
                "--rate",
                "1000",
                "--excitation",
                &format!("file:{}", d("f.csv")),
                "--out",
                &d("f.csv"),
            ]),
            "f.csv",
        ),
    ];
    for (what, args, input) in &rows {
        let before = snapshot(&dir);
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (rc, _, err) = nlsim(&args);
        assert_eq!(rc, 2, "{what}: exit {rc}: {err}");
        assert_eq!(err.trim().lines().count(), 1, "{what}: {err}");
        let name = Path::new(input).file_name().unwrap().to_str().unwrap();
        assert!(
            err.contains("input") && err.contains(name),
            "{what}: the refusal names the input {input}: {err}"
        );
        let after = snapshot(&dir);
        assert!(
            before == after,
            "{what}: files changed or created: {:?}",
            after
                .iter()
                .filter(|(p, b)| before.get(*p) != Some(b))
                .map(|(p, _)| p)
                .collect::<Vec<_>>()
        );
    }
}

/// A report folder another run holds (its lock taken here, as a concurrent run holds it) is
/// refused in one line at the start, and the folder is left as it was.
#[test]
fn a_report_folder_another_run_holds_is_refused() {
    let dir = scratch("outputs-lock");
    let rep = dir.join("rep");
    let run = |rep: &Path| {
        nlsim(&[
            "modes",
            "ecl_beam",
            "--count",
            "2",
            "-q",
            "--report",
            rep.to_str().unwrap(),
        ])
    };
    let (rc, _, e) = run(&rep);
    assert_eq!(rc, 0, "{e}");
    let before = snapshot(&dir);
    let lock = std::fs::File::create(dir.join(".rep.lock")).unwrap();
    lock.lock().unwrap();
    let (rc, _, e) = run(&rep);
    assert_eq!(rc, 2, "{e}");
    assert_eq!(e.trim().lines().count(), 1, "{e}");
    assert!(e.contains("another nlsim run is writing it"), "{e}");
    drop(lock);
    // Only the lock file differs (this test made it).
    let mut after = snapshot(&dir);
    after.remove(&dir.join(".rep.lock"));
    assert!(
        before == after,
        "the folder changed while another run held it"
    );
    // Released, the folder is written again, whole, and the lock file is gone.
    let (rc, _, e) = run(&rep);
    assert_eq!(rc, 0, "{e}");
    assert!(!dir.join(".rep.lock").exists());
}
