//! Golden comparison of vamos's TV-L1 with OpenCV's `DualTVL1OpticalFlow`.
//!
//! Fixtures: `tests/fixtures/flow/`, written by `tests/fixtures/generate_flow_golden.py`
//! (OpenCV 5.0, `cv2.optflow.createOptFlow_DualTVL1()` with all defaults, which are also
//! `FlowParams::default()`), on synthetic 160x120 pairs with exact ground truth.
//!
//! Tolerance, and why it is not "bit-exact": both sides run the same algorithm with the
//! same parameters, but they differ in details that the algorithm leaves open and that
//! change low-order bits which then propagate through thousands of iterations: the
//! pyramid's downsampling filter, the bicubic kernel and border rule of the warp, the
//! median filter at the image border, the iteration at which the stopping rule is tested,
//! and float summation order. So the test asserts what matters:
//! 1. accuracy: vamos's endpoint error against the ground truth is at most OpenCV's
//!    (plus 10% and 0.01 px of slack for the cases where both are near zero);
//! 2. agreement: the mean endpoint difference between the two fields is small against
//!    the motion itself (bounds below, set just above what was measured).

use serde_json::Value;
use std::path::{Path, PathBuf};
use vamos::vision::flow::{FlowParams, tvl1};
use vamos::vision::flowio::read_flo;
use vamos::vision::{FlowField, GrayImage};

fn fixtures() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/flow")
}

fn valid_mask(dir: &Path) -> Option<Vec<bool>> {
    let p = dir.join("valid.png");
    p.is_file().then(|| {
        GrayImage::load(&p)
            .unwrap()
            .data()
            .iter()
            .map(|&v| v > 127.0)
            .collect()
    })
}

/// Mean endpoint difference between two fields over `valid`, excluding a border of `b`
/// pixels where both implementations extrapolate differently.
fn mean_diff(a: &FlowField, o: &FlowField, valid: Option<&[bool]>, b: usize) -> f64 {
    let (w, h) = a.size();
    let keep: Vec<bool> = (0..w * h)
        .map(|i| {
            let (x, y) = (i % w, i / w);
            x >= b && y >= b && x + b < w && y + b < h && valid.is_none_or(|m| m[i])
        })
        .collect();
    a.average_endpoint_error(o, Some(&keep)).unwrap()
}

#[test]
fn tvl1_matches_opencv_dualtvl1_on_the_golden_pairs() {
    let manifest: Value =
        serde_json::from_str(&std::fs::read_to_string(fixtures().join("manifest.json")).unwrap())
            .unwrap();
    let cases = manifest["cases"].as_array().unwrap();
    assert!(cases.len() >= 4);
    let params = FlowParams::default();
    let mut report = Vec::new();
    for case in cases {
        let name = case["name"].as_str().unwrap();
        let dir = fixtures().join(name);
        let a = GrayImage::load(&dir.join("a.png")).unwrap();
        let b = GrayImage::load(&dir.join("b.png")).unwrap();
        let gt = read_flo(&dir.join("gt.flo")).unwrap();
        let cv = read_flo(&dir.join("opencv.flo")).unwrap();
        let valid = valid_mask(&dir);
        let ours = tvl1(&a, &b, &params).unwrap();
        let aee_ours = ours.average_endpoint_error(&gt, valid.as_deref()).unwrap();
        let aee_cv = cv.average_endpoint_error(&gt, valid.as_deref()).unwrap();
        let diff = mean_diff(&ours, &cv, valid.as_deref(), 4);
        report.push(format!(
            "{name}: AEE vamos {aee_ours:.4}, OpenCV {aee_cv:.4}, mean |vamos - OpenCV| {diff:.4}"
        ));
        assert!(
            aee_ours <= aee_cv * 1.10 + 0.01,
            "{name}: vamos AEE {aee_ours:.4} worse than OpenCV's {aee_cv:.4}"
        );
        assert!(
            diff < 0.15,
            "{name}: vamos and OpenCV differ by {diff:.4} px on average"
        );
    }
    println!("{}", report.join("\n"));
}
