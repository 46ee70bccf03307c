//! OTLP export (cargo feature `otlp`): `vamos serve` with `[log] otlp_endpoint` sends its
//! spans over OTLP/HTTP. The collector is a loopback HTTP server that keeps what is posted
//! to `/v1/traces`; the server is stopped with SIGTERM, which flushes the batch.

use axum::body::Bytes;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

fn free_addr() -> std::net::SocketAddr {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn serve_exports_its_request_spans_over_otlp_http() {
    let posted: Arc<Mutex<Vec<u8>>> = Arc::default();
    let sink = posted.clone();
    let app = axum::Router::new().route(
        "/v1/traces",
        axum::routing::post(move |body: Bytes| {
            let sink = sink.clone();
            async move {
                sink.lock().unwrap().extend_from_slice(&body);
                ""
            }
        }),
    );
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let collector = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await });

    let dir = tempfile::tempdir().unwrap();
    let (rest, grpc) = (free_addr(), free_addr());
    let mut child = std::process::Command::new(env!("CARGO_BIN_EXE_vamos"))
        .arg("serve")
        .env_remove("VAMOS_CONFIG")
        .env_remove("RUST_LOG")
        .env("VAMOS_SERVICE__REST_ADDR", rest.to_string())
        .env("VAMOS_SERVICE__GRPC_ADDR", grpc.to_string())
        .env("VAMOS_SERVICE__DATA_DIR", dir.path().join("data"))
        .env(
            "VAMOS_LOG__OTLP_ENDPOINT",
            format!("http://{collector}/v1/traces"),
        )
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();

    let http = reqwest::Client::new();
    let deadline = Instant::now() + Duration::from_secs(60);
    loop {
        let sent = http
            .get(format!("http://{rest}/healthz"))
            .header("x-request-id", "otlp-test-7")
            .send()
            .await;
        if sent.is_ok_and(|r| r.status().is_success()) {
            break;
        }
        assert!(Instant::now() < deadline, "vamos serve did not answer");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // SAFETY: kill(2) on the child's pid; no memory is touched.
    assert_eq!(unsafe { libc::kill(child.id() as i32, libc::SIGTERM) }, 0);
    let status = tokio::task::spawn_blocking(move || child.wait())
        .await
        .unwrap()
        .unwrap();
    assert!(status.success(), "{status}");

    // The export is protobuf: the span name, its request id and the service name appear
    // as plain strings in it.
    let body = posted.lock().unwrap().clone();
    let has = |needle: &[u8]| body.windows(needle.len()).any(|w| w == needle);
    assert!(!body.is_empty(), "nothing was exported");
    assert!(has(b"otlp-test-7"), "the request id is not in the export");
    assert!(has(b"request"), "no request span");
    assert!(has(b"vamos"), "no service name");
}
