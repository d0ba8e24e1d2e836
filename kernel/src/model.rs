//! The structural model: `M q̈ + V q̇ + K q + f_NL(q, q̇) = f(t)` (thesis eq. 4) with labelled
//! DOFs, excitation and sensor points.

use crate::damping::Damping;
use crate::dof::DofMap;
use crate::element::{Coupling, NonlinearElement};
use crate::error::{Error, Result};
use crate::sparse::SparseSym;

/// What a sensor measures at its DOF.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quantity {
    /// Displacement (m or rad).
    Displacement,
    /// Velocity (m/s or rad/s).
    Velocity,
    /// Acceleration (m/s² or rad/s²).
    Acceleration,
}

impl Quantity {
    /// Text form used in model files.
    pub fn as_str(self) -> &'static str {
        match self {
            Quantity::Displacement => "displacement",
            Quantity::Velocity => "velocity",
            Quantity::Acceleration => "acceleration",
        }
    }

    /// Parses `displacement | velocity | acceleration`.
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "displacement" => Ok(Quantity::Displacement),
            "velocity" => Ok(Quantity::Velocity),
            "acceleration" => Ok(Quantity::Acceleration),
            _ => Err(Error::invalid(
                format!("sensor quantity '{s}'"),
                "expected displacement, velocity or acceleration",
            )),
        }
    }
}

/// A force input point: the nominal amplitude of the fundamental force harmonic there.
#[derive(Debug, Clone, PartialEq)]
pub struct Excitation {
    /// Name (identifier).
    pub name: String,
    /// DOF index the force acts on.
    pub dof: usize,
    /// Nominal force amplitude (N, or N m on a rotation).
    pub amplitude: f64,
}

/// A response output point.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor {
    /// Name (identifier).
    pub name: String,
    /// DOF index measured.
    pub dof: usize,
    /// Measured quantity.
    pub quantity: Quantity,
}

/// Checks run by [`Model::validate`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ValidationConfig {
    /// Relative symmetry tolerance: `|A_ij − A_ji| ≤ tol · max|A|`.
    pub symmetry_rtol: f64,
    /// Factorise M (and `K + σM`) to prove M positive definite and K positive semi-definite.
    /// Costs one sparse Cholesky each; switch off only for very large models checked before.
    pub check_definiteness: bool,
    /// Relative shift σ of the K check: `K + σ (max K_ii / max M_ii) M` must be positive
    /// definite, which admits the rigid-body modes of free structures.
    pub definiteness_shift: f64,
}

impl Default for ValidationConfig {
    fn default() -> Self {
        ValidationConfig {
            symmetry_rtol: 1e-10,
            check_definiteness: true,
            definiteness_shift: 1e-8,
        }
    }
}

/// What [`Model::validate`] checked.
#[derive(Debug, Clone, PartialEq)]
pub struct ValidationReport {
    /// Worst relative asymmetry found in M, K (and V when given as a matrix).
    pub max_asymmetry: f64,
    /// Whether positive (semi-)definiteness was proven by factorisation.
    pub definiteness_checked: bool,
}

/// Location of one parameter: element index and parameter index within its law.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ParamId {
    /// Index of the element in [`Model::elements`].
    pub element: usize,
    /// Index of the parameter within the element's law.
    pub index: usize,
}

/// Named parameter values, e.g. `tip.k3 = 6e9`, in model order.
#[derive(Debug, Clone, PartialEq)]
pub struct ParameterSet {
    /// Full names `element.param`.
    pub names: Vec<String>,
    /// Values in SI units.
    pub values: Vec<f64>,
}

/// A linear FE structure with local nonlinear elements, excitation and sensors.
#[derive(Debug, Clone)]
pub struct Model {
    name: String,
    dofs: DofMap,
    mass: SparseSym,
    stiffness: SparseSym,
    damping: Damping,
    elements: Vec<NonlinearElement>,
    excitation: Vec<Excitation>,
    sensors: Vec<Sensor>,
}

impl Model {
    /// A model with no damping, elements, excitation or sensors; M and K must match the DOF
    /// map in size. Numeric checks are done by [`Model::validate`].
    pub fn new(
        name: impl Into<String>,
        dofs: DofMap,
        mass: SparseSym,
        stiffness: SparseSym,
    ) -> Result<Self> {
        let n = dofs.len();
        if n == 0 {
            return Err(Error::invalid("model", "has no DOFs"));
        }
        for (what, m) in [
            ("mass matrix order", &mass),
            ("stiffness matrix order", &stiffness),
        ] {
            if m.n() != n {
                return Err(Error::DimensionMismatch {
                    what: format!("{what} (vs. number of DOF labels)"),
                    expected: n,
                    found: m.n(),
                });
            }
        }
        Ok(Model {
            name: name.into(),
            dofs,
            mass,
            stiffness,
            damping: Damping::None,
            elements: Vec::new(),
            excitation: Vec::new(),
            sensors: Vec::new(),
        })
    }

