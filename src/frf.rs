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
    write_group(&root, sys, branch, y).map_err(&err)?;
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
    let gel = g.create_group("elements")?;
    let nh = sys.harmonics().len();
    for (e, el) in sys.elements().iter().enumerate() {
        let data: Vec<f64> = branch
            .points
            .iter()
            .flat_map(|p| p.x[e * nh..(e + 1) * nh].iter().copied())
            .collect();
        let d = gel.new_dataset::<f64>().shape((n, nh)).create(el.name())?;
        d.write_raw(&data)?;
        str_attr(&d, "unit", "m")?;
        str_attr(
            &d,
            "layout",
            "per point: c0, c1, s1, ..., cH, sH with u(t) = c0 + sum c_k cos(k w0 t) + s_k sin(k w0 t)",
        )?;
    }
    Ok(())
}

/// Plots `|Y|` of sensor `sensor` (responses `y` from [`responses`]) at every harmonic
/// carrying response (the fundamental thick) against frequency, as SVG or PNG by the
/// extension of `path`: stable parts solid, unstable parts red, folds and jumps marked.
/// Written atomically.
pub fn plot_frf(
    path: &Path,
    sys: &HbSystem,
    branch: &Branch,
    y: &[Mat<c64>],
    sensor: usize,
    title: &str,
) -> Result<()> {
    crate::plot::write(
        path,
        &FrfPlot {
            sys,
            branch,
            y,
            sensor,
            title,
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
}

impl crate::plot::Figure for FrfPlot<'_> {
    fn draw<DB: plotters::prelude::DrawingBackend>(
        &self,
        root: &plotters::prelude::DrawingArea<DB, plotters::coord::Shift>,
    ) -> crate::plot::DrawResult
    where
        DB::ErrorType: 'static,
    {
        let FrfPlot {
            sys,
            branch,
            y,
            sensor,
            title,
        } = *self;
        use plotters::prelude::*;
        let hz: Vec<f64> = branch
            .points
            .iter()
            .map(|p| p.omega / (2.0 * std::f64::consts::PI))
            .collect();
        let nk = sys.harmonics().h + 1;
        let amp = |i: usize, k: usize| y[i][(sensor, k)].norm();
        let peak_k: Vec<f64> = (0..nk)
            .map(|k| (0..y.len()).fold(0.0f64, |m, i| m.max(amp(i, k))))
            .collect();
        let top = peak_k.iter().fold(0.0f64, |m, v| m.max(*v));
        // Harmonics above 1 % of the largest are drawn.
        let shown: Vec<usize> = (0..nk).filter(|&k| peak_k[k] > 0.01 * top).collect();
        let (x0, x1) = hz
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| {
                (a.min(*v), b.max(*v))
            });
        let sen = &sys.sensors()[sensor];
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(44)
            .y_label_area_size(80)
            .build_cartesian_2d(
                x0..x1.max(x0 * (1.0 + 1e-9) + 1e-9),
                0.0..top * 1.08 + 1e-300,
            )?;
        let (xs, ys) = (
            crate::plot::tick_step(x0, x1, 20),
            crate::plot::tick_step(0.0, top * 1.08, 20),
        );
        chart
            .configure_mesh()
            .x_desc("frequency (Hz)")
            .y_desc(format!("|{}| ({})", sen.name, unit(sen.quantity)))
            .x_label_formatter(&|v| crate::plot::tick_label(*v, xs, x1.abs()))
            .y_label_formatter(&|v| crate::plot::tick_label(*v, ys, top * 1.08))
            .draw()?;
        let palette = [BLUE, GREEN, MAGENTA, CYAN, BLACK, RGBColor(150, 100, 0)];
        for (c, &k) in shown.iter().enumerate() {
            let colour = palette[c % palette.len()];
            let width = if k == sys.harmonics().nu { 3 } else { 1 };
            // Consecutive points of equal stability form one segment.
            let mut start = 0;
            let mut labelled = false;
            while start + 1 < y.len() {
                let stable = branch.points[start].stable() != Some(false);
                let mut end = start + 1;
                while end + 1 < y.len() && (branch.points[end].stable() != Some(false)) == stable {
                    end += 1;
                }
                let style = if stable {
                    colour.stroke_width(width)
                } else {
                    RED.stroke_width(width)
                };
                let jump = branch.points[end].kind == PointKind::Jump;
                let series: Vec<(f64, f64)> = (start..=if jump { end - 1 } else { end })
                    .map(|i| (hz[i], amp(i, k)))
                    .collect();
                let s = chart.draw_series(LineSeries::new(series, style))?;
                if stable && !labelled {
                    labelled = true;
                    s.label(format!(
                        "harmonic {} ({})",
                        harmonic_label(k, sys.harmonics().nu),
                        if k == sys.harmonics().nu {
                            "fundamental"
                        } else {
                            "stable"
                        }
                    ))
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(width))
                    });
                }
                start = end;
            }
        }
        if branch.points.iter().any(|p| p.stable() == Some(false)) {
            chart
                .draw_series(std::iter::empty::<PathElement<(f64, f64)>>())?
                .label("unstable")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED.stroke_width(2)));
        }
        let k = sys.harmonics().nu;
        let marks: Vec<(f64, f64)> = branch
            .points
            .iter()
            .enumerate()
            .filter(|(_, p)| matches!(p.kind, PointKind::Fold | PointKind::Jump))
            .map(|(i, _)| (hz[i], amp(i, k)))
            .collect();
        if !marks.is_empty() {
            chart
                .draw_series(marks.iter().map(|&p| Circle::new(p, 5, BLACK.filled())))?
                .label("fold / jump")
                .legend(|(x, y)| Circle::new((x + 10, y), 4, BLACK.filled()));
        }
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .position(SeriesLabelPosition::UpperRight)
            .draw()?;
        Ok(())
    }
}
