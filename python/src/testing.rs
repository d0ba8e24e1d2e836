//! `nlsim.virtual_test` and `nlsim.plan`: the test before the test (thesis §4.3–4.4). A
//! virtual stepped-sine test through the electrodynamic shaker model gives test data as
//! `nlsim test` writes them; a plan ranks candidate designs by the Fisher information of the
//! parameters, as `nlsim plan` does. Both take the command's test or plan file (a path, or
//! its TOML text; the Python layer turns a dict into that text) and a `Model`, and run the
//! command's library calls on it, so the numbers are the command's to the last bit.

use crate::data::TestData;
use crate::model::Model;
use crate::runs::{run, vec1};
use crate::{input, py_err};
use nlsim::commands::plan::{PlanRequest, PlanRun, describe_design, run_plan_on};
use nlsim::commands::test::{TestRequest, TestRun, run_test_on};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::Arc;

/// A test or plan file as given: TOML text (it holds a newline or `=`) or a path.
fn settings(arg: &str, spec: &Bound<'_, PyAny>) -> PyResult<(String, PathBuf)> {
    if let Ok(text) = spec.extract::<String>()
        && (text.contains('\n') || text.contains('='))
    {
        return Ok((text, PathBuf::from(format!("<{arg}>"))));
    }
    let path: PathBuf = spec.extract().map_err(|_| {
        input(format!(
            "{arg}: expected the path of a {arg} file, its TOML text or a dict"
        ))
    })?;
    let text =
        nlsim::formats::files::read_text_bounded(&path, nlsim::commands::plan::MAX_SETTINGS_BYTES)
            .map_err(py_err)?;
    Ok((text, path))
}

/// A virtual test's outcome (`nlsim.virtual_test`).
#[pyclass(module = "nlsim._native", name = "VirtualTest", frozen)]
pub struct VirtualTest {
    run: TestRun,
}

#[pymethods]
impl VirtualTest {
    /// The test data the test recorded (with measurement noise), as `nlsim test` writes them.
    #[getter]
    fn data(&self) -> TestData {
        TestData {
            data: Arc::new(self.run.test.data.clone()),
        }
    }

    /// The same test voltage-driven (each sweep's first voltage held), when the test file
    /// asks for the comparison (`compare_open_loop`, default true); else `None`.
    #[getter]
    fn open_loop(&self) -> Option<TestData> {
        self.run.open_loop.as_ref().map(|t| TestData {
            data: Arc::new(t.data.clone()),
        })
    }

    /// The input the shaker drives.
    #[getter]
    fn drive(&self) -> String {
        self.run.drive.clone()
    }

