//! Calibration and revision: thresholds from nominal episodes, conformal reporting, the
//! revision that learns nominal episodes (their scores and robot states).

use super::*;
use crate::eval::{Fusion, NominalScales, StateReference};
use crate::pipeline::scorer::StageTimings;

/// An episode of frames with these `e_c` values and nothing else.
fn episode(name: &str, e_c: &[f64]) -> EpisodeScores {
    let frames = e_c
        .iter()
        .enumerate()
        .map(|(i, &e)| FrameScore {
            index: i as u64,
            frame: i as u64,
            stamp_ns: i as i64 * 100_000_000,
            score: 0.0,
            values: crate::eval::DetectorValues::of(&[
                (Detector::Camera, e),
                (Detector::Flow, 0.01),
            ]),
            anomaly: false,
            triggered: None,
            warming_up: false,
            best_offset: None,
            registration_confidence: None,
            body_pixels: 0,
            timings: StageTimings::default(),
            heatmap: None,
            scene_cells: None,
            phase_s: 0.0,
            scene_grid: (0, 0),
            flow_cells: None,
            flow_grid: (0, 0),
            kinematic_state: None,
            depth_evidence: None,
        })
        .collect();
    EpisodeScores {
        name: name.into(),
        frames,
        frame_errors: Vec::new(),
        damage: None,
        no_joint_states: false,
        joint_gaps: Vec::new(),
        labels: None,
        info: None,
    }
}

/// Held-out nominal runs past the training maximum of `e_c` put the paper-fusion
/// conformal threshold above 1e6, where `e_o` can never alarm: calibration says so.
#[test]
fn a_conformal_threshold_above_the_trigger_base_is_reported() {
    let pipeline = PipelineConfig {
        fusion: Fusion::Paper,
        ..PipelineConfig::default()
    };
    let run = |held_e_c: f64| {
        calibrate(
            &[PathBuf::from("train.mcap")],
            &[PathBuf::from("a.mcap"), PathBuf::from("b.mcap")],
            0.5,
            Some("sha".into()),
            &pipeline,
            |paths, t: Thresholds| -> Result<Vec<EpisodeScores>, String> {
                Ok(paths
                    .iter()
                    .map(|p| {
                        let mut e = episode(&stem(p), &[1.0, 2.0, held_e_c.min(2.0)]);
                        if t.e_c.is_some() {
                            // Held-out: scored with the thresholds, as the scorer does.
                            e = scored(episode(&stem(p), &[1.0, held_e_c]), &t);
                        }
                        e
                    })
                    .collect())
            },
        )
        .unwrap()
    };
    let above = run(3.0);
    let c = above.calibration.conformal.as_ref().unwrap();
    assert!(c.threshold >= TRIGGER_BASE, "{}", c.threshold);
    assert!(
        above.notes.iter().any(|n| n.contains("can ever alarm")),
        "{:?}",
        above.notes
    );
    let below = run(1.5);
    assert!(below.calibration.conformal.unwrap().threshold < TRIGGER_BASE);
    assert!(!below.notes.iter().any(|n| n.contains("can ever alarm")));
}

/// Too few held-out episodes for alpha, or none: no conformal threshold, and the notes
/// say how many were given, how many alpha needs, and that alarms use the training
/// maximum (its value).
#[test]
fn the_fallback_to_the_training_maximum_is_noted_with_the_numbers() {
    let pipeline = PipelineConfig {
        fusion: Fusion::Paper,
        ..PipelineConfig::default()
    };
    let run = |holdout: &[PathBuf], alpha: f64| {
        calibrate(
            &[PathBuf::from("train.mcap")],
            holdout,
            alpha,
            Some("sha".into()),
            &pipeline,
            |paths, t: Thresholds| -> Result<Vec<EpisodeScores>, String> {
                Ok(paths
                    .iter()
                    .map(|p| scored(episode(&stem(p), &[1.0, 2.0]), &t))
                    .collect())
            },
        )
        .unwrap()
    };
    let two = [PathBuf::from("a.mcap"), PathBuf::from("b.mcap")];
    let few = run(&two, 0.1);
    assert!(few.calibration.conformal.is_none());
    let max = format!("{:.6}", few.calibration.score_max);
    assert!(
        few.notes
            .iter()
            .any(|n| n.contains("2 held-out episodes given")
                && n.contains("alpha 0.1 needs at least 9")
                && n.contains(&format!("training maximum of the fused score ({max})"))),
        "{:?}",
        few.notes
    );
    let none = run(&[], 0.05);
    assert!(none.calibration.conformal.is_none());
    assert!(
        none.notes
            .iter()
            .any(|n| n.starts_with("no held-out episodes")
                && n.contains("training maximum")
                && n.contains("alpha 0.05 needs at least 19")),
        "{:?}",
        none.notes
    );
    // Enough for alpha 0.5: a conformal threshold, no fallback note.
    let enough = run(&two, 0.5);
    assert!(enough.calibration.conformal.is_some());
    assert!(
        !enough.notes.iter().any(|n| n.contains("training maximum")),
        "{:?}",
        enough.notes
    );
}

