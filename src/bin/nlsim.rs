//! The `nlsim` command line. Exit codes: 0 success, 1 a run failed (bad model, numerical
//! failure), 2 bad usage.

use clap::{Args, Parser, Subcommand};
use nlsim::kernel::ValidationConfig;
use nlsim::reduction::{EigenConfig, EigenSolver, ModeSelection};
use std::io::Write as _;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Most worker threads `--threads` accepts.
const MAX_THREADS: usize = 1024;

/// Set once standard output cannot be written (a closed pipe: `nlsim ... | head`): the run
/// goes on quietly and still completes its result files.
static STDOUT_GONE: AtomicBool = AtomicBool::new(false);

/// Writes to standard output without panicking when it is closed: after the first failed
/// write nothing more is printed there. A broken pipe is silent (the reader has what it
/// wanted); any other failure is named once on stderr.
fn emit(args: std::fmt::Arguments<'_>, newline: bool) {
    if STDOUT_GONE.load(Ordering::Relaxed) {
        return;
    }
    let mut o = std::io::stdout().lock();
    let r = o
        .write_fmt(args)
        .and_then(|()| if newline { o.write_all(b"\n") } else { Ok(()) });
    if let Err(e) = r {
        STDOUT_GONE.store(true, Ordering::Relaxed);
        if e.kind() != std::io::ErrorKind::BrokenPipe {
            eprintln!("note: standard output cannot be written ({e}); the run goes on");
        }
    }
}

/// `println!` through [`emit`].
macro_rules! out {
    () => { emit(format_args!(""), true) };
    ($($t:tt)*) => { emit(format_args!($($t)*), true) };
}

/// `print!` through [`emit`].
macro_rules! out_part {
    ($($t:tt)*) => { emit(format_args!($($t)*), false) };
}

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Simulate and calibrate structures that are linear almost everywhere.
#[derive(Parser, Debug)]
#[command(name = "nlsim", version, about, long_about = None)]
struct Cli {
    /// Print only errors.
    #[arg(long, short, global = true, conflicts_with = "verbose")]
    quiet: bool,
    /// Print more detail (solver statistics, each batch job).
    #[arg(long, short, global = true)]
    verbose: bool,
    /// Worker threads for the parallel parts, 1 to 1024 (default: every core). Results do
    /// not depend on it.
    #[arg(long, global = true, value_name = "N")]
    threads: Option<usize>,
    #[command(subcommand)]
    command: Command,
}

/// The Lanczos settings of a run's reduction (as `nlsim modes --basis --restarts`): what the
/// eigensolver advises when modes do not converge.
#[derive(Args, Debug)]
struct LanczosArgs {
    /// Lanczos basis size before a restart (default max(2 k, k + 4 block) for k modes).
    #[arg(long)]
    basis: Option<usize>,
    /// Most Lanczos restarts before giving up.
    #[arg(long, default_value_t = 200)]
    restarts: usize,
    /// Fill-reducing ordering of the sparse factor: auto (the fewer factor values of amd and
    /// nd), amd (approximate minimum degree) or nd (METIS nested dissection).
    #[arg(long, default_value = "auto", value_parser = parse_ordering)]
    ordering: nlsim_reduction::Ordering,
    /// Memory the sparse factors may take together (GB); above it the Sturm check reuses the
    /// operator factor's storage, and the Lanczos iteration keeps no `M V` beside its basis
    /// unless that fits too. Default: half the memory available at start.
    #[arg(long, value_name = "GB")]
    memory_budget: Option<f64>,
}

fn parse_ordering(s: &str) -> Result<nlsim_reduction::Ordering, String> {
    nlsim_reduction::Ordering::parse(s)
        .ok_or_else(|| format!("'{s}' is not an ordering (auto, amd or nd)"))
}

