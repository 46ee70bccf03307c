//! The HTTP API (axum): health, metrics, sessions, episode scoring, and administration of
//! the data directory (models, robots, profiles, calibration jobs).
//!
//! Every route is listed once in [`ROUTES`] with who may call it; the router is built
//! from that list (the access check is a layer of each route) and `GET /openapi.json`
//! describes the same routes (a test keeps the two equal). `/healthz`, `/readyz`, `/v2`,
//! `/v2/health/*`, `/v2/models/*/ready`, `/v2/models/*/versions/*/ready`, `/metrics` and
//! `/openapi.json` are open (probes and scrapers), and so is the live view's static page
//! `/ui` (it holds no data: it asks for a token and reads everything through the API);
//! the rest needs a bearer token when tokens are configured: `viewer` for the live view's
//! data (sessions' timelines, alarms), `robot` for scoring, reading lists and marking
//! false alarms, `admin` for everything else that changes state.
//!
//! One module per resource: [`health`] (probes, metrics, the API description), `kserve`
//! (KServe v2 server and model metadata),
//! `sessions`, `episodes` (scoring), `models`, `robots`, `profiles`, `calibration`
//! (calibration jobs); `body` reads and writes bodies. Each handler parses, calls one
//! session or store operation and maps the result.
//!
//! Errors are `{"error": message}` with a status chosen in [`errors`], the one mapping:
//! 404 unknown, 400 refused (an upload the validator refused, a bad name or body), 413
//! too large, 409 in use, 429 busy, 500 internal.

mod body;
mod calibration;
mod episodes;
pub mod errors;
mod health;
mod kserve;
mod live;
mod models;
mod profiles;
mod robots;
mod sessions;
mod ui;

#[doc(hidden)]
pub use calibration::parse_calibrate_request;
pub use episodes::score_json;
pub use errors::ApiError;
#[doc(hidden)]
pub use models::parse_active_request;

use crate::api::auth::Role;
use crate::api::state::Shared;
use axum::Router;
use axum::extract::{Request, State};
use axum::http::{HeaderMap, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use axum::routing::{MethodRouter, delete, get, patch, post, put};
use std::sync::Arc;
/// Checks the bearer token of `headers` for `role`.
pub fn authorize(shared: &Shared, headers: &HeaderMap, role: Role) -> Result<Role, ApiError> {
    let h = headers
        .get(header::AUTHORIZATION)
        .and_then(|v| v.to_str().ok());
    Ok(shared.tokens.require(h, role)?)
}

/// Who may call a route.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Access {
    /// Anyone (probes, scrapers, the API description, the live view's static page).
    Open,
    /// A viewer, robot or admin token (read only: the live view's data).
    Viewer,
    /// A robot or admin token.
    Robot,
    /// An admin token.
    Admin,
}

/// Every REST route: method, path (axum syntax, the same as OpenAPI's) and access. The
/// router is built from this list and `openapi.json` must describe exactly these.
pub const ROUTES: &[(&str, &str, Access)] = &[
    ("GET", "/healthz", Access::Open),
    ("GET", "/readyz", Access::Open),
    ("GET", "/v2/health/live", Access::Open),
    ("GET", "/v2/health/ready", Access::Open),
    ("GET", "/v2/models/{name}/ready", Access::Open),
    ("GET", "/v2", Access::Open),
    ("GET", "/v2/models/{name}", Access::Robot),
    ("GET", "/v2/models/{name}/versions/{version}", Access::Robot),
    (
        "GET",
        "/v2/models/{name}/versions/{version}/ready",
        Access::Open,
    ),
    ("GET", "/metrics", Access::Open),
    ("GET", "/openapi.json", Access::Open),
    ("GET", "/v1/sessions", Access::Admin),
    ("GET", "/v1/store", Access::Admin),
    ("POST", "/v1/sessions/{id}/reload", Access::Admin),
    ("POST", "/v1/episodes:score", Access::Robot),
    ("GET", "/v1/models", Access::Robot),
    ("GET", "/v1/models/{name}", Access::Robot),
    ("PUT", "/v1/models/{name}", Access::Admin),
    ("DELETE", "/v1/models/{name}", Access::Admin),
    (
        "DELETE",
        "/v1/models/{name}/versions/{version}",
        Access::Admin,
    ),
    ("POST", "/v1/models/{name}/active", Access::Admin),
    ("GET", "/v1/robots", Access::Robot),
    ("GET", "/v1/robots/{name}", Access::Robot),
    ("PUT", "/v1/robots/{name}", Access::Admin),
    ("DELETE", "/v1/robots/{name}", Access::Admin),
    ("GET", "/v1/profiles", Access::Robot),
    ("GET", "/v1/profiles/{name}", Access::Robot),
    ("PUT", "/v1/profiles/{name}", Access::Admin),
    ("DELETE", "/v1/profiles/{name}", Access::Admin),
    ("PATCH", "/v1/profiles/{name}/thresholds", Access::Admin),
    ("POST", "/v1/profiles/{name}/calibrate", Access::Admin),
    ("GET", "/v1/profiles/{name}/nominal", Access::Viewer),
    ("POST", "/v1/profiles/{name}/recalibrate", Access::Admin),
    ("GET", "/v1/jobs", Access::Admin),
    ("GET", "/v1/jobs/{id}", Access::Admin),
    ("DELETE", "/v1/jobs/{id}", Access::Admin),
    ("POST", "/v1/jobs/{id}/apply", Access::Admin),
    ("GET", "/ui", Access::Open),
    ("GET", "/ui/{asset}", Access::Open),
    ("GET", "/v1/whoami", Access::Viewer),
    ("GET", "/v1/live", Access::Viewer),
    ("GET", "/v1/alarms", Access::Viewer),
    ("GET", "/v1/alarms/{id}", Access::Viewer),
    ("GET", "/v1/alarms/{id}/thumbnail", Access::Viewer),
    ("POST", "/v1/alarms/{id}/false-alarm", Access::Robot),
    ("GET", "/v1/sessions/{id}/alarms", Access::Viewer),
    ("GET", "/v1/sessions/{id}/timeline", Access::Viewer),
    ("GET", "/v1/sessions/{id}/frame", Access::Viewer),
    ("GET", "/v1/sessions/{id}/map", Access::Viewer),
];

