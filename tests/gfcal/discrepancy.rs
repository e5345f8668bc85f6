//! The discrepancy workflow: logs, the effect library, simulated logs, the baseline fit's gap.

use std::path::Path;

use gfcal::array::Array;
use gfcal::calib::Form;
use gfcal::calib::schedule::Schedule;
use gfcal::config::simulate_log::SimulateLogConfig;
use gfcal::discrepancy::effect::{SampleContext, library};
use gfcal::discrepancy::log::{ActiveEffect, LogSimulation, Temperature};
use gfcal::discrepancy::log::{CalibrationLog, LogError};
use gfcal::discrepancy::log::{DiagnoseError, fit_baseline};
use gfcal::sensor::noise::{NoiseSpec, WhiteNoise};
use gfcal::units::{M_S2_PER_UG, STANDARD_GRAVITY_M_S2 as G};
use nalgebra::{Matrix3, Vector3};

fn example() -> SimulateLogConfig {
    SimulateLogConfig::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/discrepancy_example.toml")).unwrap()
}

fn simulate(
    cfg: &SimulateLogConfig,
    effects: &[ActiveEffect],
    noise: NoiseSpec,
    temperature: Option<Temperature>,
    seed: u64,
) -> CalibrationLog {
    let sim = LogSimulation {
        array: &cfg.array,
        truth: &cfg.errors.truth,
        schedule: &cfg.schedule,
        noise,
        effects,
        temperature,
        g_m_s2: G,
    };
    sim.check().unwrap();
    sim.run(&mut gfcal::rng::trial_rng(seed, 0))
}

fn white(density_ug: f64) -> NoiseSpec {
    NoiseSpec {
        white: WhiteNoise::Density { density_m_s2_per_sqrt_hz: density_ug * M_S2_PER_UG },
        ..NoiseSpec::default()
    }
}

#[test]
fn logs_round_trip_through_csv_and_parquet() {
    let cfg = example();
    let temp = Some(Temperature::ramp(20.0, 30.0, 25.0));
    let log = simulate(&cfg, &[], white(50.0), temp, 1);
    assert!(log.has_temperature());
    let dir = tempfile::tempdir().unwrap();
    for name in ["log.csv", "log.parquet"] {
        let path = dir.path().join(name);
        log.write(&path).unwrap();
        let back = CalibrationLog::read(&path, 6).unwrap();
        assert_eq!(back, log, "{name}");
    }
    // The schedule read back from the log is the one simulated.
    let sched = log.schedule().unwrap();
    assert_eq!(sched.len(), 15);
    for (a, b) in sched.steps().iter().zip(cfg.schedule.steps()) {
        assert!((a.up_b() - b.up_b()).norm() < 1e-12 && (a.omega_b_rad_s() - b.omega_b_rad_s()).norm() < 1e-12);
        assert_eq!(a.samples(), b.samples());
        assert!((a.sample_rate_hz - 100.0).abs() < 1e-6);
    }
}

#[test]
fn effect_regressors_match_central_differences() {
    let ctx = SampleContext {
        step: 3,
        static_index: Some(3),
        spin_index: None,
        t_s: 37.5,
        temp_delta_c: 4.2,
        u_m_s2: 6.1,
        axis: Vector3::new(0.7, 0.1, 0.71),
        position_m: Vector3::new(0.0, -0.1, 0.001),
        up_b: Vector3::new(0.6, 0.0, 0.8),
        w2: {
            let w = Vector3::new(0.0, 6.0, 1.0);
            w * w.transpose() - Matrix3::identity() * w.norm_squared()
        },
        g_m_s2: G,
    };
    for effect in library() {
        let m = effect.parameters(12, 3);
        let p: Vec<f64> = (0..m).map(|i| 1e-3 * (1.0 + i as f64 * 0.37)).collect();
        let mut grad = vec![0.0; m];
        effect.term(&ctx, &p, &mut grad);
        for i in 0..m {
            let h = 1e-7;
            let (mut pp, mut pm) = (p.clone(), p.clone());
            pp[i] += h;
            pm[i] -= h;
            let mut scratch = vec![0.0; m];
            let fd = (effect.term(&ctx, &pp, &mut scratch) - effect.term(&ctx, &pm, &mut scratch)) / (2.0 * h);
            assert!(
                (fd - grad[i]).abs() < 1e-6 * grad[i].abs().max(1.0),
                "{} [{i}]: {} vs {fd}",
                effect.name(),
                grad[i]
            );
        }
    }
}