impl LanczosArgs {
    fn settings(&self) -> Result<nlsim::run::Lanczos, nlsim::Error> {
        let memory_budget = match self.memory_budget {
            Some(gb) if gb.is_finite() && gb > 0.0 => Some((gb * 1e9) as usize),
            Some(gb) => {
                return Err(nlsim::Error::Usage(format!(
                    "--memory-budget {gb}: give a positive number of GB"
                )));
            }
            None => nlsim::run::default_memory_budget(),
        };
        Ok(nlsim::run::Lanczos {
            basis: self.basis,
            restarts: self.restarts,
            ordering: self.ordering,
            memory_budget,
        })
    }
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Load a model (file or built-in name), validate it and print its summary.
    Check {
        /// Model file (.toml) or built-in model, e.g. `ecl_beam` or `bracket:refinement=4`.
        model: String,
        /// Skip the Cholesky factorisations that prove M positive definite and K semi-definite.
        #[arg(long)]
        no_definiteness: bool,
    },
    /// List the built-in models and their options.
    Fixtures,
    /// Write a model's K and M as Matrix Market files and its DOF labels as text (for other
    /// tools, e.g. the scipy comparison in bench/).
    Export {
        /// Model file (.toml) or built-in model.
        model: String,
        /// Directory to write K.mtx, M.mtx and dofs.txt into (created if missing).
        dir: std::path::PathBuf,
    },
    /// Compute the lowest modes: frequencies, damping, effective masses; write them to a file.
    #[command(allow_negative_numbers = true)]
    Modes {
        /// Model file (.toml) or built-in model, e.g. `bracket:dofs=100000`.
        model: String,
        /// Number of lowest modes (default 10, or every mode of a smaller model).
        #[arg(long, conflicts_with = "fmax")]
        count: Option<usize>,
        /// Every mode below this frequency (Hz) instead of a count.
        #[arg(long)]
        fmax: Option<f64>,
        /// Output file: .h5 (HDF5, with mode shapes) or .csv (the table).
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Convergence tolerance of the Ritz residuals.
        #[arg(long, default_value_t = 1e-10)]
        tol: f64,
        /// Lanczos block size (the largest multiplicity found without relying on round-off).
        #[arg(long, default_value_t = 6)]
        block: usize,
        #[command(flatten)]
        lanczos: LanczosArgs,
        /// Skip the Sturm sequence check (saves one factorisation; `--fmax` always counts).
        #[arg(long)]
        no_sturm_check: bool,
        /// Report folder: index.html (table, frequency and effective-mass plots), report.h5
        /// with the modes, plots as SVG and PNG.
        #[arg(long)]
        report: Option<std::path::PathBuf>,
    },
    /// Time response of a model: the exponential-hold integrator on the reduced model (FOH,
    /// or ZOH/LSOH for bias studies) or a reference (RK45, RK4, Newmark/HHT on the unreduced
    /// model); writes time histories.
    #[command(allow_negative_numbers = true)]
    Simulate {
        /// Model file (.toml) or built-in model, e.g. `bumpstop_cantilever`.
        model: String,
        /// Simulated time (s).
        #[arg(long)]
        duration: f64,
        /// Sample rate (Hz): the step of foh/zoh/lsoh, the output rate of the others.
        #[arg(long)]
        rate: f64,
        /// Integration method.
        #[arg(long, value_enum, default_value_t = Method::Foh)]
        method: Method,
        /// Force at the excitation points: SPEC for all of them or NAME=SPEC for one. SPEC is
        /// `none`, `sine:freq=HZ[,amp=N][,phase=DEG]`,
        /// `multisine:freq=HZ,h1=N[@DEG],h2=..,h1/3=..` (cosines: `hK=A@DEG` is
        /// A cos(K Ω t + DEG), as in `frf`; without harmonics each point's own from the model),
        /// `sweep:f0=HZ,f1=HZ[,amp=N][,duration=S][,log=true]` or `file:PATH[,rate=HZ]`
        /// (one force per line). `amp` defaults to the point's nominal amplitude. Default: a
        /// sine at the first natural frequency.
        #[arg(long)]
        excitation: Vec<String>,
        /// Output file: .h5 (HDF5) or .csv.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Retained modes of the reduced model (foh, zoh, lsoh, rk45, rk4).
        #[arg(long, default_value_t = 20)]
        modes: usize,
        /// Leave out the residual flexibility of the truncated modes.
        #[arg(long)]
        no_residual: bool,
        /// Do not locate contact events inside steps (foh).
        #[arg(long)]
        no_events: bool,
        #[command(flatten)]
        lanczos: LanczosArgs,
        /// Compress the HDF5 series (shuffle + deflate): about 1.8x smaller, 2.5x slower to write
        #[arg(long)]
        compress: bool,
        /// RK45 relative tolerance (ODE45's default 1e-3).
        #[arg(long, default_value_t = 1e-3)]
        rtol: f64,
        /// RK45 absolute tolerance on the modal states, √kg m (default: scaled to the response,
        /// 1e-3 rtol of the largest static modal state under the peak force; ODE45's fixed 1e-6
        /// is as large as a typical structure's states)
        #[arg(long)]
        atol: Option<f64>,
        /// Integration steps per sample (rk4, newmark, hht).
        #[arg(long, default_value_t = 1)]
        substeps: usize,
        /// HHT alpha in [-1/3, 0] (hht).
        #[arg(long, default_value_t = -0.05)]
        hht_alpha: f64,
        /// Report folder: index.html (summary, a plot per output, element force against
        /// displacement), report.h5 with the whole history, plots as SVG and PNG.
        #[arg(long)]
        report: Option<std::path::PathBuf>,
        /// Set an element parameter for this run: `element.param=value` (repeatable).
        #[arg(long)]
        set: Vec<String>,
    },
    /// Multi-harmonic nonlinear FRF by harmonic balance (condensed on the nonlinear DOFs):
    /// continuation through folds with Hill stability, or a stepped sine up or down as a test
    /// would run it; writes every harmonic at every sensor and an SVG plot.
    #[command(allow_negative_numbers = true)]
    Frf {
        /// Model file (.toml) or built-in model, e.g. `duffing_fig3`.
        model: String,
        /// Start frequency (Hz).
        #[arg(long)]
        from: f64,
        /// End frequency (Hz).
        #[arg(long)]
        to: f64,
        /// Harmonics H of the base frequency Ω/ν kept.
        #[arg(long, default_value_t = 7)]
        harmonics: usize,
        /// Sub-harmonic order ν: base frequency Ω/ν (1: none).
        #[arg(long, default_value_t = 1)]
        subharmonic: usize,
        /// Force amplitude (N) at the fundamental on every excitation point (default: the
        /// model's nominal amplitudes), a cosine: the phase reference.
        #[arg(long)]
        force: Option<f64>,
        /// A further force harmonic on every excitation point, `K=AMP[@DEG]` (AMP cos(KΩt +
        /// DEG)) or `1/K=AMP[@DEG]` at Ω/K (repeatable; replaces the model's
        /// [[excitation.harmonic]]), e.g. `--force-harmonic 2=1 --force-harmonic 3=2@90`.
        #[arg(long = "force-harmonic", value_name = "K=AMP[@DEG]")]
        force_harmonic: Vec<String>,
        /// Continuation (through folds, unstable parts included) or a stepped sine.
        #[arg(long, value_enum, default_value = "continuation")]
        mode: FrfMode,
        /// Stepped sine: its frequencies, evenly spaced (default 400). Continuation: the
        /// fewest points over the range (the step in frequency is at most the range over
        /// POINTS − 1).
        #[arg(long)]
        points: Option<usize>,
        /// Continuation: the largest step in frequency (Hz; default 2 % of the range).
        #[arg(long, value_name = "HZ")]
        max_step: Option<f64>,
        /// Continuation start: `auto` (from rest, or with --subharmonic ≥ 2 from a
        /// sub-harmonic solution searched over the range), `rest` (the primary branch),
        /// `subharmonic` (fail when none is found).
        #[arg(long, default_value = "auto", value_parser = ["auto", "rest", "subharmonic"])]
        start: String,
        /// Continuation start from a point of an earlier `nlsim frf --out FILE.h5` (the same
        /// model and --subharmonic; other harmonics are cut or padded): the branch through it
        /// is followed to both ends of the range. The point is the one nearest --start-hz,
        /// or within the range the one with the most sub-harmonic content (largest response
        /// when --subharmonic is 1).
        #[arg(long, value_name = "FILE.h5")]
        start_file: Option<std::path::PathBuf>,
        /// With --start-file: start from the file's point nearest this frequency (Hz).
        #[arg(long, value_name = "HZ", requires = "start_file")]
        start_hz: Option<f64>,
        /// Retained modes of the reduced model.
        #[arg(long, default_value_t = 20)]
        modes: usize,
        /// Leave out the residual flexibility of the truncated modes.
        #[arg(long)]
        no_residual: bool,
        /// Skip Hill stability (faster; no stable/unstable distinction).
        #[arg(long)]
        no_stability: bool,
        #[command(flatten)]
        lanczos: LanczosArgs,
        /// Output file: .h5 (HDF5) or .csv.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Plot of the first sensor against frequency, one panel per harmonic, FILE.svg or
        /// FILE.png (default: beside --out, .svg).
        #[arg(long)]
        plot: Option<std::path::PathBuf>,
        /// Magnitude axes of the plot: linear, log or db (dB re 1 unit).
        #[arg(long, default_value = "linear")]
        magnitude: nlsim::frf::Magnitude,
        /// Add a phase panel beside each magnitude panel of the plot.
        #[arg(long)]
        phase: bool,
        /// Report folder: index.html (summary, folds/jumps/peaks tables, the plot of every
        /// sensor), report.h5 with the data, plots as SVG and PNG.
        #[arg(long)]
        report: Option<std::path::PathBuf>,
        /// Element parameter overrides, e.g. `--set spring.k3=2e15` (repeatable).
        #[arg(long)]
        set: Vec<String>,
    },
    /// Calibrate model parameters on stepped-sine test data (CSV, docs/file-formats.md):
    /// Latin-hypercube candidates, bounded Levenberg–Marquardt on the multi-harmonic
    /// responses with the measured force, Cramér–Rao bounds and k-fold cross validation.
    /// Give MODEL DATA --param ..., or a calibration file with --config (docs/calibration.md;
    /// options given beside it override the file).
    #[command(allow_negative_numbers = true)]
    Calibrate {
        /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
        #[arg(required_unless_present = "config", conflicts_with = "config")]
        model: Option<String>,
        /// Test data: stepped-sine CSV or HDF5 (docs/file-formats.md), linear FRFs in
        /// universal file dataset 58 (.uff/.unv, ASCII or binary; 1 % noise assumed), or
        /// measured modes as CSV (mode,frequency_hz,frequency_std_hz,DOF...: FE-level
        /// parameters from frequencies and shapes).
        #[arg(required_unless_present = "config", conflicts_with = "config")]
        data: Option<std::path::PathBuf>,
        /// Calibration file (TOML): model, data, parameters, bounds and every setting.
        #[arg(long)]
        config: Option<std::path::PathBuf>,
        /// A parameter and its bounds, `NAME=LOWER:UPPER` (repeatable), e.g.
        /// `--param tip_spring.k3=1e8:1e11 --param mode2.zeta=0.002:0.05`.
        #[arg(
            long = "param",
            required_unless_present = "config",
            conflicts_with = "config"
        )]
        params: Vec<String>,
        /// Fixed overrides `element.param=value` applied before calibrating (repeatable).
        #[arg(long, conflicts_with = "config")]
        set: Vec<String>,
        /// Harmonics compared (1 = fundamental only), e.g. `1,3` [default: 1].
        #[arg(long, value_delimiter = ',')]
        compare: Option<Vec<usize>>,
        /// Residual form: complex differences or log-magnitude and phase [default: complex].
        #[arg(long, value_enum)]
        form: Option<CalibForm>,
        /// Branch of a multi-valued response the model is compared on: `nearest` repeats a
        /// step from the linear response where the continued solution is far (5σ) from
        /// the measurement and keeps the nearer solution (the test jumped elsewhere than
        /// the model); `continuation` follows the model's own branch [default: nearest].
        #[arg(long, value_enum)]
        branch: Option<CalibBranch>,
        /// Harmonics H kept by the harmonic balance [default: 3].
        #[arg(long)]
        harmonics: Option<usize>,
        /// Retained modes of the reduced model (modal data: the computed modes paired with
        /// the measured ones) [default: 20, at most the model's DOFs].
        #[arg(long)]
        modes: Option<usize>,
        /// Modal data: standard deviation of one component of a unit-normalised measured
        /// shape [default: 0.02].
        #[arg(long)]
        shape_noise: Option<f64>,
        /// Latin-hypercube candidates [default: 64].
        #[arg(long)]
        lhs: Option<usize>,
        /// Levenberg–Marquardt runs from the best candidates [default: 3].
        #[arg(long)]
        starts: Option<usize>,
        /// Folds of the cross validation (0: none) [default: 10].
        #[arg(long)]
        folds: Option<usize>,
        /// Seed of the Latin hypercube and of the folds [default: 1].
        #[arg(long)]
        seed: Option<u64>,
        /// Candidates already evaluated: the merged file of a `calibrate-candidates` batch
        /// of this calibration (docs/batch.md).
        #[arg(long)]
        candidates: Option<std::path::PathBuf>,
        /// Estimates and statistics as CSV.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Report folder: summary, tables (estimates, candidates, convergence, folds, fit)
        /// and plots as SVG and PNG (per-harmonic FRFs, k-fold bars, convergence).
        #[arg(long)]
        report: Option<std::path::PathBuf>,
    },
    /// Pre-test planning: rank candidate tests (drive points, force levels, multi-sine
    /// signals, frequency bands, sensor sets, measured harmonics) by the Fisher information
    /// of the parameters from the analytic sensitivities, with Cramér–Rao bounds and
    /// collinearity. PLAN is a plan file (docs/planning.md).
    Plan {
        /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
        model: String,
        /// Plan file (TOML): parameters and candidates.
        plan: std::path::PathBuf,
        /// Ranking criterion: D, T, A, E or max-variance [default: the file's, else D].
        #[arg(long)]
        criterion: Option<String>,
        /// Rows of the printed table [default: the file's, else 10].
        #[arg(long)]
        top: Option<usize>,
        /// Report folder: summary, ranking.csv, fim_best.csv and plots [default: the file's,
        /// else PLAN's name with `-report`, beside it].
        #[arg(long)]
        report: Option<std::path::PathBuf>,
    },
    /// Virtual stepped-sine test through an electrodynamic shaker model, voltage-driven or
    /// force-controlled off line; writes test data that `nlsim calibrate` reads. TEST is a
    /// test file (docs/planning.md).
    Test {
        /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
        model: String,
        /// Test file (TOML): drive point, shaker, controller, sweeps, noise.
        test: std::path::PathBuf,
        /// Test data, .csv or .h5 [default: the file's `out`, else virtual_test.csv beside
        /// it].
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Seed of the measurement noise [default: the file's, else 1].
        #[arg(long)]
        seed: Option<u64>,
        /// Run voltage-driven only (no force control).
        #[arg(long)]
        open_loop: bool,
        /// Report folder: summary, control.csv and force/response plots [default: the
        /// file's, else TEST's name with `-report`, beside it].
        #[arg(long)]
        report: Option<std::path::PathBuf>,
    },
    /// A nonlinear mode by the extended periodic motion concept: the free periodic motions
    /// of mode N followed in amplitude, with the frequency (backbone) and the modal damping
    /// ratio that the model's damping and dissipative elements give at each amplitude.
    #[command(allow_negative_numbers = true)]
    Nnm {
        /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
        model: String,
        /// The linear mode it grows from (1 = the lowest).
        #[arg(long, default_value_t = 1)]
        mode: usize,
        /// Smallest modal amplitude (m √kg: the fundamental's cosine coefficient of the
        /// mass-normalised modal coordinate).
        #[arg(long)]
        from: f64,
        /// Largest modal amplitude (m √kg).
        #[arg(long)]
        to: f64,
        /// Amplitudes, evenly spaced in their logarithm.
        #[arg(long, default_value_t = 50)]
        points: usize,
        /// Harmonics H of the frequency.
        #[arg(long, default_value_t = 7)]
        harmonics: usize,
        /// Retained modes of the reduced model.
        #[arg(long, default_value_t = 10)]
        modes: usize,
        #[command(flatten)]
        lanczos: LanczosArgs,
        /// Output file: .h5 (HDF5) or .csv.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Plot of frequency and damping ratio against amplitude, FILE.svg (default: beside
        /// --out; the damping ratio in FILE-damping.svg).
        #[arg(long)]
        plot: Option<std::path::PathBuf>,
        /// Element parameter overrides, e.g. `--set tip.k3=6e9` (repeatable).
        #[arg(long)]
        set: Vec<String>,
    },
    /// Run the pipeline on a built-in model, print a readable summary and write a report
    /// folder with plots.
    Demo {
        /// Model to run on (default: the ECL benchmark beam).
        #[arg(long, default_value = "ecl_beam")]
        model: String,
        /// Report folder (plots as SVG and PNG, the summary as text).
        #[arg(long, default_value = "nlsim-report")]
        report: std::path::PathBuf,
    },
    /// Many runs of `frf` or `simulate` from a jobs file (sweeps, load cases, Latin-hypercube
    /// candidates), split into shards for cluster job arrays: `nlsim batch JOBS.toml` runs
    /// shards, `nlsim batch merge JOBS.toml` joins them, `nlsim batch sbatch JOBS.toml` writes
    /// the SLURM script. See docs/batch.md.
    #[command(args_conflicts_with_subcommands = true)]
    Batch {
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
    },
}

