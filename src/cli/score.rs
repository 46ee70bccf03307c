//! `vamos score`: the detector over recorded episodes (ROS 2 bags in MCAP), and the
//! profile loading that `vamos calibrate` and `vamos eval` share.

use super::progress::Progress;
use anyhow::{Context, Result, bail};
use rayon::prelude::*;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use vamos::config::Settings;
use vamos::episode::{EpisodeFrame, McapEpisode, ScoreBagWriter, ScoreTopics};
use vamos::eval::{Detector, Thresholds};
use vamos::model::FlowModel;
use vamos::pipeline::offline::{EpisodeScores, score_episode};
use vamos::pipeline::{FrameScore, PipelineConfig, Scorer};
use vamos::session::live::{Thumb, anomaly_map};
pub use vamos::setup::Setup;

/// One scoring run of [`ScoreAll::score_all`]: thresholds, optional overrides of the
/// profile's pipeline and model, outputs and progress.
pub struct ScoreRun<'a> {
    /// Label of the run's progress bar (`scoring`, `training`, `ablation masked`...).
    pub label: &'a str,
    /// `e_c`/`e_b` thresholds.
    pub thresholds: Thresholds,
    /// Fused-score alarm threshold.
    pub alarm_threshold: f64,
    /// Pipeline parameters (default: the profile's).
    pub config: Option<&'a PipelineConfig>,
    /// Model (default: the profile's).
    pub model: Option<&'a Arc<FlowModel>>,
    /// Files to write per episode.
    pub output: Option<&'a OutputOptions>,
    /// Where progress goes.
    pub progress: &'a Progress,
}

impl<'a> ScoreRun<'a> {
    /// A run with the profile's pipeline and model, writing nothing.
    pub fn new(
        label: &'a str,
        thresholds: Thresholds,
        alarm_threshold: f64,
        progress: &'a Progress,
    ) -> Self {
        Self {
            label,
            thresholds,
            alarm_threshold,
            config: None,
            model: None,
            output: None,
            progress,
        }
    }
}