#[test]
fn a_clean_noise_free_log_gives_back_the_truth() {
    let cfg = example();
    let log = simulate(&cfg, &[], NoiseSpec::default(), None, 1);
    let sched = log.schedule().unwrap();
    let meas = log.measurements();
    let layout = gfcal::calib::Layout::new(&cfg.array, Form::Triad).unwrap();
    let e = gfcal::calib::joint::estimate(
        &layout,
        &sched,
        &meas,
        &cfg.errors.nominal,
        gfcal::calib::joint::Start::Linear,
        G,
    )
    .unwrap();
    let truth = layout.pack(&cfg.errors.truth).unwrap();
    for i in 0..truth.len() {
        assert!((e.x[i] - truth[i]).abs() <= 1e-9 * truth[i].abs(), "{}: {} vs {}", layout.name(i), e.x[i], truth[i]);
    }
}

#[test]
fn the_gap_is_noise_alone_for_a_clean_log_and_large_with_a_hidden_effect() {
    let cfg = example();
    // Clean logs: chi^2/dof near 1 and the test rarely rejects.
    let mut rejected = 0;
    for seed in 0..20 {
        let fit = fit_baseline(
            &simulate(&cfg, &[], white(50.0), None, seed),
            &cfg.array,
            &cfg.errors.nominal,
            Form::Triad,
            G,
        )
        .unwrap();
        assert!((fit.noise_sigma_m_s2 / (50.0 * M_S2_PER_UG * 10.0) - 1.0).abs() < 0.02);
        assert!(fit.chi2_per_dof() < 2.0, "seed {seed}: {}", fit.chi2_per_dof());
        if fit.p_value < 0.01 {
            rejected += 1;
        }
    }
    assert!(rejected <= 2, "{rejected} of 20 clean logs rejected at 1%");
    // The example's hidden quadratic scale factor: the test rejects, and the gap sits on
    // accelerometer 3.
    let fit = fit_baseline(
        &simulate(&cfg, &cfg.effects, white(50.0), None, 3),
        &cfg.array,
        &cfg.errors.nominal,
        Form::Triad,
        G,
    )
    .unwrap();
    assert!(fit.p_value < 1e-6, "chi2/dof {}", fit.chi2_per_dof());
    let per_accel: Vec<f64> = (0..6).map(|j| fit.whitened.iter().map(|z| z[j] * z[j]).sum::<f64>()).collect();
    let worst = (0..6).max_by(|a, b| per_accel[*a].total_cmp(&per_accel[*b])).unwrap();
    assert_eq!(worst, 2, "{per_accel:?}");
}

fn write(dir: &Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    std::fs::write(&p, text).unwrap();
    p
}

fn header(n: usize) -> String {
    let s: Vec<String> = (1..=n).map(|j| format!("s{j}")).collect();
    format!("step,t_s,up_x,up_y,up_z,omega_x_rad_s,omega_y_rad_s,omega_z_rad_s,{}\n", s.join(","))
}

fn row(step: i64, t: f64, up: [f64; 3], w: [f64; 3]) -> String {
    format!("{step},{t},{},{},{},{},{},{},1,2,3,4,5,6\n", up[0], up[1], up[2], w[0], w[1], w[2])
}

