//! # nlsim C ABI
//!
//! nlsim for callers in C, C++, Fortran and Python (ctypes/cffi): `libnlsim_c.so` (or `.a`)
//! and the header `include/nlsim.h`, generated from this file by cbindgen. The guide with
//! a complete C program is `docs/c-api.md`.
//!
//! ## Conventions
//!
//! - Every function returns an [`NlsimCode`]: `NLSIM_CODE_OK` (0); `NLSIM_CODE_STOPPED_SHORT`
//!   (1) when a solver stopped before the end and its outputs hold what it computed (the
//!   reason is in [`nlsim_last_error`]); a negative code for an error, whose message
//!   (naming the argument, DOF, parameter or step) is in [`nlsim_last_error`]. Nothing is
//!   written to the outputs on an error unless the function says so.
//! - Objects are **handles**: 64-bit integers, never pointers. A handle is created by one
//!   function, used by others and released by [`nlsim_free`] exactly once; numbers are
//!   never reused, so a freed, forged or wrong-kind handle is refused with
//!   `NLSIM_CODE_ERR_HANDLE`, never a crash. Handle 0 is never valid.
//! - Output arrays are caller buffers with their length in elements; a length that does not
//!   match the documented size is refused with `NLSIM_CODE_ERR_SIZE` naming both sizes.
//!   Complex values are interleaved `re, im` pairs. Multi-dimensional arrays are row-major
//!   (C order), their shape in the function's documentation.
//! - Units are SI throughout: m, kg, s, N; frequencies in Hz.
//! - No panic crosses the boundary: an internal failure becomes `NLSIM_CODE_ERR_INTERNAL`.
//! - **Thread safety**: every function may be called from any thread at any time. Calls that
//!   read a handle run concurrently; calls that change it (`nlsim_model_add_*`,
//!   `nlsim_model_set_*`, [`nlsim_set_param`], `nlsim_testdata_add_*`) wait for them. The
//!   message of [`nlsim_last_error`] is per thread. Results do not depend on the number of
//!   threads (calibration runs its candidates on the rayon pool).

use nlsim::hb::{ContinuationReport, HarmonicSet, HbConfig, HbSystem, continuation};
use nlsim::kernel::model::{Excitation, Sensor};
use nlsim::kernel::{
    Coupling, Damping, DofLabel, DofMap, Law, Model, NonlinearElement, Param, Parameterized,
    Quantity, SparseSym, Status, ValidationConfig, param::parse_known,
};
use nlsim::reduction::{ModalSystem, ReducedModel, ReductionConfig, reduce};
use nlsim::sim::{FohConfig, LoadCase, Plant, Signal, Simulator};
use std::cell::RefCell;
use std::collections::HashMap;
use std::ffi::{CStr, CString, c_char};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::{Arc, LazyLock, Mutex, RwLock};

mod calibration;
pub use calibration::*;

/// What a call did. Non-negative codes are outcomes, negative ones errors.
#[repr(i32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NlsimCode {
    /// The call did what it was asked.
    Ok = 0,
    /// A solver stopped before the end (iteration limit, step too small, a diverging
    /// response): the outputs hold what it computed, the info structure its status, and
    /// [`nlsim_last_error`] where and why it stopped.
    StoppedShort = 1,
    /// A required pointer argument is null.
    ErrNull = -1,
    /// A buffer length does not match the size the call needs (both in the message).
    ErrSize = -2,
    /// A handle is 0, was freed, was never created, or is of another kind.
    ErrHandle = -3,
    /// Invalid input: a matrix, DOF label, element law, parameter name or value, setting.
    ErrInput = -4,
    /// A numerical failure on valid input that leaves no partial result (e.g. an eigen
    /// solve that does not converge).
    ErrNumerical = -5,
    /// A file could not be read or parsed.
    ErrIo = -6,
    /// An internal failure (a bug in nlsim); the message says where. The library stays
    /// usable.
    ErrInternal = -7,
}

/// How an iterative solver ended (mirrors the Rust `Status`).
#[repr(i32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NlsimStatus {
    /// The convergence test was met (for runs: every step taken).
    Converged = 0,
    /// The iteration or point limit was reached first.
    IterationLimit = 1,
    /// The step was cut below its smallest allowed size.
    StepTooSmall = 2,
    /// The iterates grew without bound.
    Diverged = 3,
    /// A NaN or infinity appeared.
    NonFinite = 4,
    /// A linear system on the way was singular.
    Singular = 5,
}

impl From<Status> for NlsimStatus {
    fn from(s: Status) -> Self {
        match s {
            Status::Converged => NlsimStatus::Converged,
            Status::IterationLimit => NlsimStatus::IterationLimit,
            Status::StepTooSmall => NlsimStatus::StepTooSmall,
            Status::Diverged => NlsimStatus::Diverged,
            Status::NonFinite => NlsimStatus::NonFinite,
            Status::Singular => NlsimStatus::Singular,
        }
    }
}

/// The quantity a sensor or test channel measures (an `int32_t` argument).
#[repr(i32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NlsimQuantity {
    /// Displacement (m).
    Displacement = 0,
    /// Velocity (m/s).
    Velocity = 1,
    /// Acceleration (m/s²).
    Acceleration = 2,
}

/// Storage of a sparse matrix given to [`nlsim_model_new`] (the `format` of
/// [`NlsimSparse`]).
#[repr(i32)]
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NlsimStorage {
    /// Compressed sparse rows: `ptr` has `n + 1` row starts, `idx` the column of each value.
    Csr = 0,
    /// Compressed sparse columns: `ptr` has `n + 1` column starts, `idx` the row of each
    /// value.
    Csc = 1,
}

/// A model handle (mass, stiffness, damping, elements, inputs, sensors).
pub type NlsimModel = u64;
/// A reduced-model handle (modes and ports of a model, thesis eq. 8–10).
pub type NlsimReduced = u64;
/// A harmonic-balance system handle (thesis eq. 13–17).
pub type NlsimHb = u64;
/// A frequency-response (continuation branch) handle.
pub type NlsimFrf = u64;
/// A stepped-sine test-data handle, for calibration.
pub type NlsimTestData = u64;

/// A sparse symmetric matrix in caller arrays: CSR or CSC, either every entry or one
/// triangle (off-diagonal entries mirrored), 0- or 1-based indices (Fortran).
#[repr(C)]
#[derive(Debug, Clone, Copy)]
pub struct NlsimSparse {
    /// [`NlsimStorage`]: `NLSIM_STORAGE_CSR` or `NLSIM_STORAGE_CSC`.
    pub format: i32,
    /// 0: both triangles given; 1: one triangle (either), mirrored.
    pub triangle: i32,
    /// 0 for C indices, 1 for Fortran indices (in `ptr` and `idx`).
    pub index_base: i32,
    /// `n + 1` offsets into `idx` and `values`.
    pub ptr: *const i64,
    /// Column (CSR) or row (CSC) index of every stored value.
    pub idx: *const i64,
    /// The stored values (kg for a mass matrix, N/m for a stiffness matrix).
    pub values: *const f64,
}

/// Sizes of a model, from [`nlsim_model_info`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct NlsimModelInfo {
    /// Degrees of freedom.
    pub n_dofs: usize,
    /// Nonlinear elements.
    pub n_elements: usize,
    /// Force inputs (excitations), in the order they were added.
    pub n_inputs: usize,
    /// Sensors, in the order they were added.
    pub n_sensors: usize,
    /// Named parameters ([`nlsim_param_name`]).
    pub n_params: usize,
}

/// How an FOH simulation went, from [`nlsim_simulate`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct NlsimRunInfo {
    /// [`NlsimStatus`]: converged when every step was taken.
    pub status: i32,
    /// Samples computed per sensor (`n_steps + 1` when complete; the rest of the output rows
    /// is left as the caller set it).
    pub samples: usize,
    /// Nonlinear-loop Newton iterations over the run.
    pub newton_iterations: usize,
}

/// Sizes of a harmonic-balance system, from [`nlsim_hb_info`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct NlsimHbInfo {
    /// Highest harmonic `H`; responses hold harmonics `k = 0..=H`.
    pub harmonics: usize,
    /// Sensors (rows of a response).
    pub n_sensors: usize,
    /// Force inputs.
    pub n_inputs: usize,
    /// Condensed unknowns (element coefficients).
    pub n_unknowns: usize,
    /// Named parameters ([`nlsim_param_name`]).
    pub n_params: usize,
}

/// How a harmonic-balance point went, from [`nlsim_hb_point`] and
/// [`nlsim_hb_sensitivities`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct NlsimPointInfo {
    /// [`NlsimStatus`] of the Newton solve.
    pub status: i32,
    /// Newton iterations.
    pub iterations: usize,
    /// Final residual `‖R‖∞` (m).
    pub residual: f64,
    /// Hill stability: 1 stable, 0 unstable, −1 not computed.
    pub stable: i32,
    /// Largest real part of the Floquet exponents (1/s); NaN when not computed.
    pub max_floquet_real: f64,
}

