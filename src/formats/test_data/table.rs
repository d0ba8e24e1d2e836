//! Stepped-sine data as an amplitude-and-phase table, the layout many labs export (and the
//! Brake–Reuss beam's data ships in): one row per step, first harmonic only, amplitudes and
//! phases in named columns, sweeps told apart by key columns.
//!
//! ```text
//! control,level,frequency_hz,force_amplitude_n,accel_amplitude_m_s2,phase_rad
//! force,1,79.0,0.241,12.3,-0.11
//! ```
//!
//! - `frequency_hz` and `force_amplitude_n` are required; `force_phase_rad` is optional (0).
//!   A voltage-driven test without a force gauge gives `voltage_amplitude_v` (and
//!   optionally `voltage_phase_rad`) instead: the data's drive is then the voltage.
//! - Each response channel is a column `NAME_amplitude_UNIT` with `UNIT` `m`, `m_s` or
//!   `m_s2` (displacement, velocity, acceleration) and its phase `NAME_phase_rad`; with one
//!   channel the phase may be the bare `phase_rad`. Phases are of the response relative to
//!   the force unless `force_phase_rad` is given (then both are absolute).
//! - Every other column is a key of the sweep: a sweep is a run of consecutive rows with the
//!   same keys, labelled by them joined with `-` (`force-1`); its direction is that of its
//!   frequencies (one row: up).
//!
//! The table has no noise model: each channel gets the relative noise the caller gives
//! (`data_noise`), and the drive point is the model's excitation.

use crate::error::{Error, Result};
use faer::{Mat, c64};
use nlsim_calib::{Channel, Noise, Step, Sweep, SweepDirection, TestData};
use nlsim_kernel::Quantity;
use std::path::Path;

/// Whether `text` is an amplitude-and-phase table: its first line that is neither empty nor
/// a `#` comment names the columns `frequency_hz` and `force_amplitude_n` (or
/// `voltage_amplitude_v`).
pub fn is_amplitude_phase(text: &str) -> bool {
    text.lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .is_some_and(|h| {
            let cols: Vec<&str> = h.split(',').map(str::trim).collect();
            cols.contains(&"frequency_hz")
                && (cols.contains(&"force_amplitude_n") || cols.contains(&"voltage_amplitude_v"))
        })
}

/// What a column of the table holds.
#[derive(Debug, Clone, PartialEq)]
enum Column {
    Key,
    Frequency,
    ForceAmplitude,
    ForcePhase,
    Amplitude(usize),
    Phase(usize),
}

/// The channel name and quantity of an amplitude column `NAME_amplitude_UNIT`.
fn amplitude_column(name: &str) -> Option<(&str, Quantity)> {
    let (channel, unit) = name.rsplit_once("_amplitude_")?;
    let q = match unit {
        "m" => Quantity::Displacement,
        "m_s" => Quantity::Velocity,
        "m_s2" => Quantity::Acceleration,
        _ => return None,
    };
    (!channel.is_empty()).then_some((channel, q))
}

