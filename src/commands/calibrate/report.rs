//! What `nlsim calibrate` shows and writes from a [`CalibrationRun`]:
//! the summary lines, the estimates CSV, and the report folder with its tables and plots.
use crate::commands::calibrate::request::CalibrationRequest;
use crate::commands::calibrate::run::CalibrationRun;
use crate::error::{Error, Result};
use crate::present::plot::BarGroup;
use crate::present::plot::Bars;
use crate::present::plot::Lines;
use crate::present::summary::counted;
use nlsim_calib::{Candidate, ParamSpec, StartRun};
use nlsim_kernel::Param;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

impl CalibrationRun {
    /// The readable summary: what was calibrated on what, how the optimisation went, and
    /// per parameter the estimate, its Cramér–Rao bound, the k-fold jackknife spread and
    /// flags (on a bound, poorly identified).
    pub fn summary(&self) -> Vec<String> {
        let c = &self.calibration;
        let d = self.prepared.objective.data();
        let best = &c.runs[0].report;
        let mut v = vec![
            format!(
                "calibrating {} of '{}' on {} ({}, {}, {}); reduction {:.2} s",
                counted(c.params.len(), "parameter"),
                self.prepared.model_name,
                self.request.data.display(),
                counted(d.sweeps.len(), "sweep"),
                counted(d.n_points(), "step"),
                counted(d.channels.len(), "channel"),
                self.prepared.seconds
            ),
            optimisation_line(
                best,
                c.candidates.len(),
                &reused_costs(self.candidates_from.as_deref()),
                self.seconds,
            ),
            format!(
                "cost {:.6e}, reduced chi2 {:.3} (1 when the noise model fits), collinearity \
                 index {:.2}",
                c.cost, c.cramer_rao.reduced_chi2, c.cramer_rao.collinearity
            ),
        ];
        if let Some(w) = c.cramer_rao.misfit_warning() {
            v.push(format!("warning: {w}"));
        }
        if let Some(fe) = self.prepared.objective.fe_stats() {
            v.push(fe_reduction_line(&fe, "reduction"));
        }
        if !c.fit.failed.is_empty() {
            let at: Vec<String> = c
                .fit
                .failed
                .iter()
                .take(5)
                .map(|p| {
                    format!(
                        "sweep {} step {} ({} Hz)",
                        p.sweep + 1,
                        p.step + 1,
                        d.step(*p).frequency_hz
                    )
                })
                .collect();
            v.push(format!(
                "{} points did not converge at the estimate: {}{}",
                c.fit.failed.len(),
                at.join(", "),
                if c.fit.failed.len() > 5 { ", …" } else { "" }
            ));
        }
        v.extend(self.estimates().lines());
        if let (Some(k), nlsim_calib::FoldBy::Sweeps) =
            (c.kfold.as_ref(), self.request.config.fold_by)
        {
            let per: Vec<String> = d
                .sweeps
                .iter()
                .zip(&k.held_out_rms)
                .map(|(s, r)| format!("{} {r:.3}", s.label))
                .collect();
            v.push(format!(
                "each sweep held out and predicted from the others: rms weighted residual \
                 (1 = the noise level) {}",
                per.join(", ")
            ));
        }
        v
    }

    /// Estimates and statistics, one row per parameter.
    pub fn estimates_csv(&self) -> String {
        self.estimates().csv()
    }

