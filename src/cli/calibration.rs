//! The arguments of the calibration and test-planning commands (`calibrate`, `plan`,
//! `test`) and their requests: options given on the command line override the files.

use crate::commands;
use crate::present::console::Console;
use clap::Args;

/// The arguments of `nlsim calibrate`.
#[derive(Args, Debug)]
pub struct CalibrateArgs {
    /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
    #[arg(required_unless_present = "config", conflicts_with = "config")]
    model: Option<String>,
    /// Test data: stepped-sine CSV or HDF5 (docs/file-formats.md), linear FRFs in
    /// universal file dataset 58 (.uff/.unv, ASCII or binary; 1 % noise assumed), or
    /// measured modes as CSV (mode,frequency_hz,frequency_std_hz,DOF...: FE-level
    /// parameters from frequencies and shapes).
    #[arg(required_unless_present = "config", conflicts_with = "config")]
    data: Option<std::path::PathBuf>,
    /// Calibration file (TOML): model, data, parameters, bounds and every setting.
    #[arg(long)]
    config: Option<std::path::PathBuf>,
    /// A parameter and its bounds, `NAME=LOWER:UPPER` (repeatable), e.g.
    /// `--param tip_spring.k3=1e8:1e11 --param mode2.zeta=0.002:0.05`.
    #[arg(
        long = "param",
        required_unless_present = "config",
        conflicts_with = "config"
    )]
    params: Vec<String>,
    /// Fixed overrides `element.param=value` applied before calibrating (repeatable).
    #[arg(long, conflicts_with = "config")]
    set: Vec<String>,
    /// Harmonics compared (1 = fundamental only), e.g. `1,3` [default: 1].
    #[arg(long, value_delimiter = ',')]
    compare: Option<Vec<usize>>,
    /// Residual form: complex differences or log-magnitude and phase [default: complex].
    #[arg(long, value_enum)]
    form: Option<CalibForm>,
    /// Branch of a multi-valued response the model is compared on: `nearest` repeats a
    /// step from the linear response where the continued solution is far (5σ) from
    /// the measurement and keeps the nearer solution (the test jumped elsewhere than
    /// the model); `continuation` follows the model's own branch [default: nearest].
    #[arg(long, value_enum)]
    branch: Option<CalibBranch>,
    /// Harmonics H kept by the harmonic balance [default: 3].
    #[arg(long)]
    harmonics: Option<usize>,
    /// Retained modes of the reduced model (modal data: the computed modes paired with
    /// the measured ones) [default: 20, at most the model's DOFs].
    #[arg(long)]
    modes: Option<usize>,
    /// Relative noise of each value of data that carry no noise model (UFF 58 FRFs,
    /// amplitude-and-phase tables) [default: 0.01].
    #[arg(long)]
    data_noise: Option<f64>,
    /// Added to every measured response phase, in degrees: the data's phase convention
    /// (e.g. 180 for accelerations whose phase was recorded as a displacement's)
    /// [default: 0].
    #[arg(long, allow_hyphen_values = true)]
    phase_offset_deg: Option<f64>,
    /// The sweeps calibrated on, by label, `*` pattern or 1-based index (comma-separated,
    /// e.g. `--train 'force-*'`); the others are held out, for `nlsim validate` to predict
    /// [default: every sweep].
    #[arg(long, value_delimiter = ',')]
    train: Option<Vec<String>>,
    /// Modal data: standard deviation of one component of a unit-normalised measured
    /// shape [default: 0.02].
    #[arg(long)]
    shape_noise: Option<f64>,
    /// The data are raw time records (CSV `time_s,DRIVE,SENSOR…`, HDF5 or UFF 58 time
    /// responses, from rest): element law parameters fitted to the sampled responses by
    /// first-order-hold simulations driven by the recorded force; each channel's noise is
    /// --data-noise times its rms.
    #[arg(long)]
    time_domain: bool,
    /// The data's voltage record drives the model through a modelled shaker: nlsim's default
    /// shaker without a value (or `default`), or the `[shaker]` table of a test or
    /// calibration FILE (the default shaker where it has none) [default: the calibration
    /// file's `[shaker]`, else the voltage taken as the force times the input gain].
    #[arg(long, num_args = 0..=1, default_missing_value = "default", value_name = "FILE")]
    shaker: Option<std::path::PathBuf>,
    /// How FE-level parameters (`group:NAME.k_scale`, `group:NAME.m_scale`,
    /// `spring:NODE:COMP.k`) reduce the model at each evaluation: `parametric` (one basis,
    /// a small eigen solve per evaluation, certified against the full matrices and
    /// refreshed by a full reduction where the certificate fails) or `full` (a full
    /// reduction every time; slow) [default: parametric].
    #[arg(long, value_parser = ["parametric", "full"])]
    fe_reduction: Option<String>,
    /// Certificate tolerance of the parametric reduction (relative; the default keeps the
    /// predicted FRFs within about 1e-6 of a full re-reduction) [default: 1e-6].
    #[arg(long)]
    fe_tolerance: Option<f64>,
    /// Latin-hypercube candidates [default: 64].
    #[arg(long)]
    lhs: Option<usize>,
    /// Levenberg–Marquardt runs from the best candidates [default: 3].
    #[arg(long)]
    starts: Option<usize>,
    /// Folds of the cross validation (0: none) [default: 10].
    #[arg(long)]
    folds: Option<usize>,
    /// How the folds are dealt: `points` (a seeded shuffle of the steps) or `sweeps` (each
    /// sweep, e.g. a force level, held out whole and predicted from the others; one fold per
    /// sweep) [default: points].
    #[arg(long, value_parser = ["points", "sweeps"])]
    fold_by: Option<String>,
    /// Seed of the Latin hypercube and of the folds [default: 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Build the objective, time one evaluation of each kind and print what the
    /// calibration will cost (evaluations and an estimate of the wall time); nothing else
    /// runs and nothing is written.
    #[arg(long)]
    dry_run: bool,
    /// Candidates already evaluated: the merged file of a `calibrate-candidates` batch
    /// of this calibration (docs/batch.md), or the `.interrupted.h5` file a stopped run
    /// kept (its missing candidates are evaluated here).
    #[arg(long)]
    candidates: Option<std::path::PathBuf>,
    /// Estimates and statistics as CSV.
    #[arg(long)]
    out: Option<std::path::PathBuf>,
    /// Report folder: summary, tables (estimates, candidates, convergence, folds, fit)
    /// and plots as SVG and PNG (per-harmonic FRFs, k-fold bars, convergence).
    #[arg(long)]
    report: Option<std::path::PathBuf>,
}

