//! Forward sensitivities of the hold recursion to element law parameters (issue 45 part 4:
//! the Jacobian of a time-domain calibration without finite differences).
//!
//! The recursion of [`Simulator`] is linear in its inputs apart from the element forces,
//! which solve `f[k+1] = g(d_pred − S_d f[k+1], v_pred − S_v f[k+1]; p)` at every step. Its
//! derivative along a law parameter `p` is the same recursion driven by the force
//! sensitivities `δf = ∂f/∂p` alone (the external forces do not depend on `p`), with the loop
//! linearised at the run's own solution:
//!
//! `(I + G_u S_d + G_v S_v) δf[k+1] = G_u δd_pred + G_v δv_pred + ∂g/∂p`,
//!
//! `G_u = ∂g/∂u`, `G_v = ∂g/∂u̇` at the element displacements and velocities of step `k+1`,
//! `δd_pred`, `δv_pred` the state pass of the sensitivity states; the output sensitivities
//! follow as the outputs do. This is the exact derivative of the discrete map (thesis §3.1,
//! eq. 8 held in the sensitivities), so it agrees with central differences of the run to
//! their truncation error wherever no sample sits on a kink of a non-smooth law.
//!
//! Restrictions, refused by name: contact events located inside steps (the sub-steps move
//! with the parameters; build the simulator with [`super::FohConfig::locate_events`] off),
//! laws with internal state (hysteresis) and laws on several coordinates.

use super::{Block, Column, LANES, Simulator};
use crate::history::{LoadCase, TimeHistory};
use crate::hold::Hold;
use faer::c64;
use nlsim_kernel::{Error, Param, Result};

/// The output sensitivities of a run: `∂y_o[k]/∂p_j`.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputSensitivities {
    /// The parameters, in the order of [`OutputSensitivities::outputs`].
    pub params: Vec<Param>,
    /// `outputs[j][o][k] = ∂y_o(t_k)/∂p_j` (the output's unit per unit of the parameter), for
    /// every sample of the run (fewer than asked for when the run stopped short).
    pub outputs: Vec<Vec<Vec<f64>>>,
}

