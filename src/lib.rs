//! vamos: Visual Anomaly MOnitoring Service.
//!
//! vamos compares the motion a robot's head camera observes with the motion it expects
//! and scores every frame for anomalies (Thoduka, Gall and Plöger, IROS 2021). This crate
//! is the `vamos` binary and a library that gathers the workspace's crates under one name,
//! each as the module it was before the crates were split (ARCHITECTURE.md draws the
//! layers):
//! - [`vision`] (`vamos_vision`): images, TV-L1 optical flow, Fourier-Mellin registration,
//!   resizing and the network-input preprocessing.
//! - [`robot`] (`vamos_robot`): URDF robots, kinematics, expected camera motion, rendering
//!   and the body-motion error.
//! - [`model`] (`vamos_model`): the ONNX flow predictor: model bundles, ONNX Runtime
//!   sessions, the native head and the prediction error `e_o`.
//! - [`eval`], [`episode`], [`pipeline`], [`setup`] (`vamos_core`): evaluation and
//!   calibration maths; recorded episodes (ROS 2 bags, image folders); the per-frame
//!   [`Scorer`], profiles and calibrations; a profile loaded with its robot and model.
//! - [`proto`] (`vamos_proto`): the generated `vamos.v1` gRPC code.
//! - [`config`], [`telemetry`], [`store`], [`session`], [`api`], [`service`]
//!   (`vamos_server`): settings, logging, the data directory, the session layer, the gRPC
//!   and REST transports, the server.
//! - [`client`] (`vamos_client`): a typed gRPC client and recorded episodes replayed as
//!   live robots.
//! - [`ros2`] (`vamos_ros2`): `vamos bridge`, a ROS 2 node over RustDDS that streams a
//!   robot's topics to a server and publishes the scores, with no ROS installation.
//! - `fuzz` (hidden): one entry point per parser of outside bytes, for the `cargo fuzz`
//!   targets in `fuzz/` and the corpus regression test.
//!
//! [`Scorer`]: pipeline::Scorer

pub use vamos_client as client;
pub use vamos_core::{episode, eval, pipeline, setup};
pub use vamos_model as model;
pub use vamos_proto as proto;
pub use vamos_robot as robot;
pub use vamos_ros2 as ros2;
pub use vamos_server::{api, config, service, session, store, telemetry};
pub use vamos_vision as vision;

#[doc(hidden)]
pub mod fuzz;
