//! An episode as a folder of images.
//!
//! Layout: image files (`.png`, `.jpg`, `.jpeg`, any case) in one folder. Stamps come from
//! an optional `frames.csv` with the header `file,stamp_ns` (one row per image, file names
//! relative to the folder); without it, images are taken in file-name order at a fixed
//! period. Stamps must increase strictly: an out-of-order row is an error that names it.

use std::path::{Path, PathBuf};

/// Errors of reading episodes.
#[derive(Debug, thiserror::Error)]
pub enum EpisodeError {
    /// A file or folder could not be read.
    #[error("cannot read {path}: {reason}")]
    Io {
        /// The path.
        path: String,
        /// The system's reason.
        reason: String,
    },
    /// The folder holds no images.
    #[error("episode folder {path} holds no .png/.jpg images")]
    NoImages {
        /// The folder.
        path: String,
    },
    /// `frames.csv` is malformed.
    #[error("{path}, line {line}: {reason}")]
    BadIndex {
        /// The index file.
        path: String,
        /// 1-based line number.
        line: usize,
        /// What is wrong.
        reason: String,
    },
    /// The frame period is not positive.
    #[error("frame period must be positive, got {period_ns} ns")]
    BadPeriod {
        /// The period given.
        period_ns: i64,
    },
    /// An MCAP file could not be read or written (not a truncation of the data section).
    #[error("{path}: {reason}")]
    Mcap {
        /// The file.
        path: String,
        /// What failed.
        reason: String,
    },
    /// An MCAP file breaks off or is corrupt at `offset`; every valid message before it
    /// has been yielded.
    #[error("{path} is truncated or corrupt near byte {offset}: {reason}")]
    Truncated {
        /// The file.
        path: String,
        /// Byte offset in the file up to which records were read when the damage was found.
        offset: u64,
        /// The reader's reason.
        reason: String,
    },
    /// A topic is missing, ambiguous or of the wrong type.
    #[error("{path}: {reason}")]
    Topic {
        /// The file.
        path: String,
        /// What is wrong, with the candidate topics.
        reason: String,
    },
    /// One message could not be decoded or is invalid (NaN joint position, bad sizes...).
    #[error("{topic}, message {index}: {reason}")]
    BadMessage {
        /// The topic.
        topic: String,
        /// 0-based index of the message on its topic, in read order.
        index: usize,
        /// What is wrong.
        reason: String,
    },
    /// An image uses an encoding (or compressed format) vamos does not decode.
    #[error("{topic}, message {index}: unknown image encoding {encoding:?}")]
    UnknownEncoding {
        /// The topic.
        topic: String,
        /// 0-based image index.
        index: usize,
        /// The encoding.
        encoding: String,
    },
    /// An image's size differs from the episode's first image; later images of the first
    /// size still come.
    #[error(
        "image {index} is {width}x{height}, the episode's images are {expected_width}x{expected_height}"
    )]
    ImageSizeChanged {
        /// 0-based image index.
        index: usize,
        /// Width of the first image.
        expected_width: usize,
        /// Height of the first image.
        expected_height: usize,
        /// This image's width.
        width: usize,
        /// This image's height.
        height: usize,
    },
    /// A labels file or label message is malformed.
    #[error("labels {path}: {reason}")]
    Labels {
        /// The file or topic.
        path: String,
        /// What is wrong.
        reason: String,
    },
}

/// One image of a sequence.
#[derive(Debug, Clone, PartialEq)]
pub struct SequenceFrame {
    /// The image file.
    pub path: PathBuf,
    /// Its stamp, nanoseconds.
    pub stamp_ns: i64,
}

/// An episode stored as a folder of images.
#[derive(Debug, Clone, PartialEq)]
pub struct ImageSequence {
    /// The episode's name (the folder name).
    pub name: String,
    /// Frames in stamp order.
    pub frames: Vec<SequenceFrame>,
}

/// The optional index file's name.
pub const FRAMES_CSV: &str = "frames.csv";

