//! Harmonics of a dwell from its time histories ([`nlsim_calib::extract_dwell`]) against
//! signals built from known harmonics: closed-form truth, no other estimator involved.

use faer::c64;
use nlsim_calib::{DwellConfig, Gaussian, extract_dwell};
use std::f64::consts::PI;

/// `Re Σ_k X_k e^{ik 2π f t}` plus `mean`, sampled at `rate` for `n` samples.
fn multi_sine(x: &[c64], mean: f64, f: f64, rate: f64, n: usize) -> Vec<f64> {
    (0..n)
        .map(|i| {
            let t = i as f64 / rate;
            mean + x
                .iter()
                .enumerate()
                .map(|(k, z)| (*z * c64::cis((k + 1) as f64 * 2.0 * PI * f * t)).re)
                .sum::<f64>()
        })
        .collect()
}

/// The harmonics turned so that `drive`'s fundamental is real and positive (what
/// `extract_dwell` reports).
fn turned(x: &[c64], drive: c64) -> Vec<c64> {
    let phi = drive.arg();
    x.iter()
        .enumerate()
        .map(|(k, z)| *z * c64::cis(-((k + 1) as f64) * phi))
        .collect()
}

/// Largest error of the estimated harmonics of signal `s` relative to the true
/// fundamental's amplitude.
fn worst(d: &nlsim_calib::Dwell, s: usize, want: &[c64]) -> f64 {
    (0..want.len())
        .map(|k| (d.harmonics[(s, k)] - want[k]).norm() / want[0].norm())
        .fold(0.0, f64::max)
}

/// Leakage: 37.3 periods at 41.37 samples per period (neither an integer), the frequency
/// guessed 1 % off: the refined frequency is the true one to 1e-10 and every harmonic of
/// drive and response (0..3) is within 1e-6 of the fundamental — the check. The LS
/// fit is exact for exact data, so what is left is rounding (about 1e-12).
#[test]
fn non_integer_periods_and_a_wrong_frequency_leak_nothing() {
    let (f, rate) = (24.17, 24.17 * 41.37);
    let n = (37.3 * 41.37) as usize;
    let drive = [
        c64::new(0.8, 0.3),
        c64::new(0.02, -0.01),
        c64::new(0.004, 0.003),
    ];
    let resp = [
        c64::new(-1.2, 2.1),
        c64::new(0.3, 0.05),
        c64::new(-0.11, 0.2),
    ];
    let signals = [
        multi_sine(&drive, 0.05, f, rate, n),
        multi_sine(&resp, -0.3, f, rate, n),
    ];
    let refs: Vec<&[f64]> = signals.iter().map(Vec::as_slice).collect();
    let cfg = DwellConfig::default();
    for guess in [Some(f * 1.01), Some(f * 0.99), None] {
        let d = extract_dwell(&["force", "accel"], &refs, rate, guess, &cfg).unwrap();
        assert!(
            (d.frequency_hz - f).abs() <= 1e-10 * f,
            "{guess:?}: {}",
            d.frequency_hz
        );
        let e0 = worst(&d, 0, &turned(&drive, drive[0]));
        let e1 = worst(&d, 1, &turned(&resp, drive[0]));
        assert!(e0 <= 1e-6 && e1 <= 1e-6, "{guess:?}: {e0:.2e} {e1:.2e}");
        assert!(d.settled && d.unsettled_periods == 0, "{d:?}");
        assert!((d.mean[1] + 0.3).abs() < 1e-9);
        assert!(d.harmonics[(0, 0)].im.abs() < 1e-12 && d.harmonics[(0, 0)].re > 0.0);
        eprintln!("guess {guess:?}: errors {e0:.1e} {e1:.1e}");
    }
}

