//! Calibration schedules: static poses and constant-rate spins.

use nalgebra::Vector3;

use crate::array::Array;
use crate::motion::RigidMotion;

/// What the array does during a step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum StepKind {
    /// At rest with the unit vector `up_b` (body axes) pointing up.
    Static { up_b: Vector3<f64> },
    /// Spinning at `rate_rad_s` about the unit body axis `axis_b`, held vertical on a rate table;
    /// `positive_end_up` says whether `+axis_b` or `-axis_b` points up.
    Spin { axis_b: Vector3<f64>, rate_rad_s: f64, positive_end_up: bool },
}

/// One step of a schedule.
#[derive(Debug, Clone, PartialEq)]
pub struct Step {
    pub name: String,
    pub kind: StepKind,
    pub duration_s: f64,
    pub sample_rate_hz: f64,
}

impl Step {
    pub fn static_pose(name: impl Into<String>, up_b: Vector3<f64>, duration_s: f64, sample_rate_hz: f64) -> Self {
        Self { name: name.into(), kind: StepKind::Static { up_b }, duration_s, sample_rate_hz }
    }

    pub fn spin(
        name: impl Into<String>,
        axis_b: Vector3<f64>,
        rate_rad_s: f64,
        positive_end_up: bool,
        duration_s: f64,
        sample_rate_hz: f64,
    ) -> Self {
        Self {
            name: name.into(),
            kind: StepKind::Spin { axis_b, rate_rad_s, positive_end_up },
            duration_s,
            sample_rate_hz,
        }
    }

    /// Number of samples: `round(duration * rate)`, at least 1.
    pub fn samples(&self) -> usize {
        ((self.duration_s * self.sample_rate_hz).round() as usize).max(1)
    }

    /// The time the step's samples span, `samples / sample_rate_hz` (s): what the variance of a
    /// step mean of white noise given as a density goes with.
    pub fn sampled_duration_s(&self) -> f64 {
        self.samples() as f64 / self.sample_rate_hz
    }

    /// The unit up direction in body axes.
    pub fn up_b(&self) -> Vector3<f64> {
        match self.kind {
            StepKind::Static { up_b } => up_b,
            StepKind::Spin { axis_b, positive_end_up, .. } => {
                if positive_end_up {
                    axis_b
                } else {
                    -axis_b
                }
            }
        }
    }

    /// Body rate, rad/s.
    pub fn omega_b_rad_s(&self) -> Vector3<f64> {
        match self.kind {
            StepKind::Static { .. } => Vector3::zeros(),
            StepKind::Spin { axis_b, rate_rad_s, .. } => axis_b * rate_rad_s,
        }
    }

    pub fn is_spin(&self) -> bool {
        matches!(self.kind, StepKind::Spin { .. })
    }

    /// The (constant) motion of the step with gravity `g_m_s2`.
    pub fn motion(&self, g_m_s2: f64) -> RigidMotion {
        RigidMotion::spinning(&self.omega_b_rad_s(), &self.up_b(), g_m_s2)
    }
}

/// A schedule that cannot be run.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[non_exhaustive]
pub enum ScheduleError {
    #[error("the schedule has no steps")]
    Empty,
    #[error("step {step} (`{name}`): {problem}")]
    BadStep { step: usize, name: String, problem: String },
}

/// An ordered list of steps.
#[derive(Debug, Clone, PartialEq)]
pub struct Schedule {
    pub name: String,
    steps: Vec<Step>,
}

impl Schedule {
    /// Checks the steps: directions are normalised (a zero or non-finite one is refused), spins need
    /// a non-zero finite rate, durations and sample rates must be positive.
    pub fn new(name: impl Into<String>, steps: Vec<Step>) -> Result<Self, ScheduleError> {
        if steps.is_empty() {
            return Err(ScheduleError::Empty);
        }
        let mut checked = Vec::with_capacity(steps.len());
        for (i, mut s) in steps.into_iter().enumerate() {
            let bad = |problem: String| ScheduleError::BadStep { step: i + 1, name: s.name.clone(), problem };
            if !(s.duration_s.is_finite() && s.duration_s > 0.0) {
                return Err(bad(format!("duration must be positive, got {} s", s.duration_s)));
            }
            if !(s.sample_rate_hz.is_finite() && s.sample_rate_hz > 0.0) {
                return Err(bad(format!("sample rate must be positive, got {} Hz", s.sample_rate_hz)));
            }
            let direction = |v: &Vector3<f64>, what: &str| -> Result<Vector3<f64>, ScheduleError> {
                let n = v.norm();
                if !n.is_finite() || n < 1e-9 {
                    Err(bad(format!("{what} [{}, {}, {}] is not a direction", v.x, v.y, v.z)))
                } else {
                    Ok(v / n)
                }
            };
            s.kind = match s.kind {
                StepKind::Static { up_b } => StepKind::Static { up_b: direction(&up_b, "up")? },
                StepKind::Spin { axis_b, rate_rad_s, positive_end_up } => {
                    if !rate_rad_s.is_finite() || rate_rad_s == 0.0 {
                        return Err(bad(format!("a spin needs a non-zero rate, got {rate_rad_s} rad/s")));
                    }
                    StepKind::Spin { axis_b: direction(&axis_b, "spin axis")?, rate_rad_s, positive_end_up }
                }
            };
            checked.push(s);
        }
        Ok(Self { name: name.into(), steps: checked })
    }

