#!/usr/bin/env python3
"""Reference values of the real third-party FE files in tests/data/fe_real, by readers nlsim
does not share code with: pyyeti 1.4.7 (OUTPUT4) and scipy (eigenvalues).

For each stiffness/mass pair of `CASES` it writes one line of tests/data/fe_real/reference.csv:
the file, the two matrix selectors (as a model file gives them: NAME, or NAME@K for the K-th
matrix of a repeated name), the order, the FNV-1a hash of each matrix's lower triangle as
nlsim stores it (nonzero entries column by column, row by row: row, column as u64 and the
value's bits, little-endian) and every eigenvalue ω² (rad²/s², ascending) from
scipy.linalg.eigh when the mass is positive definite (else "-").

A matrix whose two triangles are stored is taken as nlsim takes it: each entry the mean of
itself and its mirror (0.5 * (a + b), the same double in any order). Run it again with
`python3 scripts/fe_real_reference.py` (needs pyyeti==1.4.7, scipy, numpy) after adding a file.
"""
import struct
import sys
from pathlib import Path

import numpy as np
import scipy.linalg
from pyyeti.nastran import op4

HERE = Path(__file__).resolve().parent.parent / "tests" / "data" / "fe_real"

# (file, stiffness selector, mass selector)
CASES = [
    ("pyyeti/outboard_cla.op4", "KXX", "MXX"),
    ("pyyeti/outboard_cla_2020.op4", "KXX", "MXX"),
    ("pyyeti/outboard_extseout.op4", "KXX", "MXX"),
    ("pyyeti/inboard_csuper.op4", "KXX", "MXX"),
    ("pyyeti/inboard_mk_csuper.op4", "KXX", "MXX"),
    ("pyyeti/inboard_extseout.op4", "KXX", "MXX"),
    ("pyyeti/nas2cam_csuper.op4", "KAA@3", "MAA@3"),
    ("pyyeti/nas2cam_extseout.op4", "KAA@3", "MAA@3"),
    ("pyyeti/nas2cam_notall6_msc2017.op4", "KAA@2", "MAA@2"),
    ("pyyeti/nas2cam_notall6_msc2017_b.op4", "KAA@2", "MAA@2"),
    ("pyyeti/nas2cam_notall6_nx2021.op4", "KAA@2", "MAA@2"),
    ("pyyeti/reduced_bset_notall6.op4", "KAA", "MAA"),
    ("pyyeti/inboard_nas2cam_drm12.op4", "KAA", "MAA"),
    ("pyyeti/nas2cam_cla_2020.op4", "KAA@2", "MAA@2"),
]


def matrices(path):
    """Every matrix of the file in order: (lower-case name, dense array)."""
    o = op4.OP4()
    out = []
    for name, mat, form, mtype in zip(*o.listload(str(path))):
        out.append((name.upper(), np.asarray(mat.toarray() if hasattr(mat, "toarray") else mat)))
    return out


def pick(mats, selector):
    name, _, k = selector.partition("@")
    same = [m for n, m in mats if n == name]
    return same[int(k) - 1 if k else 0]


def symmetric(a):
    """nlsim's reading of a matrix stored in full or by one triangle."""
    s = a.copy()
    n = a.shape[0]
    for j in range(n):
        for i in range(j + 1, n):
            x, y = a[i, j], a[j, i]
            v = x if y == 0.0 else (y if x == 0.0 else 0.5 * (x + y))
            s[i, j] = s[j, i] = v
    return s


def fnv(a):
    h = 0xCBF29CE484222325
    n = a.shape[0]
    for j in range(n):
        for i in range(j, n):
            v = a[i, j]
            if v == 0.0:
                continue
            for b in struct.pack("<QQd", i, j, v):
                h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


def main():
    lines = ["file,stiffness,mass,n,k_fnv,m_fnv,eigenvalues_rad2_s2"]
    for file, ks, ms in CASES:
        mats = matrices(HERE / file)
        k, m = symmetric(pick(mats, ks)), symmetric(pick(mats, ms))
        try:
            np.linalg.cholesky(m)
            w2 = scipy.linalg.eigh(k, m, eigvals_only=True)
            hz = " ".join(f"{x:.17e}" for x in w2)
        except np.linalg.LinAlgError:
            hz = "-"
        lines.append(f"{file},{ks},{ms},{k.shape[0]},{fnv(k)},{fnv(m)},{hz}")
    (HERE / "reference.csv").write_text("\n".join(lines) + "\n")
    print(f"wrote {HERE / 'reference.csv'} ({len(CASES)} pairs)", file=sys.stderr)


if __name__ == "__main__":
    main()
