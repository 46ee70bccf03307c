//! Logging set-up: `tracing` with human-readable or JSON lines on stderr, and the spans
//! exported over OTLP/HTTP when built with the `otlp` cargo feature and
//! [`LogConfig::otlp_endpoint`] is set (off by default).
//!
//! The filter comes from `RUST_LOG` when set, else from [`LogConfig::level`]; it applies
//! to the log lines and to the exported spans alike. Stdout is left to commands that print
//! results (JSON objects), so logs never mix with them.
//!
//! vamos is a workspace of crates, so its events carry the targets `vamos_vision`,
//! `vamos_core::pipeline`, `vamos_server::session`, ... A filter written for the one
//! `vamos` crate of earlier versions still works: [`workspace_directives`] turns `vamos`
//! into every crate of the workspace and `vamos::session` into `vamos_server::session`.

use serde::{Deserialize, Serialize};
use tracing_subscriber::layer::SubscriberExt;
use tracing_subscriber::util::SubscriberInitExt;
use tracing_subscriber::{EnvFilter, Layer, Registry};

/// Log line format.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    Serialize,
    Deserialize,
    clap::ValueEnum,
    schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum LogFormat {
    /// Human-readable lines.
    #[default]
    Human,
    /// One JSON object per line (for log collectors).
    Json,
}

/// The `[log]` section of the settings.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct LogConfig {
    /// `tracing` filter directive, e.g. `info` or `vamos=debug,warn`.
    pub level: String,
    /// Line format.
    pub format: LogFormat,
    /// OTLP/HTTP traces URL (e.g. `http://collector:4318/v1/traces`) the spans are
    /// exported to; empty: no export. Needs a binary built with `--features otlp`.
    pub otlp_endpoint: String,
}

impl Default for LogConfig {
    fn default() -> Self {
        Self {
            level: "info".into(),
            format: LogFormat::Human,
            otlp_endpoint: String::new(),
        }
    }
}

/// Errors of the logging set-up.
#[derive(Debug, thiserror::Error)]
pub enum TelemetryError {
    /// The filter directive does not parse.
    #[error("invalid log level {level:?}: {reason}")]
    BadFilter {
        /// The directive.
        level: String,
        /// Why.
        reason: String,
    },
    /// A global subscriber was already installed.
    #[error("logging was already initialised")]
    AlreadyInitialised,
    /// `otlp_endpoint` is set but this binary has no OTLP export.
    #[error("[log] otlp_endpoint is set, but this vamos was built without the `otlp` feature")]
    OtlpNotBuilt,
    /// The OTLP exporter could not be made.
    #[error("OTLP export to {endpoint:?}: {reason}")]
    Otlp {
        /// The endpoint.
        endpoint: String,
        /// Why.
        reason: String,
    },
}

/// What the logging set-up keeps running: the OTLP span pipeline, flushed and shut down
/// when this is dropped (keep it until the command ends).
#[must_use = "dropping it ends the span export"]
pub struct Telemetry {
    #[cfg(feature = "otlp")]
    provider: Option<opentelemetry_sdk::trace::SdkTracerProvider>,
}

impl Drop for Telemetry {
    fn drop(&mut self) {
        #[cfg(feature = "otlp")]
        if let Some(p) = self.provider.take()
            && let Err(e) = p.shutdown()
        {
            eprintln!("OTLP export: spans not flushed at exit: {e}");
        }
    }
}

type BoxedLayer = Box<dyn Layer<Registry> + Send + Sync>;

/// The OTLP layer and its provider (batch export on its own thread, blocking HTTP client).
#[cfg(feature = "otlp")]
fn otlp_layer(
    endpoint: &str,
    filter: EnvFilter,
) -> Result<(BoxedLayer, opentelemetry_sdk::trace::SdkTracerProvider), TelemetryError> {
    use opentelemetry::trace::TracerProvider as _;
    use opentelemetry_otlp::WithExportConfig;
    let exporter = opentelemetry_otlp::SpanExporter::builder()
        .with_http()
        .with_endpoint(endpoint)
        .build()
        .map_err(|e| TelemetryError::Otlp {
            endpoint: endpoint.to_string(),
            reason: e.to_string(),
        })?;
    let resource = opentelemetry_sdk::Resource::builder()
        .with_service_name("vamos")
        .build();
    let provider = opentelemetry_sdk::trace::SdkTracerProvider::builder()
        .with_batch_exporter(exporter)
        .with_resource(resource)
        .build();
    let layer = tracing_opentelemetry::layer()
        .with_tracer(provider.tracer("vamos"))
        .with_filter(filter)
        .boxed();
    Ok((layer, provider))
}

/// The crates of the workspace, whose events a directive for `vamos` covers.
const WORKSPACE_CRATES: &[&str] = &[
    "vamos",
    "vamos_vision",
    "vamos_robot",
    "vamos_model",
    "vamos_core",
    "vamos_proto",
    "vamos_server",
    "vamos_client",
    "vamos_ros2",
];

