//! A native implementation of the bundle's head (fcomb) for the predictor's hot loop.
//!
//! The head of the probabilistic U-Net (REFERENCE.md section 3) is a stack of 1x1
//! convolutions over `concat(features, tile(z))`: per pixel, a small dense network. Its
//! first layer is linear in the concatenation, so it splits into a feature part and a
//! latent part:
//!
//! `W1 [f; z] + b1 = (W1_f f + b1) + W1_z z`
//!
//! The feature part depends only on the past frame, so it is computed once when the
//! frame's encoder output is cached ([`NativeHead::project`]); each of the `(B + 1) x M`
//! rows of a frame then adds `W1_z z` (a per-channel constant) and runs the remaining
//! layers ([`NativeHead::predict_row`]). That removes the `C x H1` part of the first layer
//! from every row (a third of the paper head's work) and the copies of the feature maps
//! into a batch, which is what makes the cached predictor more than 4x cheaper than the
//! naive loop (`benches/README.md`).
//!
//! The head is read from `head.onnx` itself ([`NativeHead::from_onnx`]): the chain of
//! 1x1 `Conv` (+ `Relu`) nodes from the output `flow` back to a `Concat` of the input
//! `features` and the tiled `z`. A graph of any other shape is not recognised and the
//! model keeps using ONNX Runtime for its head; a recognised one is also checked against
//! ONNX Runtime on random inputs when the model loads (`network.rs`).
//!
//! The kernel works on tiles of [`TILE`] pixels with every layer's activations in a small
//! buffer (they stay in L1); on x86-64 with AVX2 and FMA it is compiled with those
//! features (fused multiply-add), elsewhere as plain Rust. The two builds differ in the
//! last bits of a float (FMA rounds once); each is deterministic.

use super::onnx_proto::{OnnxGraph, OnnxNode};

/// Pixels per tile of the kernel.
pub const TILE: usize = 32;

/// One 1x1 convolution: `out[o] = b[o] + sum_i w[o * inputs + i] * in[i]`, then ReLU.
#[derive(Clone, Debug, PartialEq)]
struct Dense {
    outputs: usize,
    inputs: usize,
    /// `[outputs, inputs]`, row-major (ONNX's `[O, I, 1, 1]`).
    weights: Vec<f32>,
    bias: Vec<f32>,
    relu: bool,
}

/// fcomb as plain weights, with its first layer split into feature and latent parts.
#[derive(Clone, Debug, PartialEq)]
pub struct NativeHead {
    channels: usize,
    latent: usize,
    pixels: usize,
    /// First layer: `[H1, C]` feature part, `[H1, L]` latent part, bias, ReLU.
    first_features: Vec<f32>,
    first_latent: Vec<f32>,
    first_bias: Vec<f32>,
    first_width: usize,
    first_relu: bool,
    /// The layers after the first (the last one has no ReLU and 2 outputs).
    rest: Vec<Dense>,
    widest: usize,
    fused: bool,
}

/// Per-caller buffers of [`NativeHead::predict_row`].
#[derive(Clone, Debug, Default)]
pub struct HeadScratch {
    a: Vec<[f32; TILE]>,
    b: Vec<[f32; TILE]>,
    latent_bias: Vec<f32>,
}

fn conv_1x1(graph: &OnnxGraph, node: &OnnxNode) -> Result<Dense, String> {
    let all_ones = |name: &str| node.ints(name).is_none_or(|v| v.iter().all(|&x| x == 1));
    if node.ints("group").is_some_and(|g| g != [1])
        || !all_ones("strides")
        || !all_ones("dilations")
        || !all_ones("kernel_shape")
        || node.ints("pads").is_some_and(|p| p.iter().any(|&x| x != 0))
    {
        return Err("a Conv that is not a plain 1x1 convolution".into());
    }
    let weight_name = node.inputs.get(1).ok_or("a Conv without weights")?;
    let w = graph
        .initializer(weight_name)
        .ok_or_else(|| format!("Conv weights {weight_name} are not an initializer"))?;
    let weights = w
        .floats
        .clone()
        .ok_or_else(|| format!("Conv weights {weight_name} are not float data in the file"))?;
    let (outputs, inputs) = match w.dims.as_slice() {
        [o, i, 1, 1] if *o > 0 && *i > 0 => (*o as usize, *i as usize),
        d => return Err(format!("Conv weights {weight_name} have shape {d:?}")),
    };
    let bias = match node.inputs.get(2).filter(|n| !n.is_empty()) {
        None => vec![0.0; outputs],
        Some(name) => {
            let b = graph
                .initializer(name)
                .and_then(|t| t.floats.clone())
                .ok_or_else(|| format!("Conv bias {name} is not float data in the file"))?;
            if b.len() != outputs {
                return Err(format!("Conv bias {name} has {} values", b.len()));
            }
            b
        }
    };
    Ok(Dense {
        outputs,
        inputs,
        weights,
        bias,
        relu: false,
    })
}

