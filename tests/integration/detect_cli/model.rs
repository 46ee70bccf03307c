//! With the flow predictor: the ablation table and every score topic of a scored bag.

use super::*;

/// `vamos eval --ablation` end to end: one row per flow variant in the paper's order; the
/// variants given a model (`--variant-model`) are scored with it and show AUC pairs in
/// [0, 1] beside the paper's; the others are kept and marked "no model".
#[test]
fn eval_ablation_writes_a_row_per_variant() {
    let ws = workspace();
    let dir = ws.path();
    write_calibration(dir, "profile", 0.5, 0.5, 2e6, None);
    let model = tiny_model();
    let (stdout, stderr) = vamos(
        dir,
        &[
            "eval",
            "--profile",
            "profile.toml",
            "--episodes",
            "test",
            "--ablation",
            "ablation.md",
            "--variant-model",
            &format!("masked={model}"),
            "--variant-model",
            &format!("plain={model}"),
            "--no-progress",
        ],
    );
    let report: Value = serde_json::from_str(&stdout).unwrap();
    assert!(report["anomalous_frames"].as_u64().unwrap() > 0);
    let md = std::fs::read_to_string(dir.join("ablation.md")).unwrap();
    let lines: Vec<&str> = md.lines().collect();
    assert_eq!(lines.len(), 6, "{md}");
    assert_eq!(
        cells(lines[0]),
        [
            "input flow variant",
            "OF only",
            "OF + body",
            "OF + body + camera"
        ]
    );
    assert_eq!(lines[1], "|---|---|---|---|");
    let rows: Vec<Vec<String>> = lines[2..].iter().map(|l| cells(l)).collect();
    assert_eq!(
        rows.iter().map(|r| r[0].as_str()).collect::<Vec<_>>(),
        ["plain", "registered", "masked", "masked + registered"]
    );
    for row in &rows {
        assert_eq!(row.len(), 4, "{row:?}");
    }
    for row in [&rows[0], &rows[2]] {
        for cell in &row[1..] {
            // "0.612 / 0.345 (paper 0.740 / 0.380)"
            let (ours, paper) = cell
                .split_once(" (paper ")
                .unwrap_or_else(|| panic!("{cell}"));
            assert!(paper.ends_with(')'), "{cell}");
            let (roc, pr) = ours.split_once(" / ").unwrap_or_else(|| panic!("{cell}"));
            for v in [roc, pr] {
                let v: f64 = v.parse().unwrap_or_else(|_| panic!("{cell}"));
                assert!((0.0..=1.0).contains(&v), "{cell}");
            }
        }
    }
    for row in [&rows[1], &rows[3]] {
        for cell in &row[1..] {
            assert!(cell.starts_with("no model (paper "), "{row:?}");
        }
    }
    assert!(
        stderr.contains("no model for flow variant registered"),
        "{stderr}"
    );
}

