//! The loaded flow predictor network: one ONNX Runtime session per graph (encoder, head),
//! validated against the contract and shared by every robot session.
//!
//! `ort`'s `Session::run` takes `&mut self`, so each graph is loaded into a small pool of
//! sessions ([`LoadOptions::replicas`], default one per core), each behind a `Mutex`: robot
//! sessions that call the same graph at the same moment run on different replicas, and
//! only queue when every replica is busy (each call uses the configured intra-op threads).

use super::HeadBackend;
use super::bundle::{Bundle, ENCODER, HEAD, Manifest};
use super::head::{HeadScratch, NativeHead};
use super::onnx_proto;
use super::runtime::{self, RuntimeOptions};
use super::{ModelError, rng::NormalRng};
use ort::session::Session;
use ort::session::builder::GraphOptimizationLevel;
use ort::value::{TensorElementType, TensorRef, ValueType};
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex, MutexGuard, RwLock, TryLockError};

mod checks;

use checks::*;

/// Opsets accepted (ONNX Runtime 1.31 runs them; the contract asks for 17).
pub const SUPPORTED_OPSETS: std::ops::RangeInclusive<u64> = 13..=21;

/// Options of loading a model.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct LoadOptions {
    /// Intra-op threads per session (0 = ONNX Runtime's default, one per core).
    pub intra_threads: usize,
    /// Sessions per graph, so that concurrent callers run in parallel (0 = one per core,
    /// at most 8). Each replica holds its own copy of the weights.
    pub replicas: usize,
    /// Where the ONNX Runtime library may come from.
    pub runtime: RuntimeOptions,
    /// Which implementation runs the head.
    pub head: HeadBackend,
}

impl Default for LoadOptions {
    fn default() -> Self {
        Self {
            intra_threads: 1,
            replicas: 0,
            runtime: RuntimeOptions::default(),
            head: HeadBackend::Auto,
        }
    }
}

/// The fixed dimensions of a validated model.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ModelDims {
    /// Side of the square input and output, pixels (64).
    pub size: usize,
    /// Feature channels C of the encoder output.
    pub channels: usize,
    /// Latent dimension L.
    pub latent: usize,
}

impl ModelDims {
    /// Values of one flow `[2, size, size]`.
    pub fn flow_len(&self) -> usize {
        2 * self.size * self.size
    }

    /// Values of one feature map `[C, size, size]`.
    pub fn features_len(&self) -> usize {
        self.channels * self.size * self.size
    }
}

/// The encoder's outputs for a batch of `batch` flows (C order).
#[derive(Clone, Debug, PartialEq)]
pub struct EncoderOutput {
    /// Rows in the batch.
    pub batch: usize,
    /// `[batch, C, S, S]`.
    pub features: Vec<f32>,
    /// `[batch, L]`.
    pub prior_mu: Vec<f32>,
    /// `[batch, L]`.
    pub prior_log_sigma: Vec<f32>,
}

/// Replicas of one graph's session; a caller takes a free one, or waits for one.
struct SessionPool {
    sessions: Vec<Mutex<Session>>,
    next: AtomicUsize,
}

impl SessionPool {
    /// A free replica if there is one (starting the search round-robin), else waits for
    /// the next in turn.
    fn get(&self) -> MutexGuard<'_, Session> {
        let n = self.sessions.len();
        let start = self.next.fetch_add(1, Ordering::Relaxed) % n;
        for k in 0..n {
            match self.sessions[(start + k) % n].try_lock() {
                Ok(guard) => return guard,
                // A panic elsewhere cannot leave an ONNX session half-updated.
                Err(TryLockError::Poisoned(p)) => return p.into_inner(),
                Err(TryLockError::WouldBlock) => {}
            }
        }
        self.sessions[start]
            .lock()
            .unwrap_or_else(|p| p.into_inner())
    }
}

/// The replica count `replicas` asks for (0: one per core, at most 8).
fn replica_count(replicas: usize) -> usize {
    if replicas > 0 {
        replicas
    } else {
        std::thread::available_parallelism().map_or(1, |n| n.get().min(8))
    }
}

/// A loaded, validated model: manifest and the session pools of its two graphs.
pub struct FlowModel {
    manifest: Manifest,
    sha256: String,
    dims: ModelDims,
    encoder: SessionPool,
    head: SessionPool,
    /// The head as native code, when `head.onnx` was recognised and agrees with ONNX
    /// Runtime (`HeadBackend::Auto`).
    native: Option<NativeHead>,
    /// Why the native head is not used, when it is not.
    native_note: Option<String>,
}

