//! The per-robot-session flow predictor: `e_o` of each processed frame.
//!
//! For frame `t` the pipeline hands the network input `O_t` (`[2, S, S]`,
//! `vision::preprocess::network_input`). The encoder runs once per frame, on `O_t`, and
//! its outputs (features, prior mean and log sigma) are kept for the last `A + B` frames.
//! For every `n` in `A..=A+B` whose frame `t - n` exists, `M` latent samples
//! `z = mu + exp(log_sigma) * eps` are drawn and the head runs once on the whole batch of
//! `(B + 1) * M` rows. `e_o` is the smallest mean squared error between a prediction and
//! `O_t` over the valid pixels (both channels).
//!
//! Random numbers: [`NormalRng`]; for frame `t` the normals are drawn in the order
//! n ascending, then sample, then latent index. Frames with no valid pixel and warming-up
//! frames draw none.

use super::head::{HeadScratch, NativeHead, RowScore};
use super::network::{FlowModel, ModelDims};
use super::rng::NormalRng;
use super::{ModelError, bundle::Manifest};
use std::collections::VecDeque;
use std::sync::Arc;

mod batch;
mod naive;

pub use batch::{BatchItem, push_batch};
pub use naive::naive_score;

/// Largest past offset `A + B`, processed frames (100 s at 10 Hz): the predictor keeps the
/// encoder outputs of that many past frames. Model bundles and pipeline overrides come
/// from outside (uploads, stored profiles), so a value beyond it is refused rather than
/// allocated.
pub const MAX_PAST_OFFSET: usize = 1000;

/// Most prior samples `M` per past offset.
pub const MAX_SAMPLES: usize = 1000;

/// Most head rows `(B + 1) * M` one frame may need (the paper's 5 offsets x 10 samples
/// need 50).
pub const MAX_HEAD_ROWS: usize = 10_000;

/// Temporal parameters of a predictor.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct PredictorParams {
    /// Smallest past offset A (processed frames).
    pub a: usize,
    /// Offsets span `A..=A+B`.
    pub b: usize,
    /// Prior samples M per offset.
    pub samples: usize,
}

impl PredictorParams {
    /// The bundle's parameters; `samples_override > 0` replaces its `m`.
    pub fn from_manifest(manifest: &Manifest, samples_override: usize) -> Self {
        Self {
            a: manifest.temporal.a as usize,
            b: manifest.temporal.b as usize,
            samples: if samples_override > 0 {
                samples_override
            } else {
                manifest.temporal.m as usize
            },
        }
    }

    fn validate(&self) -> Result<(), ModelError> {
        if self.a == 0 {
            return Err(ModelError::InvalidParams {
                field: "a",
                reason: "the past offset must be at least 1".into(),
            });
        }
        if self.samples == 0 {
            return Err(ModelError::InvalidParams {
                field: "samples",
                reason: "at least one prior sample is needed".into(),
            });
        }
        if self
            .a
            .checked_add(self.b)
            .is_none_or(|n| n > MAX_PAST_OFFSET)
        {
            return Err(ModelError::InvalidParams {
                field: "a, b",
                reason: format!(
                    "past offsets up to A + B = {} + {} exceed the limit of {MAX_PAST_OFFSET} frames",
                    self.a, self.b
                ),
            });
        }
        if self.samples > MAX_SAMPLES {
            return Err(ModelError::InvalidParams {
                field: "samples",
                reason: format!(
                    "{} prior samples exceed the limit of {MAX_SAMPLES}",
                    self.samples
                ),
            });
        }
        // b <= MAX_PAST_OFFSET and samples <= MAX_SAMPLES here: no overflow.
        if (self.b + 1) * self.samples > MAX_HEAD_ROWS {
            return Err(ModelError::InvalidParams {
                field: "b, samples",
                reason: format!(
                    "(B + 1) x M = {} x {} head rows per frame exceed the limit of {MAX_HEAD_ROWS}",
                    self.b + 1,
                    self.samples
                ),
            });
        }
        Ok(())
    }
}

/// The score of one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct FlowScore {
    /// Index of the frame in this predictor's stream (0 = the first pushed).
    pub frame: u64,
    /// The smallest mean squared prediction error over offsets and samples (valid pixels,
    /// both channels; normalised units of the network input).
    pub e_o: f64,
    /// The offset n of the best prediction.
    pub n: usize,
    /// The sample index (0..M) of the best prediction.
    pub sample: usize,
    /// `[S, S]` per-pixel squared error of the best prediction, the mean over the two
    /// channels (so its mean over the valid pixels is `e_o`); 0 at masked pixels.
    pub error_map: Vec<f32>,
    /// Valid pixels the error was taken over.
    pub valid_px: usize,
}

