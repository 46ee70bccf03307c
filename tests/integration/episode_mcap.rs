//! ROS 2 bags in MCAP, written by the official Python writer
//! (`tests/fixtures/episode/make_bags.py`, values in `expected.json` computed there with
//! numpy): every image encoding, compressed images, zstd/lz4/uncompressed chunks, joint
//! interpolation, and the bad-input cases; then the score-bag writer read back.

use serde_json::Value;
use std::path::{Path, PathBuf};
use std::process::Command;
use vamos::episode::ros::{decode_bool, decode_f64, schema};
use vamos::episode::{
    EpisodeConfig, EpisodeError, EpisodeFrame, EpisodeTopics, ImageData, Labels, McapEpisode,
    ScoreBagWriter,
};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/episode")
}

fn expected() -> Value {
    let text = std::fs::read_to_string(fixtures().join("expected.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn read_all(ep: &McapEpisode) -> (Vec<EpisodeFrame>, Vec<EpisodeError>) {
    let (mut ok, mut err) = (Vec::new(), Vec::new());
    for f in ep.frames() {
        match f {
            Ok(f) => ok.push(f),
            Err(e) => err.push(e),
        }
    }
    (ok, err)
}

/// Pixel tolerance: raw encodings are converted with the same formula in f32 (Python uses
/// f64), so 1e-3 grey levels; JPEG goes through a different decoder here (the `image`
/// crate) than in Python (libjpeg via Pillow), whose IDCT and chroma upsampling differ:
/// measured up to ~1.4 grey levels on these fixtures (quality 95), so 2.
fn pixel_tolerance(encoding: &str) -> f64 {
    if encoding == "jpeg" { 2.0 } else { 1e-3 }
}

fn check_frame(bag: &str, encoding: &str, got: &EpisodeFrame, want: &Value) {
    assert_eq!(got.index as u64, want["index"].as_u64().unwrap(), "{bag}");
    assert_eq!(
        got.stamp_ns,
        want["stamp_ns"].as_i64().unwrap(),
        "{bag} frame {}",
        got.index
    );
    for p in want["pixels"].as_array().unwrap() {
        let (x, y, v) = (
            p[0].as_u64().unwrap() as usize,
            p[1].as_u64().unwrap() as usize,
            p[2].as_f64().unwrap(),
        );
        let g = f64::from(got.image.get(x, y));
        assert!(
            (g - v).abs() <= pixel_tolerance(encoding),
            "{bag} frame {} pixel ({x},{y}): {g} vs {v}",
            got.index
        );
    }
    let warned = want["warned"].as_bool().unwrap();
    assert_eq!(
        got.warnings.iter().any(|w| w.contains("skipped")),
        warned,
        "{bag} frame {}: {:?}",
        got.index,
        got.warnings
    );
    match (&got.joints, want.get("joints")) {
        (Some(j), Some(w)) => {
            for (a, b) in j.positions.iter().zip(w["positions"].as_array().unwrap()) {
                assert!(
                    (a - b.as_f64().unwrap()).abs() < 1e-9,
                    "{bag} frame {}: {a} vs {b}",
                    got.index
                );
            }
            assert_eq!(j.velocities.len(), 2);
            for (a, b) in j.velocities.iter().zip(w["velocities"].as_array().unwrap()) {
                assert!(
                    (a - b.as_f64().unwrap()).abs() < 1e-9,
                    "{bag}: velocity {a} vs {b}"
                );
            }
            assert_eq!(
                j.gap_ns,
                w["gap_ns"].as_i64().unwrap(),
                "{bag} frame {}",
                got.index
            );
            assert_eq!(
                j.extrapolated,
                w["extrapolated"].as_bool().unwrap(),
                "{bag} frame {}",
                got.index
            );
            assert_eq!(j.names, ["shoulder", "elbow"]);
        }
        (None, None) => {}
        (g, w) => panic!("{bag} frame {}: joints {g:?} vs {w:?}", got.index),
    }
}

#[test]
fn every_bag_matches_the_python_reference() {
    let exp = expected();
    let cfg = EpisodeConfig::default();
    for bag in exp["bags"].as_array().unwrap() {
        let file = bag["file"].as_str().unwrap();
        let encoding = bag["encoding"].as_str().unwrap();
        let ep = McapEpisode::open(&fixtures().join(file), &cfg).unwrap();
        let info = ep.info();
        assert!(info.indexed, "{file}");
        assert_eq!(info.chosen.image, "/camera/image_raw");
        assert_eq!(
            info.image_messages,
            bag["images"].as_u64().unwrap(),
            "{file}"
        );
        assert_eq!(
            info.joint_messages,
            bag["joint_messages"].as_u64().unwrap(),
            "{file}"
        );
        let (frames, errors) = read_all(&ep);
        let want = bag["frames"].as_array().unwrap();
        assert_eq!(frames.len(), want.len(), "{file}: {errors:?}");
        for (g, w) in frames.iter().zip(want) {
            check_frame(file, encoding, g, w);
            assert_eq!(g.image.size(), (64, 48));
        }
        // Stamps strictly increase: nothing reordered, nothing repeated.
        assert!(
            frames.windows(2).all(|p| p[0].stamp_ns < p[1].stamp_ns),
            "{file}"
        );
        let want_errors = bag["errors"].as_array().unwrap();
        assert_eq!(errors.len(), want_errors.len(), "{file}: {errors:?}");
        for (e, w) in errors.iter().zip(want_errors) {
            let index = w["index"].as_u64().unwrap() as usize;
            match (w["kind"].as_str().unwrap(), e) {
                (
                    "unknown_encoding",
                    EpisodeError::UnknownEncoding {
                        index: i,
                        encoding,
                        topic,
                    },
                ) => {
                    assert_eq!(
                        (*i, encoding.as_str(), topic.as_str()),
                        (index, "yuv422", "/camera/image_raw")
                    );
                }
                (
                    "size_changed",
                    EpisodeError::ImageSizeChanged {
                        index: i,
                        width,
                        height,
                        expected_width,
                        ..
                    },
                ) => {
                    assert_eq!((*i, *width, *height, *expected_width), (index, 32, 24, 64));
                }
                (
                    "bad_joint",
                    EpisodeError::BadMessage {
                        topic,
                        index: i,
                        reason,
                    },
                ) => {
                    assert_eq!((topic.as_str(), *i), ("/joint_states", index));
                    assert!(reason.contains("NaN"), "{reason}");
                }
                (kind, e) => panic!("{file}: expected {kind} at {index}, got {e}"),
            }
        }
        assert_eq!(
            ep.info().skipped_backwards as u64,
            bag["skipped_backwards"].as_u64().unwrap(),
            "{file}"
        );
        if let Some(k) = bag["k"].as_array() {
            let ci = ep.camera_info().unwrap().unwrap();
            assert_eq!((ci.width, ci.height), (64, 48));
            let k: Vec<f64> = k.iter().map(|v| v.as_f64().unwrap()).collect();
            assert_eq!(ci.k.to_vec(), k);
            let intr = ci.intrinsics().unwrap();
            assert_eq!(
                (intr.fx, intr.fy, intr.cx, intr.cy),
                (60.0, 61.0, 31.5, 23.5)
            );
            assert_eq!(frames[0].camera_info.as_ref().unwrap().k.to_vec(), k);
            assert_eq!(
                ep.robot_description().unwrap().as_deref(),
                exp["urdf"].as_str()
            );
        }
    }
}

/// A bag written out of log-time order into small chunks (`interleaved.mcap`: chunks
/// overlap in log time, images lie in the file as 10..19 then 0..9): every image is read,
/// in log-time order, none is taken for a stamp going backwards.
#[test]
fn overlapping_chunks_are_read_in_log_time_order() {
    let exp = expected();
    let bag = exp["bags"]
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["file"] == "interleaved.mcap")
        .unwrap();
    // The fixture really is out of order (checked by the official reader in Python).
    assert!(bag["overlapping_chunk_pairs"].as_u64().unwrap() > 0);
    let file_order: Vec<u64> = bag["file_order_images"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap())
        .collect();
    assert!(file_order.windows(2).any(|p| p[0] > p[1]), "{file_order:?}");
    let ep = McapEpisode::open(
        &fixtures().join("interleaved.mcap"),
        &EpisodeConfig::default(),
    )
    .unwrap();
    let (frames, errors) = read_all(&ep);
    assert!(errors.is_empty(), "{errors:?}");
    assert_eq!(frames.len(), 20);
    assert_eq!(ep.info().skipped_backwards, 0);
    assert_eq!(
        frames.iter().map(|f| f.index).collect::<Vec<_>>(),
        (0..20).collect::<Vec<_>>()
    );
    let log_times: Vec<u64> = frames.iter().map(|f| f.source.log_time_ns).collect();
    assert!(log_times.windows(2).all(|p| p[0] < p[1]), "{log_times:?}");
    assert!(
        frames.iter().all(|f| f.warnings.is_empty()),
        "no skips, no gaps"
    );
    // Joint states from both halves of the file are merged before interpolation.
    for (f, w) in frames.iter().zip(bag["frames"].as_array().unwrap()) {
        check_frame("interleaved.mcap", "mono8", f, w);
    }
    // Every message of every topic, in log-time order, through the same reader.
    let mut all = Vec::new();
    ep.for_each_message(
        &["/camera/image_raw".into(), "/joint_states".into()],
        |_, _, t, _| all.push(t),
    )
    .unwrap();
    assert_eq!(
        all.len() as u64,
        20 + bag["joint_messages"].as_u64().unwrap()
    );
    assert!(all.windows(2).all(|p| p[0] <= p[1]));
}

/// `joint_gap.mcap` has no joint samples between images 8 and 13: exactly the frames whose
/// nearest sample is beyond `max_joint_gap_ms` (computed in Python) are flagged, with a
/// warning; a larger limit flags none.
#[test]
fn frames_beyond_the_joint_gap_limit_are_flagged() {
    let exp = expected();
    let bag = exp["bags"]
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["file"] == "joint_gap.mcap")
        .unwrap();
    let want: Vec<usize> = bag["gap_frames"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_u64().unwrap() as usize)
        .collect();
    assert!(!want.is_empty());
    let path = fixtures().join("joint_gap.mcap");
    let flagged = |cfg: &EpisodeConfig| {
        let (frames, errors) = read_all(&McapEpisode::open(&path, cfg).unwrap());
        assert!(errors.is_empty(), "{errors:?}");
        assert_eq!(frames.len(), 20);
        for f in &frames {
            let j = f.joints.as_ref().unwrap();
            assert_eq!(
                j.beyond_max_gap,
                f.warnings
                    .iter()
                    .any(|w| w.contains("nearest joint sample")),
                "frame {}",
                f.index
            );
        }
        frames
            .iter()
            .filter(|f| f.joints.as_ref().unwrap().beyond_max_gap)
            .map(|f| f.index)
            .collect::<Vec<_>>()
    };
    assert_eq!(flagged(&EpisodeConfig::default()), want);
    let wide = EpisodeConfig {
        max_joint_gap_ms: 300.0,
        ..EpisodeConfig::default()
    };
    assert_eq!(flagged(&wide), Vec::<usize>::new());
}

