#!/usr/bin/env python3
"""Checks the layout rules of ARCHITECTURE.md on the source tree (run by `make test`).

1. No import circle between files: in each crate's `src/`, a file that names an item of
   another file (`crate::…`, `super::…`, `self::…` paths, `use` lines, re-exports) depends
   on it; the graph of those dependencies has no cycle.
2. The top crate's layers point down: formats → (numeric crates only); present → formats;
   commands → present, formats; batch → commands, present, formats; cli → all of those; the binary above all.
3. Size: no file of the top crate over 800 lines unless listed in LONG with its reason.

Comments and string literals are ignored. Exit 1 with one line per violation.
"""
import os, re, sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CRATES = ["src", "kernel/src", "reduction/src", "sim/src", "hb/src", "calib/src", "fixtures/src"]
# Files of the top crate allowed over 800 lines, and why.
LONG = {
}
# Which top-level folders of `src/` each may depend on (besides itself, error.rs, lib.rs's
# re-exports of the numeric crates, and prelude.rs).
LAYERS = {
    "formats": set(),
    "present": {"formats"},
    "commands": {"present", "formats"},
    "batch": {"commands", "present", "formats"},
    "cli": {"batch", "commands", "present", "formats"},
    "bin": {"cli", "batch", "commands", "present", "formats"},
}

def strip(text):
    """The code of a Rust file with comments removed and string/char literals emptied."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            i = n if j < 0 else j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            i = n if j < 0 else j + 2
        elif c == "r" and re.match(r'r#*"', text[i:]) and not (i and (text[i - 1].isalnum() or text[i - 1] == "_")):
            hashes = re.match(r'r(#*)"', text[i:]).group(1)
            j = text.find('"' + hashes, i + 2 + len(hashes))
            out.append('""')
            i = n if j < 0 else j + 1 + len(hashes)
        elif c == '"':
            j = i + 1
            while j < n and text[j] != '"':
                j += 2 if text[j] == "\\" else 1
            out.append('""')
            i = j + 1
        elif c == "'" and re.match(r"'(?:[^'\\]|\\[^']+)'", text[i:]):
            out.append("''")
            i += len(re.match(r"'(?:[^'\\]|\\[^']+)'", text[i:]).group(0))
        else:
            out.append(c)
            i += 1
    return "".join(out)

def modules(src):
    """module path (tuple) -> file, for every .rs file under src."""
    out = {}
    for dirpath, _, files in os.walk(os.path.join(ROOT, src)):
        for f in files:
            if not f.endswith(".rs"):
                continue
            full = os.path.join(dirpath, f)
            rel = os.path.relpath(full, os.path.join(ROOT, src))
            parts = rel[:-3].split(os.sep)
            if parts[0] == "bin":
                continue
            if parts[-1] in ("mod", "lib"):
                parts = parts[:-1]
            out[tuple(parts)] = full
    return out

DEF = re.compile(r"^\s*(?:pub(?:\([^)]*\))? )?(?:fn|struct|enum|const|type|trait|static|mod|macro_rules!)\s+(\w+)", re.M)
GLOB = re.compile(r"^\s*pub use (?:self::)?(\w+)::\*;", re.M)

def analyse(src):
    mods = modules(src)
    texts = {m: strip(open(f).read()) for m, f in mods.items()}
    defs = {m: set(DEF.findall(t)) for m, t in texts.items()}
    globs = {m: GLOB.findall(t) for m, t in texts.items()}

    def resolve(path):
        """The module that defines `path` (a tuple of names, crate-relative)."""
        path = [p for p in path if p]
        best = ()
        for i in range(len(path), 0, -1):
            if tuple(path[:i]) in mods:
                best = tuple(path[:i])
                break
        rest = path[len(best):]
        if rest:
            name = rest[0]
            seen = set()
            m = best
            while name not in defs.get(m, ()) and m not in seen:
                seen.add(m)
                for g in globs.get(m, []):
                    if name in defs.get(m + (g,), ()) or globs.get(m + (g,)):
                        m = m + (g,)
                        break
            return m
        return best

    edges = {m: set() for m in mods}
    path_re = re.compile(r"\b(crate|super|self)((?:::\w+)+)(?:::\{([^}]*)\})?")
    for m, t in texts.items():
        is_dir = mods[m].endswith(("mod.rs", "lib.rs"))
        here = m if is_dir else m[:-1]
        # child modules' tests import their parent with `use super::*`: not a dependency
        t = re.sub(r"#\[cfg\(test\)\]\s*mod tests \{(?:.|\n)*", "", t)
        for kind, tail, group in path_re.findall(t):
            parts = tail.split("::")[1:]
            base = () if kind == "crate" else (here if kind == "self" else here[:-1] if kind == "super" else ())
            if kind == "super" and not is_dir:
                base = m[:-1]
            if kind == "self":
                base = here
            names = [g.strip().split("::")[0].split(" ")[0] for g in group.split(",")] if group else [None]
            for n in names:
                full = base + tuple(parts) + ((n,) if n and n != "self" else ())
                target = resolve(full)
                if target != m and target in mods:
                    edges[m].add(target)
        for g in globs[m]:
            if m + (g,) in mods:
                edges[m].add(m + (g,))
    return mods, edges

def cycles(edges):
    index, low, stack, on, out, i = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(10000)
    def visit(v):
        index[v] = low[v] = i[0]; i[0] += 1; stack.append(v); on.add(v)
        for w in edges[v]:
            if w not in index:
                visit(w); low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop(); on.discard(w); comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(comp)
    for v in edges:
        if v not in index:
            visit(v)
    return out

def main():
    bad = []
    for src in CRATES:
        mods, edges = analyse(src)
        name = lambda m: os.path.relpath(mods[m], ROOT)
        for comp in cycles(edges):
            bad.append(f"{src}: import circle between {', '.join(sorted(name(c) for c in comp))}")
        if src == "src":
            for m, deps in edges.items():
                if not m or m[0] not in LAYERS:
                    continue
                for d in deps:
                    if d and d[0] in LAYERS and d[0] != m[0] and d[0] not in LAYERS[m[0]]:
                        bad.append(f"{name(m)} uses {name(d)}: {m[0]} may not depend on {d[0]}")
    for dirpath, _, files in os.walk(os.path.join(ROOT, "src")):
        for f in files:
            full = os.path.join(dirpath, f)
            rel = os.path.relpath(full, ROOT)
            n = sum(1 for _ in open(full))
            if f.endswith(".rs") and n > 800 and rel not in LONG:
                bad.append(f"{rel}: {n} lines (over 800 without a reason in scripts/layers.py)")
    for b in bad:
        print("layers:", b)
    if not bad:
        print("layers: no import circle, layers point down, no file over 800 lines unlisted")
    return 1 if bad else 0

if __name__ == "__main__":
    sys.exit(main())
