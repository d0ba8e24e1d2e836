//! The excitation grammar of `nlsim simulate --excitation` (`sine:AMP:HZ`, `chirp:…`,
//! `multisine:…`, `file:PATH`, …): parsing into a [`Signal`] and describing one in words.
use crate::error::{Error, Result};
use faer::c64;
use nlsim_sim::{Harmonic, Signal};
use std::fmt::Write as _;
use std::path::Path;

/// Most samples a `stepped` excitation spec generates (8·10⁸ bytes).
pub const MAX_STEPPED_SAMPLES: usize = 100_000_000;

/// Parses an excitation spec (see `nlsim simulate --help`):
///
/// - `none`
/// - `sine:freq=HZ[,amp=N][,phase=DEG]`
/// - `multisine:freq=HZ,h1=N[@DEG],h2=…,h1/3=…` — harmonic `hK` at `K·freq`, `h1/K` at
///   `freq/K` (thesis eq. 12), amplitude in N and optional phase in degrees: `hK=A@φ` is
///   `A cos(2π K freq t + φ)`, the cosine convention of `frf` and model files (see
///   `docs/model-files.md`); without harmonics, each point's own (fundamental and
///   `[[excitation.harmonic]]`)
/// - `sweep:f0=HZ,f1=HZ[,amp=N][,duration=S][,log=true]`
/// - `stepped:f0=HZ,f1=HZ,steps=N,dwell=S[,amp=N]` — a stepped sine as a generator plays
///   it: `N` dwells of `S` seconds each at frequencies evenly spaced from `f0` to `f1`, the
///   phase continuous across the switches (`amp · sin φ(t)`), sampled at the run's rate
///   (at most [`MAX_STEPPED_SAMPLES`] samples)
/// - `file:PATH[,rate=HZ]` — one force per line (N); `#` comments; default rate: the run's
///
/// `amp` defaults to `default_amp` (the excitation point's nominal amplitude), a sweep's
/// duration to `duration`, a file's rate to `rate`.
pub fn parse_excitation(spec: &str, default_amp: f64, duration: f64, rate: f64) -> Result<Signal> {
    Ok(parse_signal(spec, default_amp, duration, rate)?.0)
}

