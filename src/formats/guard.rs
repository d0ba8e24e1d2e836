//! The guard between a run's inputs and its outputs: no run writes over a file it reads.
//!
//! While a [`Run`] is alive (the command line opens one per command), every file a reader
//! of `formats/` opens is recorded as an input ([`input`]), and every output the command
//! names is recorded before anything is computed ([`plan_outputs`]). An output is refused —
//! one line naming both — when it is the same file as an input: the same path once links
//! are resolved (`./`, `../`, symbolic links) **or the same inode** (a hard link); an output
//! folder (a report, an export) is refused when an input lies inside it. The check runs in
//! whichever order the two meet: an input read after the outputs were planned (a model's
//! matrices, its node file, a start file) is checked as it is opened, before its bytes are
//! parsed, and every atomic write checks its destination once more ([`before_write`]), so an
//! output nobody planned cannot replace an input either.
//!
//! Outside a [`Run`] (a library caller, the Python package) nothing is recorded and only the
//! inputs and outputs named in one [`check_outputs`](crate::formats::files::check_outputs)
//! call are compared.
//!
//! Output folders are written whole ([`StagedFolder`]): into a fresh hidden sibling, renamed
//! into place when complete, under an advisory lock ([`OutputLock`]) that a second run of
//! the same folder finds held and is refused by.

use crate::error::{Error, Result};
use std::path::{Path, PathBuf};
use std::sync::Mutex;

/// A file as the guard compares it: the path as given (for messages), the path with links
/// resolved, and its device and inode where it exists.
#[derive(Debug, Clone)]
struct Seen {
    given: PathBuf,
    resolved: PathBuf,
    id: Option<(u64, u64)>,
}

impl Seen {
    fn of(p: &Path) -> Option<Seen> {
        Some(Seen {
            given: p.to_path_buf(),
            resolved: resolved(p)?,
            id: identity(p),
        })
    }

    /// Whether `self` and `other` are one file: one resolved path or one inode.
    fn same_file(&self, other: &Seen) -> bool {
        self.resolved == other.resolved || (self.id.is_some() && self.id == other.id)
    }

    /// Whether `self` lies inside the folder `dir` (at any depth).
    fn inside(&self, dir: &Seen) -> bool {
        self.resolved != dir.resolved && self.resolved.starts_with(&dir.resolved)
    }
}

/// The inputs and outputs of the runs alive in this process.
struct Ledger {
    /// Runs alive ([`Run`]); nothing is recorded at 0.
    runs: usize,
    inputs: Vec<Seen>,
    files: Vec<Seen>,
    folders: Vec<Seen>,
    /// The locks of the planned output folders, held from the start of the run to its end.
    locks: Vec<(PathBuf, OutputLock)>,
}

impl Ledger {
    /// Records the input `seen` once.
    fn record(&mut self, seen: Seen) {
        if !self.inputs.iter().any(|i| i.resolved == seen.resolved) {
            self.inputs.push(seen);
        }
    }
}

static LEDGER: Mutex<Ledger> = Mutex::new(Ledger {
    runs: 0,
    inputs: Vec::new(),
    files: Vec::new(),
    folders: Vec::new(),
    locks: Vec::new(),
});

fn ledger() -> std::sync::MutexGuard<'static, Ledger> {
    LEDGER
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// A run whose inputs and outputs the guard records (the command line opens one per
/// command). Dropping the last one alive forgets them.
#[must_use = "the guard records only while the Run is alive"]
pub struct Run(());

impl Run {
    /// Starts recording.
    pub fn begin() -> Run {
        ledger().runs += 1;
        Run(())
    }
}

impl Drop for Run {
    fn drop(&mut self) {
        let mut l = ledger();
        l.runs = l.runs.saturating_sub(1);
        if l.runs == 0 {
            l.inputs.clear();
            l.files.clear();
            l.folders.clear();
            l.locks.clear();
        }
    }
}

