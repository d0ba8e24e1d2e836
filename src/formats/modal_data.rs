//! Measured modal data as CSV, for the linear stage of `nlsim calibrate` (FE-level parameters
//! from natural frequencies and mode shapes; [`nlsim_calib::ModalData`]).
//!
//! ```text
//! # comments start with '#'
//! mode,frequency_hz,frequency_std_hz,1:ux,3:ux,6:ux
//! 1,4.9884,0.005,0.121,0.452,1.0
//! 2,13.041,0.013,,,
//! ```
//!
//! One row per measured mode: its number (a label, any positive integer), the natural
//! frequency and its standard deviation (Hz), then the mode shape at the sensor DOFs named
//! by the header's labels (any scale and sign; the calibration normalises it). A mode whose
//! shape was not measured leaves every shape cell empty. The shape noise (per component of a
//! unit-normalised shape) is a setting of the calibration, not of the file.

use crate::error::{Error, Result};
use nlsim_calib::{MeasuredMode, ModalData};
use nlsim_kernel::Model;
use std::fmt::Write as _;
use std::path::Path;

/// The first three header columns.
const HEAD: [&str; 3] = ["mode", "frequency_hz", "frequency_std_hz"];

/// Measured modal data with the number each mode carries in the file.
#[derive(Debug, Clone, PartialEq)]
pub struct ModalFile {
    /// The data (shape noise as given to [`read_modal_csv`]).
    pub data: ModalData,
    /// The mode number of each row.
    pub labels: Vec<usize>,
}

/// True when the first line of `path` that is not a comment or blank is a modal data header
/// (`mode,frequency_hz,...`): how `nlsim calibrate` tells modal data from a stepped-sine CSV.
pub fn is_modal_csv(path: &Path) -> Result<bool> {
    let text = crate::formats::files::read_text(path)?;
    Ok(text
        .lines()
        .map(str::trim)
        .find(|l| !l.is_empty() && !l.starts_with('#'))
        .is_some_and(|l| l.split(',').map(str::trim).take(3).eq(HEAD)))
}

/// Reads modal data for `model` (whose DOF labels the shape columns name), with shape noise
/// `shape_std`. Errors name the file, the line and the column.
pub fn read_modal_csv(path: &Path, model: &Model, shape_std: f64) -> Result<ModalFile> {
    let text = crate::formats::files::read_text(path)?;
    parse_modal_csv(&text, path, model, shape_std)
}

