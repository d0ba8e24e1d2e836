//! The arguments of the analysis commands (`check`, `export`, `modes`, `simulate`, `frf`,
//! `nnm`, `demo`) and their requests.

use super::lanczos::LanczosArgs;
use crate::commands;
use crate::commands::frf::request::SweepMode as FrfMode;
use crate::commands::simulate::request::Method;
use crate::present::console::Console;
use clap::Args;

/// The arguments of `nlsim check`.
#[derive(Args, Debug)]
pub struct CheckArgs {
    /// Model file (.toml) or built-in model, e.g. `ecl_beam` or `bracket:refinement=4`.
    model: String,
    /// Skip the Cholesky factorisations that prove M positive definite and K semi-definite.
    #[arg(long)]
    no_definiteness: bool,
}

/// The arguments of `nlsim export`.
#[derive(Args, Debug)]
pub struct ExportArgs {
    /// Model file (.toml) or built-in model.
    model: String,
    /// Directory to write K.mtx, M.mtx and dofs.txt (and nodes.csv, when the model has
    /// coordinates) into (created if missing).
    dir: std::path::PathBuf,
    /// Also write K and M as Nastran OUTPUT4 `matrices.op4` (KAAX and MAAX, rows in the order
    /// of dofs.txt): `ascii`, `binary` (little-endian) or `binary-be` (big-endian).
    #[arg(long, value_name = "LAYOUT", value_parser = parse_op4_layout)]
    op4: Option<crate::formats::op4_write::Op4Layout>,
    /// Write instead `modal.toml`, a test-based modal model of the lowest N modes: shapes at
    /// the points the elements, forces and sensors use, damping ratios, and the residual
    /// flexibility of the truncated modes at the ports (docs/model-files.md, `[modal]`).
    #[arg(long, value_name = "N", value_parser = at_least_one)]
    modal: Option<usize>,
}

/// A count of 1 or more (a usage error otherwise, exit code 2 as clap's own).
fn at_least_one(s: &str) -> Result<usize, String> {
    match s.parse::<usize>() {
        Ok(0) => Err("give 1 or more".into()),
        Ok(n) => Ok(n),
        Err(_) => Err(format!("'{s}' is not a whole number")),
    }
}

fn parse_op4_layout(s: &str) -> Result<crate::formats::op4_write::Op4Layout, String> {
    crate::formats::op4_write::Op4Layout::parse(s)
        .ok_or_else(|| format!("unknown OUTPUT4 layout '{s}': use ascii, binary or binary-be"))
}

/// The arguments of `nlsim modes`.
#[derive(Args, Debug)]
pub struct ModesArgs {
    /// Model file (.toml) or built-in model, e.g. `bracket:dofs=100000`.
    model: String,
    /// Number of lowest modes (default 10, or every mode of a smaller model).
    #[arg(long, conflicts_with = "fmax", value_parser = at_least_one)]
    count: Option<usize>,
    /// Every mode below this frequency (Hz) instead of a count.
    #[arg(long)]
    fmax: Option<f64>,
    /// Output file: .h5 (HDF5, with mode shapes), .csv (the table) or .uff/.unv (universal
    /// datasets 55, after dataset 2411 of the nodes when the model has coordinates).
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
}

/// The arguments of `nlsim simulate`.
#[derive(Args, Debug)]
pub struct SimulateArgs {
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
    /// `sweep:f0=HZ,f1=HZ[,amp=N][,duration=S][,log=true]`,
    /// `stepped:f0=HZ,f1=HZ,steps=N,dwell=S[,amp=N]` (N dwells of S seconds, evenly spaced
    /// frequencies, phase-continuous: the raw records of a stepped sine, for `nlsim
    /// harmonics`) or `file:PATH[,rate=HZ]` (one force per line). `amp` defaults to the point's nominal amplitude. Default: a
    /// sine at the first natural frequency.
    #[arg(long)]
    excitation: Vec<String>,
    /// Output file: .h5 (HDF5), .csv, or .uff/.unv (universal file, dataset 58 per output and input).
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
}

