//! Episode benches: one 640x480 rgb8 `sensor_msgs/msg/Image` from CDR to gray, and whole
//! frames read from a zstd-chunked bag (decompression, decode, joint interpolation).

// criterion_group! generates undocumented items.
#![allow(missing_docs)]
// Bench set-up may unwrap: a failure is a bench failure.
#![allow(clippy::unwrap_used)]

use criterion::{Criterion, criterion_group, criterion_main};
use std::hint::black_box;
use vamos::episode::ros::{Header, ImageMsg};
use vamos::episode::synthetic::{SyntheticBag, write_bag};
use vamos::episode::{EpisodeConfig, McapEpisode};

fn decode(c: &mut Criterion) {
    let spec = SyntheticBag::default();
    let pixels = spec.pixels(0);
    for encoding in ["rgb8", "mono8"] {
        let data: Vec<u8> = if encoding == "rgb8" {
            pixels.clone()
        } else {
            pixels.iter().step_by(3).copied().collect()
        };
        let msg = ImageMsg {
            header: Header::from_stamp_ns(1, "camera"),
            height: 480,
            width: 640,
            encoding: encoding.into(),
            is_bigendian: false,
            step: if encoding == "rgb8" { 640 * 3 } else { 640 },
            data: &data,
        };
        let cdr = msg.encode();
        c.bench_function(&format!("episode/decode_gray_640x480_{encoding}"), |b| {
            b.iter(|| {
                let m = ImageMsg::decode(black_box(&cdr)).unwrap();
                black_box(m.to_gray(1 << 26).unwrap())
            })
        });
    }
}

fn frames(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("bench.mcap");
    let spec = SyntheticBag {
        frames: 30,
        ..SyntheticBag::default()
    };
    write_bag(&path, &spec).unwrap();
    let cfg = EpisodeConfig::default();
    let mut g = c.benchmark_group("episode");
    g.sample_size(10);
    g.bench_function("frames_30x640x480_rgb8_zstd", |b| {
        b.iter(|| {
            let ep = McapEpisode::open(&path, &cfg).unwrap();
            let n = ep.frames().filter(|f| f.is_ok()).count();
            assert_eq!(n, 30);
            n
        })
    });
    g.finish();
}

criterion_group!(benches, decode, frames);
criterion_main!(benches);