/// `nlsim batch merge` and `nlsim batch sbatch`.
#[derive(Subcommand, Debug)]
enum BatchAction {
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

use nlsim::run::{Method, SweepMode as FrfMode};

/// The parallelism `--threads` asks for: sequential for 1, the rayon pool otherwise.
fn par(cli: &Cli) -> faer::Par {
    match cli.threads {
        Some(1) => faer::Par::Seq,
        _ => faer::Par::rayon(0),
    }
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return usage_error(&e),
    };
    if let Some(n) = cli.threads {
        if !(1..=MAX_THREADS).contains(&n) {
            eprintln!(
                "error: --threads {n}: give 1 to {MAX_THREADS} (each thread reserves a stack; \
                 more threads than cores only slow the run down)"
            );
            return ExitCode::from(2);
        }
        // The first and only global pool: cannot fail here.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global();
    }
    // faer's implicit parallelism (dense decompositions that take no `Par`) stays
    // sequential: a blocked LU or SVD split over another number of threads rounds
    // differently, and every parallel region of nlsim names its `Par` explicitly, so the
    // numbers do not depend on the thread count.
    faer::set_global_parallelism(faer::Par::Seq);
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e @ nlsim::Error::Usage(_)) => {
            eprintln!("error: {}", nlsim::output::one_line(&e.to_string()));
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("error: {}", nlsim::output::one_line(&e.to_string()));
            ExitCode::from(1)
        }
    }
}