/// The outcome of one frame.
#[derive(Clone, Debug, PartialEq)]
pub enum Prediction {
    /// Fewer than A past frames exist: no score (not a fake one).
    WarmingUp {
        /// Frames seen before this one.
        frames_seen: u64,
        /// Frames needed before the first score (A).
        frames_needed: usize,
    },
    /// The mask left no valid pixel: no score. The frame is still cached for later ones.
    NoValidPixels {
        /// Index of the frame.
        frame: u64,
    },
    /// A score.
    Scored(FlowScore),
}

#[derive(Clone, Debug)]
struct Cached {
    /// What the head needs of the frame: its features `[C, S, S]` for ONNX Runtime's head,
    /// or their projection through the first fcomb layer `[H1, S, S]` for the native head
    /// ([`NativeHead::project`]).
    state: Vec<f32>,
    mu: Vec<f32>,
    log_sigma: Vec<f32>,
}

/// Per-session predictor state: the encoder cache, the generator and reusable buffers.
#[derive(Debug)]
pub struct Predictor {
    model: Arc<FlowModel>,
    params: PredictorParams,
    rng: NormalRng,
    /// Encoder outputs of the last `A + B` frames, oldest first.
    ring: VecDeque<Cached>,
    frames: u64,
    feature_batch: Vec<f32>,
    z_batch: Vec<f32>,
    predictions: Vec<f32>,
    /// Native head buffers: the row being computed, the best row so far, kernel scratch.
    row: Vec<f32>,
    best: Vec<f32>,
    scratch: HeadScratch,
}

/// Checks the input flow and mask; returns the number of valid pixels.
fn check_input(dims: ModelDims, input: &[f32], mask: Option<&[bool]>) -> Result<usize, ModelError> {
    if input.len() != dims.flow_len() {
        return Err(ModelError::InputShape {
            what: "flow input",
            expected: dims.flow_len(),
            actual: input.len(),
        });
    }
    if let Some(index) = input.iter().position(|v| !v.is_finite()) {
        return Err(ModelError::NonFiniteInput {
            what: "flow input",
            index,
        });
    }
    let px = dims.size * dims.size;
    match mask {
        Some(m) if m.len() != px => Err(ModelError::InputShape {
            what: "mask",
            expected: px,
            actual: m.len(),
        }),
        Some(m) => Ok(m.iter().filter(|v| **v).count()),
        None => Ok(px),
    }
}

/// Draws `z` for `samples` rows from one prior into `z_out` (appended).
fn draw(rng: &mut NormalRng, mu: &[f32], log_sigma: &[f32], samples: usize, z_out: &mut Vec<f32>) {
    for _ in 0..samples {
        for (m, s) in mu.iter().zip(log_sigma) {
            z_out.push(m + s.exp() * rng.normal() as f32);
        }
    }
}

/// Mean squared error of one prediction `[2, S, S]` against `target` over the valid pixels
/// (both channels), accumulated in f64.
fn row_mse(
    dims: ModelDims,
    p: &[f32],
    target: &[f32],
    mask: Option<&[bool]>,
    valid_px: usize,
) -> f64 {
    let px = dims.size * dims.size;
    let mut sum = 0.0f64;
    for c in 0..2 {
        let (pc, tc) = (&p[c * px..(c + 1) * px], &target[c * px..(c + 1) * px]);
        match mask {
            None => {
                for (a, b) in pc.iter().zip(tc) {
                    let d = f64::from(*a) - f64::from(*b);
                    sum += d * d;
                }
            }
            Some(m) => {
                for ((a, b), ok) in pc.iter().zip(tc).zip(m) {
                    if *ok {
                        let d = f64::from(*a) - f64::from(*b);
                        sum += d * d;
                    }
                }
            }
        }
    }
    sum / (2 * valid_px) as f64
}

/// The best row of `predictions` (`rows` flows) against `target`: (row, mse).
fn best_row(
    dims: ModelDims,
    predictions: &[f32],
    rows: usize,
    target: &[f32],
    mask: Option<&[bool]>,
    valid_px: usize,
) -> (usize, f64) {
    let flow_len = dims.flow_len();
    let mut best = (0, f64::INFINITY);
    for r in 0..rows {
        let p = &predictions[r * flow_len..(r + 1) * flow_len];
        let mse = row_mse(dims, p, target, mask, valid_px);
        // A NaN prediction never wins; ties keep the first row.
        if mse < best.1 {
            best = (r, mse);
        }
    }
    best
}

