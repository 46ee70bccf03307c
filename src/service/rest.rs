//! The HTTP API (axum): health, metrics, sessions, episode scoring, and administration of
//! the data directory (models, robots, profiles, calibration jobs).
//!
//! Every route is listed once in [`ROUTES`] with who may call it; the router is built
//! from that list (the access check is a layer of each route) and `GET /openapi.json`
//! describes the same routes (a test keeps the two equal). `/healthz`, `/readyz`,
//! `/v2/health/*`, `/v2/models/*/ready`, `/metrics` and `/openapi.json` are open (probes
//! and scrapers); the rest needs a bearer token when tokens are configured: `robot` for
//! scoring and reading lists, `admin` for everything that changes state.
//!
//! Errors are `{"error": message}` with a status from [`StoreErrorKind`]: 404 unknown,
//! 400 refused (an upload the validator refused, a bad name or body), 413 too large, 409
//! in use, 500 internal.

use super::Shared;
use super::auth::{AuthError, Role};
use super::budget::UploadTicket;
use super::grpc::score_episode_file;
use super::proto;
use crate::episode::{EpisodeError, McapEpisode};
use crate::model::FlowModel;
use crate::pipeline::calibration::calibrate;
use crate::pipeline::offline::score_episode as score_offline;
use crate::store::{
    ProfileSpec, RobotFormat, StoreError, StoreErrorKind, ThresholdsPatch, Upload, UploadKind,
    model_bundle_summary, robot_summary,
};
use axum::Json;
use axum::Router;
use axum::body::{Body, Bytes};
use axum::extract::{Path, Request, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{MethodRouter, delete, get, patch, post, put};
use futures_util::StreamExt;
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
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

/// Who may call a route.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Anyone (probes, scrapers, the API description).
    Open,
    /// A robot or admin token.
    Robot,
    /// An admin token.
    Admin,
}

/// Every REST route: method, path (axum syntax, the same as OpenAPI's) and access. The
/// router is built from this list and `openapi.json` must describe exactly these.
pub const ROUTES: &[(&str, &str, Access)] = &[
    ("GET", "/healthz", Access::Open),
    ("GET", "/readyz", Access::Open),
    ("GET", "/v2/health/live", Access::Open),
    ("GET", "/v2/health/ready", Access::Open),
    ("GET", "/v2/models/{name}/ready", Access::Open),
    ("GET", "/metrics", Access::Open),
    ("GET", "/openapi.json", Access::Open),
    ("GET", "/v1/sessions", Access::Admin),
    ("GET", "/v1/store", Access::Admin),
    ("POST", "/v1/sessions/{id}/reload", Access::Admin),
    ("POST", "/v1/episodes:score", Access::Robot),
    ("GET", "/v1/models", Access::Robot),
    ("GET", "/v1/models/{name}", Access::Robot),
    ("PUT", "/v1/models/{name}", Access::Admin),
    ("DELETE", "/v1/models/{name}", Access::Admin),
    (
        "DELETE",
        "/v1/models/{name}/versions/{version}",
        Access::Admin,
    ),
    ("POST", "/v1/models/{name}/active", Access::Admin),
    ("GET", "/v1/robots", Access::Robot),
    ("GET", "/v1/robots/{name}", Access::Robot),
    ("PUT", "/v1/robots/{name}", Access::Admin),
    ("DELETE", "/v1/robots/{name}", Access::Admin),
    ("GET", "/v1/profiles", Access::Robot),
    ("GET", "/v1/profiles/{name}", Access::Robot),
    ("PUT", "/v1/profiles/{name}", Access::Admin),
    ("DELETE", "/v1/profiles/{name}", Access::Admin),
    ("PATCH", "/v1/profiles/{name}/thresholds", Access::Admin),
    ("POST", "/v1/profiles/{name}/calibrate", Access::Admin),
    ("GET", "/v1/jobs", Access::Admin),
    ("GET", "/v1/jobs/{id}", Access::Admin),
    ("DELETE", "/v1/jobs/{id}", Access::Admin),
];

/// The OpenAPI 3.0 description served at `/openapi.json`.
pub const OPENAPI_JSON: &str = include_str!("openapi.json");

/// The handler of a route of [`ROUTES`] (`None`: no such route).
pub fn handler(method: &str, path: &str) -> Option<MethodRouter<Arc<Shared>>> {
    Some(match (method, path) {
        ("GET", "/healthz" | "/v2/health/live") => get(healthz),
        ("GET", "/readyz" | "/v2/health/ready") => get(readyz),
        ("GET", "/v2/models/{name}/ready") => get(model_ready),
        ("GET", "/metrics") => get(metrics),
        ("GET", "/openapi.json") => get(openapi),
        ("GET", "/v1/sessions") => get(sessions),
        ("GET", "/v1/store") => get(store_status),
        ("POST", "/v1/sessions/{id}/reload") => post(reload_session),
        ("POST", "/v1/episodes:score") => post(score_episode),
        ("GET", "/v1/models") => get(list_models),
        ("GET", "/v1/models/{name}") => get(get_model),
        ("PUT", "/v1/models/{name}") => put(put_model),
        ("DELETE", "/v1/models/{name}") => delete(delete_model),
        ("DELETE", "/v1/models/{name}/versions/{version}") => delete(delete_model_version),
        ("POST", "/v1/models/{name}/active") => post(set_active_model),
        ("GET", "/v1/robots") => get(list_robots),
        ("GET", "/v1/robots/{name}") => get(get_robot),
        ("PUT", "/v1/robots/{name}") => put(put_robot),
        ("DELETE", "/v1/robots/{name}") => delete(delete_robot),
        ("GET", "/v1/profiles") => get(profiles),
        ("GET", "/v1/profiles/{name}") => get(get_profile),
        ("PUT", "/v1/profiles/{name}") => put(put_profile),
        ("DELETE", "/v1/profiles/{name}") => delete(delete_profile),
        ("PATCH", "/v1/profiles/{name}/thresholds") => patch(patch_thresholds),
        ("POST", "/v1/profiles/{name}/calibrate") => post(start_calibration),
        ("GET", "/v1/jobs") => get(list_jobs),
        ("GET", "/v1/jobs/{id}") => get(get_job),
        ("DELETE", "/v1/jobs/{id}") => delete(delete_job),
        _ => return None,
    })
}