#[test]
fn a_truncated_bag_yields_its_valid_frames_then_where_it_broke() {
    let exp = expected();
    let t = &exp["truncated"];
    let path = fixtures().join(t["file"].as_str().unwrap());
    let ep = McapEpisode::open(&path, &EpisodeConfig::default()).unwrap();
    let info = ep.info();
    assert!(!info.indexed, "no footer: read by a linear scan");
    assert!(info.damage.is_some());
    let items: Vec<_> = ep.frames().collect();
    let (last, frames) = items.split_last().unwrap();
    match last {
        Err(EpisodeError::Truncated {
            offset, path: p, ..
        }) => {
            assert!(p.ends_with("truncated.mcap"));
            assert!(
                *offset >= t["chunk_start"].as_u64().unwrap(),
                "broke at {offset}"
            );
            assert!(
                *offset <= t["cut_at"].as_u64().unwrap(),
                "broke at {offset}"
            );
        }
        other => panic!("last item should be the truncation: {other:?}"),
    }
    let frames: Vec<&EpisodeFrame> = frames.iter().map(|f| f.as_ref().unwrap()).collect();
    let min = t["min_images"].as_u64().unwrap() as usize;
    assert!(
        min >= 5 && frames.len() >= min,
        "{} frames, at least {min}",
        frames.len()
    );
    // They are the original's first frames, values and joints included.
    let original = &exp["bags"][0];
    assert_eq!(original["file"], "rgb8_zstd.mcap");
    for (g, w) in frames.iter().zip(original["frames"].as_array().unwrap()) {
        let w = &mut w.clone();
        // Frames near the cut lack the joint samples after them (read up to the cut).
        if g.joints.as_ref().is_some_and(|j| j.extrapolated) {
            w.as_object_mut().unwrap().remove("joints");
            let mut g2 = (*g).clone();
            g2.joints = None;
            check_frame("truncated", "rgb8", &g2, w);
        } else {
            check_frame("truncated", "rgb8", g, w);
        }
    }
    assert_eq!(
        ep.robot_description().unwrap().as_deref(),
        exp["urdf"].as_str()
    );
}

