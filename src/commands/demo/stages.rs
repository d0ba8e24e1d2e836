//! The demo's computing stages: time response (FOH against RK45), the multi-harmonic FRF with
//! stability, and the calibration on the virtual test's data.
use crate::error::Result;
use crate::present::report::plot_both;
use std::time::Instant;

/// Stage 3 of the demo: FOH under a multi-sine at the first natural frequency (harmonics 1, 2,
/// 3 at 100, 10 and 5 % of the nominal force), checked against a tight RK45 run.
pub(crate) fn demo_time_response(
    model: &nlsim_kernel::Model,
    reduced: &nlsim_reduction::ReducedModel,
    system: &nlsim_reduction::ModalSystem,
    report: &crate::present::report::Report,
    say: &dyn Fn(&str),
) -> Result<()> {
    use nlsim_sim::{FohConfig, Harmonic, LoadCase, Plant, Rk45Config, Signal, Simulator};
    report.section("3. Time response (FOH vs RK45)");
    if model.excitation().is_empty() {
        say("[3/8] time response: the model has no excitation point; skipped");
        report.skip("the model has no excitation point");
        return Ok(());
    }
    let f1 = reduced.modes.frequencies_hz()[0];
    let plant = Plant::from_model(model, system)?;
    let forces: Vec<Signal> = model
        .excitation()
        .iter()
        .map(|x| Signal::MultiSine {
            fundamental_hz: f1,
            harmonics: [(1.0, 1.0), (2.0, 0.1), (3.0, 0.05)]
                .iter()
                .map(|&(r, a)| Harmonic {
                    ratio: r,
                    amplitude: faer::c64::new(0.0, -a * x.amplitude),
                })
                .collect(),
        })
        .collect();
    let case = LoadCase::new("multisine", forces);
    let rate = 200.0 * f1;
    let duration = 40.0 / f1;
    let n = (duration * rate).round() as usize;
    let sim = Simulator::new(&plant, &FohConfig::new(1.0 / rate))?;
    let foh = sim.run(&case, n)?;
    let rk = nlsim_sim::rk45(
        &plant,
        &case,
        1.0 / rate,
        n,
        &Rk45Config {
            rtol: 1e-9,
            atol: 1e-15,
            ..Default::default()
        },
    )?;
    report.data(|root| {
        let g = root.create_group("time_response")?;
        let info = |method: &str| crate::formats::history_file::RunInfo {
            model_spec: model.name().to_string(),
            method: method.to_string(),
            excitation: vec![format!(
                "multisine at {f1} Hz: harmonics 1, 2, 3 at 100/10/5 % of the nominal force"
            )],
            modes: reduced.n_modes(),
            compress: true,
        };
        crate::formats::history_file::write_group(&g.create_group("foh")?, &foh, &info("foh"))?;
        crate::formats::history_file::write_group(&g.create_group("rk45")?, &rk, &info("rk45"))
    })?;
    say(&format!(
        "[3/8] time response: multi-sine at {f1:.3} Hz (harmonics 1, 2, 3 at 100/10/5 % of the \
         nominal force), {duration:.2} s from rest, FOH at {rate:.0} Hz ({n} steps)"
    ));
    say(&format!(
        "  FOH {:.4} s wall ({:.2} ns per mode-step, {} contact events); RK45 (rtol 1e-9) {:.4} s \
         wall with {} steps: FOH {:.0}x faster",
        foh.stats.seconds,
        foh.stats.seconds / (n as f64 * system.n_states() as f64) * 1e9,
        foh.stats.events.len(),
        rk.stats.seconds,
        rk.stats.steps,
        rk.stats.seconds / foh.stats.seconds.max(1e-9)
    ));
    for (a, b) in foh.outputs.iter().zip(&rk.outputs) {
        let peak = b.values.iter().fold(0.0f64, |m, x| m.max(x.abs()));
        let diff = a
            .values
            .iter()
            .zip(&b.values)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        say(&format!(
            "  {:<10} {:<13} peak {peak:.4e}; FOH vs RK45 max difference {:.2e} of peak",
            a.name,
            a.quantity.as_str(),
            diff / peak.max(1e-300)
        ));
    }
    if let (Some(a), Some(b)) = (foh.outputs.first(), rk.outputs.first()) {
        // At most ~4000 points per curve.
        let every = (a.values.len() / 4000).max(1);
        let curve = |v: &[f64]| -> Vec<(f64, f64)> {
            v.iter()
                .enumerate()
                .step_by(every)
                .map(|(k, &x)| (k as f64 / rate, x))
                .collect()
        };
        let fig = crate::present::plot::Lines {
            title: format!(
                "{}: multi-sine response at {} (FOH vs RK45)",
                model.name(),
                a.name
            ),
            x_desc: "time (s)".into(),
            y_desc: format!(
                "{} {} ({})",
                a.name,
                a.quantity.as_str(),
                crate::formats::files::unit(a.quantity)
            ),
            series: vec![
                (format!("FOH, {rate:.0} Hz"), curve(&a.values)),
                ("RK45, rtol 1e-9".into(), curve(&b.values)),
            ],
        };
        let paths = plot_both(report, "time_response", &fig)?;
        say(&format!("  plots: {paths}"));
    }
    for (e, name) in foh.element_names.iter().enumerate() {
        let pu = foh.element_displacements[e]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        let pg = foh.element_forces[e]
            .iter()
            .fold(0.0f64, |m, x| m.max(x.abs()));
        say(&format!(
            "  element {name:<10} peak |u| {pu:.4e} m, peak |g| {pg:.4e} N"
        ));
    }
    Ok(())
}

