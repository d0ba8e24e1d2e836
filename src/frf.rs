//! `nlsim frf`: writing multi-harmonic FRFs (HDF5 or CSV) and plotting them (SVG).
//! The file layouts are documented in `docs/file-formats.md`.

use crate::error::{Error, Result};
use crate::output::{Format, f64_attr, str_attr, unit};
use faer::{Mat, c64};
use hdf5_metno as hdf5;
use nlsim_hb::{Branch, HbSystem, PointKind};
use std::fmt::Write as _;
use std::path::Path;

/// What each output format of `nlsim frf` holds, for the usage error.
pub const HINT: &str = ".h5 (HDF5, complex harmonics) or .csv (one row per solution point)";

/// What is stored with the data.
#[derive(Debug, Clone)]
pub struct FrfInfo {
    /// The model spec as given on the command line.
    pub model_spec: String,
    /// The model's own name.
    pub model_name: String,
    /// `continuation`, `step-up` or `step-down`.
    pub mode: String,
    /// Retained modes.
    pub modes: usize,
    /// Whether residual flexibility was included.
    pub residual: bool,
    /// Wall time of the solve (s).
    pub seconds: f64,
    /// Located response maxima ([`crate::run::FrfRun::peaks`]).
    pub peaks: Vec<nlsim_hb::Peak>,
    /// The run's notes ([`crate::run::FrfRun::notes`]).
    pub notes: Vec<String>,
}

/// Writes the located maxima `peaks` as the group `peaks` of `g`: per maximum its sensor
/// (index into the `sensors` attribute), harmonic index `k` and ratio `k/ν`, frequency (Hz),
/// level, `|Y_k|` in the sensor's unit and whether it was located between points.
pub(crate) fn write_peaks(
    g: &hdf5::Group,
    sys: &HbSystem,
    peaks: &[nlsim_hb::Peak],
) -> hdf5::Result<()> {
    if peaks.is_empty() {
        return Ok(());
    }
    let gp = g.create_group("peaks")?;
    let names: Vec<&str> = sys.sensors().iter().map(|s| s.name.as_str()).collect();
    str_attr(&gp, "sensors", &names.join(","))?;
    str_attr(
        &gp,
        "note",
        "the largest |Y_k| of each sensor and harmonic along the branch; located = 1 when found \
         between computed points by maximising along the branch, 0 when it is an end point",
    )?;
    let sensor: Vec<u32> = peaks.iter().map(|p| p.sensor as u32).collect();
    gp.new_dataset_builder()
        .with_data(&sensor)
        .create("sensor")?;
    let k: Vec<u32> = peaks.iter().map(|p| p.harmonic as u32).collect();
    gp.new_dataset_builder().with_data(&k).create("harmonic")?;
    let nu = sys.harmonics().nu as f64;
    let ratio: Vec<f64> = peaks.iter().map(|p| p.harmonic as f64 / nu).collect();
    let d = gp
        .new_dataset_builder()
        .with_data(&ratio)
        .create("harmonic_ratio")?;
    str_attr(&d, "unit", "1")?;
    let hz: Vec<f64> = peaks
        .iter()
        .map(|p| p.omega / (2.0 * std::f64::consts::PI))
        .collect();
    let d = gp
        .new_dataset_builder()
        .with_data(&hz)
        .create("frequency")?;
    str_attr(&d, "unit", "Hz")?;
    let level: Vec<f64> = peaks.iter().map(|p| p.scale).collect();
    let d = gp.new_dataset_builder().with_data(&level).create("level")?;
    str_attr(&d, "unit", "1")?;
    let v: Vec<f64> = peaks.iter().map(|p| p.value).collect();
    let d = gp.new_dataset_builder().with_data(&v).create("magnitude")?;
    str_attr(&d, "unit", "the sensor's (m, m/s or m/s^2)")?;
    let located: Vec<u8> = peaks.iter().map(|p| u8::from(p.located)).collect();
    gp.new_dataset_builder()
        .with_data(&located)
        .create("located")?;
    Ok(())
}

