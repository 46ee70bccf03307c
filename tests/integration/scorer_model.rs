//! The scorer with a real ONNX flow predictor (the committed test bundle): warm-up, `e_o`,
//! the offset overrides, heatmaps and determinism.

use std::path::PathBuf;
use std::sync::Arc;
use vamos::eval::Thresholds;
use vamos::model::{FlowModel, LoadOptions};
use vamos::pipeline::{FrameInput, FrameScore, PipelineConfig, Scorer, ScorerParts};
use vamos::robot::render::RenderConfig;
use vamos::vision::GrayImage;
use vamos::vision::flow::FlowParams;
use vamos::vision::preprocess::NetworkInputParams;
use vamos::vision::registration::RegistrationParams;
use vamos::vision::synthetic::Texture;

fn model() -> Arc<FlowModel> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model/valid.vamos");
    Arc::new(FlowModel::load(&path, &LoadOptions::default()).unwrap())
}

/// 128x96 processing under the paper's fusion (the score is `e_o` below the `e_c`/`e_b`
/// thresholds), with the past offsets `A, B` when given.
fn config(offsets: Option<(usize, usize)>) -> PipelineConfig {
    let mut config = PipelineConfig {
        fusion: vamos::eval::Fusion::Paper,
        ..PipelineConfig::default()
    };
    config.frames.width = 128;
    config.frames.height = 96;
    if let Some((a, b)) = offsets {
        config.offset_a = Some(a);
        config.offset_b = Some(b);
    }
    config
}

fn scorer(offsets: Option<(usize, usize)>, seed: u64) -> Scorer {
    Scorer::new(parts(config(offsets), seed)).unwrap()
}

/// A scorer's parts with the test model, no robot, realtime TV-L1 and heatmaps.
fn parts(config: PipelineConfig, seed: u64) -> ScorerParts {
    ScorerParts {
        config,
        flow: FlowParams::realtime(),
        registration: RegistrationParams::default(),
        network: NetworkInputParams::default(),
        render: RenderConfig::default(),
        robot: None,
        model: Some(model()),
        samples: 0,
        seed,
        thresholds: Thresholds::default(),
        alarm_threshold: f64::INFINITY,
        heatmaps: true,
    }
}

/// A texture drifting right by 1.5 px per frame, with a wobble down.
fn run(s: &mut Scorer, frames: usize) -> Vec<FrameScore> {
    let texture = Texture::random(5);
    (0..frames)
        .map(|k| {
            let (sx, sy) = (1.5 * k as f64, (k as f64 * 0.7).sin());
            let image = GrayImage::from_fn(128, 96, |x, y| {
                texture.eval(x as f64 - sx, y as f64 - sy) as f32
            });
            s.push(&FrameInput {
                stamp_ns: 1_000 + k as i64 * 100_000_000,
                image: &image,
                joints: None,
                intrinsics: None,
                depth: None,
            })
            .unwrap()
            .unwrap()
        })
        .collect()
}

#[test]
fn warm_up_lasts_a_plus_b_flow_frames_then_e_o_is_the_score() {
    // The bundle: A = 2, B = 2, M = 3. Processed frame 0 has no flow; frames 1.. feed the
    // predictor, which has A + B = 4 frames of history from frame 5 on.
    let mut s = scorer(None, 7);
    assert!(s.active().flow);
    let p = s.predictor_params().unwrap();
    assert_eq!((p.a, p.b, p.samples), (2, 2, 3));
    let scores = run(&mut s, 9);
    for f in &scores[..5] {
        assert!(f.warming_up, "frame {}", f.frame);
        assert_eq!(f.values[vamos::eval::Detector::Flow], None);
        assert_eq!(f.score, 0.0);
    }
    for f in &scores[5..] {
        assert!(!f.warming_up);
        let e_o = f.values[vamos::eval::Detector::Flow].unwrap();
        assert!(e_o.is_finite() && e_o > 0.0, "{e_o}");
        assert_eq!(f.score, e_o, "no thresholds: the score is e_o");
        assert!((2..=4).contains(&f.best_offset.unwrap()));
        let map = f.heatmap.as_ref().unwrap();
        assert_eq!(map.len(), 64 * 64);
        let mean = map.iter().map(|&v| f64::from(v)).sum::<f64>() / map.len() as f64;
        assert!((mean - e_o).abs() < 1e-5 * e_o.max(1.0), "{mean} vs {e_o}");
        assert!(!f.anomaly);
        assert!(f.timings.model_us > 0 && f.timings.total_us >= f.timings.model_us);
    }
    // Same seed, same scores; another seed draws other samples.
    let again = run(&mut scorer(None, 7), 9);
    let other = run(&mut scorer(None, 8), 9);
    assert_eq!(
        scores
            .iter()
            .map(|f| f.values[vamos::eval::Detector::Flow])
            .collect::<Vec<_>>(),
        again
            .iter()
            .map(|f| f.values[vamos::eval::Detector::Flow])
            .collect::<Vec<_>>()
    );
    assert_ne!(
        scores
            .iter()
            .map(|f| f.values[vamos::eval::Detector::Flow])
            .collect::<Vec<_>>(),
        other
            .iter()
            .map(|f| f.values[vamos::eval::Detector::Flow])
            .collect::<Vec<_>>()
    );
}

