//! What `nlsim frf` shows and writes from an [`FrfRun`]: the summary lines,
//! the FRF file, the plot and the report folder (event and peak tables, figures).
use crate::commands::frf::request::FrfOutputs;
use crate::commands::frf::request::FrfRequest;
use crate::commands::frf::run::FrfRun;
use crate::commands::setup::{cluster_note, modes_text};
use crate::error::{Error, Result};
use crate::formats::files::unit;
use crate::formats::frf_file::harmonic_label;
use crate::formats::frf_file::write_group;
use crate::formats::frf_file::write_peaks;
use crate::present::frf_plot::FrfPlot;
use crate::present::frf_plot::Magnitude;
use faer::{Mat, c64};
use nlsim_hb::{Branch, HbSystem, PointKind};
use nlsim_kernel::{Model, Status};
use std::f64::consts::PI;

/// The folds and jumps of `branch` (sensor responses `y` from [`responses`](super::responses)) as a report table
/// (`what` names the branch): kind, frequency, level and `|Y|` of every sensor at the
/// fundamental.
pub fn events_table(
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    what: &str,
) -> crate::present::report::Table {
    let nu = sys.harmonics().nu;
    let mut header: Vec<String> = ["event", "frequency (Hz)", "level", "stable"]
        .map(String::from)
        .to_vec();
    for sen in sys.sensors() {
        header.push(format!("|{}| h1 ({})", sen.name, unit(sen.quantity)));
    }
    let rows = branch
        .points
        .iter()
        .zip(y)
        .filter(|(p, _)| matches!(p.kind, PointKind::Fold | PointKind::Jump))
        .map(|(p, y)| {
            let mut row = vec![
                match p.kind {
                    PointKind::Fold => "fold".to_string(),
                    _ => "jump".to_string(),
                },
                format!("{:.6}", p.omega / (2.0 * std::f64::consts::PI)),
                format!("{:.4}", p.scale),
                match p.stable() {
                    Some(true) => "yes".into(),
                    Some(false) => "no".into(),
                    None => "not computed".into(),
                },
            ];
            for s in 0..y.nrows() {
                row.push(format!("{:.6e}", y[(s, nu.min(y.ncols() - 1))].norm()));
            }
            row
        })
        .collect();
    crate::present::report::Table {
        caption: format!("Folds and jumps of the {what}"),
        header,
        rows,
    }
}

/// The largest computed `|Y|` of every sensor and harmonic carrying response along `branch`
/// (`y` from [`responses`](super::responses)) and where it is: a report table. These are computed points, not
/// peaks located between them.
pub fn peaks_table(
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
) -> crate::present::report::Table {
    let nu = sys.harmonics().nu;
    let mut rows = Vec::new();
    for (s, sen) in sys.sensors().iter().enumerate() {
        let nk = sys.harmonics().h + 1;
        let peak = |k: usize| {
            y.iter()
                .enumerate()
                .map(|(i, m)| (i, m[(s, k)].norm()))
                .fold((0, 0.0f64), |a, b| if b.1 > a.1 { b } else { a })
        };
        let top = (0..nk).map(|k| peak(k).1).fold(0.0f64, f64::max);
        for k in 0..nk {
            let (i, v) = peak(k);
            if v > 1e-9 * top && v > 0.0 {
                rows.push(vec![
                    sen.name.clone(),
                    harmonic_label(k, nu),
                    format!(
                        "{:.6}",
                        branch.points[i].omega / (2.0 * std::f64::consts::PI)
                    ),
                    format!("{v:.6e}"),
                    unit(sen.quantity).to_string(),
                ]);
            }
        }
    }
    crate::present::report::Table {
        caption: "Largest computed response per sensor and harmonic (continuation)".into(),
        header: ["sensor", "harmonic", "frequency (Hz)", "|Y|", "unit"]
            .map(String::from)
            .to_vec(),
        rows,
    }
}

