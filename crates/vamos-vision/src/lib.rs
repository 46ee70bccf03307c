//! The vision core: everything vamos computes from pixels alone.
//!
//! - [`image`]: gray `f32` images and planar flow fields.
//! - [`preprocess`]: gray from RGB, histogram equalisation, resizing, centre crop and the
//!   64x64 network input of a flow field.
//! - [`flow`]: TV-L1 optical flow (Zach, Pock, Bischof 2007) with OpenCV's parameters.
//! - [`flowio`]: Middlebury `.flo` files and the colour-wheel visualisation.
//! - [`registration`]: Fourier-Mellin similarity registration (Reddy & Chatterji 1996).
//! - [`synthetic`]: textured image pairs with exact ground-truth motion.
//!
//! This module is the bottom of the dependency graph: it imports no other vamos module
//! and never uses tokio, tonic, prost, axum or http.

pub mod flow;
pub mod flowio;
pub mod image;
pub mod preprocess;
pub mod registration;
pub mod synthetic;

pub use image::{DepthImage, FlowField, GrayImage, ImageError};

/// The `[vision]` section: parameters of the vision kernels.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct VisionConfig {
    /// Worker threads for the vision kernels; 0 = one per core.
    pub threads: usize,
    /// TV-L1 optical flow: the `realtime` preset ([`flow::FlowParams::realtime`]) unless
    /// set. It detects as well as OpenCV's defaults at a fraction of their cost (README,
    /// "Choosing the defaults"); a profile's `flow_preset` replaces it. A partial
    /// `[vision.flow]` section keeps the realtime preset's values for the keys it leaves
    /// out.
    pub flow: flow::FlowParams,
    /// Fourier-Mellin registration.
    pub registration: registration::RegistrationParams,
    /// Flow -> network input.
    pub network_input: preprocess::NetworkInputParams,
}

impl Default for VisionConfig {
    fn default() -> Self {
        Self {
            threads: 0,
            flow: flow::FlowParams::realtime(),
            registration: Default::default(),
            network_input: Default::default(),
        }
    }
}