/// The access check of a route: refuses a missing or insufficient token before the
/// handler (and before any body is read).
async fn require(
    State((s, access)): State<(Arc<Shared>, Access)>,
    req: Request,
    next: Next,
) -> Response {
    let role = match access {
        Access::Open => return next.run(req).await,
        Access::Robot => Role::Robot,
        Access::Admin => Role::Admin,
    };
    match authorize(&s, req.headers(), role) {
        Ok(_) => next.run(req).await,
        Err(e) => e.into_response(),
    }
}

/// The REST routes of [`ROUTES`].
pub fn router(shared: Arc<Shared>) -> Router {
    let mut by_path: Vec<(&str, MethodRouter<Arc<Shared>>)> = Vec::new();
    for &(method, path, access) in ROUTES {
        let Some(h) = handler(method, path) else {
            tracing::error!(method, path, "route without a handler");
            continue;
        };
        let h = h.route_layer(axum::middleware::from_fn_with_state(
            (shared.clone(), access),
            require,
        ));
        match by_path.iter().position(|(p, _)| *p == path) {
            Some(i) => {
                let (p, existing) = by_path.swap_remove(i);
                by_path.push((p, existing.merge(h)));
            }
            None => by_path.push((path, h)),
        }
    }
    by_path
        .into_iter()
        .fold(Router::new(), |r, (path, h)| r.route(path, h))
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
    if s.ready.load(Ordering::SeqCst) && !*s.stop.borrow() && s.hub.live_workers() > 0 {
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

async fn openapi() -> Response {
    ([(header::CONTENT_TYPE, "application/json")], OPENAPI_JSON).into_response()
}

async fn sessions(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
    Ok(Json(json!({ "sessions": s.hub.sessions() })).into_response())
}

/// The data directory and, in a fleet, the shared store.
async fn store_status(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
    Ok(Json(json!({
        "data_dir": s.store.dir(),
        "read_only": s.store.read_only(),
        "problems": s.store.problems().len(),
        "shared_store": s.fleet.as_ref().map(|f| f.status()),
    }))
    .into_response())
}

fn file_profile_json(p: &super::profiles::LoadedProfile) -> serde_json::Value {
    json!({
        "name": p.name,
        "source": "file",
        "model": p.model_label,
        "robot": p.setup.robot.is_some(),
        "calibrated": p.setup.profile.calibration.is_some(),
        "alarm_threshold": finite(p.setup.profile.alarm_threshold()),
    })
}

fn stored_profile_json(s: &Shared, info: &crate::store::ProfileInfo) -> serde_json::Value {
    let model = match s.profiles.get_cached(&info.name) {
        Some(p) => p.model_label.clone(),
        None => info.spec.model.as_ref().map_or_else(
            || "none".into(),
            |m| match m.version {
                Some(v) => format!("{}@{v}", m.name),
                None => m.name.clone(),
            },
        ),
    };
    json!({
        "name": info.name,
        "source": "store",
        "model": model,
        "robot": info.spec.robot.is_some(),
        "calibrated": info.calibration.is_some(),
        "alarm_threshold": info.alarm_threshold,
        "profile": info,
    })
}

/// `GET /v1/profiles`: the profile files, then the stored profiles they do not shadow.
async fn profiles(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
    let mut list: Vec<_> = s
        .profiles
        .loaded()
        .iter()
        .filter(|p| s.profiles.is_file(&p.name))
        .map(|p| file_profile_json(p))
        .collect();
    list.sort_by(|a, b| a["name"].as_str().cmp(&b["name"].as_str()));
    let store = s.store.clone();
    let stored = blocking(move || Ok(store.profiles())).await?;
    list.extend(
        stored
            .iter()
            .filter(|p| !s.profiles.is_file(&p.name))
            .map(|p| stored_profile_json(&s, p)),
    );
    Ok(Json(json!({ "profiles": list })).into_response())
}

fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

/// KServe-v2-style model readiness: `name` is a profile or model (`name@version` label)
/// that a loaded profile uses, or a stored model whose active version has no problem
/// (every stored version was loaded with ONNX Runtime when it was uploaded, and its
/// checksum verified when the data directory was opened).
async fn model_ready(State(s): State<Arc<Shared>>, Path(name): Path<String>) -> Response {
    let loaded = s.profiles.loaded().iter().any(|p| {
        p.setup.model.is_some()
            && (p.name == name
                || p.model_label == name
                || p.model_label.split('@').next() == Some(&name))
    });
    let stored = s.store.model(&name).ok().is_some_and(|m| {
        m.active.is_some_and(|v| {
            m.versions
                .iter()
                .any(|x| x.version == v && x.problem.is_none())
        })
    });
    if loaded || stored {
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

/// `POST /v1/episodes:score?profile=P[&name=N]` with an MCAP body: the scores as JSON
/// (`{"frames": [...]}`), streamed to disk first (size-limited).
async fn score_episode(
    State(s): State<Arc<Shared>>,
    headers: HeaderMap,
    axum::extract::Query(q): axum::extract::Query<ScoreQuery>,
    body: Body,
) -> Result<Response, ApiError> {
    let profile = s
        .profiles
        .get_async(&q.profile)
        .await
        .map_err(|e| ApiError::new(StatusCode::NOT_FOUND, e.to_string()))?;
    let limit = s.hub.config().max_episode_bytes;
    let declared = content_length(&headers);
    if declared.is_some_and(|len| len > limit) {
        return Err(ApiError::new(
            StatusCode::PAYLOAD_TOO_LARGE,
            format!("episode larger than the limit of {limit} bytes"),
        ));
    }
    // Admitted before a byte is buffered: a session place and an upload slot.
    let (slot, mut ticket) = s.admit_episode(declared)?;
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
        ticket.written(size).map_err(too_many)?;
        file.write_all(&chunk)
            .map_err(|e| ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    }
    let name = q.name.unwrap_or_default();
    let wants_mcap = headers
        .get(header::ACCEPT)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.contains("mcap"));
    // The scored bag copies the input's images: keep a second name for the upload,
    // since scoring consumes (and removes) the first.
    let input = if wants_mcap {
        // The scored bag is about as large as the input again.
        ticket.written(2 * size).map_err(too_many)?;
        let original = file.path().to_path_buf();
        let kept = tempfile::Builder::new()
            .prefix("episode-in-")
            .suffix(".mcap")
            .make_in(s.upload_dir(), |p| {
                std::fs::hard_link(&original, p)?;
                std::fs::File::open(p)
            })
            .map_err(internal)?;
        Some(kept)
    } else {
        None
    };
    let config = profile.setup.episode.clone();
    // The ticket goes with the last file that holds the upload's bytes: the scored input
    // (JSON answer) or the kept copy and the scored bag (MCAP answer).
    let (scoring_ticket, answer_ticket) = if wants_mcap {
        (None, Some(ticket))
    } else {
        (Some(ticket), None)
    };
    let mut scores =
        score_episode_file(s.hub.clone(), profile, file, name, slot, scoring_ticket).await?;
    let mut frames = Vec::new();
    let mut damage = None;
    while let Some(item) = scores.next().await {
        match item {
            Ok(f) => frames.push(f),
            Err(status) => {
                damage = Some(status.message().to_string());
                break;
            }
        }
    }
    match input {
        None => {
            let frames: Vec<_> = frames.iter().map(proto::score_json).collect();
            Ok(Json(json!({ "frames": frames, "damage": damage })).into_response())
        }
        Some(input) => {
            let dir = s.upload_dir();
            let out = tokio::task::spawn_blocking(move || {
                scored_bag(input.path(), &config, &frames, &dir)
            })
            .await
            .map_err(internal)??;
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
    input: &std::path::Path,
    config: &crate::episode::EpisodeConfig,
    frames: &[proto::FrameScore],
    dir: &std::path::Path,
) -> Result<tempfile::NamedTempFile, ApiError> {
    use crate::episode::{McapEpisode, ScoreBagWriter, ScoreTopics};
    let episode = McapEpisode::open(input, config).map_err(bad_request)?;
    let out = tempfile::Builder::new()
        .prefix("scored-")
        .suffix(".mcap")
        .tempfile_in(dir)
        .map_err(internal)?;
    let mut bag = ScoreBagWriter::create(out.path(), Some(&episode.info())).map_err(internal)?;
    let by_stamp: std::collections::HashMap<i64, &proto::FrameScore> =
        frames.iter().map(|f| (f.stamp_ns, f)).collect();
    for frame in episode.frames() {
        // Frames that were refused or lie after damage have no score and are left out.
        let Ok(frame) = frame else { continue };
        if let Some(f) = by_stamp.get(&frame.stamp_ns) {
            bag.write_scored_frame(
                &frame,
                &ScoreTopics {
                    score: f.score,
                    anomaly: f.anomaly,
                    e_c: f.e_c,
                    e_b: f.e_b,
                    e_o: f.e_o,
                    heatmap: None,
                },
            )
            .map_err(internal)?;
        }
    }
    bag.finish().map_err(internal)?;
    Ok(out)
}

/// A response streaming `file` as `application/x-mcap`. Its name is removed before the
/// response is returned (the open handle keeps the data readable), so nothing is left in
/// the upload folder however the transfer ends.
async fn file_body(
    file: tempfile::NamedTempFile,
    ticket: Option<UploadTicket>,
) -> Result<Response, ApiError> {
    use tokio::io::AsyncReadExt;
    let mut std_file = file.into_file();
    let len = std_file.metadata().map_err(internal)?.len();
    std::io::Seek::rewind(&mut std_file).map_err(internal)?;
    let mut reader = tokio::fs::File::from_std(std_file);
    let (tx, rx) = tokio::sync::mpsc::channel::<Result<Vec<u8>, std::io::Error>>(4);
    tokio::spawn(async move {
        // Held until the answer is sent (or the client goes).
        let _ticket = ticket;
        loop {
            let mut buf = vec![0u8; 256 << 10];
            match reader.read(&mut buf).await {
                Ok(0) => return,
                Ok(n) => {
                    buf.truncate(n);
                    if tx.send(Ok(buf)).await.is_err() {
                        return;
                    }
                }
                Err(e) => {
                    let _ = tx.send(Err(e)).await;
                    return;
                }
            }
        }
    });
    Response::builder()
        .header(header::CONTENT_TYPE, "application/x-mcap")
        .header(header::CONTENT_LENGTH, len)
        .body(Body::from_stream(
            tokio_stream::wrappers::ReceiverStream::new(rx),
        ))
        .map_err(internal)
}

// ---- Administration of the data directory ----

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        let status = match e.kind() {
            StoreErrorKind::NotFound => StatusCode::NOT_FOUND,
            StoreErrorKind::BadRequest => StatusCode::BAD_REQUEST,
            StoreErrorKind::TooLarge => StatusCode::PAYLOAD_TOO_LARGE,
            StoreErrorKind::Conflict => StatusCode::CONFLICT,
            StoreErrorKind::StorageFull => StatusCode::INSUFFICIENT_STORAGE,
            StoreErrorKind::Internal => StatusCode::INTERNAL_SERVER_ERROR,
        };
        Self::new(status, e.to_string())
    }
}

fn internal(e: impl std::fmt::Display) -> ApiError {
    ApiError::new(StatusCode::INTERNAL_SERVER_ERROR, e.to_string())
}

fn bad_request(e: impl std::fmt::Display) -> ApiError {
    ApiError::new(StatusCode::BAD_REQUEST, e.to_string())
}

/// Runs a store call on a blocking thread.
async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, StoreError> + Send + 'static,
) -> Result<T, ApiError> {
    Ok(tokio::task::spawn_blocking(f).await.map_err(internal)??)
}

/// Largest JSON calibration request (paths on the server), bytes.
const MAX_CALIBRATE_JSON_BYTES: usize = 1 << 20;

/// Reads a JSON body of at most `limit` bytes: a longer one is refused with 413 (the
/// size), a broken one with 400.
async fn json_bytes(body: Body, limit: usize) -> Result<Bytes, ApiError> {
    let mut stream = body.into_data_stream();
    let mut out = Vec::new();
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(|e| bad_request(format!("cannot read the body: {e}")))?;
        if out.len() + chunk.len() > limit {
            return Err(ApiError::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!("the JSON body is over {limit} bytes"),
            ));
        }
        out.extend_from_slice(&chunk);
    }
    Ok(Bytes::from(out))
}