/// `(device, inode)` of the file `p` names (links followed), where it exists.
#[cfg(unix)]
fn identity(p: &Path) -> Option<(u64, u64)> {
    use std::os::unix::fs::MetadataExt as _;
    std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()))
}

#[cfg(not(unix))]
fn identity(_p: &Path) -> Option<(u64, u64)> {
    None
}

/// The path `p` names after resolving links: the file itself when it exists, else its
/// resolved folder joined with its name (`None` when the folder does not exist either).
pub(crate) fn resolved(p: &Path) -> Option<PathBuf> {
    if let Ok(c) = std::fs::canonicalize(p) {
        return Some(c);
    }
    let name = p.file_name()?;
    let parent = match p.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::canonicalize(parent).ok().map(|d| d.join(name))
}

fn how(out: &Seen, input: &Seen) -> &'static str {
    if out.resolved == input.resolved {
        ""
    } else {
        " (the same file through a hard link)"
    }
}

fn file_over_input(out: &Seen, input: &Seen) -> Error {
    Error::Usage(format!(
        "{}: is the input {}{}; writing there would replace it — name another output",
        out.given.display(),
        input.given.display(),
        how(out, input)
    ))
}

fn folder_over_input(dir: &Seen, input: &Seen) -> Error {
    Error::Usage(format!(
        "{}: holds the input {}; the folder is written whole and would replace it — name \
         another folder",
        dir.given.display(),
        input.given.display()
    ))
}

/// The first conflict between `inputs` and the outputs `files` and `folders`.
fn conflict(inputs: &[Seen], files: &[Seen], folders: &[Seen]) -> Option<Error> {
    for i in inputs {
        if let Some(o) = files.iter().find(|o| o.same_file(i)) {
            return Some(file_over_input(o, i));
        }
        if let Some(d) = folders.iter().find(|d| d.same_file(i) || i.inside(d)) {
            return Some(folder_over_input(d, i));
        }
    }
    None
}

/// Records `path` as an input of the runs alive, refusing it when an output already planned
/// would replace it. A no-op outside a [`Run`] and for a path that does not exist.
pub fn input(path: &Path) -> Result<()> {
    let mut l = ledger();
    if l.runs == 0 {
        return Ok(());
    }
    let Some(seen) = Seen::of(path).filter(|s| s.id.is_some() || cfg!(not(unix))) else {
        return Ok(());
    };
    if let Some(e) = conflict(std::slice::from_ref(&seen), &l.files, &l.folders) {
        return Err(e);
    }
    l.record(seen);
    Ok(())
}

/// Records `files` and `folders` as outputs of the runs alive after checking them against
/// `inputs` and every input recorded so far: refused when one is the same file as an input
/// or a folder holds one. Outside a [`Run`] only `inputs` are compared.
pub fn plan_outputs(inputs: &[&Path], files: &[&Path], folders: &[&Path]) -> Result<()> {
    let seen = |v: &[&Path]| -> Vec<Seen> { v.iter().filter_map(|p| Seen::of(p)).collect() };
    let named: Vec<Seen> = inputs
        .iter()
        .filter(|p| p.exists())
        .filter_map(|p| Seen::of(p))
        .collect();
    let (files, folders) = (seen(files), seen(folders));
    let mut l = ledger();
    let recorded = if l.runs == 0 { &[][..] } else { &l.inputs[..] };
    if let Some(e) =
        conflict(&named, &files, &folders).or_else(|| conflict(recorded, &files, &folders))
    {
        return Err(e);
    }
    for d in &folders {
        folder_check(&d.given)?;
    }
    if l.runs > 0 {
        // Each folder's lock from now to the end of the run: a second run of the same
        // folder is refused at its start, not after its computation.
        for d in &folders {
            if !l.locks.iter().any(|(p, _)| *p == d.resolved) {
                let lock = OutputLock::acquire(&d.given)?;
                l.locks.push((d.resolved.clone(), lock));
            }
        }
        for i in named {
            l.record(i);
        }
        l.files.extend(files);
        l.folders.extend(folders);
    }
    Ok(())
}

