//! Pre-test planning and virtual testing as the demo runs them (stages 5 and 6): a ranked
//! table of candidate tests by Fisher information, and a stepped-sine test through a shaker
//! model with and without force control, whose data the calibration stage then uses.

use crate::error::Result;
use crate::present::plot::Lines;
use crate::present::report::plot_both;
use nlsim_calib::{
    Band, ControlConfig, Criterion, Exciter, Noise, Planner, Shaker, SweepPlan, TestData,
    rank_designs, subsets, virtual_test_with,
};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{Model, Param, Parameterized};
use nlsim_reduction::ReducedModel;
use std::time::Instant;

/// The parameters the demo plans for and calibrates: the first element parameter with a
/// positive value and the damping of the mode the drive excites most at the first sensor.
pub fn demo_parameters(sys: &HbSystem) -> Option<Vec<Param>> {
    let driven = sys
        .linear()
        .dominant_mode(sys.sensors().first()?.port, 0..2)
        .unwrap_or(0);
    let element = sys
        .parameters()
        .into_iter()
        .find(|p| matches!(p, Param::Element { .. }) && sys.param(p).is_ok_and(|v| v > 0.0))?;
    Some(vec![element, Param::ModalDamping(driven)])
}

/// The natural frequency (Hz) of the driven mode of [`demo_parameters`].
fn driven_frequency(sys: &HbSystem, params: &[Param]) -> f64 {
    match params.get(1) {
        Some(Param::ModalDamping(r)) => sys.linear().frequency_hz(*r),
        _ => sys.linear().frequency_hz(0),
    }
}

/// The two stepped sines of the demo's test: a quarter of the nominal force over ±8 % of
/// the driven mode's frequency, and the nominal force from −8 % to +12 %.
pub fn demo_sweeps(sys: &HbSystem, params: &[Param], force: f64) -> Vec<SweepPlan> {
    let f = driven_frequency(sys, params);
    vec![
        SweepPlan::linear(
            format!("{:.3} N up", 0.25 * force),
            0.92 * f,
            1.08 * f,
            17,
            0.25 * force,
        ),
        SweepPlan::linear(format!("{force:.3} N up"), 0.92 * f, 1.12 * f, 21, force),
    ]
}

