//! What nominal data says is normal, and how far a frame is from it.
//!
//! - [`Scale`]: one detector's nominal location (median) and spread (a high quantile
//!   above the median) over the training frames; `(e - location) / spread` is the
//!   detector's calibrated score: 0 at the nominal median, 1 at the nominal
//!   [`SPREAD_QUANTILE`] quantile, whatever the detector's unit.
//! - [`NominalScales`]: the scales of every detector, fitted together
//!   ([`NominalScales::fit`]).
//! - [`CellStats`]: the same per cell of a coarse grid over the image (the scene-motion
//!   residual), so a cell that moves a little in every nominal run (a swaying cable, a
//!   reflective surface, the arm's usual path) counts less than one that never moves;
//!   [`pool_cells`] turns a frame's cell map into one number: normalised, each 2x2 block
//!   of cells reduced to its smallest value (an object must move in a whole block, so a
//!   one-cell glitch of the flow does not count), the mean of the largest few blocks (a
//!   small object counts).
//! - [`PhaseCells`]: optionally, the same statistics per phase of the task (seconds since
//!   the episode's first frame, in overlapping windows): a repeated task moves the same
//!   things at the same time in every nominal run, so what is normal at second 3 (the
//!   arm sweeping past a shelf) can be abnormal at second 8.
//!
//! Pure maths on slices: no image or robot types (this module is a leaf, like the rest
//! of `eval`).

use serde::{Deserialize, Serialize};

/// The quantile whose distance from the median is a detector's spread: a calibrated
/// score of 1 is as far out as 1 nominal frame in 100.
pub const SPREAD_QUANTILE: f64 = 0.99;
/// The quantile of a cell's nominal values that sets its spread (per cell there are as
/// many values as training frames, a few hundred to a few thousand).
pub const CELL_SPREAD_QUANTILE: f64 = 0.95;
/// Values a cell needs before its own statistics are used (else the grid's medians).
pub const MIN_CELL_SAMPLES: usize = 20;

/// A detector's nominal location and spread.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct Scale {
    /// Median over nominal frames.
    pub location: f64,
    /// The [`SPREAD_QUANTILE`] quantile minus the median (positive).
    pub spread: f64,
}

impl Scale {
    /// Fits the scale of `values` (NaN and infinities skipped); `None` with fewer than
    /// two finite values. A spread of zero (constant values) becomes the smallest
    /// positive spread that keeps scores finite: `max(|location| * 1e-6, 1e-12)`.
    pub fn fit(values: &[f64]) -> Option<Scale> {
        let mut v: Vec<f64> = values.iter().copied().filter(|x| x.is_finite()).collect();
        if v.len() < 2 {
            return None;
        }
        v.sort_by(f64::total_cmp);
        let location = quantile_sorted(&v, 0.5);
        let high = quantile_sorted(&v, SPREAD_QUANTILE);
        let floor = (location.abs() * 1e-6).max(1e-12);
        Some(Scale {
            location,
            spread: (high - location).max(floor),
        })
    }

    /// The calibrated score of `value`: `(value - location) / spread`. NaN stays NaN.
    pub fn score(&self, value: f64) -> f64 {
        (value - self.location) / self.spread
    }
}

/// The nominal scales of every detector (absent: the detector had no finite value).
pub type NominalScales = super::detector::PerDetector<Option<Scale>>;

/// Fits each detector's scale from its values over nominal frames.
pub fn fit_scales(values: &super::detector::PerDetector<Vec<f64>>) -> NominalScales {
    values.map(|_, v| Scale::fit(v))
}

/// Per-cell nominal statistics of a map of `columns x rows` cells (row-major).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct CellStats {
    /// Cells across.
    pub columns: usize,
    /// Cells down.
    pub rows: usize,
    /// Per-cell median of the nominal values (f64: the values survive a JSON round trip).
    pub location: Vec<f64>,
    /// Per-cell spread ([`CELL_SPREAD_QUANTILE`] minus the median), floored at a quarter
    /// of the grid's median spread so that a cell that never moved in the nominal runs
    /// does not turn sensor noise into a huge score.
    pub spread: Vec<f64>,
    /// Nominal maps the statistics come from.
    pub maps: usize,
    /// Per-phase statistics (absent: the same statistics at every phase).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phases: Option<PhaseCells>,
    /// The maps were taken with the photometric check (`residual.photometric`); scoring
    /// against these statistics takes its maps the same way whatever the profile says
    /// now, so a calibration made before the check keeps scoring as it was made.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub photometric: bool,
}

