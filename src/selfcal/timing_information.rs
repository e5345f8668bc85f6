//! What a clocked calibration's covariance leaves out: each sample's timing motion.
//!
//! With the packages' sample clocks (`selfcal::timing`) an output also depends on its package's
//! relative age `tau` times the sample's jerk and angular jerk (6 unknowns a sample). The
//! calibration fits that timing motion apart, on the residuals with the motion held, corrects the
//! outputs with it and then holds it: the joint fit and every covariance (`selfcal::fit`,
//! `selfcal::robust`) eliminate only the 9 motion unknowns of a sample. Here the information is
//! formed with the timing motion eliminated too, densely, sample by sample: the local design
//! `L` (outputs x 9, or x 15 with the timing columns, which are the specific force's and the
//! angular acceleration's scaled by the output's age), the parameters' design `G` (each output's
//! own accelerometer's 7 derivatives) and `G^T W G - G^T W L (L^T W L)^+ L^T W G`. With 9 local
//! unknowns this is the fit's own dynamic information, formed another way (the fit sums
//! the Schur complement's 7 x 7 blocks, `selfcal::schur`), which checks both.
//!
//! On the matched protocol's simulated recordings the locations' sigmas grow by a median factor
//! of 13-15 with the timing motion free, the other kinds' by at most 5%: a location change is
//! nearly absorbed by each sample's timing motion times the ages. The calibration's locations are
//! nonetheless only about 1.35 times their held sigmas off the truth, at a fixed point of its
//! alternation; how the two fit together is open (`docs/sample-clocks.md`).

use nalgebra::{DMatrix, DVector};

use super::data::{DynamicData, StaticData};
use super::fit::{Fit, FitError, FitSettings, Weights};
use super::model::{PER_ACCEL, SampleMotion, Sensor, sensors};
use super::robust::at_solution;
use crate::array::Array;

/// The motion's unknowns in a sample's local design.
const MOTION_UNKNOWNS: usize = 9;
/// The timing motion's: jerk and angular jerk (`selfcal::timing::TIMING_UNKNOWNS_PER_SAMPLE`).
const TIMING_UNKNOWNS: usize = 6;

/// The parameters' sigmas with and without the timing motion eliminated.
#[derive(Debug, Clone)]
pub struct TimingFreeSigmas {
    /// Per accelerometer parameter (`PER_ACCEL` per accelerometer, in order), its sigma with the
    /// timing motion eliminated over its sigma with it held (NaN where the fit does not see it).
    pub sigma_ratio: Vec<f64>,
    /// The dense reduction with 9 local unknowns against the fit's dynamic information: the
    /// relative Frobenius norm of their difference.
    pub agreement_with_fit: f64,
}

/// The reduced dynamic information of the accelerometer parameters (`PER_ACCEL` per
/// accelerometer), each sample's motion eliminated and, with `ages` (samples x accelerometers, s),
/// its timing motion too. `weights`: each accelerometer's inverse variance. Summed over samples in
/// order.
pub fn reduced_dynamic_information(
    sens: &[Sensor],
    d: &DynamicData,
    motion: &[SampleMotion],
    weights: &[f64],
    ages: Option<&DMatrix<f64>>,
) -> DMatrix<f64> {
    let n = sens.len();
    let na = PER_ACCEL * n;
    let local = MOTION_UNKNOWNS + if ages.is_some() { TIMING_UNKNOWNS } else { 0 };
    let mut h = DMatrix::zeros(na, na);
    let mut l = DMatrix::zeros(n, local);
    let mut g = DMatrix::zeros(n, na);
    for (i, m) in motion.iter().enumerate().take(d.samples()) {
        l.fill(0.0);
        g.fill(0.0);
        let mut w = DVector::zeros(n);
        for (j, s) in sens.iter().enumerate() {
            if !d.used[i * n + j] {
                continue;
            }
            w[j] = weights[j];
            let dl = s.d_motion(m);
            for (c, v) in dl.iter().enumerate() {
                l[(j, c)] = *v;
            }
            if let Some(ages) = ages {
                for c in 0..TIMING_UNKNOWNS {
                    l[(j, MOTION_UNKNOWNS + c)] = ages[(i, j)] * dl[c];
                }
            }
            let intrinsic = s.d_intrinsic(&m.specific_force_m_s2(&s.position_m));
            let location = s.d_location(m);
            let row = [intrinsic[0], intrinsic[1], intrinsic[2], intrinsic[3], location.x, location.y, location.z];
            for (c, v) in row.iter().enumerate() {
                g[(j, PER_ACCEL * j + c)] = *v;
            }
            // `G^T W G`: each output touches its own accelerometer's block only.
            for (r, a) in row.iter().enumerate() {
                for (c, b) in row.iter().enumerate() {
                    h[(PER_ACCEL * j + r, PER_ACCEL * j + c)] += weights[j] * a * b;
                }
            }
        }
        let lw = DMatrix::from_fn(local, n, |r, c| l[(c, r)] * w[c]);
        let b = &lw * &l;
        let largest = b.diagonal().max();
        if largest <= 0.0 {
            continue;
        }
        let Ok(b_inv) = b.pseudo_inverse(1e-12 * largest) else { continue };
        let a = &lw * &g;
        h -= a.transpose() * b_inv * a;
    }
    h
}

/// The fit's parameters' sigmas with each sample's timing motion eliminated against held (module
/// docs), at the fit's stored weights. `dynamic`: the rotation phase the fit was fitted to (its
/// motion and used outputs); `ages`: each accelerometer's relative age at every sample
/// (`selfcal::timing::accelerometer_ages` of the fitted clocks).
pub fn timing_free_sigmas(
    array: &Array,
    stat: &StaticData,
    dynamic: &DynamicData,
    settings: &FitSettings,
    fit: &Fit,
    ages: &DMatrix<f64>,
) -> Result<TimingFreeSigmas, FitError> {
    let na = PER_ACCEL * array.len();
    let weights = Weights::stored_in(fit, stat);
    let at = at_solution(array, stat, dynamic, &weights, settings, fit);
    let sens = sensors(array, &fit.params);
    let held = reduced_dynamic_information(&sens, dynamic, &fit.motion, &weights.dynamic_w, None);
    let free = reduced_dynamic_information(&sens, dynamic, &fit.motion, &weights.dynamic_w, Some(ages));
    let fit_dynamic = (&at.normal - &at.static_normal).view((0, 0), (na, na)).into_owned();
    let agreement_with_fit = (&held - &fit_dynamic).norm() / fit_dynamic.norm();
    let with = |dynamic: &DMatrix<f64>| {
        let mut information = at.static_normal.clone();
        let mut top = information.view_mut((0, 0), (na, na));
        top += dynamic;
        at.inverse(&information, fit)
    };
    let (k_held, k_free) = (with(&held)?, with(&free)?);
    let sigma_ratio = (0..na).map(|i| (k_free[(i, i)] / k_held[(i, i)]).sqrt()).collect();
    Ok(TimingFreeSigmas { sigma_ratio, agreement_with_fit })
}
