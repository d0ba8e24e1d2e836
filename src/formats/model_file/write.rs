//! Writing a test-based modal model file (`[modal]`): what `nlsim export --modal` makes of an
//! FE model's modes, read back by [`super::parse_model_file`].

use crate::error::{Error, Result};
use crate::formats::files::toml_string as text;
use nlsim_kernel::{Law, NonlinearElement, Quantity};
use std::fmt::Write;

/// One mode of a modal model file.
#[derive(Debug, Clone, PartialEq)]
pub struct ModeEntry {
    /// Natural frequency (Hz).
    pub frequency_hz: f64,
    /// Damping ratio.
    pub zeta: f64,
    /// Mass-normalised shape entries at the file's points (m/√kg).
    pub shape: Vec<f64>,
}

/// The contents of a `[modal]` model file.
#[derive(Debug, Clone)]
pub struct ModalFile {
    /// Model name.
    pub name: String,
    /// Comment lines written at the top (without `#`).
    pub comments: Vec<String>,
    /// Point labels, in shape-entry order.
    pub points: Vec<String>,
    /// The modes, ascending.
    pub modes: Vec<ModeEntry>,
    /// Residual flexibilities `(port a, port b, m/N)`.
    pub residual: Vec<(String, String, f64)>,
    /// Elements with the labels of their coordinates: `[dof]`, `[dof, dof2]` (acting on
    /// `dof − dof2`), or one per coordinate of a coupled law.
    pub elements: Vec<(NonlinearElement, Vec<String>)>,
    /// Excitations `(name, point, amplitude N, further harmonics)`.
    pub excitation: Vec<(String, String, f64, Vec<nlsim_kernel::ForceHarmonic>)>,
    /// Sensors `(name, point, quantity)`.
    pub sensors: Vec<(String, String, Quantity)>,
    /// Coordinates of the points' nodes `(node, [x, y, z])` (m), written as `[geometry]`
    /// when any is known.
    pub geometry: Vec<(u64, [f64; 3])>,
}

/// A TOML number that reads back to the same `f64` (Rust's shortest round-trip form).
fn num(x: f64) -> String {
    format!("{x:e}")
}

/// The model-file keys and values of a law, in the order the file reader takes them; an error
/// when the law has no model-file form that reads back to itself.
fn law_pairs(e: &NonlinearElement) -> Result<Vec<(String, f64)>> {
    let law = e.law();
    let mut pairs: Vec<(String, f64)> = (0..law.n_params())
        .map(|i| (law.param_name(i), law.param(i)))
        .collect();
    if let Law::Iwan { grid, .. } = law {
        pairs.push(("sliders".into(), grid.sliders() as f64));
        pairs.push(("decades".into(), grid.decades()));
    }
    let named: Vec<(&str, f64)> = pairs.iter().map(|(k, v)| (k.as_str(), *v)).collect();
    match Law::from_named(e.name(), law.kind(), &named) {
        Ok(back) if &back == law => Ok(pairs),
        _ => Err(Error::Usage(format!(
            "element '{}' ({}) has no model-file form that reads back to the same law",
            e.name(),
            law.kind()
        ))),
    }
}

/// The file's text. Numbers are written in full precision, so the model read back is the
/// one written.
pub fn modal_model_text(f: &ModalFile) -> Result<String> {
    let mut s = String::new();
    for c in &f.comments {
        let _ = writeln!(s, "# {c}");
    }
    let _ = writeln!(s, "name = {}", text(&f.name));
    let _ = writeln!(s, "\n[modal]");
    let points: Vec<String> = f.points.iter().map(|p| text(p)).collect();
    let _ = writeln!(s, "points = [{}]", points.join(", "));
    for m in &f.modes {
        let shape: Vec<String> = m.shape.iter().map(|&x| num(x)).collect();
        let _ = writeln!(
            s,
            "\n[[modal.mode]]\nf_hz = {}\nzeta = {}\nshape = [{}]",
            num(m.frequency_hz),
            num(m.zeta),
            shape.join(", ")
        );
    }
    for (a, b, x) in &f.residual {
        let _ = writeln!(
            s,
            "\n[[modal.residual]]\nports = [{}, {}]\nflexibility = {}",
            text(a),
            text(b),
            num(*x)
        );
    }
    for (e, at) in &f.elements {
        let _ = writeln!(
            s,
            "\n[[element]]\nname = {}\ntype = {}",
            text(e.name()),
            text(e.law().kind())
        );
        if e.is_coupled() {
            let labels: Vec<String> = at.iter().map(|l| text(l)).collect();
            let _ = writeln!(s, "dofs = [{}]", labels.join(", "));
        } else {
            let _ = writeln!(s, "dof = {}", text(&at[0]));
            if let Some(b) = at.get(1) {
                let _ = writeln!(s, "dof2 = {}", text(b));
            }
        }
        for (k, v) in law_pairs(e)? {
            let _ = writeln!(s, "{k} = {}", num(v));
        }
    }
    for (name, at, amplitude, harmonics) in &f.excitation {
        let _ = writeln!(
            s,
            "\n[[excitation]]\nname = {}\ndof = {}\namplitude = {}",
            text(name),
            text(at),
            num(*amplitude)
        );
        for h in harmonics {
            let _ = writeln!(
                s,
                "[[excitation.harmonic]]\norder = {}\namplitude = {}\nphase = {}",
                text(&h.ratio_text()),
                num(h.amplitude),
                num(h.phase.to_degrees())
            );
        }
    }
    for (name, at, q) in &f.sensors {
        let _ = writeln!(
            s,
            "\n[[sensor]]\nname = {}\ndof = {}\nquantity = {}",
            text(name),
            text(at),
            text(q.as_str())
        );
    }
    if !f.geometry.is_empty() {
        let nodes: Vec<String> = f
            .geometry
            .iter()
            .map(|(n, [x, y, z])| format!("[{n}, {}, {}, {}]", num(*x), num(*y), num(*z)))
            .collect();
        let _ = writeln!(s, "\n[geometry]\nnodes = [{}]", nodes.join(", "));
    }
    Ok(s)
}
