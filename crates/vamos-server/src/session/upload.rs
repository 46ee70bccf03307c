//! The one episode-upload buffer: an uploaded episode streamed into a temporary file of
//! the upload folder, within `max_episode_bytes` and the upload's disk ticket, whatever
//! the transport's chunks.

use super::budget::{UploadRefused, UploadTicket};
use super::error::SessionError;
use std::io::Write;
use std::path::Path;
use vamos_core::episode::{decompress_zstd_into, is_zstd_file};

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
        self.ticket.received(self.size)?;
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

    /// Once the upload is complete: a zstd-compressed episode (rosbag2's file
    /// compression, `.mcap.zstd`) is decompressed beside it in the upload folder, at most
    /// `limit` bytes, the copy's disk charged to the ticket as it is written (refused like
    /// the upload itself when the budget is spent); the buffer then holds the copy, the
    /// compressed file is removed and the ticket holds the copy's size. Any other file is
    /// left as it is. Blocking (file I/O).
    pub fn decompress(mut self, limit: u64) -> Result<Self, SessionError> {
        let held = self.size;
        if let Some((copy, written)) =
            charged_copy(self.file.path(), limit, &mut self.ticket, held)?
        {
            self.file = copy; // the compressed file is removed as its handle drops
            self.size = written;
            self.ticket.holds(written)?;
        }
        Ok(self)
    }

    /// [`Self::decompress`] on a blocking thread.
    pub async fn decompressed(self, limit: u64) -> Result<Self, SessionError> {
        tokio::task::spawn_blocking(move || self.decompress(limit))
            .await
            .map_err(|e| SessionError::Internal(e.to_string()))?
    }

    /// The file and the upload's ticket (the disk it holds).
    pub fn into_parts(self) -> (tempfile::NamedTempFile, UploadTicket) {
        (self.file, self.ticket)
    }
}

/// A zstd-compressed episode file of an upload (rosbag2's file compression,
/// `.mcap.zstd`; told by its magic, whatever its name) decompressed in place: the copy
/// ([`charged_copy`]) replaces it. Returns the file's new size, `None` for a file that is
/// not compressed (left as it is). On a refusal nothing is left but the compressed file.
/// Blocking (file I/O).
pub fn decompress_in_place(
    path: &Path,
    limit: u64,
    ticket: &mut UploadTicket,
    held: u64,
) -> Result<Option<u64>, SessionError> {
    let Some((copy, written)) = charged_copy(path, limit, ticket, held)? else {
        return Ok(None);
    };
    copy.persist(path)
        .map_err(|e| SessionError::Buffer { source: e.error })?;
    Ok(Some(written))
}

/// The decompressed copy of the zstd-compressed file at `path`, beside it, at most
/// `limit` bytes, each byte charged to `ticket` on top of `held` (what the upload's files
/// take, this one included) before it is written (refused like the upload itself when
/// the budget is spent), and its size; `None` for a file that is not compressed.
fn charged_copy(
    path: &Path,
    limit: u64,
    ticket: &mut UploadTicket,
    held: u64,
) -> Result<Option<(tempfile::NamedTempFile, u64)>, SessionError> {
    let not_an_episode = |source| SessionError::not_an_episode(&source, path);
    if !is_zstd_file(path).map_err(not_an_episode)? {
        return Ok(None);
    }
    let dir = path.parent().unwrap_or(Path::new("."));
    let copy = tempfile::Builder::new()
        .prefix("episode-")
        .suffix(".mcap")
        .tempfile_in(dir)
        .map_err(|source| SessionError::Buffer { source })?;
    let mut out = ChargedWriter {
        file: copy,
        written: 0,
        held,
        ticket,
        refused: None,
    };
    let result = decompress_zstd_into(path, limit, &mut out);
    let ChargedWriter {
        file: copy,
        written,
        refused,
        ..
    } = out;
    if let Some(refused) = refused {
        return Err(refused.into());
    }
    result.map_err(not_an_episode)?;
    Ok(Some((copy, written)))
}

/// A decompressed copy whose every byte is charged to the upload's ticket (on top of
/// the `held` bytes of the compressed file) before it is written.
struct ChargedWriter<'a> {
    file: tempfile::NamedTempFile,
    written: u64,
    held: u64,
    ticket: &'a mut UploadTicket,
    refused: Option<UploadRefused>,
}

