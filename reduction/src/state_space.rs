//! The diagonal (complex modal) state-space form of the reduced model, thesis eq. (10) after the
//! similarity transform `A = T Λ T⁻¹`:
//!
//! `ż_r = λ_r z_r + b̃_r u`,  `y = Σ_r w_r Re(c̃_r z_r) + D u`
//!
//! with `u` the port forces and `y` the port displacements. A complex-conjugate pair of poles is
//! stored once with weight `w_r = 2` (its partner's contribution is the complex conjugate); a real
//! pole (overdamped mode, damped rigid-body mode) has weight 1 and real `z_r`. Velocities are
//! `Σ w_r Re(c̃_r λ_r z_r)`; accelerations `Σ w_r Re(c̃_r λ_r² z_r) + D_a u` with
//! `D_a = Σ w_r Re(c̃_r λ_r b̃_r) = Φ_P Φ_Pᵀ`.
//!
//! Proportional damping (none, Rayleigh, modal) has a closed form per mode
//! (`s² + c_r s + ω_r² = 0`, `c_r = 2 ζ_r ω_r` or `α + β ω_r²`). An explicit damping matrix
//! couples the modes: the reduced state matrix `[[0, Ω], [−Ω, −ΦᵀVΦ]]` (state `[Ω q; q̇]`,
//! scaled to unit norm) goes through a dense complex eigendecomposition.

use crate::modal::{Port, ReducedModel};
use faer::{Mat, c64};
use nlsim_kernel::{Damping, Error, Result};

/// The diagonal state-space system of a reduced model.
#[derive(Debug, Clone)]
pub struct ModalSystem {
    /// Poles `λ_r` (1/s): one per complex-conjugate pair (`Im λ > 0`) or real pole.
    pub poles: Vec<c64>,
    /// `2` for a conjugate pair, `1` for a real pole.
    pub weights: Vec<f64>,
    /// Input projection `b̃` (states × ports).
    pub input: Mat<c64>,
    /// Displacement output projection `c̃` (ports × states).
    pub output: Mat<c64>,
    /// Displacement feedthrough `D` (ports × ports; m/N): the residual flexibility.
    pub feedthrough: Mat<f64>,
    /// Acceleration feedthrough `D_a = Φ_P Φ_Pᵀ` (ports × ports; 1/kg).
    pub accel_feedthrough: Mat<f64>,
    /// The ports (names and DOFs), in row/column order.
    pub ports: Vec<Port>,
    /// Initial-condition map `z(0) = G · [η(0); η̇(0)]` for modal displacements `η` (√kg m)
    /// and velocities `η̇` of the retained modes, as the nonzeros `(state, column, G_ij)` of
    /// `G` (states × 2 modes; two per state for proportional damping).
    pub initial: Vec<(usize, usize, c64)>,
    /// Number of retained modes.
    pub n_modes: usize,
}

/// Which response quantity.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Response {
    /// Displacement (receptance, m/N).
    Displacement,
    /// Velocity (mobility, m/(N s)).
    Velocity,
    /// Acceleration (accelerance, m/(N s²)).
    Acceleration,
}

/// Per-mode damping coefficient `c_r` (1/s) of proportional damping, or `None` for a matrix.
fn modal_damping(damping: &Damping, r: usize, lambda: f64) -> Option<f64> {
    let omega = lambda.max(0.0).sqrt();
    match damping {
        Damping::None => Some(0.0),
        Damping::Rayleigh { alpha, beta } => Some(alpha + beta * lambda.max(0.0)),
        Damping::Modal(md) => Some(2.0 * md.zeta(r, omega / (2.0 * std::f64::consts::PI)) * omega),
        Damping::Matrix(_) => None,
    }
}