impl NativeHead {
    /// Recognises fcomb in a parsed `head.onnx`: `flow` produced by a chain of 1x1 `Conv`
    /// nodes with `Relu` between them, whose first `Conv` reads `Concat(features, ...)`
    /// along the channel axis with `channels + latent` inputs, ending in 2 channels.
    /// `Err` says why a graph is not of that shape.
    pub(crate) fn from_onnx(
        graph: &OnnxGraph,
        channels: usize,
        latent: usize,
        size: usize,
    ) -> Result<Self, String> {
        let mut layers = Vec::new();
        let mut tensor = "flow".to_string();
        let mut relu_pending = false;
        let concat = loop {
            let node = graph
                .producer(&tensor)
                .ok_or_else(|| format!("nothing produces {tensor}"))?;
            if !node.domain.is_empty() && node.domain != "ai.onnx" {
                return Err(format!(
                    "node {} is in domain {}",
                    node.op_type, node.domain
                ));
            }
            match node.op_type.as_str() {
                "Relu" if !relu_pending && !layers.is_empty() => relu_pending = true,
                "Conv" => {
                    let mut d = conv_1x1(graph, node)?;
                    d.relu = relu_pending;
                    relu_pending = false;
                    layers.push(d);
                }
                "Concat" if !relu_pending && !layers.is_empty() => break node,
                other => return Err(format!("unexpected {other} node in the head chain")),
            }
            tensor = node
                .inputs
                .first()
                .cloned()
                .ok_or("a node without inputs")?;
            if layers.len() > 64 {
                return Err("more than 64 layers".into());
            }
        };
        if concat.ints("axis").is_none_or(|a| a != [1] && a != [-3]) {
            return Err("the Concat is not along the channel axis".into());
        }
        if concat.inputs.len() != 2 || concat.inputs[0] != "features" {
            return Err("the Concat does not take (features, z)".into());
        }
        layers.reverse();
        for pair in layers.windows(2) {
            if pair[0].outputs != pair[1].inputs {
                return Err("consecutive layers do not fit together".into());
            }
        }
        let first = layers.remove(0);
        if first.inputs != channels + latent {
            return Err(format!(
                "the first layer takes {} channels, not C + L = {}",
                first.inputs,
                channels + latent
            ));
        }
        let out = layers.last().unwrap_or(&first).outputs;
        if out != 2 {
            return Err(format!("the head ends in {out} channels, not 2"));
        }
        let h1 = first.outputs;
        let mut first_features = Vec::with_capacity(h1 * channels);
        let mut first_latent = Vec::with_capacity(h1 * latent);
        for row in first.weights.chunks_exact(first.inputs) {
            first_features.extend_from_slice(&row[..channels]);
            first_latent.extend_from_slice(&row[channels..]);
        }
        let widest = layers
            .iter()
            .map(|l| l.outputs)
            .chain([h1])
            .max()
            .unwrap_or(h1);
        Ok(Self {
            channels,
            latent,
            pixels: size * size,
            first_features,
            first_latent,
            first_bias: first.bias,
            first_width: h1,
            first_relu: first.relu,
            rest: layers,
            widest,
            fused: fma_available(),
        })
    }

    /// Values of a projected feature map (`[H1, S, S]`).
    pub fn projected_len(&self) -> usize {
        self.first_width * self.pixels
    }

