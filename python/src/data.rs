//! `nlsim.TestData`: stepped-sine test data (thesis §4.1, eq. 14) built from numpy arrays or
//! read from the files `nlsim calibrate` reads, and written as nlsim's CSV. Per step: the
//! frequency, the drive's harmonics 1..H (force in N, or voltage in V) and every channel's
//! response harmonics, optionally with their measured standard deviations.

use crate::input;
use crate::model::Model;
use crate::py_err;
use faer::{Mat, c64};
use nlsim::calib::{Channel, Drive, Noise, Step, Sweep, SweepDirection, TestData as Data};
use nlsim::kernel::Quantity;
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyReadonlyArrayDyn, PyUntypedArrayMethods};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use std::path::PathBuf;
use std::sync::Arc;

/// Most steps of test data built from arrays (as the virtual test).
const MAX_STEPS: usize = 1_000_000;

/// Stepped-sine test data: one drive point, response channels, sweeps of steps.
#[pyclass(module = "nlsim._native", name = "TestData", frozen)]
pub struct TestData {
    pub(crate) data: Arc<Data>,
}

/// `v` as a C-contiguous numpy array of `dtype` (lists, other dtypes and strided arrays
/// converted by numpy, a copy only where needed).
fn numpy_array<'py>(arg: &str, v: &Bound<'py, PyAny>, dtype: &str) -> PyResult<Bound<'py, PyAny>> {
    let py = v.py();
    let kw = PyDict::new(py);
    kw.set_item("dtype", dtype)?;
    py.import("numpy")?
        .call_method("ascontiguousarray", (v,), Some(&kw))
        .map_err(|e| input(format!("{arg}: not convertible to {dtype}: {e}")))
}

/// A complex array of `arg` (anything numpy turns into complex128) as `(shape, values in C
/// order)`.
fn complex_array(arg: &str, v: &Bound<'_, PyAny>) -> PyResult<(Vec<usize>, Vec<c64>)> {
    let v = numpy_array(arg, v, "complex128")?;
    let a: PyReadonlyArrayDyn<'_, c64> = v
        .extract()
        .map_err(|_| input(format!("{arg}: expected a complex array")))?;
    let shape = a.shape().to_vec();
    let values = a.as_array().iter().copied().collect::<Vec<c64>>();
    Ok((shape, values))
}

/// A real 1-D array of `arg`.
fn real_vector(arg: &str, v: &Bound<'_, PyAny>) -> PyResult<Vec<f64>> {
    let v = numpy_array(arg, v, "float64")?;
    let a: PyReadonlyArrayDyn<'_, f64> = v
        .extract()
        .map_err(|_| input(format!("{arg}: expected a one-dimensional float64 array")))?;
    if a.ndim() != 1 {
        return Err(input(format!(
            "{arg}: shape {}; expected one dimension (steps,)",
            shape_text(a.shape())
        )));
    }
    Ok(a.as_array().iter().copied().collect())
}

/// A numpy shape as Python prints it: `(4, 1)`, `(5,)`.
fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// `values` of `shape` as `rows × cols × h` (a missing last axis is one harmonic).
fn as_3d(
    arg: &str,
    shape: &[usize],
    values: Vec<c64>,
    steps: usize,
    rows: usize,
) -> PyResult<(usize, Vec<c64>)> {
    match *shape {
        [s, c] if s == steps && c == rows => Ok((1, values)),
        [s, c, h] if s == steps && c == rows && h >= 1 => Ok((h, values)),
        _ => Err(input(format!(
            "{arg}: shape {}; expected (steps, channels) = ({steps}, {rows}) or (steps, \
             channels, harmonics)",
            shape_text(shape)
        ))),
    }
}

/// A noise argument: one number for every channel, or one per channel (`n`); `default`
/// when not given. Each value non-negative and finite.
fn per_channel(
    arg: &str,
    v: Option<&Bound<'_, PyAny>>,
    default: f64,
    n: usize,
) -> PyResult<Vec<f64>> {
    let values = match v {
        None => vec![default; n],
        Some(v) if v.is_none() => vec![default; n],
        Some(v) => match v.extract::<f64>() {
            Ok(x) => vec![x; n],
            Err(_) => {
                let list: Vec<f64> = v.extract().map_err(|_| {
                    input(format!(
                        "{arg}: expected a number or one number per channel"
                    ))
                })?;
                if list.len() != n {
                    return Err(input(format!(
                        "{arg}: {} values for {n} channel(s)",
                        list.len()
                    )));
                }
                list
            }
        },
    };
    if let Some((i, x)) = values
        .iter()
        .enumerate()
        .find(|(_, x)| !(**x >= 0.0 && x.is_finite()))
    {
        return Err(input(format!(
            "{arg}: {x} (channel {}); give a non-negative finite number",
            i + 1
        )));
    }
    Ok(values)
}

