//! Episode names and files: bag folders of split files, `.mcap.zstd` decompressed.

use super::*;

/// The episode name of a file or bag folder: the file name without `.mcap` and a
/// compression suffix, or the folder's name.
pub(super) fn episode_name(path: &Path) -> String {
    let file = path
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "episode".into());
    let mut name = file.as_str();
    for suffix in [".zstd", ".zst", ".mcap"] {
        name = name.strip_suffix(suffix).unwrap_or(name);
    }
    if name.is_empty() {
        "episode".into()
    } else {
        name.to_string()
    }
}

/// The MCAP files of a rosbag2 bag folder (what `ros2 bag record` writes: `metadata.yaml`
/// beside `<name>_0.mcap`, `<name>_1.mcap`, ..., each possibly `.zstd`-compressed), in
/// recording order (by the number after the last `_`, then by name).
pub(super) fn bag_folder_files(dir: &Path) -> Result<Vec<PathBuf>, EpisodeError> {
    let entries = std::fs::read_dir(dir).map_err(|e| io_err(dir, e))?;
    let mut files: Vec<(u64, String, PathBuf)> = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| io_err(dir, e))?.path();
        let name = path
            .file_name()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        if !path.is_file() || !(name.ends_with(".mcap") || name.ends_with(".mcap.zstd")) {
            continue;
        }
        let stem = episode_name(&path);
        let number = stem
            .rsplit_once('_')
            .and_then(|(_, n)| n.parse::<u64>().ok())
            .unwrap_or(0);
        files.push((number, name, path));
    }
    files.sort();
    if files.is_empty() {
        return Err(EpisodeError::Mcap {
            path: dir.display().to_string(),
            reason: "a folder without .mcap files (a rosbag2 bag folder holds metadata.yaml \
                     and <name>_<n>.mcap files)"
                .into(),
        });
    }
    Ok(files.into_iter().map(|(_, _, p)| p).collect())
}

/// A zstd-compressed MCAP file (rosbag2's file compression, `.mcap.zstd`) decompressed
/// into a temporary file, at most `limit` bytes.
pub(super) fn decompress_file(
    path: &Path,
    limit: u64,
) -> Result<tempfile::NamedTempFile, EpisodeError> {
    let err = |reason: String| EpisodeError::Mcap {
        path: path.display().to_string(),
        reason,
    };
    let file = File::open(path).map_err(|e| io_err(path, e))?;
    let mut decoder = zstd::stream::read::Decoder::new(file)
        .map_err(|e| err(format!("zstd-compressed file: {e}")))?;
    let mut copy = tempfile::Builder::new()
        .prefix("vamos-episode-")
        .suffix(".mcap")
        .tempfile()
        .map_err(|e| {
            err(format!(
                "cannot make a temporary file to decompress into: {e}"
            ))
        })?;
    let copied = std::io::copy(&mut (&mut decoder).take(limit + 1), copy.as_file_mut())
        .map_err(|e| err(format!("zstd-compressed file: {e}")))?;
    if copied > limit {
        return Err(err(format!(
            "decompresses to more than {limit} bytes ([episode] max_decompressed_bytes)"
        )));
    }
    Ok(copy)
}
