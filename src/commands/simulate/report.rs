//! What `nlsim simulate` shows and writes from a [`SimRun`]: the summary lines,
//! the history file and the report folder.
use crate::commands::simulate::request::SimOutputs;
use crate::error::{Error, Result};
use nlsim_kernel::Model;
use nlsim_sim::TimeHistory;

use crate::commands::setup::cluster_note;
use crate::commands::setup::modes_text;
use crate::commands::simulate::request::SimRequest;
use crate::commands::simulate::run::SimRun;
use crate::formats::history_file::RunInfo;
use std::path::Path;

impl SimRun {
    /// `None` when the run reached its end; otherwise one line saying where it stopped and why
    /// (the history then holds the samples computed before).
    pub fn stopped_short(&self, n_steps: usize) -> Option<String> {
        let h = &self.history;
        if h.status.is_converged() {
            return None;
        }
        let samples = h.n_samples();
        Some(format!(
            "stopped short ({}) at t = {:.6e} s after {samples} of {} samples: {}",
            h.status.as_str(),
            samples.saturating_sub(1) as f64 * h.dt,
            n_steps + 1,
            h.stopped
                .as_ref()
                .map_or_else(|| "no detail".to_string(), |e| e.to_string())
        ))
    }

    /// The lines `nlsim simulate` prints for this run of `req` on `model`: the setup, the
    /// excitation per point, the run's counters, and the peak and rms of every output and
    /// element; with `verbose`, every contact event.
    pub fn summary(&self, model: &Model, req: &SimRequest, verbose: bool) -> Vec<String> {
        let mut out = Vec::new();
        let run = self;
        let n_steps = req.check().unwrap_or_default();
        let history = &run.history;
        let dt = 1.0 / req.rate;
        out.push(format!(
            "simulate {}: {}, {}, dt {dt:.4e} s, {} samples over {} s",
            model.name(),
            req.method.as_str(),
            if req.method.unreduced() {
                format!(
                    "unreduced ({} DOFs), effective stiffness factorised in {:.2} s",
                    model.n_dofs(),
                    run.setup_seconds
                )
            } else {
                format!(
                    "{} modes{} (reduced in {:.2} s)",
                    modes_text(run.modes, req.modes),
                    if req.residual {
                        " + residual flexibility"
                    } else {
                        ""
                    },
                    run.setup_seconds
                )
            },
            n_steps + 1,
            req.duration
        ));
        for (x, sp) in model.excitation().iter().zip(&run.excitation) {
            out.push(format!("  excitation {:<10} {sp}", x.name));
        }
        if let Some(note) = cluster_note(run.modes, req.modes) {
            out.push(format!("  {note}"));
        }
        if let Some((a, scaled, z_ref)) = run.atol {
            out.push(format!(
                "  rk45 tolerances: rtol {:e}, atol {a:.3e} √kg m on the modal states{}",
                req.rtol,
                if scaled {
                    " (scaled to the response: 1e-3 rtol of the largest static state)"
                } else {
                    ""
                }
            ));
            // An absolute tolerance of a percent of the states lets RK45 accept steps whose
            // error is that large: the response can be far off with no sign of it.
            if !scaled && z_ref > 0.0 && a >= 1e-2 * z_ref {
                out.push(format!(
                    "  warning: atol {a:.3e} √kg m is {:.0} % of the largest static modal state \
                     ({z_ref:.3e} √kg m): RK45 may accept steps with errors that large and the \
                     response may be far off; leave --atol out (scaled to the response: \
                     {:.1e} here)",
                    100.0 * a / z_ref,
                    1e-3 * req.rtol * z_ref
                ));
            }
        }
        let st = &history.stats;
        if run.flops_per_state_step > 0 {
            out.push(format!(
                "  run: {:.3} s wall, {:.2} ns per mode-step ({} states, {} flops each)",
                st.seconds,
                st.seconds / (n_steps as f64 * run.states as f64) * 1e9,
                run.states,
                run.flops_per_state_step
            ));
        }
        out.push(format!(
            "  {} steps ({} rejected), {} evaluations, Newton {} iterations (max {} in a step), {} \
             contact events, {:.3} s wall",
            st.steps,
            st.rejected_steps,
            st.evaluations,
            st.newton_iterations,
            st.max_newton_iterations,
            st.events.len(),
            st.seconds
        ));
        if verbose {
            for e in &st.events {
                out.push(format!(
                    "    contact event: element {} {} at t = {:.9e} s",
                    history.element_names[e.element],
                    if e.closing { "closes" } else { "opens" },
                    e.time
                ));
            }
        }
        if let Some(line) = run.stopped_short(n_steps) {
            out.push(format!("  {line}"));
        }
        out.extend(req.notes().into_iter().map(|n| format!("  {n}")));
        out.push(format!(
            "  {:<14} {:<13} {:>13} {:>13}",
            "output", "quantity", "peak", "rms"
        ));
        for s in &history.outputs {
            let peak = s.values.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let rms = (s.values.iter().map(|x| x * x).sum::<f64>() / s.values.len() as f64).sqrt();
            out.push(format!(
                "  {:<14} {:<13} {peak:>13.5e} {rms:>13.5e}",
                s.name,
                s.quantity.as_str()
            ));
        }
        for (e, name) in history.element_names.iter().enumerate() {
            let pu = history.element_displacements[e]
                .iter()
                .fold(0.0f64, |m, x| m.max(x.abs()));
            let pg = history.element_forces[e]
                .iter()
                .fold(0.0f64, |m, x| m.max(x.abs()));
            out.push(format!(
                "  element {name:<10} peak |u| {pu:.5e} m, peak |g| {pg:.5e} N"
            ));
        }
        out
    }
}

