//! What the commands share to set up a run: a model loaded with its `--set` overrides, the
//! Lanczos settings, and reductions shared between runs of one linear model (batches).
use crate::error::{Error, Result};
use nlsim_kernel::param::parse_known;
use nlsim_kernel::{Model, Param, Parameterized, ValidationConfig};
use nlsim_reduction::{EigenConfig, ModeSelection, ReducedModel, ReductionConfig};
use std::collections::HashMap;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

/// Loads and validates a model for a run (definiteness shows later, in the factorisations)
/// and applies `element.param=value` overrides.
pub fn load_for_run(spec: &str, sets: &[String]) -> Result<Model> {
    let mut model = load_validated(spec)?;
    apply_sets(&mut model, sets)?;
    Ok(model)
}

/// [`load_for_run`] for a command that also takes parameters of the reduced model: the
/// model with the overrides it knows, and the others ([`apply_sets_deferred`]).
pub fn load_for_run_deferred(spec: &str, sets: &[String]) -> Result<(Model, Vec<(Param, f64)>)> {
    let mut model = load_validated(spec)?;
    let deferred = apply_sets_deferred(&mut model, sets)?;
    Ok((model, deferred))
}

/// Loads and validates a model for a run (definiteness shows later, in the factorisations).
fn load_validated(spec: &str) -> Result<Model> {
    let model = crate::load_model(spec)?.model;
    model.validate(&ValidationConfig {
        check_definiteness: false,
        ..Default::default()
    })?;
    Ok(model)
}

/// One `--set NAME=VALUE` split into the name and the value.
fn split_set(s: &str) -> Result<(&str, f64)> {
    let (name, v) = s
        .split_once('=')
        .ok_or_else(|| Error::Usage(format!("--set '{s}': expected element.param=value")))?;
    let v: f64 = v
        .trim()
        .parse()
        .map_err(|_| Error::Usage(format!("--set '{s}': '{v}' is not a number")))?;
    Ok((name, v))
}

/// Applies `element.param=value` overrides (the `--set` option).
pub fn apply_sets(model: &mut Model, sets: &[String]) -> Result<()> {
    for s in sets {
        let (name, v) = split_set(s)?;
        let p = parse_known(name, &model.parameters())?;
        model.set_param(&p, v)?;
    }
    Ok(())
}

/// Applies the `--set` overrides the model knows and returns those of the reduced model
/// (`modeN.f`, `modeN.zeta`, `modeN.m`, `stiffness_scale`, `residual:A:B`: what `calibrate`
/// estimates on a modal model), which apply after the reduction; any other unknown name is an error that
/// lists both kinds.
pub fn apply_sets_deferred(model: &mut Model, sets: &[String]) -> Result<Vec<(Param, f64)>> {
    let mut deferred = Vec::new();
    for s in sets {
        let (name, v) = split_set(s)?;
        let known = model.parameters();
        match name.trim().parse::<Param>() {
            Ok(p) if known.contains(&p) => model.set_param(&p, v)?,
            Ok(p) if p.is_gain() => {
                return Err(nlsim_kernel::param::unknown_param(&p, &known).into());
            }
            Ok(
                p @ (Param::ModalFrequency(_)
                | Param::ModalDamping(_)
                | Param::ModalMass(_)
                | Param::StiffnessScale
                | Param::Residual(..)
                | Param::ModeShape { .. }),
            ) => deferred.push((p, v)),
            _ => {
                return Err(nlsim_kernel::Error::UnknownParameter {
                    name: name.trim().to_string(),
                    known: format!(
                        "{}, and of the reduced model modeN.f, modeN.zeta, modeN.m (N up to \
                         the retained modes), stiffness_scale and a modal model's \
                         residual:PORT:PORT and modeN.shape:POINT",
                        known
                            .iter()
                            .map(ToString::to_string)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                }
                .into());
            }
        }
    }
    Ok(deferred)
}

/// The Lanczos settings of a run's reduction (`--basis`, `--restarts` of `simulate`, `frf`
/// and `nnm`, as of `modes`): what the eigensolver's message advises when modes do not
/// converge.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Lanczos {
    /// Basis size before a restart; `None`: the solver's default `max(2k, k + 4 block)`.
    pub basis: Option<usize>,
    /// Most restarts before the solver gives up.
    pub restarts: usize,
    /// Fill-reducing ordering of the sparse factor (`--ordering`).
    pub ordering: nlsim_reduction::Ordering,
    /// Bytes the factors may take together (`--memory-budget`; see
    /// [`EigenConfig::memory_budget`]); `None`: no limit.
    pub memory_budget: Option<usize>,
}

