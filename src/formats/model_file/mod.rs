//! Model files (TOML) and the `MODEL` argument of every command.
//!
//! `MODEL` is either the path of a model file or a built-in model name, optionally with
//! options: `ecl_beam`, `bracket:refinement=4,nonlinear=bump_stop`. The model file format is
//! documented in `docs/model-files.md`; every error names the file, the line and the key.

mod elements;
mod geometry;
mod modal;
mod toml;
pub mod write;

pub use self::toml::toml_message;
use self::toml::{Doc, Tab, Val, number};
use crate::error::{Error, Result};
use crate::formats::fe_matrices as fe;
use ::toml::de::{DeTable, DeValue};
use elements::{name_and_site, read_dof, read_element, read_force_harmonic};
use nlsim_kernel::{
    Damping, DampingBand, DofLabel, DofMap, Excitation, ModalDamping, Model, Quantity, Sensor,
    SparseSym,
};
use std::path::Path;

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
    /// What reading the matrices did that `nlsim check` reports (e.g. mirrors of a matrix
    /// stored in full averaged, with the largest difference).
    pub notes: Vec<String>,
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
        notes: Vec::new(),
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
    let modal_table = top.sub("modal")?;
    let matrices_table = top.sub("matrices")?;
    let mut residuals = Vec::new();
    let mut notes = Vec::new();
    let (mut model, description, references, from_fixture) = match (modal_table, matrices_table) {
        (Some(md), Some(_)) => {
            return Err(doc.err(
                md.span.clone(),
                "modal",
                "a model has [matrices] (an FE model) or [modal] (a test-based modal model), \
                 not both",
            ));
        }
        (Some(mut md), None) => {
            let (model, pending) = modal::read_modal(&mut md, &name)?;
            md.finish("[modal] takes points, [[modal.mode]] and [[modal.residual]]")?;
            residuals = pending;
            (model, None, Vec::new(), false)
        }
        (None, Some(mut mats)) => {
            let read = read_matrices(&mut mats, &name, &base_dir, &mut notes)?;
            mats.finish(
                "[matrices] takes fixture and options, or mass, stiffness, dofs and format",
            )?;
            read
        }
        (None, None) => {
            return Err(top.missing(
                "matrices",
                "a [matrices] table (fixture = ..., or mass/stiffness), or a [modal] table (a \
                 test-based modal model)",
            ));
        }
    };

    if let Some(mut d) = top.sub("damping")? {
        if model.is_modal() {
            return Err(doc.err(
                d.span.clone(),
                "damping",
                "a [modal] model's damping is each mode's zeta: remove [damping]",
            ));
        }
        let damping = read_damping(&mut d, &base_dir, model.n_dofs())?;
        let span = d.span.clone();
        d.finish("see docs/model-files.md for the keys of each damping type")?;
        model
            .set_damping(damping)
            .map_err(|e| doc.err(span, "damping", e.to_string()))?;
    }

    let fe_only = nlsim_kernel::site::NO_FE_MATRICES;
    for mut g in top.array_of_tables("group")? {
        if model.is_modal() {
            return Err(doc.err(g.span.clone(), &g.path, fe_only));
        }
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
                Some(fe::FeMatrix::Labelled(m)) => {
                    m.onto(model.dofs(), &label, fe::SYMMETRY_TOLERANCE)?
                }
                // A file that numbers its equations numbers them as the model's.
                Some(fe::FeMatrix::Numbered(m)) => m
                    .labelled(model.dofs().labels(), "the model's DOFs")?
                    .onto(model.dofs(), &label, fe::SYMMETRY_TOLERANCE)?,
                None => read_matrix(
                    &g,
                    key,
                    v,
                    &label,
                    &base_dir,
                    fe::SYMMETRY_TOLERANCE,
                    &mut Vec::new(),
                )?,
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
        if model.is_modal() {
            return Err(doc.err(s.span.clone(), &s.path, fe_only));
        }
        let dof = read_dof(&mut s, "dof", &model)?
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
        let el = read_element(&mut e, &model)?;
        e.finish(if el.is_coupled() {
            "a coupled_polynomial element takes name, type, dofs and coefficients \
             k<i>_<p1>_..._<pm> (one power per coordinate)"
        } else {
            "an element takes name, type, dof, dof2 and the parameters of its type"
        })?;
        model.add_element(el).map_err(|err| e.at_table(err))?;
    }
    for (i, mut x) in excitation.into_iter().enumerate() {
        let (name, at) = name_and_site(
            &mut x,
            format!("force{}", i + 1),
            &model,
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
                at,
                amplitude,
                harmonics,
            })
            .map_err(|err| x.at_table(err))?;
    }
    for (i, mut s) in sensors.into_iter().enumerate() {
        let (name, at) = name_and_site(
            &mut s,
            format!("sensor{}", i + 1),
            &model,
            "the measured DOF",
        )?;
        let quantity = match s.str("quantity")? {
            None => Quantity::Acceleration,
            Some((q, sp)) => {
                Quantity::parse(&q).map_err(|e| doc.err(sp, &s.key("quantity"), e.to_string()))?
            }
        };
        s.finish("a sensor takes name, dof, quantity")?;
        model
            .add_sensor(Sensor { name, at, quantity })
            .map_err(|err| s.at_table(err))?;
    }
    modal::add_residuals(&top, &mut model, residuals)?;
    if let Some(mut g) = top.sub("geometry")? {
        let nodes = geometry::read_geometry(&mut g, &base_dir)?;
        g.finish("[geometry] takes nodes")?;
        model.set_geometry(nodes).map_err(|e| g.at_table(e))?;
    }
    top.finish("the top level takes name, units, [matrices] or [modal], [damping], [[group]], [[spring]], [[element]], [[excitation]], [[sensor]], [geometry]")?;
    Ok(LoadedModel {
        model,
        source: file.display().to_string(),
        description,
        references,
        notes,
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

fn read_matrices(
    t: &mut Tab<'_, '_>,
    name: &str,
    base: &Path,
    notes: &mut Vec<String>,
) -> Result<Matrices> {
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
    // How far an entry and its mirror may differ (relative to their columns' largest
    // magnitude) in files that store both triangles.
    let tolerance = match t.f64("symmetry_tolerance")? {
        None => fe::SYMMETRY_TOLERANCE,
        Some(x) if (0.0..=1e-3).contains(&x) => x,
        Some(x) => {
            return Err(t.doc.err(
                t.span.clone(),
                &t.key("symmetry_tolerance"),
                format!(
                    "{x:e}: give a relative tolerance from 0 (mirrors equal to the bit) to 1e-3"
                ),
            ));
        }
    };
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
    let mixed = mass_fe.is_some() != stiff_fe.is_some();
    if let (Some(m), Some(k)) = (mass_fe, stiff_fe) {
        // The labels come from the files (every DOF either matrix names), or, for files
        // that number their equations only, from `dofs`.
        let order = |f: &fe::FeMatrix| match f {
            fe::FeMatrix::Numbered(n) => Some((n.n, n.kind.clone(), n.path.clone())),
            fe::FeMatrix::Labelled(_) => None,
        };
        let numbered = order(&m).into_iter().chain(order(&k)).max_by_key(|o| o.0);
        // The equations' labels when a file numbers them (none needed otherwise).
        let (labels, source) = match (numbered, t.get("dofs")) {
            (None, Some(v)) => {
                return Err(t.err(
                    v,
                    "dofs",
                    "DMIG, 5-column Abaqus and Harwell-Boeing (with its mapping) matrices label \
                     their DOFs themselves: leave `dofs` out",
                ));
            }
            (None, None) => (Vec::new(), String::new()),
            (Some((_, kind, path)), None) => {
                return Err(t.missing(
                    "dofs",
                    &format!(
                        "{} is {kind}: its equations need labels; give dofs = the job's \
                         input file (\"job.inp\"), Ansys's mapping vector, a labels file or a \
                         list",
                        path.display()
                    ),
                ));
            }
            (Some((n, _, _)), Some(v)) => dof_labels(t, v, base, n)?,
        };
        let with = |f: fe::FeMatrix| match f {
            fe::FeMatrix::Numbered(x) => x.labelled(&labels, &source),
            fe::FeMatrix::Labelled(x) => Ok(x),
        };
        let (m, k) = (with(m)?, with(k)?);
        let dofs = fe::union_dofs(&[&k, &m]).map_err(|e| {
            t.doc
                .err(t.span.clone(), &t.key("stiffness"), e.to_string())
        })?;
        let (mass, dm) = m.onto_measured(&dofs, "mass matrix", tolerance)?;
        let (stiffness, dk) = k.onto_measured(&dofs, "stiffness matrix", tolerance)?;
        notes.extend(fe::asymmetry_note(
            "stiffness matrix",
            &k.path,
            dk,
            tolerance,
        ));
        notes.extend(fe::asymmetry_note("mass matrix", &m.path, dm, tolerance));
        let model = Model::new(name, dofs, mass, stiffness).map_err(|e| {
            t.doc
                .err(t.span.clone(), &t.key("stiffness"), e.to_string())
        })?;
        return Ok((model, None, vec![], false));
    }
    if mixed {
        return Err(t.err(
            stiff_v,
            "stiffness",
            "give mass and stiffness both from FE-code files (DMIG, Abaqus, Harwell-Boeing), \
             or both as Matrix Market, HDF5, OUTPUT4 or inline rows with `dofs`",
        ));
    }
    let mass = read_matrix(t, "mass", mass_v, "mass matrix", base, tolerance, notes)?;
    let stiffness = read_matrix(
        t,
        "stiffness",
        stiff_v,
        "stiffness matrix",
        base,
        tolerance,
        notes,
    )?;
    let dofs = match t.get("dofs") {
        None => DofMap::scalar(mass.n()),
        Some(v) => {
            let (labels, _) = dof_labels(t, v, base, mass.n())?;
            DofMap::new(labels).map_err(|e| t.err(v, "dofs", e.to_string()))?
        }
    };
    let model = Model::new(name, dofs, mass, stiffness)
        .map_err(|e| t.doc.err(t.span.clone(), &t.key("dofs"), e.to_string()))?;
    Ok((model, None, vec![], false))
}

/// The labels of `n` equations from `dofs` (`v`): a file (labels, an Abaqus `.inp`, Ansys's
/// mapping vector: [`crate::formats::equations::equation_labels`]) or an inline list, with
/// where they came from for errors.
fn dof_labels(
    t: &Tab<'_, '_>,
    v: Val<'_, '_>,
    base: &Path,
    n: usize,
) -> Result<(Vec<DofLabel>, String)> {
    match v.get_ref() {
        DeValue::String(p) => {
            let path = base.join(p.as_ref());
            let labels = crate::formats::equations::equation_labels(&path, n)?;
            Ok((labels, path.display().to_string()))
        }
        DeValue::Array(a) => {
            let labels = a
                .iter()
                .map(|l| match l.get_ref() {
                    DeValue::String(s) => s
                        .parse::<DofLabel>()
                        .map_err(|e| t.err(l, "dofs", e.to_string())),
                    _ => Err(t.err(l, "dofs", "expected DOF labels such as \"12:uz\"")),
                })
                .collect::<Result<Vec<_>>>()?;
            Ok((labels, t.key("dofs")))
        }
        _ => Err(t.err(v, "dofs", "expected a file path or a list of DOF labels")),
    }
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
) -> Result<Option<fe::FeMatrix>> {
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
    tolerance: f64,
    notes: &mut Vec<String>,
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
                use crate::formats::op4::Op4Role;
                // Without a name, a file of several matrices gives the one of the standard
                // name for the key's role (KAAX, KXX, …; MAAX, MXX, …).
                let role = match key {
                    "stiffness" => Op4Role::Stiffness,
                    "mass" => Op4Role::Mass,
                    _ => Op4Role::Any,
                };
                let m = crate::formats::op4::read_op4(&path, object, role)?;
                let dofs = nlsim_kernel::DofMap::scalar(m.n);
                let what = format!("{name} {}", m.name);
                let (matrix, largest) = fe::symmetric_measured(
                    &path,
                    &what,
                    &dofs,
                    &m.entries,
                    if m.binary {
                        fe::Place::Record
                    } else {
                        fe::Place::Line
                    },
                    tolerance,
                )?;
                notes.extend(fe::asymmetry_note(&what, &path, largest, tolerance));
                return Ok(matrix);
            }
            match h5 {
                #[cfg(feature = "hdf5")]
                Some((file, object)) => {
                    crate::formats::matrices::read_hdf5_matrix(&base.join(file), object, name)
                }
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
            let m = read_matrix(
                t,
                "matrix",
                v,
                "damping matrix",
                base,
                fe::SYMMETRY_TOLERANCE,
                &mut Vec::new(),
            )?;
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
