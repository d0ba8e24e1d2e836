//! The summary and the report folder of `nlsim plan` (ranking, Fisher information of the best
//! design, Cramér–Rao bounds, plots, the best design as a test file), and the HDF5 groups
//! plan batches write and merge.
use crate::commands::plan::request::PlanRequest;
use crate::commands::plan::request::PointSpec;
use crate::commands::plan::run::PlanCandidates;
use crate::commands::plan::run::PlanRun;
use crate::commands::plan::run::describe_design;
use crate::commands::plan::run::fim_csv;
use crate::commands::plan::run::plan_candidates;
use crate::commands::plan::run::rank;
use crate::error::{Error, Result};
use crate::formats::files::toml_string;
use crate::formats::files::write_text_atomically as write_text;
use crate::present::plot::BarGroup;
use crate::present::plot::Bars;
use crate::present::plot::Lines;
use faer::Mat;
use nlsim_calib::{Criterion, RankedDesign, SweepInformation};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::Instant;

impl PlanRun {
    /// The test file (`nlsim test`, docs/planning.md) that runs design `r`: its drive
    /// (`drive_dof` for a plan actuator), level and band as one `[[sweep]]`, its sensors
    /// as `channels` (with `[[sensor]]` entries for the plan's added sensors), the plan's
    /// harmonics, modes, overrides and noise, the data written to `virtual_test.csv`
    /// beside the file. The compared harmonics are named in a comment (they are
    /// `nlsim calibrate --compare`). `nlsim test` drives a pure sine: a design's side
    /// tones are named in a comment and left out.
    pub fn test_file(&self, r: &RankedDesign) -> String {
        let req = &self.request;
        let c = &self.candidates.sweeps[r.design.sweep];
        let sw = &self.sweeps[r.design.sweep];
        let q = |s: &str| toml_string(s);
        let mut t = String::new();
        let [drive, level, signal, band, sensors, harm] =
            describe_design(&self.candidates, &self.sweeps, r);
        let _ = writeln!(
            t,
            "# nlsim test file of a planned design of '{}': drive {drive}, {level} N, {signal}, \
             {band}, sensors {sensors}, harmonics {harm}",
            self.candidates.model_name
        );
        let compare: Vec<String> = sw
            .harmonic_numbers(&r.design)
            .iter()
            .map(usize::to_string)
            .collect();
        let _ = writeln!(
            t,
            "# calibrate the data with: nlsim calibrate MODEL virtual_test.csv --compare {} \
             --param ...",
            compare.join(",")
        );
        if !c.exciter.side.is_empty() {
            let _ = writeln!(
                t,
                "# the design's side tones ({signal}) are left out: nlsim test drives a pure sine"
            );
        }
        match req.actuators.iter().find(|a| a.name == c.exciter.input) {
            Some(a) => {
                let _ = writeln!(t, "drive_dof = {}", q(&a.dof));
            }
            None => {
                let _ = writeln!(t, "drive = {}", q(&c.exciter.input));
            }
        }
        let _ = writeln!(t, "harmonics = {}", req.harmonics);
        let _ = writeln!(t, "modes = {}", req.modes);
        let _ = writeln!(
            t,
            "noise = {{ relative = {:e}, absolute = {:e}, floor = {:e} }}",
            req.noise.relative, req.noise.absolute, req.noise_floor
        );
        let _ = writeln!(t, "out = \"virtual_test.csv\"");
        let names: Vec<String> = sw.channel_names(&r.design).into_iter().map(q).collect();
        let _ = writeln!(t, "channels = [{}]", names.join(", "));
        if !req.set.is_empty() {
            let pairs: Vec<String> = req
                .set
                .iter()
                .filter_map(|kv| kv.split_once('='))
                .map(|(k, v)| format!("{} = {}", q(k.trim()), v.trim()))
                .collect();
            let _ = writeln!(t, "set = {{ {} }}", pairs.join(", "));
        }
        let added: Vec<&PointSpec> = sw
            .channel_names(&r.design)
            .into_iter()
            .filter_map(|name| req.sensors.iter().find(|p| p.name == name))
            .collect();
        if !added.is_empty() {
            let _ = writeln!(
                t,
                "\n# the sensors below are not in the model: calibrate the data with a model \
                 file that declares them"
            );
        }
        for p in added {
            let _ = write!(
                t,
                "\n[[sensor]]\nname = {}\ndof = {}\nquantity = {}\n",
                q(&p.name),
                q(&p.dof),
                q(p.quantity.as_str())
            );
        }
        let _ = write!(
            t,
            "\n[[sweep]]\nlabel = {}\nfrom = {:?}\nto = {:?}\nsteps = {}\nforce = {:?}\n",
            q(&format!("{} N {}", c.exciter.level, c.band.label)),
            c.band.from_hz,
            c.band.to_hz,
            c.band.steps,
            c.exciter.level
        );
        t
    }

