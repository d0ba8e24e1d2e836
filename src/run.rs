//! The runs behind `nlsim frf` and `nlsim simulate`, as library calls: the command line and
//! `nlsim batch` both go through [`run_frf`] and [`run_simulation`], so a batch job computes
//! exactly what the single command computes.

use crate::error::{Error, Result};
use nlsim_hb::{Branch, ContinuationConfig, HarmonicSet, HbConfig, HbSystem, SolutionPoint};
use nlsim_kernel::param::parse_known;
use nlsim_kernel::{Model, Parameterized, Status, ValidationConfig};
use nlsim_reduction::{EigenConfig, ModalSystem, ModeSelection, ReducedModel, ReductionConfig};
use nlsim_sim::{
    FohConfig, Hold, LoadCase, Newmark, NewmarkConfig, Plant, Rk4Config, Rk45Config, Signal,
    Simulator, TimeHistory,
};
use std::collections::HashMap;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::Instant;

/// Loads and validates a model for a run (definiteness shows later, in the factorisations)
/// and applies `element.param=value` overrides.
pub fn load_for_run(spec: &str, sets: &[String]) -> Result<Model> {
    let mut model = crate::load_model(spec)?.model;
    model.validate(&ValidationConfig {
        check_definiteness: false,
        ..Default::default()
    })?;
    apply_sets(&mut model, sets)?;
    Ok(model)
}

/// Applies `element.param=value` overrides (the `--set` option).
pub fn apply_sets(model: &mut Model, sets: &[String]) -> Result<()> {
    for s in sets {
        let (name, v) = s
            .split_once('=')
            .ok_or_else(|| Error::Usage(format!("--set '{s}': expected element.param=value")))?;
        let v: f64 = v
            .trim()
            .parse()
            .map_err(|_| Error::Usage(format!("--set '{s}': '{v}' is not a number")))?;
        let p = parse_known(name, &model.parameters())?;
        model.set_param(&p, v)?;
    }
    Ok(())
}

/// The Lanczos settings of a run's reduction (`--basis`, `--restarts` of `simulate`, `frf`
/// and `nnm`, as of `modes`): what the eigensolver's message advises when modes do not
/// converge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Lanczos {
    /// Basis size before a restart; `None`: the solver's default `max(2k, k + 4 block)`.
    pub basis: Option<usize>,
    /// Most restarts before the solver gives up.
    pub restarts: usize,
    /// Fill-reducing ordering of the sparse factor (`--ordering`).
    pub ordering: nlsim_reduction::Ordering,
    /// Bytes the factors may take together (`--memory-budget`; see
    /// [`EigenConfig::memory_budget`]); `None`: no limit.
    pub memory_budget: Option<usize>,
}

impl Default for Lanczos {
    fn default() -> Self {
        let d = EigenConfig::default();
        Self {
            basis: d.basis_size,
            restarts: d.max_restarts,
            ordering: d.ordering,
            memory_budget: d.memory_budget,
        }
    }
}

/// Half the memory the system reports available (`MemAvailable` of `/proc/meminfo`, bytes):
/// the command line's default factor budget, so that a model whose two factors would not fit
/// beside each other is checked in the storage of one. `None` where the file is not there.
pub fn default_memory_budget() -> Option<usize> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: usize = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024) / 2)
}

/// The reduction every run uses: the lowest `modes` modes, with or without residual
/// flexibility.
fn reduce(
    model: &Model,
    modes: usize,
    residual: bool,
    par: faer::Par,
    lanczos: Lanczos,
) -> Result<ReducedModel> {
    Ok(nlsim_reduction::reduce(
        model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(modes),
                par,
                basis_size: lanczos.basis,
                max_restarts: lanczos.restarts,
                ordering: lanczos.ordering,
                memory_budget: lanczos.memory_budget,
                ..EigenConfig::default()
            },
            residual_flexibility: residual,
            ..Default::default()
        },
    )?)
}

type Slot = Arc<OnceLock<std::result::Result<Arc<ReducedModel>, String>>>;

/// Reduced models shared by runs that differ only in what the reduction does not see: the
/// excitation, the force level, the element parameters (elements act through their ports; their
/// laws are not part of `K` and `M`). Runs whose linear model differs (a stiffness group or a
/// boundary spring set by a job, another model) get their own reduction.
///
/// A run's reduction is identified by a hash of everything [`nlsim_reduction::reduce`] reads:
/// `K` and `M` (structure and values), the damping, the ports (element couplings, excitation
/// and sensor DOFs), the mode count and the residual flexibility switch. The reduction is
/// deterministic, so a shared one is bit-identical to a fresh one. Thread-safe: parallel jobs
/// with the same key wait for one reduction. Kept reductions are bounded by
/// [`Reductions::BUDGET_BYTES`] of mode shapes; past it, runs reduce for themselves.
#[derive(Debug, Default)]
pub struct Reductions {
    slots: Mutex<(HashMap<u64, Slot>, usize)>,
    computed: AtomicUsize,
    reused: AtomicUsize,
}

impl Reductions {
    /// Mode-shape bytes kept at most (1 GiB).
    pub const BUDGET_BYTES: usize = 1 << 30;

    /// The reduction of `model` to `modes` modes (with residual flexibility when `residual`),
    /// computed once per distinct linear model.
    pub fn get(
        &self,
        model: &Model,
        modes: usize,
        residual: bool,
        par: faer::Par,
        lanczos: Lanczos,
    ) -> Result<Arc<ReducedModel>> {
        let key = reduction_key(model, modes, residual, lanczos)?;
        let bytes = model.n_dofs().saturating_mul(modes).saturating_mul(8);
        let slot = {
            let mut guard = self.slots.lock().unwrap_or_else(|p| p.into_inner());
            let (map, used) = &mut *guard;
            match map.get(&key) {
                Some(s) => Some(s.clone()),
                None if used.saturating_add(bytes) <= Self::BUDGET_BYTES => {
                    *used += bytes;
                    Some(map.entry(key).or_default().clone())
                }
                None => None,
            }
        };
        let Some(slot) = slot else {
            self.computed.fetch_add(1, Ordering::Relaxed);
            return Ok(Arc::new(reduce(model, modes, residual, par, lanczos)?));
        };
        let mut fresh = false;
        let r = slot.get_or_init(|| {
            fresh = true;
            self.computed.fetch_add(1, Ordering::Relaxed);
            reduce(model, modes, residual, par, lanczos)
                .map(Arc::new)
                .map_err(|e| e.to_string())
        });
        if !fresh {
            self.reused.fetch_add(1, Ordering::Relaxed);
        }
        r.clone().map_err(Error::Failed)
    }

    /// How many reductions were computed and how many runs reused one.
    pub fn counts(&self) -> (usize, usize) {
        (
            self.computed.load(Ordering::Relaxed),
            self.reused.load(Ordering::Relaxed),
        )
    }
}

/// A hash of what the reduction of `model` to `modes` modes reads (see [`Reductions`]).
fn reduction_key(model: &Model, modes: usize, residual: bool, lanczos: Lanczos) -> Result<u64> {
    use std::hash::{Hash, Hasher};
    fn matrix(a: &nlsim_kernel::SparseSym, h: &mut impl Hasher) {
        let f = a.as_faer();
        f.col_ptr().hash(h);
        f.row_idx().hash(h);
        for v in f.val() {
            v.to_bits().hash(h);
        }
    }
    let mut h = std::hash::DefaultHasher::new();
    matrix(model.stiffness(), &mut h);
    matrix(model.mass(), &mut h);
    match model.damping() {
        nlsim_kernel::Damping::Matrix(v) => matrix(v, &mut h),
        d => format!("{d:?}").hash(&mut h),
    }
    format!("{:?}", nlsim_reduction::model_ports(model, &[])?).hash(&mut h);
    (modes, residual, lanczos).hash(&mut h);
    Ok(h.finish())
}

