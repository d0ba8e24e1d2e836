//! The `nlsim` command line. Exit codes: 0 success, 1 a run failed (bad model, numerical
//! failure), 2 bad usage.

use clap::{Parser, Subcommand};
use nlsim::kernel::ValidationConfig;
use std::process::ExitCode;
use std::time::Instant;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

/// Simulate and calibrate structures that are linear almost everywhere.
#[derive(Parser, Debug)]
#[command(name = "nlsim", version, about, long_about = None)]
struct Cli {
    /// Print only errors.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
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
    /// Run the pipeline on a built-in model and print a readable summary.
    Demo {
        /// Model to run on (default: the ECL benchmark beam).
        #[arg(long, default_value = "ecl_beam")]
        model: String,
    },
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(&cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(1)
        }
    }
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
                print!(
                    "{}",
                    nlsim::summary::model_summary(&loaded.model, &loaded.source, Some(&report))
                );
            }
            Ok(())
        }
        Command::Fixtures => {
            for f in nlsim::fixtures::CATALOGUE {
                println!("{:<26} {}", f.name, f.summary);
                for (k, d) in f.options {
                    println!("    {k:<20} {d}");
                }
            }
            Ok(())
        }
        Command::Demo { model } => demo(model, cli.quiet),
    }
}

/// The thesis pipeline, stage by stage; stages not built yet say so.
fn demo(model: &str, quiet: bool) -> nlsim::Result<()> {
    let say = |s: &str| {
        if !quiet {
            println!("{s}");
        }
    };
    say("nlsim demo: the model-calibration pipeline of Chen (2016) on a built-in model");
    say("");
    let t0 = Instant::now();
    let loaded = nlsim::load_model(model)?;
    let report = loaded.model.validate(&ValidationConfig::default())?;
    say(&format!(
        "[1/8] model: loaded and validated in {:.1} ms",
        t0.elapsed().as_secs_f64() * 1e3
    ));
    say(&nlsim::summary::model_summary(
        &loaded.model,
        &loaded.source,
        Some(&report),
    ));
    if let Some(d) = &loaded.description {
        say(&format!("  about        {d}"));
    }
    if !loaded.references.is_empty() {
        say("  references   (values the tests hold this model to)");
        for r in &loaded.references {
            say(&format!(
                "               {:<44} {:>12.6} {:<3} (rtol {:.0e}; {})",
                r.quantity, r.value, r.unit, r.rtol, r.source
            ));
        }
    }
    say("");
    let stages = [
        ("[2/8] modes", "reduction (issue 3)"),
        (
            "[3/8] time response under a multi-sine",
            "time-domain integrator (issue 4)",
        ),
        (
            "[4/8] multi-harmonic FRFs with the jump",
            "harmonic balance (issue 5)",
        ),
        (
            "[5/8] pre-test planning (Fisher information)",
            "calibration",
        ),
        ("[6/8] virtual force-controlled test", "calibration"),
        (
            "[7/8] linear then nonlinear calibration from LHS seeds",
            "calibration",
        ),
        ("[8/8] k-fold statistics and validation", "calibration"),
    ];
    for (stage, needs) in stages {
        say(&format!("{stage}: not built yet (needs {needs})"));
    }
    say("");
    say(&format!("done in {:.2} s", t0.elapsed().as_secs_f64()));
    Ok(())
}
