//! The figure of a multi-harmonic FRF: one panel per harmonic (magnitude, optionally phase),
//! stable and unstable points of every branch, folds and bifurcations marked; used by
//! `nlsim frf --plot`, the FRF report and the demo.
use crate::error::{Error, Result};
use crate::formats::files::unit;
use crate::formats::frf_file::harmonic_label;
use faer::{Mat, c64};
use nlsim_hb::{Branch, HbSystem, PointKind};
use std::path::Path;

/// How an FRF plot's magnitude axis reads.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Magnitude {
    /// `|Y|` in the sensor's unit on a linear axis.
    #[default]
    Linear,
    /// `|Y|` on a logarithmic axis.
    Log,
    /// `20 log₁₀(|Y| / 1 unit)`, dB re 1 m (or m/s, m/s²).
    Db,
}

impl Magnitude {
    /// The name used on the command line: `linear`, `log` or `db`.
    pub fn as_str(self) -> &'static str {
        match self {
            Magnitude::Linear => "linear",
            Magnitude::Log => "log",
            Magnitude::Db => "db",
        }
    }
}

impl std::str::FromStr for Magnitude {
    type Err = Error;
    fn from_str(s: &str) -> Result<Self> {
        match s {
            "linear" => Ok(Magnitude::Linear),
            "log" => Ok(Magnitude::Log),
            "db" | "dB" => Ok(Magnitude::Db),
            _ => Err(Error::Usage(format!(
                "magnitude axis '{s}': use linear, log or db"
            ))),
        }
    }
}

/// The magnitude axis of measured-against-model FRF plots: harmonic `k` of a `quantity`
/// response over the fundamental force, `|acceleration h3| / |F1| (m/s^2/N)`.
pub fn harmonic_over_force_axis(quantity: nlsim_kernel::Quantity, k: usize) -> String {
    format!("|{} h{k}| / |F1| ({}/N)", quantity.as_str(), unit(quantity))
}

/// Plots the FRF of sensor `sensor` (responses `y` from `commands::frf::responses`) as SVG or PNG by the
/// extension of `path`: one panel per harmonic carrying response, each on its own scale,
/// magnitude read as `magnitude`, with a phase panel beside each when `phase`, a gap across
/// each of `gaps` (Hz, a stepped sine's unsolved frequencies); stable parts
/// in the harmonic's colour, unstable parts red, folds and jumps marked. Written atomically.
#[allow(clippy::too_many_arguments)]
pub fn plot_frf(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    sensor: usize,
    title: &str,
    magnitude: Magnitude,
    phase: bool,
    gaps: &[f64],
) -> Result<()> {
    crate::present::plot::write(
        path,
        &FrfPlot {
            sys,
            branch,
            y,
            sensor,
            title,
            magnitude,
            phase,
            gaps,
        },
    )
}

/// The FRF plot of [`plot_frf`], as a [`crate::present::plot::Figure`].
pub struct FrfPlot<'a> {
    /// The system the branch belongs to.
    pub sys: &'a HbSystem,
    /// The solution points.
    pub branch: &'a Branch,
    /// Sensor responses per point, from `commands::frf::responses`.
    pub y: &'a [Mat<c64>],
    /// Sensor plotted.
    pub sensor: usize,
    /// Title above the plot.
    pub title: &'a str,
    /// How the magnitude axes read.
    pub magnitude: Magnitude,
    /// Whether a phase panel goes beside each magnitude panel.
    pub phase: bool,
    /// Frequencies (Hz) a stepped sine could not solve: the curve has a gap across each.
    pub gaps: &'a [f64],
}

/// At most this many harmonic panels: the fundamental and the largest others.
const MAX_PANELS: usize = 5;

/// A harmonic's phase is drawn only where its amplitude reaches this fraction of the figure's
/// largest amplitude (120 dB below it): below, it is set by the solver's round-off (Newton
/// stops at a residual about 1e-10 of the response), not by the structure.
pub const PHASE_FLOOR: f64 = 1e-6;

