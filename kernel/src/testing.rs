//! Test helpers shared by nlsim's crates (feature `test-util`): one closeness assertion that
//! fails on NaN, and one finite-difference check for every Jacobian.

/// `|a − b| ≤ atol + rtol · max(|a|, |b|)`, false whenever either is NaN.
pub fn is_close(a: f64, b: f64, rtol: f64, atol: f64) -> bool {
    if a.is_nan() || b.is_nan() {
        return false;
    }
    if a == b {
        return true;
    }
    (a - b).abs() <= atol + rtol * a.abs().max(b.abs())
}

/// Asserts `is_close(a, b, rtol, atol)` with a message naming both values and the tolerances.
#[macro_export]
macro_rules! assert_close {
    ($a:expr, $b:expr, $rtol:expr, $atol:expr $(,)?) => {{
        let (a, b, rtol, atol): (f64, f64, f64, f64) = ($a, $b, $rtol, $atol);
        assert!(
            $crate::testing::is_close(a, b, rtol, atol),
            "assert_close failed: {} = {:e} vs {} = {:e} (diff {:e}, rtol {:e}, atol {:e})",
            stringify!($a), a, stringify!($b), b, (a - b).abs(), rtol, atol
        );
    }};
    ($a:expr, $b:expr, $rtol:expr, $atol:expr, $($msg:tt)+) => {{
        let (a, b, rtol, atol): (f64, f64, f64, f64) = ($a, $b, $rtol, $atol);
        assert!(
            $crate::testing::is_close(a, b, rtol, atol),
            "assert_close failed: {:e} vs {:e} (diff {:e}, rtol {:e}, atol {:e}): {}",
            a, b, (a - b).abs(), rtol, atol, format!($($msg)+)
        );
    }};
}

/// Central difference `(f(x+h) − f(x−h)) / 2h` with a step scaled to `x`:
/// `h = step · max(|x|, scale)`. The truncation error is `O(h² f''')`.
pub fn central_difference(f: impl Fn(f64) -> f64, x: f64, step: f64, scale: f64) -> f64 {
    let h = step * x.abs().max(scale);
    (f(x + h) - f(x - h)) / (2.0 * h)
}

/// Checks an analytic derivative against a central difference of `f` at `x`:
/// `|analytic − fd| ≤ rtol · max(|analytic|, |fd|) + atol`. The step is
/// `h = 1e-6 · max(|x|, x_scale)`. `atol` covers the two errors of the difference itself:
/// round-off, 1e-9 of `|f| / h`, and truncation, `c h²`, estimated by Richardson from the
/// difference at `2h` (which is off by `4c h²`) and counted twice. The truncation term
/// matters where the derivative vanishes (a cubic spring at rest: the difference is `k₃h²`
/// against an exact 0) or `f` curves sharply within a few steps; `f` must be smooth on
/// `[x − 2h, x + 2h]`.
pub fn check_fd(
    what: &str,
    f: impl Fn(f64) -> f64,
    x: f64,
    x_scale: f64,
    analytic: f64,
    rtol: f64,
) -> Result<(), String> {
    let h = 1e-6 * x.abs().max(x_scale);
    let fd = (f(x + h) - f(x - h)) / (2.0 * h);
    let fd2 = (f(x + 2.0 * h) - f(x - 2.0 * h)) / (4.0 * h);
    let f0 = f(x).abs().max(f(x + h).abs()).max(f(x + 2.0 * h).abs());
    let roundoff = 1e-9 * f0 / h;
    let truncation = 2.0 * (fd2 - fd).abs() / 3.0;
    let atol = roundoff + truncation;
    if is_close(analytic, fd, rtol, atol) {
        Ok(())
    } else {
        Err(format!(
            "{what}: analytic {analytic:e} vs finite difference {fd:e} at x = {x:e} (h = {h:e}, atol {atol:e}: round-off {roundoff:e}, truncation {truncation:e})"
        ))
    }
}
