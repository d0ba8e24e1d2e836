//! A 2-DOF chain with a cubic spring, built in code: reduce, simulate with the FOH
//! integrator, solve one harmonic balance point, follow the FRF by continuation, and take
//! sensitivities — through `nlsim::prelude` alone. Run with
//! `cargo run --release --example two_dof_cubic`; the test suite runs it too.

use nlsim::prelude::*;

fn main() -> nlsim::kernel::Result<()> {
    // m = 1 kg per DOF; k = 1e4 N/m to ground and between the masses; k3 = 1e9 N/m³ at DOF 2.
    let k = SparseSym::from_dense_rows("K", &[vec![2e4, -1e4], vec![-1e4, 1e4]])?;
    let m = SparseSym::diagonal("M", &[1.0, 1.0])?;
    let spring = NonlinearElement::new("tip", Law::Cubic { k3: 1e9 }, Coupling::single(1))?;
    let model = Model::builder("chain", DofMap::scalar(2), m, k)
        .damping(Damping::Rayleigh {
            alpha: 2.0,
            beta: 0.0,
        })
        .element(spring)
        .excitation("shaker", "2:u", 1.0)
        .sensor("tip_d", "2:u", Quantity::Displacement)
        .build()?;
    let reduced = reduce(&model, &ReductionConfig::lowest(2))?;

    // 0.2 s of a 10 Hz sine of 1 N, sampled at 10 kHz.
    let plant = Plant::from_model(&model, &ModalSystem::new(&reduced)?)?;
    let foh = Simulator::new(&plant, &FohConfig::new(1e-4))?;
    let run = foh.run(&LoadCase::new("sine", vec![Signal::sine(1.0, 10.0)]), 2000)?;
    let peak = run
        .output("tip_d")?
        .values
        .iter()
        .fold(0.0f64, |a, v| a.max(v.abs()));
    println!(
        "FOH: {} ({}), peak tip displacement {peak:.4e} m",
        run.status,
        run.n_samples()
    );

    // One HB point at 12 Hz, then the FRF from 8 to 20 Hz with stability.
    let hb = HbSystem::from_model(
        &model,
        &reduced,
        HarmonicSet::new(5, 1)?,
        HbConfig::default(),
    )?;
    let omega = 2.0 * std::f64::consts::PI * 12.0;
    let (x, newton) = hb.solve(omega, 1.0, &hb.linear_guess(omega, 1.0))?;
    println!(
        "HB at 12 Hz: {} in {} iterations",
        newton.status, newton.iterations
    );
    let sweep = continuation(&hb, &ContinuationConfig::frequency(8.0, 20.0), None)?;
    let folds = sweep.branch.folds().len();
    println!(
        "FRF 8-20 Hz: {}, {} points, {folds} folds",
        sweep.status, sweep.stats.n_points
    );

    // Sensitivities of the 12 Hz response to every parameter, keyed by Param.
    for s in hb.sensitivities(&x, omega, 1.0, &hb.parameters())? {
        println!("  d|Y1|/d({}) = {:.3e}", s.param, s.dy[(0, 1)].norm());
    }
    Ok(())
}
