//! ROS 2 bags in MCAP: topic resolution, streamed frames with joint states interpolated
//! to each image stamp, the robot description and labels.
//!
//! [`McapEpisode::open`] reads only the summary section (schemas, channels, statistics,
//! chunk indexes) and resolves the topics. [`McapEpisode::frames`] then streams the image,
//! camera-info and joint-state messages in **log-time order** through the mcap crate's
//! sans-io [`IndexedReader`] ([`ReadOrder::LogTime`]) over a plain [`std::fs::File`]: the
//! reader loads chunks in the order of their first log time and merges the messages of
//! chunks whose time ranges overlap (a recorder that wrote messages out of order, several
//! writers interleaved), so memory holds the decompressed chunks that overlap the current
//! log time (one, for the usual file whose chunks follow each other) plus a short queue of
//! images waiting for the joint sample after their stamp (at most [`MAX_PENDING_IMAGES`]).
//!
//! A file without a complete summary (missing, without channel records or chunk
//! indexes, or a truncated/corrupt file whose footer is gone) is read by a linear scan
//! instead: messages are put in log-time order within a window of [`REORDER_MESSAGES`]
//! messages and [`REORDER_BYTES`] bytes (out-of-order writes inside a chunk come out as
//! the indexed reader gives them), every valid message is used, and the scan's break is
//! reported as [`EpisodeError::Truncated`] (in [`EpisodeInfo::damage`] and as the last item
//! of [`McapEpisode::frames`]).
//!
//! What rosbag2 writes is read as it is: per-message zstd compression (each payload a
//! zstd frame, decompressed up to `max_image_bytes`), file compression (`.mcap.zstd`,
//! decompressed into a temporary file up to `max_decompressed_bytes`), and bag folders
//! (`metadata.yaml` beside split files `<name>_<n>.mcap`, read one after another as one
//! episode).
//!
//! Bad input never panics: a message that cannot be decoded, an unknown encoding, NaN
//! joint positions or an image whose size differs from the first image become `Err`
//! items naming topic and message index, and the stream goes on. Images whose header
//! stamps do not increase in log-time order (the stamp really goes backwards) are skipped,
//! with a warning on the next frame and a count in [`EpisodeInfo::skipped_backwards`] —
//! never reordered.

mod assemble;
mod files;
mod prescan;
mod source;
mod topics;

pub use files::{decompress_zstd_into, is_zstd_file};

use super::EpisodeError;
use super::image::{CheckedSize, EncodedImage};
use super::joints::{interpolate_optional, interpolate_rows};
use super::labels::Labels;
use super::ros::{
    CameraInfoMsg, CompressedImageMsg, ImageMsg, JointStateMsg, MessageError, decode_string, schema,
};
use mcap::Summary;
use mcap::records::op;
use mcap::sans_io::indexed_reader::{
    IndexedReadEvent, IndexedReader, IndexedReaderOptions, ReadOrder,
};
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};
use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader};
use serde::{Deserialize, Serialize};
use std::cell::Cell;
use std::collections::{BTreeMap, HashMap, VecDeque};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vamos_vision::{DepthImage, GrayImage};

use assemble::*;
use files::*;
use prescan::{Prescan, prescan};
use source::*;
use topics::*;

/// Memory an episode's reader reserves before it decodes an image (a server's memory
/// budget, [`McapEpisode::with_decode_budget`]): the decoding's peak is reserved first,
/// then the reservation is shrunk to the decoded image and held by its frame (and the
/// frame's clones) until they drop, so no decoded byte is outside the budget.
pub trait DecodeBudget: Send + Sync + std::fmt::Debug {
    /// Reserves `bytes`, waiting for room if the budget does; `Err` says why not.
    fn reserve(&self, bytes: u64) -> Result<Arc<dyn Reserved>, String>;
}

/// A reservation of [`DecodeBudget`], given back when the last holder drops it.
pub trait Reserved: Send + Sync + std::fmt::Debug {
    /// Makes the reservation `bytes` (what a decoded image keeps).
    fn resize(&self, bytes: u64);
}

/// Images held while waiting for a joint sample past their stamp; beyond this the oldest
/// is released with the joint samples read so far (nearest sample, gap reported).
pub const MAX_PENDING_IMAGES: usize = 16;