/// Per-cell statistics per phase window: window `i` is centred on `i * step_s` seconds
/// since the episode's first frame and spans `window_s`, `step_s = window_s / 2`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct PhaseCells {
    /// Width of a window, seconds.
    pub window_s: f64,
    /// Distance between window centres, seconds.
    pub step_s: f64,
    /// Per window, per cell median (a cell with too few values in a window keeps the
    /// phase-free value).
    pub location: Vec<Vec<f64>>,
    /// Per window, per cell spread (floored as the phase-free spread).
    pub spread: Vec<Vec<f64>>,
}

/// The statistics one frame is normalised with (borrowed from a [`CellStats`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CellNorm<'a> {
    /// Cells across.
    pub columns: usize,
    /// Cells down.
    pub rows: usize,
    /// Per-cell location.
    pub location: &'a [f64],
    /// Per-cell spread.
    pub spread: &'a [f64],
}

/// Why cell statistics cannot be fitted or used.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CellStatsError {
    /// Maps of different sizes.
    #[error("cell map {index} has {len} cells, expected {expected}")]
    Size {
        /// Which map.
        index: usize,
        /// Its cells.
        len: usize,
        /// The first map's cells.
        expected: usize,
    },
    /// Too few nominal maps for per-cell statistics.
    #[error(
        "per-cell statistics need at least {needed} nominal frames with a scene residual, got {got}"
    )]
    TooFew {
        /// Maps given.
        got: usize,
        /// Maps needed.
        needed: usize,
    },
}

impl CellStats {
    /// Fits per-cell statistics from nominal maps (NaN cells skipped). Cells with fewer
    /// than [`MIN_CELL_SAMPLES`] values take the grid's median location and spread.
    pub fn fit(columns: usize, rows: usize, maps: &[&[f32]]) -> Result<CellStats, CellStatsError> {
        let cells = columns * rows;
        if maps.len() < MIN_CELL_SAMPLES {
            return Err(CellStatsError::TooFew {
                got: maps.len(),
                needed: MIN_CELL_SAMPLES,
            });
        }
        if let Some((index, m)) = maps.iter().enumerate().find(|(_, m)| m.len() != cells) {
            return Err(CellStatsError::Size {
                index,
                len: m.len(),
                expected: cells,
            });
        }
        let (mut location, mut spread) = cell_quantiles(cells, maps.iter().copied());
        let grid_median = |v: &[f64]| {
            let mut finite: Vec<f64> = v.iter().copied().filter(|x| x.is_finite()).collect();
            finite.sort_by(f64::total_cmp);
            (!finite.is_empty()).then(|| quantile_sorted(&finite, 0.5))
        };
        let fallback_location = grid_median(&location).unwrap_or(0.0);
        let fallback_spread = grid_median(&spread).unwrap_or(1.0);
        let floor = (0.25 * fallback_spread).max(1e-6);
        for (l, s) in location.iter_mut().zip(&mut spread) {
            if !l.is_finite() {
                *l = fallback_location;
                *s = fallback_spread;
            }
            *s = s.max(floor);
        }
        Ok(CellStats {
            columns,
            rows,
            location,
            spread,
            maps: maps.len(),
            phases: None,
            photometric: false,
        })
    }

