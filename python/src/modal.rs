//! `nlsim.calibrate_modal`: FE-level parameters (group stiffness and mass scales, boundary
//! springs) from measured natural frequencies and mode shapes (the linear stage, thesis §4.5),
//! as `nlsim calibrate MODEL MODES.csv` does it: maximin Latin-hypercube candidates, bounded
//! Levenberg–Marquardt with the modes and their sensitivities from the parametric reduced
//! model (or full eigen solves), modes paired by MAC, the Cramér–Rao bound at the estimate.

use crate::calibration::{
    PartialCalibration, fe_reduction, fe_stats_dict, finished_or_raise, param_specs, resumed_costs,
    search_config,
};
use crate::model::Model;
use crate::runs::{Stop, run_keeping, vec1};
use crate::{input, py_err};
use nlsim::calib::{CalibrationConfig, MeasuredMode, ModalData, ModalObjective};
use numpy::{PyArray1, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::path::PathBuf;
use std::sync::Arc;

/// A modal calibration's result (`nlsim.calibrate_modal`).
#[pyclass(module = "nlsim._native", name = "ModalCalibration", frozen)]
pub struct ModalCalibration {
    c: nlsim::calib::ModalCalibration,
    fe: nlsim::calib::FeReductionStats,
}

crate::calibration::calibration_result!(ModalCalibration, "ModalCalibration", {
    /// What the evaluations of the modes did: a dict of `fe_reduction` (`"parametric"` or
    /// `"full"`), `basis_size`, `setup_reductions`, `evaluations`, `refreshes`,
    /// `full_reductions` (full eigen solves) and `full_seconds`.
    #[getter]
    fn fe_stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        Ok(fe_stats_dict(py, Some(&self.fe))?.expect("given"))
    }

    /// The computed mode (0-based) paired with each measured mode.
    #[getter]
    fn pairing(&self) -> Vec<usize> {
        self.c.fit.pairing.clone()
    }

    /// The paired computed natural frequencies at the estimate (Hz), one per measured mode.
    #[getter]
    fn frequency_hz<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.c.fit.frequencies_hz.clone())
    }

    /// MAC of each measured shape with its paired computed one (NaN where no shape was
    /// measured).
    #[getter]
    fn mac<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.c.fit.mac.clone())
    }
});

/// Measured modes from a dict of arrays: `frequency_hz` (modes,), `frequency_std_hz`
/// (modes,), optionally `dofs` (labels of the measured DOFs) with `shapes` (dofs, modes).
fn modal_arrays(model: &Model, d: &Bound<'_, PyDict>, shape_noise: f64) -> PyResult<ModalData> {
    for key in d.keys() {
        let k: String = key.extract().map_err(|_| input("data: keys are str"))?;
        if !["frequency_hz", "frequency_std_hz", "dofs", "shapes"].contains(&k.as_str()) {
            return Err(input(format!(
                "data: unknown key '{k}' (known: frequency_hz, frequency_std_hz, dofs, shapes)"
            )));
        }
    }
    let vector = |k: &str| -> PyResult<Vec<f64>> {
        let v = d
            .get_item(k)?
            .ok_or_else(|| input(format!("data: no '{k}'")))?;
        let a: PyReadonlyArray1<'_, f64> = v.extract().map_err(|_| {
            input(format!(
                "data['{k}']: expected a one-dimensional float64 array"
            ))
        })?;
        Ok(a.as_array().to_vec())
    };
    let freq = vector("frequency_hz")?;
    let std = vector("frequency_std_hz")?;
    if std.len() != freq.len() {
        return Err(input(format!(
            "data['frequency_std_hz']: {} values for {} frequencies",
            std.len(),
            freq.len()
        )));
    }
    let (dofs, shapes) = match (d.get_item("dofs")?, d.get_item("shapes")?) {
        (None, None) => (Vec::new(), None),
        (Some(labels), Some(shapes)) => {
            let labels: Vec<String> = labels
                .extract()
                .map_err(|_| input("data['dofs']: expected a list of DOF labels (str)"))?;
            let mut dofs = Vec::with_capacity(labels.len());
            for (i, l) in labels.iter().enumerate() {
                let k = model
                    .inner
                    .dofs()
                    .find(l)
                    .map_err(|e| input(format!("data['dofs'][{i}]: '{l}': {e}")))?;
                if dofs.contains(&k) {
                    return Err(input(format!("data['dofs'][{i}]: '{l}' is listed twice")));
                }
                dofs.push(k);
            }
            let a: PyReadonlyArray2<'_, f64> = shapes
                .extract()
                .map_err(|_| input("data['shapes']: expected a two-dimensional float64 array"))?;
            let a = a.as_array();
            if a.shape() != [dofs.len(), freq.len()] {
                return Err(input(format!(
                    "data['shapes']: shape ({}, {}); expected (dofs, modes) = ({}, {})",
                    a.shape()[0],
                    a.shape()[1],
                    dofs.len(),
                    freq.len()
                )));
            }
            let cols = (0..freq.len())
                .map(|m| (0..dofs.len()).map(|r| a[[r, m]]).collect())
                .collect::<Vec<Vec<f64>>>();
            (dofs, Some(cols))
        }
        _ => return Err(input("data: give 'dofs' and 'shapes' together, or neither")),
    };
    let mut modes = Vec::with_capacity(freq.len());
    let mut shapes = shapes.map(Vec::into_iter);
    for (i, (&f, &s)) in freq.iter().zip(&std).enumerate() {
        let mode = MeasuredMode {
            frequency_hz: f,
            frequency_std_hz: s,
            shape: shapes.as_mut().and_then(Iterator::next),
        };
        if let Some(why) = mode.fault() {
            return Err(input(format!("data: mode {}: {why}", i + 1)));
        }
        modes.push(mode);
    }
    Ok(ModalData {
        dofs,
        shape_std: shape_noise,
        modes,
    })
}