/// The arguments of `nlsim validate`.
#[derive(Args, Debug)]
pub struct ValidateArgs {
    /// A calibration's result: `calibration.toml` in the report folder of `nlsim calibrate
    /// --report DIR`.
    calibration: std::path::PathBuf,
    /// Other test data to predict (read with the calibration's data options) [default: the
    /// calibration's data file].
    #[arg(long)]
    data: Option<std::path::PathBuf>,
    /// The sweeps predicted, by label, `*` pattern or 1-based index (comma-separated)
    /// [default: those held out of the training; every sweep of --data].
    #[arg(long, value_delimiter = ',')]
    sweeps: Option<Vec<String>>,
    /// Two-sided coverage of the band, in (0, 1) [default: 0.95].
    #[arg(long)]
    level: Option<f64>,
    /// Scale of the band's variances: `chi2` (by the training's reduced chi2 where it
    /// exceeds 1), `folds` (by the calibration's cross-validation held-out mean square, or
    /// the reduced chi2 where larger: with folds that leave sweeps out, the band of a run
    /// not trained on) or `none` (the Cramér–Rao covariance and the noise model as they are)
    /// [default: chi2].
    #[arg(long, value_parser = ["chi2", "folds", "none"])]
    scale: Option<String>,
    /// Report folder: summary, scores.csv, prediction.csv, a plot per sweep and harmonic
    /// (measured, predicted, band) and report.h5.
    #[arg(long)]
    report: Option<std::path::PathBuf>,
    /// The prediction as a file: .csv (every predicted value) or .uff/.unv (universal file
    /// datasets 58: predicted and measured Y_k/F1 per sweep, channel and harmonic).
    #[arg(long)]
    out: Option<std::path::PathBuf>,
}

