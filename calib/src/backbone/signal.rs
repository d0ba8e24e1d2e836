//! Signal processing behind the free-decay identification: a zero-phase Butterworth band
//! pass, a radix-2 FFT (for the spectrum's peak) and the analytic signal.
//!
//! The band pass is a cascade of second-order sections (bilinear transform, prewarped at
//! each edge) run forward and then backward over the record, so its phase cancels and its
//! magnitude is `|H(f)|²`. White noise of variance `s²` per sample comes out with variance
//! `s² · 2 B/f_s`, `B = ∫₀^{f_s/2} |H(f)|⁴ df` its noise bandwidth, which
//! [`BandPass::noise_bandwidth_hz`] gives: a least-squares fit on the filtered record uses it
//! to turn the residual's variance back into that of the white noise in the band.

use faer::c64;
use std::f64::consts::PI;

/// One second-order section `(b₀ + b₁z⁻¹ + b₂z⁻²)/(1 + a₁z⁻¹ + a₂z⁻²)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Biquad {
    b: [f64; 3],
    a: [f64; 2],
}

impl Biquad {
    /// A Butterworth section of quality `q` at `f0` (Hz), sampling rate `fs` (Hz): low pass
    /// or high pass, by the bilinear transform prewarped at `f0`.
    fn butterworth(f0: f64, fs: f64, q: f64, high: bool) -> Self {
        let w0 = 2.0 * PI * f0 / fs;
        let (s, c) = w0.sin_cos();
        let alpha = s / (2.0 * q);
        let a0 = 1.0 + alpha;
        let b = if high {
            [(1.0 + c) / 2.0, -(1.0 + c), (1.0 + c) / 2.0]
        } else {
            [(1.0 - c) / 2.0, 1.0 - c, (1.0 - c) / 2.0]
        };
        Biquad {
            b: [b[0] / a0, b[1] / a0, b[2] / a0],
            a: [-2.0 * c / a0, (1.0 - alpha) / a0],
        }
    }

    /// Runs the section over `x` in place (transposed direct form II, zero initial state).
    fn run(&self, x: &mut [f64]) {
        let (mut s1, mut s2) = (0.0, 0.0);
        for v in x.iter_mut() {
            let u = *v;
            let y = self.b[0] * u + s1;
            s1 = self.b[1] * u - self.a[0] * y + s2;
            s2 = self.b[2] * u - self.a[1] * y;
            *v = y;
        }
    }

    /// The section's response at `w` (rad per sample).
    fn response(&self, w: f64) -> c64 {
        let z1 = c64::from_polar(1.0, -w);
        let z2 = z1 * z1;
        let num = c64::new(self.b[0], 0.0) + z1 * self.b[1] + z2 * self.b[2];
        let den = c64::new(1.0, 0.0) + z1 * self.a[0] + z2 * self.a[1];
        num / den
    }
}

/// A zero-phase Butterworth band pass (forward and backward).
#[derive(Debug, Clone, PartialEq)]
pub struct BandPass {
    /// Lower edge (Hz; −3 dB of one pass); 0 when there is no high-pass part.
    pub low_hz: f64,
    /// Upper edge (Hz; −3 dB of one pass); the Nyquist frequency when there is no low-pass
    /// part.
    pub high_hz: f64,
    /// Order of each edge of one pass (2 or 4; the forward-backward run doubles it).
    pub order: usize,
    /// Noise bandwidth `∫₀^{f_s/2} |H(f)|⁴ df` of the forward-backward run (Hz).
    pub noise_bandwidth_hz: f64,
    /// Samples of the longest transient of the filter (its impulse response falls below
    /// 10⁻³ of its peak within them): the samples trimmed at each end of a filtered record.
    pub settle_samples: usize,
    sections: Vec<Biquad>,
    rate_hz: f64,
}

