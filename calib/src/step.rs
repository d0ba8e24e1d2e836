//! One step of a stepped sine: the harmonic balance solve that follows a sweep from its
//! previous step, shared by the calibration objective, the planner and the shaker coupling.

use nlsim_hb::{HbSystem, HbWorkspace};
use nlsim_kernel::{Result, Status};

/// One step of a stepped sine on `sys` at `omega` (rad/s): Newton from the previous step's
/// solution `prev` (solution, frequency); else through four intermediate frequencies from
/// it; else from the linear response. The last iterate and how its solve ended.
pub(crate) fn solve_step(
    sys: &HbSystem,
    ws: &mut HbWorkspace,
    omega: f64,
    prev: Option<&(Vec<f64>, f64)>,
) -> Result<(Vec<f64>, Status)> {
    if let Some((x0, w0)) = prev {
        let mut x = x0.clone();
        if sys.solve_with(ws, omega, 1.0, &mut x)?.converged() {
            return Ok((x, Status::Converged));
        }
        x.copy_from_slice(x0);
        let mut ok = true;
        for j in 1..=4 {
            let w = w0 + (omega - w0) * j as f64 / 4.0;
            let mut xs = x.clone();
            if !sys.solve_with(ws, w, 1.0, &mut xs)?.converged() {
                ok = false;
                break;
            }
            x = xs;
        }
        if ok {
            return Ok((x, Status::Converged));
        }
    }
    let mut x = sys.linear_guess(omega, 1.0);
    let rep = sys.solve_with(ws, omega, 1.0, &mut x)?;
    Ok((x, rep.status))
}
