//! `nlsim modes`: the modes solved with a progress line, the mode table on the terminal, the
//! modes file (through [`crate::formats::modes_file`]) and the report folder.
use crate::error::Result;
use crate::formats::modes_file::ModeReport;
use crate::formats::modes_file::write_group;
use nlsim_kernel::Model;
use nlsim_reduction::{EigenConfig, EigenMethod};
use std::fmt::Write as _;
use std::path::Path;

/// The mode table and a line on how the solve went, as aligned text.
pub fn format_table(r: &ModeReport) -> String {
    let mut s = String::new();
    let f = r.modes.frequencies_hz();
    let _ = write!(
        s,
        "  {:>5} {:>14} {:>10}",
        "mode", "frequency Hz", "damping"
    );
    for e in &r.effective {
        let _ = write!(s, " {:>9}", format!("meff {}", e.component));
    }
    let _ = writeln!(s, " {:>10}", "residual");
    for i in 0..r.modes.len() {
        let _ = write!(s, "  {:>5} {:>14.6} {:>10.5}", i + 1, f[i], r.damping[i]);
        for e in &r.effective {
            let _ = write!(s, " {:>8.2}%", 100.0 * e.per_mode[i] / e.total);
        }
        let _ = writeln!(s, " {:>10.2e}", r.modes.residuals[i]);
    }
    for e in &r.effective {
        let sum: f64 = e.per_mode.iter().sum();
        let _ = writeln!(
            s,
            "  effective mass {}: {:.2}% of {:.6} kg in these modes",
            e.component,
            100.0 * sum / e.total,
            e.total
        );
    }
    if let nlsim_reduction::ModeSelection::Lowest(asked) = r.config.selection
        && let Some(note) = crate::commands::setup::cluster_note(r.modes.len(), asked)
    {
        let _ = writeln!(s, "  {note}");
    }
    let st = &r.modes.stats;
    match st.method {
        EigenMethod::Dense => {
            let _ = writeln!(
                s,
                "  solver: dense (a small model, or most of its spectrum), {:.3} s",
                st.iteration_seconds + st.check_seconds
            );
        }
        EigenMethod::Lanczos => {
            let _ = writeln!(
                s,
                "  solver: shift-invert block Lanczos, shift {:.4e} rad²/s², block {}, basis {}, \
                 {} restarts, {} solves, factor {:.1} M values ({} ordering{})",
                st.shift,
                st.block_size,
                st.basis_size,
                st.restarts,
                st.operator_applications,
                st.factor_nnz as f64 * 1e-6,
                match st.ordering {
                    Some(nlsim_reduction::Ordering::NestedDissection) => "nested-dissection",
                    _ => "AMD",
                },
                if st.factor_released {
                    "; Sturm check in its storage"
                } else {
                    ""
                }
            );
            let _ = writeln!(
                s,
                "  time: analysis {:.2} s, factorisation {:.2} s, iteration {:.2} s, checks {:.2} s",
                st.analysis_seconds, st.factor_seconds, st.iteration_seconds, st.check_seconds
            );
            if let Some((count, at)) = st.sturm {
                let hz = |v: f64| v.max(0.0).sqrt() / (2.0 * std::f64::consts::PI);
                // What the counts prove: below --fmax, the count there (which set how many
                // modes to find) and the one just above the last found together cover the
                // whole range; for the lowest N, the range up to the last found.
                let certified = st.status.is_converged() && count == r.modes.len();
                let _ = match r.config.selection {
                    _ if !certified => writeln!(
                        s,
                        "  Sturm check: {count} eigenvalues below {:.6} Hz, {} found: modes \
                         may be missing ({})",
                        hz(at),
                        r.modes.len(),
                        st.detail
                    ),
                    nlsim_reduction::ModeSelection::Below { f_max_hz } => writeln!(
                        s,
                        "  Sturm check: {count} eigenvalues below {f_max_hz} Hz, as found (counted \
                         at {f_max_hz} Hz before the iteration and at {:.6} Hz after it): no mode \
                         below {f_max_hz} Hz is missing",
                        hz(at)
                    ),
                    nlsim_reduction::ModeSelection::Lowest(_) => writeln!(
                        s,
                        "  Sturm check: {count} eigenvalues below {:.6} Hz, as found: no mode \
                         below the last one is missing (modes above it are not counted)",
                        hz(at)
                    ),
                };
            }
        }
    }
    let _ = writeln!(s, "  largest backward error {:.2e}", st.max_residual);
    s
}

