//! The live view's static page (`GET /ui`), the REST API's reference page (`GET /docs`)
//! and their assets (`GET /ui/{asset}`), embedded
//! in the binary (`assets/ui/`, plain HTML, CSS and JavaScript: no build step). The page
//! holds no data: it asks for a token, keeps it in the tab's `sessionStorage`, and reads
//! everything through the token-checked API (`/v1/whoami`, `/v1/live`, `/v1/alarms`,
//! `/v1/sessions/{id}/...`).

use super::errors::ApiError;
use axum::extract::Path;
use axum::http::header;
use axum::response::{IntoResponse, Response};

const INDEX_HTML: &str = include_str!("../../../../../assets/ui/index.html");
const APP_JS: &str = include_str!("../../../../../assets/ui/app.js");
const APP_CSS: &str = include_str!("../../../../../assets/ui/app.css");
const DOCS_HTML: &str = include_str!("../../../../../assets/ui/docs.html");
const DOCS_JS: &str = include_str!("../../../../../assets/ui/docs.js");
const DOCS_CSS: &str = include_str!("../../../../../assets/ui/docs.css");

/// What the page may load: its own files only, nothing inline from elsewhere.
const CSP: &str = "default-src 'self'; img-src 'self' blob: data:; style-src 'self'; \
                   script-src 'self'; connect-src 'self'; frame-ancestors 'none'";

fn asset_response(content_type: &'static str, body: &'static str) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CONTENT_SECURITY_POLICY, CSP),
            (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
            (header::CACHE_CONTROL, "no-cache"),
        ],
        body,
    )
        .into_response()
}

/// `GET /ui`: the page.
pub(super) async fn index() -> Response {
    asset_response("text/html; charset=utf-8", INDEX_HTML)
}

/// `GET /docs`: the REST API's reference page (it reads `/openapi.json`).
pub(super) async fn docs() -> Response {
    asset_response("text/html; charset=utf-8", DOCS_HTML)
}

/// `GET /ui/{asset}`: `app.js`, `app.css`, and the reference page's `docs.js`, `docs.css`.
pub(super) async fn asset(Path(name): Path<String>) -> Result<Response, ApiError> {
    match name.as_str() {
        "app.js" => Ok(asset_response("text/javascript; charset=utf-8", APP_JS)),
        "app.css" => Ok(asset_response("text/css; charset=utf-8", APP_CSS)),
        "index.html" => Ok(asset_response("text/html; charset=utf-8", INDEX_HTML)),
        "docs.js" => Ok(asset_response("text/javascript; charset=utf-8", DOCS_JS)),
        "docs.css" => Ok(asset_response("text/css; charset=utf-8", DOCS_CSS)),
        _ => Err(ApiError::not_found(format!(
            "no asset {name:?} in the live view"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_page_loads_its_own_assets_and_sends_tokens_only_in_headers() {
        assert!(INDEX_HTML.contains("/ui/app.js") && INDEX_HTML.contains("/ui/app.css"));
        // The token goes in the authorization header, never into a URL.
        assert!(APP_JS.contains("Authorization"));
        assert!(!APP_JS.contains("?token") && !APP_JS.contains("&token"));
        assert!(APP_JS.contains("sessionStorage"));
        assert!(DOCS_HTML.contains("/ui/docs.js") && DOCS_JS.contains("/openapi.json"));
    }
}