    /// The estimate with its statistics.
    pub fn estimates(&self) -> EstimateView<'_> {
        let c = &self.calibration;
        EstimateView {
            params: &c.params,
            estimate: &c.estimate,
            cramer_rao: &c.cramer_rao,
            kfold: c.kfold.as_ref(),
            at_bound: &c.at_bound,
            poorly_identified: &c.poorly_identified,
        }
    }

    fn param_header(&self) -> String {
        param_header(&self.calibration.params)
    }

    /// Every candidate: index (0 = the model's values), values, cost.
    pub fn candidates_csv(&self) -> String {
        candidates_table(&self.calibration.params, &self.calibration.candidates)
    }

    /// The convergence history of every Levenberg–Marquardt run (best first): accepted
    /// iterates with cost and trust radius (internal units).
    pub fn convergence_csv(&self) -> String {
        convergence_table(&self.request.params, &self.calibration.runs)
    }

    /// The folds: estimate, status, held-out and training rms (empty without folds).
    pub fn kfold_csv(&self) -> String {
        let Some(k) = &self.calibration.kfold else {
            return String::new();
        };
        let mut s = format!(
            "fold,{},status,held_out_rms,training_rms\n",
            self.param_header()
        );
        for f in 0..k.k {
            let _ = writeln!(
                s,
                "{},{},{},{:?},{:?}",
                f + 1,
                values_row(&k.estimates[f]),
                k.status[f],
                k.held_out_rms[f],
                k.training_rms[f]
            );
        }
        s
    }

    /// Measured and calibrated harmonics at every point, channel and harmonic, with the
    /// status of the harmonic balance there.
    pub fn fit_csv(&self) -> String {
        let d = self.prepared.objective.data();
        let mut s = String::from(
            "sweep,label,direction,step,frequency_hz,force1_re,force1_im,channel,harmonic,\
             measured_re,measured_im,model_re,model_im,status\n",
        );
        for p in &self.calibration.fit.points {
            let sw = &d.sweeps[p.id.sweep];
            let st = &sw.steps[p.id.step];
            for (c, ch) in d.channels.iter().enumerate() {
                for k in 0..d.harmonics {
                    let y = st.response[(c, k)];
                    let m = p.response[(c, k)];
                    let _ = writeln!(
                        s,
                        "{},{},{},{},{:?},{:?},{:?},{},{},{:?},{:?},{:?},{:?},{}",
                        p.id.sweep + 1,
                        crate::formats::files::csv_field(&sw.label),
                        sw.direction.as_str(),
                        p.id.step + 1,
                        st.frequency_hz,
                        st.force[0].re,
                        st.force[0].im,
                        crate::formats::files::csv_field(&ch.name),
                        k + 1,
                        y.re,
                        y.im,
                        m.re,
                        m.im,
                        p.status
                    );
                }
            }
        }
        s
    }
}

fn param_header(params: &[Param]) -> String {
    params
        .iter()
        .map(|p| p.to_string())
        .collect::<Vec<_>>()
        .join(",")
}

fn values_row(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:?}"))
        .collect::<Vec<_>>()
        .join(",")
}

/// The candidates table: index (0 = the model's values), values of `params`, cost.
pub(crate) fn candidates_table(params: &[Param], candidates: &[Candidate]) -> String {
    let mut s = format!("candidate,{},cost\n", param_header(params));
    for (i, c) in candidates.iter().enumerate() {
        let _ = writeln!(s, "{i},{},{:?}", values_row(&c.values), c.cost);
    }
    s
}

/// The convergence table of `runs` (best first): accepted iterates with cost, trust radius
/// (internal units) and the parameter values.
pub(crate) fn convergence_table(specs: &[ParamSpec], runs: &[StartRun]) -> String {
    let params: Vec<Param> = specs.iter().map(|s| s.param.clone()).collect();
    let mut s = format!("run,iteration,cost,radius,{}\n", param_header(&params));
    for (r, run) in runs.iter().enumerate() {
        for st in &run.report.history {
            let v: Vec<f64> = specs
                .iter()
                .zip(&st.u)
                .map(|(p, &u)| p.to_value(u))
                .collect();
            let _ = writeln!(
                s,
                "{r},{},{:?},{:?},{}",
                st.iteration,
                st.cost,
                st.radius,
                values_row(&v)
            );
        }
    }
    s
}

/// The cost along each optimisation of `runs` as a plot `convergence` (SVG and PNG) in
/// `dir`; nothing when no run has a positive cost. Returns the files written.
pub(crate) fn convergence_plot(
    report: &crate::present::report::Report,
    model_name: &str,
    runs: &[StartRun],
) -> Result<Vec<PathBuf>> {
    let history: Vec<(String, Vec<(f64, f64)>)> = runs
        .iter()
        .enumerate()
        .map(|(r, run)| {
            (
                format!("start {} ({})", r + 1, run.report.status),
                run.report
                    .history
                    .iter()
                    .filter(|s| s.cost > 0.0)
                    .map(|s| (s.iteration as f64, s.cost.log10()))
                    .collect(),
            )
        })
        .filter(|(_, p): &(String, Vec<(f64, f64)>)| !p.is_empty())
        .collect();
    if history.is_empty() {
        return Ok(Vec::new());
    }
    let files = report.figure(
        "convergence",
        &Lines {
            title: format!("{model_name}: Levenberg–Marquardt convergence"),
            x_desc: "iteration".into(),
            y_desc: "log10 cost ½‖r‖² (1)".into(),
            series: history,
        },
    )?;
    Ok(files.to_vec())
}

/// Most FRF plots a report draws (channels × compared harmonics); the fit table holds all.
pub const MAX_FRF_PLOTS: usize = 24;

