//! The store's one error type and its coarse classes.

use std::path::PathBuf;

/// Errors of the data directory.
#[derive(Debug, thiserror::Error)]
pub enum StoreError {
    /// A file or folder could not be read, written, renamed or removed.
    #[error("{path}: {source}")]
    Io {
        /// The file or folder.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
    /// No object of that kind and name (or version).
    #[error("no {kind} named {name:?}")]
    NotFound {
        /// `model`, `model version`, `robot`, `profile`.
        kind: &'static str,
        /// The name asked for (`name@version` for a model version).
        name: String,
    },
    /// A name that is not `[A-Za-z0-9._-]{1,64}` or starts with `.`.
    #[error(
        "bad name {name:?}: use 1 to 64 characters from A-Z a-z 0-9 . _ -, not starting with ."
    )]
    BadName {
        /// The name refused.
        name: String,
    },
    /// An upload grew past its size limit (its temporary file is already deleted).
    #[error("upload larger than the limit of {limit_bytes} bytes")]
    TooLarge {
        /// The limit.
        limit_bytes: u64,
    },
    /// The request or the uploaded content is not acceptable (the validator's reason, an
    /// empty upload, a non-finite threshold, an archive of the wrong format, ...).
    #[error("{reason}")]
    Invalid {
        /// Why.
        reason: String,
    },
    /// The object is still used and cannot be deleted.
    #[error("{kind} {name:?} is in use by {}", by.join(", "))]
    InUse {
        /// `model`, `model version`, `robot`.
        kind: &'static str,
        /// Its name (`name@version` for a model version).
        name: String,
        /// Who uses it (`profile <name>`, `the active version`, ...).
        by: Vec<String>,
    },
    /// A stored file failed its checksum or cannot be parsed; it is not served.
    #[error("{path} is corrupt: {reason}")]
    Corrupt {
        /// The file or folder.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// This replica mirrors a shared store written by another replica: changes are made
    /// there.
    #[error("read-only replica: {reason}")]
    ReadOnly {
        /// Where changes go instead.
        reason: String,
    },
    /// Another process (or another [`super::Store`] in this one) has the directory open.
    #[error("{path} is locked by another vamos store")]
    Locked {
        /// The lock file.
        path: PathBuf,
    },
}

/// Coarse classes of [`StoreError`], for mapping onto protocol status codes in one place.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StoreErrorKind {
    /// [`StoreError::NotFound`] (HTTP 404).
    NotFound,
    /// [`StoreError::BadName`], [`StoreError::Invalid`] (HTTP 400, or 422 for a refused
    /// upload).
    BadRequest,
    /// [`StoreError::TooLarge`] (HTTP 413).
    TooLarge,
    /// [`StoreError::InUse`], [`StoreError::ReadOnly`] (HTTP 409).
    Conflict,
    /// [`StoreError::Io`] because the disk is full (HTTP 507).
    StorageFull,
    /// [`StoreError::Io`], [`StoreError::Corrupt`], [`StoreError::Locked`] (HTTP 500).
    Internal,
}

impl StoreError {
    /// The class of this error.
    pub fn kind(&self) -> StoreErrorKind {
        match self {
            Self::NotFound { .. } => StoreErrorKind::NotFound,
            Self::BadName { .. } | Self::Invalid { .. } => StoreErrorKind::BadRequest,
            Self::TooLarge { .. } => StoreErrorKind::TooLarge,
            Self::InUse { .. } | Self::ReadOnly { .. } => StoreErrorKind::Conflict,
            Self::Io { source, .. } if source.kind() == std::io::ErrorKind::StorageFull => {
                StoreErrorKind::StorageFull
            }
            Self::Io { .. } | Self::Corrupt { .. } | Self::Locked { .. } => {
                StoreErrorKind::Internal
            }
        }
    }

    pub(crate) fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Self::Io {
            path: path.into(),
            source,
        }
    }

    pub(crate) fn invalid(reason: impl Into<String>) -> Self {
        Self::Invalid {
            reason: reason.into(),
        }
    }
}
