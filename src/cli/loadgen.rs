//! `vamos loadgen`: replays recorded episodes as N robots streaming to a running server
//! and reports the achieved rate, score latency percentiles, drops, and the server's CPU
//! and memory (scraped from its `/metrics`).

use crate::cli::percentile;
use anyhow::{Context, Result, bail};
use serde_json::json;
use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};
use tokio::sync::Mutex;
use vamos::api::proto;
use vamos::client::replay::{Recording, record};
use vamos::client::{Client, ClientOptions, Pace, Update};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Episodes (MCAP), replayed round-robin.
    #[arg(required = true)]
    pub episodes: Vec<PathBuf>,
    /// gRPC URL of the server.
    #[arg(long, default_value = "http://127.0.0.1:8081")]
    pub server: String,
    /// The server's /metrics URL (CPU and memory figures), e.g.
    /// http://127.0.0.1:8080/metrics.
    #[arg(long)]
    pub metrics: Option<String>,
    /// Profile the sessions use.
    #[arg(long)]
    pub profile: String,
    /// Robots streaming at once.
    #[arg(long, default_value_t = 1)]
    pub robots: usize,
    /// Replay speed (1.0: recorded timing, e.g. 10 Hz images).
    #[arg(long, default_value_t = 1.0)]
    pub speed: f64,
    /// Run time, seconds.
    #[arg(long, default_value_t = 30.0)]
    pub duration: f64,
    /// Bearer token (robot role).
    #[arg(long, env = "VAMOS_LOADGEN_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// Seconds between the samples of the report's `timeline` (scores/s, server CPU
    /// and RSS per interval; 0: none).
    #[arg(long, default_value_t = 60.0)]
    pub sample_every: f64,
}

/// Options of `vamos loadgen`.
pub struct LoadOptions {
    /// gRPC URL of the server.
    pub server: String,
    /// REST base URL (for `/metrics`), if any.
    pub metrics: Option<String>,
    /// Profile the sessions use.
    pub profile: String,
    /// Robots streaming at once.
    pub robots: usize,
    /// Replay speed: 1.0 = recorded timing.
    pub speed: f64,
    /// How long to run, seconds.
    pub duration_s: f64,
    /// Bearer token.
    pub token: Option<String>,
    /// Episodes (MCAP) to replay, round-robin.
    pub episodes: Vec<PathBuf>,
    /// Seconds between the samples of the report's `timeline` (0: no timeline).
    pub sample_s: f64,
}

/// What the robots' tasks share: the tally at session ends and a live score count.
#[derive(Default)]
struct Shared {
    tally: Mutex<Tally>,
    live_scores: AtomicU64,
}

#[derive(Default)]
struct Tally {
    sessions: u64,
    images: u64,
    scores: u64,
    dropped_events: u64,
    errors: Vec<String>,
    latencies_s: Vec<f64>,
    server_latencies_s: Vec<f64>,
}

async fn one_session(
    client: &Client,
    opts: &LoadOptions,
    robot: usize,
    n: usize,
    rec: &Recording,
    deadline: Instant,
    shared: &Shared,
) -> Result<()> {
    // What fits before the deadline at this speed is what a robot would send.
    let left = deadline.saturating_duration_since(Instant::now());
    let rec = Recording {
        messages: rec
            .messages
            .iter()
            .take_while(|(at, _)| at.div_f64(opts.speed.max(1e-6)) < left)
            .cloned()
            .collect(),
        camera: rec.camera,
    };
    let open = proto::OpenSession {
        robot_id: format!("loadgen-{robot}"),
        profile: opts.profile.clone(),
        camera_info: rec.camera,
        task: "loadgen".into(),
        session_id: format!("loadgen-{robot}-{n}"),
        anomaly_maps: false,
        image_rate_hz: 0.0,
    };
    let mut sent_at: HashMap<i64, Instant> = HashMap::new();
    let mut local = Tally::default();
    let result = client
        .replay(
            open,
            &rec,
            Pace::Recorded { speed: opts.speed },
            |u| match u {
                Update::Sent { stamp_ns } => {
                    sent_at.insert(*stamp_ns, Instant::now());
                }
                Update::Score(s) => {
                    shared.live_scores.fetch_add(1, Ordering::Relaxed);
                    local.server_latencies_s.push(s.latency_s);
                    if let Some(t) = sent_at.remove(&s.stamp_ns) {
                        local.latencies_s.push(t.elapsed().as_secs_f64());
                    }
                }
                Update::Event(_) | Update::Alarm(_) => {}
            },
        )
        .await;
    let mut t = shared.tally.lock().await;
    t.latencies_s.extend(local.latencies_s);
    t.server_latencies_s.extend(local.server_latencies_s);
    let summary = result?;
    t.sessions += 1;
    t.images += summary.images_sent;
    t.scores += summary.scores.len() as u64;
    t.dropped_events += summary.dropped;
    t.errors.extend(summary.message_errors);
    Ok(())
}

