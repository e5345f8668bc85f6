//! The `[errors]` section: one set of true error parameters, and the nominal values compensation
//! assumes without calibration.
//!
//! ```toml
//! [errors]
//! bias_mg = 1.0                       # one value for all, or one per accelerometer
//! scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]
//! nominal_scale_factor = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5]   # default 1
//! location_error_mm = [[0.5, 0.8, 0.6], ...]              # default 0
//! [errors.misalignment]               # at most one of:
//! triad_deg = [{ xy = 0.6, xz = 0.5, yx = 0.8, yz = 0.7, zx = 0.4, zy = 0.8 }, ...]  # per triad
//! tilt_deg = [[0.1, -0.2], ...]       # per accelerometer
//! ```

use serde::Deserialize;

use super::{Bad, OneOrEach, finite};
use crate::array::Array;
use crate::sensor::misalignment::{Misalignment, TriadAngles};
use crate::sensor::params::{ArrayParams, SensorParams};
use crate::units::{M_PER_MM, M_S2_PER_MG, RAD_PER_DEG};

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ErrorsSection {
    pub bias_mg: Option<OneOrEach<f64>>,
    pub scale_factor: Option<OneOrEach<f64>>,
    pub nominal_scale_factor: Option<OneOrEach<f64>>,
    pub location_error_mm: Option<OneOrEach<[f64; 3]>>,
    #[serde(default)]
    pub misalignment: MisalignmentSection,
}

#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MisalignmentSection {
    pub triad_deg: Option<Vec<TriadDeg>>,
    pub tilt_deg: Option<Vec<[f64; 2]>>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TriadDeg {
    pub xy: f64,
    pub xz: f64,
    pub yx: f64,
    pub yz: f64,
    pub zx: f64,
    pub zy: f64,
}

/// True and nominal parameters resolved from the section.
#[derive(Debug, Clone)]
pub struct ErrorSet {
    pub truth: ArrayParams,
    pub nominal: ArrayParams,
}

fn scale_factors(key: &str, v: &Option<OneOrEach<f64>>, n: usize) -> Result<Vec<f64>, Bad> {
    let ks = v.clone().unwrap_or(OneOrEach::One(1.0)).expand(key, n)?;
    for (j, k) in ks.iter().enumerate() {
        let key = format!("{key}[{j}]");
        if finite(&key, *k)? == 0.0 {
            return Err(Bad::new(key, "a scale factor of zero makes the accelerometer blind"));
        }
    }
    Ok(ks)
}

impl ErrorsSection {
    pub fn resolve(&self, array: &Array) -> Result<ErrorSet, Bad> {
        let n = array.len();
        let bias_mg = self.bias_mg.clone().unwrap_or(OneOrEach::One(0.0)).expand("errors.bias_mg", n)?;
        let k = scale_factors("errors.scale_factor", &self.scale_factor, n)?;
        let k_nominal = scale_factors("errors.nominal_scale_factor", &self.nominal_scale_factor, n)?;
        let loc_mm =
            self.location_error_mm.clone().unwrap_or(OneOrEach::One([0.0; 3])).expand("errors.location_error_mm", n)?;
        let misalignment = match (&self.misalignment.triad_deg, &self.misalignment.tilt_deg) {
            (Some(_), Some(_)) => {
                return Err(Bad::new("errors.misalignment", "give either `triad_deg` or `tilt_deg`, not both"));
            }
            (Some(triads), None) => {
                if array.triads().is_empty() {
                    return Err(Bad::new(
                        "errors.misalignment.triad_deg",
                        "the array defines no triads; use `tilt_deg`",
                    ));
                }
                if triads.len() != array.triads().len() {
                    return Err(Bad::new(
                        "errors.misalignment.triad_deg",
                        format!("needs one entry per triad ({}), got {}", array.triads().len(), triads.len()),
                    ));
                }
                let mut angles = Vec::new();
                for (t, a) in triads.iter().enumerate() {
                    let key = |name: &str| format!("errors.misalignment.triad_deg[{t}].{name}");
                    angles.push(TriadAngles {
                        xy_rad: finite(&key("xy"), a.xy)? * RAD_PER_DEG,
                        xz_rad: finite(&key("xz"), a.xz)? * RAD_PER_DEG,
                        yx_rad: finite(&key("yx"), a.yx)? * RAD_PER_DEG,
                        yz_rad: finite(&key("yz"), a.yz)? * RAD_PER_DEG,
                        zx_rad: finite(&key("zx"), a.zx)? * RAD_PER_DEG,
                        zy_rad: finite(&key("zy"), a.zy)? * RAD_PER_DEG,
                    });
                }
                Misalignment::Triad(angles)
            }
            (None, tilt) => {
                let tilt = tilt.clone().unwrap_or_else(|| vec![[0.0; 2]; n]);
                if tilt.len() != n {
                    return Err(Bad::new(
                        "errors.misalignment.tilt_deg",
                        format!("needs one pair per accelerometer ({n}), got {}", tilt.len()),
                    ));
                }
                let mut rad = Vec::new();
                for (j, t) in tilt.iter().enumerate() {
                    let key = format!("errors.misalignment.tilt_deg[{j}]");
                    rad.push([finite(&key, t[0])? * RAD_PER_DEG, finite(&key, t[1])? * RAD_PER_DEG]);
                }
                Misalignment::Tilt(rad)
            }
        };
        let axes = misalignment.axes(array).map_err(|e| Bad::new("errors.misalignment", e.to_string()))?;
        let mut sensors = Vec::with_capacity(n);
        for j in 0..n {
            let bias = finite(&format!("errors.bias_mg[{j}]"), bias_mg[j])? * M_S2_PER_MG;
            let loc = super::vec3(&format!("errors.location_error_mm[{j}]"), loc_mm[j])? * M_PER_MM;
            sensors.push(SensorParams { scale_factor: k[j], bias_m_s2: bias, axis: axes[j], location_error_m: loc });
        }
        Ok(ErrorSet {
            truth: ArrayParams { sensors },
            nominal: ArrayParams::nominal_with_scale_factors(array, &k_nominal),
        })
    }
}
