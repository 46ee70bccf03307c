//! The visual front end: one processed frame at a time.
//!
//! Per pushed image (already the processed stream: the caller applies the frame stride):
//! 1. gray image resized to the processing resolution (area filter) and histogram
//!    equalised (REFERENCE.md section 3);
//! 2. forward TV-L1 flow from the previous pushed frame (`vision::flow`, the previous
//!    frame's pyramid is reused);
//! 3. Fourier-Mellin registration of the previous frame onto this one, ignoring the robot
//!    body where a body mask is given (REFERENCE.md section 1);
//! 4. the flow variant (REFERENCE.md section 3): `registered` subtracts the image motion of
//!    the registered similarity from the flow; `masked` sets the flow to zero on the body
//!    mask of this (the target) frame; then the network input (`network_input`) and, for
//!    masked variants, which of its 64x64 pixels are valid (`network_mask`).

use serde::{Deserialize, Serialize};
use std::time::Instant;
use vamos_model::FlowVariant;
use vamos_vision::flow::{FlowError, FlowEstimator, FlowParams};
use vamos_vision::preprocess::{
    NetworkInputParams, PreprocessError, ResizeFilter, equalize_histogram, network_input,
    network_mask, resize,
};
use vamos_vision::registration::{
    Registrar, Registration, RegistrationError, RegistrationParams, Similarity,
};
use vamos_vision::synthetic::similarity_forward;
use vamos_vision::{FlowField, GrayImage};

/// Errors of the front end. Each names the failing stage; the processor's state is left as
/// it was before the failing push (a bad frame loses nothing that came before).
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    /// A parameter is out of range.
    #[error("pipeline parameter {name} is invalid: {reason}")]
    InvalidParams {
        /// Parameter name.
        name: &'static str,
        /// What is wrong.
        reason: String,
    },
    /// A masked variant got a frame without a body mask.
    #[error("flow variant {variant} needs a body mask for every frame")]
    MissingMask {
        /// The configured variant.
        variant: FlowVariant,
    },
    /// The body mask does not have the processing resolution.
    #[error("body mask has {len} pixels, expected {width}x{height}")]
    MaskSize {
        /// Pixels given.
        len: usize,
        /// Processing width.
        width: usize,
        /// Processing height.
        height: usize,
    },
    /// Resizing, equalisation or the network input failed.
    #[error("preprocessing: {0}")]
    Preprocess(#[from] PreprocessError),
    /// Optical flow failed.
    #[error("optical flow: {0}")]
    Flow(#[from] FlowError),
    /// Registration failed.
    #[error("registration: {0}")]
    Registration(#[from] RegistrationError),
}

/// Parameters of the front end.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct FrameProcessorParams {
    /// Processing width, pixels. Images of another size are resized. Default 320, chosen
    /// by measurement (`benches/README.md`, whole pipeline): with the paper-size network
    /// one core scores a 320x240 frame with the `realtime` TV-L1 preset in ~74 ms, inside
    /// a 10 Hz stream's 100 ms, while 640x480 (the paper's) takes ~109 ms with `realtime`
    /// and ~371 ms with OpenCV's default TV-L1 parameters.
    pub width: usize,
    /// Processing height, pixels (default 240; the paper: 480).
    pub height: usize,
    /// Histogram-equalise every frame before flow and registration (the paper does).
    pub equalize: bool,
    /// The flow the predictor sees.
    pub variant: FlowVariant,
}

/// Largest processing width or height, pixels (4K; the paper processes 640x480). Every
/// stage allocates images and flow fields of the processing resolution, and a stored
/// profile comes from outside: a larger one is refused rather than allocated.
pub const MAX_PROCESSING_SIDE: usize = 4096;

impl FrameProcessorParams {
    /// Refuses a processing resolution below 16x16 or above [`MAX_PROCESSING_SIDE`] a side.
    pub fn validate(&self) -> Result<(), PipelineError> {
        let (w, h) = (self.width, self.height);
        if w < 16 || h < 16 {
            return Err(PipelineError::InvalidParams {
                name: "width/height",
                reason: format!("processing resolution {w}x{h} is below 16x16"),
            });
        }
        if w > MAX_PROCESSING_SIDE || h > MAX_PROCESSING_SIDE {
            return Err(PipelineError::InvalidParams {
                name: "width/height",
                reason: format!(
                    "processing resolution {w}x{h} is above {MAX_PROCESSING_SIDE}x{MAX_PROCESSING_SIDE}"
                ),
            });
        }
        Ok(())
    }
}

impl Default for FrameProcessorParams {
    fn default() -> Self {
        Self {
            width: 320,
            height: 240,
            equalize: true,
            variant: FlowVariant::Plain,
        }
    }
}

/// What the front end computed for one frame (from the second pushed frame on).
#[derive(Debug, Clone)]
pub struct ProcessedFrame {
    /// Forward TV-L1 flow previous -> this frame at the processing resolution, before the
    /// variant is applied (what the body-motion error compares).
    pub flow: FlowField,
    /// The previous frame registered onto this one (the observed camera motion).
    pub registration: Registration,
    /// The predictor's input `[2, n, n]` in the configured variant (empty from a front
    /// end [`FrameProcessor::without_network_input`]).
    pub network_input: Vec<f32>,
    /// For masked variants: which of the `n x n` input pixels are valid (not robot body).
    pub network_valid: Option<Vec<bool>>,
    /// Wall time of each stage of this push.
    pub timings: FrontEndTimings,
    /// The previous frame as the flow saw it (processing resolution, equalised if
    /// configured): the source grid of `flow`. This frame, where `flow` ends, is
    /// [`FrameProcessor::current`].
    pub previous_image: GrayImage,
}

/// Wall time of the front end's stages for one frame, microseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct FrontEndTimings {
    /// Resize and histogram equalisation.
    pub prepare_us: u64,
    /// Fourier-Mellin registration.
    pub registration_us: u64,
    /// TV-L1 optical flow.
    pub flow_us: u64,
    /// Flow variant and the 64x64 network input (and its mask).
    pub network_input_us: u64,
}