/// Stage 5: candidate tests of `model` ranked by D-optimality: 3 force levels × 3 bands ×
/// every non-empty set of the model's sensors × harmonics {1} or {1, 3}, the information
/// from the analytic sensitivities along each predicted stepped sine.
pub fn demo_planning(
    model: &Model,
    reduced: &ReducedModel,
    report: &crate::present::report::Report,
    say: &dyn Fn(&str),
) -> Result<()> {
    report.section("5. Pre-test planning (Fisher information)");
    if model.elements().is_empty() || model.excitation().is_empty() || model.sensors().is_empty() {
        say(
            "[5/8] pre-test planning: the model needs an element, an excitation and a sensor; skipped",
        );
        report.skip("the model needs an element, an excitation and a sensor");
        return Ok(());
    }
    let t = Instant::now();
    let sys = HbSystem::from_model(model, reduced, HarmonicSet::new(3, 1)?, HbConfig::default())?;
    let Some(params) = demo_parameters(&sys) else {
        say("[5/8] pre-test planning: no element parameter with a positive value; skipped");
        report.skip("no element parameter with a positive value");
        return Ok(());
    };
    let planner = Planner::new(&sys, &params)?;
    let force = model.excitation()[0].amplitude;
    let input = sys.inputs()[0].0.clone();
    let f = driven_frequency(&sys, &params);
    let bands = [
        ("below", 0.85, 0.97),
        ("across", 0.92, 1.12),
        ("above", 1.05, 1.25),
    ]
    .map(|(l, a, b)| Band {
        label: l.into(),
        from_hz: a * f,
        to_hz: b * f,
        steps: 15,
    });
    let levels = [0.25, 0.5, 1.0].map(|x| x * force);
    // 1 % of each response with a floor of 1e-3 of each sensor's largest predicted response
    // (at the largest level): the floor in the sensor's own scale, whatever its quantity.
    let top = Exciter::sine(&input, levels[2]);
    let tests: Vec<(&Exciter, &Band)> = bands.iter().map(|b| (&top, b)).collect();
    let peaks = planner.response_peaks(&tests)?;
    let noise = nlsim_calib::scaled_noise(0.01, 0.0, 1e-3, &peaks);
    if let Some((sen, _)) = sys.sensors().iter().zip(&peaks).find(|(_, p)| **p <= 0.0) {
        say(&format!(
            "[5/8] pre-test planning: sensor '{}' has no predicted response; skipped",
            sen.name
        ));
        report.skip("a sensor without a predicted response");
        return Ok(());
    }
    let harmonics = [1, 3];
    let mut sweeps = Vec::new();
    for &level in &levels {
        for b in &bands {
            sweeps.push(planner.sweep_information_with(
                &Exciter::sine(&input, level),
                b,
                &noise,
                &harmonics,
            )?);
        }
    }
    let nc = sys.sensors().len();
    let channel_sets: Vec<Vec<usize>> = (1..=nc.min(4)).flat_map(|k| subsets(nc, k)).collect();
    let harmonic_sets = vec![vec![0], vec![0, 1]];
    let ranked = rank_designs(&sweeps, &channel_sets, &harmonic_sets, None, Criterion::D)?;
    say(&format!(
        "[5/8] pre-test planning: {} candidate tests ({} levels x {} bands x {} sensor sets x \
         {} harmonic sets) ranked by D-optimality in {:.2} s; Fisher information from the \
         analytic sensitivities of {} and {} (relative units), noise 1 % with a floor of 1e-3 \
         of each sensor's largest predicted response ({})",
        ranked.len(),
        levels.len(),
        bands.len(),
        channel_sets.len(),
        harmonic_sets.len(),
        t.elapsed().as_secs_f64(),
        params[0],
        params[1],
        sys.sensors()
            .iter()
            .zip(&noise)
            .map(|(sen, n)| format!(
                "{} {:.2e} {}",
                sen.name,
                n.absolute,
                crate::formats::files::unit(sen.quantity)
            ))
            .collect::<Vec<_>>()
            .join(", ")
    ));
    let describe = |r: &nlsim_calib::RankedDesign| {
        let sw = &sweeps[r.design.sweep];
        let ch = sw.channel_names(&r.design);
        let hk: Vec<String> = sw
            .harmonic_numbers(&r.design)
            .iter()
            .map(usize::to_string)
            .collect();
        format!(
            "{:>7.3} N  {:<7} {:<12} {:<6}",
            sw.exciter.level,
            sw.band.label,
            ch.join("+"),
            hk.join(",")
        )
    };
    let text = report.table_text();
    say(&format!(
        "  rank  level      band    sensors      harm.   ln det F   Cramér–Rao std ({}, {})  collinearity",
        params[0], params[1]
    ));
    let n = ranked.len();
    for (i, r) in ranked.iter().enumerate() {
        if i < 5 || i + 2 >= n {
            say(&format!(
                "  {:>4}  {}  {:>9.3}   {:>8.3} %  {:>8.3} %   {:>6.2}",
                i + 1,
                describe(r),
                r.summary.log_det,
                100.0 * r.summary.std[0],
                100.0 * r.summary.std[1],
                r.summary.collinearity
            ));
        } else if i == 5 {
            say("  ...");
        }
    }
    drop(text);
    report.table(
        "planning_ranking",
        crate::present::report::Table {
            caption: format!(
                "Candidate tests ranked by D-optimality (Cramér–Rao std of {} and {} in % of the value)",
                params[0], params[1]
            ),
            header: [
                "rank",
                "level (N)",
                "band",
                "sensors",
                "harmonics",
                "ln det F",
                "std 1 (%)",
                "std 2 (%)",
                "collinearity",
            ]
            .map(String::from)
            .to_vec(),
            rows: ranked
                .iter()
                .enumerate()
                .map(|(i, r)| {
                    let sw = &sweeps[r.design.sweep];
                    let hk: Vec<String> = sw
                        .harmonic_numbers(&r.design)
                        .iter()
                        .map(usize::to_string)
                        .collect();
                    vec![
                        format!("{}", i + 1),
                        format!("{:.3}", sw.exciter.level),
                        sw.band.label.clone(),
                        sw.channel_names(&r.design).join("+"),
                        hk.join(" "),
                        format!("{:.3}", r.summary.log_det),
                        format!("{:.3}", 100.0 * r.summary.std[0]),
                        format!("{:.3}", 100.0 * r.summary.std[1]),
                        format!("{:.2}", r.summary.collinearity),
                    ]
                })
                .collect(),
        },
    )?;
    let best = &ranked[0].summary;
    let worst = &ranked[n - 1].summary;
    say(&format!(
        "  best vs worst: Cramér–Rao std {:.2}x and {:.2}x smaller",
        worst.std[0] / best.std[0],
        worst.std[1] / best.std[1]
    ));
    let fig = Lines {
        title: format!("{}: candidate tests ranked by D-optimality", model.name()),
        x_desc: "rank".into(),
        y_desc: "ln det F (relative units)".into(),
        series: vec![(
            "ln det of the Fisher information".into(),
            ranked
                .iter()
                .enumerate()
                .filter(|(_, r)| r.summary.log_det.is_finite())
                .map(|(i, r)| ((i + 1) as f64, r.summary.log_det))
                .collect(),
        )],
    };
    say(&format!(
        "  plots: {}",
        plot_both(report, "planning_ranking", &fig)?
    ));
    Ok(())
}

