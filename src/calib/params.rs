//! The calibration parameter vector: 7 parameters per accelerometer, in either misalignment form,
//! with names, display units, the step model and its analytic Jacobian.
//!
//! Accelerometer j owns `x[7j..7j+7] = (k, b, m1, m2, dx, dy, dz)`: scale factor (output units per
//! m/s^2), bias (m/s^2), two misalignment angles (rad) and location error (m). In the **triad**
//! form `m` are the paper's two angles of the accelerometer's row of `C_a^a'` (row 1: `xy, xz`;
//! row 2: `yx, yz`; row 3: `zx, zy`), and the axis `a = theta + m1 d1 + m2 d2` is linear in them.
//! In the **tilt** form `m` are the tilt angles of a unit axis.
//!
//! In a step with up direction `u` and rate `w`, the specific force at the true position is
//! `f = g u + W (r + dr)`, `W = w w^T - |w|^2 I`, and the mean output is `s = k (b + a . f)`:
//!
//! ```text
//! ds/dk = b + a . f    ds/db = k    ds/dm_i = k (da/dm_i) . f    ds/ddr = k W a
//! ```

use nalgebra::{DVector, Matrix3, Vector3};

use super::schedule::Step;
use crate::array::Array;
use crate::sensor::misalignment::{
    MisalignmentError, TriadAngles, tilt_angles, tilt_axis_with_derivatives, to_triad_axes, to_unit_axes, triad_angles,
};
use crate::sensor::params::{ArrayParams, SensorParams};
use crate::units::{M_PER_MM, RAD_PER_DEG, STANDARD_GRAVITY_M_S2};

/// Parameters per accelerometer.
pub const PER_ACCEL: usize = 7;

/// Misalignment form of the parameter vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Form {
    /// The paper's triad angles (eq. 6/9): axes not unit, coupled with scale factor.
    Triad,
    /// Two tilt angles of a unit axis.
    Tilt,
}

impl Form {
    pub fn name(&self) -> &'static str {
        match self {
            Form::Triad => "triad",
            Form::Tilt => "tilt",
        }
    }
}

/// What a parameter is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamKind {
    ScaleFactor,
    Bias,
    /// Misalignment angle 0 or 1.
    Misalignment(u8),
    /// Location error along body x, y or z.
    Location(u8),
}

impl ParamKind {
    pub fn of_offset(offset: usize) -> Self {
        match offset {
            0 => ParamKind::ScaleFactor,
            1 => ParamKind::Bias,
            2 | 3 => ParamKind::Misalignment((offset - 2) as u8),
            _ => ParamKind::Location((offset - 4) as u8),
        }
    }

    /// The unit of the paper's Tables 6-9 and the factor from SI to it: bias in g, angles in deg,
    /// location in mm. Used only where gfcal lays its numbers beside the paper's
    /// (`calib::reproduce`); everything else gfcal prints is in [`ParamKind::si_unit`].
    pub fn paper_unit(&self) -> (&'static str, f64) {
        match self {
            ParamKind::ScaleFactor => ("1", 1.0),
            ParamKind::Bias => ("g", 1.0 / STANDARD_GRAVITY_M_S2),
            ParamKind::Misalignment(_) => ("deg", 1.0 / RAD_PER_DEG),
            ParamKind::Location(_) => ("mm", 1.0 / M_PER_MM),
        }
    }

    /// SI unit.
    pub fn si_unit(&self) -> &'static str {
        match self {
            ParamKind::ScaleFactor => "1",
            ParamKind::Bias => "m/s^2",
            ParamKind::Misalignment(_) => "rad",
            ParamKind::Location(_) => "m",
        }
    }
}

#[derive(Debug, Clone)]
enum AxisModel {
    /// `a = own + m1 d[0] + m2 d[1]`.
    Triad { own: Vector3<f64>, d: [Vector3<f64>; 2], names: [String; 2], row: usize, triad: usize },
    /// Unit axis tilted from `theta`.
    Tilt { theta: Vector3<f64> },
}

/// The parameter vector of an array in one form.
#[derive(Debug, Clone)]
pub struct Layout {
    array: Array,
    form: Form,
    axes: Vec<AxisModel>,
}