fn micros_since(start: Instant) -> u64 {
    u64::try_from(start.elapsed().as_micros()).unwrap_or(u64::MAX)
}

/// The stateful front end of one stream (a session or an episode).
pub struct FrameProcessor {
    params: FrameProcessorParams,
    network: NetworkInputParams,
    flow: FlowEstimator,
    registrar: Registrar,
    /// Whether pushes compute the predictor's input (see [`Self::without_network_input`]).
    network_input: bool,
    /// The last pushed frame, prepared.
    last: Option<GrayImage>,
}

impl FrameProcessor {
    /// A front end with the given flow, registration and network-input parameters.
    pub fn new(
        params: FrameProcessorParams,
        flow: FlowParams,
        registration: RegistrationParams,
        network: NetworkInputParams,
    ) -> Result<Self, PipelineError> {
        params.validate()?;
        Ok(Self {
            params,
            network,
            flow: FlowEstimator::new(flow)?,
            registrar: Registrar::new(registration)?,
            network_input: true,
            last: None,
        })
    }

    /// A front end for a stream no flow predictor reads: pushes leave
    /// [`ProcessedFrame::network_input`] empty and `network_valid` `None` (about 1.3 ms
    /// of a 320x240 frame saved).
    pub fn without_network_input(mut self) -> Self {
        self.network_input = false;
        self
    }

    /// The parameters.
    pub fn params(&self) -> &FrameProcessorParams {
        &self.params
    }

    /// Forgets the previous frame (the next push starts a new stream).
    pub fn reset(&mut self) {
        self.flow.reset();
        self.registrar.reset();
        self.last = None;
    }

    /// The gray image at the processing resolution, equalised if configured.
    pub fn prepare(&self, image: &GrayImage) -> Result<GrayImage, PipelineError> {
        let (w, h) = (self.params.width, self.params.height);
        let resized = if image.size() == (w, h) {
            image.clone()
        } else {
            resize(image, w, h, ResizeFilter::Area)?
        };
        Ok(if self.params.equalize {
            equalize_histogram(&resized)?
        } else {
            resized
        })
    }

