//! `nlsim harmonics`: the time histories a test lab records during a stepped sine turned
//! into nlsim's stepped-sine test data (thesis §4.2): the dwells found from a step table or
//! from the drive's frequency, each dwell's transient found and left out, the drive and
//! response harmonics `1..=H` fitted by least squares on a whole number of periods at the
//! refined frequency ([`nlsim_calib::extract_dwell`]), and each harmonic's standard
//! deviation from the period-to-period scatter written as the step's noise. With a sweep
//! request the records hold slow sine sweeps instead, and the harmonics are tracked along
//! each ([`nlsim_calib::track_sweep`]), with a warning where the sweep is too fast for the
//! damping of a mode it passes.

use crate::error::{Error, Result};
use crate::formats::time_records::{StepRow, TimeRecords};
use faer::{Mat, c64};
use nlsim_calib::{
    Channel, Drive, DwellConfig, Noise, Step, Sweep, SweepDirection, TestData, TrackConfig,
    detect_steps, extract_dwell, sweep_rate_parameter, track_sweep,
};
use std::path::PathBuf;

/// Relative floor of every written standard deviation: a millionth of the channel's largest
/// fundamental over the record (a 24-bit recorder's range is about 1e-7 of full scale), so
/// that noise-free records do not weigh a calibration without bound.
pub const SIGMA_FLOOR: f64 = 1e-6;

/// What `nlsim harmonics` does.
#[derive(Debug, Clone)]
pub struct HarmonicsRequest {
    /// The model (file or built-in name): its sensors name the channels and give their
    /// quantities, its first excitation names the drive.
    pub model: String,
    /// The time histories (CSV).
    pub records: PathBuf,
    /// The step table (CSV); `None`: steps found from the drive.
    pub steps: Option<PathBuf>,
    /// The drive's column [default: the model's first excitation].
    pub drive: Option<String>,
    /// What the drive column holds: force (N) or the amplifier's voltage (V).
    pub record: Drive,
    /// Dwell settings (harmonics, steady-state tolerance, fewest periods, refinement).
    pub dwell: DwellConfig,
    /// Relative frequency change that starts a new step when steps are found from the drive.
    pub step_tolerance: f64,
    /// `Some`: the records hold sine sweeps, tracked with these settings (the whole record,
    /// or each row of the step table, one sweep); `None`: dwells.
    pub sweep: Option<TrackConfig>,
    /// The test data written (.csv or .h5).
    pub out: PathBuf,
}

/// One dwell's outcome, for the summary.
#[derive(Debug, Clone)]
pub struct DwellLine {
    /// Sweep label.
    pub sweep: String,
    /// The refined frequency (Hz).
    pub frequency_hz: f64,
    /// Where it came from: `line N` of the step table or `samples A–B`.
    pub origin: String,
    /// Whole periods fitted.
    pub periods: usize,
    /// Periods discarded as the transient.
    pub unsettled: usize,
    /// What is left of the transient.
    pub drift: f64,
    /// Whether it was kept.
    pub kept: bool,
}

/// One tracked sweep's outcome, for the summary.
#[derive(Debug, Clone)]
pub struct TrackLine {
    /// Sweep label.
    pub sweep: String,
    /// Where it came from: `line N` of the step table or `samples A–B`.
    pub origin: String,
    /// Points tracked.
    pub points: usize,
    /// Lowest and highest frequency tracked (Hz).
    pub band_hz: (f64, f64),
    /// Largest `|ṙ|` along it (Hz/s).
    pub rate_hz_per_s: f64,
    /// The mode the sweep passes fastest for its damping: `(mode number, f_r Hz, ζ_r, η)`
    /// ([`nlsim_calib::sweep_rate_parameter`]); `None` when it passes no mode of the model.
    pub worst_mode: Option<(usize, f64, f64, f64)>,
}

/// A sweep whose sweep-rate parameter `η` exceeds this at a mode it passes is too fast: its
/// tracked response there is off by more than about 1 % ([`nlsim_calib::sweep_bias`]).
pub const ETA_WARN: f64 = 1e-2;

/// Modes looked at for the sweep-rate check (the lowest ones of the model).
const CHECKED_MODES: usize = 30;

