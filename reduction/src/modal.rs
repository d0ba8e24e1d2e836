//! The reduced model: modes, ports (where forces enter and responses are read), and the
//! residual flexibility of the truncated modes at those ports.
//!
//! A *port* is a generalized coordinate `u = wᵀ q`: one DOF, the relative motion of two DOFs
//! (a nonlinear element between them), or a weighted direction. A force `g` on the port acts on
//! the structure as `g w`. Inputs (excitation, element forces) and outputs (sensors, element
//! coordinates) are all ports, so one symmetric matrix holds every feedthrough term.
//!
//! Residual flexibility (the static contribution of the modes left out):
//!
//! `R = Wᵀ (K − σM)⁻¹ W − Φ_Pᵀ diag(1 / (λ_r − σ)) Φ_P = Σ_{r truncated} Φ_P,r Φ_P,rᵀ / (λ_r − σ)`
//!
//! with `Φ_P = Wᵀ Φ` the port participations, from one solve per port with the factor the eigen
//! solver already holds (`σ = 0` unless `K` is singular, then a small negative shift). It is the
//! displacement feedthrough `D_L`, `D_NL` of thesis eq. (10).

use crate::eigen::{EigenConfig, EigenProgress, EigenSolver, ModeSelection, Modes};
use faer::Mat;
use nlsim_kernel::{Component, Coupling, Damping, DofLabel, Error, Model, Result, Site};

/// What a port stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PortKind {
    /// A nonlinear element: its coordinate is an output, its force an input.
    Element,
    /// A force input point.
    Excitation,
    /// A response output point.
    Sensor,
    /// A DOF asked for explicitly.
    Dof,
}

impl PortKind {
    /// Lower-case name.
    pub fn as_str(self) -> &'static str {
        match self {
            PortKind::Element => "element",
            PortKind::Excitation => "excitation",
            PortKind::Sensor => "sensor",
            PortKind::Dof => "dof",
        }
    }
}

/// A generalized coordinate `u = Σ wᵢ q_{dofᵢ}`.
#[derive(Debug, Clone, PartialEq)]
pub struct Port {
    /// Name: the element, excitation or sensor name, or the DOF label.
    pub name: String,
    /// What it stands for.
    pub kind: PortKind,
    /// DOF indices.
    pub dofs: Vec<usize>,
    /// Weights, one per DOF (dimensionless).
    pub weights: Vec<f64>,
}

impl Port {
    /// A port on one DOF.
    pub fn dof(name: impl Into<String>, kind: PortKind, dof: usize) -> Self {
        Port {
            name: name.into(),
            kind,
            dofs: vec![dof],
            weights: vec![1.0],
        }
    }

    /// A port on an element coupling.
    pub fn coupling(name: impl Into<String>, kind: PortKind, c: &Coupling) -> Self {
        Port {
            name: name.into(),
            kind,
            dofs: c.dofs().to_vec(),
            weights: c.weights().to_vec(),
        }
    }

    /// `wᵀ x` for a vector over all DOFs.
    pub fn project(&self, x: &[f64]) -> f64 {
        self.dofs
            .iter()
            .zip(&self.weights)
            .map(|(&d, &w)| w * x[d])
            .sum()
    }
}

