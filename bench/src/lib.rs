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

/// The ECL-beam calibration the calib bench and the speed gate time: the tip spring's `k3`
/// (1e8–1e11 N/m³) and the driven mode's damping (0.002–0.05) from synthesized stepped sweeps
/// `plans` (4 modes, H = 3, 3 % noise, seed 7), compared at harmonics 1 and 3.
pub fn ecl_calibration_objective(plans: &[nlsim_calib::SweepPlan]) -> nlsim_calib::FrfObjective {
    use nlsim_calib::{Form, FrfObjective, Noise, ObjectiveConfig, ParamSpec, synthesize};
    let fx = nlsim_fixtures::ecl_beam();
    let red = nlsim_reduction::reduce(&fx.model, &nlsim_reduction::ReductionConfig::lowest(4))
        .expect("the ECL beam reduces");
    let sys = nlsim_hb::HbSystem::from_model(
        &fx.model,
        &red,
        nlsim_hb::HarmonicSet::new(3, 1).expect("H = 3"),
        nlsim_hb::HbConfig::default(),
    )
    .expect("the ECL beam balances");
    let driven = sys
        .linear()
        .dominant_mode(sys.sensors()[0].port, 0..2)
        .expect("a driven mode");
    let data =
        synthesize(&sys, "shaker", plans, 3, Noise::relative(0.03), 7).expect("synthetic sweeps");
    let specs = vec![
        ParamSpec::new(nlsim_kernel::Param::element("tip_spring", "k3"), 1e8, 1e11),
        ParamSpec::new(nlsim_kernel::Param::ModalDamping(driven), 0.002, 0.05),
    ];
    let cfg = ObjectiveConfig {
        harmonics: vec![1, 3],
        form: Form::Complex,
        ..ObjectiveConfig::default()
    };
    FrfObjective::new(&sys, std::sync::Arc::new(data), specs, cfg).expect("the objective")
}
