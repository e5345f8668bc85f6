//! Known effects added to a real recording (`gfcal inject`), so that a diagnosis can be checked on
//! real data: the effect must come back named, on the right accelerometer, with its injected
//! magnitude, on top of whatever the clean recording already shows.
//!
//! Each generator works on the table itself (the recorded output column of one accelerometer), not
//! through any term the diagnosis fits. Values are in output units (the MIMU4444's outputs are in
//! m/s^2 with a scale factor near 1; a diagnosis reports input-referred values, the injected value
//! over the accelerometer's scale factor). An output pushed past the accelerometer's range is
//! clipped at the rail, as the part would.
//!
//! **What was censored stays censored.** A railed output's true value is unknown, so the effect on
//! it is unknown too: it stays at the rail (and is read as clipped). An output computed from a
//! railed one (the delay's interpolation window, the cross-coupling's partner) is unknown as well
//! and is set to the rail. A gyroscope row with any axis at its range is left as it is (its
//! least-squares rate is unknown; the row stays flagged). Without this, a scale below 1 moved railed
//! values inside the range, where they were fitted as measurements.
//!
//! | effect | what is done to output `s` at time `t` | value unit |
//! | --- | --- | --- |
//! | `bias_turn_on` | `s + V` | m/s^2 |
//! | `bias_time_drift` | `s + V (t - t_0)` | m/s^2/s |
//! | `scale_factor_quadratic` | `s + V s^2` | 1/(m/s^2) |
//! | `scale_factor_cubic` | `s + V s^3` | 1/(m/s^2)^2 |
//! | `cross_coupling` | `s + V s (+-s_K)`, `K` the axis of the same package along the first tilt direction `e1` of `s`'s nominal axis (`sensor::misalignment::tilt_basis`), signed so that `+-s_K` reads `e1 . q` | 1/(m/s^2) |
//! | `gyro_scale_misalignment` (with `--element`, no accelerometer) | each gyroscope column `y_g + a_g . ((I + G)^-1 - I) w`, `w` the reference rate, `G` zero but element `--element` = V: the true rate is `(I + G)` times the reference | 1 |
//! | `sampling_delay` | `s(t - V)`: a fractional delay by a windowed-sinc interpolator over 2 x 16 neighbours (band-limited to the sample rate's Nyquist; uniform sampling at the recording's mean interval assumed) | s |
//!
//! The delay's interpolator is band-limited rather than linear: at 62.5 Hz a hand-held rotation
//! turns the board by about 0.4 rad between samples, and linear interpolation delays such a
//! signal by only about two thirds of `V` (measured on recording 2: 0.28 ms for 0.4 ms).

use nalgebra::{Matrix3, Vector3};

use crate::array::wiring::RecordingArray;
use crate::io::table::Table;

/// The effect `gfcal inject` adds to the gyroscopes' columns (with `--element`).
pub const GYRO_EFFECT: &str = "gyro_scale_misalignment";

/// The effects `gfcal inject` can add to one accelerometer's column.
pub const INJECTABLE: [&str; 6] = [
    "bias_turn_on",
    "bias_time_drift",
    "scale_factor_quadratic",
    "scale_factor_cubic",
    "cross_coupling",
    "sampling_delay",
];

/// Why an effect cannot be injected.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum InjectError {
    #[error("--effect: unknown effect `{0}` (known: {known}, {GYRO_EFFECT})", known = INJECTABLE.join(", "))]
    UnknownEffect(String),
    #[error("--accelerometer: {given} is not an accelerometer of {array} (1 to {n})")]
    Accelerometer { given: usize, array: String, n: usize },
    #[error("--value: must be a finite number, got {0}")]
    Value(f64),
    #[error("{}: has no column `{column}` (accelerometer {j} of the array file {array})", path.display())]
    MissingColumn { path: std::path::PathBuf, column: String, j: usize, array: String },
    #[error(
        "{}: has no time column `{column}` (in seconds: the array file {array}'s `time_column`, default `t_s`)",
        path.display()
    )]
    NoTime { path: std::path::PathBuf, column: String, array: String },
    #[error(
        "--effect cross_coupling: accelerometer {j} of {array} has no axis in its package (same position) along its first cross direction, which reads the force it couples to"
    )]
    NoPartner { j: usize, array: String },
    #[error(
        "--value: a delay of {value} s is not shorter than the recording ({span_s} s): every output would be a held end value"
    )]
    DelayTooLong { value: f64, span_s: f64 },
    #[error("--element: unknown element `{0}` of the gyroscopes' matrix (known: {known})", known = GYRO_ELEMENTS.join(", "))]
    Element(String),
    #[error("--effect gyro_scale_misalignment: the array file {array} lists no gyroscopes spanning three axes")]
    NoGyroscopes { array: String },
    #[error("{}: has no column `{column}` (a gyroscope of the array file {array})", path.display())]
    MissingGyroColumn { path: std::path::PathBuf, column: String, array: String },
}

