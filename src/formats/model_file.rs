//! Model files (TOML) and the `MODEL` argument of every command.
//!
//! `MODEL` is either the path of a model file or a built-in model name, optionally with
//! options: `ecl_beam`, `bracket:refinement=4,nonlinear=bump_stop`. The model file format is
//! documented in `docs/model-files.md`; every error names the file, the line and the key.

use crate::error::{Error, Result};
use crate::formats::fe_matrices as fe;
use crate::formats::matrices as mtx;
use nlsim_kernel::{
    Coupling, Damping, DampingBand, DofLabel, DofMap, Excitation, Law, ModalDamping, Model,
    NonlinearElement, PolyTerm, Quantity, Sensor, SparseSym,
};
use std::ops::Range;
use std::path::Path;
use toml::Spanned;
use toml::de::{DeTable, DeValue};

/// A model with where it came from.
#[derive(Debug, Clone)]
pub struct LoadedModel {
    /// The model.
    pub model: Model,
    /// `fixture NAME` or the file path.
    pub source: String,
    /// The fixture's description, when the model is (or starts from) a fixture.
    pub description: Option<String>,
    /// The fixture's reference values, when it is one.
    pub references: Vec<nlsim_fixtures::Reference>,
}

/// Resolves a `MODEL` argument: an existing file (or anything ending in `.toml`) is read as a
/// model file, anything else as `fixture[:key=value,...]`.
pub fn load_model(arg: &str) -> Result<LoadedModel> {
    let path = Path::new(arg);
    if path.exists() || arg.ends_with(".toml") {
        let text = crate::formats::files::read_text(path)?;
        return parse_model_file(&text, path);
    }
    let (name, opts) = split_fixture_arg(arg);
    if !nlsim_fixtures::CATALOGUE.iter().any(|f| f.name == name) {
        return Err(Error::UnknownModel(
            arg.to_string(),
            nlsim_fixtures::CATALOGUE
                .iter()
                .map(|f| f.name)
                .collect::<Vec<_>>()
                .join(", "),
        ));
    }
    let fx = nlsim_fixtures::build(name, &opts)?;
    Ok(LoadedModel {
        model: fx.model,
        source: format!("built-in model {arg}"),
        description: Some(fx.description),
        references: fx.references,
    })
}

fn split_fixture_arg(arg: &str) -> (&str, Vec<(String, String)>) {
    match arg.split_once(':') {
        None => (arg, Vec::new()),
        Some((name, rest)) => (
            name,
            rest.split(',')
                .filter(|s| !s.trim().is_empty())
                .map(|kv| match kv.split_once('=') {
                    Some((k, v)) => (k.trim().to_string(), v.trim().to_string()),
                    None => (kv.trim().to_string(), String::new()),
                })
                .collect(),
        ),
    }
}

/// The text of a model file with its path, for error locations.
struct Doc<'a> {
    file: &'a Path,
    text: &'a str,
}

