//! The names a workflow in code needs, in one `use nlsim::prelude::*;`: build a model, reduce
//! it, simulate it with the FOH integrator, follow its multi-harmonic FRF, read and set its
//! parameters. No file or plotting dependency is involved (see the `io` feature).

pub use nlsim_calib::{
    Calibration, CalibrationConfig, Channel, Form, FrfObjective, MeasuredMode, ModalData,
    ModalObjective, Noise, ObjectiveConfig, ParamSpec, Step, Sweep, SweepDirection, SweepPlan,
    TestData, calibrate, calibrate_modal, synthesize,
};
pub use nlsim_hb::{
    Branch, ContinuationConfig, ContinuationReport, Forcing, HarmonicSet, HbConfig, HbSystem,
    PointKind, SolutionPoint, continuation, stepped_sine,
};
pub use nlsim_kernel::{
    Coupling, Damping, DofLabel, DofMap, Law, Model, ModelBuilder, NonlinearElement, Param,
    Parameterized, Quantity, SparseSym, Status, ValidationConfig,
};
pub use nlsim_reduction::{
    EigenConfig, ModalSystem, ModeSelection, ReducedModel, ReductionConfig, reduce,
};
pub use nlsim_sim::{FohConfig, LoadCase, Plant, Signal, Simulator, TimeHistory};
