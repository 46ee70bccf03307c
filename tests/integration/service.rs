//! The service end to end: the real server on ephemeral ports, a real tonic client and a
//! real HTTP client, on the simulated episodes of tests/fixtures/sim.

use futures_util::StreamExt;
use std::collections::HashMap;
use std::path::PathBuf;
use std::time::Duration;
use tokio::sync::mpsc;
use tokio_stream::wrappers::ReceiverStream;
use tonic::Request;
use tonic::metadata::MetadataValue;
use vamos::api::proto::monitor_client::MonitorClient;
use vamos::api::proto::{self, stream_request::Message as In};
use vamos::config::Settings;
use vamos::episode::McapEpisode;
use vamos::pipeline::FrameScore;
use vamos::pipeline::offline::score_episode;
use vamos::service::{RunningServer, Server};
use vamos::session::ProfileCatalog;
use vamos::setup::Setup;

pub(crate) const PROFILE: &str = r#"name = "sim-arm"
robot = "robot/vamos_arm.urdf"
camera = "camera.json"
flow_preset = "realtime"
[pipeline]
stride = 1
[pipeline.frames]
width = 160
height = 120
variant = "masked"
"#;

pub(crate) const ADMIN: &str = "admin-secret";
pub(crate) const ROBOT: &str = "robot-secret";

/// The server's `/metrics` text.
pub(crate) async fn metrics_text(rest_addr: std::net::SocketAddr) -> String {
    reqwest::get(format!("http://{rest_addr}/metrics"))
        .await
        .unwrap()
        .text()
        .await
        .unwrap()
}

pub(crate) fn fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim")
}

pub(crate) fn hex_sha256(s: &str) -> String {
    vamos::api::auth::digest(s)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

pub(crate) struct Fixture {
    _dir: tempfile::TempDir,
    pub(crate) setup: Setup,
    pub(crate) settings: Settings,
}

pub(crate) fn fixture_setup(max_sessions: usize, tokens: bool) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    // The profile names the fixture's robot and camera by absolute path.
    let profile_dir = dir.path().join("profile");
    std::fs::create_dir_all(&profile_dir).unwrap();
    let text = PROFILE
        .replace(
            "robot/vamos_arm.urdf",
            &fixture().join("robot/vamos_arm.urdf").display().to_string(),
        )
        .replace(
            "camera.json",
            &fixture().join("camera.json").display().to_string(),
        );
    let path = profile_dir.join("sim-arm.toml");
    std::fs::write(&path, text).unwrap();
    let mut settings = Settings::default();
    settings.service.grpc_addr = "127.0.0.1:0".into();
    // Another loopback address: the same string as the gRPC one would mean one port.
    settings.service.rest_addr = "127.0.0.2:0".into();
    settings.service.data_dir = dir.path().join("data");
    settings.service.max_sessions = max_sessions;
    settings.service.workers = 2;
    settings.service.queue_depth = 64;
    settings.service.shutdown_grace_s = 5.0;
    if tokens {
        settings.service.admin_token_sha256 = vec![hex_sha256(ADMIN)];
        settings.service.robot_token_sha256 = vec![hex_sha256(ROBOT)];
    }
    let setup = Setup::load(&settings, &path).unwrap();
    Fixture {
        _dir: dir,
        setup,
        settings,
    }
}

pub(crate) async fn start(f: &Fixture) -> RunningServer {
    let catalog = ProfileCatalog::from_setups(vec![f.setup.clone()]);
    Server::start(f.settings.clone(), catalog).await.unwrap()
}

/// The messages of a bag as a robot would stream them (log-time order): images, joint
/// states; and its first camera info.
pub(crate) fn episode_messages(path: &std::path::Path) -> (Vec<In>, Option<proto::CameraInfo>) {
    let rec = vamos::client::replay::record(path, &Default::default()).unwrap();
    (
        rec.messages.into_iter().map(|(_, m)| m).collect(),
        rec.camera,
    )
}

pub(crate) fn offline(setup: &Setup, path: &std::path::Path) -> Vec<FrameScore> {
    let ep = McapEpisode::open(path, &setup.episode).unwrap();
    let mut scorer = setup.calibrated_scorer(ep.name(), false).unwrap();
    score_episode::<vamos::episode::EpisodeError>(&mut scorer, &ep, |_, _| Ok(()))
        .unwrap()
        .frames
}