/// The located maxima `peaks` of a continuation ([`nlsim_hb::locate_peaks`]): a report table.
pub fn located_peaks_table(
    sys: &HbSystem,
    peaks: &[nlsim_hb::Peak],
) -> crate::present::report::Table {
    let nu = sys.harmonics().nu;
    let rows = peaks
        .iter()
        .map(|p| {
            let sen = &sys.sensors()[p.sensor];
            vec![
                sen.name.clone(),
                harmonic_label(p.harmonic, nu),
                format!("{:.7}", p.omega / (2.0 * std::f64::consts::PI)),
                format!("{:.8e}", p.value),
                unit(sen.quantity).to_string(),
                if p.located {
                    "located between points"
                } else {
                    "an end of the computed branch"
                }
                .to_string(),
            ]
        })
        .collect();
    crate::present::report::Table {
        caption: "Largest response per sensor and harmonic, located along the branch".into(),
        header: ["sensor", "harmonic", "frequency (Hz)", "|Y|", "unit", "how"]
            .map(String::from)
            .to_vec(),
        rows,
    }
}

/// The report of `nlsim frf`: its summary, the folds/jumps and peaks tables, one plot per
/// sensor (magnitude axes and phase panels as given), the FRF data in `report.h5`
/// (`/frf/<mode>`, the layout of FRF files); `summary` is [`crate::commands::frf::run::FrfRun::summary`] and
/// `command_line` goes into the provenance. Returns the page's path.
#[allow(clippy::too_many_arguments)]
pub fn write_report(
    dir: &std::path::Path,
    spec: &str,
    model: &nlsim_kernel::Model,
    req: &crate::commands::frf::request::FrfRequest,
    run: &crate::commands::frf::run::FrfRun,
    summary: &[String],
    (magnitude, phase): (Magnitude, bool),
    command_line: &str,
) -> Result<std::path::PathBuf> {
    let report = crate::present::report::Report::create(
        dir,
        &format!(
            "nlsim frf: {} from {} to {} Hz",
            model.name(),
            req.from_hz,
            req.to_hz
        ),
        command_line,
        spec,
    )?;
    report.model_name(model.name());
    let (sys, branch, y) = (&run.system, &run.branch, &run.responses);
    report.section_with(
        &format!("FRF by harmonic balance ({})", req.mode.as_str()),
        summary,
    );
    report.table("events", events_table(sys, branch, y, req.mode.as_str()))?;
    report.table(
        "peaks",
        if run.peaks.is_empty() {
            peaks_table(sys, branch, y)
        } else {
            located_peaks_table(sys, &run.peaks)
        },
    )?;
    for (s, sen) in sys.sensors().iter().enumerate() {
        let title = format!(
            "{}: {} at {}, H = {}",
            model.name(),
            req.mode.as_str(),
            sen.name,
            sys.harmonics().h
        );
        report.figure(
            &format!("frf_{}", sen.name),
            &FrfPlot {
                sys,
                branch,
                y,
                sensor: s,
                title: &title,
                magnitude,
                phase,
                gaps: &run.skipped_hz,
            },
        )?;
    }
    report.data(|root| {
        let g = root.create_group("frf")?;
        let g = g.create_group(req.mode.as_str())?;
        write_group(&g, sys, branch, y)?;
        write_peaks(&g, sys, &run.peaks)
    })?;
    report.finish()
}

