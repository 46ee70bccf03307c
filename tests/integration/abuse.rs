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

/// The fixture profile's open message (a new session id) with `change` made to it.
fn open_with(change: impl FnOnce(&mut proto::OpenSession)) -> proto::StreamRequest {
    let mut msg = open_msg("sim-arm", "", None);
    if let proto::stream_request::Message::Open(o) = &mut msg {
        change(o);
    }
    proto::StreamRequest { message: Some(msg) }
}

/// What a raw HTTP/2 peer that holds its connection open saw.
#[derive(Debug, Default)]
struct H2Peer {
    /// The server sent its SETTINGS (the connection was served, not refused).
    served: bool,
    /// PINGs the server sent and the peer answered.
    pings: usize,
    /// The server sent GOAWAY.
    goaway: bool,
    /// How long the connection lived (until EOF or a reset).
    lived: Duration,
}

/// An HTTP/2 peer from `src` that sends the preface and SETTINGS, acknowledges the
/// server's SETTINGS, answers every PING and sends nothing else, until the server closes
/// the connection or `patience` passes.
async fn h2_idle_peer(
    src: std::net::IpAddr,
    dst: std::net::SocketAddr,
    patience: Duration,
) -> H2Peer {
    let started = Instant::now();
    let mut seen = H2Peer::default();
    let socket = tokio::net::TcpSocket::new_v4().unwrap();
    socket.bind(std::net::SocketAddr::new(src, 0)).unwrap();
    let Ok(mut conn) = socket.connect(dst).await else {
        return seen;
    };
    let mut hello = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n".to_vec();
    hello.extend_from_slice(&[0, 0, 0, 4, 0, 0, 0, 0, 0]); // empty SETTINGS
    if conn.write_all(&hello).await.is_err() {
        seen.lived = started.elapsed();
        return seen;
    }
    let read_frame = async |conn: &mut tokio::net::TcpStream| -> Option<(u8, u8, Vec<u8>)> {
        let mut head = [0u8; 9];
        conn.read_exact(&mut head).await.ok()?;
        let len = u32::from_be_bytes([0, head[0], head[1], head[2]]) as usize;
        let mut payload = vec![0u8; len];
        conn.read_exact(&mut payload).await.ok()?;
        Some((head[3], head[4], payload))
    };
    while let Ok(frame) =
        tokio::time::timeout_at((started + patience).into(), read_frame(&mut conn)).await
    {
        let Some((kind, flags, payload)) = frame else {
            break; // EOF or reset: closed by the server
        };
        let answer: Option<Vec<u8>> = match (kind, flags & 1) {
            (4, 0) => {
                seen.served = true;
                Some(vec![0, 0, 0, 4, 1, 0, 0, 0, 0]) // SETTINGS ACK
            }
            (6, 0) => {
                seen.pings += 1;
                let mut ack = vec![0, 0, 8, 6, 1, 0, 0, 0, 0];
                ack.extend_from_slice(&payload);
                Some(ack)
            }
            (7, _) => {
                seen.goaway = true;
                None
            }
            _ => None,
        };
        if let Some(bytes) = answer
            && conn.write_all(&bytes).await.is_err()
        {
            break;
        }
    }
    seen.lived = started.elapsed();
    seen
}