impl ValidateArgs {
    /// The request of `nlsim validate`.
    pub fn request(&self) -> commands::validate::ValidateRequest {
        let mut r = commands::validate::ValidateRequest::new(self.calibration.clone());
        r.data = self.data.clone();
        r.sweeps = self.sweeps.clone().unwrap_or_default();
        if let Some(l) = self.level {
            r.level = l;
        }
        match self.scale.as_deref() {
            Some("none") => r.scale = commands::validate::BandScale::None,
            Some("folds") => r.scale = commands::validate::BandScale::Folds,
            _ => {}
        }
        r.report = self.report.clone();
        r.out = self.out.clone();
        r
    }

    /// `nlsim validate`.
    pub fn execute(&self, console: &Console) -> crate::Result<()> {
        commands::validate::execute(&self.request(), console)
    }
}

/// The arguments of `nlsim harmonics`.
#[derive(Args, Debug)]
pub struct HarmonicsArgs {
    /// Model file (.toml) or built-in model: its sensors name the channels and give their
    /// quantities.
    model: String,
    /// Time histories: CSV (`time_s,DRIVE,SENSOR,…`, evenly sampled), HDF5 (.h5: `/time`
    /// and the signals in `/inputs`, `/outputs` or at the root, as `nlsim simulate --out`
    /// writes them) or universal file datasets 58 of function type 1 (.uff, .unv, .uf).
    records: std::path::PathBuf,
    /// Step table (CSV: `start_s,end_s[,frequency_hz][,sweep]`) [default: the steps found
    /// from the drive's frequency].
    #[arg(long)]
    steps: Option<std::path::PathBuf>,
    /// The drive's column [default: the model's first excitation].
    #[arg(long)]
    drive: Option<String>,
    /// What the drive column holds: `force` (N) or `voltage` (the amplifier's, V).
    #[arg(long, value_parser = ["force", "voltage"], default_value = "force")]
    record: String,
    /// Harmonics fitted per dwell (1 to 64).
    #[arg(long, default_value_t = 3)]
    harmonics: usize,
    /// Relative tolerance of the steady state: periods whose fundamental differs from the
    /// settled one by more (beyond 3 times the scatter) are the transient.
    #[arg(long, default_value_t = 1e-3)]
    settle_tol: f64,
    /// Fewest settled periods a dwell needs; dwells with fewer are left out and named.
    #[arg(long, default_value_t = 4)]
    min_periods: usize,
    /// Take the step table's frequencies as exact (the generator's) instead of refining
    /// them from the drive.
    #[arg(long)]
    exact_frequency: bool,
    /// Relative frequency change that starts a new step when the steps are found from the
    /// drive.
    #[arg(long, default_value_t = 5e-3)]
    step_tol: f64,
    /// The records hold slow sine sweeps, not dwells: track the harmonics along each (the
    /// whole record, or each row of the step table, is one sweep whose frequency rises or
    /// falls throughout).
    #[arg(long)]
    sweep: bool,
    /// Periods of the drive in each tracking window (even, 4 to 10000) with --sweep.
    #[arg(long, default_value_t = 10, requires = "sweep")]
    window_periods: usize,
    /// Points per sweep, evenly spaced in frequency, with --sweep (fewer when the sweep
    /// holds fewer windows: the windows do not overlap).
    #[arg(long, default_value_t = 100, requires = "sweep")]
    points: usize,
    /// Test data written, .csv or .h5 [default: RECORDS with `-harmonics.csv`, beside it].
    #[arg(long)]
    out: Option<std::path::PathBuf>,
}

