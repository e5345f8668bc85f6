//! Calibration: test schedules, simulated measurements, estimators, identifiability and
//! schedule design (Hung & Lee 2006, Sections 3-5).
//!
//! A schedule is a list of steps: static poses (an `up` direction in body axes) and constant-rate
//! spins on a rate table (a body axis held vertical, one end up). In every step the specific force
//! at each accelerometer is constant in body axes: `f(r) = g up + W r`, `W = [omega x]^2`, so a
//! step is summarised by the mean and the within-step scatter of each output.
//!
//! The outputs of accelerometer j depend only on its own parameters `(k, b, m1, m2, dx, dy, dz)`
//! (`m` the two misalignment angles of the chosen form), so the Fisher information of a schedule
//! is block-diagonal by accelerometer. A spin about the unit axis `n` senses a location error only
//! through `a . W dr = -w^2 a . (dr - (dr . n) n)`: never along the spin axis.

pub mod design;
pub mod estimate;
pub mod fisher;
pub mod joint;
pub mod joint_pose;
pub mod measure;
pub mod paper;
pub mod paper_model;
pub mod params;
pub mod pose;
pub mod reproduce;
pub mod schedule;

pub use estimate::{Estimate, FitStatus};
pub use measure::{Measurements, StepStats};
pub use params::{Form, Layout, ParamKind};
pub use pose::PoseError;
pub use schedule::{Schedule, ScheduleError, Step, StepKind};
