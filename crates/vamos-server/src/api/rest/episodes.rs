//! `POST /v1/episodes:score`: an uploaded episode scored by the session layer's episode
//! operation ([`crate::session::episode`], the one gRPC's `ScoreEpisode` calls); the
//! scores as JSON, or the scored bag.

use super::body::{ApiQuery, content_length, file_body};
use super::errors::ApiError;
use crate::api::auth::Caller;
use crate::api::grpc::convert::frame_score_fields;
use crate::api::state::Shared;
use crate::session::budget::{DECODE_WAIT, DecodeRoom};
use crate::session::episode::{EpisodeRequest, score_episode as score};
use crate::session::error::check_label;
use crate::session::upload::EpisodeBuffer;
use crate::session::{ScoredFrame, SessionError};
use axum::Json;
use axum::body::Body;
use axum::extract::{Extension, State};
use axum::http::{HeaderMap, header};
use axum::response::{IntoResponse, Response};
use futures_util::StreamExt;
use serde_json::json;
use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;
use vamos_core::episode::{EpisodeConfig, McapEpisode, ScoreBagWriter, ScoreTopics};
use vamos_core::eval::DetectorThresholds;
use vamos_proto::ScoreJson;

/// Query of `POST /v1/episodes:score`.
#[derive(Debug, serde::Deserialize, schemars::JsonSchema)]
pub struct ScoreQuery {
    /// The profile to score with.
    profile: String,
    /// The episode's name in logs, metrics and alarms (default: none).
    #[serde(default)]
    name: Option<String>,
}

/// The JSON answer of `POST /v1/episodes:score`.
#[derive(Debug, serde::Serialize, schemars::JsonSchema)]
pub struct EpisodeScores {
    /// Every scored frame, in order.
    pub frames: Vec<ScoreJson>,
    /// The frames that were not scored, why, in order (an image that does not decode, one
    /// the memory budget could not hold).
    pub refused: Vec<String>,
    /// Why reading stopped early (a damaged or truncated bag: the frames before it are
    /// scored), if it did.
    pub damage: Option<String>,
}

/// A frame's score as the JSON object the REST API prints: the gRPC answer's fields and
/// names, as `vamos stream` prints them ([`vamos_proto::score_json`]).
fn score_json(f: &ScoredFrame) -> ScoreJson {
    ScoreJson::from(&frame_score_fields(f))
}

