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
    #[arg(long, short, global = true, conflicts_with = "verbose")]
    quiet: bool,
    /// Print more detail (solver statistics, each batch job).
    #[arg(long, short, global = true)]
    verbose: bool,
    /// Worker threads for the parallel parts (default: every core). Results do not depend on
    /// it.
    #[arg(long, global = true, value_name = "N")]
    threads: Option<usize>,
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
    /// Time response of a model: the exponential-hold integrator on the reduced model (FOH,
    /// or ZOH/LSOH for bias studies) or a reference (RK45, RK4, Newmark/HHT on the unreduced
    /// model); writes time histories.
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
        /// `multisine:freq=HZ,h1=N[@DEG],h2=..,h1/3=..`,
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
        /// RK45 relative tolerance (ODE45's default 1e-3).
        #[arg(long, default_value_t = 1e-3)]
        rtol: f64,
        /// RK45 absolute tolerance on the modal states (ODE45's default 1e-6; scale it to the
        /// response).
        #[arg(long, default_value_t = 1e-6)]
        atol: f64,
        /// Integration steps per sample (rk4, newmark, hht).
        #[arg(long, default_value_t = 1)]
        substeps: usize,
        /// HHT alpha in [-1/3, 0] (hht).
        #[arg(long, default_value_t = -0.05)]
        hht_alpha: f64,
        /// Set an element parameter for this run: `element.param=value` (repeatable).
        #[arg(long)]
        set: Vec<String>,
    },
    /// Multi-harmonic nonlinear FRF by harmonic balance (condensed on the nonlinear DOFs):
    /// continuation through folds with Hill stability, or a stepped sine up or down as a test
    /// would run it; writes every harmonic at every sensor and an SVG plot.
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
        /// model's nominal amplitudes).
        #[arg(long)]
        force: Option<f64>,
        /// Continuation (through folds, unstable parts included) or a stepped sine.
        #[arg(long, value_enum, default_value = "continuation")]
        mode: FrfMode,
        /// Frequencies of a stepped sine (evenly spaced).
        #[arg(long, default_value_t = 400)]
        points: usize,
        /// Retained modes of the reduced model.
        #[arg(long, default_value_t = 20)]
        modes: usize,
        /// Leave out the residual flexibility of the truncated modes.
        #[arg(long)]
        no_residual: bool,
        /// Skip Hill stability (faster; no stable/unstable distinction).
        #[arg(long)]
        no_stability: bool,
        /// Output file: .h5 (HDF5) or .csv.
        #[arg(long)]
        out: Option<std::path::PathBuf>,
        /// Plot of the amplitude against frequency, FILE.svg or FILE.png (default: beside
        /// --out, .svg).
        #[arg(long)]
        plot: Option<std::path::PathBuf>,
        /// Element parameter overrides, e.g. `--set spring.k3=2e15` (repeatable).
        #[arg(long)]
        set: Vec<String>,
    },
    /// Calibrate model parameters on stepped-sine test data (CSV, docs/file-formats.md):
    /// Latin-hypercube candidates, bounded Levenberg–Marquardt on the multi-harmonic
    /// responses with the measured force, Cramér–Rao bounds and k-fold cross validation.
    /// Give MODEL DATA --param ..., or a calibration file with --config (docs/calibration.md;
    /// options given beside it override the file).
    Calibrate {
        /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
        #[arg(required_unless_present = "config", conflicts_with = "config")]
        model: Option<String>,
        /// Test data: stepped-sine CSV or HDF5 (docs/file-formats.md), or linear FRFs in
        /// universal file dataset 58 (.uff/.unv, ASCII or binary; 1 % noise assumed).
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
        /// Harmonics H kept by the harmonic balance [default: 3].
        #[arg(long)]
        harmonics: Option<usize>,
        /// Retained modes of the reduced model [default: 20].
        #[arg(long)]
        modes: Option<usize>,
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
    let cli = Cli::parse();
    if let Some(n) = cli.threads {
        if n == 0 {
            eprintln!("error: --threads must be at least 1");
            return ExitCode::from(2);
        }
        // The first and only global pool: cannot fail here.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global();
        faer::set_global_parallelism(if n == 1 {
            faer::Par::Seq
        } else {
            faer::Par::rayon(n)
        });
    }
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
                par: par(cli),
                ..EigenConfig::default()
            };
            if let Some(path) = out {
                // Refuse an unknown format before the (possibly long) solve.
                nlsim::output::Format::of(path, nlsim::modes::HINT)?;
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
                nlsim::modes::write_modes(path, model, &loaded.model, &report)?;
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
            rtol,
            atol,
            substeps,
            hht_alpha,
            set,
        } => {
            let req = nlsim::run::SimRequest {
                duration: *duration,
                rate: *rate,
                method: *method,
                excitation: excitation.clone(),
                modes: *modes,
                residual: !no_residual,
                events: !no_events,
                rtol: *rtol,
                atol: *atol,
                substeps: *substeps,
                hht_alpha: *hht_alpha,
                par: par(cli),
            };
            simulate(model, &req, set, out.as_deref(), cli)
        }
        Command::Frf {
            model,
            from,
            to,
            harmonics,
            subharmonic,
            force,
            mode,
            points,
            modes,
            no_residual,
            no_stability,
            out,
            plot,
            set,
        } => {
            let req = nlsim::run::FrfRequest {
                from_hz: *from,
                to_hz: *to,
                harmonics: *harmonics,
                subharmonic: *subharmonic,
                force: *force,
                mode: *mode,
                points: *points,
                modes: *modes,
                residual: !no_residual,
                stability: !no_stability,
                par: par(cli),
            };
            frf(model, &req, set, out.as_deref(), plot.as_deref(), cli)
        }
        Command::Demo { model, report } => demo(model, report, cli.quiet),
        Command::Calibrate {
            model,
            data,
            config,
            params,
            set,
            compare,
            form,
            harmonics,
            modes,
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

/// Stage 3 of the demo: FOH under a multi-sine at the first natural frequency (harmonics 1, 2,
/// 3 at 100, 10 and 5 % of the nominal force), checked against a tight RK45 run.
fn demo_time_response(
    model: &nlsim::kernel::Model,
    reduced: &nlsim::reduction::ReducedModel,
    system: &nlsim::reduction::ModalSystem,
    report_dir: &std::path::Path,
    say: &dyn Fn(&str),
) -> nlsim::Result<()> {
    use nlsim::sim::{FohConfig, Harmonic, LoadCase, Plant, Rk45Config, Signal, Simulator};
    if model.excitation().is_empty() {
        say("[3/8] time response: the model has no excitation point; skipped");
        return Ok(());
    }
    let f1 = reduced.modes.frequencies_hz()[0];
    let plant = Plant::from_model(model, system)?;
    let forces: Vec<Signal> = model
        .excitation()
        .iter()
        .map(|x| Signal::MultiSine {
            fundamental_hz: f1,
            harmonics: [(1.0, 1.0), (2.0, 0.1), (3.0, 0.05)]
                .iter()
                .map(|&(r, a)| Harmonic {
                    ratio: r,
                    amplitude: faer::c64::new(0.0, -a * x.amplitude),
                })
                .collect(),
        })
        .collect();
    let case = LoadCase::new("multisine", forces);
    let rate = 200.0 * f1;
    let duration = 40.0 / f1;
    let n = (duration * rate).round() as usize;
    let sim = Simulator::new(&plant, &FohConfig::new(1.0 / rate))?;
    let foh = sim.run(&case, n)?;
    let rk = nlsim::sim::rk45(
        &plant,
        &case,
        1.0 / rate,
        n,
        &Rk45Config {
            rtol: 1e-9,
            atol: 1e-15,
            ..Default::default()
        },
    )?;
    say(&format!(
        "[3/8] time response: multi-sine at {f1:.3} Hz (harmonics 1, 2, 3 at 100/10/5 % of the \
         nominal force), {duration:.2} s from rest, FOH at {rate:.0} Hz ({n} steps)"
    ));
    say(&format!(
        "  FOH {:.4} s wall ({:.2} ns per mode-step, {} contact events); RK45 (rtol 1e-9) {:.4} s \
         wall with {} steps: FOH {:.0}x faster",
        foh.stats.seconds,
        foh.stats.seconds / (n as f64 * system.n_states() as f64) * 1e9,
        foh.stats.events.len(),
        rk.stats.seconds,
        rk.stats.steps,
        rk.stats.seconds / foh.stats.seconds.max(1e-9)
    ));
    for (a, b) in foh.outputs.iter().zip(&rk.outputs) {
        let peak = b.values.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let diff = a
            .values
            .iter()
            .zip(&b.values)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        say(&format!(
            "  {:<10} {:<13} peak {peak:.4e}; FOH vs RK45 max difference {:.2e} of peak",
            a.name,
            a.quantity.as_str(),
            diff / peak.max(1e-300)
        ));
    }
    if let (Some(a), Some(b)) = (foh.outputs.first(), rk.outputs.first()) {
        // At most ~4000 points per curve.
        let every = (a.values.len() / 4000).max(1);
        let curve = |v: &[f64]| -> Vec<(f64, f64)> {
            v.iter()
                .enumerate()
                .step_by(every)
                .map(|(k, &x)| (k as f64 / rate, x))
                .collect()
        };
        let fig = nlsim::plot::Lines {
            title: format!(
                "{}: multi-sine response at {} (FOH vs RK45)",
                model.name(),
                a.name
            ),
            x_desc: "time (s)".into(),
            y_desc: format!(
                "{} {} ({})",
                a.name,
                a.quantity.as_str(),
                nlsim::output::unit(a.quantity)
            ),
            series: vec![
                (format!("FOH, {rate:.0} Hz"), curve(&a.values)),
                ("RK45, rtol 1e-9".into(), curve(&b.values)),
            ],
        };
        let paths = plot_both(report_dir, "time_response", &fig)?;
        say(&format!("  plots: {paths}"));
    }
    for (e, name) in foh.element_names.iter().enumerate() {
        let pu = foh.element_displacements[e]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        let pg = foh.element_forces[e]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        say(&format!(
            "  element {name:<10} peak |u| {pu:.4e} m, peak |g| {pg:.4e} N"
        ));
    }
    Ok(())
}

/// Stage 4 of the demo: multi-harmonic FRFs by harmonic balance around the first resonance:
/// continuation with stability, and stepped sines up and down that show the jump.
fn demo_frf(
    model: &nlsim::kernel::Model,
    reduced: &nlsim::reduction::ReducedModel,
    report_dir: &std::path::Path,
    say: &dyn Fn(&str),
) -> nlsim::Result<()> {
    use nlsim::hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, PointKind};
    use std::f64::consts::PI;
    if model.elements().is_empty() || model.excitation().is_empty() || model.sensors().is_empty() {
        say(
            "[4/8] multi-harmonic FRFs: the model needs an element, an excitation and a sensor; skipped",
        );
        return Ok(());
    }
    let sys = HbSystem::from_model(model, reduced, HarmonicSet::new(7, 1)?, HbConfig::default())?;
    let f1 = reduced.modes.frequencies_hz()[0];
    let (lo, hi) = (0.85 * f1, 1.5 * f1);
    let t = Instant::now();
    let cont = nlsim::hb::continuation(&sys, &ContinuationConfig::frequency(lo, hi), None)?
        .into_branch()?;
    let t_cont = t.elapsed().as_secs_f64();
    let n = 200;
    let grid = |a: f64, b: f64| -> Vec<f64> {
        (0..n)
            .map(|i| 2.0 * PI * (a + (b - a) * i as f64 / (n - 1) as f64))
            .collect()
    };
    let t = Instant::now();
    let up = nlsim::hb::stepped_sine(&sys, &grid(lo, hi), 1.0, false)?.into_branch()?;
    let down = nlsim::hb::stepped_sine(&sys, &grid(hi, lo), 1.0, false)?.into_branch()?;
    let t_step = t.elapsed().as_secs_f64();
    let hz = |p: &nlsim::hb::SolutionPoint| p.omega / (2.0 * PI);
    let list = |kind: PointKind, b: &nlsim::hb::Branch| -> String {
        let v: Vec<String> = b
            .points
            .iter()
            .filter(|p| p.kind == kind)
            .map(|p| format!("{:.3} Hz", hz(p)))
            .collect();
        if v.is_empty() {
            "none".into()
        } else {
            v.join(", ")
        }
    };
    say(&format!(
        "[4/8] multi-harmonic FRFs {lo:.2}–{hi:.2} Hz, H = 7 ({} unknowns): continuation {} points \
         in {:.2} s with Hill stability ({} unstable), folds at {}; stepped sines of {n} points \
         in {:.3} s: up jumps at {}, down at {}",
        sys.n_unknowns(),
        cont.points.len(),
        t_cont,
        cont.points
            .iter()
            .filter(|p| p.stable() == Some(false))
            .count(),
        list(PointKind::Fold, &cont),
        t_step,
        list(PointKind::Jump, &up),
        list(PointKind::Jump, &down)
    ));
    let y = nlsim::frf::responses(&sys, &cont);
    let title = format!("{}: harmonic balance, H = 7", model.name());
    let fig = nlsim::frf::FrfPlot {
        sys: &sys,
        branch: &cont,
        y: &y,
        sensor: 0,
        title: &title,
    };
    let mut plots = vec![plot_both(
        report_dir,
        &format!("frf_{}", model.name()),
        &fig,
    )?];
    // The stepped sines as a test would run them, over the continuation.
    let fund = |b: &nlsim::hb::Branch| -> Vec<(f64, f64)> {
        nlsim::frf::responses(&sys, b)
            .iter()
            .zip(&b.points)
            .map(|(r, p)| (hz(p), r[(0, 1)].norm()))
            .collect()
    };
    let sen = &sys.sensors()[0];
    let fig = nlsim::plot::Lines {
        title: format!("{}: stepped sines jump at the folds", model.name()),
        x_desc: "frequency (Hz)".into(),
        y_desc: format!(
            "|{}| at the fundamental ({})",
            sen.name,
            nlsim::output::unit(sen.quantity)
        ),
        series: vec![
            ("continuation (every branch)".into(), fund(&cont)),
            ("stepped sine up".into(), fund(&up)),
            ("stepped sine down".into(), fund(&down)),
        ],
    };
    plots.push(plot_both(report_dir, "stepped_sines", &fig)?);
    say(&format!("  plots: {}", plots.join(", ")));
    Ok(())
}

