//! The TOML reading the model file's tables share: a table that remembers which keys were
//! read (unknown keys are errors, typos named), numbers, and errors at file, line and key.

use crate::error::{Error, Result};
use std::ops::Range;
use std::path::Path;
use toml::Spanned;
use toml::de::{DeTable, DeValue};

/// The text of a model file with its path, for error locations.
pub(super) struct Doc<'a> {
    pub(super) file: &'a Path,
    pub(super) text: &'a str,
}

impl Doc<'_> {
    pub(super) fn err(&self, span: Range<usize>, key: &str, message: impl Into<String>) -> Error {
        let line = self.text[..span.start.min(self.text.len())]
            .matches('\n')
            .count()
            + 1;
        Error::Spec {
            file: self.file.to_path_buf(),
            line,
            key: key.to_string(),
            message: message.into(),
        }
    }
}

/// A table being read: remembers which keys were used so unknown ones can be reported.
pub(super) struct Tab<'a, 'i> {
    pub(super) doc: &'a Doc<'a>,
    pub(super) path: String,
    pub(super) span: Range<usize>,
    pub(super) t: &'a DeTable<'i>,
    pub(super) used: Vec<String>,
}

pub(super) type Val<'a, 'i> = &'a Spanned<DeValue<'i>>;

impl<'a, 'i> Tab<'a, 'i> {
    pub(super) fn key(&self, k: &str) -> String {
        if self.path.is_empty() {
            k.to_string()
        } else {
            format!("{}.{k}", self.path)
        }
    }
    pub(super) fn get(&mut self, k: &str) -> Option<Val<'a, 'i>> {
        self.used.push(k.to_string());
        self.t.get(k)
    }
    pub(super) fn err(&self, v: Val<'_, '_>, k: &str, msg: impl Into<String>) -> Error {
        self.doc.err(v.span(), &self.key(k), msg)
    }
    /// A required key `k` is missing; a key of the table that is not one and lies within two
    /// edits of `k` is named as the likely typo.
    pub(super) fn missing(&self, k: &str, what: &str) -> Error {
        let typo = self
            .t
            .iter()
            .map(|(key, _)| key.get_ref().to_string())
            .find(|key| {
                !self.used.iter().any(|u| u == key) && key != k && edit_distance(key, k) <= 2
            });
        let hint = typo.map_or_else(String::new, |t| {
            format!(
                " (the table has '{}', which is not a key here: a typo of '{k}'?)",
                crate::formats::files::quoted(&t).trim_matches('\'')
            )
        });
        self.doc.err(
            self.span.clone(),
            &self.key(k),
            format!("missing: {what}{hint}"),
        )
    }
    pub(super) fn str(&mut self, k: &str) -> Result<Option<(String, Range<usize>)>> {
        match self.get(k) {
            None => Ok(None),
            Some(v) => match v.get_ref() {
                DeValue::String(s) => Ok(Some((s.to_string(), v.span()))),
                _ => Err(self.err(v, k, "expected a string")),
            },
        }
    }
    pub(super) fn f64(&mut self, k: &str) -> Result<Option<f64>> {
        match self.get(k) {
            None => Ok(None),
            Some(v) => number(v)
                .map(Some)
                .ok_or_else(|| self.err(v, k, "expected a finite number")),
        }
    }
    pub(super) fn req_f64(&mut self, k: &str, what: &str) -> Result<f64> {
        self.f64(k)?.ok_or_else(|| self.missing(k, what))
    }
    pub(super) fn sub(&mut self, k: &str) -> Result<Option<Tab<'a, 'i>>> {
        match self.get(k) {
            None => Ok(None),
            Some(v) => match v.get_ref() {
                DeValue::Table(t) => Ok(Some(Tab {
                    doc: self.doc,
                    path: self.key(k),
                    span: v.span(),
                    t,
                    used: vec![],
                })),
                _ => Err(self.err(v, k, "expected a table")),
            },
        }
    }
    /// `[[k]]` arrays of tables.
    pub(super) fn array_of_tables(&mut self, k: &str) -> Result<Vec<Tab<'a, 'i>>> {
        let Some(v) = self.get(k) else {
            return Ok(vec![]);
        };
        let DeValue::Array(a) = v.get_ref() else {
            return Err(self.err(v, k, format!("expected [[{k}]] tables")));
        };
        a.iter()
            .enumerate()
            .map(|(i, item)| match item.get_ref() {
                DeValue::Table(t) => Ok(Tab {
                    doc: self.doc,
                    path: format!("{}[{}]", self.key(k), i + 1),
                    span: item.span(),
                    t,
                    used: vec![],
                }),
                _ => Err(self.err(item, k, format!("expected [[{k}]] tables"))),
            })
            .collect()
    }
    /// A model error located at this table.
    pub(super) fn at_table(&self, e: nlsim_kernel::Error) -> Error {
        self.doc.err(self.span.clone(), &self.path, e.to_string())
    }
    /// Errors on the first key that was never read.
    pub(super) fn finish(&self, allowed_hint: &str) -> Result<()> {
        for (k, v) in self.t.iter() {
            if !self.used.iter().any(|u| u == k.get_ref().as_ref()) {
                return Err(self.doc.err(
                    k.span().start..v.span().end,
                    &self.key(k.get_ref()),
                    format!("unknown key; {allowed_hint}"),
                ));
            }
        }
        Ok(())
    }
}

/// The Levenshtein distance between two short keys (characters inserted, deleted or
/// replaced).
fn edit_distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut cur = vec![i + 1; b.len() + 1];
        for (j, &cb) in b.iter().enumerate() {
            cur[j + 1] = (prev[j] + usize::from(ca != cb))
                .min(prev[j + 1] + 1)
                .min(cur[j] + 1);
        }
        prev = cur;
    }
    prev[b.len()]
}

pub(super) fn number(v: &Spanned<DeValue<'_>>) -> Option<f64> {
    let x = match v.get_ref() {
        DeValue::Float(f) => f.as_str().replace('_', "").parse::<f64>().ok()?,
        DeValue::Integer(i) => {
            i64::from_str_radix(&i.as_str().replace('_', ""), i.radix()).ok()? as f64
        }
        _ => return None,
    };
    x.is_finite().then_some(x)
}

/// A TOML parser's message in nlsim's words: trimmed, and an empty key named as such (serde
/// writes it as an unknown field ``).
pub fn toml_message(message: &str) -> String {
    message
        .trim()
        .replace("unknown field ``", "an empty key \"\" is not a field")
}
