//! The `[modal]` table: a test-based modal model (natural frequencies, damping ratios and
//! mode-shape entries at named points, measured residual flexibilities), no M or K.

use super::toml::{Tab, number};
use crate::error::Result;
use nlsim_kernel::{Coupling, DofLabel, Model, ResidualTerm, TestMode};
use std::ops::Range;
use toml::de::DeValue;

/// A `[[modal.residual]]` entry read before the ports it names exist: checked once the
/// elements, excitation and sensors are read.
pub(super) struct PendingResidual {
    /// The term.
    pub term: ResidualTerm,
    /// Where it is written.
    pub span: Range<usize>,
    /// Its dotted key path (`modal.residual[1]`).
    pub path: String,
}

/// Largest magnitude of a `[modal]` value: the model squares frequencies and multiplies shape
/// entries in pairs, and 10¹⁵⁰ squared still is a finite, normal f64 (as 10⁻¹⁵⁰ is).
const MODAL_MAX: f64 = 1e150;

/// Whether `v` is 0 or of a magnitude in [1/[`MODAL_MAX`], [`MODAL_MAX`]].
fn representable(v: f64) -> bool {
    v == 0.0 || (1.0 / MODAL_MAX..=MODAL_MAX).contains(&v.abs())
}

/// The message for a value [`representable`] refuses.
fn out_of_range(v: f64) -> String {
    format!(
        "{}: out of range; a modal value is 0 or of a magnitude from 1e-150 to 1e150 (its \
         products and squares must stay finite)",
        crate::formats::files::number(v)
    )
}

/// Reads `[modal]`: `points`, `[[modal.mode]]` (`f_hz`, `zeta`, `shape`, optional `m`) and
/// `[[modal.residual]]` (`ports`, `flexibility`).
pub(super) fn read_modal(t: &mut Tab<'_, '_>, name: &str) -> Result<(Model, Vec<PendingResidual>)> {
    let points = read_points(t)?;
    let mut modes = Vec::new();
    let mut shapes: Vec<Vec<f64>> = Vec::new();
    let tables = t.array_of_tables("mode")?;
    if tables.is_empty() {
        return Err(t.missing(
            "mode",
            "[[modal.mode]] tables, one per mode: f_hz, zeta and shape (one entry per point)",
        ));
    }
    for mut m in tables {
        let frequency_hz = m.req_f64("f_hz", "the mode's natural frequency in Hz")?;
        let zeta = m.req_f64("zeta", "the mode's damping ratio, e.g. zeta = 0.002")?;
        for (key, v) in [("f_hz", frequency_hz), ("zeta", zeta)] {
            if !representable(v) {
                let at = m.get(key).expect("read above");
                return Err(m.err(at, key, out_of_range(v)));
            }
        }
        let shape_val = m.get("shape").ok_or_else(|| {
            m.missing(
                "shape",
                &format!(
                    "the mode-shape entries at the points [{}], one number each",
                    points
                        .iter()
                        .map(|p| p.0.to_string())
                        .collect::<Vec<_>>()
                        .join(", ")
                ),
            )
        })?;
        let DeValue::Array(list) = shape_val.get_ref() else {
            return Err(m.err(
                shape_val,
                "shape",
                "expected a list of numbers, one per point",
            ));
        };
        if list.len() != points.len() {
            return Err(m.err(
                shape_val,
                "shape",
                format!(
                    "{} entries for {} points (modal.points): one entry per point, in order",
                    list.len(),
                    points.len()
                ),
            ));
        }
        let mut shape = Vec::with_capacity(list.len());
        for x in list.iter() {
            let v = number(x).ok_or_else(|| m.err(x, "shape", "expected a finite number"))?;
            if !representable(v) {
                return Err(m.err(x, "shape", out_of_range(v)));
            }
            shape.push(v);
        }
        if let Some(v) = m.get("m") {
            let mass = number(v).ok_or_else(|| m.err(v, "m", "expected a finite number"))?;
            if !representable(mass) {
                return Err(m.err(v, "m", out_of_range(mass)));
            }
            if mass <= 0.0 {
                return Err(m.err(
                    v,
                    "m",
                    format!("the modal mass {mass} kg of the shape as written must be > 0"),
                ));
            }
            shape.iter_mut().for_each(|s| *s /= mass.sqrt());
        }
        m.finish("a mode takes f_hz, zeta, shape and m")?;
        let mode = TestMode { frequency_hz, zeta };
        // Checked here, so that an error is at the mode's own table.
        mode.check(modes.len(), modes.last())
            .map_err(|e| m.at_table(e))?;
        modes.push(mode);
        shapes.push(shape);
    }
    let mut model = Model::modal(name, &modes).map_err(|e| t.at_table(e))?;
    for (p, (label, span)) in points.iter().enumerate() {
        let terms: Vec<(usize, f64)> = shapes
            .iter()
            .enumerate()
            .filter(|(_, s)| s[p] != 0.0)
            .map(|(r, s)| (r, s[p]))
            .collect();
        let coupling = Coupling::weighted(&terms).map_err(|_| {
            t.doc.err(
                span.clone(),
                &t.key("points"),
                format!("point {label} has a zero shape entry in every mode: no mode moves it"),
            )
        })?;
        model
            .add_point(*label, coupling)
            .map_err(|e| t.doc.err(span.clone(), &t.key("points"), e.to_string()))?;
    }
    let mut pending = Vec::new();
    for mut r in t.array_of_tables("residual")? {
        let v = r.get("ports").ok_or_else(|| {
            r.missing(
                "ports",
                "the two ports (element, excitation or sensor names), e.g. ports = [\"shaker\", \
                 \"accel\"]",
            )
        })?;
        let names: Option<Vec<String>> = match v.get_ref() {
            DeValue::Array(a) if a.len() == 2 => a
                .iter()
                .map(|x| match x.get_ref() {
                    DeValue::String(s) => Some(s.to_string()),
                    _ => None,
                })
                .collect(),
            _ => None,
        };
        let Some(names) = names else {
            return Err(r.err(
                v,
                "ports",
                "expected two port names (element, excitation or sensor), e.g. [\"shaker\", \
                 \"accel\"]",
            ));
        };
        let flexibility = r.req_f64("flexibility", "the residual flexibility in m/N")?;
        if !representable(flexibility) {
            let at = r.get("flexibility").expect("read above");
            return Err(r.err(at, "flexibility", out_of_range(flexibility)));
        }
        let term =
            ResidualTerm::new(&names[0], &names[1], flexibility).map_err(|e| r.at_table(e))?;
        r.finish("a residual term takes ports and flexibility")?;
        pending.push(PendingResidual {
            term,
            span: r.span.clone(),
            path: r.path.clone(),
        });
    }
    Ok((model, pending))
}

