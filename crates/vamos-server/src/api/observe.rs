//! Request ids, spans and request metrics for both transports: one axum middleware
//! ([`layer`]) wraps the REST and the gRPC routers (tonic's routes are an axum router).
//!
//! - Request id: the caller's `x-request-id` when it is 1 to 128 visible ASCII
//!   characters, else a new random one; it is put in the request's extensions
//!   ([`RequestId`], read by the gRPC handlers for the session's span) and returned in
//!   the response's `x-request-id` header (gRPC: the initial metadata).
//! - Span: `request` with the id, method and path; the handler runs inside it.
//! - Metrics ([`Metrics`]): HTTP requests by method, route template and status; gRPC
//!   calls by method and status code, read from the response headers (trailers-only
//!   answers) or the trailers at the end of the body; durations to the end of the body.
//!   Label values are bounded: route templates and known gRPC methods only.

use crate::session::metrics::Metrics;
use axum::body::Body;
use axum::extract::{MatchedPath, Request, State};
use axum::http::{HeaderMap, HeaderValue};
use axum::middleware::Next;
use axum::response::Response;
use http_body::{Body as HttpBody, Frame, SizeHint};
use std::pin::Pin;
use std::task::{Context, Poll};
use std::time::Instant;
use tracing::Instrument;

/// The request-id header, read and returned.
pub const REQUEST_ID_HEADER: &str = "x-request-id";

/// The request id of a request (in its extensions).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RequestId(pub String);

/// The caller's request id when it is acceptable: 1 to 128 visible ASCII characters.
fn accepted(headers: &HeaderMap) -> Option<String> {
    let v = headers.get(REQUEST_ID_HEADER)?.to_str().ok()?;
    let ok = (1..=128).contains(&v.len()) && v.bytes().all(|b| b.is_ascii_graphic());
    ok.then(|| v.to_string())
}

/// A new request id: 128 random bits as 32 hex digits.
fn generated() -> String {
    format!("{:016x}{:016x}", fastrand::u64(..), fastrand::u64(..))
}

/// The gRPC methods served (labels are only ever these, or `unmatched`).
fn grpc_method(path: &str) -> &'static str {
    const KNOWN: &[&str] = &[
        "/vamos.v1.Monitor/Stream",
        "/vamos.v1.Monitor/ScoreEpisode",
        "/grpc.health.v1.Health/Check",
        "/grpc.health.v1.Health/Watch",
        "/grpc.reflection.v1.ServerReflection/ServerReflectionInfo",
        "/grpc.reflection.v1alpha.ServerReflection/ServerReflectionInfo",
    ];
    KNOWN
        .iter()
        .find(|m| **m == path)
        .copied()
        .unwrap_or("unmatched")
}

/// The `grpc-status` of headers or trailers, if there is one.
fn status_code(headers: &HeaderMap) -> Option<tonic::Code> {
    headers
        .get("grpc-status")
        .map(|v| tonic::Code::from_bytes(v.as_bytes()))
}

/// What is recorded when the response body ends (or is dropped).
enum Record {
    Http {
        method: String,
        route: String,
        status: u16,
    },
    Grpc {
        method: &'static str,
        /// The status code of a trailers-only answer; otherwise read from the trailers.
        code: Option<tonic::Code>,
    },
}

/// A response body that records the request's metrics once, when it ends.
struct Observed {
    inner: Body,
    metrics: Metrics,
    started: Instant,
    record: Option<Record>,
}

impl Observed {
    fn finish(&mut self, trailers: Option<&HeaderMap>) {
        let Some(record) = self.record.take() else {
            return;
        };
        let seconds = self.started.elapsed().as_secs_f64();
        match record {
            Record::Http {
                method,
                route,
                status,
            } => {
                let status = status.to_string();
                self.metrics
                    .http_requests
                    .with_label_values(&[method.as_str(), route.as_str(), status.as_str()])
                    .inc();
                self.metrics
                    .http_request_seconds
                    .with_label_values(&[method.as_str(), route.as_str()])
                    .observe(seconds);
            }
            Record::Grpc { method, code } => {
                // No status at all: the client went away (or the body broke) first.
                let code = code
                    .or_else(|| trailers.and_then(status_code))
                    .unwrap_or(tonic::Code::Cancelled);
                let name = format!("{code:?}");
                self.metrics
                    .grpc_requests
                    .with_label_values(&[method, name.as_str()])
                    .inc();
                self.metrics
                    .grpc_request_seconds
                    .with_label_values(&[method])
                    .observe(seconds);
            }
        }
    }
}

