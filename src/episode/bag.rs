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

use super::EpisodeError;
use super::joints::interpolate_rows;
use super::labels::Labels;
use super::ros::{
    CameraInfoMsg, CompressedImageMsg, ImageMsg, JointStateMsg, MessageError, decode_string, schema,
};
use crate::vision::GrayImage;
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
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
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
}

/// The `[episode]` settings section: reading recorded episodes.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
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
}

impl Default for EpisodeConfig {
    fn default() -> Self {
        Self {
            topics: EpisodeTopics::default(),
            max_joint_gap_ms: 100.0,
            max_image_bytes: 64 << 20,
            max_decompressed_bytes: 16 << 30,
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
    /// Notes: skipped images before this one, large joint gaps.
    pub warnings: Vec<String>,
    /// The image message as read.
    pub source: SourceMessage,
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
}

/// One MCAP file of an episode.
#[derive(Debug)]
struct Part {
    /// The file read: the file itself, or a decompressed copy of a `.mcap.zstd` file.
    read: PathBuf,
    /// The file as named (messages name it).
    path: PathBuf,
    summary: Option<Arc<Summary>>,
    damage: Option<(u64, String)>,
    /// The decompressed copy of a zstd-compressed file (removed when dropped).
    _copy: Option<tempfile::NamedTempFile>,
}

fn io_err(path: &Path, e: impl std::fmt::Display) -> EpisodeError {
    EpisodeError::Mcap {
        path: path.display().to_string(),
        reason: e.to_string(),
    }
}

/// Reads the summary section; `Ok(None)` when the file has none or it cannot be found
/// (a truncated file loses its footer).
fn read_summary(file: &mut File, path: &Path) -> Result<Option<Summary>, EpisodeError> {
    let len = file.metadata().map_err(|e| io_err(path, e))?.len();
    let mut reader = SummaryReader::new_with_options(
        mcap::sans_io::summary_reader::SummaryReaderOptions::default().with_file_size(len),
    );
    while let Some(event) = reader.next_event() {
        match event {
            Ok(SummaryReadEvent::ReadRequest(n)) => {
                let n = n.min(8 << 20);
                let got = file.read(reader.insert(n)).map_err(|e| io_err(path, e))?;
                reader.notify_read(got);
            }
            Ok(SummaryReadEvent::SeekRequest(to)) => {
                let pos = file.seek(to).map_err(|e| io_err(path, e))?;
                reader.notify_seeked(pos);
            }
            Err(e) => {
                tracing::debug!(path = %path.display(), error = %e, "no usable MCAP summary");
                return Ok(None);
            }
        }
    }
    Ok(reader.finish())
}

/// A channel as the reader sees it.
#[derive(Debug, Clone)]
struct ChannelMeta {
    topic: Arc<str>,
    schema: Arc<str>,
    encoding: Arc<str>,
    schema_id: u16,
}

/// One message handed to a consumer.
struct RawMsg<'m> {
    topic: &'m str,
    schema: &'m str,
    log_time: u64,
    data: &'m [u8],
}

/// Streams messages of some topics in log-time order: indexed (the reader merges
/// chunks), by linear scan (file order, put in log-time order within a window), or the
/// files of a bag folder one after another.
enum MessageSource {
    Indexed {
        /// The file as named (for errors).
        path: PathBuf,
        file: File,
        reader: Box<IndexedReader>,
        channels: HashMap<u16, ChannelMeta>,
        buf: Vec<u8>,
        file_len: u64,
        /// Offset of the chunk requested last (where an index-based read breaks).
        last_chunk: u64,
    },
    Linear {
        /// The file as named (for errors).
        path: PathBuf,
        scan: Box<LinearScan>,
        order: Reorder,
    },
    Chain(VecDeque<MessageSource>),
}

/// Messages a linear scan holds back to hand them out in log-time order: a recorder may
/// write messages out of order within a chunk, and a scan (unlike the indexed reader)
/// sees them in file order. Disorder within the window (by count and bytes) is undone;
/// beyond it, messages come in file order (and images whose stamps go back are skipped).
#[derive(Default)]
struct Reorder {
    held: std::collections::BinaryHeap<std::cmp::Reverse<Held>>,
    bytes: usize,
    seq: u64,
    ended: bool,
    error: Option<EpisodeError>,
}

/// Messages held by [`Reorder`] at most, and their bytes.
const REORDER_MESSAGES: usize = 1024;
const REORDER_BYTES: usize = 32 << 20;

/// A message held for reordering.
struct Held {
    log_time: u64,
    seq: u64,
    topic: Arc<str>,
    schema: Arc<str>,
    data: Vec<u8>,
}

impl PartialEq for Held {
    fn eq(&self, other: &Self) -> bool {
        (self.log_time, self.seq) == (other.log_time, other.seq)
    }
}

impl Eq for Held {}

impl PartialOrd for Held {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Held {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.log_time, self.seq).cmp(&(other.log_time, other.seq))
    }
}

