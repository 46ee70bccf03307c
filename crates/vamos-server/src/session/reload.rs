//! Moving a running session to its profile as stored now (a new active model version,
//! new thresholds or calibration), through the REST API.

use super::error::SessionError;
use super::hub::Hub;
use super::profiles::ProfileCatalog;
use std::sync::Arc;

/// Moves session `id` to its profile as loaded now. `Ok(None)`: the session is gone, or
/// it already scores with that very profile (nothing changed since it opened);
/// `Ok(Some(model))`: moved, scoring with `model` from its next frame.
pub async fn reload_session(
    hub: &Arc<Hub>,
    profiles: &ProfileCatalog,
    id: &str,
) -> Result<Option<String>, SessionError> {
    let Some(session) = hub.session(id) else {
        return Ok(None);
    };
    let failed = |e: SessionError| SessionError::Reload {
        source: Box::new(e),
    };
    let profile = profiles
        .get_async(&session.profile_name)
        .await
        .map_err(|e| failed(e.into()))?;
    if Arc::ptr_eq(&profile, &session.profile()) {
        return Ok(None);
    }
    let model = profile.model_label.clone();
    let hub = hub.clone();
    tokio::task::spawn_blocking(move || hub.reload(&session, profile))
        .await
        .map_err(|e| SessionError::Internal(e.to_string()))?
        .map_err(failed)?;
    Ok(Some(model))
}

/// Sessions moved by [`reload_model_sessions`].
#[derive(Debug, Default)]
pub struct Reloaded {
    /// Ids of the sessions moved.
    pub reloaded: Vec<String>,
    /// Sessions that could not be moved, and why.
    pub failed: Vec<(String, SessionError)>,
}

/// Moves every running session whose stored profile uses model `model` to its profile
/// as loaded now (profile files are left as they are). Sessions that closed meanwhile or
/// already score with the current version are left out.
pub async fn reload_model_sessions(
    hub: &Arc<Hub>,
    profiles: &ProfileCatalog,
    model: &str,
) -> Reloaded {
    let mut out = Reloaded::default();
    for summary in hub.sessions() {
        let uses = summary.model.split('@').next() == Some(model);
        if !uses || profiles.is_file(&summary.profile) {
            continue;
        }
        match reload_session(hub, profiles, &summary.id).await {
            Ok(Some(_)) => out.reloaded.push(summary.id),
            Ok(None) => {}
            Err(e) => out.failed.push((summary.id, e)),
        }
    }
    out
}