impl Layout {
    /// Fails for the triad form when an accelerometer belongs to no triad.
    pub fn new(array: &Array, form: Form) -> Result<Self, MisalignmentError> {
        let mut axes = Vec::with_capacity(array.len());
        for j in 0..array.len() {
            axes.push(match form {
                Form::Tilt => AxisModel::Tilt { theta: array.accelerometers()[j].axis },
                Form::Triad => {
                    let (t, row) = array.triad_of(j).ok_or(MisalignmentError::NotInTriad { index: j + 1 })?;
                    let tr = array.triads()[t];
                    let th = |k: usize| array.accelerometers()[tr[k]].axis;
                    let greek = match t {
                        0 => "alpha".to_string(),
                        1 => "beta".to_string(),
                        _ => format!("triad{}", t + 1),
                    };
                    // Rows of C_a^a' (eq. 6/9): the derivative of the axis by each angle.
                    let (d, pair) = match row {
                        0 => ([-th(2), th(1)], ["xy", "xz"]),
                        1 => ([th(2), -th(0)], ["yx", "yz"]),
                        _ => ([-th(1), th(0)], ["zx", "zy"]),
                    };
                    AxisModel::Triad {
                        own: th(row),
                        d,
                        names: [format!("{greek}_{}", pair[0]), format!("{greek}_{}", pair[1])],
                        row,
                        triad: t,
                    }
                }
            });
        }
        Ok(Self { array: array.clone(), form, axes })
    }

    pub fn array(&self) -> &Array {
        &self.array
    }
    pub fn form(&self) -> Form {
        self.form
    }
    /// Number of parameters, `7 N`.
    pub fn len(&self) -> usize {
        PER_ACCEL * self.array.len()
    }
    pub fn is_empty(&self) -> bool {
        self.array.is_empty()
    }
    pub fn kind(&self, i: usize) -> ParamKind {
        ParamKind::of_offset(i % PER_ACCEL)
    }
    /// 0-based accelerometer of parameter `i`.
    pub fn accel(&self, i: usize) -> usize {
        i / PER_ACCEL
    }

    /// Short name of the parameter's quantity, e.g. `scale_factor`, `alpha_xy`, `tilt_u`, `dz`.
    pub fn quantity(&self, i: usize) -> String {
        match self.kind(i) {
            ParamKind::ScaleFactor => "scale_factor".into(),
            ParamKind::Bias => "bias".into(),
            ParamKind::Misalignment(m) => match &self.axes[self.accel(i)] {
                AxisModel::Triad { names, .. } => names[m as usize].clone(),
                AxisModel::Tilt { .. } => ["tilt_u", "tilt_w"][m as usize].into(),
            },
            ParamKind::Location(c) => ["dx", "dy", "dz"][c as usize].into(),
        }
    }

    /// Full name, e.g. `a1.alpha_xy` (1-based accelerometer number).
    pub fn name(&self, i: usize) -> String {
        format!("a{}.{}", self.accel(i) + 1, self.quantity(i))
    }

    pub fn names(&self) -> Vec<String> {
        (0..self.len()).map(|i| self.name(i)).collect()
    }

    /// Index of a parameter by name.
    pub fn index_of(&self, name: &str) -> Option<usize> {
        (0..self.len()).find(|&i| self.name(i) == name)
    }

    /// The axis of accelerometer j for angles `m`, and its derivatives by `m1`, `m2`.
    pub fn axis(&self, j: usize, m: [f64; 2]) -> (Vector3<f64>, [Vector3<f64>; 2]) {
        match &self.axes[j] {
            AxisModel::Triad { own, d, .. } => (own + d[0] * m[0] + d[1] * m[1], *d),
            AxisModel::Tilt { theta } => tilt_axis_with_derivatives(theta, &m),
        }
    }

