//! The training dataset `vamos export-dataset` writes (format: `docs/model-bundle.md`):
//! one `<episode>.npy` (float32 `[T, 2, S, S]`) per episode and a `manifest.json`.

use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use vamos_model::FlowVariant;
use vamos_vision::preprocess::NetworkInputParams;

/// The dataset format this build writes and reads.
pub const DATASET_FORMAT_VERSION: u32 = 1;

/// Errors of writing or reading a dataset.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// File-system error.
    #[error("{path}: {reason}")]
    Io {
        /// The path.
        path: String,
        /// The system's reason.
        reason: String,
    },
    /// Two episodes with the same name.
    #[error("episode name {name:?} is used twice")]
    DuplicateEpisode {
        /// The name.
        name: String,
    },
    /// An episode name that is not a plain file name.
    #[error("episode name {name:?} is not usable as a file name")]
    BadName {
        /// The name.
        name: String,
    },
    /// Rows and frame records disagree.
    #[error("episode {name}: {values} values do not make {frames} rows of {row_len}")]
    RowMismatch {
        /// Episode.
        name: String,
        /// Values given.
        values: usize,
        /// Frame records given.
        frames: usize,
        /// Values per row.
        row_len: usize,
    },
    /// A `.npy` file this reader does not understand.
    #[error("{path}: not a little-endian float32 C-order .npy file ({reason})")]
    BadNpy {
        /// The path.
        path: String,
        /// What is wrong.
        reason: String,
    },
}

fn io_err(path: &Path) -> impl Fn(std::io::Error) -> DatasetError + '_ {
    move |e| DatasetError::Io {
        path: path.display().to_string(),
        reason: e.to_string(),
    }
}

/// Network-input parameters as recorded in the manifest.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    /// Side of the square input.
    pub size: usize,
    /// Flow magnitude mapped to 0.5, pixels of the reference width.
    pub clip_px: f32,
    /// Reference width, pixels.
    pub reference_width_px: usize,
}

impl From<&NetworkInputParams> for InputSpec {
    fn from(p: &NetworkInputParams) -> Self {
        Self {
            size: p.size_px,
            clip_px: p.clip_px,
            reference_width_px: p.reference_width_px,
        }
    }
}

/// Processing resolution and frame stride.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProcessingSpec {
    /// Processing width, pixels.
    pub width: usize,
    /// Processing height, pixels.
    pub height: usize,
    /// Flow between image `k - stride` and image `k`.
    pub stride: usize,
}

/// One exported frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameRecord {
    /// Index of the image the flow ends at (in the episode's image stream).
    pub index: usize,
    /// Its stamp, nanoseconds.
    pub stamp_ns: i64,
}

/// One exported episode.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct EpisodeRecord {
    /// Episode name.
    pub name: String,
    /// Its `.npy` file, relative to the dataset folder.
    pub file: String,
    /// One record per row of the `.npy`.
    pub frames: Vec<FrameRecord>,
}

/// `manifest.json` of a dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetManifest {
    /// Always `vamos-dataset`.
    pub format: String,
    /// [`DATASET_FORMAT_VERSION`].
    pub format_version: u32,
    /// Network input.
    pub input: InputSpec,
    /// Flow variant of the rows.
    pub flow_variant: FlowVariant,
    /// Processing resolution and stride.
    pub processing: ProcessingSpec,
    /// Episodes.
    pub episodes: Vec<EpisodeRecord>,
}

/// Writes a dataset folder episode by episode; [`DatasetWriter::finish`] writes the
/// manifest last, so a folder with a manifest is complete.
pub struct DatasetWriter {
    dir: PathBuf,
    manifest: DatasetManifest,
}

