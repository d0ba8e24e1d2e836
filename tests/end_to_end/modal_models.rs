//! Test-based modal models (`[modal]` model files, issue 44 part 1): read, written by
//! `nlsim export --modal`, and run through the same reduction, harmonic balance, time
//! integration and calibration as FE models.

use super::*;
use nlsim::prelude::*;
use std::f64::consts::PI;

/// Loads a model file.
fn load(path: &Path) -> Model {
    nlsim::load_model(path.to_str().unwrap()).unwrap().model
}

/// The fundamental and higher harmonics of every sensor at `f_hz`, by harmonic balance with
/// the model's own force, and the FOH history of a 23 Hz sine at the drive.
fn responses(model: &Model, modes: usize) -> (Vec<faer::Mat<faer::c64>>, Vec<Vec<f64>>) {
    let reduced = reduce(model, &ReductionConfig::lowest(modes)).unwrap();
    let hb = HbSystem::from_model(
        model,
        &reduced,
        HarmonicSet::new(5, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    let mut hb_out = Vec::new();
    let mut x = hb.linear_guess(2.0 * PI * 20.0, 1.0);
    for f in [20.0, 22.0, 23.0, 23.6, 24.0, 26.0] {
        let w = 2.0 * PI * f;
        let (sol, newton) = hb.solve(w, 1.0, &x).unwrap();
        assert!(newton.status.is_converged(), "{f} Hz: {}", newton.status);
        hb_out.push(hb.sensor_response(&sol, w, 1.0));
        x = sol;
    }
    let plant = Plant::from_model(model, &ModalSystem::new(&reduced).unwrap()).unwrap();
    let foh = Simulator::new(&plant, &FohConfig::new(2e-4)).unwrap();
    let run = foh
        .run(&LoadCase::new("sine", vec![Signal::sine(0.2, 23.0)]), 2500)
        .unwrap();
    let histories = model
        .sensors()
        .iter()
        .map(|s| run.output(&s.name).unwrap().values.clone())
        .collect();
    (hb_out, histories)
}

fn max_rel(a: &[faer::Mat<faer::c64>], b: &[faer::Mat<faer::c64>]) -> f64 {
    let scale = a.iter().map(|m| m.norm_max()).fold(0.0, f64::max);
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).norm_max())
        .fold(0.0, f64::max)
        / scale
}

/// The ECL beam and the modal model `nlsim export --modal 4` writes of it: the same reduced
/// system up to the rounding of the eigen solve, hence the same FRFs and time histories; and
/// the truncation the modal model carries against the FE model with 20 modes.
#[test]
fn an_exported_modal_model_reproduces_its_fe_model() {
    let dir = scratch("modal-export");
    let (rc, out, err) = nlsim(&["export", "ecl_beam", dir.to_str().unwrap(), "--modal", "4"]);
    assert_eq!(rc, 0, "{err}");
    assert!(out.contains("4 modes at 2 points"), "{out}");
    let modal = load(&dir.join("modal.toml"));
    assert!(modal.is_modal());
    let fe = nlsim::load_model("ecl_beam").unwrap().model;
    let (hb_fe, th_fe) = responses(&fe, 4);
    let (hb_mo, th_mo) = responses(&modal, 4);
    // Same reduced matrices (eigenvalues and shapes written in full precision, the residual
    // flexibility as measured terms): rounding of the eigen solve only, ~1e-14.
    let hb_err = max_rel(&hb_fe, &hb_mo);
    assert!(hb_err < 1e-10, "HB harmonics differ by {hb_err:e}");
    for (a, b) in th_fe.iter().zip(&th_mo) {
        let scale = a.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let e = a
            .iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        assert!(e < 1e-10 * scale, "FOH histories differ by {:e}", e / scale);
    }
    // The truncation: 4 modes plus residual flexibility against 20 modes of the FE model.
    let (hb_20, _) = responses(&fe, 20);
    let trunc = max_rel(&hb_20, &hb_mo);
    eprintln!("modal model (4 modes) vs FE (20 modes): HB harmonics within {trunc:.2e}");
    assert!(trunc < 1e-2, "truncation {trunc:e}");
    std::fs::remove_dir_all(&*dir).unwrap();
}