impl FrfRun {
    /// The lines `nlsim frf` prints for this run of `req` on `model`: the setup, the forces,
    /// the point count and time, folds, jumps and branch points, and each sensor's peak;
    /// with `verbose`, the Newton iteration count too.
    pub fn summary(&self, model: &Model, req: &FrfRequest, verbose: bool) -> Vec<String> {
        use nlsim_hb::PointKind;
        let mut out = Vec::new();
        let set = *self.system.harmonics();
        let run = self;
        let (sys, branch) = (&run.system, &run.branch);
        out.push(format!(
            "frf {}: {} {:.4}–{:.4} Hz, H = {} harmonics of Ω/{}, {} modes{} (reduced in {:.2} s), \
             {} unknowns, AFT samples {:?}",
            model.name(),
            req.mode.as_str(),
            req.from_hz,
            req.to_hz,
            set.h,
            set.nu,
            modes_text(run.modes, req.modes),
            if req.residual {
                " + residual flexibility"
            } else {
                ""
            },
            run.reduce_seconds,
            sys.n_unknowns(),
            sys.aft_samples()
        ));
        if let Some(note) = cluster_note(run.modes, req.modes) {
            out.push(format!("  {note}"));
        }
        for x in &sys.forcing().terms {
            let phase = x.amplitude.im.atan2(x.amplitude.re).to_degrees();
            out.push(format!(
                "  force {:<10} {:.4e} N{} at harmonic {} (Ω)",
                sys.inputs()[x.input].0,
                x.amplitude.norm(),
                if phase == 0.0 {
                    String::new()
                } else {
                    format!(" at phase {phase:.1}°")
                },
                crate::formats::frf_file::harmonic_label(x.harmonic, set.nu)
            ));
        }
        let n = branch.points.len();
        let unstable = branch
            .points
            .iter()
            .filter(|p| p.stable() == Some(false))
            .count();
        out.push(format!(
            "  {n} points in {:.3} s ({:.3} ms per point){}; {unstable} unstable",
            run.seconds,
            1e3 * run.seconds / n as f64,
            match run.status {
                Status::Converged => String::new(),
                Status::IterationLimit => " — stopped at the point limit before the end".into(),
                s => format!(" — stopped short ({})", s.as_str()),
            }
        ));
        if verbose {
            let its: usize = branch.points.iter().map(|p| p.iterations).sum();
            out.push(format!(
                "  Newton: {its} iterations in all, {:.2} per point",
                its as f64 / n.max(1) as f64
            ));
        }
        for p in branch
            .points
            .iter()
            .filter(|p| matches!(p.kind, PointKind::Fold | PointKind::Jump))
        {
            out.push(format!(
                "  {} at {:.5} Hz",
                if p.kind == PointKind::Fold {
                    "fold"
                } else {
                    "jump"
                },
                p.omega / (2.0 * PI)
            ));
        }
        for bi in branch
            .bifurcations
            .iter()
            .filter(|b| b.kind != nlsim_hb::BifurcationKind::Fold)
        {
            out.push(format!(
                "  {} at {:.6} Hz{}",
                bi.kind.as_str(),
                bi.omega / (2.0 * PI),
                if bi.located {
                    " (located)"
                } else {
                    " (interpolated between points)"
                }
            ));
        }
        for bp in &branch.branch_points {
            out.push(format!(
                "  branch point near {:.5} Hz",
                bp.omega / (2.0 * PI)
            ));
        }
        let shown: Vec<usize> = if set.nu >= 2 {
            vec![set.nu, 1]
        } else {
            vec![1]
        };
        for (s, sen) in sys.sensors().iter().enumerate() {
            for &k in &shown {
                out.push(self.peak_line(s, k, &sen.name, sen.quantity));
            }
        }
        for note in &self.notes {
            out.push(format!("  note: {note}"));
        }
        out
    }

