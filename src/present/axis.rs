//! Axes of nlsim's plots: ranges plotters can put ticks on, and tick labels an engineer reads
//! without doubt.
//!
//! A linear axis carries its power of a thousand in the unit of its name (`force (mN)` with
//! ticks `200`, `400`, not `force (N)` with `200m`, which reads as metres), or, where the unit
//! takes no prefix (`%`, a ratio, `kg`), as a factor `[×1e-6]` after the name. A logarithmic
//! axis spans decades, so each tick carries its own exponent (`1e-5`, `2e-5`; plain from 0.01
//! to 10 000).

/// Font size of tick labels, axis names and legends (plotters' units; about 12 px in the SVG):
/// the default's 9.7 px is too small to read on a page.
pub const TICK_FONT: f64 = 15.0;

/// Largest magnitude an axis shows (values beyond are drawn at the edge).
pub const AXIS_MAX: f64 = 1e300;

/// SI prefixes by power of ten.
const PREFIXES: [(i32, &str); 9] = [
    (-15, "f"),
    (-12, "p"),
    (-9, "n"),
    (-6, "µ"),
    (-3, "m"),
    (0, ""),
    (3, "k"),
    (6, "M"),
    (9, "G"),
];

/// Unit symbols that take an SI prefix when they start a unit (`m/s^2` → `mm/s^2`,
/// `N/m^3` → `GN/m^3`); anything else (`%`, `1`, `kg`, `dB`, `deg`, words) does not.
const PREFIXABLE: [&str; 11] = ["m", "N", "s", "Hz", "V", "A", "J", "W", "Pa", "rad", "ohm"];

/// The label of a tick on a logarithmic axis: plain from 0.01 to below 10 000 (`0.05`, `200`),
/// else mantissa and exponent (`1e-5`, `2.5e-9`, `3e6`). The same on any unit: a prefix letter
/// would read as a unit on a metre axis.
pub fn log_tick_label(v: f64) -> String {
    if !v.is_finite() || v == 0.0 {
        return format!("{v}");
    }
    if (1e-2..1e4).contains(&v.abs()) {
        // Ticks of a log axis are 1, 2 or 5 times a power of ten, up to rounding.
        let s = format!("{v:.6}");
        return s.trim_end_matches('0').trim_end_matches('.').to_string();
    }
    exp_label(v)
}

/// `v` as mantissa and exponent with at most four significant digits: `1e-5`, `2.5e-9`.
fn exp_label(v: f64) -> String {
    let s = format!("{v:.3e}");
    let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
    let m = if m.contains('.') {
        m.trim_end_matches('0').trim_end_matches('.')
    } else {
        m
    };
    format!("{m}e{e}")
}

/// A linear axis: its name (with the unit prefix or factor its values need), and how a tick
/// value reads.
#[derive(Debug, Clone, PartialEq)]
pub struct LinearAxis {
    /// The axis name as drawn, e.g. `force (mN)` or `ratio (1) [×1e-9]`.
    pub desc: String,
    /// What a value is divided by before it is written (a power of 1000).
    pub factor: f64,
    /// Tick spacing (same unit as the values; 0 if unknown), for the decimals a label needs.
    pub step: f64,
}

impl LinearAxis {
    /// The axis named `desc` (ending in `(unit)` where it has one) over `lo..hi` with about
    /// `n` ticks. Values of magnitude in `[1, 1000)` and unit-less values in `[1e-3, 1e5)`
    /// read as they are; others are scaled by the power of 1000 that brings the largest
    /// magnitude into `[1, 1000)`, named in the unit (`µm`) or as a factor `[×1e-6]`.
    pub fn new(desc: &str, lo: f64, hi: f64, n: usize) -> LinearAxis {
        let step = tick_step(lo, hi, n);
        let top = lo.abs().max(hi.abs());
        let plain = LinearAxis {
            desc: desc.to_string(),
            factor: 1.0,
            step,
        };
        if !(top.is_finite() && top > 0.0) {
            return plain;
        }
        let exp3 = 3 * (top.log10().floor() as i32).div_euclid(3);
        if exp3 == 0 {
            return plain;
        }
        let factor = 10f64.powi(exp3);
        if let Some((name, unit)) = split_unit(desc)
            && let Some(&(_, prefix)) = PREFIXES.iter().find(|(e, _)| *e == exp3)
        {
            return LinearAxis {
                desc: format!("{name}({prefix}{unit})"),
                factor,
                step,
            };
        }
        if (1e-3..1e5).contains(&top) {
            return plain;
        }
        LinearAxis {
            desc: format!("{desc} [×1e{exp3}]"),
            factor,
            step,
        }
    }

