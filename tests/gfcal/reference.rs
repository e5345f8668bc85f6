//! The independent reference case (`../shared/reference/hung_lee_2006_case.json`) and the paper's
//! own tables.

use approx::assert_relative_eq;
use gfcal::array::Array;
use gfcal::config::drift::DriftConfig;
use gfcal::motion::RigidMotion;

use crate::common::{f, reference, reference_truth, vec3};

#[test]
fn reference_outputs_reproduced_to_1e12_relative() {
    let r = reference();
    let g = f(&r["conventions"]["g_m_s2"]);
    let cube = Array::cube(f(&r["conventions"]["rho_m"])).unwrap();
    let truth = reference_truth(&cube, &r);
    let steps = r["steps"].as_array().unwrap();
    assert_eq!(steps.len(), 15, "12 static positions and 3 spins");
    for step in steps {
        let motion = RigidMotion::spinning(&vec3(&step["omega_rad_s"]), &vec3(&step["up"]), g);
        let mut out = [0.0; 6];
        truth.outputs(&cube, &motion, &mut out);
        for (j, o) in out.iter().enumerate() {
            let expected = f(&step["outputs"][j]);
            let rel = (o - expected).abs() / expected.abs();
            assert!(rel < 1e-12, "{} accelerometer {}: {o} vs {expected} ({rel:e})", step["name"], j + 1);
        }
    }
}

#[test]
fn true_axes_and_positions_match_reference() {
    let r = reference();
    let cube = Array::cube(0.1).unwrap();
    let truth = reference_truth(&cube, &r);
    let positions = truth.positions_m(&cube);
    for j in 0..6 {
        let axis = vec3(&r["true_parameters"]["true_axes_unnormalised"][j]);
        assert_relative_eq!(truth.sensors[j].axis, axis, epsilon = 1e-15);
        let pos = vec3(&r["true_parameters"]["true_positions_m"][j]);
        assert_relative_eq!(positions[j], pos, epsilon = 1e-15);
        let nominal = vec3(&r["nominal_axes"][j]);
        assert_relative_eq!(cube.accelerometers()[j].axis, nominal, epsilon = 1e-15);
    }
}

#[test]
fn paper_config_holds_the_reference_parameters() {
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("configs/paper_manoeuvre.toml");
    let cfg = DriftConfig::load(&path).unwrap();
    let truth = reference_truth(&cfg.array, &reference());
    for (ours, theirs) in cfg.errors.truth.sensors.iter().zip(&truth.sensors) {
        assert_relative_eq!(ours.scale_factor, theirs.scale_factor, max_relative = 1e-15);
        assert_relative_eq!(ours.bias_m_s2, theirs.bias_m_s2, max_relative = 1e-15);
        assert_relative_eq!(ours.axis, theirs.axis, epsilon = 1e-15);
        assert_relative_eq!(ours.location_error_m, theirs.location_error_m, epsilon = 1e-15);
    }
}

#[test]
fn static_outputs_flip_sign_with_gravity_except_bias() {
    // Up and down along the same direction: the sum of the two readings is 2 k b exactly
    // (Hung & Lee 2006, Tables 3-4 rely on this to separate bias).
    let r = reference();
    let cube = Array::cube(0.1).unwrap();
    let truth = reference_truth(&cube, &r);
    let steps = r["steps"].as_array().unwrap();
    for pair in steps[..12].chunks(2) {
        for (j, s) in truth.sensors.iter().enumerate() {
            let sum = f(&pair[0]["outputs"][j]) + f(&pair[1]["outputs"][j]);
            assert_relative_eq!(sum, 2.0 * s.scale_factor * s.bias_m_s2, max_relative = 1e-9);
        }
    }
}
