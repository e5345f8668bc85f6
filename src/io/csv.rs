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

use crate::calib::reproduce::TableRow;

/// Columns of the reproduced tables.
pub const TABLE_COLUMNS: [&str; 12] = [
    "parameter",
    "accelerometer",
    "unit",
    "true",
    "paper",
    "paper_model",
    "noise_free",
    "mc_mean",
    "mc_std",
    "crb_sigma",
    "augmented_mc_std",
    "augmented_crb_sigma",
];

fn row_values(r: &TableRow) -> [f64; 9] {
    [
        r.truth,
        r.paper,
        r.paper_model,
        r.noise_free,
        r.mc_mean,
        r.mc_std,
        r.crb_sigma,
        r.augmented_mc_std,
        r.augmented_crb_sigma,
    ]
}

/// A reproduced table as CSV (full precision).
pub fn table_csv(rows: &[TableRow]) -> String {
    let mut s = TABLE_COLUMNS.join(",") + "\n";
    for r in rows {
        let v: Vec<String> = row_values(r).iter().map(|v| format!("{v:e}")).collect();
        s.push_str(&format!("{},{},{},{}\n", r.parameter, r.accelerometer, r.unit, v.join(",")));
    }
    s
}

/// A reproduced table as Markdown (5 significant digits), with a caption.
pub fn table_markdown(caption: &str, rows: &[TableRow]) -> String {
    let mut s =
        format!("{caption}\n\n| {} |\n|{}|\n", TABLE_COLUMNS.join(" | "), vec!["---"; TABLE_COLUMNS.len()].join("|"));
    for r in rows {
        let v: Vec<String> = row_values(r).iter().map(|v| significant(*v, 5)).collect();
        s.push_str(&format!("| {} | {} | {} | {} |\n", r.parameter, r.accelerometer, r.unit, v.join(" | ")));
    }
    s
}

/// `value` with `digits` significant digits: fixed notation for magnitudes from 1e-4 to 1e6,
/// scientific otherwise.
pub fn significant(value: f64, digits: usize) -> String {
    if !value.is_finite() {
        return if value.is_nan() {
            "nan".into()
        } else if value > 0.0 {
            "inf".into()
        } else {
            "-inf".into()
        };
    }
    if value == 0.0 {
        return "0".into();
    }
    let magnitude = value.abs().log10().floor() as i32;
    if (-4..6).contains(&magnitude) {
        let decimals = (digits as i32 - 1 - magnitude).max(0) as usize;
        format!("{value:.decimals$}")
    } else {
        format!("{value:.*e}", digits.saturating_sub(1))
    }
}
