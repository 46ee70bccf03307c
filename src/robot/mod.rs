//! The robot model: what motion vamos should expect from the robot's joint states.
//!
//! - [`camera`]: pinhole intrinsics and the ROS optical-frame convention.
//! - [`geometry`]: triangle meshes attached to links (what the renderer draws).
//! - [`render`]: body mask, depth and exact expected body flow (CPU rasteriser).
//! - [`body_motion`]: the body-motion error `e_b`.
//!
//! Frames: `base` is the URDF's root link; poses are written `a_from_b` (the transform
//! that maps coordinates in frame `b` to frame `a`), as nalgebra `Isometry3<f64>`.

pub mod body_motion;
pub mod camera;
pub mod geometry;
pub mod render;

pub use body_motion::{BodyMotion, BodyMotionError, body_motion_error};
pub use camera::{CameraConvention, Intrinsics, IntrinsicsError};
pub use geometry::{LinkMesh, TriMesh};
