//! The session layer: everything the server does between a transport and the core,
//! in core types only (no tonic, prost, axum or http; `tests/integration/architecture.rs`
//! checks). Both transports (`crate::api::grpc`, `crate::api::rest`) call its
//! operations and map its one error type, [`SessionError`].
//!
//! - [`hub`]: the sessions and their lifecycle (open, resume, reload, close, sweep,
//!   shutdown); [`state`]: one session and its state; [`input`]: what a live session
//!   receives and when its frames are released; [`worker`]: the CPU pool that decodes
//!   and scores frames round-robin; [`joints`]: the joint-state buffer.
//! - [`event`]: the vocabulary with clients: [`LiveImage`], [`LiveJoints`] in,
//!   [`Output`] (scores, events, the error that ends a stream) out.
//! - [`episode`]: the one episode-scoring operation (an uploaded bag through the worker
//!   pool, scores in order, then the damage if any); [`upload`]: the one episode-upload
//!   buffer; [`admission`]: upload slots and session places taken before a body is read.
//! - [`profiles`]: the profiles sessions score with; [`jobs`] and [`calibration`]: the
//!   calibration jobs.
//! - [`alarms`]: per-frame flags debounced into alarms (start/end events, the recent
//!   alarms of all sessions, false-alarm marks stored); [`live`]: what the live view
//!   shows of a session (timeline points, latest frame thumbnail, anomaly map, the
//!   whole session's overview); [`history`]: each robot's last ended sessions, bounded,
//!   stored and restored at a restart.
//! - [`capacity`]: each live session's measured load on the workers, and admission of
//!   new ones against the pool's capacity.
//! - [`budget`]: memory and upload-disk budgets; [`metrics`]: Prometheus metrics;
//!   [`fleet`]: the data directory shared with other replicas.
//!
//! May import the core (`vision` .. `pipeline`, `eval`), `setup`, `store` and `config`.

pub mod admission;
pub mod alarms;
pub mod budget;
pub mod calibration;
pub mod capacity;
pub mod episode;
pub mod error;
pub mod event;
pub mod fleet;
pub mod history;
pub mod hub;
pub mod input;
pub mod jobs;
pub mod joints;
pub mod live;
pub mod metrics;
pub mod profiles;
pub mod recording;
pub mod reload;
pub mod state;
pub mod upload;
pub mod worker;

pub use error::SessionError;
pub use event::{Event, EventKind, LiveImage, LiveJoints, Outbound, Output, ScoredFrame};
pub use hub::Hub;
pub use profiles::{LoadedProfile, ProfileCatalog, ProfileLookupError};
pub use state::{OpenRequest, Session, SessionSlot, SessionSummary};
