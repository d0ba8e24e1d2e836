//! Voltage-driven test data and the gains of test data (issue 44 part 3) through the CLI:
//! `nlsim test --record voltage`, the readers of the voltage drive, a calibration through a
//! modelled shaker recovering the structure and the amplifier's gain, and bad input.

use super::*;
use nlsim::formats::test_data::{DataOptions, read};

const TEST: &str = "harmonics = 3\nmodes = 4\nseed = 2\nrecord = \"voltage\"\n\
    amplifier_gain = 8.0\n\n[control]\nenabled = false\n\n\
    [[sweep]]\nlabel = \"low\"\nfrom = 21.5\nto = 25.5\nsteps = 17\nforce = 0.05\n\n\
    [[sweep]]\nlabel = \"high\"\nfrom = 21.5\nto = 26.5\nsteps = 21\nforce = 0.2\n";

const CAL: &str = "model = \"ecl_beam\"\ndata = \"volt.csv\"\nharmonics = 3\nmodes = 4\n\
    compare = [1, 3]\nlhs = 16\nstarts = 2\nfolds = 0\nout = \"estimates.csv\"\n\n\
    [shaker]\nresistance = 1.5\n\n\
    [[param]]\nname = \"tip_spring.k3\"\nlower = 6e7\nupper = 6e11\n\n\
    [[param]]\nname = \"mode2.zeta\"\nlower = 0.001\nupper = 0.1\n\n\
    [[param]]\nname = \"input_gain\"\nlower = 1.0\nupper = 50.0\n";

/// The open-loop test recorded as voltage (the coil voltage over the amplifier gain, the
/// same for every step of a sweep): read back from CSV and HDF5 as a voltage drive; then the
/// calibration through the same shaker gives the cubic stiffness, the damping and the
/// amplifier gain within three Cramér–Rao deviations of the truth; `nlsim validate` predicts
/// a sweep from its result.
#[test]
fn voltage_record_calibrates_structure_and_amplifier_gain() {
    let dir = scratch("voltage");
    std::fs::write(dir.join("volt_test.toml"), TEST).unwrap();
    std::fs::write(dir.join("cal.toml"), CAL).unwrap();
    let test = dir.join("volt_test.toml");
    for out in ["volt.csv", "volt.h5"] {
        let (rc, o, e) = nlsim(&[
            "test",
            "ecl_beam",
            test.to_str().unwrap(),
            "--out",
            dir.join(out).to_str().unwrap(),
            "--report",
            dir.join(format!("{out}-report")).to_str().unwrap(),
        ]);
        assert_eq!(rc, 0, "{e}\n{o}");
    }
    let text = std::fs::read_to_string(dir.join("volt.csv")).unwrap();
    assert!(text.contains("\n# input: shaker, voltage\n"), "{text}");
    let model = nlsim::load_model("ecl_beam").unwrap().model;
    let csv = read(&dir.join("volt.csv"), &model, &DataOptions::default()).unwrap();
    fresh_inode(&dir.join("volt.h5"));
    let h5 = read(&dir.join("volt.h5"), &model, &DataOptions::default()).unwrap();
    assert_eq!(csv.drive, nlsim::calib::Drive::Voltage);
    assert_eq!(h5.drive, nlsim::calib::Drive::Voltage);
    assert_eq!(csv.sweeps.len(), 2);
    for (a, b) in csv.sweeps.iter().zip(&h5.sweeps) {
        assert_eq!(a.steps.len(), b.steps.len());
        let v0 = a.steps[0].force[0];
        for (s, t) in a.steps.iter().zip(&b.steps) {
            // Open loop: one voltage per sweep; the CSV's text round trip is exact.
            assert_eq!(s.force, t.force);
            assert_eq!(s.force[0], v0);
            assert!(s.force[1..].iter().all(|v| v.norm() == 0.0));
        }
    }
    let (rc, o, e) = nlsim(&[
        "calibrate",
        "--config",
        dir.join("cal.toml").to_str().unwrap(),
    ]);
    assert_eq!(rc, 0, "{e}\n{o}");
    let est = estimates(&dir.join("estimates.csv"));
    // The truth: the built-in beam's cubic spring, its Rayleigh damping (1 % on the
    // driven bending mode) and the test's amplifier gain.
    for (name, truth) in [
        ("tip_spring.k3", 6e9),
        ("mode2.zeta", 0.01),
        ("input_gain", 8.0),
    ] {
        let (v, sd) = est[name];
        assert!(
            (v - truth).abs() <= 3.0 * sd,
            "{name}: {v} vs truth {truth} (Cramér–Rao {sd})\n{o}"
        );
    }
    // The same data with the voltage taken as the force (no shaker): far off.
    let no_shaker = CAL.replace("[shaker]\nresistance = 1.5\n\n", "");
    std::fs::write(
        dir.join("cal2.toml"),
        no_shaker.replace("estimates.csv", "e2.csv"),
    )
    .unwrap();
    let (rc, o, e) = nlsim(&[
        "calibrate",
        "--config",
        dir.join("cal2.toml").to_str().unwrap(),
    ]);
    assert_eq!(rc, 0, "{e}\n{o}");
    let (k3, sd) = estimates(&dir.join("e2.csv"))["tip_spring.k3"];
    assert!((k3 - 6e9).abs() > 10.0 * sd, "{k3} ± {sd}");
    // From the command line alone: `--shaker` (nlsim's default shaker, whose resistance is
    // the calibration file's 1.5 ohm) and `--shaker TEST` (the test file's, which has no
    // `[shaker]`: the default it ran with) give the calibration file's estimates to the bit;
    // a test file whose shaker is invalid is refused naming it.
    let config = std::fs::read_to_string(dir.join("estimates.csv")).unwrap();
    for shaker in [None, Some(test.to_str().unwrap())] {
        let out = dir.join("e3.csv");
        let mut args = vec![
            "calibrate",
            "ecl_beam",
            "volt.csv",
            "--param",
            "tip_spring.k3=6e7:6e11",
            "--param",
            "mode2.zeta=0.001:0.1",
            "--param",
            "input_gain=1:50",
            "--compare",
            "1,3",
            "--modes",
            "4",
            "--lhs",
            "16",
            "--starts",
            "2",
            "--folds",
            "0",
            "--shaker",
        ];
        args.extend(shaker);
        args.extend(["--out", out.to_str().unwrap()]);
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_nlsim"))
            .args(&args)
            .current_dir(&*dir)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert_eq!(std::fs::read_to_string(&out).unwrap(), config, "{shaker:?}");
    }
    std::fs::write(dir.join("bad.toml"), "[shaker]\nresistance = -1.0\n").unwrap();
    let (rc, _, e) = nlsim(&[
        "calibrate",
        "ecl_beam",
        dir.join("volt.csv").to_str().unwrap(),
        "--param",
        "input_gain=1:50",
        "--shaker",
        dir.join("bad.toml").to_str().unwrap(),
    ]);
    assert_ne!(rc, 0);
    assert!(
        e.contains("bad.toml") && e.contains("shaker.resistance"),
        "{e}"
    );
}

