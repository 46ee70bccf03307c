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
    let compressed = file.metadata().map_err(|e| io_err(path, e))?.len();
    let by_ratio = compressed
        .saturating_mul(MAX_ZSTD_RATIO)
        .max(MIN_RATIO_ALLOWANCE);
    let decoder = zstd::stream::read::Decoder::new(file)
        .map_err(|e| err(format!("zstd-compressed file: {e}")))?;
    let mut input = decoder.take(limit.min(by_ratio) + 1);
    let mut buf = vec![0u8; 1 << 16];
    let mut copied = 0u64;
    // The first bytes out must be MCAP's magic before anything is written.
    let mut head = Vec::with_capacity(MCAP_MAGIC.len());
    loop {
        let n = match input.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(err(format!("zstd-compressed file: {e}"))),
        };
        if head.len() < MCAP_MAGIC.len() {
            let take = (MCAP_MAGIC.len() - head.len()).min(n);
            head.extend_from_slice(&buf[..take]);
            if !MCAP_MAGIC.starts_with(&head) {
                return Err(err(NOT_MCAP.into()));
            }
        }
        copied += n as u64;
        if copied > limit {
            return Err(err(format!(
                "decompresses to more than {limit} bytes ([episode] max_decompressed_bytes)"
            )));
        }
        if copied > by_ratio {
            return Err(err(format!(
                "decompresses to more than {MAX_ZSTD_RATIO} times its {compressed} bytes \
                 (a decompression bomb, not a recording)"
            )));
        }
        out.write_all(&buf[..n]).map_err(|e| io_err(path, e))?;
    }
    if head.len() < MCAP_MAGIC.len() {
        return Err(err(NOT_MCAP.into()));
    }
    Ok(copied)
}

/// The first bytes of every MCAP file.
const MCAP_MAGIC: &[u8; 8] = b"\x89MCAP0\r\n";

const NOT_MCAP: &str =
    "the zstd-compressed data is not an MCAP file (it does not begin with MCAP's magic)";

/// Most bytes a zstd-compressed recording may expand to per compressed byte. Recordings
/// of JPEG or PNG frames hardly compress (the demo's and the test fixture's episodes: a
/// ratio of 1.0 at zstd -3 and -19), raw sensor frames far less than this; constant data
/// reaches ~32,000 (100 MB of zeros at zstd -19: 3 KB), which only a bomb sends.
const MAX_ZSTD_RATIO: u64 = 1000;

/// Bytes any compressed file may expand to whatever its ratio (tiny test recordings).
const MIN_RATIO_ALLOWANCE: u64 = 16 << 20;

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
        let mut raw = MCAP_MAGIC.to_vec();
        raw.resize(200_000, 7);
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

    fn packed(dir: &Path, name: &str, raw: &[u8]) -> std::path::PathBuf {
        let path = dir.join(name);
        std::fs::write(&path, zstd::encode_all(raw, 19).unwrap()).unwrap();
        path
    }

    #[test]
    fn compressed_data_that_is_no_mcap_or_a_bomb_is_refused_before_it_is_written() {
        let dir = tempfile::tempdir().unwrap();
        // 64 MiB of zeros: no MCAP magic. Nothing is written.
        let zeros = packed(dir.path(), "zeros.zstd", &vec![0u8; 64 << 20]);
        let mut out = Vec::new();
        let err = decompress_zstd_into(&zeros, 1 << 40, &mut out).unwrap_err();
        assert!(err.to_string().contains("not an MCAP file"), "{err}");
        assert!(out.is_empty());
        // The magic and then 64 MiB of zeros: past 1000 times the compressed size.
        let mut bomb = MCAP_MAGIC.to_vec();
        bomb.resize(64 << 20, 0);
        let bomb = packed(dir.path(), "bomb.zstd", &bomb);
        let compressed = std::fs::metadata(&bomb).unwrap().len();
        assert!(compressed * MAX_ZSTD_RATIO < 64 << 20, "{compressed}");
        let mut sink = std::io::sink();
        let err = decompress_zstd_into(&bomb, 1 << 40, &mut sink).unwrap_err();
        assert!(err.to_string().contains("decompression bomb"), "{err}");
        // Shorter than the magic.
        let short = packed(dir.path(), "short.zstd", b"\x89MC");
        let err = decompress_zstd_into(&short, 1 << 40, &mut Vec::new()).unwrap_err();
        assert!(err.to_string().contains("not an MCAP file"), "{err}");
    }
}