/// Stage 4 of the demo: multi-harmonic FRFs by harmonic balance around the first resonance:
/// continuation with stability, and stepped sines up and down that show the jump.
pub(crate) fn demo_frf(
    model: &nlsim_kernel::Model,
    reduced: &nlsim_reduction::ReducedModel,
    report: &crate::present::report::Report,
    say: &dyn Fn(&str),
) -> Result<()> {
    use nlsim_hb::{ContinuationConfig, HarmonicSet, HbConfig, HbSystem, PointKind};
    use std::f64::consts::PI;
    report.section("4. Multi-harmonic FRFs (harmonic balance)");
    if model.elements().is_empty() || model.excitation().is_empty() || model.sensors().is_empty() {
        say(
            "[4/8] multi-harmonic FRFs: the model needs an element, an excitation and a sensor; skipped",
        );
        report.skip("the model needs an element, an excitation and a sensor");
        return Ok(());
    }
    let sys = HbSystem::from_model(model, reduced, HarmonicSet::new(7, 1)?, HbConfig::default())?;
    let f1 = reduced.modes.frequencies_hz()[0];
    let (lo, hi) = (0.85 * f1, 1.5 * f1);
    let t = Instant::now();
    let cont = nlsim_hb::continuation(&sys, &ContinuationConfig::frequency(lo, hi), None)?
        .into_branch()?;
    let t_cont = t.elapsed().as_secs_f64();
    let n = 200;
    let grid = |a: f64, b: f64| -> Vec<f64> {
        (0..n)
            .map(|i| 2.0 * PI * (a + (b - a) * i as f64 / (n - 1) as f64))
            .collect()
    };
    let t = Instant::now();
    let up_run = nlsim_hb::stepped_sine(&sys, &grid(lo, hi), 1.0, true)?;
    let down_run = nlsim_hb::stepped_sine(&sys, &grid(hi, lo), 1.0, true)?;
    let t_step = t.elapsed().as_secs_f64();
    let (up, down) = (&up_run.branch, &down_run.branch);
    // What a stepped sine could not settle, said rather than drawn over.
    let mut caveats = Vec::new();
    for (what, r) in [("up", &up_run), ("down", &down_run)] {
        if !r.skipped.is_empty() {
            let hz: Vec<String> = r
                .skipped
                .iter()
                .map(|w| format!("{:.3}", w / (2.0 * PI)))
                .collect();
            caveats.push(format!(
                "stepped sine {what}: no solution at {} Hz (gaps)",
                hz.join(", ")
            ));
        }
        if r.stats.n_unverified > 0 {
            caveats.push(format!(
                "stepped sine {what}: {} step(s) across a non-smooth point shown as regular \
                 (a finer grid tells whether the response jumps there)",
                r.stats.n_unverified
            ));
        }
    }
    let hz = |p: &nlsim_hb::SolutionPoint| p.omega / (2.0 * PI);
    // A jump whose step holds no fold of the continuation left a branch the continuation
    // from the lower end does not follow (the stepped sine showed that branch to fold).
    let cont_folds: Vec<f64> = cont.folds().iter().map(|&i| cont.points[i].omega).collect();
    let elsewhere = std::cell::Cell::new(false);
    let list = |kind: PointKind, b: &nlsim_hb::Branch| -> String {
        let v: Vec<String> = b
            .points
            .iter()
            .enumerate()
            .filter(|(_, p)| p.kind == kind)
            .map(|(i, p)| {
                let before = b.points[i.saturating_sub(1)].omega;
                let (a, z) = (before.min(p.omega), before.max(p.omega));
                let step = (z - a).max(2.0 * PI * (hi - lo) / (n - 1) as f64);
                let seen = cont_folds.iter().any(|&f| f >= a - step && f <= z + step);
                if kind == PointKind::Jump && !seen {
                    elsewhere.set(true);
                    format!("{:.3} Hz*", hz(p))
                } else {
                    format!("{:.3} Hz", hz(p))
                }
            })
            .collect();
        if v.is_empty() {
            "none".into()
        } else {
            format!("at {}", v.join(", "))
        }
    };
    say(&format!(
        "[4/8] multi-harmonic FRFs {lo:.2}–{hi:.2} Hz, H = 7 ({} unknowns): continuation {} points \
         in {:.2} s with Hill stability ({} unstable), folds: {}; stepped sines of {n} points \
         in {:.3} s: up jumps: {}, down jumps: {}",
        sys.n_unknowns(),
        cont.points.len(),
        t_cont,
        cont.points
            .iter()
            .filter(|p| p.stable() == Some(false))
            .count(),
        list(PointKind::Fold, &cont),
        t_step,
        list(PointKind::Jump, up),
        list(PointKind::Jump, down)
    ));
    if elsewhere.get() {
        caveats.push(format!(
            "* a jump off a branch the continuation from {lo:.2} Hz does not follow: the \
             stepped sine showed that branch to fold inside the step"
        ));
    }
    for c in &caveats {
        say(&format!("  note: {c}"));
    }
    // The sensor responses of each branch, once: for the data, the tables and the plots.
    let branches = [
        ("continuation", "continuation", &cont),
        ("step_up", "stepped sine up", up),
        ("step_down", "stepped sine down", down),
    ]
    .map(|(name, what, b)| (name, what, b, crate::commands::frf::run::responses(&sys, b)));
    report.data(|root| {
        let g = root.create_group("frf")?;
        for (name, _, b, yb) in &branches {
            crate::formats::frf_file::write_group(&g.create_group(name)?, &sys, b, yb)?;
        }
        Ok(())
    })?;
    for (_, what, b, yb) in &branches {
        report.table(
            &format!("frf_events_{what}"),
            crate::commands::frf::report::events_table(&sys, b, yb, what),
        )?;
    }
    let y = &branches[0].3;
    report.table(
        "frf_peaks",
        crate::commands::frf::report::peaks_table(&sys, &cont, y),
    )?;
    let title = format!("{}: harmonic balance, H = 7", model.name());
    let fig = crate::present::frf_plot::FrfPlot {
        sys: &sys,
        branch: &cont,
        y,
        sensor: 0,
        title: &title,
        magnitude: crate::present::frf_plot::Magnitude::Db,
        phase: true,
        gaps: &[],
    };
    let mut plots = vec![plot_both(report, &format!("frf_{}", model.name()), &fig)?];
    // The stepped sines as a test would run them, over the continuation.
    // A skipped frequency is a gap (a non-finite point) in its curve.
    let fund = |i: usize, skipped: &[f64]| -> Vec<(f64, f64)> {
        let (_, _, b, yb) = &branches[i];
        let mut out: Vec<(f64, f64)> = yb
            .iter()
            .zip(&b.points)
            .map(|(r, p)| (p.omega, r[(0, 1)].norm()))
            .chain(skipped.iter().map(|&w| (w, f64::NAN)))
            .collect();
        if !skipped.is_empty() {
            // A stepped sine's points are in test order, monotonic in frequency.
            let down = b.points.len() > 1 && b.points[b.points.len() - 1].omega < b.points[0].omega;
            out.sort_by(|a, b| {
                if down {
                    b.0.total_cmp(&a.0)
                } else {
                    a.0.total_cmp(&b.0)
                }
            });
        }
        out.into_iter().map(|(w, v)| (w / (2.0 * PI), v)).collect()
    };
    let sen = &sys.sensors()[0];
    // The continuation in the FRF figure's styles: stable blue, unstable red; each part
    // keeps the point where the other begins, so that the curve is unbroken.
    let cont = fund(0, &[]);
    let stable: Vec<bool> = branches[0]
        .2
        .points
        .iter()
        .map(|p| p.stable() != Some(false))
        .collect();
    let part = |want: bool| -> Vec<(f64, f64)> {
        cont.iter()
            .enumerate()
            .map(|(i, &(f, v))| {
                let keep = stable[i] == want || stable.get(i + 1) == Some(&want);
                (f, if keep { v } else { f64::NAN })
            })
            .collect()
    };
    let fig = crate::present::plot::Lines {
        title: format!("{}: stepped sines jump at the folds", model.name()),
        x_desc: "frequency (Hz)".into(),
        y_desc: format!(
            "|{}| at the fundamental ({})",
            sen.name,
            crate::formats::files::unit(sen.quantity)
        ),
        series: vec![
            ("continuation, stable".into(), part(true)),
            ("continuation, unstable".into(), part(false)),
            ("stepped sine up".into(), fund(1, &up_run.skipped)),
            ("stepped sine down".into(), fund(2, &down_run.skipped)),
        ],
    };
    plots.push(plot_both(report, "stepped_sines", &fig)?);
    say(&format!("  plots: {}", plots.join(", ")));
    Ok(())
}

