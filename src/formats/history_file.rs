//! Time-history result files of `nlsim simulate` as HDF5 or CSV (time, sensors, element
//! forces, the excitation it ran with). The layouts are documented in `docs/file-formats.md`.
use crate::error::{Error, Result};
use crate::formats::files::Format;
#[cfg(feature = "hdf5")]
use crate::formats::files::f64_attr;
#[cfg(feature = "hdf5")]
use crate::formats::files::str_attr;
use crate::formats::files::unit;
#[cfg(feature = "hdf5")]
use hdf5_metno as hdf5;
use nlsim_kernel::Model;
use nlsim_sim::TimeHistory;
use std::fmt::Write as _;
use std::path::Path;

/// Unit of a quantity.
/// What is stored with the data.
#[derive(Debug, Clone)]
pub struct RunInfo {
    /// Model spec as given on the command line.
    pub model_spec: String,
    /// Method name.
    pub method: String,
    /// Excitation specs, one per input.
    pub excitation: Vec<String>,
    /// Retained modes (0 for the unreduced Newmark).
    pub modes: usize,
    /// Compress the HDF5 series (shuffle, then deflate): about 1.8× smaller and 2.5× slower to
    /// write (a 20 s, 8 kHz bump-stop run: 5.2 MB in 0.22 s against 9.2 MB in 0.09 s, the run
    /// alone 0.08 s). Off, the series are written at disk speed; `nlsim batch merge` compresses
    /// its merged file either way.
    pub compress: bool,
}

/// Writes a time history: HDF5 for `.h5`/`.hdf5`, CSV for `.csv`, atomically (temporary file,
/// then rename).
pub fn write_history(path: &Path, model: &Model, h: &TimeHistory, info: &RunInfo) -> Result<()> {
    crate::formats::files::write_atomically_uff(path, HINT, |tmp, format| match format {
        Format::Csv => write_csv(tmp, h, info),
        Format::Uff => write_uff(tmp, model, h, info),
        #[cfg(feature = "hdf5")]
        Format::Hdf5 => write_hdf5(tmp, model, h, info),
        #[cfg(not(feature = "hdf5"))]
        Format::Hdf5 => {
            let _ = model;
            Err(crate::formats::files::without_hdf5(path))
        }
    })
}

/// What each output format of `nlsim simulate` holds, for the usage error.
pub const HINT: &str =
    ".h5 (HDF5), .csv or .uff/.unv (universal file: dataset 58 per output and input)";

/// The time history as universal file datasets 58 (ASCII): one time response (function type
/// 1, even abscissa from 0 s at the sample interval, real) per sensor output in its quantity
/// and per input force (N), at its DOF.
fn write_uff(path: &Path, model: &Model, h: &TimeHistory, info: &RunInfo) -> Result<()> {
    use crate::formats::uff_write::{Abscissa, UffFunction, node_direction, quantity_code};
    let labels = model.dofs();
    let real =
        |v: &[f64]| -> Vec<faer::c64> { v.iter().map(|&x| faer::c64::new(x, 0.0)).collect() };
    let mut functions = Vec::new();
    for o in &h.outputs {
        let Some(sen) = model.sensors().iter().find(|s| s.name == o.name) else {
            continue;
        };
        functions.push(UffFunction {
            id: format!(
                "{} {} ({}, {})",
                o.name,
                o.quantity.as_str(),
                info.method,
                info.model_spec
            ),
            function_type: 1,
            response: node_direction(sen.at.label(labels)),
            reference: (0, 0),
            abscissa_type: 17,
            ordinate_type: quantity_code(o.quantity),
            denominator_type: 0,
            abscissa: Abscissa::Even {
                start: 0.0,
                step: h.dt,
            },
            values: real(&o.values),
            complex: false,
        });
    }
    for (name, v) in &h.inputs {
        let Some(x) = model.excitation().iter().find(|x| &x.name == name) else {
            continue;
        };
        functions.push(UffFunction {
            id: format!("{name} force ({}, {})", info.method, info.model_spec),
            function_type: 1,
            response: node_direction(x.at.label(labels)),
            reference: (0, 0),
            abscissa_type: 17,
            ordinate_type: 13,
            denominator_type: 0,
            abscissa: Abscissa::Even {
                start: 0.0,
                step: h.dt,
            },
            values: real(v),
            complex: false,
        });
    }
    if functions.is_empty() {
        return Err(Error::Usage(format!(
            "{}: the run has no sensor output or input force to write as a universal file",
            path.display()
        )));
    }
    // `path` is already the temporary file of the atomic write.
    let bytes =
        crate::formats::uff_write::encode_functions(path, &functions, false, model.geometry())?;
    std::fs::write(path, bytes).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The CSV column of sensor output `name` measuring `quantity`:
/// `NAME_QUANTITY_UNIT` (`tip_acceleration_m_per_s2`); `nlsim harmonics` reads it back.
pub fn output_column(name: &str, quantity: nlsim_kernel::Quantity) -> String {
    format!(
        "{name}_{}_{}",
        quantity.as_str(),
        unit(quantity).replace('/', "_per_").replace("^2", "2")
    )
}

/// The CSV column of input force `name`: `NAME_force_N`.
pub fn force_column(name: &str) -> String {
    format!("{name}_force_N")
}

fn write_csv(path: &Path, h: &TimeHistory, info: &RunInfo) -> Result<()> {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# nlsim {} simulate: model {}, method {}, dt {:e} s, excitation {}",
        env!("CARGO_PKG_VERSION"),
        info.model_spec,
        info.method,
        h.dt,
        info.excitation.join("; ")
    );
    if let Some(e) = &h.stopped {
        let _ = writeln!(
            s,
            "# stopped short ({}): {}",
            h.status.as_str(),
            crate::formats::files::one_line(&e.to_string())
        );
    }
    s.push_str("time_s");
    for o in &h.outputs {
        let _ = write!(s, ",{}", output_column(&o.name, o.quantity));
    }
    for (name, _) in &h.inputs {
        let _ = write!(s, ",{}", force_column(name));
    }
    for name in &h.element_names {
        let _ = write!(s, ",{name}_u_m,{name}_force_N");
    }
    s.push('\n');
    for k in 0..h.n_samples() {
        let _ = write!(s, "{:.9e}", k as f64 * h.dt);
        for o in &h.outputs {
            let _ = write!(s, ",{:.9e}", o.values[k]);
        }
        for (_, v) in &h.inputs {
            let _ = write!(s, ",{:.9e}", v[k]);
        }
        for e in 0..h.element_names.len() {
            let _ = write!(
                s,
                ",{:.9e},{:.9e}",
                h.element_displacements[e][k], h.element_forces[e][k]
            );
        }
        s.push('\n');
    }
    std::fs::write(path, s).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(feature = "hdf5")]
