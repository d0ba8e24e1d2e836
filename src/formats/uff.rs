//! Linear FRFs from Universal File Format dataset 58 ("function at nodal DOF"), the exchange
//! format of test systems, in its ASCII form and its binary form `58b`.
//!
//! A dataset is a block between two `-1` lines: the number `58` (or `58b` followed by the
//! byte order, the float format, the count of ASCII header lines and of data bytes), five ID
//! lines, then records 6–11 in fixed columns and the data in record 12. Read here:
//!
//! - record 6: function type (4 = FRF), response node and direction, reference node and
//!   direction (directions 1..6 = +x, +y, +z, +rx, +ry, +rz; negative = the opposite sense);
//! - record 7: ordinate type (2/4 real single/double, 5/6 complex single/double), number of
//!   values, abscissa spacing (1 even: minimum and increment given; 0 uneven: each value is
//!   preceded by its abscissa);
//! - records 8–10: the specific data type of the abscissa (18 = frequency), of the ordinate
//!   numerator (8 displacement, 11 velocity, 12 acceleration) and of the denominator
//!   (13 excitation force);
//! - record 12: the values, whitespace separated (ASCII) or raw IEEE 754 (binary, in the
//!   declared byte order).
//!
//! Other datasets in the file are skipped. [`to_test_data`] turns FRFs that share a
//! frequency grid into calibration test data: one channel per response, a unit force at
//! every frequency, one sweep. Errors name the file and line (the byte offset for binary
//! data).

use crate::error::{Error, Result};
use faer::{Mat, c64};
use nlsim_calib::{Channel, Noise, Step, Sweep, SweepDirection, TestData};
use nlsim_kernel::Quantity;
use std::path::Path;

/// One dataset 58: a function of frequency at a response DOF per unit of a reference DOF.
#[derive(Debug, Clone, PartialEq)]
pub struct Uff58 {
    /// ID line 1 (the function's description), trimmed.
    pub id: String,
    /// Function type (4 = frequency response function).
    pub function_type: i64,
    /// Response node.
    pub response_node: i64,
    /// Response direction (1..6 = +x, +y, +z, +rx, +ry, +rz; negative: opposite sense).
    pub response_direction: i64,
    /// Reference (excitation) node.
    pub reference_node: i64,
    /// Reference direction.
    pub reference_direction: i64,
    /// Specific data type of the ordinate numerator (8 displacement, 11 velocity,
    /// 12 acceleration).
    pub ordinate_type: i64,
    /// Specific data type of the ordinate denominator (13 excitation force).
    pub denominator_type: i64,
    /// Abscissa (Hz).
    pub frequencies_hz: Vec<f64>,
    /// Ordinate (complex; imaginary part 0 for real data), in the file's units.
    pub values: Vec<c64>,
}

impl Uff58 {
    /// The response quantity, from the ordinate's specific data type.
    pub fn quantity(&self) -> Option<Quantity> {
        match self.ordinate_type {
            8 => Some(Quantity::Displacement),
            11 => Some(Quantity::Velocity),
            12 => Some(Quantity::Acceleration),
            _ => None,
        }
    }

    /// The response DOF as nlsim writes a DOF label, `NODE:COMP` (`12:uz`).
    pub fn response_label(&self) -> String {
        format!(
            "{}:{}",
            self.response_node,
            direction_name(self.response_direction.abs())
        )
    }
}

fn direction_name(d: i64) -> &'static str {
    match d {
        1 => "ux",
        2 => "uy",
        3 => "uz",
        4 => "rx",
        5 => "ry",
        6 => "rz",
        _ => "u",
    }
}

/// Reads every dataset 58 of a universal file (ASCII or binary).
pub fn read(path: &Path) -> Result<Vec<Uff58>> {
    let bytes = crate::formats::files::read_bytes(path)?;
    parse(&bytes, path)
}

/// A cursor over the lines of the file that knows its line number.
struct Lines<'a> {
    bytes: &'a [u8],
    pos: usize,
    line: usize,
}

