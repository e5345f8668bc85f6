//! What an array's geometry cannot see, whatever the recording: the unseen combinations
//! (`selfcal::unseen`) of the Fisher information of a rich synthetic recording of the array
//! (12 poses spread over the sphere, 400 rotation samples of random specific force, angular
//! acceleration and rate), at generic parameters (small random errors, so that a combination that
//! hinges on an exactly nominal value is not taken for the geometry's). `gfcal check` prints it for
//! an array file, and `gfcal calibrate` uses it to say what would make a recording's unseen
//! combinations identifiable.

use nalgebra::{Matrix3, Vector3};
use rand::RngExt;
use rand_distr::StandardNormal;

use super::data::DynamicData;
use super::fit::unseen_at;
use super::model::{PER_ACCEL, SampleMotion, SensorSet};
use super::unseen::Unseen;
use crate::array::Array;

/// Poses and samples of the synthetic recording.
pub const POSES: usize = 12;
pub const SAMPLES: usize = 400;

/// What the geometry cannot see with or without a measured rate.
#[derive(Debug, Clone)]
pub struct GeometryCheck {
    /// The rate is measured (reference gyroscopes, `--use-gyro`).
    pub reference_rate: bool,
    pub null_directions: usize,
    pub gauge_null_directions: usize,
    pub unseen: Unseen,
}

