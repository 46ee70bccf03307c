//! `vamos.v1.Monitor`: streaming sessions and episode scoring over gRPC.

use super::auth::{AuthError, Role};
use super::budget::UploadTicket;
use super::hub::{Hub, ImagePayload, OpenRequest, ReadyFrame, Session, SessionSlot};
use super::proto::monitor_server::Monitor;
use super::proto::{self, stream_request::Message as In};
use super::{ServiceError, Shared};
use crate::episode::McapEpisode;
use crate::pipeline::offline::{FrameError, is_fatal};
use crate::robot::Intrinsics;
use std::io::Write;
use std::pin::Pin;
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::mpsc;
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};

impl From<AuthError> for Status {
    fn from(e: AuthError) -> Self {
        match e {
            AuthError::Forbidden { .. } => Status::permission_denied(e.to_string()),
            _ => Status::unauthenticated(e.to_string()),
        }
    }
}

/// The `Monitor` service.
pub struct MonitorService {
    shared: Arc<Shared>,
}

impl MonitorService {
    /// The service over the server's shared state.
    pub fn new(shared: Arc<Shared>) -> Self {
        Self { shared }
    }

    fn authorize<T>(&self, req: &Request<T>) -> Result<Role, Status> {
        let header = req
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok());
        Ok(self.shared.tokens.require(header, Role::Robot)?)
    }
}

pub(crate) fn intrinsics_of(c: &proto::CameraInfo) -> Result<Intrinsics, Status> {
    Intrinsics::new(c.width, c.height, c.fx, c.fy, c.cx, c.cy)
        .map_err(|e| Status::invalid_argument(format!("camera_info: {e}")))
}

type BoxStream<T> = Pin<Box<dyn Stream<Item = Result<T, Status>> + Send + 'static>>;

/// Reads one session's requests until the stream ends, breaks, idles out or the server
/// stops.
async fn read_session(
    hub: Arc<Hub>,
    session: Arc<Session>,
    mut inbound: Streaming<proto::StreamRequest>,
    mut stop: tokio::sync::watch::Receiver<bool>,
) {
    let idle = Duration::from_secs_f64(hub.config().idle_timeout_s.max(0.001));
    let max_age = Duration::from_secs_f64(hub.config().max_session_s.max(0.0));
    loop {
        let remaining = max_age.saturating_sub(session.age());
        let wait = idle.min(remaining);
        let next = tokio::select! {
            r = tokio::time::timeout(wait, inbound.message()) => r,
            _ = stop.changed() => {
                // The server is stopping: score what came, then `Hub::shutdown` closes.
                hub.finish(&session);
                return;
            }
        };
        match next {
            Err(_) if session.age() >= max_age => {
                hub.close(
                    &session,
                    Some(Status::deadline_exceeded(format!(
                        "session exceeded the maximum length of {} s",
                        hub.config().max_session_s
                    ))),
                );
                return;
            }
            Err(_) => {
                hub.close(
                    &session,
                    Some(Status::deadline_exceeded(format!(
                        "no message for {} s: session closed",
                        hub.config().idle_timeout_s
                    ))),
                );
                return;
            }
            Ok(Ok(Some(req))) => match req.message {
                Some(In::Image(img)) => hub.image(&session, img),
                Some(In::Joints(j)) => hub.joints(&session, j),
                Some(In::Phase(p)) => hub.phase(&session, p),
                Some(In::Open(_)) => {
                    hub.close(
                        &session,
                        Some(Status::invalid_argument(
                            "a second open message in one stream",
                        )),
                    );
                    return;
                }
                None => {}
            },
            Ok(Ok(None)) => {
                hub.finish(&session);
                return;
            }
            Ok(Err(status)) if status.code() == tonic::Code::OutOfRange => {
                // A message over `max_message_bytes` (refused before it was decoded): the
                // client's doing, not a broken link, so the session ends and says why.
                tracing::info!(session = %session.id, "message refused: {}", status.message());
                hub.close(
                    &session,
                    Some(Status::out_of_range(format!(
                        "message refused (service.max_message_bytes): {}",
                        status.message()
                    ))),
                );
                return;
            }
            Ok(Err(status)) => {
                tracing::info!(session = %session.id, "stream broke: {}", status.message());
                hub.detach(&session);
                return;
            }
        }
    }
}

#[tonic::async_trait]
impl Monitor for MonitorService {
    type StreamStream = BoxStream<proto::StreamResponse>;
    type ScoreEpisodeStream = BoxStream<proto::FrameScore>;