/// Writes the report of `run` into `dir` (created if needed): `summary.txt`,
/// `estimates.csv`, `candidates.csv`, `convergence.csv`, `kfold.csv`, `fit.csv`,
/// `calibration.toml` (the run and its result, which `nlsim validate` reads), and plots
/// (SVG and PNG) — per channel and compared harmonic the measured and calibrated response per unit
/// fundamental force along each sweep (`frf_CHANNEL_hK`, at most [`MAX_FRF_PLOTS`]),
/// the fold estimates normalised by the estimate with the Cramér–Rao band (`kfold`,
/// thesis Fig. 14) and the cost along each optimisation (`convergence`). Returns the
/// files written.
pub fn write_report(dir: &Path, run: &CalibrationRun) -> Result<Vec<PathBuf>> {
    let report = crate::present::report::Report::create(
        dir,
        &format!("nlsim calibrate: {}", run.prepared.model_name),
        &crate::present::report::command_line(),
        &run.request.model,
    )?;
    report.model_name(&run.prepared.model_name);
    report.seed("Latin hypercube and k-fold split", run.request.config.seed)?;
    report.section_with("Summary", &run.summary());
    report.table(
        "estimates",
        crate::present::report::Table::from_csv(
            "Estimates and uncertainties",
            &run.estimates_csv(),
        ),
    )?;
    if run.calibration.kfold.is_some() {
        report.table(
            "kfold",
            crate::present::report::Table::from_csv("k-fold cross validation", &run.kfold_csv()),
        )?;
    }
    report.section("Test vs calibrated model");
    let mut written = Vec::new();
    let mut text = |name: &str, body: String| -> Result<()> {
        if !body.is_empty() {
            let p = dir.join(name);
            crate::formats::files::write_text_atomically(&p, &body)?;
            written.push(p);
        }
        Ok(())
    };
    let mut summary = run.summary().join("\n");
    summary.push('\n');
    text("summary.txt", summary)?;
    text("estimates.csv", run.estimates_csv())?;
    text("candidates.csv", run.candidates_csv())?;
    text("convergence.csv", run.convergence_csv())?;
    text("kfold.csv", run.kfold_csv())?;
    text("fit.csv", run.fit_csv())?;
    // What `nlsim validate` reads: the run as a calibration file with its result.
    text(
        "calibration.toml",
        crate::commands::calibrate::result::result_toml(run),
    )?;
    let c = &run.calibration;
    let d = run.prepared.objective.data();
    let mut plots = 0;
    'channels: for (ci, ch) in d.channels.iter().enumerate() {
        for &k in &run.request.compare {
            if k > d.harmonics {
                continue;
            }
            if plots == MAX_FRF_PLOTS {
                break 'channels;
            }
            let mut series = Vec::new();
            for (s, sw) in d.sweeps.iter().enumerate() {
                let pts = |model: bool| -> Vec<(f64, f64)> {
                    c.fit
                        .points
                        .iter()
                        .filter(|p| p.id.sweep == s)
                        .filter_map(|p| {
                            let st = &sw.steps[p.id.step];
                            let y = if model {
                                p.response[(ci, k - 1)]
                            } else {
                                st.response[(ci, k - 1)]
                            };
                            let v = y.norm() / st.force[0].norm();
                            v.is_finite().then_some((st.frequency_hz, v))
                        })
                        .collect()
                };
                series.push((format!("test, {}", sw.label), pts(false)));
                series.push((format!("model, {}", sw.label), pts(true)));
            }
            series.retain(|(_, p)| !p.is_empty());
            if series.is_empty() {
                continue;
            }
            let fig = Lines {
                title: format!(
                    "{}: test vs calibrated model, {} harmonic {k}",
                    run.prepared.model_name, ch.name
                ),
                x_desc: "frequency (Hz)".into(),
                y_desc: crate::present::frf_plot::harmonic_over_force_axis(ch.quantity, k),
                series,
            };
            let safe = crate::formats::files::file_name_part(&ch.name);
            written.extend(report.figure(&format!("frf_{safe}_h{k}"), &fig)?);
            plots += 1;
        }
    }
    report.section("Optimisation and cross validation");
    written.extend(convergence_plot(
        &report,
        &run.prepared.model_name,
        &c.runs,
    )?);
    if let Some(k) = &c.kfold {
        let groups = c
            .params
            .iter()
            .enumerate()
            .map(|(j, p)| {
                let e = c.estimate[j];
                let rel = c.cramer_rao.std[j] / e.abs();
                BarGroup {
                    label: p.to_string(),
                    values: k.estimates.iter().map(|v| v[j] / e).collect(),
                    band: rel.is_finite().then_some((1.0 - rel, 1.0 + rel)),
                }
            })
            .collect();
        written.extend(report.figure(
            "kfold",
            &Bars {
                title: format!(
                    "{}: {}-fold estimates / full-data estimate",
                    run.prepared.model_name, k.k
                ),
                bar_desc: "fold".into(),
                y_desc: "fold estimate / estimate (1)".into(),
                baseline: 1.0,
                baseline_desc: "full-data estimate".into(),
                band_desc: "Cramér–Rao ±1σ".into(),
                groups,
            },
        )?);
    }
    written.push(report.finish()?);
    written.push(dir.join(crate::present::report::DATA));
    Ok(written)
}

