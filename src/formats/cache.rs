//! A binary cache of parsed model matrices, read through a memory map, so that hundreds of
//! cluster tasks load a 10⁶-DOF model without each parsing its Matrix Market text.
//!
//! Beside `DIR/K.mtx` the first load writes `DIR/.nlsim-cache/K.mtx.csc` (atomically: a
//! temporary file, then a rename, so concurrent tasks never read a partial cache). Layout,
//! little-endian: the magic `NLSIMCSC`, format version (u64, 2), the source's length and
//! content hash, the hash of the body (u64 each), `n` and `nnz` (u64), then the body: the
//! compressed-column arrays `col_ptr` (`n + 1` u64), `row_idx` (`nnz` u64) and `values`
//! (`nnz` f64). The cache is used only when the source's bytes hash to the recorded value
//! (an edit that keeps the size and the modification time, as `cp -p`, `rsync -a` and
//! `tar x` do, is seen), its body hashes to its own record (a damaged cache is seen) and its
//! structure is valid; otherwise it is ignored and rewritten. Hashing reads the source once
//! (a few GB/s), far less than parsing it. `NLSIM_CACHE=off` turns the cache off.

use crate::error::Result;
use faer::sparse::{SparseColMat, SymbolicSparseColMat};
use nlsim_kernel::SparseSym;
use std::io::{Seek as _, Write as _};
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"NLSIMCSC";
const VERSION: u64 = 2;
const HEADER: usize = 8 + 6 * 8;
/// Byte offset of the body hash in the header.
const BODY_HASH_AT: u64 = 32;

/// A 64-bit hash of a byte stream: four multiply–rotate lanes over 8-byte words and an
/// avalanche at the end. Not cryptographic: it detects edits and damage, not an adversary
/// (who could as well edit the cache).
#[derive(Debug, Clone)]
pub struct ContentHash {
    lanes: [u64; 4],
    pending: [u8; 32],
    n_pending: usize,
    len: u64,
}

const PRIMES: [u64; 4] = [
    0x9e37_79b9_7f4a_7c15,
    0xc2b2_ae3d_27d4_eb4f,
    0x1656_67b1_9e37_79f9,
    0xd6e8_feb8_6659_fd93,
];

impl Default for ContentHash {
    fn default() -> Self {
        Self {
            lanes: PRIMES,
            pending: [0; 32],
            n_pending: 0,
            len: 0,
        }
    }
}

impl ContentHash {
    fn block(&mut self, b: &[u8]) {
        for (i, lane) in self.lanes.iter_mut().enumerate() {
            let w = u64::from_le_bytes(b[8 * i..8 * i + 8].try_into().expect("8 bytes"));
            *lane = (lane.rotate_left(23) ^ w).wrapping_mul(PRIMES[(i + 1) % 4]);
        }
    }

    /// Feeds `bytes`.
    pub fn update(&mut self, mut bytes: &[u8]) {
        self.len += bytes.len() as u64;
        if self.n_pending > 0 {
            let take = (32 - self.n_pending).min(bytes.len());
            self.pending[self.n_pending..self.n_pending + take].copy_from_slice(&bytes[..take]);
            self.n_pending += take;
            bytes = &bytes[take..];
            if self.n_pending < 32 {
                return;
            }
            let p = self.pending;
            self.block(&p);
            self.n_pending = 0;
        }
        let mut chunks = bytes.chunks_exact(32);
        for c in &mut chunks {
            self.block(c);
        }
        let rest = chunks.remainder();
        self.pending[..rest.len()].copy_from_slice(rest);
        self.n_pending = rest.len();
    }

    /// The hash of everything fed.
    pub fn finish(&self) -> u64 {
        let mut tail = [0u8; 32];
        tail[..self.n_pending].copy_from_slice(&self.pending[..self.n_pending]);
        let mut h = self.clone();
        if self.n_pending > 0 {
            h.block(&tail);
        }
        let mut r = self.len ^ PRIMES[0];
        for lane in h.lanes {
            r = (r ^ lane).wrapping_mul(PRIMES[2]);
            r ^= r >> 29;
        }
        // splitmix64's finaliser.
        r ^= r >> 30;
        r = r.wrapping_mul(0xbf58_476d_1ce4_e5b9);
        r ^= r >> 27;
        r = r.wrapping_mul(0x94d0_49bb_1331_11eb);
        r ^ (r >> 31)
    }

    /// The hash of `bytes`.
    pub fn of(bytes: &[u8]) -> u64 {
        let mut h = Self::default();
        h.update(bytes);
        h.finish()
    }
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
    let text = crate::formats::files::read_text(path)?;
    if !enabled {
        return crate::formats::matrices::parse_matrix_market(&text, path, name);
    }
    let st = (text.len() as u64, ContentHash::of(text.as_bytes()));
    if let Some(m) = read_cache(&cache_path(path), st, name) {
        return Ok(m);
    }
    let m = crate::formats::matrices::parse_matrix_market(&text, path, name)?;
    let _ = write_cache(&cache_path(path), st, &m);
    Ok(m)
}

fn u64_at(b: &[u8], i: usize) -> u64 {
    u64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes"))
}

