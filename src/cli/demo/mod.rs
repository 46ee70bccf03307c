//! `vamos demo`: the whole product on one machine with nothing but the binary. It unpacks
//! the embedded demo assets (the simulator's arm, a small model trained on simulated
//! nominal episodes, a calibrated profile, labelled test episodes; see
//! `assets/demo/README.md`), starts a vamos server in-process on loopback, streams every
//! episode to it over gRPC as concurrent robots, shows their progress live, and writes a
//! report (markdown + PNG plots + JSON).

mod report;

use super::score::expand_episodes;
use anyhow::{Context, Result, bail};
use report::{ReportContext, write_report};
use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use vamos::api::proto::{self, stream_request::Message as In};
use vamos::client::replay::{Recording, record};
use vamos::client::{Client, ClientError, ClientOptions, Pace, SessionSummary, Update};
use vamos::config::Settings;
use vamos::episode::Labels;
use vamos::model::ModelError;
use vamos::service::{RunningServer, Server};
use vamos::session::ProfileCatalog;
use vamos::setup::{Setup, SetupError};

/// The embedded assets: `(path relative to assets/demo, bytes)`, listed by build.rs.
const ASSETS: &[(&str, &[u8])] = include!(concat!(env!("OUT_DIR"), "/demo_assets.rs"));

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Output folder (report.md, report.json, plots/, the unpacked assets/).
    #[arg(short, long, default_value = "vamos-demo")]
    pub out: PathBuf,
    /// Use this profile instead of the embedded one (needs --episodes).
    #[arg(long)]
    pub profile: Option<PathBuf>,
    /// Labelled episodes (.mcap files or folders) instead of the embedded ones.
    #[arg(long, num_args = 1..)]
    pub episodes: Vec<PathBuf>,
    /// Robots streaming at once (0: one per episode, all at once).
    #[arg(long, default_value_t = 0)]
    pub robots: usize,
    /// Replay at the recorded rate times this factor (1.0: real time) instead of as
    /// fast as the server scores.
    #[arg(long)]
    pub speed: Option<f64>,
    /// No live progress table: one line per finished episode.
    #[arg(long)]
    pub quiet: bool,
    /// Keep the server and its live view (`/ui`) up after the report, replaying the
    /// episodes at their recorded rate until Ctrl-C (prints the page's URL).
    #[arg(long, conflicts_with = "vision")]
    pub serve: bool,
    /// Run the embedded demo without the flow predictor (`e_o`): no ONNX Runtime is
    /// needed. The demo does this by itself when ONNX Runtime cannot be found or fetched
    /// (a machine without network).
    #[arg(long, conflicts_with_all = ["profile", "vision"])]
    pub no_model: bool,
    /// Run the vision-core demo instead (TV-L1 and registration on synthetic pairs).
    #[arg(long)]
    pub vision: bool,
    /// Vision demo: image width in pixels.
    #[arg(long, default_value_t = 320, requires = "vision")]
    pub width: usize,
    /// Vision demo: image height in pixels.
    #[arg(long, default_value_t = 240, requires = "vision")]
    pub height: usize,
    /// Vision demo: worker threads (0 = one per core; default from the settings).
    #[arg(long, requires = "vision")]
    pub threads: Option<usize>,
}

/// `vamos demo`: the service demo, or with `--vision` the vision-core demo.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    if args.vision {
        return super::vision_demo::run(
            &args.out,
            args.width,
            args.height,
            super::resolve_threads(args.threads.unwrap_or(settings.vision.threads)),
            &settings.vision.registration,
        );
    }
    let opts = DemoOptions {
        out: args.out,
        profile: args.profile,
        episodes: args.episodes,
        robots: args.robots,
        speed: args.speed,
        quiet: args.quiet,
        serve: args.serve,
        no_model: args.no_model,
    };
    super::async_runtime()?.block_on(demo(settings, opts))
}

/// Options of the service demo.
struct DemoOptions {
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
    /// Keep serving after the report (see [`Args::serve`]).
    pub serve: bool,
    /// The embedded demo without the flow predictor (see [`Args::no_model`]).
    pub no_model: bool,
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
    /// Refused for capacity, waiting to open again.
    waiting: bool,
}

/// How long an episode the server refuses for capacity waits for room, in all, and
/// between tries.
const CAPACITY_WAIT: Duration = Duration::from_secs(120);
const CAPACITY_RETRY: Duration = Duration::from_millis(500);

/// One episode streamed and answered.
struct Streamed {
    name: String,
    labels: Option<Labels>,
    summary: SessionSummary,
    /// Seconds from each image sent to its score, client side.
    latencies_s: Vec<f64>,
}

