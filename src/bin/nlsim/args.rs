//! The command line's arguments (clap): every subcommand, option and help text of `nlsim`.
//! What they mean is documented on the request types of `nlsim::commands` they fill.

use clap::{Args, Parser, Subcommand};
use nlsim::commands::frf::request::SweepMode as FrfMode;
use nlsim::commands::simulate::request::Method;

/// Simulate and calibrate structures that are linear almost everywhere.
#[derive(Parser, Debug)]
#[command(name = "nlsim", version, about, long_about = None)]
pub struct Cli {
    /// Print only errors.
    #[arg(long, short, global = true, conflicts_with = "verbose")]
    pub quiet: bool,
    /// Print more detail (solver statistics, each batch job).
    #[arg(long, short, global = true)]
    pub verbose: bool,
    /// Worker threads for the parallel parts, 1 to 1024 (default: every core). Results do
    /// not depend on it.
    #[arg(long, global = true, value_name = "N")]
    pub threads: Option<usize>,
    #[command(subcommand)]
    pub command: Command,
}

/// The Lanczos settings of a run's reduction (as `nlsim modes --basis --restarts`): what the
/// eigensolver advises when modes do not converge.
#[derive(Args, Debug)]
pub struct LanczosArgs {
    /// Lanczos basis size before a restart (default max(2 k, k + 4 block) for k modes).
    #[arg(long)]
    pub basis: Option<usize>,
    /// Most Lanczos restarts before giving up.
    #[arg(long, default_value_t = 200)]
    pub restarts: usize,
    /// Fill-reducing ordering of the sparse factor: auto (the fewer factor values of amd and
    /// nd), amd (approximate minimum degree) or nd (METIS nested dissection).
    #[arg(long, default_value = "auto", value_parser = parse_ordering)]
    pub ordering: nlsim_reduction::Ordering,
    /// Memory the sparse factors may take together (GB); above it the Sturm check reuses the
    /// operator factor's storage, and the Lanczos iteration keeps no `M V` beside its basis
    /// unless that fits too. Default: half the memory available at start.
    #[arg(long, value_name = "GB")]
    pub memory_budget: Option<f64>,
}

pub fn parse_ordering(s: &str) -> Result<nlsim_reduction::Ordering, String> {
    nlsim_reduction::Ordering::parse(s)
        .ok_or_else(|| format!("'{s}' is not an ordering (auto, amd or nd)"))
}

impl LanczosArgs {
    pub fn settings(&self) -> Result<nlsim::commands::setup::Lanczos, nlsim::Error> {
        let memory_budget = match self.memory_budget {
            Some(gb) if gb.is_finite() && gb > 0.0 => Some((gb * 1e9) as usize),
            Some(gb) => {
                return Err(nlsim::Error::Usage(format!(
                    "--memory-budget {gb}: give a positive number of GB"
                )));
            }
            None => nlsim::commands::setup::default_memory_budget(),
        };
        Ok(nlsim::commands::setup::Lanczos {
            basis: self.basis,
            restarts: self.restarts,
            ordering: self.ordering,
            memory_budget,
        })
    }
}

#[derive(Subcommand, Debug)]
pub enum Command {
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
        magnitude: nlsim::present::frf_plot::Magnitude,
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

/// Residual form of `nlsim calibrate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum CalibForm {
    /// Real and imaginary parts of the complex difference.
    Complex,
    /// Log-magnitude and phase differences.
    LogMagnitude,
}

/// Branch choice of `nlsim calibrate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum CalibBranch {
    /// The solution nearer to the measurement where the continued one is far from it.
    Nearest,
    /// The model's own continuation from the previous step.
    Continuation,
}
