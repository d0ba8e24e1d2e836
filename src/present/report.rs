//! The report of a run: one self-contained HTML page (`index.html`: inline SVG figures, plain
//! tables, inline CSS, no script, nothing fetched) with every stage's text, tables and
//! figures and the run's provenance, and one HDF5 file beside it (`report.h5`) holding the
//! data behind every figure and table, so that each can be redrawn with h5py.
//!
//! A [`Report`] is filled as the run goes: [`Report::section`] starts a stage,
//! [`Report::say`] adds a line of its summary, [`Report::table`] and [`Report::figure`] add
//! a table or a figure (written as SVG and PNG files too), [`Report::skip`] says why a stage
//! was not built, [`Report::data`] writes a stage's results into `report.h5` in the layouts
//! of the result files, and [`Report::finish`] writes the page. The layout of `report.h5` is
//! in `docs/file-formats.md`.

use crate::error::{Error, Result};
use crate::formats::files::f64_attr;
use crate::formats::files::str_attr;
use crate::present::plot::Figure;
use hdf5_metno as hdf5;
use std::cell::RefCell;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::time::{Instant, SystemTime};

/// A table of the report: a caption, a header and rows of text cells (numbers already
/// formatted; cells that parse as numbers are stored as numbers in `report.h5`).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Table {
    /// Caption above the table.
    pub caption: String,
    /// Column headings.
    pub header: Vec<String>,
    /// Rows, each as long as the header.
    pub rows: Vec<Vec<String>>,
}

impl Table {
    /// A table from CSV text as nlsim writes it (comma-separated, no quoting; lines starting
    /// with `#` skipped), the first remaining line being the header.
    pub fn from_csv(caption: &str, csv: &str) -> Table {
        let mut lines = csv
            .lines()
            .filter(|l| !l.trim().is_empty() && !l.starts_with('#'));
        let split = |l: &str| l.split(',').map(|c| c.trim().to_string()).collect();
        let header = lines.next().map(split).unwrap_or_default();
        Table {
            caption: caption.to_string(),
            header,
            rows: lines.map(split).collect(),
        }
    }
}

/// One block of a section, in order.
enum Block {
    /// Lines of the run's summary, shown preformatted.
    Log(Vec<String>),
    Table(Table),
    Figure {
        name: String,
        title: String,
        svg: String,
    },
}

struct Section {
    id: String,
    title: String,
    skipped: Option<String>,
    blocks: Vec<Block>,
}

struct Inner {
    sections: Vec<Section>,
    seeds: Vec<(String, u64)>,
    names: std::collections::BTreeSet<String>,
    written: Vec<PathBuf>,
}

/// The report of one run (see the module docs). Methods take `&self`, so that a stage's
/// line callback can add to it while the stage holds it too.
pub struct Report {
    dir: PathBuf,
    title: String,
    command_line: String,
    model_spec: String,
    model_name: RefCell<Option<String>>,
    started: Instant,
    started_utc: String,
    h5_tmp: PathBuf,
    h5: RefCell<Option<hdf5::File>>,
    inner: RefCell<Inner>,
    /// Nesting depth of [`Report::table_text`] guards: lines said meanwhile stay off the page.
    table_text: std::cell::Cell<u32>,
}

/// While alive, lines given to [`Report::say`] stay off the page (see
/// [`Report::table_text`]).
pub struct TableText<'a>(&'a Report);

impl Drop for TableText<'_> {
    fn drop(&mut self) {
        self.0
            .table_text
            .set(self.0.table_text.get().saturating_sub(1));
    }
}

/// The file name of the page.
pub const PAGE: &str = "index.html";
/// The file name of the data beside it.
pub const DATA: &str = "report.h5";

/// A file every report folder gets as soon as the report starts (the command line that
/// made it): a run that fails half-way leaves a folder still known as an nlsim report.
pub const MARKER: &str = ".nlsim-report";

