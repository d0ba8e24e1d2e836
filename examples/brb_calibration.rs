//! Calibration on real measurements: the Brake–Reuss beam (two steel beams bolted through a
//! lap joint) tested by stepped sine around its first bending mode at 4 force-controlled and
//! 8 response-controlled levels (`../shared/data/brb/`, read its README).
//!
//! Model: one modal degree of freedom for the first bending mode (`mode1.f`, `mode1.zeta`,
//! and its modal mass `mode1.m` at the drive/response point, since a modal model has no
//! absolute shape scale) with the joint's dissipation as a quadratic damper
//! `g = c2 u̇|u̇|` (thesis eq. 7), whose equivalent viscous damping grows with amplitude as
//! the README says the beam's does. The best linear model is the same without the damper.
//!
//! Both are calibrated by Levenberg–Marquardt on the log-magnitude and phase of the
//! fundamental at the four force-controlled levels only, with the measured force at every
//! step, and then predict the eight response-controlled levels they have not seen.
//!
//! Run: `cargo run --release --example brb_calibration [PATH/TO/stepped_sine.csv]`. The test
//! suite runs it and checks that the nonlinear model predicts the held-out levels better.

use nlsim::calib::lhs::Spacing;
use nlsim::prelude::*;
use std::f64::consts::PI;
use std::sync::Arc;

/// The rows of one level: `(frequency Hz, force N, acceleration m/s², phase rad)`.
type Level = Vec<(f64, f64, f64, f64)>;

/// The levels by `(control, level)`, in file order.
type Levels = Vec<((String, usize), Level)>;

/// Reads the CSV into `(control, level) → rows`, in file order; errors name the line.
fn read(path: &str) -> Result<Levels, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{path}: {e}"))?;
    let mut lines = text.lines().enumerate();
    let header = lines.next().map(|(_, l)| l).unwrap_or("");
    let want = "control,level,frequency_hz,force_amplitude_n,accel_amplitude_m_s2,phase_rad";
    if header.trim() != want {
        return Err(format!("{path}:1: expected the header '{want}'"));
    }
    let mut out: Levels = Vec::new();
    for (i, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != 6 {
            return Err(format!("{path}:{}: {} columns, expected 6", i + 1, f.len()));
        }
        let num = |c: usize| -> Result<f64, String> {
            f[c].trim()
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| {
                    format!(
                        "{path}:{}: column {} is not a number: '{}'",
                        i + 1,
                        c + 1,
                        f[c]
                    )
                })
        };
        let key = (
            f[0].trim().to_string(),
            f[1].trim()
                .parse::<usize>()
                .map_err(|_| format!("{path}:{}: bad level '{}'", i + 1, f[1]))?,
        );
        let row = (num(2)?, num(3)?, num(4)?, num(5)?);
        match out.iter_mut().find(|(k, _)| *k == key) {
            Some((_, rows)) => rows.push(row),
            None => out.push((key, vec![row])),
        }
    }
    Ok(out)
}

/// The levels as test data: the response phase in the file is that of a displacement-like
/// response (−π/2 at resonance), so the acceleration's is that plus π.
fn test_data(levels: &[((String, usize), Level)], noise: f64) -> TestData {
    let sweeps = levels
        .iter()
        .map(|((control, level), rows)| Sweep {
            label: format!("{control}-{level}"),
            // The README does not state the direction; rows are ascending.
            direction: SweepDirection::Up,
            steps: rows
                .iter()
                .map(|&(f, force, acc, phase)| Step {
                    frequency_hz: f,
                    force: vec![faer::c64::new(force, 0.0)],
                    response: faer::Mat::from_fn(1, 1, |_, _| {
                        faer::c64::from_polar(acc, phase + PI)
                    }),
                    sigma: faer::Mat::new(),
                })
                .collect(),
        })
        .collect();
    TestData {
        input: "shaker".into(),
        drive: nlsim_calib::Drive::Force,
        channels: vec![Channel {
            name: "accel".into(),
            quantity: Quantity::Acceleration,
            noise: Noise::relative(noise),
        }],
        harmonics: 1,
        sweeps,
    }
}

/// One modal DOF at 80 Hz with 0.2 % damping, 1 kg, with the quadratic damper (`c2 = 0`
/// for the linear model).
fn model(nonlinear: bool) -> nlsim::kernel::Result<HbSystem> {
    let w = 2.0 * PI * 80.0;
    let k = SparseSym::from_dense_rows("K", &[vec![w * w]])?;
    let m = SparseSym::diagonal("M", &[1.0])?;
    let mut b = Model::builder("brb_mode1", DofMap::scalar(1), m, k)
        .damping(Damping::Rayleigh {
            alpha: 2.0 * 0.002 * w,
            beta: 0.0,
        })
        .excitation("shaker", "1:u", 1.0)
        .sensor("accel", "1:u", Quantity::Acceleration);
    // The linear model keeps the damper at c2 = 0 (not calibrated): the same solver path.
    b = b.element(NonlinearElement::new(
        "joint",
        Law::QuadraticDamping {
            c2: if nonlinear { 1.0 } else { 0.0 },
        },
        Coupling::single(0),
    )?);
    let model = b.build()?;
    let reduced = reduce(&model, &ReductionConfig::lowest(1))?;
    // Three harmonics: the quadratic damper's odd harmonics feed back on the fundamental.
    HbSystem::from_model(
        &model,
        &reduced,
        HarmonicSet::new(3, 1)?,
        HbConfig::default(),
    )
}

