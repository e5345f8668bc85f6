//! The `gfcal` command line: parses arguments, calls the library, maps errors to exit codes
//! (0 success, 1 failure while running, 2 bad input).

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::{Parser, Subcommand};

use gfcal::config::ConfigError;
use gfcal::config::drift::DriftConfig;
use gfcal::nav::{DriftRow, DriftSetup, drift_study};

#[derive(Parser)]
#[command(
    name = "gfcal",
    version,
    about = "Error analysis and calibration of gyroscope-free inertial navigation arrays"
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Validate a config without running it: says which command(s) it is for and what it holds,
    /// or what is wrong with it (exit 2).
    Check {
        /// Any gfcal config (run, drift, identify/design, simulate-log) or array file.
        config: PathBuf,
    },
    /// Navigation drift against horizon, compensating with nominal and with true parameters.
    Drift {
        /// Drift config (TOML), e.g. configs/paper_manoeuvre.toml.
        config: PathBuf,
        /// Also write the table as CSV.
        #[arg(long)]
        csv: Option<PathBuf>,
    },
    /// Fisher information of a calibration schedule: Cramer-Rao sigma of every parameter and the
    /// combinations the schedule cannot identify or identifies weakly.
    Identify {
        /// Calibration config (TOML), e.g. configs/hung_lee_2006_design.toml.
        config: PathBuf,
    },
    /// Add steps to a schedule, greedily, until every Cramer-Rao sigma is below its target.
    Design {
        /// Calibration config (TOML), e.g. configs/hung_lee_2006_design.toml.
        config: PathBuf,
    },
    /// Run a Monte Carlo sweep: calibration trials and their navigation drift, into Parquet.
    Run {
        /// Run config (TOML), e.g. configs/quickstart.toml.
        config: PathBuf,
        /// Output folder [default: results/<config name>/].
        #[arg(long)]
        out: Option<PathBuf>,
        /// Finish an interrupted run of the same config in --out (runs only missing parts).
        #[arg(long)]
        resume: bool,
        /// Replace whatever run --out holds.
        #[arg(long, conflicts_with = "resume")]
        force: bool,
        /// Run shard I of N (0-based, e.g. 2/8); defaults to SLURM_ARRAY_TASK_ID /
        /// SLURM_ARRAY_TASK_COUNT when set.
        #[arg(long)]
        shard: Option<String>,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
        /// Seconds between progress lines when stderr is not a terminal.
        #[arg(long, default_value_t = 10.0)]
        progress_interval_s: f64,
    },
    /// Write a calibration log (CSV, or Parquet for a .parquet name) simulated from true
    /// parameters, noise, a schedule and any effects of the library switched on.
    SimulateLog {
        /// Simulate-log config (TOML), e.g. configs/discrepancy_example.toml.
        config: PathBuf,
        /// The log to write (.csv or .parquet).
        #[arg(long)]
        out: PathBuf,
    },
    /// Fit the baseline model to a calibration log, find where it disagrees, and name the missing
    /// effects (see README: the log format). Also takes a real recording (a table without the
    /// log's `up_x` column) with the array file `gfcal calibrate` takes: it is segmented and
    /// fitted as there, and scored on the `--held-out` recordings.
    Diagnose {
        /// The log or recording (.csv or .parquet).
        log: PathBuf,
        /// Array file (TOML) [default: the paper's cube, rho = 0.1 m]; a recording needs one with
        /// its columns (as for `gfcal calibrate`).
        #[arg(long)]
        array: Option<PathBuf>,
        /// Recordings of the same array to score the fitting recording's model on (only the pose
        /// directions, the motion and the per-recording effects refitted there).
        #[arg(long, num_args = 1..)]
        held_out: Vec<PathBuf>,
        /// Also write the diagnosis as JSON.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Also write a self-contained HTML report: residuals by step and accelerometer before and
        /// after each added effect, and the gap after each addition.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Familywise significance level of the effect tests.
        #[arg(long, default_value_t = 0.01)]
        alpha: f64,
        /// Reference temperature of the temperature effects, deg C.
        #[arg(long, default_value_t = 25.0)]
        reference_temp_c: f64,
        /// Recordings only: take the angular rate from the reference gyroscopes (as
        /// `calibrate --use-gyro`), and try the gyroscopes' own scale factor and misalignment.
        #[arg(long)]
        use_gyro: bool,
    },
    /// Add a known effect to a real recording (to check that a diagnosis finds it): the effect's
    /// generator works on the recorded output column; values in output units (see README).
    Inject {
        /// The recording (.csv or .parquet), as for `gfcal calibrate`.
        recording: PathBuf,
        /// Its array file (columns and ranges).
        #[arg(long)]
        array: PathBuf,
        /// bias_turn_on (m/s^2), bias_time_drift (m/s^2/s), scale_factor_quadratic (1/(m/s^2)),
        /// scale_factor_cubic (1/(m/s^2)^2), cross_coupling (1/(m/s^2)) or sampling_delay (s) on
        /// an accelerometer; gyro_scale_misalignment (1) on the gyroscopes, with --element.
        #[arg(long)]
        effect: String,
        /// The accelerometer (1-based, in the array file's order); not with gyro_scale_misalignment.
        #[arg(long)]
        accelerometer: Option<usize>,
        /// gyro_scale_misalignment's element of G: xx, xy, ..., zz (row: the true rate's axis).
        #[arg(long)]
        element: Option<String>,
        /// The effect's size, in the unit above.
        #[arg(long, allow_hyphen_values = true)]
        value: f64,
        /// The recording to write (.csv or .parquet).
        #[arg(long)]
        out: PathBuf,
    },
    /// Which error parameters drive each drift metric of a run: standardised rank regression
    /// coefficients (DIR/sensitivity.csv).
    Sensitivity {
        /// The run's output folder.
        dir: PathBuf,
        /// Trials per cell to use (the first by trial id).
        #[arg(long, default_value_t = 20000)]
        max_trials: usize,
    },
    /// Write a run's report: DIR/report.html (self-contained, plots inline) and the plots as SVG
    /// files in DIR/report/.
    Report {
        /// The run's output folder.
        dir: PathBuf,
    },
    /// Recompute a run's summary (summary.csv) from its Parquet files.
    Summarize {
        /// The run's output folder.
        dir: PathBuf,
    },
    /// Calibrate a real array from a recording (hand-placed static poses, then free rotation by
    /// hand): bias, scale factor, tilt and location of every accelerometer with its sigma, the
    /// angular rate from the accelerometers alone (gyroscope-free), checked against the reference
    /// gyroscopes the array file lists.
    Calibrate {
        /// The recording (.csv or .parquet), one row per sample.
        recording: PathBuf,
        /// Array file (TOML): positions, axes, columns and ranges of the accelerometers, and the
        /// reference gyroscopes (e.g. configs/arrays/mimu4444_corners.toml).
        #[arg(long)]
        array: PathBuf,
        /// Also write the calibration as JSON (SI units).
        #[arg(long)]
        json: Option<PathBuf>,
        /// Also write a self-contained HTML report.
        #[arg(long)]
        report: Option<PathBuf>,
        /// Take the angular rate from the reference gyroscopes instead of the accelerometers.
        #[arg(long)]
        use_gyro: bool,
        /// Predict these recordings of the same array with this calibration (only their pose
        /// directions and motion refitted) and report the residuals.
        #[arg(long, num_args = 1..)]
        held_out: Vec<PathBuf>,
        /// Local gravity, m/s^2.
        #[arg(long, default_value_t = gfcal::units::STANDARD_GRAVITY_M_S2)]
        gravity_m_s2: f64,
        /// Segmentation: moving-window length, s.
        #[arg(long, default_value_t = 0.5)]
        window_s: f64,
        /// Segmentation: still when every accelerometer's moving std is below this multiple of
        /// its noise floor.
        #[arg(long, default_value_t = 2.0)]
        still_threshold: f64,
        /// Segmentation: shortest static interval, s (before trimming).
        #[arg(long, default_value_t = 5.0)]
        min_static_s: f64,
        /// Segmentation: trimmed from each end of a static interval, s.
        #[arg(long, default_value_t = 1.0)]
        trim_s: f64,
        /// Segmentation: shortest moving run counted as dynamic phase, s.
        #[arg(long, default_value_t = 10.0)]
        min_dynamic_s: f64,
    },
    /// Reproduce Hung & Lee (2006) Tables 8 and 9 (CSV and Markdown) into a folder.
    Paper {
        /// Output folder (created if missing).
        #[arg(long)]
        out: PathBuf,
        /// Monte Carlo trials per schedule.
        #[arg(long, default_value_t = 1000)]
        trials: usize,
        /// Master seed of the Monte Carlo.
        #[arg(long, default_value_t = 2006)]
        seed: u64,
        /// White noise density of every accelerometer, ug/sqrt(Hz).
        #[arg(long, default_value_t = 50.0)]
        noise_density_ug_per_sqrt_hz: f64,
    },
}

