//! Admission before a body is read: an upload slot and its temporary disk, and for an
//! episode a session place, so a busy server refuses before a byte is buffered.

use super::budget::{UploadPlane, UploadRefused, UploadTicket, Uploads};
use super::error::SessionError;
use super::hub::Hub;
use super::state::SessionSlot;

/// Admits an upload of `plane` declaring `declared` bytes (an upload slot and its disk),
/// or refuses it (counted in `uploads_refused`).
pub fn admit_upload(
    hub: &Hub,
    uploads: &Uploads,
    plane: UploadPlane,
    declared: Option<u64>,
) -> Result<UploadTicket, SessionError> {
    uploads.admit(plane, declared).map_err(|e| {
        let reason = match e {
            UploadRefused::Busy { .. } => "busy",
            UploadRefused::Disk(_) => "disk",
            UploadRefused::TooSlow { .. } => "slow",
        };
        hub.metrics()
            .uploads_refused
            .with_label_values(&[reason])
            .inc();
        SessionError::Upload(e)
    })
}

/// Admits an episode to score: a session place, then an upload slot of the robot plane.
pub fn admit_episode(
    hub: &Hub,
    uploads: &Uploads,
    declared: Option<u64>,
) -> Result<(SessionSlot, UploadTicket), SessionError> {
    let slot = hub.reserve_session().inspect_err(|e| {
        if matches!(e, SessionError::TooMany { .. }) {
            hub.metrics()
                .uploads_refused
                .with_label_values(&["sessions"])
                .inc();
        }
    })?;
    Ok((
        slot,
        admit_upload(hub, uploads, UploadPlane::Robot, declared)?,
    ))
}