/// Sample of the server's process metrics.
#[derive(Debug, Clone)]
struct ProcessSample {
    cpu_s: f64,
    rss_bytes: f64,
    /// `vamos_stage_seconds` by stage: (sum of seconds, count).
    stages: HashMap<String, (f64, f64)>,
}

async fn scrape(url: &str) -> Option<ProcessSample> {
    let text = http_get(url).await.ok()?;
    parse_sample(&text)
}

/// The figures loadgen reads from a Prometheus exposition.
fn parse_sample(text: &str) -> Option<ProcessSample> {
    let value = |name: &str| {
        text.lines()
            .find(|l| l.starts_with(name) && l[name.len()..].starts_with(' '))
            .and_then(|l| l.rsplit(' ').next())
            .and_then(|v| v.parse::<f64>().ok())
    };
    let mut stages: HashMap<String, (f64, f64)> = HashMap::new();
    for line in text.lines() {
        for (prefix, sum) in [
            ("vamos_stage_seconds_sum{stage=\"", true),
            ("vamos_stage_seconds_count{stage=\"", false),
        ] {
            let Some(rest) = line.strip_prefix(prefix) else {
                continue;
            };
            let Some((stage, tail)) = rest.split_once('"') else {
                continue;
            };
            let Some(v) = tail.rsplit(' ').next().and_then(|v| v.parse::<f64>().ok()) else {
                continue;
            };
            let e = stages.entry(stage.to_string()).or_default();
            if sum {
                e.0 = v;
            } else {
                e.1 = v;
            }
        }
    }
    Some(ProcessSample {
        cpu_s: value("process_cpu_seconds_total")?,
        rss_bytes: value("process_resident_memory_bytes")?,
        stages,
    })
}

/// Mean milliseconds per frame of each pipeline stage between two samples, slowest
/// first; stages no frame passed are left out.
fn stage_means_ms(before: &ProcessSample, after: &ProcessSample) -> Vec<(String, f64)> {
    let mut out: Vec<(String, f64)> = after
        .stages
        .iter()
        .filter_map(|(stage, (sum, count))| {
            let (s0, c0) = before.stages.get(stage).copied().unwrap_or_default();
            let n = count - c0;
            (n > 0.0).then(|| (stage.clone(), ((sum - s0) / n * 1e4).round() / 10.0))
        })
        .collect();
    out.sort_by(|a, b| b.1.total_cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
    out
}

/// A plain HTTP/1.1 GET (the load generator needs no HTTP client crate for one scrape).
async fn http_get(url: &str) -> Result<String> {
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let rest = url
        .strip_prefix("http://")
        .context("--metrics must be an http:// URL")?;
    let (host, path) = rest.split_once('/').unwrap_or((rest, ""));
    let mut conn = tokio::net::TcpStream::connect(host).await?;
    conn.write_all(
        format!("GET /{path} HTTP/1.1\r\nHost: {host}\r\nConnection: close\r\n\r\n").as_bytes(),
    )
    .await?;
    let mut buf = Vec::new();
    conn.read_to_end(&mut buf).await?;
    let text = String::from_utf8_lossy(&buf).into_owned();
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.to_string())
        .unwrap_or_default();
    Ok(body)
}

