//! The effects tried on real recordings beyond the baseline model of `selfcal::model`, each as
//! the derivatives of an output by the effect's parameters at zero (its regressor), evaluated on
//! the fitted state of a recording (`recorded_blocks`). Input-referred: an effect adds `e_j` to
//! `s_j = k_j (b_j + u_j + e_j)`, with `u_j = a_j . q_j` the accelerometer's reading of the
//! specific force `q_j` at its sensing point.
//!
//! | effect | term `e_j` | parameters | unit | what can see it |
//! | --- | --- | --- | --- | --- |
//! | `bias_time_drift` | `c_j (t - t_mid)` | one per accelerometer, per recording | m/s^2/s | both phases (time) |
//! | `scale_factor_quadratic` | `c_j u_j^2` | one per accelerometer | 1/(m/s^2) | readings beyond 1 g: the rotation phase |
//! | `scale_factor_cubic` | `c_j u_j^3` | one per accelerometer | 1/(m/s^2)^2 | the rotation phase |
//! | `cross_axis` | `c1_j (e1_j . q) + c2_j (e2_j . q)` | two per accelerometer | 1 | nothing: exactly a tilt (rank test: every direction unseen) |
//! | `cross_coupling` | `u_j (c1_j (e1_j . q) + c2_j (e2_j . q))` | two per accelerometer | 1/(m/s^2) | the rotation phase |
//! | `sampling_delay` | `-tau_m du_j/dt`, accelerometer j in package m | one per package (IMU) | s | differences between packages; a delay common to all is a rigid motion at another time, absorbed by the motion (one direction unseen) |
//! | `gyro_scale_misalignment` | the rate is `(I + G) w_ref` | nine, shared (`--use-gyro` only) | 1 | the symmetric part less the common scale (5 of 9): the antisymmetric part is a rotation of the accelerometers (tilts), the common scale a size of the array (locations) |
//!
//! `e1_j, e2_j` are the tilt basis of the nominal axis (`sensor::misalignment::tilt_basis`). A
//! first-order anti-alias filter of time constant `tau` delays a signal by `tau` to first order in
//! `omega tau`: the filter lag of one package is the same column as its sampling delay, and the
//! two are told apart only by their frequency dependence, which 62.5 Hz samples of hand motion do
//! not resolve. The sensing point of each axis inside a package (three locations per triad) is in
//! the baseline already: every accelerometer has its own location error; `recorded` tests whether
//! the three of a package differ. Saturation: clipped outputs are censored (left out of the
//! dynamic phase; `selfcal::calibrate::prepare_dynamic`), not fitted as data.

use nalgebra::Vector3;

use crate::array::Array;
use crate::sensor::misalignment::tilt_basis;

/// An effect tried on recordings (see the module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RecordedEffect {
    BiasTimeDrift,
    ScaleFactorQuadratic,
    ScaleFactorCubic,
    CrossAxis,
    CrossCoupling,
    SamplingDelay,
    GyroScaleMisalignment,
}

/// Who a parameter belongs to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Owner {
    Accelerometer(usize),
    /// The accelerometers of one package (0-based package index).
    Package(usize),
    Shared,
}

impl RecordedEffect {
    /// Every effect, in the order they are tried.
    pub const ALL: [RecordedEffect; 7] = [
        RecordedEffect::BiasTimeDrift,
        RecordedEffect::ScaleFactorQuadratic,
        RecordedEffect::ScaleFactorCubic,
        RecordedEffect::CrossCoupling,
        RecordedEffect::SamplingDelay,
        RecordedEffect::CrossAxis,
        RecordedEffect::GyroScaleMisalignment,
    ];

