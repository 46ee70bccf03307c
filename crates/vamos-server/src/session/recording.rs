//! Session recordings: a live session's input as its scorer got it (each image as it was
//! received with its depth image if it had one, the joint positions at its stamp, the
//! camera) written to an MCAP episode in the
//! data directory's `recordings/` while the session runs (`<name>.mcap.part`, renamed to
//! `<name>.mcap` when it closes). When an operator marks one of the session's alarms as a
//! false alarm its recording is kept (a `<name>.keep` mark beside it) and joins the
//! nominal set of the session's profile, from which a recalibration proposes new
//! thresholds ([`super::calibration::Calibrator::recalibrate`]).
//!
//! Disk: recordings take at most `recordings_disk_mb` together; a new session first makes
//! room by removing the oldest finished recordings that are not kept, and is not recorded
//! when that is not enough. One session records at most `max_recording_mb` (raw bytes;
//! the file is zstd-compressed and smaller), then stops recording (the episode is the
//! first part of the session).

use super::event::LiveImage;
use std::path::{Path, PathBuf};
use vamos_core::episode::image::Encoding;
use vamos_core::episode::ros::{CameraInfoMsg, CompressedImageMsg, Header, ImageMsg, schema};
use vamos_core::episode::{EpisodeError, EpisodeTopics, ScoreBagWriter};
use vamos_robot::Intrinsics;

/// The folder of recordings in the data directory.
pub const DIR: &str = "recordings";

/// Topics of a recording when the profile names none (what `vamos-sim` and most camera
/// drivers use): image, camera info, joint states, depth.
const DEFAULT_TOPICS: [&str; 4] = [
    "/camera/image_raw",
    "/camera/camera_info",
    "/joint_states",
    "/camera/depth/image_raw",
];

/// How much recordings may take.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RecordingLimits {
    /// All recordings together, bytes on disk.
    pub disk_bytes: u64,
    /// One session, raw bytes written.
    pub session_bytes: u64,
}

/// The file name (without extension) of a recording of session `id` opened at
/// `opened_unix_ms`: its id with anything but `[A-Za-z0-9_-]` replaced (at most 64
/// characters), 8 hex digits of its hash (two ids never share a file) and the time (a
/// session id used again gets a file of its own).
pub fn file_stem(id: &str, opened_unix_ms: u64) -> String {
    let clean: String = id
        .chars()
        .take(64)
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '_' || c == '-' {
                c
            } else {
                '_'
            }
        })
        .collect();
    let hash = vamos_model::bundle::sha256_hex(id.as_bytes());
    format!("{clean}-{}-{opened_unix_ms}", &hash[..8])
}

/// Marks recording `file` (`<stem>.mcap`, finished or in progress) as kept: never
/// removed to make room. `Ok(false)` when there is no such recording.
pub fn keep(dir: &Path, file: &str) -> std::io::Result<bool> {
    let Some(stem) = file
        .strip_suffix(".mcap")
        .filter(|s| !s.contains(['/', '\\']))
    else {
        return Ok(false);
    };
    if !dir.join(file).is_file() && !dir.join(format!("{file}.part")).is_file() {
        return Ok(false);
    }
    std::fs::write(dir.join(format!("{stem}.keep")), b"")?;
    Ok(true)
}

/// A session's recording in progress.
pub struct Recorder {
    writer: ScoreBagWriter,
    part: PathBuf,
    done: PathBuf,
    bytes: u64,
    limit: u64,
    topics: [String; 4],
    camera: Option<Intrinsics>,
    /// The schema of the images recorded so far.
    image_schema: Option<&'static str>,
    full: bool,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder")
            .field("part", &self.part)
            .field("bytes", &self.bytes)
            .finish_non_exhaustive()
    }
}

