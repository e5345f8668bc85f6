//! Navigation against analytic truth (the paper's manoeuvre), the growth laws of Fig. 3-4, and
//! the noise floor of rate integration.

use gfcal::array::Array;
use gfcal::nav::SimulatedArray;
use gfcal::nav::drift::attitude_error_rad;
use gfcal::nav::{DriftSample, DriftSetup, InitialState, Segment, Trajectory, drift_study, navigate};
use gfcal::sensor::noise::{NoiseGenerator, NoiseSpec, WhiteNoise};
use gfcal::sensor::{ArrayParams, Compensator};
use gfcal::units::{M_S2_PER_UG, STANDARD_GRAVITY_M_S2 as G};
use nalgebra::{UnitQuaternion, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::common::{reference, reference_truth};

fn setup<'a>(array: &'a Array, truth: &'a ArrayParams, trajectory: &'a Trajectory, step_s: f64) -> DriftSetup<'a> {
    DriftSetup { array, truth, trajectory, noise: NoiseSpec::default(), noise_seed: 0, gravity_m_s2: G, step_s }
}

fn paper_true_drift(step_s: f64) -> DriftSample {
    let cube = Array::cube(0.1).unwrap();
    let truth = reference_truth(&cube, &reference());
    let traj = Trajectory::paper_manoeuvre(10.0);
    drift_study(&setup(&cube, &truth, &traj, step_s), &[("true", &truth)], &[10.0]).unwrap()[0].sample
}

#[test]
fn paper_manoeuvre_with_true_parameters_matches_analytic_truth() {
    let d = paper_true_drift(1e-3);
    assert!(d.rate_err_rad_s < 1e-6, "{d:?}");
    assert!(d.attitude_err_rad < 1e-6, "{d:?}");
    assert!(d.velocity_err_m_s < 1e-6, "{d:?}");
    assert!(d.position_err_m < 1e-6, "{d:?}");
}

#[test]
fn halving_the_step_divides_the_error_by_16() {
    // RK4 is fourth order. The ratio is measured at 20, 10 and 5 ms, where truncation dominates:
    // at 1 ms the attitude error (2e-11 rad) is already within a decade of round-off. The rate,
    // linear in t on this manoeuvre, is integrated exactly by RK4 (round-off only).
    let d: Vec<DriftSample> = [0.02, 0.01, 0.005].iter().map(|&h| paper_true_drift(h)).collect();
    for w in d.windows(2) {
        for (name, a, b) in [
            ("attitude", w[0].attitude_err_rad, w[1].attitude_err_rad),
            ("velocity", w[0].velocity_err_m_s, w[1].velocity_err_m_s),
            ("position", w[0].position_err_m, w[1].position_err_m),
        ] {
            let ratio = a / b;
            assert!((14.0..18.0).contains(&ratio), "{name}: {a:e} / {b:e} = {ratio}");
        }
        assert!(w[0].rate_err_rad_s < 1e-11 && w[1].rate_err_rad_s < 1e-11);
    }
}

fn slope(xs: &[f64], ys: &[f64]) -> f64 {
    let lx: Vec<f64> = xs.iter().map(|x| x.ln()).collect();
    let ly: Vec<f64> = ys.iter().map(|y| y.ln()).collect();
    let n = lx.len() as f64;
    let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
    let sxy: f64 = lx.iter().zip(&ly).map(|(x, y)| (x - mx) * (y - my)).sum();
    let sxx: f64 = lx.iter().map(|x| (x - mx).powi(2)).sum();
    sxy / sxx
}

#[test]
fn one_microg_bias_grows_as_t_t2_t3_t4() {
    // Hung & Lee (2006), Fig. 3-4: a constant error grows as t in rate, t^2 in attitude, t^3 in
    // velocity (and t^4 in position). Accelerometer 1's bias drives angular acceleration about
    // (1, -1, 0): a tilt, so gravity couples the attitude error into velocity.
    let cube = Array::cube(0.1).unwrap();
    let nominal = ArrayParams::nominal(&cube);
    let mut truth = nominal.clone();
    truth.sensors[0].bias_m_s2 = M_S2_PER_UG;
    let horizons = [1.0, 1.5, 2.0, 3.0, 4.0, 6.0, 8.0, 10.0, 15.0, 20.0, 30.0];
    let traj = Trajectory::rest(30.0, UnitQuaternion::identity());
    let rows = drift_study(&setup(&cube, &truth, &traj, 0.01), &[("nominal", &nominal)], &horizons).unwrap();
    let get = |f: fn(&DriftSample) -> f64| rows.iter().map(|r| f(&r.sample)).collect::<Vec<_>>();
    for (name, ys, expected) in [
        ("rate", get(|d| d.rate_err_rad_s), 1.0),
        ("attitude", get(|d| d.attitude_err_rad), 2.0),
        ("velocity", get(|d| d.velocity_err_m_s), 3.0),
        ("position", get(|d| d.position_err_m), 4.0),
    ] {
        let s = slope(&horizons, &ys);
        assert!((s - expected).abs() < 0.1, "{name}: slope {s}, expected {expected}");
    }
    // The rate error is the bias through row 1 of S/(2 rho): 1 ug * 3.5355 / s * t.
    let rate_30 = rows.last().unwrap().sample.rate_err_rad_s;
    let expected = M_S2_PER_UG * (2f64.sqrt() * 3.5355339059327373) * 30.0;
    assert!((rate_30 / expected - 1.0).abs() < 1e-3, "{rate_30:e} vs {expected:e}");
}

