//! `nlsim.Balance`: the harmonic-balance system of a model built once (thesis eq. 13–17,
//! condensed on the nonlinear DOFs), solved point by point from Python — for loops of one's
//! own (a custom sweep, an optimiser) without the continuation around it. Each `solve` is one
//! Newton solve at one frequency and level, run on the calling thread with the GIL released
//! (a point takes microseconds to milliseconds: no worker thread, no Ctrl-C check).

use crate::runs::{Stop, Subject, run};
use crate::{input, py_err};
use faer::c64;
use nlsim::hb::{HbConfig, HbSystem, HbWorkspace};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1};
use pyo3::prelude::*;
use std::f64::consts::PI;
use std::sync::Mutex;
use std::time::Instant;

/// Workspace budget of a `Balance` (bytes), as the stepped sine's.
const WORKSPACE_BYTES: usize = 64 << 20;

/// A harmonic-balance system, built once, solved at any frequency and level.
#[pyclass(module = "nlsim._native", name = "Balance", frozen)]
pub struct Balance {
    system: HbSystem,
    /// Newton's workspace, reused from solve to solve.
    ws: Mutex<HbWorkspace>,
}

/// One solved point (`Balance.solve`).
#[pyclass(module = "nlsim._native", name = "BalancePoint", frozen)]
pub struct BalancePoint {
    /// The unknowns, made a numpy array once (the next solve's `start`).
    x: Py<PyArray1<f64>>,
    y: faer::Mat<c64>,
    status: &'static str,
    iterations: usize,
    residual: f64,
    seconds: f64,
}

#[pymethods]
impl BalancePoint {
    /// The unknowns (harmonics of the condensed DOFs, real layout): the `start` of the next
    /// solve along a sweep.
    #[getter]
    fn x<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        self.x.bind(py).clone()
    }

    /// Sensor harmonics `0..=H` (complex, cosine convention), shape `(n_sensors, H + 1)`.
    #[getter]
    fn response<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<c64>> {
        Array2::from_shape_fn((self.y.nrows(), self.y.ncols()), |(i, k)| self.y[(i, k)])
            .into_pyarray(py)
    }

    /// `"converged"`, or why Newton stopped (the last iterate is kept).
    #[getter]
    fn status(&self) -> &'static str {
        self.status
    }

    /// Newton iterations.
    #[getter]
    fn iterations(&self) -> usize {
        self.iterations
    }

    /// The final residual norm.
    #[getter]
    fn residual(&self) -> f64 {
        self.residual
    }

    /// Wall time of the library's Newton solve alone (s), without the Python call around it:
    /// what the overhead benchmark compares a call's time with.
    #[getter]
    fn seconds(&self) -> f64 {
        self.seconds
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.BalancePoint: {} in {} iteration(s), residual {:.2e}>",
            self.status, self.iterations, self.residual
        )
    }
}

#[pymethods]
impl Balance {
    /// The harmonic-balance system of `model` (or a `Reduced`) with `harmonics` harmonics on
    /// its reduction (`modes`, `residual_flexibility`, as `frf`), the excitation at its
    /// nominal amplitudes times the `level` of each solve.
    #[new]
    #[pyo3(signature = (model, harmonics=7, modes=20, residual_flexibility=true, threads=None))]
    fn new(
        py: Python<'_>,
        model: &Bound<'_, PyAny>,
        harmonics: usize,
        modes: usize,
        residual_flexibility: bool,
        threads: Option<usize>,
    ) -> PyResult<Self> {
        let subject = Subject::of(model)?;
        if modes == 0 {
            return Err(input("modes: 0; keep at least one mode"));
        }
        if subject.model().excitation().is_empty() {
            return Err(input(format!(
                "model '{}' has no excitation point to force",
                subject.model().name()
            )));
        }
        let set = crate::harmonic_set(harmonics, crate::MAX_HARMONICS)?;
        let system = run(py, threads, move |stop: &Stop| -> nlsim::Result<_> {
            let (reduced, m) = subject.reduced(modes, residual_flexibility, threads, stop)?;
            Ok(HbSystem::from_model(
                &m,
                &reduced,
                set,
                HbConfig::default(),
            )?)
        })?
        .map_err(py_err)?;
        let ws = Mutex::new(system.workspace(WORKSPACE_BYTES));
        Ok(Self { system, ws })
    }

    /// Number of unknowns (the length of `x`).
    #[getter]
    fn n_unknowns(&self) -> usize {
        self.system.n_unknowns()
    }

    /// Solves the balance at `freq_hz` and `level` by Newton from `start` (a previous
    /// point's `x`) or, without one, from rest (the linear response, then a continuation in
    /// the level where that fails).
    #[pyo3(signature = (freq_hz, level=1.0, start=None))]
    fn solve(
        &self,
        py: Python<'_>,
        freq_hz: f64,
        level: f64,
        start: Option<PyReadonlyArray1<'_, f64>>,
    ) -> PyResult<BalancePoint> {
        if !(freq_hz > 0.0 && freq_hz.is_finite()) {
            return Err(input(format!(
                "freq_hz: {freq_hz}; give a positive frequency"
            )));
        }
        if !level.is_finite() {
            return Err(input(format!("level: {level} is not a finite number")));
        }
        let n = self.system.n_unknowns();
        let x0 = match &start {
            None => None,
            Some(a) => {
                let s = a.as_slice().map_err(|e| input(format!("start: {e}")))?;
                if s.len() != n {
                    return Err(input(format!(
                        "start: {} values; the balance has {n} unknowns",
                        s.len()
                    )));
                }
                if let Some(k) = s.iter().position(|v| !v.is_finite()) {
                    return Err(input(format!("start[{k}] is {}, not finite", s[k])));
                }
                Some(s.to_vec())
            }
        };
        let omega = 2.0 * PI * freq_hz;
        let system = &self.system;
        let ws = &self.ws;
        let (x, rep, seconds) = py
            .detach(move || -> nlsim::Result<_> {
                let t = Instant::now();
                let (x, rep) = match x0 {
                    Some(mut x) => {
                        let mut ws = ws.lock().unwrap_or_else(|p| p.into_inner());
                        let rep = system.solve_with(&mut ws, omega, level, &mut x)?;
                        (x, rep)
                    }
                    None => system.solve_from_rest(omega, level)?,
                };
                Ok((x, rep, t.elapsed().as_secs_f64()))
            })
            .map_err(py_err)?;
        let y = self.system.sensor_response(&x, omega, level);
        Ok(BalancePoint {
            x: PyArray1::from_vec(py, x).unbind(),
            y,
            status: rep.status.as_str(),
            iterations: rep.iterations,
            residual: rep.residual,
            seconds,
        })
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.Balance: {} unknowns, H = {}>",
            self.system.n_unknowns(),
            self.system.harmonics().h
        )
    }
}