impl BandPass {
    /// The band pass from `low_hz` to `high_hz` at sampling rate `rate_hz`, `order` 2 or 4
    /// per edge. An edge at or below 0 leaves out the high pass, one at or above the
    /// Nyquist frequency the low pass. The caller checks `low_hz < high_hz` and the order.
    pub fn new(low_hz: f64, high_hz: f64, rate_hz: f64, order: usize) -> Self {
        let nyquist = rate_hz / 2.0;
        let qs: Vec<f64> = (0..order / 2)
            .map(|k| 1.0 / (2.0 * ((2 * k + 1) as f64 * PI / (2 * order) as f64).cos()))
            .collect();
        let mut sections = Vec::new();
        let has_high_pass = low_hz > 0.0;
        let has_low_pass = high_hz < 0.98 * nyquist;
        if has_high_pass {
            sections.extend(
                qs.iter()
                    .map(|&q| Biquad::butterworth(low_hz, rate_hz, q, true)),
            );
        }
        if has_low_pass {
            sections.extend(
                qs.iter()
                    .map(|&q| Biquad::butterworth(high_hz, rate_hz, q, false)),
            );
        }
        let mut bp = BandPass {
            low_hz: if has_high_pass { low_hz } else { 0.0 },
            high_hz: if has_low_pass { high_hz } else { nyquist },
            order,
            noise_bandwidth_hz: 0.0,
            settle_samples: 0,
            sections,
            rate_hz,
        };
        // |H|⁴ integrated by the trapezoid rule on 2¹⁴ intervals: the sections are smooth
        // in w and the integral is good to far better than the statistics it scales.
        let n = 1usize << 14;
        let mut s = 0.0;
        for i in 0..=n {
            let w = PI * i as f64 / n as f64;
            let g = bp.response(w).norm_sqr();
            let wt = if i == 0 || i == n { 0.5 } else { 1.0 };
            s += wt * g * g;
        }
        bp.noise_bandwidth_hz = s / n as f64 * nyquist;
        // The settling time from the impulse response of one pass (run long enough for the
        // narrowest edge: 40 periods of the lowest edge present).
        let edge = if has_high_pass {
            low_hz
        } else {
            high_hz.min(nyquist)
        };
        let span = ((40.0 * rate_hz / edge).ceil() as usize).clamp(64, 1 << 22);
        let mut imp = vec![0.0; span];
        imp[0] = 1.0;
        for sec in &bp.sections {
            sec.run(&mut imp);
        }
        let peak = imp.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        bp.settle_samples = imp
            .iter()
            .rposition(|v| v.abs() > 1e-3 * peak)
            .map_or(0, |i| i + 1);
        bp
    }

    /// `H(e^{iw})` of one pass at `w` (rad per sample).
    pub fn response(&self, w: f64) -> c64 {
        self.sections
            .iter()
            .fold(c64::new(1.0, 0.0), |h, s| h * s.response(w))
    }

    /// `|H(f)|²`: the gain of the forward-backward run at `f` (Hz).
    pub fn gain(&self, f_hz: f64) -> f64 {
        self.response(2.0 * PI * f_hz / self.rate_hz).norm_sqr()
    }

    /// `x` filtered forward and backward. Each end is extended by its odd reflection
    /// (`2x₀ − x_{k}`) over the filter's settling length (at most the record), which keeps
    /// the start-up transients off the record's ends; the caller still trims
    /// [`BandPass::settle_samples`] at each end.
    pub fn filtfilt(&self, x: &[f64]) -> Vec<f64> {
        let n = x.len();
        if n == 0 || self.sections.is_empty() {
            return x.to_vec();
        }
        let pad = self.settle_samples.min(n - 1);
        let mut y = Vec::with_capacity(n + 2 * pad);
        y.extend((1..=pad).rev().map(|k| 2.0 * x[0] - x[k]));
        y.extend_from_slice(x);
        y.extend((1..=pad).map(|k| 2.0 * x[n - 1] - x[n - 1 - k]));
        for s in &self.sections {
            s.run(&mut y);
        }
        y.reverse();
        for s in &self.sections {
            s.run(&mut y);
        }
        y.reverse();
        y[pad..pad + n].to_vec()
    }
}

/// In-place radix-2 FFT of `x` (length a power of two): `X_k = Σ_n x_n e^{∓2πikn/N}`, the
/// minus sign forward; the inverse is not scaled.
pub fn fft(x: &mut [c64], inverse: bool) {
    let n = x.len();
    if n <= 1 {
        return;
    }
    debug_assert!(n.is_power_of_two());
    let bits = n.trailing_zeros();
    for i in 0..n {
        let j = i.reverse_bits() >> (usize::BITS - bits);
        if j > i {
            x.swap(i, j);
        }
    }
    let sign = if inverse { 1.0 } else { -1.0 };
    let mut len = 2;
    while len <= n {
        let half = len / 2;
        // Twiddles of this stage computed directly (no accumulated rotation error).
        let tw: Vec<c64> = (0..half)
            .map(|k| c64::from_polar(1.0, sign * 2.0 * PI * k as f64 / len as f64))
            .collect();
        for start in (0..n).step_by(len) {
            for k in 0..half {
                let u = x[start + k];
                let v = x[start + k + half] * tw[k];
                x[start + k] = u + v;
                x[start + k + half] = u - v;
            }
        }
        len *= 2;
    }
}

