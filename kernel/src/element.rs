//! The nonlinear element library (thesis §2.2: eqs. 5–7, and friction).
//!
//! An element acts on a scalar coordinate `u = Σ w_i q_i` of the structure (one DOF relative
//! to ground, the relative motion `q_a − q_b` of two DOFs, or any weighted direction, which is
//! how an element is carried into reduced coordinates) and applies the force `g(u, u̇)`
//! along the same direction: its contribution to `f_NL` in thesis eq. (4)
//! `M q̈ + V q̇ + K q + f_NL(q, q̇) = f(t)` is `w g(u, u̇)`. A positive `g` resists positive `u`.
//!
//! Each law gives its force, the derivatives `∂g/∂u`, `∂g/∂u̇` (for Newton) and `∂g/∂p` for
//! each named parameter `p` (for calibration). Units: `u` in m, `u̇` in m/s, `g` in N.
//!
//! One law couples several coordinates: [`Law::CoupledPolynomial`] acts on `m` coordinates
//! `u_j = c_j(q)` at once and applies `g_i(u_1, …, u_m)` along each (`f_NL = Σ_i c_iᵀ g_i`),
//! the geometric nonlinearity of a structure in a few modal or physical coordinates (terms such
//! as `u_1² u_2`). Its element has `m` couplings ([`NonlinearElement::coupled`]); it is
//! evaluated with [`Law::eval_coupled`], not [`Law::eval`].

use crate::error::{Error, Result};
use crate::iwan::{self, IwanGrid};

/// Force and state derivatives of a law at one point.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct LawEval {
    /// Force `g(u, u̇)` (N).
    pub force: f64,
    /// `∂g/∂u` (N/m).
    pub df_du: f64,
    /// `∂g/∂u̇` (N s/m).
    pub df_dv: f64,
}

/// One term `coef · x^power` of a polynomial law.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PolyTerm {
    /// Integer power, at least 1.
    pub power: u32,
    /// Coefficient (N/m^power for stiffness, N (s/m)^power for damping).
    pub coef: f64,
}

/// One term `coef · Π_j u_j^{powers[j]}` of the force `g_{output}` of a
/// [`Law::CoupledPolynomial`].
#[derive(Debug, Clone, PartialEq)]
pub struct MonomialTerm {
    /// The force the term adds to (0-based coordinate index).
    pub output: usize,
    /// Power of each coordinate (one per coordinate; total degree 1 to 15).
    pub powers: Vec<u32>,
    /// Coefficient (N/m^d, `d` the total degree).
    pub coef: f64,
}

impl MonomialTerm {
    /// The term `coef · Π_j u_j^{powers[j]}` of force `output` (0-based).
    pub fn new(output: usize, powers: &[u32], coef: f64) -> Self {
        Self {
            output,
            powers: powers.to_vec(),
            coef,
        }
    }

    /// Total degree `Σ_j powers[j]` (saturating: a file may give any powers).
    pub fn degree(&self) -> u32 {
        self.powers.iter().fold(0u32, |a, &p| a.saturating_add(p))
    }

    /// The parameter name `k<i>_<p_1>_…_<p_m>` (output `i` 1-based): `k1_2_1` is the
    /// coefficient of `u_1² u_2` in `g_1`.
    pub fn name(&self) -> String {
        let mut s = format!("k{}", self.output + 1);
        for p in &self.powers {
            s.push('_');
            s.push_str(&p.to_string());
        }
        s
    }

    /// Parses a parameter name `k<i>_<p_1>_…_<p_m>` into `(output, powers)`; `None` when the
    /// name is not of that form.
    pub fn parse_name(name: &str) -> Option<(usize, Vec<u32>)> {
        let mut parts = name.strip_prefix('k')?.split('_');
        let output: usize = parts.next()?.parse().ok()?;
        let powers = parts
            .map(|p| p.parse::<u32>().ok())
            .collect::<Option<Vec<_>>>()?;
        if output == 0 || powers.is_empty() {
            return None;
        }
        Some((output - 1, powers))
    }

    /// `Π_j u_j^{powers[j]}`.
    #[inline]
    pub fn monomial(&self, u: &[f64]) -> f64 {
        self.powers
            .iter()
            .zip(u)
            .fold(1.0, |a, (&p, &x)| a * x.powi(p as i32))
    }
}

