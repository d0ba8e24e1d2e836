//! `nlsim check`, `nlsim fixtures` and `nlsim export`: a model validated and summarised, the
//! built-in models listed, a model's matrices written as Matrix Market with its DOF labels.

use crate::error::Result;
use crate::present::console::Console;
use std::path::Path;

/// `nlsim check MODEL`: validates the model (definiteness by a factorisation unless
/// `check_definiteness` is off) and prints its summary.
pub fn check(spec: &str, check_definiteness: bool, console: &Console) -> Result<()> {
    let loaded = crate::load_model(spec)?;
    let cfg = nlsim_kernel::ValidationConfig {
        check_definiteness,
        ..Default::default()
    };
    let report = loaded.model.validate(&cfg)?;
    console.say_part(&crate::present::summary::model_summary(
        &loaded.model,
        &loaded.source,
        Some(&report),
    ));
    for note in &loaded.notes {
        console.say(note);
    }
    Ok(())
}

/// The files of `nlsim export` written into `dir`; returns their names for the summary.
fn export_files(
    m: &nlsim_kernel::Model,
    dir: &Path,
    op4: Option<crate::formats::op4_write::Op4Layout>,
) -> Result<String> {
    let labels: String = (0..m.n_dofs())
        .map(|i| m.dofs().describe(i) + "\n")
        .collect();
    for (name, text) in [
        (
            "K.mtx",
            crate::formats::matrices::to_matrix_market(m.stiffness()),
        ),
        (
            "M.mtx",
            crate::formats::matrices::to_matrix_market(m.mass()),
        ),
        ("dofs.txt", labels),
    ] {
        crate::formats::files::write_text_atomically(&dir.join(name), &text)?;
    }
    let mut wrote = "K.mtx, M.mtx, dofs.txt".to_string();
    if !m.geometry().is_empty() {
        // What `[geometry] nodes = "nodes.csv"` reads back, every bit kept.
        let mut text = String::from("node,x,y,z\n");
        for (n, [x, y, z]) in m.geometry() {
            text.push_str(&format!("{n},{x:e},{y:e},{z:e}\n"));
        }
        crate::formats::files::write_text_atomically(&dir.join("nodes.csv"), &text)?;
        wrote.push_str(", nodes.csv");
    }
    if let Some(layout) = op4 {
        let bytes = crate::formats::op4_write::to_op4(
            &[("KAAX", m.stiffness()), ("MAAX", m.mass())],
            layout,
        );
        crate::formats::files::write_bytes_atomically(&dir.join("matrices.op4"), &bytes)?;
        wrote.push_str(", matrices.op4");
    }
    Ok(wrote)
}

/// `nlsim fixtures`: the built-in models with their options.
pub fn fixtures(console: &Console) {
    for f in nlsim_fixtures::CATALOGUE {
        console.always(&format!("{:<26} {}", f.name, f.summary));
        for (k, d) in f.options {
            console.always(&format!("    {k:<20} {d}"));
        }
    }
}

/// `nlsim export MODEL DIR`: `K.mtx`, `M.mtx` and `dofs.txt`, `nodes.csv` when the model has
/// coordinates (`node,x,y,z`, as `[geometry]` reads it), and with `op4` also
/// `matrices.op4` (KAAX and MAAX in that OUTPUT4 layout), each written atomically (a killed
/// export or a full disk leaves no truncated file under the final name).
pub fn export(
    spec: &str,
    dir: &Path,
    op4: Option<crate::formats::op4_write::Op4Layout>,
    console: &Console,
) -> Result<()> {
    // The folder is planned (and locked) first, so that a model whose files lie in it is
    // refused as they are read, before anything is written.
    crate::formats::files::check_outputs(&[Some(Path::new(spec))], &[], &[Some(dir)])?;
    let loaded = crate::load_model(spec)?;
    let m = &loaded.model;
    let wrote = crate::formats::guard::write_folder(dir, |dir| export_files(m, dir, op4))?;
    console.say(&format!(
        "wrote {wrote} ({} DOFs) to {}",
        m.n_dofs(),
        dir.display()
    ));
    Ok(())
}
