//! `nlsim simulate`: time histories by the exponential first-order hold or a reference
//! integrator. [`SimRequest`] (`request.rs`; the excitation grammar is `formats::excitation`) →
//! [`run_simulation`] (`run.rs`) → [`SimOutputs::write`] (`report.rs`).

pub mod report;
pub mod request;
pub mod run;

pub use crate::formats::excitation::*;
pub use report::*;
pub use request::*;
pub use run::*;

/// `nlsim simulate MODEL`: the request checked, the model loaded with its `--set`
/// overrides, the run with a progress line, then shown and written by [`SimOutputs::write`].
pub fn execute(
    spec: &str,
    sets: &[String],
    req: &SimRequest,
    outputs: &SimOutputs,
    console: &crate::present::console::Console,
) -> crate::Result<()> {
    req.check()?;
    outputs.check()?;
    crate::formats::files::check_outputs(
        &[Some(std::path::Path::new(spec))],
        &[outputs.out.as_deref()],
        &[outputs.report.as_deref()],
    )?;
    let model = crate::commands::setup::load_for_run(spec, sets)?;
    let run = run_simulation(&model, req, &mut console.counter("simulate"))?;
    outputs.write(spec, &model, req, &run, console)
}
