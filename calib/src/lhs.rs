//! Latin-hypercube start points (thesis §4.5): every parameter's range is cut into `n` equal
//! strata and each stratum is used once, so `n` candidates cover every parameter's range
//! evenly whatever the dimension. A maximin improvement (Morris–Mitchell `φ_p`, swaps within
//! a column keep the Latin property) spreads the points in the joint space too. Every draw
//! comes from a ChaCha8 stream of a recorded seed.

use nlsim_kernel::{Error, Result};
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// `n` points of a Latin hypercube in `[0, 1)^d` from `seed` (ChaCha8): each coordinate takes
/// every one of the `n` strata once, at a uniform position inside it.
pub fn latin_hypercube(n: usize, d: usize, seed: u64) -> Vec<Vec<f64>> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = vec![vec![0.0; d]; n];
    for c in 0..d {
        let mut strata: Vec<usize> = (0..n).collect();
        // Fisher–Yates.
        for i in (1..n).rev() {
            let j = rng.random_range(0..=i);
            strata.swap(i, j);
        }
        for (row, s) in out.iter_mut().zip(strata) {
            row[c] = (s as f64 + rng.random::<f64>()) / n as f64;
        }
    }
    out
}

/// Squared Euclidean distance.
fn dist2(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum()
}

/// Morris–Mitchell criterion `φ_p = (Σ_{i<j} d_ij^{−p})^{1/p}` (smaller is more spread; it
/// tends to the inverse of the smallest distance as `p` grows).
pub fn phi_p(points: &[Vec<f64>], p: f64) -> f64 {
    let mut s = 0.0;
    for i in 0..points.len() {
        for j in i + 1..points.len() {
            s += dist2(&points[i], &points[j]).max(1e-300).powf(-p / 2.0);
        }
    }
    s.powf(1.0 / p)
}

/// The smallest distance between two of `points`.
pub fn min_distance(points: &[Vec<f64>]) -> f64 {
    let mut m = f64::INFINITY;
    for i in 0..points.len() {
        for j in i + 1..points.len() {
            m = m.min(dist2(&points[i], &points[j]));
        }
    }
    m.sqrt()
}

/// [`latin_hypercube`] improved by `swaps` trial exchanges of two points' coordinates in one
/// column (kept when `φ_15` decreases): still a Latin hypercube, with larger separations.
/// Cost `O(swaps · n · d)`.
pub fn maximin_latin_hypercube(n: usize, d: usize, seed: u64, swaps: usize) -> Vec<Vec<f64>> {
    let mut pts = latin_hypercube(n, d, seed);
    if n < 3 || d == 0 {
        return pts;
    }
    const P: f64 = 15.0;
    // The sum S = Σ d_ij^{−p}, updated for the two rows a swap touches.
    let pair = |pts: &[Vec<f64>], i: usize, j: usize| -> f64 {
        dist2(&pts[i], &pts[j]).max(1e-300).powf(-P / 2.0)
    };
    let row_sum = |pts: &[Vec<f64>], i: usize, skip: usize| -> f64 {
        (0..pts.len())
            .filter(|&j| j != i && j != skip)
            .map(|j| pair(pts, i, j))
            .sum()
    };
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x9e37_79b9_7f4a_7c15);
    for _ in 0..swaps {
        let c = rng.random_range(0..d);
        let a = rng.random_range(0..n);
        let mut b = rng.random_range(0..n - 1);
        if b >= a {
            b += 1;
        }
        let before = row_sum(&pts, a, b) + row_sum(&pts, b, a);
        let (va, vb) = (pts[a][c], pts[b][c]);
        pts[a][c] = vb;
        pts[b][c] = va;
        let after = row_sum(&pts, a, b) + row_sum(&pts, b, a);
        if after >= before {
            pts[a][c] = va;
            pts[b][c] = vb;
        }
    }
    pts
}

/// How a parameter's range is sampled: evenly in the value, or evenly in its logarithm (for
/// parameters that span decades, such as a contact stiffness).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Spacing {
    /// Uniform in `[lo, hi]`.
    Linear,
    /// Uniform in `[ln lo, ln hi]` (needs `0 < lo`).
    Log,
}

/// Maps a unit-cube coordinate to `[lo, hi]` with `spacing`.
pub fn to_range(t: f64, lo: f64, hi: f64, spacing: Spacing) -> Result<f64> {
    if !(lo.is_finite() && hi.is_finite() && lo <= hi) {
        return Err(Error::invalid(
            "Latin hypercube range",
            format!("[{lo}, {hi}] must be finite with lower ≤ upper"),
        ));
    }
    Ok(match spacing {
        Spacing::Linear => lo + t * (hi - lo),
        Spacing::Log => {
            if lo <= 0.0 {
                return Err(Error::invalid(
                    "Latin hypercube range",
                    format!("log spacing needs a positive lower bound, not {lo}"),
                ));
            }
            (lo.ln() + t * (hi.ln() - lo.ln())).exp()
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn is_latin(p: &[Vec<f64>]) -> bool {
        let n = p.len();
        (0..p[0].len()).all(|c| {
            let mut seen = vec![false; n];
            p.iter().all(|row| {
                let s = (row[c] * n as f64).floor() as usize;
                s < n && !std::mem::replace(&mut seen[s], true)
            })
        })
    }

    #[test]
    fn fills_every_stratum_once_and_is_seeded() {
        let a = latin_hypercube(37, 4, 11);
        assert!(is_latin(&a));
        assert_eq!(a, latin_hypercube(37, 4, 11));
        assert_ne!(a, latin_hypercube(37, 4, 12));
    }

    #[test]
    fn maximin_keeps_the_latin_property_and_spreads_the_points() {
        let (n, d) = (40, 3);
        let plain = latin_hypercube(n, d, 5);
        let better = maximin_latin_hypercube(n, d, 5, 4000);
        assert!(is_latin(&better));
        assert!(phi_p(&better, 15.0) < phi_p(&plain, 15.0));
        assert!(min_distance(&better) > min_distance(&plain));
        assert_eq!(better, maximin_latin_hypercube(n, d, 5, 4000));
    }

    #[test]
    fn log_spacing_maps_to_decades() {
        assert!((to_range(0.5, 1e6, 1e8, Spacing::Log).unwrap() - 1e7).abs() < 1e-6);
        assert_eq!(to_range(0.25, 0.0, 4.0, Spacing::Linear).unwrap(), 1.0);
        assert!(to_range(0.5, 0.0, 1.0, Spacing::Log).is_err());
    }
}
