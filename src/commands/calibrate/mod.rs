//! `nlsim calibrate` as library calls: a typed [`CalibrationRequest`] (`request.rs`, from the
//! command line or a calibration file), [`run_calibration`] on it (`run.rs`; measured modes in `modal.rs`), and [`write_report`] (`report.rs`) with the tables,
//! the plots and the summary of the result.
//!
//! A calibration file (`docs/calibration.md`) holds everything the command line can say,
//! and the settings it cannot:
//!
//! ```toml
//! model = "ecl_beam"              # model file or built-in model
//! data = "test.csv"               # CSV, HDF5, UFF 58 or modal CSV (relative to this file)
//! set = { "tip.c" = 0.5 }         # fixed overrides before calibrating
//! harmonics = 3                   # harmonics H of the harmonic balance
//! compare = [1, 3]                # harmonics compared with the data
//! form = "complex"                # complex | log-magnitude
//! branch = "nearest"              # nearest | continuation (multi-valued responses)
//! modes = 20                      # retained modes
//! lhs = 64                        # Latin-hypercube candidates
//! starts = 3                      # Levenberg–Marquardt runs from the best candidates
//! folds = 10                      # cross-validation folds (0: none)
//! seed = 1                        # Latin hypercube and fold assignment
//! report = "calibration-report"   # report folder (relative to this file)
//!
//! [[param]]
//! name = "tip.k3"
//! lower = 1e8
//! upper = 1e11
//! spacing = "log"                 # log | linear (default: log over more than a decade)
//!
//! [lm]                            # Levenberg–Marquardt settings
//! max_iterations = 100
//! ```

pub mod modal;
pub mod report;
pub mod request;
pub mod result;
pub mod run;
pub mod time;

pub use modal::*;
pub use report::*;
pub use request::*;
pub use result::*;
pub use run::*;
pub use time::*;

/// `nlsim calibrate`: the request checked; raw records (`--time-domain`) go to
/// [`run_time_calibration_until`], measured modes (a modal CSV) to
/// [`run_modal_calibration_until`], stepped-sine data (CSV, HDF5, UFF 58) to
/// [`run_calibration_until`], with progress lines per phase, optionally from the candidates
/// of an earlier batch or an interrupted run; then the summary, the estimates CSV and the
/// report folder. Stopped by a signal, it keeps the candidates evaluated so far.
pub fn execute(
    req: &CalibrationRequest,
    candidates: Option<&std::path::Path>,
    console: &crate::present::console::Console,
) -> crate::Result<()> {
    use nlsim_calib::Progress;
    req.check()?;
    crate::formats::files::check_outputs(
        &[
            Some(std::path::Path::new(&req.model)),
            Some(req.data.as_path()),
            req.source.as_deref(),
            candidates,
        ],
        &[req.out.as_deref()],
        &[req.report.as_deref()],
    )?;
    let candidates = match candidates {
        None => None,
        Some(p) => Some((
            p.to_path_buf(),
            crate::formats::candidates::read_candidates(p)?,
        )),
    };
    // One line per phase with the time left (a log line per phase when stderr is not a
    // terminal); the callback runs on the worker threads.
    let phase = std::sync::Mutex::new((String::new(), std::time::Instant::now(), 0usize));
    let progress = |p: Progress| {
        let (what, d, n) = match p {
            Progress::Candidates { done, total } => ("candidates", done, total),
            Progress::Start { done, total } => ("optimisations", done, total),
            Progress::Fold { done, total } => ("folds", done, total),
        };
        let mut ph = phase
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        if ph.0 != what {
            *ph = (what.to_string(), std::time::Instant::now(), d);
        }
        console.phase(what, d, n, ph.1, ph.2);
    };
    // A stop signal is honoured at the calibration's safe points: the candidates evaluated
    // so far are kept in a file `--candidates` resumes from. Once the calibration finished,
    // a stop signal ends the run at once; the report folder is staged, so the older one
    // stays whole.
    let safe = crate::formats::interrupt::SafePoints::begin();
    let stop = crate::formats::interrupt::requested;
    let kept = if req.time_domain {
        match run_time_calibration_until(req, candidates, &progress, &stop)? {
            RunOutcome::Finished(run) if !stop() => {
                drop(safe);
                return write_time_outputs(req, &run, console);
            }
            RunOutcome::Finished(run) => nlsim_calib::Interrupted::finished(run.calibration),
            RunOutcome::Interrupted(kept) => *kept,
        }
    } else if is_modal(req)? {
        match run_modal_calibration_until(req, candidates, &progress, &stop)? {
            RunOutcome::Finished(run) if !stop() => {
                drop(safe);
                return write_modal_outputs(req, &run, console);
            }
            RunOutcome::Finished(run) => nlsim_calib::Interrupted::finished(run.calibration),
            RunOutcome::Interrupted(kept) => *kept,
        }
    } else {
        match run_calibration_until(req, candidates, &progress, &stop)? {
            RunOutcome::Finished(run) if !stop() => {
                drop(safe);
                return write_outputs(req, &run, console);
            }
            RunOutcome::Finished(run) => nlsim_calib::Interrupted::finished(run.calibration),
            RunOutcome::Interrupted(kept) => *kept,
        }
    };
    let path = keep_interrupted(req, &kept)?;
    safe.hold_to_exit();
    Err(crate::Error::Interrupted(interrupted_line(&kept, &path)))
}

