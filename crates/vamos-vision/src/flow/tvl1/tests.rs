use super::kernels::{iterate_bands, simd_rows};
use super::*;
use crate::flow::pyramid::Level;
use crate::synthetic::{Motion, pair};

fn setup(w: usize, h: usize) -> (Linearised, Vec<f32>, Vec<f32>) {
    let (a, b, _) = pair(
        w,
        h,
        &Motion::Smooth {
            amplitude_px: 2.0,
            seed: 3,
        },
        11,
    );
    let (l0, l1) = (
        Level::new(a.data().to_vec(), w, h),
        Level::new(b.data().to_vec(), w, h),
    );
    let u1: Vec<f32> = (0..w * h).map(|i| 0.3 + 0.01 * (i % 7) as f32).collect();
    let u2: Vec<f32> = (0..w * h).map(|i| -0.2 + 0.02 * (i % 5) as f32).collect();
    let mut lin = Linearised::default();
    linearise(
        &l0.image,
        &l1.packed,
        &u1,
        &u2,
        w,
        h,
        Interpolation::Bicubic,
        &mut lin,
    );
    (lin, u1, u2)
}

/// The AVX2 + FMA rows against the reference, one iteration at a time from the same
/// state, on widths that exercise every masked row end (1 to 8 leftover pixels).
#[test]
fn simd_iteration_is_close_to_reference() {
    if !simd_rows() {
        println!("no AVX2 + FMA on this CPU: the SIMD rows are not used here");
        return;
    }
    let s = Steps {
        lt: 0.045,
        theta: 0.3,
        taut: 0.25 / 0.3,
    };
    let close = |a: &[f32], b: &[f32], what: &str| {
        for (i, (x, y)) in a.iter().zip(b).enumerate() {
            assert!(
                (x - y).abs() <= 1e-5 * (1.0 + x.abs()),
                "{what}[{i}]: {x} vs {y}"
            );
        }
    };
    for (w, h) in [
        (1, 7),
        (2, 2),
        (9, 1),
        (10, 3),
        (16, 4),
        (17, 5),
        (37, 29),
        (64, 70),
    ] {
        let (lin, u1, u2) = setup(w, h);
        let (mut a1, mut a2, mut pa) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
        let mut scratch = FastScratch::default();
        for it in 0..6 {
            // Both kernels start every iteration from the reference's state.
            let (mut b1, mut b2, mut pb) = (a1.clone(), a2.clone(), pa.clone());
            let ea = iterate_reference(&lin, &mut a1, &mut a2, &mut pa, w, h, s);
            let eb = iterate_bands(
                &lin,
                &mut b1,
                &mut b2,
                &mut pb,
                w,
                h,
                s,
                &mut scratch,
                5,
                true,
            );
            let at = format!("{w}x{h} iteration {it}");
            assert!(
                (ea - eb).abs() <= 1e-4 * (1.0 + ea),
                "{at}: error {ea} vs {eb}"
            );
            close(&a1, &b1, &format!("{at} u1"));
            close(&a2, &b2, &format!("{at} u2"));
            for ((x, y), name) in pa
                .parts()
                .iter()
                .zip(pb.parts())
                .zip(["p11", "p12", "p21", "p22"])
            {
                close(x, y, &format!("{at} {name}"));
            }
        }
    }
}

/// Two iterations fused in one pass equal two separate passes, bit for bit, with
/// either set of rows.
#[test]
fn paired_iterations_equal_two_passes() {
    let s = Steps {
        lt: 0.045,
        theta: 0.3,
        taut: 0.25 / 0.3,
    };
    let flags: &[bool] = if simd_rows() {
        &[false, true]
    } else {
        &[false]
    };
    for &simd in flags {
        for (w, h) in [(1, 1), (1, 7), (9, 1), (2, 2), (17, 5), (37, 29), (64, 70)] {
            let (lin, u1, u2) = setup(w, h);
            let (mut a1, mut a2, mut pa) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
            let (mut b1, mut b2, mut pb) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
            let mut scratch = FastScratch::default();
            for it in 0..3 {
                let mut ea = 0.0;
                for _ in 0..2 {
                    ea = iterate_bands(
                        &lin,
                        &mut a1,
                        &mut a2,
                        &mut pa,
                        w,
                        h,
                        s,
                        &mut scratch,
                        h,
                        simd,
                    );
                }
                let eb = iterate_pair(&lin, &mut b1, &mut b2, &mut pb, w, h, s, &mut scratch, simd);
                let at = format!("{w}x{h} simd {simd} pair {it}");
                assert_eq!(ea, eb, "{at}");
                assert_eq!((&a1, &a2), (&b1, &b2), "{at}");
                assert_eq!(pa, pb, "{at}");
            }
        }
    }
}

#[test]
fn fast_iteration_equals_reference() {
    let s = Steps {
        lt: 0.045,
        theta: 0.3,
        taut: 0.25 / 0.3,
    };
    for (w, h) in [(37usize, 29usize), (64, 70), (2, 2), (9, 1), (1, 7)] {
        let (lin, u1, u2) = setup(w, h);
        for rows in [1, 2, 5, 16, h] {
            let (mut b1, mut b2, mut pb) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
            let mut scratch = FastScratch::default();
            let (mut a1, mut a2, mut pa) = (u1.clone(), u2.clone(), Dual::zeros(w * h));
            for it in 0..6 {
                let ea = iterate_reference(&lin, &mut a1, &mut a2, &mut pa, w, h, s);
                let eb = iterate_bands(
                    &lin,
                    &mut b1,
                    &mut b2,
                    &mut pb,
                    w,
                    h,
                    s,
                    &mut scratch,
                    rows,
                    false,
                );
                let at = format!("{w}x{h} bands of {rows} rows, iteration {it}");
                assert_eq!(ea, eb, "{at}");
                assert_eq!((&a1, &a2), (&b1, &b2), "{at}");
                assert_eq!(pa, pb, "{at}");
            }
        }
    }
}