impl FrfPlot<'_> {
    fn hz(&self) -> Vec<f64> {
        self.branch
            .points
            .iter()
            .map(|p| p.omega / (2.0 * std::f64::consts::PI))
            .collect()
    }

    fn amp(&self, i: usize, k: usize) -> f64 {
        self.y[i][(self.sensor, k)].norm()
    }

    /// The harmonics drawn, in increasing order: the fundamental (`k = ν`) and those whose
    /// largest amplitude reaches 1e-9 of the largest harmonic's, the largest first when more
    /// than [`MAX_PANELS`] qualify. Each has its own scale, so side harmonics 1e-4 of the
    /// fundamental are read as easily.
    fn shown(&self) -> Vec<usize> {
        let nk = self.sys.harmonics().h + 1;
        let nu = self.sys.harmonics().nu;
        let peak: Vec<f64> = (0..nk)
            .map(|k| (0..self.y.len()).fold(0.0f64, |m, i| m.max(self.amp(i, k))))
            .collect();
        let top = peak.iter().fold(0.0f64, |m, v| m.max(*v));
        let mut cands: Vec<usize> = (0..nk)
            .filter(|&k| k != nu && peak[k] > 1e-9 * top && peak[k] > 0.0)
            .collect();
        cands.sort_by(|&a, &b| peak[b].total_cmp(&peak[a]));
        cands.truncate(MAX_PANELS - 1);
        if nu < nk {
            cands.push(nu);
        }
        cands.sort_unstable();
        cands
    }

    /// The plotted magnitude of a response amplitude `a` (dB values for [`Magnitude::Db`]).
    fn mag(&self, a: f64, floor: f64) -> f64 {
        match self.magnitude {
            Magnitude::Linear => a,
            Magnitude::Log => a.max(floor),
            Magnitude::Db => 20.0 * a.max(floor).log10(),
        }
    }

    fn mag_label(&self) -> String {
        let sen = &self.sys.sensors()[self.sensor];
        let u = unit(sen.quantity);
        match self.magnitude {
            Magnitude::Linear | Magnitude::Log => format!("|{}| ({u})", sen.name),
            Magnitude::Db => format!("|{}| (dB re 1 {u})", sen.name),
        }
    }

    fn panel_name(&self, k: usize) -> String {
        let nu = self.sys.harmonics().nu;
        format!(
            "harmonic {}{}",
            harmonic_label(k, nu),
            if k == nu { " (fundamental)" } else { "" }
        )
    }

    /// Phase of harmonic `k` at point `i` in degrees, `(−180, 180]`, in the convention
    /// `q(t) = Re(Σ Q_k e^{i k Ω t / ν})`; NaN (not drawn) where the harmonic's amplitude is
    /// below `min_amp` ([`Self::phase_min_amp`]), where its phase is noise.
    fn phase_deg(&self, i: usize, k: usize, min_amp: f64) -> f64 {
        let y = self.y[i][(self.sensor, k)];
        if y.norm() < min_amp {
            f64::NAN
        } else {
            y.arg().to_degrees()
        }
    }

    /// The largest amplitude of any harmonic at any point (sensor's unit).
    fn top(&self) -> f64 {
        self.y
            .iter()
            .flat_map(|m| (0..m.ncols()).map(move |k| m[(self.sensor, k)].norm()))
            .fold(0.0f64, f64::max)
    }

    /// The amplitude below which a phase is not drawn: [`PHASE_FLOOR`] of the figure's
    /// largest amplitude.
    fn phase_min_amp(&self) -> f64 {
        PHASE_FLOOR * self.top()
    }
}