/// Why a session is not recorded.
#[derive(Debug, thiserror::Error)]
pub enum RecordingError {
    /// The recordings' disk is spent by recordings that are kept or in progress.
    #[error(
        "recordings take {used} bytes of their {budget}-byte disk budget (recordings_disk_mb) and none can be removed"
    )]
    Full {
        /// Bytes the recordings take.
        used: u64,
        /// The budget.
        budget: u64,
    },
    /// The folder or file could not be written.
    #[error("cannot write the recording: {0}")]
    Io(#[from] std::io::Error),
    /// The MCAP writer failed.
    #[error(transparent)]
    Episode(#[from] EpisodeError),
    /// Raw images after files or files after raw images: one topic carries one type.
    #[error("the session switched between raw and compressed images; its recording ends here")]
    MixedImages,
}

impl Recorder {
    /// Starts recording session `id` in `dir` on `topics` (the profile's, else the usual
    /// ones), after making room within `limits` (blocking: file I/O).
    pub fn start(
        dir: &Path,
        id: &str,
        topics: &EpisodeTopics,
        limits: RecordingLimits,
    ) -> Result<Recorder, RecordingError> {
        std::fs::create_dir_all(dir)?;
        let used = make_room(dir, limits.disk_bytes.saturating_sub(limits.session_bytes))?;
        if used.saturating_add(limits.session_bytes) > limits.disk_bytes {
            return Err(RecordingError::Full {
                used,
                budget: limits.disk_bytes,
            });
        }
        let opened_ms = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_millis() as u64);
        let stem = file_stem(id, opened_ms);
        let part = dir.join(format!("{stem}.mcap.part"));
        let done = dir.join(format!("{stem}.mcap"));
        let writer = ScoreBagWriter::create(&part, None)?;
        let pick = |t: &Option<String>, i: usize| t.clone().unwrap_or(DEFAULT_TOPICS[i].into());
        Ok(Recorder {
            writer,
            part,
            done,
            bytes: 0,
            limit: limits.session_bytes,
            topics: [
                pick(&topics.image, 0),
                pick(&topics.camera_info, 1),
                pick(&topics.joint_states, 2),
                pick(&topics.depth, 3),
            ],
            camera: None,
            image_schema: None,
            full: false,
        })
    }

    /// Records one frame as the scorer gets it: the camera (when it changed), the joint
    /// positions at the image's stamp, then the image as it was received (raw pixels as
    /// a `sensor_msgs/Image`, a JPEG/PNG file as a `CompressedImage`), so that scoring the
    /// recording decodes the very same pixels. Past the session's limit nothing more is
    /// written (`Ok(false)`).
    pub fn record(
        &mut self,
        image: &LiveImage,
        joints: Option<(&[String], &[f64], &[f64])>,
        camera: Option<&Intrinsics>,
    ) -> Result<bool, RecordingError> {
        let stamp_ns = image.stamp_ns;
        let compressed = matches!(
            Encoding::from_name(&image.encoding),
            Some(Encoding::Jpeg | Encoding::Png)
        );
        let schema_name = if compressed {
            schema::COMPRESSED_IMAGE
        } else {
            schema::IMAGE
        };
        if self.image_schema.is_some_and(|s| s != schema_name) {
            return Err(RecordingError::MixedImages);
        }
        let cost = (image.data.len() + image.depth.as_ref().map_or(0, |d| d.data.len())) as u64
            + joints.map_or(0, |(n, p, e)| {
                (n.len() * 24 + (p.len() + e.len()) * 8) as u64
            });
        if self.full || self.bytes.saturating_add(cost) > self.limit {
            if !self.full {
                tracing::info!(recording = %self.part.display(), bytes = self.bytes, "recording reached max_recording_mb: the rest of the session is not recorded");
            }
            self.full = true;
            return Ok(false);
        }
        if let Some(k) = camera
            && self.camera.as_ref() != Some(k)
        {
            let msg = CameraInfoMsg::from_intrinsics(stamp_ns, "camera", k);
            self.writer.write_camera_info(&self.topics[1], &msg)?;
            self.camera = Some(*k);
        }
        if let Some((names, positions, efforts)) = joints {
            self.writer
                .write_joint_state(&self.topics[2], stamp_ns, names, positions, efforts)?;
        }
        let header = Header::from_stamp_ns(stamp_ns, "camera");
        let cdr = if compressed {
            CompressedImageMsg {
                header,
                format: image.encoding.to_ascii_lowercase(),
                data: &image.data,
            }
            .encode()
        } else {
            ImageMsg {
                header,
                height: image.height,
                width: image.width,
                encoding: image.encoding.clone(),
                is_bigendian: image.big_endian,
                step: image.step,
                data: &image.data,
            }
            .encode()
        };
        self.writer
            .write_cdr(&self.topics[0], schema_name, stamp_ns, &cdr)?;
        if let Some(d) = &image.depth {
            let cdr = ImageMsg {
                header: Header::from_stamp_ns(stamp_ns, "camera"),
                height: d.height,
                width: d.width,
                encoding: d.encoding.clone(),
                is_bigendian: d.big_endian,
                step: d.step,
                data: &d.data,
            }
            .encode();
            self.writer
                .write_cdr(&self.topics[3], schema::IMAGE, stamp_ns, &cdr)?;
        }
        self.image_schema = Some(schema_name);
        self.bytes += cost;
        Ok(true)
    }

    /// The recording's file name once finished (`<stem>.mcap`).
    pub fn file_name(&self) -> String {
        self.done
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    }

    /// Ends the recording: the file is completed and renamed to `<name>.mcap`; returns
    /// its path. Blocking (file I/O).
    pub fn finish(self) -> Result<PathBuf, RecordingError> {
        self.writer.finish()?;
        std::fs::rename(&self.part, &self.done)?;
        Ok(self.done)
    }
}

