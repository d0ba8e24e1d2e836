//! The FE-level calibration of issue 49 on the bracket ([`nlsim_bench::bracket_fe_case`])
//! with the parametric reduced model: wall time, the FE-reduction counters, the estimates
//! with their Cramér–Rao bounds and the peak memory. With `--check`, the same objective with
//! a full reduction per evaluation is evaluated at the estimate: the predicted responses of
//! both, and the first-order shift of the optimum that their residual difference `δr` makes,
//! `δp = (JᵀJ)⁻¹ Jᵀ δr`, in units of the Cramér–Rao bounds. With `--full` the whole
//! calibration runs a second time with full reductions (slow: a full reduction and its
//! eigen-sensitivities at every evaluation) and the estimates are compared. `--spring LO:HI`
//! widens the spring's range (N/m; 1e3:1e9 moves the first mode out of the sweeps' band, so
//! the certificate fires and the summary counts the refreshes).
//!
//! `cargo run --release -p nlsim-bench --example fe_calibration -- 30000 [--check] [--full] [--folds N] [--spring LO:HI]`
use faer::linalg::solvers::Solve;
use nlsim_calib::{CalibrationConfig, FeReduction, SweepEvaluation, calibrate_with_progress};
use std::time::Instant;

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let target: usize = args
        .get(1)
        .map_or(30_000, |s| s.parse().expect("a DOF count"));
    let with_full = args.iter().any(|a| a == "--full");
    let check = args.iter().any(|a| a == "--check");
    let folds = args
        .iter()
        .position(|a| a == "--folds")
        .map_or(10, |i| args[i + 1].parse().expect("a fold count"));
    let t = Instant::now();
    let mut case = nlsim_bench::bracket_fe_case(target);
    if let Some(i) = args.iter().position(|a| a == "--spring") {
        let (lo, hi) = args[i + 1].split_once(':').expect("--spring LO:HI");
        let p = case.specs[0].param.clone();
        case.specs[0] = nlsim_calib::ParamSpec::new(
            p,
            lo.parse().expect("a stiffness"),
            hi.parse().expect("a stiffness"),
        );
    }
    println!(
        "{} DOFs; case built in {:.1} s",
        case.model.n_dofs(),
        t.elapsed().as_secs_f64()
    );
    let cfg = CalibrationConfig {
        folds,
        ..CalibrationConfig::default()
    };
    let mut kinds = vec![("parametric", FeReduction::default())];
    if with_full {
        kinds.push(("full", FeReduction::Full));
    }
    let mut results = Vec::new();
    for (name, fe) in kinds {
        let t = Instant::now();
        let obj = case.objective(&fe);
        let setup = t.elapsed().as_secs_f64();
        let last = std::sync::Mutex::new(String::new());
        let cal = calibrate_with_progress(&obj, &cfg, &|p| {
            let s = format!("{p:?}");
            let mut l = last.lock().expect("progress");
            if s != *l {
                eprint!("\r  {name}: {s}          ");
                *l = s;
            }
        })
        .expect("the calibration");
        eprintln!();
        let total = t.elapsed().as_secs_f64();
        println!(
            "{name}: {total:.1} s wall ({setup:.1} s to build the objective), status {:?}, \
             {} candidates, {:?}",
            cal.status,
            cal.candidates.len(),
            obj.fe_stats()
        );
        for (j, s) in case.specs.iter().enumerate() {
            println!(
                "  {:<22} {:.6e} ± {:.2e} (truth {:.3e})",
                s.param.to_string(),
                cal.estimate[j],
                cal.cramer_rao.std[j],
                case.truth[j]
            );
        }
        results.push((cal, obj));
    }
    if let [(a, _), (b, obj_full)] = &results[..] {
        let worst = (0..a.estimate.len())
            .map(|j| (a.estimate[j] - b.estimate[j]).abs() / b.cramer_rao.std[j])
            .fold(0.0f64, f64::max);
        println!("estimates differ by {worst:.2e} of their Cramér–Rao bounds at most");
        // Predicted responses at the parametric estimate, both ways.
        let mut prom = results[0].1.clone();
        let mut full = obj_full.clone();
        let pa = prom
            .evaluate_values(&a.estimate, None, false)
            .expect("evaluation");
        let pb = full
            .evaluate_values(&a.estimate, None, false)
            .expect("evaluation");
        let d = response_difference(&pa, &pb);
        println!("predicted responses differ by {d:.2e} of the largest");
    }
    if check {
        let (cal, prom) = &results[0];
        let mut prom = prom.clone();
        let mut full = case.objective(&FeReduction::Full);
        let pa = prom
            .evaluate_values(&cal.estimate, None, true)
            .expect("evaluation");
        let pb = full
            .evaluate_values(&cal.estimate, None, false)
            .expect("evaluation");
        let d = response_difference(&pa, &pb);
        println!(
            "check: predicted responses at the estimate, parametric vs full reduction: {d:.2e} \
             of the largest"
        );
        // δp = (JᵀJ)⁻¹ Jᵀ (r_full − r_prom) in the values' units.
        let j = pa.jacobian.expect("a Jacobian");
        let n = j.ncols();
        let dr: Vec<f64> = pb
            .residuals
            .iter()
            .zip(&pa.residuals)
            .map(|(a, b)| a - b)
            .collect();
        let jtj = faer::Mat::from_fn(n, n, |a, b| {
            (0..j.nrows()).map(|i| j[(i, a)] * j[(i, b)]).sum::<f64>()
        });
        let jtr = faer::Mat::from_fn(n, 1, |a, _| {
            (0..j.nrows()).map(|i| j[(i, a)] * dr[i]).sum::<f64>()
        });
        let dp = jtj.partial_piv_lu().solve(&jtr);
        let worst = (0..n)
            .map(|k| (dp[(k, 0)] / cal.cramer_rao.std[k]).abs())
            .fold(0.0f64, f64::max);
        println!(
            "check: first-order shift of the estimate by the full reduction's residuals: \
             {worst:.2e} of the Cramér–Rao bounds at most"
        );
    }
    if let Ok(s) = std::fs::read_to_string("/proc/self/status") {
        for l in s.lines().filter(|l| l.starts_with("VmHWM")) {
            println!("peak memory: {}", l.trim_start_matches("VmHWM:").trim());
        }
    }
}

/// The largest difference of the computed responses of `a` and `b` (point by point),
/// relative to the largest response of `b`.
fn response_difference(a: &SweepEvaluation, b: &SweepEvaluation) -> f64 {
    let (mut d, mut m) = (0.0f64, 0.0f64);
    for (x, y) in a.points.iter().zip(&b.points) {
        d = d.max((&x.response - &y.response).norm_max());
        m = m.max(y.response.norm_max());
    }
    d / m
}
