//! One identity for every calibratable quantity, and the outcome status of every iterative
//! solver.
//!
//! A [`Param`] names a quantity wherever it lives: a nonlinear element's law parameter
//! (`tip.k3`), a modal parameter of the reduced model (`mode1.f`, `mode1.zeta`), the global
//! stiffness scale (`stiffness_scale`), or an FE-level parameter of the full model: the
//! stiffness or mass scale of a labelled group of elements (`group:flange.k_scale`,
//! `group:flange.m_scale`) or a grounded spring at a DOF (`spring:12:uz.k`); or a gain of the
//! test data a model is calibrated on (`input_gain`, `sensor_gain:tip`). The text form
//! parses and prints round trip (`p.to_string().parse() == Ok(p)`), and it is the name used
//! in model files, jobs files, calibration settings and result files.
//!
//! Every object that holds parameters — the [`Model`](crate::Model), the reduced system, the
//! time-domain plant, the harmonic balance system — implements [`Parameterized`]: list, get,
//! set, with the same names and the same range checks. Bounds belong to the caller
//! (calibration, planning), not to the trait.
//!
//! [`Status`] is the outcome of an iterative solver that ran on valid input: converged or why
//! it stopped. A solver that stops short returns what it computed with its status; `Err` is
//! reserved for invalid input.

use crate::dof::DofLabel;
use crate::element::NonlinearElement;
use crate::error::{Error, Result};
pub use crate::names::is_valid_name;
use crate::names::mode_number;
use std::fmt;
use std::str::FromStr;

/// A calibratable quantity, by identity.
///
/// Text forms (modes are 1-based in text, 0-based in the enum):
///
/// | variant | text | unit |
/// |---|---|---|
/// | [`Param::Element`] | `ELEMENT.PARAM` (`tip.k3`) | the law's (N/m³ for `k3`) |
/// | [`Param::ModalFrequency`] | `modeN.f` | Hz |
/// | [`Param::ModalDamping`] | `modeN.zeta` | 1 (fraction of critical) |
/// | [`Param::ModalMass`] | `modeN.m` | kg (1 for mass-normalised shapes) |
/// | [`Param::ModeShape`] | `modeN.shape:POINT` (`mode1.shape:31:uz`) | m/√kg |
/// | [`Param::StiffnessScale`] | `stiffness_scale` | 1 (factor on every stiffness) |
/// | [`Param::GroupStiffness`] | `group:NAME.k_scale` | 1 (factor on the group's K) |
/// | [`Param::GroupMass`] | `group:NAME.m_scale` | 1 (factor on the group's M) |
/// | [`Param::BoundarySpring`] | `spring:NODE:COMP.k` | N/m (N m/rad on a rotation) |
/// | [`Param::InputGain`] | `input_gain` | per recorded unit: N/N, N/V, or V/V into a modelled shaker |
/// | [`Param::SensorGain`] | `sensor_gain:NAME` | 1 (recorded per true response) |
/// | [`Param::Residual`] | `residual:PORT:PORT` | m/N |
///
/// Element names may not take the form `modeN` (see
/// [`NonlinearElement::new`](crate::NonlinearElement::new)), so every text has one meaning.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Param {
    /// Parameter `param` (e.g. `k3`) of the nonlinear element named `element`.
    Element {
        /// Element name.
        element: String,
        /// Parameter name within the element's law.
        param: String,
    },
    /// Natural frequency `f_r` (Hz) of retained mode `mode` (0-based); its damping ratio is
    /// held when it changes.
    ModalFrequency(usize),
    /// Damping ratio `ζ_r` of retained mode `mode` (0-based): `c̃_rr = 2 ζ_r ω_r`.
    ModalDamping(usize),
    /// Modal mass `m_r` (kg) of retained mode `mode` (0-based) as seen at the ports: its
    /// participation becomes `Φ_P,r / √m_r`, so its receptance term is
    /// `Φ_P,r Φ_P,rᵀ / (m_r Z_rr)`. Nominal 1 for mass-normalised shapes; calibrated when the
    /// model is a modal model whose shapes are not known in absolute scale (experimental
    /// modal analysis: the modal constant `1/m_r` at a drive point).
    ModalMass(usize),
    /// The mode-shape entry `φ_pr` (m/√kg, mass-normalised, as [`crate::Model::add_point`]
    /// takes it) of mode `mode` (0-based, the file's order) at point `point` of a test-based
    /// modal model: every port on the point (its drives, sensors and elements, a relative
    /// element with its sign) moves with it. With a calibrated modal mass the port sees
    /// `φ_pr / √m_r`.
    ModeShape {
        /// Mode, 0-based.
        mode: usize,
        /// The point's label.
        point: DofLabel,
    },
    /// A factor on the whole linear stiffness: `K → s K` (every `ω_r² → s ω_r²`, residual
    /// flexibility `D → D / s`).
    StiffnessScale,
    /// Stiffness scale of a labelled group of finite elements:
    /// `K = K₀ + Σ_g (s_g − 1) K_g`.
    GroupStiffness(String),
    /// Mass scale of a labelled group of finite elements: `M = M₀ + Σ_g (s_g − 1) M_g`.
    GroupMass(String),
    /// A grounded linear spring at one DOF (boundary stiffness): `K_dd += k`.
    BoundarySpring(DofLabel),
    /// The gain of the test data's drive record: the model is driven with `g` times the
    /// recorded drive harmonics (a force gauge's sensitivity error on force data; N/V for a
    /// voltage record driving a shaker taken as a force source; volts at the coil per
    /// recorded volt when the calibration models the shaker). A property of the test data,
    /// not of the model: calibrated or set in a calibration, refused by a model.
    InputGain,
    /// The gain of test-data channel `NAME` (a sensor of the model): the channel records
    /// `s` times the true response (a sensor's sensitivity error). A property of the test
    /// data, like [`Param::InputGain`].
    SensorGain(String),
    /// The measured residual flexibility `D_ab = D_ba` (m/N) between ports `a` and `b` (element,
    /// excitation or sensor names; `a == b` on a driving point) of a test-based modal model:
    /// the static share of the modes above the test's band (thesis eq. 10, measured), added to
    /// the receptance `H = Φ_P Z⁻¹ Φ_Pᵀ + D`. The pair is unordered: [`Param::residual`] and
    /// the text form hold it with `a ≤ b`.
    Residual(String, String),
}