/// How an FRF is swept.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum SweepMode {
    /// Pseudo-arclength continuation: every branch through the folds, stability per point.
    Continuation,
    /// Stepped sine upwards, each point from the last (jumps down past the upper fold).
    StepUp,
    /// Stepped sine downwards (jumps up past the lower fold).
    StepDown,
}

impl SweepMode {
    /// `continuation`, `step-up` or `step-down`.
    pub fn as_str(self) -> &'static str {
        match self {
            SweepMode::Continuation => "continuation",
            SweepMode::StepUp => "step-up",
            SweepMode::StepDown => "step-down",
        }
    }

    /// Parses [`SweepMode::as_str`].
    pub fn parse(s: &str) -> Option<Self> {
        [Self::Continuation, Self::StepUp, Self::StepDown]
            .into_iter()
            .find(|m| m.as_str() == s)
    }
}

/// Most points of one FRF (a stepped sweep's steps, a continuation's points).
pub const MAX_FRF_POINTS: usize = 1_000_000;

/// Most harmonics `H` of one FRF.
pub const MAX_FRF_HARMONICS: usize = 256;

/// Parses a force harmonic `K=AMP[@DEG]` or `1/K=AMP[@DEG]` (`--force-harmonic`): `AMP cos(K
/// Ω t + DEG)`, the cosine convention of `docs/model-files.md`.
pub fn parse_force_harmonic(text: &str) -> Result<nlsim_kernel::ForceHarmonic> {
    let usage = |m: String| Error::Usage(format!("force harmonic '{text}': {m}"));
    let (order, value) = text
        .split_once('=')
        .ok_or_else(|| usage("expected K=AMP[@DEG], e.g. 2=1.5 or 3=2@90".into()))?;
    let (numerator, denominator) =
        nlsim_kernel::ForceHarmonic::parse_ratio(order).map_err(usage)?;
    let (amp, deg) = match value.split_once('@') {
        Some((a, d)) => (a, Some(d)),
        None => (value, None),
    };
    let num = |what: &str, v: &str| -> Result<f64> {
        v.trim()
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| usage(format!("{what} '{v}' is not a finite number")))
    };
    let amplitude = num("amplitude", amp)?;
    let phase = deg.map(|d| num("phase", d)).transpose()?.unwrap_or(0.0);
    if numerator == denominator {
        return Err(usage(
            "order 1 is the fundamental: set it with --force (the phase reference)".into(),
        ));
    }
    Ok(nlsim_kernel::ForceHarmonic {
        numerator,
        denominator,
        amplitude,
        phase: phase.to_radians(),
    })
}

/// Frequencies of a stepped sine when the request gives no point count.
pub const DEFAULT_STEPS: usize = 400;

/// Frequencies searched for a sub-harmonic start (evenly over the range).
pub const SUBHARMONIC_SEARCH: usize = 41;

/// How an FRF continuation starts.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum FrfStart {
    /// From rest at the start frequency, or, with a sub-harmonic order `ν ≥ 2`, from a
    /// sub-harmonic solution searched over the range (the primary branch from rest when
    /// none is found, with a note).
    #[default]
    Auto,
    /// From rest at the start frequency (the primary branch).
    Rest,
    /// From a sub-harmonic solution searched over the range; an error when none is found.
    Subharmonic,
}

impl FrfStart {
    /// Parses `auto`, `rest` or `subharmonic`.
    pub fn parse(s: &str) -> Option<Self> {
        match s {
            "auto" => Some(Self::Auto),
            "rest" => Some(Self::Rest),
            "subharmonic" => Some(Self::Subharmonic),
            _ => None,
        }
    }

    /// The name of [`FrfStart::parse`].
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Auto => "auto",
            Self::Rest => "rest",
            Self::Subharmonic => "subharmonic",
        }
    }
}

/// A continuation start read from an earlier `nlsim frf` HDF5 file (`--start-file`): a
/// solution point whose branch the continuation follows through the range, e.g. an isolated
/// sub-harmonic branch found once, or a branch to redo with more harmonics.
#[derive(Debug, Clone, PartialEq)]
pub struct StartFile {
    /// The file (written by `nlsim frf --out FILE.h5`).
    pub path: std::path::PathBuf,
    /// The file's point nearest this fundamental frequency (Hz) is taken. `None`: among the
    /// points within the range, the one with the most sub-harmonic content (harmonics of
    /// `Ω/ν` that are not harmonics of `Ω`) when `ν ≥ 2`, otherwise the largest response.
    pub at_hz: Option<f64>,
}

/// The point [`read_start`] took: its index in the file, fundamental (Hz) and the unknowns
/// on this run's harmonics.
struct StartPoint {
    index: usize,
    hz: f64,
    x: Vec<f64>,
    /// Harmonics of the file.
    h_file: usize,
}

/// Most values a start file may make nlsim read (2²⁶, 512 MiB).
const START_FILE_BUDGET: usize = 1 << 26;

