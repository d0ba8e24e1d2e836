//! Alternating frequency–time (AFT) evaluation of element forces (thesis §3.2).
//!
//! Per element: the coefficients `x` of its coordinate are sent to `N` samples of one period
//! of the base frequency (`u = E x`, `u̇ = ω0 E' x`), the law is evaluated sample by sample,
//! and the force is projected back onto the kept harmonics (`G = P g`, exact for any
//! trigonometric polynomial of degree below `N/2`). The Jacobian is analytic:
//! `∂G/∂x = P (diag(∂g/∂u) E + ω0 diag(∂g/∂u̇) E')`. The transforms are direct products with
//! precomputed tables: with `2H + 1 ≤ 31` the tables fit in cache and beat an FFT.

use crate::harmonics::HarmonicSet;
use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatMut, MatRef, Par, c64};
use nlsim_kernel::iwan::slider_commit;
use nlsim_kernel::{Error, Law, Result};
use std::f64::consts::PI;

/// Samples per period for `law` with `set`: enough that a polynomial of degree `p` is
/// projected without aliasing (`N > (p + 1) H`) and that the tangent's harmonics up to `2H`
/// needed by Hill's method are exact; many more for the kinks of clearance, Jenkins and Iwan
/// and the steep `tanh` of regularised Coulomb friction, whose spectra decay slowly.
pub fn samples_for(law: &Law, set: &HarmonicSet) -> usize {
    let h = set.h;
    let poly = |p: usize| ((p + 1) * h + 1).max(4 * h + 2);
    let n = match law {
        Law::Cubic { .. } => poly(3),
        Law::Polynomial { stiffness, damping } => {
            let p = stiffness
                .iter()
                .chain(damping)
                .map(|t| t.power as usize)
                .max()
                .unwrap_or(1);
            poly(p)
        }
        Law::QuadraticDamping { .. } => 16 * (2 * h + 1),
        // |x|^p sign(x) is the polynomial x^p for odd integer p; otherwise its spectrum
        // decays as a power (like the quadratic damper's).
        Law::PowerSpring { p, .. } | Law::PowerDamper { p, .. } => {
            let odd = p.fract() == 0.0 && (*p as usize) % 2 == 1;
            if odd {
                poly(*p as usize)
            } else {
                (16 * (2 * h + 1)).max(poly(p.ceil() as usize))
            }
        }
        Law::Coulomb { .. } => 32 * (2 * h + 1),
        Law::Clearance { .. } | Law::Jenkins { .. } | Law::Iwan { .. } => 64 * (2 * h + 1),
        Law::CoupledPolynomial { terms, .. } => {
            poly(terms.iter().map(|t| t.degree() as usize).max().unwrap_or(1))
        }
    };
    n + n % 2
}

/// The transform tables for one sample count.
#[derive(Debug, Clone)]
pub struct AftPlan {
    /// The harmonic set.
    pub set: HarmonicSet,
    /// Samples per period `N`.
    pub n: usize,
    /// `E` (N × (2H+1)): coefficients to samples.
    e: Mat<f64>,
    /// `E'` (N × (2H+1)): coefficients to `d/dθ` of the samples (`θ = ω0 t`).
    ed: Mat<f64>,
    /// `P` (((2H+1) × N): samples to coefficients.
    p: Mat<f64>,
}

/// What an element evaluation returns.
#[derive(Debug, Clone)]
pub struct ElementHarmonics {
    /// Force coefficients `G` (N), layout of [`HarmonicSet`].
    pub force: Vec<f64>,
    /// `∂G/∂x` ((2H+1) × (2H+1); N/m), when asked for.
    pub jacobian: Option<Mat<f64>>,
    /// `∂g/∂u` at each sample (N/m); for a law on `m` coordinates `∂g_a/∂u_b` at sample `i`
    /// in entry `(a m + b) N + i`.
    pub stiffness: Vec<f64>,
    /// `∂g/∂u̇` at each sample (N s/m); empty for a law on several coordinates (they are
    /// velocity-independent).
    pub damping: Vec<f64>,
}

impl AftPlan {
    /// Tables for `n` samples per period. Errors unless `n > 4H` (aliasing of the forces and
    /// of the tangent harmonics that Hill's method uses).
    pub fn new(set: HarmonicSet, n: usize) -> Result<Self> {
        if n <= 4 * set.h {
            return Err(Error::invalid(
                "AFT samples per period",
                format!("{n} is too few for H = {}: need more than 4H", set.h),
            ));
        }
        let nh = set.len();
        let theta = |i: usize| 2.0 * PI * i as f64 / n as f64;
        let e = Mat::from_fn(n, nh, |i, j| match j {
            0 => 1.0,
            _ => {
                let k = j.div_ceil(2) as f64;
                if j % 2 == 1 {
                    (k * theta(i)).cos()
                } else {
                    (k * theta(i)).sin()
                }
            }
        });
        let ed = Mat::from_fn(n, nh, |i, j| match j {
            0 => 0.0,
            _ => {
                let k = j.div_ceil(2) as f64;
                if j % 2 == 1 {
                    -k * (k * theta(i)).sin()
                } else {
                    k * (k * theta(i)).cos()
                }
            }
        });
        let p = Mat::from_fn(nh, n, |j, i| {
            let w = if j == 0 { 1.0 } else { 2.0 } / n as f64;
            w * e[(i, j)]
        });
        Ok(Self { set, n, e, ed, p })
    }

    /// Samples of the coordinate (`u`, m) and its velocity (`u̇`, m/s) over one period.
    pub fn to_time(&self, x: &[f64], omega0: f64) -> (Vec<f64>, Vec<f64>) {
        let (mut u, mut v) = (Vec::new(), Vec::new());
        self.to_time_into(x, omega0, &mut u, &mut v);
        (u, v)
    }

    /// [`AftPlan::to_time`] into `u` and `v` (resized to `N`; no allocation once they hold
    /// `N` values).
    pub(crate) fn to_time_into(&self, x: &[f64], omega0: f64, u: &mut Vec<f64>, v: &mut Vec<f64>) {
        let nh = self.set.len();
        u.clear();
        u.resize(self.n, 0.0);
        v.clear();
        v.resize(self.n, 0.0);
        // Column by column: the tables are column-major.
        for (j, &xj) in x.iter().enumerate().take(nh) {
            let xv = omega0 * xj;
            for ((a, b), (e, ed)) in u
                .iter_mut()
                .zip(v.iter_mut())
                .zip(self.e.col_as_slice(j).iter().zip(self.ed.col_as_slice(j)))
            {
                *a += e * xj;
                *b += ed * xv;
            }
        }
    }