    /// Sets the damping model (a matrix must match the model size).
    pub fn set_damping(&mut self, damping: Damping) -> Result<()> {
        if let Damping::Matrix(v) = &damping
            && v.n() != self.n_dofs()
        {
            return Err(Error::DimensionMismatch {
                what: "damping matrix order".into(),
                expected: self.n_dofs(),
                found: v.n(),
            });
        }
        damping.validate()?;
        self.damping = damping;
        Ok(())
    }

    /// Adds a nonlinear element; its DOFs must exist and its name must be new.
    pub fn add_element(&mut self, element: NonlinearElement) -> Result<()> {
        self.check_coupling(element.name(), element.coupling())?;
        if self.elements.iter().any(|e| e.name() == element.name()) {
            return Err(Error::DuplicateName {
                what: "element".into(),
                name: element.name().into(),
            });
        }
        self.elements.push(element);
        Ok(())
    }

    /// Adds an excitation point.
    pub fn add_excitation(&mut self, ex: Excitation) -> Result<()> {
        self.check_dof(&format!("excitation '{}'", ex.name), ex.dof)?;
        if !ex.amplitude.is_finite() {
            return Err(Error::NonFinite {
                what: "excitation amplitude".into(),
                location: format!("excitation '{}'", ex.name),
                value: ex.amplitude,
            });
        }
        if self.excitation.iter().any(|e| e.name == ex.name) {
            return Err(Error::DuplicateName {
                what: "excitation".into(),
                name: ex.name,
            });
        }
        self.excitation.push(ex);
        Ok(())
    }

    /// Adds a sensor.
    pub fn add_sensor(&mut self, s: Sensor) -> Result<()> {
        self.check_dof(&format!("sensor '{}'", s.name), s.dof)?;
        if self.sensors.iter().any(|o| o.name == s.name) {
            return Err(Error::DuplicateName {
                what: "sensor".into(),
                name: s.name,
            });
        }
        self.sensors.push(s);
        Ok(())
    }

    fn check_dof(&self, what: &str, dof: usize) -> Result<()> {
        if dof >= self.n_dofs() {
            return Err(Error::DofIndexOutOfRange {
                what: what.into(),
                index: dof,
                n: self.n_dofs(),
            });
        }
        Ok(())
    }

    fn check_coupling(&self, name: &str, c: &Coupling) -> Result<()> {
        for &d in c.dofs() {
            self.check_dof(&format!("element '{name}'"), d)?;
        }
        Ok(())
    }

    /// Model name.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Number of DOFs.
    pub fn n_dofs(&self) -> usize {
        self.dofs.len()
    }
    /// DOF labels.
    pub fn dofs(&self) -> &DofMap {
        &self.dofs
    }
    /// Mass matrix M (kg).
    pub fn mass(&self) -> &SparseSym {
        &self.mass
    }
    /// Stiffness matrix K (N/m).
    pub fn stiffness(&self) -> &SparseSym {
        &self.stiffness
    }
    /// Damping model.
    pub fn damping(&self) -> &Damping {
        &self.damping
    }
    /// Nonlinear elements.
    pub fn elements(&self) -> &[NonlinearElement] {
        &self.elements
    }
    /// Excitation points.
    pub fn excitation(&self) -> &[Excitation] {
        &self.excitation
    }
    /// Sensors.
    pub fn sensors(&self) -> &[Sensor] {
        &self.sensors
    }

    /// DOFs touched by nonlinear elements, sorted and unique.
    pub fn nonlinear_dofs(&self) -> Vec<usize> {
        let mut d: Vec<usize> = self
            .elements
            .iter()
            .flat_map(|e| e.coupling().dofs().iter().copied())
            .collect();
        d.sort_unstable();
        d.dedup();
        d
    }

    /// All element parameters with their full names, in model order.
    pub fn parameters(&self) -> ParameterSet {
        let mut names = Vec::new();
        let mut values = Vec::new();
        for e in &self.elements {
            for i in 0..e.law().n_params() {
                names.push(e.param_full_name(i));
                values.push(e.law().param(i));
            }
        }
        ParameterSet { names, values }
    }

    /// Finds a parameter by full name (`tip.k3`).
    pub fn param_id(&self, name: &str) -> Result<ParamId> {
        for (ei, e) in self.elements.iter().enumerate() {
            for i in 0..e.law().n_params() {
                if e.param_full_name(i) == name {
                    return Ok(ParamId {
                        element: ei,
                        index: i,
                    });
                }
            }
        }
        Err(Error::UnknownParameter {
            name: name.into(),
            known: self.parameters().names.join(", "),
        })
    }

    /// Value of a parameter.
    pub fn param(&self, id: ParamId) -> f64 {
        self.elements[id.element].law().param(id.index)
    }

