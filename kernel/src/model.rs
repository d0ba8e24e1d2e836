//! The structural model: `M q̈ + V q̇ + K q + f_NL(q, q̇) = f(t)` (thesis eq. 4) with labelled
//! DOFs, excitation and sensor points.

use crate::damping::{Damping, ModalDamping};
use crate::dof::{DofLabel, DofMap};
use crate::element::{Coupling, NonlinearElement};
use crate::error::{Error, Result};
use crate::param::{
    Param, Parameterized, check_finite, element_parameters, find_element_param, unknown_param,
};
use crate::site::{ResidualTerm, Site, TestMode};
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

/// A force input point: the nominal amplitude of the fundamental force harmonic there, and
/// optionally further harmonics (thesis eq. 12).
///
/// One convention for every periodic force of the project (harmonic balance, multisine time
/// signals, model files): the force at the point is
/// `f(t) = amplitude · cos Ωt + Σ_j a_j cos(r_j Ω t + φ_j)` with `r_j = p_j/q_j` from
/// [`Excitation::harmonics`]; the fundamental is the phase reference.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Excitation {
    /// Name (identifier).
    pub name: String,
    /// Where the force acts: a DOF, or a point of a test-based modal model.
    pub at: Site,
    /// Nominal force amplitude at the fundamental `Ω` (N, or N m on a rotation), a cosine.
    pub amplitude: f64,
    /// Further harmonics of the same point (super- `kΩ` or sub-harmonics `Ω/k`), each with
    /// its own amplitude and phase; empty for a single sine.
    pub harmonics: Vec<ForceHarmonic>,
}

/// One further force harmonic of an [`Excitation`]: `amplitude · cos(r Ω t + phase)` with
/// `r = numerator/denominator` (thesis eq. 12: `ν Ω` or `Ω/ν`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ForceHarmonic {
    /// Numerator `p` of the frequency ratio `r = p/q` (≥ 1).
    pub numerator: u32,
    /// Denominator `q` of the frequency ratio (≥ 1; `p = 1, q = 3` is `Ω/3`).
    pub denominator: u32,
    /// Amplitude (N, or N m on a rotation).
    pub amplitude: f64,
    /// Phase `φ` (rad) relative to the fundamental's cosine.
    pub phase: f64,
}

impl ForceHarmonic {
    /// The frequency ratio `r = p/q` to the fundamental.
    pub fn ratio(&self) -> f64 {
        f64::from(self.numerator) / f64::from(self.denominator)
    }

    /// The ratio as written in files and messages: `3` or `1/3`.
    pub fn ratio_text(&self) -> String {
        if self.denominator == 1 {
            self.numerator.to_string()
        } else {
            format!("{}/{}", self.numerator, self.denominator)
        }
    }

    /// The complex amplitude `a e^{iφ}` (N): the force is `Re{a e^{iφ} e^{i r Ω t}}`.
    pub fn complex(&self) -> faer::c64 {
        faer::c64::new(
            self.amplitude * self.phase.cos(),
            self.amplitude * self.phase.sin(),
        )
    }

    /// Parses `K` or `1/K` (or `P/Q`) as a frequency ratio in lowest terms; errors name what
    /// is accepted.
    pub fn parse_ratio(text: &str) -> std::result::Result<(u32, u32), String> {
        let bad = || {
            format!(
                "harmonic order '{text}' is not a positive integer K (the harmonic KΩ) or a \
                 fraction 1/K (the sub-harmonic Ω/K)"
            )
        };
        let (p, q) = match text.trim().split_once('/') {
            Some((p, q)) => (
                p.trim().parse::<u32>().map_err(|_| bad())?,
                q.trim().parse::<u32>().map_err(|_| bad())?,
            ),
            None => (text.trim().parse::<u32>().map_err(|_| bad())?, 1),
        };
        if p == 0 || q == 0 {
            return Err(bad());
        }
        let (mut a, mut b) = (p, q);
        while b != 0 {
            (a, b) = (b, a % b);
        }
        Ok((p / a, q / a))
    }
}