impl<'a> Lines<'a> {
    fn next(&mut self) -> Option<&'a [u8]> {
        if self.pos >= self.bytes.len() {
            return None;
        }
        let rest = &self.bytes[self.pos..];
        let end = rest.iter().position(|&b| b == b'\n').unwrap_or(rest.len());
        self.pos += (end + 1).min(rest.len());
        self.line += 1;
        let l = &rest[..end];
        Some(l.strip_suffix(b"\r").unwrap_or(l))
    }
}

/// Parses the universal file `bytes` (named `path` in errors).
pub fn parse(bytes: &[u8], path: &Path) -> Result<Vec<Uff58>> {
    let err = |line: usize, message: String| Error::DataFile {
        file: path.to_path_buf(),
        line,
        message,
    };
    let mut out = Vec::new();
    let mut lines = Lines {
        bytes,
        pos: 0,
        line: 0,
    };
    while let Some(l) = lines.next() {
        if trim(l) != "-1" {
            continue;
        }
        let Some(head) = lines.next() else { break };
        let head_line = lines.line;
        let head_text = text(head);
        let fields: Vec<&str> = head_text.split_whitespace().collect();
        let Some(&kind) = fields.first() else {
            continue;
        };
        if kind != "58" && kind != "58b" {
            // Skip another dataset: to its closing -1 (ASCII datasets only are skipped
            // safely; a binary dataset of another type declares its byte count).
            skip_dataset(&mut lines, &fields);
            continue;
        }
        let binary = if kind == "58b" {
            let num = |i: usize, what: &str| -> Result<usize> {
                fields
                    .get(i)
                    .and_then(|s| s.parse::<usize>().ok())
                    .ok_or_else(|| {
                        err(
                            head_line,
                            format!(
                                "dataset 58b: field {} ({what}) is missing or not a count",
                                i + 1
                            ),
                        )
                    })
            };
            let order = num(1, "byte order")?;
            let format = num(2, "float format")?;
            let n_bytes = num(4, "data bytes")?;
            if order != 1 && order != 2 {
                return Err(err(
                    head_line,
                    format!("dataset 58b: byte order {order} (1 = little-endian, 2 = big-endian)"),
                ));
            }
            if format != 2 {
                return Err(err(
                    head_line,
                    format!("dataset 58b: float format {format} is not IEEE 754 (2)"),
                ));
            }
            Some((order == 1, n_bytes))
        } else {
            None
        };
        let mut rec = Vec::with_capacity(11);
        for _ in 0..11 {
            let l = lines
                .next()
                .ok_or_else(|| err(lines.line, "dataset 58 ends inside its header".into()))?;
            rec.push((lines.line, text(l)));
        }
        // Integer fields of header line `r` (record r + 1) in fixed columns; the fields in
        // `text_fields` are names and read as 0.
        let ints = |r: usize, widths: &[usize], text_fields: &[usize]| -> Result<Vec<i64>> {
            let (ln, s) = &rec[r];
            // Fixed columns, unless the line holds exactly one token per field (writers
            // that separate fields by spaces without keeping the columns).
            let tokens: Vec<String> = s.split_whitespace().map(str::to_string).collect();
            let fields = if tokens.len() == widths.len() {
                tokens
            } else {
                fixed_fields(s, widths)
            };
            fields
                .iter()
                .enumerate()
                .map(|(i, f)| {
                    let f = f.trim();
                    if f.is_empty() || text_fields.contains(&i) {
                        return Ok(0);
                    }
                    f.parse::<i64>().map_err(|_| {
                        err(
                            *ln,
                            format!(
                                "record {}: field {} is not an integer: {}",
                                r + 1,
                                i + 1,
                                crate::formats::files::quoted(f)
                            ),
                        )
                    })
                })
                .collect()
        };
        // Record 6: 2(I5,I10), 2(1X,10A1,I10,I4); fields 5 and 8 are entity names.
        let r6 = ints(5, &[5, 10, 5, 10, 11, 10, 4, 11, 10, 4], &[4, 7])?;
        // Record 7: 3I10, 3E13.5.
        let (r7_line, r7) = &rec[6];
        let r7_fields: Vec<&str> = r7.split_whitespace().collect();
        let r7_num = |i: usize| -> Result<f64> {
            r7_fields
                .get(i)
                .and_then(|s| s.replace(['D', 'd'], "E").parse::<f64>().ok())
                .ok_or_else(|| {
                    err(
                        *r7_line,
                        format!("record 7: field {} is missing or not a number", i + 1),
                    )
                })
        };
        let ord_type = r7_num(0)? as i64;
        let n = r7_num(1)?;
        let even = r7_num(2)? as i64;
        let (x_min, dx) = (r7_num(3)?, r7_num(4)?);
        if ![2, 4, 5, 6].contains(&ord_type) {
            return Err(err(
                *r7_line,
                format!("record 7: ordinate data type {ord_type} (expected 2, 4, 5 or 6)"),
            ));
        }
        if even != 0 && even != 1 {
            return Err(err(
                *r7_line,
                format!("record 7: abscissa spacing {even} (0 or 1)"),
            ));
        }
        let complex = ord_type >= 5;
        let per_value = usize::from(even == 0) + if complex { 2 } else { 1 };
        // The count is bounded by what the rest of the file can hold (each number takes at
        // least 4 bytes in binary and 2 characters in ASCII).
        let room = (bytes.len() - lines.pos) / if binary.is_some() { 4 } else { 2 };
        if !(n >= 1.0 && n.fract() == 0.0 && (n as usize).saturating_mul(per_value) <= room) {
            return Err(err(
                *r7_line,
                format!(
                    "record 7: {n} values cannot be in the {} bytes that follow",
                    bytes.len() - lines.pos
                ),
            ));
        }
        let n = n as usize;
        let specific = |r: usize| -> Result<i64> { Ok(ints(r, &[10], &[])?[0]) };
        let abscissa_type = specific(7)?;
        let ordinate_type = specific(8)?;
        let denominator_type = specific(9)?;
        // Frequency (18) for FRFs, time (17) for time responses; 0 (unknown) either way.
        let wanted = if r6[0] == 1 { 17 } else { 18 };
        if abscissa_type != wanted && abscissa_type != 0 {
            return Err(err(
                rec[7].0,
                format!(
                    "record 8: the abscissa is of type {abscissa_type}, not {} ({wanted}) for \
                     function type {}",
                    if wanted == 17 { "time" } else { "frequency" },
                    r6[0]
                ),
            ));
        }
        let count = n * per_value;
        let values: Vec<f64> = match binary {
            Some((little, n_bytes)) => {
                let size = if ord_type == 2 || ord_type == 5 { 4 } else { 8 };
                let start = lines.pos;
                let need = count * size;
                let held = bytes.len() - start;
                if need > held || n_bytes > held {
                    return Err(err(
                        lines.line + 1,
                        format!(
                            "dataset 58b: {need} data bytes needed for {n} values, the header \
                             declares {n_bytes} and the file holds {held} after byte {start}"
                        ),
                    ));
                }
                // The data end where record 7's count says when the dataset's closing -1
                // follows there: the header's count may be wrong (pyuff 2.5.8 declares
                // points × 8 bytes even for complex or uneven data). Else where the header's
                // count says (data padded), if the -1 follows there.
                let end = if closes_at(bytes, start + need) {
                    start + need
                } else if closes_at(bytes, start + n_bytes) {
                    start + n_bytes
                } else {
                    return Err(err(
                        lines.line + 1,
                        format!(
                            "dataset 58b: neither the header's {n_bytes} data bytes nor the \
                             {need} of record 7 ({n} values of {size} bytes) end at the \
                             dataset's closing -1 (after byte {start})"
                        ),
                    ));
                };
                let data = &bytes[start..start + need];
                lines.pos = end;
                data.chunks_exact(size)
                    .map(|c| match (size, little) {
                        (4, true) => f32::from_le_bytes([c[0], c[1], c[2], c[3]]) as f64,
                        (4, false) => f32::from_be_bytes([c[0], c[1], c[2], c[3]]) as f64,
                        (_, true) => f64::from_le_bytes(c.try_into().unwrap_or([0; 8])),
                        (_, false) => f64::from_be_bytes(c.try_into().unwrap_or([0; 8])),
                    })
                    .collect()
            }
            None => {
                let mut v = Vec::with_capacity(count);
                while v.len() < count {
                    let l = lines.next().ok_or_else(|| {
                        err(
                            lines.line,
                            format!("dataset 58 ends after {} of its {count} numbers", v.len()),
                        )
                    })?;
                    let s = text(l);
                    if s.trim() == "-1" {
                        return Err(err(
                            lines.line,
                            format!("dataset 58 ends after {} of its {count} numbers", v.len()),
                        ));
                    }
                    for (col, tok) in s.split_whitespace().enumerate() {
                        let x = tok.replace(['D', 'd'], "E").parse::<f64>().map_err(|_| {
                            err(
                                lines.line,
                                format!(
                                    "value {} is not a number: {}",
                                    col + 1,
                                    crate::formats::files::quoted(tok)
                                ),
                            )
                        })?;
                        v.push(x);
                    }
                }
                v.truncate(count);
                v
            }
        };
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(err(
                rec[6].0,
                format!("dataset 58 value {} (of {count}) is not finite", i + 1),
            ));
        }
        let mut frequencies_hz = Vec::with_capacity(n);
        let mut out_values = Vec::with_capacity(n);
        for i in 0..n {
            let chunk = &values[i * per_value..(i + 1) * per_value];
            let (x, y) = if even == 1 {
                (x_min + dx * i as f64, chunk)
            } else {
                (chunk[0], &chunk[1..])
            };
            frequencies_hz.push(x);
            out_values.push(c64::new(y[0], if complex { y[1] } else { 0.0 }));
        }
        // To the dataset's closing -1.
        while let Some(l) = lines.next() {
            if trim(l) == "-1" {
                break;
            }
        }
        out.push(Uff58 {
            id: rec[0].1.trim().to_string(),
            function_type: r6[0],
            response_node: r6[5],
            response_direction: r6[6],
            reference_node: r6[8],
            reference_direction: r6[9],
            ordinate_type,
            denominator_type,
            frequencies_hz,
            values: out_values,
        });
    }
    if out.is_empty() {
        return Err(err(
            1,
            "no dataset 58 (function at nodal DOF) in the file".into(),
        ));
    }
    Ok(out)
}

