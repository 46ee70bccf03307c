//! A recorded episode as a robot would stream it: the bag's images (with the depth image
//! nearest each, when the episode configuration names a depth topic) and joint states as
//! `vamos.v1` stream messages in log-time order, with their offsets, and its first camera
//! info (for the open message). Used by `vamos loadgen`, `vamos stream` and the service
//! tests.

use std::path::Path;
use std::time::Duration;
use vamos_core::episode::image::Encoding;
use vamos_core::episode::ros::{CameraInfoMsg, CompressedImageMsg, ImageMsg, JointStateMsg};
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

impl Recording {
    /// The recorded image rate, Hz (images over the time from the first to the last);
    /// `None` with fewer than two images.
    pub fn image_rate_hz(&self) -> Option<f64> {
        let mut images = self
            .messages
            .iter()
            .filter(|(_, m)| matches!(m, Message::Image(_)))
            .map(|(t, _)| *t);
        let first = images.next()?;
        let (n, last) = images.fold((1usize, first), |(n, _), t| (n + 1, t));
        let span = last.saturating_sub(first).as_secs_f64();
        (n > 1 && span > 0.0).then(|| (n - 1) as f64 / span)
    }
}

/// Reads the bag at `path`.
pub fn record(path: &Path, config: &EpisodeConfig) -> Result<Recording, ReplayError> {
    let ep = McapEpisode::open(path, config)?;
    let chosen = ep.info().chosen;
    let topics: Vec<String> = [Some(chosen.image.clone()), chosen.depth.clone()]
        .into_iter()
        .chain([chosen.camera_info.clone(), chosen.joint_states.clone()])
        .flatten()
        .collect();
    let mut messages = Vec::new();
    let mut depths: Vec<(i64, proto::DepthImage)> = Vec::new();
    let mut camera = None;
    let mut first: Option<u64> = None;
    let mut error = None;
    ep.for_each_message(&topics, |topic, schema, log_time, cdr| {
        let t0 = *first.get_or_insert(log_time);
        let at = Duration::from_nanos(log_time.saturating_sub(t0));
        let decoded = match schema {
            _ if chosen.depth.as_deref() == Some(topic) => ImageMsg::decode(cdr).map(|m| {
                depths.push((
                    m.header.stamp_ns(),
                    proto::DepthImage {
                        encoding: m.encoding.clone(),
                        width: m.width,
                        height: m.height,
                        step: m.step,
                        big_endian: m.is_bigendian,
                        data: m.data.to_vec(),
                    },
                ));
                None
            }),
            "sensor_msgs/msg/Image" => ImageMsg::decode(cdr).map(|m| {
                Some(Message::Image(proto::Image {
                    stamp_ns: m.header.stamp_ns(),
                    encoding: m.encoding.clone(),
                    width: m.width,
                    height: m.height,
                    step: m.step,
                    big_endian: m.is_bigendian,
                    data: m.data.to_vec(),
                    depth: None,
                }))
            }),
            "sensor_msgs/msg/CompressedImage" => CompressedImageMsg::decode(cdr).map(|m| {
                Some(Message::Image(proto::Image {
                    stamp_ns: m.header.stamp_ns(),
                    // The file format ("rgb8; jpeg compressed bgr8" is a JPEG file).
                    encoding: match Encoding::from_compressed_format(&m.format) {
                        Some(Encoding::Png) => "png".into(),
                        Some(_) => "jpeg".into(),
                        None => m.format.clone(),
                    },
                    data: m.data.to_vec(),
                    ..Default::default()
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
    if let Some(e) = error {
        return Err(e);
    }
    attach_depths(&mut messages, depths, config.max_depth_gap_ms);
    Ok(Recording { messages, camera })
}

/// Gives each image the depth image nearest its stamp, if one is at most `max_gap_ms`
/// away (each depth image serves at most one image).
fn attach_depths(
    messages: &mut [(Duration, Message)],
    mut depths: Vec<(i64, proto::DepthImage)>,
    max_gap_ms: f64,
) {
    if depths.is_empty() {
        return;
    }
    depths.sort_by_key(|(t, _)| *t);
    let mut depths: Vec<(i64, Option<proto::DepthImage>)> =
        depths.into_iter().map(|(t, d)| (t, Some(d))).collect();
    let max_gap_ns = max_gap_ms * 1e6;
    for (_, m) in messages.iter_mut() {
        let Message::Image(image) = m else {
            continue;
        };
        let at = depths.partition_point(|(t, _)| *t < image.stamp_ns);
        let gap = |i: usize| (depths[i].0.saturating_sub(image.stamp_ns)).unsigned_abs() as f64;
        let nearest = [at.checked_sub(1), (at < depths.len()).then_some(at)]
            .into_iter()
            .flatten()
            .filter(|&i| depths[i].1.is_some() && gap(i) <= max_gap_ns)
            .min_by(|&a, &b| gap(a).total_cmp(&gap(b)));
        if let Some(i) = nearest {
            image.depth = depths[i].1.take();
        }
    }
}
