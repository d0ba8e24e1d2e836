//! Stepped-sine test data as HDF5 (documented in docs/file-formats.md).

use super::*;

/// Most complex values a test-data HDF5 file may declare (16 bytes each: 1 GiB).
const H5_MAX_VALUES: usize = 1 << 26;

/// The `unit` attribute of per-channel data in test-data HDF5: each channel's SI unit.
const CHANNEL_UNIT: &str = "the channel's SI unit: m, m/s or m/s^2 by /channels/quantity";

/// Writes `data` as HDF5 (documented in docs/file-formats.md; `h5py` reads it directly):
/// root attributes `format = "nlsim test data"`, `input`, `harmonics`; datasets
/// `channels/name`, `channels/quantity`, `channels/noise_relative`, `channels/noise_absolute`;
/// one group `sweeps/sweepN` (N from 0, measured order) per sweep with attributes `label`,
/// `direction` and datasets `frequency_hz` (steps), `force` (steps × H, complex) and
/// `response` (steps × channels × H, complex; NaN = not measured), and when any step has
/// them `sigma` (the same shape: the standard deviations of the real and imaginary parts as
/// the real and imaginary parts; NaN = the channel's noise model). Written atomically.
pub fn write_h5(path: &Path, data: &TestData) -> Result<()> {
    // What the readers would refuse is not written.
    data.validate_measured()
        .map_err(|e| Error::Usage(format!("{}: test data not written: {e}", path.display())))?;
    use crate::formats::files::h5err;
    use crate::formats::files::str_attr;
    use hdf5::types::VarLenUnicode;
    use hdf5_metno as hdf5;
    let tmp = crate::formats::files::temp_path(path);
    let _registered = crate::formats::interrupt::Temporary::new(&tmp);
    let stds = data
        .sweeps
        .iter()
        .any(|sw| sw.steps.iter().any(|st| st.sigma.nrows() > 0));
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
        str_attr(&f, "drive", data.drive.as_str())?;
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
            str_attr(&d, "unit", data.drive.unit())?;
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
            if stds {
                let nan = c64::new(f64::NAN, f64::NAN);
                let sigma: Vec<c64> = sw
                    .steps
                    .iter()
                    .flat_map(|s| {
                        (0..nc).flat_map(move |c| {
                            (0..h).map(move |k| {
                                if c < s.sigma.nrows() && k < s.sigma.ncols() {
                                    s.sigma[(c, k)]
                                } else {
                                    nan
                                }
                            })
                        })
                    })
                    .collect();
                let d = g.new_dataset::<c64>().shape((n, nc, h)).create("sigma")?;
                d.write_raw(&sigma)?;
                str_attr(&d, "unit", CHANNEL_UNIT)?;
            }
        }
        Ok(())
    })()
    .map_err(h5err(path))?;
    std::fs::rename(&tmp, path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

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
    crate::formats::files::input_file(path)?;
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
    // Optional: what the `force` datasets hold (force unless it says `voltage`).
    let drive = if f.attr_names().is_ok_and(|n| n.iter().any(|a| a == "drive")) {
        let d = str_attr(&f, "/", "drive")?;
        nlsim_calib::Drive::parse(&d).ok_or_else(|| {
            err(
                "/",
                format!(
                    "attribute 'drive' = {} is not 'force' or 'voltage'",
                    crate::formats::files::quoted(&d)
                ),
            )
        })?
    } else {
        nlsim_calib::Drive::Force
    };
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
        let sigma_name = format!("{gname}/sigma");
        let sigma = if f.link_exists(&sigma_name) {
            if budget < n * nc * harmonics {
                return Err(err(
                    &sigma_name,
                    format!("exceeds the budget of {H5_MAX_VALUES} values"),
                ));
            }
            budget -= n * nc * harmonics;
            Some(
                complex_dataset(&sigma_name, &[n, nc, harmonics])?
                    .read_raw::<c64>()
                    .map_err(|e| err(&sigma_name, e.to_string()))?,
            )
        } else {
            None
        };
        let steps = (0..n)
            .map(|s| Step {
                frequency_hz: freq[s],
                force: force[s * harmonics..(s + 1) * harmonics].to_vec(),
                response: Mat::from_fn(nc, harmonics, |c, k| resp[(s * nc + c) * harmonics + k]),
                sigma: sigma.as_ref().map_or_else(Mat::new, |v| {
                    Mat::from_fn(nc, harmonics, |c, k| v[(s * nc + c) * harmonics + k])
                }),
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
        drive,
        channels,
        harmonics,
        sweeps,
    };
    data.validate_measured()
        .map_err(|e| err("/", e.to_string()))?;
    Ok(data)
}
