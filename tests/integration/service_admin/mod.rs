//! The REST administration API end to end: tokens on every admin route, robots, models
//! (ONNX-validated uploads), stored profiles served to gRPC sessions, a model hot swap
//! that keeps running sessions, threshold patches, a calibration job, and a restart that
//! keeps the data directory.

mod calibration;
mod profiles;

use super::service::{
    ADMIN, PROFILE, ROBOT, authed, episode, episode_messages, fixture, hex_sha256, open_msg,
};

use futures_util::StreamExt;

use reqwest::{Client, Method, StatusCode};

use serde_json::{Value, json};

use std::path::PathBuf;

use std::time::Duration;

use tokio::sync::mpsc;

use tokio_stream::wrappers::ReceiverStream;

use vamos::api::proto::monitor_client::MonitorClient;

use vamos::api::proto::{self, stream_request::Message as In};

use vamos::api::rest::{Access, ROUTES};

use vamos::config::Settings;

use vamos::service::{RunningServer, Server};

use vamos::session::ProfileCatalog;

pub(crate) fn settings(dir: &std::path::Path) -> Settings {
    let mut s = Settings::default();
    s.service.grpc_addr = "127.0.0.1:0".into();
    s.service.rest_addr = "127.0.0.2:0".into();
    s.service.data_dir = dir.join("data");
    s.service.workers = 2;
    s.service.queue_depth = 64;
    s.service.shutdown_grace_s = 5.0;
    s.service.admin_token_sha256 = vec![hex_sha256(ADMIN)];
    s.service.robot_token_sha256 = vec![hex_sha256(ROBOT)];
    // Uploaded models are validated by the vamos binary in a child process, as in `vamos
    // serve` (this test program is not vamos).
    s.service.model_validator = Some(env!("CARGO_BIN_EXE_vamos").into());
    s
}

pub(crate) async fn start(settings: &Settings) -> RunningServer {
    Server::start(settings.clone(), ProfileCatalog::from_setups(Vec::new()))
        .await
        .unwrap()
}

pub(crate) fn model_fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/model")
        .join(name)
}

pub(crate) struct Api {
    http: Client,
    base: String,
}

impl Api {
    pub(crate) fn new(server: &RunningServer) -> Self {
        Self::at(format!("http://{}", server.rest_addr))
    }

    /// The API at a base URL (`http://host:port`).
    pub(crate) fn at(base: String) -> Self {
        Self {
            http: Client::new(),
            base,
        }
    }

    pub(crate) async fn call(
        &self,
        method: Method,
        path: &str,
        body: Option<Vec<u8>>,
    ) -> (StatusCode, Value) {
        let mut req = self
            .http
            .request(method, format!("{}{path}", self.base))
            .bearer_auth(ADMIN);
        if let Some(b) = body {
            req = req.body(b);
        }
        let resp = req.send().await.unwrap();
        let status = resp.status();
        let text = resp.text().await.unwrap();
        (status, serde_json::from_str(&text).unwrap_or(Value::Null))
    }

    pub(crate) async fn json(
        &self,
        method: Method,
        path: &str,
        body: Value,
    ) -> (StatusCode, Value) {
        self.call(method, path, Some(serde_json::to_vec(&body).unwrap()))
            .await
    }

    /// `POST /v1/profiles/arm-store/calibrate` with a multipart body.
    async fn calibrate_form(&self, form: reqwest::multipart::Form) -> reqwest::Response {
        self.http
            .post(format!("{}/v1/profiles/arm-store/calibrate", self.base))
            .bearer_auth(ADMIN)
            .multipart(form)
            .send()
            .await
            .unwrap()
    }

