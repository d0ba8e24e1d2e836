//! The harmonic balance system condensed on the nonlinear DOFs (thesis §3.2, paper I).
//!
//! Unknowns: the coefficients `x` of every element coordinate (`n_NL × (2H+1)` reals; a law
//! on several coordinates has one block of `2H+1` per coordinate, consecutive). Per
//! harmonic `k` the reduced model's receptances give
//!
//! `R(x) = x + H_NL,NL(kω0) G(x) − λ H_NL,ext(kω0) F = 0`
//!
//! (the element forces `G` act on the structure with a minus sign; `λ` is the force level).
//! Any sensor is recovered from the same receptances, `Y = λ H_s,ext F − H_s,NL G`.

use crate::aft::{AftPlan, AftScratch, samples_for};
use crate::dense::{Lu, LuInPlace, norm_inf};
use crate::harmonics::{Forcing, HarmonicSet};
use crate::linear::{LinearPart, LinearVariation};
use faer::{Mat, c64};
use nlsim_kernel::param::{element_parameters, find_element_param, unknown_param};
use nlsim_kernel::{
    Error, Model, NonlinearElement, Param, Parameterized, Quantity, Result, Status,
};
use nlsim_reduction::ReducedModel;
use std::f64::consts::PI;

/// A response output: a quantity at a port.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorSpec {
    /// The sensor's name.
    pub name: String,
    /// Port index of the reduced model.
    pub port: usize,
    /// Displacement (m), velocity (m/s) or acceleration (m/s²).
    pub quantity: Quantity,
}

/// Settings of the harmonic balance solver.
#[derive(Debug, Clone, PartialEq)]
pub struct HbConfig {
    /// AFT samples per period for every element; `None` picks them per law
    /// ([`crate::aft::samples_for`]).
    pub aft_samples: Option<usize>,
    /// Newton iterations before giving up.
    pub max_iterations: usize,
    /// Convergence: `‖R‖∞ ≤ rtol · max(‖x‖∞, ‖λ H F‖∞)`.
    pub rtol: f64,
    /// Most modes kept dynamic in Hill's method (the lowest, those below `(H + ½) ω0`); the
    /// others enter as quasi-static flexibility.
    pub hill_max_modes: usize,
}

impl Default for HbConfig {
    fn default() -> Self {
        Self {
            aft_samples: None,
            max_iterations: 40,
            rtol: 1e-10,
            hill_max_modes: 16,
        }
    }
}

/// How a Newton solve went: its status, the iterations taken and the final residual.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonReport {
    /// [`Status::Converged`], or why it stopped: [`Status::IterationLimit`],
    /// [`Status::Singular`] (a singular Jacobian), [`Status::NonFinite`].
    pub status: Status,
    /// Iterations taken.
    pub iterations: usize,
    /// Final `‖R‖∞` (m).
    pub residual: f64,
}

impl NewtonReport {
    /// `true` when the solve converged.
    pub fn converged(&self) -> bool {
        self.status.is_converged()
    }
}

/// Sensitivity of a solution to one parameter.
#[derive(Debug, Clone)]
pub struct Sensitivity {
    /// The parameter.
    pub param: Param,
    /// `dx/dp` of the condensed unknowns.
    pub dx: Vec<f64>,
    /// `dY/dp` of every sensor (rows) and harmonic `k = 0..=H` (columns), in the sensor's unit
    /// per parameter unit.
    pub dy: Mat<c64>,
}

/// The residual and an input port's displacement with their Jacobians
/// ([`HbSystem::input_coupling`]); real layout, `n` unknowns, `2H+1` force coefficients.
#[derive(Debug, Clone)]
pub struct InputCoupling {
    /// `R(x)` (n, m).
    pub r: Vec<f64>,
    /// `∂R/∂x` (n × n).
    pub r_x: Mat<f64>,
    /// `∂R/∂F` (n × (2H+1), m/N).
    pub r_f: Mat<f64>,
    /// `X_d` (2H+1, m).
    pub xd: Vec<f64>,
    /// `∂X_d/∂x` ((2H+1) × n).
    pub xd_x: Mat<f64>,
    /// `∂X_d/∂F` ((2H+1) × (2H+1), m/N).
    pub xd_f: Mat<f64>,
}