impl ModalSystem {
    /// Builds the diagonal form of `reduced`.
    ///
    /// Errors when a mode has no diagonal form: an undamped rigid-body mode or a critically
    /// damped mode (a double pole with one eigenvector), or rigid-body modes with matrix damping.
    pub fn new(reduced: &ReducedModel) -> Result<Self> {
        let modes = &reduced.modes;
        let m = modes.len();
        let np = reduced.ports.len();
        // Eigenvalues at rounding level are rigid-body modes: exactly zero stiffness. The
        // yardstick is the model (is K singular, and its stiffness scale), not the largest
        // retained eigenvalue (with that, keeping 107 of a 396-DOF beam's modes turned its
        // 23.7 Hz mode rigid).
        let rigid = modes.rigid_threshold;
        if let Some(r) = modes.eigenvalues.iter().position(|&l| l < -rigid) {
            return Err(Error::invalid(
                "diagonal state-space form",
                format!(
                    "mode {} has the negative eigenvalue {:e} rad²/s² (below the rigid-body \
                     threshold −{rigid:.3e}): the stiffness matrix is indefinite or too \
                     ill-conditioned for this mode count",
                    r + 1,
                    modes.eigenvalues[r]
                ),
            ));
        }
        let lambda: Vec<f64> = (0..m)
            .map(|r| {
                if modes.is_rigid(r) {
                    0.0
                } else {
                    modes.eigenvalues[r]
                }
            })
            .collect();
        let phi = &reduced.participation;
        let accel_feedthrough = phi * phi.transpose();
        let (poles, weights, input, output, initial) = if let Damping::Matrix(_) = &reduced.damping
        {
            Self::coupled(reduced, &lambda)?
        } else {
            let mut poles = Vec::with_capacity(m);
            let mut weights = Vec::with_capacity(m);
            // (mode, factor of b̃) per state.
            let mut states: Vec<(usize, c64)> = Vec::with_capacity(m);
            for r in 0..m {
                let c = modal_damping(&reduced.damping, r, lambda[r]).expect("proportional");
                let w2 = lambda[r];
                let disc = c * c - 4.0 * w2;
                let f_hz = w2.sqrt() / (2.0 * std::f64::consts::PI);
                let scale = c.abs().max(2.0 * w2.sqrt());
                if scale == 0.0 || disc.abs() <= 1e-12 * scale * scale {
                    return Err(Error::invalid(
                        "diagonal state-space form",
                        format!(
                            "mode {} ({f_hz:.4} Hz) {}: its state matrix has a double pole with \
                             one eigenvector, so no diagonal form exists; support the structure \
                             (soft springs) or change the damping",
                            r + 1,
                            if w2 == 0.0 {
                                "is an undamped rigid-body mode"
                            } else {
                                "is critically damped"
                            }
                        ),
                    ));
                }
                if disc < 0.0 {
                    let l1 = c64::new(-0.5 * c, 0.5 * (-disc).sqrt());
                    // b̃ = φᵀ / (λ − λ̄)
                    poles.push(l1);
                    weights.push(2.0);
                    states.push((r, (l1 - l1.conj()).inv()));
                } else {
                    let sq = disc.sqrt();
                    let (l1, l2) = (-0.5 * (c - sq), -0.5 * (c + sq));
                    for (a, b) in [(l1, l2), (l2, l1)] {
                        poles.push(c64::new(a, 0.0));
                        weights.push(1.0);
                        states.push((r, c64::new(1.0 / (a - b), 0.0)));
                    }
                }
            }
            let input = Mat::from_fn(states.len(), np, |s, p| {
                let (r, f) = states[s];
                f * phi[(p, r)]
            });
            let output = Mat::from_fn(np, states.len(), |p, s| {
                c64::new(phi[(p, states[s].0)], 0.0)
            });
            // A pair (w = 2): η = 2 Re z, η̇ = 2 Re(λ z). A real pair a, b: η = z_a + z_b,
            // η̇ = a z_a + b z_b.
            let mut initial = Vec::with_capacity(2 * states.len());
            let mut s = 0;
            while s < states.len() {
                let r = states[s].0;
                let l = poles[s];
                if weights[s] == 2.0 {
                    initial.push((s, r, c64::new(0.5, 0.5 * l.re / l.im)));
                    initial.push((s, m + r, c64::new(0.0, -0.5 / l.im)));
                    s += 1;
                } else {
                    let (a, b) = (l.re, poles[s + 1].re);
                    initial.push((s, r, c64::new(-b / (a - b), 0.0)));
                    initial.push((s, m + r, c64::new(1.0 / (a - b), 0.0)));
                    initial.push((s + 1, r, c64::new(-a / (b - a), 0.0)));
                    initial.push((s + 1, m + r, c64::new(1.0 / (b - a), 0.0)));
                    s += 2;
                }
            }
            (poles, weights, input, output, initial)
        };
        Ok(ModalSystem {
            poles,
            weights,
            input,
            output,
            feedthrough: reduced.residual.clone(),
            accel_feedthrough,
            ports: reduced.ports.clone(),
            initial,
            n_modes: m,
        })
    }

