//! FRF result files: the solution points of `nlsim frf` as HDF5 (complex harmonics per sensor,
//! point kinds, stability, located peaks) or CSV (one row per point). The layouts are
//! documented in `docs/file-formats.md`; batches write the same groups into their shards.
use crate::error::{Error, Result};
use crate::formats::files::Format;
#[cfg(feature = "hdf5")]
use crate::formats::files::f64_attr;
#[cfg(feature = "hdf5")]
use crate::formats::files::str_attr;
use crate::formats::files::unit;
use faer::{Mat, c64};
#[cfg(feature = "hdf5")]
use hdf5_metno as hdf5;
use nlsim_hb::{Branch, HbSystem, PointKind};
use std::f64::consts::PI;
use std::fmt::Write as _;
use std::path::Path;

/// What each output format of `nlsim frf` holds, for the usage error.
pub const HINT: &str = ".h5 (HDF5, complex harmonics), .csv (one row per solution point) or \
                        .uff/.unv (universal file: dataset 58 per sensor and harmonic)";

/// What is stored with the data.
#[derive(Debug, Clone)]
pub struct FrfInfo {
    /// The model spec as given on the command line.
    pub model_spec: String,
    /// The model's own name.
    pub model_name: String,
    /// `continuation`, `step-up` or `step-down`.
    pub mode: String,
    /// Retained modes.
    pub modes: usize,
    /// Whether residual flexibility was included.
    pub residual: bool,
    /// Wall time of the solve (s).
    pub seconds: f64,
    /// Located response maxima ([`crate::commands::frf::run::FrfRun::peaks`]).
    pub peaks: Vec<nlsim_hb::Peak>,
    /// The run's notes ([`crate::commands::frf::run::FrfRun::notes`]).
    pub notes: Vec<String>,
    /// The DOF of each sensor of the system, in its order (universal files name them).
    pub sensor_dofs: Vec<nlsim_kernel::DofLabel>,
    /// The DOF of each input of the system, in its order.
    pub input_dofs: Vec<nlsim_kernel::DofLabel>,
    /// The model's node coordinates ([`nlsim_kernel::Model::geometry`]; m): a universal file
    /// starts with dataset 2411 of the nodes it names.
    pub geometry: Vec<(u64, [f64; 3])>,
}

#[cfg(feature = "hdf5")]
/// Writes the located maxima `peaks` as the group `peaks` of `g`: per maximum its sensor
/// (index into the `sensors` attribute), harmonic index `k` and ratio `k/ν`, frequency (Hz),
/// level, `|Y_k|` in the sensor's unit and whether it was located between points.
pub fn write_peaks(g: &hdf5::Group, sys: &HbSystem, peaks: &[nlsim_hb::Peak]) -> hdf5::Result<()> {
    if peaks.is_empty() {
        return Ok(());
    }
    let gp = g.create_group("peaks")?;
    let names: Vec<&str> = sys.sensors().iter().map(|s| s.name.as_str()).collect();
    str_attr(&gp, "sensors", &names.join(","))?;
    str_attr(
        &gp,
        "note",
        "the largest |Y_k| of each sensor and harmonic along the branch; located = 1 when found \
         between computed points by maximising along the branch, 0 when it is an end point",
    )?;
    let sensor: Vec<u32> = peaks.iter().map(|p| p.sensor as u32).collect();
    gp.new_dataset_builder()
        .with_data(&sensor)
        .create("sensor")?;
    let k: Vec<u32> = peaks.iter().map(|p| p.harmonic as u32).collect();
    gp.new_dataset_builder().with_data(&k).create("harmonic")?;
    let nu = sys.harmonics().nu as f64;
    let ratio: Vec<f64> = peaks.iter().map(|p| p.harmonic as f64 / nu).collect();
    let d = gp
        .new_dataset_builder()
        .with_data(&ratio)
        .create("harmonic_ratio")?;
    str_attr(&d, "unit", "1")?;
    let hz: Vec<f64> = peaks
        .iter()
        .map(|p| p.omega / (2.0 * std::f64::consts::PI))
        .collect();
    let d = gp
        .new_dataset_builder()
        .with_data(&hz)
        .create("frequency")?;
    str_attr(&d, "unit", "Hz")?;
    let level: Vec<f64> = peaks.iter().map(|p| p.scale).collect();
    let d = gp.new_dataset_builder().with_data(&level).create("level")?;
    str_attr(&d, "unit", "1")?;
    let v: Vec<f64> = peaks.iter().map(|p| p.value).collect();
    let d = gp.new_dataset_builder().with_data(&v).create("magnitude")?;
    str_attr(&d, "unit", "the sensor's (m, m/s or m/s^2)")?;
    let located: Vec<u8> = peaks.iter().map(|p| u8::from(p.located)).collect();
    gp.new_dataset_builder()
        .with_data(&located)
        .create("located")?;
    Ok(())
}