impl crate::present::plot::Figure for FrfPlot<'_> {
    fn size(&self) -> (u32, u32) {
        let rows = self.shown().len().max(1) as u32;
        (if self.phase { 1280 } else { 960 }, 60 + 260 * rows)
    }

    fn title(&self) -> String {
        self.title.to_string()
    }

    fn data(&self) -> Vec<crate::present::plot::SeriesData> {
        let hz = self.hz();
        let floor = self.floor();
        let min_amp = self.phase_min_amp();
        let mut out = Vec::new();
        let x_label = "frequency (Hz)".to_string();
        for k in self.shown() {
            let panel = self.panel_name(k);
            out.push(crate::present::plot::SeriesData {
                panel: panel.clone(),
                label: "magnitude".into(),
                x_label: x_label.clone(),
                y_label: self.mag_label(),
                x: hz.clone(),
                y: (0..hz.len())
                    .map(|i| self.mag(self.amp(i, k), floor))
                    .collect(),
            });
            if self.phase {
                out.push(crate::present::plot::SeriesData {
                    panel: panel.clone(),
                    label: "phase".into(),
                    x_label: x_label.clone(),
                    y_label: "phase (deg)".into(),
                    x: hz.clone(),
                    y: (0..hz.len())
                        .map(|i| self.phase_deg(i, k, min_amp))
                        .collect(),
                });
            }
            for (kind, label) in [(PointKind::Fold, "fold"), (PointKind::Jump, "jump")] {
                let idx: Vec<usize> = (0..hz.len())
                    .filter(|&i| self.branch.points[i].kind == kind)
                    .collect();
                if !idx.is_empty() {
                    out.push(crate::present::plot::SeriesData {
                        panel: panel.clone(),
                        label: label.into(),
                        x_label: x_label.clone(),
                        y_label: self.mag_label(),
                        x: idx.iter().map(|&i| hz[i]).collect(),
                        y: idx
                            .iter()
                            .map(|&i| self.mag(self.amp(i, k), floor))
                            .collect(),
                    });
                }
            }
        }
        out
    }

    fn draw<DB: plotters::prelude::DrawingBackend>(
        &self,
        root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
        layout: &mut crate::present::plot::Layout,
    ) -> crate::present::plot::DrawResult
    where
        DB::ErrorType: 'static,
    {
        use crate::present::plot::{Entry, Swatch};
        use plotters::prelude::*;
        root.fill(&WHITE)?;
        let root = root.titled(self.title, ("sans-serif", 20))?;
        // One legend for every panel: the styles are the same in each.
        let has = |kind: PointKind| self.branch.points.iter().any(|p| p.kind == kind);
        let mut entries = vec![Entry::new("stable", Swatch::Line(STABLE, 2))];
        if self.branch.points.iter().any(|p| p.stable() == Some(false)) {
            entries.push(Entry::new("unstable", Swatch::Line(UNSTABLE, 2)));
        }
        if has(PointKind::Fold) {
            entries.push(Entry::new("fold", Swatch::Dot(BLACK)));
        }
        if has(PointKind::Jump) {
            entries.push(Entry::new("jump (stepped sine)", Swatch::Triangle(BLACK)));
        }
        let root = crate::present::plot::legend_band(&root, &entries, layout)?;
        let shown = self.shown();
        let cols = if self.phase { 2 } else { 1 };
        let areas = root.split_evenly((shown.len().max(1), cols));
        for (row, &k) in shown.iter().enumerate() {
            self.draw_panel(&areas[row * cols], k, false, layout)?;
            if self.phase {
                self.draw_panel(&areas[row * cols + 1], k, true, layout)?;
            }
        }
        Ok(())
    }
}

/// Colour of stable branches in every panel.
const STABLE: plotters::style::RGBColor = plotters::style::BLUE;
/// Colour of unstable branches in every panel.
const UNSTABLE: plotters::style::RGBColor = plotters::style::RED;