    /// [`CellStats::fit`], plus statistics per phase window of `window_s` seconds
    /// (`phases_s[i]`: seconds since its episode's first frame of `maps[i]`). A cell with
    /// fewer than [`MIN_CELL_SAMPLES`] values in a window keeps its phase-free statistics;
    /// every spread is floored as the phase-free ones. `window_s <= 0` (or not finite):
    /// no phases.
    pub fn fit_phased(
        columns: usize,
        rows: usize,
        maps: &[&[f32]],
        phases_s: &[f64],
        window_s: f64,
    ) -> Result<CellStats, CellStatsError> {
        let mut stats = CellStats::fit(columns, rows, maps)?;
        if !(window_s > 0.0 && window_s.is_finite()) || phases_s.len() != maps.len() {
            return Ok(stats);
        }
        let last = phases_s
            .iter()
            .copied()
            .filter(|t| t.is_finite())
            .fold(0.0f64, f64::max);
        let step_s = window_s / 2.0;
        // Bounded: a window per half window of the longest nominal episode.
        let windows = ((last / step_s).ceil() as usize + 1).min(MAX_PHASE_WINDOWS);
        let floor = stats.spread.iter().copied().fold(f64::INFINITY, f64::min);
        let cells = columns * rows;
        let (mut locations, mut spreads) =
            (Vec::with_capacity(windows), Vec::with_capacity(windows));
        for w in 0..windows {
            let centre = w as f64 * step_s;
            let in_window = maps
                .iter()
                .zip(phases_s)
                .filter(|(_, t)| (**t - centre).abs() <= step_s)
                .map(|(m, _)| *m);
            let (mut location, mut spread) = cell_quantiles(cells, in_window);
            for c in 0..cells {
                if location[c].is_finite() {
                    spread[c] = spread[c].max(floor);
                } else {
                    location[c] = stats.location[c];
                    spread[c] = stats.spread[c];
                }
            }
            locations.push(location);
            spreads.push(spread);
        }
        stats.phases = Some(PhaseCells {
            window_s,
            step_s,
            location: locations,
            spread: spreads,
        });
        Ok(stats)
    }

    /// The statistics for a frame `phase_s` seconds into its episode: the nearest phase
    /// window's, or the phase-free ones (no phases, no phase given, or a phase more than
    /// half a window past the last window: nominal runs never got there).
    pub fn at(&self, phase_s: Option<f64>) -> CellNorm<'_> {
        let phase_free = CellNorm {
            columns: self.columns,
            rows: self.rows,
            location: &self.location,
            spread: &self.spread,
        };
        let (Some(p), Some(t)) = (&self.phases, phase_s) else {
            return phase_free;
        };
        if !(t.is_finite() && t >= 0.0 && p.step_s > 0.0) {
            return phase_free;
        }
        let w = (t / p.step_s).round() as usize;
        match (p.location.get(w), p.spread.get(w)) {
            (Some(location), Some(spread))
                if location.len() == self.location.len() && spread.len() == self.spread.len() =>
            {
                CellNorm {
                    columns: self.columns,
                    rows: self.rows,
                    location,
                    spread,
                }
            }
            _ => phase_free,
        }
    }
}

/// Most phase windows fitted (a 1 s window over a 10-minute task is 1,200).
pub const MAX_PHASE_WINDOWS: usize = 4096;

/// Per-cell median and spread ([`CELL_SPREAD_QUANTILE`] minus the median) of the finite
/// values of `maps`; NaN for a cell with fewer than [`MIN_CELL_SAMPLES`] values.
fn cell_quantiles<'a>(
    cells: usize,
    maps: impl Iterator<Item = &'a [f32]> + Clone,
) -> (Vec<f64>, Vec<f64>) {
    let mut location = vec![f64::NAN; cells];
    let mut spread = vec![f64::NAN; cells];
    let mut column = Vec::new();
    for c in 0..cells {
        column.clear();
        column.extend(
            maps.clone()
                .filter_map(|m| m.get(c))
                .map(|&v| f64::from(v))
                .filter(|v| v.is_finite()),
        );
        if column.len() < MIN_CELL_SAMPLES {
            continue;
        }
        column.sort_by(f64::total_cmp);
        let median = quantile_sorted(&column, 0.5);
        location[c] = median;
        spread[c] = quantile_sorted(&column, CELL_SPREAD_QUANTILE) - median;
    }
    (location, spread)
}

/// How a cell map becomes one number.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pooling {
    /// Share of the valid cells averaged at the top (at least one cell).
    pub top_fraction: f64,
}

