//! `nlsim frf`: multi-harmonic FRFs by harmonic balance with continuation and stability, or
//! stepped sines. [`FrfRequest`] (`request.rs`, the start file in `start.rs`) →
//! [`run_frf`] (`run.rs`) → [`FrfOutputs::write`] (`report.rs`).

pub mod report;
pub mod request;
pub mod run;
pub mod start;

pub use report::*;
pub use request::*;
pub use run::*;

/// `nlsim frf MODEL`: the request checked, the model loaded with its `--set` overrides, the
/// FRF computed with a progress line, then shown and written by [`FrfOutputs::write`].
pub fn execute(
    spec: &str,
    sets: &[String],
    req: &FrfRequest,
    outputs: &FrfOutputs,
    console: &crate::present::console::Console,
) -> crate::Result<()> {
    // Refuse bad options and output names before the (possibly long) solve.
    req.check()?;
    outputs.check()?;
    let plot = outputs.plot_path();
    crate::formats::files::check_outputs(
        &[
            Some(std::path::Path::new(spec)),
            req.start_file.as_ref().map(|s| s.path.as_path()),
        ],
        &[outputs.out.as_deref(), plot.as_deref()],
        &[outputs.report.as_deref()],
    )?;
    let (model, modal_sets) = crate::commands::setup::load_for_run_deferred(spec, sets)?;
    let req = &FrfRequest {
        modal_sets,
        ..req.clone()
    };
    let t1 = std::time::Instant::now();
    let mut count = 0usize;
    let mut progress = |p: &nlsim_hb::SolutionPoint| {
        count += 1;
        if console.shows_progress() {
            console.progress(&format!(
                "  {count} points, at {:.4} Hz, {:.1} s ",
                p.omega / (2.0 * std::f64::consts::PI),
                t1.elapsed().as_secs_f64()
            ));
        }
    };
    let run = run_frf(&model, req, &mut progress)?;
    console.progress_end();
    outputs.write(spec, &model, req, &run, console)
}
