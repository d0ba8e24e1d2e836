//! `nlsim export MODEL DIR --modal N`: an FE model as a test-based modal model file — its
//! lowest modes at the points its elements, forces and sensors use, their damping ratios, and
//! the residual flexibility of the truncated modes at its ports — so that the modal model
//! reproduces the FE model's reduction (thesis eq. 10) and can stand in for a test's modal
//! model in every command.

use crate::error::{Error, Result};
use crate::formats::model_file::write::{ModalFile, ModeEntry, modal_model_text};
use crate::present::console::Console;
use nlsim_kernel::{Coupling, DofMap, Model};
use nlsim_reduction::{ReductionConfig, reduce};
use std::path::Path;

/// The labels of an element coordinate: `[dof]` for `u = q_d`, `[a, b]` for `u = q_a − q_b`.
fn coordinate_labels(dofs: &DofMap, c: &Coupling, what: &str) -> Result<Vec<String>> {
    match (c.dofs(), c.weights()) {
        ([d], [w]) if *w == 1.0 => Ok(vec![dofs.describe(*d)]),
        ([a, b], [wa, wb]) if *wa == 1.0 && *wb == -1.0 => {
            Ok(vec![dofs.describe(*a), dofs.describe(*b)])
        }
        _ => Err(Error::Usage(format!(
            "{what} acts on a weighted combination of DOFs, which a modal model file cannot \
             name (one DOF, or the difference of two)"
        ))),
    }
}

/// Builds the modal model file of `model` with its lowest `modes` modes.
pub fn modal_file(model: &Model, modes: usize) -> Result<(ModalFile, Vec<String>)> {
    if model.is_modal() {
        return Err(Error::Usage(format!(
            "'{}' is already a modal model: --modal exports an FE model's modes",
            model.name()
        )));
    }
    let dofs = model.dofs();
    let mut points: Vec<String> = Vec::new();
    let mut point_dofs: Vec<usize> = Vec::new();
    let mut add = |d: usize, points: &mut Vec<String>| {
        if !point_dofs.contains(&d) {
            point_dofs.push(d);
            points.push(dofs.describe(d));
        }
    };
    let mut elements = Vec::new();
    for e in model.elements() {
        let mut labels = Vec::new();
        for c in e.couplings() {
            let l = coordinate_labels(dofs, c, &format!("element '{}'", e.name()))?;
            if e.is_coupled() && l.len() != 1 {
                return Err(Error::Usage(format!(
                    "element '{}': a coordinate of a coupled law on two DOFs cannot be written",
                    e.name()
                )));
            }
            for &d in c.dofs() {
                add(d, &mut points);
            }
            labels.extend(l);
        }
        elements.push((e.clone(), labels));
    }
    let mut excitation = Vec::new();
    for x in model.excitation() {
        let d = x.at.dof().unwrap_or(0);
        add(d, &mut points);
        excitation.push((
            x.name.clone(),
            x.at.describe(dofs),
            x.amplitude,
            x.harmonics.clone(),
        ));
    }
    let mut sensors = Vec::new();
    for s in model.sensors() {
        let d = s.at.dof().unwrap_or(0);
        add(d, &mut points);
        sensors.push((s.name.clone(), s.at.describe(dofs), s.quantity));
    }
    if points.is_empty() {
        return Err(Error::Usage(format!(
            "'{}' has no element, excitation or sensor: a modal model is written at the points \
             they use",
            model.name()
        )));
    }
    let reduced = reduce(model, &ReductionConfig::lowest(modes))?;
    let damping = reduced.modal_damping_matrix();
    let mut notes = Vec::new();
    let n = reduced.n_modes();
    let coupled = (0..n).any(|r| (0..n).any(|s| r != s && damping[(r, s)] != 0.0));
    if coupled {
        notes.push(
            "the damping couples the modes; the modal model keeps each mode's own (the \
             diagonal of the projected damping)"
                .to_string(),
        );
    }
    let tau = 2.0 * std::f64::consts::PI;
    let entries: Vec<ModeEntry> = (0..n)
        .map(|r| {
            let w = reduced.modes.eigenvalues[r].max(0.0).sqrt();
            ModeEntry {
                frequency_hz: w / tau,
                zeta: if w > 0.0 {
                    damping[(r, r)] / (2.0 * w)
                } else {
                    0.0
                },
                shape: point_dofs
                    .iter()
                    .map(|&d| reduced.modes.vectors[(d, r)])
                    .collect(),
            }
        })
        .collect();
    let mut residual = Vec::new();
    let np = reduced.ports.len();
    for i in 0..np {
        for j in i..np {
            let x = reduced.residual[(i, j)];
            if x != 0.0 {
                residual.push((
                    reduced.ports[i].name.clone(),
                    reduced.ports[j].name.clone(),
                    x,
                ));
            }
        }
    }
    let file = ModalFile {
        name: format!("{}_modal", model.name()),
        comments: vec![
            format!(
                "The lowest {n} modes of '{}' at the points its elements, forces and sensors \
                 use, written by `nlsim export --modal {modes}`.",
                model.name()
            ),
            "Shapes are mass-normalised (m/sqrt(kg)); [[modal.residual]] holds the residual \
             flexibility of the truncated modes at the ports (m/N)."
                .to_string(),
        ],
        geometry: {
            let mut nodes: Vec<u64> = points
                .iter()
                .filter_map(|p| p.parse::<nlsim_kernel::DofLabel>().ok())
                .map(|l| l.node)
                .collect();
            nodes.sort_unstable();
            nodes.dedup();
            nodes
                .into_iter()
                .filter_map(|n| model.node_coordinates(n).map(|xyz| (n, xyz)))
                .collect()
        },
        points,
        modes: entries,
        residual,
        elements,
        excitation,
        sensors,
    };
    Ok((file, notes))
}

/// Writes `DIR/modal.toml` for `spec`'s lowest `modes` modes.
pub fn export_modal(spec: &str, dir: &Path, modes: usize, console: &Console) -> Result<()> {
    let loaded = crate::load_model(spec)?;
    let (file, notes) = modal_file(&loaded.model, modes)?;
    let text = modal_model_text(&file)?;
    std::fs::create_dir_all(dir).map_err(|source| Error::Io {
        path: dir.to_path_buf(),
        source,
    })?;
    let path = dir.join("modal.toml");
    crate::formats::files::write_text_atomically(&path, &text)?;
    for n in notes {
        console.say(&format!("  note: {n}"));
    }
    console.say(&format!(
        "wrote {} ({} modes at {} points, {} residual terms)",
        path.display(),
        file.modes.len(),
        file.points.len(),
        file.residual.len()
    ));
    Ok(())
}