/// The report of `nlsim simulate --report DIR`: the run's summary (`summary`, from
/// [`crate::commands::simulate::run::SimRun::summary`]), one figure per output and one of the element forces
/// against their displacements (at most 4 000 points per curve, evenly picked), and the whole
/// history in `report.h5` (`/time_history`, the layout of `nlsim simulate` files).
/// `command_line` goes into the provenance. Returns the page's path.
pub fn write_report(
    dir: &Path,
    model: &Model,
    h: &TimeHistory,
    info: &RunInfo,
    summary: &[String],
    command_line: &str,
) -> Result<std::path::PathBuf> {
    let report = crate::present::report::Report::create(
        dir,
        &format!("nlsim simulate: {} ({})", model.name(), info.method),
        command_line,
        &info.model_spec,
    )?;
    report.model_name(model.name());
    report.section_with("Time response", summary);
    let n = h.n_samples();
    let every = (n / 4000).max(1);
    for o in &h.outputs {
        report.figure(
            &format!("output_{}", o.name),
            &crate::present::plot::Lines {
                title: format!("{}: {} at {}", model.name(), o.quantity.as_str(), o.name),
                x_desc: "time (s)".into(),
                y_desc: format!(
                    "{} {} ({})",
                    o.name,
                    o.quantity.as_str(),
                    crate::formats::files::unit(o.quantity)
                ),
                series: vec![(
                    info.method.clone(),
                    o.values
                        .iter()
                        .enumerate()
                        .step_by(every)
                        .map(|(k, &v)| (k as f64 * h.dt, v))
                        .collect(),
                )],
            },
        )?;
    }
    if !h.element_names.is_empty() {
        report.figure(
            "element_forces",
            &crate::present::plot::Lines {
                title: format!("{}: element force against displacement", model.name()),
                x_desc: "element displacement (m)".into(),
                y_desc: "element force (N)".into(),
                series: h
                    .element_names
                    .iter()
                    .enumerate()
                    .map(|(e, name)| {
                        (
                            name.clone(),
                            h.element_displacements[e]
                                .iter()
                                .zip(&h.element_forces[e])
                                .step_by(every)
                                .map(|(&u, &g)| (u, g))
                                .collect(),
                        )
                    })
                    .collect(),
            },
        )?;
    }
    report.data(|root| {
        crate::formats::history_file::write_group(&root.create_group("time_history")?, h, info)
    })?;
    report.finish()
}

impl SimOutputs {
    /// Prints the summary and writes the history file and the report of `run`; a run that
    /// stopped short is an error after the samples it computed are written.
    pub fn write(
        &self,
        spec: &str,
        model: &Model,
        req: &SimRequest,
        run: &SimRun,
        console: &crate::present::console::Console,
    ) -> Result<()> {
        let summary = run.summary(model, req, console.verbose());
        for line in &summary {
            console.say(line);
        }
        let history = &run.history;
        let info = crate::formats::history_file::RunInfo {
            model_spec: spec.to_string(),
            method: req.method.as_str().to_string(),
            excitation: run.excitation.clone(),
            modes: run.modes,
            compress: self.compress,
        };
        if let Some(path) = &self.out {
            crate::formats::history_file::write_history(path, model, history, &info)?;
            console.say(&format!("  written to {}", path.display()));
        }
        if let Some(dir) = &self.report {
            crate::formats::guard::write_folder(dir, |dir| {
                write_report(
                    dir,
                    model,
                    history,
                    &info,
                    &summary,
                    &crate::present::report::command_line(),
                )
            })?;
            console.say(&format!(
                "  report {}",
                dir.join(crate::present::report::PAGE).display()
            ));
        }
        // Stopped short: the samples computed are kept (and written), and the run fails.
        match run.stopped_short(req.check()?) {
            None => Ok(()),
            Some(line) => Err(Error::Failed(format!(
                "simulate {line}{}",
                self.out
                    .as_ref()
                    .map_or(String::new(), |p| format!(" (written to {})", p.display()))
            ))),
        }
    }
}
