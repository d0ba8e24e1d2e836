#!/usr/bin/env python3
"""Reference values of the real third-party FE files in tests/data/fe_real, by readers nlsim
does not share code with: pyyeti 1.4.7 (OUTPUT4), pyNastran 1.4 (DMIG), numpy (Abaqus
`*MATRIX OUTPUT` text, with the equations labelled from the job's .inp as Abaqus numbers them),
scipy.io (Ansys Matrix Market, labelled by Ansys's mapping vector) and scipy (eigenvalues).

For each stiffness/mass pair of `CASES` it writes one line of tests/data/fe_real/reference.csv:
the stiffness and mass as a model file names them (FILE:NAME, FILE:NAME@K for the K-th matrix
of a repeated name, or FILE), what `dofs` names ("" when the files label their DOFs, "generic"
for OUTPUT4: labels 1:ux … n:ux), the order, the FNV-1a hash of each matrix's lower triangle as
nlsim stores it (nonzero entries column by column, row by row: row, column as u64 and the
value's bits, little-endian) and every eigenvalue ω² (rad²/s², ascending) from
scipy.linalg.eigh when the mass is positive definite (else "-").

A matrix whose two triangles are stored is taken as nlsim takes it: each entry the mean of
itself and its mirror (0.5 * (a + b), the same double in any order). Run it again with
`python3 scripts/fe_real_reference.py` (needs pyyeti==1.4.7, pyNastran 1.4, scipy, numpy) after adding a file.
"""
import struct
import sys
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.io
from pyyeti.nastran import op4

HERE = Path(__file__).resolve().parent.parent / "tests" / "data" / "fe_real"

# OUTPUT4: (file, stiffness selector, mass selector)
OP4_CASES = [
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
    ("pynastran/se_test_n11.op4", "KAA", "MAA"),
]

# Files with a stiffness and no mass: (file, matrix, reader); written with mass "-".
SINGLE_CASES = [
    ("pynastran/testplate_kgg.op4", "KGG", "op4"),
    ("pynastran/dmig_sparse.pch", "KAAX", "dmig"),
]