/// One sweep from its dict (`frequency_hz`, `force`, `response`, optional `sigma`, `label`,
/// `direction`).
fn sweep_of(i: usize, d: &Bound<'_, PyDict>, n_channels: usize) -> PyResult<(Sweep, usize)> {
    let arg = |k: &str| format!("sweeps[{i}]['{k}']");
    for key in d.keys() {
        let k: String = key
            .extract()
            .map_err(|_| input(format!("sweeps[{i}]: keys are str")))?;
        if ![
            "frequency_hz",
            "force",
            "response",
            "sigma",
            "label",
            "direction",
        ]
        .contains(&k.as_str())
        {
            return Err(input(format!(
                "sweeps[{i}]: unknown key '{k}' (known: frequency_hz, force, response, sigma, \
                 label, direction)"
            )));
        }
    }
    let need = |k: &str| -> PyResult<Bound<'_, PyAny>> {
        d.get_item(k)?
            .ok_or_else(|| input(format!("sweeps[{i}]: no '{k}'")))
    };
    let freq = real_vector(&arg("frequency_hz"), &need("frequency_hz")?)?;
    let steps = freq.len();
    if steps == 0 || steps > MAX_STEPS {
        return Err(input(format!(
            "{}: {steps} steps; give 1 to {MAX_STEPS}",
            arg("frequency_hz")
        )));
    }
    let (fshape, fvals) = complex_array(&arg("force"), &need("force")?)?;
    let (hf, fvals) = match *fshape {
        [s] if s == steps => (1, fvals),
        [s, h] if s == steps && h >= 1 => (h, fvals),
        _ => {
            return Err(input(format!(
                "{}: shape {}; expected (steps,) = ({steps},) or (steps, harmonics)",
                arg("force"),
                shape_text(&fshape)
            )));
        }
    };
    let (rshape, rvals) = complex_array(&arg("response"), &need("response")?)?;
    let (h, rvals) = as_3d(&arg("response"), &rshape, rvals, steps, n_channels)?;
    if hf != h {
        return Err(input(format!(
            "{}: {hf} harmonic(s), but the response holds {h}",
            arg("force")
        )));
    }
    let sigma = match d.get_item("sigma")? {
        None => None,
        Some(v) if v.is_none() => None,
        Some(v) => {
            let (sshape, svals) = complex_array(&arg("sigma"), &v)?;
            if sshape != rshape {
                return Err(input(format!(
                    "{}: shape {}, not the response's {}",
                    arg("sigma"),
                    shape_text(&sshape),
                    shape_text(&rshape)
                )));
            }
            Some(svals)
        }
    };
    let label = match d.get_item("label")? {
        Some(v) if !v.is_none() => v
            .extract::<String>()
            .map_err(|_| input(format!("{}: expected a str", arg("label"))))?,
        _ => format!("sweep {}", i + 1),
    };
    let direction = match d.get_item("direction")? {
        Some(v) if !v.is_none() => match v.extract::<String>().as_deref() {
            Ok("up") => SweepDirection::Up,
            Ok("down") => SweepDirection::Down,
            _ => {
                return Err(input(format!(
                    "{}: expected 'up' or 'down'",
                    arg("direction")
                )));
            }
        },
        _ if steps >= 2 && freq[steps - 1] < freq[0] => SweepDirection::Down,
        _ => SweepDirection::Up,
    };
    let steps = (0..steps)
        .map(|s| Step {
            frequency_hz: freq[s],
            force: fvals[s * h..(s + 1) * h].to_vec(),
            response: Mat::from_fn(n_channels, h, |c, k| rvals[(s * n_channels + c) * h + k]),
            sigma: sigma.as_ref().map_or_else(Mat::new, |sv| {
                Mat::from_fn(n_channels, h, |c, k| sv[(s * n_channels + c) * h + k])
            }),
        })
        .collect();
    Ok((
        Sweep {
            label,
            direction,
            steps,
        },
        h,
    ))
}

