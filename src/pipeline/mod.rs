//! Frame in, scores out. Synchronous and deterministic; the service and the offline tools
//! (`vamos export-dataset`, later `vamos score`) run exactly this code.
//!
//! - [`frames`]: the visual front end of every processed frame: resize to the processing
//!   resolution, histogram equalisation, TV-L1 flow from the previous processed frame,
//!   Fourier-Mellin registration, and the flow predictor's 64x64 input in the configured
//!   [`FlowVariant`].

pub mod frames;

pub use frames::{
    FlowVariant, FrameProcessor, FrameProcessorParams, PipelineError, ProcessedFrame,
};