impl Report {
    /// Starts the report of a run in `dir` (created if missing): `title` heads the page,
    /// `command_line` (as typed) and `model_spec` go into the provenance of the page and of
    /// `report.h5`.
    pub fn create(dir: &Path, title: &str, command_line: &str, model_spec: &str) -> Result<Self> {
        std::fs::create_dir_all(dir).map_err(|source| Error::Io {
            path: dir.to_path_buf(),
            source,
        })?;
        let marker = dir.join(MARKER);
        std::fs::write(&marker, format!("{command_line}\n")).map_err(|source| Error::Io {
            path: marker,
            source,
        })?;
        let h5_path = dir.join(DATA);
        let h5_tmp = crate::formats::files::temp_path(&h5_path);
        let err = crate::formats::files::h5err(&h5_path);
        let file = hdf5::File::create(&h5_tmp).map_err(&err)?;
        let started_utc = utc_text(SystemTime::now());
        {
            let root = file.as_group().map_err(&err)?;
            // `model_name` is written when the report finishes (the model may load later).
            crate::formats::files::provenance(&root, "report", model_spec, "", None)
                .map_err(&err)?;
            str_attr(&root, "title", title).map_err(&err)?;
            str_attr(&root, "command_line", command_line).map_err(&err)?;
            str_attr(&root, "started_utc", &started_utc).map_err(&err)?;
        }
        Ok(Report {
            dir: dir.to_path_buf(),
            title: title.to_string(),
            command_line: command_line.to_string(),
            model_spec: model_spec.to_string(),
            model_name: RefCell::new(None),
            started: Instant::now(),
            started_utc,
            h5_tmp,
            h5: RefCell::new(Some(file)),
            inner: RefCell::new(Inner {
                sections: Vec::new(),
                seeds: Vec::new(),
                names: Default::default(),
                written: Vec::new(),
            }),
            table_text: std::cell::Cell::new(0),
        })
    }

    /// The name of the model the report is about (the `model_name` attribute of
    /// `report.h5`; the model argument as given when never set).
    pub fn model_name(&self, name: &str) {
        *self.model_name.borrow_mut() = Some(name.to_string());
    }

    /// The report's folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Starts a section (a stage of the run) titled `title`; what follows goes into it.
    pub fn section(&self, title: &str) {
        let mut inner = self.inner.borrow_mut();
        let id = format!("s{}", inner.sections.len() + 1);
        inner.sections.push(Section {
            id,
            title: title.to_string(),
            skipped: None,
            blocks: Vec::new(),
        });
    }

    /// Starts a section titled `title` holding `lines` (a summary) as its first block.
    pub fn section_with(&self, title: &str, lines: &[String]) {
        self.section(title);
        for l in lines {
            self.say(l);
        }
    }

    /// Marks the current section as not built, saying why.
    pub fn skip(&self, why: &str) {
        self.with_section(|s| s.skipped = Some(why.to_string()));
    }

    /// Adds a line of the run's summary to the current section (unless a [`TableText`]
    /// guard is alive).
    pub fn say(&self, line: &str) {
        if self.table_text.get() > 0 {
            return;
        }
        self.with_section(|s| match s.blocks.last_mut() {
            Some(Block::Log(lines)) => lines.push(line.to_string()),
            _ => s.blocks.push(Block::Log(vec![line.to_string()])),
        });
    }

