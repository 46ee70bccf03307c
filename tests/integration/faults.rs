//! Faults, deterministic: a full disk during an upload (injected), the server killed
//! with SIGKILL during a model upload and during a calibration job and started again on
//! its data directory, and a model swap while four robots stream. (A robot that
//! disconnects mid-stream and a stalled client are in `service.rs` and `client.rs`.)

use super::service::{ADMIN, ROBOT, episode, episode_messages, fixture};
use super::service_admin::{
    Api, images, open_session, send_all, settings, start, stored_profile, wait_job,
};
use reqwest::{Method, StatusCode};
use serde_json::{Value, json};
use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// The files left in the store's `tmp/` (uploads in progress).
fn tmp_entries(data: &Path) -> Vec<String> {
    std::fs::read_dir(data.join("tmp"))
        .map(|d| {
            d.filter_map(|e| e.ok())
                .map(|e| e.file_name().to_string_lossy().into_owned())
                .collect()
        })
        .unwrap_or_default()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_full_disk_during_an_upload_is_a_507_and_leaves_no_partial_model() {
    let dir = tempfile::tempdir().unwrap();
    let s = settings(dir.path());
    let server = start(&s).await;
    let api = Api::new(&server);
    let bundle = stored_profile(&api).await;
    assert!(bundle.len() > 100_000);

    // The disk "fills" 64 KiB into the next upload.
    server.shared.store.inject_storage_full_after(64 << 10);
    let (status, body) = api
        .call(Method::PUT, "/v1/models/tiny", Some(bundle.clone()))
        .await;
    assert_eq!(status, StatusCode::INSUFFICIENT_STORAGE, "{body}");
    let msg = body["error"].as_str().unwrap_or_default().to_string();
    assert!(msg.contains("No space left on device"), "{body}");
    // No version 2, nothing left behind, version 1 still active.
    let model = api.get("/v1/models/tiny").await;
    assert_eq!(model["active"], 1, "{model}");
    assert_eq!(model["versions"].as_array().unwrap().len(), 1, "{model}");
    assert!(tmp_entries(&s.service.data_dir).is_empty());
    // The same connection pool goes on working (the refused body was read).
    let (status, _) = api.call(Method::GET, "/v1/models", None).await;
    assert_eq!(status, StatusCode::OK);

    // Space again: the same upload is version 2.
    server.shared.store.inject_storage_full_after(u64::MAX);
    let (status, v2) = api.call(Method::PUT, "/v1/models/tiny", Some(bundle)).await;
    assert_eq!(status, StatusCode::CREATED, "{v2}");
    assert_eq!(v2["version"], 2, "{v2}");
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_model_swap_while_four_robots_stream_loses_no_frame() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = settings(dir.path());
    // Deep enough that no image is ever dropped for the queue, whatever the machine's
    // speed: a lost frame here can only be the swap's.
    s.service.queue_depth = 1024;
    // The robots send as fast as they can, each a busy worker: admission by load would
    // rightly refuse the third (`service::streaming` tests it), which is not this test.
    s.service.admission_load = 0.0;
    let server = start(&s).await;
    let api = Api::new(&server);
    let bundle = stored_profile(&api).await;
    let (messages, camera) = episode_messages(&episode("test_0001_external_push"));
    let expected = images(&messages);
    let mut robots = Vec::new();
    for r in 0..4 {
        let id = format!("robot-{r}");
        let (tx, task, _) = open_session(server.grpc_addr, "arm-store", &id, camera).await;
        let msgs = messages.clone();
        // Each robot streams its whole episode, a message at a time, while the swap runs.
        let sender = tokio::spawn(async move {
            for chunk in msgs.chunks(8) {
                send_all(&tx, chunk).await;
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
        });
        robots.push((id, sender, task));
    }
    // Swap once every robot has had a few frames scored.
    let deadline = Instant::now() + Duration::from_secs(120);
    loop {
        let listed = api.get("/v1/sessions").await;
        let scored: Vec<u64> = listed["sessions"]
            .as_array()
            .unwrap()
            .iter()
            .map(|s| s["frames_scored"].as_u64().unwrap_or(0))
            .collect();
        if scored.len() == 4 && scored.iter().all(|&n| n >= 3) {
            break;
        }
        assert!(Instant::now() < deadline, "robots too slow: {listed}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
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
    let mut moved = 0;
    for (id, sender, task) in robots {
        sender.await.unwrap();
        let (scores, events, err) = task.await.unwrap();
        assert!(err.is_none(), "{id}: {err:?}");
        use vamos::api::proto::session_event::Kind;
        let dropped: Vec<_> = events
            .iter()
            .filter(|e| e.kind == Kind::FramesDropped as i32 || e.kind == Kind::MessageError as i32)
            .collect();
        assert!(dropped.is_empty(), "{id}: {dropped:?}");
        // Every image scored once, in order, across the swap.
        assert_eq!(scores.len(), expected, "{id}");
        assert!(
            scores.windows(2).all(|w| w[1].index == w[0].index + 1),
            "{id}"
        );
        let reloads = events
            .iter()
            .filter(|e| e.kind == Kind::Reloaded as i32)
            .count();
        // A robot that had finished before the swap reached it was not moved.
        assert!(reloads <= 1, "{id}: {events:?}");
        moved += reloads;
    }
    assert_eq!(
        moved,
        m["reloaded_sessions"].as_array().unwrap().len(),
        "{m}"
    );
    assert!(moved >= 1, "no session was moved: {m}");
    server.shutdown().await.unwrap();
}

/// `vamos serve` as a child process on ephemeral ports, JSON logs on stderr (kept).
pub(crate) struct Process {
    child: Child,
    pub(crate) rest: String,
    pub(crate) grpc: std::net::SocketAddr,
    /// Every log line so far.
    pub(crate) logs: std::sync::Arc<std::sync::Mutex<Vec<String>>>,
}

impl Process {
    pub(crate) fn start(data: &Path) -> Self {
        Self::start_with(data, "info")
    }

    pub(crate) fn start_with(data: &Path, log_level: &str) -> Self {
        Self::start_env(data, log_level, &[])
    }

    /// Started with `env` added to its environment (e.g. `VAMOS_SERVICE__*` settings).
    pub(crate) fn start_env(data: &Path, log_level: &str, env: &[(&str, &str)]) -> Self {
        Self::spawn(
            Command::new(env!("CARGO_BIN_EXE_vamos")),
            data,
            log_level,
            env,
        )
    }

    /// As [`Self::start_env`], under a hard limit of `data_bytes` on its data segment
    /// (`RLIMIT_DATA`, set by util-linux `prlimit`, which then executes the server in its
    /// place: same pid): its heap, private writable mappings and thread stacks. An allocation past it
    /// fails, and in Rust a failed allocation aborts the process: a server that lives
    /// through a test under the limit never needed more.
    pub(crate) fn start_limited(
        data: &Path,
        log_level: &str,
        env: &[(&str, &str)],
        data_bytes: u64,
    ) -> Self {
        let mut cmd = Command::new("prlimit");
        cmd.arg(format!("--data={data_bytes}"))
            .arg("--")
            .arg(env!("CARGO_BIN_EXE_vamos"));
        Self::spawn(cmd, data, log_level, env)
    }

    fn spawn(mut cmd: Command, data: &Path, log_level: &str, env: &[(&str, &str)]) -> Self {
        let mut child = cmd
            .args([
                "serve",
                "--grpc-addr",
                "127.0.0.1:0",
                "--rest-addr",
                "127.0.0.2:0",
            ])
            .arg("--data-dir")
            .arg(data)
            .env("VAMOS_ADMIN_TOKEN", ADMIN)
            .env("VAMOS_ROBOT_TOKEN", ROBOT)
            .env("VAMOS_LOG__FORMAT", "json")
            .env("VAMOS_LOG__LEVEL", log_level)
            .env("VAMOS_SERVICE__WORKERS", "2")
            .envs(env.iter().copied())
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // The bound addresses are in the "vamos serving" line.
        let stderr = child.stderr.take().unwrap();
        let (tx, rx) = std::sync::mpsc::channel();
        let logs = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
        let kept = logs.clone();
        std::thread::spawn(move || {
            let mut sent = false;
            for line in BufReader::new(stderr).lines().map_while(Result::ok) {
                kept.lock().unwrap().push(line.clone());
                if !sent
                    && let Ok(v) = serde_json::from_str::<Value>(&line)
                    && v["message"] == "vamos serving"
                {
                    let addr = |k: &str| v[k].as_str().unwrap_or_default().to_string();
                    let _ = tx.send((addr("rest_addr"), addr("grpc_addr")));
                    sent = true;
                }
            }
        });
        let (rest, grpc) = rx
            .recv_timeout(Duration::from_secs(60))
            .expect("the server did not start");
        Self {
            child,
            rest: format!("http://{rest}"),
            grpc: grpc.parse().expect("the logged gRPC address"),
            logs,
        }
    }

    pub(crate) fn pid(&self) -> u32 {
        self.child.id()
    }

    pub(crate) fn api(&self) -> Api {
        Api::at(self.rest.clone())
    }

    /// SIGKILL: no shutdown code runs.
    pub(crate) fn kill(mut self) {
        self.child.kill().unwrap();
        self.child.wait().unwrap();
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Waits until `cond` holds (polling), or fails with `what`.
async fn wait_until(what: &str, mut cond: impl AsyncFnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(120);
    while !cond().await {
        assert!(Instant::now() < deadline, "timed out: {what}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sigkill_during_a_model_upload_and_a_calibration_keeps_the_store_consistent() {
    let dir = tempfile::tempdir().unwrap();
    let data = dir.path().join("data");
    let server = Process::start(&data);
    let api = server.api();
    let bundle = stored_profile(&api).await;

    // 1. Killed mid-upload: half of version 2 sent, the rest never comes.
    let (tx, rx) = tokio::sync::mpsc::channel::<Result<Vec<u8>, std::io::Error>>(4);
    let body = reqwest::Body::wrap_stream(tokio_stream::wrappers::ReceiverStream::new(rx));
    let url = format!("{}/v1/models/tiny", server.rest);
    let upload = tokio::spawn(async move {
        reqwest::Client::new()
            .put(url)
            .bearer_auth(ADMIN)
            .body(body)
            .send()
            .await
    });
    tx.send(Ok(bundle[..bundle.len() / 2].to_vec()))
        .await
        .unwrap();
    wait_until("the upload reaches the disk", async || {
        tmp_entries(&data).iter().any(|n| n.contains(".part."))
    })
    .await;
    server.kill();
    // The client sees its request fail, not succeed.
    assert!(upload.await.unwrap().is_err());
    drop(tx);
    assert!(
        !tmp_entries(&data).is_empty(),
        "the partial upload is on disk"
    );

    let server = Process::start(&data);
    let api = server.api();
    // The partial file is gone, version 1 is the only one and still active.
    assert!(tmp_entries(&data).is_empty(), "{:?}", tmp_entries(&data));
    let model = api.get("/v1/models/tiny").await;
    assert_eq!(model["active"], 1, "{model}");
    assert_eq!(model["versions"].as_array().unwrap().len(), 1, "{model}");
    let profile = api.get("/v1/profiles/arm-store").await;
    assert!(profile["profile"]["problem"].is_null(), "{profile}");
    // ... and serves: a session on the stored profile gets every frame scored with it.
    let (messages, camera) = episode_messages(&episode("test_0000"));
    let (tx, task, opened) = open_session(server.grpc, "arm-store", "after-kill", camera).await;
    assert!(opened.detail.contains("model tiny@1"), "{}", opened.detail);
    send_all(&tx, &messages[..40]).await;
    drop(tx);
    let (scores, _, err) = task.await.unwrap();
    assert!(err.is_none(), "{err:?}");
    assert_eq!(scores.len(), images(&messages[..40]));

    // 2. Killed during a calibration job over server-side episodes (repeated so that it
    // runs for a while).
    let train = fixture().join("train");
    let episodes: Vec<String> = (0..6)
        .map(|i| {
            train
                .join(format!("train_000{}.mcap", i % 2))
                .display()
                .to_string()
        })
        .collect();
    let (status, started) = api
        .json(
            Method::POST,
            "/v1/profiles/arm-store/calibrate",
            json!({ "episodes": episodes, "alpha": 0.2 }),
        )
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{started}");
    let id = started["job"].as_u64().unwrap();
    let job = api.get(&format!("/v1/jobs/{id}")).await;
    assert_eq!(job["state"], "running", "{job}");
    server.kill();

    let server = Process::start(&data);
    let api = server.api();
    let job = api.get(&format!("/v1/jobs/{id}")).await;
    assert_eq!(job["state"], "failed", "{job}");
    assert!(
        job["error"]
            .as_str()
            .unwrap_or_default()
            .contains("interrupted"),
        "{job}"
    );
    // No calibration was half-written: the profile has none and is usable.
    let profile = api.get("/v1/profiles/arm-store").await;
    assert_eq!(profile["calibrated"], false, "{profile}");
    assert!(profile["profile"]["calibration"].is_null(), "{profile}");
    assert!(profile["profile"]["problem"].is_null(), "{profile}");
    // A new job runs to the end on the restarted server.
    let (status, again) = api
        .json(
            Method::POST,
            "/v1/profiles/arm-store/calibrate",
            json!({ "episodes": [train.join("train_0000.mcap")], "alpha": 0.2 }),
        )
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{again}");
    let done = wait_job(&api, again["job"].as_u64().unwrap()).await;
    assert_eq!(done["state"], "succeeded", "{done}");
    let profile = api.get("/v1/profiles/arm-store").await;
    assert_eq!(profile["calibrated"], true, "{profile}");
    assert!(!profile["profile"]["calibration"].is_null(), "{profile}");
    server.kill();
}