/// Writes `fig` as `DIR/NAME.svg` and `DIR/NAME.png`; returns the two paths for the summary.
fn plot_both(
    dir: &std::path::Path,
    name: &str,
    fig: &impl nlsim::plot::Figure,
) -> nlsim::Result<String> {
    let mut v = Vec::new();
    for ext in ["svg", "png"] {
        let p = dir.join(format!("{name}.{ext}"));
        nlsim::plot::write(&p, fig)?;
        v.push(p.display().to_string());
    }
    Ok(v.join(", "))
}

/// Stages 7 and 8 of the demo: a synthetic stepped-sine test of the model itself (two force
/// levels, harmonics 1–3, 2 % noise), then calibration of the first element parameter and
/// the driven mode's damping from far-off values, with and without the side harmonics, and
/// 10-fold cross validation beside the Cramér–Rao bound.
fn demo_calibration(
    model: &nlsim::kernel::Model,
    reduced: &nlsim::reduction::ReducedModel,
    report_dir: &std::path::Path,
    say: &dyn Fn(&str),
) -> nlsim::Result<()> {
    use nlsim::calib::{
        CalibrationConfig, Form, FrfObjective, Noise, ObjectiveConfig, ParamSpec, SweepPlan,
        calibrate, synthesize,
    };
    use nlsim::hb::{HarmonicSet, HbConfig, HbSystem};
    use nlsim::kernel::{Param, Parameterized};
    use std::sync::Arc;
    let skip = |why: &str| {
        say(&format!(
            "[7/8] calibration: {why}; skipped\n[8/8] k-fold statistics: skipped"
        ))
    };
    if model.elements().is_empty() || model.excitation().is_empty() || model.sensors().is_empty() {
        skip("the model needs an element, an excitation and a sensor");
        return Ok(());
    }
    let t = Instant::now();
    let mut sys =
        HbSystem::from_model(model, reduced, HarmonicSet::new(3, 1)?, HbConfig::default())?;
    // The mode the drive excites most at the first sensor, among the two lowest (a square
    // beam has two bending planes at one frequency).
    let driven = sys
        .linear()
        .dominant_mode(sys.sensors()[0].port, 0..2)
        .unwrap_or(0);
    let Some(element_param) = sys
        .parameters()
        .into_iter()
        .find(|p| matches!(p, Param::Element { .. }) && sys.param(p).is_ok_and(|v| v > 0.0))
    else {
        skip("no element parameter with a positive value");
        return Ok(());
    };
    let params = vec![element_param, Param::ModalDamping(driven)];
    let truth = sys.param_values(&params)?;
    let f = sys.linear().frequency_hz(driven);
    let force = model.excitation()[0].amplitude;
    let plans = vec![
        SweepPlan::linear(
            format!("{:.3} N up", 0.25 * force),
            0.92 * f,
            1.08 * f,
            17,
            0.25 * force,
        ),
        SweepPlan::linear(format!("{force:.3} N up"), 0.92 * f, 1.12 * f, 21, force),
    ];
    let noise = 0.02;
    let input = sys.inputs()[0].0.clone();
    let data = Arc::new(synthesize(
        &sys,
        &input,
        &plans,
        3,
        Noise::relative(noise),
        2016,
    )?);
    let csv = report_dir.join("synthetic_test.csv");
    nlsim::testdata::write_csv(&csv, &data)?;
    say(&format!(
        "[7/8] calibration: synthetic stepped-sine test of this model (stage 6 not built): {} \
         sweeps, {} steps, harmonics 1-3 at {} sensors, {:.0} % noise (seed 2016)",
        data.sweeps.len(),
        data.n_points(),
        data.channels.len(),
        100.0 * noise
    ));
    // Start far away: the element parameter 30x too large, the damping 2.5x.
    sys.set_params(&params, &[truth[0] * 30.0, truth[1] * 2.5])?;
    let specs = vec![
        ParamSpec::new(params[0].clone(), truth[0] / 100.0, truth[0] * 100.0),
        ParamSpec::new(params[1].clone(), truth[1] / 10.0, truth[1] * 10.0),
    ];
    let config = CalibrationConfig {
        lhs_samples: 32,
        seed: 2016,
        starts: 2,
        folds: 10,
        ..Default::default()
    };
    let mut fits = Vec::new();
    for (label, harmonics) in [
        ("fundamental only", vec![1]),
        ("harmonics 1 and 3", vec![1, 3]),
    ] {
        let obj = FrfObjective::new(
            &sys,
            data.clone(),
            specs.clone(),
            ObjectiveConfig {
                harmonics,
                form: Form::Complex,
            },
        )?;
        let cal = calibrate(&obj, &config)?;
        fits.push((label, cal, obj));
    }
    say(&format!(
        "  {} LHS candidates (maximin, seed {}) + the start, LM from the best {}, in {:.2} s for both metrics",
        config.lhs_samples,
        config.seed,
        config.starts,
        t.elapsed().as_secs_f64()
    ));
    say(
        "  parameter            true          start         metric             estimate      error     Cramér–Rao  10-fold (jackknife)",
    );
    for (j, p) in params.iter().enumerate() {
        for (label, cal, _) in &fits {
            say(&format!(
                "  {:<18} {:>12.5e}  {:>12.5e}  {:<18} {:>12.5e}  {:>+8.3} %  ±{:>8.3} %  ±{:>8.3} %",
                p.to_string(),
                truth[j],
                [truth[0] * 30.0, truth[1] * 2.5][j],
                label,
                cal.estimate[j],
                100.0 * (cal.estimate[j] - truth[j]) / truth[j],
                100.0 * cal.cramer_rao.relative_std[j],
                100.0 * cal.kfold.as_ref().map_or(f64::NAN, |k| k.jackknife_std[j])
                    / cal.estimate[j],
            ));
        }
    }
    for (label, cal, _) in &fits {
        say(&format!(
            "  {label}: {} in {} LM iterations, reduced chi2 {:.3}, collinearity index {:.2}{}",
            cal.status,
            cal.runs[0].report.iterations,
            cal.cramer_rao.reduced_chi2,
            cal.cramer_rao.collinearity,
            if cal.fit.failed.is_empty() {
                String::new()
            } else {
                format!(", {} points did not converge", cal.fit.failed.len())
            }
        ));
    }
    // Measured vs calibrated fundamental at the first sensor, per sweep.
    let (_, cal, obj) = &fits[1];
    let mut series = Vec::new();
    for (s, sw) in data.sweeps.iter().enumerate() {
        let pts = |model: bool| -> Vec<(f64, f64)> {
            cal.fit
                .points
                .iter()
                .filter(|p| p.id.sweep == s)
                .map(|p| {
                    let st = &sw.steps[p.id.step];
                    let y = if model {
                        p.response[(0, 0)]
                    } else {
                        st.response[(0, 0)]
                    };
                    (st.frequency_hz, y.norm())
                })
                .collect()
        };
        series.push((format!("test, {}", sw.label), pts(false)));
        series.push((format!("calibrated model, {}", sw.label), pts(true)));
    }
    let ch = &obj.data().channels[0];
    let fig = nlsim::plot::Lines {
        title: format!(
            "{}: synthetic test vs calibrated model (harmonic 1)",
            model.name()
        ),
        x_desc: "frequency (Hz)".into(),
        y_desc: format!(
            "|{}| {} ({})",
            ch.name,
            ch.quantity.as_str(),
            nlsim::output::unit(ch.quantity)
        ),
        series,
    };
    say(&format!(
        "  plots: {}",
        plot_both(report_dir, "calibration_frf", &fig)?
    ));
    say(&format!(
        "  test data: {} (try `nlsim calibrate {} {} --param {}={:e}:{:e} --compare 1,3`)",
        csv.display(),
        model.name(),
        csv.display(),
        params[0],
        truth[0] / 100.0,
        truth[0] * 100.0
    ));
    say("");
    let kf = cal.kfold.as_ref().expect("folds = 10");
    say(&format!(
        "[8/8] k-fold statistics: {} folds (seed {}), each trained on the other folds from the estimate",
        kf.k, config.seed
    ));
    let rms = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    say(&format!(
        "  mean rms weighted residual: training {:.3}, held out {:.3} (1 = at the noise level)",
        rms(&kf.training_rms),
        rms(&kf.held_out_rms)
    ));
    let groups = params
        .iter()
        .enumerate()
        .map(|(j, p)| {
            let rel = cal.cramer_rao.std[j] / cal.estimate[j].abs();
            nlsim::plot::BarGroup {
                label: p.to_string(),
                values: kf
                    .estimates
                    .iter()
                    .map(|e| e[j] / cal.estimate[j])
                    .collect(),
                band: rel.is_finite().then_some((1.0 - rel, 1.0 + rel)),
            }
        })
        .collect();
    let fig = nlsim::plot::Bars {
        title: format!("{}: fold estimates / full-data estimate", model.name()),
        bar_desc: "fold".into(),
        y_desc: "fold estimate / estimate (1)".into(),
        baseline: 1.0,
        band_desc: "Cramér–Rao ±1σ".into(),
        groups,
    };
    say(&format!(
        "  plots: {}",
        plot_both(report_dir, "kfold", &fig)?
    ));
    Ok(())
}

