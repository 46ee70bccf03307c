//! Errors as HTTP answers: a status and a JSON body `{"error": message}`. The one
//! mapping of the session layer's, the data directory's, the jobs' and the token
//! check's errors to statuses; handlers name an error, never a status.

use crate::api::auth::AuthError;
use crate::session::budget::UploadRefused;
use crate::session::calibration::{CalibrationRefused, RecalibrationRefused};
use crate::session::jobs::JobError;
use crate::session::{ProfileLookupError, SessionError};
use crate::store::{StoreError, StoreErrorKind};
use axum::Json;
use axum::http::StatusCode;
use axum::response::{IntoResponse, Response};

/// An error answer: a status and a JSON body `{"error": message}`.
#[derive(Debug)]
pub struct ApiError {
    /// HTTP status.
    pub status: StatusCode,
    /// What went wrong.
    pub message: String,
}

impl ApiError {
    /// An error with `status`.
    pub fn new(status: StatusCode, message: impl Into<String>) -> Self {
        Self {
            status,
            message: message.into(),
        }
    }

    /// 400: a request refused for what it says.
    pub fn bad_request(e: impl std::fmt::Display) -> Self {
        Self::new(StatusCode::BAD_REQUEST, e.to_string())
    }

    /// 404: nothing of that name.
    pub fn not_found(e: impl std::fmt::Display) -> Self {
        Self::new(StatusCode::NOT_FOUND, e.to_string())
    }

    /// 409: in conflict with the server's state.
    pub fn conflict(e: impl std::fmt::Display) -> Self {
        Self::new(StatusCode::CONFLICT, e.to_string())
    }

    /// 413: a body over a limit.
    pub fn too_large(e: impl std::fmt::Display) -> Self {
        Self::new(StatusCode::PAYLOAD_TOO_LARGE, e.to_string())
    }

    /// 429: no room now; retry later.
    pub fn too_many(e: impl std::fmt::Display) -> Self {
        Self::new(StatusCode::TOO_MANY_REQUESTS, e.to_string())
    }

    /// 500: the server failed.
    pub fn internal(e: impl std::fmt::Display) -> Self {
        Self::new(StatusCode::INTERNAL_SERVER_ERROR, e.to_string())
    }

    /// Whether the request was refused for what it says (400).
    pub fn is_bad_request(&self) -> bool {
        self.status == StatusCode::BAD_REQUEST
    }

    /// Whether the server's disk is full (507).
    pub fn is_storage_full(&self) -> bool {
        self.status == StatusCode::INSUFFICIENT_STORAGE
    }
}

impl IntoResponse for ApiError {
    fn into_response(self) -> Response {
        let body = ErrorBody {
            error: self.message,
        };
        (self.status, Json(body)).into_response()
    }
}

/// The body of every error answer.
#[derive(Debug, serde::Serialize, schemars::JsonSchema)]
pub struct ErrorBody {
    /// What went wrong.
    pub error: String,
}

impl From<AuthError> for ApiError {
    fn from(e: AuthError) -> Self {
        let status = match e {
            AuthError::Forbidden { .. } => StatusCode::FORBIDDEN,
            _ => StatusCode::UNAUTHORIZED,
        };
        Self::new(status, e.to_string())
    }
}