fn json_body<T: serde::de::DeserializeOwned>(body: &[u8]) -> Result<T, ApiError> {
    serde_json::from_slice(body).map_err(|e| bad_request(format!("bad JSON body: {e}")))
}

fn to_json(v: &impl serde::Serialize) -> Result<serde_json::Value, ApiError> {
    serde_json::to_value(v).map_err(internal)
}

/// The declared `Content-Length`, if any.
fn content_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
}

/// Streams `body` into a new upload of `kind`, refusing with 413 a declared or actual
/// size over the store's limit, and with 429 an upload the server has no slot or
/// temporary disk for (before a byte is read). The ticket holds the slot and the disk
/// until it is dropped (after the commit).
async fn receive(
    s: &Shared,
    kind: UploadKind,
    headers: &HeaderMap,
    body: Body,
) -> Result<(Upload, UploadTicket), ApiError> {
    let store = &s.store;
    let limit = match kind {
        UploadKind::Model => store.limits().max_model_bytes,
        UploadKind::Robot { .. } => store.limits().max_robot_bytes,
    };
    let declared = content_length(headers);
    if declared.is_some_and(|len| len > limit) {
        return Err(StoreError::TooLarge { limit_bytes: limit }.into());
    }
    let mut ticket = s.admit_upload(declared)?;
    let st = store.clone();
    let mut upload = blocking(move || st.begin_upload(kind)).await?;
    let mut stream = body.into_data_stream();
    let mut size = 0u64;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(bad_request)?;
        size += chunk.len() as u64;
        ticket.written(size).map_err(too_many)?;
        match blocking(move || upload.write_chunk(&chunk).map(|()| upload)).await {
            Ok(u) => upload = u,
            // The upload is gone (its file removed). A full disk is not the client's
            // doing: read the rest (bounded) so the 507 reaches it on a usable connection.
            Err(e) if e.status == StatusCode::INSUFFICIENT_STORAGE => {
                drain_data(&mut stream, DRAIN_LIMIT_BYTES).await;
                return Err(e);
            }
            Err(e) => return Err(e),
        }
    }
    Ok((upload, ticket))
}

