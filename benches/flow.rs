//! TV-L1 timing: every preset at three sizes, on one thread (a rayon pool of 1) and on
//! all threads, on synthetic smooth-motion pairs. One estimator per benchmark, reset
//! before every pair, so its buffers are reused as in a stream (both frames' pyramids are
//! built in every iteration).

// criterion_group! generates undocumented items.
#![allow(missing_docs)]

use std::time::Duration;

use criterion::{BenchmarkId, Criterion, criterion_group, criterion_main};
use vamos::vision::flow::{FlowEstimator, FlowParams, PRESET_NAMES};
use vamos::vision::synthetic::{Motion, pair};

fn bench_flow(c: &mut Criterion) {
    let mut group = c.benchmark_group("tvl1");
    group.sample_size(10);
    group.warm_up_time(Duration::from_millis(500));
    group.measurement_time(Duration::from_secs(3));
    let all = std::thread::available_parallelism().map_or(1, |n| n.get());
    for (w, h) in [(160usize, 120usize), (320, 240), (640, 480)] {
        let motion = Motion::Smooth {
            amplitude_px: 3.0 * w as f64 / 160.0,
            seed: 2,
        };
        let (a, b, _) = pair(w, h, &motion, 7);
        for preset in PRESET_NAMES {
            let Ok(params) = FlowParams::preset(preset) else {
                continue;
            };
            for threads in [1, all] {
                let Ok(pool) = rayon::ThreadPoolBuilder::new().num_threads(threads).build() else {
                    continue;
                };
                let id = BenchmarkId::new(format!("{preset}/{threads}t"), format!("{w}x{h}"));
                let Ok(mut est) = FlowEstimator::new(params.clone()) else {
                    continue;
                };
                group.bench_with_input(id, &(&a, &b), |bench, (a, b)| {
                    bench.iter(|| {
                        pool.install(|| {
                            est.reset();
                            let _ = est.push(a);
                            est.push(b)
                        })
                    });
                });
            }
        }
    }
    group.finish();
}

criterion_group!(benches, bench_flow);
criterion_main!(benches);
