//! Sessions: the list, a session moved to its profile as stored now, and the data
//! directory's status.

use super::errors::ApiError;
use crate::api::state::Shared;
use crate::session::reload::reload_session as reload;
use axum::Json;
use axum::extract::{Path, State};
use axum::response::{IntoResponse, Response};
use serde_json::json;
use std::sync::Arc;

pub(super) async fn sessions(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
    Ok(Json(json!({ "sessions": s.hub.sessions() })).into_response())
}

/// The data directory and, in a fleet, the shared store.
pub(super) async fn store_status(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
    Ok(Json(json!({
        "data_dir": s.store.dir(),
        "read_only": s.store.read_only(),
        "problems": s.store.problems().len(),
        "shared_store": s.fleet.as_ref().map(|f| f.status()),
    }))
    .into_response())
}

/// `POST /v1/sessions/{id}/reload`: the session scores with its profile as stored now
/// (a new active model version, new thresholds or calibration) from its next frame; its
/// flow predictor warms up again. `reloaded: false` when nothing changed since it opened.
pub(super) async fn reload_session(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    if s.hub.session(&id).is_none() {
        return Err(ApiError::not_found(format!("no open session {id:?}")));
    }
    let reloaded = reload(&s.hub, &s.profiles, &id).await?;
    let summary = s.hub.session(&id).map(|x| x.summary());
    Ok(Json(json!({
        "reloaded": reloaded.is_some(),
        "session": summary,
    }))
    .into_response())
}
