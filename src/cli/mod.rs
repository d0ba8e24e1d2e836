//! The command line of `nlsim` (feature `cli`): every subcommand, option and help text
//! (clap), each subcommand's arguments turned into the request of its command in
//! [`crate::commands`], and [`dispatch`] to the command's `execute`. The binary
//! (`src/bin/nlsim/main.rs`) parses, sets the thread pool and maps outcomes to exit codes.
//! Kept in the library so that documentation tests can parse every documented command line
//! without running it ([`Cli::try_parse_from`](clap::Parser::try_parse_from)).

mod analysis;
mod backbone;
mod batch;
mod calibration;
pub mod interrupt;
mod lanczos;

pub use analysis::*;
pub use backbone::*;
pub use batch::*;
pub use calibration::*;
pub use lanczos::*;

use crate::present::console::Console;
use clap::{Parser, Subcommand};

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
    /// The subcommand and its arguments.
    #[command(subcommand)]
    pub command: Command,
}

/// The subcommands of `nlsim`.
#[derive(Subcommand, Debug)]
pub enum Command {
    /// Load a model (file or built-in name), validate it and print its summary.
    Check(CheckArgs),
    /// List the built-in models and their options.
    Fixtures,
    /// Write a model's K and M as Matrix Market files and its DOF labels as text (for other
    /// tools, e.g. the scipy comparison in bench/).
    Export(ExportArgs),
    /// Compute the lowest modes: frequencies, damping, effective masses; write them to a file.
    #[command(allow_negative_numbers = true)]
    Modes(ModesArgs),
    /// Time response of a model: the exponential-hold integrator on the reduced model (FOH,
    /// or ZOH/LSOH for bias studies) or a reference (RK45, RK4, Newmark/HHT on the unreduced
    /// model); writes time histories.
    #[command(allow_negative_numbers = true)]
    Simulate(SimulateArgs),
    /// Multi-harmonic nonlinear FRF by harmonic balance (condensed on the nonlinear DOFs):
    /// continuation through folds with Hill stability, or a stepped sine up or down as a test
    /// would run it; writes every harmonic at every sensor and an SVG plot.
    #[command(allow_negative_numbers = true)]
    Frf(FrfArgs),
    /// Calibrate model parameters on stepped-sine test data (CSV, docs/file-formats.md):
    /// Latin-hypercube candidates, bounded Levenberg–Marquardt on the multi-harmonic
    /// responses with the measured force, Cramér–Rao bounds and k-fold cross validation.
    /// Give MODEL DATA --param ..., or a calibration file with --config (docs/calibration.md;
    /// options given beside it override the file).
    #[command(allow_negative_numbers = true)]
    Calibrate(CalibrateArgs),
    /// Predict test data with a calibration's result (its report's calibration.toml): by
    /// default the sweeps held out of the training, with a band from the parameter
    /// covariance through the HB sensitivities plus the noise model, scored per sweep (rms
    /// log-amplitude and phase errors, points inside the band, chi2, peaks). See
    /// docs/calibration.md.
    Validate(ValidateArgs),
    /// Harmonics from the time histories of a stepped-sine test or a slow sine sweep (CSV,
    /// HDF5 or universal file dataset 58 time records): the dwells found from a step table or
    /// from the drive's frequency, each dwell's transient left out, the drive and response
    /// harmonics fitted on whole periods at the refined frequency, their standard
    /// deviations from the period-to-period scatter; with --sweep, the harmonics tracked
    /// along each sweep with a warning where it is too fast for the model's damping; writes
    /// test data that `nlsim calibrate` reads (docs/file-formats.md, "Time histories").
    Harmonics(HarmonicsArgs),
    /// Pre-test planning: rank candidate tests (drive points, force levels, multi-sine
    /// signals, frequency bands, sensor sets, measured harmonics) by the Fisher information
    /// of the parameters from the analytic sensitivities, with Cramér–Rao bounds and
    /// collinearity. PLAN is a plan file (docs/planning.md).
    Plan(PlanArgs),
    /// Virtual stepped-sine test through an electrodynamic shaker model, voltage-driven or
    /// force-controlled off line; writes test data that `nlsim calibrate` reads. TEST is a
    /// test file (docs/planning.md).
    Test(TestArgs),
    /// A nonlinear mode by the extended periodic motion concept: the free periodic motions
    /// of mode N followed in amplitude, with the frequency (backbone) and the modal damping
    /// ratio that the model's damping and dissipative elements give at each amplitude.
    #[command(allow_negative_numbers = true)]
    Nnm(NnmArgs),
    /// Amplitude-dependent natural frequency and damping ratio of one mode from measured
    /// data, with standard deviations: free decays in time records (--decay: band pass,
    /// Hilbert envelope and windowed fits) or stepped sines and phase-resonance dwells (the
    /// −90° crossing with the energy-balance damping, and each level's single-mode fit).
    Backbone(BackboneArgs),
    /// Run the pipeline on a built-in model, print a readable summary and write a report
    /// folder with plots.
    Demo(DemoArgs),
    /// Many runs of `frf` or `simulate` from a jobs file (sweeps, load cases, Latin-hypercube
    /// candidates), split into shards for cluster job arrays: `nlsim batch JOBS.toml` runs
    /// shards, `nlsim batch merge JOBS.toml` joins them, `nlsim batch sbatch JOBS.toml` writes
    /// the SLURM script. See docs/batch.md.
    #[command(args_conflicts_with_subcommands = true)]
    Batch(BatchArgs),
}

