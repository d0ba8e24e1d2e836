//! The simulated plant: the diagonal modal system of the reduced model, the nonlinear
//! elements fed back at their ports, the excitation inputs and the requested outputs.

use faer::c64;
use nlsim_kernel::param::{element_param, element_parameters, set_element_param};
use nlsim_kernel::{Error, Law, Model, NonlinearElement, Param, Parameterized, Quantity, Result};
use nlsim_reduction::ModalSystem;

/// A nonlinear element fed back at a port of the modal system: one coordinate of its law.
///
/// A one-coordinate law is one entry (`coordinate` 0). A law on `m` coordinates
/// ([`Law::CoupledPolynomial`]) is `m` consecutive entries with coordinates `0..m`, each at the
/// port of its coordinate and each holding the whole element: the integrators evaluate the law
/// once for the group and feed force `g_j` back at coordinate `j`'s port. Build them with
/// [`PlantBuilder::coupled_element`] or [`Plant::from_model`].
#[derive(Debug, Clone)]
pub struct ElementPort {
    /// The element (its coupling is already folded into the port).
    pub element: NonlinearElement,
    /// Port index in [`ModalSystem::ports`].
    pub port: usize,
    /// The coordinate of the element's law at this port (0 for a one-coordinate law).
    pub coordinate: usize,
}

impl ElementPort {
    /// A one-coordinate element at `port`.
    pub fn new(element: NonlinearElement, port: usize) -> Self {
        ElementPort {
            element,
            port,
            coordinate: 0,
        }
    }

    /// The name of this entry's coordinate: the element's name, with `[j]` (from 1) for a law
    /// on several coordinates (as [`nlsim_reduction::modal::element_port_name`] names the ports).
    pub fn coordinate_name(&self) -> String {
        nlsim_reduction::modal::element_port_name(&self.element, self.coordinate)
    }
}

/// A requested output: a quantity at a port.
#[derive(Debug, Clone, PartialEq)]
pub struct OutputSpec {
    /// Name (the sensor's name for model sensors).
    pub name: String,
    /// Port index in [`ModalSystem::ports`].
    pub port: usize,
    /// Displacement (m), velocity (m/s) or acceleration (m/s²).
    pub quantity: Quantity,
}

/// The plant of a time simulation (thesis eq. 10 in diagonal coordinates).
#[derive(Debug, Clone)]
pub struct Plant {
    /// The diagonal modal system (poles, `b̃`, `c̃`, feedthrough).
    pub system: ModalSystem,
    /// Nonlinear elements and their ports.
    pub elements: Vec<ElementPort>,
    /// Excitation inputs: `(name, port index)`; a load case gives one force signal each.
    pub inputs: Vec<(String, usize)>,
    /// Outputs written at every sample.
    pub outputs: Vec<OutputSpec>,
}

/// Checks that a plant's element entries come in whole groups: a one-coordinate law as one
/// entry with coordinate 0, a law on `m` coordinates as `m` consecutive entries of the same
/// element with coordinates `0..m`.
fn check_groups(elements: &[ElementPort]) -> Result<()> {
    let mut i = 0;
    while i < elements.len() {
        let e = &elements[i].element;
        let m = e.law().arity();
        let what = || format!("element '{}'", e.name());
        if elements[i].coordinate != 0 {
            return Err(Error::invalid(
                what(),
                format!(
                    "entry {} starts a group at coordinate {} (each element's entries start at \
                     coordinate 0)",
                    i + 1,
                    elements[i].coordinate
                ),
            ));
        }
        if i + m > elements.len() {
            return Err(Error::invalid(
                what(),
                format!(
                    "its {} law acts on {m} coordinates but the plant has {} entries for it \
                     (use PlantBuilder::coupled_element with one port per coordinate)",
                    e.law().kind(),
                    elements.len() - i
                ),
            ));
        }
        for j in 1..m {
            let x = &elements[i + j];
            if x.coordinate != j || x.element != *e {
                return Err(Error::invalid(
                    what(),
                    format!(
                        "its {} law acts on {m} coordinates: entries {}..{} must hold it at \
                         coordinates 1..{m} in order (use PlantBuilder::coupled_element)",
                        e.law().kind(),
                        i + 1,
                        i + m
                    ),
                ));
            }
        }
        i += m;
    }
    Ok(())
}

