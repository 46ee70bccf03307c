//! Calibration helpers of the detectors whose value pools a per-cell map (the scene
//! residual, the flow predictor's error with `flow_pooling = "cells"`).

use crate::eval::{CellStats, Detector, Pooling, pool_cells};
use crate::pipeline::residual::ResidualParams;
use crate::pipeline::scorer::FrameScore;

/// Where a frame keeps one detector's cell map: the cells and their `(columns, rows)`.
pub type CellMap = fn(&FrameScore) -> Option<(&[f32], (usize, usize))>;

/// Per-cell statistics of the cell maps `map` takes from the training frames (those of
/// the first map's grid); `None` when no frame has one. With `phase_window_s > 0`, per
/// phase window as well (`phases`: each frame's seconds into its episode).
fn fit_cells(
    frames: &[&FrameScore],
    phases: &[f64],
    map: CellMap,
    phase_window_s: f64,
) -> Option<Result<CellStats, String>> {
    let (_, (columns, rows)) = frames.iter().find_map(|f| map(f))?;
    let (maps, map_phases): (Vec<&[f32]>, Vec<f64>) = frames
        .iter()
        .zip(phases)
        .filter_map(|(f, &t)| {
            map(f)
                .filter(|(_, g)| *g == (columns, rows))
                .map(|(m, _)| (m, t))
        })
        .unzip();
    Some(
        CellStats::fit_phased(columns, rows, &maps, &map_phases, phase_window_s)
            .map_err(|e| e.to_string()),
    )
}

/// A detector whose value pools a cell map: where its frames keep the map, and what a
/// calibration note says when there are too few maps (`what` statistics missing, and
/// `then`).
pub struct CellDetector {
    /// The detector.
    pub detector: Detector,
    /// Where a frame keeps its map.
    pub map: CellMap,
    /// The statistics' name in notes.
    pub what: &'static str,
    /// What scoring does without them.
    pub then: &'static str,
}

/// The per-cell statistics of `detector` from the training `frames` (`phases`: each one's
/// seconds into its episode), and each frame's value pooled again with them (as scored
/// where there are none: no maps, or too few, said in `notes`).
pub fn fit(
    frames: &[&FrameScore],
    phases: &[f64],
    residual: &ResidualParams,
    notes: &mut Vec<String>,
    detector: &CellDetector,
) -> (Option<CellStats>, Vec<Option<f64>>) {
    let stats = fit_noted(frames, phases, residual, notes, detector);
    let values = repool(frames, phases, stats.as_ref(), residual, detector);
    (stats, values)
}

/// [`fit_cells`] with a note when the maps are too few.
fn fit_noted(
    frames: &[&FrameScore],
    phases: &[f64],
    residual: &ResidualParams,
    notes: &mut Vec<String>,
    detector: &CellDetector,
) -> Option<CellStats> {
    match fit_cells(frames, phases, detector.map, residual.phase_window_s)? {
        Ok(stats) => Some(stats),
        Err(e) => {
            notes.push(format!(
                "no per-cell {} statistics ({e}): {}",
                detector.what, detector.then
            ));
            None
        }
    }
}

/// Each training frame's value pooled again from its cells with the fitted `stats` (as it
/// is then scored); the value as scored without statistics for a frame without cells or
/// when there are no statistics.
fn repool(
    frames: &[&FrameScore],
    phases: &[f64],
    stats: Option<&CellStats>,
    residual: &ResidualParams,
    detector: &CellDetector,
) -> Vec<Option<f64>> {
    let pooling = Pooling {
        top_fraction: residual.top_fraction,
    };
    frames
        .iter()
        .zip(phases)
        .map(|(f, &phase)| match ((detector.map)(f), stats) {
            (Some((cells, (columns, rows))), Some(stats)) => pool_cells(
                cells,
                columns,
                rows,
                Some(stats.at(Some(phase))),
                pooling,
                None,
            ),
            _ => f.values[detector.detector],
        })
        .collect()
}
