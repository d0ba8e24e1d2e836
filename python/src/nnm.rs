//! `nlsim.nnm`: a nonlinear mode — the backbone frequency and modal damping ratio against the
//! modal amplitude — by the extended periodic motion concept, as `nlsim nnm` computes it
//! (the same reduction without residual flexibility, the same cluster alignment, the same
//! amplitudes), so the numbers are the command's to the last bit.

use crate::model::Model;
use crate::runs::{run, vec1};
use crate::{input, py_err};
use faer::c64;
use nlsim::hb::nnm::{MAX_NNM_POINTS, MAX_NNM_UNKNOWNS, NnmReport};
use numpy::ndarray::Array3;
use numpy::{IntoPyArray, PyArray1, PyArray3};
use pyo3::prelude::*;
use std::f64::consts::PI;

/// A nonlinear mode (`nlsim.nnm`), amplitudes first, in increasing amplitude.
#[pyclass(module = "nlsim._native", name = "Nnm", frozen)]
pub struct Nnm {
    report: NnmReport,
    /// Sensor harmonics per point (sensors × H+1).
    y: Vec<faer::Mat<c64>>,
    sensors: Vec<String>,
    mode: usize,
    modes: usize,
}

#[pymethods]
impl Nnm {
    /// Modal amplitude (m √kg: the fundamental's cosine coefficient of the mass-normalised
    /// coordinate of the mode followed), shape `(n_points,)`.
    #[getter]
    fn amplitude<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.report.points.iter().map(|p| p.amplitude).collect())
    }

    /// Frequency of the periodic motion (Hz), shape `(n_points,)`.
    #[getter]
    fn frequency_hz<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.report
                .points
                .iter()
                .map(|p| p.omega / (2.0 * PI))
                .collect(),
        )
    }

    /// Modal damping ratio `ζ = ξ / 2ω` (1), shape `(n_points,)`.
    #[getter]
    fn damping_ratio<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.report
                .points
                .iter()
                .map(|p| p.damping_ratio())
                .collect(),
        )
    }

    /// The artificial mass-proportional damping `ξ` (1/s) that makes the motion periodic,
    /// shape `(n_points,)`.
    #[getter]
    fn xi<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.report.points.iter().map(|p| p.xi).collect())
    }

    /// Sensor harmonics `0..=H` (complex, the sensor's quantity: m, m/s or m/s², cosine
    /// convention), shape `(n_points, n_sensors, H + 1)`.
    #[getter]
    fn response<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<c64>> {
        let (s, h) = self.y.first().map_or((0, 0), |m| (m.nrows(), m.ncols()));
        Array3::from_shape_fn((self.y.len(), s, h), |(p, i, k)| self.y[p][(i, k)]).into_pyarray(py)
    }

    /// Newton iterations of each point.
    #[getter]
    fn iterations(&self) -> Vec<usize> {
        self.report.points.iter().map(|p| p.iterations).collect()
    }

    /// Sensor names, in the order of `response`'s second axis.
    #[getter]
    fn sensors(&self) -> Vec<String> {
        self.sensors.clone()
    }

    /// The linear mode it grew from (1 = the lowest).
    #[getter]
    fn mode(&self) -> usize {
        self.mode
    }

    /// Retained modes of the reduced model.
    #[getter]
    fn modes(&self) -> usize {
        self.modes
    }

    /// `"converged"` when every amplitude was reached; otherwise why it stopped (the points
    /// before are kept).
    #[getter]
    fn status(&self) -> &'static str {
        self.report.status.as_str()
    }

    /// Where and why it stopped short; empty when converged.
    #[getter]
    fn detail(&self) -> String {
        self.report.detail.clone()
    }

    fn __len__(&self) -> usize {
        self.report.points.len()
    }

    fn __repr__(&self) -> String {
        let pts = &self.report.points;
        match (pts.first(), pts.last()) {
            (Some(a), Some(b)) => format!(
                "<nlsim.Nnm: mode {}, {} point(s), {:.4} Hz at amplitude {:.3e} to {:.4} Hz at \
                 {:.3e} m√kg, {}>",
                self.mode,
                pts.len(),
                a.omega / (2.0 * PI),
                a.amplitude,
                b.omega / (2.0 * PI),
                b.amplitude,
                self.report.status.as_str()
            ),
            _ => format!("<nlsim.Nnm: mode {}, no point>", self.mode),
        }
    }
}