/// Parses modal CSV text of `path` (see [`read_modal_csv`]).
pub fn parse_modal_csv(
    text: &str,
    path: &Path,
    model: &Model,
    shape_std: f64,
) -> Result<ModalFile> {
    let err = |line: usize, message: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message,
    };
    let mut dofs: Option<Vec<usize>> = None;
    let mut header: Vec<String> = Vec::new();
    let mut modes = Vec::new();
    let mut labels = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let ln = i + 1;
        let line = raw.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if dofs.is_none() {
            if !cells.iter().take(3).copied().eq(HEAD) {
                return Err(err(
                    ln,
                    format!(
                        "the header must start with {}, then one DOF label per shape \
                         component (e.g. 12:uz)",
                        HEAD.join(",")
                    ),
                ));
            }
            let mut found = Vec::with_capacity(cells.len() - 3);
            for (c, label) in cells.iter().enumerate().skip(3) {
                let d = model.dofs().find(label).map_err(|e| {
                    err(
                        ln,
                        format!(
                            "column {} ({}): {e}",
                            c + 1,
                            crate::formats::files::quoted(label)
                        ),
                    )
                })?;
                if found.contains(&d) {
                    return Err(err(
                        ln,
                        format!(
                            "column {} ({}): this DOF is named twice",
                            c + 1,
                            crate::formats::files::quoted(label)
                        ),
                    ));
                }
                found.push(d);
            }
            header = cells.iter().map(|c| c.to_string()).collect();
            dofs = Some(found);
            continue;
        }
        if cells.len() != header.len() {
            return Err(err(
                ln,
                format!(
                    "{} fields, the header has {} (leave a shape cell empty, not out)",
                    cells.len(),
                    header.len()
                ),
            ));
        }
        let num = |c: usize| -> Result<f64> {
            let v: f64 = cells[c].parse().map_err(|_| {
                err(
                    ln,
                    format!(
                        "column {} ({}): {} is not a number",
                        c + 1,
                        crate::formats::files::quoted(&header[c]),
                        crate::formats::files::quoted(cells[c])
                    ),
                )
            })?;
            if v.is_finite() {
                Ok(v)
            } else {
                Err(err(
                    ln,
                    format!("column {} ({}): {v} is not finite", c + 1, header[c]),
                ))
            }
        };
        let label: usize = cells[0].parse().ok().filter(|&l| l > 0).ok_or_else(|| {
            err(
                ln,
                format!(
                    "column 1 (mode): {} is not a positive mode number",
                    crate::formats::files::quoted(cells[0])
                ),
            )
        })?;
        if labels.contains(&label) {
            return Err(err(
                ln,
                format!("column 1 (mode): mode {label} is listed twice"),
            ));
        }
        let frequency_hz = num(1)?;
        let frequency_std_hz = num(2)?;
        for (c, v) in [(1, frequency_hz), (2, frequency_std_hz)] {
            if v <= 0.0 {
                return Err(err(
                    ln,
                    format!(
                        "column {} ({}): must be positive, not {v}",
                        c + 1,
                        header[c]
                    ),
                ));
            }
        }
        let empty = cells[3..].iter().filter(|c| c.is_empty()).count();
        let shape = if empty == cells.len() - 3 {
            None
        } else if let Some(c) = cells[3..].iter().position(|c| c.is_empty()) {
            return Err(err(
                ln,
                format!(
                    "column {} ({}): empty while other shape cells of mode {label} are not; \
                     give the whole shape or none of it",
                    c + 4,
                    header[c + 3]
                ),
            ));
        } else {
            Some((3..cells.len()).map(num).collect::<Result<Vec<f64>>>()?)
        };
        if shape.as_ref().is_some_and(|s| s.iter().all(|v| *v == 0.0)) {
            return Err(err(ln, format!("the shape of mode {label} is all zero")));
        }
        let mode = MeasuredMode {
            frequency_hz,
            frequency_std_hz,
            shape,
        };
        // Each mode checked on its own line, the whole data after the rows.
        if let Some(why) = mode.fault() {
            return Err(err(ln, format!("mode {label}: {why}")));
        }
        labels.push(label);
        modes.push(mode);
    }
    let Some(dofs) = dofs else {
        return Err(err(
            1,
            "no header (mode,frequency_hz,frequency_std_hz,...)".into(),
        ));
    };
    if modes.is_empty() {
        return Err(err(text.lines().count().max(1), "no modes".into()));
    }
    let data = ModalData {
        dofs,
        shape_std,
        modes,
    };
    data.validate(model.n_dofs()).map_err(|e| Error::DataFile {
        file: path.to_path_buf(),
        line: 1,
        message: e.to_string(),
    })?;
    Ok(ModalFile { data, labels })
}

/// The CSV text of `file` for `model` (the inverse of [`parse_modal_csv`]; values in full
/// precision).
pub fn modal_csv(file: &ModalFile, model: &Model) -> String {
    let mut s = String::from("mode,frequency_hz,frequency_std_hz");
    for &d in &file.data.dofs {
        let _ = write!(s, ",{}", model.dofs().labels()[d]);
    }
    s.push('\n');
    for (m, label) in file.data.modes.iter().zip(&file.labels) {
        let _ = write!(s, "{label},{:?},{:?}", m.frequency_hz, m.frequency_std_hz);
        for k in 0..file.data.dofs.len() {
            match &m.shape {
                Some(v) => {
                    let _ = write!(s, ",{:?}", v[k]);
                }
                None => s.push(','),
            }
        }
        s.push('\n');
    }
    s
}
