//! The deployment files (`deploy/`) against the real server: every metric a Grafana panel
//! or an alert rule queries exists in a live server's `/metrics`, and the ports, probe
//! paths, gRPC health service and settings the Dockerfile, compose file, Helm chart and
//! systemd unit use are the ones the server has. (`promtool check` validates the
//! Prometheus files' syntax in `.ci/run`; the chart is not rendered here: no `helm`.)

use super::service::{episode, fixture, fixture_setup};
use std::collections::BTreeSet;
use std::path::PathBuf;
use vamos::api::proto;
use vamos::api::rest::{Access, ROUTES};
use vamos::client::replay::record;
use vamos::client::{Client, ClientOptions, Pace};
use vamos::config::Settings;
use vamos::setup::Setup;

fn deploy(rel: &str) -> String {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("deploy")
        .join(rel);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// The metric names (`vamos_*`, `process_*`) a text mentions.
fn metric_names(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    for prefix in ["vamos_", "process_"] {
        let mut rest = text;
        while let Some(i) = rest.find(prefix) {
            let before = rest[..i].chars().next_back();
            let tail = &rest[i..];
            let end = tail
                .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
                .unwrap_or(tail.len());
            if !before.is_some_and(|c| c.is_ascii_alphanumeric() || c == '_') {
                out.insert(tail[..end].to_string());
            }
            rest = &tail[end..];
        }
    }
    out
}

/// The series names of an exposition (histograms also as `_bucket`, `_sum`, `_count`).
fn exposed(text: &str) -> BTreeSet<String> {
    text.lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .filter_map(|l| l.split(['{', ' ']).next())
        .map(str::to_string)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn dashboards_and_alerts_query_metrics_the_server_exposes() {
    // A profile with the tiny model and an alarm threshold every frame crosses, so the
    // model, anomaly and per-profile series all appear.
    let mut f = fixture_setup(8, false);
    let dir = tempfile::tempdir().unwrap();
    let model =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model/tiny_trained.vamos");
    let profile = dir.path().join("with-model.toml");
    std::fs::write(
        &profile,
        format!(
            "name = \"with-model\"\nrobot = \"{}\"\ncamera = \"{}\"\nmodel = \"{}\"\nflow_preset = \"realtime\"\n\
             [thresholds]\nalarm = -1.0\n[pipeline]\nstride = 1\n[pipeline.frames]\nwidth = 160\nheight = 120\nvariant = \"masked\"\n",
            fixture().join("robot/vamos_arm.urdf").display(),
            fixture().join("camera.json").display(),
            model.display()
        ),
    )
    .unwrap();
    let setup = Setup::load(&f.settings, &profile).unwrap();
    f.settings.service.queue_depth = 2;
    let catalog = vamos::session::ProfileCatalog::from_setups(vec![f.setup.clone(), setup]);
    let server = vamos::service::Server::start(f.settings.clone(), catalog)
        .await
        .unwrap();
    let client = Client::connect(
        &format!("http://{}", server.grpc_addr),
        ClientOptions::default(),
    )
    .await
    .unwrap();
    let mut rec = record(&episode("test_0000"), &Default::default()).unwrap();
    // A broken image among the messages: a message error and a refused-image drop.
    let bad = rec
        .messages
        .iter()
        .position(|(_, m)| matches!(m, proto::stream_request::Message::Image(_)))
        .unwrap();
    if let (_, proto::stream_request::Message::Image(img)) = &mut rec.messages[bad] {
        img.data.truncate(3);
    }
    let open = proto::OpenSession {
        robot_id: "deploy-test".into(),
        profile: "with-model".into(),
        camera_info: rec.camera,
        task: String::new(),
        session_id: String::new(),
        anomaly_maps: false,
        image_rate_hz: 0.0,
    };
    let summary = client
        .replay(open, &rec, Pace::Window(2), |_| {})
        .await
        .unwrap();
    assert!(summary.scores.iter().any(|s| s.anomaly));
    assert!(!summary.message_errors.is_empty());
    // An HTTP request with a request id before the scrape, so the HTTP request series
    // exist; the id comes back, and one is made when none is sent.
    let http = reqwest::Client::new();
    let healthz = format!("http://{}/healthz", server.rest_addr);
    let resp = http
        .get(&healthz)
        .header("x-request-id", "deploy-test-1")
        .send()
        .await
        .unwrap();
    assert_eq!(resp.headers()["x-request-id"], "deploy-test-1");
    let resp = http.get(&healthz).send().await.unwrap();
    assert_eq!(resp.headers()["x-request-id"].len(), 32);
    let text = super::service::metrics_text(server.rest_addr).await;
    let have = exposed(&text);
    // Request metrics of both transports, with their labels.
    assert!(
        text.contains(r#"vamos_http_requests_total{method="GET",route="/healthz",status="200"} 2"#),
        "{text}"
    );
    assert!(
        text.contains(
            r#"vamos_grpc_requests_total{code="Ok",method="/vamos.v1.Monitor/Stream"} 1"#
        ),
        "{text}"
    );

    for (file, text) in [
        (
            "grafana/dashboards/vamos.json",
            deploy("grafana/dashboards/vamos.json"),
        ),
        ("prometheus/alerts.yml", deploy("prometheus/alerts.yml")),
    ] {
        let wanted = metric_names(&text);
        assert!(wanted.len() >= 5, "{file}: {wanted:?}");
        let missing: Vec<_> = wanted.iter().filter(|m| !have.contains(*m)).collect();
        assert!(
            missing.is_empty(),
            "{file} queries {missing:?}, not in /metrics:\n{text}"
        );
    }
    // The dashboard is valid JSON with one query per target.
    let dash: serde_json::Value =
        serde_json::from_str(&deploy("grafana/dashboards/vamos.json")).unwrap();
    assert!(dash["panels"].as_array().unwrap().len() >= 10);
    // Fleet variables: every query reads the chosen data source and instances.
    let vars: Vec<&str> = dash["templating"]["list"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["name"].as_str().unwrap())
        .collect();
    assert_eq!(vars, ["datasource", "instance", "profile"]);
    for panel in dash["panels"].as_array().unwrap() {
        for target in panel["targets"].as_array().unwrap() {
            assert_eq!(target["datasource"]["uid"], "${datasource}", "{panel}");
            let expr = target["expr"].as_str().unwrap();
            assert!(expr.contains(r#"instance=~"$instance""#), "{expr}");
        }
    }
    server.shutdown().await.unwrap();
}

#[test]
fn ports_probes_and_settings_of_the_deployment_files_are_the_servers() {
    let defaults = Settings::default().service;
    let grpc_port = defaults.grpc_addr.rsplit(':').next().unwrap().to_string();
    let http_port = defaults.rest_addr.rsplit(':').next().unwrap().to_string();
    assert_eq!((grpc_port.as_str(), http_port.as_str()), ("8081", "8080"));

    // Probe paths are open routes.
    let open: Vec<&str> = ROUTES
        .iter()
        .filter(|r| r.0 == "GET" && r.2 == Access::Open)
        .map(|r| r.1)
        .collect();
    let deployment = deploy("helm/vamos/templates/deployment.yaml");
    for path in ["/healthz", "/readyz"] {
        assert!(open.contains(&path));
        assert!(deployment.contains(&format!("path: {path}")), "{path}");
    }
    assert!(deployment.contains("service: vamos.v1.Monitor"));
    let monitor = deploy("helm/vamos/templates/servicemonitor.yaml");
    assert!(monitor.contains("path: /metrics") && open.contains(&"/metrics"));
    // The gRPC service the probes ask about is the one the proto declares.
    let proto_text = std::fs::read_to_string(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("proto/vamos/v1/monitor.proto"),
    )
    .unwrap();
    assert!(proto_text.contains("package vamos.v1;") && proto_text.contains("service Monitor"));

    let values = deploy("helm/vamos/values.yaml");
    assert!(values.contains(&format!("grpc: {grpc_port}")));
    assert!(values.contains(&format!("http: {http_port}")));
    let dockerfile = deploy("docker/Dockerfile");
    assert!(dockerfile.contains(&format!("EXPOSE {http_port} {grpc_port}")));
    assert!(dockerfile.contains(&format!(
        "\"vamos\", \"health\", \"--server\", \"http://127.0.0.1:{grpc_port}\""
    )));
    assert!(deploy("prometheus/prometheus.yml").contains(&format!("vamos:{http_port}")));
    let compose = deploy("compose.yaml");
    assert!(compose.contains(&format!("\"{http_port}:{http_port}\"")));
    assert!(compose.contains(&format!("\"{grpc_port}:{grpc_port}\"")));

    // Every VAMOS_* setting the files set is a real one: `vamos config` with them set
    // shows their values.
    let mut vars = BTreeSet::new();
    for text in [&dockerfile, &deployment] {
        for part in text.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_')) {
            if part.starts_with("VAMOS_") && part.contains("__") {
                vars.insert(part.to_string());
            }
        }
    }
    assert!(vars.len() >= 4, "{vars:?}");
    let mut cmd = std::process::Command::new(env!("CARGO_BIN_EXE_vamos"));
    cmd.arg("config");
    for v in &vars {
        let value = match v.as_str() {
            "VAMOS_SERVICE__GRPC_ADDR" => "0.0.0.0:8081",
            "VAMOS_SERVICE__REST_ADDR" => "0.0.0.0:8080",
            "VAMOS_SERVICE__DATA_DIR" => "/var/lib/vamos",
            "VAMOS_MODEL__ORT_PROVISION" => "false",
            "VAMOS_LOG__FORMAT" => "json",
            "VAMOS_SERVICE__ALLOW_UNAUTHENTICATED_REMOTE" => "true",
            "VAMOS_SERVICE__SHARED_STORE__URL" => "s3://fleet/vamos",
            "VAMOS_SERVICE__SHARED_STORE__ROLE" => "writer",
            "VAMOS_SERVICE__SHARED_STORE__POLL_S" => "2",
            other => panic!("add the test value of {other}"),
        };
        cmd.env(v, value);
    }
    let out = cmd.output().unwrap();
    assert!(out.status.success(), "{out:?}");
    let effective = String::from_utf8_lossy(&out.stdout);
    for (line, var) in [
        ("grpc_addr = \"0.0.0.0:8081\"", "VAMOS_SERVICE__GRPC_ADDR"),
        ("rest_addr = \"0.0.0.0:8080\"", "VAMOS_SERVICE__REST_ADDR"),
        ("data_dir = \"/var/lib/vamos\"", "VAMOS_SERVICE__DATA_DIR"),
        ("ort_provision = false", "VAMOS_MODEL__ORT_PROVISION"),
        ("format = \"json\"", "VAMOS_LOG__FORMAT"),
        (
            "allow_unauthenticated_remote = true",
            "VAMOS_SERVICE__ALLOW_UNAUTHENTICATED_REMOTE",
        ),
        (
            "url = \"s3://fleet/vamos\"",
            "VAMOS_SERVICE__SHARED_STORE__URL",
        ),
        ("role = \"writer\"", "VAMOS_SERVICE__SHARED_STORE__ROLE"),
        ("poll_s = 2.0", "VAMOS_SERVICE__SHARED_STORE__POLL_S"),
    ] {
        if vars.contains(var) {
            assert!(effective.contains(line), "{var}: {effective}");
        }
    }
}