/// A force law `g(u, u̇; p)` with named parameters `p`.
#[derive(Debug, Clone, PartialEq)]
pub enum Law {
    /// Cubic spring `g = k3 u³` (thesis eq. 5); `k3` in N/m³, negative for softening.
    Cubic {
        /// Cubic stiffness (N/m³).
        k3: f64,
    },
    /// Polynomial stiffness and damping `g = Σ k_n uⁿ + Σ c_n u̇ⁿ` with integer powers `n ≥ 1`.
    /// Parameters are named `k<n>` and `c<n>`. Even powers are asymmetric and create even
    /// harmonics (e.g. the hardening–softening beam's `k2 u² + k3 u³`).
    Polynomial {
        /// Stiffness terms `k_n uⁿ`.
        stiffness: Vec<PolyTerm>,
        /// Damping terms `c_n u̇ⁿ`.
        damping: Vec<PolyTerm>,
    },
    /// Clearance, thesis eq. (6): `g = k1 (u − e1)^r` for `u > e1`, `g = −k2 (−u − e2)^s` for
    /// `u < −e2`, zero in the gap `−e2 ≤ u ≤ e1`. The negative side is written with
    /// `|u + e2|` so that it restores for any real exponent (eq. 6 as printed equals it for odd
    /// integer `s`). A one-sided bump stop is `k2 = 0`. Gaps in m, exponents ≥ 1.
    Clearance {
        /// Contact stiffness on the positive side (N/m^r).
        k1: f64,
        /// Contact stiffness on the negative side (N/m^s).
        k2: f64,
        /// Positive-side gap (m).
        e1: f64,
        /// Negative-side gap (m).
        e2: f64,
        /// Positive-side exponent (≥ 1).
        r: f64,
        /// Negative-side exponent (≥ 1).
        s: f64,
    },
    /// Quadratic damping `g = c2 u̇ |u̇|`, thesis eq. (7); `c2` in N s²/m².
    QuadraticDamping {
        /// Quadratic damping coefficient (N s²/m²).
        c2: f64,
    },
    /// Coulomb friction regularised by `tanh`: `g = fc tanh(u̇ / v_reg)`.
    Coulomb {
        /// Friction (slip) force (N).
        fc: f64,
        /// Regularisation velocity (m/s): below it the law is a steep viscous damper.
        v_reg: f64,
    },
    /// Elastic dry friction (Jenkins element): a spring `kt` in series with a slider that slips
    /// at force `fs`. History state: the slider position `z` (m); `g = kt (u − z)` while
    /// `|kt (u − z)| ≤ fs` (stick), `g = ±fs` in slip.
    Jenkins {
        /// Tangential (stick) stiffness (N/m).
        kt: f64,
        /// Slip force (N).
        fs: f64,
    },
    /// Power-law spring `g = k |u|^p sign(u)`: odd in `u` for any real `p ≥ 1`, so that
    /// `p = 2` gives the `u|u|` stiffness whose softening or hardening is linear in the
    /// amplitude. `k` in N/m^p (negative softens), `p` dimensionless.
    PowerSpring {
        /// Coefficient (N/m^p).
        k: f64,
        /// Exponent (≥ 1).
        p: f64,
    },
    /// Power-law damper `g = c |u̇|^p sign(u̇)`: `p = 1` viscous, `p = 2` the quadratic damper,
    /// other `p ≥ 1` the damping of joints whose loss grows as a power of the amplitude
    /// (dissipation per cycle ∝ amplitude^(p+1)). `c` in N (s/m)^p.
    PowerDamper {
        /// Coefficient (N (s/m)^p, ≥ 0).
        c: f64,
        /// Exponent (≥ 1).
        p: f64,
    },
    /// Segalman's four-parameter Iwan joint (microslip of a frictional interface up to
    /// macroslip at `fs`), discretised into parallel Jenkins sliders ([`crate::iwan`], which
    /// states the discretisation). History state: each slider's position (m). Build it with
    /// [`Law::iwan`] (the grid is not written by hand).
    Iwan {
        /// Macroslip force `F_S` (N).
        fs: f64,
        /// Stiffness of the stuck joint `K_T` (N/m).
        kt: f64,
        /// Exponent `χ` of the slider population (−1 < χ ≤ 1; dissipation ∝ amplitude^(χ+3)).
        chi: f64,
        /// Share `β ≥ 0` of the population's Dirac at macroslip.
        beta: f64,
        /// The sliders, kept consistent with the four parameters.
        grid: IwanGrid,
    },
    /// A polynomial stiffness coupling `inputs` coordinates: `g_i(u) = Σ_k a_k Π_j u_j^{p_kj}`
    /// over the terms of output `i` (NLvib's polynomial stiffness nonlinearity: `f_NL = Eᵀ z`,
    /// `z_k = Π_j q_j^{p_kj}`). Parameters are the coefficients, named `k<i>_<p_1>_…_<p_m>`
    /// ([`MonomialTerm::name`]). Conservative when `g` is a gradient, as in a geometric
    /// nonlinearity; any polynomial is accepted.
    CoupledPolynomial {
        /// Number of coordinates `m` (at least 2).
        inputs: usize,
        /// The terms, in the order given.
        terms: Vec<MonomialTerm>,
    },
}