/// A decaying free response at another frequency on top of the steady state: the periods
/// it spoils are found and discarded, and the harmonics of the rest are the steady state's.
#[test]
fn the_transient_is_found_and_left_out() {
    let (f, rate) = (10.0, 1000.0);
    let n = 6000; // 60 periods
    let drive = [c64::new(1.0, 0.0), c64::new(0.0, 0.0)];
    let resp = [c64::new(0.5, -0.8), c64::new(0.01, 0.02)];
    let mut y = multi_sine(&resp, 0.0, f, rate, n);
    // Free response at 13.7 Hz, decaying with a 0.15 s time constant: e^(-t/0.15) falls
    // below 1e-6 after about 2.1 s (21 periods).
    for (i, v) in y.iter_mut().enumerate() {
        let t = i as f64 / rate;
        *v += 0.6 * (-t / 0.15).exp() * (2.0 * PI * 13.7 * t).sin();
    }
    let x = multi_sine(&drive, 0.0, f, rate, n);
    let cfg = DwellConfig {
        harmonics: 2,
        ..DwellConfig::default()
    };
    let d = extract_dwell(&["force", "tip"], &[&x, &y], rate, Some(f), &cfg).unwrap();
    assert!(d.settled, "{d:?}");
    // The transient's amplitude 0.6 e^(-t/0.15) exceeds 1e-3 of |Y1| = 0.94 until
    // t = 0.15 ln(0.6/0.94e-3) = 0.97 s: about 10 periods are spoiled.
    assert!(
        (8..=14).contains(&d.unsettled_periods),
        "{} unsettled periods",
        d.unsettled_periods
    );
    // What remains of the transient in the fitted window is below 0.6 e^(-1.0/0.15) ≈ 8e-4
    // of a sine at another frequency, whose projection on the harmonics is far smaller.
    let e = worst(&d, 1, &turned(&resp, drive[0]));
    assert!(e < 1e-4, "{e:.2e}");
    // Without discarding, the same fit over the whole record is visibly worse.
    let all = extract_dwell(
        &["force", "tip"],
        &[&x, &y],
        rate,
        Some(f),
        &DwellConfig {
            settle_tolerance: 1e6,
            ..cfg.clone()
        },
    )
    .unwrap();
    assert_eq!(all.unsettled_periods, 0);
    assert!(worst(&all, 1, &turned(&resp, drive[0])) > 10.0 * e);
}

/// A response still growing at the end of the record is reported as not settled.
#[test]
fn a_growing_response_is_not_settled() {
    let (f, rate) = (10.0, 1000.0);
    let n = 3000;
    let x = multi_sine(&[c64::new(1.0, 0.0)], 0.0, f, rate, n);
    let y: Vec<f64> = (0..n)
        .map(|i| {
            let t = i as f64 / rate;
            (1.0 - (-t / 2.0).exp()) * (2.0 * PI * f * t).cos()
        })
        .collect();
    let cfg = DwellConfig {
        harmonics: 1,
        ..DwellConfig::default()
    };
    let d = extract_dwell(&["force", "tip"], &[&x, &y], rate, Some(f), &cfg).unwrap();
    assert!(!d.settled, "{d:?}");
}

/// Noise: the standard deviations from the period-to-period scatter match the scatter of
/// the estimates over 200 records (ratio within 15 %: the sampling error of a standard
/// deviation from 200 draws is 5 %), and they are those of white noise of σ over `L`
/// samples, `σ √(2/L)` per part.
#[test]
fn the_scatter_over_periods_is_the_estimates_own() {
    let (f, rate) = (20.0, 2000.0);
    let n = 4000; // 40 periods
    let resp = [c64::new(1.0, -0.5), c64::new(0.1, 0.0)];
    let clean = multi_sine(&resp, 0.0, f, rate, n);
    let x = multi_sine(&[c64::new(2.0, 0.0)], 0.0, f, rate, n);
    let sd = 0.01;
    let cfg = DwellConfig {
        harmonics: 2,
        estimate_frequency: false,
        ..DwellConfig::default()
    };
    let mut g = Gaussian::new(7);
    let mut re = Vec::new();
    let mut reported = Vec::new();
    for _ in 0..200 {
        let y: Vec<f64> = clean.iter().map(|v| v + sd * g.sample()).collect();
        let d = extract_dwell(&["force", "y"], &[&x, &y], rate, Some(f), &cfg).unwrap();
        assert!(d.settled, "{d:?}");
        re.push(d.harmonics[(1, 0)].re);
        reported.push(d.sigma[(1, 0)].re);
    }
    let m = re.len() as f64;
    let mean = re.iter().sum::<f64>() / m;
    let empirical = (re.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / (m - 1.0)).sqrt();
    let stated = reported.iter().sum::<f64>() / m;
    let theory = sd * (2.0 / n as f64).sqrt();
    eprintln!("empirical {empirical:.3e}, stated {stated:.3e}, white-noise theory {theory:.3e}");
    assert!((stated / empirical - 1.0).abs() < 0.15);
    assert!((stated / theory - 1.0).abs() < 0.15);
    assert!((mean - 1.0).abs() < 4.0 * empirical / m.sqrt());
}

