//! The `vamos` binary: the composition root. It parses the command line, loads the
//! settings (defaults, file, environment, then the global flags), sets up logging and
//! hands over to the command's `run` in `cli/<command>.rs`. The only place that uses
//! `anyhow` outside the commands, and the only one that ends the process.

mod cli;

use anyhow::Result;
use clap::{CommandFactory, Parser, Subcommand};
use std::path::PathBuf;
use vamos::config::Settings;
use vamos::telemetry::{self, LogFormat};

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
    Demo(cli::demo::Args),
    /// TV-L1 optical flow from image A to image B (forward flow, pixels).
    Flow(cli::flow::Args),
    /// Fourier-Mellin registration of A onto B; prints one JSON object.
    Register(cli::register::Args),
    /// Run the service: gRPC streaming sessions, REST administration, /metrics. Stops
    /// gracefully on SIGTERM or Ctrl-C.
    Serve(cli::serve::Args),
    /// Ask a running server's gRPC health service (grpc.health.v1) whether it serves;
    /// prints one JSON object, exits 0 when SERVING and 1 otherwise (container and
    /// service-manager health checks).
    Health(cli::health::Args),
    /// Stream a recorded episode (MCAP) to a running server as a live robot and print
    /// every answer as a JSON line (scores and session events); a summary goes to stderr.
    Stream(cli::stream::Args),
    /// Join a ROS 2 graph (no ROS installation needed) as a node that streams a robot's
    /// camera and joint states to a running server and publishes stamped scores, alarm
    /// events, anomaly maps (when asked for) and diagnostics; stops on SIGTERM or Ctrl-C
    /// after the last scores.
    Bridge(Box<cli::bridge::Args>),
    /// Replay episodes as N robots streaming to a running server; prints the achieved
    /// rate, score latency percentiles, drops and the server's CPU and memory (JSON).
    Loadgen(cli::loadgen::Args),
    /// Score recorded episodes (ROS 2 bags in MCAP) with a profile: one JSON summary line
    /// per episode; with --out the per-frame scores (JSON lines) and, with --mcap, a bag of
    /// the images plus score topics for Foxglove or `ros2 bag play`.
    Score(cli::score::Args),
    /// Write a Foxglove layout for a profile's scored bags (`vamos score --mcap`): the
    /// bag's camera, the anomaly map, the fused score and one plot per detector the
    /// profile runs.
    Layout(cli::layout::Args),
    /// Calibrate a profile's thresholds on nominal episodes: e_c and e_b maxima (the
    /// paper) and a split-conformal threshold on the fused score from held-out episodes.
    Calibrate(cli::calibrate::Args),
    /// Evaluate a profile on labelled episodes: frame-level AUC-ROC and AUC-PR (pooled),
    /// per anomaly type, episode false-alarm rate and detection delay at the alarm
    /// threshold; prints the report as JSON.
    Eval(cli::eval::Args),
    /// Print the effective settings (defaults + file + environment) as TOML.
    Config,
    /// Write the flow predictor's training data (64x64 network inputs of every processed
    /// frame) from nominal episodes: one .npy per episode plus manifest.json.
    ExportDataset(cli::export::Args),
    /// Draw the robot as its camera sees it (mask | depth | expected body flow, side by
    /// side) and print a JSON summary: the first check of a robot set-up.
    Render(cli::render::Args),
    /// Robot descriptions (URDF + meshes).
    Robot {
        #[command(subcommand)]
        command: cli::robot::Command,
    },
    /// Recorded episodes (ROS 2 bags in MCAP).
    Episode {
        #[command(subcommand)]
        command: cli::episode::Command,
    },
    /// Profiles: `init` writes a starting profile for a new robot from one recorded bag.
    Profile {
        #[command(subcommand)]
        command: cli::profile::Command,
    },
    /// Flow-predictor model bundles and the ONNX Runtime library.
    Model {
        #[command(subcommand)]
        command: cli::model::Command,
    },
    /// Print a shell completion script (bash, zsh, fish, elvish, powershell).
    Completions(cli::shell::CompletionsArgs),
    /// Print the man page (roff), or write one page per command into a folder.
    Man(cli::shell::ManArgs),
    /// Print the JSON Schema of the settings file, a profile file or camera.json (for
    /// editors: validation and completion).
    Schema(cli::schema::SchemaArgs),
    /// Print the REST API's OpenAPI 3.0 document (what `GET /openapi.json` serves), to
    /// generate a client without a running server.
    Openapi,
}