    /// The summary line of the largest `|Y_k|` of sensor `s` (located when it could be).
    fn peak_line(
        &self,
        s: usize,
        k: usize,
        name: &str,
        quantity: nlsim_kernel::Quantity,
    ) -> String {
        let set = *self.system.harmonics();
        let (branch, y) = (&self.branch, &self.responses);
        let n = branch.points.len();
        {
            let located = self.peaks.iter().find(|p| p.sensor == s && p.harmonic == k);
            let (hz, a, how) = match located {
                Some(p) => (
                    p.omega / (2.0 * PI),
                    p.value,
                    if p.located {
                        "located"
                    } else {
                        "at an end of the computed branch"
                    },
                ),
                None => {
                    let (i, a) = (0..n)
                        .map(|i| (i, y[i][(s, k)].norm()))
                        .fold((0, 0.0f64), |m, v| if v.1 > m.1 { v } else { m });
                    (branch.points[i].omega / (2.0 * PI), a, "largest computed")
                }
            };
            let which = if k == set.nu {
                "the fundamental".to_string()
            } else {
                format!("Ω/{}", set.nu)
            };
            format!(
                "  {name:<12} peak |{}| at {which} {a:.7e} {} at {hz:.6} Hz ({how})",
                quantity.as_str(),
                crate::formats::files::unit(quantity),
            )
        }
    }
}

impl FrfOutputs {
    /// Prints the summary and writes the report, the FRF file and the plot of `run`; a run
    /// that stopped short is an error after everything it computed is written.
    pub fn write(
        &self,
        spec: &str,
        model: &nlsim_kernel::Model,
        req: &FrfRequest,
        run: &FrfRun,
        console: &crate::present::console::Console,
    ) -> Result<()> {
        use std::f64::consts::PI;
        let set = *run.system.harmonics();
        let summary = run.summary(model, req, console.verbose());
        for line in &summary {
            console.say(line);
        }
        let (sys, branch, y) = (&run.system, &run.branch, &run.responses);
        if let Some(dir) = &self.report {
            crate::formats::guard::write_folder(dir, |dir| {
                write_report(
                    dir,
                    spec,
                    model,
                    req,
                    run,
                    &summary,
                    (self.magnitude, self.phase),
                    &crate::present::report::command_line(),
                )
            })?;
            console.say(&format!(
                "  report {}",
                dir.join(crate::present::report::PAGE).display()
            ));
        }
        if let Some(path) = &self.out {
            let info = crate::formats::frf_file::FrfInfo {
                model_spec: spec.to_string(),
                model_name: model.name().to_string(),
                mode: req.mode.as_str().to_string(),
                modes: run.modes,
                residual: req.residual,
                seconds: run.seconds,
                peaks: run.peaks.clone(),
                notes: run.notes.clone(),
                sensor_dofs: sys
                    .sensors()
                    .iter()
                    .filter_map(|s| model.sensors().iter().find(|m| m.name == s.name))
                    .map(|m| m.at.label(model.dofs()))
                    .collect(),
                input_dofs: sys
                    .inputs()
                    .iter()
                    .filter_map(|(n, _)| model.excitation().iter().find(|x| &x.name == n))
                    .map(|x| x.at.label(model.dofs()))
                    .collect(),
                geometry: model.geometry().to_vec(),
            };
            crate::formats::frf_file::write_frf(path, sys, branch, y, &info)?;
            console.say(&format!("  written to {}", path.display()));
        }
        if let Some(p) = self.plot_path() {
            let title = format!("{} — {}, H = {}", model.name(), req.mode.as_str(), set.h);
            crate::present::frf_plot::plot_frf(
                &p,
                sys,
                branch,
                y,
                0,
                &title,
                self.magnitude,
                self.phase,
                &run.skipped_hz,
            )?;
            console.say(&format!("  plot {}", p.display()));
        }
        if run.status.is_converged() || run.status == nlsim_kernel::Status::IterationLimit {
            return Ok(());
        }
        // Stopped short: what was computed is kept (and written), and the run fails.
        let last = branch.points.last().map_or(0.0, |p| p.omega / (2.0 * PI));
        Err(Error::Failed(format!(
            "frf stopped short at {last:.6} Hz ({} points{}): {}",
            branch.points.len(),
            self.out
                .as_ref()
                .map_or(String::new(), |p| format!(", written to {}", p.display())),
            run.detail
        )))
    }
}