    pub(crate) async fn get(&self, path: &str) -> Value {
        let (status, v) = self.call(Method::GET, path, None).await;
        assert_eq!(status, StatusCode::OK, "GET {path}: {v}");
        v
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_route_refuses_missing_and_insufficient_tokens() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(&settings(dir.path())).await;
    let http = Client::new();
    let mut admin_routes = 0;
    for &(method, path, access) in ROUTES {
        let url = format!(
            "http://{}{}",
            server.rest_addr,
            path.replace("{name}", "x")
                .replace("{version}", "1")
                .replace("{id}", "1")
        );
        let m = Method::from_bytes(method.as_bytes()).unwrap();
        let none = http.request(m.clone(), &url).send().await.unwrap().status();
        let robot = http
            .request(m, &url)
            .bearer_auth(ROBOT)
            .send()
            .await
            .unwrap()
            .status();
        match access {
            Access::Open => {
                assert_ne!(none, StatusCode::UNAUTHORIZED, "{method} {path}");
            }
            Access::Viewer | Access::Robot => {
                assert_eq!(none, StatusCode::UNAUTHORIZED, "{method} {path}");
                assert_ne!(robot, StatusCode::FORBIDDEN, "{method} {path}");
                assert_ne!(robot, StatusCode::UNAUTHORIZED, "{method} {path}");
            }
            Access::Admin => {
                admin_routes += 1;
                assert_eq!(none, StatusCode::UNAUTHORIZED, "{method} {path}");
                assert_eq!(robot, StatusCode::FORBIDDEN, "{method} {path}");
            }
        }
    }
    assert!(admin_routes >= 12, "{admin_routes} admin routes");
    // The description served is the one the routes are checked against.
    let doc: Value = reqwest::get(format!("http://{}/openapi.json", server.rest_addr))
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(doc["paths"].as_object().unwrap().len(), {
        let mut paths: Vec<&str> = ROUTES.iter().map(|r| r.1).collect();
        paths.sort();
        paths.dedup();
        paths.len()
    });
    server.shutdown().await.unwrap();
}

/// A session on `profile` fed by a channel; returns the sender and a task collecting
/// (scores, events, error).
pub(crate) async fn open_session(
    addr: std::net::SocketAddr,
    profile: &str,
    session_id: &str,
    camera: Option<proto::CameraInfo>,
) -> (
    mpsc::Sender<proto::StreamRequest>,
    tokio::task::JoinHandle<(
        Vec<proto::FrameScore>,
        Vec<proto::SessionEvent>,
        Option<tonic::Status>,
    )>,
    proto::SessionEvent,
) {
    let mut client = MonitorClient::connect(format!("http://{addr}"))
        .await
        .unwrap();
    let (tx, rx) = mpsc::channel(256);
    tx.send(proto::StreamRequest {
        message: Some(open_msg(profile, session_id, camera)),
    })
    .await
    .unwrap();
    let mut inbound = client
        .stream(authed(ReceiverStream::new(rx), Some(ROBOT)))
        .await
        .unwrap()
        .into_inner();
    let opened = match inbound.next().await.unwrap().unwrap().message {
        Some(proto::stream_response::Message::Event(e)) => e,
        other => panic!("first message {other:?}"),
    };
    let task = tokio::spawn(async move {
        let mut scores = Vec::new();
        let mut events = Vec::new();
        while let Some(item) = inbound.next().await {
            match item {
                Ok(r) => match r.message {
                    Some(proto::stream_response::Message::Score(s)) => scores.push(s),
                    Some(proto::stream_response::Message::Event(e)) => events.push(e),
                    Some(proto::stream_response::Message::Alarm(_)) | None => {}
                },
                Err(s) => return (scores, events, Some(s)),
            }
        }
        (scores, events, None)
    });
    (tx, task, opened)
}

pub(crate) async fn send_all(tx: &mpsc::Sender<proto::StreamRequest>, messages: &[In]) {
    for m in messages {
        tx.send(proto::StreamRequest {
            message: Some(m.clone()),
        })
        .await
        .unwrap();
    }
}

pub(crate) fn images(messages: &[In]) -> usize {
    messages
        .iter()
        .filter(|m| matches!(m, In::Image(_)))
        .count()
}

/// A ProfileSpec on robot `arm` and model `tiny`: the fixture's camera and the pipeline
/// section of [`PROFILE`].
fn profile_spec() -> Value {
    let camera: Value =
        serde_json::from_str(&std::fs::read_to_string(fixture().join("camera.json")).unwrap())
            .unwrap();
    json!({
        "robot": "arm",
        "camera": camera,
        "model": { "name": "tiny" },
        "flow_preset": "realtime",
        "pipeline": { "stride": 1, "frames": { "width": 160, "height": 120, "variant": "masked" } },
    })
}

/// Robot `arm`, model `tiny` (version 1) and the stored profile `arm-store` on them.
pub(crate) async fn stored_profile(api: &Api) -> Vec<u8> {
    let urdf = std::fs::read(fixture().join("robot/vamos_arm.urdf")).unwrap();
    let (status, robot) = api
        .call(Method::PUT, "/v1/robots/arm?format=urdf", Some(urdf))
        .await;
    assert_eq!(status, StatusCode::CREATED, "{robot}");
    let bundle = std::fs::read(model_fixture("tiny_trained.vamos")).unwrap();
    let (status, v1) = api
        .call(Method::PUT, "/v1/models/tiny", Some(bundle.clone()))
        .await;
    assert_eq!(status, StatusCode::CREATED, "{v1}");
    let (status, p) = api
        .json(Method::PUT, "/v1/profiles/arm-store", profile_spec())
        .await;
    assert_eq!(status, StatusCode::OK, "{p}");
    bundle
}

/// Polls job `id` until it has ended.
pub(crate) async fn wait_job(api: &Api, id: u64) -> Value {
    let deadline = std::time::Instant::now() + Duration::from_secs(600);
    loop {
        let j = api.get(&format!("/v1/jobs/{id}")).await;
        if j["state"] != "running" {
            return j;
        }
        assert!(std::time::Instant::now() < deadline, "job {id} too slow");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}