#[pymethods]
impl TestData {
    /// Test data from arrays. `input`: the model's excitation point the drive was measured
    /// at; `channels`: `{name: quantity}` in order, each name a sensor of the model and the
    /// quantity `"displacement"` (m), `"velocity"` (m/s) or `"acceleration"` (m/s²);
    /// `sweeps`: a list of dicts, each with `frequency_hz` (steps,), `force` (steps,) or
    /// (steps, H) complex (N, or V when `drive="voltage"`), `response` (steps, channels) or
    /// (steps, channels, H) complex, optionally `sigma` of the response's shape (the real
    /// part the standard deviation of each harmonic's real part, the imaginary part that of
    /// its imaginary part; NaN where `noise` applies), `label` and `direction` (`"up"`,
    /// `"down"`; default from the frequencies). `noise` (relative, a fraction of the
    /// amplitude; default 0.01) and `noise_absolute` (the channel's unit; default 0), each a
    /// number or one per channel, are the noise model where `sigma` is not given. Harmonic `k` of the arrays is index `k - 1`.
    #[new]
    #[pyo3(signature = (input, channels, sweeps, noise=None, noise_absolute=None, drive="force"))]
    fn new(
        input: String,
        channels: &Bound<'_, PyDict>,
        sweeps: &Bound<'_, PyList>,
        noise: Option<&Bound<'_, PyAny>>,
        noise_absolute: Option<&Bound<'_, PyAny>>,
        drive: &str,
    ) -> PyResult<Self> {
        let drive = Drive::parse(drive)
            .ok_or_else(|| crate::input(format!("drive: '{drive}'; use 'force' or 'voltage'")))?;
        let n = channels.len();
        let relative = per_channel("noise", noise, 0.01, n)?;
        let absolute = per_channel("noise_absolute", noise_absolute, 0.0, n)?;
        let mut chans = Vec::new();
        for (k, v) in channels.iter() {
            let name: String = k
                .extract()
                .map_err(|_| crate::input("channels: keys are channel (sensor) names"))?;
            let q: String = v.extract().map_err(|_| {
                crate::input(format!("channels['{name}']: expected a quantity (str)"))
            })?;
            let quantity = Quantity::parse(&q)
                .map_err(|e| crate::input(format!("channels['{name}']: {e}")))?;
            chans.push(Channel {
                name,
                quantity,
                noise: Noise {
                    absolute: absolute[chans.len()],
                    relative: relative[chans.len()],
                },
            });
        }
        if chans.is_empty() {
            return Err(crate::input("channels: name at least one channel"));
        }
        let mut list = Vec::new();
        let mut harmonics = None;
        for (i, s) in sweeps.iter().enumerate() {
            let d = s
                .cast::<PyDict>()
                .map_err(|_| crate::input(format!("sweeps[{i}]: expected a dict")))?;
            let (sweep, h) = sweep_of(i, d, chans.len())?;
            match harmonics {
                Some(h0) if h0 != h => {
                    return Err(crate::input(format!(
                        "sweeps[{i}]: {h} harmonic(s), but sweeps[0] holds {h0}"
                    )));
                }
                _ => harmonics = Some(h),
            }
            list.push(sweep);
        }
        let data = Data {
            input,
            drive,
            channels: chans,
            harmonics: harmonics.ok_or_else(|| crate::input("sweeps: give at least one sweep"))?,
            sweeps: list,
        };
        data.validate()
            .map_err(|e| crate::input(format!("test data: {e}")))?;
        Ok(Self {
            data: Arc::new(data),
        })
    }

    /// Reads the test data `nlsim calibrate` reads for `model`: nlsim's stepped-sine CSV, an
    /// amplitude-and-phase table or a universal file of datasets 58 (HDF5 through h5py and
    /// the constructor). `noise` is the relative noise of data that carry none (UFF 58,
    /// tables), `phase_offset_deg` is added to every response phase (`--phase-offset`).
    #[staticmethod]
    #[pyo3(signature = (path, model, noise=0.01, phase_offset_deg=0.0))]
    fn load(path: PathBuf, model: &Model, noise: f64, phase_offset_deg: f64) -> PyResult<Self> {
        let options = nlsim::formats::test_data::DataOptions {
            noise,
            phase_offset_deg,
        };
        let data =
            nlsim::formats::test_data::read(&path, &model.inner, &options).map_err(py_err)?;
        Ok(Self {
            data: Arc::new(data),
        })
    }

