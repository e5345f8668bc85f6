//! The two misalignment forms: exact conversions, unit axes, identical outputs.

use approx::assert_relative_eq;
use gfcal::array::Array;
use gfcal::motion::RigidMotion;
use gfcal::sensor::misalignment::{
    Misalignment, TriadAngles, tilt_angles_all, tilt_basis, to_triad_axes, to_unit_axes, triad_angles,
};
use gfcal::sensor::{ArrayParams, SensorParams};
use nalgebra::Vector3;
use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

fn random_triads(rng: &mut ChaCha8Rng, scale_rad: f64) -> Vec<TriadAngles> {
    (0..2)
        .map(|_| {
            let mut a = || scale_rad * (2.0 * rng.random::<f64>() - 1.0);
            TriadAngles { xy_rad: a(), xz_rad: a(), yx_rad: a(), yz_rad: a(), zx_rad: a(), zy_rad: a() }
        })
        .collect()
}

fn params_with_axes(rng: &mut ChaCha8Rng, axes: &[Vector3<f64>]) -> ArrayParams {
    ArrayParams {
        sensors: axes
            .iter()
            .map(|a| SensorParams {
                scale_factor: 0.5 + 2.0 * rng.random::<f64>(),
                bias_m_s2: 0.02 * (rng.random::<f64>() - 0.5),
                axis: *a,
                location_error_m: Vector3::new(rng.random(), rng.random(), rng.random()) * 1e-3,
            })
            .collect(),
    }
}

#[test]
fn triad_form_round_trips_through_tilt_form() {
    let cube = Array::cube(0.1).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    for _ in 0..50 {
        let angles = random_triads(&mut rng, 0.05);
        let axes = Misalignment::Triad(angles.clone()).axes(&cube).unwrap();
        let triad = params_with_axes(&mut rng, &axes);
        let unit = to_unit_axes(&triad);
        for s in &unit.sensors {
            assert_relative_eq!(s.axis.norm(), 1.0, epsilon = 1e-15);
        }
        // Tilt angles from the unit form rebuild the same unit axes.
        let tilts = tilt_angles_all(&cube, &unit);
        let rebuilt = Misalignment::Tilt(tilts).axes(&cube).unwrap();
        for (a, b) in rebuilt.iter().zip(&unit.sensors) {
            assert_relative_eq!(*a, b.axis, epsilon = 1e-15);
        }
        // Back to the triad form: the same angles, scale factors and biases.
        let back = to_triad_axes(&cube, &unit).unwrap();
        for (a, b) in back.sensors.iter().zip(&triad.sensors) {
            assert_relative_eq!(a.scale_factor, b.scale_factor, max_relative = 1e-14);
            assert_relative_eq!(a.bias_m_s2, b.bias_m_s2, epsilon = 1e-16, max_relative = 1e-13);
            assert_relative_eq!(a.axis, b.axis, epsilon = 1e-15);
        }
        let got = triad_angles(&cube, &unit).unwrap();
        for (g, e) in got.iter().zip(&angles) {
            for (x, y) in [
                (g.xy_rad, e.xy_rad),
                (g.xz_rad, e.xz_rad),
                (g.yx_rad, e.yx_rad),
                (g.yz_rad, e.yz_rad),
                (g.zx_rad, e.zx_rad),
                (g.zy_rad, e.zy_rad),
            ] {
                assert_relative_eq!(x, y, epsilon = 1e-15);
            }
        }
    }
}