/// The OpenAPI 3.0 description served at `/openapi.json`.
pub const OPENAPI_JSON: &str = include_str!("openapi.json");

/// The handler of a route of [`ROUTES`] (`None`: no such route).
pub fn handler(method: &str, path: &str) -> Option<MethodRouter<Arc<Shared>>> {
    Some(match (method, path) {
        ("GET", "/healthz" | "/v2/health/live") => get(health::healthz),
        ("GET", "/readyz" | "/v2/health/ready") => get(health::readyz),
        ("GET", "/v2/models/{name}/ready") => get(health::model_ready),
        ("GET", "/v2") => get(kserve::server_metadata),
        ("GET", "/v2/models/{name}") => get(kserve::model_metadata),
        ("GET", "/v2/models/{name}/versions/{version}") => get(kserve::version_metadata),
        ("GET", "/v2/models/{name}/versions/{version}/ready") => get(kserve::version_ready),
        ("GET", "/metrics") => get(health::metrics),
        ("GET", "/openapi.json") => get(health::openapi),
        ("GET", "/v1/sessions") => get(sessions::sessions),
        ("GET", "/v1/store") => get(sessions::store_status),
        ("POST", "/v1/sessions/{id}/reload") => post(sessions::reload_session),
        ("POST", "/v1/episodes:score") => post(episodes::score_episode),
        ("GET", "/v1/models") => get(models::list_models),
        ("GET", "/v1/models/{name}") => get(models::get_model),
        ("PUT", "/v1/models/{name}") => put(models::put_model),
        ("DELETE", "/v1/models/{name}") => delete(models::delete_model),
        ("DELETE", "/v1/models/{name}/versions/{version}") => delete(models::delete_model_version),
        ("POST", "/v1/models/{name}/active") => post(models::set_active_model),
        ("GET", "/v1/robots") => get(robots::list_robots),
        ("GET", "/v1/robots/{name}") => get(robots::get_robot),
        ("PUT", "/v1/robots/{name}") => put(robots::put_robot),
        ("DELETE", "/v1/robots/{name}") => delete(robots::delete_robot),
        ("GET", "/v1/profiles") => get(profiles::profiles),
        ("GET", "/v1/profiles/{name}") => get(profiles::get_profile),
        ("PUT", "/v1/profiles/{name}") => put(profiles::put_profile),
        ("DELETE", "/v1/profiles/{name}") => delete(profiles::delete_profile),
        ("PATCH", "/v1/profiles/{name}/thresholds") => patch(profiles::patch_thresholds),
        ("POST", "/v1/profiles/{name}/calibrate") => post(calibration::start_calibration),
        ("GET", "/v1/jobs") => get(calibration::list_jobs),
        ("GET", "/v1/jobs/{id}") => get(calibration::get_job),
        ("DELETE", "/v1/jobs/{id}") => delete(calibration::delete_job),
        ("GET", "/v1/profiles/{name}/nominal") => get(calibration::nominal),
        ("POST", "/v1/profiles/{name}/recalibrate") => post(calibration::start_recalibration),
        ("POST", "/v1/jobs/{id}/apply") => post(calibration::apply_job),
        ("GET", "/ui") => get(ui::index),
        ("GET", "/ui/{asset}") => get(ui::asset),
        ("GET", "/v1/whoami") => get(live::whoami),
        ("GET", "/v1/live") => get(live::live),
        ("GET", "/v1/alarms") => get(live::list_alarms),
        ("GET", "/v1/alarms/{id}") => get(live::get_alarm),
        ("GET", "/v1/alarms/{id}/thumbnail") => get(live::alarm_thumbnail),
        ("POST", "/v1/alarms/{id}/false-alarm") => post(live::mark_alarm),
        ("GET", "/v1/sessions/{id}/alarms") => get(live::session_alarms),
        ("GET", "/v1/sessions/{id}/timeline") => get(live::timeline),
        ("GET", "/v1/sessions/{id}/frame") => get(live::latest_frame),
        ("GET", "/v1/sessions/{id}/map") => get(live::latest_map),
        _ => return None,
    })
}

