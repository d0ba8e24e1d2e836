//! `nlsim.simulate`: time histories as `nlsim simulate` computes them — the exponential
//! holds on the reduced model (thesis eq. 18–22), the reference integrators (RK45, RK4 on
//! the same reduced model; Newmark and HHT on the unreduced one) — with the command's
//! defaults, so a history equals the command's to the last bit.

use crate::runs::{Subject, run, vec1};
use crate::{input, py_err};
use nlsim::reduction::ModalSystem;
use nlsim::sim::{
    FohConfig, Hold, LoadCase, Newmark, NewmarkConfig, Plant, Rk4Config, Rk45Config, Signal,
    Simulator,
};
use numpy::ndarray::Array2;
use numpy::{IntoPyArray, PyArray1, PyArray2, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;

/// Most integration steps per sample `substeps` takes.
const MAX_SUBSTEPS: usize = 10_000;

/// A time history (`nlsim.simulate`), time first.
#[pyclass(module = "nlsim._native", name = "History", frozen)]
pub struct History {
    h: nlsim::sim::TimeHistory,
    excitation: Vec<String>,
    modes: usize,
}

#[pymethods]
impl History {
    /// Sample times (s), shape `(n_samples,)`.
    #[getter]
    fn time<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let n = self.h.outputs.first().map_or(0, |o| o.values.len());
        vec1(py, (0..n).map(|k| k as f64 * self.h.dt).collect())
    }

    /// Sensor responses in their quantity (m, m/s or m/s²), shape `(n_samples, n_sensors)`.
    #[getter]
    fn outputs<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let n = self.h.outputs.first().map_or(0, |o| o.values.len());
        Array2::from_shape_fn((n, self.h.outputs.len()), |(k, s)| {
            self.h.outputs[s].values[k]
        })
        .into_pyarray(py)
    }

    /// Sensor names, in the order of `outputs`' columns.
    #[getter]
    fn sensors(&self) -> Vec<String> {
        self.h.outputs.iter().map(|o| o.name.clone()).collect()
    }

    /// Force of each excitation point (N), shape `(n_samples, n_inputs)`.
    #[getter]
    fn forces<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let n = self.h.inputs.first().map_or(0, |i| i.1.len());
        Array2::from_shape_fn((n, self.h.inputs.len()), |(k, i)| self.h.inputs[i].1[k])
            .into_pyarray(py)
    }

    /// Element forces (N), shape `(n_samples, n_elements)`, columns in the order of
    /// `elements`.
    #[getter]
    fn element_forces<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        let n = self.h.element_forces.first().map_or(0, Vec::len);
        Array2::from_shape_fn((n, self.h.element_forces.len()), |(k, e)| {
            self.h.element_forces[e][k]
        })
        .into_pyarray(py)
    }

    /// Element names.
    #[getter]
    fn elements(&self) -> Vec<String> {
        self.h.element_names.clone()
    }

    /// The excitation spec each excitation point ran with.
    #[getter]
    fn excitation(&self) -> Vec<String> {
        self.excitation.clone()
    }

    /// Retained modes.
    #[getter]
    fn modes(&self) -> usize {
        self.modes
    }

    /// `"converged"` for a complete run; otherwise why it stopped (the samples computed are
    /// kept).
    #[getter]
    fn status(&self) -> &'static str {
        self.h.status.as_str()
    }

    /// What stopped the run, or `None`.
    #[getter]
    fn detail(&self) -> Option<String> {
        self.h.stopped.as_ref().map(ToString::to_string)
    }

    /// Time step (s).
    #[getter]
    fn dt(&self) -> f64 {
        self.h.dt
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.History: {} sample(s) of {} sensor(s), dt {} s, {}>",
            self.h.outputs.first().map_or(0, |o| o.values.len()),
            self.h.outputs.len(),
            self.h.dt,
            self.h.status.as_str()
        )
    }
}

