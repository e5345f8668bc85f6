//! Navigation with an accelerometer array (Hung & Lee 2006, eq. 1-4) and its drift against truth.
//!
//! States: attitude `q_b_i` (body to inertial), body rate `omega_b`, inertial velocity `v_i` and
//! position `r_i`. `dq/dt = q (0, omega_b) / 2`, `d omega_b/dt = alpha_b`, `dv_i/dt = C_b^i a_o`,
//! `dr_i/dt = v_i`, with `(alpha_b, a_o)` solved from the outputs through the compensation
//! parameters and the *navigated* rate and attitude (gravity in body axes). A constant error
//! therefore grows as t in rate, t^2 in attitude, t^3 in velocity and t^4 in position.

pub mod drift;
pub mod grid;
pub mod lanes;
pub mod navigator;
pub mod plan;
pub mod source;
pub mod state;
pub mod study;
pub mod trajectory;

pub use drift::DriftSample;
pub use grid::MotionGrid;
pub use lanes::LANES;
pub use navigator::{NavGroup, Route, navigate, navigate_groups, navigate_together};
pub use plan::{Plan, PlanStep};
pub use source::{OutputSource, SimulatedArray};
pub use state::NavState;
pub use study::{DriftRow, DriftSetup, drift_study};
pub use trajectory::{InitialState, Segment, Trajectory, TruthState};
