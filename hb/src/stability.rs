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
//! oracle). When the tangents have half-wave symmetry the matrix splits into even and odd
//! harmonics, and only the odd block is solved: it holds every exponent (see
//! `companion_eigenvalues`). The eigenvalues come from this crate's Francis QR; of them
//! only `2m` are Floquet exponents, the rest being copies shifted by `ikω0` (exact copies for
//! the untruncated problem). The exponents are picked as the `2m` eigenvalues of smallest
//! imaginary part, the representatives in the band `|Im s| ≤ ω0/2` (`≤ ω0` in the odd block,
//! whose copies are `2ω0` apart, then moved into the band): the copies near the truncation
//! edge are the least accurate, and a weight-in-the-central-harmonic criterion fails near
//! resonance, where a perturbation at `ω_r ≈ ω0` lives in the harmonics `±1`. The solution is
//! stable when every exponent has a negative real part.
//!
//! Modes that no element moves (zero participation at every element port, proportional
//! damping) keep their linear poles and are left out; so do the combinations of modes of
//! equal frequency (the two bending planes of a symmetric section) that no element moves.
//! Modes above `(H + ½) ω0`, at their linear frequency or at their frequency with the mean
//! element tangent (and beyond [`crate::HbConfig::hill_max_modes`]), have no copy in the
//! band: they respond quasi-statically at every harmonic kept and join the residual
//! flexibility `D` of the ports, so that the element tangent seen by the dynamic modes is
//! `K_eff(t) = (I + K_t(t) D_eff)⁻¹ K_t(t)`. Keeping them instead left the band short of
//! exponents, and the fallback pick took a copy twice or a mixture of copies at the
//! truncation edge: on the bump-stop beam at H = 5 and 24.72 Hz, a real part of +0.029 ω0
//! next to the two modes the stop moves at −0.010 and −0.011 ω0.

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
    /// Modes kept dynamic (indices of the retained modes; a combination of modes of equal
    /// frequency is labelled by one index of the group).
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
        // A mode above (H + ½) ω0 has no copy in the band |Im s| ≤ ω0/2 (its central copy
        // would need the harmonic H + 1): it is taken as quasi-static.
        let cutoff = ((set.h as f64 + 0.5) * w0).powi(2);
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
        // Element tangents on one common grid.
        let plan = self.hill_plan();
        let n = plan.n;
        // K_t(t) (coordinates × coordinates × samples): diagonal but for the blocks of
        // coupled laws; ∂g/∂u̇ per coordinate.
        let mut kt = vec![vec![vec![0.0; n]; ne]; ne];
        let mut ct = vec![vec![0.0; n]; ne];
        // Laws made of sliders: their tangent is not local in time (see `memory`).
        let mut memory: Vec<Option<Mat<f64>>> = vec![None; ne];
        for (e, el) in self.elements.iter().enumerate() {
            let c = self.coordinates(e);
            let xe = &x[self.unknowns(e)];
            let m = c.len();
            if m == 1 && el.law().n_sliders() > 0 {
                memory[c.start] = plan.evaluate(el.law(), xe, w0, true).jacobian;
            }
            if m == 1 && el.law().is_nonsmooth() {
                (kt[c.start][c.start], ct[c.start]) = plan.cell_tangent(el.law(), xe, w0);
                continue;
            }
            let r = plan.evaluate_element(el.law(), xe, w0, false);
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
        let mut keff = self.effective_tangent(&kt, &dynamic);
        let mut hill_modes = self.coupled_combinations(&dynamic);
        // The elements stiffen (or soften) the modes: a mode whose frequency with the mean
        // tangent, `ω_r² + φ_rᵀ mean(K_eff) φ_r`, is above the cutoff has no central copy
        // either, and joins the quasi-static ones (with the modes of equal frequency).
        let mean: Vec<Vec<f64>> = keff
            .iter()
            .map(|row| {
                row.iter()
                    .map(|s| s.iter().sum::<f64>() / n as f64)
                    .collect()
            })
            .collect();
        let high: Vec<usize> = hill_modes
            .iter()
            .filter(|(r, p)| {
                let mut w2 = lin.w2[*r];
                for a in 0..ne {
                    for b in 0..ne {
                        w2 += p[a] * mean[a][b] * p[b];
                    }
                }
                w2 > cutoff
            })
            .map(|(r, _)| *r)
            .collect();
        if !high.is_empty() && high.len() < hill_modes.len() {
            let freq = |r: usize| lin.w2[r];
            dynamic.retain(|&r| !high.iter().any(|&q| same_mode_pair(freq(r), freq(q))));
            keff = self.effective_tangent(&kt, &dynamic);
            hill_modes = self.coupled_combinations(&dynamic);
        }
        let m = hill_modes.len();
        let index: Vec<usize> = hill_modes.iter().map(|(r, _)| *r).collect();
        let phi = |e: usize, r: usize| hill_modes[r].1[e];
        let harmonic = memory
            .iter()
            .any(Option::is_some)
            .then(|| self.effective_tangent_harmonic(&kt, &memory, &dynamic));
        let tangents = HillTangents {
            keff: &keff,
            harmonic: harmonic.as_deref(),
            ct: &ct,
            phi: &phi,
            m,
            ne,
            w0,
        };
        let s = hill(self, &tangents, &index).map_err(|e| Error::Numerical {
            what: format!("Hill eigenproblem at {:.6} Hz", omega / (2.0 * PI)),
            detail: e,
        })?;
        let mut all: Vec<c64> = s.values.iter().map(|v| v * w0).collect();
        all.sort_by(|a, b| a.im.abs().total_cmp(&b.im.abs()));
        let exponents = if s.odd_block {
            // Copies 2ω0 apart: one per exponent in |Im s| ≤ ω0, moved by ω0 into the band.
            representatives(&all, m, w0, w0)
                .into_iter()
                .map(|mut s| {
                    s.im -= (s.im / w0).round() * w0;
                    if (s.im + 0.5 * w0).abs() <= EDGE * w0 {
                        s.im += w0;
                    }
                    s
                })
                .collect()
        } else {
            representatives(&all, m, w0, 0.5 * w0)
        };
        let max_real = exponents.iter().fold(f64::NEG_INFINITY, |a, s| a.max(s.re));
        Ok(Stability {
            stable: max_real < 1e-6 * w0,
            max_real,
            exponents,
            modes: index,
        })
    }

    /// The modes Hill's method keeps, as `(index, participation at each element coordinate)`.
    ///
    /// Modes of equal frequency and damping (the two bending planes of a symmetric section)
    /// are combined: any orthonormal combination of them is a mode, and the combinations
    /// that no element moves keep their linear poles. Per group of such modes, the
    /// combinations along an orthonormal basis of the span of the rows of their
    /// participations (at most one per element coordinate) are kept, each labelled by one
    /// index of the group; the rest are left out. The ECL beam's tip spring then sees one
    /// mode per bending pair instead of two. Without proportional damping every mode stands
    /// alone.
    fn coupled_combinations(&self, dynamic: &[usize]) -> Vec<(usize, Vec<f64>)> {
        let lin = &self.linear;
        let ne = self.n_coordinates();
        let part = |r: usize| -> Vec<f64> {
            (0..ne)
                .map(|e| lin.phi[(self.element_ports[e], r)])
                .collect()
        };
        let mut out: Vec<(usize, Vec<f64>)> = Vec::with_capacity(dynamic.len());
        let mut i = 0;
        while i < dynamic.len() {
            let r0 = dynamic[i];
            let mut j = i + 1;
            while lin.diagonal
                && j < dynamic.len()
                && same_mode_pair(lin.w2[r0], lin.w2[dynamic[j]])
                && same_mode_pair(lin.damping[(r0, r0)], lin.damping[(dynamic[j], dynamic[j])])
            {
                j += 1;
            }
            let group = &dynamic[i..j];
            if group.len() == 1 {
                out.push((r0, part(r0)));
            } else {
                // Rows of the participations (one per coordinate, over the group), made
                // orthonormal by Gram–Schmidt; each basis vector u gives a combination with
                // participation P u.
                let rows: Vec<Vec<f64>> = (0..ne)
                    .map(|e| {
                        group
                            .iter()
                            .map(|&r| lin.phi[(self.element_ports[e], r)])
                            .collect()
                    })
                    .collect();
                let scale = rows.iter().flatten().fold(0.0f64, |a, v| a.max(v.abs()));
                let mut basis: Vec<Vec<f64>> = Vec::new();
                for row in &rows {
                    let mut u = row.clone();
                    for _ in 0..2 {
                        for b in &basis {
                            let d: f64 = u.iter().zip(b).map(|(x, y)| x * y).sum();
                            u.iter_mut().zip(b).for_each(|(x, y)| *x -= d * y);
                        }
                    }
                    let norm = u.iter().map(|x| x * x).sum::<f64>().sqrt();
                    if norm > 1e-9 * scale && basis.len() < group.len() {
                        u.iter_mut().for_each(|x| *x /= norm);
                        basis.push(u);
                    }
                }
                for (b, u) in basis.iter().enumerate() {
                    let p = rows
                        .iter()
                        .map(|row| row.iter().zip(u).map(|(x, y)| x * y).sum())
                        .collect();
                    out.push((group[b], p));
                }
            }
            i = j;
        }
        if out.is_empty() {
            // No element moves any mode: keep the first one, uncoupled.
            if let Some(&r) = dynamic.first() {
                out.push((r, part(r)));
            }
        }
        out
    }

    /// [`HbSystem::effective_tangent`] in the harmonic domain, for solutions with a law made
    /// of sliders (Jenkins, Iwan): blocks `(a, b)` of `K_eff = (I + T (D_eff ⊗ I))⁻¹ T`, each
    /// `(2H+1)²`, with `T` the Galerkin matrices of the sampled tangents `kt` but for the
    /// coordinates of `memory`, whose block is the law's AFT Jacobian.
    ///
    /// A stuck slider pushes `k (u(t) − u(t_j))`, `t_j` its last slip: a perturbation moves
    /// its force through `u(t_j)` too, which the local tangent `k` (stick) or 0 (slip)
    /// misses. The Jacobian carries that memory for periodic perturbations (`s = 0`): it is
    /// exact where an exponent crosses zero (folds, branch points), and the approximation
    /// NLvib's Hill method makes with its harmonic-balance Jacobian. With the local tangent
    /// the resonance peak of a friction-damped oscillator came out unstable while time
    /// integration stayed on it (hb's `iwan_joint_harmonics_match_time_integration`).
    fn effective_tangent_harmonic(
        &self,
        kt: &[Vec<Vec<f64>>],
        memory: &[Option<Mat<f64>>],
        dynamic: &[usize],
    ) -> Vec<Vec<Mat<f64>>> {
        let plan = self.hill_plan();
        let ne = kt.len();
        let nb = self.set.len();
        let mut t = Mat::<f64>::zeros(ne * nb, ne * nb);
        for a in 0..ne {
            for b in 0..ne {
                let block = match &memory[a] {
                    Some(j) if a == b => j.clone(),
                    Some(_) => continue,
                    None if kt[a][b].iter().all(|&v| v == 0.0) => continue,
                    None => plan.galerkin(&kt[a][b]),
                };
                t.submatrix_mut(a * nb, b * nb, nb, nb).copy_from(&block);
            }
        }
        let d = self.quasi_static_flexibility(dynamic);
        let keff = if d.norm_max() == 0.0 {
            t
        } else {
            // I + T (D ⊗ I): column block b of T (D ⊗ I) is Σ_l T_{·l} d_lb.
            let mut a = Mat::<f64>::identity(ne * nb, ne * nb);
            for b in 0..ne {
                for l in 0..ne {
                    let w = d[(l, b)];
                    if w != 0.0 {
                        let tl = t.submatrix(0, l * nb, ne * nb, nb).to_owned();
                        let mut ab = a.submatrix_mut(0, b * nb, ne * nb, nb);
                        ab += &tl * faer::Scale(w);
                    }
                }
            }
            a.partial_piv_lu().solve(&t)
        };
        (0..ne)
            .map(|a| {
                (0..ne)
                    .map(|b| keff.submatrix(a * nb, b * nb, nb, nb).to_owned())
                    .collect()
            })
            .collect()
    }

    /// `D_eff = D + Σ_{r not dynamic} φ_r φ_rᵀ / ω_r²` at the element ports (m/N).
    fn quasi_static_flexibility(&self, dynamic: &[usize]) -> Mat<f64> {
        let lin = &self.linear;
        let ne = self.n_coordinates();
        Mat::from_fn(ne, ne, |a, b| {
            let (pa, pb) = (self.element_ports[a], self.element_ports[b]);
            lin.residual[(pa, pb)]
                + (0..lin.n_modes())
                    .filter(|r| !dynamic.contains(r))
                    .map(|r| lin.phi[(pa, r)] * lin.phi[(pb, r)] / lin.w2[r])
                    .sum::<f64>()
        })
    }

    /// The element tangent seen by the `dynamic` modes, per sample:
    /// `K_eff(t) = (I + K_t(t) D_eff)⁻¹ K_t(t)` with `D_eff = D + Σ_{r not dynamic} φ_r φ_rᵀ /
    /// ω_r²` the quasi-static flexibility at the element ports (N/m; `kt` itself when that
    /// flexibility is zero).
    fn effective_tangent(&self, kt: &[Vec<Vec<f64>>], dynamic: &[usize]) -> Vec<Vec<Vec<f64>>> {
        let ne = kt.len();
        let n = kt.first().and_then(|r| r.first()).map_or(0, Vec::len);
        let d = self.quasi_static_flexibility(dynamic);
        if d.norm_max() == 0.0 {
            return kt.to_vec();
        }
        let mut keff = vec![vec![vec![0.0; n]; ne]; ne];
        for i in 0..n {
            let a = Mat::from_fn(ne, ne, |r, c| {
                f64::from(u8::from(r == c)) + (0..ne).map(|l| kt[r][l][i] * d[(l, c)]).sum::<f64>()
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
    }
}

/// True when two modal quantities (`ω²`, or modal damping) are equal to the relative
/// `1e-9`: the modes of a symmetric section, equal up to the eigensolver's rounding.
fn same_mode_pair(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * a.abs().max(b.abs())
}

/// Half the width of the band edge `|Im s| = ω0/2` in units of `ω0`: exponents this close to
/// it are taken to sit on it (a real negative multiplier, whose Hill eigenvalues the
/// truncation moves off the edge by about the truncation error).
pub(crate) const EDGE: f64 = 1e-3;

/// The `2m` Floquet exponents among Hill's eigenvalues `all` (sorted by `|Im|`): one
/// representative per multiplier, in the band `|Im s| ≤ half` (`ω0/2` for the whole Hill
/// matrix, whose copies are `ω0` apart; `ω0` for one parity block, whose copies are `2ω0`
/// apart). Inside the band these are the central copies. On its edge a real multiplier
/// of the band's period shows as the pair `σ ± i·half` (each the other's copy): only the
/// member with `Im > 0` is kept. Picking the `2m` smallest `|Im|` instead would, once two
/// multipliers sit on the edge (between two period doublings), fill the last slots with both
/// members of one pair and drop the other multiplier, and stability would flicker with
/// rounding. Falls back to the `2m` smallest `|Im|` when the count does not come out.
fn representatives(all: &[c64], m: usize, w0: f64, half: f64) -> Vec<c64> {
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

/// Eigenvalues of Hill's matrix: all of them, or those of one parity block.
pub(crate) struct HillSpectrum {
    /// Eigenvalues `σ = s/ω0`.
    pub values: Vec<c64>,
    /// True when `values` are those of the odd-harmonic block only (copies `2ω0` apart).
    pub odd_block: bool,
}

/// Eigenvalues of Hill's companion matrix `a` in the real Fourier basis (`nb = 2H + 1`
/// coefficients per mode and half).
///
/// When the tangents have period `T/2` (an odd law under odd forcing: the Duffing
/// oscillator, a cubic spring, a symmetric clearance), harmonic `k` couples only to
/// harmonics of its parity, and `a` is, after a permutation, block diagonal. Each block then
/// holds every Floquet exponent: a perturbation `e^{st} p(t)` with `p` in the odd harmonics
/// is `e^{(s+iω0)t} q(t)` with `q` of period `T/2`, so both blocks are Hill matrices of the
/// same `T/2`-periodic system, their eigenvalues the same exponents modulo `2iω0` (the odd
/// block's shifted by `iω0`), and the exponents of period `T` are these modulo `iω0`. Only
/// the odd block is solved (unless `whole`): it holds the exponent of a fold of the
/// primary branch (a perturbation in the harmonics `±1`) at the centre of its band, where
/// the even block has it on the band edge, truncated one harmonic short. A quarter of the
/// QR work of the whole matrix for the one block against a half for both.
///
/// The couplings dropped are checked to be below [`PARITY_COUPLING`] of the largest entry;
/// otherwise the whole matrix is solved.
fn companion_eigenvalues(
    a: &Mat<f64>,
    nb: usize,
    whole: bool,
) -> std::result::Result<HillSpectrum, String> {
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
    if cross > PARITY_COUPLING * top || nb < 3 || whole {
        solve(a, &mut out)?;
        return Ok(HillSpectrum {
            values: out,
            odd_block: false,
        });
    }
    let idx: Vec<usize> = (0..n).filter(|&i| parity(i) == 1).collect();
    let block = Mat::from_fn(idx.len(), idx.len(), |r, c| a[(idx[r], idx[c])]);
    solve(&block, &mut out)?;
    Ok(HillSpectrum {
        values: out,
        odd_block: true,
    })
}

/// A Hill eigenvalue solver: [`HbSystem::hill_real`] (or, in tests, the complex-basis
/// oracle).
type HillEigenvalues =
    fn(&HbSystem, &HillTangents<'_>, &[usize]) -> std::result::Result<HillSpectrum, String>;

/// The element tangents of one solution, sampled on the Hill plan's grid.
struct HillTangents<'a> {
    /// `K_eff(t)` (elements × elements × samples).
    keff: &'a [Vec<Vec<f64>>],
    /// `K_eff`'s Galerkin blocks (elements × elements) when a law made of sliders is present
    /// ([`HbSystem::effective_tangent_harmonic`]); they replace those of `keff`.
    harmonic: Option<&'a [Vec<Mat<f64>>]>,
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
    ) -> std::result::Result<HillSpectrum, String> {
        let (a, nb) = self.hill_real_matrix(t, dynamic);
        companion_eigenvalues(&a, nb, false)
    }

    /// [`HbSystem::hill_real`] on the whole matrix, split or not: the oracle of the
    /// one-block solve.
    #[cfg(test)]
    fn hill_real_whole(
        &self,
        t: &HillTangents<'_>,
        dynamic: &[usize],
    ) -> std::result::Result<HillSpectrum, String> {
        let (a, nb) = self.hill_real_matrix(t, dynamic);
        companion_eigenvalues(&a, nb, true)
    }

    /// Hill's companion matrix in the real Fourier basis and its coefficients per mode and
    /// half `2H + 1` (see [`HbSystem::hill_real`]).
    fn hill_real_matrix(&self, t: &HillTangents<'_>, dynamic: &[usize]) -> (Mat<f64>, usize) {
        let set = self.set;
        let lin = &self.linear;
        let plan = self.hill_plan();
        let nb = set.len();
        let (m, ne, w0) = (t.m, t.ne, t.w0);
        let size = m * nb;
        // Galerkin matrices of every tangent series that appears.
        let gk: Vec<Vec<Mat<f64>>> = match t.harmonic {
            Some(h) => h.to_vec(),
            None => (0..ne)
                .map(|a| (0..ne).map(|b| plan.galerkin(&t.keff[a][b])).collect())
                .collect(),
        };
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
        (a, nb)
    }

    #[cfg(test)]
    /// The Hill problem in the complex-exponential basis `e^{ikω0t}`, `k = −H..H` (the
    /// formulation of the module documentation): the oracle of [`HbSystem::hill_real`].
    fn hill_complex(
        &self,
        t: &HillTangents<'_>,
        dynamic: &[usize],
    ) -> std::result::Result<HillSpectrum, String> {
        self.hill_complex_in(t, dynamic, false)
    }

    #[cfg(test)]
    /// [`HbSystem::hill_complex`] on the odd harmonics `k = ±1, ±3, …` only: the oracle of
    /// the one-block solve.
    fn hill_complex_odd(
        &self,
        t: &HillTangents<'_>,
        dynamic: &[usize],
    ) -> std::result::Result<HillSpectrum, String> {
        self.hill_complex_in(t, dynamic, true)
    }

    #[cfg(test)]
    /// The complex-basis Hill problem on every harmonic, or on the odd ones (`odd`).
    fn hill_complex_in(
        &self,
        t: &HillTangents<'_>,
        dynamic: &[usize],
        odd: bool,
    ) -> std::result::Result<HillSpectrum, String> {
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
        let ks: Vec<isize> = (-hh..=hh).filter(|k| !odd || k % 2 != 0).collect();
        let nb = ks.len();
        let size = m * nb;
        let mut m0 = Mat::<c64>::zeros(size, size);
        let mut m1 = Mat::<c64>::zeros(size, size);
        let w02 = w0 * w0;
        for (bk, &k) in ks.iter().enumerate() {
            let ik = c64::new(0.0, k as f64);
            for (bl, &l) in ks.iter().enumerate() {
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
        Ok(HillSpectrum {
            values: a.eigenvalues().map_err(|e| format!("{e:?}"))?,
            odd_block: odd,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dense::test_util;
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
    /// instead of Galerkin products, solved by faer): the same exponents to rounding along
    /// whole branches of the Duffing (H = 7, one mode), the bump-stop beam (several dynamic
    /// modes, quasi-static flexibility, a one-sided law: no parity split) and the ECL beam
    /// (four dynamic modes, a split). Where the tangents split by parity, the production path
    /// solves the odd block only; its oracle is the complex problem on the odd harmonics.
    /// Independently of either, the exponents' real parts sum to the trace `−tr C̃` of the
    /// dynamic modes' damping (Liouville: no element here has a velocity tangent). That
    /// checks the pick of one copy per exponent: a copy counted twice or a mode left out
    /// moves the sum by a whole mode's damping (0.7–1.0 of the trace on the bump-stop beam
    /// when modes above `(H + ½) ω0` were kept), while the truncation moves the exponents of
    /// a mode whose central copy lies in the harmonic `H` by up to 2.2e-4 of the trace (ECL
    /// beam, H = 5; 6e-13 for the one-mode Duffing).
    #[test]
    fn real_and_complex_hill_matrices_give_the_same_exponents() {
        for (name, modes, h, from, to, split) in [
            ("duffing_fig3", 1, 7, 25.0, 35.0, true),
            ("bumpstop_cantilever", 6, 5, 20.0, 28.0, false),
            ("ecl_beam", 20, 5, 20.0, 40.0, true),
        ] {
            let sys = system(name, modes, h);
            let mut cfg = ContinuationConfig::frequency(from, to);
            cfg.stability = false;
            let branch = continuation(&sys, &cfg, None)
                .unwrap()
                .into_branch()
                .unwrap();
            assert!(branch.points.len() > 20, "{name}");
            let oracle: HillEigenvalues = if split {
                HbSystem::hill_complex_odd
            } else {
                HbSystem::hill_complex
            };
            let (mut whole, mut block, mut trace) = (0.0f64, 0.0f64, 0.0f64);
            let mut unstable = 0;
            for p in branch.points.iter().step_by(3) {
                let w0 = sys.harmonics().base(p.omega);
                let at = format!("{name} at {:.4} Hz", p.omega / (2.0 * PI));
                // Each exponent against its nearest counterpart (the order of a pair with
                // rounding-level imaginary parts is arbitrary).
                let real = sys
                    .stability_with(&p.x, p.omega, HbSystem::hill_real_whole)
                    .unwrap();
                let complex = sys
                    .stability_with(&p.x, p.omega, HbSystem::hill_complex)
                    .unwrap();
                assert_eq!(real.stable, complex.stable, "{at}");
                let d = test_util::matched_distance(&real.exponents, &complex.exponents, w0);
                whole = whole.max(d);
                let fast = sys.stability(&p.x, p.omega).unwrap();
                let reference = sys.stability_with(&p.x, p.omega, oracle).unwrap();
                assert_eq!(fast.stable, reference.stable, "{at}");
                assert_eq!(fast.stable, complex.stable, "{at}");
                let d = test_util::matched_distance(&fast.exponents, &reference.exponents, w0);
                block = block.max(d);
                unstable += usize::from(!fast.stable);
                let sum: f64 = fast.exponents.iter().map(|s| s.re).sum();
                let tr: f64 = fast.modes.iter().map(|&r| sys.linear.damping[(r, r)]).sum();
                trace = trace.max((sum + tr).abs() / tr);
            }
            eprintln!(
                "{name}: real vs complex Hill exponents within {whole:.1e} ω0, the solved \
                 block vs its complex oracle {block:.1e} ω0, trace {trace:.1e}, {unstable} \
                 unstable"
            );
            assert!(whole < 1e-9, "{name}: {whole:e}");
            assert!(block < 1e-9, "{name}: {block:e}");
            assert!(trace < 1e-3, "{name}: {trace:e}");
            if name == "duffing_fig3" {
                assert!(unstable > 0, "the middle branch is unstable");
            }
        }
    }
}
