//! A hypothesis about the simulator behind Hung & Lee's Tables 8 and 9 (`paper_model`): its true
//! axes were an ordered product of elementary shears, while its estimator used the linear form of
//! eq. (6).
//!
//! Eq. (6) writes a triad's misalignment as one matrix, linear in its six angles:
//!
//! ```text
//! C_a^a' = [[ 1,    d_xz, -d_xy],
//!           [-d_yz,  1,    d_yx],
//!           [ d_zy, -d_zx,  1  ]]
//! ```
//!
//! If the paper's simulator instead built `C_a^a'` as the product of six elementary shears, the
//! identity with one of those off-diagonal entries each, `E_xz E_yz E_zy E_xy E_yx E_zx` (the xz
//! term first, the zx term last), its true axes carry second-order cross terms (products of two
//! angles, about 1e-4) that the linear form reads as slightly different angles. Noise-free, the
//! paper's procedure then recovers 0.5930, 0.5042, 0.8074, 0.7001, 0.4000 and 0.8001 deg for the
//! true 0.6, 0.5, 0.8, 0.7, 0.4 and 0.8: Table 8's six printed angles, to every digit. (Shears of
//! different rows and columns commute in pairs, so a few other orders give the same product; the
//! order above is the one with xz first and zx last.)

use nalgebra::{Matrix3, Vector3};

use crate::array::Array;
use crate::sensor::misalignment::{MisalignmentError, TriadAngles};

/// The order of the elementary shears, leftmost first.
pub const SHEAR_ORDER: [&str; 6] = ["xz", "yz", "zy", "xy", "yx", "zx"];

/// The elementary shear of one angle: the identity with that angle at its place in eq. (6).
fn shear(name: &str, a: &TriadAngles) -> Matrix3<f64> {
    let mut m = Matrix3::identity();
    match name {
        "xz" => m[(0, 1)] = a.xz_rad,
        "xy" => m[(0, 2)] = -a.xy_rad,
        "yz" => m[(1, 0)] = -a.yz_rad,
        "yx" => m[(1, 2)] = a.yx_rad,
        "zy" => m[(2, 0)] = a.zy_rad,
        _ => m[(2, 1)] = -a.zx_rad,
    }
    m
}

/// `C_a^a'` of the hypothesis: the ordered product of [`SHEAR_ORDER`].
pub fn shear_product(a: &TriadAngles) -> Matrix3<f64> {
    SHEAR_ORDER.iter().fold(Matrix3::identity(), |m, name| m * shear(name, a))
}

/// True sensitive axes of every accelerometer under the hypothesis: row `row` of
/// `shear_product(angles) C_b^a` for the accelerometer in row `row` of its triad.
pub fn axes(array: &Array, angles: &[TriadAngles]) -> Result<Vec<Vector3<f64>>, MisalignmentError> {
    let expected = array.triads().len();
    if angles.len() != expected {
        return Err(MisalignmentError::Count { what: "triads of angles", expected, got: angles.len() });
    }
    (0..array.len())
        .map(|j| {
            let (t, row) = array.triad_of(j).ok_or(MisalignmentError::NotInTriad { index: j + 1 })?;
            let members = array.triads()[t];
            let c = shear_product(&angles[t]);
            Ok((0..3).map(|k| array.accelerometers()[members[k]].axis * c[(row, k)]).sum())
        })
        .collect()
}
