//! nlsim benchmarks live in `benches/`; this library holds what they share.
//!
//! Run one with `cargo bench -p nlsim-bench --bench kernel -- --quick --noplot`.

/// Bracket refinements the kernel bench assembles: about 4.7·10³ and 3.1·10⁴ DOFs.
pub const BRACKET_REFINEMENTS: [usize; 2] = [2, 4];
