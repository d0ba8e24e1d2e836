//! `nlsim nnm`: a nonlinear mode (backbone, amplitude-dependent frequency and modal damping)
//! by the extended periodic motion concept ([`nlsim_hb::nnm`]), written as HDF5 or CSV with
//! a plot. The file layouts are documented in `docs/file-formats.md`.

use crate::error::{Error, Result};
use crate::formats::files::Format;
use crate::formats::files::str_attr;
use crate::formats::files::unit;
use faer::c64;
use hdf5_metno as hdf5;
use nlsim_hb::nnm::{NnmPoint, NnmReport};
use nlsim_hb::{HarmonicSet, HbSystem};
use nlsim_kernel::{Model, Status};
use std::fmt::Write as _;
use std::path::Path;
use std::time::Instant;

/// Output formats of `nlsim nnm --out`.
pub const HINT: &str = ".h5 (HDF5, complex harmonics) or .csv (one row per amplitude)";

pub use nlsim_hb::nnm::{MAX_NNM_POINTS, MAX_NNM_UNKNOWNS};

fn check_unknowns(modes: usize, harmonics: usize) -> Result<()> {
    let n = modes.saturating_mul(2 * harmonics + 1);
    if n > MAX_NNM_UNKNOWNS {
        return Err(Error::Usage(format!(
            "nonlinear mode request: {modes} modes × {} harmonic coefficients = {n} unknowns, \
             more than {MAX_NNM_UNKNOWNS} (the Newton matrix is dense): retain fewer modes \
             (--modes) or harmonics",
            2 * harmonics + 1
        )));
    }
    Ok(())
}

/// A nonlinear mode to compute (the options of `nlsim nnm`).
#[derive(Debug, Clone)]
pub struct NnmRequest {
    /// The linear mode it starts from (1-based).
    pub mode: usize,
    /// Smallest modal amplitude (m √kg).
    pub from: f64,
    /// Largest modal amplitude (m √kg).
    pub to: f64,
    /// Amplitudes, evenly spaced in their logarithm.
    pub points: usize,
    /// Harmonics `H` of the frequency.
    pub harmonics: usize,
    /// Retained modes.
    pub modes: usize,
    /// Parallelism of the reduction.
    pub par: faer::Par,
    /// Lanczos settings of the reduction.
    pub lanczos: crate::commands::setup::Lanczos,
}

impl NnmRequest {
    /// Checks what does not need the model; errors are usage errors naming the option.
    pub fn check(&self) -> Result<HarmonicSet> {
        let usage = |m: String| Error::Usage(format!("nonlinear mode request: {m}"));
        for (what, v) in [("from", self.from), ("to", self.to)] {
            if !(v > 0.0 && v.is_finite()) {
                return Err(usage(format!(
                    "{what} {v} must be a positive modal amplitude (m √kg)"
                )));
            }
        }
        if !(2..=MAX_NNM_POINTS).contains(&self.points) {
            return Err(usage(format!(
                "points {} must be from 2 to {MAX_NNM_POINTS}",
                self.points
            )));
        }
        if self.mode == 0 {
            return Err(usage("mode counts from 1".into()));
        }
        if self.modes < self.mode {
            return Err(usage(format!(
                "mode {} needs at least {} retained modes (got {})",
                self.mode, self.mode, self.modes
            )));
        }
        if self.harmonics == 0 || self.harmonics > crate::commands::frf::request::MAX_FRF_HARMONICS
        {
            return Err(usage(format!(
                "harmonics {} must be from 1 to {}",
                self.harmonics,
                crate::commands::frf::request::MAX_FRF_HARMONICS
            )));
        }
        check_unknowns(self.modes, self.harmonics)?;
        HarmonicSet::new(self.harmonics, 1).map_err(|e| usage(e.to_string()))
    }

    /// The amplitudes, log-spaced from `from` to `to`.
    pub fn amplitudes(&self) -> Vec<f64> {
        nlsim_hb::nnm::log_amplitudes(self.from, self.to, self.points)
    }
}