impl Default for Lanczos {
    fn default() -> Self {
        let d = EigenConfig::default();
        Self {
            basis: d.basis_size,
            restarts: d.max_restarts,
            ordering: d.ordering,
            memory_budget: d.memory_budget,
        }
    }
}

/// The reduction every run uses: the lowest `modes` modes, with or without residual
/// flexibility.
fn reduce(
    model: &Model,
    modes: usize,
    residual: bool,
    par: faer::Par,
    lanczos: Lanczos,
) -> Result<ReducedModel> {
    Ok(nlsim_reduction::reduce(
        model,
        &ReductionConfig {
            eigen: EigenConfig {
                selection: ModeSelection::Lowest(modes),
                par,
                basis_size: lanczos.basis,
                max_restarts: lanczos.restarts,
                ordering: lanczos.ordering,
                memory_budget: lanczos.memory_budget,
                ..EigenConfig::default()
            },
            residual_flexibility: residual,
            ..Default::default()
        },
    )?)
}

type Slot = Arc<OnceLock<std::result::Result<Arc<ReducedModel>, String>>>;

/// Reduced models shared by runs that differ only in what the reduction does not see: the
/// excitation, the force level, the element parameters (elements act through their ports; their
/// laws are not part of `K` and `M`). Runs whose linear model differs (a stiffness group or a
/// boundary spring set by a job, another model) get their own reduction.
///
/// A run's reduction is identified by a hash of everything [`nlsim_reduction::reduce`] reads:
/// `K` and `M` (structure and values), the damping, the ports (element couplings, excitation
/// and sensor DOFs), the mode count and the residual flexibility switch. The reduction is
/// deterministic, so a shared one is bit-identical to a fresh one. Thread-safe: parallel jobs
/// with the same key wait for one reduction. Kept reductions are bounded by
/// [`Reductions::BUDGET_BYTES`] of mode shapes; past it, runs reduce for themselves.
#[derive(Debug, Default)]
pub struct Reductions {
    slots: Mutex<(HashMap<u64, Slot>, usize)>,
    computed: AtomicUsize,
    reused: AtomicUsize,
}

impl Reductions {
    /// Mode-shape bytes kept at most (1 GiB).
    pub const BUDGET_BYTES: usize = 1 << 30;

    /// The reduction of `model` to `modes` modes (with residual flexibility when `residual`),
    /// computed once per distinct linear model.
    pub fn get(
        &self,
        model: &Model,
        modes: usize,
        residual: bool,
        par: faer::Par,
        lanczos: Lanczos,
    ) -> Result<Arc<ReducedModel>> {
        let key = reduction_key(model, modes, residual, lanczos)?;
        let bytes = model.n_dofs().saturating_mul(modes).saturating_mul(8);
        let slot = {
            let mut guard = self.slots.lock().unwrap_or_else(|p| p.into_inner());
            let (map, used) = &mut *guard;
            match map.get(&key) {
                Some(s) => Some(s.clone()),
                None if used.saturating_add(bytes) <= Self::BUDGET_BYTES => {
                    *used += bytes;
                    Some(map.entry(key).or_default().clone())
                }
                None => None,
            }
        };
        let Some(slot) = slot else {
            self.computed.fetch_add(1, Ordering::Relaxed);
            return Ok(Arc::new(reduce(model, modes, residual, par, lanczos)?));
        };
        let mut fresh = false;
        let r = slot.get_or_init(|| {
            fresh = true;
            self.computed.fetch_add(1, Ordering::Relaxed);
            reduce(model, modes, residual, par, lanczos)
                .map(Arc::new)
                .map_err(|e| e.to_string())
        });
        if !fresh {
            self.reused.fetch_add(1, Ordering::Relaxed);
        }
        r.clone().map_err(Error::Failed)
    }

    /// How many reductions were computed and how many runs reused one.
    pub fn counts(&self) -> (usize, usize) {
        (
            self.computed.load(Ordering::Relaxed),
            self.reused.load(Ordering::Relaxed),
        )
    }
}

