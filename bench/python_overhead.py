"""The Python package's overhead, measured in one run (BENCHMARKS.md, "Python").

1. A harmonic-balance point through Python against the library call inside it: `Balance.solve`
   from the previous point along a stepped sweep; the call's wall time in Python
   (`time.perf_counter` around it: argument checks, the GIL released and taken back, the
   result's arrays) against `BalancePoint.seconds` (the Rust Newton solve alone, measured
   inside the same call). Median over the points.
2. A 10^5-DOF model passed in as scipy.sparse: the resident memory `from_matrices` adds (peak
   and after) against one copy of the CSR values and indices as nlsim keeps them (8 bytes a
   value, 8 an index), and whether the Python side copied the arrays (`np.shares_memory`).

Run from the repository's root after `pip install ./python[scipy]`:
    python bench/python_overhead.py
"""

from __future__ import annotations

import resource
import statistics
import time

import numpy as np
import scipy.sparse as sp

import nlsim


def rss_mb() -> float:
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    return float("nan")


def hb_point(name: str, lo: float, hi: float, points: int, harmonics: int = 7) -> None:
    model = nlsim.load(name)
    bal = nlsim.Balance(model, harmonics=harmonics, modes=20, threads=1)
    freqs = np.linspace(lo, hi, points)
    p = bal.solve(float(freqs[0]))
    wall, inner = [], []
    for f in freqs[1:]:
        t = time.perf_counter()
        p = bal.solve(float(f), start=p.x)
        wall.append(time.perf_counter() - t)
        inner.append(p.seconds)
        assert p.status == "converged", (f, p)
    w, r = statistics.median(wall), statistics.median(inner)
    print(
        f"hb point {name}: {bal.n_unknowns} unknowns, H = {harmonics}: Python call {w * 1e6:.1f} us, "
        f"library solve {r * 1e6:.1f} us, ratio {w / r:.3f} (median of {len(wall)})"
    )


def big_model(n: int, bandwidth: int) -> None:
    # A banded SPD stiffness (diagonally dominant) and a diagonal-dominant mass.
    offsets = list(range(-bandwidth, bandwidth + 1))
    k = sp.diags([np.full(n - abs(o), -1.0 if o else 2.0 * bandwidth + 1.0) for o in offsets],
                 offsets, format="csr")
    m = sp.diags([np.full(n - abs(o), 0.01 if o else 1.0) for o in offsets], offsets, format="csr")
    nnz = k.nnz + m.nnz
    one_copy = (nnz * 16 + 2 * (n + 1) * 8) / 2**20
    before = rss_mb()
    peak_before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    t = time.perf_counter()
    model = nlsim.from_matrices(m, k)
    seconds = time.perf_counter() - t
    after = rss_mb()
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    print(
        f"from_matrices {n} DOFs, {nnz} stored entries ({k.indices.dtype} indices): "
        f"{seconds:.2f} s; resident +{after - before:.0f} MB after, peak +{max(peak - peak_before, 0):.0f} MB "
        f"(peak may be 0 when the earlier peak was higher); one copy as nlsim keeps it {one_copy:.0f} MB; "
        f"the input arrays {(k.data.nbytes + k.indices.nbytes + m.data.nbytes + m.indices.nbytes) / 2**20:.0f} MB"
    )
    csr = k.tocsr()
    print(f"  .tocsr() of a CSR matrix shares its arrays: {np.shares_memory(csr.data, k.data)}; "
          f"np.ascontiguousarray of them shares too: "
          f"{np.shares_memory(np.ascontiguousarray(k.data, dtype=np.float64), k.data)}")
    assert model.n_dofs == n


if __name__ == "__main__":
    hb_point("ecl_beam", 20.0, 24.0, 401)
    b = nlsim.modes(nlsim.load("bracket:dofs=5000"), count=1).frequency_hz[0]
    hb_point("bracket:dofs=5000", 0.95 * b, 1.0 * b, 101)
    big_model(100_000, 30)