/// Prints the summary of a stepped-sine calibration and writes the estimates CSV and the
/// report folder that `req` asks for.
pub fn write_outputs(
    req: &CalibrationRequest,
    run: &CalibrationRun,
    console: &crate::present::console::Console,
) -> Result<()> {
    let report = |dir: &Path| write_report(dir, run);
    let contents = "summary.txt, tables, plots as SVG and PNG";
    let (summary, csv) = (run.summary(), run.estimates_csv());
    write_calibration_outputs(req, &summary, &csv, (&report, contents), console)
}

/// Writes a calibration's report folder and returns its files.
pub(crate) type ReportWriter<'a> = &'a dyn Fn(&Path) -> Result<Vec<PathBuf>>;

/// What both kinds of calibration write: the summary lines, the estimates CSV (`req.out`) and
/// the report folder (`req.report`, written by `report`, whose files `contents` names).
pub(crate) fn write_calibration_outputs(
    req: &CalibrationRequest,
    summary: &[String],
    estimates_csv: &str,
    (report, contents): (ReportWriter<'_>, &str),
    console: &crate::present::console::Console,
) -> Result<()> {
    for line in summary {
        console.say(line);
    }
    if let Some(o) = &req.out {
        // Beside it first, then renamed: a killed run or a full disk keeps the older file,
        // and a hard link to another file is never written through.
        crate::formats::files::write_text_atomically(o, estimates_csv)?;
        console.say(&format!("wrote {}", o.display()));
    }
    if let Some(dir) = &req.report {
        let files = crate::formats::guard::write_folder(dir, report)?;
        console.say(&format!(
            "report: {} files in {} ({contents})",
            files.len(),
            dir.display()
        ));
    }
    Ok(())
}

/// The summary line of the FE-level evaluations: the parametric model's basis, its set-up
/// and refreshes, or the full `what` (a reduction, an eigen solve) at every evaluation.
pub fn fe_reduction_line(fe: &nlsim_calib::FeReductionStats, what: &str) -> String {
    if fe.parametric {
        format!(
            "FE-level parameters: parametric reduced model of {} basis vectors ({} to build \
             it); {} evaluations, {} refreshed by a full {what} ({:.2} s)",
            fe.basis_size,
            crate::present::summary::counted(fe.setup_reductions, &format!("full {what}")),
            fe.evaluations,
            fe.refreshes,
            fe.full_seconds
        )
    } else {
        format!(
            "FE-level parameters: a full {what} at each of {} evaluations ({:.2} s)",
            fe.evaluations, fe.full_seconds
        )
    }
}

/// What a calibration estimated, for its estimates CSV and its summary's parameter table
/// (stepped-sine and time-domain calibrations share both).
pub struct EstimateView<'a> {
    /// The parameters.
    pub params: &'a [Param],
    /// The estimate.
    pub estimate: &'a [f64],
    /// The Cramér–Rao bound at it.
    pub cramer_rao: &'a nlsim_calib::CramerRao,
    /// The cross validation, if any.
    pub kfold: Option<&'a nlsim_calib::KFold>,
    /// Parameters on a bound.
    pub at_bound: &'a [bool],
    /// Poorly identified parameters.
    pub poorly_identified: &'a [bool],
}