# Other formats: (stiffness file, mass file, dofs, reader)
OTHER_CASES = [
    ("pynastran/dmig.pch:KAAX", "pynastran/dmig.pch:MAAX", "", "dmig"),
    ("exudyn/blockC3D8_STIF1.mtx", "exudyn/blockC3D8_MASS1.mtx", "exudyn/blockC3D8.inp", "abaqus3"),
    ("exudyn/rotorDiscTestSTIF1.mtx", "exudyn/rotorDiscTestMASS1.mtx", "exudyn/rotorDiscTest.inp", "abaqus3"),
    (
        "exudyn/rotorAnsysStiffnessMatrixSparse.txt",
        "exudyn/rotorAnsysMassMatrixSparse.txt",
        "exudyn/rotorAnsysMatrixDofMappingVector.txt",
        "ansys_mmf",
    ),
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


def inp_solid_labels(path):
    """(node, dof) of each equation of an Abaqus job of solid elements only: the *NODE lines
    in order (each on an element), DOFs 1-3 each."""
    nodes, on = [], False
    for line in open(path):
        t = line.strip()
        if t.startswith("**") or not t:
            continue
        if t.startswith("*"):
            on = t.split(",")[0].strip().upper() == "*NODE"
            if t.upper().startswith("*ELEMENT"):
                assert "C3D" in t.upper(), t
            continue
        if on:
            nodes.append(int(t.split(",")[0]))
    return [(n, c) for n in nodes for c in (1, 2, 3)]


def abaqus3(path, n):
    a = np.loadtxt(path)
    d = np.zeros((n, n))
    for r, c, v in a:
        d[int(r) - 1, int(c) - 1] = v
    return d


# The node coordinates Ansys exported with the rotor's matrices (decimal commas).
ANSYS_NODES = "exudyn/rotorAnsysNodalCoordinates.txt"


def inp_coordinates(path):
    """Node coordinates of the *NODE lines of an Abaqus input file."""
    out, on = {}, False
    for line in open(path):
        t = line.strip()
        if t.startswith("*"):
            on = t.split(",")[0].strip().upper() == "*NODE"
            continue
        if on and t:
            c = t.split(",")
            out[int(c[0])] = [float(v) for v in c[1:4]]
    return out


def rigid_body_check(k, labels, xyz, what):
    """The labels are the equations' true nodes and DOFs: the free-free stiffness takes the
    three rigid rotations about the axes (built from the nodes' coordinates by label) to
    zero, within 1e-12 of |K| |r| (1e-16 here; a permuted labelling gives 0.4)."""
    for axis in range(3):
        w = np.zeros(3)
        w[axis] = 1.0
        r = np.array([np.cross(w, xyz[n])[c - 1] for n, c in labels])
        rel = np.linalg.norm(k @ r) / (np.abs(k).max() * np.linalg.norm(r))
        assert rel < 1e-12, f"{what}: rotation {axis}: {rel}"


def label_hash(labels):
    """FNV-1a of the labels in nlsim's order as text: "NODE:DOF," each (DOF 1-6)."""
    h = 0xCBF29CE484222325
    for b in "".join(f"{n}:{c}," for n, c in labels).encode():
        h = ((h ^ b) * 0x100000001B3) & 0xFFFFFFFFFFFFFFFF
    return f"{h:016x}"


def ansys_mapping(path):
    rows = [x for x in open(path) if not x.startswith("%")]
    nodes = [int(x) for x in rows[1:]]
    assert len(nodes) == int(rows[0].split()[0])
    return [(n, c) for n in nodes for c in (1, 2, 3)]


def in_label_order(d, labels):
    """The matrix on the labels sorted by node, then DOF (nlsim's order for labelled files)."""
    order = sorted(range(len(labels)), key=lambda i: labels[i])
    return d[np.ix_(order, order)]


def other_pair(ks, ms, dofs, reader):
    if reader == "dmig":
        from pyNastran.bdf.bdf import read_bdf

        out = []
        for sel in (ks, ms):
            file, _, name = sel.partition(":")
            model = read_bdf(str(HERE / file), punch=True, xref=False, debug=None)
            d = model.dmig[name]
            # The values as pyNastran parsed them (float64; its get_matrix rounds TIN = 1
            # matrices to float32, nlsim keeps the digits the file prints).
            cols = [tuple(int(x) for x in c) for c in d.GCj]
            rows = [tuple(int(x) for x in r) for r in d.GCi]
            labels = sorted(set(cols) | set(rows))
            at = {l: i for i, l in enumerate(labels)}
            m = np.zeros((len(labels), len(labels)))
            for c, r, v in zip(cols, rows, d.Real):
                assert m[at[r], at[c]] == 0.0
                m[at[r], at[c]] = v
            out.append((m, labels))
        (k, kl), (m, ml) = out
        assert kl == ml
        return in_label_order(k, kl), in_label_order(m, ml), sorted(kl)
    if reader == "abaqus3":
        labels = inp_solid_labels(HERE / dofs)
        n = len(labels)
        k = abaqus3(HERE / ks, n)
        rigid_body_check(k, labels, inp_coordinates(HERE / dofs), ks)
        return k, abaqus3(HERE / ms, n), labels
    if reader == "ansys_mmf":
        # Matrix Market keeps its equation order (the mapping vector only labels it).
        labels = ansys_mapping(HERE / dofs)
        k = scipy.io.mmread(str(HERE / ks)).toarray()
        m = scipy.io.mmread(str(HERE / ms)).toarray()
        rows = [x.replace(",", ".").split() for x in open(HERE / ANSYS_NODES).readlines()[1:]]
        xyz = {int(r[0]): [float(v) for v in r[1:4]] for r in rows}
        rigid_body_check(k, labels, xyz, ks)
        return k, m, labels
    raise ValueError(reader)


def eigenvalues(k, m):
    try:
        np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        return "-"
    w2 = scipy.linalg.eigh(k, m, eigvals_only=True)
    return " ".join(f"{x:.17e}" for x in w2)


def main():
    lines = ["stiffness,mass,dofs,n,k_fnv,m_fnv,labels_fnv,eigenvalues_rad2_s2"]
    for file, ks, ms in OP4_CASES:
        mats = matrices(HERE / file)
        k, m = symmetric(pick(mats, ks)), symmetric(pick(mats, ms))
        lines.append(
            f"{file}:{ks},{file}:{ms},generic,{k.shape[0]},{fnv(k)},{fnv(m)},-,"
            f"{eigenvalues(k, m)}"
        )
    for ks, ms, dofs, reader in OTHER_CASES:
        k, m, labels = other_pair(ks, ms, dofs, reader)
        k, m = symmetric(k), symmetric(m)
        lines.append(
            f"{ks},{ms},{dofs},{k.shape[0]},{fnv(k)},{fnv(m)},{label_hash(labels)},"
            f"{eigenvalues(k, m)}"
        )
    for file, name, reader in SINGLE_CASES:
        if reader == "op4":
            k, labels, dofs = symmetric(pick(matrices(HERE / file), name)), "-", "generic"
        else:
            k, _, labels = other_pair(f"{file}:{name}", f"{file}:{name}", "", "dmig")
            k, labels, dofs = symmetric(k), label_hash(labels), ""
        lines.append(f"{file}:{name},-,{dofs},{k.shape[0]},{fnv(k)},-,{labels},-")
    (HERE / "reference.csv").write_text("\n".join(lines) + "\n")
    n = len(OP4_CASES) + len(OTHER_CASES) + len(SINGLE_CASES)
    print(f"wrote {HERE / 'reference.csv'} ({n} pairs)", file=sys.stderr)


if __name__ == "__main__":
    main()