/// Index of the port named `name` in `ports`; the error lists the names there are.
pub fn port_index(ports: &[Port], name: &str) -> Result<usize> {
    ports.iter().position(|p| p.name == name).ok_or_else(|| {
        Error::invalid(
            "port name",
            format!(
                "no port '{name}'; the ports are: {}",
                ports
                    .iter()
                    .map(|p| p.name.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        )
    })
}

/// The name of the port of coordinate `j` (0-based) of `element`: its name, or `name[j+1]` for
/// the coordinates of a coupled law (`geometry[1]`, `geometry[2]`).
pub fn element_port_name(element: &nlsim_kernel::NonlinearElement, j: usize) -> String {
    if element.is_coupled() {
        format!("{}[{}]", element.name(), j + 1)
    } else {
        element.name().to_string()
    }
}

/// The ports of a model: its nonlinear elements (one per coordinate), excitation points and
/// sensors, in that order, then `extra_dofs`.
pub fn model_ports(model: &Model, extra_dofs: &[usize]) -> Result<Vec<Port>> {
    let mut ports = Vec::new();
    for e in model.elements() {
        for (j, c) in e.couplings().iter().enumerate() {
            ports.push(Port::coupling(
                element_port_name(e, j),
                PortKind::Element,
                c,
            ));
        }
    }
    for x in model.excitation() {
        ports.push(Port::coupling(
            &x.name,
            PortKind::Excitation,
            &x.at.coupling(),
        ));
    }
    for s in model.sensors() {
        ports.push(Port::coupling(&s.name, PortKind::Sensor, &s.at.coupling()));
    }
    for &d in extra_dofs {
        if d >= model.n_dofs() {
            return Err(Error::DofIndexOutOfRange {
                what: "extra output DOF of the reduction".into(),
                index: d,
                n: model.n_dofs(),
            });
        }
        ports.push(Port::dof(model.dofs().describe(d), PortKind::Dof, d));
    }
    Ok(ports)
}

/// Where a model's parts sit among `ports`: each element's port (checked to be an element
/// port), each excitation point's `(name, port)` and each sensor's `(name, port, quantity)`,
/// in the model's order. The simulator and the harmonic balance both start from it.
#[derive(Debug, Clone, PartialEq)]
pub struct ModelPortMap {
    /// Port of each nonlinear element (of its first coordinate for a coupled law).
    pub elements: Vec<usize>,
    /// Ports of every coordinate of each nonlinear element (one for a scalar law).
    pub element_coordinates: Vec<Vec<usize>>,
    /// `(name, port)` of each excitation point.
    pub inputs: Vec<(String, usize)>,
    /// `(name, port, quantity)` of each sensor.
    pub sensors: Vec<(String, usize, nlsim_kernel::Quantity)>,
}

/// Matches `model`'s elements, excitation points and sensors to `ports` by name.
pub fn model_port_map(model: &Model, ports: &[Port]) -> Result<ModelPortMap> {
    let element_coordinates = model
        .elements()
        .iter()
        .map(|e| {
            (0..e.couplings().len())
                .map(|j| {
                    let p = port_index(ports, &element_port_name(e, j))?;
                    if ports[p].kind != PortKind::Element {
                        return Err(Error::invalid(
                            format!("element '{}'", e.name()),
                            "its name matches a port that is not an element port",
                        ));
                    }
                    Ok(p)
                })
                .collect::<Result<Vec<_>>>()
        })
        .collect::<Result<Vec<_>>>()?;
    let elements = element_coordinates.iter().map(|c| c[0]).collect();
    let inputs = model
        .excitation()
        .iter()
        .map(|x| Ok((x.name.clone(), port_index(ports, &x.name)?)))
        .collect::<Result<Vec<_>>>()?;
    let sensors = model
        .sensors()
        .iter()
        .map(|s| Ok((s.name.clone(), port_index(ports, &s.name)?, s.quantity)))
        .collect::<Result<Vec<_>>>()?;
    Ok(ModelPortMap {
        elements,
        element_coordinates,
        inputs,
        sensors,
    })
}

/// Settings of [`reduce`].
#[derive(Debug, Clone, PartialEq)]
pub struct ReductionConfig {
    /// Which modes and how to compute them.
    pub eigen: EigenConfig,
    /// Add the residual flexibility of the truncated modes at the ports.
    pub residual_flexibility: bool,
    /// DOFs to read out besides the model's elements, excitation and sensors.
    pub extra_dofs: Vec<usize>,
}

impl ReductionConfig {
    /// The lowest `modes` modes with residual flexibility, other settings default.
    pub fn lowest(modes: usize) -> Self {
        ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(modes),
                ..EigenConfig::default()
            },
            ..ReductionConfig::default()
        }
    }
}

