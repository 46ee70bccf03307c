//! The HTTP API (axum): health, metrics, sessions, episode scoring.
//!
//! `/healthz`, `/readyz`, `/v2/health/*` and `/metrics` are open (probes and scrapers);
//! everything under `/v1` needs a bearer token when tokens are configured: `robot` for
//! scoring, `admin` for the rest.

use super::Shared;
use super::auth::{AuthError, Role};
use super::grpc::score_episode_file;
use super::proto;
use axum::Json;
use axum::Router;
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use futures_util::StreamExt;
use serde_json::json;
use std::io::Write;
use std::sync::Arc;
use std::sync::atomic::Ordering;

/// An error answer: a status and a JSON body `{"error": message}`.
#[derive(Debug)]
pub struct ApiError {
    /// HTTP status.
    pub status: StatusCode,
    /// What went wrong.
    pub message: String,
}

impl ApiError {
    /// An error with `status`.
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        (self.status, Json(json!({ "error": self.message }))).into_response()
    }
}

impl From<AuthError> for ApiError {
    fn from(e: AuthError) -> Self {
        let status = match e {
            AuthError::Forbidden { .. } => StatusCode::FORBIDDEN,
            _ => StatusCode::UNAUTHORIZED,
        };
        Self::new(status, e.to_string())
    }
}

impl From<tonic::Status> for ApiError {
    fn from(s: tonic::Status) -> Self {
        use tonic::Code;
        let status = match s.code() {
            Code::NotFound => StatusCode::NOT_FOUND,
            Code::InvalidArgument | Code::FailedPrecondition => StatusCode::BAD_REQUEST,
            Code::ResourceExhausted => StatusCode::TOO_MANY_REQUESTS,
            Code::Unauthenticated => StatusCode::UNAUTHORIZED,
            Code::PermissionDenied => StatusCode::FORBIDDEN,
            Code::Unavailable => StatusCode::SERVICE_UNAVAILABLE,
            Code::DataLoss => StatusCode::UNPROCESSABLE_ENTITY,
            _ => StatusCode::INTERNAL_SERVER_ERROR,
        };
        Self::new(status, s.message())
    }
}

/// Checks the bearer token of `headers` for `role`.
pub fn authorize(shared: &Shared, headers: &HeaderMap, role: Role) -> Result<Role, ApiError> {
    let h = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    Ok(shared.tokens.require(h, role)?)
}

/// The REST routes.
pub fn router(shared: Arc<Shared>) -> Router {
    Router::new()
        .route("/healthz", get(healthz))
        .route("/readyz", get(readyz))
        .route("/v2/health/live", get(healthz))
        .route("/v2/health/ready", get(readyz))
        .route("/metrics", get(metrics))
        .route("/v1/sessions", get(sessions))
        .route("/v1/profiles", get(profiles))
        .route("/v1/episodes:score", post(score_episode))
        .route("/v2/models/{name}/ready", get(model_ready))
        .with_state(shared)
}

/// Unknown paths: gRPC calls get `UNIMPLEMENTED` (as tonic answers them), others a 404
/// with a JSON body.
pub async fn not_found(headers: HeaderMap) -> Response {
    let grpc = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/grpc"));
    if grpc {
        (
            StatusCode::OK,
            [
                (header::CONTENT_TYPE, "application/grpc"),
                (header::HeaderName::from_static("grpc-status"), "12"),
            ],
        )
            .into_response()
    } else {
        ApiError::new(StatusCode::NOT_FOUND, "no such route").into_response()
    }
}

async fn healthz() -> impl IntoResponse {
    Json(json!({ "status": "live" }))
}

async fn readyz(State(s): State<Arc<Shared>>) -> Response {
    if s.ready.load(Ordering::SeqCst) && !*s.stop.borrow() {
        Json(json!({ "status": "ready" })).into_response()
    } else {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            Json(json!({ "status": "not ready" })),
        )
            .into_response()
    }
}

async fn metrics(State(s): State<Arc<Shared>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        s.metrics().render(),
    )
        .into_response()
}

async fn sessions(State(s): State<Arc<Shared>>, headers: HeaderMap) -> Result<Response, ApiError> {
    authorize(&s, &headers, Role::Admin)?;
    Ok(Json(json!({ "sessions": s.hub.sessions() })).into_response())
}