    /// Each step's frequency (Hz), all sweeps in order, shape `(n_steps,)`.
    #[getter]
    fn frequency_hz<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.steps().map(|s| s.frequency_hz).collect())
    }

    /// The coil voltage harmonics `0..=H` of each step (V), shape `(n_steps, H + 1)`.
    #[getter]
    fn voltage<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<faer::c64>> {
        let rows: Vec<&Vec<faer::c64>> = self.steps().map(|s| &s.voltage).collect();
        table(py, &rows)
    }

    /// The force harmonics `0..=H` on the structure at each step, before measurement noise
    /// (N), shape `(n_steps, H + 1)`.
    #[getter]
    fn force<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<faer::c64>> {
        let rows: Vec<&Vec<faer::c64>> = self.steps().map(|s| &s.force).collect();
        table(py, &rows)
    }

    /// The force controller's relative error at each step.
    #[getter]
    fn force_error<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.steps().map(|s| s.force_error).collect())
    }

    /// Each recorded channel's absolute noise floor (its unit).
    #[getter]
    fn noise_floors(&self) -> Vec<(String, f64)> {
        self.run.floors.clone()
    }

    /// Warnings about the noise (a floor that buries a channel's response).
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.run.warnings.clone()
    }

    /// The time histories the test would have recorded, when the test file has a `[raw]`
    /// table (as `nlsim test --raw` writes them; else `None`): a dict with `rate_hz`,
    /// `time_s`, `voltage` (the coil voltage, V), `force` (the stinger force with the gauge's
    /// noise, N), `responses` (`{sensor: samples}` with noise, every sensor), `noise_std`
    /// (`{sensor or "force": standard deviation}`), `steps` (one dict per step: `sweep`,
    /// `frequency_hz`, `start`, `measured`, `end` sample indices, the measured window from
    /// `measured` to `end`), `dwell_s`, `settle_s`, `oversample` and `status`.
    #[getter]
    fn raw<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(raw) = &self.run.raw else {
            return Ok(None);
        };
        let rec = &raw.record;
        let d = PyDict::new(py);
        d.set_item("rate_hz", rec.rate_hz)?;
        let n = rec.voltage.len();
        d.set_item(
            "time_s",
            vec1(py, (0..n).map(|k| k as f64 / rec.rate_hz).collect()),
        )?;
        d.set_item("voltage", vec1(py, rec.voltage.clone()))?;
        d.set_item("force", vec1(py, rec.force.clone()))?;
        let responses = PyDict::new(py);
        let noise = PyDict::new(py);
        for ((name, _, x), s) in rec.responses.iter().zip(&raw.sigmas) {
            responses.set_item(name, vec1(py, x.clone()))?;
            noise.set_item(name, *s)?;
        }
        noise.set_item("force", raw.sigmas.last().copied().unwrap_or(0.0))?;
        d.set_item("responses", responses)?;
        d.set_item("noise_std", noise)?;
        let steps = pyo3::types::PyList::empty(py);
        for st in &rec.steps {
            let s = PyDict::new(py);
            s.set_item("sweep", &st.sweep)?;
            s.set_item("frequency_hz", st.frequency_hz)?;
            s.set_item("start", st.start)?;
            s.set_item("measured", st.measured)?;
            s.set_item("end", st.end)?;
            steps.append(s)?;
        }
        d.set_item("steps", steps)?;
        d.set_item("dwell_s", raw.dwell_s)?;
        d.set_item("settle_s", raw.settle_s)?;
        d.set_item("oversample", raw.oversample)?;
        d.set_item("status", rec.status.as_str())?;
        Ok(Some(d))
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.VirtualTest: shaker at '{}', {} sweep(s), {} step(s)>",
            self.run.drive,
            self.run.test.data.sweeps.len(),
            self.run.test.data.n_points()
        )
    }
}

impl VirtualTest {
    fn steps(&self) -> impl Iterator<Item = &nlsim::calib::StepControl> {
        self.run.test.steps.iter().flatten()
    }
}

/// Rows of complex numbers of equal length as a 2-D array (NaN-padded if not).
fn table<'py>(py: Python<'py>, rows: &[&Vec<faer::c64>]) -> Bound<'py, PyArray2<faer::c64>> {
    let w = rows.iter().map(|r| r.len()).max().unwrap_or(0);
    let nan = faer::c64::new(f64::NAN, f64::NAN);
    Array2::from_shape_fn((rows.len(), w), |(i, k)| {
        rows[i].get(k).copied().unwrap_or(nan)
    })
    .into_pyarray(py)
}

/// Runs the virtual stepped-sine test `test` on `model`, as `nlsim test MODEL TEST` does:
/// the shaker model (`[shaker]`), the force controller (`[control]`), the sweeps
/// (`[[sweep]]`), seeded noise; `test` is a test file's path or TOML text
/// (`docs/planning.md`). Nothing is written (`out` and `report` of the file are not used):
/// the data come back as `result.data`, which `TestData.save` writes and `calibrate` takes.
#[pyfunction]
#[pyo3(signature = (model, test, threads=None))]
pub fn virtual_test(
    py: Python<'_>,
    model: &Model,
    test: &Bound<'_, PyAny>,
    threads: Option<usize>,
) -> PyResult<VirtualTest> {
    let (text, path) = settings("test", test)?;
    let req = TestRequest::parse(&text, &path, &model.source).map_err(py_err)?;
    req.check().map_err(py_err)?;
    let m = model.inner.clone();
    let run = run(py, threads, move |stop| {
        run_test_on(m, &req, &mut |_, _| stop.check())
    })?
    .map_err(py_err)?;
    Ok(VirtualTest { run })
}