impl Reorder {
    fn full(&self) -> bool {
        self.held.len() >= REORDER_MESSAGES || self.bytes >= REORDER_BYTES
    }

    /// The next message in log-time order from `scan`, handed to `f`.
    fn next_with<R>(
        &mut self,
        path: &Path,
        scan: &mut LinearScan,
        f: impl FnOnce(RawMsg<'_>) -> R,
    ) -> Option<Result<R, EpisodeError>> {
        while !self.ended && !self.full() {
            let seq = self.seq;
            match scan.next_with(|m| Held {
                log_time: m.log_time,
                seq,
                topic: m.topic.into(),
                schema: m.schema.into(),
                data: m.data.to_vec(),
            }) {
                Some(Ok(h)) => {
                    self.seq += 1;
                    self.bytes += h.data.len();
                    self.held.push(std::cmp::Reverse(h));
                }
                Some(Err((offset, reason))) => {
                    self.ended = true;
                    self.error = Some(EpisodeError::Truncated {
                        path: path.display().to_string(),
                        offset,
                        reason,
                    });
                }
                None => self.ended = true,
            }
        }
        match self.held.pop() {
            Some(std::cmp::Reverse(h)) => {
                self.bytes -= h.data.len();
                Some(Ok(f(RawMsg {
                    topic: &h.topic,
                    schema: &h.schema,
                    log_time: h.log_time,
                    data: &h.data,
                })))
            }
            None => self.error.take().map(Err),
        }
    }
}

/// A linear scan of a file, tolerant of damage at the end.
struct LinearScan {
    file: File,
    reader: LinearReader,
    channels: HashMap<u16, ChannelMeta>,
    schemas: HashMap<u16, (Arc<str>, Arc<str>)>,
    /// Bytes handed to the reader so far.
    fed: u64,
    topics: Option<Vec<String>>,
    /// Whether to keep schema definitions (for [`McapEpisode::schema_of`]).
    keep_schema_data: bool,
    schema_data: HashMap<u16, (String, String, Vec<u8>)>,
}

impl LinearScan {
    fn new(
        path: &Path,
        record_limit: usize,
        topics: Option<Vec<String>>,
    ) -> Result<Self, EpisodeError> {
        let file = File::open(path).map_err(|e| io_err(path, e))?;
        let reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_validate_chunk_crcs(true)
                .with_record_length_limit(record_limit),
        );
        Ok(Self {
            file,
            reader,
            channels: HashMap::new(),
            schemas: HashMap::new(),
            fed: 0,
            topics,
            keep_schema_data: false,
            schema_data: HashMap::new(),
        })
    }

    /// The next message of the chosen topics, handed to `f`; `Err((offset, reason))` where
    /// the file breaks.
    fn next_with<R>(
        &mut self,
        mut f: impl FnMut(RawMsg<'_>) -> R,
    ) -> Option<Result<R, (u64, String)>> {
        loop {
            let want = match self.reader.next_event()? {
                Err(e) => return Some(Err((self.fed, e.to_string()))),
                Ok(LinearReadEvent::ReadRequest(n)) => n.clamp(1, 4 << 20),
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE) {
                        continue;
                    }
                    let record = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(e) => return Some(Err((self.fed, e.to_string()))),
                    };
                    match record {
                        mcap::records::Record::Schema { header, data } => {
                            if self.keep_schema_data {
                                self.schema_data.insert(
                                    header.id,
                                    (header.name.clone(), header.encoding.clone(), data.to_vec()),
                                );
                            }
                            self.schemas
                                .insert(header.id, (header.name.into(), header.encoding.into()));
                        }
                        mcap::records::Record::Channel(c) => {
                            let schema = self
                                .schemas
                                .get(&c.schema_id)
                                .map(|(n, _)| n.clone())
                                .unwrap_or_else(|| Arc::from(""));
                            self.channels.insert(
                                c.id,
                                ChannelMeta {
                                    topic: c.topic.into(),
                                    schema,
                                    encoding: c.message_encoding.into(),
                                    schema_id: c.schema_id,
                                },
                            );
                        }
                        mcap::records::Record::Message { header, data } => {
                            let Some(ch) = self.channels.get(&header.channel_id) else {
                                continue;
                            };
                            if let Some(t) = &self.topics
                                && !t.iter().any(|t| **t == *ch.topic)
                            {
                                continue;
                            }
                            return Some(Ok(f(RawMsg {
                                topic: &ch.topic,
                                schema: &ch.schema,
                                log_time: header.log_time,
                                data: &data,
                            })));
                        }
                        _ => {}
                    }
                    continue;
                }
            };
            match self.file.read(self.reader.insert(want)) {
                Ok(got) => {
                    self.fed += got as u64;
                    self.reader.notify_read(got);
                }
                Err(e) => return Some(Err((self.fed, e.to_string()))),
            }
        }
    }
}