    /// The label of the tick at `v`: `v / factor` with the decimals that the tick spacing and
    /// the value need (up to 6), so that neighbouring labels differ, without trailing zeros.
    /// A tick within rounding of zero is `0`.
    pub fn label(&self, v: f64) -> String {
        if !v.is_finite() {
            return format!("{v}");
        }
        let step = self.step.abs();
        if v == 0.0 || (step > 0.0 && v.abs() < 1e-9 * step) {
            return "0".into();
        }
        let scaled = v / self.factor;
        let whole = |x: f64| {
            (0..=6)
                .find(|&d| {
                    let y = x.abs() * 10f64.powi(d);
                    (y - y.round()).abs() <= 1e-6 * y.max(1.0)
                })
                .unwrap_or(6) as usize
        };
        let by_step = if step > 0.0 && step.is_finite() {
            whole(step / self.factor)
        } else {
            0
        };
        let decimals = by_step.max(whole(scaled));
        let mut text = format!("{scaled:.decimals$}");
        if text.contains('.') {
            text = text.trim_end_matches('0').trim_end_matches('.').to_string();
        }
        if text == "-0" {
            text = "0".into();
        }
        text
    }
}

/// `desc` as `(name up to and with the space before "(", unit)` when it ends in a
/// parenthesised unit that takes an SI prefix.
fn split_unit(desc: &str) -> Option<(&str, &str)> {
    let body = desc.strip_suffix(')')?;
    let open = body.rfind('(')?;
    let unit = &body[open + 1..];
    let first = unit.split(['/', ' ', '^', '*', '·']).next()?;
    PREFIXABLE.contains(&first).then_some((&desc[..open], unit))
}

/// The tick spacing plotters will use on an axis spanning `lo..hi` with about `n` labels:
/// the span over `n`, rounded down to 1, 2 or 5 times a power of ten.
pub fn tick_step(lo: f64, hi: f64, n: usize) -> f64 {
    let raw = (hi - lo).abs() / n.max(1) as f64;
    if !(raw.is_finite() && raw > 0.0) {
        return 0.0;
    }
    let p = 10f64.powf(raw.log10().floor());
    [5.0, 2.0, 1.0]
        .into_iter()
        .map(|m| m * p)
        .find(|&s| s <= raw)
        .unwrap_or(p)
}

/// A range plotters can put ticks on in bounded time, from any data range: NaN and
/// infinite ends dropped (`0..1` when nothing finite is left), ends clamped to ±[`AXIS_MAX`],
/// and a span of at least 1e-9 of the larger end (or 1e-300) centred on the data. plotters
/// 0.3.7 searches tick spacings in a loop that never ends on an infinite span or one
/// narrower than the rounding of its ends.
pub fn axis_range(lo: f64, hi: f64) -> (f64, f64) {
    let (lo, hi) = match (lo.is_finite(), hi.is_finite()) {
        (true, true) => (lo.min(hi), lo.max(hi)),
        (true, false) => (lo, lo),
        (false, true) => (hi, hi),
        (false, false) => return (0.0, 1.0),
    };
    let (lo, hi) = (lo.clamp(-AXIS_MAX, AXIS_MAX), hi.clamp(-AXIS_MAX, AXIS_MAX));
    let min_span = (1e-9 * lo.abs().max(hi.abs())).max(1e-300);
    if hi - lo >= min_span {
        return (lo, hi);
    }
    let centre = 0.5 * lo + 0.5 * hi;
    (centre - 0.5 * min_span, centre + 0.5 * min_span)
}

/// [`axis_range`] for a logarithmic axis: ends within `[1e-300, 1e300]`, the upper at least
/// `1 + 1e-9` times the lower.
pub fn log_axis_range(lo: f64, hi: f64) -> (f64, f64) {
    let ok = |v: f64| v.is_finite() && v > 0.0;
    let (lo, hi) = match (ok(lo), ok(hi)) {
        (true, true) => (lo.min(hi), lo.max(hi)),
        (true, false) => (lo, lo),
        (false, true) => (hi, hi),
        (false, false) => return (1e-3, 1.0),
    };
    let (lo, hi) = (lo.clamp(1e-300, AXIS_MAX), hi.clamp(1e-300, AXIS_MAX));
    (lo, hi.max(lo * (1.0 + 1e-9)))
}

#[cfg(test)]
mod tests {
    use super::{LinearAxis, log_tick_label, tick_step};