/// Adds `effect` of size `value` to accelerometer `accelerometer` (1-based) of `table`; returns how
/// many of its outputs the effect put at the rail (pushed past the range, or computed from a
/// railed one), which a diagnosis then leaves out as clipped.
pub fn inject(
    table: &mut Table,
    array: &RecordingArray,
    effect: &str,
    accelerometer: usize,
    value: f64,
) -> Result<usize, InjectError> {
    if !INJECTABLE.contains(&effect) {
        return Err(InjectError::UnknownEffect(effect.to_string()));
    }
    let n = array.array.len();
    let array_name = array.path.display().to_string();
    if accelerometer == 0 || accelerometer > n {
        return Err(InjectError::Accelerometer { given: accelerometer, array: array_name, n });
    }
    if !value.is_finite() {
        return Err(InjectError::Value(value));
    }
    let j = accelerometer - 1;
    let column = array.accelerometer_columns[j].clone();
    let t: Vec<f64> = table
        .column(&array.time_column)
        .ok_or_else(|| InjectError::NoTime {
            path: table.path.clone(),
            column: array.time_column.clone(),
            array: array_name.clone(),
        })?
        .to_vec();
    let k = table.index(&column).ok_or_else(|| InjectError::MissingColumn {
        path: table.path.clone(),
        column: column.clone(),
        j: accelerometer,
        array: array_name.clone(),
    })?;
    // The cross-coupling's partner: the axis of the same package along e1; its column, sign and range.
    let partner: Option<(Vec<f64>, f64, f64)> = if effect == "cross_coupling" {
        let acc = array.array.accelerometers();
        let (e1, _) = crate::sensor::misalignment::tilt_basis(&acc[j].axis);
        let found = (0..n).find(|&m| {
            m != j && (acc[m].position_m - acc[j].position_m).norm() < 1e-9 && acc[m].axis.dot(&e1).abs() > 0.99
        });
        let m = found.ok_or_else(|| InjectError::NoPartner { j: accelerometer, array: array_name.clone() })?;
        let col = table.column(&array.accelerometer_columns[m]).ok_or_else(|| InjectError::MissingColumn {
            path: table.path.clone(),
            column: array.accelerometer_columns[m].clone(),
            j: m + 1,
            array: array_name.clone(),
        })?;
        Some((col.to_vec(), acc[m].axis.dot(&e1).signum(), array.ranges_m_s2[m]))
    } else {
        None
    };
    let range = array.ranges_m_s2[j];
    let s = &mut table.data[k];
    let t0 = t.first().copied().unwrap_or(0.0);
    let original = s.clone();
    let mean_dt = match (t.first(), t.last()) {
        (Some(a), Some(b)) if t.len() > 1 => (b - a) / (t.len() - 1) as f64,
        _ => 1.0,
    };
    if effect == "sampling_delay" && value.abs() >= mean_dt * (t.len().max(2) - 1) as f64 {
        return Err(InjectError::DelayTooLong { value, span_s: mean_dt * (t.len().max(1) - 1) as f64 });
    }
    let delay = crate::signal::FractionalDelay::new(value / mean_dt);
    let mut censored = 0;
    let railed = |y: &[f64], a: usize, b: usize| y[a..=b].iter().any(|v| v.abs() >= range);
    for (i, v) in s.iter_mut().enumerate() {
        let x = original[i];
        if x.abs() >= range {
            continue;
        }
        let (new, from_railed) = match effect {
            "bias_turn_on" => (x + value, false),
            "bias_time_drift" => (x + value * (t[i] - t0), false),
            "scale_factor_quadratic" => (x + value * x * x, false),
            "scale_factor_cubic" => (x + value * x * x * x, false),
            "cross_coupling" => partner
                .as_ref()
                .map_or((x, false), |(p, sign, rail)| (x + value * x * sign * p[i], p[i].abs() >= *rail)),
            _ => {
                let (a, b) = delay.window(i, original.len());
                (delay.at(&original, i), railed(&original, a, b))
            }
        };
        *v = if from_railed || new.abs() >= range {
            censored += 1;
            range.copysign(new)
        } else {
            new
        };
    }
    Ok(censored)
}

/// The elements of the gyroscopes' scale and misalignment matrix `G`: row (the array axis the
/// true rate is read along) then column.
pub const GYRO_ELEMENTS: [&str; 9] = ["xx", "xy", "xz", "yx", "yy", "yz", "zx", "zy", "zz"];