/// A followed frequency response, from [`nlsim_frf_info`].
#[repr(C)]
#[derive(Debug, Clone, Copy, Default)]
pub struct NlsimFrfInfo {
    /// [`NlsimStatus`]: converged when the whole range was followed.
    pub status: i32,
    /// Points on the branch.
    pub n_points: usize,
    /// Folds (turning points) among them.
    pub n_folds: usize,
    /// Steps rejected and retried shorter.
    pub n_rejected: usize,
    /// Newton iterations over the accepted points.
    pub n_newton: usize,
}

// ---------------------------------------------------------------------------------------
// Errors and the boundary guard.

/// Why a call failed: its code and message.
#[derive(Debug)]
pub(crate) struct Failure {
    code: NlsimCode,
    message: String,
}

impl Failure {
    pub(crate) fn new(code: NlsimCode, message: impl Into<String>) -> Self {
        Failure {
            code,
            message: message.into(),
        }
    }

    pub(crate) fn size(what: &str, expected: usize, found: usize) -> Self {
        Failure::new(
            NlsimCode::ErrSize,
            format!("{what} has length {found}; this call needs {expected}"),
        )
    }

    pub(crate) fn input(message: impl Into<String>) -> Self {
        Failure::new(NlsimCode::ErrInput, message)
    }
}

impl From<nlsim::kernel::Error> for Failure {
    fn from(e: nlsim::kernel::Error) -> Self {
        let code = match e {
            nlsim::kernel::Error::Numerical { .. } => NlsimCode::ErrNumerical,
            _ => NlsimCode::ErrInput,
        };
        Failure::new(code, e.to_string())
    }
}

impl From<nlsim::Error> for Failure {
    fn from(e: nlsim::Error) -> Self {
        match e {
            nlsim::Error::Model(k) => k.into(),
            other => {
                let code = match other {
                    nlsim::Error::UnknownModel(..) | nlsim::Error::Usage(_) => NlsimCode::ErrInput,
                    _ => NlsimCode::ErrIo,
                };
                Failure::new(code, other.to_string())
            }
        }
    }
}

/// What a successful call did.
pub(crate) enum Done {
    /// All of it.
    Complete,
    /// A solver stopped short; the message says where and why.
    Short(String),
}

thread_local! {
    static LAST_ERROR: RefCell<CString> = RefCell::new(CString::default());
}

fn set_last_error(message: &str) {
    // Interior NULs cannot cross into C; they never occur in nlsim's messages.
    let c = CString::new(message.replace('\0', " ")).unwrap_or_default();
    LAST_ERROR.with(|e| *e.borrow_mut() = c);
}

/// Runs `f` at the boundary: its failure or panic becomes a code and a message.
pub(crate) fn guard(f: impl FnOnce() -> Result<Done, Failure>) -> NlsimCode {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(Done::Complete)) => {
            set_last_error("");
            NlsimCode::Ok
        }
        Ok(Ok(Done::Short(why))) => {
            set_last_error(&why);
            NlsimCode::StoppedShort
        }
        Ok(Err(fail)) => {
            set_last_error(&fail.message);
            fail.code
        }
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown".into());
            set_last_error(&format!(
                "internal error in nlsim (please report it): {what}"
            ));
            NlsimCode::ErrInternal
        }
    }
}

/// The message of the last call on this thread that did not return `NLSIM_CODE_OK` (an
/// error, or where a solver stopped short); empty after a successful call. The pointer
/// stays valid until the next nlsim call on the same thread; copy the text to keep it.
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_last_error() -> *const c_char {
    LAST_ERROR.with(|e| e.borrow().as_ptr())
}

/// The library version, e.g. `"0.1.0"` (a static string).
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_version() -> *const c_char {
    static VERSION: &CStr =
        match CStr::from_bytes_with_nul(concat!(env!("CARGO_PKG_VERSION"), "\0").as_bytes()) {
            Ok(v) => v,
            Err(_) => c"unknown",
        };
    VERSION.as_ptr()
}

// ---------------------------------------------------------------------------------------
// Caller memory.

/// A C string argument as UTF-8.
///
/// # Safety
/// `p` is null or points to a NUL-terminated string valid for the call.
pub(crate) unsafe fn text<'a>(p: *const c_char, what: &str) -> Result<&'a str, Failure> {
    if p.is_null() {
        return Err(Failure::new(
            NlsimCode::ErrNull,
            format!("{what} is a null pointer"),
        ));
    }
    // SAFETY: non-null, NUL-terminated by the caller's contract.
    let s = unsafe { CStr::from_ptr(p) };
    s.to_str()
        .map_err(|_| Failure::input(format!("{what} is not valid UTF-8")))
}

fn check_span<T>(p: *const T, len: usize, what: &str) -> Result<bool, Failure> {
    if len == 0 {
        return Ok(false);
    }
    if p.is_null() {
        return Err(Failure::new(
            NlsimCode::ErrNull,
            format!("{what} is a null pointer (length {len})"),
        ));
    }
    if !p.is_aligned() {
        return Err(Failure::input(format!(
            "{what} is not aligned for its element type"
        )));
    }
    if len
        .checked_mul(size_of::<T>().max(1))
        .is_none_or(|b| b > isize::MAX as usize)
    {
        return Err(Failure::input(format!(
            "{what} length {len} exceeds the address space"
        )));
    }
    Ok(true)
}

/// `len` elements at `p` (empty when `len` is 0, whatever `p`).
///
/// # Safety
/// When `len > 0`, `p` points to `len` initialised elements valid for the call.
pub(crate) unsafe fn slice<'a, T>(p: *const T, len: usize, what: &str) -> Result<&'a [T], Failure> {
    if !check_span(p, len, what)? {
        return Ok(&[]);
    }
    // SAFETY: non-null, aligned, within the address space; the caller's contract gives the
    // length.
    Ok(unsafe { std::slice::from_raw_parts(p, len) })
}

/// `len` writable elements at `p`.
///
/// # Safety
/// When `len > 0`, `p` points to `len` writable elements valid for the call, not aliased by
/// another argument.
pub(crate) unsafe fn slice_mut<'a, T>(
    p: *mut T,
    len: usize,
    what: &str,
) -> Result<&'a mut [T], Failure> {
    if !check_span(p, len, what)? {
        return Ok(&mut []);
    }
    // SAFETY: as in `slice`, and writable by the caller's contract.
    Ok(unsafe { std::slice::from_raw_parts_mut(p, len) })
}

/// The output `*p`.
///
/// # Safety
/// `p` is null or points to a writable `T`.
pub(crate) unsafe fn out<'a, T>(p: *mut T, what: &str) -> Result<&'a mut T, Failure> {
    if p.is_null() {
        return Err(Failure::new(
            NlsimCode::ErrNull,
            format!("{what} is a null pointer"),
        ));
    }
    if !p.is_aligned() {
        return Err(Failure::input(format!("{what} is not aligned")));
    }
    // SAFETY: non-null, aligned, writable by the caller's contract.
    Ok(unsafe { &mut *p })
}

/// The optional output `*p`: `None` when `p` is null.
///
/// # Safety
/// `p` is null or points to a writable `T`.
pub(crate) unsafe fn out_opt<'a, T>(p: *mut T, what: &str) -> Result<Option<&'a mut T>, Failure> {
    if p.is_null() {
        return Ok(None);
    }
    // SAFETY: forwarded contract.
    unsafe { out(p, what) }.map(Some)
}

/// Writes `n` C-string array entries as UTF-8 strings.
///
/// # Safety
/// When `n > 0`, `p` points to `n` pointers, each a NUL-terminated string.
pub(crate) unsafe fn texts<'a>(
    p: *const *const c_char,
    n: usize,
    what: &str,
) -> Result<Vec<&'a str>, Failure> {
    // SAFETY: forwarded contract.
    let ptrs = unsafe { slice(p, n, what)? };
    ptrs.iter()
        .enumerate()
        // SAFETY: each entry is a string by the contract.
        .map(|(i, &s)| unsafe { text(s, &format!("{what}[{i}]")) })
        .collect()
}

fn positive(v: f64, what: &str) -> Result<f64, Failure> {
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(Failure::input(format!(
            "{what} must be positive and finite, not {v}"
        )))
    }
}

fn finite(v: f64, what: &str) -> Result<f64, Failure> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(Failure::input(format!("{what} must be finite, not {v}")))
    }
}

fn write_complex(dst: &mut [f64], z: impl IntoIterator<Item = faer::c64>) {
    for (pair, z) in dst.chunks_exact_mut(2).zip(z) {
        pair[0] = z.re;
        pair[1] = z.im;
    }
}

// ---------------------------------------------------------------------------------------
// Handles.

/// A reduced model with the model it was reduced from: a snapshot shared with the model
/// handle until either changes (copy on write), so the matrices are not held twice.
pub(crate) struct Reduced {
    pub(crate) reduced: ReducedModel,
    pub(crate) model: Arc<Model>,
}

/// A frequency response with the system it was computed on (a snapshot).
pub(crate) struct Frf {
    system: HbSystem,
    report: ContinuationReport,
}