/// Reads the start point of `sf` for `sys` over `from_hz..to_hz`. The file must hold the
/// same sub-harmonic order and an `/elements/<name>` dataset for every element of `sys`;
/// its harmonics may differ (the coefficients are cut or padded with zeros). Sizes are checked
/// against the datasets' shapes and a budget before anything is read; errors name the file
/// and the object.
fn read_start(sf: &StartFile, sys: &HbSystem, from_hz: f64, to_hz: f64) -> Result<StartPoint> {
    use hdf5_metno as hdf5;
    let path = &sf.path;
    let err = |object: &str, message: String| Error::Hdf5 {
        path: path.to_path_buf(),
        message: format!("start file, {object}: {message}"),
    };
    let f = hdf5::File::open(path).map_err(|e| err("file", e.to_string()))?;
    let attr = |name: &str| -> Result<f64> {
        f.attr(name)
            .and_then(|a| a.read_scalar::<f64>())
            .map_err(|e| {
                err(
                    "/",
                    format!("attribute '{name}': {e} (is it an `nlsim frf` output?)"),
                )
            })
    };
    let (h_attr, nu_attr) = (attr("harmonics")?, attr("subharmonic_order")?);
    let set = sys.harmonics();
    let whole = |v: f64| v >= 1.0 && v <= MAX_FRF_HARMONICS as f64 && v.fract() == 0.0;
    if !whole(h_attr) || !whole(nu_attr) {
        return Err(err(
            "/",
            format!("harmonics {h_attr} and subharmonic_order {nu_attr} are not valid orders"),
        ));
    }
    let (h_file, nu_file) = (h_attr as usize, nu_attr as usize);
    if nu_file != set.nu {
        return Err(err(
            "/",
            format!(
                "its branch has harmonics of Ω/{nu_file}, this run of Ω/{} (use \
                 --subharmonic {nu_file})",
                set.nu
            ),
        ));
    }
    let ds = |name: &str| f.dataset(name).map_err(|e| err(name, e.to_string()));
    let freq = ds("frequency")?;
    let shape = freq.shape();
    if shape.len() != 1 || shape[0] == 0 || shape[0] > MAX_FRF_POINTS {
        return Err(err(
            "frequency",
            format!("shape {shape:?}: expected 1 to {MAX_FRF_POINTS} points"),
        ));
    }
    let n = shape[0];
    let hz: Vec<f64> = freq
        .read_raw()
        .map_err(|e| err("frequency", e.to_string()))?;
    let nh_file = 2 * h_file + 1;
    let nh = set.len();
    let mut x_file = Vec::new();
    for (e, el) in sys.elements().iter().enumerate() {
        let name = format!("elements/{}", el.name());
        let d = f.dataset(&name).map_err(|_| {
            let there = f
                .group("elements")
                .and_then(|g| g.member_names())
                .map_or("none".into(), |v| v.join(", "));
            err(
                &name,
                format!(
                    "no such dataset: the file holds another model's elements ({there}), not \
                     this model's '{}'",
                    el.name()
                ),
            )
        })?;
        let m = sys.coordinates(e).len();
        let want = [n, m * nh_file];
        if d.shape() != want {
            return Err(err(
                &name,
                format!(
                    "shape {:?}, expected {want:?} ({n} points, {m} coordinate(s) of 2·{h_file} + 1 \
                     coefficients)",
                    d.shape()
                ),
            ));
        }
        if (x_file.len() + n * m * nh_file) > START_FILE_BUDGET {
            return Err(err(&name, format!("more than {START_FILE_BUDGET} values")));
        }
        let v: Vec<f64> = d.read_raw().map_err(|e| err(&name, e.to_string()))?;
        x_file.push((v, m));
    }
    let (lo, hi) = (from_hz.min(to_hz), from_hz.max(to_hz));
    let inside: Vec<usize> = (0..n)
        .filter(|&i| hz[i].is_finite() && hz[i] >= lo && hz[i] <= hi)
        .collect();
    if inside.is_empty() {
        return Err(err(
            "frequency",
            format!("none of its {n} points lies within {lo} to {hi} Hz"),
        ));
    }
    // The unknowns of point i on this run's harmonics.
    let point = |i: usize| -> Vec<f64> {
        let mut x = Vec::with_capacity(sys.n_unknowns());
        for (v, m) in &x_file {
            let row = &v[i * m * nh_file..(i + 1) * m * nh_file];
            for c in 0..*m {
                let block = &row[c * nh_file..(c + 1) * nh_file];
                x.extend((0..nh).map(|j| block.get(j).copied().unwrap_or(0.0)));
            }
        }
        x
    };
    let measure = |i: usize| -> f64 {
        let x = point(i);
        if set.nu >= 2 {
            // Harmonics k of Ω/ν with ν ∤ k.
            x.chunks(nh)
                .flat_map(|b| {
                    (1..=set.h)
                        .filter(|k| k % set.nu != 0)
                        .map(move |k| b[2 * k - 1].hypot(b[2 * k]))
                })
                .fold(0.0f64, f64::max)
        } else {
            x.iter().fold(0.0f64, |a, v| a.max(v.abs()))
        }
    };
    let index = match sf.at_hz {
        Some(at) => inside
            .iter()
            .copied()
            .min_by(|&a, &b| (hz[a] - at).abs().total_cmp(&(hz[b] - at).abs())),
        None => inside
            .iter()
            .map(|&i| (i, measure(i)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(i, _)| i),
    }
    .unwrap_or(inside[0]);
    let x = point(index);
    if let Some(j) = x.iter().position(|v| !v.is_finite()) {
        return Err(err(
            "elements",
            format!("point {index} has a non-finite coefficient (unknown {j})"),
        ));
    }
    Ok(StartPoint {
        index,
        hz: hz[index],
        x,
        h_file,
    })
}

/// A multi-harmonic FRF to compute (the options of `nlsim frf`).
#[derive(Debug, Clone)]
pub struct FrfRequest {
    /// Start frequency (Hz).
    pub from_hz: f64,
    /// End frequency (Hz).
    pub to_hz: f64,
    /// Harmonics `H` of the base frequency `Ω/ν`.
    pub harmonics: usize,
    /// Sub-harmonic order `ν`.
    pub subharmonic: usize,
    /// Force amplitude (N) at the fundamental on every excitation point; `None`: the model's
    /// nominal amplitudes.
    pub force: Option<f64>,
    /// Further force harmonics on every excitation point, replacing the model's
    /// `[[excitation.harmonic]]` when not empty (cosine convention, `docs/model-files.md`).
    pub force_harmonics: Vec<nlsim_kernel::ForceHarmonic>,
    /// Continuation or stepped sine.
    pub mode: SweepMode,
    /// Frequencies of a stepped sine (default [`DEFAULT_STEPS`]); for a continuation, the
    /// fewest points over the range: the step in frequency is at most the range over
    /// `points − 1` (default: the continuation's own step control).
    pub points: Option<usize>,
    /// Largest continuation step in frequency (Hz); `None`: 2 % of the range.
    pub max_step_hz: Option<f64>,
    /// How a continuation starts.
    pub start: FrfStart,
    /// A continuation start from a point of an earlier FRF file instead (`--start-file`).
    pub start_file: Option<StartFile>,
    /// Retained modes.
    pub modes: usize,
    /// Residual flexibility of the truncated modes.
    pub residual: bool,
    /// Hill stability per point.
    pub stability: bool,
    /// Parallelism of the reduction (faer's `Par`; `Par::rayon(0)` uses the current pool).
    pub par: faer::Par,
    /// Lanczos settings of the reduction.
    pub lanczos: Lanczos,
}

impl Default for FrfRequest {
    fn default() -> Self {
        Self {
            from_hz: 0.0,
            to_hz: 0.0,
            harmonics: 7,
            subharmonic: 1,
            force: None,
            force_harmonics: Vec::new(),
            mode: SweepMode::Continuation,
            points: None,
            max_step_hz: None,
            start: FrfStart::Auto,
            start_file: None,
            modes: 20,
            residual: true,
            stability: true,
            par: faer::Par::rayon(0),
            lanczos: Lanczos::default(),
        }
    }
}

impl FrfRequest {
    /// Checks the values that do not need the model; errors are usage errors naming the
    /// request field.
    pub fn check(&self) -> Result<HarmonicSet> {
        let usage = |m: String| Error::Usage(format!("FRF request: {m}"));
        for (what, v) in [("from_hz", self.from_hz), ("to_hz", self.to_hz)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(usage(format!(
                    "{what} {v} must be a positive frequency in Hz"
                )));
            }
        }
        if self.from_hz == self.to_hz {
            return Err(usage("from_hz and to_hz are equal".into()));
        }
        let upward = self.from_hz < self.to_hz;
        match self.mode {
            SweepMode::StepUp if !upward => {
                return Err(usage(format!(
                    "a step-up sweep goes up, but from_hz {} is above to_hz {} (swap them, or \
                     step down)",
                    self.from_hz, self.to_hz
                )));
            }
            SweepMode::StepDown if upward => {
                return Err(usage(format!(
                    "a step-down sweep goes down, but from_hz {} is below to_hz {} (swap them, \
                     or step up)",
                    self.from_hz, self.to_hz
                )));
            }
            _ => {}
        }
        if let Some(p) = self.points
            && !(2..=MAX_FRF_POINTS).contains(&p)
        {
            return Err(usage(format!(
                "points {p} must be from 2 to {MAX_FRF_POINTS} (each point keeps its solution)"
            )));
        }
        if let Some(h) = self.max_step_hz {
            if !(h > 0.0 && h.is_finite()) {
                return Err(usage(format!(
                    "max_step_hz {h} must be a positive frequency step in Hz"
                )));
            }
            let needed = (self.to_hz - self.from_hz).abs() / h;
            if needed > MAX_FRF_POINTS as f64 {
                return Err(usage(format!(
                    "max_step_hz {h} over {} Hz needs {needed:.3e} points, more than \
                     {MAX_FRF_POINTS}",
                    (self.to_hz - self.from_hz).abs()
                )));
            }
        }
        if self.mode != SweepMode::Continuation
            && (self.max_step_hz.is_some() || self.start != FrfStart::Auto)
        {
            return Err(usage(format!(
                "max_step_hz and start apply to a continuation, not to a {} sweep (its \
                 frequencies are the points)",
                self.mode.as_str()
            )));
        }
        if let Some(sf) = &self.start_file {
            if self.mode != SweepMode::Continuation {
                return Err(usage(format!(
                    "a start file ({}) starts a continuation; a {} sweep starts every \
                     frequency from the last (drop one of them)",
                    sf.path.display(),
                    self.mode.as_str()
                )));
            }
            if self.start != FrfStart::Auto {
                return Err(usage(format!(
                    "start = {} and a start file ({}) are two starts: give one",
                    self.start.as_str(),
                    sf.path.display()
                )));
            }
            if let Some(hz) = sf.at_hz {
                let (lo, hi) = (self.from_hz.min(self.to_hz), self.from_hz.max(self.to_hz));
                if !(hz >= lo && hz <= hi) {
                    return Err(usage(format!(
                        "start frequency {hz} Hz is outside the range {lo} to {hi} Hz"
                    )));
                }
            }
        }
        if self.start == FrfStart::Subharmonic && self.subharmonic < 2 {
            return Err(usage(
                "a sub-harmonic start needs a sub-harmonic order of at least 2".into(),
            ));
        }
        if self.harmonics > MAX_FRF_HARMONICS {
            return Err(usage(format!(
                "harmonics {} is more than {MAX_FRF_HARMONICS} (the Jacobian and the AFT grow \
                 as H²; contact rarely needs more than 50)",
                self.harmonics
            )));
        }
        if self.modes == 0 {
            return Err(usage("modes must be at least 1".into()));
        }
        if let Some(f) = self.force
            && !f.is_finite()
        {
            return Err(usage(format!("force {f} is not a finite number")));
        }
        HarmonicSet::new(self.harmonics, self.subharmonic)
            .map_err(|e| usage(format!("harmonics/subharmonic: {e}")))
    }
}

