//! Which command a config file is for (part of the `gfcal` binary): `gfcal check` validates any config without running it,
//! and a command given another command's config says whose it is instead of failing on its
//! first unexpected key.
//!
//! A file is *for* a command when that command's loader accepts it whole (every key known and
//! every value checked). When no loader accepts it, the file's top-level keys say which it was
//! meant for, and that loader's error is the one to show.

use std::path::Path;

use gfcal::config::ConfigError;

use super::error::InputError;

/// The kinds of config, by the commands that read them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ConfigKind {
    /// `gfcal run` (and `summarize`, `report`, `sensitivity` on its output).
    Run,
    /// `gfcal drift`.
    Drift,
    /// `gfcal identify` and `gfcal design`.
    Calibration,
    /// `gfcal simulate-log`.
    SimulateLog,
    /// An array file (`[array] file = ...`, `--array`).
    Array,
}

impl ConfigKind {
    pub const ALL: [ConfigKind; 5] =
        [ConfigKind::Run, ConfigKind::Drift, ConfigKind::Calibration, ConfigKind::SimulateLog, ConfigKind::Array];

    /// The commands that read this kind, as a user types them.
    pub fn commands(self) -> &'static str {
        match self {
            ConfigKind::Run => "gfcal run",
            ConfigKind::Drift => "gfcal drift",
            ConfigKind::Calibration => "gfcal identify / gfcal design",
            ConfigKind::SimulateLog => "gfcal simulate-log",
            ConfigKind::Array => "--array (an array file)",
        }
    }

    /// Loads `path` as this kind; a short description of what it holds.
    pub fn load(self, path: &Path) -> Result<String, ConfigError> {
        Ok(match self {
            ConfigKind::Run => {
                // Cell by cell, without holding the cells: bounded memory whatever the sweep.
                let c = gfcal::mc::McConfig::check(path)?;
                format!("{} cell(s) x {} trials in {} parts", c.cells, c.trials_per_cell, c.parts)
            }
            ConfigKind::Drift => {
                let c = gfcal::config::drift::DriftConfig::load(path)?;
                format!("{} accelerometers, horizons {:?} s", c.array.len(), c.navigation.horizons_s)
            }
            ConfigKind::Calibration => {
                let c = gfcal::config::calibration::CalibrationConfig::load(path)?;
                format!("{} accelerometers, schedule of {} steps", c.array.len(), c.schedule.len())
            }
            ConfigKind::SimulateLog => {
                let c = gfcal::config::simulate_log::SimulateLogConfig::load(path)?;
                format!("{} accelerometers, schedule of {} steps", c.array.len(), c.schedule.len())
            }
            ConfigKind::Array => {
                let a = gfcal::config::array::load_recording_array(path)?;
                format!("{} accelerometers, {} reference gyroscope axes", a.array.len(), a.gyroscopes.len())
            }
        })
    }

    /// The kind the file's top-level keys point to, when no loader accepts it.
    fn guess(path: &Path) -> Option<ConfigKind> {
        let text = std::fs::read_to_string(path).ok()?;
        let table: toml::Table = text.parse().ok()?;
        let has = |k: &str| table.contains_key(k);
        Some(if has("accelerometer") {
            ConfigKind::Array
        } else if has("trials_per_cell") || has("output") || has("sweep") || has("sensitivity") || has("protocol") {
            ConfigKind::Run
        } else if has("effects") || has("temperature") {
            ConfigKind::SimulateLog
        } else if has("targets") || has("design") || (has("schedule") && !has("trajectory")) {
            ConfigKind::Calibration
        } else if has("trajectory") {
            ConfigKind::Drift
        } else {
            return None;
        })
    }
}

/// What `gfcal check` found: the kinds whose loaders accept the file (with what it holds), or
/// the error of the kind it looks meant for.
pub fn check(path: &Path) -> Result<Vec<(ConfigKind, String)>, ConfigError> {
    let accepted: Vec<(ConfigKind, String)> =
        ConfigKind::ALL.iter().filter_map(|&k| k.load(path).ok().map(|d| (k, d))).collect();
    if !accepted.is_empty() {
        return Ok(accepted);
    }
    let Some(kind) = ConfigKind::guess(path) else {
        // Unreadable, or not TOML: any loader says so, naming the file and the line.
        return match ConfigKind::Run.load(path) {
            Err(e @ (ConfigError::Read { .. } | ConfigError::Parse { .. })) => Err(e),
            _ => Err(ConfigError::Invalid {
                path: path.to_path_buf(),
                key: "(top level)".into(),
                problem: "not a config of any gfcal command: no loader accepts it and its keys name none".into(),
            }),
        };
    };
    kind.load(path).map(|d| vec![(kind, d)])
}