impl Simulator {
    /// Runs `case` as [`Simulator::run`] does and returns, with the history, the derivatives
    /// of every output sample along each of `params` (element law parameters,
    /// `Param::Element`), at the values of the case.
    ///
    /// Errors: a parameter that is not an element law parameter of the plant; contact-event
    /// location switched on for a plant with a clearance; an element whose law has internal
    /// state or acts on several coordinates; a singular linearised loop (named by step).
    pub fn run_with_sensitivities(
        &self,
        case: &LoadCase,
        n_steps: usize,
        params: &[Param],
    ) -> Result<(TimeHistory, OutputSensitivities)> {
        if self.cfg.locate_events && self.cfg.hold == Hold::Foh && self.plant.has_events() {
            return Err(Error::invalid(
                "output sensitivities",
                "contact events are located inside steps, whose sub-steps move with the \
                 parameters: build the simulator with event location off",
            ));
        }
        let (_, elements) = case.prepare(&self.plant)?;
        for e in &elements {
            let law = e.element.law();
            if law.n_states() > 0 || law.arity() > 1 {
                return Err(Error::invalid(
                    "output sensitivities",
                    format!(
                        "element '{}' ({}) {}: its sensitivities are not propagated",
                        e.element.name(),
                        law.kind(),
                        if law.n_states() > 0 {
                            "has internal state"
                        } else {
                            "acts on several coordinates"
                        }
                    ),
                ));
            }
        }
        // Each parameter: its law parameter index in the entries of its element.
        let mut which: Vec<(String, usize)> = Vec::with_capacity(params.len());
        for p in params {
            let Param::Element { element, param } = p else {
                return Err(Error::invalid(
                    "output sensitivities",
                    format!("{p} is not a parameter of an element law"),
                ));
            };
            let entry = elements
                .iter()
                .find(|e| e.element.name() == element)
                .ok_or_else(|| nlsim_kernel::param::unknown_param(p, &[]))?;
            let law = entry.element.law();
            let idx = (0..law.n_params())
                .find(|&i| law.param_name(i) == *param)
                .ok_or_else(|| nlsim_kernel::param::unknown_param(p, &[]))?;
            which.push((element.clone(), idx));
        }
        let h = self.run(case, n_steps)?;
        let n = h
            .element_forces
            .first()
            .map_or_else(|| h.outputs.first().map_or(0, |o| o.values.len()), Vec::len);
        let nn = elements.len();
        let ne = self.plant.inputs.len();
        let no = self.plant.outputs.len();
        let nr = self.resp.rows.len();
        let (ns, nb) = (self.ns, self.nblocks);
        // The loop's linearisation at every sample: G_u, G_v and ∂g/∂p per element.
        let nparam: Vec<usize> = elements
            .iter()
            .map(|e| e.element.law().n_params())
            .collect();
        let mut gu = vec![vec![0.0; n]; nn];
        let mut gv = vec![vec![0.0; n]; nn];
        let mut gp: Vec<Vec<Vec<f64>>> = (0..nn).map(|i| vec![vec![0.0; n]; nparam[i]]).collect();
        let mut buf = Vec::new();
        for i in 0..nn {
            let law = elements[i].element.law();
            buf.resize(nparam[i], 0.0);
            for k in 0..n {
                let (d, v) = (h.element_displacements[i][k], h.element_velocities[i][k]);
                let ev = law.eval(d, v, &[]);
                gu[i][k] = ev.df_du;
                gv[i][k] = ev.df_dv;
                law.dforce_dparams(d, v, &[], &mut buf);
                for (q, &b) in buf.iter().enumerate() {
                    gp[i][q][k] = b;
                }
            }
        }
        let mut sens = Vec::with_capacity(params.len());
        let mut a = vec![0.0; nn * nn];
        let mut rhs = vec![0.0; nn];
        let mut vals = vec![0.0; self.cols.len()];
        let mut acc = vec![[0.0; LANES]; self.n_kernel_rows];
        let mut rp = vec![0.0; nr];
        for (element, idx) in &which {
            let dgp = |i: usize, k: usize| -> f64 {
                if elements[i].element.name() == element {
                    gp[i][*idx][k]
                } else {
                    0.0
                }
            };
            let mut df = vec![vec![0.0; n]; nn];
            let mut out = vec![vec![0.0; n]; no];
            // The linearised loop at sample k with the predicted sensitivities `pd`, `pv`.
            let mut solve_loop = |k: usize,
                                  sd: &[f64],
                                  sv: &[f64],
                                  pd: &[f64],
                                  pv: &[f64],
                                  df: &mut [Vec<f64>]|
             -> Result<()> {
                for i in 0..nn {
                    for m in 0..nn {
                        a[i * nn + m] = f64::from(u8::from(i == m))
                            + gu[i][k] * sd[i * nn + m]
                            + gv[i][k] * sv[i * nn + m];
                    }
                    rhs[i] = gu[i][k] * pd[i] + gv[i][k] * pv[i] + dgp(i, k);
                }
                if !crate::feedback::dense_solve(&mut a, &mut rhs, nn) {
                    return Err(Error::Numerical {
                        what: format!("output sensitivities at step {k}"),
                        detail: "the linearised element loop is singular".into(),
                    });
                }
                for i in 0..nn {
                    df[i][k] = rhs[i];
                }
                Ok(())
            };
            // t = 0: the states do not depend on p; the feedthrough loop only.
            let zero = vec![0.0; nn];
            solve_loop(0, &self.resp.sd0, &self.resp.sv0, &zero, &zero, &mut df)?;
            let mut u = vec![0.0; ne + nn];
            for i in 0..nn {
                u[ne + i] = -df[i][0];
            }
            for (o, series) in out.iter_mut().enumerate() {
                series[0] = self.resp.feed(2 * nn + o, &u);
            }
            // δẑ0 = Γ1 b̃ δf0.
            let mut zr = vec![[0.0; LANES]; nb];
            let mut zi = vec![[0.0; LANES]; nb];
            for s in 0..ns {
                let mut z = c64::new(0.0, 0.0);
                for i in 0..nn {
                    z += self.g1n[s * nn + i] * df[i][0];
                }
                zr[s / LANES][s % LANES] = z.re;
                zi[s / LANES][s % LANES] = z.im;
            }
            let mut zr2: Vec<Block> = zr.clone();
            let mut zi2: Vec<Block> = zi.clone();
            let (mut pd, mut pv) = (vec![0.0; nn], vec![0.0; nn]);
            for k in 0..n.saturating_sub(1) {
                for (c, col) in self.cols.iter().enumerate() {
                    vals[c] = match *col {
                        Column::Input(..) => 0.0,
                        Column::Element(i, j) => -df[i][(k as i64 + j as i64).max(0) as usize],
                    };
                }
                self.state_pass(&zr, &zi, &mut zr2, &mut zi2, &vals, &mut acc, &mut rp);
                pd.copy_from_slice(&rp[..nn]);
                pv.copy_from_slice(&rp[nn..2 * nn]);
                solve_loop(k + 1, &self.sd, &self.sv, &pd, &pv, &mut df)?;
                for i in 0..nn {
                    u[ne + i] = -df[i][k + 1];
                }
                for (o, series) in out.iter_mut().enumerate() {
                    let r = 2 * nn + o;
                    let mut y = rp[r] + self.resp.feed(r, &u);
                    for i in 0..nn {
                        y += self.corr[r * nn + i] * u[ne + i];
                    }
                    series[k + 1] = y;
                }
                std::mem::swap(&mut zr, &mut zr2);
                std::mem::swap(&mut zi, &mut zi2);
            }
            // The residual flexibility's rate terms of the element forces' sensitivities, as
            // the run adds those of the forces.
            let forces: Vec<Vec<f64>> = (0..ne)
                .map(|_| Vec::new())
                .chain(df.iter().map(|g| g.iter().map(|x| -x).collect()))
                .collect();
            let mut outs: Vec<&mut [f64]> = out.iter_mut().map(|v| v.as_mut_slice()).collect();
            crate::history::residual_rates(
                &self.plant,
                &forces,
                self.cfg.dt,
                &mut outs,
                crate::history::RateTerms::Run,
            );
            sens.push(out);
        }
        Ok((
            h,
            OutputSensitivities {
                params: params.to_vec(),
                outputs: sens,
            },
        ))
    }
}
