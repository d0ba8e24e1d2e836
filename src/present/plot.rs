//! Plots as SVG or PNG (by the file extension), written atomically.
//!
//! Text is laid out with a TrueType font read once from the system: `$NLSIM_FONT` if set,
//! else DejaVu Sans or Liberation Sans where Debian and most distributions put them, else the
//! first `.ttf` under `/usr/share/fonts`. Without any, plotting fails with the command that
//! installs one (`scripts/ensure-deps.sh` does).

use crate::error::{Error, Result};
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

/// What plots are drawn on: implemented once, rendered to any backend, and given as data so
/// that a report can store what every figure shows beside it.
pub trait Figure {
    /// Width and height in pixels.
    fn size(&self) -> (u32, u32) {
        (960, 600)
    }

    /// The title drawn above the figure.
    fn title(&self) -> String;

    /// Draws the figure on `root`, recording in `layout` where its legend and its plotted
    /// points went.
    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        layout: &mut Layout,
    ) -> DrawResult
    where
        DB::ErrorType: 'static;

    /// Every curve, bar set or marker set drawn, in the plotted units (dB values for a dB
    /// axis), in drawing order.
    fn data(&self) -> Vec<SeriesData>;
}

/// One curve (or bar set, or set of markers) of a [`Figure`] as numbers: what a reader needs
/// to redraw it (`docs/file-formats.md`, report layout).
#[derive(Debug, Clone, PartialEq)]
pub struct SeriesData {
    /// The panel it is drawn in (empty for a one-panel figure).
    pub panel: String,
    /// Its legend label.
    pub label: String,
    /// x-axis label with unit.
    pub x_label: String,
    /// y-axis label with unit.
    pub y_label: String,
    /// x values (for bars: the bar's position, 1, 2, …).
    pub x: Vec<f64>,
    /// y values, as plotted.
    pub y: Vec<f64>,
}

/// Renders `fig` as an SVG document in memory (for pages that inline their figures), with
/// its [`Layout`] in a `<metadata id="nlsim-layout">` element.
pub fn svg_string(fig: &impl Figure) -> Result<String> {
    let (mut out, layout) = render_svg(fig)?;
    if let Some(i) = out.rfind("</svg>") {
        out.insert_str(
            i,
            &format!(
                "<metadata id=\"nlsim-layout\">\n{}</metadata>\n",
                layout.to_text()
            ),
        );
    }
    Ok(out)
}

/// Where `fig` draws its legends and points, from a drawing in memory.
pub fn layout(fig: &impl Figure) -> Result<Layout> {
    render_svg(fig).map(|(_, l)| l)
}

fn render_svg(fig: &impl Figure) -> Result<(String, Layout)> {
    ensure_font()?;
    let mut out = String::new();
    let mut layout = Layout {
        size: fig.size(),
        ..Layout::default()
    };
    {
        let root = SVGBackend::with_string(&mut out, fig.size()).into_drawing_area();
        let drawn = fig
            .draw(&root, &mut layout)
            .and_then(|()| root.present().map_err(Into::into));
        if let Err(e) = drawn {
            return Err(Error::Usage(format!("drawing '{}': {e}", fig.title())));
        }
    }
    Ok((out, layout))
}

/// The error type of [`Figure::draw`].
pub type DrawResult = std::result::Result<(), Box<dyn std::error::Error>>;

/// What plot files can be: `.svg` or `.png`.
pub const HINT: &str = "FILE.svg or FILE.png";

fn font_candidates() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::env::var_os("NLSIM_FONT")
        .map(PathBuf::from)
        .into_iter()
        .collect();
    v.extend(
        [
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/TTF/DejaVuSans.ttf",
            "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
            "/Library/Fonts/Arial.ttf",
            "/System/Library/Fonts/Supplemental/Arial.ttf",
        ]
        .map(PathBuf::from),
    );
    // Any TrueType font, two levels under /usr/share/fonts.
    if let Ok(rd) = std::fs::read_dir("/usr/share/fonts") {
        let mut more: Vec<PathBuf> = rd
            .flatten()
            .flat_map(|d| std::fs::read_dir(d.path()).into_iter().flatten().flatten())
            .flat_map(|d| {
                let p = d.path();
                if p.is_dir() {
                    std::fs::read_dir(&p)
                        .into_iter()
                        .flatten()
                        .flatten()
                        .map(|e| e.path())
                        .collect()
                } else {
                    vec![p]
                }
            })
            .filter(|p| p.extension().is_some_and(|e| e == "ttf"))
            .collect();
        more.sort();
        v.extend(more);
    }
    v
}

