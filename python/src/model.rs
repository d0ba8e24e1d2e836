//! `nlsim.Model`: a structure `M ü + V u̇ + K u + g(u, u̇) = f` (thesis eq. 1–7) built from CSR
//! arrays (scipy.sparse), loaded from a model file or a built-in name, and edited the way the
//! C ABI and the model files do: damping, nonlinear elements, excitation points and sensors
//! by DOF label, parameters read and set by their text form.

use crate::{input, kernel_err, py_err};
use nlsim::kernel::faer::sparse::{SparseColMat, SymbolicSparseColMat};
use nlsim::kernel::{
    Coupling, Damping, DofLabel, DofMap, Excitation, Law, NonlinearElement, Parameterized,
    Quantity, Sensor, SparseSym, ValidationConfig,
};
use numpy::PyReadonlyArray1;
use pyo3::prelude::*;

/// Most DOFs a model built from arrays may have (as the C ABI).
const MAX_DOFS: usize = 50_000_000;

/// A model: mass, stiffness and damping, nonlinear elements, excitation points and sensors.
#[pyclass(module = "nlsim._native", name = "Model", from_py_object)]
#[derive(Clone)]
pub struct Model {
    pub(crate) inner: nlsim::kernel::Model,
    /// Where it came from: the model file or built-in spec, or `arrays`.
    pub(crate) source: String,
}

/// An index array of a CSR matrix as `usize`, from int32 or int64 numpy arrays.
fn indices(arg: &str, a: &Bound<'_, PyAny>) -> PyResult<Vec<usize>> {
    let convert = |v: &[i64]| -> PyResult<Vec<usize>> {
        v.iter()
            .enumerate()
            .map(|(i, &x)| {
                usize::try_from(x).map_err(|_| input(format!("{arg}[{i}] is {x}, negative")))
            })
            .collect()
    };
    if let Ok(a) = a.extract::<PyReadonlyArray1<'_, i64>>() {
        return convert(a.as_slice().map_err(|e| input(format!("{arg}: {e}")))?);
    }
    if let Ok(a) = a.extract::<PyReadonlyArray1<'_, i32>>() {
        let s = a.as_slice().map_err(|e| input(format!("{arg}: {e}")))?;
        return s
            .iter()
            .enumerate()
            .map(|(i, &x)| {
                usize::try_from(x).map_err(|_| input(format!("{arg}[{i}] is {x}, negative")))
            })
            .collect();
    }
    Err(input(format!(
        "{arg}: expected a one-dimensional int32 or int64 numpy array"
    )))
}

/// A symmetric matrix of order `n` from its CSR arrays. A symmetric matrix's CSR arrays are
/// its CSC arrays, so they become nlsim's compressed columns with one copy of the indices
/// (as `usize`) and of the values; a matrix that is not symmetric is refused later by the
/// model's check, which names the entry.
fn csr_matrix(
    name: &str,
    n: usize,
    indptr: &Bound<'_, PyAny>,
    idx: &Bound<'_, PyAny>,
    data: PyReadonlyArray1<'_, f64>,
) -> PyResult<SparseSym> {
    let ptr = indices(&format!("{name}.indptr"), indptr)?;
    let rows = indices(&format!("{name}.indices"), idx)?;
    let vals = data
        .as_slice()
        .map_err(|e| input(format!("{name}.data: {e}")))?;
    if ptr.len() != n + 1 {
        return Err(input(format!(
            "{name}: indptr has {} entries; a {n} x {n} matrix has {}",
            ptr.len(),
            n + 1
        )));
    }
    if ptr[0] != 0 {
        return Err(input(format!("{name}: indptr[0] is {}, not 0", ptr[0])));
    }
    if let Some(i) = (0..n).find(|&i| ptr[i + 1] < ptr[i]) {
        return Err(input(format!(
            "{name}: indptr decreases at row {i} ({} then {})",
            ptr[i],
            ptr[i + 1]
        )));
    }
    if ptr[n] != rows.len() || rows.len() != vals.len() {
        return Err(input(format!(
            "{name}: indptr ends at {}, indices has {} entries and data {}; all three must agree",
            ptr[n],
            rows.len(),
            vals.len()
        )));
    }
    if let Some(p) = rows.iter().position(|&r| r >= n) {
        return Err(input(format!(
            "{name}: indices[{p}] is {}, outside a {n} x {n} matrix",
            rows[p]
        )));
    }
    if let Some(p) = vals.iter().position(|v| !v.is_finite()) {
        let row = ptr.partition_point(|&q| q <= p) - 1;
        return Err(input(format!(
            "{name}: entry ({row}, {}) is {}, not a finite number",
            rows[p], vals[p]
        )));
    }
    let symbolic = SymbolicSparseColMat::new_unsorted_checked(n, n, ptr, None, rows);
    SparseSym::from_faer(name, SparseColMat::new(symbolic, vals.to_vec())).map_err(kernel_err)
}

