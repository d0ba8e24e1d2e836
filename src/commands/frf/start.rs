//! A continuation start read from an earlier FRF file (`nlsim frf --start-file`): the point
//! nearest a requested frequency, its harmonics padded or cut to the request's, with sizes
//! checked before anything is read.
use crate::commands::frf::request::MAX_FRF_HARMONICS;
use crate::commands::frf::request::MAX_FRF_POINTS;
use crate::commands::frf::request::StartFile;
use crate::error::{Error, Result};
use nlsim_hb::HbSystem;

/// The point [`read_start`] took: its index in the file, fundamental (Hz) and the unknowns
/// on this run's harmonics.
pub struct StartPoint {
    /// The point's index in the file.
    pub index: usize,
    /// Its fundamental frequency (Hz).
    pub hz: f64,
    /// Its unknowns in the request's harmonics (padded or cut).
    pub x: Vec<f64>,
    /// Harmonics of the file.
    pub h_file: usize,
}

/// Most values a start file may make nlsim read (2²⁶, 512 MiB).
const START_FILE_BUDGET: usize = 1 << 26;

/// Reads the start point of `sf` for `sys` over `from_hz..to_hz`. The file must hold the
/// same sub-harmonic order and an `/elements/<name>` dataset for every element of `sys`;
/// its harmonics may differ (the coefficients are cut or padded with zeros). Sizes are checked
/// against the datasets' shapes and a budget before anything is read; errors name the file
/// and the object.
pub fn read_start(sf: &StartFile, sys: &HbSystem, from_hz: f64, to_hz: f64) -> Result<StartPoint> {
    use hdf5_metno as hdf5;
    let path = &sf.path;
    let err = |object: &str, message: String| Error::Hdf5 {
        path: path.to_path_buf(),
        message: format!("start file, {object}: {message}"),
    };
    crate::formats::files::input_file(path)?;
    let f = hdf5::File::open(path).map_err(|e| err("file", e.to_string()))?;
    let attr = |name: &str| -> Result<f64> {
        crate::formats::files::number_attr(&f, name).map_err(|e| {
            err(
                "/",
                format!("attribute '{name}': {e} (is it an `nlsim frf` output?)"),
            )
        })
    };
    let (h_attr, nu_attr) = (attr("harmonics")?, attr("subharmonic_order")?);
    let set = sys.harmonics();
    let whole = |v: f64| v >= 1.0 && v <= MAX_FRF_HARMONICS as f64 && v.fract() == 0.0;
    if !whole(h_attr) || !whole(nu_attr) {
        return Err(err(
            "/",
            format!("harmonics {h_attr} and subharmonic_order {nu_attr} are not valid orders"),
        ));
    }
    let (h_file, nu_file) = (h_attr as usize, nu_attr as usize);
    if nu_file != set.nu {
        return Err(err(
            "/",
            format!(
                "its branch has harmonics of Ω/{nu_file}, this run of Ω/{} (use \
                 --subharmonic {nu_file})",
                set.nu
            ),
        ));
    }
    let ds = |name: &str| f.dataset(name).map_err(|e| err(name, e.to_string()));
    let freq = ds("frequency")?;
    let shape = freq.shape();
    if shape.len() != 1 || shape[0] == 0 || shape[0] > MAX_FRF_POINTS {
        return Err(err(
            "frequency",
            format!("shape {shape:?}: expected 1 to {MAX_FRF_POINTS} points"),
        ));
    }
    let n = shape[0];
    let hz: Vec<f64> = freq
        .read_raw()
        .map_err(|e| err("frequency", e.to_string()))?;
    let nh_file = 2 * h_file + 1;
    let nh = set.len();
    let mut x_file = Vec::new();
    for (e, el) in sys.elements().iter().enumerate() {
        let name = format!("elements/{}", el.name());
        let d = f.dataset(&name).map_err(|_| {
            let there = f
                .group("elements")
                .and_then(|g| g.member_names())
                .map_or("none".into(), |v| v.join(", "));
            err(
                &name,
                format!(
                    "no such dataset: the file holds another model's elements ({there}), not \
                     this model's '{}'",
                    el.name()
                ),
            )
        })?;
        let m = sys.coordinates(e).len();
        let want = [n, m * nh_file];
        if d.shape() != want {
            return Err(err(
                &name,
                format!(
                    "shape {:?}, expected {want:?} ({n} points, {m} coordinate(s) of 2·{h_file} + 1 \
                     coefficients)",
                    d.shape()
                ),
            ));
        }
        if (x_file.len() + n * m * nh_file) > START_FILE_BUDGET {
            return Err(err(&name, format!("more than {START_FILE_BUDGET} values")));
        }
        let v: Vec<f64> = d.read_raw().map_err(|e| err(&name, e.to_string()))?;
        x_file.push((v, m));
    }
    let (lo, hi) = (from_hz.min(to_hz), from_hz.max(to_hz));
    let inside: Vec<usize> = (0..n)
        .filter(|&i| hz[i].is_finite() && hz[i] >= lo && hz[i] <= hi)
        .collect();
    if inside.is_empty() {
        return Err(err(
            "frequency",
            format!("none of its {n} points lies within {lo} to {hi} Hz"),
        ));
    }
    // The unknowns of point i on this run's harmonics.
    let point = |i: usize| -> Vec<f64> {
        let mut x = Vec::with_capacity(sys.n_unknowns());
        for (v, m) in &x_file {
            let row = &v[i * m * nh_file..(i + 1) * m * nh_file];
            for c in 0..*m {
                let block = &row[c * nh_file..(c + 1) * nh_file];
                x.extend((0..nh).map(|j| block.get(j).copied().unwrap_or(0.0)));
            }
        }
        x
    };
    let measure = |i: usize| -> f64 {
        let x = point(i);
        if set.nu >= 2 {
            // Harmonics k of Ω/ν with ν ∤ k.
            x.chunks(nh)
                .flat_map(|b| {
                    (1..=set.h)
                        .filter(|k| k % set.nu != 0)
                        .map(move |k| b[2 * k - 1].hypot(b[2 * k]))
                })
                .fold(0.0f64, f64::max)
        } else {
            x.iter().fold(0.0f64, |a, v| a.max(v.abs()))
        }
    };
    let index = match sf.at_hz {
        Some(at) => inside
            .iter()
            .copied()
            .min_by(|&a, &b| (hz[a] - at).abs().total_cmp(&(hz[b] - at).abs())),
        None => inside
            .iter()
            .map(|&i| (i, measure(i)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i),
    }
    .unwrap_or(inside[0]);
    let x = point(index);
    if let Some(j) = x.iter().position(|v| !v.is_finite()) {
        return Err(err(
            "elements",
            format!("point {index} has a non-finite coefficient (unknown {j})"),
        ));
    }
    Ok(StartPoint {
        index,
        hz: hz[index],
        x,
        h_file,
    })
}