    /// Keeps the lines said while the returned guard lives off the page: a table drawn in
    /// text for the terminal and `summary.txt`, which the page shows as a [`Report::table`]
    /// (a table, not a preformatted block wider than the page).
    pub fn table_text(&self) -> TableText<'_> {
        self.table_text.set(self.table_text.get() + 1);
        TableText(self)
    }

    /// Records a seed of the run's random draws (shown in the provenance, stored as an
    /// attribute `seed_<what>` of `report.h5`).
    pub fn seed(&self, what: &str, seed: u64) -> Result<()> {
        self.inner.borrow_mut().seeds.push((what.to_string(), seed));
        let name = format!("seed_{}", safe_name(what));
        self.data(|root| {
            if root.attr(&name).is_err() {
                root.new_attr::<u64>()
                    .create(name.as_str())?
                    .write_scalar(&seed)?;
            }
            Ok(())
        })
    }

    /// Adds `table` to the current section, and its columns to `report.h5` as
    /// `/tables/NAME/<column>` (numbers where every cell is one, strings otherwise).
    pub fn table(&self, name: &str, table: Table) -> Result<()> {
        let name = self.unique("table", name);
        let t = table.clone();
        self.data(|root| {
            let tables = match root.group("tables") {
                Ok(g) => g,
                Err(_) => root.create_group("tables")?,
            };
            let g = tables.create_group(&name)?;
            str_attr(&g, "caption", &t.caption)?;
            let order: Vec<hdf5::types::VarLenUnicode> =
                t.header.iter().map(|h| varlen(h)).collect();
            g.new_dataset_builder()
                .with_data(&order)
                .create("columns")?;
            for (c, h) in t.header.iter().enumerate() {
                let cells: Vec<&str> = t
                    .rows
                    .iter()
                    .map(|r| r.get(c).map_or("", |s| s.as_str()))
                    .collect();
                let numbers: Option<Vec<f64>> = cells.iter().map(|s| parse_number(s)).collect();
                let col = format!("{c:02}_{}", safe_name(h));
                let d = match numbers {
                    Some(v) if !v.is_empty() => {
                        let d = g.new_dataset_builder().with_data(&v).create(col.as_str())?;
                        str_attr(&d, "unit", &unit_of(h))?;
                        d
                    }
                    _ => {
                        let v: Vec<hdf5::types::VarLenUnicode> =
                            cells.iter().map(|s| varlen(s)).collect();
                        g.new_dataset_builder().with_data(&v).create(col.as_str())?
                    }
                };
                str_attr(&d, "heading", h)?;
            }
            Ok(())
        })?;
        self.with_section(|s| s.blocks.push(Block::Table(table)));
        Ok(())
    }

    /// Adds `fig` to the current section: written as `NAME.svg` and `NAME.png` in the
    /// folder, inlined in the page, and its data ([`Figure::data`]) stored in `report.h5` as
    /// `/figures/NAME/series_<i>` with datasets `x`, `y` and attributes `label`, `panel`,
    /// `x_label`, `y_label`. Returns the two files.
    pub fn figure(&self, name: &str, fig: &impl Figure) -> Result<[PathBuf; 2]> {
        let name = self.unique("figure", name);
        // Rendered once as SVG: the page's copy and the file are the same text.
        let svg = crate::present::plot::svg_string(fig)?;
        let files = [
            self.dir.join(format!("{name}.svg")),
            self.dir.join(format!("{name}.png")),
        ];
        crate::formats::files::write_text_atomically(&files[0], &svg)?;
        crate::present::plot::write(&files[1], fig)?;
        let series = fig.data();
        let title = fig.title();
        self.data(|root| {
            let figs = match root.group("figures") {
                Ok(g) => g,
                Err(_) => root.create_group("figures")?,
            };
            let g = figs.create_group(&name)?;
            str_attr(&g, "title", &title)?;
            str_attr(&g, "svg", &format!("{name}.svg"))?;
            str_attr(&g, "png", &format!("{name}.png"))?;
            for (i, s) in series.iter().enumerate() {
                let gs = g.create_group(&format!("series_{i:02}"))?;
                str_attr(&gs, "label", &s.label)?;
                str_attr(&gs, "panel", &s.panel)?;
                str_attr(&gs, "x_label", &s.x_label)?;
                str_attr(&gs, "y_label", &s.y_label)?;
                let x = gs.new_dataset_builder().with_data(&s.x).create("x")?;
                str_attr(&x, "unit", &unit_of(&s.x_label))?;
                let y = gs.new_dataset_builder().with_data(&s.y).create("y")?;
                str_attr(&y, "unit", &unit_of(&s.y_label))?;
            }
            f64_attr(&g, "series", series.len() as f64)
        })?;
        self.inner
            .borrow_mut()
            .written
            .extend(files.iter().cloned());
        self.with_section(|s| {
            s.blocks.push(Block::Figure {
                name: name.clone(),
                title: title.clone(),
                svg,
            })
        });
        Ok(files)
    }

    /// Writes into `report.h5` (its root group given to `write`), e.g. a stage's results in
    /// the layout of its result file.
    pub fn data(&self, write: impl FnOnce(&hdf5::Group) -> hdf5::Result<()>) -> Result<()> {
        let path = self.dir.join(DATA);
        let err = crate::formats::files::h5err(&path);
        let h5 = self.h5.borrow();
        let file = h5.as_ref().expect("report.h5 is open until finish");
        let root = file.as_group().map_err(&err)?;
        write(&root).map_err(&err)
    }

    /// Notes a file the run wrote into the folder (listed on the page).
    pub fn wrote(&self, path: &Path) {
        self.inner.borrow_mut().written.push(path.to_path_buf());
    }

    /// Writes `report.h5` and `index.html` (atomically); returns the page's path.
    pub fn finish(self) -> Result<PathBuf> {
        let wall = self.started.elapsed().as_secs_f64();
        let h5_path = self.dir.join(DATA);
        let name = self
            .model_name
            .borrow()
            .clone()
            .unwrap_or_else(|| self.model_spec.clone());
        self.data(|root| {
            f64_attr(root, "wall_seconds", wall)?;
            crate::formats::files::str_attr(root, "model_name", &name)
        })?;
        let file = self.h5.borrow_mut().take().expect("finished once");
        let err = crate::formats::files::h5err(&h5_path);
        file.flush().map_err(&err)?;
        drop(file);
        std::fs::rename(&self.h5_tmp, &h5_path).map_err(|source| Error::Io {
            path: h5_path.clone(),
            source,
        })?;
        let page = self.dir.join(PAGE);
        let html = self.html(wall);
        crate::formats::files::write_text_atomically(&page, &html)?;
        Ok(page)
    }

    fn with_section(&self, f: impl FnOnce(&mut Section)) {
        let mut inner = self.inner.borrow_mut();
        if inner.sections.is_empty() {
            inner.sections.push(Section {
                id: "s1".into(),
                title: "run".into(),
                skipped: None,
                blocks: Vec::new(),
            });
        }
        f(inner.sections.last_mut().expect("one section at least"));
    }

    /// `name` made safe for files and HDF5, with `_2`, `_3`… when already used.
    /// (Figures and tables are named apart: `kind` is `figure` or `table`.)
    fn unique(&self, kind: &str, name: &str) -> String {
        let base = safe_name(name);
        let mut inner = self.inner.borrow_mut();
        let mut n = base.clone();
        let mut k = 2;
        while inner.names.contains(&format!("{kind}/{n}")) {
            n = format!("{base}_{k}");
            k += 1;
        }
        inner.names.insert(format!("{kind}/{n}"));
        n
    }

    fn html(&self, wall: f64) -> String {
        let inner = self.inner.borrow();
        let mut h = String::new();
        let _ = write!(
            h,
            "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n\
             <meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">\n\
             <title>{}</title>\n<style>{CSS}</style>\n</head>\n<body>\n<header>\n<h1>{}</h1>\n",
            esc(&self.title),
            esc(&self.title)
        );
        // Provenance.
        let _ = writeln!(h, "<table class=\"kv\">");
        let mut kv = |k: &str, v: String| {
            let _ = writeln!(h, "<tr><th>{}</th><td>{}</td></tr>", esc(k), v);
        };
        kv(
            "nlsim",
            format!("version {}", esc(env!("CARGO_PKG_VERSION"))),
        );
        kv(
            "command line",
            format!("<code>{}</code>", esc(&self.command_line)),
        );
        kv("model", format!("<code>{}</code>", esc(&self.model_spec)));
        kv("started", esc(&self.started_utc));
        kv("wall time", format!("{wall:.2} s"));
        kv(
            "seeds",
            if inner.seeds.is_empty() {
                "none (no random draws)".to_string()
            } else {
                inner
                    .seeds
                    .iter()
                    .map(|(w, s)| format!("{} {s}", esc(w)))
                    .collect::<Vec<_>>()
                    .join("; ")
            },
        );
        kv(
            "data",
            format!(
                "<a href=\"{DATA}\">{DATA}</a>: every figure's curves under <code>/figures</code>, \
                 every table under <code>/tables</code>, results in the layouts of \
                 <code>docs/file-formats.md</code>"
            ),
        );
        let _ = writeln!(h, "</table>");
        // Contents.
        let _ = writeln!(h, "<nav><ol>");
        for s in &inner.sections {
            let _ = writeln!(
                h,
                "<li><a href=\"#{}\">{}</a>{}</li>",
                s.id,
                esc(&s.title),
                if s.skipped.is_some() {
                    " <span class=\"skip\">(not built)</span>"
                } else {
                    ""
                }
            );
        }
        let _ = writeln!(h, "</ol></nav>\n</header>\n<main>");
        for s in &inner.sections {
            let _ = writeln!(h, "<section id=\"{}\">\n<h2>{}</h2>", s.id, esc(&s.title));
            if let Some(why) = &s.skipped {
                let _ = writeln!(
                    h,
                    "<p class=\"skip\">This stage was not built: {}</p>",
                    esc(why)
                );
            }
            for b in &s.blocks {
                match b {
                    Block::Log(lines) => {
                        let _ = writeln!(h, "<pre>{}</pre>", esc(&lines.join("\n")));
                    }
                    Block::Table(t) => {
                        let _ = writeln!(h, "<table class=\"data\">");
                        if !t.caption.is_empty() {
                            let _ = writeln!(h, "<caption>{}</caption>", esc(&t.caption));
                        }
                        let _ = write!(h, "<thead><tr>");
                        for c in &t.header {
                            let _ = write!(h, "<th>{}</th>", esc(c));
                        }
                        let _ = writeln!(h, "</tr></thead><tbody>");
                        for r in &t.rows {
                            let _ = write!(h, "<tr>");
                            for c in r {
                                let class = if parse_number(c).is_some() {
                                    " class=\"num\""
                                } else {
                                    ""
                                };
                                let _ = write!(h, "<td{class}>{}</td>", esc(c));
                            }
                            let _ = writeln!(h, "</tr>");
                        }
                        let _ = writeln!(h, "</tbody></table>");
                    }
                    Block::Figure { name, title, svg } => {
                        let _ = writeln!(
                            h,
                            "<figure id=\"fig-{name}\">\n{}\n<figcaption>{} — \
                             <a href=\"{name}.svg\">SVG</a>, <a href=\"{name}.png\">PNG</a>, \
                             data: <code>{DATA}:/figures/{name}</code></figcaption>\n</figure>",
                            inline_svg(svg),
                            esc(title)
                        );
                    }
                }
            }
            let _ = writeln!(h, "</section>");
        }
        let files: Vec<String> = inner
            .written
            .iter()
            .filter_map(|p| p.file_name().map(|n| n.to_string_lossy().to_string()))
            .map(|n| format!("<a href=\"{0}\">{0}</a>", esc(&n)))
            .collect();
        let _ = writeln!(
            h,
            "</main>\n<footer>Files of this run: {}{}.</footer>\n</body>\n</html>",
            files.join(", "),
            if files.is_empty() { "" } else { ", " }.to_string() + DATA
        );
        h
    }
}

