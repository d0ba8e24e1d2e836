//! The `nlsim` binary: the command line parsed by `nlsim::cli` (every option and its help,
//! and each subcommand's request), the thread pool set, the command dispatched, the outcome
//! mapped to an exit code. Nothing is computed, formatted or written here. Exit codes: 0
//! success, 1 a run failed (bad model, numerical failure), 2 bad usage, 128 + the signal
//! (130 for Ctrl-C, 143 for SIGTERM) when a stop signal ended the run.

use clap::Parser as _;
use nlsim::cli::Cli;
use nlsim::present::console::Console;
use std::process::ExitCode;

/// Most worker threads `--threads` accepts.
const MAX_THREADS: usize = 1024;

#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;

fn main() -> ExitCode {
    // First, so that Ctrl-C during the start of a run is handled as during the rest.
    nlsim::cli::interrupt::install();
    let cli = match Cli::try_parse() {
        Ok(cli) => cli,
        Err(e) => return usage_error(&e),
    };
    if let Some(n) = cli.threads {
        if !(1..=MAX_THREADS).contains(&n) {
            say(&format!(
                "error: --threads {n}: give 1 to {MAX_THREADS} (each thread reserves a stack; \
                 more threads than cores only slow the run down)"
            ));
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
    let outcome = nlsim::cli::dispatch(&cli, &console);
    nlsim::cli::interrupt::settle();
    match outcome {
        Ok(()) => ExitCode::SUCCESS,
        Err(nlsim::Error::Interrupted(kept)) => {
            say(&format!(
                "interrupted: {}",
                nlsim::formats::files::one_line(&kept)
            ));
            let signal = nlsim::formats::interrupt::last_signal().clamp(1, 64);
            ExitCode::from(128 + signal as u8)
        }
        Err(e @ nlsim::Error::Usage(_)) => {
            say(&format!(
                "error: {}",
                nlsim::formats::files::one_line(&e.to_string())
            ));
            ExitCode::from(2)
        }
        Err(e) => {
            say(&format!(
                "error: {}",
                nlsim::formats::files::one_line(&e.to_string())
            ));
            ExitCode::from(1)
        }
    }
}

/// Writes `line` to standard error; where that cannot be written (a full disk under a
/// redirection) the exit code alone says what happened, without a panic.
fn say(line: &str) {
    use std::io::Write as _;
    let _ = writeln!(std::io::stderr(), "{line}");
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
    say(&format!(
        "error: {}{tips} — see nlsim --help",
        one_line(&message)
    ));
    ExitCode::from(2)
}
