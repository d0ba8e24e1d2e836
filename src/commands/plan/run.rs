//! The run of `nlsim plan`: every candidate design's predicted stepped sine and its Fisher
//! information (in parallel over candidates, bit-identical for any thread count), ranked by
//! the request's criterion.
use crate::commands::plan::request::MAX_DESIGNS;
use crate::commands::plan::request::MAX_SETTINGS_BYTES;
use crate::commands::plan::request::MAX_STEPS;
use crate::commands::plan::request::PlanRequest;
use crate::commands::plan::request::PointSpec;
use crate::commands::plan::request::Signal;
use crate::error::{Error, Result};
use faer::Mat;
use nlsim_calib::{
    Band, Criterion, Exciter, Noise, Planner, RankedDesign, SweepInformation, rank_designs, subsets,
};
use nlsim_hb::{HarmonicSet, HbConfig};
use nlsim_kernel::{Excitation, Model, Param, Sensor};
use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

/// One candidate stepped sine: where and how the structure is driven, over which band.
#[derive(Debug, Clone, PartialEq)]
pub struct CandidateSweep {
    /// Drive point, level and signal.
    pub exciter: Exciter,
    /// The signal's label.
    pub signal: String,
    /// The band.
    pub band: Band,
}

/// The candidates of a plan: sweeps, sensor sets and harmonic sets, and the prior.
#[derive(Debug, Clone)]
pub struct PlanCandidates {
    /// The model's name.
    pub model_name: String,
    /// The candidate channels: the model's sensors, then the plan's `[[sensor]]` entries.
    pub channels: Vec<String>,
    /// Every candidate stepped sine: drives × levels × signals × bands, the last fastest.
    pub sweeps: Vec<CandidateSweep>,
    /// Every candidate sensor set (indices into the planner's channels).
    pub channel_sets: Vec<Vec<usize>>,
    /// The harmonics the information is computed for (sorted, distinct).
    pub harmonics: Vec<usize>,
    /// Every candidate set of measured harmonics (indices into `harmonics`).
    pub harmonic_sets: Vec<Vec<usize>>,
    /// The prior information (relative units), if any.
    pub prior: Option<Mat<f64>>,
}

/// A plan ready to run: its candidates and the planner.
pub struct PlanSetup {
    /// The candidates.
    pub candidates: PlanCandidates,
    /// The planner (its system's sensors are the candidate channels).
    pub planner: Planner,
    /// Each candidate channel's largest predicted fundamental response over the candidate
    /// tests at the largest level (the channel's unit): the scale of its noise floor.
    pub peaks: Vec<f64>,
    /// The noise model of each candidate channel (floors in the channel's own scale).
    pub noise: Vec<Noise>,
    /// What the user should know about the noise: floors that bury a channel's response.
    pub warnings: Vec<String>,
    /// Wall time of loading, reduction and the response scales (s).
    pub seconds: f64,
}

impl PlanCandidates {
    /// Candidate designs: sweeps × sensor sets × harmonic sets.
    pub fn n_designs(&self) -> usize {
        self.sweeps.len() * self.channel_sets.len() * self.harmonic_sets.len()
    }
}

/// `n choose k`, `None` above `usize`.
pub(crate) fn binomial(n: usize, k: usize) -> Option<usize> {
    let k = k.min(n - k.min(n));
    (0..k).try_fold(1usize, |acc, i| acc.checked_mul(n - i).map(|v| v / (i + 1)))
}

/// Loads the model of `req`, adds its candidate points, reduces it and builds the planner
/// and the candidates.
pub fn prepare_plan(req: &PlanRequest) -> Result<PlanSetup> {
    req.check()?;
    let model = crate::commands::setup::load_for_run(&req.model, &req.set)?;
    prepare_plan_on(model, req)
}

/// [`prepare_plan`] on `model` as given (loaded, `req.set` not applied; `req.model` is not
/// used).
pub fn prepare_plan_on(model: Model, req: &PlanRequest) -> Result<PlanSetup> {
    let t = Instant::now();
    let (model, candidates) = plan_candidates_on(model, req)?;
    // Sequential reduction: the modes, and with them every number of the plan, are then
    // bit-identical whatever the thread count.
    let mut reduction = nlsim_reduction::ReductionConfig::lowest(req.modes.min(model.n_dofs()));
    reduction.eigen.par = faer::Par::Seq;
    let planner = Planner::from_model(
        &model,
        &reduction,
        HarmonicSet::new(req.harmonics, 1)?,
        HbConfig::default(),
        &req.params,
    )?;
    let (peaks, noise, warnings) = channel_noise(req, &candidates, &planner)?;
    Ok(PlanSetup {
        candidates,
        planner,
        peaks,
        noise,
        warnings,
        seconds: t.elapsed().as_secs_f64(),
    })
}

