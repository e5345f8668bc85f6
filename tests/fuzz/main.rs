//! Fuzzing of every parser: run configs, array files, schedules (calibration configs with explicit
//! steps), the other commands' configs, calibration logs and recordings (CSV and Parquet).
//!
//! Each target mutates seed inputs (the shipped configs and small tables) with byte and token
//! mutations, deterministically from a fixed seed, and feeds them to the library's reader in this
//! process: an input must be accepted or refused with an error, never panic, and take under a
//! second. A sample of the same inputs goes through the `gfcal` binary (`gfcal check`, `gfcal
//! calibrate`, `gfcal diagnose`), whose exit code must be 0, 1 or 2 (not a signal, not 101), with
//! a time limit.
//!
//! `cargo test` runs 2,000 inputs per target; CI sets `GFCAL_FUZZ_INPUTS=40000` (and
//! `GFCAL_FUZZ_PROCESS_INPUTS`) and prints the counts (`--nocapture`).

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use gfcal::array::wiring::RecordingArray;
use gfcal::config::array::load_recording_array;
use gfcal::discrepancy::log::CalibrationLog;
use gfcal::selfcal::recording::Recording;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

const REPO: &str = env!("CARGO_MANIFEST_DIR");
const MIMU: &str = "configs/arrays/mimu4444_corners.toml";
/// The slowest an input may be, in process.
const SLOW: Duration = Duration::from_secs(1);

fn count(var: &str, default: usize) -> usize {
    std::env::var(var).ok().and_then(|v| v.parse().ok()).unwrap_or(default)
}

fn inputs() -> usize {
    count("GFCAL_FUZZ_INPUTS", 2_000)
}

fn process_inputs() -> usize {
    count("GFCAL_FUZZ_PROCESS_INPUTS", 20)
}

fn repo(path: &str) -> PathBuf {
    Path::new(REPO).join(path)
}

fn read(path: &str) -> Vec<u8> {
    std::fs::read(repo(path)).unwrap_or_else(|e| panic!("seed {path}: {e}"))
}

/// Values that break parsers and validators: extremes, non-numbers, wrong types.
const TOKENS: &[&str] = &[
    "0",
    "-1",
    "1e308",
    "-1e308",
    "1e-320",
    "nan",
    "inf",
    "-inf",
    "NaN",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "4294967296",
    "1e9",
    "1e12",
    "1e-12",
    "0.0",
    "\"\"",
    "\"x\"",
    "[]",
    "[[]]",
    "{}",
    "true",
    "[1e308, 1e308, 1e308]",
    "[0, 0, 0]",
    "\"\u{feff}\"",
    ",",
    "\"",
    "\r\n",
    "=",
    "[",
    "]]",
];

/// One mutation of `data`.
fn mutate_once(data: &mut Vec<u8>, rng: &mut ChaCha8Rng, text: bool) {
    let len = data.len();
    if len == 0 {
        data.extend_from_slice(TOKENS[rng.random_range(0..TOKENS.len())].as_bytes());
        return;
    }
    match rng.random_range(0..if text { 10 } else { 7 }) {
        // A random byte.
        0 => data[rng.random_range(0..len)] = rng.random(),
        // A flipped bit.
        1 => data[rng.random_range(0..len)] ^= 1 << rng.random_range(0..8),
        // A byte inserted or removed.
        2 => data.insert(rng.random_range(0..=len), rng.random()),
        3 => {
            let at = rng.random_range(0..len);
            let n = rng.random_range(1..=(len - at).min(64));
            data.drain(at..at + n);
        }
        // A range duplicated.
        4 => {
            let at = rng.random_range(0..len);
            let n = rng.random_range(1..=(len - at).min(256));
            let piece: Vec<u8> = data[at..at + n].to_vec();
            let to = rng.random_range(0..=len);
            data.splice(to..to, piece);
        }
        // Truncated.
        5 => data.truncate(rng.random_range(0..len)),
        // An extreme 4- or 8-byte integer (lengths and offsets in binary formats).
        6 => {
            let width = if rng.random() { 4 } else { 8 };
            if len >= width {
                let at = rng.random_range(0..=len - width);
                let v: u64 = [0, 1, 0x7f, 0xff, 0x7fff_ffff, 0xffff_ffff, u64::MAX, 1 << 40][rng.random_range(0..8)];
                data[at..at + width].copy_from_slice(&v.to_le_bytes()[..width]);
            }
        }
        // Text: a number or value replaced by a token.
        7 => {
            let starts: Vec<usize> = (0..len)
                .filter(|&i| {
                    (data[i].is_ascii_digit() || data[i] == b'-' || data[i] == b'"' || data[i] == b'[')
                        && (i == 0 || !data[i - 1].is_ascii_alphanumeric())
                })
                .collect();
            if let Some(&at) = starts.get(rng.random_range(0..starts.len().max(1))) {
                let end = (at + 1..len)
                    .find(|&i| matches!(data[i], b',' | b'\n' | b'\r' | b' ' | b']' | b'}'))
                    .unwrap_or(len);
                let token = TOKENS[rng.random_range(0..TOKENS.len())].as_bytes();
                data.splice(at..end, token.iter().copied());
            }
        }
        // Text: a line deleted, duplicated or moved.
        _ => {
            let mut lines: Vec<Vec<u8>> = data.split(|&b| b == b'\n').map(<[u8]>::to_vec).collect();
            let n = lines.len();
            let i = rng.random_range(0..n);
            match rng.random_range(0..3) {
                0 => {
                    lines.remove(i);
                }
                1 => {
                    let l = lines[i].clone();
                    lines.insert(rng.random_range(0..=n), l);
                }
                _ => lines.swap(i, rng.random_range(0..n)),
            }
            *data = lines.join(&b'\n');
        }
    }
}

