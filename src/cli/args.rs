//! The command line's arguments (clap): every command, its flags and their help.

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(
    name = "gfcal",
    version,
    about = "Error analysis and calibration of gyroscope-free inertial navigation arrays"
)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

#[derive(Subcommand)]
pub enum Command {
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
        /// Also write the designed schedule as [schedule] with explicit [[schedule.step]] entries,
        /// ready for a run config (to confirm it by Monte Carlo).
        #[arg(long)]
        schedule_out: Option<PathBuf>,
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
    /// Linear covariance analysis of a run config: the distribution of every drift metric of
    /// every cell and compensation without Monte Carlo, its error budget, and a nonlinearity
    /// index (DIR/lincov.csv, lincov.parquet, budget.csv).
    Lincov {
        /// Run config (TOML), as for `gfcal run`, e.g. configs/quickstart.toml.
        config: PathBuf,
        /// Output folder [default: results/<config name>/].
        #[arg(long)]
        out: Option<PathBuf>,
        /// A `gfcal run` folder of the same config: LinCov beside its Monte Carlo quantiles
        /// (DIR/compare.csv).
        #[arg(long)]
        compare: Option<PathBuf>,
        /// Truths drawn for the estimated compensation's mixture when the errors are random.
        #[arg(long, default_value_t = 1024)]
        truths: usize,
        /// Worker threads [default: all cores].
        #[arg(long)]
        threads: Option<usize>,
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
    /// effects (see docs/model-discrepancy.md: the log format). Also takes a real recording (a table without the
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
        /// Recordings only: take each recording's bias drift in time out first, as `gfcal
        /// calibrate` does by default (fitted to its own static phase alone), and diagnose what
        /// is left; see docs/real-hardware.md, "Bias drift in time".
        #[arg(long)]
        remove_bias_drift: bool,
    },
    /// Add a known effect to a real recording (to check that a diagnosis finds it): the effect's
    /// generator works on the recorded output column; values in output units (see docs/model-discrepancy.md).
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
        /// Fit a clocked rotation phase by least squares alone, without Huber's weights on the
        /// heavy tail the sample clocks leave (for comparison; see docs/sample-clocks.md).
        #[arg(long)]
        plain_least_squares: bool,
        /// Calibrate the recording as it is, without first taking each accelerometer's bias
        /// drift in time (fitted to the static phase alone) out of it; see
        /// docs/real-hardware.md, "Bias drift in time".
        #[arg(long)]
        keep_bias_drift: bool,
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