/// Where a top-level module of the `vamos` library lives (its re-exports), as a target.
fn module_target(module: &str) -> Option<String> {
    let krate = match module {
        "vision" | "robot" | "model" | "proto" | "client" | "ros2" => {
            return Some(format!("vamos_{module}"));
        }
        "episode" | "eval" | "pipeline" | "setup" => "vamos_core",
        "api" | "config" | "service" | "session" | "store" | "telemetry" => "vamos_server",
        _ => return None,
    };
    Some(format!("{krate}::{module}"))
}

/// A filter with its `vamos` targets spelled for the workspace: `vamos=debug` also names
/// every `vamos_*` crate; `vamos::MODULE...` names the crate that holds MODULE (e.g.
/// `vamos::session::hub=trace` -> `vamos_server::session::hub=trace`); other directives
/// are kept as they are.
pub fn workspace_directives(filter: &str) -> String {
    let mut out: Vec<String> = Vec::new();
    for directive in filter.split(',') {
        let end = directive.find(['[', '=']).unwrap_or(directive.len());
        let (target, rest) = directive.split_at(end);
        let target = target.trim();
        if target == "vamos" {
            out.extend(WORKSPACE_CRATES.iter().map(|c| format!("{c}{rest}")));
        } else if let Some(path) = target.strip_prefix("vamos::") {
            let (module, tail) = path.split_once("::").map_or((path, ""), |(m, t)| (m, t));
            match module_target(module) {
                Some(t) if tail.is_empty() => out.push(format!("{t}{rest}")),
                Some(t) => out.push(format!("{t}::{tail}{rest}")),
                None => out.push(directive.to_string()),
            }
        } else {
            out.push(directive.to_string());
        }
    }
    out.join(",")
}

/// Installs the global subscriber. Call once, early in `main`, and keep the returned
/// [`Telemetry`] until the command ends.
pub fn init(config: &LogConfig) -> Result<Telemetry, TelemetryError> {
    let filter = || {
        match std::env::var("RUST_LOG") {
            Ok(directive) if !directive.is_empty() => {
                EnvFilter::try_new(workspace_directives(&directive))
            }
            _ => EnvFilter::try_new(workspace_directives(&config.level)),
        }
        .map_err(|e| TelemetryError::BadFilter {
            level: config.level.clone(),
            reason: e.to_string(),
        })
    };
    // Colours only for a terminal: a file or a pipe (a service manager's journal, a
    // redirect) gets plain text. `NO_COLOR` (no-color.org) turns them off everywhere.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr())
        && std::env::var_os("NO_COLOR").is_none_or(|v| v.is_empty());
    let lines = tracing_subscriber::fmt::layer()
        .with_ansi(ansi)
        .with_writer(std::io::stderr);
    let lines: BoxedLayer = match config.format {
        LogFormat::Human => lines.with_filter(filter()?).boxed(),
        LogFormat::Json => lines
            .json()
            .flatten_event(true)
            .with_filter(filter()?)
            .boxed(),
    };
    // Pushed to only with the `otlp` feature.
    #[allow(unused_mut)]
    let mut layers = vec![lines];
    #[cfg(feature = "otlp")]
    let mut provider = None;
    if !config.otlp_endpoint.is_empty() {
        #[cfg(feature = "otlp")]
        {
            let (layer, p) = otlp_layer(&config.otlp_endpoint, filter()?)?;
            layers.push(layer);
            provider = Some(p);
        }
        #[cfg(not(feature = "otlp"))]
        return Err(TelemetryError::OtlpNotBuilt);
    }
    tracing_subscriber::registry()
        .with(layers)
        .try_init()
        .map_err(|_| TelemetryError::AlreadyInitialised)?;
    Ok(Telemetry {
        #[cfg(feature = "otlp")]
        provider,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn filters_for_the_vamos_crate_cover_the_workspace() {
        assert_eq!(workspace_directives("info"), "info");
        assert_eq!(workspace_directives("warn,hyper=info"), "warn,hyper=info");
        let all = workspace_directives("vamos=debug,warn");
        assert!(all.ends_with(",warn"), "{all}");
        for c in WORKSPACE_CRATES {
            assert!(all.contains(&format!("{c}=debug")), "{all} lacks {c}");
        }
        assert_eq!(
            workspace_directives("vamos::session::hub=trace,vamos::vision=debug"),
            "vamos_server::session::hub=trace,vamos_vision=debug"
        );
        assert_eq!(
            workspace_directives("vamos::pipeline[frame]=debug"),
            "vamos_core::pipeline[frame]=debug"
        );
        assert_eq!(workspace_directives("vamos::cli=info"), "vamos::cli=info");
        // Every rewritten filter is one EnvFilter accepts.
        for f in [
            "vamos=debug,warn",
            "vamos::session::hub=trace",
            "vamos::pipeline[frame]=debug",
        ] {
            EnvFilter::try_new(workspace_directives(f)).unwrap();
        }
    }
}