    /// Writes the data as nlsim's stepped-sine CSV (`.csv`; what `nlsim calibrate` reads),
    /// atomically: a file is complete or not there.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        match path.extension().and_then(|e| e.to_str()) {
            Some("csv") => {}
            _ => {
                return Err(crate::input(format!(
                    "path: {}: the package writes test data as .csv (for .h5, write the arrays \
                     with h5py in the layout of docs/file-formats.md)",
                    path.display()
                )));
            }
        }
        nlsim::formats::test_data::write_csv(&path, &self.data).map_err(py_err)
    }

    /// The excitation point the drive was measured at.
    #[getter]
    fn input(&self) -> String {
        self.data.input.clone()
    }

    /// `"force"` (N) or `"voltage"` (V).
    #[getter]
    fn drive(&self) -> &'static str {
        self.data.drive.as_str()
    }

    /// Channel names, in the order of the responses' channel axis.
    #[getter]
    fn channels(&self) -> Vec<String> {
        self.data.channels.iter().map(|c| c.name.clone()).collect()
    }

    /// Each channel's quantity.
    #[getter]
    fn quantities(&self) -> Vec<&'static str> {
        self.data
            .channels
            .iter()
            .map(|c| c.quantity.as_str())
            .collect()
    }

    /// Each channel's noise model `(absolute, relative)`: the standard deviation of a
    /// harmonic's real and imaginary parts is `sqrt(absolute² + (relative |Y|)²)` where the
    /// step gives no `sigma`.
    #[getter]
    fn noise(&self) -> Vec<(f64, f64)> {
        self.data
            .channels
            .iter()
            .map(|c| (c.noise.absolute, c.noise.relative))
            .collect()
    }

    /// Harmonics `H` per step.
    #[getter]
    fn harmonics(&self) -> usize {
        self.data.harmonics
    }

    /// Steps over all sweeps.
    #[getter]
    fn n_points(&self) -> usize {
        self.data.n_points()
    }

    /// The sweeps as dicts of arrays, in the constructor's layout: `label`, `direction`,
    /// `frequency_hz` (steps,), `force` (steps, H), `response` (steps, channels, H) and
    /// `sigma` (the same shape; NaN where the noise model applies) or `None`.
    #[getter]
    fn sweeps<'py>(&self, py: Python<'py>) -> PyResult<Vec<Bound<'py, PyDict>>> {
        let h = self.data.harmonics;
        let c = self.data.channels.len();
        let mut out = Vec::new();
        for s in &self.data.sweeps {
            let d = PyDict::new(py);
            d.set_item("label", &s.label)?;
            d.set_item("direction", s.direction.as_str())?;
            let n = s.steps.len();
            d.set_item(
                "frequency_hz",
                PyArray1::from_vec(py, s.steps.iter().map(|st| st.frequency_hz).collect()),
            )?;
            d.set_item(
                "force",
                Array2::from_shape_fn((n, h), |(i, k)| {
                    s.steps[i]
                        .force
                        .get(k)
                        .copied()
                        .unwrap_or(c64::new(f64::NAN, f64::NAN))
                })
                .into_pyarray(py),
            )?;
            d.set_item(
                "response",
                Array3::from_shape_fn((n, c, h), |(i, j, k)| s.steps[i].response[(j, k)])
                    .into_pyarray(py),
            )?;
            let has_sigma = s.steps.iter().any(|st| st.sigma.nrows() > 0);
            if has_sigma {
                let nan = c64::new(f64::NAN, f64::NAN);
                d.set_item(
                    "sigma",
                    Array3::from_shape_fn((n, c, h), |(i, j, k)| {
                        let m = &s.steps[i].sigma;
                        if j < m.nrows() && k < m.ncols() {
                            m[(j, k)]
                        } else {
                            nan
                        }
                    })
                    .into_pyarray(py),
                )?;
            } else {
                d.set_item("sigma", py.None())?;
            }
            out.push(d);
        }
        Ok(out)
    }

    fn __len__(&self) -> usize {
        self.data.n_points()
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.TestData: {} drive at '{}', {} channel(s), {} sweep(s), {} step(s), H = {}>",
            self.data.drive.as_str(),
            self.data.input,
            self.data.channels.len(),
            self.data.sweeps.len(),
            self.data.n_points(),
            self.data.harmonics
        )
    }
}