/// Prints a command-line error of clap in one line (its first line, with its tip) and
/// returns exit code 2; help and version go out as clap writes them.
fn usage_error(e: &clap::Error) -> ExitCode {
    use clap::error::ErrorKind;
    if matches!(
        e.kind(),
        ErrorKind::DisplayHelp
            | ErrorKind::DisplayVersion
            | ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand
    ) {
        let _ = e.print();
        return ExitCode::from(
            if e.kind() == ErrorKind::DisplayHelpOnMissingArgumentOrSubcommand {
                2
            } else {
                0
            },
        );
    }
    // clap's text: the message (lines up to `Usage:`), then tips, usage and a pointer.
    let text = e.render().to_string();
    let mut message = String::new();
    let mut tips = Vec::new();
    for line in text.lines().map(str::trim).filter(|l| !l.is_empty()) {
        if line.starts_with("Usage:") || line.starts_with("For more information") {
            break;
        }
        if let Some(t) = line.strip_prefix("tip: ") {
            tips.push(t);
        } else {
            let line = line.strip_prefix("error: ").unwrap_or(line);
            if !message.is_empty() {
                message.push(' ');
            }
            message.push_str(line);
        }
    }
    let tips = if tips.is_empty() {
        String::new()
    } else {
        format!(" ({})", nlsim::output::one_line(&tips.join("; ")))
    };
    eprintln!(
        "error: {}{tips} — see nlsim --help",
        nlsim::output::one_line(&message)
    );
    ExitCode::from(2)
}