/// True when `bytes` from `at` hold, after blanks and line ends, a line `-1` (a dataset's
/// closing delimiter).
fn closes_at(bytes: &[u8], at: usize) -> bool {
    let Some(rest) = bytes.get(at..) else {
        return false;
    };
    let rest = match rest
        .iter()
        .position(|b| !matches!(b, b' ' | b'\t' | b'\r' | b'\n'))
    {
        Some(i) => &rest[i..],
        None => return false,
    };
    rest.starts_with(b"-1")
        && rest.get(2..).is_none_or(|r| {
            r.iter()
                .take_while(|b| **b != b'\n')
                .all(|b| b.is_ascii_whitespace())
        })
}

fn skip_dataset(lines: &mut Lines<'_>, fields: &[&str]) {
    // A binary dataset (e.g. 58b of another layout, 2414b) declares its byte count in the
    // fifth field; skip the ASCII lines declared in the fourth and those bytes.
    if fields.first().is_some_and(|k| k.ends_with('b')) {
        let ascii = fields
            .get(3)
            .and_then(|s| s.parse::<usize>().ok())
            .unwrap_or(0);
        let n_bytes = fields
            .get(4)
            .and_then(|s| s.parse::<usize>().ok())
            .unwrap_or(0);
        for _ in 0..ascii {
            lines.next();
        }
        lines.pos = (lines.pos + n_bytes).min(lines.bytes.len());
    }
    while let Some(l) = lines.next() {
        if trim(l) == "-1" {
            return;
        }
    }
}