/// [`parse_excitation`], and whether the amplitude was `default_amp` (no `amp`, or a
/// multisine without harmonics): then the signal scales with the point's nominal amplitude.
pub(crate) fn parse_signal(
    spec: &str,
    default_amp: f64,
    duration: f64,
    rate: f64,
) -> Result<(Signal, bool)> {
    let (kind, rest) = spec.split_once(':').unwrap_or((spec, ""));
    let usage = |msg: String| Error::Usage(format!("excitation '{spec}': {msg}"));
    let mut kv: Vec<(String, String)> = Vec::new();
    if kind != "file" {
        for part in rest.split(',').filter(|p| !p.trim().is_empty()) {
            let (k, v) = part.split_once('=').ok_or_else(|| {
                usage(format!(
                    "{} is not key=value",
                    crate::formats::files::quoted(part)
                ))
            })?;
            kv.push((k.trim().to_string(), v.trim().to_string()));
        }
    }
    let num = |k: &str, v: &str| -> Result<f64> {
        v.parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| usage(format!("{k}={v} is not a finite number")))
    };
    let take = |kv: &[(String, String)], k: &str| -> Result<Option<f64>> {
        kv.iter()
            .find(|(key, _)| key == k)
            .map(|(_, v)| num(k, v))
            .transpose()
    };
    let allow = |kv: &[(String, String)], keys: &[&str]| -> Result<()> {
        if let Some((k, _)) = kv.iter().find(|(k, _)| !keys.contains(&k.as_str())) {
            return Err(usage(format!(
                "unknown key '{k}' (expected {})",
                keys.join(", ")
            )));
        }
        Ok(())
    };
    let signal = match kind {
        "none" | "zero" => Signal::Zero,
        "sine" => {
            allow(&kv, &["freq", "amp", "phase"])?;
            Signal::Sine {
                amplitude: take(&kv, "amp")?.unwrap_or(default_amp),
                freq_hz: take(&kv, "freq")?.ok_or_else(|| usage("needs freq=HZ".into()))?,
                phase: take(&kv, "phase")?.unwrap_or(0.0).to_radians(),
            }
        }
        "multisine" => {
            let fundamental_hz = take(&kv, "freq")?.ok_or_else(|| usage("needs freq=HZ".into()))?;
            let mut harmonics = Vec::new();
            for (k, v) in kv.iter().filter(|(k, _)| k != "freq") {
                let ratio = if let Some(sub) = k.strip_prefix("h1/") {
                    let n: u32 =
                        sub.parse().ok().filter(|&n| n >= 2).ok_or_else(|| {
                            usage(format!("'{k}': sub-harmonic order must be ≥ 2"))
                        })?;
                    1.0 / n as f64
                } else if let Some(sup) = k.strip_prefix('h') {
                    let n: u32 = sup.parse().ok().filter(|&n| n >= 1).ok_or_else(|| {
                        usage(format!("unknown key '{k}' (expected freq, hK, h1/K)"))
                    })?;
                    n as f64
                } else {
                    return Err(usage(format!(
                        "unknown key '{k}' (expected freq, hK, h1/K)"
                    )));
                };
                let (mag, phase) = match v.split_once('@') {
                    Some((m, p)) => (num(k, m)?, num(k, p)?.to_radians()),
                    None => (num(k, v)?, 0.0),
                };
                // Phase 0 is a cosine, as in `frf` and model files: F = mag·e^{iφ}.
                harmonics.push(Harmonic {
                    ratio,
                    amplitude: c64::new(mag * phase.cos(), mag * phase.sin()),
                });
            }
            if harmonics.is_empty() {
                harmonics.push(Harmonic {
                    ratio: 1.0,
                    amplitude: c64::new(default_amp, 0.0),
                });
            }
            Signal::MultiSine {
                fundamental_hz,
                harmonics,
            }
        }
        "sweep" => {
            allow(&kv, &["f0", "f1", "amp", "duration", "log"])?;
            let log = match kv.iter().find(|(k, _)| k == "log").map(|(_, v)| v.as_str()) {
                None | Some("false") => false,
                Some("true") => true,
                Some(other) => return Err(usage(format!("log={other}: expected true or false"))),
            };
            let kv2: Vec<(String, String)> =
                kv.iter().filter(|(k, _)| k != "log").cloned().collect();
            Signal::Sweep {
                amplitude: take(&kv2, "amp")?.unwrap_or(default_amp),
                f0_hz: take(&kv2, "f0")?.ok_or_else(|| usage("needs f0=HZ".into()))?,
                f1_hz: take(&kv2, "f1")?.ok_or_else(|| usage("needs f1=HZ".into()))?,
                duration: take(&kv2, "duration")?.unwrap_or(duration),
                logarithmic: log,
            }
        }
        "stepped" => {
            allow(&kv, &["f0", "f1", "steps", "dwell", "amp"])?;
            let need = |k: &str| -> Result<f64> {
                take(&kv, k)?.ok_or_else(|| usage(format!("needs {k}=…")))
            };
            let (f0, f1, dwell) = (need("f0")?, need("f1")?, need("dwell")?);
            let steps = need("steps")?;
            if !(steps >= 1.0 && steps.fract() == 0.0 && steps <= 1e6) {
                return Err(usage(format!(
                    "steps={steps}: give a whole number from 1 to 1e6"
                )));
            }
            if !(f0 > 0.0 && f1 > 0.0) {
                return Err(usage(format!(
                    "f0={f0}, f1={f1}: frequencies must be > 0 Hz"
                )));
            }
            if dwell <= 0.0 {
                return Err(usage(format!("dwell={dwell}: a dwell lasts more than 0 s")));
            }
            if f0.max(f1) >= 0.5 * rate {
                return Err(usage(format!(
                    "{} Hz is at or above the Nyquist frequency {} Hz of the {rate} Hz rate; \
                     give a rate above {} Hz",
                    f0.max(f1),
                    0.5 * rate,
                    2.0 * f0.max(f1)
                )));
            }
            let per = (dwell * rate).round();
            let total = per * steps;
            if !(per >= 1.0 && total <= MAX_STEPPED_SAMPLES as f64) {
                return Err(usage(format!(
                    "{steps} dwells of {dwell} s at {rate} Hz are {total} samples; give \
                     from 1 sample per dwell to {MAX_STEPPED_SAMPLES} in all"
                )));
            }
            let amplitude = take(&kv, "amp")?.unwrap_or(default_amp);
            let n = steps as usize;
            let mut values = Vec::with_capacity(total as usize);
            let mut phase = 0.0f64;
            for i in 0..n {
                let f = if n == 1 {
                    f0
                } else {
                    f0 + (f1 - f0) * i as f64 / (n - 1) as f64
                };
                let dphi = 2.0 * std::f64::consts::PI * f / rate;
                for _ in 0..per as usize {
                    values.push(amplitude * phase.sin());
                    phase = (phase + dphi) % (2.0 * std::f64::consts::PI);
                }
            }
            Signal::Sampled {
                rate_hz: rate,
                values,
            }
        }
        "file" => {
            let (path, opts) = match rest.rsplit_once(",rate=") {
                Some((p, r)) => (p, Some(num("rate", r)?)),
                None => (rest, None),
            };
            read_force_file(Path::new(path), opts.unwrap_or(rate))?
        }
        other => {
            return Err(usage(format!(
                "unknown kind '{other}' (expected none, sine, multisine, sweep, stepped or file)"
            )));
        }
    };
    signal
        .validate(&format!("excitation '{spec}'"))
        .map_err(|e| Error::Usage(e.to_string()))?;
    let defaulted = match kind {
        "sine" | "sweep" | "stepped" => !kv.iter().any(|(k, _)| k == "amp"),
        "multisine" => !kv.iter().any(|(k, _)| k != "freq"),
        _ => false,
    };
    Ok((signal, defaulted))
}

