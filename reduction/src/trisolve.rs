//! `(L Lᵀ) X = B` with a supernodal Cholesky factor and a block of a few right-hand sides: the
//! solve of every shift-invert Lanczos step.
//!
//! faer's own supernodal solve calls a dense triangular solve and a dense product per
//! supernode; with six right-hand sides the product packs each block of `L` before using it,
//! and with more than one thread it hands every small product to the pool. This solve reads
//! each column of `L` once per sweep and applies it to a row-major copy of the block (the six
//! values of a row are contiguous), which is what a memory-bound sweep can do best.
//!
//! **Parallel and deterministic.** Below the top of the elimination tree, the subtrees of the
//! first node with more than one child are independent. In the forward sweep each subtree
//! solves its own rows and collects its updates to the rows above it (the top chain's) in a
//! buffer of its own; the buffers are subtracted in subtree order before the top chain is
//! solved. The backward sweep solves the top chain, then the subtrees, which only read it. The
//! arithmetic is fixed by the tree, not by the number of threads, so any thread count gives the
//! same bits. Where the subtrees do not occupy contiguous columns (an ordering that is not
//! post-ordered), the whole tree is swept as one.

use std::ops::Range;

use faer::reborrow::{Reborrow, ReborrowMut};
use faer::sparse::linalg::cholesky::supernodal::SymbolicSupernodalCholesky;
use faer::{MatMut, Par};
use pulp::{Arch, Simd, WithSimd};

/// Right-hand sides per sweep: wider blocks are solved in groups of this many columns.
const MAX_BLOCK: usize = 8;

/// A subtree of supernodes `supernodes` owning the columns `cols`.
#[derive(Debug, Clone)]
struct Task {
    supernodes: Range<usize>,
    cols: Range<usize>,
}

/// How the elimination tree is split: independent subtrees, then the top chain above them.
/// Made once per symbolic analysis ([`split`]).
#[derive(Debug, Clone)]
pub(crate) struct Split {
    tasks: Vec<Task>,
    /// The top chain: supernodes and columns, swept after the tasks (forward) or before them
    /// (backward).
    top: Task,
}

/// Splits the supernodal elimination tree at its first node with more than one child.
pub(crate) fn split(sym: &SymbolicSupernodalCholesky<usize>) -> Split {
    let ns = sym.n_supernodes();
    let n = sym.nrows();
    let begin = sym.supernode_begin();
    let end = sym.supernode_end();
    let whole = Split {
        tasks: Vec::new(),
        top: Task {
            supernodes: 0..ns,
            cols: 0..n,
        },
    };
    if ns < 2 {
        return whole;
    }
    // Parent of each supernode: the one holding its first off-diagonal row.
    let mut parent = vec![usize::MAX; ns];
    let mut size = vec![1usize; ns];
    for s in 0..ns {
        let pattern = sym.supernode(s).pattern();
        if let Some(&row) = pattern.first() {
            let p = end.partition_point(|&e| e <= row);
            if p <= s || p >= ns {
                return whole;
            }
            parent[s] = p;
        }
    }
    for s in 0..ns {
        if parent[s] != usize::MAX {
            size[parent[s]] += size[s];
        }
    }
    // Walk down from the root while the tree is a chain.
    let roots: Vec<usize> = (0..ns).filter(|&s| parent[s] == usize::MAX).collect();
    let mut frontier = roots;
    let mut chain = Vec::new();
    while frontier.len() == 1 {
        let r = frontier[0];
        chain.push(r);
        frontier = (0..r).filter(|&s| parent[s] == r).collect();
    }
    if frontier.len() < 2 {
        return whole;
    }
    // Each subtree must be the contiguous run of supernodes ending at its root (post-order),
    // the runs must tile the supernodes below the chain, and the chain must follow them.
    let mut tasks = Vec::with_capacity(frontier.len());
    let mut next = 0;
    for &r in &frontier {
        let first = r + 1 - size[r];
        if first != next {
            return whole;
        }
        tasks.push(Task {
            supernodes: first..r + 1,
            cols: begin[first]..end[r],
        });
        next = r + 1;
    }
    let top_first = next;
    let mut chain_sorted = chain.clone();
    chain_sorted.sort_unstable();
    if chain_sorted != (top_first..ns).collect::<Vec<_>>() {
        return whole;
    }
    Split {
        tasks,
        top: Task {
            supernodes: top_first..ns,
            cols: if top_first < ns { begin[top_first] } else { n }..n,
        },
    }
}

impl Split {
    /// Number of subtrees the sweeps run independently (1: the tree is swept as one).
    #[cfg(test)]
    pub(crate) fn subtrees(&self) -> usize {
        self.tasks.len().max(1)
    }
}