pub(crate) enum Object {
    Model(Arc<RwLock<Arc<Model>>>),
    Reduced(Arc<Reduced>),
    Hb(Arc<RwLock<HbSystem>>),
    Frf(Arc<Frf>),
    TestData(Arc<RwLock<calibration::TestDataBuilder>>),
}

impl Object {
    fn kind(&self) -> &'static str {
        match self {
            Object::Model(_) => "a model",
            Object::Reduced(_) => "a reduced model",
            Object::Hb(_) => "a harmonic-balance system",
            Object::Frf(_) => "a frequency response",
            Object::TestData(_) => "test data",
        }
    }
}

struct Registry {
    next: u64,
    live: HashMap<u64, Object>,
}

static REGISTRY: LazyLock<Mutex<Registry>> = LazyLock::new(|| {
    Mutex::new(Registry {
        next: 1,
        live: HashMap::new(),
    })
});

fn registry() -> std::sync::MutexGuard<'static, Registry> {
    // A panic never happens while the lock is held; recover the map if one did.
    REGISTRY.lock().unwrap_or_else(|e| e.into_inner())
}

pub(crate) fn insert(object: Object) -> u64 {
    let mut r = registry();
    let id = r.next;
    r.next += 1;
    r.live.insert(id, object);
    id
}

fn missing(id: u64) -> Failure {
    Failure::new(
        NlsimCode::ErrHandle,
        if id == 0 {
            "handle 0 is not an object (was the code of the call that should have created it \
             checked?)"
                .to_string()
        } else {
            format!("handle {id} is not a live object (never created, or already freed)")
        },
    )
}

fn wrong(id: u64, found: &Object, want: &str) -> Failure {
    Failure::new(
        NlsimCode::ErrHandle,
        format!("handle {id} is {}, not {want}", found.kind()),
    )
}

macro_rules! getter {
    ($name:ident, $variant:ident, $ty:ty, $want:literal) => {
        pub(crate) fn $name(id: u64) -> Result<$ty, Failure> {
            match registry().live.get(&id) {
                Some(Object::$variant(x)) => Ok(x.clone()),
                Some(other) => Err(wrong(id, other, $want)),
                None => Err(missing(id)),
            }
        }
    };
}

getter!(get_model, Model, Arc<RwLock<Arc<Model>>>, "a model");
getter!(get_reduced, Reduced, Arc<Reduced>, "a reduced model");
getter!(
    get_hb,
    Hb,
    Arc<RwLock<HbSystem>>,
    "a harmonic-balance system"
);
getter!(get_frf, Frf, Arc<Frf>, "a frequency response");
getter!(
    get_testdata,
    TestData,
    Arc<RwLock<calibration::TestDataBuilder>>,
    "test data"
);

/// Read access that survives a poisoned lock (a panic caught at the boundary while a writer
/// held it leaves the object as the last complete change made it).
pub(crate) fn read<T>(l: &RwLock<T>) -> std::sync::RwLockReadGuard<'_, T> {
    l.read().unwrap_or_else(|e| e.into_inner())
}

pub(crate) fn write<T>(l: &RwLock<T>) -> std::sync::RwLockWriteGuard<'_, T> {
    l.write().unwrap_or_else(|e| e.into_inner())
}

/// Releases `handle` (of any kind). Objects built from it (a reduced model from a model, a
/// frequency response from a system) keep their own copies and stay valid. Freeing a handle
/// twice, or one never created, returns `NLSIM_CODE_ERR_HANDLE`.
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_free(handle: u64) -> NlsimCode {
    guard(|| match registry().live.remove(&handle) {
        Some(_) => Ok(Done::Complete),
        None => Err(missing(handle)),
    })
}

/// The number of live handles of every kind (for leak checks in a caller's tests).
///
/// # Safety
/// `count` is null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_live_handles(count: *mut usize) -> NlsimCode {
    guard(|| {
        // SAFETY: forwarded contract.
        let count = unsafe { out(count, "count")? };
        *count = registry().live.len();
        Ok(Done::Complete)
    })
}

// ---------------------------------------------------------------------------------------
// Models.

pub(crate) fn quantity(q: i32, what: &str) -> Result<Quantity, Failure> {
    match q {
        0 => Ok(Quantity::Displacement),
        1 => Ok(Quantity::Velocity),
        2 => Ok(Quantity::Acceleration),
        _ => Err(Failure::input(format!(
            "{what} {q} is not a quantity (0 displacement, 1 velocity, 2 acceleration)"
        ))),
    }
}

/// The triplets of a caller's sparse matrix of order `n`.
///
/// # Safety
/// `m`'s arrays hold `n + 1` offsets and `ptr[n] − base` indices and values.
unsafe fn sparse(name: &str, n: usize, m: &NlsimSparse) -> Result<SparseSym, Failure> {
    let base = match m.index_base {
        0 | 1 => m.index_base as i64,
        b => {
            return Err(Failure::input(format!(
                "{name}: index_base is {b}; use 0 (C) or 1 (Fortran)"
            )));
        }
    };
    let csr = match m.format {
        0 => true,
        1 => false,
        f => {
            return Err(Failure::input(format!(
                "{name}: format {f} is neither CSR (0) nor CSC (1)"
            )));
        }
    };
    if !matches!(m.triangle, 0 | 1) {
        return Err(Failure::input(format!(
            "{name}: triangle is {}; use 0 (every entry) or 1 (one triangle)",
            m.triangle
        )));
    }
    // SAFETY: `ptr` holds n + 1 offsets by the contract.
    let ptr = unsafe { slice(m.ptr, n + 1, &format!("{name}.ptr"))? };
    if ptr[0] != base {
        return Err(Failure::input(format!(
            "{name}.ptr[0] is {}; it must be the index base {base}",
            ptr[0]
        )));
    }
    for i in 0..n {
        if ptr[i + 1] < ptr[i] {
            return Err(Failure::input(format!(
                "{name}.ptr decreases at {i} ({} then {})",
                ptr[i],
                ptr[i + 1]
            )));
        }
    }
    let nnz = usize::try_from(ptr[n] - base)
        .map_err(|_| Failure::input(format!("{name}.ptr[{n}] is below the index base")))?;
    // Bounded by construction: 16 bytes a stored value in the caller's arrays already.
    if nnz > (1usize << 34) {
        return Err(Failure::input(format!(
            "{name} declares {nnz} stored values, beyond any model this library takes"
        )));
    }
    // SAFETY: `idx` and `values` hold nnz entries by the contract.
    let idx = unsafe { slice(m.idx, nnz, &format!("{name}.idx"))? };
    // SAFETY: as above.
    let values = unsafe { slice(m.values, nnz, &format!("{name}.values"))? };
    let mut triplets = Vec::with_capacity(nnz);
    for outer in 0..n {
        for p in (ptr[outer] - base) as usize..(ptr[outer + 1] - base) as usize {
            let inner = idx[p] - base;
            if inner < 0 || inner >= n as i64 {
                return Err(Failure::input(format!(
                    "{name}.idx[{p}] is {} (index base {base}): outside a matrix of order {n}",
                    idx[p]
                )));
            }
            let (i, j) = if csr {
                (outer, inner as usize)
            } else {
                (inner as usize, outer)
            };
            triplets.push((i, j, values[p]));
        }
    }
    Ok(if m.triangle == 1 {
        SparseSym::from_lower_triplets(name, n, &triplets)?
    } else {
        SparseSym::from_triplets(name, n, &triplets)?
    })
}

/// Creates a model of `n` DOFs from its mass and stiffness matrices (thesis eq. 1–2) and
/// stores its handle in `*model`. `dof_labels` is null (DOFs `1:u` … `n:u`) or `n` labels
/// `NODE:COMPONENT` (`12:uz`, `3:rx`). The model has no damping, elements, inputs or sensors
/// yet; the matrices are checked (symmetry, finiteness, definiteness) here.
///
/// # Safety
/// `name` is a string; `dof_labels` is null or holds `n` strings; `mass` and `stiffness`
/// point to [`NlsimSparse`] descriptions whose arrays hold what they declare; `model` is
/// writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_model_new(
    name: *const c_char,
    n: usize,
    dof_labels: *const *const c_char,
    mass: *const NlsimSparse,
    stiffness: *const NlsimSparse,
    model: *mut NlsimModel,
) -> NlsimCode {
    guard(|| {
        // SAFETY (every block below): the function's contract.
        let name = unsafe { text(name, "name")? };
        let model = unsafe { out(model, "model")? };
        let mass = unsafe { out(mass.cast_mut(), "mass")? };
        let stiffness = unsafe { out(stiffness.cast_mut(), "stiffness")? };
        if n == 0 || n > 50_000_000 {
            return Err(Failure::input(format!(
                "n is {n}; a model has 1 to 5e7 DOFs"
            )));
        }
        let dofs = if dof_labels.is_null() {
            DofMap::scalar(n)
        } else {
            let labels = unsafe { texts(dof_labels, n, "dof_labels")? };
            DofMap::new(
                labels
                    .iter()
                    .map(|l| l.parse::<DofLabel>())
                    .collect::<Result<Vec<_>, _>>()?,
            )?
        };
        let m = unsafe { sparse("mass", n, mass)? };
        let k = unsafe { sparse("stiffness", n, stiffness)? };
        let built = Model::new(name, dofs, m, k)?;
        built.validate(&ValidationConfig::default())?;
        *model = insert(Object::Model(Arc::new(RwLock::new(Arc::new(built)))));
        Ok(Done::Complete)
    })
}