/// A signal in the spec grammar of [`parse_excitation`] (frequencies in Hz, phases in
/// degrees), for reports of signals built in code.
pub fn describe_signal(signal: &Signal) -> String {
    match signal {
        Signal::Zero => "none".into(),
        Signal::Sine {
            amplitude,
            freq_hz,
            phase,
        } => format!(
            "sine:freq={freq_hz},amp={amplitude},phase={}",
            phase.to_degrees()
        ),
        Signal::MultiSine {
            fundamental_hz,
            harmonics,
        } => {
            let mut t = format!("multisine:freq={fundamental_hz}");
            for h in harmonics {
                // F = mag·e^{iφ} for a cosine of phase φ.
                let z = h.amplitude;
                let key = if h.ratio >= 1.0 {
                    format!("h{}", h.ratio.round())
                } else {
                    format!("h1/{}", (1.0 / h.ratio).round())
                };
                let _ = write!(t, ",{key}={}@{}", z.norm(), z.arg().to_degrees());
            }
            t
        }
        Signal::Sweep {
            amplitude,
            f0_hz,
            f1_hz,
            duration,
            logarithmic,
        } => format!(
            "sweep:f0={f0_hz},f1={f1_hz},amp={amplitude},duration={duration}{}",
            if *logarithmic { ",log=true" } else { "" }
        ),
        Signal::Sampled { rate_hz, values } => {
            format!("samples:{} at {rate_hz} Hz", values.len())
        }
    }
}

/// Reads one force (N) per line; blank lines and `#` comments are skipped.
fn read_force_file(path: &Path, rate_hz: f64) -> Result<Signal> {
    let text = crate::formats::files::read_text(path)?;
    let mut values = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let l = line.split('#').next().unwrap_or("").trim();
        if l.is_empty() {
            continue;
        }
        let v: f64 = l
            .parse()
            .ok()
            .filter(|x: &f64| x.is_finite())
            .ok_or_else(|| {
                Error::Usage(format!(
                    "{}:{}: {} is not a finite force value (one number in N per line)",
                    path.display(),
                    i + 1,
                    crate::formats::files::quoted(l)
                ))
            })?;
        values.push(v);
    }
    if values.is_empty() {
        return Err(Error::Usage(format!("{}: no force values", path.display())));
    }
    Ok(Signal::Sampled { rate_hz, values })
}

/// Refuses a force with content above the Nyquist frequency of the sample rate `rate` (Hz):
/// the step (FOH, ZOH, LSOH) or the output samples (the others) would alias it.
pub fn nyquist_check(label: &str, signal: &Signal, rate: f64) -> Result<()> {
    if let Some(f) = signal.max_frequency_hz()
        && f > 0.5 * rate
    {
        return Err(Error::Usage(format!(
            "excitation '{label}': {} Hz is above the Nyquist frequency {} Hz of the {} Hz \
             rate, which would alias it; give a rate above {} Hz",
            short(f),
            short(0.5 * rate),
            short(rate),
            short(2.0 * f)
        )));
    }
    Ok(())
}