/// The outcome of [`run`].
#[derive(Debug, Clone)]
pub struct HarmonicsRun {
    /// The test data.
    pub data: TestData,
    /// Every dwell, kept or left out (none for sweeps).
    pub dwells: Vec<DwellLine>,
    /// Every tracked sweep (none for dwells).
    pub tracks: Vec<TrackLine>,
    /// Sampling rate of the records (Hz).
    pub rate_hz: f64,
}

/// A dwell to fit: samples `start..end`, a frequency if known, its sweep, where it came from.
struct Window {
    start: usize,
    end: usize,
    frequency_hz: Option<f64>,
    sweep: String,
    origin: String,
}

fn windows_from_table(
    rows: &[StepRow],
    rec: &TimeRecords,
    table: &std::path::Path,
) -> Result<Vec<Window>> {
    let n = rec.columns[0].len();
    let last = rec.start_s + (n - 1) as f64 / rec.rate_hz;
    rows.iter()
        .map(|r| {
            let at = |t: f64| ((t - rec.start_s) * rec.rate_hz).round();
            let (s, e) = (at(r.start_s), at(r.end_s));
            if s < 0.0 || e > (n - 1) as f64 {
                return Err(Error::DataFile {
                    file: table.to_path_buf(),
                    line: r.line,
                    message: format!(
                        "the step {}–{} s reaches outside the record ({}–{last} s)",
                        r.start_s, r.end_s, rec.start_s
                    ),
                });
            }
            Ok(Window {
                start: s as usize,
                end: e as usize + 1,
                frequency_hz: r.frequency_hz,
                sweep: r.sweep.clone(),
                origin: format!("{}:{}", table.display(), r.line),
            })
        })
        .collect()
}

