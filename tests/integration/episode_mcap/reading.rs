//! Reading bags: every encoding against the Python reference, chunk order, joint gaps, truncation, labels, topics.

use super::*;

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

/// A record inside an uncompressed chunk that declares more bytes than the chunk has left
/// (fuzz-found: the MCAP reader subtracted it from the chunk's remainder unchecked). The
/// bag is read up to that chunk and the damage names it.
#[test]
fn a_record_running_past_its_uncompressed_chunk_is_damage_after_the_frames_before_it() {
    let bytes = std::fs::read(fixtures().join("rgba8_none.mcap")).unwrap();
    let u64_at = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    // The data section's chunks, and where it ends (the summary and footer are dropped so
    // that the file is read by a linear scan).
    let (mut chunks, mut pos) = (Vec::new(), 8);
    while bytes[pos] != 0x0f {
        if bytes[pos] == 0x06 {
            chunks.push(pos);
        }
        pos += 9 + u64_at(pos + 1) as usize;
    }
    assert!(chunks.len() >= 3, "{} chunks", chunks.len());
    let last = *chunks.last().unwrap();
    // Opcode and length, times and uncompressed size, CRC, "" (no compression), records length.
    assert_eq!(
        u32::from_le_bytes(bytes[last + 37..last + 41].try_into().unwrap()),
        0
    );
    let records = last + 49;
    let records_len = u64_at(last + 41);
    let mut damaged = bytes[..pos].to_vec();
    damaged[records + 1..records + 9].copy_from_slice(&(records_len + 100).to_le_bytes());
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("overrun.mcap");
    std::fs::write(&path, &damaged).unwrap();

    let ep = McapEpisode::open(&path, &EpisodeConfig::default()).unwrap();
    assert!(!ep.info().indexed);
    let items: Vec<_> = ep.frames().collect();
    let (end, frames) = items.split_last().unwrap();
    match end {
        Err(EpisodeError::Truncated { offset, reason, .. }) => {
            assert_eq!(*offset, last as u64);
            assert!(
                reason.contains(&format!("chunk at byte {last}")),
                "{reason}"
            );
            assert!(reason.contains("declares"), "{reason}");
        }
        other => panic!("the last item should be the damage: {other:?}"),
    }
    // Every image of the chunks before it (the fixture's chunks hold whole frames' worth of
    // messages; at least one image is lost with the last chunk).
    let read = frames.iter().filter(|f| f.is_ok()).count();
    let all = expected()["bags"]
        .as_array()
        .unwrap()
        .iter()
        .find(|b| b["file"] == "rgba8_none.mcap")
        .unwrap()["frames"]
        .as_array()
        .unwrap()
        .len();
    assert!(read >= 1 && read < all, "{read} of {all} frames");
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
fn a_configured_depth_topic_gives_each_frame_the_nearest_depth_image() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("depth.mcap");
    let mut w = ScoreBagWriter::create(&path, None).unwrap();
    let rgb = [9u8; 4 * 2 * 3];
    let ms = 1_000_000i64;
    for (i, stamp) in [100 * ms, 200 * ms, 300 * ms, 400 * ms, 500 * ms]
        .into_iter()
        .enumerate()
    {
        let raw = ImageData::Raw {
            width: 4,
            height: 2,
            encoding: "rgb8",
            data: &rgb,
        };
        w.write_image("/camera/image_raw", stamp, raw).unwrap();
        // Depth: 16UC1 millimetres 5 ms after the image (within the default 20 ms); the
        // third frame's 30 ms after (too far), the fourth's in another aspect ratio, the
        // fifth's in an encoding that is not depth.
        let mm: Vec<u8> = (0..8u16)
            .flat_map(|p| (1000 * (i as u16 + 1) + p).to_le_bytes())
            .collect();
        let depth = match i {
            2 => (stamp + 30 * ms, 4, 2, "16UC1", mm.clone()),
            3 => (stamp + 5 * ms, 8, 1, "16UC1", mm.clone()),
            4 => (stamp + 5 * ms, 4, 2, "mono8", vec![1u8; 8]),
            _ => (stamp + 5 * ms, 4, 2, "16UC1", mm.clone()),
        };
        let (at, dw, dh, encoding, data) = depth;
        let raw = ImageData::Raw {
            width: dw,
            height: dh,
            encoding,
            data: &data,
        };
        w.write_image("/camera/depth/image_raw", at, raw).unwrap();
    }
    w.finish().unwrap();

    // Without configuration the depth topic is not used (and not taken for the image).
    let ep = McapEpisode::open(&path, &EpisodeConfig::default()).unwrap();
    assert_eq!(ep.info().chosen.image, "/camera/image_raw");
    assert_eq!(ep.info().chosen.depth, None);
    let (frames, errors) = read_all(&ep);
    assert!(errors.is_empty() && frames.len() == 5, "{errors:?}");
    assert!(frames.iter().all(|f| f.depth.is_none()));

    let cfg = |depth: &str| EpisodeConfig {
        topics: EpisodeTopics {
            depth: Some(depth.into()),
            ..Default::default()
        },
        ..EpisodeConfig::default()
    };
    let ep = McapEpisode::open(&path, &cfg("/camera/depth/image_raw")).unwrap();
    assert_eq!(ep.info().depth_messages, 5);
    let (frames, errors) = read_all(&ep);
    assert!(errors.is_empty() && frames.len() == 5, "{errors:?}");
    for (i, f) in frames.iter().enumerate() {
        match i {
            0 | 1 => {
                let d = f.depth.as_ref().expect("depth within the gap");
                assert_eq!(d.size(), (4, 2));
                let want = 1.0 * (i as f32 + 1.0);
                assert!((d.metres()[0] - want).abs() < 1e-6, "{:?}", d.metres());
                assert!((d.metres()[7] - (want + 0.007)).abs() < 1e-6);
                assert!(f.warnings.is_empty(), "{:?}", f.warnings);
            }
            _ => {
                assert!(f.depth.is_none(), "frame {i}");
                let why = match i {
                    2 => "no /camera/depth/image_raw image within 20 ms",
                    3 => "depth image 8x1 does not fit the 4x2 image",
                    _ => "16UC1",
                };
                assert!(
                    f.warnings.iter().any(|w| w.contains(why)),
                    "frame {i}: {:?}",
                    f.warnings
                );
            }
        }
    }

    // A depth topic that is not in the file: the episode is read without depth, with a
    // warning; the image topic named as depth: refused.
    let ep = McapEpisode::open(&path, &cfg("/nope")).unwrap();
    let info = ep.info();
    assert_eq!(info.chosen.depth, None);
    assert!(
        info.warnings
            .iter()
            .any(|w| w.contains("depth topic /nope is not in the file")),
        "{:?}",
        info.warnings
    );
    let (frames, errors) = read_all(&ep);
    assert!(errors.is_empty() && frames.len() == 5);
    assert!(frames.iter().all(|f| f.depth.is_none()));
    let e = McapEpisode::open(&path, &cfg("/camera/image_raw")).unwrap_err();
    assert!(
        matches!(&e, EpisodeError::Topic { reason, .. } if reason.contains("is the image topic")),
        "{e}"
    );
}
