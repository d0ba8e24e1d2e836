//! What `nlsim validate` shows and writes: the scores per sweep as a table, every predicted
//! value with its band as CSV, and a report folder with a plot per sweep and compared
//! harmonic (measured, predicted, band; the numbers in `report.h5`).
use crate::commands::validate::run::{BandScale, ValidationRun};
use crate::error::{Error, Result};
use crate::present::plot::Lines;
use faer::c64;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Plots per report at most (sweeps × channels × compared harmonics beyond are in the CSV).
pub const MAX_PLOTS: usize = 48;

/// Pooled over every predicted value of `run`: `(rms ln|Y| error, rms phase error, fraction
/// inside the amplitude band, fraction inside the phase band, values)`.
pub fn pooled(run: &ValidationRun) -> (f64, f64, f64, f64, usize) {
    let z = run.prediction.z;
    let v: Vec<_> = run
        .prediction
        .values
        .iter()
        .filter(|v| v.is_predicted())
        .collect();
    let n = v.len().max(1) as f64;
    let rms = |f: &dyn Fn(&&nlsim_calib::PredictedValue) -> f64| {
        (v.iter().map(|x| f(x).powi(2)).sum::<f64>() / n).sqrt()
    };
    let frac = |f: &dyn Fn(&&nlsim_calib::PredictedValue) -> bool| {
        v.iter().filter(|x| f(x)).count() as f64 / n
    };
    (
        rms(&|x| x.log_error()),
        rms(&|x| x.phase_error()),
        frac(&|x| x.log_error().abs() <= z * x.sd_log()),
        frac(&|x| x.phase_error().abs() <= z * x.sd_phase()),
        v.len(),
    )
}

impl ValidationRun {
    /// The summary for people: what was predicted, the band, the table of scores and the
    /// pooled figures.
    pub fn summary(&self) -> Vec<String> {
        let p = &self.prediction;
        let r = &self.result;
        let mut out = vec![
            format!(
                "nlsim validate: {} with the estimates of {} ({} parameters, training reduced \
                 chi2 {:.3})",
                self.model_name,
                self.request.calibration.display(),
                r.estimate.len(),
                r.reduced_chi2
            ),
            format!("data: {}, {}", self.data_path.display(), self.selection),
            format!(
                "band: {:.0} % (±{:.3} sigma) from the parameter covariance through the HB \
                 sensitivities (linearised) and the data's noise model, variances scaled by \
                 {:.3}{}",
                100.0 * p.band.level,
                p.z,
                p.band.scale,
                match self.request.scale {
                    BandScale::Chi2 if r.reduced_chi2 > 1.0 => " (the training reduced chi2)",
                    BandScale::Chi2 => " (training reduced chi2 <= 1: not scaled)",
                    BandScale::Folds =>
                        " (--scale folds: the cross validation's held-out \
                                          mean square, or the reduced chi2 where larger)",
                    BandScale::None => " (--scale none)",
                }
            ),
            format!(
                "{:<14} {:>6} {:>11} {:>10} {:>8} {:>8} {:>9} {:>19} {:>31}",
                "sweep",
                "points",
                "rms ln|Y|",
                "rms phase",
                "in band",
                "phase in",
                "chi2",
                "peak measured",
                "peak predicted [band]"
            ),
        ];
        for s in &p.sweeps {
            let (fm, am) = s.peak_measured;
            let (fp, ap, lo, hi) = s.peak_predicted;
            out.push(format!(
                "{:<14} {:>6} {:>11.4} {:>10.4} {:>7.1}% {:>7.1}% {:>9.3} {:>8.3} Hz {:>8.4} {:>8.3} Hz {:>8.4} [{:.4}, {:.4}]{}",
                s.label,
                s.values,
                s.rms_log,
                s.rms_phase,
                100.0 * s.inside_amplitude,
                100.0 * s.inside_phase,
                s.chi2,
                fm,
                am,
                fp,
                ap,
                lo,
                hi,
                if s.failed > 0 {
                    format!("  ({} not converged)", s.failed)
                } else {
                    String::new()
                }
            ));
        }
        let (la, ph, ia, ip, n) = pooled(self);
        let mean_la =
            p.sweeps.iter().map(|s| s.rms_log).sum::<f64>() / p.sweeps.len().max(1) as f64;
        out.push(format!(
            "all {n} values: rms ln|Y| error {la:.4} (mean over sweeps {mean_la:.4}), rms phase \
             error {ph:.4} rad, {:.1} % of amplitudes and {:.1} % of phases inside the band",
            100.0 * ia,
            100.0 * ip
        ));
        out.push(format!("validated in {:.2} s", self.seconds));
        out
    }

