//! Abuse: oversized uploads refused before they are read, a flood of session opens held
//! to the limit, and no token in the logs. (Every admin route refusing missing and
//! robot-role tokens is `service_admin::every_route_refuses_missing_and_insufficient_tokens`.)

use super::faults::Process;
use super::service::{ADMIN, ROBOT, authed, fixture_setup, open_msg, start};
use futures_util::StreamExt;
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use vamos::api::proto::{self, monitor_client::MonitorClient};

/// Sends only the head of a request declaring `content_length` bytes and returns the
/// status line the server answers with, without a byte of the body sent.
async fn head_only(addr: &str, path: &str, content_length: u64) -> String {
    let mut conn = tokio::net::TcpStream::connect(addr).await.unwrap();
    let head = format!(
        "PUT {path} HTTP/1.1\r\nHost: {addr}\r\nAuthorization: Bearer {ADMIN}\r\n\
         Content-Type: application/octet-stream\r\nContent-Length: {content_length}\r\n\r\n"
    );
    conn.write_all(head.as_bytes()).await.unwrap();
    let mut buf = vec![0u8; 4096];
    let n = tokio::time::timeout(Duration::from_secs(20), conn.read(&mut buf))
        .await
        .expect("no answer before the body was sent")
        .unwrap();
    String::from_utf8_lossy(&buf[..n])
        .lines()
        .next()
        .unwrap_or_default()
        .to_string()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn oversized_uploads_are_refused_before_their_body_is_read() {
    let mut f = fixture_setup(4, true);
    f.settings.service.max_model_bytes = 1 << 20;
    f.settings.service.max_robot_bytes = 1 << 20;
    f.settings.service.max_episode_bytes = 1 << 20;
    let server = start(&f).await;
    let addr = server.rest_addr.to_string();
    // 1 TiB declared, nothing sent: the answer comes at once.
    for path in ["/v1/models/big", "/v1/robots/big?format=urdf"] {
        let status = head_only(&addr, path, 1 << 40).await;
        assert!(status.contains(" 413 "), "{path}: {status}");
    }
    // Without a declared length (chunked), the stream is cut at the limit.
    let (tx, rx) = tokio::sync::mpsc::channel::<Result<Vec<u8>, std::io::Error>>(4);
    let body = reqwest::Body::wrap_stream(tokio_stream::wrappers::ReceiverStream::new(rx));
    let url = format!("http://{addr}/v1/models/big");
    let sender = tokio::spawn(async move {
        // 1 MiB chunks until the server stops reading.
        for _ in 0..64 {
            if tx.send(Ok(vec![0u8; 1 << 20])).await.is_err() {
                break;
            }
        }
    });
    let t0 = Instant::now();
    let resp = reqwest::Client::new()
        .put(url)
        .bearer_auth(ADMIN)
        .body(body)
        .send()
        .await;
    // Either the 413 arrives, or the connection is closed mid-body: never a stored model.
    if let Ok(r) = &resp {
        assert_eq!(r.status(), reqwest::StatusCode::PAYLOAD_TOO_LARGE);
    }
    assert!(t0.elapsed() < Duration::from_secs(60));
    sender.abort();
    let models = super::service_admin::Api::at(format!("http://{addr}"))
        .get("/v1/models")
        .await;
    assert_eq!(models["models"].as_array().unwrap().len(), 0, "{models}");

    // gRPC: a message over max_message_bytes is refused (the stream ends with an error),
    // and the server goes on serving.
    let mut client = MonitorClient::connect(format!("http://{}", server.grpc_addr))
        .await
        .unwrap()
        .max_encoding_message_size(64 << 20);
    let huge = proto::StreamRequest {
        message: Some(proto::stream_request::Message::Image(proto::Image {
            stamp_ns: 1,
            encoding: "mono8".into(),
            width: 8192,
            height: 4096,
            step: 8192,
            big_endian: false,
            data: vec![0; 8192 * 4096],
            depth: None,
        })),
    };
    let open = proto::StreamRequest {
        message: Some(open_msg("sim-arm", "huge", None)),
    };
    let requests = tokio_stream::iter(vec![open, huge]);
    let outcome = match client.stream(authed(requests, Some(ROBOT))).await {
        Err(status) => Some(status),
        Ok(resp) => {
            let mut inbound = resp.into_inner();
            let mut err = None;
            while let Some(item) = inbound.next().await {
                if let Err(s) = item {
                    err = Some(s);
                    break;
                }
            }
            err
        }
    };
    let status = outcome.expect("an oversized message was accepted");
    assert_eq!(status.code(), tonic::Code::OutOfRange, "{status:?}");
    assert!(status.message().contains("max_message_bytes"), "{status:?}");
    server.shutdown().await.unwrap();
}

/// Opens a session on its own connection and holds it open: the response stream (or the
/// refusal) and the request sender that keeps it alive.
async fn open_held(
    url: String,
    id: String,
) -> (
    Result<tonic::Streaming<proto::StreamResponse>, tonic::Status>,
    tokio::sync::mpsc::Sender<proto::StreamRequest>,
) {
    let mut client = MonitorClient::connect(url).await.unwrap();
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    tx.send(proto::StreamRequest {
        message: Some(open_msg("sim-arm", &id, None)),
    })
    .await
    .unwrap();
    let r = client
        .stream(authed(
            tokio_stream::wrappers::ReceiverStream::new(rx),
            Some(ROBOT),
        ))
        .await;
    (r.map(|r| r.into_inner()), tx)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_flood_of_session_opens_is_held_to_max_sessions() {
    let f = fixture_setup(4, true);
    let server = start(&f).await;
    let url = format!("http://{}", server.grpc_addr);
    // 40 robots open at once and hold their streams.
    let mut opens = Vec::new();
    for i in 0..40 {
        opens.push(tokio::spawn(open_held(url.clone(), format!("flood-{i}"))));
    }
    let mut accepted = Vec::new();
    let mut refused = 0;
    for o in opens {
        match o.await.unwrap() {
            (Ok(stream), tx) => accepted.push((stream, tx)),
            (Err(s), _) => {
                assert_eq!(s.code(), tonic::Code::ResourceExhausted, "{s:?}");
                refused += 1;
            }
        }
    }
    assert_eq!(accepted.len(), 4, "{} accepted", accepted.len());
    assert_eq!(refused, 36);
    assert_eq!(server.shared.hub.session_count(), 4);
    // Once they close, new robots get in.
    drop(accepted);
    let deadline = Instant::now() + Duration::from_secs(20);
    while server.shared.hub.session_count() > 0 {
        assert!(Instant::now() < deadline, "sessions not released");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let (after, tx) = open_held(url, "after-flood".into()).await;
    assert!(after.is_ok(), "{:?}", after.err());
    drop(tx);
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_never_reach_the_logs() {
    let dir = tempfile::tempdir().unwrap();
    // Debug level: everything the server would ever log.
    let server = Process::start_with(&dir.path().join("data"), "debug");
    let http = reqwest::Client::new();
    let wrong = "wrong-token-that-must-not-be-logged";
    for (token, path) in [
        (Some(ADMIN), "/v1/models"),
        (Some(ROBOT), "/v1/models"),
        (Some(ROBOT), "/v1/jobs"),
        (Some(wrong), "/v1/profiles"),
        (None, "/v1/sessions"),
    ] {
        let mut req = http.get(format!("{}{path}", server.rest));
        if let Some(t) = token {
            req = req.bearer_auth(t);
        }
        req.send().await.unwrap();
    }
    // gRPC with a wrong token and with the robot token.
    for token in [wrong, ROBOT] {
        let mut client = MonitorClient::connect(format!("http://{}", server.grpc))
            .await
            .unwrap();
        let open = proto::StreamRequest {
            message: Some(open_msg("no-such-profile", "s", None)),
        };
        let _ = client
            .stream(authed(tokio_stream::iter(vec![open]), Some(token)))
            .await;
    }
    tokio::time::sleep(Duration::from_millis(300)).await;
    let logs = server.logs.lock().unwrap().join("\n");
    assert!(logs.contains("vamos serving"), "no logs captured");
    for secret in [ADMIN, ROBOT, wrong] {
        assert!(!logs.contains(secret), "{secret} in the logs:\n{logs}");
    }
    drop(logs);
    // The plain tokens worked (above) and are gone from the server's environment.
    let environ = std::fs::read(format!("/proc/{}/environ", server.pid())).unwrap();
    let environ = String::from_utf8_lossy(&environ);
    assert!(environ.contains("VAMOS_LOG__LEVEL=debug"), "{environ}");
    for secret in [ADMIN, ROBOT] {
        assert!(
            !environ.contains(secret),
            "{secret} in the server's environment"
        );
    }
    server.kill();
    // No client prints a token's value in its help.
    for (command, var) in [
        ("loadgen", "VAMOS_LOADGEN_TOKEN"),
        ("stream", "VAMOS_ROBOT_TOKEN"),
        ("bridge", "VAMOS_ROBOT_TOKEN"),
    ] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_vamos"))
            .args([command, "--help"])
            .env(var, "help-must-not-show-this")
            .output()
            .unwrap();
        let help = String::from_utf8_lossy(&out.stdout);
        assert!(out.status.success() && help.contains("--token"), "{help}");
        assert!(
            !help.contains("help-must-not-show-this"),
            "{command}: {help}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn json_bodies_over_their_limit_are_413() {
    use super::service_admin::{Api, settings, start};
    let dir = tempfile::tempdir().unwrap();
    let server = start(&settings(dir.path())).await;
    let api = Api::new(&server);
    let (status, p) = api
        .json(
            reqwest::Method::PUT,
            "/v1/profiles/p",
            serde_json::json!({ "flow_preset": "realtime" }),
        )
        .await;
    assert_eq!(status, reqwest::StatusCode::OK, "{p}");
    // A profile body just over axum's 2 MB, a calibration request just over its 1 MiB
    // (just over: the client has sent its body when the answer comes), each on a new
    // connection (the refused one is closed by the server).
    for (method, path, body) in [
        (
            reqwest::Method::PUT,
            "/v1/profiles/p",
            serde_json::json!({ "flow_preset": "a".repeat((2 << 20) + (16 << 10)) }),
        ),
        (
            reqwest::Method::POST,
            "/v1/profiles/p/calibrate",
            serde_json::json!({ "episodes": ["a".repeat((1 << 20) + (16 << 10))] }),
        ),
    ] {
        let (status, answer) = Api::new(&server).json(method, path, body).await;
        assert_eq!(
            status,
            reqwest::StatusCode::PAYLOAD_TOO_LARGE,
            "{path}: {answer}"
        );
    }
    server.shutdown().await.unwrap();
}