fn text(l: &[u8]) -> String {
    String::from_utf8_lossy(l).into_owned()
}

fn trim(l: &[u8]) -> String {
    text(l).trim().to_string()
}

/// Splits `s` into fixed-width fields (missing trailing fields are empty).
fn fixed_fields(s: &str, widths: &[usize]) -> Vec<String> {
    let chars: Vec<char> = s.chars().collect();
    let mut at = 0;
    widths
        .iter()
        .map(|&w| {
            let f: String = chars.iter().skip(at).take(w).collect();
            at += w;
            f
        })
        .collect()
}

/// Linear FRF test data from datasets 58 of one reference DOF on one frequency grid: the
/// drive point is named `input`; each FRF becomes a channel named by its ID line (or
/// `NODE:COMP` when that is empty or `NONE`) with `noise`; each frequency a step of a unit
/// force (so the response is the FRF), in one sweep `uff58`. An FRF of negative response or
/// reference direction is turned to the positive senses. Errors name the dataset (1-based,
/// in file order) and the frequency.
pub fn to_test_data(records: &[Uff58], input: &str, noise: Noise) -> Result<TestData> {
    let bad = |i: usize, why: String| {
        Error::Model(nlsim_kernel::Error::invalid(
            format!("FRF dataset 58 number {} (in file order)", i + 1),
            why,
        ))
    };
    let first = records.first().ok_or_else(|| bad(0, "no FRF".into()))?;
    let mut channels = Vec::with_capacity(records.len());
    for (i, r) in records.iter().enumerate() {
        if r.function_type != 4 {
            return Err(bad(
                i,
                format!("function type {} is not an FRF (4)", r.function_type),
            ));
        }
        if r.denominator_type != 13 && r.denominator_type != 0 {
            return Err(bad(
                i,
                format!(
                    "the denominator is of type {}, not excitation force (13)",
                    r.denominator_type
                ),
            ));
        }
        if (r.reference_node, r.reference_direction.abs())
            != (first.reference_node, first.reference_direction.abs())
        {
            return Err(bad(
                i,
                format!(
                    "reference {}:{} differs from the first FRF's {}:{}: one drive point per test",
                    r.reference_node,
                    r.reference_direction,
                    first.reference_node,
                    first.reference_direction
                ),
            ));
        }
        if r.frequencies_hz != first.frequencies_hz {
            return Err(bad(i, "its frequencies differ from the first FRF's".into()));
        }
        let quantity = r.quantity().ok_or_else(|| {
            bad(
                i,
                format!(
                    "ordinate type {} is not displacement (8), velocity (11) or acceleration (12)",
                    r.ordinate_type
                ),
            )
        })?;
        // The ID line names the sensor; one that no channel name can be (a comma, a
        // control character) falls back to the response's node and direction.
        let name = if r.id.is_empty()
            || r.id.eq_ignore_ascii_case("none")
            || nlsim_calib::data::label_fault(&r.id).is_some()
        {
            r.response_label()
        } else {
            r.id.clone()
        };
        channels.push(Channel {
            name,
            quantity,
            noise,
        });
    }
    let steps = first
        .frequencies_hz
        .iter()
        .enumerate()
        .map(|(s, &f)| Step {
            frequency_hz: f,
            force: vec![c64::new(1.0, 0.0)],
            response: Mat::from_fn(records.len(), 1, |c, _| {
                let r = &records[c];
                let sign = (r.response_direction.signum() * r.reference_direction.signum()) as f64;
                let sign = if sign == 0.0 { 1.0 } else { sign };
                r.values[s] * sign
            }),
            sigma: Mat::new(),
        })
        .collect();
    let data = TestData {
        input: input.to_string(),
        drive: nlsim_calib::Drive::Force,
        channels,
        harmonics: 1,
        sweeps: vec![Sweep {
            label: "uff58".into(),
            direction: SweepDirection::Up,
            steps,
        }],
    };
    data.validate_measured()
        .map_err(|e| bad(0, e.to_string()))?;
    Ok(data)
}