/// What a sensitivity is taken along: a parameter of the system, or a variation of its
/// linear part's data.
enum Direction<'a> {
    Param(&'a Param),
    Variation(&'a LinearVariation),
}

/// Receptances at the harmonics of one frequency, in the real coefficient layout.
pub(crate) struct Receptances {
    /// `H_NL,NL` (n_x × n_x).
    pub a: Mat<f64>,
    /// `H_NL,ext F` (n_x): the linear response to unit force level.
    pub b: Vec<f64>,
}

/// One evaluation of the residual.
pub(crate) struct Evaluation {
    pub r: Vec<f64>,
    pub g: Vec<f64>,
    /// Per element `∂G_e/∂x_e` (a block per pair of its coordinates).
    pub dg: Vec<Mat<f64>>,
    pub jacobian: Option<Mat<f64>>,
}

/// The forcing-independent receptances at one frequency, in the real coefficient layout.
#[derive(Debug, Clone)]
pub(crate) struct ReceptanceParts {
    /// `H_NL,NL` (n_x × n_x).
    pub a: Mat<f64>,
    /// `H_NL,ext` (n_x × inputs·(2H+1)).
    pub ext: Mat<f64>,
}

impl Default for ReceptanceParts {
    fn default() -> Self {
        Self {
            a: Mat::new(),
            ext: Mat::new(),
        }
    }
}

/// The buffers of one residual evaluation ([`HbSystem::evaluate_into`]).
#[derive(Debug)]
pub(crate) struct EvalBuffers {
    aft: AftScratch,
    g: Vec<f64>,
    /// The residual `R`.
    pub(crate) r: Vec<f64>,
    dg: Vec<Mat<f64>>,
    damping: Vec<Vec<f64>>,
    /// `∂R/∂x` (when asked for).
    pub(crate) jac: Mat<f64>,
}

impl Default for EvalBuffers {
    fn default() -> Self {
        Self {
            aft: Default::default(),
            g: Default::default(),
            r: Default::default(),
            dg: Default::default(),
            damping: Default::default(),
            jac: Mat::new(),
        }
    }
}

impl EvalBuffers {
    /// Sizes the buffers for elements with coordinates `offsets` ([`HbSystem::coordinates`])
    /// of `nh` coefficients (allocates only when they change).
    fn size(&mut self, offsets: &[usize], nh: usize) {
        let ne = offsets.len() - 1;
        let n = offsets[ne] * nh;
        self.g.resize(n, 0.0);
        self.r.resize(n, 0.0);
        let fits = self.dg.len() == ne
            && self
                .dg
                .iter()
                .zip(offsets.windows(2))
                .all(|(d, o)| d.nrows() == (o[1] - o[0]) * nh);
        if !fits {
            self.dg = offsets
                .windows(2)
                .map(|o| Mat::zeros((o[1] - o[0]) * nh, (o[1] - o[0]) * nh))
                .collect();
        }
        self.damping.resize_with(ne, Vec::new);
        if self.jac.nrows() != n {
            self.jac = Mat::zeros(n, n);
        }
    }
}

/// The buffers of [`HbSystem::evaluate_along`]: an evaluation's, the receptances and their
/// `Ω`-derivatives, and the samples of `∂G/∂Ω`. Sized on first use; no allocation after.
#[derive(Debug, Default)]
pub(crate) struct PathBuffers {
    /// The evaluation: `R` in `ev.r`, `∂R/∂x` in `ev.jac`.
    pub(crate) ev: EvalBuffers,
    /// `∂R/∂p` of the followed parameter.
    pub(crate) rp: Vec<f64>,
    parts: ReceptanceParts,
    dparts: ReceptanceParts,
    f: Vec<f64>,
    b: Vec<f64>,
    db: Vec<f64>,
    dg: Vec<f64>,
    u: Vec<f64>,
    v: Vec<f64>,
    smp: Vec<f64>,
}

/// The buffers of one Newton solve: an evaluation's, and the force, step and LU.
#[derive(Debug, Default)]
pub(crate) struct Scratch {
    ev: EvalBuffers,
    /// Force coefficients (inputs × (2H+1)).
    f: Vec<f64>,
    /// `H_NL,ext F`.
    b: Vec<f64>,
    dx: Vec<f64>,
    xt: Vec<f64>,
    lu: LuInPlace,
}

/// Receptances by frequency (the bits of `Ω`), first in first out beyond `capacity`.
#[derive(Debug)]
struct ReceptanceCache {
    capacity: usize,
    entries: std::collections::HashMap<u64, ReceptanceParts>,
    order: std::collections::VecDeque<u64>,
    hits: usize,
    misses: usize,
}

impl ReceptanceCache {
    fn new(capacity: usize) -> Self {
        Self {
            capacity: capacity.max(1),
            entries: std::collections::HashMap::new(),
            order: std::collections::VecDeque::new(),
            hits: 0,
            misses: 0,
        }
    }

    fn clear(&mut self) {
        self.entries.clear();
        self.order.clear();
    }

    fn get_or_insert(
        &mut self,
        omega: f64,
        make: impl FnOnce() -> ReceptanceParts,
    ) -> &ReceptanceParts {
        let key = omega.to_bits();
        if self.entries.contains_key(&key) {
            self.hits += 1;
        } else {
            self.misses += 1;
            if self.entries.len() >= self.capacity
                && let Some(old) = self.order.pop_front()
            {
                self.entries.remove(&old);
            }
            self.entries.insert(key, make());
            self.order.push_back(key);
        }
        &self.entries[&key]
    }
}

/// Reusable state of [`HbSystem::solve_with`]: the receptances of the frequencies already
/// solved (valid while the system's linear part is unchanged: a change of a modal parameter
/// or [`HbSystem::set_linear`] empties it; element parameters and the forcing do not) and
/// every buffer of the Newton iteration. One per thread; made by [`HbSystem::workspace`].
#[derive(Debug)]
pub struct HbWorkspace {
    /// Stamp of the linear part the cache holds.
    stamp: u64,
    cache: ReceptanceCache,
    scratch: Scratch,
}

impl Clone for HbWorkspace {
    /// An empty workspace of the same capacity (for one clone per parallel task).
    fn clone(&self) -> Self {
        Self::with_capacity(self.cache.capacity)
    }
}

impl HbWorkspace {
    /// A workspace caching the receptances of at most `frequencies` frequencies (at least 1).
    pub fn with_capacity(frequencies: usize) -> Self {
        Self {
            stamp: 0,
            cache: ReceptanceCache::new(frequencies),
            scratch: Scratch::default(),
        }
    }

    /// Frequencies whose receptances the cache can hold.
    pub fn capacity(&self) -> usize {
        self.cache.capacity
    }

    /// Solves that found their frequency in the cache, and those that computed it.
    pub fn cache_counts(&self) -> (usize, usize) {
        (self.cache.hits, self.cache.misses)
    }

    /// Serves `sys` from now on: empties the cache if it holds another linear part.
    fn bind(&mut self, sys: &HbSystem) {
        if self.stamp != sys.stamp {
            self.cache.clear();
            self.stamp = sys.stamp;
        }
    }
}

/// A stamp no system has had: identifies a linear part for the receptance caches.
fn next_stamp() -> u64 {
    use std::sync::atomic::{AtomicU64, Ordering};
    static NEXT: AtomicU64 = AtomicU64::new(1);
    NEXT.fetch_add(1, Ordering::Relaxed)
}

/// The harmonic balance system of a reduced model with local nonlinearities.
///
/// Built by [`HbSystem::from_model`] or [`HbSystem::builder`]; its parts are read through
/// accessors and changed only through methods that keep the derived AFT plans consistent
/// ([`Parameterized::set_param`], [`HbSystem::set_forcing`]).
#[derive(Debug, Clone)]
pub struct HbSystem {
    pub(crate) set: HarmonicSet,
    pub(crate) linear: LinearPart,
    pub(crate) elements: Vec<NonlinearElement>,
    /// Port of every element coordinate (one per element, several for a coupled law).
    pub(crate) element_ports: Vec<usize>,
    /// First coordinate of each element, and the total (`elements + 1` entries).
    pub(crate) offsets: Vec<usize>,
    pub(crate) inputs: Vec<(String, usize)>,
    pub(crate) sensors: Vec<SensorSpec>,
    pub(crate) forcing: Forcing,
    pub(crate) config: HbConfig,
    plans: Vec<AftPlan>,
    hill_plan: AftPlan,
    /// Changes with the linear part (the receptances), see [`HbWorkspace`].
    stamp: u64,
}

/// Assembles an [`HbSystem`] from a [`LinearPart`] part by part:
/// `HbSystem::builder(linear, set).element(e, port).input("shaker", 0).build()?`.
/// Validation (ports in range, laws, forcing) happens once, in [`HbSystemBuilder::build`].
#[derive(Debug, Clone)]
#[must_use = "a builder does nothing until build() is called"]
pub struct HbSystemBuilder {
    set: HarmonicSet,
    linear: LinearPart,
    elements: Vec<NonlinearElement>,
    element_ports: Vec<Vec<usize>>,
    inputs: Vec<(String, usize)>,
    sensors: Vec<SensorSpec>,
    forcing: Option<Forcing>,
    config: HbConfig,
}

impl HbSystemBuilder {
    /// A nonlinear element acting on port `port` (its coupling already folded into the port).
    pub fn element(mut self, element: NonlinearElement, port: usize) -> Self {
        self.elements.push(element);
        self.element_ports.push(vec![port]);
        self
    }

    /// A nonlinear element whose law acts on several coordinates, at ports `ports` (one per
    /// coordinate, in the law's order).
    pub fn coupled_element(mut self, element: NonlinearElement, ports: &[usize]) -> Self {
        self.elements.push(element);
        self.element_ports.push(ports.to_vec());
        self
    }

    /// An excitation input called `name` at port `port`.
    pub fn input(mut self, name: impl Into<String>, port: usize) -> Self {
        self.inputs.push((name.into(), port));
        self
    }

    /// A sensor recovered at every solution.
    pub fn sensor(mut self, name: impl Into<String>, port: usize, quantity: Quantity) -> Self {
        self.sensors.push(SensorSpec {
            name: name.into(),
            port,
            quantity,
        });
        self
    }

    /// The forcing at level `λ = 1` (default: unit amplitude on every input at the
    /// fundamental, harmonic `ν`).
    pub fn forcing(mut self, forcing: Forcing) -> Self {
        self.forcing = Some(forcing);
        self
    }

    /// Solver settings (default [`HbConfig::default`]).
    pub fn config(mut self, config: HbConfig) -> Self {
        self.config = config;
        self
    }

    /// The validated system.
    pub fn build(mut self) -> Result<HbSystem> {
        let forcing = self.forcing.take().unwrap_or_else(|| Forcing {
            terms: (0..self.inputs.len())
                .map(|i| crate::ForceTerm {
                    input: i,
                    harmonic: self.set.nu,
                    amplitude: c64::new(1.0, 0.0),
                })
                .collect(),
        });
        HbSystem::new(self, forcing)
    }
}

/// Expands per-harmonic complex matrices into the real coefficient layout
/// (`rows·(2H+1) × cols·(2H+1)`): `h·(c − is)` ↦ `[[h_r, h_i], [−h_i, h_r]] [c; s]`.
pub(crate) fn expand(set: &HarmonicSet, h: &[Mat<c64>]) -> Mat<f64> {
    let nh = set.len();
    let (nr, nc) = (h[0].nrows(), h[0].ncols());
    let mut a = Mat::<f64>::zeros(nr * nh, nc * nh);
    for i in 0..nr {
        for j in 0..nc {
            a[(i * nh, j * nh)] = h[0][(i, j)].re;
            for k in 1..=set.h {
                let z = h[k][(i, j)];
                let (r, c) = (i * nh + 2 * k - 1, j * nh + 2 * k - 1);
                a[(r, c)] = z.re;
                a[(r, c + 1)] = z.im;
                a[(r + 1, c)] = -z.im;
                a[(r + 1, c + 1)] = z.re;
            }
        }
    }
    a
}

impl HbSystem {
    /// The system of `model` reduced to `reduced`: the model's elements (matched to their
    /// ports by name), its excitation points as inputs forced at the fundamental with their
    /// nominal amplitudes and at their further harmonics ([`Forcing::from_excitation`]), and
    /// its sensors.
    pub fn from_model(
        model: &Model,
        reduced: &ReducedModel,
        set: HarmonicSet,
        config: HbConfig,
    ) -> Result<Self> {
        let map = nlsim_reduction::model_port_map(model, &reduced.ports)?;
        let sensors = map
            .sensors
            .into_iter()
            .map(|(name, port, quantity)| SensorSpec {
                name,
                port,
                quantity,
            })
            .collect();
        let forcing = Forcing::from_excitation(&set, model.excitation())?;
        HbSystemBuilder {
            set,
            linear: LinearPart::from_reduced(reduced)?,
            elements: model.elements().to_vec(),
            element_ports: map.element_coordinates,
            inputs: map.inputs,
            sensors,
            forcing: Some(forcing),
            config,
        }
        .build()
    }

    /// A builder on the linear part `linear` with harmonics `set`.
    pub fn builder(linear: LinearPart, set: HarmonicSet) -> HbSystemBuilder {
        HbSystemBuilder {
            set,
            linear,
            elements: Vec::new(),
            element_ports: Vec::new(),
            inputs: Vec::new(),
            sensors: Vec::new(),
            forcing: None,
            config: HbConfig::default(),
        }
    }

    /// The system of a builder's parts with `forcing`; validates ports, laws and forcing.
    fn new(parts: HbSystemBuilder, forcing: Forcing) -> Result<Self> {
        let HbSystemBuilder {
            set,
            linear,
            elements,
            element_ports,
            inputs,
            sensors,
            config,
            ..
        } = parts;
        let np = linear.phi.nrows();
        let bad = |what: String, p: usize| {
            Error::invalid(what, format!("port {p} is out of range ({np} ports)"))
        };
        for (e, ports) in elements.iter().zip(&element_ports) {
            if ports.len() != e.law().arity() {
                return Err(Error::invalid(
                    format!("element '{}'", e.name()),
                    format!(
                        "its {} law acts on {} coordinate(s) but {} port(s) are given",
                        e.law().kind(),
                        e.law().arity(),
                        ports.len()
                    ),
                ));
            }
            for &p in ports {
                if p >= np {
                    return Err(bad(format!("element '{}'", e.name()), p));
                }
            }
            e.law().validate(e.name())?;
        }
        let mut offsets = vec![0];
        for ports in &element_ports {
            offsets.push(offsets.last().copied().unwrap_or(0) + ports.len());
        }
        let element_ports: Vec<usize> = element_ports.into_iter().flatten().collect();
        for (n, p) in &inputs {
            if *p >= np {
                return Err(bad(format!("input '{n}'"), *p));
            }
        }
        for s in &sensors {
            if s.port >= np {
                return Err(bad(format!("sensor '{}'", s.name), s.port));
            }
        }
        forcing.validate(&set, inputs.len())?;
        let plans = elements
            .iter()
            .map(|e| {
                AftPlan::new(
                    set,
                    config.aft_samples.unwrap_or(samples_for(e.law(), &set)),
                )
            })
            .collect::<Result<Vec<_>>>()?;
        let hill_n = plans.iter().map(|p| p.n).max().unwrap_or(4 * set.h + 2);
        let hill_plan = AftPlan::new(set, hill_n)?;
        Ok(Self {
            set,
            linear,
            elements,
            element_ports,
            offsets,
            inputs,
            sensors,
            forcing,
            config,
            plans,
            hill_plan,
            stamp: next_stamp(),
        })
    }

    /// Number of condensed unknowns, `n_NL (2H + 1)` with `n_NL` the element coordinates.
    pub fn n_unknowns(&self) -> usize {
        self.element_ports.len() * self.set.len()
    }

    /// Number of element coordinates `n_NL` (one per element, [`nlsim_kernel::Law::arity`]
    /// for a coupled law).
    pub fn n_coordinates(&self) -> usize {
        self.element_ports.len()
    }

    /// The coordinates of element `e` (indices into [`HbSystem::element_ports`]).
    pub fn coordinates(&self, e: usize) -> std::ops::Range<usize> {
        self.offsets[e]..self.offsets[e + 1]
    }

    /// The unknowns of element `e` in `x`: its coordinates' coefficients.
    pub(crate) fn unknowns(&self, e: usize) -> std::ops::Range<usize> {
        let nh = self.set.len();
        self.offsets[e] * nh..self.offsets[e + 1] * nh
    }

    /// AFT samples per period of each element.
    pub fn aft_samples(&self) -> Vec<usize> {
        self.plans.iter().map(|p| p.n).collect()
    }

    /// The harmonics kept.
    pub fn harmonics(&self) -> &HarmonicSet {
        &self.set
    }

    /// Receptances of the reduced model.
    pub fn linear(&self) -> &LinearPart {
        &self.linear
    }

    /// Replaces the linear part by `linear`, e.g. the model reduced again after an FE-level
    /// parameter changed. It must have the same ports (the elements, inputs and sensors stay
    /// on them); the number of modes may differ.
    pub fn set_linear(&mut self, linear: LinearPart) -> Result<()> {
        let (np, nn) = (self.linear.phi.nrows(), linear.phi.nrows());
        if np != nn {
            return Err(Error::DimensionMismatch {
                what: "ports of the new linear part".into(),
                expected: np,
                found: nn,
            });
        }
        self.linear = linear;
        self.stamp = next_stamp();
        Ok(())
    }

    /// The nonlinear elements (couplings folded into their ports).
    pub fn elements(&self) -> &[NonlinearElement] {
        &self.elements
    }

    /// Port index of each element coordinate (one per element; a coupled element's
    /// coordinates are consecutive, see [`HbSystem::coordinates`]).
    pub fn element_ports(&self) -> &[usize] {
        &self.element_ports
    }

    /// Excitation inputs `(name, port)`.
    pub fn inputs(&self) -> &[(String, usize)] {
        &self.inputs
    }

    /// Sensors recovered at every solution.
    pub fn sensors(&self) -> &[SensorSpec] {
        &self.sensors
    }

    /// The forcing at level `λ = 1`.
    pub fn forcing(&self) -> &Forcing {
        &self.forcing
    }

    /// Solver settings.
    pub fn config(&self) -> &HbConfig {
        &self.config
    }

    /// Replaces the forcing (validated against the harmonics and inputs).
    pub fn set_forcing(&mut self, forcing: Forcing) -> Result<()> {
        forcing.validate(&self.set, self.inputs.len())?;
        self.forcing = forcing;
        Ok(())
    }

    /// Adds a sensor `name` of `quantity` at port `port` (an output only: the solution does
    /// not change). Errors when the port is out of range or the name is taken.
    pub fn add_sensor(
        &mut self,
        name: impl Into<String>,
        port: usize,
        quantity: Quantity,
    ) -> Result<()> {
        let name = name.into();
        let np = self.linear.phi.nrows();
        if port >= np {
            return Err(Error::invalid(
                format!("sensor '{name}'"),
                format!("port {port} is out of range ({np} ports)"),
            ));
        }
        if self.sensors.iter().any(|s| s.name == name) {
            return Err(Error::invalid(
                format!("sensor '{name}'"),
                "the system has a sensor of that name",
            ));
        }
        self.sensors.push(SensorSpec {
            name,
            port,
            quantity,
        });
        Ok(())
    }

    /// Index of element `name`.
    pub fn element_index(&self, name: &str) -> Result<usize> {
        self.elements
            .iter()
            .position(|e| e.name() == name)
            .ok_or_else(|| Error::invalid(format!("element '{name}'"), "no such element"))
    }

    /// `(element index, law parameter index)` of an element parameter.
    fn element_param(&self, p: &Param) -> Option<(usize, usize)> {
        find_element_param(&self.elements, p)
    }

    /// The forcing in the real layout (inputs × (2H+1)).
    fn force_coefficients(&self) -> Vec<f64> {
        let mut f = Vec::new();
        self.force_coefficients_into(&mut f);
        f
    }

    /// [`HbSystem::force_coefficients`] into `f` (resized).
    fn force_coefficients_into(&self, f: &mut Vec<f64>) {
        let nh = self.set.len();
        f.clear();
        f.resize(self.inputs.len() * nh, 0.0);
        for i in 0..self.inputs.len() {
            for k in 0..=self.set.h {
                let z = self.forcing.amplitude(i, k);
                self.set.set_complex(&mut f[i * nh..(i + 1) * nh], k, z);
            }
        }
    }

    /// Per-harmonic receptances from `rows` to `cols` at fundamental `omega`; with `deriv`,
    /// their derivative with respect to `Ω` instead.
    fn harmonic_receptances(
        &self,
        omega: f64,
        rows: &[usize],
        cols: &[usize],
        deriv: bool,
    ) -> Vec<Mat<c64>> {
        let w0 = self.set.base(omega);
        (0..=self.set.h)
            .map(|k| {
                let w = k as f64 * w0;
                if deriv {
                    self.linear.receptance_domega(w, rows, cols)
                        * faer::Scale(c64::new(k as f64 / self.set.nu as f64, 0.0))
                } else {
                    self.linear.receptance(w, rows, cols)
                }
            })
            .collect()
    }

    fn input_ports(&self) -> Vec<usize> {
        self.inputs.iter().map(|x| x.1).collect()
    }

    /// `H_NL,NL` and `H_NL,ext F` at `omega` (or their `Ω`-derivatives).
    pub(crate) fn receptances(&self, omega: f64, deriv: bool) -> Receptances {
        let parts = self.receptance_parts(omega, deriv);
        let mut f = Vec::new();
        let mut b = Vec::new();
        self.forced(&parts, &mut f, &mut b);
        Receptances { a: parts.a, b }
    }

    /// The forcing-independent receptances at `omega`: `H_NL,NL` and `H_NL,ext` in the real
    /// layout (or their `Ω`-derivatives).
    fn receptance_parts(&self, omega: f64, deriv: bool) -> ReceptanceParts {
        let mut out = ReceptanceParts::default();
        self.receptance_parts_into(omega, deriv, &mut out);
        out
    }

    /// [`HbSystem::receptance_parts`] into `out`. With proportional damping (a diagonal
    /// modal damping matrix) the sums `H_ij(kω0) = Σ_r φ_ir φ_jr / (ω_r² − (kω0)² + i kω0
    /// c_r) + D_ij` and their derivatives `∂H/∂Ω = (k/ν) Σ_r φ_ir φ_jr (2kω0 − i c_r) /
    /// z_r²` are written straight into the real layout with no allocation once `out` has the
    /// shape; a full damping matrix goes through one complex solve per harmonic.
    fn receptance_parts_into(&self, omega: f64, deriv: bool, out: &mut ReceptanceParts) {
        let lin = &self.linear;
        if !lin.diagonal {
            *out = self.receptance_parts_general(omega, deriv);
            return;
        }
        let set = &self.set;
        let nh = set.len();
        let w0 = set.base(omega);
        let np = self.element_ports.len();
        let ni = self.inputs.len();
        for (m, cols) in [(&mut out.a, np), (&mut out.ext, ni)] {
            if m.nrows() != np * nh || m.ncols() != cols * nh {
                *m = Mat::zeros(np * nh, cols * nh);
            }
        }
        let nm = lin.n_modes();
        // One pass per harmonic and port pair: the modal sum in mode order.
        let entry = |k: usize, pa: usize, pb: usize| -> c64 {
            let w = k as f64 * w0;
            let mut h = c64::new(0.0, 0.0);
            for r in 0..nm {
                let c = lin.damping[(r, r)];
                let d = c64::new(lin.w2[r] - w * w, w * c).inv();
                let pp = lin.phi[(pa, r)] * lin.phi[(pb, r)];
                h += if deriv {
                    d * d * c64::new(2.0 * w, -c) * pp
                } else {
                    d * pp
                };
            }
            if deriv {
                h * (k as f64 / set.nu as f64)
            } else {
                h + c64::new(lin.residual[(pa, pb)], 0.0)
            }
        };
        // Columns j = 0..ncols at ports port(j).
        let fill = |m: &mut Mat<f64>, ncols: usize, port: &dyn Fn(usize) -> usize| {
            for (i, &pa) in self.element_ports.iter().enumerate() {
                for j in 0..ncols {
                    let pb = port(j);
                    m[(i * nh, j * nh)] = if deriv { 0.0 } else { entry(0, pa, pb).re };
                    for k in 1..=set.h {
                        let z = entry(k, pa, pb);
                        let (r, c) = (i * nh + 2 * k - 1, j * nh + 2 * k - 1);
                        m[(r, c)] = z.re;
                        m[(r, c + 1)] = z.im;
                        m[(r + 1, c)] = -z.im;
                        m[(r + 1, c + 1)] = z.re;
                    }
                }
            }
        };
        fill(&mut out.a, np, &|j| self.element_ports[j]);
        fill(&mut out.ext, ni, &|j| self.inputs[j].1);
    }

    /// [`HbSystem::receptance_parts`] through the per-harmonic complex receptances of
    /// [`LinearPart`] (any damping matrix).
    fn receptance_parts_general(&self, omega: f64, deriv: bool) -> ReceptanceParts {
        let a = expand(
            &self.set,
            &self.harmonic_receptances(omega, &self.element_ports, &self.element_ports, deriv),
        );
        let ext = expand(
            &self.set,
            &self.harmonic_receptances(omega, &self.element_ports, &self.input_ports(), deriv),
        );
        ReceptanceParts { a, ext }
    }

    /// `b = H_NL,ext F` of `parts` with the current forcing into `b`, `f` holding the force
    /// coefficients (both resized; no allocation once large enough).
    fn forced(&self, parts: &ReceptanceParts, f: &mut Vec<f64>, b: &mut Vec<f64>) {
        self.force_coefficients_into(f);
        let bm = &parts.ext;
        b.clear();
        b.extend((0..bm.nrows()).map(|i| (0..f.len()).map(|j| bm[(i, j)] * f[j]).sum::<f64>()));
    }

    /// Element force coefficients and (optionally) their Jacobians at `x`.
    pub(crate) fn evaluate(
        &self,
        rec: &Receptances,
        x: &[f64],
        omega: f64,
        scale: f64,
        jacobian: bool,
    ) -> Evaluation {
        let mut s = EvalBuffers::default();
        self.evaluate_into(&rec.a, &rec.b, x, omega, scale, jacobian, &mut s);
        let EvalBuffers {
            g, r, mut dg, jac, ..
        } = s;
        if !jacobian {
            dg.clear();
        }
        Evaluation {
            r,
            g,
            dg,
            jacobian: jacobian.then_some(jac),
        }
    }

    /// [`HbSystem::evaluate`] into the buffers of `s` (`a = H_NL,NL`, `b = H_NL,ext F`): the
    /// residual in `s.r`, the element forces in `s.g`, the damping samples in `s.damping`
    /// and, with `jacobian`, `∂G_e/∂x_e` in `s.dg` and `∂R/∂x` in `s.jac`. Allocates only
    /// while the buffers grow to this system's sizes.
    #[allow(clippy::too_many_arguments)]
    fn evaluate_into(
        &self,
        a: &Mat<f64>,
        b: &[f64],
        x: &[f64],
        omega: f64,
        scale: f64,
        jacobian: bool,
        s: &mut EvalBuffers,
    ) {
        let nh = self.set.len();
        let w0 = self.set.base(omega);
        s.size(&self.offsets, nh);
        for (e, el) in self.elements.iter().enumerate() {
            let jac = if jacobian {
                Some(s.dg[e].as_mut())
            } else {
                None
            };
            let r = self.unknowns(e);
            self.plans[e].evaluate_element_into(
                el.law(),
                &x[r.clone()],
                w0,
                &mut s.aft,
                &mut s.g[r],
                jac,
            );
            s.damping[e].clear();
            s.damping[e].extend_from_slice(s.aft.damping());
        }
        // R = x + A g − λ b, by columns of A (contiguous).
        for ((r, x), b) in s.r.iter_mut().zip(x).zip(b) {
            *r = x - scale * b;
        }
        for (j, &gj) in s.g.iter().enumerate() {
            for (r, a) in s.r.iter_mut().zip(a.col_as_slice(j)) {
                *r += a * gj;
            }
        }
        if jacobian {
            // J = I + A blockdiag(∂G_e/∂x_e), column by column: J[:, o+c] = e_{o+c} +
            // Σ_l A[:, o+l] d[l, c].
            let j = &mut s.jac;
            for (e, d) in s.dg.iter().enumerate() {
                let o = self.offsets[e] * nh;
                for c in 0..d.ncols() {
                    let col = j.col_as_slice_mut(o + c);
                    col.fill(0.0);
                    for l in 0..d.nrows() {
                        let dlc = d[(l, c)];
                        for (v, a) in col.iter_mut().zip(a.col_as_slice(o + l)) {
                            *v += a * dlc;
                        }
                    }
                    col[o + c] += 1.0;
                }
            }
        }
    }

    /// The residual, its Jacobian and `∂R/∂p` of the parameter a continuation follows (`Ω`
    /// when `frequency`, else the force level: `∂R/∂λ = −H_NL,ext F`) at `x`, into `s`
    /// (`s.ev.r`, `s.ev.jac`, `s.rp`): one corrector iteration's work, with no allocation once
    /// `s` is sized (proportional damping).
    pub(crate) fn evaluate_along(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        frequency: bool,
        s: &mut PathBuffers,
    ) {
        self.receptance_parts_into(omega, false, &mut s.parts);
        self.forced(&s.parts, &mut s.f, &mut s.b);
        self.evaluate_into(&s.parts.a, &s.b, x, omega, scale, true, &mut s.ev);
        let n = self.n_unknowns();
        s.rp.resize(n, 0.0);
        if !frequency {
            for (r, b) in s.rp.iter_mut().zip(&s.b) {
                *r = -b;
            }
            return;
        }
        self.receptance_parts_into(omega, true, &mut s.dparts);
        self.forced(&s.dparts, &mut s.f, &mut s.db);
        // ∂G/∂Ω through the velocity u̇ = ω0 E' x: P diag(∂g/∂u̇) E' x / ν.
        let w0 = self.set.base(omega);
        s.dg.clear();
        s.dg.resize(n, 0.0);
        for (e, plan) in self.plans.iter().enumerate() {
            let c = &s.ev.damping[e];
            if c.iter().all(|&v| v == 0.0) {
                continue;
            }
            let r = self.unknowns(e);
            plan.to_time_into(&x[r.clone()], w0, &mut s.u, &mut s.v);
            s.smp.clear();
            let nu = self.set.nu as f64;
            s.smp
                .extend(s.v.iter().zip(c).map(|(v, c)| c * v / w0 / nu));
            plan.to_freq_into(&s.smp, &mut s.dg[r]);
        }
        let (da, a) = (&s.dparts.a, &s.parts.a);
        for i in 0..n {
            s.rp[i] = (0..n)
                .map(|j| da[(i, j)] * s.ev.g[j] + a[(i, j)] * s.dg[j])
                .sum::<f64>()
                - scale * s.db[i];
        }
    }

    /// `blockdiag(∂G_e/∂x_e) dx`: the change of the element forces along `dx`.
    fn apply_dg(&self, dg: &[Mat<f64>], dx: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; dx.len()];
        for (e, d) in dg.iter().enumerate() {
            let r = self.unknowns(e);
            let (o, xe) = (&mut out[r.clone()], &dx[r]);
            for (l, v) in o.iter_mut().enumerate() {
                *v = (0..d.ncols()).map(|c| d[(l, c)] * xe[c]).sum();
            }
        }
        out
    }

    /// The residual `R(x) = x + H_NL,NL G(x) − λ H_NL,ext F` (m, real layout) at fundamental
    /// `omega` (rad/s) and force level `scale`.
    pub fn residual(&self, x: &[f64], omega: f64, scale: f64) -> Result<Vec<f64>> {
        self.check_unknowns("harmonic balance unknowns", x)?;
        let rec = self.receptances(omega, false);
        Ok(self.evaluate(&rec, x, omega, scale, false).r)
    }

    /// `Err` unless `x` has one value per condensed unknown.
    fn check_unknowns(&self, what: &str, x: &[f64]) -> Result<()> {
        if x.len() != self.n_unknowns() {
            return Err(Error::DimensionMismatch {
                what: what.into(),
                expected: self.n_unknowns(),
                found: x.len(),
            });
        }
        Ok(())
    }

    /// `dx/dΩ = −R_x⁻¹ R_Ω` along the branch through solution `x` (m s/rad).
    pub fn dx_domega(&self, x: &[f64], omega: f64, scale: f64) -> Result<Vec<f64>> {
        self.check_unknowns("harmonic balance unknowns", x)?;
        let mut s = PathBuffers::default();
        self.evaluate_along(x, omega, scale, true, &mut s);
        let lu = Lu::new(&s.ev.jac, &|| {
            format!("branch tangent at {:.6} Hz", omega / (2.0 * PI))
        })?;
        Ok(lu.solve(&s.rp).into_iter().map(|v| -v).collect())
    }

    /// The linear response `λ H_NL,ext F` at `omega`: the start of Newton at low level.
    pub fn linear_guess(&self, omega: f64, scale: f64) -> Vec<f64> {
        self.receptances(omega, false)
            .b
            .iter()
            .map(|b| scale * b)
            .collect()
    }

    /// Solves `R(x) = 0` at `omega` (rad/s) and level `scale` with no start of the caller's:
    /// by Newton from [`HbSystem::linear_guess`], and when that fails, along the force level
    /// from `scale/64`, doubling it, each solve started from the last. At a low level every
    /// element is near its small-motion law (a Jenkins joint stuck, a gap open), where Newton
    /// converges at once; the linear guess ignores the elements' stiffness, so at full level
    /// it can start a stuck joint far into slip, where Newton on the non-smooth force cycles.
    ///
    /// Returns the solution and the last report (not converged when the homotopy failed too).
    pub fn solve_from_rest(&self, omega: f64, scale: f64) -> Result<(Vec<f64>, NewtonReport)> {
        let first = self.solve(omega, scale, &self.linear_guess(omega, scale))?;
        if first.1.converged() {
            return Ok(first);
        }
        if scale == 0.0 {
            return Ok(first);
        }
        let mut level = scale / 64.0;
        let mut x = self.linear_guess(omega, level);
        loop {
            let (xs, rep) = self.solve(omega, level, &x)?;
            if !rep.converged() {
                return Ok(first);
            }
            if level == scale {
                return Ok((xs, rep));
            }
            // The next level starts from this solution, scaled with the level.
            let next = if (4.0 * level).abs() > scale.abs() {
                scale
            } else {
                2.0 * level
            };
            x = xs.iter().map(|v| v * (next / level)).collect();
            level = next;
        }
    }

    /// Solves `R(x) = 0` at fundamental `omega` (rad/s) and force level `scale` by Newton
    /// from `x0`, halving the step until `‖R‖` decreases.
    ///
    /// Returns the last iterate with a report: [`Status::Converged`], or
    /// [`Status::IterationLimit`], [`Status::Singular`], [`Status::NonFinite`] when it
    /// stopped short. `Err` only for invalid input (a non-positive frequency, a start vector
    /// of the wrong length). A caller that solves many points keeps an [`HbWorkspace`] and
    /// calls [`HbSystem::solve_with`] instead: same iterates, no allocation.
    pub fn solve(&self, omega: f64, scale: f64, x0: &[f64]) -> Result<(Vec<f64>, NewtonReport)> {
        let mut ws = HbWorkspace::with_capacity(1);
        let mut x = x0.to_vec();
        let rep = self.solve_with(&mut ws, omega, scale, &mut x)?;
        Ok((x, rep))
    }

    /// [`HbSystem::solve`] in place: `x` holds the start on entry and the last iterate on
    /// return; every buffer comes from `ws`, whose receptance cache serves any later solve
    /// at the same `omega` (bit for bit) while the linear part is unchanged. Once `ws` has
    /// served this system at `omega`, the solve allocates nothing (checked by a test with a
    /// counting allocator). The iterates are those of [`HbSystem::solve`].
    pub fn solve_with(
        &self,
        ws: &mut HbWorkspace,
        omega: f64,
        scale: f64,
        x: &mut [f64],
    ) -> Result<NewtonReport> {
        if !(omega.is_finite() && omega > 0.0 && scale.is_finite()) {
            return Err(Error::invalid(
                "harmonic balance point",
                format!(
                    "needs a positive finite frequency and finite level (Ω = {omega}, λ = {scale})"
                ),
            ));
        }
        self.check_unknowns("harmonic balance start vector", x)?;
        ws.bind(self);
        let HbWorkspace {
            cache, scratch: s, ..
        } = ws;
        let parts = cache.get_or_insert(omega, || self.receptance_parts(omega, false));
        self.forced(parts, &mut s.f, &mut s.b);
        let a = &parts.a;
        let reference = norm_inf(&s.b) * scale.abs();
        let report = |status, iterations, residual| NewtonReport {
            status,
            iterations,
            residual,
        };
        for it in 0..=self.config.max_iterations {
            self.evaluate_into(a, &s.b, x, omega, scale, true, &mut s.ev);
            let rn = norm_inf(&s.ev.r);
            if !rn.is_finite() {
                return Ok(report(Status::NonFinite, it, rn));
            }
            let tol = self.config.rtol * norm_inf(x).max(reference).max(1e-300);
            if rn <= tol {
                return Ok(report(Status::Converged, it, rn));
            }
            if it == self.config.max_iterations {
                return Ok(report(Status::IterationLimit, it, rn));
            }
            s.dx.clear();
            s.dx.extend(s.ev.r.iter().map(|v| -v));
            if !s.lu.factor(&s.ev.jac) {
                return Ok(report(Status::Singular, it, rn));
            }
            s.lu.solve_in_place(&mut s.dx);
            let mut alpha = 1.0;
            let mut accepted = false;
            for _ in 0..16 {
                s.xt.clear();
                s.xt.extend(x.iter().zip(&s.dx).map(|(a, d)| a + alpha * d));
                self.evaluate_into(a, &s.b, &s.xt, omega, scale, false, &mut s.ev);
                let rt = norm_inf(&s.ev.r);
                if rt < (1.0 - 1e-4 * alpha) * rn {
                    x.copy_from_slice(&s.xt);
                    accepted = true;
                    break;
                }
                alpha *= 0.5;
            }
            if !accepted {
                // Full step when no damped step decreases the residual (e.g. at a contact
                // kink where ‖R‖ is not differentiable): Newton still progresses there.
                x.iter_mut().zip(&s.dx).for_each(|(a, d)| *a += d);
            }
        }
        unreachable!("the loop returns at the iteration limit")
    }

    /// A workspace for [`HbSystem::solve_with`] whose receptance cache holds at most
    /// `budget_bytes` of receptances (at least one frequency).
    pub fn workspace(&self, budget_bytes: usize) -> HbWorkspace {
        let n = self.n_unknowns();
        let per = 8 * (n * n + n * self.inputs.len() * self.set.len()) + 64;
        HbWorkspace::with_capacity((budget_bytes / per).max(1))
    }

    /// [`HbSystem::solve`] that turns a solve that stopped short into an error naming the
    /// frequency, the level, the status and the residual: for callers that need a converged
    /// point or nothing.
    pub fn solve_converged(
        &self,
        omega: f64,
        scale: f64,
        x0: &[f64],
    ) -> Result<(Vec<f64>, NewtonReport)> {
        let (x, rep) = self.solve(omega, scale, x0)?;
        if rep.converged() {
            return Ok((x, rep));
        }
        Err(self.not_converged(omega, scale, &rep))
    }

    /// The error text of a Newton solve that stopped short at (`omega`, `scale`).
    pub fn not_converged(&self, omega: f64, scale: f64, rep: &NewtonReport) -> Error {
        let hz = omega / (2.0 * PI);
        Error::Numerical {
            what: format!("harmonic balance Newton at {hz:.6} Hz (level {scale})"),
            detail: match rep.status {
                Status::IterationLimit => format!(
                    "no convergence in {} iterations: residual {:.3e} m against tolerance {:.1e} \
                     relative; take smaller frequency steps or start closer",
                    self.config.max_iterations, rep.residual, self.config.rtol
                ),
                s => format!(
                    "{s} at iteration {} (residual {:.3e} m)",
                    rep.iterations + 1,
                    rep.residual
                ),
            },
        }
    }

    /// Complex amplitudes of every sensor (rows) at every harmonic `k = 0..=H` (columns) at
    /// solution `x`, in the sensor's quantity (displacement m, velocity m/s, acceleration
    /// m/s²): `Y_k = (ikω0)^p (λ H_s,ext F − H_s,NL G)_k`.
    pub fn sensor_response(&self, x: &[f64], omega: f64, scale: f64) -> Mat<c64> {
        let nh = self.set.len();
        let rec = self.receptances(omega, false);
        let ev = self.evaluate(&rec, x, omega, scale, false);
        let y = self.recover(&self.sensor_ports(), omega, scale, &ev.g, false);
        self.to_quantities(&y, omega, nh)
    }

    fn sensor_ports(&self) -> Vec<usize> {
        self.sensors.iter().map(|s| s.port).collect()
    }

    /// `λ H_rows,ext F − H_rows,NL G` in the real layout (or its `Ω`-derivative's linear
    /// part with `deriv`).
    fn recover(&self, rows: &[usize], omega: f64, scale: f64, g: &[f64], deriv: bool) -> Vec<f64> {
        let hs = expand(
            &self.set,
            &self.harmonic_receptances(omega, rows, &self.element_ports, deriv),
        );
        let he = expand(
            &self.set,
            &self.harmonic_receptances(omega, rows, &self.input_ports(), deriv),
        );
        let f = self.force_coefficients();
        (0..hs.nrows())
            .map(|i| {
                scale * (0..f.len()).map(|j| he[(i, j)] * f[j]).sum::<f64>()
                    - (0..g.len()).map(|j| hs[(i, j)] * g[j]).sum::<f64>()
            })
            .collect()
    }

    /// Real-layout displacements (sensors × (2H+1)) to complex amplitudes in each sensor's
    /// quantity.
    fn to_quantities(&self, y: &[f64], omega: f64, nh: usize) -> Mat<c64> {
        let w0 = self.set.base(omega);
        Mat::from_fn(self.sensors.len(), self.set.h + 1, |s, k| {
            let z = self.set.complex(&y[s * nh..(s + 1) * nh], k);
            let iw = c64::new(0.0, k as f64 * w0);
            match self.sensors[s].quantity {
                Quantity::Displacement => z,
                Quantity::Velocity => iw * z,
                Quantity::Acceleration => iw * iw * z,
            }
        })
    }

    /// Multi-harmonic FRFs `H_sν = Y_ν / F_ν` (thesis eq. 14) of every sensor (rows) at every
    /// harmonic `k` (columns) forced on input `input`; NaN where that harmonic carries no
    /// force.
    pub fn frf(&self, x: &[f64], omega: f64, scale: f64, input: usize) -> Mat<c64> {
        let y = self.sensor_response(x, omega, scale);
        Mat::from_fn(y.nrows(), y.ncols(), |s, k| {
            let f = self.forcing.amplitude(input, k) * scale;
            if f == c64::new(0.0, 0.0) {
                c64::new(f64::NAN, f64::NAN)
            } else {
                y[(s, k)] / f
            }
        })
    }

    /// Sensitivities of the solution `x` at (`omega`, `scale`) to `params`, by implicit
    /// differentiation of `R(x, p) = 0`: `dx/dp = −R_x⁻¹ R_p` with one factorisation of the
    /// Jacobian for all parameters; then `dY/dp` of every sensor.
    pub fn sensitivities(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        params: &[Param],
    ) -> Result<Vec<Sensitivity>> {
        let dirs: Vec<Direction<'_>> = params.iter().map(Direction::Param).collect();
        self.sensitivities_along(x, omega, scale, &dirs)
    }

    /// As [`HbSystem::sensitivities`], along variations of the linear part's data (FE-level
    /// parameters: group scales, boundary springs), `R_p = ∂H_NL,NL/∂p G − λ ∂H_NL,ext/∂p F`
    /// from [`LinearPart::receptance_dvariation`]. Each [`Sensitivity::param`] is the
    /// variation's parameter.
    pub fn variation_sensitivities(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        variations: &[LinearVariation],
    ) -> Result<Vec<Sensitivity>> {
        for v in variations {
            v.check(self.linear.n_modes(), self.linear.phi.nrows())?;
        }
        let dirs: Vec<Direction<'_>> = variations.iter().map(Direction::Variation).collect();
        self.sensitivities_along(x, omega, scale, &dirs)
    }

    fn sensitivities_along(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        dirs: &[Direction<'_>],
    ) -> Result<Vec<Sensitivity>> {
        let nh = self.set.len();
        let n = self.n_unknowns();
        let w0 = self.set.base(omega);
        let rec = self.receptances(omega, false);
        let ev = self.evaluate(&rec, x, omega, scale, true);
        let hz = omega / (2.0 * PI);
        let lu = Lu::new(ev.jacobian.as_ref().expect("asked for"), &|| {
            format!("sensitivities at {hz:.6} Hz")
        })?;
        let sports = self.sensor_ports();
        let hs = expand(
            &self.set,
            &self.harmonic_receptances(omega, &sports, &self.element_ports, false),
        );
        let f = self.force_coefficients();
        let ports_nl = &self.element_ports;
        let inputs = self.input_ports();
        let mut out = Vec::with_capacity(dirs.len());
        for dir in dirs {
            let p = match dir {
                Direction::Param(p) => *p,
                Direction::Variation(v) => &v.param,
            };
            // R_p and the explicit part of dY/dp (sensors, real layout).
            let (rp, mut dy) = if let (Param::Element { .. }, Direction::Param(_)) = (p, dir) {
                let (element, param) = self
                    .element_param(p)
                    .ok_or_else(|| unknown_param(p, &self.parameters()))?;
                let el = &self.elements[element];
                let r = self.unknowns(element);
                let d = self.plans[element].dparams_element(el.law(), &x[r.clone()], w0);
                let mut gp = vec![0.0; n];
                for (l, i) in r.enumerate() {
                    gp[i] = d[(l, param)];
                }
                let rp: Vec<f64> = (0..n)
                    .map(|i| (0..n).map(|j| rec.a[(i, j)] * gp[j]).sum())
                    .collect();
                let dy: Vec<f64> = (0..hs.nrows())
                    .map(|i| -(0..n).map(|j| hs[(i, j)] * gp[j]).sum::<f64>())
                    .collect();
                (rp, dy)
            } else {
                let d = |rows: &[usize], cols: &[usize]| -> Result<Mat<f64>> {
                    let h = (0..=self.set.h)
                        .map(|k| match dir {
                            Direction::Param(p) => {
                                self.linear.receptance_dparam(p, k as f64 * w0, rows, cols)
                            }
                            Direction::Variation(v) => {
                                Ok(self
                                    .linear
                                    .receptance_dvariation(v, k as f64 * w0, rows, cols))
                            }
                        })
                        .collect::<Result<Vec<_>>>()?;
                    Ok(expand(&self.set, &h))
                };
                let (da, db) = (d(ports_nl, ports_nl)?, d(ports_nl, &inputs)?);
                let (dsa, dsb) = (d(&sports, ports_nl)?, d(&sports, &inputs)?);
                let lin = |a: &Mat<f64>, b: &Mat<f64>, sign: f64| -> Vec<f64> {
                    (0..a.nrows())
                        .map(|i| {
                            sign * ((0..n).map(|j| a[(i, j)] * ev.g[j]).sum::<f64>()
                                - scale * (0..f.len()).map(|j| b[(i, j)] * f[j]).sum::<f64>())
                        })
                        .collect()
                };
                (lin(&da, &db, 1.0), lin(&dsa, &dsb, -1.0))
            };
            let neg: Vec<f64> = rp.iter().map(|v| -v).collect();
            let dx = lu.solve(&neg);
            // Implicit part: −H_s,NL ∂G/∂x dx.
            let gdx = self.apply_dg(&ev.dg, &dx);
            for (i, v) in dy.iter_mut().enumerate() {
                *v -= (0..n).map(|j| hs[(i, j)] * gdx[j]).sum::<f64>();
            }
            out.push(Sensitivity {
                param: p.clone(),
                dy: self.to_quantities(&dy, omega, nh),
                dx,
            });
        }
        Ok(out)
    }

    /// Displacements (m) at every input port (rows) and harmonic `k = 0..=H` (columns) at
    /// solution `x`, and their Jacobian with respect to the real force coefficients of input
    /// `input` (real layout `[F_0, Re F_1, −Im F_1, …]` per port; (inputs·(2H+1)) × (2H+1),
    /// m/N): `dX/dF = λ (H_in,in − H_in,NL ∂G/∂x J⁻¹ H_NL,in)` by implicit differentiation of
    /// `R(x, F) = 0` (thesis eq. 10). This is what couples a structure to an exciter whose
    /// force depends on the drive-point motion (a shaker on a stinger).
    pub fn input_response_jacobian(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        input: usize,
    ) -> Result<(Mat<c64>, Mat<f64>)> {
        self.check_unknowns("harmonic balance unknowns", x)?;
        self.check_input(input)?;
        let nh = self.set.len();
        let rec = self.receptances(omega, false);
        let ev = self.evaluate(&rec, x, omega, scale, true);
        let ports = self.input_ports();
        let y = self.recover(&ports, omega, scale, &ev.g, false);
        let disp = Mat::from_fn(ports.len(), self.set.h + 1, |i, k| {
            self.set.complex(&y[i * nh..(i + 1) * nh], k)
        });
        let jac = self.force_jacobian_rows(&ev, omega, scale, input, &ports)?;
        Ok((disp, jac))
    }

    /// The residual `R(x) = x + H_NL,NL G(x) − λ H_NL,ext F` and the displacement `X_d` of
    /// input `input`'s port (real layout, m) at `x`, with their Jacobians with respect to
    /// the unknowns and to that input's real force coefficients: `∂R/∂x`, `∂R/∂F =
    /// −λ H_NL,in`, `∂X_d/∂x = −H_in,NL ∂G/∂x`, `∂X_d/∂F = λ H_in,in`. What a structure and
    /// an exciter whose force depends on the drive point's motion are solved with together,
    /// `x` and `F` as one set of unknowns: unlike a solve for `x` at each force, that stays
    /// regular where the force-driven structure folds.
    pub fn input_coupling(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        input: usize,
    ) -> Result<InputCoupling> {
        self.check_unknowns("harmonic balance unknowns", x)?;
        self.check_input(input)?;
        let nh = self.set.len();
        let n = self.n_unknowns();
        let rec = self.receptances(omega, false);
        let ev = self.evaluate(&rec, x, omega, scale, true);
        let port = [self.input_ports()[input]];
        let h_nl_in = expand(
            &self.set,
            &self.harmonic_receptances(omega, &self.element_ports, &port, false),
        );
        let h_in_nl = expand(
            &self.set,
            &self.harmonic_receptances(omega, &port, &self.element_ports, false),
        );
        let h_in_in = expand(
            &self.set,
            &self.harmonic_receptances(omega, &port, &port, false),
        );
        let xd = self.recover(&port, omega, scale, &ev.g, false);
        let mut xd_x = Mat::<f64>::zeros(nh, n);
        for j in 0..n {
            let mut e = vec![0.0; n];
            e[j] = 1.0;
            let col = self.apply_dg(&ev.dg, &e);
            for i in 0..nh {
                xd_x[(i, j)] = -(0..n).map(|l| h_in_nl[(i, l)] * col[l]).sum::<f64>();
            }
        }
        Ok(InputCoupling {
            r: ev.r,
            r_x: ev.jacobian.unwrap_or_else(|| Mat::zeros(n, n)),
            r_f: Mat::from_fn(n, nh, |i, j| -scale * h_nl_in[(i, j)]),
            xd,
            xd_x,
            xd_f: Mat::from_fn(nh, nh, |i, j| scale * h_in_in[(i, j)]),
        })
    }

    /// The Jacobian of every sensor's response with respect to the real force coefficients
    /// of input `input` at solution `x` (as [`HbSystem::input_response_jacobian`], on the
    /// sensors' ports): one matrix per force coefficient `c` of the real layout
    /// `[F_0, Re F_1, −Im F_1, …]`, sensors × harmonics `k = 0..=H` in each sensor's quantity
    /// per newton (like [`Sensitivity::dy`]). With it a response follows a force that itself
    /// depends on the parameters (a gain on the recorded force, a shaker's coupling):
    /// `dY/dp = ∂Y/∂p + Σ_c ∂Y/∂F_c dF_c/dp`.
    pub fn sensor_force_jacobian(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        input: usize,
    ) -> Result<Vec<Mat<c64>>> {
        self.check_unknowns("harmonic balance unknowns", x)?;
        self.check_input(input)?;
        let nh = self.set.len();
        let rec = self.receptances(omega, false);
        let ev = self.evaluate(&rec, x, omega, scale, true);
        let jac = self.force_jacobian_rows(&ev, omega, scale, input, &self.sensor_ports())?;
        Ok((0..nh)
            .map(|c| {
                let col: Vec<f64> = (0..jac.nrows()).map(|i| jac[(i, c)]).collect();
                self.to_quantities(&col, omega, nh)
            })
            .collect())
    }

    /// An error unless `input` is an input of the system.
    fn check_input(&self, input: usize) -> Result<()> {
        if input >= self.inputs.len() {
            return Err(Error::invalid(
                "input response",
                format!(
                    "input {input} does not exist ({} inputs)",
                    self.inputs.len()
                ),
            ));
        }
        Ok(())
    }

    /// `dX_rows/dF = λ (H_rows,in − H_rows,NL ∂G/∂x J⁻¹ H_NL,in)` in the real layout
    /// ((rows·(2H+1)) × (2H+1), m/N) for the force coefficients of input `input`, at the
    /// evaluation `ev` (with its Jacobian) of a solution.
    fn force_jacobian_rows(
        &self,
        ev: &Evaluation,
        omega: f64,
        scale: f64,
        input: usize,
        rows: &[usize],
    ) -> Result<Mat<f64>> {
        let nh = self.set.len();
        let n = self.n_unknowns();
        let ports = self.input_ports();
        let h_rows_in = expand(
            &self.set,
            &self.harmonic_receptances(omega, rows, &ports[input..=input], false),
        );
        let mut jac = Mat::from_fn(rows.len() * nh, nh, |i, j| scale * h_rows_in[(i, j)]);
        if n > 0 {
            let h_rows_nl = expand(
                &self.set,
                &self.harmonic_receptances(omega, rows, &self.element_ports, false),
            );
            let h_nl_in = expand(
                &self.set,
                &self.harmonic_receptances(
                    omega,
                    &self.element_ports,
                    &ports[input..=input],
                    false,
                ),
            );
            let hz = omega / (2.0 * PI);
            let lu = Lu::new(ev.jacobian.as_ref().expect("asked for"), &|| {
                format!("input response Jacobian at {hz:.6} Hz")
            })?;
            for c in 0..nh {
                // dx/dF_c = λ J⁻¹ H_NL,in e_c; then −H_rows,NL ∂G/∂x dx.
                let rhs: Vec<f64> = (0..n).map(|i| scale * h_nl_in[(i, c)]).collect();
                let dx = lu.solve(&rhs);
                let gdx = self.apply_dg(&ev.dg, &dx);
                for i in 0..jac.nrows() {
                    jac[(i, c)] -= (0..n).map(|j| h_rows_nl[(i, j)] * gdx[j]).sum::<f64>();
                }
            }
        }
        Ok(jac)
    }

    /// Derivatives of the modal amplitudes `η_k` (see [`HbSystem::modal_amplitudes`]) along
    /// the sensitivities `sens` computed at the same solution: one modes × (H+1) matrix per
    /// sensitivity, `dη_k/dp = −Z_k⁻¹ (∂Z_k/∂p η_k + Φ_NLᵀ dG_k/dp)` with
    /// `dG/dp = ∂G/∂p + ∂G/∂x dx/dp` (mass-normalised modes: √kg m per parameter unit).
    /// The response at any DOF `i` of the reduced model then follows as `Σ_r φ_ir/√m_r η_r`
    /// without the residual flexibility of the truncated modes (the mode-displacement
    /// approximation): what sensor placement over every DOF of a large model needs. Element
    /// parameters and `modeN.f`, `modeN.zeta`, `stiffness_scale` are supported; others
    /// (modal masses, FE-level variations) are an error.
    pub fn modal_sensitivities(
        &self,
        x: &[f64],
        omega: f64,
        scale: f64,
        sens: &[Sensitivity],
    ) -> Result<Vec<Mat<c64>>> {
        self.check_unknowns("harmonic balance unknowns", x)?;
        let nh = self.set.len();
        let n = self.n_unknowns();
        let m = self.linear.n_modes();
        let w0 = self.set.base(omega);
        let rec = self.receptances(omega, false);
        let ev = self.evaluate(&rec, x, omega, scale, true);
        let eta = self.modal_amplitudes(x, omega, scale);
        let mut out = Vec::with_capacity(sens.len());
        for s in sens {
            if s.dx.len() != n {
                return Err(Error::DimensionMismatch {
                    what: format!("sensitivity to {} (dx/dp)", s.param),
                    expected: n,
                    found: s.dx.len(),
                });
            }
            let mut dgp = self.apply_dg(&ev.dg, &s.dx);
            // ∂Z/∂p of a diagonal entry (per unit of the parameter, at frequency w).
            let mut dz: Option<Box<dyn Fn(usize, f64) -> c64>> = None;
            match &s.param {
                Param::Element { .. } => {
                    let (element, param) = self
                        .element_param(&s.param)
                        .ok_or_else(|| unknown_param(&s.param, &self.parameters()))?;
                    let r = self.unknowns(element);
                    let d = self.plans[element].dparams_element(
                        self.elements[element].law(),
                        &x[r.clone()],
                        w0,
                    );
                    for (l, i) in r.enumerate() {
                        dgp[i] += d[(l, param)];
                    }
                }
                Param::ModalFrequency(r) | Param::ModalDamping(r) if *r < m => {
                    let r = *r;
                    let wr = self.linear.w2[r].sqrt();
                    let zeta = self.linear.zeta(r);
                    let freq = matches!(s.param, Param::ModalFrequency(_));
                    dz = Some(Box::new(move |q, w| {
                        if q != r {
                            c64::new(0.0, 0.0)
                        } else if freq {
                            c64::new(2.0 * wr, 2.0 * zeta * w) * (2.0 * PI)
                        } else {
                            c64::new(0.0, 2.0 * wr * w)
                        }
                    }));
                }
                Param::StiffnessScale => {
                    let w2 = self.linear.w2.clone();
                    let kappa = self.linear.kappa;
                    dz = Some(Box::new(move |q, _| c64::new(w2[q] / kappa, 0.0)));
                }
                p => {
                    return Err(Error::invalid(
                        format!("modal sensitivity to {p}"),
                        "supported for element parameters, modeN.f, modeN.zeta and stiffness_scale",
                    ));
                }
            }
            let mut d = Mat::<c64>::zeros(m, self.set.h + 1);
            for k in 0..=self.set.h {
                let w = k as f64 * w0;
                let mut u: Vec<c64> = (0..self.n_coordinates())
                    .map(|e| -self.set.complex(&dgp[e * nh..(e + 1) * nh], k))
                    .collect();
                if let Some(dz) = &dz {
                    // −∂Z η enters as a modal force: map it through Z⁻¹ below.
                    let f: Vec<c64> = (0..m).map(|q| -dz(q, w) * eta[(q, k)]).collect();
                    let zf = self.linear.modal_solve(w, &f);
                    for (r, z) in zf.into_iter().enumerate() {
                        d[(r, k)] += z;
                    }
                }
                if self.elements.is_empty() {
                    continue;
                }
                let col = self.linear.modal_response(w, &self.element_ports, &u);
                u.clear();
                for (r, z) in col.into_iter().enumerate() {
                    d[(r, k)] += z;
                }
            }
            out.push(d);
        }
        Ok(out)
    }

    /// Modal amplitudes `η_k = Z(kω0)⁻¹ Φ_Pᵀ (λ F_k − G_k)` (modes × harmonics `0..=H`) of the
    /// solution `x`: the state of the full formulation, e.g. for initial conditions of a time
    /// integration on the same periodic orbit.
    pub fn modal_amplitudes(&self, x: &[f64], omega: f64, scale: f64) -> Mat<c64> {
        let nh = self.set.len();
        let rec = self.receptances(omega, false);
        let ev = self.evaluate(&rec, x, omega, scale, false);
        let w0 = self.set.base(omega);
        let mut ports = self.input_ports();
        ports.extend(&self.element_ports);
        let mut eta = Mat::<c64>::zeros(self.linear.n_modes(), self.set.h + 1);
        for k in 0..=self.set.h {
            let mut u: Vec<c64> = (0..self.inputs.len())
                .map(|i| self.forcing.amplitude(i, k) * scale)
                .collect();
            u.extend(
                (0..self.n_coordinates())
                    .map(|e| -self.set.complex(&ev.g[e * nh..(e + 1) * nh], k)),
            );
            let col = self.linear.modal_response(k as f64 * w0, &ports, &u);
            for (r, z) in col.into_iter().enumerate() {
                eta[(r, k)] = z;
            }
        }
        eta
    }

    /// The full formulation on the modal coordinates (thesis eq. 9 balanced harmonic by
    /// harmonic): `Z(kω0) η_k + Φ_NLᵀ G_k(Φ_NL η) − λ Φ_extᵀ F_k`, real layout (modes ×
    /// (2H+1)), and its Jacobian. It has no residual flexibility: with `D = 0` its solutions
    /// are those of the condensed residual.
    pub fn modal_residual(&self, eta: &[f64], omega: f64, scale: f64) -> (Vec<f64>, Mat<f64>) {
        let nh = self.set.len();
        let m = self.linear.n_modes();
        let w0 = self.set.base(omega);
        let z: Vec<Mat<c64>> = (0..=self.set.h)
            .map(|k| self.linear.dynamic_stiffness(k as f64 * w0))
            .collect();
        let zr = expand(&self.set, &z);
        let ne = self.elements.len();
        // Φ_NL (elements × modes) and Φ_ext.
        let phi = |p: usize, r: usize| self.linear.phi[(p, r)];
        let mut jac = zr.clone();
        let mut res: Vec<f64> = (0..m * nh)
            .map(|i| (0..m * nh).map(|j| zr[(i, j)] * eta[j]).sum())
            .collect();
        let f = self.force_coefficients();
        for (i, (_, port)) in self.inputs.iter().enumerate() {
            for r in 0..m {
                for l in 0..nh {
                    res[r * nh + l] -= scale * phi(*port, r) * f[i * nh + l];
                }
            }
        }
        for e in 0..ne {
            let ports = &self.element_ports[self.coordinates(e)];
            // The coordinates' coefficients, coordinate after coordinate.
            let xe: Vec<f64> = ports
                .iter()
                .flat_map(|&pe| {
                    (0..nh).map(move |l| (0..m).map(|r| phi(pe, r) * eta[r * nh + l]).sum())
                })
                .collect();
            let ev = self.plans[e].evaluate_element(self.elements[e].law(), &xe, w0, true);
            let dg = ev.jacobian.expect("asked for");
            for (a, &pa) in ports.iter().enumerate() {
                for r in 0..m {
                    for l in 0..nh {
                        res[r * nh + l] += phi(pa, r) * ev.force[a * nh + l];
                        for (b, &pb) in ports.iter().enumerate() {
                            for s in 0..m {
                                for c in 0..nh {
                                    jac[(r * nh + l, s * nh + c)] +=
                                        phi(pa, r) * dg[(a * nh + l, b * nh + c)] * phi(pb, s);
                                }
                            }
                        }
                    }
                }
            }
        }
        (res, jac)
    }

    /// Solves the full modal formulation by Newton from `eta0` (modes × (2H+1), real layout):
    /// the last iterate and its report (status as in [`HbSystem::solve`]; the residual is the
    /// last Newton step's `‖Δη‖∞`).
    pub fn solve_modal(
        &self,
        omega: f64,
        scale: f64,
        eta0: &[f64],
    ) -> Result<(Vec<f64>, NewtonReport)> {
        let m = self.linear.n_modes() * self.set.len();
        if eta0.len() != m {
            return Err(Error::DimensionMismatch {
                what: "modal harmonic balance start vector".into(),
                expected: m,
                found: eta0.len(),
            });
        }
        let mut eta = eta0.to_vec();
        let mut step = f64::INFINITY;
        let report = |status, iterations, residual| NewtonReport {
            status,
            iterations,
            residual,
        };
        for it in 0..self.config.max_iterations {
            let (r, j) = self.modal_residual(&eta, omega, scale);
            let Ok(lu) = Lu::new(&j, &String::new) else {
                return Ok((eta, report(Status::Singular, it, step)));
            };
            let neg: Vec<f64> = r.iter().map(|v| -v).collect();
            let d = lu.solve(&neg);
            eta.iter_mut().zip(&d).for_each(|(a, b)| *a += b);
            step = norm_inf(&d);
            if !step.is_finite() {
                return Ok((eta, report(Status::NonFinite, it + 1, step)));
            }
            if step <= self.config.rtol * norm_inf(&eta).max(1e-300) {
                return Ok((eta, report(Status::Converged, it + 1, step)));
            }
        }
        let n = self.config.max_iterations;
        Ok((eta, report(Status::IterationLimit, n, step)))
    }

    pub(crate) fn hill_plan(&self) -> &AftPlan {
        &self.hill_plan
    }
}

/// Element law parameters (element order), then the linear ones of [`LinearPart`]
/// (`modeN.f`, `modeN.zeta`, `modeN.m` of every retained mode, `stiffness_scale`, a modal
/// model's measured residual flexibilities `residual:A:B`).
impl Parameterized for HbSystem {
    fn parameters(&self) -> Vec<Param> {
        let mut p = element_parameters(&self.elements);
        p.extend(self.linear.parameters());
        p
    }

    fn param(&self, p: &Param) -> Result<f64> {
        match p {
            Param::Element { .. } => self
                .element_param(p)
                .map(|(e, i)| self.elements[e].law().param(i))
                .ok_or_else(|| unknown_param(p, &self.parameters())),
            Param::ModalFrequency(_)
            | Param::ModalDamping(_)
            | Param::ModalMass(_)
            | Param::StiffnessScale
            | Param::Residual(..)
            | Param::ModeShape { .. } => self.linear.param(p),
            _ => Err(unknown_param(p, &self.parameters())),
        }
    }

    fn set_param(&mut self, p: &Param, value: f64) -> Result<()> {
        match p {
            Param::Element { .. } => {
                let (e, i) = self
                    .element_param(p)
                    .ok_or_else(|| unknown_param(p, &self.parameters()))?;
                self.elements[e].set_param(i, value)?;
                // Keep the AFT plans those of a system built with the new value.
                let n = self
                    .config
                    .aft_samples
                    .unwrap_or(samples_for(self.elements[e].law(), &self.set));
                if n != self.plans[e].n {
                    self.plans[e] = AftPlan::new(self.set, n)?;
                    let hill_n = self.plans.iter().map(|p| p.n).max().unwrap_or(n);
                    self.hill_plan = AftPlan::new(self.set, hill_n)?;
                }
                Ok(())
            }
            Param::ModalFrequency(_)
            | Param::ModalDamping(_)
            | Param::ModalMass(_)
            | Param::StiffnessScale
            | Param::Residual(..)
            | Param::ModeShape { .. } => {
                self.linear.set_param(p, value)?;
                self.stamp = next_stamp();
                Ok(())
            }
            _ => Err(unknown_param(p, &self.parameters())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nlsim_reduction::modal::{ReductionConfig, reduce};

    /// The receptances written straight into the real layout (proportional damping) against
    /// the per-harmonic complex path of [`LinearPart`], and their `Ω`-derivatives against
    /// central differences, on the bump-stop cantilever (6 modes with residual flexibility,
    /// harmonics 0–5) and at a sub-harmonic base (`ν = 3`).
    #[test]
    fn direct_receptances_match_the_complex_path_and_differences() {
        let model = nlsim_fixtures::build("bumpstop_cantilever", &[])
            .unwrap()
            .model;
        let red = reduce(&model, &ReductionConfig::lowest(6)).unwrap();
        for (h, nu) in [(5, 1), (9, 3)] {
            let sys = HbSystem::from_model(
                &model,
                &red,
                HarmonicSet::new(h, nu).unwrap(),
                HbConfig::default(),
            )
            .unwrap();
            assert!(sys.linear.diagonal, "the fixture has proportional damping");
            let w1 = sys.linear.w2[0].sqrt();
            for omega in [0.7 * w1, 1.03 * w1, 2.5 * w1] {
                let mut fast = ReceptanceParts::default();
                for deriv in [false, true] {
                    sys.receptance_parts_into(omega, deriv, &mut fast);
                    let slow = sys.receptance_parts_general(omega, deriv);
                    for (f, s) in [(&fast.a, &slow.a), (&fast.ext, &slow.ext)] {
                        let d = (f - s).norm_max();
                        assert!(
                            d <= 1e-12 * s.norm_max(),
                            "H = {h}, ν = {nu}, Ω = {omega}, deriv {deriv}: {d:e}"
                        );
                    }
                }
                let step = 1e-6 * omega;
                let (mut up, mut down) = (ReceptanceParts::default(), ReceptanceParts::default());
                sys.receptance_parts_into(omega + step, false, &mut up);
                sys.receptance_parts_into(omega - step, false, &mut down);
                let fd = (&up.a - &down.a) * faer::Scale(0.5 / step);
                let d = (&fd - &fast.a).norm_max();
                assert!(d <= 1e-6 * fast.a.norm_max(), "Ω = {omega}: {d:e}");
            }
        }
    }
}