impl Drop for Report {
    /// An unfinished report leaves no temporary HDF5 file behind, and its marker only
    /// beside files it wrote (a folder it left empty is left as it was).
    fn drop(&mut self) {
        if let Some(f) = self.h5.borrow_mut().take() {
            drop(f);
            let _ = std::fs::remove_file(&self.h5_tmp);
            let marker = self.dir.join(MARKER);
            let others = std::fs::read_dir(&self.dir)
                .map(|d| d.flatten().any(|e| e.path() != marker))
                .unwrap_or(true);
            if !others {
                let _ = std::fs::remove_file(&marker);
            }
        }
    }
}

/// The page's style: readable on screen, figures scaled to the width, no break inside a
/// figure or table when printed.
const CSS: &str = "body{font-family:sans-serif;max-width:1300px;margin:0 auto;padding:0 1em;\
color:#222}h1{font-size:1.6em}h2{border-bottom:1px solid #ccc;margin-top:1.6em}\
pre{background:#f6f6f6;padding:.6em;font-size:.85em;white-space:pre-wrap;\
overflow-wrap:anywhere}\
table{border-collapse:collapse;margin:.8em 0}th,td{border:1px solid #ccc;padding:.2em .5em}\
td.num{text-align:right;font-variant-numeric:tabular-nums}caption{text-align:left;\
font-weight:bold;padding:.3em 0}table.kv th{text-align:left;background:#f0f0f0}\
figure{margin:1em 0}figure svg{max-width:100%;height:auto;display:block}\
figcaption{font-size:.85em;color:#555}.skip{color:#a50}footer{margin:2em 0;font-size:.85em;\
color:#555}@media print{figure,table,pre{page-break-inside:avoid}nav{display:none}}";