/// Each channel's response scale (its largest predicted fundamental over the candidate
/// tests at the largest level), its noise model (`req.noise`'s floor or `req.noise_floor`
/// of that scale, the larger) and a warning for each channel whose floor is at least a
/// tenth of its response (the channel then carries little information, whatever the
/// design: a floor in the wrong unit, or a sensor where the structure hardly moves).
#[allow(clippy::type_complexity)]
fn channel_noise(
    req: &PlanRequest,
    candidates: &PlanCandidates,
    planner: &Planner,
) -> Result<(Vec<f64>, Vec<Noise>, Vec<String>)> {
    let top = candidates
        .sweeps
        .iter()
        .map(|s| s.exciter.level)
        .fold(0.0f64, f64::max);
    let tests: Vec<(&Exciter, &Band)> = candidates
        .sweeps
        .iter()
        .filter(|s| s.exciter.level == top)
        .map(|s| (&s.exciter, &s.band))
        .collect();
    let peaks = planner.response_peaks(&tests)?;
    let noise = nlsim_calib::scaled_noise(
        req.noise.relative,
        req.noise.absolute,
        req.noise_floor,
        &peaks,
    );
    let sensors = planner.system().sensors();
    let mut warnings = Vec::new();
    for ((n, &p), sen) in noise.iter().zip(&peaks).zip(sensors) {
        let unit = crate::formats::files::unit(sen.quantity);
        if n.absolute <= 0.0 {
            return Err(Error::Usage(format!(
                "plan noise: channel '{}' has no predicted response at any candidate test (is \
                 it on a node the drive does not move?), so a floor relative to it is 0: give \
                 noise = {{ absolute = … }} in {unit}",
                sen.name
            )));
        }
        warnings.extend(floor_warning(
            &sen.name,
            sen.quantity,
            n.absolute,
            p,
            "largest predicted response",
            "it carries little information in any design",
        ));
    }
    Ok((peaks, noise, warnings))
}

/// The model of `req` with its candidate points, and the candidates, every size checked
/// against the budgets before anything is allocated (no reduction).
pub fn plan_candidates(req: &PlanRequest) -> Result<(Model, PlanCandidates)> {
    req.check()?;
    let model = crate::commands::setup::load_for_run(&req.model, &req.set)?;
    plan_candidates_on(model, req)
}

