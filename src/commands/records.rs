//! Raw time records read and mapped onto a model: the file (CSV, HDF5 or universal file
//! datasets 58 of function type 1, [`crate::formats::time_records`]), its drive column and the
//! columns of the model's sensors (by name, by the column names `nlsim simulate` writes, or by
//! DOF label), each signal checked for clipping. `nlsim harmonics` and the time-domain
//! calibration (`nlsim calibrate --time-domain`) read their records through it.

use crate::error::{Error, Result};
use crate::formats::time_records::TimeRecords;
use nlsim_kernel::{Model, Quantity};
use std::path::Path;

/// Records mapped onto a model.
#[derive(Debug, Clone)]
pub struct MappedRecords {
    /// The records as read.
    pub records: TimeRecords,
    /// The drive's name (the model's excitation).
    pub drive: String,
    /// The drive's column in [`MappedRecords::records`].
    pub drive_column: usize,
    /// The sensors recorded: name and quantity, in column order.
    pub channels: Vec<(String, Quantity)>,
    /// The columns: the drive's, then one per channel.
    pub columns: Vec<usize>,
}

/// Time records from HDF5 ([`crate::formats::time_records_h5`]); refused in a build without
/// HDF5.
fn read_h5_records(path: &Path) -> Result<crate::formats::time_records::TimeRecords> {
    #[cfg(feature = "hdf5")]
    {
        crate::formats::time_records_h5::read_records_h5(path)
    }
    #[cfg(not(feature = "hdf5"))]
    {
        Err(Error::Usage(format!(
            "{}: this nlsim was built without HDF5; convert the records to CSV or rebuild \
             with the hdf5 feature",
            path.display()
        )))
    }
}

/// Time records by extension: `.uff`/`.unv`/`.uf` universal file (datasets 58 of function
/// type 1), `.h5`/`.hdf5`, else CSV.
pub fn read_any(path: &Path) -> Result<TimeRecords> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    match ext.as_deref() {
        Some("uff" | "unv" | "uf") => {
            let sets = crate::formats::uff::read(path)?;
            crate::formats::time_records::from_uff(&sets, path)
        }
        Some("h5" | "hdf5") => read_h5_records(path),
        _ => crate::formats::time_records::read_records(path),
    }
}

/// Refuses a signal clipped by its recorder: its largest or smallest value held for 4 or
/// more samples in a row, at least twice (every period of a clipped sine).
pub(crate) fn check_clipping(name: &str, x: &[f64], rec: &TimeRecords, path: &Path) -> Result<()> {
    let (lo, hi) = x
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &v| {
            (a.min(v), b.max(v))
        });
    if hi <= lo {
        return Ok(());
    }
    for bound in [hi, lo] {
        let mut runs = Vec::new();
        let mut run = 0usize;
        for (i, &v) in x.iter().enumerate() {
            if v == bound {
                run += 1;
                if run == 4 {
                    runs.push(i + 1 - 4);
                }
            } else {
                run = 0;
            }
        }
        if runs.len() >= 2 {
            return Err(Error::DataFile {
                file: path.to_path_buf(),
                line: rec.lines[runs[0]],
                message: format!(
                    "channel '{name}' is clipped: it holds {bound} for 4 or more samples in a \
                     row {} times, first at sample {}; record it with a larger range",
                    runs.len(),
                    runs[0] + 1
                ),
            });
        }
    }
    Ok(())
}

/// Reads the records at `path` (by extension: `.uff`/`.unv`/`.uf` universal file, `.h5`/`.hdf5`,
/// else CSV) and maps them onto `model` (`model_spec` names it in errors): the drive column
/// `drive` (default: the model's first excitation), every sensor's column; columns of element
/// displacements and forces a simulation wrote are passed over, any other is refused by name.
/// With `voltage` the drive is the amplifier's voltage: the column `DRIVE_voltage_V` (as
/// `nlsim test --raw` writes it) where there is one, else the drive's own; without, such a
/// voltage column is passed over.
pub fn map_records(
    model: &Model,
    model_spec: &str,
    path: &Path,
    drive: Option<&str>,
    voltage: bool,
) -> Result<MappedRecords> {
    let rec = read_any(path)?;
    let drive = match drive {
        Some(d) => d.to_string(),
        None => model
            .excitation()
            .first()
            .map(|e| e.name.clone())
            .ok_or_else(|| {
                Error::Usage(format!(
                    "model '{}' has no excitation to name the drive; give --drive COLUMN",
                    model_spec
                ))
            })?,
    };
    // Columns by name, or as `nlsim simulate` writes them (`NAME_QUANTITY_UNIT`,
    // `NAME_force_N`); element columns of a simulation are passed over.
    use crate::formats::history_file::{force_column, output_column};
    let drive_label = model
        .excitation()
        .iter()
        .find(|e| e.name == drive)
        .map(|e| format!("force@{}", e.at.label(model.dofs())));
    use crate::formats::raw_records::voltage_column;
    let voltage_col = voltage
        .then(|| rec.names.iter().position(|n| *n == voltage_column(&drive)))
        .flatten();
    let Some(d) = voltage_col.or_else(|| {
        rec.names.iter().position(|n| {
            *n == drive || *n == force_column(&drive) || drive_label.as_deref() == Some(n.as_str())
        })
    }) else {
        return Err(Error::Usage(format!(
            "{}: no column '{drive}' for the drive; the columns are {}",
            path.display(),
            rec.names.join(", ")
        )));
    };
    let mut channels = Vec::new();
    let mut columns = vec![d];
    for (j, name) in rec.names.iter().enumerate() {
        if j == d {
            continue;
        }
        if let Some(s) = model.sensors().iter().find(|s| {
            s.name == *name
                || output_column(&s.name, s.quantity) == *name
                || s.at.label(model.dofs()).to_string() == *name
        }) {
            channels.push((s.name.clone(), s.quantity));
            columns.push(j);
            continue;
        }
        let passed_over = model
            .elements()
            .iter()
            .any(|e| *name == format!("{}_u_m", e.name()) || *name == force_column(e.name()))
            || model
                .excitation()
                .iter()
                .any(|e| *name == force_column(&e.name) || *name == voltage_column(&e.name))
            || (voltage && (*name == drive || *name == force_column(&drive)));
        if passed_over {
            continue;
        }
        let known: Vec<&str> = model.sensors().iter().map(|s| s.name.as_str()).collect();
        return Err(Error::Usage(format!(
            "{}: column '{name}' is no sensor of model '{}' (its sensors: {}) nor the drive \
             '{drive}'",
            path.display(),
            model_spec,
            known.join(", ")
        )));
    }
    if channels.is_empty() {
        return Err(Error::Usage(format!(
            "{}: only the drive '{drive}' is recorded; add a sensor's column",
            path.display()
        )));
    }
    for &j in &columns {
        check_clipping(&rec.names[j], &rec.columns[j], &rec, path)?;
    }
    Ok(MappedRecords {
        records: rec,
        drive,
        drive_column: d,
        channels,
        columns,
    })
}