impl MessageSource {
    fn next_with<R>(
        &mut self,
        mut f: impl FnMut(RawMsg<'_>) -> R,
    ) -> Option<Result<R, EpisodeError>> {
        self.next_dyn(&mut f)
    }

    fn next_dyn<R>(
        &mut self,
        f: &mut dyn FnMut(RawMsg<'_>) -> R,
    ) -> Option<Result<R, EpisodeError>> {
        match self {
            MessageSource::Linear { path, scan, order } => order.next_with(path, scan, f),
            MessageSource::Chain(sources) => loop {
                let first = sources.front_mut()?;
                match first.next_dyn(f) {
                    Some(r) => return Some(r),
                    None => {
                        sources.pop_front();
                    }
                }
            },
            MessageSource::Indexed {
                path,
                file,
                reader,
                channels,
                buf,
                file_len,
                last_chunk,
            } => {
                loop {
                    let (offset, length) = match reader.next_event()? {
                        Err(e) => {
                            return Some(Err(EpisodeError::Truncated {
                                path: path.display().to_string(),
                                offset: *last_chunk,
                                reason: e.to_string(),
                            }));
                        }
                        Ok(IndexedReadEvent::Message { header, data }) => {
                            let Some(ch) = channels.get(&header.channel_id) else {
                                continue;
                            };
                            return Some(Ok(f(RawMsg {
                                topic: &ch.topic,
                                schema: &ch.schema,
                                log_time: header.log_time,
                                data,
                            })));
                        }
                        Ok(IndexedReadEvent::ReadChunkRequest { offset, length }) => {
                            (offset, length)
                        }
                    };
                    *last_chunk = offset;
                    let broken = |reason: String| {
                        Some(Err(EpisodeError::Truncated {
                            path: path.display().to_string(),
                            offset,
                            reason,
                        }))
                    };
                    // The index is data too: a chunk past the end must not size a buffer.
                    if offset.saturating_add(length as u64) > *file_len {
                        return broken(format!(
                            "chunk of {length} bytes at {offset} runs past the end ({file_len})"
                        ));
                    }
                    buf.resize(length, 0);
                    if let Err(e) = file
                        .seek(SeekFrom::Start(offset))
                        .and_then(|_| file.read_exact(buf))
                    {
                        return broken(e.to_string());
                    }
                    if let Err(e) = reader.insert_chunk_record_data(offset, buf) {
                        return broken(e.to_string());
                    }
                }
            }
        }
    }
}

/// The episode name of a file or bag folder: the file name without `.mcap` and a
/// compression suffix, or the folder's name.
fn episode_name(path: &Path) -> String {
    let file = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "episode".into());
    let mut name = file.as_str();
    for suffix in [".zstd", ".zst", ".mcap"] {
        name = name.strip_suffix(suffix).unwrap_or(name);
    }
    if name.is_empty() {
        "episode".into()
    } else {
        name.to_string()
    }
}

/// The MCAP files of a rosbag2 bag folder (what `ros2 bag record` writes: `metadata.yaml`
/// beside `<name>_0.mcap`, `<name>_1.mcap`, ..., each possibly `.zstd`-compressed), in
/// recording order (by the number after the last `_`, then by name).
fn bag_folder_files(dir: &Path) -> Result<Vec<PathBuf>, EpisodeError> {
    let entries = std::fs::read_dir(dir).map_err(|e| io_err(dir, e))?;
    let mut files: Vec<(u64, String, PathBuf)> = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| io_err(dir, e))?.path();
        let name = path
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if !path.is_file() || !(name.ends_with(".mcap") || name.ends_with(".mcap.zstd")) {
            continue;
        }
        let stem = episode_name(&path);
        let number = stem
            .rsplit_once('_')
            .and_then(|(_, n)| n.parse::<u64>().ok())
            .unwrap_or(0);
        files.push((number, name, path));
    }
    files.sort();
    if files.is_empty() {
        return Err(EpisodeError::Mcap {
            path: dir.display().to_string(),
            reason: "a folder without .mcap files (a rosbag2 bag folder holds metadata.yaml \
                     and <name>_<n>.mcap files)"
                .into(),
        });
    }
    Ok(files.into_iter().map(|(_, _, p)| p).collect())
}

