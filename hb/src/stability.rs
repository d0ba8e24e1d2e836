//! Stability of periodic solutions by Hill's method (thesis §3.2).
//!
//! A perturbation `Δη(t) = e^{st} Σ_{k=−H..H} p_k e^{ikω0t}` of the modal coordinates obeys,
//! harmonic by harmonic,
//!
//! `(s + ikω0)² p_k + (s + ikω0) C̃ p_k + Ω² p_k + Σ_l [T_{k−l} + (s + ilω0) Γ_{k−l}] p_l = 0`
//!
//! with `T_j`, `Γ_j` the Fourier coefficients of the projected element tangents
//! `Φᵀ ∂g/∂u Φ`, `Φᵀ ∂g/∂u̇ Φ`. The quadratic eigenproblem in `s` is linearised to a
//! companion matrix of size `2 m (2H+1)`, assembled in the real Fourier basis of the same
//! space (Galerkin products of the sampled tangents; real arithmetic, eigenvalues only: 3× less
//! time than the complex basis with eigenvectors on the ECL beam, which a test keeps as the
//! oracle), split into even and odd harmonics when the tangents have half-wave symmetry, and
//! solved by this crate's Francis QR; of its eigenvalues only `2m` are Floquet exponents,
//! the rest being copies shifted by `ikω0` (exact copies for the untruncated problem). The
//! exponents are picked as the `2m` eigenvalues of smallest imaginary part, the
//! representatives in the band `|Im s| ≤ ω0/2`: the copies near the truncation edge are the
//! least accurate, and a weight-in-the-central-harmonic criterion fails near resonance, where
//! a perturbation at `ω_r ≈ ω0` lives in the harmonics `±1`. The solution is stable when
//! every exponent has a negative real part.
//!
//! Modes that no element moves (zero participation at every element port, proportional
//! damping) keep their linear poles and are left out. Modes above `(H+1) ω0` (and beyond
//! [`crate::HbConfig::hill_max_modes`]) respond
//! quasi-statically at every harmonic kept: they join the residual flexibility `D` of the
//! ports, so that the element tangent seen by the dynamic modes is
//! `K_eff(t) = (I + K_t(t) D_eff)⁻¹ K_t(t)`.

use crate::system::HbSystem;
use faer::linalg::solvers::Solve;
use faer::{Mat, c64};
use nlsim_kernel::{Error, Result};
use std::f64::consts::PI;

/// Floquet exponents of a periodic solution.
#[derive(Debug, Clone, PartialEq)]
pub struct Stability {
    /// The `2m` Floquet exponents `s` (1/s) of the `m` dynamic modes.
    pub exponents: Vec<c64>,
    /// Largest real part (1/s).
    pub max_real: f64,
    /// True when `max_real` is below `1e-6 ω0`.
    pub stable: bool,
    /// Modes kept dynamic (indices of the retained modes).
    pub modes: Vec<usize>,
}

impl HbSystem {
    /// Hill's method at solution `x` at fundamental `omega` (rad/s).
    pub fn stability(&self, x: &[f64], omega: f64) -> Result<Stability> {
        self.stability_with(x, omega, Self::hill_real)
    }

