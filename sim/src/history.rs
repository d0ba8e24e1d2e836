//! Load cases (what a run is asked to do) and time histories (what it returns).

use crate::plant::{Plant, order};
use crate::signal::Signal;
use faer::c64;
use nlsim_kernel::{Error, Law, Param, Quantity, Result, Status};

/// The state the structure starts from.
#[derive(Debug, Clone, PartialEq, Default)]
pub enum InitialState {
    /// At rest: all states zero.
    #[default]
    Rest,
    /// Given diagonal states `z(0)` (e.g. [`TimeHistory::final_state`] of an earlier run).
    States(Vec<c64>),
    /// Modal displacements `η` (√kg m) and velocities `η̇` (√kg m/s) of the retained modes,
    /// e.g. `η = Φᵀ M q₀` from `ReducedModel::modal_coordinates`.
    Modal {
        /// Modal displacements.
        displacement: Vec<f64>,
        /// Modal velocities.
        velocity: Vec<f64>,
    },
}

/// One run: forces at the plant's inputs, initial state, element parameter overrides.
#[derive(Debug, Clone, PartialEq)]
pub struct LoadCase {
    /// Name of the case (for reports and batch files).
    pub name: String,
    /// One force signal per plant input, in the order of [`Plant::inputs`].
    pub forces: Vec<Signal>,
    /// Initial state.
    pub initial: InitialState,
    /// Element parameters set for this run only: `(element.param, value)`.
    pub parameters: Vec<(Param, f64)>,
}

impl LoadCase {
    /// A case named `name` with the given forces, from rest, nominal parameters.
    pub fn new(name: impl Into<String>, forces: Vec<Signal>) -> Self {
        LoadCase {
            name: name.into(),
            forces,
            initial: InitialState::Rest,
            parameters: Vec::new(),
        }
    }

    /// Checks the case against `plant` and returns the initial states and the plant's elements
    /// with the case's parameters applied.
    pub(crate) fn prepare(
        &self,
        plant: &Plant,
    ) -> Result<(Vec<c64>, Vec<crate::plant::ElementPort>)> {
        if self.forces.len() != plant.inputs.len() {
            return Err(Error::DimensionMismatch {
                what: format!(
                    "force signals of load case '{}' (one per input: {})",
                    self.name,
                    plant
                        .inputs
                        .iter()
                        .map(|(n, _)| n.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
                expected: plant.inputs.len(),
                found: self.forces.len(),
            });
        }
        for (s, (name, _)) in self.forces.iter().zip(&plant.inputs) {
            s.validate(&format!("load case '{}', input '{name}'", self.name))?;
        }
        let ns = plant.n_states();
        let z0 = match &self.initial {
            InitialState::Rest => vec![c64::new(0.0, 0.0); ns],
            InitialState::States(z) => {
                if z.len() != ns {
                    return Err(Error::DimensionMismatch {
                        what: format!("initial states of load case '{}'", self.name),
                        expected: ns,
                        found: z.len(),
                    });
                }
                if let Some(i) = z
                    .iter()
                    .position(|v| !(v.re.is_finite() && v.im.is_finite()))
                {
                    return Err(Error::NonFinite {
                        what: format!("initial states of load case '{}'", self.name),
                        location: format!("state {}", i + 1),
                        value: z[i].re + z[i].im,
                    });
                }
                z.clone()
            }
            InitialState::Modal {
                displacement,
                velocity,
            } => plant.system.initial_states(displacement, velocity)?,
        };
        let mut elements = plant.elements.clone();
        for (p, v) in &self.parameters {
            crate::plant::set_entry_param(&mut elements, p, *v)?;
        }
        Ok((z0, elements))
    }
}

/// A contact event located inside a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ContactEvent {
    /// Time of the event (s).
    pub time: f64,
    /// Element entry index in [`Plant::elements`].
    pub element: usize,
    /// `true` when contact closes, `false` when it opens.
    pub closing: bool,
}

/// Counters and timings of a run.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct RunStats {
    /// Integration steps taken (accepted).
    pub steps: usize,
    /// Steps rejected by the error control (adaptive methods).
    pub rejected_steps: usize,
    /// Right-hand-side evaluations (Runge–Kutta) or linear solves (Newmark).
    pub evaluations: usize,
    /// Newton iterations of the nonlinear loop, summed over the run.
    pub newton_iterations: usize,
    /// Largest Newton iteration count of one step.
    pub max_newton_iterations: usize,
    /// Located contact events (FOH with event location).
    pub events: Vec<ContactEvent>,
    /// Wall time of the run (s).
    pub seconds: f64,
}

/// One sampled output.
#[derive(Debug, Clone, PartialEq)]
pub struct Series {
    /// Name (sensor or port name).
    pub name: String,
    /// Quantity.
    pub quantity: Quantity,
    /// Values at `t = k dt` (m, m/s or m/s²).
    pub values: Vec<f64>,
}

