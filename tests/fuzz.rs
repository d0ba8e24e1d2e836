//! Seeded mutation fuzzing of every reader of user files: model files, Matrix Market, jobs
//! files, the binary matrix cache and HDF5 matrices. Each input must give `Ok` or `Err`:
//! never a panic, never an abort, within a memory limit.
//!
//! `readers_survive_mutated_inputs` runs the ignored `fuzz_inner` in a child process of this
//! test binary under `ulimit -v` (an allocation abort or a runaway allocation then fails the
//! test instead of the machine). The seed is fixed and printed; `NLSIM_FUZZ_SEED` and
//! `NLSIM_FUZZ_SCALE` (a factor on the iteration counts) explore further by hand.

use std::path::Path;
use std::process::Command;

/// splitmix64: a small, seeded generator (the fuzzer's only source of randomness).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }

    fn pick<'a, T>(&mut self, v: &'a [T]) -> &'a T {
        &v[self.below(v.len())]
    }
}

/// Values that break careless readers.
const HOSTILE: &[&str] = &[
    "0",
    "-1",
    "-0.0",
    "1e308",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "18446744073709551615",
    "9223372036854775808",
    "4294967296",
    "1000000000000",
    "\"\"",
    "\"/dev/zero\"",
    "[]",
    "{}",
    "\"\u{1b}[2J\"",
    "true",
    "3.5",
    "\"x\"",
];

/// One random edit of `text`: delete, duplicate or swap lines, cut the text, replace a number
/// or a value by a hostile one, or insert odd characters.
fn mutate(text: &str, rng: &mut Rng) -> String {
    let mut lines: Vec<String> = text.lines().map(String::from).collect();
    if lines.is_empty() {
        lines.push(String::new());
    }
    let n = lines.len();
    match rng.below(8) {
        0 => {
            lines.remove(rng.below(n));
        }
        1 => {
            let l = lines[rng.below(n)].clone();
            lines.insert(rng.below(n + 1), l);
        }
        2 => {
            let (a, b) = (rng.below(n), rng.below(n));
            lines.swap(a, b);
        }
        3 => {
            let joined = lines.join("\n");
            let mut cut = rng.below(joined.len() + 1);
            while !joined.is_char_boundary(cut) {
                cut -= 1;
            }
            return joined[..cut].to_string();
        }
        4 | 5 => {
            // A number (a run of digits, signs, dots, e) or the value after `=` replaced.
            let i = rng.below(n);
            let l = lines[i].clone();
            let hostile = *rng.pick(HOSTILE);
            lines[i] = if let Some((k, _)) = l.split_once('=') {
                format!("{k}= {hostile}")
            } else {
                let words: Vec<&str> = l.split_whitespace().collect();
                if words.is_empty() {
                    hostile.to_string()
                } else {
                    let w = rng.below(words.len());
                    let hostile = hostile.trim_matches('"');
                    words
                        .iter()
                        .enumerate()
                        .map(|(j, x)| if j == w { hostile } else { x })
                        .collect::<Vec<_>>()
                        .join(" ")
                }
            };
        }
        6 => {
            let i = rng.below(n);
            let odd = *rng.pick(&[
                "\0", "\t", "\r", "\u{feff}", "é", "[", "]", "=", "\"", "#", "%",
            ]);
            let mut at = rng.below(lines[i].len() + 1);
            while !lines[i].is_char_boundary(at) {
                at -= 1;
            }
            lines[i].insert_str(at, odd);
        }
        _ => {
            // Two edits.
            let once = mutate(text, rng);
            return mutate(&once, rng);
        }
    }
    lines.join("\n")
}

/// One random damage to the bytes `b`: a bit flipped, the end cut, random bytes appended, or
/// `special` (a hostile value where the format declares a size).
fn damage(b: &mut Vec<u8>, rng: &mut Rng, special: impl FnOnce(&mut Vec<u8>, &mut Rng)) {
    match rng.below(4) {
        0 => {
            let i = rng.below(b.len());
            b[i] ^= 1 << rng.below(8);
        }
        1 => b.truncate(rng.below(b.len())),
        2 => special(b, rng),
        _ => {
            let n = rng.below(64);
            b.extend((0..n).map(|_| rng.next() as u8));
        }
    }
}

/// What an OUTPUT4 or Harwell-Boeing reader accepted, resolved as a symmetric matrix on
/// `n` scalar DOFs: the error text, if any.
fn resolve_symmetric(
    file: &str,
    n: usize,
    entries: &[(usize, usize, f64, usize)],
    place: nlsim::formats::fe_matrices::Place,
) -> Option<String> {
    nlsim::formats::fe_matrices::symmetric_from_entries(
        Path::new(file),
        "K",
        &nlsim::kernel::DofMap::scalar(n),
        entries,
        place,
        nlsim::formats::fe_matrices::SYMMETRY_TOLERANCE,
    )
    .err()
    .map(|e| e.to_string())
}

/// Runs `f` on every input; returns the inputs that panicked (at most a few, escaped).
fn survive(name: &str, inputs: usize, mut f: impl FnMut(usize) -> Option<String>) -> Vec<String> {
    let mut panics = Vec::new();
    let mut errors = 0usize;
    // Panics of the readers are counted, not printed.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    for k in 0..inputs {
        match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| f(k))) {
            Ok(Some(_)) => errors += 1,
            Ok(None) => {}
            Err(_) => panics.push(format!("{name} input {k}")),
        }
    }
    std::panic::set_hook(hook);
    println!(
        "fuzz {name}: {inputs} inputs, {errors} refused with an error, {} accepted, {} panics",
        inputs - errors - panics.len(),
        panics.len()
    );
    panics
}

fn seed() -> u64 {
    std::env::var("NLSIM_FUZZ_SEED")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(17)
}

fn scale() -> usize {
    std::env::var("NLSIM_FUZZ_SCALE")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1)
}

#[path = "common/scratch.rs"]
mod scratch_dir;
use scratch_dir::Scratch;

fn scratch() -> Scratch {
    Scratch::new("fuzz")
}

fn root() -> &'static Path {
    Path::new(env!("CARGO_MANIFEST_DIR"))
}

/// Creates `name` under `loc` as a dataset of a hostile type, shape and content: reals with
/// NaN and huge values, integers, strings, complex numbers, or an unwritten dataset whose
/// shape declares 2⁴⁰ values.
fn hostile_dataset(loc: &hdf5_metno::Group, name: &str, rng: &mut Rng) -> hdf5_metno::Result<()> {
    use hdf5_metno::types::VarLenUnicode;
    let n = *rng.pick(&[0usize, 1, 2, 3, 4, 6]);
    match rng.below(6) {
        0 => {
            let v: Vec<f64> = (0..n)
                .map(|_| *rng.pick(&[f64::NAN, 1e308, -1.0, 0.0, 1e-320, 2.0]))
                .collect();
            loc.new_dataset_builder().with_data(&v).create(name)?;
        }
        1 => {
            let v: Vec<i64> = (0..n)
                .map(|_| *rng.pick(&[-1i64, 0, 3, i64::MAX]))
                .collect();
            loc.new_dataset_builder().with_data(&v).create(name)?;
        }
        2 => {
            let v: Vec<VarLenUnicode> = (0..n)
                .map(|_| {
                    rng.pick(&["tip", "acceleration", "", "x\ny"])
                        .parse()
                        .unwrap()
                })
                .collect();
            loc.new_dataset_builder().with_data(&v).create(name)?;
        }
        3 => {
            let v: Vec<faer::c64> = (0..n * 2)
                .map(|_| faer::c64::new(*rng.pick(&[1.0, f64::NAN, 1e308]), 0.0))
                .collect();
            loc.new_dataset::<faer::c64>()
                .shape((n, 2))
                .create(name)?
                .write_raw(&v)?;
        }
        4 => {
            // Declared, never written: a reader that trusts the shape allocates 8 TiB.
            loc.new_dataset::<f64>()
                .shape((1usize << 20, 1usize << 20))
                .create(name)?;
        }
        _ => {
            loc.create_group(name)?;
        }
    }
    Ok(())
}

