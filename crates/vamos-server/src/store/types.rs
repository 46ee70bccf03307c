//! The store's public data types (also the service's REST bodies) and its on-disk records.

use super::RobotFormat;
use serde::{Deserialize, Deserializer, Serialize};
use std::path::PathBuf;
use vamos_core::episode::EpisodeTopics;
use vamos_core::eval::Thresholds;
use vamos_core::pipeline::{AlarmRule, Calibration, PipelineConfig, Profile, ThresholdOverrides};
use vamos_robot::CameraSpec;

/// Upload size limits.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StoreLimits {
    /// Largest model bundle, bytes.
    pub max_model_bytes: u64,
    /// Largest robot package (URDF file or archive), bytes.
    pub max_robot_bytes: u64,
}

impl Default for StoreLimits {
    /// 1 GiB per model (a bundle holds two ONNX graphs of at most 512 MiB each), 512 MiB
    /// per robot (the default `[robot] max_archive_bytes`).
    fn default() -> Self {
        Self {
            max_model_bytes: 1 << 30,
            max_robot_bytes: 512 << 20,
        }
    }
}

/// One stored version of a model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ModelVersionInfo {
    /// Version number: 1 for a name's first upload, then one more than the largest ever
    /// given under that name (never reused while the model exists).
    pub version: u32,
    /// sha256 (hex) of the bundle file: the model's identity.
    pub sha256: String,
    /// Size of the bundle file, bytes.
    pub size_bytes: u64,
    /// When it was uploaded, seconds since the Unix epoch.
    pub created_unix_s: u64,
    /// What the validator reported about it (e.g. manifest facts).
    pub summary: serde_json::Value,
    /// Why it is not served (checksum failure, missing file), if so.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub problem: Option<String>,
}

/// A model: its versions and which one is active.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ModelInfo {
    /// Name.
    pub name: String,
    /// The version profiles without a pinned version use (`null`: no version left).
    pub active: Option<u32>,
    /// Versions, oldest first.
    pub versions: Vec<ModelVersionInfo>,
}

/// A stored robot package.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct RobotInfo {
    /// Name.
    pub name: String,
    /// How many times it was uploaded under this name (each upload replaces the last).
    pub revision: u32,
    /// How the package is packed.
    pub format: RobotFormat,
    /// sha256 (hex) of the stored file.
    pub sha256: String,
    /// Size of the stored file, bytes.
    pub size_bytes: u64,
    /// First upload under this name, seconds since the Unix epoch.
    pub created_unix_s: u64,
    /// This revision's upload, seconds since the Unix epoch.
    pub updated_unix_s: u64,
    /// What the validator reported about it (e.g. links, joints, warnings).
    pub summary: serde_json::Value,
    /// Why it is not served, if so.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub problem: Option<String>,
}

/// A model a profile uses.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ModelRef {
    /// The model's name in the store.
    pub name: String,
    /// A pinned version; absent: the model's active version at the time of use.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub version: Option<u32>,
}

/// What a profile binds (the body of `PUT /v1/profiles/{name}`): a robot and camera,
/// pipeline parameters, a model and thresholds. Absent parts fall back as in a profile
/// file ([`vamos_core::pipeline::profile`]).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ProfileSpec {
    /// The robot's name in the store (needs `camera`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub robot: Option<String>,
    /// The camera: its URDF link and intrinsics.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera: Option<CameraSpec>,
    /// The flow-predictor model.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub model: Option<ModelRef>,
    /// TV-L1 preset name (absent: the settings' `[vision.flow]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub flow_preset: Option<String>,
    /// Which calibrated threshold on the fused score sets the anomaly flag.
    #[serde(default)]
    pub alarm: AlarmRule,
    /// Pipeline parameters (absent: the settings' `[pipeline]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub pipeline: Option<PipelineConfig>,
    /// Topic names of this robot's bags (absent: the settings' `[episode.topics]`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub topics: Option<EpisodeTopics>,
    /// Manual thresholds on top of the calibration (see [`Self::thresholds`] and
    /// [`super::Store::patch_thresholds`]).
    #[serde(default, skip_serializing_if = "ThresholdOverrides::is_empty")]
    pub thresholds: ThresholdOverrides,
    /// How per-frame flags become alarm events (absent: 3 of 5 frames).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alarm_events: Option<vamos_core::eval::alarm::Debounce>,
}

/// A stored profile.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
pub struct ProfileInfo {
    /// Name.
    pub name: String,
    /// What it binds.
    pub spec: ProfileSpec,
    /// Its calibration, if one was saved.
    pub calibration: Option<Calibration>,
    /// The `e_c`/`e_b` thresholds in force: calibrated, overrides on top.
    pub thresholds: Thresholds,
    /// The fused-score alarm threshold in force (`null`: no alarms, i.e. `+inf`).
    pub alarm_threshold: Option<f64>,
    /// First stored, seconds since the Unix epoch.
    pub created_unix_s: u64,
    /// Last change of the spec or its thresholds, seconds since the Unix epoch (the
    /// calibration has its own `created_unix_s`).
    pub updated_unix_s: u64,
    /// Why it cannot be used, if so (a corrupt calibration).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub problem: Option<String>,
}