/// Pools a frame's cell map (`columns x rows`, NaN = no value) into one score: each cell
/// normalised by `stats` (raw values without them), each 2x2 block with at least two
/// valid cells reduced to its smallest valid value ([`block_minima`]), then the mean of
/// the largest `top_fraction` of the blocks. `None` when no cell has a value or the map does not match the
/// statistics. `normalised`, when given, receives the normalised map (before the blocks).
pub fn pool_cells(
    cells: &[f32],
    columns: usize,
    rows: usize,
    stats: Option<CellNorm<'_>>,
    pooling: Pooling,
    normalised: Option<&mut Vec<f32>>,
) -> Option<f64> {
    if cells.len() != columns * rows {
        return None;
    }
    if let Some(s) = stats
        && (s.columns != columns
            || s.rows != rows
            || s.location.len() != cells.len()
            || s.spread.len() != cells.len())
    {
        return None;
    }
    let z: Vec<f32> = match stats {
        Some(s) => cells
            .iter()
            .zip(s.location.iter().zip(s.spread))
            .map(|(&v, (&l, &sp))| ((f64::from(v) - l) / sp) as f32)
            .collect(),
        None => cells.to_vec(),
    };
    let mut smooth = block_minima(&z, columns, rows);
    if let Some(out) = normalised {
        *out = z;
    }
    if smooth.is_empty() {
        return None;
    }
    let k = ((smooth.len() as f64 * pooling.top_fraction).round() as usize).clamp(1, smooth.len());
    let split = smooth.len() - k;
    let last = smooth.len() - 1;
    smooth.select_nth_unstable_by(split.min(last), f64::total_cmp);
    Some(smooth[split..].iter().sum::<f64>() / k as f64)
}

/// The smallest valid value of every 2x2 block of cells (overlapping, stride 1) that has
/// at least two valid cells. A map one cell wide or high has no blocks: its valid cells
/// are returned as they are.
pub fn block_minima(z: &[f32], columns: usize, rows: usize) -> Vec<f64> {
    if columns < 2 || rows < 2 {
        return z
            .iter()
            .filter(|v| v.is_finite())
            .map(|&v| f64::from(v))
            .collect();
    }
    let mut out = Vec::with_capacity((columns - 1) * (rows - 1));
    for r in 0..rows - 1 {
        for c in 0..columns - 1 {
            let block = [
                z[r * columns + c],
                z[r * columns + c + 1],
                z[(r + 1) * columns + c],
                z[(r + 1) * columns + c + 1],
            ];
            let valid = block.iter().filter(|v| v.is_finite());
            if valid.clone().count() >= 2 {
                out.push(f64::from(valid.fold(f32::INFINITY, |a, &b| a.min(b))));
            }
        }
    }
    out
}