/// [`plan_candidates`] on `model` as given.
pub fn plan_candidates_on(mut model: Model, req: &PlanRequest) -> Result<(Model, PlanCandidates)> {
    req.check()?;
    add_points(&mut model, req)?;
    if model.excitation().is_empty() {
        return Err(Error::Usage(format!(
            "plan: '{}' has no excitation; add candidate drive points as [[actuator]]",
            model.name()
        )));
    }
    if model.sensors().is_empty() {
        return Err(Error::Usage(format!(
            "plan: '{}' has no sensor; add candidate sensors as [[sensor]]",
            model.name()
        )));
    }
    let levels = if req.levels.is_empty() {
        let a = model.excitation()[0].amplitude;
        if !(a.is_finite() && a > 0.0) {
            return Err(Error::Usage(format!(
                "plan: give `levels`; the model's excitation amplitude {a} N is no force level"
            )));
        }
        vec![a]
    } else {
        req.levels.clone()
    };
    let signals = if req.signals.is_empty() {
        vec![Signal {
            label: "sine".into(),
            side: Vec::new(),
        }]
    } else {
        req.signals.clone()
    };
    let drives: Vec<String> = model.excitation().iter().map(|e| e.name.clone()).collect();
    let n_sweeps = drives.len() * levels.len() * signals.len() * req.bands.len();
    let steps: usize = req.bands.iter().map(|b| b.steps).sum::<usize>()
        * drives.len()
        * levels.len()
        * signals.len();
    if steps > MAX_STEPS {
        return Err(Error::Usage(format!(
            "plan: {n_sweeps} candidate sweeps with {steps} steps in all, more than {MAX_STEPS}; \
             split it into a plan-candidates batch (docs/batch.md) or use fewer candidates"
        )));
    }
    let nc = model.sensors().len();
    let counts: Vec<usize> = if req.sensor_counts.is_empty() {
        (1..=nc.min(4)).collect()
    } else {
        req.sensor_counts.clone()
    };
    if let Some(&k) = counts.iter().find(|&&k| k > nc) {
        return Err(Error::Usage(format!(
            "plan sensor_counts: a set of {k} sensors, but the model has {nc} (with the \
             [[sensor]] candidates)"
        )));
    }
    let n_sets = counts
        .iter()
        .try_fold(0usize, |a, &k| a.checked_add(binomial(nc, k)?));
    let n_designs = n_sets
        .and_then(|s| s.checked_mul(n_sweeps))
        .and_then(|s| s.checked_mul(req.measured.len()));
    match n_designs {
        Some(n) if n <= MAX_DESIGNS => {}
        _ => {
            return Err(Error::Usage(format!(
                "plan: {} candidate designs ({n_sweeps} sweeps × {} sensor sets × {} harmonic \
                 sets), more than {MAX_DESIGNS}: enumerate fewer sensor-set sizes, or place \
                 sensors greedily (nlsim_calib::greedy_placement)",
                n_designs.map_or("over 2^64".into(), |n| n.to_string()),
                n_sets.map_or("over 2^64".into(), |n| n.to_string()),
                req.measured.len()
            )));
        }
    }
    let channel_sets: Vec<Vec<usize>> = counts.iter().flat_map(|&k| subsets(nc, k)).collect();
    let mut harmonics: Vec<usize> = req.measured.iter().flatten().copied().collect();
    harmonics.sort_unstable();
    harmonics.dedup();
    let harmonic_sets = req
        .measured
        .iter()
        .map(|m| {
            let mut s: Vec<usize> = m
                .iter()
                .map(|k| harmonics.iter().position(|h| h == k).expect("collected"))
                .collect();
            s.sort_unstable();
            s.dedup();
            s
        })
        .collect();
    let mut sweeps = Vec::with_capacity(n_sweeps);
    for d in &drives {
        for &level in &levels {
            for s in &signals {
                for b in &req.bands {
                    sweeps.push(CandidateSweep {
                        exciter: Exciter {
                            input: d.clone(),
                            level,
                            side: s.side.clone(),
                        },
                        signal: s.label.clone(),
                        band: b.clone(),
                    });
                }
            }
        }
    }
    let prior = match &req.prior {
        None => None,
        Some(p) => Some(read_fim_csv(p, &req.params)?),
    };
    let candidates = PlanCandidates {
        model_name: model.name().to_string(),
        channels: model.sensors().iter().map(|s| s.name.clone()).collect(),
        sweeps,
        channel_sets,
        harmonics,
        harmonic_sets,
        prior,
    };
    Ok((model, candidates))
}

/// Adds the request's candidate actuators (as excitations of zero nominal amplitude) and
/// sensors to `model`; errors name the point and its DOF.
fn add_points(model: &mut Model, req: &PlanRequest) -> Result<()> {
    for a in &req.actuators {
        let at = point_site(model, a, "plan actuator")?;
        model.add_excitation(Excitation {
            name: a.name.clone(),
            at,
            amplitude: 0.0,
            harmonics: Vec::new(),
        })?;
    }
    add_sensors(model, &req.sensors, "plan sensor")
}

/// Adds `sensors` to `model` (a plan's or a test file's `[[sensor]]` entries); an unknown
/// DOF is named with `what` (e.g. `plan sensor`) and the point.
pub(crate) fn add_sensors(model: &mut Model, sensors: &[PointSpec], what: &str) -> Result<()> {
    for s in sensors {
        let at = point_site(model, s, what)?;
        model.add_sensor(Sensor {
            name: s.name.clone(),
            at,
            quantity: s.quantity,
        })?;
    }
    Ok(())
}

/// The site of point `p` in `model` (a DOF, or a point of a modal model); the error names
/// `what`, the point and its DOF.
fn point_site(model: &Model, p: &PointSpec, what: &str) -> Result<nlsim_kernel::Site> {
    model.site(&p.dof).map_err(|e| {
        Error::Usage(format!(
            "{what} '{}': DOF '{}' is not in '{}': {e}",
            p.name,
            p.dof,
            model.name()
        ))
    })
}

