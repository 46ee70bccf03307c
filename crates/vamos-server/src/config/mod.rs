//! Settings: defaults, then an optional TOML file, then `VAMOS_*` environment variables,
//! then a few CLI flags (applied by `main.rs`).
//!
//! Environment variables name a key path with `__` between levels, e.g.
//! `VAMOS_LOG__FORMAT=json` or `VAMOS_VISION__FLOW__WARPS=3`. `VAMOS_CONFIG` names the
//! file; it and the few other variables of [`is_reserved_env`] are not keys.
//! Unknown keys, in the file or the environment, are errors: a
//! typo must not silently fall back to a default.

use vamos_core::episode::EpisodeConfig;
use vamos_core::pipeline::PipelineConfig;
use vamos_model::ModelConfig;
use vamos_robot::RobotConfig;
use vamos_robot::render::RenderConfig;
pub mod service;

use crate::telemetry::LogConfig;
use figment::Figment;
use figment::providers::{Format, Serialized, Toml};
use serde::{Deserialize, Serialize};
pub use service::{FleetRole, QueuePolicy, ServiceConfig, SharedStoreConfig, TlsConfig};
use std::path::Path;
pub use vamos_vision::VisionConfig;

/// The environment variable that names the settings file.
pub const CONFIG_ENV: &str = "VAMOS_CONFIG";

/// `VAMOS_*` variables that are not settings keys: the settings file, the cache folder and
/// Python interpreter of the ONNX Runtime look-up (`model::runtime`), test and bench knobs
/// (`VAMOS_SKIP_*`, `VAMOS_BENCH_*`, `VAMOS_BIN`: the binary the Python tests run,
/// `VAMOS_REQUIRE_*`: a test that needs something fails instead of skipping without it, e.g.
/// `VAMOS_REQUIRE_GPU_TESTS` (a wgpu adapter) and `VAMOS_REQUIRE_BROWSER_TESTS` (chromium)),
/// and the service's plain tokens (`VAMOS_ADMIN_TOKEN`, `VAMOS_ROBOT_TOKEN`,
/// `VAMOS_VIEWER_TOKEN`).
pub fn is_reserved_env(name: &str) -> bool {
    matches!(
        name,
        CONFIG_ENV
            | "VAMOS_CACHE_DIR"
            | "VAMOS_PYTHON"
            | "VAMOS_BIN"
            | "VAMOS_ADMIN_TOKEN"
            | "VAMOS_ROBOT_TOKEN"
            | "VAMOS_VIEWER_TOKEN"
            | "VAMOS_LOADGEN_TOKEN"
    ) || name.starts_with("VAMOS_SKIP_")
        || name.starts_with("VAMOS_REQUIRE_")
        || name.starts_with("VAMOS_BENCH_")
}

/// Errors of loading settings.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    /// The named settings file does not exist.
    #[error("settings file {path} does not exist")]
    MissingFile {
        /// The path.
        path: String,
    },
    /// A value is malformed or a key unknown.
    #[error("invalid settings: {0}")]
    Invalid(String),
}

/// All settings of the `vamos` binary.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct Settings {
    /// Logging.
    pub log: LogConfig,
    /// Vision kernels.
    pub vision: VisionConfig,
    /// The detection pipeline.
    pub pipeline: PipelineConfig,
    /// Robot descriptions: mesh and archive caps, tessellation.
    pub robot: RobotConfig,
    /// Rendering of the robot body (mask, depth, expected body flow).
    pub render: RenderConfig,
    /// The flow predictor (ONNX Runtime).
    pub model: ModelConfig,
    /// Recorded episodes (ROS 2 bags in MCAP): topics, joint-gap warning, size caps.
    pub episode: EpisodeConfig,
    /// The server (`vamos serve`).
    pub service: ServiceConfig,
}

