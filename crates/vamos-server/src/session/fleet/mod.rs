//! A store shared by a fleet of replicas (`[service.shared_store]`, `deploy/SCALING.md`).
//!
//! One replica is the **writer**: it takes the REST changes into its data directory, as a
//! lone server does, and publishes the directory's models, robots and profiles to the
//! shared store whenever they change. Every other replica is a **reader**: it polls the
//! shared store, makes its own data directory hold exactly what was published (so it
//! scores from local files, and keeps scoring from them when the shared store is
//! unreachable) and refuses changes with 409, naming the writer's role. New sessions see
//! a publication as soon as it is applied; running sessions keep the profile they
//! opened with, as on a single server.
//!
//! # Layout of the shared store
//!
//! ```text
//! <prefix>/manifest.json       {"format": "vamos-fleet/1", "generation", "writer", "published_unix_s", "files": [{path, sha256, size}]}
//! <prefix>/blobs/<sha256>      the content of every listed file, by its sha256
//! ```
//!
//! The manifest is the commit point: the writer uploads the blobs it names first, then
//! replaces the manifest (one PUT, atomic on S3 and on a file system), then deletes the
//! blobs no manifest names any more. A reader downloads what it lacks, checks every
//! sha256 and size, and only then changes its data directory (in one step under the
//! store's lock, [`Store::apply_mirror`]). A reader that finds a blob gone (a newer
//! publication collected it) retries on its next poll with the newer manifest.

mod reader;

use crate::config::{FleetRole, SharedStoreConfig};
use crate::store::{MirrorChange, Store, StoredFile, hex, now_unix_s};
use futures_util::StreamExt;
use object_store::path::Path as ObjectPath;
use object_store::{ObjectStore, PutPayload};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::HashSet;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// `format` of the manifest.
pub const MANIFEST_FORMAT: &str = "vamos-fleet/1";
/// Files larger than this are uploaded in parts of this size.
const PART_BYTES: usize = 16 << 20;
/// Longest manifest accepted, bytes.
const MAX_MANIFEST_BYTES: usize = 64 << 20;

/// What the writer publishes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// [`MANIFEST_FORMAT`].
    pub format: String,
    /// Counts up with every publication.
    pub generation: u64,
    /// Who published it (host name and process id).
    pub writer: String,
    /// When, seconds since the Unix epoch.
    pub published_unix_s: u64,
    /// The data directory's files.
    pub files: Vec<StoredFile>,
}