/// The warning for a channel whose noise floor buries its response (`floor` at least a
/// tenth of `peak`, both in the channel's unit), `None` otherwise; `largest` names the peak
/// (e.g. `largest predicted response`) and `consequence` what it means.
pub fn floor_warning(
    channel: &str,
    quantity: nlsim_kernel::Quantity,
    floor: f64,
    peak: f64,
    largest: &str,
    consequence: &str,
) -> Option<String> {
    if !(peak.is_finite() && floor >= 0.1 * peak) {
        return None;
    }
    let unit = crate::formats::files::unit(quantity);
    Some(format!(
        "the noise floor of channel '{channel}', {floor:.3e} {unit}, is {} its {largest} \
         ({peak:.3e} {unit}): {consequence}; check the floor's unit, or give noise = {{ floor = \
         … }} (relative to the response)",
        if floor >= peak {
            "above".to_string()
        } else {
            format!("{:.0} % of", 100.0 * floor / peak)
        },
    ))
}

/// The information of candidate sweep `i` of `setup`, with its channels' noise.
pub fn sweep_information(setup: &PlanSetup, i: usize) -> Result<SweepInformation> {
    let c = &setup.candidates;
    let s = c.sweeps.get(i).ok_or_else(|| {
        Error::Usage(format!(
            "candidate sweep {i} is beyond the plan's {}",
            c.sweeps.len()
        ))
    })?;
    Ok(setup
        .planner
        .sweep_information_with(&s.exciter, &s.band, &setup.noise, &c.harmonics)?)
}

/// A finished plan.
pub struct PlanRun {
    /// The request.
    pub request: PlanRequest,
    /// The candidates.
    pub candidates: PlanCandidates,
    /// The parameters planned for.
    pub params: Vec<Param>,
    /// Their nominal values.
    pub nominal: Vec<f64>,
    /// Wall time of loading and reduction (s).
    pub setup_seconds: f64,
    /// The information of every candidate sweep.
    pub sweeps: Vec<SweepInformation>,
    /// Every design, best first.
    pub ranked: Vec<RankedDesign>,
    /// Wall time of the predicted sweeps (s).
    pub sweep_seconds: f64,
    /// Wall time of the ranking (s).
    pub rank_seconds: f64,
    /// Each candidate channel's response scale ([`PlanSetup::peaks`]).
    pub peaks: Vec<f64>,
    /// Each candidate channel's noise model ([`PlanSetup::noise`]).
    pub noise: Vec<Noise>,
    /// Warnings about the noise ([`PlanSetup::warnings`]).
    pub warnings: Vec<String>,
}

/// Runs `req`: every candidate sweep predicted with its information (in parallel on the
/// calling rayon pool; each sweep is independent, so the numbers do not depend on the
/// thread count), then every design ranked. `progress(done, total)` after each sweep.
pub fn run_plan(req: &PlanRequest, progress: &(dyn Fn(usize, usize) + Sync)) -> Result<PlanRun> {
    let setup = prepare_plan(req)?;
    finish_plan(setup, req, progress)
}