/// Sensor responses (sensors × harmonics) of every point.
pub fn responses(sys: &HbSystem, branch: &Branch) -> Vec<Mat<c64>> {
    branch
        .points
        .iter()
        .map(|p| sys.sensor_response(&p.x, p.omega, p.scale))
        .collect()
}

fn kind_code(k: PointKind) -> u8 {
    match k {
        PointKind::Regular => 0,
        PointKind::Fold => 1,
        PointKind::End => 2,
        PointKind::Jump => 3,
    }
}

fn stable_code(p: &nlsim_hb::SolutionPoint) -> i8 {
    match p.stable() {
        Some(true) => 1,
        Some(false) => 0,
        None => -1,
    }
}

/// Label of harmonic `k` of `Ω/ν` as a multiple of the fundamental: `1`, `2`, `1/3`, `2/3`.
pub fn harmonic_label(k: usize, nu: usize) -> String {
    if k.is_multiple_of(nu) {
        format!("{}", k / nu)
    } else {
        format!("{k}/{nu}")
    }
}

/// Writes the FRF of `branch` with its sensor responses `y` (from [`responses`]): HDF5 for
/// `.h5`/`.hdf5`, CSV for `.csv`, atomically.
pub fn write_frf(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    info: &FrfInfo,
) -> Result<()> {
    crate::output::write_atomically(path, HINT, |tmp, format| match format {
        Format::Csv => write_csv(tmp, sys, branch, y, info),
        Format::Hdf5 => write_hdf5(tmp, sys, branch, y, info),
    })
}

fn write_csv(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    info: &FrfInfo,
) -> Result<()> {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# nlsim {} frf: model {}, mode {}, H = {} harmonics of Omega/{}, {} modes{}",
        env!("CARGO_PKG_VERSION"),
        info.model_spec,
        info.mode,
        sys.harmonics().h,
        sys.harmonics().nu,
        info.modes,
        if info.residual {
            " + residual flexibility"
        } else {
            ""
        }
    );
    let _ = writeln!(
        s,
        "# stable: 1 stable, 0 unstable, -1 not computed; kind: 0 regular, 1 fold, 2 end, 3 jump; \
         <sensor>_h<r>_re/_im: complex amplitude of harmonic r x Omega (q = Re(Q e^(i r Omega t)))"
    );
    let nu = sys.harmonics().nu;
    for p in &info.peaks {
        let _ = writeln!(
            s,
            "# peak {} harmonic {}: |Y| = {:.10e} at {:.10e} Hz ({})",
            sys.sensors()[p.sensor].name,
            harmonic_label(p.harmonic, nu),
            p.value,
            p.omega / (2.0 * std::f64::consts::PI),
            if p.located { "located" } else { "end point" }
        );
    }
    for b in &branch.bifurcations {
        let _ = writeln!(
            s,
            "# bifurcation {} at {:.10e} Hz ({})",
            b.kind.as_str(),
            b.omega / (2.0 * std::f64::consts::PI),
            if b.located { "located" } else { "interpolated" }
        );
    }
    for note in &info.notes {
        let _ = writeln!(s, "# note: {note}");
    }
    s.push_str("frequency_hz,level,stable,kind,max_floquet_real_per_s");
    for sen in sys.sensors() {
        for k in 0..=sys.harmonics().h {
            let l = harmonic_label(k, sys.harmonics().nu).replace('/', "_");
            let u = unit(sen.quantity).replace('/', "_per_").replace("^2", "2");
            let _ = write!(s, ",{0}_h{l}_re_{u},{0}_h{l}_im_{u}", sen.name);
        }
    }
    s.push('\n');
    for (p, yp) in branch.points.iter().zip(y) {
        let _ = write!(
            s,
            "{:.10e},{:.6e},{},{},{:.6e}",
            p.omega / (2.0 * std::f64::consts::PI),
            p.scale,
            stable_code(p),
            kind_code(p.kind),
            p.stability.as_ref().map_or(f64::NAN, |s| s.max_real)
        );
        for r in 0..yp.nrows() {
            for k in 0..yp.ncols() {
                let _ = write!(s, ",{:.9e},{:.9e}", yp[(r, k)].re, yp[(r, k)].im);
            }
        }
        s.push('\n');
    }
    std::fs::write(path, s).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn write_hdf5(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    info: &FrfInfo,
) -> Result<()> {
    let err = crate::output::h5err(path);
    let file = hdf5::File::create(path).map_err(&err)?;
    let root = file.as_group().map_err(&err)?;
    crate::output::provenance(
        &root,
        "frf",
        &info.model_spec,
        info.model_name.as_str(),
        None,
    )
    .map_err(&err)?;
    str_attr(&root, "mode", &info.mode).map_err(&err)?;
    f64_attr(&root, "modes", info.modes as f64).map_err(&err)?;
    f64_attr(
        &root,
        "residual_flexibility",
        f64::from(u8::from(info.residual)),
    )
    .map_err(&err)?;
    f64_attr(&root, "wall_seconds", info.seconds).map_err(&err)?;
    if !info.notes.is_empty() {
        str_attr(&root, "notes", &info.notes.join("\n")).map_err(&err)?;
    }
    write_group(&root, sys, branch, y).map_err(&err)?;
    write_peaks(&root, sys, &info.peaks).map_err(&err)?;
    file.flush().map_err(&err)?;
    Ok(())
}

