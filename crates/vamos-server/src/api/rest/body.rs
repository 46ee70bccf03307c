//! Request and response bodies: JSON read with a size limit, uploads streamed to the
//! data directory, files streamed back, refused bodies drained.

use super::errors::ApiError;
use crate::api::state::Shared;
use crate::session::SessionError;
use crate::session::budget::UploadTicket;
use crate::store::{StoreError, Upload, UploadKind};
use axum::body::{Body, Bytes};
use axum::extract::{FromRequestParts, Query};
use axum::http::request::Parts;
use axum::http::{HeaderMap, header};
use axum::response::Response;
use futures_util::StreamExt;

/// A query string read as `T`; a bad one is a 400 with a JSON error body, as every other
/// refusal (axum's own `Query` answers those in plain text).
pub(super) struct ApiQuery<T>(pub T);

impl<T: serde::de::DeserializeOwned, S: Send + Sync> FromRequestParts<S> for ApiQuery<T> {
    type Rejection = ApiError;

    async fn from_request_parts(parts: &mut Parts, state: &S) -> Result<Self, ApiError> {
        match Query::<T>::from_request_parts(parts, state).await {
            Ok(Query(q)) => Ok(ApiQuery(q)),
            Err(e) => Err(ApiError::bad_request(e.body_text())),
        }
    }
}

/// Runs a store call on a blocking thread.
pub(super) async fn blocking<T: Send + 'static>(
    f: impl FnOnce() -> Result<T, StoreError> + Send + 'static,
) -> Result<T, ApiError> {
    Ok(tokio::task::spawn_blocking(f)
        .await
        .map_err(ApiError::internal)??)
}

/// Reads a JSON body of at most `limit` bytes: a longer one is refused with 413 (the
/// size), a broken one with 400.
pub(super) async fn json_bytes(body: Body, limit: usize) -> Result<Bytes, ApiError> {
    let mut stream = body.into_data_stream();
    let mut out = Vec::new();
    while let Some(chunk) = stream.next().await {
        let chunk =
            chunk.map_err(|e| ApiError::bad_request(format!("cannot read the body: {e}")))?;
        if out.len() + chunk.len() > limit {
            return Err(ApiError::too_large(format!(
                "the JSON body is over {limit} bytes"
            )));
        }
        out.extend_from_slice(&chunk);
    }
    Ok(Bytes::from(out))
}

pub(super) fn json_body<T: serde::de::DeserializeOwned>(body: &[u8]) -> Result<T, ApiError> {
    // Every JSON body of the API is an object: serde would also take a struct's fields
    // as an array (`[]` for a struct whose fields all have defaults).
    if body.trim_ascii_start().first() != Some(&b'{') {
        return Err(ApiError::bad_request(
            "bad JSON body: expected a JSON object",
        ));
    }
    serde_json::from_slice(body).map_err(|e| ApiError::bad_request(format!("bad JSON body: {e}")))
}

/// The declared `Content-Length`, if any.
pub(super) fn content_length(headers: &HeaderMap) -> Option<u64> {
    headers
        .get(header::CONTENT_LENGTH)
        .and_then(|v| v.to_str().ok())
        .and_then(|v| v.parse::<u64>().ok())
}

/// Streams `body` into a new upload of `kind`, refusing with 413 a declared or actual
/// size over the store's limit, and with 429 an upload the server has no slot or
/// temporary disk for (before a byte is read). The ticket holds the slot and the disk
/// until it is dropped (after the commit).
pub(super) async fn receive(
    s: &Shared,
    kind: UploadKind,
    headers: &HeaderMap,
    body: Body,
) -> Result<(Upload, UploadTicket), ApiError> {
    let store = &s.store;
    let limit = match kind {
        UploadKind::Model => store.limits().max_model_bytes,
        UploadKind::Robot { .. } => store.limits().max_robot_bytes,
    };
    let declared = content_length(headers);
    if declared.is_some_and(|len| len > limit) {
        return Err(StoreError::TooLarge { limit_bytes: limit }.into());
    }
    let mut ticket = s.admit_upload(declared)?;
    let st = store.clone();
    let mut upload = blocking(move || st.begin_upload(kind)).await?;
    let mut stream = body.into_data_stream();
    let mut size = 0u64;
    while let Some(chunk) = stream.next().await {
        let chunk = chunk.map_err(ApiError::bad_request)?;
        size += chunk.len() as u64;
        ticket.received(size).map_err(SessionError::from)?;
        ticket.written(size).map_err(SessionError::from)?;
        match blocking(move || upload.write_chunk(&chunk).map(|()| upload)).await {
            Ok(u) => upload = u,
            // The upload is gone (its file removed). A full disk is not the client's
            // doing: read the rest (bounded) so the 507 reaches it on a usable connection.
            Err(e) if e.is_storage_full() => {
                drain_data(&mut stream, DRAIN_LIMIT_BYTES).await;
                return Err(e);
            }
            Err(e) => return Err(e),
        }
    }
    Ok((upload, ticket))
}

/// Reads and drops up to `budget` more bytes of a body.
pub(super) async fn drain_data(stream: &mut axum::body::BodyDataStream, mut budget: u64) {
    while let Some(Ok(chunk)) = stream.next().await {
        budget = budget.saturating_sub(chunk.len() as u64);
        if budget == 0 {
            return;
        }
    }
}

/// The start of the message of a body multer cannot parse.
pub(super) const BROKEN_MULTIPART: &str = "bad multipart body";

/// At most this much of a refused upload is read before answering (beyond it the
/// connection is closed instead).
pub(super) const DRAIN_LIMIT_BYTES: u64 = 64 << 20;

pub(super) async fn drain(multipart: &mut multer::Multipart<'_>, mut budget: u64) {
    while let Ok(Some(mut field)) = multipart.next_field().await {
        while let Ok(Some(chunk)) = field.chunk().await {
            budget = budget.saturating_sub(chunk.len() as u64);
            if budget == 0 {
                return;
            }
        }
    }
}

/// A response streaming `file` as `application/x-mcap`. Its name is removed before the
/// response is returned (the open handle keeps the data readable), so nothing is left in
/// the upload folder however the transfer ends.
pub(super) async fn file_body(
    file: tempfile::NamedTempFile,
    ticket: Option<UploadTicket>,
) -> Result<Response, ApiError> {
    use tokio::io::AsyncReadExt;
    let mut std_file = file.into_file();
    let len = std_file.metadata().map_err(ApiError::internal)?.len();
    std::io::Seek::rewind(&mut std_file).map_err(ApiError::internal)?;
    let mut reader = tokio::fs::File::from_std(std_file);
    let (tx, rx) = tokio::sync::mpsc::channel::<Result<Vec<u8>, std::io::Error>>(4);
    tokio::spawn(async move {
        // Held until the answer is sent (or the client goes).
        let _ticket = ticket;
        loop {
            let mut buf = vec![0u8; 256 << 10];
            match reader.read(&mut buf).await {
                Ok(0) => return,
                Ok(n) => {
                    buf.truncate(n);
                    if tx.send(Ok(buf)).await.is_err() {
                        return;
                    }
                }
                Err(e) => {
                    let _ = tx.send(Err(e)).await;
                    return;
                }
            }
        }
    });
    Response::builder()
        .header(header::CONTENT_TYPE, "application/x-mcap")
        .header(header::CONTENT_LENGTH, len)
        .body(Body::from_stream(
            tokio_stream::wrappers::ReceiverStream::new(rx),
        ))
        .map_err(ApiError::internal)
}
