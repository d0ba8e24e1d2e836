//! The documentation runs as printed: every shell command of `README.md` and `docs/*.md` is
//! run in a scratch directory, in the order a reader meets it, and must exit 0.
//!
//! - `nlsim ARGS` and `cargo run --release -- ARGS` run the binary under test with `ARGS`
//!   (split as a POSIX shell splits them: quotes, backslash continuations, `# comments`).
//! - A file a doc shows is written from its code block, before the doc's first command, when
//!   the line before the block's fence is `<!-- file: NAME -->` (invisible on the rendered
//!   page): the files a guide shows ship with it.
//! - Paths like `examples/models/two_dof.toml` resolve as from the repository root: the
//!   scratch directory holds a link `examples` to the repository's.
//! - Commands that cannot run inside the test suite are listed in [`ELSEWHERE`] with where
//!   they do run; a command that is neither run nor listed fails the test, so a new command
//!   in the docs is covered or named. Likewise a TOML block is a file the commands use or is
//!   marked `<!-- fragment -->` (a part of a file, shown only).

use std::path::{Path, PathBuf};
use std::process::Command;

#[path = "common/scratch.rs"]
mod scratch_dir;
use scratch_dir::Scratch;

/// Commands run elsewhere, by prefix (after comments are cut), with the place they run.
const ELSEWHERE: &[(&str, &str)] = &[
    ("make test", "CI runs it; it is this suite"),
    ("make bench-gate", "CI runs it after the tests"),
    ("make bench", "the benches (BENCHMARKS.md); minutes each"),
    (
        "cargo run --release --example",
        "the examples module of tests/lib.rs runs each example",
    ),
    (
        "python3 -m venv .venv && .venv/bin/pip install ./python",
        "scripts/python-tests.sh (make test) installs the package this way into a fresh \
         virtual environment",
    ),
    (
        "cargo build --release -p nlsim-capi",
        "make test builds the C library and runs C and ctypes programs against it",
    ),
    (
        "cc ",
        "make test compiles the C API's programs (capi/tests)",
    ),
    (
        "python3 capi/tests/python/check.py target/release/libnlsim_c.so examples",
        "capi/tests/foreign.rs (make test) runs the ctypes check with these arguments",
    ),
    (
        "nlsim batch sbatch jobs.toml --tasks 32 --cpus-per-task 4 --time 02:00:00 --submit",
        "needs a SLURM cluster; scripts/slurm-e2e.sh (make test) submits to a stub sbatch",
    ),
];

/// A fenced code block of a document.
struct Block {
    /// Line of the opening fence (1-based).
    line: usize,
    /// The fence's language tag.
    lang: String,
    /// The name given by a `<!-- file: NAME -->` line before the fence.
    file: Option<String>,
    /// Marked `<!-- fragment -->` before the fence: a part of a file, shown, not run.
    fragment: bool,
    /// The lines between the fences.
    lines: Vec<String>,
}

fn blocks(text: &str) -> Vec<Block> {
    let mut out = Vec::new();
    let mut open: Option<Block> = None;
    let mut previous = "";
    for (i, l) in text.lines().enumerate() {
        if let Some(fence) = l.trim_start().strip_prefix("```") {
            match open.take() {
                Some(b) => out.push(b),
                None => {
                    let file = previous
                        .trim()
                        .strip_prefix("<!-- file:")
                        .and_then(|r| r.strip_suffix("-->"))
                        .map(|n| n.trim().to_string());
                    open = Some(Block {
                        line: i + 1,
                        lang: fence.trim().to_string(),
                        file,
                        fragment: previous.trim() == "<!-- fragment -->",
                        lines: Vec::new(),
                    });
                }
            }
        } else if let Some(b) = &mut open {
            b.lines.push(l.to_string());
        }
        previous = l;
    }
    out
}