/// Loads a model file (`.toml`, as the `nlsim` command line reads it) or a built-in model by
/// name (`ecl_beam`, `bracket:dofs=20000`, …) and stores its handle in `*model`. Needs the
/// `io` feature (on in the shipped library).
///
/// # Safety
/// `path_or_name` is a string; `model` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_model_load(
    path_or_name: *const c_char,
    model: *mut NlsimModel,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let arg = unsafe { text(path_or_name, "path_or_name")? };
        // SAFETY: the function's contract.
        let model = unsafe { out(model, "model")? };
        load(arg, model)
    })
}

#[cfg(feature = "io")]
fn load(arg: &str, model: &mut NlsimModel) -> Result<Done, Failure> {
    let loaded = nlsim::load_model(arg)?;
    *model = insert(Object::Model(Arc::new(RwLock::new(Arc::new(loaded.model)))));
    Ok(Done::Complete)
}

#[cfg(not(feature = "io"))]
fn load(arg: &str, _model: &mut NlsimModel) -> Result<Done, Failure> {
    Err(Failure::new(
        NlsimCode::ErrIo,
        format!("cannot load '{arg}': this library was built without the io feature"),
    ))
}

/// Sets Rayleigh damping `V = α M + β K` (`alpha` in 1/s, `beta` in s; thesis eq. 2).
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_model_set_rayleigh(model: NlsimModel, alpha: f64, beta: f64) -> NlsimCode {
    guard(|| {
        let m = get_model(model)?;
        Arc::make_mut(&mut write(&m)).set_damping(Damping::Rayleigh { alpha, beta })?;
        Ok(Done::Complete)
    })
}

/// Sets the same modal damping ratio `zeta` (dimensionless, e.g. 0.01) on every mode.
#[unsafe(no_mangle)]
pub extern "C" fn nlsim_model_set_modal_damping(model: NlsimModel, zeta: f64) -> NlsimCode {
    guard(|| {
        let m = get_model(model)?;
        Arc::make_mut(&mut write(&m)).set_damping(Damping::Modal(
            nlsim::kernel::damping::ModalDamping::uniform(zeta),
        ))?;
        Ok(Done::Complete)
    })
}

/// Parses `"cubic k3=1.7e15"` ([`Law::from_text`]).
fn parse_law(element: &str, text: &str) -> Result<Law, Failure> {
    Ok(Law::from_text(element, text)?)
}

fn dof_index(model: &Model, label: &str) -> Result<usize, Failure> {
    Ok(model.dofs().find(label)?)
}

/// Adds a nonlinear element named `name` (thesis eq. 4–7). `law` is the law type and its
/// parameters as `key=value` words with the model-file keys: `"cubic k3=1.7e15"`,
/// `"polynomial k2=1e5 k3=2e9 c3=10"`, `"clearance k1=5e5 e1=1e-3 k2=5e5 e2=2e-3"`,
/// `"bump_stop k=1e6 gap=1e-3"`, `"quadratic_damping c2=20"`, `"coulomb fc=10 v_reg=1e-3"`,
/// `"jenkins kt=1e5 fs=20"`. It acts on DOF `dof` (a label, `"12:uz"`), or on `dof − dof2`
/// when `dof2` is not null. Its parameters are then `NAME.KEY` ([`nlsim_param_name`]). A law on
/// several coordinates is added by [`nlsim_model_add_coupled_element`].
///
/// # Safety
/// `name`, `law` and `dof` are strings; `dof2` is null or a string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_model_add_element(
    model: NlsimModel,
    name: *const c_char,
    law: *const c_char,
    dof: *const c_char,
    dof2: *const c_char,
) -> NlsimCode {
    guard(|| {
        // SAFETY (every block below): the function's contract.
        let name = unsafe { text(name, "name")? };
        let law = unsafe { text(law, "law")? };
        let dof = unsafe { text(dof, "dof")? };
        let dof2 = if dof2.is_null() {
            None
        } else {
            Some(unsafe { text(dof2, "dof2")? })
        };
        let m = get_model(model)?;
        let mut guard = write(&m);
        let m = Arc::make_mut(&mut guard);
        let a = dof_index(m, dof)?;
        let coupling = match dof2 {
            None => Coupling::single(a),
            Some(l) => {
                let b = dof_index(m, l)?;
                if b == a {
                    return Err(Failure::input(format!(
                        "element '{name}': dof2 {l} is dof itself"
                    )));
                }
                Coupling::relative(a, b)
            }
        };
        let law = parse_law(name, law)?;
        m.add_element(NonlinearElement::new(name, law, coupling)?)?;
        Ok(Done::Complete)
    })
}

/// Adds a nonlinear element named `name` whose law acts on several coordinates: the geometric
/// nonlinearity `g_i = Σ k_i,p u_1^p1 ⋯ u_m^pm` of a `coupled_polynomial`, with the model-file
/// keys (`"coupled_polynomial k1_2_0=1.915 k1_1_1=4 k2_0_3=2.638"`: the coefficient of
/// `u1² u0⁰`… in `g_1`, one power per coordinate). Coordinate `u_j` is DOF `dofs[j − 1]`
/// (labels, `n_dofs` of them, as many as the law's powers). Its parameters are then
/// `NAME.k<i>_<p1>_…` ([`nlsim_param_name`]). Harmonic balance and [`nlsim_simulate`] take it.
///
/// # Safety
/// `name` and `law` are strings; `dofs` points to `n_dofs` strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_model_add_coupled_element(
    model: NlsimModel,
    name: *const c_char,
    law: *const c_char,
    dofs: *const *const c_char,
    n_dofs: usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY (every block below): the function's contract.
        let name = unsafe { text(name, "name")? };
        let law = unsafe { text(law, "law")? };
        let labels = unsafe { texts(dofs, n_dofs, "dofs")? };
        let m = get_model(model)?;
        let mut guard = write(&m);
        let m = Arc::make_mut(&mut guard);
        let couplings = labels
            .iter()
            .map(|l| Ok(Coupling::single(dof_index(m, l)?)))
            .collect::<Result<Vec<_>, Failure>>()?;
        let law = parse_law(name, law)?;
        if law.arity() != couplings.len() {
            return Err(Failure::input(format!(
                "element '{name}': its {} law acts on {} coordinates but {} dofs were given",
                law.kind(),
                law.arity(),
                couplings.len()
            )));
        }
        m.add_element(NonlinearElement::coupled(name, law, couplings)?)?;
        Ok(Done::Complete)
    })
}

/// Adds a force input `name` at DOF `dof` with nominal amplitude `amplitude` (N): the
/// fundamental force harmonic of harmonic balance (scaled by the level), and the input row
/// of [`nlsim_simulate`]'s forces in the order inputs were added.
///
/// # Safety
/// `name` and `dof` are strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_model_add_excitation(
    model: NlsimModel,
    name: *const c_char,
    dof: *const c_char,
    amplitude: f64,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let name = unsafe { text(name, "name")? };
        // SAFETY: the function's contract.
        let dof = unsafe { text(dof, "dof")? };
        let m = get_model(model)?;
        let mut guard = write(&m);
        let m = Arc::make_mut(&mut guard);
        let at = m.site(dof)?;
        m.add_excitation(Excitation {
            name: name.into(),
            at,
            amplitude: finite(amplitude, "amplitude")?,
            harmonics: Vec::new(),
        })?;
        Ok(Done::Complete)
    })
}

/// Adds a sensor `name` measuring `quantity` ([`NlsimQuantity`]) at DOF `dof`: a row of
/// every response, in the order sensors were added.
///
/// # Safety
/// `name` and `dof` are strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_model_add_sensor(
    model: NlsimModel,
    name: *const c_char,
    dof: *const c_char,
    quantity: i32,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let name = unsafe { text(name, "name")? };
        // SAFETY: the function's contract.
        let dof = unsafe { text(dof, "dof")? };
        let q = self::quantity(quantity, "quantity")?;
        let m = get_model(model)?;
        let mut guard = write(&m);
        let m = Arc::make_mut(&mut guard);
        let at = m.site(dof)?;
        m.add_sensor(Sensor {
            name: name.into(),
            at,
            quantity: q,
        })?;
        Ok(Done::Complete)
    })
}

/// The sizes of a model.
///
/// # Safety
/// `info` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_model_info(
    model: NlsimModel,
    info: *mut NlsimModelInfo,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let info = unsafe { out(info, "info")? };
        let m = get_model(model)?;
        let m = read(&m);
        *info = NlsimModelInfo {
            n_dofs: m.n_dofs(),
            n_elements: m.elements().len(),
            n_inputs: m.excitation().len(),
            n_sensors: m.sensors().len(),
            n_params: m.parameters().len(),
        };
        Ok(Done::Complete)
    })
}