fn error_map(
    dims: ModelDims,
    prediction: &[f32],
    target: &[f32],
    mask: Option<&[bool]>,
) -> Vec<f32> {
    let px = dims.size * dims.size;
    (0..px)
        .map(|i| {
            if mask.is_some_and(|m| !m[i]) {
                return 0.0;
            }
            let du = prediction[i] - target[i];
            let dv = prediction[px + i] - target[px + i];
            0.5 * (du * du + dv * dv)
        })
        .collect()
}

impl Predictor {
    /// A predictor for one robot session, its generator seeded with `seed`.
    pub fn new(
        model: Arc<FlowModel>,
        params: PredictorParams,
        seed: u64,
    ) -> Result<Self, ModelError> {
        params.validate()?;
        Ok(Self {
            model,
            params,
            rng: NormalRng::new(seed),
            ring: VecDeque::with_capacity(params.a + params.b + 1),
            frames: 0,
            feature_batch: Vec::new(),
            z_batch: Vec::new(),
            predictions: Vec::new(),
            row: Vec::new(),
            best: Vec::new(),
            scratch: HeadScratch::default(),
        })
    }

    /// The model this predictor uses.
    pub fn model(&self) -> &Arc<FlowModel> {
        &self.model
    }

    /// The temporal parameters.
    pub fn params(&self) -> PredictorParams {
        self.params
    }

    /// Frames pushed so far.
    pub fn frames_seen(&self) -> u64 {
        self.frames
    }

    /// Forgets the past frames (a new episode); the generator continues its stream.
    pub fn reset(&mut self) {
        self.ring.clear();
        self.frames = 0;
    }

    /// Scores frame `t` (the next one) and caches its encoder output for later frames.
    ///
    /// `input` is `O_t`, `[2, S, S]`; `mask` marks valid pixels (`true` = use), `[S, S]`.
    /// A bad input is an error and leaves the state untouched; so does a failure of either
    /// network call (the frame is then not counted).
    pub fn push(&mut self, input: &[f32], mask: Option<&[bool]>) -> Result<Prediction, ModelError> {
        let prepared = self.prepare(input, mask)?;
        let model = self.model.clone();
        if let Some(head) = model.native_head() {
            let enc = model.encode(input, 1)?;
            return Ok(self.finish_native(
                head,
                prepared,
                input,
                mask,
                enc.features,
                enc.prior_mu,
                enc.prior_log_sigma,
            ));
        }
        if prepared.rows > 0 {
            model.predict_into(
                &self.feature_batch,
                &self.z_batch,
                prepared.rows,
                &mut self.predictions,
            )?;
        }
        let enc = model.encode(input, 1)?;
        let predictions = std::mem::take(&mut self.predictions);
        let best = self.best_of(&prepared, &predictions, input, mask);
        let out = self.finish(
            prepared,
            input,
            mask,
            best,
            enc.features,
            enc.prior_mu,
            enc.prior_log_sigma,
        );
        self.predictions = predictions;
        Ok(out)
    }

    /// Runs the native head on the prepared frame's rows, then [`Predictor::finish`].
    #[allow(clippy::too_many_arguments)]
    fn finish_native(
        &mut self,
        head: &NativeHead,
        prepared: Prepared,
        input: &[f32],
        mask: Option<&[bool]>,
        features: Vec<f32>,
        mu: Vec<f32>,
        log_sigma: Vec<f32>,
    ) -> Prediction {
        let best = self.native_best(head, &prepared, input, mask);
        let best_pred = std::mem::take(&mut self.best);
        let out = self.finish(
            prepared,
            input,
            mask,
            best.map(|(row, e_o)| (row, e_o, best_pred.as_slice())),
            features,
            mu,
            log_sigma,
        );
        self.best = best_pred;
        out
    }