    fn labels(desc: &str, lo: f64, hi: f64, ticks: &[f64]) -> (String, Vec<String>) {
        let a = LinearAxis::new(desc, lo, hi, 20);
        (a.desc.clone(), ticks.iter().map(|&v| a.label(v)).collect())
    }

    /// The prefix goes into the unit: no `200m` on a newton axis.
    #[test]
    fn a_linear_axis_names_its_prefix_in_the_unit() {
        assert_eq!(
            labels("force (N)", 0.0, 0.8, &[0.0, 0.2, 0.45]),
            (
                "force (mN)".into(),
                vec!["0".into(), "200".into(), "450".into()]
            )
        );
        assert_eq!(
            labels("|tip| (m)", -4e-5, 4e-5, &[-2e-5, 1.5e-5]),
            ("|tip| (µm)".into(), vec!["-20".into(), "15".into()])
        );
        assert_eq!(
            labels("|tip| acceleration (m/s^2)", 0.0, 2.5e-3, &[1e-3]),
            ("|tip| acceleration (mm/s^2)".into(), vec!["1".into()])
        );
        assert_eq!(
            labels("stiffness (N/m^3)", 5e9, 7e9, &[6.25e9]),
            ("stiffness (GN/m^3)".into(), vec!["6.25".into()])
        );
        assert_eq!(
            labels("frequency (Hz)", 20.0, 35.0, &[22.5, 30.0]),
            ("frequency (Hz)".into(), vec!["22.5".into(), "30".into()])
        );
        assert_eq!(
            labels("frequency (Hz)", 500.0, 2500.0, &[1000.0, 1500.0]),
            ("frequency (kHz)".into(), vec!["1".into(), "1.5".into()])
        );
    }

    /// Units that take no prefix keep plain numbers where they read well, else a factor.
    #[test]
    fn units_without_prefix_read_plain_or_with_a_factor() {
        assert_eq!(
            labels("std (% of the nominal value)", 0.0, 9000.0, &[2000.0]),
            ("std (% of the nominal value)".into(), vec!["2000".into()])
        );
        assert_eq!(
            labels("fold estimate / estimate (1)", 0.99, 1.01, &[0.995, 1.0]),
            (
                "fold estimate / estimate (1)".into(),
                vec!["0.995".into(), "1".into()]
            )
        );
        assert_eq!(
            labels("ratio (1)", 0.0, 4e-7, &[2e-7]),
            ("ratio (1) [×1e-9]".into(), vec!["200".into()])
        );
        assert_eq!(
            labels("mass (kg)", 0.0, 0.004, &[0.002]),
            ("mass (kg)".into(), vec!["0.002".into()])
        );
        // A word in brackets is no unit.
        assert_eq!(
            labels("angle (phase wraps)", 0.0, 2e-6, &[1e-6]).0,
            "angle (phase wraps) [×1e-6]"
        );
    }

    #[test]
    fn neighbouring_ticks_stay_distinct_and_zero_is_zero() {
        let a = LinearAxis::new("x (1)", 1.0001, 1.0009, 8);
        let mut l: Vec<String> = (1..=8).map(|i| a.label(1.0 + i as f64 * 1e-4)).collect();
        let n = l.len();
        l.dedup();
        assert_eq!(l.len(), n, "{l:?}");
        let a = LinearAxis::new("y (m)", -1.0, 1.0, 20);
        assert_eq!(a.label(1e-17), "0");
        assert_eq!(a.label(-0.0), "0");
        assert_eq!(a.label(0.30000000000000004), "0.3");
    }

    #[test]
    fn log_ticks_carry_their_own_exponent() {
        let got: Vec<String> = (-7..=5).map(|e| log_tick_label(10f64.powi(e))).collect();
        assert_eq!(
            got,
            [
                "1e-7", "1e-6", "1e-5", "1e-4", "1e-3", "0.01", "0.1", "1", "10", "100", "1000",
                "1e4", "1e5"
            ]
        );
        assert_eq!(log_tick_label(2e-7), "2e-7");
        assert_eq!(log_tick_label(5e-2), "0.05");
        assert_eq!(log_tick_label(2.5e-9), "2.5e-9");
        assert_eq!(log_tick_label(9.999999999e-6), "1e-5");
    }

    #[test]
    fn tick_steps_are_1_2_5_decades() {
        assert_eq!(tick_step(0.0, 10.0, 10), 1.0);
        assert_eq!(tick_step(0.0, 4.5e-3, 10), 2e-4);
        assert_eq!(tick_step(0.0, 70.0, 10), 5.0);
        assert_eq!(tick_step(1.0, 1.0, 10), 0.0);
    }
}