/// Voltage data and gains refuse what they cannot use, in one line naming the place.
#[test]
fn gains_and_voltage_records_refuse_bad_input() {
    let dir = scratch("voltage-bad");
    std::fs::write(dir.join("volt_test.toml"), TEST).unwrap();
    let data = dir.join("volt.csv");
    let (rc, _, e) = nlsim(&[
        "test",
        "ecl_beam",
        dir.join("volt_test.toml").to_str().unwrap(),
        "--out",
        data.to_str().unwrap(),
    ]);
    assert_eq!(rc, 0, "{e}");
    let d = data.to_str().unwrap();
    let run = |extra: &[&str]| {
        let mut args = vec![
            "calibrate",
            "ecl_beam",
            d,
            "--param",
            "tip_spring.k3=6e7:6e11",
        ];
        args.extend_from_slice(extra);
        args.push("--dry-run");
        nlsim(&args)
    };
    // A voltage record with no gain stated or calibrated.
    let (rc, _, e) = run(&[]);
    assert_eq!(rc, 2, "{e}");
    assert!(
        e.contains("recorded as a voltage") && e.contains("input_gain"),
        "{e}"
    );
    // A gain that is not positive; a channel the data do not have.
    let (rc, _, e) = run(&["--set", "input_gain=-2"]);
    assert_eq!(rc, 2, "{e}");
    assert!(e.contains("input_gain") && e.contains("positive"), "{e}");
    let (rc, _, e) = run(&[
        "--set",
        "input_gain=3",
        "--param",
        "sensor_gain:nosuch=0.5:2",
    ]);
    assert_ne!(rc, 0);
    assert!(
        e.contains("sensor_gain:nosuch") && e.contains("sensor_gain:tip"),
        "{e}"
    );
    let (rc, _, e) = run(&["--param", "input_gain=0:5"]);
    assert_ne!(rc, 0);
    assert!(e.contains("input_gain") && e.contains("lower bound"), "{e}");
    // A model holds no gain.
    let (rc, _, e) = nlsim(&[
        "frf",
        "ecl_beam",
        "--from",
        "20",
        "--to",
        "25",
        "--set",
        "input_gain=2",
    ]);
    assert_ne!(rc, 0);
    assert!(e.contains("belongs to the test data"), "{e}");
    // A shaker needs a voltage record.
    let force = dir.join("force.csv");
    std::fs::write(
        &force,
        std::fs::read_to_string(&data)
            .unwrap()
            .replace("# input: shaker, voltage", "# input: shaker"),
    )
    .unwrap();
    let cal = CAL.replace("volt.csv", force.to_str().unwrap());
    std::fs::write(dir.join("cal.toml"), &cal).unwrap();
    let (rc, _, e) = nlsim(&[
        "calibrate",
        "--config",
        dir.join("cal.toml").to_str().unwrap(),
        "--dry-run",
    ]);
    assert_ne!(rc, 0);
    assert!(e.contains("shaker") && e.contains("voltage"), "{e}");
    // An unknown drive record, in the data and in the test file.
    let bad = dir.join("bad.csv");
    std::fs::write(
        &bad,
        std::fs::read_to_string(&data)
            .unwrap()
            .replace("# input: shaker, voltage", "# input: shaker, volts"),
    )
    .unwrap();
    let (rc, _, e) = nlsim(&[
        "calibrate",
        "ecl_beam",
        bad.to_str().unwrap(),
        "--param",
        "tip_spring.k3=6e7:6e11",
        "--dry-run",
    ]);
    assert_ne!(rc, 0);
    assert!(e.contains("bad.csv:2") && e.contains("volts"), "{e}");
    std::fs::write(
        dir.join("t2.toml"),
        TEST.replace("\"voltage\"", "\"current\""),
    )
    .unwrap();
    let (rc, _, e) = nlsim(&["test", "ecl_beam", dir.join("t2.toml").to_str().unwrap()]);
    assert_ne!(rc, 0);
    assert!(
        e.contains("t2.toml") && e.contains("record") && e.contains("current"),
        "{e}"
    );
    let (rc, _, e) = nlsim(&[
        "test",
        "ecl_beam",
        dir.join("volt_test.toml").to_str().unwrap(),
        "--amplifier-gain",
        "0",
    ]);
    assert_ne!(rc, 0);
    assert!(e.contains("amplifier_gain"), "{e}");
    // A table with both drive columns.
    let table = dir.join("both.csv");
    std::fs::write(
        &table,
        "frequency_hz,force_amplitude_n,voltage_amplitude_v,tip_amplitude_m_s2,phase_rad\n\
         20,1,2,3,0.1\n",
    )
    .unwrap();
    let (rc, _, e) = nlsim(&[
        "calibrate",
        "ecl_beam",
        table.to_str().unwrap(),
        "--param",
        "tip_spring.k3=6e7:6e11",
        "--dry-run",
    ]);
    assert_ne!(rc, 0);
    assert!(
        e.contains("both.csv:1") && e.contains("voltage_amplitude_v"),
        "{e}"
    );
}

