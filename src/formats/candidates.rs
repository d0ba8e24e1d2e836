//! The candidates file of a merged `calibrate-candidates` batch, as
//! `nlsim calibrate --candidates` reads it (layout in `docs/batch.md`).

use crate::error::{Error, Result};
use crate::formats::files::{h5err, job_group_name, u64_attr};
use hdf5_metno as hdf5;
use std::path::Path;

/// Most values a merged candidates file may declare (parameters × candidates): 2²⁶.
const CANDIDATE_BUDGET: usize = 1 << 26;

/// The evaluated candidates of a merged `calibrate-candidates` batch (for
/// `nlsim calibrate --candidates`): values from `parameters`, costs from `cost`. Fails on
/// another kind of file, an incomplete merge or a failed candidate.
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
    let values = table.read_raw::<f64>().map_err(&err)?;
    let costs = cost.read_raw::<f64>().map_err(&err)?;
    let mut out = Vec::with_capacity(rows);
    for (i, c) in costs.iter().enumerate() {
        let v = values[i * cols..(i + 1) * cols].to_vec();
        if c.is_nan() || v.iter().any(|x| x.is_nan()) {
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
