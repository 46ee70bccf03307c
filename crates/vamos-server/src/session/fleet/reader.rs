//! The reader's side: the manifest's files downloaded and checked, then applied to the
//! data directory in one step.

use super::{Fleet, FleetError, Manifest};
use crate::store::{MirrorChange, StoredFile, hex};
use futures_util::StreamExt;
use sha2::{Digest, Sha256};
use std::collections::HashMap;

impl Fleet {
    pub(super) async fn reader_round(&self) -> Result<MirrorChange, FleetError> {
        let Some(m) = self.manifest().await? else {
            tracing::debug!(url = %self.url, "nothing published yet");
            return Ok(MirrorChange::default());
        };
        let applied = self
            .state()
            .synced
            .as_ref()
            .is_some_and(|s| s.generation == m.generation && s.writer == m.writer);
        if applied {
            return Ok(MirrorChange::default());
        }
        let change = self.apply(&m).await?;
        if !change.is_empty() {
            tracing::info!(
                url = %self.url,
                generation = m.generation,
                written = change.written.len(),
                removed = change.removed.len(),
                "applied the fleet's publication"
            );
        }
        self.state().synced = Some(m);
        Ok(change)
    }

    /// Downloads what this data directory lacks of `m`, checks it, and applies it.
    pub(super) async fn apply(&self, m: &Manifest) -> Result<MirrorChange, FleetError> {
        let local: HashMap<String, String> = self
            .local_files()
            .await?
            .into_iter()
            .map(|f| (f.path, f.sha256))
            .collect();
        let staging = self.store.dir().join("tmp").join(format!(
            "fleet-{}-{}",
            std::process::id(),
            m.generation
        ));
        tokio::fs::create_dir_all(&staging)
            .await
            .map_err(|e| FleetError::Io {
                path: staging.clone(),
                source: e,
            })?;
        let result = async {
            let mut staged = HashMap::new();
            for f in &m.files {
                if local.get(&f.path) == Some(&f.sha256) || staged.contains_key(&f.sha256) {
                    continue;
                }
                let target = staging.join(&f.sha256);
                self.download_blob(f, &target).await?;
                staged.insert(f.sha256.clone(), target);
            }
            let store = self.store.clone();
            let files = m.files.clone();
            Ok::<_, FleetError>(
                tokio::task::spawn_blocking(move || store.apply_mirror(&files, &staged))
                    .await
                    .map_err(|e| self.content_err(format!("apply task failed: {e}")))??,
            )
        }
        .await;
        let _ = tokio::fs::remove_dir_all(&staging).await;
        result
    }

    async fn download_blob(
        &self,
        f: &StoredFile,
        target: &std::path::Path,
    ) -> Result<(), FleetError> {
        if f.sha256.len() != 64 || !f.sha256.bytes().all(|b| b.is_ascii_hexdigit()) {
            return Err(self.content_err(format!("{}: bad sha256 {:?}", f.path, f.sha256)));
        }
        let got = self
            .remote
            .get(&self.blob_path(&f.sha256))
            .await
            .map_err(|e| self.remote_err(e))?;
        let io = |e| FleetError::Io {
            path: target.to_path_buf(),
            source: e,
        };
        let mut out = tokio::fs::File::create(target).await.map_err(io)?;
        let mut hasher = Sha256::new();
        let mut total = 0u64;
        let mut stream = got.into_stream();
        while let Some(chunk) = stream.next().await {
            let chunk = chunk.map_err(|e| self.remote_err(e))?;
            total += chunk.len() as u64;
            if total > f.size {
                return Err(self.content_err(format!(
                    "blob of {} is larger than its {} bytes",
                    f.path, f.size
                )));
            }
            hasher.update(&chunk);
            tokio::io::AsyncWriteExt::write_all(&mut out, &chunk)
                .await
                .map_err(io)?;
        }
        tokio::io::AsyncWriteExt::flush(&mut out)
            .await
            .map_err(io)?;
        let sha = hex(&hasher.finalize());
        if sha != f.sha256 || total != f.size {
            return Err(self.content_err(format!(
                "blob of {} does not match: {total} bytes with sha256 {sha}, listed {} bytes with {}",
                f.path, f.size, f.sha256
            )));
        }
        Ok(())
    }
}