async fn profiles(State(s): State<Arc<Shared>>, headers: HeaderMap) -> Result<Response, ApiError> {
    authorize(&s, &headers, Role::Robot)?;
    let list: Vec<_> = s
        .profiles
        .names()
        .into_iter()
        .filter_map(|n| s.profiles.get(&n).ok())
        .map(|p| {
            json!({
                "name": p.name,
                "model": p.model_label,
                "robot": p.setup.robot.is_some(),
                "calibrated": p.setup.profile.calibration.is_some(),
                "alarm_threshold": finite(p.setup.profile.alarm_threshold()),
            })
        })
        .collect();
    Ok(Json(json!({ "profiles": list })).into_response())
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// KServe-v2-style model readiness: the profile or model named is loaded.
async fn model_ready(State(s): State<Arc<Shared>>, Path(name): Path<String>) -> Response {
    let ready = s.profiles.names().into_iter().any(|n| {
        s.profiles
            .get(&n)
            .is_ok_and(|p| p.setup.model.is_some() && (p.name == name || p.model_label == name))
    });
    if ready {
        Json(json!({ "name": name, "ready": true })).into_response()
    } else {
        (
            StatusCode::NOT_FOUND,
            Json(json!({ "name": name, "ready": false })),
        )
            .into_response()
    }
}

/// Query of `POST /v1/episodes:score`.
#[derive(Debug, serde::Deserialize)]
struct ScoreQuery {
    profile: String,
    #[serde(default)]
    name: Option<String>,
}

fn score_json(s: &proto::FrameScore) -> serde_json::Value {
    let detector = match proto::Detector::try_from(s.detector) {
        Ok(proto::Detector::Camera) => Some("camera"),
        Ok(proto::Detector::Body) => Some("body"),
        Ok(proto::Detector::Flow) => Some("flow"),
        _ => None,
    };
    json!({
        "stamp_ns": s.stamp_ns,
        "index": s.index,
        "frame": s.frame,
        "score": s.score,
        "e_c": s.e_c,
        "e_b": s.e_b,
        "e_o": s.e_o,
        "anomaly": s.anomaly,
        "detector": detector,
        "warming_up": s.warming_up,
        "compute_s": s.compute_s,
    })
}

/// `POST /v1/episodes:score?profile=P[&name=N]` with an MCAP body: the scores as JSON
/// (`{"frames": [...]}`), streamed to disk first (size-limited).
async fn score_episode(
    State(s): State<Arc<Shared>>,
    headers: HeaderMap,
    axum::extract::Query(q): axum::extract::Query<ScoreQuery>,
    body: Body,
) -> Result<Response, ApiError> {
    authorize(&s, &headers, Role::Robot)?;
    let profile = s
        .profiles
        .get(&q.profile)
        .map_err(|e| ApiError::new(StatusCode::NOT_FOUND, e.to_string()))?;
    let limit = s.hub.config().max_episode_bytes;
    if let Some(len) = headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
        && len > limit
    {
        return Err(ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("episode larger than the limit of {limit} bytes"),
        ));
    }
    let mut file = tempfile::Builder::new()
        .prefix("episode-")
        .suffix(".mcap")
        .tempfile_in(s.upload_dir())
        .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    let mut size = 0u64;
    let mut stream = body.into_data_stream();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| ApiError::new(StatusCode::BAD_REQUEST, e.to_string()))?;
        size += chunk.len() as u64;
        if size > limit {
            return Err(ApiError::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!("episode larger than the limit of {limit} bytes"),
            ));
        }
        file.write_all(&chunk)
            .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    }
    let name = q.name.unwrap_or_default();
    let mut scores = score_episode_file(s.hub.clone(), profile, file, name).await?;
    let mut frames = Vec::new();
    let mut damage = None;
    while let Some(item) = scores.next().await {
        match item {
            Ok(f) => frames.push(score_json(&f)),
            Err(status) => {
                damage = Some(status.message().to_string());
                break;
            }
        }
    }
    Ok(Json(json!({ "frames": frames, "damage": damage })).into_response())
}