    pub fn name(&self) -> &'static str {
        match self {
            Self::BiasTimeDrift => "bias_time_drift",
            Self::ScaleFactorQuadratic => "scale_factor_quadratic",
            Self::ScaleFactorCubic => "scale_factor_cubic",
            Self::CrossAxis => "cross_axis",
            Self::CrossCoupling => "cross_coupling",
            Self::SamplingDelay => "sampling_delay",
            Self::GyroScaleMisalignment => "gyro_scale_misalignment",
        }
    }

    pub fn unit(&self) -> &'static str {
        match self {
            Self::BiasTimeDrift => "m/s^2/s",
            Self::ScaleFactorQuadratic | Self::CrossCoupling => "1/(m/s^2)",
            Self::ScaleFactorCubic => "1/(m/s^2)^2",
            Self::CrossAxis | Self::GyroScaleMisalignment => "1",
            Self::SamplingDelay => "s",
        }
    }

    /// Whether the parameters differ between recordings (refitted on a held-out recording)
    /// rather than carried over.
    pub fn per_recording(&self) -> bool {
        matches!(self, Self::BiasTimeDrift)
    }

    /// Whether it needs the reference rate (`--use-gyro`).
    pub fn needs_reference_rate(&self) -> bool {
        matches!(self, Self::GyroScaleMisalignment)
    }

    /// Number of parameters.
    pub fn parameters(&self, layout: &EffectLayout) -> usize {
        let n = layout.package_of.len();
        match self {
            Self::BiasTimeDrift | Self::ScaleFactorQuadratic | Self::ScaleFactorCubic => n,
            Self::CrossAxis | Self::CrossCoupling => 2 * n,
            Self::SamplingDelay => layout.packages.len(),
            Self::GyroScaleMisalignment => 9,
        }
    }

    /// The owner of parameter `c`.
    pub fn owner(&self, c: usize) -> Owner {
        match self {
            Self::BiasTimeDrift | Self::ScaleFactorQuadratic | Self::ScaleFactorCubic => Owner::Accelerometer(c),
            Self::CrossAxis | Self::CrossCoupling => Owner::Accelerometer(c / 2),
            Self::SamplingDelay => Owner::Package(c),
            Self::GyroScaleMisalignment => Owner::Shared,
        }
    }

    /// Parameters per owner (the group a test is made on).
    pub fn per_owner(&self) -> usize {
        match self {
            Self::CrossAxis | Self::CrossCoupling => 2,
            Self::GyroScaleMisalignment => 9,
            _ => 1,
        }
    }

    /// Parses a name of [`RecordedEffect::ALL`].
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|e| e.name() == name)
    }

    /// Adds the regressor of accelerometer `row.j`'s output to `out` (this effect's columns).
    pub fn regress(&self, row: &Row, layout: &EffectLayout, out: &mut [f64]) {
        let j = row.j;
        let u = row.axis.dot(&row.q_m_s2);
        let k = row.k;
        match self {
            Self::BiasTimeDrift => out[j] += k * row.t_from_mid_s,
            Self::ScaleFactorQuadratic => out[j] += k * u * u,
            Self::ScaleFactorCubic => out[j] += k * u * u * u,
            Self::CrossAxis | Self::CrossCoupling => {
                let (e1, e2) = tilt_basis(&row.nominal_axis);
                let f = if *self == Self::CrossCoupling { k * u } else { k };
                out[2 * j] += f * e1.dot(&row.q_m_s2);
                out[2 * j + 1] += f * e2.dot(&row.q_m_s2);
            }
            Self::SamplingDelay => out[layout.package_of[j]] -= k * row.axis.dot(&row.dq_dt_m_s3),
            Self::GyroScaleMisalignment => {
                if let (Some(d), Some(w)) = (row.d_omega, row.reference_rate_rad_s) {
                    for a in 0..3 {
                        for b in 0..3 {
                            out[3 * a + b] += d[a] * w[b];
                        }
                    }
                }
            }
        }
    }
}

/// Packages of an array: accelerometers with the same nominal position (the axes of one IMU).
#[derive(Debug, Clone, PartialEq)]
pub struct EffectLayout {
    pub packages: Vec<Vec<usize>>,
    pub package_of: Vec<usize>,
}

impl EffectLayout {
    pub fn new(array: &Array) -> Self {
        let mut packages: Vec<Vec<usize>> = Vec::new();
        let mut package_of = Vec::new();
        let acc = array.accelerometers();
        for (j, a) in acc.iter().enumerate() {
            let found = packages.iter().position(|p| (acc[p[0]].position_m - a.position_m).norm() < 1e-9);
            let m = found.unwrap_or_else(|| {
                packages.push(Vec::new());
                packages.len() - 1
            });
            packages[m].push(j);
            package_of.push(m);
        }
        Self { packages, package_of }
    }
}

/// What an effect sees of one output.
#[derive(Debug, Clone, Copy)]
pub struct Row {
    pub j: usize,
    pub k: f64,
    /// True (tilted) and nominal unit axes.
    pub axis: Vector3<f64>,
    pub nominal_axis: Vector3<f64>,
    /// Specific force at the sensing point and its time derivative (zero when still).
    pub q_m_s2: Vector3<f64>,
    pub dq_dt_m_s3: Vector3<f64>,
    /// Time from the recording's middle, s.
    pub t_from_mid_s: f64,
    /// Derivative of the output by the angular rate, and the reference rate (dynamic samples
    /// with `--use-gyro`).
    pub d_omega: Option<[f64; 3]>,
    pub reference_rate_rad_s: Option<Vector3<f64>>,
}
