//! The run behind `nlsim simulate` and simulate batch jobs: the reduced model (or the
//! unreduced one for Newmark/HHT), the excitation signals per point, the chosen integrator.
use crate::commands::setup::Reductions;
use crate::commands::simulate::request::Drive;
use crate::commands::simulate::request::Method;
use crate::commands::simulate::request::SimRequest;
use crate::error::{Error, Result};
use crate::formats::excitation::nyquist_check;
use nlsim_kernel::Model;
use nlsim_reduction::ModalSystem;
use nlsim_sim::{
    FohConfig, Hold, LoadCase, Newmark, NewmarkConfig, Plant, Rk4Config, Rk45Config, Signal,
    Simulator, TimeHistory,
};
use std::time::Instant;

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
    /// RK45's absolute tolerance, whether it was scaled to the response, and the largest
    /// static modal state it is judged against (√kg m; RK45 only).
    pub atol: Option<(f64, bool, f64)>,
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
            let auto = nlsim_sim::auto_atol(&plant, &case.forces, dt, n_steps, req.rtol);
            let a = req.atol.unwrap_or(auto);
            // The largest static modal state the auto tolerance is scaled to.
            let z_ref = auto / (1e-3 * req.rtol);
            atol = Some((a, req.atol.is_none(), z_ref));
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
