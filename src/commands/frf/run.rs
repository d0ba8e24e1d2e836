//! The run behind `nlsim frf` and FRF batch jobs: reduce (or take a shared reduction), build
//! the harmonic-balance system, continue or step through the range, locate peaks. A batch job
//! computes exactly what the single command computes.
use crate::commands::frf::request::DEFAULT_STEPS;
use crate::commands::frf::request::FrfRequest;
use crate::commands::frf::request::FrfStart;
use crate::commands::frf::request::MAX_FRF_POINTS;
use crate::commands::frf::request::SUBHARMONIC_SEARCH;
use crate::commands::frf::request::SweepMode;
use crate::commands::frf::start::read_start;
use crate::commands::setup::Reductions;
use crate::error::{Error, Result};
use faer::{Mat, c64};
use nlsim_hb::{Branch, ContinuationConfig, HbConfig, HbSystem, SolutionPoint};
use nlsim_kernel::{Model, Status};
use std::f64::consts::PI;
use std::time::Instant;

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
    /// Sensor responses (sensors × harmonics) per point, from [`crate::commands::frf::run::responses`].
    pub responses: Vec<faer::Mat<faer::c64>>,
    /// Retained modes.
    pub modes: usize,
    /// Wall time of the reduction (s).
    pub reduce_seconds: f64,
    /// Wall time of the sweep (s).
    pub seconds: f64,
    /// Stepped sines: frequencies (Hz) where no start converged, left out (gaps).
    pub skipped_hz: Vec<f64>,
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
    // Parameters of the reduced model (`--set mode1.f=…`), after the reduction.
    let mut system = system;
    for (p, v) in &req.modal_sets {
        nlsim_kernel::Parameterized::set_param(&mut system, p, *v)?;
    }
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
    if report.stats.n_unverified > 0 {
        notes.push(format!(
            "{} step(s) the branch of the last point could not be followed across (a \
             non-smooth point): their points are shown as regular, not as jumps, though the \
             response may have left its branch there; a finer grid (--points) tells",
            report.stats.n_unverified
        ));
    }
    let skipped_hz: Vec<f64> = report.skipped.iter().map(|w| w / (2.0 * PI)).collect();
    if !skipped_hz.is_empty() {
        let list: Vec<String> = skipped_hz.iter().map(|f| format!("{f:.5}")).collect();
        notes.push(format!(
            "no solution converged at {} Hz (from the last point, other starts or a \
             continuation in the force level): left out, a gap in the sweep and its plot",
            list.join(", ")
        ));
    }
    let status = report.status;
    let detail = report.detail.replace('\n', ": ");
    if report.branch.points.is_empty() {
        // Nothing to return: the start point itself failed.
        return Err(match report.into_branch() {
            Err(e) => e.into(),
            Ok(_) => Error::Failed(format!(
                "FRF of '{name}': {}: no point converged, not even the start point at {} \
                 Hz{} (are the parameters physical? try --start rest, more --harmonics or a \
                 smaller range)",
                status.as_str(),
                req.from_hz,
                if detail.is_empty() {
                    String::new()
                } else {
                    format!(" ({detail})")
                }
            )),
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
    let responses = crate::commands::frf::run::responses(&system, &branch);
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
        skipped_hz,
    })
}

/// Sensor responses (sensors × harmonics) of every point.
pub fn responses(sys: &HbSystem, branch: &Branch) -> Vec<Mat<c64>> {
    branch
        .points
        .iter()
        .map(|p| sys.sensor_response(&p.x, p.omega, p.scale))
        .collect()
}