/// One force per excitation point: a spec of `nlsim simulate --excitation` (`"sine:freq=20"`,
/// `"sweep:f0=5,f1=50"`, …; amplitudes default to the point's nominal one) or samples (N) at
/// `rate_hz`, held linearly between samples and zero after the last.
fn drive(
    point: &nlsim::kernel::Excitation,
    value: &Bound<'_, PyAny>,
    duration: f64,
    rate_hz: f64,
) -> PyResult<(Signal, String)> {
    if let Ok(spec) = value.extract::<String>() {
        let signal =
            nlsim::formats::excitation::parse_excitation(&spec, point.amplitude, duration, rate_hz)
                .map_err(|e| input(format!("excitation['{}']: {e}", point.name)))?;
        nlsim::formats::excitation::nyquist_check(&spec, &signal, rate_hz)
            .map_err(|e| input(format!("excitation['{}']: {e}", point.name)))?;
        return Ok((signal, spec));
    }
    let samples = value
        .extract::<PyReadonlyArray1<'_, f64>>()
        .map_err(|_| {
            input(format!(
                "excitation['{}']: expected a spec string or a one-dimensional float64 array of forces (N)",
                point.name
            ))
        })?;
    let values = samples
        .as_slice()
        .map_err(|e| input(format!("excitation['{}']: {e}", point.name)))?;
    if let Some(k) = values.iter().position(|v| !v.is_finite()) {
        return Err(input(format!(
            "excitation['{}']: sample {k} is {}, not a finite force",
            point.name, values[k]
        )));
    }
    Ok((
        Signal::Sampled {
            rate_hz,
            values: values.to_vec(),
        },
        format!("{} samples at {rate_hz} Hz", values.len()),
    ))
}

/// The integrators `simulate` takes, by their `nlsim simulate --method` names.
#[derive(Clone, Copy, PartialEq)]
enum Method {
    /// A hold of the exponential integrator (FOH, ZOH, LSOH).
    Hold(Hold),
    /// Adaptive Dormand–Prince 5(4) on the reduced model, dense output at the samples.
    Rk45,
    /// Classical fixed-step RK4 on the reduced model.
    Rk4,
    /// Newmark average acceleration with Newton on the unreduced model (`hht_alpha` 0).
    Newmark,
    /// Hilber–Hughes–Taylor α on the unreduced model.
    Hht,
}

impl Method {
    fn parse(name: &str) -> PyResult<Self> {
        Ok(match name {
            "foh" => Method::Hold(Hold::Foh),
            "zoh" => Method::Hold(Hold::Zoh),
            "lsoh" => Method::Hold(Hold::Lsoh),
            "rk45" => Method::Rk45,
            "rk4" => Method::Rk4,
            "newmark" => Method::Newmark,
            "hht" => Method::Hht,
            other => {
                return Err(input(format!(
                    "method: '{other}'; use 'foh', 'zoh', 'lsoh', 'rk45', 'rk4', 'newmark' or 'hht'"
                )));
            }
        })
    }

    /// Whether it integrates the unreduced model.
    fn unreduced(self) -> bool {
        matches!(self, Method::Newmark | Method::Hht)
    }
}

