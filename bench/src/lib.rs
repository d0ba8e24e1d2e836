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
    let tip = model.excitation()[0].at.clone();
    model
        .add_sensor(nlsim_kernel::Sensor {
            name: "tip_d".into(),
            at: tip,
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

/// The FE-level calibration case of the parametric-reduction benchmark (issue 49): the
/// hexahedral bracket nearest `target` DOFs (consistent mass, 0.5 % modal damping) with a
/// grounded spring of 1e4 N/m at the upright's tip (`spring:NODE:ux.k`, the boundary
/// condition to identify) beside the cubic tip element (`tip.k3`, 1e13 N/m³ nominal), and
/// synthetic stepped-sine data of the model at the true values k = 2e4 N/m, k3 = 1e12 N/m³:
/// two sweeps of 16 steps over ±8 % of the first natural frequency, up at 2 N and down at
/// 20 N, the tip displacement's harmonics 1..3 with 1 % noise (seed 7), 20 modes, H = 3.
pub struct FeCase {
    /// The model at its nominal values.
    pub model: nlsim_kernel::Model,
    /// The synthetic test data.
    pub data: std::sync::Arc<nlsim_calib::TestData>,
    /// The calibrated parameters: the spring (5e3–1e5 N/m) and k3 (1e11–1e13 N/m³).
    pub specs: Vec<nlsim_calib::ParamSpec>,
    /// The true values, in `specs` order.
    pub truth: Vec<f64>,
    /// The reduction (20 lowest modes with residual flexibility).
    pub reduction: nlsim_reduction::ReductionConfig,
}

/// Builds [`FeCase`] for the bracket nearest `target` DOFs.
pub fn bracket_fe_case(target: usize) -> FeCase {
    use nlsim_calib::{Noise, ParamSpec, SweepPlan, synthesize};
    use nlsim_kernel::{Param, Parameterized};
    let mut model = bracket_with_tip_sensor(target);
    let tip = model.excitation()[0]
        .at
        .dof()
        .expect("the bracket's force acts on a DOF");
    model
        .add_boundary_spring(tip, 1e4)
        .expect("a spring at the tip");
    let spring: Param = format!("spring:{}.k", model.dofs().labels()[tip])
        .parse()
        .expect("a spring parameter");
    let specs = vec![
        ParamSpec::new(spring, 5e3, 1e5),
        ParamSpec::new(Param::element("tip", "k3"), 1e11, 1e13),
    ];
    let truth = vec![2e4, 1e12];
    let reduction = nlsim_reduction::ReductionConfig::lowest(20);
    let mut t = model.clone();
    for (s, &v) in specs.iter().zip(&truth) {
        t.set_param(&s.param, v).expect("the true values");
    }
    let red = nlsim_reduction::reduce(&t, &reduction).expect("the bracket reduces");
    let f1 = red.modes.eigenvalues[0].sqrt() / (2.0 * std::f64::consts::PI);
    let sys = nlsim_hb::HbSystem::from_model(
        &t,
        &red,
        nlsim_hb::HarmonicSet::new(3, 1).expect("H = 3"),
        nlsim_hb::HbConfig::default(),
    )
    .expect("the bracket balances");
    let plans = [
        SweepPlan::linear("0.5 N up", 0.92 * f1, 1.08 * f1, 16, 0.5),
        SweepPlan::linear("4 N down", 1.08 * f1, 0.92 * f1, 16, 4.0),
    ];
    let data =
        synthesize(&sys, "shaker", &plans, 3, Noise::relative(0.01), 7).expect("synthetic sweeps");
    FeCase {
        model,
        data: std::sync::Arc::new(data),
        specs,
        truth,
        reduction,
    }
}

impl FeCase {
    /// The calibration objective of the case (H = 3, the fundamental compared) with the
    /// FE-level parameters reduced as `fe` says.
    pub fn objective(&self, fe: &nlsim_calib::FeReduction) -> nlsim_calib::FrfObjective {
        nlsim_calib::FrfObjective::from_model_with(
            &self.model,
            &self.reduction,
            fe,
            nlsim_hb::HarmonicSet::new(3, 1).expect("H = 3"),
            nlsim_hb::HbConfig::default(),
            std::sync::Arc::clone(&self.data),
            self.specs.clone(),
            nlsim_calib::ObjectiveConfig::default(),
        )
        .expect("the objective")
    }
}