    /// The information of design `r` (prior included).
    pub fn fim(&self, r: &RankedDesign) -> Mat<f64> {
        self.sweeps[r.design.sweep].fim(
            &r.design.channels,
            &r.design.harmonics,
            self.candidates.prior.as_ref(),
        )
    }

    /// The noise floor as the summary states it: the absolute floor, the relative one, and
    /// each channel's resulting floor in its unit.
    fn floor_text(&self) -> String {
        let req = &self.request;
        let mut parts = Vec::new();
        if req.noise.absolute > 0.0 {
            parts.push(format!("{:e} absolute", req.noise.absolute));
        }
        if req.noise_floor > 0.0 {
            parts.push(format!(
                "{:e} of each channel's largest predicted response",
                req.noise_floor
            ));
        }
        let mut text = format!("a floor of {}", parts.join(" or, if larger, "));
        if !self.noise.is_empty() {
            let per: Vec<String> = self
                .candidates
                .channels
                .iter()
                .zip(&self.noise)
                .map(|(c, n)| format!("{c} {:.2e}", n.absolute))
                .collect();
            text.push_str(&format!(" ({})", per.join(", ")));
        }
        text
    }

    /// The readable summary: what was planned, the best designs and the worst, and how much
    /// better the best is.
    pub fn summary(&self) -> Vec<String> {
        let req = &self.request;
        let s = &self.candidates;
        let names: Vec<String> = self.params.iter().map(|p| p.to_string()).collect();
        let mut v = vec![
            format!(
                "planning a test of '{}' for {} (nominal {}); Fisher information from the \
                 analytic harmonic-balance sensitivities, relative units (d/d ln p), noise {} % \
                 + {}{}",
                s.model_name,
                names.join(", "),
                self.nominal
                    .iter()
                    .map(|x| format!("{x:.4e}"))
                    .collect::<Vec<_>>()
                    .join(", "),
                100.0 * req.noise.relative,
                self.floor_text(),
                if s.prior.is_some() {
                    ", prior information added"
                } else {
                    ""
                }
            ),
            format!(
                "{} candidate designs = {} sweeps (drives x levels x signals x bands) x {} \
                 sensor sets x {} harmonic sets, ranked by {}; reduction {:.2} s, sweeps \
                 {:.2} s, ranking {:.2} s",
                self.ranked.len(),
                s.sweeps.len(),
                s.channel_sets.len(),
                s.harmonic_sets.len(),
                criterion_desc(req.criterion),
                self.setup_seconds,
                self.sweep_seconds,
                self.rank_seconds
            ),
        ];
        for (i, sw) in self.sweeps.iter().enumerate() {
            if !sw.failed_hz.is_empty() {
                v.push(format!(
                    "sweep {} ({} at {}): the prediction did not converge at {} of {} steps \
                     (from {:.4} Hz); they add no information",
                    i + 1,
                    s.sweeps[i].band.label,
                    sw.exciter.describe(),
                    sw.failed_hz.len(),
                    sw.band.steps,
                    sw.failed_hz[0]
                ));
            }
        }
        let std_head: Vec<String> = names.iter().map(|n| format!("{n:>14}")).collect();
        v.push(format!(
            "{:>6}  {:<10} {:>9} {:<10} {:<26} {:<16} {:<6} {:>12}  {}  {:>8}  most collinear",
            "rank",
            "drive",
            "level N",
            "signal",
            "band",
            "sensors",
            "harm.",
            req.criterion.as_str(),
            std_head.join(" "),
            "gamma"
        ));
        let n = self.ranked.len();
        for (i, r) in self.ranked.iter().enumerate() {
            if i < req.top || i + 1 == n {
                if i == req.top && n > req.top + 1 {
                    v.push("   ...".into());
                }
                v.push(self.row(i, r));
            }
        }
        if let (Some(b), Some(w)) = (self.ranked.first(), self.ranked.last()) {
            let pct = |x: f64| {
                if x.is_finite() {
                    format!("{:.4} %", 100.0 * x)
                } else {
                    "unidentifiable".into()
                }
            };
            let each: Vec<String> = names
                .iter()
                .enumerate()
                .map(|(j, nm)| {
                    format!(
                        "{nm} {} -> {}",
                        pct(b.summary.std[j]),
                        pct(w.summary.std[j])
                    )
                })
                .collect();
            v.push(format!(
                "Cramér–Rao std (of the nominal value), best design -> worst: {}",
                each.join(", ")
            ));
        }
        for w in &self.warnings {
            v.push(format!("warning: {w}"));
        }
        v
    }