/// Sets element parameter `p` on every entry of its element (a coupled element has one entry
/// per coordinate), with the law's range checks.
pub(crate) fn set_entry_param(elements: &mut [ElementPort], p: &Param, value: f64) -> Result<()> {
    set_element_param(elements, p, value)?;
    if let Param::Element { element, .. } = p
        && let Some(first) = elements.iter().position(|e| e.element.name() == element)
    {
        let e = elements[first].element.clone();
        for x in &mut elements[first + 1..] {
            if x.element.name() == element {
                x.element = e.clone();
            }
        }
    }
    Ok(())
}

impl Plant {
    /// The plant of `model` reduced to `system`: the model's elements (matched to their ports
    /// by name), its excitation points as inputs, and its sensors as outputs.
    pub fn from_model(model: &Model, system: &ModalSystem) -> Result<Self> {
        let map = nlsim_reduction::model_port_map(model, &system.ports)?;
        let elements = model
            .elements()
            .iter()
            .zip(map.element_coordinates)
            .flat_map(|(e, ports)| {
                ports
                    .into_iter()
                    .enumerate()
                    .map(|(coordinate, port)| ElementPort {
                        element: e.clone(),
                        port,
                        coordinate,
                    })
            })
            .collect();
        let outputs = map
            .sensors
            .into_iter()
            .map(|(name, port, quantity)| OutputSpec {
                name,
                port,
                quantity,
            })
            .collect();
        let inputs = map.inputs;
        Self::new(system.clone(), elements, inputs, outputs)
    }

    /// A plant from its parts; checks port indices and element parameters.
    pub fn new(
        system: ModalSystem,
        elements: Vec<ElementPort>,
        inputs: Vec<(String, usize)>,
        outputs: Vec<OutputSpec>,
    ) -> Result<Self> {
        let np = system.ports.len();
        let check = |what: String, p: usize| {
            if p >= np {
                Err(Error::invalid(
                    what,
                    format!("port index {p} is out of range (the system has {np} ports)"),
                ))
            } else {
                Ok(())
            }
        };
        for e in &elements {
            check(format!("element '{}'", e.element.name()), e.port)?;
            e.element.law().validate(e.element.name())?;
        }
        check_groups(&elements)?;
        for (name, p) in &inputs {
            check(format!("input '{name}'"), *p)?;
        }
        for o in &outputs {
            check(format!("output '{}'", o.name), o.port)?;
        }
        if let Some(s) = system
            .poles
            .iter()
            .position(|l| !(l.re.is_finite() && l.im.is_finite()) || l.re > 0.0)
        {
            return Err(Error::invalid(
                "modal system",
                format!(
                    "state {} has pole {} (unstable or not finite)",
                    s + 1,
                    system.poles[s]
                ),
            ));
        }
        Ok(Plant {
            system,
            elements,
            inputs,
            outputs,
        })
    }

    /// A builder on `system`: `Plant::builder(sys).element(e, port).input("f", 0).build()?`.
    pub fn builder(system: ModalSystem) -> PlantBuilder {
        PlantBuilder {
            system,
            elements: Vec::new(),
            inputs: Vec::new(),
            outputs: Vec::new(),
        }
    }

    /// Number of diagonal states.
    pub fn n_states(&self) -> usize {
        self.system.n_states()
    }