impl Law {
    /// The law's type name as used in model files.
    pub fn kind(&self) -> &'static str {
        match self {
            Law::Cubic { .. } => "cubic",
            Law::Polynomial { .. } => "polynomial",
            Law::Clearance { .. } => "clearance",
            Law::QuadraticDamping { .. } => "quadratic_damping",
            Law::Coulomb { .. } => "coulomb",
            Law::Jenkins { .. } => "jenkins",
            Law::PowerSpring { .. } => "power_spring",
            Law::PowerDamper { .. } => "power_damper",
            Law::Iwan { .. } => "iwan",
            Law::CoupledPolynomial { .. } => "coupled_polynomial",
        }
    }

    /// Segalman's Iwan joint (`fs` N, `kt` N/m, `chi`, `beta`) on the default grid
    /// ([`iwan::DEFAULT_SLIDERS`] sliders over [`iwan::DEFAULT_DECADES`] decades).
    pub fn iwan(fs: f64, kt: f64, chi: f64, beta: f64) -> Result<Self> {
        Self::iwan_with(
            fs,
            kt,
            chi,
            beta,
            iwan::DEFAULT_SLIDERS,
            iwan::DEFAULT_DECADES,
        )
    }

    /// [`Law::iwan`] on `sliders` sliders whose slip displacements span `decades` decades
    /// below macroslip. Checks every value.
    pub fn iwan_with(
        fs: f64,
        kt: f64,
        chi: f64,
        beta: f64,
        sliders: usize,
        decades: f64,
    ) -> Result<Self> {
        let law = Law::Iwan {
            fs,
            kt,
            chi,
            beta,
            grid: IwanGrid::new("iwan", sliders, decades, [fs, kt, chi, beta])?,
        };
        law.validate("iwan")?;
        Ok(law)
    }

    /// Number of parallel Jenkins sliders the law is made of: 1 for Jenkins, the grid's
    /// sliders and the Dirac's for Iwan, 0 for the other laws. Slider `s` carries history
    /// state `s`.
    pub fn n_sliders(&self) -> usize {
        match self {
            Law::Jenkins { .. } => 1,
            Law::Iwan { grid, .. } => grid.sliders() + 1,
            _ => 0,
        }
    }

    /// Stiffness (N/m) and slip force (N) of slider `s < n_sliders()`.
    ///
    /// # Panics
    /// When the law has no slider `s` (a programming error).
    #[inline]
    pub fn slider(&self, s: usize) -> (f64, f64) {
        match self {
            Law::Jenkins { kt, fs } if s == 0 => (*kt, *fs),
            Law::Iwan { grid, .. } => grid.slider(s),
            _ => panic!("slider {s} of a {} law", self.kind()),
        }
    }

    /// `∂k_s/∂p_i` into `dk` and `∂f_s/∂p_i` into `df` (each [`Law::n_params`] long) for
    /// slider `s`: how the slider's stiffness and slip force move with the law's parameters.
    ///
    /// # Panics
    /// When the law has no slider `s` or the buffers have the wrong length.
    pub fn slider_dparams(&self, s: usize, dk: &mut [f64], df: &mut [f64]) {
        match self {
            Law::Jenkins { .. } if s == 0 => {
                dk.copy_from_slice(&[1.0, 0.0]);
                df.copy_from_slice(&[0.0, 1.0]);
            }
            Law::Iwan {
                fs,
                kt,
                chi,
                beta,
                grid,
            } => grid.dslider(s, [*fs, *kt, *chi, *beta], dk, df),
            _ => panic!("slider {s} of a {} law", self.kind()),
        }
    }

    /// Number of coordinates the law acts on: `inputs` for [`Law::CoupledPolynomial`], 1 for
    /// every other law.
    pub fn arity(&self) -> usize {
        match self {
            Law::CoupledPolynomial { inputs, .. } => *inputs,
            _ => 1,
        }
    }

    /// A one-sided bump stop: contact stiffness `k` beyond gap `gap`, linear (`r = 1`).
    pub fn bump_stop(k: f64, gap: f64) -> Self {
        Law::Clearance {
            k1: k,
            k2: 0.0,
            e1: gap,
            e2: 0.0,
            r: 1.0,
            s: 1.0,
        }
    }

    /// Parses a law written as one line, `"cubic k3=1.7e15"` or `"clearance, k1=5e5,
    /// e1=1e-3"`: the law type, then `key=value` words (spaces or commas between) with the
    /// model file's keys, handed to [`Law::from_named`]. The line form of the C ABI and the
    /// Python package; `element` names the element in errors.
    pub fn from_text(element: &str, text: &str) -> Result<Self> {
        let bad = |reason: String| Error::invalid(format!("law of element '{element}'"), reason);
        let mut words = text
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|w| !w.is_empty());
        let kind = words
            .next()
            .ok_or_else(|| bad("the law is empty; write e.g. \"cubic k3=1e9\"".into()))?;
        let mut pairs = Vec::new();
        for w in words {
            let (k, v) = w
                .split_once('=')
                .ok_or_else(|| bad(format!("'{w}' is not key=value (e.g. k3=1e9)")))?;
            let v: f64 = v
                .trim()
                .parse()
                .map_err(|_| bad(format!("the value of '{k}' ('{v}') is not a number")))?;
            pairs.push((k.trim(), v));
        }
        Law::from_named(element, kind, &pairs)
    }

    /// The law of type `kind` (the model-file names: `cubic`, `polynomial`, `clearance`,
    /// `bump_stop`, `quadratic_damping`, `coulomb`, `jenkins`) from `name = value` pairs with
    /// the model file's keys and defaults (`clearance`: `k2 = e2 = 0`, `r = s = 1`;
    /// `coulomb`: `v_reg = 1e-3` m/s; `polynomial`: any `k<n>`, `c<n>` with `n ≥ 1`).
    /// `element` names the element in errors. An unknown or repeated key, a missing required
    /// one or an unknown type is an error that lists what is accepted; values are checked by
    /// [`NonlinearElement::new`].
    pub fn from_named(element: &str, kind: &str, pairs: &[(&str, f64)]) -> Result<Self> {
        let keys: &[&str] = match kind {
            "cubic" => &["k3"],
            "quadratic_damping" => &["c2"],
            "coulomb" => &["fc", "v_reg"],
            "jenkins" => &["kt", "fs"],
            "power_spring" => &["k", "p"],
            "power_damper" => &["c", "p"],
            "iwan" => &["fs", "kt", "chi", "beta", "sliders", "decades"],
            "bump_stop" => &["k", "gap"],
            "clearance" => &["k1", "k2", "e1", "e2", "r", "s"],
            "polynomial" => &[],
            "coupled_polynomial" => return Self::coupled_from_named(element, pairs),
            other => {
                return Err(Error::invalid(
                    format!("element '{element}'"),
                    format!("unknown type '{other}'; use {}", Self::KINDS),
                ));
            }
        };
        for (i, (k, _)) in pairs.iter().enumerate() {
            if pairs[..i].iter().any(|(p, _)| p == k) {
                return Err(Error::invalid(
                    format!("element '{element}'"),
                    format!("parameter '{k}' is given twice"),
                ));
            }
            let poly = kind == "polynomial"
                && (k.starts_with('k') || k.starts_with('c'))
                && k[1..].parse::<u32>().is_ok_and(|n| n >= 1);
            if !poly && !keys.contains(k) {
                let accepted = if kind == "polynomial" {
                    "k<n> and c<n> with an integer power n >= 1".to_string()
                } else {
                    keys.join(", ")
                };
                return Err(Error::invalid(
                    format!("element '{element}'"),
                    format!("a {kind} law has no parameter '{k}'; it takes {accepted}"),
                ));
            }
        }
        let get = |k: &str| pairs.iter().find(|(p, _)| *p == k).map(|&(_, v)| v);
        let req = |k: &str| {
            get(k).ok_or_else(|| {
                Error::invalid(
                    format!("element '{element}'"),
                    format!("a {kind} law needs '{k}' (it takes {})", keys.join(", ")),
                )
            })
        };
        Ok(match kind {
            "cubic" => Law::Cubic { k3: req("k3")? },
            "quadratic_damping" => Law::QuadraticDamping { c2: req("c2")? },
            "coulomb" => Law::Coulomb {
                fc: req("fc")?,
                v_reg: get("v_reg").unwrap_or(1e-3),
            },
            "jenkins" => Law::Jenkins {
                kt: req("kt")?,
                fs: req("fs")?,
            },
            "power_spring" => Law::PowerSpring {
                k: req("k")?,
                p: req("p")?,
            },
            "power_damper" => Law::PowerDamper {
                c: req("c")?,
                p: req("p")?,
            },
            "iwan" => {
                let sliders = match get("sliders") {
                    None => iwan::DEFAULT_SLIDERS,
                    Some(v) if v.fract() == 0.0 && (1.0..=1000.0).contains(&v) => v as usize,
                    Some(v) => {
                        return Err(Error::InvalidParameter {
                            name: format!("{element}.sliders"),
                            value: v,
                            reason: "the number of sliders must be an integer from 1 to 1000"
                                .into(),
                        });
                    }
                };
                let (fs, kt, chi, beta) = (req("fs")?, req("kt")?, req("chi")?, req("beta")?);
                let decades = get("decades").unwrap_or(iwan::DEFAULT_DECADES);
                Law::Iwan {
                    fs,
                    kt,
                    chi,
                    beta,
                    grid: IwanGrid::new(element, sliders, decades, [fs, kt, chi, beta])?,
                }
            }
            "bump_stop" => Law::bump_stop(req("k")?, req("gap")?),
            "clearance" => Law::Clearance {
                k1: req("k1")?,
                k2: get("k2").unwrap_or(0.0),
                e1: req("e1")?,
                e2: get("e2").unwrap_or(0.0),
                r: get("r").unwrap_or(1.0),
                s: get("s").unwrap_or(1.0),
            },
            _ => {
                let term = |prefix: char| {
                    let mut t: Vec<PolyTerm> = pairs
                        .iter()
                        .filter(|(k, _)| k.starts_with(prefix))
                        .map(|&(k, coef)| PolyTerm {
                            power: k[1..].parse().unwrap_or(1),
                            coef,
                        })
                        .collect();
                    t.sort_by_key(|p| p.power);
                    t
                };
                Law::Polynomial {
                    stiffness: term('k'),
                    damping: term('c'),
                }
            }
        })
    }

    /// The law types of model files, for messages.
    pub const KINDS: &'static str = "cubic, polynomial, clearance, bump_stop, quadratic_damping, \
         coulomb, jenkins, iwan, power_spring, power_damper or coupled_polynomial";

    /// A [`Law::CoupledPolynomial`] from coefficients named `k<i>_<p_1>_…_<p_m>`; the number of
    /// powers in the names sets `m` (all names must agree).
    fn coupled_from_named(element: &str, pairs: &[(&str, f64)]) -> Result<Self> {
        let err = |m: String| Error::invalid(format!("element '{element}'"), m);
        if pairs.is_empty() {
            return Err(err(
                "a coupled_polynomial law needs at least one coefficient k<i>_<p1>_..._<pm> \
                 (e.g. k1_2_1 for u1^2 u2 in force 1)"
                    .into(),
            ));
        }
        let mut terms: Vec<MonomialTerm> = Vec::with_capacity(pairs.len());
        for (k, v) in pairs {
            let (output, powers) = MonomialTerm::parse_name(k).ok_or_else(|| {
                err(format!(
                    "a coupled_polynomial law has no parameter '{k}'; its coefficients are named \
                     k<i>_<p1>_..._<pm> (e.g. k1_2_1 for u1^2 u2 in force 1)"
                ))
            })?;
            terms.push(MonomialTerm {
                output,
                powers,
                coef: *v,
            });
        }
        let inputs = terms.first().map_or(0, |t| t.powers.len());
        if let Some(t) = terms.iter().find(|t| t.powers.len() != inputs) {
            return Err(err(format!(
                "'{}' has {} powers where '{}' has {inputs}: every term needs one power per \
                 coordinate",
                t.name(),
                t.powers.len(),
                terms[0].name()
            )));
        }
        Ok(Law::CoupledPolynomial { inputs, terms })
    }

    /// Number of named parameters.
    pub fn n_params(&self) -> usize {
        match self {
            Law::Cubic { .. } | Law::QuadraticDamping { .. } => 1,
            Law::Polynomial { stiffness, damping } => stiffness.len() + damping.len(),
            Law::Clearance { .. } => 6,
            Law::Coulomb { .. }
            | Law::Jenkins { .. }
            | Law::PowerSpring { .. }
            | Law::PowerDamper { .. } => 2,
            Law::Iwan { .. } => 4,
            Law::CoupledPolynomial { terms, .. } => terms.len(),
        }
    }

    /// Name of parameter `i` (`k3`, `e1`, …); `i < n_params()`.
    pub fn param_name(&self, i: usize) -> String {
        match self {
            Law::Cubic { .. } => "k3".into(),
            Law::QuadraticDamping { .. } => "c2".into(),
            Law::Polynomial { stiffness, damping } => {
                if i < stiffness.len() {
                    format!("k{}", stiffness[i].power)
                } else {
                    format!("c{}", damping[i - stiffness.len()].power)
                }
            }
            Law::Clearance { .. } => ["k1", "k2", "e1", "e2", "r", "s"][i].into(),
            Law::Coulomb { .. } => ["fc", "v_reg"][i].into(),
            Law::Jenkins { .. } => ["kt", "fs"][i].into(),
            Law::PowerSpring { .. } => ["k", "p"][i].into(),
            Law::PowerDamper { .. } => ["c", "p"][i].into(),
            Law::Iwan { .. } => ["fs", "kt", "chi", "beta"][i].into(),
            Law::CoupledPolynomial { terms, .. } => terms[i].name(),
        }
    }

    /// SI unit of parameter `i`, for reports (`N/m^3`, `m`, `-`).
    pub fn param_unit(&self, i: usize) -> String {
        match self {
            Law::Cubic { .. } => "N/m^3".into(),
            Law::QuadraticDamping { .. } => "N s^2/m^2".into(),
            Law::Polynomial { stiffness, damping } => {
                if i < stiffness.len() {
                    format!("N/m^{}", stiffness[i].power)
                } else {
                    format!("N s^{0}/m^{0}", damping[i - stiffness.len()].power)
                }
            }
            Law::Clearance { .. } => ["N/m^r", "N/m^s", "m", "m", "-", "-"][i].into(),
            Law::Coulomb { .. } => ["N", "m/s"][i].into(),
            Law::Jenkins { .. } => ["N/m", "N"][i].into(),
            Law::PowerSpring { .. } => ["N/m^p", "-"][i].into(),
            Law::PowerDamper { .. } => ["N (s/m)^p", "-"][i].into(),
            Law::Iwan { .. } => ["N", "N/m", "-", "-"][i].into(),
            Law::CoupledPolynomial { terms, .. } => format!("N/m^{}", terms[i].degree()),
        }
    }

    /// Value of parameter `i`.
    pub fn param(&self, i: usize) -> f64 {
        match self {
            Law::Cubic { k3 } => *k3,
            Law::QuadraticDamping { c2 } => *c2,
            Law::Polynomial { stiffness, damping } => {
                if i < stiffness.len() {
                    stiffness[i].coef
                } else {
                    damping[i - stiffness.len()].coef
                }
            }
            Law::Clearance {
                k1,
                k2,
                e1,
                e2,
                r,
                s,
            } => [*k1, *k2, *e1, *e2, *r, *s][i],
            Law::Coulomb { fc, v_reg } => [*fc, *v_reg][i],
            Law::Jenkins { kt, fs } => [*kt, *fs][i],
            Law::PowerSpring { k, p } => [*k, *p][i],
            Law::PowerDamper { c, p } => [*c, *p][i],
            Law::Iwan {
                fs, kt, chi, beta, ..
            } => [*fs, *kt, *chi, *beta][i],
            Law::CoupledPolynomial { terms, .. } => terms[i].coef,
        }
    }

    fn param_mut(&mut self, i: usize) -> &mut f64 {
        match self {
            Law::Cubic { k3 } => k3,
            Law::QuadraticDamping { c2 } => c2,
            Law::Polynomial { stiffness, damping } => {
                let ns = stiffness.len();
                if i < ns {
                    &mut stiffness[i].coef
                } else {
                    &mut damping[i - ns].coef
                }
            }
            Law::Clearance {
                k1,
                k2,
                e1,
                e2,
                r,
                s,
            } => match i {
                0 => k1,
                1 => k2,
                2 => e1,
                3 => e2,
                4 => r,
                _ => s,
            },
            Law::Coulomb { fc, v_reg } => {
                if i == 0 {
                    fc
                } else {
                    v_reg
                }
            }
            Law::Jenkins { kt, fs } => {
                if i == 0 {
                    kt
                } else {
                    fs
                }
            }
            Law::PowerSpring { k: a, p } | Law::PowerDamper { c: a, p } => {
                if i == 0 {
                    a
                } else {
                    p
                }
            }
            Law::Iwan {
                fs, kt, chi, beta, ..
            } => match i {
                0 => fs,
                1 => kt,
                2 => chi,
                _ => beta,
            },
            Law::CoupledPolynomial { terms, .. } => &mut terms[i].coef,
        }
    }

    /// Sets parameter `i` to `value`, keeping the old value if the law would become invalid.
    /// `element` names the element in the error.
    pub fn set_param(&mut self, element: &str, i: usize, value: f64) -> Result<()> {
        if i >= self.n_params() {
            return Err(Error::invalid(
                format!("parameter index {i} of element '{element}'"),
                format!("the {} law has {} parameters", self.kind(), self.n_params()),
            ));
        }
        let old = self.param(i);
        *self.param_mut(i) = value;
        if let Err(e) = self.validate(element) {
            *self.param_mut(i) = old;
            return Err(e);
        }
        if let Law::Iwan {
            fs,
            kt,
            chi,
            beta,
            grid,
        } = self
        {
            grid.refresh(*fs, *kt, *chi, *beta);
        }
        Ok(())
    }

    /// Checks every parameter for finiteness and range; `element` names the element in errors.
    pub fn validate(&self, element: &str) -> Result<()> {
        let name = |p: &str| format!("{element}.{p}");
        for i in 0..self.n_params() {
            let v = self.param(i);
            if !v.is_finite() {
                return Err(Error::InvalidParameter {
                    name: name(&self.param_name(i)),
                    value: v,
                    reason: "must be finite".into(),
                });
            }
        }
        let nonneg = |p: &str, v: f64, what: &str| {
            if v < 0.0 {
                Err(Error::InvalidParameter {
                    name: name(p),
                    value: v,
                    reason: format!("{what} must be >= 0"),
                })
            } else {
                Ok(())
            }
        };
        match self {
            Law::Cubic { .. } => Ok(()),
            Law::QuadraticDamping { c2 } => nonneg("c2", *c2, "a damping coefficient"),
            Law::Polynomial { stiffness, damping } => {
                if stiffness.is_empty() && damping.is_empty() {
                    return Err(Error::invalid(
                        format!("element '{element}'"),
                        "a polynomial law needs at least one stiffness or damping term",
                    ));
                }
                for (terms, prefix) in [(stiffness, 'k'), (damping, 'c')] {
                    for (a, t) in terms.iter().enumerate() {
                        if t.power == 0 || t.power > 15 {
                            return Err(Error::InvalidParameter {
                                name: name(&format!("{prefix}{}", t.power)),
                                value: t.power as f64,
                                reason: "powers must be integers from 1 to 15".into(),
                            });
                        }
                        if terms[..a].iter().any(|o| o.power == t.power) {
                            return Err(Error::DuplicateName {
                                what: "polynomial term".into(),
                                name: name(&format!("{prefix}{}", t.power)),
                            });
                        }
                    }
                }
                Ok(())
            }
            Law::Clearance {
                k1,
                k2,
                e1,
                e2,
                r,
                s,
            } => {
                nonneg("k1", *k1, "a contact stiffness")?;
                nonneg("k2", *k2, "a contact stiffness")?;
                for (p, v) in [("r", *r), ("s", *s)] {
                    if v < 1.0 {
                        return Err(Error::InvalidParameter {
                            name: name(p),
                            value: v,
                            reason: "a contact exponent must be >= 1 (smaller ones give an infinite stiffness at first contact)".into(),
                        });
                    }
                }
                if e1 + e2 < 0.0 {
                    return Err(Error::InvalidParameter {
                        name: name("e1"),
                        value: *e1,
                        reason: format!(
                            "the contact regions overlap: need e1 + e2 >= 0, e2 = {e2:e}"
                        ),
                    });
                }
                Ok(())
            }
            Law::Coulomb { fc, v_reg } => {
                nonneg("fc", *fc, "a friction force")?;
                if *v_reg <= 0.0 {
                    return Err(Error::InvalidParameter {
                        name: name("v_reg"),
                        value: *v_reg,
                        reason: "the regularisation velocity must be > 0".into(),
                    });
                }
                Ok(())
            }
            Law::Jenkins { kt, fs } => {
                if *kt <= 0.0 {
                    return Err(Error::InvalidParameter {
                        name: name("kt"),
                        value: *kt,
                        reason: "the stick stiffness must be > 0".into(),
                    });
                }
                nonneg("fs", *fs, "a slip force")
            }
            Law::PowerSpring { p, .. } | Law::PowerDamper { p, .. } => {
                if let Law::PowerDamper { c, .. } = self {
                    nonneg("c", *c, "a damping coefficient")?;
                }
                if !(1.0..=15.0).contains(p) {
                    return Err(Error::InvalidParameter {
                        name: name("p"),
                        value: *p,
                        reason: "the exponent must be from 1 to 15 (below 1 the tangent is \
                                 infinite at rest; use coulomb or iwan for friction)"
                            .into(),
                    });
                }
                Ok(())
            }
            Law::Iwan {
                fs,
                kt,
                chi,
                beta,
                grid,
            } => {
                iwan::check_grid(element, grid.sliders(), grid.decades())?;
                for (p, v, what) in [
                    ("fs", *fs, "the macroslip force"),
                    ("kt", *kt, "the joint stiffness"),
                ] {
                    if v <= 0.0 {
                        return Err(Error::InvalidParameter {
                            name: name(p),
                            value: v,
                            reason: format!("{what} must be > 0"),
                        });
                    }
                }
                if !(*chi > -1.0 && *chi <= 1.0) {
                    return Err(Error::InvalidParameter {
                        name: name("chi"),
                        value: *chi,
                        reason: "the exponent must be in (-1, 1] (lap joints: -1 < chi <= 0)"
                            .into(),
                    });
                }
                nonneg("beta", *beta, "the share of the macroslip Dirac")
            }
            Law::CoupledPolynomial { inputs, terms } => {
                if *inputs < 2 {
                    return Err(Error::invalid(
                        format!("element '{element}'"),
                        format!(
                            "a coupled_polynomial law needs at least 2 coordinates (has {inputs}); \
                             one coordinate is a polynomial law"
                        ),
                    ));
                }
                if terms.is_empty() {
                    return Err(Error::invalid(
                        format!("element '{element}'"),
                        "a coupled_polynomial law needs at least one term",
                    ));
                }
                for (a, t) in terms.iter().enumerate() {
                    if t.powers.len() != *inputs || t.output >= *inputs {
                        return Err(Error::invalid(
                            format!("element '{element}', term {}", t.name()),
                            format!(
                                "needs {inputs} powers and a force index from 1 to {inputs} \
                                 (one per coordinate)"
                            ),
                        ));
                    }
                    let d = t.degree();
                    if d == 0 || d > 15 {
                        return Err(Error::InvalidParameter {
                            name: name(&t.name()),
                            value: f64::from(d),
                            reason: "the total degree of a term must be from 1 to 15".into(),
                        });
                    }
                    if terms[..a]
                        .iter()
                        .any(|o| o.output == t.output && o.powers == t.powers)
                    {
                        return Err(Error::DuplicateName {
                            what: "polynomial term".into(),
                            name: name(&t.name()),
                        });
                    }
                }
                Ok(())
            }
        }
    }

    /// Number of history variables the law carries (1 for Jenkins: the slider position).
    pub fn n_states(&self) -> usize {
        match self {
            Law::Jenkins { .. } | Law::Iwan { .. } => self.n_sliders(),
            _ => 0,
        }
    }

    /// True when the force or its derivative has kinks (clearance, Jenkins): harmonic balance
    /// should sample such laws more densely and the time integrator should locate events.
    pub fn is_nonsmooth(&self) -> bool {
        matches!(
            self,
            Law::Clearance { .. } | Law::Jenkins { .. } | Law::Iwan { .. }
        )
    }

    /// Force and derivatives at displacement `u` (m) and velocity `v` (m/s), given the committed
    /// history `state` (length [`Law::n_states`]). Allocation-free.
    ///
    /// At a kink (`u = e1` or `u = −e2` of the clearance, the stick–slip limit of Jenkins) the
    /// derivative returned is the one of the gap/stick side.
    #[inline]
    pub fn eval(&self, u: f64, v: f64, state: &[f64]) -> LawEval {
        match self {
            Law::Cubic { k3 } => LawEval {
                force: k3 * u * u * u,
                df_du: 3.0 * k3 * u * u,
                df_dv: 0.0,
            },
            Law::Polynomial { stiffness, damping } => {
                let mut e = LawEval::default();
                for t in stiffness {
                    let p = t.power as i32;
                    e.force += t.coef * u.powi(p);
                    e.df_du += t.coef * p as f64 * u.powi(p - 1);
                }
                for t in damping {
                    let p = t.power as i32;
                    e.force += t.coef * v.powi(p);
                    e.df_dv += t.coef * p as f64 * v.powi(p - 1);
                }
                e
            }
            Law::Clearance {
                k1,
                k2,
                e1,
                e2,
                r,
                s,
            } => {
                let d1 = u - e1;
                let d2 = -u - e2;
                if d1 > 0.0 {
                    LawEval {
                        force: k1 * d1.powf(*r),
                        df_du: k1 * r * d1.powf(r - 1.0),
                        df_dv: 0.0,
                    }
                } else if d2 > 0.0 {
                    LawEval {
                        force: -k2 * d2.powf(*s),
                        df_du: k2 * s * d2.powf(s - 1.0),
                        df_dv: 0.0,
                    }
                } else {
                    LawEval::default()
                }
            }
            Law::QuadraticDamping { c2 } => LawEval {
                force: c2 * v * v.abs(),
                df_du: 0.0,
                df_dv: 2.0 * c2 * v.abs(),
            },
            Law::Coulomb { fc, v_reg } => {
                let t = (v / v_reg).tanh();
                LawEval {
                    force: fc * t,
                    df_du: 0.0,
                    df_dv: fc / v_reg * (1.0 - t * t),
                }
            }
            Law::Jenkins { kt, fs } => {
                let (force, df_du) = iwan::slider_force(*kt, *fs, u, state[0]);
                LawEval {
                    force,
                    df_du,
                    df_dv: 0.0,
                }
            }
            Law::Iwan { grid, .. } => {
                let (force, df_du) = grid.force(u, state);
                LawEval {
                    force,
                    df_du,
                    df_dv: 0.0,
                }
            }
            Law::PowerSpring { k, p } => {
                let a = u.abs();
                LawEval {
                    force: k * a.powf(*p) * u.signum(),
                    df_du: k * p * a.powf(p - 1.0),
                    df_dv: 0.0,
                }
            }
            Law::PowerDamper { c, p } => {
                let a = v.abs();
                LawEval {
                    force: c * a.powf(*p) * v.signum(),
                    df_du: 0.0,
                    df_dv: c * p * a.powf(p - 1.0),
                }
            }
            // No scalar form: every consumer dispatches on `arity()` first.
            Law::CoupledPolynomial { .. } => LawEval::default(),
        }
    }

    /// Forces `g_i(u)` (N) of a law on `u.len()` coordinates (m) into `force`, and
    /// `∂g_i/∂u_j` (N/m) into `jac[i·m + j]` (row-major, `m × m`). For a one-coordinate law
    /// it is [`Law::eval`] at zero velocity and state. Allocation-free.
    ///
    /// # Panics
    /// When `u`, `force` or `jac` do not match [`Law::arity`] (a programming error).
    #[inline]
    pub fn eval_coupled(&self, u: &[f64], force: &mut [f64], jac: &mut [f64]) {
        let m = self.arity();
        assert!(
            u.len() == m && force.len() == m && jac.len() == m * m,
            "eval_coupled: buffer sizes"
        );
        match self {
            Law::CoupledPolynomial { terms, .. } => {
                force.fill(0.0);
                jac.fill(0.0);
                for t in terms {
                    force[t.output] += t.coef * t.monomial(u);
                    for (j, &p) in t.powers.iter().enumerate() {
                        if p == 0 {
                            continue;
                        }
                        // ∂/∂u_j of Π u^p: p u_j^{p−1} Π_{l≠j} u_l^{p_l}.
                        let mut d = t.coef * f64::from(p) * u[j].powi(p as i32 - 1);
                        for (l, (&pl, &ul)) in t.powers.iter().zip(u).enumerate() {
                            if l != j {
                                d *= ul.powi(pl as i32);
                            }
                        }
                        jac[t.output * m + j] += d;
                    }
                }
            }
            scalar => {
                let e = scalar.eval(u[0], 0.0, &[]);
                force[0] = e.force;
                jac[0] = e.df_du;
            }
        }
    }

    /// `∂g_i/∂p_k` of a [`Law::CoupledPolynomial`] at coordinates `u` into `out[i·n_params + k]`
    /// (`m × n_params`, row-major): the monomial of term `k` in the row of its output.
    ///
    /// # Panics
    /// When `out` has the wrong length or the law is not coupled (a programming error).
    pub fn dforce_dparams_coupled(&self, u: &[f64], out: &mut [f64]) {
        let Law::CoupledPolynomial { inputs, terms } = self else {
            panic!("dforce_dparams_coupled: not a coupled law");
        };
        let np = terms.len();
        assert_eq!(
            out.len(),
            inputs * np,
            "dforce_dparams_coupled: output length"
        );
        out.fill(0.0);
        for (k, t) in terms.iter().enumerate() {
            out[t.output * np + k] = t.monomial(u);
        }
    }

    /// Commits the history after a converged step at `(u, v)`: the Jenkins slider moves so that
    /// the spring force is at the slip limit. No-op for memoryless laws.
    #[inline]
    pub fn commit_state(&self, u: f64, _v: f64, state: &mut [f64]) {
        match self {
            Law::Jenkins { kt, fs } => {
                iwan::slider_commit(*kt, *fs, u, &mut state[0]);
            }
            Law::Iwan { grid, .. } => {
                for (s, z) in state.iter_mut().enumerate().take(grid.sliders() + 1) {
                    let (k, f) = grid.slider(s);
                    iwan::slider_commit(k, f, u, z);
                }
            }
            _ => {}
        }
    }

    /// `∂g/∂p_i` for every parameter, written into `out` (length [`Law::n_params`]), at fixed
    /// committed `state`. The derivative of `r`, `s` at the contact point is its limit 0.
    pub fn dforce_dparams(&self, u: f64, v: f64, state: &[f64], out: &mut [f64]) {
        assert_eq!(
            out.len(),
            self.n_params(),
            "dforce_dparams: wrong output length"
        );
        match self {
            Law::Cubic { .. } => out[0] = u * u * u,
            Law::QuadraticDamping { .. } => out[0] = v * v.abs(),
            Law::Polynomial { stiffness, damping } => {
                let ns = stiffness.len();
                for (o, t) in out[..ns].iter_mut().zip(stiffness) {
                    *o = u.powi(t.power as i32);
                }
                for (o, t) in out[ns..].iter_mut().zip(damping) {
                    *o = v.powi(t.power as i32);
                }
            }
            Law::Clearance {
                k1,
                k2,
                e1,
                e2,
                r,
                s,
            } => {
                out.fill(0.0);
                let d1 = u - e1;
                let d2 = -u - e2;
                if d1 > 0.0 {
                    let p = d1.powf(*r);
                    out[0] = p;
                    out[2] = -k1 * r * d1.powf(r - 1.0);
                    out[4] = k1 * p * d1.ln();
                } else if d2 > 0.0 {
                    let p = d2.powf(*s);
                    out[1] = -p;
                    out[3] = k2 * s * d2.powf(s - 1.0);
                    out[5] = -k2 * p * d2.ln();
                }
            }
            Law::Coulomb { fc, v_reg } => {
                let x = v / v_reg;
                let t = x.tanh();
                out[0] = t;
                out[1] = -fc * (1.0 - t * t) * x / v_reg;
            }
            Law::Jenkins { .. } | Law::Iwan { .. } => {
                out.fill(0.0);
                let np = out.len();
                let (mut dk, mut df) = ([0.0; 4], [0.0; 4]);
                for (s, &z) in state.iter().enumerate().take(self.n_sliders()) {
                    let (k, f) = self.slider(s);
                    self.slider_dparams(s, &mut dk[..np], &mut df[..np]);
                    let trial = k * (u - z);
                    for i in 0..np {
                        out[i] += if trial.abs() <= f {
                            dk[i] * (u - z)
                        } else {
                            df[i] * trial.signum()
                        };
                    }
                }
            }
            Law::PowerSpring { k, p } | Law::PowerDamper { c: k, p } => {
                let x = if matches!(self, Law::PowerSpring { .. }) {
                    u
                } else {
                    v
                };
                let a = x.abs();
                let m = if x == 0.0 {
                    0.0
                } else {
                    a.powf(*p).copysign(x)
                };
                out[0] = m;
                out[1] = if x == 0.0 { 0.0 } else { k * m * a.ln() };
            }
            // No scalar form (see `dforce_dparams_coupled`).
            Law::CoupledPolynomial { .. } => out.fill(0.0),
        }
    }
}

