//! The `[schedule]` section: a preset or explicit steps.
//!
//! ```toml
//! [schedule]
//! preset = "hung_lee_2006"          # or "hung_lee_2006_augmented"; or give [[schedule.step]]
//! spin_rate_rad_s = 6.283185307179586
//! step_duration_s = 1.0
//! sample_rate_hz = 100.0
//!
//! [[schedule.step]]                 # instead of a preset
//! kind = "static"                   # or "spin"
//! up = [0.0, 0.0, 1.0]              # static: up direction, body axes (normalised)
//! axis = [1.0, 0.0, 0.0]            # spin: body axis held vertical (normalised)
//! rate_rad_s = 6.283185307179586    # spin
//! up_end = "negative"               # spin: which end of the axis points up
//! duration_s = 1.0                  # default: step_duration_s
//! sample_rate_hz = 100.0            # default: sample_rate_hz
//! ```

use nalgebra::Vector3;
use serde::Deserialize;

use super::{Bad, positive, vec3};
use crate::array::Array;
use crate::calib::schedule::{Schedule, Step};

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScheduleSection {
    pub preset: Option<String>,
    pub spin_rate_rad_s: Option<f64>,
    pub step_duration_s: Option<f64>,
    pub sample_rate_hz: Option<f64>,
    #[serde(default)]
    pub step: Vec<StepEntry>,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum StepKindEntry {
    Static,
    Spin,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UpEnd {
    Positive,
    Negative,
}

#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StepEntry {
    pub kind: StepKindEntry,
    pub name: Option<String>,
    pub up: Option<[f64; 3]>,
    pub axis: Option<[f64; 3]>,
    pub rate_rad_s: Option<f64>,
    pub up_end: Option<UpEnd>,
    pub duration_s: Option<f64>,
    pub sample_rate_hz: Option<f64>,
}

/// Names of the presets.
pub const PRESETS: [&str; 2] = ["hung_lee_2006", "hung_lee_2006_augmented"];

impl ScheduleSection {
    pub fn build(&self, array: &Array) -> Result<Schedule, Bad> {
        let duration_s = positive("schedule.step_duration_s", self.step_duration_s.unwrap_or(1.0))?;
        let rate_hz = positive("schedule.sample_rate_hz", self.sample_rate_hz.unwrap_or(100.0))?;
        let spin_rate = self.spin_rate_rad_s.unwrap_or(2.0 * std::f64::consts::PI);
        if !spin_rate.is_finite() || spin_rate == 0.0 {
            return Err(Bad::new("schedule.spin_rate_rad_s", format!("a spin needs a non-zero rate, got {spin_rate}")));
        }
        match (&self.preset, self.step.is_empty()) {
            (Some(_), false) => Err(Bad::new("schedule", "give either `preset` or [[schedule.step]], not both")),
            (None, true) => Err(Bad::new("schedule", "the schedule has no steps: give `preset` or [[schedule.step]]")),
            (Some(p), true) => {
                if duration_s * rate_hz < 1.0 {
                    return Err(Bad::new(
                        "schedule.step_duration_s",
                        format!(
                            "{duration_s} s at {rate_hz} Hz is less than one sample (it would be raised to one, silently)"
                        ),
                    ));
                }
                let base = Schedule::hung_lee_2006(array, spin_rate, duration_s, rate_hz)
                    .map_err(|e| Bad::new("schedule", e.to_string()))?;
                match p.as_str() {
                    "hung_lee_2006" => Ok(base),
                    "hung_lee_2006_augmented" => {
                        crate::calib::schedule::hung_lee_2006_augmented(array, spin_rate, duration_s, rate_hz)
                            .map_err(|e| Bad::new("schedule", e.to_string()))
                    }
                    other => Err(Bad::new(
                        "schedule.preset",
                        format!("unknown preset `{other}` (known: {})", PRESETS.join(", ")),
                    )),
                }
            }
            (None, false) => {
                let mut steps = Vec::new();
                for (i, e) in self.step.iter().enumerate() {
                    let key = |k: &str| format!("schedule.step[{i}].{k}");
                    let d = positive(&key("duration_s"), e.duration_s.unwrap_or(duration_s))?;
                    let f = positive(&key("sample_rate_hz"), e.sample_rate_hz.unwrap_or(rate_hz))?;
                    if d * f < 1.0 {
                        return Err(Bad::new(
                            key("duration_s"),
                            format!("{d} s at {f} Hz is less than one sample (it would be raised to one, silently)"),
                        ));
                    }
                    let dir = |name: &str, v: Option<[f64; 3]>| -> Result<Vector3<f64>, Bad> {
                        let v = vec3(
                            &key(name),
                            v.ok_or_else(|| Bad::new(key(name), "is required for this kind of step"))?,
                        )?;
                        if v.norm() < 1e-9 {
                            return Err(Bad::new(key(name), "is not a direction (zero length)"));
                        }
                        Ok(v.normalize())
                    };
                    let name = e.name.clone().unwrap_or_else(|| format!("step {}", i + 1));
                    steps.push(match e.kind {
                        StepKindEntry::Static => {
                            for (k, given) in [
                                ("axis", e.axis.is_some()),
                                ("rate_rad_s", e.rate_rad_s.is_some()),
                                ("up_end", e.up_end.is_some()),
                            ] {
                                if given {
                                    return Err(Bad::new(key(k), "applies to spins only"));
                                }
                            }
                            Step::static_pose(name, dir("up", e.up)?, d, f)
                        }
                        StepKindEntry::Spin => {
                            if e.up.is_some() {
                                return Err(Bad::new(
                                    key("up"),
                                    "a spin's up direction is its axis: use `axis` and `up_end`",
                                ));
                            }
                            let rate = e.rate_rad_s.unwrap_or(spin_rate);
                            if !rate.is_finite() || rate == 0.0 {
                                return Err(Bad::new(
                                    key("rate_rad_s"),
                                    format!("a spin needs a non-zero rate, got {rate}"),
                                ));
                            }
                            let up_end = e.up_end.ok_or_else(|| {
                                Bad::new(key("up_end"), "is required for a spin (\"positive\" or \"negative\")")
                            })?;
                            Step::spin(name, dir("axis", e.axis)?, rate, up_end == UpEnd::Positive, d, f)
                        }
                    });
                }
                Schedule::new("custom", steps).map_err(|e| Bad::new("schedule.step", e.to_string()))
            }
        }
    }
}

/// `schedule` as a `[schedule]` section of explicit `[[schedule.step]]` entries, which
/// [`ScheduleSection::build`] reads back to the same steps (directions to the last bit: `{:?}`
/// prints the shortest round-trip form, and unit vectors normalise to themselves).
pub fn schedule_toml(schedule: &Schedule) -> String {
    use crate::calib::schedule::StepKind;
    let v = |x: &Vector3<f64>| format!("[{:?}, {:?}, {:?}]", x.x, x.y, x.z);
    let mut out = format!("# schedule `{}`, {} steps\n[schedule]\n", schedule.name, schedule.len());
    for step in schedule.steps() {
        out.push_str("\n[[schedule.step]]\n");
        out.push_str(&format!("name = {:?}\n", step.name));
        match &step.kind {
            StepKind::Static { up_b } => {
                out.push_str(&format!("kind = \"static\"\nup = {}\n", v(up_b)));
            }
            StepKind::Spin { axis_b, rate_rad_s, positive_end_up } => {
                out.push_str(&format!(
                    "kind = \"spin\"\naxis = {}\nrate_rad_s = {:?}\nup_end = \"{}\"\n",
                    v(axis_b),
                    rate_rad_s,
                    if *positive_end_up { "positive" } else { "negative" }
                ));
            }
        }
        out.push_str(&format!("duration_s = {:?}\nsample_rate_hz = {:?}\n", step.duration_s, step.sample_rate_hz));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The augmented preset written as explicit steps reads back to the same steps.
    #[test]
    fn a_schedule_written_as_steps_reads_back_to_itself() {
        let cube = Array::cube(0.1).expect("cube");
        let s = crate::calib::schedule::hung_lee_2006_augmented(&cube, 5.0, 0.7, 200.0).expect("preset");
        let text = schedule_toml(&s);
        #[derive(Deserialize)]
        struct File {
            schedule: ScheduleSection,
        }
        let file: File = toml::from_str(&text).expect("parses");
        let back = file.schedule.build(&cube).expect("builds");
        assert_eq!(back.steps(), s.steps());
    }
}