/// Stage 6: the demo's test (see [`demo_sweeps`]) through the default [`Shaker`] at the
/// model's drive point, first voltage-driven, then force-controlled (1 %); 2 % response
/// noise with a floor of 1e-3 of each sensor's largest response (seed 2016). Returns the controlled test's data for the calibration stage, or
/// `None` when the model has nothing to test.
pub fn demo_virtual_test(
    model: &Model,
    reduced: &ReducedModel,
    report: &crate::present::report::Report,
    say: &dyn Fn(&str),
) -> Result<Option<TestData>> {
    report.section("6. Virtual test through a shaker");
    if model.elements().is_empty() || model.excitation().is_empty() || model.sensors().is_empty() {
        say("[6/8] virtual test: the model needs an element, an excitation and a sensor; skipped");
        report.skip("the model needs an element, an excitation and a sensor");
        return Ok(None);
    }
    let t = Instant::now();
    let sys = HbSystem::from_model(model, reduced, HarmonicSet::new(3, 1)?, HbConfig::default())?;
    let Some(params) = demo_parameters(&sys) else {
        say("[6/8] virtual test: no element parameter with a positive value; skipped");
        report.skip("no element parameter with a positive value");
        return Ok(None);
    };
    let force = model.excitation()[0].amplitude;
    let plans = demo_sweeps(&sys, &params, force);
    let input = sys.inputs()[0].0.clone();
    let shaker = Shaker::default();
    // 2 % noise with a floor of 1e-3 of each sensor's largest response in the noise-free
    // controlled test (a harmonic the structure does not make is then noise, not zero).
    let quiet = Noise::relative(0.0);
    let control = ControlConfig::default();
    let n_sensors = sys.sensors().len();
    let clean = virtual_test_with(
        &sys,
        &input,
        &shaker,
        &plans,
        3,
        &control,
        &vec![quiet; n_sensors],
        quiet,
        2016,
    )?;
    let peaks = clean.data.fundamental_peaks();
    let noise = nlsim_calib::scaled_noise(0.02, 0.0, 1e-3, &peaks);
    let open = virtual_test_with(
        &sys,
        &input,
        &shaker,
        &plans,
        3,
        &ControlConfig {
            enabled: false,
            ..ControlConfig::default()
        },
        &noise,
        quiet,
        2016,
    )?;
    let ctl = virtual_test_with(
        &sys, &input, &shaker, &plans, 3, &control, &noise, quiet, 2016,
    )?;
    say(&format!(
        "[6/8] virtual test: the stepped sines through a shaker model (armature {} kg, Bl {} N/A, \
         coil {} ohm, stinger {:.0e} N/m) at '{input}', voltage-driven and force-controlled, in {:.2} s",
        shaker.armature_mass,
        shaker.force_constant,
        shaker.resistance,
        shaker.stinger_stiffness,
        t.elapsed().as_secs_f64()
    ));
    let text = report.table_text();
    say(
        "  sweep            open loop: min |F1|/target  max |F3|/|F1|   controlled: iterations mean/max  max force error  steps converged",
    );
    let mut rows = Vec::new();
    let mut notes = Vec::new();
    for (s, plan) in plans.iter().enumerate() {
        let o = &open.steps[s];
        let c = &ctl.steps[s];
        let min_ratio = crate::commands::test::run::min_force_ratio(o, plan.force);
        let distortion = o
            .iter()
            .map(|st| st.force[3].norm() / st.force[1].norm())
            .filter(|v| v.is_finite())
            .fold(0.0f64, f64::max);
        let cs = crate::commands::test::run::ControlStats::of(c);
        say(&format!(
            "  {:<16} {:>27.3}  {:>13.2e}   {:>21.1}/{:<3}  {:>13.2} %  {:>6}/{}",
            plan.label,
            min_ratio,
            distortion,
            cs.mean_iterations,
            cs.max_iterations,
            100.0 * cs.max_force_error,
            cs.converged,
            cs.steps
        ));
        rows.push(vec![
            plan.label.clone(),
            format!("{min_ratio:.3}"),
            format!("{distortion:.2e}"),
            format!("{:.1}", cs.mean_iterations),
            format!("{}", cs.max_iterations),
            format!("{:.2}", 100.0 * cs.max_force_error),
            format!("{}/{}", cs.converged, cs.steps),
        ]);
        // Steps a run could not solve are named, not dropped in silence.
        for (what, steps) in [("open loop", o), ("controlled", c)] {
            let failed = crate::commands::test::run::unsolved_steps(steps, 3);
            if !failed.is_empty() {
                notes.push(format!(
                    "  {}, {what}: structure not solved at step{} {}: left out, a gap in the plots",
                    plan.label,
                    if failed.len() == 1 { "" } else { "s" },
                    failed.join(", ")
                ));
            }
        }
    }
    drop(text);
    report.table(
        "virtual_test_runs",
        crate::present::report::Table {
            caption: "The virtual test's sweeps: voltage-driven (open loop) and force-controlled"
                .into(),
            header: [
                "sweep",
                "open loop: min |F1|/target",
                "open loop: max |F3|/|F1|",
                "controlled: mean iterations",
                "controlled: max iterations",
                "controlled: max force error (%)",
                "controlled: steps converged",
            ]
            .map(String::from)
            .to_vec(),
            rows,
        },
    )?;
    for n in &notes {
        say(n);
    }
    let csv = report.dir().join("virtual_test.csv");
    crate::formats::test_data::write_csv(&csv, &ctl.data)?;
    report.wrote(&csv);
    report.seed("virtual test noise", 2016)?;
    // Thesis Fig. 11: the force at the drive point and the response, open loop vs control.
    let last = plans.len() - 1;
    let series = |t: &nlsim_calib::VirtualTest, k: usize| -> Vec<(f64, f64)> {
        // A step not solved is a gap (a non-finite point).
        t.steps[last]
            .iter()
            .map(|st| (st.frequency_hz, st.force[k].norm()))
            .collect()
    };
    let fig = Lines {
        title: format!(
            "{}: force at the drive point, {} (harmonics 1 and 3)",
            model.name(),
            plans[last].label
        ),
        x_desc: "frequency (Hz)".into(),
        y_desc: "|F| (N)".into(),
        series: vec![
            ("voltage-driven, F1".into(), series(&open, 1)),
            ("force-controlled, F1".into(), series(&ctl, 1)),
            ("voltage-driven, F3".into(), series(&open, 3)),
            ("force-controlled, F3".into(), series(&ctl, 3)),
        ],
    };
    let ch = &ctl.data.channels[0];
    // Every step in test order; one left out of the data is a gap.
    let resp = |t: &nlsim_calib::VirtualTest| -> Vec<(f64, f64)> {
        let data = t.data.sweeps.iter().find(|s| s.label == plans[last].label);
        t.steps[last]
            .iter()
            .map(|rec| {
                let f = rec.frequency_hz;
                let v = data
                    .and_then(|s| s.steps.iter().find(|st| st.frequency_hz == f))
                    .map_or(f64::NAN, |st| st.response[(0, 0)].norm());
                (f, v)
            })
            .collect()
    };
    let fig2 = Lines {
        title: format!("{}: response, {}", model.name(), plans[last].label),
        x_desc: "frequency (Hz)".into(),
        y_desc: format!(
            "|{}| {} ({})",
            ch.name,
            ch.quantity.as_str(),
            crate::formats::files::unit(ch.quantity)
        ),
        series: vec![
            ("voltage-driven".into(), resp(&open)),
            ("force-controlled".into(), resp(&ctl)),
        ],
    };
    say(&format!(
        "  plots: {}, {}",
        plot_both(report, "virtual_test_force", &fig)?,
        plot_both(report, "virtual_test_response", &fig2)?
    ));
    say(&format!(
        "  test data: {} (the force-controlled test; stage 7 calibrates on it)",
        csv.display()
    ));
    Ok(Some(ctl.data))
}