impl HttpBody for Observed {
    type Data = axum::body::Bytes;
    type Error = axum::Error;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Self::Data>, Self::Error>>> {
        let this = &mut *self;
        let polled = Pin::new(&mut this.inner).poll_frame(cx);
        match &polled {
            Poll::Ready(Some(Ok(frame))) => {
                if let Some(trailers) = frame.trailers_ref() {
                    this.finish(Some(trailers));
                }
            }
            Poll::Ready(None) => this.finish(None),
            Poll::Ready(Some(Err(_))) => this.finish(None),
            Poll::Pending => {}
        }
        polled
    }

    fn is_end_stream(&self) -> bool {
        self.inner.is_end_stream()
    }

    fn size_hint(&self) -> SizeHint {
        self.inner.size_hint()
    }
}

impl Drop for Observed {
    fn drop(&mut self) {
        self.finish(None);
    }
}

/// The middleware: request id, span, metrics (see the module docs).
pub async fn observe(State(metrics): State<Metrics>, mut req: Request, next: Next) -> Response {
    let started = Instant::now();
    let id = accepted(req.headers()).unwrap_or_else(generated);
    req.extensions_mut().insert(RequestId(id.clone()));
    let grpc = req
        .headers()
        .get(axum::http::header::CONTENT_TYPE)
        .and_then(|v| v.to_str().ok())
        .is_some_and(|v| v.starts_with("application/grpc"));
    let method = req.method().as_str().to_string();
    let path = req.uri().path().to_string();
    let route = req
        .extensions()
        .get::<MatchedPath>()
        .map_or("unmatched", |m| m.as_str())
        .to_string();
    let span = tracing::info_span!("request", request_id = %id, method = %method, path = %path);
    let mut response = next.run(req).instrument(span).await;
    if let Ok(v) = HeaderValue::from_str(&id) {
        response.headers_mut().insert(REQUEST_ID_HEADER, v);
    }
    let record = if grpc {
        Record::Grpc {
            method: grpc_method(&path),
            code: status_code(response.headers()),
        }
    } else {
        Record::Http {
            method,
            route,
            status: response.status().as_u16(),
        }
    };
    response.map(|inner| {
        Body::new(Observed {
            inner,
            metrics,
            started,
            record: Some(record),
        })
    })
}

/// Wraps every route (and the fallback) of `router` in [`observe`].
pub fn layer(router: axum::Router, metrics: Metrics) -> axum::Router {
    router.layer(axum::middleware::from_fn_with_state(metrics, observe))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn request_ids_are_accepted_or_generated() {
        let mut h = HeaderMap::new();
        assert_eq!(accepted(&h), None);
        h.insert(REQUEST_ID_HEADER, HeaderValue::from_static("abc-123"));
        assert_eq!(accepted(&h).as_deref(), Some("abc-123"));
        h.insert(REQUEST_ID_HEADER, HeaderValue::from_static("has space"));
        assert_eq!(accepted(&h), None);
        let long = "x".repeat(129);
        h.insert(REQUEST_ID_HEADER, HeaderValue::from_str(&long).unwrap());
        assert_eq!(accepted(&h), None);
        let (a, b) = (generated(), generated());
        assert_eq!(a.len(), 32);
        assert!(a.bytes().all(|c| c.is_ascii_hexdigit()));
        assert_ne!(a, b);
    }

    #[test]
    fn grpc_method_labels_are_bounded() {
        assert_eq!(
            grpc_method("/vamos.v1.Monitor/Stream"),
            "/vamos.v1.Monitor/Stream"
        );
        assert_eq!(grpc_method("/x.Y/Z"), "unmatched");
    }
}
