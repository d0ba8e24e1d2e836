//! Many runs at once: load cases or parameter sets in parallel with rayon.
//!
//! Each case is integrated by one thread from start to end with no shared mutable state, so
//! the results are bit-identical whatever the number of threads, and come back in input order.

use crate::foh::Simulator;
use crate::history::{LoadCase, TimeHistory};
use nlsim_kernel::Result;
use rayon::prelude::*;

/// Runs every case for `n_steps` steps on the rayon thread pool (use
/// `rayon::ThreadPool::install` to choose the pool). One result per case, in order; a failing
/// case does not stop the others.
pub fn run_batch(sim: &Simulator, cases: &[LoadCase], n_steps: usize) -> Vec<Result<TimeHistory>> {
    cases.par_iter().map(|c| sim.run(c, n_steps)).collect()
}