/// A zstd-compressed MCAP file (rosbag2's file compression, `.mcap.zstd`) decompressed
/// into a temporary file, at most `limit` bytes.
fn decompress_file(path: &Path, limit: u64) -> Result<tempfile::NamedTempFile, EpisodeError> {
    let err = |reason: String| EpisodeError::Mcap {
        path: path.display().to_string(),
        reason,
    };
    let file = File::open(path).map_err(|e| io_err(path, e))?;
    let mut decoder = zstd::stream::read::Decoder::new(file)
        .map_err(|e| err(format!("zstd-compressed file: {e}")))?;
    let mut copy = tempfile::Builder::new()
        .prefix("vamos-episode-")
        .suffix(".mcap")
        .tempfile()
        .map_err(|e| {
            err(format!(
                "cannot make a temporary file to decompress into: {e}"
            ))
        })?;
    let copied = std::io::copy(&mut (&mut decoder).take(limit + 1), copy.as_file_mut())
        .map_err(|e| err(format!("zstd-compressed file: {e}")))?;
    if copied > limit {
        return Err(err(format!(
            "decompresses to more than {limit} bytes ([episode] max_decompressed_bytes)"
        )));
    }
    Ok(copy)
}

/// The topics of one file, by name.
type PartTopics = BTreeMap<String, TopicInfo>;

impl Part {
    /// Opens one file: its summary when complete, else a linear scan for the topics and
    /// the damage. Returns the part, its topics and its (first, last) log times.
    fn open(
        path: &Path,
        cfg: &EpisodeConfig,
    ) -> Result<(Self, PartTopics, (u64, u64)), EpisodeError> {
        let mut file = File::open(path).map_err(|e| io_err(path, e))?;
        let mut magic = [0u8; 4];
        let compressed = file.read_exact(&mut magic).is_ok() && magic == ZSTD_MAGIC;
        let copy = if compressed {
            Some(decompress_file(path, cfg.max_decompressed_bytes)?)
        } else {
            None
        };
        let read = copy
            .as_ref()
            .map_or(path.to_path_buf(), |c| c.path().to_path_buf());
        let mut file = File::open(&read).map_err(|e| io_err(path, e))?;
        let summary = read_summary(&mut file, path)?.filter(|s| {
            // Index-based reading needs statistics (counts), chunk indexes and a channel
            // for every channel with messages; anything less is read by a scan.
            s.stats.as_ref().is_some_and(|st| {
                st.message_count == 0
                    || (!s.chunk_indexes.is_empty()
                        && !s.channels.is_empty()
                        && st
                            .channel_message_counts
                            .keys()
                            .all(|id| s.channels.contains_key(id)))
            })
        });
        let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
        let (span, damage);
        if let Some(s) = &summary {
            // Invariant: the filter above kept only summaries with statistics.
            let stats = s.stats.clone().unwrap_or_default();
            for (id, ch) in &s.channels {
                let t = topics.entry(ch.topic.clone()).or_insert_with(|| TopicInfo {
                    name: ch.topic.clone(),
                    schema: ch
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    message_encoding: ch.message_encoding.clone(),
                    message_count: 0,
                });
                t.message_count += stats.channel_message_counts.get(id).copied().unwrap_or(0);
            }
            (span, damage) = ((stats.message_start_time, stats.message_end_time), None);
        } else {
            let mut scan = LinearScan::new(&read, record_limit(cfg), None)?;
            let mut counts: HashMap<String, u64> = HashMap::new();
            let (mut lo, mut hi) = (u64::MAX, 0u64);
            let mut broke = None;
            while let Some(r) = scan.next_with(|m| {
                *counts.entry(m.topic.to_string()).or_default() += 1;
                (lo, hi) = (lo.min(m.log_time), hi.max(m.log_time));
            }) {
                if let Err(e) = r {
                    broke = Some(e);
                    break;
                }
            }
            for ch in scan.channels.values() {
                topics
                    .entry(ch.topic.to_string())
                    .or_insert_with(|| TopicInfo {
                        name: ch.topic.to_string(),
                        schema: ch.schema.to_string(),
                        message_encoding: ch.encoding.to_string(),
                        message_count: counts.get(&*ch.topic).copied().unwrap_or(0),
                    });
            }
            if lo == u64::MAX {
                lo = 0;
            }
            // Nothing readable at all: say where it broke rather than "no topics".
            if let (Some((offset, reason)), true) = (&broke, topics.is_empty()) {
                return Err(EpisodeError::Truncated {
                    path: path.display().to_string(),
                    offset: *offset,
                    reason: reason.clone(),
                });
            }
            (span, damage) = ((lo, hi), broke);
        }
        let part = Self {
            read,
            path: path.to_path_buf(),
            summary: summary.map(Arc::new),
            damage,
            _copy: copy,
        };
        Ok((part, topics, span))
    }

