//! nlsim benchmarks live in `benches/`; this library holds what they share.
//!
//! Run one with `cargo bench -p nlsim-bench --bench kernel -- --quick --noplot`.

/// Bracket refinements the kernel bench assembles: about 4.7·10³ and 3.1·10⁴ DOFs.
pub const BRACKET_REFINEMENTS: [usize; 2] = [2, 4];

/// The hexahedral bracket nearest `target` DOFs (consistent mass, cubic tip spring) with a
/// displacement sensor `tip_d` at its excitation point: the model the sim and hb benches
/// time.
pub fn bracket_with_tip_sensor(target: usize) -> nlsim_kernel::Model {
    let cfg = nlsim_fixtures::bracket::BracketConfig {
        lumped_mass: false,
        ..nlsim_fixtures::bracket::BracketConfig::for_target_dofs(target)
    };
    let mut model = nlsim_fixtures::bracket_fixture(&cfg, "cubic")
        .expect("the bracket fixture builds")
        .model;
    let tip = model.excitation()[0].dof;
    model
        .add_sensor(nlsim_kernel::Sensor {
            name: "tip_d".into(),
            dof: tip,
            quantity: nlsim_kernel::Quantity::Displacement,
        })
        .expect("a new sensor name");
    model
}
