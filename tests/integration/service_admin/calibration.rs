//! Calibration jobs from uploaded episodes; false alarms join the nominal set and a recalibration clears them.

use super::*;

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
    // The second as rosbag2 compresses a file (`.mcap.zstd`): decompressed on arrival,
    // charged to the upload, named after its stem like the others.
    let compressed = {
        let bytes = std::fs::read(fixture().join("train").join("train_0001.mcap")).unwrap();
        reqwest::multipart::Part::bytes(zstd::encode_all(bytes.as_slice(), 3).unwrap())
            .file_name("train_0001.mcap.zstd")
            .mime_str("application/zstd")
            .unwrap()
    };
    let form = reqwest::multipart::Form::new()
        .part("episodes", part("train_0000.mcap"))
        .part("episodes", compressed)
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

/// The alarm of session `session` among the recent alarms.
async fn alarm_of(api: &Api, session: &str) -> Value {
    let alarms = api.get("/v1/alarms").await;
    alarms["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["session_id"] == session)
        .unwrap_or_else(|| panic!("no alarm of the run: {alarms}"))
        .clone()
}

/// Profile `profile`'s nominal set once its first episode's recording has finished.
async fn finished_nominal(api: &Api, profile: &str) -> Value {
    let deadline = std::time::Instant::now() + Duration::from_secs(30);
    loop {
        let n = api.get(&format!("/v1/profiles/{profile}/nominal")).await;
        if n["episodes"][0]["finished"] == true {
            return n;
        }
        assert!(std::time::Instant::now() < deadline, "{n}");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
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
    let alarm = alarm_of(&api, "pushed").await;
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
    let nominal = finished_nominal(&api, "arm-store").await;
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

/// A profile file is calibrated and recalibrated like a stored profile: the calibration
/// lives in the data directory (the file's folder is not written), is in force after a
/// restart, and gives way when the file's own calibration changes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_profile_file_is_calibrated_and_recalibrated_in_the_data_directory() {
    use crate::service::{fixture_setup, start as start_file};
    let f = fixture_setup(4, true);
    let server = start_file(&f).await;
    let api = Api::new(&server);
    let path = "/v1/profiles/sim-arm";
    let p = api.get(path).await;
    assert_eq!(
        (&p["source"], &p["calibrated"]),
        (&json!("file"), &json!(false))
    );
    assert!(p.get("calibration_source").is_none(), "{p}");

    let train = fixture().join("train");
    let (status, job) = api
        .json(
            Method::POST,
            &format!("{path}/calibrate"),
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
    let p = api.get(path).await;
    assert_eq!(p["calibration_source"], "store", "{p}");
    let threshold = p["alarm_threshold"].as_f64().unwrap();
    let profile_file = &f.setup.profile.path;
    let beside = vamos::pipeline::Profile::calibration_path_for(profile_file);
    assert!(!beside.exists(), "the profile file's folder is not written");
    let kept = f
        .settings
        .service
        .data_dir
        .join("file-calibrations/sim-arm.json");
    assert!(kept.is_file());

    // A run that alarms, marked as a false alarm, recalibrated and applied.
    let (messages, camera) = episode_messages(&episode("test_0001_external_push"));
    let addr = server.grpc_addr;
    let run = |session: &'static str| {
        let messages = messages.clone();
        async move {
            let (tx, task, _) = open_session(addr, "sim-arm", session, camera).await;
            send_all(&tx, &messages).await;
            drop(tx);
            let (scores, _, error) = task.await.unwrap();
            assert!(error.is_none(), "{error:?}");
            scores
        }
    };
    assert!(
        run("pushed").await.iter().any(|s| s.anomaly),
        "the run alarms"
    );
    let alarm = alarm_of(&api, "pushed").await;
    let id = alarm["id"].as_str().unwrap();
    let (status, marked) = api
        .json(
            Method::POST,
            &format!("/v1/alarms/{id}/false-alarm"),
            json!({}),
        )
        .await;
    assert_eq!(status, StatusCode::OK, "{marked}");
    finished_nominal(&api, "sim-arm").await;
    let (status, started) = api
        .call(Method::POST, &format!("{path}/recalibrate"), None)
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{started}");
    let job_id = started["job"].as_u64().unwrap();
    let job = wait_job(&api, job_id).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    assert_eq!(job["proposal"]["current"]["alarm"], threshold, "{job}");
    let proposed = job["proposal"]["proposed"]["alarm"].as_f64().unwrap();
    assert!(proposed > threshold, "{job}");
    let (status, applied) = api
        .call(Method::POST, &format!("/v1/jobs/{job_id}/apply"), None)
        .await;
    assert_eq!(status, StatusCode::OK, "{applied}");
    assert_eq!(
        api.get(path).await["alarm_threshold"].as_f64(),
        Some(proposed)
    );
    assert!(
        run("again").await.iter().all(|s| !s.anomaly),
        "no alarm after it"
    );
    assert!(!beside.exists());

    // A restart keeps it in force.
    server.shutdown().await.unwrap();
    let server = start_file(&f).await;
    let api = Api::new(&server);
    let p = api.get(path).await;
    assert_eq!(p["calibration_source"], "store", "{p}");
    assert_eq!(p["alarm_threshold"].as_f64(), Some(proposed));
    server.shutdown().await.unwrap();

    // The file gets its own calibration (made elsewhere): the file's is in force again.
    let mut own = job["calibration"].clone();
    own["created_unix_s"] = json!(12345);
    std::fs::write(&beside, own.to_string()).unwrap();
    let setup = vamos::setup::Setup::load(&f.settings, profile_file).unwrap();
    let server = Server::start(f.settings.clone(), ProfileCatalog::from_setups(vec![setup]))
        .await
        .unwrap();
    let p = Api::new(&server).get(path).await;
    assert_eq!(p["calibration_source"], "file", "{p}");
    server.shutdown().await.unwrap();
}

/// A calibration job's decoding is charged to the server's memory budget: while the budget
/// is spent, its frames wait for room and, after the wait, are left out, which the job's
/// notes say; once there is room again the job goes on and succeeds.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_calibration_job_decodes_within_the_memory_budget() {
    let dir = tempfile::tempdir().unwrap();
    let mut settings = settings(dir.path());
    settings.service.memory_budget_mb = 64;
    let server = start(&settings).await;
    let api = Api::new(&server);
    stored_profile(&api).await;
    // Something else holds the whole budget.
    let budget = server.shared.hub.budget().clone();
    let held = budget.charge(budget.limit()).unwrap();
    let train = fixture().join("train");
    let (status, job) = api
        .json(
            Method::POST,
            "/v1/profiles/arm-store/calibrate",
            json!({ "episodes": [train.join("train_0000.mcap"), train.join("train_0001.mcap")] }),
        )
        .await;
    assert_eq!(status, StatusCode::ACCEPTED, "{job}");
    let id = job["job"].as_u64().unwrap();
    // The first frame waits for room (10 s) and is then left out.
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(api.get(&format!("/v1/jobs/{id}")).await["state"], "running");
    tokio::time::sleep(Duration::from_secs(9)).await;
    drop(held);
    let job = wait_job(&api, id).await;
    assert_eq!(job["state"], "succeeded", "{job}");
    let notes = job["notes"].to_string();
    assert!(
        notes.contains("train_0000: 1 frame(s) left out") && notes.contains("memory_budget_mb"),
        "{job}"
    );
    assert_eq!(budget.used(), 0, "every charge given back");
    server.shutdown().await.unwrap();
}
