//! The computations: modes, the reduction, FOH time histories and harmonic-balance FRFs, each
//! with the settings of the matching `nlsim` command (`modes`, `simulate`, `frf`) so that the
//! results are the command's to the last bit. Every run happens on a worker thread inside a
//! rayon pool of `threads` threads while the calling thread waits without the GIL and checks
//! for Ctrl-C ten times a second.

use crate::model::Model;
use crate::{ComputationError, input, py_err};
use faer::c64;
use nlsim::hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, PointKind};
use nlsim::reduction::{EigenConfig, ModalSystem, ModeSelection, ReducedModel, ReductionConfig};
use nlsim::sim::{FohConfig, Hold, LoadCase, Plant, Signal, Simulator};
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering as AtomicOrdering};
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

/// Most worker threads `threads=` accepts (as `nlsim --threads`).
const MAX_THREADS: usize = 1024;

/// Stack of the worker thread (the CLI's main thread has 8 MiB; deep recursion in the
/// ordering of large factors needs it).
const WORKER_STACK: usize = 64 << 20;

/// The parallelism of `threads`: sequential for 1, the run's rayon pool otherwise (as the
/// command line's `--threads`).
fn par(threads: Option<usize>) -> faer::Par {
    match threads {
        Some(1) => faer::Par::Seq,
        _ => faer::Par::rayon(0),
    }
}

/// The payload a run unwinds with when Ctrl-C stops it (never shown: caught by [`run`]).
struct Interrupted;

/// The stop flag of a run: set when Python has a pending signal (Ctrl-C), checked by the
/// run's progress callbacks (every eigensolver restart, continuation point and about 200
/// times per time history), which then unwind out of the computation. Everything the run
/// allocated is dropped on the way; nothing reaches Python.
#[derive(Clone, Default)]
pub(crate) struct Stop(Arc<AtomicBool>);

impl Stop {
    /// Unwinds out of the run when it was asked to stop.
    pub(crate) fn check(&self) {
        if self.0.load(AtomicOrdering::Relaxed) {
            std::panic::resume_unwind(Box::new(Interrupted));
        }
    }
}

/// Runs `job` on a worker thread in a rayon pool of `threads` threads (default: one per
/// core), waiting without the GIL. At Ctrl-C (any pending Python signal) the run is told to
/// stop at its next progress check and waited for, then `KeyboardInterrupt` is raised; a
/// second Ctrl-C while it winds down stops the wait and leaves the worker to end alone.
pub(crate) fn run<T: Send + 'static>(
    py: Python<'_>,
    threads: Option<usize>,
    job: impl FnOnce(&Stop) -> T + Send + 'static,
) -> PyResult<T> {
    if let Some(n) = threads
        && !(1..=MAX_THREADS).contains(&n)
    {
        return Err(input(format!(
            "threads: {n}; give 1 to {MAX_THREADS} (more threads than cores only slow a run down)"
        )));
    }
    let mut builder = rayon::ThreadPoolBuilder::new();
    if let Some(n) = threads {
        builder = builder.num_threads(n);
    }
    let pool = builder
        .build()
        .map_err(|e| ComputationError::new_err(format!("thread pool: {e}")))?;
    let stop = Stop::default();
    let (tx, rx) = std::sync::mpsc::channel();
    // A receiver is not `Sync`; the waits without the GIL borrow it through a lock.
    let rx = std::sync::Mutex::new(rx);
    let worker_stop = stop.clone();
    std::thread::Builder::new()
        .name("nlsim".into())
        .stack_size(WORKER_STACK)
        .spawn(move || {
            let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                pool.install(|| job(&worker_stop))
            }));
            let _ = tx.send(r);
        })
        .map_err(|e| ComputationError::new_err(format!("worker thread: {e}")))?;
    let wait = || {
        py.detach(|| {
            rx.lock()
                .unwrap_or_else(|p| p.into_inner())
                .recv_timeout(Duration::from_millis(100))
        })
    };
    loop {
        match wait() {
            Ok(Ok(r)) => return Ok(r),
            Ok(Err(payload)) => {
                let what = payload
                    .downcast_ref::<&str>()
                    .map(|s| s.to_string())
                    .or_else(|| payload.downcast_ref::<String>().cloned())
                    .unwrap_or_else(|| "no message".into());
                return Err(ComputationError::new_err(format!(
                    "internal error ({what}); please report it with the model and the call"
                )));
            }
            Err(RecvTimeoutError::Timeout) => {
                if let Err(interrupt) = py.check_signals() {
                    stop.0.store(true, AtomicOrdering::Relaxed);
                    while matches!(wait(), Err(RecvTimeoutError::Timeout)) {
                        if py.check_signals().is_err() {
                            break;
                        }
                    }
                    return Err(interrupt);
                }
            }
            Err(RecvTimeoutError::Disconnected) => {
                return Err(ComputationError::new_err(
                    "the computation ended without a result (an internal error; please report \
                     it with the model)",
                ));
            }
        }
    }
}

