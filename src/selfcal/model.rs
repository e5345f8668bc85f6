//! The model of a free (hand-held) calibration recording and its parameters.
//!
//! Accelerometer j (nominal position `r_j`, nominal unit axis `theta_j`) has a scale factor `k_j`,
//! an input-referred bias `b_j` (m/s^2), a unit true axis `a_j` tilted from `theta_j` by two angles
//! `(tilt_u, tilt_w)` (tilt form, `sensor::misalignment`), and a location error `dr_j` (m). Its
//! output is
//!
//! ```text
//! s_j = k_j (b_j + a_j . q_j)
//! static pose p:     q_j = g u_p                                  (u_p unit, up, array axes)
//! dynamic sample t:  q_j = f_t + alpha_t x r'_j + w_t (w_t . r'_j) - |w_t|^2 r'_j,  r'_j = r_j + dr_j
//! ```
//!
//! with the pose directions `u_p` and the motion `(f_t, alpha_t, w_t)` (specific force at the
//! array origin, angular acceleration, angular rate) unknown nuisances.
//!
//! **Gauge.** Three families of parameter changes leave every output unchanged, so no recording
//! can see them:
//! - a common rotation `e` of every axis, every pose and every location (and of the motion):
//!   `d tilt_u_j = e . w_j`, `d tilt_w_j = -e . u_j`, `d u_p = e x u_p`, `d dr_j = e x r'_j`.
//!   Fixed by *the array frame is the mean frame of the accelerometers*: the rotation vectors of
//!   the tilts sum to zero, `sum_j (tilt_u_j w_j - tilt_w_j u_j) = 0`. (With reference
//!   gyroscopes supplying the rate, their axes fix it instead.)
//! - a common shift `d` of every location, absorbed by `f_t` (`f_t -> f_t - A_t d`). Fixed by
//!   *the origin is the centroid of the sensing points*: `sum_j dr_j = 0`.
//! - without gyroscopes, a common scaling about the centroid (`r' -> l r'`, `alpha -> alpha / l`,
//!   `w -> w / sqrt(l)`): a gyroscope-free array cannot measure its own size, since its rate is
//!   known only through `|w|^2 r`. Fixed by *the array has its nominal size*:
//!   `sum_j (r_j - c) . dr_j = 0` with `c` the nominal centroid.

use nalgebra::{DMatrix, Matrix3, Vector3};

use crate::array::Array;
use crate::sensor::misalignment::{tilt_axis_with_derivatives, tilt_basis};

/// Parameters per accelerometer: `k, b, tilt_u, tilt_w, dx, dy, dz`.
pub const PER_ACCEL: usize = 7;

/// Parameter names per accelerometer, as in the parameters table.
pub const NAMES: [&str; PER_ACCEL] = ["scale_factor", "bias", "tilt_u", "tilt_w", "dx", "dy", "dz"];
/// SI units of [`NAMES`].
pub const UNITS: [&str; PER_ACCEL] = ["1", "m/s^2", "rad", "rad", "m", "m", "m"];

/// The error parameters of every accelerometer.
#[derive(Debug, Clone, PartialEq)]
pub struct SensorSet {
    pub scale_factor: Vec<f64>,
    pub bias_m_s2: Vec<f64>,
    pub tilt_rad: Vec<[f64; 2]>,
    pub location_error_m: Vec<Vector3<f64>>,
}

