//! The REST administration API end to end: tokens on every admin route, robots, models
//! (ONNX-validated uploads), stored profiles served to gRPC sessions, a model hot swap
//! that keeps running sessions, threshold patches, a calibration job, and a restart that
//! keeps the data directory.

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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn stored_profiles_serve_sessions_swap_models_calibrate_and_survive_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let settings = settings(dir.path());
    let server = start(&settings).await;
    let api = Api::new(&server);

    // A robot.
    let urdf = std::fs::read(fixture().join("robot/vamos_arm.urdf")).unwrap();
    let (status, robot) = api
        .call(Method::PUT, "/v1/robots/arm?format=urdf", Some(urdf))
        .await;
    assert_eq!(status, StatusCode::CREATED, "{robot}");
    assert_eq!(robot["name"], "arm");
    assert_eq!(robot["format"], "urdf");
    assert!(robot["summary"]["joints"].as_u64().unwrap() > 0);

    // A model; a corrupt one is refused with the reason and leaves it as it was.
    let bundle = std::fs::read(model_fixture("tiny_trained.vamos")).unwrap();
    let (status, v1) = api
        .call(Method::PUT, "/v1/models/tiny", Some(bundle.clone()))
        .await;
    assert_eq!(status, StatusCode::CREATED, "{v1}");
    assert_eq!(v1["version"], 1);
    assert_eq!(v1["active"], 1);
    assert_eq!(v1["name"], "tiny");
    for bad in ["corrupt_onnx.vamos", "checksum.vamos"] {
        let (status, e) = api
            .call(
                Method::PUT,
                "/v1/models/tiny",
                Some(std::fs::read(model_fixture(bad)).unwrap()),
            )
            .await;
        assert_eq!(status, StatusCode::BAD_REQUEST, "{bad}: {e}");
        assert!(e["error"].as_str().unwrap().len() > 10, "{e}");
    }
    let model = api.get("/v1/models/tiny").await;
    assert_eq!(model["active"], 1);
    assert_eq!(model["versions"].as_array().unwrap().len(), 1);

    // A profile: the fixture's camera and pipeline section, the stored robot and model.
    assert!(PROFILE.contains("width = 160") && PROFILE.contains("variant = \"masked\""));
    let (status, p) = api
        .json(Method::PUT, "/v1/profiles/arm-store", profile_spec())
        .await;
    assert_eq!(status, StatusCode::OK, "{p}");
    assert_eq!(p["load_error"], Value::Null, "{p}");
    assert_eq!(p["model"], "tiny@1");
    let list = api.get("/v1/profiles").await;
    assert!(
        list["profiles"]
            .as_array()
            .unwrap()
            .iter()
            .any(|p| p["name"] == "arm-store" && p["source"] == "store")
    );
    let ready = reqwest::get(format!("{}/v2/models/tiny/ready", api.base))
        .await
        .unwrap();
    assert_eq!(ready.status(), StatusCode::OK);

    // A session scores with the stored profile.
    let (messages, camera_info) = episode_messages(&episode("test_0000"));
    let half = messages.len() / 2;
    let (tx_a, task_a, opened_a) =
        open_session(server.grpc_addr, "arm-store", "a", camera_info).await;
    assert!(
        opened_a.detail.contains("model tiny@1"),
        "{}",
        opened_a.detail
    );
    send_all(&tx_a, &messages[..half]).await;

    // A second version, made active while session a streams.
    let (status, v2) = api.call(Method::PUT, "/v1/models/tiny", Some(bundle)).await;
    assert_eq!(status, StatusCode::CREATED, "{v2}");
    assert_eq!(v2["version"], 2);
    assert_eq!(v2["active"], 1, "a new version is not active by itself");
    let (status, m) = api
        .json(
            Method::POST,
            "/v1/models/tiny/active",
            json!({ "version": 2 }),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{m}");
    assert_eq!(m["active"], 2);
    let (tx_b, task_b, opened_b) =
        open_session(server.grpc_addr, "arm-store", "b", camera_info).await;
    assert!(
        opened_b.detail.contains("model tiny@2"),
        "{}",
        opened_b.detail
    );
    send_all(&tx_a, &messages[half..]).await;
    send_all(&tx_b, &messages[..half]).await;
    drop(tx_a);
    drop(tx_b);
    let (scores_a, _, err_a) = task_a.await.unwrap();
    let (scores_b, _, err_b) = task_b.await.unwrap();
    assert!(err_a.is_none(), "{err_a:?}");
    assert!(err_b.is_none(), "{err_b:?}");
    assert_eq!(
        scores_a.len(),
        images(&messages),
        "session a scored every frame"
    );
    assert_eq!(scores_b.len(), images(&messages[..half]));
    assert!(scores_a.iter().all(|s| s.score.is_finite()));
    // Same frames, same geometry (e_c, e_b do not depend on the model; e_o does on the
    // session's sampling seed).
    for (a, b) in scores_a.iter().zip(&scores_b) {
        assert_eq!(a.stamp_ns, b.stamp_ns);
        assert_eq!(a.e_c, b.e_c);
        assert_eq!(a.e_b, b.e_b);
    }
    assert!(scores_b.iter().any(|s| s.e_o.is_some_and(|v| v > 0.0)));
    // The active version cannot go while the profile follows it.
    let (status, _) = api
        .call(Method::DELETE, "/v1/models/tiny/versions/2", None)
        .await;
    assert_eq!(status, StatusCode::CONFLICT);

    // Thresholds.
    let (status, p) = api
        .json(
            Method::PATCH,
            "/v1/profiles/arm-store/thresholds",
            json!({ "alarm": 3.5 }),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{p}");
    let p = api.get("/v1/profiles/arm-store").await;
    assert_eq!(p["alarm_threshold"], 3.5);

    // Calibration over the training episodes.
    let train = fixture().join("train");
    let (status, job) = api
        .json(
            Method::POST,
            "/v1/profiles/arm-store/calibrate",
            json!({ "episodes": [train] }),
        )
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["job"].as_u64().unwrap();
    let deadline = std::time::Instant::now() + Duration::from_secs(600);
    let job = loop {
        let j = api.get(&format!("/v1/jobs/{id}")).await;
        if j["state"] != "running" {
            break j;
        }
        assert!(std::time::Instant::now() < deadline, "calibration too slow");
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(job["profile"], "arm-store");
    let p = api.get("/v1/profiles/arm-store").await;
    assert_eq!(p["calibrated"], true);
    let cal = &p["profile"]["calibration"];
    assert_eq!(cal, &job["calibration"]);
    assert_eq!(
        cal["training_episodes"],
        json!(["train_0000", "train_0001"])
    );
    assert!(cal["training_frames"].as_u64().unwrap() > 0);
    // The override stays in force over the calibrated alarm threshold; the calibrated
    // e_c threshold is in force.
    assert_eq!(p["alarm_threshold"], 3.5);
    assert_eq!(p["profile"]["thresholds"]["e_c"], cal["thresholds"]["e_c"]);
    let jobs = api.get("/v1/jobs").await;
    assert_eq!(jobs["jobs"].as_array().unwrap().len(), 1);
    // Lists give the sizes of the bulky statistics (the nominal robot states, the
    // scene's per-cell statistics); the profile and the job themselves give them whole.
    let whole = &cal["thresholds"]["kinematics"];
    let count = whole["count"].as_u64().unwrap();
    assert!(
        count > 0 && whole["codes"].as_str().unwrap().len() > 100,
        "{whole}"
    );
    assert!(cal["thresholds"]["scene"]["maps"].as_u64().unwrap() > 0);
    assert_eq!(
        api.get(&format!("/v1/jobs/{}", job["id"])).await["calibration"],
        *cal
    );
    let listed = api
        .get("/v1/profiles")
        .await
        .get("profiles")
        .and_then(|l| {
            l.as_array()?
                .iter()
                .find(|p| p["name"] == "arm-store")
                .cloned()
        })
        .unwrap();
    for thresholds in [
        &jobs["jobs"][0]["calibration"]["thresholds"],
        &listed["profile"]["calibration"]["thresholds"],
        &listed["profile"]["thresholds"],
    ] {
        let k = &thresholds["kinematics"];
        assert_eq!(
            (k["count"].as_u64(), &k["dims"]),
            (Some(count), &whole["dims"]),
            "{k}"
        );
        assert!(k.get("codes").is_none() && k["detail"].is_string(), "{k}");
        let scene = &thresholds["scene"];
        assert_eq!(scene["maps"], cal["thresholds"]["scene"]["maps"], "{scene}");
        assert!(scene.get("location").is_none(), "{scene}");
        assert_eq!(thresholds["e_c"], cal["thresholds"]["e_c"]);
    }

    // A restart on the same data directory keeps everything.
    server.shutdown().await.unwrap();
    let server = start(&settings).await;
    let api = Api::new(&server);
    let model = api.get("/v1/models/tiny").await;
    assert_eq!(model["active"], 2);
    assert_eq!(model["versions"].as_array().unwrap().len(), 2);
    assert_eq!(api.get("/v1/robots").await["robots"][0]["name"], "arm");
    let p = api.get("/v1/profiles/arm-store").await;
    assert_eq!(p["profile"]["calibration"], *cal);
    assert_eq!(p["alarm_threshold"], 3.5);
    // The job's record is kept in the data directory.
    let jobs = api.get("/v1/jobs").await;
    assert_eq!(jobs["jobs"].as_array().unwrap().len(), 1, "{jobs}");
    assert_eq!(jobs["jobs"][0]["state"], "succeeded");
    let (_, _, opened) = open_session(server.grpc_addr, "arm-store", "c", camera_info).await;
    assert!(opened.detail.contains("model tiny@2"), "{}", opened.detail);
    server.shutdown().await.unwrap();
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_running_session_moves_to_a_new_model_version_when_asked() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(&settings(dir.path())).await;
    let api = Api::new(&server);
    let bundle = stored_profile(&api).await;
    let (messages, camera_info) = episode_messages(&episode("test_0000"));
    let half = messages.len() / 2;
    let (tx, task, opened) = open_session(server.grpc_addr, "arm-store", "a", camera_info).await;
    assert!(opened.detail.contains("model tiny@1"), "{}", opened.detail);
    // A session that keeps its version, for comparison.
    let (tx_keep, task_keep, _) =
        open_session(server.grpc_addr, "arm-store", "keep", camera_info).await;
    send_all(&tx, &messages[..half]).await;
    send_all(&tx_keep, &messages[..half]).await;

    // Nothing changed yet: a reload is a no-op. Unknown sessions are 404.
    let (status, r) = api.call(Method::POST, "/v1/sessions/a/reload", None).await;
    assert_eq!(status, StatusCode::OK, "{r}");
    assert_eq!(r["reloaded"], false);
    let (status, _) = api
        .call(Method::POST, "/v1/sessions/nobody/reload", None)
        .await;
    assert_eq!(status, StatusCode::NOT_FOUND);

    // Version 2, made active with `reload_sessions`: both running sessions move.
    let (status, v2) = api.call(Method::PUT, "/v1/models/tiny", Some(bundle)).await;
    assert_eq!(status, StatusCode::CREATED, "{v2}");
    let (status, m) = api
        .json(
            Method::POST,
            "/v1/models/tiny/active",
            json!({ "version": 2, "reload_sessions": true }),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{m}");
    assert_eq!(m["active"], 2);
    let mut moved: Vec<&str> = m["reloaded_sessions"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    moved.sort();
    assert_eq!(moved, ["a", "keep"]);
    let listed = api.get("/v1/sessions").await;
    let a = listed["sessions"]
        .as_array()
        .unwrap()
        .iter()
        .find(|s| s["id"] == "a")
        .unwrap()
        .clone();
    assert_eq!(a["model"], "tiny@2", "{a}");
    assert_eq!(a["reloads"], 1, "{a}");
    // Asked again: already on the current version.
    let (_, r) = api.call(Method::POST, "/v1/sessions/a/reload", None).await;
    assert_eq!(r["reloaded"], false, "{r}");

    send_all(&tx, &messages[half..]).await;
    send_all(&tx_keep, &messages[half..]).await;
    drop(tx);
    drop(tx_keep);
    let (scores, events, err) = task.await.unwrap();
    let (scores_keep, _, err_keep) = task_keep.await.unwrap();
    assert!(err.is_none(), "{err:?}");
    assert!(err_keep.is_none(), "{err_keep:?}");
    // Every frame scored, indices going on across the reload.
    assert_eq!(scores.len(), images(&messages));
    assert!(scores.windows(2).all(|w| w[1].index == w[0].index + 1));
    assert!(scores.windows(2).all(|w| w[1].frame == w[0].frame + 1));
    use proto::session_event::Kind;
    let reloaded: Vec<&proto::SessionEvent> = events
        .iter()
        .filter(|e| e.kind == Kind::Reloaded as i32)
        .collect();
    assert_eq!(reloaded.len(), 1, "{events:?}");
    assert!(
        reloaded[0].detail.contains("model tiny@2"),
        "{:?}",
        reloaded[0]
    );
    assert_eq!(reloaded[0].count, 1);
    // The predictor warms up again after the reload, and e_o comes back after that.
    let warm = events
        .iter()
        .filter(|e| e.kind == Kind::WarmingUp as i32)
        .count();
    assert_eq!(warm, 2, "{events:?}");
    let after: Vec<&proto::FrameScore> = scores.iter().filter(|s| s.warming_up).collect();
    assert!(after.len() > 1);
    assert!(
        scores[half.min(scores.len() - 1)..]
            .iter()
            .any(|s| s.e_o.is_some())
    );
    assert_eq!(scores_keep.len(), scores.len());
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn calibration_from_uploaded_episodes_with_job_limits_cancel_and_restart() {
    let dir = tempfile::tempdir().unwrap();
    let mut settings = settings(dir.path());
    settings.service.max_jobs = 1;
    let server = start(&settings).await;
    let api = Api::new(&server);
    stored_profile(&api).await;

    // Episodes uploaded with the request (multipart/form-data).
    let part = |name: &str| {
        let bytes = std::fs::read(fixture().join("train").join(name)).unwrap();
        reqwest::multipart::Part::bytes(bytes)
            .file_name(name.to_string())
            .mime_str("application/x-mcap")
            .unwrap()
    };
    let form = reqwest::multipart::Form::new()
        .part("episodes", part("train_0000.mcap"))
        .part("episodes", part("train_0001.mcap"))
        .text("alpha", "0.2");
    let resp = api.calibrate_form(form).await;
    assert_eq!(resp.status(), StatusCode::ACCEPTED);
    let first = resp.json::<Value>().await.unwrap()["job"].as_u64().unwrap();

    // One job at a time here: a second one is refused while the first runs.
    let train = fixture().join("train");
    let many = json!({ "episodes": [&train, &train, &train, &train] });
    let (status, e) = api
        .json(
            Method::POST,
            "/v1/profiles/arm-store/calibrate",
            many.clone(),
        )
        .await;
    // (The first job still running after the refused request was running during it.)
    let first_state = api.get(&format!("/v1/jobs/{first}")).await["state"].clone();
    if first_state == "running" {
        assert_eq!(status, StatusCode::TOO_MANY_REQUESTS, "{e}");
        assert!(e["error"].as_str().unwrap().contains("at once"), "{e}");
    } else if status == StatusCode::ACCEPTED {
        wait_job(&api, e["job"].as_u64().unwrap()).await;
    }
    let job = wait_job(&api, first).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(
        job["episodes"],
        json!(["train_0000.mcap", "train_0001.mcap"])
    );
    let cal = &job["calibration"];
    assert_eq!(
        cal["training_episodes"],
        json!(["train_0000", "train_0001"])
    );
    assert!(cal["training_frames"].as_u64().unwrap() > 0);
    let p = api.get("/v1/profiles/arm-store").await;
    assert_eq!(p["profile"]["calibration"], *cal);
    // The uploads went with the job.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let leftovers = || {
        std::fs::read_dir(server.shared.upload_dir())
            .unwrap()
            .count()
    };
    while leftovers() > 0 && std::time::Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    assert_eq!(leftovers(), 0);

    // Bad uploads are refused before any job starts.
    let form = reqwest::multipart::Form::new().part("weights", part("train_0000.mcap"));
    let resp = api.calibrate_form(form).await;
    assert_eq!(resp.status(), StatusCode::BAD_REQUEST);
    let text = resp.text().await.unwrap();
    assert!(text.contains("unknown part"), "{text}");
    let form = reqwest::multipart::Form::new()
        .part("episodes", part("train_0000.mcap"))
        .part("episodes", part("train_0000.mcap"));
    let resp = api.calibrate_form(form).await;
    assert_eq!(resp.status(), StatusCode::BAD_REQUEST);

    // A long job, cancelled: it stops before its next episode and saves nothing.
    let (status, j) = api
        .json(Method::POST, "/v1/profiles/arm-store/calibrate", many)
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{j}");
    let long = j["job"].as_u64().unwrap();
    let (status, _) = api
        .call(Method::DELETE, &format!("/v1/jobs/{long}"), None)
        .await;
    if status == StatusCode::ACCEPTED {
        let ended = wait_job(&api, long).await;
        assert_eq!(ended["state"], "cancelled", "{ended}");
        assert!(ended.get("calibration").is_none(), "{ended}");
        let p = api.get("/v1/profiles/arm-store").await;
        assert_eq!(
            p["profile"]["calibration"], *cal,
            "a cancelled job saved nothing"
        );
    } else {
        // It ended before the cancel arrived and its record was removed instead.
        assert_eq!(status, StatusCode::NO_CONTENT);
    }
    // A finished job's record can be removed; an unknown job is 404.
    let (status, _) = api.call(Method::DELETE, "/v1/jobs/999", None).await;
    assert_eq!(status, StatusCode::NOT_FOUND);

    // The job list survives a restart.
    let before = api.get("/v1/jobs").await;
    server.shutdown().await.unwrap();
    let server = start(&settings).await;
    let api = Api::new(&server);
    let after = api.get("/v1/jobs").await;
    assert_eq!(after, before);
    assert_eq!(after["jobs"][0]["id"], first);
    let (status, _) = api
        .call(Method::DELETE, &format!("/v1/jobs/{first}"), None)
        .await;
    assert_eq!(status, StatusCode::NO_CONTENT);
    let (status, _) = api
        .call(Method::GET, &format!("/v1/jobs/{first}"), None)
        .await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    server.shutdown().await.unwrap();
}

/// An operator's false alarm puts its session's recording in the profile's nominal set;
/// a recalibration from it proposes thresholds, shown (and nothing changed) before they
/// are applied; applied, the same run no longer alarms. Applying twice, a recalibration
/// without a calibration or without nominal episodes, are refused.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_false_alarm_joins_the_nominal_set_and_a_recalibration_clears_it() {
    const VIEWER: &str = "viewer-secret";
    let dir = tempfile::tempdir().unwrap();
    let mut settings = settings(dir.path());
    settings.service.viewer_token_sha256 = vec![hex_sha256(VIEWER)];
    let server = start(&settings).await;
    let api = Api::new(&server);
    stored_profile(&api).await;
    let recalibrate = "/v1/profiles/arm-store/recalibrate";
    let (status, e) = api.call(Method::POST, recalibrate, None).await;
    assert_eq!(status, StatusCode::CONFLICT, "{e}");
    assert!(
        e["error"].as_str().unwrap().contains("not calibrated"),
        "{e}"
    );

    // Calibrated on one training episode, the other held out (alpha 0.5: its maximum).
    let train = fixture().join("train");
    let (status, job) = api
        .json(
            Method::POST,
            "/v1/profiles/arm-store/calibrate",
            json!({
                "episodes": [train.join("train_0000.mcap")],
                "holdout": [train.join("train_0001.mcap")],
                "alpha": 0.5,
            }),
        )
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let job = wait_job(&api, job["job"].as_u64().unwrap()).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let maxima = &job["calibration"]["conformal"]["episode_maxima"];
    assert_eq!(maxima.as_array().map(Vec::len), Some(1), "{job}");
    let before = api.get("/v1/profiles/arm-store").await["alarm_threshold"].clone();
    assert!(before.as_f64().unwrap().is_finite());
    assert_eq!(
        api.get("/v1/profiles/arm-store/nominal").await,
        json!({ "episodes": [] })
    );
    let (status, e) = api.call(Method::POST, recalibrate, None).await;
    assert_eq!(status, StatusCode::CONFLICT, "{e}");
    assert!(e["error"].as_str().unwrap().contains("nominal set"), "{e}");

    // A run that alarms (the robot is pushed); the operator says it was a false alarm.
    let (messages, camera) = episode_messages(&episode("test_0001_external_push"));
    let addr = server.grpc_addr;
    let run = |camera: Option<proto::CameraInfo>| {
        let messages = messages.clone();
        async move {
            let (tx, task, _) = open_session(addr, "arm-store", "pushed", camera).await;
            send_all(&tx, &messages).await;
            drop(tx);
            let (scores, _, error) = task.await.unwrap();
            assert!(error.is_none(), "{error:?}");
            assert_eq!(scores.len(), images(&messages));
            scores
        }
    };
    let first = run(camera).await;
    assert!(first.iter().any(|s| s.anomaly), "the run alarms");
    let alarms = api.get("/v1/alarms").await;
    let alarm = alarms["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["session_id"] == "pushed")
        .unwrap_or_else(|| panic!("no alarm of the run: {alarms}"))
        .clone();
    // The push is over before the run is: the alarm's end was recorded too.
    assert!(alarm["end_frame"].is_u64(), "{alarm}");
    assert!(
        alarm["recording"].is_string(),
        "a recorded session: {alarm}"
    );
    let id = alarm["id"].as_str().unwrap();
    let (status, marked) = api
        .json(
            Method::POST,
            &format!("/v1/alarms/{id}/false-alarm"),
            json!({ "note": "a person leaned on it" }),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{marked}");
    let recording = marked["recording"].as_str().unwrap().to_string();
    assert!(recording.ends_with(".mcap"), "{marked}");
    // The session's recording is in the nominal set once the session has ended.
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    let nominal = loop {
        let n = api.get("/v1/profiles/arm-store/nominal").await;
        if n["episodes"][0]["finished"] == true {
            break n;
        }
        assert!(std::time::Instant::now() < deadline, "{n}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    };
    // A viewer may look at the nominal set, but neither recalibrate nor stream.
    let as_viewer = |method: Method, path: &str| {
        reqwest::Client::new()
            .request(method, format!("http://{}{path}", server.rest_addr))
            .bearer_auth(VIEWER)
            .send()
    };
    let seen = as_viewer(Method::GET, "/v1/profiles/arm-store/nominal")
        .await
        .unwrap();
    assert_eq!(seen.status(), StatusCode::OK);
    let refused = as_viewer(Method::POST, recalibrate).await.unwrap();
    assert_eq!(refused.status(), StatusCode::FORBIDDEN);
    let (tx, rx) = mpsc::channel(1);
    tx.send(proto::StreamRequest {
        message: Some(open_msg("arm-store", "viewer", None)),
    })
    .await
    .unwrap();
    let mut client = MonitorClient::connect(format!("http://{addr}"))
        .await
        .unwrap();
    let err = client
        .stream(authed(ReceiverStream::new(rx), Some(VIEWER)))
        .await
        .unwrap_err();
    assert_eq!(err.code(), tonic::Code::PermissionDenied, "{err}");
    let e = &nominal["episodes"][0];
    assert_eq!(
        (e["session_id"].as_str(), e["recording"].as_str()),
        (Some("pushed"), Some(recording.as_str()))
    );
    assert_eq!(e["alarms"], json!([id]));
    assert!(
        dir.path()
            .join("data/recordings")
            .join(&recording)
            .is_file()
    );

    // The recalibration proposes; nothing changes until it is applied.
    let (status, started) = api.call(Method::POST, recalibrate, None).await;
    assert_eq!(status, StatusCode::ACCEPTED, "{started}");
    let job_id = started["job"].as_u64().unwrap();
    let job = wait_job(&api, job_id).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let proposal = &job["proposal"];
    assert_eq!(proposal["current"]["alarm"], before, "{job}");
    let proposed = proposal["proposed"]["alarm"].as_f64().unwrap();
    let recorded = &proposal["episodes"][0];
    // The recording scores as the session did: its largest score is the run's.
    let run_max = first.iter().map(|s| s.score).fold(f64::MIN, f64::max);
    assert_eq!(
        recorded["max_score_before"].as_f64().unwrap(),
        run_max,
        "{job}"
    );
    assert!(
        recorded["max_score_after"].as_f64().unwrap() < proposed,
        "{job}"
    );
    assert!(proposal["applied_unix_s"].is_null());
    assert_eq!(
        api.get("/v1/profiles/arm-store").await["alarm_threshold"],
        before
    );

    // Applied: the profile's thresholds are the proposed ones, and the same run (seeded
    // the same, so scored the same) no longer alarms.
    let apply = format!("/v1/jobs/{job_id}/apply");
    let (status, applied) = api.call(Method::POST, &apply, None).await;
    assert_eq!(status, StatusCode::OK, "{applied}");
    assert!(applied["proposal"]["applied_unix_s"].is_u64(), "{applied}");
    let profile = api.get("/v1/profiles/arm-store").await;
    assert_eq!(profile["alarm_threshold"].as_f64(), Some(proposed));
    let again = run(camera).await;
    assert!(
        again.iter().all(|s| !s.anomaly),
        "a false alarm again after the recalibration"
    );
    let (status, e) = api.call(Method::POST, &apply, None).await;
    assert_eq!(status, StatusCode::CONFLICT, "{e}");
    server.shutdown().await.unwrap();
}
