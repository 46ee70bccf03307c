//! Recorded executions (episodes): reading them frame by frame in stamp order.
//!
//! - [`folder`]: an episode as a folder of images with optional stamps (`frames.csv`).
//!   ROS 2 bags in MCAP come with the episode issue.
//! - [`joints`]: joint states at their own rate (`joints.csv`), interpolated to image stamps.

pub mod folder;
pub mod joints;

pub use folder::{EpisodeError, ImageSequence, SequenceFrame};
pub use joints::{JointSample, JointTrack};
