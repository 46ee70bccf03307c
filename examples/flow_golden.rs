//! Checks the default preset against the OpenCV `DualTVL1` golden fixtures (not part of
//! the API): per case, AEE vs ground truth of vamos and of OpenCV, the bound
//! `opencv * 1.10 + 0.01`, and vamos's single-thread time (minimum of `reps` runs).
//!
//! `cargo run --release --example flow_golden -- [preset] [reps=N]`

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::Context;
use vamos::vision::GrayImage;
use vamos::vision::flow::{FlowParams, tvl1};
use vamos::vision::image::FlowField;

/// Reads a Middlebury `.flo` file (little endian: magic 202021.25, width, height, then
/// interleaved `(u, v)` f32, row-major).
fn read_flo(path: &Path) -> anyhow::Result<FlowField> {
    let bytes = std::fs::read(path).with_context(|| path.display().to_string())?;
    let word = |i: usize| -> anyhow::Result<[u8; 4]> {
        bytes
            .get(4 * i..4 * i + 4)
            .and_then(|b| b.try_into().ok())
            .context("truncated .flo")
    };
    anyhow::ensure!(f32::from_le_bytes(word(0)?) == 202021.25, "bad .flo magic");
    let w = i32::from_le_bytes(word(1)?) as usize;
    let h = i32::from_le_bytes(word(2)?) as usize;
    anyhow::ensure!(bytes.len() == 12 + 8 * w * h, "bad .flo size");
    let mut f = FlowField::zeros(w, h);
    for i in 0..w * h {
        f.u[i] = f32::from_le_bytes(word(3 + 2 * i)?);
        f.v[i] = f32::from_le_bytes(word(4 + 2 * i)?);
    }
    Ok(f)
}

fn main() -> anyhow::Result<()> {
    let mut params = FlowParams::default();
    let mut reps = 3;
    for arg in std::env::args().skip(1) {
        match arg.split_once('=') {
            Some(("reps", v)) => reps = v.parse()?,
            _ => params = FlowParams::preset(&arg)?,
        }
    }
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/flow");
    let manifest: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("manifest.json"))?)?;
    let cases = manifest["cases"]
        .as_array()
        .context("manifest has no cases")?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let mut all_ok = true;
    println!("case            vamos_aee  opencv_aee  bound   vamos_ms  opencv_ms  ok");
    for case in cases {
        let name = case["name"].as_str().context("case without name")?;
        let dir = root.join(name);
        let a = GrayImage::load(&dir.join("a.png"))?;
        let b = GrayImage::load(&dir.join("b.png"))?;
        let gt = read_flo(&dir.join("gt.flo"))?;
        let cv = read_flo(&dir.join("opencv.flo"))?;
        let valid: Option<Vec<bool>> = if dir.join("valid.png").exists() {
            let m = GrayImage::load(&dir.join("valid.png"))?;
            Some(m.data().iter().map(|&v| v > 127.0).collect())
        } else {
            None
        };
        let mut best = f64::MAX;
        let mut flow = None;
        for _ in 0..reps {
            let t = Instant::now();
            let f = pool.install(|| tvl1(&a, &b, &params))?;
            best = best.min(t.elapsed().as_secs_f64() * 1e3);
            flow = Some(f);
        }
        let flow = flow.context("no run")?;
        let ours = flow
            .average_endpoint_error(&gt, valid.as_deref())
            .context("size mismatch")?;
        let theirs = cv
            .average_endpoint_error(&gt, valid.as_deref())
            .context("size mismatch")?;
        let bound = theirs * 1.10 + 0.01;
        let ok = ours <= bound;
        all_ok &= ok;
        println!(
            "{name:15} {ours:9.4}  {theirs:10.4}  {bound:6.4}  {best:8.1}  {:9.1}  {ok}",
            case["opencv_ms"].as_f64().unwrap_or(f64::NAN)
        );
    }
    anyhow::ensure!(all_ok, "a case is above its bound");
    Ok(())
}