/// The `q` quantile (0..=1) of sorted values, linear between order statistics (NumPy's
/// default). `values` must not be empty.
pub fn quantile_sorted(values: &[f64], q: f64) -> f64 {
    let pos = q.clamp(0.0, 1.0) * (values.len() - 1) as f64;
    let lo = pos.floor() as usize;
    let hi = pos.ceil() as usize;
    values[lo] + (values[hi] - values[lo]) * (pos - lo as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn scale_is_median_and_high_quantile() {
        let v: Vec<f64> = (0..=100).map(f64::from).collect();
        let s = Scale::fit(&v).unwrap();
        assert_eq!(s.location, 50.0);
        assert!((s.spread - 49.0).abs() < 1e-9);
        assert!((s.score(99.0) - 1.0).abs() < 1e-9);
        assert_eq!(Scale::fit(&[1.0]), None);
        assert_eq!(Scale::fit(&[f64::NAN, 2.0, f64::INFINITY]), None);
        let flat = Scale::fit(&[3.0, 3.0, 3.0]).unwrap();
        assert!(flat.spread > 0.0 && flat.score(3.0) == 0.0 && flat.score(4.0).is_finite());
    }

    #[test]
    fn quantiles_match_numpy_linear() {
        let v = [1.0, 2.0, 4.0, 8.0];
        assert_eq!(quantile_sorted(&v, 0.5), 3.0);
        assert!((quantile_sorted(&v, 0.9) - 6.8).abs() < 1e-12);
        assert_eq!(quantile_sorted(&v, 0.0), 1.0);
        assert_eq!(quantile_sorted(&v, 1.0), 8.0);
    }

    fn nominal_maps(n: usize) -> Vec<Vec<f32>> {
        // 4x3 cells; cell 5 is busy (large nominal values), the others quiet.
        (0..n)
            .map(|i| {
                (0..12)
                    .map(|c| {
                        let noise = ((i * 7 + c * 3) % 11) as f32 / 10.0;
                        if c == 5 {
                            10.0 + 5.0 * noise
                        } else {
                            0.1 * noise
                        }
                    })
                    .collect()
            })
            .collect()
    }

    #[test]
    fn busy_cells_count_less_than_quiet_ones() {
        let maps = nominal_maps(200);
        let refs: Vec<&[f32]> = maps.iter().map(Vec::as_slice).collect();
        let stats = CellStats::fit(4, 3, &refs).unwrap();
        assert_eq!(stats.maps, 200);
        let pooling = Pooling { top_fraction: 0.0 };
        // The same raw value of 12 px: nominal in the busy cell, far out in a quiet one.
        let mut busy = vec![0.05f32; 12];
        busy[5] = 12.0;
        let mut quiet = vec![0.05f32; 12];
        for c in [2, 3, 6, 7] {
            quiet[c] = 12.0;
        }
        let b = pool_cells(&busy, 4, 3, Some(stats.at(None)), pooling, None).unwrap();
        let q = pool_cells(&quiet, 4, 3, Some(stats.at(None)), pooling, None).unwrap();
        assert!(q > 10.0 * b.max(1.0), "quiet {q} vs busy {b}");
        // Without statistics: raw values, and one hot cell alone is a glitch, not motion.
        let rb = pool_cells(&busy, 4, 3, None, pooling, None).unwrap();
        let rq = pool_cells(&quiet, 4, 3, None, pooling, None).unwrap();
        assert_eq!(rb, 0.05f32 as f64);
        assert!(rq > 1.0, "a block moving: {rq}");
    }

    #[test]
    fn pooling_skips_missing_cells_and_refuses_mismatches() {
        let mut cells = vec![f32::NAN; 12];
        let pooling = Pooling { top_fraction: 0.5 };
        assert_eq!(pool_cells(&cells, 4, 3, None, pooling, None), None);
        cells[7] = 2.0;
        assert_eq!(
            pool_cells(&cells, 4, 3, None, pooling, None),
            None,
            "one cell"
        );
        cells[3] = 3.0;
        assert_eq!(pool_cells(&cells, 4, 3, None, pooling, None), Some(2.0));
        assert_eq!(pool_cells(&cells, 3, 3, None, pooling, None), None);
        let maps = nominal_maps(30);
        let refs: Vec<&[f32]> = maps.iter().map(Vec::as_slice).collect();
        let stats = CellStats::fit(4, 3, &refs).unwrap();
        assert_eq!(
            pool_cells(&cells[..6], 3, 2, Some(stats.at(None)), pooling, None),
            None
        );
    }

    #[test]
    fn fitting_needs_enough_maps_of_one_size() {
        let maps = nominal_maps(5);
        let refs: Vec<&[f32]> = maps.iter().map(Vec::as_slice).collect();
        assert!(matches!(
            CellStats::fit(4, 3, &refs),
            Err(CellStatsError::TooFew { got: 5, .. })
        ));
        let mut maps = nominal_maps(25);
        maps[3].pop();
        let refs: Vec<&[f32]> = maps.iter().map(Vec::as_slice).collect();
        assert!(matches!(
            CellStats::fit(4, 3, &refs),
            Err(CellStatsError::Size { index: 3, .. })
        ));
    }

    #[test]
    fn a_cell_seen_too_rarely_takes_the_grid_median() {
        let mut maps = nominal_maps(40);
        for m in &mut maps {
            m[2] = f32::NAN;
        }
        let refs: Vec<&[f32]> = maps.iter().map(Vec::as_slice).collect();
        let stats = CellStats::fit(4, 3, &refs).unwrap();
        assert!(stats.location[2].is_finite() && stats.spread[2] > 0.0);
        assert!(stats.location[2] < 1.0, "the quiet majority's median");
    }
}
