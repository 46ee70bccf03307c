//! Episode files named on a command line or in a request: a file stands for itself, a
//! folder for the `.mcap` files directly inside it. One expander for the CLI and the
//! service's calibration jobs.

use std::path::{Path, PathBuf};

/// Why a list of episode paths does not expand.
#[derive(Debug, thiserror::Error)]
pub enum ExpandError {
    /// A folder that cannot be listed.
    #[error("cannot list {path}: {source}")]
    List {
        /// The folder.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A folder without `.mcap` files.
    #[error("{path} holds no .mcap episodes")]
    EmptyFolder {
        /// The folder.
        path: PathBuf,
    },
    /// A path that is neither a file nor a folder.
    #[error("{path}: no such episode file or folder")]
    Missing {
        /// The path.
        path: PathBuf,
    },
}

/// The `.mcap` files directly inside `dir`, sorted.
pub fn mcap_files_in(dir: &Path) -> Result<Vec<PathBuf>, ExpandError> {
    let mut found: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|source| ExpandError::List {
            path: dir.to_path_buf(),
            source,
        })?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|f| f.extension().is_some_and(|x| x == "mcap"))
        .collect();
    found.sort();
    Ok(found)
}

/// Expands folders into the `.mcap` files they hold (sorted); files pass through. A
/// folder without episodes and a path that does not exist are errors (a typo must not
/// silently shrink the set).
pub fn expand_episodes(paths: &[PathBuf]) -> Result<Vec<PathBuf>, ExpandError> {
    let mut out = Vec::new();
    for p in paths {
        if p.is_dir() {
            let found = mcap_files_in(p)?;
            if found.is_empty() {
                return Err(ExpandError::EmptyFolder { path: p.clone() });
            }
            out.extend(found);
        } else if p.is_file() {
            out.push(p.clone());
        } else {
            return Err(ExpandError::Missing { path: p.clone() });
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn folders_expand_and_empty_or_missing_ones_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let empty = dir.path().join("empty");
        std::fs::create_dir(&empty).unwrap();
        let full = dir.path().join("full");
        std::fs::create_dir(&full).unwrap();
        for n in ["b.mcap", "a.mcap", "notes.txt"] {
            std::fs::write(full.join(n), b"").unwrap();
        }
        let got = expand_episodes(std::slice::from_ref(&full)).unwrap();
        assert_eq!(got, vec![full.join("a.mcap"), full.join("b.mcap")]);
        assert!(matches!(
            expand_episodes(&[empty]),
            Err(ExpandError::EmptyFolder { .. })
        ));
        assert!(matches!(
            expand_episodes(&[dir.path().join("nothing.mcap")]),
            Err(ExpandError::Missing { .. })
        ));
    }
}