#[test]
fn labels_come_from_the_sidecar_or_the_label_topic() {
    let exp = expected();
    let ep = McapEpisode::open(
        &fixtures().join("rgb8_zstd.mcap"),
        &EpisodeConfig::default(),
    )
    .unwrap();
    let l = ep.labels().unwrap().unwrap();
    let side = &exp["sidecar"];
    assert_eq!(l.anomaly_type.as_deref(), side["anomaly_type"].as_str());
    let [a, b] = l.intervals_ns[0];
    assert_eq!(a, side["intervals_ns"][0][0].as_i64().unwrap());
    assert!(
        l.is_anomalous(a) && l.is_anomalous(b) && !l.is_anomalous(b + 1) && !l.is_anomalous(a - 1)
    );
    let flagged: Vec<usize> = read_all(&ep)
        .0
        .iter()
        .filter(|f| l.is_anomalous(f.stamp_ns))
        .map(|f| f.index)
        .collect();
    assert_eq!(flagged, [10, 11, 12]);

    let ep = McapEpisode::open(
        &fixtures().join("png_label_topic.mcap"),
        &EpisodeConfig::default(),
    )
    .unwrap();
    assert_eq!(ep.info().chosen.labels.as_deref(), Some("/vamos/labels"));
    let from_topic = ep.labels().unwrap().unwrap();
    let want: Labels = serde_json::from_value(exp["bags"][9]["labels_topic"].clone()).unwrap();
    assert_eq!(from_topic, want);
    let ep = McapEpisode::open(
        &fixtures().join("no_joints.mcap"),
        &EpisodeConfig::default(),
    )
    .unwrap();
    assert_eq!(ep.labels().unwrap(), None);
}

