//! KServe v2 (Open Inference Protocol) metadata: `GET /v2` (server), `GET
//! /v2/models/{name}` and `GET /v2/models/{name}/versions/{version}` (model metadata),
//! `GET /v2/models/{name}/versions/{version}/ready`. The health and model-readiness routes
//! are in `health.rs`.
//!
//! How vamos maps onto a KServe "model" (docs/service-reference.md, "Model serving
//! conventions"):
//! - a **profile** (what a robot session opens) is a model without versions, platform
//!   `vamos_profile`: its inputs are what a robot streams (an encoded camera image and the
//!   joint positions), its outputs what it gets back (the fused score and the alarm);
//! - a **stored model** (a flow-predictor bundle in the data directory) is a model whose
//!   versions are the stored versions, platform `vamos_bundle`: its input is the flow
//!   field the network reads, its output the per-frame score e_o.
//!
//! A name that is both is answered as the profile. vamos scores through its gRPC stream
//! and `POST /v1/episodes:score`, not through KServe's `/infer`; these routes let KServe
//! and Triton tooling discover and probe what is served.

use super::body::blocking;
use super::errors::ApiError;
use super::health::ModelReady;
use crate::api::state::Shared;
use crate::store::{ModelInfo, ModelVersionInfo};
use axum::Json;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use std::sync::Arc;

/// KServe v2 server metadata (`GET /v2`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ServerMetadata {
    /// `vamos`.
    pub name: &'static str,
    /// The server's version.
    pub version: &'static str,
    /// The optional protocol extensions served: none.
    pub extensions: Vec<String>,
}

/// One tensor of KServe v2 model metadata.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct TensorMetadata {
    /// Tensor name.
    pub name: &'static str,
    /// KServe data type (`BYTES`, `FP32`, `FP64`, `BOOL`).
    pub datatype: &'static str,
    /// Shape; -1 for a size that varies.
    pub shape: Vec<i64>,
}

/// KServe v2 model metadata (`GET /v2/models/{name}[/versions/{version}]`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ModelMetadata {
    /// The profile's or stored model's name.
    pub name: String,
    /// Served versions (a profile has none).
    pub versions: Vec<String>,
    /// `vamos_profile` (what a robot streams and gets back) or `vamos_bundle` (a stored
    /// flow-predictor bundle).
    pub platform: &'static str,
    /// Inputs.
    pub inputs: Vec<TensorMetadata>,
    /// Outputs.
    pub outputs: Vec<TensorMetadata>,
}

/// `GET /v2`: server metadata.
pub(super) async fn server_metadata() -> Json<ServerMetadata> {
    Json(ServerMetadata {
        name: "vamos",
        version: env!("CARGO_PKG_VERSION"),
        extensions: Vec::new(),
    })
}

fn tensor(name: &'static str, datatype: &'static str, shape: &[i64]) -> TensorMetadata {
    TensorMetadata {
        name,
        datatype,
        shape: shape.to_vec(),
    }
}

/// Metadata of a profile: a model without versions.
fn profile_metadata(name: &str) -> ModelMetadata {
    ModelMetadata {
        name: name.into(),
        versions: Vec::new(),
        platform: "vamos_profile",
        inputs: vec![
            tensor("image", "BYTES", &[1]),
            tensor("joint_positions", "FP64", &[-1]),
        ],
        outputs: vec![tensor("score", "FP64", &[1]), tensor("alarm", "BOOL", &[1])],
    }
}

/// The stored versions that are served (no checksum or file problem).
fn served(model: &ModelInfo) -> impl Iterator<Item = &ModelVersionInfo> {
    model.versions.iter().filter(|v| v.problem.is_none())
}

/// Metadata of a stored model; `version` narrows `versions` to that one.
fn bundle_metadata(model: &ModelInfo, version: Option<&ModelVersionInfo>) -> ModelMetadata {
    // The network input of the version asked for, else of the active one; the manifest
    // is what the upload's validator recorded.
    let shown = version.or_else(|| {
        model
            .active
            .and_then(|a| served(model).find(|v| v.version == a))
    });
    let input = shown.map(|v| &v.summary["manifest"]["input"]);
    let dim = |key: &str| input.and_then(|i| i[key].as_i64()).unwrap_or(-1);
    let versions: Vec<String> = match version {
        Some(v) => vec![v.version.to_string()],
        None => served(model).map(|v| v.version.to_string()).collect(),
    };
    ModelMetadata {
        name: model.name.clone(),
        versions,
        platform: "vamos_bundle",
        inputs: vec![tensor(
            "flow",
            "FP32",
            &[-1, dim("channels"), dim("size"), dim("size")],
        )],
        outputs: vec![tensor("e_o", "FP32", &[-1])],
    }
}

/// Whether `name` is a profile: a profile file of the configuration or a stored one.
pub(super) async fn is_profile(s: &Arc<Shared>, name: &str) -> bool {
    if s.profiles.is_file(name) {
        return true;
    }
    let store = s.store.clone();
    let n = name.to_string();
    blocking(move || store.profile(&n)).await.is_ok()
}

async fn stored_model(s: &Arc<Shared>, name: &str) -> Result<ModelInfo, ApiError> {
    let store = s.store.clone();
    let n = name.to_string();
    blocking(move || store.model(&n)).await
}

/// `GET /v2/models/{name}`: model metadata (a profile, else a stored model).
pub(super) async fn model_metadata(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    if is_profile(&s, &name).await {
        return Ok(Json(profile_metadata(&name)).into_response());
    }
    let model = stored_model(&s, &name)
        .await
        .map_err(|_| ApiError::not_found(format!("no profile or model named {name:?}")))?;
    Ok(Json(bundle_metadata(&model, None)).into_response())
}

/// The served version `version` of the stored model `name`.
async fn model_version(
    s: &Arc<Shared>,
    name: &str,
    version: &str,
) -> Result<(ModelInfo, u32), ApiError> {
    let missing =
        || ApiError::not_found(format!("model {name:?} has no served version {version:?}"));
    let v: u32 = version.parse().map_err(|_| missing())?;
    let model = stored_model(s, name).await.map_err(|_| missing())?;
    if served(&model).any(|x| x.version == v) {
        Ok((model, v))
    } else {
        Err(missing())
    }
}

/// `GET /v2/models/{name}/versions/{version}`: one stored version's metadata.
pub(super) async fn version_metadata(
    State(s): State<Arc<Shared>>,
    Path((name, version)): Path<(String, String)>,
) -> Result<Response, ApiError> {
    let (model, v) = model_version(&s, &name, &version).await?;
    let info = served(&model).find(|x| x.version == v);
    Ok(Json(bundle_metadata(&model, info)).into_response())
}

/// `GET /v2/models/{name}/versions/{version}/ready`: the version is stored, verified and
/// loadable (every stored version was loaded with ONNX Runtime at upload).
pub(super) async fn version_ready(
    State(s): State<Arc<Shared>>,
    Path((name, version)): Path<(String, String)>,
) -> Response {
    let ready = model_version(&s, &name, &version).await.is_ok();
    let status = if ready {
        StatusCode::OK
    } else {
        StatusCode::NOT_FOUND
    };
    let ready = ModelReady {
        name,
        version: Some(version),
        ready,
    };
    (status, Json(ready)).into_response()
}