/// Scoring many episodes with one profile.
pub trait ScoreAll {
    /// Scores `episodes` in parallel (one scorer each), reporting progress as frames are
    /// read and each episode finishes. Episodes that cannot be opened are errors.
    fn score_all(&self, episodes: &[PathBuf], run: &ScoreRun<'_>) -> Result<Vec<EpisodeScores>>;
}

impl ScoreAll for Setup {
    fn score_all(&self, episodes: &[PathBuf], run: &ScoreRun<'_>) -> Result<Vec<EpisodeScores>> {
        let progress = run.progress.run(run.label, episodes.len());
        let results: Vec<Result<EpisodeScores>> = episodes
            .par_iter()
            .map(|path| {
                let episode = McapEpisode::open(path, &self.episode)
                    .with_context(|| format!("episode {}", path.display()))?;
                let bar = progress.episode(episode.name(), episode.info().image_messages);
                let heatmaps = run.output.is_some_and(|o| o.mcap);
                let mut scorer = self.scorer(
                    episode.name(),
                    run.thresholds.clone(),
                    run.alarm_threshold,
                    heatmaps,
                    run.config,
                    run.model,
                )?;
                // Image indices count every image read (strided ones too).
                let seen = |frame: &EpisodeFrame| bar.set(frame.index as u64 + 1);
                let scores = match run.output {
                    Some(o) => write_outputs(&mut scorer, &episode, o, run, seen)?,
                    None => score_episode::<anyhow::Error>(&mut scorer, &episode, |frame, _| {
                        seen(frame);
                        Ok(())
                    })?,
                };
                drop(bar);
                progress.finished(&format!(
                    "{}: {} frames scored{}{}",
                    scores.name,
                    scores.frames.len(),
                    if scores.frame_errors.is_empty() {
                        String::new()
                    } else {
                        format!(", {} refused", scores.frame_errors.len())
                    },
                    scores
                        .damage
                        .as_ref()
                        .map_or(String::new(), |d| format!(", damaged: {d}"))
                ));
                Ok(scores)
            })
            .collect();
        results.into_iter().collect()
    }
}

/// Where `vamos score` writes.
pub struct OutputOptions {
    /// Output folder.
    pub dir: PathBuf,
    /// Also write `<name>.scored.mcap` (input images + score topics + heatmaps).
    pub mcap: bool,
}

/// Expands folders into the `.mcap` files they hold (sorted); files pass through
/// ([`vamos::episode::files::expand_episodes`]); nothing at all is an error.
pub fn expand_episodes(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let out = vamos::episode::files::expand_episodes(paths)?;
    if out.is_empty() {
        bail!("no episodes given");
    }
    Ok(out)
}

/// Scores one episode writing `<name>.scores.jsonl` and, if asked, `<name>.scored.mcap`.
fn write_outputs(
    scorer: &mut Scorer,
    episode: &McapEpisode,
    o: &OutputOptions,
    run: &ScoreRun<'_>,
    seen: impl Fn(&EpisodeFrame),
) -> Result<EpisodeScores> {
    std::fs::create_dir_all(&o.dir)
        .with_context(|| format!("cannot create {}", o.dir.display()))?;
    let jsonl = o.dir.join(format!("{}.scores.jsonl", episode.name()));
    let mut lines = std::io::BufWriter::new(
        std::fs::File::create(&jsonl)
            .with_context(|| format!("cannot create {}", jsonl.display()))?,
    );
    let mut bag = if o.mcap {
        let path = o.dir.join(format!("{}.scored.mcap", episode.name()));
        let mut bag = ScoreBagWriter::create(&path, Some(&episode.info()))?;
        bag.copy_context(episode)?;
        Some(bag)
    } else {
        None
    };
    let mut thresholds_json = Some(serde_json::to_string(&scorer.detector_thresholds())?);
    let scores = score_episode::<anyhow::Error>(scorer, episode, |frame, score| {
        seen(frame);
        serde_json::to_writer(&mut lines, score)?;
        lines.write_all(b"\n")?;
        if let Some(bag) = bag.as_mut() {
            let map = anomaly_map(score, &run.thresholds, run.alarm_threshold);
            write_frame(bag, frame, score, map.as_ref(), thresholds_json.take())?;
        }
        Ok(())
    })?;
    lines.flush()?;
    if let Some(bag) = bag {
        bag.finish()?;
    }
    Ok(scores)
}

/// The score topics of one frame, beside a copy of its image.
fn write_frame(
    bag: &mut ScoreBagWriter,
    frame: &EpisodeFrame,
    s: &FrameScore,
    map: Option<&Thumb>,
    thresholds_json: Option<String>,
) -> Result<()> {
    bag.write_scored_frame(
        frame,
        &ScoreTopics {
            score: s.score,
            anomaly: s.anomaly,
            values: s.values,
            heatmap: s.heatmap.as_deref(),
            anomaly_map: map.map(|m| (m.width as u32, m.height as u32, m.pixels.as_slice())),
            thresholds_json: thresholds_json.as_deref(),
        },
    )?;
    Ok(())
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The profile (TOML; see README "Detection: profiles").
    #[arg(long)]
    pub profile: PathBuf,
    /// Episodes: .mcap files or folders of them.
    #[arg(required = true)]
    pub episodes: Vec<PathBuf>,
    /// Output folder for `<episode>.scores.jsonl` (and `.scored.mcap`).
    #[arg(short, long)]
    pub out: Option<PathBuf>,
    /// Also write `<episode>.scored.mcap`: input images, camera info, joint states and
    /// robot description, /vamos/score, /vamos/anomaly, /vamos/e_c, /vamos/e_b,
    /// /vamos/e_o, /vamos/heatmap, /vamos/anomaly_map, /vamos/thresholds.
    #[arg(long)]
    pub mcap: bool,
    /// No progress bars (they are drawn on stderr only when it is a terminal).
    #[arg(long)]
    pub no_progress: bool,
}
/// `vamos score`: prints one JSON summary line per episode on stdout.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    if let Some(dir) = &args.out {
        super::check_output_dir("--out", dir)?;
    }
    score(
        settings,
        &args.profile,
        &args.episodes,
        args.out,
        args.mcap,
        &Progress::new(args.no_progress),
    )
}