pub(crate) fn open_msg(profile: &str, session_id: &str, camera: Option<proto::CameraInfo>) -> In {
    In::Open(proto::OpenSession {
        robot_id: format!("robot-{session_id}"),
        profile: profile.into(),
        camera_info: camera,
        task: "place_book".into(),
        session_id: session_id.into(),
        anomaly_maps: false,
    })
}

pub(crate) fn authed<T>(msg: T, token: Option<&str>) -> Request<T> {
    let mut req = Request::new(msg);
    if let Some(t) = token {
        req.metadata_mut().insert(
            "authorization",
            MetadataValue::try_from(format!("Bearer {t}")).unwrap(),
        );
    }
    req
}

/// Streams `messages` after `open` and collects the responses until the server closes.
pub(crate) async fn stream_all(
    addr: std::net::SocketAddr,
    token: Option<&str>,
    open: In,
    messages: Vec<In>,
) -> Result<(Vec<proto::FrameScore>, Vec<proto::SessionEvent>), tonic::Status> {
    let mut client = MonitorClient::connect(format!("http://{addr}"))
        .await
        .unwrap();
    let (tx, rx) = mpsc::channel(16);
    tokio::spawn(async move {
        let _ = tx
            .send(proto::StreamRequest {
                message: Some(open),
            })
            .await;
        for m in messages {
            if tx
                .send(proto::StreamRequest { message: Some(m) })
                .await
                .is_err()
            {
                return;
            }
        }
    });
    let mut inbound = client
        .stream(authed(ReceiverStream::new(rx), token))
        .await?
        .into_inner();
    let mut scores = Vec::new();
    let mut events = Vec::new();
    while let Some(item) = inbound.next().await {
        match item?.message {
            Some(proto::stream_response::Message::Score(s)) => scores.push(s),
            Some(proto::stream_response::Message::Event(e)) => events.push(e),
            Some(proto::stream_response::Message::Alarm(_)) | None => {}
        }
    }
    Ok((scores, events))
}

/// A TCP proxy to `target` on an ephemeral port; aborting the task cuts every
/// connection at once (no orderly end of stream).
async fn tcp_proxy(
    target: std::net::SocketAddr,
) -> (std::net::SocketAddr, tokio::task::JoinHandle<()>) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    let task = tokio::spawn(async move {
        let mut conns = tokio::task::JoinSet::new();
        loop {
            let Ok((mut inbound, _)) = listener.accept().await else {
                return;
            };
            conns.spawn(async move {
                let mut outbound = tokio::net::TcpStream::connect(target).await.unwrap();
                let _ = tokio::io::copy_bidirectional(&mut inbound, &mut outbound).await;
            });
        }
    });
    (addr, task)
}

pub(crate) fn episode(name: &str) -> PathBuf {
    fixture().join("test").join(format!("{name}.mcap"))
}

