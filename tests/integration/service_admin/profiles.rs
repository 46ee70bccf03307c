//! Stored profiles serve sessions, swap models and survive a restart; a running session moves to a new model version.

use super::*;

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