fn mutate(seed: &[u8], rng: &mut ChaCha8Rng, text: bool) -> Vec<u8> {
    let mut data = seed.to_vec();
    for _ in 0..rng.random_range(1..=4) {
        mutate_once(&mut data, rng, text);
    }
    data
}

/// The mutation stream of a target (FNV-1a of its name as the seed).
fn target_rng(target: &str) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(
        target.bytes().fold(1469598103934665603u64, |h, b| (h ^ u64::from(b)).wrapping_mul(1099511628211)),
    )
}

/// What a target did.
#[derive(Debug, Default)]
struct Tally {
    accepted: usize,
    refused: usize,
    panics: usize,
    panic_samples: Vec<String>,
    slowest: Duration,
    slow: Vec<String>,
}

/// Runs `inputs()` mutated inputs of `seeds` through `parse`, each written to `dir/name.ext`.
fn fuzz<F>(target: &str, seeds: &[(Vec<u8>, &str)], text: bool, parse: F) -> Tally
where
    F: Fn(&Path) -> Result<(), String>,
{
    let dir = tempfile::tempdir().expect("temporary folder");
    let mut rng = target_rng(target);
    let mut tally = Tally::default();
    let previous_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    for k in 0..inputs() {
        let (seed, ext) = &seeds[k % seeds.len()];
        let data = mutate(seed, &mut rng, text);
        let path = dir.path().join(format!("input.{ext}"));
        std::fs::write(&path, &data).expect("fuzz input written");
        let start = Instant::now();
        match catch_unwind(AssertUnwindSafe(|| parse(&path))) {
            Ok(Ok(())) => tally.accepted += 1,
            Ok(Err(_)) => tally.refused += 1,
            Err(p) => {
                let what = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                    .unwrap_or_default();
                tally.panics += 1;
                if tally.panic_samples.len() < 5 {
                    tally.panic_samples.push(format!("input {k}: {what}\n{}", String::from_utf8_lossy(&data)));
                }
            }
        }
        let took = start.elapsed();
        tally.slowest = tally.slowest.max(took);
        if took > SLOW && tally.slow.len() < 5 {
            tally.slow.push(format!("input {k}: {took:?}\n{}", String::from_utf8_lossy(&data)));
        }
    }
    std::panic::set_hook(previous_hook);
    println!(
        "fuzz {target}: {} inputs, {} accepted, {} refused, {} panics, slowest {:.1} ms",
        inputs(),
        tally.accepted,
        tally.refused,
        tally.panics,
        tally.slowest.as_secs_f64() * 1e3
    );
    tally
}

fn assert_clean(target: &str, tally: &Tally) {
    assert!(
        tally.panics == 0,
        "{target}: {} panics, the first:\n{}",
        tally.panics,
        tally.panic_samples.join("\n---\n")
    );
    assert!(tally.slow.is_empty(), "{target}: inputs slower than {SLOW:?}:\n{}", tally.slow.join("\n---\n"));
    assert!(tally.refused > 0 && tally.accepted + tally.refused == inputs(), "{target}: {tally:?}");
}