    /// Non-proportional damping: dense complex eigendecomposition of the reduced state matrix.
    #[allow(clippy::type_complexity)]
    fn coupled(
        reduced: &ReducedModel,
        lambda: &[f64],
    ) -> Result<(
        Vec<c64>,
        Vec<f64>,
        Mat<c64>,
        Mat<c64>,
        Vec<(usize, usize, c64)>,
    )> {
        let m = lambda.len();
        let np = reduced.ports.len();
        if let Some(r) = lambda.iter().position(|&l| l <= 0.0) {
            return Err(Error::invalid(
                "diagonal state-space form",
                format!(
                    "mode {} is a rigid-body mode; with an explicit damping matrix the diagonal \
                     form needs a supported structure (all ω > 0)",
                    r + 1
                ),
            ));
        }
        // Ṽ = Φᵀ V Φ
        let vt = reduced.modal_damping_matrix();
        let omega: Vec<f64> = lambda.iter().map(|l| l.sqrt()).collect();
        // A' = [[0, Ω], [−Ω, −Ṽ]] on the state [Ω q; q̇], scaled to unit norm for faer.
        let mut a = Mat::<f64>::zeros(2 * m, 2 * m);
        for r in 0..m {
            a[(r, m + r)] = omega[r];
            a[(m + r, r)] = -omega[r];
            for c in 0..m {
                a[(m + r, m + c)] = -vt[(r, c)];
            }
        }
        let s = a.norm_max();
        let a_scaled = &a * faer::Scale(1.0 / s);
        let evd = a_scaled.eigen().map_err(|e| Error::Numerical {
            what: "eigendecomposition of the reduced state matrix (matrix damping)".into(),
            detail: format!("{e:?}"),
        })?;
        let mut t = evd.U().to_owned();
        let scaled_poles: Vec<c64> = (0..2 * m).map(|i| evd.S()[i]).collect();
        repair_clusters(&a_scaled, &scaled_poles, &mut t)?;
        let all_poles: Vec<c64> = scaled_poles.iter().map(|&l| l * s).collect();
        // B' = [0; Φ_Pᵀ], C' = [Φ_P Ω⁻¹, 0].
        let pp = &reduced.participation;
        let b = Mat::from_fn(2 * m, np, |i, p| {
            if i >= m {
                c64::new(pp[(p, i - m)], 0.0)
            } else {
                c64::new(0.0, 0.0)
            }
        });
        let lu = t.partial_piv_lu();
        let tib = faer::linalg::solvers::Solve::solve(&lu, &b);
        // [η; η̇] ↦ the state [Ω η; η̇] ↦ T⁻¹ of it.
        let to_state = Mat::from_fn(2 * m, 2 * m, |i, j| {
            if i != j {
                c64::new(0.0, 0.0)
            } else if i < m {
                c64::new(omega[i], 0.0)
            } else {
                c64::new(1.0, 0.0)
            }
        });
        let tinit = faer::linalg::solvers::Solve::solve(&lu, &to_state);
        let cfull = Mat::from_fn(np, 2 * m, |p, j| {
            (0..m)
                .map(|r| t[(r, j)] * (pp[(p, r)] / omega[r]))
                .fold(c64::new(0.0, 0.0), |acc, x| acc + x)
        });
        let (mut poles, mut weights, mut keep) = (Vec::new(), Vec::new(), Vec::new());
        for (j, &l) in all_poles.iter().enumerate() {
            let tol = 1e-10 * l.norm();
            if l.im > tol {
                poles.push(l);
                weights.push(2.0);
                keep.push(j);
            } else if l.im.abs() <= tol {
                poles.push(c64::new(l.re, 0.0));
                weights.push(1.0);
                keep.push(j);
            }
        }
        let input = Mat::from_fn(keep.len(), np, |s, p| tib[(keep[s], p)]);
        let mut initial = Mat::from_fn(keep.len(), 2 * m, |s, j| tinit[(keep[s], j)]);
        let output = Mat::from_fn(np, keep.len(), |p, s| cfull[(p, keep[s])]);
        // A real pole's products c̃ b̃ are real up to round-off; drop the imaginary dust.
        let mut input = input;
        let mut output = output;
        for (s, &w) in weights.iter().enumerate() {
            if w == 1.0 {
                // Normalise the (arbitrary complex) eigenvector phase out of the product.
                let phase = (0..np)
                    .map(|p| output[(p, s)])
                    .max_by(|x, y| x.norm().total_cmp(&y.norm()))
                    .filter(|x| x.norm() > 0.0)
                    .map_or(c64::new(1.0, 0.0), |x| x / x.norm());
                for p in 0..np {
                    output[(p, s)] = c64::new((output[(p, s)] / phase).re, 0.0);
                    input[(s, p)] = c64::new((input[(s, p)] * phase).re, 0.0);
                }
                for j in 0..2 * m {
                    initial[(s, j)] = c64::new((initial[(s, j)] * phase).re, 0.0);
                }
            }
        }
        let mut sparse = Vec::new();
        for s in 0..initial.nrows() {
            for j in 0..2 * m {
                if initial[(s, j)] != c64::new(0.0, 0.0) {
                    sparse.push((s, j, initial[(s, j)]));
                }
            }
        }
        Ok((poles, weights, input, output, sparse))
    }