/// `POST /v1/episodes:score?profile=P[&name=N]` with an MCAP body: the scores as JSON
/// (`{"frames": [...], "damage": ...}`), or with `Accept: application/x-mcap` the scored
/// bag (damage in `x-vamos-damage`); streamed to disk first (size-limited).
pub(super) async fn score_episode(
    State(s): State<Arc<Shared>>,
    Extension(caller): Extension<Caller>,
    headers: HeaderMap,
    ApiQuery(q): ApiQuery<ScoreQuery>,
    body: Body,
) -> Result<Response, ApiError> {
    let profile = s
        .profiles
        .get_async(&q.profile)
        .await
        .map_err(SessionError::from)?;
    check_label("name", q.name.as_deref().unwrap_or_default())?;
    let limit = s.hub.config().max_episode_bytes;
    let declared = content_length(&headers);
    if declared.is_some_and(|len| len > limit) {
        return Err(SessionError::EpisodeTooLarge { limit }.into());
    }
    // Admitted before a byte is buffered: a session place and an upload slot.
    let (slot, ticket) = s.admit_episode(declared)?;
    let mut buffer = EpisodeBuffer::new(&s.upload_dir(), limit, ticket)?;
    let mut stream = body.into_data_stream();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(ApiError::bad_request)?;
        buffer.write(&chunk)?;
    }
    // A `.mcap.zstd` upload is decompressed in the upload folder, charged as written: the
    // scoring and the scored bag read the copy.
    let mut buffer = buffer
        .decompressed(profile.setup.episode.max_decompressed_bytes)
        .await?;
    let wants_mcap = headers
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.contains("mcap"));
    // The scored bag copies the input's images: keep a second name for the upload,
    // since scoring consumes (and removes) the first.
    let input = if wants_mcap {
        // The scored bag is about as large as the input again.
        buffer.reserve_disk(2 * buffer.size())?;
        let original = buffer.path().to_path_buf();
        let kept = tempfile::Builder::new()
            .prefix("episode-in-")
            .suffix(".mcap")
            .make_in(s.upload_dir(), |p| {
                std::fs::hard_link(&original, p)?;
                std::fs::File::open(p)
            })
            .map_err(ApiError::internal)?;
        Some(kept)
    } else {
        None
    };
    let config = profile.setup.episode.clone();
    let (file, ticket) = buffer.into_parts();
    // The ticket goes with the last file that holds the upload's bytes: the scored input
    // (JSON answer) or the kept copy and the scored bag (MCAP answer).
    let (scoring_ticket, answer_ticket) = if wants_mcap {
        (None, Some(ticket))
    } else {
        (Some(ticket), None)
    };
    let name = q.name.unwrap_or_default();
    // A scored bag carries each frame's anomaly map; JSON answers do not.
    let scores = score(
        s.hub.clone(),
        profile.clone(),
        file,
        EpisodeRequest {
            name,
            slot,
            ticket: scoring_ticket,
            maps: wants_mcap,
            opener: caller.robot_token,
        },
    )
    .await?;
    let (frames, refused, damage) = scores.collect().await;
    let damage = damage.map(|e| e.to_string());
    match input {
        None => {
            let frames = frames.iter().map(score_json).collect();
            Ok(Json(EpisodeScores {
                frames,
                refused,
                damage,
            })
            .into_response())
        }
        Some(input) => {
            let dir = s.upload_dir();
            let thresholds = profile.setup.detector_thresholds();
            let room = DecodeRoom::new(s.hub.budget().clone(), DECODE_WAIT);
            let out = tokio::task::spawn_blocking(move || {
                scored_bag(input.path(), &config, room, &frames, &dir, thresholds)
            })
            .await
            .map_err(ApiError::internal)??;
            let mut response = file_body(out, answer_ticket).await?;
            if let Some(d) = damage
                && let Ok(v) = header::HeaderValue::from_str(&d.replace(['\r', '\n'], " "))
            {
                response.headers_mut().insert("x-vamos-damage", v);
            }
            Ok(response)
        }
    }
}

/// Writes the scored bag of `input` (its images and the score topics of `frames`, matched
/// by stamp) into a temporary file in `dir`.
fn scored_bag(
    input: &Path,
    config: &EpisodeConfig,
    room: Arc<DecodeRoom>,
    frames: &[ScoredFrame],
    dir: &Path,
    thresholds: DetectorThresholds,
) -> Result<tempfile::NamedTempFile, ApiError> {
    let episode = McapEpisode::open(input, config)
        .map_err(ApiError::bad_request)?
        .with_decode_budget(room);
    let out = tempfile::Builder::new()
        .prefix("scored-")
        .suffix(".mcap")
        .tempfile_in(dir)
        .map_err(ApiError::internal)?;
    let mut bag =
        ScoreBagWriter::create(out.path(), Some(&episode.info())).map_err(ApiError::internal)?;
    bag.copy_context(&episode).map_err(ApiError::internal)?;
    let mut thresholds_json = Some(json!(thresholds).to_string());
    let by_stamp: HashMap<i64, &ScoredFrame> =
        frames.iter().map(|f| (f.score.stamp_ns, f)).collect();
    for frame in episode.frames() {
        // Frames that were refused or lie after damage have no score and are left out.
        let Ok(frame) = frame else { continue };
        if let Some(f) = by_stamp.get(&frame.stamp_ns) {
            let s = &f.score;
            bag.write_scored_frame(
                &frame,
                &ScoreTopics {
                    score: s.score,
                    anomaly: s.anomaly,
                    values: s.values,
                    heatmap: None,
                    anomaly_map: f
                        .anomaly_map
                        .as_ref()
                        .map(|m| (m.width as u32, m.height as u32, m.pixels.as_slice())),
                    thresholds_json: thresholds_json.take().as_deref(),
                },
            )
            .map_err(ApiError::internal)?;
        }
    }
    bag.finish().map_err(ApiError::internal)?;
    Ok(out)
}