// ---------------------------------------------------------------------------------------
// Parameters, on models and harmonic-balance systems alike.

/// An object with parameters (a model is held as an `Arc` that a change copies only while a
/// reduced model shares it). The registry's lock is released before the object's own lock
/// is taken, so a long solve on one object never holds up calls on others.
enum WithParams {
    Model(Arc<RwLock<Arc<Model>>>),
    Hb(Arc<RwLock<HbSystem>>),
}

fn parameterized(handle: u64) -> Result<WithParams, Failure> {
    match registry().live.get(&handle) {
        Some(Object::Model(m)) => Ok(WithParams::Model(m.clone())),
        Some(Object::Hb(h)) => Ok(WithParams::Hb(h.clone())),
        Some(other) => Err(wrong(handle, other, "a model or a harmonic-balance system")),
        None => Err(missing(handle)),
    }
}

fn parameters_of(handle: u64) -> Result<Vec<Param>, Failure> {
    Ok(match parameterized(handle)? {
        WithParams::Model(m) => read(&m).parameters(),
        WithParams::Hb(h) => read(&h).parameters(),
    })
}

/// Copies `s` into the caller's buffer with a NUL, or says how long it must be.
fn copy_text(s: &str, buf: &mut [u8], needed: &mut usize) -> Result<Done, Failure> {
    *needed = s.len() + 1;
    if buf.len() < s.len() + 1 {
        return Err(Failure::size("buf", s.len() + 1, buf.len()));
    }
    buf[..s.len()].copy_from_slice(s.as_bytes());
    buf[s.len()] = 0;
    Ok(Done::Complete)
}

/// The name of parameter `index` of a model or harmonic-balance system (`tip.k3`,
/// `stop.e1`, `mode2.zeta`, `stiffness_scale`, …), NUL-terminated into `buf` of `buf_len`
/// bytes. `*needed` receives the bytes the name needs with its NUL, also when `buf` is too
/// short (then `NLSIM_CODE_ERR_SIZE`); pass `buf = NULL, buf_len = 0` to ask.
///
/// # Safety
/// `buf` holds `buf_len` writable bytes (or is null with `buf_len` 0); `needed` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_param_name(
    handle: u64,
    index: usize,
    buf: *mut c_char,
    buf_len: usize,
    needed: *mut usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let needed = unsafe { out(needed, "needed")? };
        // SAFETY: the function's contract.
        let buf = unsafe { slice_mut(buf.cast::<u8>(), buf_len, "buf")? };
        let params = parameters_of(handle)?;
        let p = params.get(index).ok_or_else(|| {
            Failure::input(format!(
                "parameter index {index}: handle {handle} has {} parameters",
                params.len()
            ))
        })?;
        copy_text(&p.to_string(), buf, needed)
    })
}

/// The value of parameter `name` of a model or harmonic-balance system into `*value`, in
/// its SI unit. An unknown name is an error listing the known ones.
///
/// # Safety
/// `name` is a string; `value` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_get_param(
    handle: u64,
    name: *const c_char,
    value: *mut f64,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let name = unsafe { text(name, "name")? };
        // SAFETY: the function's contract.
        let value = unsafe { out(value, "value")? };
        *value = match parameterized(handle)? {
            WithParams::Model(m) => {
                let m = read(&m);
                m.param(&parse_known(name, &m.parameters())?)?
            }
            WithParams::Hb(h) => {
                let h = read(&h);
                h.param(&parse_known(name, &h.parameters())?)?
            }
        };
        Ok(Done::Complete)
    })
}

/// Sets parameter `name` of a model or harmonic-balance system to `value` (SI unit), with
/// the range checks of its law (a negative gap, a non-finite value are refused and the old
/// value kept). A reduced model or system built from a model before keeps the old value.
///
/// # Safety
/// `name` is a string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_set_param(
    handle: u64,
    name: *const c_char,
    value: f64,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let name = unsafe { text(name, "name")? };
        match parameterized(handle)? {
            WithParams::Model(m) => {
                let mut guard = write(&m);
                let m = Arc::make_mut(&mut guard);
                let p = parse_known(name, &m.parameters())?;
                m.set_param(&p, value)?;
            }
            WithParams::Hb(h) => {
                let mut h = write(&h);
                let p = parse_known(name, &h.parameters())?;
                h.set_param(&p, value)?;
            }
        }
        Ok(Done::Complete)
    })
}

// ---------------------------------------------------------------------------------------
// Reduction.

/// Reduces a model to its `n_modes` lowest modes (shift-invert Lanczos with a Sturm check;
/// thesis eq. 8–10), with residual flexibility at the element, input and sensor DOFs when
/// `residual_flexibility` is non-zero, and stores the handle in `*reduced`. The reduced
/// model keeps a copy of the model as it is now.
///
/// # Safety
/// `reduced` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_reduce(
    model: NlsimModel,
    n_modes: usize,
    residual_flexibility: i32,
    reduced: *mut NlsimReduced,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let reduced = unsafe { out(reduced, "reduced")? };
        let m = get_model(model)?;
        let m = read(&m).clone();
        if n_modes == 0 {
            return Err(Failure::input("n_modes is 0; keep at least one mode"));
        }
        m.validate(&ValidationConfig::default())?;
        let mut cfg = ReductionConfig::lowest(n_modes.min(m.n_dofs()));
        cfg.residual_flexibility = residual_flexibility != 0;
        let r = reduce(&m, &cfg)?;
        *reduced = insert(Object::Reduced(Arc::new(Reduced {
            reduced: r,
            model: m,
        })));
        Ok(Done::Complete)
    })
}

/// The number of modes of a reduced model into `*n_modes`.
///
/// # Safety
/// `n_modes` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_reduced_n_modes(
    reduced: NlsimReduced,
    n_modes: *mut usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let n = unsafe { out(n_modes, "n_modes")? };
        *n = get_reduced(reduced)?.reduced.n_modes();
        Ok(Done::Complete)
    })
}

/// The natural frequencies (Hz) of a reduced model's modes, ascending, into `freq_hz` of
/// `len` = the number of modes.
///
/// # Safety
/// `freq_hz` holds `len` writable doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_reduced_frequencies(
    reduced: NlsimReduced,
    freq_hz: *mut f64,
    len: usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let dst = unsafe { slice_mut(freq_hz, len, "freq_hz")? };
        let r = get_reduced(reduced)?;
        let f = r.reduced.modes.frequencies_hz();
        if dst.len() != f.len() {
            return Err(Failure::size("freq_hz", f.len(), dst.len()));
        }
        dst.copy_from_slice(&f);
        Ok(Done::Complete)
    })
}

// ---------------------------------------------------------------------------------------
// Time simulation.

/// Simulates the reduced model with the exponential first-order-hold integrator (thesis
/// eq. 18–22, implicit nonlinear feedback) for `n_steps` steps of `dt` s from rest.
///
/// `forces` holds the input forces (N), one row per input in the order they were added,
/// `forces_len / n_inputs` samples each at `t = k dt`, linearly interpolated between samples
/// and zero after the last. `outputs` receives one row of `n_steps + 1` samples per sensor
/// (in its quantity: m, m/s or m/s²): `outputs_len = n_sensors · (n_steps + 1)`.
///
/// A run whose nonlinear loop fails or whose response diverges returns
/// `NLSIM_CODE_STOPPED_SHORT` with the samples computed (`info->samples`) and the step in
/// [`nlsim_last_error`].
///
/// # Safety
/// `forces` holds `forces_len` doubles (or is null with 0); `outputs` holds `outputs_len`
/// writable doubles; `info` is null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_simulate(
    reduced: NlsimReduced,
    dt: f64,
    n_steps: usize,
    forces: *const f64,
    forces_len: usize,
    outputs: *mut f64,
    outputs_len: usize,
    info: *mut NlsimRunInfo,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let forces = unsafe { slice(forces, forces_len, "forces")? };
        // SAFETY: the function's contract.
        let outputs = unsafe { slice_mut(outputs, outputs_len, "outputs")? };
        // SAFETY: the function's contract.
        let info = unsafe { out_opt(info, "info")? };
        let dt = positive(dt, "dt")?;
        let r = get_reduced(reduced)?;
        let model = &r.model;
        let n_in = model.excitation().len();
        let n_out = model.sensors().len();
        if n_out == 0 {
            return Err(Failure::input(
                "the model has no sensors: nothing to output",
            ));
        }
        let samples = n_steps
            .checked_add(1)
            .filter(|s| s.checked_mul(n_out).is_some())
            .ok_or_else(|| Failure::input(format!("n_steps {n_steps} is too large")))?;
        if outputs.len() != samples * n_out {
            return Err(Failure::size("outputs", samples * n_out, outputs.len()));
        }
        if n_in == 0 && !forces.is_empty() {
            return Err(Failure::size("forces", 0, forces.len()));
        }
        if n_in > 0 && forces.len() % n_in != 0 {
            return Err(Failure::input(format!(
                "forces has length {}, not a multiple of the {n_in} inputs",
                forces.len()
            )));
        }
        if let Some(i) = forces.iter().position(|v| !v.is_finite()) {
            return Err(Failure::input(format!(
                "forces[{i}] is {} (input {}, sample {})",
                forces[i],
                i / (forces.len() / n_in.max(1)).max(1),
                i % (forces.len() / n_in.max(1)).max(1)
            )));
        }
        let per = forces.len().checked_div(n_in).unwrap_or(0);
        let signals = (0..n_in)
            .map(|i| Signal::Sampled {
                rate_hz: 1.0 / dt,
                values: forces[i * per..(i + 1) * per].to_vec(),
            })
            .collect();
        let plant = Plant::from_model(model, &ModalSystem::new(&r.reduced)?)?;
        let sim = Simulator::new(&plant, &FohConfig::new(dt))?;
        let run = sim.run(&LoadCase::new("capi", signals), n_steps)?;
        let mut computed = 0;
        for (s, sensor) in model.sensors().iter().enumerate() {
            let v = &run.output(&sensor.name)?.values;
            let row = &mut outputs[s * samples..(s + 1) * samples];
            let k = v.len().min(samples);
            row[..k].copy_from_slice(&v[..k]);
            computed = k;
        }
        if let Some(info) = info {
            *info = NlsimRunInfo {
                status: NlsimStatus::from(run.status) as i32,
                samples: computed,
                newton_iterations: run.stats.newton_iterations,
            };
        }
        Ok(match &run.stopped {
            None => Done::Complete,
            Some(e) => Done::Short(e.to_string()),
        })
    })
}

