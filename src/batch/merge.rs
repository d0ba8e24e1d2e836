//! Joining the complete shard files of one split into `merged.h5`.

use crate::error::{Error, Result};
use crate::formats::files::h5err;
use crate::formats::files::str_attr;
use hdf5_metno as hdf5;
use std::collections::BTreeMap;
use std::path::PathBuf;

use super::calib::{CalibRow, read_calib_job, write_calib_summary};
use super::*;

/// The result of a merge.
#[derive(Debug, Clone)]
pub struct MergeOutcome {
    /// The merged file.
    pub path: PathBuf,
    /// Shards joined.
    pub shards: usize,
    /// Jobs in it.
    pub jobs: usize,
    /// Jobs that had failed.
    pub failed: usize,
    /// What a calibration batch found (best candidates, or the fold statistics) or a plan
    /// batch's ranking, one line each; empty for other batches.
    pub summary: Vec<String>,
}

/// Joins the complete shard files of `b` (all `count` of one split) into `merged.h5`, jobs in
/// index order with a `parameters` table (job × swept parameter). Fails naming the missing
/// shards when a split is incomplete.
pub fn merge(b: &Batch) -> Result<MergeOutcome> {
    let entries: Vec<std::fs::DirEntry> = match std::fs::read_dir(&b.output) {
        Ok(rd) => rd.flatten().collect(),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Vec::new(),
        Err(source) => {
            return Err(Error::Io {
                path: b.output.clone(),
                source,
            });
        }
    };
    // Shard files by task count.
    let mut splits: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
    for e in entries {
        let name = e.file_name();
        let Some(n) = name.to_str() else { continue };
        let Some(rest) = n.strip_prefix("shard-").and_then(|r| r.strip_suffix(".h5")) else {
            continue;
        };
        let Some((t, c)) = rest.split_once("-of-") else {
            continue;
        };
        if let (Ok(t), Ok(c)) = (t.parse::<usize>(), c.parse::<usize>())
            && t < c
            && on_disk(&e.path(), b.hash, b.shard_jobs(t, c).count()) == OnDisk::Complete
        {
            splits.entry(c).or_default().push(t);
        }
    }
    let Some((&count, _)) = splits.iter().find(|(c, ts)| ts.len() == **c) else {
        let msg = match splits.iter().max_by_key(|(_, ts)| ts.len()) {
            None => format!(
                "no complete shard of {} in {}: run `nlsim batch {}` first",
                b.file.display(),
                b.output.display(),
                b.file.display()
            ),
            Some((c, ts)) => {
                let missing: Vec<String> = (0..*c)
                    .filter(|t| !ts.contains(t))
                    .map(|t| t.to_string())
                    .collect();
                format!(
                    "shards {} of {c} are missing or incomplete in {}: run them with \
                     `nlsim batch {} --task-count {c} --task-index N` (complete shards are skipped)",
                    missing.join(", "),
                    b.output.display(),
                    b.file.display()
                )
            }
        };
        return Err(Error::Usage(msg));
    };
    let path = b.merged_path();
    let calib_req = match &b.command {
        BatchCommand::CalibrateCandidates(r) | BatchCommand::CalibrateFolds(r, _) => Some(r),
        _ => None,
    };
    // Swept parameter names, in order of first appearance (a calibration's parameters).
    let mut names: Vec<String> = calib_req
        .map(|r| r.params.iter().map(|p| p.param.to_string()).collect())
        .unwrap_or_default();
    // Per job of a calibration: its values and its cost or fold result.
    let mut calib_rows: Vec<Option<CalibRow>> = Vec::new();
    for j in &b.jobs {
        for a in &j.assignments {
            if let Assignment::Set(n, _) = a
                && !names.contains(n)
            {
                names.push(n.clone());
            }
        }
    }
    let mut failed = 0;
    let mut summary = Vec::new();
    let mut plan_groups: Vec<hdf5::Group> = Vec::new();
    crate::formats::files::write_atomically(&path, ".h5", |tmp, _| {
        let err = h5err(tmp);
        let out = hdf5::File::create(tmp).map_err(&err)?;
        let root = out.as_group().map_err(&err)?;
        write_root_attrs(&root, b).map_err(&err)?;
        let jobs = out.create_group("jobs").map_err(&err)?;
        let shards: Vec<hdf5::File> = (0..count)
            .map(|t| {
                let p = b.shard_path(t, count);
                crate::formats::files::input_file(&p)?;
                hdf5::File::open(&p).map_err(h5err(&p))
            })
            .collect::<Result<_>>()?;
        for j in &b.jobs {
            let name = job_group_name(j.index);
            let p = b.shard_path(j.index % count, count);
            let src = shards[j.index % count]
                .group(&format!("jobs/{name}"))
                .map_err(|e| Error::Hdf5 {
                    path: p.clone(),
                    message: format!("job {} is missing: {e}", j.index),
                })?;
            if src.attr("ok").and_then(|a| a.read_scalar::<u8>()).ok() != Some(1) {
                failed += 1;
            }
            let dst = jobs.create_group(&name).map_err(&err)?;
            copy_group(&src, &dst).map_err(h5err(&p))?;
            if calib_req.is_some() {
                calib_rows.push(read_calib_job(&src));
            }
            if matches!(b.command, BatchCommand::PlanCandidates(_)) {
                plan_groups.push(src);
            }
        }
        if let BatchCommand::PlanCandidates(req) = &b.command {
            match crate::commands::plan::report::merged_plan(req, &plan_groups) {
                Ok(run) => {
                    crate::commands::plan::report::write_ranking(&root, &run).map_err(&err)?;
                    let dir = b.output.join("plan-report");
                    crate::commands::plan::report::write_plan_report(&dir, &run)?;
                    summary = run.summary();
                    summary.push(format!(
                        "every design: {} (and group /ranking of the merged file); plots in {}",
                        dir.join("ranking.csv").display(),
                        dir.display()
                    ));
                }
                Err(e) => summary.push(format!("ranking left out: {e}")),
            }
        }
        // The parameter table: NaN where a job does not set the parameter.
        let mut table = vec![f64::NAN; b.jobs.len() * names.len()];
        for (j, row) in calib_rows.iter().enumerate() {
            if let Some((v, _, _)) = row
                && v.len() == names.len()
            {
                table[j * names.len()..(j + 1) * names.len()].copy_from_slice(v);
            }
        }
        if calib_req.is_some() {
            summary = write_calib_summary(&out, b, &names, &calib_rows).map_err(&err)?;
        }
        for j in &b.jobs {
            for a in &j.assignments {
                if let Assignment::Set(n, v) = a {
                    let c = names.iter().position(|x| x == n).expect("collected above");
                    table[j.index * names.len() + c] = *v;
                }
            }
        }
        let d = out
            .new_dataset::<f64>()
            .shape((b.jobs.len(), names.len()))
            .create("parameters")
            .map_err(&err)?;
        d.write_raw(&table).map_err(&err)?;
        str_attr(&d, "columns", &names.join(",")).map_err(&err)?;
        str_attr(&d, "dims", "job x parameter (NaN: not set by the job)").map_err(&err)?;
        str_attr(&d, "unit", "SI, per parameter").map_err(&err)?;
        u64_attr_write(&root, "complete", 1).map_err(&err)?;
        out.flush().map_err(&err)?;
        Ok(())
    })?;
    Ok(MergeOutcome {
        path,
        shards: count,
        jobs: b.jobs.len(),
        failed,
        summary,
    })
}