fn run(cli: &Cli) -> nlsim::Result<()> {
    match &cli.command {
        Command::Check {
            model,
            no_definiteness,
        } => {
            let loaded = nlsim::load_model(model)?;
            let cfg = ValidationConfig {
                check_definiteness: !no_definiteness,
                ..Default::default()
            };
            let report = loaded.model.validate(&cfg)?;
            if !cli.quiet {
                out_part!(
                    "{}",
                    nlsim::summary::model_summary(&loaded.model, &loaded.source, Some(&report))
                );
            }
            Ok(())
        }
        Command::Fixtures => {
            for f in nlsim::fixtures::CATALOGUE {
                out!("{:<26} {}", f.name, f.summary);
                for (k, d) in f.options {
                    out!("    {k:<20} {d}");
                }
            }
            Ok(())
        }
        Command::Modes {
            model,
            count,
            fmax,
            out,
            tol,
            block,
            lanczos,
            no_sturm_check,
            report: report_dir,
        } => {
            if let Some(path) = out {
                // Refuse an unknown format before the (possibly long) solve.
                nlsim::output::Format::of(path, nlsim::modes::HINT)?;
            }
            let loaded = nlsim::load_model(model)?;
            let selection = match (count, fmax) {
                (_, Some(f)) => ModeSelection::Below { f_max_hz: *f },
                (Some(c), None) => ModeSelection::Lowest(*c),
                // The default: 10 modes, or every mode of a smaller model.
                (None, None) => ModeSelection::Lowest(10.min(loaded.model.n_dofs())),
            };
            let settings = lanczos.settings()?;
            let cfg = EigenConfig {
                selection,
                tol: *tol,
                block_size: *block,
                basis_size: settings.basis,
                max_restarts: settings.restarts,
                ordering: settings.ordering,
                memory_budget: settings.memory_budget,
                sturm_check: !no_sturm_check,
                par: par(cli),
                ..EigenConfig::default()
            };
            // Symmetry, finiteness, massless DOFs; definiteness shows in the factorisation.
            loaded.model.validate(&ValidationConfig {
                check_definiteness: false,
                ..Default::default()
            })?;
            let report = modes(&loaded.model, cfg, cli.quiet)?;
            if !cli.quiet {
                out!(
                    "{}",
                    nlsim::summary::model_summary(&loaded.model, &loaded.source, None)
                );
                out_part!("{}", nlsim::modes::format_table(&report));
            }
            if let Some(path) = out {
                nlsim::modes::write_modes(path, model, &loaded.model, &report)?;
                if !cli.quiet {
                    out!("  written to {}", path.display());
                }
            }
            if let Some(dir) = report_dir {
                let page = nlsim::modes::write_report(
                    dir,
                    model,
                    &loaded.model,
                    &report,
                    &nlsim::report::command_line(),
                )?;
                if !cli.quiet {
                    out!("  report {}", page.display());
                }
            }
            Ok(())
        }
        Command::Export { model, dir } => {
            let loaded = nlsim::load_model(model)?;
            std::fs::create_dir_all(dir).map_err(|source| nlsim::Error::Io {
                path: dir.clone(),
                source,
            })?;
            let m = &loaded.model;
            let labels: String = (0..m.n_dofs())
                .map(|i| m.dofs().describe(i) + "\n")
                .collect();
            for (name, text) in [
                ("K.mtx", nlsim::mtx::to_matrix_market(m.stiffness())),
                ("M.mtx", nlsim::mtx::to_matrix_market(m.mass())),
                ("dofs.txt", labels),
            ] {
                // Atomic: a killed export or a full disk leaves no truncated file under
                // the final name.
                nlsim::output::write_text_atomically(&dir.join(name), &text)?;
            }
            if !cli.quiet {
                out!(
                    "wrote K.mtx, M.mtx, dofs.txt ({} DOFs) to {}",
                    m.n_dofs(),
                    dir.display()
                );
            }
            Ok(())
        }
        Command::Simulate {
            model,
            duration,
            rate,
            method,
            excitation,
            out,
            modes,
            no_residual,
            no_events,
            lanczos,
            compress,
            rtol,
            atol,
            substeps,
            hht_alpha,
            report,
            set,
        } => {
            let req = nlsim::run::SimRequest {
                duration: *duration,
                rate: *rate,
                method: *method,
                excitation: excitation
                    .iter()
                    .map(|e| nlsim::run::Drive::parse(e, *duration, *rate))
                    .collect::<nlsim::Result<_>>()?,
                modes: *modes,
                residual: !no_residual,
                events: !no_events,
                rtol: *rtol,
                atol: *atol,
                substeps: *substeps,
                hht_alpha: *hht_alpha,
                par: par(cli),
                lanczos: lanczos.settings()?,
            };
            simulate(
                model,
                &req,
                set,
                (out.as_deref(), report.as_deref()),
                *compress,
                cli,
            )
        }
        Command::Frf {
            model,
            from,
            to,
            harmonics,
            subharmonic,
            force,
            force_harmonic,
            mode,
            points,
            max_step,
            start,
            start_file,
            start_hz,
            modes,
            no_residual,
            no_stability,
            lanczos,
            out,
            plot,
            magnitude,
            phase,
            report,
            set,
        } => {
            let req = nlsim::run::FrfRequest {
                from_hz: *from,
                to_hz: *to,
                harmonics: *harmonics,
                subharmonic: *subharmonic,
                force: *force,
                force_harmonics: force_harmonic
                    .iter()
                    .map(|t| nlsim::run::parse_force_harmonic(t))
                    .collect::<nlsim::Result<_>>()?,
                mode: *mode,
                points: *points,
                max_step_hz: *max_step,
                start: nlsim::run::FrfStart::parse(start).expect("clap checked the value"),
                start_file: start_file.as_ref().map(|path| nlsim::run::StartFile {
                    path: path.clone(),
                    at_hz: *start_hz,
                }),
                modes: *modes,
                residual: !no_residual,
                stability: !no_stability,
                par: par(cli),
                lanczos: lanczos.settings()?,
            };
            let outputs = FrfOutputs {
                out: out.as_deref(),
                plot: plot.as_deref(),
                magnitude: *magnitude,
                phase: *phase,
                report: report.as_deref(),
            };
            frf(model, &req, set, &outputs, cli)
        }
        Command::Nnm {
            model,
            mode,
            from,
            to,
            points,
            harmonics,
            modes,
            lanczos,
            out,
            plot,
            set,
        } => {
            let req = nlsim::nnm::NnmRequest {
                mode: *mode,
                from: *from,
                to: *to,
                points: *points,
                harmonics: *harmonics,
                modes: *modes,
                par: par(cli),
                lanczos: lanczos.settings()?,
            };
            nnm(model, &req, set, (out.as_deref(), plot.as_deref()), cli)
        }
        Command::Demo { model, report } => demo(model, report, cli.quiet),
        Command::Plan {
            model,
            plan,
            criterion,
            top,
            report,
        } => {
            let mut req = nlsim::pretest::PlanRequest::load(plan, model)?;
            if let Some(c) = criterion {
                req.criterion = nlsim::calib::Criterion::parse(c)
                    .map_err(|e| nlsim::Error::Usage(format!("--criterion: {e}")))?;
            }
            if let Some(t) = top {
                req.top = *t;
            }
            if let Some(r) = report {
                req.report = Some(r.clone());
            }
            if req.report.is_none() {
                req.report = Some(default_report(plan));
            }
            plan_cmd(&req, cli)
        }
        Command::Test {
            model,
            test,
            out,
            seed,
            open_loop,
            report,
        } => {
            let mut req = nlsim::vtest::TestRequest::load(test, model)?;
            if let Some(o) = out {
                req.out = o.clone();
            }
            if let Some(s) = seed {
                req.seed = *s;
            }
            if *open_loop {
                req.control.enabled = false;
                req.compare_open_loop = false;
            }
            if let Some(r) = report {
                req.report = Some(r.clone());
            }
            if req.report.is_none() {
                req.report = Some(default_report(test));
            }
            test_cmd(&req, cli)
        }
        Command::Calibrate {
            model,
            data,
            config,
            params,
            set,
            compare,
            form,
            branch,
            harmonics,
            modes,
            shape_noise,
            lhs,
            starts,
            folds,
            seed,
            candidates,
            out,
            report,
        } => {
            let mut req = match (config, model, data) {
                (Some(path), _, _) => nlsim::calibration::CalibrationRequest::load(path)?,
                (None, Some(model), Some(data)) => {
                    let specs = params
                        .iter()
                        .map(|p| nlsim::calibration::parse_param_bounds(p))
                        .collect::<nlsim::Result<Vec<_>>>()?;
                    let mut r = nlsim::calibration::CalibrationRequest::new(
                        model.clone(),
                        data.clone(),
                        specs,
                    );
                    r.set = set.clone();
                    r
                }
                _ => unreachable!("clap requires MODEL and DATA without --config"),
            };
            if let Some(v) = compare {
                req.compare = v.clone();
            }
            if let Some(f) = form {
                req.form = match f {
                    CalibForm::Complex => nlsim::calib::Form::Complex,
                    CalibForm::LogMagnitude => nlsim::calib::Form::LogMagnitudePhase,
                };
            }
            if let Some(b) = branch {
                req.branch = match b {
                    CalibBranch::Nearest => nlsim::calib::BranchChoice::NearestToData,
                    CalibBranch::Continuation => nlsim::calib::BranchChoice::Continuation,
                };
            }
            let c = &mut req.config;
            for (dst, src) in [
                (&mut req.harmonics, harmonics),
                (&mut req.modes, modes),
                (&mut c.lhs_samples, lhs),
                (&mut c.starts, starts),
                (&mut c.folds, folds),
            ] {
                if let Some(v) = src {
                    *dst = *v;
                }
            }
            if let Some(s) = seed {
                c.seed = *s;
            }
            if let Some(s) = shape_noise {
                req.shape_noise = *s;
            }
            if out.is_some() {
                req.out = out.clone();
            }
            if report.is_some() {
                req.report = report.clone();
            }
            calibrate_cmd(&req, candidates.as_deref(), cli)
        }
        Command::Batch {
            action,
            jobs,
            task_index,
            task_count,
            output,
        } => match action {
            Some(BatchAction::Merge { jobs, output }) => batch_merge(jobs, output.as_deref(), cli),
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
                let o = nlsim::batch::SbatchOptions {
                    tasks: *tasks,
                    cpus_per_task: *cpus_per_task,
                    partition: partition.clone(),
                    time: time.clone(),
                    mem: mem.clone(),
                };
                batch_sbatch(jobs, output.as_deref(), &o, *submit, cli)
            }
            None => {
                let jobs = jobs.as_ref().ok_or_else(|| {
                    nlsim::Error::Usage(
                        "nlsim batch needs a jobs file: nlsim batch JOBS.toml (or merge, sbatch)"
                            .into(),
                    )
                })?;
                batch_run(jobs, *task_index, *task_count, output.as_deref(), cli)
            }
        },
    }
}