/// The nonlinear mode of `model` grown from linear mode `mode` (1 = the lowest) by the
/// extended periodic motion concept (Krack 2015): `points` modal amplitudes from
/// `from_amplitude` to `to_amplitude` (m √kg), evenly spaced in their logarithm, `harmonics`
/// harmonics of the frequency, the `modes` lowest modes retained without residual
/// flexibility — `nlsim nnm MODEL --mode … --from … --to …` with the same defaults.
#[pyfunction]
#[pyo3(signature = (model, from_amplitude, to_amplitude, mode=1, points=50, harmonics=7, modes=10, threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn nnm(
    py: Python<'_>,
    model: &Model,
    from_amplitude: f64,
    to_amplitude: f64,
    mode: usize,
    points: usize,
    harmonics: usize,
    modes: usize,
    threads: Option<usize>,
) -> PyResult<Nnm> {
    for (arg, v) in [
        ("from_amplitude", from_amplitude),
        ("to_amplitude", to_amplitude),
    ] {
        if !(v > 0.0 && v.is_finite()) {
            return Err(input(format!(
                "{arg}: {v}; give a positive modal amplitude (m √kg)"
            )));
        }
    }
    if !(2..=MAX_NNM_POINTS).contains(&points) {
        return Err(input(format!(
            "points: {points}; give 2 to {MAX_NNM_POINTS} amplitudes"
        )));
    }
    if mode == 0 {
        return Err(input("mode: 0; modes count from 1"));
    }
    if modes < mode {
        return Err(input(format!(
            "modes: {modes}; mode {mode} needs at least {mode} retained modes"
        )));
    }
    let unknowns = modes.saturating_mul(2 * harmonics + 1);
    if unknowns > MAX_NNM_UNKNOWNS {
        return Err(input(format!(
            "modes x (2 harmonics + 1) = {unknowns} unknowns, more than {MAX_NNM_UNKNOWNS} (the \
             Newton matrix is dense): retain fewer modes or harmonics"
        )));
    }
    let set = crate::harmonic_set(harmonics, crate::MAX_HARMONICS)?;
    let m = model.inner.clone();
    if mode > m.n_dofs() {
        return Err(input(format!(
            "mode: {mode} of a model with {} DOFs",
            m.n_dofs()
        )));
    }
    let amplitudes = nlsim::hb::nnm::log_amplitudes(from_amplitude, to_amplitude, points);
    let (report, y, sensors, kept) = run(py, threads, move |stop| -> nlsim::Result<_> {
        let free = nlsim::hb::nnm::free_model(&m)?;
        let reduced = crate::runs::reduce_model(&free, modes, false, threads, stop)?;
        let kept = reduced.modes.len();
        let unknowns = kept.saturating_mul(2 * harmonics + 1);
        if unknowns > MAX_NNM_UNKNOWNS {
            return Err(nlsim::Error::Usage(format!(
                "modes: a cluster of equal frequencies kept whole gives {kept} modes, {unknowns} \
                 unknowns, more than {MAX_NNM_UNKNOWNS}: retain fewer modes or harmonics"
            )));
        }
        let system = nlsim::hb::nnm::free_motion_system(&free, &reduced, set)?;
        let report =
            nlsim::hb::nnm::nonlinear_mode(&system, mode - 1, &amplitudes, &mut |_| stop.check())?;
        let y = report
            .points
            .iter()
            .map(|p| nlsim::hb::nnm::sensor_harmonics(&system, p))
            .collect();
        let sensors = system.sensors().iter().map(|s| s.name.clone()).collect();
        Ok((report, y, sensors, kept))
    })?
    .map_err(py_err)?;
    if report.points.is_empty() {
        return Err(crate::ComputationError::new_err(format!(
            "nonlinear mode {mode}: no amplitude converged ({})",
            nlsim::formats::files::one_line(&report.detail)
        )));
    }
    Ok(Nnm {
        report,
        y,
        sensors,
        mode,
        modes: kept,
    })
}
