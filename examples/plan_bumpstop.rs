//! Does the planned test identify better? (thesis §4.3–4.4, paper V) On the bump-stop beam
//! (`bumpstop_cantilever`: a cantilever whose tip meets a one-sided stop, contact stiffness
//! `stop.k1` and gap `stop.e1`), the plan below ranks 36 candidate tests by D-optimality.
//! Four of them are then run as virtual tests — the best, one in the middle of the
//! identifiable ones, the worst identifiable one and the worst of all (a level too low to
//! close the gap) — each through the shaker model with the force controller and 1 %
//! measurement noise, and each is calibrated from a wide box with 10-fold cross validation.
//!
//! The table gives per design the plan's Cramér–Rao standard deviations, the calibrated
//! estimates with their error in Cramér–Rao deviations, and the 10-fold jackknife standard
//! deviations. The program fails (exit 1) unless the best design's jackknife deviations are
//! smaller than the worst identifiable design's for every parameter, and every estimate of
//! an identifiable design lies within 4 Cramér–Rao deviations of the truth.
//!
//! Run: `cargo run --release --example plan_bumpstop [DIR]` (about 10 s; the plan report,
//! test files, data and calibration reports go to DIR, by default a folder in the system's
//! temporary directory).

use nlsim::commands::calibrate::request::CalibrationRequest;

use nlsim::commands::calibrate::run::run_calibration;
use nlsim::commands::plan::request::PlanRequest;
use nlsim::commands::plan::run::run_plan;
use nlsim::commands::test::request::TestRequest;
use nlsim::commands::test::run::run_test;
use nlsim::prelude::*;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

const MODEL: &str = "bumpstop_cantilever";

/// The candidates: three levels × two bands × three sensor sets × two harmonic sets.
const PLAN: &str = r#"
params = ["stop.k1", "stop.e1"]
criterion = "D"
levels = [0.1, 0.2, 0.5]
measured = [[1], [1, 3]]
sensor_counts = [1, 2]
noise = { relative = 0.01, absolute = 1e-6 }
harmonics = 3
modes = 20

[[band]]
label = "low"
from = 20.0
to = 25.0
steps = 21

[[band]]
label = "across"
from = 22.0
to = 28.0
steps = 25
"#;

/// The truth (the model's values) and the calibration box.
const TRUTH: [f64; 2] = [2e5, 1e-3];
const BOUNDS: [(f64, f64); 2] = [(5e4, 1e6), (5e-4, 2e-3)];

struct Row {
    what: &'static str,
    rank: usize,
    design: String,
    planned: Vec<f64>,
    estimate: Vec<f64>,
    cr: Vec<f64>,
    jackknife: Vec<f64>,
    identifiable: bool,
}