/// `nlsim plan` with gains among the parameters (planned as calibrated along, nominal 1):
/// ranked with their Cramér–Rao deviations; a design without the tip sensor cannot identify
/// its gain, nor one with the tip alone (the scaling law below); a gain of a sensor the model
/// lacks is refused naming it.
#[test]
fn a_plan_takes_gains_as_parameters() {
    let dir = scratch("plan-gains");
    let plan = |params: &str| {
        let path = dir.join("plan.toml");
        std::fs::write(
            &path,
            format!(
                "params = [{params}]\nlevels = [0.1, 0.2]\nmeasured = [[1], [1, 3]]\n\
                 harmonics = 3\nmodes = 6\ntop = 100\nreport = \"{}\"\n\n[[band]]\n\
                 label = \"across\"\nfrom = 22.0\nto = 26.0\nsteps = 9\n",
                dir.join("report").display()
            ),
        )
        .unwrap();
        nlsim(&["plan", "ecl_beam", path.to_str().unwrap()])
    };
    let (rc, out, e) =
        plan("\"tip_spring.k3\", \"mode2.zeta\", \"input_gain\", \"sensor_gain:tip\"");
    assert_eq!(rc, 0, "{e}");
    assert!(
        out.contains(
            "input_gain, sensor_gain:tip (nominal 6.0000e9, 1.0000e-2, 1.0000e0, 1.0000e0)"
        ),
        "{out}"
    );
    let ranking = std::fs::read_to_string(dir.join("report/ranking.csv")).unwrap();
    let head: Vec<&str> = ranking.lines().next().unwrap().split(',').collect();
    let col = head
        .iter()
        .position(|h| h.contains("sensor_gain:tip"))
        .unwrap_or_else(|| panic!("{head:?}"));
    let sensors = head.iter().position(|h| *h == "sensors").unwrap();
    // With the tip alone the three cannot be told apart: a cubic driven by g F answers
    // `g Y(F; g² k3)`, so the tip's reading `s g Y(F; g² k3)` fixes only `s g` and `g² k3`.
    // The mid sensor (gain exact) fixes g.
    let mut seen = [0; 3];
    for line in ranking.lines().skip(1) {
        let c: Vec<&str> = line.split(',').collect();
        let sd: f64 = c[col].parse().unwrap();
        let set: Vec<&str> = c[sensors].split('+').collect();
        match (set.contains(&"tip"), set.contains(&"mid")) {
            (true, true) => {
                assert!(sd.is_finite() && sd > 0.0, "{line}");
                seen[0] += 1;
            }
            (true, false) => {
                assert!(sd.is_infinite(), "{line}");
                seen[1] += 1;
            }
            _ => {
                assert!(sd.is_infinite(), "{line}");
                seen[2] += 1;
            }
        }
    }
    assert!(seen.iter().all(|&n| n > 0), "{seen:?}");
    let (rc, _, e) = plan("\"tip_spring.k3\", \"sensor_gain:nope\"");
    assert_ne!(rc, 0);
    assert!(e.contains("sensor_gain:nope"), "{e}");
    std::fs::remove_dir_all(&*dir).unwrap();
}
