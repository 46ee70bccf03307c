//! Recorded executions (episodes): reading them frame by frame in stamp order, and writing
//! score bags.
//!
//! - [`folder`]: an episode as a folder of images with optional stamps (`frames.csv`).
//! - [`joints`]: joint states at their own rate (`joints.csv`), interpolated to image stamps.
//! - [`bag`]: ROS 2 bags in MCAP ([`McapEpisode`]): topics resolved by name or schema,
//!   frames streamed chunk by chunk with joint states interpolated to each image stamp,
//!   damaged files read up to where they break. Settings: [`EpisodeConfig`] (`[episode]`).
//! - [`writer`]: [`ScoreBagWriter`], MCAP output with images and score topics.
//! - [`cdr`], [`ros`]: the CDR encoding and the ROS 2 messages vamos reads and writes.
//! - [`image`]: image decoding to gray, one encoding table, for live and recorded images.
//! - [`files`]: episode files and folders named on a command line or in a request.
//! - [`labels`]: evaluation labels (`<stem>.labels.json` or a label topic).
//! - [`synthetic`]: synthetic bags (images, joint states, URDF) for tests and benches.
//!
//! Typical use:
//! ```no_run
//! # use vamos_core::episode::{EpisodeConfig, McapEpisode};
//! # fn main() -> Result<(), vamos_core::episode::EpisodeError> {
//! let ep = McapEpisode::open("run.mcap".as_ref(), &EpisodeConfig::default())?;
//! let urdf = ep.robot_description()?;
//! for frame in ep.frames() {
//!     match frame {
//!         Ok(f) => println!("{} {} {:?}", f.index, f.stamp_ns, f.joints.map(|j| j.positions)),
//!         Err(e) => eprintln!("{e}"), // one bad frame; later frames still come
//!     }
//! }
//! # Ok(()) }
//! ```
//!
//! May import `vision` and `robot`; never async crates.

pub mod bag;
pub mod cdr;
pub mod files;
pub mod folder;
pub mod image;
pub mod joints;
pub mod labels;
pub mod ros;
pub mod synthetic;
pub mod writer;

pub use bag::{
    ChosenTopics, DecodeBudget, EpisodeConfig, EpisodeFrame, EpisodeInfo, EpisodeTopics, Frames,
    JointStateAt, McapEpisode, Reserved, SourceMessage, TopicInfo, decompress_zstd_into,
    is_zstd_file,
};
pub use folder::{EpisodeError, ImageSequence, SequenceFrame};
pub use joints::{JointSample, JointTrack, interpolate_optional, interpolate_rows};
pub use labels::Labels;
pub use ros::CameraInfoMsg;
pub use writer::{ImageData, ScoreBagWriter, ScoreTopics, heatmap_rgb};
