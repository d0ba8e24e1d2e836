//! A readable summary of a model, for `nlsim check` and the demo.

use nlsim_kernel::{Component, Damping, Model, Parameterized, ValidationReport};
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
    let _ = writeln!(
        s,
        "  DOFs         {} on {} nodes ({})",
        model.n_dofs(),
        nodes.len(),
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
    let damping = match model.damping() {
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
            c.dofs()
                .iter()
                .zip(c.weights())
                .map(|(&d, &w)| {
                    if w == 1.0 {
                        dofs.describe(d)
                    } else if w == -1.0 {
                        format!("-{}", dofs.describe(d))
                    } else {
                        format!("{w}*{}", dofs.describe(d))
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
            dofs.describe(x.dof),
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
                dofs.describe(x.dof)
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
         stiffness_scale: parameters of the reduced model (--set, --param)"
    );
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

#[cfg(test)]
mod counted_tests {
    #[test]
    fn one_is_singular() {
        assert_eq!(super::counted(1, "parameter"), "1 parameter");
        assert_eq!(super::counted(0, "fold"), "0 folds");
        assert_eq!(super::counted(12, "step"), "12 steps");
    }
}
