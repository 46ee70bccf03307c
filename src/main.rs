//! The `vamos` binary: CLI -> settings -> run. The only place that uses `anyhow`.

mod cli;

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Instant;
use vamos::config::Settings;
use vamos::telemetry::{self, LogFormat};
use vamos::vision::flow::{FlowEstimator, FlowParams};
use vamos::vision::flowio::{write_flo, write_flow_png};
use vamos::vision::preprocess::equalize_histogram;
use vamos::vision::registration::Registrar;
use vamos::vision::{FlowField, GrayImage};

/// vamos: Visual Anomaly MOnitoring Service.
#[derive(Parser, Debug)]
#[command(name = "vamos", version, about, long_about = None)]
struct Cli {
    /// Settings file (TOML). Environment variables `VAMOS_SECTION__KEY` override it.
    #[arg(long, global = true, env = "VAMOS_CONFIG")]
    config: Option<PathBuf>,
    /// Log filter, e.g. `info` or `vamos=debug` (overrides the settings).
    #[arg(long, global = true)]
    log_level: Option<String>,
    /// Log format (overrides the settings).
    #[arg(long, global = true, value_enum)]
    log_format: Option<LogFormat>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// The main job on embedded data: start a vamos server in-process, stream the bundled
    /// simulated episodes (nominal and anomalous) to it over gRPC as concurrent robots,
    /// show their scores live, and write a report with plots. `--vision` instead runs the
    /// vision core on synthetic image pairs with exactly known motion.
    Demo {
        /// Output folder (report.md, report.json, plots/, the unpacked assets/).
        #[arg(short, long, default_value = "vamos-demo")]
        out: PathBuf,
        /// Use this profile instead of the embedded one (needs --episodes).
        #[arg(long)]
        profile: Option<PathBuf>,
        /// Labelled episodes (.mcap files or folders) instead of the embedded ones.
        #[arg(long, num_args = 1..)]
        episodes: Vec<PathBuf>,
        /// Robots streaming at once (0: one per episode, all at once).
        #[arg(long, default_value_t = 0)]
        robots: usize,
        /// Replay at the recorded rate times this factor (1.0: real time) instead of as
        /// fast as the server scores.
        #[arg(long)]
        speed: Option<f64>,
        /// No live progress table: one line per finished episode.
        #[arg(long)]
        quiet: bool,
        /// Run the vision-core demo instead (TV-L1 and registration on synthetic pairs).
        #[arg(long)]
        vision: bool,
        /// Vision demo: image width in pixels.
        #[arg(long, default_value_t = 320, requires = "vision")]
        width: usize,
        /// Vision demo: image height in pixels.
        #[arg(long, default_value_t = 240, requires = "vision")]
        height: usize,
        /// Vision demo: worker threads (0 = one per core; default from the settings).
        #[arg(long, requires = "vision")]
        threads: Option<usize>,
    },
    /// TV-L1 optical flow from image A to image B (forward flow, pixels).
    Flow {
        /// First image (PNG or JPEG; colour is converted to gray).
        a: PathBuf,
        /// Second image, same size.
        b: PathBuf,
        /// Colour-coded flow (Middlebury colour wheel), PNG.
        #[arg(short, long)]
        output: PathBuf,
        /// Also write the raw field in Middlebury `.flo` format.
        #[arg(long)]
        raw: Option<PathBuf>,
        /// Parameter preset: `default` (OpenCV DualTVL1's defaults), `realtime`,
        /// `realtime-hq` or `balanced`; without it the settings' `[vision.flow]` apply.
        #[arg(long)]
        preset: Option<String>,
        /// Worker threads (0 = one per core; default from the settings).
        #[arg(long)]
        threads: Option<usize>,
        /// Histogram-equalise both images first (as the detection pipeline does).
        #[arg(long)]
        equalize: bool,
        /// Saturation magnitude of the colour coding in pixels (default: the largest).
        #[arg(long)]
        max_flow: Option<f32>,
        /// Compute the flow this many times (timing).
        #[arg(long, default_value_t = 1)]
        repeat: usize,
        /// Print a JSON line with the flow computation time on stdout.
        #[arg(long)]
        timing: bool,
    },
    /// Fourier-Mellin registration of A onto B; prints one JSON object.
    Register {
        /// First image.
        a: PathBuf,
        /// Second image, same size.
        b: PathBuf,
        /// Pixels to ignore (non-zero = ignore), same size, e.g. the robot body.
        #[arg(long)]
        mask: Option<PathBuf>,
        /// Register this many times (timing).
        #[arg(long, default_value_t = 1)]
        repeat: usize,
        /// Add `ms_min` and `ms_median` of the registration alone to the JSON.
        #[arg(long)]
        timing: bool,
    },
    /// Run the service: gRPC streaming sessions, REST administration, /metrics. Stops
    /// gracefully on SIGTERM or Ctrl-C.
    Serve {
        /// gRPC address (default from the settings: 127.0.0.1:8081).
        #[arg(long)]
        grpc_addr: Option<String>,
        /// REST and /metrics address (default 127.0.0.1:8080); the gRPC address serves
        /// both on one port.
        #[arg(long)]
        rest_addr: Option<String>,
        /// Data directory (models, robots, profiles, calibrations).
        #[arg(long)]
        data_dir: Option<PathBuf>,
        /// Profile files to serve (TOML, as `vamos score --profile` takes); repeatable.
        #[arg(long = "profile")]
        profiles: Vec<PathBuf>,
    },
    /// Ask a running server's gRPC health service (grpc.health.v1) whether it serves;
    /// prints one JSON object, exits 0 when SERVING and 1 otherwise (container and
    /// service-manager health checks).
    Health {
        /// gRPC address of the server.
        #[arg(long, default_value = "http://127.0.0.1:8081")]
        server: String,
        /// Service to ask about ("" is the whole server).
        #[arg(long, default_value = "vamos.v1.Monitor")]
        service: String,
        /// PEM file of the CA for an https:// server.
        #[arg(long)]
        ca: Option<PathBuf>,
        /// Give up after this many seconds.
        #[arg(long, default_value_t = 5.0)]
        timeout: f64,
    },
    /// Stream a recorded episode (MCAP) to a running server as a live robot and print
    /// every answer as a JSON line (scores and session events); a summary goes to stderr.
    Stream {
        /// The episode.
        episode: PathBuf,
        /// gRPC URL of the server (`https://` needs --ca).
        #[arg(long, default_value = "http://127.0.0.1:8081")]
        server: String,
        /// Profile the session uses.
        #[arg(long)]
        profile: String,
        /// Replay at the recorded rate times this factor (1.0: real time).
        #[arg(long, default_value_t = 1.0, conflicts_with = "fast")]
        speed: f64,
        /// As fast as the server scores instead, with at most --window images unanswered.
        #[arg(long)]
        fast: bool,
        /// Images in flight with --fast; below the server's queue_depth (default 8) no
        /// image is dropped.
        #[arg(long, default_value_t = 4, requires = "fast")]
        window: usize,
        /// Upload the whole file for batch scoring (Monitor.ScoreEpisode) instead.
        #[arg(long, conflicts_with_all = ["fast", "speed"])]
        batch: bool,
        /// Robot id reported to the server.
        #[arg(long, default_value = "vamos-stream")]
        robot_id: String,
        /// Session id (for resumption and seeding; default: the episode's file stem).
        #[arg(long)]
        session_id: Option<String>,
        /// Bearer token (default: $VAMOS_ROBOT_TOKEN).
        #[arg(long, env = "VAMOS_ROBOT_TOKEN", hide_env_values = true)]
        token: Option<String>,
        /// CA certificate (PEM) of an https:// server.
        #[arg(long)]
        ca: Option<PathBuf>,
    },
    /// Replay episodes as N robots streaming to a running server; prints the achieved
    /// rate, score latency percentiles, drops and the server's CPU and memory (JSON).
    Loadgen {
        /// Episodes (MCAP), replayed round-robin.
        #[arg(required = true)]
        episodes: Vec<PathBuf>,
        /// gRPC URL of the server.
        #[arg(long, default_value = "http://127.0.0.1:8081")]
        server: String,
        /// The server's /metrics URL (CPU and memory figures), e.g.
        /// http://127.0.0.1:8080/metrics.
        #[arg(long)]
        metrics: Option<String>,
        /// Profile the sessions use.
        #[arg(long)]
        profile: String,
        /// Robots streaming at once.
        #[arg(long, default_value_t = 1)]
        robots: usize,
        /// Replay speed (1.0: recorded timing, e.g. 10 Hz images).
        #[arg(long, default_value_t = 1.0)]
        speed: f64,
        /// Run time, seconds.
        #[arg(long, default_value_t = 30.0)]
        duration: f64,
        /// Bearer token (robot role).
        #[arg(long, env = "VAMOS_LOADGEN_TOKEN", hide_env_values = true)]
        token: Option<String>,
        /// Seconds between the samples of the report's `timeline` (scores/s, server CPU
        /// and RSS per interval; 0: none).
        #[arg(long, default_value_t = 60.0)]
        sample_every: f64,
    },
    /// Score recorded episodes (ROS 2 bags in MCAP) with a profile: one JSON summary line
    /// per episode; with --out the per-frame scores (JSON lines) and, with --mcap, a bag of
    /// the images plus score topics for Foxglove or `ros2 bag play`.
    Score {
        /// The profile (TOML; see README "Profiles").
        #[arg(long)]
        profile: PathBuf,
        /// Episodes: .mcap files or folders of them.
        #[arg(required = true)]
        episodes: Vec<PathBuf>,
        /// Output folder for `<episode>.scores.jsonl` (and `.scored.mcap`).
        #[arg(short, long)]
        out: Option<PathBuf>,
        /// Also write `<episode>.scored.mcap`: input images, /vamos/score, /vamos/anomaly,
        /// /vamos/e_c, /vamos/e_b, /vamos/e_o, /vamos/heatmap.
        #[arg(long)]
        mcap: bool,
        /// No progress bars (they are drawn on stderr only when it is a terminal).
        #[arg(long)]
        no_progress: bool,
    },
    /// Calibrate a profile's thresholds on nominal episodes: e_c and e_b maxima (the
    /// paper) and a split-conformal threshold on the fused score from held-out episodes.
    Calibrate {
        /// The profile; the calibration is written beside it (`<stem>.calibration.json`).
        #[arg(long)]
        profile: PathBuf,
        /// Nominal training episodes (.mcap files or folders).
        #[arg(required = true)]
        episodes: Vec<PathBuf>,
        /// Held-out nominal episodes for the conformal threshold.
        #[arg(long, num_args = 1..)]
        holdout: Vec<PathBuf>,
        /// Per-episode false-alarm budget of the conformal threshold.
        #[arg(long, default_value_t = 0.1)]
        alpha: f64,
        /// No progress bars (they are drawn on stderr only when it is a terminal).
        #[arg(long)]
        no_progress: bool,
    },
    /// Evaluate a profile on labelled episodes: frame-level AUC-ROC and AUC-PR (pooled),
    /// per anomaly type, episode false-alarm rate and detection delay at the alarm
    /// threshold; prints the report as JSON.
    Eval {
        /// The profile (calibrated).
        #[arg(long)]
        profile: PathBuf,
        /// Labelled episodes (.mcap with `<stem>.labels.json` or a label topic), files or
        /// folders.
        #[arg(long, required = true, num_args = 1..)]
        episodes: Vec<PathBuf>,
        /// Also write the report here.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Write plots here: a score timeline per episode, roc.png, pr.png.
        #[arg(long)]
        plots: Option<PathBuf>,
        /// Run the paper's ablation (4 flow variants x OF only / +body / +body+camera) and
        /// write it as markdown here.
        #[arg(long)]
        ablation: Option<PathBuf>,
        /// A model per flow variant for the ablation, `VARIANT=PATH` (repeatable); the
        /// profile's model serves its own variant.
        #[arg(long)]
        variant_model: Vec<String>,
        /// No progress bars (they are drawn on stderr only when it is a terminal).
        #[arg(long)]
        no_progress: bool,
    },
    /// Print the effective settings (defaults + file + environment) as TOML.
    Config,
    /// Write the flow predictor's training data (64x64 network inputs of every processed
    /// frame) from nominal episodes: one .npy per episode plus manifest.json.
    ExportDataset {
        /// Episodes: ROS 2 bags (.mcap, or folders of them; topics from `[episode]`), or
        /// image folders: images (.png/.jpg) in name order, or listed with stamps in
        /// `frames.csv` (`file,stamp_ns`), joint states in `joints.csv`.
        #[arg(required = true)]
        episodes: Vec<PathBuf>,
        /// Output folder.
        #[arg(short, long)]
        out: PathBuf,
        /// Take the robot, camera, pipeline parameters, TV-L1 preset and topics from this
        /// profile (the flags below still override).
        #[arg(long)]
        profile: Option<PathBuf>,
        /// Flow variant: plain, registered, masked or masked_registered (default:
        /// `pipeline.frames.variant`). Masked variants need --robot and --camera.
        #[arg(long)]
        variant: Option<vamos::pipeline::FlowVariant>,
        /// Robot (URDF file, package folder or archive): with --camera, every frame's body
        /// mask is rendered from the episode's joints.csv (`stamp_ns,JOINT,...`).
        #[arg(long)]
        robot: Option<PathBuf>,
        /// Camera JSON (as `vamos render --camera`).
        #[arg(long)]
        camera: Option<PathBuf>,
        /// Report image stamps further than this from a joint sample, milliseconds.
        #[arg(long, default_value_t = 100.0)]
        max_joint_gap_ms: f64,
        /// Process every N-th image (default: `pipeline.stride`).
        #[arg(long)]
        stride: Option<usize>,
        /// Frame rate of folders without frames.csv.
        #[arg(long, default_value_t = 10.0)]
        fps: f64,
        /// TV-L1 preset (default: the settings' `[vision.flow]`).
        #[arg(long)]
        preset: Option<String>,
        /// Worker threads (0 = one per core; default from the settings).
        #[arg(long)]
        threads: Option<usize>,
        /// No progress bars (they are drawn on stderr only when it is a terminal).
        #[arg(long)]
        no_progress: bool,
    },
    /// Draw the robot as its camera sees it (mask | depth | expected body flow, side by
    /// side) and print a JSON summary: the first check of a robot set-up.
    Render {
        /// URDF file, robot package folder, or .zip / .tar.gz package archive.
        #[arg(long)]
        robot: PathBuf,
        /// JSON object of joint name -> position at time t.
        #[arg(long)]
        joints: PathBuf,
        /// Joint positions at t-1: adds the expected body flow t-1 -> t.
        #[arg(long)]
        previous_joints: Option<PathBuf>,
        /// Camera JSON: {"frame": LINK, "convention": "optical"|"body", "width": W,
        /// "height": H, and "fx","fy","cx","cy" or "k" (CameraInfo) or "hfov_deg"}.
        #[arg(long)]
        camera: PathBuf,
        /// Output PNG.
        #[arg(short, long)]
        out: PathBuf,
        /// A real camera image to draw the mask over.
        #[arg(long)]
        background: Option<PathBuf>,
        /// Render width (intrinsics scaled; default: the camera's).
        #[arg(long)]
        width: Option<u32>,
        /// Render height (default: keeps the camera's aspect ratio).
        #[arg(long)]
        height: Option<u32>,
        /// The paper's expected flow (TV-L1 on two shaded renders) instead of the exact one.
        #[arg(long)]
        tvl1: bool,
    },
    /// Robot descriptions (URDF + meshes).
    Robot {
        #[command(subcommand)]
        command: RobotCommand,
    },
    /// Recorded episodes (ROS 2 bags in MCAP).
    Episode {
        #[command(subcommand)]
        command: EpisodeCommand,
    },
    /// Flow-predictor model bundles and the ONNX Runtime library.
    Model {
        #[command(subcommand)]
        command: ModelCommand,
    },
}