/// Reads the records, fits every dwell, and assembles the test data (nothing written).
pub fn run(req: &HarmonicsRequest) -> Result<HarmonicsRun> {
    let loaded = crate::load_model(&req.model)?;
    let model = &loaded.model;
    let crate::commands::records::MappedRecords {
        records: rec,
        drive,
        drive_column: d,
        channels,
        columns,
    } = crate::commands::records::map_records(
        model,
        &req.model,
        &req.records,
        req.drive.as_deref(),
        req.record == Drive::Voltage,
    )?;
    let windows = match &req.steps {
        Some(table) => {
            let rows = crate::formats::time_records::read_step_table(table)?;
            windows_from_table(&rows, &rec, table)?
        }
        None if req.sweep.is_some() => vec![Window {
            start: 0,
            end: rec.columns[d].len(),
            frequency_hz: None,
            sweep: "sweep1".into(),
            origin: format!("samples 1–{}", rec.columns[d].len()),
        }],
        None => {
            let found = detect_steps(&rec.columns[d], rec.rate_hz, req.step_tolerance);
            if found.is_empty() {
                return Err(Error::Usage(format!(
                    "{}: no dwell of 3 periods or more found in the drive '{drive}'; give the \
                     steps with --steps TABLE",
                    req.records.display()
                )));
            }
            sweeps_of(&found)
                .into_iter()
                .map(|(label, w)| Window {
                    start: w.start,
                    end: w.end,
                    frequency_hz: Some(w.frequency_hz),
                    sweep: label,
                    origin: format!("samples {}–{}", w.start + 1, w.end),
                })
                .collect()
        }
    };
    let names: Vec<&str> = columns.iter().map(|&j| rec.names[j].as_str()).collect();
    let h = req.dwell.harmonics;
    let mut dwells = Vec::new();
    let mut tracks = Vec::new();
    let mut steps: Vec<(String, Step)> = Vec::new();
    if let Some(cfg) = &req.sweep {
        let modes = mode_table(model, &drive)?;
        for w in &windows {
            let signals: Vec<&[f64]> = columns
                .iter()
                .map(|&j| &rec.columns[j][w.start..w.end])
                .collect();
            let track = track_sweep(&names, &signals, rec.rate_hz, cfg).map_err(|e| {
                Error::Usage(format!(
                    "{}: sweep at {}: {e}",
                    req.records.display(),
                    w.origin
                ))
            })?;
            tracks.push(track_line(w, &track, &modes));
            let nc = channels.len();
            for p in &track.points {
                steps.push((
                    w.sweep.clone(),
                    Step {
                        frequency_hz: p.frequency_hz,
                        force: (0..cfg.harmonics).map(|k| p.harmonics[(0, k)]).collect(),
                        response: Mat::from_fn(nc, cfg.harmonics, |c, k| p.harmonics[(c + 1, k)]),
                        sigma: with_drive_noise(&p.harmonics, &p.sigma, nc, cfg.harmonics),
                    },
                ));
            }
        }
    }
    for w in windows.iter().filter(|_| req.sweep.is_none()) {
        let signals: Vec<&[f64]> = columns
            .iter()
            .map(|&j| &rec.columns[j][w.start..w.end])
            .collect();
        let fit = extract_dwell(&names, &signals, rec.rate_hz, w.frequency_hz, &req.dwell)
            .map_err(|e| {
                Error::Usage(format!(
                    "{}: step at {}: {e}",
                    req.records.display(),
                    w.origin
                ))
            })?;
        dwells.push(DwellLine {
            sweep: w.sweep.clone(),
            frequency_hz: fit.frequency_hz,
            origin: w.origin.clone(),
            periods: fit.periods,
            unsettled: fit.unsettled_periods,
            drift: fit.drift,
            kept: fit.settled,
        });
        if !fit.settled {
            continue;
        }
        let nc = channels.len();
        steps.push((
            w.sweep.clone(),
            Step {
                frequency_hz: fit.frequency_hz,
                force: (0..h).map(|k| fit.harmonics[(0, k)]).collect(),
                response: Mat::from_fn(nc, h, |c, k| fit.harmonics[(c + 1, k)]),
                sigma: with_drive_noise(&fit.harmonics, &fit.sigma, nc, h),
            },
        ));
    }
    if steps.is_empty() && req.sweep.is_some() {
        return Err(Error::Failed(format!(
            "{}: no point could be tracked; nothing to write",
            req.records.display()
        )));
    }
    if steps.is_empty() {
        return Err(Error::Failed(format!(
            "{}: none of the {} dwells settled; nothing to write (lower --min-periods, or \
             record longer dwells)",
            req.records.display(),
            windows.len()
        )));
    }
    // The floor of the standard deviations, per channel.
    let floors: Vec<f64> = (0..channels.len())
        .map(|c| {
            SIGMA_FLOOR
                * steps
                    .iter()
                    .map(|(_, s)| s.response[(c, 0)].norm())
                    .fold(0.0, f64::max)
        })
        .collect();
    for (_, s) in &mut steps {
        for c in 0..channels.len() {
            for k in 0..h {
                let v = s.sigma[(c, k)];
                s.sigma[(c, k)] = if v.re.is_nan() {
                    v
                } else {
                    c64::new(v.re.max(floors[c]), v.im.max(floors[c]))
                };
            }
        }
    }
    let mut sweeps: Vec<Sweep> = Vec::new();
    for (label, step) in steps {
        match sweeps.iter_mut().find(|s| s.label == label) {
            Some(s) => s.steps.push(step),
            None => sweeps.push(Sweep {
                label,
                direction: SweepDirection::Up,
                steps: vec![step],
            }),
        }
    }
    for s in &mut sweeps {
        let f: Vec<f64> = s.steps.iter().map(|st| st.frequency_hz).collect();
        let up = f.windows(2).all(|w| w[1] > w[0]);
        let down = f.windows(2).all(|w| w[1] < w[0]);
        s.direction = match (up, down) {
            (true, _) => SweepDirection::Up,
            (false, true) => SweepDirection::Down,
            _ => {
                return Err(Error::Usage(format!(
                    "sweep '{}': its steps' frequencies neither rise nor fall throughout \
                     ({}); give each direction its own sweep label in the step table",
                    s.label,
                    f.iter()
                        .map(|v| format!("{v:.4}"))
                        .collect::<Vec<_>>()
                        .join(", ")
                )));
            }
        };
    }
    let data = TestData {
        input: drive,
        drive: req.record,
        channels: channels
            .iter()
            .zip(&floors)
            .map(|((name, quantity), &floor)| Channel {
                name: name.clone(),
                quantity: *quantity,
                noise: Noise {
                    absolute: floor,
                    relative: 0.0,
                },
            })
            .collect(),
        harmonics: h,
        sweeps,
    };
    Ok(HarmonicsRun {
        data,
        dwells,
        tracks,
        rate_hz: rec.rate_hz,
    })
}