/// Solves `L Lᵀ X = B` in place for a supernodal factor `values` of `sym` (its tree split by
/// [`split`]), whose analysis put row `fwd[i]` of the original order at `i` (`None`:
/// identity). `par` runs the subtrees of the elimination tree in parallel; the result is the
/// same for any `par`.
pub(crate) fn solve_llt(
    sym: &SymbolicSupernodalCholesky<usize>,
    tree: &Split,
    perm: Option<&[usize]>,
    values: &[f64],
    mut rhs: MatMut<'_, f64>,
    par: Par,
) {
    let n = sym.nrows();
    debug_assert_eq!(rhs.nrows(), n);
    if n == 0 || rhs.ncols() == 0 {
        return;
    }
    let mut c0 = 0;
    while c0 < rhs.ncols() {
        let b = (rhs.ncols() - c0).min(MAX_BLOCK);
        let block = rhs.rb_mut().subcols_mut(c0, b);
        match b {
            1 => solve_block::<1>(sym, tree, perm, values, block, par),
            2 => solve_block::<2>(sym, tree, perm, values, block, par),
            3 => solve_block::<3>(sym, tree, perm, values, block, par),
            4 => solve_block::<4>(sym, tree, perm, values, block, par),
            5 => solve_block::<5>(sym, tree, perm, values, block, par),
            6 => solve_block::<6>(sym, tree, perm, values, block, par),
            7 => solve_block::<7>(sym, tree, perm, values, block, par),
            _ => solve_block::<8>(sym, tree, perm, values, block, par),
        }
        c0 += b;
    }
}

/// The rows below the top chain cut into each subtree's own (they tile them in order).
fn subtrees_of<'t, 'x, const B: usize>(
    tasks: &'t [Task],
    mut rest: &'x mut [[f64; B]],
) -> Vec<(&'t Task, &'x mut [[f64; B]])> {
    let mut pieces = Vec::with_capacity(tasks.len());
    for t in tasks {
        let (mine, after) = rest.split_at_mut(t.cols.end - t.cols.start);
        pieces.push((t, mine));
        rest = after;
    }
    pieces
}

/// `f` on every item, in parallel or in order; each item's work does not depend on which.
fn for_each<T: Send>(items: &mut [T], parallel: bool, f: impl Fn(&mut T) + Sync + Send) {
    if parallel {
        use rayon::prelude::*;
        items.par_iter_mut().for_each(f);
    } else {
        items.iter_mut().for_each(f);
    }
}

fn solve_block<const B: usize>(
    sym: &SymbolicSupernodalCholesky<usize>,
    tree: &Split,
    perm: Option<&[usize]>,
    values: &[f64],
    mut rhs: MatMut<'_, f64>,
    par: Par,
) {
    let n = sym.nrows();
    // Row-major, permuted copy: x[i] = rhs[fwd[i]].
    let mut x = vec![[0.0f64; B]; n];
    for c in 0..rhs.ncols() {
        let col = rhs.rb().col(c);
        match perm {
            Some(fwd) => {
                for (xi, &f) in x.iter_mut().zip(fwd) {
                    xi[c] = col[f];
                }
            }
            None => {
                for (i, xi) in x.iter_mut().enumerate() {
                    xi[c] = col[i];
                }
            }
        }
    }
    let arch = Arch::new();
    let parallel = par.degree() > 1 && tree.tasks.len() > 1;

    // Forward: the subtrees (each collecting its updates to the top chain's rows), then the
    // collected updates in subtree order, then the top chain.
    let top_lo = tree.top.cols.start;
    {
        let (below, top) = x.split_at_mut(top_lo);
        let mut pieces: Vec<_> = subtrees_of(&tree.tasks, below)
            .into_iter()
            .map(|(t, mine)| (t, mine, vec![[0.0f64; B]; n - top_lo]))
            .collect();
        for_each(&mut pieces, parallel, |(t, mine, buf)| {
            arch.dispatch(Forward {
                sym,
                values,
                supernodes: t.supernodes.clone(),
                x: mine,
                lo: t.cols.start,
                hi: t.cols.end,
                out: buf,
                out_lo: top_lo,
            })
        });
        for (_, _, buf) in &pieces {
            for (xi, u) in top.iter_mut().zip(buf) {
                for k in 0..B {
                    xi[k] -= u[k];
                }
            }
        }
        arch.dispatch(Forward {
            sym,
            values,
            supernodes: tree.top.supernodes.clone(),
            x: top,
            lo: top_lo,
            hi: n,
            out: &mut [],
            out_lo: n,
        });
    }

    // Backward: the top chain, then the subtrees, which read it.
    {
        let (below, top) = x.split_at_mut(top_lo);
        arch.dispatch(Backward {
            sym,
            values,
            supernodes: tree.top.supernodes.clone(),
            x: top,
            lo: top_lo,
            hi: n,
            above: &[],
            above_lo: n,
        });
        let top: &[[f64; B]] = top;
        let mut pieces = subtrees_of(&tree.tasks, below);
        for_each(&mut pieces, parallel, |(t, mine)| {
            arch.dispatch(Backward {
                sym,
                values,
                supernodes: t.supernodes.clone(),
                x: mine,
                lo: t.cols.start,
                hi: t.cols.end,
                above: top,
                above_lo: top_lo,
            })
        });
    }

    // rhs[fwd[i]] = x[i].
    for c in 0..rhs.ncols() {
        let mut col = rhs.rb_mut().col_mut(c);
        match perm {
            Some(fwd) => {
                for (xi, &f) in x.iter().zip(fwd) {
                    col[f] = xi[c];
                }
            }
            None => {
                for (i, xi) in x.iter().enumerate() {
                    col[i] = xi[c];
                }
            }
        }
    }
}