/// Creates attribute `name` on `loc` with a hostile type or value.
fn hostile_attr(loc: &hdf5_metno::Group, name: &str, rng: &mut Rng) -> hdf5_metno::Result<()> {
    use hdf5_metno::types::VarLenUnicode;
    match rng.below(4) {
        0 => loc
            .new_attr::<u64>()
            .create(name)?
            .write_scalar(rng.pick(&[0u64, 1, 2, 1001, u64::MAX]))?,
        1 => loc
            .new_attr::<f64>()
            .create(name)?
            .write_scalar(rng.pick(&[f64::NAN, 2.5, -1.0, 1e308]))?,
        2 => {
            let long = "x".repeat(5000);
            let s: VarLenUnicode = rng
                .pick(&[
                    "",
                    "up",
                    "down",
                    "low",
                    "nlsim test data",
                    "a\u{1b}[2J",
                    long.as_str(),
                ])
                .parse()
                .unwrap();
            loc.new_attr::<VarLenUnicode>()
                .create(name)?
                .write_scalar(&s)?;
        }
        _ => loc
            .new_attr::<i32>()
            .shape(3)
            .create(name)?
            .write(&[1, 2, 3])?,
    }
    Ok(())
}

/// What `nlsim harmonics` does with time histories that read: the steps found from the
/// drive and one dwell fitted over the whole record; `Some` with the error when refused.
fn fit_records(r: nlsim::Result<nlsim::formats::time_records::TimeRecords>) -> Option<String> {
    let r = match r {
        Ok(r) => r,
        Err(e) => return Some(e.to_string()),
    };
    let names: Vec<&str> = r.names.iter().map(String::as_str).collect();
    let signals: Vec<&[f64]> = r.columns.iter().map(Vec::as_slice).collect();
    let _ = nlsim::calib::detect_steps(signals[0], r.rate_hz, 5e-3);
    nlsim::calib::extract_dwell(
        &names,
        &signals,
        r.rate_hz,
        None,
        &nlsim::calib::DwellConfig::default(),
    )
    .err()
    .map(|e| e.to_string())
}