    /// Samples of `∂g/∂u` of a one-coordinate law for Hill's method, each averaged over its
    /// sample cell `[θ_i − δ/2, θ_i + δ/2]` (`δ = 2π/N`) where the tangent jumps.
    ///
    /// A clearance or a Jenkins slider switches its stiffness at instants that fall between
    /// samples; sampled at points, the tangent's harmonics are off by up to the jump times
    /// `δ/(2π)` and jump whenever an instant crosses a sample, so that the Floquet exponents
    /// of a contact branch scatter from point to point (up to ±3e-2 ω0 on NLvib's example 3).
    /// Where the coordinate moves monotonically across a cell, the force's divided difference
    /// between the cell's ends, `(g(θ_i + δ/2) − g(θ_i − δ/2)) / (u(θ_i + δ/2) − u(θ_i − δ/2))`,
    /// is the average of `∂g/∂u` over the displacement the cell sweeps, i.e. its time
    /// average up to the curvature of `u` within the cell: the harmonics are then off by
    /// `O(k δ²)` and move continuously with the solution. The half-sample values come from the
    /// coefficients shifted by `δ/2`, and the law runs along the interleaved grid (with its
    /// history, periodically started). Cells where the velocity changes sign (the coordinate
    /// turns) keep the point sample: a Jenkins slider sticks again exactly at a reversal, so
    /// its two reversal cells per period still switch with the sampling (its stick-to-slip
    /// switches in between are averaged). Returns these stiffness samples and the point
    /// samples of `∂g/∂u̇` (both laws' kinks are in `u`).
    pub(crate) fn cell_tangent(&self, law: &Law, x: &[f64], omega0: f64) -> (Vec<f64>, Vec<f64>) {
        let (n, h) = (self.n, self.set.h);
        let half = PI / n as f64;
        let mut shifted = x.to_vec();
        for k in 1..=h {
            let (s, c) = (k as f64 * half).sin_cos();
            let (a, b) = (x[2 * k - 1], x[2 * k]);
            shifted[2 * k - 1] = a * c + b * s;
            shifted[2 * k] = b * c - a * s;
        }
        let (u, v) = self.to_time(x, omega0);
        let (uh, vh) = self.to_time(&shifted, omega0);
        // Interleaved grid: 2i is sample i, 2i + 1 the end of its cell.
        let uu: Vec<f64> = (0..2 * n)
            .map(|j| if j % 2 == 0 { u[j / 2] } else { uh[j / 2] })
            .collect();
        let vv: Vec<f64> = (0..2 * n)
            .map(|j| if j % 2 == 0 { v[j / 2] } else { vh[j / 2] })
            .collect();
        let (mut state, mut start, mut last) = (Vec::new(), Vec::new(), Vec::new());
        periodic_start_into(law, &uu, &mut state, &mut start, &mut last);
        let mut g = vec![0.0; 2 * n];
        let (mut point, mut damping) = (vec![0.0; n], vec![0.0; n]);
        for j in 0..2 * n {
            let e = law.eval(uu[j], vv[j], &state);
            g[j] = e.force;
            if j % 2 == 0 {
                point[j / 2] = e.df_du;
                damping[j / 2] = e.df_dv;
            }
            law.commit_state(uu[j], vv[j], &mut state);
        }
        let scale = uu.iter().fold(0.0f64, |m, a| m.max(a.abs()));
        let stiffness = (0..n)
            .map(|i| {
                let (a, b) = ((2 * i + 2 * n - 1) % (2 * n), 2 * i + 1);
                let du = uu[b] - uu[a];
                let monotone = vv[a].signum() == v[i].signum() && vv[b].signum() == v[i].signum();
                if monotone && du.abs() > 1e-12 * scale {
                    (g[b] - g[a]) / du
                } else {
                    point[i]
                }
            })
            .collect();
        (stiffness, damping)
    }

    /// The Galerkin matrix `P diag(f) E` ((2H+1) × (2H+1)) of the multiplication by the
    /// sampled function `f`: the coefficients of `f(θ) u(θ)` from those of `u`, truncated.
    pub(crate) fn galerkin(&self, f: &[f64]) -> Mat<f64> {
        let nh = self.set.len();
        if self.dense() {
            let mut g = Mat::<f64>::zeros(nh, nh);
            self.galerkin_into(f, &mut Vec::new(), g.as_mut());
            return g;
        }
        let mut fe = Mat::<f64>::zeros(self.n, nh);
        for i in 0..self.n {
            for j in 0..nh {
                fe[(i, j)] = f[i] * self.e[(i, j)];
            }
        }
        let mut g = Mat::<f64>::zeros(nh, nh);
        self.project(g.as_mut(), fe.as_ref());
        g
    }

    /// True when the plan samples far more densely than the harmonics need (`N ≥ 8(2H+1)`:
    /// the kinks of clearance and Jenkins, steep friction): Galerkin matrices then come from
    /// the `4H + 1` Fourier sums of the sampled function ([`AftPlan::galerkin_into`]), `O(N H)`
    /// work instead of the product's `O(N H²)`.
    fn dense(&self) -> bool {
        self.n >= 8 * self.set.len()
    }