/// The status of a session error.
fn status_of(e: &SessionError) -> StatusCode {
    use SessionError as E;
    match e {
        E::Upload(UploadRefused::TooSlow { .. }) => StatusCode::REQUEST_TIMEOUT,
        E::TooMany { .. } | E::OverCapacity(_) | E::Upload(_) => StatusCode::TOO_MANY_REQUESTS,
        E::EpisodeTooLarge { .. } | E::MessageTooLarge { .. } => StatusCode::PAYLOAD_TOO_LARGE,
        E::Busy { .. } | E::Reload { .. } => StatusCode::CONFLICT,
        E::RobotNotAllowed { .. } | E::NotYours { .. } => StatusCode::FORBIDDEN,
        E::ProfileMismatch { .. }
        | E::BadId(_)
        | E::BadLabel { .. }
        | E::BadCamera { .. }
        | E::OpenExpected
        | E::SecondOpen
        | E::NoChunk
        | E::NotAnEpisode { .. }
        | E::Scorer { .. }
        | E::Closed { .. } => StatusCode::BAD_REQUEST,
        // A profile that does not resolve or load cannot score: no such scoring profile.
        E::Profile(
            ProfileLookupError::NotFound { .. }
            | ProfileLookupError::Load { .. }
            | ProfileLookupError::Store { .. },
        ) => StatusCode::NOT_FOUND,
        E::ShuttingDown => StatusCode::SERVICE_UNAVAILABLE,
        E::NoOpen | E::TooOld { .. } | E::Idle { .. } => StatusCode::REQUEST_TIMEOUT,
        E::Damaged { .. } => StatusCode::UNPROCESSABLE_ENTITY,
        E::Buffer { .. } | E::Internal(_) => StatusCode::INTERNAL_SERVER_ERROR,
        E::UnknownSession { .. } | E::UnknownAlarm { .. } => StatusCode::NOT_FOUND,
        E::AlarmMarked { .. } => StatusCode::CONFLICT,
        E::BadNote { .. } => StatusCode::BAD_REQUEST,
        E::Store { source } => store_status(source),
    }
}

/// The status of a data-directory error.
fn store_status(e: &StoreError) -> StatusCode {
    match e.kind() {
        StoreErrorKind::NotFound => StatusCode::NOT_FOUND,
        StoreErrorKind::BadRequest => StatusCode::BAD_REQUEST,
        StoreErrorKind::TooLarge => StatusCode::PAYLOAD_TOO_LARGE,
        StoreErrorKind::Conflict => StatusCode::CONFLICT,
        StoreErrorKind::StorageFull => StatusCode::INSUFFICIENT_STORAGE,
        StoreErrorKind::Internal => StatusCode::INTERNAL_SERVER_ERROR,
    }
}

impl From<SessionError> for ApiError {
    fn from(e: SessionError) -> Self {
        Self::new(status_of(&e), e.to_string())
    }
}

impl From<StoreError> for ApiError {
    fn from(e: StoreError) -> Self {
        Self::new(store_status(&e), e.to_string())
    }
}

impl From<JobError> for ApiError {
    fn from(e: JobError) -> Self {
        match e {
            JobError::Busy { .. } => Self::too_many(e),
            JobError::Store(e) => e.into(),
        }
    }
}

impl From<RecalibrationRefused> for ApiError {
    fn from(e: RecalibrationRefused) -> Self {
        use RecalibrationRefused as R;
        match e {
            R::Profile(p) => SessionError::Profile(p).into(),
            R::Job(j) => j.into(),
            R::Store(s) => s.into(),
            R::NotCalibrated { .. }
            | R::NoNominalEpisodes { .. }
            | R::NotAProposal { .. }
            | R::Applied { .. }
            | R::Stale { .. } => Self::conflict(e),
        }
    }
}

impl From<CalibrationRefused> for ApiError {
    fn from(e: CalibrationRefused) -> Self {
        Self::bad_request(e)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_errors_map_to_the_statuses_of_the_rest_api() {
        let cases = [
            (
                SessionError::TooMany { max: 2 },
                StatusCode::TOO_MANY_REQUESTS,
            ),
            (
                SessionError::EpisodeTooLarge { limit: 9 },
                StatusCode::PAYLOAD_TOO_LARGE,
            ),
            (SessionError::ShuttingDown, StatusCode::SERVICE_UNAVAILABLE),
            (SessionError::NoChunk, StatusCode::BAD_REQUEST),
            (
                SessionError::Profile(ProfileLookupError::NotFound { name: "p".into() }),
                StatusCode::NOT_FOUND,
            ),
            (
                SessionError::Reload {
                    source: Box::new(SessionError::Closed { id: "s".into() }),
                },
                StatusCode::CONFLICT,
            ),
        ];
        for (e, status) in cases {
            let text = e.to_string();
            let answer = ApiError::from(e);
            assert_eq!(answer.status, status, "{text}");
            assert_eq!(answer.message, text);
        }
    }
}