#[test]
fn bad_logs_are_refused_with_what_and_where() {
    let dir = tempfile::tempdir().unwrap();
    let z = [0.0, 0.0, 1.0];
    let ok = header(6) + &row(1, 0.0, z, [0.0; 3]) + &row(1, 0.01, z, [0.0; 3]);
    let err = |text: &str| CalibrationLog::read(&write(dir.path(), "bad.csv", text), 6).unwrap_err();
    let msg = |e: LogError| e.to_string();
    assert!(CalibrationLog::read(&write(dir.path(), "ok.csv", &ok), 6).is_ok());
    let without_omega_y: String = ok
        .lines()
        .map(|l| {
            let mut f: Vec<&str> = l.split(',').collect();
            f.remove(6);
            f.join(",") + "\n"
        })
        .collect();
    let m = msg(err(&without_omega_y));
    assert!(m.contains("bad.csv") && m.contains("missing column(s): omega_y_rad_s"), "{m}");
    let m = msg(err(&ok.replacen(",s6", ",s6,temp", 1).replace("5,6\n", "5,6,1\n")));
    assert!(m.contains("unknown column(s): temp"), "{m}");
    let m = msg(err(&ok.replacen("1,2,3,4,5,6\n", "1,2,NaN,4,5,6\n", 1)));
    assert!(m.contains("data row 1, column `s3`") && m.contains("not a finite number"), "{m}");
    let m = msg(err(&ok.replacen("1,2,3,4,5,6\n", "1,2,x,4,5,6\n", 1)));
    assert!(m.contains("data row 1, column `s3`: `x` is not a number"), "{m}");
    let m = msg(CalibrationLog::read(&write(dir.path(), "bad.csv", &ok), 9).unwrap_err());
    assert!(m.contains("the log has 6 outputs (s1..s6) but the array has 9"), "{m}");
    let back = header(6) + &row(2, 0.0, z, [0.0; 3]) + &row(1, 0.01, z, [0.0; 3]);
    assert!(msg(err(&back)).contains("step 1: comes after step 2"));
    let again = header(6) + &row(1, 0.0, z, [0.0; 3]) + &row(2, 0.01, z, [0.0; 3]) + &row(1, 0.02, z, [0.0; 3]);
    assert!(msg(err(&again)).contains("step 1: comes after step 2 (data row 3)"));
    let changes = header(6) + &row(1, 0.0, z, [0.0; 3]) + &row(1, 0.01, [1.0, 0.0, 0.0], [0.0; 3]);
    assert!(msg(err(&changes)).contains("changes within the step (data row 2)"));
    let tilted = header(6) + &row(1, 0.0, z, [6.0, 0.0, 0.0]);
    assert!(msg(err(&tilted)).contains("not vertical"));
    let time = header(6) + &row(1, 0.0, z, [0.0; 3]) + &row(1, 0.0, z, [0.0; 3]);
    assert!(msg(err(&time)).contains("column `t_s`: 0 does not increase"));
    let no_up = header(6) + &row(1, 0.0, [0.0; 3], [0.0; 3]);
    assert!(msg(err(&no_up)).contains("not a direction"));
    // Parquet: a NaN is named the same way.
    let cfg = example();
    let mut log = simulate(&cfg, &[], white(50.0), None, 1);
    log.steps[2].outputs[7] = f64::NAN;
    let pq = dir.path().join("nan.parquet");
    log.write(&pq).unwrap();
    let m = msg(CalibrationLog::read(&pq, 6).unwrap_err());
    assert!(m.contains("nan.parquet: data row 2002, column `s2`: NaN is not a finite number"), "{m}");
}

/// The recordings' flags on a calibration log: refused, naming the flag and the file, with a
/// non-zero exit and no output written.
#[test]
fn the_recordings_flags_on_a_log_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let log = simulate(&example(), &[], white(50.0), None, 1);
    let path = dir.path().join("log.csv");
    log.write(&path).unwrap();
    let json = dir.path().join("d.json");
    for flag in ["--remove-bias-drift", "--use-gyro"] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_gfcal"))
            .args(["diagnose", path.to_str().unwrap(), flag, "--json", json.to_str().unwrap()])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&o.stderr);
        assert!(!o.status.success(), "{flag}");
        assert!(stderr.contains(&format!("{flag} takes real recordings")) && stderr.contains("log.csv"), "{stderr}");
        assert!(!json.exists(), "{flag}: no output is written");
    }
}

#[test]
fn a_log_too_short_to_fit_says_how_many_steps_it_needs() {
    let cfg = example();
    let short = Schedule::new("short", cfg.schedule.steps()[..5].to_vec()).unwrap();
    let sim = LogSimulation {
        array: &cfg.array,
        truth: &cfg.errors.truth,
        schedule: &short,
        noise: white(50.0),
        effects: &[],
        temperature: None,
        g_m_s2: G,
    };
    let log = sim.run(&mut gfcal::rng::trial_rng(1, 0));
    let err = fit_baseline(&log, &cfg.array, &cfg.errors.nominal, Form::Triad, G).unwrap_err();
    assert!(matches!(err, DiagnoseError::TooShort { steps: 5, needed: 8 }), "{err}");
    assert!(err.to_string().contains("needs at least 8"));
    // Enough steps but no spins: the location errors are named as unidentifiable.
    let statics = Schedule::new("statics", cfg.schedule.steps()[..12].to_vec()).unwrap();
    let sim = LogSimulation { schedule: &statics, ..sim };
    let err = fit_baseline(&sim.run(&mut gfcal::rng::trial_rng(1, 0)), &cfg.array, &cfg.errors.nominal, Form::Triad, G)
        .unwrap_err();
    assert!(err.to_string().contains("cannot identify") && err.to_string().contains("a1.dx"), "{err}");
    let _ = Array::cube(0.1);
}