    /// `dst = P diag(f) E` from the discrete Fourier sums of `f`, `C_m = ⟨f cos mθ⟩` and
    /// `S_m = ⟨f sin mθ⟩` (`m = 0..=2H`, `⟨·⟩` the mean over the samples): by the
    /// product-to-sum identities, sample by sample, row `cos kθ` and column `cos lθ` is
    /// `C_{k−l} + C_{k+l}`, (`cos k`, `sin l`) `S_{l+k} + S_{l−k}`, (`sin k`, `cos l`)
    /// `S_{k+l} + S_{k−l}`, (`sin k`, `sin l`) `C_{k−l} − C_{k+l}` (`C_{−m} = C_m`,
    /// `S_{−m} = −S_m`; the constant is `cos 0θ`, and its row carries half the weight). Equal
    /// to the product up to rounding. `sums` is scratch.
    fn galerkin_into(&self, f: &[f64], sums: &mut Vec<f64>, mut dst: MatMut<'_, f64>) {
        let (n, h, nh) = (self.n, self.set.h, self.set.len());
        let (cos, sin) = (self.e.col_as_slice(1), self.e.col_as_slice(2));
        sums.clear();
        sums.resize(2 * (2 * h + 1), 0.0);
        let (c, s) = sums.split_at_mut(2 * h + 1);
        for m in 0..=2 * h {
            // cos(m θ_i) = cos θ_{m i mod N}.
            let (mut a, mut b, mut at) = (0.0, 0.0, 0usize);
            for &fi in &f[..n] {
                a += fi * cos[at];
                b += fi * sin[at];
                at += m;
                if at >= n {
                    at -= n;
                }
            }
            c[m] = a / n as f64;
            s[m] = b / n as f64;
        }
        let cm = |m: isize| c[m.unsigned_abs()];
        let sm = |m: isize| {
            if m < 0 {
                -s[m.unsigned_abs()]
            } else {
                s[m as usize]
            }
        };
        let kind = |j: usize| (j.div_ceil(2) as isize, j > 0 && j.is_multiple_of(2));
        for col in 0..nh {
            let (l, l_sin) = kind(col);
            for row in 0..nh {
                let (k, k_sin) = kind(row);
                let v = match (k_sin, l_sin) {
                    (false, false) => cm(k - l) + cm(k + l),
                    (false, true) => sm(l + k) + sm(l - k),
                    (true, false) => sm(k + l) + sm(k - l),
                    (true, true) => cm(k - l) - cm(k + l),
                };
                dst[(row, col)] = if row == 0 { 0.5 * v } else { v };
            }
        }
    }

    /// `dst = P w`: the harmonic coefficients of the sampled columns of `w`, by faer's
    /// product on one thread. faer's product kernels return with the upper halves of the
    /// vector registers dirty, and the baseline target's legacy-encoded SSE code that runs
    /// next (the Newton and Hill loops around this) is about 2.8× slower until they are
    /// cleared (44 against 15.6 µs for one Duffing Hill block of order 16): they are cleared
    /// here, after every product of this crate's hot paths.
    fn project(&self, dst: MatMut<'_, f64>, w: MatRef<'_, f64>) {
        matmul(dst, Accum::Replace, self.p.as_ref(), w, 1.0, Par::Seq);
        clear_upper_state();
    }

