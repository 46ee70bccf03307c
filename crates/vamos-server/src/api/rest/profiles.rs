//! Profiles: the profile files and the data directory's profiles; stored ones can be
//! written, deleted and their thresholds patched.

use super::body::{blocking, json_body};
use super::errors::ApiError;
use crate::api::state::Shared;
use crate::session::LoadedProfile;
use crate::store::{ProfileInfo, ProfileSpec, ThresholdsPatch};
use axum::Json;
use axum::body::Bytes;
use axum::extract::{Path, State};
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};
use serde_json::json;
use std::sync::Arc;

pub(super) fn file_profile_json(p: &LoadedProfile) -> serde_json::Value {
    json!({
        "name": p.name,
        "source": "file",
        "model": p.model_label,
        "robot": p.setup.robot.is_some(),
        "calibrated": p.setup.profile.calibration.is_some(),
        "alarm_threshold": finite(p.setup.profile.alarm_threshold()),
    })
}

/// What a list leaves out of a calibration: the scene residual's and the flow error's
/// per-cell statistics (tens of kB) and the kinematic novelty's nominal states (up to about 1 MB) become
/// their sizes. `GET /v1/profiles/{name}` and `GET /v1/jobs/{id}` give them whole.
const LEFT_OUT: &str = "left out of lists; GET the profile or job itself for the values";

/// Replaces the bulky parts of a serialised `Thresholds` by their sizes (see [`LEFT_OUT`]).
fn summarise_thresholds(thresholds: &mut serde_json::Value) {
    for (key, sizes) in [
        ("scene", &["columns", "rows", "maps"][..]),
        ("flow", &["columns", "rows", "maps"][..]),
        ("kinematics", &["dims", "count"][..]),
    ] {
        if let Some(part) = thresholds.get_mut(key).filter(|v| v.is_object()) {
            let mut summary = serde_json::Map::new();
            for size in sizes {
                if let Some(n) = part.get(*size) {
                    summary.insert((*size).into(), n.clone());
                }
            }
            if let Some(windows) = part.pointer("/phases/location").and_then(|l| l.as_array()) {
                summary.insert("phase_windows".into(), windows.len().into());
            }
            summary.insert("detail".into(), LEFT_OUT.into());
            *part = summary.into();
        }
    }
}

/// The list form of a serialised object holding `thresholds` and/or
/// `calibration.thresholds` (a stored profile, a job): bulky statistics summarised.
pub(super) fn summarised(mut v: serde_json::Value) -> serde_json::Value {
    for path in ["/thresholds", "/calibration/thresholds"] {
        if let Some(t) = v.pointer_mut(path) {
            summarise_thresholds(t);
        }
    }
    v
}

pub(super) fn stored_profile_json(s: &Shared, info: &ProfileInfo) -> serde_json::Value {
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

/// `GET /v1/profiles`: the profile files, then the stored profiles they do not shadow
/// (their bulky calibration statistics summarised, [`summarised`]).
pub(super) async fn profiles(State(s): State<Arc<Shared>>) -> Result<Response, ApiError> {
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
            .map(|p| {
                let mut v = stored_profile_json(&s, p);
                if let Some(profile) = v.get_mut("profile") {
                    *profile = summarised(profile.take());
                }
                v
            }),
    );
    Ok(Json(json!({ "profiles": list })).into_response())
}

pub(super) fn finite(v: f64) -> Option<f64> {
    v.is_finite().then_some(v)
}

pub(super) fn refuse_file_profile(s: &Shared, name: &str) -> Result<(), ApiError> {
    if s.profiles.is_file(name) {
        return Err(ApiError::conflict(format!(
            "profile {name:?} is a profile file of the server's settings, which takes priority; it cannot be changed through the API"
        )));
    }
    Ok(())
}

pub(super) async fn get_profile(
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
pub(super) async fn put_profile(
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

pub(super) async fn delete_profile(
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

pub(super) async fn patch_thresholds(
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