/// The arguments of `nlsim frf`.
#[derive(Args, Debug)]
pub struct FrfArgs {
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
    /// Output file: .h5 (HDF5), .csv, or .uff/.unv (universal file, dataset 58 per sensor and harmonic).
    #[arg(long)]
    out: Option<std::path::PathBuf>,
    /// Plot of the first sensor against frequency, one panel per harmonic, FILE.svg or
    /// FILE.png (default: beside --out, .svg).
    #[arg(long)]
    plot: Option<std::path::PathBuf>,
    /// Magnitude axes of the plot: linear, log or db (dB re 1 unit).
    #[arg(long, default_value = "linear")]
    magnitude: crate::present::frf_plot::Magnitude,
    /// Add a phase panel beside each magnitude panel of the plot.
    #[arg(long)]
    phase: bool,
    /// Report folder: index.html (summary, folds/jumps/peaks tables, the plot of every
    /// sensor), report.h5 with the data, plots as SVG and PNG.
    #[arg(long)]
    report: Option<std::path::PathBuf>,
    /// Parameter overrides, e.g. `--set spring.k3=2e15` (repeatable): element and FE-level parameters of the model, or of the reduced model (`mode2.f=24`, `mode2.zeta`, `mode2.m`, `stiffness_scale`, set after the reduction: what `calibrate` estimates).
    #[arg(long)]
    set: Vec<String>,
}

/// The arguments of `nlsim nnm`.
#[derive(Args, Debug)]
pub struct NnmArgs {
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
}

/// The arguments of `nlsim demo`.
#[derive(Args, Debug)]
pub struct DemoArgs {
    /// Model to run on (default: the ECL benchmark beam).
    #[arg(long, default_value = "ecl_beam")]
    model: String,
    /// Report folder (plots as SVG and PNG, the summary as text); default `nlsim-report` for
    /// the ECL beam, `nlsim-report-MODEL` for another model (so that one model's demo does
    /// not replace another's). A folder that holds files but no nlsim report is refused.
    #[arg(long)]
    report: Option<std::path::PathBuf>,
}

impl CheckArgs {
    /// `nlsim check`: loads, validates and summarises the model.
    pub fn execute(&self, console: &Console) -> crate::Result<()> {
        commands::check::check(&self.model, !self.no_definiteness, console)
    }
}

impl ExportArgs {
    /// `nlsim export`: writes the model's matrices and DOF labels.
    pub fn execute(&self, console: &Console) -> crate::Result<()> {
        match self.modal {
            Some(n) => {
                if self.op4.is_some() {
                    return Err(crate::Error::Usage(
                        "--modal writes a modal model file, --op4 FE matrices: give one".into(),
                    ));
                }
                commands::modal_export::export_modal(&self.model, &self.dir, n, console)
            }
            None => commands::check::export(&self.model, &self.dir, self.op4, console),
        }
    }
}

impl ModesArgs {
    /// The request of `nlsim modes`.
    pub fn request(&self, par: faer::Par) -> crate::Result<commands::modes::ModesRequest> {
        Ok(commands::modes::ModesRequest {
            model: self.model.clone(),
            count: self.count,
            fmax_hz: self.fmax,
            tol: self.tol,
            block: self.block,
            lanczos: self.lanczos.settings()?,
            sturm_check: !self.no_sturm_check,
            par,
            out: self.out.clone(),
            report: self.report.clone(),
        })
    }
}