/// Calibrating the tip spring from one virtual test on the FE model and on its modal model
/// gives the same estimates (the same reduced system) to far below their Cramér–Rao bounds.
#[test]
fn a_modal_model_calibrates_like_its_fe_model() {
    let dir = scratch("modal-calibrate");
    let d = dir.to_str().unwrap();
    assert_eq!(nlsim(&["export", "ecl_beam", d, "--modal", "4"]).0, 0);
    let test = dir.join("test.toml");
    std::fs::write(
        &test,
        "harmonics = 3\nmodes = 4\nseed = 3\nout = \"data.csv\"\n\n[[sweep]]\nfrom = 21.0\n\
         to = 26.0\nsteps = 12\nforce = 0.1\n",
    )
    .unwrap();
    let (rc, _, err) = nlsim(&["test", "ecl_beam", test.to_str().unwrap()]);
    assert_eq!(rc, 0, "{err}");
    let data = dir.join("data.csv");
    let estimate = |model: &str| -> (f64, f64) {
        let (rc, out, err) = nlsim(&[
            "calibrate",
            model,
            data.to_str().unwrap(),
            "--modes",
            "4",
            "--param",
            "tip_spring.k3=1e8:1e11",
            "--param",
            "mode2.zeta=0.002:0.05",
            "--folds",
            "0",
            "--threads",
            "1",
        ]);
        assert_eq!(rc, 0, "{err}");
        let line = out
            .lines()
            .find(|l| l.starts_with("tip_spring.k3"))
            .unwrap_or_else(|| panic!("{out}"));
        let w: Vec<f64> = line
            .split_whitespace()
            .skip(1)
            .take(2)
            .map(|x| x.parse().unwrap())
            .collect();
        (w[0], w[1])
    };
    let (k_fe, crb) = estimate("ecl_beam");
    let modal = dir.join("modal.toml");
    let (k_mo, _) = estimate(modal.to_str().unwrap());
    assert!(
        (k_fe - k_mo).abs() < 1e-6 * crb,
        "FE {k_fe:e}, modal {k_mo:e}, Cramér–Rao {crb:e}"
    );
    std::fs::remove_dir_all(&*dir).unwrap();
}

