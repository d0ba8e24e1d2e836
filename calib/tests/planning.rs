//! Pre-test planning: the Fisher information against a finite-difference one, a collinear
//! pair found, the D-optimal design against a brute force of independent calibration
//! objectives, and the greedy/exchange placement against full enumeration.

use faer::{Mat, c64};
use nlsim_calib::{
    Band, Criterion, Exciter, FimSummary, Form, FrfObjective, Noise, ObjectiveConfig, ParamSpec,
    Planner, SweepPlan, dof_information, greedy_placement, rank_designs, subsets, synthesize,
};
use nlsim_hb::{HarmonicSet, HbConfig, HbSystem};
use nlsim_kernel::{
    Component, Coupling, DofLabel, Law, Model, NonlinearElement, Param, Parameterized, Quantity,
    Sensor,
};
use nlsim_reduction::{ReducedModel, ReductionConfig, reduce};
use std::sync::Arc;

/// The ECL beam of 10 elements with a third sensor at the quarter point.
fn beam() -> Model {
    let mut model = nlsim_fixtures::build("ecl_beam", &[("elements".into(), "10".into())])
        .unwrap()
        .model;
    let dof = model
        .dofs()
        .index_of(&DofLabel::new(4, Component::Uz))
        .unwrap();
    model
        .add_sensor(Sensor {
            name: "quarter".into(),
            at: nlsim_kernel::Site::Dof(dof),
            quantity: Quantity::Acceleration,
        })
        .unwrap();
    model
}

fn system(model: &Model, modes: usize) -> (HbSystem, ReducedModel) {
    let red = reduce(model, &ReductionConfig::lowest(modes)).unwrap();
    let sys = HbSystem::from_model(
        model,
        &red,
        HarmonicSet::new(3, 1).unwrap(),
        HbConfig::default(),
    )
    .unwrap();
    (sys, red)
}

fn noise() -> Noise {
    Noise {
        absolute: 1e-3,
        relative: 0.01,
    }
}

fn params(sys: &HbSystem) -> Vec<Param> {
    let driven = sys
        .linear()
        .dominant_mode(sys.sensors()[0].port, 0..2)
        .unwrap();
    vec![
        Param::element("tip_spring", "k3"),
        Param::ModalDamping(driven),
    ]
}

fn f1(sys: &HbSystem, p: &[Param]) -> f64 {
    let Param::ModalDamping(r) = p[1] else {
        unreachable!()
    };
    sys.linear().frequency_hz(r)
}

/// A stepped sine of 12 steps from 0.95 to 1.08 times the driven mode's frequency `f` (Hz).
fn around_mode_1(f: f64) -> Band {
    Band {
        label: "around mode 1".into(),
        from_hz: 0.95 * f,
        to_hz: 1.08 * f,
        steps: 12,
    }
}

/// The Fisher information `Σ Re(dY_a* dY_b)/σ²` over the steps' `responses` (channels ×
/// harmonics), every channel and the `harmonics` listed, from the derivatives `d[a][step]`
/// (same layout) and the noise model of [`noise`] at the response.
fn information(responses: &[Mat<c64>], d: &[Vec<Mat<c64>>], harmonics: &[usize]) -> Mat<f64> {
    let n = d.len();
    let mut f = Mat::<f64>::zeros(n, n);
    for (i, y) in responses.iter().enumerate() {
        for c in 0..y.nrows() {
            for &k in harmonics {
                let s = noise().sigma(y[(c, k - 1)]);
                for a in 0..n {
                    for b in 0..n {
                        let (da, db) = (d[a][i][(c, k - 1)], d[b][i][(c, k - 1)]);
                        f[(a, b)] += (da.re * db.re + da.im * db.im) / (s * s);
                    }
                }
            }
        }
    }
    f
}