fn specs(nonlinear: bool) -> Vec<ParamSpec> {
    let mut s = vec![
        ParamSpec {
            param: Param::ModalFrequency(0),
            lower: 78.0,
            upper: 83.0,
            spacing: Spacing::Linear,
        },
        ParamSpec::new(Param::ModalDamping(0), 1e-4, 0.05),
        ParamSpec::new(Param::ModalMass(0), 1e-3, 1e2),
    ];
    if nonlinear {
        s.push(ParamSpec::new(Param::element("joint", "c2"), 1e-4, 1e4));
    }
    s
}

/// Per level: measured and predicted peak accelerance, rms log-amplitude and phase errors.
struct LevelFit {
    label: String,
    measured_peak: f64,
    predicted_peak: f64,
    rms_log_amplitude: f64,
    rms_phase: f64,
}

fn assess(obj: &mut FrfObjective, values: &[f64]) -> nlsim::kernel::Result<Vec<LevelFit>> {
    let ev = obj.evaluate_values(values, None, false)?;
    let data = obj.data().clone();
    let mut out = Vec::new();
    for (s, sw) in data.sweeps.iter().enumerate() {
        let (mut mp, mut pp, mut la, mut ph, mut n) = (0.0f64, 0.0f64, 0.0, 0.0, 0);
        for pr in ev.points.iter().filter(|p| p.id.sweep == s) {
            let st = &sw.steps[pr.id.step];
            let f = st.force[0].norm();
            let (ym, yd) = (pr.response[(0, 0)], st.response[(0, 0)]);
            mp = mp.max(yd.norm() / f);
            if ym.re.is_nan() {
                continue;
            }
            pp = pp.max(ym.norm() / f);
            la += (ym.norm() / yd.norm()).ln().powi(2);
            ph += nlsim::calib::objective::wrap(ym.arg() - yd.arg()).powi(2);
            n += 1;
        }
        out.push(LevelFit {
            label: sw.label.clone(),
            measured_peak: mp,
            predicted_peak: pp,
            rms_log_amplitude: (la / n.max(1) as f64).sqrt(),
            rms_phase: (ph / n.max(1) as f64).sqrt(),
        });
    }
    Ok(out)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let path = std::env::args().nth(1).unwrap_or_else(|| {
        concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../shared/data/brb/stepped_sine.csv"
        )
        .to_string()
    });
    let levels = read(&path)?;
    let (train, held): (Vec<_>, Vec<_>) = levels.into_iter().partition(|((c, _), _)| c == "force");
    // No noise estimate comes with the data: 2 % of each amplitude (and 0.02 rad of phase)
    // weights the points; the reduced χ² printed below says how well that matches.
    let noise = 0.02;
    let (train, held) = (
        Arc::new(test_data(&train, noise)),
        Arc::new(test_data(&held, noise)),
    );
    let objective = ObjectiveConfig {
        harmonics: vec![1],
        form: Form::LogMagnitudePhase,
        ..ObjectiveConfig::default()
    };
    let config = CalibrationConfig {
        lhs_samples: 48,
        seed: 2022,
        starts: 3,
        folds: 4,
        ..Default::default()
    };
    println!(
        "Brake–Reuss beam: {} training sweeps ({} points), {} held-out sweeps",
        train.sweeps.len(),
        train.n_points(),
        held.sweeps.len()
    );
    let mut mean_errors = Vec::new();
    for nonlinear in [false, true] {
        let name = if nonlinear {
            "nonlinear (quadratic joint damping)"
        } else {
            "linear"
        };
        let sys = model(nonlinear)?;
        let obj = FrfObjective::new(&sys, train.clone(), specs(nonlinear), objective.clone())?;
        let cal = calibrate(&obj, &config)?;
        println!(
            "\n{name} model: {} after {} LM iterations, cost {:.4e}, reduced chi2 {:.2}",
            cal.status, cal.runs[0].report.iterations, cal.cost, cal.cramer_rao.reduced_chi2
        );
        let kf = cal.kfold.as_ref();
        for (j, p) in cal.params.iter().enumerate() {
            println!(
                "  {:<10} = {:>12.6e}  Cramér–Rao ±{:.2e}  {}-fold ±{:.2e}{}{}",
                p.to_string(),
                cal.estimate[j],
                cal.cramer_rao.std[j],
                config.folds,
                kf.map_or(f64::NAN, |k| k.jackknife_std[j]),
                if cal.at_bound[j] { "  [at bound]" } else { "" },
                if cal.poorly_identified[j] {
                    "  [poorly identified]"
                } else {
                    ""
                },
            );
        }
        let mut sys_fit = sys.clone();
        sys_fit.set_params(&cal.params, &cal.estimate)?;
        let mut pred =
            FrfObjective::new(&sys_fit, held.clone(), specs(nonlinear), objective.clone())?;
        let fits = assess(&mut pred, &cal.estimate)?;
        println!(
            "  level        peak |A/F| measured  predicted   rms ln|A| error  rms phase error (rad)"
        );
        for f in &fits {
            println!(
                "  {:<12} {:>12.2} {:>16.2} {:>15.4} {:>16.4}",
                f.label, f.measured_peak, f.predicted_peak, f.rms_log_amplitude, f.rms_phase
            );
        }
        let mean_la = fits.iter().map(|f| f.rms_log_amplitude).sum::<f64>() / fits.len() as f64;
        let mean_ph = fits.iter().map(|f| f.rms_phase).sum::<f64>() / fits.len() as f64;
        println!("  held-out mean: rms ln|A| error {mean_la:.4}, rms phase error {mean_ph:.4} rad");
        mean_errors.push((mean_la, mean_ph));
    }
    let (lin, nl) = (mean_errors[0], mean_errors[1]);
    println!(
        "\nheld-out levels: the nonlinear model's log-amplitude error is {:.2}x smaller and its phase error {:.2}x smaller than the linear model's",
        lin.0 / nl.0,
        lin.1 / nl.1
    );
    Ok(())
}