impl HarmonicsArgs {
    /// The request of `nlsim harmonics`; a usage error for values out of range.
    pub fn request(&self) -> crate::Result<commands::harmonics::HarmonicsRequest> {
        if !(1..=64).contains(&self.harmonics) {
            return Err(crate::Error::Usage(format!(
                "--harmonics {}: fit 1 to 64 harmonics",
                self.harmonics
            )));
        }
        for (name, v) in [
            ("--settle-tol", self.settle_tol),
            ("--step-tol", self.step_tol),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(crate::Error::Usage(format!(
                    "{name} {v}: give a positive relative tolerance"
                )));
            }
        }
        if self.min_periods == 0 {
            return Err(crate::Error::Usage(
                "--min-periods 0: a dwell needs at least one settled period".into(),
            ));
        }
        if self.sweep {
            if self.window_periods < 4
                || !self.window_periods.is_multiple_of(2)
                || self.window_periods > 10_000
            {
                return Err(crate::Error::Usage(format!(
                    "--window-periods {}: give an even number of periods, 4 to 10000",
                    self.window_periods
                )));
            }
            if self.points == 0 {
                return Err(crate::Error::Usage(
                    "--points 0: track at least one point per sweep".into(),
                ));
            }
            if self.exact_frequency {
                return Err(crate::Error::Usage(
                    "--exact-frequency is for dwells: a sweep's frequency is tracked from its \
                     drive"
                        .into(),
                ));
            }
        }
        if self.exact_frequency && self.steps.is_none() {
            return Err(crate::Error::Usage(
                "--exact-frequency takes the step table's frequencies: give --steps TABLE".into(),
            ));
        }
        let out = self.out.clone().unwrap_or_else(|| {
            let stem = self
                .records
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "records".into());
            self.records.with_file_name(format!("{stem}-harmonics.csv"))
        });
        Ok(commands::harmonics::HarmonicsRequest {
            model: self.model.clone(),
            records: self.records.clone(),
            steps: self.steps.clone(),
            drive: self.drive.clone(),
            record: nlsim_calib::Drive::parse(&self.record).unwrap_or(nlsim_calib::Drive::Force),
            dwell: nlsim_calib::DwellConfig {
                harmonics: self.harmonics,
                settle_tolerance: self.settle_tol,
                min_periods: self.min_periods,
                estimate_frequency: !self.exact_frequency,
            },
            step_tolerance: self.step_tol,
            sweep: self.sweep.then_some(nlsim_calib::TrackConfig {
                harmonics: self.harmonics,
                window_periods: self.window_periods,
                points: self.points,
            }),
            out,
        })
    }
}

/// The arguments of `nlsim plan`.
#[derive(Args, Debug)]
pub struct PlanArgs {
    /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
    model: String,
    /// Plan file (TOML): parameters and candidates.
    plan: std::path::PathBuf,
    /// Ranking criterion: D, T, A, E or max-variance [default: the file's, else D].
    #[arg(long)]
    criterion: Option<String>,
    /// Rows of the printed table [default: the file's, else 10].
    #[arg(long)]
    top: Option<usize>,
    /// Report folder: summary, ranking.csv, fim_best.csv and plots [default: the file's,
    /// else PLAN's name with `-report`, beside it].
    #[arg(long)]
    report: Option<std::path::PathBuf>,
}