impl Doc<'_> {
    fn err(&self, span: Range<usize>, key: &str, message: impl Into<String>) -> Error {
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
struct Tab<'a, 'i> {
    doc: &'a Doc<'a>,
    path: String,
    span: Range<usize>,
    t: &'a DeTable<'i>,
    used: Vec<String>,
}

type Val<'a, 'i> = &'a Spanned<DeValue<'i>>;

impl<'a, 'i> Tab<'a, 'i> {
    fn key(&self, k: &str) -> String {
        if self.path.is_empty() {
            k.to_string()
        } else {
            format!("{}.{k}", self.path)
        }
    }
    fn get(&mut self, k: &str) -> Option<Val<'a, 'i>> {
        self.used.push(k.to_string());
        self.t.get(k)
    }
    fn err(&self, v: Val<'_, '_>, k: &str, msg: impl Into<String>) -> Error {
        self.doc.err(v.span(), &self.key(k), msg)
    }
    /// A required key `k` is missing; a key of the table that is not one and lies within two
    /// edits of `k` is named as the likely typo.
    fn missing(&self, k: &str, what: &str) -> Error {
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
    fn str(&mut self, k: &str) -> Result<Option<(String, Range<usize>)>> {
        match self.get(k) {
            None => Ok(None),
            Some(v) => match v.get_ref() {
                DeValue::String(s) => Ok(Some((s.to_string(), v.span()))),
                _ => Err(self.err(v, k, "expected a string")),
            },
        }
    }
    fn f64(&mut self, k: &str) -> Result<Option<f64>> {
        match self.get(k) {
            None => Ok(None),
            Some(v) => number(v)
                .map(Some)
                .ok_or_else(|| self.err(v, k, "expected a finite number")),
        }
    }
    fn req_f64(&mut self, k: &str, what: &str) -> Result<f64> {
        self.f64(k)?.ok_or_else(|| self.missing(k, what))
    }
    fn sub(&mut self, k: &str) -> Result<Option<Tab<'a, 'i>>> {
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
    fn array_of_tables(&mut self, k: &str) -> Result<Vec<Tab<'a, 'i>>> {
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
    /// `name` (or `default`) and the required labelled `dof` of an excitation or sensor.
    fn name_and_dof(
        &mut self,
        default: String,
        dofs: &DofMap,
        what: &str,
    ) -> Result<(String, usize)> {
        let name = self.str("name")?.map_or(default, |s| s.0);
        let dof = read_dof(self, "dof", dofs)?
            .ok_or_else(|| self.missing("dof", &format!("{what}, e.g. dof = \"21:uz\"")))?;
        Ok((name, dof))
    }
    /// A model error located at this table.
    fn at_table(&self, e: nlsim_kernel::Error) -> Error {
        self.doc.err(self.span.clone(), &self.path, e.to_string())
    }
    /// Errors on the first key that was never read.
    fn finish(&self, allowed_hint: &str) -> Result<()> {
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

fn number(v: &Spanned<DeValue<'_>>) -> Option<f64> {
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

/// Parses a model file's text; `file` is used for relative paths and error locations.
pub fn parse_model_file(text: &str, file: &Path) -> Result<LoadedModel> {
    let doc = Doc { file, text };
    let root = DeTable::parse(text).map_err(|e| {
        let span = e.span().unwrap_or(0..0);
        doc.err(span, "(syntax)", e.message().trim().to_string())
    })?;
    let mut top = Tab {
        doc: &doc,
        path: String::new(),
        span: root.span(),
        t: root.get_ref(),
        used: vec![],
    };
    let base_dir = file.parent().map(Path::to_path_buf).unwrap_or_default();

    let default_name = file
        .file_stem()
        .map_or("model".to_string(), |s| s.to_string_lossy().into_owned());
    let name = top.str("name")?.map_or(default_name, |s| s.0);
    if let Some((u, span)) = top.str("units")?
        && !u.eq_ignore_ascii_case("SI")
    {
        return Err(doc.err(
            span,
            "units",
            format!("'{u}' is not supported: nlsim works in SI (m, kg, s, N, rad)"),
        ));
    }
    let mut mats = top.sub("matrices")?.ok_or_else(|| {
        top.missing(
            "matrices",
            "a [matrices] table (fixture = ..., or mass/stiffness)",
        )
    })?;
    let (mut model, description, references, from_fixture) =
        read_matrices(&mut mats, &name, &base_dir)?;
    mats.finish("[matrices] takes fixture and options, or mass, stiffness, dofs and format")?;

    if let Some(mut d) = top.sub("damping")? {
        let damping = read_damping(&mut d, &base_dir, model.n_dofs())?;
        let span = d.span.clone();
        d.finish("see docs/model-files.md for the keys of each damping type")?;
        model
            .set_damping(damping)
            .map_err(|e| doc.err(span, "damping", e.to_string()))?;
    }

    for mut g in top.array_of_tables("group")? {
        let (gname, span) = g.str("name")?.ok_or_else(|| {
            g.missing(
                "name",
                "a group name, e.g. name = \"flange\" (parameters group:flange.k_scale, ...)",
            )
        })?;
        let n = model.n_dofs();
        let mut part = |key: &str, what: &str| -> Result<Option<SparseSym>> {
            let Some(v) = g.get(key) else {
                return Ok(None);
            };
            let label = format!("group '{gname}' {what}");
            let m = match fe_matrix(&g, key, v, &base_dir, None)? {
                // An FE code's matrix lands on the model's DOFs by label.
                Some(m) => m.onto(model.dofs(), &label)?,
                None => read_matrix(&g, key, v, &label, &base_dir)?,
            };
            if m.n() != n {
                return Err(g.err(
                    v,
                    key,
                    format!("the matrix has order {}, the model {n} DOFs", m.n()),
                ));
            }
            Ok(Some(m))
        };
        let stiffness = part("stiffness", "stiffness")?;
        let mass = part("mass", "mass")?;
        if stiffness.is_none() && mass.is_none() {
            return Err(doc.err(
                span,
                &g.key("name"),
                "a group needs its stiffness or mass part (or both): the share of K or M its \
                 scale multiplies",
            ));
        }
        g.finish("a group takes name, stiffness and mass")?;
        model
            .add_group(gname, stiffness, mass)
            .map_err(|err| g.at_table(err))?;
    }
    for mut s in top.array_of_tables("spring")? {
        let dof = read_dof(&mut s, "dof", model.dofs())?
            .ok_or_else(|| s.missing("dof", "the DOF the spring grounds, e.g. dof = \"12:uz\""))?;
        let k = s.req_f64("k", "the spring stiffness in N/m (N m/rad on a rotation)")?;
        s.finish("a boundary spring takes dof and k")?;
        model
            .add_boundary_spring(dof, k)
            .map_err(|err| s.at_table(err))?;
    }

    let elements = top.array_of_tables("element")?;
    let excitation = top.array_of_tables("excitation")?;
    let sensors = top.array_of_tables("sensor")?;
    if from_fixture {
        // Lists given in the file replace the fixture's; absent lists keep them.
        model = rebuild(
            &model,
            &name,
            elements.is_empty(),
            excitation.is_empty(),
            sensors.is_empty(),
        )?;
    }
    for mut e in elements {
        let el = read_element(&mut e, model.dofs())?;
        e.finish(if el.is_coupled() {
            "a coupled_polynomial element takes name, type, dofs and coefficients \
             k<i>_<p1>_..._<pm> (one power per coordinate)"
        } else {
            "an element takes name, type, dof, dof2 and the parameters of its type"
        })?;
        model.add_element(el).map_err(|err| e.at_table(err))?;
    }
    for (i, mut x) in excitation.into_iter().enumerate() {
        let (name, dof) = x.name_and_dof(
            format!("force{}", i + 1),
            model.dofs(),
            "the DOF the force acts on",
        )?;
        let amplitude = x.req_f64("amplitude", "the force amplitude in N")?;
        let mut harmonics = Vec::new();
        for mut h in x.array_of_tables("harmonic")? {
            harmonics.push(read_force_harmonic(&mut h)?);
            h.finish("an excitation harmonic takes order, amplitude, phase")?;
        }
        x.finish("an excitation takes name, dof, amplitude, [[excitation.harmonic]]")?;
        model
            .add_excitation(Excitation {
                name,
                dof,
                amplitude,
                harmonics,
            })
            .map_err(|err| x.at_table(err))?;
    }
    for (i, mut s) in sensors.into_iter().enumerate() {
        let (name, dof) =
            s.name_and_dof(format!("sensor{}", i + 1), model.dofs(), "the measured DOF")?;
        let quantity = match s.str("quantity")? {
            None => Quantity::Acceleration,
            Some((q, sp)) => {
                Quantity::parse(&q).map_err(|e| doc.err(sp, &s.key("quantity"), e.to_string()))?
            }
        };
        s.finish("a sensor takes name, dof, quantity")?;
        model
            .add_sensor(Sensor {
                name,
                dof,
                quantity,
            })
            .map_err(|err| s.at_table(err))?;
    }
    top.finish("the top level takes name, units, [matrices], [damping], [[group]], [[spring]], [[element]], [[excitation]], [[sensor]]")?;
    Ok(LoadedModel {
        model,
        source: file.display().to_string(),
        description,
        references,
    })
}

/// A copy of `m` named `name` that keeps only the lists asked for (groups and boundary
/// springs always stay).
fn rebuild(m: &Model, name: &str, keep_el: bool, keep_ex: bool, keep_se: bool) -> Result<Model> {
    let mut out = m.clone();
    out.set_name(name);
    if !keep_el {
        out.clear_elements();
    }
    if !keep_ex {
        out.clear_excitation();
    }
    if !keep_se {
        out.clear_sensors();
    }
    Ok(out)
}

type Matrices = (Model, Option<String>, Vec<nlsim_fixtures::Reference>, bool);

fn read_matrices(t: &mut Tab<'_, '_>, name: &str, base: &Path) -> Result<Matrices> {
    if let Some((fx, span)) = t.str("fixture")? {
        let mut opts = Vec::new();
        if let Some(o) = t.sub("options")? {
            for (k, v) in o.t.iter() {
                let text = match v.get_ref() {
                    DeValue::String(s) => s.to_string(),
                    DeValue::Integer(i) => i.as_str().to_string(),
                    DeValue::Float(f) => f.as_str().to_string(),
                    DeValue::Boolean(b) => b.to_string(),
                    _ => {
                        return Err(o.err(
                            v,
                            k.get_ref(),
                            "expected a number, a string or a boolean",
                        ));
                    }
                };
                opts.push((k.get_ref().to_string(), text));
            }
        }
        let f = nlsim_fixtures::build(&fx, &opts)
            .map_err(|e| t.doc.err(span, &t.key("fixture"), e.to_string()))?;
        return Ok((f.model, Some(f.description), f.references, true));
    }
    let mass_v = t.get("mass").ok_or_else(|| {
        t.missing(
            "mass",
            "fixture = \"NAME\", or mass and stiffness (Matrix Market path or inline rows)",
        )
    })?;
    let stiff_v = t.get("stiffness").ok_or_else(|| {
        t.missing(
            "stiffness",
            "the stiffness matrix (Matrix Market path or inline rows)",
        )
    })?;
    let format = match t.str("format")? {
        None => None,
        Some((f, span)) => Some(match f.to_ascii_lowercase().as_str() {
            "matrix-market" | "hdf5" => None,
            other => Some(fe::FeFormat::parse(other).ok_or_else(|| {
                t.doc.err(
                    span,
                    &t.key("format"),
                    format!(
                        "unknown matrix format {}; use matrix-market, hdf5, dmig, abaqus or \
                         harwell-boeing (OUTPUT4 is read from .op4 files)",
                        crate::formats::files::quoted(&f)
                    ),
                )
            })?),
        }),
    };
    let mass_fe = fe_matrix(t, "mass", mass_v, base, format)?;
    let stiff_fe = fe_matrix(t, "stiffness", stiff_v, base, format)?;
    if let (Some(m), Some(k)) = (&mass_fe, &stiff_fe) {
        // The labels come from the files: every DOF either matrix names.
        if let Some(v) = t.get("dofs") {
            return Err(t.err(
                v,
                "dofs",
                "DMIG, Abaqus and Harwell-Boeing (with its mapping) matrices label their DOFs themselves: leave `dofs` out",
            ));
        }
        let dofs = fe::union_dofs(&[k, m]).map_err(|e| {
            t.doc
                .err(t.span.clone(), &t.key("stiffness"), e.to_string())
        })?;
        let mass = m.onto(&dofs, "mass matrix")?;
        let stiffness = k.onto(&dofs, "stiffness matrix")?;
        let model = Model::new(name, dofs, mass, stiffness).map_err(|e| {
            t.doc
                .err(t.span.clone(), &t.key("stiffness"), e.to_string())
        })?;
        return Ok((model, None, vec![], false));
    }
    if mass_fe.is_some() != stiff_fe.is_some() {
        return Err(t.err(
            stiff_v,
            "stiffness",
            "give mass and stiffness both from FE-code files (DMIG, Abaqus, Harwell-Boeing with mapping), which label \
             their DOFs, or both as Matrix Market, HDF5 or inline rows with `dofs`",
        ));
    }
    let mass = read_matrix(t, "mass", mass_v, "mass matrix", base)?;
    let stiffness = read_matrix(t, "stiffness", stiff_v, "stiffness matrix", base)?;
    let dofs = match t.get("dofs") {
        None => DofMap::scalar(mass.n()),
        Some(v) => {
            let labels = match v.get_ref() {
                DeValue::String(p) => {
                    let path = base.join(p.as_ref());
                    let text = crate::formats::files::read_text(&path)?;
                    mtx::parse_dof_labels(&text, &path)?
                }
                DeValue::Array(a) => a
                    .iter()
                    .map(|l| match l.get_ref() {
                        DeValue::String(s) => s
                            .parse::<DofLabel>()
                            .map_err(|e| t.err(l, "dofs", e.to_string())),
                        _ => Err(t.err(l, "dofs", "expected DOF labels such as \"12:uz\"")),
                    })
                    .collect::<Result<Vec<_>>>()?,
                _ => return Err(t.err(v, "dofs", "expected a file path or a list of DOF labels")),
            };
            DofMap::new(labels).map_err(|e| t.err(v, "dofs", e.to_string()))?
        }
    };
    let model = Model::new(name, dofs, mass, stiffness)
        .map_err(|e| t.doc.err(t.span.clone(), &t.key("dofs"), e.to_string()))?;
    Ok((model, None, vec![], false))
}

/// The matrix of `key` if it names an FE code's file (`FILE.pch[:NAME]`, `FILE.bdf[:NAME]`,
/// an Abaqus `.mtx`, a Harwell-Boeing file with its `.mapping`, or any file with `format =
/// "dmig"`/`"abaqus"`/`"harwell-boeing"`), read with its labels.
/// A DMIG matrix's name defaults to `KAAX` for the stiffness and `MAAX` for the mass.
fn fe_matrix(
    t: &Tab<'_, '_>,
    key: &str,
    v: Val<'_, '_>,
    base: &Path,
    format: Option<Option<fe::FeFormat>>,
) -> Result<Option<fe::LabelledMatrix>> {
    let DeValue::String(p) = v.get_ref() else {
        return Ok(None);
    };
    let p: &str = p.as_ref();
    // `FILE:NAME` names one matrix of a DMIG file.
    let (file, name) = match p.rsplit_once(':') {
        Some((f, n))
            if !n.contains(['/', '\\'])
                && (format == Some(Some(fe::FeFormat::Dmig))
                    || fe::dmig_extension(Path::new(f))) =>
        {
            (f, Some(n))
        }
        _ => (p, None),
    };
    let path = base.join(file);
    let format = match format {
        Some(f) => f,
        None => fe::detect(&path).map_err(|e| t.err(v, key, e.to_string()))?,
    };
    let Some(format) = format else {
        return Ok(None);
    };
    let default = if key == "mass" { "MAAX" } else { "KAAX" };
    let m = crate::formats::fe_read::read(&path, format, Some(name.unwrap_or(default)))?;
    Ok(Some(m))
}

fn read_matrix(
    t: &Tab<'_, '_>,
    key: &str,
    v: Val<'_, '_>,
    name: &str,
    base: &Path,
) -> Result<SparseSym> {
    match v.get_ref() {
        DeValue::String(p) => {
            // `FILE.h5[:OBJECT]` (default object: the key) or a Matrix Market file, read
            // through the binary cache.
            let p: &str = p.as_ref();
            let lower = p.to_ascii_lowercase();
            let h5 = [".h5", ".hdf5"].iter().find_map(|ext| {
                if lower.ends_with(ext) {
                    Some((p, key))
                } else {
                    lower
                        .find(&format!("{ext}:"))
                        .map(|i| (&p[..i + ext.len()], &p[i + ext.len() + 1..]))
                }
            });
            // `FILE.op4[:NAME]`: a Nastran OUTPUT4 matrix (labels from `dofs`).
            let op4 = if lower.ends_with(".op4") {
                Some((p, None))
            } else {
                lower
                    .find(".op4:")
                    .map(|i| (&p[..i + 4], Some(&p[i + 5..])))
            };
            if let Some((file, object)) = op4 {
                let path = base.join(file);
                let m = crate::formats::op4::read_op4(&path, object)?;
                let dofs = nlsim_kernel::DofMap::scalar(m.n);
                return fe::symmetric_from_entries(
                    &path,
                    &format!("{name} {}", m.name),
                    &dofs,
                    &m.entries,
                    if m.binary {
                        fe::Place::Record
                    } else {
                        fe::Place::Line
                    },
                );
            }
            match h5 {
                #[cfg(feature = "hdf5")]
                Some((file, object)) => mtx::read_hdf5_matrix(&base.join(file), object, name),
                #[cfg(not(feature = "hdf5"))]
                Some((file, _)) => Err(crate::formats::files::without_hdf5(&base.join(file))),
                None => crate::formats::cache::load_matrix_market(&base.join(p), name),
            }
        }
        DeValue::Array(rows) => {
            let mut dense = Vec::with_capacity(rows.len());
            for r in rows.iter() {
                let DeValue::Array(vals) = r.get_ref() else {
                    return Err(t.err(
                        r,
                        key,
                        "inline matrices are lists of rows: [[m11, m12], [m21, m22]]",
                    ));
                };
                let row = vals
                    .iter()
                    .map(|x| number(x).ok_or_else(|| t.err(x, key, "expected a finite number")))
                    .collect::<Result<Vec<f64>>>()?;
                if row.len() != rows.len() {
                    return Err(t.err(
                        r,
                        key,
                        format!(
                            "{name} row has {} entries, the matrix has {} rows",
                            row.len(),
                            rows.len()
                        ),
                    ));
                }
                dense.push(row);
            }
            Ok(SparseSym::from_dense_rows(name, &dense)?)
        }
        _ => Err(t.err(v, key, "expected a Matrix Market file path or inline rows")),
    }
}

fn read_damping(t: &mut Tab<'_, '_>, base: &Path, n: usize) -> Result<Damping> {
    let (kind, span) = t.str("type")?.ok_or_else(|| {
        t.missing(
            "type",
            "type = \"none\" | \"rayleigh\" | \"modal\" | \"matrix\"",
        )
    })?;
    Ok(match kind.as_str() {
        "none" => Damping::None,
        "rayleigh" => {
            if let Some(f1) = t.f64("f1_hz")? {
                let z1 = t.req_f64("zeta1", "zeta1 at f1_hz")?;
                let f2 = t.req_f64("f2_hz", "f2_hz")?;
                let z2 = t.req_f64("zeta2", "zeta2 at f2_hz")?;
                let tau = 2.0 * std::f64::consts::PI;
                Damping::rayleigh_from_two_modes(tau * f1, z1, tau * f2, z2)
                    .map_err(|e| t.doc.err(span, &t.key("f1_hz"), e.to_string()))?
            } else {
                Damping::Rayleigh {
                    alpha: t.f64("alpha")?.unwrap_or(0.0),
                    beta: t.f64("beta")?.unwrap_or(0.0),
                }
            }
        }
        "modal" => {
            let ratio = |t: &Tab<'_, '_>, x: Val<'_, '_>, key: &str| -> Result<f64> {
                let z = number(x).ok_or_else(|| t.err(x, key, "expected a number"))?;
                if (0.0..1.0).contains(&z) {
                    Ok(z)
                } else {
                    Err(t.err(x, key, format!("damping ratio {z} must lie in [0, 1)")))
                }
            };
            let mut md = ModalDamping::uniform(0.0);
            if let Some(v) = t.get("zeta") {
                match v.get_ref() {
                    DeValue::Array(a) => {
                        md.per_mode = a
                            .iter()
                            .map(|x| ratio(t, x, "zeta"))
                            .collect::<Result<_>>()?;
                    }
                    _ => md.default = ratio(t, v, "zeta")?,
                }
            }
            if let Some(v) = t.get("default") {
                md.default = ratio(t, v, "default")?;
            }
            for mut b in t.array_of_tables("bands")? {
                md.bands.push(DampingBand {
                    f_min_hz: b.req_f64("f_min_hz", "band lower edge in Hz")?,
                    f_max_hz: b.req_f64("f_max_hz", "band upper edge in Hz")?,
                    zeta: match b.get("zeta") {
                        Some(v) => ratio(&b, v, "zeta")?,
                        None => return Err(b.missing("zeta", "band damping ratio")),
                    },
                });
                b.finish("a band takes f_min_hz, f_max_hz, zeta")?;
            }
            Damping::Modal(md)
        }
        "matrix" => {
            let v = t.get("matrix").ok_or_else(|| {
                t.missing(
                    "matrix",
                    "the damping matrix (Matrix Market path or inline rows)",
                )
            })?;
            let m = read_matrix(t, "matrix", v, "damping matrix", base)?;
            if m.n() != n {
                return Err(t.err(
                    v,
                    "matrix",
                    format!(
                        "the damping matrix is {0}x{0}, the model has {n} DOFs",
                        m.n()
                    ),
                ));
            }
            Damping::Matrix(m)
        }
        other => {
            return Err(t.doc.err(
                span,
                &t.key("type"),
                format!("unknown damping type '{other}'; use none, rayleigh, modal or matrix"),
            ));
        }
    })
}

/// One `[[excitation.harmonic]]`: `order` (an integer `K` for `KΩ`, or `"1/K"` for `Ω/K`),
/// `amplitude` (N), `phase` (degrees, default 0; the fundamental's cosine is the reference).
fn read_force_harmonic(h: &mut Tab<'_, '_>) -> Result<nlsim_kernel::ForceHarmonic> {
    let what = "the harmonic's order: an integer K (the force at KΩ) or \"1/K\" (at Ω/K)";
    let (numerator, denominator) = match h.get("order") {
        None => return Err(h.missing("order", what)),
        Some(v) => {
            let text = match v.get_ref() {
                DeValue::String(s) => s.to_string(),
                DeValue::Integer(i) => i.as_str().to_string(),
                _ => return Err(h.err(v, "order", format!("expected {what}"))),
            };
            nlsim_kernel::ForceHarmonic::parse_ratio(&text).map_err(|m| h.err(v, "order", m))?
        }
    };
    let amplitude = h.req_f64("amplitude", "the harmonic's force amplitude in N")?;
    let phase = h.f64("phase")?.unwrap_or(0.0).to_radians();
    Ok(nlsim_kernel::ForceHarmonic {
        numerator,
        denominator,
        amplitude,
        phase,
    })
}

fn read_dof(t: &mut Tab<'_, '_>, key: &str, dofs: &DofMap) -> Result<Option<usize>> {
    match t.str(key)? {
        None => Ok(None),
        Some((label, span)) => dofs
            .find(&label)
            .map(Some)
            .map_err(|e| t.doc.err(span, &t.key(key), e.to_string())),
    }
}

/// A `coupled_polynomial` element: `dofs = ["1:ux", "2:ux"]` (its coordinates `u1, u2, …`, one
/// DOF each) and coefficients `k<i>_<p1>_…_<pm>` (of `u1^p1 … um^pm` in the force on `ui`).
fn read_coupled_element(
    t: &mut Tab<'_, '_>,
    name: &str,
    dofs: &DofMap,
) -> Result<NonlinearElement> {
    let v = t.get("dofs").ok_or_else(|| {
        t.missing(
            "dofs",
            "the DOFs of the coordinates u1, u2, ..., e.g. dofs = [\"1:ux\", \"2:ux\"]",
        )
    })?;
    let DeValue::Array(list) = v.get_ref() else {
        return Err(t.err(
            v,
            "dofs",
            "expected a list of DOF labels, e.g. [\"1:ux\", \"2:ux\"]",
        ));
    };
    let mut couplings = Vec::with_capacity(list.len());
    for l in list.iter() {
        let DeValue::String(label) = l.get_ref() else {
            return Err(t.err(l, "dofs", "expected DOF labels such as \"12:uz\""));
        };
        let d = dofs
            .find(label)
            .map_err(|e| t.err(l, "dofs", e.to_string()))?;
        couplings.push(Coupling::single(d));
    }
    let mut pairs: Vec<(String, f64)> = Vec::new();
    for (k, v) in t.t.iter() {
        let key = k.get_ref().as_ref();
        if matches!(key, "name" | "type" | "dofs") {
            continue;
        }
        let Some((_, powers)) = nlsim_kernel::MonomialTerm::parse_name(key) else {
            continue;
        };
        if powers.len() != couplings.len() {
            return Err(t.err(
                v,
                key,
                format!(
                    "has {} powers but the element has {} coordinates (dofs): one power per \
                     coordinate, e.g. k1_2_1 for u1^2 u2",
                    powers.len(),
                    couplings.len()
                ),
            ));
        }
        let coef = number(v).ok_or_else(|| t.err(v, key, "expected a finite number"))?;
        pairs.push((key.to_string(), coef));
        t.used.push(key.to_string());
    }
    let named: Vec<(&str, f64)> = pairs.iter().map(|(k, v)| (k.as_str(), *v)).collect();
    let law =
        Law::from_named(name, "coupled_polynomial", &named).map_err(|e| element_error(t, e))?;
    NonlinearElement::coupled(name, law, couplings).map_err(|e| element_error(t, e))
}

fn read_element(t: &mut Tab<'_, '_>, dofs: &DofMap) -> Result<NonlinearElement> {
    let (name, _) = t
        .str("name")?
        .ok_or_else(|| t.missing("name", "an element name, e.g. name = \"tip_spring\""))?;
    let (kind, kspan) = t
        .str("type")?
        .ok_or_else(|| t.missing("type", Law::KINDS))?;
    if kind == "coupled_polynomial" {
        return read_coupled_element(t, &name, dofs);
    }
    let a = read_dof(t, "dof", dofs)?
        .ok_or_else(|| t.missing("dof", "the DOF the element acts on, e.g. dof = \"21:uz\""))?;
    let coupling = match read_dof(t, "dof2", dofs)? {
        Some(b) if b == a => {
            return Err(t.missing(
                "dof2",
                "a DOF other than dof (the element acts on dof − dof2)",
            ));
        }
        Some(b) => Coupling::relative(a, b),
        None => Coupling::single(a),
    };
    let law = match kind.as_str() {
        "cubic" => Law::Cubic {
            k3: t.req_f64("k3", "k3 in N/m^3")?,
        },
        "quadratic_damping" => Law::QuadraticDamping {
            c2: t.req_f64("c2", "c2 in N s^2/m^2")?,
        },
        "coulomb" => Law::Coulomb {
            fc: t.req_f64("fc", "fc (slip force) in N")?,
            v_reg: t.f64("v_reg")?.unwrap_or(1e-3),
        },
        "jenkins" => Law::Jenkins {
            kt: t.req_f64("kt", "kt (stick stiffness) in N/m")?,
            fs: t.req_f64("fs", "fs (slip force) in N")?,
        },
        "power_spring" => Law::PowerSpring {
            k: t.req_f64("k", "k in N/m^p (g = k |u|^p sign u)")?,
            p: t.req_f64("p", "p, the exponent (>= 1)")?,
        },
        "power_damper" => Law::PowerDamper {
            c: t.req_f64("c", "c in N (s/m)^p (g = c |v|^p sign v)")?,
            p: t.req_f64("p", "p, the exponent (>= 1)")?,
        },
        "iwan" => {
            let mut named = vec![
                ("fs", t.req_f64("fs", "fs (macroslip force) in N")?),
                (
                    "kt",
                    t.req_f64("kt", "kt (stiffness of the stuck joint) in N/m")?,
                ),
                (
                    "chi",
                    t.req_f64("chi", "chi, the slider exponent (-1 < chi <= 1)")?,
                ),
                (
                    "beta",
                    t.req_f64("beta", "beta >= 0, the share of the macroslip Dirac")?,
                ),
            ];
            for key in ["sliders", "decades"] {
                if let Some(v) = t.f64(key)? {
                    named.push((key, v));
                }
            }
            Law::from_named(&name, "iwan", &named).map_err(|e| element_error(t, e))?
        }
        "bump_stop" => Law::bump_stop(
            t.req_f64("k", "k (contact stiffness) in N/m")?,
            t.req_f64("gap", "gap in m")?,
        ),
        "clearance" => Law::Clearance {
            k1: t.req_f64("k1", "k1 in N/m^r")?,
            k2: t.f64("k2")?.unwrap_or(0.0),
            e1: t.req_f64("e1", "e1 (gap) in m")?,
            e2: t.f64("e2")?.unwrap_or(0.0),
            r: t.f64("r")?.unwrap_or(1.0),
            s: t.f64("s")?.unwrap_or(1.0),
        },
        "polynomial" => {
            let mut stiffness = Vec::new();
            let mut damping = Vec::new();
            for (k, v) in t.t.iter() {
                let key = k.get_ref().as_ref();
                let (prefix, rest) = key.split_at(1.min(key.len()));
                let Ok(power) = rest.parse::<u32>() else {
                    continue;
                };
                let coef = number(v).ok_or_else(|| t.err(v, key, "expected a finite number"))?;
                match prefix {
                    "k" => stiffness.push(PolyTerm { power, coef }),
                    "c" => damping.push(PolyTerm { power, coef }),
                    _ => continue,
                }
                t.used.push(key.to_string());
            }
            Law::Polynomial { stiffness, damping }
        }
        other => {
            return Err(t.doc.err(
                kspan,
                &t.key("type"),
                format!("unknown element type '{other}'; use {}", Law::KINDS),
            ));
        }
    };
    NonlinearElement::new(name, law, coupling).map_err(|e| element_error(t, e))
}

/// An element's model error at the offending parameter's own line when the file gives it,
/// otherwise at the element's table.
fn element_error(t: &Tab<'_, '_>, e: nlsim_kernel::Error) -> Error {
    if let nlsim_kernel::Error::InvalidParameter { name, .. } = &e
        && let Some((_, p)) = name.rsplit_once('.')
        && let Some((k, v)) = t.t.iter().find(|(k, _)| k.get_ref().as_ref() == p)
    {
        return t
            .doc
            .err(k.span().start..v.span().end, &t.key(p), e.to_string());
    }
    t.doc.err(t.span.clone(), &t.path, e.to_string())
}
