//! The raw records of `nlsim test --raw` (docs/file-formats.md, "Raw records of a virtual
//! test"): the time histories the test's recorder holds, in the layouts `nlsim harmonics` and
//! `nlsim calibrate --time-domain` read ([`crate::formats::time_records`]), and its step
//! table.
//!
//! - CSV: `time_s`, one column per sensor (`NAME_QUANTITY_UNIT`, as `nlsim simulate` writes
//!   them), the force gauge `DRIVE_force_N` (unless only the voltage is recorded) and the
//!   voltage into the amplifier `DRIVE_voltage_V`; `#` lines say what made them.
//! - HDF5: `/time_s`, `/outputs/SENSOR`, `/inputs/DRIVE` (force, N) and
//!   `/inputs/DRIVE_voltage_V`, each with a `unit` attribute.
//! - Universal file: one dataset 58 (function type 1, time response) per signal, named by the
//!   first word of its ID line 1; the voltage has ordinate type 1 (general, labelled volts).
//! - The step table (CSV, `start_s,end_s,frequency_hz,sweep`): the measured window of each
//!   step (after its settling), as `nlsim harmonics --steps` reads it.

use crate::error::{Error, Result};
use crate::formats::files::Format;
use crate::formats::history_file::{force_column, output_column};
use nlsim_calib::{Drive, RawRecord};
use nlsim_kernel::Quantity;
use std::fmt::Write as _;
use std::path::Path;

/// What the raw records hold beside the samples.
#[derive(Debug, Clone)]
pub struct RawInfo<'a> {
    /// Model spec as given.
    pub model_spec: &'a str,
    /// The drive (the model's excitation the shaker drives).
    pub drive: &'a str,
    /// What the lab records at the drive: force and voltage, or voltage alone.
    pub record: Drive,
    /// Amplifier gain (V at the coil per V in): the voltage column is the coil's over it.
    pub amplifier_gain: f64,
    /// The sensors recorded, by name; empty: every sensor of the record.
    pub channels: &'a [String],
    /// One comment line on the noise and seed.
    pub noise: String,
    /// The model's name (for the HDF5 provenance).
    pub model_name: &'a str,
    /// UFF node and direction of each sensor and of the drive, by name.
    pub sites: &'a [(String, (i64, i64))],
    /// The model's node coordinates (m): a universal file starts with dataset 2411 of the
    /// nodes it names.
    pub geometry: &'a [(u64, [f64; 3])],
}

/// The column (and HDF5 dataset) of the amplifier's input voltage of drive `name`:
/// `NAME_voltage_V`; `nlsim harmonics --record voltage` takes it as the drive.
pub fn voltage_column(name: &str) -> String {
    format!("{name}_voltage_V")
}

/// Output formats of the raw records, for the usage error.
pub const HINT: &str = ".csv, .h5 (HDF5) or .uff/.unv (universal file: dataset 58 per signal)";

/// One signal of the records: column name, short name (HDF5, UFF), unit, UFF ordinate type,
/// the response quantity of a sensor, samples.
struct Column<'a> {
    csv: String,
    name: String,
    unit: &'static str,
    uff: i64,
    quantity: Option<Quantity>,
    values: std::borrow::Cow<'a, [f64]>,
}

fn columns<'a>(rec: &'a RawRecord, info: &RawInfo<'_>) -> Vec<Column<'a>> {
    let mut out = Vec::new();
    for (name, q, v) in &rec.responses {
        if !info.channels.is_empty() && !info.channels.contains(name) {
            continue;
        }
        out.push(Column {
            csv: output_column(name, *q),
            name: name.clone(),
            unit: crate::formats::files::unit(*q),
            uff: crate::formats::uff_write::quantity_code(*q),
            quantity: Some(*q),
            values: std::borrow::Cow::Borrowed(v),
        });
    }
    if info.record == Drive::Force {
        out.push(Column {
            csv: force_column(info.drive),
            name: info.drive.to_string(),
            unit: "N",
            uff: 13,
            quantity: None,
            values: std::borrow::Cow::Borrowed(&rec.force),
        });
    }
    out.push(Column {
        csv: voltage_column(info.drive),
        name: voltage_column(info.drive),
        unit: "V",
        uff: 1,
        quantity: None,
        values: std::borrow::Cow::Owned(
            rec.voltage
                .iter()
                .map(|v| v / info.amplifier_gain)
                .collect(),
        ),
    });
    out
}

/// Writes `rec` to `path` (CSV, HDF5 or universal file by extension), atomically.
pub fn write_raw(path: &Path, rec: &RawRecord, info: &RawInfo<'_>) -> Result<()> {
    let cols = columns(rec, info);
    crate::formats::files::write_atomically_uff(path, HINT, |tmp, format| match format {
        Format::Csv => write_csv(tmp, rec, info, &cols),
        Format::Uff => write_uff(tmp, rec, info, &cols),
        #[cfg(feature = "hdf5")]
        Format::Hdf5 => write_hdf5(tmp, rec, info, &cols),
        #[cfg(not(feature = "hdf5"))]
        Format::Hdf5 => Err(crate::formats::files::without_hdf5(path)),
    })
}

