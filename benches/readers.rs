//! Reading a model's K and M from each file format nlsim takes, against the Matrix Market
//! reader on the same matrices (issue 47: each within 2×).
//!
//! `cargo bench --bench readers` builds `bracket:dofs=N` (N = `NLSIM_READERS_DOFS`, default
//! 10⁶), writes its matrices as Matrix Market (nlsim's `export`), Nastran DMIG (large-field
//! punch, as pyNastran and Nastran write it), Abaqus coordinate files, Ansys Harwell–Boeing
//! (RSA) with mapping, and OUTPUT4 (ASCII and binary), then times `nlsim::load_model` of a
//! model file per format (the matrix cache off: the first read a user meets), `NLSIM_READERS_RUNS`
//! times (default 3) each, interleaved, and prints the best time and its ratio to Matrix
//! Market's. The files go to `target/readers-bench` and are removed at the end.

use nlsim::formats::op4_write::{Op4Layout, to_op4};
use nlsim::kernel::{Component, DofLabel, SparseSym};
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

fn component(l: &DofLabel) -> u8 {
    match l.component {
        Component::Ux => 1,
        Component::Uy => 2,
        Component::Uz => 3,
        Component::Rx => 4,
        Component::Ry => 5,
        Component::Rz => 6,
        Component::U => 0,
    }
}

/// The lower triangle of `a`, column by column.
fn lower(a: &SparseSym) -> impl Iterator<Item = (usize, usize, f64)> + '_ {
    a.entries().filter(|(i, j, _)| i >= j)
}

/// A value in a 16-character large field, as Nastran punches it: `-1.2345678901D+04`.
fn large_field(v: f64) -> String {
    let s = format!("{v:.9E}");
    let (m, e) = s.split_once('E').unwrap();
    let e: i32 = e.parse().unwrap();
    format!("{m}D{}{:02}", if e < 0 { '-' } else { '+' }, e.abs())
}

fn dmig(name: &str, a: &SparseSym, labels: &[DofLabel]) -> String {
    let mut s = String::with_capacity(a.nnz() * 50);
    let _ = writeln!(s, "DMIG*   {name:>16}{:>16}{:>16}{:>16}", 0, 6, 2);
    let _ = writeln!(s, "*       {:>16}{:>16}{:>16}{:>16}", 2, 0, "", a.n());
    let mut col = usize::MAX;
    for (i, j, v) in lower(a) {
        if j != col {
            col = j;
            let _ = writeln!(
                s,
                "DMIG*   {name:>16}{:>16}{:>16}",
                labels[j].node,
                component(&labels[j])
            );
        }
        let _ = writeln!(
            s,
            "*       {:>16}{:>16}{:>16}",
            labels[i].node,
            component(&labels[i]),
            large_field(v)
        );
    }
    s
}

fn abaqus(a: &SparseSym, labels: &[DofLabel]) -> String {
    let mut s = String::with_capacity(a.nnz() * 40);
    for (i, j, v) in lower(a) {
        let (r, c) = (&labels[i], &labels[j]);
        let _ = writeln!(
            s,
            "{},{}, {},{}, {v:?}",
            r.node,
            component(r),
            c.node,
            component(c)
        );
    }
    s
}

fn harwell_boeing(a: &SparseSym, title: &str) -> String {
    let n = a.n();
    let mut ptr = vec![1usize];
    let mut ind = Vec::new();
    let mut val = Vec::new();
    for j in 0..n {
        let (rows, vals) = a.col(j);
        for (&i, &v) in rows.iter().zip(vals) {
            if i >= j {
                ind.push(i + 1);
                val.push(v);
            }
        }
        ptr.push(ind.len() + 1);
    }
    let w = (ind.len() + 1).to_string().len() + 1;
    let per = 80 / w;
    let ints = |v: &[usize]| -> (String, usize) {
        let mut s = String::with_capacity(v.len() * w + v.len() / per + 1);
        let mut lines = 0;
        for c in v.chunks(per) {
            for x in c {
                let _ = write!(s, "{x:>w$}");
            }
            s.push('\n');
            lines += 1;
        }
        (s, lines)
    };
    let (ps, pl) = ints(&ptr);
    let (is, il) = ints(&ind);
    let mut vs = String::with_capacity(val.len() * 26);
    let mut vl = 0;
    for c in val.chunks(3) {
        for x in c {
            let _ = write!(vs, "{:>25}", format!("{x:.16E}"));
        }
        vs.push('\n');
        vl += 1;
    }
    let fi = format!("({per}I{w})");
    format!(
        "{title:<72}{:<8}\n{:14}{pl:14}{il:14}{vl:14}{:14}\nRSA{:11}{n:14}{n:14}{:14}{:14}\n\
         {fi:<16}{fi:<16}{:<20}{:<20}\n{ps}{is}{vs}",
        "KEY",
        pl + il + vl,
        0,
        "",
        val.len(),
        0,
        "(3E25.16)",
        ""
    )
}

fn mapping(labels: &[DofLabel]) -> String {
    let names = ["", "UX", "UY", "UZ", "ROTX", "ROTY", "ROTZ"];
    let mut s = String::from(" Matrix Eqn   Node   DOF\n");
    for (k, l) in labels.iter().enumerate() {
        let _ = writeln!(
            s,
            "{:11} {:6} {:>5}",
            k + 1,
            l.node,
            names[component(l) as usize]
        );
    }
    s
}