    /// [`HbSystem::stability`] with the Hill eigenvalues `σ = s/ω0` from `hill`.
    fn stability_with(&self, x: &[f64], omega: f64, hill: HillEigenvalues) -> Result<Stability> {
        let set = self.set;
        let w0 = set.base(omega);
        let lin = &self.linear;
        let nm = lin.n_modes();
        let cutoff = ((set.h + 1) as f64 * w0).powi(2);
        // Element coordinates (a coupled law has several).
        let ne = self.n_coordinates();
        // Modes that no element moves keep their linear (stable) poles: with proportional
        // damping they decouple and are left out.
        let reach: Vec<f64> = (0..nm)
            .map(|r| {
                self.element_ports
                    .iter()
                    .fold(0.0f64, |a, &p| a.max(lin.phi[(p, r)].abs()))
            })
            .collect();
        let top = reach.iter().fold(0.0f64, |a, v| a.max(*v));
        let coupled: Vec<usize> = (0..nm)
            .filter(|&r| !lin.diagonal || reach[r] > 1e-9 * top)
            .collect();
        let mut dynamic: Vec<usize> = coupled
            .iter()
            .copied()
            .filter(|&r| lin.w2[r] <= cutoff)
            .take(self.config.hill_max_modes.max(1))
            .collect();
        if dynamic.is_empty() {
            dynamic.push(coupled.first().copied().unwrap_or(0));
        }
        let m = dynamic.len();
        // Quasi-static flexibility at the element ports: D + Σ_{r not dynamic} φ_r φ_rᵀ / ω_r².
        let d = Mat::from_fn(ne, ne, |a, b| {
            let (pa, pb) = (self.element_ports[a], self.element_ports[b]);
            lin.residual[(pa, pb)]
                + (0..nm)
                    .filter(|r| !dynamic.contains(r))
                    .map(|r| lin.phi[(pa, r)] * lin.phi[(pb, r)] / lin.w2[r])
                    .sum::<f64>()
        });
        let quasi_static = d.norm_max() > 0.0;
        // Element tangents on one common grid.
        let plan = self.hill_plan();
        let n = plan.n;
        // K_t(t) (coordinates × coordinates × samples): diagonal but for the blocks of
        // coupled laws; ∂g/∂u̇ per coordinate.
        let mut kt = vec![vec![vec![0.0; n]; ne]; ne];
        let mut ct = vec![vec![0.0; n]; ne];
        for (e, el) in self.elements.iter().enumerate() {
            let c = self.coordinates(e);
            let r = plan.evaluate_element(el.law(), &x[self.unknowns(e)], w0, false);
            let m = c.len();
            if m == 1 {
                kt[c.start][c.start] = r.stiffness;
                ct[c.start] = r.damping;
            } else {
                for a in 0..m {
                    for b in 0..m {
                        kt[c.start + a][c.start + b]
                            .copy_from_slice(&r.stiffness[(a * m + b) * n..(a * m + b + 1) * n]);
                    }
                }
            }
        }
        // K_eff(t) per sample (coordinates × coordinates), then its harmonics 0..2H.
        let keff = if quasi_static {
            let mut keff = vec![vec![vec![0.0; n]; ne]; ne];
            for i in 0..n {
                let a = Mat::from_fn(ne, ne, |r, c| {
                    f64::from(u8::from(r == c))
                        + (0..ne).map(|l| kt[r][l][i] * d[(l, c)]).sum::<f64>()
                });
                let k = Mat::from_fn(ne, ne, |r, c| kt[r][c][i]);
                let sol = a.partial_piv_lu().solve(&k);
                for r in 0..ne {
                    for c in 0..ne {
                        keff[r][c][i] = sol[(r, c)];
                    }
                }
            }
            keff
        } else {
            kt
        };
        let phi = |e: usize, r: usize| lin.phi[(self.element_ports[e], dynamic[r])];
        let tangents = HillTangents {
            keff: &keff,
            ct: &ct,
            phi: &phi,
            m,
            ne,
            w0,
        };
        let s = hill(self, &tangents, &dynamic).map_err(|e| Error::Numerical {
            what: format!("Hill eigenproblem at {:.6} Hz", omega / (2.0 * PI)),
            detail: e,
        })?;
        let mut all: Vec<c64> = s.iter().map(|v| v * w0).collect();
        all.sort_by(|a, b| a.im.abs().total_cmp(&b.im.abs()));
        let exponents = representatives(&all, m, w0);
        let max_real = exponents.iter().fold(f64::NEG_INFINITY, |a, s| a.max(s.re));
        Ok(Stability {
            stable: max_real < 1e-6 * w0,
            max_real,
            exponents,
            modes: dynamic,
        })
    }
}

/// Half the width of the band edge `|Im s| = ω0/2` in units of `ω0`: exponents this close to
/// it are taken to sit on it (a real negative multiplier, whose Hill eigenvalues the
/// truncation moves off the edge by about the truncation error).
pub(crate) const EDGE: f64 = 1e-3;

/// The `2m` Floquet exponents among Hill's eigenvalues `all` (sorted by `|Im|`): one
/// representative per multiplier. Inside the band `|Im s| < ω0/2` these are the central
/// copies. On its edge a real negative multiplier `−e^{σT}` shows as the pair `σ ± iω0/2`
/// (each the other's copy shifted by `ω0`): only the member with `Im > 0` is kept. Picking
/// the `2m` smallest `|Im|` instead would, once two multipliers sit on the negative real axis
/// (between two period doublings), fill the last slots with both members of one pair and
/// drop the other multiplier, and stability would flicker with rounding. Falls back to the
/// `2m` smallest `|Im|` when the count does not come out.
fn representatives(all: &[c64], m: usize, w0: f64) -> Vec<c64> {
    let half = 0.5 * w0;
    let picked: Vec<c64> = all
        .iter()
        .copied()
        .filter(|s| {
            let d = s.im.abs() - half;
            if d.abs() <= EDGE * w0 {
                s.im > 0.0
            } else {
                d < 0.0
            }
        })
        .take(2 * m)
        .collect();
    if picked.len() == 2 * m {
        picked
    } else {
        all.iter().copied().take(2 * m).collect()
    }
}

