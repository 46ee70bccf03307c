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

/// Whether the file at `path` starts with zstd's frame magic (rosbag2's file
/// compression, `.mcap.zstd`), whatever its name.
pub fn is_zstd_file(path: &Path) -> Result<bool, EpisodeError> {
    let mut file = File::open(path).map_err(|e| io_err(path, e))?;
    let mut magic = [0u8; 4];
    let mut n = 0;
    while n < magic.len() {
        match file.read(&mut magic[n..]) {
            Ok(0) => return Ok(false),
            Ok(k) => n += k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e) => return Err(io_err(path, e)),
        }
    }
    Ok(magic == super::assemble::ZSTD_MAGIC)
}

/// Decompresses the zstd-compressed file at `path` into `out`, at most `limit` bytes
/// (more is an error naming `[episode] max_decompressed_bytes`); returns the bytes
/// written. A write error of `out` comes back as an [`EpisodeError::Mcap`] with its
/// message (a writer that refuses bytes keeps its own typed reason for its caller).
pub fn decompress_zstd_into(
    path: &Path,
    limit: u64,
    out: &mut impl std::io::Write,
) -> Result<u64, EpisodeError> {
    let err = |reason: String| EpisodeError::Mcap {
        path: path.display().to_string(),
        reason,
    };
    let file = File::open(path).map_err(|e| io_err(path, e))?;
    let decoder = zstd::stream::read::Decoder::new(file)
        .map_err(|e| err(format!("zstd-compressed file: {e}")))?;
    let mut input = decoder.take(limit + 1);
    let mut buf = vec![0u8; 1 << 16];
    let mut copied = 0u64;
    loop {
        let n = match input.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(err(format!("zstd-compressed file: {e}"))),
        };
        copied += n as u64;
        if copied > limit {
            return Err(err(format!(
                "decompresses to more than {limit} bytes ([episode] max_decompressed_bytes)"
            )));
        }
        out.write_all(&buf[..n]).map_err(|e| io_err(path, e))?;
    }
    Ok(copied)
}

/// A zstd-compressed MCAP file (rosbag2's file compression, `.mcap.zstd`) decompressed
/// into a temporary file, at most `limit` bytes.
pub(super) fn decompress_file(
    path: &Path,
    limit: u64,
) -> Result<tempfile::NamedTempFile, EpisodeError> {
    let mut copy = tempfile::Builder::new()
        .prefix("vamos-episode-")
        .suffix(".mcap")
        .tempfile()
        .map_err(|e| EpisodeError::Mcap {
            path: path.display().to_string(),
            reason: format!("cannot make a temporary file to decompress into: {e}"),
        })?;
    decompress_zstd_into(path, limit, copy.as_file_mut())?;
    Ok(copy)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn zstd_files_are_told_by_their_magic_and_decompressed_within_the_limit() {
        let dir = tempfile::tempdir().unwrap();
        let raw = vec![7u8; 200_000];
        let mut streamed = zstd::stream::write::Encoder::new(Vec::new(), 3).unwrap();
        std::io::Write::write_all(&mut streamed, &raw).unwrap();
        let packed = dir.path().join("a.mcap.zstd");
        std::fs::write(&packed, streamed.finish().unwrap()).unwrap();
        assert!(is_zstd_file(&packed).unwrap());
        let mut out = Vec::new();
        assert_eq!(
            decompress_zstd_into(&packed, 200_000, &mut out).unwrap(),
            200_000
        );
        assert_eq!(out, raw);
        let err = decompress_zstd_into(&packed, 199_999, &mut Vec::new()).unwrap_err();
        assert!(err.to_string().contains("more than 199999 bytes"), "{err}");
        let copy = decompress_file(&packed, 1 << 20).unwrap();
        assert_eq!(std::fs::read(copy.path()).unwrap(), raw);
        // Not compressed, shorter than the magic, empty, missing.
        for (name, bytes) in [
            ("plain.mcap", &b"\x89MCAP0\r\n"[..]),
            ("short", &b"\x28\xb5"[..]),
            ("empty", &b""[..]),
        ] {
            let p = dir.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            assert!(!is_zstd_file(&p).unwrap(), "{name}");
        }
        assert!(is_zstd_file(&dir.path().join("missing")).is_err());
    }
}