impl Default for ReductionConfig {
    fn default() -> Self {
        ReductionConfig {
            eigen: EigenConfig::default(),
            residual_flexibility: true,
            extra_dofs: Vec::new(),
        }
    }
}

/// A model reduced to its lowest modes plus residual flexibility at its ports.
#[derive(Debug, Clone)]
pub struct ReducedModel {
    /// The retained modes (mass-normalised).
    pub modes: Modes,
    /// The ports, in the order of the rows of [`ReducedModel::participation`].
    pub ports: Vec<Port>,
    /// `Φ_P = Wᵀ Φ`: modal participation of each port (ports × modes; m/√kg).
    pub participation: Mat<f64>,
    /// Residual flexibility of the truncated modes at the ports (ports × ports, symmetric;
    /// m/N); zero when switched off.
    pub residual: Mat<f64>,
    /// Shift `σ` (rad²/s²) at which the residual flexibility was evaluated.
    pub residual_shift: f64,
    /// The damping model of the structure.
    pub damping: Damping,
    /// Seconds spent on the residual flexibility (solves and projection).
    pub residual_seconds: f64,
    /// The measured residual flexibilities of a test-based modal model
    /// ([`Model::residual_terms`]), already added to [`ReducedModel::residual`]: kept by port
    /// so that they can be calibrated (`residual:A:B`).
    pub measured: Vec<MeasuredResidual>,
    /// The measured points of a test-based modal model and the ports on each (see
    /// [`PointPorts`]): what makes its mode-shape entries calibratable
    /// (`modeN.shape:POINT`). Empty for an FE model.
    pub points: Vec<PointPorts>,
}

/// A measured point of a test-based modal model ([`Model::points`]) and the ports that move
/// with it: port `p`'s coupling holds the point's with weight `w` (1 for a drive, sensor or
/// element on the point, −1 for the second point of a relative element).
#[derive(Debug, Clone, PartialEq)]
pub struct PointPorts {
    /// The point's label.
    pub label: DofLabel,
    /// Its mode-shape entries `(modal coordinate, φ)` (m/√kg), as the model holds them.
    pub shape: Vec<(usize, f64)>,
    /// `(port index, weight)` of every port on the point.
    pub ports: Vec<(usize, f64)>,
}

/// A measured residual flexibility between two ports of a reduced model (see
/// [`ReducedModel::measured`]).
#[derive(Debug, Clone, PartialEq)]
pub struct MeasuredResidual {
    /// Port index of the first port.
    pub a: usize,
    /// Port index of the second port (equal to `a` on a driving point).
    pub b: usize,
    /// The flexibility added to `D_ab` and `D_ba` (m/N).
    pub flexibility: f64,
}

impl ReducedModel {
    /// Index of the port named `name`.
    pub fn port_index(&self, name: &str) -> Result<usize> {
        port_index(&self.ports, name)
    }

    /// Number of retained modes.
    pub fn n_modes(&self) -> usize {
        self.modes.len()
    }

    /// The modal damping matrix `C̃ = Φᵀ V Φ` of the retained mass-normalised modes (modes ×
    /// modes; 1/s), so that each mode obeys `η̈ + C̃ η̇ + Ω² η = Φ_Pᵀ f` (thesis eq. 9 in modal
    /// coordinates). Diagonal for proportional damping: `c_r = α + β ω_r²` (Rayleigh) or
    /// `2 ζ_r ω_r` (modal); a damping matrix `V` is projected and symmetrised.
    pub fn modal_damping_matrix(&self) -> Mat<f64> {
        let m = self.n_modes();
        let lambda = &self.modes.eigenvalues;
        let diag = |c: &dyn Fn(usize, f64) -> f64| {
            Mat::from_fn(m, m, |r, s| {
                if r == s {
                    c(r, lambda[r].max(0.0))
                } else {
                    0.0
                }
            })
        };
        match &self.damping {
            Damping::None => Mat::zeros(m, m),
            Damping::Rayleigh { alpha, beta } => diag(&|_, l| alpha + beta * l),
            Damping::Modal(md) => diag(&|r, l| {
                let w = l.sqrt();
                2.0 * md.zeta(r, w / (2.0 * std::f64::consts::PI)) * w
            }),
            Damping::Matrix(v) => {
                let phi = &self.modes.vectors;
                let mut vphi = Mat::<f64>::zeros(phi.nrows(), m);
                faer::sparse::linalg::matmul::sparse_dense_matmul(
                    vphi.as_mut(),
                    faer::Accum::Replace,
                    v.as_faer(),
                    phi.as_ref(),
                    1.0,
                    faer::Par::Seq,
                );
                let vt = phi.transpose() * &vphi;
                Mat::from_fn(m, m, |r, s| 0.5 * (vt[(r, s)] + vt[(s, r)]))
            }
        }
    }

