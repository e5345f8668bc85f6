//! Reproduction of Hung & Lee (2006), Tables 8 and 9: the paper's case, our noise-free recovery,
//! a seeded Monte Carlo of the joint estimator, Cramer-Rao sigmas, on the paper's schedule and on
//! the augmented one.

use nalgebra::{DVector, Vector3};
use rayon::prelude::*;

use super::estimate::CalibError;
use super::fisher::{fisher_information, structurally_unidentifiable};
use super::joint::{Start, check_identifiable, estimate_unchecked};
use super::measure::simulate;
use super::params::{Form, Layout, ParamKind};
use super::schedule::Schedule;
use crate::array::Array;
use crate::io::format::significant;
use crate::sensor::misalignment::{Misalignment, TriadAngles};
use crate::sensor::noise::NoiseSpec;
use crate::sensor::params::{ArrayParams, SensorParams};
use crate::units::{M_PER_MM, M_S2_PER_MG, RAD_PER_DEG};

fn deg_triad(xy: f64, xz: f64, yx: f64, yz: f64, zx: f64, zy: f64) -> TriadAngles {
    TriadAngles {
        xy_rad: xy * RAD_PER_DEG,
        xz_rad: xz * RAD_PER_DEG,
        yx_rad: yx * RAD_PER_DEG,
        yz_rad: yz * RAD_PER_DEG,
        zx_rad: zx * RAD_PER_DEG,
        zy_rad: zy * RAD_PER_DEG,
    }
}

/// The paper's true misalignment angles (Table 7), the same for both triads.
pub fn paper_angles() -> TriadAngles {
    deg_triad(0.6, 0.5, 0.8, 0.7, 0.4, 0.8)
}

/// The paper's true parameters (Tables 6 and 7) on the cube with rho = 0.1 m.
pub fn paper_truth(array: &Array) -> Result<ArrayParams, CalibError> {
    let angles = paper_angles();
    let axes = Misalignment::Triad(vec![angles, angles]).axes(array)?;
    let k = [0.5, 2.5, 0.5, 2.5, 2.5, 2.5];
    let loc_mm = [[0.5, 0.8, 0.6], [0.7, 0.5, 0.6], [0.5, 0.9, 0.8], [0.4, 0.7, 0.5], [0.8, 0.7, 0.5], [0.6, 0.8, 0.9]];
    let sensors = (0..6)
        .map(|j| SensorParams {
            scale_factor: k[j],
            bias_m_s2: M_S2_PER_MG,
            axis: axes[j],
            location_error_m: Vector3::from(loc_mm[j]) * M_PER_MM,
        })
        .collect();
    Ok(ArrayParams { sensors })
}

/// The paper's recovered values (Table 8 in the triad form's order of parameters; Table 9 in mm),
/// by accelerometer number, in display units: `[bias g, k, m1 deg, m2 deg, dx mm, dy mm, dz mm]`.
pub fn paper_recovered() -> [[f64; 7]; 6] {
    // Table 8 rows are listed 1, 4, 6, 2, 3, 5; the triad form's angle pairs are
    // (xy, xz) for row 1, (yx, yz) for row 2, (zx, zy) for row 3 of each triad.
    [
        [0.001, 0.5, 0.5930, 0.5042, 0.38, 0.85, 8.91],
        [0.001, 2.4998, 0.5930, 0.5042, 0.51, 0.58, 0.72],
        [0.001, 0.4999, 0.8074, 0.7001, 5.42, 0.9, 0.92],
        [0.001, 2.4996, 0.8074, 0.7001, 5.22, 0.57, 0.5],
        [0.001, 2.4997, 0.4000, 0.8001, 0.8, 0.88, 0.5],
        [0.001, 2.4997, 0.4000, 0.8001, 0.6, 0.8, 1.09],
    ]
}

/// Monte Carlo of the joint estimator: per-parameter mean and standard deviation of the
/// estimates over the trials that converged, and the number that did not.
#[derive(Debug, Clone)]
pub struct McResult {
    pub mean: DVector<f64>,
    pub std: DVector<f64>,
    pub rmse: DVector<f64>,
    pub converged: usize,
    pub failed: usize,
}