/// Errors of the shared store.
#[derive(Debug, thiserror::Error)]
pub enum FleetError {
    /// The settings name no usable store.
    #[error("service.shared_store: {0}")]
    Config(String),
    /// The object store failed.
    #[error("shared store {url}: {source}")]
    Remote {
        /// The store's URL.
        url: String,
        /// The error.
        source: object_store::Error,
    },
    /// What the shared store holds is not a publication of this version.
    #[error("shared store {url}: {reason}")]
    Content {
        /// The store's URL.
        url: String,
        /// What is wrong.
        reason: String,
    },
    /// The local data directory.
    #[error("data directory: {0}")]
    Store(#[from] crate::store::StoreError),
    /// Local I/O while staging downloads.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: std::path::PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

/// The replica's view of the shared store, for `GET /v1/store` and the metrics.
#[derive(Debug, Clone, Default, Serialize, schemars::JsonSchema)]
pub struct FleetStatus {
    /// `writer` or `reader`.
    pub role: &'static str,
    /// The shared store (credentials are never part of it).
    pub url: String,
    /// The generation published (writer) or applied (reader); 0: none yet.
    pub generation: u64,
    /// Files in that generation.
    pub files: usize,
    /// Last successful publication or check, seconds since the Unix epoch.
    pub last_sync_unix_s: Option<u64>,
    /// The last error, cleared by the next success.
    pub last_error: Option<String>,
}

/// One replica's link to the shared store.
pub struct Fleet {
    remote: Arc<dyn ObjectStore>,
    prefix: ObjectPath,
    url: String,
    role: FleetRole,
    poll: Duration,
    store: Store,
    writer_id: String,
    state: Mutex<FleetState>,
}

#[derive(Default)]
struct FleetState {
    /// What the writer last published, or the reader last applied.
    synced: Option<Manifest>,
    /// Blobs known to be in the shared store (writer).
    blobs: Option<HashSet<String>>,
    last_sync_unix_s: Option<u64>,
    last_error: Option<String>,
}

/// The object store and prefix a URL names: `file:///path` or `s3://bucket/prefix`.
fn open_remote(url: &str) -> Result<(Arc<dyn ObjectStore>, ObjectPath), FleetError> {
    let parsed = url::Url::parse(url).map_err(|e| FleetError::Config(format!("{url:?}: {e}")))?;
    match parsed.scheme() {
        "file" => {
            let dir = parsed
                .to_file_path()
                .map_err(|()| FleetError::Config(format!("{url:?} is not an absolute path")))?;
            std::fs::create_dir_all(&dir).map_err(|e| FleetError::Io {
                path: dir.clone(),
                source: e,
            })?;
            let fs = object_store::local::LocalFileSystem::new_with_prefix(&dir).map_err(|e| {
                FleetError::Remote {
                    url: url.into(),
                    source: e,
                }
            })?;
            Ok((Arc::new(fs), ObjectPath::default()))
        }
        "s3" | "s3a" => {
            let s3 = object_store::aws::AmazonS3Builder::from_env()
                .with_url(url)
                .build()
                .map_err(|e| FleetError::Remote {
                    url: url.into(),
                    source: e,
                })?;
            let prefix = ObjectPath::from(parsed.path().trim_matches('/'));
            Ok((Arc::new(s3), prefix))
        }
        other => Err(FleetError::Config(format!(
            "{url:?}: scheme {other:?} is not supported (file://, s3://)"
        ))),
    }
}

impl Fleet {
    /// Connects `store` to the shared store of `cfg`; a reader's store becomes read-only.
    /// Nothing is transferred yet ([`Fleet::sync`]).
    pub fn new(cfg: &SharedStoreConfig, store: Store) -> Result<Self, FleetError> {
        if cfg.url.is_empty() {
            return Err(FleetError::Config("url is empty".into()));
        }
        if !(cfg.poll_s.is_finite() && cfg.poll_s > 0.0) {
            return Err(FleetError::Config(format!(
                "poll_s must be a positive number of seconds, not {}",
                cfg.poll_s
            )));
        }
        let (remote, prefix) = open_remote(&cfg.url)?;
        if cfg.role == FleetRole::Reader {
            store.set_read_only(Some(format!(
                "this replica mirrors the shared store {}; make changes on the writer replica",
                cfg.url
            )));
        }
        let host = std::env::var("HOSTNAME").unwrap_or_else(|_| "vamos".into());
        Ok(Self {
            remote,
            prefix,
            url: cfg.url.clone(),
            role: cfg.role,
            poll: Duration::from_secs_f64(cfg.poll_s),
            store,
            writer_id: format!("{host}:{}", std::process::id()),
            state: Mutex::new(FleetState::default()),
        })
    }

    /// How often [`Fleet::run`] syncs.
    pub fn poll_interval(&self) -> Duration {
        self.poll
    }

    /// This replica's role.
    pub fn role(&self) -> FleetRole {
        self.role
    }

    fn state(&self) -> std::sync::MutexGuard<'_, FleetState> {
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Where things stand.
    pub fn status(&self) -> FleetStatus {
        let st = self.state();
        FleetStatus {
            role: match self.role {
                FleetRole::Writer => "writer",
                FleetRole::Reader => "reader",
            },
            url: self.url.clone(),
            generation: st.synced.as_ref().map_or(0, |m| m.generation),
            files: st.synced.as_ref().map_or(0, |m| m.files.len()),
            last_sync_unix_s: st.last_sync_unix_s,
            last_error: st.last_error.clone(),
        }
    }

    fn path(&self, rel: &str) -> ObjectPath {
        if self.prefix.as_ref().is_empty() {
            ObjectPath::from(rel)
        } else {
            ObjectPath::from(format!("{}/{rel}", self.prefix.as_ref()))
        }
    }

    fn blob_path(&self, sha256: &str) -> ObjectPath {
        self.path(&format!("blobs/{sha256}"))
    }

    fn remote_err(&self, source: object_store::Error) -> FleetError {
        FleetError::Remote {
            url: self.url.clone(),
            source,
        }
    }

    fn content_err(&self, reason: impl Into<String>) -> FleetError {
        FleetError::Content {
            url: self.url.clone(),
            reason: reason.into(),
        }
    }

    /// The published manifest, `None` before the first publication.
    pub async fn manifest(&self) -> Result<Option<Manifest>, FleetError> {
        let got = match self.remote.get(&self.path("manifest.json")).await {
            Ok(g) => g,
            Err(object_store::Error::NotFound { .. }) => return Ok(None),
            Err(e) => return Err(self.remote_err(e)),
        };
        if got.meta.size as usize > MAX_MANIFEST_BYTES {
            return Err(self.content_err(format!(
                "manifest.json is {} bytes, over {MAX_MANIFEST_BYTES}",
                got.meta.size
            )));
        }
        let bytes = got.bytes().await.map_err(|e| self.remote_err(e))?;
        let m: Manifest = serde_json::from_slice(&bytes)
            .map_err(|e| self.content_err(format!("manifest.json: {e}")))?;
        if m.format != MANIFEST_FORMAT {
            return Err(self.content_err(format!(
                "manifest.json has format {:?}, this vamos reads {MANIFEST_FORMAT:?}",
                m.format
            )));
        }
        Ok(Some(m))
    }

    /// One round: the writer publishes when its data directory changed (first adopting
    /// a publication when its own directory is empty: a replaced writer starts from the
    /// fleet's state); a reader applies a new publication. Returns what changed in
    /// this replica's data directory (the writer's is changed only by the adoption).
    pub async fn sync(&self) -> Result<MirrorChange, FleetError> {
        let result = match self.role {
            FleetRole::Writer => self.writer_round().await,
            FleetRole::Reader => self.reader_round().await,
        };
        let mut st = self.state();
        match &result {
            Ok(_) => {
                st.last_sync_unix_s = Some(now_unix_s());
                st.last_error = None;
            }
            Err(e) => st.last_error = Some(e.to_string()),
        }
        result
    }

    async fn local_files(&self) -> Result<Vec<StoredFile>, FleetError> {
        let store = self.store.clone();
        Ok(tokio::task::spawn_blocking(move || store.stored_files())
            .await
            .map_err(|e| self.content_err(format!("listing task failed: {e}")))??)
    }

    async fn writer_round(&self) -> Result<MirrorChange, FleetError> {
        let mut change = MirrorChange::default();
        let mut local = self.local_files().await?;
        if self.state().synced.is_none() {
            // First round: carry on the fleet's numbering, and start from its state when
            // this data directory is empty (a replaced writer).
            if let Some(m) = self.manifest().await? {
                if local.is_empty() && !m.files.is_empty() {
                    tracing::info!(
                        url = %self.url,
                        generation = m.generation,
                        "empty data directory: adopting the fleet's publication"
                    );
                    change = self.apply(&m).await?;
                    local = self.local_files().await?;
                }
                if m.writer != self.writer_id {
                    tracing::info!(url = %self.url, previous = %m.writer, "taking over as the fleet's writer");
                }
                self.state().synced = Some(m);
            }
        } else if self
            .state()
            .synced
            .as_ref()
            .is_some_and(|m| m.files != local)
            && let Some(m) = self.manifest().await?
            && self
                .state()
                .synced
                .as_ref()
                .is_some_and(|ours| m.generation > ours.generation && m.writer != self.writer_id)
        {
            tracing::error!(
                url = %self.url,
                other = %m.writer,
                "another writer published to this shared store: a fleet has exactly one writer"
            );
        }
        let unchanged = self
            .state()
            .synced
            .as_ref()
            .is_some_and(|m| m.files == local);
        if !unchanged {
            self.publish(local).await?;
        }
        Ok(change)
    }

    /// Uploads the blobs `files` needs, then the manifest, then collects blobs no longer
    /// named.
    async fn publish(&self, files: Vec<StoredFile>) -> Result<(), FleetError> {
        let known = self.state().blobs.clone();
        let mut blobs = match known {
            Some(b) => b,
            None => self.list_blobs().await?,
        };
        for f in &files {
            if blobs.contains(&f.sha256) {
                continue;
            }
            self.upload_blob(f).await?;
            blobs.insert(f.sha256.clone());
        }
        let generation = self.state().synced.as_ref().map_or(0, |m| m.generation) + 1;
        let manifest = Manifest {
            format: MANIFEST_FORMAT.into(),
            generation,
            writer: self.writer_id.clone(),
            published_unix_s: now_unix_s(),
            files,
        };
        let body = serde_json::to_vec_pretty(&manifest)
            .map_err(|e| self.content_err(format!("manifest: {e}")))?;
        self.remote
            .put(&self.path("manifest.json"), PutPayload::from(body))
            .await
            .map_err(|e| self.remote_err(e))?;
        tracing::info!(
            url = %self.url,
            generation,
            files = manifest.files.len(),
            "published the data directory"
        );
        let named: HashSet<&str> = manifest.files.iter().map(|f| f.sha256.as_str()).collect();
        let unused: Vec<String> = blobs
            .iter()
            .filter(|b| !named.contains(b.as_str()))
            .cloned()
            .collect();
        for b in unused {
            match self.remote.delete(&self.blob_path(&b)).await {
                Ok(()) | Err(object_store::Error::NotFound { .. }) => {
                    blobs.remove(&b);
                }
                Err(e) => {
                    tracing::warn!(url = %self.url, blob = %b, "cannot delete an unused blob: {e}")
                }
            }
        }
        let mut st = self.state();
        st.blobs = Some(blobs);
        st.synced = Some(manifest);
        Ok(())
    }

    async fn list_blobs(&self) -> Result<HashSet<String>, FleetError> {
        let prefix = self.path("blobs");
        let mut out = HashSet::new();
        let mut listing = self.remote.list(Some(&prefix));
        while let Some(meta) = listing.next().await {
            let meta = meta.map_err(|e| self.remote_err(e))?;
            if let Some(name) = meta.location.filename() {
                out.insert(name.to_string());
            }
        }
        Ok(out)
    }

    /// Uploads one file as the blob of its sha256, hashing what is read: a file that
    /// changed since it was listed is not published under the wrong name.
    async fn upload_blob(&self, f: &StoredFile) -> Result<(), FleetError> {
        let path = self.store.dir().join(&f.path);
        let io = |e| FleetError::Io {
            path: path.clone(),
            source: e,
        };
        let mut file = tokio::fs::File::open(&path).await.map_err(io)?;
        let target = self.blob_path(&f.sha256);
        let mut hasher = Sha256::new();
        let mut total = 0u64;
        let mismatch = |total: u64, got: String| {
            self.content_err(format!(
                "{} changed while it was published ({total} bytes, sha256 {got}); retrying",
                f.path
            ))
        };
        if f.size as usize <= PART_BYTES {
            let mut buf = Vec::with_capacity(f.size as usize);
            tokio::io::AsyncReadExt::read_to_end(&mut file, &mut buf)
                .await
                .map_err(io)?;
            hasher.update(&buf);
            let got = hex(&hasher.finalize());
            if got != f.sha256 || buf.len() as u64 != f.size {
                return Err(mismatch(buf.len() as u64, got));
            }
            self.remote
                .put(&target, PutPayload::from(buf))
                .await
                .map_err(|e| self.remote_err(e))?;
            return Ok(());
        }
        let mut upload = self
            .remote
            .put_multipart(&target)
            .await
            .map_err(|e| self.remote_err(e))?;
        let parts = async {
            loop {
                let mut part = vec![0u8; PART_BYTES];
                let mut filled = 0;
                while filled < PART_BYTES {
                    let n = tokio::io::AsyncReadExt::read(&mut file, &mut part[filled..])
                        .await
                        .map_err(io)?;
                    if n == 0 {
                        break;
                    }
                    filled += n;
                }
                if filled == 0 {
                    break;
                }
                part.truncate(filled);
                hasher.update(&part);
                total += filled as u64;
                upload
                    .put_part(PutPayload::from(part))
                    .await
                    .map_err(|e| self.remote_err(e))?;
                if filled < PART_BYTES {
                    break;
                }
            }
            let got = hex(&hasher.clone().finalize());
            if got != f.sha256 || total != f.size {
                return Err(mismatch(total, got));
            }
            Ok(())
        }
        .await;
        match parts {
            Ok(()) => {
                upload.complete().await.map_err(|e| self.remote_err(e))?;
                Ok(())
            }
            Err(e) => {
                let _ = upload.abort().await;
                Err(e)
            }
        }
    }
}
