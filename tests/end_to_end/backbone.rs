//! `nlsim backbone` from the command line: a free decay written as a lab's CSV records,
//! identified against its known frequency and damping within the standard deviations the
//! command reports; several sensors combined by a shape; the real Brake–Reuss stepped sines
//! (../shared/data/brb); usage errors by name.

use super::*;
use std::f64::consts::PI;

/// The rows of a backbone CSV of method `method`: `(amplitude, f, σ_f, ζ, σ_ζ, level)`.
fn rows(path: &Path, method: &str) -> Vec<(f64, f64, f64, f64, f64, String)> {
    let text = std::fs::read_to_string(path).unwrap();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let head: Vec<&str> = lines.next().unwrap().split(',').collect();
    let col = |n: &str| head.iter().position(|h| *h == n).unwrap();
    let (a, f, sf, z, sz, lv, m) = (
        col("amplitude"),
        col("frequency_hz"),
        col("frequency_sigma_hz"),
        col("damping_ratio"),
        col("damping_sigma"),
        col("level"),
        col("method"),
    );
    lines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|r| r[m] == method)
        .map(|r| {
            let v = |i: usize| r[i].parse::<f64>().unwrap();
            (v(a), v(f), v(sf), v(z), v(sz), r[lv].to_string())
        })
        .collect()
}

/// Two decaying modes (12 Hz, ζ 0.4 %, and 40 Hz) with noise, as accelerometer columns of
/// a CSV at 512 Hz; `scale` multiplies the first mode in each of the two columns.
fn write_decay(path: &Path, scale: [f64; 2]) {
    let (fs, f1, z1) = (512.0, 12.0, 0.004);
    let w1 = 2.0 * PI * f1;
    let wd = w1 * (1.0f64 - z1 * z1).sqrt();
    let mut g = nlsim::calib::Gaussian::new(7);
    let mut s = String::from("time_s,a1,a2\n");
    for i in 0..20_000 {
        let t = i as f64 / fs;
        let m1 = 3.0 * (-z1 * w1 * t).exp() * (wd * t + 0.2).cos();
        let m2 = 0.8 * (-0.01 * 2.0 * PI * 40.0 * t).exp() * (2.0 * PI * 40.0 * t).sin();
        s.push_str(&format!(
            "{t:.8},{:.9e},{:.9e}\n",
            scale[0] * m1 + m2 + 0.01 * g.sample(),
            scale[1] * m1 - m2 + 0.01 * g.sample()
        ));
    }
    std::fs::write(path, s).unwrap();
}