    /// Modal coordinates `η = Φᵀ M q` of a physical vector `q` (the projection onto the
    /// retained mass-normalised modes); `mass` is the model's `M`.
    pub fn modal_coordinates(&self, mass: &nlsim_kernel::SparseSym, q: &[f64]) -> Result<Vec<f64>> {
        let n = self.modes.vectors.nrows();
        if mass.n() != n || q.len() != n {
            return Err(Error::DimensionMismatch {
                what: "physical vector projected onto the modes".into(),
                expected: n,
                found: if mass.n() != n { mass.n() } else { q.len() },
            });
        }
        let mut mq = vec![0.0; n];
        mass.mul_vec(q, &mut mq);
        Ok((0..self.n_modes())
            .map(|r| (0..n).map(|i| self.modes.vectors[(i, r)] * mq[i]).sum())
            .collect())
    }
}

/// Reduces `model`: modes, ports, residual flexibility.
pub fn reduce(model: &Model, cfg: &ReductionConfig) -> Result<ReducedModel> {
    reduce_with(model, cfg, &mut EigenSolver::new(), &mut |_| {})
}

/// As [`reduce`], with a solver that keeps its symbolic analysis across calls (parameter
/// studies) and a progress callback for the eigen solve.
pub fn reduce_with(
    model: &Model,
    cfg: &ReductionConfig,
    solver: &mut EigenSolver,
    progress: &mut dyn FnMut(&EigenProgress),
) -> Result<ReducedModel> {
    let ports = model_ports(model, &cfg.extra_dofs)?;
    let modes = solver
        .solve_with_progress(model.stiffness(), model.mass(), &cfg.eigen, progress)
        .and_then(Modes::into_converged)
        .map_err(|e| name_dofs(e, model))?;
    let n_ports = ports.len();
    let n_modes = modes.len();
    let participation = Mat::from_fn(n_ports, n_modes, |p, r| {
        let port = &ports[p];
        port.dofs
            .iter()
            .zip(&port.weights)
            .map(|(&d, &w)| w * modes.vectors[(d, r)])
            .sum()
    });
    let t = std::time::Instant::now();
    let (mut residual, residual_shift) = if cfg.residual_flexibility && n_ports > 0 {
        residual_flexibility(model, solver, &modes, &ports, &participation, cfg.eigen.par)?
    } else {
        (Mat::zeros(n_ports, n_ports), 0.0)
    };
    let measured = add_measured_residual(model, &ports, &mut residual)?;
    let points = point_ports(model, &ports);
    Ok(ReducedModel {
        modes,
        ports,
        participation,
        residual,
        residual_shift,
        damping: model.damping().clone(),
        residual_seconds: t.elapsed().as_secs_f64(),
        measured,
        points,
    })
}

/// Adds a test-based modal model's measured residual flexibilities
/// ([`Model::residual_terms`]) to the ports' residual, symmetrically; a term naming a port the
/// model does not have is an error. Returns the terms by port.
pub(crate) fn add_measured_residual(
    model: &Model,
    ports: &[Port],
    residual: &mut Mat<f64>,
) -> Result<Vec<MeasuredResidual>> {
    let mut out = Vec::with_capacity(model.residual_terms().len());
    for term in model.residual_terms() {
        let a = port_index(ports, &term.a)?;
        let b = port_index(ports, &term.b)?;
        residual[(a, b)] += term.flexibility;
        if a != b {
            residual[(b, a)] += term.flexibility;
        }
        out.push(MeasuredResidual {
            a,
            b,
            flexibility: term.flexibility,
        });
    }
    Ok(out)
}

