//! Running a shard: its jobs in parallel, each written to a temporary file that is renamed
//! into place when complete.

use crate::commands::calibrate::run::Prepared;
use crate::commands::frf::run::run_frf_shared;
use crate::commands::setup::Reductions;
use crate::commands::simulate::run::run_simulation_shared;
use crate::error::{Error, Result};
use crate::formats::files::h5err;
use crate::formats::files::str_attr;
use hdf5_metno as hdf5;
use rayon::prelude::*;
use std::path::PathBuf;
use std::time::Instant;

use super::*;

/// What happened to a shard.
#[derive(Debug, Clone, PartialEq)]
pub enum ShardOutcome {
    /// Its file was already complete for this jobs file: nothing was run.
    Skipped(PathBuf),
    /// It ran; `failed` lists the jobs that failed, with their errors (recorded in the file).
    Written {
        /// The shard file.
        path: PathBuf,
        /// Jobs run.
        jobs: usize,
        /// `(job index, error)` of the jobs that failed.
        failed: Vec<(usize, String)>,
        /// Wall time (s).
        seconds: f64,
        /// Reductions computed for the shard's jobs (jobs that differ only in excitation,
        /// force or element parameters share one).
        reductions: usize,
    },
}

/// Progress of a shard, for the caller to show.
#[derive(Debug, Clone)]
pub enum ShardEvent {
    /// A stale shard file (another jobs file) or temporary files of a killed run were found.
    Note(String),
    /// A job finished (`done` of `total`).
    JobDone {
        /// Its index in the batch.
        index: usize,
        /// Jobs of this shard finished so far.
        done: usize,
        /// Jobs in this shard.
        total: usize,
        /// Its error, if it failed.
        error: Option<String>,
    },
}

/// The result of one job, ready to be written.
enum JobResult {
    Frf(Box<crate::commands::frf::run::FrfRun>),
    Simulate(Box<crate::commands::simulate::run::SimRun>),
    /// A calibration candidate: its values and cost.
    Candidate(Vec<f64>, f64),
    /// A fold of a calibration's cross validation.
    Fold(nlsim_calib::FoldResult),
    /// A candidate sweep of a plan: its information and the nominal parameter values.
    PlanSweep(Box<nlsim_calib::SweepInformation>, Vec<f64>),
}

/// What the jobs of a calibration shard share: the objective (model loaded and reduced once)
/// and the candidate points.
struct CalibContext {
    prepared: Prepared,
    candidates: Vec<Vec<f64>>,
}

/// The planner a plan batch's jobs share (`None` for other batches).
fn plan_context(b: &Batch) -> Result<Option<crate::commands::plan::run::PlanSetup>> {
    match &b.command {
        BatchCommand::PlanCandidates(req) => {
            Ok(Some(crate::commands::plan::run::prepare_plan(req)?))
        }
        _ => Ok(None),
    }
}

/// The shared part of a calibration batch's jobs (`None` for other batches).
fn calib_context(b: &Batch) -> Result<Option<CalibContext>> {
    let req = match &b.command {
        BatchCommand::CalibrateCandidates(r) | BatchCommand::CalibrateFolds(r, _) => r,
        _ => return Ok(None),
    };
    let prepared = crate::commands::calibrate::run::prepare(req)?;
    // Folds against the data points, once for the shard rather than once per job.
    req.config
        .validate(prepared.objective.data().n_points())
        .map_err(|e| Error::Usage(format!("{}: {e}", req.data.display())))?;
    let candidates = match &b.command {
        BatchCommand::CalibrateCandidates(_) => {
            nlsim_calib::candidate_points(&prepared.objective, &req.config)?
        }
        _ => Vec::new(),
    };
    Ok(Some(CalibContext {
        prepared,
        candidates,
    }))
}

