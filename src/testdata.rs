//! Stepped-sine test data as CSV (documented in docs/file-formats.md; `pandas.read_csv(path,
//! comment="#")` reads it): a header of `#` lines with the drive point, the harmonics and one
//! line per channel, then one row per step and harmonic.
//!
//! ```text
//! # nlsim stepped-sine test data
//! # input: shaker
//! # harmonics: 3
//! # channel: tip, acceleration, relative=0.02, absolute=0
//! sweep,direction,frequency_hz,harmonic,force_re,force_im,tip_re,tip_im
//! low,up,22.0,1,0.05,0,-0.513,0.207
//! ```
//!
//! Amplitudes are complex harmonics `Z` with `z(t) = Re(Z e^{ikΩt})` in SI units (N, m, m/s,
//! m/s²); an empty response cell is a harmonic not measured. Rows of one sweep are contiguous
//! and in measured order, and each step lists harmonics `1..=H` in turn.

use crate::error::{Error, Result};
use faer::{Mat, c64};
use nlsim_calib::{Channel, Noise, Step, Sweep, SweepDirection, TestData};
use nlsim_kernel::Quantity;
use std::fmt::Write as _;
use std::path::Path;

fn quantity(s: &str) -> Option<Quantity> {
    match s {
        "displacement" => Some(Quantity::Displacement),
        "velocity" => Some(Quantity::Velocity),
        "acceleration" => Some(Quantity::Acceleration),
        _ => None,
    }
}

/// Reads test data from the CSV layout above; errors name the file, line and column.
pub fn read_csv(path: &Path) -> Result<TestData> {
    let text = std::fs::read_to_string(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_csv(&text, path)
}

/// Parses the CSV text of `path` (see [`read_csv`]).
pub fn parse_csv(text: &str, path: &Path) -> Result<TestData> {
    let err = |line: usize, message: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message,
    };
    let mut input = None;
    let mut harmonics = None;
    let mut channels: Vec<Channel> = Vec::new();
    let mut header: Option<(usize, Vec<String>)> = None;
    let mut sweeps: Vec<Sweep> = Vec::new();
    // The step being read: (line, frequency, harmonics seen).
    let mut pending: Option<(usize, usize)> = None;
    let n_lines = text.lines().count();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let line = raw.trim();
        if line.is_empty() {
            continue;
        }
        if let Some(meta) = line.strip_prefix('#') {
            let meta = meta.trim();
            if let Some(v) = meta.strip_prefix("input:") {
                input = Some(v.trim().to_string());
            } else if let Some(v) = meta.strip_prefix("harmonics:") {
                let h: usize = v
                    .trim()
                    .parse()
                    .map_err(|_| err(ln, format!("harmonics: '{}' is not a count", v.trim())))?;
                if h == 0 || h > 1000 {
                    return Err(err(ln, format!("harmonics: {h} is outside 1..=1000")));
                }
                harmonics = Some(h);
            } else if let Some(v) = meta.strip_prefix("channel:") {
                let f: Vec<&str> = v.split(',').map(str::trim).collect();
                if f.len() < 2 {
                    return Err(err(
                        ln,
                        "channel: expected 'NAME, QUANTITY[, relative=R][, absolute=A]'".into(),
                    ));
                }
                let q = quantity(f[1]).ok_or_else(|| err(ln, format!("channel '{}': quantity '{}' is not displacement, velocity or acceleration", f[0], f[1])))?;
                let mut noise = Noise {
                    absolute: 0.0,
                    relative: 0.0,
                };
                for kv in &f[2..] {
                    let (k, v) = kv.split_once('=').ok_or_else(|| {
                        err(ln, format!("channel '{}': '{kv}' is not KEY=VALUE", f[0]))
                    })?;
                    let v: f64 = v
                        .trim()
                        .parse()
                        .ok()
                        .filter(|v: &f64| v.is_finite() && *v >= 0.0)
                        .ok_or_else(|| {
                            err(
                                ln,
                                format!(
                                    "channel '{}': {k} = '{v}' is not a non-negative number",
                                    f[0]
                                ),
                            )
                        })?;
                    match k.trim() {
                        "relative" => noise.relative = v,
                        "absolute" => noise.absolute = v,
                        other => {
                            return Err(err(
                                ln,
                                format!(
                                    "channel '{}': unknown key '{other}' (relative, absolute)",
                                    f[0]
                                ),
                            ));
                        }
                    }
                }
                channels.push(Channel {
                    name: f[0].to_string(),
                    quantity: q,
                    noise,
                });
            }
            continue;
        }
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        let Some((_, names)) = &header else {
            let mut want = vec![
                "sweep",
                "direction",
                "frequency_hz",
                "harmonic",
                "force_re",
                "force_im",
            ]
            .into_iter()
            .map(String::from)
            .collect::<Vec<_>>();
            for c in &channels {
                want.push(format!("{}_re", c.name));
                want.push(format!("{}_im", c.name));
            }
            if channels.is_empty() {
                return Err(err(
                    ln,
                    "no '# channel:' line before the column header".into(),
                ));
            }
            if cells != want {
                return Err(err(
                    ln,
                    format!("the column header must be '{}'", want.join(",")),
                ));
            }
            header = Some((ln, want));
            continue;
        };
        let h =
            harmonics.ok_or_else(|| err(ln, "no '# harmonics:' line before the data".into()))?;
        if cells.len() != names.len() {
            return Err(err(
                ln,
                format!("{} columns, expected {}", cells.len(), names.len()),
            ));
        }
        let num = |c: usize| -> Result<f64> {
            cells[c]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    err(
                        ln,
                        format!(
                            "column {} ({}): '{}' is not a finite number",
                            c + 1,
                            names[c],
                            cells[c]
                        ),
                    )
                })
        };
        let direction = match cells[1] {
            "up" => SweepDirection::Up,
            "down" => SweepDirection::Down,
            d => {
                return Err(err(
                    ln,
                    format!("column 2 (direction): '{d}' is not up or down"),
                ));
            }
        };
        let f = num(2)?;
        let k: usize = cells[3].parse().map_err(|_| {
            err(
                ln,
                format!(
                    "column 4 (harmonic): '{}' is not a harmonic number",
                    cells[3]
                ),
            )
        })?;
        let force = c64::new(num(4)?, num(5)?);
        let response: Vec<c64> = (0..channels.len())
            .map(|c| {
                let (a, b) = (6 + 2 * c, 7 + 2 * c);
                if cells[a].is_empty() && cells[b].is_empty() {
                    Ok(c64::new(f64::NAN, f64::NAN))
                } else {
                    Ok(c64::new(num(a)?, num(b)?))
                }
            })
            .collect::<Result<_>>()?;
        let new_sweep = sweeps.last().is_none_or(|s| s.label != cells[0]);
        if new_sweep {
            if let Some((l, seen)) = pending
                && seen != h
            {
                return Err(err(
                    l,
                    format!("the step lists {seen} harmonics, expected {h}"),
                ));
            }
            if sweeps.iter().any(|s| s.label == cells[0]) {
                return Err(err(
                    ln,
                    format!(
                        "column 1 (sweep): rows of sweep '{}' are not contiguous",
                        cells[0]
                    ),
                ));
            }
            sweeps.push(Sweep {
                label: cells[0].to_string(),
                direction,
                steps: Vec::new(),
            });
            pending = None;
        }
        let sw = sweeps.last_mut().expect("pushed above");
        if sw.direction != direction {
            return Err(err(
                ln,
                format!(
                    "column 2 (direction): sweep '{}' changes direction",
                    sw.label
                ),
            ));
        }
        if k == 1 {
            // Bounded by construction: a step's storage (channels × H) is allocated only when
            // the file still holds the H rows that fill it.
            if n_lines - i < h {
                return Err(err(
                    ln,
                    format!("a step needs {h} harmonic rows; the file ends first"),
                ));
            }
            if let Some((l, seen)) = pending
                && seen != h
            {
                return Err(err(
                    l,
                    format!("the step lists {seen} harmonics, expected {h}"),
                ));
            }
            sw.steps.push(Step {
                frequency_hz: f,
                force: vec![c64::new(0.0, 0.0); h],
                response: Mat::from_fn(channels.len(), h, |_, _| c64::new(f64::NAN, f64::NAN)),
            });
            pending = Some((ln, 0));
        }
        let Some((l, seen)) = pending.as_mut() else {
            return Err(err(
                ln,
                format!("column 4 (harmonic): a step starts with harmonic 1, not {k}"),
            ));
        };
        let st = sw.steps.last_mut().expect("a step was started");
        if k != *seen + 1 || k > h || st.frequency_hz != f {
            return Err(err(
                ln,
                format!(
                    "column 4 (harmonic): expected harmonic {} of the step at {} Hz (line {l})",
                    *seen + 1,
                    st.frequency_hz
                ),
            ));
        }
        st.force[k - 1] = force;
        for (c, y) in response.into_iter().enumerate() {
            st.response[(c, k - 1)] = y;
        }
        *seen = k;
    }
    if let Some((l, seen)) = pending {
        let h = harmonics.unwrap_or(0);
        if seen != h {
            return Err(err(
                l,
                format!("the step lists {seen} harmonics, expected {h}"),
            ));
        }
    }
    let data = TestData {
        input: input.ok_or_else(|| err(1, "no '# input:' line naming the drive point".into()))?,
        channels,
        harmonics: harmonics.ok_or_else(|| err(1, "no '# harmonics:' line".into()))?,
        sweeps,
    };
    data.validate()
        .map_err(|e| err(header.map_or(1, |h| h.0), e.to_string()))?;
    Ok(data)
}