#[test]
fn topics_resolve_by_config_default_and_schema() {
    let path = fixtures().join("rgb8_zstd.mcap");
    let cfg = |topics: EpisodeTopics| EpisodeConfig {
        topics,
        ..EpisodeConfig::default()
    };
    let e = McapEpisode::open(
        &path,
        &cfg(EpisodeTopics {
            image: Some("/nope".into()),
            ..Default::default()
        }),
    )
    .unwrap_err();
    assert!(
        matches!(&e, EpisodeError::Topic { reason, .. } if reason.contains("/nope") && reason.contains("/camera/image_raw")),
        "{e}"
    );
    let e = McapEpisode::open(
        &path,
        &cfg(EpisodeTopics {
            image: Some("/joint_states".into()),
            ..Default::default()
        }),
    )
    .unwrap_err();
    assert!(
        matches!(&e, EpisodeError::Topic { reason, .. } if reason.contains("JointState")),
        "{e}"
    );

    // Two image topics without the default name: the one not named *depth*; two colour
    // topics: an error listing both.
    let dir = tempfile::tempdir().unwrap();
    let raw = [7u8; 12];
    let img = |w: &mut ScoreBagWriter, topic: &str| {
        w.write_image(
            topic,
            1,
            ImageData::Raw {
                width: 2,
                height: 2,
                encoding: "rgb8",
                data: &raw,
            },
        )
        .unwrap();
    };
    let two = dir.path().join("two.mcap");
    let mut w = ScoreBagWriter::create(&two, None).unwrap();
    img(&mut w, "/cam/depth/image");
    img(&mut w, "/cam/color/image");
    w.finish().unwrap();
    let ep = McapEpisode::open(&two, &EpisodeConfig::default()).unwrap();
    assert_eq!(ep.info().chosen.image, "/cam/color/image");
    assert_eq!(ep.info().chosen.joint_states, None);
    let (frames, errors) = read_all(&ep);
    assert!(errors.is_empty() && frames.len() == 1 && frames[0].joints.is_none());
    assert!((f64::from(frames[0].image.get(1, 1)) - 7.0).abs() < 1e-4);
    let amb = dir.path().join("ambiguous.mcap");
    let mut w = ScoreBagWriter::create(&amb, None).unwrap();
    img(&mut w, "/left/image");
    img(&mut w, "/right/image");
    w.finish().unwrap();
    let e = McapEpisode::open(&amb, &EpisodeConfig::default()).unwrap_err();
    assert!(
        matches!(&e, EpisodeError::Topic { reason, .. } if reason.contains("/left/image") && reason.contains("/right/image")),
        "{e}"
    );
}