pub(crate) fn assert_same_scores(streamed: &[proto::FrameScore], offline: &[FrameScore]) {
    assert_eq!(streamed.len(), offline.len(), "frame counts differ");
    assert!(!offline.is_empty());
    for (s, o) in streamed.iter().zip(offline) {
        assert_eq!(s.stamp_ns, o.stamp_ns);
        assert_eq!(s.index, o.index);
        assert_eq!(s.frame, o.frame);
        assert_eq!(s.score, o.score, "score of frame {}", o.frame);
        assert_eq!(s.e_c, o.e_c);
        assert_eq!(s.e_b, o.e_b);
        assert_eq!(s.e_o, o.e_o);
        assert_eq!(s.anomaly, o.anomaly);
        assert!(s.latency_s >= s.compute_s && s.compute_s > 0.0);
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_streamed_session_scores_every_frame_as_offline_scoring_does() {
    let f = fixture_setup(8, false);
    let server = start(&f).await;
    let name = "test_0001_external_push";
    let (messages, camera) = episode_messages(&episode(name));
    let images = messages
        .iter()
        .filter(|m| matches!(m, In::Image(_)))
        .count();
    let (scores, events) = stream_all(
        server.grpc_addr,
        None,
        open_msg("sim-arm", name, camera),
        messages,
    )
    .await
    .unwrap();
    let expected = offline(&f.setup, &episode(name));
    assert_same_scores(&scores, &expected);
    // At stride 1 every image has a score (the first one warming up).
    assert_eq!(scores.len(), images);
    assert_eq!(events[0].kind, proto::session_event::Kind::Opened as i32);
    assert_eq!(events[0].session_id, name);
    assert!(
        !events
            .iter()
            .any(|e| e.kind == proto::session_event::Kind::MessageError as i32),
        "{events:?}"
    );
    // The session is gone once its stream closed; the metrics counted its frames.
    assert_eq!(server.shared.hub.session_count(), 0);
    let metrics = metrics_text(server.rest_addr).await;
    assert!(
        metrics.contains(&format!(
            "vamos_frames_processed_total{{profile=\"sim-arm\"}} {}",
            scores.len()
        )),
        "{metrics}"
    );
    assert!(metrics.contains("vamos_stage_seconds_bucket{stage=\"flow\""));
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_robots_at_once_each_get_their_own_scores_and_episode_upload_matches() {
    let f = fixture_setup(8, false);
    let server = start(&f).await;
    let a = "test_0000";
    let b = "test_0002_sensor_fault";
    let (ma, ca) = episode_messages(&episode(a));
    let (mb, cb) = episode_messages(&episode(b));
    let addr = server.grpc_addr;
    let (ra, rb) = tokio::join!(
        stream_all(addr, None, open_msg("sim-arm", a, ca), ma),
        stream_all(addr, None, open_msg("sim-arm", b, cb), mb),
    );
    assert_same_scores(&ra.unwrap().0, &offline(&f.setup, &episode(a)));
    assert_same_scores(&rb.unwrap().0, &offline(&f.setup, &episode(b)));

    // The same episode uploaded whole (gRPC ScoreEpisode, 64 KiB chunks).
    let bytes = std::fs::read(episode(b)).unwrap();
    let chunks: Vec<proto::EpisodeChunk> = bytes
        .chunks(64 << 10)
        .enumerate()
        .map(|(i, c)| proto::EpisodeChunk {
            profile: if i == 0 {
                "sim-arm".into()
            } else {
                String::new()
            },
            data: c.to_vec(),
            name: if i == 0 { b.into() } else { String::new() },
        })
        .collect();
    let mut client = MonitorClient::connect(format!("http://{addr}"))
        .await
        .unwrap();
    let mut out = client
        .score_episode(tokio_stream::iter(chunks))
        .await
        .unwrap()
        .into_inner();
    let mut uploaded = Vec::new();
    while let Some(s) = out.next().await {
        uploaded.push(s.unwrap());
    }
    let expected = offline(&f.setup, &episode(b));
    assert_same_scores(&uploaded, &expected);

    // And over REST.
    let http = reqwest::Client::new();
    let body: serde_json::Value = http
        .post(format!(
            "http://{}/v1/episodes:score?profile=sim-arm&name={b}",
            server.rest_addr
        ))
        .body(bytes.clone())
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let frames = body["frames"].as_array().unwrap();
    assert_eq!(frames.len(), expected.len());
    for (j, o) in frames.iter().zip(&expected) {
        assert_eq!(j["score"].as_f64().unwrap(), o.score);
        assert_eq!(j["stamp_ns"].as_i64().unwrap(), o.stamp_ns);
    }
    // The same as a scored MCAP bag (Accept: application/x-mcap): the input's images and
    // one /vamos/score message per scored frame, readable as an episode again.
    let response = http
        .post(format!(
            "http://{}/v1/episodes:score?profile=sim-arm&name={b}",
            server.rest_addr
        ))
        .header("accept", "application/x-mcap")
        .body(bytes.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    assert_eq!(
        response.headers()["content-type"].to_str().unwrap(),
        "application/x-mcap"
    );
    let scored = response.bytes().await.unwrap();
    let out = tempfile::Builder::new().suffix(".mcap").tempfile().unwrap();
    std::fs::write(out.path(), &scored).unwrap();
    let bag = McapEpisode::open(out.path(), &Default::default()).unwrap();
    let info = bag.info();
    let count = |topic: &str| {
        info.topics
            .iter()
            .find(|t| t.name == topic)
            .map_or(0, |t| t.message_count)
    };
    assert_eq!(count("/vamos/score"), expected.len() as u64);
    assert_eq!(count("/vamos/anomaly"), expected.len() as u64);
    let image_topic = info
        .topics
        .iter()
        .find(|t| t.schema == "sensor_msgs/msg/Image");
    assert_eq!(image_topic.unwrap().message_count, expected.len() as u64);
    // No upload is left behind in the data directory's tmp/ (the scoring task removes
    // its copy when it ends, which may be just after the last score was sent).
    let leftovers = || {
        std::fs::read_dir(server.shared.upload_dir())
            .unwrap()
            .count()
    };
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while leftovers() > 0 && std::time::Instant::now() < deadline {
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    assert_eq!(leftovers(), 0);
    // The same episode compressed as rosbag2 compresses files (streamed zstd, no declared
    // size: a `.mcap.zstd`): decompressed in the upload folder, the same scores over REST
    // (JSON and scored bag) and gRPC, and nothing left behind.
    let packed = zstd::stream::encode_all(&bytes[..], 3).unwrap();
    let body: serde_json::Value = http
        .post(format!(
            "http://{}/v1/episodes:score?profile=sim-arm&name={b}",
            server.rest_addr
        ))
        .body(packed.clone())
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let zstd_scores: Vec<f64> = body["frames"]
        .as_array()
        .unwrap_or_else(|| panic!("{body}"))
        .iter()
        .map(|j| j["score"].as_f64().unwrap())
        .collect();
    assert_eq!(
        zstd_scores,
        expected.iter().map(|o| o.score).collect::<Vec<_>>()
    );
    let response = http
        .post(format!(
            "http://{}/v1/episodes:score?profile=sim-arm&name={b}",
            server.rest_addr
        ))
        .header("accept", "application/x-mcap")
        .body(packed.clone())
        .send()
        .await
        .unwrap();
    assert_eq!(response.status(), 200);
    let out = tempfile::Builder::new().suffix(".mcap").tempfile().unwrap();
    std::fs::write(out.path(), response.bytes().await.unwrap()).unwrap();
    let unpacked = McapEpisode::open(out.path(), &Default::default())
        .unwrap()
        .info();
    for topic in ["/vamos/score", "/vamos/anomaly"] {
        let n = unpacked.topics.iter().find(|t| t.name == topic);
        assert_eq!(n.map(|t| t.message_count), Some(count(topic)), "{topic}");
    }
    let chunk = proto::EpisodeChunk {
        profile: "sim-arm".into(),
        data: packed,
        name: b.into(),
    };
    let mut out = client
        .score_episode(tokio_stream::iter(vec![chunk]))
        .await
        .unwrap()
        .into_inner();
    let mut uploaded = Vec::new();
    while let Some(s) = out.next().await {
        uploaded.push(s.unwrap());
    }
    assert_same_scores(&uploaded, &expected);
    let deadline = std::time::Instant::now() + std::time::Duration::from_secs(10);
    while leftovers() > 0 && std::time::Instant::now() < deadline {
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
    }
    assert_eq!(leftovers(), 0);
    // A truncated upload: the frames before the damage, then the damage reported.
    let cut = &bytes[..bytes.len() * 2 / 3];
    let body: serde_json::Value = http
        .post(format!(
            "http://{}/v1/episodes:score?profile=sim-arm",
            server.rest_addr
        ))
        .body(cut.to_vec())
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let n = body["frames"].as_array().unwrap().len();
    assert!(n > 0 && n < expected.len(), "{n} of {}", expected.len());
    assert!(body["damage"].as_str().unwrap().contains("damaged"));
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tokens_limits_bad_messages_and_disconnects() {
    let f = fixture_setup(1, true);
    let server = start(&f).await;
    let addr = server.grpc_addr;
    let name = "test_0000";
    let (messages, camera) = episode_messages(&episode(name));

    // No token, a wrong token: UNAUTHENTICATED. REST admin routes: 401 / 403.
    let err = stream_all(addr, None, open_msg("sim-arm", "x", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated);
    let err = stream_all(addr, Some("nope"), open_msg("sim-arm", "x", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::Unauthenticated);
    let http = reqwest::Client::new();
    let url = format!("http://{}/v1/sessions", server.rest_addr);
    assert_eq!(http.get(&url).send().await.unwrap().status(), 401);
    assert_eq!(
        http.get(&url)
            .bearer_auth(ROBOT)
            .send()
            .await
            .unwrap()
            .status(),
        403
    );
    // Unknown profile: NOT_FOUND.
    let err = stream_all(addr, Some(ROBOT), open_msg("nope", "x", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::NotFound);

    // A session that holds the only slot (it sends a few frames, then waits). It goes
    // through a TCP proxy, so the test can cut its connection as a network failure would.
    let (proxy_addr, proxy) = tcp_proxy(addr).await;
    let mut client = MonitorClient::connect(format!("http://{proxy_addr}"))
        .await
        .unwrap();
    let (tx, rx) = mpsc::channel(16);
    tx.send(proto::StreamRequest {
        message: Some(open_msg("sim-arm", "held", camera)),
    })
    .await
    .unwrap();
    let mut held = client
        .stream(authed(ReceiverStream::new(rx), Some(ROBOT)))
        .await
        .unwrap()
        .into_inner();
    let first = held.next().await.unwrap().unwrap();
    assert!(matches!(
        first.message,
        Some(proto::stream_response::Message::Event(ref e)) if e.kind == proto::session_event::Kind::Opened as i32
    ));
    // max_sessions = 1: a second session is refused.
    let err = stream_all(
        addr,
        Some(ROBOT),
        open_msg("sim-arm", "other", None),
        vec![],
    )
    .await
    .unwrap_err();
    assert_eq!(err.code(), tonic::Code::ResourceExhausted, "{err:?}");
    // A re-open of a session id that is streaming: ALREADY_EXISTS.
    let err = stream_all(addr, Some(ROBOT), open_msg("sim-arm", "held", None), vec![])
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::AlreadyExists, "{err:?}");

    // Bad messages: an undecodable image, NaN joints, a stamp going backwards. Each is
    // reported as an event and the session goes on.
    let mut good = messages.clone().into_iter();
    let mut sent = Vec::new();
    for m in good.by_ref() {
        let img = matches!(m, In::Image(_));
        sent.push(m);
        if img && sent.iter().filter(|m| matches!(m, In::Image(_))).count() == 4 {
            break;
        }
    }
    let last_stamp = sent
        .iter()
        .filter_map(|m| match m {
            In::Image(i) => Some(i.stamp_ns),
            _ => None,
        })
        .next_back()
        .unwrap();
    for m in sent {
        tx.send(proto::StreamRequest { message: Some(m) })
            .await
            .unwrap();
    }
    let bad = [
        In::Image(proto::Image {
            stamp_ns: last_stamp + 1,
            encoding: "rgb8".into(),
            width: 160,
            height: 120,
            step: 0,
            big_endian: false,
            data: vec![0; 10],
        }),
        In::Joints(proto::JointState {
            stamp_ns: last_stamp + 2,
            names: vec!["pan".into()],
            positions: vec![f64::NAN],
            ..Default::default()
        }),
        In::Image(proto::Image {
            stamp_ns: 5,
            encoding: "jpeg".into(),
            data: vec![1, 2, 3],
            ..Default::default()
        }),
    ];
    for m in bad {
        tx.send(proto::StreamRequest { message: Some(m) })
            .await
            .unwrap();
    }
    let mut errors = Vec::new();
    let mut scores = 0;
    while errors.len() < 3 {
        let item = tokio::time::timeout(Duration::from_secs(30), held.next())
            .await
            .expect("events in time")
            .unwrap()
            .unwrap();
        match item.message {
            Some(proto::stream_response::Message::Event(e))
                if e.kind == proto::session_event::Kind::MessageError as i32 =>
            {
                errors.push(e.detail)
            }
            Some(proto::stream_response::Message::Score(_)) => scores += 1,
            _ => {}
        }
    }
    let all = errors.join("\n");
    assert!(all.contains("image refused"), "{all}");
    assert!(all.contains("non-finite"), "{all}");
    assert!(all.contains("is not after the previous image"), "{all}");
    let sessions: serde_json::Value = http
        .get(&url)
        .bearer_auth(ADMIN)
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    let list = sessions["sessions"].as_array().unwrap();
    assert_eq!(list.len(), 1);
    assert_eq!(list[0]["id"], "held");
    assert_eq!(list[0]["robot_id"], "robot-held");
    assert!(list[0]["dropped"].as_u64().unwrap() >= 2);
    let _ = scores;

    // The robot's connection breaks mid-stream: the resumable session waits for its
    // client, and a resume carries on where it stopped.
    proxy.abort();
    let _ = proxy.await;
    let mut detached = false;
    for _ in 0..100 {
        let s: serde_json::Value = http
            .get(&url)
            .bearer_auth(ADMIN)
            .send()
            .await
            .unwrap()
            .json()
            .await
            .unwrap();
        if s["sessions"][0]["state"] == "detached" {
            detached = true;
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    assert!(detached, "the session was not kept for resumption");
    let rest: Vec<In> = good.collect();
    let (scores, events) = stream_all(addr, Some(ROBOT), open_msg("sim-arm", "held", None), rest)
        .await
        .unwrap();
    assert_eq!(events[0].kind, proto::session_event::Kind::Resumed as i32);
    assert!(!scores.is_empty());
    // Frame indices carry on from before the disconnect.
    assert!(scores[0].frame >= 2, "{}", scores[0].frame);
    assert_eq!(server.shared.hub.session_count(), 0);

    // A session that never sends its open message, and a stream whose first message is
    // not `open`.
    let err = stream_all(
        addr,
        Some(ROBOT),
        In::Phase(proto::PhaseMarker {
            stamp_ns: 0,
            phase: "release".into(),
        }),
        vec![],
    )
    .await
    .unwrap_err();
    assert_eq!(err.code(), tonic::Code::InvalidArgument);
    let mut counts = HashMap::new();
    for line in metrics_text(server.rest_addr)
        .await
        .lines()
        .filter(|l| l.starts_with("vamos_message_errors_total"))
    {
        let (k, v) = line.rsplit_once(' ').unwrap();
        counts.insert(k.to_string(), v.parse::<f64>().unwrap());
    }
    assert_eq!(
        counts["vamos_message_errors_total{kind=\"joints\",profile=\"sim-arm\"}"],
        1.0
    );
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn health_reflection_readiness_and_one_port() {
    let f = fixture_setup(4, false);
    let server = start(&f).await;
    assert_ne!(server.grpc_addr, server.rest_addr);
    let mut health = tonic_health::pb::health_client::HealthClient::new(
        tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
            .unwrap()
            .connect()
            .await
            .unwrap(),
    );
    let r = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: "vamos.v1.Monitor".into(),
        })
        .await
        .unwrap()
        .into_inner();
    assert_eq!(
        r.status,
        tonic_health::pb::health_check_response::ServingStatus::Serving as i32
    );
    // `vamos health` (the containers' health check) says the same, and exit code 1 for a
    // service the server does not have.
    let probe = |service: &'static str| {
        let url = format!("http://{}", server.grpc_addr);
        tokio::task::spawn_blocking(move || {
            std::process::Command::new(env!("CARGO_BIN_EXE_vamos"))
                .args(["health", "--server", &url, "--service", service])
                .output()
                .unwrap()
        })
    };
    let out = probe("vamos.v1.Monitor").await.unwrap();
    assert!(out.status.success(), "{out:?}");
    let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["status"], "SERVING");
    let out = probe("no.such.Service").await.unwrap();
    assert_eq!(out.status.code(), Some(1), "{out:?}");
    // Server reflection, as grpcurl uses it: list the services, then fetch the file that
    // declares Monitor (v1 and v1alpha).
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    {
        use tonic_reflection::pb::v1::{
            ServerReflectionRequest, server_reflection_client::ServerReflectionClient,
            server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
        };
        let mut client = ServerReflectionClient::new(channel.clone());
        let requests = [
            MessageRequest::ListServices(String::new()),
            MessageRequest::FileContainingSymbol("vamos.v1.Monitor".into()),
        ]
        .map(|m| ServerReflectionRequest {
            host: String::new(),
            message_request: Some(m),
        });
        let mut answers = client
            .server_reflection_info(tokio_stream::iter(requests))
            .await
            .unwrap()
            .into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) =
            answers.next().await.unwrap().unwrap().message_response
        else {
            panic!("no service list");
        };
        let names: Vec<&str> = list.service.iter().map(|s| s.name.as_str()).collect();
        assert!(names.contains(&"vamos.v1.Monitor"), "{names:?}");
        assert!(names.contains(&"grpc.health.v1.Health"), "{names:?}");
        let Some(MessageResponse::FileDescriptorResponse(files)) =
            answers.next().await.unwrap().unwrap().message_response
        else {
            panic!("no file descriptor");
        };
        let fd = <prost_types::FileDescriptorProto as prost::Message>::decode(
            files.file_descriptor_proto[0].as_slice(),
        )
        .unwrap();
        assert_eq!(fd.package(), "vamos.v1");
        let methods: Vec<&str> = fd.service[0].method.iter().map(|m| m.name()).collect();
        assert_eq!(methods, ["Stream", "ScoreEpisode"]);
    }
    {
        use tonic_reflection::pb::v1alpha::{
            ServerReflectionRequest, server_reflection_client::ServerReflectionClient,
            server_reflection_request::MessageRequest, server_reflection_response::MessageResponse,
        };
        let mut client = ServerReflectionClient::new(channel);
        let mut answers = client
            .server_reflection_info(tokio_stream::iter([ServerReflectionRequest {
                host: String::new(),
                message_request: Some(MessageRequest::ListServices(String::new())),
            }]))
            .await
            .unwrap()
            .into_inner();
        let Some(MessageResponse::ListServicesResponse(list)) =
            answers.next().await.unwrap().unwrap().message_response
        else {
            panic!("no service list (v1alpha)");
        };
        assert!(list.service.iter().any(|s| s.name == "vamos.v1.Monitor"));
    }
    let ready = reqwest::get(format!("http://{}/readyz", server.rest_addr))
        .await
        .unwrap();
    assert_eq!(ready.status(), 200);
    let missing = reqwest::get(format!("http://{}/v2/models/nope/ready", server.rest_addr))
        .await
        .unwrap();
    assert_eq!(missing.status(), 404);
    server.shutdown().await.unwrap();

    // gRPC and REST on one port.
    let mut f = fixture_setup(4, false);
    f.settings.service.grpc_addr = "127.0.0.1:0".into();
    f.settings.service.rest_addr = f.settings.service.grpc_addr.clone();
    let catalog = ProfileCatalog::from_setups(vec![f.setup.clone()]);
    let server = Server::start(f.settings.clone(), catalog).await.unwrap();
    assert_eq!(server.grpc_addr, server.rest_addr);
    let body = reqwest::get(format!("http://{}/healthz", server.rest_addr))
        .await
        .unwrap()
        .text()
        .await
        .unwrap();
    assert!(body.contains("live"));
    let mut health = tonic_health::pb::health_client::HealthClient::new(
        tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
            .unwrap()
            .connect()
            .await
            .unwrap(),
    );
    assert!(
        health
            .check(tonic_health::pb::HealthCheckRequest {
                service: String::new(),
            })
            .await
            .is_ok()
    );
    let unknown = reqwest::get(format!("http://{}/nope", server.rest_addr))
        .await
        .unwrap();
    assert_eq!(unknown.status(), 404);
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_on_both_transports_with_a_generated_certificate() {
    let mut f = fixture_setup(4, false);
    let cert = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (cert_path, key_path) = (dir.path().join("tls.crt"), dir.path().join("tls.key"));
    std::fs::write(&cert_path, cert.cert.pem()).unwrap();
    std::fs::write(&key_path, cert.signing_key.serialize_pem()).unwrap();
    f.settings.service.tls = Some(vamos::service::TlsConfig {
        cert: cert_path,
        key: key_path,
    });
    let server = start(&f).await;

    // gRPC over TLS: a session end to end.
    let tls = tonic::transport::ClientTlsConfig::new()
        .ca_certificate(tonic::transport::Certificate::from_pem(cert.cert.pem()))
        .domain_name("localhost");
    let channel = tonic::transport::Endpoint::from_shared(format!("https://{}", server.grpc_addr))
        .unwrap()
        .tls_config(tls)
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut client = MonitorClient::new(channel);
    let name = "test_0000";
    let (messages, camera) = episode_messages(&episode(name));
    let mut requests = vec![proto::StreamRequest {
        message: Some(open_msg("sim-arm", name, camera)),
    }];
    requests.extend(
        messages
            .into_iter()
            .map(|m| proto::StreamRequest { message: Some(m) }),
    );
    let mut inbound = client
        .stream(tokio_stream::iter(requests))
        .await
        .unwrap()
        .into_inner();
    let mut scores = Vec::new();
    while let Some(item) = inbound.next().await {
        if let Some(proto::stream_response::Message::Score(s)) = item.unwrap().message {
            scores.push(s);
        }
    }
    assert_same_scores(&scores, &offline(&f.setup, &episode(name)));

    // REST over TLS, trusting the generated certificate; plain HTTP is refused.
    let http = reqwest::Client::builder()
        .add_root_certificate(reqwest::Certificate::from_pem(cert.cert.pem().as_bytes()).unwrap())
        .resolve("localhost", server.rest_addr)
        .build()
        .unwrap();
    let r = http
        .get(format!(
            "https://localhost:{}/healthz",
            server.rest_addr.port()
        ))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 200);
    assert!(
        reqwest::get(format!("http://{}/healthz", server.rest_addr))
            .await
            .is_err()
    );
    // A client that does not trust the certificate fails the handshake.
    assert!(
        reqwest::get(format!(
            "https://localhost:{}/healthz",
            server.rest_addr.port()
        ))
        .await
        .is_err()
    );
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn backpressure_drops_oldest_or_rejects_and_says_so() {
    for policy in [
        vamos::service::QueuePolicy::DropOldest,
        vamos::service::QueuePolicy::Reject,
    ] {
        let mut f = fixture_setup(4, false);
        f.settings.service.queue_depth = 2;
        f.settings.service.queue_policy = policy;
        f.settings.service.workers = 1;
        let server = start(&f).await;
        let name = "test_0000";
        let (messages, camera) = episode_messages(&episode(name));
        let images = messages
            .iter()
            .filter(|m| matches!(m, In::Image(_)))
            .count() as u64;
        // Everything at once: far faster than one worker scores.
        let (scores, events) = stream_all(
            server.grpc_addr,
            None,
            open_msg("sim-arm", name, camera),
            messages,
        )
        .await
        .unwrap();
        let dropped = events
            .iter()
            .filter(|e| e.kind == proto::session_event::Kind::FramesDropped as i32)
            .map(|e| e.count)
            .max()
            .unwrap_or(0);
        assert!(dropped > 0, "{policy:?}: nothing dropped");
        assert_eq!(scores.len() as u64 + dropped, images, "{policy:?}");
        // Scores stay in stamp order.
        assert!(scores.windows(2).all(|w| w[0].stamp_ns < w[1].stamp_ns));
        let detail = &events
            .iter()
            .find(|e| e.kind == proto::session_event::Kind::FramesDropped as i32)
            .unwrap()
            .detail;
        let reason = match policy {
            vamos::service::QueuePolicy::DropOldest => "dropped (oldest first)",
            vamos::service::QueuePolicy::Reject => "rejected",
        };
        assert!(detail.contains(reason), "{detail}");
        let metrics = metrics_text(server.rest_addr).await;
        let label = match policy {
            vamos::service::QueuePolicy::DropOldest => "queue_full",
            vamos::service::QueuePolicy::Reject => "rejected",
        };
        assert!(
            metrics.contains(&format!(
                "vamos_frames_dropped_total{{profile=\"sim-arm\",reason=\"{label}\"}} {dropped}"
            )),
            "{metrics}"
        );
        server.shutdown().await.unwrap();
    }
}
