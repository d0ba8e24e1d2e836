#!/usr/bin/env python3
"""Reads nlsim's HDF5 files with h5py alone, knowing nothing of nlsim.

    h5check.py read FILE...           every dataset and attribute is read; checks the layout
                                      rules of docs/file-formats.md that hold for every file
    h5check.py same A B [--ignore N]  A and B hold the same tree, datasets equal bit for bit,
                                      attributes equal (except those named N, e.g. timings)
    h5check.py documented KIND FILE   FILE holds what docs/file-formats.md's section of KIND
                                      (modes, simulate, frf, nnm, test-data) lists: every
                                      path of its table (`<name>` any child, `sweepN` any
                                      sweep, `{a,b}` each) and every root attribute named
    h5check.py report DIR             a report folder: report.h5 read as above, every figure
                                      in it inline in index.html with its SVG and PNG files,
                                      and curves redrawn from the data: the first curve of
                                      the time-response figure against its SVG polyline
                                      (pixels an affine map of the data, to 1 px), the FRF's
                                      fundamental from /frf against the figure data (1e-12),
                                      the modes table against /modes

Exit status 0 when every check holds, 1 otherwise (with one line per problem).
"""
import os
import re
import sys

import h5py
import numpy as np


def walk(f):
    """(path, object) of every group and dataset, the root first, in name order."""
    out = [("/", f)]
    f.visititems(lambda name, obj: out.append(("/" + name, obj)))
    return out


# Attributes that count or order something: stored as integers, never as floats (`mode` is
# also the text of an FRF's sweep mode).
INTEGER_ATTRIBUTES = {"harmonics", "modes", "mode", "subharmonic_order", "seed"}


def read(path):
    problems = []
    with h5py.File(path, "r") as f:
        # Test data come from a lab as often as from a model: no model attributes there.
        data = f.attrs.get("command") == "test data"
        required = ("nlsim_version", "command") if data else (
            "nlsim_version", "command", "model", "model_name")
        for key in required:
            if key not in f.attrs:
                problems.append(f"{path}: root attribute '{key}' is missing")
        if not data and "model_name" in f.attrs and not str(f.attrs["model_name"]):
            problems.append(f"{path}: root attribute 'model_name' is empty")
        n = 0
        for name, obj in walk(f):
            for k, v in obj.attrs.items():
                _ = v  # reading the value is the check
                if k in INTEGER_ATTRIBUTES and np.asarray(v).dtype.kind == "f":
                    problems.append(
                        f"{path}:{name}: attribute '{k}' is {np.asarray(v).dtype}, not an integer")
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


# The section of docs/file-formats.md that documents each kind of file.
SECTIONS = {
    "modes": "## Modes (`nlsim modes MODEL --out FILE`)",
    "simulate": "## `nlsim simulate --out FILE.h5`",
    "frf": "## `nlsim frf --out FILE.h5`",
    "nnm": "## `nlsim nnm --out FILE`",
    "test-data": "## Stepped-sine test data (HDF5)",
}


def documented(kind, path):
    """What docs/file-formats.md says FILE of KIND holds, checked in it."""
    doc = os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "docs", "file-formats.md")
    text = open(doc, encoding="utf-8").read()
    start = text.index(SECTIONS[kind])
    end = text.find("\n## ", start + 1)
    section = text[start:end if end >= 0 else len(text)]
    paths, attributes = [], []
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")] if line.startswith("|") else []
        if cells and ("attributes" in cells[0] or "attributes" in (cells[1] if len(cells) > 1 else "")) \
                and "`/`" in cells[0]:
            # The root's attributes: the names before any parenthesis or "when".
            body = re.sub(r"\([^)]*\)", "", cells[-1].split(" and, when")[0])
            attributes += [a for a in re.findall(r"`([a-z_]+)(?: = [^`]*)?`", body)]
        elif cells and cells[0].startswith("`/"):
            for p in re.findall(r"`(/[^`]+)`", cells[0]):
                m = re.match(r"(.*)\{([^}]*)\}(.*)", p)
                paths += [m.group(1) + x + m.group(3) for x in m.group(2).split(",")] if m else [p]
    if kind == "nnm":
        m = re.search(r"root attributes (.*?); datasets", section, re.S)
        attributes += re.findall(r"`([a-z_]+)`", re.sub(r"\([^)]*\)", "", m.group(1)))
        paths += [p for p in re.findall(r"`(/[a-z_<>/]+)`", section)]
    problems = []
    with h5py.File(path, "r") as f:
        for a in attributes:
            if a in ("common", "detail"):
                continue
            if a not in f.attrs:
                problems.append(f"{path}: root attribute '{a}' that the docs list is missing")
        for p in paths:
            if not exists(f, p.strip("/").split("/")):
                problems.append(f"{path}: '{p}' that the docs list is missing")
    if not paths:
        problems.append(f"{path}: no path read from the docs' section on {kind}")
    return problems


