//! Writes the synthetic flow test pairs as PNG plus ground truth as raw `.flo` (for a
//! comparison with OpenCV): `cargo run --release --example flow_pairs -- OUT_DIR [W H]`.

use std::io::Write;

use vamos::vision::synthetic::{Motion, pair};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let out = std::path::PathBuf::from(args.get(1).cloned().unwrap_or_else(|| "/tmp/pairs".into()));
    let w: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(320);
    let h: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(240);
    std::fs::create_dir_all(&out)?;
    let s = w as f64 / 160.0;
    let cases = [
        (
            "translation",
            Motion::Translation {
                dx: 2.5 * s,
                dy: -1.25 * s,
            },
        ),
        (
            "rotation",
            Motion::Similarity {
                tx: 0.0,
                ty: 0.0,
                scale: 1.0,
                rotation_deg: 3.0,
            },
        ),
        (
            "smooth",
            Motion::Smooth {
                amplitude_px: 3.0 * s,
                seed: 2,
            },
        ),
        (
            "square",
            Motion::MovingSquare {
                x: 0.3 * w as f64,
                y: 0.3 * h as f64,
                size_px: 0.35 * h as f64,
                dx: 3.0 * s,
                dy: 2.0 * s,
            },
        ),
    ];
    for (name, m) in cases {
        let (a, b, gt) = pair(w, h, &m, 7);
        a.save_png(&out.join(format!("{name}_a.png")))?;
        b.save_png(&out.join(format!("{name}_b.png")))?;
        let mut f = std::fs::File::create(out.join(format!("{name}_gt.flo")))?;
        f.write_all(&202021.25f32.to_le_bytes())?;
        f.write_all(&(w as i32).to_le_bytes())?;
        f.write_all(&(h as i32).to_le_bytes())?;
        for i in 0..w * h {
            f.write_all(&gt.u[i].to_le_bytes())?;
            f.write_all(&gt.v[i].to_le_bytes())?;
        }
    }
    Ok(())
}
