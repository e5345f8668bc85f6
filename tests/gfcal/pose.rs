//! Pose error (`calib::pose`): tilt Jacobians against central differences, the perfect fixture
//! against today's committed output, the Cramer-Rao bounds an independent analysis gave for the
//! paper's schedule, and the estimator with tilt nuisance against its bound by Monte Carlo.

#![allow(clippy::needless_range_loop)]

use std::path::PathBuf;
use std::process::Command;

use gfcal::array::Array;
use gfcal::calib::joint::{Start, estimate_unchecked};
use gfcal::calib::joint_pose::estimate_with_poses;
use gfcal::calib::measure::{noise_free, simulate};
use gfcal::calib::params::StepMotion;
use gfcal::calib::pose::{PoseError, crb_sigma, marginal_fisher, motion_and_partials, output_by_motion, tilted};
use gfcal::calib::reproduce::paper_truth;
use gfcal::calib::schedule::Schedule;
use gfcal::calib::{Form, Layout};
use gfcal::rng::trial_rng;
use gfcal::sensor::ArrayParams;
use gfcal::sensor::noise::{NoiseSpec, WhiteNoise};
use gfcal::units::{M_S2_PER_UG, RAD_PER_ARCSEC, RAD_PER_DEG, STANDARD_GRAVITY_M_S2 as G};
use nalgebra::DVector;
use rand::RngExt;
use rand_distr::StandardNormal;
use rayon::prelude::*;

const TWO_PI: f64 = 2.0 * std::f64::consts::PI;
/// 50 ug/sqrt(Hz) per sample at 100 Hz.
const DENSITY_M_S2_PER_SQRT_HZ: f64 = 50.0 * M_S2_PER_UG;
const WEAK: [&str; 6] = ["a1.dz", "a2.dy", "a3.dx", "a4.dx", "a5.dy", "a6.dz"];

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn paper() -> (Array, Layout, ArrayParams, ArrayParams, DVector<f64>, Schedule) {
    let array = Array::cube(0.1).unwrap();
    let layout = Layout::new(&array, Form::Triad).unwrap();
    let truth = paper_truth(&array).unwrap();
    let mut nominal = ArrayParams::nominal(&array);
    for (n, t) in nominal.sensors.iter_mut().zip(&truth.sensors) {
        n.scale_factor = t.scale_factor;
    }
    let x = layout.pack(&truth).unwrap();
    let schedule = Schedule::hung_lee_2006(&array, TWO_PI, 1.0, 100.0).unwrap();
    (array, layout, truth, nominal, x, schedule)
}

fn fixture(arcsec: f64) -> PoseError {
    PoseError { static_sigma_rad: arcsec * RAD_PER_ARCSEC, spin_sigma_rad: arcsec * RAD_PER_ARCSEC }
}

#[test]
fn tilt_partials_match_central_differences() {
    let (array, layout, _, _, x, schedule) = paper();
    let h = 1e-6;
    for step in schedule.steps() {
        for t0 in [[0.0, 0.0], [3e-3, -2e-3]] {
            let (_, partials) = motion_and_partials(step, t0, G);
            for c in 0..2 {
                let mut tp = t0;
                let mut tm = t0;
                tp[c] += h;
                tm[c] -= h;
                let mp = StepMotion::new(&tilted(step, tp), G);
                let mm = StepMotion::new(&tilted(step, tm), G);
                for j in 0..array.len() {
                    let xj: [f64; 7] = std::array::from_fn(|a| x[7 * j + a]);
                    let fd = (layout.accel_model(j, &xj, &mp).0 - layout.accel_model(j, &xj, &mm).0) / (2.0 * h);
                    let analytic = output_by_motion(&layout, j, &xj, &partials[c]);
                    assert!(
                        (fd - analytic).abs() <= 1e-6 * (1.0 + analytic.abs()),
                        "step {} tilt {c} accelerometer {}: finite difference {fd}, analytic {analytic}",
                        step.name,
                        j + 1
                    );
                }
            }
        }
    }
}