/// The responses' standard deviations (`nc` channels × `h` harmonics, rows `1..` of `sigma`)
/// with the drive's own noise folded in (the effective variance of errors in the input): the
/// calibration takes the measured drive harmonics as exact, so a response predicted from a
/// drive fundamental off by `δF₁` is off by about `Y_k δF₁/F₁`; with `r² = var(F₁)/|F₁|²`
/// from the drive's scatter, each of the real and imaginary parts gains the variance
/// `|Y_k|² r²/2`. Nothing changes for an exact drive (a generator's voltage). The noise of
/// the drive's higher harmonics is not folded in.
fn with_drive_noise(harmonics: &Mat<c64>, sigma: &Mat<c64>, nc: usize, h: usize) -> Mat<c64> {
    let f1 = harmonics[(0, 0)].norm();
    let sf = sigma[(0, 0)];
    let r2 = if f1 > 0.0 && sf.re.is_finite() && sf.im.is_finite() {
        (sf.re * sf.re + sf.im * sf.im) / (f1 * f1)
    } else {
        0.0
    };
    Mat::from_fn(nc, h, |c, k| {
        let s = sigma[(c + 1, k)];
        let add = harmonics[(c + 1, k)].norm_sqr() * r2 / 2.0;
        c64::new((s.re * s.re + add).sqrt(), (s.im * s.im + add).sqrt())
    })
}

/// The lowest modes of `model` (up to [`CHECKED_MODES`]) that the excitation `drive` drives
/// (a resonant receptance at its point, `φ²/(2ζω²)`, above 1e-6 of the largest mode's, when
/// it is one of the model's excitations; else every mode): mode number, natural frequency (Hz) and damping ratio, for the
/// sweep-rate check.
fn mode_table(model: &nlsim_kernel::Model, drive: &str) -> Result<Vec<(usize, f64, f64)>> {
    let mut cfg = nlsim_reduction::ReductionConfig::lowest(CHECKED_MODES.min(model.n_dofs()));
    cfg.eigen.par = faer::Par::Seq;
    cfg.residual_flexibility = false;
    let reduced = nlsim_reduction::reduce(model, &cfg)?;
    let zeta = nlsim_reduction::damping_ratios(&reduced.modes, &reduced.damping);
    let map = nlsim_reduction::model_port_map(model, &reduced.ports)?;
    let driven: Vec<bool> = match map.inputs.iter().find(|(n, _)| n == drive) {
        Some(&(_, port)) => {
            // Each mode's resonant receptance at the drive, φ²/(2ζω²).
            let omega = reduced.modes.omega();
            let peak: Vec<f64> = (0..reduced.n_modes())
                .map(|r| {
                    let phi = reduced.participation[(port, r)];
                    let v = phi * phi / (2.0 * zeta[r] * omega[r] * omega[r]);
                    if v.is_finite() { v } else { 0.0 }
                })
                .collect();
            let top = peak.iter().copied().fold(0.0, f64::max);
            peak.iter().map(|&v| v > 1e-6 * top).collect()
        }
        None => vec![true; reduced.n_modes()],
    };
    Ok(reduced
        .modes
        .omega()
        .iter()
        .zip(zeta)
        .enumerate()
        .filter(|(r, _)| driven[*r])
        .map(|(r, (w, z))| (r + 1, w / (2.0 * std::f64::consts::PI), z))
        .collect())
}

