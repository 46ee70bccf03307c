//! `vamos stream`: one recorded episode sent to a running server as a live robot (or
//! uploaded for batch scoring); every answer printed as a JSON line.

use anyhow::{Context, Result};
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
use vamos::api::proto;
use vamos::client::replay::record;
use vamos::client::{Client, ClientOptions, Pace, Update};
use vamos::config::Settings;
use vamos::episode::EpisodeConfig;

/// How the episode goes to the server.
enum Mode {
    /// As a live session (`Monitor.Stream`) at this pace.
    Pace(Pace),
    /// As one upload (`Monitor.ScoreEpisode`).
    Batch,
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The episode.
    pub episode: PathBuf,
    /// gRPC URL of the server (`https://` needs --ca).
    #[arg(long, default_value = "http://127.0.0.1:8081")]
    pub server: String,
    /// Profile the session uses.
    #[arg(long)]
    pub profile: String,
    /// Replay at the recorded rate times this factor (1.0: real time).
    #[arg(long, default_value_t = 1.0, conflicts_with = "fast")]
    pub speed: f64,
    /// As fast as the server scores instead, with at most --window images unanswered.
    #[arg(long)]
    pub fast: bool,
    /// Images in flight with --fast; below the server's queue_depth (default 8) no
    /// image is dropped.
    #[arg(long, default_value_t = 4, requires = "fast")]
    pub window: usize,
    /// Upload the whole file for batch scoring (Monitor.ScoreEpisode) instead.
    #[arg(long, conflicts_with_all = ["fast", "speed"])]
    pub batch: bool,
    /// Robot id reported to the server.
    #[arg(long, default_value = "vamos-stream")]
    pub robot_id: String,
    /// Session id (for resumption and seeding; default: the episode's file stem).
    #[arg(long)]
    pub session_id: Option<String>,
    /// Bearer token (default: $VAMOS_ROBOT_TOKEN).
    #[arg(long, env = "VAMOS_ROBOT_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// CA certificate (PEM) of an https:// server.
    #[arg(long)]
    pub ca: Option<PathBuf>,
}

/// What `run` streams, resolved from the flags.
struct StreamOptions {
    /// The episode (MCAP).
    pub episode: PathBuf,
    /// gRPC URL.
    pub server: String,
    /// Profile name on the server.
    pub profile: String,
    /// Live or batch.
    pub mode: Mode,
    /// Robot id.
    pub robot_id: String,
    /// Session id (default: the file stem).
    pub session_id: Option<String>,
    /// Bearer token.
    pub token: Option<String>,
    /// CA certificate for https.
    pub ca: Option<PathBuf>,
    /// Topics of the bag.
    pub episode_config: EpisodeConfig,
}

fn score_json(s: &proto::FrameScore) -> serde_json::Value {
    let mut v = proto::score_json(s);
    v["type"] = json!("score");
    v["latency_s"] = json!(s.latency_s);
    v
}

fn event_json(e: &proto::SessionEvent) -> serde_json::Value {
    let kind = proto::session_event::Kind::try_from(e.kind).map_or_else(
        |_| format!("KIND_{}", e.kind),
        |k| k.as_str_name().to_string(),
    );
    json!({
        "type": "event", "kind": kind, "session_id": e.session_id, "detail": e.detail,
        "stamp_ns": e.stamp_ns, "count": e.count,
    })
}

fn alarm_json(a: &proto::AlarmEvent) -> serde_json::Value {
    let edge = proto::alarm_event::Edge::try_from(a.edge).map_or_else(
        |_| format!("EDGE_{}", a.edge),
        |k| k.as_str_name().to_string(),
    );
    let detector = |d: i32| {
        proto::Detector::try_from(d).map_or_else(|_| d.to_string(), |k| k.as_str_name().into())
    };
    json!({
        "type": "alarm", "edge": edge, "alarm_id": a.alarm_id, "session_id": a.session_id,
        "detector": detector(a.detector),
        "detectors": a.detectors.iter().map(|d| detector(*d)).collect::<Vec<_>>(),
        "start_frame": a.start_frame, "end_frame": a.end_frame,
        "frames_flagged": a.frames_flagged, "alarm_threshold": a.alarm_threshold,
        "e_c_threshold": a.e_c_threshold, "e_b_threshold": a.e_b_threshold,
    })
}

fn emit(value: &serde_json::Value) {
    let mut out = std::io::stdout().lock();
    // A closed stdout (e.g. `| head`) is not an error worth stopping the session for.
    let _ = writeln!(out, "{value}");
}

/// Runs it.
/// Streams (or uploads) the episode.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    let mode = if args.batch {
        Mode::Batch
    } else if args.fast {
        Mode::Pace(Pace::Window(args.window))
    } else {
        Mode::Pace(Pace::Recorded { speed: args.speed })
    };
    let opts = StreamOptions {
        episode: args.episode,
        server: args.server,
        profile: args.profile,
        mode,
        robot_id: args.robot_id,
        session_id: args.session_id,
        token: args.token,
        ca: args.ca,
        episode_config: settings.episode.clone(),
    };
    super::async_runtime()?.block_on(stream(opts))
}

async fn stream(opts: StreamOptions) -> Result<()> {
    let ca_pem = match &opts.ca {
        Some(p) => Some(std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?),
        None => None,
    };
    let client = Client::connect(
        &opts.server,
        ClientOptions {
            token: opts.token.clone(),
            ca_pem,
            ..ClientOptions::default()
        },
    )
    .await?;
    let stem = opts
        .episode
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    match opts.mode {
        Mode::Batch => {
            let scores = client
                .score_episode(&opts.episode, &opts.profile, |s| emit(&score_json(s)))
                .await?;
            let alarms = scores.iter().filter(|s| s.anomaly).count();
            eprintln!("{}: {} frames scored, {alarms} alarmed", stem, scores.len());
        }
        Mode::Pace(pace) => {
            let rec = record(&opts.episode, &opts.episode_config)
                .with_context(|| format!("cannot read {}", opts.episode.display()))?;
            let open = proto::OpenSession {
                robot_id: opts.robot_id.clone(),
                profile: opts.profile.clone(),
                camera_info: rec.camera,
                task: stem.clone(),
                session_id: opts.session_id.clone().unwrap_or_else(|| stem.clone()),
                anomaly_maps: false,
                image_rate_hz: 0.0,
            };
            let summary = client
                .replay(open, &rec, pace, |u| match u {
                    Update::Sent { .. } => {}
                    Update::Score(s) => emit(&score_json(s)),
                    Update::Event(e) => emit(&event_json(e)),
                    Update::Alarm(a) => emit(&alarm_json(a)),
                })
                .await?;
            let alarms = summary.scores.iter().filter(|s| s.anomaly).count();
            eprintln!(
                "{stem}: session {}, {} images sent, {} scored, {alarms} alarmed, {} dropped, \
                 {} refused, {:.1} s",
                summary.session_id,
                summary.images_sent,
                summary.scores.len(),
                summary.dropped,
                summary.message_errors.len(),
                summary.elapsed.as_secs_f64()
            );
        }
    }
    Ok(())
}
