//! The algebraic loop on the nonlinear ports: find the element forces `f` with
//! `f = g(d_pred − S_d f, v_pred − S_v f)`, where `S_d`, `S_v` are the (small, precomputed)
//! sensitivities of the port displacements and velocities to the element forces at the end of
//! the step. Damped Newton in `n_NL` unknowns, allocation-free. A law on several coordinates
//! is evaluated once for its group of ports and contributes its `m × m` block `∂g_a/∂u_b` to
//! the loop's Jacobian.

use crate::plant::ElementPort;

/// Newton settings of the nonlinear feedback loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NewtonConfig {
    /// Iteration limit per solve.
    pub max_iterations: usize,
    /// Relative force tolerance: `|r_i| ≤ rtol (|f_i| + |g_i|)` (plus a tiny absolute floor).
    pub rtol: f64,
}

impl Default for NewtonConfig {
    fn default() -> Self {
        NewtonConfig {
            max_iterations: 50,
            rtol: 1e-12,
        }
    }
}

/// Why the loop failed.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LoopFailure {
    pub iterations: usize,
    pub residual: f64,
    pub element: usize,
    pub displacement: f64,
}

/// Work buffers of the loop for `n` elements.
#[derive(Debug, Clone)]
pub(crate) struct Feedback {
    n: usize,
    d: Vec<f64>,
    v: Vec<f64>,
    g: Vec<f64>,
    gu: Vec<f64>,
    gv: Vec<f64>,
    r: Vec<f64>,
    trial: Vec<f64>,
    step: Vec<f64>,
    jac: Vec<f64>,
    /// Displacements of the last solution.
    pub last_d: Vec<f64>,
    /// Velocities of the last solution.
    pub last_v: Vec<f64>,
    /// Static stiffness of each element's port (N/m), for the absolute force tolerance.
    stiffness: Vec<f64>,
    /// Per port of a coupled group (its entries in coordinate order,
    /// [`ElementPort::coordinate`]): the offset of its row of `∂g/∂u` in `gjac`.
    row_at: Vec<usize>,
    /// `∂g_a/∂u_b` of every coupled group, row-major blocks.
    gjac: Vec<f64>,
}

impl Feedback {
    /// Buffers for the loop of `plant`'s elements.
    pub fn new(plant: &crate::plant::Plant) -> Self {
        let n = plant.elements.len();
        let stiffness = plant
            .elements
            .iter()
            .map(|e| {
                let flex = plant.static_flexibility(e.port);
                if flex.is_finite() && flex > 0.0 {
                    1.0 / flex
                } else {
                    0.0
                }
            })
            .collect();
        let mut row_at = vec![0; n];
        let mut blocks = 0;
        for (r, e) in row_at.iter_mut().zip(&plant.elements) {
            let m = e.element.law().arity();
            if m > 1 {
                *r = blocks;
                blocks += m;
            }
        }
        Feedback {
            stiffness,
            row_at,
            gjac: vec![0.0; blocks],
            n,
            d: vec![0.0; n],
            v: vec![0.0; n],
            g: vec![0.0; n],
            gu: vec![0.0; n],
            gv: vec![0.0; n],
            r: vec![0.0; n],
            trial: vec![0.0; n],
            step: vec![0.0; n],
            jac: vec![0.0; n * n],
            last_d: vec![0.0; n],
            last_v: vec![0.0; n],
        }
    }

    /// Residual `r = f − g(d(f), v(f))` into `self.r`; returns `‖r‖∞` and whether every
    /// component meets the tolerance.
    #[allow(clippy::too_many_arguments)]
    fn residual(
        &mut self,
        elements: &[ElementPort],
        states: &[Vec<f64>],
        d_pred: &[f64],
        v_pred: &[f64],
        sd: &[f64],
        sv: &[f64],
        f: &[f64],
        rtol: f64,
    ) -> (f64, bool) {
        let n = self.n;
        for i in 0..n {
            let (mut d, mut v) = (d_pred[i], v_pred[i]);
            for j in 0..n {
                d -= sd[i * n + j] * f[j];
                v -= sv[i * n + j] * f[j];
            }
            self.d[i] = d;
            self.v[i] = v;
        }
        let mut norm = 0.0f64;
        let mut ok = true;
        let mut i = 0;
        while i < n {
            let law = elements[i].element.law();
            let m = law.arity().max(1);
            if m == 1 {
                let e = law.eval(self.d[i], self.v[i], &states[i]);
                self.g[i] = e.force;
                self.gu[i] = e.df_du;
                self.gv[i] = e.df_dv;
            } else {
                let o = self.row_at[i];
                law.eval_coupled(
                    &self.d[i..i + m],
                    &mut self.g[i..i + m],
                    &mut self.gjac[o..o + m * m],
                );
            }
            for a in i..i + m {
                let (d, g) = (self.d[a], self.g[a]);
                let r = f[a] - g;
                self.r[a] = r;
                norm = norm.max(r.abs());
                // Force scale of the port's motion: its static stiffness times |u|. It keeps
                // the test meaningful where the element force itself vanishes (at a contact
                // kink).
                let floor = self.stiffness[a] * d.abs();
                let tol = rtol * (f[a].abs() + g.abs() + floor) + 1e-300;
                // NaN fails too.
                if r.abs().partial_cmp(&tol) != Some(std::cmp::Ordering::Less) && r.abs() != tol {
                    ok = false;
                }
            }
            i += m;
        }
        (norm, ok)
    }