/// `points = ["1:uz", "31:uz"]`: the labels the shape entries belong to.
fn read_points(t: &mut Tab<'_, '_>) -> Result<Vec<(DofLabel, Range<usize>)>> {
    let v = t.get("points").ok_or_else(|| {
        t.missing(
            "points",
            "the measured points the shapes are given at, e.g. points = [\"1:uz\", \"31:uz\"]",
        )
    })?;
    let DeValue::Array(list) = v.get_ref() else {
        return Err(t.err(v, "points", "expected a list of labels such as \"31:uz\""));
    };
    if list.is_empty() {
        return Err(t.err(v, "points", "needs at least one point"));
    }
    let mut out: Vec<(DofLabel, Range<usize>)> = Vec::with_capacity(list.len());
    for x in list.iter() {
        let DeValue::String(s) = x.get_ref() else {
            return Err(t.err(x, "points", "expected labels such as \"31:uz\""));
        };
        let label: DofLabel = s
            .parse()
            .map_err(|e: nlsim_kernel::Error| t.err(x, "points", e.to_string()))?;
        if out.iter().any(|(l, _)| *l == label) {
            return Err(t.err(x, "points", format!("point {label} is listed twice")));
        }
        out.push((label, x.span()));
    }
    Ok(out)
}

/// Checks each pending residual term's ports against `model`'s ports and adds it.
pub(super) fn add_residuals(
    t: &Tab<'_, '_>,
    model: &mut Model,
    pending: Vec<PendingResidual>,
) -> Result<()> {
    let mut ports: Vec<String> = Vec::new();
    for e in model.elements() {
        for j in 0..e.couplings().len() {
            ports.push(nlsim_reduction::modal::element_port_name(e, j));
        }
    }
    ports.extend(model.excitation().iter().map(|x| x.name.clone()));
    ports.extend(model.sensors().iter().map(|s| s.name.clone()));
    for p in pending {
        for name in [&p.term.a, &p.term.b] {
            if !ports.iter().any(|q| q == name) {
                return Err(t.doc.err(
                    p.span.clone(),
                    &format!("{}.ports", p.path),
                    format!(
                        "'{name}' is not a port of the model; its ports: {}",
                        ports.join(", ")
                    ),
                ));
            }
        }
        model
            .add_residual(p.term)
            .map_err(|e| t.doc.err(p.span.clone(), &p.path, e.to_string()))?;
    }
    Ok(())
}