mod check;
use check::ConfigKind;
mod commands;
mod hardware;
mod progress;
mod runs;

/// An error the user can fix by changing the input: exit code 2.
#[derive(Debug, thiserror::Error)]
pub(crate) enum InputError {
    #[error(transparent)]
    Config(#[from] ConfigError),
    #[error("{0}")]
    Other(String),
}

/// Refuses a command whose output would replace one of its inputs (`gfcal inject` with `--out` the
/// recording it reads would destroy the recording), or whose two outputs are one file.
fn refuse_overwriting(inputs: &[(&str, &Path)], outputs: &[(&str, Option<&Path>)]) -> Result<(), InputError> {
    let outputs: Vec<(&str, &Path)> = outputs.iter().filter_map(|(flag, p)| p.map(|p| (*flag, p))).collect();
    for (flag, out) in &outputs {
        if let Some((what, input)) = inputs.iter().find(|(_, input)| gfcal::io::same_file(out, input)) {
            return Err(InputError::Other(format!(
                "{flag}: {} is the {what} {}, which gfcal reads; it never writes over its input: give another file",
                out.display(),
                input.display()
            )));
        }
    }
    for (i, (flag, out)) in outputs.iter().enumerate() {
        let same = |(_, other): &&(&str, &Path)| other == out || gfcal::io::same_file(out, other);
        if let Some((other_flag, _)) = outputs[i + 1..].iter().find(same) {
            return Err(InputError::Other(format!(
                "{flag} and {other_flag}: both name {}; give each its own file",
                out.display()
            )));
        }
    }
    Ok(())
}

const EXIT_FAILURE: u8 = 1;
const EXIT_BAD_INPUT: u8 = 2;

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("gfcal: error: {}", message(&e));
            if e.downcast_ref::<InputError>().is_some() {
                ExitCode::from(EXIT_BAD_INPUT)
            } else {
                ExitCode::from(EXIT_FAILURE)
            }
        }
    }
}