/// The coordinate an element acts on: `u = Σ w_i q_i` over a few DOFs.
#[derive(Debug, Clone, PartialEq)]
pub struct Coupling {
    dofs: Vec<usize>,
    weights: Vec<f64>,
}

impl Coupling {
    /// One DOF relative to ground: `u = q_dof`.
    pub fn single(dof: usize) -> Self {
        Coupling {
            dofs: vec![dof],
            weights: vec![1.0],
        }
    }

    /// Relative motion of two DOFs: `u = q_a − q_b`.
    pub fn relative(a: usize, b: usize) -> Self {
        Coupling {
            dofs: vec![a, b],
            weights: vec![1.0, -1.0],
        }
    }

    /// A general direction `u = Σ w_i q_i` (e.g. a scaled DOF, or a skewed contact normal).
    pub fn weighted(terms: &[(usize, f64)]) -> Result<Self> {
        if terms.is_empty() {
            return Err(Error::invalid("element coupling", "needs at least one DOF"));
        }
        for (k, &(d, w)) in terms.iter().enumerate() {
            if !w.is_finite() || w == 0.0 {
                return Err(Error::invalid(
                    "element coupling",
                    format!("weight {w} of term {} must be finite and non-zero", k + 1),
                ));
            }
            if terms[..k].iter().any(|&(o, _)| o == d) {
                return Err(Error::invalid(
                    "element coupling",
                    format!("DOF index {d} appears twice"),
                ));
            }
        }
        Ok(Coupling {
            dofs: terms.iter().map(|t| t.0).collect(),
            weights: terms.iter().map(|t| t.1).collect(),
        })
    }

