//! CSV tables (units in the column names).

use crate::nav::DriftRow;

/// The drift table as CSV: one row per compensation and horizon.
pub fn drift_csv(rows: &[DriftRow]) -> String {
    let mut s =
        String::from("compensation,horizon_s,rate_err_rad_s,attitude_err_rad,velocity_err_m_s,position_err_m\n");
    for r in rows {
        let d = &r.sample;
        s.push_str(&format!(
            "{},{},{:e},{:e},{:e},{:e}\n",
            r.compensation, d.horizon_s, d.rate_err_rad_s, d.attitude_err_rad, d.velocity_err_m_s, d.position_err_m
        ));
    }
    s
}
