//! The `gfcal` command line: parses arguments, calls the library, maps errors to exit codes
//! (0 success, 1 failure while running, 2 bad input).

use std::path::PathBuf;
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
    /// Navigation drift against horizon, compensating with nominal and with true parameters.
    Drift {
        /// Drift config (TOML), e.g. configs/paper_manoeuvre.toml.
        config: PathBuf,
        /// Also write the table as CSV.
        #[arg(long)]
        csv: Option<PathBuf>,
    },
}

/// An error the user can fix by changing the input: exit code 2.
#[derive(Debug, thiserror::Error)]
#[error(transparent)]
struct InputError(#[from] ConfigError);

const EXIT_FAILURE: u8 = 1;
const EXIT_BAD_INPUT: u8 = 2;

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("gfcal: error: {e:#}");
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
        Command::Drift { config, csv } => drift(&config, csv.as_deref()),
    }
}

fn drift(config_path: &std::path::Path, csv: Option<&std::path::Path>) -> anyhow::Result<()> {
    let cfg = DriftConfig::load(config_path).map_err(InputError)?;
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
        InputError(ConfigError::Invalid {
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
