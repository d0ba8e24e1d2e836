//! `nlsim batch`: many runs of one command described in a jobs file (TOML), split into shards
//! for cluster job arrays, each shard written atomically to its own HDF5 file, and merged.
//!
//! The jobs file (`docs/batch.md`):
//!
//! ```toml
//! name = "duffing-k3"           # names the output directory and the SLURM job
//! command = "frf"               # frf | simulate | calibrate-candidates | calibrate-folds | plan-candidates
//! model = "duffing_fig3"        # model file or built-in model
//! seed = 7                      # seed of the Latin hypercube (recorded in every file)
//! set = { "spring.c" = 0.5 }    # fixed element-parameter overrides
//!
//! [frf]                         # the options of `nlsim frf` (or [simulate] for simulate)
//! from = 80.0
//! to = 140.0
//!
//! [[sweep]]                     # sweeps are crossed with each other and with [lhs]
//! set = "spring.k3"             # an element parameter ...
//! values = [1e3, 2e3]
//! [[sweep]]
//! option = "force"              # ... or an option: force (frf), excitation (simulate), model
//! values = [0.5, 1.0]
//!
//! [lhs]                         # Latin-hypercube candidates of several parameters
//! samples = 8
//! params = [{ set = "spring.k3", min = 1e3, max = 1e4, log = true }]
//! ```
//!
//! A calibration spreads over a cluster in two batches of the same `[calibrate]` table (the
//! keys of a calibration file, [`crate::commands::calibrate`], without `model`):
//! `calibrate-candidates` evaluates candidate `i` (0: the model's values, then the Latin
//! hypercube) in job `i`, and `nlsim calibrate --candidates merged.h5` goes on from them;
//! `calibrate-folds` runs fold `f` of the cross validation in job `f`, from the top-level
//! `estimate = { "tip.k3" = 1.2e9 }`, and the merge adds the fold statistics.
//!
//! A plan spreads the same way: `plan-candidates` with a `[plan]` table (the keys of a plan
//! file, [`crate::commands::plan`]) predicts candidate sweep `i` and its Fisher information in job
//! `i`; the merge ranks every design (sweeps × sensor sets × harmonic sets) and writes the
//! ranking beside the jobs.
//!
//! Job `i` belongs to shard `i mod T` of `T`. A shard computes its jobs in parallel (rayon),
//! each job single-threaded inside, so results do not depend on the thread count or on the
//! number of shards; it writes each finished job to a temporary file and renames the file into
//! place only when every job is in it. A shard file that exists is therefore complete; a
//! resubmitted shard whose file exists for the same jobs file is skipped.
//!
//! The files by role: `jobs.rs` reads a jobs file into a [`Batch`]; `shard.rs` runs a shard
//! ([`run_shard`]); `merge.rs` joins the shards ([`merge`]); `calib.rs` holds what calibration
//! batches add (the fold statistics and best candidates of a merge, [`read_candidates`]);
//! `slurm.rs` writes the job-array script ([`sbatch_script`]).

mod calib;
pub mod command;
mod jobs;
mod merge;
mod shard;
mod slurm;

pub use crate::formats::candidates::read_candidates;
use crate::formats::files::{job_group_name, u64_attr};
pub use merge::{MergeOutcome, merge};
pub use shard::{ShardEvent, ShardOutcome, run_shard};
pub use slurm::{SbatchOptions, sbatch_script};

use crate::commands::calibrate::request::CalibrationRequest;
use crate::commands::frf::request::FrfRequest;
use crate::commands::simulate::request::SimRequest;
use crate::formats::files::provenance;
use crate::formats::files::str_attr;
use hdf5_metno as hdf5;
use std::path::{Path, PathBuf};

