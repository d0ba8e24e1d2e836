//! Universal file dataset 58 written: FRFs (function type 4, from `nlsim frf`) and time
//! responses (type 1, from `nlsim simulate`), ASCII with records 1–11 in their fixed columns
//! or binary `58b`, so that test software (and pyuff) reads nlsim's predictions; the reader
//! is [`crate::formats::uff`].

use crate::error::{Error, Result};
use crate::formats::uff::Uff58;
use faer::c64;
use nlsim_kernel::Quantity;
use std::fmt::Write as _;
use std::path::Path;

/// Writes `records` as datasets 58 (ASCII, double precision, uneven abscissa) or 58b
/// (binary little-endian), atomically ([`write_functions`]).
pub fn write(path: &Path, records: &[Uff58], binary: bool) -> Result<()> {
    let functions: Vec<UffFunction> = records
        .iter()
        .map(|r| UffFunction {
            id: r.id.clone(),
            function_type: r.function_type,
            response: (r.response_node, r.response_direction),
            reference: (r.reference_node, r.reference_direction),
            abscissa_type: 18,
            ordinate_type: r.ordinate_type,
            denominator_type: r.denominator_type,
            abscissa: Abscissa::Uneven(r.frequencies_hz.clone()),
            values: r.values.clone(),
            complex: true,
        })
        .collect();
    write_functions(path, &functions, binary, &[])
}

/// The abscissa of a function written by [`write_functions`].
#[derive(Debug, Clone, PartialEq)]
pub enum Abscissa {
    /// Evenly spaced: the first value and the increment (s or Hz).
    Even {
        /// First abscissa value.
        start: f64,
        /// Increment.
        step: f64,
    },
    /// One abscissa value per ordinate value.
    Uneven(Vec<f64>),
}

/// A function written as dataset 58 by [`write_functions`]: a time history (function type 1)
/// or a frequency response (type 4), real or complex, at a response DOF per a reference DOF.
#[derive(Debug, Clone, PartialEq)]
pub struct UffFunction {
    /// ID line 1: what the function is.
    pub id: String,
    /// Function type: 1 time response, 4 frequency response function.
    pub function_type: i64,
    /// Response node and direction (1..6 = +x … +rz; 0 a scalar coordinate).
    pub response: (i64, i64),
    /// Reference node and direction (0, 0 for a time response).
    pub reference: (i64, i64),
    /// Specific data type of the abscissa: 17 time (s), 18 frequency (Hz).
    pub abscissa_type: i64,
    /// Specific data type of the ordinate (numerator): 8 displacement, 11 velocity,
    /// 12 acceleration, 13 excitation force.
    pub ordinate_type: i64,
    /// Specific data type of the denominator: 13 excitation force (an FRF), 0 none.
    pub denominator_type: i64,
    /// The abscissa.
    pub abscissa: Abscissa,
    /// The ordinate values (SI units of the ordinate over the denominator).
    pub values: Vec<c64>,
    /// Complex ordinate (ordinate data type 6), else real (4; the imaginary parts unused).
    pub complex: bool,
}

/// The UFF node and direction of DOF `label`: its node number and 1..6 for ux … rz, 0 for a
/// scalar coordinate.
pub fn node_direction(label: nlsim_kernel::DofLabel) -> (i64, i64) {
    use nlsim_kernel::Component as C;
    let d = match label.component {
        C::Ux => 1,
        C::Uy => 2,
        C::Uz => 3,
        C::Rx => 4,
        C::Ry => 5,
        C::Rz => 6,
        C::U => 0,
    };
    (i64::try_from(label.node).unwrap_or(i64::MAX), d)
}

/// The UFF specific data type of a response quantity (8, 11, 12).
pub fn quantity_code(q: Quantity) -> i64 {
    match q {
        Quantity::Displacement => 8,
        Quantity::Velocity => 11,
        Quantity::Acceleration => 12,
    }
}

fn axis_label(code: i64) -> (&'static str, &'static str) {
    match code {
        17 => ("Time", "s"),
        18 => ("Frequency", "Hz"),
        8 => ("Displacement", "m"),
        11 => ("Velocity", "m/s"),
        12 => ("Acceleration", "m/s^2"),
        13 => ("Force", "N"),
        _ => ("NONE", "NONE"),
    }
}

/// Writes `functions` as datasets 58 to `path`, atomically, after a dataset 2411 of the
/// nodes they name that `geometry` holds ([`encode_functions`]).
pub fn write_functions(
    path: &Path,
    functions: &[UffFunction],
    binary: bool,
    geometry: &[(u64, [f64; 3])],
) -> Result<()> {
    crate::formats::files::write_bytes_atomically(
        path,
        &encode_functions(path, functions, binary, geometry)?,
    )
}

/// The response and reference nodes of `functions` (node 0, "none", left out).
fn function_nodes(functions: &[UffFunction]) -> impl Iterator<Item = u64> + '_ {
    functions
        .iter()
        .flat_map(|f| [f.response.0, f.reference.0])
        .filter_map(|n| u64::try_from(n).ok().filter(|&n| n > 0))
}