    fn row(&self, i: usize, r: &RankedDesign) -> String {
        let [drive, level, signal, band, sensors, harm] =
            describe_design(&self.candidates, &self.sweeps, r);
        let std: Vec<String> = r
            .summary
            .std
            .iter()
            .map(|s| format!("{:>13.4}%", 100.0 * s))
            .collect();
        let pair = r.summary.most_collinear.map_or(String::new(), |(a, b, c)| {
            format!("{} ~ {} ({c:+.3})", self.params[a], self.params[b])
        });
        format!(
            "{:>6}  {:<10} {:>9} {:<10} {:<26} {:<16} {:<6} {:>12.5e}  {}  {:>8.2}  {}",
            i + 1,
            drive,
            level,
            signal,
            band,
            sensors,
            harm,
            r.summary.value(self.request.criterion),
            std.join(" "),
            r.summary.collinearity,
            pair
        )
    }

    /// Every design, best first: what it is, every criterion, rank, the Cramér–Rao relative
    /// standard deviations and the collinearity.
    pub fn ranking_csv(&self) -> String {
        let params = &self.params;
        let mut s = String::from(
            "rank,sweep,drive,level_n,signal,band,from_hz,to_hz,steps,sensors,harmonics,\
             log_det,trace,trace_inverse,min_eigenvalue,max_variance,fim_rank,collinearity,\
             most_collinear,cosine",
        );
        for p in params {
            let _ = write!(s, ",std_{p}");
        }
        s.push('\n');
        for (i, r) in self.ranked.iter().enumerate() {
            let c = &self.candidates.sweeps[r.design.sweep];
            let [drive, level, signal, _, sensors, harm] =
                describe_design(&self.candidates, &self.sweeps, r);
            let m = &r.summary;
            let (pair, cos) = m
                .most_collinear
                .map_or((String::new(), f64::NAN), |(a, b, c)| {
                    (format!("{}~{}", params[a], params[b]), c)
                });
            let _ = write!(
                s,
                "{},{},{},{},{},{},{:?},{:?},{},{},{},{:?},{:?},{:?},{:?},{:?},{},{:?},{},{:?}",
                i + 1,
                r.design.sweep + 1,
                crate::formats::files::csv_field(&drive),
                level,
                crate::formats::files::csv_field(&signal),
                crate::formats::files::csv_field(&c.band.label),
                c.band.from_hz,
                c.band.to_hz,
                c.band.steps,
                crate::formats::files::csv_field(&sensors),
                harm,
                m.log_det,
                m.trace,
                m.trace_inverse,
                m.min_eigenvalue,
                m.max_variance,
                m.rank,
                m.collinearity,
                pair,
                cos
            );
            for x in &m.std {
                let _ = write!(s, ",{x:?}");
            }
            s.push('\n');
        }
        s
    }
}

