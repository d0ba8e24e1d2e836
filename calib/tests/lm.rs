//! Levenberg–Marquardt against reference least-squares problems with known optima (Moré,
//! Garbow and Hillstrom, *Testing unconstrained optimization software*, ACM TOMS 7, 1981:
//! the MINPACK test set), with and without bounds.

use faer::Mat;
use nlsim_calib::{Evaluation, LeastSquares, LmConfig, Status, levenberg_marquardt};
use nlsim_kernel::Result;

type Resid = fn(&[f64]) -> Vec<f64>;
type Jac = fn(&[f64]) -> Vec<Vec<f64>>;

struct Problem {
    n: usize,
    r: Resid,
    j: Jac,
}

impl LeastSquares for Problem {
    fn n_params(&self) -> usize {
        self.n
    }
    fn evaluate(&mut self, u: &[f64]) -> Result<Option<Evaluation>> {
        let r = (self.r)(u);
        let j = (self.j)(u);
        Ok(Some(Evaluation {
            jacobian: Mat::from_fn(r.len(), self.n, |i, k| j[i][k]),
            residuals: r,
        }))
    }
}

fn rosenbrock_r(x: &[f64]) -> Vec<f64> {
    vec![10.0 * (x[1] - x[0] * x[0]), 1.0 - x[0]]
}
fn rosenbrock_j(x: &[f64]) -> Vec<Vec<f64>> {
    vec![vec![-20.0 * x[0], 10.0], vec![-1.0, 0.0]]
}
fn powell_r(x: &[f64]) -> Vec<f64> {
    vec![
        1e4 * x[0] * x[1] - 1.0,
        (-x[0]).exp() + (-x[1]).exp() - 1.0001,
    ]
}
fn powell_j(x: &[f64]) -> Vec<Vec<f64>> {
    vec![
        vec![1e4 * x[1], 1e4 * x[0]],
        vec![-(-x[0]).exp(), -(-x[1]).exp()],
    ]
}
fn brown_r(x: &[f64]) -> Vec<f64> {
    vec![x[0] - 1e6, x[1] - 2e-6, x[0] * x[1] - 2.0]
}
fn brown_j(x: &[f64]) -> Vec<Vec<f64>> {
    vec![vec![1.0, 0.0], vec![0.0, 1.0], vec![x[1], x[0]]]
}
const BEALE_Y: [f64; 3] = [1.5, 2.25, 2.625];
fn beale_r(x: &[f64]) -> Vec<f64> {
    (1..=3)
        .map(|i| BEALE_Y[i - 1] - x[0] * (1.0 - x[1].powi(i as i32)))
        .collect()
}
fn beale_j(x: &[f64]) -> Vec<Vec<f64>> {
    (1..=3)
        .map(|i: i32| vec![-(1.0 - x[1].powi(i)), x[0] * i as f64 * x[1].powi(i - 1)])
        .collect()
}
fn helical_r(x: &[f64]) -> Vec<f64> {
    let theta =
        (x[1] / x[0]).atan() / (2.0 * std::f64::consts::PI) + if x[0] < 0.0 { 0.5 } else { 0.0 };
    vec![
        10.0 * (x[2] - 10.0 * theta),
        10.0 * ((x[0] * x[0] + x[1] * x[1]).sqrt() - 1.0),
        x[2],
    ]
}
fn helical_j(x: &[f64]) -> Vec<Vec<f64>> {
    let s = x[0] * x[0] + x[1] * x[1];
    let tpi = 2.0 * std::f64::consts::PI;
    let r = s.sqrt();
    vec![
        vec![100.0 * x[1] / (tpi * s), -100.0 * x[0] / (tpi * s), 10.0],
        vec![10.0 * x[0] / r, 10.0 * x[1] / r, 0.0],
        vec![0.0, 0.0, 1.0],
    ]
}
const BARD_Y: [f64; 15] = [
    0.14, 0.18, 0.22, 0.25, 0.29, 0.32, 0.35, 0.39, 0.37, 0.58, 0.73, 0.96, 1.34, 2.10, 4.39,
];
fn bard_uvw(i: usize) -> (f64, f64, f64) {
    let u = i as f64;
    let v = 16.0 - u;
    (u, v, u.min(v))
}
fn bard_r(x: &[f64]) -> Vec<f64> {
    (1..=15)
        .map(|i| {
            let (u, v, w) = bard_uvw(i);
            BARD_Y[i - 1] - (x[0] + u / (v * x[1] + w * x[2]))
        })
        .collect()
}
fn bard_j(x: &[f64]) -> Vec<Vec<f64>> {
    (1..=15)
        .map(|i| {
            let (u, v, w) = bard_uvw(i);
            let d = v * x[1] + w * x[2];
            vec![-1.0, u * v / (d * d), u * w / (d * d)]
        })
        .collect()
}
const KO_Y: [f64; 11] = [
    0.1957, 0.1947, 0.1735, 0.1600, 0.0844, 0.0627, 0.0456, 0.0342, 0.0323, 0.0235, 0.0246,
];
const KO_U: [f64; 11] = [
    4.0, 2.0, 1.0, 0.5, 0.25, 0.167, 0.125, 0.1, 0.0833, 0.0714, 0.0625,
];
fn ko_r(x: &[f64]) -> Vec<f64> {
    (0..11)
        .map(|i| {
            let u = KO_U[i];
            KO_Y[i] - x[0] * (u * u + u * x[1]) / (u * u + u * x[2] + x[3])
        })
        .collect()
}
fn ko_j(x: &[f64]) -> Vec<Vec<f64>> {
    (0..11)
        .map(|i| {
            let u = KO_U[i];
            let num = u * u + u * x[1];
            let den = u * u + u * x[2] + x[3];
            vec![
                -num / den,
                -x[0] * u / den,
                x[0] * num * u / (den * den),
                x[0] * num / (den * den),
            ]
        })
        .collect()
}
const MEYER_Y: [f64; 16] = [
    34780.0, 28610.0, 23650.0, 19630.0, 16370.0, 13720.0, 11540.0, 9744.0, 8261.0, 7030.0, 6005.0,
    5147.0, 4427.0, 3820.0, 3307.0, 2872.0,
];
fn meyer_r(x: &[f64]) -> Vec<f64> {
    (1..=16)
        .map(|i| {
            let t = 45.0 + 5.0 * i as f64;
            x[0] * (x[1] / (t + x[2])).exp() - MEYER_Y[i - 1]
        })
        .collect()
}
fn meyer_j(x: &[f64]) -> Vec<Vec<f64>> {
    (1..=16)
        .map(|i| {
            let t = 45.0 + 5.0 * i as f64;
            let e = (x[1] / (t + x[2])).exp();
            vec![
                e,
                x[0] * e / (t + x[2]),
                -x[0] * e * x[1] / ((t + x[2]) * (t + x[2])),
            ]
        })
        .collect()
}
fn box3d_r(x: &[f64]) -> Vec<f64> {
    (1..=10)
        .map(|i| {
            let t = 0.1 * i as f64;
            (-t * x[0]).exp() - (-t * x[1]).exp() - x[2] * ((-t).exp() - (-10.0 * t).exp())
        })
        .collect()
}
fn box3d_j(x: &[f64]) -> Vec<Vec<f64>> {
    (1..=10)
        .map(|i| {
            let t = 0.1 * i as f64;
            vec![
                -t * (-t * x[0]).exp(),
                t * (-t * x[1]).exp(),
                -((-t).exp() - (-10.0 * t).exp()),
            ]
        })
        .collect()
}
fn jennrich_r(x: &[f64]) -> Vec<f64> {
    (1..=10)
        .map(|i| {
            let i = i as f64;
            2.0 + 2.0 * i - ((i * x[0]).exp() + (i * x[1]).exp())
        })
        .collect()
}
fn jennrich_j(x: &[f64]) -> Vec<Vec<f64>> {
    (1..=10)
        .map(|i| {
            let i = i as f64;
            vec![-i * (i * x[0]).exp(), -i * (i * x[1]).exp()]
        })
        .collect()
}