/// Registers the plot font once (`sans-serif` for every style).
fn ensure_font() -> Result<()> {
    static FONT: OnceLock<std::result::Result<PathBuf, String>> = OnceLock::new();
    let r = FONT.get_or_init(|| {
        for p in font_candidates() {
            let Ok(bytes) = std::fs::read(&p) else {
                continue;
            };
            // The font lives as long as the process: plotters keeps a reference to it.
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            let ok = [FontStyle::Normal, FontStyle::Bold, FontStyle::Italic]
                .into_iter()
                .all(|s| plotters::style::register_font("sans-serif", s, bytes).is_ok());
            if ok {
                return Ok(p);
            }
        }
        Err(
            "no TrueType font found for the plot text: install one with \
             `sudo apt-get install fonts-dejavu-core`, or point NLSIM_FONT at a .ttf file"
                .to_string(),
        )
    });
    r.as_ref().map(|_| ()).map_err(|m| Error::Usage(m.clone()))
}

pub use crate::present::axis::{
    AXIS_MAX, LinearAxis, TICK_FONT, axis_range, log_axis_range, log_tick_label, tick_step,
};
pub use crate::present::legend::{Entry, Layout, Swatch, legend_band};

/// The companion of plot `path` named `STEM-suffix.EXT` (e.g. the damping plot beside a
/// backbone's frequency plot), in the same folder and format (`svg` when `path` has none).
pub fn companion(path: &Path, suffix: &str) -> std::path::PathBuf {
    let stem = path
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    let ext = path
        .extension()
        .map_or_else(|| "svg".into(), |e| e.to_string_lossy().into_owned());
    path.with_file_name(format!("{stem}-{suffix}.{ext}"))
}

/// Checks that `path` names a plot format, before a long run.
pub fn check_path(path: &Path) -> Result<()> {
    match path.extension().and_then(|e| e.to_str()) {
        Some("svg" | "png") => Ok(()),
        _ => Err(Error::Usage(format!(
            "{}: name the plot {HINT}",
            path.display()
        ))),
    }
}

/// Renders `fig` to `path` (SVG or PNG by extension) through a temporary file.
pub fn write(path: &Path, fig: &impl Figure) -> Result<()> {
    check_path(path)?;
    crate::formats::guard::before_write(path)?;
    ensure_font()?;
    let tmp = crate::formats::files::temp_path(path);
    let _registered = crate::formats::interrupt::Temporary::new(&tmp);
    let (w, h) = fig.size();
    let render = || -> DrawResult {
        if path.extension().is_some_and(|e| e == "svg") {
            let svg = svg_string(fig).map_err(|e| e.to_string())?;
            std::fs::write(&tmp, svg)?;
        } else {
            let mut rgb = vec![255u8; (w * h * 3) as usize];
            {
                let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
                fig.draw(&root, &mut Layout::default())?;
                root.present()?;
            }
            let file = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
            let mut enc = png::Encoder::new(file, w, h);
            enc.set_color(png::ColorType::Rgb);
            enc.set_depth(png::BitDepth::Eight);
            let mut writer = enc.write_header()?;
            writer.write_image_data(&rgb)?;
            writer.finish()?;
        }
        Ok(())
    };
    let io = |e: String| Error::Io {
        path: path.to_path_buf(),
        source: std::io::Error::other(e),
    };
    if let Err(e) = render() {
        let _ = std::fs::remove_file(&tmp);
        return Err(io(e.to_string()));
    }
    std::fs::rename(&tmp, path).map_err(|e| io(e.to_string()))
}

/// Writes `fig` as `dir/NAME.svg` and `dir/NAME.png`; returns the two paths.
pub fn write_both(dir: &Path, name: &str, fig: &impl Figure) -> Result<[PathBuf; 2]> {
    let paths = ["svg", "png"].map(|e| dir.join(format!("{name}.{e}")));
    for p in &paths {
        write(p, fig)?;
    }
    Ok(paths)
}

/// Line plots sharing axes: `(label, points)` each.
pub struct Lines {
    /// Title above the plot.
    pub title: String,
    /// x-axis label with unit.
    pub x_desc: String,
    /// y-axis label with unit.
    pub y_desc: String,
    /// The curves; a non-finite point leaves a gap.
    pub series: Vec<(String, Vec<(f64, f64)>)>,
}

