//! The computations: modes, the reduction, FOH time histories and harmonic-balance FRFs, each
//! with the settings of the matching `nlsim` command (`modes`, `simulate`, `frf`) so that the
//! results are the command's to the last bit. Every run happens on a worker thread inside a
//! rayon pool of `threads` threads while the calling thread waits without the GIL and checks
//! for Ctrl-C ten times a second.

use crate::model::Model;
use crate::{ComputationError, input, py_err};
use faer::c64;
use nlsim::hb::{ContinuationConfig, HbConfig, HbSystem, PointKind};
use nlsim::reduction::{EigenConfig, ModeSelection, ReducedModel, ReductionConfig};
use numpy::ndarray::{Array2, Array3};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use std::f64::consts::PI;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering as AtomicOrdering};
use std::sync::mpsc::RecvTimeoutError;
use std::time::Duration;

/// Frequencies of a stepped sine when `points` is not given (as `nlsim frf --mode step-up`).
const DEFAULT_STEPS: usize = 400;

/// Most frequencies of a stepped sine (as `nlsim frf --points`).
const MAX_FRF_POINTS: usize = 1_000_000;

/// How `frf` sweeps: `nlsim frf --mode`'s values.
#[derive(Clone, Copy, PartialEq, Eq)]
enum SweepMode {
    /// Pseudo-arclength continuation through the folds.
    Continuation,
    /// Stepped sine upwards, each point from the last.
    StepUp,
    /// Stepped sine downwards.
    StepDown,
}

impl SweepMode {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "continuation" => Some(Self::Continuation),
            "step-up" => Some(Self::StepUp),
            "step-down" => Some(Self::StepDown),
            _ => None,
        }
    }
}

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
    /// Whether the run was asked to stop (for runs that stop at their own safe points and
    /// return what they completed).
    pub(crate) fn requested(&self) -> bool {
        self.0.load(AtomicOrdering::Relaxed)
    }

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
    match run_keeping(py, threads, job)? {
        Ended::Done(t) => Ok(t),
        Ended::Interrupted(e, _) => Err(e),
    }
}

/// How [`run_keeping`] ended.
pub(crate) enum Ended<T> {
    /// The job returned without an interrupt.
    Done(T),
    /// Ctrl-C: the `KeyboardInterrupt` to raise, and what the job returned after it was
    /// told to stop (`None` when it unwound or a second Ctrl-C ended the wait).
    Interrupted(PyErr, Option<T>),
}

/// [`run`] that keeps what the job returns after Ctrl-C: a job that stops at its own safe
/// points ([`Stop::requested`]) hands back what it completed.
pub(crate) fn run_keeping<T: Send + 'static>(
    py: Python<'_>,
    threads: Option<usize>,
    job: impl FnOnce(&Stop) -> T + Send + 'static,
) -> PyResult<Ended<T>> {
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
            Ok(Ok(r)) => return Ok(Ended::Done(r)),
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
                    loop {
                        match wait() {
                            Ok(Ok(r)) => return Ok(Ended::Interrupted(interrupt, Some(r))),
                            Err(RecvTimeoutError::Timeout) if py.check_signals().is_ok() => {}
                            _ => return Ok(Ended::Interrupted(interrupt, None)),
                        }
                    }
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

pub(crate) fn vec1<'py>(py: Python<'py>, v: Vec<f64>) -> Bound<'py, PyArray1<f64>> {
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
pub(crate) fn reduce_model(
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
pub(crate) enum Subject {
    Model(nlsim::kernel::Model),
    Reduced(Arc<ReducedModel>, nlsim::kernel::Model),
}

impl Subject {
    pub(crate) fn of(obj: &Bound<'_, PyAny>) -> PyResult<Subject> {
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

    pub(crate) fn model(&self) -> &nlsim::kernel::Model {
        match self {
            Subject::Model(m) | Subject::Reduced(_, m) => m,
        }
    }

    pub(crate) fn reduced(
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
/// scales the excitation's nominal amplitudes. `mode="step-up"` or `"step-down"` runs a
/// stepped sine instead (`--mode`): `points` evenly spaced frequencies (default 400), each
/// solved from the last, so the response jumps past a fold as a test's would.
#[pyfunction]
#[pyo3(signature = (model, from_hz, to_hz, harmonics=7, level=1.0, stability=true, modes=20, residual_flexibility=true, max_points=None, mode="continuation", points=None, threads=None))]
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
    mode: &str,
    points: Option<usize>,
    threads: Option<usize>,
) -> PyResult<Frf> {
    let sweep = SweepMode::parse(mode).ok_or_else(|| {
        input(format!(
            "mode: '{mode}'; use 'continuation', 'step-up' or 'step-down'"
        ))
    })?;
    let steps = match (sweep, points) {
        (SweepMode::Continuation, Some(_)) => {
            return Err(input(
                "points: a stepped sine's frequency count; a continuation takes max_points",
            ));
        }
        (SweepMode::Continuation, None) => 0,
        (_, p) => {
            let upward = from_hz < to_hz;
            if sweep == SweepMode::StepUp && !upward {
                return Err(input(format!(
                    "mode 'step-up' goes up, but from_hz {from_hz} is above to_hz {to_hz} (swap \
                     them, or step down)"
                )));
            }
            if sweep == SweepMode::StepDown && upward {
                return Err(input(format!(
                    "mode 'step-down' goes down, but from_hz {from_hz} is below to_hz {to_hz} \
                     (swap them, or step up)"
                )));
            }
            let n = p.unwrap_or(DEFAULT_STEPS);
            if !(2..=MAX_FRF_POINTS).contains(&n) {
                return Err(input(format!(
                    "points: {n}; a stepped sine takes 2 to {MAX_FRF_POINTS} frequencies"
                )));
            }
            n
        }
    };
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
    let set = crate::harmonic_set(harmonics, crate::MAX_HARMONICS)?;
    let (system, report, y) = run(py, threads, move |stop| -> nlsim::Result<_> {
        let (reduced, m) = subject.reduced(modes, residual_flexibility, threads, stop)?;
        let system = HbSystem::from_model(&m, &reduced, set, HbConfig::default())?;
        let report = if sweep == SweepMode::Continuation {
            let mut cfg = ContinuationConfig::frequency(from_hz, to_hz);
            cfg.stability = stability;
            cfg.fixed = level;
            if let Some(n) = max_points {
                cfg.max_points = n;
            }
            nlsim::hb::continuation_with_progress(&system, &cfg, None, &mut |_| stop.check())?
        } else {
            // The command line's stepped sine: evenly spaced from `from_hz` to `to_hz`.
            let (a, b) = (from_hz, to_hz);
            let omegas: Vec<f64> = (0..steps)
                .map(|i| 2.0 * PI * (a + (b - a) * i as f64 / (steps - 1) as f64))
                .collect();
            nlsim::hb::stepped_sine_with_progress(&system, &omegas, level, stability, &mut |_| {
                stop.check()
            })?
        };
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
