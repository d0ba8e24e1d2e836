//! The `nlsim` command line: arguments parsed into the request types of `nlsim::commands`
//! (see `args.rs` for every option) and dispatched to their `execute` functions. Nothing is
//! computed, formatted or written here. Exit codes: 0 success, 1 a run failed (bad model,
//! numerical failure), 2 bad usage.

mod args;

use args::{BatchAction, CalibBranch, CalibForm, Cli, Command};
use clap::Parser as _;
use nlsim::commands;
use nlsim::present::console::Console;
use std::process::ExitCode;

/// Most worker threads `--threads` accepts.
const MAX_THREADS: usize = 1024;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

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
    let console = Console::terminal(cli.quiet, cli.verbose);
    match dispatch(&cli, &console) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e @ nlsim::Error::Usage(_)) => {
            eprintln!("error: {}", nlsim::formats::files::one_line(&e.to_string()));
            ExitCode::from(2)
        }
        Err(e) => {
            eprintln!("error: {}", nlsim::formats::files::one_line(&e.to_string()));
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
    let one_line = nlsim::formats::files::one_line;
    let tips = if tips.is_empty() {
        String::new()
    } else {
        format!(" ({})", one_line(&tips.join("; ")))
    };
    eprintln!("error: {}{tips} — see nlsim --help", one_line(&message));
    ExitCode::from(2)
}

/// The parallelism `--threads` asks for: sequential for 1, the rayon pool otherwise.
fn par(cli: &Cli) -> faer::Par {
    match cli.threads {
        Some(1) => faer::Par::Seq,
        _ => faer::Par::rayon(0),
    }
}

/// Each subcommand's arguments into its request, then the command's `execute`.
fn dispatch(cli: &Cli, console: &Console) -> nlsim::Result<()> {
    match &cli.command {
        Command::Check {
            model,
            no_definiteness,
        } => commands::check::check(model, !no_definiteness, console),
        Command::Fixtures => {
            commands::check::fixtures(console);
            Ok(())
        }
        Command::Export { model, dir } => commands::check::export(model, dir, console),
        Command::Modes {
            model,
            count,
            fmax,
            out,
            tol,
            block,
            lanczos,
            no_sturm_check,
            report,
        } => {
            let req = commands::modes::ModesRequest {
                model: model.clone(),
                count: *count,
                fmax_hz: *fmax,
                tol: *tol,
                block: *block,
                lanczos: lanczos.settings()?,
                sturm_check: !no_sturm_check,
                par: par(cli),
                out: out.clone(),
                report: report.clone(),
            };
            commands::modes::execute(&req, console)
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
            use commands::simulate::{Drive, SimOutputs, SimRequest};
            let req = SimRequest {
                duration: *duration,
                rate: *rate,
                method: *method,
                excitation: excitation
                    .iter()
                    .map(|e| Drive::parse(e, *duration, *rate))
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
            let outputs = SimOutputs {
                out: out.clone(),
                report: report.clone(),
                compress: *compress,
            };
            commands::simulate::execute(model, set, &req, &outputs, console)
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
            use commands::frf::{FrfOutputs, FrfRequest, FrfStart, StartFile};
            let req = FrfRequest {
                from_hz: *from,
                to_hz: *to,
                harmonics: *harmonics,
                subharmonic: *subharmonic,
                force: *force,
                force_harmonics: force_harmonic
                    .iter()
                    .map(|t| commands::frf::parse_force_harmonic(t))
                    .collect::<nlsim::Result<_>>()?,
                mode: *mode,
                points: *points,
                max_step_hz: *max_step,
                start: FrfStart::parse(start).expect("clap checked the value"),
                start_file: start_file.as_ref().map(|path| StartFile {
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
                out: out.clone(),
                plot: plot.clone(),
                magnitude: *magnitude,
                phase: *phase,
                report: report.clone(),
            };
            commands::frf::execute(model, set, &req, &outputs, console)
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
            let req = commands::nnm::NnmRequest {
                mode: *mode,
                from: *from,
                to: *to,
                points: *points,
                harmonics: *harmonics,
                modes: *modes,
                par: par(cli),
                lanczos: lanczos.settings()?,
            };
            let outputs = (out.as_deref(), plot.as_deref());
            commands::nnm::execute(model, set, &req, outputs, console)
        }
        Command::Demo { model, report } => commands::demo::execute(model, report, console),
        Command::Plan {
            model,
            plan,
            criterion,
            top,
            report,
        } => {
            let mut req = commands::plan::PlanRequest::load(plan, model)?;
            if let Some(c) = criterion {
                req.criterion = nlsim::calib::Criterion::parse(c)
                    .map_err(|e| nlsim::Error::Usage(format!("--criterion: {e}")))?;
            }
            if let Some(t) = top {
                req.top = *t;
            }
            req.report = Some(
                report
                    .clone()
                    .or(req.report)
                    .unwrap_or_else(|| commands::setup::default_report(plan)),
            );
            commands::plan::execute(&req, console)
        }
        Command::Test {
            model,
            test,
            out,
            seed,
            open_loop,
            report,
        } => {
            let mut req = commands::test::TestRequest::load(test, model)?;
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
            req.report = Some(
                report
                    .clone()
                    .or(req.report)
                    .unwrap_or_else(|| commands::setup::default_report(test)),
            );
            commands::test::execute(&req, console)
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
            use commands::calibrate::{CalibrationRequest, parse_param_bounds};
            let mut req = match (config, model, data) {
                (Some(path), _, _) => CalibrationRequest::load(path)?,
                (None, Some(model), Some(data)) => {
                    let specs = params
                        .iter()
                        .map(|p| parse_param_bounds(p))
                        .collect::<nlsim::Result<Vec<_>>>()?;
                    let mut r = CalibrationRequest::new(model.clone(), data.clone(), specs);
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
            commands::calibrate::execute(&req, candidates.as_deref(), console)
        }
        Command::Batch {
            action,
            jobs,
            task_index,
            task_count,
            output,
        } => {
            use nlsim::batch::command;
            match action {
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
                    let o = nlsim::batch::SbatchOptions {
                        tasks: *tasks,
                        cpus_per_task: *cpus_per_task,
                        partition: partition.clone(),
                        time: time.clone(),
                        mem: mem.clone(),
                    };
                    let b = command::load(jobs, output.as_deref())?;
                    let exe = std::env::current_exe().map_err(|source| nlsim::Error::Io {
                        path: "nlsim".into(),
                        source,
                    })?;
                    command::sbatch(&b, jobs, &exe, &o, *submit, console)
                }
                None => {
                    let jobs = jobs.as_ref().ok_or_else(|| {
                        nlsim::Error::Usage(
                            "nlsim batch needs a jobs file: nlsim batch JOBS.toml (or merge, \
                             sbatch)"
                                .into(),
                        )
                    })?;
                    let b = command::load(jobs, output.as_deref())?;
                    let env = |v: &str| std::env::var(v).ok();
                    let index = command::task_number(
                        *task_index,
                        "SLURM_ARRAY_TASK_ID",
                        env("SLURM_ARRAY_TASK_ID"),
                    )?;
                    let count = command::task_number(
                        *task_count,
                        "SLURM_ARRAY_TASK_COUNT",
                        env("SLURM_ARRAY_TASK_COUNT"),
                    )?
                    .unwrap_or(1);
                    command::run(&b, index, count, console)
                }
            }
        }
    }
}