/// For a command that could not load `path` as `expected`: whose config it is, if another
/// command's loader accepts it whole.
pub fn meant_for_another(path: &Path, expected: ConfigKind) -> Option<String> {
    let other: Vec<ConfigKind> =
        ConfigKind::ALL.iter().copied().filter(|&k| k != expected && k.load(path).is_ok()).collect();
    (!other.is_empty()).then(|| {
        format!(
            "{}: a config for `{}`, not for `{}`",
            path.display(),
            other.iter().map(|k| k.commands()).collect::<Vec<_>>().join("` and `"),
            expected.commands()
        )
    })
}

/// `gfcal check CONFIG`.
pub fn run(path: &Path) -> anyhow::Result<()> {
    let found = check(path).map_err(InputError::Config)?;
    for (kind, what) in found {
        println!("{}: a valid config for `{}`: {what}", path.display(), kind.commands());
        if kind == ConfigKind::Array
            && let Ok(a) = gfcal::config::array::load_recording_array(path)
        {
            print!("{}", geometry_text(&a));
        }
    }
    Ok(())
}

/// What an array file's geometry cannot see, with and without a measured rate
/// (`gfcal::selfcal::geometry`).
fn geometry_text(a: &gfcal::array::wiring::RecordingArray) -> String {
    use gfcal::selfcal::geometry::{POSES, SAMPLES, check, remedies};
    use std::fmt::Write;
    let n = a.array.len();
    let mut s = String::new();
    let groups = gfcal::selfcal::model::axis_groups(&a.array).iter().max().map_or(1, |g| g + 1);
    if groups > 1 {
        let _ = writeln!(
            s,
            "  axis groups: the axes split into {groups} groups orthogonal to one another; each group's common translation is seen only through its axes' tilts, and the gauge fixes it (its mean sensing point is the drawing's): {} directions beside the gauge's null ones",
            3 * (groups - 1)
        );
    }
    for reference_rate in [false, true] {
        let c = check(&a.array, reference_rate);
        let how = if reference_rate { "with a measured rate (--use-gyro)" } else { "gyroscope-free" };
        if c.unseen.is_empty() {
            let _ = writeln!(
                s,
                "  geometry, {how}: sees every parameter beyond the gauge (Fisher null directions {}, gauge {}; {POSES} poses and {SAMPLES} rotation samples, synthetic)",
                c.null_directions, c.gauge_null_directions
            );
            if let Some((lambda, comb)) = c.unseen.weakest.first() {
                let _ = writeln!(
                    s,
                    "    weakest combination seen (scaled eigenvalue {lambda:.1e} of the largest; null below {:.0e}): {}",
                    gfcal::selfcal::unseen::NULL_RELATIVE,
                    gfcal::selfcal::unseen::describe(comb, n)
                );
            }
            if !reference_rate && let Some(flat) = gfcal::selfcal::geometry::flatness(&a.array) {
                let _ = writeln!(s, "    {flat}");
            }
            continue;
        }
        let names = gfcal::selfcal::geometry::unseen_names(&c.unseen.parameters, n);
        let _ = writeln!(
            s,
            "  geometry, {how}: CANNOT SEE {} parameter combination(s) beyond the gauge (Fisher null directions {}, gauge {}; {POSES} poses and {SAMPLES} rotation samples, synthetic); `gfcal calibrate` leaves their {} parameters unidentified:",
            c.unseen.combinations.len(),
            c.null_directions,
            c.gauge_null_directions,
            names.len()
        );
        for comb in &c.unseen.combinations {
            let _ = writeln!(s, "    {}", gfcal::selfcal::unseen::describe(comb, n));
        }
        let _ = writeln!(s, "    unidentified: {}", names.join(", "));
        for r in remedies(&a.array, a.gyroscopes.len(), reference_rate, true, c.unseen.combinations.len()) {
            let _ = writeln!(s, "    to see them: {r}");
        }
    }
    s
}

/// The error of a command that could not load `path` as `expected`: whose config it is when
/// another command's loader accepts it, else the loader's own error.
pub fn input_error(e: ConfigError, path: &Path, expected: ConfigKind) -> InputError {
    match e {
        ConfigError::Read { .. } => InputError::Config(e),
        _ => match meant_for_another(path, expected) {
            Some(m) => InputError::Other(m),
            None => InputError::Config(e),
        },
    }
}