fn main() -> std::process::ExitCode {
    let cli = Cli::parse();
    if matches!(cli.command, Command::Serve(_)) {
        // SAFETY: no thread has been started yet (the async runtime comes later).
        unsafe { vamos::api::auth::take_env_tokens() };
    }
    match run(cli) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        // Already reported on stdout.
        Err(e) if e.is::<cli::Failed>() => std::process::ExitCode::FAILURE,
        Err(e) => {
            // Once: through the log when it is set up (it writes to stderr), else plainly.
            let text = cli::error_text(&e);
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

fn run(cli: Cli) -> Result<()> {
    // Made from the clap definition alone: no settings, no logging.
    match &cli.command {
        Command::Completions(args) => {
            cli::shell::completions(Cli::command(), args, &mut std::io::stdout());
            return Ok(());
        }
        Command::Man(args) => {
            for path in cli::shell::man(Cli::command(), args, &mut std::io::stdout())? {
                println!("{}", path.display());
            }
            return Ok(());
        }
        Command::Openapi => {
            println!("{}", vamos::api::rest::openapi::document_json());
            return Ok(());
        }
        Command::Schema(args) => return cli::schema::run(args),
        _ => {}
    }
    let mut settings = Settings::load(cli.config.as_deref())?;
    if let Some(level) = cli.log_level {
        settings.log.level = level;
    } else if matches!(cli.command, Command::Demo(_))
        && std::env::var_os("VAMOS_LOG__LEVEL").is_none()
        && cli.config.is_none()
    {
        // The demo's terminal is for its progress table: the in-process server's
        // informational logs would bury it (--log-level info brings them back).
        settings.log.level = "warn".into();
    }
    if matches!(cli.command, Command::Bridge(_)) {
        // RustDDS logs every discovery step at info, and ros2-client warns that
        // ROS_DISTRO is unset, which is normal without a ROS installation: the bridge's own
        // logs stay at the level asked for, theirs from warn and error up (RUST_LOG
        // replaces all of this).
        settings.log.level = cli::bridge::quieter_dds(&settings.log.level);
    }
    if let Some(format) = cli.log_format {
        settings.log.format = format;
    }
    // Kept to the end of the command: dropping it flushes the OTLP export, if any.
    let _telemetry = telemetry::init(&settings.log)?;
    tracing::debug!(settings = ?settings, "effective settings");
    match cli.command {
        Command::Demo(args) => cli::demo::run(&settings, args),
        Command::Flow(args) => cli::flow::run(&settings, args),
        Command::Register(args) => cli::register::run(&settings, args),
        Command::Serve(args) => cli::serve::run(settings, args),
        Command::Health(args) => cli::health::run(args),
        Command::Stream(args) => cli::stream::run(&settings, args),
        Command::Bridge(args) => cli::bridge::run(*args),
        Command::Loadgen(args) => cli::loadgen::run(args),
        Command::Score(args) => cli::score::run(&settings, args),
        Command::Layout(args) => cli::layout::run(&settings, args),
        Command::Calibrate(args) => cli::calibrate::run(&settings, args),
        Command::Eval(args) => cli::eval::run(&settings, args),
        Command::Config => cli::config::run(&settings),
        Command::ExportDataset(args) => cli::export::run(&settings, args),
        Command::Render(args) => cli::render::run(&settings, args),
        Command::Robot { command } => cli::robot::run(&settings, command),
        Command::Episode { command } => cli::episode::run(&settings, command),
        Command::Profile { command } => cli::profile::run(&settings, command),
        Command::Model { command } => cli::model::run(&settings, command),
        Command::Completions(_) | Command::Man(_) | Command::Openapi | Command::Schema(_) => Ok(()),
    }
}
