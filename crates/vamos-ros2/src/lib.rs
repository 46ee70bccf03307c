//! vamos on a ROS 2 graph without a ROS installation: `vamos bridge` is a ROS 2 node
//! written on `ros2-client` (pure Rust, over RustDDS). It subscribes to a robot's camera
//! images (optionally with a registered depth image each), camera info and joint states,
//! streams them to a vamos server as one session, and publishes every score stamped with
//! the scored image's header, plus `diagnostic_msgs` diagnostics.
//!
//! - [`msg`]: the ROS 2 messages as serde structs in `.msg` field order, and their
//!   conversions to and from `vamos.v1`;
//! - [`names`]: topic name resolution under the node's namespace, as rcl does it;
//! - [`status`]: the session's bookkeeping and its diagnostic level;
//! - [`depth`]: each colour image paired with the depth image nearest its stamp (pure);
//! - [`bridge`]: the node itself.
//!
//! Its wire format is tested against a second DDS implementation, Eclipse Cyclone DDS
//! (`clients/ros2/dds_wire`).

pub mod bridge;
pub mod depth;
pub mod msg;
pub mod names;
pub mod status;

pub use bridge::{BridgeError, BridgeOptions, BridgeReport, run};