/// Input no dwell can be fitted to is refused, naming the signal and the sample.
#[test]
fn bad_records_are_refused_by_name() {
    let cfg = DwellConfig::default();
    let x = multi_sine(&[c64::new(1.0, 0.0)], 0.0, 10.0, 1000.0, 500);
    let mut y = x.clone();
    y[123] = f64::NAN;
    let err = |r: nlsim_kernel::Result<nlsim_calib::Dwell>| r.unwrap_err().to_string();
    let e = err(extract_dwell(
        &["f", "tip"],
        &[&x, &y],
        1000.0,
        Some(10.0),
        &cfg,
    ));
    assert!(e.contains("'tip'") && e.contains("sample 124"), "{e}");
    let e = err(extract_dwell(
        &["f", "tip"],
        &[&x, &x[..400]],
        1000.0,
        Some(10.0),
        &cfg,
    ));
    assert!(e.contains("'tip'") && e.contains("400 samples"), "{e}");
    let e = err(extract_dwell(&["f"], &[&x[..50]], 1000.0, Some(10.0), &cfg));
    assert!(e.contains("shorter than one period"), "{e}");
    let e = err(extract_dwell(&["f"], &[&x], 1000.0, Some(200.0), &cfg));
    assert!(e.contains("Nyquist"), "{e}");
    let e = err(extract_dwell(&["f"], &[&x[..15]], 1000.0, None, &cfg));
    assert!(e.contains("fewer than 3 periods"), "{e}");
    let e = err(extract_dwell(&["f"], &[&x], -1.0, Some(10.0), &cfg));
    assert!(e.contains("sampling rate"), "{e}");
}

/// Steps found from the drive alone: three dwells 1 % apart, phase-continuous switching (a
/// generator), 0.5 % noise on the drive. Each dwell is found within two periods of its true
/// bounds, at its frequency to 1e-3, and its harmonics then come out right.
#[test]
fn steps_are_found_from_the_drive() {
    let rate = 2000.0;
    let freqs = [20.0, 20.2, 20.4];
    let per_step = 3000; // 30 periods each
    let mut drive = Vec::new();
    let mut phase = 0.0f64;
    let mut g = Gaussian::new(3);
    for &f in &freqs {
        for _ in 0..per_step {
            drive.push(phase.cos() + 0.005 * g.sample());
            phase += 2.0 * PI * f / rate;
        }
    }
    let w = nlsim_calib::detect_steps(&drive, rate, 5e-3);
    assert_eq!(w.len(), 3, "{w:?}");
    for (i, s) in w.iter().enumerate() {
        let period = rate / freqs[i];
        assert!((s.frequency_hz - freqs[i]).abs() < 1e-3 * freqs[i], "{s:?}");
        assert!(
            (s.start as f64 - (i * per_step) as f64).abs() <= 2.0 * period,
            "{s:?}"
        );
        assert!(
            (s.end as f64 - ((i + 1) * per_step) as f64).abs() <= 2.0 * period,
            "{s:?}"
        );
        let d = extract_dwell(
            &["drive"],
            &[&drive[s.start..s.end]],
            rate,
            Some(s.frequency_hz),
            &DwellConfig::default(),
        )
        .unwrap();
        assert!((d.frequency_hz - freqs[i]).abs() < 1e-4 * freqs[i], "{d:?}");
        assert!((d.harmonics[(0, 0)].re - 1.0).abs() < 1e-3, "{d:?}");
    }
}