/// The fuzzing itself; run by `readers_survive_mutated_inputs` in a memory-limited child.
#[test]
#[ignore = "run under a memory limit by readers_survive_mutated_inputs"]
fn fuzz_inner() {
    let dir = scratch();
    let mut rng = Rng(seed());
    println!("fuzz seed {}", seed());
    let mut panics = Vec::new();

    // Model files (with their matrix files beside them, in a copy of examples/models).
    let models = dir.join("models");
    std::fs::create_dir_all(&models).unwrap();
    let mut corpus = Vec::new();
    for e in std::fs::read_dir(root().join("examples/models"))
        .unwrap()
        .flatten()
    {
        if !e.path().is_file() {
            continue;
        }
        std::fs::copy(e.path(), models.join(e.file_name())).unwrap();
        if e.file_name().to_string_lossy().ends_with(".toml") {
            corpus.push(std::fs::read_to_string(e.path()).unwrap());
        }
    }
    let model_path = models.join("fuzzed.toml");
    panics.extend(survive("model file", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&corpus).clone().as_str(), &mut rng);
        match nlsim::parse_model_file(&text, &model_path) {
            Ok(m) => m
                .model
                .validate(&nlsim::kernel::ValidationConfig::default())
                .err()
                .map(|e| e.to_string()),
            Err(e) => Some(e.to_string()),
        }
    }));

    // Node coordinates from a CSV file (`[geometry] nodes = "nodes.csv"`, issue 45).
    let nodes_csv = "# the beam\nnode,x,y,z\n1,0,0,0\n2,0.035,0,0\n21,7e-1,1e-3,-2.5\n".to_string();
    let geometry_model = models.join("geometry.toml");
    panics.extend(survive("geometry csv", 3000 * scale(), |_| {
        let text = mutate(&nodes_csv, &mut rng);
        std::fs::write(models.join("nodes.csv"), text).unwrap();
        nlsim::parse_model_file(
            "[matrices]\nfixture = \"duffing_fig3\"\n\n[geometry]\nnodes = \"nodes.csv\"\n",
            &geometry_model,
        )
        .err()
        .map(|e| e.to_string())
    }));

    // Matrix Market text.
    let mtx = [
        std::fs::read_to_string(root().join("examples/models/spring_mass.mtx")).unwrap(),
        "%%MatrixMarket matrix coordinate real general\n% c\n3 3 5\n1 1 2.0\n2 2 3.0\n\
         3 3 4.0\n1 2 -1.0\n2 1 -1.0\n"
            .to_string(),
    ];
    panics.extend(survive("matrix market", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&mtx).clone().as_str(), &mut rng);
        nlsim::formats::matrices::parse_matrix_market(&text, Path::new("K.mtx"), "stiffness matrix")
            .err()
            .map(|e| e.to_string())
    }));

    // Jobs files (parsed only: running them is the batch tests' work).
    let jobs = [
        std::fs::read_to_string(root().join("examples/batch/duffing_k3.toml")).unwrap(),
        "name = \"s\"\ncommand = \"simulate\"\nmodel = \"duffing_fig3\"\nseed = 3\n\
         [simulate]\nduration = 1.0\nrate = 1000.0\nexcitation = [\"sine:freq=30\"]\n\
         [[sweep]]\noption = \"excitation\"\nvalues = [\"sine:freq=20\", \"none\"]\n"
            .to_string(),
    ];
    let jobs_path = dir.join("jobs.toml");
    panics.extend(survive("jobs file", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&jobs).clone().as_str(), &mut rng);
        nlsim::batch::Batch::parse(&text, &jobs_path)
            .err()
            .map(|e| e.to_string())
    }));

    // The binary cache: a valid cache with bytes flipped, cut or extended.
    let src = dir.join("K.mtx");
    std::fs::copy(root().join("examples/models/spring_mass.mtx"), &src).unwrap();
    let want = nlsim::formats::cache::load_matrix_market(&src, "K")
        .unwrap()
        .to_dense();
    let cache = nlsim::formats::cache::cache_path(&src);
    let good = std::fs::read(&cache).unwrap();
    panics.extend(survive("matrix cache", 3000 * scale(), |_| {
        let mut b = good.clone();
        damage(&mut b, &mut rng, |b, rng| {
            // A header word set to a hostile size.
            let w = 8 * (1 + rng.below(6));
            let v = *rng.pick(&[0u64, 1, u64::MAX, 1 << 40, 1 << 62]);
            b[w..w + 8].copy_from_slice(&v.to_le_bytes());
        });
        std::fs::write(&cache, &b).unwrap();
        // Whatever the cache holds, the matrix is the source's.
        let m = nlsim::formats::cache::load_matrix_market(&src, "K")
            .unwrap()
            .to_dense();
        assert_eq!(m, want, "a damaged cache was trusted");
        None
    }));

    // HDF5 matrices: well-formed files with hostile shapes, types and indices.
    let h5 = dir.join("m.h5");
    panics.extend(survive("hdf5 matrix", 1000 * scale(), |_| {
        let _ = std::fs::remove_file(&h5);
        let write = |rng: &mut Rng| -> hdf5_metno::Result<()> {
            let f = hdf5_metno::File::create(&h5)?;
            let n = *rng.pick(&[0usize, 1, 2, 3, 5]);
            if rng.below(3) == 0 {
                let rows = *rng.pick(&[0usize, 1, 2, 3]);
                let cols = *rng.pick(&[0usize, 1, 2, 3]);
                let data: Vec<f64> = (0..rows * cols)
                    .map(|_| *rng.pick(&[1.0, -1.0, 0.0, f64::NAN, 1e308]))
                    .collect();
                f.new_dataset::<f64>()
                    .shape((rows, cols))
                    .create("obj")?
                    .write_raw(&data)?;
                return Ok(());
            }
            let g = f.create_group("obj")?;
            let len = |rng: &mut Rng| *rng.pick(&[0usize, 1, 2, 3, 4, 6]);
            let idx = |rng: &mut Rng| *rng.pick(&[-1i64, 0, 1, 2, 3, 7, i64::MAX]);
            // A valid 3 x 3 CSR (a diagonal) with one thing changed, or random arrays.
            let (mut indices, mut indptr, mut data): (Vec<i64>, Vec<i64>, Vec<f64>) =
                (vec![0, 1, 2], vec![0, 1, 2, 3], vec![1.0, 2.0, 3.0]);
            let n = if rng.below(2) == 0 {
                match rng.below(5) {
                    0 => indices[rng.below(3)] = idx(rng),
                    1 => indptr[rng.below(4)] = idx(rng),
                    2 => data[rng.below(3)] = *rng.pick(&[f64::NAN, -1e308, 0.0]),
                    3 => {
                        indices.pop();
                    }
                    _ => {}
                }
                3
            } else {
                indices = (0..len(rng)).map(|_| idx(rng)).collect();
                indptr = (0..len(rng)).map(|_| idx(rng)).collect();
                data = (0..len(rng))
                    .map(|_| *rng.pick(&[1.0, -2.0, f64::INFINITY]))
                    .collect();
                n
            };
            if rng.below(4) == 0 {
                let as_f: Vec<f64> = indices.iter().map(|&v| v as f64 + 0.5).collect();
                g.new_dataset_builder().with_data(&as_f).create("indices")?;
            } else {
                g.new_dataset_builder()
                    .with_data(&indices)
                    .create("indices")?;
            }
            g.new_dataset_builder()
                .with_data(&indptr)
                .create("indptr")?;
            g.new_dataset_builder().with_data(&data).create("data")?;
            if rng.below(5) != 0 {
                let shape = [*rng.pick(&[n as i64, -1, 0, 1 << 40]), n as i64];
                g.new_attr::<i64>()
                    .shape(2)
                    .create("shape")?
                    .write(&shape)?;
            }
            Ok(())
        };
        if write(&mut rng).is_err() {
            return Some("not written".into());
        }
        nlsim::formats::matrices::read_hdf5_matrix(&h5, "/obj", "K")
            .err()
            .map(|e| e.to_string())
    }));

    // Stepped-sine test data (CSV), validated as the readers do.
    let test_csv = [
        "# nlsim stepped-sine test data\n# input: shaker\n# harmonics: 2\n\
         # channel: tip, acceleration, relative=0.02, absolute=0\n\
         # channel: mid, velocity, relative=0.01, absolute=1e-6\n\
         sweep,direction,frequency_hz,harmonic,force_re,force_im,tip_re,tip_im,mid_re,mid_im\n\
         low,up,22.0,1,0.05,0,-0.513,0.207,0.1,0.2\nlow,up,22.0,2,0.001,0,0.01,0.002,,\n\
         low,up,23.5,1,0.05,0.001,-0.9,0.4,0.15,0.25\nlow,up,23.5,2,0,0,0.02,0.001,,\n\
         high,down,23.0,1,0.2,0,-1.5,0.9,0.3,0.1\nhigh,down,23.0,2,0.01,0,0.1,0.05,0.01,0\n"
            .to_string(),
        // With per-step standard deviations.
        "# nlsim stepped-sine test data\n# input: shaker\n# harmonics: 2\n\
         # channel: tip, acceleration, relative=0.02, absolute=0\n\
         sweep,direction,frequency_hz,harmonic,force_re,force_im,tip_re,tip_im,tip_re_std,tip_im_std\n\
         low,up,22.0,1,0.05,0,-0.513,0.207,0.004,0.002\nlow,up,22.0,2,0.001,0,0.01,0.002,,\n\
         low,up,23.5,1,0.05,0.001,-0.9,0.4,1e-3,5e-4\nlow,up,23.5,2,0,0,0.02,0.001,1e-4,1e-4\n"
            .to_string(),
        // A voltage record (no force gauge).
        "# nlsim stepped-sine test data\n# input: shaker, voltage\n# harmonics: 1\n\
         # channel: tip, acceleration, relative=0.02, absolute=0\n\
         sweep,direction,frequency_hz,harmonic,force_re,force_im,tip_re,tip_im\n\
         low,up,22.0,1,0.01,0.004,-0.513,0.207\nlow,up,23.5,1,0.01,0.004,-0.9,0.4\n"
            .to_string(),
    ];
    let csv_path = dir.join("test.csv");
    panics.extend(survive("test data csv", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&test_csv).clone().as_str(), &mut rng);
        match nlsim::formats::test_data::parse_csv(&text, &csv_path) {
            // What was read is written back and read again: the writer refuses what the
            // reader would.
            Ok(d) => {
                let back = dir.join("back.csv");
                nlsim::formats::test_data::write_csv(&back, &d)
                    .and_then(|()| nlsim::formats::test_data::read_csv(&back))
                    .err()
                    .map(|e| e.to_string())
            }
            Err(e) => Some(e.to_string()),
        }
    }));

    // Amplitude-and-phase tables (the Brake–Reuss layout and a two-channel one).
    let tables = [
        "control,level,frequency_hz,force_amplitude_n,accel_amplitude_m_s2,phase_rad\n\
         force,1,79.0,0.24,12.3,-0.11\nforce,1,79.05,0.25,12.9,-0.12\n\
         response,1,79.2,0.05,5.0,-0.2\nresponse,1,79.25,0.05,5.1,-0.3\n"
            .to_string(),
        "# exported\nrun,frequency_hz,force_amplitude_n,force_phase_rad,tip_amplitude_m,\
         tip_phase_rad,mid_amplitude_m_s,mid_phase_rad\n\
         a,20.0,1.0,0.1,1e-4,-0.5,2e-3,1.0\na,21.0,1.0,0.1,2e-4,-0.9,3e-3,0.5\n\
         b,21.0,2.0,0.0,4e-4,-1.0,6e-3,0.4\nb,20.0,2.0,0.0,2e-4,-0.6,4e-3,0.9\n"
            .to_string(),
        "level,frequency_hz,voltage_amplitude_v,voltage_phase_rad,tip_amplitude_m_s2,tip_phase_rad\n\
         1,79.0,0.5,0.0,12.3,-0.11\n1,79.05,0.5,0.0,12.9,-0.12\n"
            .to_string(),
    ];
    let table_path = dir.join("table.csv");
    panics.extend(survive("amplitude-phase table", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&tables).clone().as_str(), &mut rng);
        match nlsim::formats::test_data::parse_amplitude_phase(
            &text,
            &table_path,
            "shaker",
            nlsim::calib::Noise::relative(0.02),
        ) {
            // What was read is valid test data: nlsim's CSV writer takes it and reads it back.
            Ok(d) => {
                let back = dir.join("table-back.csv");
                nlsim::formats::test_data::write_csv(&back, &d)
                    .and_then(|()| nlsim::formats::test_data::read_csv(&back))
                    .err()
                    .map(|e| e.to_string())
            }
            Err(e) => Some(e.to_string()),
        }
    }));

    // Raw time histories and step tables (`nlsim harmonics`), and the dwell fit on what
    // they hold: a record that reads must fit or be refused, never panic.
    let mut rec = String::from("# raw\ntime_s,shaker,tip\n");
    for i in 0..120 {
        let t = i as f64 / 100.0;
        let w = 2.0 * std::f64::consts::PI * 5.0 * t;
        rec.push_str(&format!(
            "{t},{},{}\n",
            0.2 * w.sin(),
            3.0 * (w - 0.4).sin()
        ));
    }
    let records = [rec];
    let rec_path = dir.join("records.csv");
    panics.extend(survive("time histories", 2000 * scale(), |_| {
        let text = mutate(rng.pick(&records).clone().as_str(), &mut rng);
        fit_records(nlsim::formats::time_records::parse_records(
            &text, &rec_path,
        ))
    }));
    let tables =
        ["# steps\nstart_s,end_s,frequency_hz,sweep\n0,0.5,5.0,up\n0.5,1.1,5.5,up\n".to_string()];
    let steps_path = dir.join("steps.csv");
    panics.extend(survive("step table", 2000 * scale(), |_| {
        let text = mutate(rng.pick(&tables).clone().as_str(), &mut rng);
        nlsim::formats::time_records::parse_step_table(&text, &steps_path)
            .err()
            .map(|e| e.to_string())
    }));

    // Measured modes (CSV) for a model with DOFs 2:ux..6:ux.
    let chain = nlsim::load_model(
        root()
            .join("examples/models/grouped_chain6.toml")
            .to_str()
            .unwrap(),
    )
    .unwrap()
    .model;
    let modal = [
        "# measured\nmode,frequency_hz,frequency_std_hz,2:ux,4:ux,6:ux\n\
         1,5.0,0.01,0.1,0.2,0.3\n2,13.5,0.02,,,\n3,21.0,0.05,0.3,-0.1,0.2\n"
            .to_string(),
    ];
    let modal_path = dir.join("modes.csv");
    panics.extend(survive("modal csv", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&modal).clone().as_str(), &mut rng);
        nlsim::formats::modal_data::parse_modal_csv(&text, &modal_path, &chain, 0.02)
            .err()
            .map(|e| e.to_string())
    }));

    // Universal files, dataset 58: ASCII as text, binary as bytes.
    let rec = |id: &str, dir: i64| nlsim::formats::uff::Uff58 {
        id: id.into(),
        function_type: 4,
        response_node: 21,
        response_direction: dir,
        reference_node: 21,
        reference_direction: 3,
        ordinate_type: 12,
        denominator_type: 13,
        frequencies_hz: vec![10.0, 10.5, 11.0, 11.5],
        values: vec![
            faer::c64::new(0.1, -0.2),
            faer::c64::new(0.3, 0.1),
            faer::c64::new(-0.2, 0.4),
            faer::c64::new(0.05, -0.01),
        ],
    };
    let recs = vec![rec("tip", 3), rec("NONE", -2)];
    let uff_ascii = dir.join("a.uff");
    let uff_binary = dir.join("b.uff");
    nlsim::formats::uff_write::write(&uff_ascii, &recs, false).unwrap();
    nlsim::formats::uff_write::write(&uff_binary, &recs, true).unwrap();
    let ascii = [std::fs::read_to_string(&uff_ascii).unwrap()];
    let binary = std::fs::read(&uff_binary).unwrap();
    let to_data = |r: nlsim::Result<Vec<nlsim::formats::uff::Uff58>>| -> Option<String> {
        match r.and_then(|v| {
            nlsim::formats::uff::to_test_data(&v, "shaker", nlsim::calib::Noise::relative(0.01))
        }) {
            Ok(_) => None,
            Err(e) => Some(e.to_string()),
        }
    };
    panics.extend(survive("uff58 ascii", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&ascii).clone().as_str(), &mut rng);
        to_data(nlsim::formats::uff::parse(
            text.as_bytes(),
            Path::new("a.uff"),
        ))
    }));
    panics.extend(survive("uff58 binary", 10000 * scale(), |_| {
        let mut b = binary.clone();
        damage(&mut b, &mut rng, |b, rng| {
            // A header field (byte order, format, line and byte counts) set to a hostile
            // value.
            if let Some(i) = b.windows(3).position(|w| w == b"58b") {
                let v = rng.pick(HOSTILE).as_bytes();
                let at = i + 4 + 6 * rng.below(4);
                if at + v.len() < b.len() {
                    b[at..at + v.len()].copy_from_slice(v);
                }
            }
        });
        to_data(nlsim::formats::uff::parse(&b, Path::new("b.uff")))
    }));

    // Universal-file time records (function type 1) as `nlsim harmonics` reads them, and
    // the dwell fit on what they hold.
    let time_fn = |id: &str, ordinate: i64, lag: f64| nlsim::formats::uff_write::UffFunction {
        id: id.into(),
        function_type: 1,
        response: (21, 3),
        reference: (0, 0),
        abscissa_type: 17,
        ordinate_type: ordinate,
        denominator_type: 0,
        abscissa: nlsim::formats::uff_write::Abscissa::Even {
            start: 0.0,
            step: 0.01,
        },
        values: (0..120)
            .map(|i| {
                faer::c64::new(
                    (2.0 * std::f64::consts::PI * 0.05 * i as f64 - lag).sin(),
                    0.0,
                )
            })
            .collect(),
        complex: false,
    };
    let uff_time = dir.join("t.uff");
    nlsim::formats::uff_write::write_functions(
        &uff_time,
        &[time_fn("shaker", 13, 0.0), time_fn("NONE", 12, 0.4)],
        false,
        // Coordinates: a dataset 2411 before the records, which the reader skips.
        &[
            (1, [0.0, 0.5, -1.0]),
            (2, [1.0, 0.0, 0.0]),
            (21, [0.7, 0.0, 0.0]),
        ],
    )
    .unwrap();
    let times = [std::fs::read_to_string(&uff_time).unwrap()];
    panics.extend(survive("uff58 time records", 3000 * scale(), |_| {
        let text = mutate(rng.pick(&times).clone().as_str(), &mut rng);
        fit_records(
            nlsim::formats::uff::parse(text.as_bytes(), &uff_time)
                .and_then(|v| nlsim::formats::time_records::from_uff(&v, &uff_time)),
        )
    }));

    // Calibration, plan and test files (parsed and checked; no model is loaded).
    let calibration = [
        "model = \"ecl_beam\"\ndata = \"test.csv\"\nset = { \"tip.c\" = 0.5 }\nharmonics = 3\n\
         compare = [1, 3]\nform = \"complex\"\nbranch = \"nearest\"\nmodes = 20\nlhs = 64\n\
         starts = 3\nfolds = 10\nseed = 1\nmaximin_swaps = 2000\nreport = \"cal\"\n\n\
         [[param]]\nname = \"tip.k3\"\nlower = 1e8\nupper = 1e11\nspacing = \"log\"\n\n\
         [lm]\nmax_iterations = 100\n"
            .to_string(),
        // A modal model's shape entry and residual term (issue 44 part 1).
        "model = \"examples/models/ecl_modal.toml\"\ndata = \"test.csv\"\nmodes = 4\n\n\
         [[param]]\nname = \"mode2.shape:21:uz\"\nlower = -3.0\nupper = -1.0\n\n\
         [[param]]\nname = \"residual:shaker:tip\"\nlower = 0.0\nupper = 1e-5\n"
            .to_string(),
        // A calibration's result with its cross validation's held-out mean square.
        "model = \"ecl_beam\"\ndata = \"test.csv\"\ntrain = [\"a\"]\nfolds = 1\n\
         fold_by = \"sweeps\"\n\n[[param]]\nname = \"tip.k3\"\nlower = 1e8\nupper = 1e11\n\n\
         [result]\nstatus = \"converged\"\nestimate = [1e9]\ncovariance = [[1e14]]\n\
         reduced_chi2 = 5.8\npoints = 41\nresiduals = 82\nheld_out_mean_square = 24.5\n"
            .to_string(),
    ];
    let cal_path = dir.join("cal.toml");
    panics.extend(survive("calibration file", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&calibration).clone().as_str(), &mut rng);
        nlsim::commands::calibrate::CalibrationRequest::parse(&text, &cal_path)
            .err()
            .map(|e| e.to_string())
    }));
    let plans = [
        "params = [\"tip_spring.k3\", \"mode2.zeta\"]\ncriterion = \"D\"\nlevels = [0.05, 0.1]\n\
         measured = [[1], [1, 3]]\nsensor_counts = [1, 2]\n\
         noise = { relative = 0.01, absolute = 1e-3 }\nharmonics = 3\nmodes = 20\ntop = 10\n\
         report = \"plan-report\"\n\n[[actuator]]\nname = \"mid_drive\"\ndof = \"11:uz\"\n\n\
         [[sensor]]\nname = \"n7\"\ndof = \"7:uz\"\nquantity = \"acceleration\"\n\n\
         [[signal]]\nlabel = \"sine+3h\"\nside = [{ harmonic = 3, fraction = 0.05 }]\n\n\
         [[band]]\nlabel = \"across\"\nfrom = 22.0\nto = 30.0\nsteps = 9\n"
            .to_string(),
        // Gains planned along (issue 44).
        "params = [\"tip_spring.k3\", \"input_gain\", \"sensor_gain:tip\"]\nlevels = [0.1]\n\
         [[band]]\nlabel = \"b\"\nfrom = 22.0\nto = 26.0\nsteps = 5\n"
            .to_string(),
    ];
    let plan_path = dir.join("plan.toml");
    panics.extend(survive("plan file", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&plans).clone().as_str(), &mut rng);
        nlsim::commands::plan::PlanRequest::parse(&text, &plan_path, "ecl_beam")
            .err()
            .map(|e| e.to_string())
    }));
    let tests = [
        "drive = \"shaker\"\nharmonics = 3\nmodes = 20\nseed = 1\nnoise = { relative = 0.02 }\n\
         force_noise = { relative = 0.0 }\nout = \"virtual_test.csv\"\nreport = \"test-report\"\n\
         channels = [\"tip\", \"mid\"]\n\n[shaker]\narmature_mass = 0.03\n\
         suspension_stiffness = 3e3\nsuspension_damping = 2.0\nresistance = 1.5\n\
         inductance = 2e-4\nforce_constant = 4.0\nstinger_stiffness = 2e5\n\n[control]\n\
         enabled = true\ntolerance = 0.01\nmax_iterations = 20\n\n[[sweep]]\n\
         label = \"0.2 N up\"\nfrom = 21.0\nto = 30.0\nsteps = 19\nforce = 0.2\n"
            .to_string(),
        "harmonics = 3\nrecord = \"voltage\"\namplifier_gain = 2.0\n\n[raw]\nout = \"raw.h5\"\n\
         rate = 9500\ndwell = 8.1\noversample = 4\n\n[[sweep]]\nfrom = 22.0\nto = 24.0\n\
         steps = 3\nforce = 0.1\n"
            .to_string(),
    ];
    let test_path = dir.join("test.toml");
    panics.extend(survive("test file", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&tests).clone().as_str(), &mut rng);
        nlsim::commands::test::TestRequest::parse(&text, &test_path, "ecl_beam")
            .err()
            .map(|e| e.to_string())
    }));

    // Stepped-sine test data (HDF5): nlsim's layout written, then one to three objects or
    // attributes deleted or replaced by hostile ones (wrong type, wrong or huge shape,
    // hostile values); what is read is written back as CSV and read again.
    let base = nlsim::formats::test_data::parse_csv(&test_csv[0], &csv_path).unwrap();
    let td_h5 = dir.join("test.h5");
    let objects = [
        "channels/name",
        "channels/quantity",
        "channels/noise_relative",
        "channels/noise_absolute",
        "sweeps/sweep0/frequency_hz",
        "sweeps/sweep0/force",
        "sweeps/sweep1/response",
        "sweeps/sweep1",
        "sweeps",
    ];
    let attributes = [
        ("", "format"),
        ("", "input"),
        ("", "harmonics"),
        ("sweeps/sweep0", "label"),
        ("sweeps/sweep1", "label"),
        ("sweeps/sweep1", "direction"),
    ];
    panics.extend(survive("test data hdf5", 10000 * scale(), |_| {
        let _ = std::fs::remove_file(&td_h5);
        nlsim::formats::test_data::write_h5(&td_h5, &base).unwrap();
        let edit = |rng: &mut Rng| -> hdf5_metno::Result<()> {
            let f = hdf5_metno::File::open_rw(&td_h5)?;
            for _ in 0..1 + rng.below(3) {
                if rng.below(2) == 0 {
                    let name = *rng.pick(&objects);
                    let _ = f.unlink(name);
                    if rng.below(4) != 0 {
                        hostile_dataset(&f, name, rng)?;
                    }
                } else {
                    let (at, name) = *rng.pick(&attributes);
                    let loc: hdf5_metno::Group = if at.is_empty() {
                        f.group("/")?
                    } else {
                        f.group(at)?
                    };
                    let _ = loc.delete_attr(name);
                    hostile_attr(&loc, name, rng)?;
                }
            }
            Ok(())
        };
        if edit(&mut rng).is_err() {
            return Some("not edited".into());
        }
        match nlsim::formats::test_data::read_h5(&td_h5) {
            Ok(d) => {
                let back = dir.join("back_h5.csv");
                nlsim::formats::test_data::write_csv(&back, &d)
                    .and_then(|()| nlsim::formats::test_data::read_csv(&back))
                    .err()
                    .map(|e| e.to_string())
            }
            Err(e) => Some(e.to_string()),
        }
    }));

    // Time records in HDF5 (`nlsim harmonics`): a good file of a time base and three
    // signals in /inputs, /outputs and at the root, with datasets replaced by hostile ones
    // (types, shapes, NaN, huge declared sizes) and lengths changed; what reads is fitted.
    let rec_h5 = dir.join("records.h5");
    let signals = [
        "time",
        "inputs/shaker",
        "outputs/tip",
        "mid",
        "outputs",
        "inputs",
    ];
    panics.extend(survive("time records hdf5", 3000 * scale(), |_| {
        let _ = std::fs::remove_file(&rec_h5);
        let write = |rng: &mut Rng| -> hdf5_metno::Result<()> {
            let f = hdf5_metno::File::create(&rec_h5)?;
            let n = *rng.pick(&[400usize, 399, 2, 1]);
            let t: Vec<f64> = (0..n).map(|i| i as f64 / 1000.0).collect();
            let sine = |a: f64, m: usize| -> Vec<f64> {
                (0..m)
                    .map(|i| a * (2.0 * std::f64::consts::PI * 25.0 * i as f64 / 1000.0).sin())
                    .collect()
            };
            f.new_dataset_builder().with_data(&t).create("time")?;
            f.create_group("inputs")?
                .new_dataset_builder()
                .with_data(&sine(0.2, n))
                .create("shaker")?;
            let m = if rng.below(4) == 0 {
                n.saturating_sub(1)
            } else {
                n
            };
            f.create_group("outputs")?
                .new_dataset_builder()
                .with_data(&sine(3.0, m))
                .create("tip")?;
            f.new_dataset_builder()
                .with_data(&sine(1.0, n))
                .create("mid")?;
            for _ in 0..rng.below(3) {
                let name = *rng.pick(&signals);
                let _ = f.unlink(name);
                if rng.below(4) != 0 {
                    let (group, leaf) = name.rsplit_once('/').unwrap_or(("/", name));
                    let loc = match f.group(group) {
                        Ok(g) => g,
                        Err(_) => f.create_group(group)?,
                    };
                    hostile_dataset(&loc, leaf, rng)?;
                }
            }
            Ok(())
        };
        if write(&mut rng).is_err() {
            return Some("not written".into());
        }
        fit_records(nlsim::formats::time_records_h5::read_records_h5(&rec_h5))
    }));

    // The candidates file of a merged calibrate-candidates batch or of an interrupted
    // calibration: its attributes and two tables with hostile types, shapes and values.
    let cands = dir.join("candidates.h5");
    panics.extend(survive("candidates file", 10000 * scale(), |_| {
        let _ = std::fs::remove_file(&cands);
        let write = |rng: &mut Rng| -> hdf5_metno::Result<()> {
            let f = hdf5_metno::File::create(&cands)?;
            let root = f.group("/")?;
            if rng.below(6) != 0 {
                let c = *rng.pick(&["calibrate-candidates", "calibrate-folds", ""]);
                let v: hdf5_metno::types::VarLenUnicode = c.parse().unwrap();
                root.new_attr::<hdf5_metno::types::VarLenUnicode>()
                    .create("command")?
                    .write_scalar(&v)?;
            } else {
                hostile_attr(&root, "command", rng)?;
            }
            if rng.below(4) != 0 {
                root.new_attr::<u64>()
                    .create("complete")?
                    .write_scalar(rng.pick(&[1u64, 1, 1, 0, u64::MAX]))?;
            } else {
                hostile_attr(&root, "complete", rng)?;
            }
            // The mark of an interrupted calibration's file (NaN costs: not evaluated).
            match rng.below(4) {
                0 => root
                    .new_attr::<u64>()
                    .create("interrupted")?
                    .write_scalar(rng.pick(&[1u64, 0, 2]))?,
                1 => hostile_attr(&root, "interrupted", rng)?,
                _ => {}
            }
            let rows = *rng.pick(&[0usize, 1, 2, 3]);
            let cols = *rng.pick(&[0usize, 1, 2]);
            if rng.below(3) != 0 {
                let v: Vec<f64> = (0..rows * cols)
                    .map(|_| *rng.pick(&[1.0, 2.5e10, 0.0, -1.0, f64::NAN, 1e308, f64::INFINITY]))
                    .collect();
                f.new_dataset::<f64>()
                    .shape((rows, cols))
                    .create("parameters")?
                    .write_raw(&v)?;
            } else {
                hostile_dataset(&f, "parameters", rng)?;
            }
            if rng.below(3) != 0 {
                let v: Vec<f64> = (0..rows)
                    .map(|_| *rng.pick(&[1.0, 0.0, f64::NAN, f64::INFINITY, -1.0]))
                    .collect();
                f.new_dataset_builder().with_data(&v).create("cost")?;
            } else {
                hostile_dataset(&f, "cost", rng)?;
            }
            Ok(())
        };
        if write(&mut rng).is_err() {
            return Some("not written".into());
        }
        nlsim::formats::candidates::read_candidates(&cands)
            .err()
            .map(|e| e.to_string())
    }));

    // A start file (`frf --start-file`) for the Duffing oscillator's harmonic balance system:
    // nlsim's layout with hostile attributes, shapes and values.
    let duffing = nlsim::fixtures::duffing_fig3().model;
    let reduced = nlsim::reduction::reduce(
        &duffing,
        &nlsim::reduction::ReductionConfig::lowest(duffing.n_dofs()),
    )
    .unwrap();
    let system = nlsim::hb::HbSystem::from_model(
        &duffing,
        &reduced,
        nlsim::hb::HarmonicSet::new(3, 1).unwrap(),
        nlsim::hb::HbConfig::default(),
    )
    .unwrap();
    let start = nlsim::commands::frf::StartFile {
        path: dir.join("start.h5"),
        at_hz: None,
    };
    panics.extend(survive("start file", 10000 * scale(), |_| {
        let _ = std::fs::remove_file(&start.path);
        let write = |rng: &mut Rng| -> hdf5_metno::Result<()> {
            let f = hdf5_metno::File::create(&start.path)?;
            let root = f.group("/")?;
            let h = *rng.pick(&[3.0, 3.0, 1.0, 5.0, 0.0, 2.5, 1e308, f64::NAN]);
            for (name, v) in [("harmonics", h), ("subharmonic_order", 1.0)] {
                if rng.below(8) != 0 {
                    root.new_attr::<f64>()
                        .create(name)?
                        .write_scalar(&if rng.below(8) == 0 { h } else { v })?;
                } else {
                    hostile_attr(&root, name, rng)?;
                }
            }
            let n = *rng.pick(&[0usize, 1, 2, 5]);
            if rng.below(6) != 0 {
                let hz: Vec<f64> = (0..n)
                    .map(|_| *rng.pick(&[30.0, 31.0, 1e308, f64::NAN, -1.0, 1e-320]))
                    .collect();
                f.new_dataset_builder().with_data(&hz).create("frequency")?;
            } else {
                hostile_dataset(&f, "frequency", rng)?;
            }
            let els = f.create_group("elements")?;
            let hf = if h.is_finite() && (1.0..=5.0).contains(&h) {
                h as usize
            } else {
                3
            };
            for (e, el) in system.elements().iter().enumerate() {
                let m = system.coordinates(e).len();
                let name = if rng.below(10) == 0 {
                    "other"
                } else {
                    el.name()
                };
                if rng.below(5) != 0 {
                    let cols = m * (2 * hf + 1) + usize::from(rng.below(6) == 0);
                    let v: Vec<f64> = (0..n * cols)
                        .map(|_| *rng.pick(&[0.01, -0.02, 0.0, 1e308, f64::NAN]))
                        .collect();
                    els.new_dataset::<f64>()
                        .shape((n, cols))
                        .create(name)?
                        .write_raw(&v)?;
                } else {
                    hostile_dataset(&els, name, rng)?;
                }
            }
            Ok(())
        };
        if write(&mut rng).is_err() {
            return Some("not written".into());
        }
        match nlsim::commands::frf::start::read_start(&start, &system, 20.0, 40.0) {
            Ok(p) => {
                // What is accepted is usable: finite unknowns of this system's size.
                assert_eq!(p.x.len(), system.n_unknowns());
                assert!(p.x.iter().all(|v| v.is_finite()) && p.hz.is_finite());
                None
            }
            Err(e) => Some(e.to_string()),
        }
    }));

    // A prior information matrix (`plan`'s `prior = "fim_best.csv"`).
    let params: Vec<nlsim::kernel::Param> = ["tip_spring.k3", "mode2.zeta"]
        .iter()
        .map(|p| p.parse().unwrap())
        .collect();
    let fim = faer::Mat::from_fn(2, 2, |i, j| if i == j { 4.0 } else { 1.5 });
    let priors = [nlsim::commands::plan::fim_csv(&params, &fim)];
    let prior_path = dir.join("fim_best.csv");
    panics.extend(survive("prior csv", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&priors).clone().as_str(), &mut rng);
        std::fs::write(&prior_path, text).unwrap();
        match nlsim::commands::plan::read_fim_csv(&prior_path, &params) {
            Ok(f) => {
                // What is accepted is symmetric with a non-negative, finite diagonal.
                assert!((0..2).all(|i| f[(i, i)] >= 0.0 && f[(i, i)].is_finite()));
                None
            }
            Err(e) => Some(e.to_string()),
        }
    }));

    // FE codes' matrices: Nastran DMIG (small, large and free field) and Abaqus coordinate
    // files, read and placed on the DOFs they name.
    let dmig = [
        std::fs::read_to_string(root().join("examples/models/spring_mass_dmig.bdf")).unwrap(),
        "DMIG    KAAX    0       6       2       0                       2\n\
         DMIG    KAAX    1       3               1       3       2.0+6\n\
         +       2       3       -1.0+6\n\
         DMIG    KAAX    2       3               2       3       1.0+6\n"
            .to_string(),
        "DMIG,KAAX,0,6,2,0,,,2\nDMIG,KAAX,1,3,,1,3,2.0E6,,\n+,2,3,-1.0E6\n\
         DMIG,KAAX,2,3,,2,3,1.0E6\n"
            .to_string(),
        // Free field with a named continuation marker in field 10, and a line whose fields
        // run past it (refused: they would be lost).
        "DMIG,KAAX,0,6,2,0,,,2\nDMIG,KAAX,1,3,,1,3,2.0E6,,+C1,,\n+C1,2,3,-1.0E6\n\
         DMIG,KAAX,2,3,,2,3,1.0E6,,2,3,4.0\n"
            .to_string(),
    ];
    let fe_place = |m: nlsim::formats::fe_matrices::LabelledMatrix| -> Option<String> {
        nlsim::formats::fe_matrices::union_dofs(&[&m])
            .and_then(|d| m.onto(&d, "stiffness matrix", 1e-12))
            .err()
            .map(|e| e.to_string())
    };
    panics.extend(survive("dmig", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&dmig).clone().as_str(), &mut rng);
        match nlsim::formats::dmig::parse_dmig(&text, Path::new("k.pch"), "KAAX") {
            Ok(m) => fe_place(m),
            Err(e) => Some(e.to_string()),
        }
    }));
    // Node numbers of every width in universal files (datasets 2411 and 58): written only
    // where the I10 fields hold them, and read back as written.
    let wide = [
        0i64,
        1,
        21,
        999_999_999,
        2_147_483_647,
        2_147_483_648,
        9_999_999_999,
        10_000_000_000,
        -1,
        i64::MAX,
        i64::MIN,
    ];
    panics.extend(survive("uff node ids", 10000 * scale(), |_| {
        let node = rng.pick(&wide).wrapping_add([0, 1, -1][rng.below(3)]);
        let reference = *rng.pick(&wide);
        let f = nlsim::formats::uff_write::UffFunction {
            id: "tip".into(),
            function_type: 4,
            response: (node, 3),
            reference: (reference, 3),
            abscissa_type: 18,
            ordinate_type: 12,
            denominator_type: 13,
            abscissa: nlsim::formats::uff_write::Abscissa::Uneven(vec![10.0, 11.0]),
            values: vec![faer::c64::new(1.0, -1.0); 2],
            complex: true,
        };
        let geometry: Vec<(u64, [f64; 3])> = [node, reference]
            .iter()
            .filter_map(|&n| u64::try_from(n).ok())
            .map(|n| (n, [0.0, 1.0, 2.0]))
            .collect::<std::collections::BTreeMap<_, _>>()
            .into_iter()
            .collect();
        let binary = rng.below(2) == 0;
        let path = Path::new("ids.uff");
        match nlsim::formats::uff_write::encode_functions(path, &[f], binary, &geometry) {
            Err(e) => Some(e.to_string()),
            Ok(bytes) => {
                let back = nlsim::formats::uff::parse(&bytes, path).expect("written files read");
                assert_eq!(back.len(), 1);
                assert_eq!(
                    (back[0].response_node, back[0].reference_node),
                    (node, reference)
                );
                None
            }
        }
    }));

    // The values of a `[modal]` model file replaced by hostile numbers: refused at their
    // key, or a model that validates (no later failure without a file and key).
    let modal_text =
        std::fs::read_to_string(root().join("examples/models/ecl_modal.toml")).unwrap();
    let modal_path = models.join("modal.toml");
    let numbers = [
        "1e308",
        "-1e308",
        "1e-320",
        "-1e-320",
        "1e151",
        "1e-151",
        "1e150",
        "0.0",
        "-0.0",
        "nan",
        "inf",
        "5e-324",
        "1.7976931348623157e308",
    ];
    panics.extend(survive("modal values", 10000 * scale(), |_| {
        let lines: Vec<&str> = modal_text.lines().collect();
        let candidates: Vec<usize> = (0..lines.len())
            .filter(|&i| lines[i].contains('=') && lines[i].contains(|c: char| c.is_ascii_digit()))
            .collect();
        let i = *rng.pick(&candidates);
        let (key, value) = lines[i].split_once('=').unwrap();
        let hostile = *rng.pick(&numbers);
        let value = if value.trim_start().starts_with('[') {
            let parts: Vec<&str> = value.trim().trim_matches(['[', ']']).split(',').collect();
            let k = rng.below(parts.len());
            let parts: Vec<&str> = parts
                .iter()
                .enumerate()
                .map(|(j, p)| if j == k { hostile } else { p })
                .collect();
            format!("[{}]", parts.join(","))
        } else {
            hostile.to_string()
        };
        let mut edited: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        edited[i] = format!("{key}= {value}");
        match nlsim::parse_model_file(&edited.join("\n"), &modal_path) {
            Ok(m) => m
                .model
                .validate(&nlsim::kernel::ValidationConfig::default())
                .err()
                .map(|e| e.to_string()),
            Err(e) => {
                let e = e.to_string();
                assert!(e.contains("modal.toml:"), "no file and line: {e}");
                Some(e)
            }
        }
    }));

    // Node coordinates of FE decks: Nastran GRID cards and Abaqus *NODE blocks (issue 45).
    let grids = [
        "BEGIN BULK\nGRID           1               0.      0.      0.\n\
         GRID*                 21                  7.0000000D-01   0.0000000D+00\n\
         *         0.0000000D+00\nGRID,3,0,1.-3,2.5,-4.E+2\nENDDATA\n"
            .to_string(),
    ];
    panics.extend(survive("nastran grid", 5000 * scale(), |_| {
        let text = mutate(rng.pick(&grids).clone().as_str(), &mut rng);
        nlsim::formats::dmig::parse_grids(&text, Path::new("g.bdf"))
            .err()
            .map(|e| e.to_string())
    }));
    let inp = [
        "*Heading\n** c\n*Node, nset=all\n1, 0., 0., 0.\n21, 0.7, 0.5\n\
                *Element, type=B31\n1, 1, 21\n"
            .to_string(),
    ];
    panics.extend(survive("abaqus nodes", 5000 * scale(), |_| {
        let text = mutate(rng.pick(&inp).clone().as_str(), &mut rng);
        nlsim::formats::abaqus::parse_inp_nodes(&text, Path::new("m.inp"))
            .err()
            .map(|e| e.to_string())
    }));
    let abaqus =
        [std::fs::read_to_string(root().join("examples/models/spring_mass_K.abq.mtx")).unwrap()];
    panics.extend(survive("abaqus mtx", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&abaqus).clone().as_str(), &mut rng);
        match nlsim::formats::abaqus::parse_abaqus(&text, Path::new("k.mtx")) {
            Ok(nlsim::formats::fe_matrices::FeMatrix::Labelled(m)) => fe_place(m),
            Ok(nlsim::formats::fe_matrices::FeMatrix::Numbered(m)) => Some(m.n.to_string()),
            Err(e) => Some(e.to_string()),
        }
    }));
    // Real Abaqus output (tests/data/fe_real): 3-column COORDINATE files (the first 60 lines
    // of EXUDYN's block, and all of FEMBeam's 5-column mass), labelled by equation from a
    // job's input file, then placed.
    let fe_real = root().join("tests/data/fe_real");
    let head = |file: &str, lines: usize| -> String {
        std::fs::read_to_string(fe_real.join(file))
            .unwrap()
            .lines()
            .take(lines)
            .map(|l| format!("{l}\n"))
            .collect()
    };
    let coordinate = [
        head("exudyn/blockC3D8_MASS1.mtx", 60),
        head("exudyn/rotorDiscTestSTIF1.mtx", 60),
        head("fembeam/model_MASS1.mtx", 60),
    ];
    let block_labels = nlsim::formats::abaqus::inp_equation_labels(
        &std::fs::read_to_string(fe_real.join("exudyn/blockC3D8.inp")).unwrap(),
        Path::new("block.inp"),
    )
    .unwrap();
    panics.extend(survive("abaqus coordinate", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&coordinate).clone().as_str(), &mut rng);
        match nlsim::formats::abaqus::parse_abaqus(&text, Path::new("k.mtx")) {
            Ok(nlsim::formats::fe_matrices::FeMatrix::Labelled(m)) => fe_place(m),
            Ok(nlsim::formats::fe_matrices::FeMatrix::Numbered(m)) => {
                match m.labelled(&block_labels, "block.inp") {
                    Ok(m) => fe_place(m),
                    Err(e) => Some(e.to_string()),
                }
            }
            Err(e) => Some(e.to_string()),
        }
    }));
    let inp = [
        std::fs::read_to_string(fe_real.join("exudyn/blockC3D8.inp")).unwrap(),
        std::fs::read_to_string(fe_real.join("fembeam/model.inp")).unwrap(),
        "*NODE\n1, 0., 0.\n2, 1., 0.\n3, 2., 0.\n*ELEMENT, TYPE=B21\n1, 1, 2\n\
         *ELEMENT, TYPE=T2D2\n2, 2, 3\n*ELEMENT, TYPE=C3D20\n3, 1, 2, 3, 1, 2, 3, 1, 2, 3,\n1, 2, 3\n"
            .to_string(),
    ];
    panics.extend(survive("abaqus inp equations", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&inp).clone().as_str(), &mut rng);
        match nlsim::formats::abaqus::inp_equation_labels(&text, Path::new("job.inp")) {
            Ok(labels) => nlsim::kernel::DofMap::new(labels)
                .err()
                .map(|e| e.to_string()),
            Err(e) => Some(e.to_string()),
        }
    }));
    // Ansys's DOF mapping vector (Matrix Market integer array), for matrices of 345 (the
    // rotor's: 3 DOFs per node) or other orders.
    let vector =
        [
            std::fs::read_to_string(fe_real.join("exudyn/rotorAnsysMatrixDofMappingVector.txt"))
                .unwrap(),
        ];
    panics.extend(survive("ansys mapping vector", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&vector).clone().as_str(), &mut rng);
        let n = *rng.pick(&[345usize, 690, 230, 344, 1, 0]);
        match nlsim::formats::equations::parse_ansys_mapping_vector(&text, Path::new("map.txt"), n)
        {
            Ok(labels) => nlsim::kernel::DofMap::new(labels)
                .err()
                .map(|e| e.to_string()),
            Err(e) => Some(e.to_string()),
        }
    }));

    // Nastran OUTPUT4 (ASCII, sparse strings) as pyNastran writes it.
    let op4 = [std::fs::read_to_string(root().join("examples/models/spring_mass.op4")).unwrap()];
    panics.extend(survive("op4 ascii", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&op4).clone().as_str(), &mut rng);
        match nlsim::formats::op4::parse_op4(
            &text,
            Path::new("k.op4"),
            Some("KAAX"),
            nlsim::formats::op4::Op4Role::Stiffness,
        ) {
            Ok(m) => resolve_symmetric(
                "k.op4",
                m.n,
                &m.entries,
                nlsim::formats::fe_matrices::Place::Line,
            ),
            Err(e) => Some(e.to_string()),
        }
    }));

    // Nastran OUTPUT4, binary, as `nlsim export --op4` writes it (both byte orders; the
    // spring-mass chain and a 120-DOF beam), words overwritten with hostile integers.
    let sm = nlsim::load_model(
        root()
            .join("examples/models/spring_mass.toml")
            .to_str()
            .unwrap(),
    )
    .unwrap()
    .model;
    let beam = nlsim::load_model("ecl_beam").unwrap().model;
    let op4_bin: Vec<Vec<u8>> = [
        nlsim::formats::op4_write::Op4Layout::BinaryLittleEndian,
        nlsim::formats::op4_write::Op4Layout::BinaryBigEndian,
    ]
    .into_iter()
    .flat_map(|l| {
        [&sm, &beam].map(|m| {
            nlsim::formats::op4_write::to_op4(&[("KAAX", m.stiffness()), ("MAAX", m.mass())], l)
        })
    })
    .chain(
        // Real Nastran files of the corpus: 64-bit words (MSC 2017), end-of-matrix records
        // that hold a double, repeated names.
        [
            "nas2cam_notall6_msc2017.op4",
            "nas2cam_notall6_nx2021.op4",
            "inboard_mk_csuper.op4",
        ]
        .map(|f| std::fs::read(root().join("tests/data/fe_real/pyyeti").join(f)).unwrap()),
    )
    .collect();
    panics.extend(survive("op4 binary", 10000 * scale(), |_| {
        let mut b = rng.pick(&op4_bin).clone();
        damage(&mut b, &mut rng, |b, rng| {
            let words = b.len() / 4;
            if words > 0 {
                let at = 4 * rng.below(words);
                let v: i32 = *rng.pick(&[
                    0,
                    -1,
                    1,
                    24,
                    48,
                    65_535,
                    65_536,
                    i32::MAX,
                    i32::MIN,
                    2_000_000_000,
                    (3 << 16) + 2,
                ]);
                let bytes = if rng.below(2) == 0 {
                    v.to_le_bytes()
                } else {
                    v.to_be_bytes()
                };
                b[at..at + 4].copy_from_slice(&bytes);
            }
        });
        let name = *rng.pick(&[Some("KAAX"), Some("MAAX"), Some("KAA@2"), Some("MXX"), None]);
        let role = *rng.pick(&[
            nlsim::formats::op4::Op4Role::Stiffness,
            nlsim::formats::op4::Op4Role::Mass,
        ]);
        match nlsim::formats::op4::parse_op4_binary(&b, Path::new("k.op4"), name, role) {
            Ok(m) => resolve_symmetric(
                "k.op4",
                m.n,
                &m.entries,
                nlsim::formats::fe_matrices::Place::Record,
            ),
            Err(e) => Some(e.to_string()),
        }
    }));

    // Ansys Harwell-Boeing (RSA as HBMAT writes it, RUA) and its mapping file.
    let hb = [
        std::fs::read_to_string(root().join("examples/models/spring_mass_K.rsa")).unwrap(),
        std::fs::read_to_string(root().join("examples/models/spring_mass_M.rsa")).unwrap(),
        "t                                                                       K\n\
         \x20           4             1             1             2             0\n\
         RUA                        2             2             4             0\n\
         (3I3)           (3I3)           (2E24.16)\n\
         \x20 1  3  5\n  1  2  1  2\n\
         \x20 2.0000000000000000E+00 -1.0000000000000000E+00\n\
         -1.0000000000000000E+00  1.0000000000000000E+00\n"
            .to_string(),
    ];
    panics.extend(survive("harwell-boeing", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&hb).clone().as_str(), &mut rng);
        match nlsim::formats::harwell_boeing::parse_harwell_boeing(&text, Path::new("k.rsa")) {
            Ok(m) => resolve_symmetric(
                "k.rsa",
                m.n,
                &m.entries,
                nlsim::formats::fe_matrices::Place::Line,
            ),
            Err(e) => Some(e.to_string()),
        }
    }));
    let mapping =
        [std::fs::read_to_string(root().join("examples/models/spring_mass_K.mapping")).unwrap()];
    panics.extend(survive("hb mapping", 10000 * scale(), |_| {
        let text = mutate(rng.pick(&mapping).clone().as_str(), &mut rng);
        match nlsim::formats::harwell_boeing::parse_mapping(&text, Path::new("k.mapping")) {
            Ok(labels) => nlsim::kernel::DofMap::new(labels)
                .err()
                .map(|e| e.to_string()),
            Err(e) => Some(e.to_string()),
        }
    }));

    std::fs::remove_dir_all(&dir).unwrap();
    assert!(panics.is_empty(), "panics: {panics:?}");
}

