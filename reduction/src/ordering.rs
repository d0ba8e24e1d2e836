//! Fill-reducing orderings of the pencil's pattern: approximate minimum degree (faer's AMD) and
//! nested dissection (METIS 5, through `metis-sys`, built from its vendored C sources).
//!
//! On the 3-D solid meshes the project is for, nested dissection leaves about half the fill of
//! AMD in the Cholesky factor (the factor of a 3-D grid of `n` nodes holds `O(n^{4/3})` values
//! either way, with a smaller constant for dissection); on thin or 1-D-like structures AMD wins.
//! [`Ordering::Auto`] analyses both and keeps the one whose factor is predicted to be smaller:
//! the prediction is exact (the symbolic analysis counts the factor's values), so the choice costs
//! two symbolic analyses and never a numeric factorisation.

use nlsim_kernel::{Error, Result};

/// Which fill-reducing ordering the symbolic analysis of `K − σM` uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Ordering {
    /// Both orderings analysed; the one with the fewer factor values is kept (default). AMD
    /// alone when nested dissection fails (METIS out of memory, or a graph beyond its 32-bit
    /// indices).
    #[default]
    Auto,
    /// Approximate minimum degree (faer).
    Amd,
    /// Nested dissection (METIS `NodeND`, fixed seed: the same ordering on every run).
    NestedDissection,
}

impl Ordering {
    /// Short name (`auto`, `amd`, `nd`), as the command line spells it.
    pub fn name(self) -> &'static str {
        match self {
            Ordering::Auto => "auto",
            Ordering::Amd => "amd",
            Ordering::NestedDissection => "nd",
        }
    }

    /// Parses [`Ordering::name`]'s spelling (`nested-dissection`, `metis` are also taken).
    pub fn parse(s: &str) -> Option<Ordering> {
        match s {
            "auto" => Some(Ordering::Auto),
            "amd" => Some(Ordering::Amd),
            "nd" | "nested-dissection" | "metis" => Some(Ordering::NestedDissection),
            _ => None,
        }
    }
}

/// The seed METIS draws its random matchings from (fixed: orderings are reproducible).
const METIS_SEED: i32 = 20_161_024;

/// Nested-dissection ordering of the graph of a symmetric pattern given by its lower triangle
/// (`col_ptr`, `row_idx`, compressed columns, diagonal allowed). Returns `(forward, inverse)`
/// with `forward[new] = old` (faer's and AMD's convention), or `Ok(None)` when the graph has
/// more edges than METIS's 32-bit indices hold (the caller then keeps AMD).
pub(crate) fn nested_dissection(
    n: usize,
    col_ptr: &[usize],
    row_idx: &[usize],
) -> Result<Option<(Vec<usize>, Vec<usize>)>> {
    if n == 0 {
        return Ok(Some((Vec::new(), Vec::new())));
    }
    // Degrees of the full symmetric graph without self loops.
    let mut degree = vec![0usize; n];
    for j in 0..n {
        for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
            if i != j {
                degree[i] += 1;
                degree[j] += 1;
            }
        }
    }
    let edges: usize = degree.iter().sum();
    if n > i32::MAX as usize || edges > i32::MAX as usize {
        return Ok(None);
    }
    let mut xadj = Vec::new();
    let mut adjncy = Vec::new();
    xadj.try_reserve_exact(n + 1)
        .and_then(|_| adjncy.try_reserve_exact(edges))
        .map_err(|_| Error::Numerical {
            what: "nested-dissection ordering".into(),
            detail: format!("out of memory for a graph of {n} vertices and {edges} edge ends"),
        })?;
    xadj.push(0i32);
    let mut acc = 0usize;
    for &d in &degree {
        acc += d;
        xadj.push(acc as i32);
    }
    adjncy.resize(edges, 0i32);
    // next[v] = next free slot of vertex v's list.
    let mut next: Vec<usize> = xadj[..n].iter().map(|&x| x as usize).collect();
    drop(degree);
    for j in 0..n {
        for &i in &row_idx[col_ptr[j]..col_ptr[j + 1]] {
            if i != j {
                adjncy[next[i]] = j as i32;
                next[i] += 1;
                adjncy[next[j]] = i as i32;
                next[j] += 1;
            }
        }
    }
    drop(next);
    let mut perm = vec![0i32; n];
    let mut iperm = vec![0i32; n];
    let status = node_nd(&mut xadj, &mut adjncy, &mut perm, &mut iperm);
    if status != metis_sys::rstatus_et_METIS_OK {
        return Err(Error::Numerical {
            what: "nested-dissection ordering (METIS_NodeND)".into(),
            detail: format!(
                "METIS returned status {status} ({}) on a graph of {n} vertices and {} edges",
                match status {
                    metis_sys::rstatus_et_METIS_ERROR_MEMORY => "out of memory",
                    metis_sys::rstatus_et_METIS_ERROR_INPUT => "invalid input",
                    _ => "error",
                },
                edges / 2
            ),
        });
    }
    // METIS: perm[new] = old, iperm[old] = new.
    let forward: Vec<usize> = perm.iter().map(|&p| p as usize).collect();
    let inverse: Vec<usize> = iperm.iter().map(|&p| p as usize).collect();
    let valid = forward.len() == n
        && forward
            .iter()
            .enumerate()
            .all(|(k, &old)| old < n && inverse[old] == k);
    if !valid {
        return Err(Error::Numerical {
            what: "nested-dissection ordering (METIS_NodeND)".into(),
            detail: "METIS returned arrays that are not inverse permutations".into(),
        });
    }
    Ok(Some((forward, inverse)))
}

