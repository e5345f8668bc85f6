//! The sensing point of each axis inside a package: the baseline gives every accelerometer its
//! own location error, so the three axes of an IMU may sit at three points. Whether they do is
//! a Wald test of the differences of their location errors within the package (`3 (k - 1)`
//! values for `k` axes), with the robust covariance of the fitting recording (`projected`). The
//! differences are free of the gauge: a common shift, a common rotation or a scaling about the
//! centroid moves the axes of one package together (to first order).

use nalgebra::{DMatrix, DVector};

use super::effect::EffectLayout;
use super::projected::Accumulated;
use crate::selfcal::fit::constrained_inverse;
use crate::selfcal::model::{PER_ACCEL, SensorSet};
use crate::stats::{symmetric_pinv, wald_p};

/// The test of one package.
#[derive(Debug, Clone, PartialEq)]
pub struct SensingPoint {
    /// Package index (0-based) and its accelerometers (0-based).
    pub package: usize,
    pub accelerometers: Vec<usize>,
    /// Location error of each axis minus the first axis's, m (3 per further axis), and sigmas.
    pub difference_m: Vec<f64>,
    pub sigma_m: Vec<f64>,
    pub p_value: f64,
}

/// One further axis of a package against the package's first: the difference of their location
/// errors along the array's x, y and z axes, m, and its sigmas.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisOffset {
    /// The further axis and the package's first (0-based accelerometers).
    pub accelerometer: usize,
    pub minus: usize,
    pub difference_m: [f64; 3],
    pub sigma_m: [f64; 3],
}

impl SensingPoint {
    /// The differences, labelled: one per further axis of the package.
    pub fn offsets(&self) -> Vec<AxisOffset> {
        let first = self.accelerometers[0];
        self.accelerometers
            .iter()
            .skip(1)
            .enumerate()
            .map(|(i, &j)| AxisOffset {
                accelerometer: j,
                minus: first,
                difference_m: [self.difference_m[3 * i], self.difference_m[3 * i + 1], self.difference_m[3 * i + 2]],
                sigma_m: [self.sigma_m[3 * i], self.sigma_m[3 * i + 1], self.sigma_m[3 * i + 2]],
            })
            .collect()
    }
}

impl AxisOffset {
    /// `a14 - a13: x 1.20 +- 0.30, y ..., z ... mm` (accelerometers 1-based, array axes).
    pub fn describe_mm(&self) -> String {
        let parts: Vec<String> = ["x", "y", "z"]
            .iter()
            .zip(self.difference_m.iter().zip(&self.sigma_m))
            .map(|(axis, (v, s))| format!("{axis} {:.2} +- {:.2}", v * 1e3, s * 1e3))
            .collect();
        format!("a{} - a{}: {} mm", self.accelerometer + 1, self.minus + 1, parts.join(", "))
    }
}

/// Tests every package with more than one axis. `total` is the fitting recording's accumulation
/// with the baseline as its first `PER_ACCEL n` columns, then up to `nuisance_columns` the rest
/// of the nuisance (the sample clocks' relative parameters, `blocks::ClockNuisance`), which is
/// eliminated first.
///
/// `groups`: the gauge's rows (over the accelerometer parameters) when the array has several
/// axis groups, `None` otherwise.
pub fn sensing_points(
    total: &Accumulated,
    nuisance_columns: usize,
    layout: &EffectLayout,
    params: &SensorSet,
    groups: Option<&DMatrix<f64>>,
) -> Vec<SensingPoint> {
    let n = params.len();
    let g: Vec<usize> = (0..PER_ACCEL * n).collect();
    let columns = nuisance_columns.max(g.len());
    // The spread of the scores: the dynamic samples' sandwich and the static intervals' model
    // information (`projected`; at the baseline's own solution, with its variance factor).
    let normal = DMatrix::from_fn(columns, columns, |i, j| total.normal[(i, j)]);
    let meat = DMatrix::from_fn(columns, columns, |i, j| total.meat[(i, j)] + total.model_normal[(i, j)]);
    // The other nuisance eliminated: the baseline's normal matrix is its Schur complement, and its
    // score `s_g - K s_c` (`K = N_gc N_cc^+`) spreads as `L M L^T`, `L = [I, -K]`.
    let p = g.len();
    let (ngg, mgg) = if columns > p {
        let c = columns - p;
        let ncc = normal.view((p, p), (c, c)).into_owned();
        let k = normal.view((0, p), (p, c)) * symmetric_pinv(&ncc, 1e-11).0;
        let ngg = normal.view((0, 0), (p, p)) - &k * normal.view((p, 0), (c, p));
        let mut l = DMatrix::zeros(p, columns);
        l.view_mut((0, 0), (p, p)).fill_with_identity();
        l.view_mut((0, p), (p, c)).copy_from(&(-k));
        (ngg, &l * meat * l.transpose())
    } else {
        (normal, meat)
    };
    let pg = groups.and_then(|c| gauge_inverse(&ngg, c)).unwrap_or_else(|| symmetric_pinv(&ngg, 1e-11).0);
    let cov = &pg * mgg * &pg;
    let mut out = Vec::new();
    for (m, accs) in layout.packages.iter().enumerate() {
        if accs.len() < 2 {
            continue;
        }
        let rows = 3 * (accs.len() - 1);
        let mut d = DMatrix::zeros(rows, g.len());
        let mut value = DVector::zeros(rows);
        for (i, &j) in accs.iter().skip(1).enumerate() {
            for c in 0..3 {
                d[(3 * i + c, PER_ACCEL * j + 4 + c)] = 1.0;
                d[(3 * i + c, PER_ACCEL * accs[0] + 4 + c)] = -1.0;
                value[3 * i + c] = params.location_error_m[j][c] - params.location_error_m[accs[0]][c];
            }
        }
        let c = &d * &cov * d.transpose();
        let v: Vec<f64> = value.iter().copied().collect();
        out.push(SensingPoint {
            package: m,
            accelerometers: accs.clone(),
            sigma_m: (0..rows).map(|i| c[(i, i)].max(0.0).sqrt()).collect(),
            p_value: wald_p(&v, &c),
            difference_m: v,
        });
    }
    out
}

/// The inverse of `n` in the gauge `C x = 0` (`selfcal::fit::constrained_inverse`), zero on the
/// parameters `n` holds no information on; `None` when singular.
fn gauge_inverse(n: &DMatrix<f64>, c: &DMatrix<f64>) -> Option<DMatrix<f64>> {
    let dim = n.nrows();
    if c.ncols() != dim {
        return None;
    }
    let active: Vec<bool> = (0..dim).map(|i| n[(i, i)] != 0.0).collect();
    let inv = constrained_inverse(n, c, &active, &vec![false; dim], true).ok()?;
    let inv = inv.map(|v| if v.is_nan() { 0.0 } else { v });
    inv.iter().all(|v| v.is_finite()).then_some(inv)
}