/// Stages 7 and 8 of the demo: a synthetic stepped-sine test of the model itself (two force
/// levels, harmonics 1–3, 2 % noise), then calibration of the first element parameter and
/// the driven mode's damping from far-off values, with and without the side harmonics, and
/// 10-fold cross validation beside the Cramér–Rao bound.
pub(crate) fn demo_calibration(
    model: &nlsim_kernel::Model,
    reduced: &nlsim_reduction::ReducedModel,
    virtual_data: Option<nlsim_calib::TestData>,
    report: &crate::present::report::Report,
    say: &dyn Fn(&str),
) -> Result<()> {
    use nlsim_calib::{
        CalibrationConfig, Form, FrfObjective, Noise, ObjectiveConfig, ParamSpec, calibrate,
        synthesize,
    };
    use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
    use nlsim_kernel::Parameterized;
    use std::sync::Arc;
    report.section("7. Calibration");
    let skip = |why: &str| {
        say(&format!(
            "[7/8] calibration: {why}; skipped\n[8/8] k-fold statistics: skipped"
        ));
        report.skip(why);
        report.section("8. k-fold statistics");
        report.skip(why);
    };
    if model.elements().is_empty() || model.excitation().is_empty() || model.sensors().is_empty() {
        skip("the model needs an element, an excitation and a sensor");
        return Ok(());
    }
    let t = Instant::now();
    let mut sys =
        HbSystem::from_model(model, reduced, HarmonicSet::new(3, 1)?, HbConfig::default())?;
    let Some(params) = crate::commands::demo::planning::demo_parameters(&sys) else {
        skip("no element parameter with a positive value");
        return Ok(());
    };
    let truth = sys.param_values(&params)?;
    let force = model.excitation()[0].amplitude;
    let noise = 0.02;
    let (data, source) = match virtual_data {
        Some(d) => (
            Arc::new(d),
            "the force-controlled virtual test of stage 6".to_string(),
        ),
        None => {
            let plans = crate::commands::demo::planning::demo_sweeps(&sys, &params, force);
            let input = sys.inputs()[0].0.clone();
            let d = synthesize(&sys, &input, &plans, 3, Noise::relative(noise), 2016)?;
            let csv = report.dir().join("synthetic_test.csv");
            crate::formats::test_data::write_csv(&csv, &d)?;
            report.wrote(&csv);
            (
                Arc::new(d),
                format!("a synthetic stepped-sine test ({})", csv.display()),
            )
        }
    };
    say(&format!(
        "[7/8] calibration on {source}: {} sweeps, {} steps, harmonics 1-3 at {} sensors, {:.0} % \
         noise with a floor of 1e-3 of each sensor's largest response (seed 2016)",
        data.sweeps.len(),
        data.n_points(),
        data.channels.len(),
        100.0 * noise
    ));
    // Start far away: the element parameter 30x too large, the damping 2.5x.
    sys.set_params(&params, &[truth[0] * 30.0, truth[1] * 2.5])?;
    let specs = vec![
        ParamSpec::new(params[0].clone(), truth[0] / 100.0, truth[0] * 100.0),
        ParamSpec::new(params[1].clone(), truth[1] / 10.0, truth[1] * 10.0),
    ];
    let config = CalibrationConfig {
        lhs_samples: 32,
        seed: 2016,
        starts: 2,
        folds: 10,
        ..Default::default()
    };
    report.seed("Latin hypercube and k-fold split", config.seed)?;
    let mut fits = Vec::new();
    for (label, harmonics) in [
        ("fundamental only", vec![1]),
        ("harmonics 1 and 3", vec![1, 3]),
    ] {
        let obj = FrfObjective::new(
            &sys,
            data.clone(),
            specs.clone(),
            ObjectiveConfig {
                harmonics,
                form: Form::Complex,
                ..ObjectiveConfig::default()
            },
        )?;
        let cal = calibrate(&obj, &config)?;
        fits.push((label, cal, obj));
    }
    say(&format!(
        "  {} LHS candidates (maximin, seed {}) + the start, LM from the best {}, in {:.2} s for both metrics",
        config.lhs_samples,
        config.seed,
        config.starts,
        t.elapsed().as_secs_f64()
    ));
    let text = report.table_text();
    say(
        "  parameter            true          start         metric             estimate      error     Cramér–Rao  10-fold (jackknife)",
    );
    let mut rows = Vec::new();
    for (j, p) in params.iter().enumerate() {
        for (label, cal, _) in &fits {
            let jack = cal.kfold.as_ref().map_or(f64::NAN, |k| k.jackknife_std[j]);
            rows.push(vec![
                p.to_string(),
                format!("{:.5e}", truth[j]),
                format!("{:.5e}", [truth[0] * 30.0, truth[1] * 2.5][j]),
                label.to_string(),
                format!("{:.5e}", cal.estimate[j]),
                format!("{:+.3}", 100.0 * (cal.estimate[j] - truth[j]) / truth[j]),
                format!("{:.3}", 100.0 * cal.cramer_rao.relative_std[j]),
                format!("{:.3}", 100.0 * jack / cal.estimate[j]),
            ]);
            say(&format!(
                "  {:<18} {:>12.5e}  {:>12.5e}  {:<18} {:>12.5e}  {:>+8.3} %  ±{:>8.3} %  ±{:>8.3} %",
                p.to_string(),
                truth[j],
                [truth[0] * 30.0, truth[1] * 2.5][j],
                label,
                cal.estimate[j],
                100.0 * (cal.estimate[j] - truth[j]) / truth[j],
                100.0 * cal.cramer_rao.relative_std[j],
                100.0 * cal.kfold.as_ref().map_or(f64::NAN, |k| k.jackknife_std[j])
                    / cal.estimate[j],
            ));
        }
    }
    drop(text);
    report.table(
        "calibration_estimates",
        crate::present::report::Table {
            caption: "Estimates and their uncertainties (std as % of the estimate)".into(),
            header: [
                "parameter",
                "true",
                "start",
                "metric",
                "estimate",
                "error (%)",
                "Cramér–Rao std (%)",
                "10-fold jackknife std (%)",
            ]
            .map(String::from)
            .to_vec(),
            rows,
        },
    )?;
    for (label, cal, _) in &fits {
        say(&format!(
            "  {label}: {} in {} LM iterations, reduced chi2 {:.3}, collinearity index {:.2}{}",
            cal.status,
            cal.runs[0].report.iterations,
            cal.cramer_rao.reduced_chi2,
            cal.cramer_rao.collinearity,
            if cal.fit.failed.is_empty() {
                String::new()
            } else {
                format!(", {} points did not converge", cal.fit.failed.len())
            }
        ));
    }
    // Measured vs calibrated fundamental at the first sensor, per sweep.
    let (_, cal, obj) = &fits[1];
    let mut series = Vec::new();
    for (s, sw) in data.sweeps.iter().enumerate() {
        let pts = |model: bool| -> Vec<(f64, f64)> {
            cal.fit
                .points
                .iter()
                .filter(|p| p.id.sweep == s)
                .map(|p| {
                    let st = &sw.steps[p.id.step];
                    let y = if model {
                        p.response[(0, 0)]
                    } else {
                        st.response[(0, 0)]
                    };
                    (st.frequency_hz, y.norm())
                })
                .collect()
        };
        series.push((format!("test, {}", sw.label), pts(false)));
        series.push((format!("calibrated model, {}", sw.label), pts(true)));
    }
    let ch = &obj.data().channels[0];
    let fig = crate::present::plot::Lines {
        title: format!(
            "{}: synthetic test vs calibrated model (harmonic 1)",
            model.name()
        ),
        x_desc: "frequency (Hz)".into(),
        y_desc: format!(
            "|{}| {} ({})",
            ch.name,
            ch.quantity.as_str(),
            crate::formats::files::unit(ch.quantity)
        ),
        series,
    };
    say(&format!(
        "  plots: {}",
        plot_both(report, "calibration_frf", &fig)?
    ));
    say(&format!(
        "  try `nlsim calibrate {} REPORT/virtual_test.csv --param {}={:e}:{:e} --compare 1,3`",
        model.name(),
        params[0],
        truth[0] / 100.0,
        truth[0] * 100.0
    ));
    say("");
    let kf = cal.kfold.as_ref().expect("folds = 10");
    report.section("8. k-fold statistics");
    say(&format!(
        "[8/8] k-fold statistics: {} folds (seed {}), each trained on the other folds from the estimate",
        kf.k, config.seed
    ));
    let rms = |v: &[f64]| v.iter().sum::<f64>() / v.len() as f64;
    say(&format!(
        "  mean rms weighted residual: training {:.3}, held out {:.3} (1 = at the noise level)",
        rms(&kf.training_rms),
        rms(&kf.held_out_rms)
    ));
    let groups = params
        .iter()
        .enumerate()
        .map(|(j, p)| {
            let rel = cal.cramer_rao.std[j] / cal.estimate[j].abs();
            crate::present::plot::BarGroup {
                label: p.to_string(),
                values: kf
                    .estimates
                    .iter()
                    .map(|e| e[j] / cal.estimate[j])
                    .collect(),
                band: rel.is_finite().then_some((1.0 - rel, 1.0 + rel)),
            }
        })
        .collect();
    let fig = crate::present::plot::Bars {
        title: format!("{}: fold estimates / full-data estimate", model.name()),
        bar_desc: "fold".into(),
        y_desc: "fold estimate / estimate (1)".into(),
        baseline: 1.0,
        baseline_desc: "full-data estimate".into(),
        band_desc: "Cramér–Rao ±1σ".into(),
        groups,
    };
    say(&format!("  plots: {}", plot_both(report, "kfold", &fig)?));
    Ok(())
}
