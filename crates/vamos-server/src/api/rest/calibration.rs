//! Calibration jobs: started with episodes on the server (JSON) or uploaded
//! (`multipart/form-data`), listed, read, cancelled and removed.

use super::body::{
    BROKEN_MULTIPART, DRAIN_LIMIT_BYTES, blocking, content_length, drain, json_body, json_bytes,
};
use super::errors::ApiError;
use crate::api::state::Shared;
use crate::session::SessionError;
use crate::session::budget::UploadTicket;
use crate::session::calibration::{CalibrationRequest, NominalEpisode, nominal_set};
use crate::session::upload::decompress_in_place;
use crate::store::JobInfo;
use axum::Json;
use axum::body::Body;
use axum::extract::{Path, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::response::{IntoResponse, Response};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;

/// A job started (`202`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct JobStarted {
    /// Its id: `GET /v1/jobs/{id}` follows it.
    pub job: u64,
}

/// `DELETE /v1/jobs/{id}` of a running job (`202`).
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct JobCancelling {
    /// Its id.
    pub job: u64,
    /// Always `true`: it stops before its next episode and is then `cancelled`.
    pub cancelling: bool,
}

/// `GET /v1/jobs`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct JobList {
    /// Every job, oldest first; the calibrations' bulky statistics summarised by their
    /// sizes (`GET /v1/jobs/{id}` gives them whole).
    #[schemars(with = "Vec<JobInfo>")]
    pub jobs: Vec<serde_json::Value>,
}

/// `GET /v1/profiles/{name}/nominal`.
#[derive(Debug, Serialize, schemars::JsonSchema)]
pub struct NominalList {
    /// The profile's nominal set, oldest mark first.
    pub episodes: Vec<NominalEpisode>,
}

/// Largest JSON calibration request (paths on the server), bytes.
const MAX_CALIBRATE_JSON_BYTES: usize = 1 << 20;

/// A JSON calibration body, parsed and checked as `POST /v1/profiles/{name}/calibrate`
/// does before it starts a job (for the fuzz targets).
pub fn parse_calibrate_request(body: &[u8]) -> Result<(), ApiError> {
    let req: CalibrationRequest = json_body(body)?;
    Ok(req.check()?)
}

/// Episodes uploaded with a calibration request, in a temporary folder of the upload
/// directory that is removed when the job ends (and, after a crash, when the store
/// opens).
pub(super) struct CalibrationUpload {
    dir: tempfile::TempDir,
    request: CalibrationRequest,
    episodes: Vec<String>,
    holdout: Vec<String>,
    /// The upload's slot and disk, held as long as the files.
    ticket: UploadTicket,
}

