//! `nlsim backbone`: the amplitude-dependent natural frequency and damping ratio of one mode
//! from measured data ([`nlsim_calib::backbone`]) — free decays in time records (ring-downs,
//! the tail after a burst or a shaker cut-off), or stepped sines and phase-resonance dwells
//! in test data — written as a table (CSV or HDF5) with standard deviations and plotted
//! against the amplitude. The layouts are in `docs/file-formats.md`, the method in
//! `docs/calibration.md`.

use crate::error::{Error, Result};
use crate::formats::files::Format;
use crate::formats::test_data::DataOptions;
use faer::c64;
use nlsim_calib::backbone::{
    BackbonePoint, Decay, DecayConfig, LevelStep, Resonance, ResonanceConfig, StepLevel,
    identify_decay, identify_resonance,
};
use nlsim_kernel::Quantity;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Output formats of `nlsim backbone --out`.
pub const HINT: &str = ".csv (one row per point) or .h5 (HDF5, one group per method)";

/// What the input holds.
#[derive(Debug, Clone)]
pub enum Source {
    /// Free decays in time records: the channels (columns) read and, with more than one,
    /// the weights of the mode's shape that combine them into one modal signal
    /// `q = Σ w_c y_c / Σ w_c²`.
    Decay {
        /// Record columns.
        channels: Vec<String>,
        /// One weight per channel (empty: a single channel, weight 1).
        shape: Vec<f64>,
        /// What the channels measure (`None`: not stated; no displacement column).
        quantity: Option<Quantity>,
        /// The identification's settings.
        config: DecayConfig,
    },
    /// Stepped sines or phase-resonance dwells in test data: one level per sweep.
    Stepped {
        /// The response channel (default: the data's only channel).
        channel: Option<String>,
        /// Sweeps taken (patterns as in `train`; empty: all).
        sweeps: Vec<String>,
        /// Added to every response phase (degrees), the data's convention.
        phase_offset_deg: f64,
        /// The identification's settings (the quantity is the channel's).
        config: ResonanceConfig,
    },
}

/// A backbone identification (the options of `nlsim backbone`).
#[derive(Debug, Clone)]
pub struct BackboneRequest {
    /// The input file.
    pub input: PathBuf,
    /// What it holds and how it is read.
    pub source: Source,
    /// The table written (.csv or .h5).
    pub out: Option<PathBuf>,
    /// The plots: FILE.svg (frequency) and FILE-damping.svg.
    pub plot: Option<PathBuf>,
}

/// One method's curve.
#[derive(Debug, Clone)]
pub struct Curve {
    /// The method's name as written (`hilbert`, `fit`, `phase_resonance`, `level_fit`).
    pub method: &'static str,
    /// The points.
    pub points: Vec<BackbonePoint>,
}

/// The outcome: curves, the quantity of their amplitude, summary lines and checks.
#[derive(Debug, Clone)]
pub struct BackboneRun {
    /// The curves.
    pub curves: Vec<Curve>,
    /// What the amplitude is (`None`: unstated, or a modal combination).
    pub quantity: Option<Quantity>,
    /// The amplitude's unit as written.
    pub unit: String,
    /// Summary lines (settings and what was found).
    pub summary: Vec<String>,
    /// Where the data break the method's assumptions.
    pub checks: Vec<String>,
}

fn unit_of(q: Option<Quantity>) -> String {
    q.map_or_else(
        || "sensor unit".into(),
        |q| crate::formats::files::unit(q).into(),
    )
}

/// Runs the identification (no files written).
pub fn run(req: &BackboneRequest) -> Result<BackboneRun> {
    match &req.source {
        Source::Decay {
            channels,
            shape,
            quantity,
            config,
        } => run_decay(&req.input, channels, shape, *quantity, config),
        Source::Stepped {
            channel,
            sweeps,
            phase_offset_deg,
            config,
        } => run_stepped(
            &req.input,
            channel.as_deref(),
            sweeps,
            *phase_offset_deg,
            config,
        ),
    }
}