impl Param {
    /// An element law parameter, `element.param`.
    pub fn element(element: impl Into<String>, param: impl Into<String>) -> Self {
        Param::Element {
            element: element.into(),
            param: param.into(),
        }
    }

    /// The residual flexibility between ports `a` and `b`, the pair held in order (`a ≤ b`)
    /// so that both spellings name one parameter.
    pub fn residual(a: impl Into<String>, b: impl Into<String>) -> Self {
        let (a, b) = (a.into(), b.into());
        if a <= b {
            Param::Residual(a, b)
        } else {
            Param::Residual(b, a)
        }
    }

    /// Whether this is a gain of test data ([`Param::InputGain`], [`Param::SensorGain`]):
    /// held by a calibration's objective, not by a model.
    pub fn is_gain(&self) -> bool {
        matches!(self, Param::InputGain | Param::SensorGain(_))
    }

    /// The unit of the value, as text (`Hz`, `1`, `N/m`; an element parameter's unit comes
    /// from its law and is `law` here).
    pub fn unit(&self) -> &'static str {
        match self {
            Param::Element { .. } => "law",
            Param::ModalFrequency(_) => "Hz",
            Param::ModalDamping(_)
            | Param::StiffnessScale
            | Param::GroupStiffness(_)
            | Param::GroupMass(_) => "1",
            Param::ModalMass(_) => "kg",
            Param::ModeShape { .. } => "m/√kg",
            Param::BoundarySpring(_) => "N/m",
            Param::Residual(..) => "m/N",
            Param::InputGain => "per recorded unit",
            Param::SensorGain(_) => "1",
        }
    }
}

impl fmt::Display for Param {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Param::Element { element, param } => write!(f, "{element}.{param}"),
            Param::ModalFrequency(r) => write!(f, "mode{}.f", r + 1),
            Param::ModalDamping(r) => write!(f, "mode{}.zeta", r + 1),
            Param::ModalMass(r) => write!(f, "mode{}.m", r + 1),
            Param::ModeShape { mode, point } => write!(f, "mode{}.shape:{point}", mode + 1),
            Param::StiffnessScale => f.write_str("stiffness_scale"),
            Param::GroupStiffness(g) => write!(f, "group:{g}.k_scale"),
            Param::GroupMass(g) => write!(f, "group:{g}.m_scale"),
            Param::BoundarySpring(d) => write!(f, "spring:{d}.k"),
            Param::InputGain => f.write_str("input_gain"),
            Param::SensorGain(s) => write!(f, "sensor_gain:{s}"),
            Param::Residual(a, b) if a <= b => write!(f, "residual:{a}:{b}"),
            Param::Residual(a, b) => write!(f, "residual:{b}:{a}"),
        }
    }
}

