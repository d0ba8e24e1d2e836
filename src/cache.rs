//! A binary cache of parsed model matrices, read through a memory map, so that hundreds of
//! cluster tasks load a 10⁶-DOF model without each parsing its Matrix Market text.
//!
//! Beside `DIR/K.mtx` the first load writes `DIR/.nlsim-cache/K.mtx.csc` (atomically: a
//! temporary file, then a rename, so concurrent tasks never read a partial cache). Layout,
//! little-endian: the magic `NLSIMCSC`, format version (u64), the source's size and
//! modification time in ns (u64 each), `n` and `nnz` (u64), then the compressed-column arrays
//! `col_ptr` (`n + 1` u64), `row_idx` (`nnz` u64) and `values` (`nnz` f64). A cache whose
//! stamp differs from its source, or that fails any structural check, is ignored and
//! rewritten. `NLSIM_CACHE=off` turns the cache off.

use crate::error::Result;
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use nlsim_kernel::SparseSym;
use std::io::Write as _;
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"NLSIMCSC";
const VERSION: u64 = 1;
const HEADER: usize = 8 + 5 * 8;

/// The source's size and modification time (ns since the epoch): the cache's validity stamp.
fn stamp(path: &Path) -> Option<(u64, u64)> {
    let m = std::fs::metadata(path).ok()?;
    let t = m
        .modified()
        .ok()?
        .duration_since(std::time::UNIX_EPOCH)
        .ok()?;
    Some((m.len(), t.as_nanos() as u64))
}

/// Where the cache of `source` lives.
pub fn cache_path(source: &Path) -> PathBuf {
    let name = source
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    source
        .with_file_name(".nlsim-cache")
        .join(format!("{name}.csc"))
}

/// Loads the matrix of the Matrix Market file `path` from its cache when the cache is current,
/// else parses the text and writes the cache (best effort: an unwritable directory only costs
/// the next load a parse).
pub fn load_matrix_market(path: &Path, name: &str) -> Result<SparseSym> {
    let enabled = std::env::var("NLSIM_CACHE").map_or(true, |v| v != "off");
    let st = stamp(path);
    if enabled
        && let Some(st) = st
        && let Some(m) = read_cache(&cache_path(path), st, name)
    {
        return Ok(m);
    }
    let text = crate::output::read_text(path)?;
    let m = crate::mtx::parse_matrix_market(&text, path, name)?;
    if enabled && let Some(st) = st {
        let _ = write_cache(&cache_path(path), st, &m);
    }
    Ok(m)
}

fn u64_at(b: &[u8], i: usize) -> u64 {
    u64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes"))
}

/// Reads a current, well-formed cache; `None` otherwise.
fn read_cache(path: &Path, (len, mtime): (u64, u64), name: &str) -> Option<SparseSym> {
    let file = std::fs::File::open(path).ok()?;
    // SAFETY: the map is read-only and only read while `file` is open. Cache files are
    // written under a temporary name and renamed into place, never modified in place, so
    // the mapped bytes do not change under us (a replacement is a new inode).
    #[allow(unsafe_code)]
    let map = unsafe { memmap2::Mmap::map(&file) }.ok()?;
    let b: &[u8] = &map;
    if b.len() < HEADER
        || &b[..8] != MAGIC
        || u64_at(b, 8) != VERSION
        || u64_at(b, 16) != len
        || u64_at(b, 24) != mtime
    {
        return None;
    }
    let n = usize::try_from(u64_at(b, 32)).ok()?;
    let nnz = usize::try_from(u64_at(b, 40)).ok()?;
    let need = HEADER.checked_add((n.checked_add(1)?.checked_add(2 * nnz)?).checked_mul(8)?)?;
    if b.len() != need {
        return None;
    }
    let words = |off: usize, k: usize| b[off..off + 8 * k].chunks_exact(8);
    let col_ptr: Vec<usize> = words(HEADER, n + 1)
        .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")) as usize)
        .collect();
    let off_r = HEADER + 8 * (n + 1);
    let row_idx: Vec<usize> = words(off_r, nnz)
        .map(|c| u64::from_le_bytes(c.try_into().expect("8 bytes")) as usize)
        .collect();
    let values: Vec<f64> = words(off_r + 8 * nnz, nnz)
        .map(|c| f64::from_le_bytes(c.try_into().expect("8 bytes")))
        .collect();
    // The invariants faer checks (it panics on a violation; a damaged cache is just stale).
    if col_ptr[0] != 0 || col_ptr[n] != nnz || col_ptr.windows(2).any(|w| w[0] > w[1]) {
        return None;
    }
    for j in 0..n {
        let rows = &row_idx[col_ptr[j]..col_ptr[j + 1]];
        if rows.iter().any(|&r| r >= n) || rows.windows(2).any(|w| w[0] >= w[1]) {
            return None;
        }
    }
    let sym = SymbolicSparseColMat::new_checked(n, n, col_ptr, None, row_idx);
    SparseSym::from_faer(name, SparseColMat::new(sym, values)).ok()
}

fn write_cache(path: &Path, (len, mtime): (u64, u64), m: &SparseSym) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let a = m.as_faer();
    let tmp = crate::output::temp_path(path);
    let write = || -> std::io::Result<()> {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        w.write_all(MAGIC)?;
        for v in [VERSION, len, mtime, m.n() as u64, m.nnz() as u64] {
            w.write_all(&v.to_le_bytes())?;
        }
        for &p in a.col_ptr() {
            w.write_all(&(p as u64).to_le_bytes())?;
        }
        for &r in a.row_idx() {
            w.write_all(&(r as u64).to_le_bytes())?;
        }
        for &v in a.val() {
            w.write_all(&v.to_le_bytes())?;
        }
        w.into_inner().map_err(|e| e.into_error())?.sync_all()
    };
    if let Err(e) = write() {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cache_round_trips_and_goes_stale_with_its_source() {
        let dir = std::env::temp_dir().join(format!("nlsim-cache-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let src = dir.join("K.mtx");
        let k = SparseSym::from_lower_triplets(
            "K",
            3,
            &[
                (0, 0, 4.0),
                (1, 0, -1.5),
                (1, 1, 3.0),
                (2, 2, 2.0),
                (2, 1, 0.25),
            ],
        )
        .unwrap();
        std::fs::write(&src, crate::mtx::to_matrix_market(&k)).unwrap();
        let first = load_matrix_market(&src, "K").unwrap();
        let cache = cache_path(&src);
        assert!(cache.is_file());
        let st = stamp(&src).unwrap();
        let cached = read_cache(&cache, st, "K").expect("a current cache is used");
        assert_eq!(cached.to_dense(), first.to_dense());
        assert_eq!(cached.to_dense(), k.to_dense());
        // Another stamp (the source changed): not used.
        assert!(read_cache(&cache, (st.0 + 1, st.1), "K").is_none());
        // A damaged cache is ignored, not trusted and not a panic.
        let mut bytes = std::fs::read(&cache).unwrap();
        let last = bytes.len() - 8 * 5 - 8 * 4; // inside row_idx
        bytes[last] = 0xff;
        std::fs::write(&cache, &bytes).unwrap();
        assert!(read_cache(&cache, st, "K").is_none());
        bytes.truncate(20);
        std::fs::write(&cache, &bytes).unwrap();
        assert!(read_cache(&cache, st, "K").is_none());
        // And the loader falls back to the text and rewrites the cache.
        assert_eq!(
            load_matrix_market(&src, "K").unwrap().to_dense(),
            k.to_dense()
        );
        assert!(read_cache(&cache, st, "K").is_some());
    }
}