fn run_job(
    b: &Batch,
    job: &Job,
    ctx: Option<&CalibContext>,
    plan: Option<&crate::commands::plan::run::PlanSetup>,
    reductions: &Reductions,
) -> Result<JobResult> {
    let mut spec = b.model.clone();
    let mut sets = b.sets.clone();
    let mut force = None;
    let mut excitation = None;
    for a in &job.assignments {
        match a {
            Assignment::Set(n, v) => sets.push(format!("{n}={v:e}")),
            Assignment::Force(v) => force = Some(*v),
            Assignment::Excitation(s) => excitation = Some(s.clone()),
            Assignment::Model(m) => spec = m.clone(),
            &Assignment::Candidate(i) => {
                let ctx = ctx.ok_or_else(|| Error::Failed("no calibration context".into()))?;
                let values = ctx.candidates.get(i).cloned().ok_or_else(|| {
                    Error::Failed(format!(
                        "candidate {i} is beyond the {} candidates",
                        ctx.candidates.len()
                    ))
                })?;
                let cost = ctx.prepared.objective.clone().cost_values(&values)?;
                return Ok(JobResult::Candidate(values, cost));
            }
            &Assignment::Fold(f) => {
                let (Some(ctx), BatchCommand::CalibrateFolds(req, estimate)) = (ctx, &b.command)
                else {
                    return Err(Error::Failed("no calibration context".into()));
                };
                let r = nlsim_calib::fold(&ctx.prepared.objective, estimate, &req.config, f)?;
                return Ok(JobResult::Fold(r));
            }
            &Assignment::PlanSweep(i) => {
                let (Some(setup), BatchCommand::PlanCandidates(_)) = (plan, &b.command) else {
                    return Err(Error::Failed("no planning context".into()));
                };
                let info = crate::commands::plan::run::sweep_information(setup, i)?;
                return Ok(JobResult::PlanSweep(
                    Box::new(info),
                    setup.planner.nominal().to_vec(),
                ));
            }
        }
    }
    let model = crate::commands::setup::load_for_run(&spec, &sets)?;
    match &b.command {
        BatchCommand::Frf(req) => {
            let mut req = req.clone();
            if force.is_some() {
                req.force = force;
            }
            Ok(JobResult::Frf(Box::new(run_frf_shared(
                &model,
                &req,
                &mut |_| {},
                reductions,
            )?)))
        }
        BatchCommand::Simulate(req) => {
            let mut req = req.clone();
            if let Some(e) = excitation {
                req.excitation = vec![crate::commands::simulate::request::Drive::parse(
                    &e,
                    req.duration,
                    req.rate,
                )?];
            }
            Ok(JobResult::Simulate(Box::new(run_simulation_shared(
                &model,
                &req,
                &mut |_, _| {},
                reductions,
            )?)))
        }
        BatchCommand::CalibrateCandidates(_)
        | BatchCommand::CalibrateFolds(..)
        | BatchCommand::PlanCandidates(_) => Err(Error::Failed(format!(
            "job {} names no candidate, fold or sweep",
            job.index
        ))),
    }
}

/// The parameter values of a calibration job, as dataset `values`.
fn write_values(g: &hdf5::Group, values: &[f64]) -> hdf5::Result<()> {
    g.new_dataset::<f64>()
        .shape(values.len())
        .create("values")?
        .write_raw(values)
}

fn write_job(
    jobs: &hdf5::Group,
    b: &Batch,
    job: &Job,
    result: &Result<JobResult>,
) -> hdf5::Result<()> {
    let g = jobs.create_group(&job_group_name(job.index))?;
    u64_attr_write(&g, "index", job.index as u64)?;
    let desc: Vec<String> = job.assignments.iter().map(|a| a.to_string()).collect();
    str_attr(&g, "assignments", &desc.join("; "))?;
    for a in &job.assignments {
        if let Assignment::Set(n, v) = a {
            g.new_attr::<f64>()
                .create(format!("set:{n}").as_str())?
                .write_scalar(v)?;
        }
    }
    match result {
        Err(e) => {
            g.new_attr::<u8>().create("ok")?.write_scalar(&0u8)?;
            str_attr(&g, "error", &e.to_string())
        }
        Ok(r) => {
            g.new_attr::<u8>().create("ok")?.write_scalar(&1u8)?;
            match r {
                JobResult::Frf(run) => {
                    crate::formats::frf_file::write_group(
                        &g,
                        &run.system,
                        &run.branch,
                        &run.responses,
                    )?;
                    crate::formats::frf_file::write_peaks(&g, &run.system, &run.peaks)?;
                    // A branch that stopped short is kept, and says so.
                    str_attr(&g, "status", run.status.as_str())?;
                    if !run.detail.is_empty() {
                        str_attr(&g, "detail", &run.detail)?;
                    }
                    Ok(())
                }
                JobResult::Candidate(values, cost) => {
                    write_values(&g, values)?;
                    g.new_attr::<f64>().create("cost")?.write_scalar(cost)
                }
                JobResult::Fold(r) => {
                    write_values(&g, &r.values)?;
                    str_attr(&g, "status", r.status.as_str())?;
                    for (name, v) in [
                        ("held_out_rms", r.held_out_rms),
                        ("training_rms", r.training_rms),
                    ] {
                        g.new_attr::<f64>().create(name)?.write_scalar(&v)?;
                    }
                    Ok(())
                }
                JobResult::PlanSweep(info, nominal) => {
                    crate::commands::plan::report::write_sweep_group(&g, info, nominal)
                }
                JobResult::Simulate(run) => {
                    let info = crate::formats::history_file::RunInfo {
                        model_spec: b.model.clone(),
                        method: match &b.command {
                            BatchCommand::Simulate(r) => r.method.as_str().into(),
                            _ => String::new(),
                        },
                        excitation: run.excitation.clone(),
                        modes: run.modes,
                        // Shards are intermediate: `batch merge` compresses the merged file.
                        compress: false,
                    };
                    crate::formats::history_file::write_group(&g, &run.history, &info)
                }
            }
        }
    }
}