/// The mode table for a report: mode, frequency, damping ratio, effective mass per direction
/// (% of the total), residual.
pub fn table(r: &ModeReport) -> crate::present::report::Table {
    let mut header: Vec<String> = ["mode", "frequency (Hz)", "damping ratio"]
        .map(String::from)
        .to_vec();
    for e in &r.effective {
        header.push(format!(
            "eff. mass {} (% of {:.4} kg)",
            e.component, e.total
        ));
    }
    header.push("backward error".into());
    let f = r.modes.frequencies_hz();
    let rows = (0..r.modes.len())
        .map(|i| {
            let mut row = vec![
                format!("{}", i + 1),
                format!("{:.6}", f[i]),
                format!("{:.5}", r.damping[i]),
            ];
            for e in &r.effective {
                row.push(format!("{:.2}", 100.0 * e.per_mode[i] / e.total));
            }
            row.push(format!("{:.2e}", r.modes.residuals[i]));
            row
        })
        .collect();
    crate::present::report::Table {
        caption: format!(
            "{} modes: frequencies, damping and effective masses",
            r.modes.len()
        ),
        header,
        rows,
    }
}

/// The report of `nlsim modes --report DIR`: the table and the solver's account as text, the
/// mode table, the frequencies and effective masses as figures, and the modes (shapes
/// included) in `report.h5` in the layout of mode files. `command_line` goes into the
/// provenance. Returns the page's path.
pub fn write_report(
    dir: &Path,
    model_spec: &str,
    model: &Model,
    r: &ModeReport,
    command_line: &str,
) -> Result<std::path::PathBuf> {
    let report = crate::present::report::Report::create(
        dir,
        &format!("nlsim modes: {}", model.name()),
        command_line,
        model_spec,
    )?;
    report.model_name(model.name());
    report.section("Modes");
    for line in format_table(r).lines() {
        report.say(line);
    }
    report.table("modes", table(r))?;
    let f = r.modes.frequencies_hz();
    report.figure(
        "frequencies",
        &crate::present::plot::Lines {
            title: format!("{}: natural frequencies", model.name()),
            x_desc: "mode".into(),
            y_desc: "frequency (Hz)".into(),
            series: vec![(
                "natural frequency".into(),
                f.iter()
                    .enumerate()
                    .map(|(i, &v)| ((i + 1) as f64, v))
                    .collect(),
            )],
        },
    )?;
    if !r.effective.is_empty() && !r.modes.is_empty() {
        report.figure(
            "effective_mass",
            &crate::present::plot::Bars {
                title: format!("{}: effective mass per mode", model.name()),
                bar_desc: "mode".into(),
                y_desc: "effective mass (% of the total)".into(),
                baseline: 0.0,
                baseline_desc: String::new(),
                band_desc: String::new(),
                groups: r
                    .effective
                    .iter()
                    .map(|e| crate::present::plot::BarGroup {
                        label: format!("direction {}", e.component),
                        values: e.per_mode.iter().map(|m| 100.0 * m / e.total).collect(),
                        band: None,
                    })
                    .collect(),
            },
        )?;
    }
    report.data(|root| write_group(root, model, r))?;
    report.finish()
}

/// What `nlsim modes` computes and writes.
#[derive(Debug, Clone)]
pub struct ModesRequest {
    /// The model (file or built-in name).
    pub model: String,
    /// The lowest `count` modes (default: 10, or every mode of a smaller model).
    pub count: Option<usize>,
    /// Every mode below this frequency (Hz); takes precedence over `count`.
    pub fmax_hz: Option<f64>,
    /// Convergence tolerance of the eigen solver (relative residual).
    pub tol: f64,
    /// Lanczos block size.
    pub block: usize,
    /// Lanczos basis, restarts, ordering and memory budget.
    pub lanczos: crate::commands::setup::Lanczos,
    /// Whether the Sturm count certifies that no mode was missed.
    pub sturm_check: bool,
    /// Parallelism of the factorisations and products.
    pub par: faer::Par,
    /// The modes file (`.h5` or `.csv`).
    pub out: Option<std::path::PathBuf>,
    /// The report folder.
    pub report: Option<std::path::PathBuf>,
}

