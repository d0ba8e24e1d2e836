//! `nlsim plan MODEL PLAN` as library calls: a typed [`PlanRequest`] (`request.rs`) read from a plan file,
//! [`run_plan`] on it (`run.rs`) (thesis §4.3: the Fisher information `F = Jᵀ Σ⁻¹ J` of every
//! candidate test from the analytic harmonic-balance sensitivities), and
//! [`write_plan_report`] (`report.rs`) with the ranked table, the Cramér–Rao bounds and the plots.
//!
//! A plan file (`docs/planning.md`) names the parameters the test should identify and the
//! candidates: drive points, force levels, excitation signals, frequency bands, sensor sets
//! and measured harmonics. Every combination is one candidate design.
//!
//! ```toml
//! params = ["tip.k3", "mode1.zeta"]   # what the test should identify
//! criterion = "D"                     # D | T | A | E | max-variance
//! levels = [0.05, 0.1, 0.2]           # fundamental force amplitudes (N)
//! measured = [[1], [1, 3]]            # candidate sets of measured harmonics
//! sensor_counts = [1, 2]              # sizes of the candidate sensor sets
//! noise = { relative = 0.01, floor = 1e-3 }  # floor: of each channel's largest response
//!
//! [[actuator]]                        # drive points beside the model's excitations
//! name = "mid"
//! dof = "11:uz"
//!
//! [[band]]
//! label = "across"
//! from = 30.0
//! to = 36.0
//! steps = 15
//! ```

#[cfg(feature = "io")]
pub mod report;
pub mod request;
pub mod run;

#[cfg(feature = "io")]
pub use report::*;
pub use request::*;
pub use run::*;

/// `nlsim plan MODEL PLAN`: the request checked, every candidate evaluated with a progress
/// line, the ranked summary printed and the report folder written.
#[cfg(feature = "io")]
pub fn execute(req: &PlanRequest, console: &crate::present::console::Console) -> crate::Result<()> {
    req.check()?;
    crate::formats::files::check_outputs(
        &[
            Some(std::path::Path::new(&req.model)),
            req.source.as_deref(),
            req.prior.as_deref(),
        ],
        &[],
        &[req.report.as_deref()],
    )?;
    let progress = std::sync::Mutex::new(console.eta("candidate sweeps"));
    let run = run_plan(req, &|d, n| {
        if let Ok(mut p) = progress.lock() {
            p(d, n)
        }
    })?;
    for line in run.summary() {
        console.say(&line);
    }
    if let Some(dir) = &req.report {
        let files = crate::formats::guard::write_folder(dir, |d| write_plan_report(d, &run))?;
        console.say(&format!(
            "report: {} files in {} (summary.txt, ranking.csv, fim_best.csv, plots as SVG \
             and PNG); the best design as a test file: nlsim test {} {}",
            files.len(),
            dir.display(),
            req.model,
            dir.join("best_test.toml").display()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use faer::Mat;
    use nlsim_calib::{Criterion, subsets};
    use nlsim_kernel::Param;
    use std::path::Path;

    const PLAN: &str = r#"
params = ["tip.k3", "mode1.zeta"]
levels = [0.1, 0.2]
measured = [[1], [1, 3]]

[[band]]
label = "across"
from = 30.0
to = 36.0
steps = 5
"#;

    #[test]
    fn a_plan_file_reads_into_its_request() {
        let r = PlanRequest::parse(PLAN, Path::new("/p/plan.toml"), "ecl_beam").unwrap();
        assert_eq!(r.params.len(), 2);
        assert_eq!(r.levels, vec![0.1, 0.2]);
        assert_eq!(r.measured, vec![vec![1], vec![1, 3]]);
        assert_eq!(r.bands[0].steps, 5);
        assert_eq!(r.criterion, Criterion::D);
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let cases = [
            (PLAN.replace("steps = 5", "steps = 5\nbogus = 1"), "bogus"),
            (
                PLAN.replace("levels = [0.1, 0.2]", "levels = [0.1, -2.0]"),
                "levels",
            ),
            (PLAN.replace("[[1], [1, 3]]", "[[1], [1, 5]]"), "measured"),
            (
                PLAN.replace("levels", "criterion = \"Q\"\nlevels"),
                "criterion",
            ),
            (
                PLAN.replace("levels", "noise = { absolute = 0.0 }\nlevels"),
                "noise",
            ),
        ];
        for (text, key) in cases {
            let e = PlanRequest::parse(&text, Path::new("plan.toml"), "m").unwrap_err();
            let msg = e.to_string();
            let line = text
                .lines()
                .position(|l| l.trim_start().starts_with(key))
                .unwrap()
                + 1;
            assert!(
                msg.starts_with(&format!("plan.toml:{line}:")) && msg.contains(key),
                "{key}: {msg}"
            );
        }
    }

    #[test]
    fn binomial_counts_subsets_and_overflows_to_none() {
        for (n, k) in [(5, 2), (7, 0), (7, 7), (10, 3)] {
            assert_eq!(binomial(n, k), Some(subsets(n, k).len()));
        }
        assert_eq!(binomial(10_000, 5000), None);
    }

    #[test]
    fn a_prior_reads_back_by_name_and_must_be_symmetric() {
        let params: Vec<Param> = vec!["a.k".parse().unwrap(), "b.c".parse().unwrap()];
        let f = Mat::from_fn(2, 2, |i, j| [[4.0, 1.0], [1.0, 3.0]][i][j]);
        let dir = std::env::temp_dir().join(format!("nlsim-prior-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("fim.csv");
        std::fs::write(&p, fim_csv(&params, &f)).unwrap();
        // The parameters in the other order: the matrix is permuted by name.
        let swapped = [params[1].clone(), params[0].clone()];
        let g = read_fim_csv(&p, &swapped).unwrap();
        assert_eq!((g[(0, 0)], g[(1, 1)], g[(0, 1)]), (3.0, 4.0, 1.0));
        std::fs::write(&p, "param,a.k,b.c\na.k,4,1\nb.c,2,3\n").unwrap();
        let e = read_fim_csv(&p, &params).unwrap_err().to_string();
        assert!(e.contains("not symmetric"), "{e}");
        std::fs::write(&p, "param,a.k,b.c\na.k,4,1\n").unwrap();
        let e = read_fim_csv(&p, &params).unwrap_err().to_string();
        assert!(e.contains("one row per planned parameter"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn toml_strings_round_trip() {
        #[derive(serde::Deserialize)]
        struct T {
            s: String,
        }
        for text in [
            "plain",
            "a \"quoted\" name",
            "back\\slash",
            "tab\tand\nnewline",
            "é ü",
        ] {
            let t: T = toml::from_str(&format!("s = {}", crate::formats::files::toml_string(text)))
                .unwrap();
            assert_eq!(t.s, text);
        }
    }
}
