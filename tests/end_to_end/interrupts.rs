//! Interrupts keep what was computed (issue 72 part 3): Ctrl-C (SIGINT) at seeded points of
//! a calibration stops it at the next safe point, keeps the candidates evaluated so far in a
//! file `--candidates` resumes from — to the estimates of an uninterrupted run, bit for bit —
//! and exits 130; `kill -9` leaves the older outputs or complete new ones; a command without
//! safe points stops at once and leaves no temporary behind.

use super::*;

/// A delay in `[lo, hi)` of `whole` seconds from the splitmix64 sequence of `state`.
fn seeded_delay(state: &mut u64, whole: f64, lo: f64, hi: f64) -> std::time::Duration {
    *state = state.wrapping_add(0x9e37_79b9_7f4a_7c15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    let frac = ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64;
    std::time::Duration::from_secs_f64(whole * (lo + (hi - lo) * frac))
}

/// Starts the binary with `args`, sends `signal` (`INT` or `KILL`) after `delay`,
/// and returns its exit code (`None` when a signal ended it before nlsim could answer) and
/// its standard error.
fn signalled(args: &[&str], delay: std::time::Duration, signal: &str) -> (Option<i32>, String) {
    let child = Command::new(env!("CARGO_BIN_EXE_nlsim"))
        .args(args)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    std::thread::sleep(delay);
    let number = match signal {
        "INT" => libc::SIGINT,
        "KILL" => libc::SIGKILL,
        other => panic!("no signal {other}"),
    };
    // SAFETY: a signal to our own child, which has not been waited for (its pid is ours).
    #[allow(unsafe_code)]
    unsafe {
        libc::kill(child.id() as libc::pid_t, number);
    }
    let out = child.wait_with_output().unwrap();
    (
        out.status.code(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Temporary files, staging folders and lock files in `dir`.
fn leftovers(dir: &Path) -> Vec<String> {
    std::fs::read_dir(dir)
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .filter(|n| n.contains(".tmp-") || n.ends_with(".lock"))
        .collect()
}

/// A stepped-sine test of the ECL beam and a calibration of its cubic spring and damping
/// on it that runs about half a second: long enough for seeded signals to land in the
/// candidates, the optimisations, the folds and the report.
fn calibration_case(dir: &Path) -> Vec<String> {
    std::fs::write(
        dir.join("t.toml"),
        "harmonics = 3\nmodes = 4\nseed = 2\n\n\
         [[sweep]]\nlabel = \"low\"\nfrom = 21.5\nto = 25.5\nsteps = 17\nforce = 0.05\n\n\
         [[sweep]]\nlabel = \"high\"\nfrom = 21.5\nto = 26.5\nsteps = 21\nforce = 0.2\n",
    )
    .unwrap();
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let (rc, _, e) = nlsim(&["test", "ecl_beam", &d("t.toml"), "--out", &d("d.csv"), "-q"]);
    assert_eq!(rc, 0, "{e}");
    [
        "calibrate",
        "ecl_beam",
        &d("d.csv"),
        "--param",
        "tip_spring.k3=6e7:6e11",
        "--param",
        "mode2.zeta=0.001:0.1",
        "--harmonics",
        "7",
        "--modes",
        "8",
        "--lhs",
        "200",
        "--folds",
        "4",
        "-q",
        "--report",
        &d("rep"),
    ]
    .map(String::from)
    .to_vec()
}

/// Ctrl-C at 20 seeded points of `calibrate --out --report`: exit 130 with one line naming
/// the candidates file (or 0 when the run had ended), the older report folder whole, no
/// temporary left; `--candidates` on the kept file ends in the estimates of the
/// uninterrupted run, bit for bit.
#[test]
fn ctrl_c_keeps_the_candidates_and_the_resumed_run_matches_bit_for_bit() {
    let dir = scratch("interrupt-calibrate");
    let case = calibration_case(&dir);
    let with = |extra: &[&str]| -> Vec<String> {
        let mut a = case.clone();
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let reference = dir.join("ref.csv");
    let args = with(&["--out", reference.to_str().unwrap()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let t = std::time::Instant::now();
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    let whole = t.elapsed().as_secs_f64();
    let expected = std::fs::read(&reference).unwrap();
    let out = dir.join("b.csv");
    let kept = dir.join("rep.interrupted.h5");
    let args = with(&["--out", out.to_str().unwrap()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let resume = with(&[
        "--out",
        out.to_str().unwrap(),
        "--candidates",
        kept.to_str().unwrap(),
    ]);
    let resume: Vec<&str> = resume.iter().map(String::as_str).collect();
    let mut state = 0x1e7e_2272_u64;
    let mut interrupted = 0;
    for k in 0..20 {
        let _ = std::fs::remove_file(&out);
        let _ = std::fs::remove_file(&kept);
        let delay = seeded_delay(&mut state, whole, 0.05, 0.8);
        let (rc, err) = signalled(&args, delay, "INT");
        let why = format!("Ctrl-C {k} at {delay:?} of {whole:.2} s");
        assert!(
            rep_complete(&dir.join("rep")),
            "{why}: the report folder is not whole"
        );
        assert!(leftovers(&dir).is_empty(), "{why}: {:?}", leftovers(&dir));
        match rc {
            Some(0) => assert_eq!(std::fs::read(&out).unwrap(), expected, "{why}"),
            Some(130) if kept.exists() => {
                interrupted += 1;
                assert_eq!(err.lines().count(), 1, "{why}: {err}");
                assert!(err.contains("--candidates"), "{why}: {err}");
                assert!(!out.exists(), "{why}: an estimates file from a stopped run");
                let (rc, _, e) = nlsim(&resume);
                assert_eq!(rc, 0, "{why}: {e}");
                assert_eq!(
                    std::fs::read(&out).unwrap(),
                    expected,
                    "{why}: the resumed run differs"
                );
                assert!(leftovers(&dir).is_empty(), "{why}: {:?}", leftovers(&dir));
            }
            // Stopped in the report phase: at once, nothing kept, the older folder whole.
            Some(130) => assert!(err.contains("stopped at once"), "{why}: {err}"),
            other => panic!("{why}: exit {other:?}: {err}"),
        }
    }
    assert!(
        interrupted >= 8,
        "only {interrupted} of 20 stopped at a safe point"
    );
}

/// The runs of a race that wrote their output (exit 0); every other run must have been
/// refused in one line because the other held the lock (exit 2), counted in `refused`.
fn settle_race(outs: &[std::process::Output], why: &str, refused: &mut usize) -> usize {
    let mut won = 0;
    for o in outs {
        let err = String::from_utf8_lossy(&o.stderr);
        match o.status.code() {
            Some(0) => won += 1,
            Some(2) => {
                assert_eq!(err.lines().count(), 1, "{why}: {err}");
                assert!(
                    err.contains("another nlsim run is writing it"),
                    "{why}: {err}"
                );
                *refused += 1;
            }
            other => panic!("{why}: exit {other:?}: {err}"),
        }
    }
    won
}

/// Whether `rep` is a complete report folder (its manifest and a whole page).
fn rep_complete(rep: &Path) -> bool {
    rep.join(".nlsim-report").is_file()
        && std::fs::read_to_string(rep.join("index.html"))
            .is_ok_and(|p| p.trim_end().ends_with("</html>"))
}

/// `kill -9` at 20 seeded points of `calibrate --out --report`: the estimates file is the
/// older one or the new complete one, the report folder whole, and the next run leaves no
/// temporary file or staging folder.
#[test]
fn a_killed_calibration_leaves_older_outputs_or_complete_new_ones() {
    let dir = scratch("interrupt-kill-calibrate");
    let mut args = calibration_case(&dir);
    let out = dir.join("b.csv");
    args.extend(["--out".to_string(), out.to_str().unwrap().to_string()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let t = std::time::Instant::now();
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    let whole = t.elapsed().as_secs_f64();
    let expected = std::fs::read(&out).unwrap();
    let mut state = 0x0dea_d0c5_u64;
    for k in 0..20 {
        let delay = seeded_delay(&mut state, whole, 0.0, 1.0);
        let _ = signalled(&args, delay, "KILL");
        let why = format!("kill -9 {k} at {delay:?} of {whole:.2} s");
        assert_eq!(std::fs::read(&out).unwrap(), expected, "{why}");
        assert!(rep_complete(&dir.join("rep")), "{why}");
    }
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    assert_eq!(std::fs::read(&out).unwrap(), expected);
    assert!(leftovers(&dir).is_empty(), "{:?}", leftovers(&dir));
}

/// `modes` of the refined bracket with a result file `out` and a report `rep`: long enough
/// (about 0.2 s) for signals to land in the load, the solve, the result file and the report.
fn modes_args(out: &Path, rep: &Path) -> Vec<String> {
    [
        "modes",
        "bracket:refinement=2",
        "--count",
        "6",
        "-q",
        "--out",
        out.to_str().unwrap(),
        "--report",
        rep.to_str().unwrap(),
    ]
    .map(String::from)
    .to_vec()
}

/// `kill -9` at seeded points of a run that writes a result file and a report folder: the
/// final names hold the older complete outputs or the new complete ones, never a partial
/// file or a mixed folder, and the next run leaves no temporary file or staging folder.
#[test]
fn a_killed_run_leaves_older_outputs_or_complete_new_ones() {
    let dir = scratch("outputs-kill");
    let (rep, out) = (dir.join("rep"), dir.join("m.h5"));
    let args = modes_args(&out, &rep);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let t = std::time::Instant::now();
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    let whole = t.elapsed().as_secs_f64();
    let complete = |why: &str| {
        assert!(rep_complete(&rep), "{why}: no manifest or a partial page");
        for f in [rep.join("report.h5"), out.clone()] {
            let f = hdf5_metno::File::open(&f).unwrap_or_else(|e| panic!("{why}: {e}"));
            assert!(f.attr("nlsim_version").is_ok(), "{why}");
        }
    };
    complete("the first run");
    let mut state = 0x5eed_u64;
    for k in 0..20 {
        let delay = seeded_delay(&mut state, whole, 0.0, 1.0);
        let _ = signalled(&args, delay, "KILL");
        complete(&format!("kill {k} at {delay:?}"));
    }
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    complete("the run after the kills");
    assert!(
        leftovers(&dir).is_empty(),
        "left behind: {:?}",
        leftovers(&dir)
    );
}

/// Ctrl-C at 10 seeded points of a command without safe points (`modes` with a result file
/// and a report): it stops at once with exit 130 and one line, removes its temporaries,
/// staging folder and lock itself (no later run needed), and the final names keep the
/// older complete outputs.
#[test]
fn ctrl_c_stops_a_command_without_safe_points_at_once_and_leaves_nothing() {
    let dir = scratch("interrupt-modes");
    let (rep, out) = (dir.join("rep"), dir.join("m.h5"));
    let args = modes_args(&out, &rep);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let t = std::time::Instant::now();
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    let whole = t.elapsed().as_secs_f64();
    let mut state = 0x0000_0c7c_u64;
    let mut stopped = 0;
    for k in 0..10 {
        let delay = seeded_delay(&mut state, whole, 0.05, 0.5);
        let (rc, err) = signalled(&args, delay, "INT");
        let why = format!("Ctrl-C {k} at {delay:?} of {whole:.2} s");
        match rc {
            Some(0) => {}
            Some(130) => {
                stopped += 1;
                assert_eq!(err.lines().count(), 1, "{why}: {err}");
                assert!(err.contains("stopped at once"), "{why}: {err}");
            }
            other => panic!("{why}: exit {other:?}: {err}"),
        }
        assert!(leftovers(&dir).is_empty(), "{why}: {:?}", leftovers(&dir));
        assert!(rep_complete(&rep), "{why}");
        let f = hdf5_metno::File::open(&out).unwrap_or_else(|e| panic!("{why}: {e}"));
        assert!(f.attr("nlsim_version").is_ok(), "{why}");
    }
    assert!(
        stopped >= 3,
        "only {stopped} of 10 signals landed in the run"
    );
}

/// Two `calibrate --report rep` runs started together, 10 times (seeds 1 and 2): one
/// writes the folder whole, the other is refused in one line (exit 2) or runs after it;
/// the folder's manifest, calibration file and HDF5 always come from one run.
#[test]
fn two_runs_on_one_report_folder_never_mix_it() {
    let dir = scratch("interrupt-race");
    let case = calibration_case(&dir);
    let rep = dir.join("rep");
    let mut refused = 0;
    for k in 0..10 {
        let children: Vec<_> = [1, 2]
            .map(|seed| {
                let mut a = case.clone();
                a.extend(["--seed".into(), seed.to_string()]);
                Command::new(env!("CARGO_BIN_EXE_nlsim"))
                    .args(&a)
                    .stdout(std::process::Stdio::null())
                    .stderr(std::process::Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .into_iter()
            .collect();
        let outs: Vec<_> = children
            .into_iter()
            .map(|c| c.wait_with_output().unwrap())
            .collect();
        let why = format!("try {k}");
        let won = settle_race(&outs, &why, &mut refused);
        assert!(won >= 1, "{why}: neither run wrote the folder");
        assert!(rep_complete(&rep), "{why}");
        let manifest = std::fs::read_to_string(rep.join(".nlsim-report")).unwrap();
        let seed = if manifest.trim_end().ends_with("--seed 1") {
            1
        } else {
            2
        };
        let toml = std::fs::read_to_string(rep.join("calibration.toml")).unwrap();
        assert!(
            toml.contains(&format!("\nseed = {seed}\n")),
            "{why}: a mixed folder"
        );
        let h5 = hdf5_metno::File::open(rep.join("report.h5")).unwrap();
        let line: hdf5_metno::types::VarLenUnicode =
            h5.attr("command_line").unwrap().read_scalar().unwrap();
        assert!(
            line.as_str().ends_with(&format!("--seed {seed}")),
            "{why}: {line}"
        );
        assert!(leftovers(&dir).is_empty(), "{why}: {:?}", leftovers(&dir));
    }
    // Started together, the runs overlapped at least once (else the test tried nothing).
    assert!(refused >= 1, "no try had both runs at once");
}

/// The same batch shard run twice at once, 10 times: one run writes it, the other is
/// refused in one line (exit 2) or finds it complete; the shard is never damaged (the merge
/// of the last try equals a single run's).
#[test]
fn two_runs_of_one_shard_never_damage_it() {
    let dir = scratch("interrupt-shard-race");
    let jobs = dir.join("jobs.toml");
    std::fs::write(
        &jobs,
        "name = \"race\"\ncommand = \"simulate\"\nmodel = \"ecl_beam\"\nseed = 4\n\
         [simulate]\nduration = 2.0\nrate = 4000.0\nmodes = 8\n\
         [lhs]\nsamples = 16\nparams = [{ set = \"tip_spring.k3\", min = 1e9, max = 1e10 }]\n",
    )
    .unwrap();
    let j = jobs.to_str().unwrap();
    let shard = dir.join("race-results/shard-00000-of-00001.h5");
    let args = [
        "-q",
        "--threads",
        "1",
        "batch",
        j,
        "--task-count",
        "1",
        "--task-index",
        "0",
    ];
    let mut refused = 0;
    for k in 0..10 {
        let _ = std::fs::remove_file(&shard);
        let children: Vec<_> = (0..2)
            .map(|_| {
                Command::new(env!("CARGO_BIN_EXE_nlsim"))
                    .args(args)
                    .stdout(std::process::Stdio::null())
                    .stderr(std::process::Stdio::piped())
                    .spawn()
                    .unwrap()
            })
            .collect();
        let why = format!("try {k}");
        let outs: Vec<_> = children
            .into_iter()
            .map(|c| c.wait_with_output().unwrap())
            .collect();
        let won = settle_race(&outs, &why, &mut refused);
        assert!(won >= 1, "{why}: neither run wrote the shard");
        assert!(shard.is_file(), "{why}");
        assert!(leftovers(&dir.join("race-results")).is_empty(), "{why}");
    }
    assert!(refused >= 1, "no try had both runs at once");
    let (rc, _, e) = nlsim(&["batch", "merge", j]);
    assert_eq!(rc, 0, "{e}");
    let single = dir.join("single");
    for a in [
        vec!["-q", "batch", j, "--output", single.to_str().unwrap()],
        vec![
            "-q",
            "batch",
            "merge",
            j,
            "--output",
            single.to_str().unwrap(),
        ],
    ] {
        let (rc, _, e) = nlsim(&a);
        assert_eq!(rc, 0, "{e}");
    }
    h5check(&[
        "same",
        dir.join("race-results/merged.h5").to_str().unwrap(),
        single.join("merged.h5").to_str().unwrap(),
    ]);
}

/// A full disk (a 1 MiB tmpfs, mounted in a user namespace where the machine allows it):
/// `export`, `test --out --report` and `validate --report` rerun into it with nothing free
/// and with 12 KiB free fail with exit 1 naming the file, keep the older complete outputs
/// byte for byte, and leave no temporary file, staging folder or lock.
#[test]
fn a_full_disk_keeps_older_outputs_and_leaves_nothing_partial() {
    let ok = Command::new("unshare")
        .args(["--user", "--map-root-user", "--mount", "true"])
        .status()
        .is_ok_and(|s| s.success());
    if !ok {
        eprintln!("skipped: this machine cannot mount a tmpfs in a user namespace (unshare -rm)");
        return;
    }
    let dir = scratch("interrupt-full-disk");
    let mut case = calibration_case(&dir);
    // The calibration's report (outside the small file system) is what validate reads.
    case.retain(|a| a != "-q");
    let args: Vec<&str> = case.iter().map(String::as_str).collect();
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    let fs = dir.join("fs");
    std::fs::create_dir(&fs).unwrap();
    let script = r#"set -u
mount -t tmpfs -o size=1m tmpfs "$FS" || { echo "mount failed"; exit 0; }
cd "$FS"
state() { find . -path ./filler -prune -o -type f -print | sort | xargs sha256sum | sha256sum | cut -c1-16; }
left() { find . -name '*.tmp-*' -o -name '*.lock' | tr '\n' ' '; }
"$NLSIM" -q export ecl_beam ex || echo "setup export failed"
"$NLSIM" -q test ecl_beam "$DIR/t.toml" --out d.csv --report trep || echo "setup test failed"
"$NLSIM" -q validate "$DIR/rep/calibration.toml" --report vrep || echo "setup validate failed"
before=$(state)
for free in 0 12; do
  rm -f filler
  dd if=/dev/zero of=filler bs=1k 2>/dev/null
  if [ "$free" -gt 0 ]; then truncate -s -${free}k filler; fi
  "$NLSIM" -q export ecl_beam ex 2>"$DIR/err"; echo "export free=$free rc=$? err=$(head -c 300 "$DIR/err")"
  "$NLSIM" -q test ecl_beam "$DIR/t.toml" --out d.csv --report trep 2>"$DIR/err"; echo "test free=$free rc=$? err=$(head -c 300 "$DIR/err")"
  "$NLSIM" -q validate "$DIR/rep/calibration.toml" --report vrep 2>"$DIR/err"; echo "validate free=$free rc=$? err=$(head -c 300 "$DIR/err")"
  echo "state free=$free same=$([ "$before" = "$(state)" ] && echo yes || echo no) left=[$(left)]"
done
"#;
    let out = Command::new("unshare")
        .args(["--user", "--map-root-user", "--mount", "sh", "-c", script])
        .env("FS", &fs)
        .env("DIR", &*dir)
        .env("NLSIM", env!("CARGO_BIN_EXE_nlsim"))
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&out.stdout).into_owned();
    if said.contains("mount failed") {
        eprintln!("skipped: no tmpfs in a user namespace here\n{said}");
        return;
    }
    assert!(!said.contains("setup"), "{said}");
    let mut runs = 0;
    for line in said.lines() {
        if line.starts_with("state") {
            assert!(
                line.contains("same=yes") && line.contains("left=[]"),
                "{line}\n{said}"
            );
        } else {
            runs += 1;
            assert!(line.contains(" rc=1 "), "{line}\n{said}");
            assert!(line.contains("No space left on device"), "{line}");
            // The message names the file asked for, not a temporary or staging name.
            assert!(!line.contains(".tmp-"), "{line}");
        }
    }
    assert_eq!(runs, 6, "{said}");
}

/// kill -9 and Ctrl-C (alternating) at 20 seeded points each of `export`, `validate
/// --report --out`, `test --out --raw` and a batch shard: after every stop the final names
/// hold the older complete outputs (text files byte for byte as the first run wrote them,
/// HDF5 files whole, folders with their manifest) or none where there was none; Ctrl-C
/// exits 130 or 0; the run after the last stop leaves no temporary, staging folder or lock.
#[test]
fn killed_or_interrupted_writers_leave_older_outputs_whole() {
    let dir = scratch("interrupt-writers");
    let case = calibration_case(&dir);
    let args: Vec<&str> = case.iter().map(String::as_str).collect();
    let (rc, _, e) = nlsim(&args);
    assert_eq!(rc, 0, "{e}");
    std::fs::write(
        dir.join("rt.toml"),
        "harmonics = 3\nmodes = 4\nseed = 2\n\n\
         [[sweep]]\nlabel = \"low\"\nfrom = 22.0\nto = 25.0\nsteps = 4\nforce = 0.05\n",
    )
    .unwrap();
    std::fs::write(
        dir.join("jobs.toml"),
        "name = \"w\"\ncommand = \"simulate\"\nmodel = \"ecl_beam\"\nseed = 4\n\
         [simulate]\nduration = 2.0\nrate = 4000.0\nmodes = 8\n\
         [lhs]\nsamples = 16\nparams = [{ set = \"tip_spring.k3\", min = 1e9, max = 1e10 }]\n",
    )
    .unwrap();
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let shard = dir.join("w-results/shard-00000-of-00001.h5");
    // (what, arguments, outputs: files and folders; whether the output is removed before
    // each try, so that the run has to write it again)
    let cases: Vec<(&str, Vec<String>, Vec<PathBuf>, bool)> = vec![
        (
            "export",
            vec!["export".into(), "ecl_beam".into(), d("ex")],
            vec![dir.join("ex")],
            false,
        ),
        (
            "validate",
            [
                "validate",
                &d("rep/calibration.toml"),
                "--report",
                &d("vrep"),
                "--out",
                &d("v.csv"),
            ]
            .map(String::from)
            .to_vec(),
            vec![dir.join("vrep"), dir.join("v.csv")],
            false,
        ),
        (
            "test --raw",
            [
                "test",
                "ecl_beam",
                &d("rt.toml"),
                "--out",
                &d("rd.csv"),
                "--raw",
                &d("raw.h5"),
            ]
            .map(String::from)
            .to_vec(),
            vec![
                dir.join("rd.csv"),
                dir.join("raw.h5"),
                dir.join("raw_steps.csv"),
            ],
            false,
        ),
        (
            "batch shard",
            [
                "--threads",
                "1",
                "batch",
                &d("jobs.toml"),
                "--task-count",
                "1",
                "--task-index",
                "0",
            ]
            .map(String::from)
            .to_vec(),
            vec![shard.clone()],
            true,
        ),
    ];
    let mut state = 0x0005_1a7e_u64;
    for (what, args, outputs, fresh) in cases {
        let mut args: Vec<&str> = args.iter().map(String::as_str).collect();
        args.insert(0, "-q");
        let t = std::time::Instant::now();
        let (rc, _, e) = nlsim(&args);
        assert_eq!(rc, 0, "{what}: {e}");
        let whole = t.elapsed().as_secs_f64();
        let first: Vec<Option<Vec<u8>>> = outputs
            .iter()
            .map(|p| {
                (p.is_file() && p.extension().is_some_and(|e| e == "csv"))
                    .then(|| std::fs::read(p).unwrap())
            })
            .collect();
        let whole_outputs = |why: &str, may_be_missing: bool| {
            for (p, text) in outputs.iter().zip(&first) {
                if may_be_missing && !p.exists() {
                    continue;
                }
                if p.is_dir() {
                    assert!(
                        p.join(".nlsim-report").is_file(),
                        "{why}: {} partial",
                        p.display()
                    );
                } else if let Some(bytes) = text {
                    assert_eq!(&std::fs::read(p).unwrap(), bytes, "{why}: {}", p.display());
                } else {
                    let f = hdf5_metno::File::open(p)
                        .unwrap_or_else(|e| panic!("{why}: {}: {e}", p.display()));
                    assert!(f.attr("nlsim_version").is_ok(), "{why}: {}", p.display());
                }
            }
        };
        for k in 0..20 {
            if fresh {
                for p in &outputs {
                    let _ = std::fs::remove_file(p);
                }
            }
            let signal = if k % 2 == 0 { "KILL" } else { "INT" };
            let delay = seeded_delay(&mut state, whole, 0.05, 1.0);
            let (rc, err) = signalled(&args, delay, signal);
            let why = format!("{what}: {signal} {k} at {delay:?} of {whole:.3} s");
            // (`None`: the signal came before `main` installed the handler, nothing
            // touched yet.)
            if signal == "INT" {
                assert!(
                    matches!(rc, Some(0) | Some(130) | None),
                    "{why}: exit {rc:?}: {err}"
                );
            }
            whole_outputs(&why, fresh);
        }
        let (rc, _, e) = nlsim(&args);
        assert_eq!(rc, 0, "{what}: the run after the stops: {e}");
        whole_outputs(&format!("{what}: the run after the stops"), false);
        for folder in [dir.to_path_buf(), dir.join("w-results")] {
            if folder.is_dir() {
                assert!(
                    leftovers(&folder).is_empty(),
                    "{what}: {:?}",
                    leftovers(&folder)
                );
            }
        }
    }
}

/// Runs `args` (which write `out`) once whole, then Ctrl-C at `tries` seeded points: exit
/// 130 with the line naming `kept` (then `--candidates kept` resumes to the whole run's
/// `out`, bit for bit) or 0 with that `out`; no temporary left in `dir`. Returns how many
/// stopped at a safe point.
fn interrupt_and_resume(
    dir: &Path,
    args: &[String],
    out: &Path,
    kept: &Path,
    tries: usize,
    seed: u64,
) -> usize {
    let with = |extra: &[&str]| -> Vec<String> {
        let mut a = args.to_vec();
        a.extend(extra.iter().map(|s| s.to_string()));
        a
    };
    let reference = dir.join("whole.csv");
    let first = with(&["--out", reference.to_str().unwrap()]);
    let first: Vec<&str> = first.iter().map(String::as_str).collect();
    let t = std::time::Instant::now();
    let (rc, _, e) = nlsim(&first);
    assert_eq!(rc, 0, "{e}");
    let whole = t.elapsed().as_secs_f64();
    let expected = std::fs::read(&reference).unwrap();
    let run = with(&["--out", out.to_str().unwrap()]);
    let run: Vec<&str> = run.iter().map(String::as_str).collect();
    let resume = with(&[
        "--out",
        out.to_str().unwrap(),
        "--candidates",
        kept.to_str().unwrap(),
    ]);
    // Not quiet: the summary says where the costs came from.
    let resume: Vec<&str> = resume
        .iter()
        .map(String::as_str)
        .filter(|a| *a != "-q")
        .collect();
    let mut state = seed;
    let mut stopped = 0;
    for k in 0..tries {
        let _ = std::fs::remove_file(out);
        let _ = std::fs::remove_file(kept);
        let delay = seeded_delay(&mut state, whole, 0.1, 0.8);
        let (rc, err) = signalled(&run, delay, "INT");
        let why = format!("{} Ctrl-C {k} at {delay:?} of {whole:.2} s", args[2]);
        assert!(leftovers(dir).is_empty(), "{why}: {:?}", leftovers(dir));
        match rc {
            Some(0) => assert_eq!(std::fs::read(out).unwrap(), expected, "{why}"),
            Some(130) if kept.exists() => {
                stopped += 1;
                eprintln!("{why}: {err}");
                assert_eq!(err.lines().count(), 1, "{why}: {err}");
                assert!(err.contains("--candidates"), "{why}: {err}");
                assert!(!out.exists(), "{why}: an estimates file from a stopped run");
                let (rc, o, e) = nlsim(&resume);
                assert_eq!(rc, 0, "{why}: {e}");
                assert!(o.contains("with the costs"), "{why}: {o}");
                assert_eq!(
                    std::fs::read(out).unwrap(),
                    expected,
                    "{why}: the resumed run differs"
                );
            }
            other => panic!("{why}: exit {other:?}: {err}"),
        }
    }
    stopped
}

/// A chain of `n` unit masses and 1e4 N/m springs clamped at DOF 1 with a grounded spring at
/// its tip (the FE-level parameter `spring:n:ux.k`), as Matrix Market files, and measured
/// modes `m.csv` with its first mode at `hz`; returns the model file's path.
fn chain_model(dir: &Path, n: usize, hz: f64) -> String {
    let mut k = format!(
        "%%MatrixMarket matrix coordinate real symmetric\n{n} {n} {}\n",
        2 * n - 1
    );
    let mut m = format!("%%MatrixMarket matrix coordinate real symmetric\n{n} {n} {n}\n");
    let mut dofs = String::new();
    for i in 1..=n {
        k.push_str(&format!("{i} {i} {}\n", if i < n { 2.0e4 } else { 1.0e4 }));
        if i < n {
            k.push_str(&format!("{} {i} -1.0e4\n", i + 1));
        }
        m.push_str(&format!("{i} {i} 1.0\n"));
        dofs.push_str(&format!("{i}:ux\n"));
    }
    std::fs::write(dir.join("K.mtx"), k).unwrap();
    std::fs::write(dir.join("M.mtx"), m).unwrap();
    std::fs::write(dir.join("dofs.txt"), dofs).unwrap();
    std::fs::write(
        dir.join("chain.toml"),
        format!(
            "name = \"chain\"\n[matrices]\nstiffness = \"K.mtx\"\nmass = \"M.mtx\"\n\
             dofs = \"dofs.txt\"\n[[spring]]\ndof = \"{n}:ux\"\nk = 500.0\n"
        ),
    )
    .unwrap();
    std::fs::write(
        dir.join("m.csv"),
        format!(
            "mode,frequency_hz,frequency_std_hz\n1,{hz},{}\n",
            hz / 100.0
        ),
    )
    .unwrap();
    dir.join("chain.toml").to_str().unwrap().to_string()
}

/// Calibrations on measured modes and on raw time records stop at a safe point at Ctrl-C and
/// keep their candidates like stepped-sine ones: 6 seeded points each, every kept file
/// resumed to the uninterrupted run's estimates bit for bit.
#[test]
fn modal_and_time_domain_calibrations_keep_their_candidates_at_ctrl_c() {
    let dir = scratch("interrupt-modal-time");
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    // A chain of 3000 DOFs: 41 candidates, each a full eigen solve (about 1 s in all).
    let model = chain_model(&dir, 3000, 0.02);
    let modal: Vec<String> = [
        "-q",
        "calibrate",
        &model,
        &d("m.csv"),
        "--param",
        "spring:3000:ux.k=100:5000",
        "--fe-reduction",
        "full",
        "--lhs",
        "40",
        "--starts",
        "2",
    ]
    .map(String::from)
    .to_vec();
    let stopped = interrupt_and_resume(
        &dir,
        &modal,
        &dir.join("est.csv"),
        &dir.join("est.interrupted.h5"),
        6,
        0x00de_7a11,
    );
    assert!(stopped >= 2, "only {stopped} of 6 modal runs stopped");
    // A 3 s sine sweep through the bump stop (12 001 samples), 301 candidates, 4 starts
    // and 2 folds: about 0.8 s.
    let (rc, _, e) = nlsim(&[
        "-q",
        "simulate",
        "bumpstop_cantilever",
        "--excitation",
        "sweep:f0=19,f1=28.4,amp=0.6",
        "--rate",
        "4000",
        "--duration",
        "3",
        "--out",
        &d("sweep.csv"),
    ]);
    assert_eq!(rc, 0, "{e}");
    let time: Vec<String> = [
        "-q",
        "calibrate",
        "bumpstop_cantilever",
        &d("sweep.csv"),
        "--time-domain",
        "--param",
        "stop.k1=5e4:1e6",
        "--param",
        "stop.e1=5e-4:2e-3",
        "--set",
        "stop.k1=4e5",
        "--set",
        "stop.e1=1.5e-3",
        "--folds",
        "2",
        "--lhs",
        "300",
        "--starts",
        "4",
    ]
    .map(String::from)
    .to_vec();
    let stopped = interrupt_and_resume(
        &dir,
        &time,
        &dir.join("t.csv"),
        &dir.join("t.interrupted.h5"),
        6,
        0x07a1_3d0e,
    );
    assert!(stopped >= 2, "only {stopped} of 6 time-domain runs stopped");
}

/// A second Ctrl-C while a calibration heads for its next safe point stops it at once: a
/// chain of 30 000 DOFs whose every candidate is a full eigen solve (about half a second)
/// gets both signals inside its first candidate; it exits 130 saying so, keeps nothing,
/// leaves no temporary and its older estimates file whole. One Ctrl-C alone stops it at the
/// end of that candidate (or before it, when it lands in the set-up) with the candidates
/// file.
#[test]
fn a_second_ctrl_c_stops_a_calibration_at_once() {
    let dir = scratch("interrupt-twice");
    let n = 30_000;
    let model = chain_model(&dir, n, 0.008);
    let d = |n: &str| dir.join(n).to_str().unwrap().to_string();
    let param = format!("spring:{n}:ux.k=100:5000");
    let args = |out: &str| -> Vec<String> {
        [
            "-q",
            "--threads",
            "1",
            "calibrate",
            &model,
            &d("m.csv"),
            "--param",
            &param,
            "--fe-reduction",
            "full",
            "--lhs",
            "2",
            "--starts",
            "1",
            "--out",
            out,
        ]
        .map(String::from)
        .to_vec()
    };
    let older = b"an older estimates file\n";
    std::fs::write(dir.join("e.csv"), older).unwrap();
    let kept = dir.join("e.interrupted.h5");
    let twice = args(&d("e.csv"));
    let twice: Vec<&str> = twice.iter().map(String::as_str).collect();
    let child = Command::new(env!("CARGO_BIN_EXE_nlsim"))
        .args(&twice)
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pid = child.id() as libc::pid_t;
    for wait in [150, 30] {
        std::thread::sleep(std::time::Duration::from_millis(wait));
        // SAFETY: a signal to our own child, which has not been waited for.
        #[allow(unsafe_code)]
        unsafe {
            libc::kill(pid, libc::SIGINT);
        }
    }
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(130), "{err}");
    assert!(err.contains("stopped at once"), "{err}");
    assert!(!kept.exists(), "a second Ctrl-C still kept the candidates");
    assert_eq!(std::fs::read(dir.join("e.csv")).unwrap(), older);
    assert!(leftovers(&dir).is_empty(), "{:?}", leftovers(&dir));
    // One Ctrl-C: the first candidate ends, then the run stops with what it kept.
    let once = args(&d("e.csv"));
    let once: Vec<&str> = once.iter().map(String::as_str).collect();
    let (rc, err) = signalled(&once, std::time::Duration::from_millis(150), "INT");
    assert_eq!(rc, Some(130), "{err}");
    assert!(
        err.contains("stopped in the candidates phase with 1 of 3"),
        "{err}"
    );
    assert!(kept.is_file(), "{err}");
    assert_eq!(std::fs::read(dir.join("e.csv")).unwrap(), older);
    assert!(leftovers(&dir).is_empty(), "{:?}", leftovers(&dir));
}
