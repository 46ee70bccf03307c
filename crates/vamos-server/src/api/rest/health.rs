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

/// KServe-v2-style model readiness: `name` is a profile or model (`name@version` label)
/// that a loaded profile uses, or a stored model whose active version has no problem
/// (every stored version was loaded with ONNX Runtime when it was uploaded, and its
/// checksum verified when the data directory was opened).
pub(super) async fn model_ready(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Response {
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
    let status = if loaded || stored {
        StatusCode::OK
    } else {
        StatusCode::NOT_FOUND
    };
    let ready = ModelReady {
        name,
        version: None,
        ready: loaded || stored,
    };
    (status, Json(ready)).into_response()
}
