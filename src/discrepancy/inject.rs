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
//! | effect | what is done to output `s` at time `t` | value unit |
//! | --- | --- | --- |
//! | `bias_turn_on` | `s + V` | m/s^2 |
//! | `bias_time_drift` | `s + V (t - t_0)` | m/s^2/s |
//! | `scale_factor_quadratic` | `s + V s^2` | 1/(m/s^2) |
//! | `scale_factor_cubic` | `s + V s^3` | 1/(m/s^2)^2 |
//! | `cross_coupling` | `s + V s (+-s_K)`, `K` the axis of the same package along the first tilt direction `e1` of `s`'s nominal axis (`sensor::misalignment::tilt_basis`), signed so that `+-s_K` reads `e1 . q` | 1/(m/s^2) |
//! | `sampling_delay` | `s(t - V)`: a fractional delay by a windowed-sinc interpolator over 2 x 16 neighbours (band-limited to the sample rate's Nyquist; uniform sampling at the recording's mean interval assumed) | s |
//!
//! The delay's interpolator is band-limited rather than linear: at 62.5 Hz a hand-held rotation
//! turns the board by about 0.4 rad between samples, and linear interpolation delays such a
//! signal by only about two thirds of `V` (measured on recording 2: 0.28 ms for 0.4 ms).

use crate::io::table::Table;
use crate::selfcal::recording::RecordingArray;

/// The effects `gfcal inject` can add.
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
    #[error("--effect: unknown effect `{0}` (known: {known})", known = INJECTABLE.join(", "))]
    UnknownEffect(String),
    #[error("--accelerometer: {given} is not an accelerometer of {array} (1 to {n})")]
    Accelerometer { given: usize, array: String, n: usize },
    #[error("--value: must be a finite number, got {0}")]
    Value(f64),
    #[error("{}: has no column `{column}` (accelerometer {j} of the array file {array})", path.display())]
    MissingColumn { path: std::path::PathBuf, column: String, j: usize, array: String },
    #[error("{}: has no column `t_s`", path.display())]
    NoTime { path: std::path::PathBuf },
    #[error(
        "--effect cross_coupling: accelerometer {j} of {array} has no axis in its package (same position) along its first cross direction, which reads the force it couples to"
    )]
    NoPartner { j: usize, array: String },
}

/// Adds `effect` of size `value` to accelerometer `accelerometer` (1-based) of `table`.
pub fn inject(
    table: &mut Table,
    array: &RecordingArray,
    effect: &str,
    accelerometer: usize,
    value: f64,
) -> Result<(), InjectError> {
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
    let t: Vec<f64> = table.column("t_s").ok_or_else(|| InjectError::NoTime { path: table.path.clone() })?.to_vec();
    let k = table.index(&column).ok_or_else(|| InjectError::MissingColumn {
        path: table.path.clone(),
        column: column.clone(),
        j: accelerometer,
        array: array_name.clone(),
    })?;
    // The cross-coupling's partner: the axis of the same package along e1, and its sign.
    let partner: Option<(Vec<f64>, f64)> = if effect == "cross_coupling" {
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
        Some((col.to_vec(), acc[m].axis.dot(&e1).signum()))
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
    for (i, v) in s.iter_mut().enumerate() {
        let x = original[i];
        *v = match effect {
            "bias_turn_on" => x + value,
            "bias_time_drift" => x + value * (t[i] - t0),
            "scale_factor_quadratic" => x + value * x * x,
            "scale_factor_cubic" => x + value * x * x * x,
            "cross_coupling" => partner.as_ref().map_or(x, |(p, sign)| x + value * x * sign * p[i]),
            _ => crate::signal::fractional_delay(&original, i, value / mean_dt),
        };
        if v.abs() > range {
            *v = range.copysign(*v);
        }
    }
    Ok(())
}

/// `y` at `at` by linear interpolation over increasing `t` (held at the ends).
#[cfg(test)]
fn interpolate(t: &[f64], y: &[f64], at: f64) -> f64 {
    match t.partition_point(|&ti| ti <= at) {
        0 => y[0],
        i if i >= t.len() => y[t.len() - 1],
        i => {
            let w = (at - t[i - 1]) / (t[i] - t[i - 1]);
            y[i - 1] + w * (y[i] - y[i - 1])
        }
    }
}

#[cfg(test)]
mod tests {
    use super::interpolate;

    #[test]
    fn interpolation_is_linear_and_held_at_the_ends() {
        let t = [0.0, 1.0, 2.0];
        let y = [0.0, 10.0, 30.0];
        assert_eq!(interpolate(&t, &y, 0.25), 2.5);
        assert_eq!(interpolate(&t, &y, 1.5), 20.0);
        assert_eq!(interpolate(&t, &y, -1.0), 0.0);
        assert_eq!(interpolate(&t, &y, 5.0), 30.0);
    }
}
