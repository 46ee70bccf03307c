//! `vamos eval`: frame-level AUCs, episode false alarms and detection delays on labelled
//! episodes, plots, and the paper's ablation table.

use super::score::{ScoreAll, Setup, expand_episodes};
use anyhow::{Context, Result, bail};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vamos::config::Settings;
use vamos::eval::plot::{PlotOptions, plot_episode, plot_pr, plot_roc};
use vamos::eval::{AblationTable, AucPair, FusionLevel};
use vamos::eval::{
    ScoredFrame, Thresholds, average_precision, evaluate, fuse, pr_curve, roc_auc, roc_curve,
};
use vamos::model::FlowModel;
use vamos::pipeline::FlowVariant;
use vamos::pipeline::offline::EpisodeScores;

/// Options of `vamos eval`.
pub struct EvalOptions {
    /// The profile (calibrated for thresholds and the alarm threshold).
    pub profile: PathBuf,
    /// Labelled episodes (files or folders).
    pub episodes: Vec<PathBuf>,
    /// Write the report as JSON here.
    pub json: Option<PathBuf>,
    /// Write plots (per-episode timelines, ROC, PR) into this folder.
    pub plots: Option<PathBuf>,
    /// Run the ablation table; markdown goes here.
    pub ablation: Option<PathBuf>,
    /// Models per flow variant for the ablation (`variant=path`).
    pub variant_models: Vec<String>,
}

/// The frames of scored episodes with their labels.
pub fn labelled_frames(results: &[EpisodeScores]) -> Result<Vec<ScoredFrame>> {
    let mut frames = Vec::new();
    for e in results {
        let Some(labels) = &e.labels else {
            bail!(
                "episode {} has no labels (<episode>.labels.json or a label topic)",
                e.name
            );
        };
        for f in &e.frames {
            frames.push(ScoredFrame {
                episode: e.name.clone(),
                stamp_ns: f.stamp_ns,
                score: f.score,
                anomalous: labels.is_anomalous(f.stamp_ns),
                anomaly_type: labels.anomaly_type.clone(),
                warming_up: f.warming_up,
            });
        }
    }
    Ok(frames)
}