impl From<&Settings> for vamos_core::setup::CoreSettings {
    fn from(s: &Settings) -> Self {
        Self {
            vision: s.vision.clone(),
            pipeline: s.pipeline.clone(),
            robot: s.robot.clone(),
            render: s.render.clone(),
            model: s.model.clone(),
            episode: s.episode.clone(),
        }
    }
}

impl Settings {
    /// Loads defaults, then `file` (if given), then `VAMOS_*` variables from the process
    /// environment.
    pub fn load(file: Option<&Path>) -> Result<Self, ConfigError> {
        Self::load_with_env(file, std::env::vars())
    }

    /// As [`Settings::load`] with an explicit environment (for tests).
    pub fn load_with_env(
        file: Option<&Path>,
        env: impl IntoIterator<Item = (String, String)>,
    ) -> Result<Self, ConfigError> {
        let mut fig = Figment::from(Serialized::defaults(Settings::default()));
        if let Some(path) = file {
            if !path.is_file() {
                return Err(ConfigError::MissingFile {
                    path: path.display().to_string(),
                });
            }
            fig = fig.merge(Toml::file_exact(path));
        }
        // Parse the given variables with figment's own value syntax (numbers, bools,
        // strings), keys lower-cased, `__` as the level separator.
        let mut dict = figment::value::Dict::new();
        for (key, value) in env {
            let Some(rest) = key.strip_prefix("VAMOS_") else {
                continue;
            };
            // Only `VAMOS_SECTION__KEY` names are settings: `VAMOS_SIM`, `VAMOS_TRAIN` and
            // the like belong to scripts and tools.
            if is_reserved_env(&key) || !rest.contains("__") {
                continue;
            }
            let path: Vec<String> = rest.split("__").map(|s| s.to_ascii_lowercase()).collect();
            // Checked alone, so a wrong one is named.
            let mut one = figment::value::Dict::new();
            insert_path(&mut one, &path, parse_env_value(&value));
            Figment::from(Serialized::defaults(Settings::default()))
                .merge(Serialized::defaults(one))
                .extract::<Settings>()
                .map_err(|e| ConfigError::Invalid(format!("environment variable {key}: {e}")))?;
            insert_path(&mut dict, &path, parse_env_value(&value));
        }
        fig = fig.merge(Serialized::defaults(dict));
        fig.extract()
            .map_err(|e| ConfigError::Invalid(e.to_string()))
    }
}

fn parse_env_value(raw: &str) -> figment::value::Value {
    // Env::parse-like: try TOML scalar syntax, fall back to a plain string.
    raw.parse::<figment::value::Value>()
        .unwrap_or_else(|_| figment::value::Value::from(raw.to_string()))
}