fn eigen_config(selection: ModeSelection, threads: Option<usize>) -> EigenConfig {
    EigenConfig {
        selection,
        par: par(threads),
        // As the command line's default `--memory-budget`.
        memory_budget: nlsim::formats::files::default_memory_budget(),
        ..EigenConfig::default()
    }
}

fn vec1<'py>(py: Python<'py>, v: Vec<f64>) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_vec(py, v)
}

fn mat2<'py>(py: Python<'py>, m: &faer::Mat<f64>) -> Bound<'py, PyArray2<f64>> {
    Array2::from_shape_fn((m.nrows(), m.ncols()), |(i, j)| m[(i, j)]).into_pyarray(py)
}

// -----------------------------------------------------------------------------------------
// Modes and the reduction.

/// Modes of a model (`nlsim.modes`): what `nlsim modes` computes.
#[pyclass(module = "nlsim._native", name = "Modes", frozen)]
pub struct Modes {
    report: nlsim::formats::modes_file::ModeReport,
    dofs: Vec<String>,
}

#[pymethods]
impl Modes {
    /// Natural frequencies (Hz), ascending, shape `(n_modes,)`.
    #[getter]
    fn frequency_hz<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.report.modes.frequencies_hz())
    }

    /// Eigenvalues `ω²` (rad²/s²), shape `(n_modes,)`.
    #[getter]
    fn eigenvalues<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.report.modes.eigenvalues.clone())
    }

    /// Damping ratio of each mode under the model's damping, shape `(n_modes,)`.
    #[getter]
    fn damping_ratio<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.report.damping.clone())
    }

    /// Mass-normalised mode shapes (1/√kg), shape `(n_dofs, n_modes)`: column `r` is mode
    /// `r`, rows in the order of `dofs`.
    #[getter]
    fn shapes<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat2(py, &self.report.modes.vectors)
    }

    /// Relative residual `‖K φ − λ M φ‖ / ‖K φ‖` of each mode, shape `(n_modes,)`.
    #[getter]
    fn residual<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.report.modes.residuals.clone())
    }

    /// Effective masses (kg) per translational direction: `{"ux": array (n_modes,), …}`.
    #[getter]
    fn effective_mass<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for e in &self.report.effective {
            d.set_item(e.component.to_string(), vec1(py, e.per_mode.clone()))?;
        }
        Ok(d)
    }

    /// DOF labels of the shapes' rows.
    #[getter]
    fn dofs(&self) -> Vec<String> {
        self.dofs.clone()
    }

    fn __len__(&self) -> usize {
        self.report.modes.len()
    }

    fn __repr__(&self) -> String {
        let f = self.report.modes.frequencies_hz();
        format!(
            "<nlsim.Modes: {} mode(s), {:.6} to {:.6} Hz>",
            f.len(),
            f.first().copied().unwrap_or(f64::NAN),
            f.last().copied().unwrap_or(f64::NAN)
        )
    }
}

