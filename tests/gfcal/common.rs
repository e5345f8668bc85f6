//! Shared test helpers: the reference case of `../shared/reference/`.

use std::path::PathBuf;

use gfcal::array::Array;
use gfcal::sensor::misalignment::{Misalignment, TriadAngles};
use gfcal::sensor::params::{ArrayParams, SensorParams};
use nalgebra::Vector3;
use serde_json::Value;

/// The shared folder: `../shared` beside the repository (as CI lays it out).
pub fn shared_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..").join("shared")
}

pub fn reference() -> Value {
    let path = shared_dir().join("reference").join("hung_lee_2006_case.json");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("cannot read {}: {e}", path.display()));
    serde_json::from_str(&text).expect("reference JSON parses")
}

pub fn f(v: &Value) -> f64 {
    v.as_f64().expect("a number")
}

pub fn vec3(v: &Value) -> Vector3<f64> {
    Vector3::new(f(&v[0]), f(&v[1]), f(&v[2]))
}

pub fn triad_deg(v: &Value) -> TriadAngles {
    let r = |k: &str| f(&v[k]).to_radians();
    TriadAngles { xy_rad: r("xy"), xz_rad: r("xz"), yx_rad: r("yx"), yz_rad: r("yz"), zx_rad: r("zx"), zy_rad: r("zy") }
}

/// The paper's true parameters (Tables 6-7) from the reference file, in the triad form.
pub fn reference_truth(array: &Array, reference: &Value) -> ArrayParams {
    let t = &reference["true_parameters"];
    let mis = &t["misalignment_deg"];
    // Triad A = (1, 4, 6) takes alpha, triad B = (2, 3, 5) beta.
    let axes = Misalignment::Triad(vec![triad_deg(&mis["alpha"]), triad_deg(&mis["beta"])])
        .axes(array)
        .expect("cube has triads");
    let sensors = (0..6)
        .map(|j| SensorParams {
            scale_factor: f(&t["scale_factor"][j]),
            bias_m_s2: f(&t["bias_m_s2"][j]),
            axis: axes[j],
            location_error_m: vec3(&t["location_error_m"][j]),
        })
        .collect();
    ArrayParams { sensors }
}
