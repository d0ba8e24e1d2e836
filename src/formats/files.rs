//! What every result writer shares: the format chosen by the file extension, and atomic
//! writes (a temporary file beside the destination, renamed into place when complete, so a
//! failed or killed run leaves no partial file and an existing one untouched).

use crate::error::{Error, Result};
#[cfg(feature = "hdf5")]
use hdf5_metno as hdf5;
use std::path::{Path, PathBuf};

/// Result file format, from the extension.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Format {
    /// `.csv`
    Csv,
    /// `.h5` or `.hdf5`
    Hdf5,
    /// `.uff` or `.unv`: universal file datasets 58 (where the command writes them)
    Uff,
}

impl Format {
    /// The format of `path` among CSV and HDF5, or a usage error naming it with `hint` (what
    /// each format holds).
    pub fn of(path: &Path, hint: &str) -> Result<Self> {
        Self::of_any(path, hint, false)
    }

    /// [`Format::of`], universal files too when `uff` (the commands that write them).
    pub fn of_any(path: &Path, hint: &str, uff: bool) -> Result<Self> {
        match path
            .extension()
            .and_then(|e| e.to_str())
            .map(str::to_ascii_lowercase)
            .as_deref()
        {
            Some("csv") => Ok(Format::Csv),
            Some("h5" | "hdf5") => Ok(Format::Hdf5),
            Some("uff" | "unv") if uff => Ok(Format::Uff),
            _ => Err(Error::Usage(format!(
                "{}: unknown output format; name the file {hint}",
                path.display()
            ))),
        }
    }
}

/// Writes `path` through `write(temporary path, format)`, flushes it to the disk and
/// renames it into place, so that the final name never holds a partial file, even after a
/// crash of the machine; the temporary file is removed on failure, and those of killed runs
/// of the same destination first.
pub fn write_atomically(
    path: &Path,
    hint: &str,
    write: impl FnOnce(&Path, Format) -> Result<()>,
) -> Result<()> {
    let format = Format::of(path, hint)?;
    replace_atomically(path, |tmp| write(tmp, format))
}

/// [`write_atomically`] for a command that also writes universal files.
pub fn write_atomically_uff(
    path: &Path,
    hint: &str,
    write: impl FnOnce(&Path, Format) -> Result<()>,
) -> Result<()> {
    let format = Format::of_any(path, hint, true)?;
    replace_atomically(path, |tmp| write(tmp, format))
}

/// Writes `text` to `path` the way [`write_atomically`] writes a result.
pub fn write_text_atomically(path: &Path, text: &str) -> Result<()> {
    write_bytes_atomically(path, text.as_bytes())
}

/// Writes `bytes` to `path` the way [`write_atomically`] writes a result.
pub fn write_bytes_atomically(path: &Path, bytes: &[u8]) -> Result<()> {
    replace_atomically(path, |tmp| {
        std::fs::write(tmp, bytes).map_err(|source| Error::Io {
            path: tmp.to_path_buf(),
            source,
        })
    })
}

/// Writes `path` through `write(temporary path)`, flushes the temporary file to the disk
/// and renames it into place, so that the final name never holds a partial file, even after
/// a crash of the machine (a killed run or a full disk leaves the previous file, or none);
/// the temporary file is removed on failure. Temporary files of the same destination left
/// by runs that no longer exist are removed first.
pub fn replace_atomically(path: &Path, write: impl FnOnce(&Path) -> Result<()>) -> Result<()> {
    crate::formats::guard::before_write(path)?;
    remove_temporaries(path, true);
    let tmp = temp_path(path);
    let _registered = crate::formats::interrupt::Temporary::new(&tmp);
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    let written = write(&tmp).and_then(|()| {
        std::fs::File::open(&tmp)
            .and_then(|f| f.sync_all())
            .map_err(io)
    });
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        // The message names the file the user asked for, not the temporary one.
        return Err(match e {
            Error::Io { path: p, source } if p == tmp => Error::Io {
                path: path.to_path_buf(),
                source,
            },
            Error::Hdf5 { path: p, message } if p == tmp => Error::Hdf5 {
                path: path.to_path_buf(),
                message: message.replace(
                    tmp.to_string_lossy().as_ref(),
                    path.to_string_lossy().as_ref(),
                ),
            },
            e => e,
        });
    }
    if let Err(e) = std::fs::rename(&tmp, path) {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(e));
    }
    // The rename itself reaches the disk with the folder's entry.
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        let _ = std::fs::File::open(dir).and_then(|d| d.sync_all());
    }
    Ok(())
}