fn kind_code(k: PointKind) -> u8 {
    match k {
        PointKind::Regular => 0,
        PointKind::Fold => 1,
        PointKind::End => 2,
        PointKind::Jump => 3,
    }
}

fn stable_code(p: &nlsim_hb::SolutionPoint) -> i8 {
    match p.stable() {
        Some(true) => 1,
        Some(false) => 0,
        None => -1,
    }
}

/// Label of harmonic `k` of `Ω/ν` as a multiple of the fundamental: `1`, `2`, `1/3`, `2/3`.
pub fn harmonic_label(k: usize, nu: usize) -> String {
    if k.is_multiple_of(nu) {
        format!("{}", k / nu)
    } else {
        format!("{k}/{nu}")
    }
}

/// Writes the FRF of `branch` with its sensor responses `y` (from `commands::frf::responses`): HDF5 for
/// `.h5`/`.hdf5`, CSV for `.csv`, atomically.
pub fn write_frf(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    info: &FrfInfo,
) -> Result<()> {
    crate::formats::files::write_atomically_uff(path, HINT, |tmp, format| match format {
        Format::Csv => write_csv(tmp, sys, branch, y, info),
        Format::Uff => write_uff(tmp, sys, branch, y, info),
        #[cfg(feature = "hdf5")]
        Format::Hdf5 => write_hdf5(tmp, sys, branch, y, info),
        #[cfg(not(feature = "hdf5"))]
        Format::Hdf5 => Err(crate::formats::files::without_hdf5(path)),
    })
}

