//! Reading a `.vamos` model bundle (docs/model-bundle.md): a zip archive holding exactly
//! `manifest.json`, `encoder.onnx` and `head.onnx`.
//!
//! Checks, before anything reaches ONNX Runtime: only the expected member names; each
//! member's declared size below a cap (so an absurd member is refused before it is read),
//! and the bytes read capped again (a lying header cannot inflate memory); the manifest's
//! `format` and `format_version` (newer -> [`ModelError::FutureFormatVersion`]); the
//! manifest's fields (unknown fields are errors, except inside `training`, which is
//! informational); each ONNX member's SHA-256 against the manifest.

use super::ModelError;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::BTreeMap;
use std::fmt;
use std::io::{Read, Seek};
use std::path::Path;
use std::str::FromStr;

/// The newest bundle `format_version` this code reads.
pub const FORMAT_VERSION: u64 = 1;
/// The value of the manifest's `format` field.
pub const FORMAT: &str = "vamos-model";
/// The manifest member.
pub const MANIFEST: &str = "manifest.json";
/// The encoder member (U-Net + prior net).
pub const ENCODER: &str = "encoder.onnx";
/// The head member (fcomb).
pub const HEAD: &str = "head.onnx";
/// Largest accepted `manifest.json`, bytes.
pub const MAX_MANIFEST_BYTES: u64 = 1 << 20;
/// Largest accepted ONNX member, bytes (the paper's network is ~15 MB of weights).
pub const MAX_ONNX_BYTES: u64 = 512 << 20;

/// Which flow the network sees (REFERENCE.md section 3; masked was best in the paper):
/// the manifest's `flow_variant` (what a bundle was trained on) and the pipeline's
/// `frames.variant` (what the front end computes). One type for both, so they compare with
/// `==`; the names are the same in manifests, profiles and settings.
#[derive(
    Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize, schemars::JsonSchema,
)]
#[serde(rename_all = "snake_case")]
pub enum FlowVariant {
    /// The observed flow as is.
    #[default]
    Plain,
    /// The observed flow minus the registered camera motion.
    Registered,
    /// Zero flow on the robot body (target frame's mask).
    Masked,
    /// Both.
    MaskedRegistered,
}

impl FlowVariant {
    /// All variants, in the paper's order.
    pub const ALL: [FlowVariant; 4] = [
        Self::Plain,
        Self::Registered,
        Self::Masked,
        Self::MaskedRegistered,
    ];

    /// The name used in files and settings.
    pub fn name(self) -> &'static str {
        match self {
            Self::Plain => "plain",
            Self::Registered => "registered",
            Self::Masked => "masked",
            Self::MaskedRegistered => "masked_registered",
        }
    }

    /// Whether the robot body is masked out.
    pub fn is_masked(self) -> bool {
        matches!(self, Self::Masked | Self::MaskedRegistered)
    }

    /// Whether camera motion is removed.
    pub fn is_registered(self) -> bool {
        matches!(self, Self::Registered | Self::MaskedRegistered)
    }
}

impl fmt::Display for FlowVariant {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for FlowVariant {
    type Err = UnknownFlowVariant;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| UnknownFlowVariant { name: s.into() })
    }
}

/// A name that is not a [`FlowVariant`].
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown flow variant {name:?} (expected plain, registered, masked or masked_registered)")]
pub struct UnknownFlowVariant {
    /// The name given.
    pub name: String,
}

/// `architecture`: the network's shape (informational except `latent_dim` and
/// `feature_channels`, which must match the graphs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Architecture {
    /// U-Net filters per level.
    pub filters: Vec<u32>,
    /// Convolutions per level.
    pub convs_per_level: u32,
    /// Latent dimension L.
    pub latent_dim: u32,
    /// Feature channels C of the U-Net output.
    pub feature_channels: u32,
    /// Channels of fcomb's hidden layers.
    pub fcomb_channels: u32,
    /// fcomb's 1x1 layers.
    pub fcomb_layers: u32,
    /// Parameters of the whole trained model.
    pub parameters_total: u64,
    /// Parameters needed at inference.
    pub parameters_inference: u64,
}

