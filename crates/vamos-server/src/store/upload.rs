//! Streamed uploads: a temporary file in the store's `tmp/`, hashed as it is written.

use super::StoreError;
use super::files::hex;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// How a robot package is packed; decides the stored file's extension, which
/// [`vamos_robot::Robot::load`] dispatches on.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum RobotFormat {
    /// A single URDF file (meshes cannot come with it: use an archive for those).
    Urdf,
    /// A gzip-compressed tar archive of a robot package (`.tar.gz`, `.tgz`).
    TarGz,
    /// A zip archive of a robot package.
    Zip,
}

impl RobotFormat {
    /// The extension of stored files of this format (without the dot).
    pub fn extension(self) -> &'static str {
        match self {
            Self::Urdf => "urdf",
            Self::TarGz => "tar.gz",
            Self::Zip => "zip",
        }
    }

    /// The format a file name's extension names (`.urdf`, `.tar.gz`, `.tgz`, `.zip`,
    /// case-insensitive), if any.
    pub fn from_file_name(name: &str) -> Option<Self> {
        let lower = name.to_ascii_lowercase();
        if lower.ends_with(".urdf") {
            Some(Self::Urdf)
        } else if lower.ends_with(".tar.gz") || lower.ends_with(".tgz") {
            Some(Self::TarGz)
        } else if lower.ends_with(".zip") {
            Some(Self::Zip)
        } else {
            None
        }
    }
}

/// What an upload will become.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UploadKind {
    /// A model bundle (`.vamos`), for [`super::Store::commit_model`].
    Model,
    /// A robot package, for [`super::Store::commit_robot`].
    Robot {
        /// How it is packed.
        format: RobotFormat,
    },
}

/// An upload in progress: chunks are appended to a temporary file in the store's `tmp/`
/// and hashed as they arrive, so nothing is held whole in memory. Commit it with
/// [`super::Store::commit_model`] or [`super::Store::commit_robot`]; dropping it
/// uncommitted deletes the temporary file. A crash leaves the file behind, and the next
/// [`super::Store::open`] deletes it.
#[derive(Debug)]
pub struct Upload {
    pub(crate) kind: UploadKind,
    pub(crate) path: PathBuf,
    file: Option<BufWriter<File>>,
    hasher: Sha256,
    bytes: u64,
    limit_bytes: u64,
    /// Fault injection: writes past this many bytes fail as on a full disk.
    storage_full_after: u64,
    /// Set once the limit was passed: the file is gone, the upload is dead.
    too_large: bool,
    /// Set once the file was moved into the store: `Drop` leaves it alone.
    pub(crate) moved: bool,
}

/// What a finished upload holds.
#[derive(Debug, Clone)]
pub(crate) struct Finished {
    pub(crate) sha256: String,
    pub(crate) size_bytes: u64,
}

impl Upload {
    pub(crate) fn create(
        tmp_dir: &Path,
        kind: UploadKind,
        limit_bytes: u64,
        storage_full_after: u64,
    ) -> Result<Self, StoreError> {
        // The extension tells validators such as `Robot::load` what the file is.
        let ext = match kind {
            UploadKind::Model => "vamos",
            UploadKind::Robot { format } => format.extension(),
        };
        let path = tmp_dir.join(super::files::unique_name("upload", &format!(".part.{ext}")));
        let file = File::options()
            .write(true)
            .create_new(true)
            .open(&path)
            .map_err(|e| StoreError::io(&path, e))?;
        Ok(Self {
            kind,
            path,
            file: Some(BufWriter::with_capacity(1 << 18, file)),
            hasher: Sha256::new(),
            bytes: 0,
            limit_bytes,
            storage_full_after,
            too_large: false,
            moved: false,
        })
    }

    /// What this upload is for.
    pub fn kind(&self) -> UploadKind {
        self.kind
    }

    /// Bytes written so far.
    pub fn bytes(&self) -> u64 {
        self.bytes
    }

    /// The most bytes this upload accepts.
    pub fn limit_bytes(&self) -> u64 {
        self.limit_bytes
    }

    /// Appends a chunk. Past the limit the temporary file is deleted at once and this
    /// (and every later call, and the commit) fails with [`StoreError::TooLarge`].
    pub fn write_chunk(&mut self, chunk: &[u8]) -> Result<(), StoreError> {
        let too_large = StoreError::TooLarge {
            limit_bytes: self.limit_bytes,
        };
        if self.too_large {
            return Err(too_large);
        }
        if self.bytes.saturating_add(chunk.len() as u64) > self.limit_bytes {
            self.too_large = true;
            self.file = None;
            super::files::remove_file_quiet(&self.path);
            return Err(too_large);
        }
        let Some(file) = self.file.as_mut() else {
            return Err(StoreError::invalid("the upload is already finished"));
        };
        if self.bytes.saturating_add(chunk.len() as u64) > self.storage_full_after {
            // Injected (tests): what `write` reports on a full disk.
            return Err(StoreError::io(
                &self.path,
                std::io::Error::from_raw_os_error(28),
            ));
        }
        file.write_all(chunk)
            .map_err(|e| StoreError::io(&self.path, e))?;
        self.hasher.update(chunk);
        self.bytes += chunk.len() as u64;
        Ok(())
    }

    /// Flushes and fsyncs the file and returns its checksum and size; later writes fail.
    pub(crate) fn finish(&mut self) -> Result<Finished, StoreError> {
        if self.too_large {
            return Err(StoreError::TooLarge {
                limit_bytes: self.limit_bytes,
            });
        }
        if let Some(writer) = self.file.take() {
            let file = writer
                .into_inner()
                .map_err(|e| StoreError::io(&self.path, e.into_error()))?;
            file.sync_all().map_err(|e| StoreError::io(&self.path, e))?;
        }
        Ok(Finished {
            sha256: hex(&self.hasher.clone().finalize()),
            size_bytes: self.bytes,
        })
    }
}

impl Write for Upload {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.write_chunk(buf).map_err(std::io::Error::other)?;
        Ok(buf.len())
    }

    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Drop for Upload {
    fn drop(&mut self) {
        if !self.moved {
            self.file = None;
            super::files::remove_file_quiet(&self.path);
        }
    }
}
