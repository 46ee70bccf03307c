//! `vamos.v1.Monitor`: streaming sessions and episode scoring over gRPC. Each handler
//! checks the caller, converts the messages ([`super::convert`]) and calls the session
//! layer; errors become statuses in [`super::error`].

use super::convert::{frame_score, intrinsics_of, live_image, live_joints, stream_response};
use crate::api::auth::{Caller, Role};
use crate::api::proto::monitor_server::Monitor;
use crate::api::proto::{self, stream_request::Message as In};
use crate::api::state::Shared;
use crate::session::episode::{EpisodeRequest, score_episode};
use crate::session::error::check_label;
use crate::session::upload::EpisodeBuffer;
use crate::session::{Event, EventKind, Hub, OpenRequest, Output, Session, SessionError};
use futures_util::StreamExt;
use std::pin::Pin;
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_stream::Stream;
use tokio_stream::wrappers::ReceiverStream;
use tonic::{Request, Response, Status, Streaming};
use tracing::Instrument;

/// The `Monitor` service.
pub struct MonitorService {
    shared: Arc<Shared>,
}

impl MonitorService {
    /// The service over the server's shared state.
    pub fn new(shared: Arc<Shared>) -> Self {
        Self { shared }
    }

    fn authorize<T>(&self, req: &Request<T>) -> Result<Caller, Status> {
        let header = req
            .metadata()
            .get("authorization")
            .and_then(|v| v.to_str().ok());
        Ok(self.shared.tokens.require_caller(header, Role::Robot)?)
    }
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
                let max_s = hub.config().max_session_s;
                hub.close(&session, Some(SessionError::TooOld { max_s }));
                return;
            }
            Err(_) => {
                let idle_s = hub.config().idle_timeout_s;
                hub.close(&session, Some(SessionError::Idle { idle_s }));
                return;
            }
            Ok(Ok(Some(req))) => match req.message {
                Some(In::Image(img)) => hub.image(&session, live_image(img)),
                Some(In::Joints(j)) => hub.joints(&session, live_joints(j)),
                Some(In::Phase(p)) => hub.phase(&session, p.stamp_ns, p.phase),
                Some(In::Open(_)) => {
                    hub.close(&session, Some(SessionError::SecondOpen));
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
                let detail = status.message().to_string();
                hub.close(&session, Some(SessionError::MessageTooLarge { detail }));
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
        let caller = self.authorize(&request)?;
        let request_id = request
            .extensions()
            .get::<crate::api::observe::RequestId>()
            .map(|r| r.0.clone())
            .unwrap_or_default();
        let mut inbound = request.into_inner();
        let hub = self.shared.hub.clone();
        let idle = Duration::from_secs_f64(hub.config().idle_timeout_s.max(0.001));
        let first = tokio::time::timeout(idle, inbound.message())
            .await
            .map_err(|_| SessionError::NoOpen)??;
        let Some(In::Open(open)) = first.and_then(|m| m.message) else {
            return Err(SessionError::OpenExpected.into());
        };
        let profile = self
            .shared
            .profiles
            .get_async(&open.profile)
            .await
            .map_err(SessionError::from)?;
        // A robot token acts for its robots, and resumes only what it may see.
        if !caller.may_act_for(&open.robot_id) {
            return Err(SessionError::RobotNotAllowed {
                robot_id: open.robot_id,
            }
            .into());
        }
        if let Some(s) = hub.session(open.session_id.trim())
            && !caller.sees(s.opener, &s.robot_id)
        {
            return Err(SessionError::NotYours { id: s.id.clone() }.into());
        }
        let camera = open.camera_info.as_ref().map(intrinsics_of).transpose()?;
        let (tx, rx) = mpsc::channel(1024);
        let (session, resumed) = hub.open(
            profile,
            OpenRequest {
                robot_id: open.robot_id,
                task: open.task,
                opener: caller.robot_token,
                session_id: open.session_id,
                camera,
                episode: false,
                seed_key: None,
                slot: None,
                request_id,
                maps: open.anomaly_maps,
                image_rate_hz: (open.image_rate_hz.is_finite() && open.image_rate_hz > 0.0)
                    .then_some(open.image_rate_hz),
            },
            tx.clone(),
        )?;
        let kind = if resumed {
            EventKind::Resumed
        } else {
            EventKind::Opened
        };
        let detail = format!(
            "session {} profile {} model {}",
            session.id,
            session.profile_name,
            session.profile().model_label
        );
        let _ = tx
            .send(Output::Event(Event {
                kind,
                session_id: session.id.clone(),
                detail,
                stamp_ns: 0,
                count: 0,
            }))
            .await;
        drop(tx);
        // The session's span: its reading task (and, by its fields, the worker's frames).
        let span = tracing::info_span!(
            "session",
            session = %session.id,
            robot = %session.robot_id,
            profile = %session.profile_name,
            request_id = %session.request_id,
        );
        tokio::spawn(
            read_session(hub, session, inbound, self.shared.stop.subscribe()).instrument(span),
        );
        Ok(Response::new(Box::pin(
            ReceiverStream::new(rx).map(stream_response),
        )))
    }

    async fn score_episode(
        &self,
        request: Request<Streaming<proto::EpisodeChunk>>,
    ) -> Result<Response<Self::ScoreEpisodeStream>, Status> {
        let caller = self.authorize(&request)?;
        // Admitted before a byte is buffered: a session place and an upload slot.
        let (slot, ticket) = self.shared.admit_episode(None)?;
        let mut inbound = request.into_inner();
        let limit = self.shared.hub.config().max_episode_bytes;
        let mut buffer = EpisodeBuffer::new(&self.shared.upload_dir(), limit, ticket)?;
        let mut profile_name = None;
        let mut episode_name = String::new();
        while let Some(chunk) = inbound.message().await? {
            if profile_name.is_none() {
                profile_name = Some(chunk.profile.clone());
                episode_name = chunk.name.clone();
                check_label("name", &episode_name)?;
            }
            buffer.write(&chunk.data)?;
        }
        let name = profile_name.ok_or(SessionError::NoChunk)?;
        let profile = self
            .shared
            .profiles
            .get_async(&name)
            .await
            .map_err(SessionError::from)?;
        // A `.mcap.zstd` upload is decompressed in the upload folder, charged as written.
        let buffer = buffer
            .decompressed(profile.setup.episode.max_decompressed_bytes)
            .await?;
        let (file, ticket) = buffer.into_parts();
        let scores = score_episode(
            self.shared.hub.clone(),
            profile,
            file,
            EpisodeRequest {
                name: episode_name,
                slot,
                ticket: Some(ticket),
                maps: false,
                opener: caller.robot_token,
            },
        )
        .await?;
        let mapped = scores
            .into_stream()
            .map(|item| item.map(|f| frame_score(&f)).map_err(Status::from));
        Ok(Response::new(Box::pin(mapped)))
    }
}
