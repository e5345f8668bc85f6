//! Reference trajectories: piecewise-constant angular acceleration (body axes) and linear
//! acceleration (inertial axes), from which the truth is known at any time.
//!
//! Within a segment `omega_b(tau) = omega_0 + alpha tau`. When `omega_0` and `alpha` are parallel
//! the rotation axis is fixed and the attitude is analytic (the paper's manoeuvre and rest are
//! such cases); otherwise it is integrated with the fourth-order Magnus method on a 1 ms grid of
//! knots plus one Magnus step from the last knot, so the truth is far more accurate than any
//! navigation step it is compared with. Velocity and position are analytic.

use nalgebra::{UnitQuaternion, Vector3};

use crate::motion::RigidMotion;

/// One piece of a trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment {
    pub duration_s: f64,
    /// Angular acceleration in body axes, rad/s^2.
    pub alpha_b_rad_s2: Vector3<f64>,
    /// Acceleration of the body origin in inertial axes (`r''`), m/s^2.
    pub accel_i_m_s2: Vector3<f64>,
}

/// State at the start of a trajectory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InitialState {
    pub q_b_i: UnitQuaternion<f64>,
    pub omega_b_rad_s: Vector3<f64>,
    pub v_i_m_s: Vector3<f64>,
    pub r_i_m: Vector3<f64>,
}

impl Default for InitialState {
    fn default() -> Self {
        Self {
            q_b_i: UnitQuaternion::identity(),
            omega_b_rad_s: Vector3::zeros(),
            v_i_m_s: Vector3::zeros(),
            r_i_m: Vector3::zeros(),
        }
    }
}

/// The true state at one time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthState {
    pub q_b_i: UnitQuaternion<f64>,
    pub omega_b_rad_s: Vector3<f64>,
    pub alpha_b_rad_s2: Vector3<f64>,
    pub accel_i_m_s2: Vector3<f64>,
    pub v_i_m_s: Vector3<f64>,
    pub r_i_m: Vector3<f64>,
}

impl TruthState {
    /// The rigid-body motion the array senses, with inertial gravity `gravity_i_m_s2`.
    pub fn motion(&self, gravity_i_m_s2: &Vector3<f64>) -> RigidMotion {
        RigidMotion::from_inertial(
            &self.q_b_i,
            &self.accel_i_m_s2,
            &self.omega_b_rad_s,
            &self.alpha_b_rad_s2,
            gravity_i_m_s2,
        )
    }
}

#[derive(Debug, Clone, PartialEq)]
enum Attitude {
    /// Rotation about a fixed unit axis by `w0 tau + a tau^2 / 2`.
    FixedAxis { axis: Vector3<f64>, w0_rad_s: f64, a_rad_s2: f64 },
    /// Magnus knots every `h_s` from the segment start.
    Knots { h_s: f64, knots: Vec<UnitQuaternion<f64>> },
}

#[derive(Debug, Clone, PartialEq)]
struct Piece {
    t0_s: f64,
    segment: Segment,
    start: InitialState,
    attitude: Attitude,
}

/// A reference trajectory built from segments.
#[derive(Debug, Clone, PartialEq)]
pub struct Trajectory {
    pieces: Vec<Piece>,
    duration_s: f64,
}

/// Spacing of the Magnus knots of a segment whose rotation axis moves.
const KNOT_SPACING_S: f64 = 1e-3;

impl Trajectory {
    /// Builds the trajectory; segments run one after another from `initial`. Past the last
    /// segment, the last one continues.
    pub fn new(initial: InitialState, segments: &[Segment]) -> Self {
        assert!(!segments.is_empty(), "a trajectory needs a segment");
        let mut pieces = Vec::with_capacity(segments.len());
        let mut start = initial;
        let mut t0_s = 0.0;
        for seg in segments {
            let attitude = attitude_model(&start, seg);
            let piece = Piece { t0_s, segment: *seg, start, attitude };
            let end = piece.state(seg.duration_s);
            start = InitialState {
                q_b_i: end.q_b_i,
                omega_b_rad_s: end.omega_b_rad_s,
                v_i_m_s: end.v_i_m_s,
                r_i_m: end.r_i_m,
            };
            t0_s += seg.duration_s;
            pieces.push(piece);
        }
        Self { pieces, duration_s: t0_s }
    }

    /// Hung & Lee (2006), Section 5: `r'' = (9.81, 0, 0)` m/s^2 (inertial), `omega' = (pi/4, 0, 0)`
    /// rad/s^2, all initial conditions zero.
    pub fn paper_manoeuvre(duration_s: f64) -> Self {
        Self::new(
            InitialState::default(),
            &[Segment {
                duration_s,
                alpha_b_rad_s2: Vector3::new(std::f64::consts::FRAC_PI_4, 0.0, 0.0),
                accel_i_m_s2: Vector3::new(9.81, 0.0, 0.0),
            }],
        )
    }