/// The lowest modes of `model` as `nlsim modes` computes them: `count` modes (default 10, or
/// every mode of a smaller model) or every mode below `fmax_hz`; shift-invert Lanczos with a
/// Sturm check (thesis eq. 8–10), the dense solver below 200 DOFs.
#[pyfunction]
#[pyo3(signature = (model, count=None, fmax_hz=None, threads=None))]
pub fn modes(
    py: Python<'_>,
    model: &Model,
    count: Option<usize>,
    fmax_hz: Option<f64>,
    threads: Option<usize>,
) -> PyResult<Modes> {
    let m = model.inner.clone();
    let selection = match (count, fmax_hz) {
        (_, Some(f)) if !(f > 0.0 && f.is_finite()) => {
            return Err(input(format!("fmax_hz: {f}; give a positive frequency")));
        }
        (_, Some(f)) => ModeSelection::Below { f_max_hz: f },
        (Some(0), None) => return Err(input("count: 0; ask for at least one mode")),
        (Some(c), None) => ModeSelection::Lowest(c),
        (None, None) => ModeSelection::Lowest(10.min(m.n_dofs())),
    };
    let cfg = eigen_config(selection, threads);
    let dofs = model.dofs_text();
    let report = run(py, threads, move |stop| -> nlsim::Result<_> {
        m.validate(&nlsim::kernel::ValidationConfig {
            check_definiteness: false,
            ..Default::default()
        })?;
        let modes = nlsim::reduction::EigenSolver::new()
            .solve_with_progress(m.stiffness(), m.mass(), &cfg, &mut |_| stop.check())
            .and_then(nlsim::reduction::Modes::into_converged)?;
        Ok(nlsim::formats::modes_file::ModeReport::new(&m, modes, cfg))
    })?
    .map_err(py_err)?;
    Ok(Modes { report, dofs })
}

/// A reduced model (`nlsim.reduce`): the retained modes with residual flexibility at the
/// ports (thesis eq. 8–11), and the model it was made from. `simulate` and `frf` take it in
/// place of a model to skip the reduction.
#[pyclass(module = "nlsim._native", name = "Reduced", frozen)]
pub struct Reduced {
    pub(crate) reduced: Arc<ReducedModel>,
    pub(crate) model: nlsim::kernel::Model,
    pub(crate) residual: bool,
}

#[pymethods]
impl Reduced {
    /// Natural frequencies (Hz) of the retained modes, shape `(n_modes,)`.
    #[getter]
    fn frequency_hz<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(py, self.reduced.modes.frequencies_hz())
    }

    /// Mass-normalised shapes of the retained modes, shape `(n_dofs, n_modes)`.
    #[getter]
    fn shapes<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        mat2(py, &self.reduced.modes.vectors)
    }

    /// Number of retained modes.
    #[getter]
    fn n_modes(&self) -> usize {
        self.reduced.modes.len()
    }

    /// Whether the residual flexibility of the truncated modes is kept.
    #[getter]
    fn residual_flexibility(&self) -> bool {
        self.residual
    }

    /// The model as it was when reduced (a copy).
    #[getter]
    fn model(&self) -> Model {
        Model {
            inner: self.model.clone(),
            source: "reduced".into(),
        }
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.Reduced '{}': {} mode(s){}>",
            self.model.name(),
            self.reduced.modes.len(),
            if self.residual {
                " with residual flexibility"
            } else {
                ""
            }
        )
    }
}

/// The reduction `simulate` and `frf` use (`nlsim simulate`/`frf`'s `--modes`, residual
/// flexibility unless `--no-residual`).
fn reduce_model(
    m: &nlsim::kernel::Model,
    modes: usize,
    residual: bool,
    threads: Option<usize>,
    stop: &Stop,
) -> nlsim::Result<ReducedModel> {
    Ok(nlsim::reduction::reduce_with(
        m,
        &ReductionConfig {
            eigen: eigen_config(ModeSelection::Lowest(modes.min(m.n_dofs())), threads),
            residual_flexibility: residual,
            ..Default::default()
        },
        &mut nlsim::reduction::EigenSolver::new(),
        &mut |_| stop.check(),
    )?)
}