impl std::fmt::Debug for FlowModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FlowModel")
            .field("name", &self.manifest.name)
            .field("sha256", &self.sha256)
            .field("dims", &self.dims)
            .field("native_head", &self.native.is_some())
            .finish_non_exhaustive()
    }
}

impl FlowModel {
    /// Reads, checks and loads a bundle file.
    pub fn load(path: &Path, options: &LoadOptions) -> Result<Self, ModelError> {
        Self::from_bundle(Bundle::read(path)?, options)
    }

    /// Loads and validates a read bundle: opsets, graph signatures against the contract,
    /// C and L agreement of encoder, head and manifest, and a smoke inference.
    pub fn from_bundle(bundle: Bundle, options: &LoadOptions) -> Result<Self, ModelError> {
        let m = &bundle.manifest;
        check_opset(ENCODER, &bundle.encoder, m.opset)?;
        check_opset(HEAD, &bundle.head, m.opset)?;
        let size = i64::from(m.input.size);
        let encoder = session(ENCODER, &bundle.encoder, options)?;
        let head = session(HEAD, &bundle.head, options)?;

        check_outlets(
            ENCODER,
            "inputs",
            encoder.inputs(),
            &[("flow", &[Some(2), Some(size), Some(size)])],
        )?;
        let enc_out = check_outlets(
            ENCODER,
            "outputs",
            encoder.outputs(),
            &[
                ("features", &[None, Some(size), Some(size)]),
                ("prior_mu", &[None]),
                ("prior_log_sigma", &[None]),
            ],
        )?;
        let head_in = check_outlets(
            HEAD,
            "inputs",
            head.inputs(),
            &[
                ("features", &[None, Some(size), Some(size)]),
                ("z", &[None]),
            ],
        )?;
        check_outlets(
            HEAD,
            "outputs",
            head.outputs(),
            &[("flow", &[Some(2), Some(size), Some(size)])],
        )?;
        let (enc_c, enc_l, enc_ls) = (enc_out[0][1], enc_out[1][1], enc_out[2][1]);
        let (head_c, head_l) = (head_in[0][1], head_in[1][1]);
        if enc_l != enc_ls {
            return Err(ModelError::Signature {
                member: ENCODER.into(),
                reason: format!("prior_mu has L = {enc_l} but prior_log_sigma {enc_ls}"),
            });
        }
        let man_c = i64::from(m.architecture.feature_channels);
        let man_l = i64::from(m.architecture.latent_dim);
        if enc_c != head_c || enc_c != man_c {
            return Err(ModelError::DimensionMismatch {
                what: "feature_channels (C)",
                encoder: enc_c,
                head: head_c,
                manifest: man_c,
            });
        }
        if enc_l != head_l || enc_l != man_l {
            return Err(ModelError::DimensionMismatch {
                what: "latent_dim (L)",
                encoder: enc_l,
                head: head_l,
                manifest: man_l,
            });
        }
        let dims = ModelDims {
            size: m.input.size as usize,
            channels: enc_c as usize,
            latent: enc_l as usize,
        };
        let replicas = replica_count(options.replicas);
        let mut encoders = vec![Mutex::new(encoder)];
        let mut heads = vec![Mutex::new(head)];
        for _ in 1..replicas {
            encoders.push(Mutex::new(session(ENCODER, &bundle.encoder, options)?));
            heads.push(Mutex::new(session(HEAD, &bundle.head, options)?));
        }
        let mut model = Self {
            manifest: bundle.manifest,
            sha256: bundle.sha256,
            dims,
            encoder: SessionPool {
                sessions: encoders,
                next: AtomicUsize::new(0),
            },
            head: SessionPool {
                sessions: heads,
                next: AtomicUsize::new(0),
            },
            native: None,
            native_note: None,
        };
        model.smoke_test()?;
        match options.head {
            HeadBackend::Onnx => model.native_note = Some("head = \"onnx\" in the settings".into()),
            HeadBackend::Auto => match model.native_candidate(&bundle.head) {
                Ok(head) => model.native = Some(head),
                Err(why) => {
                    tracing::info!(
                        model = %model.manifest.name,
                        "the head runs in ONNX Runtime: {why}"
                    );
                    model.native_note = Some(why);
                }
            },
        }
        Ok(model)
    }

