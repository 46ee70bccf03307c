//! The native head: the split first layer, recognising fcomb (and refusing other shapes),
//! scored rows and their early stop.

use super::*;

/// A head with random weights: C 5, L 3, hidden 7 (odd, to exercise the single
/// output path), 2 hidden layers, 9x9 pixels (a partial tile).
fn random_head(fused: bool) -> NativeHead {
    let mut rng = crate::rng::NormalRng::new(3);
    let mut r = |n: usize| -> Vec<f32> { (0..n).map(|_| rng.normal() as f32 * 0.4).collect() };
    let (c, l, h) = (5, 3, 7);
    NativeHead {
        channels: c,
        latent: l,
        pixels: 81,
        first_features: r(h * c),
        first_latent: r(h * l),
        first_bias: r(h),
        first_width: h,
        first_relu: true,
        rest: vec![
            Dense {
                outputs: h,
                inputs: h,
                weights: r(h * h),
                bias: r(h),
                relu: true,
            },
            Dense {
                outputs: 2,
                inputs: h,
                weights: r(2 * h),
                bias: r(2),
                relu: false,
            },
        ],
        widest: h,
        fused,
    }
}

/// The straightforward per-pixel evaluation of the whole head on `[features, z]`.
fn reference(head: &NativeHead, features: &[f32], z: &[f32]) -> Vec<f32> {
    let px = head.pixels;
    let mut out = vec![0.0; 2 * px];
    for p in 0..px {
        let mut act: Vec<f32> = (0..head.first_width)
            .map(|o| {
                let mut v = head.first_bias[o];
                for c in 0..head.channels {
                    v += head.first_features[o * head.channels + c] * features[c * px + p];
                }
                for (l, zl) in z.iter().enumerate() {
                    v += head.first_latent[o * head.latent + l] * zl;
                }
                v.max(0.0)
            })
            .collect();
        for layer in &head.rest {
            act = (0..layer.outputs)
                .map(|o| {
                    let v = layer.bias[o]
                        + (0..layer.inputs)
                            .map(|i| layer.weights[o * layer.inputs + i] * act[i])
                            .sum::<f32>();
                    if layer.relu { v.max(0.0) } else { v }
                })
                .collect();
        }
        out[p] = act[0];
        out[px + p] = act[1];
    }
    out
}

