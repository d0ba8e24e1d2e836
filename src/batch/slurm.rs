//! The SLURM job-array script of a batch.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

use super::*;

/// Options of the SLURM job-array script.
#[derive(Debug, Clone, Default)]
pub struct SbatchOptions {
    /// Array size: shards.
    pub tasks: usize,
    /// CPUs per task (`--cpus-per-task`); the shard runs that many jobs at once.
    pub cpus_per_task: usize,
    /// `--partition`, if any.
    pub partition: Option<String>,
    /// `--time` limit (`HH:MM:SS`), if any.
    pub time: Option<String>,
    /// `--mem` per node (e.g. `4G`), if any.
    pub mem: Option<String>,
}

/// The job-array script that runs every shard of `b` with the nlsim executable `exe`; logs go
/// to `OUTPUT/logs/`.
pub fn sbatch_script(b: &Batch, exe: &Path, o: &SbatchOptions) -> Result<String> {
    if o.tasks == 0 {
        return Err(Error::Usage("--tasks must be at least 1".into()));
    }
    if o.tasks > super::MAX_TASKS {
        return Err(Error::Usage(format!(
            "--tasks {}: at most {} array tasks",
            o.tasks,
            super::MAX_TASKS
        )));
    }
    let abs = |p: &Path| -> Result<PathBuf> {
        std::path::absolute(p).map_err(|source| Error::Io {
            path: p.to_path_buf(),
            source,
        })
    };
    let q = |p: &Path| -> Result<String> {
        let s = abs(p)?.display().to_string();
        Ok(format!("'{}'", s.replace('\'', r"'\''")))
    };
    let logs = b.output.join("logs");
    let mut s = String::from("#!/bin/bash\n");
    s += &format!("#SBATCH --job-name=nlsim-{}\n", b.name);
    s += &format!("#SBATCH --array=0-{}\n", o.tasks - 1);
    s += &format!("#SBATCH --output={}/%x-%A_%a.out\n", abs(&logs)?.display());
    s += &format!("#SBATCH --cpus-per-task={}\n", o.cpus_per_task.max(1));
    for (k, v) in [
        ("partition", &o.partition),
        ("time", &o.time),
        ("mem", &o.mem),
    ] {
        if let Some(v) = v {
            s += &format!("#SBATCH --{k}={v}\n");
        }
    }
    s += &format!(
        "# Written by nlsim {} for {} ({} jobs in {} shards). A shard whose file is complete is\n\
         # skipped, so resubmitting this script redoes only what is missing. Then run:\n\
         #   nlsim batch merge {}\n",
        env!("CARGO_PKG_VERSION"),
        abs(&b.file)?.display(),
        b.jobs.len(),
        o.tasks,
        abs(&b.file)?.display()
    );
    s += "set -euo pipefail\n";
    s += &format!(
        "exec {} batch {} --output {} --task-index \"$SLURM_ARRAY_TASK_ID\" --task-count {} \
         --threads \"${{SLURM_CPUS_PER_TASK:-1}}\"\n",
        q(exe)?,
        q(&b.file)?,
        q(&b.output)?,
        o.tasks
    );
    Ok(s)
}