mod diagnosis {
    use super::*;
    use gfcal::discrepancy::effect::by_name;
    use gfcal::discrepancy::log::{DiagnoseSettings, Diagnosis, Verdict, diagnose};

    fn effect(name: &str, values: Vec<f64>) -> ActiveEffect {
        ActiveEffect { effect: by_name(name).unwrap(), values }
    }

    fn on(j: usize, v: f64) -> Vec<f64> {
        let mut out = vec![0.0; 6];
        out[j] = v;
        out
    }

    fn run(effects: &[ActiveEffect], temperature: Option<Temperature>, seed: u64) -> Diagnosis {
        let cfg = example();
        let log = simulate(&cfg, effects, white(50.0), temperature, seed);
        diagnose(&log, &cfg.array, &cfg.errors.nominal, &DiagnoseSettings::default()).unwrap()
    }

    fn named(d: &Diagnosis) -> Vec<(String, Option<usize>)> {
        d.findings.iter().map(|f| (f.name.clone(), f.accelerometer)).collect()
    }

    /// The effect is named (with its accelerometer), and the gap falls to what noise explains.
    fn found(d: &Diagnosis, name: &str, accel: Option<usize>) {
        assert!(named(d).contains(&(name.to_string(), accel)), "{name} {accel:?}: named {:?}", named(d));
        assert!(d.p_value_after > 0.01, "{name}: chi2 test still rejects (p = {})", d.p_value_after);
        assert!(!d.unmodelled_effect_remains);
        // The gap falls. (A small effect can hide in the overall chi-square, as the cubic term does
        // at 1.4 per dof, and still be found by its targeted likelihood-ratio test.)
        assert!(d.gap_after < d.gap_before && d.gap_after < 1.5, "{name}: gap {} -> {}", d.gap_before, d.gap_after);
    }

    const G0: f64 = 9.80665;
    const RAMP: Option<Temperature> =
        Some(Temperature { start_c: 15.0, end_c: 35.0, reference_c: 25.0, wobble_c: 0.0, wobble_period_s: 1.0 });
    /// The same ramp with a 3 degC wobble of period 40 s: temperature no longer follows time.
    const WOBBLE: Option<Temperature> =
        Some(Temperature { start_c: 15.0, end_c: 35.0, reference_c: 25.0, wobble_c: 3.0, wobble_period_s: 40.0 });

    #[test]
    fn each_identifiable_effect_is_named_and_the_gap_closes() {
        // Realistic magnitudes: 300 ug/g^2, 100 ug/g^3, 1 ug/s, 20 ppm/degC, 0.05 deg poses.
        let d = run(&[effect("scale_factor_quadratic", on(2, 300e-6 / G0))], None, 3);
        found(&d, "scale_factor_quadratic", Some(2));
        let f = &d.findings[0];
        assert!((f.value[0] - 300e-6 / G0).abs() < 4.0 * f.sigma[0], "{f:?}");
        found(&run(&[effect("scale_factor_cubic", on(1, 100e-6 / (G0 * G0)))], None, 4), "scale_factor_cubic", Some(1));
        // 0.5 ug/s over a 150 s log is at the detection limit; 1 ug/s (a MEMS warm-up drift) is not.
        found(&run(&[effect("bias_time_drift", on(4, 1.0 * M_S2_PER_UG))], None, 5), "bias_time_drift", Some(4));
        found(&run(&[effect("scale_factor_temperature", on(3, 20e-6))], RAMP, 6), "scale_factor_temperature", Some(3));
        // A temperature-driven bias needs a log whose temperature does not just follow time.
        let d = run(&[effect("bias_temperature", on(1, 10.0 * M_S2_PER_UG))], WOBBLE, 13);
        found(&d, "bias_temperature", Some(1));
        assert!(d.findings[0].confounded_with.is_none(), "{:?}", d.findings[0]);
        let poses: Vec<f64> = (0..24).map(|i| 0.05f64.to_radians() * ((i as f64 * 0.7).sin())).collect();
        found(&run(&[effect("pose_misalignment", poses)], None, 7), "pose_misalignment", None);
    }