/// A computed nonlinear mode.
pub struct NnmRun {
    /// The harmonic-balance system (its sensors give the physical responses).
    pub system: HbSystem,
    /// The points and how the run ended.
    pub report: NnmReport,
    /// Retained modes.
    pub modes: usize,
    /// Wall time (s).
    pub seconds: f64,
    /// The model's name.
    pub model_name: String,
}

impl NnmRun {
    /// Sensor harmonics (sensors × H+1, complex, in each sensor's quantity) of point `p`:
    /// `Y_k = Φ_s (c_k − i s_k)` times `(ikω)^d` for velocity (`d = 1`) and acceleration.
    pub fn sensor_harmonics(&self, p: &NnmPoint) -> faer::Mat<c64> {
        nlsim_hb::nnm::sensor_harmonics(&self.system, p)
    }

    /// The lines `nlsim nnm` prints: the setup, a table of about ten points, how it ended.
    pub fn summary(&self, model: &Model, req: &NnmRequest) -> Vec<String> {
        let pts = &self.report.points;
        let mut out = vec![format!(
            "nnm {}: mode {} by the extended periodic motion concept, H = {}, {} modes, \
             modal amplitude {:.3e} to {:.3e} m√kg",
            model.name(),
            req.mode,
            req.harmonics,
            self.modes,
            req.from,
            req.to
        )];
        out.push(format!(
            "  {} points in {:.3} s; linear mode {:.6} Hz",
            pts.len(),
            self.seconds,
            self.system.linear().frequency_hz(req.mode - 1)
        ));
        out.push("  amplitude (m√kg)  frequency (Hz)  damping ratio".into());
        let step = pts.len().div_ceil(10).max(1);
        for (i, p) in pts.iter().enumerate() {
            if i % step == 0 || i + 1 == pts.len() {
                out.push(format!(
                    "  {:>16.5e}  {:>14.7}  {:>13.5e}",
                    p.amplitude,
                    p.omega / (2.0 * std::f64::consts::PI),
                    p.damping_ratio()
                ));
            }
        }
        if self.report.status != Status::Converged {
            out.push(format!("  stopped short: {}", self.report.detail));
        }
        out
    }
}

/// Computes the nonlinear mode `req` asks for on `model`, calling `progress` after every
/// point. The model's damping is what the mode's damping ratio measures; its forcing is not
/// used.
pub fn run_nnm(
    model: &Model,
    req: &NnmRequest,
    progress: &mut dyn FnMut(&NnmPoint),
) -> Result<NnmRun> {
    let set = req.check()?;
    if model.elements().is_empty() {
        return Err(Error::Usage(format!(
            "model '{}' has no nonlinear element: its modes are linear (see `nlsim modes`)",
            model.name()
        )));
    }
    let modes = req.modes.min(model.n_dofs());
    if req.mode > modes {
        return Err(Error::Usage(format!(
            "mode {} of a model with {} DOFs",
            req.mode,
            model.n_dofs()
        )));
    }
    let free = nlsim_hb::nnm::free_model(model)?;
    let t0 = Instant::now();
    let reduced = crate::commands::setup::Reductions::default().get(
        &free,
        modes,
        false,
        req.par,
        req.lanczos,
    )?;
    // A cluster kept whole may add modes beyond the request.
    check_unknowns(reduced.n_modes(), req.harmonics)?;
    let system = nlsim_hb::nnm::free_motion_system(&free, &reduced, set)?;
    let report = nlsim_hb::nnm::nonlinear_mode(&system, req.mode - 1, &req.amplitudes(), progress)?;
    if report.points.is_empty() {
        return Err(Error::Failed(report.detail));
    }
    Ok(NnmRun {
        system,
        modes: reduced.modes.len(),
        report,
        seconds: t0.elapsed().as_secs_f64(),
        model_name: model.name().to_string(),
    })
}