/// Solves for the modes with a progress line (`modes: converged/wanted after n restart(s)`).
pub fn solve(
    model: &Model,
    cfg: EigenConfig,
    console: &crate::present::console::Console,
) -> Result<ModeReport> {
    let t = std::time::Instant::now();
    let mut solver = nlsim_reduction::EigenSolver::new();
    let modes = solver
        .solve_with_progress(model.stiffness(), model.mass(), &cfg, &mut |p| {
            if console.shows_progress() {
                console.progress(&format!(
                    "  modes: {}/{} converged after {} restart(s), {:.1} s ",
                    p.converged,
                    p.wanted,
                    p.restart,
                    t.elapsed().as_secs_f64()
                ));
            }
        })
        .and_then(nlsim_reduction::Modes::into_converged);
    if modes
        .as_ref()
        .is_ok_and(|m| m.stats.method == EigenMethod::Lanczos)
    {
        console.progress_end();
    }
    let modes = modes?;
    indefinite(model, &modes)?;
    Ok(ModeReport::new(model, modes, cfg))
}

/// Refuses modes of an indefinite stiffness: an eigenvalue `ω² < 0` beyond round-off (below
/// −1e-8 of `max Kᵢᵢ / max Mᵢᵢ`, a bound of the spectrum's scale; the rigid-body eigenvalues of
/// a free–free model are ±1e-16 of it) would print as a 0 Hz mode with meaningless damping.
fn indefinite(model: &Model, modes: &nlsim_reduction::Modes) -> Result<()> {
    let largest =
        |m: &nlsim_kernel::SparseSym| (0..m.n()).fold(0.0f64, |a, i| a.max(m.get(i, i).abs()));
    let scale = largest(model.stiffness()) / largest(model.mass()).max(f64::MIN_POSITIVE);
    match modes.eigenvalues.iter().position(|&l| l < -1e-8 * scale) {
        None => Ok(()),
        Some(i) => Err(nlsim_kernel::Error::NotDefinite {
            matrix: "stiffness matrix".into(),
            required: "positive semi-definite".into(),
            detail: format!(
                "mode {} has eigenvalue ω² = {:.4e} rad²/s² ({:.1e} of the scale max Kii / max \
                 Mii = {scale:.3e}), a mode without a frequency; `nlsim check` finds where (a \
                 negative spring or element sign?)",
                i + 1,
                modes.eigenvalues[i],
                modes.eigenvalues[i] / scale
            ),
        }
        .into()),
    }
}

/// `nlsim modes MODEL`: the modes, the table on the terminal, the modes file and the report.
pub fn execute(req: &ModesRequest, console: &crate::present::console::Console) -> Result<()> {
    if let Some(path) = &req.out {
        // Refuse an unknown format before the (possibly long) solve.
        crate::formats::files::Format::of_any(path, crate::formats::modes_file::HINT, true)?;
    }
    crate::formats::files::check_outputs(
        &[Some(std::path::Path::new(&req.model))],
        &[req.out.as_deref()],
        &[req.report.as_deref()],
    )?;
    let loaded = crate::load_model(&req.model)?;
    let selection = match (req.count, req.fmax_hz) {
        (_, Some(f)) => nlsim_reduction::ModeSelection::Below { f_max_hz: f },
        (Some(c), None) => nlsim_reduction::ModeSelection::Lowest(c),
        // The default: 10 modes, or every mode of a smaller model.
        (None, None) => nlsim_reduction::ModeSelection::Lowest(10.min(loaded.model.n_dofs())),
    };
    let cfg = EigenConfig {
        selection,
        tol: req.tol,
        block_size: req.block,
        basis_size: req.lanczos.basis,
        max_restarts: req.lanczos.restarts,
        ordering: req.lanczos.ordering,
        memory_budget: req.lanczos.memory_budget,
        sturm_check: req.sturm_check,
        par: req.par,
        ..EigenConfig::default()
    };
    // Symmetry, finiteness, massless DOFs; definiteness shows in the factorisation.
    loaded.model.validate(&nlsim_kernel::ValidationConfig {
        check_definiteness: false,
        ..Default::default()
    })?;
    let report = solve(&loaded.model, cfg, console)?;
    console.say(&crate::present::summary::model_summary(
        &loaded.model,
        &loaded.source,
        None,
    ));
    console.say_part(&format_table(&report));
    if let Some(path) = &req.out {
        crate::formats::modes_file::write_modes(path, &req.model, &loaded.model, &report)?;
        console.say(&format!("  written to {}", path.display()));
    }
    if let Some(dir) = &req.report {
        crate::formats::guard::write_folder(dir, |dir| {
            write_report(
                dir,
                &req.model,
                &loaded.model,
                &report,
                &crate::present::report::command_line(),
            )
        })?;
        console.say(&format!(
            "  report {}",
            dir.join(crate::present::report::PAGE).display()
        ));
    }
    Ok(())
}
