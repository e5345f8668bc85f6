//! The mechanization derived from geometry against the paper's S and T (eq. 3-4), and the rank test.

use approx::assert_relative_eq;
use gfcal::array::{Array, ArrayError, Mechanization};
use nalgebra::{DMatrix, Vector3};

use crate::common::{f, reference};

fn matrix(v: &serde_json::Value) -> DMatrix<f64> {
    let rows = v.as_array().unwrap();
    DMatrix::from_fn(rows.len(), rows[0].as_array().unwrap().len(), |i, j| f(&rows[i][j]))
}

#[test]
fn cube_solve_is_papers_s_over_2rho_and_t_over_2() {
    let r = reference();
    let p = Array::cube(0.1).unwrap().mechanization().pseudo_inverse();
    let s = matrix(&r["paper_S_over_2rho"]);
    let t = matrix(&r["paper_T_over_2"]);
    assert_relative_eq!(p.rows(0, 3).into_owned(), s, epsilon = 1e-12);
    assert_relative_eq!(p.rows(3, 3).into_owned(), t, epsilon = 1e-12);
}

#[test]
fn cube_solve_scales_as_one_over_rho() {
    // S/(2 rho) with rho = 0.05: the angular rows double, the linear rows do not change.
    let p1 = Array::cube(0.1).unwrap().mechanization().pseudo_inverse();
    let p2 = Array::cube(0.05).unwrap().mechanization().pseudo_inverse();
    assert_relative_eq!(p2.rows(0, 3).into_owned(), p1.rows(0, 3) * 2.0, epsilon = 1e-12);
    assert_relative_eq!(p2.rows(3, 3).into_owned(), p1.rows(3, 3).into_owned(), epsilon = 1e-12);
}

#[test]
fn cube_centripetal_term_is_papers_rho_products() {
    // -(T/2) c, c_j = theta_j . (w x (w x r_j)), equals rho [wy wz, wx wz, wx wy] (eq. 3).
    let rho = 0.1;
    let cube = Array::cube(rho).unwrap();
    let m = cube.mechanization();
    let t_over_2 = m.pseudo_inverse().rows(3, 3).into_owned();
    for w in [Vector3::new(1.0, 2.0, 3.0), Vector3::new(-0.3, 7.0, 0.2), Vector3::new(5.0, -4.0, -6.0)] {
        let mut c = vec![0.0; 6];
        m.centripetal_m_s2(&w, &mut c);
        let lhs = -(&t_over_2 * nalgebra::DVector::from_vec(c));
        let rhs = Vector3::new(w.y * w.z, w.x * w.z, w.x * w.y) * rho;
        assert_relative_eq!(Vector3::new(lhs[0], lhs[1], lhs[2]), rhs, epsilon = 1e-12);
    }
}

#[test]
fn solve_inverts_the_array_for_any_motion() {
    // Readings of an ideal cube for a known motion give that motion back (with the same omega, g).
    let cube = Array::cube(0.1).unwrap();
    let motion = gfcal::motion::RigidMotion {
        accel_b_m_s2: Vector3::new(1.0, -2.0, 0.5),
        alpha_b_rad_s2: Vector3::new(0.3, 0.1, -0.7),
        omega_b_rad_s: Vector3::new(2.0, -1.0, 0.5),
        gravity_b_m_s2: Vector3::new(0.0, 3.0, -9.0),
    };
    let params = gfcal::sensor::ArrayParams::nominal(&cube);
    let mut out = [0.0; 6];
    params.outputs(&cube, &motion, &mut out);
    let acc = cube.mechanization().solve(&out, &motion.omega_b_rad_s, &motion.gravity_b_m_s2);
    assert_relative_eq!(acc.alpha_b_rad_s2, motion.alpha_b_rad_s2, epsilon = 1e-12);
    assert_relative_eq!(acc.accel_b_m_s2, motion.accel_b_m_s2, epsilon = 1e-12);
}

fn cube_layout() -> (Vec<Vector3<f64>>, Vec<Vector3<f64>>) {
    let cube = Array::cube(0.1).unwrap();
    (cube.positions_m(), cube.axes())
}

#[test]
fn radial_axes_cannot_see_angular_acceleration() {
    // Every axis along its position vector: r x theta = 0, so no angular acceleration is sensed.
    let (positions, _) = cube_layout();
    let axes: Vec<_> = positions.iter().map(|p| p.normalize()).collect();
    let err = Mechanization::new(&positions, &axes).unwrap_err();
    assert_eq!(err.unseen.len(), 3, "{err}");
    let msg = err.to_string();
    assert!(msg.contains("3 independent motions") && msg.contains("angular acceleration about"), "{msg}");
}

#[test]
fn all_axes_vertical_cannot_see_horizontal_acceleration() {
    let (positions, _) = cube_layout();
    let axes = vec![Vector3::z(); 6];
    let err = Array::new("vertical", &positions, &axes, vec![]).unwrap_err();
    let ArrayError::Degenerate(rank) = &err else { panic!("expected a rank error, got {err}") };
    assert!(rank.unseen.len() >= 2, "{err}");
    // Every unseen motion reads zero on every accelerometer.
    let m = rank.unseen.iter().map(|v| {
        let mut worst: f64 = 0.0;
        for (p, a) in positions.iter().zip(&axes) {
            let alpha = Vector3::new(v[0], v[1], v[2]);
            let acc = Vector3::new(v[3], v[4], v[5]);
            worst = worst.max((a.dot(&acc) + p.cross(a).dot(&alpha)).abs());
        }
        worst
    });
    assert!(m.fold(0.0, f64::max) < 1e-12);
    assert!(err.to_string().starts_with("degenerate array: the accelerometers cannot sense"), "{err}");
}

#[test]
fn single_unseen_motion_is_named() {
    // Every axis lies in the x-y plane: nothing senses linear acceleration along z.
    let positions = vec![
        Vector3::new(0.1, 0.0, 0.0),
        Vector3::new(-0.1, 0.0, 0.0),
        Vector3::new(0.0, 0.1, 0.0),
        Vector3::new(0.0, -0.1, 0.0),
        Vector3::new(0.0, 0.0, 0.1),
        Vector3::new(0.0, 0.0, -0.1),
    ];
    let axes = vec![
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(1.0, 0.0, 0.0),
        Vector3::new(0.0, 1.0, 0.0),
    ];
    let err = Mechanization::new(&positions, &axes).unwrap_err();
    let msg = err.to_string();
    assert!(msg.contains("linear acceleration along z"), "{msg}");
}

#[test]
fn too_few_accelerometers_are_refused() {
    let (positions, axes) = cube_layout();
    let err = Array::new("five", &positions[..5], &axes[..5], vec![]).unwrap_err();
    assert_eq!(err, ArrayError::TooFew { count: 5 });
}

#[test]
fn zero_axis_is_refused() {
    let (positions, mut axes) = cube_layout();
    axes[3] = Vector3::zeros();
    assert_eq!(Array::new("zero", &positions, &axes, vec![]).unwrap_err(), ArrayError::ZeroAxis { index: 4 });
}