/// The error and its causes, each said once: a cause whose text the message already holds
/// (an error that prints its source, then the source itself) is left out.
fn message(e: &anyhow::Error) -> String {
    let mut out = e.to_string();
    for cause in e.chain().skip(1) {
        let text = cause.to_string();
        let plain = text.split(" (os error").next().unwrap_or(&text).to_string();
        if !out.contains(&plain) {
            out.push_str(": ");
            out.push_str(&text);
        }
    }
    out
}

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Check { config } => check::run(&config),
        Command::Drift { config, csv } => {
            refuse_overwriting(&[("config", &config)], &[("--csv", csv.as_deref())])?;
            drift(&config, csv.as_deref())
        }
        Command::Identify { config } => commands::identify(&config),
        Command::Run { config, out, resume, force, shard, threads, progress_interval_s } => {
            runs::run(&config, out, resume, force, shard.as_deref(), threads, progress_interval_s)
        }
        Command::Summarize { dir } => runs::summarize(&dir),
        Command::Report { dir } => runs::report(&dir),
        Command::Sensitivity { dir, max_trials } => runs::sensitivity(&dir, max_trials),
        Command::SimulateLog { config, out } => {
            refuse_overwriting(&[("config", &config)], &[("--out", Some(&out))])?;
            commands::simulate_log(&config, &out)
        }
        Command::Diagnose { log, array, held_out, json, report, alpha, reference_temp_c, use_gyro } => {
            let mut inputs: Vec<(&str, &Path)> = vec![("log or recording", &log)];
            inputs.extend(array.as_deref().map(|a| ("array file", a)));
            inputs.extend(held_out.iter().map(|h| ("held-out recording", h.as_path())));
            refuse_overwriting(&inputs, &[("--json", json.as_deref()), ("--report", report.as_deref())])?;
            if let Some(array_path) = array.as_deref()
                && let Some(table) = commands::recording_table(&log)
            {
                commands::diagnose_recordings(
                    &table,
                    array_path,
                    &held_out,
                    commands::RecordingOptions { json: json.as_deref(), report: report.as_deref(), alpha, use_gyro },
                )
            } else if use_gyro {
                Err(InputError::Other(format!(
                    "{}: --use-gyro takes real recordings (tables without the log's `up_x` column) with --array",
                    log.display()
                ))
                .into())
            } else if !held_out.is_empty() {
                Err(InputError::Other(format!(
                    "{}: --held-out takes real recordings (tables without the log's `up_x` column) with --array",
                    log.display()
                ))
                .into())
            } else {
                commands::diagnose(&log, array.as_deref(), json.as_deref(), report.as_deref(), alpha, reference_temp_c)
            }
        }
        Command::Design { config } => commands::design(&config),
        Command::Inject { recording, array, effect, accelerometer, element, value, out } => {
            refuse_overwriting(&[("recording", &recording), ("array file", &array)], &[("--out", Some(&out))])?;
            commands::inject(&recording, &array, &effect, accelerometer, element.as_deref(), value, &out)
        }
        Command::Calibrate {
            recording,
            array,
            json,
            report,
            use_gyro,
            held_out,
            gravity_m_s2,
            window_s,
            still_threshold,
            min_static_s,
            trim_s,
            min_dynamic_s,
        } => {
            let mut inputs: Vec<(&str, &Path)> = vec![("recording", &recording), ("array file", &array)];
            inputs.extend(held_out.iter().map(|h| ("held-out recording", h.as_path())));
            refuse_overwriting(&inputs, &[("--json", json.as_deref()), ("--report", report.as_deref())])?;
            let detector = gfcal::selfcal::segment::DetectorSettings {
                window_s,
                threshold: still_threshold,
                min_static_s,
                trim_s,
                min_dynamic_s,
            };
            hardware::calibrate(hardware::CalibrateArgs {
                recording: &recording,
                array: &array,
                json: json.as_deref(),
                report: report.as_deref(),
                use_gyro,
                held_out: &held_out,
                gravity_m_s2,
                detector,
            })
        }
        Command::Paper { out, trials, seed, noise_density_ug_per_sqrt_hz } => {
            commands::paper(&out, trials, seed, noise_density_ug_per_sqrt_hz)
        }
    }
}