/// Removes the `NAME.tmp-PID` files beside `path` ([`temp_path`]): with `orphans_only`,
/// those whose process `PID` no longer runs (where `/proc` tells; nothing otherwise), so
/// that a concurrent run's file is kept; else all of them (a batch shard, which one task
/// owns at a time). Returns what was removed.
pub fn remove_temporaries(path: &Path, orphans_only: bool) -> Vec<PathBuf> {
    let mut removed = Vec::new();
    if orphans_only && !Path::new("/proc/self").exists() {
        return removed;
    }
    let Some(name) = path.file_name().and_then(|n| n.to_str()) else {
        return removed;
    };
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    };
    let prefix = format!("{name}.tmp-");
    let Ok(rd) = std::fs::read_dir(&dir) else {
        return removed;
    };
    for e in rd.flatten() {
        let file = e.file_name();
        let Some(suffix) = file.to_str().and_then(|n| n.strip_prefix(&prefix)) else {
            continue;
        };
        let orphan = || {
            suffix
                .parse::<u32>()
                .is_ok_and(|pid| !Path::new("/proc").join(pid.to_string()).exists())
        };
        if (!orphans_only || orphan()) && std::fs::remove_file(e.path()).is_ok() {
            removed.push(e.path());
        }
    }
    removed
}

/// Checks a run's outputs before anything is computed or written: no output (a result
/// file in `files`, a report or export folder in `folders`) is one of the run's `inputs` or
/// of the inputs the run has read so far (through [`crate::formats::guard`]: the same path
/// after resolving links, or the same inode — a hard link), no folder holds an input, and no
/// two outputs are one file; a result file is not an existing folder nor a symbolic link
/// (the atomic rename would replace the link, not its target); a report folder is not an
/// existing file. `None` entries (an option not given) and inputs that do not exist (a
/// built-in model's name) are skipped. Inside a [`crate::formats::guard::Run`] the outputs
/// are recorded, so that an input read later is checked against them as it is opened.
pub fn check_outputs(
    inputs: &[Option<&Path>],
    files: &[Option<&Path>],
    folders: &[Option<&Path>],
) -> Result<()> {
    let usage = |m: String| Err(Error::Usage(m));
    let given = |v: &[Option<&Path>]| -> Vec<PathBuf> {
        v.iter().flatten().map(|p| p.to_path_buf()).collect()
    };
    let (inputs, files, folders) = (given(inputs), given(files), given(folders));
    for f in &files {
        if let Ok(meta) = std::fs::symlink_metadata(f) {
            if meta.is_dir() {
                return usage(format!(
                    "{}: is a folder; name the file to write",
                    f.display()
                ));
            }
            if meta.file_type().is_symlink() {
                let target = std::fs::read_link(f)
                    .map(|t| t.display().to_string())
                    .unwrap_or_default();
                let into_dir = std::fs::metadata(f).is_ok_and(|m| m.is_dir());
                return usage(format!(
                    "{}: is a symbolic link to {target}{}; writing would replace the link, \
                     not its target: name the target itself or remove the link",
                    f.display(),
                    if into_dir { " (a folder)" } else { "" }
                ));
            }
        }
    }
    for f in &files {
        writable_folder(f)?;
    }
    for d in &folders {
        if std::fs::metadata(d).is_ok_and(|m| !m.is_dir()) {
            return usage(format!(
                "{}: is a file; the report is a folder, name another",
                d.display()
            ));
        }
    }
    let mut outs: Vec<(PathBuf, &PathBuf)> = Vec::new();
    for o in files.iter().chain(&folders) {
        let Some(r) = crate::formats::guard::resolved(o) else {
            continue;
        };
        if let Some((_, other)) = outs
            .iter()
            .find(|(ro, _)| *ro == r || r.starts_with(ro) || ro.starts_with(&r))
        {
            return usage(format!(
                "{} and {} are the same file or one holds the other; name two outputs",
                other.display(),
                o.display()
            ));
        }
        outs.push((r, o));
    }
    fn as_paths(v: &[PathBuf]) -> Vec<&Path> {
        v.iter().map(PathBuf::as_path).collect()
    }
    crate::formats::guard::plan_outputs(&as_paths(&inputs), &as_paths(&files), &as_paths(&folders))
}