impl FromStr for Param {
    type Err = Error;

    fn from_str(text: &str) -> Result<Self> {
        let s = text.trim();
        let bad = |why: &str| {
            Error::invalid(
                format!("parameter '{s}'"),
                format!(
                    "{why}; expected ELEMENT.PARAM (tip.k3), modeN.f, modeN.zeta, \
                     modeN.m, modeN.shape:POINT, stiffness_scale, group:NAME.k_scale, group:NAME.m_scale, spring:NODE:COMP.k, \
                     residual:PORT:PORT, input_gain or sensor_gain:NAME"
                ),
            )
        };
        if s == "stiffness_scale" {
            return Ok(Param::StiffnessScale);
        }
        if s == "input_gain" {
            return Ok(Param::InputGain);
        }
        if let Some(sensor) = s.strip_prefix("sensor_gain:") {
            if !is_valid_name(sensor) {
                return Err(bad("a sensor name has letters, digits, '_' and '-' only"));
            }
            return Ok(Param::SensorGain(sensor.into()));
        }
        if let Some(pair) = s.strip_prefix("residual:") {
            return match pair.split_once(':') {
                Some((a, b)) if is_port_name(a) && is_port_name(b) => Ok(Param::residual(a, b)),
                _ => Err(bad(
                    "a residual flexibility names two ports, residual:PORT:PORT (element, \
                     excitation or sensor names, a coupled element's coordinate as NAME[i])",
                )),
            };
        }
        // A point label holds no '.', so the first '.' after `modeN` splits a shape entry.
        if let Some((head, point)) = s.split_once(".shape:")
            && let Some(mode) = mode_number(head)
        {
            return Ok(Param::ModeShape {
                mode,
                point: point.parse()?,
            });
        }
        let (head, tail) = s.rsplit_once('.').ok_or_else(|| bad("no '.'"))?;
        if let Some(group) = head.strip_prefix("group:") {
            if !is_valid_name(group) {
                return Err(bad("a group name has letters, digits, '_' and '-' only"));
            }
            return match tail {
                "k_scale" => Ok(Param::GroupStiffness(group.into())),
                "m_scale" => Ok(Param::GroupMass(group.into())),
                _ => Err(bad("a group has k_scale and m_scale")),
            };
        }
        if let Some(dof) = head.strip_prefix("spring:") {
            if tail != "k" {
                return Err(bad("a boundary spring has one parameter, k"));
            }
            return Ok(Param::BoundarySpring(dof.parse()?));
        }
        if let Some(r) = mode_number(head) {
            return match tail {
                "f" => Ok(Param::ModalFrequency(r)),
                "zeta" => Ok(Param::ModalDamping(r)),
                "m" => Ok(Param::ModalMass(r)),
                _ => Err(bad("a mode has f, zeta, m and shape:POINT")),
            };
        }
        if head.starts_with("mode") && head[4..].bytes().all(|b| b.is_ascii_digit()) {
            return Err(bad("modes are numbered from 1"));
        }
        if !is_valid_name(head) {
            return Err(bad("an element name has letters, digits, '_' and '-' only"));
        }
        if tail.is_empty() || !tail.chars().all(|c| c.is_ascii_alphanumeric() || c == '_') {
            return Err(bad("a parameter name has letters, digits and '_' only"));
        }
        Ok(Param::element(head, tail))
    }
}

/// A port name: an element, excitation or sensor name, or a coupled element's coordinate
/// `NAME[i]` (`i ≥ 1`).
fn is_port_name(s: &str) -> bool {
    match s.strip_suffix(']').and_then(|t| t.split_once('[')) {
        Some((name, i)) => {
            is_valid_name(name)
                && !i.is_empty()
                && !i.starts_with('0')
                && i.bytes().all(|b| b.is_ascii_digit())
        }
        None => is_valid_name(s),
    }
}

