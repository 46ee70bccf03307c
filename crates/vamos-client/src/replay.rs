//! A recorded episode as a robot would stream it: the bag's images and joint states as
//! `vamos.v1` stream messages in log-time order, with their offsets, and its first camera
//! info (for the open message). Used by `vamos loadgen` and the service tests.

use std::path::Path;
use std::time::Duration;
use vamos_core::episode::ros::{CameraInfoMsg, ImageMsg, JointStateMsg};
use vamos_core::episode::{EpisodeConfig, EpisodeError, McapEpisode};
use vamos_proto as proto;
use vamos_proto::stream_request::Message;

/// Why a bag cannot be replayed.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The bag does not read.
    #[error(transparent)]
    Episode(#[from] EpisodeError),
    /// A message does not decode.
    #[error("{path}: {schema} message: {reason}")]
    Message {
        /// The bag.
        path: String,
        /// The message's schema.
        schema: String,
        /// Why.
        reason: String,
    },
}

/// An episode ready to stream.
pub struct Recording {
    /// Images and joint states, with their offsets from the first message.
    pub messages: Vec<(Duration, Message)>,
    /// The first camera info, if the bag has one.
    pub camera: Option<proto::CameraInfo>,
}

/// Reads the bag at `path`.
pub fn record(path: &Path, config: &EpisodeConfig) -> Result<Recording, ReplayError> {
    let ep = McapEpisode::open(path, config)?;
    let topics: Vec<String> = ep.info().topics.iter().map(|t| t.name.clone()).collect();
    let mut messages = Vec::new();
    let mut camera = None;
    let mut first: Option<u64> = None;
    let mut error = None;
    ep.for_each_message(&topics, |_topic, schema, log_time, cdr| {
        let t0 = *first.get_or_insert(log_time);
        let at = Duration::from_nanos(log_time.saturating_sub(t0));
        let decoded = match schema {
            "sensor_msgs/msg/Image" => ImageMsg::decode(cdr).map(|m| {
                Some(Message::Image(proto::Image {
                    stamp_ns: m.header.stamp_ns(),
                    encoding: m.encoding.clone(),
                    width: m.width,
                    height: m.height,
                    step: m.step,
                    big_endian: m.is_bigendian,
                    data: m.data.to_vec(),
                }))
            }),
            "sensor_msgs/msg/JointState" => JointStateMsg::decode(cdr).map(|m| {
                Some(Message::Joints(proto::JointState {
                    stamp_ns: m.header.stamp_ns(),
                    names: m.name,
                    positions: m.position,
                    velocities: m.velocity,
                    efforts: m.effort,
                }))
            }),
            "sensor_msgs/msg/CameraInfo" if camera.is_none() => {
                CameraInfoMsg::decode(cdr).map(|c| {
                    camera = Some(proto::CameraInfo {
                        width: c.width,
                        height: c.height,
                        fx: c.k[0],
                        fy: c.k[4],
                        cx: c.k[2],
                        cy: c.k[5],
                    });
                    None
                })
            }
            _ => Ok(None),
        };
        match decoded {
            Ok(Some(m)) => messages.push((at, m)),
            Ok(None) => {}
            Err(e) => {
                error.get_or_insert(ReplayError::Message {
                    path: path.display().to_string(),
                    schema: schema.to_string(),
                    reason: e.to_string(),
                });
            }
        }
    })?;
    match error {
        Some(e) => Err(e),
        None => Ok(Recording { messages, camera }),
    }
}
