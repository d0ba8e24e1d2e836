//! A readable summary of a model, for `nlsim check` and the demo.

use nlsim_kernel::{Component, Coupling, Damping, Model, Parameterized, Site, ValidationReport};
use std::fmt::Write;

/// Formats the summary of `model` (and of its validation, when given) as aligned text.
pub fn model_summary(model: &Model, source: &str, validation: Option<&ValidationReport>) -> String {
    let mut s = String::new();
    let dofs = model.dofs();
    let mut nodes: Vec<u64> = dofs.labels().iter().map(|l| l.node).collect();
    nodes.sort_unstable();
    nodes.dedup();
    let mut comps: Vec<Component> = dofs.labels().iter().map(|l| l.component).collect();
    comps.sort_unstable();
    comps.dedup();
    let comp_list: Vec<&str> = comps.iter().map(|c| c.as_str()).collect();
    let _ = writeln!(s, "  model        {}  ({source})", model.name());
    if model.is_modal() {
        modal_lines(model, &mut s);
    } else {
        fe_lines(model, &comps, nodes.len(), &comp_list, &mut s);
    }
    let damping = match model.damping() {
        Damping::Modal(_) if model.is_modal() => "each mode's zeta".to_string(),
        Damping::None => "none".to_string(),
        Damping::Rayleigh { alpha, beta } => {
            format!("Rayleigh, alpha = {alpha:.4e} 1/s, beta = {beta:.4e} s")
        }
        Damping::Modal(m) if m.per_mode.is_empty() && m.bands.is_empty() => {
            format!("modal, zeta = {} for every mode", m.default)
        }
        Damping::Modal(m) => format!(
            "modal, {} per-mode ratios, {} bands, default {}",
            m.per_mode.len(),
            m.bands.len(),
            m.default
        ),
        Damping::Matrix(v) => format!("explicit matrix, {} stored entries", v.nnz()),
    };
    let _ = writeln!(s, "  damping      {damping}");
    if model.elements().is_empty() {
        let _ = writeln!(s, "  elements     none (a linear model)");
    }
    for (i, e) in model.elements().iter().enumerate() {
        let coordinate = |c: &nlsim_kernel::Coupling| -> String {
            if let Some(named) = point_coordinate(model, c) {
                return named;
            }
            c.dofs()
                .iter()
                .zip(c.weights())
                .map(|(&d, &w)| {
                    let d = model.describe_site(&Site::Dof(d));
                    if w == 1.0 {
                        d
                    } else if w == -1.0 {
                        format!("-{d}")
                    } else {
                        format!("{w}*{d}")
                    }
                })
                .collect::<Vec<_>>()
                .join(" + ")
        };
        let at = if e.is_coupled() {
            let c: Vec<String> = e
                .couplings()
                .iter()
                .enumerate()
                .map(|(j, c)| format!("u{} = {}", j + 1, coordinate(c)))
                .collect();
            c.join(", ")
        } else {
            coordinate(e.coupling())
        };
        let params: Vec<String> = (0..e.law().n_params())
            .map(|p| {
                format!(
                    "{} = {:.4e} {}",
                    e.law().param_name(p),
                    e.law().param(p),
                    e.law().param_unit(p)
                )
            })
            .collect();
        let head = if i == 0 {
            "  elements     "
        } else {
            "               "
        };
        let _ = writeln!(
            s,
            "{head}{} ({}) on {}: {}",
            e.name(),
            e.law().kind(),
            at,
            params.join(", ")
        );
    }
    for (i, x) in model.excitation().iter().enumerate() {
        let head = if i == 0 {
            "  excitation   "
        } else {
            "               "
        };
        let more: String = x
            .harmonics
            .iter()
            .map(|h| {
                let at = match (h.numerator, h.denominator) {
                    (1, 1) => "Ω".to_string(),
                    (p, 1) => format!("{p}Ω"),
                    (1, q) => format!("Ω/{q}"),
                    (p, q) => format!("{p}Ω/{q}"),
                };
                format!(
                    " + {} N at {at} (phase {:.1}°)",
                    h.amplitude,
                    h.phase.to_degrees()
                )
            })
            .collect();
        let _ = writeln!(
            s,
            "{head}{} at {}, {} N{more}",
            x.name,
            model.describe_site(&x.at),
            x.amplitude
        );
    }
    for (i, g) in model.groups().iter().enumerate() {
        let head = if i == 0 {
            "  groups       "
        } else {
            "               "
        };
        let parts: Vec<String> = [("K_g", g.stiffness()), ("M_g", g.mass())]
            .into_iter()
            .filter_map(|(w, m)| m.map(|m| format!("{w} {} stored entries", m.nnz())))
            .collect();
        let _ = writeln!(s, "{head}{}: {}", g.name(), parts.join(", "));
    }
    if !model.boundary_springs().is_empty() {
        let springs: Vec<String> = model
            .boundary_springs()
            .iter()
            .map(|&(d, k)| format!("{} {k:.4e} N/m", dofs.describe(d)))
            .collect();
        let _ = writeln!(s, "  springs      {}", springs.join(", "));
    }
    let sensors: Vec<String> = model
        .sensors()
        .iter()
        .map(|x| {
            format!(
                "{} ({} at {})",
                x.name,
                x.quantity.as_str(),
                model.describe_site(&x.at)
            )
        })
        .collect();
    let _ = writeln!(
        s,
        "  sensors      {}",
        if sensors.is_empty() {
            "none".into()
        } else {
            sensors.join(", ")
        }
    );
    let p = model.parameters();
    let _ = writeln!(
        s,
        "  parameters   {}",
        if p.is_empty() {
            "none".into()
        } else {
            p.iter()
                .map(ToString::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        }
    );
    // The reduced model's parameters exist once the model is reduced; `--set` and
    // `--param` take them as well.
    let _ = writeln!(
        s,
        "  reduced      modeN.f (Hz), modeN.zeta, modeN.m (kg) of every retained mode N, \
         stiffness_scale{}: parameters of the reduced model (--set, --param)",
        if model.is_modal() {
            ", the residual terms residual:A:B (m/N) and the shape entries modeN.shape:POINT \
             (m/sqrt(kg)) of every mode and point"
        } else {
            ""
        }
    );
    if let (Some(first), Some(last)) = (model.geometry().first(), model.geometry().last()) {
        let _ = writeln!(
            s,
            "  geometry     {} with coordinates (nodes {} to {}): written as dataset 2411 of \
             universal files",
            counted(model.geometry().len(), "node"),
            first.0,
            last.0
        );
    }
    if let Some(v) = validation {
        let _ = writeln!(
            s,
            "  validation   finite, symmetric (worst relative asymmetry {:.1e}){}",
            v.max_asymmetry,
            if v.definiteness_checked {
                ", M positive definite, K positive semi-definite"
            } else {
                " (definiteness not checked)"
            }
        );
    }
    s
}

/// `n` and a noun, singular for one: `counted(1, "parameter")` is `1 parameter`,
/// `counted(3, "parameter")` is `3 parameters` (nouns taking `-s`).
pub fn counted(n: usize, noun: &str) -> String {
    if n == 1 {
        format!("1 {noun}")
    } else {
        format!("{n} {noun}s")
    }
}

/// The DOF, mass and stiffness lines of an FE model.
fn fe_lines(model: &Model, comps: &[Component], nodes: usize, comp_list: &[&str], s: &mut String) {
    let _ = writeln!(
        s,
        "  DOFs         {} on {nodes} nodes ({})",
        model.n_dofs(),
        comp_list.join(" ")
    );
    let _ = writeln!(s, "  mass         {} stored entries", model.mass().nnz());
    let masses: Vec<String> = [Component::Ux, Component::Uy, Component::Uz, Component::U]
        .into_iter()
        .filter(|c| comps.contains(c))
        .map(|c| format!("{c} {:.4} kg", model.translational_mass(c)))
        .collect();
    if !masses.is_empty() {
        let _ = writeln!(
            s,
            "               rigid-body mass along {}",
            masses.join(", ")
        );
    }
    let _ = writeln!(
        s,
        "  stiffness    {} stored entries",
        model.stiffness().nnz()
    );
}

/// The modes, points and residual terms of a test-based modal model.
fn modal_lines(model: &Model, s: &mut String) {
    let tau = 2.0 * std::f64::consts::PI;
    let zeta = |r: usize, f: f64| match model.damping() {
        Damping::Modal(m) => m.zeta(r, f),
        _ => 0.0,
    };
    let modes: Vec<String> = (0..model.n_dofs())
        .map(|r| {
            let (rows, vals) = model.stiffness().col(r);
            let k = rows
                .iter()
                .zip(vals)
                .find(|(i, _)| **i == r)
                .map_or(0.0, |(_, v)| *v);
            let f = k.max(0.0).sqrt() / tau;
            format!("mode{} {f:.4} Hz (zeta {})", r + 1, zeta(r, f))
        })
        .collect();
    let _ = writeln!(
        s,
        "  modal        a test-based modal model, {} mode{}: {}",
        model.n_dofs(),
        if model.n_dofs() == 1 { "" } else { "s" },
        modes.join(", ")
    );
    let points: Vec<String> = model.points().iter().map(|(l, _)| l.to_string()).collect();
    let _ = writeln!(s, "  points       {}", points.join(", "));
    for (i, t) in model.residual_terms().iter().enumerate() {
        let head = if i == 0 {
            "  residual     "
        } else {
            "               "
        };
        let _ = writeln!(s, "{head}{} - {}: {:.4e} m/N", t.a, t.b, t.flexibility);
    }
}

/// A coordinate of a modal model named by its points: `31:uz`, or `31:uz - 1:uz`.
fn point_coordinate(model: &Model, c: &Coupling) -> Option<String> {
    let points = model.points();
    model.point_terms(c).first().map(|terms| {
        terms
            .iter()
            .map(|&(i, _)| points[i].0.to_string())
            .collect::<Vec<_>>()
            .join(" - ")
    })
}

#[cfg(test)]
mod counted_tests {
    #[test]
    fn one_is_singular() {
        assert_eq!(super::counted(1, "parameter"), "1 parameter");
        assert_eq!(super::counted(0, "fold"), "0 folds");
        assert_eq!(super::counted(12, "step"), "12 steps");
    }
}