/// The low pass that demodulates a record band-limited to `f_c(1 ± b)` in
/// [`analytic_signal`]: order 8 at `f_c √(b(2 − b))`, the geometric mean of the band's
/// half-width `b f_c` and the image's nearest frequency `(2 − b) f_c`.
pub fn demodulation_filter(rate_hz: f64, centre_hz: f64, band: f64) -> BandPass {
    BandPass::new(0.0, centre_hz * (band * (2.0 - band)).sqrt(), rate_hz, 8)
}

/// The analytic signal `z = y + i H[y]` of a record `y` band-limited to `f_c(1 ± b)`, by
/// complex demodulation: `z = 2 L[y e^{−iω_c t}] e^{iω_c t}`, `L` the zero-phase low pass of
/// [`demodulation_filter`]. For a band narrower than `±f_c` this is the Hilbert transform's
/// analytic signal, without the FFT transform's `1/t` leakage of a record that starts at a
/// large value. The image at `2f_c` is attenuated by `1/(1 + r⁸)²` with `r = √((2−b)/b)`
/// (`b = 0.3`: 10⁻⁶), a component `δ` from the carrier by `1/(1 + (δ/c)¹⁶)` (`δ ≤ b f_c/2`:
/// below 2·10⁻⁶); the low pass's start-up transient stays within its settling length of
/// the ends.
pub fn analytic_signal(y: &[f64], rate_hz: f64, centre_hz: f64, band: f64) -> Vec<c64> {
    let lp = demodulation_filter(rate_hz, centre_hz, band);
    let w = 2.0 * PI * centre_hz / rate_hz;
    let carrier: Vec<c64> = (0..y.len())
        .map(|i| c64::from_polar(1.0, w * i as f64))
        .collect();
    let re: Vec<f64> = y.iter().zip(&carrier).map(|(v, c)| v * c.re).collect();
    let im: Vec<f64> = y.iter().zip(&carrier).map(|(v, c)| -v * c.im).collect();
    let (re, im) = (lp.filtfilt(&re), lp.filtfilt(&im));
    re.iter()
        .zip(&im)
        .zip(&carrier)
        .map(|((a, b), c)| c64::new(2.0 * a, 2.0 * b) * c)
        .collect()
}