/// [`run_plan`] on `model` as given (loaded, `req.set` not applied).
pub fn run_plan_on(
    model: Model,
    req: &PlanRequest,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<PlanRun> {
    let setup = prepare_plan_on(model, req)?;
    finish_plan(setup, req, progress)
}

/// The candidate sweeps of `setup` and the ranking.
fn finish_plan(
    setup: PlanSetup,
    req: &PlanRequest,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<PlanRun> {
    let t = Instant::now();
    let done = AtomicUsize::new(0);
    let total = setup.candidates.sweeps.len();
    let sweeps = (0..total)
        .into_par_iter()
        .map(|i| {
            let r = sweep_information(&setup, i);
            progress(done.fetch_add(1, Ordering::Relaxed) + 1, total);
            r
        })
        .collect::<Result<Vec<_>>>()?;
    let sweep_seconds = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let ranked = rank(&setup.candidates, &sweeps, req.criterion)?;
    Ok(PlanRun {
        request: req.clone(),
        params: setup.planner.params().to_vec(),
        nominal: setup.planner.nominal().to_vec(),
        setup_seconds: setup.seconds,
        candidates: setup.candidates,
        sweeps,
        ranked,
        sweep_seconds,
        rank_seconds: t.elapsed().as_secs_f64(),
        peaks: setup.peaks,
        noise: setup.noise,
        warnings: setup.warnings,
    })
}

/// Every design of `setup` over the informations `sweeps`, best first.
pub fn rank(
    setup: &PlanCandidates,
    sweeps: &[SweepInformation],
    criterion: Criterion,
) -> Result<Vec<RankedDesign>> {
    Ok(rank_designs(
        sweeps,
        &setup.channel_sets,
        &setup.harmonic_sets,
        setup.prior.as_ref(),
        criterion,
    )?)
}

/// One design in words: drive, level, signal, band, sensors, harmonics.
pub fn describe_design(
    setup: &PlanCandidates,
    sweeps: &[SweepInformation],
    r: &RankedDesign,
) -> [String; 6] {
    let c = &setup.sweeps[r.design.sweep];
    let sw = &sweeps[r.design.sweep];
    let ch = sw.channel_names(&r.design);
    let hk: Vec<String> = sw
        .harmonic_numbers(&r.design)
        .iter()
        .map(usize::to_string)
        .collect();
    [
        c.exciter.input.clone(),
        crate::formats::files::number(c.exciter.level),
        c.signal.clone(),
        format!(
            "{} ({}-{} Hz)",
            c.band.label,
            crate::formats::files::number(c.band.from_hz),
            crate::formats::files::number(c.band.to_hz)
        ),
        ch.join("+"),
        hk.join("+"),
    ]
}

/// Reads an information matrix written as `fim_best.csv` (header `param,NAME...`, one row
/// `NAME,F_i1,...` per parameter, relative units) for `params` (rows and columns taken by
/// name, so their order may differ); it must be symmetric with a non-negative diagonal.
pub fn read_fim_csv(path: &Path, params: &[Param]) -> Result<Mat<f64>> {
    let text = crate::formats::files::read_text_bounded(path, MAX_SETTINGS_BYTES)?;
    let bad = |line: usize, m: String| Error::Usage(format!("{}:{line}: {m}", path.display()));
    let mut lines = text
        .lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty());
    let Some((_, header)) = lines.next() else {
        return Err(bad(
            1,
            "empty; expected `param,NAME,...` and one row per parameter".into(),
        ));
    };
    let names: Vec<&str> = header.split(',').map(str::trim).collect();
    if names.first() != Some(&"param") || names.len() < 2 {
        return Err(bad(
            1,
            format!(
                "header {}: expected `param,NAME,...`",
                crate::formats::files::quoted(header)
            ),
        ));
    }
    let cols = &names[1..];
    let index = |name: &str, line: usize| -> Result<usize> {
        params
            .iter()
            .position(|p| p.to_string() == name)
            .ok_or_else(|| {
                bad(
                    line,
                    format!(
                        "{} is not a planned parameter",
                        crate::formats::files::quoted(name)
                    ),
                )
            })
    };
    let col_idx: Vec<usize> = cols.iter().map(|c| index(c, 1)).collect::<Result<_>>()?;
    let n = params.len();
    if cols.len() != n {
        return Err(bad(
            1,
            format!("{} columns for {n} planned parameters", cols.len()),
        ));
    }
    let mut f = Mat::<f64>::from_fn(n, n, |_, _| f64::NAN);
    let mut rows = 0;
    for (i, line) in lines {
        let cells: Vec<&str> = line.split(',').map(str::trim).collect();
        if cells.len() != n + 1 {
            return Err(bad(
                i + 1,
                format!("{} fields, expected {}", cells.len(), n + 1),
            ));
        }
        let r = index(cells[0], i + 1)?;
        for (c, v) in cells[1..].iter().enumerate() {
            let x: f64 = v
                .parse()
                .ok()
                .filter(|x: &f64| x.is_finite())
                .ok_or_else(|| {
                    bad(
                        i + 1,
                        format!(
                            "{} is not a finite number",
                            crate::formats::files::quoted(v)
                        ),
                    )
                })?;
            f[(r, col_idx[c])] = x;
        }
        rows += 1;
    }
    if rows != n || (0..n).any(|i| (0..n).any(|j| f[(i, j)].is_nan())) {
        return Err(bad(1, format!("needs one row per planned parameter ({n})")));
    }
    for i in 0..n {
        if f[(i, i)] < 0.0 {
            return Err(bad(1, format!("diagonal of {} is negative", params[i])));
        }
        for j in 0..i {
            let tol = 1e-9 * (f[(i, i)] * f[(j, j)]).sqrt().max(f64::MIN_POSITIVE);
            if (f[(i, j)] - f[(j, i)]).abs() > tol {
                return Err(bad(
                    1,
                    format!("not symmetric at ({}, {})", params[i], params[j]),
                ));
            }
        }
    }
    Ok(f)
}

/// An information matrix as `read_fim_csv` reads it.
pub fn fim_csv(params: &[Param], f: &Mat<f64>) -> String {
    let mut s = String::from("param");
    for p in params {
        let _ = write!(s, ",{p}");
    }
    s.push('\n');
    for (i, p) in params.iter().enumerate() {
        let _ = write!(s, "{p}");
        for j in 0..params.len() {
            let _ = write!(s, ",{:?}", f[(i, j)]);
        }
        s.push('\n');
    }
    s
}