    /// The first layer's feature part and bias on one frame's features `[C, S, S]`:
    /// `[H1, S, S]`, cached with the frame.
    pub fn project(&self, features: &[f32]) -> Vec<f32> {
        debug_assert_eq!(features.len(), self.channels * self.pixels);
        let mut out = vec![0.0f32; self.first_width * self.pixels];
        #[cfg(target_arch = "x86_64")]
        if self.fused {
            // SAFETY: `fused` is only set when the CPU has AVX2 and FMA (`fma_available`).
            unsafe { project_fma(self, features, &mut out) };
            return out;
        }
        project_impl::<Plain>(self, features, &mut out);
        out
    }

    /// The predicted flow `[2, S, S]` for one latent sample `z` (`[L]`) from a projected
    /// feature map, written to `out`.
    pub fn predict_row(
        &self,
        projected: &[f32],
        z: &[f32],
        out: &mut [f32],
        scratch: &mut HeadScratch,
    ) {
        self.run_row(projected, z, out, scratch, None);
    }

    /// As [`NativeHead::predict_row`], also summing the squared error against
    /// `score.target` over its valid pixels in f64, tile by tile. Stops early and returns
    /// `None` as soon as the partial sum reaches `score.bound` (the row can then not beat a
    /// row whose sum is the bound; `out` is then incomplete); otherwise returns the sum.
    pub fn predict_row_sse(
        &self,
        projected: &[f32],
        z: &[f32],
        out: &mut [f32],
        scratch: &mut HeadScratch,
        score: RowScore<'_>,
    ) -> Option<f64> {
        debug_assert_eq!(score.target.len(), 2 * self.pixels);
        debug_assert!(score.mask.is_none_or(|m| m.len() == self.pixels));
        self.run_row(projected, z, out, scratch, Some(score))
    }

    fn run_row(
        &self,
        projected: &[f32],
        z: &[f32],
        out: &mut [f32],
        scratch: &mut HeadScratch,
        score: Option<RowScore<'_>>,
    ) -> Option<f64> {
        debug_assert_eq!(projected.len(), self.projected_len());
        debug_assert_eq!(z.len(), self.latent);
        debug_assert_eq!(out.len(), 2 * self.pixels);
        scratch.latent_bias.clear();
        scratch.latent_bias.extend(
            self.first_latent
                .chunks_exact(self.latent)
                .map(|w| w.iter().zip(z).map(|(a, b)| a * b).sum::<f32>()),
        );
        scratch.a.resize(self.widest, [0.0; TILE]);
        scratch.b.resize(self.widest, [0.0; TILE]);
        #[cfg(target_arch = "x86_64")]
        if self.fused {
            // SAFETY: `fused` is only set when the CPU has AVX2 and FMA (`fma_available`).
            return unsafe { predict_row_fma(self, projected, out, scratch, score) };
        }
        predict_row_impl::<Plain>(self, projected, out, scratch, score)
    }
}

/// What a scored row ([`NativeHead::predict_row_sse`]) is compared with.
#[derive(Clone, Copy, Debug)]
pub struct RowScore<'a> {
    /// The observed flow `[2, S, S]`.
    pub target: &'a [f32],
    /// Valid pixels `[S, S]` (`true` = use), or `None` for all.
    pub mask: Option<&'a [bool]>,
    /// The sum of squared errors at which the row stops (`f64::INFINITY`: never).
    pub bound: f64,
}

/// Whether the fused (AVX2 + FMA) kernel can run here.
fn fma_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Multiply-add `a * b + c`, rounded once (`Fused`) or twice (`Plain`).
trait MulAdd {
    fn madd(a: f32, b: f32, c: f32) -> f32;
}

struct Plain;
impl MulAdd for Plain {
    #[inline(always)]
    fn madd(a: f32, b: f32, c: f32) -> f32 {
        a * b + c
    }
}