/// Runs a sample of mutated inputs through the binary: exit code 0, 1 or 2, within a time limit.
fn through_the_binary(target: &str, seeds: &[(Vec<u8>, &str)], text: bool, args: &dyn Fn(&Path) -> Vec<String>) {
    let dir = tempfile::tempdir().expect("temporary folder");
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed ^ target.len() as u64);
    let mut codes = [0usize; 3];
    for k in 0..process_inputs() {
        let (seed, ext) = &seeds[k % seeds.len()];
        let data = mutate(seed, &mut rng, text);
        let path = dir.path().join(format!("input-{k}.{ext}"));
        std::fs::write(&path, &data).expect("fuzz input written");
        let mut child = Command::new(env!("CARGO_BIN_EXE_gfcal"))
            .args(args(&path))
            .current_dir(REPO)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("gfcal starts");
        let start = Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().expect("wait") {
                break s;
            }
            if start.elapsed() > Duration::from_secs(60) {
                let _ = child.kill();
                panic!("{target}: input {k} still running after 60 s:\n{}", String::from_utf8_lossy(&data));
            }
            std::thread::sleep(Duration::from_millis(2));
        };
        match status.code() {
            Some(c @ 0..=2) => codes[c as usize] += 1,
            other => panic!("{target}: input {k} ended with {other:?}:\n{}", String::from_utf8_lossy(&data)),
        }
    }
    println!(
        "fuzz {target} through the binary: {} inputs, exit 0: {}, 1: {}, 2: {}",
        process_inputs(),
        codes[0],
        codes[1],
        codes[2]
    );
}

fn text_seeds(paths: &[&str]) -> Vec<(Vec<u8>, &'static str)> {
    paths.iter().map(|p| (read(p), "toml")).collect()
}

fn check_args(path: &Path) -> Vec<String> {
    vec!["check".into(), path.display().to_string()]
}

#[test]
fn run_configs() {
    let seeds = text_seeds(&[
        "configs/quickstart.toml",
        "configs/identifiability_sweep.toml",
        "configs/sobol_indices.toml",
        "configs/mimu4444_protocol.toml",
        "configs/overnight.toml",
    ]);
    // The text is parsed as if it lay in configs/ (array files are found relative to it).
    let origin = repo("configs/fuzzed.toml");
    let tally = fuzz("run config", &seeds, true, |p| {
        let text = std::fs::read_to_string(p).map_err(|e| e.to_string())?;
        gfcal::mc::McConfig::from_text(text, &origin).map(|_| ()).map_err(|e| e.to_string())
    });
    assert_clean("run config", &tally);
    through_the_binary("run config", &seeds, true, &check_args);
}

#[test]
fn array_files() {
    let seeds = text_seeds(&[MIMU, "configs/arrays/nine.toml"]);
    let tally = fuzz("array file", &seeds, true, |p| load_recording_array(p).map(|_| ()).map_err(|e| e.to_string()));
    assert_clean("array file", &tally);
    through_the_binary("array file", &seeds, true, &check_args);
}

/// A calibration config with its schedule spelled out step by step.
const EXPLICIT_SCHEDULE: &str = r#"
[array]
preset = "cube"
rho_m = 0.1

[errors]
bias_mg = 1.0
scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]
nominal_scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]

[noise]
white_density_ug_per_sqrt_hz = 50.0

[schedule]
step_duration_s = 1.0
sample_rate_hz = 100.0

[[schedule.step]]
kind = "static"
up = [0.0, 0.0, 1.0]

[[schedule.step]]
kind = "static"
up = [0.0, 0.0, -1.0]
duration_s = 2.0

[[schedule.step]]
kind = "static"
up = [1.0, 0.0, 0.0]
sample_rate_hz = 1000.0

[[schedule.step]]
kind = "static"
up = [-1.0, 0.0, 0.0]

[[schedule.step]]
kind = "static"
up = [0.0, 1.0, 0.0]

[[schedule.step]]
kind = "static"
up = [0.0, -1.0, 0.0]

[[schedule.step]]
kind = "spin"
axis = [1.0, 0.0, 0.0]
rate_rad_s = 6.283185307179586
up_end = "negative"

[[schedule.step]]
kind = "spin"
axis = [0.0, 1.0, 0.0]
rate_rad_s = 6.283185307179586
up_end = "positive"