fn write(dir: &Path, name: &str, bytes: impl AsRef<[u8]>) {
    std::fs::write(dir.join(name), bytes).unwrap();
}

fn main() {
    let n: usize = std::env::var("NLSIM_READERS_DOFS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(1_000_000);
    let runs: usize = std::env::var("NLSIM_READERS_RUNS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    // The matrix cache would turn the second read of a Matrix Market file into a memory map.
    let cache_off = std::env::var("NLSIM_CACHE").is_ok_and(|v| v == "off");
    assert!(
        cache_off,
        "run with NLSIM_CACHE=off (the cache would time a memory map, not the reader)"
    );
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("target/readers-bench");
    std::fs::create_dir_all(&dir).unwrap();
    let t = Instant::now();
    let model = nlsim::load_model(&format!("bracket:dofs={n}"))
        .unwrap()
        .model;
    let (k, m) = (model.stiffness(), model.mass());
    let labels = model.dofs().labels().to_vec();
    eprintln!(
        "bracket: {} DOFs, K {} and M {} stored entries (built in {:.1} s)",
        model.n_dofs(),
        k.nnz(),
        m.nnz(),
        t.elapsed().as_secs_f64()
    );
    let t = Instant::now();
    write(&dir, "K.mtx", nlsim::formats::matrices::to_matrix_market(k));
    write(&dir, "M.mtx", nlsim::formats::matrices::to_matrix_market(m));
    let dofs: String = labels.iter().map(|l| format!("{l}\n")).collect();
    write(&dir, "dofs.txt", &dofs);
    let mut pch = dmig("KAAX", k, &labels);
    pch.push_str(&dmig("MAAX", m, &labels));
    write(&dir, "km.pch", pch);
    write(&dir, "K.abq.mtx", abaqus(k, &labels));
    write(&dir, "M.abq.mtx", abaqus(m, &labels));
    write(&dir, "K.rsa", harwell_boeing(k, "stiffness"));
    write(&dir, "M.rsa", harwell_boeing(m, "mass"));
    write(&dir, "K.mapping", mapping(&labels));
    write(&dir, "M.mapping", mapping(&labels));
    write(
        &dir,
        "ascii.op4",
        to_op4(&[("KAAX", k), ("MAAX", m)], Op4Layout::Ascii),
    );
    write(
        &dir,
        "binary.op4",
        to_op4(&[("KAAX", k), ("MAAX", m)], Op4Layout::BinaryLittleEndian),
    );
    let formats: [(&str, &str, &[&str]); 6] = [
        ("Matrix Market", "K.mtx", &["K.mtx", "M.mtx"]),
        ("DMIG (large field)", "km.pch:KAAX", &["km.pch"]),
        (
            "Abaqus coordinate",
            "K.abq.mtx",
            &["K.abq.mtx", "M.abq.mtx"],
        ),
        (
            "Harwell-Boeing + mapping",
            "K.rsa",
            &["K.rsa", "M.rsa", "K.mapping", "M.mapping"],
        ),
        ("OUTPUT4 ASCII", "ascii.op4:KAAX", &["ascii.op4"]),
        ("OUTPUT4 binary", "binary.op4:KAAX", &["binary.op4"]),
    ];
    let mut files = Vec::new();
    for (what, kfile, sources) in &formats {
        let mfile = kfile.replace("KAAX", "MAAX").replacen("K.", "M.", 1);
        let dofs_line = if kfile.contains(".op4") || kfile.ends_with("K.mtx") {
            "dofs = \"dofs.txt\"\n"
        } else {
            ""
        };
        let toml = format!(
            "name = \"readers\"\n[matrices]\nstiffness = \"{kfile}\"\nmass = \"{mfile}\"\n{dofs_line}"
        );
        let file = dir.join(format!("{}.toml", files.len()));
        std::fs::write(&file, toml).unwrap();
        let bytes: u64 = sources
            .iter()
            .map(|s| std::fs::metadata(dir.join(s)).unwrap().len())
            .sum();
        files.push((*what, file, bytes));
    }
    eprintln!("files written in {:.1} s", t.elapsed().as_secs_f64());
    let mut best = vec![f64::INFINITY; files.len()];
    for _ in 0..runs {
        for (k, (_, file, _)) in files.iter().enumerate() {
            let t = Instant::now();
            let got = nlsim::load_model(file.to_str().unwrap()).unwrap().model;
            best[k] = best[k].min(t.elapsed().as_secs_f64());
            assert_eq!(got.n_dofs(), model.n_dofs());
        }
    }
    println!(
        "reading K and M of bracket:dofs={n} ({} DOFs), best of {runs}, NLSIM_CACHE=off",
        model.n_dofs()
    );
    println!(
        "{:<26} {:>10} {:>9} {:>12}",
        "format", "MB", "s", "× Matrix Market"
    );
    for (k, (what, _, bytes)) in files.iter().enumerate() {
        println!(
            "{what:<26} {:>10.0} {:>9.2} {:>12.2}",
            *bytes as f64 / 1e6,
            best[k],
            best[k] / best[0]
        );
    }
    if std::env::var("NLSIM_READERS_KEEP").is_err() {
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