/// Relative size (to the largest entry) below which the couplings between the even and the
/// odd harmonics of Hill's matrix are rounding: the tangents of a solution with half-wave
/// symmetry carry odd harmonics of about `1e-16` of their mean.
const PARITY_COUPLING: f64 = 1e-12;

/// Eigenvalues of Hill's companion matrix `a` in the real Fourier basis (`nb = 2H + 1`
/// coefficients per mode and half). When the tangents have period `T/2` (an odd law under
/// odd forcing: the Duffing oscillator, a cubic spring, a symmetric clearance), harmonic `k`
/// couples only to harmonics of its parity: `a` is then, after a permutation, block
/// diagonal, and the even and odd blocks (about half the size each) are solved apart: a
/// quarter of the QR work. The couplings dropped are checked to be below
/// [`PARITY_COUPLING`] of the largest entry; otherwise the whole matrix is solved.
fn companion_eigenvalues(a: &Mat<f64>, nb: usize) -> std::result::Result<Vec<c64>, String> {
    let n = a.nrows();
    let parity = |i: usize| (i % nb).div_ceil(2) % 2;
    let mut top = 0.0f64;
    let mut cross = 0.0f64;
    for c in 0..n {
        for r in 0..n {
            let v = a[(r, c)].abs();
            top = top.max(v);
            if parity(r) != parity(c) {
                cross = cross.max(v);
            }
        }
    }
    let mut work = Vec::new();
    let mut out = Vec::with_capacity(n);
    // This crate's Francis QR; faer's driver if it does not converge.
    let mut solve = |m: &Mat<f64>, out: &mut Vec<c64>| {
        let start = out.len();
        if crate::eigs::eigenvalues_into(m, &mut work, out).is_err() {
            out.truncate(start);
            out.extend(m.eigenvalues().map_err(|e| format!("{e:?}"))?);
        }
        Ok::<(), String>(())
    };
    if cross > PARITY_COUPLING * top || nb < 3 {
        solve(a, &mut out)?;
        return Ok(out);
    }
    for p in 0..2 {
        let idx: Vec<usize> = (0..n).filter(|&i| parity(i) == p).collect();
        let block = Mat::from_fn(idx.len(), idx.len(), |r, c| a[(idx[r], idx[c])]);
        solve(&block, &mut out)?;
    }
    Ok(out)
}

/// A Hill eigenvalue solver: [`HbSystem::hill_real`] (or, in tests, the complex-basis
/// oracle).
type HillEigenvalues =
    fn(&HbSystem, &HillTangents<'_>, &[usize]) -> std::result::Result<Vec<c64>, String>;

/// The element tangents of one solution, sampled on the Hill plan's grid.
struct HillTangents<'a> {
    /// `K_eff(t)` (elements × elements × samples).
    keff: &'a [Vec<Vec<f64>>],
    /// `∂g/∂u̇` (elements × samples).
    ct: &'a [Vec<f64>],
    /// Participation of dynamic mode `r` at element `e`.
    phi: &'a dyn Fn(usize, usize) -> f64,
    m: usize,
    ne: usize,
    w0: f64,
}

