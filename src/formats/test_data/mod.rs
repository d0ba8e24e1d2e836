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
mod table;
#[cfg(feature = "hdf5")]
pub use h5::{read_h5, write_h5};
pub use table::{is_amplitude_phase, parse_amplitude_phase};

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

/// Cell `j` of a CSV row as a finite number; the message names the column (1-based), its
/// name from `names` and the cell.
pub(crate) fn finite_cell(
    cells: &[&str],
    names: &[impl AsRef<str>],
    j: usize,
) -> std::result::Result<f64, String> {
    cells[j]
        .parse::<f64>()
        .ok()
        .filter(|v| v.is_finite())
        .ok_or_else(|| {
            format!(
                "column {} ({}): {} is not a finite number",
                j + 1,
                names[j].as_ref(),
                crate::formats::files::quoted(cells[j])
            )
        })
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
    let mut drive = nlsim_calib::Drive::Force;
    let mut harmonics = None;
    let mut channels: Vec<Channel> = Vec::new();
    let mut header: Option<(usize, Vec<String>)> = None;
    // The header carries `<channel>_re_std,<channel>_im_std` columns.
    let mut stds = false;
    let mut sweeps: Vec<Sweep> = Vec::new();
    let mut labels = std::collections::HashSet::new();
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
                // `NAME` or `NAME, voltage` (or `, force`): what was recorded there.
                let (name, kind) = match v.split_once(',') {
                    Some((n, k)) => (n.trim(), Some(k.trim())),
                    None => (v.trim(), None),
                };
                if let Some(k) = kind {
                    drive = nlsim_calib::Drive::parse(k).ok_or_else(|| {
                        err(
                            ln,
                            format!(
                                "input: the drive record {} is not 'force' or 'voltage'",
                                crate::formats::files::quoted(k)
                            ),
                        )
                    })?;
                }
                input = Some(name.to_string());
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
        let num = |c: usize| finite_cell(&cells, names, c).map_err(|m| err(ln, m));
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
            // A set of the labels seen: one lookup per sweep, not a scan of every earlier one.
            if !labels.insert(cells[0].to_string()) {
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
        drive,
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
    match data.drive {
        nlsim_calib::Drive::Force => {
            let _ = writeln!(s, "# input: {}", data.input);
        }
        nlsim_calib::Drive::Voltage => {
            let _ = writeln!(s, "# input: {}, voltage", data.input);
        }
    }
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
    crate::formats::files::write_text_atomically(path, &s)
}

/// What a test-data file does not say, given beside it (calibration-file keys, options of
/// `nlsim calibrate` and `nlsim validate`).
#[derive(Debug, Clone, PartialEq)]
pub struct DataOptions {
    /// Relative noise of every value of data that carry no noise model (UFF 58 and
    /// amplitude-and-phase tables), a fraction of the amplitude (default 0.01).
    pub noise: f64,
    /// Added to every measured response phase, degrees (default 0): the data's phase
    /// convention, e.g. 180 for acceleration amplitudes whose phase was recorded as that of a
    /// displacement-like response (−90° at resonance), or a sensor mounted the other way.
    pub phase_offset_deg: f64,
}

impl Default for DataOptions {
    fn default() -> Self {
        Self {
            noise: 0.01,
            phase_offset_deg: 0.0,
        }
    }
}

impl DataOptions {
    /// `Err` naming the setting when the noise is not positive or the offset not finite.
    pub fn check(&self) -> std::result::Result<(), (&'static str, String)> {
        if !(self.noise.is_finite() && self.noise > 0.0) {
            return Err(("data_noise", format!("{} must be positive", self.noise)));
        }
        if !self.phase_offset_deg.is_finite() || self.phase_offset_deg.abs() > 360.0 {
            return Err((
                "phase_offset_deg",
                format!(
                    "{} is not an angle in [-360, 360] degrees",
                    self.phase_offset_deg
                ),
            ));
        }
        Ok(())
    }

    /// Turns every measured response by the phase offset; per-step standard deviations of
    /// the real and imaginary parts follow when the offset is a multiple of 90° (else `Err`:
    /// the turned parts would be correlated).
    fn apply(&self, path: &Path, data: &mut TestData) -> Result<()> {
        if self.phase_offset_deg == 0.0 {
            return Ok(());
        }
        let quarter = self.phase_offset_deg / 90.0;
        let has_std = data
            .sweeps
            .iter()
            .any(|s| s.steps.iter().any(|st| st.sigma.nrows() > 0));
        if has_std && quarter.fract() != 0.0 {
            return Err(Error::Usage(format!(
                "{}: phase_offset_deg = {} with per-step standard deviations of the real and \
                 imaginary parts: use a multiple of 90 degrees",
                path.display(),
                self.phase_offset_deg
            )));
        }
        // Exact at multiples of 90°: no rounding of cos(π/2) into the parts.
        let quarters = (quarter.fract() == 0.0).then(|| (quarter as i64).rem_euclid(4));
        let turn = match quarters {
            Some(0) => c64::new(1.0, 0.0),
            Some(1) => c64::new(0.0, 1.0),
            Some(2) => c64::new(-1.0, 0.0),
            Some(_) => c64::new(0.0, -1.0),
            None => c64::from_polar(1.0, self.phase_offset_deg.to_radians()),
        };
        // An odd number of quarter turns swaps the real and imaginary parts' deviations.
        let swap = quarters.is_some_and(|q| q % 2 == 1);
        for st in data.sweeps.iter_mut().flat_map(|s| s.steps.iter_mut()) {
            for y in st.response.col_iter_mut().flat_map(|c| c.iter_mut()) {
                if !y.re.is_nan() {
                    *y *= turn;
                }
            }
            if swap {
                for v in st.sigma.col_iter_mut().flat_map(|c| c.iter_mut()) {
                    *v = c64::new(v.im, v.re);
                }
            }
        }
        Ok(())
    }
}

/// The indices (ascending) of the sweeps of `data` that `selection` names — each entry a
/// sweep label, a pattern with `*` wildcards (`force-*`) or a 1-based index; `what` names the
/// selection in errors (e.g. `train`). `Err` for an entry that matches no sweep.
pub fn sweep_indices(data: &TestData, selection: &[String], what: &str) -> Result<Vec<usize>> {
    let labels: Vec<&str> = data.sweeps.iter().map(|s| s.label.as_str()).collect();
    let mut keep = vec![false; labels.len()];
    for entry in selection {
        let hits: Vec<usize> = match entry.parse::<usize>() {
            Ok(i) if labels.iter().all(|l| l != entry) => {
                if i == 0 || i > labels.len() {
                    return Err(Error::Usage(format!(
                        "{what}: sweep {i} does not exist (the data have {} sweeps)",
                        labels.len()
                    )));
                }
                vec![i - 1]
            }
            _ => (0..labels.len())
                .filter(|&i| glob(entry, labels[i]))
                .collect(),
        };
        if hits.is_empty() {
            return Err(Error::Usage(format!(
                "{what}: {} matches no sweep (the data have: {})",
                crate::formats::files::quoted(entry),
                labels.join(", ")
            )));
        }
        for i in hits {
            keep[i] = true;
        }
    }
    Ok((0..keep.len()).filter(|&i| keep[i]).collect())
}

/// The sweeps of `data` that `selection` names ([`sweep_indices`]), in data order; all of
/// them for an empty selection.
pub fn select_sweeps(data: &TestData, selection: &[String], what: &str) -> Result<TestData> {
    if selection.is_empty() {
        return Ok(data.clone());
    }
    Ok(data.select_sweeps(&sweep_indices(data, selection, what)?)?)
}

/// Whether `text` matches `pattern`, where `*` stands for any run of characters.
fn glob(pattern: &str, text: &str) -> bool {
    let parts: Vec<&str> = pattern.split('*').collect();
    if parts.len() == 1 {
        return pattern == text;
    }
    let (first, last) = (parts[0], parts[parts.len() - 1]);
    if !text.starts_with(first) || text.len() < first.len() + last.len() || !text.ends_with(last) {
        return false;
    }
    let mut rest = &text[first.len()..text.len() - last.len()];
    for p in &parts[1..parts.len() - 1] {
        match rest.find(p) {
            Some(i) => rest = &rest[i + p.len()..],
            None => return false,
        }
    }
    true
}

/// Test data by file extension (`nlsim calibrate`'s `DATA`): CSV (nlsim's stepped-sine
/// layout, or an amplitude-and-phase table, recognised by its header), HDF5 (`.h5`,
/// `.hdf5`) or linear FRFs in universal file dataset 58 (`.uff`, `.unv`, `.uf`; ASCII or
/// binary). Data without a drive point name (tables, UFF) are driven at the model's single
/// excitation, and data without a noise model get `options.noise` of each value; the phase
/// offset of `options` is applied to every response.
pub fn read(path: &Path, model: &nlsim_kernel::Model, options: &DataOptions) -> Result<TestData> {
    options
        .check()
        .map_err(|(k, m)| Error::Usage(format!("{}: {k}: {m}", path.display())))?;
    let input = |what: &str| single_input(path, model, what).map(str::to_string);
    let mut data = read_as_given(path, &input, options)?;
    options.apply(path, &mut data)?;
    Ok(data)
}

/// [`read`] without a model: data that name no drive point (tables, UFF) are driven at
/// `drive` (`nlsim backbone` reads the measurements alone).
pub fn read_standalone(path: &Path, drive: &str, options: &DataOptions) -> Result<TestData> {
    options
        .check()
        .map_err(|(k, m)| Error::Usage(format!("{}: {k}: {m}", path.display())))?;
    let mut data = read_as_given(path, &|_| Ok(drive.to_string()), options)?;
    options.apply(path, &mut data)?;
    Ok(data)
}

/// The model's single excitation, the drive point of data that name none.
fn single_input<'a>(path: &Path, model: &'a nlsim_kernel::Model, what: &str) -> Result<&'a str> {
    let inputs: Vec<&str> = model.excitation().iter().map(|e| e.name.as_str()).collect();
    let [input] = inputs.as_slice() else {
        return Err(Error::Usage(format!(
            "{}: {what} name no drive point in the model's terms, so the model needs \
             exactly one excitation (it has: {})",
            path.display(),
            if inputs.is_empty() {
                "none".to_string()
            } else {
                inputs.join(", ")
            }
        )));
    };
    Ok(input)
}

/// The data at `path` as held; `input(what)` names the drive of data that name none.
fn read_as_given(
    path: &Path,
    input: &dyn Fn(&str) -> Result<String>,
    options: &DataOptions,
) -> Result<TestData> {
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
        "csv" => {
            let text = crate::formats::files::read_text(path)?;
            if is_amplitude_phase(&text) {
                let input = input("amplitude-and-phase tables")?;
                parse_amplitude_phase(&text, path, &input, Noise::relative(options.noise))
            } else {
                parse_csv(&text, path)
            }
        }
        #[cfg(feature = "hdf5")]
        "h5" | "hdf5" => read_h5(path),
        #[cfg(not(feature = "hdf5"))]
        "h5" | "hdf5" => Err(crate::formats::files::without_hdf5(path)),
        "uff" | "unv" | "uf" => {
            let records = crate::formats::uff::read(path)?;
            let input = input("FRFs")?;
            crate::formats::uff::to_test_data(&records, &input, Noise::relative(options.noise))
                .map_err(
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