/// Writes the output folder `target` whole ([`StagedFolder`]): `write` fills the staging
/// folder it is given, and the folder is renamed into place when `write` returns `Ok`. The
/// value `write` returns is passed on; paths in it name the staging folder
/// ([`StagedFolder::final_path`] names them as committed).
pub fn write_folder<T>(target: &Path, write: impl FnOnce(&Path) -> Result<T>) -> Result<T> {
    let staged = StagedFolder::begin(target)?;
    let value = write(staged.path()).map_err(|e| staged.named_finally(e))?;
    staged.commit(&command_line())?;
    Ok(value)
}

/// The command line of this process, as the manifest of a folder records it.
fn command_line() -> String {
    std::env::args().collect::<Vec<_>>().join(" ")
}

/// Checks a folder output before anything is written: not a file nor a symbolic link, and
/// if it exists, written by nlsim ([`MANIFEST`]) or empty — any other folder would be
/// replaced whole with what the user keeps in it.
pub fn folder_check(target: &Path) -> Result<()> {
    let usage = |m: String| Err(Error::Usage(m));
    let Ok(meta) = std::fs::symlink_metadata(target) else {
        return Ok(());
    };
    if meta.file_type().is_symlink() {
        return usage(format!(
            "{}: is a symbolic link; the folder is written whole and would replace the link \
             — name the folder itself",
            target.display()
        ));
    }
    if !meta.is_dir() {
        return usage(format!(
            "{}: is a file; the output is a folder, name another",
            target.display()
        ));
    }
    let mut entries = std::fs::read_dir(target).map_err(|source| Error::Io {
        path: target.to_path_buf(),
        source,
    })?;
    if !target.join(MANIFEST).is_file() && entries.next().is_some() {
        return usage(format!(
            "{}: exists and holds files nlsim did not write (no {MANIFEST} in it); the \
             folder is written whole and would replace them — name a new or empty folder",
            target.display()
        ));
    }
    Ok(())
}

/// Refuses to write `path` when it is an input of the runs alive (the last check of every
/// atomic write, for outputs no command planned). A no-op outside a [`Run`].
pub fn before_write(path: &Path) -> Result<()> {
    let l = ledger();
    if l.runs == 0 {
        return Ok(());
    }
    let Some(out) = Seen::of(path) else {
        return Ok(());
    };
    match l.inputs.iter().find(|i| out.same_file(i)) {
        Some(i) => Err(file_over_input(&out, i)),
        None => Ok(()),
    }
}

/// An advisory lock on an output (a report or export folder, a batch shard): the lock file
/// `.NAME.lock` beside it, held (`flock`) while the run writes and removed when the lock is
/// released. A second run that finds it held is refused in one line; a lock file left by a
/// killed run is not held and is taken over.
#[derive(Debug)]
pub struct OutputLock {
    path: PathBuf,
    file: Option<std::fs::File>,
    _registered: crate::formats::interrupt::Temporary,
}

impl OutputLock {
    /// The lock file's path for `output`.
    pub fn path_for(output: &Path) -> PathBuf {
        let name = output
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default();
        output.with_file_name(format!(".{name}.lock"))
    }