/// A response output point.
#[derive(Debug, Clone, PartialEq)]
pub struct Sensor {
    /// Name (identifier).
    pub name: String,
    /// What it measures: a DOF, or a point of a test-based modal model.
    pub at: Site,
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

/// A labelled group of finite elements whose stiffness and mass contributions can be scaled
/// as calibration parameters ([`Param::GroupStiffness`], [`Param::GroupMass`]).
#[derive(Debug, Clone)]
pub struct ElementGroup {
    name: String,
    stiffness: Option<SparseSym>,
    mass: Option<SparseSym>,
    k_scale: f64,
    m_scale: f64,
}

impl ElementGroup {
    /// Group name (letters, digits, `_`, `-`).
    pub fn name(&self) -> &str {
        &self.name
    }
    /// The group's own stiffness contribution `K_g` (N/m), included once in the model's K.
    pub fn stiffness(&self) -> Option<&SparseSym> {
        self.stiffness.as_ref()
    }
    /// The group's own mass contribution `M_g` (kg), included once in the model's M.
    pub fn mass(&self) -> Option<&SparseSym> {
        self.mass.as_ref()
    }
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
    /// `K₀`, `M₀` with every group at scale 1 and no boundary spring, kept once groups or
    /// springs exist so that the effective matrices can be rebuilt.
    base: Option<Box<(SparseSym, SparseSym)>>,
    groups: Vec<ElementGroup>,
    springs: Vec<(usize, f64)>,
    /// Named points: combinations of DOFs (a test-based modal model's measured points).
    points: Vec<(DofLabel, Coupling)>,
    /// True for a test-based modal model ([`Model::modal`]).
    modal: bool,
    /// Measured residual flexibilities between ports (test-based modal models).
    residual: Vec<ResidualTerm>,
    /// Node coordinates (m), ascending by node id: what output files that carry geometry
    /// write (universal dataset 2411); no analysis uses them.
    geometry: Vec<(u64, [f64; 3])>,
}

impl Model {
    /// A model with no damping, elements, excitation or sensors; M and K must match the DOF
    /// map in size. Numeric checks are done by [`Model::validate`].
    pub fn new(
        name: impl Into<String>,
        dofs: DofMap,
        mut mass: SparseSym,
        stiffness: SparseSym,
    ) -> Result<Self> {
        // One mesh gives M and K one pattern: hold it once (0.7 GB at 10⁶ DOFs).
        mass.share_pattern(&stiffness);
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
            base: None,
            groups: Vec::new(),
            springs: Vec::new(),
            points: Vec::new(),
            modal: false,
            residual: Vec::new(),
            geometry: Vec::new(),
        })
    }

    /// A test-based modal model (thesis eq. 9 with the modes taken from a test): one
    /// coordinate per mode, mass-normalised (`M = I`, `K = diag(ω_r²)`, modal damping `ζ_r`),
    /// no FE matrices. Its measured points come from [`Model::add_point`] with their
    /// mass-normalised mode-shape entries (m/√kg), its measured residual flexibilities from
    /// [`Model::add_residual`]. Modes must be given in ascending frequency, so that mode `r`
    /// of the file is `mode{r}` of every parameter and table.
    pub fn modal(name: impl Into<String>, modes: &[TestMode]) -> Result<Self> {
        if modes.is_empty() {
            return Err(Error::invalid("modal model", "has no modes"));
        }
        for (r, m) in modes.iter().enumerate() {
            m.check(r, r.checked_sub(1).map(|p| &modes[p]))?;
        }
        let tau = 2.0 * std::f64::consts::PI;
        let n = modes.len();
        let mass = SparseSym::diagonal("M", &vec![1.0; n])?;
        let k: Vec<f64> = modes
            .iter()
            .map(|m| (tau * m.frequency_hz).powi(2))
            .collect();
        let stiffness = SparseSym::diagonal("K", &k)?;
        let mut model = Model::new(name, DofMap::scalar(n), mass, stiffness)?;
        let mut damping = ModalDamping::uniform(0.0);
        damping.per_mode = modes.iter().map(|m| m.zeta).collect();
        model.damping = Damping::Modal(damping);
        model.modal = true;
        Ok(model)
    }

    /// True for a test-based modal model ([`Model::modal`]): its DOFs are modal coordinates.
    pub fn is_modal(&self) -> bool {
        self.modal
    }

    /// Declares a named point whose motion is `coupling` over the model's DOFs (for a modal
    /// model: the point's mass-normalised mode-shape entries, m/√kg). Forces, sensors and
    /// elements then name it like a DOF ([`Model::site`]). A label must be new and, on a model
    /// with physical DOFs, not one of them.
    pub fn add_point(&mut self, label: DofLabel, coupling: Coupling) -> Result<()> {
        self.check_coupling(&format!("point {label}"), &coupling)?;
        if self.points.iter().any(|(l, _)| *l == label) {
            return Err(Error::DuplicateName {
                what: "point".into(),
                name: label.to_string(),
            });
        }
        if !self.modal && self.dofs.index_of(&label).is_ok() {
            return Err(Error::invalid(
                format!("point {label}"),
                "is a DOF of the model: a point needs a label of its own",
            ));
        }
        self.points.push((label, coupling));
        Ok(())
    }

    /// The named points with their couplings, in the order declared.
    pub fn points(&self) -> &[(DofLabel, Coupling)] {
        &self.points
    }

    /// The ways coordinate `c` is made of the declared points ([`Model::add_point`]): one
    /// point (`[(i, 1)]`) or the difference of two (`[(i, 1), (j, −1)]`, as a relative element
    /// between points is built), each as `(index into` [`Model::points`]`, sign)`, compared
    /// exactly (the same arithmetic on the same numbers). Empty when none matches; more than
    /// one when points move alike in every mode.
    pub fn point_terms(&self, c: &Coupling) -> Vec<Vec<(usize, f64)>> {
        let pts = &self.points;
        let mut found = Vec::new();
        for (i, (_, a)) in pts.iter().enumerate() {
            if a == c {
                found.push(vec![(i, 1.0)]);
            }
        }
        for (i, (_, a)) in pts.iter().enumerate() {
            for (j, (_, b)) in pts.iter().enumerate() {
                if i != j && Coupling::difference(a, b).as_ref() == Some(c) {
                    found.push(vec![(i, 1.0), (j, -1.0)]);
                }
            }
        }
        found
    }

    /// The site a label names: a declared point, on a modal model its modal coordinate
    /// `modeN` (mode `N`, 1-based), else the DOF with that label.
    pub fn site(&self, label: &str) -> Result<Site> {
        let text = label.trim();
        if self.modal
            && let Some(r) = text
                .strip_prefix("mode")
                .and_then(|r| r.parse::<usize>().ok())
        {
            return if (1..=self.n_dofs()).contains(&r) {
                Ok(Site::Dof(r - 1))
            } else {
                Err(Error::invalid(
                    format!("modal coordinate '{text}'"),
                    format!("the model has modes 1 to {}", self.n_dofs()),
                ))
            };
        }
        let parsed: std::result::Result<DofLabel, _> = text.parse();
        if let Ok(l) = parsed
            && let Some((_, c)) = self.points.iter().find(|(p, _)| *p == l)
        {
            return Ok(Site::Point {
                label: l,
                coupling: c.clone(),
            });
        }
        if self.modal {
            let listed: Vec<String> = self.points.iter().map(|(l, _)| l.to_string()).collect();
            return Err(Error::invalid(
                format!("point '{text}'"),
                format!(
                    "is not a point of this modal model; its points: {}; its modal \
                     coordinates: mode1 to mode{}",
                    if listed.is_empty() {
                        "none".to_string()
                    } else {
                        listed.join(", ")
                    },
                    self.n_dofs()
                ),
            ));
        }
        Ok(Site::Dof(self.dofs.find(text)?))
    }

    /// A site's label as text: the DOF's or point's label, `modeN` for a coordinate of a
    /// modal model.
    pub fn describe_site(&self, site: &Site) -> String {
        match site {
            Site::Dof(d) if self.modal => format!("mode{}", d + 1),
            _ => site.describe(&self.dofs),
        }
    }

    /// Adds a measured residual flexibility between two ports (element, excitation or sensor
    /// names), which [`crate::Model`]'s reductions add to their residual flexibility. The
    /// names are checked against the ports when the model is reduced.
    pub fn add_residual(&mut self, term: ResidualTerm) -> Result<()> {
        if self
            .residual
            .iter()
            .any(|t| (t.a == term.a && t.b == term.b) || (t.a == term.b && t.b == term.a))
        {
            return Err(Error::invalid(
                format!("residual flexibility between '{}' and '{}'", term.a, term.b),
                "is given twice",
            ));
        }
        self.residual.push(term);
        Ok(())
    }

    /// The measured residual flexibilities ([`Model::add_residual`]).
    pub fn residual_terms(&self) -> &[ResidualTerm] {
        &self.residual
    }

    /// Sets the coordinates `(node id, [x, y, z])` (m, global Cartesian) of the model's nodes
    /// or measured points, in any order; they replace earlier ones. Output files that carry
    /// geometry (universal dataset 2411 beside the functions and shapes) write those of the
    /// nodes they name; nodes without coordinates are left out. Errors on a non-finite
    /// coordinate or a node given twice.
    pub fn set_geometry(&mut self, mut nodes: Vec<(u64, [f64; 3])>) -> Result<()> {
        for (node, xyz) in &nodes {
            if let Some(v) = xyz.iter().find(|v| !v.is_finite()) {
                return Err(Error::NonFinite {
                    what: "node coordinate".into(),
                    location: format!("node {node}"),
                    value: *v,
                });
            }
        }
        nodes.sort_by_key(|n| n.0);
        if let Some(w) = nodes.windows(2).find(|w| w[0].0 == w[1].0) {
            return Err(Error::invalid(
                format!("coordinates of node {}", w[0].0),
                "are given twice",
            ));
        }
        self.geometry = nodes;
        Ok(())
    }

    /// The node coordinates ([`Model::set_geometry`]), ascending by node id (m).
    pub fn geometry(&self) -> &[(u64, [f64; 3])] {
        &self.geometry
    }

    /// The coordinates of `node` (m), when known.
    pub fn node_coordinates(&self, node: u64) -> Option<[f64; 3]> {
        self.geometry
            .binary_search_by_key(&node, |n| n.0)
            .ok()
            .map(|i| self.geometry[i].1)
    }

    /// A builder: `Model::builder(name, dofs, M, K).damping(d).element(e).build()?` adds the
    /// parts in order and validates the whole model with `cfg` on [`ModelBuilder::build`].
    pub fn builder(
        name: impl Into<String>,
        dofs: DofMap,
        mass: SparseSym,
        stiffness: SparseSym,
    ) -> ModelBuilder {
        ModelBuilder {
            model: Model::new(name, dofs, mass, stiffness),
            validation: Some(ValidationConfig::default()),
        }
    }

    /// Declares a labelled group of finite elements: `stiffness` and `mass` are the group's
    /// own contributions `K_g`, `M_g`, which the model's K and M already contain. Its scales
    /// start at 1 and become the parameters `group:NAME.k_scale` and `group:NAME.m_scale`.
    pub fn add_group(
        &mut self,
        name: impl Into<String>,
        stiffness: Option<SparseSym>,
        mass: Option<SparseSym>,
    ) -> Result<()> {
        let name = name.into();
        self.refuse_on_modal(&format!("group '{name}'"))?;
        if !crate::param::is_valid_name(&name) {
            return Err(Error::invalid(
                format!("group name '{name}'"),
                "use letters, digits, '_' and '-' only (it names parameters, e.g. group:NAME.k_scale)",
            ));
        }
        if self.groups.iter().any(|g| g.name == name) {
            return Err(Error::DuplicateName {
                what: "group".into(),
                name,
            });
        }
        for (what, m) in [("stiffness", &stiffness), ("mass", &mass)] {
            if let Some(m) = m
                && m.n() != self.n_dofs()
            {
                return Err(Error::DimensionMismatch {
                    what: format!("group '{name}' {what} matrix order"),
                    expected: self.n_dofs(),
                    found: m.n(),
                });
            }
        }
        self.keep_base();
        self.groups.push(ElementGroup {
            name,
            stiffness,
            mass,
            k_scale: 1.0,
            m_scale: 1.0,
        });
        Ok(())
    }

    /// Adds a grounded spring `k` (N/m, or N m/rad on a rotation) at `dof`: the parameter
    /// `spring:LABEL.k`. Its stiffness is added to K.
    pub fn add_boundary_spring(&mut self, dof: usize, k: f64) -> Result<()> {
        self.check_dof("boundary spring", dof)?;
        self.refuse_on_modal("boundary spring")?;
        let label = self.dofs.labels()[dof];
        if self.springs.iter().any(|&(d, _)| d == dof) {
            return Err(Error::DuplicateName {
                what: "boundary spring".into(),
                name: label.to_string(),
            });
        }
        let p = Param::BoundarySpring(label);
        check_spring(&p, k)?;
        self.keep_base();
        self.springs.push((dof, k));
        self.rebuild()
    }

    /// Labelled element groups.
    pub fn groups(&self) -> &[ElementGroup] {
        &self.groups
    }

    fn keep_base(&mut self) {
        if self.base.is_none() {
            self.base = Some(Box::new((self.stiffness.clone(), self.mass.clone())));
        }
    }

    /// `K = K₀ + Σ_g (s_g − 1) K_g + Σ_i k_i e_i e_iᵀ`, `M = M₀ + Σ_g (t_g − 1) M_g`.
    fn rebuild(&mut self) -> Result<()> {
        let Some(base) = &self.base else {
            return Ok(());
        };
        let (mut k, mut m) = (base.0.clone(), base.1.clone());
        for g in &self.groups {
            if let Some(kg) = &g.stiffness
                && g.k_scale != 1.0
            {
                k = SparseSym::linear_combination(
                    "stiffness matrix",
                    1.0,
                    &k,
                    g.k_scale - 1.0,
                    kg,
                )?;
            }
            if let Some(mg) = &g.mass
                && g.m_scale != 1.0
            {
                m = SparseSym::linear_combination("mass matrix", 1.0, &m, g.m_scale - 1.0, mg)?;
            }
        }
        if !self.springs.is_empty() {
            let mut d = vec![0.0; self.n_dofs()];
            for &(i, v) in &self.springs {
                d[i] += v;
            }
            let s = SparseSym::diagonal("boundary springs", &d)?;
            k = SparseSym::linear_combination("stiffness matrix", 1.0, &k, 1.0, &s)?;
        }
        // A spring or a group leaves K's pattern as it was, in general: hold it once again.
        k.share_pattern(&base.0);
        m.share_pattern(&k);
        self.stiffness = k;
        self.mass = m;
        Ok(())
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
        for c in element.couplings() {
            self.check_coupling(element.name(), c)?;
        }
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
        self.check_site(&format!("excitation '{}'", ex.name), &ex.at)?;
        if !ex.amplitude.is_finite() {
            return Err(Error::NonFinite {
                what: "excitation amplitude".into(),
                location: format!("excitation '{}'", ex.name),
                value: ex.amplitude,
            });
        }
        for (j, h) in ex.harmonics.iter().enumerate() {
            let location = format!(
                "excitation '{}', harmonic {} (order {})",
                ex.name,
                j + 1,
                h.ratio_text()
            );
            for (what, v) in [("amplitude", h.amplitude), ("phase", h.phase)] {
                if !v.is_finite() {
                    return Err(Error::NonFinite {
                        what: format!("excitation harmonic {what}"),
                        location,
                        value: v,
                    });
                }
            }
            if h.numerator == 0 || h.denominator == 0 {
                return Err(Error::invalid(location, "the order must be K ≥ 1 or 1/K"));
            }
            if h.numerator == h.denominator {
                return Err(Error::invalid(
                    location,
                    "order 1 is the fundamental: give it as the excitation's amplitude (the \
                     phase reference)",
                ));
            }
            if ex.harmonics[..j].iter().any(|o| {
                u64::from(o.numerator) * u64::from(h.denominator)
                    == u64::from(h.numerator) * u64::from(o.denominator)
            }) {
                return Err(Error::invalid(location, "this order is given twice"));
            }
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
        self.check_site(&format!("sensor '{}'", s.name), &s.at)?;
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

    /// FE-level parts (groups, boundary springs) need FE matrices.
    fn refuse_on_modal(&self, what: &str) -> Result<()> {
        if self.modal {
            return Err(Error::invalid(what, crate::site::NO_FE_MATRICES));
        }
        Ok(())
    }

    fn check_site(&self, what: &str, site: &Site) -> Result<()> {
        match site {
            Site::Dof(d) => self.check_dof(what, *d),
            Site::Point { coupling, .. } => {
                for &d in coupling.dofs() {
                    self.check_dof(what, d)?;
                }
                Ok(())
            }
        }
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

    /// Renames the model.
    pub fn set_name(&mut self, name: impl Into<String>) {
        self.name = name.into();
    }

    /// Removes every nonlinear element (the linear structure, groups and springs stay).
    pub fn clear_elements(&mut self) {
        self.elements.clear();
    }

    /// Removes every excitation point.
    pub fn clear_excitation(&mut self) {
        self.excitation.clear();
    }

    /// Removes every sensor.
    pub fn clear_sensors(&mut self) {
        self.sensors.clear();
    }

    /// Boundary springs as `(DOF index, k)` (N/m, or N m/rad on a rotation), in the order
    /// they were added.
    pub fn boundary_springs(&self) -> &[(usize, f64)] {
        &self.springs
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
            .flat_map(|e| e.couplings().iter().flat_map(|c| c.dofs().iter().copied()))
            .collect();
        d.sort_unstable();
        d.dedup();
        d
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
        // A damping matrix dissipates: a negative diagonal entry feeds energy in at that DOF
        // (checked whatever the definiteness setting: it costs one pass).
        if let Damping::Matrix(v) = &self.damping
            && let Some((i, c)) = v.diag().iter().copied().enumerate().find(|(_, c)| *c < 0.0)
        {
            return Err(Error::NotDefinite {
                matrix: "damping matrix".into(),
                required: "positive semi-definite".into(),
                detail: format!(
                    "negative diagonal entry {c:e} at DOF {}: it would feed energy in",
                    self.dofs.describe(i)
                ),
            });
        }
        for e in &self.elements {
            e.law().validate(e.name())?;
        }

        // Massless DOFs are reported by name, whatever the definiteness setting.
        if let Some(e) = mass_sign_error(&self.stiffness, &self.mass, |i| self.dofs.describe(i)) {
            return Err(e);
        }
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
        if cfg.check_definiteness
            && let Damping::Matrix(v) = &self.damping
        {
            // As K: V + σM with a small shift is positive definite unless V has a negative
            // eigenvalue.
            let vmax = v.diag().iter().fold(0.0_f64, |a, &b| a.max(b));
            let mmax = md.iter().fold(0.0_f64, |a, &b| a.max(b));
            let sigma = cfg.definiteness_shift * vmax.max(f64::MIN_POSITIVE) / mmax;
            let shifted = SparseSym::linear_combination("V + σM", 1.0, v, sigma, &self.mass)?;
            if let Err(step) = shifted.cholesky() {
                return Err(Error::NotDefinite {
                    matrix: "damping matrix".into(),
                    required: "positive semi-definite".into(),
                    detail: format!(
                        "V + σM with σ = {sigma:.3e} 1/s is not positive definite (non-positive \
                         pivot at elimination step {step}): V has a negative eigenvalue, which \
                         feeds energy in"
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

fn check_spring(p: &Param, k: f64) -> Result<()> {
    check_finite(p, k)?;
    if k < 0.0 {
        return Err(Error::InvalidParameter {
            name: p.to_string(),
            value: k,
            reason: "a boundary spring stiffness must be non-negative".into(),
        });
    }
    Ok(())
}

fn check_scale(p: &Param, s: f64) -> Result<()> {
    check_finite(p, s)?;
    if s <= 0.0 {
        return Err(Error::InvalidParameter {
            name: p.to_string(),
            value: s,
            reason: "a scale factor must be positive".into(),
        });
    }
    Ok(())
}

/// The derivative of the model's matrices with respect to one FE-level parameter
/// ([`Model::matrix_derivative`]): `∂K/∂p` and `∂M/∂p`, constant because `K` and `M` are
/// affine in every FE-level parameter.
#[derive(Debug, Clone, Copy)]
pub enum MatrixDerivative<'a> {
    /// A group scale: `∂K/∂s_g = K_g` (stiffness scale) or `∂M/∂t_g = M_g` (mass scale).
    Group {
        /// `∂K/∂p` (N/m), when the parameter scales a stiffness.
        stiffness: Option<&'a SparseSym>,
        /// `∂M/∂p` (kg), when the parameter scales a mass.
        mass: Option<&'a SparseSym>,
    },
    /// A boundary spring: `∂K/∂k = e_d e_dᵀ` at DOF index `d`, `∂M/∂k = 0`.
    Spring {
        /// DOF index of the spring.
        dof: usize,
    },
}

impl MatrixDerivative<'_> {
    /// `y = (∂K/∂p − λ ∂M/∂p) x`, the right-hand side of the derivative of the eigenproblem
    /// `(K − λM) φ = 0` at eigenvalue `λ` (rad²/s²) without its `∂λ/∂p` term.
    ///
    /// # Panics
    /// When `x` or `y` does not have the model's order (a programming error of the caller).
    pub fn apply(&self, lambda: f64, x: &[f64], y: &mut [f64]) {
        y.fill(0.0);
        match *self {
            MatrixDerivative::Group { stiffness, mass } => {
                let mut t = vec![0.0; y.len()];
                if let Some(k) = stiffness {
                    k.mul_vec(x, &mut t);
                    y.iter_mut().zip(&t).for_each(|(a, b)| *a += b);
                }
                if let Some(m) = mass {
                    m.mul_vec(x, &mut t);
                    y.iter_mut().zip(&t).for_each(|(a, b)| *a -= lambda * b);
                }
            }
            MatrixDerivative::Spring { dof } => y[dof] = x[dof],
        }
    }

    /// The quadratic form `xᵀ (∂K/∂p − λ ∂M/∂p) x`: for a mass-normalised mode `x = φ_r` at
    /// `λ = λ_r` it is the eigenvalue derivative `∂λ_r/∂p` (rad²/s² per unit of `p`).
    pub fn quadratic(&self, lambda: f64, x: &[f64]) -> f64 {
        match *self {
            MatrixDerivative::Group { stiffness, mass } => {
                stiffness.map_or(0.0, |k| k.bilinear(x, x))
                    - lambda * mass.map_or(0.0, |m| m.bilinear(x, x))
            }
            MatrixDerivative::Spring { dof } => x[dof] * x[dof],
        }
    }

    /// `xᵀ (∂M/∂p) x` (kg per unit of `p`).
    pub fn mass_quadratic(&self, x: &[f64]) -> f64 {
        match *self {
            MatrixDerivative::Group { mass, .. } => mass.map_or(0.0, |m| m.bilinear(x, x)),
            MatrixDerivative::Spring { .. } => 0.0,
        }
    }
}

impl Model {
    /// `∂K/∂p` and `∂M/∂p` for an FE-level parameter (a group scale or a boundary spring);
    /// an error naming the known FE-level parameters for any other.
    pub fn matrix_derivative(&self, p: &Param) -> Result<MatrixDerivative<'_>> {
        let fe_params = || {
            self.parameters()
                .into_iter()
                .filter(|q| !matches!(q, Param::Element { .. }))
                .collect::<Vec<_>>()
        };
        let found = match p {
            Param::GroupStiffness(g) => self
                .group_index(g)
                .and_then(|i| self.groups[i].stiffness.as_ref())
                .map(|k| MatrixDerivative::Group {
                    stiffness: Some(k),
                    mass: None,
                }),
            Param::GroupMass(g) => self
                .group_index(g)
                .and_then(|i| self.groups[i].mass.as_ref())
                .map(|m| MatrixDerivative::Group {
                    stiffness: None,
                    mass: Some(m),
                }),
            Param::BoundarySpring(d) => self.spring_index(d).map(|i| MatrixDerivative::Spring {
                dof: self.springs[i].0,
            }),
            _ => None,
        };
        found.ok_or_else(|| unknown_param(p, &fe_params()))
    }

    fn group_index(&self, name: &str) -> Option<usize> {
        self.groups.iter().position(|g| g.name == name)
    }

    fn spring_index(&self, dof: &crate::dof::DofLabel) -> Option<usize> {
        let labels = self.dofs.labels();
        self.springs.iter().position(|&(d, _)| labels[d] == *dof)
    }
}

/// Element law parameters (model order), then the group scales of groups that have a
/// stiffness (`k_scale`) or mass (`m_scale`) part, then the boundary springs.
impl Parameterized for Model {
    fn parameters(&self) -> Vec<Param> {
        let mut out = element_parameters(&self.elements);
        for g in &self.groups {
            if g.stiffness.is_some() {
                out.push(Param::GroupStiffness(g.name.clone()));
            }
            if g.mass.is_some() {
                out.push(Param::GroupMass(g.name.clone()));
            }
        }
        let labels = self.dofs.labels();
        out.extend(
            self.springs
                .iter()
                .map(|&(d, _)| Param::BoundarySpring(labels[d])),
        );
        out
    }

    fn param(&self, p: &Param) -> Result<f64> {
        let found = match p {
            Param::Element { .. } => {
                find_element_param(&self.elements, p).map(|(e, i)| self.elements[e].law().param(i))
            }
            Param::GroupStiffness(g) => self
                .group_index(g)
                .filter(|&i| self.groups[i].stiffness.is_some())
                .map(|i| self.groups[i].k_scale),
            Param::GroupMass(g) => self
                .group_index(g)
                .filter(|&i| self.groups[i].mass.is_some())
                .map(|i| self.groups[i].m_scale),
            Param::BoundarySpring(d) => self.spring_index(d).map(|i| self.springs[i].1),
            _ => None,
        };
        found.ok_or_else(|| unknown_param(p, &self.parameters()))
    }

    fn set_param(&mut self, p: &Param, value: f64) -> Result<()> {
        match p {
            Param::Element { .. } => {
                let (e, i) = find_element_param(&self.elements, p)
                    .ok_or_else(|| unknown_param(p, &self.parameters()))?;
                self.elements[e].set_param(i, value)
            }
            Param::GroupStiffness(g) | Param::GroupMass(g) => {
                let stiff = matches!(p, Param::GroupStiffness(_));
                let i = self
                    .group_index(g)
                    .filter(|&i| {
                        let gr = &self.groups[i];
                        if stiff {
                            gr.stiffness.is_some()
                        } else {
                            gr.mass.is_some()
                        }
                    })
                    .ok_or_else(|| unknown_param(p, &self.parameters()))?;
                check_scale(p, value)?;
                if stiff {
                    self.groups[i].k_scale = value;
                } else {
                    self.groups[i].m_scale = value;
                }
                self.rebuild()
            }
            Param::BoundarySpring(d) => {
                let i = self
                    .spring_index(d)
                    .ok_or_else(|| unknown_param(p, &self.parameters()))?;
                check_spring(p, value)?;
                self.springs[i].1 = value;
                self.rebuild()
            }
            _ => Err(unknown_param(p, &self.parameters())),
        }
    }
}

/// Builds a [`Model`] part by part and validates it once at the end
/// ([`Model::builder`]). The first error met is returned by [`ModelBuilder::build`].
#[derive(Debug)]
#[must_use = "a builder does nothing until build() is called"]
pub struct ModelBuilder {
    model: Result<Model>,
    validation: Option<ValidationConfig>,
}

impl ModelBuilder {
    fn with(mut self, f: impl FnOnce(&mut Model) -> Result<()>) -> Self {
        if let Ok(m) = &mut self.model
            && let Err(e) = f(m)
        {
            self.model = Err(e);
        }
        self
    }

    /// Sets the damping model.
    pub fn damping(self, damping: Damping) -> Self {
        self.with(|m| m.set_damping(damping))
    }

    /// Adds a nonlinear element.
    pub fn element(self, element: NonlinearElement) -> Self {
        self.with(|m| m.add_element(element))
    }

    /// Adds an excitation point: `amplitude` (N) at the DOF or point labelled `dof` (e.g.
    /// `"2:ux"`; see [`Model::site`]).
    pub fn excitation(self, name: &str, dof: &str, amplitude: f64) -> Self {
        self.with(|m| {
            let at = m.site(dof)?;
            m.add_excitation(Excitation {
                name: name.into(),
                at,
                amplitude,
                harmonics: Vec::new(),
            })
        })
    }

    /// Adds a sensor measuring `quantity` at the DOF or point labelled `dof`.
    pub fn sensor(self, name: &str, dof: &str, quantity: Quantity) -> Self {
        self.with(|m| {
            let at = m.site(dof)?;
            m.add_sensor(Sensor {
                name: name.into(),
                at,
                quantity,
            })
        })
    }

    /// Declares a labelled element group (see [`Model::add_group`]).
    pub fn group(self, name: &str, stiffness: Option<SparseSym>, mass: Option<SparseSym>) -> Self {
        self.with(|m| m.add_group(name, stiffness, mass))
    }

    /// Adds a grounded spring (see [`Model::add_boundary_spring`]) at the DOF labelled `dof`.
    pub fn boundary_spring(self, dof: &str, k: f64) -> Self {
        self.with(|m| {
            let d = m.dofs.find(dof)?;
            m.add_boundary_spring(d, k)
        })
    }

    /// The checks run by [`ModelBuilder::build`] (default: [`ValidationConfig::default`]);
    /// `None` skips validation.
    pub fn validation(mut self, cfg: Option<ValidationConfig>) -> Self {
        self.validation = cfg;
        self
    }

    /// The model, validated.
    pub fn build(self) -> Result<Model> {
        let model = self.model?;
        if let Some(cfg) = &self.validation {
            model.validate(cfg)?;
        }
        Ok(model)
    }
}

/// Negative mass diagonals, described: how many DOFs, which (`describe` names DOF `i`),
/// whether their stiffness diagonals are negative too, and whether the block they form is
/// coupled to the other DOFs in `K` or `M`. An uncoupled block with negative mass and
/// stiffness diagonals (an acoustic fluid in pressure form written with the opposite sign, as
/// some matrix collections store it) has the spectrum of the block negated, and the message
/// says to negate it; anything else is an indefinite mass matrix. `None` when no mass
/// diagonal is negative.
pub fn mass_sign_error(
    k: &SparseSym,
    m: &SparseSym,
    describe: impl Fn(usize) -> String,
) -> Option<Error> {
    let md = m.diag();
    let negative: Vec<usize> = (0..md.len()).filter(|&i| md[i] < 0.0).collect();
    if negative.is_empty() {
        return None;
    }
    let kd = k.diag();
    let mut inside = vec![false; md.len()];
    for &i in &negative {
        inside[i] = true;
    }
    let k_negative = negative.iter().filter(|&&i| kd[i] < 0.0).count();
    let coupled = [k, m].iter().any(|a| {
        a.entries()
            .any(|(i, j, v)| v != 0.0 && inside[i] != inside[j])
    });
    let listed: Vec<String> = negative.iter().take(10).map(|&i| describe(i)).collect();
    let more = if negative.len() > 10 {
        format!(", … {} more", negative.len() - 10)
    } else {
        String::new()
    };
    let detail = if k_negative == negative.len() && !coupled {
        format!(
            "their stiffness diagonals are negative too and they form a block not coupled to \
             the other {} DOFs: a block written with the opposite sign (an acoustic fluid in \
             pressure form, say). Its eigenvalues are those of the block negated; negate its \
             rows and columns of K and M (nlsim does not change signs silently)",
            md.len() - negative.len()
        )
    } else {
        format!(
            "{k_negative} of them have negative stiffness diagonals, and the block they form is \
             {}coupled to the other DOFs: the pencil is not a structural one (a mass matrix must \
             be positive definite); check the matrix signs and units",
            if coupled { "" } else { "not " }
        )
    };
    Some(Error::NegativeMassDofs {
        count: negative.len(),
        listed: listed.join(", ") + &more,
        detail,
    })
}