/// Frames fused as the scorer fuses them under paper fusion with `t`.
fn scored(mut e: EpisodeScores, t: &Thresholds) -> EpisodeScores {
    for f in &mut e.frames {
        let mut c = DetectorValues::default();
        c[Detector::Camera] = f.values[Detector::Camera];
        c[Detector::Flow] = f.values[Detector::Flow];
        f.score = fuse_frame(&c, t, Fusion::Paper).score;
    }
    e
}

#[test]
fn a_revision_takes_the_nominal_episodes_in_and_leaves_no_frame_of_them_alarming() {
    let pipeline = PipelineConfig {
        fusion: Fusion::Paper,
        ..PipelineConfig::default()
    };
    let conformal = conformal_threshold(&[0.01, 0.02, 0.03], 0.5).unwrap();
    assert_eq!(conformal.episode_maxima, vec![0.01, 0.02, 0.03]);
    let current = Calibration {
        created_unix_s: 1,
        model_sha256: Some("sha".into()),
        training_episodes: vec!["t".into()],
        calibration_episodes: vec!["a".into(), "b".into(), "c".into()],
        training_frames: 3,
        thresholds: Thresholds::paper(Some(2.0), None),
        score_max: 0.02,
        conformal: Some(conformal),
    };
    // A run whose e_c passed the threshold (a false alarm of the camera detector).
    let run = scored(episode("run", &[1.0, 2.5, 1.5]), &current.thresholds);
    assert!(run.frames[1].score >= TRIGGER_BASE);
    let r = revise(&current, &pipeline, true, std::slice::from_ref(&run));
    let t = r.calibration.thresholds.e_c.unwrap();
    assert_eq!(t, 2.5f64.next_up());
    assert_eq!(r.episodes.len(), 1);
    let (name, before, after) = &r.episodes[0];
    assert_eq!((name.as_str(), *before), ("run", run.frames[1].score));
    assert_eq!(*after, 0.01, "no frame triggers now: the score is e_o");
    // Conformal over the kept maxima and the run's: n = 4, alpha 0.5, k = 3.
    let c = r.calibration.conformal.as_ref().unwrap();
    assert_eq!((c.n, c.rank_k, c.order_statistic), (4, 3, 0.02));
    assert!(r.calibration.score_max >= 0.02);
    assert!(r.calibration.created_unix_s > 1);
    assert_eq!(r.calibration.calibration_episodes.len(), 4);
    // Re-fused with the revision, none of the run's frames reaches the new threshold.
    let again = scored(episode("run", &[1.0, 2.5, 1.5]), &r.calibration.thresholds);
    assert!(again.frames.iter().all(|f| f.score < c.threshold));
    // A calibration that kept no maxima: the threshold is raised above the run.
    let mut old = current.clone();
    if let Some(c) = old.conformal.as_mut() {
        c.episode_maxima.clear();
    }
    let high = scored(episode("run", &[1.0, 1.9]), &old.thresholds);
    let mut hot = high.clone();
    for f in &mut hot.frames {
        f.values[Detector::Flow] = Some(0.5);
        f.score = 0.5;
    }
    let r = revise(&old, &pipeline, true, &[hot]);
    let c = r.calibration.conformal.unwrap();
    assert_eq!(c.threshold, 0.5f64.next_up());
    assert!(
        r.notes.iter().any(|n| n.contains("no longer holds")),
        "{:?}",
        r.notes
    );
    assert_eq!(r.calibration.score_max, 0.5);
}

