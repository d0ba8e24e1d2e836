//! The C ABI from other languages: `tests/c/check.c` compiled against `include/nlsim.h` and
//! linked with `libnlsim_c` (shared, then static), and `tests/python/check.py` through
//! ctypes. Both print `key value...` lines; every number is compared here with the same
//! computation through the Rust API (`nlsim::prelude`), and every deliberately bad call must
//! have returned its error code with a message.
//!
//! Tolerance: the callers build the same matrices and force samples, so the arithmetic is the
//! same except the force samples' `sin`, which the C library and Rust may round differently
//! by an ulp; the response of this damped 2-DOF system moves by a like amount. Values are
//! compared to 1e-12 of the largest magnitude in their line.

use nlsim::calib::{
    CalibrationConfig, Channel, FrfObjective, Noise, ObjectiveConfig, ParamSpec, Step, Sweep,
    SweepDirection, TestData, calibrate,
};
use nlsim::hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, continuation};
use nlsim::kernel::{
    Coupling, Damping, DofMap, Law, Model, NonlinearElement, Param, Parameterized, Quantity,
    SparseSym,
};
use nlsim::reduction::{ModalSystem, ReductionConfig, reduce};
use nlsim::sim::{FohConfig, LoadCase, Plant, Signal, Simulator};
use std::collections::BTreeMap;
use std::f64::consts::PI;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::Arc;

type Lines = BTreeMap<String, Vec<String>>;

/// The directory cargo put `libnlsim_c.{so,a}` in: the test binary's own (`target/*/deps`).
fn lib_dir() -> PathBuf {
    let exe = std::env::current_exe().expect("test binary path");
    let dir = exe.parent().expect("deps directory").to_path_buf();
    assert!(
        dir.join("libnlsim_c.so").exists(),
        "{} has no libnlsim_c.so (cargo builds it with the crate's tests)",
        dir.display()
    );
    dir
}

fn examples() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../examples")
}

#[path = "../../tests/common/scratch.rs"]
mod scratch_dir;
use scratch_dir::Scratch;

fn scratch(name: &str) -> Scratch {
    Scratch::new(&format!("capi-{name}"))
}

/// Runs `cmd`, requires success, and parses its output into keyed lines.
fn run(mut cmd: Command, what: &str) -> Lines {
    let out = cmd
        .output()
        .unwrap_or_else(|e| panic!("{what}: cannot start: {e}"));
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "{what} failed ({}):\n{stdout}\n{}",
        out.status,
        String::from_utf8_lossy(&out.stderr)
    );
    let mut lines = Lines::new();
    for l in stdout.lines() {
        let mut words = l.split_whitespace().map(String::from);
        if let Some(key) = words.next() {
            let key = if key == "bad" || key == "model_param" {
                format!("{key} {}", words.next().unwrap_or_default())
            } else {
                key
            };
            lines.insert(key, words.collect());
        }
    }
    lines
}

