//! `vamos stream`: one recorded episode sent to a running server as a live robot (or
//! uploaded for batch scoring); every answer printed as a JSON line.

use anyhow::{Context, Result};
use serde_json::json;
use std::io::Write;
use std::path::PathBuf;
use vamos::client::{Client, ClientOptions, Pace, Update};
use vamos::episode::EpisodeConfig;
use vamos::service::proto;
use vamos::service::replay::record;

/// How the episode goes to the server.
pub enum Mode {
    /// As a live session (`Monitor.Stream`) at this pace.
    Pace(Pace),
    /// As one upload (`Monitor.ScoreEpisode`).
    Batch,
}

/// Options of `vamos stream`.
pub struct StreamOptions {
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

fn emit(value: &serde_json::Value) {
    let mut out = std::io::stdout().lock();
    // A closed stdout (e.g. `| head`) is not an error worth stopping the session for.
    let _ = writeln!(out, "{value}");
}

/// Runs it.
pub async fn run(opts: StreamOptions) -> Result<()> {
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
            };
            let summary = client
                .replay(open, &rec, pace, |u| match u {
                    Update::Sent { .. } => {}
                    Update::Score(s) => emit(&score_json(s)),
                    Update::Event(e) => emit(&event_json(e)),
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
