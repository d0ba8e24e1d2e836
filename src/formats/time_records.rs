//! Raw time histories of a test and its step table, as `nlsim harmonics` reads them
//! (docs/file-formats.md, "Time histories").
//!
//! Time histories (CSV): `#` comment lines and blank lines anywhere, a header `time_s,NAME,…`
//! (the drive's and the sensors' names), then one row per sample, evenly spaced in time
//! (each time within 1 % of a sample interval of the even grid from the first to the last).
//!
//! Step table (CSV): a header with `start_s` and `end_s` and optionally `frequency_hz` and
//! `sweep`, in any order, then one row per dwell: its time window (s), its drive frequency
//! if known (refined from the drive), the label of the sweep it belongs to (default `sweep1`).
//!
//! Time histories also come as universal file datasets 58 of function type 1 (time
//! response; ASCII or binary, as test systems and pyuff write them): each dataset one
//! signal, named by the first word of its ID line 1 (or `NODE:COMP` of its response DOF,
//! `force@NODE:COMP` for a force, where that word is empty or `NONE`), all on the same even
//! time abscissa
//! ([`from_uff`]).
//!
//! Both are read line by line from text whose size was known before reading (the parsed
//! numbers take no more memory than their text); errors name the file, line and column.

use crate::error::{Error, Result};
use crate::formats::test_data::finite_cell;
use std::path::Path;

/// Time histories read from a CSV file.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeRecords {
    /// Sampling rate (Hz), from the time column.
    pub rate_hz: f64,
    /// Time of the first sample (s).
    pub start_s: f64,
    /// The signals' names, as in the header (the time column not included).
    pub names: Vec<String>,
    /// The signals, one per name, each the same number of samples.
    pub columns: Vec<Vec<f64>>,
    /// 1-based line of each sample (for error messages).
    pub lines: Vec<usize>,
}

/// Largest ratio of a sample time to the sample interval that keeps every time within
/// 10⁻⁴ of an interval in f64 (2⁻⁵² · 10¹² ≈ 2·10⁻⁴): times further from zero lose the
/// sampling itself to rounding.
pub const MAX_TIME_OVER_INTERVAL: f64 = 1e12;

/// Why times from `first` to `last` (s), `dt` apart, cannot be read as a sampling (`None`
/// when they can): beyond [`MAX_TIME_OVER_INTERVAL`] intervals from zero the f64 times no
/// longer resolve the interval (an absolute clock such as 1e300 s, or a wrong unit).
pub fn coarse_times(first: f64, last: f64, dt: f64) -> Option<String> {
    let far = first.abs().max(last.abs());
    (far / dt > MAX_TIME_OVER_INTERVAL).then(|| {
        format!(
            "times reach {} s with samples {} s apart: at more than {:e} intervals from zero \
             an f64 time no longer resolves the sampling; give times from the start of the \
             record",
            crate::formats::files::number(far),
            crate::formats::files::number(dt),
            MAX_TIME_OVER_INTERVAL
        )
    })
}

/// One row of a step table.
#[derive(Debug, Clone, PartialEq)]
pub struct StepRow {
    /// 1-based line in the table.
    pub line: usize,
    /// Start of the dwell (s).
    pub start_s: f64,
    /// End of the dwell (s).
    pub end_s: f64,
    /// The drive frequency (Hz), if the table gives it.
    pub frequency_hz: Option<f64>,
    /// The sweep's label.
    pub sweep: String,
}

fn data_error(path: &Path, line: usize, message: String) -> Error {
    Error::DataFile {
        file: path.to_path_buf(),
        line,
        message,
    }
}

/// A data row's cells, trimmed; an error naming the line unless there is one per column.
fn row<'a>(path: &Path, line: usize, text: &'a str, columns: usize) -> Result<Vec<&'a str>> {
    let cells: Vec<&str> = text.split(',').map(str::trim).collect();
    if cells.len() != columns {
        return Err(data_error(
            path,
            line,
            format!("{} cells; the header names {columns} columns", cells.len()),
        ));
    }
    Ok(cells)
}

/// The lines that hold data: 1-based line number and text, comments and blank lines left
/// out.
fn data_lines(text: &str) -> impl Iterator<Item = (usize, &str)> {
    text.lines().enumerate().filter_map(|(i, l)| {
        let t = l.trim();
        (!t.is_empty() && !t.starts_with('#')).then_some((i + 1, t))
    })
}

/// Reads time histories from `path` (see the module documentation).
pub fn read_records(path: &Path) -> Result<TimeRecords> {
    let text = crate::formats::files::read_text(path)?;
    parse_records(&text, path)
}