/// Dataset 2411 ("nodes — double precision") of the nodes among `nodes` that `geometry`
/// (ascending by id, as [`nlsim_kernel::Model::geometry`] holds it) has coordinates for,
/// ascending and each once: per node record 1 (`4I10`: the node, export and displacement
/// coordinate systems 0 — global Cartesian — and colour 1) and record 2 (`1P3D25.16`: x, y,
/// z in m). Empty when none of them has coordinates, so that a model without geometry
/// writes the functions alone.
pub fn nodes_text(geometry: &[(u64, [f64; 3])], nodes: impl Iterator<Item = u64>) -> String {
    let wanted: std::collections::BTreeSet<u64> = nodes.collect();
    let mut s = String::new();
    for node in wanted {
        let Ok(i) = geometry.binary_search_by_key(&node, |g| g.0) else {
            continue;
        };
        if s.is_empty() {
            let _ = writeln!(s, "{:>6}\n{:>6}", -1, 2411);
        }
        let _ = writeln!(s, "{node:>10}{:>10}{:>10}{:>10}", 0, 0, 1);
        for v in geometry[i].1 {
            s.push_str(&fortran_d(v));
        }
        s.push('\n');
    }
    if !s.is_empty() {
        let _ = writeln!(s, "{:>6}", -1);
    }
    s
}

/// A number in Fortran `1PD25.16` form: one digit before the point, 16 after, a `D`
/// exponent of at least two digits, right-aligned in 25 columns.
fn fortran_d(v: f64) -> String {
    crate::formats::uff55::fortran_e(v, 25, 16).replacen('E', "D", 1)
}

/// The bytes of `functions` as datasets 58 (ASCII: records 1–11 in their fixed columns,
/// double precision values `E20.11`, an uneven abscissa `E13.5` as the format gives it) or
/// 58b (binary little-endian IEEE doubles, the header's byte count exact). ID lines 2–5
/// carry `nlsim` and the version; units are SI (the ordinate's over the denominator's).
/// First a dataset 2411 of the nodes they name that `geometry` holds ([`nodes_text`]).
/// `path` names the destination in errors.
pub fn encode_functions(
    path: &Path,
    functions: &[UffFunction],
    binary: bool,
    geometry: &[(u64, [f64; 3])],
) -> Result<Vec<u8>> {
    for f in functions {
        for node in [f.response.0, f.reference.0] {
            crate::formats::uff55::check_node(path, node, &f.id)?;
        }
    }
    let mut out: Vec<u8> = nodes_text(geometry, function_nodes(functions)).into_bytes();
    for (i, f) in functions.iter().enumerate() {
        let n = f.values.len();
        if let Abscissa::Uneven(x) = &f.abscissa
            && x.len() != n
        {
            return Err(Error::Usage(format!(
                "{}: function {} ('{}'): {} abscissa values for {n} ordinate values",
                path.display(),
                i + 1,
                f.id,
                x.len()
            )));
        }
        let mut data = Vec::with_capacity(3 * n);
        for (k, v) in f.values.iter().enumerate() {
            if let Abscissa::Uneven(x) = &f.abscissa {
                data.push(x[k]);
            }
            data.push(v.re);
            if f.complex {
                data.push(v.im);
            }
        }
        let mut s = String::new();
        let _ = writeln!(s, "{:>6}", -1);
        if binary {
            let _ = writeln!(
                s,
                "{:>6}b{:>6}{:>6}{:>12}{:>12}{:>6}{:>6}{:>12}{:>12}",
                58,
                1,
                2,
                11,
                data.len() * 8,
                0,
                0,
                0,
                0
            );
        } else {
            let _ = writeln!(s, "{:>6}", 58);
        }
        let id: String = f.id.chars().take(80).collect();
        let _ = writeln!(s, "{id:<80}");
        let _ = writeln!(s, "{:<80}", format!("nlsim {}", env!("CARGO_PKG_VERSION")));
        for _ in 0..3 {
            let _ = writeln!(s, "{:<80}", "NONE");
        }
        let _ = writeln!(
            s,
            "{:>5}{:>10}{:>5}{:>10} {:<10}{:>10}{:>4} {:<10}{:>10}{:>4}",
            f.function_type,
            0,
            0,
            0,
            "NONE",
            f.response.0,
            f.response.1,
            "NONE",
            f.reference.0,
            f.reference.1
        );
        let (spacing, start, step) = match f.abscissa {
            Abscissa::Even { start, step } => (1, start, step),
            Abscissa::Uneven(_) => (0, 0.0, 0.0),
        };
        let _ = writeln!(
            s,
            "{:>10}{:>10}{:>10}{:>13.5e}{:>13.5e}{:>13.5e}",
            if f.complex { 6 } else { 4 },
            n,
            spacing,
            start,
            step,
            0.0
        );
        for t in [f.abscissa_type, f.ordinate_type, f.denominator_type, 0] {
            let (label, units) = axis_label(t);
            let _ = writeln!(s, "{t:>10}{:>5}{:>5}{:>5} {label:<20} {units:<20}", 0, 0, 0);
        }
        out.extend(s.as_bytes());
        if binary {
            for v in &data {
                out.extend(v.to_le_bytes());
            }
            out.push(b'\n');
        } else {
            let mut body = String::new();
            match (&f.abscissa, f.complex) {
                (Abscissa::Uneven(_), true) => {
                    for c in data.chunks(3) {
                        let _ = writeln!(body, "{:>13.5e}{:>20.11e}{:>20.11e}", c[0], c[1], c[2]);
                    }
                }
                (Abscissa::Uneven(_), false) => {
                    for c in data.chunks(2) {
                        let _ = writeln!(body, "{:>13.5e}{:>20.11e}", c[0], c[1]);
                    }
                }
                (Abscissa::Even { .. }, _) => {
                    for row in data.chunks(4) {
                        for v in row {
                            let _ = write!(body, "{v:>20.11e}");
                        }
                        body.push('\n');
                    }
                }
            }
            out.extend(body.as_bytes());
        }
        out.extend(format!("{:>6}\n", -1).as_bytes());
    }
    Ok(out)
}