impl Cli {
    /// The parallelism `--threads` asks for: sequential for 1, the rayon pool otherwise.
    pub fn par(&self) -> faer::Par {
        match self.threads {
            Some(1) => faer::Par::Seq,
            _ => faer::Par::rayon(0),
        }
    }
}

/// Runs the parsed command: its arguments into its request, then the command's `execute`.
/// `Err` carries what failed; [`crate::Error::Usage`] is a bad combination of arguments.
pub fn dispatch(cli: &Cli, console: &Console) -> crate::Result<()> {
    // Every file the command reads and writes is recorded, so that no output replaces an
    // input (`formats::guard`).
    let _run = crate::formats::guard::Run::begin();
    let par = cli.par();
    match &cli.command {
        Command::Check(a) => a.execute(console),
        Command::Fixtures => {
            crate::commands::check::fixtures(console);
            Ok(())
        }
        Command::Export(a) => a.execute(console),
        Command::Modes(a) => crate::commands::modes::execute(&a.request(par)?, console),
        Command::Simulate(a) => a.execute(par, console),
        Command::Frf(a) => a.execute(par, console),
        Command::Nnm(a) => a.execute(par, console),
        Command::Backbone(a) => a.execute(console),
        Command::Demo(a) => a.execute(console),
        Command::Calibrate(a) => a.execute(console),
        Command::Validate(a) => a.execute(console),
        Command::Harmonics(a) => crate::commands::harmonics::execute(&a.request()?, console),
        Command::Plan(a) => crate::commands::plan::execute(&a.request()?, console),
        Command::Test(a) => crate::commands::test::execute(&a.request()?, console),
        Command::Batch(a) => a.execute(console),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory as _;

    fn parse(line: &str) -> Result<Cli, clap::Error> {
        Cli::try_parse_from(line.split_whitespace())
    }

    #[test]
    fn clap_declarations_are_consistent() {
        // clap's own check: no duplicate names, every `requires`/`conflicts_with` names an
        // argument that exists.
        Cli::command().debug_assert();
    }

    #[test]
    fn arguments_fill_the_request() {
        let cli = parse("nlsim --threads 1 modes ecl_beam --fmax 300 --no-sturm-check").unwrap();
        let Command::Modes(a) = &cli.command else {
            panic!("parsed as {:?}", cli.command)
        };
        let req = a.request(cli.par()).unwrap();
        assert_eq!(req.fmax_hz, Some(300.0));
        assert_eq!(req.count, None);
        assert!(!req.sturm_check);
        assert!(matches!(req.par, faer::Par::Seq));
        assert_eq!(req.tol, 1e-10);

        let cli = parse(
            "nlsim calibrate m.toml d.csv --param spring.k3=1e8:1e11 --compare 1,3 \
             --form log-magnitude --lhs 7 --seed 9",
        )
        .unwrap();
        let Command::Calibrate(a) = &cli.command else {
            panic!("parsed as {:?}", cli.command)
        };
        let req = a.request().unwrap();
        assert_eq!(req.model, "m.toml");
        assert_eq!(req.compare, vec![1, 3]);
        assert!(matches!(req.form, crate::calib::Form::LogMagnitudePhase));
        assert_eq!(req.config.lhs_samples, 7);
        assert_eq!(req.config.seed, 9);
        assert_eq!(req.params.len(), 1);
    }

    #[test]
    fn negative_numbers_and_bad_combinations() {
        let cli = parse("nlsim simulate m --duration 1 --rate 100 --hht-alpha -0.1").unwrap();
        let Command::Simulate(a) = &cli.command else {
            panic!("parsed as {:?}", cli.command)
        };
        assert_eq!(a.request(faer::Par::Seq).unwrap().0.hht_alpha, -0.1);
        // --start-hz needs --start-file; --count and --fmax exclude each other; a calibration
        // file excludes MODEL DATA.
        assert!(parse("nlsim frf m --from 1 --to 2 --start-hz 1.5").is_err());
        assert!(parse("nlsim modes m --count 3 --fmax 100").is_err());
        assert!(parse("nlsim calibrate m d --config c.toml").is_err());
        // A compared harmonic named twice would count its residuals twice.
        let cli =
            parse("nlsim calibrate m.toml d.csv --param s.k3=1e8:1e11 --compare 1,1").unwrap();
        let Command::Calibrate(a) = &cli.command else {
            panic!("parsed as {:?}", cli.command)
        };
        let e = a.request().unwrap().check().unwrap_err().to_string();
        assert!(e.contains("harmonic 1 is named twice"), "{e}");
        // A memory budget that is no positive number is a usage error of the request.
        let cli = parse("nlsim modes m --memory-budget -1").unwrap();
        let Command::Modes(a) = &cli.command else {
            panic!("parsed as {:?}", cli.command)
        };
        assert!(matches!(
            a.request(faer::Par::Seq),
            Err(crate::Error::Usage(_))
        ));
    }
}