fn run_decay(
    path: &Path,
    channels: &[String],
    shape: &[f64],
    quantity: Option<Quantity>,
    config: &DecayConfig,
) -> Result<BackboneRun> {
    let rec = crate::commands::records::read_any(path)?;
    let cols: Vec<usize> = if channels.is_empty() {
        if rec.names.len() != 1 {
            return Err(Error::Usage(format!(
                "{}: {} signals ({}): name the decay's with --channel",
                path.display(),
                rec.names.len(),
                rec.names.join(", ")
            )));
        }
        vec![0]
    } else {
        channels
            .iter()
            .map(|c| {
                rec.names.iter().position(|n| n == c).ok_or_else(|| {
                    Error::Usage(format!(
                        "{}: no column '{c}' (it has: {})",
                        path.display(),
                        rec.names.join(", ")
                    ))
                })
            })
            .collect::<Result<_>>()?
    };
    if !shape.is_empty() && shape.len() != cols.len() {
        return Err(Error::Usage(format!(
            "--shape gives {} weights for {} channels: one weight per --channel, in order",
            shape.len(),
            cols.len()
        )));
    }
    if cols.len() > 1 && shape.is_empty() {
        return Err(Error::Usage(
            "several channels need the mode's shape at them (--shape, one weight each) to \
             combine them into one modal signal"
                .into(),
        ));
    }
    let weights: Vec<f64> = if shape.is_empty() {
        vec![1.0]
    } else {
        shape.to_vec()
    };
    let norm: f64 = weights.iter().map(|w| w * w).sum();
    if !(norm.is_finite() && norm > 0.0) {
        return Err(Error::Usage(format!(
            "--shape {weights:?}: the weights must be finite and not all zero"
        )));
    }
    for &c in &cols {
        crate::commands::records::check_clipping(&rec.names[c], &rec.columns[c], &rec, path)?;
    }
    let n = rec.columns[cols[0]].len();
    let signal: Vec<f64> = (0..n)
        .map(|i| {
            cols.iter()
                .zip(&weights)
                .map(|(&c, w)| w * rec.columns[c][i])
                .sum::<f64>()
                / norm
        })
        .collect();
    let mut cfg = config.clone();
    // The start is given on the records' clock.
    if let Some(t) = cfg.start_s {
        cfg.start_s = Some(t - rec.start_s);
    }
    let d = identify_decay(&signal, rec.rate_hz, &cfg)
        .map_err(|e| Error::Usage(format!("{}: {e}", path.display())))?;
    let combined = cols.len() > 1;
    let quantity = if combined { None } else { quantity };
    let what = if combined {
        format!(
            "modal signal of {} (weights {:?})",
            cols.iter()
                .map(|&c| rec.names[c].as_str())
                .collect::<Vec<_>>()
                .join(", "),
            weights
        )
    } else {
        format!("'{}'", rec.names[cols[0]])
    };
    let mut summary = vec![format!(
        "free decay of {what}: {n} samples at {} Hz",
        fmt_num(rec.rate_hz)
    )];
    summary.extend(decay_lines(&d, rec.start_s, rec.rate_hz));
    Ok(BackboneRun {
        curves: vec![
            Curve {
                method: "hilbert",
                points: shift(d.hilbert.clone(), rec.start_s),
            },
            Curve {
                method: "fit",
                points: shift(d.fit.clone(), rec.start_s),
            },
        ],
        quantity,
        unit: if combined {
            "modal unit".into()
        } else {
            unit_of(quantity)
        },
        summary,
        checks: d.checks.clone(),
    })
}

/// Points' times on the records' clock.
fn shift(mut p: Vec<BackbonePoint>, start: f64) -> Vec<BackbonePoint> {
    p.iter_mut().for_each(|p| p.time_s += start);
    p
}

