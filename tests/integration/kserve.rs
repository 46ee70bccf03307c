//! The KServe v2 metadata routes over real HTTP: server metadata, a profile and a stored
//! model as KServe models, one version's metadata and readiness, unknown names and
//! versions, and the robot token on model metadata.

use super::service::ROBOT;
use super::service_admin::{Api, settings, start, stored_profile};
use reqwest::{Client, Method, StatusCode};
use serde_json::{Value, json};

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn kserve_v2_server_and_model_metadata() {
    let dir = tempfile::tempdir().unwrap();
    let server = start(&settings(dir.path())).await;
    let api = Api::new(&server);
    let base = format!("http://{}", server.rest_addr);
    let http = Client::new();

    // Server metadata needs no token.
    let meta: Value = http
        .get(format!("{base}/v2"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(meta["name"], "vamos");
    assert_eq!(meta["version"], env!("CARGO_PKG_VERSION"));
    assert!(meta["extensions"].is_array(), "{meta}");

    // Robot `arm`, model `tiny` version 1, profile `arm-store` on them.
    stored_profile(&api).await;

    // Model metadata needs a robot token.
    let url = format!("{base}/v2/models/tiny");
    let status = http.get(&url).send().await.unwrap().status();
    assert_eq!(status, StatusCode::UNAUTHORIZED);
    let resp = http.get(&url).bearer_auth(ROBOT).send().await.unwrap();
    assert_eq!(resp.status(), StatusCode::OK);
    let model: Value = resp.json().await.unwrap();
    assert_eq!(model["name"], "tiny");
    assert_eq!(model["platform"], "vamos_bundle");
    assert_eq!(model["versions"], json!(["1"]));
    let flow = &model["inputs"][0];
    assert_eq!(flow["name"], "flow");
    assert_eq!(flow["datatype"], "FP32");
    // The network input of the bundle's manifest: [batch, channels, size, size].
    let shape: Vec<i64> = serde_json::from_value(flow["shape"].clone()).unwrap();
    assert_eq!(shape.len(), 4, "{model}");
    assert_eq!(shape[0], -1);
    assert_eq!(shape[1], 2, "{model}");
    assert!(shape[2] > 0 && shape[2] == shape[3], "{model}");
    assert_eq!(model["outputs"][0]["name"], "e_o");

    // A second upload is version 2; each version has its metadata and readiness.
    let bundle = std::fs::read(super::service_admin::model_fixture("tiny_trained.vamos")).unwrap();
    let (status, v2) = api.call(Method::PUT, "/v1/models/tiny", Some(bundle)).await;
    assert_eq!(status, StatusCode::CREATED, "{v2}");
    let model = api.get("/v2/models/tiny").await;
    assert_eq!(model["versions"], json!(["1", "2"]));
    let one = api.get("/v2/models/tiny/versions/1").await;
    assert_eq!(one["versions"], json!(["1"]));
    assert_eq!(one["inputs"], model["inputs"]);
    for (version, expected) in [
        ("1", StatusCode::OK),
        ("2", StatusCode::OK),
        ("3", StatusCode::NOT_FOUND),
        ("x", StatusCode::NOT_FOUND),
    ] {
        let resp = http
            .get(format!("{base}/v2/models/tiny/versions/{version}/ready"))
            .send()
            .await
            .unwrap();
        assert_eq!(resp.status(), expected, "version {version}");
        let body: Value = resp.json().await.unwrap();
        assert_eq!(body["ready"], expected == StatusCode::OK, "{body}");
        let (status, _) = api
            .call(
                Method::GET,
                &format!("/v2/models/tiny/versions/{version}"),
                None,
            )
            .await;
        assert_eq!(status, expected, "metadata of version {version}");
    }
    // A deleted version (2: not the active one) is neither described nor ready.
    let (status, e) = api
        .call(Method::DELETE, "/v1/models/tiny/versions/2", None)
        .await;
    assert_eq!(status, StatusCode::NO_CONTENT, "{e}");
    assert_eq!(api.get("/v2/models/tiny").await["versions"], json!(["1"]));
    let status = http
        .get(format!("{base}/v2/models/tiny/versions/2/ready"))
        .send()
        .await
        .unwrap()
        .status();
    assert_eq!(status, StatusCode::NOT_FOUND);

    // The profile is a model without versions: what a robot sends and gets back.
    let profile = api.get("/v2/models/arm-store").await;
    assert_eq!(profile["platform"], "vamos_profile");
    assert_eq!(profile["versions"], json!([]));
    let names = |key: &str| -> Vec<String> {
        profile[key]
            .as_array()
            .unwrap()
            .iter()
            .map(|t| t["name"].as_str().unwrap().to_string())
            .collect()
    };
    assert_eq!(names("inputs"), ["image", "joint_positions"]);
    assert_eq!(names("outputs"), ["score", "alarm"]);
    // A profile has no versions to ask about.
    let (status, _) = api
        .call(Method::GET, "/v2/models/arm-store/versions/1", None)
        .await;
    assert_eq!(status, StatusCode::NOT_FOUND);

    // Readiness answers for the names metadata describes, and only those (a model label
    // such as `tiny@1` is not a KServe model name).
    for (name, expected) in [
        ("arm-store", StatusCode::OK),
        ("tiny", StatusCode::OK),
        ("tiny@1", StatusCode::NOT_FOUND),
        ("nothing", StatusCode::NOT_FOUND),
    ] {
        let ready = http
            .get(format!("{base}/v2/models/{name}/ready"))
            .send()
            .await
            .unwrap();
        assert_eq!(ready.status(), expected, "{name} ready");
        let (status, _) = api
            .call(Method::GET, &format!("/v2/models/{name}"), None)
            .await;
        assert_eq!(status, expected, "{name} metadata");
    }

    // Unknown names are 404 with an error message.
    let (status, e) = api.call(Method::GET, "/v2/models/nothing", None).await;
    assert_eq!(status, StatusCode::NOT_FOUND);
    assert!(e["error"].as_str().unwrap().contains("nothing"), "{e}");
    server.shutdown().await.unwrap();
}