/// Writes the FRF datasets of `branch` into `g` (the layout of `docs/file-formats.md`; used
/// for `nlsim frf` files and for each job of an `nlsim batch` shard).
pub(crate) fn write_group(
    g: &hdf5::Group,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
) -> hdf5::Result<()> {
    str_attr(
        g,
        "convention",
        "q(t) = Re(sum_k Q_k exp(i k Omega t / nu)); harmonic k is at k/nu times the fundamental",
    )?;
    f64_attr(g, "harmonics", sys.harmonics().h as f64)?;
    f64_attr(g, "subharmonic_order", sys.harmonics().nu as f64)?;
    let n = branch.points.len();
    let real = |g: &hdf5::Group, name: &str, data: &[f64], u: &str| -> hdf5::Result<()> {
        let d = g.new_dataset_builder().with_data(data).create(name)?;
        str_attr(&d, "unit", u)
    };
    let hz: Vec<f64> = branch
        .points
        .iter()
        .map(|p| p.omega / (2.0 * std::f64::consts::PI))
        .collect();
    real(g, "frequency", &hz, "Hz")?;
    let level: Vec<f64> = branch.points.iter().map(|p| p.scale).collect();
    real(g, "level", &level, "1")?;
    let fl: Vec<f64> = branch
        .points
        .iter()
        .map(|p| p.stability.as_ref().map_or(f64::NAN, |s| s.max_real))
        .collect();
    real(g, "max_floquet_real", &fl, "1/s")?;
    let st: Vec<i8> = branch.points.iter().map(stable_code).collect();
    let d = g.new_dataset_builder().with_data(&st).create("stable")?;
    str_attr(&d, "legend", "1 stable, 0 unstable, -1 not computed")?;
    let kd: Vec<u8> = branch.points.iter().map(|p| kind_code(p.kind)).collect();
    let d = g.new_dataset_builder().with_data(&kd).create("kind")?;
    str_attr(&d, "legend", "0 regular, 1 fold, 2 end, 3 jump")?;
    let ratio: Vec<f64> = (0..=sys.harmonics().h)
        .map(|k| k as f64 / sys.harmonics().nu as f64)
        .collect();
    real(g, "harmonic_ratio", &ratio, "1")?;
    let gsen = g.create_group("sensors")?;
    let nk = sys.harmonics().h + 1;
    for (s, sen) in sys.sensors().iter().enumerate() {
        let gs = gsen.create_group(&sen.name)?;
        str_attr(&gs, "quantity", sen.quantity.as_str())?;
        let data: Vec<c64> = (0..n)
            .flat_map(|i| (0..nk).map(move |k| (i, k)))
            .map(|(i, k)| y[i][(s, k)])
            .collect();
        let d = gs.new_dataset::<c64>().shape((n, nk)).create("response")?;
        d.write_raw(&data)?;
        str_attr(&d, "unit", unit(sen.quantity))?;
        str_attr(&d, "dims", "point x harmonic")?;
        // FRFs per input: Y_k / F_k where harmonic k is forced.
        for (i, (name, _)) in sys.inputs().iter().enumerate() {
            let frf: Vec<c64> = (0..n)
                .flat_map(|p| (0..nk).map(move |k| (p, k)))
                .map(|(p, k)| {
                    let f = sys.forcing().amplitude(i, k) * branch.points[p].scale;
                    if f == c64::new(0.0, 0.0) {
                        c64::new(f64::NAN, f64::NAN)
                    } else {
                        y[p][(s, k)] / f
                    }
                })
                .collect();
            let d = gs
                .new_dataset::<c64>()
                .shape((n, nk))
                .create(format!("frf_{name}").as_str())?;
            d.write_raw(&frf)?;
            str_attr(&d, "unit", &format!("{}/N", unit(sen.quantity)))?;
            str_attr(&d, "note", "NaN where the harmonic carries no force")?;
        }
    }
    if !branch.bifurcations.is_empty() {
        let gb = g.create_group("bifurcations")?;
        let kind: Vec<u8> = branch
            .bifurcations
            .iter()
            .map(|b| match b.kind {
                nlsim_hb::BifurcationKind::Fold => 0,
                nlsim_hb::BifurcationKind::BranchPoint => 1,
                nlsim_hb::BifurcationKind::PeriodDoubling => 2,
                nlsim_hb::BifurcationKind::NeimarkSacker => 3,
            })
            .collect();
        let d = gb.new_dataset_builder().with_data(&kind).create("kind")?;
        str_attr(
            &d,
            "legend",
            "0 fold, 1 branch point, 2 period doubling, 3 Neimark-Sacker",
        )?;
        let hz: Vec<f64> = branch
            .bifurcations
            .iter()
            .map(|b| b.omega / (2.0 * std::f64::consts::PI))
            .collect();
        real(&gb, "frequency", &hz, "Hz")?;
        let level: Vec<f64> = branch.bifurcations.iter().map(|b| b.scale).collect();
        real(&gb, "level", &level, "1")?;
        let located: Vec<u8> = branch
            .bifurcations
            .iter()
            .map(|b| u8::from(b.located))
            .collect();
        gb.new_dataset_builder()
            .with_data(&located)
            .create("located")?;
    }
    let gel = g.create_group("elements")?;
    let nh = sys.harmonics().len();
    for (e, el) in sys.elements().iter().enumerate() {
        let c = sys.coordinates(e);
        let data: Vec<f64> = branch
            .points
            .iter()
            .flat_map(|p| p.x[c.start * nh..c.end * nh].iter().copied())
            .collect();
        // A coupled law's coordinates side by side: (points, coordinates · (2H+1)).
        let d = gel
            .new_dataset::<f64>()
            .shape((n, c.len() * nh))
            .create(el.name())?;
        d.write_raw(&data)?;
        str_attr(&d, "unit", "m")?;
        str_attr(
            &d,
            "layout",
            "per point: c0, c1, s1, ..., cH, sH with u(t) = c0 + sum c_k cos(k w0 t) + s_k sin(k w0 t); one such block per coordinate of a coupled law",
        )?;
    }
    Ok(())
}

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

