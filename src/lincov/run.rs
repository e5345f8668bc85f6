//! Every cell of a run config: the linearisation and the motion grid computed once for the cells
//! that navigate alike, then each cell analysed (in parallel, each cell's result a function of the
//! config and seed alone).

use std::sync::Arc;

use nalgebra::Vector3;
use rayon::prelude::*;

use super::analysis::{CellResult, LincovError, Settings, analyse_cell, check, linearisation};
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
    let shared: Vec<Option<(Arc<Linearisation>, Arc<MotionGrid>)>> = cfg
        .cells
        .par_iter()
        .enumerate()
        .map(|(i, cell)| {
            if leader[i] != i {
                return Ok(None);
            }
            let lin = linearisation(cell)?;
            let nav = &cell.navigation;
            let gravity_i = Vector3::new(0.0, 0.0, -cell.calibration.gravity_m_s2);
            let grid = MotionGrid::new(&nav.trajectory, &gravity_i, nav.step_s, &nav.horizons_s);
            Ok(Some((Arc::new(lin), Arc::new(grid))))
        })
        .collect::<Result<_, LincovError>>()?;
    cfg.cells
        .par_iter()
        .enumerate()
        .map(|(i, cell)| {
            let (lin, grid) = shared[leader[i]].as_ref().expect("every leader is linearised");
            analyse_cell(cell, lin, cfg.seed, settings, Some(grid))
        })
        .collect()
}
