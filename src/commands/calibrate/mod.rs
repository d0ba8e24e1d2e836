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

/// `nlsim calibrate`: the request checked; measured modes (a modal CSV) go to
/// [`run_modal_calibration`], stepped-sine data (CSV, HDF5, UFF 58) to [`run_calibration`]
/// with progress lines per phase, optionally from the candidates of an earlier batch; then the
/// summary, the estimates CSV and the report folder.
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
    if req.time_domain {
        if candidates.is_some() {
            return Err(crate::Error::Usage(
                "--candidates: a time-domain calibration evaluates its candidates itself (it \
                 has no batch kinds)"
                    .into(),
            ));
        }
        let run = run_time_calibration(req, &progress)?;
        return write_time_outputs(req, &run, console);
    }
    let modal = req
        .data
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
        && crate::formats::modal_data::is_modal_csv(&req.data)?;
    if modal {
        if candidates.is_some() {
            return Err(crate::Error::Usage(
                "--candidates: a modal-data calibration evaluates its candidates itself (it \
                 has no batch kinds)"
                    .into(),
            ));
        }
        let run = run_modal_calibration(req, &progress)?;
        return write_modal_outputs(req, &run, console);
    }
    let run = run_calibration(req, candidates, &progress)?;
    write_outputs(req, &run, console)
}
