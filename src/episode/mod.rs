//! Recorded executions (episodes): reading them frame by frame in stamp order.
//!
//! - [`folder`]: an episode as a folder of images with optional stamps (`frames.csv`).
//!   ROS 2 bags in MCAP come with the episode issue.

pub mod folder;

pub use folder::{EpisodeError, ImageSequence, SequenceFrame};