/// Columns of `L` applied together: each row of the block is loaded and stored once per group
/// instead of once per column.
const GROUP: usize = 8;

/// Columns per group in the backward sweep (its accumulators stay in registers).
const BACK_GROUP: usize = 3;

/// `L y = b` over `supernodes` (ascending). Rows `lo..hi` are `x` (solved in place); updates to
/// rows at or above `out_lo` (outside the subtree) are added to `out` instead, for the caller
/// to subtract.
struct Forward<'a, const B: usize> {
    sym: &'a SymbolicSupernodalCholesky<usize>,
    values: &'a [f64],
    supernodes: Range<usize>,
    x: &'a mut [[f64; B]],
    lo: usize,
    hi: usize,
    out: &'a mut [[f64; B]],
    out_lo: usize,
}

/// One supernode's columns `f..f + w` of `L` (column-major, leading dimension `ld`), its
/// off-diagonal rows `pattern`, of which the first `inside` lie in the swept rows.
struct Node<'a> {
    ls: &'a [f64],
    ld: usize,
    f: usize,
    w: usize,
    pattern: &'a [usize],
    inside: usize,
}

impl<'a> Node<'a> {
    /// Supernode `s` of the factor `values`, swept over rows below `hi`.
    #[inline(always)]
    fn new(
        sym: &'a SymbolicSupernodalCholesky<usize>,
        values: &'a [f64],
        s: usize,
        hi: usize,
    ) -> Self {
        let f = sym.supernode_begin()[s];
        let w = sym.supernode_end()[s] - f;
        let pattern = sym.supernode(s).pattern();
        let val_ptr = sym.col_ptr_for_val();
        Node {
            ls: &values[val_ptr[s]..val_ptr[s + 1]],
            ld: w + pattern.len(),
            f,
            w,
            pattern,
            inside: pattern.partition_point(|&i| i < hi),
        }
    }
}

impl<const B: usize> WithSimd for Forward<'_, B> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let Self {
            sym,
            values,
            supernodes,
            x,
            lo,
            hi,
            out,
            out_lo,
        } = self;
        for s in supernodes {
            let node = Node::new(sym, values, s, hi);
            let w = node.w;
            let mut c = 0;
            while c + GROUP <= w {
                forward_group::<B, GROUP>(&node, c, x, lo, out, out_lo);
                c += GROUP;
            }
            while c < w {
                forward_group::<B, 1>(&node, c, x, lo, out, out_lo);
                c += 1;
            }
        }
    }
}

/// Forward substitution for the columns `c..c + G` of one supernode, then their updates to the
/// rows below them.
#[inline(always)]
fn forward_group<const B: usize, const G: usize>(
    node: &Node<'_>,
    c: usize,
    x: &mut [[f64; B]],
    lo: usize,
    out: &mut [[f64; B]],
    out_lo: usize,
) {
    let Node {
        ls,
        ld,
        f,
        w,
        pattern,
        inside,
    } = *node;
    let cols: [&[f64]; G] = core::array::from_fn(|j| &ls[(c + j) * ld..(c + j + 1) * ld]);
    // The small triangle.
    let mut xs = [[0.0f64; B]; G];
    for j in 0..G {
        let mut v = x[f + c + j - lo];
        for jj in 0..j {
            let l = cols[jj][c + j];
            for k in 0..B {
                v[k] = (-l).mul_add(xs[jj][k], v[k]);
            }
        }
        let d = cols[j][c + j];
        for v in v.iter_mut() {
            *v /= d;
        }
        xs[j] = v;
        x[f + c + j - lo] = v;
    }
    // Rows of the diagonal block below the group.
    for r in c + G..w {
        let y = &mut x[f + r - lo];
        for j in 0..G {
            let l = cols[j][r];
            for k in 0..B {
                y[k] = (-l).mul_add(xs[j][k], y[k]);
            }
        }
    }
    // Off-diagonal rows in the sweep, then outside it.
    let np = pattern.len();
    let (pin, pout) = pattern.split_at(inside);
    let bin: [&[f64]; G] = core::array::from_fn(|j| &cols[j][w..w + inside]);
    let bout: [&[f64]; G] = core::array::from_fn(|j| &cols[j][w + inside..w + np]);
    for (p, &i) in pin.iter().enumerate() {
        let y = &mut x[i - lo];
        for j in 0..G {
            let l = bin[j][p];
            for k in 0..B {
                y[k] = (-l).mul_add(xs[j][k], y[k]);
            }
        }
    }
    for (p, &i) in pout.iter().enumerate() {
        let y = &mut out[i - out_lo];
        for j in 0..G {
            let l = bout[j][p];
            for k in 0..B {
                y[k] = l.mul_add(xs[j][k], y[k]);
            }
        }
    }
}