/// Plots the FRF of sensor `sensor` (responses `y` from [`responses`]) as SVG or PNG by the
/// extension of `path`: one panel per harmonic carrying response, each on its own scale,
/// magnitude read as `magnitude`, with a phase panel beside each when `phase`; stable parts
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
) -> Result<()> {
    crate::plot::write(
        path,
        &FrfPlot {
            sys,
            branch,
            y,
            sensor,
            title,
            magnitude,
            phase,
        },
    )
}

/// The FRF plot of [`plot_frf`], as a [`crate::plot::Figure`].
pub struct FrfPlot<'a> {
    /// The system the branch belongs to.
    pub sys: &'a HbSystem,
    /// The solution points.
    pub branch: &'a Branch,
    /// Sensor responses per point, from [`responses`].
    pub y: &'a [Mat<c64>],
    /// Sensor plotted.
    pub sensor: usize,
    /// Title above the plot.
    pub title: &'a str,
    /// How the magnitude axes read.
    pub magnitude: Magnitude,
    /// Whether a phase panel goes beside each magnitude panel.
    pub phase: bool,
}

/// At most this many harmonic panels: the fundamental and the largest others.
const MAX_PANELS: usize = 5;

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
    /// `q(t) = Re(Σ Q_k e^{i k Ω t / ν})`.
    fn phase_deg(&self, i: usize, k: usize) -> f64 {
        self.y[i][(self.sensor, k)].arg().to_degrees()
    }
}