/// Most shards of a batch (`--task-count`, `$SLURM_ARRAY_TASK_COUNT`, `sbatch --tasks`), as
/// many as the most Latin-hypercube jobs a jobs file may make.
pub const MAX_TASKS: usize = 1_000_000;
/// The command every job of a batch runs, with its base options.
#[derive(Debug, Clone)]
pub enum BatchCommand {
    /// `nlsim frf`.
    Frf(FrfRequest),
    /// `nlsim simulate`.
    Simulate(SimRequest),
    /// The candidates of a calibration: job `i` evaluates the cost at candidate `i`.
    CalibrateCandidates(Box<CalibrationRequest>),
    /// The cross validation of a calibration: job `f` runs fold `f` from the estimate
    /// (parameter values in the request's order).
    CalibrateFolds(Box<CalibrationRequest>, Vec<f64>),
    /// The candidate sweeps of a plan: job `i` predicts sweep `i` and its Fisher
    /// information; the merge ranks every design.
    PlanCandidates(Box<crate::commands::plan::request::PlanRequest>),
}

impl BatchCommand {
    /// `frf` or `simulate`.
    pub fn name(&self) -> &'static str {
        match self {
            BatchCommand::Frf(_) => "frf",
            BatchCommand::Simulate(_) => "simulate",
            BatchCommand::CalibrateCandidates(_) => "calibrate-candidates",
            BatchCommand::CalibrateFolds(..) => "calibrate-folds",
            BatchCommand::PlanCandidates(_) => "plan-candidates",
        }
    }
}

/// One change a job makes to the base run.
#[derive(Debug, Clone, PartialEq)]
pub enum Assignment {
    /// An element parameter, `element.param = value`.
    Set(String, f64),
    /// The force amplitude of an FRF (N).
    Force(f64),
    /// The excitation spec of a time response.
    Excitation(String),
    /// The model.
    Model(String),
    /// Candidate `i` of a calibration (0: the model's values, then the Latin hypercube).
    Candidate(usize),
    /// Fold `f` of a calibration's cross validation (0-based).
    Fold(usize),
    /// Candidate sweep `i` of a plan (0-based).
    PlanSweep(usize),
}

impl std::fmt::Display for Assignment {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Assignment::Set(n, v) => write!(f, "{n}={v:e}"),
            Assignment::Force(v) => write!(f, "force={v:e}"),
            Assignment::Excitation(s) => write!(f, "excitation={s}"),
            Assignment::Model(s) => write!(f, "model={s}"),
            Assignment::Candidate(i) => write!(f, "candidate={i}"),
            Assignment::Fold(i) => write!(f, "fold={}", i + 1),
            Assignment::PlanSweep(i) => write!(f, "sweep={}", i + 1),
        }
    }
}

/// One run of a batch.
#[derive(Debug, Clone, PartialEq)]
pub struct Job {
    /// Position in the batch (0-based).
    pub index: usize,
    /// What it changes, in sweep order.
    pub assignments: Vec<Assignment>,
}

/// A parsed jobs file.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The jobs file.
    pub file: PathBuf,
    /// The batch name.
    pub name: String,
    /// The command and its base options.
    pub command: BatchCommand,
    /// The base model spec.
    pub model: String,
    /// Fixed overrides `element.param=value`.
    pub sets: Vec<String>,
    /// The output directory (shards and the merged file).
    pub output: PathBuf,
    /// The seed of the Latin hypercube (0 when not given).
    pub seed: u64,
    /// Every job, in order.
    pub jobs: Vec<Job>,
    /// FNV-1a hash of the jobs file's text: shards written for another text are not reused.
    pub hash: u64,
}

pub use nlsim_calib::latin_hypercube;

/// What a shard or merged file on disk is.
#[derive(Debug, Clone, PartialEq, Eq)]
enum OnDisk {
    /// No file.
    Missing,
    /// Complete, for this jobs file.
    Complete,
    /// Written for another version of the jobs file, or never completed.
    Stale,
    /// Not a readable HDF5 file (zero length, truncated, overwritten): why.
    Damaged(String),
}