/// Recordings a server left in progress when it stopped without closing them (killed,
/// crashed): each `<stem>.mcap.part` becomes `<stem>.mcap`, a finished recording cut
/// short, so that it is listed, read back up to the cut and, unless kept, removed
/// oldest-first to make room like any other (a `.part` is never removed, so left alone
/// it would hold its disk for good). Returns how many. For a server's start, before any
/// session records.
pub fn recover_interrupted(dir: &Path) -> std::io::Result<usize> {
    let mut recovered = 0;
    let entries = match std::fs::read_dir(dir) {
        Ok(e) => e,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(0),
        Err(e) => return Err(e),
    };
    for entry in entries {
        let entry = entry?;
        let name = entry.file_name().to_string_lossy().into_owned();
        let Some(done) = name.strip_suffix(".part").filter(|n| n.ends_with(".mcap")) else {
            continue;
        };
        std::fs::rename(entry.path(), dir.join(done))?;
        recovered += 1;
    }
    Ok(recovered)
}

/// Removes the oldest finished recordings that are not kept until the folder takes at
/// most `target` bytes; returns what it takes then.
fn make_room(dir: &Path, target: u64) -> std::io::Result<u64> {
    let mut finished = Vec::new();
    let mut used = 0u64;
    for entry in std::fs::read_dir(dir)? {
        let entry = entry?;
        // A file renamed or removed since the listing (another session finishing its
        // recording, or making room) is not counted: no reason to refuse this one.
        let meta = match entry.metadata() {
            Ok(m) => m,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => continue,
            Err(e) => return Err(e),
        };
        if !meta.is_file() {
            continue;
        }
        used += meta.len();
        let name = entry.file_name().to_string_lossy().into_owned();
        if let Some(stem) = name.strip_suffix(".mcap")
            && !dir.join(format!("{stem}.keep")).exists()
        {
            let age = meta.modified().unwrap_or(std::time::UNIX_EPOCH);
            finished.push((age, meta.len(), entry.path()));
        }
    }
    finished.sort();
    for (_, len, path) in finished {
        if used <= target {
            break;
        }
        match std::fs::remove_file(&path) {
            Ok(()) => used = used.saturating_sub(len),
            Err(e) => tracing::warn!("cannot remove the recording {}: {e}", path.display()),
        }
    }
    Ok(used)
}

#[cfg(test)]
mod tests {
    use super::*;
    use vamos_core::episode::McapEpisode;

    fn limits(disk: u64, session: u64) -> RecordingLimits {
        RecordingLimits {
            disk_bytes: disk,
            session_bytes: session,
        }
    }

    fn rgb(stamp_ns: i64, width: u32, height: u32, seed: u8) -> LiveImage {
        LiveImage {
            stamp_ns,
            encoding: "rgb8".into(),
            width,
            height,
            step: 3 * width,
            big_endian: false,
            data: (0..3 * width * height)
                .map(|i| (i as u8).wrapping_mul(7).wrapping_add(seed))
                .collect(),
            depth: None,
        }
    }