/// Runs the evaluation; prints the report as JSON on stdout.
pub fn run(settings: &Settings, opts: EvalOptions) -> Result<()> {
    let setup = Setup::load(settings, &opts.profile)?;
    let episodes = expand_episodes(&opts.episodes)?;
    let thresholds = setup.profile.thresholds();
    let alarm = setup.profile.alarm_threshold();
    if setup.profile.calibration.is_none() {
        eprintln!(
            "note: profile {} is not calibrated: no e_c/e_b thresholds, no alarm threshold",
            setup.profile.path.display()
        );
    }
    let results = setup.score_all(&episodes, thresholds, alarm, None, None, None)?;
    let frames = labelled_frames(&results)?;
    let report = evaluate(&frames, alarm);
    let text = serde_json::to_string_pretty(&report)?;
    println!("{text}");
    if let Some(path) = &opts.json {
        std::fs::write(path, text + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(dir) = &opts.plots {
        write_plots(dir, &results, &frames, alarm)?;
        eprintln!("plots in {}", dir.display());
    }
    if let Some(out) = &opts.ablation {
        let table = ablation(&setup, &episodes, &opts.variant_models)?;
        let md = table.to_markdown();
        std::fs::write(out, &md).with_context(|| format!("cannot write {}", out.display()))?;
        eprintln!("{md}\nablation table written to {}", out.display());
    }
    Ok(())
}

fn write_plots(
    dir: &Path,
    results: &[EpisodeScores],
    frames: &[ScoredFrame],
    alarm: f64,
) -> Result<()> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let options = PlotOptions {
        log_y: true,
        ..PlotOptions::default()
    };
    let threshold = alarm.is_finite().then_some(alarm);
    for e in results {
        let Some(t0) = e.frames.first().map(|f| f.stamp_ns) else {
            continue;
        };
        let s = |ns: i64| (ns - t0) as f64 / 1e9;
        let stamps: Vec<f64> = e.frames.iter().map(|f| s(f.stamp_ns)).collect();
        let scores: Vec<f64> = e.frames.iter().map(|f| f.score).collect();
        let intervals: Vec<(f64, f64)> = e
            .labels
            .as_ref()
            .map(|l| l.intervals_ns.iter().map(|[a, b]| (s(*a), s(*b))).collect())
            .unwrap_or_default();
        plot_episode(
            &dir.join(format!("{}.png", e.name)),
            &e.name,
            &stamps,
            &scores,
            &intervals,
            threshold,
            &options,
        )?;
    }
    let scores: Vec<f64> = frames.iter().map(|f| f.score).collect();
    let labels: Vec<bool> = frames.iter().map(|f| f.anomalous).collect();
    if let (Some(roc), Some(pr)) = (roc_curve(&scores, &labels), pr_curve(&scores, &labels)) {
        let options = PlotOptions::default();
        plot_roc(
            &dir.join("roc.png"),
            &[("all frames", &roc, roc_auc(&scores, &labels))],
            &options,
        )?;
        plot_pr(
            &dir.join("pr.png"),
            &[("all frames", &pr, average_precision(&scores, &labels))],
            &options,
        )?;
    }
    Ok(())
}

/// The paper's table: per flow variant one pipeline run (its own model), then the three
/// detector combinations fused from the same per-frame errors with the profile's
/// calibrated thresholds.
fn ablation(
    setup: &Setup,
    episodes: &[PathBuf],
    variant_models: &[String],
) -> Result<AblationTable> {
    let calibrated = setup.profile.thresholds();
    let mut models: BTreeMap<String, Arc<FlowModel>> = BTreeMap::new();
    for spec in variant_models {
        let Some((name, path)) = spec.split_once('=') else {
            bail!("--variant-model takes VARIANT=PATH, got {spec:?}");
        };
        let variant: FlowVariant = name.parse()?;
        let model = FlowModel::load(Path::new(path), &setup.settings.model.load_options())
            .with_context(|| format!("cannot load model {path}"))?;
        models.insert(variant.name().to_string(), Arc::new(model));
    }
    if let Some(m) = &setup.model {
        let name = serde_json::to_value(m.manifest().flow_variant)?
            .as_str()
            .unwrap_or_default()
            .to_string();
        models.entry(name).or_insert_with(|| m.clone());
    }
    let mut table = AblationTable::new();
    for variant in FlowVariant::ALL {
        let Some(model) = models.get(variant.name()) else {
            eprintln!("ablation: no model for flow variant {variant}; row left out");
            continue;
        };
        let mut config = setup.config.clone();
        config.frames.variant = variant;
        config.detectors.flow = true;
        eprintln!("ablation: flow variant {variant}");
        let results = setup.score_all(
            episodes,
            Thresholds::default(),
            f64::INFINITY,
            Some(&config),
            Some(model),
            None,
        )?;
        let frames = labelled_frames(&results)?;
        let labels: Vec<bool> = frames.iter().map(|f| f.anomalous).collect();
        let components: Vec<_> = results.iter().flat_map(|e| &e.frames).collect();
        for level in FusionLevel::ALL {
            let th = match level {
                FusionLevel::FlowOnly => Thresholds::default(),
                FusionLevel::FlowBody => Thresholds {
                    e_c: None,
                    e_b: calibrated.e_b,
                },
                FusionLevel::FlowBodyCamera => calibrated,
            };
            let scores: Vec<f64> = components
                .iter()
                .map(|f| fuse(f.e_c, f.e_b, f.e_o, &th).score)
                .collect();
            table.set(
                &variant_label(variant),
                level,
                AucPair {
                    auc_roc: roc_auc(&scores, &labels),
                    auc_pr: average_precision(&scores, &labels),
                },
            );
        }
    }
    Ok(table.with_paper_reference())
}

fn variant_label(v: FlowVariant) -> String {
    match v {
        FlowVariant::MaskedRegistered => "masked + registered".into(),
        other => other.name().into(),
    }
}