fn criterion_desc(c: Criterion) -> &'static str {
    match c {
        Criterion::D => "D-optimality (ln det F, larger is better)",
        Criterion::T => "T-optimality (tr F, larger is better)",
        Criterion::A => "A-optimality (tr F^-1, smaller is better)",
        Criterion::E => "E-optimality (smallest eigenvalue, larger is better)",
        Criterion::MaxVariance => "the largest relative variance max diag F^-1 (smaller is better)",
    }
}

/// Writes the report of `run` into `dir` (created if needed): `summary.txt`,
/// `ranking.csv` (every design), `fim_best.csv` (the best design's information, readable
/// as the `prior` of the next plan), `best_test.toml` (the best design as an `nlsim test`
/// file, [`PlanRun::test_file`]) and plots (SVG and PNG): the criterion along the
/// ranking (`ranking`), the Cramér–Rao standard deviations of the best five designs and
/// the worst (`crb`), and the best design's predicted responses (`best_prediction`).
/// Returns the files written.
pub fn write_plan_report(dir: &Path, run: &PlanRun) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let mut written = Vec::new();
    let mut text = |name: &str, body: String| -> Result<()> {
        let p = dir.join(name);
        write_text(&p, &body)?;
        written.push(p);
        Ok(())
    };
    let report = crate::present::report::Report::create(
        dir,
        &format!("nlsim plan: {}", run.candidates.model_name),
        &crate::present::report::command_line(),
        &run.request.model,
    )?;
    report.model_name(&run.candidates.model_name);
    report.section_with("Summary", &run.summary());
    report.table(
        "ranking",
        crate::present::report::Table::from_csv("Candidate tests, best first", &run.ranking_csv()),
    )?;
    report.section("Figures");
    let mut summary = run.summary().join("\n");
    summary.push('\n');
    text("summary.txt", summary)?;
    text("ranking.csv", run.ranking_csv())?;
    let params = &run.params;
    let Some(best) = run.ranked.first() else {
        written.push(report.finish()?);
        written.push(dir.join(crate::present::report::DATA));
        return Ok(written);
    };
    text("fim_best.csv", fim_csv(params, &run.fim(best)))?;
    text("best_test.toml", run.test_file(best))?;
    let crit = run.request.criterion;
    written.extend(report.figure(
        "ranking",
        &Lines {
            title: format!(
                "{}: {} candidate tests ranked by {}",
                run.candidates.model_name,
                run.ranked.len(),
                crit.as_str()
            ),
            x_desc: "rank".into(),
            y_desc: format!("{} criterion (relative units)", crit.as_str()),
            series: vec![(
                crit.as_str().into(),
                run.ranked
                    .iter()
                    .enumerate()
                    .map(|(i, r)| ((i + 1) as f64, r.summary.value(crit)))
                    .filter(|p| p.1.is_finite())
                    .collect(),
            )],
        },
    )?);
    let mut shown: Vec<&RankedDesign> = run.ranked.iter().take(5).collect();
    if run.ranked.len() > 5 {
        shown.push(run.ranked.last().expect("non-empty"));
    }
    let groups = params
        .iter()
        .enumerate()
        .map(|(j, p)| BarGroup {
            label: p.to_string(),
            values: shown
                .iter()
                .map(|r| {
                    let s = 100.0 * r.summary.std[j];
                    if s.is_finite() { s } else { f64::NAN }
                })
                .collect(),
            band: None,
        })
        .collect();
    written.extend(report.figure(
        "crb",
        &Bars {
            title: format!(
                "{}: Cramér–Rao std of the best {} designs{}",
                run.candidates.model_name,
                shown.len().min(5),
                if run.ranked.len() > 5 {
                    " and the worst (right)"
                } else {
                    ""
                }
            ),
            bar_desc: "design".into(),
            y_desc: "std (% of the nominal value)".into(),
            baseline: 0.0,
            baseline_desc: String::new(),
            band_desc: String::new(),
            groups,
        },
    )?);
    let sw = &run.sweeps[best.design.sweep];
    let freqs = sw.band.frequencies_hz();
    let mut series = Vec::new();
    for &c in &best.design.channels {
        for &h in &best.design.harmonics {
            let k = sw.harmonics[h];
            series.push((
                format!("{} h{k}", sw.channels[c]),
                freqs
                    .iter()
                    .zip(&sw.responses)
                    .filter_map(|(&f, y)| {
                        let v = y[(c, k - 1)].norm();
                        (v.is_finite() && !sw.failed_hz.contains(&f)).then_some((f, v))
                    })
                    .collect(),
            ));
        }
    }
    series.retain(|(_, p): &(String, Vec<(f64, f64)>)| !p.is_empty());
    if !series.is_empty() {
        written.extend(report.figure(
            "best_prediction",
            &Lines {
                title: format!(
                    "{}: predicted responses of the best test ({})",
                    run.candidates.model_name,
                    sw.exciter.describe()
                ),
                x_desc: "frequency (Hz)".into(),
                y_desc: "|response harmonic| (sensor units)".into(),
                series,
            },
        )?);
    }
    written.push(report.finish()?);
    written.push(dir.join(crate::present::report::DATA));
    Ok(written)
}

