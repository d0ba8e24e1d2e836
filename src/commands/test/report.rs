//! The summary and the report folder of `nlsim test` (control statistics, force and response
//! plots).
use crate::commands::test::run::ControlStats;
use crate::commands::test::run::TestRun;
use crate::commands::test::run::distortion;
use crate::commands::test::run::min_force_ratio;
use crate::error::Result;
use crate::formats::files::write_text_atomically as write_text;
use crate::present::plot::Lines;
use nlsim_kernel::Status;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

impl TestRun {
    /// The readable summary: the test, then per sweep the force drop-out and distortion of
    /// the voltage-driven test and the controller's iterations, error and converged steps.
    pub fn summary(&self) -> Vec<String> {
        let r = &self.request;
        let s = &r.shaker;
        let mut v = vec![
            format!(
                "virtual test of '{}' at '{}' through a shaker (armature {} kg, suspension {} \
                 N/m, coil {} ohm {} H, Bl {} N/A, stinger {:e} N/m), {}; {} sweeps, {} \
                 harmonics, noise {} % + a floor of {} (seed {}); reduction {:.2} s, test \
                 {:.2} s",
                self.model_name,
                self.drive,
                s.armature_mass,
                s.suspension_stiffness,
                s.resistance,
                s.inductance,
                s.force_constant,
                s.stinger_stiffness,
                if r.control.enabled {
                    format!("force-controlled to {} %", 100.0 * r.control.tolerance)
                } else {
                    "voltage-driven".into()
                },
                r.sweeps.len(),
                r.harmonics,
                100.0 * r.noise.relative,
                self.floors
                    .iter()
                    .map(|(c, f)| format!("{f:.2e} at {c}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                r.seed,
                self.setup_seconds,
                self.seconds
            ),
            format!(
                "{:<24} {:>22} {:>16}   {:>20} {:>16} {:>10}",
                "sweep",
                "open loop: min |F1|/F*",
                "max distortion",
                "iterations mean/max",
                "max force error",
                "converged"
            ),
        ];
        for (i, plan) in r.sweeps.iter().enumerate() {
            let c = &self.test.steps[i];
            let (min_ratio, dist) = match &self.open_loop {
                Some(o) => (
                    min_force_ratio(&o.steps[i], plan.force),
                    o.steps[i]
                        .iter()
                        .map(|st| distortion(&st.force))
                        .filter(|x| x.is_finite())
                        .fold(0.0f64, f64::max),
                ),
                None => (f64::NAN, f64::NAN),
            };
            let cs = ControlStats::of(c);
            let shown = |x: f64, f: &dyn Fn(f64) -> String| {
                if x.is_nan() { "-".to_string() } else { f(x) }
            };
            v.push(format!(
                "{:<24} {:>22} {:>16}   {:>16.1}/{:<3} {:>14.3} % {:>6}/{}",
                plan.label,
                shown(min_ratio, &|x| format!("{x:.3}")),
                shown(dist, &|x| format!("{x:.3e}")),
                cs.mean_iterations,
                cs.max_iterations,
                100.0 * cs.max_force_error,
                cs.converged,
                cs.steps
            ));
            if let Some(o) = &self.open_loop {
                let failed = crate::commands::test::run::unsolved_steps(&o.steps[i], 4);
                if !failed.is_empty() {
                    v.push(format!(
                        "  open loop: structure not solved at step{} {}: left out of its data \
                         and a gap in its plots",
                        if failed.len() == 1 { "" } else { "s" },
                        failed.join(", ")
                    ));
                }
            }
            for st in c.iter().filter(|st| !st.status.is_converged()) {
                v.push(format!(
                    "  {:.4} Hz: {}{}",
                    st.frequency_hz,
                    st.status,
                    if matches!(st.status, Status::IterationLimit) {
                        format!(
                            " (force error {:.2} %, kept in the data)",
                            100.0 * st.force_error
                        )
                    } else {
                        " (structure not solved; left out of the data)".into()
                    }
                ));
            }
        }
        v.push(format!(
            "test data: {} ({} steps, {} channels); calibrate with `nlsim calibrate MODEL {} \
             --param ...`",
            r.out.display(),
            self.test.data.n_points(),
            self.test.data.channels.len(),
            r.out.display()
        ));
        if let (Some(raw), Some(rr)) = (&self.raw, &r.raw) {
            v.extend(self.raw_lines(raw, rr));
        }
        for w in &self.warnings {
            v.push(format!("warning: {w}"));
        }
        v
    }

    /// The summary's lines on the raw records.
    fn raw_lines(
        &self,
        raw: &crate::commands::test::run::RawRun,
        rr: &crate::commands::test::request::RawRequest,
    ) -> Vec<String> {
        let rec = &raw.record;
        let r = &self.request;
        let steps = crate::commands::test::request::raw_steps_path(&rr.out);
        // The settling each step's measured window leaves out (at most the dwell less 4
        // periods).
        let waited = rec
            .steps
            .iter()
            .map(|s| (s.measured - s.start) as f64 / rec.rate_hz)
            .fold(f64::INFINITY, f64::min);
        let dwell = format!(
            "{} s per step, measured after {:.1} s of settling (the slowest mode near the band \
             to {:e} in {:.1} s)",
            raw.dwell_s,
            waited,
            crate::commands::test::request::DEFAULT_SETTLE,
            raw.settle_s,
        );
        let sig = |name: &str, s: f64| format!("{name} {s:.2e}");
        let mut noise: Vec<String> = rec
            .responses
            .iter()
            .zip(&raw.sigmas)
            .filter(|((n, _, _), _)| r.channels.is_empty() || r.channels.contains(n))
            .map(|((n, _, _), &s)| sig(n, s))
            .collect();
        if r.record == nlsim_calib::Drive::Force {
            noise.push(sig("force", raw.sigmas.last().copied().unwrap_or(0.0)));
        }
        let mut v = vec![format!(
            "raw records: {} ({} samples at {} Hz, {} steps, {dwell}; hold integration \
             through the shaker at {} steps per sample {:.2} s; noise std {}); step table {}",
            rr.out.display(),
            rec.voltage.len(),
            rec.rate_hz,
            rec.steps.len(),
            raw.oversample,
            raw.seconds,
            noise.join(", "),
            steps.display()
        )];
        if waited < 0.999 * raw.settle_s {
            v.push(format!(
                "warning: the raw records' steps are measured {waited:.1} s after their start, \
                 before the slowest mode near the band has settled to {:e} ({:.1} s): lengthen \
                 the dwell to {:.1} s or more, or expect transients in the harmonics",
                crate::commands::test::request::DEFAULT_SETTLE,
                raw.settle_s,
                raw.settle_s
                    + crate::commands::test::request::DEFAULT_MEASURED_PERIODS
                        / rec
                            .steps
                            .iter()
                            .map(|s| s.frequency_hz)
                            .fold(f64::INFINITY, f64::min)
            ));
        }
        if let Some(why) = &rec.stopped {
            v.push(format!(
                "warning: the raw records stop short at {:.3} s ({}): {why}",
                rec.voltage.len() as f64 / rec.rate_hz,
                rec.status
            ));
        }
        v.push(format!(
            "  harmonics from them: `nlsim harmonics {} {} --steps {}{}`",
            r.model,
            rr.out.display(),
            steps.display(),
            if r.record == nlsim_calib::Drive::Voltage {
                " --record voltage"
            } else {
                ""
            }
        ));
        v
    }

    /// Every step of the test (and of the open loop): sweep, frequency, status,
    /// iterations, force error, force and voltage harmonics.
    pub fn control_csv(&self) -> String {
        let h = self.request.harmonics;
        let mut s = String::from("run,sweep,label,step,frequency_hz,status,iterations,force_error");
        for k in 0..=h {
            let _ = write!(s, ",force{k}_re,force{k}_im");
        }
        for k in 0..=h {
            let _ = write!(s, ",voltage{k}_re,voltage{k}_im");
        }
        s.push('\n');
        let runs = std::iter::once(("test", &self.test))
            .chain(self.open_loop.as_ref().map(|o| ("open-loop", o)));
        for (name, t) in runs {
            for (i, steps) in t.steps.iter().enumerate() {
                for (j, st) in steps.iter().enumerate() {
                    let _ = write!(
                        s,
                        "{name},{},\"{}\",{},{:?},{},{},{:?}",
                        i + 1,
                        self.request.sweeps[i].label.replace('"', "\"\""),
                        j + 1,
                        st.frequency_hz,
                        st.status,
                        st.iterations,
                        st.force_error
                    );
                    for f in st.force.iter().chain(&st.voltage) {
                        let _ = write!(s, ",{:?},{:?}", f.re, f.im);
                    }
                    s.push('\n');
                }
            }
        }
        s
    }
}

/// Writes the report of `run` into `dir` (created if needed): `summary.txt`, `control.csv`
/// and plots (SVG and PNG, thesis Fig. 11): the fundamental force and the distortion at
/// the drive point per sweep, controlled and voltage-driven (`force`), and the first
/// channel's fundamental response (`response`). Returns the files written.
pub fn write_test_report(dir: &Path, run: &TestRun) -> Result<Vec<PathBuf>> {
    let report = crate::present::report::Report::create(
        dir,
        &format!("nlsim test: {}", run.model_name),
        &crate::present::report::command_line(),
        &run.request.model,
    )?;
    report.model_name(&run.model_name);
    report.seed("measurement noise", run.request.seed)?;
    report.section_with("Summary", &run.summary());
    report.section("Force and response");
    let mut written = Vec::new();
    for (name, body) in [
        ("summary.txt", run.summary().join("\n") + "\n"),
        ("control.csv", run.control_csv()),
    ] {
        let p = dir.join(name);
        write_text(&p, &body)?;
        written.push(p);
    }
    let ctl = if run.request.control.enabled {
        "force-controlled"
    } else {
        "voltage-driven"
    };
    let mut tests = vec![(ctl, &run.test)];
    if let Some(o) = &run.open_loop {
        tests.push(("voltage-driven", o));
    }
    let mut force = Vec::new();
    for (what, t) in &tests {
        for (i, plan) in run.request.sweeps.iter().enumerate() {
            // A step whose structure was not solved is a gap (a non-finite point).
            let pts = |f: &dyn Fn(&[faer::c64]) -> f64| -> Vec<(f64, f64)> {
                t.steps[i]
                    .iter()
                    .map(|st| (st.frequency_hz, f(&st.force)))
                    .collect()
            };
            force.push((
                format!("{}, {what}, |F1|", plan.label),
                pts(&|f| f[1].norm()),
            ));
            if run.request.harmonics >= 2 {
                force.push((
                    format!("{}, {what}, |F2..FH|", plan.label),
                    pts(&|f| distortion(f) * f[1].norm()),
                ));
            }
        }
    }
    force.retain(|(_, p)| p.iter().any(|q| q.1.is_finite()));
    written.extend(report.figure(
        "force",
        &Lines {
            title: format!(
                "{}: force at the drive point '{}'",
                run.model_name, run.drive
            ),
            x_desc: "frequency (Hz)".into(),
            y_desc: "force harmonic amplitude (N)".into(),
            series: force,
        },
    )?);
    let ch = &run.test.data.channels[0];
    let mut resp = Vec::new();
    for (what, t) in &tests {
        for (i, plan) in run.request.sweeps.iter().enumerate() {
            // Every step of the sweep in test order; one left out of the data (structure
            // not solved) is a gap.
            let data = t.data.sweeps.iter().find(|sw| sw.label == plan.label);
            let value = |f: f64| -> f64 {
                data.and_then(|sw| sw.steps.iter().find(|st| st.frequency_hz == f))
                    .map_or(f64::NAN, |st| st.response[(0, 0)].norm())
            };
            resp.push((
                format!("{}, {what}", plan.label),
                t.steps[i]
                    .iter()
                    .map(|st| (st.frequency_hz, value(st.frequency_hz)))
                    .collect::<Vec<_>>(),
            ));
        }
    }
    resp.retain(|(_, p)| p.iter().any(|q| q.1.is_finite()));
    written.extend(report.figure(
        "response",
        &Lines {
            title: format!("{}: response at '{}', harmonic 1", run.model_name, ch.name),
            x_desc: "frequency (Hz)".into(),
            y_desc: format!(
                "|{}| {} ({})",
                ch.name,
                ch.quantity.as_str(),
                crate::formats::files::unit(ch.quantity)
            ),
            series: resp,
        },
    )?);
    written.push(report.finish()?);
    written.push(dir.join(crate::present::report::DATA));
    Ok(written)
}