/// Parses the time-history CSV `text` of `path`.
pub fn parse_records(text: &str, path: &Path) -> Result<TimeRecords> {
    let mut lines = data_lines(text);
    let Some((hline, header)) = lines.next() else {
        return Err(data_error(
            path,
            1,
            "no header: the first line that is not a comment names the columns, \
             `time_s,DRIVE,SENSOR,…`"
                .into(),
        ));
    };
    let names: Vec<String> = header.split(',').map(|c| c.trim().to_string()).collect();
    if names[0] != "time_s" {
        return Err(data_error(
            path,
            hline,
            format!(
                "the first column is {}; it must be time_s (the sample times in seconds)",
                crate::formats::files::quoted(&names[0])
            ),
        ));
    }
    if names.len() < 2 {
        return Err(data_error(
            path,
            hline,
            "only a time column: name the drive and the sensors after it".into(),
        ));
    }
    let mut seen = std::collections::HashSet::new();
    for (j, n) in names.iter().enumerate() {
        if n.is_empty() {
            return Err(data_error(
                path,
                hline,
                format!("column {} has no name", j + 1),
            ));
        }
        if !seen.insert(n.as_str()) {
            return Err(data_error(
                path,
                hline,
                format!("column {} repeats the name '{n}'", j + 1),
            ));
        }
    }
    let mut time = Vec::new();
    let mut columns = vec![Vec::new(); names.len() - 1];
    let mut at = Vec::new();
    for (line, l) in lines {
        let cells = row(path, line, l, names.len())?;
        for j in 0..cells.len() {
            let v = finite_cell(&cells, &names, j).map_err(|m| data_error(path, line, m))?;
            if j == 0 {
                time.push(v);
            } else {
                columns[j - 1].push(v);
            }
        }
        at.push(line);
    }
    let n = time.len();
    if n < 2 {
        return Err(data_error(
            path,
            at.first().copied().unwrap_or(hline),
            format!("{n} sample(s); a time history needs at least 2"),
        ));
    }
    let dt = (time[n - 1] - time[0]) / (n - 1) as f64;
    if dt <= 0.0 {
        return Err(data_error(
            path,
            at[n - 1],
            "the times do not increase: time_s must rise from the first sample to the last".into(),
        ));
    }
    if let Some(m) = coarse_times(time[0], time[n - 1], dt) {
        return Err(data_error(path, at[0], m));
    }
    for (i, &t) in time.iter().enumerate() {
        let even = time[0] + i as f64 * dt;
        if (t - even).abs() > 0.01 * dt {
            return Err(data_error(
                path,
                at[i],
                format!(
                    "time {t} s is off the even sampling ({even} s at {:.6} Hz from the first \
                     and last times) by {:.3} sample intervals; resample the record evenly",
                    1.0 / dt,
                    (t - even).abs() / dt
                ),
            ));
        }
    }
    Ok(TimeRecords {
        rate_hz: 1.0 / dt,
        start_s: time[0],
        names: names[1..].to_vec(),
        columns,
        lines: at,
    })
}

/// Reads a step table from `path` (see the module documentation).
pub fn read_step_table(path: &Path) -> Result<Vec<StepRow>> {
    let text = crate::formats::files::read_text(path)?;
    parse_step_table(&text, path)
}