// ---------------------------------------------------------------------------------------
// Harmonic balance.

/// Builds the condensed harmonic-balance system of a reduced model with harmonics
/// `0..=harmonics` (thesis eq. 13–17: receptances of the retained modes with residual
/// flexibility, AFT for the element forces) and stores its handle in `*hb`. The force is
/// the model's inputs at their nominal amplitudes on the fundamental, times the level given
/// to each solve.
///
/// # Safety
/// `hb` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_hb_new(
    reduced: NlsimReduced,
    harmonics: usize,
    hb: *mut NlsimHb,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let hb = unsafe { out(hb, "hb")? };
        if harmonics == 0 || harmonics > 256 {
            return Err(Failure::input(format!(
                "harmonics is {harmonics}; use 1 to 256"
            )));
        }
        let r = get_reduced(reduced)?;
        let sys = HbSystem::from_model(
            &r.model,
            &r.reduced,
            HarmonicSet::new(harmonics, 1)?,
            HbConfig::default(),
        )?;
        *hb = insert(Object::Hb(Arc::new(RwLock::new(sys))));
        Ok(Done::Complete)
    })
}

/// The sizes of a harmonic-balance system.
///
/// # Safety
/// `info` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_hb_info(hb: NlsimHb, info: *mut NlsimHbInfo) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let info = unsafe { out(info, "info")? };
        let h = get_hb(hb)?;
        let h = read(&h);
        *info = NlsimHbInfo {
            harmonics: h.harmonics().h,
            n_sensors: h.sensors().len(),
            n_inputs: h.inputs().len(),
            n_unknowns: h.n_unknowns(),
            n_params: h.parameters().len(),
        };
        Ok(Done::Complete)
    })
}

/// Doubles in one point's response: `[n_sensors][H + 1][2]`.
fn per_point(sys: &HbSystem) -> usize {
    2 * sys.sensors().len() * (sys.harmonics().h + 1)
}

/// Solves one periodic response, started from rest.
fn solve_point(
    sys: &HbSystem,
    freq_hz: f64,
    level: f64,
) -> Result<(Vec<f64>, f64, nlsim::hb::system::NewtonReport), Failure> {
    let omega = 2.0 * std::f64::consts::PI * positive(freq_hz, "freq_hz")?;
    let level = finite(level, "level")?;
    let (x, rep) = sys.solve_from_rest(omega, level)?;
    Ok((x, omega, rep))
}

fn point_info(
    sys: &HbSystem,
    x: &[f64],
    omega: f64,
    rep: &nlsim::hb::system::NewtonReport,
    stability: bool,
) -> Result<NlsimPointInfo, Failure> {
    let mut info = NlsimPointInfo {
        status: NlsimStatus::from(rep.status) as i32,
        iterations: rep.iterations,
        residual: rep.residual,
        stable: -1,
        max_floquet_real: f64::NAN,
    };
    if stability && rep.converged() {
        let s = sys.stability(x, omega)?;
        info.stable = i32::from(s.stable);
        info.max_floquet_real = s.max_real;
    }
    Ok(info)
}

fn not_converged(freq_hz: f64, rep: &nlsim::hb::system::NewtonReport) -> Done {
    Done::Short(format!(
        "the harmonic balance at {freq_hz} Hz did not converge: {} after {} iterations \
         (residual {:.3e} m)",
        rep.status.as_str(),
        rep.iterations,
        rep.residual
    ))
}

/// Solves the periodic response at `freq_hz` (Hz) and force level `level` (1 = the
/// nominal amplitudes) by Newton from rest, and writes every sensor's complex amplitude at
/// every harmonic `k = 0..=H` (in the sensor's quantity) into `response`: shape
/// `[n_sensors][H + 1][2]` (`re, im`), `response_len = 2 · n_sensors · (H + 1)`. With
/// `stability` non-zero, Hill's method gives `info->stable`.
///
/// Where Newton does not converge, returns `NLSIM_CODE_STOPPED_SHORT` with the last iterate's
/// response; near a fold, follow the branch with [`nlsim_frf`] instead.
///
/// # Safety
/// `response` holds `response_len` writable doubles; `info` is null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_hb_point(
    hb: NlsimHb,
    freq_hz: f64,
    level: f64,
    stability: i32,
    response: *mut f64,
    response_len: usize,
    info: *mut NlsimPointInfo,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let dst = unsafe { slice_mut(response, response_len, "response")? };
        let info = unsafe { out_opt(info, "info")? };
        let h = get_hb(hb)?;
        let sys = read(&h);
        let need = per_point(&sys);
        if dst.len() != need {
            return Err(Failure::size("response", need, dst.len()));
        }
        let (x, omega, rep) = solve_point(&sys, freq_hz, level)?;
        let y = sys.sensor_response(&x, omega, level);
        write_complex(dst, mat_entries(&y));
        let pi = point_info(&sys, &x, omega, &rep, stability != 0)?;
        if let Some(info) = info {
            *info = pi;
        }
        Ok(if rep.converged() {
            Done::Complete
        } else {
            not_converged(freq_hz, &rep)
        })
    })
}

pub(crate) fn params_of(sys: &HbSystem, names: &[&str]) -> Result<Vec<Param>, Failure> {
    let known = sys.parameters();
    names
        .iter()
        .map(|n| parse_known(n, &known).map_err(Failure::from))
        .collect()
}

/// Sensitivities of the periodic response at `freq_hz` and `level` to the parameters
/// `names[0..n_params]` (implicit differentiation of the harmonic balance, one factorisation
/// for all): `dresponse` receives `∂Y/∂p` with shape `[n_params][n_sensors][H + 1][2]`, in
/// the sensor's unit per parameter unit; `response` (optional, may be null with length 0)
/// the response itself as [`nlsim_hb_point`] writes it.
///
/// # Safety
/// `names` holds `n_params` strings; `response` and `dresponse` hold their lengths in
/// writable doubles; `info` is null or writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_hb_sensitivities(
    hb: NlsimHb,
    freq_hz: f64,
    level: f64,
    names: *const *const c_char,
    n_params: usize,
    response: *mut f64,
    response_len: usize,
    dresponse: *mut f64,
    dresponse_len: usize,
    info: *mut NlsimPointInfo,
) -> NlsimCode {
    guard(|| {
        // SAFETY (every block below): the function's contract.
        let names = unsafe { texts(names, n_params, "names")? };
        let resp = unsafe { slice_mut(response, response_len, "response")? };
        let dresp = unsafe { slice_mut(dresponse, dresponse_len, "dresponse")? };
        let info = unsafe { out_opt(info, "info")? };
        let h = get_hb(hb)?;
        let sys = read(&h);
        let params = params_of(&sys, &names)?;
        let per = per_point(&sys);
        if !resp.is_empty() && resp.len() != per {
            return Err(Failure::size("response", per, resp.len()));
        }
        if dresp.len() != per * params.len() {
            return Err(Failure::size("dresponse", per * params.len(), dresp.len()));
        }
        let (x, omega, rep) = solve_point(&sys, freq_hz, level)?;
        if !resp.is_empty() {
            let y = sys.sensor_response(&x, omega, level);
            write_complex(resp, mat_entries(&y));
        }
        let pi = point_info(&sys, &x, omega, &rep, false)?;
        if let Some(info) = info {
            *info = pi;
        }
        if !rep.converged() {
            return Ok(not_converged(freq_hz, &rep));
        }
        for (j, s) in sys
            .sensitivities(&x, omega, level, &params)?
            .iter()
            .enumerate()
        {
            write_complex(&mut dresp[j * per..(j + 1) * per], mat_entries(&s.dy));
        }
        Ok(Done::Complete)
    })
}