    /// Harmonic coefficients of samples `g`.
    pub fn to_freq(&self, g: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; self.set.len()];
        self.to_freq_into(g, &mut out);
        out
    }

    /// [`AftPlan::to_freq`] into `out` (2H+1 values).
    pub(crate) fn to_freq_into(&self, g: &[f64], out: &mut [f64]) {
        // P's row j is E's column j weighted by 1/N (j = 0) or 2/N: E is column-major.
        let n = self.n as f64;
        for (j, o) in out.iter_mut().enumerate() {
            let w = if j == 0 { 1.0 } else { 2.0 } / n;
            *o = w * self
                .e
                .col_as_slice(j)
                .iter()
                .zip(g)
                .map(|(e, g)| e * g)
                .sum::<f64>();
        }
    }

    /// Complex Fourier coefficients `c_j = (1/N) Σ g_n e^{−ijθ_n}`, `j = 0..=jmax`, of samples
    /// `g` (so that `g(θ) = Σ_{j=−jmax..jmax} c_j e^{ijθ}`).
    pub fn exponential(&self, g: &[f64], jmax: usize) -> Vec<c64> {
        let n = self.n as f64;
        (0..=jmax)
            .map(|j| {
                g.iter()
                    .enumerate()
                    .map(|(i, &gi)| {
                        let a = -2.0 * PI * (j * i) as f64 / n;
                        c64::new(gi * a.cos(), gi * a.sin())
                    })
                    .sum::<c64>()
                    * (1.0 / n)
            })
            .collect()
    }

    /// Evaluates `law` on the coordinate with coefficients `x` at base frequency `omega0`
    /// (rad/s). History-dependent laws (Jenkins) are marched over repeated periods from a
    /// zero state until the state at the period's start repeats.
    pub fn evaluate(&self, law: &Law, x: &[f64], omega0: f64, jacobian: bool) -> ElementHarmonics {
        self.evaluate_element(law, x, omega0, jacobian)
    }

    /// [`AftPlan::evaluate`] into caller buffers: the force coefficients into `force` (2H+1),
    /// `∂G/∂x` into `jacobian` ((2H+1) × (2H+1)) when given, the samples of `∂g/∂u` and
    /// `∂g/∂u̇` left in `scratch` ([`AftScratch::stiffness`], [`AftScratch::damping`]). Once
    /// `scratch` has served a plan with as many samples, nothing is allocated.
    ///
    /// # Panics
    /// When `force` or `jacobian` has the wrong size (a programming error).
    pub fn evaluate_into(
        &self,
        law: &Law,
        x: &[f64],
        omega0: f64,
        scratch: &mut AftScratch,
        force: &mut [f64],
        jacobian: Option<MatMut<'_, f64>>,
    ) {
        let n = self.n;
        let nh = self.set.len();
        assert_eq!(force.len(), nh, "AFT force buffer");
        let AftScratch {
            u,
            v,
            g,
            kt,
            ct,
            state,
            start,
            slip_ref,
            last,
            w,
            sums,
            gc,
            ..
        } = scratch;
        self.to_time_into(x, omega0, u, v);
        g.resize(n, 0.0);
        kt.resize(n, 0.0);
        ct.resize(n, 0.0);
        // A slider stuck at sample i sits where its last slip left it, at `u_j − ±f/k` of
        // that sample j (of this period or, periodically, an earlier one): its force
        // `k (u_i − u_j) ± f` then depends on x through u_j too. `slip_ref[i ns + s]` is that
        // j for slider s stuck at i (NO_SLIP when it slips there, or never slipped: a slider
        // that stays where it started does not depend on x).
        let ns = law.n_sliders();
        let history = jacobian.is_some() && ns > 0;
        periodic_start_into(law, u, state, start, last);
        if history {
            slip_ref.clear();
            slip_ref.resize(n * ns, NO_SLIP);
        }
        for i in 0..n {
            let e = law.eval(u[i], v[i], state);
            g[i] = e.force;
            kt[i] = e.df_du;
            ct[i] = e.df_dv;
            if history {
                for s in 0..ns {
                    let (k, f) = law.slider(s);
                    if (k * (u[i] - state[s])).abs() <= f {
                        slip_ref[i * ns + s] = last[s];
                    }
                    if slider_commit(k, f, u[i], &mut state[s]) {
                        last[s] = i;
                    }
                }
            } else {
                law.commit_state(u[i], v[i], state);
            }
        }
        self.to_freq_into(g, force);
        if let Some(mut jac) = jacobian {
            if !history && self.dense() {
                self.galerkin_into(kt, sums, jac.as_mut());
                if ct.iter().any(|&c| c != 0.0) {
                    if gc.nrows() != nh {
                        *gc = Mat::zeros(nh, nh);
                    }
                    self.galerkin_into(ct, sums, gc.as_mut());
                    // ω0 P diag(ct) E' = ω0 G(ct) D: E' has −k sin kθ in the cosine column
                    // of harmonic k and k cos kθ in its sine column.
                    for k in 1..=self.set.h {
                        let wk = omega0 * k as f64;
                        for r in 0..nh {
                            jac[(r, 2 * k - 1)] -= wk * gc[(r, 2 * k)];
                            jac[(r, 2 * k)] += wk * gc[(r, 2 * k - 1)];
                        }
                    }
                }
                return;
            }
            if w.nrows() != n || w.ncols() != nh {
                *w = Mat::zeros(n, nh);
            }
            for j in 0..nh {
                for i in 0..n {
                    w[(i, j)] = kt[i] * self.e[(i, j)] + omega0 * ct[i] * self.ed[(i, j)];
                }
            }
            if history {
                // Sliders stuck since the same reversal share their reference sample: sum
                // their stiffnesses over each run of equal references.
                for i in 0..n {
                    let refs = &slip_ref[i * ns..(i + 1) * ns];
                    let mut s = 0;
                    while s < ns {
                        let r = refs[s];
                        let mut k = 0.0;
                        while s < ns && refs[s] == r {
                            k += law.slider(s).0;
                            s += 1;
                        }
                        if r != NO_SLIP {
                            for j in 0..nh {
                                w[(i, j)] -= k * self.e[(r, j)];
                            }
                        }
                    }
                }
            }
            self.project(jac, w.as_ref());
        }
    }

    /// Evaluates a law on [`Law::arity`] `m` coordinates whose coefficients are `x`
    /// (`m (2H+1)`, coordinate after coordinate), at base frequency `omega0` (rad/s): the force
    /// coefficients of every coordinate in the same layout, `∂G/∂x` (`m(2H+1)` square, blocks
    /// `P diag(∂g_a/∂u_b) E`) when asked for, the tangent samples. For a one-coordinate law
    /// this is [`AftPlan::evaluate`].
    pub fn evaluate_element(
        &self,
        law: &Law,
        x: &[f64],
        omega0: f64,
        jacobian: bool,
    ) -> ElementHarmonics {
        let w = law.arity() * self.set.len();
        let mut scratch = AftScratch::default();
        let mut force = vec![0.0; w];
        let mut jac = jacobian.then(|| Mat::zeros(w, w));
        self.evaluate_element_into(
            law,
            x,
            omega0,
            &mut scratch,
            &mut force,
            jac.as_mut().map(|j| j.as_mut()),
        );
        ElementHarmonics {
            force,
            jacobian: jac,
            stiffness: scratch.kt,
            damping: scratch.ct,
        }
    }

    /// [`AftPlan::evaluate_element`] into caller buffers (see [`AftPlan::evaluate_into`]; a
    /// coupled law leaves `∂g_a/∂u_b` in [`AftScratch::stiffness`] at `(a m + b) N + i` and no
    /// damping samples). Allocation-free once `scratch` has served as large an element.
    ///
    /// # Panics
    /// When `x`, `force` or `jacobian` do not hold `arity · (2H+1)` coefficients.
    pub fn evaluate_element_into(
        &self,
        law: &Law,
        x: &[f64],
        omega0: f64,
        scratch: &mut AftScratch,
        force: &mut [f64],
        jacobian: Option<MatMut<'_, f64>>,
    ) {
        let m = law.arity();
        if m == 1 {
            return self.evaluate_into(law, x, omega0, scratch, force, jacobian);
        }
        let (n, nh) = (self.n, self.set.len());
        assert!(
            x.len() == m * nh && force.len() == m * nh,
            "AFT coupled buffers"
        );
        let AftScratch {
            u,
            v,
            kt,
            ct,
            w,
            coords,
            forces,
            point_force,
            point_jac,
            ..
        } = scratch;
        // Samples of every coordinate, sample-major: coords[i m + j].
        coords.resize(m * n, 0.0);
        for j in 0..m {
            self.to_time_into(&x[j * nh..(j + 1) * nh], omega0, u, v);
            for i in 0..n {
                coords[i * m + j] = u[i];
            }
        }
        kt.resize(m * m * n, 0.0);
        ct.clear();
        forces.resize(m * n, 0.0);
        point_force.resize(m, 0.0);
        point_jac.resize(m * m, 0.0);
        for i in 0..n {
            law.eval_coupled(&coords[i * m..(i + 1) * m], point_force, point_jac);
            for a in 0..m {
                forces[a * n + i] = point_force[a];
                for b in 0..m {
                    kt[(a * m + b) * n + i] = point_jac[a * m + b];
                }
            }
        }
        for a in 0..m {
            self.to_freq_into(
                &forces[a * n..(a + 1) * n],
                &mut force[a * nh..(a + 1) * nh],
            );
        }
        if let Some(mut jac) = jacobian {
            if w.nrows() != n || w.ncols() != nh {
                *w = Mat::zeros(n, nh);
            }
            for a in 0..m {
                for b in 0..m {
                    let k = &kt[(a * m + b) * n..(a * m + b + 1) * n];
                    for j in 0..nh {
                        for i in 0..n {
                            w[(i, j)] = k[i] * self.e[(i, j)];
                        }
                    }
                    self.project(
                        jac.as_mut().submatrix_mut(a * nh, b * nh, nh, nh),
                        w.as_ref(),
                    );
                }
            }
        }
    }

    /// `∂G/∂p` of every coordinate's force coefficients (`arity (2H+1) × n_params`) at
    /// coefficients `x` (`arity (2H+1)`); [`AftPlan::dparams`] for a one-coordinate law.
    pub fn dparams_element(&self, law: &Law, x: &[f64], omega0: f64) -> Mat<f64> {
        let m = law.arity();
        if m == 1 {
            return self.dparams(law, x, omega0);
        }
        let (n, nh, np) = (self.n, self.set.len(), law.n_params());
        let mut u = vec![0.0; m * n];
        for j in 0..m {
            let (uj, _) = self.to_time(&x[j * nh..(j + 1) * nh], omega0);
            for i in 0..n {
                u[i * m + j] = uj[i];
            }
        }
        let mut out = vec![0.0; m * np];
        let mut d = Mat::<f64>::zeros(m * nh, np);
        let mut samples = Mat::<f64>::zeros(n, np);
        for a in 0..m {
            for i in 0..n {
                law.dforce_dparams_coupled(&u[i * m..(i + 1) * m], &mut out);
                for c in 0..np {
                    samples[(i, c)] = out[a * np + c];
                }
            }
            d.submatrix_mut(a * nh, 0, nh, np)
                .copy_from(&self.p * &samples);
        }
        d
    }

    /// `∂G/∂p` ((2H+1) × n_params) of `law`'s parameters at coefficients `x`, the history of
    /// hysteretic laws taken from the periodic march of [`AftPlan::evaluate`].
    ///
    /// A slider stuck since its last slip at sample j with sign σ pushes
    /// `k (u_i − u_j) + σ f`: its derivative is `∂k/∂p (u_i − u_j) + σ ∂f/∂p`, the slip
    /// position moving with the parameters (not `∂k/∂p (u_i − z)` at a frozen `z`); while
    /// slipping, `σ ∂f/∂p`; never slipped, `∂k/∂p u_i`.
    pub fn dparams(&self, law: &Law, x: &[f64], omega0: f64) -> Mat<f64> {
        let (u, v) = self.to_time(x, omega0);
        let np = law.n_params();
        let mut samples = Mat::<f64>::zeros(self.n, np);
        let ns = law.n_sliders();
        if ns > 0 {
            let (mut state, mut start, mut last) = (Vec::new(), Vec::new(), Vec::new());
            periodic_start_into(law, &u, &mut state, &mut start, &mut last);
            // The sign of each slider's last slip: the spring force k (u − z) = ±f just after.
            let mut sign: Vec<f64> = (0..ns)
                .map(|s| match last[s] {
                    NO_SLIP => 0.0,
                    j => (u[j] - state[s]).signum(),
                })
                .collect();
            let (mut dk, mut df) = (vec![0.0; ns * np], vec![0.0; ns * np]);
            for s in 0..ns {
                law.slider_dparams(
                    s,
                    &mut dk[s * np..(s + 1) * np],
                    &mut df[s * np..(s + 1) * np],
                );
            }
            for i in 0..self.n {
                for s in 0..ns {
                    let (k, f) = law.slider(s);
                    let trial = k * (u[i] - state[s]);
                    let (dks, dfs) = (&dk[s * np..(s + 1) * np], &df[s * np..(s + 1) * np]);
                    for c in 0..np {
                        samples[(i, c)] += if trial.abs() > f {
                            dfs[c] * trial.signum()
                        } else if last[s] == NO_SLIP {
                            dks[c] * (u[i] - state[s])
                        } else {
                            dks[c] * (u[i] - u[last[s]]) + sign[s] * dfs[c]
                        };
                    }
                    if slider_commit(k, f, u[i], &mut state[s]) {
                        last[s] = i;
                        sign[s] = trial.signum();
                    }
                }
            }
            return &self.p * &samples;
        }
        let mut state = periodic_start(law, &u);
        let mut out = vec![0.0; np];
        for i in 0..self.n {
            law.dforce_dparams(u[i], v[i], &state, &mut out);
            for (c, o) in out.iter().enumerate() {
                samples[(i, c)] = *o;
            }
            law.commit_state(u[i], v[i], &mut state);
        }
        &self.p * &samples
    }
}