/// Default topic names, tried before auto-detection by schema.
pub mod default_topic {
    /// Images.
    pub const IMAGE: &str = "/camera/image_raw";
    /// Camera info.
    pub const CAMERA_INFO: &str = "/camera/camera_info";
    /// Joint states.
    pub const JOINT_STATES: &str = "/joint_states";
    /// The URDF text.
    pub const ROBOT_DESCRIPTION: &str = "/robot_description";
    /// Labels (a `std_msgs/msg/String` carrying label JSON).
    pub const LABELS: &str = "/vamos/labels";
}

/// Topic names of an episode; `None` = the default name if present, else the only topic
/// of the matching schema.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EpisodeTopics {
    /// `sensor_msgs/msg/Image` or `sensor_msgs/msg/CompressedImage`; several candidates:
    /// the one whose name does not contain `depth`, else an error listing them.
    pub image: Option<String>,
    /// `sensor_msgs/msg/CameraInfo`.
    pub camera_info: Option<String>,
    /// `sensor_msgs/msg/JointState`.
    pub joint_states: Option<String>,
    /// `std_msgs/msg/String` with the URDF (auto: a String topic named `*robot_description`).
    pub robot_description: Option<String>,
    /// `std_msgs/msg/String` with label JSON (auto: only `/vamos/labels`).
    pub labels: Option<String>,
    /// `sensor_msgs/msg/Image` with a depth image registered to the image topic (the same
    /// field of view; `16UC1` millimetres or `32FC1` metres), e.g. a depth camera's
    /// `aligned_depth_to_color` topic. Never chosen automatically: a depth topic that is
    /// not registered to the image would place the scene wrongly.
    pub depth: Option<String>,
}

/// The `[episode]` settings section: reading recorded episodes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct EpisodeConfig {
    /// Topic names (empty = defaults and auto-detection).
    pub topics: EpisodeTopics,
    /// A frame whose nearest joint sample is further than this (milliseconds) gets a
    /// warning. Default 100.
    pub max_joint_gap_ms: f64,
    /// Largest accepted image message and MCAP record (bytes); also caps decoded pixels.
    /// Default 64 MiB.
    pub max_image_bytes: usize,
    /// Largest decompressed size of a zstd-compressed bag file (rosbag2's `.mcap.zstd`),
    /// bytes; it is decompressed into a temporary file. Default 16 GiB.
    pub max_decompressed_bytes: u64,
    /// A frame takes the depth image nearest its stamp if it is at most this far
    /// (milliseconds); else it has none (with a warning) and the assumed depth is used.
    /// Default 20.
    pub max_depth_gap_ms: f64,
}

impl Default for EpisodeConfig {
    fn default() -> Self {
        Self {
            topics: EpisodeTopics::default(),
            max_joint_gap_ms: 100.0,
            max_image_bytes: 64 << 20,
            max_decompressed_bytes: 16 << 30,
            max_depth_gap_ms: 20.0,
        }
    }
}

/// One topic of the file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct TopicInfo {
    /// Topic name.
    pub name: String,
    /// Schema name (empty when the channel has none).
    pub schema: String,
    /// Message encoding (`cdr` for ROS 2).
    pub message_encoding: String,
    /// Messages on the topic.
    pub message_count: u64,
}

/// The topics vamos reads.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct ChosenTopics {
    /// Images.
    pub image: String,
    /// Schema of the image topic (Image or CompressedImage).
    pub image_schema: String,
    /// Camera info, if any.
    pub camera_info: Option<String>,
    /// Joint states, if any.
    pub joint_states: Option<String>,
    /// Robot description, if any.
    pub robot_description: Option<String>,
    /// Label topic, if any.
    pub labels: Option<String>,
    /// Depth images registered to the images, if configured.
    pub depth: Option<String>,
}

/// What an episode holds.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EpisodeInfo {
    /// The episode's name (file stem).
    pub name: String,
    /// The file.
    pub path: PathBuf,
    /// True when read through the summary and chunk indexes, false for a linear scan.
    pub indexed: bool,
    /// Every topic of the file, by name.
    pub topics: Vec<TopicInfo>,
    /// The topics used.
    pub chosen: ChosenTopics,
    /// First message log time, ns (0 when empty).
    pub start_ns: u64,
    /// Last message log time, ns.
    pub end_ns: u64,
    /// `end - start`, seconds.
    pub duration_s: f64,
    /// Messages on the image topic.
    pub image_messages: u64,
    /// Messages on the camera-info topic.
    pub camera_info_messages: u64,
    /// Messages on the joint-state topic (0: frames come without joints).
    pub joint_messages: u64,
    /// Messages on the depth topic.
    pub depth_messages: u64,
    /// Images skipped so far by [`McapEpisode::frames`] because their stamp did not
    /// increase (updated as frames are read).
    pub skipped_backwards: usize,
    /// Notes on topic resolution (ambiguous optional topics left out).
    pub warnings: Vec<String>,
    /// Where a damaged file breaks, found by the linear scan.
    pub damage: Option<String>,
}

