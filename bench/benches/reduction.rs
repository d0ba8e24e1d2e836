//! Reduction benchmarks on the hexahedral bracket at about 10⁵ DOFs (refinement 6: 95 904 DOFs,
//! consistent mass): the sparse Cholesky of `K` alone (the part ARPACK + a direct solver also
//! pays), and the lowest 50 and 200 modes by shift-invert block Lanczos, with and without the
//! Sturm check. The time split (analysis / factorisation / iteration / checks) of each solve
//! is printed once before timing. `NLSIM_BENCH_DOFS` picks another size.
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
        let name = format!("lanczos_{n}_{count}{}", if sturm { "" } else { "_nosturm" });
        g.bench_function(name, |b| {
            b.iter(|| black_box(EigenSolver::new().solve(k, m, &cfg).expect("modes")))
        });
    }
    g.finish();
}

criterion_group!(benches, reduction);
criterion_main!(benches);
