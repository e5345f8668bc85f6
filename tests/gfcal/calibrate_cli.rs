//! `gfcal calibrate` on bad recordings: too few static intervals, no dynamic phase, a missing
//! column, NaN, time going backwards, everything clipped, a held-out recording of another array;
//! and recordings as labs write them (the time in milliseconds or under another name, semicolons,
//! decimal commas, all rotation).
//! Each is refused with exit code 2 and a message naming the file, the column and the problem,
//! and writes nothing; a recording with no dynamic phase is calibrated as far as it can be, naming
//! what is not identifiable.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use gfcal::array::wiring::RecordingArray;
use gfcal::rng::trial_rng;
use gfcal::selfcal::simulate::{Protocol, random_truth, simulate};

use super::selfcal::{mimu_array, protocol};

const ARRAY: &str = "configs/arrays/mimu4444_corners.toml";

fn gfcal(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_gfcal"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("gfcal runs")
}

/// A simulated recording of the board's protocol with `poses` poses and `dynamic_s` seconds of
/// rotation, as the rows of a CSV table with the array file's columns (header first).
fn simulated_rows(array: &RecordingArray, poses: usize, dynamic_s: f64) -> Vec<Vec<String>> {
    let n = array.array.len();
    let mut rng = trial_rng(11, 0);
    let truth = random_truth(&array.array, 0.005, 0.3, 0.004, 0.5e-3, &mut rng);
    let protocol = Protocol { poses, pose_s: 7.0, dynamic_s, ..protocol(n) };
    let sim = simulate(array, &truth, &protocol, &mut trial_rng(11, 1)).expect("simulated");
    let rec = &sim.recording;
    let mut header = vec!["t_s".to_string()];
    header.extend(array.accelerometer_columns.iter().cloned());
    header.extend(array.gyroscopes.iter().map(|g| g.column.clone()));
    let mut rows = vec![header];
    for i in 0..rec.samples() {
        let mut row = vec![format!("{}", rec.t_s[i])];
        row.extend((0..n).map(|j| format!("{}", rec.outputs[(i, j)])));
        row.extend(array.gyroscopes.iter().map(|g| format!("{}", g.axis.dot(&sim.motion[i].omega_rad_s))));
        rows.push(row);
    }
    rows
}

fn write_csv(path: &Path, rows: &[Vec<String>]) {
    let text: String = rows.iter().map(|r| r.join(",") + "\n").collect();
    std::fs::write(path, text).expect("test CSV written");
}

/// Runs `calibrate` on `rows` written to a fresh folder; returns the output, the recording's path
/// and the JSON path asked for.
fn calibrate(rows: &[Vec<String>], extra: &[&str]) -> (Output, PathBuf, PathBuf, tempfile::TempDir) {
    let dir = tempfile::tempdir().expect("temp dir");
    let rec = dir.path().join("rec.csv");
    write_csv(&rec, rows);
    let json = dir.path().join("out.json");
    let mut args = vec!["calibrate", rec.to_str().unwrap(), "--array", ARRAY, "--json", json.to_str().unwrap()];
    args.extend_from_slice(extra);
    let o = gfcal(&args);
    (o, rec, json, dir)
}