    /// The coordinate `a − b` (the terms of both, equal DOFs summed, in `a`'s then `b`'s
    /// order); `None` when it vanishes (`a = b`, or two points of a modal model that move
    /// alike in every mode).
    pub fn difference(a: &Coupling, b: &Coupling) -> Option<Coupling> {
        let mut terms: Vec<(usize, f64)> = Vec::new();
        let pairs = a
            .dofs
            .iter()
            .zip(&a.weights)
            .map(|(&d, &w)| (d, w))
            .chain(b.dofs.iter().zip(&b.weights).map(|(&d, &w)| (d, -w)));
        for (d, w) in pairs {
            match terms.iter_mut().find(|(e, _)| *e == d) {
                Some(t) => t.1 += w,
                None => terms.push((d, w)),
            }
        }
        terms.retain(|&(_, w)| w != 0.0);
        Coupling::weighted(&terms).ok()
    }

    /// DOF indices involved.
    pub fn dofs(&self) -> &[usize] {
        &self.dofs
    }

    /// Their weights.
    pub fn weights(&self) -> &[f64] {
        &self.weights
    }

    /// `u = Σ w_i q_i`.
    #[inline]
    pub fn coordinate(&self, q: &[f64]) -> f64 {
        self.dofs
            .iter()
            .zip(&self.weights)
            .map(|(&d, &w)| w * q[d])
            .sum()
    }