/// Solves for the modes with a progress line on stderr.
fn modes(
    model: &nlsim::kernel::Model,
    cfg: EigenConfig,
    quiet: bool,
) -> nlsim::Result<nlsim::modes::ModeReport> {
    let t = Instant::now();
    // A progress line only on a terminal: in a log its carriage returns pile up.
    let show = !quiet && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut solver = EigenSolver::new();
    let modes = solver
        .solve_with_progress(model.stiffness(), model.mass(), &cfg, &mut |p| {
            if show {
                eprint!(
                    "\r  modes: {}/{} converged after {} restart(s), {:.1} s ",
                    p.converged,
                    p.wanted,
                    p.restart,
                    t.elapsed().as_secs_f64()
                );
            }
        })
        .and_then(nlsim::reduction::Modes::into_converged);
    if show
        && modes
            .as_ref()
            .is_ok_and(|m| m.stats.method == nlsim::reduction::EigenMethod::Lanczos)
    {
        eprintln!();
    }
    Ok(nlsim::modes::ModeReport::new(model, modes?, cfg))
}

/// Residual form of `nlsim calibrate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum CalibForm {
    /// Real and imaginary parts of the complex difference.
    Complex,
    /// Log-magnitude and phase differences.
    LogMagnitude,
}

/// Branch choice of `nlsim calibrate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum CalibBranch {
    /// The solution nearer to the measurement where the continued one is far from it.
    Nearest,
    /// The model's own continuation from the previous step.
    Continuation,
}

/// `nlsim calibrate`: the run, its summary, the estimates CSV and the report folder.
fn calibrate_cmd(
    req: &nlsim::calibration::CalibrationRequest,
    candidates: Option<&std::path::Path>,
    cli: &Cli,
) -> nlsim::Result<()> {
    use nlsim::calib::Progress;
    req.check()?;
    let say = |s: &str| {
        if !cli.quiet {
            out!("{s}");
        }
    };
    let candidates = match candidates {
        None => None,
        Some(p) => Some((p.to_path_buf(), nlsim::batch::read_candidates(p)?)),
    };
    let show = !cli.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let progress = |p: Progress| {
        if show {
            let (what, d, n) = match p {
                Progress::Candidates { done, total } => ("candidates", done, total),
                Progress::Start { done, total } => ("optimisations", done, total),
                Progress::Fold { done, total } => ("folds", done, total),
            };
            eprint!("\r  {what} {d}/{n}        ");
            if d == n {
                eprintln!();
            }
        }
    };
    let modal = req
        .data
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
        && nlsim::modaldata::is_modal_csv(&req.data)?;
    if modal {
        if candidates.is_some() {
            return Err(nlsim::Error::Usage(
                "--candidates: a modal-data calibration evaluates its candidates itself (it \
                 has no batch kinds)"
                    .into(),
            ));
        }
        let run = nlsim::modal_calibration::run_modal_calibration(req)?;
        for line in run.summary() {
            say(&line);
        }
        if let Some(o) = &req.out {
            std::fs::write(o, run.estimates_csv()).map_err(|source| nlsim::Error::Io {
                path: o.clone(),
                source,
            })?;
            say(&format!("wrote {}", o.display()));
        }
        if let Some(dir) = &req.report {
            let files = nlsim::modal_calibration::write_modal_report(dir, &run)?;
            say(&format!(
                "report: {} files in {} (summary.txt, tables, convergence plot)",
                files.len(),
                dir.display()
            ));
        }
        return Ok(());
    }
    let run = nlsim::calibration::run_calibration(req, candidates, &progress)?;
    for line in run.summary() {
        say(&line);
    }
    if let Some(o) = &req.out {
        std::fs::write(o, run.estimates_csv()).map_err(|source| nlsim::Error::Io {
            path: o.clone(),
            source,
        })?;
        say(&format!("wrote {}", o.display()));
    }
    if let Some(dir) = &req.report {
        let files = nlsim::calibration::write_report(dir, &run)?;
        say(&format!(
            "report: {} files in {} (summary.txt, tables, plots as SVG and PNG)",
            files.len(),
            dir.display()
        ));
    }
    Ok(())
}

/// `DIR/NAME-report` for a settings file `DIR/NAME.toml`.
fn default_report(file: &std::path::Path) -> std::path::PathBuf {
    let stem = file
        .file_stem()
        .map_or("nlsim".into(), |s| s.to_string_lossy());
    file.with_file_name(format!("{stem}-report"))
}

/// `nlsim plan`: the ranked table and the report.
fn plan_cmd(req: &nlsim::pretest::PlanRequest, cli: &Cli) -> nlsim::Result<()> {
    req.check()?;
    let progress = std::sync::Mutex::new(progress_line(cli.quiet, "candidate sweeps"));
    let run = nlsim::pretest::run_plan(req, &|d, n| {
        if let Ok(mut p) = progress.lock() {
            p(d, n)
        }
    })?;
    if !cli.quiet {
        for line in run.summary() {
            out!("{line}");
        }
    }
    if let Some(dir) = &req.report {
        let files = nlsim::pretest::write_plan_report(dir, &run)?;
        if !cli.quiet {
            out!(
                "report: {} files in {} (summary.txt, ranking.csv, fim_best.csv, plots as SVG \
                 and PNG); the best design as a test file: nlsim test {} {}",
                files.len(),
                dir.display(),
                req.model,
                dir.join("best_test.toml").display()
            );
        }
    }
    Ok(())
}

/// `nlsim test`: the virtual test, its data and its report.
fn test_cmd(req: &nlsim::vtest::TestRequest, cli: &Cli) -> nlsim::Result<()> {
    let mut progress = progress_line(cli.quiet, "sweeps");
    let run = nlsim::vtest::run_test(req, &mut progress)?;
    progress(req.sweeps.len(), req.sweeps.len());
    if !cli.quiet {
        for line in run.summary() {
            out!("{line}");
        }
    }
    if let Some(dir) = &req.report {
        let files = nlsim::vtest::write_test_report(dir, &run)?;
        if !cli.quiet {
            out!(
                "report: {} files in {} (summary.txt, control.csv, force and response plots)",
                files.len(),
                dir.display()
            );
        }
    }
    Ok(())
}

