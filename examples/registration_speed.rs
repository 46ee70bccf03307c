//! Registration speed and accuracy per parameter set, for `benches/registration_speed.md`.
//!
//! Usage: `registration_speed [time|acc] [--refine N] [--angles N] [--radii N]`.
//! `time` prints the minimum over many runs (ms, one thread) of a warm pair
//! (`Registrar::register`), a fresh pair (free `register`, plans built per call) and the
//! streaming `push`, at 128, 256 and 512 pixels. `acc` prints the worst errors over random
//! similarities in the documented range (256x256 and 128x128, translations up to 1/8 of
//! the side) and over large rotations at 256x256.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::time::Instant;

use vamos::vision::registration::{Registrar, RegistrationParams, Similarity, register};
use vamos::vision::synthetic::{self, Motion, SplitMix64};

/// (translation px, rotation deg, scale error in percent).
fn errors(t: &Similarity, tx: f64, ty: f64, scale: f64, rot: f64) -> (f64, f64, f64) {
    let (dt, dr, ds) = t.difference(&Similarity {
        tx_px: tx,
        ty_px: ty,
        scale,
        rotation_deg: rot,
    });
    (dt, dr, ds * 100.0)
}

fn min_ms(runs: usize, mut f: impl FnMut()) -> f64 {
    let mut best = f64::INFINITY;
    for _ in 0..runs {
        let t0 = Instant::now();
        f();
        best = best.min(t0.elapsed().as_secs_f64() * 1e3);
    }
    best
}

fn time(params: &RegistrationParams) {
    for n in [128usize, 256, 512] {
        let motion = Motion::Similarity {
            tx: 5.0,
            ty: -3.0,
            scale: 1.05,
            rotation_deg: 6.0,
        };
        let (a, b, _) = synthetic::pair(n, n, &motion, 1);
        let runs = if n == 512 { 40 } else { 150 };
        let mut r = Registrar::new(params.clone()).unwrap();
        let warm = min_ms(runs, || {
            r.register(&a, &b, None).unwrap();
        });
        let fresh = min_ms(runs / 4, || {
            register(&a, &b, None, params).unwrap();
        });
        let mut s = Registrar::new(params.clone()).unwrap();
        let frames = [a.clone(), b.clone()];
        s.push(&frames[1], None).unwrap();
        let mut k = 0usize;
        let push = min_ms(runs, || {
            k += 1;
            s.push(&frames[k % 2], None).unwrap();
        });
        println!("{n}x{n}: pair warm {warm:.3} ms, pair fresh {fresh:.3} ms, push {push:.3} ms");
    }
}

fn sweep(params: &RegistrationParams, n: usize, cases: u64, seed: u64) -> (f64, f64, f64) {
    let mut r = Registrar::new(params.clone()).unwrap();
    let mut rng = SplitMix64::new(seed);
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for i in 0..cases {
        let tx = rng.uniform(-1.0, 1.0) * n as f64 / 8.0;
        let ty = rng.uniform(-1.0, 1.0) * n as f64 / 8.0;
        let s = rng.uniform(0.8f64.ln(), 1.25f64.ln()).exp();
        let rot = rng.uniform(-45.0, 45.0);
        let motion = Motion::Similarity {
            tx,
            ty,
            scale: s,
            rotation_deg: rot,
        };
        let (a, b, _) = synthetic::pair(n, n, &motion, i + 1000 * seed);
        let reg = r.register(&a, &b, None).unwrap();
        let e = errors(&reg.transform, tx, ty, s, rot);
        worst = (worst.0.max(e.0), worst.1.max(e.1), worst.2.max(e.2));
    }
    worst
}

fn acc(params: &RegistrationParams) {
    let w = sweep(params, 256, 80, 7);
    println!(
        "256x256, 80 random similarities: worst {:.3} px, {:.3} deg, {:.3} %",
        w.0, w.1, w.2
    );
    let w = sweep(params, 128, 40, 99);
    println!(
        "128x128, 40 random similarities: worst {:.3} px, {:.3} deg, {:.3} %",
        w.0, w.1, w.2
    );
    let mut r = Registrar::new(params.clone()).unwrap();
    let mut worst = (0.0f64, 0.0f64, 0.0f64);
    for (k, &(tx, ty, s, rot)) in [
        (4.0, -6.0, 1.05, 120.0),
        (-3.0, 2.0, 0.95, 179.0),
        (1.5, 7.0, 1.0, -150.0),
        (0.0, 0.0, 1.1, 95.0),
        (10.0, -8.0, 1.0, -91.0),
    ]
    .iter()
    .enumerate()
    {
        let motion = Motion::Similarity {
            tx,
            ty,
            scale: s,
            rotation_deg: rot,
        };
        let (a, b, _) = synthetic::pair(256, 256, &motion, 500 + k as u64);
        let reg = r.register(&a, &b, None).unwrap();
        let e = errors(&reg.transform, tx, ty, s, rot);
        worst = (worst.0.max(e.0), worst.1.max(e.1), worst.2.max(e.2));
    }
    println!(
        "256x256, 5 large rotations: worst {:.3} px, {:.3} deg, {:.3} %",
        worst.0, worst.1, worst.2
    );
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let mut params = RegistrationParams::default();
    let mut mode = "time".to_string();
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut val = || it.next().expect("missing value").parse::<usize>().unwrap();
        match a.as_str() {
            "--refine" => params.refine_iterations = val() as u32,
            "--angles" => params.log_polar_angles = val(),
            "--radii" => params.log_polar_radii = val(),
            m => mode = m.to_string(),
        }
    }
    println!("{params:?}");
    match mode.as_str() {
        "acc" => acc(&params),
        _ => time(&params),
    }
}