    /// Adds the next processed frame. `body_mask` (true = robot body, processing
    /// resolution) is this frame's mask: registration ignores those pixels, and masked
    /// variants need it. Returns `None` for the first frame of a stream.
    pub fn push(
        &mut self,
        image: &GrayImage,
        body_mask: Option<&[bool]>,
    ) -> Result<Option<ProcessedFrame>, PipelineError> {
        let (w, h) = (self.params.width, self.params.height);
        if let Some(m) = body_mask
            && m.len() != w * h
        {
            return Err(PipelineError::MaskSize {
                len: m.len(),
                width: w,
                height: h,
            });
        }
        if self.params.variant.is_masked() && body_mask.is_none() {
            return Err(PipelineError::MissingMask {
                variant: self.params.variant,
            });
        }
        let mut timings = FrontEndTimings::default();
        let start = Instant::now();
        let frame = self.prepare(image)?;
        timings.prepare_us = micros_since(start);
        // Registration first: if it fails the flow estimator has not advanced either.
        let start = Instant::now();
        let registration = self.registrar.push(&frame, body_mask)?;
        timings.registration_us = micros_since(start);
        let start = Instant::now();
        let flow = match self.flow.push(&frame) {
            Ok(f) => f,
            Err(e) => {
                // Keep both streams in step: the registrar saw this frame, the flow did
                // not, so start both afresh from this frame's successor.
                self.registrar.reset();
                self.last = None;
                return Err(e.into());
            }
        };
        timings.flow_us = micros_since(start);
        let previous_image = self.last.replace(frame);
        let (Some(flow), Some(registration), Some(previous_image)) =
            (flow, registration, previous_image)
        else {
            return Ok(None);
        };
        let start = Instant::now();
        let (network_input, network_valid) = if self.network_input {
            let variant_flow = apply_variant(
                &flow,
                self.params.variant,
                &registration.transform,
                body_mask,
            );
            let valid = match (self.params.variant.is_masked(), body_mask) {
                (true, Some(m)) => Some(network_mask(m, w, h, &self.network)?),
                _ => None,
            };
            (network_input(&variant_flow, &self.network)?, valid)
        } else {
            (Vec::new(), None)
        };
        timings.network_input_us = micros_since(start);
        Ok(Some(ProcessedFrame {
            flow,
            registration,
            network_input,
            network_valid,
            timings,
            previous_image,
        }))
    }

    /// The latest frame pushed, as the flow saw it (after a [`Self::push`] that returned a
    /// frame: where its flow ends); `None` before the first and after a failed push.
    pub fn current(&self) -> Option<&GrayImage> {
        self.last.as_ref()
    }
}