    /// Reads fcomb out of `head.onnx` and checks it against ONNX Runtime's head on four
    /// random rows: every output within 1e-4 x (1 + the largest |output|).
    fn native_candidate(&self, head_onnx: &[u8]) -> Result<NativeHead, String> {
        let graph = onnx_proto::read_graph(head_onnx)?;
        let d = self.dims;
        let head = NativeHead::from_onnx(&graph, d.channels, d.latent, d.size)
            .map_err(|e| format!("head.onnx is not a recognised fcomb ({e})"))?;
        let mut rng = NormalRng::new(0xfc0b);
        let rows = 4;
        // U-Net features come out of a ReLU: non-negative, of order one.
        let features: Vec<f32> = (0..rows * d.features_len())
            .map(|_| rng.normal().abs() as f32)
            .collect();
        let z: Vec<f32> = (0..rows * d.latent)
            .map(|_| (rng.normal() * 1.5) as f32)
            .collect();
        let want = self
            .predict(&features, &z, rows)
            .map_err(|e| format!("checking the native head: {e}"))?;
        let (fe, fl) = (d.features_len(), d.flow_len());
        let mut got = vec![0.0f32; fl];
        let mut scratch = HeadScratch::default();
        for r in 0..rows {
            let projected = head.project(&features[r * fe..(r + 1) * fe]);
            head.predict_row(
                &projected,
                &z[r * d.latent..(r + 1) * d.latent],
                &mut got,
                &mut scratch,
            );
            let w = &want[r * fl..(r + 1) * fl];
            let scale = 1.0 + w.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            let worst = got
                .iter()
                .zip(w)
                .map(|(a, b)| (a - b).abs())
                .fold(
                    0.0f32,
                    |m, v| if v.is_nan() { f32::INFINITY } else { m.max(v) },
                );
            if worst > 1e-4 * scale {
                return Err(format!(
                    "the native head differs from ONNX Runtime's by {worst:e} (row {r})"
                ));
            }
        }
        Ok(head)
    }

    /// The native head, when it runs the head instead of ONNX Runtime.
    pub fn native_head(&self) -> Option<&NativeHead> {
        self.native.as_ref()
    }

    /// Which implementation runs the head: `"native"` or `"onnxruntime"`, and why not
    /// native when it is not.
    pub fn head_backend(&self) -> (&'static str, Option<&str>) {
        match &self.native {
            Some(_) => ("native", None),
            None => ("onnxruntime", self.native_note.as_deref()),
        }
    }

    /// Sessions per graph (concurrent inference calls that do not wait for each other).
    pub fn replicas(&self) -> usize {
        self.encoder.sessions.len()
    }

    /// Runs both graphs on a random batch of two and checks shapes and finiteness.
    fn smoke_test(&self) -> Result<(), ModelError> {
        let smoke = |reason: String| ModelError::SmokeTest { reason };
        let mut rng = NormalRng::new(0x5eed);
        let n = 2;
        let flow: Vec<f32> = (0..n * self.dims.flow_len())
            .map(|_| (rng.normal() * 0.15).clamp(-0.5, 0.5) as f32)
            .collect();
        let enc = self
            .encode(&flow, n)
            .map_err(|e| smoke(format!("encoder: {e}")))?;
        for (name, v) in [
            ("features", &enc.features),
            ("prior_mu", &enc.prior_mu),
            ("prior_log_sigma", &enc.prior_log_sigma),
        ] {
            if let Some(i) = v.iter().position(|x| !x.is_finite()) {
                return Err(smoke(format!("encoder output {name}[{i}] is {}", v[i])));
            }
        }
        let z: Vec<f32> = enc
            .prior_mu
            .iter()
            .zip(&enc.prior_log_sigma)
            .map(|(m, s)| m + s.exp() * rng.normal() as f32)
            .collect();
        let pred = self
            .predict(&enc.features, &z, n)
            .map_err(|e| smoke(format!("head: {e}")))?;
        if let Some(i) = pred.iter().position(|x| !x.is_finite()) {
            return Err(smoke(format!("head output flow[{i}] is {}", pred[i])));
        }
        Ok(())
    }

    /// The manifest.
    pub fn manifest(&self) -> &Manifest {
        &self.manifest
    }

    /// SHA-256 (hex) of the bundle file.
    pub fn sha256(&self) -> &str {
        &self.sha256
    }

    /// The fixed dimensions.
    pub fn dims(&self) -> ModelDims {
        self.dims
    }