/// Refuses, before anything is computed, an output file whose folder does not exist or
/// cannot be written (a file is created there and removed again, the honest test of both).
pub fn writable_folder(out: &Path) -> Result<()> {
    let dir = match out.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if !dir.is_dir() {
        return Err(Error::Usage(format!(
            "{}: the folder {} does not exist; create it first or name another output",
            out.display(),
            dir.display()
        )));
    }
    let probe = temp_path(out);
    let _registered = crate::formats::interrupt::Temporary::new(&probe);
    match std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .open(&probe)
    {
        Ok(_) => {
            let _ = std::fs::remove_file(&probe);
            Ok(())
        }
        Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => Ok(()),
        Err(e) => Err(Error::Usage(format!(
            "{}: cannot write in the folder {} ({e})",
            out.display(),
            dir.display()
        ))),
    }
}

/// 1-based line of byte `offset` in `text` (where a TOML parser's error span starts).
pub fn line_of(text: &str, offset: usize) -> usize {
    text[..offset.min(text.len())].matches('\n').count() + 1
}

/// Reads a text file; the error names it.
pub fn read_text(path: &Path) -> Result<String> {
    utf8(path, read_bytes(path)?)
}

fn utf8(path: &Path, bytes: Vec<u8>) -> Result<String> {
    String::from_utf8(bytes).map_err(|e| {
        Error::Usage(format!(
            "{}: not UTF-8 text (byte {} is not valid); is this the right file?",
            path.display(),
            e.utf8_error().valid_up_to()
        ))
    })
}

/// Reads the bytes of the regular file `path` (no device, pipe or directory), at most the size
/// it had when opened.
pub fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    read_bytes_up_to(path, None)
}

/// [`read_bytes`], refusing a file larger than `max_bytes` (named, with its size) before
/// reading it.
pub(crate) fn read_bytes_up_to(path: &Path, max_bytes: Option<u64>) -> Result<Vec<u8>> {
    use std::io::Read as _;
    let io = |source| Error::Io {
        path: path.to_path_buf(),
        source,
    };
    // Checked before opening: opening a FIFO blocks until somebody writes into it.
    input_file(path)?;
    let file = std::fs::File::open(path).map_err(io)?;
    let meta = file.metadata().map_err(io)?;
    // Checked again on what was opened (the name may have been replaced meanwhile).
    if !meta.is_file() {
        return Err(not_regular(path));
    }
    let len = meta.len();
    if let Some(max) = max_bytes.filter(|&m| len > m) {
        return Err(Error::Usage(format!(
            "{}: {len} bytes; a file of this kind holds at most {max} (is this the right file?)",
            path.display()
        )));
    }
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0).min(1 << 30));
    // At most the size it had when opened: a file that grows meanwhile cannot fill the memory.
    file.take(len).read_to_end(&mut bytes).map_err(io)?;
    Ok(bytes)
}

/// Refuses a path that is not a regular file (after following links): a directory, a
/// device such as `/dev/zero` (no end) or a FIFO (opening it blocks until a writer comes).
/// Every reader of a user's file calls it before opening, HDF5 files included.
pub fn regular_file(path: &Path) -> Result<()> {
    let meta = std::fs::metadata(path).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })?;
    if meta.is_file() {
        Ok(())
    } else {
        Err(not_regular(path))
    }
}

/// [`regular_file`] for a file a run reads: also recorded as the run's input
/// ([`crate::formats::guard::input`]), refused when an output of the run would replace it.
/// Every reader of a user's file calls it (or reads through [`read_bytes`]) before opening.
pub fn input_file(path: &Path) -> Result<()> {
    regular_file(path)?;
    crate::formats::guard::input(path)
}

fn not_regular(path: &Path) -> Error {
    Error::Usage(format!(
        "{}: not a regular file (a directory, a device or a pipe); give a file",
        path.display()
    ))
}

/// Reads a settings file (plan, test, prior) of at most `max_bytes`; the error names it and
/// says how large it is, so that a wrong path to a huge file does not fill the memory.
pub fn read_text_bounded(path: &Path, max_bytes: u64) -> Result<String> {
    utf8(path, read_bytes_up_to(path, Some(max_bytes))?)
}

/// The temporary name `path` is written under first: `NAME.tmp-PID`, beside it.
pub fn temp_path(path: &Path) -> PathBuf {
    let mut name = path
        .file_name()
        .map(|n| n.to_os_string())
        .unwrap_or_default();
    name.push(format!(".tmp-{}", std::process::id()));
    path.with_file_name(name)
}

