#!/usr/bin/env python3
"""Reads nlsim's HDF5 files with h5py alone, knowing nothing of nlsim.

    h5check.py read FILE...           every dataset and attribute is read; checks the layout
                                      rules of docs/file-formats.md that hold for every file
    h5check.py same A B [--ignore N]  A and B hold the same tree, datasets equal bit for bit,
                                      attributes equal (except those named N, e.g. timings)

Exit status 0 when every check holds, 1 otherwise (with one line per problem).
"""
import sys

import h5py
import numpy as np


def walk(f):
    """(path, object) of every group and dataset, the root first, in name order."""
    out = [("/", f)]
    f.visititems(lambda name, obj: out.append(("/" + name, obj)))
    return out


def read(path):
    problems = []
    with h5py.File(path, "r") as f:
        for key in ("nlsim_version", "command", "model"):
            if key not in f.attrs:
                problems.append(f"{path}: root attribute '{key}' is missing")
        n = 0
        for name, obj in walk(f):
            for k, v in obj.attrs.items():
                _ = v  # reading the value is the check
            if isinstance(obj, h5py.Dataset):
                data = obj[()]
                n += 1
                if obj.dtype.kind == "V":
                    problems.append(f"{path}:{name}: compound type h5py cannot map ({obj.dtype})")
                if obj.dtype.kind == "f" and "unit" not in obj.attrs and obj.size > 1:
                    problems.append(f"{path}:{name}: real series without a 'unit' attribute")
                if obj.dtype.kind == "c" and not np.iscomplexobj(data):
                    problems.append(f"{path}:{name}: complex data did not read as complex")
        if n == 0:
            problems.append(f"{path}: no datasets")
    return problems, n


def equal_bits(a, b):
    """Bit-for-bit equality; strings (object arrays of str or bytes) compared by value."""
    if a.dtype.kind == "O" or b.dtype.kind == "O":
        return a.shape == b.shape and list(a.ravel()) == list(b.ravel())
    return a.tobytes() == b.tobytes()


def same(a, b, ignore):
    problems = []
    with h5py.File(a, "r") as fa, h5py.File(b, "r") as fb:
        ta, tb = dict(walk(fa)), dict(walk(fb))
        for name in sorted(set(ta) ^ set(tb)):
            problems.append(f"{name}: only in {a if name in ta else b}")
        for name in sorted(set(ta) & set(tb)):
            oa, ob = ta[name], tb[name]
            ka = {k for k in oa.attrs if k not in ignore}
            kb = {k for k in ob.attrs if k not in ignore}
            for k in sorted(ka ^ kb):
                problems.append(f"{name}: attribute '{k}' only in one file")
            for k in sorted(ka & kb):
                va, vb = np.asarray(oa.attrs[k]), np.asarray(ob.attrs[k])
                if va.dtype != vb.dtype or not equal_bits(va, vb):
                    problems.append(f"{name}: attribute '{k}': {oa.attrs[k]!r} != {ob.attrs[k]!r}")
            if isinstance(oa, h5py.Dataset) != isinstance(ob, h5py.Dataset):
                problems.append(f"{name}: a dataset in one file, a group in the other")
            elif isinstance(oa, h5py.Dataset):
                da, db = oa[()], ob[()]
                if oa.dtype != ob.dtype or oa.shape != ob.shape:
                    problems.append(f"{name}: {oa.dtype}{oa.shape} != {ob.dtype}{ob.shape}")
                elif not equal_bits(np.asarray(da), np.asarray(db)):
                    problems.append(f"{name}: data differ")
    return problems


def main(argv):
    if len(argv) >= 2 and argv[0] == "read":
        problems = []
        for p in argv[1:]:
            pr, n = read(p)
            problems += pr
            if not pr:
                print(f"h5check: {p}: {n} datasets read")
    elif len(argv) >= 3 and argv[0] == "same":
        ignore = set()
        rest = argv[3:]
        while rest:
            if rest[0] == "--ignore" and len(rest) >= 2:
                ignore.add(rest[1])
                rest = rest[2:]
            else:
                print(__doc__, file=sys.stderr)
                return 2
        problems = same(argv[1], argv[2], ignore)
        if not problems:
            print(f"h5check: {argv[1]} and {argv[2]} are the same")
    else:
        print(__doc__, file=sys.stderr)
        return 2
    for p in problems:
        print("h5check: " + p, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
