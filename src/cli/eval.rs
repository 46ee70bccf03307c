//! `vamos eval`: frame-level AUCs, episode false alarms and detection delays on labelled
//! episodes, plots, and the paper's ablation table.

use super::progress::Progress;
use super::score::{ScoreAll, ScoreRun, Setup, expand_episodes};
use anyhow::{Context, Result, bail};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vamos::config::Settings;
use vamos::episode::Labels;
use vamos::eval::plot::{PlotOptions, plot_episode, plot_pr, plot_roc};
use vamos::eval::{AblationTable, AucPair, Detector, FusionLevel};
use vamos::eval::{
    RocPoint, ScoredFrame, Thresholds, average_precision, evaluate, frames_by_type, fuse, pr_curve,
    roc_auc, roc_curve,
};
use vamos::model::FlowModel;
use vamos::pipeline::FlowVariant;
use vamos::pipeline::offline::EpisodeScores;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The profile (calibrated).
    #[arg(long)]
    pub profile: PathBuf,
    /// Labelled episodes (.mcap with `<stem>.labels.json` or a label topic), files or
    /// folders.
    #[arg(long, required = true, num_args = 1..)]
    pub episodes: Vec<PathBuf>,
    /// Also write the report here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Write plots here: a score timeline per episode, roc.png, pr.png.
    #[arg(long)]
    pub plots: Option<PathBuf>,
    /// Run the paper's ablation (4 flow variants x OF only / +body / +body+camera) and
    /// write it as markdown here.
    #[arg(long)]
    pub ablation: Option<PathBuf>,
    /// A model per flow variant for the ablation, `VARIANT=PATH` (repeatable); the
    /// profile's model serves its own variant.
    #[arg(long)]
    pub variant_model: Vec<String>,
    /// No progress bars (they are drawn on stderr only when it is a terminal).
    #[arg(long)]
    pub no_progress: bool,
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
pub fn run(settings: &Settings, opts: Args) -> Result<()> {
    if let Some(path) = &opts.json {
        super::check_output_file("--json", path)?;
    }
    if let Some(path) = &opts.ablation {
        super::check_output_file("--ablation", path)?;
    }
    if let Some(dir) = &opts.plots {
        super::check_output_dir("--plots", dir)?;
    }
    let progress = Progress::new(opts.no_progress);
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
    let results = setup.score_all(
        &episodes,
        &ScoreRun::new("eval", thresholds, alarm, &progress),
    )?;
    let frames = labelled_frames(&results)?;
    let report = evaluate(&frames, alarm);
    let text = serde_json::to_string_pretty(&report)?;
    println!("{text}");
    if let Some(path) = &opts.json {
        std::fs::write(path, text + "\n")
            .with_context(|| format!("cannot write {}", path.display()))?;
    }
    if let Some(dir) = &opts.plots {
        write_plots(dir, &timelines(&results), &frames, alarm)?;
        let series: Vec<DetectorSeries<'_>> = results.iter().map(DetectorSeries::from).collect();
        write_detector_plots(
            dir,
            &series,
            &setup.detector_thresholds(),
            setup.profile.file.alarm_events.unwrap_or_default(),
        )?;
        eprintln!("plots in {}", dir.display());
    }
    if let Some(out) = &opts.ablation {
        let table = ablation(&setup, &episodes, &opts.variant_model, &progress)?;
        let md = table.to_markdown();
        std::fs::write(out, &md).with_context(|| format!("cannot write {}", out.display()))?;
        eprintln!("{md}\nablation table written to {}", out.display());
    }
    Ok(())
}

/// One frame's values for the detector plots and the first-alarm frame.
#[derive(Debug, Clone, Copy)]
pub struct DetectorPoint {
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Fused score.
    pub score: f64,
    /// Each detector's value.
    pub values: vamos::eval::DetectorValues,
    /// The flow predictor is still warming up.
    pub warming_up: bool,
    /// The frame is flagged (`score >= alarm threshold`).
    pub anomaly: bool,
}

impl From<&vamos::pipeline::FrameScore> for DetectorPoint {
    fn from(f: &vamos::pipeline::FrameScore) -> Self {
        Self {
            stamp_ns: f.stamp_ns,
            score: f.score,
            values: f.values,
            warming_up: f.warming_up,
            anomaly: f.anomaly,
        }
    }
}

impl From<&vamos::api::proto::FrameScore> for DetectorPoint {
    fn from(f: &vamos::api::proto::FrameScore) -> Self {
        Self {
            stamp_ns: f.stamp_ns,
            score: f.score,
            values: vamos::eval::DetectorValues::from_array([f.e_c, f.e_b, f.e_o, f.e_r, f.e_k]),
            warming_up: f.warming_up,
            anomaly: f.anomaly,
        }
    }
}

