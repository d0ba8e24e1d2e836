//! What calibration batches add: the fold statistics and best candidates of a merge, and the
//! candidates file `nlsim calibrate --candidates` reads.

use crate::commands::calibrate::request::CalibrationRequest;
use crate::formats::files::str_attr;
use hdf5_metno as hdf5;

use super::*;

/// A calibration job read back: values, `[cost, NaN]` (a candidate) or `[held-out rms,
/// training rms]` and the status (a fold).
pub(super) type CalibRow = (Vec<f64>, [f64; 2], String);

/// The values and `[cost, NaN]` (a candidate) or `[held-out rms, training rms]` and status
/// (a fold) of a calibration job group; `None` for a job that failed.
pub(super) fn read_calib_job(g: &hdf5::Group) -> Option<CalibRow> {
    if g.attr("ok").and_then(|a| a.read_scalar::<u8>()).ok() != Some(1) {
        return None;
    }
    let values = g.dataset("values").ok()?.read_raw::<f64>().ok()?;
    let f = |n: &str| g.attr(n).and_then(|a| a.read_scalar::<f64>()).ok();
    if let Some(c) = f("cost") {
        return Some((values, [c, f64::NAN], String::new()));
    }
    let status: hdf5::types::VarLenUnicode = g.attr("status").ok()?.read_scalar().ok()?;
    Some((
        values,
        [f("held_out_rms")?, f("training_rms")?],
        status.as_str().to_string(),
    ))
}

/// Root datasets of a merged calibration batch: `cost` per candidate, or per fold
/// `held_out_rms`, `training_rms` and the fold statistics `kfold_mean`, `kfold_std`,
/// `jackknife_std`, `kfold_covariance` (when every fold ran). Returns summary lines.
pub(super) fn write_calib_summary(
    out: &hdf5::File,
    b: &Batch,
    names: &[String],
    rows: &[Option<CalibRow>],
) -> hdf5::Result<Vec<String>> {
    let col = |i: usize| -> Vec<f64> {
        rows.iter()
            .map(|r| r.as_ref().map_or(f64::NAN, |r| r.1[i]))
            .collect()
    };
    let put = |name: &str, v: &[f64], dims: &str| -> hdf5::Result<()> {
        let d = out.new_dataset::<f64>().shape(v.len()).create(name)?;
        d.write_raw(v)?;
        str_attr(&d, "dims", dims)
    };
    let mut lines = Vec::new();
    match &b.command {
        BatchCommand::CalibrateCandidates(req) => {
            let cost = col(0);
            put(
                "cost",
                &cost,
                "job (= candidate; NaN: failed); cost ½‖r‖², infinite where a point failed",
            )?;
            let mut order: Vec<usize> = (0..cost.len()).filter(|&i| cost[i].is_finite()).collect();
            order.sort_by(|&a, &c| cost[a].total_cmp(&cost[c]).then(a.cmp(&c)));
            for &i in order.iter().take(req.config.starts) {
                let v = rows[i].as_ref().map(|r| &r.0[..]).unwrap_or(&[]);
                let vals: Vec<String> = names
                    .iter()
                    .zip(v)
                    .map(|(n, x)| format!("{n} = {x:.6e}"))
                    .collect();
                lines.push(format!(
                    "candidate {i}: cost {:.6e} at {}",
                    cost[i],
                    vals.join(", ")
                ));
            }
            lines.push(format!(
                "{} of {} candidates with a finite cost; go on with `nlsim calibrate --config \
                 FILE --candidates {}`",
                order.len(),
                cost.len(),
                b.merged_path().display()
            ));
        }
        BatchCommand::CalibrateFolds(req, estimate) => {
            put("held_out_rms", &col(0), "job (= fold)")?;
            put("training_rms", &col(1), "job (= fold)")?;
            let folds: Option<Vec<nlsim_calib::FoldResult>> = rows
                .iter()
                .map(|r| {
                    let (values, [h, t], status) = r.as_ref()?;
                    Some(nlsim_calib::FoldResult {
                        values: values.clone(),
                        status: status.parse().ok()?,
                        held_out_rms: *h,
                        training_rms: *t,
                    })
                })
                .collect();
            let n_points = req_points(req);
            match (folds, n_points) {
                (Some(folds), Some(n_points)) => {
                    let fold_of =
                        nlsim_calib::fold_assignment(n_points, req.config.folds, req.config.seed);
                    if let Ok(k) = nlsim_calib::KFold::from_folds(fold_of, folds) {
                        put("kfold_mean", &k.mean, "parameter")?;
                        put("kfold_std", &k.std, "parameter")?;
                        put("jackknife_std", &k.jackknife_std, "parameter")?;
                        let n = k.mean.len();
                        let cov: Vec<f64> =
                            (0..n * n).map(|i| k.covariance[(i / n, i % n)]).collect();
                        let d = out
                            .new_dataset::<f64>()
                            .shape((n, n))
                            .create("kfold_covariance")?;
                        d.write_raw(&cov)?;
                        for (j, name) in names.iter().enumerate() {
                            lines.push(format!(
                                "{name}: estimate {:.6e}, {}-fold mean {:.6e}, jackknife std \
                                 {:.3e} ({:.3} % of the estimate)",
                                estimate[j],
                                k.k,
                                k.mean[j],
                                k.jackknife_std[j],
                                100.0 * k.jackknife_std[j] / estimate[j].abs()
                            ));
                        }
                        let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
                        lines.push(format!(
                            "mean rms weighted residual: training {:.3}, held out {:.3}",
                            mean(&k.training_rms),
                            mean(&k.held_out_rms)
                        ));
                    }
                }
                _ => lines.push(
                    "fold statistics left out: a fold failed or the test data cannot be read"
                        .into(),
                ),
            }
        }
        _ => {}
    }
    Ok(lines)
}

/// Data points of a calibration request's test data (`None` if it cannot be read now).
fn req_points(req: &CalibrationRequest) -> Option<usize> {
    let model = crate::commands::setup::load_for_run(&req.model, &req.model_sets()).ok()?;
    crate::commands::calibrate::run::training_data(req, &model)
        .ok()
        .map(|d| d.n_points())
}
