//! Interrupts as a run sees them: how many stop signals (SIGINT, SIGTERM) arrived, whether
//! the command is between safe points, and the temporaries to remove when the process stops
//! at once. The command line installs the signal handler (`cli::interrupt`); this module
//! holds only what the handler and the commands share, so that nothing below the command
//! line reads a signal: a command asks [`requested`] at its safe points, and a write
//! registers its temporary file or folder ([`Temporary`]) while it exists.
//!
//! The rule (docs/file-formats.md, "What a run never does to your files"): a command that
//! has safe points (a calibration) stops at the next one on the first signal and writes what
//! was complete; any other command, or a second signal, stops at once: the temporaries are
//! removed and nothing partial is left under a final name. Outside the command line (a
//! library caller, Python) nothing here is ever set and [`requested`] stays `false`.

use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicI32, AtomicUsize, Ordering};

/// Stop signals received so far.
static SIGNALS: AtomicUsize = AtomicUsize::new(0);
/// The number of the last stop signal received (2 for SIGINT, 15 for SIGTERM).
static LAST_SIGNAL: AtomicI32 = AtomicI32::new(0);
/// How many [`SafePoints`] are open: while one is, the first signal waits for a safe point.
static SAFE: AtomicUsize = AtomicUsize::new(0);
/// Set when the process is being ended at once ([`abandon`]).
static ENDING: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
/// The temporaries that exist now; `None` once [`abandon`] removed them (the process is
/// ending).
static TEMPORARIES: Mutex<Option<Vec<PathBuf>>> = Mutex::new(Some(Vec::new()));

/// Records a stop signal `signal`. Only atomics: safe to call from a signal handler.
pub fn note_signal(signal: i32) {
    LAST_SIGNAL.store(signal, Ordering::SeqCst);
    SIGNALS.fetch_add(1, Ordering::SeqCst);
}

/// Stop signals received so far.
pub fn signals() -> usize {
    SIGNALS.load(Ordering::SeqCst)
}

/// The last stop signal's number (0 before any).
pub fn last_signal() -> i32 {
    LAST_SIGNAL.load(Ordering::SeqCst)
}

/// `true` once a stop signal arrived: a command stops at its next safe point.
pub fn requested() -> bool {
    signals() > 0
}

/// `true` while a command runs between safe points ([`SafePoints`]).
pub fn at_safe_points() -> bool {
    SAFE.load(Ordering::SeqCst) > 0
}

/// While alive, the first stop signal is left to the command's safe points instead of
/// ending the process at once.
#[derive(Debug)]
pub struct SafePoints(());

impl SafePoints {
    /// Opens a stretch of work with safe points.
    pub fn begin() -> SafePoints {
        SAFE.fetch_add(1, Ordering::SeqCst);
        SafePoints(())
    }
}

impl SafePoints {
    /// Keeps the first signal with the command until the process ends: for a command that
    /// stopped at a safe point and returns to say what it kept, so that the message is not
    /// cut short by the stop-at-once rule.
    pub fn hold_to_exit(self) {
        std::mem::forget(self);
    }
}

impl Drop for SafePoints {
    fn drop(&mut self) {
        SAFE.fetch_sub(1, Ordering::SeqCst);
    }
}

/// A temporary file or folder, registered while it exists so that a process stopped at
/// once removes it ([`abandon`]). Dropped (written and renamed, or removed), it is
/// unregistered; its owner removes it as usual.
#[derive(Debug)]
pub struct Temporary(PathBuf);

impl Temporary {
    /// Registers `path` (a file, or a folder removed with its contents).
    pub fn new(path: &Path) -> Temporary {
        if let Some(list) = lock().as_mut() {
            list.push(path.to_path_buf());
        }
        Temporary(path.to_path_buf())
    }
}

impl Drop for Temporary {
    fn drop(&mut self) {
        if let Some(list) = lock().as_mut()
            && let Some(i) = list.iter().rposition(|p| *p == self.0)
        {
            list.swap_remove(i);
        }
    }
}

fn lock() -> std::sync::MutexGuard<'static, Option<Vec<PathBuf>>> {
    TEMPORARIES
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Removes every registered temporary and keeps the register closed, for a process about
/// to end at once: a write that starts later registers nothing, and one that ends later
/// finds its temporary gone. Returns how many were removed. (A temporary created in the
/// instant between its registration and this call may survive; the next run of the same
/// output removes it, its process being gone.)
pub fn abandon() -> usize {
    ENDING.store(true, Ordering::SeqCst);
    let mut guard = lock();
    let list = guard.take().unwrap_or_default();
    drop(guard);
    let mut removed = 0;
    for p in list {
        let gone = if p.is_dir() {
            remove_folder(&p)
        } else {
            std::fs::remove_file(&p)
        };
        removed += usize::from(gone.is_ok());
    }
    removed
}

/// `true` once [`abandon`] began: the process is being ended at once, and an error the
/// command meets now (a file removed under it) is a consequence, not news.
pub fn ending() -> bool {
    ENDING.load(Ordering::SeqCst)
}

/// Removes a staging folder that another thread may still be writing into: renamed first,
/// so that no file is created under its path any more, then removed (again while a file
/// opened before the rename still appears in it).
fn remove_folder(p: &Path) -> std::io::Result<()> {
    let mut name = p.as_os_str().to_os_string();
    name.push(".abandoned");
    let gone = PathBuf::from(name);
    let target = if std::fs::rename(p, &gone).is_ok() {
        gone
    } else {
        p.to_path_buf()
    };
    let mut last = Ok(());
    for _ in 0..20 {
        last = std::fs::remove_dir_all(&target);
        if last.is_ok() || !target.exists() {
            return Ok(());
        }
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
    last
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn abandon_removes_registered_files_and_folders_only() {
        let dir = std::env::temp_dir().join(format!("nlsim-interrupt-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("staged")).unwrap();
        std::fs::write(dir.join("staged/a.csv"), "1").unwrap();
        std::fs::write(dir.join("f.tmp"), "1").unwrap();
        std::fs::write(dir.join("done.tmp"), "1").unwrap();
        std::fs::write(dir.join("keep.csv"), "1").unwrap();
        let _a = Temporary::new(&dir.join("staged"));
        let _b = Temporary::new(&dir.join("f.tmp"));
        drop(Temporary::new(&dir.join("done.tmp")));
        assert_eq!(abandon(), 2);
        assert!(!dir.join("staged").exists() && !dir.join("f.tmp").exists());
        assert!(dir.join("done.tmp").exists() && dir.join("keep.csv").exists());
        // Closed: later registrations are not kept.
        let _c = Temporary::new(&dir.join("keep.csv"));
        assert_eq!(abandon(), 0);
        assert!(dir.join("keep.csv").exists());
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