impl HbSystem {
    /// Eigenvalues `σ = s/ω0` of the Hill problem assembled in the real Fourier basis
    /// `(c_0, c_1, s_1, …, c_H, s_H)` of each dynamic mode: `σ² b + σ M1 b + M0 b = 0` with
    /// `M1 = 2∇ + C̃/ω0 + Γ/ω0`, `M0 = ∇² + (C̃/ω0)∇ + Ω²/ω0² + T/ω0² + (Γ/ω0)∇`, `∇` the
    /// derivative in `θ = ω0 t` and `T`, `Γ` the Galerkin projections `P diag(f) E` of the
    /// projected tangents. The same truncated problem as the complex-exponential basis (a
    /// change of basis of the same space), in real arithmetic: its companion matrix has half
    /// the storage and a quarter of the QR work.
    fn hill_real(
        &self,
        t: &HillTangents<'_>,
        dynamic: &[usize],
    ) -> std::result::Result<Vec<c64>, String> {
        let set = self.set;
        let lin = &self.linear;
        let plan = self.hill_plan();
        let nb = set.len();
        let (m, ne, w0) = (t.m, t.ne, t.w0);
        let size = m * nb;
        // Galerkin matrices of every tangent series that appears.
        let gk: Vec<Vec<Mat<f64>>> = (0..ne)
            .map(|a| (0..ne).map(|b| plan.galerkin(&t.keff[a][b])).collect())
            .collect();
        let gc: Vec<Mat<f64>> = (0..ne).map(|a| plan.galerkin(&t.ct[a])).collect();
        // ∇: c_k' = k s_k, s_k' = −k c_k.
        let nabla = |j: usize, l: usize| -> f64 {
            if j == 0 || l == 0 {
                return 0.0;
            }
            let (kj, kl) = (j.div_ceil(2), l.div_ceil(2));
            if kj != kl {
                0.0
            } else if j % 2 == 1 && l == j + 1 {
                kj as f64
            } else if j.is_multiple_of(2) && l + 1 == j {
                -(kj as f64)
            } else {
                0.0
            }
        };
        let mut a = Mat::<f64>::zeros(2 * size, 2 * size);
        let w02 = w0 * w0;
        let mut tm = Mat::<f64>::zeros(nb, nb);
        let mut gm = Mat::<f64>::zeros(nb, nb);
        for r in 0..m {
            for q in 0..m {
                tm.fill(0.0);
                gm.fill(0.0);
                for e in 0..ne {
                    let pe = (t.phi)(e, r);
                    for b in 0..ne {
                        let w = pe * (t.phi)(b, q) / w02;
                        if w != 0.0 {
                            tm += &gk[e][b] * faer::Scale(w);
                        }
                    }
                    let w = pe * (t.phi)(e, q) / w0;
                    if w != 0.0 {
                        gm += &gc[e] * faer::Scale(w);
                    }
                }
                let c = lin.damping[(dynamic[r], dynamic[q])] / w0;
                for j in 0..nb {
                    for l in 0..nb {
                        // (Γ∇)_jl = Γ_j,i ∇_il for the one row i of column l that ∇ fills:
                        // s_k (i = l + 1, −k) under a c_k column, c_k (i = l − 1, +k) under
                        // an s_k one.
                        let gn = match l {
                            0 => 0.0,
                            _ if l % 2 == 1 => -gm[(j, l + 1)] * l.div_ceil(2) as f64,
                            _ => gm[(j, l - 1)] * (l / 2) as f64,
                        };
                        let mut v0 = tm[(j, l)] + gn + c * nabla(j, l);
                        let mut v1 = gm[(j, l)];
                        if j == l {
                            v1 += c;
                        }
                        if r == q {
                            let k = j.div_ceil(2) as f64;
                            if j == l {
                                v0 += lin.w2[dynamic[r]] / w02 - k * k;
                            }
                            v1 += 2.0 * nabla(j, l);
                        }
                        let (row, col) = (r * nb + j, q * nb + l);
                        a[(size + row, col)] = -v0;
                        a[(size + row, size + col)] = -v1;
                    }
                }
            }
        }
        for i in 0..size {
            a[(i, size + i)] = 1.0;
        }
        companion_eigenvalues(&a, nb)
    }