/// Writes the information of one candidate sweep into a batch job's group: datasets
/// `terms` (channels × harmonics × parameters × parameters, relative units), `failed_hz`
/// and `nominal` (the parameters' values), attributes `exciter` and `band`.
pub(crate) fn write_sweep_group(
    g: &hdf5_metno::Group,
    info: &SweepInformation,
    nominal: &[f64],
) -> hdf5_metno::Result<()> {
    let nc = info.terms.len();
    let nh = info.harmonics.len();
    let np = nominal.len();
    let mut flat = Vec::with_capacity(nc * nh * np * np);
    for c in &info.terms {
        for m in c {
            for i in 0..np {
                for j in 0..np {
                    flat.push(m[(i, j)]);
                }
            }
        }
    }
    let d = g
        .new_dataset::<f64>()
        .shape((nc, nh, np, np))
        .create("terms")?;
    d.write_raw(&flat)?;
    crate::formats::files::str_attr(
        &d,
        "dims",
        "channel x measured harmonic x parameter x parameter (relative units)",
    )?;
    g.new_dataset::<f64>()
        .shape(info.failed_hz.len())
        .create("failed_hz")?
        .write_raw(&info.failed_hz)?;
    g.new_dataset::<f64>()
        .shape(np)
        .create("nominal")?
        .write_raw(nominal)?;
    crate::formats::files::str_attr(g, "exciter", &info.exciter.describe())?;
    crate::formats::files::str_attr(g, "band", &info.band.label)
}

/// Reads back candidate sweep `i` of `c` from a batch job's group (shapes checked against
/// the plan before reading); `None` when the job failed or does not match.
fn read_sweep_group(
    g: &hdf5_metno::Group,
    c: &PlanCandidates,
    i: usize,
    np: usize,
) -> Option<(SweepInformation, Vec<f64>)> {
    if g.attr("ok").and_then(|a| a.read_scalar::<u8>()).ok() != Some(1) {
        return None;
    }
    let (nc, nh) = (c.channels.len(), c.harmonics.len());
    let terms = g.dataset("terms").ok()?;
    if terms.shape() != [nc, nh, np, np] {
        return None;
    }
    let failed = g.dataset("failed_hz").ok()?;
    let nominal = g.dataset("nominal").ok()?;
    let sw = c.sweeps.get(i)?;
    if failed.shape().first().copied().unwrap_or(0) > sw.band.steps || nominal.shape() != [np] {
        return None;
    }
    let flat = terms.read_raw::<f64>().ok()?;
    let mut at = 0;
    let terms = (0..nc)
        .map(|_| {
            (0..nh)
                .map(|_| {
                    let m = Mat::from_fn(np, np, |a, b| flat[at + a * np + b]);
                    at += np * np;
                    m
                })
                .collect()
        })
        .collect();
    Some((
        SweepInformation {
            exciter: sw.exciter.clone(),
            band: sw.band.clone(),
            channels: c.channels.clone(),
            harmonics: c.harmonics.clone(),
            terms,
            responses: Vec::new(),
            failed_hz: failed.read_raw::<f64>().ok()?,
        },
        nominal.read_raw::<f64>().ok()?,
    ))
}

