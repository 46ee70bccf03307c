//! `vamos demo`: the whole product on one machine with nothing but the binary. It unpacks
//! the embedded demo assets (the simulator's arm, a small model trained on simulated
//! nominal episodes, a calibrated profile, labelled test episodes; see
//! `assets/demo/README.md`), starts a vamos server in-process on loopback, streams every
//! episode to it over gRPC as concurrent robots, shows their progress live, and writes a
//! report (markdown + PNG plots + JSON).

use super::eval::{Timeline, write_plots};
use super::score::expand_episodes;
use anyhow::{Context, Result, bail};
use serde_json::json;
use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use vamos::client::{Client, ClientOptions, Pace, SessionSummary, Update};
use vamos::config::Settings;
use vamos::episode::Labels;
use vamos::eval::{EvalReport, ScoredFrame, evaluate};
use vamos::service::profiles::ProfileCatalog;
use vamos::service::proto::{self, stream_request::Message as In};
use vamos::service::replay::{Recording, record};
use vamos::service::{RunningServer, Server};
use vamos::setup::Setup;

/// The embedded assets: `(path relative to assets/demo, bytes)`, listed by build.rs.
const ASSETS: &[(&str, &[u8])] = include!(concat!(env!("OUT_DIR"), "/demo_assets.rs"));

/// Options of `vamos demo`.
pub struct DemoOptions {
    /// Output folder (assets unpacked under `assets/`, report and plots beside).
    pub out: PathBuf,
    /// A profile of your own instead of the embedded one.
    pub profile: Option<PathBuf>,
    /// Labelled episodes (files or folders) instead of the embedded ones.
    pub episodes: Vec<PathBuf>,
    /// Robots streaming at once (0: all episodes at once).
    pub robots: usize,
    /// Replay at the recorded rate times this factor instead of as fast as the server
    /// scores.
    pub speed: Option<f64>,
    /// No live progress table (one line per finished episode instead).
    pub quiet: bool,
}

/// Live state of one robot, for the progress table.
#[derive(Debug, Clone, Default)]
struct Progress {
    episode: String,
    images: usize,
    sent: usize,
    scored: usize,
    last_score: f64,
    alarms: usize,
    first_alarm_s: Option<f64>,
    dropped: u64,
    done: bool,
    failed: Option<String>,
}

/// One episode streamed and answered.
struct Streamed {
    name: String,
    labels: Option<Labels>,
    summary: SessionSummary,
    /// Seconds from each image sent to its score, client side.
    latencies_s: Vec<f64>,
}

/// Writes the embedded assets under `dir` and returns the profile's path.
fn unpack(dir: &Path) -> Result<PathBuf> {
    if ASSETS.is_empty() {
        bail!(
            "this vamos binary was built without demo assets (assets/demo is empty); \
             run assets/demo/make_demo_assets.sh or pass --profile and --episodes"
        );
    }
    for (rel, bytes) in ASSETS {
        let path = dir.join(rel);
        if let Some(parent) = path.parent() {
            std::fs::create_dir_all(parent)
                .with_context(|| format!("cannot create {}", parent.display()))?;
        }
        let unchanged = std::fs::metadata(&path).is_ok_and(|m| m.len() == bytes.len() as u64)
            && std::fs::read(&path).is_ok_and(|b| b == *bytes);
        if !unchanged {
            std::fs::write(&path, bytes)
                .with_context(|| format!("cannot write {}", path.display()))?;
        }
    }
    Ok(dir.join("profile.toml"))
}