/// The embedded profile without a model (its own calibration): what the demo runs when
/// ONNX Runtime is not available, or with `--no-model`.
const NO_MODEL_PROFILE: &str = "profile-no-model.toml";

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
async fn demo(settings: &Settings, opts: DemoOptions) -> Result<()> {
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
            let mut profile = unpack(&assets)?;
            if opts.no_model {
                profile = assets.join(NO_MODEL_PROFILE);
            }
            let episodes = if opts.episodes.is_empty() {
                expand_episodes(&[assets.join("episodes")])?
            } else {
                expand_episodes(&opts.episodes)?
            };
            (profile, episodes)
        }
    };
    let load = |path: PathBuf| {
        let settings = settings.clone();
        async move {
            tokio::task::spawn_blocking(move || Setup::load(&settings, &path))
                .await
                .context("the profile loader failed")
        }
    };
    let (setup, profile_path) = match load(profile_path.clone()).await? {
        Ok(setup) => (setup, profile_path),
        // The embedded demo on a machine without ONNX Runtime (and no network to fetch
        // it): the same demo without the flow predictor, calibrated on its own.
        Err(SetupError::Model {
            source: ModelError::Runtime(why),
            ..
        }) if opts.profile.is_none() => {
            println!(
                "ONNX Runtime is not available ({why}): the demo runs without the flow \
                 predictor (e_o), every other detector as calibrated; `--no-model` says so \
                 from the start"
            );
            let path = profile_path.with_file_name(NO_MODEL_PROFILE);
            let setup = load(path.clone())
                .await?
                .with_context(|| format!("cannot load profile {}", path.display()))?;
            (setup, path)
        }
        Err(e) => {
            return Err(anyhow::Error::new(e)
                .context(format!("cannot load profile {}", profile_path.display())));
        }
    };
    let profile_name = setup.profile.file.name.clone();
    let alarm = setup.profile.alarm_threshold();
    let thresholds = setup.detector_thresholds();
    let rule = setup.profile.file.alarm_events.unwrap_or_default();
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

    let recordings = read_recordings(&episode_paths, &setup.episode)?;
    let episode_config = setup.episode.clone();

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
    // What the first run uses (and, on a machine without it, fetched).
    if let Some(rt) = vamos::model::runtime::loaded() {
        println!(
            "ONNX Runtime: {} ({}; {:.1} s to find and load)",
            rt.path.display(),
            rt.source.describe(),
            rt.setup_secs
        );
    }
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

    let again = opts.serve;
    let result = stream_all(&client, &profile_name, recordings, &opts, queue_depth).await;
    let serving = match (again, &result) {
        (true, Ok(_)) => Some(server),
        _ => {
            let stop = shutdown(server).await;
            if result.is_ok() {
                stop?;
            }
            None
        }
    };
    let streamed = result?;
    let report_path = write_report(
        &ReportContext {
            out: &opts.out,
            profile_path: &profile_path,
            profile_name: &profile_name,
            model: model_desc.as_deref(),
            thresholds,
            rule,
            episodes: &episode_paths,
            episode_config: &episode_config,
        },
        &streamed,
        started.elapsed(),
    )?;
    println!("report: {}", report_path.display());
    let Some(server) = serving else {
        return Ok(());
    };
    // --serve: the page stays up and the robots keep coming (at their recorded rate).
    println!(
        "live view: http://{}/ui (the episodes replay at their recorded rate; Ctrl-C stops)",
        server.rest_addr
    );
    let replay = DemoOptions {
        speed: Some(1.0),
        quiet: true,
        ..opts
    };
    let looped = async {
        loop {
            let round = read_recordings(&episode_paths, &episode_config)?;
            stream_all(&client, &profile_name, round, &replay, queue_depth).await?;
        }
        // Only errors leave the loop: the type of what the block returns.
        #[allow(unreachable_code)]
        Ok::<(), anyhow::Error>(())
    };
    let ended: Result<()> = tokio::select! {
        r = looped => r,
        _ = tokio::signal::ctrl_c() => Ok(()),
    };
    shutdown(server).await?;
    ended
}

/// The episodes as recordings, with their names and labels.
fn read_recordings(
    paths: &[PathBuf],
    config: &vamos::episode::EpisodeConfig,
) -> Result<Vec<(String, Option<Labels>, Recording)>> {
    let mut recordings = Vec::new();
    for path in paths {
        let name = path
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default();
        let labels =
            Labels::load_for(path).with_context(|| format!("labels of {}", path.display()))?;
        let rec = record(path, config)
            .with_context(|| format!("cannot read episode {}", path.display()))?;
        recordings.push((name, labels, rec));
    }
    Ok(recordings)
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
                anomaly_maps: true,
                image_rate_hz: 0.0,
            };
            let mut sent_at: BTreeMap<i64, Instant> = BTreeMap::new();
            let mut latencies_s = Vec::new();
            let t0 = rec.messages.iter().find_map(|(_, m)| match m {
                In::Image(img) => Some(img.stamp_ns),
                _ => None,
            });
            // A session the server refuses for capacity (the robots before it measured
            // more load than it has room for) waits for room and opens again: the demo's
            // episodes are a batch, not robots that must be live now.
            let mut waited = Duration::ZERO;
            let result = loop {
                let result = client
                    .replay(open.clone(), &rec, pace, |u| {
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
                                        p.first_alarm_s =
                                            t0.map(|t0| (s.stamp_ns - t0) as f64 / 1e9);
                                    }
                                }
                            }
                            Update::Event(e) => {
                                if e.kind == proto::session_event::Kind::FramesDropped as i32 {
                                    p.dropped = e.count;
                                }
                            }
                            Update::Alarm(_) => {}
                        }
                    })
                    .await;
                let refused = result.as_ref().is_err_and(ClientError::is_over_capacity);
                let scored = progress.lock().unwrap_or_else(|e| e.into_inner())[i].scored;
                if !refused || scored > 0 || waited >= CAPACITY_WAIT {
                    break result;
                }
                {
                    let mut all = progress.lock().unwrap_or_else(|e| e.into_inner());
                    all[i].sent = 0;
                    all[i].waiting = true;
                }
                sent_at.clear();
                tokio::time::sleep(CAPACITY_RETRY).await;
                waited += CAPACITY_RETRY;
            };
            let mut all = progress.lock().unwrap_or_else(|e| e.into_inner());
            all[i].waiting = false;
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
        (None, false) if p.waiting => "waiting for capacity".into(),
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