    /// Diagonal states `z(0)` for modal displacements `eta` (√kg m) and velocities `eta_dot`
    /// (√kg m/s) of the retained modes (e.g. from [`crate::ReducedModel::modal_coordinates`]).
    pub fn initial_states(&self, eta: &[f64], eta_dot: &[f64]) -> Result<Vec<c64>> {
        let m = self.n_modes;
        for (what, v) in [("modal displacements", eta), ("modal velocities", eta_dot)] {
            if v.len() != m {
                return Err(Error::DimensionMismatch {
                    what: format!("initial {what} (one per retained mode)"),
                    expected: m,
                    found: v.len(),
                });
            }
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(Error::NonFinite {
                    what: format!("initial {what}"),
                    location: format!("mode {}", i + 1),
                    value: v[i],
                });
            }
        }
        let mut z = vec![c64::new(0.0, 0.0); self.n_states()];
        for &(s, j, g) in &self.initial {
            z[s] += g * if j < m { eta[j] } else { eta_dot[j - m] };
        }
        Ok(z)
    }

    /// Number of stored states (conjugate pairs count once).
    pub fn n_states(&self) -> usize {
        self.poles.len()
    }

    /// Index of the port named `name`.
    pub fn port_index(&self, name: &str) -> Result<usize> {
        crate::modal::port_index(&self.ports, name)
    }

    /// Frequency response between ports at `omega` (rad/s): `H[o, i]` for every `o` in
    /// `outputs` and `i` in `inputs` (port indices),
    /// `H(ω) = Σ_r [c̃ b̃ / (iω − λ_r) + (c̃ b̃)* / (iω − λ_r*)] + D` times `(iω)^p` for velocity
    /// (`p = 1`) or acceleration (`p = 2`).
    pub fn frf(
        &self,
        omega: f64,
        outputs: &[usize],
        inputs: &[usize],
        q: Response,
    ) -> Result<Mat<c64>> {
        let np = self.ports.len();
        if let Some(&bad) = outputs.iter().chain(inputs).find(|&&p| p >= np) {
            return Err(Error::invalid(
                "FRF port",
                format!("port index {bad} is out of range (the system has {np} ports)"),
            ));
        }
        if !omega.is_finite() {
            return Err(Error::NonFinite {
                what: "FRF frequency".into(),
                location: "frf()".into(),
                value: omega,
            });
        }
        let iw = c64::new(0.0, omega);
        let mut h = Mat::<c64>::zeros(outputs.len(), inputs.len());
        for (s, &l) in self.poles.iter().enumerate() {
            let pair = self.weights[s] == 2.0;
            let d1 = (iw - l).inv();
            let d2 = (iw - l.conj()).inv();
            for (a, &o) in outputs.iter().enumerate() {
                let c = self.output[(o, s)];
                for (b, &i) in inputs.iter().enumerate() {
                    let cb = c * self.input[(s, i)];
                    h[(a, b)] += if pair {
                        cb * d1 + cb.conj() * d2
                    } else {
                        cb * d1
                    };
                }
            }
        }
        for (a, &o) in outputs.iter().enumerate() {
            for (b, &i) in inputs.iter().enumerate() {
                h[(a, b)] += c64::new(self.feedthrough[(o, i)], 0.0);
            }
        }
        let factor = match q {
            Response::Displacement => c64::new(1.0, 0.0),
            Response::Velocity => iw,
            Response::Acceleration => iw * iw,
        };
        if q != Response::Displacement {
            for v in h.as_mut().col_iter_mut().flat_map(|c| c.iter_mut()) {
                *v *= factor;
            }
        }
        Ok(h)
    }

    /// Receptance (m/N) between every pair of ports at `omega` (rad/s).
    pub fn receptance(&self, omega: f64) -> Result<Mat<c64>> {
        let all: Vec<usize> = (0..self.ports.len()).collect();
        self.frf(omega, &all, &all, Response::Displacement)
    }

    /// Physical displacement of every port from the diagonal states `z` and port forces `u`:
    /// `y = Σ_r w_r Re(c̃_r z_r) + D u`.
    pub fn port_displacements(&self, z: &[c64], u: &[f64]) -> Result<Vec<f64>> {
        let (ns, np) = (self.n_states(), self.ports.len());
        if z.len() != ns || u.len() != np {
            return Err(Error::DimensionMismatch {
                what: "states and port forces of the modal system".into(),
                expected: if z.len() != ns { ns } else { np },
                found: if z.len() != ns { z.len() } else { u.len() },
            });
        }
        Ok((0..np)
            .map(|p| {
                let modal: f64 = (0..ns)
                    .map(|s| self.weights[s] * (self.output[(p, s)] * z[s]).re)
                    .sum();
                modal
                    + (0..np)
                        .map(|i| self.feedthrough[(p, i)] * u[i])
                        .sum::<f64>()
            })
            .collect())
    }
}