    fn source(
        &self,
        topics: &[String],
        cfg: &EpisodeConfig,
    ) -> Result<MessageSource, EpisodeError> {
        match &self.summary {
            Some(summary) => {
                let file = File::open(&self.read).map_err(|e| io_err(&self.path, e))?;
                let file_len = file.metadata().map_err(|e| io_err(&self.path, e))?.len();
                let reader = IndexedReader::new_with_options(
                    summary,
                    IndexedReaderOptions::new()
                        .with_order(ReadOrder::LogTime)
                        .include_topics(topics.iter().cloned())
                        .with_record_length_limit(record_limit(cfg)),
                )
                .map_err(|e| io_err(&self.path, e))?;
                let channels = summary
                    .channels
                    .iter()
                    .map(|(id, ch)| {
                        (
                            *id,
                            ChannelMeta {
                                topic: ch.topic.as_str().into(),
                                schema: ch
                                    .schema
                                    .as_ref()
                                    .map_or_else(|| Arc::from(""), |s| s.name.as_str().into()),
                                encoding: ch.message_encoding.as_str().into(),
                                schema_id: ch.schema.as_ref().map_or(0, |s| s.id),
                            },
                        )
                    })
                    .collect();
                Ok(MessageSource::Indexed {
                    path: self.path.clone(),
                    file,
                    reader: Box::new(reader),
                    channels,
                    buf: Vec::new(),
                    file_len,
                    last_chunk: 0,
                })
            }
            None => Ok(MessageSource::Linear {
                path: self.path.clone(),
                scan: Box::new(LinearScan::new(
                    &self.read,
                    record_limit(cfg),
                    Some(topics.to_vec()),
                )?),
                order: Reorder::default(),
            }),
        }
    }
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
            if part.summary.is_none() || lo != 0 || hi != 0 {
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
            indexed: parts.iter().all(|p| p.summary.is_some()),
            image_messages: count(&Some(chosen.image.clone())),
            camera_info_messages: count(&chosen.camera_info),
            joint_messages: count(&chosen.joint_states),
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
        })
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

impl Part {
    fn schema_of(
        &self,
        topic: &str,
        cfg: &EpisodeConfig,
    ) -> Result<Option<(String, String, Vec<u8>)>, EpisodeError> {
        if let Some(summary) = &self.summary {
            return Ok(summary
                .channels
                .values()
                .find(|c| c.topic == topic)
                .and_then(|c| c.schema.as_ref())
                .map(|s| (s.name.clone(), s.encoding.clone(), s.data.to_vec())));
        }
        let mut scan = LinearScan::new(&self.read, record_limit(cfg), Some(vec![topic.into()]))?;
        scan.keep_schema_data = true;
        while let Some(r) = scan.next_with(|_| ()) {
            if r.is_err() {
                break;
            }
            if scan.channels.values().any(|c| &*c.topic == topic) {
                break;
            }
        }
        Ok(scan
            .channels
            .iter()
            .find(|(_, c)| &*c.topic == topic)
            .and_then(|(_, c)| {
                scan.schema_data
                    .get(&c.schema_id)
                    .map(|(n, e, d)| (n.clone(), e.clone(), d.clone()))
            }))
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
        let (source, error) = match self.source(&topics) {
            Ok(s) => (Some(s), None),
            Err(e) => (None, Some(e)),
        };
        let mut asm = Assembler::new(self, joints_topic.is_some());
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

fn record_limit(cfg: &EpisodeConfig) -> usize {
    cfg.max_image_bytes.saturating_mul(4).max(256 << 20)
}

fn resolve_topics(
    topics: &[TopicInfo],
    wanted: &EpisodeTopics,
    path: &Path,
    warnings: &mut Vec<String>,
) -> Result<ChosenTopics, EpisodeError> {
    let err = |reason: String| EpisodeError::Topic {
        path: path.display().to_string(),
        reason,
    };
    let find = |name: &str| topics.iter().find(|t| t.name == name);
    let is_image =
        |t: &TopicInfo| t.schema == schema::IMAGE || t.schema == schema::COMPRESSED_IMAGE;
    let list = |v: &[&TopicInfo]| {
        v.iter()
            .map(|t| format!("{} ({})", t.name, t.schema))
            .collect::<Vec<_>>()
            .join(", ")
    };
    // A configured topic must exist with one of the schemas.
    let configured = |name: &str, schemas: &[&str]| -> Result<String, EpisodeError> {
        match find(name) {
            Some(t) if schemas.contains(&t.schema.as_str()) => Ok(t.name.clone()),
            Some(t) => Err(err(format!(
                "topic {name} has schema {}, expected {}",
                t.schema,
                schemas.join(" or ")
            ))),
            None => Err(err(format!(
                "topic {name} is not in the file (topics: {})",
                list(&topics.iter().collect::<Vec<_>>())
            ))),
        }
    };
    let image = match &wanted.image {
        Some(name) => configured(name, &[schema::IMAGE, schema::COMPRESSED_IMAGE])?,
        None => match find(default_topic::IMAGE).filter(|t| is_image(t)) {
            Some(t) => t.name.clone(),
            None => {
                let all: Vec<&TopicInfo> = topics.iter().filter(|t| is_image(t)).collect();
                let colour: Vec<&TopicInfo> = all
                    .iter()
                    .copied()
                    .filter(|t| !t.name.contains("depth"))
                    .collect();
                match (all.as_slice(), colour.as_slice()) {
                    ([], _) => {
                        return Err(err(
                            "no sensor_msgs/msg/Image or CompressedImage topic".into()
                        ));
                    }
                    ([one], _) | (_, [one]) => one.name.clone(),
                    _ => {
                        return Err(err(format!(
                            "several image topics, set [episode.topics] image: {}",
                            list(&all)
                        )));
                    }
                }
            }
        },
    };
    let image_schema = find(&image).map(|t| t.schema.clone()).unwrap_or_default();
    let image_ns = image.rsplit_once('/').map_or("", |(ns, _)| ns).to_string();
    // Optional topics: configured, default name, only one of the schema, or (several)
    // the one in the image topic's namespace.
    let optional = |configured_name: &Option<String>,
                    default: &str,
                    schema_name: &str,
                    name_filter: &dyn Fn(&str) -> bool,
                    warnings: &mut Vec<String>|
     -> Result<Option<String>, EpisodeError> {
        if let Some(name) = configured_name {
            return configured(name, &[schema_name]).map(Some);
        }
        if let Some(t) = find(default).filter(|t| t.schema == schema_name) {
            return Ok(Some(t.name.clone()));
        }
        let cands: Vec<&TopicInfo> = topics
            .iter()
            .filter(|t| t.schema == schema_name && name_filter(&t.name))
            .collect();
        match cands.as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(one.name.clone())),
            many => {
                let same_ns: Vec<&&TopicInfo> = many
                    .iter()
                    .filter(|t| t.name.rsplit_once('/').map_or("", |(ns, _)| ns) == image_ns)
                    .collect();
                if let [one] = same_ns.as_slice() {
                    return Ok(Some(one.name.clone()));
                }
                warnings.push(format!(
                    "several {schema_name} topics, none used (set [episode.topics]): {}",
                    list(many)
                ));
                Ok(None)
            }
        }
    };
    let any = |_: &str| true;
    Ok(ChosenTopics {
        camera_info: optional(
            &wanted.camera_info,
            default_topic::CAMERA_INFO,
            schema::CAMERA_INFO,
            &any,
            warnings,
        )?,
        joint_states: optional(
            &wanted.joint_states,
            default_topic::JOINT_STATES,
            schema::JOINT_STATE,
            &any,
            warnings,
        )?,
        robot_description: optional(
            &wanted.robot_description,
            default_topic::ROBOT_DESCRIPTION,
            schema::STRING,
            &|n: &str| n.ends_with("robot_description"),
            warnings,
        )?,
        labels: optional(
            &wanted.labels,
            default_topic::LABELS,
            schema::STRING,
            &|_: &str| false,
            warnings,
        )?,
        image,
        image_schema,
    })
}