    /// Sets a parameter by id, with range checks.
    pub fn set_param(&mut self, id: ParamId, value: f64) -> Result<()> {
        let n = self.elements.len();
        let e = self.elements.get_mut(id.element).ok_or_else(|| {
            Error::invalid(
                format!("parameter id (element {})", id.element),
                format!("the model has {n} elements"),
            )
        })?;
        e.set_param(id.index, value)
    }

    /// Sets a parameter by full name, with range checks.
    pub fn set_param_by_name(&mut self, name: &str, value: f64) -> Result<()> {
        let id = self.param_id(name)?;
        self.set_param(id, value)
    }

    /// Checks the model: finite entries, symmetric M, K (and V), M positive definite (naming
    /// massless DOFs), K positive semi-definite, element parameters in range.
    pub fn validate(&self, cfg: &ValidationConfig) -> Result<ValidationReport> {
        let mut max_asym = 0.0_f64;
        let mut mats: Vec<(&str, &SparseSym)> = vec![
            ("mass matrix", &self.mass),
            ("stiffness matrix", &self.stiffness),
        ];
        if let Damping::Matrix(v) = &self.damping {
            mats.push(("damping matrix", v));
        }
        for (name, m) in &mats {
            if let Some((i, j, v)) = m.first_non_finite() {
                return Err(Error::NonFinite {
                    what: (*name).into(),
                    location: format!(
                        "entry ({}, {})",
                        self.dofs.describe(i),
                        self.dofs.describe(j)
                    ),
                    value: v,
                });
            }
            if let Some(d) = m.symmetry_defect() {
                if d.rel_diff > cfg.symmetry_rtol {
                    return Err(Error::NotSymmetric {
                        matrix: (*name).into(),
                        row: self.dofs.describe(d.row),
                        col: self.dofs.describe(d.col),
                        a_ij: d.a_ij,
                        a_ji: d.a_ji,
                        rel_diff: d.rel_diff,
                        tolerance: cfg.symmetry_rtol,
                    });
                }
                max_asym = max_asym.max(d.rel_diff);
            }
        }
        self.damping.validate()?;
        for e in &self.elements {
            e.law().validate(e.name())?;
        }

        // Massless DOFs are reported by name, whatever the definiteness setting.
        let md = self.mass.diag();
        let massless: Vec<usize> = (0..md.len()).filter(|&i| md[i] <= 0.0).collect();
        if !massless.is_empty() {
            let listed: Vec<String> = massless
                .iter()
                .take(10)
                .map(|&i| self.dofs.describe(i))
                .collect();
            let more = if massless.len() > 10 {
                format!(", … {} more", massless.len() - 10)
            } else {
                String::new()
            };
            return Err(Error::MasslessDofs {
                count: massless.len(),
                listed: listed.join(", ") + &more,
            });
        }
        if cfg.check_definiteness {
            if let Err(step) = self.mass.cholesky() {
                return Err(Error::NotDefinite {
                    matrix: "mass matrix".into(),
                    required: "positive definite".into(),
                    detail: format!(
                        "the Cholesky factorisation met a non-positive pivot at elimination step {step}"
                    ),
                });
            }
            let kd = self.stiffness.diag();
            let kmax = kd.iter().fold(0.0_f64, |a, &b| a.max(b));
            if let Some(i) = kd.iter().position(|&k| k < 0.0) {
                return Err(Error::NotDefinite {
                    matrix: "stiffness matrix".into(),
                    required: "positive semi-definite".into(),
                    detail: format!(
                        "negative diagonal entry {:e} at DOF {}",
                        kd[i],
                        self.dofs.describe(i)
                    ),
                });
            }
            let mmax = md.iter().fold(0.0_f64, |a, &b| a.max(b));
            let sigma = cfg.definiteness_shift * kmax.max(f64::MIN_POSITIVE) / mmax;
            let shifted =
                SparseSym::linear_combination("K + σM", 1.0, &self.stiffness, sigma, &self.mass)?;
            if let Err(step) = shifted.cholesky() {
                return Err(Error::NotDefinite {
                    matrix: "stiffness matrix".into(),
                    required: "positive semi-definite".into(),
                    detail: format!(
                        "K + σM with σ = {sigma:.3e} 1/s² is not positive definite (non-positive pivot at elimination step {step}): \
                         K has a negative eigenvalue (check element signs, or a negative spring)"
                    ),
                });
            }
        }
        Ok(ValidationReport {
            max_asymmetry: max_asym,
            definiteness_checked: cfg.check_definiteness,
        })
    }

    /// Rigid-body mass along a translation: `rᵀ M r` with `r = 1` on every DOF of that component.
    pub fn translational_mass(&self, component: crate::dof::Component) -> f64 {
        let r: Vec<f64> = self
            .dofs
            .labels()
            .iter()
            .map(|l| if l.component == component { 1.0 } else { 0.0 })
            .collect();
        self.mass.bilinear(&r, &r)
    }
}
