//! Mode result files: the mode table ([`ModeReport`]: frequencies, damping, effective masses,
//! residuals) written as HDF5 (shapes included) or CSV (the table).
//!
//! HDF5 layout (`docs/file-formats.md`): group `/modes` with attributes `model`, `method`,
//! `shift_rad2_s2`, `tolerance`, `sturm_count`; datasets `frequency_hz`, `eigenvalue_rad2_s2`,
//! `damping_ratio`, `residual`, `effective_mass_<dir>_kg` (attribute `total_kg`), and `shapes`
//! (modes × DOFs, mass-normalised, m/√kg); dataset `/dofs/labels` (strings such as `12:uz`).
use crate::error::{Error, Result};
use crate::formats::files::Format;
#[cfg(feature = "hdf5")]
use hdf5_metno as hdf5;
use nlsim_kernel::Model;
#[cfg(feature = "hdf5")]
use nlsim_reduction::EigenMethod;
use nlsim_reduction::{EffectiveMass, EigenConfig, Modes};
use std::fmt::Write as _;
use std::path::Path;

/// Modes with what the table shows about them.
#[derive(Debug, Clone)]
pub struct ModeReport {
    /// The modes.
    pub modes: Modes,
    /// Damping ratio per mode ([`nlsim_reduction::damping_ratios`]).
    pub damping: Vec<f64>,
    /// Effective masses per translational direction.
    pub effective: Vec<EffectiveMass>,
    /// The solver settings used.
    pub config: EigenConfig,
}

impl ModeReport {
    /// Collects damping ratios and effective masses for `modes` of `model`.
    pub fn new(model: &Model, modes: Modes, config: EigenConfig) -> Self {
        let damping = nlsim_reduction::damping_ratios(&modes, model.damping());
        let effective = nlsim_reduction::effective_masses(model, &modes);
        ModeReport {
            modes,
            damping,
            effective,
            config,
        }
    }
}

/// Writes the modes to `path`: HDF5 for `.h5`/`.hdf5`, CSV (the table) for `.csv`, universal
/// datasets 55 (shapes with frequency and damping, [`crate::formats::uff55`]; after dataset
/// 2411 of the model's nodes when it has coordinates) for `.uff`/`.unv`. The file is written
/// next to its destination and renamed into place, so a failed run leaves no partial file
/// and an existing one untouched.
/// `model_spec` is the model argument as given (stored with the data).
pub fn write_modes(path: &Path, model_spec: &str, model: &Model, r: &ModeReport) -> Result<()> {
    crate::formats::files::write_atomically_uff(path, HINT, |tmp, format| match format {
        Format::Csv => write_csv(tmp, r),
        #[cfg(feature = "hdf5")]
        Format::Hdf5 => write_hdf5(tmp, model_spec, model, r),
        #[cfg(not(feature = "hdf5"))]
        Format::Hdf5 => {
            let _ = (model_spec, model);
            Err(crate::formats::files::without_hdf5(path))
        }
        Format::Uff => {
            // A modal model's coordinates are modes, not nodes: no geometry for them.
            let nodes = if model.is_modal() {
                String::new()
            } else {
                crate::formats::uff_write::nodes_text(
                    model.geometry(),
                    model.dofs().labels().iter().map(|l| l.node),
                )
            };
            let text =
                nodes + &crate::formats::uff55::modes_text(path, model, &r.modes, &r.damping)?;
            std::fs::write(tmp, text).map_err(|source| Error::Io {
                path: tmp.to_path_buf(),
                source,
            })
        }
    })
}

/// What each output format of `nlsim modes` holds, for the usage error.
pub const HINT: &str =
    ".h5 (HDF5, with mode shapes), .csv (the table) or .uff/.unv (universal dataset 55 per mode)";