/// The zstd frame magic (rosbag2's message and file compression).
const ZSTD_MAGIC: [u8; 4] = [0x28, 0xb5, 0x2f, 0xfd];

fn is_zstd(data: &[u8]) -> bool {
    data.starts_with(&ZSTD_MAGIC)
}

/// Decompresses a zstd-compressed message payload, refusing more than `limit` bytes
/// (read in steps, so a bomb costs at most `limit`).
fn decompress_payload(data: &[u8], limit: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let decoder = zstd::stream::read::Decoder::new(data).map_err(|e| e.to_string())?;
    let read = decoder
        .take(limit as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("zstd-compressed message: {e}"))?;
    if read > limit {
        return Err(format!(
            "zstd-compressed message decompresses to more than {limit} bytes"
        ));
    }
    Ok(out)
}

/// A decoded image waiting for joint samples.
struct PendingFrame {
    index: usize,
    stamp_ns: i64,
    image: GrayImage,
    camera_info: Option<CameraInfoMsg>,
    warnings: Vec<String>,
    source: SourceMessage,
}

/// Turns the message stream into frames.
struct Assembler {
    image_topic: String,
    max_image_bytes: usize,
    max_gap_ns: f64,
    joints_expected: bool,
    pending: VecDeque<Result<PendingFrame, EpisodeError>>,
    ready: VecDeque<Result<EpisodeFrame, EpisodeError>>,
    camera_info: Option<CameraInfoMsg>,
    last_image_stamp: Option<i64>,
    size: Option<(usize, usize)>,
    carry_warnings: Vec<String>,
    images_seen: usize,
    joint_msgs_seen: usize,
    camera_msgs_seen: usize,
    skipped: usize,
    // Joint window: stamps sorted ascending, positions and velocities row-major.
    joint_names: Option<Vec<String>>,
    joint_stamps: Vec<i64>,
    joint_pos: Vec<f64>,
    joint_vel: Vec<f64>,
    joint_has_vel: Vec<bool>,
    latest_joint_ns: Option<i64>,
}

