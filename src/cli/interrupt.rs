//! Ctrl-C (SIGINT) and SIGTERM in the command line: the handler only counts the signal
//! ([`crate::formats::interrupt::note_signal`]); a watcher thread acts on it. While a
//! command runs between safe points (a calibration, [`crate::formats::interrupt::SafePoints`])
//! the first signal asks it to stop at the next one and write what was complete; otherwise,
//! or at a second signal, the watcher removes the run's temporaries and ends the process at
//! once with exit code 128 + the signal's number (130 for Ctrl-C). Nothing partial is left
//! under a final name either way: outputs are written under temporary names and renamed
//! whole (docs/file-formats.md).

use crate::formats::interrupt;
use std::time::Duration;

/// How often the watcher looks at the signal count: the delay between a signal and an
/// immediate stop.
const POLL: Duration = Duration::from_millis(20);

/// Installs the handler for SIGINT and SIGTERM and starts the watcher thread. Called once,
/// by the binary, before the command runs.
pub fn install() {
    #[cfg(unix)]
    {
        extern "C" fn on_signal(signal: libc::c_int) {
            interrupt::note_signal(signal);
        }
        for signal in [libc::SIGINT, libc::SIGTERM] {
            // SAFETY: `sigaction` is given a zeroed, then filled, struct that lives across
            // the call; the handler only touches atomics (async-signal-safe).
            #[allow(unsafe_code)]
            unsafe {
                let mut action: libc::sigaction = std::mem::zeroed();
                action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as usize;
                action.sa_flags = libc::SA_RESTART;
                libc::sigemptyset(&mut action.sa_mask);
                libc::sigaction(signal, &action, std::ptr::null_mut());
            }
        }
        let _ = std::thread::Builder::new()
            .name("nlsim-signals".into())
            .spawn(watch);
    }
}

/// Called by the binary when the command returned: while the watcher is ending the
/// process at once, the command's outcome (often an error about a temporary removed under
/// it) is not reported; this waits for the watcher's exit instead.
pub fn settle() {
    while interrupt::ending() {
        std::thread::sleep(POLL);
    }
}

/// The watcher: says once that the command will stop at its next safe point, and ends the
/// process at once when the command has none or a second signal came.
#[cfg(unix)]
fn watch() {
    // When the first signal was seen; the notice waits a second, so that a command that
    // reaches its safe point quickly prints only its own line of what it kept.
    let mut seen: Option<std::time::Instant> = None;
    let mut told = false;
    loop {
        std::thread::sleep(POLL);
        let n = interrupt::signals();
        if n == 0 {
            continue;
        }
        let since = *seen.get_or_insert_with(std::time::Instant::now);
        if n >= 2 || !interrupt::at_safe_points() {
            let removed = interrupt::abandon();
            let signal = interrupt::last_signal();
            eprintln!(
                "interrupted ({}): stopped at once; no partial file left under a final name{}",
                signal_name(signal),
                if removed > 0 {
                    format!(" ({removed} temporary files removed)")
                } else {
                    String::new()
                }
            );
            // SAFETY: ends the process without running exit handlers, which could flush
            // half-written files the command still holds; nothing of ours is touched.
            #[allow(unsafe_code)]
            unsafe {
                libc::_exit(128 + signal.clamp(1, 64))
            };
        }
        if !told && since.elapsed() >= Duration::from_secs(1) {
            told = true;
            eprintln!(
                "interrupted ({}): stopping at the next safe point to keep what was computed \
                 (interrupt again to stop at once)",
                signal_name(interrupt::last_signal())
            );
        }
    }
}

/// `SIGINT`, `SIGTERM` or the number.
fn signal_name(signal: i32) -> String {
    match signal {
        2 => "SIGINT".into(),
        15 => "SIGTERM".into(),
        s => format!("signal {s}"),
    }
}