fn drift(config_path: &std::path::Path, csv: Option<&std::path::Path>) -> anyhow::Result<()> {
    let cfg = DriftConfig::load(config_path).map_err(|e| check::input_error(e, config_path, ConfigKind::Drift))?;
    let nav = &cfg.navigation;
    let setup = DriftSetup {
        array: &cfg.array,
        truth: &cfg.errors.truth,
        trajectory: &cfg.trajectory,
        noise: cfg.noise,
        noise_seed: cfg.noise_seed,
        gravity_m_s2: nav.gravity_m_s2,
        step_s: nav.step_s,
    };
    let compensations = [("nominal", &cfg.errors.nominal), ("true", &cfg.errors.truth)];
    let rows = drift_study(&setup, &compensations, &nav.horizons_s).map_err(|e| {
        InputError::Config(ConfigError::Invalid {
            path: config_path.to_path_buf(),
            key: "errors".into(),
            problem: format!("the true parameters give {e}"),
        })
    })?;
    print!("{}", drift_table(&rows));
    if let Some(path) = csv {
        gfcal::io::write_atomic(path, gfcal::io::csv::drift_csv(&rows).as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

fn drift_table(rows: &[DriftRow]) -> String {
    let mut s = format!(
        "{:<12} {:>10} {:>16} {:>16} {:>16} {:>16}\n",
        "compensation", "horizon_s", "rate_err_rad_s", "attitude_err_rad", "velocity_err_m_s", "position_err_m"
    );
    for r in rows {
        let d = &r.sample;
        s.push_str(&format!(
            "{:<12} {:>10} {:>16.4e} {:>16.4e} {:>16.4e} {:>16.4e}\n",
            r.compensation, d.horizon_s, d.rate_err_rad_s, d.attitude_err_rad, d.velocity_err_m_s, d.position_err_m
        ));
    }
    s
}

#[cfg(test)]
mod tests {
    /// Issue 13: "Read-only file system (os error 30): Read-only file system" said the cause twice.
    #[test]
    fn an_error_says_each_cause_once() {
        let io = std::io::Error::from_raw_os_error(30);
        let text = io.to_string();
        let e = anyhow::Error::new(io).context(format!("cannot write out.csv: {text}"));
        let m = super::message(&e);
        assert_eq!(m.matches("Read-only file system").count(), 1, "{m}");
        let e = anyhow::Error::new(std::io::Error::from_raw_os_error(2)).context("cannot write out.csv");
        assert_eq!(super::message(&e), "cannot write out.csv: No such file or directory (os error 2)");
    }
}