/// The summary of a tracked sweep: its band, its fastest rate, and the mode within its band
/// with the largest sweep-rate parameter at the rate the sweep passes it.
fn track_line(w: &Window, track: &nlsim_calib::Track, modes: &[(usize, f64, f64)]) -> TrackLine {
    let f: Vec<f64> = track.points.iter().map(|p| p.frequency_hz).collect();
    let lo = f.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = f.iter().copied().fold(0.0, f64::max);
    let mut worst: Option<(usize, f64, f64, f64)> = None;
    for &(r, fr, z) in modes {
        if !(fr >= lo && fr <= hi && z > 0.0) {
            continue;
        }
        let Some(p) = track.points.iter().min_by(|a, b| {
            (a.frequency_hz - fr)
                .abs()
                .total_cmp(&(b.frequency_hz - fr).abs())
        }) else {
            continue;
        };
        let eta = sweep_rate_parameter(p.rate_hz_per_s, fr, z);
        if worst.is_none_or(|w| eta > w.3) {
            worst = Some((r, fr, z, eta));
        }
    }
    TrackLine {
        sweep: w.sweep.clone(),
        origin: w.origin.clone(),
        points: track.points.len(),
        band_hz: (lo, hi),
        rate_hz_per_s: track
            .points
            .iter()
            .map(|p| p.rate_hz_per_s.abs())
            .fold(0.0, f64::max),
        worst_mode: worst,
    }
}

/// Found dwells grouped into sweeps: a new sweep wherever the frequency turns.
fn sweeps_of(found: &[nlsim_calib::StepWindow]) -> Vec<(String, nlsim_calib::StepWindow)> {
    let mut out = Vec::with_capacity(found.len());
    let mut sweep = 1;
    let mut rising: Option<bool> = None;
    for (i, w) in found.iter().enumerate() {
        if i > 0 {
            let up = w.frequency_hz > found[i - 1].frequency_hz;
            if rising.is_some_and(|r| r != up) {
                sweep += 1;
                rising = None;
            } else {
                rising = Some(up);
            }
        }
        out.push((format!("sweep{sweep}"), *w));
    }
    out
}

/// `nlsim harmonics`: the run, its summary, the test data written.
pub fn execute(req: &HarmonicsRequest, console: &crate::present::console::Console) -> Result<()> {
    crate::formats::files::check_outputs(
        &[Some(req.records.as_path()), req.steps.as_deref()],
        &[Some(req.out.as_path())],
        &[],
    )?;
    console.progress(if req.sweep.is_some() {
        "tracking the harmonics along every sweep"
    } else {
        "fitting the harmonics of every dwell"
    });
    let r = run(req);
    console.progress_end();
    let r = r?;
    if req.sweep.is_some() {
        say_tracks(&r, req, console);
    } else {
        say_dwells(&r, req, console);
    }
    match req.out.extension().and_then(|e| e.to_str()) {
        Some("h5" | "hdf5") => crate::formats::test_data::write_h5(&req.out, &r.data)?,
        _ => crate::formats::test_data::write_csv(&req.out, &r.data)?,
    }
    console.say(&format!("  written to {}", req.out.display()));
    Ok(())
}

/// The summary of tracked sweeps, with the sweep-rate warning.
fn say_tracks(
    r: &HarmonicsRun,
    req: &HarmonicsRequest,
    console: &crate::present::console::Console,
) {
    console.say(&format!(
        "harmonics 1..{} of {} channel(s) and the drive '{}' ({}) tracked along {} sweep(s) \
         of {}, {} Hz sampling",
        r.data.harmonics,
        r.data.channels.len(),
        r.data.input,
        r.data.drive.as_str(),
        r.tracks.len(),
        req.records.display(),
        r.rate_hz
    ));
    for t in &r.tracks {
        let mode = match t.worst_mode {
            Some((m, f, z, eta)) => format!(
                "; passes mode {m} ({f:.4} Hz, zeta {z:.4}) at sweep-rate parameter eta = \
                 {eta:.2e}"
            ),
            None => "; passes no mode of the model".into(),
        };
        console.say(&format!(
            "  sweep '{}' ({}): {} points {:.4}–{:.4} Hz, up to {:.3e} Hz/s{mode}",
            t.sweep, t.origin, t.points, t.band_hz.0, t.band_hz.1, t.rate_hz_per_s
        ));
        if let Some((m, f, z, eta)) = t.worst_mode
            && eta > ETA_WARN
        {
            console.note(&format!(
                "warning: sweep '{}' is too fast for mode {m} ({f:.4} Hz, zeta {z:.4}): eta = {eta:.2e} \
                 > {ETA_WARN:e}, so the tracked response there is off by about {:.0} % (mostly \
                 in phase: the response lags the sweep); sweep at most {:.3e} Hz/s there, or \
                 record dwells (docs/file-formats.md, \"Sweeps\")",
                t.sweep,
                100.0 * eta,
                ETA_WARN * 2.0 * std::f64::consts::PI * z * z * f * f
            ));
        }
    }
}

