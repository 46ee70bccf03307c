//! Writes a large synthetic bag (640x480 rgb8 at 30 Hz, joints at 100 Hz) and reads every
//! frame back, printing sizes and times; run under `/usr/bin/time -v` to see that peak
//! memory does not grow with the bag.
//!
//! `cargo run --release --example episode_bigbag -- OUT.mcap [FRAMES]`

use std::path::PathBuf;
use std::time::Instant;
use vamos::episode::synthetic::{SyntheticBag, write_bag};
use vamos::episode::{EpisodeConfig, McapEpisode};

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = PathBuf::from(args.next().unwrap_or_else(|| "big.mcap".into()));
    let frames: usize = args.next().map(|s| s.parse()).transpose()?.unwrap_or(600);
    if !path.exists() {
        let t = Instant::now();
        write_bag(
            &path,
            &SyntheticBag {
                frames,
                ..SyntheticBag::default()
            },
        )?;
        println!(
            "wrote {} frames in {:.2} s",
            frames,
            t.elapsed().as_secs_f64()
        );
    }
    let size = std::fs::metadata(&path)?.len();
    let t = Instant::now();
    let ep = McapEpisode::open(&path, &EpisodeConfig::default())?;
    let open_ms = t.elapsed().as_secs_f64() * 1e3;
    let t = Instant::now();
    let mut n = 0usize;
    for f in ep.frames() {
        f?;
        n += 1;
    }
    let s = t.elapsed().as_secs_f64();
    println!(
        "{}: {:.1} MB, open {:.2} ms, {n} frames in {:.2} s ({:.2} ms/frame)",
        path.display(),
        size as f64 / 1e6,
        open_ms,
        s,
        s * 1e3 / n.max(1) as f64
    );
    Ok(())
}
