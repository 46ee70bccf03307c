//! The flow predictor: ONNX Runtime sessions for a trained model bundle and the per-session
//! prediction error `e_o` (REFERENCE.md section 3, docs/model-bundle.md).
//!
//! - [`runtime`]: finds (or provisions) the ONNX Runtime shared library and initialises
//!   `ort` once per process.
//! - [`bundle`]: reads a `.vamos` zip bundle (manifest, checksums, size caps).
//! - [`network`]: the loaded, validated encoder and head sessions ([`FlowModel`], shared
//!   by all robot sessions) and [`ModelSlot`], an atomically swappable holder.
//! - [`predictor`]: per-robot-session state ([`Predictor`]): the encoder cache over the
//!   last `A + B` frames, prior sampling and the minimum prediction error.
//! - [`rng`]: the documented random generator behind the prior samples.
//!
//! This module is synchronous and imports only `vision`-level types and plain crates
//! (never tokio, tonic, prost, axum or http).

pub mod bundle;
pub mod head;
pub mod network;
#[doc(hidden)]
pub mod onnx_proto;
pub mod predictor;
pub mod rng;
pub mod runtime;

pub use bundle::{Bundle, FlowVariant, Manifest, UnknownFlowVariant};
pub use network::{EncoderOutput, FlowModel, LoadOptions, ModelDims, ModelSlot};
pub use predictor::{BatchItem, FlowScore, Prediction, Predictor, PredictorParams, push_batch};
pub use runtime::RuntimeError;

use serde::{Deserialize, Serialize};

/// Errors of loading a model bundle or running the flow predictor.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// The ONNX Runtime library could not be found, provisioned or loaded.
    #[error(transparent)]
    Runtime(#[from] RuntimeError),
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The bundle is not a readable zip archive.
    #[error("{path} is not a valid model bundle (zip): {reason}")]
    NotAZip {
        /// The bundle file (or `<memory>`).
        path: String,
        /// What the zip reader said.
        reason: String,
    },
    /// A required member is missing from the bundle.
    #[error("the model bundle has no member {member}")]
    MissingMember {
        /// The member name.
        member: String,
    },
    /// The bundle holds a member the contract does not know.
    #[error(
        "the model bundle has an unexpected member {member} (allowed: manifest.json, encoder.onnx, head.onnx)"
    )]
    UnexpectedMember {
        /// The member name.
        member: String,
    },
    /// A member is larger than the limit (checked before reading it).
    #[error("bundle member {member} is {size_bytes} bytes, more than the limit of {limit_bytes}")]
    MemberTooLarge {
        /// The member name.
        member: String,
        /// Its (declared or actual) uncompressed size.
        size_bytes: u64,
        /// The limit.
        limit_bytes: u64,
    },
    /// `manifest.json` is malformed or inconsistent.
    #[error("invalid manifest.json: {reason}")]
    Manifest {
        /// What is wrong.
        reason: String,
    },
    /// The manifest's `format_version` is newer than this server understands.
    #[error(
        "model bundle format_version {found} is newer than this vamos supports ({supported}); upgrade vamos"
    )]
    FutureFormatVersion {
        /// The bundle's version.
        found: u64,
        /// The newest version known here.
        supported: u64,
    },
    /// A member's SHA-256 differs from the manifest's.
    #[error("checksum mismatch for {member}: manifest says {expected}, content is {actual}")]
    ChecksumMismatch {
        /// The member name.
        member: String,
        /// The manifest's hex digest.
        expected: String,
        /// The content's hex digest.
        actual: String,
    },
    /// A member is not a loadable ONNX model.
    #[error("{member} is not a valid ONNX model: {reason}")]
    InvalidOnnx {
        /// The member name.
        member: String,
        /// What is wrong.
        reason: String,
    },
    /// A graph's ONNX opset differs from the manifest's or is unsupported.
    #[error("{member} uses ONNX opset {found}; {reason}")]
    Opset {
        /// The member name.
        member: String,
        /// The graph's default-domain opset.
        found: u64,
        /// Why it is refused.
        reason: String,
    },
    /// A graph's inputs or outputs differ from the contract (docs/model-bundle.md).
    #[error("{member}: {reason}")]
    Signature {
        /// The member name.
        member: String,
        /// What differs.
        reason: String,
    },
    /// Encoder, head and manifest disagree on a dimension.
    #[error("{what} mismatch: encoder {encoder}, head {head}, manifest {manifest}")]
    DimensionMismatch {
        /// Which dimension (`feature_channels`, `latent_dim`, `input size`).
        what: &'static str,
        /// The encoder's value.
        encoder: i64,
        /// The head's value.
        head: i64,
        /// The manifest's value.
        manifest: i64,
    },
    /// The smoke inference at load time failed or gave non-finite / wrongly shaped output.
    #[error("smoke inference failed: {reason}")]
    SmokeTest {
        /// What went wrong.
        reason: String,
    },
    /// ONNX Runtime reported an error.
    #[error("onnxruntime: {context}: {reason}")]
    Ort {
        /// What was being done.
        context: &'static str,
        /// ONNX Runtime's message.
        reason: String,
    },
    /// An input buffer has the wrong number of elements.
    #[error("{what} has {actual} values, expected {expected}")]
    InputShape {
        /// Which input.
        what: &'static str,
        /// The expected number of values.
        expected: usize,
        /// The given number of values.
        actual: usize,
    },
    /// An input holds NaN or an infinity.
    #[error("{what} holds a non-finite value at index {index}")]
    NonFiniteInput {
        /// Which input.
        what: &'static str,
        /// The first offending index.
        index: usize,
    },
    /// A parameter is out of range.
    #[error("invalid parameter {field}: {reason}")]
    InvalidParams {
        /// The parameter.
        field: &'static str,
        /// Why.
        reason: String,
    },
}