fn fmt_num(v: f64) -> String {
    let s = format!("{v:.6}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

fn decay_lines(d: &Decay, start: f64, rate: f64) -> Vec<String> {
    let f = &d.filter;
    let mut l = vec![
        format!(
            "  band pass {:.4}–{:.4} Hz (Butterworth, order {} per edge, forward and backward; \
             noise bandwidth {:.4} Hz) around {:.4} Hz",
            f.low_hz, f.high_hz, f.order, f.noise_bandwidth_hz, d.centre_hz
        ),
        format!(
            "  analysed {:.4}–{:.4} s (filter transients trimmed); in-band noise {:.3e}, \
             floor {:.3e}: {} windows below it dropped",
            start + d.samples.0 as f64 / rate,
            start + d.samples.1 as f64 / rate,
            d.noise,
            d.floor,
            d.below_floor
        ),
    ];
    if let (Some(a), Some(b)) = (d.fit.first(), d.fit.last()) {
        l.push(format!(
            "  {} points: amplitude {:.4e} → {:.4e}, frequency {:.5} → {:.5} Hz, damping \
             ratio {:.4e} → {:.4e}",
            d.fit.len(),
            a.amplitude,
            b.amplitude,
            a.frequency_hz,
            b.frequency_hz,
            a.damping_ratio,
            b.damping_ratio
        ));
    }
    l
}

fn run_stepped(
    path: &Path,
    channel: Option<&str>,
    sweeps: &[String],
    phase_offset_deg: f64,
    config: &ResonanceConfig,
) -> Result<BackboneRun> {
    let options = DataOptions {
        phase_offset_deg,
        ..DataOptions::default()
    };
    let data = crate::formats::test_data::read_standalone(path, "drive", &options)?;
    let data = if sweeps.is_empty() {
        data
    } else {
        crate::formats::test_data::select_sweeps(&data, sweeps, "--sweeps")?
    };
    let c = match channel {
        Some(name) => data
            .channels
            .iter()
            .position(|c| c.name == name)
            .ok_or_else(|| {
                Error::Usage(format!(
                    "{}: no channel '{name}' (it has: {})",
                    path.display(),
                    names(&data)
                ))
            })?,
        None if data.channels.len() == 1 => 0,
        None => {
            return Err(Error::Usage(format!(
                "{}: {} channels ({}): name the response with --channel",
                path.display(),
                data.channels.len(),
                names(&data)
            )));
        }
    };
    let quantity = data.channels[c].quantity;
    let levels: Vec<StepLevel> = data
        .sweeps
        .iter()
        .map(|s| StepLevel {
            label: s.label.clone(),
            steps: s
                .steps
                .iter()
                .map(|st| {
                    let r = st.response[(c, 0)];
                    // Measured per-step deviations only; a noise model the file does not
                    // carry (tables) is not evidence.
                    let sigma = if st.sigma.nrows() > c && st.sigma.ncols() > 0 {
                        let s = st.sigma[(c, 0)];
                        (0.5 * (s.re * s.re + s.im * s.im)).sqrt() / r.norm()
                    } else {
                        f64::NAN
                    };
                    LevelStep {
                        frequency_hz: st.frequency_hz,
                        force: st.force.first().copied().unwrap_or(c64::new(f64::NAN, 0.0)),
                        response: r,
                        sigma,
                    }
                })
                .collect(),
        })
        .collect();
    let mut cfg = config.clone();
    cfg.quantity = quantity;
    let r = identify_resonance(&levels, &cfg)
        .map_err(|e| Error::Usage(format!("{}: {e}", path.display())))?;
    let mut summary = vec![format!(
        "stepped sines of '{}' ({}): {} levels, phase offset {phase_offset_deg}°",
        data.channels[c].name,
        quantity.as_str(),
        levels.len()
    )];
    summary.extend(resonance_lines(&r, quantity));
    let mut checks = r.checks.clone();
    checks.extend(
        r.levels
            .iter()
            .filter(|l| !l.note.is_empty())
            .map(|l| format!("{}: {}", l.label, l.note)),
    );
    let pr: Vec<BackbonePoint> = r
        .levels
        .iter()
        .filter_map(|l| l.phase_resonance.clone())
        .collect();
    let lf: Vec<BackbonePoint> = r
        .levels
        .iter()
        .filter_map(|l| {
            let f = l.fit.as_ref()?;
            let p = l.phase_resonance.as_ref();
            Some(BackbonePoint {
                time_s: f64::NAN,
                level: l.label.clone(),
                amplitude: p.map_or(f64::NAN, |p| p.amplitude),
                amplitude_sigma: p.map_or(f64::NAN, |p| p.amplitude_sigma),
                frequency_hz: f.frequency_hz.0,
                frequency_sigma_hz: f.frequency_hz.1,
                damping_ratio: f.damping_ratio.0,
                damping_sigma: f.damping_ratio.1,
                force: p.map_or(f64::NAN, |p| p.force),
            })
        })
        .collect();
    Ok(BackboneRun {
        curves: vec![
            Curve {
                method: "phase_resonance",
                points: pr,
            },
            Curve {
                method: "level_fit",
                points: lf,
            },
        ],
        quantity: Some(quantity),
        unit: unit_of(Some(quantity)),
        summary,
        checks,
    })
}

fn names(data: &nlsim_calib::TestData) -> String {
    data.channels
        .iter()
        .map(|c| c.name.as_str())
        .collect::<Vec<_>>()
        .join(", ")
}

fn resonance_lines(r: &Resonance, q: Quantity) -> Vec<String> {
    let u = crate::formats::files::unit(q);
    let (k, ks) = r.modal_constant;
    let mut l = vec![format!(
        "  modal constant {k:.5e} ± {ks:.2e} 1/kg ({})",
        if r.modal_constant_given {
            "given"
        } else {
            "mean of the level fits"
        }
    )];
    l.push(format!(
        "  {:<14} {:>12} {:>10} {:>18} {:>20} {:>18} {:>20}",
        "level",
        format!("ampl. ({u})"),
        "force (N)",
        "f at −90° (Hz)",
        "ζ energy balance",
        "f level fit (Hz)",
        "ζ level fit"
    ));
    for lv in &r.levels {
        let p = lv.phase_resonance.as_ref();
        let f = lv.fit.as_ref();
        let pm = |v: Option<(f64, f64)>, w: usize, d: usize| match v {
            Some((a, b)) => format!("{:>w$}", format!("{a:.d$} ± {b:.d$}")),
            None => format!("{:>w$}", "—"),
        };
        l.push(format!(
            "  {:<14} {:>12} {:>10} {} {} {} {}",
            lv.label,
            p.map_or("—".into(), |p| format!("{:.4}", p.amplitude)),
            p.map_or("—".into(), |p| format!("{:.4}", p.force)),
            pm(p.map(|p| (p.frequency_hz, p.frequency_sigma_hz)), 18, 4),
            pm(p.map(|p| (p.damping_ratio, p.damping_sigma)), 20, 5),
            pm(f.map(|f| f.frequency_hz), 18, 4),
            pm(f.map(|f| f.damping_ratio), 20, 5),
        ));
    }
    l
}

/// Writes the curves: CSV or HDF5 by extension, atomically.
pub fn write(path: &Path, run: &BackboneRun, req: &BackboneRequest) -> Result<()> {
    crate::formats::files::write_atomically(path, HINT, |tmp, format| match format {
        Format::Csv => write_csv(tmp, run, req),
        #[cfg(feature = "hdf5")]
        Format::Hdf5 => write_hdf5(tmp, run, req),
        #[cfg(not(feature = "hdf5"))]
        Format::Hdf5 => Err(crate::formats::files::without_hdf5(path)),
        Format::Uff => Err(Error::Usage(format!(
            "{}: universal files are not written by `backbone`; name the file {HINT}",
            path.display()
        ))),
    })
}

/// The columns of a row, in the order written.
const COLUMNS: [&str; 11] = [
    "amplitude",
    "amplitude_sigma",
    "displacement_m",
    "frequency_hz",
    "frequency_sigma_hz",
    "damping_ratio",
    "damping_sigma",
    "force_n",
    "time_s",
    "level",
    "method",
];

fn row(p: &BackbonePoint, q: Option<Quantity>) -> [f64; 9] {
    [
        p.amplitude,
        p.amplitude_sigma,
        q.map_or(f64::NAN, |q| p.displacement(q)),
        p.frequency_hz,
        p.frequency_sigma_hz,
        p.damping_ratio,
        p.damping_sigma,
        p.force,
        p.time_s,
    ]
}

fn write_csv(path: &Path, run: &BackboneRun, req: &BackboneRequest) -> Result<()> {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# nlsim {} backbone of {}: amplitude of the fundamental in {}; frequency: the \
         equivalent linear oscillator's undamped natural frequency; sigma: standard deviations",
        env!("CARGO_PKG_VERSION"),
        req.input.display(),
        run.unit
    );
    for line in &run.summary {
        let _ = writeln!(s, "# {}", line.trim());
    }
    s.push_str(&COLUMNS.join(","));
    s.push('\n');
    for c in &run.curves {
        for p in &c.points {
            for v in row(p, run.quantity) {
                let _ = write!(s, "{v:.10e},");
            }
            let _ = writeln!(s, "{},{}", p.level, c.method);
        }
    }
    std::fs::write(path, s).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(feature = "hdf5")]
fn write_hdf5(path: &Path, run: &BackboneRun, req: &BackboneRequest) -> Result<()> {
    use crate::formats::files::str_attr;
    use hdf5_metno as hdf5;
    let err = crate::formats::files::h5err(path);
    let file = hdf5::File::create(path).map_err(&err)?;
    let root = file.as_group().map_err(&err)?;
    (|| -> hdf5::Result<()> {
        crate::formats::files::provenance(&root, "backbone", "", "", None)?;
        str_attr(&root, "input", &req.input.to_string_lossy())?;
        str_attr(&root, "amplitude_unit", &run.unit)?;
        str_attr(&root, "summary", &run.summary.join("\n"))?;
        str_attr(&root, "checks", &run.checks.join("\n"))?;
        let units = ["", "", "m", "Hz", "Hz", "1", "1", "N", "s"];
        for c in &run.curves {
            let g = root.create_group(c.method)?;
            let rows: Vec<[f64; 9]> = c.points.iter().map(|p| row(p, run.quantity)).collect();
            for (k, name) in COLUMNS[..9].iter().enumerate() {
                let data: Vec<f64> = rows.iter().map(|r| r[k]).collect();
                let d = g.new_dataset_builder().with_data(&data).create(*name)?;
                let u = if k < 2 { run.unit.as_str() } else { units[k] };
                str_attr(&d, "unit", u)?;
            }
            let labels: Vec<hdf5::types::VarLenUnicode> = c
                .points
                .iter()
                .map(|p| {
                    p.level
                        .parse()
                        .unwrap_or_else(|_| "?".parse().expect("ascii"))
                })
                .collect();
            g.new_dataset_builder().with_data(&labels).create("level")?;
        }
        Ok(())
    })()
    .map_err(&err)?;
    file.flush().map_err(&err)?;
    Ok(())
}

/// The plots against log10 of the amplitude: frequency and damping ratio, one series per
/// method and its ±σ band edges.
pub fn plots(run: &BackboneRun, req: &BackboneRequest) -> [crate::present::plot::Lines; 2] {
    let name = req
        .input
        .file_name()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    let x_desc = format!("log10 amplitude ({})", run.unit);
    let series = |f: &dyn Fn(&BackbonePoint) -> (f64, f64)| -> Vec<(String, Vec<(f64, f64)>)> {
        let mut out = Vec::new();
        for c in &run.curves {
            let mut pts: Vec<&BackbonePoint> = c.points.iter().collect();
            pts.sort_by(|a, b| a.amplitude.total_cmp(&b.amplitude));
            let line = |s: f64| -> Vec<(f64, f64)> {
                pts.iter()
                    .map(|p| {
                        let (v, sd) = f(p);
                        (p.amplitude.log10(), v + s * sd)
                    })
                    .collect()
            };
            out.push((c.method.to_string(), line(0.0)));
            out.push((format!("{} + σ", c.method), line(1.0)));
            out.push((format!("{} − σ", c.method), line(-1.0)));
        }
        out
    };
    [
        crate::present::plot::Lines {
            title: format!("{name}: backbone"),
            x_desc: x_desc.clone(),
            y_desc: "natural frequency (Hz)".into(),
            series: series(&|p| (p.frequency_hz, p.frequency_sigma_hz)),
        },
        crate::present::plot::Lines {
            title: format!("{name}: damping"),
            x_desc,
            y_desc: "damping ratio (1)".into(),
            series: series(&|p| (p.damping_ratio, p.damping_sigma)),
        },
    ]
}

/// `nlsim backbone INPUT`: reads, identifies, prints the summary and the checks, writes the
/// table and the plots.
pub fn execute(req: &BackboneRequest, console: &crate::present::console::Console) -> Result<()> {
    if let Some(path) = &req.out {
        Format::of(path, HINT)?;
    }
    let plot_path = req
        .plot
        .clone()
        .or_else(|| req.out.as_ref().map(|p| p.with_extension("svg")));
    let damping_path = plot_path
        .as_ref()
        .map(|p| crate::present::plot::companion(p, "damping"));
    if let Some(p) = &plot_path {
        crate::present::plot::check_path(p)?;
    }
    crate::formats::files::check_outputs(
        &[Some(req.input.as_path())],
        &[
            req.out.as_deref(),
            plot_path.as_deref(),
            damping_path.as_deref(),
        ],
        &[],
    )?;
    let run = run(req)?;
    for line in &run.summary {
        console.say(line);
    }
    for c in &run.checks {
        console.note(&format!("check: {c}"));
    }
    if run.curves.iter().all(|c| c.points.is_empty()) {
        return Err(Error::Failed(format!(
            "{}: no backbone point could be identified (see the checks above)",
            req.input.display()
        )));
    }
    if let Some(path) = &req.out {
        write(path, &run, req)?;
        console.say(&format!("  written to {}", path.display()));
    }
    if let (Some(p), Some(dp)) = (plot_path, damping_path) {
        let [freq, damping] = plots(&run, req);
        crate::present::plot::write(&p, &freq)?;
        crate::present::plot::write(&dp, &damping)?;
        console.say(&format!("  plots {} and {}", p.display(), dp.display()));
    }
    Ok(())
}
