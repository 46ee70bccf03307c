//! Sessions: the list, a session moved to its profile as stored now, and the data
//! directory's status.

use super::errors::ApiError;
use crate::api::state::Shared;
use crate::session::SessionSummary;
use crate::session::fleet::FleetStatus;
use crate::session::reload::reload_session as reload;
use axum::Json;
use axum::extract::{Path, State};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;

/// `GET /v1/sessions`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct SessionList {
    /// The open sessions (streaming, detached or scoring an episode).
    pub sessions: Vec<SessionSummary>,
}

/// `GET /v1/store`: the data directory and, in a fleet, the shared store.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct StoreStatus {
    /// The data directory.
    pub data_dir: PathBuf,
    /// Why changes are refused (uploads, profile and threshold changes), if they are.
    pub read_only: Option<String>,
    /// Problems found when it was opened (objects not served).
    pub problems: usize,
    /// The shared store of a fleet (absent: this server is alone).
    pub shared_store: Option<FleetStatus>,
}

/// `POST /v1/sessions/{id}/reload`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct SessionReloaded {
    /// Whether anything changed since the session opened (`false`: it goes on as it was).
    pub reloaded: bool,
    /// The session now.
    pub session: Option<SessionSummary>,
}

pub(super) async fn sessions(State(s): State<Arc<Shared>>) -> Json<SessionList> {
    Json(SessionList {
        sessions: s.hub.sessions(),
    })
}

/// The data directory and, in a fleet, the shared store.
pub(super) async fn store_status(State(s): State<Arc<Shared>>) -> Json<StoreStatus> {
    Json(StoreStatus {
        data_dir: s.store.dir().to_path_buf(),
        read_only: s.store.read_only(),
        problems: s.store.problems().len(),
        shared_store: s.fleet.as_ref().map(|f| f.status()),
    })
}

/// `POST /v1/sessions/{id}/reload`: the session scores with its profile as stored now
/// (a new active model version, new thresholds or calibration) from its next frame; its
/// flow predictor warms up again. `reloaded: false` when nothing changed since it opened.
pub(super) async fn reload_session(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
) -> Result<Json<SessionReloaded>, ApiError> {
    if s.hub.session(&id).is_none() {
        return Err(ApiError::not_found(format!("no open session {id:?}")));
    }
    let reloaded = reload(&s.hub, &s.profiles, &id).await?;
    let summary = s.hub.session(&id).map(|x| x.summary());
    Ok(Json(SessionReloaded {
        reloaded: reloaded.is_some(),
        session: summary,
    }))
}
