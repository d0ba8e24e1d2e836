//! `nlsim test MODEL TEST` as library calls: a virtual stepped-sine test through an
//! electrodynamic shaker model (thesis §4.4, Fig. 11), voltage-driven or with the off-line
//! force controller, written as test data in the format `nlsim calibrate` reads.
//!
//! A test file (`docs/planning.md`):
//!
//! ```toml
//! drive = "tip"                # the model's excitation the shaker drives (or drive_dof)
//! harmonics = 3                # measured harmonics (and the harmonic balance's H)
//! seed = 1                     # measurement noise
//! noise = { relative = 0.02 }  # response noise
//! out = "virtual_test.csv"     # .csv or .h5
//! channels = ["tip", "n7"]     # the sensors recorded [default: every sensor]
//!
//! [[sensor]]                   # sensors beside the model's
//! name = "n7"
//! dof = "7:uz"
//! quantity = "acceleration"
//!
//! [shaker]                     # any of the fields of nlsim_calib::Shaker
//! armature_mass = 0.03
//!
//! [control]                    # the off-line force controller
//! enabled = true
//! tolerance = 0.01
//!
//! [[sweep]]
//! label = "0.2 N up"
//! from = 30.0
//! to = 36.0
//! steps = 21
//! force = 0.2
//! ```
//!
//! The request and its test file are in `request.rs`, the run in `run.rs`, the summary and the
//! report folder in `report.rs`.

#[cfg(feature = "io")]
pub mod report;
pub mod request;
pub mod run;

#[cfg(feature = "io")]
pub use report::*;
pub use request::*;
pub use run::*;

/// `nlsim test MODEL TEST`: the virtual test with a progress line per sweep, its summary,
/// the test data (written by the run) and the report folder.
#[cfg(feature = "io")]
pub fn execute(req: &TestRequest, console: &crate::present::console::Console) -> crate::Result<()> {
    // The request's own errors first (run_test checks it again, as a library entry).
    req.check()?;
    crate::formats::files::check_outputs(
        &[
            Some(std::path::Path::new(&req.model)),
            req.source.as_deref(),
        ],
        &[
            Some(req.out.as_path()),
            req.raw.as_ref().map(|r| r.out.as_path()),
            req.raw
                .as_ref()
                .map(|r| request::raw_steps_path(&r.out))
                .as_deref(),
        ],
        &[req.report.as_deref()],
    )?;
    let mut progress = console.eta("test");
    let run = run_test(req, &mut progress)?;
    progress(req.sweeps.len(), req.sweeps.len());
    for line in run.summary() {
        console.say(&line);
    }
    if let Some(dir) = &req.report {
        let files = crate::formats::guard::write_folder(dir, |d| write_test_report(d, &run))?;
        console.say(&format!(
            "report: {} files in {} (summary.txt, control.csv, force and response plots)",
            files.len(),
            dir.display()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nlsim_calib::Shaker;
    use std::path::Path;

    const TEST: &str = r#"
drive = "tip"
seed = 4
noise = { relative = 0.01 }

[shaker]
armature_mass = 0.05

[control]
tolerance = 0.02

[[sweep]]
from = 30.0
to = 36.0
steps = 7
force = 0.1
"#;

    #[test]
    fn a_test_file_reads_into_its_request() {
        let r = TestRequest::parse(TEST, Path::new("/t/test.toml"), "ecl_beam").unwrap();
        assert_eq!(r.drive.as_deref(), Some("tip"));
        assert_eq!(r.seed, 4);
        assert_eq!(r.noise.relative, 0.01);
        assert_eq!(r.shaker.armature_mass, 0.05);
        assert_eq!(r.shaker.resistance, Shaker::default().resistance);
        assert_eq!(r.control.tolerance, 0.02);
        assert_eq!(r.sweeps[0].frequencies_hz.len(), 7);
        assert_eq!(r.out, Path::new("/t/virtual_test.csv"));
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let cases = [
            (
                TEST.replace("force = 0.1", "force = 0.1\nspeed = 2"),
                "speed",
            ),
            (TEST.replace("force = 0.1", "force = -1.0"), "sweep"),
            (
                TEST.replace("armature_mass = 0.05", "armature_mass = 0.0"),
                "shaker",
            ),
            (
                TEST.replace("tolerance = 0.02", "tolerance = 0.0"),
                "control",
            ),
            (TEST.replace("seed = 4", "seed = 4\nout = \"x.txt\""), "out"),
        ];
        for (text, key) in cases {
            let e = TestRequest::parse(&text, Path::new("test.toml"), "m").unwrap_err();
            let msg = e.to_string();
            let line = text
                .lines()
                .position(|l| {
                    let l = l.trim_start();
                    l.starts_with(key)
                        || l.starts_with(&format!("[{key}]"))
                        || l.starts_with(&format!("[[{key}]]"))
                })
                .unwrap()
                + 1;
            assert!(
                msg.starts_with(&format!("test.toml:{line}:")) && msg.contains(key),
                "{key}: {msg}"
            );
        }
    }
}
