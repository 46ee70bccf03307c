//! Errors as gRPC statuses: the one mapping of the session layer's [`SessionError`] and
//! of [`AuthError`] to status codes.

use crate::api::auth::AuthError;
use crate::session::budget::UploadRefused;
use crate::session::{ProfileLookupError, SessionError};
use tonic::{Code, Status};

/// The status code of a session error.
pub fn code_of(e: &SessionError) -> Code {
    use SessionError as E;
    match e {
        E::Upload(UploadRefused::TooSlow { .. }) => Code::DeadlineExceeded,
        E::TooMany { .. } | E::OverCapacity(_) | E::Upload(_) | E::EpisodeTooLarge { .. } => {
            Code::ResourceExhausted
        }
        E::Busy { .. } => Code::AlreadyExists,
        E::RobotNotAllowed { .. } | E::NotYours { .. } => Code::PermissionDenied,
        E::ProfileMismatch { .. }
        | E::BadId(_)
        | E::BadLabel { .. }
        | E::BadCamera { .. }
        | E::OpenExpected
        | E::SecondOpen
        | E::NoChunk
        | E::NotAnEpisode { .. } => Code::InvalidArgument,
        E::ShuttingDown => Code::Unavailable,
        E::Scorer { .. } | E::Closed { .. } | E::Reload { .. } => Code::FailedPrecondition,
        E::Profile(ProfileLookupError::NotFound { .. }) => Code::NotFound,
        E::Profile(ProfileLookupError::Load { .. } | ProfileLookupError::Store { .. }) => {
            Code::FailedPrecondition
        }
        E::NoOpen | E::TooOld { .. } | E::Idle { .. } => Code::DeadlineExceeded,
        E::MessageTooLarge { .. } => Code::OutOfRange,
        E::Damaged { .. } => Code::DataLoss,
        E::Buffer { .. } | E::Internal(_) | E::Store { .. } => Code::Internal,
        E::UnknownSession { .. } | E::UnknownAlarm { .. } => Code::NotFound,
        E::AlarmMarked { .. } => Code::AlreadyExists,
        E::BadNote { .. } => Code::InvalidArgument,
    }
}

impl From<SessionError> for Status {
    fn from(e: SessionError) -> Self {
        Status::new(code_of(&e), e.to_string())
    }
}

impl From<AuthError> for Status {
    fn from(e: AuthError) -> Self {
        match e {
            AuthError::Forbidden { .. } => Status::permission_denied(e.to_string()),
            _ => Status::unauthenticated(e.to_string()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn session_errors_keep_their_codes_and_messages() {
        let cases = [
            (SessionError::TooMany { max: 2 }, Code::ResourceExhausted),
            (SessionError::Busy { id: "a".into() }, Code::AlreadyExists),
            (SessionError::ShuttingDown, Code::Unavailable),
            (SessionError::SecondOpen, Code::InvalidArgument),
            (SessionError::Idle { idle_s: 0.5 }, Code::DeadlineExceeded),
            (SessionError::TooOld { max_s: 1.5 }, Code::DeadlineExceeded),
            (
                SessionError::Profile(ProfileLookupError::NotFound { name: "p".into() }),
                Code::NotFound,
            ),
            (
                SessionError::EpisodeTooLarge { limit: 9 },
                Code::ResourceExhausted,
            ),
        ];
        for (e, code) in cases {
            let text = e.to_string();
            let status = Status::from(e);
            assert_eq!(status.code(), code, "{text}");
            assert_eq!(status.message(), text);
        }
        assert_eq!(
            SessionError::TooOld { max_s: 1.5 }.to_string(),
            "session exceeded the maximum length of 1.5 s"
        );
    }
}