impl SimulateArgs {
    /// The request and outputs of `nlsim simulate`; `Err` for an excitation that does not
    /// parse.
    pub fn request(
        &self,
        par: faer::Par,
    ) -> crate::Result<(
        commands::simulate::SimRequest,
        commands::simulate::SimOutputs,
    )> {
        use commands::simulate::{Drive, SimOutputs, SimRequest};
        let req = SimRequest {
            duration: self.duration,
            rate: self.rate,
            method: self.method,
            excitation: self
                .excitation
                .iter()
                .map(|e| Drive::parse(e, self.duration, self.rate))
                .collect::<crate::Result<_>>()?,
            modes: self.modes,
            residual: !self.no_residual,
            events: !self.no_events,
            rtol: self.rtol,
            atol: self.atol,
            substeps: self.substeps,
            hht_alpha: self.hht_alpha,
            par,
            lanczos: self.lanczos.settings()?,
        };
        let outputs = SimOutputs {
            out: self.out.clone(),
            report: self.report.clone(),
            compress: self.compress,
        };
        Ok((req, outputs))
    }

    /// `nlsim simulate`.
    pub fn execute(&self, par: faer::Par, console: &Console) -> crate::Result<()> {
        let (req, outputs) = self.request(par)?;
        commands::simulate::execute(&self.model, &self.set, &req, &outputs, console)
    }
}

impl FrfArgs {
    /// The request and outputs of `nlsim frf`; `Err` for a force harmonic that does not
    /// parse or a bad Lanczos setting.
    pub fn request(
        &self,
        par: faer::Par,
    ) -> crate::Result<(commands::frf::FrfRequest, commands::frf::FrfOutputs)> {
        use commands::frf::{FrfOutputs, FrfRequest, FrfStart, StartFile};
        let start = FrfStart::parse(&self.start).ok_or_else(|| {
            crate::Error::Usage(format!(
                "--start {}: give auto, rest or subharmonic",
                self.start
            ))
        })?;
        let req = FrfRequest {
            from_hz: self.from,
            to_hz: self.to,
            harmonics: self.harmonics,
            subharmonic: self.subharmonic,
            force: self.force,
            force_harmonics: self
                .force_harmonic
                .iter()
                .map(|t| commands::frf::parse_force_harmonic(t))
                .collect::<crate::Result<_>>()?,
            mode: self.mode,
            points: self.points,
            max_step_hz: self.max_step,
            start,
            start_file: self.start_file.as_ref().map(|path| StartFile {
                path: path.clone(),
                at_hz: self.start_hz,
            }),
            modes: self.modes,
            residual: !self.no_residual,
            stability: !self.no_stability,
            par,
            lanczos: self.lanczos.settings()?,
            modal_sets: Vec::new(),
        };
        let outputs = FrfOutputs {
            out: self.out.clone(),
            plot: self.plot.clone(),
            magnitude: self.magnitude,
            phase: self.phase,
            report: self.report.clone(),
        };
        Ok((req, outputs))
    }

    /// `nlsim frf`.
    pub fn execute(&self, par: faer::Par, console: &Console) -> crate::Result<()> {
        let (req, outputs) = self.request(par)?;
        commands::frf::execute(&self.model, &self.set, &req, &outputs, console)
    }
}

impl NnmArgs {
    /// The request of `nlsim nnm`.
    pub fn request(&self, par: faer::Par) -> crate::Result<commands::nnm::NnmRequest> {
        Ok(commands::nnm::NnmRequest {
            mode: self.mode,
            from: self.from,
            to: self.to,
            points: self.points,
            harmonics: self.harmonics,
            modes: self.modes,
            par,
            lanczos: self.lanczos.settings()?,
        })
    }

    /// `nlsim nnm`.
    pub fn execute(&self, par: faer::Par, console: &Console) -> crate::Result<()> {
        let outputs = (self.out.as_deref(), self.plot.as_deref());
        commands::nnm::execute(
            &self.model,
            &self.set,
            &self.request(par)?,
            outputs,
            console,
        )
    }
}

impl DemoArgs {
    /// `nlsim demo`.
    pub fn execute(&self, console: &Console) -> crate::Result<()> {
        let dir = self
            .report
            .clone()
            .unwrap_or_else(|| commands::demo::default_report_dir(&self.model));
        commands::demo::execute(&self.model, &dir, console)
    }
}