/// Runs the demo.
pub async fn run(settings: &Settings, opts: DemoOptions) -> Result<()> {
    let started = Instant::now();
    std::fs::create_dir_all(&opts.out)
        .with_context(|| format!("cannot create {}", opts.out.display()))?;
    let (profile_path, episode_paths) = match &opts.profile {
        Some(p) => {
            if opts.episodes.is_empty() {
                bail!("--profile needs --episodes (labelled .mcap files or folders)");
            }
            (p.clone(), expand_episodes(&opts.episodes)?)
        }
        None => {
            let assets = opts.out.join("assets");
            let profile = unpack(&assets)?;
            let episodes = if opts.episodes.is_empty() {
                expand_episodes(&[assets.join("episodes")])?
            } else {
                expand_episodes(&opts.episodes)?
            };
            (profile, episodes)
        }
    };
    let setup = {
        let settings = settings.clone();
        let path = profile_path.clone();
        tokio::task::spawn_blocking(move || Setup::load(&settings, &path))
            .await?
            .with_context(|| format!("cannot load profile {}", profile_path.display()))?
    };
    let profile_name = setup.profile.file.name.clone();
    let alarm = setup.profile.alarm_threshold();
    let thresholds = setup.profile.thresholds();
    let model_desc = setup.model.as_ref().map(|m| {
        let man = m.manifest();
        let frames = man
            .training
            .get("frames_train")
            .and_then(|v| v.as_u64())
            .map_or(String::new(), |n| format!(", trained on {n} frames"));
        format!(
            "{} ({} parameters, A={}, B={}{frames})",
            man.name, man.architecture.parameters_total, man.temporal.a, man.temporal.b
        )
    });

    let mut recordings = Vec::new();
    for path in &episode_paths {
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let labels =
            Labels::load_for(path).with_context(|| format!("labels of {}", path.display()))?;
        let rec = record(path, &setup.episode)
            .with_context(|| format!("cannot read episode {}", path.display()))?;
        recordings.push((name, labels, rec));
    }

    // The server: loopback, ephemeral port, gRPC and REST on one port, a throw-away data
    // directory, the profile preloaded.
    let data_dir = tempfile::Builder::new()
        .prefix("vamos-demo-data")
        .tempdir()
        .context("cannot create a temporary data directory")?;
    let mut server_settings = settings.clone();
    server_settings.service.grpc_addr = "127.0.0.1:0".into();
    server_settings.service.rest_addr = "127.0.0.1:0".into();
    server_settings.service.data_dir = data_dir.path().to_path_buf();
    let queue_depth = server_settings.service.queue_depth.max(2);
    let server = Server::start(server_settings, ProfileCatalog::from_setups(vec![setup]))
        .await
        .context("cannot start the in-process server")?;
    let url = format!("http://{}", server.grpc_addr);
    println!(
        "vamos demo: server on {url} (gRPC + REST, in-process), profile {profile_name:?}, \
         model {}, alarm threshold {}",
        model_desc.as_deref().unwrap_or("none"),
        fmt_threshold(alarm)
    );
    let token = ["VAMOS_ROBOT_TOKEN", "VAMOS_ADMIN_TOKEN"]
        .iter()
        .find_map(|k| std::env::var(k).ok())
        .and_then(|v| v.split(',').next().map(|t| t.trim().to_string()));
    let client = Client::connect(
        &url,
        ClientOptions {
            token,
            ..ClientOptions::default()
        },
    )
    .await?;

    let result = stream_all(&client, &profile_name, recordings, &opts, queue_depth).await;
    let stop = shutdown(server).await;
    let streamed = result?;
    stop?;

    let report_path = write_report(
        &opts.out,
        &profile_path,
        &profile_name,
        model_desc.as_deref(),
        alarm,
        thresholds,
        &streamed,
        started.elapsed(),
    )?;
    println!("report: {}", report_path.display());
    Ok(())
}

async fn shutdown(server: RunningServer) -> Result<()> {
    server
        .shutdown()
        .await
        .context("the in-process server did not stop cleanly")
}

fn fmt_threshold(t: f64) -> String {
    if t.is_finite() {
        format!("{t:.3}")
    } else {
        "none (uncalibrated profile)".into()
    }
}

