//! Every cell of a run config: the linearisation and the motion grid computed once for the cells
//! that navigate alike, then each cell analysed (in parallel, each cell's result a function of the
//! config and seed alone).

use std::sync::Arc;

use nalgebra::Vector3;
use rayon::prelude::*;

use super::analysis::{
    CalibratedTruths, CellResult, LincovError, Settings, analyse_cell, calibrate_truths, check, linearisation,
};
use super::dynamics::Linearisation;
use super::sources::reference;
use crate::mc::{Cell, McConfig};
use crate::nav::MotionGrid;

/// Whether two cells' navigations linearise alike (same array, form, reference errors,
/// trajectory, steps, horizons, gravity and noise switch).
fn navigate_alike(a: &Cell, b: &Cell) -> bool {
    let (na, nb) = (&a.navigation, &b.navigation);
    na.trajectory == nb.trajectory
        && na.step_s == nb.step_s
        && na.horizons_s == nb.horizons_s
        && na.noise == nb.noise
        && (a.noise.white.density_m_s2_per_sqrt_hz() > 0.0) == (b.noise.white.density_m_s2_per_sqrt_hz() > 0.0)
        && a.calibration.gravity_m_s2 == b.calibration.gravity_m_s2
        && a.layout.form() == b.layout.form()
        && a.array.positions_m() == b.array.positions_m()
        && a.array.axes() == b.array.axes()
        && reference(a) == reference(b)
}

/// Analyses every cell of `cfg` (checked first: an unsupported key fails before any work).
pub fn analyse(cfg: &McConfig, settings: &Settings) -> Result<Vec<CellResult>, LincovError> {
    for cell in &cfg.cells {
        check(cell)?;
    }
    // The first cell of each group of cells that navigate alike.
    let leader: Vec<usize> = cfg
        .cells
        .iter()
        .enumerate()
        .map(|(i, c)| (0..i).find(|&k| navigate_alike(&cfg.cells[k], c)).unwrap_or(i))
        .collect();
    // Each group's linearisation and motion grid, beside its leader's truths (their
    // calibrations do not need the navigation: a single cell's threads stay busy). Only where the
    // groups are fewer than the threads: otherwise they fill the threads themselves, and every
    // leader's truths would be held at once.
    let groups = (0..leader.len()).filter(|&i| leader[i] == i).count();
    let beside = groups <= rayon::current_num_threads();
    type Shared = (Arc<Linearisation>, Arc<MotionGrid>);
    let shared: Vec<Option<(Shared, std::sync::Mutex<Option<CalibratedTruths>>)>> = cfg
        .cells
        .par_iter()
        .enumerate()
        .map(|(i, cell)| {
            if leader[i] != i {
                return Ok(None);
            }
            let (navigation, calibrated) = rayon::join(
                || -> Result<Shared, LincovError> {
                    let lin = linearisation(cell)?;
                    let nav = &cell.navigation;
                    let gravity_i = Vector3::new(0.0, 0.0, -cell.calibration.gravity_m_s2);
                    let grid = MotionGrid::new(&nav.trajectory, &gravity_i, nav.step_s, &nav.horizons_s);
                    Ok((Arc::new(lin), Arc::new(grid)))
                },
                || if beside { calibrate_truths(cell, cfg.seed, settings) } else { None },
            );
            Ok(Some((navigation?, std::sync::Mutex::new(calibrated))))
        })
        .collect::<Result<_, LincovError>>()?;
    cfg.cells
        .par_iter()
        .enumerate()
        .map(|(i, cell)| {
            let ((lin, grid), calibrated) = shared[leader[i]].as_ref().expect("every leader is linearised");
            // The leader's own truths (taken once); the others calibrate theirs.
            let own = if leader[i] == i { calibrated.lock().ok().and_then(|mut c| c.take()) } else { None };
            analyse_cell(cell, lin, cfg.seed, settings, Some(grid), own)
        })
        .collect()
}