/// Writes a nonlinear mode: HDF5 for `.h5`/`.hdf5`, CSV for `.csv`, atomically.
pub fn write_nnm(path: &Path, run: &NnmRun, model_spec: &str, req: &NnmRequest) -> Result<()> {
    crate::formats::files::write_atomically(path, HINT, |tmp, format| match format {
        Format::Csv => write_csv(tmp, run, model_spec, req),
        Format::Hdf5 => write_hdf5(tmp, run, model_spec, req),
        // Not offered (Format::of takes no universal file here); an error, never a panic.
        Format::Uff => Err(Error::Usage(format!(
            "{}: universal files are not written by `nnm`; name the file {HINT}",
            path.display()
        ))),
    })
}

fn write_csv(path: &Path, run: &NnmRun, model_spec: &str, req: &NnmRequest) -> Result<()> {
    let sys = &run.system;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "# nlsim {} nnm: model {model_spec}, mode {}, H = {}, {} modes; amplitude: the \
         fundamental's cosine coefficient of the mass-normalised modal coordinate",
        env!("CARGO_PKG_VERSION"),
        req.mode,
        req.harmonics,
        run.modes
    );
    let _ = writeln!(
        s,
        "# damping_ratio = xi / (2 omega); <sensor>_h<k>: complex harmonic k of the sensor \
         (q = Re(Q e^(i k omega t)))"
    );
    s.push_str("amplitude_m_sqrt_kg,frequency_hz,damping_ratio,xi_per_s");
    for sen in sys.sensors() {
        let u = unit(sen.quantity).replace('/', "_per_").replace("^2", "2");
        for k in 0..=sys.harmonics().h {
            let _ = write!(s, ",{0}_h{k}_re_{u},{0}_h{k}_im_{u}", sen.name);
        }
    }
    s.push('\n');
    for p in &run.report.points {
        let _ = write!(
            s,
            "{:.10e},{:.12e},{:.10e},{:.10e}",
            p.amplitude,
            p.omega / (2.0 * std::f64::consts::PI),
            p.damping_ratio(),
            p.xi
        );
        let y = run.sensor_harmonics(p);
        for r in 0..y.nrows() {
            for k in 0..y.ncols() {
                let _ = write!(s, ",{:.10e},{:.10e}", y[(r, k)].re, y[(r, k)].im);
            }
        }
        s.push('\n');
    }
    std::fs::write(path, s).map_err(|source| Error::Io {
        path: path.to_path_buf(),
        source,
    })
}

fn write_hdf5(path: &Path, run: &NnmRun, model_spec: &str, req: &NnmRequest) -> Result<()> {
    let err = crate::formats::files::h5err(path);
    let file = hdf5::File::create(path).map_err(&err)?;
    let root = file.as_group().map_err(&err)?;
    let sys = &run.system;
    crate::formats::files::provenance(&root, "nnm", model_spec, &run.model_name, None)
        .map_err(&err)?;
    crate::formats::files::count_attr(&root, "mode", req.mode).map_err(&err)?;
    crate::formats::files::count_attr(&root, "harmonics", req.harmonics).map_err(&err)?;
    crate::formats::files::count_attr(&root, "modes", run.modes).map_err(&err)?;
    str_attr(&root, "status", run.report.status.as_str()).map_err(&err)?;
    let pts = &run.report.points;
    let real = |name: &str, data: Vec<f64>, u: &str| -> hdf5::Result<()> {
        let d = root.new_dataset_builder().with_data(&data).create(name)?;
        str_attr(&d, "unit", u)
    };
    (|| -> hdf5::Result<()> {
        real(
            "amplitude",
            pts.iter().map(|p| p.amplitude).collect(),
            "m sqrt(kg)",
        )?;
        real(
            "frequency",
            pts.iter()
                .map(|p| p.omega / (2.0 * std::f64::consts::PI))
                .collect(),
            "Hz",
        )?;
        real(
            "damping_ratio",
            pts.iter().map(NnmPoint::damping_ratio).collect(),
            "1",
        )?;
        real("xi", pts.iter().map(|p| p.xi).collect(), "1/s")?;
        let gs = root.create_group("sensors")?;
        let nk = sys.harmonics().h + 1;
        let ys: Vec<faer::Mat<c64>> = pts.iter().map(|p| run.sensor_harmonics(p)).collect();
        for (s, sen) in sys.sensors().iter().enumerate() {
            let g = gs.create_group(&sen.name)?;
            str_attr(&g, "quantity", sen.quantity.as_str())?;
            let data: Vec<c64> = ys
                .iter()
                .flat_map(|y| (0..nk).map(move |k| y[(s, k)]))
                .collect();
            let d = g
                .new_dataset::<c64>()
                .shape((pts.len(), nk))
                .create("response")?;
            d.write_raw(&data)?;
            str_attr(&d, "unit", unit(sen.quantity))?;
            str_attr(&d, "dims", "point x harmonic")?;
        }
        Ok(())
    })()
    .map_err(&err)?;
    file.flush().map_err(&err)?;
    Ok(())
}