/// The entries of `m` in row-major order.
fn mat_entries(m: &faer::Mat<faer::c64>) -> impl Iterator<Item = faer::c64> + '_ {
    (0..m.nrows()).flat_map(move |i| (0..m.ncols()).map(move |j| m[(i, j)]))
}

/// Follows the frequency response from `from_hz` to `to_hz` (either order) at force level
/// `level` by pseudo-arclength continuation (thesis §3.3; folds and turning branches
/// followed), with Hill stability at every point when `stability` is non-zero and at most
/// `max_points` points (0: 5000), and stores the branch's handle in `*frf`. A run that stops
/// short returns `NLSIM_CODE_STOPPED_SHORT` and still creates the handle with the points
/// found. Read it with [`nlsim_frf_info`], [`nlsim_frf_frequencies`],
/// [`nlsim_frf_response`], [`nlsim_frf_stability`], [`nlsim_frf_sensitivities`].
///
/// # Safety
/// `frf` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_frf(
    hb: NlsimHb,
    from_hz: f64,
    to_hz: f64,
    level: f64,
    stability: i32,
    max_points: usize,
    frf: *mut NlsimFrf,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let frf = unsafe { out(frf, "frf")? };
        let from = positive(from_hz, "from_hz")?;
        let to = positive(to_hz, "to_hz")?;
        if from == to {
            return Err(Failure::input(format!(
                "from_hz and to_hz are both {from}: the range is empty"
            )));
        }
        let h = get_hb(hb)?;
        let sys = read(&h).clone();
        let mut cfg = nlsim::hb::ContinuationConfig::frequency(from, to);
        cfg.fixed = finite(level, "level")?;
        cfg.stability = stability != 0;
        if max_points > 0 {
            cfg.max_points = max_points;
        }
        let report = continuation(&sys, &cfg, None)?;
        let done = if report.is_complete() {
            Done::Complete
        } else {
            Done::Short(report.detail.clone())
        };
        *frf = insert(Object::Frf(Arc::new(Frf {
            system: sys,
            report,
        })));
        Ok(done)
    })
}

/// The status and counters of a frequency response.
///
/// # Safety
/// `info` is writable.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_frf_info(frf: NlsimFrf, info: *mut NlsimFrfInfo) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let info = unsafe { out(info, "info")? };
        let f = get_frf(frf)?;
        let r = &f.report;
        *info = NlsimFrfInfo {
            status: NlsimStatus::from(r.status) as i32,
            n_points: r.branch.points.len(),
            n_folds: r.branch.folds().len(),
            n_rejected: r.stats.n_rejected,
            n_newton: r.stats.n_newton,
        };
        Ok(Done::Complete)
    })
}

/// The frequencies (Hz) of the branch's points, in order along the branch (they turn back
/// at folds), into `freq_hz` of `len = n_points`.
///
/// # Safety
/// `freq_hz` holds `len` writable doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_frf_frequencies(
    frf: NlsimFrf,
    freq_hz: *mut f64,
    len: usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let dst = unsafe { slice_mut(freq_hz, len, "freq_hz")? };
        let f = get_frf(frf)?;
        let pts = &f.report.branch.points;
        if dst.len() != pts.len() {
            return Err(Failure::size("freq_hz", pts.len(), dst.len()));
        }
        for (d, p) in dst.iter_mut().zip(pts) {
            *d = p.omega / (2.0 * std::f64::consts::PI);
        }
        Ok(Done::Complete)
    })
}

/// The sensors' complex harmonic amplitudes at every point of the branch, shape
/// `[n_points][n_sensors][H + 1][2]`.
///
/// # Safety
/// `response` holds `len` writable doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_frf_response(
    frf: NlsimFrf,
    response: *mut f64,
    len: usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let dst = unsafe { slice_mut(response, len, "response")? };
        let f = get_frf(frf)?;
        let sys = &f.system;
        let pts = &f.report.branch.points;
        let per = per_point(sys);
        if dst.len() != per * pts.len() {
            return Err(Failure::size("response", per * pts.len(), dst.len()));
        }
        for (chunk, p) in dst.chunks_exact_mut(per.max(1)).zip(pts) {
            let y = sys.sensor_response(&p.x, p.omega, p.scale);
            write_complex(chunk, mat_entries(&y));
        }
        Ok(Done::Complete)
    })
}

/// The stability of every point (1 stable, 0 unstable, −1 not computed) and whether it is a
/// fold (1) or not (0), into `stable` and `fold`, each of `len = n_points` (either may be
/// null to skip it).
///
/// # Safety
/// `stable` and `fold` are null or hold `len` writable `int32_t`.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_frf_stability(
    frf: NlsimFrf,
    stable: *mut i32,
    fold: *mut i32,
    len: usize,
) -> NlsimCode {
    guard(|| {
        let f = get_frf(frf)?;
        let pts = &f.report.branch.points;
        if len != pts.len() {
            return Err(Failure::size("stable/fold", pts.len(), len));
        }
        if !stable.is_null() {
            // SAFETY: the function's contract.
            let s = unsafe { slice_mut(stable, len, "stable")? };
            for (d, p) in s.iter_mut().zip(pts) {
                *d = p.stable().map_or(-1, i32::from);
            }
        }
        if !fold.is_null() {
            // SAFETY: the function's contract.
            let s = unsafe { slice_mut(fold, len, "fold")? };
            for (d, p) in s.iter_mut().zip(pts) {
                *d = i32::from(p.kind == nlsim::hb::PointKind::Fold);
            }
        }
        Ok(Done::Complete)
    })
}