#[test]
fn a_free_decay_is_identified_within_its_deviations() {
    let dir = scratch("backbone-decay");
    let rec = dir.join("ringdown.csv");
    write_decay(&rec, [1.0, 0.5]);
    let out = dir.join("bb.csv");
    let (code, stdout, err) = nlsim(&[
        "backbone",
        rec.to_str().unwrap(),
        "--decay",
        "--channel",
        "a1",
        "--frequency",
        "12",
        "--quantity",
        "acceleration",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("band pass 8.4000–15.6000 Hz"), "{stdout}");
    assert!(dir.join("bb.svg").is_file() && dir.join("bb-damping.svg").is_file());
    let fit = rows(&out, "fit");
    let hil = rows(&out, "hilbert");
    assert!(
        fit.len() > 20 && fit.len() == hil.len(),
        "{} {}",
        fit.len(),
        hil.len()
    );
    // Independent windows (every other) within 4σ of the truth: 12 Hz is ω_n/2π.
    for p in fit.iter().chain(&hil).step_by(2) {
        assert!((p.1 - 12.0).abs() < 4.0 * p.2, "{p:?}");
        assert!((p.3 - 0.004).abs() < 4.0 * p.4, "{p:?}");
    }
    // The two columns hold the mode as 1 and 0.5: combined by that shape, the modal signal
    // is the mode itself (amplitude 3 at t = 0) and the 40 Hz mode (−1, +1) is gone from it.
    let out2 = dir.join("modal.csv");
    let (code, stdout, err) = nlsim(&[
        "backbone",
        rec.to_str().unwrap(),
        "--decay",
        "--channel",
        "a1",
        "--channel",
        "a2",
        "--shape",
        "1,0.5",
        "--out",
        out2.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("modal signal of a1, a2"), "{stdout}");
    let text = std::fs::read_to_string(&out2).unwrap();
    let t_col = 8;
    for l in text.lines().filter(|l| !l.starts_with('#')).skip(1) {
        let r: Vec<&str> = l.split(',').collect();
        let (a, sa, t): (f64, f64, f64) = (
            r[0].parse().unwrap(),
            r[1].parse().unwrap(),
            r[t_col].parse().unwrap(),
        );
        let exact = 3.0 * (-0.004 * 2.0 * PI * 12.0 * t).exp();
        assert!((a - exact).abs() < 4.0 * sa, "{l}: {exact}");
    }
}

#[test]
fn the_brake_reuss_stepped_sines_give_two_backbones() {
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data/brb/stepped_sine.csv");
    let dir = scratch("backbone-brb");
    let out = dir.join("brb.csv");
    let (code, stdout, err) = nlsim(&[
        "backbone",
        data.to_str().unwrap(),
        "--phase-offset-deg",
        "180",
        "--out",
        out.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    assert!(stdout.contains("12 levels"), "{stdout}");
    let pr = rows(&out, "phase_resonance");
    let lf = rows(&out, "level_fit");
    assert_eq!(pr.len(), 12);
    assert_eq!(lf.len(), 12);
    // The response-controlled levels: the damping grows with the amplitude at every level
    // (the joint's microslip; the README's fourfold fall of the peak accelerance), and the
    // energy balance at −90° agrees with the level's single-mode fit within 3 combined σ.
    let resp: Vec<_> = pr.iter().filter(|p| p.5.starts_with("response")).collect();
    assert_eq!(resp.len(), 8);
    for w in resp.windows(2) {
        assert!(
            w[1].0 > w[0].0 && w[1].3 > w[0].3,
            "{:?} then {:?}",
            w[0],
            w[1]
        );
    }
    let (lo, hi) = (resp[0].3, resp[7].3);
    assert!(hi / lo > 4.0, "ζ from {lo} to {hi}");
    for (p, f) in pr
        .iter()
        .zip(&lf)
        .filter(|(p, _)| p.5.starts_with("response"))
    {
        assert_eq!(p.5, f.5);
        let s = (p.4 * p.4 + f.4 * f.4).sqrt();
        assert!((p.3 - f.3).abs() < 3.0 * s, "{p:?} vs {f:?}");
        // The −90° crossing is within the fit's natural frequency to 3σ.
        let sf = (p.2 * p.2 + f.2 * f.2).sqrt();
        assert!((p.1 - f.1).abs() < 3.0 * sf, "{p:?} vs {f:?}");
    }
}

#[test]
fn backbone_usage_errors_name_what_is_wrong() {
    let dir = scratch("backbone-usage");
    let rec = dir.join("r.csv");
    write_decay(&rec, [1.0, 1.0]);
    let r = rec.to_str().unwrap();
    usage_error(
        &["backbone", r, "--decay"],
        "2 signals (a1, a2): name the decay's with --channel",
    );
    usage_error(
        &["backbone", r, "--decay", "--channel", "a3"],
        "no column 'a3' (it has: a1, a2)",
    );
    usage_error(
        &[
            "backbone",
            r,
            "--decay",
            "--channel",
            "a1",
            "--channel",
            "a2",
        ],
        "several channels need the mode's shape",
    );
    usage_error(
        &["backbone", r, "--shape", "1"],
        "--shape, --frequency and --start are for free decays",
    );
    usage_error(
        &["backbone", r, "--decay", "--channel", "a1", "--band", "2"],
        "band 2 must be from 0.01 to 0.9",
    );
    usage_error(
        &["backbone", r, "--decay", "--channel", "a1", "--out", r],
        "writing there would replace it",
    );
}