/// A change of a profile's threshold overrides (`PATCH /v1/profiles/{name}/thresholds`):
/// for each of `e_c`, `e_b`, `alarm`, a number sets the override, `null` clears it (the
/// calibrated value is back in force) and an absent key leaves it as it is.
#[derive(Debug, Clone, Copy, PartialEq, Default, Deserialize, schemars::JsonSchema)]
#[serde(deny_unknown_fields)]
pub struct ThresholdsPatch {
    /// `e_c` override: a number sets it, `null` clears it, absent leaves it.
    #[serde(default, deserialize_with = "present")]
    pub e_c: Option<Option<f64>>,
    /// `e_b` override, as `e_c`.
    #[serde(default, deserialize_with = "present")]
    pub e_b: Option<Option<f64>>,
    /// Fused-score alarm threshold override, as `e_c`.
    #[serde(default, deserialize_with = "present")]
    pub alarm: Option<Option<f64>>,
}

/// A key that is present: `null` becomes `Some(None)`, a number `Some(Some(x))`.
fn present<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Option<f64>>, D::Error> {
    Option::<f64>::deserialize(d).map(Some)
}

impl ThresholdsPatch {
    /// `overrides` with this patch applied.
    pub fn apply(&self, mut overrides: ThresholdOverrides) -> ThresholdOverrides {
        for (slot, change) in [
            (&mut overrides.e_c, self.e_c),
            (&mut overrides.e_b, self.e_b),
            (&mut overrides.alarm, self.alarm),
        ] {
            if let Some(value) = change {
                *slot = value;
            }
        }
        overrides
    }
}

/// The model version a profile resolved to.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ResolvedModel {
    /// Model name.
    pub name: String,
    /// The version used.
    pub version: u32,
    /// Its sha256.
    pub sha256: String,
}

/// A profile made ready for [`vamos_core::setup::Setup::from_profile`]: its robot and model are
/// the stored files' paths, and `file.thresholds` holds the overrides, so
/// [`Profile::thresholds`] and [`Profile::alarm_threshold`] give the values in force.
#[derive(Debug, Clone)]
pub struct ResolvedProfile {
    /// The profile (its `path` is the stored `profile.json`; `file.camera` is `None`,
    /// the camera being already read into `camera`).
    pub profile: Profile,
    /// The model version resolved (a followed active version is fixed at call time).
    pub model: Option<ResolvedModel>,
    /// The robot's name in the store.
    pub robot: Option<String>,
    /// Things worth a log line (e.g. a calibration made with another model).
    pub warnings: Vec<String>,
}

/// Something wrong in the data directory, found when it was opened: such objects are not
/// served until replaced or deleted.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct StoreProblem {
    /// `model`, `model version`, `robot`, `profile`, `entry`.
    pub kind: &'static str,
    /// The object's name (`name@version` for a model version).
    pub name: String,
    /// The file or folder concerned.
    pub path: PathBuf,
    /// What is wrong.
    pub reason: String,
}

/// What [`super::Store::open`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize)]
pub struct OpenReport {
    /// Temporary files and folders of interrupted uploads and writes, removed.
    pub removed_temp_entries: usize,
    /// Data files no metadata refers to (a crash between storing a file and recording
    /// it), removed.
    pub removed_orphan_files: usize,
    /// Stored data and metadata files whose checksum was verified.
    pub verified_files: usize,
}

// On-disk records (bodies of the checksummed metadata files).

/// `models/<name>/index.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ModelIndex {
    pub(crate) name: String,
    pub(crate) active: Option<u32>,
    /// The version the next upload gets.
    pub(crate) next_version: u32,
    pub(crate) versions: Vec<StoredVersion>,
}

/// One version in a [`ModelIndex`]; the file is `models/<name>/<version>.vamos`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct StoredVersion {
    pub(crate) version: u32,
    pub(crate) sha256: String,
    pub(crate) size_bytes: u64,
    pub(crate) created_unix_s: u64,
    pub(crate) summary: serde_json::Value,
}

/// `robots/<name>/meta.json`; the file is `robots/<name>/<revision>.<ext>`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct RobotMeta {
    pub(crate) name: String,
    pub(crate) revision: u32,
    pub(crate) format: RobotFormat,
    pub(crate) sha256: String,
    pub(crate) size_bytes: u64,
    pub(crate) created_unix_s: u64,
    pub(crate) updated_unix_s: u64,
    pub(crate) summary: serde_json::Value,
}

impl RobotMeta {
    pub(crate) fn file_name(&self) -> String {
        format!("{}.{}", self.revision, self.format.extension())
    }
}

/// `profiles/<name>/profile.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct ProfileRecord {
    pub(crate) name: String,
    pub(crate) created_unix_s: u64,
    pub(crate) updated_unix_s: u64,
    pub(crate) spec: ProfileSpec,
}