/// Runs `trials` seeded trials in parallel (trial i draws from `trial_rng(seed, i)`).
#[allow(clippy::too_many_arguments)]
pub fn monte_carlo(
    layout: &Layout,
    schedule: &Schedule,
    truth: &ArrayParams,
    nominal: &ArrayParams,
    noise: &NoiseSpec,
    seed: u64,
    trials: usize,
    g_m_s2: f64,
) -> Result<McResult, CalibError> {
    check_identifiable(layout, schedule, nominal, g_m_s2)?;
    let x_true = layout.pack(truth)?;
    let array = layout.array();
    let estimates: Vec<Option<DVector<f64>>> = (0..trials)
        .into_par_iter()
        .map(|i| {
            let mut rng = crate::rng::trial_rng(seed, i as u64);
            let meas = simulate(array, truth, schedule, noise, g_m_s2, &mut rng);
            estimate_unchecked(layout, schedule, &meas, nominal, Start::Linear, g_m_s2)
                .ok()
                .filter(|e| e.status.converged)
                .map(|e| e.x)
        })
        .collect();
    let ok: Vec<&DVector<f64>> = estimates.iter().flatten().collect();
    let p = layout.len();
    let n = ok.len().max(1) as f64;
    let mean = ok.iter().fold(DVector::zeros(p), |acc, x| acc + *x) / n;
    let var = ok.iter().fold(DVector::zeros(p), |acc, x| acc + (*x - &mean).map(|v| v * v)) / (n - 1.0).max(1.0);
    let mse = ok.iter().fold(DVector::zeros(p), |acc, x| acc + (*x - &x_true).map(|v| v * v)) / n;
    Ok(McResult {
        mean,
        std: var.map(f64::sqrt),
        rmse: mse.map(f64::sqrt),
        converged: ok.len(),
        failed: trials - ok.len(),
    })
}

/// One row of a reproduced table, display units.
#[derive(Debug, Clone, PartialEq)]
pub struct TableRow {
    pub parameter: String,
    pub accelerometer: usize,
    pub unit: String,
    pub truth: f64,
    pub paper: f64,
    /// The paper's procedure, noise-free, on data from the `paper_model` hypothesis of the
    /// paper's simulator (true axes an ordered product of shears).
    pub paper_model: f64,
    pub noise_free: f64,
    pub mc_mean: f64,
    pub mc_std: f64,
    pub crb_sigma: f64,
    pub augmented_mc_std: f64,
    pub augmented_crb_sigma: f64,
}

/// Settings of the reproduction.
#[derive(Debug, Clone)]
pub struct PaperRun {
    pub noise: NoiseSpec,
    pub seed: u64,
    pub trials: usize,
    pub g_m_s2: f64,
}

/// Everything `gfcal paper` writes.
#[derive(Debug, Clone)]
pub struct PaperTables {
    pub table8: Vec<TableRow>,
    pub table9: Vec<TableRow>,
    /// Location errors (mm) recovered by our location step from the paper's own Table 8 static
    /// results and noise-free spins: `[accelerometer][x, y, z]`.
    pub table9_from_table8_mm: Vec<[f64; 3]>,
    /// The same with the spins simulated from the `paper_model` hypothesis (shear-product axes).
    pub table9_from_table8_paper_model_mm: Vec<[f64; 3]>,
    pub paper_schedule: McResult,
    pub augmented_schedule: McResult,
}