    /// `out += w g`: adds the element force `g` to a DOF-space vector.
    #[inline]
    pub fn scatter_add(&self, g: f64, out: &mut [f64]) {
        for (&d, &w) in self.dofs.iter().zip(&self.weights) {
            out[d] += w * g;
        }
    }
}

/// A named nonlinear element: a law acting on a coupling coordinate (or, for a law of
/// [`Law::arity`] `m > 1`, on `m` coordinates).
#[derive(Debug, Clone, PartialEq)]
pub struct NonlinearElement {
    name: String,
    law: Law,
    couplings: Vec<Coupling>,
}

impl NonlinearElement {
    /// A validated element. Names are identifiers: letters, digits, `_`, `-`. A law on several
    /// coordinates needs [`NonlinearElement::coupled`].
    pub fn new(name: impl Into<String>, law: Law, coupling: Coupling) -> Result<Self> {
        Self::coupled(name, law, vec![coupling])
    }

    /// A validated element whose law acts on the coordinates `couplings` (one per
    /// [`Law::arity`], in the order of the law's coordinates).
    pub fn coupled(name: impl Into<String>, law: Law, couplings: Vec<Coupling>) -> Result<Self> {
        let name = name.into();
        if !crate::names::is_valid_name(&name) {
            return Err(Error::invalid(
                format!("element name '{name}'"),
                "use letters, digits, '_' and '-' only (it prefixes parameter names, e.g. tip.k3)",
            ));
        }
        if crate::names::mode_number(&name).is_some() || name == "stiffness_scale" {
            return Err(Error::invalid(
                format!("element name '{name}'"),
                "is reserved for the modal parameters (modeN.f, modeN.zeta, stiffness_scale)",
            ));
        }
        law.validate(&name)?;
        if couplings.len() != law.arity() {
            return Err(Error::invalid(
                format!("element '{name}'"),
                format!(
                    "its {} law acts on {} coordinate(s), {} given",
                    law.kind(),
                    law.arity(),
                    couplings.len()
                ),
            ));
        }
        Ok(NonlinearElement {
            name,
            law,
            couplings,
        })
    }