    /// The scores, one row per sweep.
    pub fn scores_csv(&self) -> String {
        let mut s = String::from(
            "sweep,points,failed,rms_log_error,rms_phase_error_rad,inside_amplitude,inside_phase,\
             chi2,peak_measured_hz,peak_measured,peak_predicted_hz,peak_predicted,\
             peak_predicted_lower,peak_predicted_upper\n",
        );
        for w in &self.prediction.sweeps {
            let _ = writeln!(
                s,
                "{},{},{},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?}",
                crate::formats::files::csv_field(&w.label),
                w.values,
                w.failed,
                w.rms_log,
                w.rms_phase,
                w.inside_amplitude,
                w.inside_phase,
                w.chi2,
                w.peak_measured.0,
                w.peak_measured.1,
                w.peak_predicted.0,
                w.peak_predicted.1,
                w.peak_predicted.2,
                w.peak_predicted.3
            );
        }
        s
    }

    /// Every predicted value: measured and predicted harmonic, errors and standard
    /// deviations, and whether it lies in the band.
    pub fn prediction_csv(&self) -> String {
        let d = &self.data;
        let z = self.prediction.z;
        let mut s = String::from(
            "sweep,step,frequency_hz,force1_amplitude,channel,harmonic,measured_re,measured_im,\
             predicted_re,predicted_im,log_error,phase_error_rad,sd_log_param,sd_log_noise,\
             sd_phase_param,sd_phase_noise,inside_amplitude,inside_phase\n",
        );
        for v in &self.prediction.values {
            let _ = writeln!(
                s,
                "{},{},{:?},{:?},{},{},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{:?},{},{}",
                crate::formats::files::csv_field(&d.sweeps[v.id.sweep].label),
                v.id.step + 1,
                v.frequency_hz,
                v.force,
                crate::formats::files::csv_field(&d.channels[v.channel].name),
                v.harmonic,
                v.measured.re,
                v.measured.im,
                v.predicted.re,
                v.predicted.im,
                v.log_error(),
                v.phase_error(),
                v.sd_log_param,
                v.sd_log_noise,
                v.sd_phase_param,
                v.sd_phase_noise,
                v.log_error().abs() <= z * v.sd_log(),
                v.phase_error().abs() <= z * v.sd_phase()
            );
        }
        s
    }
}

impl ValidationRun {
    /// The prediction as universal file functions (dataset 58, function type 4): per sweep,
    /// channel and compared harmonic `k`, the predicted `Y_k/F₁` and the measured one (`F₁` the
    /// step's measured complex drive fundamental; per volt for voltage-driven data) over the
    /// sweep's step frequencies, at the channel's sensor DOF per the drive's DOF (node 0 where
    /// the model has none). ID line 1 names sweep, channel, harmonic and which of the two.
    pub fn prediction_uff(&self) -> Vec<crate::formats::uff_write::UffFunction> {
        use crate::formats::uff_write::{Abscissa, UffFunction, node_direction, quantity_code};
        use std::collections::BTreeMap;
        let d = &self.data;
        // (sweep, channel, harmonic) → the sweep's values in step order.
        let mut groups: BTreeMap<(usize, usize, usize), Vec<&nlsim_calib::PredictedValue>> =
            BTreeMap::new();
        for v in &self.prediction.values {
            groups
                .entry((v.id.sweep, v.channel, v.harmonic))
                .or_default()
                .push(v);
        }
        let reference = self.input_dof.map_or((0, 0), node_direction);
        let per = match d.drive {
            nlsim_calib::Drive::Force => (13, "F1"),
            nlsim_calib::Drive::Voltage => (0, "V1"),
        };
        let mut out = Vec::new();
        for ((sweep, c, k), mut values) in groups {
            values.sort_by_key(|v| v.id.step);
            let hz: Vec<f64> = values.iter().map(|v| v.frequency_hz).collect();
            let f1: Vec<c64> = values.iter().map(|v| d.step(v.id).force[0]).collect();
            let channel = &d.channels[c];
            let which = if k == 1 {
                "fundamental".to_string()
            } else {
                format!("harmonic {k}")
            };
            for (what, pick) in [
                (
                    "predicted",
                    (|v: &nlsim_calib::PredictedValue| v.predicted) as fn(&_) -> c64,
                ),
                ("measured", |v: &nlsim_calib::PredictedValue| v.measured),
            ] {
                out.push(UffFunction {
                    id: format!(
                        "{what} {}: {} {which} / {} {}",
                        d.sweeps[sweep].label, channel.name, d.input, per.1
                    ),
                    function_type: 4,
                    response: self.channel_dofs[c].map_or((0, 0), node_direction),
                    reference,
                    abscissa_type: 18,
                    ordinate_type: quantity_code(channel.quantity),
                    denominator_type: per.0,
                    abscissa: Abscissa::Uneven(hz.clone()),
                    values: values.iter().zip(&f1).map(|(v, f)| pick(v) / f).collect(),
                    complex: true,
                });
            }
        }
        out
    }
}

