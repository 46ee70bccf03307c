//! Writing score bags: an MCAP file (zstd chunks, profile `ros2`) with the input's images
//! and vamos's outputs as ROS 2 messages, openable by Foxglove and `ros2 bag play`.
//!
//! Schemas are written with encoding `ros2msg` and the full message definition (dependent
//! types after `====` separators, as rosbag2 stores them); channels use message encoding
//! `cdr`. Each message's log time and publish time are its stamp.

use super::EpisodeError;
use super::bag::{EpisodeInfo, SourceMessage};
use super::image::Encoding;
use super::ros::{self, CompressedImageMsg, Header, ImageMsg, schema};
use crate::eval::DetectorValues;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

/// An image to write.
#[derive(Debug, Clone, Copy)]
pub enum ImageData<'a> {
    /// A message as read (its CDR bytes are copied unchanged, with its schema, which must
    /// be `sensor_msgs/msg/Image` or `sensor_msgs/msg/CompressedImage`).
    Source(&'a SourceMessage),
    /// Raw pixels, packed rows (`step` = width x bytes per pixel).
    Raw {
        /// Columns.
        width: u32,
        /// Rows.
        height: u32,
        /// ROS encoding (`rgb8`, `mono8`, ...).
        encoding: &'a str,
        /// Pixels.
        data: &'a [u8],
    },
    /// A compressed file (`sensor_msgs/msg/CompressedImage`).
    Compressed {
        /// Format string (`jpeg`, `png`).
        format: &'a str,
        /// The file's bytes.
        data: &'a [u8],
    },
}

/// One frame's outputs as score topics (see [`ScoreBagWriter::write_scored_frame`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct ScoreTopics<'a> {
    /// The fused score (`/vamos/score`).
    pub score: f64,
    /// The alarm (`/vamos/anomaly`).
    pub anomaly: bool,
    /// Each detector's value (`/vamos/e_c` .. `/vamos/e_k`, [`crate::eval::Detector::topic`]), when
    /// defined.
    pub values: DetectorValues,
    /// Square squared-error map of the best prediction (`/vamos/heatmap`), when kept.
    pub heatmap: Option<&'a [f32]>,
    /// The frame's anomaly map `(width, height, mono8 pixels)` (`/vamos/anomaly_map`,
    /// 0 = nominal), when there is one.
    pub anomaly_map: Option<(u32, u32, &'a [u8])>,
    /// The thresholds in force as JSON (`/vamos/thresholds`, a `std_msgs/msg/String`),
    /// written when given (once, with the first frame).
    pub thresholds_json: Option<&'a str>,
}

/// Colours a squared-error map: black (0) through red and yellow to white at an RMS error
/// of 0.25 network units (7.5 px at 640 px wide), the same scale for every frame.
pub fn heatmap_rgb(map: &[f32]) -> Vec<u8> {
    let mut rgb = Vec::with_capacity(map.len() * 3);
    for &v in map {
        let x = (v.max(0.0).sqrt() / 0.25).clamp(0.0, 1.0);
        let r = (x * 3.0).min(1.0);
        let g = (x * 3.0 - 1.0).clamp(0.0, 1.0);
        let b = (x * 3.0 - 2.0).clamp(0.0, 1.0);
        rgb.extend([(r * 255.0) as u8, (g * 255.0) as u8, (b * 255.0) as u8]);
    }
    rgb
}

/// Writes a score bag. Call [`ScoreBagWriter::finish`] to complete the file (a writer
/// dropped without it leaves a file without summary, which readers scan linearly).
pub struct ScoreBagWriter {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    schemas: HashMap<(String, String, Vec<u8>), u16>,
    channels: HashMap<String, (u16, String)>,
    sequence: u32,
}

impl std::fmt::Debug for ScoreBagWriter {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ScoreBagWriter")
            .field("path", &self.path)
            .field("channels", &self.channels.len())
            .finish_non_exhaustive()
    }
}

fn stamp_u64(stamp_ns: i64) -> u64 {
    u64::try_from(stamp_ns).unwrap_or(0)
}