/// Simulates `model` (or a `Reduced`) for `duration` s at `rate_hz` samples per second, as
/// `nlsim simulate` does: by default with the exponential first-order hold on the reduced
/// model (thesis eq. 18–22; `method="zoh"` or `"lsoh"` for the other holds), or with a
/// reference integrator: `"rk45"` (adaptive, `rtol`, `atol` on the modal states in m √kg,
/// scaled to the response when `None`), `"rk4"` (`substeps` per sample) on the same reduced
/// model, `"newmark"` or `"hht"` (`hht_alpha` in [-1/3, 0]) on the unreduced model with
/// Newton at every step. `excitation` maps excitation-point names to a spec string or an
/// array of force samples (N) at `rate_hz`; points not named get a sine of their nominal
/// amplitude at the first natural frequency, as on the command line.
#[pyfunction]
#[pyo3(signature = (model, duration, rate_hz, excitation=None, method="foh", modes=20, residual_flexibility=true, locate_events=true, rtol=1e-3, atol=None, substeps=1, hht_alpha=-0.05, threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn simulate(
    py: Python<'_>,
    model: &Bound<'_, PyAny>,
    duration: f64,
    rate_hz: f64,
    excitation: Option<&Bound<'_, PyDict>>,
    method: &str,
    modes: usize,
    residual_flexibility: bool,
    locate_events: bool,
    rtol: f64,
    atol: Option<f64>,
    substeps: usize,
    hht_alpha: f64,
    threads: Option<usize>,
) -> PyResult<History> {
    let subject = Subject::of(model)?;
    if !(duration > 0.0 && duration.is_finite()) {
        return Err(input(format!(
            "duration: {duration}; give a positive number of seconds"
        )));
    }
    if !(rate_hz > 0.0 && rate_hz.is_finite()) {
        return Err(input(format!("rate_hz: {rate_hz}; give a positive rate")));
    }
    let n_steps = (duration * rate_hz).round();
    if !(1.0..=2e8).contains(&n_steps) {
        return Err(input(format!(
            "duration x rate_hz gives {n_steps} steps; it must be between 1 and 2e8"
        )));
    }
    let n_steps = n_steps as usize;
    let method = Method::parse(method)?;
    if modes == 0 {
        return Err(input("modes: 0; keep at least one mode"));
    }
    if !(rtol > 0.0 && rtol < 1.0) {
        return Err(input(format!(
            "rtol: {rtol}; give a relative tolerance in (0, 1)"
        )));
    }
    if let Some(a) = atol
        && !(a > 0.0 && a.is_finite())
    {
        return Err(input(format!(
            "atol: {a}; give a positive tolerance (m √kg)"
        )));
    }
    if !(1..=MAX_SUBSTEPS).contains(&substeps) {
        return Err(input(format!(
            "substeps: {substeps}; give 1 to {MAX_SUBSTEPS} integration steps per sample"
        )));
    }
    if !(-1.0 / 3.0..=0.0).contains(&hht_alpha) {
        return Err(input(format!(
            "hht_alpha: {hht_alpha}; give a value in [-1/3, 0]"
        )));
    }
    let points = subject.model().excitation().to_vec();
    let mut given: Vec<Option<(Signal, String)>> = vec![None; points.len()];
    if let Some(d) = excitation {
        for (k, v) in d.iter() {
            let name: String = k
                .extract()
                .map_err(|_| input("excitation: keys are excitation-point names (str)"))?;
            let i = points.iter().position(|p| p.name == name).ok_or_else(|| {
                input(format!(
                    "excitation: no excitation point '{name}' (the model has {})",
                    if points.is_empty() {
                        "none".to_string()
                    } else {
                        points
                            .iter()
                            .map(|p| p.name.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    }
                ))
            })?;
            given[i] = Some(drive(&points[i], &v, duration, rate_hz)?);
        }
    }
    let (hist, excitation, modes) = run(py, threads, move |stop| -> nlsim::Result<_> {
        // The unreduced integrators need the reduction only for the default drive's
        // frequency: one mode, as on the command line.
        let (reduced, m) = match method.unreduced() {
            true => subject.reduced(1, residual_flexibility, threads, stop)?,
            false => subject.reduced(modes, residual_flexibility, threads, stop)?,
        };
        // The command line's default drive: a sine at the first natural frequency (to 1 µHz).
        let f1: f64 = format!("{:.6}", reduced.modes.frequencies_hz()[0])
            .parse()
            .unwrap_or(0.0);
        let (signals, labels): (Vec<Signal>, Vec<String>) = points
            .iter()
            .zip(given)
            .map(|(p, g)| {
                g.unwrap_or_else(|| (Signal::sine(p.amplitude, f1), format!("sine:freq={f1:.6}")))
            })
            .unzip();
        let case = LoadCase::new("simulate", signals);
        let dt = 1.0 / rate_hz;
        let mut progress = |_: usize, _: usize| stop.check();
        if method.unreduced() {
            let mut cfg = NewmarkConfig::new(dt);
            cfg.substeps = substeps;
            cfg.alpha = if method == Method::Hht {
                hht_alpha
            } else {
                0.0
            };
            let nm = Newmark::new(&m, &cfg)?;
            let h = nm.run_with_progress(&case, n_steps, &mut progress)?;
            return Ok((h, labels, 0));
        }
        let system = ModalSystem::new(&reduced)?;
        let plant = Plant::from_model(&m, &system)?;
        let h = match method {
            Method::Hold(hold) => {
                let mut cfg = FohConfig::new(dt);
                cfg.hold = hold;
                cfg.locate_events = locate_events;
                Simulator::new(&plant, &cfg)?.run_with_progress(&case, n_steps, &mut progress)?
            }
            Method::Rk45 => {
                let a = atol.unwrap_or_else(|| {
                    nlsim::sim::auto_atol(&plant, &case.forces, dt, n_steps, rtol)
                });
                nlsim::sim::rk45_with_progress(
                    &plant,
                    &case,
                    dt,
                    n_steps,
                    &Rk45Config {
                        rtol,
                        atol: a,
                        ..Default::default()
                    },
                    &mut progress,
                )?
            }
            _ => nlsim::sim::rk4_with_progress(
                &plant,
                &case,
                dt,
                n_steps,
                &Rk4Config {
                    substeps,
                    ..Default::default()
                },
                &mut progress,
            )?,
        };
        Ok((h, labels, reduced.modes.len()))
    })?
    .map_err(py_err)?;
    Ok(History {
        h: hist,
        excitation,
        modes,
    })
}