    #[cfg(test)]
    /// The Hill problem in the complex-exponential basis `e^{ikω0t}`, `k = −H..H` (the
    /// formulation of the module documentation): the oracle of [`HbSystem::hill_real`].
    fn hill_complex(
        &self,
        t: &HillTangents<'_>,
        dynamic: &[usize],
    ) -> std::result::Result<Vec<c64>, String> {
        let set = self.set;
        let lin = &self.linear;
        let plan = self.hill_plan();
        let (m, ne, w0) = (t.m, t.ne, t.w0);
        let jmax = 2 * set.h;
        let kh: Vec<Vec<Vec<c64>>> = t
            .keff
            .iter()
            .map(|row| row.iter().map(|s| plan.exponential(s, jmax)).collect())
            .collect();
        let ch: Vec<Vec<c64>> = t.ct.iter().map(|s| plan.exponential(s, jmax)).collect();
        let phi = t.phi;
        // T_j, Γ_j (m × m) for j = −2H..2H (index j + 2H); negative j by conjugation.
        let coef = |j: isize, r: usize, s: usize, stiff: bool| -> c64 {
            let (ja, conj) = (j.unsigned_abs(), j < 0);
            let mut acc = c64::new(0.0, 0.0);
            for a in 0..ne {
                if stiff {
                    for b in 0..ne {
                        acc += kh[a][b][ja] * (phi(a, r) * phi(b, s));
                    }
                } else {
                    acc += ch[a][ja] * (phi(a, r) * phi(a, s));
                }
            }
            if conj { acc.conj() } else { acc }
        };
        // Dimensionless σ = s/ω0: σ² p + σ M1 p + M0 p = 0.
        let hh = set.h as isize;
        let nb = 2 * set.h + 1;
        let size = m * nb;
        let mut m0 = Mat::<c64>::zeros(size, size);
        let mut m1 = Mat::<c64>::zeros(size, size);
        let w02 = w0 * w0;
        for bk in 0..nb {
            let k = bk as isize - hh;
            let ik = c64::new(0.0, k as f64);
            for bl in 0..nb {
                let l = bl as isize - hh;
                let il = c64::new(0.0, l as f64);
                for r in 0..m {
                    for s in 0..m {
                        let (row, col) = (bk * m + r, bl * m + s);
                        let t = coef(k - l, r, s, true);
                        let g = coef(k - l, r, s, false);
                        let mut v0 = t * (1.0 / w02) + il * g * (1.0 / w0);
                        let mut v1 = g * (1.0 / w0);
                        if k == l {
                            let c = lin.damping[(dynamic[r], dynamic[s])];
                            v0 += ik * c * (1.0 / w0);
                            v1 += c64::new(c / w0, 0.0);
                            if r == s {
                                v0 += c64::new(lin.w2[dynamic[r]] / w02, 0.0) + ik * ik;
                                v1 += ik * 2.0;
                            }
                        }
                        m0[(row, col)] = v0;
                        m1[(row, col)] = v1;
                    }
                }
            }
        }
        let mut a = Mat::<c64>::zeros(2 * size, 2 * size);
        for i in 0..size {
            a[(i, size + i)] = c64::new(1.0, 0.0);
            for j in 0..size {
                a[(size + i, j)] = -m0[(i, j)];
                a[(size + i, size + j)] = -m1[(i, j)];
            }
        }
        a.eigenvalues().map_err(|e| format!("{e:?}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{ContinuationConfig, HarmonicSet, HbConfig, continuation};
    use nlsim_reduction::modal::{ReductionConfig, reduce};

    fn system(name: &str, modes: usize, h: usize) -> HbSystem {
        let model = nlsim_fixtures::build(name, &[]).unwrap().model;
        let red = reduce(&model, &ReductionConfig::lowest(modes)).unwrap();
        HbSystem::from_model(
            &model,
            &red,
            HarmonicSet::new(h, 1).unwrap(),
            HbConfig::default(),
        )
        .unwrap()
    }

    /// The real-basis Hill matrix against the complex-exponential one (a different basis of
    /// the same truncated problem, assembled from the Fourier coefficients of the tangents
    /// instead of Galerkin products): the same exponents to rounding along whole branches
    /// of the Duffing (H = 7, one mode) and of the bump-stop beam (several dynamic modes,
    /// quasi-static flexibility, a non-smooth law).
    #[test]
    fn real_and_complex_hill_matrices_give_the_same_exponents() {
        for (name, modes, h, from, to) in [
            ("duffing_fig3", 1, 7, 25.0, 35.0),
            ("bumpstop_cantilever", 6, 5, 20.0, 28.0),
        ] {
            let sys = system(name, modes, h);
            let mut cfg = ContinuationConfig::frequency(from, to);
            cfg.stability = false;
            let branch = continuation(&sys, &cfg, None)
                .unwrap()
                .into_branch()
                .unwrap();
            assert!(branch.points.len() > 20, "{name}");
            let mut worst = 0.0f64;
            let mut unstable = 0;
            for p in branch.points.iter().step_by(3) {
                let real = sys.stability(&p.x, p.omega).unwrap();
                let complex = sys
                    .stability_with(&p.x, p.omega, HbSystem::hill_complex)
                    .unwrap();
                assert_eq!(real.stable, complex.stable, "{name} at {}", p.omega);
                unstable += usize::from(!real.stable);
                // Each exponent against its nearest counterpart (the order of a pair with
                // rounding-level imaginary parts is arbitrary).
                let w0 = sys.harmonics().base(p.omega);
                let d = crate::dense::test_util::matched_distance(
                    &real.exponents,
                    &complex.exponents,
                    w0,
                );
                worst = worst.max(d);
            }
            eprintln!(
                "{name}: real vs complex Hill exponents within {worst:.1e} ω0, {unstable} unstable"
            );
            assert!(worst < 1e-9, "{name}: {worst:e}");
            if name == "duffing_fig3" {
                assert!(unstable > 0, "the middle branch is unstable");
            }
        }
    }
}