/// `input`: what the network input is.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputSpec {
    /// Side of the square input, pixels (64).
    pub size: u32,
    /// Channels (2: u, v).
    pub channels: u32,
    /// Flow magnitude mapped to 0.5, pixels of a `reference_width_px` image.
    pub clip_px: f32,
    /// Width the clip bound refers to, pixels.
    pub reference_width_px: u32,
}

/// `temporal`: the past offsets and samples.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Temporal {
    /// Smallest past offset A (processed flow frames).
    pub a: u32,
    /// Offsets span A..=A+B.
    pub b: u32,
    /// Default prior samples per offset.
    pub m: u32,
}

/// `processing`: the image geometry training used.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Processing {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Images between the two ends of a flow.
    pub stride: u32,
}

/// `members.<name>`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MemberInfo {
    /// Lowercase hex SHA-256 of the member's bytes.
    pub sha256: String,
}

/// `manifest.json` of a bundle, format version 1.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Manifest {
    /// Always `vamos-model`.
    pub format: String,
    /// Bundle format version.
    pub format_version: u64,
    /// Model name.
    pub name: String,
    /// Creation time (RFC 3339), informational.
    pub created: String,
    /// ONNX opset of both graphs.
    pub opset: u64,
    /// Network shape.
    pub architecture: Architecture,
    /// Network input.
    pub input: InputSpec,
    /// Past offsets and samples.
    pub temporal: Temporal,
    /// The flow variant trained on.
    pub flow_variant: FlowVariant,
    /// Image geometry of training.
    pub processing: Processing,
    /// Training facts (informational, free-form beyond the documented keys).
    pub training: serde_json::Map<String, serde_json::Value>,
    /// Checksums of the ONNX members.
    pub members: BTreeMap<String, MemberInfo>,
}