fn too_many(e: impl std::fmt::Display) -> ApiError {
    ApiError::new(StatusCode::TOO_MANY_REQUESTS, e.to_string())
}

/// Reads and drops up to `budget` more bytes of a body.
async fn drain_data(stream: &mut axum::body::BodyDataStream, mut budget: u64) {
    while let Some(Ok(chunk)) = stream.next().await {
        budget = budget.saturating_sub(chunk.len() as u64);
        if budget == 0 {
            return;
        }
    }
}

async fn list_models(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let models = blocking(move || Ok(store.models())).await?;
    Ok(Json(json!({ "models": models })).into_response())
}

async fn get_model(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let model = blocking(move || store.model(&name)).await?;
    Ok(Json(model).into_response())
}

/// `PUT /v1/models/{name}`: the body is a model bundle; it becomes the next version once
/// it reads as a bundle and loads with ONNX Runtime.
async fn put_model(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let (upload, _ticket) = receive(&s, UploadKind::Model, &headers, body).await?;
    let store = s.store.clone();
    // Validation loads the model once (one replica, one thread) and one upload at a time:
    // its memory is one model's, however many uploads arrive together.
    let options = crate::model::LoadOptions {
        replicas: 1,
        intra_threads: 1,
        ..s.settings.model.load_options()
    };
    let _validating = s.model_validation.lock().await;
    let n = name.clone();
    let (info, active) = blocking(move || {
        let info = store.commit_model(&n, upload, |path| {
            let summary = model_bundle_summary(path)?;
            FlowModel::load(path, &options)
                .map_err(|e| format!("the model does not load with ONNX Runtime: {e}"))?;
            Ok(summary)
        })?;
        let active = store.model(&n)?.active;
        Ok((info, active))
    })
    .await?;
    s.profiles.invalidate_model(&name);
    let mut body = to_json(&info)?;
    body["name"] = json!(name);
    body["active"] = json!(active);
    Ok((StatusCode::CREATED, Json(body)).into_response())
}

async fn delete_model(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.delete_model(&n, None)).await?;
    s.profiles.invalidate_model(&name);
    Ok(StatusCode::NO_CONTENT.into_response())
}

async fn delete_model_version(
    State(s): State<Arc<Shared>>,
    Path((name, version)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let version: u32 = version
        .parse()
        .map_err(|_| bad_request(format!("bad version {version:?}")))?;
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.delete_model(&n, Some(version))).await?;
    s.profiles.invalidate_model(&name);
    Ok(StatusCode::NO_CONTENT.into_response())
}

