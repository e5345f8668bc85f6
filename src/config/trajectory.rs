//! The `[trajectory]` and `[navigation]` sections.
//!
//! ```toml
//! [trajectory]
//! kind = "paper_manoeuvre"          # or "rest", or "segments"
//! initial_attitude_rpy_deg = [0, 0, 0]   # rest and segments
//! initial_omega_rad_s = [0, 0, 0]        # segments
//! initial_velocity_m_s = [0, 0, 0]       # segments
//! [[trajectory.segment]]                 # segments: piecewise-constant accelerations
//! duration_s = 5.0
//! angular_accel_rad_s2 = [0.0, 0.0, 0.1]  # body axes
//! linear_accel_m_s2 = [1.0, 0.0, 0.0]     # inertial axes (r'')
//!
//! [navigation]
//! step_s = 0.001
//! horizons_s = [1, 2, 5, 10]
//! gravity_m_s2 = 9.80665
//! ```

use nalgebra::{UnitQuaternion, Vector3};
use serde::Deserialize;

use super::{Bad, positive, vec3};
use crate::nav::trajectory::{InitialState, Segment, Trajectory};
use crate::units::{RAD_PER_DEG, STANDARD_GRAVITY_M_S2};

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrajectoryKind {
    PaperManoeuvre,
    Rest,
    Segments,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrajectorySection {
    pub kind: TrajectoryKind,
    pub initial_attitude_rpy_deg: Option<[f64; 3]>,
    pub initial_omega_rad_s: Option<[f64; 3]>,
    pub initial_velocity_m_s: Option<[f64; 3]>,
    #[serde(default)]
    pub segment: Vec<SegmentEntry>,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentEntry {
    pub duration_s: f64,
    #[serde(default)]
    pub angular_accel_rad_s2: [f64; 3],
    #[serde(default)]
    pub linear_accel_m_s2: [f64; 3],
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavigationSection {
    pub step_s: f64,
    pub horizons_s: Vec<f64>,
    pub gravity_m_s2: Option<f64>,
}

/// Navigation settings in SI.
#[derive(Debug, Clone, PartialEq)]
pub struct NavigationSettings {
    pub step_s: f64,
    /// Ascending, positive, distinct.
    pub horizons_s: Vec<f64>,
    pub gravity_m_s2: f64,
}

/// The most integration steps one navigation may take (about 400 s of one core at the measured
/// 0.4 us a step): a config that needs more cannot finish a sweep and is refused.
pub const MAX_NAVIGATION_STEPS: f64 = 1e9;

/// Checks that navigating with `step_s` to the largest of `horizons_s` (ascending) means what it
/// says and can finish: the step must not exceed every horizon (every step would then be cut to
/// land on a horizon), and the number of steps must stay within [`MAX_NAVIGATION_STEPS`].
pub fn check_navigation_work(step_s: f64, horizons_s: &[f64]) -> Result<(), Bad> {
    let last = horizons_s.last().copied().unwrap_or(0.0);
    if step_s > last {
        return Err(Bad::new(
            "navigation.step_s",
            format!(
                "{step_s} s is longer than every horizon (the longest is {last} s): no step of that length is taken"
            ),
        ));
    }
    let steps = last / step_s;
    if steps > MAX_NAVIGATION_STEPS {
        return Err(Bad::new(
            "navigation.horizons_s",
            format!(
                "navigating {last} s in steps of {step_s} s takes {steps:.3e} steps per navigation (at about 0.4 us a \
                 step, {:.1e} s): more than the {MAX_NAVIGATION_STEPS:.0e} a run can finish",
                steps * 0.4e-6
            ),
        ));
    }
    Ok(())
}

impl NavigationSection {
    pub fn resolve(&self) -> Result<NavigationSettings, Bad> {
        let step_s = positive("navigation.step_s", self.step_s)?;
        if self.horizons_s.is_empty() {
            return Err(Bad::new("navigation.horizons_s", "needs at least one horizon"));
        }
        let mut horizons_s = Vec::new();
        for (k, h) in self.horizons_s.iter().enumerate() {
            horizons_s.push(positive(&format!("navigation.horizons_s[{k}]"), *h)?);
        }
        horizons_s.sort_by(f64::total_cmp);
        horizons_s.dedup();
        check_navigation_work(step_s, &horizons_s)?;
        let gravity_m_s2 = positive("navigation.gravity_m_s2", self.gravity_m_s2.unwrap_or(STANDARD_GRAVITY_M_S2))?;
        Ok(NavigationSettings { step_s, horizons_s, gravity_m_s2 })
    }
}

impl TrajectorySection {
    /// Builds the trajectory long enough for `horizon_s`.
    pub fn build(&self, horizon_s: f64) -> Result<Trajectory, Bad> {
        let rpy = vec3("trajectory.initial_attitude_rpy_deg", self.initial_attitude_rpy_deg.unwrap_or([0.0; 3]))?
            * RAD_PER_DEG;
        let q_b_i = UnitQuaternion::from_euler_angles(rpy[0], rpy[1], rpy[2]);
        let omega = vec3("trajectory.initial_omega_rad_s", self.initial_omega_rad_s.unwrap_or([0.0; 3]))?;
        let velocity = vec3("trajectory.initial_velocity_m_s", self.initial_velocity_m_s.unwrap_or([0.0; 3]))?;
        let only_segments = |key: &str, given: bool| {
            if given && self.kind != TrajectoryKind::Segments {
                Err(Bad::new(format!("trajectory.{key}"), "applies to kind = \"segments\" only"))
            } else {
                Ok(())
            }
        };
        only_segments("initial_omega_rad_s", self.initial_omega_rad_s.is_some())?;
        only_segments("initial_velocity_m_s", self.initial_velocity_m_s.is_some())?;
        only_segments("segment", !self.segment.is_empty())?;
        match self.kind {
            TrajectoryKind::PaperManoeuvre => {
                if self.initial_attitude_rpy_deg.is_some() {
                    return Err(Bad::new(
                        "trajectory.initial_attitude_rpy_deg",
                        "the paper's manoeuvre starts level (all initial conditions zero)",
                    ));
                }
                Ok(Trajectory::paper_manoeuvre(horizon_s))
            }
            TrajectoryKind::Rest => Ok(Trajectory::rest(horizon_s, q_b_i)),
            TrajectoryKind::Segments => {
                if self.segment.is_empty() {
                    return Err(Bad::new(
                        "trajectory.segment",
                        "kind = \"segments\" needs at least one [[trajectory.segment]]",
                    ));
                }
                let mut segments = Vec::new();
                for (k, s) in self.segment.iter().enumerate() {
                    let key = |name: &str| format!("trajectory.segment[{k}].{name}");
                    segments.push(Segment {
                        duration_s: positive(&key("duration_s"), s.duration_s)?,
                        alpha_b_rad_s2: vec3(&key("angular_accel_rad_s2"), s.angular_accel_rad_s2)?,
                        accel_i_m_s2: vec3(&key("linear_accel_m_s2"), s.linear_accel_m_s2)?,
                    });
                }
                let total_s: f64 = segments.iter().map(|s| s.duration_s).sum();
                if horizon_s > total_s * (1.0 + 1e-12) {
                    return Err(Bad::new(
                        "navigation.horizons_s",
                        format!("the last horizon ({horizon_s} s) is past the end of the segments ({total_s} s)"),
                    ));
                }
                let initial = InitialState { q_b_i, omega_b_rad_s: omega, v_i_m_s: velocity, r_i_m: Vector3::zeros() };
                Ok(Trajectory::new(initial, &segments))
            }
        }
    }
}