impl SensorSet {
    /// Scale factor 1, no bias, nominal axes and positions.
    pub fn nominal(n: usize) -> Self {
        Self {
            scale_factor: vec![1.0; n],
            bias_m_s2: vec![0.0; n],
            tilt_rad: vec![[0.0; 2]; n],
            location_error_m: vec![Vector3::zeros(); n],
        }
    }
    pub fn len(&self) -> usize {
        self.scale_factor.len()
    }
    pub fn is_empty(&self) -> bool {
        self.scale_factor.is_empty()
    }
    /// Parameter `p` (0..7) of accelerometer `j` in SI units.
    pub fn get(&self, j: usize, p: usize) -> f64 {
        match p {
            0 => self.scale_factor[j],
            1 => self.bias_m_s2[j],
            2 | 3 => self.tilt_rad[j][p - 2],
            _ => self.location_error_m[j][p - 4],
        }
    }
    /// The parameters as one vector, `PER_ACCEL` per accelerometer in [`NAMES`] order (the order
    /// of `calib::Layout` in the tilt form).
    pub fn to_vector(&self) -> Vec<f64> {
        (0..self.len() * PER_ACCEL).map(|i| self.get(i / PER_ACCEL, i % PER_ACCEL)).collect()
    }
    /// The inverse of [`SensorSet::to_vector`].
    pub fn from_vector(x: &[f64]) -> Self {
        let n = x.len() / PER_ACCEL;
        let mut s = Self::nominal(n);
        for (i, v) in x.iter().enumerate().take(n * PER_ACCEL) {
            let (j, p) = (i / PER_ACCEL, i % PER_ACCEL);
            s.add(j, p, v - s.get(j, p));
        }
        s
    }
    /// Adds `d` to parameter `p` of accelerometer `j`.
    pub fn add(&mut self, j: usize, p: usize, d: f64) {
        match p {
            0 => self.scale_factor[j] += d,
            1 => self.bias_m_s2[j] += d,
            2 | 3 => self.tilt_rad[j][p - 2] += d,
            _ => self.location_error_m[j][p - 4] += d,
        }
    }
}

/// One accelerometer's geometry at the current parameters, cached for evaluation.
#[derive(Debug, Clone, Copy)]
pub struct Sensor {
    pub k: f64,
    pub b_m_s2: f64,
    /// True unit axis and its derivatives by the two tilt angles.
    pub axis: Vector3<f64>,
    pub daxis: [Vector3<f64>; 2],
    /// True position `r_j + dr_j`, m.
    pub position_m: Vector3<f64>,
}

/// The geometry of every accelerometer at `params`.
pub fn sensors(array: &Array, params: &SensorSet) -> Vec<Sensor> {
    array
        .accelerometers()
        .iter()
        .enumerate()
        .map(|(j, a)| {
            let (axis, daxis) = tilt_axis_with_derivatives(&a.axis, &params.tilt_rad[j]);
            Sensor {
                k: params.scale_factor[j],
                b_m_s2: params.bias_m_s2[j],
                axis,
                daxis,
                position_m: a.position_m + params.location_error_m[j],
            }
        })
        .collect()
}

/// The rigid motion of one dynamic sample, array axes.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SampleMotion {
    /// Specific force at the array origin, m/s^2.
    pub f_m_s2: Vector3<f64>,
    pub alpha_rad_s2: Vector3<f64>,
    pub omega_rad_s: Vector3<f64>,
}

impl SampleMotion {
    /// Specific force at `r` (m).
    pub fn specific_force_m_s2(&self, r: &Vector3<f64>) -> Vector3<f64> {
        let w = &self.omega_rad_s;
        self.f_m_s2 + self.alpha_rad_s2.cross(r) + w * w.dot(r) - r * w.norm_squared()
    }
}

impl Sensor {
    /// Output at specific force `q`.
    pub fn output(&self, q: &Vector3<f64>) -> f64 {
        self.k * (self.b_m_s2 + self.axis.dot(q))
    }

    /// Derivatives of the output at specific force `q` by `(k, b, tilt_u, tilt_w)`.
    pub fn d_intrinsic(&self, q: &Vector3<f64>) -> [f64; 4] {
        [self.b_m_s2 + self.axis.dot(q), self.k, self.k * self.daxis[0].dot(q), self.k * self.daxis[1].dot(q)]
    }