/// An object whose parameters can be listed, read and set by [`Param`].
///
/// Setting checks the value against the parameter's admissible range (a stiffness must be
/// non-negative, a frequency positive, …) and keeps every derived quantity of the object
/// consistent, so that the object afterwards equals one built with the new value.
pub trait Parameterized {
    /// Every parameter the object holds, in a fixed order.
    fn parameters(&self) -> Vec<Param>;

    /// The current value of `p` in its unit ([`Param::unit`]); an unknown parameter is an
    /// error that lists the known ones.
    fn param(&self, p: &Param) -> Result<f64>;

    /// Sets `p` to `value` (its unit), with range checks.
    fn set_param(&mut self, p: &Param, value: f64) -> Result<()>;

    /// The values of `params`, in order.
    fn param_values(&self, params: &[Param]) -> Result<Vec<f64>> {
        params.iter().map(|p| self.param(p)).collect()
    }

    /// Sets every `params[i]` to `values[i]`.
    fn set_params(&mut self, params: &[Param], values: &[f64]) -> Result<()> {
        if params.len() != values.len() {
            return Err(Error::DimensionMismatch {
                what: "parameter values".into(),
                expected: params.len(),
                found: values.len(),
            });
        }
        params
            .iter()
            .zip(values)
            .try_for_each(|(p, &v)| self.set_param(p, v))
    }
}

/// The error for a parameter the object does not hold, listing those it does (a gain, which
/// no model holds, gets its own message).
pub fn unknown_param(p: &Param, known: &[Param]) -> Error {
    if p.is_gain() {
        return Error::invalid(
            format!("parameter '{p}'"),
            "a gain belongs to the test data, not to a model: set or calibrate it in \
             `nlsim calibrate` (its value then carries into `nlsim validate`)",
        );
    }
    Error::UnknownParameter {
        name: p.to_string(),
        known: known
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(", "),
    }
}

/// Parses `name` as a parameter of an object whose parameters are `known`: a text that
/// does not parse is reported like an unknown parameter, with the known ones listed.
pub fn parse_known(name: &str, known: &[Param]) -> Result<Param> {
    name.parse().map_err(|_| Error::UnknownParameter {
        name: name.trim().to_string(),
        known: known
            .iter()
            .map(ToString::to_string)
            .collect::<Vec<_>>()
            .join(", "),
    })
}

/// Checks that `value` is finite for parameter `p`.
pub fn check_finite(p: &Param, value: f64) -> Result<()> {
    if value.is_finite() {
        Ok(())
    } else {
        Err(Error::NonFinite {
            what: "parameter value".into(),
            location: p.to_string(),
            value,
        })
    }
}

/// The law parameters of `elements`, in order (`element.param`).
pub fn element_parameters<E: AsRef<NonlinearElement>>(elements: &[E]) -> Vec<Param> {
    elements
        .iter()
        .map(AsRef::as_ref)
        .flat_map(|e| {
            (0..e.law().n_params()).map(move |i| Param::element(e.name(), e.law().param_name(i)))
        })
        .collect()
}

/// `(element index, parameter index)` of element parameter `p` among `elements`; `None` for
/// another kind of parameter or a name no element has.
pub fn find_element_param<E: AsRef<NonlinearElement>>(
    elements: &[E],
    p: &Param,
) -> Option<(usize, usize)> {
    let Param::Element { element, param } = p else {
        return None;
    };
    let e = elements.iter().position(|e| e.as_ref().name() == element)?;
    let law = elements[e].as_ref().law();
    Some((
        e,
        (0..law.n_params()).find(|&i| law.param_name(i) == *param)?,
    ))
}

/// The value of element parameter `p` among `elements`.
pub fn element_param<E: AsRef<NonlinearElement>>(elements: &[E], p: &Param) -> Result<f64> {
    find_element_param(elements, p)
        .map(|(e, i)| elements[e].as_ref().law().param(i))
        .ok_or_else(|| unknown_param(p, &element_parameters(elements)))
}

/// Sets element parameter `p` among `elements`, with the law's range checks. An element
/// that exists without that parameter is an error listing the law's parameters.
pub fn set_element_param<E: AsRef<NonlinearElement> + AsMut<NonlinearElement>>(
    elements: &mut [E],
    p: &Param,
    value: f64,
) -> Result<()> {
    let Param::Element { element, param } = p else {
        return Err(unknown_param(p, &element_parameters(elements)));
    };
    match elements.iter_mut().find(|e| e.as_ref().name() == element) {
        Some(e) => e
            .as_mut()
            .set_named_param(&format!("parameter '{p}'"), param, value),
        None => Err(unknown_param(p, &element_parameters(elements))),
    }
}