/// Copies the attributes of `src` onto `dst` (the types nlsim writes).
fn copy_attrs(src: &hdf5::Location, dst: &hdf5::Location) -> hdf5::Result<()> {
    use hdf5::types::{FloatSize, IntSize, TypeDescriptor as T, VarLenUnicode};
    for name in src.attr_names()? {
        let a = src.attr(&name)?;
        if !a.is_scalar() {
            continue;
        }
        match a.dtype()?.to_descriptor()? {
            T::Float(FloatSize::U8) => dst
                .new_attr::<f64>()
                .create(name.as_str())?
                .write_scalar(&a.read_scalar::<f64>()?)?,
            T::Unsigned(IntSize::U8) => dst
                .new_attr::<u64>()
                .create(name.as_str())?
                .write_scalar(&a.read_scalar::<u64>()?)?,
            T::Unsigned(IntSize::U1) => dst
                .new_attr::<u8>()
                .create(name.as_str())?
                .write_scalar(&a.read_scalar::<u8>()?)?,
            T::VarLenUnicode => {
                let s: VarLenUnicode = a.read_scalar()?;
                dst.new_attr::<VarLenUnicode>()
                    .create(name.as_str())?
                    .write_scalar(&s)?
            }
            other => {
                return Err(hdf5::Error::from(format!(
                    "attribute '{name}' has a type nlsim does not write ({other:?})"
                )));
            }
        }
    }
    Ok(())
}

/// Copies a dataset of element type `E`, keeping its shape and its chunking/compression.
fn copy_dataset<E: hdf5::H5Type>(
    src: &hdf5::Dataset,
    dst: &hdf5::Group,
    name: &str,
) -> hdf5::Result<hdf5::Dataset> {
    let data = src.read_raw::<E>()?;
    let b = dst.new_dataset::<E>().shape(src.shape());
    let d = match src.chunk() {
        Some(c) => b.chunk(c).shuffle().deflate(4).create(name)?,
        None => b.create(name)?,
    };
    d.write_raw(&data)?;
    Ok(d)
}

/// Recursively copies the groups, datasets and attributes under `src` into `dst`.
fn copy_group(src: &hdf5::Group, dst: &hdf5::Group) -> hdf5::Result<()> {
    use hdf5::types::{FloatSize, IntSize, TypeDescriptor as T};
    copy_attrs(src, dst)?;
    for name in src.member_names()? {
        if let Ok(g) = src.group(&name) {
            let d = dst.create_group(&name)?;
            copy_group(&g, &d)?;
            continue;
        }
        let ds = src.dataset(&name)?;
        let d = match ds.dtype()?.to_descriptor()? {
            T::Float(FloatSize::U8) => copy_dataset::<f64>(&ds, dst, &name)?,
            T::Integer(IntSize::U1) => copy_dataset::<i8>(&ds, dst, &name)?,
            T::Unsigned(IntSize::U1) => copy_dataset::<u8>(&ds, dst, &name)?,
            T::Unsigned(IntSize::U4) => copy_dataset::<u32>(&ds, dst, &name)?,
            T::Compound(c) if c.fields.len() == 2 => copy_dataset::<faer::c64>(&ds, dst, &name)?,
            other => {
                return Err(hdf5::Error::from(format!(
                    "dataset '{name}' has a type nlsim does not write ({other:?})"
                )));
            }
        };
        copy_attrs(&ds, &d)?;
    }
    Ok(())
}