/// A computed FRF.
pub struct FrfRun {
    /// The condensed harmonic-balance system (with the forcing used).
    pub system: HbSystem,
    /// The solution points.
    pub branch: Branch,
    /// [`Status::Converged`] when the whole range was followed,
    /// [`Status::IterationLimit`] when the continuation stopped at its point limit, another
    /// status when it stopped short (the branch then holds the points found before).
    pub status: Status,
    /// Where and why the run stopped short (one line); empty when it converged.
    pub detail: String,
    /// Response maxima per sensor and harmonic, located between the computed points
    /// ([`nlsim_hb::locate_peaks`]; continuation only, empty for a stepped sine).
    pub peaks: Vec<nlsim_hb::Peak>,
    /// What the run found worth saying: how a sub-harmonic branch was started, or that it
    /// was not found.
    pub notes: Vec<String>,
    /// Sensor responses (sensors × harmonics) per point, from [`crate::frf::responses`].
    pub responses: Vec<faer::Mat<faer::c64>>,
    /// Retained modes.
    pub modes: usize,
    /// Wall time of the reduction (s).
    pub reduce_seconds: f64,
    /// Wall time of the sweep (s).
    pub seconds: f64,
}

impl FrfRun {
    /// The lines `nlsim frf` prints for this run of `req` on `model`: the setup, the forces,
    /// the point count and time, folds, jumps and branch points, and each sensor's peak;
    /// with `verbose`, the Newton iteration count too.
    pub fn summary(&self, model: &Model, req: &FrfRequest, verbose: bool) -> Vec<String> {
        use nlsim_hb::PointKind;
        let mut out = Vec::new();
        let set = *self.system.harmonics();
        let run = self;
        let (sys, branch) = (&run.system, &run.branch);
        out.push(format!(
            "frf {}: {} {:.4}–{:.4} Hz, H = {} harmonics of Ω/{}, {} modes{} (reduced in {:.2} s), \
             {} unknowns, AFT samples {:?}",
            model.name(),
            req.mode.as_str(),
            req.from_hz,
            req.to_hz,
            set.h,
            set.nu,
            modes_text(run.modes, req.modes),
            if req.residual {
                " + residual flexibility"
            } else {
                ""
            },
            run.reduce_seconds,
            sys.n_unknowns(),
            sys.aft_samples()
        ));
        if let Some(note) = cluster_note(run.modes, req.modes) {
            out.push(format!("  {note}"));
        }
        for x in &sys.forcing().terms {
            let phase = x.amplitude.im.atan2(x.amplitude.re).to_degrees();
            out.push(format!(
                "  force {:<10} {:.4e} N{} at harmonic {} (Ω)",
                sys.inputs()[x.input].0,
                x.amplitude.norm(),
                if phase == 0.0 {
                    String::new()
                } else {
                    format!(" at phase {phase:.1}°")
                },
                crate::frf::harmonic_label(x.harmonic, set.nu)
            ));
        }
        let n = branch.points.len();
        let unstable = branch
            .points
            .iter()
            .filter(|p| p.stable() == Some(false))
            .count();
        out.push(format!(
            "  {n} points in {:.3} s ({:.3} ms per point){}; {unstable} unstable",
            run.seconds,
            1e3 * run.seconds / n as f64,
            match run.status {
                Status::Converged => String::new(),
                Status::IterationLimit => " — stopped at the point limit before the end".into(),
                s => format!(" — stopped short ({})", s.as_str()),
            }
        ));
        if verbose {
            let its: usize = branch.points.iter().map(|p| p.iterations).sum();
            out.push(format!(
                "  Newton: {its} iterations in all, {:.2} per point",
                its as f64 / n.max(1) as f64
            ));
        }
        for p in branch
            .points
            .iter()
            .filter(|p| matches!(p.kind, PointKind::Fold | PointKind::Jump))
        {
            out.push(format!(
                "  {} at {:.5} Hz",
                if p.kind == PointKind::Fold {
                    "fold"
                } else {
                    "jump"
                },
                p.omega / (2.0 * PI)
            ));
        }
        for bi in branch
            .bifurcations
            .iter()
            .filter(|b| b.kind != nlsim_hb::BifurcationKind::Fold)
        {
            out.push(format!(
                "  {} at {:.6} Hz{}",
                bi.kind.as_str(),
                bi.omega / (2.0 * PI),
                if bi.located {
                    " (located)"
                } else {
                    " (interpolated between points)"
                }
            ));
        }
        for bp in &branch.branch_points {
            out.push(format!(
                "  branch point near {:.5} Hz",
                bp.omega / (2.0 * PI)
            ));
        }
        let shown: Vec<usize> = if set.nu >= 2 {
            vec![set.nu, 1]
        } else {
            vec![1]
        };
        for (s, sen) in sys.sensors().iter().enumerate() {
            for &k in &shown {
                out.push(self.peak_line(s, k, &sen.name, sen.quantity));
            }
        }
        for note in &self.notes {
            out.push(format!("  note: {note}"));
        }
        out
    }

    /// The summary line of the largest `|Y_k|` of sensor `s` (located when it could be).
    fn peak_line(
        &self,
        s: usize,
        k: usize,
        name: &str,
        quantity: nlsim_kernel::Quantity,
    ) -> String {
        let set = *self.system.harmonics();
        let (branch, y) = (&self.branch, &self.responses);
        let n = branch.points.len();
        {
            let located = self.peaks.iter().find(|p| p.sensor == s && p.harmonic == k);
            let (hz, a, how) = match located {
                Some(p) => (
                    p.omega / (2.0 * PI),
                    p.value,
                    if p.located {
                        "located"
                    } else {
                        "at an end of the computed branch"
                    },
                ),
                None => {
                    let (i, a) = (0..n)
                        .map(|i| (i, y[i][(s, k)].norm()))
                        .fold((0, 0.0f64), |m, v| if v.1 > m.1 { v } else { m });
                    (branch.points[i].omega / (2.0 * PI), a, "largest computed")
                }
            };
            let which = if k == set.nu {
                "the fundamental".to_string()
            } else {
                format!("Ω/{}", set.nu)
            };
            format!(
                "  {name:<12} peak |{}| at {which} {a:.7e} {} at {hz:.6} Hz ({how})",
                quantity.as_str(),
                crate::output::unit(quantity),
            )
        }
    }
}

/// Computes the FRF `req` asks for on `model`, calling `progress` after every point.
pub fn run_frf(
    model: &Model,
    req: &FrfRequest,
    progress: &mut dyn FnMut(&SolutionPoint),
) -> Result<FrfRun> {
    run_frf_shared(model, req, progress, &Reductions::default())
}