/// Which implementation runs the model's head (fcomb).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum HeadBackend {
    /// Native code (`model::head`) when `head.onnx` is a recognised fcomb that agrees
    /// with ONNX Runtime on random inputs at load time; ONNX Runtime otherwise.
    #[default]
    Auto,
    /// Always ONNX Runtime.
    Onnx,
}

/// How each predictor's random generator is seeded.
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum SeedPolicy {
    /// Every predictor starts from `seed`: replaying an episode gives the same scores.
    Fixed,
    /// `seed` mixed with a hash of the session key: different robots draw different
    /// samples, and each is still reproducible.
    #[default]
    PerSession,
}

/// The `[model]` settings section.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct ModelConfig {
    /// Intra-op threads of each ONNX Runtime session (encoder and head). 1 keeps the
    /// cores for concurrent robot sessions and the vision kernels; 0 = ONNX Runtime's
    /// default (one per core).
    pub threads: usize,
    /// ONNX Runtime sessions per graph, so that robot sessions run inference in parallel
    /// (0 = one per core, at most 8; each holds a copy of the weights).
    pub replicas: usize,
    /// Prior samples M per past offset n; 0 = the bundle's `temporal.m`.
    pub samples: usize,
    /// Base seed of the prior-sample generator.
    pub seed: u64,
    /// How each robot session's generator is seeded from `seed`.
    pub seed_policy: SeedPolicy,
    /// Download the ONNX Runtime library from PyPI (`pip download onnxruntime`) into the
    /// cache when no other copy is found.
    pub ort_provision: bool,
    /// Look for the library in the Python `onnxruntime` package (`python3`'s site-packages).
    pub ort_use_python_package: bool,
    /// Which implementation runs the head: `auto` (native fcomb when recognised and
    /// checked against ONNX Runtime at load) or `onnx`.
    pub head: HeadBackend,
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            threads: 1,
            replicas: 0,
            samples: 0,
            seed: 0,
            seed_policy: SeedPolicy::PerSession,
            ort_provision: true,
            ort_use_python_package: true,
            head: HeadBackend::Auto,
        }
    }
}

impl ModelConfig {
    /// The seed of the predictor of the session named `session_key`.
    pub fn session_seed(&self, session_key: &str) -> u64 {
        match self.seed_policy {
            SeedPolicy::Fixed => self.seed,
            SeedPolicy::PerSession => {
                // FNV-1a of the key, then one SplitMix64 step to spread it.
                let mut h: u64 = 0xcbf2_9ce4_8422_2325;
                for b in session_key.as_bytes() {
                    h ^= u64::from(*b);
                    h = h.wrapping_mul(0x0100_0000_01b3);
                }
                rng::splitmix64(&mut (self.seed ^ h))
            }
        }
    }

    /// The runtime look-up options these settings select.
    pub fn runtime_options(&self) -> runtime::RuntimeOptions {
        runtime::RuntimeOptions {
            provision: self.ort_provision,
            use_python_package: self.ort_use_python_package,
        }
    }

    /// The session options these settings select.
    pub fn load_options(&self) -> LoadOptions {
        LoadOptions {
            intra_threads: self.threads,
            replicas: self.replicas,
            runtime: self.runtime_options(),
            head: self.head,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn seeds_follow_the_policy() {
        let mut c = ModelConfig {
            seed: 5,
            seed_policy: SeedPolicy::Fixed,
            ..ModelConfig::default()
        };
        assert_eq!(c.session_seed("a"), 5);
        assert_eq!(c.session_seed("b"), 5);
        c.seed_policy = SeedPolicy::PerSession;
        let (a, b) = (c.session_seed("a"), c.session_seed("b"));
        assert_ne!(a, b);
        assert_eq!(a, c.session_seed("a"), "deterministic");
        c.seed = 6;
        assert_ne!(a, c.session_seed("a"), "the base seed matters");
    }
}