/// The commands of a shell block: continuation lines joined, comments cut, with the line
/// each starts on (offset in the block).
fn commands(b: &Block) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut cur = String::new();
    let mut start = 0;
    for (i, l) in b.lines.iter().enumerate() {
        if cur.is_empty() {
            start = i;
        }
        let l = cut_comment(l);
        if let Some(head) = l.trim_end().strip_suffix('\\') {
            cur.push_str(head);
            cur.push(' ');
            continue;
        }
        cur.push_str(&l);
        let c = cur.trim().to_string();
        if !c.is_empty() {
            out.push((b.line + 1 + start, c));
        }
        cur.clear();
    }
    out
}

/// `l` without a `#` comment (a `#` at the start or after whitespace, outside quotes).
fn cut_comment(l: &str) -> String {
    let (mut single, mut double) = (false, false);
    let mut prev = ' ';
    for (i, c) in l.char_indices() {
        match c {
            '\'' if !double => single = !single,
            '"' if !single => double = !double,
            '#' if !single && !double && prev.is_whitespace() => return l[..i].to_string(),
            _ => {}
        }
        prev = c;
    }
    l.to_string()
}

/// Words as a POSIX shell splits them (quotes removed); `None` for what this harness does
/// not run (pipes, substitutions, redirections).
fn words(c: &str) -> Option<Vec<String>> {
    let mut out = Vec::new();
    let mut w = String::new();
    let mut started = false;
    let (mut single, mut double) = (false, false);
    for ch in c.chars() {
        match ch {
            '\'' if !double => {
                single = !single;
                started = true;
            }
            '"' if !single => {
                double = !double;
                started = true;
            }
            '|' | '>' | '<' | '$' | '`' | ';' | '&' if !single && !double => return None,
            c if c.is_whitespace() && !single && !double => {
                if started {
                    out.push(std::mem::take(&mut w));
                    started = false;
                }
            }
            c => {
                w.push(c);
                started = true;
            }
        }
    }
    if single || double {
        return None;
    }
    if started {
        out.push(w);
    }
    Some(out)
}

/// What the harness does with command `c`: the binary's arguments, or where it runs
/// instead (`Err`).
fn plan(c: &str) -> Result<Vec<String>, Option<&'static str>> {
    if let Some((_, why)) = ELSEWHERE.iter().find(|(p, _)| c.starts_with(p)) {
        return Err(Some(why));
    }
    let w = words(c).ok_or(None)?;
    let w: Vec<&str> = w.iter().map(String::as_str).collect();
    match w.as_slice() {
        ["nlsim", rest @ ..] | ["cargo", "run", "--release", "--", rest @ ..] => {
            Ok(rest.iter().map(|s| s.to_string()).collect())
        }
        // `make demo` is `nlsim demo` after the dependency check.
        ["make", "demo"] => Ok(vec!["demo".into()]),
        _ => Err(None),
    }
}

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Runs every command of document `doc` (relative to the repository) in order in a scratch
/// directory; `Err` lists what failed, each with the document's line.
fn run_doc(doc: &str) -> Result<usize, String> {
    let text = std::fs::read_to_string(repo().join(doc)).unwrap();
    let stem = Path::new(doc)
        .file_stem()
        .unwrap()
        .to_string_lossy()
        .to_string();
    let dir = Scratch::new(&format!("docs-{stem}"));
    std::os::unix::fs::symlink(repo().join("examples"), dir.join("examples")).unwrap();
    let mut ran = 0;
    let mut failures = Vec::new();
    let blocks = blocks(&text);
    // The files a document shows ship with it: written before its first command.
    for b in &blocks {
        if let Some(name) = &b.file {
            std::fs::write(dir.join(name), b.lines.join("\n") + "\n").unwrap();
        }
    }
    for b in blocks {
        // A settings file is either one the doc's commands use or marked as a fragment.
        if b.lang == "toml" && b.file.is_none() && !b.fragment {
            failures.push(format!(
                "{doc}:{}: a TOML block neither written as a file (`<!-- file: NAME -->`) nor \
                 marked `<!-- fragment -->`",
                b.line
            ));
        }
        if b.file.is_some() || !matches!(b.lang.as_str(), "sh" | "bash" | "console") {
            continue;
        }
        for (line, c) in commands(&b) {
            match plan(&c) {
                Ok(args) => {
                    let out = Command::new(env!("CARGO_BIN_EXE_nlsim"))
                        .args(&args)
                        .current_dir(&*dir)
                        .output()
                        .unwrap();
                    ran += 1;
                    if !out.status.success() {
                        failures.push(format!(
                            "{doc}:{line}: `{c}` exited {:?}: {}",
                            out.status.code(),
                            String::from_utf8_lossy(&out.stderr).trim()
                        ));
                    }
                }
                Err(Some(_)) => {}
                Err(None) => failures.push(format!(
                    "{doc}:{line}: `{c}` is neither run by this harness nor listed in ELSEWHERE"
                )),
            }
        }
    }
    if failures.is_empty() {
        Ok(ran)
    } else {
        Err(failures.join("\n"))
    }
}