fn refused(rows: &[Vec<String>], words: &[&str]) {
    let (o, rec, json, _dir) = calibrate(rows, &[]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains(rec.to_str().unwrap()), "names the file: {err}");
    for w in words {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
    assert!(!err.contains("panicked"), "{err}");
    assert!(!json.exists(), "nothing written");
}

fn column(rows: &[Vec<String>], name: &str) -> usize {
    rows[0].iter().position(|c| c == name).expect("column in the table")
}

#[test]
fn too_few_static_intervals_are_refused_saying_how_many_were_found_and_are_needed() {
    let rows = simulated_rows(&mimu_array(), 3, 12.0);
    // 24 accelerometers: 4 N - 3 = 93 static parameters against 22 per pose, so 6 poses.
    refused(&rows, &["3 static interval(s)", "at least 6"]);
}

#[test]
fn a_missing_column_is_refused_naming_it_and_the_array_file() {
    let mut rows = simulated_rows(&mimu_array(), 7, 12.0);
    let c = column(&rows, "acc3_y_m_s2");
    for r in &mut rows {
        r.remove(c);
    }
    refused(&rows, &["acc3_y_m_s2", "missing column", "mimu4444_corners.toml"]);
}

#[test]
fn nan_time_backwards_and_everything_clipped_are_refused_naming_row_and_column() {
    let rows = simulated_rows(&mimu_array(), 7, 12.0);
    let mut nan = rows.clone();
    let c = column(&nan, "acc5_z_m_s2");
    nan[41][c] = "NaN".into();
    refused(&nan, &["data row 41", "acc5_z_m_s2", "not a finite number"]);

    let mut back = rows.clone();
    back[101][0] = "0.5".into();
    refused(&back, &["data row 101", "t_s", "time does not increase"]);

    let mut clipped = rows.clone();
    for r in clipped.iter_mut().skip(1) {
        for v in r.iter_mut().skip(1).take(24) {
            *v = "200".into();
        }
    }
    refused(&clipped, &["all clipped"]);
}

/// A gyroscope column whose values pile up just below the array file's range (a rail the file does
/// not know): refused, naming the column, the value and the key to set.
#[test]
fn a_rail_below_the_array_files_range_is_refused() {
    let mut rows = simulated_rows(&mimu_array(), 7, 12.0);
    let c = column(&rows, "gyro3_z_rad_s");
    for r in rows.iter_mut().skip(300).take(20) {
        r[c] = "-34.8".into();
    }
    refused(&rows, &["data row 300", "gyro3_z_rad_s", "20 values sit at 34.8 rad/s", "range_rad_s"]);
}

/// Without a rotation phase, static poses of unknown direction need 9 (8 leave a deformation of
/// the pose directions that the sensor parameters absorb: `selfcal::fit`); with 10 the intrinsic
/// parameters are calibrated and the locations named as not identifiable.
#[test]
fn a_recording_without_rotation_calibrates_what_static_poses_identify_and_names_the_rest() {
    refused(&simulated_rows(&mimu_array(), 8, 0.0), &["8 static interval(s)", "static poses alone", "at least 9"]);

    let rows = simulated_rows(&mimu_array(), 10, 0.0);
    let (o, _rec, json, _dir) = calibrate(&rows, &[]);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(out.contains("10 static interval(s)"), "{out}");
    assert!(out.contains("Fisher null directions 3 (gauge 3)"), "{out}");
    assert!(out.contains("no dynamic phase") && out.contains("not identifiable"), "{out}");
    // Only the carries between poses move: the longest of them, not a rotation too short.
    let longest_s = |out: &str| {
        let why = "no dynamic phase (no moving run lasts --min-dynamic-s 10 s; the longest lasts ";
        let at = out.find(why).unwrap_or_else(|| panic!("{out}"));
        let rest = &out[at + why.len()..];
        let value: f64 = rest.split(' ').next().and_then(|v| v.parse().ok()).unwrap_or(f64::NAN);
        assert!(rest.starts_with(&format!("{value:.1} s)")), "{out}");
        value
    };
    assert!(longest_s(&out) < 3.0, "{out}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("JSON written")).unwrap();
    let params = v["parameters"].as_array().expect("parameters");
    let sigma =
        |name: &str| params.iter().find(|p| p["name"] == name && p["accelerometer"] == 1).unwrap()["sigma"].clone();
    assert!(sigma("dx").is_null(), "location sigma is null: not identifiable");
    // 0.04 m/s^2 a sample, about 280 samples a pose, 10 poses: a bias sigma of a few 1e-4.
    assert!(sigma("bias").as_f64().is_some_and(|s| s > 1e-4 && s < 3e-3), "bias sigma {}", sigma("bias"));
    // The bias drift check needs only the static phase; this recording's biases do not drift.
    let d = &v["static"]["bias_drift"];
    assert_eq!(d["test_dof"], 24, "{d}");
    assert_eq!(d["drifts"], false, "{d}");
    assert!(d["p_value"].as_f64().is_some_and(|p| p > 1e-3), "{d}");
    assert_eq!(d["rates"].as_array().map(Vec::len), Some(24));
    assert_eq!(d["parameters"].as_array().map(Vec::len), Some(96));
    for k in ["scale_factor", "bias", "tilt_u", "tilt_w"] {
        assert!(d["move_rms_sigma"][k].is_f64() && d["sigma_over_printed"][k].is_f64(), "{k}: {d}");
    }
    assert!(out.contains("static phase refitted with a bias drift in time"), "{out}");

    // A rotation shorter than --min-dynamic-s (10 s by default) is no rotation phase, and the
    // summary says so, with the length the segmentation found.
    let (o, _rec, _json, _dir) = calibrate(&simulated_rows(&mimu_array(), 10, 6.0), &[]);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let longest_s = longest_s(&out);
    assert!((5.0..10.0).contains(&longest_s), "{longest_s} s: {out}");
}

#[test]
fn a_held_out_recording_of_another_array_is_refused_naming_both_files() {
    let array = mimu_array();
    let rows = simulated_rows(&array, 7, 12.0);
    let dir = tempfile::tempdir().expect("temp dir");
    let main = dir.path().join("main.csv");
    write_csv(&main, &rows);
    // The same table under the default column names s1..s6 of a six-accelerometer array.
    let other = dir.path().join("other.csv");
    let six: Vec<Vec<String>> = rows
        .iter()
        .enumerate()
        .map(|(i, r)| {
            let mut v = vec![r[0].clone()];
            v.extend((1..=6).map(|j| if i == 0 { format!("s{j}") } else { r[j].clone() }));
            v
        })
        .collect();
    write_csv(&other, &six);
    let json = dir.path().join("out.json");
    // `gfcal calibrate`, and `gfcal diagnose` on recordings (issue 11), refuse it the same way.
    for command in ["calibrate", "diagnose"] {
        let o = gfcal(&[
            command,
            main.to_str().unwrap(),
            "--array",
            ARRAY,
            "--json",
            json.to_str().unwrap(),
            "--held-out",
            other.to_str().unwrap(),
        ]);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(2), "{command}: {err}");
        assert!(
            err.contains(main.to_str().unwrap()) && err.contains(other.to_str().unwrap()),
            "{command} names both: {err}"
        );
        assert!(!json.exists(), "{command}: nothing written");
    }
}

/// An array file whose range is below what a board at rest reads (accelerometer 1 at 5 m/s^2: its static
/// means near +-9.8 would be means of clipped outputs, read as measured): refused at the first such output,
/// naming the recording, the row, the static interval, the key and the array file, before any fit; the same
/// for a held-out recording in `diagnose` (pushed past its rail by `inject`), refused before the fitting
/// recording is calibrated (it was refused after a minute's fit before). The six recordings with the shipped
/// array file have none.
#[test]
fn an_output_at_its_range_inside_a_static_interval_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(ARRAY)).unwrap();
    let low = dir.path().join("low.toml");
    std::fs::write(&low, text.replacen("range_m_s2 = 156.9", "range_m_s2 = 5.0", 1)).unwrap();
    let rec = super::recorded::real(2);
    let json = dir.path().join("out.json");
    let o = gfcal(&[
        "calibrate",
        rec.to_str().unwrap(),
        "--array",
        low.to_str().unwrap(),
        "--json",
        json.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    for w in
        [rec.to_str().unwrap(), "data row", "static interval", "`accelerometer[0].range_m_s2`", low.to_str().unwrap()]
    {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
    assert!(!json.exists());
    // A held-out recording whose accelerometer 1 is pushed past its rail (by 200 m/s^2) everywhere but
    // at its most negative readings, fitted recording 3 with the shipped array file.
    let pushed = dir.path().join("pushed.parquet");
    super::recorded::inject_into(&rec, &pushed, "bias_turn_on", ["--accelerometer", "1"], "200");
    let o = gfcal(&[
        "diagnose",
        super::recorded::real(3).to_str().unwrap(),
        "--array",
        ARRAY,
        "--held-out",
        pushed.to_str().unwrap(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    for w in [pushed.to_str().unwrap(), "static interval", "`accelerometer[0].range_m_s2`"] {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
}

/// Recording 1 of the MIMU4444 as a table, for recordings written as labs write them.
fn real_table() -> gfcal::io::table::Table {
    gfcal::io::table::Table::read(&super::recorded::real(1)).expect("recording 1")
}

/// `table`'s first `rows` rows as CSV text with the separator `sep`, numbers written by `number`.
fn csv_text(table: &gfcal::io::table::Table, rows: usize, sep: &str, number: impl Fn(f64) -> String) -> String {
    let mut text = table.names.join(sep) + "\n";
    for i in 0..rows.min(table.rows()) {
        text += &table.data.iter().map(|c| number(c[i])).collect::<Vec<_>>().join(sep);
        text += "\n";
    }
    text
}

/// `gfcal calibrate FILE --array ARRAY --json FILE.json`: the output, and whether the JSON was
/// written.
fn calibrate_file(file: &Path, array: &str) -> (Output, bool) {
    run_on_file("calibrate", file, array)
}

/// `gfcal COMMAND FILE --array ARRAY --json FILE.json` (`calibrate` or `diagnose`).
fn run_on_file(command: &str, file: &Path, array: &str) -> (Output, bool) {
    let json = file.with_extension("json");
    let o = gfcal(&[command, file.to_str().unwrap(), "--array", array, "--json", json.to_str().unwrap()]);
    (o, json.exists())
}

/// Issue 30, item 6: a recording whose time is in milliseconds ended in "1 static interval(s)
/// ... needs at least 6". Now the message gives the sample rate the time implies (62.5 Hz read as
/// 0.0625 Hz), names the likely unit error and what the segmentation found; exit 2.
#[test]
fn a_recording_in_milliseconds_is_named_as_such() {
    let dir = tempfile::tempdir().unwrap();
    let mut table = real_table();
    let k = table.index("t_s").unwrap();
    for t in &mut table.data[k] {
        *t *= 1000.0;
    }
    let file = dir.path().join("in_ms.parquet");
    table.write(&file).unwrap();
    let (o, written) = calibrate_file(&file, ARRAY);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    for w in [
        file.to_str().unwrap(),
        "static interval(s) found",
        "`t_s`",
        "0.0625 Hz",
        "milliseconds (62.5 Hz if so)",
        "divide the column by 1000",
        "The segmentation found",
    ] {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
    assert!(!written);
    // The same recording in seconds: 62.5 Hz is plausible, nothing is suspected.
    let t = &real_table().data[k];
    let rate = gfcal::selfcal::segment::implied_rate_hz(t);
    assert!((rate - 62.5).abs() < 0.1, "{rate}");
    assert!(gfcal::selfcal::segment::time_unit_suspicion(rate, t).is_none());
}

/// Issue 30, item 6: a semicolon-separated file (as spreadsheets write it where the decimal
/// separator is a comma) said "the header has 1 field"; it now says how it is separated, and
/// whether its numbers have decimal commas. A comma-separated file with decimal commas splits its
/// numbers: said so too. Exit 2, naming the file.
#[test]
fn a_semicolon_separated_or_decimal_comma_file_says_so() {
    let dir = tempfile::tempdir().unwrap();
    let table = real_table();
    let point = |v: f64| format!("{v}");
    let comma = |v: f64| format!("{v}").replace('.', ",");
    let cases: [(&str, String, &[&str]); 4] = [
        ("semicolons.csv", csv_text(&table, 500, ";", point), &["separated by semicolons", "not commas"]),
        ("european.csv", csv_text(&table, 500, ";", comma), &["separated by semicolons", "decimal commas (9,81)"]),
        ("tabs.csv", csv_text(&table, 500, "\t", point), &["separated by tabs"]),
        ("split.csv", csv_text(&table, 500, ",", comma), &["data row 1", "decimal commas"]),
    ];
    for (name, text, words) in cases {
        let file = dir.path().join(name);
        std::fs::write(&file, text).unwrap();
        let (o, written) = calibrate_file(&file, ARRAY);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(2), "{name}: {err}");
        assert!(err.contains(file.to_str().unwrap()), "{name}: names the file: {err}");
        for w in words {
            assert!(err.contains(w), "{name}: mentions `{w}`: {err}");
        }
        assert!(!err.contains("the header has 1"), "{name}: {err}");
        assert!(!written);
    }
    // A quoted number with a decimal comma in a comma-separated file (data row 2: row 1's time is 0).
    let mut text = csv_text(&table, 3, ",", point);
    let second = text.lines().nth(2).unwrap().to_string();
    let (t, rest) = second.split_once(',').unwrap();
    text = text.replacen(&second, &format!("\"{}\",{rest}", t.replace('.', ",")), 1);
    let file = dir.path().join("quoted.csv");
    std::fs::write(&file, text).unwrap();
    let (o, _) = calibrate_file(&file, ARRAY);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("data row 2, column `t_s`") && err.contains("a decimal comma?"), "{err}");
}

/// Issue 30, item 6: a recording that is all rotation (the last 94 s of recording 1) was told it
/// had "no rotation phase". It is now told what the segmentation found and that a calibration
/// needs it to rest in static poses; exit 2.
#[test]
fn a_recording_that_is_all_rotation_is_not_told_it_has_no_rotation_phase() {
    let dir = tempfile::tempdir().unwrap();
    let mut table = real_table();
    let k = table.index("t_s").unwrap();
    let first = table.data[k].iter().position(|t| *t > 505.0).unwrap();
    for c in &mut table.data {
        c.drain(..first);
    }
    let file = dir.path().join("rotation.parquet");
    table.write(&file).unwrap();
    // `diagnose` calibrates the recording first: the same message.
    for command in ["calibrate", "diagnose"] {
        let (o, written) = run_on_file(command, &file, ARRAY);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(2), "{command}: {err}");
        assert!(!err.contains("(no rotation phase)"), "{command}: {err}");
        for w in [file.to_str().unwrap(), "62.5 Hz", "short runs", "does it rest at all?", "all rotation"] {
            assert!(err.contains(w), "{command}: mentions `{w}`: {err}");
        }
        assert!(!written);
    }
}

/// Issue 30, item 6: the time column is the array file's `time_column` (default `t_s`): a
/// recording whose time is `time_s` is read with it, and without it is refused naming the
/// column, the key and the table's columns (it said "named by the array file", which it was not).
/// An empty `time_column`, or one that is a sensor's column, is refused naming the key.
#[test]
fn the_time_column_is_named_by_the_array_file() {
    let dir = tempfile::tempdir().unwrap();
    let mut table = real_table();
    let k = table.index("t_s").unwrap();
    table.names[k] = "time_s".into();
    table.data.iter_mut().for_each(|c| c.truncate(2000));
    let file = dir.path().join("time_s.parquet");
    table.write(&file).unwrap();
    let shipped = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join(ARRAY)).unwrap();
    let named = dir.path().join("named.toml");
    std::fs::write(&named, format!("time_column = \"time_s\"\n{shipped}")).unwrap();
    let array = gfcal::config::array::load_recording_array(&named).unwrap();
    assert_eq!(array.time_column, "time_s");
    let rec = gfcal::selfcal::recording::Recording::read(&file, &array).unwrap();
    assert_eq!(rec.t_s, table.data[k]);
    // The shipped array file reads `t_s`, which this recording lacks.
    let (o, written) = calibrate_file(&file, ARRAY);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(2), "{err}");
    for w in [file.to_str().unwrap(), "no time column `t_s`", "`time_column`", "seconds", "`time_s`", ARRAY] {
        assert!(err.contains(w), "mentions `{w}`: {err}");
    }
    assert!(!err.contains("named by the array file"), "{err}");
    assert!(!written);
    // Bad keys, through `gfcal check` of the array file.
    for (value, words) in [("\"\"", "is empty"), ("\"acc1_x_m_s2\"", "is also a sensor's column")] {
        let bad = dir.path().join("bad.toml");
        std::fs::write(&bad, format!("time_column = {value}\n{shipped}")).unwrap();
        let o = gfcal(&["check", bad.to_str().unwrap()]);
        let err = String::from_utf8_lossy(&o.stderr).into_owned();
        assert_eq!(o.status.code(), Some(2), "{err}");
        assert!(err.contains(bad.to_str().unwrap()) && err.contains("time_column") && err.contains(words), "{err}");
    }
}

/// The shipped array file cut to the IMUs `keep` (1-based): their packages, accelerometers and
/// gyroscopes, in the shipped order.
fn cut_array_file(keep: &[usize]) -> String {
    let text = std::fs::read_to_string(PathBuf::from(env!("CARGO_MANIFEST_DIR")).join(ARRAY)).unwrap();
    let mut blocks = text.split("\n[[");
    let mut out = blocks.next().unwrap().to_string();
    for b in blocks {
        let imu = b.split('"').find_map(|w| w.strip_prefix("imu")).and_then(|d| d.parse::<usize>().ok());
        if imu.is_none_or(|k| keep.contains(&k)) {
            out += "\n[[";
            out += b;
        }
    }
    out
}

/// Recording 1 shortened for a cheap test: its first 150 s (six static poses) and 40 s of its
/// rotation phase (from 495 s), moved in time to follow the poses.
fn shortened_recording_1(path: &Path) {
    let mut table = real_table();
    let t = table.index("t_s").unwrap();
    let keep: Vec<usize> =
        (0..table.rows()).filter(|&i| table.data[t][i] < 150.0 || (495.0..535.0).contains(&table.data[t][i])).collect();
    for col in &mut table.data {
        *col = keep.iter().map(|&i| col[i]).collect();
    }
    // The rotation follows the poses at once (a gap in time would read as one long still run).
    let first = table.data[t].iter().position(|&x| x >= 495.0).unwrap();
    let shift = table.data[t][first] - table.data[t][first - 1] - 0.016;
    for x in &mut table.data[t][first..] {
        *x -= shift;
    }
    table.write(path).unwrap();
}

/// Issue 30, item 1: the four top IMUs of the MIMU4444 (12 accelerometers in one plane) either
/// passed gyroscope-free with 22 null directions (gauge 7), finite sigmas for all 84 parameters and
/// a rate 1,400% off, or ended with exit 1 "the normal equations are singular beyond the gauge"
/// naming nothing. Now the combinations the Fisher information cannot see beyond the gauge are
/// named, their parameters have no value and no sigma, the rest are calibrated (exit 0), the
/// message says what would make them identifiable (`--use-gyro`, a geometry that is not flat),
/// `--use-gyro` identifies more, and `gfcal check` says the cut file's geometry is flat.
/// Its clock model diverges (the rate is not resolved), and is given up at its first refit,
/// where the misfit is already above the fit without it (it once ran all nine, 57 s).
#[test]
fn a_flat_subset_of_the_board_names_what_it_cannot_see_and_calibrates_the_rest() {
    let dir = tempfile::tempdir().unwrap();
    let array = dir.path().join("top_imus.toml");
    std::fs::write(&array, cut_array_file(&[1, 3, 5, 7])).unwrap();
    let rec = dir.path().join("r1_short.parquet");
    shortened_recording_1(&rec);
    let (rec_s, array_s) = (rec.to_str().unwrap(), array.to_str().unwrap());

    let json = dir.path().join("free.json");
    let o = gfcal(&["calibrate", rec_s, "--array", array_s, "--json", json.to_str().unwrap()]);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(o.status.code(), Some(0), "{}\n{out}", String::from_utf8_lossy(&o.stderr));
    for w in ["NOT IDENTIFIABLE", "beyond the gauge", "unidentified:", "--use-gyro", "not flat"] {
        assert!(out.contains(w), "mentions `{w}`: {out}");
    }
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let note = v["sample_clock_note"].as_str().unwrap_or_default();
    assert!(note.contains("made the rotation phase's misfit worse") && note.contains("at its refit 1)"), "{note}");
    let unidentified: Vec<&str> = v["unidentified"].as_array().unwrap().iter().map(|s| s.as_str().unwrap()).collect();
    assert!(!unidentified.is_empty(), "{}", v["gauge"]);
    let unseen = v["unseen_combinations"].as_array().unwrap();
    assert!(!unseen.is_empty());
    assert_eq!(v["gauge"]["unseen_beyond_gauge"], unseen.len());
    // The raw count (eigenvalues of the whole information) and the count beyond the gauge (of the
    // information on the directions the gauge leaves free) may differ by a few where the spectrum
    // runs on below the threshold; both exceed the gauge.
    assert!(v["gauge"]["null_directions"].as_u64().unwrap() > v["gauge"]["expected_null_directions"].as_u64().unwrap());
    // Every parameter named in a combination is unidentified (the combinations' printed
    // components are the larger shares of each).
    for c in unseen {
        for p in c["components"].as_array().unwrap() {
            let name = p["parameter"].as_str().unwrap();
            assert!(name.starts_with("pose") || unidentified.contains(&name), "{name} in {}", c["combination"]);
        }
    }
    let params = v["parameters"].as_array().unwrap();
    assert_eq!(params.len(), 84);
    let mut identified = 0;
    for p in params {
        let name = format!("a{}.{}", p["accelerometer"], p["name"].as_str().unwrap());
        if unidentified.contains(&name.as_str()) {
            assert!(p["value"].is_null() && p["sigma"].is_null(), "{p}");
        } else {
            identified += 1;
            assert!(p["value"].as_f64().is_some_and(f64::is_finite), "{p}");
            assert!(p["sigma"].as_f64().is_some_and(|s| s.is_finite() && s > 0.0), "{p}");
        }
    }
    assert!(identified > 0, "the identifiable parameters are calibrated");
    // Issue 30, item 7: the verdict per kind, and provenance as run.json has it.
    let verdicts = v["assessment"].as_array().expect("assessment");
    let kinds: Vec<&str> = verdicts.iter().map(|k| k["kind"].as_str().unwrap()).collect();
    assert_eq!(kinds, ["scale_factors", "biases", "tilts", "locations", "rate"]);
    let verdict = |kind: &str| verdicts.iter().find(|k| k["kind"] == kind).unwrap();
    assert_eq!(verdict("locations")["trustworthy"], false);
    assert!(verdict("locations")["reason"].as_str().unwrap().contains("unidentified"), "{}", verdict("locations"));
    assert_eq!(verdict("rate")["trustworthy"], false);
    assert!(verdict("rate")["reason"].as_str().unwrap().contains("differs from the gyroscopes"));
    assert!(out.contains("assessment:") && out.contains("  locations: not trustworthy"), "{out}");
    assert_eq!(v["gfcal_version"], env!("CARGO_PKG_VERSION"));
    assert!(v["git_commit"].as_str().is_some_and(|c| !c.is_empty()));
    for k in ["started", "finished"] {
        assert!(v[k].as_str().is_some_and(|t| t.ends_with('Z') && t.len() == 20), "{k}: {}", v[k]);
    }
    let remedies = v["to_identify"].as_array().unwrap();
    assert!(remedies.iter().any(|r| r.as_str().unwrap().starts_with("--use-gyro")), "{remedies:?}");
    assert!(remedies.iter().any(|r| r.as_str().unwrap().contains("not flat")), "{remedies:?}");

    // With the gyroscopes' rate the same subset sees more: fewer unidentified parameters. Not all: four IMUs whose axes are all parallel leave each axis
    // group's common location shift to the specific force, seen through the tilts alone (on the
    // whole recording 1 too: 8 combinations, docs/real-hardware.md).
    let json = dir.path().join("gyro.json");
    let o = gfcal(&["calibrate", rec_s, "--array", array_s, "--use-gyro", "--json", json.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    let g: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let with_gyro = g["unidentified"].as_array().unwrap().len();
    assert!(with_gyro < unidentified.len(), "{with_gyro} against {}", unidentified.len());

    // `gfcal check` on the cut file: its geometry is flat, which gyroscope-free cannot see well.
    let o = gfcal(&["check", array_s]);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stderr));
    for w in
        ["12 accelerometers", "geometry, gyroscope-free", "flat: the sensing points lie within 0.00 mm", "--use-gyro"]
    {
        assert!(out.contains(w), "mentions `{w}`: {out}");
    }
    // The shipped file's geometry is not flat (the bottom IMUs sit 2 mm below the top ones).
    let o = gfcal(&["check", ARRAY]);
    let out = String::from_utf8_lossy(&o.stdout).into_owned();
    assert!(out.contains("sees every parameter beyond the gauge") && !out.contains("flat:"), "{out}");
    // Its 24 axes lie along the array's x, y and z: three axis groups, whose common translations the
    // gauge fixes (selfcal::model::Gauge), 6 directions beside the 7 null ones.
    assert!(out.contains("axis groups: the axes split into 3 groups") && out.contains("6 directions beside"), "{out}");
}