/// Streams every recording as its own robot (at most `opts.robots` at once) and shows
/// progress until all are answered.
async fn stream_all(
    client: &Client,
    profile: &str,
    recordings: Vec<(String, Option<Labels>, Recording)>,
    opts: &DemoOptions,
    queue_depth: usize,
) -> Result<Vec<Streamed>> {
    let n = recordings.len();
    let robots = if opts.robots == 0 {
        n
    } else {
        opts.robots.min(n)
    };
    let pace = match opts.speed {
        Some(speed) => Pace::Recorded { speed },
        // Below the queue depth: nothing is dropped, the server is never idle.
        None => Pace::Window((queue_depth / 2).max(1)),
    };
    println!(
        "streaming {n} episode(s) as {robots} concurrent robot(s), {}",
        match pace {
            Pace::Recorded { speed } => format!("at {speed}x the recorded rate"),
            Pace::Window(w) => format!("as fast as the server scores (window {w})"),
        }
    );
    let progress: Arc<Mutex<Vec<Progress>>> = Arc::new(Mutex::new(
        recordings
            .iter()
            .map(|(name, _, rec)| Progress {
                episode: name.clone(),
                images: rec
                    .messages
                    .iter()
                    .filter(|(_, m)| matches!(m, In::Image(_)))
                    .count(),
                last_score: f64::NAN,
                ..Progress::default()
            })
            .collect(),
    ));
    let slots = Arc::new(tokio::sync::Semaphore::new(robots));
    let mut tasks = Vec::new();
    for (i, (name, labels, rec)) in recordings.into_iter().enumerate() {
        let (client, progress, slots) = (client.clone(), progress.clone(), slots.clone());
        let profile = profile.to_string();
        tasks.push(tokio::spawn(async move {
            let _slot = slots.acquire_owned().await;
            let open = proto::OpenSession {
                robot_id: format!("demo-robot-{}", i + 1),
                profile,
                camera_info: rec.camera,
                task: name.clone(),
                // The session id seeds the predictor: the same as `vamos score` uses for
                // this episode, so the demo's scores equal offline scoring's.
                session_id: name.clone(),
            };
            let mut sent_at: BTreeMap<i64, Instant> = BTreeMap::new();
            let mut latencies_s = Vec::new();
            let t0 = rec.messages.iter().find_map(|(_, m)| match m {
                In::Image(img) => Some(img.stamp_ns),
                _ => None,
            });
            let result = client
                .replay(open, &rec, pace, |u| {
                    let mut all = progress.lock().unwrap_or_else(|e| e.into_inner());
                    let p = &mut all[i];
                    match u {
                        Update::Sent { stamp_ns } => {
                            p.sent += 1;
                            sent_at.insert(*stamp_ns, Instant::now());
                        }
                        Update::Score(s) => {
                            p.scored += 1;
                            p.last_score = s.score;
                            if let Some(t) = sent_at.remove(&s.stamp_ns) {
                                latencies_s.push(t.elapsed().as_secs_f64());
                            }
                            if s.anomaly {
                                p.alarms += 1;
                                if p.first_alarm_s.is_none() {
                                    p.first_alarm_s = t0.map(|t0| (s.stamp_ns - t0) as f64 / 1e9);
                                }
                            }
                        }
                        Update::Event(e) => {
                            if e.kind == proto::session_event::Kind::FramesDropped as i32 {
                                p.dropped = e.count;
                            }
                        }
                    }
                })
                .await;
            let mut all = progress.lock().unwrap_or_else(|e| e.into_inner());
            all[i].done = true;
            match result {
                Ok(summary) => Ok(Streamed {
                    name,
                    labels,
                    summary,
                    latencies_s,
                }),
                Err(e) => {
                    all[i].failed = Some(e.to_string());
                    Err(anyhow::anyhow!("episode {name}: {e}"))
                }
            }
        }));
    }
    let live = !opts.quiet && std::io::stdout().is_terminal();
    let mut drawn = 0usize;
    let mut announced = vec![false; n];
    loop {
        let finished = tasks.iter().all(|t| t.is_finished());
        {
            let all = progress.lock().unwrap_or_else(|e| e.into_inner()).clone();
            if live {
                drawn = draw_table(&all, drawn)?;
            } else {
                for (k, p) in all.iter().enumerate() {
                    if p.done && !announced[k] {
                        announced[k] = true;
                        println!("{}", progress_line(p));
                    }
                }
            }
        }
        if finished {
            break;
        }
        tokio::time::sleep(Duration::from_millis(if live { 200 } else { 100 })).await;
    }
    let mut streamed = Vec::new();
    for t in tasks {
        streamed.push(t.await??);
    }
    Ok(streamed)
}

fn progress_line(p: &Progress) -> String {
    let bar_len = 24usize;
    let filled = (p.scored * bar_len)
        .checked_div(p.images)
        .unwrap_or(0)
        .min(bar_len);
    let state = match (&p.failed, p.done) {
        (Some(e), _) => format!("FAILED: {e}"),
        (None, true) => "done".into(),
        (None, false) if p.sent == 0 => "waiting".into(),
        _ => "streaming".into(),
    };
    let alarm = match p.first_alarm_s {
        Some(t) => format!("ALARM at {t:5.1} s ({} frames)", p.alarms),
        None => "no alarm".into(),
    };
    format!(
        "{:<34} [{}{}] {:>4}/{:<4} score {:>9} {:<26} {}{}",
        truncate(&p.episode, 34),
        "#".repeat(filled),
        ".".repeat(bar_len - filled),
        p.scored,
        p.images,
        fmt_score(p.last_score),
        alarm,
        state,
        if p.dropped > 0 {
            format!(" ({} dropped)", p.dropped)
        } else {
            String::new()
        }
    )
}

