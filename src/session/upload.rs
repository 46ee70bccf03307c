//! The one episode-upload buffer: an uploaded episode streamed into a temporary file of
//! the upload folder, within `max_episode_bytes` and the upload's disk ticket, whatever
//! the transport's chunks.

use super::budget::UploadTicket;
use super::error::SessionError;
use std::io::Write;
use std::path::Path;

/// An episode being received.
pub struct EpisodeBuffer {
    file: tempfile::NamedTempFile,
    size: u64,
    limit: u64,
    ticket: UploadTicket,
}

impl EpisodeBuffer {
    /// A new buffer in `dir` for an episode of at most `limit` bytes, its disk charged to
    /// `ticket`.
    pub fn new(dir: &Path, limit: u64, ticket: UploadTicket) -> Result<Self, SessionError> {
        let file = tempfile::Builder::new()
            .prefix("episode-")
            .suffix(".mcap")
            .tempfile_in(dir)
            .map_err(|source| SessionError::Buffer { source })?;
        Ok(Self {
            file,
            size: 0,
            limit,
            ticket,
        })
    }

    /// Appends a chunk: refused past the limit or the upload disk budget.
    pub fn write(&mut self, chunk: &[u8]) -> Result<(), SessionError> {
        self.size += chunk.len() as u64;
        if self.size > self.limit {
            return Err(SessionError::EpisodeTooLarge { limit: self.limit });
        }
        self.ticket.written(self.size)?;
        self.file
            .write_all(chunk)
            .map_err(|source| SessionError::Buffer { source })
    }

    /// Bytes received.
    pub fn size(&self) -> u64 {
        self.size
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        self.file.path()
    }

    /// Charges `bytes` of disk in all to the upload (e.g. a scored copy to come).
    pub fn reserve_disk(&mut self, bytes: u64) -> Result<(), SessionError> {
        Ok(self.ticket.written(bytes)?)
    }

    /// The file and the upload's ticket (the disk it holds).
    pub fn into_parts(self) -> (tempfile::NamedTempFile, UploadTicket) {
        (self.file, self.ticket)
    }
}
