//! The random generator behind the prior samples: xoshiro256++ (Blackman and Vigna)
//! seeded with SplitMix64, standard normals by the Box-Muller transform.
//!
//! It is written out here (rather than taken from a crate) so that the stream is fixed by
//! this file alone: `tests/fixtures/model/make_test_bundles.py` re-implements it in Python
//! to compute reference scores. Uniforms are `((x >> 11) + 1) * 2^-53`, in (0, 1]; each
//! Box-Muller pair `(u1, u2)` gives `r cos(2 pi u2)` first and `r sin(2 pi u2)` next, with
//! `r = sqrt(-2 ln u1)`, computed in `f64`.

/// One SplitMix64 step: advances `state` and returns the next output.
pub fn splitmix64(state: &mut u64) -> u64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A deterministic source of standard normal numbers.
#[derive(Clone, Debug)]
pub struct NormalRng {
    s: [u64; 4],
    spare: Option<f64>,
}

impl NormalRng {
    /// A generator whose whole stream is fixed by `seed`.
    pub fn new(seed: u64) -> Self {
        let mut st = seed;
        let s = [
            splitmix64(&mut st),
            splitmix64(&mut st),
            splitmix64(&mut st),
            splitmix64(&mut st),
        ];
        Self { s, spare: None }
    }

    /// The next 64 random bits (xoshiro256++).
    pub fn next_u64(&mut self) -> u64 {
        let s = &mut self.s;
        let result = s[0].wrapping_add(s[3]).rotate_left(23).wrapping_add(s[0]);
        let t = s[1] << 17;
        s[2] ^= s[0];
        s[3] ^= s[1];
        s[1] ^= s[2];
        s[0] ^= s[3];
        s[2] ^= t;
        s[3] = s[3].rotate_left(45);
        result
    }

    /// A uniform number in (0, 1].
    pub fn uniform_open0(&mut self) -> f64 {
        ((self.next_u64() >> 11) + 1) as f64 * (1.0 / (1u64 << 53) as f64)
    }

    /// A standard normal number.
    pub fn normal(&mut self) -> f64 {
        if let Some(v) = self.spare.take() {
            return v;
        }
        let u1 = self.uniform_open0();
        let u2 = self.uniform_open0();
        let r = (-2.0 * u1.ln()).sqrt();
        let theta = 2.0 * std::f64::consts::PI * u2;
        self.spare = Some(r * theta.sin());
        r * theta.cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xoshiro_matches_the_reference_stream() {
        // Reference values: the C reference implementation of xoshiro256++ started from
        // state [1, 2, 3, 4] (the first outputs are 41943041, 58720359, 3588806011781223).
        let mut r = NormalRng {
            s: [1, 2, 3, 4],
            spare: None,
        };
        assert_eq!(r.next_u64(), 41_943_041);
        assert_eq!(r.next_u64(), 58_720_359);
        assert_eq!(r.next_u64(), 3_588_806_011_781_223);
    }

    #[test]
    fn splitmix_matches_the_reference() {
        // SplitMix64 from seed 0: first output 0xe220a8397b1dcdaf.
        let mut s = 0u64;
        assert_eq!(splitmix64(&mut s), 0xe220_a839_7b1d_cdaf);
    }

    #[test]
    fn normals_match_the_python_fixture_generator() {
        // tests/fixtures/model/make_test_bundles.py's NormalRng(42), first three normals.
        let mut r = NormalRng::new(42);
        let expected = [
            -0.268_607_369_462_095_24,
            0.581_971_051_862_882_7,
            -0.054_462_170_108_150_8,
        ];
        for e in expected {
            let v = r.normal();
            assert!((v - e).abs() < 1e-12, "{v} vs {e}");
        }
    }

    #[test]
    fn normals_have_unit_moments() {
        let mut r = NormalRng::new(1);
        let n = 200_000;
        let xs: Vec<f64> = (0..n).map(|_| r.normal()).collect();
        let mean = xs.iter().sum::<f64>() / n as f64;
        let var = xs.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / n as f64;
        // Standard errors: 1/sqrt(n) = 0.0022 for the mean, sqrt(2/n) = 0.0032 for the variance.
        assert!(mean.abs() < 0.01, "{mean}");
        assert!((var - 1.0).abs() < 0.015, "{var}");
        assert!(xs.iter().all(|x| x.is_finite()));
    }
}
