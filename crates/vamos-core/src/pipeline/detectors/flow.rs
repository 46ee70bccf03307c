//! `e_o`, the flow-prediction error (REFERENCE.md section 3): the probabilistic U-Net's
//! predictions of this frame's flow from the past `A..=A+B` frames against the observed
//! flow, the best of them; the paper's mean squared error, or (`flow_pooling = "cells"`)
//! the error per cell pooled against the nominal per-cell statistics.
//!
//! Calibration ([`fit`]): with cells, per-cell statistics of the training frames' error
//! maps and their `e_o` pooled again with them.

use super::cells::{self, CellDetector};
use super::{FrameContext, FrameDetector};
use crate::eval::{CellStats, Detector, Pooling, pool_cells};
use crate::pipeline::PipelineConfig;
use crate::pipeline::residual::{self, FlowPooling, ResidualParams};
use crate::pipeline::scorer::{FrameScore, ScorerError};
use std::sync::Arc;
use vamos_model::FlowModel;
use vamos_model::predictor::{Prediction, Predictor, PredictorParams};

/// The flow-prediction detector: the predictor of one stream.
pub struct Flow {
    predictor: Predictor,
    residual: ResidualParams,
    heatmaps: bool,
}

impl Flow {
    /// The predictor of `model` with the pipeline's offsets and samples (`samples` when
    /// the pipeline does not say; 0: the bundle's), seeded with `seed`; with `heatmaps`,
    /// each frame keeps its error map.
    pub fn new(
        config: &PipelineConfig,
        model: Arc<FlowModel>,
        samples: usize,
        seed: u64,
        heatmaps: bool,
    ) -> Result<Flow, ScorerError> {
        let manifest = model.manifest();
        if manifest.flow_variant != config.frames.variant {
            tracing::warn!(
                model = ?manifest.flow_variant,
                pipeline = %config.frames.variant,
                "the model was trained on another flow variant than the pipeline computes"
            );
        }
        let samples = config.samples.unwrap_or(samples);
        let mut params = PredictorParams::from_manifest(manifest, samples);
        if let Some(a) = config.offset_a {
            params.a = a;
        }
        if let Some(b) = config.offset_b {
            params.b = b;
        }
        Ok(Flow {
            predictor: Predictor::new(model, params, seed)?,
            residual: config.residual.clone(),
            heatmaps,
        })
    }
}

impl FrameDetector for Flow {
    fn detector(&self) -> Detector {
        Detector::Flow
    }

    /// Writes `warming_up` (fewer than `A + B` frames of history), the best offset, the
    /// error map (with heatmaps) and the cells (`flow_pooling = "cells"`).
    fn measure(
        &mut self,
        frame: &FrameContext<'_>,
        out: &mut FrameScore,
    ) -> Result<Option<f64>, ScorerError> {
        let Some(processed) = frame.processed else {
            return Ok(None);
        };
        let p = self.predictor.params();
        let history = self.predictor.frames_seen();
        let size = self.predictor.model().dims().size;
        let prediction = self
            .predictor
            .push(&processed.network_input, processed.network_valid.as_deref())?;
        let full_history = history >= (p.a + p.b) as u64;
        let s = match prediction {
            Prediction::Scored(s) if full_history => s,
            Prediction::Scored(_) | Prediction::WarmingUp { .. } => {
                out.warming_up = true;
                return Ok(None);
            }
            Prediction::NoValidPixels { .. } => {
                out.warming_up = !full_history;
                return Ok(None);
            }
        };
        let thresholds = frame.thresholds;
        // Cells once calibrated with them, or before any calibration (what the calibration
        // fits on); the paper's mean under a calibration made with it.
        let e_o = if self.residual.flow_pooling == FlowPooling::Cells
            && (thresholds.flow.is_some() || thresholds.scales.is_none())
        {
            let (columns, rows) = residual::cell_grid(size, size, self.residual.flow_cell_px);
            let cells = residual::flow_cells(
                &s.error_map,
                processed.network_valid.as_deref(),
                size,
                self.residual.flow_cell_px,
            );
            let e_o = pool_cells(
                &cells,
                columns,
                rows,
                thresholds.flow.as_ref().map(|f| f.at(Some(frame.phase_s))),
                Pooling {
                    top_fraction: self.residual.top_fraction,
                },
                None,
            );
            out.flow_cells = Some(cells);
            out.flow_grid = (columns, rows);
            e_o
        } else {
            Some(s.e_o)
        };
        out.best_offset = Some(s.n);
        out.heatmap = self.heatmaps.then_some(s.error_map);
        Ok(e_o)
    }

    fn reset(&mut self) {
        self.predictor.reset();
    }

    fn predictor_params(&self) -> Option<PredictorParams> {
        Some(self.predictor.params())
    }
}

/// A frame's flow-error cells and their `(columns, rows)`.
pub fn cell_map(f: &FrameScore) -> Option<(&[f32], (usize, usize))> {
    Some((f.flow_cells.as_deref()?, f.flow_grid))
}

/// The flow-error statistics of a calibration (`flow_pooling = "cells"`) from the training
/// `frames`, and each frame's `e_o` pooled again with them (as scored where there are
/// none: no cells, or too few maps, said in `notes`).
pub fn fit(
    frames: &[&FrameScore],
    phases: &[f64],
    residual: &ResidualParams,
    notes: &mut Vec<String>,
) -> (Option<CellStats>, Vec<Option<f64>>) {
    cells::fit(
        frames,
        phases,
        residual,
        notes,
        &CellDetector {
            detector: Detector::Flow,
            map: cell_map,
            what: "flow-error",
            then: "e_o is scored from raw cell errors",
        },
    )
}