/// Parses an amplitude-and-phase table (module docs) from `path`'s `text`: the drive point
/// is `input`, every channel's noise `noise`. Errors name the file, the line and the column.
pub fn parse_amplitude_phase(
    text: &str,
    path: &Path,
    input: &str,
    noise: Noise,
) -> Result<TestData> {
    let err = |line: usize, message: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message,
    };
    let quoted = crate::formats::files::quoted;
    let mut rows = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty() && !l.starts_with('#'));
    let Some((hl, header)) = rows.next() else {
        return Err(err(1, "no column header".into()));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let mut channels: Vec<Channel> = Vec::new();
    let mut columns = Vec::with_capacity(names.len());
    let mut drive: Option<nlsim_calib::Drive> = None;
    for name in &names {
        let col = match *name {
            "frequency_hz" => Column::Frequency,
            "force_amplitude_n" | "voltage_amplitude_v" => {
                let d = if *name == "force_amplitude_n" {
                    nlsim_calib::Drive::Force
                } else {
                    nlsim_calib::Drive::Voltage
                };
                if drive.is_some_and(|k| k != d) {
                    return Err(err(
                        hl,
                        "the header names both force_amplitude_n and voltage_amplitude_v: \
                         one drive record per table"
                            .into(),
                    ));
                }
                drive = Some(d);
                Column::ForceAmplitude
            }
            "force_phase_rad" | "voltage_phase_rad" => Column::ForcePhase,
            n => match amplitude_column(n) {
                Some((ch, q)) => {
                    if channels.iter().any(|c| c.name == ch) {
                        return Err(err(
                            hl,
                            format!("channel {} has two amplitude columns", quoted(ch)),
                        ));
                    }
                    channels.push(Channel {
                        name: ch.to_string(),
                        quantity: q,
                        noise,
                    });
                    Column::Amplitude(channels.len() - 1)
                }
                None if n.ends_with("_phase_rad") || n == "phase_rad" => Column::Phase(usize::MAX),
                None if n.contains("_amplitude_") => {
                    return Err(err(
                        hl,
                        format!(
                            "column {}: an amplitude column is NAME_amplitude_UNIT with UNIT m, \
                             m_s or m_s2",
                            quoted(n)
                        ),
                    ));
                }
                None if n.is_empty() => {
                    return Err(err(hl, "an empty column name in the header".into()));
                }
                None => Column::Key,
            },
        };
        if col != Column::Key
            && !matches!(col, Column::Amplitude(_) | Column::Phase(_))
            && columns.contains(&col)
        {
            return Err(err(hl, format!("column {} appears twice", quoted(name))));
        }
        columns.push(col);
    }
    if channels.is_empty() {
        return Err(err(
            hl,
            "no response column: name one NAME_amplitude_UNIT (UNIT m, m_s or m_s2)".into(),
        ));
    }
    // Each channel's phase column.
    let mut phase_of = vec![None; channels.len()];
    for (j, name) in names.iter().enumerate() {
        if columns[j] != Column::Phase(usize::MAX) {
            continue;
        }
        let c = if *name == "phase_rad" {
            if channels.len() != 1 {
                return Err(err(
                    hl,
                    format!(
                        "column 'phase_rad' is ambiguous with {} channels: name it \
                         CHANNEL_phase_rad",
                        channels.len()
                    ),
                ));
            }
            0
        } else {
            let ch = name.strip_suffix("_phase_rad").unwrap_or(name);
            channels.iter().position(|c| c.name == ch).ok_or_else(|| {
                err(
                    hl,
                    format!(
                        "column {}: no amplitude column of channel {}",
                        quoted(name),
                        quoted(ch)
                    ),
                )
            })?
        };
        if phase_of[c].replace(j).is_some() {
            return Err(err(
                hl,
                format!(
                    "channel {} has two phase columns",
                    quoted(&channels[c].name)
                ),
            ));
        }
        columns[j] = Column::Phase(c);
    }
    if let Some(c) = phase_of.iter().position(Option::is_none) {
        return Err(err(
            hl,
            format!(
                "channel {} has no phase column ({}_phase_rad)",
                quoted(&channels[c].name),
                channels[c].name
            ),
        ));
    }
    for need in [Column::Frequency, Column::ForceAmplitude] {
        if !columns.contains(&need) {
            return Err(err(
                hl,
                "the header names no frequency_hz or no force_amplitude_n (or \
                 voltage_amplitude_v)"
                    .into(),
            ));
        }
    }
    let mut sweeps: Vec<Sweep> = Vec::new();
    let mut labels = std::collections::HashSet::new();
    // The keys of the sweep being read.
    let mut keys_of_last: Option<Vec<String>> = None;
    for (ln, line) in rows {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != names.len() {
            return Err(err(
                ln,
                format!("{} columns, expected {}", cells.len(), names.len()),
            ));
        }
        let num = |j: usize| super::finite_cell(&cells, &names, j).map_err(|m| err(ln, m));
        let keys: Vec<String> = columns
            .iter()
            .zip(&cells)
            .filter(|(c, _)| **c == Column::Key)
            .map(|(_, v)| v.to_string())
            .collect();
        let (mut f, mut fa, mut fp) = (f64::NAN, f64::NAN, 0.0);
        let mut amp = vec![f64::NAN; channels.len()];
        let mut ph = vec![f64::NAN; channels.len()];
        for (j, col) in columns.iter().enumerate() {
            match col {
                Column::Key => {}
                Column::Frequency => f = num(j)?,
                Column::ForceAmplitude => fa = num(j)?,
                Column::ForcePhase => fp = num(j)?,
                Column::Amplitude(c) => amp[*c] = num(j)?,
                Column::Phase(c) => ph[*c] = num(j)?,
            }
        }
        if f <= 0.0 {
            return Err(err(ln, format!("frequency_hz: {f} is not positive")));
        }
        if fa <= 0.0 {
            let col = match drive {
                Some(nlsim_calib::Drive::Voltage) => "voltage_amplitude_v",
                _ => "force_amplitude_n",
            };
            return Err(err(ln, format!("{col}: {fa} is not positive")));
        }
        if let Some(c) = amp.iter().position(|a| *a < 0.0) {
            return Err(err(
                ln,
                format!("{}: amplitude {} is negative", channels[c].name, amp[c]),
            ));
        }
        if keys_of_last.as_ref() != Some(&keys) {
            let label = if keys.is_empty() {
                "sweep".to_string()
            } else {
                keys.join("-")
            };
            if let Some(why) = nlsim_calib::data::label_fault(&label) {
                return Err(err(ln, format!("sweep label {}: {why}", quoted(&label))));
            }
            // A set of the labels seen: one lookup per sweep, not a scan of every earlier one.
            if !labels.insert(label.clone()) {
                return Err(err(
                    ln,
                    format!("rows of sweep {} are not contiguous", quoted(&label)),
                ));
            }
            sweeps.push(Sweep {
                label,
                direction: SweepDirection::Up,
                steps: Vec::new(),
            });
            keys_of_last = Some(keys);
        }
        let sw = sweeps.last_mut().expect("pushed above");
        if let Some(last) = sw.steps.last() {
            let dir = if f > last.frequency_hz {
                SweepDirection::Up
            } else if f < last.frequency_hz {
                SweepDirection::Down
            } else {
                return Err(err(
                    ln,
                    format!(
                        "sweep {}: {f} Hz repeats the previous step",
                        quoted(&sw.label)
                    ),
                ));
            };
            if sw.steps.len() == 1 {
                sw.direction = dir;
            } else if dir != sw.direction {
                return Err(err(
                    ln,
                    format!(
                        "sweep {}: the frequency turns ({f} Hz after {} Hz in a sweep going {})",
                        quoted(&sw.label),
                        last.frequency_hz,
                        sw.direction.as_str()
                    ),
                ));
            }
        }
        sw.steps.push(Step {
            frequency_hz: f,
            force: vec![c64::from_polar(fa, fp)],
            response: Mat::from_fn(channels.len(), 1, |c, _| {
                c64::from_polar(amp[c], ph[c] + fp)
            }),
            sigma: Mat::new(),
        });
    }
    if sweeps.is_empty() {
        return Err(err(hl, "no data rows after the header".into()));
    }
    let data = TestData {
        input: input.to_string(),
        drive: drive.unwrap_or_default(),
        channels,
        harmonics: 1,
        sweeps,
    };
    data.validate_measured()
        .map_err(|e| err(hl, e.to_string()))?;
    Ok(data)
}