    /// Runs the encoder on `batch` flows `[batch, 2, S, S]`.
    pub fn encode(&self, flow: &[f32], batch: usize) -> Result<EncoderOutput, ModelError> {
        let d = self.dims;
        let expected = batch * d.flow_len();
        if batch == 0 || flow.len() != expected {
            return Err(ModelError::InputShape {
                what: "encoder flow",
                expected,
                actual: flow.len(),
            });
        }
        let input = TensorRef::from_array_view(([batch, 2, d.size, d.size], flow))
            .map_err(ort_err("wrapping the encoder input"))?;
        let mut session = self.encoder.get();
        let outputs = session
            .run(ort::inputs!["flow" => input])
            .map_err(ort_err("running the encoder"))?;
        let take = |name: &'static str, len: usize| -> Result<Vec<f32>, ModelError> {
            let value = outputs.get(name).ok_or(ModelError::Ort {
                context: "reading encoder outputs",
                reason: format!("no output {name}"),
            })?;
            let (_, data) = value
                .try_extract_tensor::<f32>()
                .map_err(ort_err("reading encoder outputs"))?;
            if data.len() != len {
                return Err(ModelError::Ort {
                    context: "reading encoder outputs",
                    reason: format!("{name} has {} values, expected {len}", data.len()),
                });
            }
            Ok(data.to_vec())
        };
        Ok(EncoderOutput {
            batch,
            features: take("features", batch * d.features_len())?,
            prior_mu: take("prior_mu", batch * d.latent)?,
            prior_log_sigma: take("prior_log_sigma", batch * d.latent)?,
        })
    }

    /// Runs the head on `batch` (features, z) rows; returns `[batch, 2, S, S]`.
    pub fn predict(
        &self,
        features: &[f32],
        z: &[f32],
        batch: usize,
    ) -> Result<Vec<f32>, ModelError> {
        let mut out = Vec::new();
        self.predict_into(features, z, batch, &mut out)?;
        Ok(out)
    }

    /// As [`FlowModel::predict`], writing into `out` (resized; its allocation is reused).
    pub fn predict_into(
        &self,
        features: &[f32],
        z: &[f32],
        batch: usize,
        out: &mut Vec<f32>,
    ) -> Result<(), ModelError> {
        let d = self.dims;
        if batch == 0 || features.len() != batch * d.features_len() {
            return Err(ModelError::InputShape {
                what: "head features",
                expected: batch * d.features_len(),
                actual: features.len(),
            });
        }
        if z.len() != batch * d.latent {
            return Err(ModelError::InputShape {
                what: "head z",
                expected: batch * d.latent,
                actual: z.len(),
            });
        }
        let f = TensorRef::from_array_view(([batch, d.channels, d.size, d.size], features))
            .map_err(ort_err("wrapping the head features"))?;
        let zt = TensorRef::from_array_view(([batch, d.latent], z))
            .map_err(ort_err("wrapping the head z"))?;
        let mut session = self.head.get();
        let outputs = session
            .run(ort::inputs!["features" => f, "z" => zt])
            .map_err(ort_err("running the head"))?;
        let value = outputs.get("flow").ok_or(ModelError::Ort {
            context: "reading the head output",
            reason: "no output flow".into(),
        })?;
        let (_, data) = value
            .try_extract_tensor::<f32>()
            .map_err(ort_err("reading the head output"))?;
        if data.len() != batch * d.flow_len() {
            return Err(ModelError::Ort {
                context: "reading the head output",
                reason: format!(
                    "flow has {} values, expected {}",
                    data.len(),
                    batch * d.flow_len()
                ),
            });
        }
        out.clear();
        out.extend_from_slice(data);
        Ok(())
    }
}

/// Holds the current model; a new one replaces it atomically, and only once it has
/// loaded and validated, so a bad bundle never displaces a working model. Readers get an
/// `Arc` and keep using the model they hold while a swap happens.
#[derive(Debug, Default)]
pub struct ModelSlot {
    current: RwLock<Option<Arc<FlowModel>>>,
}

impl ModelSlot {
    /// An empty slot.
    pub fn new() -> Self {
        Self::default()
    }

    /// The current model, if any.
    pub fn get(&self) -> Option<Arc<FlowModel>> {
        self.current
            .read()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Installs an already validated model; returns the previous one.
    pub fn replace(&self, model: Arc<FlowModel>) -> Option<Arc<FlowModel>> {
        let mut guard = self.current.write().unwrap_or_else(|p| p.into_inner());
        guard.replace(model)
    }

    /// Loads and validates `path`, then installs it. On any error the current model stays.
    pub fn load(&self, path: &Path, options: &LoadOptions) -> Result<Arc<FlowModel>, ModelError> {
        let model = Arc::new(FlowModel::load(path, options)?);
        self.replace(model.clone());
        Ok(model)
    }
}