fn run(dir: &Path) -> nlsim::Result<Vec<Row>> {
    std::fs::create_dir_all(dir).map_err(|source| nlsim::Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let plan_path = dir.join("plan.toml");
    let mut plan = PlanRequest::parse(PLAN, &plan_path, MODEL)?;
    plan.report = Some(dir.join("plan-report"));
    let planned = run_plan(&plan, &|_, _| {})?;
    nlsim::commands::plan::report::write_plan_report(&dir.join("plan-report"), &planned)?;
    let n = planned.ranked.len();
    let identifiable: Vec<usize> = (0..n)
        .filter(|&i| planned.ranked[i].summary.rank == plan.params.len())
        .collect();
    let (Some(&first), Some(&last)) = (identifiable.first(), identifiable.last()) else {
        return Err(nlsim::Error::Failed(
            "no candidate identifies both parameters".into(),
        ));
    };
    let picks = [
        ("best", first),
        ("middle", identifiable[identifiable.len() / 2]),
        ("worst identifiable", last),
        ("worst", n - 1),
    ];
    let specs: Vec<ParamSpec> = plan
        .params
        .iter()
        .zip(BOUNDS)
        .map(|(p, (lo, hi))| ParamSpec::new(p.clone(), lo, hi))
        .collect();
    let mut rows = Vec::new();
    for (what, i) in picks {
        let r = &planned.ranked[i];
        let sub = dir.join(format!("rank{}", i + 1));
        std::fs::create_dir_all(&sub).map_err(|source| nlsim::Error::Io {
            path: sub.clone(),
            source,
        })?;
        let test_path = sub.join("test.toml");
        let text = planned.test_file(r);
        std::fs::write(&test_path, &text).map_err(|source| nlsim::Error::Io {
            path: test_path.clone(),
            source,
        })?;
        let mut test = TestRequest::load(&test_path, MODEL)?;
        test.seed = 7;
        test.compare_open_loop = false;
        let data = run_test(&test, &mut |_, _| {})?;
        let sw = &planned.sweeps[r.design.sweep];
        let mut cal = CalibrationRequest::new(MODEL, data.request.out.clone(), specs.clone());
        cal.compare = sw.harmonic_numbers(&r.design);
        cal.harmonics = plan.harmonics;
        cal.modes = plan.modes;
        cal.config.folds = 10;
        let c = run_calibration(&cal, None, &|_| {})?.calibration;
        let jk = c
            .kfold
            .as_ref()
            .map_or(vec![f64::NAN; specs.len()], |k| k.jackknife_std.clone());
        rows.push(Row {
            what,
            rank: i + 1,
            design: nlsim::commands::plan::run::describe_design(
                &planned.candidates,
                &planned.sweeps,
                r,
            )[1..]
                .join(", "),
            planned: r.summary.std.clone(),
            estimate: c.estimate.clone(),
            cr: c.cramer_rao.std.clone(),
            jackknife: jk,
            identifiable: r.summary.rank == specs.len(),
        });
    }
    Ok(rows)
}

fn main() -> ExitCode {
    let dir = std::env::args().nth(1).map_or_else(
        || std::env::temp_dir().join("nlsim-plan-bumpstop"),
        PathBuf::from,
    );
    let rows = match run(&dir) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    println!(
        "{MODEL}: truth stop.k1 = {:e} N/m, stop.e1 = {:e} m; 1 % noise, force-controlled \
         virtual tests (seed 7), 10-fold cross validation; std in % of the truth",
        TRUTH[0], TRUTH[1]
    );
    println!(
        "{:<20} {:>4}  {:<46} {:>9} {:>9}  {:>11} {:>6} {:>8} {:>8}  {:>11} {:>6} {:>8} {:>8}",
        "design",
        "rank",
        "level N, signal, band, sensors, harmonics",
        "plan k1",
        "plan e1",
        "k1",
        "err/CR",
        "CR",
        "k-fold",
        "e1",
        "err/CR",
        "CR",
        "k-fold"
    );
    let pct = |v: f64, t: f64| {
        if v.is_finite() {
            format!("{:.3}%", 100.0 * v / t)
        } else {
            "inf".into()
        }
    };
    let mut ok = true;
    for r in &rows {
        let mut line = format!(
            "{:<20} {:>4}  {:<46} {:>9} {:>9}",
            r.what,
            r.rank,
            r.design,
            // The plan's deviations are relative (d ln p).
            pct(r.planned[0] * TRUTH[0], TRUTH[0]),
            pct(r.planned[1] * TRUTH[1], TRUTH[1]),
        );
        for j in 0..2 {
            let z = (r.estimate[j] - TRUTH[j]) / r.cr[j];
            // An unidentifiable design leaves the start where it is: its folds agree
            // trivially, so their spread says nothing.
            let (zs, jk) = if r.identifiable {
                (format!("{z:.2}"), pct(r.jackknife[j], TRUTH[j]))
            } else {
                ("-".into(), "n/a".into())
            };
            line.push_str(&format!(
                "  {:>11.5e} {:>6} {:>8} {:>8}",
                r.estimate[j],
                zs,
                pct(r.cr[j], TRUTH[j]),
                jk
            ));
            if r.identifiable && (z.is_nan() || z.abs() > 4.0) {
                eprintln!("{} design: {} is {z:.2} CR deviations off", r.what, j);
                ok = false;
            }
        }
        println!("{line}");
    }
    let best = &rows[0];
    let poor = &rows[2];
    for j in 0..2 {
        if best.jackknife[j].partial_cmp(&poor.jackknife[j]) != Some(std::cmp::Ordering::Less) {
            eprintln!(
                "parameter {j}: the best design's k-fold std {:e} is not below the worst \
                 identifiable one's {:e}",
                best.jackknife[j], poor.jackknife[j]
            );
            ok = false;
        }
    }
    println!("files: {}", dir.display());
    if ok {
        ExitCode::SUCCESS
    } else {
        ExitCode::FAILURE
    }
}
