"""The reference users would otherwise reach for: ARPACK shift-invert through scipy,
eigsh(K, k, M, sigma=0), on matrices written by `nlsim export MODEL DIR`.

    python3 bench/scipy/eigsh_reference.py DIR N_MODES [SIGMA] [--lu] [--cholmod]

Prints the total eigsh time (its SuperLU factorisation of K - sigma M included), peak memory,
and the lowest frequencies; with --lu first times a stand-alone splu (which then also counts in
the peak memory). With --cholmod the inverse is a CHOLMOD Cholesky factor of K - sigma M
(scikit-sparse: `apt install libsuitesparse-dev`, then `pip install scikit-sparse==0.4.12` for
Debian 12's SuiteSparse 5) passed to eigsh as OPinv: the stronger anchor. Run it with
OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 for one thread. So that nlsim's
`nlsim modes` on the same model can be compared in the same run. Needs numpy and scipy
(not a dependency of nlsim; `pip install scipy`).
"""
import resource
import sys
import time

import numpy as np
import scipy.io
import scipy.sparse.linalg as sla


def main():
    args = [a for a in sys.argv[1:] if a not in ("--lu", "--cholmod")]
    d, k = args[0], int(args[1])
    sigma = float(args[2]) if len(args) > 2 else 0.0
    t = time.perf_counter()
    K = scipy.io.mmread(f"{d}/K.mtx").tocsc()
    M = scipy.io.mmread(f"{d}/M.mtx").tocsc()
    print(f"read {K.shape[0]} DOFs in {time.perf_counter() - t:.1f} s")
    if "--lu" in sys.argv:
        t = time.perf_counter()
        lu = sla.splu((K - sigma * M).tocsc())
        t_lu = time.perf_counter() - t
        print(f"splu(K - sigma M): {t_lu:.2f} s, nnz(L+U) = {lu.L.nnz + lu.U.nnz}")
        del lu
    t = time.perf_counter()
    if "--cholmod" in sys.argv:
        from sksparse.cholmod import cholesky

        factor = cholesky((K - sigma * M).tocsc())
        t_f = time.perf_counter() - t
        nnz_l = factor.L().nnz
        print(f"CHOLMOD factor: {t_f:.2f} s, nnz(L) = {nnz_l}")
        op = sla.LinearOperator(K.shape, matvec=factor, dtype=np.float64)
        vals, vecs = sla.eigsh(K, k=k, M=M, sigma=sigma, which="LM", tol=1e-10, OPinv=op)
    else:
        vals, vecs = sla.eigsh(K, k=k, M=M, sigma=sigma, which="LM", tol=1e-10)
    t_all = time.perf_counter() - t
    f = np.sqrt(np.abs(np.sort(vals))) / (2 * np.pi)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(f"eigsh k={k}: {t_all:.2f} s total, peak RSS {rss:.0f} MB")
    print("lowest frequencies (Hz):", " ".join(f"{x:.6f}" for x in f[:5]), "...", f"{f[-1]:.6f}")


if __name__ == "__main__":
    main()