/// `(name, problem, start, sum of squares at the optimum, optimum when unique)`.
type Case = (&'static str, Problem, Vec<f64>, f64, Option<Vec<f64>>);

fn cases() -> Vec<Case> {
    vec![
        (
            "Rosenbrock",
            Problem {
                n: 2,
                r: rosenbrock_r,
                j: rosenbrock_j,
            },
            vec![-1.2, 1.0],
            0.0,
            Some(vec![1.0, 1.0]),
        ),
        (
            "Powell badly scaled",
            Problem {
                n: 2,
                r: powell_r,
                j: powell_j,
            },
            vec![0.0, 1.0],
            0.0,
            Some(vec![1.098159e-5, 9.106146]),
        ),
        (
            "Brown badly scaled",
            Problem {
                n: 2,
                r: brown_r,
                j: brown_j,
            },
            vec![1.0, 1.0],
            0.0,
            Some(vec![1e6, 2e-6]),
        ),
        (
            "Beale",
            Problem {
                n: 2,
                r: beale_r,
                j: beale_j,
            },
            vec![1.0, 1.0],
            0.0,
            Some(vec![3.0, 0.5]),
        ),
        (
            "helical valley",
            Problem {
                n: 3,
                r: helical_r,
                j: helical_j,
            },
            vec![-1.0, 0.0, 0.0],
            0.0,
            Some(vec![1.0, 0.0, 0.0]),
        ),
        (
            "Bard",
            Problem {
                n: 3,
                r: bard_r,
                j: bard_j,
            },
            vec![1.0, 1.0, 1.0],
            8.21487e-3,
            None,
        ),
        (
            "Kowalik–Osborne",
            Problem {
                n: 4,
                r: ko_r,
                j: ko_j,
            },
            vec![0.25, 0.39, 0.415, 0.39],
            3.07505e-4,
            None,
        ),
        (
            "Meyer",
            Problem {
                n: 3,
                r: meyer_r,
                j: meyer_j,
            },
            vec![0.02, 4000.0, 250.0],
            87.9458,
            None,
        ),
        (
            "Box 3-D",
            Problem {
                n: 3,
                r: box3d_r,
                j: box3d_j,
            },
            vec![0.0, 10.0, 20.0],
            0.0,
            None,
        ),
        (
            "Jennrich–Sampson",
            Problem {
                n: 2,
                r: jennrich_r,
                j: jennrich_j,
            },
            vec![0.3, 0.4],
            124.362,
            Some(vec![0.2578, 0.2578]),
        ),
    ]
}

#[test]
fn jacobians_of_the_test_problems_match_central_differences() {
    // The oracle's own check: an analytic Jacobian typo would make the LM test meaningless.
    for (name, mut p, x0, _, _) in cases() {
        let x: Vec<f64> = x0.iter().map(|v| v * 1.1 + 0.05).collect();
        let ev = p.evaluate(&x).unwrap().unwrap();
        for k in 0..p.n {
            let h = 1e-6 * x[k].abs().max(1e-3);
            let (mut a, mut b) = (x.clone(), x.clone());
            a[k] += h;
            b[k] -= h;
            let (ra, rb) = ((p.r)(&a), (p.r)(&b));
            for i in 0..ra.len() {
                let fd = (ra[i] - rb[i]) / (2.0 * h);
                let an = ev.jacobian[(i, k)];
                assert!(
                    (fd - an).abs() <= 1e-5 * an.abs().max(fd.abs()).max(1e-3),
                    "{name} J[{i},{k}]: {an} vs {fd}"
                );
            }
        }
    }
}

#[test]
fn reaches_the_published_optima() {
    let cfg = LmConfig {
        max_iterations: 400,
        ..LmConfig::default()
    };
    for (name, mut p, x0, fstar, xstar) in cases() {
        let inf = vec![f64::INFINITY; p.n];
        let ninf = vec![f64::NEG_INFINITY; p.n];
        let rep = levenberg_marquardt(&mut p, &x0, &ninf, &inf, &cfg).unwrap();
        assert_eq!(
            rep.status,
            Status::Converged,
            "{name}: {:?} after {} iterations",
            rep.reason,
            rep.iterations
        );
        let ss = 2.0 * rep.cost;
        // Published sums of squares carry 6 significant digits.
        if fstar == 0.0 {
            assert!(ss < 1e-20, "{name}: sum of squares {ss:e}");
        } else {
            assert!(
                (ss - fstar).abs() <= 1e-5 * fstar,
                "{name}: {ss} vs {fstar}"
            );
        }
        if let Some(xs) = xstar {
            for (a, b) in rep.u.iter().zip(&xs) {
                assert!(
                    (a - b).abs() <= 1e-4 * b.abs().max(1e-6),
                    "{name}: {:?} vs {xs:?}",
                    rep.u
                );
            }
        }
        // The history is monotone in cost.
        assert!(
            rep.history.windows(2).all(|w| w[1].cost <= w[0].cost),
            "{name}"
        );
    }
}

#[test]
fn bounds_hold_at_every_iterate_and_the_bounded_optimum_is_found() {
    // Rosenbrock with x1 ≤ 0.5: along x2 = x1² the cost is (1 − x1)², so the optimum is the
    // corner of the feasible valley (0.5, 0.25) with cost ½ (1 − 0.5)² = 0.125.
    let mut p = Problem {
        n: 2,
        r: rosenbrock_r,
        j: rosenbrock_j,
    };
    let lo = [-2.0, -1.0];
    let hi = [0.5, 3.0];
    let rep = levenberg_marquardt(&mut p, &[-1.2, 1.0], &lo, &hi, &LmConfig::default()).unwrap();
    assert_eq!(rep.status, Status::Converged, "{:?}", rep.reason);
    assert!(
        (rep.u[0] - 0.5).abs() < 1e-12 && (rep.u[1] - 0.25).abs() < 1e-8,
        "{:?}",
        rep.u
    );
    assert!((rep.cost - 0.125).abs() < 1e-12);
    assert_eq!(rep.active_bounds, vec![true, false]);
    for s in &rep.history {
        assert!(
            s.u.iter()
                .zip(lo.iter().zip(&hi))
                .all(|(u, (l, h))| u >= l && u <= h),
            "{:?}",
            s.u
        );
    }
    // A start outside the box is projected onto it.
    let rep = levenberg_marquardt(&mut p, &[9.0, -9.0], &lo, &hi, &LmConfig::default()).unwrap();
    assert_eq!(rep.history[0].u, vec![0.5, -1.0]);
    assert!((rep.u[0] - 0.5).abs() < 1e-12);
}

#[test]
fn invalid_input_is_an_error_and_failed_evaluations_are_a_status() {
    let mut p = Problem {
        n: 2,
        r: rosenbrock_r,
        j: rosenbrock_j,
    };
    assert!(
        levenberg_marquardt(&mut p, &[0.0], &[0.0; 2], &[1.0; 2], &LmConfig::default()).is_err()
    );
    assert!(
        levenberg_marquardt(
            &mut p,
            &[0.0, 0.0],
            &[1.0, 0.0],
            &[0.0, 1.0],
            &LmConfig::default()
        )
        .is_err()
    );

    /// Fails to evaluate for x > 0.3: the optimum (1, 1) is out of reach.
    struct Fragile(Problem);
    impl LeastSquares for Fragile {
        fn n_params(&self) -> usize {
            2
        }
        fn evaluate(&mut self, u: &[f64]) -> Result<Option<Evaluation>> {
            if u[0] > 0.3 {
                return Ok(None);
            }
            self.0.evaluate(u)
        }
    }
    let mut f = Fragile(Problem {
        n: 2,
        r: rosenbrock_r,
        j: rosenbrock_j,
    });
    let inf = [f64::INFINITY; 2];
    let rep = levenberg_marquardt(
        &mut f,
        &[-1.2, 1.0],
        &[-inf[0]; 2],
        &inf,
        &LmConfig::default(),
    )
    .unwrap();
    assert!(rep.failed_evaluations > 0);
    assert!(rep.u[0] <= 0.3 && rep.cost.is_finite());
    // It returns the best point reached, with a status rather than an error.
    assert!(rep.history.last().unwrap().cost <= rep.history[0].cost);
}