/// Clears the upper halves of the vector registers (`vzeroupper` on x86, which the compiler
/// places at the return of a function that used them: here one 256- or 512-bit register
/// value).
fn clear_upper_state() {
    pulp::Arch::new().dispatch(ClearUpper);
}

/// [`clear_upper_state`] as a `pulp` kernel.
struct ClearUpper;

impl pulp::WithSimd for ClearUpper {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, simd: S) {
        std::hint::black_box(simd.splat_f64s(std::hint::black_box(0.0)));
    }
}

/// The history state at the start of a period of the motion `(u, v)` once it repeats: marched
/// from zero over at most 16 periods, until the state at the period's end equals the one at
/// its start to 1e-13 of the motion. Empty for memoryless laws.
fn periodic_start(law: &Law, u: &[f64]) -> Vec<f64> {
    let (mut state, mut start, mut last) = (Vec::new(), Vec::new(), Vec::new());
    periodic_start_into(law, u, &mut state, &mut start, &mut last);
    state
}

/// [`periodic_start`] into `state` (`start` scratch), recording in `last[s]` the sample
/// (within the period) of slider `s`'s last slip over the whole march (NO_SLIP if it never
/// slipped): the marched periods repeat the same samples, so a slip in an earlier period
/// pins the slider at that sample's displacement. The laws with a history are those made of
/// sliders (`Law::n_states` = `Law::n_sliders`), whose history depends on `u` alone.
fn periodic_start_into(
    law: &Law,
    u: &[f64],
    state: &mut Vec<f64>,
    start: &mut Vec<f64>,
    last: &mut Vec<usize>,
) {
    let ns = law.n_sliders();
    state.clear();
    state.resize(ns, 0.0);
    last.clear();
    last.resize(ns, NO_SLIP);
    if ns == 0 {
        return;
    }
    let scale = u.iter().fold(0.0f64, |m, a| m.max(a.abs()));
    for _ in 0..16 {
        start.clear();
        start.extend_from_slice(state);
        for (i, &ui) in u.iter().enumerate() {
            for s in 0..ns {
                let (k, f) = law.slider(s);
                if slider_commit(k, f, ui, &mut state[s]) {
                    last[s] = i;
                }
            }
        }
        if start
            .iter()
            .zip(state.iter())
            .all(|(a, b)| (a - b).abs() <= 1e-13 * scale)
        {
            break;
        }
    }
}

/// Reusable buffers of [`AftPlan::evaluate_into`]: the samples of one period and the
/// history state. Sized on first use; reused without allocation for plans of no more samples.
#[derive(Debug, Clone)]
pub struct AftScratch {
    u: Vec<f64>,
    v: Vec<f64>,
    g: Vec<f64>,
    kt: Vec<f64>,
    ct: Vec<f64>,
    state: Vec<f64>,
    start: Vec<f64>,
    slip_ref: Vec<usize>,
    last: Vec<usize>,
    w: Mat<f64>,
    /// Densely sampled laws: the tangents' Fourier sums and the damping tangent's Galerkin
    /// matrix.
    sums: Vec<f64>,
    gc: Mat<f64>,
    /// Coupled laws: coordinate samples (sample-major), forces (coordinate-major), and one
    /// sample's forces and tangent.
    coords: Vec<f64>,
    forces: Vec<f64>,
    point_force: Vec<f64>,
    point_jac: Vec<f64>,
}