/// A test plan's outcome (`nlsim.plan`): every candidate design, best first.
#[pyclass(module = "nlsim._native", name = "Plan", frozen)]
pub struct Plan {
    run: PlanRun,
}

#[pymethods]
impl Plan {
    /// The parameters planned for.
    #[getter]
    fn params(&self) -> Vec<String> {
        self.run.params.iter().map(ToString::to_string).collect()
    }

    /// Their nominal values.
    #[getter]
    fn nominal<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.run.nominal.clone())
    }

    /// The ranking criterion (`"D"`, `"T"`, `"A"`, `"E"` or `"max-variance"`).
    #[getter]
    fn criterion(&self) -> &'static str {
        self.run.request.criterion.as_str()
    }

    /// Each design in words, best first: `(drive, level N, signal, band, sensors,
    /// harmonics)`.
    #[getter]
    fn designs(&self) -> Vec<(String, String, String, String, String, String)> {
        self.run
            .ranked
            .iter()
            .map(|r| {
                let [a, b, c, d, e, f] = describe_design(&self.run.candidates, &self.run.sweeps, r);
                (a, b, c, d, e, f)
            })
            .collect()
    }

    /// `ln det F` of each design (relative units), best first, shape `(n_designs,)`.
    #[getter]
    fn log_det<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.run.ranked.iter().map(|r| r.summary.log_det).collect(),
        )
    }

    /// `max_j (F⁻¹)_jj` of each design, best first.
    #[getter]
    fn max_variance<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.run
                .ranked
                .iter()
                .map(|r| r.summary.max_variance)
                .collect(),
        )
    }

    /// Cramér–Rao relative standard deviations (a fraction of the nominal value) of each
    /// design and parameter, best first, shape `(n_designs, n_params)`.
    #[getter]
    fn relative_std<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let r = &self.run.ranked;
        let p = self.run.params.len();
        Array2::from_shape_fn((r.len(), p), |(i, j)| r[i].summary.std[j]).into_pyarray(py)
    }

    /// Collinearity index of each design (above about 15 the parameters cannot be told
    /// apart).
    #[getter]
    fn collinearity<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.run
                .ranked
                .iter()
                .map(|r| r.summary.collinearity)
                .collect(),
        )
    }

    /// Warnings about the noise model.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.run.warnings.clone()
    }

    fn __len__(&self) -> usize {
        self.run.ranked.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.Plan: {} design(s) for {}, criterion {}>",
            self.run.ranked.len(),
            self.params().join(", "),
            self.criterion()
        )
    }
}

/// Ranks the candidate test designs of `plan` on `model` by the Fisher information of the
/// parameters they would identify, as `nlsim plan MODEL PLAN` does: every combination of
/// drive point, force level, signal, band, sensor set and measured harmonics, from the
/// analytic harmonic-balance sensitivities; `plan` is a plan file's path or TOML text
/// (`docs/planning.md`). Nothing is written.
#[pyfunction]
#[pyo3(signature = (model, plan, threads=None))]
pub fn plan(
    py: Python<'_>,
    model: &Model,
    plan: &Bound<'_, PyAny>,
    threads: Option<usize>,
) -> PyResult<Plan> {
    let (text, path) = settings("plan", plan)?;
    let req = PlanRequest::parse(&text, &path, &model.source).map_err(py_err)?;
    let m = model.inner.clone();
    let run = run(py, threads, move |stop| {
        run_plan_on(m, &req, &|_, _| stop.check())
    })?
    .map_err(py_err)?;
    Ok(Plan { run })
}