/// A hash of what the reduction of `model` to `modes` modes reads (see [`Reductions`]).
fn reduction_key(model: &Model, modes: usize, residual: bool, lanczos: Lanczos) -> Result<u64> {
    use std::hash::{Hash, Hasher};
    fn matrix(a: &nlsim_kernel::SparseSym, h: &mut impl Hasher) {
        let f = a.as_faer();
        f.col_ptr().hash(h);
        f.row_idx().hash(h);
        for v in f.val() {
            v.to_bits().hash(h);
        }
    }
    let mut h = std::hash::DefaultHasher::new();
    matrix(model.stiffness(), &mut h);
    matrix(model.mass(), &mut h);
    match model.damping() {
        nlsim_kernel::Damping::Matrix(v) => matrix(v, &mut h),
        d => format!("{d:?}").hash(&mut h),
    }
    format!("{:?}", nlsim_reduction::model_ports(model, &[])?).hash(&mut h);
    (modes, residual, lanczos).hash(&mut h);
    Ok(h.finish())
}

#[cfg(feature = "io")]
/// The retained mode count as a summary prints it: `20`, or `all 3` when the request asked
/// for more modes than the model has.
pub(crate) fn modes_text(kept: usize, asked: usize) -> String {
    if asked > kept {
        format!("all {kept}")
    } else {
        kept.to_string()
    }
}

#[cfg(feature = "io")]
/// The note when more modes were kept than asked: the rest complete a degenerate cluster.
pub(crate) fn cluster_note(kept: usize, asked: usize) -> Option<String> {
    (kept > asked && asked > 0).then(|| {
        let which = if kept == asked + 1 {
            format!("mode {kept} is kept with mode {asked}")
        } else {
            format!("modes {}-{kept} are kept with mode {asked}", asked + 1)
        };
        format!("{which}: equal frequencies (to 1e-8), and a degenerate cluster is not split at the cut-off")
    })
}

/// The default report folder of a settings file: `DIR/NAME-report` for `DIR/NAME.toml`.
pub fn default_report(file: &std::path::Path) -> std::path::PathBuf {
    let stem = file
        .file_stem()
        .map_or("nlsim".into(), |s| s.to_string_lossy());
    file.with_file_name(format!("{stem}-report"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nlsim_kernel::Param;

    #[test]
    fn a_reduction_is_shared_exactly_when_the_linear_model_is_the_same() {
        let model = nlsim_fixtures::ecl_beam().model;
        let key = |m: &Model, modes: usize, residual: bool| {
            reduction_key(m, modes, residual, Lanczos::default()).unwrap()
        };
        let base = key(&model, 10, true);
        // Element parameters act through the ports: the same reduction.
        let mut softer = model.clone();
        softer
            .set_param(
                &Param::Element {
                    element: "tip_spring".into(),
                    param: "k3".into(),
                },
                1e3,
            )
            .unwrap();
        assert_eq!(key(&softer, 10, true), base);
        // Another mode count, no residual flexibility, a grounded spring (K changes), another
        // damping: each its own.
        assert_ne!(key(&model, 11, true), base);
        assert_ne!(key(&model, 10, false), base);
        let mut sprung = model.clone();
        sprung.add_boundary_spring(5, 1e3).unwrap();
        assert_ne!(key(&sprung, 10, true), base);
        let mut damped = model.clone();
        damped
            .set_damping(nlsim_kernel::Damping::Rayleigh {
                alpha: 1.0,
                beta: 0.0,
            })
            .unwrap();
        assert_ne!(key(&damped, 10, true), base);

        // Shared reductions are the ones a run computes for itself, bit for bit.
        let shared = Reductions::default();
        let a = shared
            .get(&model, 10, true, faer::Par::Seq, Lanczos::default())
            .unwrap();
        let b = shared
            .get(&softer, 10, true, faer::Par::Seq, Lanczos::default())
            .unwrap();
        let c = shared
            .get(&sprung, 10, true, faer::Par::Seq, Lanczos::default())
            .unwrap();
        assert!(Arc::ptr_eq(&a, &b) && !Arc::ptr_eq(&a, &c));
        assert_eq!(shared.counts(), (2, 1));
        let fresh = reduce(&softer, 10, true, faer::Par::Seq, Lanczos::default()).unwrap();
        assert_eq!(fresh.modes.eigenvalues, b.modes.eigenvalues);
        assert_eq!(fresh.residual, b.residual);
        assert_eq!(fresh.participation, b.participation);
    }
}
