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
        /// SVG plot of the amplitude against frequency (default: beside --out, .svg).
        #[arg(long)]
        plot: Option<std::path::PathBuf>,
        /// Element parameter overrides, e.g. `--set spring.k3=2e15` (repeatable).
        #[arg(long)]
        set: Vec<String>,
    },
    /// Run the pipeline on a built-in model and print a readable summary.
    Demo {
        /// Model to run on (default: the ECL benchmark beam).
        #[arg(long, default_value = "ecl_beam")]
        model: String,
    },
}

/// How `nlsim frf` sweeps.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum FrfMode {
    /// Pseudo-arclength continuation: every branch through the folds, stability per point.
    Continuation,
    /// Stepped sine upwards, each point from the last (jumps down past the upper fold).
    StepUp,
    /// Stepped sine downwards (jumps up past the lower fold).
    StepDown,
}

/// Time integration methods of `nlsim simulate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
enum Method {
    /// Exponential first-order hold with nonlinear feedback (the fast method).
    Foh,
    /// Zero-order hold (bias studies).
    Zoh,
    /// Lagrange second-order hold (bias studies).
    Lsoh,
    /// Dormand-Prince RK45 with ODE45's error control on the reduced model.
    Rk45,
    /// Classic RK4 on the reduced model.
    Rk4,
    /// Newmark average acceleration with Newton on the unreduced model.
    Newmark,
    /// HHT-alpha with Newton on the unreduced model.
    Hht,
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
            let opts = SimulateOptions {
                duration: *duration,
                rate: *rate,
                method: *method,
                excitation,
                modes: *modes,
                residual: !no_residual,
                events: !no_events,
                rtol: *rtol,
                atol: *atol,
                substeps: *substeps,
                hht_alpha: *hht_alpha,
                set,
            };
            simulate(model, &opts, out.as_deref(), cli.quiet)
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
            let o = FrfOptions {
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
                set,
            };
            frf(model, &o, out.as_deref(), plot.as_deref(), cli.quiet)
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

/// Stage 3 of the demo: FOH under a multi-sine at the first natural frequency (harmonics 1, 2,
/// 3 at 100, 10 and 5 % of the nominal force), checked against a tight RK45 run.
fn demo_time_response(
    model: &nlsim::kernel::Model,
    reduced: &nlsim::reduction::ReducedModel,
    system: &nlsim::reduction::ModalSystem,
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
    let cont = nlsim::hb::continuation(
        &sys,
        &ContinuationConfig::frequency(lo, hi),
        None,
        &mut |_| {},
    )?;
    let t_cont = t.elapsed().as_secs_f64();
    let n = 200;
    let grid = |a: f64, b: f64| -> Vec<f64> {
        (0..n)
            .map(|i| 2.0 * PI * (a + (b - a) * i as f64 / (n - 1) as f64))
            .collect()
    };
    let t = Instant::now();
    let up = nlsim::hb::stepped_sine(&sys, &grid(lo, hi), 1.0, false, &mut |_| {})?;
    let down = nlsim::hb::stepped_sine(&sys, &grid(hi, lo), 1.0, false, &mut |_| {})?;
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
    let dir = std::path::Path::new("nlsim-report");
    std::fs::create_dir_all(dir).map_err(|source| nlsim::Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let plot = dir.join(format!("frf_{}.svg", model.name()));
    nlsim::frf::plot_svg(
        &plot,
        &sys,
        &cont,
        &nlsim::frf::responses(&sys, &cont),
        0,
        &format!("{}: harmonic balance, H = 7", model.name()),
    )?;
    say(&format!("  plot: {}", plot.display()));
    Ok(())
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
    demo_time_response(&loaded.model, &reduced, &system, &say)?;
    say("");
    demo_frf(&loaded.model, &reduced, &say)?;
    say("");
    let stages = [
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

struct SimulateOptions<'a> {
    duration: f64,
    rate: f64,
    method: Method,
    excitation: &'a [String],
    modes: usize,
    residual: bool,
    events: bool,
    rtol: f64,
    atol: f64,
    substeps: usize,
    hht_alpha: f64,
    set: &'a [String],
}

/// A progress line on stderr, only when it is a terminal.
fn progress_line(quiet: bool, what: &'static str) -> impl FnMut(usize, usize) {
    use std::io::IsTerminal;
    let show = !quiet && std::io::stderr().is_terminal();
    let t = Instant::now();
    move |done, total| {
        if show {
            eprint!(
                "\r  {what}: {:3.0} % ({done}/{total} steps, {:.1} s) ",
                100.0 * done as f64 / total.max(1) as f64,
                t.elapsed().as_secs_f64()
            );
            if done == total {
                eprintln!();
            }
        }
    }
}

/// Options of `nlsim frf`.
struct FrfOptions<'a> {
    from_hz: f64,
    to_hz: f64,
    harmonics: usize,
    subharmonic: usize,
    force: Option<f64>,
    mode: FrfMode,
    points: usize,
    modes: usize,
    residual: bool,
    stability: bool,
    set: &'a [String],
}

/// Loads and validates a model for a run (definiteness shows in the factorisations) and
/// applies its `--set` overrides.
fn load_for_run(spec: &str, sets: &[String]) -> nlsim::Result<nlsim::kernel::Model> {
    let mut model = nlsim::load_model(spec)?.model;
    model.validate(&ValidationConfig {
        check_definiteness: false,
        ..Default::default()
    })?;
    apply_sets(&mut model, sets)?;
    Ok(model)
}

/// Applies `--set element.param=value` overrides.
fn apply_sets(model: &mut nlsim::kernel::Model, sets: &[String]) -> nlsim::Result<()> {
    for s in sets {
        let (name, v) = s.split_once('=').ok_or_else(|| {
            nlsim::Error::Usage(format!("--set '{s}': expected element.param=value"))
        })?;
        let v: f64 = v
            .trim()
            .parse()
            .map_err(|_| nlsim::Error::Usage(format!("--set '{s}': '{v}' is not a number")))?;
        model.set_param_by_name(name.trim(), v)?;
    }
    Ok(())
}

fn frf(
    spec: &str,
    o: &FrfOptions<'_>,
    out: Option<&std::path::Path>,
    plot: Option<&std::path::Path>,
    quiet: bool,
) -> nlsim::Result<()> {
    use nlsim::hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, PointKind};
    use std::f64::consts::PI;
    let usage = |m: String| nlsim::Error::Usage(m);
    for (what, v) in [("--from", o.from_hz), ("--to", o.to_hz)] {
        if !(v > 0.0 && v.is_finite()) {
            return Err(usage(format!(
                "{what} {v} must be a positive frequency in Hz"
            )));
        }
    }
    if o.from_hz == o.to_hz {
        return Err(usage("--from and --to are equal".into()));
    }
    if o.points < 2 {
        return Err(usage("--points must be at least 2".into()));
    }
    if let Some(f) = o.force
        && !f.is_finite()
    {
        return Err(usage(format!("--force {f} is not a finite number")));
    }
    if let Some(path) = out {
        nlsim::output::Format::of(path, nlsim::frf::HINT)?;
    }
    let plot_path = plot
        .map(|p| p.to_path_buf())
        .or_else(|| out.map(|p| p.with_extension("svg")));
    if let Some(p) = &plot_path
        && p.extension().and_then(|e| e.to_str()) != Some("svg")
    {
        return Err(usage(format!(
            "--plot {}: name the plot FILE.svg",
            p.display()
        )));
    }
    let set = HarmonicSet::new(o.harmonics, o.subharmonic)
        .map_err(|e| usage(format!("--harmonics/--subharmonic: {e}")))?;
    let say = |s: String| {
        if !quiet {
            println!("{s}");
        }
    };
    let model = load_for_run(spec, o.set)?;
    if model.elements().is_empty() {
        return Err(usage(format!(
            "model '{spec}' has no nonlinear element: its FRF is linear (see `nlsim modes`)"
        )));
    }
    if model.excitation().is_empty() {
        return Err(usage(format!(
            "model '{spec}' has no excitation point to force"
        )));
    }
    if model.sensors().is_empty() {
        return Err(usage(format!("model '{spec}' has no sensor to report")));
    }
    let n_modes = o.modes.min(model.n_dofs());
    if n_modes == 0 {
        return Err(usage("--modes must be at least 1".into()));
    }
    let t0 = Instant::now();
    let reduced = nlsim::reduction::reduce(
        &model,
        &nlsim::reduction::ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(n_modes),
                ..EigenConfig::default()
            },
            residual_flexibility: o.residual,
            ..Default::default()
        },
    )?;
    let red_s = t0.elapsed().as_secs_f64();
    let mut sys = HbSystem::from_model(&model, &reduced, set, HbConfig::default())?;
    if let Some(f) = o.force {
        for t in &mut sys.forcing.terms {
            t.amplitude = nlsim::hb::harmonics::c64::new(f, 0.0);
        }
    }
    let mode_name = match o.mode {
        FrfMode::Continuation => "continuation",
        FrfMode::StepUp => "step-up",
        FrfMode::StepDown => "step-down",
    };
    say(format!(
        "frf {}: {mode_name} {:.4}–{:.4} Hz, H = {} harmonics of Ω/{}, {} modes{} (reduced in          {red_s:.2} s), {} unknowns, AFT samples {:?}",
        model.name(),
        o.from_hz,
        o.to_hz,
        set.h,
        set.nu,
        n_modes,
        if o.residual {
            " + residual flexibility"
        } else {
            ""
        },
        sys.n_unknowns(),
        sys.aft_samples()
    ));
    for x in &sys.forcing.terms {
        say(format!(
            "  force {:<10} {:.4e} N at harmonic {} (Ω)",
            sys.inputs[x.input].0,
            x.amplitude.norm(),
            nlsim::frf::harmonic_label(x.harmonic, set.nu)
        ));
    }
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
    let branch = match o.mode {
        FrfMode::Continuation => {
            let mut cfg = ContinuationConfig::frequency(o.from_hz, o.to_hz);
            cfg.stability = o.stability;
            nlsim::hb::continuation(&sys, &cfg, None, &mut progress)?
        }
        FrfMode::StepUp | FrfMode::StepDown => {
            let (a, b) = if o.mode == FrfMode::StepUp {
                (o.from_hz.min(o.to_hz), o.from_hz.max(o.to_hz))
            } else {
                (o.from_hz.max(o.to_hz), o.from_hz.min(o.to_hz))
            };
            let omegas: Vec<f64> = (0..o.points)
                .map(|i| 2.0 * PI * (a + (b - a) * i as f64 / (o.points - 1) as f64))
                .collect();
            nlsim::hb::stepped_sine(&sys, &omegas, 1.0, o.stability, &mut progress)?
        }
    };
    if show {
        eprintln!();
    }
    let secs = t1.elapsed().as_secs_f64();
    let n = branch.points.len();
    let unstable = branch
        .points
        .iter()
        .filter(|p| p.stable() == Some(false))
        .count();
    say(format!(
        "  {n} points in {secs:.3} s ({:.3} ms per point){}; {unstable} unstable",
        1e3 * secs / n as f64,
        if branch.complete {
            ""
        } else {
            " — stopped at the point limit before the end"
        }
    ));
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
    let y = nlsim::frf::responses(&sys, &branch);
    for (s, sen) in sys.sensors.iter().enumerate() {
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
    let info = nlsim::frf::FrfInfo {
        model_spec: spec.to_string(),
        mode: mode_name.to_string(),
        modes: n_modes,
        residual: o.residual,
        seconds: secs,
    };
    if let Some(path) = out {
        nlsim::frf::write_frf(path, &sys, &branch, &y, &info)?;
        say(format!("  written to {}", path.display()));
    }
    if let Some(p) = plot_path {
        let title = format!("{} — {mode_name}, H = {}", model.name(), set.h);
        nlsim::frf::plot_svg(&p, &sys, &branch, &y, 0, &title)?;
        say(format!("  plot {}", p.display()));
    }
    Ok(())
}

