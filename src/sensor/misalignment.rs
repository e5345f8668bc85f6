//! Misalignment of the sensitive axes, in two forms, with exact conversions between them.
//!
//! **Triad form** (Hung & Lee 2006, eq. 5-10). The array's accelerometers are grouped in triads of
//! linearly independent axes; for a triad with ideal axes `(theta_a, theta_b, theta_c)` as the rows
//! of `C_b^a`, the true axes are the rows of `C_a^a' C_b^a` with
//!
//! ```text
//! C_a^a' = [[ 1,    d_xz, -d_xy],
//!           [-d_yz,  1,    d_yx],
//!           [ d_zy, -d_zx,  1  ]]
//! ```
//!
//! so `theta'_a = theta_a + d_xz theta_b - d_xy theta_c` and so on. These axes are not unit
//! vectors, so tilting an axis toward a non-orthogonal neighbour changes its length: misalignment
//! and scale factor are coupled in this form.
//!
//! **Tilt form**. Two small angles `(t_u, t_w)` rotate the nominal unit axis `theta` toward the
//! unit vectors `u` and `w` orthogonal to it; the true axis stays a unit vector:
//! `theta' = cos(phi) theta + sin(phi) (t_u u + t_w w) / phi`, `phi = |(t_u, t_w)|`. `u` is the
//! body axis least aligned with `theta`, made orthogonal to it; `w = theta x u`.
//!
//! Both forms describe the same physics once the axis length is moved into scale factor and bias:
//! `k (b + v . f) = (k / lambda) (lambda b + (lambda v) . f)` for any `lambda > 0`
//! ([`rescale_axis`]), so [`to_unit_axes`] and [`to_triad_axes`] convert parameters both ways
//! without loss.

use nalgebra::{Matrix3, Vector3};

use super::params::{ArrayParams, SensorParams};
use crate::array::Array;

/// The paper's six angles of one triad (rad). Row 1 of the triad has `(xy, xz)`, row 2 `(yx, yz)`,
/// row 3 `(zx, zy)`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct TriadAngles {
    pub xy_rad: f64,
    pub xz_rad: f64,
    pub yx_rad: f64,
    pub yz_rad: f64,
    pub zx_rad: f64,
    pub zy_rad: f64,
}

/// A misalignment of every accelerometer, in one of the two forms.
#[derive(Debug, Clone, PartialEq)]
pub enum Misalignment {
    /// One set of angles per triad of the array, in the array's triad order.
    Triad(Vec<TriadAngles>),
    /// Two tilt angles `(t_u, t_w)` per accelerometer, rad.
    Tilt(Vec<[f64; 2]>),
}