/// The FRF as universal file datasets 58 (ASCII for `.unv`/`.uff`; [`crate::formats::uff`]):
/// per sensor and harmonic `k` carrying response, the complex `Y_k / F_1` (the harmonic's
/// response over the fundamental force of the first input, thesis eq. 14 for `k = 1`) against
/// the fundamental frequency (Hz, uneven: the branch's points in order), function type 4,
/// the reference the first input's DOF. A branch through folds goes back and forth in
/// frequency as it does here.
fn write_uff(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    info: &FrfInfo,
) -> Result<()> {
    use crate::formats::uff_write::{Abscissa, UffFunction, node_direction, quantity_code};
    let set = *sys.harmonics();
    let (Some(input), Some(&input_dof)) = (sys.inputs().first(), info.input_dofs.first()) else {
        return Err(Error::Usage(format!(
            "{}: a universal file of FRFs needs an input (the model's excitation)",
            path.display()
        )));
    };
    let hz: Vec<f64> = branch.points.iter().map(|p| p.omega / (2.0 * PI)).collect();
    // The fundamental force of the first input at each point.
    let f1: Vec<c64> = branch
        .points
        .iter()
        .map(|p| sys.forcing().amplitude(0, set.nu) * p.scale)
        .collect();
    if f1.iter().any(|f| f.norm() == 0.0) {
        return Err(Error::Usage(format!(
            "{}: input '{}' carries no force at the fundamental: no FRF to write",
            path.display(),
            input.0
        )));
    }
    let mut functions = Vec::new();
    for (s, sen) in sys.sensors().iter().enumerate() {
        let dof = info.sensor_dofs.get(s).copied().ok_or_else(|| {
            Error::Usage(format!(
                "{}: no DOF for sensor '{}'",
                path.display(),
                sen.name
            ))
        })?;
        // Harmonics that carry no response (below 1e-12 of the sensor's largest, round-off
        // of a symmetric element's even harmonics) are left out.
        let top = (0..branch.points.len())
            .flat_map(|i| (1..=set.h).map(move |k| (i, k)))
            .map(|(i, k)| (y[i][(s, k)] / f1[i]).norm())
            .fold(0.0f64, f64::max);
        for k in 1..=set.h {
            let values: Vec<c64> = (0..branch.points.len())
                .map(|i| y[i][(s, k)] / f1[i])
                .collect();
            if values.iter().all(|v| v.norm() <= 1e-12 * top) {
                continue;
            }
            let which = if k == set.nu {
                "fundamental".to_string()
            } else {
                format!("harmonic {k}/{}", set.nu)
            };
            functions.push(UffFunction {
                id: format!("{} {which} / {} F1 ({})", sen.name, input.0, info.mode),
                function_type: 4,
                response: node_direction(dof),
                reference: node_direction(input_dof),
                abscissa_type: 18,
                ordinate_type: quantity_code(sen.quantity),
                denominator_type: 13,
                abscissa: Abscissa::Uneven(hz.clone()),
                values,
                complex: true,
            });
        }
    }
    // `path` is already the temporary file of the atomic write.
    let bytes =
        crate::formats::uff_write::encode_functions(path, &functions, false, &info.geometry)?;
    std::fs::write(path, bytes).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn write_csv(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    info: &FrfInfo,
) -> Result<()> {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# nlsim {} frf: model {}, mode {}, H = {} harmonics of Omega/{}, {} modes{}",
        env!("CARGO_PKG_VERSION"),
        info.model_spec,
        info.mode,
        sys.harmonics().h,
        sys.harmonics().nu,
        info.modes,
        if info.residual {
            " + residual flexibility"
        } else {
            ""
        }
    );
    let _ = writeln!(
        s,
        "# stable: 1 stable, 0 unstable, -1 not computed; kind: 0 regular, 1 fold, 2 end, 3 jump; \
         <sensor>_h<r>_re/_im: complex amplitude of harmonic r x Omega (q = Re(Q e^(i r Omega t)))"
    );
    let nu = sys.harmonics().nu;
    for p in &info.peaks {
        let _ = writeln!(
            s,
            "# peak {} harmonic {}: |Y| = {:.10e} at {:.10e} Hz ({})",
            sys.sensors()[p.sensor].name,
            harmonic_label(p.harmonic, nu),
            p.value,
            p.omega / (2.0 * std::f64::consts::PI),
            if p.located { "located" } else { "end point" }
        );
    }
    for b in &branch.bifurcations {
        let _ = writeln!(
            s,
            "# bifurcation {} at {:.10e} Hz ({})",
            b.kind.as_str(),
            b.omega / (2.0 * std::f64::consts::PI),
            if b.located { "located" } else { "interpolated" }
        );
    }
    for note in &info.notes {
        let _ = writeln!(s, "# note: {note}");
    }
    s.push_str("frequency_hz,level,stable,kind,max_floquet_real_per_s");
    for sen in sys.sensors() {
        for k in 0..=sys.harmonics().h {
            let l = harmonic_label(k, sys.harmonics().nu).replace('/', "_");
            let u = unit(sen.quantity).replace('/', "_per_").replace("^2", "2");
            let _ = write!(s, ",{0}_h{l}_re_{u},{0}_h{l}_im_{u}", sen.name);
        }
    }
    s.push('\n');
    for (p, yp) in branch.points.iter().zip(y) {
        let _ = write!(
            s,
            "{:.10e},{:.6e},{},{},{:.6e}",
            p.omega / (2.0 * std::f64::consts::PI),
            p.scale,
            stable_code(p),
            kind_code(p.kind),
            p.stability.as_ref().map_or(f64::NAN, |s| s.max_real)
        );
        for r in 0..yp.nrows() {
            for k in 0..yp.ncols() {
                let _ = write!(s, ",{:.9e},{:.9e}", yp[(r, k)].re, yp[(r, k)].im);
            }
        }
        s.push('\n');
    }
    std::fs::write(path, s).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

#[cfg(feature = "hdf5")]
fn write_hdf5(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    info: &FrfInfo,
) -> Result<()> {
    let err = crate::formats::files::h5err(path);
    let file = hdf5::File::create(path).map_err(&err)?;
    let root = file.as_group().map_err(&err)?;
    crate::formats::files::provenance(
        &root,
        "frf",
        &info.model_spec,
        info.model_name.as_str(),
        None,
    )
    .map_err(&err)?;
    str_attr(&root, "mode", &info.mode).map_err(&err)?;
    crate::formats::files::count_attr(&root, "modes", info.modes).map_err(&err)?;
    f64_attr(
        &root,
        "residual_flexibility",
        f64::from(u8::from(info.residual)),
    )
    .map_err(&err)?;
    f64_attr(&root, "wall_seconds", info.seconds).map_err(&err)?;
    if !info.notes.is_empty() {
        str_attr(&root, "notes", &info.notes.join("\n")).map_err(&err)?;
    }
    write_group(&root, sys, branch, y).map_err(&err)?;
    write_peaks(&root, sys, &info.peaks).map_err(&err)?;
    file.flush().map_err(&err)?;
    Ok(())
}

#[cfg(feature = "hdf5")]
/// Writes the FRF datasets of `branch` into `g` (the layout of `docs/file-formats.md`; used
/// for `nlsim frf` files and for each job of an `nlsim batch` shard).
pub fn write_group(
    g: &hdf5::Group,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
) -> hdf5::Result<()> {
    str_attr(
        g,
        "convention",
        "q(t) = Re(sum_k Q_k exp(i k Omega t / nu)); harmonic k is at k/nu times the fundamental",
    )?;
    crate::formats::files::count_attr(g, "harmonics", sys.harmonics().h)?;
    crate::formats::files::count_attr(g, "subharmonic_order", sys.harmonics().nu)?;
    let n = branch.points.len();
    let real = |g: &hdf5::Group, name: &str, data: &[f64], u: &str| -> hdf5::Result<()> {
        let d = g.new_dataset_builder().with_data(data).create(name)?;
        str_attr(&d, "unit", u)
    };
    let hz: Vec<f64> = branch
        .points
        .iter()
        .map(|p| p.omega / (2.0 * std::f64::consts::PI))
        .collect();
    real(g, "frequency", &hz, "Hz")?;
    let level: Vec<f64> = branch.points.iter().map(|p| p.scale).collect();
    real(g, "level", &level, "1")?;
    let fl: Vec<f64> = branch
        .points
        .iter()
        .map(|p| p.stability.as_ref().map_or(f64::NAN, |s| s.max_real))
        .collect();
    real(g, "max_floquet_real", &fl, "1/s")?;
    let st: Vec<i8> = branch.points.iter().map(stable_code).collect();
    let d = g.new_dataset_builder().with_data(&st).create("stable")?;
    str_attr(&d, "legend", "1 stable, 0 unstable, -1 not computed")?;
    let kd: Vec<u8> = branch.points.iter().map(|p| kind_code(p.kind)).collect();
    let d = g.new_dataset_builder().with_data(&kd).create("kind")?;
    str_attr(&d, "legend", "0 regular, 1 fold, 2 end, 3 jump")?;
    let ratio: Vec<f64> = (0..=sys.harmonics().h)
        .map(|k| k as f64 / sys.harmonics().nu as f64)
        .collect();
    real(g, "harmonic_ratio", &ratio, "1")?;
    let gsen = g.create_group("sensors")?;
    let nk = sys.harmonics().h + 1;
    for (s, sen) in sys.sensors().iter().enumerate() {
        let gs = gsen.create_group(&sen.name)?;
        str_attr(&gs, "quantity", sen.quantity.as_str())?;
        let data: Vec<c64> = (0..n)
            .flat_map(|i| (0..nk).map(move |k| (i, k)))
            .map(|(i, k)| y[i][(s, k)])
            .collect();
        let d = gs.new_dataset::<c64>().shape((n, nk)).create("response")?;
        d.write_raw(&data)?;
        str_attr(&d, "unit", unit(sen.quantity))?;
        str_attr(&d, "dims", "point x harmonic")?;
        // FRFs per input: Y_k / F_k where harmonic k is forced.
        for (i, (name, _)) in sys.inputs().iter().enumerate() {
            let frf: Vec<c64> = (0..n)
                .flat_map(|p| (0..nk).map(move |k| (p, k)))
                .map(|(p, k)| {
                    let f = sys.forcing().amplitude(i, k) * branch.points[p].scale;
                    if f == c64::new(0.0, 0.0) {
                        c64::new(f64::NAN, f64::NAN)
                    } else {
                        y[p][(s, k)] / f
                    }
                })
                .collect();
            let d = gs
                .new_dataset::<c64>()
                .shape((n, nk))
                .create(format!("frf_{name}").as_str())?;
            d.write_raw(&frf)?;
            str_attr(&d, "unit", &format!("{}/N", unit(sen.quantity)))?;
            str_attr(&d, "note", "NaN where the harmonic carries no force")?;
        }
    }
    if !branch.bifurcations.is_empty() {
        let gb = g.create_group("bifurcations")?;
        let kind: Vec<u8> = branch
            .bifurcations
            .iter()
            .map(|b| match b.kind {
                nlsim_hb::BifurcationKind::Fold => 0,
                nlsim_hb::BifurcationKind::BranchPoint => 1,
                nlsim_hb::BifurcationKind::PeriodDoubling => 2,
                nlsim_hb::BifurcationKind::NeimarkSacker => 3,
            })
            .collect();
        let d = gb.new_dataset_builder().with_data(&kind).create("kind")?;
        str_attr(
            &d,
            "legend",
            "0 fold, 1 branch point, 2 period doubling, 3 Neimark-Sacker",
        )?;
        let hz: Vec<f64> = branch
            .bifurcations
            .iter()
            .map(|b| b.omega / (2.0 * std::f64::consts::PI))
            .collect();
        real(&gb, "frequency", &hz, "Hz")?;
        let level: Vec<f64> = branch.bifurcations.iter().map(|b| b.scale).collect();
        real(&gb, "level", &level, "1")?;
        let located: Vec<u8> = branch
            .bifurcations
            .iter()
            .map(|b| u8::from(b.located))
            .collect();
        gb.new_dataset_builder()
            .with_data(&located)
            .create("located")?;
    }
    let gel = g.create_group("elements")?;
    let nh = sys.harmonics().len();
    for (e, el) in sys.elements().iter().enumerate() {
        let c = sys.coordinates(e);
        let data: Vec<f64> = branch
            .points
            .iter()
            .flat_map(|p| p.x[c.start * nh..c.end * nh].iter().copied())
            .collect();
        // A coupled law's coordinates side by side: (points, coordinates · (2H+1)).
        let d = gel
            .new_dataset::<f64>()
            .shape((n, c.len() * nh))
            .create(el.name())?;
        d.write_raw(&data)?;
        str_attr(&d, "unit", "m")?;
        str_attr(
            &d,
            "layout",
            "per point: c0, c1, s1, ..., cH, sH with u(t) = c0 + sum c_k cos(k w0 t) + s_k sin(k w0 t); one such block per coordinate of a coupled law",
        )?;
    }
    Ok(())
}