    #[test]
    fn two_hidden_effects_are_both_named() {
        let d = run(
            &[
                effect("scale_factor_quadratic", on(2, 300e-6 / G0)),
                effect("bias_time_drift", on(4, 1.0 * M_S2_PER_UG)),
            ],
            None,
            8,
        );
        let n = named(&d);
        assert!(
            n.contains(&("scale_factor_quadratic".into(), Some(2))) && n.contains(&("bias_time_drift".into(), Some(4))),
            "{n:?}"
        );
        assert_eq!(n.len(), 2, "{n:?}");
        assert!(d.p_value_after > 0.01);
    }

    /// The procedure names an effect at a nominal 1% rate on a clean log. Of 100 clean logs,
    /// Binomial(100, 0.01) gives 4 or more false alarms with probability 1.8%: at least 97 quiet.
    #[test]
    fn clean_logs_name_nothing_in_97_of_100_seeds() {
        let quiet = (0..100).filter(|&seed| run(&[], None, 1000 + seed).findings.is_empty()).count();
        assert!(quiet >= 97, "{quiet} of 100 clean logs named nothing");
    }

    /// Issue 11, item 6: a bias that follows a temperature varying *within* steps (a 3 degC
    /// wobble of period 4 s inside 10 s steps) was first named `bias_instability`, then
    /// `bias_temperature`. Deterministic within-step regressors are tried before within-step
    /// scatter is called correlated noise: only `bias_temperature` is named.
    #[test]
    fn a_bias_following_the_temperature_within_steps_is_not_called_correlated_noise() {
        let fast =
            Some(Temperature { start_c: 15.0, end_c: 35.0, reference_c: 25.0, wobble_c: 3.0, wobble_period_s: 4.0 });
        let d = run(&[effect("bias_temperature", on(1, 20.0 * M_S2_PER_UG))], fast, 14);
        assert_eq!(named(&d), vec![("bias_temperature".to_string(), Some(1))], "{:?}", named(&d));
        let f = &d.findings[0];
        assert!((f.value[0] - 20.0 * M_S2_PER_UG).abs() < 4.0 * f.sigma[0], "{f:?}");
        assert!(d.p_value_after > 0.01, "{} -> {}", d.gap_before, d.gap_after);
    }

    /// Issue 11, item 6: a log hiding an effect outside the library (a bias that jumps by 300 ug
    /// on accelerometer 3 halfway through the log, as after a shock) gets no sigma-less finding, a
    /// held-out error that is a number or absent, and is reported as a partial explanation.
    #[test]
    #[ignore = "slow: about 4 minutes (one diagnosis whose forward selection never closes the gap, each round cross-validated); run with --ignored (docs/testing.md)"]
    fn an_effect_outside_the_library_is_reported_as_a_partial_explanation() {
        let cfg = example();
        let mut log = simulate(&cfg, &[], white(50.0), None, 15);
        let (n, k3) = (log.n, cfg.errors.truth.sensors[2].scale_factor);
        let half = log.steps.len() / 2;
        for st in &mut log.steps[half..] {
            for v in st.outputs.iter_mut().skip(2).step_by(n) {
                *v += k3 * 300.0 * M_S2_PER_UG;
            }
        }
        let d = diagnose(&log, &cfg.array, &cfg.errors.nominal, &DiagnoseSettings::default()).unwrap();
        for f in &d.findings {
            assert!(f.sigma.iter().all(|s| s.is_finite() && *s > 0.0), "a finding without a sigma: {f:?}");
            // Determined as a whole: no parameter's sigma exceeds the largest value it was named with
            // (before the fix, a 24-parameter pose effect was named at 0.08 rad +- 27 rad).
            let largest = f.value.iter().fold(0.0f64, |m, v| m.max(v.abs()));
            assert!(f.sigma.iter().all(|s| *s < largest), "{f:?}");
        }
        for h in [d.held_out_before, d.held_out_after].into_iter().flatten() {
            assert!(h.is_finite(), "held-out error {h}");
        }
        // The jump is not in the library: what is left stays above the noise at the test's level.
        assert!(d.unmodelled_effect_remains, "gap {} -> {} (p {})", d.gap_before, d.gap_after, d.p_value_after);
        assert_eq!(d.explanation(), gfcal::discrepancy::Explanation::Partial, "{:?}", named(&d));
    }