    /// The parameter vector of `params`, converted to this form (scale factor and bias absorb
    /// the axis length).
    pub fn pack(&self, params: &ArrayParams) -> Result<DVector<f64>, MisalignmentError> {
        let n = self.array.len();
        let (converted, angles): (ArrayParams, Vec<[f64; 2]>) = match self.form {
            Form::Triad => {
                let p = to_triad_axes(&self.array, params)?;
                let triads = triad_angles(&self.array, &p)?;
                let angles = (0..n)
                    .map(|j| match &self.axes[j] {
                        AxisModel::Triad { row, triad, .. } => triad_pair(&triads[*triad], *row),
                        AxisModel::Tilt { .. } => [0.0; 2],
                    })
                    .collect();
                (p, angles)
            }
            Form::Tilt => {
                let p = to_unit_axes(params);
                let angles = self
                    .array
                    .accelerometers()
                    .iter()
                    .zip(&p.sensors)
                    .map(|(a, s)| tilt_angles(&a.axis, &s.axis))
                    .collect();
                (p, angles)
            }
        };
        let mut x = DVector::zeros(self.len());
        for (j, s) in converted.sensors.iter().enumerate() {
            let o = PER_ACCEL * j;
            x[o] = s.scale_factor;
            x[o + 1] = s.bias_m_s2;
            x[o + 2] = angles[j][0];
            x[o + 3] = angles[j][1];
            for c in 0..3 {
                x[o + 4 + c] = s.location_error_m[c];
            }
        }
        Ok(x)
    }

    /// The sensors' parameters for a parameter vector.
    pub fn unpack(&self, x: &DVector<f64>) -> ArrayParams {
        let sensors = (0..self.array.len())
            .map(|j| {
                let o = PER_ACCEL * j;
                SensorParams {
                    scale_factor: x[o],
                    bias_m_s2: x[o + 1],
                    axis: self.axis(j, [x[o + 2], x[o + 3]]).0,
                    location_error_m: Vector3::new(x[o + 4], x[o + 5], x[o + 6]),
                }
            })
            .collect();
        ArrayParams { sensors }
    }

    /// Mean outputs of one step (output units) and, when asked, each accelerometer's 7 partial
    /// derivatives (by its own parameters, in vector order).
    pub fn step_model(
        &self,
        x: &DVector<f64>,
        step: &Step,
        g_m_s2: f64,
        out: &mut [f64],
        mut jac: Option<&mut [[f64; PER_ACCEL]]>,
    ) {
        let motion = StepMotion::new(step, g_m_s2);
        for (j, o) in out.iter_mut().enumerate() {
            let xj: [f64; PER_ACCEL] = std::array::from_fn(|a| x[PER_ACCEL * j + a]);
            let (s, d) = self.accel_model(j, &xj, &motion);
            *o = s;
            if let Some(jac) = jac.as_deref_mut() {
                jac[j] = d;
            }
        }
    }

    /// Mean output of accelerometer `j` with parameters `xj` in a step, and its 7 partials.
    pub fn accel_model(&self, j: usize, xj: &[f64; PER_ACCEL], motion: &StepMotion) -> (f64, [f64; PER_ACCEL]) {
        let [k, b, m1, m2, dx, dy, dz] = *xj;
        let (a, da) = self.axis(j, [m1, m2]);
        let dr = Vector3::new(dx, dy, dz);
        let f = motion.gravity_up_m_s2 + motion.w2 * (self.array.accelerometers()[j].position_m + dr);
        let af = a.dot(&f);
        let wa = motion.w2 * a * k;
        (k * (b + af), [b + af, k, k * da[0].dot(&f), k * da[1].dot(&f), wa.x, wa.y, wa.z])
    }
}

/// What a step does to the specific force: `f(r) = g up + W r`, `W = [omega x]^2`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepMotion {
    pub gravity_up_m_s2: Vector3<f64>,
    pub w2: Matrix3<f64>,
}

impl StepMotion {
    pub fn new(step: &Step, g_m_s2: f64) -> Self {
        let w = step.omega_b_rad_s();
        Self { gravity_up_m_s2: step.up_b() * g_m_s2, w2: w * w.transpose() - Matrix3::identity() * w.norm_squared() }
    }
}

fn triad_pair(a: &TriadAngles, row: usize) -> [f64; 2] {
    match row {
        0 => [a.xy_rad, a.xz_rad],
        1 => [a.yx_rad, a.yz_rad],
        _ => [a.zx_rad, a.zy_rad],
    }
}