#[test]
fn a_revision_learns_the_robot_states_of_the_nominal_episodes() {
    let pipeline = PipelineConfig {
        fusion: Fusion::Calibrated,
        ..PipelineConfig::default()
    };
    let line = |y: f32| -> Vec<Vec<f32>> { (0..10).map(|i| vec![i as f32 * 0.1, y]).collect() };
    let reference = StateReference::fit(&[line(0.0)], 2, None).unwrap();
    let mut scales = NominalScales::default();
    scales[Detector::Kinematics] = Some(crate::eval::Scale {
        location: 0.0,
        spread: 0.1,
    });
    let current = Calibration {
        created_unix_s: 1,
        model_sha256: None,
        training_episodes: vec!["t".into()],
        calibration_episodes: vec![],
        training_frames: 10,
        thresholds: Thresholds {
            scales: Some(scales),
            kinematics: Some(reference.clone()),
            ..Thresholds::default()
        },
        score_max: 1.0,
        conformal: None,
    };
    // Two runs 0.5 away from every training state: e_k 0.5, calibrated score 5.
    let run = |name: &str, y: f32| {
        let mut e = episode(name, &[0.0; 10]);
        for (f, s) in e.frames.iter_mut().zip(line(y)) {
            f.values[Detector::Kinematics] = reference.distance(&s);
            f.kinematic_state = Some(s);
            f.score = fuse_frame(
                &DetectorValues::from_fn(|d| f.values[d].filter(|_| d == Detector::Kinematics)),
                &current.thresholds,
                Fusion::Calibrated,
            )
            .score;
        }
        e
    };
    let runs = [run("a", 0.5), run("b", 0.52)];
    assert!((episode_max(&runs[0]) - 5.0).abs() < 1e-3);
    let r = revise(&current, &pipeline, false, &runs);
    // Each run against the training states and the other run: 0.02 away, score 0.2.
    for (name, before, after) in &r.episodes {
        assert!(*before > 4.9, "{name}: {before}");
        assert!((after - 0.2).abs() < 1e-3, "{name}: {after}");
    }
    assert_eq!(
        r.calibration.score_max, 1.0,
        "nothing above the training maximum"
    );
    let learned = r.calibration.thresholds.kinematics.as_ref().unwrap();
    assert_eq!(learned.len(), 30);
    assert!(learned.distance(&[0.3, 0.52]).unwrap() < 1e-4);
    assert!(
        r.notes.iter().any(|n| n.contains("10 -> 30")),
        "{:?}",
        r.notes
    );
}

#[test]
fn held_out_episodes_beyond_the_maximum() {
    for alpha in [0.05, 0.1, 0.2, 0.3] {
        let n = episodes_beyond_max(alpha);
        let scores = |n: usize| (0..n).map(|i| i as f64).collect::<Vec<_>>();
        let at = conformal_threshold(&scores(n), alpha).unwrap();
        assert!(at.rank_k < at.n, "alpha {alpha}: {n} episodes");
        if let Ok(below) = conformal_threshold(&scores(n - 1), alpha) {
            assert_eq!(below.rank_k, below.n, "alpha {alpha}: {} episodes", n - 1);
        }
    }
    assert_eq!(episodes_beyond_max(0.2), 9);
}

/// With `learn_depth`, the training episodes are scored, the depth learned from their
/// evidence, and scored again with it; the calibration keeps it. Without the scene
/// detector there is nothing to learn from, and the note says why.
#[test]
fn learn_depth_scores_the_training_episodes_again_with_the_learned_depth() {
    use crate::eval::depth::DepthEvidence;
    let calibrate_with = |pipeline: &PipelineConfig| {
        let mut passes: Vec<bool> = Vec::new();
        let outcome = calibrate(
            &[PathBuf::from("train.mcap")],
            &[],
            0.2,
            None,
            pipeline,
            |paths, t: Thresholds| -> Result<Vec<EpisodeScores>, String> {
                passes.push(t.depth.is_some());
                Ok(paths
                    .iter()
                    .map(|p| {
                        let mut e = episode(&stem(p), &[1.0, 2.0, 1.5, 1.0]);
                        // A camera that translates in front of a wall at 0.5 m.
                        for (i, f) in e.frames.iter_mut().enumerate() {
                            f.depth_evidence = Some(DepthEvidence {
                                camera_from_base: nalgebra::Isometry3::translation(
                                    0.01 * i as f64,
                                    0.0,
                                    0.0,
                                ),
                                cell_rad: 0.05,
                                cells: vec![[2.0, 1.0]; 16 * 12],
                            });
                        }
                        e
                    })
                    .collect())
            },
        )
        .unwrap();
        (outcome, passes)
    };
    let mut pipeline = PipelineConfig::default();
    pipeline.camera_motion.learn_depth = true;
    let (outcome, passes) = calibrate_with(&pipeline);
    assert_eq!(passes, [false, true], "scored without, then with the depth");
    let noted = |outcome: &CalibrationOutcome, text: &str| {
        assert!(
            outcome.notes.iter().any(|n| n.contains(text)),
            "{text}: {:?}",
            outcome.notes
        );
    };
    noted(&outcome, "learned the static scene's depth");
    let depth = outcome.calibration.thresholds.depth.expect("learned");
    assert_eq!(depth.summary().0, 0.5);
    pipeline.detectors.scene = false;
    let (outcome, passes) = calibrate_with(&pipeline);
    assert_eq!(passes, [false]);
    assert!(outcome.calibration.thresholds.depth.is_none());
    noted(&outcome, "needs the scene detector");
    pipeline.camera_motion.learn_depth = false;
    pipeline.detectors.scene = true;
    let (outcome, passes) = calibrate_with(&pipeline);
    assert_eq!(passes, [false], "off: one pass");
    assert!(outcome.calibration.thresholds.depth.is_none());
}