#[test]
fn split_first_layer_equals_the_whole_head() {
    for fused in [false, fma_available()] {
        let head = random_head(fused);
        let mut rng = crate::rng::NormalRng::new(11);
        let features: Vec<f32> = (0..5 * 81).map(|_| rng.normal() as f32).collect();
        let z: Vec<f32> = (0..3).map(|_| rng.normal() as f32).collect();
        let want = reference(&head, &features, &z);
        let projected = head.project(&features);
        let mut got = vec![f32::NAN; 2 * 81];
        let mut scratch = HeadScratch::default();
        head.predict_row(&projected, &z, &mut got, &mut scratch);
        let worst = got
            .iter()
            .zip(&want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(worst <= 1e-5, "fused {fused}: {worst}");
        // The buffers are reused: a second call gives the same answer.
        let mut again = vec![0.0; 2 * 81];
        head.predict_row(&projected, &z, &mut again, &mut scratch);
        assert_eq!(got, again);
    }
}

fn node(op: &str, inputs: &[&str], output: &str, ints: &[(&str, &[i64])]) -> OnnxNode {
    OnnxNode {
        op_type: op.into(),
        domain: String::new(),
        inputs: inputs.iter().map(|s| s.to_string()).collect(),
        outputs: vec![output.into()],
        int_attributes: ints
            .iter()
            .map(|(n, v)| (n.to_string(), v.to_vec()))
            .collect(),
    }
}

fn tensor(name: &str, dims: &[i64]) -> super::super::onnx_proto::OnnxTensor {
    let n: i64 = dims.iter().product();
    super::super::onnx_proto::OnnxTensor {
        name: name.into(),
        dims: dims.to_vec(),
        data_type: 1,
        floats: Some((0..n).map(|i| i as f32).collect()),
    }
}

/// fcomb with C 4, L 2, hidden 3: Concat -> Conv -> Relu -> Conv.
fn fcomb_graph() -> OnnxGraph {
    OnnxGraph {
        nodes: vec![
            node("Unsqueeze", &["z", "axes"], "z4", &[]),
            node("Tile", &["z4", "reps"], "zt", &[]),
            node("Concat", &["features", "zt"], "cat", &[("axis", &[1])]),
            node(
                "Conv",
                &["cat", "w1", "b1"],
                "h",
                &[("kernel_shape", &[1, 1])],
            ),
            node("Relu", &["h"], "hr", &[]),
            node(
                "Conv",
                &["hr", "w2", "b2"],
                "flow",
                &[("pads", &[0, 0, 0, 0])],
            ),
        ],
        initializers: vec![
            tensor("w1", &[3, 6, 1, 1]),
            tensor("b1", &[3]),
            tensor("w2", &[2, 3, 1, 1]),
            tensor("b2", &[2]),
        ],
        inputs: vec!["features".into(), "z".into()],
        outputs: vec!["flow".into()],
    }
}

#[test]
fn recognises_fcomb_and_refuses_other_shapes() {
    let head = NativeHead::from_onnx(&fcomb_graph(), 4, 2, 8).unwrap();
    assert_eq!(
        (head.first_width, head.rest.len(), head.projected_len()),
        (3, 1, 3 * 64)
    );
    assert!(head.first_relu && !head.rest[0].relu);
    // The split keeps each row's first C weights for the features, the rest for z.
    assert_eq!(
        head.first_features[..8],
        [0.0, 1.0, 2.0, 3.0, 6.0, 7.0, 8.0, 9.0]
    );
    assert_eq!(head.first_latent[..4], [4.0, 5.0, 10.0, 11.0]);
    let refuse = |g: OnnxGraph, c: usize, why: &str| {
        let e = NativeHead::from_onnx(&g, c, 2, 8).unwrap_err();
        assert!(e.contains(why), "{e}");
    };
    refuse(fcomb_graph(), 5, "C + L");
    let mut g = fcomb_graph();
    g.nodes[2].inputs.swap(0, 1);
    refuse(g, 4, "(features, z)");
    let mut g = fcomb_graph();
    g.nodes[3].int_attributes = vec![("kernel_shape".into(), vec![3, 3])];
    refuse(g, 4, "not a plain 1x1");
    let mut g = fcomb_graph();
    g.initializers.remove(2);
    refuse(g, 4, "not an initializer");
    let mut g = fcomb_graph();
    g.nodes[4].op_type = "Sigmoid".into();
    refuse(g, 4, "unexpected Sigmoid");
    let mut g = fcomb_graph();
    g.initializers[2] = tensor("w2", &[3, 3, 1, 1]);
    refuse(g.clone(), 4, "Conv bias b2 has 2 values");
    g.initializers[3] = tensor("b2", &[3]);
    refuse(g, 4, "not 2");
    let mut g = fcomb_graph();
    g.nodes[2].int_attributes = vec![("axis".into(), vec![2])];
    refuse(g, 4, "channel axis");
}

/// The scored row sums the squared error over the valid pixels of both channels and
/// stops (None) exactly when that sum cannot end below the bound.
#[test]
fn scored_rows_sum_the_error_and_stop_at_the_bound() {
    let head = random_head(fma_available());
    let mut rng = crate::rng::NormalRng::new(5);
    let features: Vec<f32> = (0..5 * 81).map(|_| rng.normal().abs() as f32).collect();
    let z: Vec<f32> = (0..3).map(|_| rng.normal() as f32).collect();
    let target: Vec<f32> = (0..2 * 81).map(|_| rng.normal() as f32).collect();
    let projected = head.project(&features);
    let mut scratch = HeadScratch::default();
    let mut pred = vec![0.0; 2 * 81];
    head.predict_row(&projected, &z, &mut pred, &mut scratch);
    let mask: Vec<bool> = (0..81).map(|i| i % 3 != 0).collect();
    for m in [None, Some(mask.as_slice())] {
        let want: f64 = (0..81)
            .filter(|&i| m.is_none_or(|m| m[i]))
            .map(|i| {
                let du = f64::from(pred[i]) - f64::from(target[i]);
                let dv = f64::from(pred[81 + i]) - f64::from(target[81 + i]);
                du * du + dv * dv
            })
            .sum();
        let score = |bound| RowScore {
            target: &target,
            mask: m,
            bound,
        };
        let mut out = vec![0.0; 2 * 81];
        let sse = head
            .predict_row_sse(&projected, &z, &mut out, &mut scratch, score(f64::INFINITY))
            .unwrap();
        assert!((sse - want).abs() <= 1e-9 * want, "{sse} vs {want}");
        assert_eq!(out, pred);
        // A bound at or below the sum stops the row; one above it does not.
        let stopped = head.predict_row_sse(&projected, &z, &mut out, &mut scratch, score(sse));
        assert_eq!(stopped, None);
        let kept =
            head.predict_row_sse(&projected, &z, &mut out, &mut scratch, score(sse * 1.0001));
        assert_eq!(kept, Some(sse));
    }
}
