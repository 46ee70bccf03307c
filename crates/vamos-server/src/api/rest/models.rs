//! The data directory's models: list, read, upload (validated with ONNX Runtime),
//! delete, and the active version.

use super::body::{blocking, json_body, receive};
use super::errors::ApiError;
use crate::api::state::Shared;
use crate::session::reload::{Reloaded, reload_model_sessions};
use crate::store::{ModelInfo, ModelVersionInfo, UploadKind};
use axum::Json;
use axum::body::{Body, Bytes};
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use std::collections::BTreeMap;
use std::sync::Arc;

/// `GET /v1/models`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ModelList {
    /// The stored models, by name.
    pub models: Vec<ModelInfo>,
}

/// `PUT /v1/models/{name}`: the version stored.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ModelUploaded {
    /// The model's name.
    pub name: String,
    /// Its active version now (a first upload becomes active).
    pub active: Option<u32>,
    /// The new version.
    #[serde(flatten)]
    pub version: ModelVersionInfo,
}

/// `POST /v1/models/{name}/active`: the model, and the sessions moved when asked.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ActiveModel {
    /// The model with its new active version.
    #[serde(flatten)]
    pub model: ModelInfo,
    /// With `reload_sessions`: the sessions moved to the new version.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reloaded_sessions: Option<Vec<String>>,
    /// With `reload_sessions`: the sessions that could not be moved, and why.
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub reload_errors: BTreeMap<String, String>,
}

pub(super) async fn list_models(State(s): State<Arc<Shared>>) -> Result<Json<ModelList>, ApiError> {
    let store = s.store.clone();
    let models = blocking(move || Ok(store.models())).await?;
    Ok(Json(ModelList { models }))
}

pub(super) async fn get_model(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let model = blocking(move || store.model(&name)).await?;
    Ok(Json(model).into_response())
}

/// `PUT /v1/models/{name}`: the body is a model bundle; it becomes the next version once
/// it reads as a bundle and loads with ONNX Runtime.
pub(super) async fn put_model(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    let (upload, _ticket) = receive(&s, UploadKind::Model, &headers, body).await?;
    let store = s.store.clone();
    // Validation loads the model once (one replica, one thread, in a child process with
    // its own memory and time limits) and one upload at a time.
    let validator = s.model_validator.clone();
    let _validating = s.model_validation.lock().await;
    let n = name.clone();
    let (info, active) = blocking(move || {
        let info = store.commit_model(&n, upload, |path| validator.check(path))?;
        let active = store.model(&n)?.active;
        Ok((info, active))
    })
    .await?;
    s.profiles.invalidate_model(&name);
    let body = ModelUploaded {
        name,
        active,
        version: info,
    };
    Ok((StatusCode::CREATED, Json(body)).into_response())
}

pub(super) async fn delete_model(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.delete_model(&n, None)).await?;
    s.profiles.invalidate_model(&name);
    Ok(StatusCode::NO_CONTENT.into_response())
}

pub(super) async fn delete_model_version(
    State(s): State<Arc<Shared>>,
    Path((name, version)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let version: u32 = version
        .parse()
        .map_err(|_| ApiError::bad_request(format!("bad version {version:?}")))?;
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.delete_model(&n, Some(version))).await?;
    s.profiles.invalidate_model(&name);
    Ok(StatusCode::NO_CONTENT.into_response())
}

/// Body of `POST /v1/models/{name}/active`.
#[derive(Debug, serde::Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ActiveRequest {
    /// The version to make active.
    version: u32,
    /// Also move the running sessions whose profile uses this model to the new version
    /// (by default they keep the version they opened with).
    #[serde(default)]
    reload_sessions: bool,
}

pub(super) async fn set_active_model(
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
    let mut body = ActiveModel {
        model,
        reloaded_sessions: None,
        reload_errors: BTreeMap::new(),
    };
    if req.reload_sessions {
        let Reloaded { reloaded, failed } = reload_model_sessions(&s.hub, &s.profiles, &name).await;
        body.reloaded_sessions = Some(reloaded);
        body.reload_errors = failed
            .into_iter()
            .map(|(id, e)| (id, e.to_string()))
            .collect();
    }
    Ok(Json(body).into_response())
}

/// A `POST /v1/models/{name}/active` body, parsed as the handler does (for the fuzz
/// targets).
pub fn parse_active_request(body: &[u8]) -> Result<(), ApiError> {
    json_body::<ActiveRequest>(body).map(|_| ())
}