    /// Takes the lock of `output` or says which run holds it (the output's folder is
    /// created if missing).
    pub fn acquire(output: &Path) -> Result<OutputLock> {
        let path = Self::path_for(output);
        if let Some(dir) = path
            .parent()
            .filter(|d| !d.as_os_str().is_empty() && !d.exists())
        {
            std::fs::create_dir_all(dir).map_err(|source| Error::Io {
                path: dir.to_path_buf(),
                source,
            })?;
        }
        let io = |source| Error::Io {
            path: path.clone(),
            source,
        };
        // A lock file removed by its owner between our open and our lock would leave us
        // holding a lock nobody else sees: take it again on the file now under the name.
        for _ in 0..16 {
            let file = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create(true)
                .truncate(false)
                .open(&path)
                .map_err(io)?;
            match file.try_lock() {
                Ok(()) => {}
                Err(std::fs::TryLockError::WouldBlock) => {
                    let holder = std::fs::read_to_string(&path).unwrap_or_default();
                    return Err(Error::Usage(format!(
                        "{}: another nlsim run is writing it{} (lock {} held); wait for it \
                         to end or name another output",
                        output.display(),
                        match holder.trim() {
                            "" => String::new(),
                            h => format!(" (process {h})"),
                        },
                        path.display()
                    )));
                }
                Err(std::fs::TryLockError::Error(e)) => return Err(io(e)),
            }
            #[cfg(unix)]
            {
                use std::os::unix::fs::MetadataExt as _;
                let held = file.metadata().map_err(io)?;
                let named = std::fs::metadata(&path).ok();
                if named.is_none_or(|m| (m.dev(), m.ino()) != (held.dev(), held.ino())) {
                    continue;
                }
            }
            {
                use std::io::Write as _;
                let mut f = &file;
                let _ = f.set_len(0);
                let _ = write!(f, "{}", std::process::id());
            }
            return Ok(OutputLock {
                _registered: crate::formats::interrupt::Temporary::new(&path),
                path,
                file: Some(file),
            });
        }
        Err(Error::Usage(format!(
            "{}: its lock {} keeps changing hands; try again",
            output.display(),
            path.display()
        )))
    }
}

impl Drop for OutputLock {
    fn drop(&mut self) {
        // Removed while still held, so that no other run takes the name meanwhile.
        let _ = std::fs::remove_file(&self.path);
        drop(self.file.take());
    }
}

/// The marker that says a folder is a complete output of nlsim (the command line that wrote
/// it); written last into a staged folder.
pub const MANIFEST: &str = ".nlsim-report";

/// An output folder written whole: the run writes into a fresh hidden sibling
/// (`.NAME.tmp-PID`), and [`StagedFolder::commit`] renames it into place, so that the final
/// name holds a previous complete folder or the new complete one, never a mix or a partial
/// one. A folder that already exists is replaced only when nlsim wrote it (it holds
/// [`MANIFEST`]) or it is empty; any other folder is refused at [`StagedFolder::begin`],
/// before anything is computed. Dropped without a commit (an error, an interrupt), the
/// staging folder is removed and the final name keeps what it held.
#[derive(Debug)]
pub struct StagedFolder {
    target: PathBuf,
    staging: PathBuf,
    committed: bool,
    _registered: crate::formats::interrupt::Temporary,
    _lock: Option<OutputLock>,
}

