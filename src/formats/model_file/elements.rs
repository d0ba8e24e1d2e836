//! Elements, excitation harmonics and labels of a model file: `[[element]]` of every law,
//! `coupled_polynomial`, `[[excitation.harmonic]]`, and DOF or point labels.

use super::toml::{Tab, number};
use crate::error::{Error, Result};
use nlsim_kernel::{Coupling, Law, Model, NonlinearElement, PolyTerm, Site};
use toml::de::DeValue;

/// One `[[excitation.harmonic]]`: `order` (an integer `K` for `KΩ`, or `"1/K"` for `Ω/K`),
/// `amplitude` (N), `phase` (degrees, default 0; the fundamental's cosine is the reference).
pub(super) fn read_force_harmonic(h: &mut Tab<'_, '_>) -> Result<nlsim_kernel::ForceHarmonic> {
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

/// The DOF labelled by `key`, if given.
pub(super) fn read_dof(t: &mut Tab<'_, '_>, key: &str, model: &Model) -> Result<Option<usize>> {
    match t.str(key)? {
        None => Ok(None),
        Some((label, span)) => model
            .dofs()
            .find(&label)
            .map(Some)
            .map_err(|e| t.doc.err(span, &t.key(key), e.to_string())),
    }
}

/// `name` (or `default`) and the required labelled `dof` of an excitation or sensor: a DOF,
/// or a point of a modal model.
pub(super) fn name_and_site(
    t: &mut Tab<'_, '_>,
    default: String,
    model: &Model,
    what: &str,
) -> Result<(String, Site)> {
    let name = t.str("name")?.map_or(default, |s| s.0);
    let site = read_site(t, "dof", model)?
        .ok_or_else(|| t.missing("dof", &format!("{what}, e.g. dof = \"21:uz\"")))?;
    Ok((name, site))
}

/// The site labelled by `key`, if given: a DOF, a point of a modal model, or its modal
/// coordinate `modeN` (see [`Model::site`]).
pub(super) fn read_site(t: &mut Tab<'_, '_>, key: &str, model: &Model) -> Result<Option<Site>> {
    match t.str(key)? {
        None => Ok(None),
        Some((label, span)) => model
            .site(&label)
            .map(Some)
            .map_err(|e| t.doc.err(span, &t.key(key), e.to_string())),
    }
}

/// A `coupled_polynomial` element: `dofs = ["1:ux", "2:ux"]` (its coordinates `u1, u2, …`, one
/// DOF each) and coefficients `k<i>_<p1>_…_<pm>` (of `u1^p1 … um^pm` in the force on `ui`).
fn read_coupled_element(
    t: &mut Tab<'_, '_>,
    name: &str,
    model: &Model,
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
        let site = model
            .site(label)
            .map_err(|e| t.err(l, "dofs", e.to_string()))?;
        couplings.push(site.coupling());
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

/// One `[[element]]` of any law, on DOFs or (in a modal model) points and modal coordinates.
pub(super) fn read_element(t: &mut Tab<'_, '_>, model: &Model) -> Result<NonlinearElement> {
    let (name, _) = t
        .str("name")?
        .ok_or_else(|| t.missing("name", "an element name, e.g. name = \"tip_spring\""))?;
    let (kind, kspan) = t
        .str("type")?
        .ok_or_else(|| t.missing("type", Law::KINDS))?;
    if kind == "coupled_polynomial" {
        return read_coupled_element(t, &name, model);
    }
    let a = read_site(t, "dof", model)?
        .ok_or_else(|| t.missing("dof", "the DOF the element acts on, e.g. dof = \"21:uz\""))?;
    let coupling = match read_site(t, "dof2", model)? {
        Some(b) => Coupling::difference(&a.coupling(), &b.coupling()).ok_or_else(|| {
            t.missing(
                "dof2",
                "a DOF (or point) that moves unlike dof (the element acts on dof − dof2)",
            )
        })?,
        None => a.coupling(),
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