/// A part's file name as a safe episode file name (`[A-Za-z0-9._-]`, ending in `.mcap`);
/// the episode is named after its stem, as on the command line.
pub(super) fn episode_file_name(raw: Option<&str>, index: usize) -> String {
    let base = raw
        .and_then(|n| n.rsplit(['/', '\\']).next())
        .unwrap_or("")
        .trim_end_matches(".zstd")
        .trim_end_matches(".zst")
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
pub(super) async fn receive_calibration(
    s: &Shared,
    content_type: &str,
    body: Body,
    ticket: UploadTicket,
) -> Result<CalibrationUpload, ApiError> {
    let boundary = multer::parse_boundary(content_type)
        .map_err(|e| ApiError::bad_request(format!("bad multipart content type: {e}")))?;
    let cfg = s.hub.config();
    let (per_file, total_limit) = (cfg.max_episode_bytes, cfg.max_calibration_bytes);
    let dir = tempfile::Builder::new()
        .prefix("calibrate-")
        .tempdir_in(s.upload_dir())
        .map_err(ApiError::internal)?;
    for sub in ["episodes", "holdout"] {
        std::fs::create_dir(dir.path().join(sub)).map_err(ApiError::internal)?;
    }
    let mut multipart = multer::Multipart::new(body.into_data_stream(), boundary);
    match read_calibration_parts(
        &mut multipart,
        dir.path(),
        per_file,
        total_limit,
        s.settings.episode.max_decompressed_bytes,
        ticket,
    )
    .await
    {
        Ok((request, episodes, holdout, ticket)) => Ok(CalibrationUpload {
            dir,
            request,
            episodes,
            holdout,
            ticket,
        }),
        Err(e) => {
            // A request refused for what it says (not for its size or a broken body):
            // read the rest, so the connection stays usable for the client's next call.
            if e.is_bad_request() && !e.message.starts_with(BROKEN_MULTIPART) {
                drain(&mut multipart, DRAIN_LIMIT_BYTES).await;
            }
            Err(e)
        }
    }
}

/// The parts of a calibration upload, each file written into `dir`.
pub(super) async fn read_calibration_parts(
    multipart: &mut multer::Multipart<'_>,
    dir: &std::path::Path,
    per_file: u64,
    total_limit: u64,
    decompress_limit: u64,
    mut ticket: UploadTicket,
) -> Result<(CalibrationRequest, Vec<String>, Vec<String>, UploadTicket), ApiError> {
    use tokio::io::AsyncWriteExt;
    let mut request = CalibrationRequest::default();
    let (mut episodes, mut holdout) = (Vec::new(), Vec::new());
    let mut total = 0u64;
    let part_error = |e: multer::Error| ApiError::bad_request(format!("{BROKEN_MULTIPART}: {e}"));
    let mut index = 0;
    while let Some(mut field) = multipart.next_field().await.map_err(part_error)? {
        let part = field.name().unwrap_or("").to_string();
        let (paths, names) = match part.as_str() {
            "episodes" => (&mut request.episodes, &mut episodes),
            "holdout" => (&mut request.holdout, &mut holdout),
            "alpha" => {
                let text = field.text().await.map_err(part_error)?;
                request.alpha = text.trim().parse().map_err(|_| {
                    ApiError::bad_request(format!("alpha {text:?} is not a number"))
                })?;
                continue;
            }
            other => {
                return Err(ApiError::bad_request(format!(
                    "unknown part {other:?}: expected files `episodes` and `holdout`, text `alpha`"
                )));
            }
        };
        index += 1;
        let file_name = episode_file_name(field.file_name(), index);
        if names.contains(&file_name) {
            return Err(ApiError::bad_request(format!(
                "two `{part}` files are named {file_name:?}: episodes are told apart by name"
            )));
        }
        let path = dir.join(&part).join(&file_name);
        let mut file = tokio::fs::File::create(&path)
            .await
            .map_err(ApiError::internal)?;
        let mut size = 0u64;
        while let Some(chunk) = field.chunk().await.map_err(part_error)? {
            size += chunk.len() as u64;
            total += chunk.len() as u64;
            if size > per_file {
                return Err(ApiError::too_large(format!(
                    "episode {file_name:?} is larger than the limit of {per_file} bytes"
                )));
            }
            if total > total_limit {
                return Err(ApiError::too_large(format!(
                    "the calibration upload is larger than the limit of {total_limit} bytes"
                )));
            }
            ticket.received(total).map_err(SessionError::from)?;
            ticket.written(total).map_err(SessionError::from)?;
            file.write_all(&chunk).await.map_err(ApiError::internal)?;
        }
        file.flush().await.map_err(ApiError::internal)?;
        drop(file);
        if size == 0 {
            return Err(ApiError::bad_request(format!(
                "episode {file_name:?} is empty"
            )));
        }
        // A `.mcap.zstd` episode is decompressed here, its copy charged to the upload like
        // its bytes (the job then reads the copy; nothing is decompressed outside the
        // upload's disk budget).
        let (returned, decompressed) = {
            let path = path.clone();
            tokio::task::spawn_blocking(move || {
                let r = decompress_in_place(&path, decompress_limit, &mut ticket, total);
                (ticket, r)
            })
            .await
            .map_err(ApiError::internal)?
        };
        ticket = returned;
        if let Some(copy) = decompressed? {
            total = total - size + copy;
            ticket.holds(total).map_err(ApiError::too_many)?;
        }
        paths.push(path);
        names.push(file_name);
    }
    Ok((request, episodes, holdout, ticket))
}

/// `POST /v1/profiles/{name}/calibrate`: starts a calibration job (202 `{"job": id}`)
/// over episodes on the server (JSON body) or uploaded with the request
/// (`multipart/form-data`).
pub(super) async fn start_calibration(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
    headers: HeaderMap,
    body: Body,
) -> Result<Response, ApiError> {
    // A profile file's calibration is kept in the data directory (the file is not
    // written); a stored profile must exist.
    if !s.profiles.is_file(&name) {
        let store = s.store.clone();
        let n = name.clone();
        blocking(move || store.profile(&n)).await?;
    }
    let content_type = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .unwrap_or("");
    let (req, upload, episodes, holdout) = if content_type
        .to_ascii_lowercase()
        .starts_with("multipart/form-data")
    {
        // Refused before the episodes are read when no job could start.
        s.jobs.check_room()?;
        let declared = content_length(&headers);
        if declared.is_some_and(|len| len > s.hub.config().max_calibration_bytes) {
            return Err(ApiError::too_large(format!(
                "the calibration upload is larger than the limit of {} bytes",
                s.hub.config().max_calibration_bytes
            )));
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
        let req: CalibrationRequest = json_body(&bytes)?;
        let show = |v: &[PathBuf]| v.iter().map(|p| p.display().to_string()).collect();
        let (e, h) = (show(&req.episodes), show(&req.holdout));
        (req, None, e, h)
    };
    req.check()?;
    let id = s.calibrator().start(name, req, episodes, holdout, upload)?;
    Ok((StatusCode::ACCEPTED, Json(JobStarted { job: id })).into_response())
}

/// `GET /v1/jobs`: every job, oldest first, the calibrations' bulky statistics
/// summarised (`GET /v1/jobs/{id}` gives them whole).
pub(super) async fn list_jobs(State(s): State<Arc<Shared>>) -> Result<Json<JobList>, ApiError> {
    let jobs = s
        .jobs
        .list()
        .iter()
        .map(|job| super::profiles::summarised(job, None, job.calibration.as_ref()))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(Json(JobList { jobs }))
}

pub(super) fn job_id(id: &str) -> Result<u64, ApiError> {
    id.parse::<u64>()
        .map_err(|_| ApiError::not_found(format!("no job {id:?}")))
}

pub(super) async fn get_job(
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
pub(super) async fn delete_job(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
    let jobs = s.clone();
    let cancelled = blocking(move || jobs.jobs.cancel(id)).await?;
    if cancelled {
        let body = JobCancelling {
            job: id,
            cancelling: true,
        };
        return Ok((StatusCode::ACCEPTED, Json(body)).into_response());
    }
    let jobs = s.clone();
    blocking(move || jobs.jobs.delete(id)).await?;
    Ok(StatusCode::NO_CONTENT.into_response())
}

/// `GET /v1/profiles/{name}/nominal`: the profile's nominal set, the kept recordings of
/// sessions with an alarm marked as a false alarm.
pub(super) async fn nominal(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let (store, dir) = (s.store.clone(), s.hub.recordings_dir());
    let episodes = blocking(move || nominal_set(&store, &dir, &name)).await?;
    Ok(Json(NominalList { episodes }).into_response())
}

/// `POST /v1/profiles/{name}/recalibrate`: starts a recalibration from the profile's
/// nominal set (202 `{"job": id}`); its proposal is in the job's record once it succeeds.
pub(super) async fn start_recalibration(
    State(s): State<Arc<Shared>>,
    Path(name): Path<String>,
) -> Result<Response, ApiError> {
    let calibrator = s.calibrator();
    let dir = s.hub.recordings_dir();
    let handle = tokio::runtime::Handle::current();
    let id = tokio::task::spawn_blocking(move || {
        let _runtime = handle.enter();
        calibrator.recalibrate(name, &dir)
    })
    .await
    .map_err(ApiError::internal)??;
    Ok((StatusCode::ACCEPTED, Json(JobStarted { job: id })).into_response())
}

/// `POST /v1/jobs/{id}/apply`: applies a finished recalibration's proposal (200, the job).
pub(super) async fn apply_job(
    State(s): State<Arc<Shared>>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id = job_id(&id)?;
    let calibrator = s.calibrator();
    let job = tokio::task::spawn_blocking(move || calibrator.apply(id))
        .await
        .map_err(ApiError::internal)??;
    Ok(Json(job).into_response())
}
