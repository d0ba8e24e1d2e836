//! The arguments of `nlsim batch` and its `merge` and `sbatch` actions.

use crate::batch::command;
use crate::present::console::Console;
use clap::{Args, Subcommand};

/// The arguments of `nlsim batch`.
#[derive(Args, Debug)]
pub struct BatchArgs {
    #[command(subcommand)]
    action: Option<BatchAction>,
    /// The jobs file (TOML).
    jobs: Option<std::path::PathBuf>,
    /// Shard to run (default: $SLURM_ARRAY_TASK_ID; without either, every shard in turn).
    #[arg(long)]
    task_index: Option<usize>,
    /// Number of shards (default: $SLURM_ARRAY_TASK_COUNT, else 1).
    #[arg(long)]
    task_count: Option<usize>,
    /// Output directory (default: from the jobs file).
    #[arg(long)]
    output: Option<std::path::PathBuf>,
}

/// `nlsim batch merge` and `nlsim batch sbatch`.
#[derive(Subcommand, Debug)]
pub enum BatchAction {
    /// Join the complete shard files into OUTPUT/merged.h5 (fails naming missing shards).
    Merge {
        /// The jobs file (TOML).
        jobs: std::path::PathBuf,
        /// Output directory (default: from the jobs file).
        #[arg(long)]
        output: Option<std::path::PathBuf>,
    },
    /// Write the SLURM job-array script OUTPUT/nlsim-batch.sbatch (and submit it with
    /// --submit).
    Sbatch {
        /// The jobs file (TOML).
        jobs: std::path::PathBuf,
        /// Array size: the number of shards.
        #[arg(long)]
        tasks: usize,
        /// CPUs per array task (jobs run at once in a shard).
        #[arg(long, default_value_t = 1)]
        cpus_per_task: usize,
        /// SLURM partition.
        #[arg(long)]
        partition: Option<String>,
        /// Time limit per task, e.g. 01:00:00.
        #[arg(long)]
        time: Option<String>,
        /// Memory per task, e.g. 4G.
        #[arg(long)]
        mem: Option<String>,
        /// Submit the script with sbatch and print the job id.
        #[arg(long)]
        submit: bool,
        /// Output directory (default: from the jobs file).
        #[arg(long)]
        output: Option<std::path::PathBuf>,
    },
}

impl BatchArgs {
    /// `nlsim batch` (shards of the jobs file; the task from `--task-index`/`--task-count`
    /// or SLURM's array variables), `batch merge` or `batch sbatch`.
    pub fn execute(&self, console: &Console) -> crate::Result<()> {
        match &self.action {
            Some(BatchAction::Merge { jobs, output }) => {
                command::merge(&command::load(jobs, output.as_deref())?, console)
            }
            Some(BatchAction::Sbatch {
                jobs,
                tasks,
                cpus_per_task,
                partition,
                time,
                mem,
                submit,
                output,
            }) => {
                let o = crate::batch::SbatchOptions {
                    tasks: *tasks,
                    cpus_per_task: *cpus_per_task,
                    partition: partition.clone(),
                    time: time.clone(),
                    mem: mem.clone(),
                };
                let b = command::load(jobs, output.as_deref())?;
                let exe = std::env::current_exe().map_err(|source| crate::Error::Io {
                    path: "nlsim".into(),
                    source,
                })?;
                command::sbatch(&b, jobs, &exe, &o, *submit, console)
            }
            None => {
                let jobs = self.jobs.as_ref().ok_or_else(|| {
                    crate::Error::Usage(
                        "nlsim batch needs a jobs file: nlsim batch JOBS.toml (or merge, sbatch)"
                            .into(),
                    )
                })?;
                let b = command::load(jobs, self.output.as_deref())?;
                let env = |v: &str| std::env::var(v).ok();
                let index = command::task_number(
                    self.task_index,
                    "SLURM_ARRAY_TASK_ID",
                    env("SLURM_ARRAY_TASK_ID"),
                )?;
                let count = command::task_number(
                    self.task_count,
                    "SLURM_ARRAY_TASK_COUNT",
                    env("SLURM_ARRAY_TASK_COUNT"),
                )?
                .unwrap_or(1);
                command::run(&b, index, count, console)
            }
        }
    }
}