#[test]
fn tilt_form_round_trips_through_triad_form() {
    let cube = Array::cube(0.1).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for _ in 0..50 {
        let tilts: Vec<[f64; 2]> =
            (0..6).map(|_| [0.05 * (rng.random::<f64>() - 0.5), 0.05 * (rng.random::<f64>() - 0.5)]).collect();
        let axes = Misalignment::Tilt(tilts.clone()).axes(&cube).unwrap();
        let unit = params_with_axes(&mut rng, &axes);
        let triad = to_triad_axes(&cube, &unit).unwrap();
        let back = to_unit_axes(&triad);
        let got = tilt_angles_all(&cube, &back);
        for (j, (g, e)) in got.iter().zip(&tilts).enumerate() {
            assert_relative_eq!(g[0], e[0], epsilon = 1e-15);
            assert_relative_eq!(g[1], e[1], epsilon = 1e-15);
            assert_relative_eq!(back.sensors[j].scale_factor, unit.sensors[j].scale_factor, max_relative = 1e-14);
            assert_relative_eq!(back.sensors[j].axis.norm(), 1.0, epsilon = 1e-15);
        }
    }
}

#[test]
fn both_forms_give_the_same_outputs() {
    let cube = Array::cube(0.1).unwrap();
    let mut rng = ChaCha8Rng::seed_from_u64(3);
    let axes = Misalignment::Triad(random_triads(&mut rng, 0.02)).axes(&cube).unwrap();
    let triad = params_with_axes(&mut rng, &axes);
    let unit = to_unit_axes(&triad);
    let motion = RigidMotion {
        accel_b_m_s2: Vector3::new(1.0, 2.0, -3.0),
        alpha_b_rad_s2: Vector3::new(0.4, -0.2, 0.1),
        omega_b_rad_s: Vector3::new(3.0, 1.0, -2.0),
        gravity_b_m_s2: Vector3::new(0.0, 0.0, -9.8),
    };
    let (mut a, mut b) = ([0.0; 6], [0.0; 6]);
    triad.outputs(&cube, &motion, &mut a);
    unit.outputs(&cube, &motion, &mut b);
    for (x, y) in a.iter().zip(&b) {
        assert_relative_eq!(x, y, max_relative = 1e-14);
    }
}

#[test]
fn triad_form_couples_misalignment_with_scale_factor() {
    // physics.md: theta_2 . theta_3 = 1/2, so tilting accelerometer 2 toward 3 by d lengthens its
    // axis to sqrt(1 + d + d^2): the unit form's scale factor absorbs that length.
    let cube = Array::cube(0.1).unwrap();
    let d = 0.01;
    let angles = vec![TriadAngles::default(), TriadAngles { xz_rad: d, ..TriadAngles::default() }];
    let axes = Misalignment::Triad(angles).axes(&cube).unwrap();
    assert_relative_eq!(axes[1].norm(), (1.0 + d + d * d).sqrt(), epsilon = 1e-15);
    // The tilt of that axis is the angle between theta_2 and theta_2 + d theta_3.
    let unit = to_unit_axes(&ArrayParams {
        sensors: axes
            .iter()
            .map(|a| SensorParams { scale_factor: 1.0, bias_m_s2: 0.0, axis: *a, location_error_m: Vector3::zeros() })
            .collect(),
    });
    let t = tilt_angles_all(&cube, &unit)[1];
    let nominal = cube.accelerometers()[1].axis;
    let angle = nominal.cross(&axes[1]).norm().atan2(nominal.dot(&axes[1]));
    assert_relative_eq!(t[0].hypot(t[1]), angle, epsilon = 1e-15);
    assert_relative_eq!(unit.sensors[1].scale_factor, (1.0 + d + d * d).sqrt(), epsilon = 1e-15);
}

#[test]
fn tilt_basis_is_orthonormal_and_orthogonal_to_the_axis() {
    for a in Array::cube(0.1).unwrap().axes() {
        let (u, w) = tilt_basis(&a);
        assert_relative_eq!(u.norm(), 1.0, epsilon = 1e-15);
        assert_relative_eq!(w.norm(), 1.0, epsilon = 1e-15);
        assert!(u.dot(&a).abs() < 1e-15 && w.dot(&a).abs() < 1e-15 && u.dot(&w).abs() < 1e-15);
    }
}
