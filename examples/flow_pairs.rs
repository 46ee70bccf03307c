//! Writes the synthetic flow accuracy pairs as PNG plus ground truth as `.flo` (for a
//! comparison with other tools): `cargo run --release --example flow_pairs -- OUT_DIR [W H]`.

use vamos::vision::flowio::write_flo;
use vamos::vision::synthetic::{accuracy_cases, pair};

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().collect();
    let out = std::path::PathBuf::from(args.get(1).cloned().unwrap_or_else(|| "/tmp/pairs".into()));
    let w: usize = args.get(2).map(|s| s.parse()).transpose()?.unwrap_or(320);
    let h: usize = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(240);
    std::fs::create_dir_all(&out)?;
    for (name, m) in accuracy_cases(w, h) {
        let (a, b, gt) = pair(w, h, &m, 7);
        a.save_png(&out.join(format!("{name}_a.png")))?;
        b.save_png(&out.join(format!("{name}_b.png")))?;
        write_flo(&gt, &out.join(format!("{name}_gt.flo")))?;
    }
    Ok(())
}
