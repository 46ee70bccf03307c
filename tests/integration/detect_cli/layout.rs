//! `vamos layout`: the Foxglove layout of a profile's scored bags shows topics those bags
//! have, and only the detectors that give values.

use super::*;

/// The topics of an MCAP file.
fn bag_topics(path: &Path) -> Vec<String> {
    let bytes = std::fs::read(path).unwrap();
    let summary = mcap::Summary::read(&bytes).unwrap().unwrap();
    let mut topics: Vec<String> = summary.channels.values().map(|c| c.topic.clone()).collect();
    topics.sort();
    topics
}

fn layout(dir: &Path, bag: &str) -> (Value, String) {
    let (stdout, stderr) = vamos(dir, &["layout", "--profile", "profile.toml", bag]);
    (serde_json::from_str(&stdout).unwrap(), stderr)
}

#[test]
fn the_layout_of_a_profile_shows_what_its_scored_bags_carry() {
    let ws = workspace();
    let dir = ws.path();
    let episode = "test/test_0001_external_push.mcap";
    // Not calibrated: no e_k (no nominal states), no anomaly map (no statistics, no model).
    let (before, stderr) = layout(dir, episode);
    let named = vamos::pipeline::layout::layout_topics(&before);
    assert!(stderr.contains("/camera/image_raw"), "{stderr}");
    for absent in ["/vamos/e_k", "/vamos/e_o", "/vamos/anomaly_map"] {
        assert!(!named.iter().any(|t| t == absent), "{absent}: {named:?}");
    }

    vamos(
        dir,
        &[
            "calibrate",
            "--profile",
            "profile.toml",
            "train",
            "--holdout",
            "test/test_0000.mcap",
            "--alpha",
            "0.5",
        ],
    );
    vamos(
        dir,
        &[
            "score",
            "--profile",
            "profile.toml",
            episode,
            "-o",
            "scored",
            "--mcap",
        ],
    );
    let scored = dir.join("scored/test_0001_external_push.scored.mcap");
    let in_bag = bag_topics(&scored);
    // From the input bag or the scored one: the same layout.
    let (from_input, _) = layout(dir, episode);
    let (from_scored, _) = layout(dir, scored.to_str().unwrap());
    assert_eq!(from_input, from_scored);
    let named = vamos::pipeline::layout::layout_topics(&from_scored);
    for expected in [
        "/camera/image_raw",
        "/camera/camera_info",
        "/vamos/score",
        "/vamos/anomaly_map",
        "/vamos/e_c",
        "/vamos/e_b",
        "/vamos/e_r",
        "/vamos/e_k",
    ] {
        assert!(named.iter().any(|t| t == expected), "{expected}: {named:?}");
    }
    let missing: Vec<_> = named.iter().filter(|t| !in_bag.contains(t)).collect();
    assert!(
        missing.is_empty(),
        "shown but not in the bag: {missing:?} ({in_bag:?})"
    );

    // --out writes the same document.
    vamos(
        dir,
        &[
            "layout",
            "--profile",
            "profile.toml",
            episode,
            "--out",
            "layout.json",
        ],
    );
    let written: Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("layout.json")).unwrap()).unwrap();
    assert_eq!(written, from_scored);
}
