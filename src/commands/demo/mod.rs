//! `nlsim demo` as a library call: the model-calibration pipeline of the thesis, stage by stage,
//! on one model, with a readable summary (through a line callback) and a report folder.
//!
//! The stages are in `stages.rs` (time response, FRF, calibration) and `planning.rs`
//! (pre-test planning, virtual test).
pub mod planning;
pub mod stages;

use crate::error::Result;
use nlsim_kernel::ValidationConfig;
use nlsim_reduction::{EigenConfig, ModeSelection};
use stages::{demo_calibration, demo_frf, demo_time_response};
use std::path::Path;
use std::time::Instant;

/// Runs the thesis pipeline stage by stage on `model` (a built-in model or a model file):
/// model summary, modes and residual flexibility, an FOH time response checked against RK45,
/// the nonlinear FRF with stability, pre-test planning, a virtual test through a shaker, then
/// calibration with k-fold statistics. Every line goes to `show`, to `REPORT/summary.txt` and
/// to the report page `REPORT/index.html` ([`crate::present::report`]), with every table and figure
/// (also as SVG and PNG files) and the data behind them in `REPORT/report.h5`.
/// `command_line` is recorded in the provenance.
pub fn run_demo(
    model: &str,
    report_dir: &Path,
    command_line: &str,
    show: &dyn Fn(&str),
) -> Result<()> {
    let report = crate::present::report::Report::create(
        report_dir,
        &format!("nlsim demo: the model-calibration pipeline on {model}"),
        command_line,
        model,
    )?;
    // Everything said also goes to REPORT/summary.txt and the page.
    let text = std::cell::RefCell::new(String::new());
    let say = |s: &str| {
        show(s);
        report.say(s);
        let mut t = text.borrow_mut();
        t.push_str(s);
        t.push('\n');
    };
    // The heading line is the page's title.
    let heading = "nlsim demo: the model-calibration pipeline of Chen (2016) on a built-in model";
    show(heading);
    show("");
    text.borrow_mut().push_str(&format!("{heading}\n\n"));
    let t0 = Instant::now();
    report.section("1. Model");
    let loaded = crate::load_model(model)?;
    report.model_name(loaded.model.name());
    let validation = loaded.model.validate(&ValidationConfig::default())?;
    say(&format!(
        "[1/8] model: loaded and validated in {:.1} ms",
        t0.elapsed().as_secs_f64() * 1e3
    ));
    say(&crate::present::summary::model_summary(
        &loaded.model,
        &loaded.source,
        Some(&validation),
    ));
    if let Some(d) = &loaded.description {
        say(&format!("  about        {d}"));
    }
    if !loaded.references.is_empty() {
        let text = report.table_text();
        say("  references   (values the tests hold this model to)");
        for r in &loaded.references {
            say(&format!(
                "               {:<44} {:>12.6} {:<3} (rtol {:.0e}; {})",
                r.quantity, r.value, r.unit, r.rtol, r.source
            ));
        }
        drop(text);
        report.table(
            "model_references",
            crate::present::report::Table {
                caption: "Reference values the tests hold this model to".into(),
                header: ["quantity", "value", "unit", "rtol", "source"]
                    .map(String::from)
                    .to_vec(),
                rows: loaded
                    .references
                    .iter()
                    .map(|r| {
                        vec![
                            r.quantity.to_string(),
                            format!("{:.6}", r.value),
                            r.unit.to_string(),
                            format!("{:.0e}", r.rtol),
                            r.source.to_string(),
                        ]
                    })
                    .collect(),
            },
        )?;
    }
    say("");
    report.section("2. Modes and reduction");
    let t = Instant::now();
    let n_modes = loaded.model.n_dofs().min(12);
    let cfg = nlsim_reduction::ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(n_modes),
            ..EigenConfig::default()
        },
        ..Default::default()
    };
    let reduced = nlsim_reduction::reduce(&loaded.model, &cfg)?;
    let system = nlsim_reduction::ModalSystem::new(&reduced)?;
    say(&format!(
        "[2/8] modes: the lowest {n_modes} in {:.1} ms; diagonal state space with {} stored \
         states (conjugate pairs once) and {} ports",
        t.elapsed().as_secs_f64() * 1e3,
        system.n_states(),
        system.ports.len()
    ));
    let modes = crate::formats::modes_file::ModeReport::new(
        &loaded.model,
        reduced.modes.clone(),
        cfg.eigen,
    );
    {
        let _text = report.table_text();
        say(&crate::commands::modes::format_table(&modes));
    }
    report.table("modes", crate::commands::modes::table(&modes))?;
    report.data(|root| crate::formats::modes_file::write_group(root, &loaded.model, &modes))?;
    // How much of the static flexibility at each port the truncated modes carry (for a
    // supported structure; rigid-body modes have no static flexibility).
    let supported = reduced.modes.eigenvalues.iter().all(|&l| l > 0.0);
    for (p, port) in reduced.ports.iter().enumerate().filter(|_| supported) {
        let modal: f64 = (0..reduced.n_modes())
            .map(|r| reduced.participation[(p, r)].powi(2) / reduced.modes.eigenvalues[r])
            .sum();
        let resid = reduced.residual[(p, p)];
        say(&format!(
            "  port {:<12} ({:<10}) static flexibility {:.4e} m/N, of which residual (truncated \
             modes) {:.2} %",
            port.name,
            port.kind.as_str(),
            modal + resid,
            100.0 * resid / (modal + resid)
        ));
    }
    say("");
    demo_time_response(&loaded.model, &reduced, &system, &report, &say)?;
    say("");
    demo_frf(&loaded.model, &reduced, &report, &say)?;
    say("");
    crate::commands::demo::planning::demo_planning(&loaded.model, &reduced, &report, &say)?;
    say("");
    let virtual_data =
        crate::commands::demo::planning::demo_virtual_test(&loaded.model, &reduced, &report, &say)?;
    say("");
    demo_calibration(&loaded.model, &reduced, virtual_data, &report, &say)?;
    say("");
    let summary = report_dir.join("summary.txt");
    say(&format!(
        "done in {:.2} s; report in {} (index.html with every table and plot, report.h5 with \
         their data, summary.txt, plots as SVG and PNG)",
        t0.elapsed().as_secs_f64(),
        report_dir.display()
    ));
    crate::formats::files::write_text_atomically(&summary, &text.borrow())?;
    report.wrote(&summary);
    report.finish()?;
    Ok(())
}

