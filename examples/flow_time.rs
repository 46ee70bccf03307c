//! Quick timing and accuracy of TV-L1 on the synthetic pairs (not part of the API).
//!
//! `cargo run --release --example flow_time -- [preset|key=value...]`

use std::time::Instant;

/// CPU time of the process, ms, all threads (with `RAYON_NUM_THREADS=1` the bands run on
/// the one rayon worker, not on this thread). Unlike wall time it does not count the
/// time spent waiting for a core on a loaded machine.
fn process_cpu_ms() -> f64 {
    let mut ts = libc::timespec {
        tv_sec: 0,
        tv_nsec: 0,
    };
    // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_PROCESS_CPUTIME_ID, &mut ts) };
    if rc != 0 {
        return f64::NAN;
    }
    ts.tv_sec as f64 * 1e3 + ts.tv_nsec as f64 * 1e-6
}

use vamos::vision::flow::{FlowEstimator, FlowParams, Interpolation};
use vamos::vision::synthetic::{
    accuracy_cases, moving_square_valid, pair, with_160x120_displacements,
};

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let mut p = FlowParams::default();
    let mut size = (320usize, 240usize);
    let mut reps = 3;
    // `motion=pixels`: the motions of the 160x120 cases at every size (as
    // `benches/compare_flow.py`'s default scaling); `motion=scaled` (default): motions
    // grow with the image.
    let mut fixed_motion = false;
    for arg in std::env::args().skip(1) {
        if let Some((k, v)) = arg.split_once('=') {
            match k {
                "tau" => p.tau = v.parse()?,
                "lambda" => p.lambda = v.parse()?,
                "theta" => p.theta = v.parse()?,
                "n_scales" => p.n_scales = v.parse()?,
                "scale_step" => p.scale_step = v.parse()?,
                "warps" => p.warps = v.parse()?,
                "epsilon" => p.epsilon = v.parse()?,
                "inner" => p.inner_iterations = v.parse()?,
                "outer" => p.outer_iterations = v.parse()?,
                "median" => p.median_filter = v.parse()?,
                "finest" => p.finest_scale = v.parse()?,
                "fwarps" => p.finest_warps = v.parse()?,
                "warm" => p.warm_start_dual = v.parse()?,
                "finner" => p.finest_inner_iterations = v.parse()?,
                "cmedian" => p.coarse_median_filter = Some(v.parse()?),
                "cinterp" => {
                    p.coarse_interpolation = Some(if v == "bilinear" {
                        Interpolation::Bilinear
                    } else {
                        Interpolation::Bicubic
                    })
                }
                "interp" => {
                    p.interpolation = if v == "bilinear" {
                        Interpolation::Bilinear
                    } else {
                        Interpolation::Bicubic
                    }
                }
                "w" => size.0 = v.parse()?,
                "h" => size.1 = v.parse()?,
                "reps" => reps = v.parse()?,
                "motion" => fixed_motion = v == "pixels",
                _ => anyhow::bail!("unknown key {k}"),
            }
        } else {
            p = FlowParams::preset(&arg)?;
        }
    }
    let (w, h) = size;
    let mut total_ms = 0.0;
    let mut total_cpu = 0.0;
    let mut aees = Vec::new();
    let cases = accuracy_cases(w, h).into_iter().map(|(name, m)| {
        (
            name,
            if fixed_motion {
                with_160x120_displacements(m, w, h)
            } else {
                m
            },
        )
    });
    for (name, m) in cases {
        let (a, b, gt) = pair(w, h, &m, 7);
        let mut best = f64::MAX;
        let mut best_cpu = f64::MAX;
        let mut flow = None;
        // One estimator per case, reset before every pair: its buffers are reused from
        // run to run, as a stream reuses them from frame to frame (OpenCV's DualTVL1
        // object keeps its buffers across calls too). Both frames' pyramids are built in
        // every run.
        let mut est = FlowEstimator::new(p.clone())?;
        for _ in 0..reps {
            let (t, c) = (Instant::now(), process_cpu_ms());
            est.reset();
            est.push(&a)?;
            let f = est
                .push(&b)?
                .ok_or_else(|| anyhow::anyhow!("no flow for the second frame"))?;
            best = best.min(t.elapsed().as_secs_f64() * 1e3);
            best_cpu = best_cpu.min(process_cpu_ms() - c);
            flow = Some(f);
        }
        let Some(f) = flow else {
            anyhow::bail!("no run")
        };
        let valid = moving_square_valid(w, h, &m, 2.0);
        let aee = f
            .average_endpoint_error(&gt, valid.as_deref())
            .unwrap_or(f64::NAN);
        println!("{name:12} {w}x{h} aee {aee:.4} min {best:.2} ms cpu {best_cpu:.2} ms");
        total_ms += best;
        total_cpu += best_cpu;
        aees.push(aee);
    }
    println!(
        "mean aee {:.4}  mean ms {:.2}  mean cpu ms {:.2}",
        aees.iter().sum::<f64>() / aees.len() as f64,
        total_ms / aees.len() as f64,
        total_cpu / aees.len() as f64
    );
    Ok(())
}