impl Model {
    /// The DOF labels as text, in the order of the matrices' rows.
    pub(crate) fn dofs_text(&self) -> Vec<String> {
        self.inner
            .dofs()
            .labels()
            .iter()
            .map(ToString::to_string)
            .collect()
    }

    fn dof(&self, arg: &str, label: &str) -> PyResult<usize> {
        self.inner
            .dofs()
            .find(label)
            .map_err(|e| input(format!("{arg}: {e}")))
    }

    /// The site a label names: a DOF, or a point (or `modeN`) of a test-based modal model.
    fn site(&self, arg: &str, label: &str) -> PyResult<nlsim::kernel::Site> {
        self.inner
            .site(label)
            .map_err(|e| input(format!("{arg}: {e}")))
    }

    fn param(&self, name: &str) -> PyResult<nlsim::kernel::Param> {
        nlsim::kernel::param::parse_known(name, &self.inner.parameters()).map_err(kernel_err)
    }
}

#[pymethods]
impl Model {
    /// Loads a model file (`.toml`, as `nlsim` reads it) or a built-in model by name
    /// (`"ecl_beam"`, `"bracket:dofs=20000"`; see `builtin_models()`).
    #[staticmethod]
    fn load(py: Python<'_>, spec: &str) -> PyResult<Model> {
        let spec = spec.to_string();
        let loaded = py.detach(|| nlsim::load_model(&spec)).map_err(py_err)?;
        Ok(Model {
            inner: loaded.model,
            source: spec,
        })
    }

    /// A model from the CSR arrays of its mass and stiffness matrices (`Model.from_matrices`
    /// passes scipy.sparse matrices here). `dofs`: one label `NODE:COMPONENT` per DOF
    /// (`"12:uz"`), or `None` for `1:u` … `n:u`. The matrices are checked (symmetric, finite,
    /// positive mass); the model has no damping, elements, excitation or sensors yet.
    #[staticmethod]
    #[pyo3(signature = (name, n, m_indptr, m_indices, m_data, k_indptr, k_indices, k_data, dofs=None))]
    #[allow(clippy::too_many_arguments)]
    fn from_csr(
        name: &str,
        n: usize,
        m_indptr: &Bound<'_, PyAny>,
        m_indices: &Bound<'_, PyAny>,
        m_data: PyReadonlyArray1<'_, f64>,
        k_indptr: &Bound<'_, PyAny>,
        k_indices: &Bound<'_, PyAny>,
        k_data: PyReadonlyArray1<'_, f64>,
        dofs: Option<Vec<String>>,
    ) -> PyResult<Model> {
        if n == 0 || n > MAX_DOFS {
            return Err(input(format!(
                "M, K: order {n}; a model has 1 to {MAX_DOFS} DOFs"
            )));
        }
        let dofs = match dofs {
            None => DofMap::scalar(n),
            Some(labels) => {
                if labels.len() != n {
                    return Err(input(format!(
                        "dofs: {} labels for a model of {n} DOFs",
                        labels.len()
                    )));
                }
                let parsed = labels
                    .iter()
                    .enumerate()
                    .map(|(i, l)| {
                        l.parse::<DofLabel>()
                            .map_err(|e| input(format!("dofs[{i}]: {e}")))
                    })
                    .collect::<PyResult<Vec<_>>>()?;
                DofMap::new(parsed).map_err(|e| input(format!("dofs: {e}")))?
            }
        };
        let m = csr_matrix("M", n, m_indptr, m_indices, m_data)?;
        let k = csr_matrix("K", n, k_indptr, k_indices, k_data)?;
        let model = nlsim::kernel::Model::new(name, dofs, m, k).map_err(kernel_err)?;
        model
            .validate(&ValidationConfig {
                check_definiteness: false,
                ..Default::default()
            })
            .map_err(|e| match e {
                // The matrices were read as the transposes of the CSR arrays given: name
                // the entries as the caller stored them.
                nlsim::kernel::Error::NotSymmetric {
                    matrix,
                    row,
                    col,
                    a_ij,
                    a_ji,
                    rel_diff,
                    tolerance,
                } => kernel_err(nlsim::kernel::Error::NotSymmetric {
                    matrix,
                    row: col,
                    col: row,
                    a_ij,
                    a_ji,
                    rel_diff,
                    tolerance,
                }),
                other => kernel_err(other),
            })?;
        Ok(Model {
            inner: model,
            source: "arrays".into(),
        })
    }

    /// Rayleigh damping `V = alpha M + beta K` (`alpha` in 1/s, `beta` in s; thesis eq. 2).
    fn set_rayleigh(&mut self, alpha: f64, beta: f64) -> PyResult<()> {
        self.inner
            .set_damping(Damping::Rayleigh { alpha, beta })
            .map_err(kernel_err)
    }

    /// The same modal damping ratio `zeta` (dimensionless, e.g. 0.01) on every mode.
    fn set_modal_damping(&mut self, zeta: f64) -> PyResult<()> {
        self.inner
            .set_damping(Damping::Modal(
                nlsim::kernel::damping::ModalDamping::uniform(zeta),
            ))
            .map_err(kernel_err)
    }