fn simulate(
    spec: &str,
    o: &SimulateOptions<'_>,
    out: Option<&std::path::Path>,
    quiet: bool,
) -> nlsim::Result<()> {
    use nlsim::sim::{FohConfig, Hold, LoadCase, Newmark, NewmarkConfig, Plant, Simulator};
    let usage = |m: String| nlsim::Error::Usage(m);
    if !(o.duration > 0.0 && o.duration.is_finite()) {
        return Err(usage(format!(
            "--duration {} must be a positive number of seconds",
            o.duration
        )));
    }
    if !(o.rate > 0.0 && o.rate.is_finite()) {
        return Err(usage(format!(
            "--rate {} must be a positive frequency in Hz",
            o.rate
        )));
    }
    let n_steps = (o.duration * o.rate).round() as usize;
    if n_steps == 0 || n_steps > 200_000_000 {
        return Err(usage(format!(
            "--duration x --rate gives {n_steps} steps; it must be between 1 and 2e8"
        )));
    }
    if let Some(path) = out {
        // Refuse an unknown format before the run.
        nlsim::output::Format::of(path, nlsim::simulate::HINT)?;
    }
    let dt = 1.0 / o.rate;
    let say = |s: String| {
        if !quiet {
            println!("{s}");
        }
    };
    let model = load_for_run(spec, o.set)?;
    if model.excitation().is_empty() && !o.excitation.is_empty() {
        return Err(usage(format!(
            "model '{spec}' has no excitation points to drive"
        )));
    }
    let t_red = Instant::now();
    let unreduced = matches!(o.method, Method::Newmark | Method::Hht);
    let n_modes = if unreduced {
        1
    } else {
        o.modes.min(model.n_dofs())
    };
    if n_modes == 0 {
        return Err(usage("--modes must be at least 1".into()));
    }
    let cfg = nlsim::reduction::ReductionConfig {
        eigen: EigenConfig {
            selection: ModeSelection::Lowest(n_modes),
            ..EigenConfig::default()
        },
        residual_flexibility: o.residual,
        ..Default::default()
    };
    let reduced = nlsim::reduction::reduce(&model, &cfg)?;
    let f1 = reduced.modes.frequencies_hz()[0];
    let red_s = t_red.elapsed().as_secs_f64();
    // Excitation: one signal per excitation point.
    let mut specs: Vec<String> = model
        .excitation()
        .iter()
        .map(|_| format!("sine:freq={f1:.6}"))
        .collect();
    for e in o.excitation {
        match e
            .split_once('=')
            .filter(|(n, _)| !n.contains(':') && !n.contains(','))
        {
            Some((name, sp)) => {
                let i = model
                    .excitation()
                    .iter()
                    .position(|x| x.name == name)
                    .ok_or_else(|| {
                        usage(format!(
                            "--excitation '{e}': no excitation point '{name}' (the model has {})",
                            model
                                .excitation()
                                .iter()
                                .map(|x| x.name.as_str())
                                .collect::<Vec<_>>()
                                .join(", ")
                        ))
                    })?;
                specs[i] = sp.to_string();
            }
            None => specs.iter_mut().for_each(|s| *s = e.clone()),
        }
    }
    let forces = model
        .excitation()
        .iter()
        .zip(&specs)
        .map(|(x, sp)| nlsim::simulate::parse_excitation(sp, x.amplitude, o.duration, o.rate))
        .collect::<nlsim::Result<Vec<_>>>()?;
    let case = LoadCase::new("simulate", forces);
    let method_name = format!("{:?}", o.method).to_lowercase();
    say(format!(
        "simulate {}: {method_name}, {}, dt {dt:.4e} s, {} samples over {} s",
        model.name(),
        if unreduced {
            format!("unreduced ({} DOFs)", model.n_dofs())
        } else {
            format!(
                "{n_modes} modes{} (reduced in {red_s:.2} s)",
                if o.residual {
                    " + residual flexibility"
                } else {
                    ""
                }
            )
        },
        n_steps + 1,
        o.duration
    ));
    for (x, sp) in model.excitation().iter().zip(&specs) {
        say(format!("  excitation {:<10} {sp}", x.name));
    }
    let history = if unreduced {
        let mut cfg = NewmarkConfig::new(dt);
        cfg.substeps = o.substeps;
        cfg.alpha = if o.method == Method::Hht {
            o.hht_alpha
        } else {
            0.0
        };
        let nm = Newmark::new(&model, &cfg)?;
        say(format!(
            "  effective stiffness factorised in {:.2} s",
            nm.setup_seconds
        ));
        nm.run(&case, n_steps)?
    } else {
        let system = nlsim::reduction::ModalSystem::new(&reduced)?;
        let plant = Plant::from_model(&model, &system)?;
        match o.method {
            Method::Foh | Method::Zoh | Method::Lsoh => {
                let mut cfg = FohConfig::new(dt);
                cfg.hold = match o.method {
                    Method::Zoh => Hold::Zoh,
                    Method::Lsoh => Hold::Lsoh,
                    _ => Hold::Foh,
                };
                cfg.locate_events = o.events;
                let sim = Simulator::new(&plant, &cfg)?;
                let h =
                    sim.run_with_progress(&case, n_steps, &mut progress_line(quiet, "simulate"))?;
                let per = h.stats.seconds / (n_steps as f64 * system.n_states() as f64) * 1e9;
                say(format!(
                    "  run: {:.3} s wall, {:.2} ns per mode-step ({} states, {} flops each)",
                    h.stats.seconds,
                    per,
                    system.n_states(),
                    sim.flops_per_state_step()
                ));
                h
            }
            Method::Rk45 => nlsim::sim::rk45(
                &plant,
                &case,
                dt,
                n_steps,
                &nlsim::sim::Rk45Config {
                    rtol: o.rtol,
                    atol: o.atol,
                    ..Default::default()
                },
            )?,
            _ => nlsim::sim::rk4(
                &plant,
                &case,
                dt,
                n_steps,
                &nlsim::sim::Rk4Config {
                    substeps: o.substeps,
                    ..Default::default()
                },
            )?,
        }
    };
    let st = &history.stats;
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
            method: method_name,
            excitation: specs,
            modes: if unreduced { 0 } else { n_modes },
        };
        nlsim::simulate::write_history(path, &model, &history, &info)?;
        say(format!("  written to {}", path.display()));
    }
    Ok(())
}
