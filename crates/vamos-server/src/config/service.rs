//! The `[service]` settings of `vamos serve`.

use serde::{Deserialize, Serialize};
use std::path::PathBuf;

/// What a session does when its queue is full (the robot sends faster than it is scored).
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum QueuePolicy {
    /// Drop the oldest waiting image and queue the new one (the score stays current).
    #[default]
    DropOldest,
    /// Refuse the new image (the waiting ones are scored).
    Reject,
}

/// TLS for both transports (PEM files).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct TlsConfig {
    /// Certificate chain, PEM.
    pub cert: PathBuf,
    /// Private key, PEM.
    pub key: PathBuf,
}

/// What a replica does with the shared store.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum FleetRole {
    /// Takes the REST changes and publishes its data directory (one per fleet).
    Writer,
    /// Mirrors what the writer published and refuses changes (any number).
    #[default]
    Reader,
}

/// `[service.shared_store]`: models, robots and profiles shared by a fleet of replicas
/// (see `deploy/SCALING.md`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct SharedStoreConfig {
    /// `file:///mnt/vamos-shared` (a shared file system) or `s3://bucket/prefix` (any
    /// S3-compatible store; endpoint, region and credentials from the standard `AWS_*`
    /// variables).
    pub url: String,
    /// This replica's part.
    pub role: FleetRole,
    /// How often the writer looks for changes to publish and readers for a new
    /// publication, seconds.
    pub poll_s: f64,
}

impl Default for SharedStoreConfig {
    fn default() -> Self {
        Self {
            url: String::new(),
            role: FleetRole::Reader,
            poll_s: 2.0,
        }
    }
}

