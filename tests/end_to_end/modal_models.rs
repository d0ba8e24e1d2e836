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

/// A two-mode model file: points `1:uz`, `2:uz`; mode 1 at 20 Hz with shape `[0.5, s21]` as
/// written and `m = 4` kg (so `φ = shape / 2`), mode 2 at 120 Hz `[0.8, -0.4]`; a residual
/// flexibility `r` between the drive and the sensor; a cubic `k3` between the two points; the
/// drive at `2:uz`, the displacement sensor `root` at `1:uz`.
fn two_mode(s21: f64, r: f64, k3: f64) -> String {
    format!(
        r#"[modal]
points = ["1:uz", "2:uz"]
[[modal.mode]]
f_hz = 20.0
zeta = 0.01
shape = [0.5, {s21:e}]
m = 4.0
[[modal.mode]]
f_hz = 120.0
zeta = 0.02
shape = [0.8, -0.4]
[[modal.residual]]
ports = ["shaker", "root"]
flexibility = {r:e}

[[element]]
name = "spring"
type = "cubic"
dof = "2:uz"
dof2 = "1:uz"
k3 = {k3:e}

[[excitation]]
name = "shaker"
dof = "2:uz"
amplitude = 1.0

[[sensor]]
name = "root"
dof = "1:uz"
quantity = "displacement"
"#
    )
}

