#!/usr/bin/env python3
"""Writes the K and M of an `nlsim export` folder (K.mtx, M.mtx, dofs.txt) in the layouts of
the FE codes, for nlsim's reader tests and the examples in docs/model-files.md:

- `pynastran.bdf`: DMIG entries KAAX and MAAX written by pyNastran (large field, double
  precision: 11 significant digits, as Nastran's own punch files);
- `free.pch`: DMIG entries in free field with every value to the bit (Python's shortest
  round-trip repr), K given by its upper triangle and M by its lower one;
- `K.abq.mtx`, `M.abq.mtx`: Abaqus *MATRIX GENERATE coordinate output (NODE, DOF, NODE,
  DOF, VALUE), K with both triangles and M with its lower one, values to the bit;
- `sparse.op4` (and `dense.op4` up to 2000 DOFs): Nastran OUTPUT4, ASCII, KAAX and MAAX
  as full symmetric matrices, written by pyNastran;
- `K.pyn.mtx`, `M.pyn.mtx`: pyNastran's own reading of `pynastran.bdf`, in the Abaqus
  layout (values to the bit): what nlsim's DMIG reader must find in that file.

Usage: fe_write.py EXPORT_DIR OUT_DIR [--no-pynastran]
"""
import os
import sys

COMPONENTS = {"ux": 1, "uy": 2, "uz": 3, "rx": 4, "ry": 5, "rz": 6, "u": 0}


def read_mm(path):
    """The lower-triangle entries (row, col, value), 0-based, of a symmetric Matrix Market file."""
    entries = []
    size = None
    with open(path) as f:
        for line in f:
            if line.startswith("%"):
                continue
            parts = line.split()
            if not parts:
                continue
            if size is None:
                size = tuple(int(p) for p in parts)
                continue
            entries.append((int(parts[0]) - 1, int(parts[1]) - 1, float(parts[2])))
    assert size is not None and len(entries) == size[2], path
    return entries


def read_dofs(path):
    out = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            node, comp = line.split(":")
            out.append((int(node), COMPONENTS[comp]))
    return out


def free_dmig(name, entries, dofs, upper):
    """Free-field DMIG: a header and one card per entry, continuation-free."""
    lines = [f"DMIG,{name},0,6,2,0,,,{len(dofs)}"]
    for i, j, v in entries:
        if upper:
            i, j = j, i
        (gi, ci), (gj, cj) = dofs[i], dofs[j]
        lines.append(f"DMIG,{name},{gj},{cj},,{gi},{ci},{v!r}")
    return "\n".join(lines) + "\n"


def abaqus(entries, dofs, both):
    lines = ["** written by scripts/fe_write.py after the *MATRIX GENERATE coordinate layout"]
    for i, j, v in entries:
        (gi, ci), (gj, cj) = dofs[i], dofs[j]
        lines.append(f"{gi},{ci}, {gj},{cj}, {v!r}")
        if both and i != j:
            lines.append(f"{gj},{cj}, {gi},{ci}, {v!r}")
    return "\n".join(lines) + "\n"


def main():
    src, out = sys.argv[1], sys.argv[2]
    os.makedirs(out, exist_ok=True)
    k = read_mm(os.path.join(src, "K.mtx"))
    m = read_mm(os.path.join(src, "M.mtx"))
    dofs = read_dofs(os.path.join(src, "dofs.txt"))
    with open(os.path.join(out, "free.pch"), "w") as f:
        f.write("$ DMIG in free field, written by scripts/fe_write.py\n")
        f.write(free_dmig("KAAX", k, dofs, upper=True))
        f.write(free_dmig("MAAX", m, dofs, upper=False))
    with open(os.path.join(out, "K.abq.mtx"), "w") as f:
        f.write(abaqus(k, dofs, both=True))
    with open(os.path.join(out, "M.abq.mtx"), "w") as f:
        f.write(abaqus(m, dofs, both=False))
    if "--no-pynastran" not in sys.argv:
        from pyNastran.bdf.bdf import BDF

        model = BDF(debug=None)
        for name, entries in (("KAAX", k), ("MAAX", m)):
            gcj = [dofs[j] for _, j, _ in entries]
            gci = [dofs[i] for i, _, _ in entries]
            real = [v for _, _, v in entries]
            model.add_dmig(name, 6, 2, 2, 0, len(dofs), GCj=gcj, GCi=gci, Real=real)
        model.write_bdf(os.path.join(out, "pynastran.bdf"), size=16, is_double=True)
        # OUTPUT4, ASCII, by pyNastran: sparse (strings) always, dense too for small models
        # (a dense column runs from its first to its last nonzero row).
        import numpy as np
        from scipy.sparse import coo_matrix
        from pyNastran.op4.op4 import OP4

        n = len(dofs)
        full = {}
        for name, entries in (("KAAX", k), ("MAAX", m)):
            rows = [i for i, j, _ in entries] + [j for i, j, _ in entries if i != j]
            cols = [j for i, j, _ in entries] + [i for i, j, _ in entries if i != j]
            vals = [v for _, _, v in entries] + [v for i, j, v in entries if i != j]
            full[name] = coo_matrix((np.array(vals), (np.array(rows), np.array(cols))), shape=(n, n))
        OP4(debug=False).write_op4(
            os.path.join(out, "sparse.op4"),
            {name: (6, a) for name, a in full.items()},
            is_binary=False,
        )
        if n <= 2000:
            OP4(debug=False).write_op4(
                os.path.join(out, "dense.op4"),
                {name: (6, a.toarray()) for name, a in full.items()},
                is_binary=False,
            )
        # pyNastran's own reading of what it wrote, as Abaqus coordinate files (values to
        # the bit): the oracle of nlsim's DMIG reader on this file.
        back = BDF(debug=None)
        back.read_bdf(os.path.join(out, "pynastran.bdf"), punch=True, xref=False)
        for name, file in (("KAAX", "K.pyn.mtx"), ("MAAX", "M.pyn.mtx")):
            d = back.dmig[name]
            lines = ["** pyNastran's reading of DMIG " + name]
            for (gi, ci), (gj, cj), v in zip(d.GCi, d.GCj, d.Real):
                lines.append(f"{gi},{ci}, {gj},{cj}, {float(v)!r}")
            with open(os.path.join(out, file), "w") as f:
                f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
