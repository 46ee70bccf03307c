//! `vamos::client` against the real server: a recorded episode replayed as a live robot
//! (as fast as the server scores, and at a recorded rate), batch episode scoring, and
//! the errors a caller sees.

use super::service::{ROBOT, assert_same_scores, episode, fixture_setup, offline, start};
use vamos::api::proto;
use vamos::client::replay::record;
use vamos::client::{Client, ClientError, ClientOptions, Pace, Update};

fn open(session_id: &str, camera: Option<proto::CameraInfo>) -> proto::OpenSession {
    proto::OpenSession {
        robot_id: "client-test".into(),
        profile: "sim-arm".into(),
        camera_info: camera,
        task: "place_book".into(),
        session_id: session_id.into(),
        anomaly_maps: false,
        image_rate_hz: 0.0,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_window_paced_replay_drops_nothing_on_a_short_queue_and_matches_offline() {
    let mut f = fixture_setup(8, false);
    // A queue of 3 with drop-oldest: an unpaced client would lose frames here.
    f.settings.service.queue_depth = 3;
    let server = start(&f).await;
    let url = format!("http://{}", server.grpc_addr);
    let client = Client::connect(&url, ClientOptions::default())
        .await
        .unwrap();
    let name = "test_0002_sensor_fault";
    let rec = record(&episode(name), &Default::default()).unwrap();
    let mut sent = 0;
    let mut max_in_flight = 0;
    let mut scored_seen = 0;
    let summary = client
        .replay(open(name, rec.camera), &rec, Pace::Window(2), |u| match u {
            Update::Sent { .. } => {
                sent += 1;
                max_in_flight = max_in_flight.max(sent - scored_seen);
            }
            Update::Score(_) => scored_seen += 1,
            Update::Event(_) | Update::Alarm(_) => {}
        })
        .await
        .unwrap();
    assert_eq!(summary.dropped, 0);
    assert!(
        summary.message_errors.is_empty(),
        "{:?}",
        summary.message_errors
    );
    assert_eq!(summary.images_sent, sent);
    assert_eq!(summary.scores.len() as u64, summary.images_sent);
    assert!(max_in_flight <= 2, "window exceeded: {max_in_flight}");
    assert_eq!(summary.session_id, name);
    assert_same_scores(&summary.scores, &offline(&f.setup, &episode(name)));

    // Batch scoring through the same client gives the same scores.
    let mut seen = 0;
    let batch = client
        .score_episode(&episode(name), "sim-arm", |_| seen += 1)
        .await
        .unwrap();
    assert_eq!(seen, batch.len());
    assert_same_scores(&batch, &offline(&f.setup, &episode(name)));

    // `vamos stream` (the binary) prints one JSON line per answer: the same scores.
    let cmd_url = url.clone();
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new(env!("CARGO_BIN_EXE_vamos"))
            .args([
                "stream",
                "--fast",
                // Below the queue of 3: the default window (4) could lose frames here.
                "--window",
                "2",
                "--profile",
                "sim-arm",
                "--server",
                &cmd_url,
            ])
            .arg(episode(name))
            .env("VAMOS_LOG__LEVEL", "warn")
            .output()
            .unwrap()
    })
    .await
    .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let lines: Vec<serde_json::Value> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let scores: Vec<(i64, f64)> = lines
        .iter()
        .filter(|l| l["type"] == "score")
        .map(|l| {
            (
                l["stamp_ns"].as_i64().unwrap(),
                l["score"].as_f64().unwrap(),
            )
        })
        .collect();
    let expected: Vec<(i64, f64)> = summary
        .scores
        .iter()
        .map(|s| (s.stamp_ns, s.score))
        .collect();
    assert_eq!(scores, expected);
    assert_eq!(lines[0]["kind"], "KIND_OPENED");
    assert!(
        stderr.contains(&format!("{} scored", expected.len())),
        "{stderr}"
    );
    server.shutdown().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn recorded_pace_follows_the_bag_timing_and_errors_are_typed() {
    let f = fixture_setup(8, true);
    let server = start(&f).await;
    let url = format!("http://{}", server.grpc_addr);
    let name = "test_0000";
    let rec = record(&episode(name), &Default::default()).unwrap();
    let span = rec.messages.last().unwrap().0;

    // Without a token the server refuses the session with UNAUTHENTICATED.
    let anonymous = Client::connect(&url, ClientOptions::default())
        .await
        .unwrap();
    match anonymous
        .replay(open("anon", rec.camera), &rec, Pace::Window(2), |_| {})
        .await
    {
        Err(ClientError::Status(s)) => assert_eq!(s.code(), tonic::Code::Unauthenticated),
        other => panic!(
            "expected UNAUTHENTICATED, got {:?}",
            other.map(|s| s.scores.len())
        ),
    }

    // With the robot token, at 4x the recorded rate: the replay takes at least a quarter
    // of the bag's span and every frame is scored.
    let client = Client::connect(
        &url,
        ClientOptions {
            token: Some(ROBOT.into()),
            ..ClientOptions::default()
        },
    )
    .await
    .unwrap();
    let summary = client
        .replay(
            open(name, rec.camera),
            &rec,
            Pace::Recorded { speed: 4.0 },
            |_| {},
        )
        .await
        .unwrap();
    assert!(
        summary.elapsed >= span.div_f64(4.0),
        "{:?} < {:?} / 4",
        summary.elapsed,
        span
    );
    assert_eq!(summary.scores.len() as u64, summary.images_sent);
    assert!(summary.images_sent > 20);

    // A bad speed is refused before anything is sent; an unknown profile is NOT_FOUND.
    assert!(matches!(
        client
            .replay(open("x", None), &rec, Pace::Recorded { speed: 0.0 }, |_| {})
            .await,
        Err(ClientError::Config(_))
    ));
    let mut bad = open("y", None);
    bad.profile = "no-such-profile".into();
    match client.replay(bad, &rec, Pace::Window(2), |_| {}).await {
        Err(ClientError::Status(s)) => assert_eq!(s.code(), tonic::Code::NotFound),
        other => panic!(
            "expected NOT_FOUND, got {:?}",
            other.map(|s| s.scores.len())
        ),
    }
    server.shutdown().await.unwrap();

    // Nobody listens on the port any more: a connection error naming the URL.
    match Client::connect(&url, ClientOptions::default()).await {
        Err(ClientError::Connect { url: u, .. }) => assert_eq!(u, url),
        Err(e) => panic!("expected a connection error, got {e}"),
        Ok(_) => panic!("connected to a stopped server"),
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_and_overlong_sessions_end_with_deadline_exceeded_and_others_go_on() {
    let mut f = fixture_setup(8, false);
    f.settings.service.idle_timeout_s = 0.6;
    f.settings.service.max_session_s = 1.5;
    let server = start(&f).await;
    let url = format!("http://{}", server.grpc_addr);
    let client = Client::connect(&url, ClientOptions::default())
        .await
        .unwrap();
    let rec = record(&episode("test_0000"), &Default::default()).unwrap();
    let joints: Vec<_> = rec
        .messages
        .iter()
        .filter_map(|(_, m)| match m {
            proto::stream_request::Message::Joints(j) => Some(j.clone()),
            _ => None,
        })
        .collect();

    // A stalled client: opened, then silent. The server ends it after the idle timeout.
    let mut stalled = client.open(open("stalled", rec.camera)).await.unwrap();
    // A chatty one: a joint state every 100 ms, never idle, but longer than max_session_s.
    let mut chatty = client.open(open("chatty", rec.camera)).await.unwrap();
    let t0 = std::time::Instant::now();
    let chatty_task = tokio::spawn(async move {
        let mut sent = 0;
        for j in joints.into_iter().cycle().take(40) {
            if chatty
                .send(proto::stream_request::Message::Joints(j))
                .await
                .is_err()
            {
                break;
            }
            sent += 1;
            tokio::time::sleep(std::time::Duration::from_millis(100)).await;
        }
        let mut status = None;
        while let Some(u) = chatty.next().await {
            if let Err(ClientError::Status(s)) = u {
                status = Some(s);
                break;
            }
        }
        (sent, status)
    });
    let mut stalled_status = None;
    while let Some(u) = stalled.next().await {
        if let Err(ClientError::Status(s)) = u {
            stalled_status = Some(s);
            break;
        }
    }
    let stalled_after = t0.elapsed();
    let s = stalled_status.expect("the stalled session ended without a status");
    assert_eq!(s.code(), tonic::Code::DeadlineExceeded, "{s:?}");
    assert!(s.message().contains("no message for"), "{}", s.message());
    assert!(stalled_after.as_secs_f64() >= 0.5, "{stalled_after:?}");

    let (sent, status) = chatty_task.await.unwrap();
    let s = status.expect("the overlong session ended without a status");
    assert_eq!(s.code(), tonic::Code::DeadlineExceeded, "{s:?}");
    assert!(s.message().contains("maximum length"), "{}", s.message());
    // It was cut near 1.5 s (15 joint states at 10 Hz), well before its 40 messages.
    assert!((10..40).contains(&sent), "sent {sent}");

    // Afterwards the server serves other robots as usual: a short session (the first
    // ten images, well inside the 1.5 s limit) is scored in full.
    let tenth = rec
        .messages
        .iter()
        .enumerate()
        .filter(|(_, (_, m))| matches!(m, proto::stream_request::Message::Image(_)))
        .nth(10)
        .unwrap()
        .0;
    let short = vamos::client::replay::Recording {
        messages: rec.messages[..tenth].to_vec(),
        camera: rec.camera,
    };
    let summary = client
        .replay(open("after", rec.camera), &short, Pace::Window(2), |_| {})
        .await
        .unwrap();
    assert_eq!(summary.images_sent, 10);
    assert_eq!(summary.scores.len(), 10);
    assert_eq!(server.shared.hub.session_count(), 0);
    server.shutdown().await.unwrap();
}

/// A bag with a depth topic replays as a robot with a depth camera would stream it: the
/// colour images, each with the depth image nearest its stamp when the topic is configured.
#[test]
fn a_replayed_bag_sends_its_configured_depth_images_with_their_colour_images() {
    use vamos::episode::{EpisodeConfig, EpisodeTopics, ImageData, ScoreBagWriter};
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("depth.mcap");
    let mut w = ScoreBagWriter::create(&path, None).unwrap();
    let rgb = [5u8; 4 * 2 * 3];
    for i in 0..4i64 {
        let stamp = (i + 1) * 100_000_000;
        let raw = ImageData::Raw {
            width: 4,
            height: 2,
            encoding: "rgb8",
            data: &rgb,
        };
        w.write_image("/camera/image_raw", stamp, raw).unwrap();
        // The last depth image is 50 ms late: beyond the default 20 ms, not attached.
        let late = if i == 3 { 50_000_000 } else { 2_000_000 };
        let mm: Vec<u8> = (0..8u16)
            .flat_map(|_| (1000 + i as u16).to_le_bytes())
            .collect();
        let raw = ImageData::Raw {
            width: 4,
            height: 2,
            encoding: "16UC1",
            data: &mm,
        };
        w.write_image("/camera/depth/image_raw", stamp + late, raw)
            .unwrap();
    }
    w.finish().unwrap();
    let images = |config: &EpisodeConfig| -> Vec<proto::Image> {
        record(&path, config)
            .unwrap()
            .messages
            .into_iter()
            .filter_map(|(_, m)| match m {
                proto::stream_request::Message::Image(img) => Some(img),
                _ => None,
            })
            .collect()
    };
    // Unconfigured: the colour images only, none carrying depth.
    let plain = images(&EpisodeConfig::default());
    assert_eq!(plain.len(), 4);
    assert!(
        plain
            .iter()
            .all(|i| i.encoding == "rgb8" && i.depth.is_none())
    );
    let config = EpisodeConfig {
        topics: EpisodeTopics {
            depth: Some("/camera/depth/image_raw".into()),
            ..Default::default()
        },
        ..EpisodeConfig::default()
    };
    let with_depth = images(&config);
    assert_eq!(with_depth.len(), 4);
    for (i, img) in with_depth.iter().enumerate() {
        match (&img.depth, i) {
            (None, 3) => {}
            (Some(d), 0..=2) => {
                assert_eq!((d.encoding.as_str(), d.width, d.height), ("16UC1", 4, 2));
                assert_eq!(d.data[..2], (1000 + i as u16).to_le_bytes());
            }
            (d, _) => panic!("image {i}: {d:?}"),
        }
    }
}