/// `nlsim demo`: the pipeline in [`nlsim::demo`], printed unless `--quiet`.
fn demo(model: &str, report_dir: &std::path::Path, quiet: bool) -> nlsim::Result<()> {
    let command_line = nlsim::report::command_line();
    nlsim::demo::run_demo(model, report_dir, &command_line, &|s: &str| {
        if !quiet {
            out!("{s}");
        }
    })
}

/// A progress line on stderr, only when it is a terminal.
fn progress_line(quiet: bool, what: &'static str) -> impl FnMut(usize, usize) {
    use std::io::IsTerminal;
    let show = !quiet && std::io::stderr().is_terminal();
    let t = Instant::now();
    move |done, total| {
        if show {
            eprint!(
                "\r  {what}: {:3.0} % ({done}/{total}, {:.1} s) ",
                100.0 * done as f64 / total.max(1) as f64,
                t.elapsed().as_secs_f64()
            );
            if done == total {
                eprintln!();
            }
        }
    }
}

/// Where `nlsim frf` writes and how it plots.
struct FrfOutputs<'a> {
    out: Option<&'a std::path::Path>,
    plot: Option<&'a std::path::Path>,
    magnitude: nlsim::frf::Magnitude,
    phase: bool,
    report: Option<&'a std::path::Path>,
}

fn frf(
    spec: &str,
    req: &nlsim::run::FrfRequest,
    sets: &[String],
    outputs: &FrfOutputs<'_>,
    cli: &Cli,
) -> nlsim::Result<()> {
    use std::f64::consts::PI;
    let FrfOutputs {
        out,
        plot,
        magnitude,
        phase,
        report,
    } = *outputs;
    let quiet = cli.quiet;
    // Refuse bad options and output names before the (possibly long) solve.
    let set = req.check()?;
    if let Some(path) = out {
        nlsim::output::Format::of(path, nlsim::frf::HINT)?;
    }
    let plot_path = plot
        .map(|p| p.to_path_buf())
        .or_else(|| out.map(|p| p.with_extension("svg")));
    if let Some(p) = &plot_path {
        nlsim::plot::check_path(p)?;
    }
    let say = |s: String| {
        if !quiet {
            out!("{s}");
        }
    };
    let model = nlsim::run::load_for_run(spec, sets)?;
    let show = !quiet && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let t1 = Instant::now();
    let mut count = 0usize;
    let mut progress = |p: &nlsim::hb::SolutionPoint| {
        count += 1;
        if show {
            eprint!(
                "\r  {count} points, at {:.4} Hz, {:.1} s ",
                p.omega / (2.0 * PI),
                t1.elapsed().as_secs_f64()
            );
        }
    };
    let run = nlsim::run::run_frf(&model, req, &mut progress)?;
    if show {
        eprintln!();
    }
    let summary = run.summary(&model, req, cli.verbose);
    for line in &summary {
        say(line.clone());
    }
    let (sys, branch, y) = (&run.system, &run.branch, &run.responses);
    if let Some(dir) = report {
        let page = nlsim::frf::write_report(
            dir,
            spec,
            &model,
            req,
            &run,
            &summary,
            (magnitude, phase),
            &nlsim::report::command_line(),
        )?;
        say(format!("  report {}", page.display()));
    }
    if let Some(path) = out {
        let info = nlsim::frf::FrfInfo {
            model_spec: spec.to_string(),
            model_name: model.name().to_string(),
            mode: req.mode.as_str().to_string(),
            modes: run.modes,
            residual: req.residual,
            seconds: run.seconds,
            peaks: run.peaks.clone(),
            notes: run.notes.clone(),
        };
        nlsim::frf::write_frf(path, sys, branch, y, &info)?;
        say(format!("  written to {}", path.display()));
    }
    if let Some(p) = plot_path {
        let title = format!("{} — {}, H = {}", model.name(), req.mode.as_str(), set.h);
        nlsim::frf::plot_frf(&p, sys, branch, y, 0, &title, magnitude, phase)?;
        say(format!("  plot {}", p.display()));
    }
    if run.status.is_converged() || run.status == nlsim::kernel::Status::IterationLimit {
        return Ok(());
    }
    // Stopped short: what was computed is kept (and written), and the run fails.
    let last = branch.points.last().map_or(0.0, |p| p.omega / (2.0 * PI));
    Err(nlsim::Error::Failed(format!(
        "frf stopped short at {last:.6} Hz ({} points{}): {}",
        branch.points.len(),
        out.map_or(String::new(), |p| format!(", written to {}", p.display())),
        run.detail
    )))
}

fn nnm(
    spec: &str,
    req: &nlsim::nnm::NnmRequest,
    sets: &[String],
    (out, plot): (Option<&std::path::Path>, Option<&std::path::Path>),
    cli: &Cli,
) -> nlsim::Result<()> {
    req.check()?;
    if let Some(path) = out {
        nlsim::output::Format::of(path, nlsim::nnm::HINT)?;
    }
    let plot_path = plot
        .map(|p| p.to_path_buf())
        .or_else(|| out.map(|p| p.with_extension("svg")));
    if let Some(p) = &plot_path {
        nlsim::plot::check_path(p)?;
    }
    let model = nlsim::run::load_for_run(spec, sets)?;
    let show = !cli.quiet && std::io::IsTerminal::is_terminal(&std::io::stderr());
    let mut count = 0usize;
    let mut progress = |p: &nlsim::hb::nnm::NnmPoint| {
        count += 1;
        if show {
            eprint!("\r  {count} points, amplitude {:.3e} ", p.amplitude);
        }
    };
    let run = nlsim::nnm::run_nnm(&model, req, &mut progress)?;
    if show {
        eprintln!();
    }
    let say = |s: String| {
        if !cli.quiet {
            out!("{s}");
        }
    };
    for line in run.summary(&model, req) {
        say(line);
    }
    if let Some(path) = out {
        nlsim::nnm::write_nnm(path, &run, spec, req)?;
        say(format!("  written to {}", path.display()));
    }
    if let Some(p) = plot_path {
        let [freq, damping] = nlsim::nnm::plots(&run, &model, req);
        nlsim::plot::write(&p, &freq)?;
        let stem = p
            .file_stem()
            .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
        let ext = p
            .extension()
            .map_or_else(|| "svg".into(), |e| e.to_string_lossy().into_owned());
        let dp = p.with_file_name(format!("{stem}-damping.{ext}"));
        nlsim::plot::write(&dp, &damping)?;
        say(format!("  plots {} and {}", p.display(), dp.display()));
    }
    if run.report.status.is_converged() {
        Ok(())
    } else {
        Err(nlsim::Error::Failed(format!(
            "nnm stopped short after {} points{}: {}",
            run.report.points.len(),
            out.map_or(String::new(), |p| format!(", written to {}", p.display())),
            run.report.detail
        )))
    }
}