fn truncate(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        s.chars().take(n - 1).collect::<String>() + "~"
    }
}

fn fmt_score(s: f64) -> String {
    if s.is_nan() {
        "-".into()
    } else if s.abs() >= 1e4 {
        format!("{s:.2e}")
    } else {
        format!("{s:.3}")
    }
}

/// Redraws the progress table in place (`drawn`: lines drawn last time).
fn draw_table(all: &[Progress], drawn: usize) -> Result<usize> {
    let mut out = std::io::stdout().lock();
    if drawn > 0 {
        write!(out, "\x1b[{drawn}A")?;
    }
    for p in all {
        writeln!(out, "\x1b[2K{}", progress_line(p))?;
    }
    out.flush()?;
    Ok(all.len())
}

fn percentile(sorted: &[f64], q: f64) -> Option<f64> {
    if sorted.is_empty() {
        return None;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted.get(i).copied()
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// Writes `report.md`, `report.json` and the plots; returns the report's path.
#[allow(clippy::too_many_arguments)]
fn write_report(
    out: &Path,
    profile_path: &Path,
    profile_name: &str,
    model: Option<&str>,
    alarm: f64,
    thresholds: vamos::eval::Thresholds,
    streamed: &[Streamed],
    elapsed: Duration,
) -> Result<PathBuf> {
    let mut frames = Vec::new();
    for s in streamed {
        for f in &s.summary.scores {
            frames.push(ScoredFrame {
                episode: s.name.clone(),
                stamp_ns: f.stamp_ns,
                score: f.score,
                anomalous: s
                    .labels
                    .as_ref()
                    .is_some_and(|l| l.is_anomalous(f.stamp_ns)),
                anomaly_type: s.labels.as_ref().and_then(|l| l.anomaly_type.clone()),
                warming_up: f.warming_up,
            });
        }
    }
    let report: EvalReport = evaluate(&frames, alarm);
    let outcomes = vamos::eval::episode_outcomes(&frames, alarm);
    let plots_dir = out.join("plots");
    let timelines: Vec<Timeline<'_>> = streamed
        .iter()
        .map(|s| Timeline {
            name: &s.name,
            points: s
                .summary
                .scores
                .iter()
                .map(|f| (f.stamp_ns, f.score))
                .collect(),
            labels: s.labels.as_ref(),
        })
        .collect();
    write_plots(&plots_dir, &timelines, &frames, alarm)?;

    let mut latencies: Vec<f64> = streamed
        .iter()
        .flat_map(|s| s.latencies_s.iter().copied())
        .collect();
    latencies.sort_by(f64::total_cmp);
    let mut compute: Vec<f64> = streamed
        .iter()
        .flat_map(|s| s.summary.scores.iter().map(|f| f.compute_s))
        .collect();
    compute.sort_by(f64::total_cmp);
    let scored: usize = streamed.iter().map(|s| s.summary.scores.len()).sum();
    let sent: u64 = streamed.iter().map(|s| s.summary.images_sent).sum();
    let dropped: u64 = streamed.iter().map(|s| s.summary.dropped).sum();
    let errors: usize = streamed
        .iter()
        .map(|s| s.summary.message_errors.len())
        .sum();
    let ms = |v: Option<f64>| v.map(|s| s * 1e3);

    let mut md = String::new();
    md.push_str("# vamos demo report\n\n");
    md.push_str(&format!(
        "vamos {} · profile `{profile_name}` ({}) · model {} · {} episode(s) streamed over \
         gRPC to an in-process server as concurrent robots · {:.1} s in all\n\n",
        env!("CARGO_PKG_VERSION"),
        profile_path.display(),
        model.unwrap_or("none (no flow predictor)"),
        streamed.len(),
        elapsed.as_secs_f64()
    ));
    md.push_str(&format!(
        "Thresholds: e_c {}, e_b {}; alarm when the fused score reaches {}.\n\n",
        opt(thresholds.e_c, 3),
        opt(thresholds.e_b, 3),
        fmt_threshold(alarm)
    ));
    md.push_str("## Summary\n\n| figure | value |\n|---|---|\n");
    for (k, v) in [
        ("frames scored / images sent", format!("{scored} / {sent}")),
        ("frames dropped / refused", format!("{dropped} / {errors}")),
        ("frame-level AUC-ROC", opt(report.auc_roc, 3)),
        ("frame-level AUC-PR", opt(report.auc_pr, 3)),
        (
            "anomalous episodes detected",
            opt(report.detection_rate.map(|r| r * 100.0), 0) + " %",
        ),
        (
            "median detection delay",
            opt(report.median_detection_delay_s, 2) + " s",
        ),
        (
            "nominal episodes with a false alarm",
            opt(report.episode_false_alarm_rate.map(|r| r * 100.0), 0) + " %",
        ),
        (
            "score latency p50 / p99 (image sent -> score received; includes queueing)",
            format!(
                "{} / {} ms",
                opt(ms(percentile(&latencies, 0.5)), 1),
                opt(ms(percentile(&latencies, 0.99)), 1)
            ),
        ),
        (
            "server compute per frame p50 / p99",
            format!(
                "{} / {} ms",
                opt(ms(percentile(&compute, 0.5)), 1),
                opt(ms(percentile(&compute, 0.99)), 1)
            ),
        ),
    ] {
        md.push_str(&format!("| {k} | {v} |\n"));
    }
    md.push_str(
        "\n## Episodes\n\n| episode | anomaly | frames | max score | onset | first alarm | \
         delay | outcome |\n|---|---|---:|---:|---:|---:|---:|---|\n",
    );
    for o in &outcomes {
        let t0 = frames
            .iter()
            .filter(|f| f.episode == o.episode)
            .map(|f| f.stamp_ns)
            .min()
            .unwrap_or(0);
        let rel = |ns: Option<i64>| ns.map(|n| (n - t0) as f64 / 1e9);
        let outcome = match (o.anomalous, o.detection_delay_s, o.false_alarm) {
            (false, _, false) => "ok (no alarm)",
            (false, _, true) => "FALSE ALARM",
            (true, Some(_), false) => "detected",
            (true, Some(_), true) => "detected (alarm before onset too)",
            (true, None, _) => "MISSED",
        };
        md.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            o.episode,
            o.anomaly_type.as_deref().unwrap_or("-"),
            o.frames,
            fmt_score(o.max_score),
            opt(rel(o.onset_ns), 1) + if o.onset_ns.is_some() { " s" } else { "" },
            opt(rel(o.first_alarm_ns), 1) + if o.first_alarm_ns.is_some() { " s" } else { "" },
            opt(o.detection_delay_s, 1)
                + if o.detection_delay_s.is_some() {
                    " s"
                } else {
                    ""
                },
            outcome
        ));
    }
    if !report.per_type.is_empty() {
        md.push_str(
            "\n## Per anomaly type (each type's episodes pooled with the nominal ones)\n\n\
             | type | episodes | AUC-ROC | AUC-PR | detected | median delay |\n\
             |---|---:|---:|---:|---:|---:|\n",
        );
        for (t, r) in &report.per_type {
            md.push_str(&format!(
                "| {t} | {} | {} | {} | {} % | {} |\n",
                r.episodes,
                opt(r.auc_roc, 3),
                opt(r.auc_pr, 3),
                opt(r.detection_rate.map(|v| v * 100.0), 0),
                opt(r.median_detection_delay_s, 2)
                    + if r.median_detection_delay_s.is_some() {
                        " s"
                    } else {
                        ""
                    }
            ));
        }
    }
    md.push_str("\n## Plots\n\n");
    if plots_dir.join("roc.png").is_file() {
        md.push_str("![ROC](plots/roc.png) ![PR](plots/pr.png)\n\n");
    }
    md.push_str(
        "Score timelines (log scale; anomalous intervals shaded, the alarm threshold \
         dashed):\n\n",
    );
    for s in streamed {
        md.push_str(&format!("![{0}](plots/{0}.png)\n", s.name));
    }
    let path = out.join("report.md");
    std::fs::write(&path, md).with_context(|| format!("cannot write {}", path.display()))?;
    let json_path = out.join("report.json");
    let value = json!({
        "profile": profile_name,
        "model": model,
        "alarm_threshold": alarm.is_finite().then_some(alarm),
        "evaluation": report,
        "episodes": outcomes,
        "frames_scored": scored,
        "images_sent": sent,
        "frames_dropped": dropped,
        "message_errors": errors,
        "latency_ms": {
            "p50": ms(percentile(&latencies, 0.5)),
            "p99": ms(percentile(&latencies, 0.99)),
        },
        "compute_ms": {
            "p50": ms(percentile(&compute, 0.5)),
            "p99": ms(percentile(&compute, 0.99)),
        },
        "elapsed_s": elapsed.as_secs_f64(),
    });
    std::fs::write(&json_path, serde_json::to_string_pretty(&value)? + "\n")
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    Ok(path)
}