#[cfg(feature = "hdf5")]
/// Checks that an HDF5 dataset holds complex numbers the way nlsim and h5py write them: a
/// compound of two floating-point members named `r` and `i`. HDF5 converts compounds by
/// member name, so `{re, im}` or `{real, imag}` would read as zeros; `Err` says what the
/// dataset holds instead.
pub fn complex_layout(ds: &hdf5::Dataset) -> std::result::Result<(), String> {
    use hdf5::types::{TypeDescriptor, TypeDescriptor::Compound};
    let td = ds
        .dtype()
        .and_then(|t| t.to_descriptor())
        .map_err(|e| format!("type not readable: {e}"))?;
    let ok = match &td {
        Compound(c) => {
            let names: Vec<&str> = c.fields.iter().map(|f| f.name.as_str()).collect();
            names == ["r", "i"]
                && c.fields
                    .iter()
                    .all(|f| matches!(f.ty, TypeDescriptor::Float(_)))
        }
        _ => false,
    };
    if ok {
        Ok(())
    } else {
        let what = match &td {
            Compound(c) => format!(
                "a compound of {}",
                c.fields
                    .iter()
                    .map(|f| format!("'{}'", f.name))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            other => format!("{other}"),
        };
        Err(format!(
            "holds {what}; complex values are a compound of two floats named 'r' and 'i' (as h5py writes them)"
        ))
    }
}

/// A number for a message or a table: as written (`0.2`, `21.5`, `1500`) between 1e-4 and
/// 1e7, in exponent form (`1e-320`, `1.5e12`) beyond, so an extreme value stays short.
pub fn number(v: f64) -> String {
    if v == 0.0 || !v.is_finite() || (1e-4..1e7).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

/// `s` as a file-name part: every character but ASCII letters, digits, `-` and `_` made `_`.
pub fn file_name_part(s: &str) -> String {
    s.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || "-_".contains(c) {
                c
            } else {
                '_'
            }
        })
        .collect()
}