    /// Issue 11, item 6: a temperature column that never changes is said to be constant, not
    /// given NaN correlations.
    #[test]
    fn a_constant_temperature_column_is_named_constant() {
        let cfg = example();
        let mut log = simulate(&cfg, &[], white(50.0), Some(Temperature::ramp(21.5, 21.5, 25.0)), 16);
        assert!(log.has_temperature());
        log.steps.iter_mut().for_each(|s| s.temp_c.iter_mut().for_each(|t| *t = 21.5));
        let d = diagnose(&log, &cfg.array, &cfg.errors.nominal, &DiagnoseSettings::default()).unwrap();
        let rows = gfcal::discrepancy::log::regressor_correlations(&log, &cfg.array, &d.baseline, Form::Triad, G);
        for row in &rows {
            match &row.correlation {
                gfcal::discrepancy::log::Correlation::PerAccelerometer(r) => {
                    assert!(r.iter().all(|v| v.is_some_and(f64::is_finite)), "{}: {r:?}", row.regressor)
                }
                gfcal::discrepancy::log::Correlation::Constant(v) => {
                    assert_eq!(row.regressor, "temperature");
                    assert!((v - 21.5).abs() < 1e-12);
                }
            }
        }
        assert!(rows.iter().any(|r| r.regressor == "temperature"
            && matches!(r.correlation, gfcal::discrepancy::log::Correlation::Constant(_))));
        // Through the binary: the printout says it, and neither it nor the JSON carries a NaN.
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("constant.csv");
        log.write(&path).unwrap();
        let json = dir.path().join("d.json");
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_gfcal"))
            .args(["diagnose", path.to_str().unwrap(), "--json", json.to_str().unwrap()])
            .output()
            .unwrap();
        let stdout = String::from_utf8_lossy(&o.stdout);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        assert!(stdout.contains("temperature is constant (21.5 degC)"), "{stdout}");
        assert!(!stdout.to_lowercase().contains("nan"), "{stdout}");
        let body = std::fs::read_to_string(&json).unwrap();
        assert!(body.contains("\"constant_c\": 21.5"), "{body}");
    }

    #[test]
    fn effects_the_log_cannot_separate_are_reported_as_confounded() {
        // With a linear temperature ramp, a temperature-driven bias is a time drift: whichever is
        // named, the other is reported as confounded with it.
        let d = run(&[effect("bias_temperature", on(1, 10.0 * M_S2_PER_UG))], RAMP, 9);
        assert_eq!(d.findings.len(), 1, "{:?}", named(&d));
        let f = &d.findings[0];
        assert_eq!(f.accelerometer, Some(1));
        let pair = [f.name.as_str(), f.confounded_with.as_deref().unwrap_or("")].join(" | ");
        assert!(
            pair == "bias_temperature | bias_time_drift (accelerometer 2)"
                || pair == "bias_time_drift | bias_temperature (accelerometer 2)",
            "{pair}"
        );
        // A spin-rate error rescales every position: the location errors absorb it, nothing is
        // named, and the verdict says what it is confounded with.
        let d = run(&[effect("spin_rate_error", vec![500e-6])], None, 10);
        assert!(d.findings.is_empty(), "{:?}", named(&d));
        let v = d.verdicts.iter().find(|(l, _)| l == "spin_rate_error").unwrap();
        let Verdict::ConfoundedWithModel(with) = &v.1 else { panic!("{v:?}") };
        assert!(with.iter().all(|w| w.contains(".d")), "{with:?}");
        // Gravity magnitude: the scale factors absorb it.
        let d = run(&[effect("gravity_magnitude", vec![300e-6])], None, 11);
        assert!(d.findings.is_empty());
        let v = d.verdicts.iter().find(|(l, _)| l == "gravity_magnitude").unwrap();
        assert!(
            matches!(&v.1, Verdict::ConfoundedWithModel(w) if w.iter().any(|n| n.ends_with("scale_factor"))),
            "{v:?}"
        );
    }
}