/// A hand-built two-mode model against the closed-form receptance `Σ φ_a φ_b / (ω_r² − ω² +
/// 2iζ_r ω_r ω) + R`, with a point driven, a second point measured, an element at zero
/// strength, and modal masses given as `m` beside unit-scaled shapes.
#[test]
fn a_modal_model_file_gives_the_closed_form_receptance() {
    let dir = scratch("modal-closed-form");
    let path = dir.join("two_mode.toml");
    std::fs::write(
        &path,
        r#"[modal]
points = ["1:uz", "2:uz"]
[[modal.mode]]
f_hz = 20.0
zeta = 0.01
shape = [0.5, 1.0]
m = 4.0
[[modal.mode]]
f_hz = 120.0
zeta = 0.02
shape = [0.8, -0.4]
[[modal.residual]]
ports = ["shaker", "root"]
flexibility = 3e-7

[[element]]
name = "spring"
type = "cubic"
dof = "2:uz"
dof2 = "1:uz"
k3 = 0.0

[[excitation]]
name = "shaker"
dof = "2:uz"
amplitude = 1.0

[[sensor]]
name = "root"
dof = "1:uz"
quantity = "displacement"
"#,
    )
    .unwrap();
    let model = load(&path);
    let reduced = reduce(&model, &ReductionConfig::lowest(2)).unwrap();
    let hb = HbSystem::from_model(
        &model,
        &reduced,
        HarmonicSet::new(1, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    // Mass-normalised entries: mode 1 given with m = 4 kg, so φ = shape / 2.
    let phi = [[0.25, 0.5], [0.8, -0.4]];
    let (w1, w2) = (2.0 * PI * 20.0, 2.0 * PI * 120.0);
    for f in [5.0, 19.0, 20.0, 21.0, 70.0, 119.0, 130.0] {
        let w = 2.0 * PI * f;
        let term = |p: [f64; 2], wr: f64, z: f64| {
            faer::c64::new(p[1] * p[0], 0.0) / faer::c64::new(wr * wr - w * w, 2.0 * z * wr * w)
        };
        let exact = term(phi[0], w1, 0.01) + term(phi[1], w2, 0.02) + faer::c64::new(3e-7, 0.0);
        let (x, _) = hb.solve(w, 1.0, &hb.linear_guess(w, 1.0)).unwrap();
        let y = hb.sensor_response(&x, w, 1.0)[(0, 1)];
        let got = faer::c64::new(y.re, y.im);
        assert!(
            (got - exact).norm() < 1e-12 * exact.norm(),
            "{f} Hz: {got:?} vs {exact:?}"
        );
    }
    let summary = nlsim(&["check", path.to_str().unwrap()]).1;
    assert!(
        summary.contains("spring (cubic) on 2:uz - 1:uz"),
        "{summary}"
    );
    assert!(summary.contains("points       1:uz, 2:uz"), "{summary}");
    std::fs::remove_dir_all(&*dir).unwrap();
}

/// Every bad `[modal]` input is refused with one line naming the file, the line and the key.
#[test]
fn bad_modal_model_files_name_file_line_and_key() {
    let dir = scratch("modal-errors");
    let good_mode = "[[modal.mode]]\nf_hz = 20.0\nzeta = 0.01\nshape = [1.0, 0.5]\n";
    let head = "[modal]\npoints = [\"1:uz\", \"2:uz\"]\n";
    let tail = "[[excitation]]\nname = \"shaker\"\ndof = \"1:uz\"\namplitude = 1.0\n";
    let cases: Vec<(String, &str, &str)> = vec![
        (format!("[modal]\n{good_mode}"), "modal.points", "missing"),
        (
            format!("{head}[[modal.mode]]\nf_hz = 20.0\nzeta = 0.01\nshape = [1.0]\n"),
            "modal.mode[1].shape",
            "1 entries for 2 points",
        ),
        (
            format!(
                "{head}{good_mode}[[modal.mode]]\nf_hz = 10.0\nzeta = 0.01\nshape = [1.0, 0.5]\n"
            ),
            "modal.mode[2]",
            "ascending",
        ),
        (
            format!("{head}[[modal.mode]]\nf_hz = 20.0\nzeta = 1.5\nshape = [1.0, 0.5]\n"),
            "modal.mode[1]",
            "[0, 1)",
        ),
        (
            format!(
                "{head}[[modal.mode]]\nf_hz = 20.0\nzeta = 0.01\nshape = [1.0, 0.5]\nm = -2.0\n"
            ),
            "modal.mode[1].m",
            "must be > 0",
        ),
        (
            format!("{head}[[modal.mode]]\nf_hz = 20.0\nzeta = 0.01\nshape = [1.0, 0.0]\n"),
            "modal.points",
            "no mode moves it",
        ),
        (
            "[modal]\npoints = [\"1:uz\", \"1:uz\"]\n".to_string() + good_mode,
            "modal.points",
            "listed twice",
        ),
        (
            format!("{head}{good_mode}[matrices]\nfixture = \"ecl_beam\"\n"),
            "modal",
            "not both",
        ),
        (
            format!("{head}{good_mode}[damping]\ntype = \"none\"\n"),
            "damping",
            "each mode's zeta",
        ),
        (
            format!("{head}{good_mode}[[spring]]\ndof = \"mode1\"\nk = 1.0\n"),
            "spring[1]",
            "no FE matrices",
        ),
        (
            format!(
                "{head}{good_mode}[[element]]\nname = \"e\"\ntype = \"cubic\"\ndof = \"3:uz\"\nk3 = 1.0\n"
            ),
            "element[1].dof",
            "not a point of this modal model",
        ),
        (
            format!(
                "{head}{good_mode}[[element]]\nname = \"e\"\ntype = \"cubic\"\ndof = \"mode2\"\nk3 = 1.0\n"
            ),
            "element[1].dof",
            "modes 1 to 1",
        ),
        (
            format!(
                "{head}{good_mode}[[modal.residual]]\nports = [\"shaker\", \"tip\"]\nflexibility = 1e-7\n{tail}"
            ),
            "modal.residual[1].ports",
            "'tip' is not a port",
        ),
        (
            format!(
                "{head}{good_mode}[[modal.residual]]\nports = [\"shaker\", \"shaker\"]\nflexibility = -1e-7\n{tail}"
            ),
            "modal.residual[1]",
            "negative",
        ),
    ];
    for (text, key, says) in &cases {
        let path = dir.join("bad.toml");
        let e = nlsim::parse_model_file(text, &path)
            .err()
            .unwrap_or_else(|| panic!("accepted:\n{text}"))
            .to_string();
        assert!(
            e.contains("bad.toml:") && e.contains(&format!(": {key}: ")),
            "expected key {key}: {e}\n{text}"
        );
        assert!(e.contains(says), "expected '{says}': {e}");
        assert_eq!(e.lines().count(), 1, "{e}");
    }
    std::fs::remove_dir_all(&*dir).unwrap();
}