    /// Derivative of a dynamic output by the location error: `k (a x alpha + W a)`.
    pub fn d_location(&self, m: &SampleMotion) -> Vector3<f64> {
        let w = &m.omega_rad_s;
        let a = &self.axis;
        (a.cross(&m.alpha_rad_s2) + w * w.dot(a) - a * w.norm_squared()) * self.k
    }

    /// Derivatives of a dynamic output by the motion `(f, alpha, omega)`.
    pub fn d_motion(&self, m: &SampleMotion) -> [f64; 9] {
        let a = &self.axis;
        let r = &self.position_m;
        let w = &m.omega_rad_s;
        let df = a * self.k;
        let dalpha = r.cross(a) * self.k;
        let domega = (r * a.dot(w) + a * w.dot(r) - w * (2.0 * a.dot(r))) * self.k;
        [df.x, df.y, df.z, dalpha.x, dalpha.y, dalpha.z, domega.x, domega.y, domega.z]
    }

    /// Second derivative of a dynamic output by the rate, `k (a r^T + r a^T - 2 (a . r) I)`: the
    /// centripetal term is quadratic in the rate, so this is the same at every motion.
    pub fn d2_rate(&self) -> Matrix3<f64> {
        let a = &self.axis;
        let r = &self.position_m;
        (a * r.transpose() + r * a.transpose() - Matrix3::identity() * (2.0 * a.dot(r))) * self.k
    }
}

/// Which gauge conditions apply: rotation (no reference rate), translation (dynamic data), scale
/// (dynamic data and no reference rate).
///
/// **Translation by axis group.** The specific force at the origin is a free unknown of every
/// sample, and a sensing point enters an output only through `a_j . (alpha x r_j + W r_j)`: a
/// common translation `d` of the sensing points of a set of accelerometers changes their outputs
/// by `a_j . (alpha x d + W d)`, which the specific force's component along their axes absorbs
/// exactly, unless some other accelerometer's axis shares that component. So where the nominal
/// axes fall into groups whose spans are mutually orthogonal ([`axis_groups`]: the 24 axes of
/// eight three-axis packages aligned with the array frame fall into the x, y and z groups), each
/// group's common translation is null at nominal axes, and the data see it only through the axes'
/// small tilts (a few mrad): a fit that lets it go takes it from whatever the model leaves out
/// (on the MIMU4444, sensing points of one package's x, y and z axes 8-29 mm apart). The gauge
/// then fixes every group's translation (its location errors sum to zero: the group's mean
/// sensing point is the drawing's), `3 x groups` rows in place of the origin's 3. An array of one
/// group (any array whose axes do not split so) has the single translation row set as before.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Gauge {
    pub rotation: bool,
    pub translation: bool,
    pub scale: bool,
    /// Axis groups whose translations are fixed ([`axis_groups`]); 1 for most arrays.
    pub translation_groups: usize,
}

/// Axes closer to orthogonal than this (|cos|) do not join two accelerometers into one group.
pub const ORTHOGONAL_COS: f64 = 1e-6;

/// The accelerometers' axis groups: the connected components of "the nominal axes are not
/// orthogonal" (`|a_j . a_k| > ORTHOGONAL_COS`), numbered in the order they first appear. The
/// spans of two groups are orthogonal, so each group alone sees the specific force's component in
/// its span (see [`Gauge`]).
pub fn axis_groups(array: &Array) -> Vec<usize> {
    let axes: Vec<Vector3<f64>> = array.accelerometers().iter().map(|a| a.axis).collect();
    let n = axes.len();
    let mut group = vec![usize::MAX; n];
    let mut next = 0;
    for start in 0..n {
        if group[start] != usize::MAX {
            continue;
        }
        group[start] = next;
        let mut stack = vec![start];
        while let Some(j) = stack.pop() {
            for k in 0..n {
                if group[k] == usize::MAX && axes[j].dot(&axes[k]).abs() > ORTHOGONAL_COS {
                    group[k] = next;
                    stack.push(k);
                }
            }
        }
        next += 1;
    }
    group
}