    /// Solves the loop in place: `f` holds the initial guess and receives the solution.
    /// Returns the number of Newton iterations.
    #[allow(clippy::too_many_arguments)]
    pub fn solve(
        &mut self,
        elements: &[ElementPort],
        states: &[Vec<f64>],
        d_pred: &[f64],
        v_pred: &[f64],
        sd: &[f64],
        sv: &[f64],
        f: &mut [f64],
        cfg: &NewtonConfig,
    ) -> Result<usize, LoopFailure> {
        let n = self.n;
        if n == 0 {
            return Ok(0);
        }
        let (mut norm, mut ok) =
            self.residual(elements, states, d_pred, v_pred, sd, sv, f, cfg.rtol);
        let mut it = 0;
        while !ok {
            if it >= cfg.max_iterations || !norm.is_finite() {
                let worst = (0..n)
                    .max_by(|&a, &b| self.r[a].abs().total_cmp(&self.r[b].abs()))
                    .unwrap_or(0);
                return Err(LoopFailure {
                    iterations: it,
                    residual: norm,
                    element: worst,
                    displacement: self.d[worst],
                });
            }
            it += 1;
            // J = I + G_u S_d + G_v S_v (G diagonal but for the blocks of coupled laws, whose
            // velocity tangent is zero); solve J Δ = −r.
            for i in 0..n {
                let m = elements[i].element.law().arity();
                if m <= 1 {
                    for j in 0..n {
                        self.jac[i * n + j] = f64::from(u8::from(i == j))
                            + self.gu[i] * sd[i * n + j]
                            + self.gv[i] * sv[i * n + j];
                    }
                } else {
                    let s0 = i - elements[i].coordinate;
                    let row = &self.gjac[self.row_at[i]..self.row_at[i] + m];
                    for j in 0..n {
                        let mut x = f64::from(u8::from(i == j));
                        for (b, g) in row.iter().enumerate() {
                            x += g * sd[(s0 + b) * n + j];
                        }
                        self.jac[i * n + j] = x;
                    }
                }
                self.step[i] = -self.r[i];
            }
            if !dense_solve(&mut self.jac, &mut self.step, n) {
                // Singular tangent: fall back to the fixed-point update f ← g.
                for i in 0..n {
                    self.step[i] = -self.r[i];
                }
            }
            // Backtracking on ‖r‖∞.
            let mut alpha = 1.0;
            self.trial.copy_from_slice(f);
            loop {
                for i in 0..n {
                    f[i] = self.trial[i] + alpha * self.step[i];
                }
                let (nn, okn) =
                    self.residual(elements, states, d_pred, v_pred, sd, sv, f, cfg.rtol);
                if okn || nn <= (1.0 - 1e-4 * alpha) * norm || alpha < 1e-6 {
                    norm = nn;
                    ok = okn;
                    break;
                }
                alpha *= 0.5;
            }
        }
        self.last_d.copy_from_slice(&self.d);
        self.last_v.copy_from_slice(&self.v);
        Ok(it)
    }
}

/// Gaussian elimination with partial pivoting on a row-major `n × n` matrix; `false` when
/// singular.
pub(crate) fn dense_solve(a: &mut [f64], b: &mut [f64], n: usize) -> bool {
    if n == 1 {
        if a[0] == 0.0 || !a[0].is_finite() {
            return false;
        }
        b[0] /= a[0];
        return true;
    }
    for c in 0..n {
        let p = (c..n)
            .max_by(|&x, &y| a[x * n + c].abs().total_cmp(&a[y * n + c].abs()))
            .unwrap_or(c);
        if a[p * n + c] == 0.0 || !a[p * n + c].is_finite() {
            return false;
        }
        if p != c {
            for j in 0..n {
                a.swap(c * n + j, p * n + j);
            }
            b.swap(c, p);
        }
        for r in c + 1..n {
            let m = a[r * n + c] / a[c * n + c];
            for j in c..n {
                a[r * n + j] -= m * a[c * n + j];
            }
            b[r] -= m * b[c];
        }
    }
    for c in (0..n).rev() {
        let mut s = b[c];
        for j in c + 1..n {
            s -= a[c * n + j] * b[j];
        }
        b[c] = s / a[c * n + c];
    }
    true
}

#[cfg(test)]
mod tests {
    use super::dense_solve;

    #[test]
    fn dense_solve_pivots() {
        let mut a = vec![0.0, 2.0, 1.0, 1.0, 1.0, 0.0, 3.0, 0.0, 1.0];
        let x = [1.0, -2.0, 0.5];
        let mut b: Vec<f64> = (0..3)
            .map(|i| (0..3).map(|j| a[i * 3 + j] * x[j]).sum())
            .collect();
        assert!(dense_solve(&mut a, &mut b, 3));
        for i in 0..3 {
            assert!((b[i] - x[i]).abs() < 1e-14);
        }
    }
}