/// The plan of a merged `plan-candidates` batch: every job's sweep read back from `jobs`
/// (`jobs[i]` the group of job `i`) and every design ranked. `Err` names the first job
/// that failed.
pub(crate) fn merged_plan(req: &PlanRequest, jobs: &[hdf5_metno::Group]) -> Result<PlanRun> {
    let t = Instant::now();
    let (_, candidates) = plan_candidates(req)?;
    let np = req.params.len();
    if jobs.len() != candidates.sweeps.len() {
        return Err(Error::Failed(format!(
            "{} jobs for {} candidate sweeps",
            jobs.len(),
            candidates.sweeps.len()
        )));
    }
    let mut sweeps = Vec::with_capacity(jobs.len());
    let mut nominal = Vec::new();
    for (i, g) in jobs.iter().enumerate() {
        let (info, nom) = read_sweep_group(g, &candidates, i, np).ok_or_else(|| {
            Error::Failed(format!(
                "job {i} (sweep {}) failed or does not match the plan; rerun its shard",
                i + 1
            ))
        })?;
        sweeps.push(info);
        nominal = nom;
    }
    let setup_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let ranked = rank(&candidates, &sweeps, req.criterion)?;
    Ok(PlanRun {
        request: req.clone(),
        candidates,
        params: req.params.clone(),
        nominal,
        setup_seconds,
        sweeps,
        ranked,
        sweep_seconds: 0.0,
        rank_seconds: t.elapsed().as_secs_f64(),
        // The shards computed these; the merge does not reduce the model again.
        peaks: Vec::new(),
        noise: Vec::new(),
        warnings: Vec::new(),
    })
}

/// Writes the ranking of a merged plan into `out`: group `ranking` with, per design best
/// first, `sweep` (job index), `value` (of the criterion, attribute `criterion`),
/// `log_det`, `collinearity` and `std` (designs × parameters, relative).
pub(crate) fn write_ranking(out: &hdf5_metno::Group, run: &PlanRun) -> hdf5_metno::Result<()> {
    let g = out.create_group("ranking")?;
    crate::formats::files::str_attr(&g, "criterion", run.request.criterion.as_str())?;
    let names: Vec<String> = run.params.iter().map(|p| p.to_string()).collect();
    crate::formats::files::str_attr(&g, "parameters", &names.join(","))?;
    let n = run.ranked.len();
    let sweep: Vec<u64> = run.ranked.iter().map(|r| r.design.sweep as u64).collect();
    g.new_dataset::<u64>()
        .shape(n)
        .create("sweep")?
        .write_raw(&sweep)?;
    let crit = run.request.criterion;
    for (name, f) in [
        (
            "value",
            &(|r: &RankedDesign| r.summary.value(crit)) as &dyn Fn(&RankedDesign) -> f64,
        ),
        ("log_det", &|r: &RankedDesign| r.summary.log_det),
        ("collinearity", &|r: &RankedDesign| r.summary.collinearity),
    ] {
        let v: Vec<f64> = run.ranked.iter().map(f).collect();
        g.new_dataset::<f64>()
            .shape(n)
            .create(name)?
            .write_raw(&v)?;
    }
    let np = run.params.len();
    let std: Vec<f64> = run
        .ranked
        .iter()
        .flat_map(|r| r.summary.std.iter().copied())
        .collect();
    g.new_dataset::<f64>()
        .shape((n, np))
        .create("std")?
        .write_raw(&std)?;
    Ok(())
}
