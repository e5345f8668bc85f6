//! The `gfcal` command line: parses arguments ([`args`]), calls the library, writes the files
//! the flags name, and maps errors to exit codes ([`error`]: 0 success, 1 failure while running,
//! 2 bad input). The library never prints; this is where its results become text.

use std::path::Path;
use std::process::ExitCode;

use anyhow::Context;
use clap::Parser;

use gfcal::config::ConfigError;
use gfcal::config::drift::DriftConfig;
use gfcal::nav::{DriftRow, DriftSetup, drift_study};

mod args;
mod calibrate;
mod check;
mod discrepancy;
mod error;
mod lincov;
mod outputs;
mod progress;
mod runs;
mod schedule;

use args::{Cli, Command};
use check::ConfigKind;
use error::{InputError, message, refuse_overwriting};
use outputs::{Output, check_outputs};

const EXIT_FAILURE: u8 = 1;
const EXIT_BAD_INPUT: u8 = 2;

/// The command line: parses, runs, and maps the outcome to an exit code.
pub fn main() -> ExitCode {
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

fn run(cli: Cli) -> anyhow::Result<()> {
    match cli.command {
        Command::Check { config } => check::run(&config),
        Command::Drift { config, csv } => {
            refuse_overwriting(&[("config", &config)], &[("--csv", csv.as_deref())])?;
            check_outputs(&files(&[("--csv", csv.as_deref())]))?;
            drift(&config, csv.as_deref())
        }
        Command::Identify { config } => schedule::identify(&config),
        Command::Run { config, out, resume, force, shard, threads, progress_interval_s } => {
            runs::run(&config, out, resume, force, shard.as_deref(), threads, progress_interval_s)
        }
        Command::Summarize { dir } => runs::summarize(&dir),
        Command::Lincov { config, out, compare, truths, threads } => {
            lincov::lincov(lincov::LincovArgs { config: &config, out, compare: compare.as_deref(), truths, threads })
        }
        Command::Report { dir } => runs::report(&dir),
        Command::Sensitivity { dir, max_trials } => runs::sensitivity(&dir, max_trials),
        Command::SimulateLog { config, out } => {
            refuse_overwriting(&[("config", &config)], &[("--out", Some(&out))])?;
            check_outputs(&[Output::File("--out", &out)])?;
            discrepancy::simulate_log(&config, &out)
        }
        Command::Diagnose {
            log,
            array,
            held_out,
            json,
            report,
            alpha,
            reference_temp_c,
            use_gyro,
            remove_bias_drift,
        } => {
            let mut inputs: Vec<(&str, &Path)> = vec![("log or recording", &log)];
            inputs.extend(array.as_deref().map(|a| ("array file", a)));
            inputs.extend(held_out.iter().map(|h| ("held-out recording", h.as_path())));
            refuse_overwriting(&inputs, &[("--json", json.as_deref()), ("--report", report.as_deref())])?;
            check_outputs(&files(&[("--json", json.as_deref()), ("--report", report.as_deref())]))?;
            if let Some(array_path) = array.as_deref()
                && let Some(table) = discrepancy::recording_table(&log)
            {
                discrepancy::diagnose_recordings(
                    &table,
                    array_path,
                    &held_out,
                    discrepancy::RecordingOptions {
                        json: json.as_deref(),
                        report: report.as_deref(),
                        alpha,
                        use_gyro,
                        remove_bias_drift,
                    },
                )
            } else if remove_bias_drift {
                Err(InputError::Other(format!(
                    "{}: --remove-bias-drift takes real recordings (tables without the log's `up_x` column) with --array",
                    log.display()
                ))
                .into())
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
                discrepancy::diagnose(
                    &log,
                    array.as_deref(),
                    json.as_deref(),
                    report.as_deref(),
                    alpha,
                    reference_temp_c,
                )
            }
        }
        Command::Design { config, schedule_out } => schedule::design(&config, schedule_out.as_deref()),
        Command::Inject { recording, array, effect, accelerometer, element, value, out } => {
            refuse_overwriting(&[("recording", &recording), ("array file", &array)], &[("--out", Some(&out))])?;
            check_outputs(&[Output::File("--out", &out)])?;
            discrepancy::inject(&recording, &array, &effect, accelerometer, element.as_deref(), value, &out)
        }
        Command::Calibrate {
            recording,
            array,
            json,
            report,
            use_gyro,
            plain_least_squares,
            keep_bias_drift,
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
            check_outputs(&files(&[("--json", json.as_deref()), ("--report", report.as_deref())]))?;
            let detector = gfcal::selfcal::segment::DetectorSettings {
                window_s,
                threshold: still_threshold,
                min_static_s,
                trim_s,
                min_dynamic_s,
            };
            calibrate::calibrate(calibrate::CalibrateArgs {
                recording: &recording,
                array: &array,
                json: json.as_deref(),
                report: report.as_deref(),
                use_gyro,
                plain_least_squares,
                remove_bias_drift: !keep_bias_drift,
                held_out: &held_out,
                gravity_m_s2,
                detector,
            })
        }
        Command::Paper { out, trials, seed, noise_density_ug_per_sqrt_hz } => {
            check_outputs(&[Output::Folder("--out", &out)])?;
            schedule::paper(&out, trials, seed, noise_density_ug_per_sqrt_hz)
        }
    }
}

/// The file outputs among optional flags.
fn files<'a>(flags: &[(&'a str, Option<&'a Path>)]) -> Vec<Output<'a>> {
    flags.iter().filter_map(|(flag, p)| p.map(|p| Output::File(flag, p))).collect()
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
        gfcal::io::write_atomic(path, gfcal::nav::study::drift_csv(&rows).as_bytes())
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