#[test]
fn readers_survive_mutated_inputs() {
    let exe = std::env::current_exe().unwrap();
    // 3 GB of address space: the readers need a few MB; a size read from a file and
    // trusted would need far more.
    let out = Command::new("sh")
        .arg("-c")
        .arg("ulimit -v 3000000; exec \"$0\" fuzz_inner --exact --ignored --nocapture --test-threads 1")
        .arg(&exe)
        .env("NLSIM_CACHE", "on")
        .output()
        .unwrap();
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    println!("{text}");
    assert!(
        out.status.success(),
        "the fuzzer failed or aborted:\n{text}"
    );
    assert!(text.contains("1 passed"), "{text}");
    for reader in [
        "model file",
        "matrix market",
        "jobs file",
        "matrix cache",
        "hdf5 matrix",
        "test data csv",
        "modal csv",
        "uff58 ascii",
        "uff58 binary",
        "calibration file",
        "plan file",
        "test file",
        "test data hdf5",
        "candidates file",
        "start file",
        "prior csv",
        "dmig",
        "abaqus mtx",
        "abaqus coordinate",
        "abaqus inp equations",
        "ansys mapping vector",
        "op4 ascii",
        "op4 binary",
        "harwell-boeing",
        "hb mapping",
    ] {
        assert!(
            text.contains(&format!("fuzz {reader}:")),
            "{reader} not fuzzed:\n{text}"
        );
    }
}