/// The result of a run: outputs, element forces and coordinates, input forces, all sampled at
/// `t = k dt`, `k = 0..n_samples`.
#[derive(Debug, Clone, PartialEq)]
pub struct TimeHistory {
    /// Method that produced it (`foh`, `rk45`, …).
    pub method: String,
    /// Name of the load case.
    pub case: String,
    /// Sample interval (s).
    pub dt: f64,
    /// Requested outputs.
    pub outputs: Vec<Series>,
    /// Input forces `(name, samples)` (N).
    pub inputs: Vec<(String, Vec<f64>)>,
    /// Element names, one per [`Plant::elements`] entry: a law on several coordinates has one
    /// per coordinate, `name[j]` ([`crate::ElementPort::coordinate_name`]).
    pub element_names: Vec<String>,
    /// Element coordinates `u` (m), one series per [`Plant::elements`] entry.
    pub element_displacements: Vec<Vec<f64>>,
    /// Element velocities `u̇` (m/s).
    pub element_velocities: Vec<Vec<f64>>,
    /// Element forces `g` (N; positive resists positive `u`).
    pub element_forces: Vec<Vec<f64>>,
    /// Diagonal states at the last sample (to continue the run).
    pub final_state: Vec<c64>,
    /// Counters and timings.
    pub stats: RunStats,
    /// [`Status::Converged`] when every requested step was taken; otherwise why the run
    /// stopped ([`Status::IterationLimit`]: the nonlinear loop's Newton failed;
    /// [`Status::NonFinite`]: the response diverged; [`Status::StepTooSmall`]: an adaptive
    /// step fell below its minimum). The series then hold the samples computed before.
    pub status: Status,
    /// Where and why the run stopped short (step, time, element), as an error a caller that
    /// needs the whole run can return; `None` when complete.
    pub stopped: Option<Error>,
}

impl TimeHistory {
    /// The history when the run is complete; the reason it stopped short otherwise, for
    /// callers that need every requested sample.
    pub fn into_complete(self) -> Result<TimeHistory> {
        match self.stopped {
            Some(e) => Err(e),
            None => Ok(self),
        }
    }

    /// Number of samples.
    pub fn n_samples(&self) -> usize {
        self.inputs
            .first()
            .map(|i| i.1.len())
            .or_else(|| self.outputs.first().map(|o| o.values.len()))
            .or_else(|| self.element_forces.first().map(|o| o.len()))
            .unwrap_or(0)
    }

    /// Sample times (s).
    pub fn times(&self) -> Vec<f64> {
        (0..self.n_samples()).map(|k| k as f64 * self.dt).collect()
    }

    /// The output named `name`.
    pub fn output(&self, name: &str) -> Result<&Series> {
        self.outputs.iter().find(|o| o.name == name).ok_or_else(|| {
            Error::invalid(
                format!("output '{name}'"),
                format!(
                    "the run has outputs {}",
                    self.outputs
                        .iter()
                        .map(|o| o.name.as_str())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )
        })
    }
}

/// Adds the rate terms of the residual flexibility to velocity and acceleration outputs, by
/// central differences of the samples (one-sided at the ends). Displacements already hold `D u`.
///
/// Velocities get `D u̇` with `u` every port force (excitation inputs and `−g` at element
/// ports). Accelerations get `D ü` of the excitation inputs and of the elements whose law is a
/// polynomial of the displacements (cubic, polynomial, coupled polynomial: `g` as smooth as the
/// motion). Any other element force can have a kink (a contact closing, a joint sticking) and
/// then an impulsive `g̈`, whose second difference grows as 1/h and made accelerations depend
/// on the output rate (1.1 % at the peak between 8 and 64 kHz on the bump-stop cantilever).
/// The truncated modes' real response to such a kink is ringing that the quasi-static residual
/// cannot represent, so that term is left out there; the modal part and the direct term
/// `Φ_P Φ_Pᵀ g` carry the element's effect. (Leaving it out for a cubic spring too cost 2e-5
/// to 7e-5 of the fundamental against the harmonic balance, which keeps it.)
pub(crate) fn add_residual_rates(plant: &Plant, h: &mut TimeHistory) {
    let forces: Vec<Vec<f64>> = h
        .inputs
        .iter()
        .map(|(_, v)| v.clone())
        .chain(
            h.element_forces
                .iter()
                .map(|g| g.iter().map(|x| -x).collect()),
        )
        .collect();
    let dt = h.dt;
    let mut outputs: Vec<&mut [f64]> = h
        .outputs
        .iter_mut()
        .map(|o| o.values.as_mut_slice())
        .collect();
    residual_rates(plant, &forces, dt, &mut outputs, RateTerms::Run);
}

/// Which residual-flexibility rate terms [`residual_rates`] adds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum RateTerms {
    /// Those the integrators add to their outputs: velocities of every force, accelerations
    /// of the excitations and the polynomial laws.
    Run,
    /// Accelerations of the kinked laws alone (a recorder's, from its own samples).
    Kinked,
}