/// Idle HTTP/2 connections that answer every PING are closed all the same, one client
/// address cannot hold more than its share of the cap, and a flood from many addresses
/// is cleared fast enough for a health check to get through.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_http2_connections_are_closed_and_cannot_shut_out_health_checks() {
    let mut f = fixture_setup(4, true);
    f.settings.service.max_connections = 40;
    f.settings.service.connection_idle_s = 3.0; // keep-alive pings every second
    let server = start(&f).await;
    let grpc = server.grpc_addr;
    let rest = server.rest_addr;
    let attacker: std::net::IpAddr = "127.0.0.3".parse().unwrap();

    // One address: 30 peers, of which the per-address cap (a quarter of 40) serves 10.
    let peers: Vec<_> = (0..30)
        .map(|_| tokio::spawn(h2_idle_peer(attacker, grpc, Duration::from_secs(20))))
        .collect();
    tokio::time::sleep(Duration::from_millis(500)).await;
    // Health (gRPC, from another address) answers while they are held.
    let t0 = Instant::now();
    let mut health = tonic_health::pb::health_client::HealthClient::new(
        tonic::transport::Endpoint::from_shared(format!("http://{grpc}"))
            .unwrap()
            .connect()
            .await
            .unwrap(),
    );
    let status = health
        .check(tonic_health::pb::HealthCheckRequest::default())
        .await
        .unwrap()
        .into_inner()
        .status;
    assert_eq!(
        status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    assert!(t0.elapsed() < Duration::from_secs(2), "{:?}", t0.elapsed());
    drop(health);
    let mut seen = Vec::new();
    for p in peers {
        seen.push(p.await.unwrap());
    }
    let served: Vec<_> = seen.iter().filter(|p| p.served).collect();
    assert_eq!(served.len(), 10, "{seen:?}");
    for p in &served {
        // Answering the pings kept none of them: GOAWAY after ~3 s idle, then closed.
        assert!(p.pings >= 1, "{p:?}");
        assert!(p.goaway, "{p:?}");
        assert!(p.lived < Duration::from_secs(10), "{p:?}");
    }
    for p in seen.iter().filter(|p| !p.served) {
        assert!(p.lived < Duration::from_secs(1), "a refused peer: {p:?}");
    }
    let text = super::service::metrics_text(rest).await;
    let series = |name: &str| {
        text.lines()
            .find_map(|l| l.strip_prefix(name)?.trim().parse::<f64>().ok())
            .unwrap_or(0.0)
    };
    assert!(
        series("vamos_connections_refused_total{reason=\"address\"}") >= 20.0,
        "{text}"
    );
    assert!(
        series("vamos_connections_closed_total{reason=\"idle\"}") >= 10.0,
        "{text}"
    );

    // Many addresses, 50 peers for 40 places: the cap fills, the server is pressed and
    // closes idle connections within 0.5 s, and a health check (REST, retried as a
    // load balancer would) gets through within 2 s.
    let peers: Vec<_> = (0..50)
        .map(|i| {
            let src = std::net::IpAddr::from([127, 0, 1, 1 + (i % 5) as u8]);
            tokio::spawn(h2_idle_peer(src, grpc, Duration::from_secs(20)))
        })
        .collect();
    tokio::time::sleep(Duration::from_millis(300)).await;
    let http = reqwest::Client::builder()
        .pool_max_idle_per_host(0)
        .timeout(Duration::from_millis(500))
        .build()
        .unwrap();
    let t0 = Instant::now();
    let mut ok = false;
    while t0.elapsed() < Duration::from_secs(2) {
        if let Ok(r) = http.get(format!("http://{rest}/healthz")).send().await
            && r.status() == 200
        {
            ok = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(ok, "no health answer in 2 s");
    for p in peers {
        let p = p.await.unwrap();
        assert!(p.lived < Duration::from_secs(8), "{p:?}");
    }
    server.shutdown().await.unwrap();
}

/// A robot's stalled uploads cannot hold the admin's slot, and are cut at the body
/// timeout; a JSON body that never comes is answered at the body timeout too.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stalled_uploads_cannot_block_the_admin_plane() {
    let mut f = fixture_setup(8, true);
    f.settings.service.max_uploads = 4;
    f.settings.service.body_timeout_s = 2.0;
    let server = start(&f).await;
    let rest = server.rest_addr;
    // Sends a head and 1 KiB of a declared 1 MiB body, then stalls; returns the status
    // line the server answers with and when.
    let stall = |path: &'static str, token: &'static str| async move {
        let mut c = tokio::net::TcpStream::connect(rest).await.unwrap();
        let head = format!(
            "POST {path} HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {token}\r\n\
             Content-Type: application/octet-stream\r\nContent-Length: 1048576\r\n\r\n"
        );
        c.write_all(head.as_bytes()).await.unwrap();
        c.write_all(&[7u8; 1024]).await.unwrap();
        let t0 = Instant::now();
        let mut buf = vec![0u8; 1024];
        let n = tokio::time::timeout(Duration::from_secs(15), c.read(&mut buf))
            .await
            .map(|r| r.unwrap_or(0))
            .unwrap_or(0);
        let line = String::from_utf8_lossy(&buf[..n])
            .lines()
            .next()
            .unwrap_or("")
            .to_string();
        (line, t0.elapsed())
    };
    let episode = "/v1/episodes:score?profile=sim-arm";
    let stalled: Vec<_> = (0..3)
        .map(|_| tokio::spawn(stall(episode, ROBOT)))
        .collect();
    tokio::time::sleep(Duration::from_millis(300)).await;
    // A fourth episode finds the robots' slots full...
    let (line, _) = stall(episode, ROBOT).await;
    assert!(line.contains("429"), "{line}");
    // ...and the admin's model upload is admitted (it is not a valid bundle: refused
    // for what it is, not for a slot).
    let model = reqwest::Client::new()
        .put(format!("http://{rest}/v1/models/m"))
        .bearer_auth(ADMIN)
        .body(vec![0u8; 4096])
        .send()
        .await
        .unwrap();
    assert_ne!(model.status(), reqwest::StatusCode::TOO_MANY_REQUESTS);
    assert!(model.status().is_client_error(), "{}", model.status());
    // The stalled ones are cut at the body timeout (2 s) with a client error.
    for s in stalled {
        let (line, took) = s.await.unwrap();
        assert!(line.contains(" 400 ") || line.contains(" 408 "), "{line}");
        assert!(took < Duration::from_secs(6), "{took:?}");
    }
    // Their slots are free again.
    let (line, _) = stall(episode, ROBOT).await;
    assert!(!line.contains("429"), "{line}");
    // A JSON route whose declared body never comes.
    let mut c = tokio::net::TcpStream::connect(rest).await.unwrap();
    c.write_all(
        format!(
            "PUT /v1/profiles/p HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {ADMIN}\r\n\
             Content-Type: application/json\r\nContent-Length: 1000\r\n\r\n"
        )
        .as_bytes(),
    )
    .await
    .unwrap();
    let mut buf = vec![0u8; 512];
    let n = tokio::time::timeout(Duration::from_secs(8), c.read(&mut buf))
        .await
        .expect("no answer to a body that never came")
        .unwrap_or(0);
    let answer = String::from_utf8_lossy(&buf[..n]);
    assert!(answer.starts_with("HTTP/1.1 4"), "{answer}");
    server.shutdown().await.unwrap();
}

/// A robot token sees, resumes and marks only its own: a token issued for other robots,
/// and one issued for none (which sees only what it opened), find another robot's live
/// session, its frames and its alarms unknown, and cannot act for its robot; the owner,
/// viewers and admins see it, and once it ended still see it (its robot's ended sessions)
/// while the other tokens still do not.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn robot_tokens_see_only_their_own_sessions_and_alarms() {
    use super::service::{episode, episode_messages, fixture_with, hex_sha256};
    use super::service_admin::{open_session, send_all};
    const SCOPED: &str = "robot-a-secret";
    const OTHER: &str = "robot-c-secret";
    const VIEWER: &str = "viewer-secret";
    // Every frame's score is at the alarm threshold: the session alarms.
    let mut f = fixture_with(8, true, "[thresholds]\nalarm = 0.0\n");
    f.settings
        .service
        .robot_token_sha256
        .extend([format!("{}:arm-a", hex_sha256(SCOPED)), hex_sha256(OTHER)]);
    f.settings.service.viewer_token_sha256 = vec![hex_sha256(VIEWER)];
    let server = start(&f).await;
    let grpc = server.grpc_addr;
    let rest = server.rest_addr;
    // The owner (ROBOT, issued for any robot) streams session "b-1" as robot "robot-b-1"
    // and keeps it open.
    let (messages, camera) = episode_messages(&episode("test_0000"));
    let (tx, task, _) = open_session(grpc, "sim-arm", "b-1", camera).await;
    send_all(&tx, &messages).await;
    let get = |token: &'static str, path: String| async move {
        let r = reqwest::Client::new()
            .get(format!("http://{rest}{path}"))
            .bearer_auth(token)
            .send()
            .await
            .unwrap();
        let status = r.status();
        (status, r.text().await.unwrap())
    };
    // Wait for the owner's alarm.
    let deadline = Instant::now() + Duration::from_secs(60);
    let alarm_id = loop {
        let (_, body) = get(ROBOT, "/v1/alarms?session=b-1".into()).await;
        let v: serde_json::Value = serde_json::from_str(&body).unwrap();
        if let Some(id) = v["alarms"][0]["id"].as_str() {
            break id.to_string();
        }
        assert!(Instant::now() < deadline, "no alarm: {body}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    let session_paths = [
        "/v1/sessions/b-1/timeline",
        "/v1/sessions/b-1/frame",
        "/v1/sessions/b-1/alarms",
        &format!("/v1/alarms/{alarm_id}"),
        &format!("/v1/alarms/{alarm_id}/thumbnail"),
    ]
    .map(String::from);
    for token in [SCOPED, OTHER] {
        for path in &session_paths {
            let (status, body) = get(token, path.clone()).await;
            assert_eq!(
                status,
                reqwest::StatusCode::NOT_FOUND,
                "{token} {path}: {body}"
            );
        }
        let (_, live) = get(token, "/v1/live".into()).await;
        assert!(!live.contains("b-1"), "{token}: {live}");
        let (_, alarms) = get(token, "/v1/alarms".into()).await;
        assert!(!alarms.contains(&alarm_id), "{token}: {alarms}");
        let mark = reqwest::Client::new()
            .post(format!("http://{rest}/v1/alarms/{alarm_id}/false-alarm"))
            .bearer_auth(token)
            .send()
            .await
            .unwrap();
        assert_eq!(mark.status(), reqwest::StatusCode::NOT_FOUND, "{token}");
        // Resuming the session: refused, though its id is known.
        let mut client = MonitorClient::connect(format!("http://{grpc}"))
            .await
            .unwrap();
        let open = proto::StreamRequest {
            message: Some(open_msg("sim-arm", "b-1", None)),
        };
        let err = client
            .stream(authed(tokio_stream::iter([open]), Some(token)))
            .await
            .unwrap_err();
        assert_eq!(err.code(), tonic::Code::PermissionDenied, "{token}: {err}");
    }
    // The scoped token cannot act for a robot it is not issued for, and can for its own.
    let mut client = MonitorClient::connect(format!("http://{grpc}"))
        .await
        .unwrap();
    let open = |robot: &str| open_with(|o| o.robot_id = robot.into());
    let err = client
        .stream(authed(tokio_stream::iter([open("arm-b")]), Some(SCOPED)))
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::PermissionDenied, "{err}");
    assert!(err.message().contains("arm-b"), "{err}");
    let (tx_a, rx_a) = tokio::sync::mpsc::channel(1);
    tx_a.send(open("arm-a")).await.unwrap();
    let mut own = client
        .stream(authed(
            tokio_stream::wrappers::ReceiverStream::new(rx_a),
            Some(SCOPED),
        ))
        .await
        .unwrap()
        .into_inner();
    assert!(own.next().await.unwrap().is_ok());
    drop(tx_a);
    // The owner, a viewer and the admin see it; the owner marks its alarm.
    for token in [ROBOT, VIEWER, ADMIN] {
        for path in &session_paths {
            let (status, body) = get(token, path.clone()).await;
            assert_eq!(status, reqwest::StatusCode::OK, "{token} {path}: {body}");
        }
        let (_, live) = get(token, "/v1/live".into()).await;
        assert!(live.contains("\"b-1\""), "{token}: {live}");
    }
    let mark = reqwest::Client::new()
        .post(format!("http://{rest}/v1/alarms/{alarm_id}/false-alarm"))
        .bearer_auth(ROBOT)
        .send()
        .await
        .unwrap();
    assert_eq!(mark.status(), reqwest::StatusCode::OK);
    drop(tx);
    task.await.unwrap();
    // Ended, the session is kept for the live view and seen exactly as before.
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let (status, body) = get(ROBOT, "/v1/sessions/b-1/timeline".into()).await;
        if body.contains("\"state\":\"ended\"") {
            assert_eq!(status, reqwest::StatusCode::OK);
            break;
        }
        assert!(Instant::now() < deadline, "b-1 never ended: {body}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    for token in [SCOPED, OTHER] {
        for path in &session_paths[..3] {
            let (status, body) = get(token, path.clone()).await;
            assert_eq!(
                status,
                reqwest::StatusCode::NOT_FOUND,
                "{token} {path}: {body}"
            );
        }
        let (_, live) = get(token, "/v1/live".into()).await;
        assert!(!live.contains("b-1"), "{token}: {live}");
    }
    for token in [ROBOT, VIEWER, ADMIN] {
        let (_, live) = get(token, "/v1/live".into()).await;
        let v: serde_json::Value = serde_json::from_str(&live).unwrap();
        let ended: Vec<&str> = v["robots"]["robots"]
            .as_array()
            .unwrap()
            .iter()
            .flat_map(|r| r["ended"].as_array().unwrap())
            .filter_map(|e| e["id"].as_str())
            .collect();
        assert!(ended.contains(&"b-1"), "{token}: {live}");
        let (status, body) = get(token, "/v1/sessions/b-1/alarms".into()).await;
        assert_eq!(status, reqwest::StatusCode::OK, "{token}: {body}");
        assert!(body.contains(&alarm_id), "{token}: {body}");
    }
    server.shutdown().await.unwrap();
}