/// A perfect fixture (sigma 0) gives today's results bit for bit: `gfcal identify` prints exactly
/// the committed output of the paper's case, with the key left out or set to 0.
#[test]
fn perfect_fixture_reproduces_the_committed_identify_output() {
    let committed = std::fs::read_to_string(repo().join("results/hung_lee_2006/identify.txt")).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let text = std::fs::read_to_string(repo().join("configs/hung_lee_2006_design.toml")).unwrap();
    let zero = dir.path().join("zero.toml");
    std::fs::write(&zero, text.replace("estimator = \"joint\"", "estimator = \"joint\"\npose_tilt_sigma_arcsec = 0.0"))
        .unwrap();
    for config in [repo().join("configs/hung_lee_2006_design.toml"), zero] {
        let out = Command::new(env!("CARGO_BIN_EXE_gfcal")).arg("identify").arg(&config).output().unwrap();
        assert!(out.status.success());
        assert_eq!(String::from_utf8(out.stdout).unwrap(), committed, "{}", config.display());
    }
}

/// An independent analysis of the paper's schedule: at 36 arcsec of fixture error the strong
/// location bounds rise from 0.017 mm to about 0.06 mm. Expected before running: every strong
/// component between 0.04 and 0.07 mm, the weak ones still millimetres.
#[test]
fn fixture_error_of_36_arcsec_raises_the_strong_location_bounds_to_about_006_mm() {
    let (array, layout, _, _, x, schedule) = paper();
    let perfect =
        crb_sigma(&marginal_fisher(&layout, &x, &schedule, G, DENSITY_M_S2_PER_SQRT_HZ, &PoseError::PERFECT), 6, true);
    let real =
        crb_sigma(&marginal_fisher(&layout, &x, &schedule, G, DENSITY_M_S2_PER_SQRT_HZ, &fixture(36.0)), 6, false);
    for i in 0..layout.len() {
        let name = layout.name(i);
        if !name.contains(".d") {
            continue;
        }
        let (before_mm, after_mm) = (perfect[i] * 1e3, real[i] * 1e3);
        if WEAK.contains(&name.as_str()) {
            assert!(after_mm > 1.0, "{name}: {after_mm} mm");
        } else {
            assert!((before_mm - 0.017).abs() < 0.001, "{name}: {before_mm} mm with a perfect fixture");
            assert!((0.04..0.07).contains(&after_mm), "{name}: {after_mm} mm at 36 arcsec");
        }
    }
    // Every bound rises (information can only be lost to nuisance), none falls.
    for i in 0..layout.len() {
        assert!(real[i] >= perfect[i] * (1.0 - 1e-9), "{}", layout.name(i));
    }
    assert_eq!(array.len(), 6);
}

/// An independent analysis: a 0.01 deg tilt of one spin axis alone moves the weak location
/// estimates (fitted as if the fixture were perfect) by millimetres, and the strong ones by
/// little.
#[test]
fn a_001_deg_tilt_of_one_spin_axis_moves_the_weak_locations_by_millimetres() {
    let (array, layout, truth, nominal, x, schedule) = paper();
    let z_spin = schedule.steps().iter().position(|s| s.is_spin()).unwrap();
    let steps: Vec<_> = schedule
        .steps()
        .iter()
        .enumerate()
        .map(|(i, s)| if i == z_spin { tilted(s, [0.01 * RAD_PER_DEG, 0.0]) } else { s.clone() })
        .collect();
    let delivered = Schedule::new("tilted", steps).unwrap();
    let meas = noise_free(&array, &truth, &delivered, G);
    let fit = estimate_unchecked(&layout, &schedule, &meas, &nominal, Start::Linear, G).unwrap();
    let mut weak_max_mm: f64 = 0.0;
    let mut strong_max_mm: f64 = 0.0;
    for i in 0..layout.len() {
        let name = layout.name(i);
        if !name.contains(".d") {
            continue;
        }
        let moved_mm = (fit.x[i] - x[i]).abs() * 1e3;
        if WEAK.contains(&name.as_str()) {
            weak_max_mm = weak_max_mm.max(moved_mm);
        } else {
            strong_max_mm = strong_max_mm.max(moved_mm);
        }
    }
    eprintln!("moved by the tilt: weak up to {weak_max_mm:.3} mm, strong up to {strong_max_mm:.4} mm");
    assert!(weak_max_mm > 1.0, "weak components moved by at most {weak_max_mm} mm");
    assert!(strong_max_mm < 0.1 * weak_max_mm, "strong components moved by {strong_max_mm} mm");
}