    /// Adds a nonlinear element `name` with `law` as the model files write it (`"cubic
    /// k3=1.7e15"`, `"clearance k1=5e5 e1=1e-3 k2=5e5 e2=2e-3"`, `"jenkins kt=1e5 fs=20"`)
    /// on DOF `dof` (a label), or between `dof` and `dof2`. Its parameters are then
    /// `NAME.KEY`.
    #[pyo3(signature = (name, law, dof, dof2=None))]
    fn add_element(
        &mut self,
        name: &str,
        law: &str,
        dof: &str,
        dof2: Option<&str>,
    ) -> PyResult<()> {
        let a = self.dof("dof", dof)?;
        let coupling = match dof2 {
            None => Coupling::single(a),
            Some(l) => {
                let b = self.dof("dof2", l)?;
                if b == a {
                    return Err(input(format!("element '{name}': dof2 {l} is dof itself")));
                }
                Coupling::relative(a, b)
            }
        };
        let law = Law::from_text(name, law).map_err(kernel_err)?;
        let element = NonlinearElement::new(name, law, coupling).map_err(kernel_err)?;
        self.inner.add_element(element).map_err(kernel_err)
    }

    /// Adds an excitation point `name` at DOF `dof` with nominal force amplitude `amplitude`
    /// (N): the fundamental of harmonic balance and the default sine of `simulate`.
    fn add_excitation(&mut self, name: &str, dof: &str, amplitude: f64) -> PyResult<()> {
        if !amplitude.is_finite() {
            return Err(input(format!(
                "amplitude: {amplitude} is not a finite number"
            )));
        }
        let at = self.site("dof", dof)?;
        self.inner
            .add_excitation(Excitation {
                name: name.into(),
                at,
                amplitude,
                harmonics: Vec::new(),
            })
            .map_err(kernel_err)
    }

    /// Adds a sensor `name` at DOF `dof` measuring `quantity`: `"displacement"` (m),
    /// `"velocity"` (m/s) or `"acceleration"` (m/s²).
    #[pyo3(signature = (name, dof, quantity="displacement"))]
    fn add_sensor(&mut self, name: &str, dof: &str, quantity: &str) -> PyResult<()> {
        let quantity = Quantity::parse(quantity).map_err(|e| input(format!("quantity: {e}")))?;
        let at = self.site("dof", dof)?;
        self.inner
            .add_sensor(Sensor {
                name: name.into(),
                at,
                quantity,
            })
            .map_err(kernel_err)
    }

    /// The model's name.
    #[getter]
    fn name(&self) -> String {
        self.inner.name().to_string()
    }

    /// Where the model came from: the model file or built-in spec, or `"arrays"`.
    #[getter]
    fn source(&self) -> String {
        self.source.clone()
    }

    /// Number of DOFs.
    #[getter]
    fn n_dofs(&self) -> usize {
        self.inner.n_dofs()
    }

    /// DOF labels (`"12:uz"`), in the order of the matrices' rows.
    #[getter]
    fn dofs(&self) -> Vec<String> {
        self.dofs_text()
    }

    /// Names of the nonlinear elements.
    #[getter]
    fn elements(&self) -> Vec<String> {
        self.inner
            .elements()
            .iter()
            .map(|e| e.name().to_string())
            .collect()
    }

    /// Names of the excitation points, in the order of `simulate`'s force rows.
    #[getter]
    fn excitations(&self) -> Vec<String> {
        self.inner
            .excitation()
            .iter()
            .map(|x| x.name.clone())
            .collect()
    }

    /// Names of the sensors, in the order of the results' sensor axis.
    #[getter]
    fn sensors(&self) -> Vec<String> {
        self.inner
            .sensors()
            .iter()
            .map(|s| s.name.clone())
            .collect()
    }

    /// The parameters' text forms (`"tip.k3"`, `"mode1.zeta"`, `"group:web.k_scale"`).
    #[getter]
    fn parameters(&self) -> Vec<String> {
        self.inner
            .parameters()
            .iter()
            .map(ToString::to_string)
            .collect()
    }

    /// The value of parameter `name` (its text form, as `parameters` lists it).
    fn get(&self, name: &str) -> PyResult<f64> {
        let p = self.param(name)?;
        self.inner.param(&p).map_err(kernel_err)
    }

    /// Sets parameter `name` to `value`.
    fn set(&mut self, name: &str, value: f64) -> PyResult<()> {
        let p = self.param(name)?;
        self.inner.set_param(&p, value).map_err(kernel_err)
    }

    /// An independent copy (models are edited in place by `set` and `add_*`).
    fn copy(&self) -> Model {
        self.clone()
    }

    fn __repr__(&self) -> String {
        format!(
            "<nlsim.Model '{}': {} DOFs, {} element(s), {} excitation point(s), {} sensor(s), from {}>",
            self.inner.name(),
            self.inner.n_dofs(),
            self.inner.elements().len(),
            self.inner.excitation().len(),
            self.inner.sensors().len(),
            self.source
        )
    }
}