impl StagedFolder {
    /// Checks `target` (not a file, an nlsim folder or empty if it exists, its parent
    /// writable), takes its lock, removes staging folders left by killed runs of it, and
    /// creates a fresh staging folder.
    pub fn begin(target: &Path) -> Result<StagedFolder> {
        let usage = |m: String| Error::Usage(m);
        folder_check(target)?;
        let parent = match target.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        std::fs::create_dir_all(&parent).map_err(|source| Error::Io {
            path: parent.clone(),
            source,
        })?;
        // The run's own lock when it planned this folder, else one taken now.
        let held = resolved(target).is_some_and(|r| ledger().locks.iter().any(|(p, _)| *p == r));
        let lock = if held {
            None
        } else {
            Some(OutputLock::acquire(target)?)
        };
        let name = target
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .ok_or_else(|| usage(format!("{}: names no folder", target.display())))?;
        // Staging folders of this target whose runs are gone: with the lock held, any.
        let prefix = format!(".{name}.tmp-");
        if let Ok(rd) = std::fs::read_dir(&parent) {
            for e in rd.flatten() {
                if e.file_name().to_string_lossy().starts_with(&prefix) {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
        let staging = parent.join(format!("{prefix}{}", std::process::id()));
        std::fs::create_dir(&staging).map_err(|source| Error::Io {
            path: target.to_path_buf(),
            source,
        })?;
        Ok(StagedFolder {
            target: target.to_path_buf(),
            _registered: crate::formats::interrupt::Temporary::new(&staging),
            staging,
            committed: false,
            _lock: lock,
        })
    }

    /// Where the run writes its files until [`StagedFolder::commit`].
    pub fn path(&self) -> &Path {
        &self.staging
    }

    /// The final folder.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// `e` with the paths inside the staging folder named as they will be once committed:
    /// a message names the file the user asked for, not the hidden staging folder.
    pub fn named_finally(&self, e: Error) -> Error {
        let staging = self.staging.to_string_lossy().into_owned();
        let target = self.target.to_string_lossy().into_owned();
        match e {
            Error::Io { path, source } => Error::Io {
                path: self.final_path(&path),
                source,
            },
            Error::Hdf5 { path, message } => Error::Hdf5 {
                path: self.final_path(&path),
                message: message.replace(&staging, &target),
            },
            e => e,
        }
    }

    /// `p` (a path inside the staging folder) as it will be named once committed.
    pub fn final_path(&self, p: &Path) -> PathBuf {
        match p.strip_prefix(&self.staging) {
            Ok(rest) => self.target.join(rest),
            Err(_) => p.to_path_buf(),
        }
    }

    /// Writes [`MANIFEST`] (`manifest`: the command line), flushes the folder, and renames it
    /// into place; an older folder under the name is moved aside first and removed after.
    pub fn commit(mut self, manifest: &str) -> Result<PathBuf> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| Error::Io { path, source }
        };
        // The staging folder is private to this run and is committed whole below, so the
        // manifest needs no temporary of its own: written and flushed in place.
        let manifest_path = self.staging.join(MANIFEST);
        std::fs::File::create(&manifest_path)
            .and_then(|mut f| {
                std::io::Write::write_all(&mut f, format!("{manifest}\n").as_bytes())?;
                f.sync_all()
            })
            .map_err(io(&manifest_path))?;
        let _ = std::fs::File::open(&self.staging).and_then(|d| d.sync_all());
        let old = self.staging.with_file_name(format!(
            "{}.old",
            self.staging
                .file_name()
                .unwrap_or_default()
                .to_string_lossy()
        ));
        let had_old = self.target.exists();
        if had_old && exchange(&self.staging, &self.target) {
            // One step: the target names the new folder, the staging name the old one.
            self.committed = true;
            let _ = std::fs::remove_dir_all(&self.staging);
        } else {
            if had_old {
                std::fs::rename(&self.target, &old).map_err(io(&self.target))?;
            }
            if let Err(e) = std::fs::rename(&self.staging, &self.target) {
                if had_old {
                    let _ = std::fs::rename(&old, &self.target);
                }
                return Err(io(&self.target)(e));
            }
            self.committed = true;
        }
        if let Some(parent) = self.target.parent().filter(|d| !d.as_os_str().is_empty()) {
            let _ = std::fs::File::open(parent).and_then(|d| d.sync_all());
        }
        if had_old {
            let _ = std::fs::remove_dir_all(&old);
        }
        Ok(self.target.clone())
    }
}

/// Swaps the names `a` and `b` in one step (Linux `renameat2` with `RENAME_EXCHANGE`), so
/// that no moment passes with neither folder under `b`; `false` where the system or the file
/// system cannot (the caller then renames in two steps).
#[cfg(target_os = "linux")]
fn exchange(a: &Path, b: &Path) -> bool {
    use std::os::unix::ffi::OsStrExt as _;
    let (Ok(a), Ok(b)) = (
        std::ffi::CString::new(a.as_os_str().as_bytes()),
        std::ffi::CString::new(b.as_os_str().as_bytes()),
    ) else {
        return false;
    };
    // SAFETY: both paths are NUL-terminated C strings that live across the call; the call
    // reads them and touches no memory of ours.
    #[allow(unsafe_code)]
    let rc = unsafe {
        libc::renameat2(
            libc::AT_FDCWD,
            a.as_ptr(),
            libc::AT_FDCWD,
            b.as_ptr(),
            libc::RENAME_EXCHANGE,
        )
    };
    rc == 0
}

#[cfg(not(target_os = "linux"))]
fn exchange(_a: &Path, _b: &Path) -> bool {
    false
}

impl Drop for StagedFolder {
    fn drop(&mut self) {
        if !self.committed {
            let _ = std::fs::remove_dir_all(&self.staging);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("nlsim-guard-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn an_output_over_an_input_is_refused_by_path_link_and_inode() {
        let d = scratch("inode");
        let data = d.join("data.csv");
        std::fs::write(&data, "x\n").unwrap();
        std::fs::hard_link(&data, d.join("hard.csv")).unwrap();
        std::os::unix::fs::symlink(&data, d.join("soft.csv")).unwrap();
        std::fs::create_dir(d.join("sub")).unwrap();
        let spellings = [
            data.clone(),
            d.join("sub/../data.csv"),
            d.join("./data.csv"),
            d.join("soft.csv"),
            d.join("hard.csv"),
        ];
        for out in &spellings {
            let e = plan_outputs(&[&data], &[out], &[]).unwrap_err().to_string();
            assert!(e.contains("is the input"), "{out:?}: {e}");
        }
        // Inside a run, the input recorded first and the output planned later, and the
        // other order; and an output folder that holds the input.
        let run = Run::begin();
        input(&data).unwrap();
        let e = plan_outputs(&[], &[&d.join("hard.csv")], &[]).unwrap_err();
        assert!(e.to_string().contains("hard link"), "{e}");
        let e = plan_outputs(&[], &[], &[&d]).unwrap_err();
        assert!(e.to_string().contains("holds the input"), "{e}");
        assert!(before_write(&d.join("soft.csv")).is_err());
        drop(run);
        let run = Run::begin();
        plan_outputs(&[], &[&d.join("hard.csv")], &[]).unwrap();
        assert!(input(&data).is_err());
        drop(run);
        assert!(
            before_write(&data).is_ok(),
            "outside a run nothing is recorded"
        );
        assert_eq!(std::fs::read_to_string(&data).unwrap(), "x\n");
        let _ = std::fs::remove_dir_all(&d);
    }

    #[test]
    fn a_staged_folder_appears_whole_or_not_at_all() {
        let d = scratch("staged");
        let target = d.join("rep");
        let s = StagedFolder::begin(&target).unwrap();
        std::fs::write(s.path().join("a.csv"), "1").unwrap();
        assert!(
            !target.exists(),
            "nothing under the final name before the commit"
        );
        // A second run of the same folder meanwhile is refused.
        let e = StagedFolder::begin(&target).unwrap_err().to_string();
        assert!(e.contains("another nlsim run"), "{e}");
        s.commit("test").unwrap();
        assert_eq!(std::fs::read_to_string(target.join("a.csv")).unwrap(), "1");
        // A run that fails leaves the older folder as it was, and no staging folder.
        let s = StagedFolder::begin(&target).unwrap();
        std::fs::write(s.path().join("b.csv"), "2").unwrap();
        drop(s);
        assert!(target.join("a.csv").exists() && !target.join("b.csv").exists());
        let left: Vec<_> = std::fs::read_dir(&d)
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(left, vec![std::ffi::OsString::from("rep")], "{left:?}");
        // A folder nlsim did not write is refused before anything is written.
        let mine = d.join("mine");
        std::fs::create_dir(&mine).unwrap();
        std::fs::write(mine.join("notes.txt"), "keep").unwrap();
        let e = StagedFolder::begin(&mine).unwrap_err().to_string();
        assert!(e.contains("did not write"), "{e}");
        assert_eq!(
            std::fs::read_to_string(mine.join("notes.txt")).unwrap(),
            "keep"
        );
        let _ = std::fs::remove_dir_all(&d);
    }
}