/// METIS draws from one random-number state for the whole process (GKlib's Mersenne twister
/// is a plain `static`): two calls at once would interleave their draws and give orderings
/// that depend on timing. Calls are serialised, each reseeding first: the same ordering for
/// the same graph, whatever runs beside it.
static METIS_LOCK: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// One call of `METIS_NodeND` with default options but a fixed seed.
#[allow(unsafe_code)]
fn node_nd(xadj: &mut [i32], adjncy: &mut [i32], perm: &mut [i32], iperm: &mut [i32]) -> i32 {
    // A panic elsewhere while holding the lock leaves no METIS state behind: take it anyway.
    let _serial = METIS_LOCK
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner);
    let mut nvtxs = perm.len() as i32;
    debug_assert_eq!(xadj.len(), perm.len() + 1);
    debug_assert_eq!(iperm.len(), perm.len());
    debug_assert_eq!(xadj[perm.len()] as usize, adjncy.len());
    let mut options = [0i32; metis_sys::METIS_NOPTIONS as usize];
    // SAFETY: `options` has METIS_NOPTIONS entries, as METIS_SetDefaultOptions writes.
    unsafe {
        metis_sys::METIS_SetDefaultOptions(options.as_mut_ptr());
    }
    options[metis_sys::moptions_et_METIS_OPTION_SEED as usize] = METIS_SEED;
    options[metis_sys::moptions_et_METIS_OPTION_NUMBERING as usize] = 0;
    // SAFETY: the graph is a valid CSR graph of `nvtxs` vertices (xadj has nvtxs + 1 entries
    // ending at adjncy.len(), every adjacency entry is a vertex index below nvtxs and no vertex
    // lists itself); perm and iperm have nvtxs entries; a null vertex-weight pointer means unit
    // weights. METIS reads the graph and writes only perm and iperm.
    unsafe {
        metis_sys::METIS_NodeND(
            &mut nvtxs,
            xadj.as_mut_ptr(),
            adjncy.as_mut_ptr(),
            core::ptr::null_mut(),
            options.as_mut_ptr(),
            perm.as_mut_ptr(),
            iperm.as_mut_ptr(),
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Lower pattern of a 5-point Laplacian on a `g × g` grid.
    fn grid(g: usize) -> (usize, Vec<usize>, Vec<usize>) {
        let n = g * g;
        let mut cp = vec![0];
        let mut ri = Vec::new();
        for j in 0..n {
            let (x, y) = (j % g, j / g);
            ri.push(j);
            if x + 1 < g {
                ri.push(j + 1);
            }
            if y + 1 < g {
                ri.push(j + g);
            }
            cp.push(ri.len());
        }
        (n, cp, ri)
    }

    #[test]
    fn nested_dissection_is_a_reproducible_permutation() {
        let (n, cp, ri) = grid(40);
        let (f, i) = nested_dissection(n, &cp, &ri).unwrap().unwrap();
        for (k, &old) in f.iter().enumerate() {
            assert_eq!(i[old], k);
        }
        let (f2, _) = nested_dissection(n, &cp, &ri).unwrap().unwrap();
        assert_eq!(f, f2, "same seed, same ordering");
        // METIS's random state is process-wide: calls from several threads at once must not
        // disturb each other.
        let orders: Vec<Vec<usize>> = std::thread::scope(|s| {
            let handles: Vec<_> = (0..4)
                .map(|_| s.spawn(|| nested_dissection(n, &cp, &ri).unwrap().unwrap().0))
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        for o in &orders {
            assert_eq!(o, &f);
        }
    }
}