fn simulate(
    spec: &str,
    req: &nlsim::run::SimRequest,
    sets: &[String],
    (out, report): (Option<&std::path::Path>, Option<&std::path::Path>),
    compress: bool,
    cli: &Cli,
) -> nlsim::Result<()> {
    let quiet = cli.quiet;
    req.check()?;
    if let Some(path) = out {
        // Refuse an unknown format before the run.
        nlsim::output::Format::of(path, nlsim::simulate::HINT)?;
    }
    let say = |s: String| {
        if !quiet {
            out!("{s}");
        }
    };
    let model = nlsim::run::load_for_run(spec, sets)?;
    let run = nlsim::run::run_simulation(&model, req, &mut progress_line(quiet, "simulate"))?;
    let summary = run.summary(&model, req, cli.verbose);
    for line in &summary {
        say(line.clone());
    }
    let history = &run.history;
    let info = nlsim::simulate::RunInfo {
        model_spec: spec.to_string(),
        method: req.method.as_str().to_string(),
        excitation: run.excitation.clone(),
        modes: run.modes,
        compress,
    };
    if let Some(path) = out {
        nlsim::simulate::write_history(path, &model, history, &info)?;
        say(format!("  written to {}", path.display()));
    }
    if let Some(dir) = report {
        let page = nlsim::simulate::write_report(
            dir,
            &model,
            history,
            &info,
            &summary,
            &nlsim::report::command_line(),
        )?;
        say(format!("  report {}", page.display()));
    }
    // Stopped short: the samples computed are kept (and written), and the run fails.
    match run.stopped_short(req.check()?) {
        None => Ok(()),
        Some(line) => Err(nlsim::Error::Failed(format!(
            "simulate {line}{}",
            out.map_or(String::new(), |p| format!(" (written to {})", p.display()))
        ))),
    }
}

/// Loads a jobs file, with `--output` overriding its output directory.
fn load_batch(
    jobs: &std::path::Path,
    output: Option<&std::path::Path>,
) -> nlsim::Result<nlsim::batch::Batch> {
    let mut b = nlsim::batch::Batch::load(jobs)?;
    if let Some(o) = output {
        b.output = o.to_path_buf();
    }
    Ok(b)
}

/// A task index or count from the command line, else from a SLURM variable.
fn from_env(given: Option<usize>, var: &str) -> nlsim::Result<Option<usize>> {
    if given.is_some() {
        return Ok(given);
    }
    match std::env::var(var) {
        Err(_) => Ok(None),
        Ok(v) => v.trim().parse().map(Some).map_err(|_| {
            nlsim::Error::Usage(format!("${var} = '{v}' is not a non-negative integer"))
        }),
    }
}

fn batch_run(
    jobs: &std::path::Path,
    task_index: Option<usize>,
    task_count: Option<usize>,
    output: Option<&std::path::Path>,
    cli: &Cli,
) -> nlsim::Result<()> {
    use nlsim::batch::{ShardEvent, ShardOutcome};
    let b = load_batch(jobs, output)?;
    let index = from_env(task_index, "SLURM_ARRAY_TASK_ID")?;
    let count = from_env(task_count, "SLURM_ARRAY_TASK_COUNT")?.unwrap_or(1);
    if count == 0 {
        return Err(nlsim::Error::Usage(
            "--task-count must be at least 1".into(),
        ));
    }
    if let Some(i) = index
        && i >= count
    {
        return Err(nlsim::Error::Usage(format!(
            "--task-index {i} is not below --task-count {count}"
        )));
    }
    b.check_models()?;
    let say = |s: String| {
        if !cli.quiet {
            out!("{s}");
        }
    };
    say(format!(
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
        let mut bar = progress_line(cli.quiet, "jobs");
        let verbose = cli.verbose && !cli.quiet;
        let outcome = nlsim::batch::run_shard(&b, task, count, &mut |ev| match ev {
            ShardEvent::Note(m) => {
                if !cli.quiet {
                    eprintln!("  note: {m}");
                }
            }
            ShardEvent::JobDone {
                index,
                done,
                total,
                error,
            } => {
                if verbose {
                    out!(
                        "  job {index}: {}",
                        error.map_or("ok".to_string(), |e| format!("failed: {e}"))
                    );
                }
                bar(done, total);
            }
        })?;
        match outcome {
            ShardOutcome::Skipped(p) => say(format!(
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
                say(format!(
                    "  shard {task} of {count}: {jobs} jobs in {seconds:.2} s{shared}, {} failed, \
                     written to {}",
                    failed.len(),
                    path.display()
                ));
                for (i, e) in &failed {
                    eprintln!("  job {i} failed: {e}");
                }
                n_failed += failed.len();
            }
        }
    }
    if n_failed > 0 {
        return Err(nlsim::Error::Failed(format!(
            "{n_failed} job(s) failed (their errors are in the shard files); the others are written"
        )));
    }
    Ok(())
}

fn batch_merge(
    jobs: &std::path::Path,
    output: Option<&std::path::Path>,
    cli: &Cli,
) -> nlsim::Result<()> {
    let b = load_batch(jobs, output)?;
    let m = nlsim::batch::merge(&b)?;
    if !cli.quiet {
        out!(
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
        );
        for line in &m.summary {
            out!("  {line}");
        }
    }
    Ok(())
}

fn batch_sbatch(
    jobs: &std::path::Path,
    output: Option<&std::path::Path>,
    o: &nlsim::batch::SbatchOptions,
    submit: bool,
    cli: &Cli,
) -> nlsim::Result<()> {
    let b = load_batch(jobs, output)?;
    b.check_models()?;
    let exe = std::env::current_exe().map_err(|source| nlsim::Error::Io {
        path: "nlsim".into(),
        source,
    })?;
    let script = nlsim::batch::sbatch_script(&b, &exe, o)?;
    let logs = b.output.join("logs");
    std::fs::create_dir_all(&logs).map_err(|source| nlsim::Error::Io {
        path: logs.clone(),
        source,
    })?;
    let path = b.output.join("nlsim-batch.sbatch");
    std::fs::write(&path, &script).map_err(|source| nlsim::Error::Io {
        path: path.clone(),
        source,
    })?;
    if !cli.quiet {
        out!(
            "batch {}: {} jobs in a {}-task array, script {}",
            b.name,
            b.jobs.len(),
            o.tasks,
            path.display()
        );
    }
    if submit {
        let out = std::process::Command::new("sbatch")
            .arg("--parsable")
            .arg(&path)
            .output()
            .map_err(|e| {
                nlsim::Error::Usage(format!(
                    "cannot run sbatch ({e}): submit from a SLURM login node, or run the script \
                     with `sbatch {}`",
                    path.display()
                ))
            })?;
        if !out.status.success() {
            return Err(nlsim::Error::Usage(format!(
                "sbatch {} failed: {}",
                path.display(),
                String::from_utf8_lossy(&out.stderr).trim()
            )));
        }
        let id = String::from_utf8_lossy(&out.stdout).trim().to_string();
        // Scripts read the job id from stdout, even with --quiet.
        out!("{id}");
        if !cli.quiet {
            eprintln!(
                "  submitted; when it is done: nlsim batch merge {}",
                jobs.display()
            );
        }
    }
    Ok(())
}