    /// Index of the input named `name`.
    pub fn input_index(&self, name: &str) -> Result<usize> {
        self.inputs
            .iter()
            .position(|(n, _)| n == name)
            .ok_or_else(|| {
                Error::invalid(
                    format!("excitation '{name}'"),
                    format!(
                        "the plant's inputs are: {}",
                        self.inputs
                            .iter()
                            .map(|(n, _)| n.as_str())
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            })
    }

    /// True when an element has a kink that the integrators treat as an event (clearance).
    pub fn has_events(&self) -> bool {
        self.elements
            .iter()
            .any(|e| matches!(e.element.law(), Law::Clearance { .. }))
    }

    /// The port index of every force input in global input order: excitation inputs first,
    /// then element ports.
    pub(crate) fn input_ports(&self) -> Vec<usize> {
        self.inputs
            .iter()
            .map(|(_, p)| *p)
            .chain(self.elements.iter().map(|e| e.port))
            .collect()
    }

    /// `Σ_s w_s Re(c̃_{p,s} λ_s^o z_s)`: the modal part of the response of port `port` (index
    /// in the system's ports) for diagonal states `z`, `o` = 0, 1, 2 for displacement, velocity,
    /// acceleration. The feedthrough of the port forces is not included.
    pub fn modal_response(&self, port: usize, quantity: Quantity, z: &[c64]) -> f64 {
        let sys = &self.system;
        let order = order(quantity);
        (0..sys.n_states())
            .map(|s| {
                sys.weights[s] * (sys.output[(port, s)] * sys.poles[s].powi(order as i32) * z[s]).re
            })
            .sum()
    }

    /// Static flexibility of port `p` (m/N): the receptance at zero frequency,
    /// `Σ_s w Re(c̃ b̃ / (−λ)) + D`; infinite with a rigid-body mode.
    pub fn static_flexibility(&self, p: usize) -> f64 {
        let sys = &self.system;
        let mut f = sys.feedthrough[(p, p)];
        for s in 0..sys.n_states() {
            if sys.poles[s].norm() == 0.0 {
                return f64::INFINITY;
            }
            f += sys.weights[s] * (sys.output[(p, s)] * sys.input[(s, p)] / (-sys.poles[s])).re;
        }
        f
    }

    /// Feedthrough of port force `q` into the `order`-th derivative of port `p`'s response:
    /// `D` for displacement, `Σ w Re(c̃ b̃)` (zero for a mechanical system) for velocity and
    /// `Σ w Re(c̃ λ b̃) = Φ_P Φ_Pᵀ` for acceleration.
    pub(crate) fn feedthrough(&self, p: usize, q: usize, order: u32) -> f64 {
        let sys = &self.system;
        if order == 0 {
            return sys.feedthrough[(p, q)];
        }
        (0..sys.n_states())
            .map(|s| {
                sys.weights[s]
                    * (sys.output[(p, s)] * sys.poles[s].powi(order as i32 - 1) * sys.input[(s, q)])
                        .re
            })
            .sum()
    }
}

/// The port responses the integrators evaluate: rows `(port, order)` for the element
/// displacements, the element velocities and the outputs, in that order; their modal
/// coefficients `w_s c̃_{p,s} λ_s^order` (rows × states) and feedthrough of the port forces
/// (rows × inputs, inputs = excitations then elements); and the loop sensitivities of the
/// element rows to the element forces through the feedthrough alone.
#[derive(Debug, Clone)]
pub(crate) struct Responses {
    /// Port of every force input: excitations, then elements.
    pub ports: Vec<usize>,
    pub rows: Vec<(usize, u32)>,
    pub row_c: Vec<c64>,
    pub feed: Vec<f64>,
    pub sd0: Vec<f64>,
    pub sv0: Vec<f64>,
    ns: usize,
    ne: usize,
}

impl Responses {
    pub fn new(plant: &Plant) -> Self {
        let sys = &plant.system;
        let ns = sys.n_states();
        let ne = plant.inputs.len();
        let nn = plant.elements.len();
        let nq = ne + nn;
        let ports = plant.input_ports();
        let mut rows: Vec<(usize, u32)> = plant.elements.iter().map(|e| (e.port, 0)).collect();
        rows.extend(plant.elements.iter().map(|e| (e.port, 1)));
        rows.extend(plant.outputs.iter().map(|o| (o.port, order(o.quantity))));
        let mut row_c = Vec::with_capacity(rows.len() * ns);
        let mut feed = Vec::with_capacity(rows.len() * nq);
        for &(p, o) in &rows {
            for s in 0..ns {
                row_c.push(sys.output[(p, s)] * sys.poles[s].powi(o as i32) * sys.weights[s]);
            }
            feed.extend(ports.iter().map(|&q| plant.feedthrough(p, q, o)));
        }
        let sens = |first_row: usize| -> Vec<f64> {
            (0..nn * nn)
                .map(|im| feed[(first_row + im / nn) * nq + ne + im % nn])
                .collect()
        };
        let (sd0, sv0) = (sens(0), sens(nn));
        Responses {
            ports,
            rows,
            row_c,
            feed,
            sd0,
            sv0,
            ns,
            ne,
        }
    }

    /// Modal coefficients of row `r`.
    pub fn coefficients(&self, r: usize) -> &[c64] {
        &self.row_c[r * self.ns..(r + 1) * self.ns]
    }

    /// `Σ_s Re(row_c z_s)`: the modal part of row `r` for states `z`.
    pub fn modal(&self, r: usize, z: &[c64]) -> f64 {
        self.coefficients(r)
            .iter()
            .zip(z)
            .map(|(c, z)| (c * z).re)
            .sum()
    }

    /// Feedthrough of the first `u.len()` inputs into row `r`.
    pub fn feed(&self, r: usize, u: &[f64]) -> f64 {
        let nq = self.ports.len();
        self.feed[r * nq..r * nq + u.len()]
            .iter()
            .zip(u)
            .map(|(f, u)| f * u)
            .sum()
    }

    /// Feedthrough of the excitation inputs `e` into row `r`.
    pub fn feed_ext(&self, r: usize, e: &[f64]) -> f64 {
        self.feed(r, &e[..self.ne])
    }
}

/// Response order of a quantity: 0 displacement, 1 velocity, 2 acceleration.
pub(crate) fn order(q: Quantity) -> u32 {
    match q {
        Quantity::Displacement => 0,
        Quantity::Velocity => 1,
        Quantity::Acceleration => 2,
    }
}

impl AsRef<NonlinearElement> for ElementPort {
    fn as_ref(&self) -> &NonlinearElement {
        &self.element
    }
}

impl AsMut<NonlinearElement> for ElementPort {
    fn as_mut(&mut self) -> &mut NonlinearElement {
        &mut self.element
    }
}

/// The element law parameters of the plant (`element.param`). Its modal system is fixed:
/// modal parameters are set on the reduced model before the plant is built.
impl Parameterized for Plant {
    fn parameters(&self) -> Vec<Param> {
        // A coupled element's parameters once (its first entry).
        let first: Vec<&ElementPort> = self.elements.iter().filter(|e| e.coordinate == 0).collect();
        element_parameters(&first)
    }

    fn param(&self, p: &Param) -> Result<f64> {
        element_param(&self.elements, p)
    }

    fn set_param(&mut self, p: &Param, value: f64) -> Result<()> {
        set_entry_param(&mut self.elements, p, value)
    }
}

/// Assembles a [`Plant`] part by part ([`Plant::builder`]); validated by
/// [`PlantBuilder::build`].
#[derive(Debug, Clone)]
#[must_use = "a builder does nothing until build() is called"]
pub struct PlantBuilder {
    system: ModalSystem,
    elements: Vec<ElementPort>,
    inputs: Vec<(String, usize)>,
    outputs: Vec<OutputSpec>,
}

impl PlantBuilder {
    /// A nonlinear element with a one-coordinate law fed back at port `port`.
    pub fn element(mut self, element: NonlinearElement, port: usize) -> Self {
        self.elements.push(ElementPort::new(element, port));
        self
    }

    /// A nonlinear element whose law acts on several coordinates ([`Law::arity`] of them),
    /// coordinate `j` at port `ports[j]`: force `g_j(u)` is fed back at `ports[j]`. A count
    /// of ports other than the arity is an error of [`PlantBuilder::build`].
    pub fn coupled_element(mut self, element: NonlinearElement, ports: &[usize]) -> Self {
        for (coordinate, &port) in ports.iter().enumerate() {
            self.elements.push(ElementPort {
                element: element.clone(),
                port,
                coordinate,
            });
        }
        self
    }

    /// An excitation input `name` at port `port`.
    pub fn input(mut self, name: impl Into<String>, port: usize) -> Self {
        self.inputs.push((name.into(), port));
        self
    }

    /// An output: `quantity` at port `port`.
    pub fn output(mut self, name: impl Into<String>, port: usize, quantity: Quantity) -> Self {
        self.outputs.push(OutputSpec {
            name: name.into(),
            port,
            quantity,
        });
        self
    }

    /// The validated plant.
    pub fn build(self) -> Result<Plant> {
        Plant::new(self.system, self.elements, self.inputs, self.outputs)
    }
}