/// Runs the load and prints one JSON report.
/// Runs the load and prints the report.
pub fn run(args: Args) -> Result<()> {
    let opts = LoadOptions {
        server: args.server,
        metrics: args.metrics,
        profile: args.profile,
        robots: args.robots,
        speed: args.speed,
        duration_s: args.duration,
        token: args.token,
        episodes: args.episodes,
        sample_s: args.sample_every,
    };
    super::async_runtime()?.block_on(load(opts))
}

async fn load(opts: LoadOptions) -> Result<()> {
    if opts.robots == 0 || opts.episodes.is_empty() {
        bail!("give at least one robot and one episode");
    }
    let recordings: Vec<Recording> = opts
        .episodes
        .iter()
        .map(|p| record(p, &Default::default()).with_context(|| format!("episode {}", p.display())))
        .collect::<Result<_>>()?;
    let image_rate = recordings[0]
        .image_rate_hz()
        .map_or(f64::NAN, |r| r * opts.speed);
    let before = match &opts.metrics {
        Some(u) => scrape(u).await,
        None => None,
    };
    let started = Instant::now();
    let deadline = started + Duration::from_secs_f64(opts.duration_s.max(0.0));
    let shared = Arc::new(Shared::default());
    let opts = Arc::new(opts);
    let recordings = Arc::new(recordings);
    let connect = ClientOptions {
        token: opts.token.clone(),
        ..ClientOptions::default()
    };
    let mut tasks = Vec::new();
    for robot in 0..opts.robots {
        let (o, recordings, shared) = (opts.clone(), recordings.clone(), shared.clone());
        // One connection per robot, as separate robots would have.
        let client = Client::connect(&opts.server, connect.clone()).await?;
        tasks.push(tokio::spawn(async move {
            let mut n = 0;
            while Instant::now() < deadline {
                let rec = &recordings[(robot + n) % recordings.len()];
                if let Err(e) = one_session(&client, &o, robot, n, rec, deadline, &shared).await {
                    shared
                        .tally
                        .lock()
                        .await
                        .errors
                        .push(format!("robot {robot}: {e:#}"));
                    // A refused robot tries again a second later.
                    tokio::time::sleep(Duration::from_secs(1)).await;
                }
                n += 1;
            }
        }));
        // Stagger the robots over one image period so their frames do not arrive in
        // lock-step.
        tokio::time::sleep(Duration::from_millis(100 / opts.robots as u64)).await;
    }
    let mut peak_rss = before.as_ref().map_or(0.0, |s| s.rss_bytes);
    let mut middle_rss = None;
    // The timeline: per interval, the scores received and the server's CPU and RSS, so a
    // long (soak) run shows whether throughput stays steady and memory flat.
    let mut timeline = Vec::new();
    let mut last_sample = (started, 0u64, before.clone());
    while tasks.iter().any(|t| !t.is_finished()) {
        tokio::time::sleep(Duration::from_millis(500)).await;
        let sample = match &opts.metrics {
            Some(u) => scrape(u).await,
            None => None,
        };
        if let Some(s) = &sample {
            peak_rss = peak_rss.max(s.rss_bytes);
            if middle_rss.is_none() && started.elapsed().as_secs_f64() >= opts.duration_s / 2.0 {
                middle_rss = Some(s.rss_bytes);
            }
        }
        let since = last_sample.0.elapsed().as_secs_f64();
        if opts.sample_s > 0.0 && since >= opts.sample_s {
            let scores = shared.live_scores.load(Ordering::Relaxed);
            let cpu = match (&last_sample.2, &sample) {
                (Some(a), Some(b)) => Some((b.cpu_s - a.cpu_s) / since),
                _ => None,
            };
            timeline.push(json!({
                "t_s": (started.elapsed().as_secs_f64() * 10.0).round() / 10.0,
                "scores_per_s": (scores - last_sample.1) as f64 / since,
                "server_cpu_cores": cpu,
                "rss_mib": sample.as_ref().map(|s| (s.rss_bytes / (1 << 20) as f64 * 10.0).round() / 10.0),
            }));
            last_sample = (Instant::now(), scores, sample.or(last_sample.2));
        }
    }
    for t in tasks {
        let _ = t.await;
    }
    let elapsed = started.elapsed().as_secs_f64();
    let after = match &opts.metrics {
        Some(u) => scrape(u).await,
        None => None,
    };
    let mut t = shared.tally.lock().await;
    t.latencies_s.sort_by(f64::total_cmp);
    t.server_latencies_s.sort_by(f64::total_cmp);
    let mb = |b: f64| (b / (1 << 20) as f64 * 10.0).round() / 10.0;
    let server = match (&before, &after) {
        (Some(b), Some(a)) => json!({
            "cpu_cores_busy": (a.cpu_s - b.cpu_s) / elapsed,
            "cpu_s_per_robot_second": (a.cpu_s - b.cpu_s) / elapsed / opts.robots as f64,
            "rss_mib_start": mb(b.rss_bytes),
            "rss_mib_middle": middle_rss.map(mb),
            "rss_mib_end": mb(a.rss_bytes),
            "rss_mib_peak": mb(peak_rss),
            // Mean ms per scored frame of each stage ("total" is the scorer's whole push;
            // decode, record and live are the worker's own).
            "stage_ms": stage_means_ms(b, a)
                .into_iter()
                .map(|(k, v)| (k, json!(v)))
                .collect::<serde_json::Map<_, _>>(),
        }),
        _ => serde_json::Value::Null,
    };
    let ms = |v: Option<f64>| v.map(|s| (s * 1e4).round() / 10.0);
    let report = json!({
        "robots": opts.robots,
        "image_rate_hz_per_robot": image_rate,
        "duration_s": elapsed,
        "sessions": t.sessions,
        "images_sent": t.images,
        "scores_received": t.scores,
        "scores_per_s": t.scores as f64 / elapsed,
        "scores_per_s_per_robot": t.scores as f64 / elapsed / opts.robots as f64,
        "unscored_images": t.images.saturating_sub(t.scores),
        "dropped_reported": t.dropped_events,
        "latency_ms": {
            "p50": ms(percentile(&t.latencies_s, 0.5)),
            "p95": ms(percentile(&t.latencies_s, 0.95)),
            "p99": ms(percentile(&t.latencies_s, 0.99)),
            "max": ms(t.latencies_s.last().copied()),
        },
        "server_latency_ms": {
            "p50": ms(percentile(&t.server_latencies_s, 0.5)),
            "p99": ms(percentile(&t.server_latencies_s, 0.99)),
        },
        "server": server,
        "timeline": timeline,
        "errors": t.errors.iter().take(10).collect::<Vec<_>>(),
        "error_count": t.errors.len(),
    });
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stage_means_come_from_the_histograms_sums_and_counts() {
        let before = parse_sample(
            "process_cpu_seconds_total 1\nprocess_resident_memory_bytes 100\n\
             vamos_stage_seconds_sum{stage=\"flow\"} 0.5\n\
             vamos_stage_seconds_count{stage=\"flow\"} 10\n",
        )
        .unwrap();
        let after = parse_sample(
            "process_cpu_seconds_total 3\nprocess_resident_memory_bytes 200\n\
             vamos_stage_seconds_bucket{stage=\"flow\",le=\"0.01\"} 12\n\
             vamos_stage_seconds_sum{stage=\"flow\"} 0.9\n\
             vamos_stage_seconds_count{stage=\"flow\"} 30\n\
             vamos_stage_seconds_sum{stage=\"decode\"} 0.2\n\
             vamos_stage_seconds_count{stage=\"decode\"} 20\n\
             vamos_stage_seconds_sum{stage=\"model\"} 0\n\
             vamos_stage_seconds_count{stage=\"model\"} 0\n",
        )
        .unwrap();
        assert_eq!(after.cpu_s, 3.0);
        // flow: 0.4 s over 20 new frames; decode 0.2 s over 20; model never ran.
        assert_eq!(
            stage_means_ms(&before, &after),
            vec![("flow".to_string(), 20.0), ("decode".to_string(), 10.0)]
        );
        assert!(parse_sample("vamos_stage_seconds_sum{stage=\"x\"} 1\n").is_none());
    }
}