#[cfg(target_arch = "x86_64")]
struct Fused;
#[cfg(target_arch = "x86_64")]
impl MulAdd for Fused {
    #[inline(always)]
    fn madd(a: f32, b: f32, c: f32) -> f32 {
        a.mul_add(b, c)
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn predict_row_fma(
    head: &NativeHead,
    projected: &[f32],
    out: &mut [f32],
    s: &mut HeadScratch,
    score: Option<RowScore<'_>>,
) -> Option<f64> {
    predict_row_impl::<Fused>(head, projected, out, s, score)
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn project_fma(head: &NativeHead, features: &[f32], out: &mut [f32]) {
    project_impl::<Fused>(head, features, out);
}

#[inline(always)]
fn project_impl<M: MulAdd>(head: &NativeHead, features: &[f32], out: &mut [f32]) {
    let px = head.pixels;
    for (o, row) in out.chunks_exact_mut(px).enumerate() {
        row.fill(head.first_bias[o]);
        let w = &head.first_features[o * head.channels..(o + 1) * head.channels];
        for (c, &wc) in w.iter().enumerate() {
            for (r, f) in row.iter_mut().zip(&features[c * px..(c + 1) * px]) {
                *r = M::madd(wc, *f, *r);
            }
        }
    }
}

#[inline(always)]
fn predict_row_impl<M: MulAdd>(
    head: &NativeHead,
    projected: &[f32],
    out: &mut [f32],
    s: &mut HeadScratch,
    score: Option<RowScore<'_>>,
) -> Option<f64> {
    let mut sse = 0.0f64;
    let px = head.pixels;
    let h1 = head.first_width;
    let mut t0 = 0;
    while t0 < px {
        let len = TILE.min(px - t0);
        // First layer: the cached feature part plus this sample's latent part.
        for (o, dst) in s.a[..h1].iter_mut().enumerate() {
            let src = &projected[o * px + t0..o * px + t0 + len];
            let zb = s.latent_bias[o];
            for (d, v) in dst.iter_mut().zip(src) {
                let x = v + zb;
                *d = if head.first_relu { x.max(0.0) } else { x };
            }
            dst[len..].fill(0.0);
        }
        let (mut cur, mut next) = (&mut s.a, &mut s.b);
        for layer in &head.rest {
            dense_tile::<M>(layer, &cur[..layer.inputs], &mut next[..layer.outputs]);
            std::mem::swap(&mut cur, &mut next);
        }
        for c in 0..2 {
            out[c * px + t0..c * px + t0 + len].copy_from_slice(&cur[c][..len]);
        }
        if let Some(RowScore {
            target,
            mask,
            bound,
        }) = score
        {
            let (u, v) = (&target[t0..t0 + len], &target[px + t0..px + t0 + len]);
            let mut tile = 0.0f64;
            for p in 0..len {
                if mask.is_none_or(|m| m[t0 + p]) {
                    let du = f64::from(cur[0][p]) - f64::from(u[p]);
                    let dv = f64::from(cur[1][p]) - f64::from(v[p]);
                    tile += du * du + dv * dv;
                }
            }
            sse += tile;
            // Squared errors only add up: once the partial sum reaches the bound, the
            // whole row cannot end below it.
            if sse >= bound {
                return None;
            }
        }
        t0 += len;
    }
    Some(sse)
}

/// One layer on one tile, two output channels at a time (their accumulators and one
/// input row stay in registers).
#[inline(always)]
fn dense_tile<M: MulAdd>(layer: &Dense, input: &[[f32; TILE]], output: &mut [[f32; TILE]]) {
    let n_in = layer.inputs;
    let mut o = 0;
    while o + 2 <= layer.outputs {
        let w0 = &layer.weights[o * n_in..(o + 1) * n_in];
        let w1 = &layer.weights[(o + 1) * n_in..(o + 2) * n_in];
        let mut acc0 = [layer.bias[o]; TILE];
        let mut acc1 = [layer.bias[o + 1]; TILE];
        for ((x, &a), &b) in input.iter().zip(w0).zip(w1) {
            for p in 0..TILE {
                acc0[p] = M::madd(a, x[p], acc0[p]);
                acc1[p] = M::madd(b, x[p], acc1[p]);
            }
        }
        if layer.relu {
            for p in 0..TILE {
                acc0[p] = acc0[p].max(0.0);
                acc1[p] = acc1[p].max(0.0);
            }
        }
        output[o] = acc0;
        output[o + 1] = acc1;
        o += 2;
    }
    if o < layer.outputs {
        let w0 = &layer.weights[o * n_in..(o + 1) * n_in];
        let mut acc0 = [layer.bias[o]; TILE];
        for (x, &a) in input.iter().zip(w0) {
            for p in 0..TILE {
                acc0[p] = M::madd(a, x[p], acc0[p]);
            }
        }
        if layer.relu {
            for v in &mut acc0 {
                *v = v.max(0.0);
            }
        }
        output[o] = acc0;
    }
}

#[cfg(test)]
#[path = "head_tests.rs"]
mod tests;