#[test]
fn fisher_information_equals_a_finite_difference_one() {
    let (sys, _) = system(&beam(), 6);
    let p = params(&sys);
    let f = f1(&sys, &p);
    let planner = Planner::new(&sys, &p).unwrap();
    let ex = Exciter::sine("shaker", 0.2);
    let band = around_mode_1(f);
    let harmonics = [1, 3];
    let info = planner
        .sweep_information(&ex, &band, noise(), &harmonics)
        .unwrap();
    assert!(info.failed_hz.is_empty());
    let all: Vec<usize> = (0..info.channels.len()).collect();
    let fim = info.fim(&all, &[0, 1], None);
    // The derivatives of the predicted responses by central differences in ln p, step 1e-5:
    // truncation ~1e-10, Newton round-off (1e-10 relative) / 1e-5 ~ 1e-5 relative.
    let nominal = sys.param_values(&p).unwrap();
    let responses = |j: usize, factor: f64| {
        let mut s = sys.clone();
        s.set_param(&p[j], nominal[j] * factor).unwrap();
        let pl = Planner::new(&s, &p).unwrap();
        pl.sweep_information(&ex, &band, noise(), &harmonics)
            .unwrap()
            .responses
    };
    let h: f64 = 1e-5;
    let d: Vec<Vec<Mat<c64>>> = (0..p.len())
        .map(|j| {
            let (u, dn) = (responses(j, h.exp()), responses(j, (-h).exp()));
            u.iter()
                .zip(&dn)
                .map(|(a, b)| (a - b) * faer::Scale(c64::new(0.5 / h, 0.0)))
                .collect()
        })
        .collect();
    let fd = information(&info.responses, &d, &harmonics);
    let scale = fim.norm_max();
    assert!(scale > 0.0);
    for a in 0..p.len() {
        for b in 0..p.len() {
            assert!(
                (fim[(a, b)] - fd[(a, b)]).abs() <= 1e-4 * scale,
                "F[{a},{b}] analytic {} vs finite difference {}",
                fim[(a, b)],
                fd[(a, b)]
            );
        }
    }
    let s = FimSummary::new(&fim);
    assert_eq!(s.rank, 2);
    assert!(s.std.iter().all(|v| v.is_finite() && *v > 0.0));
    assert!(s.collinearity.is_finite());
}