/// Builds Tables 8 and 9 (see the module docs).
pub fn reproduce(
    array: &Array,
    paper: &Schedule,
    augmented: &Schedule,
    run: &PaperRun,
) -> Result<PaperTables, CalibError> {
    let layout = Layout::new(array, Form::Triad)?;
    let truth = paper_truth(array)?;
    let x_true = layout.pack(&truth)?;
    // An uncalibrated unit knows its design scale factors (Table 6): the fit starts there.
    let mut nominal = ArrayParams::nominal(array);
    for (n, t) in nominal.sensors.iter_mut().zip(&truth.sensors) {
        n.scale_factor = t.scale_factor;
    }
    let clean = super::measure::noise_free(array, &truth, paper, run.g_m_s2);
    let noise_free = super::paper::estimate(&layout, paper, &clean, run.g_m_s2)?.x;
    let mut hypothesis = truth.clone();
    let axes = super::paper_model::axes(array, &[paper_angles(), paper_angles()])?;
    for (s, a) in hypothesis.sensors.iter_mut().zip(axes) {
        s.axis = a;
    }
    let paper_model = {
        let data = super::measure::noise_free(array, &hypothesis, paper, run.g_m_s2);
        super::paper::estimate(&layout, paper, &data, run.g_m_s2)?.x
    };
    let density = run.noise.white.density_m_s2_per_sqrt_hz();
    let crb = |s: &Schedule| -> DVector<f64> {
        let fim = fisher_information(&layout, &x_true, s, run.g_m_s2, density);
        let bad = structurally_unidentifiable(&layout, &x_true, s, run.g_m_s2);
        let inv =
            fim.try_inverse().unwrap_or_else(|| nalgebra::DMatrix::from_element(layout.len(), layout.len(), f64::NAN));
        DVector::from_iterator(
            layout.len(),
            (0..layout.len()).map(|i| if bad.contains(&i) { f64::INFINITY } else { inv[(i, i)].max(0.0).sqrt() }),
        )
    };
    let (crb_paper, crb_aug) = (crb(paper), crb(augmented));
    let mc_paper = monte_carlo(&layout, paper, &truth, &nominal, &run.noise, run.seed, run.trials, run.g_m_s2)?;
    let mc_aug = monte_carlo(&layout, augmented, &truth, &nominal, &run.noise, run.seed, run.trials, run.g_m_s2)?;
    let recovered = paper_recovered();
    let (mut table8, mut table9) = (Vec::new(), Vec::new());
    for i in 0..layout.len() {
        let kind = layout.kind(i);
        let (unit, f) = kind.paper_unit();
        let j = layout.accel(i);
        let paper_value = match kind {
            ParamKind::Bias => recovered[j][0],
            ParamKind::ScaleFactor => recovered[j][1],
            ParamKind::Misalignment(m) => recovered[j][2 + m as usize],
            ParamKind::Location(c) => recovered[j][4 + c as usize],
        };
        // The paper's Table 8 angle pairs are listed (xy, xz), (yx, yz), (zx, zy): the layout's order.
        let row = TableRow {
            parameter: layout.quantity(i),
            accelerometer: j + 1,
            unit: unit.to_string(),
            truth: x_true[i] * f,
            paper: paper_value,
            paper_model: paper_model[i] * f,
            noise_free: noise_free[i] * f,
            mc_mean: mc_paper.mean[i] * f,
            mc_std: mc_paper.std[i] * f,
            crb_sigma: crb_paper[i] * f,
            augmented_mc_std: mc_aug.std[i] * f,
            augmented_crb_sigma: crb_aug[i] * f,
        };
        if matches!(kind, ParamKind::Location(_)) { table9.push(row) } else { table8.push(row) }
    }
    let table9_from_table8_mm = location_from_table8(array, &truth, paper, run.g_m_s2)?;
    let table9_from_table8_paper_model_mm = location_from_table8(array, &hypothesis, paper, run.g_m_s2)?;
    Ok(PaperTables {
        table8,
        table9,
        table9_from_table8_mm,
        table9_from_table8_paper_model_mm,
        paper_schedule: mc_paper,
        augmented_schedule: mc_aug,
    })
}

/// Our location step (Table 5, noise-free spins simulated from `truth`) fed with the paper's
/// Table 8 static results.
fn location_from_table8(
    array: &Array,
    truth: &ArrayParams,
    schedule: &Schedule,
    g_m_s2: f64,
) -> Result<Vec<[f64; 3]>, CalibError> {
    let r = paper_recovered();
    // Triad A = (1, 4, 6): rows are accelerometers 1, 4, 6 -> recovered[0], [3], [5].
    let alpha = deg_triad(r[0][2], r[0][3], r[3][2], r[3][3], r[5][2], r[5][3]);
    let beta = deg_triad(r[1][2], r[1][3], r[2][2], r[2][3], r[4][2], r[4][3]);
    let axes = Misalignment::Triad(vec![alpha, beta]).axes(array)?;
    let mut with_table8 = truth.clone();
    for (j, s) in with_table8.sensors.iter_mut().enumerate() {
        s.scale_factor = r[j][1];
        s.bias_m_s2 = r[j][0] * crate::units::STANDARD_GRAVITY_M_S2;
        s.axis = axes[j];
    }
    let clean = super::measure::noise_free(array, truth, schedule, g_m_s2);
    let spins: Vec<usize> = schedule.steps().iter().enumerate().filter(|(_, s)| s.is_spin()).map(|(i, _)| i).collect();
    let mut out = Vec::new();
    for j in 0..array.len() {
        let dr = super::paper::location_only(
            schedule,
            &clean,
            &spins,
            j,
            &with_table8.sensors[j],
            &array.accelerometers()[j].position_m,
            g_m_s2,
        )
        .map_err(|c| CalibError::Unidentifiable {
            parameters: c.iter().map(|c| format!("a{}.d{}", j + 1, ["x", "y", "z"][*c])).collect(),
        })?;
        out.push([dr.x / M_PER_MM, dr.y / M_PER_MM, dr.z / M_PER_MM]);
    }
    Ok(out)
}

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