[[schedule.step]]
kind = "spin"
axis = [0.0, 0.0, 1.0]
rate_rad_s = 6.283185307179586
up_end = "positive"
name = "z spin"
"#;

#[test]
fn schedules() {
    use gfcal::config::calibration::CalibrationConfig;
    let explicit = tempfile::tempdir().expect("temporary folder");
    let seed_path = explicit.path().join("explicit.toml");
    std::fs::write(&seed_path, EXPLICIT_SCHEDULE).expect("seed written");
    // The seed itself is valid: the fuzzing starts from a schedule the loader accepts.
    let loaded = CalibrationConfig::load(&seed_path).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(loaded.schedule.len(), 9);
    let mut seeds = vec![(EXPLICIT_SCHEDULE.as_bytes().to_vec(), "toml")];
    seeds.extend(text_seeds(&["configs/hung_lee_2006_design.toml"]));
    let tally = fuzz("schedule", &seeds, true, |p| CalibrationConfig::load(p).map(|_| ()).map_err(|e| e.to_string()));
    assert_clean("schedule", &tally);
    through_the_binary("schedule", &seeds, true, &check_args);
}

#[test]
fn other_configs() {
    use gfcal::config::drift::DriftConfig;
    use gfcal::config::simulate_log::SimulateLogConfig;
    let seeds = text_seeds(&[
        "configs/paper_manoeuvre.toml",
        "configs/nine_accelerometer.toml",
        "configs/discrepancy_example.toml",
    ]);
    // Mutated files are written to a temporary folder: array files named by relative path are not
    // found there, which is one more kind of bad input.
    let tally = fuzz("drift and simulate-log config", &seeds, true, |p| {
        let drift = DriftConfig::load(p).map(|_| ()).map_err(|e| e.to_string());
        let log = SimulateLogConfig::load(p).map(|_| ()).map_err(|e| e.to_string());
        drift.or(log)
    });
    assert_clean("drift and simulate-log config", &tally);
    through_the_binary("drift and simulate-log config", &seeds, true, &check_args);
}

/// A small calibration log of 6 accelerometers: three steps, the second a spin, with temperature.
/// (The spin's 6.28 rad/s is written as a lab would; the replayed inputs depend on these bytes.)
#[allow(clippy::approx_constant)]
fn log_csv() -> String {
    let mut s =
        String::from("step,t_s,up_x,up_y,up_z,omega_x_rad_s,omega_y_rad_s,omega_z_rad_s,temp_c,s1,s2,s3,s4,s5,s6\n");
    let mut t = 0.0;
    for (step, up, w) in [(0, [0.0, 0.0, 1.0], 0.0), (1, [0.0, 0.0, 1.0], 6.28), (2, [1.0, 0.0, 0.0], 0.0)] {
        for i in 0..6 {
            let g = [0.01 * i as f64, -4.9, 4.9, 0.1, 6.9, -6.9];
            s.push_str(&format!(
                "{step},{t:.2},{},{},{},0,0,{},{:.1},{}\n",
                up[0],
                up[1],
                up[2],
                w * up[2],
                20.0 + t,
                g.iter().map(|v| format!("{v}")).collect::<Vec<_>>().join(",")
            ));
            t += 0.01;
        }
    }
    s
}

fn table_seeds(csv: String, read_parquet_from_csv: impl Fn(&Path, &Path)) -> Vec<(Vec<u8>, &'static str)> {
    let dir = tempfile::tempdir().expect("temporary folder");
    let csv_path = dir.path().join("seed.csv");
    std::fs::write(&csv_path, &csv).expect("seed written");
    let pq = dir.path().join("seed.parquet");
    read_parquet_from_csv(&csv_path, &pq);
    vec![(csv.into_bytes(), "csv"), (std::fs::read(&pq).expect("seed read"), "parquet")]
}

fn log_seeds() -> Vec<(Vec<u8>, &'static str)> {
    table_seeds(log_csv(), |csv, pq| {
        let log = CalibrationLog::read(csv, 6).unwrap_or_else(|e| panic!("the seed log reads: {e}"));
        log.write(pq).expect("Parquet seed written");
        assert_eq!(CalibrationLog::read(pq, 6).expect("the Parquet seed reads"), log);
    })
}