fn stamp_or_log_time(stamp_ns: i64, log_time: u64) -> i64 {
    if stamp_ns == 0 {
        i64::try_from(log_time).unwrap_or(i64::MAX)
    } else {
        stamp_ns
    }
}

impl Assembler {
    fn new(ep: &McapEpisode, joints_expected: bool) -> Self {
        Self {
            image_topic: ep.info.chosen.image.clone(),
            max_image_bytes: ep.cfg.max_image_bytes,
            max_gap_ns: ep.cfg.max_joint_gap_ms * 1e6,
            joints_expected,
            pending: VecDeque::new(),
            ready: VecDeque::new(),
            camera_info: None,
            last_image_stamp: None,
            size: None,
            carry_warnings: Vec::new(),
            images_seen: 0,
            joint_msgs_seen: 0,
            camera_msgs_seen: 0,
            skipped: 0,
            joint_names: None,
            joint_stamps: Vec::new(),
            joint_pos: Vec::new(),
            joint_vel: Vec::new(),
            joint_has_vel: Vec::new(),
            latest_joint_ns: None,
        }
    }

    fn push(&mut self, m: RawMsg<'_>) {
        // rosbag2's per-message compression: the payload is a zstd frame.
        if is_zstd(m.data) {
            match decompress_payload(m.data, self.max_image_bytes) {
                Ok(data) => self.dispatch(RawMsg { data: &data, ..m }),
                Err(reason) => {
                    let index = if m.topic == self.image_topic {
                        self.images_seen += 1;
                        self.images_seen - 1
                    } else {
                        0
                    };
                    self.pending.push_back(Err(EpisodeError::BadMessage {
                        topic: m.topic.into(),
                        index,
                        reason,
                    }));
                    self.release(false);
                }
            }
        } else {
            self.dispatch(m);
        }
    }

    fn dispatch(&mut self, m: RawMsg<'_>) {
        if m.topic == self.image_topic {
            let index = self.images_seen;
            self.images_seen += 1;
            let item = self.image(m, index);
            if let Some(item) = item {
                self.pending.push_back(item);
            }
        } else if m.schema == schema::CAMERA_INFO {
            let index = self.camera_msgs_seen;
            self.camera_msgs_seen += 1;
            match CameraInfoMsg::decode(m.data) {
                Ok(ci) => self.camera_info = Some(ci),
                Err(e) => self.pending.push_back(Err(bad(m.topic, index, e))),
            }
        } else if m.schema == schema::JOINT_STATE {
            let index = self.joint_msgs_seen;
            self.joint_msgs_seen += 1;
            if let Err(e) = self.joint(m.data, m.log_time) {
                self.pending.push_back(Err(EpisodeError::BadMessage {
                    topic: m.topic.into(),
                    index,
                    reason: e,
                }));
            }
        }
        self.release(false);
    }

    fn image(&mut self, m: RawMsg<'_>, index: usize) -> Option<Result<PendingFrame, EpisodeError>> {
        if m.data.len() > self.max_image_bytes {
            return Some(Err(EpisodeError::BadMessage {
                topic: m.topic.into(),
                index,
                reason: format!(
                    "{} bytes exceed max_image_bytes {}",
                    m.data.len(),
                    self.max_image_bytes
                ),
            }));
        }
        let decoded = if m.schema == schema::COMPRESSED_IMAGE {
            CompressedImageMsg::decode(m.data)
                .and_then(|c| Ok((c.header.stamp_ns(), c.to_gray(self.max_image_bytes)?)))
        } else {
            ImageMsg::decode(m.data)
                .and_then(|c| Ok((c.header.stamp_ns(), c.to_gray(self.max_image_bytes)?)))
        };
        let (stamp, image) = match decoded {
            Ok(v) => v,
            Err(MessageError::UnknownEncoding { encoding }) => {
                return Some(Err(EpisodeError::UnknownEncoding {
                    topic: m.topic.into(),
                    index,
                    encoding,
                }));
            }
            Err(e) => return Some(Err(bad(m.topic, index, e))),
        };
        let stamp_ns = stamp_or_log_time(stamp, m.log_time);
        if let Some(prev) = self.last_image_stamp
            && stamp_ns <= prev
        {
            self.skipped += 1;
            self.carry_warnings.push(format!(
                "image {index} skipped: stamp {stamp_ns} ns does not increase (previous {prev} ns)"
            ));
            return None;
        }
        let (w, h) = image.size();
        match self.size {
            None => self.size = Some((w, h)),
            Some((ew, eh)) if (ew, eh) != (w, h) => {
                return Some(Err(EpisodeError::ImageSizeChanged {
                    index,
                    expected_width: ew,
                    expected_height: eh,
                    width: w,
                    height: h,
                }));
            }
            Some(_) => {}
        }
        self.last_image_stamp = Some(stamp_ns);
        Some(Ok(PendingFrame {
            index,
            stamp_ns,
            image,
            camera_info: self.camera_info.clone(),
            warnings: std::mem::take(&mut self.carry_warnings),
            source: SourceMessage {
                topic: m.topic.into(),
                schema: m.schema.into(),
                log_time_ns: m.log_time,
                cdr: m.data.to_vec(),
            },
        }))
    }