#[test]
fn magnus_truth_agrees_with_rk4_navigation_on_tumbling_segments() {
    // Segments whose rate and angular acceleration are not parallel use the Magnus truth; an
    // ideal array navigated by RK4 must agree with it (two independent integrators).
    let cube = Array::cube(0.1).unwrap();
    let params = ArrayParams::nominal(&cube);
    let initial = InitialState {
        q_b_i: UnitQuaternion::from_euler_angles(0.2, -0.1, 0.5),
        omega_b_rad_s: Vector3::new(0.5, -0.3, 1.0),
        v_i_m_s: Vector3::new(1.0, 0.0, 0.0),
        r_i_m: Vector3::zeros(),
    };
    let segments = [
        Segment {
            duration_s: 2.0,
            alpha_b_rad_s2: Vector3::new(0.2, 0.4, -0.1),
            accel_i_m_s2: Vector3::new(0.5, 0.0, 1.0),
        },
        Segment {
            duration_s: 3.0,
            alpha_b_rad_s2: Vector3::new(-0.3, 0.0, 0.6),
            accel_i_m_s2: Vector3::new(0.0, -1.0, 0.0),
        },
    ];
    let traj = Trajectory::new(initial, &segments);
    let rows = drift_study(&setup(&cube, &params, &traj, 1e-3), &[("true", &params)], &[1.0, 2.0, 3.5, 5.0]).unwrap();
    assert_eq!(rows.len(), 4, "one row per horizon, none for the breakpoint");
    for r in &rows {
        let d = r.sample;
        assert!(d.attitude_err_rad < 1e-9 && d.rate_err_rad_s < 1e-9, "{d:?}");
        assert!(d.velocity_err_m_s < 1e-8 && d.position_err_m < 1e-8, "{d:?}");
    }
    // Continuity at the segment boundary.
    let (a, b) = (traj.truth(2.0 - 1e-12), traj.truth(2.0));
    assert!(attitude_error_rad(&a.q_b_i, &b.q_b_i) < 1e-10);
    assert!((a.omega_b_rad_s - b.omega_b_rad_s).norm() < 1e-10);
    assert!((a.r_i_m - b.r_i_m).norm() < 1e-10);
}

#[test]
fn attitude_error_is_accurate_for_tiny_angles() {
    let q = UnitQuaternion::from_euler_angles(0.3, 0.2, -1.0);
    for angle in [1e-12, 1e-9, 1e-6, 0.1, 3.0] {
        let dq = UnitQuaternion::from_scaled_axis(Vector3::new(1.0, 2.0, -2.0).normalize() * angle);
        // Composing q * dq costs ~1e-16 absolute; acos of a trace would lose everything below 1e-8.
        let err = attitude_error_rad(&q, &(q * dq));
        assert!((err - angle).abs() < 1e-15 + 1e-12 * angle, "{angle:e}: {err:e}");
    }
}