/// `v` in plain notation in the usual range, in scientific notation beyond it.
fn short(v: f64) -> String {
    if v == 0.0 || (1e-3..1e7).contains(&v.abs()) {
        format!("{v}")
    } else {
        format!("{v:e}")
    }
}

#[cfg(test)]
mod tests {
    /// A stepped sine: its dwells at evenly spaced frequencies, `steps · dwell · rate`
    /// samples, the phase continuous across the switches (each sample follows the last by
    /// the phase step of the frequency of its dwell), and out-of-range values refused.
    #[test]
    fn stepped_sines_switch_with_a_continuous_phase() {
        let rate = 1000.0;
        let Signal::Sampled { rate_hz, values } = parse_excitation(
            "stepped:f0=10,f1=30,steps=3,dwell=0.5,amp=2",
            1.0,
            1.0,
            rate,
        )
        .unwrap() else {
            panic!("not sampled");
        };
        assert_eq!(rate_hz, rate);
        assert_eq!(values.len(), 1500);
        let mut phase = 0.0f64;
        for (i, v) in values.iter().enumerate() {
            assert!((v - 2.0 * phase.sin()).abs() < 1e-9, "sample {i}");
            let f = [10.0, 20.0, 30.0][i / 500];
            phase += 2.0 * std::f64::consts::PI * f / rate;
        }
        for bad in [
            "stepped:f0=10,f1=30,steps=0,dwell=1",
            "stepped:f0=10,f1=30,steps=2.5,dwell=1",
            "stepped:f0=10,f1=600,steps=2,dwell=1",
            "stepped:f0=0,f1=30,steps=2,dwell=1",
            "stepped:f0=10,f1=30,steps=2,dwell=-1",
            "stepped:f0=10,f1=30,steps=2",
            "stepped:f0=10,f1=30,steps=2,dwell=1,log=true",
            "stepped:f0=10,f1=30,steps=1000000,dwell=1000",
        ] {
            assert!(parse_excitation(bad, 1.0, 1.0, rate).is_err(), "{bad}");
        }
    }

    use super::*;

    #[test]
    fn excitation_specs() {
        let s = parse_excitation("sine:freq=25,amp=3", 1.0, 1.0, 1000.0).unwrap();
        assert_eq!(
            s,
            Signal::Sine {
                amplitude: 3.0,
                freq_hz: 25.0,
                phase: 0.0
            }
        );
        let s = parse_excitation("sine:freq=25", 0.2, 1.0, 1000.0).unwrap();
        assert!(matches!(s, Signal::Sine { amplitude, .. } if amplitude == 0.2));
        let s =
            parse_excitation("multisine:freq=10,h1=2,h3=0.1@90,h1/3=0.05", 1.0, 1.0, 1e3).unwrap();
        let Signal::MultiSine { harmonics, .. } = s else {
            panic!()
        };
        assert_eq!(harmonics.len(), 3);
        assert!((harmonics[2].ratio - 1.0 / 3.0).abs() < 1e-15);
        // Cosines, as in `frf` and model files: h1=2 is 2 cos Ωt, h3=0.1@90 is
        // 0.1 cos(3Ωt + 90°) = Re{0.1 i e^{3iΩt}}.
        assert_eq!(harmonics[0].amplitude, c64::new(2.0, 0.0));
        assert!((harmonics[1].amplitude - c64::new(0.0, 0.1)).norm() < 1e-16);
        let s = parse_excitation("sweep:f0=5,f1=50,log=true", 1.0, 2.0, 1e3).unwrap();
        assert!(matches!(s, Signal::Sweep { duration, logarithmic: true, .. } if duration == 2.0));
        for bad in [
            "sine",
            "sine:freq=x",
            "sine:frq=3",
            "chirp:f=1",
            "multisine:freq=1,h1/1=2",
            "sweep:f0=1",
            "sweep:f0=1,f1=2,log=maybe",
            "sine:freq=-3",
        ] {
            let e = parse_excitation(bad, 1.0, 1.0, 1e3).unwrap_err();
            assert!(matches!(e, Error::Usage(_)), "{bad}: {e}");
            assert!(e.to_string().contains(bad), "{bad}: {e}");
        }
    }
}