#[test]
fn a_score_bag_reads_back_with_images_and_scores() {
    let src =
        McapEpisode::open(&fixtures().join("bgr8_lz4.mcap"), &EpisodeConfig::default()).unwrap();
    let (frames, _) = read_all(&src);
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("scores.mcap");
    let mut w = ScoreBagWriter::create(&out, Some(&src.info())).unwrap();
    let heat: Vec<u8> = (0..8 * 6 * 3).map(|i| (i * 5 % 256) as u8).collect();
    for f in &frames {
        w.write_image(
            "/camera/image_raw",
            f.stamp_ns,
            ImageData::Source(&f.source),
        )
        .unwrap();
        w.write_f64("/vamos/score", f.stamp_ns, f.index as f64 * 0.5)
            .unwrap();
        w.write_bool("/vamos/anomaly", f.stamp_ns, f.index % 3 == 0)
            .unwrap();
        w.write_heatmap("/vamos/heatmap", f.stamp_ns, 8, 6, &heat)
            .unwrap();
    }
    // Wrong sizes are errors, not panics.
    assert!(
        w.write_heatmap("/vamos/heatmap", 0, 8, 6, &heat[1..])
            .is_err()
    );
    assert!(
        w.write_f64("/vamos/heatmap", 0, 1.0).is_err(),
        "one schema per topic"
    );
    w.copy_message(
        "/other",
        "pkg/msg/Thing",
        "ros2msg",
        b"int32 x\n",
        &[0, 1, 0, 0, 5, 0, 0, 0],
        42,
    )
    .unwrap();
    w.finish().unwrap();

    let back = McapEpisode::open(&out, &EpisodeConfig::default()).unwrap();
    let info = back.info();
    assert!(info.indexed);
    assert_eq!(info.chosen.image, "/camera/image_raw");
    assert_eq!(info.image_messages, frames.len() as u64);
    let schema_of = |t: &str| {
        info.topics
            .iter()
            .find(|x| x.name == t)
            .unwrap()
            .schema
            .clone()
    };
    assert_eq!(schema_of("/vamos/score"), schema::FLOAT64);
    assert_eq!(schema_of("/vamos/anomaly"), schema::BOOL);
    assert_eq!(schema_of("/vamos/heatmap"), schema::IMAGE);
    assert_eq!(schema_of("/other"), "pkg/msg/Thing");
    let (again, errors) = read_all(&back);
    assert!(errors.is_empty(), "{errors:?}");
    assert_eq!(again.len(), frames.len());
    for (a, b) in again.iter().zip(&frames) {
        assert_eq!((a.index, a.stamp_ns), (b.index, b.stamp_ns));
        assert_eq!(a.image.data(), b.image.data());
        assert_eq!(a.source.cdr, b.source.cdr, "copied unchanged");
        assert_eq!(a.source.log_time_ns, b.stamp_ns as u64, "log time = stamp");
    }
    let mut scores = Vec::new();
    let mut flags = Vec::new();
    back.for_each_message(
        &["/vamos/score".into(), "/vamos/anomaly".into()],
        |t, _, log, data| {
            if t == "/vamos/score" {
                scores.push((log, decode_f64(data).unwrap()));
            } else {
                flags.push(decode_bool(data).unwrap());
            }
        },
    )
    .unwrap();
    assert_eq!(scores.len(), frames.len());
    assert_eq!(scores[3], (frames[3].stamp_ns as u64, 1.5));
    assert_eq!(
        flags.iter().filter(|&&f| f).count(),
        frames.len().div_ceil(3)
    );
    let (name, enc, def) = back.schema_of("/vamos/heatmap").unwrap().unwrap();
    assert_eq!((name.as_str(), enc.as_str()), (schema::IMAGE, "ros2msg"));
    assert!(
        String::from_utf8(def)
            .unwrap()
            .contains("MSG: builtin_interfaces/Time")
    );
    let heat_cfg = EpisodeConfig {
        topics: EpisodeTopics {
            image: Some("/vamos/heatmap".into()),
            ..Default::default()
        },
        ..EpisodeConfig::default()
    };
    let h = McapEpisode::open(&out, &heat_cfg).unwrap();
    let f = h.frames().next().unwrap().unwrap();
    let want = 0.299 * f32::from(heat[3]) + 0.587 * f32::from(heat[4]) + 0.114 * f32::from(heat[5]);
    assert!((f.image.get(1, 0) - want).abs() < 1e-3);
}