/// One episode's frames for [`write_detector_plots`], whatever scored them.
pub struct DetectorSeries<'a> {
    /// Episode name (the plot's file stem).
    pub name: &'a str,
    /// Its labels, if any.
    pub labels: Option<&'a Labels>,
    /// Its scored frames, in order.
    pub points: Vec<DetectorPoint>,
}

impl<'a> From<&'a EpisodeScores> for DetectorSeries<'a> {
    fn from(e: &'a EpisodeScores) -> Self {
        Self {
            name: &e.name,
            labels: e.labels.as_ref(),
            points: e.frames.iter().map(DetectorPoint::from).collect(),
        }
    }
}

/// Index of the frame where the first alarm starts: the debounced start under `rule`,
/// as the service reports it.
pub fn first_alarm(
    points: &[DetectorPoint],
    rule: vamos::eval::alarm::Debounce,
) -> Result<Option<usize>> {
    Ok(
        vamos::eval::alarm::alarm_intervals(points.iter().map(|p| p.anomaly), rule)?
            .first()
            .map(|(start, _)| *start),
    )
}

/// Writes `<episode>.detectors.png` for every scored episode: the fused score (log axis,
/// the alarm threshold) above each detector's value against its own threshold, the flow
/// predictor's warm-up greyed, the labelled intervals shaded, and the first alarm (the
/// debounced start, as the service reports it) marked. Returns the files written.
pub fn write_detector_plots(
    dir: &Path,
    episodes: &[DetectorSeries<'_>],
    thresholds: &vamos::eval::DetectorThresholds,
    rule: vamos::eval::alarm::Debounce,
) -> Result<Vec<PathBuf>> {
    use vamos::eval::detector_plot::{Panel, plot_detectors};
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let options = PlotOptions {
        width_px: 900,
        height_px: 780,
        log_y: false,
    };
    let mut written = Vec::new();
    for e in episodes {
        let Some(t0) = e.points.first().map(|f| f.stamp_ns) else {
            continue;
        };
        let s = |ns: i64| (ns - t0) as f64 / 1e9;
        let stamps: Vec<f64> = e.points.iter().map(|f| s(f.stamp_ns)).collect();
        let score: Vec<f64> = e.points.iter().map(|f| f.score).collect();
        let values = vamos::eval::PerDetector::from_fn(|d| {
            e.points
                .iter()
                .map(|f| f.values[d].unwrap_or(f64::NAN))
                .collect::<Vec<f64>>()
        });
        let labels = vamos::eval::PerDetector::from_fn(Detector::title);
        let warming: Vec<bool> = e.points.iter().map(|f| f.warming_up).collect();
        let first_alarm = first_alarm(&e.points, rule)?.and_then(|i| stamps.get(i).copied());
        let intervals: Vec<(f64, f64)> = e
            .labels
            .map(|l| l.intervals_ns.iter().map(|[a, b]| (s(*a), s(*b))).collect())
            .unwrap_or_default();
        let panels: Vec<Panel<'_>> = std::iter::once(Panel {
            label: "fused score",
            values: &score,
            threshold: thresholds.alarm,
            log_y: true,
        })
        .chain(vamos::eval::Detector::ALL.map(|d| Panel {
            label: &labels[d],
            values: &values[d],
            threshold: thresholds.detectors[d],
            log_y: false,
        }))
        .collect();
        let path = dir.join(format!("{}.detectors.png", e.name));
        plot_detectors(
            &path,
            e.name,
            &stamps,
            &panels,
            &warming,
            &intervals,
            first_alarm,
            &options,
        )?;
        written.push(path);
    }
    Ok(written)
}

/// One episode's score timeline for the plots.
pub struct Timeline<'a> {
    /// Episode name (also the PNG's stem).
    pub name: &'a str,
    /// `(image stamp ns, score)` in stamp order.
    pub points: Vec<(i64, f64)>,
    /// The episode's labels (anomalous intervals are shaded).
    pub labels: Option<&'a Labels>,
}

/// The timelines of offline-scored episodes.
pub fn timelines(results: &[EpisodeScores]) -> Vec<Timeline<'_>> {
    results
        .iter()
        .map(|e| Timeline {
            name: &e.name,
            points: e.frames.iter().map(|f| (f.stamp_ns, f.score)).collect(),
            labels: e.labels.as_ref(),
        })
        .collect()
}

