//! Probes, metrics and the API description: `/healthz`, `/readyz`, the KServe-v2
//! health and model-readiness routes, `/metrics`, `/openapi.json`.

use super::openapi;
use crate::api::state::Shared;
use axum::Json;
use axum::extract::{Path, State};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use std::sync::Arc;
use std::sync::atomic::Ordering;

/// What a probe answers.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct Health {
    /// `live` (`/healthz`), `ready` or `not ready` (`/readyz`).
    pub status: &'static str,
}

/// A model's readiness (`GET /v2/models/{name}/ready`; with `version`, also
/// `GET /v2/models/{name}/versions/{version}/ready`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ModelReady {
    /// The name asked for.
    pub name: String,
    /// The version asked for.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub version: Option<String>,
    /// Ready to score.
    pub ready: bool,
}

pub(super) async fn healthz() -> Json<Health> {
    Json(Health { status: "live" })
}

pub(super) async fn readyz(State(s): State<Arc<Shared>>) -> Response {
    if s.ready.load(Ordering::SeqCst) && !*s.stop.borrow() && s.hub.live_workers() > 0 {
        Json(Health { status: "ready" }).into_response()
    } else {
        (
            StatusCode::SERVICE_UNAVAILABLE,
            Json(Health {
                status: "not ready",
            }),
        )
            .into_response()
    }
}

pub(super) async fn metrics(State(s): State<Arc<Shared>>) -> Response {
    (
        [(
            header::CONTENT_TYPE,
            "text/plain; version=0.0.4; charset=utf-8",
        )],
        s.metrics().render(),
    )
        .into_response()
}

pub(super) async fn openapi() -> Response {
    (
        [(header::CONTENT_TYPE, "application/json")],
        openapi::document_json(),
    )
        .into_response()
}

/// KServe-v2 model readiness, for the names `GET /v2/models/{name}` describes: a profile
/// is ready when it loads (robot, camera and model: a stored profile not loaded yet is
/// loaded here, as the first session would), a stored model when its active version has no
/// problem (every stored version was loaded with ONNX Runtime when it was uploaded, and
/// its checksum verified when the data directory was opened). 200 when ready, 503 for a
/// known name that is not, 404 for an unknown one.
pub(super) async fn model_ready(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Response {
    let (known, ready) = if super::kserve::is_profile(&s, &name).await {
        (true, s.profiles.get_async(&name).await.is_ok())
    } else {
        match s.store.model(&name) {
            Ok(m) => (
                true,
                m.active.is_some_and(|v| {
                    m.versions
                        .iter()
                        .any(|x| x.version == v && x.problem.is_none())
                }),
            ),
            Err(_) => (false, false),
        }
    };
    let status = match (known, ready) {
        (_, true) => StatusCode::OK,
        (true, false) => StatusCode::SERVICE_UNAVAILABLE,
        (false, _) => StatusCode::NOT_FOUND,
    };
    let ready = ModelReady {
        name,
        version: None,
        ready,
    };
    (status, Json(ready)).into_response()
}
