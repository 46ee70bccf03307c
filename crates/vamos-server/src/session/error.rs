//! The session layer's one error type. Each transport maps it once: to gRPC codes in
//! `api::grpc::error`, to HTTP statuses in `api::rest::errors`. The messages are what
//! clients read.

use super::budget::UploadRefused;
use super::profiles::ProfileLookupError;
use vamos_core::episode::EpisodeError;
use vamos_core::setup::SetupError;
use vamos_robot::IntrinsicsError;

/// Why a session operation failed, or why a session's stream ended.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// `max_sessions` are open.
    #[error("the server has its maximum of {max} sessions open")]
    TooMany {
        /// The limit.
        max: usize,
    },
    /// The live sessions' measured load leaves no room for one more.
    #[error(transparent)]
    OverCapacity(#[from] super::capacity::OverCapacity),
    /// A session with that id is streaming.
    #[error("session {id:?} is already streaming")]
    Busy {
        /// The id.
        id: String,
    },
    /// The caller's robot token is not issued for this robot.
    #[error("this robot token is not issued for robot {robot_id:?}")]
    RobotNotAllowed {
        /// The robot id asked for.
        robot_id: String,
    },
    /// A session (to resume) that another robot token opened.
    #[error("session {id:?} was opened by another robot token")]
    NotYours {
        /// The id.
        id: String,
    },
    /// A resumed session belongs to another profile.
    #[error("session {id:?} was opened with profile {profile:?}")]
    ProfileMismatch {
        /// The id.
        id: String,
        /// Its profile.
        profile: String,
    },
    /// The server is shutting down.
    #[error("the server is shutting down")]
    ShuttingDown,
    /// The scorer could not be built.
    #[error("{source}")]
    Scorer {
        /// Why.
        #[source]
        source: Box<SetupError>,
    },
    /// The session is closed.
    #[error("session {id:?} is closed")]
    Closed {
        /// The id.
        id: String,
    },
    /// An id that is not acceptable.
    #[error("invalid session id: {0}")]
    BadId(&'static str),
    /// A client's label (robot id, task, phase, episode name) that is too long or holds
    /// control characters.
    #[error(
        "{field} must be at most {MAX_LABEL_BYTES} bytes of printable characters ({len} bytes given)"
    )]
    BadLabel {
        /// The message field.
        field: &'static str,
        /// Its length, bytes.
        len: usize,
    },
    /// The open message's camera is not valid.
    #[error("camera_info: {source}")]
    BadCamera {
        /// Why.
        #[source]
        source: IntrinsicsError,
    },
    /// No open message came in time.
    #[error("no open message")]
    NoOpen,
    /// The first message was not an open message.
    #[error("the first message of a stream must be `open`")]
    OpenExpected,
    /// A second open message in one stream.
    #[error("a second open message in one stream")]
    SecondOpen,
    /// A message over the transport's size limit.
    #[error("message refused (service.max_message_bytes): {detail}")]
    MessageTooLarge {
        /// The transport's words.
        detail: String,
    },
    /// The session reached `max_session_s`.
    #[error("session exceeded the maximum length of {max_s} s")]
    TooOld {
        /// The limit, seconds.
        max_s: f64,
    },
    /// The client said nothing for `idle_timeout_s`.
    #[error("no message for {idle_s} s: session closed")]
    Idle {
        /// The limit, seconds.
        idle_s: f64,
    },
    /// The profile cannot be used.
    #[error(transparent)]
    Profile(#[from] ProfileLookupError),
    /// A session could not be moved to its profile as stored now.
    #[error("{source}")]
    Reload {
        /// Why.
        #[source]
        source: Box<SessionError>,
    },
    /// No upload slot or temporary disk for an upload.
    #[error(transparent)]
    Upload(#[from] UploadRefused),
    /// An episode over `max_episode_bytes`.
    #[error("episode larger than the limit of {limit} bytes")]
    EpisodeTooLarge {
        /// The limit, bytes.
        limit: u64,
    },
    /// An episode upload without any chunk.
    #[error("no chunk received")]
    NoChunk,
    /// The upload could not be written to disk.
    #[error("cannot buffer the episode: {source}")]
    Buffer {
        /// Why.
        #[source]
        source: std::io::Error,
    },
    /// The upload is not an episode vamos reads.
    #[error("not a readable episode: {reason}")]
    NotAnEpisode {
        /// Why, without the server's path of the upload ([`Self::not_an_episode`]).
        reason: String,
    },
    /// The episode broke part-way; the frames before the damage were scored.
    #[error("the episode is damaged; frames before the damage were scored: {source}")]
    Damaged {
        /// Where and how it broke.
        #[source]
        source: EpisodeError,
    },
    /// A failure of the server itself (a task that died).
    #[error("{0}")]
    Internal(String),
    /// No open session has that id (it never existed, or it ended).
    #[error("no open session {id:?} (it may have ended, or the server restarted)")]
    UnknownSession {
        /// The id asked for.
        id: String,
    },
    /// No recent alarm has that id.
    #[error("no alarm {id:?} among the recent alarms (it may be older, or the server restarted)")]
    UnknownAlarm {
        /// The id asked for.
        id: String,
    },
    /// The alarm is already marked as a false alarm.
    #[error("alarm {id:?} is already marked as a false alarm")]
    AlarmMarked {
        /// The id.
        id: String,
    },
    /// A mark's note is too long.
    #[error("the note is longer than {max} characters")]
    BadNote {
        /// The limit, characters.
        max: usize,
    },
    /// The data directory refused or failed an operation.
    #[error("{source}")]
    Store {
        /// Why.
        #[source]
        source: Box<crate::store::StoreError>,
    },
}

impl SessionError {
    /// A scorer that could not be built.
    pub fn scorer(source: SetupError) -> Self {
        Self::Scorer {
            source: Box::new(source),
        }
    }
}

impl SessionError {
    /// An upload buffered at `path` that is not an episode vamos reads: the reason names
    /// it "the upload", never the server's path (which a client has no business seeing).
    pub fn not_an_episode(source: &EpisodeError, path: &std::path::Path) -> Self {
        Self::NotAnEpisode {
            reason: source
                .to_string()
                .replace(&path.display().to_string(), "the upload"),
        }
    }
}

/// Longest label a client may give (robot id, task, phase, episode name), bytes: labels
/// are kept with the session, listed by `/v1/live` and written on log lines.
pub const MAX_LABEL_BYTES: usize = 256;

/// `value` of `field` as a label: at most [`MAX_LABEL_BYTES`], no control characters.
pub fn check_label(field: &'static str, value: &str) -> Result<(), SessionError> {
    if value.len() > MAX_LABEL_BYTES || value.chars().any(char::is_control) {
        return Err(SessionError::BadLabel {
            field,
            len: value.len(),
        });
    }
    Ok(())
}