/// Monte Carlo with the fixture's tilts drawn at 36 arcsec: the estimator with tilt nuisance is
/// efficient. With K = 400 trials RMS(error / sigma) has a relative standard error of about
/// 1 / sqrt(2K) = 3.5%; 15% is 4.2 standard errors, so over 42 parameters a correct estimator
/// fails with probability below 0.1%. The estimator that ignores the tilts is shown worse.
#[test]
fn estimator_with_tilt_nuisance_meets_its_cramer_rao_bound_under_fixture_error() {
    let (array, layout, truth, nominal, x, schedule) = paper();
    let pose = fixture(36.0);
    let bound = crb_sigma(&marginal_fisher(&layout, &x, &schedule, G, DENSITY_M_S2_PER_SQRT_HZ, &pose), 6, false);
    let noise = NoiseSpec {
        white: WhiteNoise::Density { density_m_s2_per_sqrt_hz: 50.0 * M_S2_PER_UG },
        ..NoiseSpec::default()
    };
    let trials = 400;
    let errors: Vec<(DVector<f64>, DVector<f64>)> = (0..trials)
        .into_par_iter()
        .map(|k| {
            let mut rng = trial_rng(77, k);
            let tilts: Vec<[f64; 2]> = schedule
                .steps()
                .iter()
                .map(|s| {
                    let sigma = pose.sigma_rad(s);
                    [sigma * rng.sample::<f64, _>(StandardNormal), sigma * rng.sample::<f64, _>(StandardNormal)]
                })
                .collect();
            let delivered = gfcal::calib::pose::tilted_schedule(&schedule, &tilts);
            let meas = simulate(&array, &truth, &delivered, &noise, G, &mut rng);
            let with = estimate_with_poses(
                &layout,
                &schedule,
                &meas,
                &nominal,
                Start::Linear,
                G,
                &pose,
                DENSITY_M_S2_PER_SQRT_HZ,
            )
            .unwrap();
            assert!(with.status.converged, "{}", with.status.message);
            let without = estimate_unchecked(&layout, &schedule, &meas, &nominal, Start::Linear, G).unwrap();
            (&with.x - &x, &without.x - &x)
        })
        .collect();
    let mut worse = 0;
    for i in 0..layout.len() {
        let z = (errors.iter().map(|e| (e.0[i] / bound[i]).powi(2)).sum::<f64>() / trials as f64).sqrt();
        let ignoring = (errors.iter().map(|e| (e.1[i] / bound[i]).powi(2)).sum::<f64>() / trials as f64).sqrt();
        assert!((z - 1.0).abs() < 0.15, "{}: RMS(error / CRB sigma) = {z:.3}", layout.name(i));
        if ignoring > 1.15 {
            worse += 1;
        }
    }
    eprintln!("ignoring the tilts: {worse} of {} parameters more than 15% above the bound", layout.len());
    assert!(worse > 0);
}

/// A tilt sigma that is negative or NaN is refused in any config; `inf` (a free pose) is refused
/// in a run, which must draw the tilts, naming the key; a finite one runs.
#[test]
fn bad_tilt_sigmas_are_refused_naming_the_key() {
    let dir = tempfile::tempdir().unwrap();
    let gfcal = |args: &[&std::ffi::OsStr]| Command::new(env!("CARGO_BIN_EXE_gfcal")).args(args).output().unwrap();
    let design = std::fs::read_to_string(repo().join("configs/hung_lee_2006_design.toml")).unwrap();
    for (value, key) in [("-5.0", "pose_tilt_sigma_arcsec"), ("nan", "pose_tilt_sigma_arcsec")] {
        let path = dir.path().join("bad.toml");
        std::fs::write(
            &path,
            design.replace("estimator = \"joint\"", &format!("estimator = \"joint\"\n{key} = {value}")),
        )
        .unwrap();
        let out = gfcal(&["identify".as_ref(), path.as_os_str()]);
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{value}: {err}");
        assert!(err.contains(&format!("calibration.{key}")) && err.contains("bad.toml"), "{err}");
    }
    let quick = std::fs::read_to_string(repo().join("configs/quickstart.toml")).unwrap();
    let run = |extra: &str, name: &str| {
        let path = dir.path().join(name);
        let text = quick.replace("trials_per_cell = 20000", "trials_per_cell = 40");
        std::fs::write(&path, text.replace("start = \"linear\"", &format!("start = \"linear\"\n{extra}"))).unwrap();
        let out_dir = dir.path().join(format!("{name}.out"));
        gfcal(&["run".as_ref(), path.as_os_str(), "--out".as_ref(), out_dir.as_os_str()])
    };
    let out = run("spin_axis_tilt_sigma_arcsec = inf", "free.toml");
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("calibration.spin_axis_tilt_sigma_arcsec") && err.contains("finite"), "{err}");
    let out = run("pose_tilt_sigma_arcsec = 36.0", "fixture.toml");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
}