/// The `[service]` section.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ServiceConfig {
    /// gRPC address (`Monitor`, health, reflection).
    pub grpc_addr: String,
    /// REST and `/metrics` address; the same as `grpc_addr` serves both on one port.
    pub rest_addr: String,
    /// Data directory: models, robots, profiles, calibrations.
    pub data_dir: PathBuf,
    /// Profile files (TOML, as `vamos score --profile` takes) served beside the data
    /// directory's profiles, under their `name`.
    pub profiles: Vec<PathBuf>,
    /// Scoring threads shared by all sessions (0 = one per core).
    pub workers: usize,
    /// Sessions open at once (streams and episode uploads).
    pub max_sessions: usize,
    /// The fraction of the scoring workers live sessions may load: a new session is
    /// refused (`RESOURCE_EXHAUSTED`) when the live sessions' measured load plus what its
    /// profile's recent sessions cost would exceed it, so admitted sessions keep their
    /// latency. The rest is headroom for the server's own threads (gRPC, REST,
    /// recordings' disk) and for bursts. 0 = no admission by load.
    pub admission_load: f64,
    /// Images a session may have waiting to be scored.
    pub queue_depth: usize,
    /// What happens to an image that finds the queue full.
    pub queue_policy: QueuePolicy,
    /// Largest gRPC message, bytes.
    pub max_message_bytes: usize,
    /// A session that sends nothing for this long is closed, seconds.
    pub idle_timeout_s: f64,
    /// Longest session, seconds.
    pub max_session_s: f64,
    /// How long a session with a client-chosen id that lost its stream waits to be
    /// resumed, seconds.
    pub resume_window_s: f64,
    /// How long (in stamp time) an image waits for a joint state at or after its stamp
    /// before it is scored with the nearest one, milliseconds.
    pub joint_wait_ms: f64,
    /// Largest episode upload (gRPC `ScoreEpisode`, REST), bytes.
    pub max_episode_bytes: u64,
    /// Largest model bundle upload, bytes.
    pub max_model_bytes: u64,
    /// Largest robot package upload, bytes.
    pub max_robot_bytes: u64,
    /// The `vamos` executable that validates uploaded models in a child process (`vamos
    /// model inspect`). Absent: this program when it is `vamos`; a server started inside
    /// another program then validates in its own process, without the limits below.
    pub model_validator: Option<PathBuf>,
    /// Memory a model's validation may use (the child's data segment), MiB; past it the
    /// upload is refused (422).
    pub model_validation_mb: u64,
    /// Longest model validation, seconds; past it the child is killed and the upload
    /// refused (422).
    pub model_validation_s: f64,
    /// Calibration jobs running at once; more are refused (HTTP 429) until one ends.
    pub max_jobs: usize,
    /// Largest calibration upload (all the episodes of one multipart request), bytes.
    pub max_calibration_bytes: u64,
    /// sha256 digests (hex) of admin tokens; `VAMOS_ADMIN_TOKEN` adds plain tokens.
    pub admin_token_sha256: Vec<String>,
    /// sha256 digests (hex) of robot tokens; `VAMOS_ROBOT_TOKEN` adds plain tokens.
    pub robot_token_sha256: Vec<String>,
    /// sha256 digests (hex) of viewer tokens (read only: the live view at `/ui`, session
    /// and alarm lists); `VAMOS_VIEWER_TOKEN` adds plain tokens.
    pub viewer_token_sha256: Vec<String>,
    /// Without any token, listen on non-loopback addresses anyway.
    pub allow_unauthenticated_remote: bool,
    /// TLS for both transports; absent: plain text.
    pub tls: Option<TlsConfig>,
    /// Seconds a shutdown waits for in-flight frames before closing streams.
    pub shutdown_grace_s: f64,
    /// A store shared with other replicas; absent: the data directory is this replica's.
    pub shared_store: Option<SharedStoreConfig>,
    /// Largest streamed image, pixels (checked from the message or file header before
    /// decoding; no side may exceed 32768).
    pub max_image_pixels: usize,
    /// Memory the server may hold for its clients (buffered images and joint states,
    /// images being decoded), MiB; work past it is refused with a clear error. 0: half of
    /// the memory the process may use (cgroup limit or machine), at least 256 MiB.
    pub memory_budget_mb: u64,
    /// Most joints in one joint state.
    pub max_joints: usize,
    /// Joint states kept behind a session's newest one (stamp time) when no image waits
    /// for them, seconds.
    pub joint_buffer_s: f64,
    /// Most bytes of joint states one session may buffer; past it joint states are
    /// refused (the client is told).
    pub max_joint_buffer_bytes: u64,
    /// Uploads (episodes to score, models, robots, calibration episodes) in progress at
    /// once; more are refused (HTTP 429, gRPC RESOURCE_EXHAUSTED) before a byte is read.
    /// Episodes to score (which robot tokens send) may hold all but one of them: the
    /// admin's uploads always have a slot.
    pub max_uploads: usize,
    /// Slowest upload, KiB/s: once `upload_grace_s` has passed, an upload whose average
    /// rate since it began is below this is cut (HTTP 408, gRPC DEADLINE_EXCEEDED), so a
    /// client that trickles bytes cannot hold an upload slot. 0: no minimum.
    pub min_upload_rate_kib_s: u64,
    /// Seconds an upload has before `min_upload_rate_kib_s` applies.
    pub upload_grace_s: f64,
    /// Temporary disk all uploads in progress may use together, MiB. 0: a quarter of the
    /// data directory's free disk when the server starts, 256 MiB to 32 GiB.
    pub max_upload_disk_mb: u64,
    /// Connections open at once, both listeners together; past it new ones are closed at
    /// once. 0: the process's open-file limit less 64 (at most 4096).
    pub max_connections: usize,
    /// Connections open at once from one client address (an IPv6 client's /64); past it
    /// its new ones are closed at once, so one client cannot fill `max_connections`.
    /// 0: a quarter of `max_connections` (at least 8). Behind a proxy that is the proxy's
    /// address: raise it there.
    pub max_connections_per_address: usize,
    /// Seconds a connection has to send its first bytes and each HTTP/1 request head
    /// (a tenth of it, at most 1 s, while more than three quarters of the connections
    /// are in use).
    pub header_timeout_s: f64,
    /// A connection with no request in flight for this many seconds is closed (HTTP/2:
    /// GOAWAY, after which clients reconnect on their next call); keep-alive PINGs are
    /// not activity. A tenth of it, 0.5 to 5 s, while more than three quarters of the
    /// connections are in use. A streaming session is a request in flight throughout.
    pub connection_idle_s: f64,
    /// A request body (an upload, a JSON body, a gRPC stream) that sends nothing for this
    /// many seconds while the server reads it fails, and with it the request.
    pub body_timeout_s: f64,
    /// Record each live session's input (gray images, joint positions, camera) in the
    /// data directory's `recordings/`, so that a session with a false alarm can join its
    /// profile's nominal set.
    pub record_sessions: bool,
    /// Disk all recordings may take together, MiB (the oldest ones not kept for a nominal
    /// set are removed to make room).
    pub recordings_disk_mb: u64,
    /// Most raw bytes one session records, MiB; the rest of a longer session is not
    /// recorded.
    pub max_recording_mb: u64,
    /// Ended live sessions the live view keeps per robot (summary, downsampled timeline,
    /// alarms; stored in the data directory's `ended/` and restored at a restart), at most
    /// 100; 1000 in all robots together. 0: none.
    pub ended_sessions_per_robot: usize,
    /// The oldest ended session kept, seconds since it ended. 0: none.
    pub ended_session_max_age_s: f64,
    /// Every this many seconds the allocator hands the memory it holds but no longer
    /// uses back to the system (glibc's `malloc_trim`; Linux with glibc only), so the
    /// server's resident memory follows what it uses after bursts (sessions closing,
    /// model swaps). 0: never.
    pub trim_memory_s: f64,
    /// Allocations of at least this many KiB get pages of their own, handed back to the
    /// system when freed (glibc's `M_MMAP_THRESHOLD`; Linux with glibc only). Setting it
    /// keeps it fixed: left alone, glibc raises the threshold to the size of each large
    /// block freed (up to 32 MiB), after which model and frame buffers come from the
    /// shared heap and stay resident, scattered, after they are freed. 0: glibc's own
    /// moving threshold.
    pub mmap_threshold_kib: u64,
}