impl ScoreBagWriter {
    /// Creates `path` (replacing it). `input` (the episode scored) goes into a metadata
    /// record `vamos.input` (name, path, image topic).
    pub fn create(path: &Path, input: Option<&EpisodeInfo>) -> Result<Self, EpisodeError> {
        let err = |e: &dyn std::fmt::Display| EpisodeError::Mcap {
            path: path.display().to_string(),
            reason: e.to_string(),
        };
        let file = File::create(path).map_err(|e| err(&e))?;
        let mut writer = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("vamos ", env!("CARGO_PKG_VERSION")))
            .compression(Some(mcap::Compression::Zstd))
            .create(BufWriter::new(file))
            .map_err(|e| err(&e))?;
        if let Some(info) = input {
            let metadata = BTreeMap::from([
                ("episode".to_string(), info.name.clone()),
                ("path".to_string(), info.path.display().to_string()),
                ("image_topic".to_string(), info.chosen.image.clone()),
            ]);
            writer
                .write_metadata(&mcap::records::Metadata {
                    name: "vamos.input".into(),
                    metadata,
                })
                .map_err(|e| err(&e))?;
        }
        Ok(Self {
            path: path.to_path_buf(),
            writer,
            schemas: HashMap::new(),
            channels: HashMap::new(),
            sequence: 0,
        })
    }

    fn err(&self, e: impl std::fmt::Display) -> EpisodeError {
        EpisodeError::Mcap {
            path: self.path.display().to_string(),
            reason: e.to_string(),
        }
    }

    fn channel(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema_data: &[u8],
        message_encoding: &str,
    ) -> Result<u16, EpisodeError> {
        if let Some((id, existing)) = self.channels.get(topic) {
            if existing != schema_name {
                return Err(self.err(format!(
                    "topic {topic} already carries {existing}, not {schema_name}"
                )));
            }
            return Ok(*id);
        }
        let key = (
            schema_name.to_string(),
            schema_encoding.to_string(),
            schema_data.to_vec(),
        );
        let schema_id = match self.schemas.get(&key) {
            Some(id) => *id,
            None => {
                let id = self
                    .writer
                    .add_schema(schema_name, schema_encoding, schema_data)
                    .map_err(|e| self.err(e))?;
                self.schemas.insert(key, id);
                id
            }
        };
        let id = self
            .writer
            .add_channel(schema_id, topic, message_encoding, &BTreeMap::new())
            .map_err(|e| self.err(e))?;
        self.channels
            .insert(topic.to_string(), (id, schema_name.to_string()));
        Ok(id)
    }

    fn ros_channel(&mut self, topic: &str, schema_name: &str) -> Result<u16, EpisodeError> {
        let def = ros::definition(schema_name)
            .ok_or_else(|| self.err(format!("no definition for {schema_name}")))?;
        self.channel(topic, schema_name, "ros2msg", def.as_bytes(), "cdr")
    }

    fn write(&mut self, channel_id: u16, log_time: u64, data: &[u8]) -> Result<(), EpisodeError> {
        self.sequence = self.sequence.wrapping_add(1);
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: self.sequence,
            log_time,
            publish_time: log_time,
        };
        self.writer
            .write_to_known_channel(&header, data)
            .map_err(|e| self.err(e))
    }

    /// Writes an image on `topic` at `stamp_ns` (log time; a [`ImageData::Raw`] image also
    /// gets it as header stamp).
    pub fn write_image(
        &mut self,
        topic: &str,
        stamp_ns: i64,
        image: ImageData<'_>,
    ) -> Result<(), EpisodeError> {
        match image {
            ImageData::Source(src) => {
                if src.schema != schema::IMAGE && src.schema != schema::COMPRESSED_IMAGE {
                    return Err(self.err(format!("{} is not an image schema", src.schema)));
                }
                let id = self.ros_channel(topic, &src.schema)?;
                self.write(id, stamp_u64(stamp_ns), &src.cdr)
            }
            ImageData::Raw {
                width,
                height,
                encoding,
                data,
            } => {
                // The one encoding table (any letter case); files have no row size.
                let Some(bpp) = Encoding::from_name(encoding).and_then(Encoding::bytes_per_pixel)
                else {
                    return Err(self.err(format!("unknown image encoding {encoding:?}")));
                };
                let step = width as usize * bpp;
                if data.len() != step * height as usize {
                    return Err(self.err(format!(
                        "{} bytes for a {width}x{height} {encoding} image (expected {})",
                        data.len(),
                        step * height as usize
                    )));
                }
                let msg = ImageMsg {
                    header: Header::from_stamp_ns(stamp_ns, ""),
                    height,
                    width,
                    encoding: encoding.into(),
                    is_bigendian: false,
                    step: u32::try_from(step).map_err(|e| self.err(e))?,
                    data,
                };
                let id = self.ros_channel(topic, schema::IMAGE)?;
                self.write(id, stamp_u64(stamp_ns), &msg.encode())
            }
            ImageData::Compressed { format, data } => {
                let msg = CompressedImageMsg {
                    header: Header::from_stamp_ns(stamp_ns, ""),
                    format: format.into(),
                    data,
                };
                let id = self.ros_channel(topic, schema::COMPRESSED_IMAGE)?;
                self.write(id, stamp_u64(stamp_ns), &msg.encode())
            }
        }
    }

    /// Writes a message already encoded (CDR) of ROS 2 type `schema_name` on `topic` at
    /// log time `stamp_ns`.
    pub fn write_cdr(
        &mut self,
        topic: &str,
        schema_name: &str,
        stamp_ns: i64,
        cdr: &[u8],
    ) -> Result<(), EpisodeError> {
        let id = self.ros_channel(topic, schema_name)?;
        self.write(id, stamp_u64(stamp_ns), cdr)
    }

    /// Writes a `sensor_msgs/msg/JointState` of positions and efforts (empty: none),
    /// stamped `stamp_ns`.
    pub fn write_joint_state(
        &mut self,
        topic: &str,
        stamp_ns: i64,
        names: &[String],
        positions: &[f64],
        efforts: &[f64],
    ) -> Result<(), EpisodeError> {
        let msg = ros::JointStateMsg {
            header: Header::from_stamp_ns(stamp_ns, ""),
            name: names.to_vec(),
            position: positions.to_vec(),
            velocity: Vec::new(),
            effort: efforts.to_vec(),
        };
        let id = self.ros_channel(topic, schema::JOINT_STATE)?;
        self.write(id, stamp_u64(stamp_ns), &msg.encode())
    }

    /// Writes a `sensor_msgs/msg/CameraInfo`.
    pub fn write_camera_info(
        &mut self,
        topic: &str,
        msg: &ros::CameraInfoMsg,
    ) -> Result<(), EpisodeError> {
        let id = self.ros_channel(topic, schema::CAMERA_INFO)?;
        let stamp = msg.header.stamp_ns();
        self.write(id, stamp_u64(stamp), &msg.encode())
    }

    /// Writes a `std_msgs/msg/Float64`.
    pub fn write_f64(
        &mut self,
        topic: &str,
        stamp_ns: i64,
        value: f64,
    ) -> Result<(), EpisodeError> {
        let id = self.ros_channel(topic, schema::FLOAT64)?;
        self.write(id, stamp_u64(stamp_ns), &ros::encode_f64(value))
    }

    /// Writes a `std_msgs/msg/Bool`.
    pub fn write_bool(
        &mut self,
        topic: &str,
        stamp_ns: i64,
        value: bool,
    ) -> Result<(), EpisodeError> {
        let id = self.ros_channel(topic, schema::BOOL)?;
        self.write(id, stamp_u64(stamp_ns), &ros::encode_bool(value))
    }

    /// Writes a `std_msgs/msg/String`.
    pub fn write_string(
        &mut self,
        topic: &str,
        stamp_ns: i64,
        value: &str,
    ) -> Result<(), EpisodeError> {
        let id = self.ros_channel(topic, schema::STRING)?;
        self.write(id, stamp_u64(stamp_ns), &ros::encode_string(value))
    }

    /// Writes a heatmap as an `rgb8` `sensor_msgs/msg/Image`.
    pub fn write_heatmap(
        &mut self,
        topic: &str,
        stamp_ns: i64,
        width: u32,
        height: u32,
        rgb8: &[u8],
    ) -> Result<(), EpisodeError> {
        self.write_image(
            topic,
            stamp_ns,
            ImageData::Raw {
                width,
                height,
                encoding: "rgb8",
                data: rgb8,
            },
        )
    }

    /// Copies any message with its schema (e.g. an input topic vamos does not decode).
    /// The channel's message encoding is `cdr` for `ros2msg` schemas, else taken from
    /// `schema_encoding`'s usual pairing (`jsonschema` -> `json`, `protobuf` -> `protobuf`).
    pub fn copy_message(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema_data: &[u8],
        message: &[u8],
        log_time_ns: u64,
    ) -> Result<(), EpisodeError> {
        let message_encoding = match schema_encoding {
            "jsonschema" => "json",
            "protobuf" => "protobuf",
            "flatbuffer" => "flatbuffer",
            _ => "cdr",
        };
        let id = self.channel(
            topic,
            schema_name,
            schema_encoding,
            schema_data,
            message_encoding,
        )?;
        self.write(id, log_time_ns, message)
    }

    /// A scored frame: a copy of its image message on its own topic, then the score
    /// topics at its stamp.
    pub fn write_scored_frame(
        &mut self,
        frame: &super::bag::EpisodeFrame,
        s: &ScoreTopics<'_>,
    ) -> Result<(), EpisodeError> {
        let t = frame.stamp_ns;
        self.write_image(&frame.source.topic, t, ImageData::Source(&frame.source))?;
        self.write_f64("/vamos/score", t, s.score)?;
        self.write_bool("/vamos/anomaly", t, s.anomaly)?;
        for (detector, v) in s.values.present() {
            self.write_f64(detector.topic(), t, v)?;
        }
        if let Some(map) = s.heatmap {
            let side = (map.len() as f64).sqrt() as usize;
            if side * side == map.len() {
                let rgb = heatmap_rgb(map);
                self.write_heatmap("/vamos/heatmap", t, side as u32, side as u32, &rgb)?;
            }
        }
        if let Some((width, height, data)) = s.anomaly_map {
            self.write_image(
                "/vamos/anomaly_map",
                t,
                ImageData::Raw {
                    width,
                    height,
                    encoding: "mono8",
                    data,
                },
            )?;
        }
        if let Some(json) = s.thresholds_json {
            self.write_string("/vamos/thresholds", t, json)?;
        }
        Ok(())
    }

    /// Copies the input episode's camera info, joint states and robot description (the
    /// chosen topics, as recorded) into the bag, so that it replays the whole context of
    /// its scores. Messages of other schemas on those topics are left out.
    pub fn copy_context(&mut self, episode: &super::McapEpisode) -> Result<(), EpisodeError> {
        let chosen = &episode.info().chosen;
        let topics: Vec<String> = [
            &chosen.camera_info,
            &chosen.joint_states,
            &chosen.robot_description,
        ]
        .into_iter()
        .flatten()
        .cloned()
        .collect();
        if topics.is_empty() {
            return Ok(());
        }
        let mut first_error = None;
        episode.for_each_message(&topics, |topic, schema_name, log_time, cdr| {
            if first_error.is_some() || ros::definition(schema_name).is_none() {
                return;
            }
            let written = self
                .ros_channel(topic, schema_name)
                .and_then(|id| self.write(id, log_time, cdr));
            if let Err(e) = written {
                first_error = Some(e);
            }
        })?;
        first_error.map_or(Ok(()), Err)
    }

    /// Completes the file (summary, indexes, footer).
    pub fn finish(mut self) -> Result<(), EpisodeError> {
        self.writer.finish().map_err(|e| self.err(e))?;
        Ok(())
    }
}
