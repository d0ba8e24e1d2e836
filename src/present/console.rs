//! The terminal: result lines on standard output that survive a closed pipe, notes on
//! standard error, and progress lines on standard error only when it is a terminal (in a log
//! their carriage returns would pile up). A library caller that wants the lines instead of
//! the terminal gives a sink ([`Console::with_sink`]).

use std::io::{IsTerminal as _, Write as _};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

/// Set once standard output cannot be written (a closed pipe: `nlsim ... | head`): the run
/// goes on quietly and still completes its result files.
static STDOUT_GONE: AtomicBool = AtomicBool::new(false);

/// Writes to standard output without panicking when it is closed: after the first failed
/// write nothing more is printed there. A broken pipe is silent (the reader has what it
/// wanted); any other failure is named once on stderr.
pub fn emit(args: std::fmt::Arguments<'_>, newline: bool) {
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

/// A receiver of the lines a command would print (see [`Console::with_sink`]).
type Sink = Box<dyn Fn(&str) + Sync>;

/// Where a command's lines go, and how much it says.
pub struct Console {
    quiet: bool,
    verbose: bool,
    progress: bool,
    sink: Option<Sink>,
}

impl Console {
    /// The terminal: result lines on stdout unless `quiet`, detail when `verbose` (and not
    /// `quiet`), progress on stderr when it is a terminal and not `quiet`.
    pub fn terminal(quiet: bool, verbose: bool) -> Self {
        Console {
            quiet,
            verbose: verbose && !quiet,
            progress: !quiet && std::io::stderr().is_terminal(),
            sink: None,
        }
    }

    /// Nothing printed: result lines and notes go to `sink`, no progress.
    pub fn with_sink(sink: impl Fn(&str) + Sync + 'static) -> Self {
        Console {
            quiet: false,
            verbose: false,
            progress: false,
            sink: Some(Box::new(sink)),
        }
    }

    /// Whether only errors are wanted.
    pub fn quiet(&self) -> bool {
        self.quiet
    }

    /// Whether detail (solver statistics, each batch job) is wanted.
    pub fn verbose(&self) -> bool {
        self.verbose
    }

    /// Whether progress lines are shown.
    pub fn shows_progress(&self) -> bool {
        self.progress
    }

    /// A result line (stdout), unless quiet.
    pub fn say(&self, line: &str) {
        if !self.quiet {
            self.always(line);
        }
    }

    /// A line that goes out even when quiet (what scripts read, e.g. a submitted job id).
    pub fn always(&self, line: &str) {
        match &self.sink {
            Some(f) => f(line),
            None => emit(format_args!("{line}"), true),
        }
    }

    /// Text without a line end (stdout), unless quiet.
    pub fn say_part(&self, text: &str) {
        if self.quiet {
            return;
        }
        match &self.sink {
            Some(f) => f(text.strip_suffix('\n').unwrap_or(text)),
            None => emit(format_args!("{text}"), false),
        }
    }

    /// A note or warning (stderr), unless quiet.
    pub fn note(&self, line: &str) {
        if self.quiet {
            return;
        }
        match &self.sink {
            Some(f) => f(line),
            None => eprintln!("{line}"),
        }
    }

    /// An error line that goes out whatever the verbosity (stderr).
    pub fn error(&self, line: &str) {
        match &self.sink {
            Some(f) => f(line),
            None => eprintln!("{line}"),
        }
    }

    /// Replaces the progress line (stderr, carriage return) when progress is shown.
    pub fn progress(&self, text: &str) {
        if self.progress {
            eprint!("\r{text}");
        }
    }

    /// Ends the progress line when progress is shown.
    pub fn progress_end(&self) {
        if self.progress {
            eprintln!();
        }
    }

    /// Progress of one phase of a long run with an estimate of the time left: on a
    /// terminal the replaced line `  WHAT done/total, 3.1 s, about 12 s left` (ended at the
    /// last), elsewhere (a log file, a batch job) one line when the phase ends,
    /// `  WHAT total/total in 15.2 s`. `started` is when `first` of the items were done
    /// (the rate is measured from there).
    pub fn phase(&self, what: &str, done: usize, total: usize, started: Instant, first: usize) {
        if self.quiet {
            return;
        }
        let s = started.elapsed().as_secs_f64();
        if self.progress {
            let left = if done > first && done < total {
                format!(
                    ", about {} left",
                    duration_text(s / (done - first) as f64 * (total - done) as f64)
                )
            } else {
                String::new()
            };
            eprint!(
                "\r  {what} {done}/{total}, {}{left}        ",
                duration_text(s)
            );
            if done == total {
                eprintln!();
            }
        } else if done == total && self.sink.is_none() {
            eprintln!("  {what} {done}/{total} in {}", duration_text(s));
        }
    }

    /// A `done/total` progress callback with the time left ([`Console::phase`]): the
    /// replaced line on a terminal, one line in a log when the last item is done.
    pub fn eta<'a>(&'a self, what: &'a str) -> impl FnMut(usize, usize) + 'a {
        let t = Instant::now();
        move |done, total| self.phase(what, done, total, t, 0)
    }

    /// A `done/total` progress callback: `  WHAT:  42 % (21/50, 3.1 s)`, ended at the last.
    pub fn counter<'a>(&'a self, what: &'a str) -> impl FnMut(usize, usize) + 'a {
        let t = Instant::now();
        move |done, total| {
            if self.progress {
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
}

/// A duration for people: `3.1 s`, `4 min 05 s`, `1 h 02 min`.
pub fn duration_text(seconds: f64) -> String {
    if !seconds.is_finite() || seconds < 0.0 {
        return "?".into();
    }
    if seconds < 60.0 {
        return format!("{seconds:.1} s");
    }
    let s = seconds.round() as u64;
    if s < 3600 {
        format!("{} min {:02} s", s / 60, s % 60)
    } else {
        format!("{} h {:02} min", s / 3600, (s % 3600) / 60)
    }
}