/// `nlsim demo`: [`run_demo`] with its lines on the console.
pub fn execute(
    model: &str,
    report_dir: &Path,
    console: &crate::present::console::Console,
) -> Result<()> {
    refuse_foreign_folder(report_dir)?;
    // Locked for the run (a second demo into the same folder is refused), and refused if a
    // model file the demo reads lies in it.
    crate::formats::files::check_outputs(&[Some(Path::new(model))], &[], &[Some(report_dir)])?;
    let command_line = crate::present::report::command_line();
    run_demo(model, report_dir, &command_line, &|s: &str| console.say(s))
}

/// The demo's report folder when none is given: `nlsim-report` for the default model (the ECL
/// beam), `nlsim-report-MODEL` for another (characters other than letters, digits, `-` and
/// `_` of the model's name or spec become `_`).
pub fn default_report_dir(model: &str) -> std::path::PathBuf {
    if model == "ecl_beam" {
        return "nlsim-report".into();
    }
    let stem = Path::new(model)
        .file_stem()
        .map_or_else(|| model.to_string(), |s| s.to_string_lossy().into_owned());
    format!("nlsim-report-{}", crate::present::report::safe_name(&stem)).into()
}

/// Refuses a report folder that exists, holds files and is not an nlsim report (no
/// `report.h5`, `index.html` or the marker a report leaves as soon as it starts): the demo
/// replaces its own reports, finished or not, never someone's folder.
fn refuse_foreign_folder(dir: &Path) -> Result<()> {
    let Ok(mut entries) = std::fs::read_dir(dir) else {
        return Ok(()); // missing (created later) or unreadable (that error comes later)
    };
    let ours = [
        crate::present::report::DATA,
        crate::present::report::PAGE,
        crate::present::report::MARKER,
    ]
    .iter()
    .any(|f| dir.join(f).is_file());
    if !ours && entries.next().is_some() {
        return Err(crate::error::Error::Usage(format!(
            "{}: the folder holds files and no nlsim report; the demo would write into it: \
             give another --report folder",
            dir.display()
        )));
    }
    Ok(())
}

#[cfg(test)]
mod report_dir_tests {
    #[test]
    fn each_model_has_its_own_default_folder() {
        use super::default_report_dir as d;
        assert_eq!(d("ecl_beam"), std::path::PathBuf::from("nlsim-report"));
        assert_eq!(
            d("duffing_fig3"),
            std::path::PathBuf::from("nlsim-report-duffing_fig3")
        );
        assert_eq!(
            d("bracket:refinement=2"),
            std::path::PathBuf::from("nlsim-report-bracket_refinement_2")
        );
        assert_eq!(
            d("examples/models/two_dof.toml"),
            std::path::PathBuf::from("nlsim-report-two_dof")
        );
    }

    /// A report that stopped half-way (plots written, no `report.h5` or page yet) is still
    /// the demo's own folder: the next run may replace it; a folder of other files is not.
    #[test]
    fn a_half_written_report_is_still_ours() {
        let dir = std::env::temp_dir().join(format!("nlsim-demo-dir-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let report = crate::present::report::Report::create(&dir, "t", "nlsim demo", "m")
            .expect("report starts");
        std::fs::write(dir.join("time_response.svg"), "<svg/>").unwrap();
        drop(report);
        assert!(!dir.join(crate::present::report::DATA).exists());
        super::refuse_foreign_folder(&dir).expect("a half-written report is ours");
        std::fs::remove_file(dir.join(crate::present::report::MARKER)).unwrap();
        let e = super::refuse_foreign_folder(&dir).unwrap_err().to_string();
        assert!(e.contains("holds files and no nlsim report"), "{e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
