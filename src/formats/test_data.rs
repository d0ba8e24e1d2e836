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
    let tmp = crate::formats::files::temp_path(path);
    std::fs::write(&tmp, s)
        .and_then(|()| std::fs::rename(&tmp, path))
        .map_err(|source| Error::Io {
            path: path.to_path_buf(),
            source,
        })
}

/// Most complex values a test-data HDF5 file may declare (16 bytes each: 1 GiB).
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

#[cfg(feature = "hdf5")]
const H5_MAX_VALUES: usize = 1 << 26;

/// The `unit` attribute of per-channel data in test-data HDF5: each channel's SI unit.
#[cfg(feature = "hdf5")]
const CHANNEL_UNIT: &str = "the channel's SI unit: m, m/s or m/s^2 by /channels/quantity";

#[cfg(feature = "hdf5")]
/// Writes `data` as HDF5 (documented in docs/file-formats.md; `h5py` reads it directly):
/// root attributes `format = "nlsim test data"`, `input`, `harmonics`; datasets
/// `channels/name`, `channels/quantity`, `channels/noise_relative`, `channels/noise_absolute`;
/// one group `sweeps/sweepN` (N from 0, measured order) per sweep with attributes `label`,
/// `direction` and datasets `frequency_hz` (steps), `force` (steps × H, complex) and
/// `response` (steps × channels × H, complex; NaN = not measured). Written atomically.
pub fn write_h5(path: &Path, data: &TestData) -> Result<()> {
    // What the readers would refuse is not written.
    data.validate_measured()
        .map_err(|e| Error::Usage(format!("{}: test data not written: {e}", path.display())))?;
    use crate::formats::files::h5err;
    use crate::formats::files::str_attr;
    use hdf5::types::VarLenUnicode;
    use hdf5_metno as hdf5;
    let tmp = crate::formats::files::temp_path(path);
    let vlen = |v: &[&str]| -> Vec<VarLenUnicode> {
        v.iter()
            .map(|s| s.parse().unwrap_or_else(|_| "?".parse().expect("ascii")))
            .collect()
    };
    (|| -> hdf5::Result<()> {
        let f = hdf5::File::create(&tmp)?;
        str_attr(&f, "nlsim_version", env!("CARGO_PKG_VERSION"))?;
        str_attr(&f, "command", "test data")?;
        str_attr(&f, "format", "nlsim test data")?;
        str_attr(&f, "input", &data.input)?;
        crate::formats::files::count_attr(&f, "harmonics", data.harmonics)?;
        let ch = f.create_group("channels")?;
        let names: Vec<&str> = data.channels.iter().map(|c| c.name.as_str()).collect();
        let quantities: Vec<&str> = data.channels.iter().map(|c| c.quantity.as_str()).collect();
        ch.new_dataset_builder()
            .with_data(&vlen(&names))
            .create("name")?;
        ch.new_dataset_builder()
            .with_data(&vlen(&quantities))
            .create("quantity")?;
        let rel: Vec<f64> = data.channels.iter().map(|c| c.noise.relative).collect();
        let abs: Vec<f64> = data.channels.iter().map(|c| c.noise.absolute).collect();
        let d = ch
            .new_dataset_builder()
            .with_data(&rel)
            .create("noise_relative")?;
        str_attr(&d, "unit", "1")?;
        let d = ch
            .new_dataset_builder()
            .with_data(&abs)
            .create("noise_absolute")?;
        str_attr(&d, "unit", CHANNEL_UNIT)?;
        let sweeps = f.create_group("sweeps")?;
        let (nc, h) = (data.channels.len(), data.harmonics);
        for (i, sw) in data.sweeps.iter().enumerate() {
            let g = sweeps.create_group(&format!("sweep{i}"))?;
            str_attr(&g, "label", &sw.label)?;
            str_attr(&g, "direction", sw.direction.as_str())?;
            let n = sw.steps.len();
            let freq: Vec<f64> = sw.steps.iter().map(|s| s.frequency_hz).collect();
            let d = g
                .new_dataset_builder()
                .with_data(&freq)
                .create("frequency_hz")?;
            str_attr(&d, "unit", "Hz")?;
            let force: Vec<c64> = sw
                .steps
                .iter()
                .flat_map(|s| s.force.iter().copied())
                .collect();
            let d = g.new_dataset::<c64>().shape((n, h)).create("force")?;
            d.write_raw(&force)?;
            str_attr(&d, "unit", "N")?;
            let resp: Vec<c64> = sw
                .steps
                .iter()
                .flat_map(|s| (0..nc).flat_map(move |c| (0..h).map(move |k| s.response[(c, k)])))
                .collect();
            let d = g
                .new_dataset::<c64>()
                .shape((n, nc, h))
                .create("response")?;
            d.write_raw(&resp)?;
            str_attr(&d, "unit", CHANNEL_UNIT)?;
        }
        Ok(())
    })()
    .map_err(h5err(path))?;
    std::fs::rename(&tmp, path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(feature = "hdf5")]
/// Reads test data written in the layout of [`write_h5`] (by nlsim or by any HDF5 tool);
/// errors name the file and the object. Declared sizes are checked against the datasets'
/// shapes and a budget of 2²⁶ values before anything is read.
pub fn read_h5(path: &Path) -> Result<TestData> {
    use hdf5::types::VarLenUnicode;
    use hdf5_metno as hdf5;
    let err = |object: &str, message: String| Error::Hdf5 {
        path: path.to_path_buf(),
        message: format!("{object}: {message}"),
    };
    crate::formats::files::regular_file(path)?;
    let f = hdf5::File::open(path).map_err(|e| err("file", e.to_string()))?;
    let str_attr = |loc: &hdf5::Location, object: &str, name: &str| -> Result<String> {
        loc.attr(name)
            .and_then(|a| a.read_scalar::<VarLenUnicode>())
            .map(|s| s.as_str().to_string())
            .map_err(|e| err(object, format!("attribute '{name}': {e}")))
    };
    let format = str_attr(&f, "/", "format")?;
    if format != "nlsim test data" {
        return Err(err(
            "/",
            format!(
                "format {} is not 'nlsim test data'",
                crate::formats::files::quoted(&format)
            ),
        ));
    }
    let input = str_attr(&f, "/", "input")?;
    let harmonics = f
        .attr("harmonics")
        .and_then(|a| a.read_scalar::<u64>())
        .map_err(|e| err("/", format!("attribute 'harmonics': {e}")))? as usize;
    if harmonics == 0 || harmonics > 1000 {
        return Err(err("/", format!("harmonics = {harmonics} (1..=1000)")));
    }
    let dataset = |name: &str, shape: &[usize]| -> Result<hdf5::Dataset> {
        let d = f.dataset(name).map_err(|e| err(name, e.to_string()))?;
        let found = d.shape();
        if found != shape {
            return Err(err(name, format!("shape {found:?}, expected {shape:?}")));
        }
        Ok(d)
    };
    let complex_dataset = |name: &str, shape: &[usize]| -> Result<hdf5::Dataset> {
        let d = dataset(name, shape)?;
        crate::formats::files::complex_layout(&d).map_err(|m| err(name, m))?;
        Ok(d)
    };
    let nc = f
        .dataset("channels/name")
        .map_err(|e| err("channels/name", e.to_string()))?
        .shape()
        .first()
        .copied()
        .unwrap_or(0);
    if nc == 0 || nc > 10_000 {
        return Err(err("channels/name", format!("{nc} channels (1..=10000)")));
    }
    let strings = |name: &str| -> Result<Vec<String>> {
        dataset(name, &[nc])?
            .read_raw::<VarLenUnicode>()
            .map(|v| v.iter().map(|s| s.as_str().to_string()).collect())
            .map_err(|e| err(name, e.to_string()))
    };
    let reals = |name: &str| -> Result<Vec<f64>> {
        dataset(name, &[nc])?
            .read_raw::<f64>()
            .map_err(|e| err(name, e.to_string()))
    };
    let names = strings("channels/name")?;
    let quantities = strings("channels/quantity")?;
    let rel = reals("channels/noise_relative")?;
    let abs = reals("channels/noise_absolute")?;
    let mut channels = Vec::with_capacity(nc);
    for c in 0..nc {
        channels.push(Channel {
            name: names[c].clone(),
            quantity: quantity(&quantities[c]).ok_or_else(|| {
                err(
                    "channels/quantity",
                    format!(
                        "entry {c}: {} is not displacement, velocity or acceleration",
                        crate::formats::files::quoted(&quantities[c])
                    ),
                )
            })?,
            noise: Noise {
                absolute: abs[c],
                relative: rel[c],
            },
        });
    }
    let group = f
        .group("sweeps")
        .map_err(|e| err("sweeps", e.to_string()))?;
    let n_sweeps = group.len() as usize;
    let mut sweeps = Vec::with_capacity(n_sweeps.min(10_000));
    let mut budget = H5_MAX_VALUES;
    for i in 0..n_sweeps {
        let gname = format!("sweeps/sweep{i}");
        let g = f.group(&gname).map_err(|_| {
            err(
                &gname,
                format!("missing: the sweeps must be sweep0..sweep{}", n_sweeps - 1),
            )
        })?;
        let label = str_attr(&g, &gname, "label")?;
        let dir = str_attr(&g, &gname, "direction")?;
        let direction = match dir.as_str() {
            "up" => SweepDirection::Up,
            "down" => SweepDirection::Down,
            _ => {
                return Err(err(
                    &gname,
                    format!(
                        "direction {} is not up or down",
                        crate::formats::files::quoted(&dir)
                    ),
                ));
            }
        };
        let fname = format!("{gname}/frequency_hz");
        let n = f
            .dataset(&fname)
            .map_err(|e| err(&fname, e.to_string()))?
            .shape()
            .first()
            .copied()
            .unwrap_or(0);
        let values = n.saturating_mul(nc + 1).saturating_mul(harmonics);
        if values > budget {
            return Err(err(
                &gname,
                format!(
                    "{n} steps × {nc} channels × {harmonics} harmonics exceed the budget of {H5_MAX_VALUES} values"
                ),
            ));
        }
        budget -= values;
        let freq = dataset(&fname, &[n])?
            .read_raw::<f64>()
            .map_err(|e| err(&fname, e.to_string()))?;
        let force_name = format!("{gname}/force");
        let force = complex_dataset(&force_name, &[n, harmonics])?
            .read_raw::<c64>()
            .map_err(|e| err(&force_name, e.to_string()))?;
        let resp_name = format!("{gname}/response");
        let resp = complex_dataset(&resp_name, &[n, nc, harmonics])?
            .read_raw::<c64>()
            .map_err(|e| err(&resp_name, e.to_string()))?;
        let steps = (0..n)
            .map(|s| Step {
                frequency_hz: freq[s],
                force: force[s * harmonics..(s + 1) * harmonics].to_vec(),
                response: Mat::from_fn(nc, harmonics, |c, k| resp[(s * nc + c) * harmonics + k]),
            })
            .collect();
        sweeps.push(Sweep {
            label,
            direction,
            steps,
        });
    }
    let data = TestData {
        input,
        channels,
        harmonics,
        sweeps,
    };
    data.validate_measured()
        .map_err(|e| err("/", e.to_string()))?;
    Ok(data)
}