impl Figure for Lines {
    fn title(&self) -> String {
        self.title.clone()
    }

    fn data(&self) -> Vec<SeriesData> {
        self.series
            .iter()
            .map(|(label, p)| SeriesData {
                panel: String::new(),
                label: label.clone(),
                x_label: self.x_desc.clone(),
                y_label: self.y_desc.clone(),
                x: p.iter().map(|q| q.0).collect(),
                y: p.iter().map(|q| q.1).collect(),
            })
            .collect()
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        layout: &mut Layout,
    ) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let root = root.titled(&self.title, ("sans-serif", 20))?;
        let style = |i: usize| {
            (
                LINE_COLOURS[i % LINE_COLOURS.len()],
                if i == 0 { 2 } else { 1 },
            )
        };
        let entries: Vec<Entry> = self
            .series
            .iter()
            .enumerate()
            .map(|(i, (label, _))| {
                let (c, w) = style(i);
                Entry::new(label.clone(), Swatch::Line(c, w + 1))
            })
            .collect();
        let area = legend_band(&root, &entries, layout)?;
        let finite = || {
            self.series
                .iter()
                .flat_map(|(_, p)| p.iter().copied())
                .filter(|(x, y)| x.is_finite() && y.is_finite())
        };
        let (x0, x1, y0, y1) = finite().fold(
            (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ),
            |(a, b, c, d), (x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
        );
        let (x0, x1) = axis_range(x0, x1);
        let (y0, y1) = axis_range(y0, y1);
        let pad = 0.05 * (y1 - y0);
        let (y0, y1) = axis_range(y0 - pad, y1 + pad);
        let mut chart = ChartBuilder::on(&area)
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        // The spacing is estimated from the span as plotters' 10 labels would divide it.
        let xa = LinearAxis::new(&self.x_desc, x0, x1, 20);
        let ya = LinearAxis::new(&self.y_desc, y0, y1, 20);
        chart
            .configure_mesh()
            .label_style(("sans-serif", TICK_FONT))
            .axis_desc_style(("sans-serif", TICK_FONT))
            .x_desc(&xa.desc)
            .y_desc(&ya.desc)
            .x_label_formatter(&|v| xa.label(*v))
            .y_label_formatter(&|v| ya.label(*v))
            .draw()?;
        for (i, (_, p)) in self.series.iter().enumerate() {
            let (c, w) = style(i);
            // A non-finite point is a gap: each finite stretch is its own line.
            for stretch in p
                .split(|(x, y)| !(x.is_finite() && y.is_finite()))
                .filter(|s| !s.is_empty())
            {
                chart.draw_series(LineSeries::new(stretch.iter().copied(), c.stroke_width(w)))?;
            }
        }
        layout.panel(&chart, finite());
        Ok(())
    }
}

/// Colours of the curves of a [`Lines`] figure, in order.
const LINE_COLOURS: [RGBColor; 5] = [BLUE, RED, RGBColor(0, 140, 0), MAGENTA, BLACK];

/// One group of [`Bars`]: a label, its bars and an optional band drawn behind them.
pub struct BarGroup {
    /// Label written above the group.
    pub label: String,
    /// Bar heights, left to right.
    pub values: Vec<f64>,
    /// A `(low, high)` band across the group, e.g. a ±1σ interval.
    pub band: Option<(f64, f64)>,
}

/// Grouped bars rising from a baseline, one panel (with its own scale) per group, e.g. fold
/// estimates normalised by the full-data estimate per parameter (thesis Fig. 14).
pub struct Bars {
    /// Title above the panels.
    pub title: String,
    /// What one bar of a group is, e.g. `fold`.
    pub bar_desc: String,
    /// y-axis label with unit.
    pub y_desc: String,
    /// Where bars start (a horizontal line is drawn there).
    pub baseline: f64,
    /// What the baseline is, for the legend (empty: no legend entry, e.g. for zero).
    pub baseline_desc: String,
    /// What the band means, for the legend.
    pub band_desc: String,
    /// The groups, left to right.
    pub groups: Vec<BarGroup>,
}

impl Figure for Bars {
    fn title(&self) -> String {
        self.title.clone()
    }