/// The unseen combinations of `array`'s geometry on the synthetic recording (module docs).
pub fn check(array: &Array, reference_rate: bool) -> GeometryCheck {
    let n = array.len();
    let mut rng = crate::rng::trial_rng(30, 0);
    let mut g = |s: f64| -> f64 { s * rng.sample::<f64, _>(StandardNormal) };
    // Poses: the 6 faces and 6 of the 8 corners' directions (any 9 or more in general position do).
    let up: Vec<Vector3<f64>> = [
        [1.0, 0.0, 0.0],
        [-1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
        [0.0, -1.0, 0.0],
        [0.0, 0.0, 1.0],
        [0.0, 0.0, -1.0],
        [1.0, 1.0, 1.0],
        [1.0, -1.0, 1.0],
        [-1.0, 1.0, -1.0],
        [-1.0, -1.0, 1.0],
        [1.0, 1.0, -1.0],
        [-1.0, 1.0, 1.0],
    ]
    .iter()
    .map(|v| Vector3::from(*v).normalize())
    .collect();
    debug_assert_eq!(up.len(), POSES);
    let mut params = SensorSet::nominal(n);
    for j in 0..n {
        params.scale_factor[j] += g(0.01);
        params.bias_m_s2[j] += g(0.05);
        params.tilt_rad[j] = [g(2e-3), g(2e-3)];
        params.location_error_m[j] += Vector3::new(g(2e-4), g(2e-4), g(2e-4));
    }
    let mut v3 = |s: f64| Vector3::new(g(s), g(s), g(s));
    let motion: Vec<SampleMotion> = (0..SAMPLES)
        .map(|_| SampleMotion { f_m_s2: v3(20.0), alpha_rad_s2: v3(300.0), omega_rad_s: v3(10.0) })
        .collect();
    let dynamic = DynamicData {
        t_s: (0..SAMPLES).map(|i| i as f64 * 0.01).collect(),
        outputs: nalgebra::DMatrix::zeros(SAMPLES, n),
        used: vec![true; SAMPLES * n],
        run_starts: vec![0],
        reference_rate_rad_s: reference_rate.then(|| motion.iter().map(|m| m.omega_rad_s).collect()),
        extra_unknowns_per_sample: 0,
    };
    let counts = vec![500; POSES];
    let sigma = vec![0.04; n];
    let (null_directions, gauge, unseen) =
        unseen_at(array, &counts, &sigma, &up, Some(&dynamic), &motion, &params, crate::units::STANDARD_GRAVITY_M_S2);
    GeometryCheck { reference_rate, null_directions, gauge_null_directions: gauge.null_count(), unseen }
}

/// The sensing points' extent along their principal directions, largest first (m, RMS about the
/// centroid), with the directions.
pub fn extent(array: &Array) -> (Vector3<f64>, Matrix3<f64>) {
    let p = array.positions_m();
    let c: Vector3<f64> = p.iter().sum::<Vector3<f64>>() / p.len().max(1) as f64;
    let cov: Matrix3<f64> =
        p.iter().map(|r| (r - c) * (r - c).transpose()).sum::<Matrix3<f64>>() / p.len().max(1) as f64;
    let eig = cov.symmetric_eigen();
    let mut order = [0, 1, 2];
    order.sort_by(|&a, &b| eig.eigenvalues[b].total_cmp(&eig.eigenvalues[a]));
    let values = Vector3::from_fn(|k, _| eig.eigenvalues[order[k]].max(0.0).sqrt());
    let dirs = Matrix3::from_fn(|r, k| eig.eigenvectors[(r, order[k])]);
    (values, dirs)
}

/// Whether the sensing points are flat (their extent normal to their best plane is below a twentieth
/// of their largest extent, [`FLAT_RATIO`]), in words: what such a geometry cannot see well.
pub fn flatness(array: &Array) -> Option<String> {
    let (ext, dirs) = extent(array);
    (ext[2] < FLAT_RATIO * ext[0]).then(|| {
        let normal = dirs.column(2);
        format!(
            "flat: the sensing points lie within {:.2} mm (RMS) of one plane, normal [{:.2}, {:.2}, {:.2}], across {:.1} mm (RMS {:.2} mm): a real rotation by hand can leave combinations unseen that this synthetic one sees (the four top IMUs of the MIMU4444 on recording 1: 9 gyroscope-free, 8 with --use-gyro; docs/real-hardware.md)",
            ext[2] * 1e3,
            normal.x,
            normal.y,
            normal.z,
            2.0 * ext[0] * 1e3,
            ext[0] * 1e3
        )
    })
}

/// [`flatness`]'s threshold: extent normal to the plane over the largest extent.
pub const FLAT_RATIO: f64 = 0.05;

/// What would make unseen combinations identifiable, in words, for a calibration with
/// (`reference_rate`) or without a measured rate, with or without a rotation phase, of an array
/// whose file lists `gyroscopes` reference gyroscope axes. `recording_unseen` is how many the
/// recording's own fit left unseen.
pub fn remedies(
    array: &Array,
    gyroscopes: usize,
    reference_rate: bool,
    with_dynamic: bool,
    recording_unseen: usize,
) -> Vec<String> {
    let mut out = Vec::new();
    if !with_dynamic {
        out.push("a rotation phase (the locations are seen only while the board turns)".to_string());
    }
    let own = check(array, reference_rate);
    if !reference_rate {
        let with_rate = check(array, true);
        let what = if with_rate.unseen.is_empty() {
            "with a measured rate this geometry sees every parameter on a rich synthetic recording".to_string()
        } else {
            format!("with a measured rate this geometry still leaves {} unseen", with_rate.unseen.combinations.len())
        };
        if gyroscopes > 0 {
            out.push(format!(
                "--use-gyro (the rate from the array file's {gyroscopes} reference gyroscope axes): {what}"
            ));
        } else {
            out.push(format!("reference gyroscopes (then --use-gyro): {what}"));
        }
    }
    let (ext, dirs) = extent(array);
    if ext[2] < FLAT_RATIO * ext[0] {
        let normal = dirs.column(2);
        out.push(format!(
            "a geometry that is not flat: the sensing points lie within {:.2} mm (RMS) of one plane (normal [{:.2}, {:.2}, {:.2}]) across {:.1} mm",
            ext[2] * 1e3,
            normal.x,
            normal.y,
            normal.z,
            2.0 * ext[0] * 1e3
        ));
    }
    if !own.unseen.is_empty() && ext[2] >= FLAT_RATIO * ext[0] {
        out.push(format!(
            "another geometry: this one leaves {} combination(s) unseen even on a rich synthetic recording ({POSES} poses, {SAMPLES} rotation samples)",
            own.unseen.combinations.len()
        ));
    }
    if recording_unseen > own.unseen.combinations.len() {
        out.push(format!(
            "more poses and a richer rotation phase: on a rich synthetic recording this geometry leaves {} unseen, this recording {}",
            own.unseen.combinations.len(),
            recording_unseen
        ));
    }
    out
}

/// The parameters (`a3.dz`, ...) with a share in `unseen`, of an array of `n` accelerometers.
pub fn unseen_names(unseen: &[bool], n: usize) -> Vec<String> {
    (0..(PER_ACCEL * n).min(unseen.len())).filter(|&i| unseen[i]).map(|i| super::unseen::name(i, n)).collect()
}