/// Body of `POST /v1/models/{name}/active`.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct ActiveRequest {
    version: u32,
    /// Also move the running sessions whose profile uses this model to the new version
    /// (by default they keep the version they opened with).
    #[serde(default)]
    reload_sessions: bool,
}

async fn set_active_model(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    let req: ActiveRequest = json_body(&body)?;
    let store = s.store.clone();
    let n = name.clone();
    let model = blocking(move || {
        store.set_active_model(&n, req.version)?;
        store.model(&n)
    })
    .await?;
    s.profiles.invalidate_model(&name);
    let mut body = to_json(&model)?;
    if req.reload_sessions {
        let mut reloaded = Vec::new();
        let mut failed = serde_json::Map::new();
        for summary in s.hub.sessions() {
            let uses = summary.model.split('@').next() == Some(name.as_str());
            if !uses || s.profiles.is_file(&summary.profile) {
                continue;
            }
            match reload_one(&s, &summary.id).await {
                Ok(Some(_)) => reloaded.push(summary.id),
                // Closed meanwhile, or already on the current version.
                Ok(None) => {}
                Err(e) => {
                    failed.insert(summary.id, json!(e.message));
                }
            }
        }
        body["reloaded_sessions"] = json!(reloaded);
        if !failed.is_empty() {
            body["reload_errors"] = serde_json::Value::Object(failed);
        }
    }
    Ok(Json(body).into_response())
}

/// Moves session `id` to its profile as loaded now. `Ok(None)`: the session is gone, or
/// it already scores with that very profile (nothing changed since it opened).
async fn reload_one(s: &Arc<Shared>, id: &str) -> Result<Option<String>, ApiError> {
    let Some(session) = s.hub.session(id) else {
        return Ok(None);
    };
    let profile = s
        .profiles
        .get_async(&session.profile_name)
        .await
        .map_err(|e| ApiError::new(StatusCode::CONFLICT, e.to_string()))?;
    if Arc::ptr_eq(&profile, &session.profile()) {
        return Ok(None);
    }
    let model = profile.model_label.clone();
    let hub = s.hub.clone();
    tokio::task::spawn_blocking(move || hub.reload(&session, profile))
        .await
        .map_err(internal)?
        .map_err(|e| ApiError::new(StatusCode::CONFLICT, e.to_string()))?;
    Ok(Some(model))
}

/// `POST /v1/sessions/{id}/reload`: the session scores with its profile as stored now
/// (a new active model version, new thresholds or calibration) from its next frame; its
/// flow predictor warms up again. `reloaded: false` when nothing changed since it opened.
async fn reload_session(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    if s.hub.session(&id).is_none() {
        return Err(ApiError::new(
            StatusCode::NOT_FOUND,
            format!("no open session {id:?}"),
        ));
    }
    let reloaded = reload_one(&s, &id).await?;
    let summary = s.hub.session(&id).map(|x| x.summary());
    Ok(Json(json!({
        "reloaded": reloaded.is_some(),
        "session": summary,
    }))
    .into_response())
}

async fn list_robots(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let robots = blocking(move || Ok(store.robots())).await?;
    Ok(Json(json!({ "robots": robots })).into_response())
}

async fn get_robot(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let robot = blocking(move || store.robot(&name)).await?;
    Ok(Json(robot).into_response())
}

/// Query of `PUT /v1/robots/{name}`.
#[derive(Debug, serde::Deserialize)]
struct RobotQuery {
    #[serde(default)]
    format: Option<String>,
}

/// The package format: `?format=urdf|tar.gz|tgz|zip`, else the Content-Type.
fn robot_format(q: &RobotQuery, headers: &HeaderMap) -> Result<RobotFormat, ApiError> {
    if let Some(f) = &q.format {
        return match f.to_ascii_lowercase().as_str() {
            "urdf" => Ok(RobotFormat::Urdf),
            "tar.gz" | "tgz" => Ok(RobotFormat::TarGz),
            "zip" => Ok(RobotFormat::Zip),
            other => Err(bad_request(format!(
                "unknown robot format {other:?} (urdf, tar.gz or zip)"
            ))),
        };
    }
    let ctype = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let mime = ctype
        .split(';')
        .next()
        .unwrap_or("")
        .trim()
        .to_ascii_lowercase();
    match mime.as_str() {
        "application/gzip" | "application/x-gzip" | "application/x-tar+gzip" => {
            Ok(RobotFormat::TarGz)
        }
        "application/zip" => Ok(RobotFormat::Zip),
        "application/xml" | "text/xml" => Ok(RobotFormat::Urdf),
        _ => Err(bad_request(format!(
            "cannot tell the robot format from Content-Type {ctype:?}: use ?format=urdf|tar.gz|zip"
        ))),
    }
}

/// `PUT /v1/robots/{name}`: the body is a URDF file or a robot package archive.
async fn put_robot(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    axum::extract::Query(q): axum::extract::Query<RobotQuery>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let format = robot_format(&q, &headers)?;
    let (upload, _ticket) = receive(&s, UploadKind::Robot { format }, &headers, body).await?;
    let store = s.store.clone();
    let cfg = s.settings.robot.clone();
    let n = name.clone();
    let info =
        blocking(move || store.commit_robot(&n, upload, |path| robot_summary(path, &cfg))).await?;
    s.profiles.invalidate_robot(&name);
    Ok((StatusCode::CREATED, Json(info)).into_response())
}

async fn delete_robot(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.delete_robot(&n)).await?;
    s.profiles.invalidate_robot(&name);
    Ok(StatusCode::NO_CONTENT.into_response())
}