/// Joint states interpolated to an image stamp.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct JointStateAt {
    /// Joint names (of the first joint-state message).
    pub names: Vec<String>,
    /// Positions (rad or m), in `names` order.
    pub positions: Vec<f64>,
    /// Velocities, in `names` order; empty unless both samples used carry them.
    pub velocities: Vec<f64>,
    /// Efforts (N m or N), in `names` order; empty unless both samples used carry one
    /// finite effort per name.
    pub efforts: Vec<f64>,
    /// Distance to the nearest joint sample, ns.
    pub gap_ns: i64,
    /// Whether the stamp lies outside the joint samples (nearest taken).
    pub extrapolated: bool,
    /// Whether `gap_ns` exceeds `[episode] max_joint_gap_ms` (the frame also carries a
    /// warning): the joints were interpolated over a gap in the joint states.
    pub beyond_max_gap: bool,
}

/// The original image message, for copying it to an output bag unchanged.
#[derive(Clone, Debug, PartialEq)]
pub struct SourceMessage {
    /// Topic.
    pub topic: String,
    /// Schema name.
    pub schema: String,
    /// Log time, ns.
    pub log_time_ns: u64,
    /// The CDR payload.
    pub cdr: Vec<u8>,
}

impl SourceMessage {
    /// The image as packed 8-bit RGB (see [`EncodedImage::to_rgb8`]): width, height,
    /// pixels.
    pub fn to_rgb8(&self, max_pixels: usize) -> Result<(usize, usize, Vec<u8>), MessageError> {
        if self.schema == schema::COMPRESSED_IMAGE {
            CompressedImageMsg::decode(&self.cdr)?
                .encoded()
                .to_rgb8(max_pixels)
        } else {
            ImageMsg::decode(&self.cdr)?.encoded().to_rgb8(max_pixels)
        }
    }
}

/// One image with what was known at its stamp.
#[derive(Clone, Debug)]
pub struct EpisodeFrame {
    /// Ordinal of the image message on its topic (skipped and failed images keep their
    /// numbers, so indices may jump).
    pub index: usize,
    /// `header.stamp` (the log time when the header stamp is zero), ns.
    pub stamp_ns: i64,
    /// Gray, 0..=255 (see [`super::ros`]).
    pub image: GrayImage,
    /// The latest camera info read before this image.
    pub camera_info: Option<CameraInfoMsg>,
    /// Joint states at `stamp_ns`; `None` without joint states.
    pub joints: Option<JointStateAt>,
    /// The depth image nearest `stamp_ns` (within `[episode] max_depth_gap_ms`), when the
    /// episode has a depth topic.
    pub depth: Option<DepthImage>,
    /// Notes: skipped images before this one, large joint gaps.
    pub warnings: Vec<String>,
    /// The image message as read.
    pub source: SourceMessage,
    /// The memory the decoded image (and depth image) hold in the episode's
    /// [`DecodeBudget`]; empty without one.
    pub reserved: Vec<Arc<dyn Reserved>>,
}

/// A ROS 2 bag in MCAP, opened for reading.
#[derive(Debug)]
pub struct McapEpisode {
    path: PathBuf,
    cfg: EpisodeConfig,
    /// The MCAP files, in recording order (one, or the split files of a bag folder).
    parts: Vec<Part>,
    info: EpisodeInfo,
    skipped_backwards: Cell<usize>,
    budget: Option<Arc<dyn DecodeBudget>>,
}