#[test]
fn garbage_and_missing_files_are_errors_not_panics() {
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("junk.mcap");
    std::fs::write(&p, b"this is not an mcap file at all").unwrap();
    match McapEpisode::open(&p, &EpisodeConfig::default()) {
        Err(EpisodeError::Truncated { offset, .. }) => assert!(offset <= 31),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        McapEpisode::open(&dir.path().join("missing.mcap"), &EpisodeConfig::default()),
        Err(EpisodeError::Mcap { .. })
    ));
    // A valid bag with bytes flipped inside a chunk and the footer cut: every item is an
    // Ok frame or a typed error, and the reader ends.
    let mut data = std::fs::read(fixtures().join("rgb8_zstd.mcap")).unwrap();
    let n = data.len();
    for i in (n / 3..n / 3 + 64).step_by(7) {
        data[i] ^= 0x5a;
    }
    // Footer intact: read through the index. Chunk CRCs are not checked on this path, so
    // flipped bytes may decode to wrong pixels; what must hold is no panic and an end.
    std::fs::write(&p, &data).unwrap();
    let ep = McapEpisode::open(&p, &EpisodeConfig::default()).unwrap();
    assert!(ep.info().indexed);
    let items: Vec<_> = ep.frames().collect();
    assert!(items.len() <= 21 && items.iter().filter(|i| i.is_ok()).count() >= 5);
    data.truncate(n - 100);
    std::fs::write(&p, &data).unwrap();
    let ep = McapEpisode::open(&p, &EpisodeConfig::default()).unwrap();
    let items: Vec<_> = ep.frames().collect();
    assert!(items.iter().filter(|i| i.is_ok()).count() >= 5);
    assert!(matches!(
        items.last(),
        Some(Err(EpisodeError::Truncated { .. }))
    ));
}

#[test]
fn the_cli_prints_info_and_copies_a_bag() {
    let bin = env!("CARGO_BIN_EXE_vamos");
    let bag = fixtures().join("backwards.mcap");
    let out = Command::new(bin)
        .args(["episode", "inspect", "--frames"])
        .arg(&bag)
        .env_remove("VAMOS_CONFIG")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(v["info"]["name"], "backwards");
    assert_eq!(v["info"]["image_messages"], 20);
    assert_eq!(v["info"]["skipped_backwards"], 2);
    assert_eq!(v["frames"], 18);
    assert_eq!(v["camera_info"]["k"][0], 60.0);
    assert!(v["labels"].is_null());
    let topics = v["info"]["topics"].as_array().unwrap();
    assert_eq!(topics.len(), 4);

    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("copy.mcap");
    let out = Command::new(bin)
        .args(["episode", "copy"])
        .arg(fixtures().join("truncated.mcap"))
        .arg(&copy)
        .env_remove("VAMOS_CONFIG")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["damage"].as_str().unwrap().contains("truncated"));
    let n = v["frames"].as_u64().unwrap();
    let ep = McapEpisode::open(&copy, &EpisodeConfig::default()).unwrap();
    assert!(ep.info().indexed, "the copy is complete");
    assert_eq!(ep.info().image_messages, n);
    assert_eq!(ep.frames().filter(|f| f.is_ok()).count() as u64, n);

    let out = Command::new(bin)
        .args(["episode", "inspect"])
        .arg(dir.path().join("nope.mcap"))
        .env_remove("VAMOS_CONFIG")
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
}
