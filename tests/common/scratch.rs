//! A scratch directory per test, shared by the test crates of the workspace (included with
//! `#[path]`): removed when the test passes, kept (and named) when it fails.

use std::path::{Path, PathBuf};

/// A directory `nlsim-<name>-<pid>` under the system's temporary directory, created on
/// [`Scratch::new`] and removed on drop unless the test is panicking; a failing test's files
/// stay for inspection, and their path is printed with the failure.
pub struct Scratch(PathBuf);

impl Scratch {
    /// Creates (if needed) the scratch directory `name` of this process.
    pub fn new(name: &str) -> Scratch {
        let d = std::env::temp_dir().join(format!("nlsim-{name}-{}", std::process::id()));
        std::fs::create_dir_all(&d)
            .unwrap_or_else(|e| panic!("scratch directory {}: {e}", d.display()));
        Scratch(d)
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("scratch directory kept: {}", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}
