//! Parity of vamos's inference with Python onnxruntime on the tiny network *trained by the
//! project's own script* (`tests/fixtures/model/make_tiny_trained.py`: vamos-train on a
//! synthetic dataset, exported to a bundle, reference outputs from Python onnxruntime
//! 1.31.1 in `tiny_trained_reference.npz`). Both sides run the same ONNX Runtime build on
//! the same graphs; observed max abs differences are quoted per output.

use std::collections::HashMap;
use std::io::Read;
use std::path::Path;
use vamos::model::{FlowModel, LoadOptions};
use vamos::pipeline::dataset::parse_npy_f32;

fn npz(path: &Path) -> HashMap<String, (Vec<usize>, Vec<f32>)> {
    let mut zip = zip::ZipArchive::new(std::fs::File::open(path).unwrap()).unwrap();
    let mut out = HashMap::new();
    for i in 0..zip.len() {
        let mut member = zip.by_index(i).unwrap();
        let name = member.name().unwrap().trim_end_matches(".npy").to_string();
        let mut bytes = Vec::new();
        member.read_to_end(&mut bytes).unwrap();
        out.insert(name.clone(), parse_npy_f32(&bytes, &name).unwrap());
    }
    out
}

fn max_abs_diff(a: &[f32], b: &[f32]) -> f32 {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f32::max)
}

#[test]
fn trained_fixture_matches_python_onnxruntime() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model");
    let model = FlowModel::load(&dir.join("tiny_trained.vamos"), &LoadOptions::default()).unwrap();
    let r = npz(&dir.join("tiny_trained_reference.npz"));
    let (flow_shape, flow) = &r["flow"];
    let batch = flow_shape[0];
    assert_eq!(flow_shape[1..], [2, 64, 64]);
    let enc = model.encode(flow, batch).unwrap();
    let d_features = max_abs_diff(&enc.features, &r["features"].1);
    let d_mu = max_abs_diff(&enc.prior_mu, &r["prior_mu"].1);
    let d_sigma = max_abs_diff(&enc.prior_log_sigma, &r["prior_log_sigma"].1);
    // z = mu + exp(log sigma) * eps, computed here from the Python eps.
    let z: Vec<f32> = enc
        .prior_mu
        .iter()
        .zip(&enc.prior_log_sigma)
        .zip(&r["eps"].1)
        .map(|((m, s), e)| m + s.exp() * e)
        .collect();
    let d_z = max_abs_diff(&z, &r["z"].1);
    let head = model.predict(&r["features"].1, &r["z"].1, batch).unwrap();
    let d_head = max_abs_diff(&head, &r["head_flow"].1);
    eprintln!(
        "max abs diff: features {d_features:e}, mu {d_mu:e}, log sigma {d_sigma:e}, z {d_z:e}, head {d_head:e}"
    );
    // Observed: 0 for every graph output (same library, same graph, one thread) and
    // ~1e-7 for z (exp in Rust vs numpy).
    assert!(
        d_features <= 1e-6 && d_mu <= 1e-6 && d_sigma <= 1e-6,
        "{d_features} {d_mu} {d_sigma}"
    );
    assert!(d_z <= 1e-6, "{d_z}");
    assert!(d_head <= 1e-6, "{d_head}");
    // The fixture is a trained network, not a constant: its predictions vary.
    let spread = head.iter().fold(f32::NEG_INFINITY, |a, &b| a.max(b))
        - head.iter().fold(f32::INFINITY, |a, &b| a.min(b));
    assert!(spread > 1e-3, "{spread}");
    assert_eq!(model.manifest().architecture.latent_dim, 6);
}

/// The native head (`model::head`, fcomb read out of `head.onnx`) on the Python reference
/// inputs gives Python onnxruntime's head output. The two sum in different orders (and
/// the native kernel uses FMA where the CPU has it), so they agree to float rounding:
/// observed max abs diff ~1e-7 on outputs of order 0.1; the bound is 1e-5.
#[test]
fn native_head_matches_python_onnxruntime() {
    use vamos::model::head::HeadScratch;
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/model");
    let model = FlowModel::load(&dir.join("tiny_trained.vamos"), &LoadOptions::default()).unwrap();
    assert_eq!(model.head_backend(), ("native", None));
    let head = model.native_head().unwrap();
    let r = npz(&dir.join("tiny_trained_reference.npz"));
    let d = model.dims();
    let (features, z, want) = (&r["features"].1, &r["z"].1, &r["head_flow"].1);
    let batch = r["flow"].0[0];
    let (fe, fl, l) = (d.features_len(), d.flow_len(), d.latent);
    let mut got = vec![0.0f32; batch * fl];
    let mut scratch = HeadScratch::default();
    for b in 0..batch {
        let projected = head.project(&features[b * fe..(b + 1) * fe]);
        head.predict_row(
            &projected,
            &z[b * l..(b + 1) * l],
            &mut got[b * fl..(b + 1) * fl],
            &mut scratch,
        );
    }
    let diff = max_abs_diff(&got, want);
    eprintln!("native head vs Python onnxruntime: max abs diff {diff:e}");
    assert!(diff <= 1e-5, "{diff}");

    // With the head forced to ONNX Runtime the model says so.
    let onnx = FlowModel::load(
        &dir.join("tiny_trained.vamos"),
        &LoadOptions {
            head: vamos::model::HeadBackend::Onnx,
            ..LoadOptions::default()
        },
    )
    .unwrap();
    assert!(onnx.native_head().is_none());
    assert_eq!(onnx.head_backend().0, "onnxruntime");
}
