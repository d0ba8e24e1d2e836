//! Kernel benchmarks: nonlinear element evaluation (the inner loop of every integrator and
//! AFT step), assembly of the hexahedral bracket, and model validation (two sparse Cholesky
//! factorisations).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use nlsim_bench::BRACKET_REFINEMENTS;
use nlsim_fixtures::bracket::{Bracket, BracketConfig};
use nlsim_kernel::{Law, ValidationConfig};
use std::hint::black_box;

fn element_eval(c: &mut Criterion) {
    let laws = [
        ("cubic", Law::Cubic { k3: 6e9 }),
        ("polynomial", nlsim_fixtures::hardening_softening_law()),
        (
            "clearance",
            Law::Clearance {
                k1: 2e5,
                k2: 1e5,
                e1: 1e-3,
                e2: 1e-3,
                r: 1.5,
                s: 1.0,
            },
        ),
        (
            "coulomb",
            Law::Coulomb {
                fc: 5.0,
                v_reg: 1e-3,
            },
        ),
        ("jenkins", Law::Jenkins { kt: 1e5, fs: 10.0 }),
    ];
    let n = 4096;
    let u: Vec<f64> = (0..n).map(|i| 2e-3 * ((i as f64) * 0.37).sin()).collect();
    let v: Vec<f64> = (0..n).map(|i| 0.1 * ((i as f64) * 0.37).cos()).collect();
    let mut g = c.benchmark_group("element_eval");
    g.throughput(Throughput::Elements(n as u64));
    for (name, law) in &laws {
        let state = [2e-4];
        let st = &state[..law.n_states()];
        g.bench_function(*name, |b| {
            b.iter(|| {
                let mut acc = 0.0;
                for i in 0..n {
                    let e = law.eval(black_box(u[i]), black_box(v[i]), st);
                    acc += e.force + e.df_du + e.df_dv;
                }
                acc
            })
        });
    }
    g.finish();
}

fn bracket(c: &mut Criterion) {
    let mut g = c.benchmark_group("bracket");
    g.sample_size(10);
    for r in BRACKET_REFINEMENTS {
        let cfg = BracketConfig {
            refinement: r,
            ..Default::default()
        };
        let b = Bracket::generate(&cfg).expect("valid bracket");
        let n = b.dofs.len();
        g.bench_function(format!("assemble/{n}dofs"), |bch| {
            bch.iter(|| Bracket::generate(black_box(&cfg)).expect("valid"))
        });
        let fx = nlsim_fixtures::bracket_fixture(&cfg, "cubic").expect("valid fixture");
        g.bench_function(format!("validate/{n}dofs"), |bch| {
            bch.iter(|| {
                fx.model
                    .validate(&ValidationConfig::default())
                    .expect("valid model")
            })
        });
    }
    g.finish();
}

criterion_group!(benches, element_eval, bracket);
criterion_main!(benches);
