//! The true motion along a run's navigation, computed once per run and shared by every trial and
//! every compensation: the rigid-body motion (specific-force terms, rate, gravity in body axes) at
//! the three distinct times of each step, and the true state at the start and at each horizon. A
//! trial then only applies its own error parameters to it.

use nalgebra::Vector3;

use super::plan::Plan;
use super::trajectory::{Trajectory, TruthState};
use crate::motion::RigidMotion;

#[derive(Debug, Clone)]
pub struct MotionGrid {
    pub plan: Plan,
    /// Per step, the motion at its start, midpoint and end, each by the formulas of the segment
    /// that holds the midpoint (as `Trajectory::truth_in_segment_of`).
    pub motions: Vec<[RigidMotion; 3]>,
    pub initial: TruthState,
    /// The true state at each of `plan.records`' horizons.
    pub record_truths: Vec<TruthState>,
}

impl MotionGrid {
    pub fn new(trajectory: &Trajectory, gravity_i_m_s2: &Vector3<f64>, step_s: f64, horizons_s: &[f64]) -> Self {
        let plan = Plan::new(trajectory, step_s, horizons_s);
        let motions = plan
            .steps
            .iter()
            .map(|st| {
                let mid_s = st.t_s + 0.5 * st.h_s;
                st.stage_times_s().map(|t| trajectory.truth_in_segment_of(t, mid_s).motion(gravity_i_m_s2))
            })
            .collect();
        let record_truths = plan.records.iter().map(|&(_, h)| trajectory.truth(h)).collect();
        Self { plan, motions, initial: trajectory.truth(0.0), record_truths }
    }
}
