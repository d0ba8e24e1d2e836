//! The candidates file `nlsim calibrate --candidates` reads: a merged
//! `calibrate-candidates` batch (layout in `docs/batch.md`), or the candidates an
//! interrupted calibration kept ([`write_interrupted`]; docs/file-formats.md).

use crate::error::{Error, Result};
use crate::formats::files::{h5err, job_group_name, u64_attr};
use hdf5_metno as hdf5;
use std::path::Path;

/// Most values a merged candidates file may declare (parameters × candidates): 2²⁶.
const CANDIDATE_BUDGET: usize = 1 << 26;

/// The evaluated candidates of a merged `calibrate-candidates` batch or of an interrupted
/// calibration (for `nlsim calibrate --candidates`): values from `parameters`, costs from
/// `cost`. In a file an interrupted calibration wrote (attribute `interrupted = 1`) a NaN
/// cost marks a candidate not evaluated yet (the calibration evaluates it); in a merged
/// batch it marks a failed job, refused. Fails on another kind of file or an incomplete
/// merge.
pub fn read_candidates(path: &Path) -> Result<Vec<nlsim_calib::Candidate>> {
    let err = h5err(path);
    let bad = |m: String| Error::Usage(format!("{}: {m}", path.display()));
    crate::formats::files::input_file(path)?;
    let file = hdf5::File::open(path).map_err(&err)?;
    let command: Option<hdf5::types::VarLenUnicode> =
        file.attr("command").and_then(|a| a.read_scalar()).ok();
    if command.as_ref().map(|c| c.as_str()) != Some("calibrate-candidates") {
        return Err(bad(format!(
            "not a merged 'calibrate-candidates' batch (command: {})",
            command.as_ref().map_or("none", |c| c.as_str())
        )));
    }
    if u64_attr(&file, "complete") != Some(1) {
        return Err(bad("the merge did not complete".into()));
    }
    let table = file.dataset("parameters").map_err(&err)?;
    let cost = file.dataset("cost").map_err(&err)?;
    let shape = table.shape();
    let (Some(&rows), Some(&cols)) = (shape.first(), shape.get(1)) else {
        return Err(bad(format!(
            "`parameters` has shape {shape:?}, not jobs × parameters"
        )));
    };
    if rows.saturating_mul(cols) > CANDIDATE_BUDGET || cost.shape() != [rows] {
        return Err(bad(format!(
            "`parameters` {rows}×{cols} and `cost` {:?} do not agree or exceed 2^26 values",
            cost.shape()
        )));
    }
    let interrupted = u64_attr(&file, "interrupted") == Some(1);
    let values = table.read_raw::<f64>().map_err(&err)?;
    let costs = cost.read_raw::<f64>().map_err(&err)?;
    let mut out = Vec::with_capacity(rows);
    for (i, c) in costs.iter().enumerate() {
        let v = values[i * cols..(i + 1) * cols].to_vec();
        if v.iter().any(|x| x.is_nan()) {
            return Err(bad(format!("candidate {i}: a parameter value is NaN")));
        }
        if c.is_nan() && !interrupted {
            return Err(bad(format!(
                "candidate {i} failed (see jobs/{}/error); rerun its shard",
                job_group_name(i)
            )));
        }
        out.push(nlsim_calib::Candidate {
            values: v,
            cost: *c,
        });
    }
    Ok(out)
}

/// Writes the candidates an interrupted calibration kept to `path` (HDF5, atomically): the
/// layout [`read_candidates`] reads — `parameters` (candidates × parameters), `cost` (NaN
/// where not evaluated), attributes `command = "calibrate-candidates"`, `complete = 1`,
/// `interrupted = 1`, `phase`, `evaluated` — plus `parameter_names`, and `best` with its
/// `best_cost` when a finite cost was reached. `--candidates` resumes from it.
pub fn write_interrupted(path: &Path, kept: &nlsim_calib::Interrupted) -> Result<()> {
    use hdf5::types::VarLenUnicode;
    let err = h5err(path);
    let rows = kept.points.len();
    let cols = kept.params.len();
    let text = |s: &str| -> VarLenUnicode { s.parse().unwrap_or_default() };
    crate::formats::files::replace_atomically(path, |tmp| {
        let file = hdf5::File::create(tmp).map_err(&err)?;
        let flat: Vec<f64> = kept.points.iter().flatten().copied().collect();
        file.new_dataset::<f64>()
            .shape((rows, cols))
            .create("parameters")
            .and_then(|d| d.write_raw(&flat))
            .map_err(&err)?;
        let costs: Vec<f64> = kept.costs.iter().map(|c| c.unwrap_or(f64::NAN)).collect();
        file.new_dataset::<f64>()
            .shape(rows)
            .create("cost")
            .and_then(|d| d.write_raw(&costs))
            .map_err(&err)?;
        let names: Vec<VarLenUnicode> = kept.params.iter().map(|p| text(&p.to_string())).collect();
        file.new_attr::<VarLenUnicode>()
            .shape(names.len())
            .create("parameter_names")
            .and_then(|a| a.write(&names))
            .map_err(&err)?;
        file.new_attr::<VarLenUnicode>()
            .create("command")
            .and_then(|a| a.write_scalar(&text("calibrate-candidates")))
            .map_err(&err)?;
        file.new_attr::<VarLenUnicode>()
            .create("phase")
            .and_then(|a| a.write_scalar(&text(kept.phase.as_str())))
            .map_err(&err)?;
        for (name, v) in [
            ("complete", 1u64),
            ("interrupted", 1),
            ("evaluated", kept.evaluated() as u64),
        ] {
            file.new_attr::<u64>()
                .create(name)
                .and_then(|a| a.write_scalar(&v))
                .map_err(&err)?;
        }
        if let Some((best, cost)) = kept.best() {
            file.new_dataset::<f64>()
                .shape(best.len())
                .create("best")
                .and_then(|d| d.write_raw(best))
                .map_err(&err)?;
            file.new_attr::<f64>()
                .create("best_cost")
                .and_then(|a| a.write_scalar(&cost))
                .map_err(&err)?;
        }
        file.flush().map_err(&err)
    })
}