#[test]
fn bias_instability_is_named_from_the_allan_variance() {
    use gfcal::discrepancy::log::{DiagnoseSettings, diagnose};
    use gfcal::sensor::noise::GaussMarkov;
    let cfg = example();
    // 100 ug first-order Gauss-Markov with a 0.2 s correlation time over 20 ug/sqrt(Hz) white
    // noise. The test sees correlated noise whose correlation time is well inside a step (10 s);
    // noise correlated over longer acts as a bias per step and shows only in the gap.
    let noise = NoiseSpec {
        gauss_markov: Some(GaussMarkov { sigma_m_s2: 100.0 * M_S2_PER_UG, correlation_time_s: 0.2 }),
        ..white(20.0)
    };
    let log = simulate(&cfg, &[], noise, None, 12);
    let d = diagnose(&log, &cfg.array, &cfg.errors.nominal, &DiagnoseSettings::default()).unwrap();
    let named: Vec<_> = d.findings.iter().map(|f| (f.name.as_str(), f.accelerometer)).collect();
    for j in 0..6 {
        assert!(named.contains(&("bias_instability", Some(j))), "{named:?}");
    }
    assert!(named.iter().all(|n| n.0 == "bias_instability"), "{named:?}");
    assert!(d.p_value_after > 0.01, "{} -> {} (p {})", d.gap_before, d.gap_after, d.p_value_after);
    // White noise alone: no Allan excess is named (also checked over 100 seeds by the clean-log test).
    let clean = diagnose(
        &simulate(&cfg, &[], white(20.0), None, 12),
        &cfg.array,
        &cfg.errors.nominal,
        &DiagnoseSettings::default(),
    )
    .unwrap();
    assert!(clean.findings.is_empty());
}

/// Every effect's generator in the simulator's truth model (which changes the physical motion or
/// sensor) against its fitted term (its first-order model), in a static pose and in a spin: the
/// two agree to second order in the effect's size. The simulated logs take their truth from the
/// generators, so a detection test no longer fits the term that made its data (issue 12).
#[test]
fn every_effects_generator_agrees_with_its_term_to_first_order() {
    use gfcal::discrepancy::effect::TruthSample;
    let axis = Vector3::new(0.7, 0.1, 0.71);
    let position_m = Vector3::new(0.0, -0.1, 0.001);
    let cases = [
        (Some(3), None, Vector3::new(0.6, 0.0, 0.8), Vector3::zeros()),
        (None, Some(1), Vector3::new(0.0, 0.0, -1.0), Vector3::new(0.3, 6.0, 1.0)),
    ];
    for (static_index, spin_index, up_b, omega_b_rad_s) in cases {
        let base = TruthSample {
            static_index,
            spin_index,
            t_s: 37.5,
            temp_delta_c: 4.2,
            up_b,
            omega_b_rad_s,
            g_m_s2: G,
            position_m,
            bias_m_s2: 0.01,
            gain: 1.0,
            quadratic_per_m_s2: 0.0,
            cubic_per_m2_s4: 0.0,
        };
        let w = omega_b_rad_s;
        let ctx = SampleContext {
            step: 4,
            static_index,
            spin_index,
            t_s: base.t_s,
            temp_delta_c: base.temp_delta_c,
            u_m_s2: base.reading_m_s2(&axis) - base.bias_m_s2,
            axis,
            position_m,
            up_b,
            w2: w * w.transpose() - Matrix3::identity() * w.norm_squared(),
            g_m_s2: G,
        };
        for effect in library() {
            let m = effect.parameters(12, 3);
            // Sizes that make each effect about 1e-3 of the reading.
            let scale = match effect.name() {
                "scale_factor_quadratic" => 1e-4,
                "scale_factor_cubic" => 1e-5,
                "spin_axis_offset" => 1e-4,
                "bias_time_drift" => 1e-5,
                _ => 1e-3,
            };
            let p: Vec<f64> = (0..m).map(|i| scale * (1.0 + 0.37 * i as f64)).collect();
            let mut generated = base;
            effect.generate(&mut generated, &p);
            let from_generator = generated.reading_m_s2(&axis) - base.reading_m_s2(&axis);
            let from_term = effect.term(&ctx, &p, &mut vec![0.0; m]);
            let tolerance = 2e-3 * from_term.abs() + 1e-12;
            assert!(
                (from_generator - from_term).abs() <= tolerance,
                "{} ({}): generator {from_generator:e}, term {from_term:e}",
                effect.name(),
                if static_index.is_some() { "static" } else { "spin" }
            );
        }
    }
}

