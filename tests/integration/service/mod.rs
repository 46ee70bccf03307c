//! The service end to end: the real server on ephemeral ports, a real tonic client and a
//! real HTTP client, on the simulated episodes of tests/fixtures/sim.

mod streaming;
mod transport;

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
    fixture_with(max_sessions, tokens, "")
}

/// [`fixture_setup`] with `extra` appended to the profile file (e.g. `[thresholds]`).
pub(crate) fn fixture_with(max_sessions: usize, tokens: bool, extra: &str) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    // The profile names the fixture's robot and camera by absolute path.
    let profile_dir = dir.path().join("profile");
    std::fs::create_dir_all(&profile_dir).unwrap();
    let text = format!("{PROFILE}{extra}")
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
    settings.service.model_validator = Some(env!("CARGO_BIN_EXE_vamos").into());
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
        image_rate_hz: 0.0,
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
        assert_eq!(s.e_c, o.values[vamos::eval::Detector::Camera]);
        assert_eq!(s.e_b, o.values[vamos::eval::Detector::Body]);
        assert_eq!(s.e_o, o.values[vamos::eval::Detector::Flow]);
        assert_eq!(s.anomaly, o.anomaly);
        assert!(s.latency_s >= s.compute_s && s.compute_s > 0.0);
    }
}