/// The arguments of `nlsim test`.
#[derive(Args, Debug)]
pub struct TestArgs {
    /// Model file (.toml) or built-in model, e.g. `ecl_beam`.
    model: String,
    /// Test file (TOML): drive point, shaker, controller, sweeps, noise.
    test: std::path::PathBuf,
    /// Test data, .csv or .h5 [default: the file's `out`, else virtual_test.csv beside
    /// it].
    #[arg(long)]
    out: Option<std::path::PathBuf>,
    /// Seed of the measurement noise [default: the file's, else 1].
    #[arg(long)]
    seed: Option<u64>,
    /// Run voltage-driven only (no force control).
    #[arg(long)]
    open_loop: bool,
    /// What the data record at the drive point: `force` (a force gauge) or `voltage` (the
    /// amplifier's input, no force gauge) [default: the file's `record`, else force].
    #[arg(long, value_parser = ["force", "voltage"])]
    record: Option<String>,
    /// The amplifier's gain (V at the coil per V in) a voltage record is divided by
    /// [default: the file's `amplifier_gain`, else 1].
    #[arg(long)]
    amplifier_gain: Option<f64>,
    /// Report folder: summary, control.csv and force/response plots [default: the
    /// file's, else TEST's name with `-report`, beside it].
    #[arg(long)]
    report: Option<std::path::PathBuf>,
    /// Also write the time histories the test would have recorded (.csv, .h5, .uff) and
    /// their step table beside them, the shaker coupled in the time domain [default: the
    /// file's `[raw]`, else none].
    #[arg(long)]
    raw: Option<std::path::PathBuf>,
}

impl CalibrateArgs {
    /// The request of `nlsim calibrate`: the calibration file's with the options given beside
    /// it, or one built from MODEL, DATA and `--param`; `Err` for a parameter that does not
    /// parse or a calibration file that does not load.
    pub fn request(&self) -> crate::Result<commands::calibrate::CalibrationRequest> {
        use commands::calibrate::{CalibrationRequest, parse_param_bounds};
        let mut req = match (&self.config, &self.model, &self.data) {
            (Some(path), _, _) => CalibrationRequest::load(path)?,
            (None, Some(model), Some(data)) => {
                let specs = self
                    .params
                    .iter()
                    .map(|p| parse_param_bounds(p))
                    .collect::<crate::Result<Vec<_>>>()?;
                let mut r = CalibrationRequest::new(model.clone(), data.clone(), specs);
                r.set = self.set.clone();
                r
            }
            _ => {
                return Err(crate::Error::Usage(
                    "nlsim calibrate needs MODEL DATA --param ... or --config FILE".into(),
                ));
            }
        };
        if let Some(v) = &self.compare {
            req.compare = v.clone();
        }
        if let Some(f) = self.form {
            req.form = match f {
                CalibForm::Complex => crate::calib::Form::Complex,
                CalibForm::LogMagnitude => crate::calib::Form::LogMagnitudePhase,
            };
        }
        if let Some(b) = self.branch {
            req.branch = match b {
                CalibBranch::Nearest => crate::calib::BranchChoice::NearestToData,
                CalibBranch::Continuation => crate::calib::BranchChoice::Continuation,
            };
        }
        let c = &mut req.config;
        for (dst, src) in [
            (&mut req.harmonics, self.harmonics),
            (&mut req.modes, self.modes),
            (&mut c.lhs_samples, self.lhs),
            (&mut c.starts, self.starts),
            (&mut c.folds, self.folds),
        ] {
            if let Some(v) = src {
                *dst = v;
            }
        }
        if let Some(s) = self.seed {
            c.seed = s;
        }
        if let Some(f) = &self.fold_by {
            c.fold_by = crate::commands::calibrate::request::parse_fold_by(f)
                .map_err(|m| crate::Error::Usage(format!("--fold-by {m}")))?;
        }
        if self.time_domain {
            req.time_domain = true;
        }
        if let Some(f) = &self.shaker {
            req.shaker = Some(if f.as_os_str() == "default" {
                crate::calib::Shaker::default()
            } else {
                crate::formats::settings::shaker_of_file(f)?
            });
        }
        if let Some(s) = self.shape_noise {
            req.shape_noise = s;
        }
        if let Some(v) = self.data_noise {
            req.data_options.noise = v;
        }
        if let Some(v) = self.phase_offset_deg {
            req.data_options.phase_offset_deg = v;
        }
        if let Some(t) = &self.train {
            req.train = t.clone();
        }
        if self.fe_reduction.is_some() || self.fe_tolerance.is_some() {
            let kind = self.fe_reduction.as_deref().or(match &req.fe {
                crate::calib::FeReduction::Full if self.fe_tolerance.is_none() => Some("full"),
                _ => None,
            });
            let tol = self.fe_tolerance.or(match &req.fe {
                crate::calib::FeReduction::Parametric(p) if self.fe_reduction.is_none() => {
                    Some(p.tolerance)
                }
                _ => None,
            });
            req.fe = commands::calibrate::parse_fe_reduction(kind, tol).map_err(|(key, m)| {
                crate::Error::Usage(format!("--{}: {m}", key.replace('_', "-")))
            })?;
        }
        if self.out.is_some() {
            req.out = self.out.clone();
        }
        if self.report.is_some() {
            req.report = self.report.clone();
        }
        Ok(req)
    }