#[test]
fn offsets_from_the_pipeline_config_override_the_bundle() {
    let mut s = scorer(Some((1, 0)), 7);
    let p = s.predictor_params().unwrap();
    assert_eq!((p.a, p.b), (1, 0));
    let scores = run(&mut s, 4);
    assert!(scores[1].warming_up, "frame 1 has no history");
    assert!(!scores[2].warming_up);
    assert_eq!(scores[2].best_offset, Some(1));
    assert_eq!(scores[3].best_offset, Some(1));
}

/// M per past offset: the bundle's (3) unless `[model] samples` (the parts' `samples`)
/// sets it, and the pipeline's `samples` above both; 0 means the bundle's at either level.
#[test]
fn samples_from_the_pipeline_config_override_the_settings_and_the_bundle() {
    let m = |pipeline: Option<usize>, settings: usize| {
        let mut config = config(None);
        config.samples = pipeline;
        let mut parts = parts(config, 7);
        parts.samples = settings;
        parts.heatmaps = false;
        let s = Scorer::new(parts).unwrap();
        s.predictor_params().unwrap().samples
    };
    assert_eq!(m(None, 0), 3, "the bundle's temporal.m");
    assert_eq!(m(None, 4), 4, "[model] samples");
    assert_eq!(m(Some(5), 4), 5, "the pipeline's beats [model]");
    assert_eq!(m(Some(5), 0), 5);
    assert_eq!(m(Some(0), 4), 3, "0: the bundle's");
}

/// A profile's `[pipeline] samples` reaches the scorers `Setup` makes, over the settings'
/// `[model] samples`; one above the limit is refused by the store's check.
#[test]
fn a_profile_sets_the_prior_samples() {
    let dir = tempfile::tempdir().unwrap();
    let bundle = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model/valid.vamos");
    let path = dir.path().join("p.toml");
    let write = |pipeline: &str| {
        std::fs::write(
            &path,
            format!(
                "name = \"p\"\nmodel = {:?}\n[pipeline]\nstride = 1\n{pipeline}\
                 [pipeline.frames]\nwidth = 128\nheight = 96\nvariant = \"plain\"\n",
                bundle.display().to_string()
            ),
        )
        .unwrap();
    };
    let mut settings = vamos::config::Settings::default();
    settings.model.samples = 7;
    let samples = |settings: &vamos::config::Settings| {
        let setup = vamos::setup::Setup::load(settings, &path).unwrap();
        let scorer = setup.calibrated_scorer("episode", false).unwrap();
        scorer.predictor_params().unwrap().samples
    };
    write("samples = 2\n");
    assert_eq!(samples(&settings), 2);
    write("");
    assert_eq!(samples(&settings), 7, "absent: [model] samples");
    let config = PipelineConfig {
        samples: Some(vamos::model::predictor::MAX_SAMPLES + 1),
        ..PipelineConfig::default()
    };
    let e = config.check_limits().unwrap_err();
    assert!(e.contains("samples"), "{e}");
}