#[test]
fn white_noise_rate_error_variance_matches_closed_form() {
    // At rest with white noise of density N on every accelerometer and true compensation, the
    // rate error after T seconds is a random walk: E|d omega|^2 = T N^2 ||P_alpha||_F^2, with
    // P_alpha the angular rows of the solve, whatever the step (noise held over each step, as for
    // outputs averaged over the sample interval).
    let cube = Array::cube(0.1).unwrap();
    let params = ArrayParams::nominal(&cube);
    let density = 1e-4;
    let spec = NoiseSpec { white: WhiteNoise::Density { density_m_s2_per_sqrt_hz: density }, ..NoiseSpec::default() };
    let (t_end, step) = (2.0, 0.01);
    let traj = Trajectory::rest(t_end, UnitQuaternion::identity());
    let gravity = Vector3::new(0.0, 0.0, -G);
    let p = cube.mechanization().pseudo_inverse();
    let expected = t_end * density * density * p.rows(0, 3).iter().map(|v| v * v).sum::<f64>();
    let runs = 2000;
    let mut sum_sq = 0.0;
    for seed in 0..runs {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let generator = NoiseGenerator::new(&spec, 6, 1.0 / step, &mut rng);
        let mut source = SimulatedArray::new(&cube, &params, &traj, gravity).with_noise(generator, rng, 0.0);
        let comp = Compensator::new(&cube, &params).unwrap();
        let d = navigate(&traj, &mut source, &comp, &gravity, step, &[t_end]);
        sum_sq += d[0].rate_err_rad_s.powi(2);
    }
    // |d omega|^2 is a scaled chi-square with 3 degrees of freedom: relative sd of the mean is
    // sqrt(2/3/runs) = 1.8%; allow 4 sigma.
    let ratio = sum_sq / runs as f64 / expected;
    assert!((ratio - 1.0).abs() < 0.075, "mean square / expected = {ratio}");
}

/// Closed forms at rest on the cube (rho = 0.1 m) with white noise of density N on every
/// accelerometer and true compensation (issue 12). The solve's angular rows have
/// `||P_alpha||_F^2 = 1.5 / rho^2 = 150` (50 per axis) and its linear rows `||P_a||_F^2 = 1.5`, and
/// the two are orthogonal on the cube, so with `W` a unit random walk:
/// - rate `d omega = P_alpha W`: `E|d omega(T)|^2 = 150 N^2 T`;
/// - attitude, its integral: `150 N^2 T^3 / 3 = 50 N^2 T^3`;
/// - velocity, gravity through the two horizontal tilt components (100 N^2 of the 150) integrated
///   once more (`g^2 100 N^2 T^5 / 20`) plus the linear rows' noise: `5 g^2 N^2 T^5 + 1.5 N^2 T`;
/// - position, once more: `(100 / 252) g^2 N^2 T^7 + 0.5 N^2 T^3`.
///
/// Each is asserted within 4 standard errors of its Monte Carlo mean (2000 runs; a mean of a
/// 3-degree-of-freedom square has a relative standard error near 1.8%).
#[test]
fn white_noise_drift_at_rest_matches_the_closed_forms() {
    let cube = Array::cube(0.1).unwrap();
    let params = ArrayParams::nominal(&cube);
    let n = 1e-4;
    let spec = NoiseSpec { white: WhiteNoise::Density { density_m_s2_per_sqrt_hz: n }, ..NoiseSpec::default() };
    let (t, step) = (4.0, 0.01);
    let traj = Trajectory::rest(t, UnitQuaternion::identity());
    let gravity = Vector3::new(0.0, 0.0, -G);
    let runs = 2000;
    let mut sq: [Vec<f64>; 4] = Default::default();
    for seed in 0..runs {
        let mut rng = ChaCha8Rng::seed_from_u64(10_000 + seed);
        let generator = NoiseGenerator::new(&spec, 6, 1.0 / step, &mut rng);
        let mut source = SimulatedArray::new(&cube, &params, &traj, gravity).with_noise(generator, rng, 0.0);
        let comp = Compensator::new(&cube, &params).unwrap();
        let d = navigate(&traj, &mut source, &comp, &gravity, step, &[t])[0];
        for (k, v) in
            [d.rate_err_rad_s, d.attitude_err_rad, d.velocity_err_m_s, d.position_err_m].into_iter().enumerate()
        {
            sq[k].push(v * v);
        }
    }
    let n2 = n * n;
    let expected = [
        150.0 * n2 * t,
        50.0 * n2 * t.powi(3),
        5.0 * G * G * n2 * t.powi(5) + 1.5 * n2 * t,
        100.0 / 252.0 * G * G * n2 * t.powi(7) + 0.5 * n2 * t.powi(3),
    ];
    for (k, name) in ["rate", "attitude", "velocity", "position"].iter().enumerate() {
        let m = sq[k].iter().sum::<f64>() / runs as f64;
        let var = sq[k].iter().map(|v| (v - m).powi(2)).sum::<f64>() / (runs - 1) as f64;
        let se = (var / runs as f64).sqrt();
        let z = (m - expected[k]) / se;
        eprintln!("{name}: mean square {m:.4e}, closed form {:.4e}, {z:+.2} standard errors", expected[k]);
        assert!(z.abs() < 4.0, "{name}: mean square {m:e} against {:e} ({z:+.2} standard errors)", expected[k]);
    }
}