    /// `nlsim calibrate`.
    pub fn execute(&self, console: &Console) -> crate::Result<()> {
        if self.dry_run {
            let req = self.request()?;
            req.check()?;
            let estimate = if req.time_domain {
                commands::calibrate::estimate_time_calibration(&req)?
            } else if commands::calibrate::is_modal(&req)? {
                commands::calibrate::estimate_modal_calibration(&req)?
            } else {
                commands::calibrate::estimate_calibration(&req)?
            };
            for line in estimate.lines() {
                console.say(&line);
            }
            return Ok(());
        }
        commands::calibrate::execute(&self.request()?, self.candidates.as_deref(), console)
    }
}

impl PlanArgs {
    /// The request of `nlsim plan`: the plan file's, with `--criterion`, `--top` and
    /// `--report` overriding it.
    pub fn request(&self) -> crate::Result<commands::plan::PlanRequest> {
        let mut req = commands::plan::PlanRequest::load(&self.plan, &self.model)?;
        if let Some(c) = &self.criterion {
            req.criterion = crate::calib::Criterion::parse(c)
                .map_err(|e| crate::Error::Usage(format!("--criterion: {e}")))?;
        }
        if let Some(t) = self.top {
            req.top = t;
        }
        req.report = Some(
            self.report
                .clone()
                .or(req.report)
                .unwrap_or_else(|| commands::setup::default_report(&self.plan)),
        );
        Ok(req)
    }
}

impl TestArgs {
    /// The request of `nlsim test`: the test file's, with `--out`, `--seed`, `--open-loop`,
    /// `--raw` and `--report` overriding it.
    pub fn request(&self) -> crate::Result<commands::test::TestRequest> {
        let mut req = commands::test::TestRequest::load(&self.test, &self.model)?;
        if let Some(o) = &self.out {
            req.out = o.clone();
        }
        if let Some(s) = self.seed {
            req.seed = s;
        }
        if self.open_loop {
            req.control.enabled = false;
            req.compare_open_loop = false;
        }
        if let Some(r) = self.record.as_deref().and_then(nlsim_calib::Drive::parse) {
            req.record = r;
        }
        if let Some(g) = self.amplifier_gain {
            req.amplifier_gain = g;
        }
        if let Some(out) = &self.raw {
            match &mut req.raw {
                Some(r) => r.out = out.clone(),
                None => {
                    req.raw = Some(commands::test::RawRequest {
                        out: out.clone(),
                        rate_hz: None,
                        dwell_s: None,
                        oversample: None,
                    })
                }
            }
        }
        req.check()?;
        req.report = Some(
            self.report
                .clone()
                .or(req.report)
                .unwrap_or_else(|| commands::setup::default_report(&self.test)),
        );
        Ok(req)
    }
}

/// Residual form of `nlsim calibrate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum CalibForm {
    /// Real and imaginary parts of the complex difference.
    Complex,
    /// Log-magnitude and phase differences.
    LogMagnitude,
}

/// Branch choice of `nlsim calibrate`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum CalibBranch {
    /// The solution nearer to the measurement where the continued one is far from it.
    Nearest,
    /// The model's own continuation from the previous step.
    Continuation,
}