/// As [`run_frf`], taking the reduction from `reductions` when a run of the same linear model
/// made it (a batch's jobs).
pub fn run_frf_shared(
    model: &Model,
    req: &FrfRequest,
    progress: &mut dyn FnMut(&SolutionPoint),
    reductions: &Reductions,
) -> Result<FrfRun> {
    let set = req.check()?;
    let name = model.name();
    if model.elements().is_empty() {
        return Err(Error::Usage(format!(
            "model '{name}' has no nonlinear element: its FRF is linear (see `nlsim modes`)"
        )));
    }
    if model.excitation().is_empty() {
        return Err(Error::Usage(format!(
            "model '{name}' has no excitation point to force"
        )));
    }
    if model.sensors().is_empty() {
        return Err(Error::Usage(format!(
            "model '{name}' has no sensor to report"
        )));
    }
    let modes = req.modes.min(model.n_dofs());
    let t0 = Instant::now();
    let reduced = reductions.get(model, modes, req.residual, req.par, req.lanczos)?;
    let modes = reduced.modes.len();
    let reduce_seconds = t0.elapsed().as_secs_f64();
    let system = if req.force.is_some() || !req.force_harmonics.is_empty() {
        // The overrides apply to every excitation point before the forcing is built, so a
        // model harmonic the overrides replace cannot fail the build.
        let mut forced = model.clone();
        forced.clear_excitation();
        for x in model.excitation() {
            let mut x = x.clone();
            if let Some(f) = req.force {
                x.amplitude = f;
            }
            if !req.force_harmonics.is_empty() {
                x.harmonics = req.force_harmonics.clone();
            }
            forced.add_excitation(x)?;
        }
        HbSystem::from_model(&forced, &reduced, set, HbConfig::default())?
    } else {
        HbSystem::from_model(model, &reduced, set, HbConfig::default())?
    };
    let mut notes = Vec::new();
    let mut cfg = None;
    let t1 = Instant::now();
    let report = match req.mode {
        SweepMode::Continuation => {
            let mut c = ContinuationConfig::frequency(req.from_hz, req.to_hz);
            c.stability = req.stability;
            let span = (req.to_hz - req.from_hz).abs();
            if let Some(n) = req.points {
                c.ds_max = c.ds_max.min(1.0 / (n - 1) as f64);
                c.max_points = c.max_points.max(4 * n);
            }
            if let Some(h) = req.max_step_hz {
                c.ds_max = c.ds_max.min(h / span);
                c.max_points = c.max_points.max((4.0 * span / h).ceil().min(1e6) as usize);
            }
            c.max_points = c.max_points.min(MAX_FRF_POINTS);
            c.ds = c.ds.min(c.ds_max);
            c.ds_min = c.ds_min.min(c.ds);
            let from_file = match &req.start_file {
                Some(sf) => Some(read_start(sf, &system, req.from_hz, req.to_hz)?),
                None => None,
            };
            let search = set.nu >= 2 && req.start != FrfStart::Rest && from_file.is_none();
            let found = if search {
                let omegas: Vec<f64> = (0..SUBHARMONIC_SEARCH)
                    .map(|i| {
                        2.0 * PI
                            * (req.from_hz
                                + (req.to_hz - req.from_hz) * i as f64
                                    / (SUBHARMONIC_SEARCH - 1) as f64)
                    })
                    .collect();
                nlsim_hb::find_subharmonic(&system, &omegas, 1.0)?
            } else {
                None
            };
            let report = match (from_file, found) {
                (Some(sp), _) => {
                    let sf = req
                        .start_file
                        .as_ref()
                        .map_or("", |s| s.path.to_str().unwrap_or("the start file"));
                    notes.push(format!(
                        "start: point {} of {sf} at {:.5} Hz (H = {} there{}); the branch \
                         through it is followed to both ends of the range",
                        sp.index + 1,
                        sp.hz,
                        sp.h_file,
                        if sp.h_file == set.h {
                            String::new()
                        } else {
                            format!(", {} here", set.h)
                        }
                    ));
                    nlsim_hb::continuation_through(&system, &c, 2.0 * PI * sp.hz, &sp.x, progress)?
                }
                (None, Some(st)) => {
                    notes.push(format!(
                        "sub-harmonic start: a 1/{} solution at {:.5} Hz ({:.0} % of the \
                         response at Ω/{}) from the backbone of mode {} ({} Newton starts); \
                         the branch through it is followed to both ends of the range",
                        set.nu,
                        st.omega / (2.0 * PI),
                        100.0 * st.content,
                        set.nu,
                        st.mode + 1,
                        st.attempts
                    ));
                    nlsim_hb::continuation_through(&system, &c, st.omega, &st.x, progress)?
                }
                (None, None) => {
                    if req.start == FrfStart::Subharmonic {
                        return Err(Error::Failed(format!(
                            "no 1/{} sub-harmonic solution found: Newton from the backbones of \
                             the 3 modes nearest Ω/{} at {SUBHARMONIC_SEARCH} frequencies from \
                             {} to {} Hz converged to none (a larger force, another range or \
                             more harmonics may reach one)",
                            set.nu, set.nu, req.from_hz, req.to_hz
                        )));
                    }
                    if search {
                        notes.push(format!(
                            "no 1/{} sub-harmonic solution found (Newton from the backbones of \
                             the 3 modes nearest Ω/{} at {SUBHARMONIC_SEARCH} frequencies): \
                             the branch from rest follows",
                            set.nu, set.nu
                        ));
                    }
                    nlsim_hb::continuation_with_progress(&system, &c, None, progress)?
                }
            };
            cfg = Some(c);
            report
        }
        SweepMode::StepUp | SweepMode::StepDown => {
            let (lo, hi) = (req.from_hz.min(req.to_hz), req.from_hz.max(req.to_hz));
            let (a, b) = if req.mode == SweepMode::StepUp {
                (lo, hi)
            } else {
                (hi, lo)
            };
            let steps = req.points.unwrap_or(DEFAULT_STEPS);
            let omegas: Vec<f64> = (0..steps)
                .map(|i| 2.0 * PI * (a + (b - a) * i as f64 / (steps - 1) as f64))
                .collect();
            nlsim_hb::stepped_sine_with_progress(&system, &omegas, 1.0, req.stability, progress)?
        }
    };
    let seconds = t1.elapsed().as_secs_f64();
    if report.stats.n_wiggles > 0 {
        notes.push(format!(
            "{} pair(s) of turning points closer than {} of the range with the response \
             within {} % between them were ripples of the non-smooth branch, not folds \
             (kept as regular points)",
            report.stats.n_wiggles,
            nlsim_hb::continuation::WIGGLE_PARAMETER,
            100.0 * nlsim_hb::continuation::WIGGLE_RESPONSE
        ));
    }
    let status = report.status;
    let detail = report.detail.replace('\n', ": ");
    if report.branch.points.is_empty() {
        // Nothing to return: the start point itself failed.
        return Err(match report.into_branch() {
            Err(e) => e.into(),
            Ok(_) => Error::Failed(format!("{}: no point converged", status.as_str())),
        });
    }
    let branch = report.branch;
    if set.nu >= 2 {
        let share = branch
            .points
            .iter()
            .map(|p| nlsim_hb::subharmonic_content(&system, &p.x))
            .fold(0.0f64, f64::max);
        if share < nlsim_hb::start::SUBHARMONIC_SHARE {
            notes.push(format!(
                "the computed branch carries no Ω/{} content (largest share {share:.1e} of the \
                 response): it is the primary response, not a 1/{} sub-harmonic one",
                set.nu, set.nu
            ));
        }
    }
    let responses = crate::frf::responses(&system, &branch);
    let peaks = match &cfg {
        Some(c) => nlsim_hb::locate_peaks(&system, c, &branch, &responses),
        None => Vec::new(),
    };
    Ok(FrfRun {
        system,
        branch,
        status,
        detail,
        peaks,
        notes,
        responses,
        modes,
        reduce_seconds,
        seconds,
    })
}