/// The summary of fitted dwells.
fn say_dwells(
    r: &HarmonicsRun,
    req: &HarmonicsRequest,
    console: &crate::present::console::Console,
) {
    let kept = r.dwells.iter().filter(|d| d.kept).count();
    console.say(&format!(
        "harmonics 1..{} of {} channel(s) and the drive '{}' ({}) from {}: {} of {} dwells \
         settled, {} Hz sampling",
        r.data.harmonics,
        r.data.channels.len(),
        r.data.input,
        r.data.drive.as_str(),
        req.records.display(),
        kept,
        r.dwells.len(),
        r.rate_hz
    ));
    for s in &r.data.sweeps {
        let d: Vec<&DwellLine> = r
            .dwells
            .iter()
            .filter(|d| d.sweep == s.label && d.kept)
            .collect();
        let periods = d.iter().map(|d| d.periods);
        let unsettled = d.iter().map(|d| d.unsettled);
        console.say(&format!(
            "  sweep '{}' ({}): {} steps {:.4}–{:.4} Hz; {}–{} periods fitted, {}–{} discarded \
             as transients; largest drift left {:.1e}",
            s.label,
            s.direction.as_str(),
            s.steps.len(),
            s.steps.first().map_or(0.0, |x| x.frequency_hz),
            s.steps.last().map_or(0.0, |x| x.frequency_hz),
            periods.clone().min().unwrap_or(0),
            periods.max().unwrap_or(0),
            unsettled.clone().min().unwrap_or(0),
            unsettled.max().unwrap_or(0),
            d.iter().map(|d| d.drift).fold(0.0, f64::max)
        ));
    }
    if let Some(w) = drive_truncation_warning(&r.data) {
        console.say(&w);
    }
    for d in r.dwells.iter().filter(|d| !d.kept) {
        let why = if d.periods < req.dwell.min_periods {
            format!(
                "{} settled period(s), at least {} needed",
                d.periods, req.dwell.min_periods
            )
        } else {
            format!(
                "still drifting over its second half (drift {:.1e})",
                d.drift
            )
        };
        console.say(&format!(
            "  left out: the dwell at {} ({:.4} Hz): not settled: {why}",
            d.origin, d.frequency_hz
        ));
    }
}

/// Largest measured drive harmonic, relative to the fundamental, among the upper half of the
/// harmonics kept (`H/2 < k ≤ H`) that the summary warns above: the calibration drives the
/// balance with the measured force's harmonics 1..H and cannot see what lies above, so a
/// force whose harmonics are still this large at H has more above it.
const DRIVE_TRUNCATION_WARN: f64 = 1e-3;

/// The summary's warning when a measured force still carries harmonics of more than
/// [`DRIVE_TRUNCATION_WARN`] of its fundamental in the upper half of those kept (a contact
/// at the drive point, whose kink the stinger force follows), naming the step; `None` for a
/// voltage record (the generator's own signal) or fewer than 2 harmonics.
fn drive_truncation_warning(data: &nlsim_calib::TestData) -> Option<String> {
    let h = data.harmonics;
    if data.drive != nlsim_calib::Drive::Force || h < 2 {
        return None;
    }
    let mut worst: Option<(f64, usize, &str, f64)> = None;
    for s in &data.sweeps {
        for st in &s.steps {
            let f1 = st.force.first().map_or(0.0, |f| f.norm());
            if f1 <= 0.0 {
                continue;
            }
            for (k, fk) in st.force.iter().enumerate().skip(h / 2) {
                let r = fk.norm() / f1;
                if r > worst.map_or(0.0, |w| w.0) {
                    worst = Some((r, k + 1, &s.label, st.frequency_hz));
                }
            }
        }
    }
    let (r, k, label, f) = worst?;
    (r > DRIVE_TRUNCATION_WARN).then(|| {
        format!(
            "warning: the drive's harmonic {k} is still {r:.1e} of its fundamental (sweep \
             '{label}', {f:.4} Hz): the calibration takes the force's harmonics 1..{h} as its \
             input and cannot see those above; extract and calibrate with more (--harmonics, \
             at most 64) where the drive point meets a contact"
        )
    })
}