/// What `nlsim validate --out` writes, for the usage error.
pub const OUT_HINT: &str = ".csv (every predicted value, as prediction.csv of the report) or \
                            .uff/.unv (universal file: dataset 58 per sweep, channel and \
                            harmonic, predicted and measured)";

/// The format of `--out PATH` (CSV or universal file), or the usage error naming it.
pub fn out_format(path: &Path) -> Result<crate::formats::files::Format> {
    use crate::formats::files::Format;
    match Format::of_any(path, OUT_HINT, true)? {
        Format::Hdf5 => Err(Error::Usage(format!(
            "--out {}: validate writes its prediction as {OUT_HINT}; the HDF5 numbers are in \
             report.h5 of --report",
            path.display()
        ))),
        f => Ok(f),
    }
}

/// Writes the prediction of `run` to `path`: CSV or universal file by extension
/// ([`OUT_HINT`], [`out_format`]), atomically.
pub fn write_prediction(path: &Path, run: &ValidationRun) -> Result<()> {
    if out_format(path)? == crate::formats::files::Format::Csv {
        crate::formats::files::write_text_atomically(path, &run.prediction_csv())
    } else {
        crate::formats::uff_write::write_functions(
            path,
            &run.prediction_uff(),
            false,
            &run.geometry,
        )
    }
}

/// Writes the report folder of `run` into `dir`: `summary.txt`, `scores.csv`,
/// `prediction.csv`, and per sweep, channel and compared harmonic (at most [`MAX_PLOTS`]) a
/// plot of `|Y|/|F₁|` measured, predicted and the band's edges (SVG, PNG, numbers in
/// `report.h5`), and the page. Returns the files written.
pub fn write_report(dir: &Path, run: &ValidationRun) -> Result<Vec<PathBuf>> {
    let report = crate::present::report::Report::create(
        dir,
        &format!("nlsim validate: {}", run.model_name),
        &crate::present::report::command_line(),
        &run.calibration.model,
    )?;
    report.model_name(&run.model_name);
    report.section_with("Summary", &run.summary());
    report.table(
        "scores",
        crate::present::report::Table::from_csv("Scores per sweep", &run.scores_csv()),
    )?;
    let mut written = Vec::new();
    for (name, body) in [
        ("summary.txt", run.summary().join("\n") + "\n"),
        ("scores.csv", run.scores_csv()),
        ("prediction.csv", run.prediction_csv()),
    ] {
        let p = dir.join(name);
        crate::formats::files::write_text_atomically(&p, &body)?;
        written.push(p);
    }
    report.section("Measured vs predicted, with the band");
    let d = &run.data;
    let z = run.prediction.z;
    let mut plots = 0;
    'all: for (si, sw) in d.sweeps.iter().enumerate() {
        for (ci, ch) in d.channels.iter().enumerate() {
            for &k in &run.prediction.harmonics {
                if plots == MAX_PLOTS {
                    report.skip(&format!(
                        "plots after the first {MAX_PLOTS} left out: every value is in \
                         prediction.csv"
                    ));
                    break 'all;
                }
                let vals: Vec<_> = run
                    .prediction
                    .values
                    .iter()
                    .filter(|v| v.id.sweep == si && v.channel == ci && v.harmonic == k)
                    .collect();
                if vals.is_empty() {
                    continue;
                }
                let pts = |f: &dyn Fn(&nlsim_calib::PredictedValue) -> f64| -> Vec<(f64, f64)> {
                    vals.iter().map(|v| (v.frequency_hz, f(v))).collect()
                };
                let series = vec![
                    (
                        "measured".to_string(),
                        pts(&|v| v.measured.norm() / v.force),
                    ),
                    (
                        "predicted".to_string(),
                        pts(&|v| v.predicted.norm() / v.force),
                    ),
                    (
                        format!("band {:.0} %, upper", 100.0 * run.prediction.band.level),
                        pts(&|v| v.predicted.norm() / v.force * (z * v.sd_log()).exp()),
                    ),
                    (
                        format!("band {:.0} %, lower", 100.0 * run.prediction.band.level),
                        pts(&|v| v.predicted.norm() / v.force * (-z * v.sd_log()).exp()),
                    ),
                ];
                let fig = Lines {
                    title: format!(
                        "{}: sweep {}, {} harmonic {k}",
                        run.model_name, sw.label, ch.name
                    ),
                    x_desc: "frequency (Hz)".into(),
                    y_desc: crate::present::frf_plot::harmonic_over_force_axis(ch.quantity, k),
                    series,
                };
                let safe = crate::formats::files::file_name_part(&format!(
                    "{}_{}_h{k}",
                    sw.label, ch.name
                ));
                written.extend(report.figure(&format!("frf_{safe}"), &fig)?);
                plots += 1;
            }
        }
    }
    written.push(report.finish()?);
    written.push(dir.join(crate::present::report::DATA));
    Ok(written)
}