impl ImageSequence {
    /// Reads the folder's listing (not the images). `period_ns` spaces the stamps when
    /// there is no `frames.csv` (first image at stamp 0).
    pub fn open(dir: &Path, period_ns: i64) -> Result<Self, EpisodeError> {
        if period_ns <= 0 {
            return Err(EpisodeError::BadPeriod { period_ns });
        }
        let io = |e: std::io::Error, p: &Path| EpisodeError::Io {
            path: p.display().to_string(),
            reason: e.to_string(),
        };
        let name = dir
            .canonicalize()
            .map_err(|e| io(e, dir))?
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "episode".into());
        let index = dir.join(FRAMES_CSV);
        let frames = if index.is_file() {
            let text = std::fs::read_to_string(&index).map_err(|e| io(e, &index))?;
            parse_index(dir, &index, &text)?
        } else {
            let mut files = Vec::new();
            for entry in std::fs::read_dir(dir).map_err(|e| io(e, dir))? {
                let path = entry.map_err(|e| io(e, dir))?.path();
                if path.is_file() && is_image(&path) {
                    files.push(path);
                }
            }
            files.sort();
            files
                .into_iter()
                .enumerate()
                .map(|(i, path)| SequenceFrame {
                    path,
                    stamp_ns: i as i64 * period_ns,
                })
                .collect()
        };
        if frames.is_empty() {
            return Err(EpisodeError::NoImages {
                path: dir.display().to_string(),
            });
        }
        Ok(Self { name, frames })
    }
}

fn is_image(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .map(|e| matches!(e.to_ascii_lowercase().as_str(), "png" | "jpg" | "jpeg"))
        .unwrap_or(false)
}

fn parse_index(dir: &Path, index: &Path, text: &str) -> Result<Vec<SequenceFrame>, EpisodeError> {
    let bad = |line: usize, reason: String| EpisodeError::BadIndex {
        path: index.display().to_string(),
        line,
        reason,
    };
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, header)) if header.trim() == "file,stamp_ns" => {}
        Some((_, header)) => {
            return Err(bad(
                1,
                format!("expected the header `file,stamp_ns`, got {header:?}"),
            ));
        }
        None => return Err(bad(1, "empty file".into())),
    }
    let mut frames: Vec<SequenceFrame> = Vec::new();
    for (i, line) in lines {
        let line_no = i + 1;
        if line.trim().is_empty() {
            continue;
        }
        let (file, stamp) = line
            .rsplit_once(',')
            .ok_or_else(|| bad(line_no, "expected `file,stamp_ns`".into()))?;
        let stamp_ns: i64 = stamp
            .trim()
            .parse()
            .map_err(|_| bad(line_no, format!("stamp {stamp:?} is not an integer")))?;
        let rel = Path::new(file.trim());
        if rel.is_absolute()
            || rel
                .components()
                .any(|c| matches!(c, std::path::Component::ParentDir))
        {
            return Err(bad(
                line_no,
                format!("{file:?} must be a path inside the folder"),
            ));
        }
        if let Some(prev) = frames.last()
            && stamp_ns <= prev.stamp_ns
        {
            return Err(bad(
                line_no,
                format!(
                    "stamp {stamp_ns} does not increase (previous {})",
                    prev.stamp_ns
                ),
            ));
        }
        frames.push(SequenceFrame {
            path: dir.join(rel),
            stamp_ns,
        });
    }
    Ok(frames)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(dir: &Path, name: &str) {
        std::fs::write(dir.join(name), b"x").unwrap();
    }

    #[test]
    fn sorted_listing_with_period() {
        let dir = tempfile::tempdir().unwrap();
        for n in ["b.png", "a.JPG", "c.txt", "d.jpeg"] {
            touch(dir.path(), n);
        }
        let s = ImageSequence::open(dir.path(), 100).unwrap();
        let names: Vec<_> = s
            .frames
            .iter()
            .map(|f| f.path.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        assert_eq!(names, ["a.JPG", "b.png", "d.jpeg"]);
        assert_eq!(s.frames[2].stamp_ns, 200);
        assert!(matches!(
            ImageSequence::open(dir.path(), 0),
            Err(EpisodeError::BadPeriod { .. })
        ));
    }

    #[test]
    fn index_file_gives_stamps_and_rejects_disorder() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(
            dir.path().join(FRAMES_CSV),
            "file,stamp_ns\nx.png,10\ny.png,25\n",
        )
        .unwrap();
        let s = ImageSequence::open(dir.path(), 1).unwrap();
        assert_eq!(s.frames[1].stamp_ns, 25);
        assert_eq!(s.frames[1].path, dir.path().join("y.png"));
        for (body, line) in [
            ("file,stamp_ns\nx.png,10\ny.png,10\n", 3),
            ("file,stamp_ns\nx.png,ten\n", 2),
            ("stamp,file\n", 1),
            ("file,stamp_ns\n../x.png,1\n", 2),
        ] {
            std::fs::write(dir.path().join(FRAMES_CSV), body).unwrap();
            match ImageSequence::open(dir.path(), 1) {
                Err(EpisodeError::BadIndex { line: l, .. }) => assert_eq!(l, line, "{body}"),
                other => panic!("{body}: {other:?}"),
            }
        }
    }

    #[test]
    fn empty_folder_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        assert!(matches!(
            ImageSequence::open(dir.path(), 1),
            Err(EpisodeError::NoImages { .. })
        ));
    }
}