/// [`AftScratch`]'s mark of a slider with no reference sample (slipping, or never slipped).
const NO_SLIP: usize = usize::MAX;

impl Default for AftScratch {
    fn default() -> Self {
        Self {
            u: Default::default(),
            v: Default::default(),
            g: Default::default(),
            kt: Default::default(),
            ct: Default::default(),
            state: Default::default(),
            start: Default::default(),
            slip_ref: Default::default(),
            last: Default::default(),
            w: Mat::new(),
            sums: Default::default(),
            gc: Mat::new(),
            coords: Default::default(),
            forces: Default::default(),
            point_force: Default::default(),
            point_jac: Default::default(),
        }
    }
}

impl AftScratch {
    /// `∂g/∂u` at each sample of the last evaluation (N/m).
    pub fn stiffness(&self) -> &[f64] {
        &self.kt
    }

    /// `∂g/∂u̇` at each sample of the last evaluation (N s/m).
    pub fn damping(&self) -> &[f64] {
        &self.ct
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cubic_of_a_cosine_is_exact() {
        // (A cos θ)³ = ¾A³ cos θ + ¼A³ cos 3θ
        let set = HarmonicSet::new(3, 1).unwrap();
        let law = Law::Cubic { k3: 2.0 };
        let plan = AftPlan::new(set, samples_for(&law, &set)).unwrap();
        let mut x = vec![0.0; set.len()];
        x[1] = 0.5;
        let r = plan.evaluate(&law, &x, 10.0, false);
        let want = [
            0.0,
            2.0 * 0.75 * 0.125,
            0.0,
            0.0,
            0.0,
            2.0 * 0.25 * 0.125,
            0.0,
        ];
        for (a, b) in r.force.iter().zip(want) {
            assert!((a - b).abs() < 1e-15, "{:?}", r.force);
        }
    }

    /// Length of `[a, b]` inside the periodic interval `[lo, hi]` (period 2π).
    fn overlap(a: f64, b: f64, lo: f64, hi: f64) -> f64 {
        [-2.0 * PI, 0.0, 2.0 * PI]
            .iter()
            .map(|s| (b.min(hi + s) - a.max(lo + s)).max(0.0))
            .sum()
    }

    /// The cell-averaged tangent against the exact averages over the cells for `u = A cos θ`:
    /// a bump stop (contact while `A cos θ > e`) and a Jenkins slider (stuck for `θs` after
    /// each reversal, `cos θs = 1 − 2 fs/(kt A)`, then slipping). Every cell agrees to `δ/2`
    /// of the jump (`δ = 2π/N`; the curvature of `u` within the switching cell: 3.6e-4 of it
    /// measured for the stop) and the mean over the period to `δ²` of it but, for the
    /// slider, the two cells holding a velocity reversal (where it sticks again): those keep
    /// the point sample. The point samples are off by up to half the jump in every switching
    /// cell.
    #[test]
    fn cell_tangent_is_the_exact_cell_average() {
        let set = HarmonicSet::new(7, 1).unwrap();
        let plan = AftPlan::new(set, 64 * set.len()).unwrap();
        let (n, a) = (plan.n, 2e-3_f64);
        let delta = 2.0 * PI / n as f64;
        let mut x = vec![0.0; set.len()];
        x[1] = a;
        let (k, e) = (1e5_f64, 1.2e-3_f64);
        let (kt, fs) = (2e4_f64, 12.0_f64);
        let ts = (1.0 - 2.0 * fs / (kt * a)).acos();
        for (law, jump, exact, turning) in [
            (
                Law::bump_stop(k, e),
                k,
                Box::new(|lo: f64, hi: f64| {
                    let c = (e / a).acos();
                    k * overlap(lo, hi, -c, c) / (hi - lo)
                }) as Box<dyn Fn(f64, f64) -> f64>,
                false,
            ),
            (
                Law::Jenkins { kt, fs },
                kt,
                Box::new(|lo: f64, hi: f64| {
                    kt * (overlap(lo, hi, 0.0, ts) + overlap(lo, hi, PI, PI + ts)) / (hi - lo)
                }),
                true,
            ),
        ] {
            let (cell, _) = plan.cell_tangent(&law, &x, 1.0);
            let point = plan.evaluate(&law, &x, 1.0, false).stiffness;
            let (mut worst, mut worst_point, mut mean) = (0.0f64, 0.0f64, 0.0f64);
            for i in 0..n {
                let th = delta * i as f64;
                let (lo, hi) = (th - 0.5 * delta, th + 0.5 * delta);
                let reverses = overlap(lo, hi, -1e-12, 1e-12) > 0.0
                    || overlap(lo, hi, PI - 1e-12, PI + 1e-12) > 0.0
                    || i == 0
                    || 2 * i == n;
                let want = exact(lo, hi);
                worst_point = worst_point.max((point[i] - want).abs());
                if turning && reverses {
                    continue;
                }
                worst = worst.max((cell[i] - want).abs());
                mean += (cell[i] - want) / n as f64;
            }
            eprintln!(
                "{}: cells within {:.1e}, mean {:.1e}, points {:.1e} of the jump",
                law.kind(),
                worst / jump,
                mean.abs() / jump,
                worst_point / jump
            );
            assert!(
                worst < 0.5 * delta * jump && mean.abs() < delta * delta * jump,
                "{}: {worst:e}, mean {mean:e}",
                law.kind()
            );
            assert!(worst_point > 0.1 * jump, "{}: {worst_point:e}", law.kind());
        }
    }

    #[test]
    fn galerkin_from_fourier_sums_equals_the_product() {
        let set = HarmonicSet::new(7, 1).unwrap();
        let plan = AftPlan::new(set, 16 * set.len()).unwrap();
        assert!(plan.dense());
        let nh = set.len();
        // A step (a contact tangent) plus a smooth part.
        let f: Vec<f64> = (0..plan.n)
            .map(|i| {
                let t = 2.0 * PI * i as f64 / plan.n as f64;
                f64::from(u8::from(t.sin() > 0.3)) * 100.0 + (3.0 * t).cos() - 0.2 * t.sin()
            })
            .collect();
        let mut fe = Mat::<f64>::zeros(plan.n, nh);
        for j in 0..nh {
            for i in 0..plan.n {
                fe[(i, j)] = f[i] * plan.e[(i, j)];
            }
        }
        let mut direct = Mat::<f64>::zeros(nh, nh);
        plan.project(direct.as_mut(), fe.as_ref());
        let sums = plan.galerkin(&f);
        let err = (0..nh)
            .flat_map(|r| (0..nh).map(move |c| (r, c)))
            .map(|(r, c)| (sums[(r, c)] - direct[(r, c)]).abs())
            .fold(0.0f64, f64::max);
        assert!(err < 1e-13 * direct.norm_max(), "{err:e}");
    }

    #[test]
    fn jacobians_match_finite_differences() {
        let set = HarmonicSet::new(4, 2).unwrap();
        let x: Vec<f64> = (0..set.len())
            .map(|j| 1e-3 * (0.7 - 0.13 * j as f64))
            .collect();
        let laws = [
            Law::Cubic { k3: 3e9 },
            Law::QuadraticDamping { c2: 40.0 },
            Law::Coulomb {
                fc: 2.0,
                v_reg: 0.05,
            },
            Law::bump_stop(1e5, 5e-4),
        ];
        for law in laws {
            let plan = AftPlan::new(set, samples_for(&law, &set)).unwrap();
            let w0 = 60.0;
            let j = plan.evaluate(&law, &x, w0, true).jacobian.unwrap();
            for c in 0..set.len() {
                let h = 1e-9;
                let mut xp = x.clone();
                xp[c] += h;
                let mut xm = x.clone();
                xm[c] -= h;
                let gp = plan.evaluate(&law, &xp, w0, false).force;
                let gm = plan.evaluate(&law, &xm, w0, false).force;
                for r in 0..set.len() {
                    let fd = (gp[r] - gm[r]) / (2.0 * h);
                    // The clearance kink makes the central difference O(h) wrong at the
                    // one or two samples that straddle it: 1/N of the entry.
                    let tol = 1e-6 * j.norm_max()
                        + if law.is_nonsmooth() { 2e-2 } else { 0.0 } * j.norm_max();
                    assert!(
                        (fd - j[(r, c)]).abs() <= tol,
                        "{}: ({r},{c}) {fd} vs {}",
                        law.kind(),
                        j[(r, c)]
                    );
                }
            }
        }
    }

    #[test]
    fn jenkins_jacobian_follows_the_slider_history() {
        // While stuck, the force kt (u_i − u_j) ± fs depends on the sample j of the last slip:
        // the Jacobian must carry −kt ∂u_j/∂x, an O(1) part (not 1/N) of every entry.
        let set = HarmonicSet::new(3, 1).unwrap();
        let law = Law::Jenkins { kt: 2e4, fs: 3.0 };
        let plan = AftPlan::new(set, samples_for(&law, &set)).unwrap();
        let w0 = 2.0 * std::f64::consts::PI * 20.0;
        // Slipping over part of each period (kt·|u| reaches 8 N > 3 N), and stuck throughout.
        for (amp, slips) in [(4e-4, true), (1e-4, false)] {
            let x = [
                1e-5,
                amp,
                0.3 * amp,
                0.0,
                0.1 * amp,
                0.05 * amp,
                -0.02 * amp,
            ];
            let j = plan.evaluate(&law, &x, w0, true).jacobian.unwrap();
            let mut worst = 0.0f64;
            for c in 0..set.len() {
                let h = 1e-10;
                let mut xp = x;
                xp[c] += h;
                let mut xm = x;
                xm[c] -= h;
                let gp = plan.evaluate(&law, &xp, w0, false).force;
                let gm = plan.evaluate(&law, &xm, w0, false).force;
                for r in 0..set.len() {
                    let fd = (gp[r] - gm[r]) / (2.0 * h);
                    worst = worst.max((fd - j[(r, c)]).abs());
                }
            }
            // A stick–slip switch inside [x − h, x + h] at one of the N = 448 samples moves an
            // entry by at most kt/N · 2 ≈ 1e-2 of kt; away from one, round-off (1e-6 kt).
            assert!(worst <= 2e-2 * j.norm_max(), "amp {amp:e}: {worst:e}");
            // Stuck throughout, the element is the linear spring kt: ∂G/∂x = kt I.
            if !slips {
                for r in 0..set.len() {
                    for c in 0..set.len() {
                        let want = if r == c { 2e4 } else { 0.0 };
                        assert!((j[(r, c)] - want).abs() <= 1e-9 * 2e4, "({r},{c})");
                    }
                }
            }
        }
    }

    /// Laws made of sliders (Jenkins, Iwan) in micro- and macroslip, with a mean offset: the
    /// Jacobian carries the stuck sliders' dependence on their last slip, and so do the
    /// parameter derivatives (`∂f/∂p` moves the slip position), both against central
    /// differences; the power laws' parameter derivatives likewise.
    #[test]
    fn slider_and_power_laws_follow_their_history_in_both_derivatives() {
        let set = HarmonicSet::new(3, 1).unwrap();
        let w0 = 2.0 * PI * 20.0;
        let laws = [
            Law::Jenkins { kt: 2e4, fs: 3.0 },
            Law::iwan_with(5.0, 1e5, -0.5, 0.1, 30, 3.0).unwrap(),
            Law::iwan(5.0, 1e5, -0.2, 0.02).unwrap(),
            Law::PowerSpring { k: -3e7, p: 1.6 },
            Law::PowerDamper { c: 40.0, p: 2.5 },
        ];
        for law in &laws {
            let plan = AftPlan::new(set, samples_for(law, &set)).unwrap();
            for amp in [5e-5, 3e-4] {
                let x = [
                    0.2 * amp,
                    amp,
                    0.3 * amp,
                    0.0,
                    0.1 * amp,
                    0.05 * amp,
                    -0.02 * amp,
                ];
                let j = plan.evaluate(law, &x, w0, true).jacobian.unwrap();
                let mut worst = 0.0f64;
                for c in 0..set.len() {
                    let h = 1e-6 * amp;
                    let (mut xp, mut xm) = (x, x);
                    xp[c] += h;
                    xm[c] -= h;
                    let gp = plan.evaluate(law, &xp, w0, false).force;
                    let gm = plan.evaluate(law, &xm, w0, false).force;
                    for r in 0..set.len() {
                        worst = worst.max(((gp[r] - gm[r]) / (2.0 * h) - j[(r, c)]).abs());
                    }
                }
                // A stick–slip switch of one slider within the step moves an entry by at most
                // 2 k_s/N of the N = 448 samples.
                assert!(
                    worst <= 2e-2 * j.norm_max(),
                    "{law:?} amp {amp:e}: {worst:e}"
                );
                let d = plan.dparams(law, &x, w0);
                for i in 0..law.n_params() {
                    let h = 1e-6 * law.param(i).abs();
                    let at = |p: f64| {
                        let mut l = law.clone();
                        l.set_param("e", i, p).unwrap();
                        plan.evaluate(&l, &x, w0, false).force
                    };
                    let (gp, gm) = (at(law.param(i) + h), at(law.param(i) - h));
                    let scale = d.col(i).norm_max().max(1e-300);
                    for r in 0..set.len() {
                        let fd = (gp[r] - gm[r]) / (2.0 * h);
                        assert!(
                            (fd - d[(r, i)]).abs() <= 2e-2 * scale,
                            "{} amp {amp:e} d/d{} row {r}: {} vs fd {fd}",
                            law.kind(),
                            law.param_name(i),
                            d[(r, i)]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn parameter_derivatives_match_finite_differences() {
        let set = HarmonicSet::new(3, 1).unwrap();
        let x = [1e-4, 2e-3, -5e-4, 1e-4, 3e-4, -2e-5, 1e-5];
        let law = Law::Polynomial {
            stiffness: vec![
                nlsim_kernel::PolyTerm {
                    power: 2,
                    coef: -1e7,
                },
                nlsim_kernel::PolyTerm {
                    power: 3,
                    coef: 8e9,
                },
            ],
            damping: vec![nlsim_kernel::PolyTerm {
                power: 1,
                coef: 3.0,
            }],
        };
        let plan = AftPlan::new(set, samples_for(&law, &set)).unwrap();
        let d = plan.dparams(&law, &x, 100.0);
        for i in 0..law.n_params() {
            let h = 1e-6 * law.param(i).abs();
            let mut lp = law.clone();
            lp.set_param("e", i, law.param(i) + h).unwrap();
            let mut lm = law.clone();
            lm.set_param("e", i, law.param(i) - h).unwrap();
            let gp = plan.evaluate(&lp, &x, 100.0, false).force;
            let gm = plan.evaluate(&lm, &x, 100.0, false).force;
            for r in 0..set.len() {
                let fd = (gp[r] - gm[r]) / (2.0 * h);
                assert!((fd - d[(r, i)]).abs() <= 1e-7 * d.col(i).norm_max() + 1e-300);
            }
        }
    }

    /// A law on two coordinates: the coupled force of `u1 = a cos θ`, `u2 = b sin θ` against
    /// its closed form, the Jacobian blocks and the parameter derivatives against central
    /// differences, and a one-coordinate law through the same entry point.
    #[test]
    fn coupled_law_forces_jacobian_and_parameters() {
        let set = HarmonicSet::new(4, 1).unwrap();
        let nh = set.len();
        let term = nlsim_kernel::MonomialTerm::new;
        let law = Law::CoupledPolynomial {
            inputs: 2,
            terms: vec![
                term(0, &[1, 1], 2.0),
                term(1, &[2, 0], 1.0),
                term(1, &[1, 2], -3.0),
                term(0, &[0, 1], 0.5),
            ],
        };
        let plan = AftPlan::new(set, samples_for(&law, &set)).unwrap();
        let (a, b) = (0.4, 0.7);
        let mut x = vec![0.0; 2 * nh];
        x[1] = a; // u1 = a cos θ
        x[nh + 2] = b; // u2 = b sin θ
        let r = plan.evaluate_element(&law, &x, 3.0, true);
        // g1 = 2 u1 u2 + 0.5 u2 = a b sin 2θ + 0.5 b sin θ;
        // g2 = u1² − 3 u1 u2² = a²/2 (1 + cos 2θ) − 3 a b² (cos θ − cos 3θ)/4.
        let mut want = vec![0.0; 2 * nh];
        want[2] = 0.5 * b;
        want[4] = a * b;
        want[nh] = a * a / 2.0;
        want[nh + 3] = a * a / 2.0;
        want[nh + 1] = -0.75 * a * b * b;
        want[nh + 5] = 0.75 * a * b * b;
        for (g, w) in r.force.iter().zip(&want) {
            assert!((g - w).abs() < 1e-14, "{:?} vs {want:?}", r.force);
        }
        x[3] = 0.1;
        x[nh] = -0.2;
        x[nh + 5] = 0.05;
        let jac = plan.evaluate_element(&law, &x, 3.0, true).jacobian.unwrap();
        for c in 0..2 * nh {
            let h = 1e-6;
            let (mut xp, mut xm) = (x.clone(), x.clone());
            xp[c] += h;
            xm[c] -= h;
            let gp = plan.evaluate_element(&law, &xp, 3.0, false).force;
            let gm = plan.evaluate_element(&law, &xm, 3.0, false).force;
            for r in 0..2 * nh {
                let fd = (gp[r] - gm[r]) / (2.0 * h);
                assert!(
                    (fd - jac[(r, c)]).abs() <= 1e-8 * jac.norm_max(),
                    "∂G{r}/∂x{c}: {fd} vs {}",
                    jac[(r, c)]
                );
            }
        }
        let d = plan.dparams_element(&law, &x, 3.0);
        for i in 0..law.n_params() {
            let h = 1e-6;
            let mut lp = law.clone();
            lp.set_param("e", i, law.param(i) + h).unwrap();
            let mut lm = law.clone();
            lm.set_param("e", i, law.param(i) - h).unwrap();
            let gp = plan.evaluate_element(&lp, &x, 3.0, false).force;
            let gm = plan.evaluate_element(&lm, &x, 3.0, false).force;
            for r in 0..2 * nh {
                let fd = (gp[r] - gm[r]) / (2.0 * h);
                assert!((fd - d[(r, i)]).abs() <= 1e-8 * d.col(i).norm_max());
            }
        }
        // A one-coordinate law through the element entry point is the scalar evaluation.
        let cubic = Law::Cubic { k3: 2.0 };
        let e1 = plan.evaluate_element(&cubic, &x[..nh], 3.0, true);
        let e2 = plan.evaluate(&cubic, &x[..nh], 3.0, true);
        assert_eq!(e1.force, e2.force);
    }
}