/// How an iterative solver ended on valid input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Status {
    /// The convergence test was met.
    Converged,
    /// The iteration (or point) limit was reached first.
    IterationLimit,
    /// The step was cut below its smallest allowed size.
    StepTooSmall,
    /// The iterates grew without bound or the residual rose beyond recovery.
    Diverged,
    /// A NaN or infinity appeared in the iterates.
    NonFinite,
    /// A linear system on the way was singular (a Jacobian, a pencil).
    Singular,
}

impl Status {
    /// `true` for [`Status::Converged`].
    pub fn is_converged(self) -> bool {
        self == Status::Converged
    }

    /// A short lower-case description, as reports print it.
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Converged => "converged",
            Status::IterationLimit => "iteration limit reached",
            Status::StepTooSmall => "step too small",
            Status::Diverged => "diverged",
            Status::NonFinite => "non-finite values",
            Status::Singular => "singular linear system",
        }
    }
}

impl fmt::Display for Status {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl Status {
    /// Every status, in declaration order.
    pub const ALL: [Status; 6] = [
        Status::Converged,
        Status::IterationLimit,
        Status::StepTooSmall,
        Status::Diverged,
        Status::NonFinite,
        Status::Singular,
    ];
}

impl std::str::FromStr for Status {
    type Err = Error;

    /// The inverse of [`Status::as_str`] (as files written by nlsim hold it).
    fn from_str(text: &str) -> Result<Self> {
        Status::ALL
            .into_iter()
            .find(|s| s.as_str() == text)
            .ok_or_else(|| {
                Error::invalid(
                    "status",
                    format!(
                        "'{text}' is none of: {}",
                        Status::ALL.map(Status::as_str).join(", ")
                    ),
                )
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_text_round_trips() {
        for s in Status::ALL {
            assert_eq!(s.as_str().parse::<Status>().unwrap(), s);
        }
        let e = "done".parse::<Status>().unwrap_err().to_string();
        assert!(e.contains("'done'") && e.contains("step too small"), "{e}");
    }

    #[test]
    fn text_forms_are_unique_and_checked() {
        for (s, p) in [
            ("tip.k3", Param::element("tip", "k3")),
            ("mode1.f", Param::ModalFrequency(0)),
            ("mode12.zeta", Param::ModalDamping(11)),
            ("mode3.m", Param::ModalMass(2)),
            ("stiffness_scale", Param::StiffnessScale),
            (
                "group:flange.k_scale",
                Param::GroupStiffness("flange".into()),
            ),
            ("group:flange.m_scale", Param::GroupMass("flange".into())),
            (
                "spring:12:uz.k",
                Param::BoundarySpring("12:uz".parse().unwrap()),
            ),
            ("residual:accel:shaker", Param::residual("shaker", "accel")),
            ("residual:joint[2]:tip", Param::residual("joint[2]", "tip")),
            ("residual:tip:tip", Param::residual("tip", "tip")),
            (
                "mode2.shape:31:uz",
                Param::ModeShape {
                    mode: 1,
                    point: "31:uz".parse().unwrap(),
                },
            ),
        ] {
            assert_eq!(s.parse::<Param>().unwrap(), p, "{s}");
            assert_eq!(p.to_string(), s);
        }
        for bad in [
            "",
            "k3",
            "mode0.f",
            "mode1.k",
            "group:.k_scale",
            "group:a.x",
            "spring:12:uz.c",
            "spring:x.k",
            "a b.k3",
            "tip.",
            ".k3",
            "residual:tip",
            "residual:tip:",
            "residual:a b:tip",
            "residual:j[0]:tip",
            "residual:j[]:tip",
            "residual:a:b:c",
            "mode1.shape:",
            "mode1.shape:31",
            "mode0.shape:31:uz",
        ] {
            assert!(bad.parse::<Param>().is_err(), "{bad:?} parsed");
        }
        // Both spellings of a pair are one parameter, printed in order.
        let swapped: Param = "residual:tip:accel".parse().unwrap();
        assert_eq!(swapped, Param::residual("accel", "tip"));
        assert_eq!(swapped.to_string(), "residual:accel:tip");
    }
}