/// `Lᵀ x = y` over `supernodes` (descending). Rows `lo..hi` are `x`; rows at or above
/// `above_lo` are read from `above` (already solved).
struct Backward<'a, const B: usize> {
    sym: &'a SymbolicSupernodalCholesky<usize>,
    values: &'a [f64],
    supernodes: Range<usize>,
    x: &'a mut [[f64; B]],
    lo: usize,
    hi: usize,
    above: &'a [[f64; B]],
    above_lo: usize,
}

impl<const B: usize> WithSimd for Backward<'_, B> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, _simd: S) {
        let Self {
            sym,
            values,
            supernodes,
            x,
            lo,
            hi,
            above,
            above_lo,
        } = self;
        for s in supernodes.rev() {
            let node = Node::new(sym, values, s, hi);
            let w = node.w;
            // The same groups as the forward sweep, last first.
            let mut c = w;
            let tail = w % BACK_GROUP;
            for _ in 0..tail {
                c -= 1;
                backward_group::<B, 1>(&node, c, x, lo, above, above_lo);
            }
            while c > 0 {
                c -= BACK_GROUP;
                backward_group::<B, BACK_GROUP>(&node, c, x, lo, above, above_lo);
            }
        }
    }
}

/// Back substitution for the columns `c..c + G` of one supernode: their dot products with the
/// solved rows below them, then the small triangle.
#[inline(always)]
fn backward_group<const B: usize, const G: usize>(
    node: &Node<'_>,
    c: usize,
    x: &mut [[f64; B]],
    lo: usize,
    above: &[[f64; B]],
    above_lo: usize,
) {
    let Node {
        ls,
        ld,
        f,
        w,
        pattern,
        inside,
    } = *node;
    let cols: [&[f64]; G] = core::array::from_fn(|j| &ls[(c + j) * ld..(c + j + 1) * ld]);
    let mut acc = [[0.0f64; B]; G];
    for r in c + G..w {
        let y = &x[f + r - lo];
        for j in 0..G {
            let l = cols[j][r];
            for k in 0..B {
                acc[j][k] = l.mul_add(y[k], acc[j][k]);
            }
        }
    }
    let np = pattern.len();
    let (pin, pout) = pattern.split_at(inside);
    let bin: [&[f64]; G] = core::array::from_fn(|j| &cols[j][w..w + inside]);
    let bout: [&[f64]; G] = core::array::from_fn(|j| &cols[j][w + inside..w + np]);
    for (p, &i) in pin.iter().enumerate() {
        let y = &x[i - lo];
        for j in 0..G {
            let l = bin[j][p];
            for k in 0..B {
                acc[j][k] = l.mul_add(y[k], acc[j][k]);
            }
        }
    }
    for (p, &i) in pout.iter().enumerate() {
        let y = &above[i - above_lo];
        for j in 0..G {
            let l = bout[j][p];
            for k in 0..B {
                acc[j][k] = l.mul_add(y[k], acc[j][k]);
            }
        }
    }
    // The small triangle, last column first.
    let mut xs = [[0.0f64; B]; G];
    for j in (0..G).rev() {
        let mut v = x[f + c + j - lo];
        for k in 0..B {
            v[k] -= acc[j][k];
        }
        for jj in j + 1..G {
            let l = cols[j][c + jj];
            for k in 0..B {
                v[k] = (-l).mul_add(xs[jj][k], v[k]);
            }
        }
        let d = cols[j][c + j];
        for v in v.iter_mut() {
            *v /= d;
        }
        xs[j] = v;
        x[f + c + j - lo] = v;
    }
}
