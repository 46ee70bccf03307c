//! The robot model: what motion vamos should expect from the robot's joint states.
//!
//! - [`camera`]: pinhole intrinsics and the ROS optical-frame convention.
//! - [`camera_motion`]: the image motion the kinematics predict (a 2-D similarity in the
//!   registration's convention) and the camera-motion error `e_c`.
//! - [`geometry`]: triangle meshes attached to links (what the renderer draws).
//!
//! Frames: `base` is the URDF's root link; poses are written `a_from_b` (the transform
//! that maps coordinates in frame `b` to frame `a`), as nalgebra `Isometry3<f64>`.

pub mod camera;
pub mod camera_motion;
pub mod geometry;

pub use camera::{CameraConvention, Intrinsics, IntrinsicsError};
pub use geometry::{LinkMesh, TriMesh};