/// The ports on each measured point of a test-based modal model. A drive or sensor names its
/// point; an element's coordinate is matched to the coupling of one point, or to the
/// difference of two (as the model file builds a relative element), exactly — the same
/// arithmetic on the same numbers. Empty for an FE model, and when a port's coupling is
/// matched ambiguously (two points that move alike in every mode) or not at all while it is
/// not a modal coordinate: then no shape entry can be calibrated, rather than one that would
/// leave a port behind.
fn point_ports(model: &Model, ports: &[Port]) -> Vec<PointPorts> {
    if !model.is_modal() || model.points().is_empty() {
        return Vec::new();
    }
    let pts = model.points();
    let mut out: Vec<PointPorts> = pts
        .iter()
        .map(|(label, c)| PointPorts {
            label: *label,
            shape: c
                .dofs()
                .iter()
                .copied()
                .zip(c.weights().iter().copied())
                .collect(),
            ports: Vec::new(),
        })
        .collect();
    let by_label = |site: &Site| match site {
        Site::Point { label, .. } => pts
            .iter()
            .position(|(l, _)| l == label)
            .map(|i| vec![(i, 1.0)]),
        Site::Dof(_) => Some(Vec::new()),
    };
    let by_coupling = |c: &Coupling| -> Option<Vec<(usize, f64)>> {
        let mut found = model.point_terms(c);
        if found.is_empty() && c.dofs().len() == 1 && c.weights()[0] == 1.0 {
            return Some(Vec::new()); // a modal coordinate
        }
        (found.len() == 1).then(|| found.remove(0))
    };
    let mut k = 0;
    for e in model.elements() {
        for c in e.couplings() {
            let Some(on) = by_coupling(c) else {
                return Vec::new();
            };
            on.into_iter().for_each(|(i, w)| out[i].ports.push((k, w)));
            k += 1;
        }
    }
    for site in model
        .excitation()
        .iter()
        .map(|x| &x.at)
        .chain(model.sensors().iter().map(|s| &s.at))
    {
        let Some(on) = by_label(site) else {
            return Vec::new();
        };
        on.into_iter().for_each(|(i, w)| out[i].ports.push((k, w)));
        k += 1;
    }
    debug_assert!(k <= ports.len());
    out
}

/// Replaces `DOF index i` in an error message of the eigen solver by the DOF label.
fn name_dofs(e: Error, model: &Model) -> Error {
    let label = |listed: String| -> String {
        listed
            .split(", ")
            .map(|s| {
                s.strip_prefix("DOF index ")
                    .and_then(|i| i.parse::<usize>().ok())
                    .map_or(s.to_string(), |i| model.dofs().describe(i))
            })
            .collect::<Vec<_>>()
            .join(", ")
    };
    match e {
        Error::MasslessDofs { count, listed } => Error::MasslessDofs {
            count,
            listed: label(listed),
        },
        Error::NegativeMassDofs {
            count,
            listed,
            detail,
        } => Error::NegativeMassDofs {
            count,
            listed: label(listed),
            detail,
        },
        other => other,
    }
}

/// The port load matrix `W` (DOFs × ports): column `p` holds port `p`'s weights at its DOFs.
pub(crate) fn port_loads(n: usize, ports: &[Port]) -> Mat<f64> {
    let mut w = Mat::<f64>::zeros(n, ports.len());
    for (p, port) in ports.iter().enumerate() {
        for (&d, &wt) in port.dofs.iter().zip(&port.weights) {
            w[(d, p)] += wt;
        }
    }
    w
}