/// Gains of the test data planned as calibrated along (nominal 1): the Fisher information of
/// `[k3, ζ, input_gain, sensor_gain:tip]` against one from derivatives taken independently —
/// the structure's and the input gain's by central differences (the input gain as the
/// exciter's level scaled by `e^{±h}`: the model is driven with the gain times the recorded
/// force), the sensor gain's in closed form (`d(sY)/d ln s = Y` on its channel, 0 on the
/// others).
#[test]
fn gains_enter_the_information_as_the_calibration_sees_them() {
    let (sys, _) = system(&beam(), 6);
    let mut p = params(&sys);
    let f = f1(&sys, &p);
    p.push(Param::InputGain);
    p.push(Param::SensorGain("tip".into()));
    let planner = Planner::new(&sys, &p).unwrap();
    assert_eq!(&planner.nominal()[2..], &[1.0, 1.0]);
    let band = around_mode_1(f);
    let harmonics = [1, 3];
    let info = |level: f64, s: &HbSystem| {
        Planner::new(s, &p)
            .unwrap()
            .sweep_information(&Exciter::sine("shaker", level), &band, noise(), &harmonics)
            .unwrap()
    };
    let nominal = info(0.2, &sys);
    assert!(nominal.failed_hz.is_empty());
    let all: Vec<usize> = (0..nominal.channels.len()).collect();
    let fim = nominal.fim(&all, &[0, 1], None);
    let tip = nominal.channels.iter().position(|c| c == "tip").unwrap();
    let h: f64 = 1e-5;
    let values = sys.param_values(&p[..2]).unwrap();
    let diff = |u: Vec<Mat<c64>>, d: Vec<Mat<c64>>| -> Vec<Mat<c64>> {
        u.iter()
            .zip(&d)
            .map(|(a, b)| (a - b) * faer::Scale(c64::new(0.5 / h, 0.0)))
            .collect()
    };
    let mut d: Vec<Vec<Mat<c64>>> = (0..2)
        .map(|j| {
            let at = |factor: f64| {
                let mut s = sys.clone();
                s.set_param(&p[j], values[j] * factor).unwrap();
                info(0.2, &s).responses
            };
            diff(at(h.exp()), at((-h).exp()))
        })
        .collect();
    d.push(diff(
        info(0.2 * h.exp(), &sys).responses,
        info(0.2 * (-h).exp(), &sys).responses,
    ));
    d.push(
        nominal
            .responses
            .iter()
            .map(|y| {
                Mat::from_fn(y.nrows(), y.ncols(), |c, k| {
                    if c == tip {
                        y[(c, k)]
                    } else {
                        c64::new(0.0, 0.0)
                    }
                })
            })
            .collect(),
    );
    let n = p.len();
    let fd = information(&nominal.responses, &d, &harmonics);
    // As above: the differences' round-off ~1e-5 relative.
    let scale = fim.norm_max();
    for a in 0..n {
        for b in 0..n {
            assert!(
                (fim[(a, b)] - fd[(a, b)]).abs() <= 1e-4 * scale,
                "F[{}, {}] planned {} vs independent {}",
                p[a],
                p[b],
                fim[(a, b)],
                fd[(a, b)]
            );
        }
    }
    // Identified together here (the cubic's amplitude dependence separates the force gain
    // from the damping); without the tip channel its gain is not identified at all.
    assert_eq!(FimSummary::new(&fim).rank, 4);
    let others: Vec<usize> = all.iter().copied().filter(|&c| c != tip).collect();
    let without = FimSummary::new(&nominal.fim(&others, &[0, 1], None));
    assert_eq!(without.rank, 3);
    assert!(without.std[3].is_infinite());
}

#[test]
fn a_collinear_pair_is_reported_not_a_silent_huge_variance() {
    // Two cubic springs on the same DOF: only their sum is identifiable.
    let mut model = beam();
    let tip = model
        .dofs()
        .index_of(&DofLabel::new(11, Component::Uz))
        .unwrap();
    model
        .add_element(
            NonlinearElement::new("twin", Law::Cubic { k3: 2e9 }, Coupling::single(tip)).unwrap(),
        )
        .unwrap();
    let (sys, _) = system(&model, 6);
    let p = vec![
        Param::element("tip_spring", "k3"),
        Param::element("twin", "k3"),
    ];
    let f = sys.linear().frequency_hz(0);
    let planner = Planner::new(&sys, &p).unwrap();
    let info = planner
        .sweep_information(
            &Exciter::sine("shaker", 0.2),
            &Band {
                label: "b".into(),
                from_hz: 0.95 * f,
                to_hz: 1.1 * f,
                steps: 10,
            },
            noise(),
            &[1],
        )
        .unwrap();
    let s = FimSummary::new(&info.fim(&[0, 1, 2], &[0], None));
    assert_eq!(s.rank, 1, "{s:?}");
    assert!(s.collinearity > 1e5, "{s:?}");
    let (i, j, cos) = s.most_collinear.unwrap();
    assert_eq!((i, j), (0, 1));
    assert!((cos - 1.0).abs() < 1e-8, "cosine {cos}");
    assert!(s.std.iter().all(|v| v.is_infinite()));
    assert_eq!(s.log_det, f64::NEG_INFINITY);
}