/// plotters' SVG document as an element of the page: its XML declaration dropped.
fn inline_svg(svg: &str) -> &str {
    match svg.find("<svg") {
        Some(i) => &svg[i..],
        None => svg,
    }
}

/// HTML text escaping.
fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            _ => o.push(c),
        }
    }
    o
}

/// A name for files and HDF5 objects: ASCII letters, digits, `-` and `_`.
pub(crate) fn safe_name(s: &str) -> String {
    let n: String = s
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect();
    if n.is_empty() { "_".into() } else { n }
}

fn varlen(s: &str) -> hdf5::types::VarLenUnicode {
    // Interior NULs are the only thing a VarLenUnicode refuses.
    s.replace('\0', " ")
        .parse()
        .expect("a string without NUL is valid")
}

/// The unit of an axis label or column heading: the text in its last parentheses
/// (`frequency (Hz)` → `Hz`, `|tip| (dB re 1 m)` → `dB re 1 m`), else `1`.
fn unit_of(label: &str) -> String {
    match (label.rfind('('), label.rfind(')')) {
        (Some(a), Some(b)) if a < b => label[a + 1..b].trim().to_string(),
        _ => "1".into(),
    }
}

/// A cell as a number: plain or with a trailing `%` (kept as the percentage), else `None`.
fn parse_number(s: &str) -> Option<f64> {
    let t = s.trim().trim_end_matches('%').trim();
    let t = t.strip_prefix('±').unwrap_or(t);
    if t.is_empty() {
        return None;
    }
    t.parse::<f64>().ok()
}