impl Write for ChargedWriter<'_> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let total = self.written + buf.len() as u64;
        if let Err(e) = self.ticket.written(self.held.saturating_add(total)) {
            let message = e.to_string();
            self.refused = Some(e);
            return Err(std::io::Error::other(message));
        }
        let n = self.file.write(buf)?;
        self.written += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::session::budget::{MinRate, UploadPlane, Uploads};
    use prometheus::IntGauge;

    fn new_uploads(disk: u64, gauge: &IntGauge) -> Uploads {
        let any_rate = MinRate {
            bytes_per_s: 0,
            grace: std::time::Duration::ZERO,
        };
        Uploads::new(4, disk, gauge.clone(), any_rate)
    }

    /// `len` bytes of an MCAP file's contents: its magic, then `fill`.
    fn mcap_like(len: usize, fill: impl Fn(usize) -> u8) -> Vec<u8> {
        let magic = b"\x89MCAP0\r\n";
        (0..len)
            .map(|i| magic.get(i).copied().unwrap_or_else(|| fill(i)))
            .collect()
    }

    fn zstd(raw: &[u8]) -> Vec<u8> {
        // Streamed, as rosbag2 compresses: the frame does not declare its size.
        let mut encoder = zstd::stream::write::Encoder::new(Vec::new(), 3).unwrap();
        encoder.write_all(raw).unwrap();
        encoder.finish().unwrap()
    }

    fn buffer(dir: &Path, uploads: &Uploads, bytes: &[u8]) -> EpisodeBuffer {
        let ticket = uploads
            .admit(UploadPlane::Robot, None)
            .unwrap_or_else(|e| panic!("{e}"));
        let mut b = EpisodeBuffer::new(dir, 1 << 20, ticket).unwrap_or_else(|e| panic!("{e}"));
        b.write(bytes).unwrap_or_else(|e| panic!("{e}"));
        b
    }

    #[test]
    fn a_compressed_upload_is_replaced_by_its_copy_charged_as_written() {
        let dir = tempfile::tempdir().unwrap();
        let gauge = IntGauge::new("d", "d").unwrap();
        let uploads = new_uploads(1_000_000, &gauge);
        let raw = mcap_like(300_000, |i| (i % 251) as u8);
        let packed = zstd(&raw);
        let b = buffer(dir.path(), &uploads, &packed);
        let compressed_path = b.path().to_path_buf();
        let b = b.decompress(1 << 20).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(std::fs::read(b.path()).unwrap(), raw);
        assert_eq!(b.size(), raw.len() as u64);
        assert!(!compressed_path.exists(), "the compressed file is removed");
        assert_eq!(
            b.path().parent(),
            Some(dir.path()),
            "the copy is in the upload folder"
        );
        assert_eq!(gauge.get(), raw.len() as i64, "the ticket holds the copy");
        // A plain file is left as it is.
        let plain = buffer(dir.path(), &uploads, b"\x89MCAP0\r\n");
        let path = plain.path().to_path_buf();
        let plain = plain.decompress(1 << 20).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(plain.path(), path);
        drop((b, plain));
        assert_eq!(gauge.get(), 0);
    }

    #[test]
    fn a_copy_past_the_disk_budget_or_the_limit_is_refused_and_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let gauge = IntGauge::new("d", "d").unwrap();
        let raw = mcap_like(500_000, |_| 3);
        let packed = zstd(&raw);
        // The compressed upload fits the budget; its copy does not.
        let uploads = new_uploads(400_000, &gauge);
        let b = buffer(dir.path(), &uploads, &packed);
        let err = b.decompress(1 << 20).err().expect("refused");
        assert!(matches!(err, SessionError::Upload(_)), "{err}");
        assert!(err.to_string().contains("upload disk budget"), "{err}");
        // Past `max_decompressed_bytes`.
        let uploads = new_uploads(10_000_000, &gauge);
        let b = buffer(dir.path(), &uploads, &packed);
        let err = b.decompress(100_000).err().expect("refused");
        assert!(matches!(err, SessionError::NotAnEpisode { .. }), "{err}");
        assert!(err.to_string().contains("max_decompressed_bytes"), "{err}");
        assert_eq!(gauge.get(), 0, "every charge given back");
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            0,
            "no file left"
        );
    }

    #[test]
    fn an_upload_part_is_decompressed_in_place_charged_on_top_of_the_others() {
        let dir = tempfile::tempdir().unwrap();
        let gauge = IntGauge::new("d", "d").unwrap();
        let raw = mcap_like(300_000, |_| 5);
        let packed = zstd(&raw);
        let part = dir.path().join("b.mcap");
        std::fs::write(&part, &packed).unwrap();
        let held = 100_000 + packed.len() as u64;
        // The other files (100 kB) and this one, then its copy on top: over a 350 kB budget.
        let uploads = new_uploads(350_000, &gauge);
        let mut ticket = uploads
            .admit(UploadPlane::Robot, None)
            .unwrap_or_else(|e| panic!("{e}"));
        ticket.written(held).unwrap_or_else(|e| panic!("{e}"));
        let err = decompress_in_place(&part, 1 << 20, &mut ticket, held).unwrap_err();
        assert!(err.to_string().contains("upload disk budget"), "{err}");
        assert_eq!(
            std::fs::read(&part).unwrap(),
            packed,
            "the part is left as it was"
        );
        assert_eq!(
            std::fs::read_dir(dir.path()).unwrap().count(),
            1,
            "no copy left"
        );
        drop(ticket);
        assert_eq!(gauge.get(), 0);
        // With room: the part becomes its copy.
        let uploads = new_uploads(1_000_000, &gauge);
        let mut ticket = uploads
            .admit(UploadPlane::Robot, None)
            .unwrap_or_else(|e| panic!("{e}"));
        ticket.written(held).unwrap_or_else(|e| panic!("{e}"));
        let size = decompress_in_place(&part, 1 << 20, &mut ticket, held)
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(size, Some(raw.len() as u64));
        assert_eq!(std::fs::read(&part).unwrap(), raw);
        assert_eq!(
            gauge.get(),
            (held + raw.len() as u64) as i64,
            "charged as written"
        );
        // A part that is not compressed is left alone.
        assert_eq!(
            decompress_in_place(&part, 1 << 20, &mut ticket, held)
                .unwrap_or_else(|e| panic!("{e}")),
            None
        );
        drop(ticket);
        assert_eq!(gauge.get(), 0);
    }
}