fn residual_flexibility(
    model: &Model,
    solver: &EigenSolver,
    modes: &Modes,
    ports: &[Port],
    participation: &Mat<f64>,
    par: faer::Par,
) -> Result<(Mat<f64>, f64)> {
    let w = port_loads(model.n_dofs(), ports);
    // The eigen solve's factor when it ran Lanczos (again at its shift when released under
    // its memory budget); otherwise a factor made here (small models).
    let (mut own, mut own_factor) = (None, None);
    let (pencil, factor) = solver.operator(
        model.stiffness(),
        model.mass(),
        par,
        &mut own,
        &mut own_factor,
    )?;
    let sigma = factor.shift();
    let mut x = w.clone();
    pencil.solve_in_place(factor, x.as_mut());
    let mut r = w.transpose() * &x;
    for r_mode in 0..modes.len() {
        let s = 1.0 / (modes.eigenvalues[r_mode] - sigma);
        for a in 0..ports.len() {
            for b in 0..ports.len() {
                r[(a, b)] -= participation[(a, r_mode)] * participation[(b, r_mode)] * s;
            }
        }
    }
    // Symmetrise against round-off.
    let rs = Mat::from_fn(ports.len(), ports.len(), |a, b| {
        0.5 * (r[(a, b)] + r[(b, a)])
    });
    Ok((rs, sigma))
}

/// Effective modal masses in one translational direction.
#[derive(Debug, Clone, PartialEq)]
pub struct EffectiveMass {
    /// The direction (`ux`, `uy`, `uz`, or `u` for scalar models).
    pub component: Component,
    /// `Γ_r² = (φ_rᵀ M r)²` per retained mode (kg), `r` the unit rigid translation.
    pub per_mode: Vec<f64>,
    /// `rᵀ M r` (kg): the sum over all modes.
    pub total: f64,
}

/// Effective masses of `modes` in every translational direction the model has.
pub fn effective_masses(model: &Model, modes: &Modes) -> Vec<EffectiveMass> {
    let n = model.n_dofs();
    let mut out = Vec::new();
    for comp in [Component::Ux, Component::Uy, Component::Uz, Component::U] {
        let r: Vec<f64> = (0..n)
            .map(|i| f64::from(u8::from(model.dofs().label(i).component == comp)))
            .collect();
        if r.iter().all(|&v| v == 0.0) {
            continue;
        }
        let mut mr = vec![0.0; n];
        model.mass().mul_vec(&r, &mut mr);
        let total: f64 = r.iter().zip(&mr).map(|(a, b)| a * b).sum();
        let per_mode = (0..modes.len())
            .map(|c| {
                let g: f64 = (0..n).map(|i| modes.vectors[(i, c)] * mr[i]).sum();
                g * g
            })
            .collect();
        out.push(EffectiveMass {
            component: comp,
            per_mode,
            total,
        });
    }
    out
}

/// Viscous damping ratio `ζ_r` of each mode: exact for proportional damping
/// (`α/(2ω) + βω/2`, or the modal table), and `φ_rᵀ V φ_r / (2 ω_r)` for an explicit matrix
/// (the diagonal of the modal damping matrix; the off-diagonal coupling is left out). A
/// rigid-body mode (`ω_r = 0`) gets 0 when its modal damping `φ_rᵀ C φ_r` is 0 (no damping, or
/// stiffness-proportional damping only) and `+∞` otherwise (`c / (2ω) → ∞`).
pub fn damping_ratios(modes: &Modes, damping: &Damping) -> Vec<f64> {
    let omega = modes.omega();
    (0..modes.len())
        .map(|r| {
            let w = omega[r];
            let c = match damping {
                Damping::None => 0.0,
                Damping::Rayleigh { alpha, beta } => alpha + beta * w * w,
                Damping::Modal(md) => return md.zeta(r, w / (2.0 * std::f64::consts::PI)),
                Damping::Matrix(v) => {
                    let col: Vec<f64> = (0..modes.vectors.nrows())
                        .map(|i| modes.vectors[(i, r)])
                        .collect();
                    v.bilinear(&col, &col)
                }
            };
            if w > 0.0 {
                c / (2.0 * w)
            } else if c == 0.0 {
                0.0
            } else {
                f64::INFINITY
            }
        })
        .collect()
}