/// The plots of a nonlinear mode against log10 of the modal amplitude: the frequency (Hz,
/// the backbone) and the modal damping ratio.
pub fn plots(run: &NnmRun, model: &Model, req: &NnmRequest) -> [crate::present::plot::Lines; 2] {
    let pts = &run.report.points;
    let x = |p: &NnmPoint| p.amplitude.log10();
    [
        crate::present::plot::Lines {
            title: format!("{}: nonlinear mode {} (backbone)", model.name(), req.mode),
            x_desc: "log10 modal amplitude (m √kg)".into(),
            y_desc: "frequency (Hz)".into(),
            series: vec![(
                "frequency".into(),
                pts.iter()
                    .map(|p| (x(p), p.omega / (2.0 * std::f64::consts::PI)))
                    .collect(),
            )],
        },
        crate::present::plot::Lines {
            title: format!(
                "{}: nonlinear mode {} (modal damping)",
                model.name(),
                req.mode
            ),
            x_desc: "log10 modal amplitude (m √kg)".into(),
            y_desc: "damping ratio (1)".into(),
            series: vec![(
                "damping ratio".into(),
                pts.iter().map(|p| (x(p), p.damping_ratio())).collect(),
            )],
        },
    ]
}

/// `nlsim nnm MODEL`: the request checked, the model loaded with its `--set` overrides, the
/// backbone continued with a progress line, the summary printed, the file and the two plots
/// (frequency and damping against amplitude) written; a run that stopped short is an error
/// after what it computed is written.
pub fn execute(
    spec: &str,
    sets: &[String],
    req: &NnmRequest,
    (out, plot): (Option<&Path>, Option<&Path>),
    console: &crate::present::console::Console,
) -> Result<()> {
    req.check()?;
    if let Some(path) = out {
        Format::of(path, HINT)?;
    }
    let plot_path = plot
        .map(|p| p.to_path_buf())
        .or_else(|| out.map(|p| p.with_extension("svg")));
    if let Some(p) = &plot_path {
        crate::present::plot::check_path(p)?;
    }
    crate::formats::files::check_outputs(
        &[Some(Path::new(spec))],
        &[out, plot_path.as_deref()],
        &[],
    )?;
    let model = crate::commands::setup::load_for_run(spec, sets)?;
    let mut count = 0usize;
    let mut progress = |p: &NnmPoint| {
        count += 1;
        if console.shows_progress() {
            console.progress(&format!("  {count} points, amplitude {:.3e} ", p.amplitude));
        }
    };
    let run = run_nnm(&model, req, &mut progress)?;
    console.progress_end();
    for line in run.summary(&model, req) {
        console.say(&line);
    }
    if let Some(path) = out {
        write_nnm(path, &run, spec, req)?;
        console.say(&format!("  written to {}", path.display()));
    }
    if let Some(p) = plot_path {
        let [freq, damping] = plots(&run, &model, req);
        crate::present::plot::write(&p, &freq)?;
        let dp = crate::present::plot::companion(&p, "damping");
        crate::present::plot::write(&dp, &damping)?;
        console.say(&format!("  plots {} and {}", p.display(), dp.display()));
    }
    if run.report.status.is_converged() {
        Ok(())
    } else {
        Err(Error::Failed(format!(
            "nnm stopped short after {} points{}: {}",
            run.report.points.len(),
            out.map_or(String::new(), |p| format!(", written to {}", p.display())),
            run.report.detail
        )))
    }
}
