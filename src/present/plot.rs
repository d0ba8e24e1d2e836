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

    /// Draws the figure on `root`.
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
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

/// Renders `fig` as an SVG document in memory (for pages that inline their figures).
pub fn svg_string(fig: &impl Figure) -> Result<String> {
    ensure_font()?;
    let mut out = String::new();
    {
        let root = SVGBackend::with_string(&mut out, fig.size()).into_drawing_area();
        let drawn = fig
            .draw(&root)
            .and_then(|()| root.present().map_err(Into::into));
        if let Err(e) = drawn {
            return Err(Error::Usage(format!("drawing '{}': {e}", fig.title())));
        }
    }
    Ok(out)
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

/// Font size of tick labels and axis names (plotters' units; about 12 px in the SVG): the
/// default's 9.7 px is too small to read on a page.
pub const TICK_FONT: f64 = 15.0;

/// The label of a tick on a logarithmic axis: each tick with its own engineering prefix
/// (`10f`, `100p`, `1n`, `1µ`), since the ticks span decades: one prefix for the axis, as
/// [`tick_label`] gives a linear axis, wrote `0µ` or `0.00001n` for the small ones.
pub fn log_tick_label(v: f64) -> String {
    tick_label(v, 0.0, v.abs())
}

/// An engineering tick label: `v` scaled by the SI prefix that brings the axis' largest
/// magnitude `axis_max` into `[1, 1000)` (`50`; `0.5` → `500m` on an axis up to 0.8, `0.5`
/// on one up to 1.2; `2e-3` → `2m`, `1.5e-6` → `1.5µ`, `3e9` → `3G`), with the decimals that the
/// axis' tick spacing `step` (same unit as `v`; 0 if unknown) and the value itself need
/// (up to 6), so that neighbouring labels differ, and no trailing zeros. Zero is `0`; values beyond the prefixes (below 1e-15 or from
/// 1e12) keep an exponent.
pub fn tick_label(v: f64, step: f64, axis_max: f64) -> String {
    const PREFIXES: [(i32, &str); 9] = [
        (-15, "f"),
        (-12, "p"),
        (-9, "n"),
        (-6, "µ"),
        (-3, "m"),
        (0, ""),
        (3, "k"),
        (6, "M"),
        (9, "G"),
    ];
    if !v.is_finite() {
        return format!("{v}");
    }
    // A tick within rounding of zero on an axis through it is zero.
    let step = step.abs();
    if v == 0.0 || (step > 0.0 && v.abs() < 1e-9 * step) {
        return "0".into();
    }
    // One prefix for the whole axis (from its largest magnitude), so that 0.999 and 1.001
    // read alike; from the value when the axis is not given.
    let reference = if axis_max.is_finite() && axis_max > 0.0 {
        axis_max
    } else {
        v.abs()
    };
    let exp3 = 3 * (reference.log10().floor() as i32).div_euclid(3);
    let Some(&(e, prefix)) = PREFIXES.iter().find(|(e, _)| *e == exp3) else {
        return format!("{v:.3e}");
    };
    let scale = 10f64.powi(e);
    let scaled = v / scale;
    // The fewest decimals (at most 6) in which both the step at this scale and the value
    // are whole (a step of 2.5 needs one; a tick at 0.25 two), so that neighbouring ticks
    // differ whatever spacing plotters chose.
    let whole = |x: f64| {
        (0..=6)
            .find(|&d| {
                let y = x.abs() * 10f64.powi(d);
                (y - y.round()).abs() <= 1e-6 * y.max(1.0)
            })
            .unwrap_or(6) as usize
    };
    let by_step = if step > 0.0 && step.is_finite() {
        whole(step / scale)
    } else {
        0
    };
    let decimals = by_step.max(whole(scaled));
    let mut text = format!("{scaled:.decimals$}");
    if text.contains('.') {
        text = text.trim_end_matches('0').trim_end_matches('.').to_string();
    }
    if text == "-0" {
        text = "0".into();
    }
    format!("{text}{prefix}")
}

/// The tick spacing plotters will use on an axis spanning `lo..hi` with about `n` labels:
/// the span over `n`, rounded down to 1, 2 or 5 times a power of ten.
pub(crate) fn tick_step(lo: f64, hi: f64, n: usize) -> f64 {
    let raw = (hi - lo).abs() / n.max(1) as f64;
    if !(raw.is_finite() && raw > 0.0) {
        return 0.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&s| s <= raw)
        .unwrap_or(p)
}

/// Largest magnitude an axis shows (values beyond are drawn at the edge).
pub const AXIS_MAX: f64 = 1e300;

/// A range plotters can put ticks on in bounded time, from any data range: NaN and
/// infinite ends dropped (`0..1` when nothing finite is left), ends clamped to ±[`AXIS_MAX`],
/// and a span of at least 1e-9 of the larger end (or 1e-300) centred on the data. plotters
/// 0.3.7 searches tick spacings in a loop that never ends on an infinite span or one
/// narrower than the rounding of its ends.
pub fn axis_range(lo: f64, hi: f64) -> (f64, f64) {
    let (lo, hi) = match (lo.is_finite(), hi.is_finite()) {
        (true, true) => (lo.min(hi), lo.max(hi)),
        (true, false) => (lo, lo),
        (false, true) => (hi, hi),
        (false, false) => return (0.0, 1.0),
    };
    let (lo, hi) = (lo.clamp(-AXIS_MAX, AXIS_MAX), hi.clamp(-AXIS_MAX, AXIS_MAX));
    let min_span = (1e-9 * lo.abs().max(hi.abs())).max(1e-300);
    if hi - lo >= min_span {
        return (lo, hi);
    }
    let centre = 0.5 * lo + 0.5 * hi;
    (centre - 0.5 * min_span, centre + 0.5 * min_span)
}

/// [`axis_range`] for a logarithmic axis: ends within `[1e-300, 1e300]`, the upper at least
/// `1 + 1e-9` times the lower.
pub fn log_axis_range(lo: f64, hi: f64) -> (f64, f64) {
    let ok = |v: f64| v.is_finite() && v > 0.0;
    let (lo, hi) = match (ok(lo), ok(hi)) {
        (true, true) => (lo.min(hi), lo.max(hi)),
        (true, false) => (lo, lo),
        (false, true) => (hi, hi),
        (false, false) => return (1e-3, 1.0),
    };
    let (lo, hi) = (lo.clamp(1e-300, AXIS_MAX), hi.clamp(1e-300, AXIS_MAX));
    (lo, hi.max(lo * (1.0 + 1e-9)))
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
    ensure_font()?;
    let tmp = crate::formats::files::temp_path(path);
    let (w, h) = fig.size();
    let render = || -> DrawResult {
        if path.extension().is_some_and(|e| e == "svg") {
            let root = SVGBackend::new(&tmp, (w, h)).into_drawing_area();
            fig.draw(&root)?;
            root.present()?;
        } else {
            let mut rgb = vec![255u8; (w * h * 3) as usize];
            {
                let root = BitMapBackend::with_buffer(&mut rgb, (w, h)).into_drawing_area();
                fig.draw(&root)?;
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

/// The legend of every nlsim plot: a framed, slightly transparent box at `position`.
pub(crate) fn draw_legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    position: SeriesLabelPosition,
) -> DrawResult
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .label_font(("sans-serif", TICK_FONT))
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .position(position)
        .draw()?;
    Ok(())
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

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let pts = self
            .series
            .iter()
            .flat_map(|(_, p)| p.iter())
            .filter(|(x, y)| x.is_finite() && y.is_finite());
        let (x0, x1, y0, y1) = pts.fold(
            (
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ),
            |(a, b, c, d), &(x, y)| (a.min(x), b.max(x), c.min(y), d.max(y)),
        );
        let (x0, x1) = axis_range(x0, x1);
        let (y0, y1) = axis_range(y0, y1);
        let pad = 0.05 * (y1 - y0);
        let (y0, y1) = axis_range(y0 - pad, y1 + pad);
        let mut chart = ChartBuilder::on(root)
            .caption(&self.title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(80)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        // Engineering labels (50, 500m, 2µ) with the decimals the spacing needs; the
        // spacing is estimated from the span as plotters' 10 labels would divide it.
        let (xs, ys) = (tick_step(x0, x1, 20), tick_step(y0, y1, 20));
        chart
            .configure_mesh()
            .label_style(("sans-serif", TICK_FONT))
            .axis_desc_style(("sans-serif", TICK_FONT))
            .x_desc(&self.x_desc)
            .y_desc(&self.y_desc)
            .x_label_formatter(&|v| tick_label(*v, xs, x0.abs().max(x1.abs())))
            .y_label_formatter(&|v| tick_label(*v, ys, y0.abs().max(y1.abs())))
            .draw()?;
        let palette = [BLUE, RED, GREEN, MAGENTA, BLACK];
        for (i, (label, p)) in self.series.iter().enumerate() {
            let c = palette[i % palette.len()];
            let w = if i == 0 { 2 } else { 1 };
            // A non-finite point is a gap: each finite stretch is its own line.
            let stretches = p
                .split(|(x, y)| !(x.is_finite() && y.is_finite()))
                .filter(|s| !s.is_empty());
            for (j, stretch) in stretches.enumerate() {
                let drawn = chart
                    .draw_series(LineSeries::new(stretch.iter().copied(), c.stroke_width(w)))?;
                if j == 0 {
                    drawn.label(label).legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(w))
                    });
                }
            }
        }
        draw_legend(&mut chart, SeriesLabelPosition::UpperRight)
    }
}

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

    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult
    where
        DB::ErrorType: 'static,
    {
        root.fill(&WHITE)?;
        let root = root.titled(&self.title, ("sans-serif", 20))?;
        let panels = root.split_evenly((1, self.groups.len().max(1)));
        let band_colour = RGBColor(255, 200, 120);
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
            let mut y0 = b - 0.1 * extent;
            let mut y1 = b + 0.1 * extent;
            for &v in group.values.iter().filter(|v| v.is_finite()) {
                y0 = y0.min(v);
                y1 = y1.max(v);
            }
            if let Some((lo, hi, _)) = band {
                y0 = y0.min(lo);
                y1 = y1.max(hi);
            }
            let (y0, y1) = axis_range(y0, y1);
            let pad = 0.08 * (y1 - y0);
            let (y0, y1) = axis_range(y0 - pad, y1 + pad);
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
            let ys = tick_step(y0, y1, 20);
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
                .y_desc(&self.y_desc)
                .y_label_formatter(&|v| tick_label(*v, ys, y0.abs().max(y1.abs())))
                .draw()?;
            if let Some((lo, hi, _)) = band {
                chart
                    .draw_series([Rectangle::new(
                        [(0.5, lo), (m + 0.5, hi)],
                        band_colour.mix(0.5).filled(),
                    )])?
                    .label(&self.band_desc)
                    .legend(move |(px, py)| {
                        Rectangle::new([(px, py - 5), (px + 20, py + 5)], band_colour.filled())
                    });
            }
            chart.draw_series(
                group
                    .values
                    .iter()
                    .enumerate()
                    .filter(|(_, v)| v.is_finite())
                    .map(|(i, &v)| {
                        let x = (i + 1) as f64;
                        Rectangle::new([(x - 0.35, b), (x + 0.35, v)], BLUE.mix(0.7).filled())
                    }),
            )?;
            chart
                .draw_series(LineSeries::new(
                    [(0.5, b), (m + 0.5, b)],
                    BLACK.stroke_width(1),
                ))?
                .label(format!("{b}"))
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLACK));
            draw_legend(&mut chart, SeriesLabelPosition::LowerRight)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::{tick_label, tick_step};

    /// Every text of a figure — ticks, axis names, legend — is at least 11 px in the SVG
    /// (plotters' default made ticks and legends 9.7 px).
    #[test]
    fn figure_text_is_at_least_11_px() {
        let dir = std::env::temp_dir().join(format!("nlsim-plot-font-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("lines.svg");
        let fig = super::Lines {
            title: "t".into(),
            x_desc: "frequency (Hz)".into(),
            y_desc: "|y| (m)".into(),
            series: vec![
                (
                    "a".into(),
                    vec![(1.0, 2.0), (2.0, 3.0), (3.0, f64::NAN), (4.0, 1.0)],
                ),
                ("b".into(), vec![(1.0, 1.0), (4.0, 2.5)]),
            ],
        };
        super::write(&path, &fig).unwrap();
        let svg = std::fs::read_to_string(&path).unwrap();
        std::fs::remove_dir_all(&dir).unwrap();
        let sizes: Vec<f64> = svg
            .split("font-size=\"")
            .skip(1)
            .map(|r| r.split('"').next().unwrap().parse().unwrap())
            .collect();
        assert!(sizes.len() > 10, "{svg}");
        assert!(sizes.iter().all(|&s| s >= 11.0), "{sizes:?}");
    }

    #[test]
    fn log_axis_ticks_each_carry_their_own_prefix() {
        let labels: Vec<String> = (-14..=-5)
            .map(|e| super::log_tick_label(10f64.powi(e)))
            .collect();
        assert_eq!(
            labels,
            [
                "10f", "100f", "1p", "10p", "100p", "1n", "10n", "100n", "1µ", "10µ"
            ]
        );
        assert_eq!(super::log_tick_label(2e-7), "200n");
    }

    #[test]
    fn tick_labels_are_engineering_numbers_from_1e_minus_9_to_1e9() {
        for (v, step, want) in [
            (0.0, 1.0, "0"),
            (50.0, 10.0, "50"),
            (0.5, 0.1, "500m"),
            (2e-3, 1e-3, "2m"),
            (-2e-3, 1e-3, "-2m"),
            (1.5e-6, 5e-7, "1.5µ"),
            (1e-9, 1e-10, "1n"),
            (2.5e-9, 5e-10, "2.5n"),
            (1e9, 1e8, "1G"),
            (3.25e9, 5e7, "3.25G"),
            (12_500.0, 2_500.0, "12.5k"),
            (999.0, 1.0, "999"),
            (1000.0, 100.0, "1k"),
            (31.0715, 0.0001, "31.0715"),
            (-750.0, 250.0, "-750"),
            (4.08e-5, 2e-7, "40.8µ"),
            (0.25, 0.1, "250m"),
            (1.25, 0.1, "1.25"),
            (0.30000000000000004, 0.1, "300m"),
            // A tick a rounding error from zero on an axis through it.
            (1e-17, 0.1, "0"),
            (2e-20, 0.0, "2.000e-20"),
            (5e15, 1e15, "5.000e15"),
        ] {
            assert_eq!(tick_label(v, step, v.abs()), want, "{v} with step {step}");
        }
        // One prefix per axis: a ratio axis around 1, a millimetre axis.
        assert_eq!(tick_label(0.999, 5e-4, 1.004), "0.999");
        assert_eq!(tick_label(1.0, 5e-4, 1.004), "1");
        assert_eq!(tick_label(5e-4, 5e-4, 2e-3), "0.5m");
        assert_eq!(tick_label(-1.5e-3, 5e-4, 2e-3), "-1.5m");
        assert_eq!(tick_label(0.0, 5e-4, 2e-3), "0");
        // Neighbouring ticks of a narrow axis stay distinct.
        let step = tick_step(1.0001, 1.0009, 8);
        let labels: Vec<String> = (1..=8)
            .map(|i| tick_label(1.0 + i as f64 * 1e-4, step, 1.001))
            .collect();
        let mut unique = labels.clone();
        unique.dedup();
        assert_eq!(unique.len(), 8, "{labels:?}");
    }

    #[test]
    fn tick_steps_are_1_2_5_decades() {
        assert_eq!(tick_step(0.0, 10.0, 10), 1.0);
        assert_eq!(tick_step(0.0, 4.5e-3, 10), 2e-4);
        assert_eq!(tick_step(0.0, 70.0, 10), 5.0);
        assert_eq!(tick_step(1.0, 1.0, 10), 0.0);
    }
}