impl crate::plot::Figure for FrfPlot<'_> {
    fn size(&self) -> (u32, u32) {
        let rows = self.shown().len().max(1) as u32;
        (if self.phase { 1280 } else { 960 }, 60 + 260 * rows)
    }

    fn title(&self) -> String {
        self.title.to_string()
    }

    fn data(&self) -> Vec<crate::plot::SeriesData> {
        let hz = self.hz();
        let floor = self.floor();
        let mut out = Vec::new();
        let x_label = "frequency (Hz)".to_string();
        for k in self.shown() {
            let panel = self.panel_name(k);
            out.push(crate::plot::SeriesData {
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
                out.push(crate::plot::SeriesData {
                    panel: panel.clone(),
                    label: "phase".into(),
                    x_label: x_label.clone(),
                    y_label: "phase (deg)".into(),
                    x: hz.clone(),
                    y: (0..hz.len()).map(|i| self.phase_deg(i, k)).collect(),
                });
            }
            for (kind, label) in [(PointKind::Fold, "fold"), (PointKind::Jump, "jump")] {
                let idx: Vec<usize> = (0..hz.len())
                    .filter(|&i| self.branch.points[i].kind == kind)
                    .collect();
                if !idx.is_empty() {
                    out.push(crate::plot::SeriesData {
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
    ) -> crate::plot::DrawResult
    where
        DB::ErrorType: 'static,
    {
        use plotters::prelude::*;
        root.fill(&WHITE)?;
        let root = root.titled(self.title, ("sans-serif", 20))?;
        let shown = self.shown();
        let cols = if self.phase { 2 } else { 1 };
        let areas = root.split_evenly((shown.len().max(1), cols));
        let palette = [BLUE, GREEN, MAGENTA, CYAN, BLACK, RGBColor(150, 100, 0)];
        for (row, &k) in shown.iter().enumerate() {
            let colour = if k == self.sys.harmonics().nu {
                BLUE
            } else {
                palette[1 + row % (palette.len() - 1)]
            };
            let legend = row == 0;
            self.draw_panel(&areas[row * cols], k, colour, false, legend)?;
            if self.phase {
                self.draw_panel(&areas[row * cols + 1], k, colour, true, false)?;
            }
        }
        Ok(())
    }
}

impl FrfPlot<'_> {
    /// The smallest magnitude drawn on a log or dB axis: 1e-12 of the largest.
    fn floor(&self) -> f64 {
        let top = self
            .y
            .iter()
            .flat_map(|m| (0..m.ncols()).map(move |k| m[(self.sensor, k)].norm()))
            .fold(0.0f64, f64::max);
        (1e-12 * top).max(f64::MIN_POSITIVE)
    }

    /// One panel: the magnitude (or phase) of harmonic `k`, stable stretches in `colour`,
    /// unstable red, folds and jumps marked and named in the legend.
    fn draw_panel<DB: plotters::prelude::DrawingBackend>(
        &self,
        area: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
        k: usize,
        colour: plotters::style::RGBColor,
        phase: bool,
        legend: bool,
    ) -> crate::plot::DrawResult
    where
        DB::ErrorType: 'static,
    {
        use crate::plot::{tick_label, tick_step};
        use plotters::prelude::*;
        let hz = self.hz();
        let n = hz.len();
        let floor = self.floor();
        let value = |i: usize| {
            if phase {
                self.phase_deg(i, k)
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
        let x1 = x1.max(x0 * (1.0 + 1e-9) + 1e-9);
        let (v0, v1) = vals
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(*v), b.max(*v))
            });
        let caption = format!(
            "{}{}",
            self.panel_name(k),
            if phase { ": phase" } else { "" }
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
        let xs = tick_step(x0, x1, 20);
        let x_fmt = |v: &f64| tick_label(*v, xs, x1.abs());
        // Segments of equal stability; a jump starts a new curve, and so does a phase wrap.
        let segments = || {
            let mut out: Vec<(bool, Vec<(f64, f64)>)> = Vec::new();
            for i in 0..n {
                let stable = self.branch.points[i].stable() != Some(false);
                let jump = self.branch.points[i].kind == PointKind::Jump;
                let wrap = phase && i > 0 && (vals[i] - vals[i - 1]).abs() > 180.0;
                match out.last_mut() {
                    Some((s, pts)) if !jump && !wrap => {
                        pts.push((hz[i], vals[i]));
                        if *s != stable {
                            // The shared point ends one stretch and starts the next.
                            out.push((stable, vec![(hz[i], vals[i])]));
                        }
                    }
                    _ => out.push((stable, vec![(hz[i], vals[i])])),
                }
            }
            out
        };
        let marks = |kind: PointKind| -> Vec<(f64, f64)> {
            (0..n)
                .filter(|&i| self.branch.points[i].kind == kind)
                .map(|i| (hz[i], vals[i]))
                .collect()
        };
        let any_unstable = self.branch.points.iter().any(|p| p.stable() == Some(false));
        let width = if k == self.sys.harmonics().nu { 2 } else { 1 };
        // The drawing is the same on a linear and a log axis; a macro keeps one copy.
        macro_rules! finish {
            ($chart:expr) => {{
                let mut chart = $chart;
                let mut labelled = false;
                for (stable, pts) in segments() {
                    let style = if stable {
                        colour.stroke_width(width)
                    } else {
                        RED.stroke_width(width)
                    };
                    let s = chart.draw_series(LineSeries::new(pts, style))?;
                    if legend && stable && !labelled {
                        labelled = true;
                        s.label("stable").legend(move |(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                        });
                    }
                }
                if legend && any_unstable {
                    chart
                        .draw_series(std::iter::empty::<PathElement<(f64, f64)>>())?
                        .label("unstable")
                        .legend(|(x, y)| {
                            PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2))
                        });
                }
                let folds = marks(PointKind::Fold);
                if !folds.is_empty() {
                    let s = chart
                        .draw_series(folds.iter().map(|&p| Circle::new(p, 5, BLACK.filled())))?;
                    if legend {
                        s.label("fold")
                            .legend(|(x, y)| Circle::new((x + 10, y), 4, BLACK.filled()));
                    }
                }
                let jumps = marks(PointKind::Jump);
                if !jumps.is_empty() {
                    let s = chart.draw_series(
                        jumps
                            .iter()
                            .map(|&p| TriangleMarker::new(p, 6, BLACK.filled())),
                    )?;
                    if legend {
                        s.label("jump (stepped sine)")
                            .legend(|(x, y)| TriangleMarker::new((x + 10, y), 5, BLACK.filled()));
                    }
                }
                if legend {
                    crate::plot::draw_legend(&mut chart, SeriesLabelPosition::UpperRight)?;
                }
            }};
        }
        if phase {
            let chart = builder.build_cartesian_2d(x0..x1, -180.0..180.0)?;
            let mut chart = chart;
            chart
                .configure_mesh()
                .x_desc("frequency (Hz)")
                .y_desc(&y_desc)
                .x_label_formatter(&x_fmt)
                .y_labels(9)
                .y_label_formatter(&|v| format!("{v:.0}"))
                .draw()?;
            finish!(chart);
        } else if self.magnitude == Magnitude::Log {
            let lo = v0.max(floor) / 1.2;
            // The legend's panel keeps a band above the curves for it.
            let hi = v1.max(floor) * if legend { 6.0 } else { 1.2 };
            let mut chart = builder.build_cartesian_2d(x0..x1, (lo..hi).log_scale())?;
            chart
                .configure_mesh()
                .x_desc("frequency (Hz)")
                .y_desc(&y_desc)
                .x_label_formatter(&x_fmt)
                .y_label_formatter(&|v| tick_label(*v, 0.0, hi))
                .draw()?;
            finish!(chart);
        } else {
            let head = if legend { 0.35 } else { 0.05 };
            let (lo, hi) = if self.magnitude == Magnitude::Db {
                let span = (v1 - v0).max(1.0);
                (v0 - 0.05 * span, v1 + head * span)
            } else {
                (0.0, v1 * (1.03 + head) + 1e-300)
            };
            let ys = tick_step(lo, hi, 20);
            let mut chart = builder.build_cartesian_2d(x0..x1, lo..hi)?;
            chart
                .configure_mesh()
                .x_desc("frequency (Hz)")
                .y_desc(&y_desc)
                .x_label_formatter(&x_fmt)
                .y_label_formatter(&|v| tick_label(*v, ys, lo.abs().max(hi.abs())))
                .draw()?;
            finish!(chart);
        }
        Ok(())
    }
}

/// The folds and jumps of `branch` (sensor responses `y` from [`responses`]) as a report table
/// (`what` names the branch): kind, frequency, level and `|Y|` of every sensor at the
/// fundamental.
pub fn events_table(
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    what: &str,
) -> crate::report::Table {
    let nu = sys.harmonics().nu;
    let mut header: Vec<String> = ["event", "frequency (Hz)", "level", "stable"]
        .map(String::from)
        .to_vec();
    for sen in sys.sensors() {
        header.push(format!("|{}| h1 ({})", sen.name, unit(sen.quantity)));
    }
    let rows = branch
        .points
        .iter()
        .zip(y)
        .filter(|(p, _)| matches!(p.kind, PointKind::Fold | PointKind::Jump))
        .map(|(p, y)| {
            let mut row = vec![
                match p.kind {
                    PointKind::Fold => "fold".to_string(),
                    _ => "jump".to_string(),
                },
                format!("{:.6}", p.omega / (2.0 * std::f64::consts::PI)),
                format!("{:.4}", p.scale),
                match p.stable() {
                    Some(true) => "yes".into(),
                    Some(false) => "no".into(),
                    None => "not computed".into(),
                },
            ];
            for s in 0..y.nrows() {
                row.push(format!("{:.6e}", y[(s, nu.min(y.ncols() - 1))].norm()));
            }
            row
        })
        .collect();
    crate::report::Table {
        caption: format!("Folds and jumps of the {what}"),
        header,
        rows,
    }
}

/// The largest computed `|Y|` of every sensor and harmonic carrying response along `branch`
/// (`y` from [`responses`]) and where it is: a report table. These are computed points, not
/// peaks located between them.
pub fn peaks_table(sys: &HbSystem, branch: &Branch, y: &[Mat<c64>]) -> crate::report::Table {
    let nu = sys.harmonics().nu;
    let mut rows = Vec::new();
    for (s, sen) in sys.sensors().iter().enumerate() {
        let nk = sys.harmonics().h + 1;
        let peak = |k: usize| {
            y.iter()
                .enumerate()
                .map(|(i, m)| (i, m[(s, k)].norm()))
                .fold((0, 0.0f64), |a, b| if b.1 > a.1 { b } else { a })
        };
        let top = (0..nk).map(|k| peak(k).1).fold(0.0f64, f64::max);
        for k in 0..nk {
            let (i, v) = peak(k);
            if v > 1e-9 * top && v > 0.0 {
                rows.push(vec![
                    sen.name.clone(),
                    harmonic_label(k, nu),
                    format!(
                        "{:.6}",
                        branch.points[i].omega / (2.0 * std::f64::consts::PI)
                    ),
                    format!("{v:.6e}"),
                    unit(sen.quantity).to_string(),
                ]);
            }
        }
    }
    crate::report::Table {
        caption: "Largest computed response per sensor and harmonic (continuation)".into(),
        header: ["sensor", "harmonic", "frequency (Hz)", "|Y|", "unit"]
            .map(String::from)
            .to_vec(),
        rows,
    }
}

/// The located maxima `peaks` of a continuation ([`nlsim_hb::locate_peaks`]): a report table.
pub fn located_peaks_table(sys: &HbSystem, peaks: &[nlsim_hb::Peak]) -> crate::report::Table {
    let nu = sys.harmonics().nu;
    let rows = peaks
        .iter()
        .map(|p| {
            let sen = &sys.sensors()[p.sensor];
            vec![
                sen.name.clone(),
                harmonic_label(p.harmonic, nu),
                format!("{:.7}", p.omega / (2.0 * std::f64::consts::PI)),
                format!("{:.8e}", p.value),
                unit(sen.quantity).to_string(),
                if p.located {
                    "located between points"
                } else {
                    "an end of the computed branch"
                }
                .to_string(),
            ]
        })
        .collect();
    crate::report::Table {
        caption: "Largest response per sensor and harmonic, located along the branch".into(),
        header: ["sensor", "harmonic", "frequency (Hz)", "|Y|", "unit", "how"]
            .map(String::from)
            .to_vec(),
        rows,
    }
}

/// The report of `nlsim frf`: its summary, the folds/jumps and peaks tables, one plot per
/// sensor (magnitude axes and phase panels as given), the FRF data in `report.h5`
/// (`/frf/<mode>`, the layout of FRF files); `summary` is [`crate::run::FrfRun::summary`] and
/// `command_line` goes into the provenance. Returns the page's path.
#[allow(clippy::too_many_arguments)]
pub fn write_report(
    dir: &std::path::Path,
    spec: &str,
    model: &nlsim_kernel::Model,
    req: &crate::run::FrfRequest,
    run: &crate::run::FrfRun,
    summary: &[String],
    (magnitude, phase): (Magnitude, bool),
    command_line: &str,
) -> Result<std::path::PathBuf> {
    let report = crate::report::Report::create(
        dir,
        &format!(
            "nlsim frf: {} from {} to {} Hz",
            model.name(),
            req.from_hz,
            req.to_hz
        ),
        command_line,
        spec,
    )?;
    let (sys, branch, y) = (&run.system, &run.branch, &run.responses);
    report.section_with(
        &format!("FRF by harmonic balance ({})", req.mode.as_str()),
        summary,
    );
    report.table("events", events_table(sys, branch, y, req.mode.as_str()))?;
    report.table(
        "peaks",
        if run.peaks.is_empty() {
            peaks_table(sys, branch, y)
        } else {
            located_peaks_table(sys, &run.peaks)
        },
    )?;
    for (s, sen) in sys.sensors().iter().enumerate() {
        let title = format!(
            "{}: {} at {}, H = {}",
            model.name(),
            req.mode.as_str(),
            sen.name,
            sys.harmonics().h
        );
        report.figure(
            &format!("frf_{}", sen.name),
            &FrfPlot {
                sys,
                branch,
                y,
                sensor: s,
                title: &title,
                magnitude,
                phase,
            },
        )?;
    }
    report.data(|root| {
        let g = root.create_group("frf")?;
        let g = g.create_group(req.mode.as_str())?;
        write_group(&g, sys, branch, y)?;
        write_peaks(&g, sys, &run.peaks)
    })?;
    report.finish()
}