/// The state of a shard or merged file for the jobs file of hash `hash` holding `n_jobs`
/// jobs: complete only when it opens, carries the hash and `complete = 1`, and holds a group
/// for each of its jobs.
fn on_disk(path: &Path, hash: u64, n_jobs: usize) -> OnDisk {
    if !path.exists() {
        return OnDisk::Missing;
    }
    if let Err(e) = crate::formats::files::regular_file(path) {
        return OnDisk::Damaged(e.to_string());
    }
    let file = match hdf5::File::open(path) {
        Ok(f) => f,
        Err(e) => {
            let len = std::fs::metadata(path).map_or(0, |m| m.len());
            let why = if len == 0 {
                "it is empty".to_string()
            } else {
                crate::formats::files::one_line(&e.to_string())
            };
            return OnDisk::Damaged(why);
        }
    };
    if u64_attr(&file, "jobs_hash") != Some(hash) || u64_attr(&file, "complete") != Some(1) {
        return OnDisk::Stale;
    }
    let groups = file
        .group("jobs")
        .and_then(|g| g.member_names())
        .map_or(0, |names| {
            names.iter().filter(|n| n.starts_with("job-")).count()
        });
    if groups == n_jobs {
        OnDisk::Complete
    } else {
        OnDisk::Damaged(format!("it holds {groups} of its {n_jobs} jobs"))
    }
}

/// Writes a scalar `u64` attribute.
fn u64_attr_write(loc: &hdf5::Location, name: &str, v: u64) -> hdf5::Result<()> {
    loc.new_attr::<u64>().create(name)?.write_scalar(&v)
}

fn write_root_attrs(root: &hdf5::Group, b: &Batch) -> hdf5::Result<()> {
    provenance(root, b.command.name(), &b.model, &b.model, Some(b.seed))?;
    str_attr(root, "batch", &b.name)?;
    u64_attr_write(root, "jobs_hash", b.hash)?;
    u64_attr_write(root, "n_jobs", b.jobs.len() as u64)
}

#[cfg(test)]
mod tests {
    use super::jobs::fnv1a;
    use super::*;

    const FRF: &str = r#"
name = "t"
command = "frf"
model = "duffing_fig3"
seed = 3

[frf]
from = 80.0
to = 140.0
mode = "step-up"
points = 10

[[sweep]]
set = "spring.k3"
values = [1e3, 2e3, 3e3]

[[sweep]]
option = "force"
values = [0.5, 1]

[lhs]
samples = 4
params = [{ set = "spring.c", min = 0.1, max = 10.0, log = true }]
"#;

    #[test]
    fn grid_is_the_cartesian_product_first_axis_slowest() {
        let b = Batch::parse(FRF, Path::new("/x/jobs.toml")).unwrap();
        assert_eq!(b.jobs.len(), 3 * 2 * 4);
        assert_eq!(b.output, Path::new("/x/t-results"));
        let j = &b.jobs[4 * 2 + 4 + 1]; // k3 = 2e3, force = 1, sample 1
        assert_eq!(j.assignments[0], Assignment::Set("spring.k3".into(), 2e3));
        assert_eq!(j.assignments[1], Assignment::Force(1.0));
        // Shards partition the jobs.
        let mut seen: Vec<usize> = (0..5)
            .flat_map(|t| b.shard_jobs(t, 5).map(|j| j.index).collect::<Vec<_>>())
            .collect();
        seen.sort_unstable();
        assert_eq!(seen, (0..b.jobs.len()).collect::<Vec<_>>());
    }

    #[test]
    fn latin_hypercube_fills_every_stratum_once_and_is_seeded() {
        let (n, d) = (37, 3);
        let a = latin_hypercube(n, d, 11);
        for c in 0..d {
            let mut s: Vec<usize> = a.iter().map(|r| (r[c] * n as f64) as usize).collect();
            s.sort_unstable();
            assert_eq!(s, (0..n).collect::<Vec<_>>());
        }
        assert_eq!(a, latin_hypercube(n, d, 11));
        assert_ne!(a, latin_hypercube(n, d, 12));
    }