    /// At rest with the given attitude.
    pub fn rest(duration_s: f64, q_b_i: UnitQuaternion<f64>) -> Self {
        Self::new(
            InitialState { q_b_i, ..InitialState::default() },
            &[Segment { duration_s, alpha_b_rad_s2: Vector3::zeros(), accel_i_m_s2: Vector3::zeros() }],
        )
    }

    pub fn duration_s(&self) -> f64 {
        self.duration_s
    }

    /// The true state at `t_s` (clamped at 0). At a boundary between segments, the later one.
    pub fn truth(&self, t_s: f64) -> TruthState {
        self.truth_in_segment_of(t_s, t_s)
    }

    /// The true state at `t_s` by the formulas of the segment that holds `reference_s`: an
    /// integration step evaluates all its stages in the segment of its midpoint, so that the
    /// accelerations' jumps at boundaries fall between steps, not inside them.
    pub fn truth_in_segment_of(&self, t_s: f64, reference_s: f64) -> TruthState {
        let k = self.pieces.partition_point(|p| p.t0_s <= reference_s.max(0.0)).saturating_sub(1);
        let piece = &self.pieces[k];
        piece.state(t_s.max(0.0) - piece.t0_s)
    }

    /// Times where the accelerations may jump (the starts of segments after the first), s.
    pub fn breakpoints_s(&self) -> Vec<f64> {
        self.pieces.iter().skip(1).map(|p| p.t0_s).collect()
    }
}

impl Piece {
    fn state(&self, tau_s: f64) -> TruthState {
        let s = &self.start;
        let seg = &self.segment;
        let omega = s.omega_b_rad_s + seg.alpha_b_rad_s2 * tau_s;
        let q_b_i = match &self.attitude {
            Attitude::FixedAxis { axis, w0_rad_s, a_rad_s2 } => {
                let angle = w0_rad_s * tau_s + 0.5 * a_rad_s2 * tau_s * tau_s;
                s.q_b_i * UnitQuaternion::from_scaled_axis(axis * angle)
            }
            Attitude::Knots { h_s, knots } => {
                let k = ((tau_s / h_s).floor() as usize).min(knots.len() - 1);
                let tk = k as f64 * h_s;
                magnus_step(&knots[k], &s.omega_b_rad_s, &seg.alpha_b_rad_s2, tk, tau_s - tk)
            }
        };
        TruthState {
            q_b_i,
            omega_b_rad_s: omega,
            alpha_b_rad_s2: seg.alpha_b_rad_s2,
            accel_i_m_s2: seg.accel_i_m_s2,
            v_i_m_s: s.v_i_m_s + seg.accel_i_m_s2 * tau_s,
            r_i_m: s.r_i_m + s.v_i_m_s * tau_s + seg.accel_i_m_s2 * (0.5 * tau_s * tau_s),
        }
    }
}

fn attitude_model(start: &InitialState, seg: &Segment) -> Attitude {
    let w0 = start.omega_b_rad_s;
    let a = seg.alpha_b_rad_s2;
    let cross = w0.cross(&a).norm();
    if cross <= 1e-14 * w0.norm() * a.norm() {
        let axis = if a.norm() > 0.0 {
            a.normalize()
        } else if w0.norm() > 0.0 {
            w0.normalize()
        } else {
            Vector3::x()
        };
        return Attitude::FixedAxis { axis, w0_rad_s: w0.dot(&axis), a_rad_s2: a.dot(&axis) };
    }
    let count = (seg.duration_s / KNOT_SPACING_S).ceil().max(1.0) as usize;
    let h_s = seg.duration_s / count as f64;
    let mut knots = Vec::with_capacity(count + 1);
    let mut q = start.q_b_i;
    knots.push(q);
    for k in 0..count {
        q = magnus_step(&q, &w0, &a, k as f64 * h_s, h_s);
        knots.push(q);
    }
    Attitude::Knots { h_s, knots }
}

/// One fourth-order Magnus step of `dq/dt = q (0, omega) / 2` with `omega(tau) = w0 + a tau`, from
/// `tau0` over `h`: rotation vector `h (w1 + w2) / 2 + sqrt(3) h^2 (w1 x w2) / 12` at the Gauss
/// points (applied on the right, body frame).
pub fn magnus_step(
    q: &UnitQuaternion<f64>,
    w0: &Vector3<f64>,
    a: &Vector3<f64>,
    tau0: f64,
    h: f64,
) -> UnitQuaternion<f64> {
    if h == 0.0 {
        return *q;
    }
    let c = 3f64.sqrt() / 6.0;
    let w1 = w0 + a * (tau0 + (0.5 - c) * h);
    let w2 = w0 + a * (tau0 + (0.5 + c) * h);
    let rotvec = (w1 + w2) * (0.5 * h) + w1.cross(&w2) * (3f64.sqrt() / 12.0 * h * h);
    q * UnitQuaternion::from_scaled_axis(rotvec)
}