/// Compiles the C program against the header and links it with the library.
fn build_c(dir: &Path, shared: bool) -> PathBuf {
    let capi = Path::new(env!("CARGO_MANIFEST_DIR"));
    let exe = dir.join(if shared {
        "check_shared"
    } else {
        "check_static"
    });
    let mut cc = Command::new("cc");
    cc.args([
        "-std=c11",
        "-D_DEFAULT_SOURCE",
        "-Wall",
        "-Wextra",
        "-Werror",
        "-O1",
    ])
    .arg(format!("-I{}", capi.join("include").display()))
    .arg(format!("-DNLSIM_EXAMPLES=\"{}\"", examples().display()))
    .arg(capi.join("tests/c/check.c"))
    .arg("-o")
    .arg(&exe);
    let lib = lib_dir();
    if shared {
        // DT_RPATH (not RUNPATH): searched before LD_LIBRARY_PATH, which cargo points at
        // target/debug too, where an older uplifted libnlsim_c.so may lie.
        cc.arg(format!("-L{}", lib.display()))
            .arg("-lnlsim_c")
            .arg(format!("-Wl,-rpath,{}", lib.display()))
            .arg("-Wl,--disable-new-dtags");
    } else {
        // The static archive needs what rustc reports as its native libraries
        // (`--print native-static-libs`), HDF5 found as the build found it.
        cc.arg(lib.join("libnlsim_c.a"));
        let hdf5 = Command::new("pkg-config")
            .args(["--libs", "hdf5"])
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).trim().to_string())
            .unwrap_or_else(|| "-lhdf5_serial".into());
        cc.args(hdf5.split_whitespace());
        cc.args(["-lgcc_s", "-lutil", "-lrt", "-lpthread", "-ldl"]);
    }
    cc.arg("-lm");
    let out = cc
        .output()
        .expect("cc (gcc is installed by scripts/ensure-deps.sh)");
    assert!(
        out.status.success(),
        "compiling check.c failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

/// The reference: the same computations through the Rust API.
fn reference() -> BTreeMap<&'static str, Vec<f64>> {
    let mut r = BTreeMap::new();
    let k = SparseSym::from_dense_rows("stiffness", &[vec![2e4, -1e4], vec![-1e4, 1e4]]).unwrap();
    let m = SparseSym::diagonal("mass", &[1.0, 1.0]).unwrap();
    let model = Model::builder("chain", DofMap::scalar(2), m, k)
        .damping(Damping::Rayleigh {
            alpha: 2.0,
            beta: 0.0,
        })
        .element(NonlinearElement::new("tip", Law::Cubic { k3: 1e9 }, Coupling::single(1)).unwrap())
        .excitation("shaker", "2:u", 1.0)
        .sensor("tip_d", "2:u", Quantity::Displacement)
        .build()
        .unwrap();
    r.insert("model_info", vec![2.0, 1.0, 1.0, 1.0, 1.0]);
    let mut cfg = ReductionConfig::lowest(2);
    cfg.residual_flexibility = false;
    let reduced = reduce(&model, &cfg).unwrap();
    r.insert("frequencies", reduced.modes.frequencies_hz());

    let dt = 1e-4;
    let force: Vec<f64> = (0..=2000)
        .map(|i| (2.0 * PI * 10.0 * i as f64 * dt).sin())
        .collect();
    let plant = Plant::from_model(&model, &ModalSystem::new(&reduced).unwrap()).unwrap();
    let history = Simulator::new(&plant, &FohConfig::new(dt))
        .unwrap()
        .run(
            &LoadCase::new(
                "capi",
                vec![Signal::Sampled {
                    rate_hz: 1.0 / dt,
                    values: force,
                }],
            ),
            2000,
        )
        .unwrap();
    let tip = &history.output("tip_d").unwrap().values;
    r.insert("run_info", vec![0.0, 2001.0]);
    r.insert("simulate", vec![tip[500], tip[1000], tip[1500], tip[2000]]);

    let mut sys = HbSystem::from_model(
        &model,
        &reduced,
        HarmonicSet::new(5, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    r.insert(
        "hb_info",
        vec![
            5.0,
            1.0,
            1.0,
            sys.n_unknowns() as f64,
            sys.parameters().len() as f64,
        ],
    );
    let flat = |m: &faer::Mat<faer::c64>| -> Vec<f64> {
        (0..m.nrows())
            .flat_map(|i| (0..m.ncols()).flat_map(move |j| [m[(i, j)].re, m[(i, j)].im]))
            .collect()
    };
    let w = 2.0 * PI * 12.0;
    let (x, rep) = sys.solve_from_rest(w, 1.0).unwrap();
    let stable = sys.stability(&x, w).unwrap().stable;
    r.insert("point_info", vec![0.0, f64::from(u8::from(stable))]);
    assert!(rep.converged());
    r.insert("point_12hz", flat(&sys.sensor_response(&x, w, 1.0)));
    let params = [Param::element("tip", "k3"), "mode1.zeta".parse().unwrap()];
    let sens = sys.sensitivities(&x, w, 1.0, &params).unwrap();
    r.insert("sens_12hz", sens.iter().flat_map(|s| flat(&s.dy)).collect());

    let mut ccfg = ContinuationConfig::frequency(8.0, 20.0);
    ccfg.fixed = 1.0;
    let rep = continuation(&sys, &ccfg, None).unwrap();
    let pts = &rep.branch.points;
    let last = pts.last().unwrap();
    r.insert(
        "frf_info",
        vec![0.0, pts.len() as f64, rep.branch.folds().len() as f64],
    );
    r.insert(
        "frf_counts",
        vec![
            pts.iter().filter(|p| p.stable() == Some(true)).count() as f64,
            rep.branch.folds().len() as f64,
        ],
    );
    r.insert(
        "frf_ends",
        vec![pts[0].omega / (2.0 * PI), last.omega / (2.0 * PI)],
    );
    r.insert(
        "frf_last",
        flat(&sys.sensor_response(&last.x, last.omega, last.scale)),
    );
    r.insert(
        "frf_sens_last",
        sys.sensitivities(&last.x, last.omega, last.scale, &params)
            .unwrap()
            .iter()
            .flat_map(|s| flat(&s.dy))
            .collect(),
    );
    r.insert("k3", vec![sys.param(&params[0]).unwrap()]);
    let mut stiffer = sys.clone();
    stiffer.set_param(&params[0], 2e9).unwrap();
    let (x2, _) = stiffer.solve_from_rest(w, 1.0).unwrap();
    r.insert(
        "point_12hz_k3x2",
        flat(&stiffer.sensor_response(&x2, w, 1.0)),
    );

    // Calibration of k3 from the system's own fundamental, started at 3e9.
    let freqs = [5.0, 6.5, 8.0, 9.0, 17.0, 18.5, 20.0];
    let steps = freqs
        .iter()
        .map(|&f| {
            let w = 2.0 * PI * f;
            let (x, _) = sys.solve_from_rest(w, 1.0).unwrap();
            let y = sys.sensor_response(&x, w, 1.0);
            Step {
                frequency_hz: f,
                force: vec![faer::c64::new(1.0, 0.0)],
                response: faer::Mat::from_fn(1, 1, |_, _| y[(0, 1)]),
                sigma: faer::Mat::new(),
            }
        })
        .collect();
    let data = TestData {
        input: "shaker".into(),
        drive: nlsim::calib::Drive::Force,
        channels: vec![Channel {
            name: "tip_d".into(),
            quantity: Quantity::Displacement,
            noise: Noise::relative(0.01),
        }],
        harmonics: 1,
        sweeps: vec![Sweep {
            label: "up".into(),
            direction: SweepDirection::Up,
            steps,
        }],
    };
    sys.set_param(&params[0], 3e9).unwrap();
    let data_force = data.clone();
    let objective = FrfObjective::new(
        &sys,
        Arc::new(data),
        vec![ParamSpec::new(params[0].clone(), 1e8, 1e10)],
        ObjectiveConfig::default(),
    )
    .unwrap();
    let config = CalibrationConfig {
        lhs_samples: 8,
        starts: 1,
        folds: 0,
        ..CalibrationConfig::default()
    };
    let cal = calibrate(&objective, &config).unwrap();
    assert!(
        (cal.estimate[0] / 1e9 - 1.0).abs() < 1e-6,
        "noise-free data give k3 back: {}",
        cal.estimate[0]
    );
    r.insert(
        "calibration",
        vec![cal.estimate[0], cal.cramer_rao.std[0], 0.0],
    );

    // The same recorded as a voltage (0.4 V for 1 N), the input gain calibrated beside k3,
    // each step weighed by its own standard deviations (1 % of the response per part).
    let mut volt = data_force.clone();
    volt.drive = nlsim::calib::Drive::Voltage;
    for st in &mut volt.sweeps[0].steps {
        st.force = vec![faer::c64::new(0.4, 0.0)];
        let s = 0.01 * st.response[(0, 0)].norm();
        st.sigma = faer::Mat::from_fn(1, 1, |_, _| faer::c64::new(s, s));
    }
    let objective = FrfObjective::new(
        &sys,
        Arc::new(volt),
        vec![
            ParamSpec::new(params[0].clone(), 1e8, 1e10),
            ParamSpec::new(nlsim::kernel::Param::InputGain, 0.5, 10.0),
        ],
        ObjectiveConfig::default(),
    )
    .unwrap();
    let gains = calibrate(&objective, &config).unwrap();
    assert!(
        (gains.estimate[0] / 1e9 - 1.0).abs() < 1e-6
            && (gains.estimate[1] / 2.5 - 1.0).abs() < 1e-6,
        "noise-free data give k3 and the input gain back: {:?}",
        gains.estimate
    );
    r.insert(
        "gain_calibration",
        vec![
            gains.estimate[0],
            gains.estimate[1],
            gains.cramer_rao.std[0],
            gains.cramer_rao.std[1],
            gains.cramer_rao.reduced_chi2.sqrt(),
            f64::from(u8::from(gains.cramer_rao.misfit_warning().is_some())),
        ],
    );

    let file = nlsim::load_model(examples().join("models/two_dof.toml").to_str().unwrap())
        .unwrap()
        .model;
    r.insert(
        "file_model",
        vec![
            file.n_dofs() as f64,
            file.elements().len() as f64,
            file.excitation().len() as f64,
            file.sensors().len() as f64,
            file.parameters().len() as f64,
        ],
    );
    r.insert("live_handles", vec![0.0]);
    r.insert("failures", vec![0.0]);
    r
}

/// Every numeric line of the reference that `lines` holds agrees; `required` must be there.
fn compare(
    lines: &Lines,
    reference: &BTreeMap<&'static str, Vec<f64>>,
    required: &[&str],
    who: &str,
) {
    for key in required {
        assert!(lines.contains_key(*key), "{who} printed no '{key}' line");
    }
    for (key, want) in reference {
        let Some(got) = lines.get(*key) else { continue };
        let got: Vec<f64> = got
            .iter()
            .map(|v| {
                v.parse()
                    .unwrap_or_else(|_| panic!("{who} {key}: '{v}' is not a number"))
            })
            .collect();
        assert_eq!(got.len(), want.len(), "{who} {key}: {got:?} vs {want:?}");
        let scale = want.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            assert!(
                (g - w).abs() <= 1e-12 * scale,
                "{who} {key}[{i}]: {g:e} vs the Rust API's {w:e}"
            );
        }
    }
}

const BAD_CALLS: &[(&str, i32)] = &[
    ("null_out", -1),
    ("unknown_dof", -4),
    ("bad_law", -4),
    ("coupled_dofs", -4),
    ("unknown_param", -4),
    ("wrong_size", -2),
    ("null_buffer", -1),
    ("wrong_kind", -3),
    ("missing_file", -6),
    ("use_after_free", -3),
    ("double_free", -3),
];

fn check_bad_calls(lines: &Lines, who: &str) {
    for (name, code) in BAD_CALLS {
        let line = lines
            .get(&format!("bad {name}"))
            .unwrap_or_else(|| panic!("{who} made no bad call '{name}'"));
        assert_eq!(line[0], code.to_string(), "{who} bad call {name}: {line:?}");
        assert!(line.len() > 1, "{who} bad call {name} left no message");
    }
}

#[test]
fn a_c_program_linked_shared_and_static_agrees_with_the_rust_api() {
    let reference = reference();
    let dir = scratch("c");
    let required = [
        "version",
        "frequencies",
        "simulate",
        "point_12hz",
        "sens_12hz",
        "frf_info",
        "frf_last",
        "frf_sens_last",
        "point_12hz_k3x2",
        "calibration",
        "gain_calibration",
        "file_model",
        "live_handles",
        "failures",
    ];
    for shared in [true, false] {
        let who = if shared { "C (shared)" } else { "C (static)" };
        let exe = build_c(&dir, shared);
        let lines = run(Command::new(&exe), who);
        assert_eq!(lines["version"], [env!("CARGO_PKG_VERSION")]);
        assert_eq!(lines["model_param 0"], ["tip.k3"]);
        compare(&lines, &reference, &required, who);
        check_bad_calls(&lines, who);
        for extra in [
            "sigma_size",
            "bad_record",
            "asymmetric",
            "index_outside",
            "handle_zero",
            "forged_handle",
        ] {
            assert!(
                lines.contains_key(&format!("bad {extra}")),
                "{who}: bad {extra}"
            );
        }
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn a_python_ctypes_script_agrees_with_the_rust_api() {
    let reference = reference();
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/python/check.py");
    let mut cmd = Command::new("python3");
    cmd.arg(script)
        .arg(lib_dir().join("libnlsim_c.so"))
        .arg(examples());
    let lines = run(cmd, "python3 check.py");
    let required = [
        "frequencies",
        "simulate",
        "point_12hz",
        "sens_12hz",
        "frf_info",
        "frf_last",
        "point_12hz_k3x2",
        "file_model",
        "live_handles",
    ];
    compare(&lines, &reference, &required, "Python");
    check_bad_calls(&lines, "Python");
}