/// Time integration methods.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "cli", derive(clap::ValueEnum))]
pub enum Method {
    /// Exponential first-order hold with nonlinear feedback (the fast method).
    Foh,
    /// Zero-order hold (bias studies).
    Zoh,
    /// Lagrange second-order hold (bias studies).
    Lsoh,
    /// Dormand-Prince RK45 with ODE45's error control on the reduced model.
    Rk45,
    /// Classic RK4 on the reduced model.
    Rk4,
    /// Newmark average acceleration with Newton on the unreduced model.
    Newmark,
    /// HHT-alpha with Newton on the unreduced model.
    Hht,
}

impl Method {
    /// Lower-case name, as on the command line.
    pub fn as_str(self) -> &'static str {
        match self {
            Method::Foh => "foh",
            Method::Zoh => "zoh",
            Method::Lsoh => "lsoh",
            Method::Rk45 => "rk45",
            Method::Rk4 => "rk4",
            Method::Newmark => "newmark",
            Method::Hht => "hht",
        }
    }

    /// Parses [`Method::as_str`].
    pub fn parse(s: &str) -> Option<Self> {
        use Method::*;
        [Foh, Zoh, Lsoh, Rk45, Rk4, Newmark, Hht]
            .into_iter()
            .find(|m| m.as_str() == s)
    }

    /// Whether the method integrates the unreduced sparse model.
    pub fn unreduced(self) -> bool {
        matches!(self, Method::Newmark | Method::Hht)
    }
}

impl SimRun {
    /// `None` when the run reached its end; otherwise one line saying where it stopped and why
    /// (the history then holds the samples computed before).
    pub fn stopped_short(&self, n_steps: usize) -> Option<String> {
        let h = &self.history;
        if h.status.is_converged() {
            return None;
        }
        let samples = h.n_samples();
        Some(format!(
            "stopped short ({}) at t = {:.6e} s after {samples} of {} samples: {}",
            h.status.as_str(),
            samples.saturating_sub(1) as f64 * h.dt,
            n_steps + 1,
            h.stopped
                .as_ref()
                .map_or_else(|| "no detail".to_string(), |e| e.to_string())
        ))
    }

    /// The lines `nlsim simulate` prints for this run of `req` on `model`: the setup, the
    /// excitation per point, the run's counters, and the peak and rms of every output and
    /// element; with `verbose`, every contact event.
    pub fn summary(&self, model: &Model, req: &SimRequest, verbose: bool) -> Vec<String> {
        let mut out = Vec::new();
        let run = self;
        let n_steps = req.check().unwrap_or_default();
        let history = &run.history;
        let dt = 1.0 / req.rate;
        out.push(format!(
            "simulate {}: {}, {}, dt {dt:.4e} s, {} samples over {} s",
            model.name(),
            req.method.as_str(),
            if req.method.unreduced() {
                format!(
                    "unreduced ({} DOFs), effective stiffness factorised in {:.2} s",
                    model.n_dofs(),
                    run.setup_seconds
                )
            } else {
                format!(
                    "{} modes{} (reduced in {:.2} s)",
                    modes_text(run.modes, req.modes),
                    if req.residual {
                        " + residual flexibility"
                    } else {
                        ""
                    },
                    run.setup_seconds
                )
            },
            n_steps + 1,
            req.duration
        ));
        for (x, sp) in model.excitation().iter().zip(&run.excitation) {
            out.push(format!("  excitation {:<10} {sp}", x.name));
        }
        if let Some(note) = cluster_note(run.modes, req.modes) {
            out.push(format!("  {note}"));
        }
        if let Some((a, scaled)) = run.atol {
            out.push(format!(
                "  rk45 tolerances: rtol {:e}, atol {a:.3e} √kg m on the modal states{}",
                req.rtol,
                if scaled {
                    " (scaled to the response: 1e-3 rtol of the largest static state)"
                } else {
                    ""
                }
            ));
        }
        let st = &history.stats;
        if run.flops_per_state_step > 0 {
            out.push(format!(
                "  run: {:.3} s wall, {:.2} ns per mode-step ({} states, {} flops each)",
                st.seconds,
                st.seconds / (n_steps as f64 * run.states as f64) * 1e9,
                run.states,
                run.flops_per_state_step
            ));
        }
        out.push(format!(
            "  {} steps ({} rejected), {} evaluations, Newton {} iterations (max {} in a step), {} \
             contact events, {:.3} s wall",
            st.steps,
            st.rejected_steps,
            st.evaluations,
            st.newton_iterations,
            st.max_newton_iterations,
            st.events.len(),
            st.seconds
        ));
        if verbose {
            for e in &st.events {
                out.push(format!(
                    "    contact event: element {} {} at t = {:.9e} s",
                    history.element_names[e.element],
                    if e.closing { "closes" } else { "opens" },
                    e.time
                ));
            }
        }
        if let Some(line) = run.stopped_short(n_steps) {
            out.push(format!("  {line}"));
        }
        out.extend(req.notes().into_iter().map(|n| format!("  {n}")));
        out.push(format!(
            "  {:<14} {:<13} {:>13} {:>13}",
            "output", "quantity", "peak", "rms"
        ));
        for s in &history.outputs {
            let peak = s.values.iter().fold(0.0f64, |m, x| m.max(x.abs()));
            let rms = (s.values.iter().map(|x| x * x).sum::<f64>() / s.values.len() as f64).sqrt();
            out.push(format!(
                "  {:<14} {:<13} {peak:>13.5e} {rms:>13.5e}",
                s.name,
                s.quantity.as_str()
            ));
        }
        for (e, name) in history.element_names.iter().enumerate() {
            let pu = history.element_displacements[e]
                .iter()
                .fold(0.0f64, |m, x| m.max(x.abs()));
            let pg = history.element_forces[e]
                .iter()
                .fold(0.0f64, |m, x| m.max(x.abs()));
            out.push(format!(
                "  element {name:<10} peak |u| {pu:.5e} m, peak |g| {pg:.5e} N"
            ));
        }
        out
    }
}

/// What drives the excitation points of a simulation: a signal on one point or on all.
#[derive(Debug, Clone, PartialEq)]
pub struct Drive {
    /// The excitation point's name; `None` drives every point.
    pub point: Option<String>,
    /// The force (N); per unit of each point's nominal amplitude when `nominal`.
    pub signal: Signal,
    /// Scale `signal` by the point's nominal amplitude (a spec that gave no amplitude).
    pub nominal: bool,
    /// How reports and result files name the drive (the spec it was parsed from).
    pub label: String,
}

impl Drive {
    /// `signal` (N) on every excitation point.
    pub fn all(signal: Signal) -> Self {
        Self {
            point: None,
            label: crate::simulate::describe_signal(&signal),
            signal,
            nominal: false,
        }
    }

    /// `signal` (N) on excitation point `name`.
    pub fn at(name: impl Into<String>, signal: Signal) -> Self {
        Self {
            point: Some(name.into()),
            ..Self::all(signal)
        }
    }

    /// Parses `SPEC` (every point) or `NAME=SPEC` (one point) in the grammar of
    /// [`crate::simulate::parse_excitation`]; a sweep without `duration` lasts `duration_s`,
    /// a force file without `rate` is sampled at `rate_hz`.
    pub fn parse(text: &str, duration_s: f64, rate_hz: f64) -> Result<Self> {
        let (point, spec) = match text
            .split_once('=')
            .filter(|(n, _)| !n.contains(':') && !n.contains(','))
        {
            Some((name, spec)) => (Some(name.to_string()), spec),
            None => (None, text),
        };
        let (signal, nominal) = crate::simulate::parse_signal(spec, 1.0, duration_s, rate_hz)?;
        Ok(Self {
            point,
            signal,
            nominal,
            label: spec.to_string(),
        })
    }
}