/// `ln det JᵀJ` of one design, from a calibration objective on noise-free synthetic data of
/// just that design's channels.
fn brute_force_log_det(
    sys: &HbSystem,
    p: &[Param],
    ex: &Exciter,
    band: &Band,
    channels: &[usize],
    harmonics: &[usize],
) -> f64 {
    let plan = SweepPlan::linear("b", band.from_hz, band.to_hz, band.steps, ex.level);
    let mut data = synthesize(sys, &ex.input, &[plan], 3, Noise::relative(0.0), 1).unwrap();
    data.channels = channels.iter().map(|&c| data.channels[c].clone()).collect();
    for ch in &mut data.channels {
        ch.noise = noise();
    }
    for st in &mut data.sweeps[0].steps {
        let r = st.response.clone();
        st.response = Mat::from_fn(channels.len(), 3, |i, k| r[(channels[i], k)]);
    }
    let nominal = sys.param_values(p).unwrap();
    // Log-spaced specs: the Jacobian columns are d/d ln p.
    let specs = p
        .iter()
        .zip(&nominal)
        .map(|(q, &v)| ParamSpec::new(q.clone(), v / 100.0, v * 100.0))
        .collect();
    let mut obj = FrfObjective::new(
        sys,
        Arc::new(data),
        specs,
        ObjectiveConfig {
            harmonics: harmonics.to_vec(),
            form: Form::Complex,
            ..ObjectiveConfig::default()
        },
    )
    .unwrap();
    let j = obj
        .evaluate_values(&nominal, None, true)
        .unwrap()
        .jacobian
        .unwrap();
    FimSummary::new(&(j.transpose() * &j)).log_det
}

#[test]
fn the_d_optimal_design_is_the_brute_force_optimum() {
    let (sys, _) = system(&beam(), 6);
    let p = params(&sys);
    let f = f1(&sys, &p);
    let planner = Planner::new(&sys, &p).unwrap();
    let exciters = [Exciter::sine("shaker", 0.05), Exciter::sine("shaker", 0.2)];
    let bands = [
        Band {
            label: "below".into(),
            from_hz: 0.85 * f,
            to_hz: 0.97 * f,
            steps: 8,
        },
        Band {
            label: "across".into(),
            from_hz: 0.95 * f,
            to_hz: 1.1 * f,
            steps: 10,
        },
    ];
    let harmonics = [1, 3];
    let mut sweeps = Vec::new();
    let mut keys = Vec::new();
    for ex in &exciters {
        for b in &bands {
            sweeps.push(
                planner
                    .sweep_information(ex, b, noise(), &harmonics)
                    .unwrap(),
            );
            keys.push((ex.clone(), b.clone()));
        }
    }
    let channel_sets = subsets(3, 1);
    let harmonic_sets = vec![vec![0], vec![0, 1]];
    let ranked = rank_designs(&sweeps, &channel_sets, &harmonic_sets, None, Criterion::D).unwrap();
    assert_eq!(ranked.len(), 4 * 3 * 2);
    let mut best = (f64::NEG_INFINITY, None);
    for r in &ranked {
        let (ex, b) = &keys[r.design.sweep];
        let hk: Vec<usize> = r.design.harmonics.iter().map(|&h| harmonics[h]).collect();
        let bf = brute_force_log_det(&sys, &p, ex, b, &r.design.channels, &hk);
        // Both are ln det of the same JᵀJ summed in another order: agreement to round-off
        // of the sums (relative 1e-9 of the determinant).
        assert!(
            (bf - r.summary.log_det).abs() < 1e-9 * bf.abs().max(1.0),
            "{:?}: planner {} vs brute force {bf}",
            r.design,
            r.summary.log_det
        );
        if bf > best.0 {
            best = (bf, Some(r.design.clone()));
        }
    }
    assert_eq!(Some(ranked[0].design.clone()), best.1);
    // Ranked best first by every criterion.
    for c in Criterion::ALL {
        let r = rank_designs(&sweeps, &channel_sets, &harmonic_sets, None, c).unwrap();
        assert!(
            r.windows(2)
                .all(|w| w[0].summary.score(c) >= w[1].summary.score(c))
        );
    }
}