    async fn stream(
        &self,
        request: Request<Streaming<proto::StreamRequest>>,
    ) -> Result<Response<Self::StreamStream>, Status> {
        self.authorize(&request)?;
        let mut inbound = request.into_inner();
        let hub = self.shared.hub.clone();
        let idle = Duration::from_secs_f64(hub.config().idle_timeout_s.max(0.001));
        let first = tokio::time::timeout(idle, inbound.message())
            .await
            .map_err(|_| Status::deadline_exceeded("no open message"))??;
        let open = match first.and_then(|m| m.message) {
            Some(In::Open(o)) => o,
            _ => {
                return Err(Status::invalid_argument(
                    "the first message of a stream must be `open`",
                ));
            }
        };
        let profile = self
            .shared
            .profiles
            .get_async(&open.profile)
            .await
            .map_err(ServiceError::from)?;
        let camera = open.camera_info.as_ref().map(intrinsics_of).transpose()?;
        let (tx, rx) = mpsc::channel(1024);
        let (session, resumed) = hub.open(
            profile,
            OpenRequest {
                robot_id: open.robot_id,
                task: open.task,
                session_id: open.session_id,
                camera,
                episode: false,
                seed_key: None,
                slot: None,
            },
            tx.clone(),
        )?;
        let kind = if resumed {
            proto::session_event::Kind::Resumed
        } else {
            proto::session_event::Kind::Opened
        };
        let detail = format!(
            "session {} profile {} model {}",
            session.id,
            session.profile_name,
            session.profile().model_label
        );
        let _ = tx
            .send(Ok(proto::StreamResponse {
                message: Some(proto::stream_response::Message::Event(
                    proto::SessionEvent {
                        kind: kind as i32,
                        session_id: session.id.clone(),
                        detail,
                        stamp_ns: 0,
                        count: 0,
                    },
                )),
            }))
            .await;
        drop(tx);
        tokio::spawn(read_session(
            hub,
            session,
            inbound,
            self.shared.stop.subscribe(),
        ));
        Ok(Response::new(Box::pin(ReceiverStream::new(rx))))
    }

    async fn score_episode(
        &self,
        request: Request<Streaming<proto::EpisodeChunk>>,
    ) -> Result<Response<Self::ScoreEpisodeStream>, Status> {
        self.authorize(&request)?;
        // Admitted before a byte is buffered: a session place and an upload slot.
        let (slot, mut ticket) = self.shared.admit_episode(None)?;
        let mut inbound = request.into_inner();
        let limit = self.shared.hub.config().max_episode_bytes;
        let mut file = tempfile::Builder::new()
            .prefix("episode-")
            .suffix(".mcap")
            .tempfile_in(self.shared.upload_dir())
            .map_err(|e| Status::internal(format!("cannot buffer the episode: {e}")))?;
        let mut profile_name = None;
        let mut episode_name = String::new();
        let mut size = 0u64;
        while let Some(chunk) = inbound.message().await? {
            if profile_name.is_none() {
                profile_name = Some(chunk.profile.clone());
                episode_name = chunk.name.clone();
            }
            size += chunk.data.len() as u64;
            if size > limit {
                return Err(Status::resource_exhausted(format!(
                    "episode larger than the limit of {limit} bytes"
                )));
            }
            ticket
                .written(size)
                .map_err(|e| Status::resource_exhausted(e.to_string()))?;
            file.write_all(&chunk.data)
                .map_err(|e| Status::internal(format!("cannot buffer the episode: {e}")))?;
        }
        let name = profile_name.ok_or_else(|| Status::invalid_argument("no chunk received"))?;
        let profile = self
            .shared
            .profiles
            .get_async(&name)
            .await
            .map_err(ServiceError::from)?;
        let stream = score_episode_file(
            self.shared.hub.clone(),
            profile,
            file,
            episode_name,
            slot,
            Some(ticket),
        )
        .await?;
        Ok(Response::new(stream))
    }
}

/// Scores a buffered episode through the worker pool, in the session place `slot`
/// reserved before it was read; the scores stream back in order, then DATA_LOSS if the
/// file was damaged part-way. `ticket` (the upload's slot and disk) is given back when
/// the file is removed.
pub async fn score_episode_file(
    hub: Arc<Hub>,
    profile: Arc<super::profiles::LoadedProfile>,
    file: tempfile::NamedTempFile,
    seed_key: String,
    slot: SessionSlot,
    ticket: Option<UploadTicket>,
) -> Result<BoxStream<proto::FrameScore>, Status> {
    let config = profile.setup.episode.clone();
    let path = file.path().to_path_buf();
    let episode = tokio::task::spawn_blocking(move || McapEpisode::open(&path, &config))
        .await
        .map_err(|e| Status::internal(e.to_string()))?
        .map_err(|e| Status::invalid_argument(format!("not a readable episode: {e}")))?;
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
                    let bytes = (4 * frame.image.data().len() as u64).min(hub.budget().limit());
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
                        image: ImagePayload::Decoded(frame.image, k),
                        joints: frame.joints.map(|j| (j.names, j.positions)),
                        arrived: Instant::now(),
                        charge: Some(charge),
                    };
                    if !hub.push_blocking(&session, ready) {
                        return;
                    }
                }
                Err(e) => {
                    if is_fatal(&e) {
                        damage = Some(e.to_string());
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
        if let Some(d) = damage {
            // The scores of the frames before the damage go out first.
            hub.wait_closed(&session);
            let _ = tx.blocking_send(Err(Status::data_loss(format!(
                "the episode is damaged; frames before the damage were scored: {d}"
            ))));
        }
    });
    let scores = ReceiverStream::new(rx);
    let mapped = tokio_stream::StreamExt::filter_map(scores, |item| match item {
        Ok(proto::StreamResponse {
            message: Some(proto::stream_response::Message::Score(s)),
        }) => Some(Ok(s)),
        Ok(_) => None,
        Err(status) => Some(Err(status)),
    });
    Ok(Box::pin(mapped))
}