fn write_csv(path: &Path, r: &ModeReport) -> Result<()> {
    let mut s = String::from("mode,frequency_hz,eigenvalue_rad2_s2,damping_ratio");
    for e in &r.effective {
        let _ = write!(s, ",effective_mass_{}_kg", e.component);
    }
    s.push_str(",residual\n");
    let f = r.modes.frequencies_hz();
    for i in 0..r.modes.len() {
        let _ = write!(
            s,
            "{},{:.12e},{:.12e},{:.6e}",
            i + 1,
            f[i],
            r.modes.eigenvalues[i],
            r.damping[i]
        );
        for e in &r.effective {
            let _ = write!(s, ",{:.9e}", e.per_mode[i]);
        }
        let _ = writeln!(s, ",{:.3e}", r.modes.residuals[i]);
    }
    std::fs::write(path, s).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(feature = "hdf5")]
fn write_hdf5(path: &Path, model_spec: &str, model: &Model, r: &ModeReport) -> Result<()> {
    let err = crate::formats::files::h5err(path);
    let file = hdf5::File::create(path).map_err(&err)?;
    let root = file.as_group().map_err(&err)?;
    crate::formats::files::provenance(&root, "modes", model_spec, model.name(), None)
        .map_err(&err)?;
    write_group(&root, model, r).map_err(&err)?;
    file.flush().map_err(&err)?;
    Ok(())
}

#[cfg(feature = "hdf5")]
/// Writes group `modes` and dataset `dofs/labels` into `root` (the layout of `nlsim modes`
/// files, also used by reports).
pub fn write_group(root: &hdf5::Group, model: &Model, r: &ModeReport) -> hdf5::Result<()> {
    use crate::formats::files::f64_attr;
    use crate::formats::files::str_attr;
    let g = root.create_group("modes")?;
    let put = |name: &str, data: &[f64], unit: &str| -> hdf5::Result<hdf5::Dataset> {
        let d = g.new_dataset_builder().with_data(data).create(name)?;
        str_attr(&d, "unit", unit)?;
        Ok(d)
    };
    put("frequency_hz", &r.modes.frequencies_hz(), "Hz")?;
    put("eigenvalue_rad2_s2", &r.modes.eigenvalues, "rad^2/s^2")?;
    put("damping_ratio", &r.damping, "1")?;
    put("residual", &r.modes.residuals, "1")?;
    for e in &r.effective {
        let d = put(
            &format!("effective_mass_{}_kg", e.component),
            &e.per_mode,
            "kg",
        )?;
        d.new_attr::<f64>()
            .create("total_kg")?
            .write_scalar(&e.total)?;
    }
    let (n, m) = (r.modes.vectors.nrows(), r.modes.vectors.ncols());
    // Row-major modes × DOFs: mode r is the contiguous column r of the column-major matrix.
    let mut raw = Vec::with_capacity(n * m);
    for c in 0..m {
        raw.extend((0..n).map(|i| r.modes.vectors[(i, c)]));
    }
    let shapes = g
        .new_dataset::<f64>()
        .shape((m, n))
        .chunk((1, n.clamp(1, 1 << 16)))
        .shuffle()
        .deflate(4)
        .create("shapes")?;
    shapes.write_raw(&raw)?;
    str_attr(&shapes, "unit", "1/sqrt(kg) (mass-normalised)")?;
    let st = &r.modes.stats;
    str_attr(&g, "model", model.name())?;
    str_attr(
        &g,
        "method",
        match st.method {
            EigenMethod::Dense => "dense",
            EigenMethod::Lanczos => "shift-invert block Lanczos",
        },
    )?;
    f64_attr(&g, "shift_rad2_s2", st.shift)?;
    f64_attr(&g, "tolerance", r.config.tol)?;
    f64_attr(&g, "max_residual", st.max_residual)?;
    if let Some((count, _)) = st.sturm {
        g.new_attr::<u64>()
            .create("sturm_count")?
            .write_scalar(&(count as u64))?;
    }
    let labels: Vec<hdf5::types::VarLenUnicode> = (0..model.n_dofs())
        .map(|i| {
            model
                .dofs()
                .describe(i)
                .parse()
                .expect("DOF labels are plain ASCII")
        })
        .collect();
    root.create_group("dofs")?
        .new_dataset_builder()
        .with_data(&labels)
        .create("labels")?;
    Ok(())
}