/// Scores `episodes` with `profile`, printing one JSON summary line per episode.
pub fn score(
    settings: &Settings,
    profile: &Path,
    episodes: &[PathBuf],
    out: Option<PathBuf>,
    mcap: bool,
    progress: &Progress,
) -> Result<()> {
    if mcap && out.is_none() {
        bail!("--mcap writes into the --out folder: give --out");
    }
    let setup = Setup::load(settings, profile)?;
    if setup.profile.calibration.is_none() {
        eprintln!(
            "note: profile {} is not calibrated (run `vamos calibrate`): no thresholds, no alarms",
            setup.profile.path.display()
        );
    }
    let rule = setup.alarm_rule();
    if rule.fallback {
        eprintln!("note: {}", rule.why);
    }
    let episodes = expand_episodes(episodes)?;
    let output = out.map(|dir| OutputOptions { dir, mcap });
    let results = setup.score_all(
        &episodes,
        &ScoreRun {
            output: output.as_ref(),
            ..ScoreRun::new(
                "scoring",
                setup.profile.thresholds(),
                setup.profile.alarm_threshold(),
                progress,
            )
        },
    )?;
    let mut not_run: Vec<(String, usize)> = Vec::new();
    for r in &results {
        let off = detectors_not_run(&setup, r);
        for d in &off {
            let line = format!("{} did not run: {}", d.detector, d.reason);
            match not_run.iter_mut().find(|(l, _)| *l == line) {
                Some((_, n)) => *n += 1,
                None => not_run.push((line, 1)),
            }
        }
        let alarms = r.frames.iter().filter(|f| f.anomaly).count();
        let first_alarm_ns = r.frames.iter().find(|f| f.anomaly).map(|f| f.stamp_ns);
        let max_score = r.frames.iter().map(|f| f.score).fold(f64::NAN, f64::max);
        let mean_ms = r
            .frames
            .iter()
            .map(|f| f.timings.total_us as f64)
            .sum::<f64>()
            / r.frames.len().max(1) as f64
            / 1e3;
        println!(
            "{}",
            serde_json::json!({
                "episode": r.name,
                "frames": r.frames.len(),
                "alarms": alarms,
                "first_alarm_ns": first_alarm_ns,
                "max_score": if max_score.is_nan() { None } else { Some(max_score) },
                "refused": r.frame_errors,
                "damage": r.damage,
                "no_joint_states": r.no_joint_states,
                "joint_gaps": r.joint_gaps,
                "mean_frame_ms": mean_ms,
                "alarm_rule": rule,
                "detectors_not_run": off,
            })
        );
    }
    for (line, n) in not_run {
        eprintln!("note: {line} ({n} of {} episodes)", results.len());
    }
    Ok(())
}

/// A detector switched on in the profile that gave no value on an episode, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct NotRun {
    /// `e_c`, `e_b`, `e_o`, `e_r` or `e_k`.
    pub detector: &'static str,
    /// Why it could not run.
    pub reason: String,
}

/// The detectors `setup`'s pipeline switches on that gave no value on any frame of `r`,
/// each with the first reason that applies (no robot, no model, no joint states, no
/// calibrated nominal states, the body never in view, a model still warming up). Empty
/// for an episode without frames.
pub fn detectors_not_run(setup: &Setup, r: &EpisodeScores) -> Vec<NotRun> {
    if r.frames.is_empty() {
        return Vec::new();
    }
    let on = setup.config.detectors;
    let mut out = Vec::new();
    for d in Detector::ALL {
        if !on.get(d) || r.frames.iter().any(|f| f.values[d].is_some()) {
            continue;
        }
        let detector = d.key();
        let needs_robot = d.needs_robot();
        let reason = if needs_robot && setup.robot.is_none() {
            "the profile has no robot (`robot` and `camera`): it needs the robot's joint \
             states and body"
                .to_string()
        } else if detector == "e_o" && setup.model.is_none() {
            "the profile has no flow model (`model`)".to_string()
        } else if needs_robot && r.no_joint_states {
            "the episode has no joint states (sensor_msgs/msg/JointState)".to_string()
        } else if detector == "e_k" && setup.profile.calibration.is_none() {
            "the profile is not calibrated: e_k compares the robot's state with the \
             calibration's nominal states (`vamos calibrate`)"
                .to_string()
        } else if detector == "e_k" && setup.profile.thresholds().kinematics.is_none() {
            "the calibration has no nominal robot states (made without joint states or \
             before e_k): calibrate again"
                .to_string()
        } else if detector == "e_b" && r.frames.iter().all(|f| f.body_pixels == 0) {
            "the robot's body was never in view (no body pixels: its meshes are missing or \
             the camera does not see it)"
                .to_string()
        } else if detector == "e_o" && r.frames.iter().all(|f| f.warming_up) {
            "the episode is shorter than the flow model's history (every frame warming up)"
                .to_string()
        } else {
            "no frame of the episode gave a value".to_string()
        };
        out.push(NotRun { detector, reason });
    }
    out
}
