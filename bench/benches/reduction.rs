//! Reduction benchmarks on the hexahedral bracket at about 10⁵ DOFs (refinement 6: 95 904 DOFs,
//! consistent mass): the sparse Cholesky of `K` alone (the part ARPACK + a direct solver also
//! pays), and the lowest 50 and 200 modes by shift-invert block Lanczos, with and without the
//! Sturm check. The time split (analysis / factorisation / iteration / checks) of each solve
//! is printed once before timing. `NLSIM_BENCH_DOFS` picks another size.
//!
//! `NLSIM_BENCH_ROWS="4:50 4:200 6:50 6:200 9:50"` (bracket refinement : modes) instead times
//! those solves, with the Sturm check: nlsim's column of the reduction table in BENCHMARKS.md,
//! whose other column is `bench/scipy/table.sh` (which also times both sides as processes).
//!
//! Run with `cargo bench -p nlsim-bench --bench reduction -- --quick --noplot`.

use criterion::{Criterion, criterion_group, criterion_main};
use nlsim_fixtures::bracket::BracketConfig;
use nlsim_reduction::{EigenConfig, EigenSolver, ModeSelection, ShiftedPencil};
use std::hint::black_box;
use std::time::Duration;

fn bracket() -> nlsim_kernel::Model {
    let dofs = std::env::var("NLSIM_BENCH_DOFS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(100_000);
    let cfg = BracketConfig {
        lumped_mass: false,
        ..BracketConfig::for_target_dofs(dofs)
    };
    nlsim_fixtures::bracket_fixture(&cfg, "none")
        .expect("bracket fixture")
        .model
}

fn reduction(c: &mut Criterion) {
    if let Ok(rows) = std::env::var("NLSIM_BENCH_ROWS") {
        return table(c, &rows);
    }
    let model = bracket();
    let (k, m) = (model.stiffness(), model.mass());
    let n = model.n_dofs();
    let mut g = c.benchmark_group("reduction");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(1));
    g.measurement_time(Duration::from_secs(1));
    let pencil = ShiftedPencil::new(k, m).expect("analysis");
    g.bench_function(format!("cholesky_{n}"), |b| {
        b.iter(|| black_box(pencil.cholesky(0.0).expect("factor").expect("definite")))
    });
    for (count, sturm) in [(50, true), (50, false), (200, true)] {
        let name = format!("lanczos_{n}_{count}{}", if sturm { "" } else { "_nosturm" });
        modes(&mut g, &name, k, m, count, sturm);
    }
    g.finish();
}

/// One timed solve of the lowest `count` modes, its time split printed first.
fn modes(
    g: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
    name: &str,
    k: &nlsim_kernel::SparseSym,
    m: &nlsim_kernel::SparseSym,
    count: usize,
    sturm: bool,
) {
    let n = k.n();
    let cfg = EigenConfig {
        selection: ModeSelection::Lowest(count),
        sturm_check: sturm,
        ..EigenConfig::default()
    };
    let modes = EigenSolver::new().solve(k, m, &cfg).expect("modes");
    let s = &modes.stats;
    eprintln!(
        "{n} DOFs, {count} modes, Sturm {sturm}: analysis {:.2} s, factor {:.2} s, \
         iteration {:.2} s ({} solves, {} restarts), checks {:.2} s, residual {:.1e}",
        s.analysis_seconds,
        s.factor_seconds,
        s.iteration_seconds,
        s.operator_applications,
        s.restarts,
        s.check_seconds,
        s.max_residual
    );
    g.bench_function(name, |b| {
        b.iter(|| black_box(EigenSolver::new().solve(k, m, &cfg).expect("modes")))
    });
}

/// The rows of `NLSIM_BENCH_ROWS`: `refinement:modes` pairs separated by spaces or commas.
fn table(c: &mut Criterion, rows: &str) {
    let mut g = c.benchmark_group("reduction_table");
    g.sample_size(10);
    g.warm_up_time(Duration::from_millis(1));
    g.measurement_time(Duration::from_secs(1));
    let mut built: Option<(usize, nlsim_kernel::Model)> = None;
    for row in rows.split([' ', ',']).filter(|r| !r.is_empty()) {
        let parsed = row
            .split_once(':')
            .and_then(|(r, k)| Some((r.parse::<usize>().ok()?, k.parse::<usize>().ok()?)));
        let Some((refinement, count)) = parsed else {
            panic!("NLSIM_BENCH_ROWS: `{row}` is not REFINEMENT:MODES");
        };
        if built.as_ref().is_none_or(|(r, _)| *r != refinement) {
            // The previous model goes before the next is built.
            drop(built.take());
            let cfg = BracketConfig {
                refinement,
                clamped: true,
                lumped_mass: false,
            };
            let model = nlsim_fixtures::bracket_fixture(&cfg, "none")
                .expect("bracket fixture")
                .model;
            built = Some((refinement, model));
        }
        let (_, model) = built.as_ref().expect("built above");
        let (k, m) = (model.stiffness(), model.mass());
        modes(
            &mut g,
            &format!("lanczos_{}_{count}", model.n_dofs()),
            k,
            m,
            count,
            true,
        );
    }
    g.finish();
}

criterion_group!(benches, reduction);
criterion_main!(benches);