/// A time response to compute (the options of `nlsim simulate`).
#[derive(Debug, Clone)]
pub struct SimRequest {
    /// Simulated time (s).
    pub duration: f64,
    /// Sample rate (Hz).
    pub rate: f64,
    /// Integration method.
    pub method: Method,
    /// Drives in order (a later one replaces an earlier one on the points it names); a point
    /// no drive names gets a sine at the first natural frequency of its nominal amplitude.
    pub excitation: Vec<Drive>,
    /// Retained modes (reduced methods).
    pub modes: usize,
    /// Residual flexibility of the truncated modes.
    pub residual: bool,
    /// Locate contact events inside steps (FOH).
    pub events: bool,
    /// RK45 relative tolerance.
    pub rtol: f64,
    /// RK45 absolute tolerance on the modal states (√kg m); `None` scales it to the response
    /// (see [`auto_atol`]).
    pub atol: Option<f64>,
    /// Integration steps per sample (RK4, Newmark, HHT).
    pub substeps: usize,
    /// HHT α in `[−1/3, 0]`.
    pub hht_alpha: f64,
    /// Parallelism of the reduction (faer's `Par`; `Par::rayon(0)` uses the current pool).
    pub par: faer::Par,
    /// Lanczos settings of the reduction.
    pub lanczos: Lanczos,
}

impl Default for SimRequest {
    fn default() -> Self {
        Self {
            duration: 0.0,
            rate: 0.0,
            method: Method::Foh,
            excitation: Vec::new(),
            modes: 20,
            residual: true,
            events: true,
            rtol: 1e-3,
            atol: None,
            substeps: 1,
            hht_alpha: -0.05,
            par: faer::Par::rayon(0),
            lanczos: Lanczos::default(),
        }
    }
}

impl SimRequest {
    /// Checks the values that do not need the model and returns the number of steps.
    pub fn check(&self) -> Result<usize> {
        let usage = |m: String| Error::Usage(format!("simulation request: {m}"));
        if !(self.duration > 0.0 && self.duration.is_finite()) {
            return Err(usage(format!(
                "duration {} must be a positive number of seconds",
                self.duration
            )));
        }
        if !(self.rate > 0.0 && self.rate.is_finite()) {
            return Err(usage(format!(
                "rate {} must be a positive frequency in Hz",
                self.rate
            )));
        }
        if self.modes == 0 {
            return Err(usage("modes must be at least 1".into()));
        }
        let n_steps = (self.duration * self.rate).round() as usize;
        if n_steps == 0 || n_steps > 200_000_000 {
            return Err(usage(format!(
                "duration x rate gives {n_steps} steps; it must be between 1 and 2e8"
            )));
        }
        for d in &self.excitation {
            nyquist_check(&d.label, &d.signal, self.rate)?;
        }
        Ok(n_steps)
    }

    /// Notes on drives that stop before the run ends (a force file shorter than the run: the
    /// force is zero after its last sample, as for a hammer blow).
    pub fn notes(&self) -> Vec<String> {
        self.excitation
            .iter()
            .filter_map(|d| match &d.signal {
                Signal::Sampled { rate_hz, values } => {
                    let end = values.len().saturating_sub(1) as f64 / rate_hz;
                    (end < self.duration - 0.5 / self.rate).then(|| {
                        format!(
                            "note: the force '{}' ends at {end} s ({} samples at {rate_hz} Hz) \
                             and is zero for the rest of the {} s run",
                            d.label,
                            values.len(),
                            self.duration
                        )
                    })
                }
                _ => None,
            })
            .collect()
    }
}

/// The retained mode count as a summary prints it: `20`, or `all 3` when the request asked
/// for more modes than the model has.
fn modes_text(kept: usize, asked: usize) -> String {
    if asked > kept {
        format!("all {kept}")
    } else {
        kept.to_string()
    }
}

/// The note when more modes were kept than asked: the rest complete a degenerate cluster.
pub(crate) fn cluster_note(kept: usize, asked: usize) -> Option<String> {
    (kept > asked && asked > 0).then(|| {
        let which = if kept == asked + 1 {
            format!("mode {kept} is kept with mode {asked}")
        } else {
            format!("modes {}-{kept} are kept with mode {asked}", asked + 1)
        };
        format!("{which}: equal frequencies (to 1e-8), and a degenerate cluster is not split at the cut-off")
    })
}