/// Calibrates FE-level parameters of `model` on measured modes. `data`: a modal CSV (the
/// file `nlsim calibrate` reads: `mode,frequency_hz,frequency_std_hz,DOF…`) or a dict of
/// arrays `frequency_hz` (modes,), `frequency_std_hz` (modes,) and optionally `dofs` (labels)
/// with `shapes` (dofs, modes; any scale and sign). `params` maps FE-level parameters
/// (`group:NAME.k_scale`, `group:NAME.m_scale`, `spring:…`) to their bounds; `shape_noise`
/// is the standard deviation of one component of a unit-normalised measured shape; `modes`
/// the computed modes the MAC pairing chooses from (at least the measured ones);
/// `fe_reduction` `"parametric"` (the parametric reduced model, certified to `fe_tolerance`,
/// default 1e-6) or `"full"` (a full eigen solve per evaluation). The other arguments are
/// `nlsim calibrate`'s, with its defaults. Ctrl-C raises `KeyboardInterrupt` carrying what
/// was complete (`err.args[1]`); `resume=` that value with the same arguments goes on to the
/// estimates of an uninterrupted call, bit for bit.
#[pyfunction]
#[pyo3(signature = (model, data, params, shape_noise=0.02, modes=20, lhs=64, seed=1, starts=3, fe_reduction="parametric", fe_tolerance=None, threads=None, resume=None))]
#[allow(clippy::too_many_arguments)]
pub fn calibrate_modal(
    py: Python<'_>,
    model: &Model,
    data: &Bound<'_, PyAny>,
    params: &Bound<'_, PyDict>,
    shape_noise: f64,
    modes: usize,
    lhs: usize,
    seed: u64,
    starts: usize,
    fe_reduction: &str,
    fe_tolerance: Option<f64>,
    threads: Option<usize>,
    resume: Option<&PartialCalibration>,
) -> PyResult<ModalCalibration> {
    let fe = self::fe_reduction(fe_reduction, fe_tolerance)?;
    let resumed = resume.map(PartialCalibration::kept);
    if !(shape_noise > 0.0 && shape_noise.is_finite()) {
        return Err(input(format!(
            "shape_noise: {shape_noise}; give a positive standard deviation"
        )));
    }
    let specs = param_specs(model, params)?;
    let measured = if let Ok(d) = data.cast::<PyDict>() {
        modal_arrays(model, d, shape_noise)?
    } else {
        let path: PathBuf = data
            .extract()
            .map_err(|_| input("data: expected the path of a modal CSV or a dict of arrays"))?;
        nlsim::formats::modal_data::read_modal_csv(&path, &model.inner, shape_noise)
            .map_err(py_err)?
            .data
    };
    let n = model.inner.n_dofs();
    if measured.modes.len() > n {
        return Err(input(format!(
            "data: {} measured modes, but the model has {n} DOFs",
            measured.modes.len()
        )));
    }
    let modes = modes.clamp(measured.modes.len(), n);
    // Folds do not apply to a handful of modes: the default's are not used.
    let config = search_config(lhs, seed, starts, CalibrationConfig::default().folds)?;
    let m = model.inner.clone();
    let job = move |stop: &Stop| -> nlsim::Result<_> {
        let objective = ModalObjective::with_reduction(
            m,
            Arc::new(measured),
            specs,
            modes,
            faer::Par::Seq,
            &fe,
        )?;
        let points = objective.candidate_points(&config)?;
        let known = resumed_costs(resumed.as_deref(), &points)?;
        let outcome =
            nlsim::calib::calibrate_modal_until(&objective, &config, &known, &|_| {}, &|| {
                stop.requested()
            })?;
        Ok((outcome, objective.fe_stats()))
    };
    let (c, fe) = finished_or_raise(py, run_keeping(py, threads, job)?)?;
    Ok(ModalCalibration { c, fe })
}
