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
//! m/s²); an empty response cell is a harmonic not measured. The header may go on with
//! `<channel>_re_std,<channel>_im_std` for every channel: the measured standard deviations of
//! each harmonic's real and imaginary parts, which replace the channel's noise model where
//! given (empty cells keep it). Rows of one sweep are contiguous
//! and in measured order, and each step lists harmonics `1..=H` in turn.

use crate::error::{Error, Result};
use faer::{Mat, c64};
use nlsim_calib::{Channel, Noise, Step, Sweep, SweepDirection, TestData};
use nlsim_kernel::Quantity;
use std::fmt::Write as _;
use std::path::Path;

#[cfg(feature = "hdf5")]
mod h5;
#[cfg(feature = "hdf5")]
pub use h5::{read_h5, write_h5};

/// `1st`, `2nd`, `3rd`, `4th`, …
fn ordinal(n: usize) -> String {
    let suffix = match (n % 10, n % 100) {
        (_, 11..=13) => "th",
        (1, _) => "st",
        (2, _) => "nd",
        (3, _) => "rd",
        _ => "th",
    };
    format!("{n}{suffix}")
}

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
    let text = crate::formats::files::read_text(path)?;
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
    // The header carries `<channel>_re_std,<channel>_im_std` columns.
    let mut stds = false;
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
            let key = ["input", "harmonics", "channel"]
                .into_iter()
                .find(|k| meta.strip_prefix(k).is_some_and(|r| r.starts_with(':')));
            if let (Some(k), Some((hl, _))) = (key, &header) {
                return Err(err(
                    ln,
                    format!(
                        "'# {k}:' after the column header (line {hl}): the '#' lines that \
                         describe the data come before it"
                    ),
                ));
            }
            if let Some(v) = meta.strip_prefix("input:") {
                if input.is_some() {
                    return Err(err(ln, "a second '# input:' line".into()));
                }
                input = Some(v.trim().to_string());
            } else if let Some(v) = meta.strip_prefix("harmonics:") {
                if harmonics.is_some() {
                    return Err(err(ln, "a second '# harmonics:' line".into()));
                }
                let h: usize = v.trim().parse().map_err(|_| {
                    err(
                        ln,
                        format!(
                            "harmonics: {} is not a count",
                            crate::formats::files::quoted(v.trim())
                        ),
                    )
                })?;
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
                let q = quantity(f[1]).ok_or_else(|| {
                    err(
                        ln,
                        format!(
                            "channel {}: quantity {} is not displacement, velocity or acceleration",
                            crate::formats::files::quoted(f[0]),
                            crate::formats::files::quoted(f[1])
                        ),
                    )
                })?;
                let mut noise = Noise {
                    absolute: 0.0,
                    relative: 0.0,
                };
                for kv in &f[2..] {
                    let (k, v) = kv.split_once('=').ok_or_else(|| {
                        err(
                            ln,
                            format!(
                                "channel {}: {} is not KEY=VALUE",
                                crate::formats::files::quoted(f[0]),
                                crate::formats::files::quoted(kv)
                            ),
                        )
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
                                    "channel {}: {} = {} is not a non-negative number",
                                    crate::formats::files::quoted(f[0]),
                                    crate::formats::files::quoted(k),
                                    crate::formats::files::quoted(v)
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
                                    "channel {}: unknown key {} (relative, absolute)",
                                    crate::formats::files::quoted(f[0]),
                                    crate::formats::files::quoted(other)
                                ),
                            ));
                        }
                    }
                }
                if f[0].is_empty() {
                    return Err(err(ln, "channel: the name is empty".into()));
                }
                if let Some(c) = channels.iter().position(|c| c.name == f[0]) {
                    return Err(err(
                        ln,
                        format!(
                            "channel {} is declared twice (the {} '# channel:' line too)",
                            crate::formats::files::quoted(f[0]),
                            ordinal(c + 1)
                        ),
                    ));
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
            let mut with_std = want.clone();
            for c in &channels {
                with_std.push(format!("{}_re_std", c.name));
                with_std.push(format!("{}_im_std", c.name));
            }
            if cells == with_std {
                stds = true;
                header = Some((ln, with_std));
                continue;
            }
            if cells != want {
                return Err(err(
                    ln,
                    format!(
                        "the column header must be '{}', optionally followed by the standard \
                         deviations '{}'",
                        want.join(","),
                        with_std[want.len()..].join(",")
                    ),
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
                            "column {} ({}): {} is not a finite number",
                            c + 1,
                            names[c],
                            crate::formats::files::quoted(cells[c])
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
                    format!(
                        "column 2 (direction): {} is not up or down",
                        crate::formats::files::quoted(d)
                    ),
                ));
            }
        };
        let f = num(2)?;
        let k: usize = cells[3].parse().map_err(|_| {
            err(
                ln,
                format!(
                    "column 4 (harmonic): {} is not a harmonic number",
                    crate::formats::files::quoted(cells[3])
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
        let nc = channels.len();
        let sigma: Vec<c64> = if stds {
            (0..nc)
                .map(|c| {
                    let (a, b) = (6 + 2 * nc + 2 * c, 7 + 2 * nc + 2 * c);
                    if cells[a].is_empty() && cells[b].is_empty() {
                        return Ok(c64::new(f64::NAN, f64::NAN));
                    }
                    let v = c64::new(num(a)?, num(b)?);
                    if !(v.re > 0.0 && v.im > 0.0) {
                        return Err(err(
                            ln,
                            format!(
                                "columns {} and {} ({}, {}): standard deviations must be \
                                 positive (or both empty: the channel's noise model)",
                                a + 1,
                                b + 1,
                                names[a],
                                names[b]
                            ),
                        ));
                    }
                    Ok(v)
                })
                .collect::<Result<_>>()?
        } else {
            Vec::new()
        };
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
                        "column 1 (sweep): rows of sweep {} are not contiguous",
                        crate::formats::files::quoted(cells[0])
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
                sigma: if stds {
                    Mat::from_fn(channels.len(), h, |_, _| c64::new(f64::NAN, f64::NAN))
                } else {
                    Mat::new()
                },
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
        for (c, v) in sigma.into_iter().enumerate() {
            st.sigma[(c, k - 1)] = v;
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
    data.validate_measured()
        .map_err(|e| err(header.map_or(1, |h| h.0), e.to_string()))?;
    Ok(data)
}

/// Writes `data` in the CSV layout above (atomically: a temporary file, then a rename).
pub fn write_csv(path: &Path, data: &TestData) -> Result<()> {
    // What the readers would refuse is not written.
    data.validate_measured()
        .map_err(|e| Error::Usage(format!("{}: test data not written: {e}", path.display())))?;
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
    let stds = data
        .sweeps
        .iter()
        .any(|sw| sw.steps.iter().any(|st| st.sigma.nrows() > 0));
    if stds {
        for c in &data.channels {
            let _ = write!(s, ",{0}_re_std,{0}_im_std", c.name);
        }
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
                if stds {
                    for c in 0..data.channels.len() {
                        let given = c < st.sigma.nrows() && k < st.sigma.ncols();
                        match given.then(|| st.sigma[(c, k)]) {
                            Some(v) if !v.re.is_nan() => {
                                let _ = write!(s, ",{:?},{:?}", v.re, v.im);
                            }
                            _ => s.push_str(",,"),
                        }
                    }
                }
                s.push('\n');
            }
        }
    }
    let tmp = crate::formats::files::temp_path(path);
    std::fs::write(&tmp, s)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })
}

