//! Scoring recorded episodes (ROS 2 bags in MCAP): the same [`Scorer`] the service runs,
//! fed from [`McapEpisode::frames`].
//!
//! Bad input does not end an episode: an image whose size changed, a frame the scorer
//! refuses (NaN joints, a stamp going backwards) is recorded in
//! [`EpisodeScores::frame_errors`] and the next frame goes on; a damaged file yields every
//! valid frame before the damage and records where it broke ([`EpisodeScores::damage`]).
//! Only an episode that cannot be opened at all is an error.

use super::scorer::{FrameInput, FrameScore, JointInput, Scorer};
use crate::episode::{EpisodeError, EpisodeFrame, EpisodeInfo, Labels, McapEpisode};
use serde::Serialize;
use vamos_robot::Intrinsics;

/// A frame that could not be scored.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FrameError {
    /// Image index on its topic (when known).
    pub index: Option<usize>,
    /// What went wrong.
    pub message: String,
}

/// An image whose joint states were interpolated over a gap: its nearest joint sample is
/// further than `[episode] max_joint_gap_ms`.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct JointGap {
    /// Image index on its topic.
    pub index: usize,
    /// Image stamp, ns.
    pub stamp_ns: i64,
    /// Distance to the nearest joint sample, ms.
    pub gap_ms: f64,
}

/// The scores of one episode.
#[derive(Debug, Clone, Serialize)]
pub struct EpisodeScores {
    /// Episode name (file stem).
    pub name: String,
    /// The scores of the processed frames, in stamp order.
    pub frames: Vec<FrameScore>,
    /// Frames that were refused, with the reason.
    pub frame_errors: Vec<FrameError>,
    /// Where a damaged file broke (the frames before it are scored).
    pub damage: Option<String>,
    /// The episode had no joint states at all: scored from `e_o` only.
    pub no_joint_states: bool,
    /// Images read whose nearest joint sample is beyond `[episode] max_joint_gap_ms`
    /// (every image read, also those the stride skips), in stamp order.
    pub joint_gaps: Vec<JointGap>,
    /// The episode's frame labels, when it has any (sidecar or label topic).
    pub labels: Option<Labels>,
    /// What the file holds.
    #[serde(skip)]
    pub info: Option<EpisodeInfo>,
}

/// Scores every frame of `episode` with `scorer` (reset first). `sink` sees each scored
/// frame with the episode frame it came from (e.g. to write an output bag); an error from
/// it stops the episode.
pub fn score_episode<E>(
    scorer: &mut Scorer,
    episode: &McapEpisode,
    mut sink: impl FnMut(&EpisodeFrame, &FrameScore) -> Result<(), E>,
) -> Result<EpisodeScores, E>
where
    E: From<EpisodeError>,
{
    scorer.reset();
    let info = episode.info();
    let labels = episode.labels()?;
    let no_joint_states = info.joint_messages == 0;
    if no_joint_states {
        tracing::warn!(
            episode = %episode.name(),
            "no joint states in the episode: scored from the flow predictor (e_o) only"
        );
    }
    let mut out = EpisodeScores {
        name: episode.name().to_string(),
        frames: Vec::new(),
        frame_errors: Vec::new(),
        damage: None,
        no_joint_states,
        joint_gaps: Vec::new(),
        labels,
        info: None,
    };
    let mut intrinsics: Option<(u32, u32, [f64; 9], Option<Intrinsics>)> = None;
    for item in episode.frames() {
        let frame = match item {
            Ok(f) => f,
            Err(e @ EpisodeError::Truncated { .. }) => {
                out.damage = Some(e.to_string());
                break;
            }
            Err(e) => {
                out.frame_errors.push(FrameError {
                    index: error_index(&e),
                    message: e.to_string(),
                });
                if is_fatal(&e) {
                    out.damage = Some(e.to_string());
                    break;
                }
                continue;
            }
        };
        for w in &frame.warnings {
            tracing::warn!(episode = %out.name, index = frame.index, "{w}");
        }
        if let Some(j) = frame.joints.as_ref().filter(|j| j.beyond_max_gap) {
            out.joint_gaps.push(JointGap {
                index: frame.index,
                stamp_ns: frame.stamp_ns,
                gap_ms: j.gap_ns as f64 * 1e-6,
            });
        }
        // Camera info -> intrinsics, converted once per distinct message.
        let k = frame.camera_info.as_ref().and_then(|c| {
            let fresh = !matches!(&intrinsics, Some((w, h, k, _)) if *w == c.width && *h == c.height && *k == c.k);
            if fresh {
                let converted = Intrinsics::from_k(c.width, c.height, &c.k).ok();
                if converted.is_none() {
                    tracing::warn!(episode = %out.name, "camera info with an invalid K ignored");
                }
                intrinsics = Some((c.width, c.height, c.k, converted));
            }
            intrinsics.as_ref().and_then(|(_, _, _, i)| *i)
        });
        let joints = frame.joints.as_ref().map(|j| JointInput {
            names: &j.names,
            positions: &j.positions,
            efforts: &j.efforts,
        });
        match scorer.push(&FrameInput {
            stamp_ns: frame.stamp_ns,
            image: &frame.image,
            joints,
            intrinsics: k.as_ref(),
            depth: frame.depth.as_ref(),
        }) {
            Ok(Some(score)) => {
                sink(&frame, &score)?;
                out.frames.push(score);
            }
            Ok(None) => {}
            Err(e) => out.frame_errors.push(FrameError {
                index: Some(frame.index),
                message: e.to_string(),
            }),
        }
    }
    out.info = Some(episode.info());
    Ok(out)
}

fn error_index(e: &EpisodeError) -> Option<usize> {
    match e {
        EpisodeError::ImageSizeChanged { index, .. } => Some(*index),
        EpisodeError::BadMessage { index, .. } | EpisodeError::UnknownEncoding { index, .. } => {
            Some(*index)
        }
        _ => None,
    }
}

/// Errors after which the reader cannot go on.
/// Whether an episode error ends the episode (the file is damaged or unreadable) rather
/// than one frame.
pub fn is_fatal(e: &EpisodeError) -> bool {
    matches!(e, EpisodeError::Truncated { .. })
        || matches!(e, EpisodeError::Io { .. } | EpisodeError::Mcap { .. })
}