/// Reduces `model` to its `modes` lowest modes, with the residual flexibility of the others
/// at the element, excitation and sensor DOFs unless `residual_flexibility` is false.
#[pyfunction]
#[pyo3(signature = (model, modes=20, residual_flexibility=true, threads=None))]
pub fn reduce(
    py: Python<'_>,
    model: &Model,
    modes: usize,
    residual_flexibility: bool,
    threads: Option<usize>,
) -> PyResult<Reduced> {
    if modes == 0 {
        return Err(input("modes: 0; keep at least one mode"));
    }
    let m = model.inner.clone();
    let (reduced, m) = run(py, threads, move |stop| {
        let r = reduce_model(&m, modes, residual_flexibility, threads, stop);
        (r, m)
    })?;
    Ok(Reduced {
        reduced: Arc::new(reduced.map_err(py_err)?),
        model: m,
        residual: residual_flexibility,
    })
}

/// A model or a reduced model as given to `simulate` or `frf`: the reduction to use (made
/// here, on the worker, when a model is given).
enum Subject {
    Model(nlsim::kernel::Model),
    Reduced(Arc<ReducedModel>, nlsim::kernel::Model),
}

impl Subject {
    fn of(obj: &Bound<'_, PyAny>) -> PyResult<Subject> {
        if let Ok(r) = obj.cast::<Reduced>() {
            let r = r.get();
            return Ok(Subject::Reduced(r.reduced.clone(), r.model.clone()));
        }
        if let Ok(m) = obj.extract::<PyRef<'_, Model>>() {
            return Ok(Subject::Model(m.inner.clone()));
        }
        Err(input(format!(
            "model: expected an nlsim.Model or nlsim.Reduced, got {}",
            obj.get_type()
                .name()
                .map_or_else(|_| "another type".into(), |n| n.to_string())
        )))
    }

    fn model(&self) -> &nlsim::kernel::Model {
        match self {
            Subject::Model(m) | Subject::Reduced(_, m) => m,
        }
    }

    fn reduced(
        self,
        modes: usize,
        residual: bool,
        threads: Option<usize>,
        stop: &Stop,
    ) -> nlsim::Result<(Arc<ReducedModel>, nlsim::kernel::Model)> {
        match self {
            Subject::Reduced(r, m) => Ok((r, m)),
            Subject::Model(m) => Ok((
                Arc::new(reduce_model(&m, modes, residual, threads, stop)?),
                m,
            )),
        }
    }
}

// -----------------------------------------------------------------------------------------
// Time simulation.

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

/// Simulates `model` (or a `Reduced`) for `duration` s at `rate_hz` samples per second with
/// the exponential first-order hold (thesis eq. 18–22; `method="zoh"` or `"lsoh"` for the
/// other holds), as `nlsim simulate` does. `excitation` maps excitation-point names to a spec
/// string or an array of force samples (N) at `rate_hz`; points not named get a sine of
/// their nominal amplitude at the first natural frequency, as on the command line.
#[pyfunction]
#[pyo3(signature = (model, duration, rate_hz, excitation=None, method="foh", modes=20, residual_flexibility=true, locate_events=true, threads=None))]
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
    let hold = match method {
        "foh" => Hold::Foh,
        "zoh" => Hold::Zoh,
        "lsoh" => Hold::Lsoh,
        other => {
            return Err(input(format!(
                "method: '{other}'; use 'foh', 'zoh' or 'lsoh'"
            )));
        }
    };
    if modes == 0 {
        return Err(input("modes: 0; keep at least one mode"));
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
        let (reduced, m) = subject.reduced(modes, residual_flexibility, threads, stop)?;
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
        let system = ModalSystem::new(&reduced)?;
        let plant = Plant::from_model(&m, &system)?;
        let mut cfg = FohConfig::new(1.0 / rate_hz);
        cfg.hold = hold;
        cfg.locate_events = locate_events;
        let sim = Simulator::new(&plant, &cfg)?;
        let h =
            sim.run_with_progress(&LoadCase::new("simulate", signals), n_steps, &mut |_, _| {
                stop.check()
            })?;
        Ok((h, labels, reduced.modes.len()))
    })?
    .map_err(py_err)?;
    Ok(History {
        h: hist,
        excitation,
        modes,
    })
}

