//! The data directory's robots: list, read, upload (URDF or package archive), delete.

use super::body::{ApiQuery, blocking, receive};
use super::errors::ApiError;
use crate::api::state::Shared;
use crate::store::{RobotFormat, RobotInfo, UploadKind, robot_summary};
use axum::Json;
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use std::sync::Arc;

/// `GET /v1/robots`.
#[derive(Debug, serde::Serialize, schemars::JsonSchema)]
pub struct RobotList {
    /// The stored robots, by name.
    pub robots: Vec<RobotInfo>,
}

pub(super) async fn list_robots(State(s): State<Arc<Shared>>) -> Result<Json<RobotList>, ApiError> {
    let store = s.store.clone();
    let robots = blocking(move || Ok(store.robots())).await?;
    Ok(Json(RobotList { robots }))
}

pub(super) async fn get_robot(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let robot = blocking(move || store.robot(&name)).await?;
    Ok(Json(robot).into_response())
}

/// Query of `PUT /v1/robots/{name}`.
#[derive(Debug, serde::Deserialize, schemars::JsonSchema)]
pub struct RobotQuery {
    /// How the body is packed: `urdf` (one URDF file; its meshes must be inline or
    /// absent), `tar.gz` (or `tgz`) or `zip` (a package: a URDF and its meshes).
    /// Absent: told from the Content-Type (`application/xml`, `application/gzip`,
    /// `application/zip`).
    #[serde(default)]
    format: Option<String>,
}

/// The package format: `?format=urdf|tar.gz|tgz|zip`, else the Content-Type.
pub(super) fn robot_format(q: &RobotQuery, headers: &HeaderMap) -> Result<RobotFormat, ApiError> {
    if let Some(f) = &q.format {
        return match f.to_ascii_lowercase().as_str() {
            "urdf" => Ok(RobotFormat::Urdf),
            "tar.gz" | "tgz" => Ok(RobotFormat::TarGz),
            "zip" => Ok(RobotFormat::Zip),
            other => Err(ApiError::bad_request(format!(
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
        _ => Err(ApiError::bad_request(format!(
            "cannot tell the robot format from Content-Type {ctype:?}: use ?format=urdf|tar.gz|zip"
        ))),
    }
}

/// `PUT /v1/robots/{name}`: the body is a URDF file or a robot package archive.
pub(super) async fn put_robot(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    ApiQuery(q): ApiQuery<RobotQuery>,
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

pub(super) async fn delete_robot(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let store = s.store.clone();
    let n = name.clone();
    blocking(move || store.delete_robot(&n)).await?;
    s.profiles.invalidate_robot(&name);
    Ok(StatusCode::NO_CONTENT.into_response())
}