/// Repeated poles (the symmetric-section pairs of a beam, kept by damping that does not couple
/// them) leave the eigenvectors of a non-symmetric solver nearly parallel within the cluster,
/// and `T` close to singular. For every cluster of `k ≥ 2` equal poles the eigenvectors are
/// recomputed as the `k` right singular vectors of `A − λ I` with the smallest singular values,
/// an orthonormal basis of the eigenspace.
fn repair_clusters(a: &Mat<f64>, poles: &[c64], t: &mut Mat<c64>) -> Result<()> {
    let n = poles.len();
    let mut done = vec![false; n];
    for i in 0..n {
        if done[i] {
            continue;
        }
        let cluster: Vec<usize> = (i..n)
            .filter(|&j| {
                !done[j] && (poles[j] - poles[i]).norm() <= 1e-8 * poles[i].norm().max(1e-300)
            })
            .collect();
        for &j in &cluster {
            done[j] = true;
        }
        if cluster.len() < 2 {
            continue;
        }
        let k = cluster.len();
        let mean = cluster
            .iter()
            .fold(c64::new(0.0, 0.0), |acc, &j| acc + poles[j])
            / k as f64;
        let shifted = Mat::from_fn(n, n, |r, c| {
            c64::new(a[(r, c)], 0.0) - if r == c { mean } else { c64::new(0.0, 0.0) }
        });
        let svd = shifted.svd().map_err(|e| Error::Numerical {
            what: "eigenspace of a repeated pole of the reduced state matrix".into(),
            detail: format!("{e:?}"),
        })?;
        let sv: Vec<f64> = (0..n).map(|q| svd.S()[q].re).collect();
        let mut order: Vec<usize> = (0..n).collect();
        order.sort_by(|&x, &y| sv[x].total_cmp(&sv[y]));
        for (slot, &j) in cluster.iter().enumerate() {
            let src = order[slot];
            for r in 0..n {
                t[(r, j)] = svd.V()[(r, src)];
            }
        }
    }
    Ok(())
}