/// Writes `data` in the CSV layout above (atomically: a temporary file, then a rename).
pub fn write_csv(path: &Path, data: &TestData) -> Result<()> {
    let mut s = String::new();
    let _ = writeln!(s, "# nlsim stepped-sine test data");
    let _ = writeln!(s, "# input: {}", data.input);
    let _ = writeln!(s, "# harmonics: {}", data.harmonics);
    for c in &data.channels {
        let _ = writeln!(
            s,
            "# channel: {}, {}, relative={:e}, absolute={:e}",
            c.name,
            c.quantity.as_str(),
            c.noise.relative,
            c.noise.absolute
        );
    }
    s.push_str("sweep,direction,frequency_hz,harmonic,force_re,force_im");
    for c in &data.channels {
        let _ = write!(s, ",{0}_re,{0}_im", c.name);
    }
    s.push('\n');
    for sw in &data.sweeps {
        for st in &sw.steps {
            for k in 0..data.harmonics {
                let f = st.force[k];
                let _ = write!(
                    s,
                    "{},{},{:?},{},{:?},{:?}",
                    sw.label,
                    sw.direction.as_str(),
                    st.frequency_hz,
                    k + 1,
                    f.re,
                    f.im
                );
                for c in 0..data.channels.len() {
                    let y = st.response[(c, k)];
                    if y.re.is_nan() {
                        s.push_str(",,");
                    } else {
                        let _ = write!(s, ",{:?},{:?}", y.re, y.im);
                    }
                }
                s.push('\n');
            }
        }
    }
    let tmp = crate::output::temp_path(path);
    std::fs::write(&tmp, s)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })
}
