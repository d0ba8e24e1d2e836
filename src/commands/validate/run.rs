//! The request and run of `nlsim validate`: a calibration's result predicts test data it was
//! not trained on, with a band from the parameter covariance and the noise model.
use crate::commands::calibrate::{CalibrationRequest, StoredResult, load_result, prepare_on};
use crate::error::{Error, Result};
use crate::formats::test_data::{read, select_sweeps, sweep_indices};
use nlsim_calib::{BandConfig, Prediction, TestData};
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

/// How the band's variances are scaled.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum BandScale {
    /// By the calibration's reduced χ² where it exceeds 1 (the noise level estimated from
    /// the training misfit), else 1.
    #[default]
    Chi2,
    /// By the calibration's cross-validation: the larger of the mean square held-out
    /// weighted residual of its folds (`held_out_mean_square` of the result; with
    /// `fold_by = "sweeps"` it holds how the model predicts a run it was not trained on) and
    /// the reduced χ², at least 1.
    Folds,
    /// As given: the Cramér–Rao covariance and the data's noise model.
    None,
}

/// What `nlsim validate` predicts and how.
#[derive(Debug, Clone)]
pub struct ValidateRequest {
    /// The calibration's result file (`calibration.toml` of its report folder).
    pub calibration: PathBuf,
    /// Other test data to predict (read with the calibration's data options); default: the
    /// calibration's own data file.
    pub data: Option<PathBuf>,
    /// The sweeps predicted (labels, `*` patterns, 1-based indices); empty: the sweeps the
    /// calibration held out of its training (every sweep of other data).
    pub sweeps: Vec<String>,
    /// Two-sided band level in (0, 1).
    pub level: f64,
    /// How the band is scaled.
    pub scale: BandScale,
    /// Report folder.
    pub report: Option<PathBuf>,
    /// The prediction as a file: `.csv` (every predicted value, as `prediction.csv` of the
    /// report) or `.uff`/`.unv` (universal file datasets 58: per sweep, channel and compared
    /// harmonic the predicted and the measured `Y_k/F₁`, for test software to overlay).
    pub out: Option<PathBuf>,
}

impl ValidateRequest {
    /// A request with a 95 % band scaled by the reduced χ², predicting the held-out sweeps.
    pub fn new(calibration: impl Into<PathBuf>) -> Self {
        Self {
            calibration: calibration.into(),
            data: None,
            sweeps: Vec::new(),
            level: 0.95,
            scale: BandScale::Chi2,
            report: None,
            out: None,
        }
    }
}

/// A finished validation.
pub struct ValidationRun {
    /// The request.
    pub request: ValidateRequest,
    /// The calibration it read (model, data options, parameters, settings).
    pub calibration: CalibrationRequest,
    /// The calibration's result.
    pub result: StoredResult,
    /// The model's name.
    pub model_name: String,
    /// The data file predicted.
    pub data_path: PathBuf,
    /// Which sweeps were predicted and why, for people.
    pub selection: String,
    /// The prediction and its scores.
    pub prediction: Prediction,
    /// The predicted test data.
    pub data: Arc<TestData>,
    /// The DOF of the data's drive in the model (None when the model has no such excitation).
    pub input_dof: Option<nlsim_kernel::DofLabel>,
    /// The DOF of each channel's sensor in the model.
    pub channel_dofs: Vec<Option<nlsim_kernel::DofLabel>>,
    /// The model's node coordinates (m), for dataset 2411 of a universal file.
    pub geometry: Vec<(u64, [f64; 3])>,
    /// Wall time (s).
    pub seconds: f64,
}

/// Runs `req`: loads the calibration's result, reads and selects the data, predicts.
pub fn run_validation(req: &ValidateRequest) -> Result<ValidationRun> {
    let t = Instant::now();
    let (cal, result) = load_result(&req.calibration)?;
    let model = crate::commands::setup::load_for_run(&cal.model, &cal.model_sets())?;
    let data_path = req.data.clone().unwrap_or_else(|| cal.data.clone());
    let all = read(&data_path, &model, &cal.data_options)?;
    let (data, selection) = if !req.sweeps.is_empty() {
        let d = select_sweeps(&all, &req.sweeps, "--sweeps")?;
        let n = d.sweeps.len();
        (d, format!("{n} sweeps selected by --sweeps"))
    } else if req.data.is_none() && !cal.train.is_empty() {
        let trained = sweep_indices(&all, &cal.train, "train")?;
        let held: Vec<usize> = (0..all.sweeps.len())
            .filter(|i| !trained.contains(i))
            .collect();
        if held.is_empty() {
            return Err(Error::Usage(format!(
                "{}: the calibration trained on every sweep of {}; nothing is held out \
                 (give --sweeps '*' to predict the training sweeps)",
                req.calibration.display(),
                data_path.display()
            )));
        }
        let n = held.len();
        (
            all.select_sweeps(&held)?,
            format!("the {n} sweeps held out of the training"),
        )
    } else {
        let n = all.sweeps.len();
        let why = if req.data.is_some() {
            "every sweep of the given data"
        } else {
            "every sweep (the calibration trained on all of them: an in-sample check)"
        };
        (all, format!("{n} sweeps: {why}"))
    };
    let cov = result.covariance_matrix();
    for (j, p) in cal.params.iter().enumerate() {
        if !cov[(j, j)].is_finite() {
            return Err(Error::Usage(format!(
                "{}: parameter {} has an infinite variance (the training data do not \
                 identify it): fix it with `set` and calibrate again",
                req.calibration.display(),
                p.param
            )));
        }
    }
    let scale = match req.scale {
        BandScale::Chi2 => result.reduced_chi2.max(1.0),
        BandScale::Folds => match result.held_out_mean_square {
            Some(ms) if ms.is_finite() => ms.max(result.reduced_chi2).max(1.0),
            Some(_) => {
                return Err(Error::Usage(format!(
                    "{}: --scale folds: a fold's harmonic balance failed at a held-out point                      (held_out_mean_square = inf); use --scale chi2",
                    req.calibration.display()
                )));
            }
            None => {
                return Err(Error::Usage(format!(
                    "{}: --scale folds needs the cross validation's held_out_mean_square in                      [result]: calibrate with folds (e.g. fold_by = \"sweeps\") and validate                      the new result",
                    req.calibration.display()
                )));
            }
        },
        BandScale::None => 1.0,
    };
    let input_dof = model
        .excitation()
        .iter()
        .find(|x| x.name == data.input)
        .map(|x| x.at.label(model.dofs()));
    let channel_dofs = data
        .channels
        .iter()
        .map(|c| {
            model
                .sensors()
                .iter()
                .find(|s| s.name == c.name)
                .map(|s| s.at.label(model.dofs()))
        })
        .collect();
    let data = Arc::new(data);
    let prepared = prepare_on(&cal, &model, Arc::clone(&data), t)?;
    let mut obj = prepared.objective;
    let prediction = nlsim_calib::predict(
        &mut obj,
        &result.estimate,
        &cov,
        &BandConfig {
            level: req.level,
            scale,
        },
    )
    .map_err(|e| Error::Usage(format!("{}: {e}", req.calibration.display())))?;
    Ok(ValidationRun {
        request: req.clone(),
        calibration: cal,
        result,
        model_name: prepared.model_name,
        data_path,
        selection,
        prediction,
        data,
        input_dof,
        channel_dofs,
        geometry: model.geometry().to_vec(),
        seconds: t.elapsed().as_secs_f64(),
    })
}