/// Parses the step-table CSV `text` of `path`.
pub fn parse_step_table(text: &str, path: &Path) -> Result<Vec<StepRow>> {
    let mut lines = data_lines(text);
    let Some((hline, header)) = lines.next() else {
        return Err(data_error(
            path,
            1,
            "no header: name the columns start_s,end_s[,frequency_hz][,sweep]".into(),
        ));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    let col = |want: &str| names.iter().position(|n| *n == want);
    for (j, n) in names.iter().enumerate() {
        if !["start_s", "end_s", "frequency_hz", "sweep"].contains(n) {
            return Err(data_error(
                path,
                hline,
                format!(
                    "column {} is {}; a step table has start_s, end_s, frequency_hz and sweep",
                    j + 1,
                    crate::formats::files::quoted(n)
                ),
            ));
        }
        if names[..j].contains(n) {
            return Err(data_error(
                path,
                hline,
                format!("column {} repeats '{n}'", j + 1),
            ));
        }
    }
    let (Some(start), Some(end)) = (col("start_s"), col("end_s")) else {
        return Err(data_error(
            path,
            hline,
            "a step table needs the columns start_s and end_s".into(),
        ));
    };
    let (freq, sweep) = (col("frequency_hz"), col("sweep"));
    let mut rows = Vec::new();
    for (line, l) in lines {
        let cells = row(path, line, l, names.len())?;
        let num = |j: usize| finite_cell(&cells, &names, j).map_err(|m| data_error(path, line, m));
        let (s, e) = (num(start)?, num(end)?);
        if e <= s {
            return Err(data_error(
                path,
                line,
                format!("the step ends at {e} s, not after its start at {s} s"),
            ));
        }
        let f = match freq {
            Some(j) if !cells[j].is_empty() => {
                let f = num(j)?;
                if f <= 0.0 {
                    return Err(data_error(
                        path,
                        line,
                        format!(
                            "column {} (frequency_hz): {f} Hz; it must be positive",
                            j + 1
                        ),
                    ));
                }
                Some(f)
            }
            _ => None,
        };
        let label = match sweep {
            Some(j) if !cells[j].is_empty() => cells[j].to_string(),
            _ => "sweep1".to_string(),
        };
        rows.push(StepRow {
            line,
            start_s: s,
            end_s: e,
            frequency_hz: f,
            sweep: label,
        });
    }
    if rows.is_empty() {
        return Err(data_error(path, hline, "no step below the header".into()));
    }
    Ok(rows)
}

/// Time histories from universal file datasets 58 of function type 1 (time response), read
/// by [`crate::formats::uff::read`]: one signal per dataset, named by the first word of its ID
/// line 1, or by its response DOF (`21:uz`; `force@21:uz` for a force, ordinate type 13)
/// where that is empty or `NONE`. Every dataset
/// must be a real time response on the first one's even time abscissa; errors name the
/// file and the dataset (1-based, in file order).
pub fn from_uff(records: &[crate::formats::uff::Uff58], path: &Path) -> Result<TimeRecords> {
    let bad = |i: usize, why: String| {
        Error::Usage(format!(
            "{}: dataset 58 number {} (in file order): {why}",
            path.display(),
            i + 1
        ))
    };
    let Some(first) = records.first() else {
        return Err(Error::Usage(format!(
            "{}: no dataset 58 (function at nodal DOF) in the file",
            path.display()
        )));
    };
    let x = &first.frequencies_hz;
    let n = x.len();
    if n < 2 {
        return Err(bad(
            0,
            format!("{n} value(s); a time history needs at least 2"),
        ));
    }
    let dt = (x[n - 1] - x[0]) / (n - 1) as f64;
    if let Some(m) = (dt > 0.0)
        .then(|| coarse_times(x[0], x[n - 1], dt))
        .flatten()
    {
        return Err(bad(0, m));
    }
    if dt.is_nan() || dt <= 0.0 {
        return Err(bad(0, "the abscissa does not increase".into()));
    }
    if let Some(k) = (0..n).find(|&k| (x[k] - (x[0] + k as f64 * dt)).abs() > 0.01 * dt) {
        return Err(bad(
            0,
            format!(
                "abscissa value {} at {} is off the even sampling ({:.6} Hz); resample evenly",
                k + 1,
                x[k],
                1.0 / dt
            ),
        ));
    }
    let mut names = Vec::with_capacity(records.len());
    let mut columns = Vec::with_capacity(records.len());
    for (i, r) in records.iter().enumerate() {
        if r.function_type != 1 {
            return Err(bad(
                i,
                format!(
                    "function type {} is not a time response (1); `nlsim harmonics` reads time histories",
                    r.function_type
                ),
            ));
        }
        if r.frequencies_hz.len() != n
            || r.frequencies_hz
                .iter()
                .zip(x)
                .any(|(a, b)| (a - b).abs() > 0.01 * dt)
        {
            return Err(bad(
                i,
                format!(
                    "{} samples on another time abscissa than the first dataset's {n}",
                    r.frequencies_hz.len()
                ),
            ));
        }
        if let Some(k) = r
            .values
            .iter()
            .position(|v| !(v.re.is_finite() && v.im == 0.0))
        {
            return Err(bad(
                i,
                format!(
                    "sample {} is {} — a time response holds finite real values",
                    k + 1,
                    r.values[k]
                ),
            ));
        }
        let word = r.id.split_whitespace().next().unwrap_or("");
        let name = if word.is_empty() || word.eq_ignore_ascii_case("none") {
            // A force (ordinate type 13) at a DOF is the drive there, not its response.
            if r.ordinate_type == 13 {
                format!("force@{}", r.response_label())
            } else {
                r.response_label()
            }
        } else {
            word.to_string()
        };
        if names.contains(&name) {
            return Err(bad(i, format!("a second signal named '{name}'")));
        }
        names.push(name);
        columns.push(r.values.iter().map(|v| v.re).collect());
    }
    Ok(TimeRecords {
        rate_hz: 1.0 / dt,
        start_s: x[0],
        names,
        columns,
        // Binary or fixed-column data have no line per sample: errors name the sample.
        lines: (1..=n).collect(),
    })
}