#[test]
fn damaged_parquet_files_that_crashed_the_decoder_are_refused_with_a_message() {
    // Inputs 24137, 25553 and 36317 of the log target panicked inside the Parquet decoder
    // ("column start and length should not be negative", "index out of bounds", "Decoder for
    // dict should have been set") before the readers ran it through `io::guard`. They are kept as
    // files: replaying the mutations would depend on the bytes gfcal's writer produces today.
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fuzz/damaged");
    for k in [24137, 25553, 36317] {
        let path = dir.join(format!("log_{k}.parquet"));
        // Without the guard the decoder still panics on it (else this file no longer tests the guard).
        let raw = gfcal::io::guard::decode(|| {
            let file = std::fs::File::open(&path).expect("fixture opens");
            if let Ok(builder) = parquet::arrow::arrow_reader::ParquetRecordBatchReaderBuilder::try_new(file)
                && let Ok(reader) = builder.build()
            {
                reader.for_each(drop);
            }
        });
        assert!(raw.is_err(), "{}: the raw decoder no longer panics", path.display());
        let e = CalibrationLog::read(&path, 6).expect_err("a damaged file is refused");
        let message = e.to_string();
        assert!(
            message.contains("not a readable Parquet file") && message.contains(path.to_str().unwrap()),
            "{message}"
        );
        let o = Command::new(env!("CARGO_BIN_EXE_gfcal"))
            .args(["diagnose", path.to_str().unwrap()])
            .output()
            .expect("runs");
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
    }
}

#[test]
fn calibration_logs() {
    let seeds = log_seeds();
    let tally =
        fuzz("calibration log", &seeds, false, |p| CalibrationLog::read(p, 6).map(|_| ()).map_err(|e| e.to_string()));
    assert_clean("calibration log", &tally);
    through_the_binary("calibration log", &seeds, false, &|p| vec!["diagnose".into(), p.display().to_string()]);
}

/// A small recording of the MIMU4444 board (its array file's columns): 40 rows at rest.
fn recording_csv(array: &RecordingArray) -> String {
    let mut header = vec!["t_s".to_string()];
    header.extend(array.accelerometer_columns.iter().cloned());
    header.extend(array.gyroscopes.iter().map(|g| g.column.clone()));
    let mut s = header.join(",") + "\n";
    for i in 0..40 {
        let mut row = vec![format!("{:.4}", i as f64 * 0.008)];
        row.extend(array.array.axes().iter().map(|a| format!("{:.5}", 9.80665 * a.z)));
        row.extend(array.gyroscopes.iter().map(|_| "0.001".to_string()));
        s.push_str(&(row.join(",") + "\n"));
    }
    s
}

fn write_parquet_copy(csv: &Path, pq: &Path) {
    use arrow_array::{ArrayRef, Float64Array, RecordBatch};
    use arrow_schema::{DataType, Field, Schema};
    let table = gfcal::io::table::Table::read(csv).expect("the seed CSV reads");
    let fields: Vec<Field> = table.names.iter().map(|n| Field::new(n, DataType::Float64, false)).collect();
    let columns: Vec<ArrayRef> =
        table.data.iter().map(|c| std::sync::Arc::new(Float64Array::from(c.clone())) as ArrayRef).collect();
    let batch = RecordBatch::try_new(std::sync::Arc::new(Schema::new(fields)), columns).expect("batch");
    let props = parquet::file::properties::WriterProperties::builder()
        .set_compression(parquet::basic::Compression::SNAPPY)
        .build();
    let file = std::fs::File::create(pq).expect("seed file");
    let mut w = parquet::arrow::ArrowWriter::try_new(file, batch.schema(), Some(props)).expect("writer");
    w.write(&batch).expect("written");
    w.close().expect("closed");
}

#[test]
fn recordings() {
    let array = load_recording_array(&repo(MIMU)).expect("the shipped array file loads");
    let seeds = table_seeds(recording_csv(&array), |csv, pq| {
        write_parquet_copy(csv, pq);
        let a = Recording::read(csv, &array).unwrap_or_else(|e| panic!("the seed recording reads: {e}"));
        let b = Recording::read(pq, &array).expect("the Parquet seed reads");
        assert_eq!(a.samples(), b.samples());
    });
    let tally = fuzz("recording", &seeds, false, |p| Recording::read(p, &array).map(|_| ()).map_err(|e| e.to_string()));
    assert_clean("recording", &tally);
    through_the_binary("recording", &seeds, false, &|p| {
        vec!["calibrate".into(), p.display().to_string(), "--array".into(), MIMU.into()]
    });
}