    /// The best of ONNX Runtime's head `predictions` for a prepared frame:
    /// (row, mse, the row's prediction).
    fn best_of<'a>(
        &self,
        prepared: &Prepared,
        predictions: &'a [f32],
        input: &[f32],
        mask: Option<&[bool]>,
    ) -> Option<(usize, f64, &'a [f32])> {
        if prepared.rows == 0 || prepared.valid_px == 0 {
            return None;
        }
        let dims = self.model.dims();
        let (row, e_o) = best_row(
            dims,
            predictions,
            prepared.rows,
            input,
            mask,
            prepared.valid_px,
        );
        let fl = dims.flow_len();
        Some((row, e_o, &predictions[row * fl..(row + 1) * fl]))
    }

    /// Runs the native head on every row of a prepared frame, keeping the best prediction
    /// in `self.best`: (row, mse), or `None` when there are no rows.
    fn native_best(
        &mut self,
        head: &NativeHead,
        prepared: &Prepared,
        input: &[f32],
        mask: Option<&[bool]>,
    ) -> Option<(usize, f64)> {
        if prepared.rows == 0 || prepared.valid_px == 0 {
            return None;
        }
        let dims = self.model.dims();
        let (fl, l, m) = (dims.flow_len(), dims.latent, self.params.samples);
        self.row.resize(fl, 0.0);
        self.best.resize(fl, 0.0);
        // Sums of squared errors; a row stops as soon as it cannot beat the best so far.
        let mut best: Option<(usize, f64)> = None;
        for (k, &n) in prepared.offsets.iter().enumerate() {
            let state = &self.ring[self.ring.len() - n].state;
            for s in 0..m {
                let r = k * m + s;
                let z = &self.z_batch[r * l..(r + 1) * l];
                let bound = best.map_or(f64::INFINITY, |b| b.1);
                let sse = head.predict_row_sse(
                    state,
                    z,
                    &mut self.row,
                    &mut self.scratch,
                    RowScore {
                        target: input,
                        mask,
                        bound,
                    },
                );
                // As `best_row`: a NaN prediction never wins; ties keep the first row.
                if let Some(sse) = sse.filter(|v| *v < bound) {
                    best = Some((r, sse));
                    std::mem::swap(&mut self.row, &mut self.best);
                }
            }
        }
        let best = best.map(|(r, sse)| (r, sse / (2 * prepared.valid_px) as f64));
        if best.is_none() {
            // Every row was NaN or infinite: row 0 with an infinite error, as `best_row`.
            let state = &self.ring[self.ring.len() - prepared.offsets[0]].state;
            head.predict_row(state, &self.z_batch[..l], &mut self.best, &mut self.scratch);
            return Some((0, f64::INFINITY));
        }
        best
    }

    /// Validates the input and assembles this frame's head rows in `feature_batch` and
    /// `z_batch`, drawing from a copy of the generator. Changes no state.
    fn prepare(&mut self, input: &[f32], mask: Option<&[bool]>) -> Result<Prepared, ModelError> {
        let dims = self.model.dims();
        let valid_px = check_input(dims, input, mask)?;
        let t = self.frames;
        let p = self.params;
        let mut rng = self.rng.clone();
        self.feature_batch.clear();
        self.z_batch.clear();
        let mut offsets = Vec::new();
        if (t as usize) >= p.a && valid_px > 0 {
            offsets = (p.a..=p.a + p.b)
                .filter(|&n| n <= self.ring.len())
                .collect();
            let native = self.model.native_head().is_some();
            for &n in &offsets {
                let c = &self.ring[self.ring.len() - n];
                if !native {
                    for _ in 0..p.samples {
                        self.feature_batch.extend_from_slice(&c.state);
                    }
                }
                draw(&mut rng, &c.mu, &c.log_sigma, p.samples, &mut self.z_batch);
            }
        }
        Ok(Prepared {
            rows: offsets.len() * p.samples,
            offsets,
            rng_after: rng,
            valid_px,
        })
    }

    /// Turns the best head row of the prepared frame (row, mse, its prediction) into the
    /// outcome and commits the frame's encoder output and the generator state. Cannot fail.
    #[allow(clippy::too_many_arguments)]
    fn finish(
        &mut self,
        prepared: Prepared,
        input: &[f32],
        mask: Option<&[bool]>,
        best: Option<(usize, f64, &[f32])>,
        features: Vec<f32>,
        mu: Vec<f32>,
        log_sigma: Vec<f32>,
    ) -> Prediction {
        let dims = self.model.dims();
        let t = self.frames;
        let p = self.params;
        let outcome = if (t as usize) < p.a {
            Prediction::WarmingUp {
                frames_seen: t,
                frames_needed: p.a,
            }
        } else {
            match best {
                Some((row, e_o, pred)) if prepared.valid_px > 0 && prepared.rows > 0 => {
                    Prediction::Scored(FlowScore {
                        frame: t,
                        e_o,
                        n: prepared.offsets[row / p.samples],
                        sample: row % p.samples,
                        error_map: error_map(dims, pred, input, mask),
                        valid_px: prepared.valid_px,
                    })
                }
                _ => Prediction::NoValidPixels { frame: t },
            }
        };
        let state = match self.model.native_head() {
            Some(head) => head.project(&features),
            None => features,
        };
        self.ring.push_back(Cached {
            state,
            mu,
            log_sigma,
        });
        while self.ring.len() > p.a + p.b {
            self.ring.pop_front();
        }
        self.rng = prepared.rng_after;
        self.frames += 1;
        outcome
    }
}

#[derive(Debug)]
struct Prepared {
    offsets: Vec<usize>,
    rows: usize,
    rng_after: NormalRng,
    valid_px: usize,
}