    #[test]
    fn a_recording_reads_back_as_the_frames_the_scorer_decoded() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = Recorder::start(
            dir.path(),
            "robot/1 ..",
            &EpisodeTopics::default(),
            limits(1 << 30, 1 << 20),
        )
        .unwrap();
        let names = vec!["a".to_string(), "b".to_string()];
        let k = Intrinsics {
            width: 8,
            height: 6,
            fx: 10.0,
            fy: 11.0,
            cx: 4.0,
            cy: 3.0,
        };
        let mut sent = Vec::new();
        for i in 0..4u8 {
            let img = rgb(1_000_000_000 + i64::from(i) * 100_000_000, 8, 6, i);
            let positions = [0.1 * f64::from(i), -0.2];
            let efforts = [f64::from(i), -3.0];
            assert!(
                r.record(&img, Some((&names, &positions, &efforts)), Some(&k))
                    .unwrap()
            );
            sent.push(img);
        }
        // A PNG after raw images: one topic carries one type, so the recording ends.
        let mut png = Vec::new();
        image::GrayImage::from_fn(8, 6, |x, y| image::Luma([(x * 30 + y) as u8]))
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let file = LiveImage {
            stamp_ns: 1_400_000_000,
            encoding: "PNG".into(),
            width: 0,
            height: 0,
            step: 0,
            big_endian: false,
            data: png,
            depth: None,
        };
        let err = r.record(&file, None, None).unwrap_err();
        assert!(matches!(err, RecordingError::MixedImages), "{err}");
        // A robot that sends files has them recorded as CompressedImage.
        let mut files = Recorder::start(
            dir.path(),
            "png-robot",
            &EpisodeTopics::default(),
            limits(1 << 30, 1 << 20),
        )
        .unwrap();
        assert!(files.record(&file, None, None).unwrap());
        let png_path = files.finish().unwrap();
        let png_episode = McapEpisode::open(&png_path, &Default::default()).unwrap();
        let read: Vec<_> = png_episode.frames().map(Result::unwrap).collect();
        let (live, _) = super::super::worker::decode_live_image(&file, 1 << 20, None).unwrap();
        assert_eq!(read.len(), 1);
        assert_eq!(read[0].image, live);
        let name = r.file_name();
        assert!(!dir.path().join(&name).exists(), "in progress");
        let path = r.finish().unwrap();
        assert_eq!(path, dir.path().join(&name));
        assert!(
            name.starts_with("robot_1___-") && name.ends_with(".mcap"),
            "{name}"
        );
        // Read back, every frame decodes to the pixels the live decoder gives.
        let config = vamos_core::episode::EpisodeConfig::default();
        let episode = McapEpisode::open(&path, &config).unwrap();
        let frames: Vec<_> = episode.frames().map(Result::unwrap).collect();
        assert_eq!(frames.len(), 4);
        for (i, (f, img)) in frames.iter().zip(&sent).enumerate() {
            assert_eq!(f.stamp_ns, img.stamp_ns);
            let (live, _) = super::super::worker::decode_live_image(img, 1 << 20, None).unwrap();
            assert_eq!(f.image, live);
            let joints = f.joints.as_ref().unwrap();
            assert_eq!(joints.names, names);
            assert_eq!(joints.efforts, vec![i as f64, -3.0], "efforts recorded");
            assert_eq!(f.camera_info.as_ref().unwrap().intrinsics().unwrap(), k);
        }
    }

    #[test]
    fn limits_stop_a_long_session_and_make_room_for_new_ones() {
        let dir = tempfile::tempdir().unwrap();
        let img = |t| rgb(t, 100, 40, 1); // 12,000 bytes
        // One session: two frames fit, the third does not.
        let mut r = Recorder::start(
            dir.path(),
            "a",
            &EpisodeTopics::default(),
            limits(1 << 20, 25_000),
        )
        .unwrap();
        assert!(r.record(&img(1), None, None).unwrap());
        assert!(r.record(&img(2), None, None).unwrap());
        assert!(!r.record(&img(3), None, None).unwrap());
        let a = r.finish().unwrap();
        let kept = Recorder::start(
            dir.path(),
            "b",
            &EpisodeTopics::default(),
            limits(1 << 20, 25_000),
        )
        .unwrap();
        let b = kept.finish().unwrap();
        let b_name = b.file_name().unwrap().to_string_lossy().into_owned();
        assert!(keep(dir.path(), &b_name).unwrap());
        assert!(!keep(dir.path(), "nobody.mcap").unwrap());
        assert!(!keep(dir.path(), "../escape.mcap").unwrap());
        // A budget that holds only the new session: the oldest unkept one goes, the kept
        // one stays.
        let used = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().metadata().unwrap().len())
            .sum::<u64>();
        let c = Recorder::start(
            dir.path(),
            "c",
            &EpisodeTopics::default(),
            limits(used - 1 + 25_000, 25_000),
        );
        let c = c.unwrap();
        assert!(!a.exists(), "the oldest unkept recording made room");
        assert!(b.exists(), "a kept recording stays");
        // Nothing left to remove: the next session is not recorded.
        let err = Recorder::start(
            dir.path(),
            "d",
            &EpisodeTopics::default(),
            limits(1, 25_000),
        )
        .unwrap_err();
        assert!(matches!(err, RecordingError::Full { .. }), "{err}");
        c.finish().unwrap();
    }

    #[test]
    fn a_recording_left_in_progress_is_recovered_as_a_finished_one_that_can_make_room() {
        let dir = tempfile::tempdir().unwrap();
        let mut r = Recorder::start(
            dir.path(),
            "killed",
            &EpisodeTopics::default(),
            limits(1 << 30, 1 << 20),
        )
        .unwrap();
        r.record(&rgb(1_000_000, 8, 6, 1), None, None).unwrap();
        let name = r.file_name();
        drop(r); // never finished, as when the server is killed
        let part = dir.path().join(format!("{name}.part"));
        assert!(part.is_file());
        assert_eq!(
            make_room(dir.path(), 0).unwrap(),
            part.metadata().unwrap().len(),
            "a part is never removed"
        );
        assert_eq!(recover_interrupted(dir.path()).unwrap(), 1);
        assert!(dir.path().join(&name).is_file());
        assert!(!part.exists());
        assert_eq!(make_room(dir.path(), 0).unwrap(), 0, "now it makes room");
        assert!(!dir.path().join(&name).exists());
        assert_eq!(recover_interrupted(&dir.path().join("none")).unwrap(), 0);
    }
}