/// `s` as one CSV field: quoted (quotes doubled) when it holds a comma, a quote or a newline.
pub fn csv_field(s: &str) -> String {
    if s.contains([',', '"', '\n']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// `s` as a TOML basic string (quotes, backslashes and control characters escaped).
pub fn toml_string(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for ch in s.chars() {
        match ch {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            c if c.is_control() => {
                o.push_str(&format!("\\u{:04X}", c as u32));
            }
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

/// Longest part of a user's value quoted in an error message (characters).
pub const QUOTE_MAX: usize = 60;

/// A user's value quoted for an error message: `'VALUE'`, cut after [`QUOTE_MAX`]
/// characters (with `…` and its length in bytes) and with control characters escaped, so a
/// huge or binary value keeps the message one readable line.
pub fn quoted(value: &str) -> String {
    let mut out = String::from("'");
    for (i, c) in value.chars().enumerate() {
        if i == QUOTE_MAX {
            out.push_str(&format!("…' ({} bytes)", value.len()));
            return out;
        }
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out.push('\'');
    out
}

/// SI unit of a response quantity, as written in file headers and attributes.
pub fn unit(q: nlsim_kernel::Quantity) -> &'static str {
    match q {
        nlsim_kernel::Quantity::Displacement => "m",
        nlsim_kernel::Quantity::Velocity => "m/s",
        nlsim_kernel::Quantity::Acceleration => "m/s^2",
    }
}

#[cfg(feature = "hdf5")]
/// Writes a string attribute (non-ASCII-safe text; `?` if it cannot be stored).
pub fn str_attr(loc: &hdf5::Location, name: &str, v: &str) -> hdf5::Result<()> {
    let s: hdf5::types::VarLenUnicode = v.parse().unwrap_or_else(|_| "?".parse().expect("ascii"));
    loc.new_attr::<hdf5::types::VarLenUnicode>()
        .create(name)?
        .write_scalar(&s)
}

#[cfg(feature = "hdf5")]
/// Writes a scalar `f64` attribute.
pub fn f64_attr(loc: &hdf5::Location, name: &str, v: f64) -> hdf5::Result<()> {
    loc.new_attr::<f64>().create(name)?.write_scalar(&v)
}

#[cfg(feature = "hdf5")]
/// Writes a scalar `u64` attribute: counts and orders (harmonics, modes, a mode number).
pub fn count_attr(loc: &hdf5::Location, name: &str, v: usize) -> hdf5::Result<()> {
    loc.new_attr::<u64>()
        .create(name)?
        .write_scalar(&(v as u64))
}

#[cfg(feature = "hdf5")]
/// Reads a scalar numeric attribute as `f64`, whether stored as an integer (files of this
/// version) or a float (earlier ones).
pub fn number_attr(loc: &hdf5::Location, name: &str) -> hdf5::Result<f64> {
    use hdf5::types::TypeDescriptor;
    let a = loc.attr(name)?;
    match a.dtype()?.to_descriptor()? {
        TypeDescriptor::Unsigned(_) => Ok(a.read_scalar::<u64>()? as f64),
        TypeDescriptor::Integer(_) => Ok(a.read_scalar::<i64>()? as f64),
        _ => a.read_scalar::<f64>(),
    }
}

/// `text` as one printable line: its lines trimmed and joined by `; `, and any other control
/// character (an escape sequence read from a file name or a file, a tab) written as an
/// escape, so that an error never spans lines or drives the terminal.
pub fn one_line(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for line in text.lines().map(str::trim).filter(|l| !l.is_empty()) {
        if !out.is_empty() {
            out.push_str("; ");
        }
        for c in line.chars() {
            if c.is_control() {
                out.extend(c.escape_default());
            } else {
                out.push(c);
            }
        }
    }
    out
}

/// The error for an HDF5 file in a build without the `hdf5` feature (the Python package and
/// `--features formats` builds link no libhdf5): names the file and what to do instead.
pub fn without_hdf5(path: &Path) -> Error {
    Error::Hdf5 {
        path: path.to_path_buf(),
        message: "this build of nlsim reads and writes no HDF5 (it was built without the \
                  `hdf5` feature); use the CSV form, or read the file with h5py and pass the \
                  arrays in"
            .into(),
    }
}

#[cfg(feature = "hdf5")]
/// Maps an HDF5 error to [`Error::Hdf5`] naming `path`.
pub fn h5err(path: &Path) -> impl Fn(hdf5::Error) -> Error + '_ {
    move |e| Error::Hdf5 {
        path: path.to_path_buf(),
        message: one_line(&e.to_string()),
    }
}

#[cfg(feature = "hdf5")]
/// Writes what every nlsim HDF5 file carries at its root (`docs/file-formats.md`): the nlsim
/// version, the command, the model spec as given, the model's name, the seed of any random
/// draws, and — when the spec is a model file — that file's text, so the data can be traced
/// back without the file.
pub fn provenance(
    root: &hdf5::Group,
    command: &str,
    model_spec: &str,
    model_name: &str,
    seed: Option<u64>,
) -> hdf5::Result<()> {
    str_attr(root, "nlsim_version", env!("CARGO_PKG_VERSION"))?;
    str_attr(root, "command", command)?;
    str_attr(root, "model", model_spec)?;
    // An empty name is written later by the caller (a report, whose model loads after it
    // starts).
    if !model_name.is_empty() {
        str_attr(root, "model_name", model_name)?;
    }
    if let Some(s) = seed {
        root.new_attr::<u64>().create("seed")?.write_scalar(&s)?;
    }
    let p = Path::new(model_spec);
    if p.is_file()
        && let Ok(text) = std::fs::read_to_string(p)
    {
        str_attr(root, "model_file_text", &text)?;
    }
    Ok(())
}

#[cfg(feature = "hdf5")]
/// Reads a `u64` root attribute, if present.
pub fn u64_attr(file: &hdf5::File, name: &str) -> Option<u64> {
    file.attr(name).ok()?.read_scalar::<u64>().ok()
}

/// Half the memory the system reports available (`MemAvailable` of `/proc/meminfo`, bytes):
/// the command line's default factor budget, so that a model whose two factors would not fit
/// beside each other is checked in the storage of one. `None` where the file is not there.
pub fn default_memory_budget() -> Option<usize> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = info.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: usize = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib.saturating_mul(1024) / 2)
}

/// Name of job `index`'s group in shard and merged files.
pub fn job_group_name(index: usize) -> String {
    format!("job-{index:08}")
}

#[cfg(test)]
mod tests {
    #[test]
    fn an_error_text_becomes_one_printable_line() {
        // HDF5's multi-line messages, a file name with an escape sequence, a tab.
        let text = "H5Dwrite(): can't write data\n    major: Dataset\n\n  minor: Write failed\n";
        assert_eq!(
            super::one_line(text),
            "H5Dwrite(): can't write data; major: Dataset; minor: Write failed"
        );
        assert_eq!(
            super::one_line("model '\u{1b}[2Jx\tbeam.toml': not found"),
            "model '\\u{1b}[2Jx\\tbeam.toml': not found"
        );
        assert_eq!(super::one_line("plain é ∂"), "plain é ∂");
    }
}