/// The access check of a route: refuses a missing or insufficient token before the
/// handler (and before any body is read).
async fn require(
    State((s, access)): State<(Arc<Shared>, Access)>,
    req: Request,
    next: Next,
) -> Response {
    let role = match access {
        Access::Open => return next.run(req).await,
        Access::Viewer => Role::Viewer,
        Access::Robot => Role::Robot,
        Access::Admin => Role::Admin,
    };
    match authorize(&s, req.headers(), role) {
        Ok(_) => next.run(req).await,
        Err(e) => e.into_response(),
    }
}

/// The REST routes of [`ROUTES`].
pub fn router(shared: Arc<Shared>) -> Router {
    let mut by_path: Vec<(&str, MethodRouter<Arc<Shared>>)> = Vec::new();
    for &(method, path, access) in ROUTES {
        let Some(h) = handler(method, path) else {
            tracing::error!(method, path, "route without a handler");
            continue;
        };
        let h = h.route_layer(axum::middleware::from_fn_with_state(
            (shared.clone(), access),
            require,
        ));
        match by_path.iter().position(|(p, _)| *p == path) {
            Some(i) => {
                let (p, existing) = by_path.swap_remove(i);
                by_path.push((p, existing.merge(h)));
            }
            None => by_path.push((path, h)),
        }
    }
    by_path
        .into_iter()
        .fold(Router::new(), |r, (path, h)| r.route(path, h))
        .with_state(shared)
}

/// Unknown paths: gRPC calls get `UNIMPLEMENTED` (as tonic answers them), others a 404
/// with a JSON body.
pub async fn not_found(headers: HeaderMap) -> Response {
    let grpc = headers
        .get(header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/grpc"));
    if grpc {
        (
            StatusCode::OK,
            [
                (header::CONTENT_TYPE, "application/grpc"),
                (header::HeaderName::from_static("grpc-status"), "12"),
            ],
        )
            .into_response()
    } else {
        ApiError::not_found("no such route").into_response()
    }
}

#[cfg(test)]
mod tests {
    use super::{Access, OPENAPI_JSON, ROUTES, handler};
    use std::collections::BTreeSet;

    #[test]
    fn openapi_describes_exactly_the_routes() {
        let doc: serde_json::Value = serde_json::from_str(OPENAPI_JSON).unwrap();
        assert_eq!(doc["openapi"].as_str().map(|v| &v[..2]), Some("3."));
        let mut described = BTreeSet::new();
        for (path, ops) in doc["paths"].as_object().unwrap() {
            for (method, op) in ops.as_object().unwrap() {
                let method = method.to_ascii_uppercase();
                // The role in the description is the one enforced.
                let role = op.get("x-vamos-role").and_then(|r| r.as_str());
                let access = ROUTES
                    .iter()
                    .find(|(m, p, _)| *m == method && p == path)
                    .map(|r| r.2);
                let expected = match access {
                    Some(Access::Open) => None,
                    Some(Access::Viewer) => Some("viewer"),
                    Some(Access::Robot) => Some("robot"),
                    Some(Access::Admin) => Some("admin"),
                    None => panic!("{method} {path} is described but not routed"),
                };
                assert_eq!(role, expected, "{method} {path}");
                described.insert((method, path.clone()));
            }
        }
        let routed: BTreeSet<(String, String)> = ROUTES
            .iter()
            .map(|(m, p, _)| (m.to_string(), p.to_string()))
            .collect();
        assert_eq!(routed.len(), ROUTES.len(), "a route is listed twice");
        assert_eq!(described, routed);
    }

    #[test]
    fn every_listed_route_has_a_handler() {
        for (m, p, _) in ROUTES {
            assert!(handler(m, p).is_some(), "{m} {p}");
        }
        assert!(handler("GET", "/v1/nothing").is_none());
    }
}