// -----------------------------------------------------------------------------------------
// Harmonic balance.

/// A frequency response by harmonic balance (`nlsim.frf`), points first, in order along the
/// branch (the frequency turns back at folds).
#[pyclass(module = "nlsim._native", name = "Frf", frozen)]
pub struct Frf {
    system: HbSystem,
    report: nlsim::hb::ContinuationReport,
    y: Vec<faer::Mat<c64>>,
}

#[pymethods]
impl Frf {
    /// Frequency of each point (Hz), shape `(n_points,)`.
    #[getter]
    fn frequency_hz<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.report
                .branch
                .points
                .iter()
                .map(|p| p.omega / (2.0 * std::f64::consts::PI))
                .collect(),
        )
    }

    /// Force level of each point (the excitation's nominal amplitudes times this), shape
    /// `(n_points,)`.
    #[getter]
    fn level<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        vec1(
            py,
            self.report.branch.points.iter().map(|p| p.scale).collect(),
        )
    }

    /// Complex harmonic amplitudes of each sensor in its quantity (m, m/s or m/s²), shape
    /// `(n_points, n_sensors, n_harmonics)`; harmonic `k` is `harmonics[k]` times the
    /// fundamental, in the cosine convention `y(t) = Re Σ Y_k e^{i k Ω t}`.
    #[getter]
    fn response<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray3<c64>> {
        let n = self.y.len();
        let (s, h) = self.y.first().map_or((0, 0), |m| (m.nrows(), m.ncols()));
        Array3::from_shape_fn((n, s, h), |(p, i, k)| self.y[p][(i, k)]).into_pyarray(py)
    }

    /// Harmonic numbers of `response`'s last axis as multiples of the fundamental.
    #[getter]
    fn harmonics<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let set = self.system.harmonics();
        vec1(py, (0..=set.h).map(|k| k as f64 / set.nu as f64).collect())
    }

    /// Stability of each point by Hill's method: 1 stable, 0 unstable, -1 not computed;
    /// shape `(n_points,)`.
    #[getter]
    fn stable<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<i8>> {
        PyArray1::from_vec(
            py,
            self.report
                .branch
                .points
                .iter()
                .map(|p| match p.stable() {
                    Some(true) => 1,
                    Some(false) => 0,
                    None => -1,
                })
                .collect(),
        )
    }

    /// Kind of each point: `"regular"`, `"fold"`, `"end"` or `"jump"`.
    #[getter]
    fn kind(&self) -> Vec<&'static str> {
        self.report
            .branch
            .points
            .iter()
            .map(|p| match p.kind {
                PointKind::Regular => "regular",
                PointKind::Fold => "fold",
                PointKind::End => "end",
                PointKind::Jump => "jump",
            })
            .collect()
    }

    /// Indices of the fold points (turning points of the frequency).
    #[getter]
    fn folds(&self) -> Vec<usize> {
        self.report.branch.folds()
    }

    /// Bifurcations found from the stability changes: `(kind, frequency in Hz, index of the
    /// point before, index after)` with kind `"fold"`, `"branch point"`, `"period
    /// doubling"` or `"Neimark–Sacker"`.
    #[getter]
    fn bifurcations(&self) -> Vec<(&'static str, f64, usize, usize)> {
        self.report
            .branch
            .bifurcations
            .iter()
            .map(|b| {
                (
                    b.kind.as_str(),
                    b.omega / (2.0 * std::f64::consts::PI),
                    b.between.0,
                    b.between.1,
                )
            })
            .collect()
    }

    /// Sensor names, in the order of `response`'s second axis.
    #[getter]
    fn sensors(&self) -> Vec<String> {
        self.system
            .sensors()
            .iter()
            .map(|s| s.name.clone())
            .collect()
    }

    /// `"converged"` when the whole range was followed; otherwise why it stopped (the
    /// points found are kept).
    #[getter]
    fn status(&self) -> &'static str {
        self.report.status.as_str()
    }

    /// What the continuation reported when it stopped short (empty when complete).
    #[getter]
    fn detail(&self) -> String {
        self.report.detail.clone()
    }

    fn __len__(&self) -> usize {
        self.report.branch.points.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.Frf: {} point(s), {} fold(s), {}>",
            self.report.branch.points.len(),
            self.report.branch.folds().len(),
            self.report.status.as_str()
        )
    }
}

