//! What the settings files (calibration, plan and test files, TOML) share: a parsed document
//! whose errors name the file, the line and the key, and the line of a key in its text.
use crate::error::{Error, Result};
use std::path::{Path, PathBuf};

/// The key a TOML error is about (the field in backticks of "unknown field `x`" or
/// "missing field `x`"), else `toml`.
pub fn toml_key(message: &str) -> String {
    message
        .strip_prefix("unknown field `")
        .or_else(|| message.strip_prefix("missing field `"))
        .and_then(|r| r.split('`').next())
        .unwrap_or("toml")
        .to_string()
}

/// A settings file being read (calibration, plan, test): errors name the file, the line of
/// the key and the key; relative paths in it are taken from its folder.
pub struct SettingsFile<'a> {
    /// The file's text.
    pub text: &'a str,
    /// The file.
    pub path: &'a Path,
}

impl<'a> SettingsFile<'a> {
    /// Parses `text` as `T`, a TOML error located at its line and key.
    pub fn parse<T: serde::de::DeserializeOwned>(text: &'a str, path: &'a Path) -> Result<T> {
        toml::from_str(text).map_err(|e| Error::Spec {
            file: path.to_path_buf(),
            line: e
                .span()
                .map_or(1, |s| crate::formats::files::line_of(text, s.start)),
            key: toml_key(e.message()),
            message: plain_types(e.message()),
        })
    }

    /// An error about `key` (dotted: the line of its last part).
    pub fn err(&self, key: &str, message: String) -> Error {
        Error::Spec {
            file: self.path.to_path_buf(),
            line: line_of_key(self.text, key.rsplit('.').next().unwrap_or(key)),
            key: key.to_string(),
            message,
        }
    }

    /// `p` relative to the file's folder (absolute paths as they are).
    pub fn rel(&self, p: &str) -> PathBuf {
        let p = Path::new(p);
        if p.is_absolute() {
            p.to_path_buf()
        } else {
            self.path.parent().unwrap_or(Path::new("")).join(p)
        }
    }

    /// A request's `check` error `"{prefix} KEY: ..."` located at `KEY`.
    pub fn located(&self, prefix: &str, e: Error) -> Error {
        let msg = e.to_string();
        let key = msg
            .strip_prefix(prefix)
            .and_then(|m| m.strip_prefix(' '))
            .and_then(|m| m.split(':').next())
            .unwrap_or("")
            .to_string();
        self.err(&key, msg)
    }
}

/// Line of the first `key = ` (or `[key]`) in `text`, for errors found after parsing.
pub fn line_of_key(text: &str, key: &str) -> usize {
    text.lines()
        .position(|l| {
            let l = l.trim_start();
            l.strip_prefix(key)
                .is_some_and(|rest| rest.trim_start().starts_with('='))
                || l.starts_with(&format!("[{key}]"))
                || l.starts_with(&format!("[[{key}]]"))
        })
        .map_or(1, |i| i + 1)
}

/// A deserializer's message with Rust's type names in words: `expected usize` becomes
/// `expected a whole number (0 or more)`, `expected f64` `expected a number`.
pub fn plain_types(message: &str) -> String {
    let mut m = message.to_string();
    for (rust, words) in [
        ("expected usize", "expected a whole number (0 or more)"),
        ("expected u64", "expected a whole number (0 or more)"),
        ("expected u32", "expected a whole number (0 or more)"),
        ("expected u16", "expected a whole number (0 or more)"),
        ("expected u8", "expected a whole number (0 or more)"),
        ("expected i64", "expected a whole number"),
        ("expected i32", "expected a whole number"),
        ("expected f64", "expected a number"),
        ("expected f32", "expected a number"),
        ("expected a boolean", "expected true or false"),
    ] {
        if let Some(at) = m.find(rust) {
            let end = at + rust.len();
            // Whole words only (`expected u8` is not `expected u80`).
            if !m[end..].starts_with(|c: char| c.is_ascii_alphanumeric()) {
                m.replace_range(at..end, words);
            }
        }
    }
    m
}

#[cfg(test)]
mod plain_type_tests {
    #[test]
    fn rust_type_names_become_words() {
        assert_eq!(
            super::plain_types("invalid type: floating point `2.5`, expected usize"),
            "invalid type: floating point `2.5`, expected a whole number (0 or more)"
        );
        assert_eq!(
            super::plain_types("invalid type: string \"x\", expected f64"),
            "invalid type: string \"x\", expected a number"
        );
    }
}

/// The `[shaker]` table of a test or calibration file: an electrodynamic shaker on a stinger
/// ([`nlsim_calib::Shaker`]); absent keys take the default shaker's values. Read by the
/// command layer.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ShakerTable {
    armature_mass: Option<f64>,
    suspension_stiffness: Option<f64>,
    suspension_damping: Option<f64>,
    resistance: Option<f64>,
    inductance: Option<f64>,
    force_constant: Option<f64>,
    stinger_stiffness: Option<f64>,
}

/// The shaker of a test or calibration file at `path` (`nlsim calibrate --shaker FILE`): its
/// `[shaker]` table, the default shaker's values for the keys it leaves out, and the default
/// shaker when it has none (as `nlsim test` runs it). The other keys of the file are not read.
pub fn shaker_of_file(path: &Path) -> Result<nlsim_calib::Shaker> {
    #[derive(serde::Deserialize)]
    struct Only {
        shaker: Option<ShakerTable>,
    }
    let text = crate::formats::files::read_text_bounded(path, MAX_SHAKER_FILE_BYTES)?;
    let only: Only = SettingsFile::parse(&text, path)?;
    let shaker = ShakerTable::shaker(only.shaker.as_ref());
    shaker.check().map_err(|e| Error::Spec {
        file: path.to_path_buf(),
        line: line_of_key(&text, "shaker"),
        key: "shaker".into(),
        message: e.to_string(),
    })?;
    Ok(shaker)
}

/// Largest test or calibration file read for its `[shaker]` table (bytes).
pub const MAX_SHAKER_FILE_BYTES: u64 = 1 << 20;

impl ShakerTable {
    /// The shaker of `table`: the default one with the keys given replaced.
    pub(crate) fn shaker(table: Option<&ShakerTable>) -> nlsim_calib::Shaker {
        let ds = nlsim_calib::Shaker::default();
        let Some(s) = table else { return ds };
        nlsim_calib::Shaker {
            armature_mass: s.armature_mass.unwrap_or(ds.armature_mass),
            suspension_stiffness: s.suspension_stiffness.unwrap_or(ds.suspension_stiffness),
            suspension_damping: s.suspension_damping.unwrap_or(ds.suspension_damping),
            resistance: s.resistance.unwrap_or(ds.resistance),
            inductance: s.inductance.unwrap_or(ds.inductance),
            force_constant: s.force_constant.unwrap_or(ds.force_constant),
            stinger_stiffness: s.stinger_stiffness.unwrap_or(ds.stinger_stiffness),
        }
    }
}