fn insert_path(dict: &mut figment::value::Dict, path: &[String], value: figment::value::Value) {
    use figment::value::{Dict, Value};
    match path {
        [] => {}
        [last] => {
            dict.insert(last.clone(), value);
        }
        [first, rest @ ..] => {
            let entry = dict
                .entry(first.clone())
                .or_insert_with(|| Value::from(Dict::new()));
            if let Value::Dict(_, inner) = entry {
                insert_path(inner, rest, value);
            } else {
                let mut inner = Dict::new();
                insert_path(&mut inner, rest, value);
                *entry = Value::from(inner);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn env(pairs: &[(&str, &str)]) -> Vec<(String, String)> {
        pairs
            .iter()
            .map(|(a, b)| (a.to_string(), b.to_string()))
            .collect()
    }

    #[test]
    fn defaults_are_the_recommended_values() {
        let s = Settings::load_with_env(None, env(&[])).unwrap();
        assert_eq!(s, Settings::default());
        assert_eq!(s.vision.flow, vamos_vision::flow::FlowParams::realtime());
    }

    #[test]
    fn file_then_environment_override() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("vamos.toml");
        let mut f = std::fs::File::create(&path).unwrap();
        writeln!(
            f,
            "[log]\nformat = \"json\"\n[vision]\nthreads = 3\n[vision.flow]\nwarps = 2"
        )
        .unwrap();
        let s = Settings::load_with_env(
            Some(&path),
            env(&[
                ("VAMOS_VISION__THREADS", "1"),
                ("VAMOS_CONFIG", "ignored"),
                ("VAMOS_CACHE_DIR", "/tmp/ignored"),
                ("VAMOS_BENCH_MODEL", "ignored"),
                ("VAMOS_REQUIRE_GPU_TESTS", "1"),
                ("VAMOS_REQUIRE_BROWSER_TESTS", "1"),
                ("VAMOS_VIEWER_TOKEN", "v"),
                ("OTHER", "x"),
            ]),
        )
        .unwrap();
        assert_eq!(s.log.format, crate::telemetry::LogFormat::Json);
        assert_eq!(s.vision.threads, 1, "environment beats the file");
        assert_eq!(s.vision.flow.warps, 2);
        // The keys the file leaves out keep the realtime preset's values.
        let realtime = vamos_vision::flow::FlowParams::realtime();
        assert_eq!(s.vision.flow.scale_step, realtime.scale_step);
        assert_eq!(s.vision.flow.finest_scale, realtime.finest_scale);
    }

    #[test]
    fn only_section_key_variables_are_settings_and_a_wrong_one_is_named() {
        let s = Settings::load_with_env(
            None,
            env(&[
                ("VAMOS_SIM", "vamos-sim"),
                ("VAMOS_TRAIN", "x"),
                ("VAMOS_X", "1"),
            ]),
        )
        .unwrap();
        assert_eq!(s, Settings::default());
        for (var, value) in [
            ("VAMOS_SERVCE__WORKERS", "2"),
            ("VAMOS_SERVICE__WORKRS", "2"),
            ("VAMOS_SERVICE__WORKERS", "many"),
        ] {
            let err = Settings::load_with_env(None, env(&[(var, value)])).unwrap_err();
            assert!(err.to_string().contains(var), "{var}: {err}");
        }
    }

    #[test]
    fn the_shipped_example_lists_every_default() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../deploy/vamos.example.toml");
        let s = Settings::load_with_env(Some(&path), env(&[])).unwrap();
        assert_eq!(s, Settings::default());
        // Every key of the defaults appears in the example (so it documents them all).
        let text = std::fs::read_to_string(&path).unwrap();
        let defaults = toml::to_string(&Settings::default()).unwrap();
        for line in defaults.lines().filter(|l| l.contains(" = ")) {
            let key = line.split(" = ").next().unwrap();
            assert!(text.contains(&format!("{key} = ")), "example lacks {key}");
        }
    }

    #[test]
    fn render_section_is_read_from_the_environment() {
        let s = Settings::load_with_env(
            None,
            env(&[
                ("VAMOS_RENDER__MASK_MARGIN_PX", "3"),
                ("VAMOS_RENDER__BACKEND", "cpu"),
                ("VAMOS_RENDER__FLOW_GRID", "source"),
            ]),
        )
        .unwrap();
        assert_eq!(s.render.mask_margin_px, 3);
        assert_eq!(s.render.backend, vamos_robot::render::RenderBackend::Cpu);
        assert_eq!(s.render.flow_grid, vamos_robot::render::FlowGrid::Source);
        assert_eq!(s.render.near_m, 0.05);
    }

    #[test]
    fn unknown_keys_and_bad_values_are_errors() {
        let e = Settings::load_with_env(None, env(&[("VAMOS_VISION__THREDS", "1")])).unwrap_err();
        assert!(e.to_string().contains("threds"), "{e}");
        let e =
            Settings::load_with_env(None, env(&[("VAMOS_VISION__THREADS", "many")])).unwrap_err();
        assert!(matches!(e, ConfigError::Invalid(_)));
        let e =
            Settings::load_with_env(Some(Path::new("/nonexistent.toml")), env(&[])).unwrap_err();
        assert!(matches!(e, ConfigError::MissingFile { .. }));
    }
}