impl FrfPlot<'_> {
    /// The smallest magnitude drawn on a log or dB axis: 1e-12 of the largest.
    fn floor(&self) -> f64 {
        (1e-12 * self.top()).max(f64::MIN_POSITIVE)
    }

    /// One panel: the magnitude (or phase) of harmonic `k`, stable stretches blue, unstable
    /// red, folds and jumps marked; recorded in `layout`.
    fn draw_panel<DB: plotters::prelude::DrawingBackend>(
        &self,
        area: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
        k: usize,
        phase: bool,
        layout: &mut crate::present::plot::Layout,
    ) -> crate::present::plot::DrawResult
    where
        DB::ErrorType: 'static,
    {
        use crate::present::plot::{LinearAxis, TICK_FONT};
        use plotters::prelude::*;
        let hz = self.hz();
        let n = hz.len();
        let floor = self.floor();
        let min_amp = self.phase_min_amp();
        let value = |i: usize| {
            if phase {
                self.phase_deg(i, k, min_amp)
            } else {
                self.mag(self.amp(i, k), floor)
            }
        };
        let vals: Vec<f64> = (0..n).map(value).collect();
        let (x0, x1) = hz
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(*v), b.max(*v))
            });
        let (x0, x1) = crate::present::plot::axis_range(x0, x1.max(x0 * (1.0 + 1e-9) + 1e-9));
        let (v0, v1) = vals
            .iter()
            .filter(|v| v.is_finite())
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(*v), b.max(*v))
            });
        let (v0, v1) = crate::present::plot::axis_range(v0, v1);
        let caption = format!(
            "{}{}",
            self.panel_name(k),
            match (phase, phase && vals.iter().any(|v| v.is_nan())) {
                (false, _) => "",
                (true, false) => ": phase",
                (true, true) => ": phase (drawn where |Y| ≥ 1e-6 of the largest)",
            }
        );
        let y_desc = if phase {
            "phase (deg)".to_string()
        } else {
            self.mag_label()
        };
        let mut builder = ChartBuilder::on(area);
        builder
            .caption(caption, ("sans-serif", 15))
            .margin(8)
            .x_label_area_size(40)
            .y_label_area_size(76);
        let xa = LinearAxis::new("frequency (Hz)", x0, x1, 20);
        let x_fmt = |v: &f64| xa.label(*v);
        // Segments of equal stability; a jump starts a new curve, and so do a phase wrap and a
        // skipped frequency.
        let segments = || {
            let mut out: Vec<(bool, Vec<(f64, f64)>)> = Vec::new();
            for i in 0..n {
                let stable = self.branch.points[i].stable() != Some(false);
                let jump = self.branch.points[i].kind == PointKind::Jump;
                // A masked phase (NaN) is left out, the curve broken there.
                if !vals[i].is_finite() {
                    out.push((stable, Vec::new()));
                    continue;
                }
                let wrap = phase && i > 0 && (vals[i] - vals[i - 1]).abs() > 180.0;
                let gap = i > 0
                    && self
                        .gaps
                        .iter()
                        .any(|&g| (g - hz[i - 1]) * (hz[i] - g) > 0.0);
                match out.last_mut() {
                    Some((s, pts)) if pts.is_empty() => {
                        *s = stable;
                        pts.push((hz[i], vals[i]));
                    }
                    Some((s, pts)) if !jump && !wrap && !gap => {
                        pts.push((hz[i], vals[i]));
                        if *s != stable {
                            // The shared point ends one stretch and starts the next.
                            out.push((stable, vec![(hz[i], vals[i])]));
                        }
                    }
                    _ => out.push((stable, vec![(hz[i], vals[i])])),
                }
            }
            out.retain(|(_, p)| !p.is_empty());
            out
        };
        let marks = |kind: PointKind| -> Vec<(f64, f64)> {
            (0..n)
                .filter(|&i| self.branch.points[i].kind == kind && vals[i].is_finite())
                .map(|i| (hz[i], vals[i]))
                .collect()
        };
        // The drawing is the same on a linear and a log axis; a macro keeps one copy.
        macro_rules! finish {
            ($chart:expr) => {{
                let mut chart = $chart;
                for (stable, pts) in segments() {
                    let colour = if stable { STABLE } else { UNSTABLE };
                    chart.draw_series(LineSeries::new(pts, colour.stroke_width(2)))?;
                }
                let folds = marks(PointKind::Fold);
                chart.draw_series(folds.iter().map(|&p| Circle::new(p, 5, BLACK.filled())))?;
                let jumps = marks(PointKind::Jump);
                chart.draw_series(
                    jumps
                        .iter()
                        .map(|&p| TriangleMarker::new(p, 6, BLACK.filled())),
                )?;
                layout.panel(
                    &chart,
                    (0..n)
                        .filter(|&i| vals[i].is_finite())
                        .map(|i| (hz[i], vals[i])),
                );
            }};
        }
        if phase {
            let chart = builder.build_cartesian_2d(x0..x1, -180.0..180.0)?;
            let mut chart = chart;
            chart
                .configure_mesh()
                .label_style(("sans-serif", TICK_FONT))
                .axis_desc_style(("sans-serif", TICK_FONT))
                .x_desc(&xa.desc)
                .y_desc(&y_desc)
                .x_label_formatter(&x_fmt)
                .y_labels(9)
                .y_label_formatter(&|v| format!("{v:.0}"))
                .draw()?;
            finish!(chart);
        } else if self.magnitude == Magnitude::Log {
            let (lo, hi) =
                crate::present::plot::log_axis_range(v0.max(floor) / 1.2, v1.max(floor) * 1.2);
            let mut chart = builder.build_cartesian_2d(x0..x1, (lo..hi).log_scale())?;
            chart
                .configure_mesh()
                .label_style(("sans-serif", TICK_FONT))
                .axis_desc_style(("sans-serif", TICK_FONT))
                .x_desc(&xa.desc)
                .y_desc(&y_desc)
                .x_label_formatter(&x_fmt)
                .y_label_formatter(&|v| crate::present::plot::log_tick_label(*v))
                .draw()?;
            finish!(chart);
        } else {
            let (lo, hi) = if self.magnitude == Magnitude::Db {
                let span = (v1 - v0).max(1.0);
                (v0 - 0.05 * span, v1 + 0.05 * span)
            } else {
                (0.0, v1 * 1.05 + 1e-300)
            };
            let (lo, hi) = crate::present::plot::axis_range(lo, hi);
            let ya = LinearAxis::new(&y_desc, lo, hi, 20);
            let mut chart = builder.build_cartesian_2d(x0..x1, lo..hi)?;
            chart
                .configure_mesh()
                .label_style(("sans-serif", TICK_FONT))
                .axis_desc_style(("sans-serif", TICK_FONT))
                .x_desc(&xa.desc)
                .y_desc(&ya.desc)
                .x_label_formatter(&x_fmt)
                .y_label_formatter(&|v| ya.label(*v))
                .draw()?;
            finish!(chart);
        }
        Ok(())
    }
}
