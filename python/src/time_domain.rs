//! `nlsim.calibrate_time`: element law parameters from raw time records (a force and the
//! sensors' responses from rest), as `nlsim calibrate MODEL RECORDS --time-domain` does it:
//! first-order-hold simulations driven by the recorded force, the Jacobian from the forward
//! sensitivities of the hold, Latin-hypercube candidates, Levenberg–Marquardt over growing
//! horizons, the Cramér–Rao bound and k-fold cross validation over contiguous blocks.

use crate::calibration::{
    PartialCalibration, finished_or_raise, param_specs, resumed_costs, search_config,
};
use crate::model::Model;
use crate::runs::{Stop, run_keeping, vec1};
use crate::{input, py_err};
use nlsim::calib::{TimeChannel, TimeObjective, TimeRecords};
use numpy::{PyArray1, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;

/// A time-domain calibration's result (`nlsim.calibrate_time`).
#[pyclass(module = "nlsim._native", name = "TimeCalibration", frozen)]
pub struct TimeCalibration {
    c: nlsim::calib::TimeCalibration,
    channels: Vec<String>,
}

crate::calibration::calibration_result!(TimeCalibration, "TimeCalibration", {
    /// Whether each parameter is poorly identified.
    #[getter]
    fn poorly_identified(&self) -> Vec<bool> {
        self.c.poorly_identified.clone()
    }

    /// Mean, standard deviation and jackknife spread of the fold estimates (each shape
    /// `(param,)`), or `None` without cross validation.
    #[getter]
    #[allow(clippy::type_complexity)]
    fn kfold<'py>(
        &self,
        py: Python<'py>,
    ) -> Option<(
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<f64>>,
    )> {
        self.c.kfold.as_ref().map(|k| {
            (
                vec1(py, k.mean.clone()),
                vec1(py, k.std.clone()),
                vec1(py, k.jackknife_std.clone()),
            )
        })
    }

    /// The calibrated model's response at every sample, per channel: `{name: (sample,)}`.
    #[getter]
    fn simulated<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for (name, y) in self.channels.iter().zip(&self.c.fit.simulated) {
            d.set_item(name, vec1(py, y.clone()))?;
        }
        Ok(d)
    }
});

/// Calibrates element law parameters of `model` on a raw time record: `force` (N, shape
/// `(sample,)`) at the excitation `drive` (default: the model's first), `responses` a dict
/// `{sensor name: (sample,)}` of the model's sensors' measured responses, all sampled at
/// `rate_hz` from rest. Each channel's noise standard deviation is `data_noise` times its
/// rms. `params` maps element parameters (`"stop.k1"`) to their bounds; `modes` retained
/// (with residual flexibility); `lhs`, `seed`, `starts`, `folds` (contiguous blocks of samples)
/// as `nlsim calibrate`. Ctrl-C raises `KeyboardInterrupt` carrying what was complete
/// (`err.args[1]`); `resume=` that value with the same arguments goes on to the estimates of
/// an uninterrupted call, bit for bit.
#[pyfunction]
#[pyo3(signature = (model, force, responses, rate_hz, params, drive=None, data_noise=0.01, modes=20, lhs=64, seed=1, starts=3, folds=10, threads=None, resume=None))]
#[allow(clippy::too_many_arguments)]
pub fn calibrate_time(
    py: Python<'_>,
    model: &Model,
    force: PyReadonlyArray1<'_, f64>,
    responses: &Bound<'_, PyDict>,
    rate_hz: f64,
    params: &Bound<'_, PyDict>,
    drive: Option<String>,
    data_noise: f64,
    modes: usize,
    lhs: usize,
    seed: u64,
    starts: usize,
    folds: usize,
    threads: Option<usize>,
    resume: Option<&PartialCalibration>,
) -> PyResult<TimeCalibration> {
    let resumed = resume.map(PartialCalibration::kept);
    if !(data_noise > 0.0 && data_noise.is_finite()) {
        return Err(input(format!(
            "data_noise: {data_noise}; give a positive fraction of each channel's rms"
        )));
    }
    if modes == 0 {
        return Err(input("modes: 0; keep at least one mode"));
    }
    let specs = param_specs(model, params)?;
    let drive = match drive {
        Some(d) => d,
        None => model
            .inner
            .excitation()
            .first()
            .map(|e| e.name.clone())
            .ok_or_else(|| input("drive: the model has no excitation to drive"))?,
    };
    let force = force
        .as_slice()
        .map_err(|e| input(format!("force: {e}")))?
        .to_vec();
    let mut channels = Vec::new();
    for (k, v) in responses.iter() {
        let name: String = k
            .extract()
            .map_err(|_| input("responses: keys are sensor names (str)"))?;
        let values = v
            .extract::<PyReadonlyArray1<'_, f64>>()
            .map_err(|_| {
                input(format!(
                    "responses['{name}']: expected a one-dimensional float64 array"
                ))
            })?
            .as_slice()
            .map_err(|e| input(format!("responses['{name}']: {e}")))?
            .to_vec();
        let rms = (values.iter().map(|v| v * v).sum::<f64>() / values.len().max(1) as f64).sqrt();
        if !(rms > 0.0 && rms.is_finite()) {
            return Err(input(format!(
                "responses['{name}']: zero or not finite throughout; no noise level to scale"
            )));
        }
        channels.push(TimeChannel {
            name,
            values,
            sigma: data_noise * rms,
        });
    }
    let names: Vec<String> = channels.iter().map(|c| c.name.clone()).collect();
    let records = Arc::new(TimeRecords {
        rate_hz,
        input: drive,
        force,
        channels,
    });
    records
        .validate()
        .map_err(|e| py_err(nlsim::Error::from(e)))?;
    let config = search_config(lhs, seed, starts, folds)?;
    let m = model.inner.clone();
    let job = move |stop: &Stop| -> nlsim::Result<_> {
        let reduction = nlsim::reduction::ReductionConfig::lowest(modes.min(m.n_dofs()));
        let objective = TimeObjective::new(&m, &reduction, records, specs)?;
        let points = objective.candidate_points(&config)?;
        let known = resumed_costs(resumed.as_deref(), &points)?;
        let outcome =
            nlsim::calib::calibrate_time_until(&objective, &config, &known, &|_| {}, &|| {
                stop.requested()
            })?;
        Ok((outcome, ()))
    };
    let (c, ()) = finished_or_raise(py, run_keeping(py, threads, job)?)?;
    Ok(TimeCalibration { c, channels: names })
}