/// Residual form of `nlsim calibrate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
enum CalibForm {
    /// Real and imaginary parts of the complex difference.
    Complex,
    /// Log-magnitude and phase differences.
    LogMagnitude,
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
            println!("{s}");
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

/// The thesis pipeline, stage by stage; stages not built yet say so.
fn demo(model: &str, report_dir: &std::path::Path, quiet: bool) -> nlsim::Result<()> {
    std::fs::create_dir_all(report_dir).map_err(|source| nlsim::Error::Io {
        path: report_dir.to_path_buf(),
        source,
    })?;
    // Everything said also goes to REPORT/summary.txt.
    let text = std::cell::RefCell::new(String::new());
    let say = |s: &str| {
        if !quiet {
            println!("{s}");
        }
        let mut t = text.borrow_mut();
        t.push_str(s);
        t.push('\n');
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
    demo_time_response(&loaded.model, &reduced, &system, report_dir, &say)?;
    say("");
    demo_frf(&loaded.model, &reduced, report_dir, &say)?;
    say("");
    let stages = [
        (
            "[5/8] pre-test planning (Fisher information)",
            "the planning issue; no planning-ranking plot",
        ),
        (
            "[6/8] virtual force-controlled test with a shaker model",
            "the planning issue; stage 7 measures a synthetic stepped sine instead",
        ),
    ];
    for (stage, needs) in stages {
        say(&format!("{stage}: not built yet (needs {needs})"));
    }
    say("");
    demo_calibration(&loaded.model, &reduced, report_dir, &say)?;
    say("");
    let summary = report_dir.join("summary.txt");
    say(&format!(
        "done in {:.2} s; report in {} (summary.txt, plots as SVG and PNG)",
        t0.elapsed().as_secs_f64(),
        report_dir.display()
    ));
    let tmp = report_dir.join(".summary.txt.tmp");
    std::fs::write(&tmp, text.borrow().as_bytes())
        .and_then(|()| std::fs::rename(&tmp, &summary))
        .map_err(|source| nlsim::Error::Io {
            path: summary,
            source,
        })?;
    Ok(())
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

fn frf(
    spec: &str,
    req: &nlsim::run::FrfRequest,
    sets: &[String],
    out: Option<&std::path::Path>,
    plot: Option<&std::path::Path>,
    cli: &Cli,
) -> nlsim::Result<()> {
    use nlsim::hb::PointKind;
    use std::f64::consts::PI;
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
            println!("{s}");
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
    let (sys, branch, y) = (&run.system, &run.branch, &run.responses);
    say(format!(
        "frf {}: {} {:.4}–{:.4} Hz, H = {} harmonics of Ω/{}, {} modes{} (reduced in {:.2} s), \
         {} unknowns, AFT samples {:?}",
        model.name(),
        req.mode.as_str(),
        req.from_hz,
        req.to_hz,
        set.h,
        set.nu,
        run.modes,
        if req.residual {
            " + residual flexibility"
        } else {
            ""
        },
        run.reduce_seconds,
        sys.n_unknowns(),
        sys.aft_samples()
    ));
    for x in &sys.forcing().terms {
        say(format!(
            "  force {:<10} {:.4e} N at harmonic {} (Ω)",
            sys.inputs()[x.input].0,
            x.amplitude.norm(),
            nlsim::frf::harmonic_label(x.harmonic, set.nu)
        ));
    }
    let n = branch.points.len();
    let unstable = branch
        .points
        .iter()
        .filter(|p| p.stable() == Some(false))
        .count();
    say(format!(
        "  {n} points in {:.3} s ({:.3} ms per point){}; {unstable} unstable",
        run.seconds,
        1e3 * run.seconds / n as f64,
        if run.status.is_converged() {
            ""
        } else {
            " — stopped at the point limit before the end"
        }
    ));
    if cli.verbose {
        let its: usize = branch.points.iter().map(|p| p.iterations).sum();
        say(format!(
            "  Newton: {its} iterations in all, {:.2} per point",
            its as f64 / n.max(1) as f64
        ));
    }
    for p in branch
        .points
        .iter()
        .filter(|p| matches!(p.kind, PointKind::Fold | PointKind::Jump))
    {
        say(format!(
            "  {} at {:.5} Hz",
            if p.kind == PointKind::Fold {
                "fold"
            } else {
                "jump"
            },
            p.omega / (2.0 * PI)
        ));
    }
    for bp in &branch.branch_points {
        say(format!(
            "  branch point near {:.5} Hz",
            bp.omega / (2.0 * PI)
        ));
    }
    for (s, sen) in sys.sensors().iter().enumerate() {
        let (i, a) = (0..n)
            .map(|i| (i, y[i][(s, set.nu)].norm()))
            .fold((0, 0.0f64), |m, v| if v.1 > m.1 { v } else { m });
        say(format!(
            "  {:<12} peak |{}| at the fundamental {a:.5e} {} at {:.5} Hz",
            sen.name,
            sen.quantity.as_str(),
            nlsim::output::unit(sen.quantity),
            branch.points[i].omega / (2.0 * PI)
        ));
    }
    if let Some(path) = out {
        let info = nlsim::frf::FrfInfo {
            model_spec: spec.to_string(),
            model_name: model.name().to_string(),
            mode: req.mode.as_str().to_string(),
            modes: run.modes,
            residual: req.residual,
            seconds: run.seconds,
        };
        nlsim::frf::write_frf(path, sys, branch, y, &info)?;
        say(format!("  written to {}", path.display()));
    }
    if let Some(p) = plot_path {
        let title = format!("{} — {}, H = {}", model.name(), req.mode.as_str(), set.h);
        nlsim::frf::plot_frf(&p, sys, branch, y, 0, &title)?;
        say(format!("  plot {}", p.display()));
    }
    Ok(())
}

fn simulate(
    spec: &str,
    req: &nlsim::run::SimRequest,
    sets: &[String],
    out: Option<&std::path::Path>,
    cli: &Cli,
) -> nlsim::Result<()> {
    let quiet = cli.quiet;
    let n_steps = req.check()?;
    if let Some(path) = out {
        // Refuse an unknown format before the run.
        nlsim::output::Format::of(path, nlsim::simulate::HINT)?;
    }
    let say = |s: String| {
        if !quiet {
            println!("{s}");
        }
    };
    let model = nlsim::run::load_for_run(spec, sets)?;
    let run = nlsim::run::run_simulation(&model, req, &mut progress_line(quiet, "simulate"))?;
    let history = &run.history;
    let dt = 1.0 / req.rate;
    say(format!(
        "simulate {}: {}, {}, dt {dt:.4e} s, {} samples over {} s",
        model.name(),
        req.method.as_str(),
        if req.method.unreduced() {
            format!(
                "unreduced ({} DOFs), effective stiffness factorised in {:.2} s",
                model.n_dofs(),
                run.setup_seconds
            )
        } else {
            format!(
                "{} modes{} (reduced in {:.2} s)",
                run.modes,
                if req.residual {
                    " + residual flexibility"
                } else {
                    ""
                },
                run.setup_seconds
            )
        },
        n_steps + 1,
        req.duration
    ));
    for (x, sp) in model.excitation().iter().zip(&run.excitation) {
        say(format!("  excitation {:<10} {sp}", x.name));
    }
    let st = &history.stats;
    if run.flops_per_state_step > 0 {
        say(format!(
            "  run: {:.3} s wall, {:.2} ns per mode-step ({} states, {} flops each)",
            st.seconds,
            st.seconds / (n_steps as f64 * run.states as f64) * 1e9,
            run.states,
            run.flops_per_state_step
        ));
    }
    say(format!(
        "  {} steps ({} rejected), {} evaluations, Newton {} iterations (max {} in a step), {} \
         contact events, {:.3} s wall",
        st.steps,
        st.rejected_steps,
        st.evaluations,
        st.newton_iterations,
        st.max_newton_iterations,
        st.events.len(),
        st.seconds
    ));
    if cli.verbose {
        for e in &st.events {
            say(format!(
                "    contact event: element {} {} at t = {:.9e} s",
                history.element_names[e.element],
                if e.closing { "closes" } else { "opens" },
                e.time
            ));
        }
    }
    say(format!(
        "  {:<14} {:<13} {:>13} {:>13}",
        "output", "quantity", "peak", "rms"
    ));
    for s in &history.outputs {
        let peak = s.values.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let rms = (s.values.iter().map(|x| x * x).sum::<f64>() / s.values.len() as f64).sqrt();
        say(format!(
            "  {:<14} {:<13} {peak:>13.5e} {rms:>13.5e}",
            s.name,
            s.quantity.as_str()
        ));
    }
    for (e, name) in history.element_names.iter().enumerate() {
        let pu = history.element_displacements[e]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        let pg = history.element_forces[e]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        say(format!(
            "  element {name:<10} peak |u| {pu:.5e} m, peak |g| {pg:.5e} N"
        ));
    }
    if let Some(path) = out {
        let info = nlsim::simulate::RunInfo {
            model_spec: spec.to_string(),
            method: req.method.as_str().to_string(),
            excitation: run.excitation.clone(),
            modes: run.modes,
        };
        nlsim::simulate::write_history(path, &model, history, &info)?;
        say(format!("  written to {}", path.display()));
    }
    Ok(())
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
            println!("{s}");
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
                    println!(
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
            } => {
                say(format!(
                    "  shard {task} of {count}: {jobs} jobs in {seconds:.2} s, {} failed, written to {}",
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
        println!(
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
            println!("  {line}");
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
        println!(
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
        println!("{id}");
        if !cli.quiet {
            eprintln!(
                "  submitted; when it is done: nlsim batch merge {}",
                jobs.display()
            );
        }
    }
    Ok(())
}
