//! Streamed sessions score as offline scoring does, several robots at once, and back-pressure says what it drops.

use super::*;

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
        // The frame after a gap starts the motion history afresh: it says how many images
        // were lost before it and has no motion score, so a gap never raises an alarm.
        let resumed: Vec<_> = scores.iter().filter(|s| s.frames_lost > 0).collect();
        assert!(!resumed.is_empty(), "{policy:?}");
        for s in &resumed {
            assert!(
                s.warming_up && !s.anomaly && s.score == 0.0,
                "{policy:?}: {s:?}"
            );
            assert!(s.e_c.is_none() && s.e_r.is_none(), "{policy:?}: {s:?}");
        }
        let lost: u64 = scores.iter().map(|s| s.frames_lost).sum();
        match policy {
            // Every dropped image is older than a queued one, which reports it.
            vamos::service::QueuePolicy::DropOldest => assert_eq!(lost, dropped),
            // The last rejected images may have no successor to report them.
            vamos::service::QueuePolicy::Reject => assert!(lost <= dropped && lost > 0),
        }
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

/// A streamed depth image is used for the frame's successor (at the profile's assumed
/// depth it changes nothing, at another it does); one that cannot be used is reported and
/// its image is still scored.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn streamed_depth_images_are_used_and_bad_ones_reported_without_losing_frames() {
    let f = fixture_setup(8, false);
    let server = start(&f).await;
    let name = "test_0001_external_push";
    let (messages, camera) = episode_messages(&episode(name));
    let assumed_m = f.setup.config.camera_motion.assumed_depth_m as f32;
    // 32FC1 at half the image's resolution (the same aspect ratio), one value everywhere.
    let with_depth = |metres: f32, bad: &dyn Fn(usize) -> Option<proto::DepthImage>| {
        let mut images = 0;
        messages
            .iter()
            .cloned()
            .map(|m| match m {
                In::Image(mut img) => {
                    images += 1;
                    img.depth = bad(images).or_else(|| {
                        Some(proto::DepthImage {
                            encoding: "32FC1".into(),
                            width: img.width / 2,
                            height: img.height / 2,
                            step: 0,
                            big_endian: false,
                            data: metres
                                .to_le_bytes()
                                .repeat((img.width * img.height / 4) as usize),
                        })
                    });
                    In::Image(img)
                }
                other => other,
            })
            .collect::<Vec<_>>()
    };
    let offline = offline(&f.setup, &episode(name));

    // At the assumed depth: the same scores as without depth, no message errors.
    let (scores, events) = stream_all(
        server.grpc_addr,
        None,
        open_msg("sim-arm", "depth-assumed", camera),
        with_depth(assumed_m, &|_| None),
    )
    .await
    .unwrap();
    assert_same_scores(&scores, &offline);
    assert!(
        !events
            .iter()
            .any(|e| e.kind == proto::session_event::Kind::MessageError as i32),
        "{events:?}"
    );

    // Nearer than assumed: the head camera's small translation now moves the scene more.
    let (scores, _) = stream_all(
        server.grpc_addr,
        None,
        open_msg("sim-arm", "depth-near", camera),
        with_depth(0.2, &|_| None),
    )
    .await
    .unwrap();
    assert_eq!(scores.len(), offline.len());
    assert!(
        scores
            .iter()
            .zip(&offline)
            .any(|(s, o)| s.e_r != o.values[vamos::eval::Detector::Scene]),
        "a depth of 0.2 m changed no e_r"
    );

    // Bad depth images on the 3rd (not a depth encoding), 5th (another aspect ratio) and
    // 7th image (too few bytes): each reported; every image scored.
    let bad = |i: usize| {
        let d = |encoding: &str, width, height, data: Vec<u8>| proto::DepthImage {
            encoding: encoding.into(),
            width,
            height,
            step: 0,
            big_endian: false,
            data,
        };
        match i {
            3 => Some(d("rgb8", 160, 120, vec![0; 160 * 120 * 3])),
            5 => Some(d("16UC1", 160, 40, vec![1; 160 * 40 * 2])),
            7 => Some(d("16UC1", 160, 120, vec![1; 99])),
            _ => None,
        }
    };
    let (scores, events) = stream_all(
        server.grpc_addr,
        None,
        open_msg("sim-arm", "depth-bad", camera),
        with_depth(assumed_m, &bad),
    )
    .await
    .unwrap();
    assert_eq!(
        scores.len(),
        offline.len(),
        "a bad depth image lost a frame"
    );
    let errors: Vec<&str> = events
        .iter()
        .filter(|e| e.kind == proto::session_event::Kind::MessageError as i32)
        .map(|e| e.detail.as_str())
        .collect();
    assert_eq!(errors.len(), 3, "{errors:?}");
    for (detail, why) in errors
        .iter()
        .zip(["16UC1", "another aspect ratio", "needs"])
    {
        assert!(
            detail.contains("depth image refused") && detail.contains(why),
            "{detail}"
        );
    }
    server.shutdown().await.unwrap();
}