    fn data(&self) -> Vec<SeriesData> {
        let mut out = Vec::new();
        for g in &self.groups {
            out.push(SeriesData {
                panel: g.label.clone(),
                label: self.bar_desc.clone(),
                x_label: self.bar_desc.clone(),
                y_label: self.y_desc.clone(),
                x: (1..=g.values.len()).map(|i| i as f64).collect(),
                y: g.values.clone(),
            });
            if let Some((lo, hi)) = g.band {
                out.push(SeriesData {
                    panel: g.label.clone(),
                    label: self.band_desc.clone(),
                    x_label: self.bar_desc.clone(),
                    y_label: self.y_desc.clone(),
                    x: vec![0.5, 0.5],
                    y: vec![lo, hi],
                });
            }
        }
        out
    }

    fn draw<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
        layout: &mut Layout,
    ) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let root = root.titled(&self.title, ("sans-serif", 20))?;
        // A light orange band (drawn opaque, behind the bars).
        let band_colour = RGBColor(255, 227, 187);
        let mut entries = Vec::new();
        if self.groups.iter().any(|g| g.band.is_some()) {
            entries.push(Entry::new(
                self.band_desc.clone(),
                Swatch::Patch(band_colour),
            ));
        }
        entries.push(Entry::new(
            self.baseline_desc.clone(),
            Swatch::Line(BLACK, 1),
        ));
        let root = legend_band(&root, &entries, layout)?;
        let panels = root.split_evenly((1, self.groups.len().max(1)));
        for (group, area) in self.groups.iter().zip(&panels) {
            let b = self.baseline;
            // The scale follows the bars; a band much wider than them is clipped (and says so).
            let extent = group
                .values
                .iter()
                .filter(|v| v.is_finite())
                .map(|v| (v - b).abs())
                .fold(1e-6 * b.abs().max(1e-300), f64::max);
            let limit = 4.0 * extent;
            let band = group
                .band
                .filter(|(lo, hi)| lo.is_finite() && hi.is_finite())
                .map(|(lo, hi)| (lo.max(b - limit), hi.min(b + limit), hi - lo > 2.0 * limit));
            // Bars on one side of the baseline leave no room on the other (a standard
            // deviation's axis starts at 0).
            let mut y0 = b;
            let mut y1 = b;
            for &v in group.values.iter().filter(|v| v.is_finite()) {
                y0 = y0.min(v);
                y1 = y1.max(v);
            }
            if let Some((lo, hi, _)) = band {
                y0 = y0.min(lo);
                y1 = y1.max(hi);
            }
            let (lo_free, hi_free) = (y0 < b, y1 > b);
            let (y0, y1) = axis_range(y0, y1);
            let pad = 0.08 * (y1 - y0);
            let (y0, y1) = axis_range(
                if lo_free || !hi_free { y0 - pad } else { y0 },
                if hi_free || !lo_free { y1 + pad } else { y1 },
            );
            let m = group.values.len().max(1) as f64;
            let caption = match band {
                Some((_, _, true)) => format!("{} ({} clipped)", group.label, self.band_desc),
                _ => group.label.clone(),
            };
            let mut chart = ChartBuilder::on(area)
                .caption(caption, ("sans-serif", 15))
                .margin(8)
                .x_label_area_size(36)
                .y_label_area_size(70)
                .build_cartesian_2d(0.5..m + 0.5, y0..y1)?;
            let ya = LinearAxis::new(&self.y_desc, y0, y1, 20);
            chart
                .configure_mesh()
                .label_style(("sans-serif", TICK_FONT))
                .axis_desc_style(("sans-serif", TICK_FONT))
                .disable_x_mesh()
                .x_labels(group.values.len().min(10))
                .x_label_formatter(&|v| {
                    if (v - v.round()).abs() < 1e-9 {
                        format!("{v:.0}")
                    } else {
                        String::new()
                    }
                })
                .x_desc(&self.bar_desc)
                .y_desc(&ya.desc)
                .y_label_formatter(&|v| ya.label(*v))
                .draw()?;
            if let Some((lo, hi, _)) = band {
                chart.draw_series([Rectangle::new(
                    [(0.5, lo), (m + 0.5, hi)],
                    band_colour.filled(),
                )])?;
            }
            let tops: Vec<(f64, f64)> = group
                .values
                .iter()
                .enumerate()
                .filter(|(_, v)| v.is_finite())
                .map(|(i, &v)| ((i + 1) as f64, v))
                .collect();
            chart.draw_series(tops.iter().map(|&(x, v)| {
                Rectangle::new([(x - 0.35, b), (x + 0.35, v)], BLUE.mix(0.7).filled())
            }))?;
            chart.draw_series(LineSeries::new(
                [(0.5, b), (m + 0.5, b)],
                BLACK.stroke_width(1),
            ))?;
            layout.panel(&chart, tops);
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{BarGroup, Bars, Figure, Lines};

    fn lines() -> Lines {
        Lines {
            title: "t".into(),
            x_desc: "frequency (Hz)".into(),
            y_desc: "force (N)".into(),
            series: vec![
                (
                    "a long legend label of the first curve".into(),
                    // A curve through the top right corner, where a legend used to sit.
                    (0..200)
                        .map(|i| (i as f64, if i == 90 { f64::NAN } else { 1e-3 * i as f64 }))
                        .collect(),
                ),
                ("b".into(), vec![(1.0, 0.1), (199.0, 0.2)]),
            ],
        }
    }

    /// Every text of a figure — ticks, axis names, legend — is at least 11 px in the SVG
    /// (plotters' default made ticks and legends 9.7 px).
    #[test]
    fn figure_text_is_at_least_11_px() {
        let svg = super::svg_string(&lines()).unwrap();
        let sizes: Vec<f64> = svg
            .split("font-size=\"")
            .skip(1)
            .map(|r| r.split('"').next().unwrap().parse().unwrap())
            .collect();
        assert!(sizes.len() > 10, "{svg}");
        assert!(sizes.iter().all(|&s| s >= 11.0), "{sizes:?}");
        // The N axis is in mN, not ticks like 200m; the layout rides along in the file.
        assert!(svg.contains("\nforce (mN)\n</text>"), "{svg}");
        assert!(!svg.contains("0m\n</text>"), "{svg}");
        assert!(svg.contains("<metadata id=\"nlsim-layout\">\nsize 960 600\nlegend "));
    }

    /// Legends sit in their own band: no plotted point under them, whatever the data; the
    /// legend lies outside every plotting area.
    #[test]
    fn legends_cover_no_plotted_point() {
        let l = super::layout(&lines()).unwrap();
        assert_eq!(l.legends.len(), 1);
        assert_eq!(l.panels.len(), 1);
        assert!(l.panels[0].points.len() > 150, "{:?}", l.panels[0]);
        assert!(l.covered().is_empty(), "{:?}", l.covered());
        let area = l.panels[0].area.unwrap();
        assert!(!l.legends[0].overlaps(&area), "{l:?}");
        // The top right corner of the data is where an inside legend would have been.
        let top_right = l.panels[0].points.iter().max_by_key(|p| p.0 - p.1).unwrap();
        assert!(
            top_right.0 > area.x1 - 20 && top_right.1 < area.y0 + 40,
            "{top_right:?}"
        );
    }

    /// A standard deviation's axis starts at its baseline 0 (was −0.5), and a baseline
    /// without a name has no legend entry (was `— 0`).
    #[test]
    fn bars_of_non_negative_values_start_at_zero() {
        let fig = Bars {
            title: "crb".into(),
            bar_desc: "design".into(),
            y_desc: "std (% of the nominal value)".into(),
            baseline: 0.0,
            baseline_desc: String::new(),
            band_desc: String::new(),
            groups: vec![BarGroup {
                label: "k3".into(),
                values: vec![1.0, 2.5, 4.0],
                band: None,
            }],
        };
        let l = super::layout(&fig).unwrap();
        assert!(l.legends.is_empty(), "{l:?}");
        let area = l.panels[0].area.unwrap();
        // The bars' tops, and the zero line at the bottom edge of the plotting area.
        assert_eq!(l.panels[0].points.len(), 3);
        let svg = super::svg_string(&fig).unwrap();
        assert!(
            !svg.contains("\n-0.5\n") && !svg.contains("\n-1\n"),
            "{svg}"
        );
        assert!(fig.data().iter().all(|d| d.y.iter().all(|&v| v >= 0.0)));
        assert!(area.y1 > area.y0);
        let with_band = Bars {
            baseline: 1.0,
            baseline_desc: "full-data estimate".into(),
            band_desc: "Cramér–Rao ±1σ".into(),
            groups: vec![BarGroup {
                label: "k3".into(),
                values: vec![0.99, 1.02, 1.0],
                band: Some((0.98, 1.02)),
            }],
            ..fig
        };
        let l = super::layout(&with_band).unwrap();
        assert_eq!(l.legends.len(), 1);
        assert!(l.covered().is_empty());
        let svg = super::svg_string(&with_band).unwrap();
        assert!(svg.contains("\nfull-data estimate\n") && svg.contains("\nCramér–Rao ±1σ\n"));
    }
}