impl McapEpisode {
    /// Opens a bag: reads its summary (or scans it when the summary is missing) and
    /// resolves the topics of `cfg.topics`.
    pub fn open(path: &Path, cfg: &EpisodeConfig) -> Result<Self, EpisodeError> {
        let name = episode_name(path);
        let files = if path.is_dir() {
            bag_folder_files(path)?
        } else {
            vec![path.to_path_buf()]
        };
        let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
        let (mut start_ns, mut end_ns) = (u64::MAX, 0u64);
        let mut parts = Vec::with_capacity(files.len());
        for file in &files {
            let (part, part_topics, (lo, hi)) = Part::open(file, cfg)?;
            for t in part_topics.into_values() {
                match topics.get_mut(&t.name) {
                    Some(known) => known.message_count += t.message_count,
                    None => {
                        topics.insert(t.name.clone(), t);
                    }
                }
            }
            if !part.indexed() || lo != 0 || hi != 0 {
                (start_ns, end_ns) = (start_ns.min(lo), end_ns.max(hi));
            }
            parts.push(part);
        }
        if start_ns == u64::MAX {
            start_ns = 0;
        }
        let damage = parts.iter().find_map(|p| {
            p.damage
                .as_ref()
                .map(|(offset, reason)| (p.path.clone(), *offset, reason.clone()))
        });
        let topics: Vec<TopicInfo> = topics.into_values().collect();
        let mut warnings = Vec::new();
        let chosen = resolve_topics(&topics, &cfg.topics, path, &mut warnings)?;
        let count = |t: &Option<String>| {
            t.as_ref()
                .and_then(|t| topics.iter().find(|x| &x.name == t))
                .map_or(0, |x| x.message_count)
        };
        let info = EpisodeInfo {
            name,
            path: path.to_path_buf(),
            indexed: parts.iter().all(Part::indexed),
            image_messages: count(&Some(chosen.image.clone())),
            camera_info_messages: count(&chosen.camera_info),
            joint_messages: count(&chosen.joint_states),
            depth_messages: count(&chosen.depth),
            topics,
            chosen,
            start_ns,
            end_ns,
            duration_s: end_ns.saturating_sub(start_ns) as f64 * 1e-9,
            skipped_backwards: 0,
            warnings,
            damage: damage.as_ref().map(|(file, offset, reason)| {
                if files.len() > 1 {
                    format!("{} breaks near byte {offset}: {reason}", file.display())
                } else {
                    format!("breaks near byte {offset}: {reason}")
                }
            }),
        };
        Ok(Self {
            path: path.to_path_buf(),
            cfg: cfg.clone(),
            parts,
            info,
            skipped_backwards: Cell::new(0),
            budget: None,
        })
    }

    /// Images are decoded within `budget` ([`DecodeBudget`]).
    pub fn with_decode_budget(mut self, budget: Arc<dyn DecodeBudget>) -> Self {
        self.budget = Some(budget);
        self
    }

    /// The episode's name (file stem).
    pub fn name(&self) -> &str {
        &self.info.name
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What the episode holds (with the count of skipped out-of-order images so far).
    pub fn info(&self) -> EpisodeInfo {
        let mut info = self.info.clone();
        info.skipped_backwards = self.skipped_backwards.get();
        info
    }

    fn source(&self, topics: &[String]) -> Result<MessageSource, EpisodeError> {
        let mut sources = self
            .parts
            .iter()
            .map(|p| p.source(topics, &self.cfg))
            .collect::<Result<VecDeque<_>, _>>()?;
        Ok(match sources.len() {
            1 => sources
                .pop_front()
                .unwrap_or(MessageSource::Chain(VecDeque::new())),
            _ => MessageSource::Chain(sources),
        })
    }

    /// The first message of `topic`, decoded by `f`; `Ok(None)` when it has none.
    fn first_message<T>(
        &self,
        topic: &str,
        f: impl Fn(&[u8]) -> Result<T, MessageError>,
    ) -> Result<Option<T>, EpisodeError> {
        let mut src = self.source(&[topic.to_string()])?;
        let limit = self.cfg.max_image_bytes;
        let decode = |m: RawMsg<'_>| {
            if is_zstd(m.data) {
                let data = decompress_payload(m.data, limit)
                    .map_err(|reason| MessageError::BadSize { reason })?;
                f(&data)
            } else {
                f(m.data)
            }
        };
        match src.next_with(decode) {
            // A damaged file that breaks before the topic's first message has none.
            None | Some(Err(EpisodeError::Truncated { .. })) => Ok(None),
            Some(Err(e)) => Err(e),
            Some(Ok(r)) => r.map(Some).map_err(|e| EpisodeError::BadMessage {
                topic: topic.into(),
                index: 0,
                reason: e.to_string(),
            }),
        }
    }

    /// Every message of `topics` in log-time order, handed to `f(topic, schema,
    /// log_time_ns, cdr)` (zstd-compressed payloads decompressed); for reading score
    /// topics or copying other topics. A damaged file yields its valid messages, then
    /// [`EpisodeError::Truncated`].
    pub fn for_each_message(
        &self,
        topics: &[String],
        mut f: impl FnMut(&str, &str, u64, &[u8]),
    ) -> Result<(), EpisodeError> {
        let mut src = self.source(topics)?;
        let limit = record_limit(&self.cfg);
        while let Some(r) = src.next_with(|m| {
            let data = if is_zstd(m.data) {
                decompress_payload(m.data, limit).ok()
            } else {
                None
            };
            f(
                m.topic,
                m.schema,
                m.log_time,
                data.as_deref().unwrap_or(m.data),
            )
        }) {
            r?;
        }
        match self.damage() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }

    /// The damage a linear scan found at open (the first damaged file's), as an error.
    fn damage(&self) -> Option<EpisodeError> {
        self.parts.iter().find_map(|p| {
            p.damage
                .as_ref()
                .map(|(offset, reason)| EpisodeError::Truncated {
                    path: p.path.display().to_string(),
                    offset: *offset,
                    reason: reason.clone(),
                })
        })
    }

    /// The schema (name, encoding, definition bytes) of `topic`'s channel, read from the
    /// summary (or found by a scan); `None` when the topic is not in the file.
    pub fn schema_of(
        &self,
        topic: &str,
    ) -> Result<Option<(String, String, Vec<u8>)>, EpisodeError> {
        for part in &self.parts {
            if let Some(found) = part.schema_of(topic, &self.cfg)? {
                return Ok(Some(found));
            }
        }
        Ok(None)
    }

    /// The URDF text: the first message of the robot-description topic, if there is one.
    pub fn robot_description(&self) -> Result<Option<String>, EpisodeError> {
        match &self.info.chosen.robot_description {
            Some(t) => self.first_message(t, decode_string),
            None => Ok(None),
        }
    }
}

impl McapEpisode {
    /// The first camera info, if there is one.
    pub fn camera_info(&self) -> Result<Option<CameraInfoMsg>, EpisodeError> {
        match &self.info.chosen.camera_info {
            Some(t) => self.first_message(t, CameraInfoMsg::decode),
            None => Ok(None),
        }
    }

    /// Labels: the sidecar `<stem>.labels.json` if present, else the first message of the
    /// label topic, else `None`.
    pub fn labels(&self) -> Result<Option<Labels>, EpisodeError> {
        if let Some(l) = Labels::load_for(&self.path)? {
            return Ok(Some(l));
        }
        match &self.info.chosen.labels {
            Some(t) => match self.first_message(t, decode_string)? {
                Some(json) => Labels::parse(&json, t).map(Some),
                None => Ok(None),
            },
            None => Ok(None),
        }
    }

    /// Streams the frames (see the module docs). Items are `Err` for images or joint
    /// messages that fail, and a final [`EpisodeError::Truncated`] for a damaged file.
    pub fn frames(&self) -> Frames<'_> {
        let c = &self.info.chosen;
        let mut topics = vec![c.image.clone()];
        topics.extend(c.camera_info.iter().cloned());
        let joints_topic = c
            .joint_states
            .clone()
            .filter(|_| self.info.joint_messages > 0);
        topics.extend(joints_topic.iter().cloned());
        let depth_topic = c.depth.clone().filter(|_| self.info.depth_messages > 0);
        topics.extend(depth_topic.iter().cloned());
        let (source, error) = match self.source(&topics) {
            Ok(s) => (Some(s), None),
            Err(e) => (None, Some(e)),
        };
        let mut asm = Assembler::new(self, joints_topic.is_some(), depth_topic);
        if let Some(e) = error {
            asm.ready.push_back(Err(e));
        }
        Frames {
            episode: self,
            source,
            asm,
        }
    }
}

/// The frames of an episode; see [`McapEpisode::frames`].
pub struct Frames<'a> {
    episode: &'a McapEpisode,
    source: Option<MessageSource>,
    asm: Assembler,
}

impl Iterator for Frames<'_> {
    type Item = Result<EpisodeFrame, EpisodeError>;

    fn next(&mut self) -> Option<Self::Item> {
        loop {
            if let Some(item) = self.asm.ready.pop_front() {
                return Some(item);
            }
            let source = self.source.as_mut()?;
            let asm = &mut self.asm;
            match source.next_with(|m| asm.push(m)) {
                Some(Ok(())) => {}
                end => {
                    self.asm.release(true);
                    self.episode.skipped_backwards.set(self.asm.skipped);
                    if let Some(Err(e)) = end {
                        self.asm.ready.push_back(Err(e));
                    } else if let Some(e) = self.episode.damage() {
                        // The summary-less scan found damage: report it after the frames.
                        self.asm.ready.push_back(Err(e));
                    }
                    self.source = None;
                }
            }
            self.episode.skipped_backwards.set(self.asm.skipped);
        }
    }
}
