//! Offline scoring of damaged and unusual bags (tests/fixtures/episode, written by the
//! official Python MCAP writer): every valid frame is scored, every refused one is
//! reported with its index, nothing panics.

use std::path::PathBuf;
use vamos::episode::{EpisodeConfig, McapEpisode};
use vamos::eval::Thresholds;
use vamos::pipeline::offline::{EpisodeScores, score_episode};
use vamos::pipeline::{PipelineConfig, Scorer, ScorerParts};
use vamos::robot::render::RenderConfig;
use vamos::vision::flow::FlowParams;
use vamos::vision::preprocess::NetworkInputParams;
use vamos::vision::registration::RegistrationParams;

fn score(file: &str) -> EpisodeScores {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/episode")
        .join(file);
    let episode = McapEpisode::open(&path, &EpisodeConfig::default()).unwrap();
    let mut config = PipelineConfig::default();
    config.frames.width = 64;
    config.frames.height = 48;
    let mut scorer = Scorer::new(ScorerParts {
        config,
        flow: FlowParams::realtime(),
        registration: RegistrationParams::default(),
        network: NetworkInputParams::default(),
        render: RenderConfig::default(),
        robot: None,
        model: None,
        samples: 0,
        seed: 0,
        thresholds: Thresholds::default(),
        alarm_threshold: f64::INFINITY,
        heatmaps: false,
    })
    .unwrap();
    let mut seen = 0usize;
    let out = score_episode::<vamos::episode::EpisodeError>(&mut scorer, &episode, |frame, s| {
        assert_eq!(frame.stamp_ns, s.stamp_ns);
        seen += 1;
        Ok(())
    })
    .unwrap();
    assert_eq!(seen, out.frames.len(), "the sink sees every scored frame");
    out
}

fn indices(s: &EpisodeScores) -> Vec<Option<usize>> {
    s.frame_errors.iter().map(|e| e.index).collect()
}

#[test]
fn a_clean_bag_scores_every_image_in_stamp_order() {
    let s = score("rgb8_zstd.mcap");
    assert_eq!(s.frames.len(), 20);
    assert!(s.frame_errors.is_empty() && s.damage.is_none() && !s.no_joint_states);
    assert!(s.frames.windows(2).all(|w| w[0].stamp_ns < w[1].stamp_ns));
    assert_eq!(s.labels.as_ref().unwrap().episode, "rgb8_zstd");
}

#[test]
fn size_changes_and_unknown_encodings_are_reported_and_skipped() {
    let s = score("size_change.mcap");
    assert_eq!(s.frames.len(), 18);
    assert_eq!(indices(&s), vec![Some(10), Some(11)]);
    assert!(
        s.frame_errors[0].message.contains("10"),
        "{:?}",
        s.frame_errors
    );
    let s = score("unknown_encoding.mcap");
    assert_eq!(s.frames.len(), 19);
    assert_eq!(indices(&s), vec![Some(4)]);
    assert!(s.frame_errors[0].message.contains("encoding"));
}

#[test]
fn a_truncated_bag_is_scored_up_to_the_damage() {
    let s = score("truncated.mcap");
    let damage = s.damage.as_deref().unwrap();
    assert!(damage.contains("truncated"), "{damage}");
    // The generator cut the file inside the chunk after at least 12 complete images.
    assert!(s.frames.len() >= 12, "{}", s.frames.len());
    assert!(s.frames.len() < 20);
}

#[test]
fn backwards_stamps_are_skipped_and_missing_joints_said() {
    let s = score("backwards.mcap");
    assert_eq!(
        s.frames.len(),
        18,
        "the two images going back in time are skipped"
    );
    assert_eq!(s.info.as_ref().unwrap().skipped_backwards, 2);
    let s = score("no_joints.mcap");
    assert!(s.no_joint_states);
    assert_eq!(s.frames.len(), 20);
    assert!(
        s.frames
            .iter()
            .all(|f| f.values[vamos::eval::Detector::Camera].is_none()
                && f.values[vamos::eval::Detector::Body].is_none())
    );
}
