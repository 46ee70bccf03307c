//! Scored bags read back; garbage and missing files are errors; the episode CLI.

use super::*;

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

/// `vamos ARGS...` without a settings file from the environment.
fn vamos_cli<S: AsRef<std::ffi::OsStr>>(args: impl IntoIterator<Item = S>) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_vamos"))
        .args(args)
        .env_remove("VAMOS_CONFIG")
        .output()
        .unwrap()
}

/// Asserts that a `vamos` run succeeded, with its stderr as the message.
fn assert_ran(out: &std::process::Output) {
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

#[test]
fn the_cli_prints_info_and_copies_a_bag() {
    let bag = fixtures().join("backwards.mcap");
    let out = vamos_cli([
        "episode".as_ref(),
        "inspect".as_ref(),
        "--frames".as_ref(),
        bag.as_os_str(),
    ]);
    assert_ran(&out);
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
    let truncated = fixtures().join("truncated.mcap");
    let out = vamos_cli([
        "episode".as_ref(),
        "copy".as_ref(),
        truncated.as_os_str(),
        copy.as_os_str(),
    ]);
    assert_ran(&out);
    let v: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert!(v["damage"].as_str().unwrap().contains("truncated"));
    let n = v["frames"].as_u64().unwrap();
    let ep = McapEpisode::open(&copy, &EpisodeConfig::default()).unwrap();
    assert!(ep.info().indexed, "the copy is complete");
    assert_eq!(ep.info().image_messages, n);
    assert_eq!(ep.frames().filter(|f| f.is_ok()).count() as u64, n);

    let nope = dir.path().join("nope.mcap");
    let out = vamos_cli(["episode".as_ref(), "inspect".as_ref(), nope.as_os_str()]);
    assert!(!out.status.success());
    assert!(!String::from_utf8_lossy(&out.stderr).contains("panicked"));
}

/// `vamos episode copy --jpeg Q` re-encodes the images as JPEG files: the copy reads as
/// the same frames (gray within JPEG's error) with the same joint states, and carries no
/// diagnostics.
#[test]
fn copy_with_jpeg_re_encodes_the_images_and_keeps_the_frames() {
    let source =
        Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim/test/test_0000.mcap");
    let dir = tempfile::tempdir().unwrap();
    let copy = dir.path().join("jpeg.mcap");
    let jpeg = |quality: &str, out: &Path| {
        vamos_cli([
            "episode".as_ref(),
            "copy".as_ref(),
            "--jpeg".as_ref(),
            quality.as_ref(),
            source.as_os_str(),
            out.as_os_str(),
        ])
    };
    assert_ran(&jpeg("90", &copy));
    let cfg = EpisodeConfig::default();
    let (a, b) = (
        McapEpisode::open(&source, &cfg).unwrap(),
        McapEpisode::open(&copy, &cfg).unwrap(),
    );
    assert_eq!(b.info().chosen.image_schema, schema::COMPRESSED_IMAGE);
    assert!(
        b.info()
            .topics
            .iter()
            .all(|t| !t.name.starts_with("/vamos/"))
    );
    let (fa, ea) = read_all(&a);
    let (fb, eb) = read_all(&b);
    assert!(ea.is_empty() && eb.is_empty(), "{ea:?} {eb:?}");
    assert_eq!(fa.len(), fb.len());
    for (x, y) in fa.iter().zip(&fb) {
        assert_eq!(x.stamp_ns, y.stamp_ns);
        assert_eq!(
            x.joints.as_ref().map(|j| &j.positions),
            y.joints.as_ref().map(|j| &j.positions)
        );
        let diff: f32 = x
            .image
            .data()
            .iter()
            .zip(y.image.data())
            .map(|(p, q)| (p - q).abs())
            .sum::<f32>()
            / x.image.data().len() as f32;
        assert!(diff < 3.0, "frame {}: mean gray difference {diff}", x.index);
    }
    // 8-bit images only, and quality within 1..=100.
    assert!(!jpeg("0", &dir.path().join("x.mcap")).status.success());
}