#[test]
fn greedy_exchange_placement_finds_the_enumerated_optimum() {
    let model = beam();
    let (sys, red) = system(&model, 8);
    let p = params(&sys);
    let f = f1(&sys, &p);
    let ex = Exciter::sine("shaker", 0.2);
    let band = Band {
        label: "across".into(),
        from_hz: 0.95 * f,
        to_hz: 1.08 * f,
        steps: 10,
    };
    // Every translational DOF of the beam as a candidate accelerometer.
    let cand: Vec<usize> = (0..model.n_dofs())
        .filter(|&i| {
            matches!(
                model.dofs().label(i).component,
                Component::Ux | Component::Uy | Component::Uz
            )
        })
        .collect();
    let shapes = Mat::from_fn(cand.len(), red.n_modes(), |i, r| {
        red.modes.vectors[(cand[i], r)]
    });
    let (terms, failed) = dof_information(
        &sys,
        shapes.as_ref(),
        Quantity::Acceleration,
        &ex,
        &band,
        &p,
        noise(),
        &[1, 3],
    )
    .unwrap();
    assert!(failed.is_empty());
    assert_eq!(terms.len(), cand.len());
    // The DOF term at the mid sensor is the planner's term there, up to the residual
    // flexibility the mode-displacement approximation leaves out (8 modes of a 10-element
    // beam: a few per cent).
    let info = Planner::new(&sys, &p)
        .unwrap()
        .sweep_information(&ex, &band, noise(), &[1, 3])
        .unwrap();
    let mid_dof = model.sensors()[1].at.dof().unwrap();
    let ci = cand.iter().position(|&d| d == mid_dof).unwrap();
    let planner_mid = info.fim(&[1], &[0, 1], None);
    let rel = (&terms[ci] - &planner_mid).norm_max() / planner_mid.norm_max();
    assert!(
        rel < 0.05,
        "mid sensor: DOF term vs planner term differ by {rel}"
    );
    for k in [2, 3] {
        let pl = greedy_placement(&terms, k, None, 50).unwrap();
        let mut best = f64::NEG_INFINITY;
        for s in subsets(terms.len(), k) {
            let mut f = Mat::<f64>::zeros(2, 2);
            for &i in &s {
                f += &terms[i];
            }
            best = best.max(FimSummary::new(&f).log_det);
        }
        assert!(
            (pl.log_det - best).abs() < 1e-9 * best.abs().max(1.0),
            "k = {k}: exchange {} vs enumerated {best}",
            pl.log_det
        );
        // The greedy pass alone is within a factor 2 of the optimal determinant.
        assert!(pl.greedy_log_det >= best - 2f64.ln(), "{pl:?} vs {best}");
    }
}

#[test]
fn a_planner_from_the_model_equals_one_from_its_reduced_system() {
    let model = beam();
    let (sys, _) = system(&model, 6);
    let p = vec![Param::element("tip_spring", "k3")];
    let f = sys.linear().frequency_hz(0);
    let band = Band {
        label: "b".into(),
        from_hz: 0.95 * f,
        to_hz: 1.1 * f,
        steps: 8,
    };
    let ex = Exciter::sine("shaker", 0.2);
    let a = Planner::new(&sys, &p)
        .unwrap()
        .sweep_information(&ex, &band, noise(), &[1])
        .unwrap();
    let b = Planner::from_model(
        &model,
        &ReductionConfig::lowest(6),
        HarmonicSet::new(3, 1).unwrap(),
        HbConfig::default(),
        &p,
    )
    .unwrap()
    .sweep_information(&ex, &band, noise(), &[1])
    .unwrap();
    let (fa, fb) = (a.fim(&[0, 1, 2], &[0], None), b.fim(&[0, 1, 2], &[0], None));
    // The same reduction and solves: equal to round-off.
    assert!(
        (&fa - &fb).norm_max() <= 1e-10 * fa.norm_max(),
        "{fa:?} vs {fb:?}"
    );
}