    /// The element's name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Its force law.
    pub fn law(&self) -> &Law {
        &self.law
    }

    /// Its coordinate (the first of a coupled law's).
    pub fn coupling(&self) -> &Coupling {
        &self.couplings[0]
    }

    /// Its coordinates, one per [`Law::arity`].
    pub fn couplings(&self) -> &[Coupling] {
        &self.couplings
    }

    /// True when the law acts on more than one coordinate.
    pub fn is_coupled(&self) -> bool {
        self.couplings.len() > 1
    }

    /// Full name of parameter `i`: `element.param`.
    pub fn param_full_name(&self, i: usize) -> String {
        format!("{}.{}", self.name, self.law.param_name(i))
    }

    /// Sets parameter `i` with range checking.
    pub fn set_param(&mut self, i: usize, value: f64) -> Result<()> {
        self.law.set_param(&self.name, i, value)
    }

    /// Sets the parameter called `param` (e.g. `k3`) with range checking; an unknown name is
    /// an error that lists the law's parameters. `what` names the setting in the error.
    pub fn set_named_param(&mut self, what: &str, param: &str, value: f64) -> Result<()> {
        let law = &self.law;
        let i = (0..law.n_params())
            .find(|&i| law.param_name(i) == param)
            .ok_or_else(|| {
                Error::invalid(
                    what,
                    format!(
                        "element '{}' ({}) has parameters {}",
                        self.name,
                        law.kind(),
                        (0..law.n_params())
                            .map(|i| law.param_name(i))
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            })?;
        self.set_param(i, value)
    }
}

impl AsRef<NonlinearElement> for NonlinearElement {
    fn as_ref(&self) -> &NonlinearElement {
        self
    }
}

impl AsMut<NonlinearElement> for NonlinearElement {
    fn as_mut(&mut self) -> &mut NonlinearElement {
        self
    }
}