    pub fn steps(&self) -> &[Step] {
        &self.steps
    }

    pub fn len(&self) -> usize {
        self.steps.len()
    }

    pub fn is_empty(&self) -> bool {
        self.steps.is_empty()
    }

    /// The schedule with more steps appended.
    pub fn extended(&self, name: impl Into<String>, more: &[Step]) -> Result<Self, ScheduleError> {
        let mut steps = self.steps.clone();
        steps.extend_from_slice(more);
        Self::new(name, steps)
    }

    /// Hung & Lee (2006): the six static poses of Table 3 (triad B: up = +-theta_5, +-theta_2,
    /// +-theta_3), the six of Table 4 (triad A: +-theta_4, +-theta_1, +-theta_6), then spins about
    /// body x, y and z with that axis pointing down (Table 5), all at `spin_rate_rad_s`.
    pub fn hung_lee_2006(
        array: &Array,
        spin_rate_rad_s: f64,
        duration_s: f64,
        sample_rate_hz: f64,
    ) -> Result<Self, ScheduleError> {
        let mut steps = Vec::new();
        // Triad B first (Table 3), then triad A (Table 4), each in the tables' order.
        let order: [(usize, &str); 6] = [(4, "B"), (1, "B"), (2, "B"), (3, "A"), (0, "A"), (5, "A")];
        for (j, triad) in order {
            let axis = array.accelerometers().get(j).map(|a| a.axis).unwrap_or_else(Vector3::z);
            for (sign, s) in [(1.0, "+"), (-1.0, "-")] {
                steps.push(Step::static_pose(
                    format!("static {triad}{s}theta{}", j + 1),
                    axis * sign,
                    duration_s,
                    sample_rate_hz,
                ));
            }
        }
        for (k, name) in ["x", "y", "z"].iter().enumerate() {
            steps.push(Step::spin(
                format!("spin about {name}, {name} axis pointing down"),
                Vector3::ith(k, 1.0),
                spin_rate_rad_s,
                false,
                duration_s,
                sample_rate_hz,
            ));
        }
        Self::new("hung_lee_2006", steps)
    }
}

/// The paper's schedule augmented by `gfcal design configs/hung_lee_2006_design.toml` (Table 6-7
/// errors, 50 ug/sqrt(Hz), 1 s steps at 100 Hz, targets 0.1 mm, 0.01 deg, 50 ug, 100 ppm): two
/// spins about face diagonals, which see every location component of every accelerometer through
/// its large axis components. The rates scale with `spin_rate_rad_s` (the design picked 2x and 1x
/// the paper's 2 pi rad/s).
pub fn hung_lee_2006_augmented(
    array: &Array,
    spin_rate_rad_s: f64,
    duration_s: f64,
    sample_rate_hz: f64,
) -> Result<Schedule, ScheduleError> {
    let base = Schedule::hung_lee_2006(array, spin_rate_rad_s, duration_s, sample_rate_hz)?;
    let added: Vec<Step> = AUGMENTED_SPINS
        .iter()
        .map(|(axis, multiple, positive_end_up)| {
            let a = Vector3::from(*axis).normalize();
            let rate = spin_rate_rad_s * multiple;
            Step::spin(
                format!(
                    "spin about [{:.4}, {:.4}, {:.4}] at {rate:.4} rad/s, {} end up",
                    a.x,
                    a.y,
                    a.z,
                    if *positive_end_up { "+" } else { "-" }
                ),
                a,
                rate,
                *positive_end_up,
                duration_s,
                sample_rate_hz,
            )
        })
        .collect();
    base.extended("hung_lee_2006_augmented", &added)
}

/// Spins added to the paper's schedule: (axis, rate in multiples of the paper's rate, + end up).
pub const AUGMENTED_SPINS: &[([f64; 3], f64, bool)] = &[([0.0, 1.0, 1.0], 2.0, true), ([1.0, -1.0, 0.0], 1.0, true)];