/// `vamos score --mcap` with a model: the scored bag holds the images, /vamos/score and
/// /vamos/anomaly for every frame, /vamos/e_c, /vamos/e_b and /vamos/e_o for every frame
/// that has them (Float64, the values of the JSON lines) and one /vamos/heatmap (a 64x64
/// rgb8 Image) per frame with e_o.
#[test]
fn score_mcap_with_a_model_writes_every_score_topic() {
    let ws = workspace();
    let dir = ws.path();
    write_model_profile(dir, "model");
    let (stdout, _) = vamos(
        dir,
        &[
            "score",
            "--profile",
            "model.toml",
            "test/test_0000.mcap",
            "-o",
            "out",
            "--mcap",
            "--no-progress",
        ],
    );
    let summary: Value = serde_json::from_str(stdout.trim()).unwrap();
    let frames = jsonl(&dir.join("out/test_0000.scores.jsonl"));
    let n = frames.len();
    assert_eq!(n as u64, summary["frames"].as_u64().unwrap());
    let values =
        |key: &str| -> Vec<f64> { frames.iter().filter_map(|f| f[key].as_f64()).collect() };
    let (e_c, e_b, e_o) = (values("e_c"), values("e_b"), values("e_o"));
    // Processed frame 0 has no flow, then A + B = 4 frames of history: e_o from frame 5.
    assert_eq!(e_o.len(), n - 5, "{n} frames");
    assert_eq!(e_c.len(), n - 1);
    assert!(!e_b.is_empty());

    let bag = McapEpisode::open(
        &dir.join("out/test_0000.scored.mcap"),
        &EpisodeConfig::default(),
    )
    .unwrap();
    let info = bag.info();
    let topic = |name: &str| info.topics.iter().find(|t| t.name == name).cloned();
    for (name, count, schema) in [
        ("/camera/image_raw", n, "sensor_msgs/msg/Image"),
        ("/vamos/score", n, "std_msgs/msg/Float64"),
        ("/vamos/anomaly", n, "std_msgs/msg/Bool"),
        ("/vamos/e_c", e_c.len(), "std_msgs/msg/Float64"),
        ("/vamos/e_b", e_b.len(), "std_msgs/msg/Float64"),
        ("/vamos/e_o", e_o.len(), "std_msgs/msg/Float64"),
        ("/vamos/heatmap", e_o.len(), "sensor_msgs/msg/Image"),
    ] {
        let t = topic(name).unwrap_or_else(|| panic!("no {name} in {:?}", info.topics));
        assert_eq!(
            (t.message_count, t.schema.as_str()),
            (count as u64, schema),
            "{name}"
        );
    }
    let (mut got_e_c, mut got_e_b, mut got_e_o, mut maps) = (vec![], vec![], vec![], 0);
    bag.for_each_message(
        &[
            "/vamos/e_c".into(),
            "/vamos/e_b".into(),
            "/vamos/e_o".into(),
            "/vamos/heatmap".into(),
        ],
        |topic, _, _, cdr| match topic {
            "/vamos/heatmap" => {
                let m = ImageMsg::decode(cdr).unwrap();
                assert_eq!((m.width, m.height, m.encoding.as_str()), (64, 64, "rgb8"));
                maps += 1;
            }
            "/vamos/e_c" => got_e_c.push(decode_f64(cdr).unwrap()),
            "/vamos/e_b" => got_e_b.push(decode_f64(cdr).unwrap()),
            _ => got_e_o.push(decode_f64(cdr).unwrap()),
        },
    )
    .unwrap();
    assert_eq!((got_e_c, got_e_b, got_e_o), (e_c, e_b, e_o.clone()));
    assert_eq!(maps, e_o.len());
}

/// `residual.flow_pooling = "cells"`: calibration fits per-cell statistics of the flow
/// predictor's error (one cell grid over the network's input) and `e_o` is then its worst
/// cells, normalised; a profile calibrated with the paper's mean keeps the mean (no cell
/// statistics in its calibration), so the two give different `e_o` on the same frames.
#[test]
fn flow_cells_are_calibrated_per_cell_and_pool_e_o() {
    let ws = workspace();
    let dir = ws.path();
    let model = tiny_model();
    let mut e_o = Vec::new();
    for pooling in ["mean", "cells"] {
        let profile = PROFILE
            .replace(
                "name = \"sim-arm\"",
                &format!("name = \"{pooling}\"\nmodel = \"{model}\""),
            )
            .replace("fusion = \"paper\"", "fusion = \"calibrated\"")
            + &format!("[pipeline.residual]\nflow_pooling = \"{pooling}\"\nflow_cell_px = 8\n");
        std::fs::write(dir.join(format!("{pooling}.toml")), profile).unwrap();
        vamos(
            dir,
            &[
                "calibrate",
                "--profile",
                &format!("{pooling}.toml"),
                "train",
                "--no-progress",
            ],
        );
        let cal: Value = serde_json::from_str(
            &std::fs::read_to_string(dir.join(format!("{pooling}.calibration.json"))).unwrap(),
        )
        .unwrap();
        let flow = &cal["thresholds"]["flow"];
        if pooling == "mean" {
            assert!(flow.is_null(), "{flow}");
        } else {
            // The tiny model's input is S x S: cells of 8 pixels, a (S/8) x (S/8) grid.
            let (columns, rows) = (
                flow["columns"].as_u64().unwrap(),
                flow["rows"].as_u64().unwrap(),
            );
            assert!(columns >= 2 && columns == rows, "{flow}");
            let n = (columns * rows) as usize;
            assert_eq!(flow["location"].as_array().unwrap().len(), n);
            assert!(flow["maps"].as_u64().unwrap() > 10, "{flow}");
        }
        let out = format!("scores-{pooling}");
        vamos(
            dir,
            &[
                "score",
                "--profile",
                &format!("{pooling}.toml"),
                "test/test_0000.mcap",
                "--out",
                &out,
            ],
        );
        let values: Vec<f64> = jsonl(&dir.join(&out).join("test_0000.scores.jsonl"))
            .iter()
            .filter_map(|v| v["e_o"].as_f64())
            .collect();
        assert!(values.len() > 10, "{values:?}");
        assert!(values.iter().all(|v| v.is_finite()));
        e_o.push(values);
    }
    assert_eq!(e_o[0].len(), e_o[1].len());
    assert_ne!(
        e_o[0], e_o[1],
        "the cells pool e_o differently from the mean"
    );
}