fn header(rec: &RawRecord, info: &RawInfo<'_>) -> Vec<String> {
    let mut lines = vec![format!(
        "nlsim {} test raw records: model {}, drive {} through the shaker, {} Hz, {} steps",
        env!("CARGO_PKG_VERSION"),
        info.model_spec,
        info.drive,
        rec.rate_hz,
        rec.steps.len()
    )];
    lines.push(info.noise.clone());
    if info.amplifier_gain != 1.0 {
        lines.push(format!(
            "the voltage is the coil's over the amplifier gain {}",
            info.amplifier_gain
        ));
    }
    if let Some(why) = &rec.stopped {
        lines.push(format!(
            "stopped short ({}): {}",
            rec.status.as_str(),
            crate::formats::files::one_line(why)
        ));
    }
    lines
}

fn write_csv(path: &Path, rec: &RawRecord, info: &RawInfo<'_>, cols: &[Column<'_>]) -> Result<()> {
    let mut s = String::new();
    for l in header(rec, info) {
        let _ = writeln!(s, "# {l}");
    }
    s.push_str("time_s");
    for c in cols {
        let _ = write!(s, ",{}", c.csv);
    }
    s.push('\n');
    for k in 0..rec.voltage.len() {
        let _ = write!(s, "{:.9e}", k as f64 / rec.rate_hz);
        for c in cols {
            let _ = write!(s, ",{:.9e}", c.values[k]);
        }
        s.push('\n');
    }
    std::fs::write(path, s).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn write_uff(path: &Path, rec: &RawRecord, info: &RawInfo<'_>, cols: &[Column<'_>]) -> Result<()> {
    use crate::formats::uff_write::{Abscissa, UffFunction};
    let site = |name: &str| {
        info.sites
            .iter()
            .find(|(n, _)| n == name)
            .map_or((0, 0), |s| s.1)
    };
    let functions: Vec<UffFunction> = cols
        .iter()
        .map(|c| {
            let response = match c.quantity {
                Some(_) => site(&c.name),
                None => site(info.drive),
            };
            UffFunction {
                id: format!("{} {} (virtual test, {})", c.name, c.unit, info.model_spec),
                function_type: 1,
                response,
                reference: (0, 0),
                abscissa_type: 17,
                ordinate_type: c.uff,
                denominator_type: 0,
                abscissa: Abscissa::Even {
                    start: 0.0,
                    step: 1.0 / rec.rate_hz,
                },
                values: c.values.iter().map(|&x| faer::c64::new(x, 0.0)).collect(),
                complex: false,
            }
        })
        .collect();
    let bytes =
        crate::formats::uff_write::encode_functions(path, &functions, false, info.geometry)?;
    std::fs::write(path, bytes).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(feature = "hdf5")]
fn write_hdf5(path: &Path, rec: &RawRecord, info: &RawInfo<'_>, cols: &[Column<'_>]) -> Result<()> {
    use crate::formats::files::str_attr;
    use hdf5_metno as hdf5;
    let err = crate::formats::files::h5err(path);
    let write = || -> hdf5::Result<()> {
        let file = hdf5::File::create(path)?;
        let root = file.as_group()?;
        crate::formats::files::provenance(&root, "test", info.model_spec, info.model_name, None)?;
        str_attr(&root, "description", &header(rec, info).join("; "))?;
        let n = rec.voltage.len();
        let chunk = n.clamp(1, 1 << 14);
        let series = |g: &hdf5::Group, name: &str, data: &[f64], unit: &str| {
            let d = g
                .new_dataset::<f64>()
                .shape(data.len())
                .chunk(chunk)
                .shuffle()
                .deflate(4)
                .create(name)?;
            d.write_raw(data)?;
            str_attr(&d, "unit", unit)
        };
        let t: Vec<f64> = (0..n).map(|k| k as f64 / rec.rate_hz).collect();
        series(&root, "time_s", &t, "s")?;
        let go = root.create_group("outputs")?;
        let gi = root.create_group("inputs")?;
        for c in cols {
            let g = if c.quantity.is_some() { &go } else { &gi };
            series(g, &c.name, &c.values, c.unit)?;
        }
        file.flush()
    };
    write().map_err(&err)
}

/// Writes the step table of `rec` to `path` (CSV): `start_s,end_s,frequency_hz,sweep`, one
/// row per step, the times of the first and last sample of its measured window (the step
/// after its settling).
pub fn write_step_table(path: &Path, rec: &RawRecord) -> Result<()> {
    let mut s = String::from("start_s,end_s,frequency_hz,sweep\n");
    for st in &rec.steps {
        let _ = writeln!(
            s,
            "{:.9e},{:.9e},{:.12e},{}",
            st.measured as f64 / rec.rate_hz,
            (st.end - 1) as f64 / rec.rate_hz,
            st.frequency_hz,
            st.sweep
        );
    }
    crate::formats::files::write_text_atomically(path, &s)
}
