//! A fleet sharing one store: a writer and two readers on a shared folder (`file://`),
//! each a real server. What the writer is given reaches the readers without a restart and
//! serves their sessions; readers refuse changes; a deletion reaches them; a writer that
//! replaces the old one with an empty data directory starts from the fleet's state.

use super::service::{episode, episode_messages};
use super::service_admin::{Api, open_session, send_all, settings, start, stored_profile};
use reqwest::{Method, StatusCode};
use serde_json::Value;
use std::time::{Duration, Instant};
use vamos::config::Settings;
use vamos::service::{FleetRole, RunningServer, SharedStoreConfig};

fn fleet_settings(
    dir: &std::path::Path,
    name: &str,
    shared: &std::path::Path,
    role: FleetRole,
) -> Settings {
    let mut s = settings(&dir.join(name));
    s.service.shared_store = Some(SharedStoreConfig {
        url: url_of(shared),
        role,
        poll_s: 0.1,
    });
    s
}

fn url_of(dir: &std::path::Path) -> String {
    format!("file://{}", dir.display())
}

/// Polls `GET path` on `api` until `done` holds.
async fn wait_for(api: &Api, path: &str, done: impl Fn(&Value) -> bool) -> Value {
    let deadline = Instant::now() + Duration::from_secs(30);
    loop {
        let (status, v) = api.call(Method::GET, path, None).await;
        if status == StatusCode::OK && done(&v) {
            return v;
        }
        if Instant::now() >= deadline {
            // The replica's view of the shared store says why (its last error).
            let store = api.call(Method::GET, "/v1/store", None).await.1;
            panic!("GET {path} never got there: {status} {v}\nGET /v1/store: {store}");
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
}

fn names(list: &Value, key: &str) -> Vec<String> {
    list[key]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["name"].as_str().unwrap().to_string())
        .collect()
}

/// Replaces a file as the writer does (a rename), so a reader never reads half of it.
fn replace_file(path: &std::path::Path, bytes: &[u8]) {
    let part = path.with_extension("part");
    std::fs::write(&part, bytes).unwrap();
    std::fs::rename(&part, path).unwrap();
}

/// The value of an unlabelled metric in the server's `/metrics`.
async fn metric(server: &RunningServer, name: &str) -> f64 {
    let text = super::service::metrics_text(server.rest_addr).await;
    let prefix = format!("{name} ");
    text.lines()
        .find_map(|l| l.strip_prefix(prefix.as_str()))
        .unwrap_or_else(|| panic!("{name} missing: {text}"))
        .parse()
        .unwrap()
}

async fn scores_with(server: &RunningServer, profile: &str, id: &str) -> usize {
    let (messages, camera) = episode_messages(&episode("test_0000"));
    let (tx, task, opened) = open_session(server.grpc_addr, profile, id, camera).await;
    assert!(opened.detail.contains("model tiny@"), "{}", opened.detail);
    send_all(&tx, &messages[..messages.len().min(40)]).await;
    drop(tx);
    let (scores, _, status) = task.await.unwrap();
    assert!(status.is_none(), "{status:?}");
    scores.len()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn replicas_share_models_robots_and_profiles_without_a_restart() {
    let dir = tempfile::tempdir().unwrap();
    let shared = dir.path().join("shared");
    let writer = start(&fleet_settings(dir.path(), "w", &shared, FleetRole::Writer)).await;
    let reader_a = start(&fleet_settings(dir.path(), "a", &shared, FleetRole::Reader)).await;
    let (w, a) = (Api::new(&writer), Api::new(&reader_a));
    let status = a.get("/v1/store").await;
    assert_eq!(status["shared_store"]["role"], "reader", "{status}");
    assert!(
        status["read_only"].as_str().unwrap().contains("writer"),
        "{status}"
    );

    // The writer takes a robot, a model and a profile; the reader serves them soon after.
    stored_profile(&w).await;
    let profiles = wait_for(&a, "/v1/profiles", |v| {
        names(v, "profiles").contains(&"arm-store".to_string())
    })
    .await;
    assert_eq!(names(&profiles, "profiles"), ["arm-store"]);
    assert_eq!(names(&a.get("/v1/robots").await, "robots"), ["arm"]);
    let model = a.get("/v1/models/tiny").await;
    assert_eq!(model["active"], 1, "{model}");
    assert!(scores_with(&reader_a, "arm-store", "on-a").await > 0);
    let st = a.get("/v1/store").await;
    assert!(
        st["shared_store"]["generation"].as_u64().unwrap() >= 1,
        "{st}"
    );
    assert_eq!(st["shared_store"]["last_error"], Value::Null, "{st}");

    // A replica started later catches up at start: ready means it has the fleet's state.
    let reader_b = start(&fleet_settings(dir.path(), "b", &shared, FleetRole::Reader)).await;
    let b = Api::new(&reader_b);
    assert_eq!(
        names(&b.get("/v1/profiles").await, "profiles"),
        ["arm-store"]
    );
    assert!(scores_with(&reader_b, "arm-store", "on-b").await > 0);

    // Readers refuse changes and say where they go; nothing changes.
    let urdf = std::fs::read(super::service::fixture().join("robot/vamos_arm.urdf")).unwrap();
    let (status, e) = b
        .call(Method::PUT, "/v1/robots/other?format=urdf", Some(urdf))
        .await;
    assert_eq!(status, StatusCode::CONFLICT, "{e}");
    assert!(
        e["error"].as_str().unwrap().contains("writer replica"),
        "{e}"
    );
    let (status, e) = b.call(Method::DELETE, "/v1/profiles/arm-store", None).await;
    assert_eq!(status, StatusCode::CONFLICT, "{e}");
    assert_eq!(names(&b.get("/v1/robots").await, "robots"), ["arm"]);

    // A new model version made active on the writer reaches new sessions on the readers.
    let bundle = std::fs::read(super::service_admin::model_fixture("tiny_trained.vamos")).unwrap();
    let (status, v2) = w.call(Method::PUT, "/v1/models/tiny", Some(bundle)).await;
    assert_eq!(status, StatusCode::CREATED, "{v2}");
    let (status, m) = w
        .json(
            Method::POST,
            "/v1/models/tiny/active",
            serde_json::json!({ "version": 2 }),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{m}");
    for api in [&a, &b] {
        wait_for(api, "/v1/models/tiny", |v| v["active"] == 2).await;
    }
    let (messages, camera) = episode_messages(&episode("test_0000"));
    let (tx, task, opened) = open_session(reader_a.grpc_addr, "arm-store", "v2", camera).await;
    assert!(opened.detail.contains("model tiny@2"), "{}", opened.detail);
    send_all(&tx, &messages[..20]).await;
    drop(tx);
    assert!(task.await.unwrap().2.is_none());

    // A deletion reaches them too.
    let (status, e) = w.call(Method::DELETE, "/v1/profiles/arm-store", None).await;
    assert!(status.is_success(), "{status} {e}");
    for api in [&a, &b] {
        wait_for(api, "/v1/profiles", |v| names(v, "profiles").is_empty()).await;
    }
    assert!(!dir.path().join("a/data/profiles/arm-store").exists());

    // The metrics say which generation each replica has.
    assert!(metric(&reader_b, "vamos_shared_store_generation").await >= 3.0);

    // The writer is replaced by one with an empty data directory: it starts from the
    // fleet's state and carries on publishing.
    writer.shutdown().await.unwrap();
    let writer2 = start(&fleet_settings(
        dir.path(),
        "w2",
        &shared,
        FleetRole::Writer,
    ))
    .await;
    let w2 = Api::new(&writer2);
    assert_eq!(names(&w2.get("/v1/robots").await, "robots"), ["arm"]);
    assert_eq!(w2.get("/v1/models/tiny").await["active"], 2);
    let (status, e) = w2
        .call(Method::DELETE, "/v1/models/tiny/versions/1", None)
        .await;
    assert!(status.is_success(), "{status} {e}");
    wait_for(&a, "/v1/models/tiny", |v| {
        v["versions"].as_array().unwrap().len() == 1
    })
    .await;
    // Blobs no publication names are collected.
    let blobs = std::fs::read_dir(shared.join("blobs")).unwrap().count();
    let manifest: Value =
        serde_json::from_slice(&std::fs::read(shared.join("manifest.json")).unwrap()).unwrap();
    assert_eq!(blobs, {
        let mut shas: Vec<&str> = manifest["files"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| f["sha256"].as_str().unwrap())
            .collect();
        shas.sort_unstable();
        shas.dedup();
        shas.len()
    });

    for s in [writer2, reader_a, reader_b] {
        s.shutdown().await.unwrap();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_damaged_publication_is_refused_and_the_reader_keeps_serving() {
    let dir = tempfile::tempdir().unwrap();
    let shared = dir.path().join("shared");
    let writer = start(&fleet_settings(dir.path(), "w", &shared, FleetRole::Writer)).await;
    let reader = start(&fleet_settings(dir.path(), "r", &shared, FleetRole::Reader)).await;
    let (w, r) = (Api::new(&writer), Api::new(&reader));
    stored_profile(&w).await;
    wait_for(&r, "/v1/profiles", |v| !names(v, "profiles").is_empty()).await;
    writer.shutdown().await.unwrap();

    // A manifest naming a path outside the data directory, then one whose blob does not
    // match: each is refused, reported, and the reader's copy stays as it was.
    let manifest_path = shared.join("manifest.json");
    let good: Value = serde_json::from_slice(&std::fs::read(&manifest_path).unwrap()).unwrap();
    let mut escape = good.clone();
    escape["generation"] = (good["generation"].as_u64().unwrap() + 1).into();
    escape["files"][0]["path"] = "../../outside".into();
    replace_file(&manifest_path, &serde_json::to_vec(&escape).unwrap());
    wait_for(&r, "/v1/store", |v| {
        v["shared_store"]["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("not a data directory file"))
    })
    .await;
    assert!(!dir.path().join("outside").exists());

    let mut tampered = good.clone();
    tampered["generation"] = (good["generation"].as_u64().unwrap() + 2).into();
    let target = tampered["files"]
        .as_array()
        .unwrap()
        .iter()
        .position(|f| f["path"] == "profiles/arm-store/profile.json")
        .unwrap();
    let sha = tampered["files"][target]["sha256"]
        .as_str()
        .unwrap()
        .to_string();
    let blob = shared.join("blobs").join(&sha);
    let mut bytes = std::fs::read(&blob).unwrap();
    bytes[10] ^= 1;
    // The changed content, listed under a new name so the reader must fetch it.
    let fake = "0".repeat(64);
    std::fs::write(shared.join("blobs").join(&fake), &bytes).unwrap();
    tampered["files"][target]["sha256"] = fake.into();
    replace_file(&manifest_path, &serde_json::to_vec(&tampered).unwrap());
    let st = wait_for(&r, "/v1/store", |v| {
        v["shared_store"]["last_error"]
            .as_str()
            .is_some_and(|e| e.contains("does not match"))
    })
    .await;
    assert!(
        st["shared_store"]["generation"].as_u64().unwrap()
            < tampered["generation"].as_u64().unwrap()
    );
    assert_eq!(
        names(&r.get("/v1/profiles").await, "profiles"),
        ["arm-store"]
    );
    assert!(scores_with(&reader, "arm-store", "still").await > 0);
    assert!(metric(&reader, "vamos_shared_store_errors_total").await >= 2.0);
    reader.shutdown().await.unwrap();
}
