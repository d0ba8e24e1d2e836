//! Prediction with a band (`nlsim validate`, thesis §4.6): the ECL beam's cubic tip spring
//! and first-mode damping calibrated on two force levels predict two others.

use faer::Mat;
use nlsim_calib::{
    BandConfig, CalibrationConfig, FoldBy, FoldResult, FrfObjective, KFold, Noise, ObjectiveConfig,
    ParamSpec, Status, SweepPlan, TestData, calibrate, predict, synthesize,
};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Param, Parameterized};
use nlsim_reduction::{ReductionConfig, reduce};
use std::sync::Arc;

fn ecl() -> HbSystem {
    let fx = nlsim_fixtures::ecl_beam();
    let red = reduce(&fx.model, &ReductionConfig::lowest(4)).unwrap();
    HbSystem::from_model(
        &fx.model,
        &red,
        HarmonicSet::new(3, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap()
}

fn specs(sys: &HbSystem) -> Vec<ParamSpec> {
    let mode = sys
        .linear()
        .dominant_mode(sys.sensors()[0].port, 0..2)
        .unwrap();
    vec![
        ParamSpec::new(Param::element("tip_spring", "k3"), 1e8, 1e11),
        ParamSpec::new(Param::ModalDamping(mode), 0.002, 0.05),
    ]
}

/// The system's values of the calibrated parameters.
fn truth(sys: &HbSystem) -> Vec<f64> {
    let params: Vec<Param> = specs(sys).iter().map(|s| s.param.clone()).collect();
    sys.param_values(&params).unwrap()
}

fn levels(forces: &[f64]) -> Vec<SweepPlan> {
    forces
        .iter()
        .map(|&f| SweepPlan::linear(format!("{f} N up"), 22.0, 26.5, 19, f))
        .collect()
}

fn objective(sys: &HbSystem, data: TestData) -> FrfObjective {
    FrfObjective::new(sys, Arc::new(data), specs(sys), ObjectiveConfig::default()).unwrap()
}

/// On noise-free held-out data the prediction at the true parameters equals the data to the
/// harmonic balance's accuracy, whatever the band.
#[test]
fn noise_free_held_out_data_are_predicted_to_solver_accuracy() {
    let sys = ecl();
    let truth = truth(&sys);
    let held = synthesize(
        &sys,
        "shaker",
        &levels(&[0.1, 0.15]),
        3,
        Noise::relative(0.0),
        1,
    )
    .unwrap();
    let channels = held.channels.len();
    let mut obj = objective(&sys, held);
    let cov = Mat::from_fn(2, 2, |i, j| {
        if i == j {
            (0.01 * truth[i]).powi(2)
        } else {
            0.0
        }
    });
    let p = predict(&mut obj, &truth, &cov, &BandConfig::default()).unwrap();
    assert_eq!(p.values.len(), 2 * 19 * channels);
    for v in &p.values {
        assert!(v.log_error().abs() < 1e-9, "{v:?}");
        assert!(v.phase_error().abs() < 1e-9, "{v:?}");
    }
    for s in &p.sweeps {
        assert_eq!(s.inside_amplitude, 1.0);
        assert_eq!(s.failed, 0);
        assert!(s.rms_log < 1e-9);
    }
}

/// The band's parameter part is the linearised propagation `|∂ ln|Y|/∂p| σ_p`: checked against
/// central differences of the prediction at every point, one parameter at a time.
#[test]
fn the_parameter_band_matches_central_differences() {
    let sys = ecl();
    let truth = truth(&sys);
    let data = synthesize(&sys, "shaker", &levels(&[0.15]), 3, Noise::relative(0.0), 1).unwrap();
    let mut obj = objective(&sys, data);
    for j in 0..2 {
        let sd = 1e-3 * truth[j];
        let cov = Mat::from_fn(2, 2, |a, b| if a == j && b == j { sd * sd } else { 0.0 });
        let p = predict(&mut obj, &truth, &cov, &BandConfig::default()).unwrap();
        let h = 1e-4 * truth[j];
        let at = |d: f64, obj: &mut FrfObjective| {
            let mut v = truth.clone();
            v[j] += d;
            predict(obj, &v, &Mat::zeros(2, 2), &BandConfig::default()).unwrap()
        };
        let (up, down) = (at(h, &mut obj), at(-h, &mut obj));
        for (i, v) in p.values.iter().enumerate() {
            let dlog = (up.values[i].predicted.norm().ln() - down.values[i].predicted.norm().ln())
                / (2.0 * h);
            let dph = nlsim_calib::objective::wrap(
                up.values[i].predicted.arg() - down.values[i].predicted.arg(),
            ) / (2.0 * h);
            // Central differences carry O(h²) truncation and the solver's 1e-10 noise / h.
            let tol = 1e-4 * (dlog.abs() * sd).max(1e-6 * sd / h);
            assert!(
                (v.sd_log_param - dlog.abs() * sd).abs() < tol.max(1e-9),
                "param {j}, value {i}: band {:e} vs differences {:e}",
                v.sd_log_param,
                dlog.abs() * sd
            );
            assert!(
                (v.sd_phase_param - dph.abs() * sd).abs() < (1e-4 * dph.abs() * sd).max(1e-9),
                "param {j}, value {i}: phase band {:e} vs differences {:e}",
                v.sd_phase_param,
                dph.abs() * sd
            );
        }
    }
}

/// Values of the held-out 0.1 N and 0.15 N levels (2 % noise, seed `1000 + seed`) inside
/// the band of a calibration, pooled over seeds.
#[derive(Default)]
struct Coverage {
    amplitude: f64,
    phase: f64,
    values: usize,
}

impl Coverage {
    fn add(
        &mut self,
        sys: &HbSystem,
        cal: &nlsim_calib::Calibration,
        band: &BandConfig,
        seed: u64,
    ) {
        let held = synthesize(
            sys,
            "shaker",
            &levels(&[0.1, 0.15]),
            3,
            Noise::relative(0.02),
            1000 + seed,
        )
        .unwrap();
        let mut obj = objective(sys, held);
        let p = predict(&mut obj, &cal.estimate, &cal.cramer_rao.covariance, band).unwrap();
        for s in &p.sweeps {
            assert_eq!(s.failed, 0);
            self.amplitude += s.inside_amplitude * s.values as f64;
            self.phase += s.inside_phase * s.values as f64;
            self.values += s.values;
        }
    }

    /// Shares of amplitudes and phases inside, and the number of values.
    fn shares(&self) -> (f64, f64, usize) {
        let n = self.values as f64;
        (self.amplitude / n, self.phase / n, self.values)
    }
}

/// On synthetic data with the right noise model (2 %), the 95 % band of a calibration on the
/// 0.05 N and 0.2 N levels covers 90–99 % of the held-out 0.1 N and 0.15 N levels' values
/// (fresh noise), pooled over 20 seeds — the check of the band.
#[test]
fn the_95_percent_band_covers_held_out_values_at_its_level() {
    let sys = ecl();
    let cfg = CalibrationConfig {
        lhs_samples: 8,
        starts: 1,
        folds: 0,
        ..Default::default()
    };
    let mut cover = Coverage::default();
    for seed in 0..20u64 {
        let train = synthesize(
            &sys,
            "shaker",
            &levels(&[0.05, 0.2]),
            3,
            Noise::relative(0.02),
            seed,
        )
        .unwrap();
        let cal = calibrate(&objective(&sys, train), &cfg).unwrap();
        assert!(cal.status.is_converged(), "seed {seed}: {}", cal.status);
        cover.add(&sys, &cal, &BandConfig::default(), seed);
    }
    let (ca, cp, n) = cover.shares();
    eprintln!(
        "coverage of the 95 % band over {n} held-out values: amplitude {ca:.4}, phase {cp:.4}"
    );
    assert!((0.90..=0.99).contains(&ca), "amplitude coverage {ca}");
    assert!((0.90..=0.99).contains(&cp), "phase coverage {cp}");
}

/// The cross validation's held-out mean square weighs each fold's mean square by its
/// points: folds of 3 and 1 points with held-out rms 2 and 4 give (3·4 + 1·16)/4 = 7.
#[test]
fn the_held_out_mean_square_weighs_folds_by_their_points() {
    let fold = |rms: f64| FoldResult {
        values: vec![1.0],
        status: Status::Converged,
        held_out_rms: rms,
        training_rms: 1.0,
    };
    let kf = KFold::from_folds(vec![0, 0, 1, 0], vec![fold(2.0), fold(4.0)]).unwrap();
    assert_eq!(kf.held_out_mean_square(), 7.0);
    let failed = KFold::from_folds(vec![0, 1], vec![fold(2.0), fold(f64::INFINITY)]).unwrap();
    assert_eq!(failed.held_out_mean_square(), f64::INFINITY);
}

/// On synthetic data with the right noise model (2 %), leaving each of four training levels
/// out in turn predicts it at the noise level: the held-out mean square `s²` is 1 plus the
/// fold estimates' own spread (the two parameters fitted on three levels), so the band scaled by it (`nlsim validate --scale folds`) still covers
/// 90–99 % of the held-out 0.1 N and 0.15 N levels over 20 seeds.
#[test]
fn the_folds_scale_is_near_one_with_the_right_noise_and_its_band_covers() {
    let sys = ecl();
    let cfg = CalibrationConfig {
        lhs_samples: 8,
        starts: 1,
        folds: 1,
        fold_by: FoldBy::Sweeps,
        ..Default::default()
    };
    let mut cover = Coverage::default();
    let mut scales = Vec::new();
    for seed in 0..20u64 {
        let train = synthesize(
            &sys,
            "shaker",
            &levels(&[0.05, 0.08, 0.2, 0.25]),
            3,
            Noise::relative(0.02),
            seed,
        )
        .unwrap();
        let cal = calibrate(&objective(&sys, train), &cfg).unwrap();
        assert!(cal.status.is_converged(), "seed {seed}: {}", cal.status);
        let kf = cal.kfold.as_ref().unwrap();
        assert_eq!(kf.k, 4);
        let s2 = kf.held_out_mean_square();
        scales.push(s2);
        let band = BandConfig {
            scale: s2.max(cal.cramer_rao.reduced_chi2).max(1.0),
            ..BandConfig::default()
        };
        cover.add(&sys, &cal, &band, seed);
    }
    let mean = scales.iter().sum::<f64>() / scales.len() as f64;
    let (ca, cp, _) = cover.shares();
    eprintln!(
        "held-out mean square over 20 seeds: mean {mean:.4}, range {:.4}-{:.4}; coverage of the \
         folds-scaled 95 % band: amplitude {ca:.4}, phase {cp:.4}",
        scales.iter().cloned().fold(f64::INFINITY, f64::min),
        scales.iter().cloned().fold(0.0, f64::max)
    );
    // Each seed's s² is a mean of 4·19·2 = 152 squared residuals (sd 0.115 for noise alone),
    // the mean over 20 seeds has sd 0.026: 0.95 is two below 1, and 1.2 leaves the folds'
    // own spread (2 parameters fitted on 114 residuals: a few per cent) far inside.
    assert!(
        (0.95..=1.2).contains(&mean),
        "mean held-out mean square {mean}"
    );
    assert!((0.90..=0.99).contains(&ca), "amplitude coverage {ca}");
    assert!((0.90..=0.99).contains(&cp), "phase coverage {cp}");
}

/// Bad settings are errors, not panics.
#[test]
fn bad_band_settings_and_covariances_are_refused() {
    let sys = ecl();
    let data = synthesize(&sys, "shaker", &levels(&[0.1]), 3, Noise::relative(0.0), 1).unwrap();
    let mut obj = objective(&sys, data);
    let v = [1e9, 0.01];
    let e = predict(&mut obj, &v, &Mat::zeros(3, 3), &BandConfig::default()).unwrap_err();
    assert!(e.to_string().contains("covariance"), "{e}");
    let mut nan = Mat::zeros(2, 2);
    nan[(1, 1)] = f64::NAN;
    let e = predict(&mut obj, &v, &nan, &BandConfig::default()).unwrap_err();
    assert!(e.to_string().contains("entry (2, 2)"), "{e}");
    let e = predict(
        &mut obj,
        &v,
        &Mat::zeros(2, 2),
        &BandConfig {
            level: 0.0,
            scale: 1.0,
        },
    )
    .unwrap_err();
    assert!(e.to_string().contains("band level"), "{e}");
}
