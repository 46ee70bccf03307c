//! The one episode-scoring operation, called by `Monitor.ScoreEpisode` (gRPC) and
//! `POST /v1/episodes:score` (REST): an uploaded bag read frame by frame into a session
//! of its own, scored by the worker pool like live frames, the scores coming back in
//! order as core [`FrameScore`](vamos_core::pipeline::FrameScore)s, then the damage (a
//! [`SessionError::Damaged`]) if the file broke part-way.

use super::budget::{DECODE_WAIT, DecodeRoom, UploadTicket};
use super::error::SessionError;
use super::event::{EventKind, Output, ScoredFrame};
use super::hub::Hub;
use super::profiles::LoadedProfile;
use super::state::{FrameJoints, ImagePayload, OpenRequest, ReadyFrame, SessionSlot};
use futures_util::Stream;
use std::sync::Arc;
use std::time::Instant;
use tokio::sync::mpsc;
use vamos_core::episode::McapEpisode;
use vamos_core::pipeline::offline::is_fatal;
use vamos_robot::Intrinsics;

/// The scores of an episode as they come: frames in order, then at most one error (the
/// damage, or the session closed by the server).
pub struct EpisodeScores {
    rx: mpsc::Receiver<Output>,
    refused: Vec<String>,
}

impl EpisodeScores {
    /// The next score, or the error that ended the scoring; `None` at the end.
    pub async fn next(&mut self) -> Option<Result<ScoredFrame, SessionError>> {
        loop {
            match self.rx.recv().await? {
                Output::Score(s) => return Some(Ok(s)),
                Output::Event(e) if e.kind == EventKind::MessageError => {
                    self.refused.push(e.detail);
                }
                Output::Event(_) | Output::Alarm(_) => continue,
                Output::Closed(e) => return Some(Err(e)),
            }
        }
    }

    /// Every score, the frames refused (why, in order), and the error that ended the
    /// scoring early, if any.
    pub async fn collect(mut self) -> (Vec<ScoredFrame>, Vec<String>, Option<SessionError>) {
        let mut frames = Vec::new();
        let mut end = None;
        while let Some(item) = self.next().await {
            match item {
                Ok(f) => frames.push(f),
                Err(e) => {
                    end = Some(e);
                    break;
                }
            }
        }
        (frames, self.refused, end)
    }

    /// The scores as a stream.
    pub fn into_stream(self) -> impl Stream<Item = Result<ScoredFrame, SessionError>> + Send {
        futures_util::stream::unfold(
            self,
            |mut s| async move { s.next().await.map(|item| (item, s)) },
        )
    }
}

/// An episode to score, besides its file and profile.
pub struct EpisodeRequest {
    /// Its name: seeds the predictor's sampling (as `vamos score` does) and names it in
    /// logs.
    pub name: String,
    /// The session place reserved before the upload was read.
    pub slot: SessionSlot,
    /// The upload's slot and disk, given back when the file is removed.
    pub ticket: Option<UploadTicket>,
    /// Each score carries its anomaly map.
    pub maps: bool,
    /// The robot token that sent it ([`super::Session::opener`]).
    pub opener: Option<usize>,
}

/// Scores the buffered episode `file` with `profile` through the worker pool, in the
/// session place its request reserved.
pub async fn score_episode(
    hub: Arc<Hub>,
    profile: Arc<LoadedProfile>,
    file: tempfile::NamedTempFile,
    req: EpisodeRequest,
) -> Result<EpisodeScores, SessionError> {
    let EpisodeRequest {
        name: seed_key,
        slot,
        ticket,
        maps,
        opener,
    } = req;
    let config = profile.setup.episode.clone();
    let path = file.path().to_path_buf();
    let episode = tokio::task::spawn_blocking(move || McapEpisode::open(&path, &config))
        .await
        .map_err(|e| SessionError::Internal(e.to_string()))?
        .map_err(|source| SessionError::not_an_episode(&source, file.path()))?;
    // Every image is decoded within the server's memory budget, its peak charged first.
    let episode = episode.with_decode_budget(DecodeRoom::new(hub.budget().clone(), DECODE_WAIT));
    let (tx, rx) = mpsc::channel(1024);
    let (session, _) = hub.open(
        profile,
        OpenRequest {
            robot_id: String::new(),
            task: String::new(),
            opener,
            session_id: String::new(),
            camera: None,
            episode: true,
            seed_key: Some(seed_key),
            slot: Some(slot),
            request_id: String::new(),
            maps,
            image_rate_hz: None,
        },
        tx.clone(),
    )?;
    tokio::task::spawn_blocking(move || {
        let _file = file;
        let _ticket = ticket;
        let mut damage = None;
        for item in episode.frames() {
            match item {
                Ok(frame) => {
                    let k = frame
                        .camera_info
                        .as_ref()
                        .and_then(|c| Intrinsics::from_k(c.width, c.height, &c.k).ok());
                    let ready = ReadyFrame {
                        stamp_ns: frame.stamp_ns,
                        image: ImagePayload::Decoded(frame.image, k, frame.depth),
                        joints: frame.joints.map(|j| FrameJoints {
                            names: j.names,
                            positions: j.positions,
                            efforts: j.efforts,
                        }),
                        arrived: Instant::now(),
                        held: frame.reserved,
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
                    // Reported in order with the scores (a MESSAGE_ERROR event), and
                    // counted as dropped.
                    tracing::warn!(session = %session.id, "episode frame refused: {e}");
                    hub.refuse(&session, "frame", format!("frame refused: {e}"), 0);
                }
            }
        }
        hub.finish(&session);
        if let Some(source) = damage {
            // The scores of the frames before the damage go out first.
            hub.wait_closed(&session);
            let _ = tx.blocking_send(Output::Closed(SessionError::Damaged { source }));
        }
    });
    Ok(EpisodeScores {
        rx,
        refused: Vec::new(),
    })
}