/// `v` in plain notation in the usual range, in scientific notation beyond it.
fn short(v: f64) -> String {
    if v == 0.0 || (1e-3..1e7).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// Refuses a force with content above the Nyquist frequency of the sample rate `rate` (Hz):
/// the step (FOH, ZOH, LSOH) or the output samples (the others) would alias it.
fn nyquist_check(label: &str, signal: &Signal, rate: f64) -> Result<()> {
    if let Some(f) = signal.max_frequency_hz()
        && f > 0.5 * rate
    {
        return Err(Error::Usage(format!(
            "excitation '{label}': {} Hz is above the Nyquist frequency {} Hz of the {} Hz \
             rate, which would alias it; give a rate above {} Hz",
            short(f),
            short(0.5 * rate),
            short(rate),
            short(2.0 * f)
        )));
    }
    Ok(())
}

/// A computed time response.
pub struct SimRun {
    /// The time history.
    pub history: TimeHistory,
    /// The excitation spec used at each excitation point.
    pub excitation: Vec<String>,
    /// Retained modes (0 for the unreduced methods).
    pub modes: usize,
    /// Wall time of the reduction or of the effective-stiffness factorisation (s).
    pub setup_seconds: f64,
    /// Stored states of the reduced model (0 for the unreduced methods).
    pub states: usize,
    /// Flops per state and step of the FOH loop (0 for the other methods).
    pub flops_per_state_step: usize,
    /// RK45's absolute tolerance and whether it was scaled to the response (RK45 only).
    pub atol: Option<(f64, bool)>,
}

/// RK45's absolute tolerance scaled to the response (√kg m): `10⁻³ rtol z_ref`, with
/// `z_ref = max_s Σ_i |b̃_{s,i}| F_i / |λ_s|` the largest static amplitude of a modal state
/// under the peak excitation forces `F_i` (sampled over the run). ODE45's fixed default 1e-6
/// is as large as the states of a typical structure (10⁻⁶–10⁻⁴ √kg m) and was measured 17 % and
/// 89 % off on the clearance beams; relative to the response, `rtol` governs. Rigid-body states
/// (`λ = 0`) are left out; with no force at all the floor is 1e-15.
pub fn auto_atol(plant: &Plant, forces: &[Signal], dt: f64, n_steps: usize, rtol: f64) -> f64 {
    let peaks: Vec<f64> = forces
        .iter()
        .map(|f| {
            (0..=n_steps)
                .map(|k| f.eval(k as f64 * dt).abs())
                .fold(0.0, f64::max)
        })
        .collect();
    let sys = &plant.system;
    let z_ref = (0..sys.n_states())
        .filter(|&s| sys.poles[s].norm() > 0.0)
        .map(|s| {
            plant
                .inputs
                .iter()
                .zip(&peaks)
                .map(|((_, p), f)| sys.input[(s, *p)].norm() * f)
                .sum::<f64>()
                / sys.poles[s].norm()
        })
        .fold(0.0, f64::max);
    (1e-3 * rtol * z_ref).max(1e-15)
}

/// The periodic force of excitation point `x` at fundamental `fundamental_hz`: its amplitude
/// as a cosine and its further harmonics, in the convention of `docs/model-files.md`.
pub fn point_multisine(x: &nlsim_kernel::Excitation, fundamental_hz: f64) -> Signal {
    let mut harmonics = vec![nlsim_sim::Harmonic {
        ratio: 1.0,
        amplitude: faer::c64::new(x.amplitude, 0.0),
    }];
    harmonics.extend(x.harmonics.iter().map(|h| nlsim_sim::Harmonic {
        ratio: h.ratio(),
        amplitude: h.complex(),
    }));
    Signal::MultiSine {
        fundamental_hz,
        harmonics,
    }
}

/// One signal and label per excitation point: a sine at `f1` (Hz, to 1 µHz) of the point's
/// nominal amplitude everywhere, then `drives` in order.
fn point_signals(model: &Model, drives: &[Drive], f1: f64) -> Result<(Vec<Signal>, Vec<String>)> {
    let points = model.excitation();
    let f1: f64 = format!("{f1:.6}").parse().expect("a formatted number");
    let mut signals: Vec<Signal> = points
        .iter()
        .map(|x| Signal::sine(x.amplitude, f1))
        .collect();
    let mut labels: Vec<String> = points
        .iter()
        .map(|_| format!("sine:freq={f1:.6}"))
        .collect();
    for (d, drive) in drives.iter().enumerate() {
        let targets: Vec<usize> = match &drive.point {
            None => (0..points.len()).collect(),
            Some(name) => vec![points.iter().position(|x| &x.name == name).ok_or_else(|| {
                Error::Usage(format!(
                    "simulation request: excitation[{d}] ('{}'): no excitation point '{name}' \
                     (the model has {})",
                    drive.label,
                    points
                        .iter()
                        .map(|x| x.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ))
            })?],
        };
        for i in targets {
            signals[i] = if drive.nominal {
                match &drive.signal {
                    // A multisine that names no harmonic: the point's own forcing.
                    Signal::MultiSine { fundamental_hz, .. } => {
                        point_multisine(&points[i], *fundamental_hz)
                    }
                    s => s.scaled(points[i].amplitude),
                }
            } else {
                drive.signal.clone()
            };
            labels[i] = drive.label.clone();
        }
    }
    Ok((signals, labels))
}

/// Integrates `model` as `req` asks, calling `progress(samples done, total)` about 200 times
/// whatever the method.
pub fn run_simulation(
    model: &Model,
    req: &SimRequest,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<SimRun> {
    run_simulation_shared(model, req, progress, &Reductions::default())
}

/// As [`run_simulation`], taking the reduction from `reductions` when a run of the same linear
/// model made it (a batch's jobs).
pub fn run_simulation_shared(
    model: &Model,
    req: &SimRequest,
    progress: &mut dyn FnMut(usize, usize),
    reductions: &Reductions,
) -> Result<SimRun> {
    let n_steps = req.check()?;
    let dt = 1.0 / req.rate;
    if model.excitation().is_empty() && !req.excitation.is_empty() {
        return Err(Error::Usage(format!(
            "model '{}' has no excitation points to drive",
            model.name()
        )));
    }
    let unreduced = req.method.unreduced();
    let modes = if unreduced {
        1
    } else {
        req.modes.min(model.n_dofs())
    };
    let t0 = Instant::now();
    let reduced = reductions.get(model, modes, req.residual, req.par, req.lanczos)?;
    let modes = if unreduced { 0 } else { reduced.modes.len() };
    let f1 = reduced.modes.frequencies_hz()[0];
    let reduce_seconds = t0.elapsed().as_secs_f64();
    let (forces, excitation) = point_signals(model, &req.excitation, f1)?;
    for (signal, label) in forces.iter().zip(&excitation) {
        nyquist_check(label, signal, req.rate)?;
    }
    let case = LoadCase::new("simulate", forces);
    if unreduced {
        let mut cfg = NewmarkConfig::new(dt);
        cfg.substeps = req.substeps;
        cfg.alpha = if req.method == Method::Hht {
            req.hht_alpha
        } else {
            0.0
        };
        let nm = Newmark::new(model, &cfg)?;
        let history = nm.run_with_progress(&case, n_steps, progress)?;
        return Ok(SimRun {
            history,
            excitation,
            modes: 0,
            setup_seconds: nm.setup_seconds,
            states: 0,
            flops_per_state_step: 0,
            atol: None,
        });
    }
    let system = ModalSystem::new(&reduced)?;
    let plant = Plant::from_model(model, &system)?;
    let mut flops = 0;
    let mut atol = None;
    let history = match req.method {
        Method::Foh | Method::Zoh | Method::Lsoh => {
            let mut cfg = FohConfig::new(dt);
            cfg.hold = match req.method {
                Method::Zoh => Hold::Zoh,
                Method::Lsoh => Hold::Lsoh,
                _ => Hold::Foh,
            };
            cfg.locate_events = req.events;
            let sim = Simulator::new(&plant, &cfg)?;
            flops = sim.flops_per_state_step();
            sim.run_with_progress(&case, n_steps, progress)?
        }
        Method::Rk45 => {
            let a = req
                .atol
                .unwrap_or_else(|| auto_atol(&plant, &case.forces, dt, n_steps, req.rtol));
            atol = Some((a, req.atol.is_none()));
            nlsim_sim::rk45_with_progress(
                &plant,
                &case,
                dt,
                n_steps,
                &Rk45Config {
                    rtol: req.rtol,
                    atol: a,
                    ..Default::default()
                },
                progress,
            )?
        }
        _ => nlsim_sim::rk4_with_progress(
            &plant,
            &case,
            dt,
            n_steps,
            &Rk4Config {
                substeps: req.substeps,
                ..Default::default()
            },
            progress,
        )?,
    };
    Ok(SimRun {
        history,
        excitation,
        modes,
        setup_seconds: reduce_seconds,
        states: system.n_states(),
        flops_per_state_step: flops,
        atol,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nlsim_kernel::Param;

    #[test]
    fn a_reduction_is_shared_exactly_when_the_linear_model_is_the_same() {
        let model = nlsim_fixtures::ecl_beam().model;
        let key = |m: &Model, modes: usize, residual: bool| {
            reduction_key(m, modes, residual, Lanczos::default()).unwrap()
        };
        let base = key(&model, 10, true);
        // Element parameters act through the ports: the same reduction.
        let mut softer = model.clone();
        softer
            .set_param(
                &Param::Element {
                    element: "tip_spring".into(),
                    param: "k3".into(),
                },
                1e3,
            )
            .unwrap();
        assert_eq!(key(&softer, 10, true), base);
        // Another mode count, no residual flexibility, a grounded spring (K changes), another
        // damping: each its own.
        assert_ne!(key(&model, 11, true), base);
        assert_ne!(key(&model, 10, false), base);
        let mut sprung = model.clone();
        sprung.add_boundary_spring(5, 1e3).unwrap();
        assert_ne!(key(&sprung, 10, true), base);
        let mut damped = model.clone();
        damped
            .set_damping(nlsim_kernel::Damping::Rayleigh {
                alpha: 1.0,
                beta: 0.0,
            })
            .unwrap();
        assert_ne!(key(&damped, 10, true), base);

        // Shared reductions are the ones a run computes for itself, bit for bit.
        let shared = Reductions::default();
        let a = shared
            .get(&model, 10, true, faer::Par::Seq, Lanczos::default())
            .unwrap();
        let b = shared
            .get(&softer, 10, true, faer::Par::Seq, Lanczos::default())
            .unwrap();
        let c = shared
            .get(&sprung, 10, true, faer::Par::Seq, Lanczos::default())
            .unwrap();
        assert!(Arc::ptr_eq(&a, &b) && !Arc::ptr_eq(&a, &c));
        assert_eq!(shared.counts(), (2, 1));
        let fresh = reduce(&softer, 10, true, faer::Par::Seq, Lanczos::default()).unwrap();
        assert_eq!(fresh.modes.eigenvalues, b.modes.eigenvalues);
        assert_eq!(fresh.residual, b.residual);
        assert_eq!(fresh.participation, b.participation);
    }
}