/// Test data by file extension (`nlsim calibrate`'s `DATA`): CSV, HDF5 (`.h5`, `.hdf5`) or linear FRFs in universal
/// file dataset 58 (`.uff`, `.unv`, `.uf`; ASCII or binary), whose drive point is the
/// model's single excitation and whose noise is `uff_noise` of each value.
pub fn read(path: &Path, model: &nlsim_kernel::Model, uff_noise: f64) -> Result<TestData> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "csv" if crate::formats::modal_data::is_modal_csv(path)? => Err(Error::Usage(format!(
            "{}: this is modal data (mode,frequency_hz,...), not a stepped-sine test: \
             `nlsim calibrate` runs it on its own (the modal calibration); it has no \
             batch kinds and no harmonic balance",
            path.display()
        ))),
        "csv" => read_csv(path),
        #[cfg(feature = "hdf5")]
        "h5" | "hdf5" => read_h5(path),
        #[cfg(not(feature = "hdf5"))]
        "h5" | "hdf5" => Err(crate::formats::files::without_hdf5(path)),
        "uff" | "unv" | "uf" => {
            let records = crate::formats::uff::read(path)?;
            let inputs: Vec<&str> = model.excitation().iter().map(|e| e.name.as_str()).collect();
            let [input] = inputs.as_slice() else {
                return Err(Error::Usage(format!(
                    "{}: FRFs name no drive point in the model's terms, so the model needs \
                     exactly one excitation (it has: {})",
                    path.display(),
                    inputs.join(", ")
                )));
            };
            crate::formats::uff::to_test_data(&records, input, Noise::relative(uff_noise)).map_err(
                // Invalid records are bad input; the line names the file.
                |e| Error::Usage(format!("{}: {e}", path.display())),
            )
        }
        _ => Err(Error::Usage(format!(
            "{}: test data must be .csv, .h5/.hdf5 or universal file dataset 58 \
             (.uff/.unv/.uf)",
            path.display()
        ))),
    }
}
