//! # nlsim-calib
//!
//! Calibration of nonlinear structural models from stepped-sine test data (thesis §4.1,
//! §4.5, §4.6; papers I, IV, V):
//!
//! - [`data`]: the test data: measured force and response harmonics per frequency step,
//!   sweep directions, a noise model per channel;
//! - [`objective`]: the weighted deviation of computed from measured multi-harmonic responses
//!   along each sweep (fundamental only or with side harmonics; complex or log-magnitude and
//!   phase), with its Jacobian from the harmonic balance sensitivities;
//! - [`modal`]: the linear stage: FE-level parameters (group scales, boundary springs) from
//!   measured frequencies and mode shapes, with analytic eigen-sensitivities;
//! - [`lm`]: bounded Levenberg–Marquardt with a scaled trust region;
//! - [`lhs`]: seeded maximin Latin-hypercube start points;
//! - [`calibrate`](mod@calibrate): the workflow (candidates in parallel → LM from the best few →
//!   Cramér–Rao bound → k-fold cross validation);
//! - [`stats`]: Cramér–Rao bounds, identifiability, estimate statistics;
//! - [`plan`]: pre-test planning by Fisher information (design ranking, sensor placement,
//!   multi-sine side tones);
//! - [`backbone`]: amplitude-dependent natural frequency and damping of one mode from free
//!   decays, stepped sines and phase-resonance tests, with standard deviations;
//! - [`dwell`], [`track`]: harmonics from raw time histories of stepped-sine dwells and of
//!   slow sweeps;
//! - [`shaker`]: a virtual stepped-sine test through an electrodynamic shaker model, with and
//!   without off-line force control; [`raw_test`]: the time histories that test records,
//!   the shaker coupled in the time domain;
//! - [`time_domain`]: calibration on measured time histories, Jacobian by forward
//!   sensitivities of the hold recursion.
//!
//! Solvers that stop short return what they computed with a [`Status`];
//! `Err` means invalid input. Nothing here prints, reads files or exits.

pub mod backbone;
pub mod calibrate;
pub mod coupling;
pub mod data;
pub mod dwell;
pub mod lhs;
mod linalg;
pub mod lm;
pub mod modal;
pub mod objective;
pub mod plan;
pub mod predict;
pub mod raw_test;
pub mod shaker;
pub mod stats;
mod step;
pub mod synthetic;
pub mod time_domain;
pub mod track;

pub use calibrate::{
    Calibration, CalibrationConfig, Candidate, FoldBy, FoldResult, Interrupted, KFold, MAX_FOLDS,
    MAX_LHS_SAMPLES, MAX_MAXIMIN_SWAPS, MAX_STARTS, Outcome, Phase, Progress, Searched, StartRun,
    Stop, calibrate, calibrate_from_candidates, calibrate_from_candidates_until, calibrate_until,
    calibrate_with_progress, candidate_points, fold, fold_assignment, fold_plan, kfold,
};
pub use data::{Channel, Drive, Noise, PointId, Step, Sweep, SweepDirection, TestData};
pub use dwell::{Dwell, DwellConfig, StepWindow, detect_steps, extract_dwell};
pub use lhs::{Spacing, latin_hypercube, maximin_latin_hypercube};
pub use linalg::Svd;
pub use lm::{Evaluation, LeastSquares, LmConfig, LmReport, StopReason, levenberg_marquardt};
pub use modal::{
    MeasuredMode, ModalCalibration, ModalData, ModalFit, ModalObjective, calibrate_modal,
    calibrate_modal_until, calibrate_modal_with_progress, mac_of,
};
pub use nlsim_kernel::Status;
pub use nlsim_reduction::{ParametricConfig, ParametricStats};
pub use objective::{
    BRANCH_CHECK, BranchChoice, FeReduction, FeReductionStats, Form, FrfObjective, ObjectiveConfig,
    ParamSpec, PointResult, SweepEvaluation,
};
pub use plan::{
    Band, Criterion, Design, Exciter, FimSummary, Placement, Planner, RankedDesign, SideTone,
    SweepInformation, dof_information, greedy_placement, rank_designs, scaled_noise, subsets,
};
pub use predict::{BandConfig, PredictedValue, Prediction, SweepScore, normal_quantile, predict};
pub use raw_test::{
    MAX_RAW_VALUES, RawConfig, RawRecord, RawStep, add_raw_noise, raw_records, settle_time,
    shaker_plant,
};
pub use shaker::{
    ControlConfig, Shaker, StepControl, VirtualTest, virtual_test, virtual_test_with,
};
pub use stats::{CHI2_WARN, CramerRao};
pub use synthetic::{Gaussian, SweepPlan, synthesize};
pub use time_domain::{
    MAX_TIME_SAMPLES, TimeCalibration, TimeChannel, TimeFit, TimeObjective, TimeRecords,
    calibrate_time, calibrate_time_until, check_time_folds, synthesize_time, time_blocks,
};
pub use track::{Track, TrackConfig, TrackPoint, sweep_bias, sweep_rate_parameter, track_sweep};