/// Runs shard `task` of `count`: skips it when its file is complete for this jobs file,
/// otherwise computes its jobs (in parallel, `rayon::current_num_threads()` at a time, each
/// single-threaded inside so that the numbers do not depend on the thread count), appends each
/// to a temporary file as it finishes and renames the file into place at the end. A job that
/// fails is recorded with its error and the others go on.
pub fn run_shard(
    b: &Batch,
    task: usize,
    count: usize,
    event: &mut dyn FnMut(ShardEvent),
) -> Result<ShardOutcome> {
    if count == 0 || task >= count {
        return Err(Error::Usage(format!(
            "task index {task} is not below the task count {count}"
        )));
    }
    let path = b.shard_path(task, count);
    match on_disk(&path, b.hash, b.shard_jobs(task, count).count()) {
        OnDisk::Complete => return Ok(ShardOutcome::Skipped(path)),
        OnDisk::Missing => {}
        OnDisk::Stale => event(ShardEvent::Note(format!(
            "{} was written for another version of {}; recomputing it",
            path.display(),
            b.file.display()
        ))),
        OnDisk::Damaged(why) => event(ShardEvent::Note(format!(
            "{} is damaged ({why}); recomputing it",
            path.display()
        ))),
    }
    let start = Instant::now();
    // What the jobs share is loaded (and checked) before anything is written.
    let ctx = calib_context(b)?;
    let plan = plan_context(b)?;
    std::fs::create_dir_all(&b.output).map_err(|source| Error::Io {
        path: b.output.clone(),
        source,
    })?;
    // Held until the shard is in place: a second run of the same shard at once is refused
    // here, and with the lock held every temporary file of the shard is an orphan.
    let _lock = crate::formats::guard::OutputLock::acquire(&path)?;
    for p in crate::formats::files::remove_temporaries(&path, false) {
        event(ShardEvent::Note(format!(
            "removed {} (left by a run that was killed)",
            p.display()
        )));
    }
    let mine: Vec<&Job> = b.shard_jobs(task, count).collect();
    // Jobs that differ only in excitation, force or element parameters share one reduction.
    let reductions = Reductions::default();
    let total = mine.len();
    let mut failed = Vec::new();
    crate::formats::files::write_atomically(&path, ".h5", |tmp, _| {
        let err = h5err(tmp);
        let file = hdf5::File::create(tmp).map_err(&err)?;
        let root = file.as_group().map_err(&err)?;
        write_root_attrs(&root, b).map_err(&err)?;
        for (name, v) in [("task_index", task), ("task_count", count)] {
            u64_attr_write(&root, name, v as u64).map_err(&err)?;
        }
        let jobs = file.create_group("jobs").map_err(&err)?;
        let width = rayon::current_num_threads().max(1);
        let mut done = 0;
        let mut outcome = Ok(());
        for chunk in mine.chunks(width) {
            let results: Vec<Result<JobResult>> = chunk
                .par_iter()
                .map(|j| run_job(b, j, ctx.as_ref(), plan.as_ref(), &reductions))
                .collect();
            for (job, r) in chunk.iter().zip(&results) {
                if let Err(e) = write_job(&jobs, b, job, r).map_err(&err) {
                    outcome = Err(e);
                    break;
                }
                done += 1;
                let error = r.as_ref().err().map(|e| e.to_string());
                if let Some(e) = &error {
                    failed.push((job.index, e.clone()));
                }
                event(ShardEvent::JobDone {
                    index: job.index,
                    done,
                    total,
                    error,
                });
            }
            if outcome.is_err() {
                break;
            }
            file.flush().map_err(&err)?;
        }
        outcome?;
        u64_attr_write(&root, "complete", 1).map_err(&err)?;
        file.flush().map_err(&err)?;
        Ok(())
    })?;
    Ok(ShardOutcome::Written {
        path,
        jobs: total,
        failed,
        seconds: start.elapsed().as_secs_f64(),
        reductions: reductions.counts().0,
    })
}
