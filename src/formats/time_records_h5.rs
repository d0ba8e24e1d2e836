//! Raw time histories in HDF5, as `nlsim harmonics` reads them (docs/file-formats.md, "Time
//! histories"): the layout `nlsim simulate --out F.h5` writes, or the same flattened.
//!
//! - `/time` (or `/time_s`): f64 `[n]`, the sample times (s), evenly spaced (each within 1 % of
//!   a sample interval of the even grid from the first to the last);
//! - the signals: every floating-point dataset of shape `[n]` in `/inputs` (drives, e.g. the
//!   force or the amplifier's voltage), in `/outputs` (sensors) and at the root besides the
//!   time, named by its dataset name. Groups such as `/elements` and `/events` are passed
//!   over.
//!
//! Shapes, types and a budget of [`H5_MAX_SAMPLES`] values are checked before anything is
//! read; errors name the file and the dataset.

use crate::error::{Error, Result};
use crate::formats::time_records::TimeRecords;
use hdf5_metno as hdf5;
use std::path::Path;

/// Most values (samples of every signal, the time included) read from one file (2²⁷: 1 GiB).
pub const H5_MAX_SAMPLES: usize = 1 << 27;

/// Reads time histories from the HDF5 file `path` (see the module documentation).
pub fn read_records_h5(path: &Path) -> Result<TimeRecords> {
    let err = |object: &str, message: String| Error::Hdf5 {
        path: path.to_path_buf(),
        message: format!("{object}: {message}"),
    };
    crate::formats::files::input_file(path)?;
    let f = hdf5::File::open(path).map_err(|e| err("file", e.to_string()))?;
    // A one-dimensional floating-point dataset: its length.
    let series = |d: &hdf5::Dataset, name: &str| -> Result<Option<usize>> {
        let shape = d.shape();
        let float = matches!(
            d.dtype().and_then(|t| t.to_descriptor()),
            Ok(hdf5::types::TypeDescriptor::Float(_))
        );
        if shape.len() != 1 || !float {
            return Ok(None);
        }
        if shape[0] > H5_MAX_SAMPLES {
            return Err(err(
                name,
                format!("{} samples exceed the budget of {H5_MAX_SAMPLES}", shape[0]),
            ));
        }
        Ok(Some(shape[0]))
    };
    let time_name = ["time", "time_s"]
        .into_iter()
        .find(|n| f.link_exists(n))
        .ok_or_else(|| {
            err(
                "/",
                "no '/time' dataset: the sample times (s), f64 [n], as `nlsim simulate --out \
                 F.h5` writes them"
                    .into(),
            )
        })?;
    let td = f
        .dataset(time_name)
        .map_err(|e| err(time_name, e.to_string()))?;
    let n = series(&td, time_name)?.ok_or_else(|| {
        err(
            time_name,
            format!("shape {:?}: expected f64 [n]", td.shape()),
        )
    })?;
    if n < 2 {
        return Err(err(
            time_name,
            format!("{n} sample(s); a time history needs at least 2"),
        ));
    }
    // The signals, named and checked before any is read.
    let mut found: Vec<(String, hdf5::Dataset)> = Vec::new();
    for (group, prefix) in [("inputs", "inputs/"), ("outputs", "outputs/"), ("/", "")] {
        if group != "/" && !f.link_exists(group) {
            continue;
        }
        let g = f.group(group).map_err(|e| err(group, e.to_string()))?;
        let members = g.member_names().map_err(|e| err(group, e.to_string()))?;
        for m in members {
            if group == "/" && m == time_name {
                continue;
            }
            let Ok(d) = g.dataset(&m) else {
                continue;
            };
            let at = format!("{prefix}{m}");
            match series(&d, &at)? {
                Some(len) if len == n => {}
                Some(len) => {
                    return Err(err(
                        &at,
                        format!(
                            "{len} samples; '{time_name}' has {n}: every signal is sampled at the same times"
                        ),
                    ));
                }
                // In /inputs and /outputs every dataset is a signal: one that is not f64 [n]
                // is refused, not passed over (a sensor left out would calibrate on the rest).
                None if group != "/" => {
                    return Err(err(
                        &at,
                        format!(
                            "shape {:?} of {}: a signal is a floating-point dataset [{n}] \
                             (convert integer counts to units first)",
                            d.shape(),
                            d.dtype()
                                .and_then(|t| t.to_descriptor())
                                .map_or_else(|e| e.to_string(), |t| t.to_string())
                        ),
                    ));
                }
                None => continue,
            }
            if found.iter().any(|(name, _)| *name == m) {
                return Err(err(&at, format!("a second signal named '{m}'")));
            }
            found.push((m, d));
        }
    }
    if found.is_empty() {
        return Err(err(
            "/",
            format!(
                "no signal: put the drive and the sensors as f64 [{n}] datasets in /inputs and \
                 /outputs (or at the root)"
            ),
        ));
    }
    let total = n.saturating_mul(found.len() + 1);
    if total > H5_MAX_SAMPLES {
        return Err(err(
            "/",
            format!(
                "{} signals of {n} samples exceed the budget of {H5_MAX_SAMPLES} values",
                found.len()
            ),
        ));
    }
    let read = |d: &hdf5::Dataset, name: &str| -> Result<Vec<f64>> {
        d.read_raw::<f64>().map_err(|e| err(name, e.to_string()))
    };
    let time = read(&td, time_name)?;
    if let Some(k) = time.iter().position(|t| !t.is_finite()) {
        return Err(err(
            time_name,
            format!("sample {} is {}: times are finite seconds", k + 1, time[k]),
        ));
    }
    let dt = (time[n - 1] - time[0]) / (n - 1) as f64;
    if dt <= 0.0 {
        return Err(err(
            time_name,
            "the times do not increase from the first sample to the last".into(),
        ));
    }
    if let Some(m) = crate::formats::time_records::coarse_times(time[0], time[n - 1], dt) {
        return Err(err(time_name, m));
    }
    if let Some(k) = (0..n).find(|&k| (time[k] - (time[0] + k as f64 * dt)).abs() > 0.01 * dt) {
        return Err(err(
            time_name,
            format!(
                "sample {} at {} s is off the even sampling ({:.6} Hz from the first and last \
                 times); resample the record evenly",
                k + 1,
                time[k],
                1.0 / dt
            ),
        ));
    }
    let mut names = Vec::with_capacity(found.len());
    let mut columns = Vec::with_capacity(found.len());
    for (name, d) in &found {
        columns.push(read(d, name)?);
        names.push(name.clone());
    }
    Ok(TimeRecords {
        rate_hz: 1.0 / dt,
        start_s: time[0],
        names,
        columns,
        // No line per sample: errors name the sample.
        lines: (1..=n).collect(),
    })
}