fn refuse_file_profile(s: &Shared, name: &str) -> Result<(), ApiError> {
    if s.profiles.is_file(name) {
        return Err(ApiError::new(
            StatusCode::CONFLICT,
            format!(
                "profile {name:?} is a profile file of the server's settings, which takes priority; it cannot be changed through the API"
            ),
        ));
    }
    Ok(())
}

async fn get_profile(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    if let Some(p) = s
        .profiles
        .get_cached(&name)
        .filter(|_| s.profiles.is_file(&name))
    {
        return Ok(Json(file_profile_json(&p)).into_response());
    }
    let store = s.store.clone();
    let info = blocking(move || store.profile(&name)).await?;
    Ok(Json(stored_profile_json(&s, &info)).into_response())
}

/// `PUT /v1/profiles/{name}`: stores the profile, then loads it (robot, camera, model) so
/// the first session does not wait; a profile that does not load is stored anyway and
/// the answer says why (`load_error`).
async fn put_profile(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    refuse_file_profile(&s, &name)?;
    let spec: ProfileSpec = json_body(&body)?;
    let store = s.store.clone();
    let n = name.clone();
    let info = blocking(move || store.put_profile(&n, spec)).await?;
    s.profiles.invalidate_profile(&name);
    let load_error = s
        .profiles
        .get_async(&name)
        .await
        .err()
        .map(|e| e.to_string());
    let mut body = stored_profile_json(&s, &info);
    body["load_error"] = json!(load_error);
    Ok(Json(body).into_response())
}

async fn delete_profile(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    refuse_file_profile(&s, &name)?;
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.delete_profile(&n)).await?;
    s.profiles.invalidate_profile(&name);
    Ok(StatusCode::NO_CONTENT.into_response())
}

async fn patch_thresholds(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<Response, ApiError> {
    refuse_file_profile(&s, &name)?;
    let patch: ThresholdsPatch = json_body(&body)?;
    let store = s.store.clone();
    let n = name.clone();
    let info = blocking(move || store.patch_thresholds(&n, patch)).await?;
    s.profiles.invalidate_profile(&name);
    Ok(Json(stored_profile_json(&s, &info)).into_response())
}

fn default_alpha() -> f64 {
    0.1
}

/// Body of `POST /v1/profiles/{name}/calibrate` as JSON: episode files or folders of
/// `.mcap` files on the server.
#[derive(Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct CalibrateRequest {
    episodes: Vec<PathBuf>,
    #[serde(default)]
    holdout: Vec<PathBuf>,
    #[serde(default = "default_alpha")]
    alpha: f64,
}

fn check_calibrate_request(req: &CalibrateRequest) -> Result<(), ApiError> {
    if req.episodes.is_empty() {
        return Err(bad_request("`episodes` is empty"));
    }
    if !(req.alpha > 0.0 && req.alpha < 1.0) {
        return Err(bad_request(format!("alpha {} is not in (0, 1)", req.alpha)));
    }
    Ok(())
}

/// A JSON calibration body, parsed and checked as `POST /v1/profiles/{name}/calibrate`
/// does before it starts a job (for the fuzz targets).
pub(crate) fn parse_calibrate_request(body: &[u8]) -> Result<(), ApiError> {
    let req: CalibrateRequest = json_body(body)?;
    check_calibrate_request(&req)
}

/// A `POST /v1/models/{name}/active` body, parsed as the handler does (for the fuzz
/// targets).
pub(crate) fn parse_active_request(body: &[u8]) -> Result<(), ApiError> {
    json_body::<ActiveRequest>(body).map(|_| ())
}

/// Folders become the `.mcap` files directly inside them (sorted).
fn expand(paths: &[PathBuf]) -> Result<Vec<PathBuf>, String> {
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            let mut found: Vec<PathBuf> = std::fs::read_dir(p)
                .map_err(|e| format!("{}: {e}", p.display()))?
                .filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|f| f.extension().is_some_and(|x| x == "mcap"))
                .collect();
            found.sort();
            out.extend(found);
        } else if p.is_file() {
            out.push(p.clone());
        } else {
            return Err(format!("{}: no such episode file or folder", p.display()));
        }
    }
    Ok(out)
}

/// The calibration job's work (blocking): scores the episodes with the profile, saves
/// the calibration. Stops before the next episode once `job` is cancelled.
fn run_calibration(
    s: &Shared,
    name: &str,
    req: &CalibrateRequest,
    job: &super::jobs::JobHandle,
) -> Result<(crate::pipeline::Calibration, Vec<String>), String> {
    let profile = s.profiles.get(name).map_err(|e| e.to_string())?;
    let setup = &profile.setup;
    let training = expand(&req.episodes)?;
    let holdout = expand(&req.holdout)?;
    if training.is_empty() {
        return Err("no training episodes".into());
    }
    let model_sha256 = setup.model.as_ref().map(|m| m.sha256().to_string());
    let outcome = calibrate(
        &training,
        &holdout,
        req.alpha,
        model_sha256,
        &setup.config,
        |episodes, thresholds| {
            episodes
                .iter()
                .map(|path| {
                    if job.cancelled() {
                        return Err("cancelled".to_string());
                    }
                    let what = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
                    let episode = McapEpisode::open(path, &setup.episode).map_err(|e| what(&e))?;
                    let mut scorer = setup
                        .scorer(
                            episode.name(),
                            thresholds.clone(),
                            f64::INFINITY,
                            false,
                            None,
                            None,
                        )
                        .map_err(|e| what(&e))?;
                    score_offline::<EpisodeError>(&mut scorer, &episode, |_, _| Ok(()))
                        .map_err(|e| what(&e))
                })
                .collect()
        },
    )?;
    if job.cancelled() {
        return Err("cancelled".into());
    }
    s.store
        .save_calibration(name, outcome.calibration.clone())
        .map_err(|e| e.to_string())?;
    Ok((outcome.calibration, outcome.notes))
}