def exists(group, parts):
    """Whether the path `parts` is in `group`, `<…>` and `…N` segments matching any child."""
    if not parts:
        return True
    head, rest = parts[0], parts[1:]
    if not isinstance(group, h5py.Group):
        return False
    if "<" in head or re.fullmatch(r"[a-z]+N", head):
        prefix = head.split("<")[0] if "<" in head else head[:-1]
        return any(k.startswith(prefix) and exists(group[k], rest) for k in group.keys())
    return head in group and exists(group[head], rest)


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


def affine_residual(values, pixels):
    """Largest distance (px) of `pixels` from the least-squares affine map of `values`,
    and that map's slope."""
    a = np.vstack([np.ones_like(values), values]).T
    coef, *_ = np.linalg.lstsq(a, pixels, rcond=None)
    return float(np.max(np.abs(a @ coef - pixels))), float(coef[1])


def report(d):
    problems = []
    h5 = os.path.join(d, "report.h5")
    page = open(os.path.join(d, "index.html"), encoding="utf-8").read()
    pr, _ = read(h5)
    problems += pr
    with h5py.File(h5, "r") as f:
        for key in ("command_line", "started_utc", "wall_seconds"):
            if key not in f.attrs:
                problems.append(f"{h5}: root attribute '{key}' is missing")
        figures = f.get("figures", {})
        if len(figures) == 0:
            problems.append(f"{h5}: no figures")
        for name, g in figures.items():
            for ext in ("svg", "png"):
                if not os.path.isfile(os.path.join(d, f"{name}.{ext}")):
                    problems.append(f"{name}.{ext} is missing")
            m = re.search(r'<figure id="fig-%s">(.*?)</figure>' % re.escape(name), page, re.S)
            if not m or "<svg" not in m.group(1) or "</svg>" not in m.group(1):
                problems.append(f"figure {name}: not inline in index.html")
            for s in g.values():
                if s["x"].shape != s["y"].shape or s["x"].size == 0:
                    problems.append(f"figure {name}/{s.name}: x and y differ in size or are empty")
        # 1. The time response's first curve against the pixels of its polyline.
        if "time_response" in figures:
            s = figures["time_response"]["series_00"]
            x, y = s["x"][()], s["y"][()]
            m = re.search(r'<figure id="fig-time_response">(.*?)</figure>', page, re.S)
            lines = re.findall(r'<polyline[^>]*stroke="#0000FF"[^>]*points="([^"]*)"', m.group(1))
            pts = max(lines, key=len).split() if lines else []
            if len(pts) != len(x):
                problems.append(f"time_response: {len(pts)} points drawn, {len(x)} stored")
            else:
                px = np.array([[float(v) for v in p.split(",")] for p in pts])
                rx, bx = affine_residual(x, px[:, 0])
                ry, by = affine_residual(y, px[:, 1])
                if not (rx <= 1.0 and ry <= 1.0 and bx > 0 and by < 0):
                    problems.append(
                        f"time_response: drawn pixels are not the stored data "
                        f"(off by {rx:.2f} px in x, {ry:.2f} px in y)")
                else:
                    print(f"h5check: time_response: {len(x)} points redrawn from report.h5 "
                          f"within {max(rx, ry):.2f} px of the SVG")
        # 2. The FRF's fundamental magnitude recomputed from the FRF data.
        for name, g in figures.items():
            if not name.startswith("frf_") or "frf/continuation" not in f:
                continue
            c = f["frf/continuation"]
            nu = int(c.attrs["subharmonic_order"])
            for s in g.values():
                if s.attrs["label"] == "magnitude" and "(fundamental)" in s.attrs["panel"]:
                    ylab = s.attrs["y_label"]
                    sensor = ylab.split("|")[1]  # "|tip| (dB re 1 m/s^2)"
                    resp = c["sensors"][sensor]["response"][()]
                    amp = np.abs(resp[:, nu])
                    want = 20 * np.log10(amp) if "dB" in ylab else amp
                    got = s["y"][()]
                    fx = c["frequency"][()]
                    err = np.max(np.abs(got - want)) / np.max(np.abs(want))
                    if got.shape != want.shape or err > 1e-12 or np.any(s["x"][()] != fx):
                        problems.append(f"{name}: the fundamental differs from /frf/continuation")
                    else:
                        print(f"h5check: {name}: fundamental of {len(got)} points equals "
                              f"/frf/continuation ({err:.1e})")
        # 3. The modes table against the modes.
        if "tables/modes" in f and "modes" in f:
            t = f["tables/modes"]
            col = [k for k in t if k.startswith("01_")][0]
            hz = f["modes/frequency_hz"][()]
            if np.max(np.abs(t[col][()] - hz) / hz) > 1e-6:
                problems.append("tables/modes: frequencies differ from /modes/frequency_hz")
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
    elif len(argv) == 3 and argv[0] == "documented" and argv[1] in SECTIONS:
        problems = documented(argv[1], argv[2])
        if not problems:
            print(f"h5check: {argv[2]} holds what the docs list for {argv[1]}")
    elif len(argv) == 2 and argv[0] == "report":
        problems = report(argv[1])
        if not problems:
            print(f"h5check: report {argv[1]}: every figure inline and its data consistent")
    else:
        print(__doc__, file=sys.stderr)
        return 2
    for p in problems:
        print("h5check: " + p, file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