    fn joint(&mut self, data: &[u8], log_time: u64) -> Result<(), String> {
        let msg = JointStateMsg::decode(data).map_err(|e| e.to_string())?;
        let stamp = stamp_or_log_time(msg.header.stamp_ns(), log_time);
        let names = self.joint_names.get_or_insert_with(|| msg.name.clone());
        // Map the message's order onto the first message's names.
        let order: Vec<usize> = if *names == msg.name {
            (0..names.len()).collect()
        } else {
            names
                .iter()
                .map(|n| {
                    msg.name
                        .iter()
                        .position(|m| m == n)
                        .ok_or_else(|| format!("joint {n} missing (names {:?})", msg.name))
                })
                .collect::<Result<_, _>>()?
        };
        let at = self.joint_stamps.partition_point(|&t| t <= stamp);
        if at > 0 && self.joint_stamps[at - 1] == stamp {
            return Err(format!("duplicate joint stamp {stamp} ns"));
        }
        let n = order.len();
        let has_vel = !msg.velocity.is_empty();
        self.joint_stamps.insert(at, stamp);
        self.joint_has_vel.insert(at, has_vel);
        let pos: Vec<f64> = order.iter().map(|&i| msg.position[i]).collect();
        let vel: Vec<f64> = order
            .iter()
            .map(|&i| msg.velocity.get(i).copied().unwrap_or(0.0))
            .collect();
        self.joint_pos.splice(at * n..at * n, pos);
        self.joint_vel.splice(at * n..at * n, vel);
        self.latest_joint_ns = Some(self.latest_joint_ns.map_or(stamp, |l| l.max(stamp)));
        Ok(())
    }

    /// Moves frames whose joints are known (or all, at the end) to `ready`.
    fn release(&mut self, at_end: bool) {
        while let Some(front) = self.pending.front() {
            let go = match front {
                Err(_) => true,
                Ok(p) => {
                    at_end
                        || !self.joints_expected
                        || self.latest_joint_ns.is_some_and(|l| l >= p.stamp_ns)
                        || self.pending.len() > MAX_PENDING_IMAGES
                }
            };
            if !go {
                break;
            }
            match self.pending.pop_front() {
                Some(Ok(p)) => {
                    let frame = self.finish_frame(p);
                    self.ready.push_back(Ok(frame));
                }
                Some(Err(e)) => self.ready.push_back(Err(e)),
                None => break,
            }
        }
    }

    fn finish_frame(&mut self, p: PendingFrame) -> EpisodeFrame {
        let mut warnings = p.warnings;
        let joints = match &self.joint_names {
            Some(names) if !self.joint_stamps.is_empty() => {
                let n = names.len();
                let s = interpolate_rows(&self.joint_stamps, &self.joint_pos, n, p.stamp_ns);
                // Velocities only when both samples used carry them.
                let after = self.joint_stamps.partition_point(|&t| t < p.stamp_ns);
                let used = [
                    after.saturating_sub(1),
                    after.min(self.joint_stamps.len() - 1),
                ];
                let velocities = if used.iter().all(|&i| self.joint_has_vel[i]) {
                    interpolate_rows(&self.joint_stamps, &self.joint_vel, n, p.stamp_ns).positions
                } else {
                    Vec::new()
                };
                let beyond_max_gap = s.gap_ns as f64 > self.max_gap_ns;
                if beyond_max_gap {
                    warnings.push(format!(
                        "nearest joint sample is {:.1} ms away",
                        s.gap_ns as f64 * 1e-6
                    ));
                }
                // Later images have later stamps: samples before the last one at or
                // before this stamp are no longer needed.
                let keep_from = after.saturating_sub(1);
                if keep_from > 0 {
                    self.joint_stamps.drain(..keep_from);
                    self.joint_has_vel.drain(..keep_from);
                    self.joint_pos.drain(..keep_from * n);
                    self.joint_vel.drain(..keep_from * n);
                }
                Some(JointStateAt {
                    names: names.clone(),
                    positions: s.positions,
                    velocities,
                    gap_ns: s.gap_ns,
                    extrapolated: s.extrapolated,
                    beyond_max_gap,
                })
            }
            _ => None,
        };
        EpisodeFrame {
            index: p.index,
            stamp_ns: p.stamp_ns,
            image: p.image,
            camera_info: p.camera_info,
            joints,
            warnings,
            source: p.source,
        }
    }
}

fn bad(topic: &str, index: usize, e: MessageError) -> EpisodeError {
    EpisodeError::BadMessage {
        topic: topic.into(),
        index,
        reason: e.to_string(),
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
