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
  layout (values to the bit): what nlsim's DMIG reader must find in that file;
- `sparse_be.op4`, `bigmat_le.op4` (and `dense_le.op4` up to 2000 DOFs): Nastran OUTPUT4,
  binary, double precision, written here after the documented record layout (pyNastran
  1.4.1's binary writer fails on dense matrices and has no sparse form) and checked by
  pyNastran's reader: sparse strings big-endian, bigmat strings (NROW < 0) and dense columns
  little-endian;
- `K.rua`: Harwell-Boeing, real unsymmetric assembled (both triangles), written by scipy;
  `M.rsa`: Harwell-Boeing, real symmetric assembled (lower triangle), as Ansys HBMAT writes,
  after the Harwell-Boeing layout; `K.mapping`, `M.mapping`: their equation-to-node/DOF maps
  in the layout of HBMAT's mapping file.

When the export folder holds `matrices.op4` (`nlsim export --op4 ...`), pyNastran reads it
and the script stops with an error unless its KAAX and MAAX equal K.mtx and M.mtx to the bit.

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


def op4_binary(path, mats, endian, layout):
    """OUTPUT4 binary records of the full symmetric scipy matrices `mats` (name -> csc):
    `layout` 'dense' (a column from its first to its last nonzero row), 'sparse' (one-word
    string headers IROW + 65536 (L + 1)) or 'bigmat' (NROW < 0, two-word headers L + 1, IROW);
    form 6, type 2 (double precision: two words per value)."""
    import struct

    def record(f, payload):
        f.write(struct.pack(endian + "i", len(payload)))
        f.write(payload)
        f.write(struct.pack(endian + "i", len(payload)))

    with open(path, "wb") as f:
        for name, a in mats.items():
            a = a.tocsc()
            a.sort_indices()
            n = a.shape[0]
            nrow = -n if layout == "bigmat" else n
            record(f, struct.pack(endian + "4i8s", n, nrow, 6, 2, f"{name:<8}".encode()))
            for j in range(n):
                rows = a.indices[a.indptr[j]:a.indptr[j + 1]]
                vals = a.data[a.indptr[j]:a.indptr[j + 1]]
                if len(rows) == 0:
                    continue
                if layout == "dense":
                    col = [0.0] * (rows[-1] - rows[0] + 1)
                    for r, v in zip(rows, vals):
                        col[r - rows[0]] = v
                    body = struct.pack(endian + "3i", j + 1, rows[0] + 1, 2 * len(col))
                    body += struct.pack(endian + f"{len(col)}d", *col)
                    record(f, body)
                    continue
                strings = []
                for r, v in zip(rows, vals):
                    if strings and strings[-1][0] + len(strings[-1][1]) == r:
                        strings[-1][1].append(v)
                    else:
                        strings.append((r, [v]))
                words = b""
                nw = 0
                for r0, vs in strings:
                    ell = 2 * len(vs)
                    if layout == "bigmat":
                        words += struct.pack(endian + "2i", ell + 1, r0 + 1)
                        nw += 2
                    else:
                        words += struct.pack(endian + "i", (r0 + 1) + ((ell + 1) << 16))
                        nw += 1
                    words += struct.pack(endian + f"{len(vs)}d", *vs)
                    nw += ell
                record(f, struct.pack(endian + "3i", j + 1, 0, nw) + words)
            record(f, struct.pack(endian + "3id", n + 1, 1, 2, 1.0))


def same_as_pynastran(path, mats):
    """Stops unless pyNastran reads `path` as the matrices `mats` (name -> sparse), to the bit."""
    from scipy.sparse import coo_matrix
    from pyNastran.op4.op4 import read_op4

    got = read_op4(path, debug=False)
    for name, a in mats.items():
        b = coo_matrix(got[name].data).tocsr()
        a = a.tocsr()
        diff = (b != a).nnz
        if b.shape != a.shape or diff:
            sys.exit(f"{path}: pyNastran reads {name} with {diff} entries unlike the source")


def harwell_boeing_rsa(path, a, title, key):
    """The lower triangle of the symmetric scipy matrix `a` as a real symmetric assembled
    Harwell-Boeing file (RSA): column pointers, row indices and values, 17 digits."""
    from scipy.sparse import tril

    low = tril(a).tocsc()
    low.sort_indices()
    n = low.shape[0]
    ptr = [p + 1 for p in low.indptr]
    ind = [i + 1 for i in low.indices]
    vals = [float(v) for v in low.data]

    def lines(items, per, fmt):
        return [
            "".join(fmt.format(x) for x in items[k:k + per]) for k in range(0, len(items), per)
        ]

    iw = len(str(max(ptr + ind))) + 1
    ip = 80 // iw
    ptr_l = lines(ptr, ip, "{:>%d}" % iw)
    ind_l = lines(ind, ip, "{:>%d}" % iw)
    val_l = lines(vals, 3, "{:>25.16E}")
    with open(path, "w") as f:
        f.write(f"{title:<72}{key:<8}\n")
        f.write(
            f"{len(ptr_l) + len(ind_l) + len(val_l):14}{len(ptr_l):14}{len(ind_l):14}"
            f"{len(val_l):14}{0:14}\n"
        )
        f.write(f"{'RSA':<14}{n:14}{n:14}{len(vals):14}{0:14}\n")
        fi = f"({ip}I{iw})"
        f.write(f"{fi:<16}{fi:<16}{'(3E25.16)':<20}{'':<20}\n")
        for l in ptr_l + ind_l + val_l:
            f.write(l + "\n")


ANSYS_DOF = {"ux": "UX", "uy": "UY", "uz": "UZ", "rx": "ROTX", "ry": "ROTY", "rz": "ROTZ"}


def mapping(path, dofs):
    """An HBMAT-style mapping file: a heading, then one `EQUATION NODE DOF` line per row."""
    inv = {v: k for k, v in COMPONENTS.items()}
    with open(path, "w") as f:
        f.write(" Matrix Eqn   Node   DOF\n")
        for k, (g, c) in enumerate(dofs):
            f.write(f"{k + 1:11} {g:6} {ANSYS_DOF[inv[c]]:>5}\n")


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
        # OUTPUT4, binary, after the record layout, each read back by pyNastran.
        layouts = [("sparse_be.op4", ">", "sparse"), ("bigmat_le.op4", "<", "bigmat")]
        if n <= 2000:
            layouts.append(("dense_le.op4", "<", "dense"))
        for file, endian, layout in layouts:
            op4_binary(os.path.join(out, file), full, endian, layout)
            same_as_pynastran(os.path.join(out, file), full)
        exported = os.path.join(src, "matrices.op4")
        if os.path.isfile(exported):
            same_as_pynastran(exported, full)
        # Harwell-Boeing: scipy's writer (RUA, both triangles) for K, the RSA layout HBMAT
        # writes for M, and the mapping files beside them.
        import scipy.io

        scipy.io.hb_write(os.path.join(out, "K.rua"), full["KAAX"].tocsc())
        harwell_boeing_rsa(os.path.join(out, "M.rsa"), full["MAAX"], "nlsim mass", "MASS")
        mapping(os.path.join(out, "K.mapping"), dofs)
        mapping(os.path.join(out, "M.mapping"), dofs)
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