/// A live session's measured load is what admission counts: with the workers' capacity
/// taken, another session is refused with the figures, and once it closes one is
/// admitted again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_that_would_pass_the_measured_capacity_is_refused_with_the_figures() {
    let mut f = fixture_setup(8, false);
    f.settings.service.workers = 1;
    // A sliver of one worker: the first session alone fills it.
    f.settings.service.admission_load = 0.001;
    let server = start(&f).await;
    let (messages, camera) = episode_messages(&episode("test_0000"));
    let mut client = MonitorClient::connect(format!("http://{}", server.grpc_addr))
        .await
        .unwrap();
    let (tx, rx) = mpsc::channel(64);
    tx.send(proto::StreamRequest {
        message: Some(open_msg("sim-arm", "first", camera)),
    })
    .await
    .unwrap();
    let mut first = client
        .stream(authed(ReceiverStream::new(rx), None))
        .await
        .unwrap()
        .into_inner();
    // It sends its first frames (joint states with them) and waits for three scores.
    let mut scores = 0;
    let mut sent = messages.into_iter();
    while scores < 3 {
        for m in sent.by_ref() {
            let image = matches!(m, In::Image(_));
            tx.send(proto::StreamRequest { message: Some(m) })
                .await
                .unwrap();
            if image {
                break;
            }
        }
        let deadline = tokio::time::Instant::now() + Duration::from_millis(300);
        while let Ok(Some(Ok(r))) = tokio::time::timeout_at(deadline, first.next()).await {
            if matches!(r.message, Some(proto::stream_response::Message::Score(_))) {
                scores += 1;
            }
        }
    }
    let metrics = metrics_text(server.rest_addr).await;
    assert!(metrics.contains("vamos_capacity_cores 0.001"), "{metrics}");
    let load: f64 = metrics
        .lines()
        .find_map(|l| l.strip_prefix("vamos_load_cores "))
        .unwrap()
        .parse()
        .unwrap();
    assert!(load > 0.0, "{load}");
    // A client that says it sends 10 Hz is told what it would add; one that does not
    // say is refused on the load alone.
    let mut at_10_hz = open_msg("sim-arm", "second", None);
    if let In::Open(o) = &mut at_10_hz {
        o.image_rate_hz = 10.0;
    }
    let told: &[&str] = &[
        "admission_load",
        "\"sim-arm\"",
        "ms per frame",
        "10.0 Hz",
        "of 0.00 cores",
    ];
    let untold: &[&str] = &["admission_load", "of 0.00 cores"];
    for (open, parts) in [
        (at_10_hz, told),
        (open_msg("sim-arm", "second", None), untold),
    ] {
        let err = stream_all(server.grpc_addr, None, open, vec![])
            .await
            .unwrap_err();
        assert_eq!(err.code(), tonic::Code::ResourceExhausted, "{err:?}");
        for part in parts {
            assert!(err.message().contains(part), "{part}: {}", err.message());
        }
    }
    // The first session ends: its load leaves, and a new session is admitted.
    drop(tx);
    while first.next().await.is_some() {}
    let (_, events) = stream_all(
        server.grpc_addr,
        None,
        open_msg("sim-arm", "third", None),
        vec![],
    )
    .await
    .unwrap();
    assert_eq!(events[0].kind, proto::session_event::Kind::Opened as i32);
    assert!(
        metrics_text(server.rest_addr)
            .await
            .contains("vamos_load_cores 0\n")
    );
    server.shutdown().await.unwrap();
}