/// Writes `<episode>.png` (score over time, anomalous intervals shaded, the alarm
/// threshold drawn) for every timeline, and `roc.png` + `pr.png` over all `frames` when
/// both classes are present. Returns the files written.
pub fn write_plots(
    dir: &Path,
    timelines: &[Timeline<'_>],
    frames: &[ScoredFrame],
    alarm: f64,
) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let options = PlotOptions {
        log_y: true,
        ..PlotOptions::default()
    };
    let threshold = alarm.is_finite().then_some(alarm);
    let mut written = Vec::new();
    for e in timelines {
        let Some(t0) = e.points.first().map(|p| p.0) else {
            continue;
        };
        let s = |ns: i64| (ns - t0) as f64 / 1e9;
        let stamps: Vec<f64> = e.points.iter().map(|p| s(p.0)).collect();
        let scores: Vec<f64> = e.points.iter().map(|p| p.1).collect();
        let intervals: Vec<(f64, f64)> = e
            .labels
            .map(|l| l.intervals_ns.iter().map(|[a, b]| (s(*a), s(*b))).collect())
            .unwrap_or_default();
        let path = dir.join(format!("{}.png", e.name));
        plot_episode(
            &path, e.name, &stamps, &scores, &intervals, threshold, &options,
        )?;
        written.push(path);
    }
    let scores: Vec<f64> = frames.iter().map(|f| f.score).collect();
    let labels: Vec<bool> = frames.iter().map(|f| f.anomalous).collect();
    if let (Some(roc), Some(pr)) = (roc_curve(&scores, &labels), pr_curve(&scores, &labels)) {
        let options = PlotOptions::default();
        let (roc_path, pr_path) = (dir.join("roc.png"), dir.join("pr.png"));
        plot_roc(
            &roc_path,
            &[("all frames", &roc, roc_auc(&scores, &labels))],
            &options,
        )?;
        plot_pr(
            &pr_path,
            &[("all frames", &pr, average_precision(&scores, &labels))],
            &options,
        )?;
        written.extend([roc_path, pr_path]);
        // One ROC curve per anomaly type: its episodes' frames pooled with every nominal
        // episode's, as in the report's per-type AUCs; "all frames" for reference.
        let by_type = frames_by_type(frames);
        let typed: Vec<(String, Vec<RocPoint>, Option<f64>)> = by_type
            .iter()
            .filter_map(|(kind, (s, l))| Some((kind.clone(), roc_curve(s, l)?, roc_auc(s, l))))
            .collect();
        if !typed.is_empty() {
            let mut curves: Vec<(&str, &[RocPoint], Option<f64>)> =
                vec![("all frames", &roc, roc_auc(&scores, &labels))];
            curves.extend(typed.iter().map(|(k, c, a)| (k.as_str(), c.as_slice(), *a)));
            let path = dir.join("roc_per_type.png");
            plot_roc(&path, &curves, &options)?;
            written.push(path);
        }
    }
    Ok(written)
}

/// The paper's table: per flow variant one pipeline run (its own model), then the three
/// detector combinations fused from the same per-frame errors with the profile's
/// calibrated thresholds.
fn ablation(
    setup: &Setup,
    episodes: &[PathBuf],
    variant_models: &[String],
    progress: &Progress,
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
            eprintln!("ablation: no model for flow variant {variant}; row marked \"no model\"");
            table.set_not_run(&variant_label(variant), "no model");
            continue;
        };
        let mut config = setup.config.clone();
        config.frames.variant = variant;
        config.detectors.flow = true;
        eprintln!("ablation: flow variant {variant}");
        let label = format!("ablation {variant}");
        let results = setup.score_all(
            episodes,
            &ScoreRun {
                config: Some(&config),
                model: Some(model),
                ..ScoreRun::new(&label, Thresholds::default(), f64::INFINITY, progress)
            },
        )?;
        let frames = labelled_frames(&results)?;
        let labels: Vec<bool> = frames.iter().map(|f| f.anomalous).collect();
        let components: Vec<_> = results.iter().flat_map(|e| &e.frames).collect();
        for level in FusionLevel::ALL {
            let th = match level {
                FusionLevel::FlowOnly => Thresholds::default(),
                FusionLevel::FlowBody => Thresholds::paper(None, calibrated.e_b),
                FusionLevel::FlowBodyCamera => calibrated.clone(),
            };
            let scores: Vec<f64> = components
                .iter()
                .map(|f| {
                    let v = |d| f.values[d];
                    fuse(
                        v(Detector::Camera),
                        v(Detector::Body),
                        v(Detector::Flow),
                        &th,
                    )
                    .score
                })
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