/// Issue 13: logs as labs write them. The same log as Parquet with every codec pyarrow writes
/// (none, snappy, gzip, lz4, lz4_raw, brotli, zstd), `step` as Int32, outputs as Float32 and a
/// pandas index column; and as CSV with a byte-order mark, CRLF line ends and quoted headers. All
/// read as the original (outputs within Float32 precision).
#[test]
fn logs_as_labs_write_them_are_read() {
    use arrow_array::{ArrayRef, Float32Array, Float64Array, Int32Array, Int64Array, RecordBatch};
    use parquet::arrow::ArrowWriter;
    use parquet::basic::{BrotliLevel, Compression, GzipLevel, ZstdLevel};
    use parquet::file::properties::WriterProperties;
    use std::sync::Arc;

    let cfg = example();
    let log = simulate(&cfg, &[], white(50.0), None, 3);
    let dir = tempfile::tempdir().unwrap();
    let csv = dir.path().join("log.csv");
    log.write(&csv).unwrap();
    let table = gfcal::io::table::Table::read(&csv).unwrap();
    let rows = table.rows();
    let columns: Vec<(String, ArrayRef)> = std::iter::once((
        "__index_level_0__".to_string(),
        Arc::new(Int64Array::from_iter_values(0..rows as i64)) as ArrayRef,
    ))
    .chain(table.names.iter().zip(&table.data).map(|(name, data)| {
        let array: ArrayRef = if name == "step" {
            Arc::new(Int32Array::from_iter_values(data.iter().map(|v| *v as i32)))
        } else if name.starts_with('s') {
            Arc::new(Float32Array::from_iter_values(data.iter().map(|v| *v as f32)))
        } else {
            Arc::new(Float64Array::from(data.clone()))
        };
        (name.clone(), array)
    }))
    .collect();
    let batch = RecordBatch::try_from_iter(columns).unwrap();
    let same = |read: &CalibrationLog, what: &str| {
        assert_eq!(read.steps.len(), log.steps.len(), "{what}");
        for (a, b) in read.steps.iter().zip(&log.steps) {
            assert_eq!(a.step, b.step, "{what}");
            assert_eq!(a.t_s, b.t_s, "{what}");
            for (x, y) in a.outputs.iter().zip(&b.outputs) {
                assert!((x - y).abs() <= 1e-6 * y.abs().max(1.0), "{what}: {x} against {y}");
            }
        }
    };
    for (name, codec) in [
        ("none", Compression::UNCOMPRESSED),
        ("snappy", Compression::SNAPPY),
        ("gzip", Compression::GZIP(GzipLevel::default())),
        ("lz4", Compression::LZ4),
        ("lz4_raw", Compression::LZ4_RAW),
        ("brotli", Compression::BROTLI(BrotliLevel::default())),
        ("zstd", Compression::ZSTD(ZstdLevel::default())),
    ] {
        let path = dir.path().join(format!("log_{name}.parquet"));
        let props = WriterProperties::builder().set_compression(codec).build();
        let mut w = ArrowWriter::try_new(std::fs::File::create(&path).unwrap(), batch.schema(), Some(props)).unwrap();
        w.write(&batch).unwrap();
        w.close().unwrap();
        same(&CalibrationLog::read(&path, 6).unwrap_or_else(|e| panic!("{name}: {e}")), name);
    }
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    let header = lines.next().unwrap().split(',').map(|h| format!("\"{h}\"")).collect::<Vec<_>>().join(",");
    let lab = format!("\u{feff}{header}\r\n") + &lines.map(|l| format!("{l}\r\n")).collect::<String>();
    let lab_path = dir.path().join("lab.csv");
    std::fs::write(&lab_path, lab).unwrap();
    same(&CalibrationLog::read(&lab_path, 6).unwrap(), "CSV with BOM, CRLF and quoted headers");
}