/// `YYYY-MM-DD hh:mm:ss UTC` of `t` (civil calendar from days since 1970, Hinnant's method).
fn utc_text(t: SystemTime) -> String {
    let secs = t
        .duration_since(SystemTime::UNIX_EPOCH)
        .map_or(0, |d| d.as_secs()) as i64;
    let (days, rem) = (secs.div_euclid(86_400), secs.rem_euclid(86_400));
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z - era * 146_097;
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    let y = yoe + era * 400 + i64::from(m <= 2);
    format!(
        "{y:04}-{m:02}-{d:02} {:02}:{:02}:{:02} UTC",
        rem / 3600,
        rem % 3600 / 60,
        rem % 60
    )
}

/// The command line of this process as one shell-readable string (arguments with spaces or
/// quotes single-quoted).
pub fn command_line() -> String {
    std::env::args()
        .map(|a| {
            if !a.is_empty()
                && a.chars()
                    .all(|c| c.is_ascii_alphanumeric() || "-_./=:,@+%".contains(c))
            {
                a
            } else {
                format!("'{}'", a.replace('\'', "'\\''"))
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

/// Adds `fig` to the report (files `NAME.svg` and `NAME.png`, inline on the page, its data in
/// `report.h5`); returns the two files' paths as text for the summary.
pub(crate) fn plot_both(
    report: &Report,
    name: &str,
    fig: &impl crate::present::plot::Figure,
) -> Result<String> {
    let paths = report.figure(name, fig)?;
    Ok(format!("{}, {}", paths[0].display(), paths[1].display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn utc_dates_match_known_instants() {
        let at = |s: u64| utc_text(SystemTime::UNIX_EPOCH + std::time::Duration::from_secs(s));
        assert_eq!(at(0), "1970-01-01 00:00:00 UTC");
        // 2000-02-29 12:34:56 (a leap day of a century leap year).
        assert_eq!(at(951_827_696), "2000-02-29 12:34:56 UTC");
        // 2026-11-25 00:00:00.
        assert_eq!(at(1_795_564_800), "2026-11-25 00:00:00 UTC");
    }

    /// A page with a built and a skipped stage: the skipped one says why, the figure is
    /// inline with its files beside it, the table's cells are on the page, and report.h5
    /// holds the curve and the numeric column as given. A report dropped unfinished leaves
    /// no temporary file.
    #[test]
    fn page_and_data_of_a_small_run() {
        let dir = std::env::temp_dir().join(format!("nlsim-report-unit-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let r = Report::create(&dir, "unit <run>", "nlsim unit --x 1", "model.toml").unwrap();
        r.section("A stage");
        r.say("line one");
        r.say("line two");
        r.table(
            "t",
            Table {
                caption: "numbers".into(),
                header: vec!["name".into(), "value (Hz)".into()],
                rows: vec![
                    vec!["a".into(), "1.5".into()],
                    vec!["b".into(), "-2e3".into()],
                ],
            },
        )
        .unwrap();
        let curve = vec![(0.0, 1.0), (1.0, 4.0), (2.0, 9.0)];
        let fig = crate::present::plot::Lines {
            title: "squares".into(),
            x_desc: "x (s)".into(),
            y_desc: "y (m)".into(),
            series: vec![("x²".into(), curve.clone())],
        };
        r.figure("sq", &fig).unwrap();
        r.section("B stage");
        r.skip("the model has no element");
        r.seed("noise", 7).unwrap();
        let page = r.finish().unwrap();
        let html = std::fs::read_to_string(&page).unwrap();
        assert!(html.contains("<title>unit &lt;run&gt;</title>"));
        assert!(html.contains("<pre>line one\nline two</pre>"));
        assert!(html.contains("This stage was not built: the model has no element"));
        assert!(html.contains("<td class=\"num\">-2e3</td>"));
        assert!(html.contains("<figure id=\"fig-sq\">\n<svg"));
        assert!(html.contains("noise 7") && html.contains("nlsim unit --x 1"));
        assert!(dir.join("sq.svg").is_file() && dir.join("sq.png").is_file());
        let f = hdf5::File::open(dir.join(DATA)).unwrap();
        let y: Vec<f64> = f
            .dataset("figures/sq/series_00/y")
            .unwrap()
            .read_raw()
            .unwrap();
        assert_eq!(y, [1.0, 4.0, 9.0]);
        let v: Vec<f64> = f
            .dataset("tables/t/01_value__Hz_")
            .unwrap()
            .read_raw()
            .unwrap();
        assert_eq!(v, [1.5, -2e3]);
        let seed: u64 = f.attr("seed_noise").unwrap().read_scalar().unwrap();
        assert_eq!(seed, 7);
        drop(f);
        // Unfinished: nothing half-written stays.
        let dir2 = dir.join("unfinished");
        let r = Report::create(&dir2, "x", "x", "x").unwrap();
        r.section("only");
        drop(r);
        let left: Vec<_> = std::fs::read_dir(&dir2).unwrap().flatten().collect();
        assert!(left.is_empty(), "{left:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn escaping_names_and_numbers() {
        assert_eq!(esc("<a & \"b\">"), "&lt;a &amp; &quot;b&quot;&gt;");
        assert_eq!(safe_name("frf tip/h3"), "frf_tip_h3");
        assert_eq!(parse_number("12.5 %"), Some(12.5));
        assert_eq!(parse_number("±0.3%"), Some(0.3));
        assert_eq!(parse_number("-1.5e-3"), Some(-1.5e-3));
        assert_eq!(parse_number("tip.k3"), None);
        assert_eq!(unit_of("|tip| (dB re 1 m)"), "dB re 1 m");
        assert_eq!(unit_of("rank"), "1");
        let t = Table::from_csv("c", "# comment\na,b\n1,x\n\n2,y\n");
        assert_eq!(t.header, ["a", "b"]);
        assert_eq!(t.rows, [["1", "x"], ["2", "y"]]);
    }
}