impl Default for ServiceConfig {
    fn default() -> Self {
        Self {
            grpc_addr: "127.0.0.1:8081".into(),
            rest_addr: "127.0.0.1:8080".into(),
            data_dir: PathBuf::from("vamos-data"),
            profiles: Vec::new(),
            workers: 0,
            max_sessions: 64,
            admission_load: 0.8,
            queue_depth: 8,
            queue_policy: QueuePolicy::DropOldest,
            max_message_bytes: 16 << 20,
            idle_timeout_s: 30.0,
            max_session_s: 4.0 * 3600.0,
            resume_window_s: 30.0,
            joint_wait_ms: 200.0,
            max_episode_bytes: 4 << 30,
            max_model_bytes: 512 << 20,
            max_robot_bytes: 512 << 20,
            model_validator: None,
            model_validation_mb: 2048,
            model_validation_s: 120.0,
            max_jobs: 2,
            max_calibration_bytes: 16 << 30,
            admin_token_sha256: Vec::new(),
            robot_token_sha256: Vec::new(),
            viewer_token_sha256: Vec::new(),
            allow_unauthenticated_remote: false,
            tls: None,
            shutdown_grace_s: 10.0,
            shared_store: None,
            max_image_pixels: 1 << 24,
            memory_budget_mb: 0,
            max_joints: 1024,
            joint_buffer_s: 10.0,
            max_joint_buffer_bytes: 16 << 20,
            max_uploads: 4,
            max_upload_disk_mb: 0,
            min_upload_rate_kib_s: 16,
            upload_grace_s: 10.0,
            max_connections: 0,
            max_connections_per_address: 0,
            header_timeout_s: 10.0,
            connection_idle_s: 60.0,
            body_timeout_s: 30.0,
            trim_memory_s: 30.0,
            mmap_threshold_kib: 128,
            record_sessions: true,
            recordings_disk_mb: 2048,
            max_recording_mb: 256,
            ended_sessions_per_robot: 5,
            ended_session_max_age_s: 86400.0,
        }
    }
}