impl Gauge {
    /// The gauge of a calibration of `array`: with dynamic data (locations and their
    /// translation), and with or without a reference rate.
    pub fn new(array: &Array, with_dynamic: bool, reference_rate: bool) -> Self {
        let groups = axis_groups(array).iter().max().map_or(1, |g| g + 1);
        Self {
            rotation: !(with_dynamic && reference_rate),
            translation: with_dynamic,
            scale: with_dynamic && !reference_rate,
            translation_groups: groups.max(1),
        }
    }

    /// The constraint rows: the directions the gauge fixes.
    pub fn count(&self) -> usize {
        3 * self.rotation as usize + 3 * self.translation_groups * self.translation as usize + self.scale as usize
    }

    /// The directions the Fisher information leaves exactly null at generic (tilted) axes: the
    /// rows less the axis groups' translations beyond the origin's, which the tilts let the data
    /// see a little.
    pub fn null_count(&self) -> usize {
        self.count() - 3 * (self.translation_groups - 1) * self.translation as usize
    }

    /// Names of the gauge conditions, in row order of [`Gauge::constraints`].
    pub fn describe(&self) -> Vec<String> {
        let mut v = Vec::new();
        if self.rotation {
            v.push(
                "rotation: the array frame is the mean frame of the accelerometers (tilt rotation vectors sum to zero)"
                    .to_string(),
            );
        }
        if self.translation && self.translation_groups > 1 {
            v.push(format!(
                "translation of each of the {} axis groups (accelerometers whose axes are orthogonal to every other group's): each group's location errors sum to zero, its mean sensing point the drawing's (the specific force along a group's axes absorbs the group's common translation; only the axes' tilts let the data see it)",
                self.translation_groups
            ));
        } else if self.translation {
            v.push(
                "translation: the origin is the centroid of the sensing points (location errors sum to zero)"
                    .to_string(),
            );
        }
        if self.scale {
            v.push("scale: the array has its nominal size (sum of (r_j - centroid) . dr_j is zero)".to_string());
        }
        v
    }

    /// The gauge conditions as linear rows over the accelerometer parameters (`PER_ACCEL * n`
    /// columns, then `extra` zero columns for the poses): `C x = 0` with `x` the parameter values
    /// (tilt angles and location errors; scale factors and biases do not enter).
    pub fn constraints(&self, array: &Array, with_locations: bool, extra: usize) -> DMatrix<f64> {
        let n = array.len();
        let cols = PER_ACCEL * n + extra;
        let mut c = DMatrix::zeros(self.count(), cols);
        let mut row = 0;
        if self.rotation {
            for (j, acc) in array.accelerometers().iter().enumerate() {
                let (u, w) = tilt_basis(&acc.axis);
                for d in 0..3 {
                    c[(row + d, PER_ACCEL * j + 2)] = w[d];
                    c[(row + d, PER_ACCEL * j + 3)] = -u[d];
                }
            }
            row += 3;
        }
        if self.translation && with_locations {
            let group = if self.translation_groups > 1 { axis_groups(array) } else { vec![0; n] };
            for (j, g) in group.iter().enumerate() {
                for d in 0..3 {
                    c[(row + 3 * g + d, PER_ACCEL * j + 4 + d)] = 1.0;
                }
            }
            row += 3 * self.translation_groups;
        }
        if self.scale && with_locations {
            let centroid: Vector3<f64> =
                array.accelerometers().iter().map(|a| a.position_m).sum::<Vector3<f64>>() / n as f64;
            for (j, acc) in array.accelerometers().iter().enumerate() {
                let r = acc.position_m - centroid;
                for d in 0..3 {
                    c[(row, PER_ACCEL * j + 4 + d)] = r[d];
                }
            }
        }
        c
    }
}
