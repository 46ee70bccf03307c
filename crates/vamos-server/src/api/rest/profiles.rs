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
use serde::Serialize;
use std::sync::Arc;
use vamos_core::eval::Thresholds;
use vamos_core::pipeline::Calibration;

/// Where a profile comes from.
#[derive(Debug, Clone, Copy, Serialize, schemars::JsonSchema)]
#[serde(rename_all = "lowercase")]
pub enum ProfileSource {
    /// A profile file of the server's settings (read only through the API, except its
    /// calibration, which the service keeps in the data directory; it shadows a stored
    /// profile of the same name).
    File,
    /// The data directory.
    Store,
}

/// A profile as the REST API shows it.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ProfileView {
    /// Name.
    pub name: String,
    /// Where it comes from.
    pub source: ProfileSource,
    /// The flow-predictor model it scores with (`name@version`), or `none`.
    pub model: String,
    /// It names a robot (the camera and body detectors can run).
    pub robot: bool,
    /// It has a calibration.
    pub calibrated: bool,
    /// Where the calibration in force is kept: `file` (beside a profile file) or `store`
    /// (the data directory: a stored profile's, or one the service made for a profile
    /// file, which replaces the file's own). `null`: not calibrated.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub calibration_source: Option<ProfileSource>,
    /// The fused-score alarm threshold in force (`null`: no alarms).
    pub alarm_threshold: Option<f64>,
    /// The stored profile (stored profiles only). In `GET /v1/profiles` its thresholds'
    /// bulky statistics are summarised by their sizes.
    #[serde(skip_serializing_if = "Option::is_none")]
    #[schemars(with = "Option<ProfileInfo>")]
    pub profile: Option<serde_json::Value>,
    /// `PUT` only: why the stored profile does not load (robot, camera or model missing
    /// or wrong); it is stored anyway.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub load_error: Option<String>,
}

/// `GET /v1/profiles`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct ProfileList {
    /// The profile files, then the stored profiles they do not shadow.
    pub profiles: Vec<ProfileView>,
}

pub(super) fn file_profile_view(p: &LoadedProfile) -> ProfileView {
    ProfileView {
        name: p.name.clone(),
        source: ProfileSource::File,
        model: p.model_label.clone(),
        robot: p.setup.robot.is_some(),
        calibrated: p.setup.profile.calibration.is_some(),
        calibration_source: p.setup.profile.calibration.as_ref().map(|_| {
            if p.calibration_stored {
                ProfileSource::Store
            } else {
                ProfileSource::File
            }
        }),
        alarm_threshold: finite(p.setup.profile.alarm_threshold()),
        profile: None,
        load_error: None,
    }
}

/// What a list leaves out of a calibration: the scene residual's and the flow error's
/// per-cell statistics (tens of kB) and the kinematic novelty's nominal states (up to about 1 MB) become
/// their sizes. `GET /v1/profiles/{name}` and `GET /v1/jobs/{id}` give them whole.
const LEFT_OUT: &str = "left out of lists; GET the profile or job itself for the values";

/// The JSON of `value`, whose `thresholds` and `calibration.thresholds` are `thresholds`
/// and `calibration`'s, with their bulky statistics summarised ([`LEFT_OUT`]).
pub(super) fn summarised(
    value: &impl Serialize,
    thresholds: Option<&Thresholds>,
    calibration: Option<&Calibration>,
) -> Result<serde_json::Value, ApiError> {
    let internal = |e: serde_json::Error| ApiError::internal(format!("summary: {e}"));
    let mut v = serde_json::to_value(value).map_err(internal)?;
    if let Some(t) = thresholds {
        v["thresholds"] = t.summarised_json(LEFT_OUT).map_err(internal)?;
    }
    if let Some(c) = calibration {
        v["calibration"]["thresholds"] =
            c.thresholds.summarised_json(LEFT_OUT).map_err(internal)?;
    }
    Ok(v)
}

/// A stored profile's view; `summary`: its statistics summarised, as lists show them.
pub(super) fn stored_profile_view(
    s: &Shared,
    info: &ProfileInfo,
    summary: bool,
) -> Result<ProfileView, ApiError> {
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
    let profile = if summary {
        summarised(info, Some(&info.thresholds), info.calibration.as_ref())?
    } else {
        serde_json::to_value(info).map_err(|e| ApiError::internal(format!("profile: {e}")))?
    };
    Ok(ProfileView {
        name: info.name.clone(),
        source: ProfileSource::Store,
        model,
        robot: info.spec.robot.is_some(),
        calibrated: info.calibration.is_some(),
        calibration_source: info.calibration.as_ref().map(|_| ProfileSource::Store),
        alarm_threshold: info.alarm_threshold,
        profile: Some(profile),
        load_error: None,
    })
}

/// `GET /v1/profiles`: the profile files, then the stored profiles they do not shadow
/// (their bulky calibration statistics summarised, [`summarised`]).
pub(super) async fn profiles(State(s): State<Arc<Shared>>) -> Result<Json<ProfileList>, ApiError> {
    let mut list: Vec<_> = s
        .profiles
        .loaded()
        .iter()
        .filter(|p| s.profiles.is_file(&p.name))
        .map(|p| file_profile_view(p))
        .collect();
    list.sort_by(|a, b| a.name.cmp(&b.name));
    let store = s.store.clone();
    let stored = blocking(move || Ok(store.profiles())).await?;
    for p in stored.iter().filter(|p| !s.profiles.is_file(&p.name)) {
        list.push(stored_profile_view(&s, p, true)?);
    }
    Ok(Json(ProfileList { profiles: list }))
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
) -> Result<Json<ProfileView>, ApiError> {
    if let Some(p) = s
        .profiles
        .get_cached(&name)
        .filter(|_| s.profiles.is_file(&name))
    {
        return Ok(Json(file_profile_view(&p)));
    }
    let store = s.store.clone();
    let info = blocking(move || store.profile(&name)).await?;
    Ok(Json(stored_profile_view(&s, &info, false)?))
}

/// `PUT /v1/profiles/{name}`: stores the profile, then loads it (robot, camera, model) so
/// the first session does not wait; a profile that does not load is stored anyway and
/// the answer says why (`load_error`).
pub(super) async fn put_profile(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    body: Bytes,
) -> Result<Json<ProfileView>, ApiError> {
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
    let mut body = stored_profile_view(&s, &info, false)?;
    body.load_error = load_error;
    Ok(Json(body))
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
) -> Result<Json<ProfileView>, ApiError> {
    refuse_file_profile(&s, &name)?;
    let patch: ThresholdsPatch = json_body(&body)?;
    let store = s.store.clone();
    let n = name.clone();
    let info = blocking(move || store.patch_thresholds(&n, patch)).await?;
    s.profiles.invalidate_profile(&name);
    Ok(Json(stored_profile_view(&s, &info, false)?))
}
