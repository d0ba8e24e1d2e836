//! `nlsim batch JOBS`, `nlsim batch merge JOBS` and `nlsim batch sbatch JOBS` as library
//! calls: shards run with their progress and outcome lines, merges and job-array scripts.

use super::{Batch, SbatchOptions, ShardEvent, ShardOutcome};
use crate::error::{Error, Result};
use crate::present::console::Console;
use std::path::Path;

/// Loads a jobs file, with `output` overriding its output directory.
pub fn load(jobs: &Path, output: Option<&Path>) -> Result<Batch> {
    let mut b = Batch::load(jobs)?;
    if let Some(o) = output {
        b.output = o.to_path_buf();
    }
    Ok(b)
}

/// A task index or count given on the command line, else from a SLURM variable (its value
/// `from_env` read, `None` when unset).
pub fn task_number(
    given: Option<usize>,
    var: &str,
    from_env: Option<String>,
) -> Result<Option<usize>> {
    if given.is_some() {
        return Ok(given);
    }
    match from_env {
        None => Ok(None),
        Some(v) => v
            .trim()
            .parse()
            .map(Some)
            .map_err(|_| Error::Usage(format!("${var} = '{v}' is not a non-negative integer"))),
    }
}

/// `nlsim batch JOBS`: shard `index` of `count` (every shard in turn without an index), each
/// written atomically; fails after the others are written when a job failed.
pub fn run(b: &Batch, index: Option<usize>, count: usize, console: &Console) -> Result<()> {
    if count == 0 {
        return Err(Error::Usage("--task-count must be at least 1".into()));
    }
    if count > super::MAX_TASKS {
        return Err(Error::Usage(format!(
            "--task-count {count}: at most {} shards (this batch has {} jobs)",
            super::MAX_TASKS,
            b.jobs.len()
        )));
    }
    if let Some(i) = index
        && i >= count
    {
        return Err(Error::Usage(format!(
            "--task-index {i} is not below --task-count {count}"
        )));
    }
    b.check_models()?;
    console.say(&format!(
        "batch {}: {} {} jobs of {} in {count} shard(s), seed {}, output {}",
        b.name,
        b.jobs.len(),
        b.command.name(),
        b.model,
        b.seed,
        b.output.display()
    ));
    let tasks: Vec<usize> = match index {
        Some(i) => vec![i],
        None => (0..count).collect(),
    };
    let mut n_failed = 0;
    for task in tasks {
        let mut bar = console.counter("jobs");
        let outcome = super::run_shard(b, task, count, &mut |ev| match ev {
            ShardEvent::Note(m) => console.note(&format!("  note: {m}")),
            ShardEvent::JobDone {
                index,
                done,
                total,
                error,
            } => {
                if console.verbose() {
                    console.say(&format!(
                        "  job {index}: {}",
                        error.map_or("ok".to_string(), |e| format!("failed: {e}"))
                    ));
                }
                bar(done, total);
            }
        })?;
        match outcome {
            ShardOutcome::Skipped(p) => console.say(&format!(
                "  shard {task} of {count}: complete in {}, skipped",
                p.display()
            )),
            ShardOutcome::Written {
                path,
                jobs,
                failed,
                seconds,
                reductions,
            } => {
                let shared = if reductions > 0 && reductions < jobs {
                    format!(
                        " ({reductions} reduction{} for {jobs} jobs)",
                        if reductions == 1 { "" } else { "s" }
                    )
                } else {
                    String::new()
                };
                console.say(&format!(
                    "  shard {task} of {count}: {jobs} jobs in {seconds:.2} s{shared}, {} failed, \
                     written to {}",
                    failed.len(),
                    path.display()
                ));
                for (i, e) in &failed {
                    console.error(&format!("  job {i} failed: {e}"));
                }
                n_failed += failed.len();
            }
        }
    }
    if n_failed > 0 {
        return Err(Error::Failed(format!(
            "{n_failed} job(s) failed (their errors are in the shard files); the others are written"
        )));
    }
    Ok(())
}

/// `nlsim batch merge JOBS`: the shards joined into one file, with its summary.
pub fn merge(b: &Batch, console: &Console) -> Result<()> {
    let m = super::merge(b)?;
    console.say(&format!(
        "batch {}: merged {} jobs from {} shard(s) into {}{}",
        b.name,
        m.jobs,
        m.shards,
        m.path.display(),
        if m.failed > 0 {
            format!(" ({} failed jobs, with their errors)", m.failed)
        } else {
            String::new()
        }
    ));
    for line in &m.summary {
        console.say(&format!("  {line}"));
    }
    Ok(())
}

/// `nlsim batch sbatch JOBS`: the job-array script for `exe` (and its log folder) written
/// into the output directory, and with `submit` handed to `sbatch`, whose job id is printed
/// even when quiet (scripts read it).
pub fn sbatch(
    b: &Batch,
    jobs: &Path,
    exe: &Path,
    o: &SbatchOptions,
    submit: bool,
    console: &Console,
) -> Result<()> {
    b.check_models()?;
    let script = super::sbatch_script(b, exe, o)?;
    let logs = b.output.join("logs");
    std::fs::create_dir_all(&logs).map_err(|source| Error::Io {
        path: logs.clone(),
        source,
    })?;
    let path = b.output.join("nlsim-batch.sbatch");
    crate::formats::files::write_text_atomically(&path, &script)?;
    console.say(&format!(
        "batch {}: {} jobs in a {}-task array, script {}",
        b.name,
        b.jobs.len(),
        o.tasks,
        path.display()
    ));
    if submit {
        let out = std::process::Command::new("sbatch")
            .arg("--parsable")
            .arg(&path)
            .output()
            .map_err(|e| {
                Error::Usage(format!(
                    "cannot run sbatch ({e}): submit from a SLURM login node, or run the script \
                     with `sbatch {}`",
                    path.display()
                ))
            })?;
        if !out.status.success() {
            return Err(Error::Usage(format!(
                "sbatch {} failed: {}",
                path.display(),
                String::from_utf8_lossy(&out.stderr).trim()
            )));
        }
        let id = String::from_utf8_lossy(&out.stdout).trim().to_string();
        // Scripts read the job id from stdout, even with --quiet.
        console.always(&id);
        console.note(&format!(
            "  submitted; when it is done: nlsim batch merge {}",
            jobs.display()
        ));
    }
    Ok(())
}