    #[test]
    fn errors_name_the_line_and_key() {
        let cases = [
            (
                "name = \"a\"\ncommand = \"frf\"\nmodel = \"m\"\nbogus = 1\n",
                4,
                "bogus",
            ),
            (
                "name = \"a\"\ncommand = \"fft\"\nmodel = \"m\"\n",
                2,
                "unknown command 'fft'",
            ),
            (
                "name = \"a\"\ncommand = \"frf\"\nmodel = \"m\"\n[frf]\nfrom = 1.0\nto = 2.0\n\
                 [[sweep]]\nset = \"s.k\"\nvalues = []\n",
                7,
                "`values` is empty",
            ),
            (
                "name = \"a\"\ncommand = \"frf\"\nmodel = \"m\"\n[frf]\nfrom = 1.0\nto = 2.0\n\
                 mode = \"sideways\"\n",
                7,
                "'sideways'",
            ),
            (
                "name = \"a\"\ncommand = \"frf\"\nmodel = \"m\"\n[frf]\nfrom = 1.0\nto = 2.0\n\
                 ordering = \"metis5\"\n",
                7,
                "frf.ordering: 'metis5': use auto, amd or nd",
            ),
            (
                "name = \"a\"\ncommand = \"simulate\"\nmodel = \"m\"\n[simulate]\nduration = 1.0\n\
                 rate = 100.0\nmemory_budget = -2.0\n",
                7,
                "simulate.memory_budget: -2: give a positive number of GB",
            ),
            (
                "name = \"a\"\ncommand = \"simulate\"\nmodel = \"m\"\n[simulate]\nduration = 1.0\n\
                 rate = 100.0\nrestarts = 0\n",
                7,
                "simulate.restarts: 0: give at least 1",
            ),
        ];
        for (text, line, what) in cases {
            let e = Batch::parse(text, Path::new("jobs.toml")).unwrap_err();
            let msg = e.to_string();
            assert!(
                msg.starts_with(&format!("jobs.toml:{line}:")) && msg.contains(what),
                "{msg}"
            );
        }
    }

    #[test]
    fn lanczos_keys_reach_the_requests() {
        let frf = "name = \"a\"\ncommand = \"frf\"\nmodel = \"duffing_fig3\"\n[frf]\nfrom = 80.0\n\
                   to = 90.0\nbasis = 40\nrestarts = 7\nordering = \"nd\"\nmemory_budget = 2.5\n";
        let BatchCommand::Frf(r) = Batch::parse(frf, Path::new("j.toml")).unwrap().command else {
            panic!("an frf batch");
        };
        assert_eq!(r.lanczos.basis, Some(40));
        assert_eq!(r.lanczos.restarts, 7);
        assert_eq!(
            r.lanczos.ordering,
            nlsim_reduction::Ordering::NestedDissection
        );
        assert_eq!(r.lanczos.memory_budget, Some(2_500_000_000));
        let sim = "name = \"a\"\ncommand = \"simulate\"\nmodel = \"duffing_fig3\"\n[simulate]\n\
                   duration = 1.0\nrate = 100.0\nordering = \"amd\"\n";
        let BatchCommand::Simulate(r) = Batch::parse(sim, Path::new("j.toml")).unwrap().command
        else {
            panic!("a simulate batch");
        };
        let d = crate::commands::setup::Lanczos::default();
        assert_eq!(r.lanczos.ordering, nlsim_reduction::Ordering::Amd);
        assert_eq!(
            (r.lanczos.basis, r.lanczos.restarts, r.lanczos.memory_budget),
            (d.basis, d.restarts, d.memory_budget)
        );
    }

    #[test]
    fn the_hash_is_stable() {
        // FNV-1a test vector.
        assert_eq!(fnv1a(b"a"), 0xaf63_dc4c_8601_ec8c);
    }
}