/// Sensitivities of the whole branch to `names[0..n_params]`, point by point at each
/// point's frequency: shape `[n_points][n_params][n_sensors][H + 1][2]`. At a fold the
/// derivative at fixed frequency is unbounded and its entries are large or non-finite.
///
/// # Safety
/// `names` holds `n_params` strings; `dresponse` holds `len` writable doubles.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn nlsim_frf_sensitivities(
    frf: NlsimFrf,
    names: *const *const c_char,
    n_params: usize,
    dresponse: *mut f64,
    len: usize,
) -> NlsimCode {
    guard(|| {
        // SAFETY: the function's contract.
        let names = unsafe { texts(names, n_params, "names")? };
        // SAFETY: the function's contract.
        let dst = unsafe { slice_mut(dresponse, len, "dresponse")? };
        let f = get_frf(frf)?;
        let sys = &f.system;
        let params = params_of(sys, &names)?;
        let pts = &f.report.branch.points;
        let per = per_point(sys);
        let need = per * params.len() * pts.len();
        if dst.len() != need {
            return Err(Failure::size("dresponse", need, dst.len()));
        }
        if need == 0 {
            return Ok(Done::Complete);
        }
        for (chunk, p) in dst.chunks_exact_mut(per * params.len()).zip(pts) {
            for (j, s) in sys
                .sensitivities(&p.x, p.omega, p.scale, &params)?
                .iter()
                .enumerate()
            {
                write_complex(&mut chunk[j * per..(j + 1) * per], mat_entries(&s.dy));
            }
        }
        Ok(Done::Complete)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_becomes_an_internal_error_with_its_message() {
        let code = guard(|| -> Result<Done, Failure> { panic!("index 7 out of range") });
        assert_eq!(code, NlsimCode::ErrInternal);
        // SAFETY: nlsim_last_error returns this thread's NUL-terminated message.
        let msg = unsafe { CStr::from_ptr(nlsim_last_error()) }
            .to_str()
            .unwrap();
        assert!(msg.contains("index 7 out of range"), "{msg}");
        assert_eq!(guard(|| Ok(Done::Complete)), NlsimCode::Ok);
        // SAFETY: as above.
        assert!(unsafe { CStr::from_ptr(nlsim_last_error()) }.is_empty());
    }

    #[test]
    fn laws_parse_with_the_model_file_keys_and_defaults() {
        assert_eq!(
            parse_law("s", "cubic k3=1.7e15").unwrap(),
            Law::Cubic { k3: 1.7e15 }
        );
        assert_eq!(
            parse_law("s", "clearance, k1=5e5, e1=1e-3").unwrap(),
            Law::Clearance {
                k1: 5e5,
                k2: 0.0,
                e1: 1e-3,
                e2: 0.0,
                r: 1.0,
                s: 1.0
            }
        );
        let Law::Polynomial { stiffness, damping } =
            parse_law("p", "polynomial k3=2 c1=0.5 k2=1").unwrap()
        else {
            panic!("not a polynomial")
        };
        assert_eq!(
            stiffness
                .iter()
                .map(|t| (t.power, t.coef))
                .collect::<Vec<_>>(),
            [(2, 1.0), (3, 2.0)]
        );
        assert_eq!(damping.len(), 1);
        for (bad, why) in [
            ("", "empty"),
            ("cubic", "needs 'k3'"),
            ("cubic k3", "not key=value"),
            ("cubic k3=abc", "not a number"),
            ("cubic k3=1 k3=2", "twice"),
            ("spline k=1", "unknown type"),
            ("polynomial k0=1", "no parameter 'k0'"),
        ] {
            let e = parse_law("s", bad)
                .err()
                .unwrap_or_else(|| panic!("{bad} parsed"));
            assert!(e.message.contains(why), "{bad}: {}", e.message);
        }
    }

    /// NLvib's example 6 built through the ABI (its coupled element from a law string and two
    /// DOF labels) is the model file's, and simulates to the same samples, bit for bit.
    #[cfg(feature = "io")]
    #[test]
    fn a_coupled_element_through_the_abi_is_the_model_files() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../examples/models/nlvib_ex6.toml"
        );
        let file = nlsim::load_model(path).unwrap().model;
        let el = file.elements()[0].clone();
        let law = std::iter::once("coupled_polynomial".to_string())
            .chain(
                (0..el.law().n_params())
                    .map(|i| format!("{}={:e}", el.law().param_name(i), el.law().param(i))),
            )
            .collect::<Vec<_>>()
            .join(" ");
        let mut bare = file.clone();
        bare.clear_elements();
        let handle = |m: Model| insert(Object::Model(Arc::new(RwLock::new(Arc::new(m)))));
        let (a, b) = (handle(file.clone()), handle(bare));
        let law_c = std::ffi::CString::new(law).unwrap();
        let dofs = [c"1:u".as_ptr(), c"2:u".as_ptr()];
        // SAFETY: strings and an array of two strings.
        let add = |d: &[*const c_char]| unsafe {
            nlsim_model_add_coupled_element(
                b,
                c"geometry".as_ptr(),
                law_c.as_ptr(),
                d.as_ptr(),
                d.len(),
            )
        };
        assert_eq!(add(&dofs[..1]), NlsimCode::ErrInput);
        // SAFETY: the message is a NUL-terminated string of this thread.
        let msg = unsafe { CStr::from_ptr(nlsim_last_error()) }
            .to_str()
            .unwrap()
            .to_owned();
        assert!(
            msg.contains("'geometry'") && msg.contains("2 coordinates"),
            "{msg}"
        );
        assert_eq!(add(&dofs), NlsimCode::Ok);
        let built = get_model(b).unwrap();
        assert_eq!(built.read().unwrap().elements(), file.elements());
        let run = |m: NlsimModel| {
            let mut red = 0;
            // SAFETY: `red` is writable.
            assert_eq!(unsafe { nlsim_reduce(m, 2, 1, &mut red) }, NlsimCode::Ok);
            let n = 400;
            let forces: Vec<f64> = (0..2 * (n + 1))
                .map(|i| 0.03 * (1.1 * 0.05 * (i % (n + 1)) as f64).sin())
                .collect();
            let mut y = vec![0.0; 2 * (n + 1)];
            // SAFETY: the lengths given are the buffers'.
            let code = unsafe {
                nlsim_simulate(
                    red,
                    0.05,
                    n,
                    forces.as_ptr(),
                    forces.len(),
                    y.as_mut_ptr(),
                    y.len(),
                    std::ptr::null_mut(),
                )
            };
            assert_eq!(code, NlsimCode::Ok);
            y
        };
        let (ya, yb) = (run(a), run(b));
        assert!(ya.iter().fold(0.0f64, |m, v| m.max(v.abs())) > 0.05);
        assert_eq!(ya, yb);
    }

    /// The same 3×3 matrix in every storage the ABI accepts equals its dense assembly.
    #[test]
    fn every_sparse_storage_gives_the_same_matrix() {
        let dense = [[4.0, -1.0, 0.0], [-1.0, 4.0, -2.0], [0.0, -2.0, 5.0]];
        let want =
            SparseSym::from_dense_rows("k", &dense.iter().map(|r| r.to_vec()).collect::<Vec<_>>())
                .unwrap();
        // format, triangle, index base, ptr, idx, values.
        type Case = (i32, i32, i32, Vec<i64>, Vec<i64>, Vec<f64>);
        let cases: [Case; 4] = [
            // Full CSR, 0-based.
            (
                0,
                0,
                0,
                vec![0, 2, 5, 7],
                vec![0, 1, 0, 1, 2, 1, 2],
                vec![4., -1., -1., 4., -2., -2., 5.],
            ),
            // Lower triangle CSC, 1-based.
            (
                1,
                1,
                1,
                vec![1, 3, 5, 6],
                vec![1, 2, 2, 3, 3],
                vec![4., -1., 4., -2., 5.],
            ),
            // Upper triangle CSR, 0-based.
            (
                0,
                1,
                0,
                vec![0, 2, 4, 5],
                vec![0, 1, 1, 2, 2],
                vec![4., -1., 4., -2., 5.],
            ),
            // Full CSC, 1-based.
            (
                1,
                0,
                1,
                vec![1, 3, 6, 8],
                vec![1, 2, 1, 2, 3, 2, 3],
                vec![4., -1., -1., 4., -2., -2., 5.],
            ),
        ];
        for (format, triangle, index_base, ptr, idx, values) in &cases {
            let m = NlsimSparse {
                format: *format,
                triangle: *triangle,
                index_base: *index_base,
                ptr: ptr.as_ptr(),
                idx: idx.as_ptr(),
                values: values.as_ptr(),
            };
            // SAFETY: the arrays hold what `m` declares.
            let got = unsafe { sparse("k", 3, &m) }.unwrap_or_else(|e| panic!("{}", e.message));
            assert_eq!(
                got.to_dense(),
                want.to_dense(),
                "{format} {triangle} {index_base}"
            );
        }
        // A pair given on both sides of a "triangle" is refused, not doubled.
        let (_, _, _, ptr, idx, values) = &cases[0];
        let m = NlsimSparse {
            format: 0,
            triangle: 1,
            index_base: 0,
            ptr: ptr.as_ptr(),
            idx: idx.as_ptr(),
            values: values.as_ptr(),
        };
        // SAFETY: as above.
        assert!(unsafe { sparse("k", 3, &m) }.is_err());
    }

    /// Threads solving on one system while another sets its parameter: every solve sees one
    /// value or the other, never a torn state, and handles created and freed concurrently
    /// all end freed.
    #[test]
    fn calls_from_many_threads_are_safe() {
        let k = SparseSym::from_dense_rows("k", &[vec![2e4, -1e4], vec![-1e4, 1e4]]).unwrap();
        let m = SparseSym::diagonal("m", &[1.0, 1.0]).unwrap();
        let mut model = Model::new("chain", DofMap::scalar(2), m, k).unwrap();
        model
            .set_damping(Damping::Rayleigh {
                alpha: 2.0,
                beta: 0.0,
            })
            .unwrap();
        model
            .add_element(
                NonlinearElement::new("tip", Law::Cubic { k3: 1e9 }, Coupling::single(1)).unwrap(),
            )
            .unwrap();
        model
            .add_excitation(Excitation {
                name: "f".into(),
                at: nlsim::kernel::Site::Dof(1),
                amplitude: 1.0,
                harmonics: Vec::new(),
            })
            .unwrap();
        model
            .add_sensor(Sensor {
                name: "y".into(),
                at: nlsim::kernel::Site::Dof(1),
                quantity: Quantity::Displacement,
            })
            .unwrap();
        let mh = insert(Object::Model(Arc::new(RwLock::new(Arc::new(model)))));
        let mut red = 0;
        // SAFETY: `red` is writable.
        assert_eq!(unsafe { nlsim_reduce(mh, 2, 1, &mut red) }, NlsimCode::Ok);
        let mut hb = 0;
        // SAFETY: `hb` is writable.
        assert_eq!(unsafe { nlsim_hb_new(red, 3, &mut hb) }, NlsimCode::Ok);
        let solve = |hb: u64| {
            let mut y = [0.0; 8];
            // SAFETY: `y` holds 8 doubles.
            let code =
                unsafe { nlsim_hb_point(hb, 5.0, 1.0, 0, y.as_mut_ptr(), 8, std::ptr::null_mut()) };
            assert_eq!(code, NlsimCode::Ok);
            y[2]
        };
        let set = |v: f64| {
            // SAFETY: a static string.
            let code = unsafe { nlsim_set_param(hb, c"tip.k3".as_ptr(), v) };
            assert_eq!(code, NlsimCode::Ok);
        };
        set(2e9);
        let y2 = solve(hb);
        set(1e9);
        let y1 = solve(hb);
        std::thread::scope(|s| {
            for t in 0..4 {
                s.spawn(move || {
                    for i in 0..20 {
                        if t == 0 {
                            set(if i % 2 == 0 { 2e9 } else { 1e9 });
                        } else {
                            let y = solve(hb);
                            assert!(y == y1 || y == y2, "{y} is neither {y1} nor {y2}");
                        }
                        let mut extra = 0;
                        // SAFETY: `extra` is writable.
                        assert_eq!(unsafe { nlsim_hb_new(red, 1, &mut extra) }, NlsimCode::Ok);
                        assert_eq!(nlsim_free(extra), NlsimCode::Ok);
                        assert_eq!(nlsim_free(extra), NlsimCode::ErrHandle);
                    }
                });
            }
        });
        for h in [hb, red, mh] {
            assert_eq!(nlsim_free(h), NlsimCode::Ok);
        }
    }
}