impl DatasetWriter {
    /// Creates `dir` (and parents) for a dataset of the given kind.
    pub fn create(
        dir: &Path,
        input: InputSpec,
        flow_variant: FlowVariant,
        processing: ProcessingSpec,
    ) -> Result<Self, DatasetError> {
        std::fs::create_dir_all(dir).map_err(io_err(dir))?;
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest: DatasetManifest {
                format: "vamos-dataset".into(),
                format_version: DATASET_FORMAT_VERSION,
                input,
                flow_variant,
                processing,
                episodes: Vec::new(),
            },
        })
    }

    /// Values per row (`2 * size * size`).
    pub fn row_len(&self) -> usize {
        2 * self.manifest.input.size * self.manifest.input.size
    }

    /// Adds an episode: `rows` holds `frames.len()` network inputs back to back.
    pub fn add_episode(
        &mut self,
        name: &str,
        frames: Vec<FrameRecord>,
        rows: &[f32],
    ) -> Result<(), DatasetError> {
        if name.is_empty()
            || name.starts_with('.')
            || name.contains(['/', '\\'])
            || name == "manifest"
        {
            return Err(DatasetError::BadName { name: name.into() });
        }
        if self.manifest.episodes.iter().any(|e| e.name == name) {
            return Err(DatasetError::DuplicateEpisode { name: name.into() });
        }
        let row_len = self.row_len();
        if rows.len() != frames.len() * row_len {
            return Err(DatasetError::RowMismatch {
                name: name.into(),
                values: rows.len(),
                frames: frames.len(),
                row_len,
            });
        }
        let file = format!("{name}.npy");
        let s = self.manifest.input.size;
        write_npy_f32(&self.dir.join(&file), &[frames.len(), 2, s, s], rows)?;
        self.manifest.episodes.push(EpisodeRecord {
            name: name.into(),
            file,
            frames,
        });
        Ok(())
    }

    /// Writes `manifest.json` (atomically) and returns it.
    pub fn finish(self) -> Result<DatasetManifest, DatasetError> {
        let path = self.dir.join("manifest.json");
        let tmp = self.dir.join(".manifest.json.tmp");
        let text = serde_json::to_string_pretty(&self.manifest).map_err(|e| DatasetError::Io {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        std::fs::write(&tmp, text).map_err(io_err(&tmp))?;
        std::fs::rename(&tmp, &path).map_err(io_err(&path))?;
        Ok(self.manifest)
    }
}

/// Writes a little-endian float32 C-order `.npy` (npyz; format 1.0, the header padded so
/// the data starts on a 64-byte boundary), through a temporary file and a rename.
pub fn write_npy_f32(path: &Path, shape: &[usize], data: &[f32]) -> Result<(), DatasetError> {
    let shape: Vec<u64> = shape.iter().map(|&d| d as u64).collect();
    let tmp = path.with_extension("npy.tmp");
    let write = || -> std::io::Result<()> {
        use npyz::WriterBuilder;
        let mut f = std::io::BufWriter::new(std::fs::File::create(&tmp)?);
        let mut npy = npyz::WriteOptions::<f32>::new()
            .default_dtype()
            .shape(&shape)
            .writer(&mut f)
            .begin_nd()?;
        npy.extend(data.iter().copied())?;
        npy.finish()?;
        f.into_inner().map_err(|e| e.into_error())?.sync_all()
    };
    write().map_err(io_err(&tmp))?;
    std::fs::rename(&tmp, path).map_err(io_err(path))
}

/// Reads a `.npy` written by [`write_npy_f32`] (or numpy: little-endian float32, C order,
/// format 1.0 or 2.0). Returns the shape and the values.
pub fn read_npy_f32(path: &Path) -> Result<(Vec<usize>, Vec<f32>), DatasetError> {
    let bytes = std::fs::read(path).map_err(io_err(path))?;
    parse_npy_f32(&bytes, &path.display().to_string())
}

/// Parses the bytes of a `.npy` (as [`read_npy_f32`]; `name` labels errors), e.g. a member
/// of an `.npz`. The header is read by npyz; the data length is checked against the
/// shape before anything is allocated for it.
pub fn parse_npy_f32(bytes: &[u8], name: &str) -> Result<(Vec<usize>, Vec<f32>), DatasetError> {
    let bad = |reason: &str| DatasetError::BadNpy {
        path: name.to_string(),
        reason: reason.into(),
    };
    // npyz allocates the header length the file claims before reading it: check the claim
    // against the bytes there are (version 1 has a u16 length at 8, later ones a u32).
    let claimed = match bytes.get(6) {
        Some(1) => bytes
            .get(8..10)
            .map(|b| u16::from_le_bytes([b[0], b[1]]) as usize),
        Some(_) => bytes
            .get(8..12)
            .map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize),
        None => None,
    };
    if !bytes.starts_with(b"\x93NUMPY") || claimed.is_none_or(|n| n > bytes.len()) {
        return Err(bad("no .npy magic, or a truncated header"));
    }
    let mut reader = std::io::Cursor::new(bytes);
    let header = npyz::NpyHeader::from_reader(&mut reader).map_err(|e| bad(&e.to_string()))?;
    match header.dtype() {
        npyz::DType::Plain(t) if t.to_string() == "<f4" => {}
        other => return Err(bad(&format!("dtype is {}, not '<f4'", other.descr()))),
    }
    if header.order() != npyz::Order::C {
        return Err(bad("Fortran order"));
    }
    let shape: Vec<usize> = header
        .shape()
        .iter()
        .map(|&d| usize::try_from(d).map_err(|_| bad("bad shape")))
        .collect::<Result<_, _>>()?;
    let body = bytes.len() - reader.position() as usize;
    let expected = shape.iter().try_fold(4usize, |acc, &d| acc.checked_mul(d));
    if expected != Some(body) {
        return Err(bad("data length does not match the shape"));
    }
    let data = npyz::NpyFile::with_header(header, reader)
        .into_vec::<f32>()
        .map_err(|e| bad(&e.to_string()))?;
    Ok((shape, data))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn writer(dir: &Path) -> DatasetWriter {
        DatasetWriter::create(
            dir,
            InputSpec {
                size: 4,
                clip_px: 15.0,
                reference_width_px: 640,
            },
            FlowVariant::Masked,
            ProcessingSpec {
                width: 64,
                height: 48,
                stride: 3,
            },
        )
        .unwrap()
    }

    #[test]
    fn npy_round_trip_and_header_alignment() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.npy");
        let data: Vec<f32> = (0..24).map(|i| i as f32 * 0.5 - 3.0).collect();
        write_npy_f32(&path, &[2, 3, 4], &data).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        assert_eq!((bytes.len() - 24 * 4) % 64, 0);
        let (shape, back) = read_npy_f32(&path).unwrap();
        assert_eq!(shape, [2, 3, 4]);
        assert_eq!(back, data);
        write_npy_f32(&path, &[3], &[1.0, 2.0, 3.0]).unwrap();
        assert_eq!(read_npy_f32(&path).unwrap().0, [3]);
        std::fs::write(&path, &bytes[..bytes.len() - 1]).unwrap();
        assert!(matches!(
            read_npy_f32(&path),
            Err(DatasetError::BadNpy { .. })
        ));
    }

    #[test]
    fn writer_checks_names_rows_and_writes_the_manifest_last() {
        let dir = tempfile::tempdir().unwrap();
        let mut w = writer(dir.path());
        let frames = vec![
            FrameRecord {
                index: 3,
                stamp_ns: 300,
            },
            FrameRecord {
                index: 6,
                stamp_ns: 600,
            },
        ];
        let rows = vec![0.25f32; 2 * 32];
        assert!(matches!(
            w.add_episode("e1", frames.clone(), &rows[1..]),
            Err(DatasetError::RowMismatch { .. })
        ));
        assert!(matches!(
            w.add_episode("../e", frames.clone(), &rows),
            Err(DatasetError::BadName { .. })
        ));
        w.add_episode("e1", frames.clone(), &rows).unwrap();
        assert!(matches!(
            w.add_episode("e1", frames.clone(), &rows),
            Err(DatasetError::DuplicateEpisode { .. })
        ));
        assert!(!dir.path().join("manifest.json").exists());
        let m = w.finish().unwrap();
        let text = std::fs::read_to_string(dir.path().join("manifest.json")).unwrap();
        let back: DatasetManifest = serde_json::from_str(&text).unwrap();
        assert_eq!(back, m);
        assert!(text.contains("\"flow_variant\": \"masked\""));
        let (shape, data) = read_npy_f32(&dir.path().join("e1.npy")).unwrap();
        assert_eq!(shape, [2, 2, 4, 4]);
        assert_eq!(data, rows);
    }
}