#[derive(Subcommand, Debug)]
enum RobotCommand {
    /// Load a robot and print its joints, links, visuals, warnings (and link poses for
    /// given joint positions) as one JSON object.
    Inspect {
        /// URDF file, robot package folder, or .zip / .tar.gz package archive.
        #[arg(long)]
        robot: PathBuf,
        /// JSON object of joint name -> position (rad or m): adds `poses` and
        /// `out_of_limits`.
        #[arg(long)]
        joints: Option<PathBuf>,
    },
}

#[derive(Subcommand, Debug)]
enum EpisodeCommand {
    /// Print what a bag holds (topics, chosen topics, counts, labels, camera info) as one
    /// JSON object.
    Inspect {
        /// The bag (.mcap).
        bag: PathBuf,
        /// Also read every frame: count frames, warnings and errors.
        #[arg(long)]
        frames: bool,
    },
    /// Copy a bag through vamos's reader and writer (images, camera info, joints, URDF,
    /// plus per-frame diagnostics); recovers the valid part of a damaged bag.
    Copy {
        /// The input bag.
        input: PathBuf,
        /// The output bag (replaced).
        output: PathBuf,
    },
}

#[derive(Subcommand, Debug)]
enum ModelCommand {
    /// Read and validate a model bundle (.vamos); print its summary as JSON (exit code 1
    /// when invalid).
    Inspect {
        /// The bundle.
        bundle: PathBuf,
    },
    /// Find (or download into the cache) and load ONNX Runtime; print where from as JSON.
    Runtime,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    if matches!(cli.command, Command::Serve { .. }) {
        // SAFETY: no thread has been started yet (the async runtime comes later).
        unsafe { vamos::service::auth::take_env_tokens() };
    }
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // Once: through the log when it is set up (it writes to stderr), else plainly.
            let text = error_text(&e);
            let logged = tracing::dispatcher::has_been_set()
                && tracing::level_filters::LevelFilter::current()
                    >= tracing::level_filters::LevelFilter::ERROR;
            if logged {
                tracing::error!("{text}");
            } else {
                eprintln!("error: {text}");
            }
            std::process::ExitCode::FAILURE
        }
    }
}