/// Adds the gyroscopes' own scale factor and misalignment to `table`: element `element` of `G` is
/// `value` (1), the others 0, and the reference rate (the least-squares rate of the array file's
/// gyroscope axes, as a recording reads it) becomes `(I + G)^-1 w`, so that the true rate is
/// `(I + G)` times the reference, as `gyro_scale_misalignment` models it. Each gyroscope column
/// `y_g` gains `a_g . ((I + G)^-1 - I) w`, which moves the least-squares rate by exactly that and
/// leaves each axis's own noise in place; an output pushed past its range is clipped at the rail,
/// and a row with an axis at its range is left as it is (censored).
pub fn inject_gyro(table: &mut Table, array: &RecordingArray, element: &str, value: f64) -> Result<(), InjectError> {
    let position =
        GYRO_ELEMENTS.iter().position(|e| *e == element).ok_or_else(|| InjectError::Element(element.into()))?;
    if !value.is_finite() {
        return Err(InjectError::Value(value));
    }
    let gyros = &array.gyroscopes;
    let normal: Matrix3<f64> = gyros.iter().map(|g| g.axis * g.axis.transpose()).sum();
    let inverse = normal.try_inverse().filter(|_| !gyros.is_empty());
    let inverse = inverse.ok_or_else(|| InjectError::NoGyroscopes { array: array.path.display().to_string() })?;
    let mut g = Matrix3::zeros();
    g[(position / 3, position % 3)] = value;
    let change = (Matrix3::identity() + g).try_inverse().ok_or(InjectError::Value(value))? - Matrix3::identity();
    let mut columns = Vec::with_capacity(gyros.len());
    for gyro in gyros {
        let k = table.index(&gyro.column).ok_or_else(|| InjectError::MissingGyroColumn {
            path: table.path.clone(),
            column: gyro.column.clone(),
            array: array.path.display().to_string(),
        })?;
        columns.push(k);
    }
    let rows = table.data.first().map_or(0, Vec::len);
    for i in 0..rows {
        if gyros.iter().zip(&columns).any(|(gyro, &k)| table.data[k][i].abs() >= gyro.range_rad_s) {
            continue;
        }
        let b: Vector3<f64> = gyros.iter().zip(&columns).map(|(gyro, &k)| gyro.axis * table.data[k][i]).sum();
        let add = change * (inverse * b);
        for (gyro, &k) in gyros.iter().zip(&columns) {
            let v = table.data[k][i] + gyro.axis.dot(&add);
            table.data[k][i] = if v.abs() > gyro.range_rad_s { gyro.range_rad_s.copysign(v) } else { v };
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::array::Array;
    use crate::array::wiring::ReferenceGyro;

    /// A railed output's true value is unknown: it stays at the rail under every effect, and an
    /// output whose delay window reads it goes to the rail; outputs whose window is clear of it are
    /// delayed as usual. A gyroscope row with an axis at its range is left as it is.
    #[test]
    fn what_was_censored_stays_censored() {
        let mut array = RecordingArray::plain(Array::cube(0.1).unwrap(), std::path::Path::new("a.toml"));
        array.ranges_m_s2[0] = 10.0;
        let rows = 200;
        // A slow sine that rails at +10 around row 100 (rows 98-102).
        let signal: Vec<f64> =
            (0..rows).map(|i| if (98..=102).contains(&i) { 10.0 } else { 9.0 * (i as f64 * 0.01).sin() }).collect();
        let table = |col: &[f64]| Table {
            path: "r.csv".into(),
            names: vec!["t_s".into(), "s1".into()],
            data: vec![(0..rows).map(|i| i as f64 * 0.016).collect(), col.to_vec()],
            first_null_row: vec![None; 2],
        };
        for (effect, value) in [("scale_factor_quadratic", -1e-2), ("bias_turn_on", -0.5), ("sampling_delay", 4e-3)] {
            let mut t = table(&signal);
            inject(&mut t, &array, effect, 1, value).unwrap();
            for i in 98..=102 {
                assert_eq!(t.data[1][i], 10.0, "{effect}: row {i} stays railed");
            }
            assert!(t.data[1][20] != signal[20] && t.data[1][20].abs() < 10.0, "{effect}: row 20 changed, in range");
        }
        let mut t = table(&signal);
        let censored = inject(&mut t, &array, "sampling_delay", 1, 4e-3).unwrap();
        // A quarter-sample delay reads rows i - 16 to i + 15: rows 83-118, less the five railed before.
        for i in 70..=130 {
            let window_reads_rail = i + 15 >= 98 && i <= 102 + 16;
            assert_eq!(t.data[1][i] == 10.0, window_reads_rail, "row {i}: {}", t.data[1][i]);
        }
        assert_eq!(censored, (118 - 83 + 1) - 5);
        let clear = crate::signal::FractionalDelay::new(0.25).at(&signal, 40);
        assert_eq!(t.data[1][40], clear);
        // Pushed past the range by +2: every output from 8 up, none of the railed ones again.
        let mut t = table(&signal);
        let pushed = signal.iter().filter(|&&v| (8.0..10.0).contains(&v)).count();
        assert!(pushed > 10);
        assert_eq!(inject(&mut t, &array, "bias_turn_on", 1, 2.0).unwrap(), pushed);
        // A delay as long as the recording holds an end value everywhere: refused.
        let mut t = table(&signal);
        let span_s = 199.0 * 0.016;
        assert!(matches!(inject(&mut t, &array, "sampling_delay", 1, -span_s), Err(InjectError::DelayTooLong { .. })));
        assert!(inject(&mut t, &array, "sampling_delay", 1, 0.9 * span_s).is_ok());

        array.gyroscopes = [Vector3::x(), Vector3::y(), Vector3::z()]
            .iter()
            .enumerate()
            .map(|(i, a)| ReferenceGyro { axis: *a, column: format!("g{i}"), range_rad_s: 5.0, package: None })
            .collect();
        let mut g = Table {
            path: "r.csv".into(),
            names: (0..3).map(|k| format!("g{k}")).collect(),
            data: vec![vec![1.0, 5.0], vec![2.0, 2.0], vec![3.0, 3.0]],
            first_null_row: vec![None; 3],
        };
        inject_gyro(&mut g, &array, "yy", -0.1).unwrap();
        assert_eq!([g.data[0][1], g.data[1][1], g.data[2][1]], [5.0, 2.0, 3.0], "the railed row is untouched");
        assert!((g.data[1][0] - 2.0 / 0.9).abs() < 1e-12, "the other row reads through (I + G)^-1");
    }

    /// Four gyroscope axes (three orthogonal and a skew one) with noisy columns; after injecting
    /// `G_xy = 0.01` the least-squares rate, computed here from the columns, is `(I + G)^-1` times
    /// the one before, and each axis's own residual (its noise) is where it was.
    #[test]
    fn the_gyroscopes_read_through_the_inverse_of_i_plus_g_with_their_noise_kept() {
        let axes = [Vector3::x(), Vector3::y(), Vector3::z(), Vector3::new(1.0, 1.0, 1.0).normalize()];
        let mut array = RecordingArray::plain(Array::cube(0.1).unwrap(), std::path::Path::new("a.toml"));
        array.gyroscopes = axes
            .iter()
            .enumerate()
            .map(|(i, a)| ReferenceGyro {
                axis: *a,
                column: format!("g{i}"),
                range_rad_s: f64::INFINITY,
                package: None,
            })
            .collect();
        let rows = 50;
        let rate =
            |i: usize| Vector3::new((i as f64 * 0.3).sin() * 5.0, (i as f64 * 0.17).cos() * 3.0, 2.0 - i as f64 * 0.1);
        let noise = |i: usize, g: usize| 1e-3 * ((i * 7 + g * 13) as f64).sin();
        let mut table = Table {
            path: "r.csv".into(),
            names: (0..4).map(|g| format!("g{g}")).collect(),
            data: (0..4).map(|g| (0..rows).map(|i| axes[g].dot(&rate(i)) + noise(i, g)).collect()).collect(),
            first_null_row: vec![None; 4],
        };
        let least_squares = |t: &Table, i: usize| {
            let n: Matrix3<f64> = axes.iter().map(|a| a * a.transpose()).sum();
            let b: Vector3<f64> = axes.iter().enumerate().map(|(g, a)| a * t.data[g][i]).sum();
            n.try_inverse().unwrap() * b
        };
        let before: Vec<Vector3<f64>> = (0..rows).map(|i| least_squares(&table, i)).collect();
        let original = table.data.clone();
        inject_gyro(&mut table, &array, "xy", 0.01).unwrap();
        let mut g = Matrix3::identity();
        g[(0, 1)] = 0.01;
        let read = g.try_inverse().unwrap();
        for i in 0..rows {
            let after = least_squares(&table, i);
            assert!((after - read * before[i]).norm() < 1e-12, "row {i}");
            for (k, a) in axes.iter().enumerate() {
                let residual = |t: &Vec<Vec<f64>>, w: &Vector3<f64>| t[k][i] - a.dot(w);
                assert!((residual(&table.data, &after) - residual(&original, &before[i])).abs() < 1e-12);
            }
        }
        assert!(matches!(inject_gyro(&mut table, &array, "xw", 0.01), Err(InjectError::Element(_))));
        array.gyroscopes.clear();
        assert!(matches!(inject_gyro(&mut table, &array, "xy", 0.01), Err(InjectError::NoGyroscopes { .. })));
    }
}