/// The flow the predictor sees: `registered` subtracts the displacement of `camera`
/// (previous -> current similarity about the image centre) at every pixel; `masked` zeroes
/// the flow where `body_mask` is true.
pub fn apply_variant(
    flow: &FlowField,
    variant: FlowVariant,
    camera: &Similarity,
    body_mask: Option<&[bool]>,
) -> FlowField {
    let (w, h) = flow.size();
    let mut out = flow.clone();
    if variant.is_registered() {
        let centre = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let t = (
            camera.tx_px,
            camera.ty_px,
            camera.scale,
            camera.rotation_deg,
        );
        for y in 0..h {
            for x in 0..w {
                let (qx, qy) = similarity_forward((x as f64, y as f64), centre, t);
                let i = y * w + x;
                out.u[i] -= (qx - x as f64) as f32;
                out.v[i] -= (qy - y as f64) as f32;
            }
        }
    }
    if variant.is_masked()
        && let Some(mask) = body_mask
    {
        for (i, &m) in mask.iter().enumerate() {
            if m {
                out.u[i] = 0.0;
                out.v[i] = 0.0;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use vamos_vision::flow::FlowParams;
    use vamos_vision::synthetic::{self, Motion};

    fn processor(variant: FlowVariant) -> FrameProcessor {
        FrameProcessor::new(
            FrameProcessorParams {
                width: 160,
                height: 120,
                equalize: true,
                variant,
            },
            FlowParams::realtime(),
            RegistrationParams::default(),
            NetworkInputParams::default(),
        )
        .unwrap()
    }

    #[test]
    fn processing_resolution_is_bounded() {
        let params = |width, height| FrameProcessorParams {
            width,
            height,
            ..FrameProcessorParams::default()
        };
        assert!(params(160, 120).validate().is_ok());
        assert!(params(MAX_PROCESSING_SIDE, 16).validate().is_ok());
        for (w, h) in [
            (15, 120),
            (160, 0),
            (MAX_PROCESSING_SIDE + 1, 120),
            (160, 100_000),
        ] {
            assert!(
                matches!(
                    params(w, h).validate(),
                    Err(PipelineError::InvalidParams {
                        name: "width/height",
                        ..
                    })
                ),
                "{w}x{h}"
            );
        }
    }

    #[test]
    fn registered_variant_removes_camera_translation() {
        // A pure translation of the whole image: the registered flow is about zero, the
        // plain one is the translation.
        let motion = Motion::Translation { dx: 2.0, dy: -1.0 };
        let (a, b, _) = synthetic::pair(160, 120, &motion, 3);
        let mut plain = processor(FlowVariant::Plain);
        let mut registered = processor(FlowVariant::Registered);
        for p in [&mut plain, &mut registered] {
            assert!(p.push(&a, None).unwrap().is_none());
        }
        let fp = plain.push(&b, None).unwrap().unwrap();
        let fr = registered.push(&b, None).unwrap().unwrap();
        let t = fp.registration.transform;
        assert!(
            (t.tx_px - 2.0).abs() < 0.1 && (t.ty_px + 1.0).abs() < 0.1,
            "{t:?}"
        );
        // Network inputs: 2 px at 160 px wide = 8 px at 640 -> 8 / 15 * 0.5 = 0.267.
        let mean = |v: &[f32]| v.iter().map(|&x| f64::from(x)).sum::<f64>() / v.len() as f64;
        let n = 64 * 64;
        assert!((mean(&fp.network_input[..n]) - 0.2667).abs() < 0.02);
        assert!((mean(&fp.network_input[n..]) + 0.1333).abs() < 0.02);
        assert!(mean(&fr.network_input[..n]).abs() < 0.01);
        assert!(mean(&fr.network_input[n..]).abs() < 0.01);
        assert!(fp.network_valid.is_none());
    }

    #[test]
    fn masked_variant_zeroes_the_body_and_reports_valid_pixels() {
        let motion = Motion::Translation { dx: 1.5, dy: 0.0 };
        let (a, b, _) = synthetic::pair(160, 120, &motion, 4);
        let mask: Vec<bool> = (0..160 * 120).map(|i| i % 160 >= 120).collect();
        let mut p = processor(FlowVariant::Masked);
        assert!(matches!(
            p.push(&a, None),
            Err(PipelineError::MissingMask { .. })
        ));
        assert!(matches!(
            p.push(&a, Some(&mask[1..])),
            Err(PipelineError::MaskSize { .. })
        ));
        assert!(p.push(&a, Some(&mask)).unwrap().is_none());
        let f = p.push(&b, Some(&mask)).unwrap().unwrap();
        let valid = f.network_valid.unwrap();
        // The right quarter of the image is the body: masked input is zero there.
        for (i, &ok) in valid.iter().enumerate() {
            if !ok {
                assert_eq!(f.network_input[i], 0.0);
            }
        }
        let invalid = valid.iter().filter(|&&v| !v).count();
        // 40 of 160 columns -> of the 85-wide resized image ~21 columns, minus the 10
        // cropped on the right: ~11 columns of 64.
        assert!((10 * 64..=12 * 64).contains(&invalid), "{invalid}");
    }

    #[test]
    fn a_bad_frame_is_an_error_and_the_stream_goes_on() {
        let motion = Motion::Translation { dx: 1.0, dy: 1.0 };
        let (a, b, _) = synthetic::pair(160, 120, &motion, 5);
        let mut p = processor(FlowVariant::Plain);
        assert!(p.push(&a, None).unwrap().is_none());
        let mut bad = b.clone();
        bad.data_mut()[10] = f32::NAN;
        assert!(p.push(&bad, None).is_err());
        // The bad frame was refused before any stage advanced: the next good frame pairs
        // with `a`.
        let f = p.push(&b, None).unwrap().unwrap();
        let mean_u = f.flow.u.iter().map(|&x| f64::from(x)).sum::<f64>() / f.flow.u.len() as f64;
        assert!((mean_u - 1.0).abs() < 0.1, "{mean_u}");
        assert!(p.push(&a, None).unwrap().is_some());
    }
}