/// The frequency response of `model` (or a `Reduced`) from `from_hz` to `to_hz` (either
/// order) by harmonic balance with `harmonics` harmonics (thesis eq. 13–17) and
/// pseudo-arclength continuation through folds (thesis §3.3), with Hill stability unless
/// `stability` is false — `nlsim frf MODEL --from … --to …` with the same defaults. `level`
/// scales the excitation's nominal amplitudes.
#[pyfunction]
#[pyo3(signature = (model, from_hz, to_hz, harmonics=7, level=1.0, stability=true, modes=20, residual_flexibility=true, max_points=None, threads=None))]
#[allow(clippy::too_many_arguments)]
pub fn frf(
    py: Python<'_>,
    model: &Bound<'_, PyAny>,
    from_hz: f64,
    to_hz: f64,
    harmonics: usize,
    level: f64,
    stability: bool,
    modes: usize,
    residual_flexibility: bool,
    max_points: Option<usize>,
    threads: Option<usize>,
) -> PyResult<Frf> {
    let subject = Subject::of(model)?;
    for (arg, v) in [("from_hz", from_hz), ("to_hz", to_hz)] {
        if !(v > 0.0 && v.is_finite()) {
            return Err(input(format!("{arg}: {v}; give a positive frequency")));
        }
    }
    if from_hz == to_hz {
        return Err(input(format!(
            "from_hz and to_hz are both {from_hz}: the range is empty"
        )));
    }
    if !level.is_finite() {
        return Err(input(format!("level: {level} is not a finite number")));
    }
    if modes == 0 {
        return Err(input("modes: 0; keep at least one mode"));
    }
    if max_points == Some(0) {
        return Err(input("max_points: 0; allow at least one point"));
    }
    let m = subject.model();
    let name = m.name().to_string();
    for (empty, what) in [
        (m.excitation().is_empty(), "no excitation point to force"),
        (m.sensors().is_empty(), "no sensor to report"),
    ] {
        if empty {
            return Err(input(format!("model '{name}' has {what}")));
        }
    }
    let set = HarmonicSet::new(harmonics, 1).map_err(|e| input(format!("harmonics: {e}")))?;
    let (system, report, y) = run(py, threads, move |stop| -> nlsim::Result<_> {
        let (reduced, m) = subject.reduced(modes, residual_flexibility, threads, stop)?;
        let system = HbSystem::from_model(&m, &reduced, set, HbConfig::default())?;
        let mut cfg = ContinuationConfig::frequency(from_hz, to_hz);
        cfg.stability = stability;
        cfg.fixed = level;
        if let Some(n) = max_points {
            cfg.max_points = n;
        }
        let report =
            nlsim::hb::continuation_with_progress(&system, &cfg, None, &mut |_| stop.check())?;
        let y = report
            .branch
            .points
            .iter()
            .map(|p| system.sensor_response(&p.x, p.omega, p.scale))
            .collect();
        Ok((system, report, y))
    })?
    .map_err(py_err)?;
    if report.branch.points.is_empty() {
        // Nothing computed is not a result: as on the command line, an error saying why.
        return Err(ComputationError::new_err(format!(
            "FRF of '{name}': {}: no point converged, not even the start point at {from_hz} Hz \
             ({}); are the parameters physical? try more harmonics or a smaller range",
            report.status.as_str(),
            nlsim::formats::files::one_line(&report.detail)
        )));
    }
    Ok(Frf { system, report, y })
}

/// Names of the built-in models `Model.load` takes (`"ecl_beam"`, `"bracket"`, …), with
/// their one-line descriptions.
#[pyfunction]
pub fn builtin_models() -> Vec<(&'static str, &'static str)> {
    nlsim::fixtures::CATALOGUE
        .iter()
        .map(|f| (f.name, f.summary))
        .collect()
}
