//! The robot model: what motion vamos should expect from the robot's joint states.
//!
//! - [`description`]: [`Robot`], loaded from a URDF file, string, package folder or
//!   archive; mesh path resolution; visual meshes per link.
//! - [`kinematics`]: the joint tree, forward kinematics (`base_from_link`), camera poses.
//! - [`joints`]: joint states by name -> joint vector ([`JointMapper`]).
//! - [`mesh`]: mesh files (STL, OBJ, COLLADA) and URDF primitives as [`TriMesh`]es.
//! - [`camera`]: pinhole intrinsics and the ROS optical-frame convention.
//! - [`camera_motion`]: the image motion the kinematics predict (a 2-D similarity in the
//!   registration's convention) and the camera-motion error `e_c`.
//! - [`geometry`]: triangle meshes attached to links (what the renderer draws).
//! - [`config`]: [`RobotConfig`], the `[robot]` settings (caps, tessellation).
//! - [`render`]: body mask, depth and exact expected body flow (CPU rasteriser).
//! - [`body_motion`]: the body-motion error `e_b`.
//!
//! Frames: `base` is the URDF's root link; poses are written `a_from_b` (the transform
//! that maps coordinates in frame `b` to frame `a`), as nalgebra `Isometry3<f64>`.
//!
//! ```no_run
//! use vamos_robot::{CameraConvention, Robot, RobotConfig};
//! # fn main() -> Result<(), vamos_robot::RobotError> {
//! let robot = Robot::load("panda/".as_ref(), &RobotConfig::default())?;
//! let mut mapper = robot.joint_mapper(); // once per session
//! let q = mapper.map(&["panda_joint1"], &[0.3])?.positions;
//! let base_from_link = robot.forward(&q)?; // index = link index = LinkMesh::link
//! let camera = robot.camera("panda_hand", CameraConvention::Body)?; // once
//! let camera_from_base = camera.camera_from_base(&base_from_link);
//! # Ok(()) }
//! ```

pub mod body_motion;
pub mod camera;
pub mod camera_motion;
pub mod config;
pub mod description;
pub mod error;
pub mod geometry;
pub mod joints;
pub mod kinematics;
pub mod mesh;
mod prepass;
pub mod render;

pub use body_motion::{BodyMotion, BodyMotionError, body_motion_error};
pub use camera::{CameraConvention, CameraSpec, CameraSpecError, Intrinsics, IntrinsicsError};
pub use config::RobotConfig;
pub use description::{MissingMesh, Robot, VisualGeometry, VisualInfo};
pub use error::RobotError;
pub use geometry::{LinkMesh, TriMesh};
pub use joints::{JointMapper, MappedJoints};
pub use kinematics::{
    CameraMount, Joint, JointKind, JointLimits, JointPositions, Kinematics, LimitViolation, Mimic,
};
