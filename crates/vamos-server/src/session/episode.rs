//! The one episode-scoring operation, called by `Monitor.ScoreEpisode` (gRPC) and
//! `POST /v1/episodes:score` (REST): an uploaded bag read frame by frame into a session
//! of its own, scored by the worker pool like live frames, the scores coming back in
//! order as core [`FrameScore`](vamos_core::pipeline::FrameScore)s, then the damage (a
//! [`SessionError::Damaged`]) if the file broke part-way.

use super::budget::UploadTicket;
use super::error::SessionError;
use super::event::{Output, ScoredFrame};
use super::hub::Hub;
use super::profiles::LoadedProfile;
use super::state::{FrameJoints, ImagePayload, OpenRequest, ReadyFrame, SessionSlot};
use futures_util::Stream;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use vamos_core::episode::McapEpisode;
use vamos_core::pipeline::offline::{FrameError, is_fatal};
use vamos_robot::Intrinsics;

/// The scores of an episode as they come: frames in order, then at most one error (the
/// damage, or the session closed by the server).
pub struct EpisodeScores {
    rx: mpsc::Receiver<Output>,
}

impl EpisodeScores {
    /// The next score, or the error that ended the scoring; `None` at the end.
    pub async fn next(&mut self) -> Option<Result<ScoredFrame, SessionError>> {
        loop {
            match self.rx.recv().await? {
                Output::Score(s) => return Some(Ok(s)),
                Output::Event(_) | Output::Alarm(_) => continue,
                Output::Closed(e) => return Some(Err(e)),
            }
        }
    }

    /// Every score, and the error that ended the scoring early, if any.
    pub async fn collect(mut self) -> (Vec<ScoredFrame>, Option<SessionError>) {
        let mut frames = Vec::new();
        while let Some(item) = self.next().await {
            match item {
                Ok(f) => frames.push(f),
                Err(e) => return (frames, Some(e)),
            }
        }
        (frames, None)
    }

    /// The scores as a stream.
    pub fn into_stream(self) -> impl Stream<Item = Result<ScoredFrame, SessionError>> + Send {
        futures_util::stream::unfold(
            self,
            |mut s| async move { s.next().await.map(|item| (item, s)) },
        )
    }
}

/// Scores the buffered episode `file` with `profile` through the worker pool, in the
/// session place `slot` reserved before it was read. `seed_key` seeds the predictor's
/// sampling (the episode's name, as `vamos score` does). `ticket` (the upload's slot and
/// disk) is given back when the file is removed. With `maps`, each score carries its
/// anomaly map.
pub async fn score_episode(
    hub: Arc<Hub>,
    profile: Arc<LoadedProfile>,
    file: tempfile::NamedTempFile,
    seed_key: String,
    slot: SessionSlot,
    ticket: Option<UploadTicket>,
    maps: bool,
) -> Result<EpisodeScores, SessionError> {
    let config = profile.setup.episode.clone();
    let path = file.path().to_path_buf();
    let episode = tokio::task::spawn_blocking(move || McapEpisode::open(&path, &config))
        .await
        .map_err(|e| SessionError::Internal(e.to_string()))?
        .map_err(|source| SessionError::NotAnEpisode { source })?;
    let (tx, rx) = mpsc::channel(1024);
    let (session, _) = hub.open(
        profile,
        OpenRequest {
            robot_id: String::new(),
            task: String::new(),
            session_id: String::new(),
            camera: None,
            episode: true,
            seed_key: Some(seed_key),
            slot: Some(slot),
            request_id: String::new(),
            maps,
        },
        tx.clone(),
    )?;
    tokio::task::spawn_blocking(move || {
        let _file = file;
        let _ticket = ticket;
        let mut errors: Vec<FrameError> = Vec::new();
        let mut damage = None;
        for item in episode.frames() {
            match item {
                Ok(frame) => {
                    let k = frame
                        .camera_info
                        .as_ref()
                        .and_then(|c| Intrinsics::from_k(c.width, c.height, &c.k).ok());
                    // Decoded frames wait for room in the memory budget: the session's
                    // queue, and others', drain as they are scored.
                    // (A frame larger than the whole budget takes all of it.)
                    let values = frame.image.data().len()
                        + frame.depth.as_ref().map_or(0, |d| d.metres().len());
                    let bytes = (4 * values as u64).min(hub.budget().limit());
                    let charge = loop {
                        match hub.budget().charge(bytes) {
                            Ok(c) => break c,
                            Err(_) if !hub.is_closed(&session) => {
                                std::thread::sleep(Duration::from_millis(20));
                            }
                            Err(_) => return,
                        }
                    };
                    let ready = ReadyFrame {
                        stamp_ns: frame.stamp_ns,
                        image: ImagePayload::Decoded(frame.image, k, frame.depth),
                        joints: frame.joints.map(|j| FrameJoints {
                            names: j.names,
                            positions: j.positions,
                            efforts: j.efforts,
                        }),
                        arrived: Instant::now(),
                        charge: Some(charge),
                    };
                    if !hub.push_blocking(&session, ready) {
                        return;
                    }
                }
                Err(e) => {
                    if is_fatal(&e) {
                        damage = Some(e);
                        break;
                    }
                    errors.push(FrameError {
                        index: None,
                        message: e.to_string(),
                    });
                }
            }
        }
        for e in &errors {
            tracing::warn!(session = %session.id, "episode frame refused: {}", e.message);
        }
        hub.finish(&session);
        if let Some(source) = damage {
            // The scores of the frames before the damage go out first.
            hub.wait_closed(&session);
            let _ = tx.blocking_send(Output::Closed(SessionError::Damaged { source }));
        }
    });
    Ok(EpisodeScores { rx })
}