/// The frequency (Hz) of the largest peak of `x`'s Hann-windowed spectrum between `lo_hz`
/// and `hi_hz`, refined by a parabola through the log magnitudes of the peak bin and its
/// neighbours; `None` when the band holds no bin or the record is constant.
pub fn spectral_peak(x: &[f64], rate_hz: f64, lo_hz: f64, hi_hz: f64) -> Option<f64> {
    let n = x.len();
    if n < 4 {
        return None;
    }
    let size = (4 * n).next_power_of_two();
    let mean = x.iter().sum::<f64>() / n as f64;
    let mut z: Vec<c64> = x
        .iter()
        .enumerate()
        .map(|(i, &v)| {
            let w = 0.5 - 0.5 * (2.0 * PI * i as f64 / (n - 1) as f64).cos();
            c64::new((v - mean) * w, 0.0)
        })
        .collect();
    z.resize(size, c64::new(0.0, 0.0));
    fft(&mut z, false);
    let df = rate_hz / size as f64;
    let first = ((lo_hz / df).ceil() as usize).max(1);
    let last = ((hi_hz / df).floor() as usize).min(size / 2 - 1);
    if first > last {
        return None;
    }
    let (k, peak) = (first..=last)
        .map(|k| (k, z[k].norm()))
        .fold((first, -1.0), |a, b| if b.1 > a.1 { b } else { a });
    if peak <= 0.0 {
        return None;
    }
    let lm = |k: usize| z[k].norm().max(1e-300).ln();
    let shift = if k > 1 && k + 1 < size / 2 {
        let (a, b, c) = (lm(k - 1), lm(k), lm(k + 1));
        let d = a - 2.0 * b + c;
        if d < 0.0 { 0.5 * (a - c) / d } else { 0.0 }
    } else {
        0.0
    };
    Some((k as f64 + shift.clamp(-0.5, 0.5)) * df)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fft_matches_the_direct_sum() {
        let n = 16;
        let x: Vec<c64> = (0..n)
            .map(|i| c64::new((i as f64 * 0.7).sin(), (i as f64 * 0.3).cos()))
            .collect();
        let mut y = x.clone();
        fft(&mut y, false);
        for (k, yk) in y.iter().enumerate() {
            let d: c64 = x
                .iter()
                .enumerate()
                .map(|(m, v)| *v * c64::from_polar(1.0, -2.0 * PI * (k * m) as f64 / n as f64))
                .sum();
            assert!((d - yk).norm() < 1e-12, "bin {k}: {d} vs {yk}");
        }
        fft(&mut y, true);
        for (a, b) in x.iter().zip(&y) {
            assert!((*a - *b / n as f64).norm() < 1e-14);
        }
    }

    #[test]
    fn analytic_signal_of_a_decaying_cosine_is_its_phasor() {
        // A decaying cosine that starts at its largest value: the FFT transform would leak
        // 2/(πd) of it at d samples from the start; demodulation is exact to the low pass's
        // image and gain (1e-6, module docs), past its settling length.
        let (fs, f, s) = (1000.0, 37.1, 3.0);
        let n = 4000;
        let x: Vec<f64> = (0..n)
            .map(|i| {
                let t = i as f64 / fs;
                (-s * t).exp() * (2.0 * PI * f * t + 0.7).cos()
            })
            .collect();
        let z = analytic_signal(&x, fs, 40.0, 0.3);
        let settle = demodulation_filter(fs, 40.0, 0.3).settle_samples;
        // Within one settling length the start-up transient is up to 2e-4 (the definition
        // of the length is the impulse response's tail below 1e-3 of its peak); at two, 1e-6.
        for (i, zi) in z.iter().enumerate().take(n - 2 * settle).skip(2 * settle) {
            let t = i as f64 / fs;
            let e = c64::from_polar((-s * t).exp(), 2.0 * PI * f * t + 0.7);
            assert!(
                (*zi - e).norm() < 1e-5 * e.norm(),
                "sample {i}: {zi} vs {e}"
            );
        }
    }

    #[test]
    fn band_pass_gain_is_half_at_the_edges_and_zero_phase() {
        let fs = 1000.0;
        let bp = BandPass::new(40.0, 60.0, fs, 4);
        // The bilinear Butterworth pass: |H|² = 1/(1 + (Ω/Ω_h)^2n) · 1/(1 + (Ω_l/Ω)^2n) with
        // the warped frequencies Ω = tan(πf/f_s) — one half at each edge times the other
        // edge's gain there.
        let warped = |f: f64| (PI * f / fs).tan();
        let exact = |f: f64| {
            1.0 / (1.0 + (warped(f) / warped(60.0)).powi(8))
                / (1.0 + (warped(40.0) / warped(f)).powi(8))
        };
        for f in [30.0, 40.0, 47.0, 60.0, 90.0] {
            assert!(
                (bp.gain(f) - exact(f)).abs() < 1e-12,
                "{f}: {} vs {}",
                bp.gain(f),
                exact(f)
            );
        }
        assert!(bp.gain(5.0) < 1e-6 && bp.gain(300.0) < 1e-6);
        // A sine at the centre passes with the gain |H|² and without a phase shift.
        let f = 49.0;
        let n = 20_000;
        let x: Vec<f64> = (0..n)
            .map(|i| (2.0 * PI * f * i as f64 / fs + 0.3).sin())
            .collect();
        let y = bp.filtfilt(&x);
        let g = bp.gain(f);
        // Within the settling length of the ends the start-up transient is below 10⁻³ of
        // the signal (the definition of the length); three lengths in, it is gone.
        let s = bp.settle_samples;
        for i in (s..n - s).step_by(7) {
            let tol = if i < 3 * s || i >= n - 3 * s {
                1e-3
            } else {
                1e-9
            };
            assert!(
                (y[i] - g * x[i]).abs() < tol,
                "sample {i}: {} vs {}",
                y[i],
                g * x[i]
            );
        }
        // The noise bandwidth ∫|H|⁴ df from the closed form by Simpson's rule on 10⁵
        // intervals (this narrow band is far from flat: about half of 20 Hz).
        let m = 100_000;
        let h = (fs / 2.0 - 1e-9) / m as f64;
        let simpson: f64 = (0..=m)
            .map(|i| {
                let wt = if i == 0 || i == m {
                    1.0
                } else if i % 2 == 1 {
                    4.0
                } else {
                    2.0
                };
                wt * exact(1e-9 + i as f64 * h).powi(2)
            })
            .sum::<f64>()
            * h
            / 3.0;
        assert!(
            (bp.noise_bandwidth_hz / simpson - 1.0).abs() < 1e-6,
            "{} vs {simpson}",
            bp.noise_bandwidth_hz
        );
    }

    #[test]
    fn spectral_peak_finds_a_tone_between_bins() {
        let fs = 512.0;
        let x: Vec<f64> = (0..3000)
            .map(|i| (2.0 * PI * 47.3 * i as f64 / fs).cos())
            .collect();
        let f = spectral_peak(&x, fs, 5.0, 200.0).unwrap();
        assert!((f - 47.3).abs() < 0.01, "{f}");
    }
}