/// A misalignment that does not fit the array.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum MisalignmentError {
    #[error("the triad form needs every accelerometer in a triad; accelerometer {index} is in none")]
    NotInTriad { index: usize },
    #[error("expected {expected} {what}, got {got}")]
    Count { what: &'static str, expected: usize, got: usize },
    #[error("accelerometer {index}: the axis {problem}")]
    Axis { index: usize, problem: &'static str },
}

impl Misalignment {
    /// True sensitive axes of every accelerometer: unnormalised rows of `C_a^a' C_b^a` for the
    /// triad form, unit vectors for the tilt form.
    pub fn axes(&self, array: &Array) -> Result<Vec<Vector3<f64>>, MisalignmentError> {
        let n = array.len();
        match self {
            Misalignment::Triad(angles) => {
                let expected = array.triads().len();
                if angles.len() != expected {
                    return Err(MisalignmentError::Count { what: "triads of angles", expected, got: angles.len() });
                }
                (0..n)
                    .map(|j| {
                        let (t, row) = array.triad_of(j).ok_or(MisalignmentError::NotInTriad { index: j + 1 })?;
                        let tr = array.triads()[t];
                        let th = |k: usize| array.accelerometers()[tr[k]].axis;
                        let c = triad_row(&angles[t], row);
                        Ok(th(0) * c[0] + th(1) * c[1] + th(2) * c[2])
                    })
                    .collect()
            }
            Misalignment::Tilt(tilts) => {
                if tilts.len() != n {
                    return Err(MisalignmentError::Count { what: "tilt pairs", expected: n, got: tilts.len() });
                }
                Ok(array.accelerometers().iter().zip(tilts).map(|(a, t)| tilt_axis(&a.axis, t)).collect())
            }
        }
    }
}

/// Row `row` of `C_a^a'` (eq. 6/9): coefficients of the triad's ideal axes in the true axis.
fn triad_row(a: &TriadAngles, row: usize) -> [f64; 3] {
    match row {
        0 => [1.0, a.xz_rad, -a.xy_rad],
        1 => [-a.yz_rad, 1.0, a.yx_rad],
        _ => [a.zy_rad, -a.zx_rad, 1.0],
    }
}

/// Orthonormal pair `(u, w)` orthogonal to the unit axis `theta` that defines the tilt angles.
pub fn tilt_basis(theta: &Vector3<f64>) -> (Vector3<f64>, Vector3<f64>) {
    let k = (0..3).min_by(|&a, &b| theta[a].abs().total_cmp(&theta[b].abs())).unwrap_or(0);
    let e = Vector3::ith(k, 1.0);
    let u = (e - theta * theta.dot(&e)).normalize();
    (u, theta.cross(&u))
}

/// The unit true axis for tilt angles `t` (rad) of the nominal unit axis `theta`.
pub fn tilt_axis(theta: &Vector3<f64>, t: &[f64; 2]) -> Vector3<f64> {
    let (u, w) = tilt_basis(theta);
    let phi = t[0].hypot(t[1]);
    if phi == 0.0 {
        return *theta;
    }
    theta * phi.cos() + (u * t[0] + w * t[1]) * (phi.sin() / phi)
}

/// The unit tilted axis and its derivatives by the two tilt angles (exact; a series near zero).
pub fn tilt_axis_with_derivatives(theta: &Vector3<f64>, t: &[f64; 2]) -> (Vector3<f64>, [Vector3<f64>; 2]) {
    let (u, w) = tilt_basis(theta);
    let phi2 = t[0] * t[0] + t[1] * t[1];
    let phi = phi2.sqrt();
    // sinc(phi) = sin(phi)/phi and (d sinc/d phi)/phi.
    let (sinc, dsinc_over_phi) = if phi < 1e-4 {
        (1.0 - phi2 / 6.0, -1.0 / 3.0 + phi2 / 30.0)
    } else {
        let (s, c) = phi.sin_cos();
        (s / phi, (phi * c - s) / (phi2 * phi))
    };
    let e = u * t[0] + w * t[1];
    let a = theta * phi.cos() + e * sinc;
    let da = |ti: f64, basis: &Vector3<f64>| -theta * (sinc * ti) + e * (dsinc_over_phi * ti) + basis * sinc;
    (a, [da(t[0], &u), da(t[1], &w)])
}

/// Tilt angles (rad) of any non-zero true axis (its length is ignored) from nominal unit `theta`.
pub fn tilt_angles(theta: &Vector3<f64>, axis: &Vector3<f64>) -> [f64; 2] {
    let (u, w) = tilt_basis(theta);
    let d = axis.normalize();
    let perp = d - theta * d.dot(theta);
    let s = perp.norm();
    if s == 0.0 {
        return [0.0, 0.0];
    }
    let phi = s.atan2(d.dot(theta));
    [phi * perp.dot(&u) / s, phi * perp.dot(&w) / s]
}

/// Rescales one accelerometer's axis by `lambda > 0` and compensates scale factor and bias so
/// that its output is unchanged.
pub fn rescale_axis(s: &SensorParams, lambda: f64) -> SensorParams {
    SensorParams {
        scale_factor: s.scale_factor / lambda,
        bias_m_s2: s.bias_m_s2 * lambda,
        axis: s.axis * lambda,
        location_error_m: s.location_error_m,
    }
}

/// The same sensors with unit axes (tilt form): scale factor and bias absorb the axis length.
pub fn to_unit_axes(params: &ArrayParams) -> ArrayParams {
    ArrayParams { sensors: params.sensors.iter().map(|s| rescale_axis(s, 1.0 / s.axis.norm())).collect() }
}

/// The same sensors with triad-form axes (coefficient 1 on the accelerometer's own nominal axis),
/// scale factor and bias compensating.
pub fn to_triad_axes(array: &Array, params: &ArrayParams) -> Result<ArrayParams, MisalignmentError> {
    let sensors = params
        .sensors
        .iter()
        .enumerate()
        .map(|(j, s)| {
            let (c, row) = triad_coefficients(array, j, &s.axis)?;
            let own = c[row];
            if own <= 0.0 {
                return Err(MisalignmentError::Axis {
                    index: j + 1,
                    problem: "points away from its nominal direction",
                });
            }
            Ok(rescale_axis(s, 1.0 / own))
        })
        .collect::<Result<_, _>>()?;
    Ok(ArrayParams { sensors })
}

/// The paper's angles of every triad read from parameters in triad form (see [`to_triad_axes`]).
pub fn triad_angles(array: &Array, params: &ArrayParams) -> Result<Vec<TriadAngles>, MisalignmentError> {
    let triad_params = to_triad_axes(array, params)?;
    let mut out = vec![TriadAngles::default(); array.triads().len()];
    for (j, s) in triad_params.sensors.iter().enumerate() {
        let (c, row) = triad_coefficients(array, j, &s.axis)?;
        let (t, _) = array.triad_of(j).ok_or(MisalignmentError::NotInTriad { index: j + 1 })?;
        let a = &mut out[t];
        match row {
            0 => (a.xz_rad, a.xy_rad) = (c[1], -c[2]),
            1 => (a.yz_rad, a.yx_rad) = (-c[0], c[2]),
            _ => (a.zy_rad, a.zx_rad) = (c[0], -c[1]),
        }
    }
    Ok(out)
}

/// Tilt angles of every accelerometer (rad).
pub fn tilt_angles_all(array: &Array, params: &ArrayParams) -> Vec<[f64; 2]> {
    array.accelerometers().iter().zip(&params.sensors).map(|(a, s)| tilt_angles(&a.axis, &s.axis)).collect()
}

/// Coefficients of `axis` on its triad's nominal axes, and the accelerometer's row in the triad.
fn triad_coefficients(array: &Array, j: usize, axis: &Vector3<f64>) -> Result<([f64; 3], usize), MisalignmentError> {
    let (t, row) = array.triad_of(j).ok_or(MisalignmentError::NotInTriad { index: j + 1 })?;
    let tr = array.triads()[t];
    let th = |k: usize| array.accelerometers()[tr[k]].axis;
    let basis = Matrix3::from_columns(&[th(0), th(1), th(2)]);
    let c = basis
        .lu()
        .solve(axis)
        .ok_or(MisalignmentError::Axis { index: j + 1, problem: "cannot be expressed in its triad" })?;
    Ok(([c[0], c[1], c[2]], row))
}