impl Manifest {
    /// Parses and checks `manifest.json`: format, version first (so a future version is
    /// reported as such even if its fields changed), then the fields.
    pub fn parse(bytes: &[u8]) -> Result<Self, ModelError> {
        let bad = |reason: String| ModelError::Manifest { reason };
        let value: serde_json::Value =
            serde_json::from_slice(bytes).map_err(|e| bad(format!("not JSON: {e}")))?;
        let obj = value
            .as_object()
            .ok_or_else(|| bad("not a JSON object".into()))?;
        match obj.get("format").and_then(|f| f.as_str()) {
            Some(FORMAT) => {}
            other => {
                return Err(bad(format!(
                    "format is {other:?}, expected \"{FORMAT}\" (is this a model bundle?)"
                )));
            }
        }
        let version = obj
            .get("format_version")
            .and_then(|v| v.as_u64())
            .ok_or_else(|| bad("format_version is missing or not a whole number".into()))?;
        if version > FORMAT_VERSION {
            return Err(ModelError::FutureFormatVersion {
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        if version == 0 {
            return Err(bad("format_version 0 does not exist".into()));
        }
        let m: Manifest = serde_json::from_value(value).map_err(|e| bad(e.to_string()))?;
        let keys: Vec<&str> = m.members.keys().map(String::as_str).collect();
        if keys != [ENCODER, HEAD] {
            return Err(bad(format!(
                "members lists {keys:?}, expected exactly [\"{ENCODER}\", \"{HEAD}\"]"
            )));
        }
        for (name, info) in &m.members {
            let ok = info.sha256.len() == 64
                && info
                    .sha256
                    .bytes()
                    .all(|b| b.is_ascii_digit() || (b'a'..=b'f').contains(&b));
            if !ok {
                return Err(bad(format!(
                    "members.{name}.sha256 is not 64 lowercase hex digits"
                )));
            }
        }
        if m.input.channels != 2 {
            return Err(bad(format!(
                "input.channels is {}, the flow has 2",
                m.input.channels
            )));
        }
        if m.input.size == 0
            || m.architecture.latent_dim == 0
            || m.architecture.feature_channels == 0
        {
            return Err(bad(
                "input.size, latent_dim and feature_channels must be positive".into(),
            ));
        }
        if m.temporal.m == 0 {
            return Err(bad("temporal.m must be positive".into()));
        }
        Ok(m)
    }
}

impl Manifest {
    /// Checks that the serving pipeline's network-input settings are the ones the model
    /// was trained with (docs/model-bundle.md: a mismatch is refused).
    pub fn check_network_input(
        &self,
        params: &vamos_vision::preprocess::NetworkInputParams,
    ) -> Result<(), ModelError> {
        let i = &self.input;
        let same = params.size_px == i.size as usize
            && params.reference_width_px == i.reference_width_px as usize
            && (params.clip_px - i.clip_px).abs() <= 1e-6 * i.clip_px.abs().max(1.0);
        if same {
            return Ok(());
        }
        Err(ModelError::Manifest {
            reason: format!(
                "the model was trained on inputs of size {} with clip {} px at {} px wide, \
                 the settings ([vision.network_input]) say size {}, clip {} px at {} px",
                i.size,
                i.clip_px,
                i.reference_width_px,
                params.size_px,
                params.clip_px,
                params.reference_width_px
            ),
        })
    }
}

/// A read and checked bundle: the manifest and the raw ONNX bytes.
#[derive(Clone, Debug)]
pub struct Bundle {
    /// The parsed manifest.
    pub manifest: Manifest,
    /// `encoder.onnx`.
    pub encoder: Vec<u8>,
    /// `head.onnx`.
    pub head: Vec<u8>,
    /// SHA-256 (hex) of the whole bundle file: a model's identity.
    pub sha256: String,
}

/// Lowercase hex SHA-256.
pub fn sha256_hex(bytes: &[u8]) -> String {
    let digest = Sha256::digest(bytes);
    digest.iter().map(|b| format!("{b:02x}")).collect()
}

impl Bundle {
    /// Reads a bundle file.
    pub fn read(path: &Path) -> Result<Self, ModelError> {
        let bytes = std::fs::read(path).map_err(|source| ModelError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_bytes_named(&bytes, &path.display().to_string())
    }

    /// Reads a bundle held in memory.
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, ModelError> {
        Self::from_bytes_named(bytes, "<memory>")
    }

    fn from_bytes_named(bytes: &[u8], label: &str) -> Result<Self, ModelError> {
        let not_zip = |reason: String| ModelError::NotAZip {
            path: label.to_string(),
            reason,
        };
        let mut zip = zip::ZipArchive::new(std::io::Cursor::new(bytes))
            .map_err(|e| not_zip(e.to_string()))?;
        for i in 0..zip.len() {
            let entry = zip.by_index_raw(i).map_err(|e| not_zip(e.to_string()))?;
            let name = entry.name().map_err(|e| not_zip(e.to_string()))?;
            if ![MANIFEST, ENCODER, HEAD].contains(&name.as_ref()) {
                return Err(ModelError::UnexpectedMember {
                    member: name.into_owned(),
                });
            }
        }
        let manifest_bytes = read_member(&mut zip, MANIFEST, MAX_MANIFEST_BYTES, label)?;
        let manifest = Manifest::parse(&manifest_bytes)?;
        let encoder = read_member(&mut zip, ENCODER, MAX_ONNX_BYTES, label)?;
        let head = read_member(&mut zip, HEAD, MAX_ONNX_BYTES, label)?;
        for (name, data) in [(ENCODER, &encoder), (HEAD, &head)] {
            let actual = sha256_hex(data);
            // Invariant: Manifest::parse checked that `members` holds exactly both names.
            let expected = &manifest.members[name].sha256;
            if &actual != expected {
                return Err(ModelError::ChecksumMismatch {
                    member: name.into(),
                    expected: expected.clone(),
                    actual,
                });
            }
        }
        Ok(Self {
            manifest,
            encoder,
            head,
            sha256: sha256_hex(bytes),
        })
    }
}

fn read_member<R: Read + Seek>(
    zip: &mut zip::ZipArchive<R>,
    name: &str,
    limit_bytes: u64,
    label: &str,
) -> Result<Vec<u8>, ModelError> {
    let mut entry = match zip.by_name(name) {
        Ok(e) => e,
        Err(zip::result::ZipError::FileNotFound) => {
            return Err(ModelError::MissingMember {
                member: name.into(),
            });
        }
        Err(e) => {
            return Err(ModelError::NotAZip {
                path: label.into(),
                reason: format!("{name}: {e}"),
            });
        }
    };
    if entry.size() > limit_bytes {
        return Err(ModelError::MemberTooLarge {
            member: name.into(),
            size_bytes: entry.size(),
            limit_bytes,
        });
    }
    let mut data = Vec::with_capacity(usize::try_from(entry.size()).unwrap_or(0));
    (&mut entry)
        .take(limit_bytes + 1)
        .read_to_end(&mut data)
        .map_err(|e| ModelError::NotAZip {
            path: label.into(),
            reason: format!("{name}: {e}"),
        })?;
    if data.len() as u64 > limit_bytes {
        return Err(ModelError::MemberTooLarge {
            member: name.into(),
            size_bytes: data.len() as u64,
            limit_bytes,
        });
    }
    Ok(data)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn variant_names_round_trip() {
        for v in FlowVariant::ALL {
            assert_eq!(v.name().parse::<FlowVariant>().unwrap(), v);
        }
        assert!(matches!(
            "masked+registered".parse::<FlowVariant>(),
            Err(UnknownFlowVariant { .. })
        ));
    }

    pub(crate) fn fixture(name: &str) -> std::path::PathBuf {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../tests/fixtures/model")
            .join(name)
    }

    fn zip_of(members: &[(&str, &[u8])]) -> Vec<u8> {
        let mut buf = std::io::Cursor::new(Vec::new());
        {
            let mut w = zip::ZipWriter::new(&mut buf);
            for (name, data) in members {
                w.start_file(*name, zip::write::SimpleFileOptions::default())
                    .unwrap();
                w.write_all(data).unwrap();
            }
            w.finish().unwrap();
        }
        buf.into_inner()
    }

    #[test]
    fn reads_the_valid_fixture() {
        let b = Bundle::read(&fixture("valid.vamos")).unwrap();
        assert_eq!(b.manifest.format_version, 1);
        assert_eq!(b.manifest.architecture.latent_dim, 3);
        assert_eq!(b.manifest.architecture.feature_channels, 4);
        assert_eq!(b.manifest.temporal, Temporal { a: 2, b: 2, m: 3 });
        assert_eq!(b.manifest.flow_variant, FlowVariant::Masked);
        assert_eq!(sha256_hex(&b.encoder), b.manifest.members[ENCODER].sha256);
        assert!(b.encoder.len() > 100 && b.head.len() > 100);
        let raw = std::fs::read(fixture("valid.vamos")).unwrap();
        assert_eq!(b.sha256, sha256_hex(&raw));
    }

    #[test]
    fn network_input_settings_must_match() {
        use vamos_vision::preprocess::NetworkInputParams;
        let b = Bundle::read(&fixture("valid.vamos")).unwrap();
        let mut p = NetworkInputParams::default();
        assert!(b.manifest.check_network_input(&p).is_ok());
        p.clip_px = 10.0;
        let e = b.manifest.check_network_input(&p).unwrap_err();
        assert!(e.to_string().contains("clip 10 px"), "{e}");
        p = NetworkInputParams {
            size_px: 32,
            ..NetworkInputParams::default()
        };
        assert!(b.manifest.check_network_input(&p).is_err());
    }

    #[test]
    fn sha256_of_a_known_string() {
        // FIPS 180-2 example "abc".
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
    }

    #[test]
    fn bad_bundles_give_typed_errors() {
        let e = Bundle::read(&fixture("future_version.vamos")).unwrap_err();
        assert!(
            matches!(
                e,
                ModelError::FutureFormatVersion {
                    found: 99,
                    supported: 1
                }
            ),
            "{e}"
        );
        let e = Bundle::read(&fixture("checksum.vamos")).unwrap_err();
        assert!(
            matches!(&e, ModelError::ChecksumMismatch { member, .. } if member == HEAD),
            "{e}"
        );
        let e = Bundle::read(&fixture("missing_member.vamos")).unwrap_err();
        assert!(
            matches!(&e, ModelError::MissingMember { member } if member == HEAD),
            "{e}"
        );
        let e = Bundle::read(&fixture("extra_member.vamos")).unwrap_err();
        assert!(
            matches!(&e, ModelError::UnexpectedMember { member } if member == "notes.txt"),
            "{e}"
        );
        let e = Bundle::from_bytes(b"PK\x03\x04 not really").unwrap_err();
        assert!(matches!(e, ModelError::NotAZip { .. }), "{e}");
        let e = Bundle::read(Path::new("/nonexistent.vamos")).unwrap_err();
        assert!(matches!(e, ModelError::Io { .. }), "{e}");
    }

    #[test]
    fn manifest_checks() {
        let good = std::fs::read(fixture("valid.vamos")).unwrap();
        let b = Bundle::from_bytes(&good).unwrap();
        let mut v = serde_json::to_value(&b.manifest).unwrap();
        // Unknown top-level key.
        v["colour"] = "red".into();
        let e = Manifest::parse(&serde_json::to_vec(&v).unwrap()).unwrap_err();
        assert!(e.to_string().contains("colour"), "{e}");
        // Unknown training keys are fine (informational).
        let mut v = serde_json::to_value(&b.manifest).unwrap();
        v["training"]["gpu"] = "none".into();
        assert!(Manifest::parse(&serde_json::to_vec(&v).unwrap()).is_ok());
        // Wrong format name, bad digest, unknown variant.
        let mut v = serde_json::to_value(&b.manifest).unwrap();
        v["format"] = "vamos-dataset".into();
        assert!(Manifest::parse(&serde_json::to_vec(&v).unwrap()).is_err());
        let mut v = serde_json::to_value(&b.manifest).unwrap();
        v["members"]["head.onnx"]["sha256"] = "ABC".into();
        assert!(Manifest::parse(&serde_json::to_vec(&v).unwrap()).is_err());
        let mut v = serde_json::to_value(&b.manifest).unwrap();
        v["flow_variant"] = "sideways".into();
        assert!(Manifest::parse(&serde_json::to_vec(&v).unwrap()).is_err());
        assert!(Manifest::parse(b"[1, 2]").is_err());
    }

    #[test]
    fn oversized_members_are_refused_before_reading() {
        let b = Bundle::read(&fixture("valid.vamos")).unwrap();
        let manifest = serde_json::to_vec(&b.manifest).unwrap();
        let big = vec![b' '; (MAX_MANIFEST_BYTES + 10) as usize];
        let bytes = zip_of(&[(MANIFEST, &big), (ENCODER, &b.encoder), (HEAD, &b.head)]);
        let e = Bundle::from_bytes(&bytes).unwrap_err();
        assert!(
            matches!(&e, ModelError::MemberTooLarge { member, .. } if member == MANIFEST),
            "{e}"
        );
        // The same bundle with a normal manifest reads (deflate written by Rust, too).
        let bytes = zip_of(&[
            (MANIFEST, &manifest),
            (ENCODER, &b.encoder),
            (HEAD, &b.head),
        ]);
        assert!(Bundle::from_bytes(&bytes).is_ok());
    }
}