/// Every document with commands, each in its own scratch directory.
#[test]
fn every_documented_command_runs_as_printed() {
    let mut docs = vec!["README.md".to_string()];
    let mut rest: Vec<String> = std::fs::read_dir(repo().join("docs"))
        .unwrap()
        .flatten()
        .map(|e| format!("docs/{}", e.file_name().to_string_lossy()))
        .filter(|n| n.ends_with(".md"))
        .collect();
    rest.sort();
    docs.extend(rest);
    let mut failures = Vec::new();
    let mut ran = 0;
    for d in &docs {
        match run_doc(d) {
            Ok(n) => ran += n,
            Err(e) => failures.push(e),
        }
    }
    assert!(failures.is_empty(), "{}", failures.join("\n"));
    assert!(ran >= 30, "only {ran} documented commands ran");
}

/// The harness sees a broken example: a documented command that stops working (here a
/// block of a copy of the planning guide whose plan names an unknown parameter) fails it,
/// naming the document's line; a command nobody runs fails it too.
#[test]
fn a_broken_example_is_caught() {
    let dir = Scratch::new("docs-broken");
    let good = std::fs::read_to_string(repo().join("docs/planning.md")).unwrap();
    assert!(good.contains("params = [\"tip_spring.k3\", \"mode2.zeta\"]"));
    let bad = good.replacen(
        "params = [\"tip_spring.k3\", \"mode2.zeta\"]",
        "params = [\"tip_spring.k33\", \"mode2.zeta\"]",
        1,
    );
    let copy = dir.join("planning.md");
    std::fs::write(&copy, bad).unwrap();
    let e = run_doc(copy.to_str().unwrap()).unwrap_err();
    assert!(
        e.contains("`nlsim plan ecl_beam plan.toml` exited Some(") && e.contains("k33"),
        "{e}"
    );
    let unknown = "# t\n\n```sh\nrm -rf build\n```\n";
    let copy = dir.join("unknown.md");
    std::fs::write(&copy, unknown).unwrap();
    let e = run_doc(copy.to_str().unwrap()).unwrap_err();
    assert!(
        e.contains("unknown.md:4: `rm -rf build` is neither run"),
        "{e}"
    );
}

#[test]
fn shell_words_and_comments() {
    assert_eq!(
        words("simulate m --excitation \"multisine:freq=2,h1=0.2\" --x 'a b'").unwrap(),
        [
            "simulate",
            "m",
            "--excitation",
            "multisine:freq=2,h1=0.2",
            "--x",
            "a b"
        ]
    );
    assert!(words("a | b").is_none() && words("a $(b)").is_none());
    assert_eq!(cut_comment("nlsim x   # note"), "nlsim x   ");
    assert_eq!(cut_comment("nlsim 'a # b'"), "nlsim 'a # b'");
}