/// Shape entries (`modeN.shape:POINT`) and measured residual flexibilities
/// (`residual:A:B`) of a modal model are parameters like any other (issue 44 part 1):
/// listed, set (equal to the model file written with the new value, which moves every port
/// on the point: the drive, the sensor and the element's end with its sign), differentiated
/// (harmonic balance sensitivities against central differences at a nonlinear solution), set
/// from the command line, and calibrated from a virtual test.
#[test]
fn shape_entries_and_residual_terms_are_parameters() {
    let dir = scratch("modal-shape-params");
    let (s21, r, k3) = (1.0, 3e-7, 3e11);
    let system = |text: &str| {
        let path = dir.join("m.toml");
        std::fs::write(&path, text).unwrap();
        let model = load(&path);
        let reduced = reduce(&model, &ReductionConfig::lowest(2)).unwrap();
        HbSystem::from_model(
            &model,
            &reduced,
            HarmonicSet::new(3, 1).unwrap(),
            HbConfig::default(),
        )
        .unwrap()
    };
    let nominal = system(&two_mode(s21, r, k3));
    let p_shape: Param = "mode1.shape:2:uz".parse().unwrap();
    let p_root: Param = "mode2.shape:1:uz".parse().unwrap();
    let p_res: Param = "residual:shaker:root".parse().unwrap();
    let known = nominal.parameters();
    for p in [&p_shape, &p_root, &p_res] {
        assert!(known.contains(p), "{p} not in {known:?}");
    }
    // Mass-normalised: the written 1.0 with m = 4 kg is 0.5 m/√kg.
    assert_eq!(nominal.param(&p_shape).unwrap(), 0.5);
    assert_eq!(nominal.param(&p_root).unwrap(), 0.8);
    assert_eq!(nominal.param(&p_res).unwrap(), r);
    // Setting equals the file written with the new values (φ 0.5 → 0.6, i.e. 1.2 as
    // written; residual 3e-7 → 5e-7; mode 2 at 1:uz 0.8 → 0.7), at a nonlinear solution.
    let mut set = nominal.clone();
    set.set_param(&p_shape, 0.6).unwrap();
    set.set_param(&p_res, 5e-7).unwrap();
    set.set_param(&p_root, 0.7).unwrap();
    let edited =
        system(&two_mode(1.2, 5e-7, k3).replace("shape = [0.8, -0.4]", "shape = [0.7, -0.4]"));
    let w = 2.0 * PI * 19.6;
    let solve = |s: &HbSystem| {
        let (x, rep) = s.solve(w, 1.0, &s.linear_guess(w, 1.0)).unwrap();
        assert!(rep.converged());
        (s.sensor_response(&x, w, 1.0), x)
    };
    let (y_set, _) = solve(&set);
    let (y_file, _) = solve(&edited);
    let d = (&y_set - &y_file).norm_max() / y_file.norm_max();
    assert!(d < 1e-10, "set vs edited file: {d:e}");
    // Sensitivities against central differences (relative step 1e-5: truncation ~1e-10,
    // Newton's 1e-10 round-off over the step ~1e-5 of the response), as for FE parameters.
    let (y0, x0) = solve(&nominal);
    let third = y0[(0, 3)].norm() / y0[(0, 1)].norm();
    assert!(third > 1e-3, "the cubic barely acts: 3rd/1st {third:e}");
    let sens = nominal
        .sensitivities(
            &x0,
            w,
            1.0,
            &[p_shape.clone(), p_root.clone(), p_res.clone()],
        )
        .unwrap();
    for s in &sens {
        let v = nominal.param(&s.param).unwrap();
        let h = 1e-5 * v.abs();
        let at = |dv: f64| {
            let mut q = nominal.clone();
            q.set_param(&s.param, v + dv).unwrap();
            let (x, rep) = q.solve(w, 1.0, &x0).unwrap();
            assert!(rep.converged());
            q.sensor_response(&x, w, 1.0)
        };
        let fd = (at(h) - at(-h)) * faer::Scale(faer::c64::new(1.0 / (2.0 * h), 0.0));
        let scale =
            y0.norm_max() * 1e-4 + (&fd * faer::Scale(faer::c64::new(v, 0.0))).norm_max() * 1e-4;
        let diff = (&fd - &s.dy).norm_max() * v.abs();
        assert!(
            diff <= scale,
            "{}: analytic {:?} vs differences {:?}",
            s.param,
            s.dy,
            fd
        );
        assert!(
            s.dy.norm_max() * v.abs() > 1e-3 * y0.norm_max(),
            "{} has no effect",
            s.param
        );
    }
    // The command line: `frf --set` equals the edited file.
    let nominal_path = dir.join("nominal.toml");
    std::fs::write(&nominal_path, two_mode(s21, r, k3)).unwrap();
    let edited_path = dir.join("edited.toml");
    std::fs::write(&edited_path, two_mode(1.2, 5e-7, k3)).unwrap();
    let frf = |model: &Path, out: &str, sets: &[&str]| {
        let out = dir.join(out);
        let mut args = vec![
            "frf",
            model.to_str().unwrap(),
            "--from",
            "15",
            "--to",
            "25",
            "--mode",
            "step-up",
            "--points",
            "21",
            "--modes",
            "2",
            "--harmonics",
            "3",
            "--out",
            out.to_str().unwrap(),
            "-q",
        ];
        for s in sets {
            args.extend(["--set", s]);
        }
        let (rc, _, e) = nlsim(&args);
        assert_eq!(rc, 0, "{e}");
        std::fs::read_to_string(out).unwrap()
    };
    let a = frf(
        &nominal_path,
        "a.csv",
        &["mode1.shape:2:uz=0.6", "residual:root:shaker=5e-7"],
    );
    let b = frf(&edited_path, "b.csv", &[]);
    let numbers = |t: &str| -> Vec<f64> {
        t.lines()
            .filter(|l| !l.starts_with('#'))
            .skip(1)
            .flat_map(|l| {
                l.split(',')
                    .filter_map(|c| c.parse::<f64>().ok())
                    .collect::<Vec<_>>()
            })
            .collect()
    };
    let (na, nb) = (numbers(&a), numbers(&b));
    assert_eq!(na.len(), nb.len());
    assert!(!na.is_empty());
    let top = nb.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (x, y) in na.iter().zip(&nb) {
        assert!(
            (x - y).abs() <= 1e-9 * y.abs().max(1e-6 * top),
            "{x} vs {y}"
        );
    }
    // `check` names the new kinds; an entry of a mode or a pair the model lacks is refused
    // with the parameters it has.
    let summary = nlsim(&["check", nominal_path.to_str().unwrap()]).1;
    assert!(
        summary.contains("residual:A:B") && summary.contains("modeN.shape:POINT"),
        "{summary}"
    );
    for (bad, says) in [
        ("mode3.shape:2:uz=1", "mode2.shape:1:uz"),
        ("residual:shaker:spring=1e-7", "residual:root:shaker"),
        ("mode1.shape:9:uz=1", "mode1.shape:2:uz"),
    ] {
        let (rc, _, e) = nlsim(&[
            "frf",
            nominal_path.to_str().unwrap(),
            "--from",
            "15",
            "--to",
            "16",
            "--modes",
            "2",
            "--set",
            bad,
        ]);
        assert_ne!(rc, 0, "{bad} accepted");
        assert!(
            e.contains(bad.split('=').next().unwrap()) && e.contains(says),
            "{bad}: {e}"
        );
        assert_eq!(e.trim().lines().count(), 1, "{e}");
    }
    // Calibration: a virtual test of the edited structure (1 % noise), the nominal model's
    // shape entry and residual term recovered within three Cramér–Rao deviations.
    let test = dir.join("test.toml");
    std::fs::write(
        &test,
        "harmonics = 3\nmodes = 2\nseed = 5\nout = \"data.csv\"\nnoise = { relative = 0.01 }\n\n\
         [[sweep]]\nfrom = 12.0\nto = 90.0\nsteps = 40\nforce = 0.5\n",
    )
    .unwrap();
    let (rc, _, e) = nlsim(&[
        "test",
        edited_path.to_str().unwrap(),
        test.to_str().unwrap(),
    ]);
    assert_eq!(rc, 0, "{e}");
    let est = dir.join("est.csv");
    let (rc, o, e) = nlsim(&[
        "calibrate",
        nominal_path.to_str().unwrap(),
        dir.join("data.csv").to_str().unwrap(),
        "--modes",
        "2",
        "--harmonics",
        "3",
        "--param",
        "mode1.shape:2:uz=0.2:1.5",
        "--param",
        "residual:shaker:root=-2e-6:2e-6",
        "--folds",
        "0",
        "--threads",
        "1",
        "--out",
        est.to_str().unwrap(),
    ]);
    assert_eq!(rc, 0, "{e}\n{o}");
    let got = estimates(&est);
    for (name, truth) in [("mode1.shape:2:uz", 0.6), ("residual:root:shaker", 5e-7)] {
        let (v, sd) = got[name];
        eprintln!(
            "{name}: {v:e} ± {sd:e} (truth {truth:e}, {:+.2} σ)",
            (v - truth) / sd
        );
        assert!(
            (v - truth).abs() < 3.0 * sd,
            "{name}: {v:e} ± {sd:e}, truth {truth:e}"
        );
    }
    std::fs::remove_dir_all(&*dir).unwrap();
}

/// A hand-built two-mode model against the closed-form receptance `Σ φ_a φ_b / (ω_r² − ω² +
/// 2iζ_r ω_r ω) + R`, with a point driven, a second point measured, an element at zero
/// strength, and modal masses given as `m` beside unit-scaled shapes.
#[test]
fn a_modal_model_file_gives_the_closed_form_receptance() {
    let dir = scratch("modal-closed-form");
    let path = dir.join("two_mode.toml");
    std::fs::write(&path, two_mode(1.0, 3e-7, 0.0)).unwrap();
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