fn write_hdf5(path: &Path, model: &Model, h: &TimeHistory, info: &RunInfo) -> Result<()> {
    let err = crate::formats::files::h5err(path);
    let file = hdf5::File::create(path).map_err(&err)?;
    let root = file.as_group().map_err(&err)?;
    crate::formats::files::provenance(&root, "simulate", &info.model_spec, model.name(), None)
        .map_err(&err)?;
    f64_attr(&root, "wall_seconds", h.stats.seconds).map_err(&err)?;
    write_group(&root, h, info).map_err(&err)?;
    file.flush().map_err(&err)?;
    Ok(())
}

#[cfg(feature = "hdf5")]
/// Writes the datasets of a time history into `g` (the layout of `docs/file-formats.md`; used
/// for `nlsim simulate` files and for each job of an `nlsim batch` shard). Series are chunked,
/// and compressed (shuffle, then deflate) when `info.compress`.
pub fn write_group(g: &hdf5::Group, h: &TimeHistory, info: &RunInfo) -> hdf5::Result<()> {
    let n = h.n_samples();
    let chunk = n.clamp(1, 1 << 14);
    let series = |g: &hdf5::Group, name: &str, data: &[f64], unit: &str| -> hdf5::Result<()> {
        let b = g
            .new_dataset::<f64>()
            .shape(data.len())
            .chunk(chunk.min(data.len().max(1)));
        let d = if info.compress {
            b.shuffle().deflate(4).create(name)?
        } else {
            b.create(name)?
        };
        d.write_raw(data)?;
        str_attr(&d, "unit", unit)
    };
    str_attr(g, "method", &info.method)?;
    str_attr(g, "case", &h.case)?;
    f64_attr(g, "dt_s", h.dt)?;
    crate::formats::files::count_attr(g, "modes", info.modes)?;
    // A run that stopped short keeps the samples it computed, and says so.
    str_attr(g, "status", h.status.as_str())?;
    if let Some(e) = &h.stopped {
        str_attr(g, "detail", &e.to_string())?;
    }
    let times: Vec<f64> = h.times();
    series(g, "time", &times, "s")?;
    let go = g.create_group("outputs")?;
    for o in &h.outputs {
        series(&go, &o.name, &o.values, unit(o.quantity))?;
        str_attr(&*go.dataset(&o.name)?, "quantity", o.quantity.as_str())?;
    }
    let gi = g.create_group("inputs")?;
    for ((name, v), spec) in h.inputs.iter().zip(&info.excitation) {
        series(&gi, name, v, "N")?;
        str_attr(&*gi.dataset(name)?, "excitation", spec)?;
    }
    let gel = g.create_group("elements")?;
    for (e, name) in h.element_names.iter().enumerate() {
        let ge = gel.create_group(name)?;
        series(&ge, "displacement", &h.element_displacements[e], "m")?;
        series(&ge, "velocity", &h.element_velocities[e], "m/s")?;
        series(&ge, "force", &h.element_forces[e], "N")?;
    }
    let gev = g.create_group("events")?;
    let t: Vec<f64> = h.stats.events.iter().map(|e| e.time).collect();
    let el: Vec<u32> = h.stats.events.iter().map(|e| e.element as u32).collect();
    let cl: Vec<u8> = h.stats.events.iter().map(|e| u8::from(e.closing)).collect();
    let d = gev.new_dataset_builder().with_data(&t).create("time")?;
    str_attr(&d, "unit", "s")?;
    gev.new_dataset_builder().with_data(&el).create("element")?;
    gev.new_dataset_builder().with_data(&cl).create("closing")?;
    Ok(())
}