impl EstimateView<'_> {
    /// The estimates CSV: per parameter the estimate, its Cramér–Rao standard deviation, the
    /// k-fold mean, standard deviation and jackknife spread (NaN without folds), the flags and
    /// the χ²-scaled standard deviation.
    pub fn csv(&self) -> String {
        let mut csv = String::from(
            "param,estimate,cramer_rao_std,kfold_mean,kfold_std,jackknife_std,at_bound,poorly_identified,chi2_scaled_std\n",
        );
        let kf = self.kfold;
        for (j, p) in self.params.iter().enumerate() {
            let _ = writeln!(
                csv,
                "{p},{:?},{:?},{:?},{:?},{:?},{},{},{:?}",
                self.estimate[j],
                self.cramer_rao.std[j],
                kf.map_or(f64::NAN, |k| k.mean[j]),
                kf.map_or(f64::NAN, |k| k.std[j]),
                kf.map_or(f64::NAN, |k| k.jackknife_std[j]),
                self.at_bound[j],
                self.poorly_identified[j],
                self.cramer_rao.scaled_std[j]
            );
        }
        csv
    }

    /// The summary's parameter table: a header, then per parameter the estimate, its
    /// Cramér–Rao and χ²-scaled standard deviations, the k-fold jackknife spread and the flags
    /// (`at bound`, `poorly identified`).
    pub fn lines(&self) -> Vec<String> {
        let mut v = vec![format!(
            "{:<22} {:>14} {:>14} {:>14} {:>14}  flags",
            "parameter", "estimate", "Cramér–Rao", "chi2-scaled", "k-fold (jk)"
        )];
        for (j, p) in self.params.iter().enumerate() {
            let flags: Vec<&str> = [
                (self.at_bound[j], "at bound"),
                (self.poorly_identified[j], "poorly identified"),
            ]
            .iter()
            .filter(|f| f.0)
            .map(|f| f.1)
            .collect();
            v.push(format!(
                "{:<22} {:>14.6e} {:>14.3e} {:>14.3e} {:>14.3e}  {}",
                p.to_string(),
                self.estimate[j],
                self.cramer_rao.std[j],
                self.cramer_rao.scaled_std[j],
                self.kfold.map_or(f64::NAN, |k| k.jackknife_std[j]),
                flags.join(", ")
            ));
        }
        v
    }
}

/// Where an optimisation line says the candidate costs came from: ` (with the costs FILE
/// holds)` when a candidates file was given, else nothing.
pub fn reused_costs(from: Option<&std::path::Path>) -> String {
    from.map_or(String::new(), |p| {
        format!(" (with the costs {} holds)", p.display())
    })
}

/// The summary line of a search's best optimisation: its status, iterations, evaluations
/// (rejected, failed), the candidates it started from (`from`: where they were evaluated,
/// or empty) and the wall time.
pub fn optimisation_line(
    best: &nlsim_calib::LmReport,
    candidates: usize,
    from: &str,
    seconds: f64,
) -> String {
    format!(
        "{} in {} LM iterations ({} evaluations, {} rejected, {} failed) from the best of \
         {candidates} candidates{from}; {seconds:.2} s",
        best.status, best.iterations, best.evaluations, best.rejected, best.failed_evaluations,
    )
}

/// The start of a search's report folder (modal and time-domain calibrations): `dir`
/// created, `summary.txt`, `estimates.csv`, `candidates.csv`, `convergence.csv` and the
/// `extra` text files written, and the page opened with the model, the Latin-hypercube seed,
/// the summary and the estimates table. Returns the page and the files written.
#[allow(clippy::too_many_arguments)]
pub(crate) fn search_report(
    dir: &Path,
    title: &str,
    req: &CalibrationRequest,
    model_name: &str,
    summary: &[String],
    estimates_csv: &str,
    (params, candidates, runs): (&[Param], &[Candidate], &[StartRun]),
    extra: Vec<(&str, String)>,
) -> Result<(crate::present::report::Report, Vec<PathBuf>)> {
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut text = summary.join("\n");
    text.push('\n');
    let mut files = vec![
        ("summary.txt", text),
        ("estimates.csv", estimates_csv.to_string()),
        ("candidates.csv", candidates_table(params, candidates)),
        ("convergence.csv", convergence_table(&req.params, runs)),
    ];
    files.extend(extra);
    let mut written = Vec::new();
    for (name, text) in files {
        let p = dir.join(name);
        crate::formats::files::write_text_atomically(&p, &text)?;
        written.push(p);
    }
    let report = crate::present::report::Report::create(
        dir,
        title,
        &crate::present::report::command_line(),
        &req.model,
    )?;
    report.model_name(model_name);
    report.seed("Latin hypercube", req.config.seed)?;
    report.section_with("Summary", summary);
    report.table(
        "estimates",
        crate::present::report::Table::from_csv("Estimates and uncertainties", estimates_csv),
    )?;
    Ok((report, written))
}

/// The end of a search's report ([`search_report`]): the convergence plot under
/// "Optimisation", the page finished; `written` gains the plot, the page and `report.h5`.
pub(crate) fn finish_search_report(
    report: crate::present::report::Report,
    model_name: &str,
    runs: &[StartRun],
    mut written: Vec<PathBuf>,
) -> Result<Vec<PathBuf>> {
    report.section("Optimisation");
    written.extend(convergence_plot(&report, model_name, runs)?);
    let data = report.dir().join(crate::present::report::DATA);
    written.push(report.finish()?);
    written.push(data);
    Ok(written)
}