/// Labels a client gives (robot id, task, phase, episode name) are bounded; a profile
/// body that is no object, or a stride of 0, is refused instead of stored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn long_labels_and_degenerate_profiles_are_refused() {
    use super::service_admin::{Api, settings};
    let f = fixture_setup(4, true);
    let server = start(&f).await;
    let grpc = server.grpc_addr;
    let mut client = MonitorClient::connect(format!("http://{grpc}"))
        .await
        .unwrap();
    let long = "x".repeat(300);
    for field in ["robot_id", "task"] {
        let open = open_with(|o| match field {
            "robot_id" => o.robot_id = long.clone(),
            _ => o.task = long.clone(),
        });
        let err = client
            .stream(authed(tokio_stream::iter([open]), Some(ROBOT)))
            .await
            .unwrap_err();
        assert_eq!(err.code(), tonic::Code::InvalidArgument, "{field}: {err}");
        assert!(
            err.message().contains(field) && err.message().contains("300"),
            "{err}"
        );
    }
    // A phase that long is refused as a message (the session goes on).
    let (tx, rx) = tokio::sync::mpsc::channel(4);
    tx.send(proto::StreamRequest {
        message: Some(open_msg("sim-arm", "", None)),
    })
    .await
    .unwrap();
    tx.send(proto::StreamRequest {
        message: Some(proto::stream_request::Message::Phase(proto::PhaseMarker {
            stamp_ns: 1,
            phase: "p".repeat(1 << 20),
        })),
    })
    .await
    .unwrap();
    let mut inbound = client
        .stream(authed(
            tokio_stream::wrappers::ReceiverStream::new(rx),
            Some(ROBOT),
        ))
        .await
        .unwrap()
        .into_inner();
    let mut refused = None;
    while let Some(Ok(r)) = tokio::time::timeout(Duration::from_secs(5), inbound.next())
        .await
        .unwrap()
    {
        if let Some(proto::stream_response::Message::Event(e)) = r.message
            && e.detail.contains("phase dropped")
        {
            refused = Some(e.detail);
            break;
        }
    }
    let refused = refused.expect("the long phase was not refused");
    assert!(
        refused.len() < 1000,
        "the refusal repeats the phase: {} bytes",
        refused.len()
    );
    drop(tx);
    // An episode name that long, over REST.
    let answer = reqwest::Client::new()
        .post(format!(
            "http://{}/v1/episodes:score?profile=sim-arm&name={long}",
            server.rest_addr
        ))
        .bearer_auth(ROBOT)
        .body(vec![0u8; 16])
        .send()
        .await
        .unwrap();
    assert_eq!(answer.status(), reqwest::StatusCode::BAD_REQUEST);
    server.shutdown().await.unwrap();

    let dir = tempfile::tempdir().unwrap();
    let server = super::service_admin::start(&settings(dir.path())).await;
    let api = Api::new(&server);
    for body in [
        serde_json::json!([]),
        serde_json::json!({ "pipeline": { "stride": 0 } }),
    ] {
        let (status, answer) = api
            .json(reqwest::Method::PUT, "/v1/profiles/p", body.clone())
            .await;
        assert_eq!(status, reqwest::StatusCode::BAD_REQUEST, "{body}: {answer}");
    }
    let (status, _) = api.call(reqwest::Method::GET, "/v1/profiles/p", None).await;
    assert_eq!(status, reqwest::StatusCode::NOT_FOUND, "nothing was stored");
    server.shutdown().await.unwrap();
}
