//! The Lanczos options that every command with a reduction takes (`--basis`, `--restarts`,
//! `--ordering`, `--memory-budget`).

use clap::Args;

/// The Lanczos settings of a run's reduction (as `nlsim modes --basis --restarts`): what the
/// eigensolver advises when modes do not converge.
#[derive(Args, Debug)]
pub struct LanczosArgs {
    /// Lanczos basis size before a restart (default max(2 k, k + 4 block) for k modes).
    #[arg(long)]
    pub basis: Option<usize>,
    /// Most Lanczos restarts before giving up.
    #[arg(long, default_value_t = 200)]
    pub restarts: usize,
    /// Fill-reducing ordering of the sparse factor: auto (the fewer factor values of amd and
    /// nd), amd (approximate minimum degree) or nd (METIS nested dissection).
    #[arg(long, default_value = "auto", value_parser = parse_ordering)]
    pub ordering: nlsim_reduction::Ordering,
    /// Memory the sparse factors may take together (GB); above it the Sturm check reuses the
    /// operator factor's storage, and the Lanczos iteration keeps no `M V` beside its basis
    /// unless that fits too. Default: half the memory available at start.
    #[arg(long, value_name = "GB")]
    pub memory_budget: Option<f64>,
}

/// `--ordering`: a fill-reducing ordering by name.
pub fn parse_ordering(s: &str) -> Result<nlsim_reduction::Ordering, String> {
    nlsim_reduction::Ordering::parse(s)
        .ok_or_else(|| format!("'{s}' is not an ordering (auto, amd or nd)"))
}

impl LanczosArgs {
    /// The Lanczos settings these arguments ask for; `Err` for a memory budget that is not
    /// a positive number of GB.
    pub fn settings(&self) -> Result<crate::commands::setup::Lanczos, crate::Error> {
        let memory_budget = match self.memory_budget {
            Some(gb) if gb.is_finite() && gb > 0.0 => Some((gb * 1e9) as usize),
            Some(gb) => {
                return Err(crate::Error::Usage(format!(
                    "--memory-budget {gb}: give a positive number of GB"
                )));
            }
            None => crate::formats::files::default_memory_budget(),
        };
        Ok(crate::commands::setup::Lanczos {
            basis: self.basis,
            restarts: self.restarts,
            ordering: self.ordering,
            memory_budget,
        })
    }
}