/// Whether `req`'s data is measured modes (a modal CSV) rather than stepped sines.
pub fn is_modal(req: &CalibrationRequest) -> crate::Result<bool> {
    Ok(req
        .data
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
        && crate::formats::modal_data::is_modal_csv(&req.data)?)
}

/// Writes the candidates an interrupted calibration kept beside its first output (the
/// report folder's name, else the estimates file's, else `calibration`, with
/// `.interrupted.h5`; `-2`, `-3`, … when that name is an input of the run, e.g. the file it
/// resumed from) and returns the path.
fn keep_interrupted(
    req: &CalibrationRequest,
    kept: &nlsim_calib::Interrupted,
) -> crate::Result<std::path::PathBuf> {
    use std::path::{Path, PathBuf};
    let base: PathBuf = match (req.report.as_deref(), req.out.as_deref()) {
        (Some(r), _) => r.to_path_buf(),
        (None, Some(o)) => o.with_extension(""),
        (None, None) => PathBuf::from("calibration"),
    };
    let name = |k: usize| {
        let mut n = base
            .file_name()
            .unwrap_or(Path::new("calibration").as_os_str())
            .to_os_string();
        if k > 1 {
            n.push(format!("-{k}"));
        }
        n.push(".interrupted.h5");
        base.with_file_name(n)
    };
    let mut last = None;
    for k in 1..=100 {
        let p = name(k);
        match crate::formats::guard::before_write(&p) {
            Ok(()) => {
                crate::formats::candidates::write_interrupted(&p, kept)?;
                return Ok(p);
            }
            Err(e) => last = Some(e),
        }
    }
    Err(last.unwrap_or_else(|| crate::Error::Usage("no name for the candidates file".into())))
}

/// The one line an interrupted calibration prints: what was kept and how to go on.
fn interrupted_line(kept: &nlsim_calib::Interrupted, path: &std::path::Path) -> String {
    let best = match kept.best() {
        Some((values, cost)) => format!(
            "; best so far (cost {cost:.6e}): {}",
            kept.params
                .iter()
                .zip(values)
                .map(|(p, v)| format!("{p} = {v:.6e}"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
        None => String::new(),
    };
    format!(
        "stopped in the {} phase with {} of {} candidates evaluated and {} optimisations \
         finished; kept in {} (not a calibration result){best}; go on with the same \
         command and --candidates {}",
        kept.phase.as_str(),
        kept.evaluated(),
        kept.points.len(),
        kept.runs.len(),
        path.display(),
        path.display()
    )
}