/// Episodes uploaded with a calibration request, in a temporary folder of the upload
/// directory that is removed when the job ends (and, after a crash, when the store
/// opens).
struct CalibrationUpload {
    dir: tempfile::TempDir,
    request: CalibrateRequest,
    episodes: Vec<String>,
    holdout: Vec<String>,
    /// The upload's slot and disk, held as long as the files.
    ticket: UploadTicket,
}

/// A part's file name as a safe episode file name (`[A-Za-z0-9._-]`, ending in `.mcap`);
/// the episode is named after its stem, as on the command line.
fn episode_file_name(raw: Option<&str>, index: usize) -> String {
    let base = raw
        .and_then(|n| n.rsplit(['/', '\\']).next())
        .unwrap_or("")
        .trim_end_matches(".mcap");
    let mut clean: String = base
        .chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || matches!(c, '.' | '_' | '-') {
                c
            } else {
                '_'
            }
        })
        .take(100)
        .collect();
    if clean.trim_matches('.').is_empty() {
        clean = format!("episode_{index:04}");
    }
    format!("{clean}.mcap")
}

/// Receives a `multipart/form-data` calibration request: file parts `episodes` (one or
/// more, nominal training episodes) and `holdout` (held-out nominal episodes), an
/// optional text part `alpha`. Each file streams to disk, limited to
/// `max_episode_bytes`, all of them together to `max_calibration_bytes`.
async fn receive_calibration(
    s: &Shared,
    content_type: &str,
    body: Body,
    mut ticket: UploadTicket,
) -> Result<CalibrationUpload, ApiError> {
    let boundary = multer::parse_boundary(content_type)
        .map_err(|e| bad_request(format!("bad multipart content type: {e}")))?;
    let cfg = s.hub.config();
    let (per_file, total_limit) = (cfg.max_episode_bytes, cfg.max_calibration_bytes);
    let dir = tempfile::Builder::new()
        .prefix("calibrate-")
        .tempdir_in(s.upload_dir())
        .map_err(internal)?;
    for sub in ["episodes", "holdout"] {
        std::fs::create_dir(dir.path().join(sub)).map_err(internal)?;
    }
    let mut multipart = multer::Multipart::new(body.into_data_stream(), boundary);
    match read_calibration_parts(
        &mut multipart,
        dir.path(),
        per_file,
        total_limit,
        &mut ticket,
    )
    .await
    {
        Ok((request, episodes, holdout)) => Ok(CalibrationUpload {
            dir,
            request,
            episodes,
            holdout,
            ticket,
        }),
        Err(e) => {
            // A request refused for what it says (not for its size or a broken body):
            // read the rest, so the connection stays usable for the client's next call.
            if e.status == StatusCode::BAD_REQUEST && !e.message.starts_with(BROKEN_MULTIPART) {
                drain(&mut multipart, DRAIN_LIMIT_BYTES).await;
            }
            Err(e)
        }
    }
}

/// The start of the message of a body multer cannot parse.
const BROKEN_MULTIPART: &str = "bad multipart body";

/// At most this much of a refused upload is read before answering (beyond it the
/// connection is closed instead).
const DRAIN_LIMIT_BYTES: u64 = 64 << 20;

async fn drain(multipart: &mut multer::Multipart<'_>, mut budget: u64) {
    while let Ok(Some(mut field)) = multipart.next_field().await {
        while let Ok(Some(chunk)) = field.chunk().await {
            budget = budget.saturating_sub(chunk.len() as u64);
            if budget == 0 {
                return;
            }
        }
    }
}

/// The parts of a calibration upload, each file written into `dir`.
async fn read_calibration_parts(
    multipart: &mut multer::Multipart<'_>,
    dir: &std::path::Path,
    per_file: u64,
    total_limit: u64,
    ticket: &mut UploadTicket,
) -> Result<(CalibrateRequest, Vec<String>, Vec<String>), ApiError> {
    use tokio::io::AsyncWriteExt;
    let mut request = CalibrateRequest {
        episodes: Vec::new(),
        holdout: Vec::new(),
        alpha: default_alpha(),
    };
    let (mut episodes, mut holdout) = (Vec::new(), Vec::new());
    let mut total = 0u64;
    let part_error = |e: multer::Error| bad_request(format!("{BROKEN_MULTIPART}: {e}"));
    let mut index = 0;
    while let Some(mut field) = multipart.next_field().await.map_err(part_error)? {
        let part = field.name().unwrap_or("").to_string();
        let (paths, names) = match part.as_str() {
            "episodes" => (&mut request.episodes, &mut episodes),
            "holdout" => (&mut request.holdout, &mut holdout),
            "alpha" => {
                let text = field.text().await.map_err(part_error)?;
                request.alpha = text
                    .trim()
                    .parse()
                    .map_err(|_| bad_request(format!("alpha {text:?} is not a number")))?;
                continue;
            }
            other => {
                return Err(bad_request(format!(
                    "unknown part {other:?}: expected files `episodes` and `holdout`, text `alpha`"
                )));
            }
        };
        index += 1;
        let file_name = episode_file_name(field.file_name(), index);
        if names.contains(&file_name) {
            return Err(bad_request(format!(
                "two `{part}` files are named {file_name:?}: episodes are told apart by name"
            )));
        }
        let path = dir.join(&part).join(&file_name);
        let mut file = tokio::fs::File::create(&path).await.map_err(internal)?;
        let mut size = 0u64;
        while let Some(chunk) = field.chunk().await.map_err(part_error)? {
            size += chunk.len() as u64;
            total += chunk.len() as u64;
            if size > per_file {
                return Err(ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    format!("episode {file_name:?} is larger than the limit of {per_file} bytes"),
                ));
            }
            if total > total_limit {
                return Err(ApiError::new(
                    StatusCode::PAYLOAD_TOO_LARGE,
                    format!(
                        "the calibration upload is larger than the limit of {total_limit} bytes"
                    ),
                ));
            }
            ticket.written(total).map_err(too_many)?;
            file.write_all(&chunk).await.map_err(internal)?;
        }
        file.flush().await.map_err(internal)?;
        if size == 0 {
            return Err(bad_request(format!("episode {file_name:?} is empty")));
        }
        paths.push(path);
        names.push(file_name);
    }
    Ok((request, episodes, holdout))
}