/// An error and its causes, joined by ": ", leaving out a cause whose text the message
/// already holds (many errors print their source in their own message).
fn error_text(e: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in e.chain() {
        let text = cause.to_string();
        if out.contains(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

fn run(cli: Cli) -> Result<()> {
    let mut settings = Settings::load(cli.config.as_deref())?;
    if let Some(level) = cli.log_level {
        settings.log.level = level;
    } else if matches!(cli.command, Command::Demo { .. })
        && std::env::var_os("VAMOS_LOG__LEVEL").is_none()
        && cli.config.is_none()
    {
        // The demo's terminal is for its progress table: the in-process server's
        // informational logs would bury it (--log-level info brings them back).
        settings.log.level = "warn".into();
    }
    if let Some(format) = cli.log_format {
        settings.log.format = format;
    }
    telemetry::init(&settings.log)?;
    tracing::debug!(settings = ?settings, "effective settings");
    match cli.command {
        Command::Model { command } => match command {
            ModelCommand::Inspect { bundle } => {
                if cli::model::inspect(&bundle, &settings.model)? {
                    Ok(())
                } else {
                    bail!("{} is not a valid model bundle", bundle.display())
                }
            }
            ModelCommand::Runtime => cli::model::runtime(&settings.model),
        },
        Command::Config => {
            print!("{}", toml::to_string_pretty(&settings)?);
            Ok(())
        }
        Command::Health {
            server,
            service,
            ca,
            timeout,
        } => {
            let ca_pem = match ca {
                Some(p) => Some(
                    std::fs::read(&p).with_context(|| format!("cannot read {}", p.display()))?,
                ),
                None => None,
            };
            let limit = std::time::Duration::from_secs_f64(timeout.clamp(0.1, 3600.0));
            let status = async_runtime()?.block_on(async {
                tokio::time::timeout(limit, async {
                    let client = vamos::client::Client::connect(
                        &server,
                        vamos::client::ClientOptions {
                            ca_pem,
                            connect_timeout: Some(limit),
                            ..Default::default()
                        },
                    )
                    .await?;
                    client.health(&service).await
                })
                .await
            });
            let status = match status {
                Ok(Ok(s)) => Ok(s),
                Ok(Err(e)) => Err(("ERROR", e.to_string())),
                Err(_) => Err(("UNREACHABLE", format!("no answer within {timeout} s"))),
            };
            let status = match status {
                Ok(s) => s,
                Err((status, error)) => {
                    println!(
                        "{}",
                        serde_json::json!({ "server": server, "status": status, "error": error })
                    );
                    std::process::exit(1);
                }
            };
            println!(
                "{}",
                serde_json::json!({ "server": server, "service": service, "status": status })
            );
            if status != "SERVING" {
                std::process::exit(1);
            }
            Ok(())
        }
        Command::Stream {
            episode,
            server,
            profile,
            speed,
            fast,
            window,
            batch,
            robot_id,
            session_id,
            token,
            ca,
        } => async_runtime()?.block_on(cli::stream::run(cli::stream::StreamOptions {
            episode,
            server,
            profile,
            mode: if batch {
                cli::stream::Mode::Batch
            } else if fast {
                cli::stream::Mode::Pace(vamos::client::Pace::Window(window))
            } else {
                cli::stream::Mode::Pace(vamos::client::Pace::Recorded { speed })
            },
            robot_id,
            session_id,
            token,
            ca,
            episode_config: settings.episode.clone(),
        })),
        Command::Loadgen {
            episodes,
            server,
            metrics,
            profile,
            robots,
            speed,
            duration,
            token,
            sample_every,
        } => async_runtime()?.block_on(cli::loadgen::run(cli::loadgen::LoadOptions {
            server,
            metrics,
            profile,
            robots,
            speed,
            duration_s: duration,
            token,
            episodes,
            sample_s: sample_every,
        })),
        Command::Serve {
            grpc_addr,
            rest_addr,
            data_dir,
            profiles,
        } => {
            if let Some(a) = grpc_addr {
                settings.service.grpc_addr = a;
            }
            if let Some(a) = rest_addr {
                settings.service.rest_addr = a;
            }
            if let Some(d) = data_dir {
                settings.service.data_dir = d;
            }
            settings.service.profiles.extend(profiles);
            async_runtime()?.block_on(vamos::service::serve(settings))?;
            Ok(())
        }
        Command::Score {
            profile,
            episodes,
            out,
            mcap,
            no_progress,
        } => cli::score::run(
            &settings,
            &profile,
            &episodes,
            out,
            mcap,
            &cli::progress::Progress::new(no_progress),
        ),
        Command::Calibrate {
            profile,
            episodes,
            holdout,
            alpha,
            no_progress,
        } => cli::calibrate::run(
            &settings,
            cli::calibrate::CalibrateOptions {
                profile,
                episodes,
                holdout,
                alpha,
                progress: cli::progress::Progress::new(no_progress),
            },
        ),
        Command::Eval {
            profile,
            episodes,
            json,
            plots,
            ablation,
            variant_model,
            no_progress,
        } => cli::eval::run(
            &settings,
            cli::eval::EvalOptions {
                profile,
                episodes,
                json,
                plots,
                ablation,
                variant_models: variant_model,
                progress: cli::progress::Progress::new(no_progress),
            },
        ),
        Command::ExportDataset {
            episodes,
            out,
            profile,
            variant,
            mut robot,
            mut camera,
            max_joint_gap_ms,
            stride,
            fps,
            preset,
            threads,
            no_progress,
        } => {
            let threads = resolve_threads(threads.unwrap_or(settings.vision.threads));
            let mut settings = settings.clone();
            if let Some(path) = &profile {
                let p = vamos::pipeline::Profile::load(path)?;
                if let Some(pipeline) = p.file.pipeline {
                    settings.pipeline = pipeline;
                }
                if let Some(preset) = &p.file.flow_preset {
                    settings.vision.flow = vamos::vision::flow::FlowParams::preset(preset)?;
                }
                if let Some(topics) = p.file.topics {
                    settings.episode.topics = topics;
                }
                robot = robot.or(p.file.robot);
                camera = camera.or(p.file.camera);
            }
            let opts = cli::export::ExportOptions {
                episodes,
                out,
                variant,
                stride,
                fps,
                preset,
                robot,
                camera,
                max_joint_gap_ms,
                progress: cli::progress::Progress::new(no_progress),
            };
            pool(threads)?.install(|| cli::export::run(&settings, opts))?;
            Ok(())
        }
        Command::Render {
            robot,
            joints,
            previous_joints,
            camera,
            out,
            background,
            width,
            height,
            tvl1,
        } => {
            let opts = cli::render::RenderOptions {
                robot,
                joints,
                previous_joints,
                camera,
                out,
                background,
                width,
                height,
                tvl1,
            };
            let summary = cli::render::run(&opts, &settings.robot, &settings.render)?;
            println!("{summary}");
            Ok(())
        }
        Command::Episode { command } => {
            let out = match command {
                EpisodeCommand::Inspect { bag, frames } => {
                    cli::episode::inspect(&bag, &settings.episode, frames)?
                }
                EpisodeCommand::Copy { input, output } => {
                    cli::episode::copy(&input, &output, &settings.episode)?
                }
            };
            println!("{out}");
            Ok(())
        }
        Command::Robot {
            command: RobotCommand::Inspect { robot, joints },
        } => {
            let out = cli::robot::inspect(&robot, joints.as_deref(), &settings.robot)?;
            println!("{out}");
            Ok(())
        }
        Command::Flow {
            a,
            b,
            output,
            raw,
            preset,
            threads,
            equalize,
            max_flow,
            repeat,
            timing,
        } => {
            let params = match preset.as_deref() {
                Some(name) => FlowParams::preset(name)?,
                None => settings.vision.flow.clone(),
            };
            let threads = resolve_threads(threads.unwrap_or(settings.vision.threads));
            let (mut ia, mut ib) = (load(&a)?, load(&b)?);
            if equalize {
                ia = equalize_histogram(&ia)?;
                ib = equalize_histogram(&ib)?;
            }
            let pool = pool(threads)?;
            let mut times = Vec::new();
            let mut flow = None;
            // One estimator for every repeat: its buffers are reused, as in a stream.
            let mut est = FlowEstimator::new(params.clone())?;
            for _ in 0..repeat.max(1) {
                let start = Instant::now();
                let f = pool.install(|| flow_of(&mut est, &ia, &ib))?;
                times.push(start.elapsed().as_secs_f64() * 1e3);
                flow = Some(f);
            }
            let flow = flow.context("no flow computed")?;
            write_flow_png(&flow, max_flow, &output)?;
            if let Some(raw) = raw {
                write_flo(&flow, &raw)?;
            }
            let (min, median) = min_median(&mut times);
            tracing::info!(ms_min = min, ms_median = median, threads, "flow computed");
            if timing {
                println!(
                    "{}",
                    json!({
                        "width": flow.width(), "height": flow.height(),
                        "preset": preset.unwrap_or_else(|| "settings".into()),
                        "threads": threads, "repeat": times.len(),
                        "ms_min": min, "ms_median": median,
                    })
                );
            }
            Ok(())
        }
        Command::Register {
            a,
            b,
            mask,
            repeat,
            timing,
        } => {
            let (ia, ib) = (load(&a)?, load(&b)?);
            let mask = match mask {
                Some(path) => {
                    let m = load(&path)?;
                    if m.size() != ia.size() {
                        bail!(
                            "mask {} is {}x{} but the images are {}x{}",
                            path.display(),
                            m.width(),
                            m.height(),
                            ia.width(),
                            ia.height()
                        );
                    }
                    Some(m.data().iter().map(|&v| v > 0.0).collect::<Vec<bool>>())
                }
                None => None,
            };
            let mut registrar = Registrar::new(settings.vision.registration.clone())?;
            let mut times = Vec::new();
            let mut result = None;
            for _ in 0..repeat.max(1) {
                let start = Instant::now();
                result = Some(registrar.register(&ia, &ib, mask.as_deref())?);
                times.push(start.elapsed().as_secs_f64() * 1e3);
            }
            let r = result.context("no registration computed")?;
            let mut out = json!({
                "tx": r.transform.tx_px, "ty": r.transform.ty_px, "scale": r.transform.scale,
                "rotation_deg": r.transform.rotation_deg, "confidence": r.confidence,
            });
            if timing {
                let (min, median) = min_median(&mut times);
                out["ms_min"] = json!(min);
                out["ms_median"] = json!(median);
            }
            println!("{out}");
            Ok(())
        }
        Command::Demo {
            out,
            profile,
            episodes,
            robots,
            speed,
            quiet,
            vision,
            width,
            height,
            threads,
        } => {
            if vision {
                return cli::vision_demo::run(
                    &out,
                    width,
                    height,
                    resolve_threads(threads.unwrap_or(settings.vision.threads)),
                    &settings.vision.registration,
                );
            }
            async_runtime()?.block_on(cli::demo::run(
                &settings,
                cli::demo::DemoOptions {
                    out,
                    profile,
                    episodes,
                    robots,
                    speed,
                    quiet,
                },
            ))
        }
    }
}

fn load(path: &Path) -> Result<GrayImage> {
    Ok(GrayImage::load(path)?)
}

/// The flow `a -> b` from `est`, reset first (so it holds no earlier frame).
fn flow_of(est: &mut FlowEstimator, a: &GrayImage, b: &GrayImage) -> Result<FlowField> {
    est.reset();
    est.push(a)?;
    est.push(b)?
        .context("the estimator returned no flow for the second frame")
}

/// The multi-threaded tokio runtime of the async sub-commands.
fn async_runtime() -> Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .context("cannot start the async runtime")
}

fn resolve_threads(n: usize) -> usize {
    if n == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        n
    }
}

fn pool(threads: usize) -> Result<rayon::ThreadPool> {
    Ok(rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?)
}

fn min_median(times: &mut [f64]) -> (f64, f64) {
    times.sort_by(f64::total_cmp);
    (
        times.first().copied().unwrap_or(f64::NAN),
        times.get(times.len() / 2).copied().unwrap_or(f64::NAN),
    )
}