/// The rate terms of [`add_residual_rates`] added to `outputs` (one per plant output, every
/// sample at step `dt`) from the port forces `forces` (one per force input in
/// [`Plant::input_ports`] order: the excitations, then the element ports, `−g`; an empty
/// series is no force). The forward sensitivities add the same terms of the force
/// sensitivities. `terms` picks which: [`RateTerms::Run`] those of [`add_residual_rates`],
/// [`RateTerms::Kinked`] those of [`add_kinked_residual_accelerations`].
pub(crate) fn residual_rates(
    plant: &Plant,
    forces: &[Vec<f64>],
    dt: f64,
    outputs: &mut [&mut [f64]],
    terms: RateTerms,
) {
    let ports = plant.input_ports();
    let ne = plant.inputs.len();
    // Which forces have a smooth second derivative: the inputs, and polynomial laws.
    let smooth = |q: usize| q < ne || polynomial(plant.elements[q - ne].element.law());
    for (spec, out) in plant.outputs.iter().zip(outputs.iter_mut()) {
        let ord = order(spec.quantity);
        let n = out.len();
        if ord == 0 || n < 3 {
            continue;
        }
        for (q, u) in forces.iter().enumerate() {
            let d = plant.system.feedthrough[(spec.port, ports[q])];
            let wanted = match terms {
                RateTerms::Run => ord == 1 || smooth(q),
                RateTerms::Kinked => ord == 2 && !smooth(q),
            };
            if d == 0.0 || u.len() < n || !wanted {
                continue;
            }
            for k in 0..n {
                let rate = if ord == 1 {
                    if k == 0 {
                        (u[1] - u[0]) / dt
                    } else if k == n - 1 {
                        (u[n - 1] - u[n - 2]) / dt
                    } else {
                        (u[k + 1] - u[k - 1]) / (2.0 * dt)
                    }
                } else {
                    let m = k.clamp(1, n - 2);
                    (u[m + 1] - 2.0 * u[m] + u[m - 1]) / (dt * dt)
                };
                out[k] += d * rate;
            }
        }
    }
}

/// The acceleration term the integrators leave out of their outputs (the residual
/// flexibility's `D g̈` of kinked laws), for a recorder that samples the run:
/// `−D_{p,e} Δ²g_e / dt²` added to every acceleration output `p` for every element `e`
/// whose law is not a polynomial (a clearance, friction, a power law), from the element
/// forces `element_forces` (N, one series per element in [`Plant::elements`] order) sampled
/// at the recorder's step `dt` (s) — the samples the outputs `outputs` (one per plant output,
/// equally long) hold.
///
/// A kink in `g` makes `g̈` impulsive. Its second difference at the recorder's step is the
/// impulse spread over the samples next to the kink with its area kept, so the harmonics of
/// the sampled acceleration are those of `−k² ω² (D g)_k` up to the factor
/// `sinc²(k ω dt / 2)` of the difference (second order in the step, as for the smooth
/// laws), which is what the harmonic balance predicts; left out, the impulse costs the
/// accelerations' harmonics a part independent of the step (on the bump-stop cantilever the
/// calibrated gap moved by 3e-5 of itself). The time history itself gets a spike of width
/// `2 dt` at each kink, whose height grows as `1/dt`: this is for records analysed by their
/// harmonics, not for peak values. The differences must be taken on the recorder's samples,
/// not on a finer run's: keeping every m-th sample of a spike keeps or drops it whole.
/// Series shorter than 3 samples, and element series shorter than the outputs, are left as
/// they are.
pub fn add_kinked_residual_accelerations(
    plant: &Plant,
    element_forces: &[Vec<f64>],
    dt: f64,
    outputs: &mut [&mut [f64]],
) {
    let forces: Vec<Vec<f64>> = plant
        .inputs
        .iter()
        .map(|_| Vec::new())
        .chain(
            element_forces
                .iter()
                .take(plant.elements.len())
                .map(|g| g.iter().map(|x| -x).collect()),
        )
        .collect();
    residual_rates(plant, &forces, dt, outputs, RateTerms::Kinked);
}

/// Whether an element law is a polynomial of the displacements (its force as smooth as the
/// motion, so that its second difference is a rate and not an impulse).
fn polynomial(law: &Law) -> bool {
    matches!(
        law,
        Law::Cubic { .. } | Law::Polynomial { .. } | Law::CoupledPolynomial { .. }
    )
}

/// Calls a progress callback `progress(done, total)` about 200 times over a run of `total`
/// samples, without a division per sample.
pub(crate) struct Progress<'a> {
    callback: &'a mut dyn FnMut(usize, usize),
    total: usize,
    every: usize,
    left: usize,
}

impl<'a> Progress<'a> {
    /// Reports for a run of `total` samples.
    pub fn new(callback: &'a mut dyn FnMut(usize, usize), total: usize) -> Self {
        let every = (total / 200).max(1);
        Progress {
            callback,
            total,
            every,
            left: every,
        }
    }

    /// Sample `done` is finished.
    #[inline]
    pub fn tick(&mut self, done: usize) {
        self.left -= 1;
        if self.left == 0 {
            self.left = self.every;
            (self.callback)(done, self.total);
        }
    }
}