/// `POST /v1/profiles/{name}/calibrate`: starts a calibration job (202 `{"job": id}`)
/// over episodes on the server (JSON body) or uploaded with the request
/// (`multipart/form-data`).
async fn start_calibration(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    refuse_file_profile(&s, &name)?;
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.profile(&n)).await?;
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let busy = |e: super::jobs::JobError| match e {
        super::jobs::JobError::Busy { .. } => too_many(e),
        super::jobs::JobError::Store(e) => e.into(),
    };
    let (req, upload, episodes, holdout) = if content_type
        .to_ascii_lowercase()
        .starts_with("multipart/form-data")
    {
        // Refused before the episodes are read when no job could start.
        s.jobs.check_room().map_err(busy)?;
        let declared = content_length(&headers);
        if declared.is_some_and(|len| len > s.hub.config().max_calibration_bytes) {
            return Err(ApiError::new(
                StatusCode::PAYLOAD_TOO_LARGE,
                format!(
                    "the calibration upload is larger than the limit of {} bytes",
                    s.hub.config().max_calibration_bytes
                ),
            ));
        }
        let ticket = s.admit_upload(declared)?;
        let CalibrationUpload {
            dir,
            request,
            episodes,
            holdout,
            ticket,
        } = receive_calibration(&s, content_type, body, ticket).await?;
        (request, Some((dir, ticket)), episodes, holdout)
    } else {
        let bytes = json_bytes(body, MAX_CALIBRATE_JSON_BYTES).await?;
        let req: CalibrateRequest = json_body(&bytes)?;
        let show = |v: &[PathBuf]| v.iter().map(|p| p.display().to_string()).collect();
        let (e, h) = (show(&req.episodes), show(&req.holdout));
        (req, None, e, h)
    };
    check_calibrate_request(&req)?;
    let job = s.jobs.start(&name, episodes, holdout).map_err(busy)?;
    let id = job.id;
    let shared = s.clone();
    tokio::task::spawn_blocking(move || {
        let result = run_calibration(&shared, &name, &req, &job);
        match &result {
            Ok(_) => {
                shared.profiles.invalidate_profile(&name);
                tracing::info!(job = id, profile = %name, "calibration job succeeded");
            }
            Err(e) => tracing::warn!(job = id, profile = %name, "calibration job failed: {e}"),
        }
        shared.jobs.finish(&job, result);
        // The uploaded episodes go with the job.
        drop(upload);
    });
    Ok((StatusCode::ACCEPTED, Json(json!({ "job": id }))).into_response())
}

async fn list_jobs(State(s): State<Arc<Shared>>) -> Response {
    Json(json!({ "jobs": s.jobs.list() })).into_response()
}

fn job_id(id: &str) -> Result<u64, ApiError> {
    id.parse::<u64>()
        .map_err(|_| ApiError::new(StatusCode::NOT_FOUND, format!("no job {id:?}")))
}

async fn get_job(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
    let jobs = s.clone();
    let job = blocking(move || jobs.jobs.get(id)).await?;
    Ok(Json(job).into_response())
}

/// `DELETE /v1/jobs/{id}`: cancels a running job (202; it stops before its next episode
/// and is then `cancelled`), or removes a finished job's record (204).
async fn delete_job(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
    let jobs = s.clone();
    let cancelled = blocking(move || jobs.jobs.cancel(id)).await?;
    if cancelled {
        return Ok((
            StatusCode::ACCEPTED,
            Json(json!({ "job": id, "cancelling": true })),
        )
            .into_response());
    }
    let jobs = s.clone();
    blocking(move || jobs.jobs.delete(id)).await?;
    Ok(StatusCode::NO_CONTENT.into_response())
}

#[cfg(test)]
mod tests {
    use super::{Access, OPENAPI_JSON, ROUTES, handler};
    use std::collections::BTreeSet;

    #[test]
    fn openapi_describes_exactly_the_routes() {
        let doc: serde_json::Value = serde_json::from_str(OPENAPI_JSON).unwrap();
        assert_eq!(doc["openapi"].as_str().map(|v| &v[..2]), Some("3."));
        let mut described = BTreeSet::new();
        for (path, ops) in doc["paths"].as_object().unwrap() {
            for (method, op) in ops.as_object().unwrap() {
                let method = method.to_ascii_uppercase();
                // The role in the description is the one enforced.
                let role = op.get("x-vamos-role").and_then(|r| r.as_str());
                let access = ROUTES
                    .iter()
                    .find(|(m, p, _)| *m == method && p == path)
                    .map(|r| r.2);
                let expected = match access {
                    Some(Access::Open) => None,
                    Some(Access::Robot) => Some("robot"),
                    Some(Access::Admin) => Some("admin"),
                    None => panic!("{method} {path} is described but not routed"),
                };
                assert_eq!(role, expected, "{method} {path}");
                described.insert((method, path.clone()));
            }
        }
        let routed: BTreeSet<(String, String)> = ROUTES
            .iter()
            .map(|(m, p, _)| (m.to_string(), p.to_string()))
            .collect();
        assert_eq!(routed.len(), ROUTES.len(), "a route is listed twice");
        assert_eq!(described, routed);
    }

    #[test]
    fn every_listed_route_has_a_handler() {
        for (m, p, _) in ROUTES {
            assert!(handler(m, p).is_some(), "{m} {p}");
        }
        assert!(handler("GET", "/v1/nothing").is_none());
    }
}
