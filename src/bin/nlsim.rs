//! The `nlsim` command line. Exit codes: 0 success, 1 a run failed (bad model, numerical
//! failure), 2 bad usage.

use clap::{Parser, Subcommand};
use nlsim::kernel::ValidationConfig;
use nlsim::reduction::{EigenConfig, EigenSolver, ModeSelection};
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
    /// Write a model's K and M as Matrix Market files and its DOF labels as text (for other
    /// tools, e.g. the scipy comparison in bench/).
    Export {
        /// Model file (.toml) or built-in model.
        model: String,
        /// Directory to write K.mtx, M.mtx and dofs.txt into (created if missing).
        dir: std::path::PathBuf,
    },
    /// Compute the lowest modes: frequencies, damping, effective masses; write them to a file.
    Modes {
        /// Model file (.toml) or built-in model, e.g. `bracket:dofs=100000`.
        model: String,
        /// Number of lowest modes (default 10).
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
        /// Skip the Sturm sequence check (saves one factorisation; `--fmax` always counts).
        #[arg(long)]
        no_sturm_check: bool,
    },
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
        Err(e @ nlsim::Error::Usage(_)) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
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
        Command::Modes {
            model,
            count,
            fmax,
            out,
            tol,
            block,
            no_sturm_check,
        } => {
            let selection = match (count, fmax) {
                (_, Some(f)) => ModeSelection::Below { f_max_hz: *f },
                (Some(c), None) => ModeSelection::Lowest(*c),
                (None, None) => ModeSelection::Lowest(10),
            };
            let cfg = EigenConfig {
                selection,
                tol: *tol,
                block_size: *block,
                sturm_check: !no_sturm_check,
                ..EigenConfig::default()
            };
            if let Some(path) = out {
                // Refuse an unknown format before the (possibly long) solve.
                let ext = path.extension().and_then(|e| e.to_str()).unwrap_or("");
                if !["h5", "hdf5", "csv"].contains(&ext.to_ascii_lowercase().as_str()) {
                    return Err(nlsim::Error::Usage(format!(
                        "{}: unknown output format; name the file .h5 (HDF5, with mode shapes) \
                         or .csv (the table)",
                        path.display()
                    )));
                }
            }
            let loaded = nlsim::load_model(model)?;
            // Symmetry, finiteness, massless DOFs; definiteness shows in the factorisation.
            loaded.model.validate(&ValidationConfig {
                check_definiteness: false,
                ..Default::default()
            })?;
            let report = modes(&loaded.model, cfg, cli.quiet)?;
            if !cli.quiet {
                println!(
                    "{}",
                    nlsim::summary::model_summary(&loaded.model, &loaded.source, None)
                );
                print!("{}", nlsim::modes::format_table(&report));
            }
            if let Some(path) = out {
                nlsim::modes::write_modes(path, &loaded.model, &report)?;
                if !cli.quiet {
                    println!("  written to {}", path.display());
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
                let path = dir.join(name);
                std::fs::write(&path, text).map_err(|source| nlsim::Error::Io { path, source })?;
            }
            if !cli.quiet {
                println!(
                    "wrote K.mtx, M.mtx, dofs.txt ({} DOFs) to {}",
                    m.n_dofs(),
                    dir.display()
                );
            }
            Ok(())
        }
        Command::Demo { model } => demo(model, cli.quiet),
    }
}

/// Solves for the modes with a progress line on stderr.
fn modes(
    model: &nlsim::kernel::Model,
    cfg: EigenConfig,
    quiet: bool,
) -> nlsim::Result<nlsim::modes::ModeReport> {
    let t = Instant::now();
    let mut solver = EigenSolver::new();
    let modes = solver.solve_with_progress(model.stiffness(), model.mass(), &cfg, &mut |p| {
        if !quiet {
            eprint!(
                "\r  modes: {}/{} converged after {} restart(s), {:.1} s ",
                p.converged,
                p.wanted,
                p.restart,
                t.elapsed().as_secs_f64()
            );
        }
    });
    if !quiet
        && modes
            .as_ref()
            .is_ok_and(|m| m.stats.method == nlsim::reduction::EigenMethod::Lanczos)
    {
        eprintln!();
    }
    Ok(nlsim::modes::ModeReport::new(model, modes?, cfg))
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
    let t = Instant::now();
    let n_modes = loaded.model.n_dofs().min(12);
    let cfg = nlsim::reduction::ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(n_modes),
            ..EigenConfig::default()
        },
        ..Default::default()
    };
    let reduced = nlsim::reduction::reduce(&loaded.model, &cfg)?;
    let system = nlsim::reduction::ModalSystem::new(&reduced)?;
    say(&format!(
        "[2/8] modes: the lowest {n_modes} in {:.1} ms; diagonal state space with {} stored \
         states (conjugate pairs once) and {} ports",
        t.elapsed().as_secs_f64() * 1e3,
        system.n_states(),
        system.ports.len()
    ));
    let report = nlsim::modes::ModeReport::new(&loaded.model, reduced.modes.clone(), cfg.eigen);
    say(&nlsim::modes::format_table(&report));
    // How much of the static flexibility at each port the truncated modes carry (for a
    // supported structure; rigid-body modes have no static flexibility).
    let supported = reduced.modes.eigenvalues.iter().all(|&l| l > 0.0);
    for (p, port) in reduced.ports.iter().enumerate().filter(|_| supported) {
        let modal: f64 = (0..reduced.n_modes())
            .map(|r| reduced.participation[(p, r)].powi(2) / reduced.modes.eigenvalues[r])
            .sum();
        let resid = reduced.residual[(p, p)];
        say(&format!(
            "  port {:<12} ({:<10}) static flexibility {:.4e} m/N, of which residual (truncated \
             modes) {:.2} %",
            port.name,
            port.kind.as_str(),
            modal + resid,
            100.0 * resid / (modal + resid)
        ));
    }
    say("");
    let stages = [
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
