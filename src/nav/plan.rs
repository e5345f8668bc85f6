//! The integration steps of a navigation, fixed before it starts: they depend on the trajectory's
//! breakpoints, the step and the horizons, never on the state, so every trial of a run and every
//! compensation of a trial takes the same steps.

use super::trajectory::Trajectory;

/// One RK4 step from `t_s` over `h_s`; the state then stands at `next_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlanStep {
    pub t_s: f64,
    pub h_s: f64,
    pub next_s: f64,
}

impl PlanStep {
    /// The three distinct times of the step's stages: start, midpoint (stages 2 and 3), end.
    pub fn stage_times_s(&self) -> [f64; 3] {
        [self.t_s, self.t_s + 0.5 * self.h_s, self.t_s + self.h_s]
    }
}

/// Steps of fixed length `step_s`, shortened to land exactly on each horizon and each breakpoint.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    pub steps: Vec<PlanStep>,
    /// `(steps taken, horizon_s)`: the drift at each horizon, ascending, is recorded once that
    /// many steps are done.
    pub records: Vec<(usize, f64)>,
}

impl Plan {
    pub fn new(trajectory: &Trajectory, step_s: f64, horizons_s: &[f64]) -> Self {
        assert!(step_s > 0.0, "step must be positive");
        let mut stops: Vec<(f64, bool)> = horizons_s.iter().map(|&h| (h, true)).collect();
        let last_s = horizons_s.iter().copied().fold(0.0, f64::max);
        stops.extend(trajectory.breakpoints_s().into_iter().filter(|&b| b < last_s).map(|b| (b, false)));
        stops.sort_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)));
        let mut steps = Vec::new();
        let mut records = Vec::new();
        let mut t_s = 0.0;
        for &(horizon, record) in &stops {
            loop {
                let remaining = horizon - t_s;
                if remaining <= 1e-9 * step_s {
                    t_s = horizon;
                    break;
                }
                // A full step unless the stop falls within it (or just past it).
                let h_s = if remaining < step_s * (1.0 + 1e-9) { remaining } else { step_s };
                let next_s = if h_s == step_s { t_s + h_s } else { horizon };
                steps.push(PlanStep { t_s, h_s, next_s });
                t_s = next_s;
            }
            if record {
                records.push((steps.len(), horizon));
            }
        }
        Self { steps, records }
    }
}