/// Reads a current, well-formed cache; `None` otherwise.
fn read_cache(path: &Path, (len, hash): (u64, u64), name: &str) -> Option<SparseSym> {
    // A FIFO under the cache's name would block the open: only a regular file is a cache.
    if !std::fs::metadata(path).ok()?.is_file() {
        return None;
    }
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
        || u64_at(b, 24) != hash
    {
        return None;
    }
    let n = usize::try_from(u64_at(b, 40)).ok()?;
    let nnz = usize::try_from(u64_at(b, 48)).ok()?;
    let need = HEADER
        .checked_add((n.checked_add(1)?.checked_add(nnz.checked_mul(2)?)?).checked_mul(8)?)?;
    if b.len() != need || ContentHash::of(&b[HEADER..]) != u64_at(b, BODY_HASH_AT as usize) {
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

fn write_cache(path: &Path, (len, hash): (u64, u64), m: &SparseSym) -> std::io::Result<()> {
    let dir = path.parent().unwrap_or(Path::new("."));
    std::fs::create_dir_all(dir)?;
    let a = m.as_faer();
    let tmp = crate::formats::files::temp_path(path);
    let _registered = crate::formats::interrupt::Temporary::new(&tmp);
    let write = || -> std::io::Result<()> {
        let mut w = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        w.write_all(MAGIC)?;
        // The body hash is filled in once the body is written.
        for v in [VERSION, len, hash, 0, m.n() as u64, m.nnz() as u64] {
            w.write_all(&v.to_le_bytes())?;
        }
        let mut body = ContentHash::default();
        let mut put = |w: &mut std::io::BufWriter<std::fs::File>, bytes: [u8; 8]| {
            body.update(&bytes);
            w.write_all(&bytes)
        };
        for &p in a.col_ptr() {
            put(&mut w, (p as u64).to_le_bytes())?;
        }
        for &r in a.row_idx() {
            put(&mut w, (r as u64).to_le_bytes())?;
        }
        for &v in a.val() {
            put(&mut w, v.to_le_bytes())?;
        }
        let mut f = w.into_inner().map_err(|e| e.into_error())?;
        f.seek(std::io::SeekFrom::Start(BODY_HASH_AT))?;
        f.write_all(&body.finish().to_le_bytes())?;
        f.sync_all()
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

    /// The length and content hash of the file at `path`, read in 1 MiB blocks.
    pub(super) fn stamp(path: &Path) -> Option<(u64, u64)> {
        let mut f = std::fs::File::open(path).ok()?;
        let mut h = ContentHash::default();
        let mut buf = vec![0u8; 1 << 20];
        loop {
            match std::io::Read::read(&mut f, &mut buf) {
                Ok(0) => break,
                Ok(k) => h.update(&buf[..k]),
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(_) => return None,
            }
        }
        Some((h.len, h.finish()))
    }

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
        std::fs::write(&src, crate::formats::matrices::to_matrix_market(&k)).unwrap();
        let first = load_matrix_market(&src, "K").unwrap();
        let cache = cache_path(&src);
        assert!(cache.is_file());
        let st = stamp(&src).unwrap();
        let cached = read_cache(&cache, st, "K").expect("a current cache is used");
        assert_eq!(cached.to_dense(), first.to_dense());
        assert_eq!(cached.to_dense(), k.to_dense());
        // Another stamp (the source changed): not used.
        assert!(read_cache(&cache, (st.0 + 1, st.1), "K").is_none());
        // A damaged cache is ignored, not trusted and not a panic: a flipped bit of a value
        // (structurally still valid) is seen by the body hash.
        let good = std::fs::read(&cache).unwrap();
        let mut bytes = good.clone();
        let at = bytes.len() - 3; // inside the last value
        bytes[at] ^= 0x01;
        std::fs::write(&cache, &bytes).unwrap();
        assert!(read_cache(&cache, st, "K").is_none());
        let mut bytes = good.clone();
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
        // The source edited in place with its size and modification time kept (what
        // `cp -p`, `rsync -a` and `tar x` leave): the cache is not used.
        let text = std::fs::read_to_string(&src).unwrap();
        let edited = text.replacen("4", "5", 1);
        assert_eq!(edited.len(), text.len());
        let mtime = std::fs::metadata(&src).unwrap().modified().unwrap();
        std::fs::write(&src, &edited).unwrap();
        std::fs::File::options()
            .write(true)
            .open(&src)
            .unwrap()
            .set_modified(mtime)
            .unwrap();
        assert_eq!(std::fs::metadata(&src).unwrap().modified().unwrap(), mtime);
        let reloaded = load_matrix_market(&src, "K").unwrap().to_dense();
        assert_eq!(reloaded[(0, 0)], 5.0);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_content_hash_does_not_depend_on_how_the_bytes_arrive() {
        let bytes: Vec<u8> = (0..1000u32).map(|i| (i * 7 + i / 13) as u8).collect();
        let whole = ContentHash::of(&bytes);
        for split in [1, 5, 31, 32, 33, 64, 999] {
            let mut h = ContentHash::default();
            for c in bytes.chunks(split) {
                h.update(c);
            }
            assert_eq!(h.finish(), whole, "chunks of {split}");
        }
        // Every single-bit change, and a change of length (trailing zeros), changes it.
        for i in [0, 7, 31, 32, 500, 999] {
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert_ne!(ContentHash::of(&b), whole, "bit at byte {i}");
        }
        let mut longer = bytes.clone();
        longer.push(0);
        assert_ne!(ContentHash::of(&longer), whole);
        assert_ne!(ContentHash::of(&[]), ContentHash::of(&[0]));
    }
}
