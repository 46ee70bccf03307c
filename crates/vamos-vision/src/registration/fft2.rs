//! Two-dimensional real-to-complex FFT with cached plans and scratch buffers.
//!
//! The spectrum is kept **column-major** ("transposed"): the value at horizontal frequency
//! `kx` (`0..=w/2`) and vertical frequency `ky` (`0..h`, unshifted) lives at
//! `kx * h + ky`. Rows are transformed with `realfft`, then the `w/2 + 1` columns are
//! transformed in one batched `rustfft` call on contiguous memory, so the forward
//! transform needs one transpose and the inverse one more. The transposes move blocks of
//! eight rows, so each column write or read covers a whole cache line.

use std::sync::Arc;

use realfft::num_complex::Complex;
use realfft::{ComplexToReal, RealFftPlanner, RealToComplex};
use rustfft::{Fft, FftPlanner};

use super::RegistrationError;

/// Plans and scratch space for `w x h` real images.
pub(crate) struct Fft2 {
    w: usize,
    h: usize,
    wc: usize,
    r2c: Arc<dyn RealToComplex<f32>>,
    c2r: Arc<dyn ComplexToReal<f32>>,
    col_fwd: Arc<dyn Fft<f32>>,
    col_inv: Arc<dyn Fft<f32>>,
    row_real: Vec<f32>,
    /// `BLOCK` row spectra, so the transpose writes and reads whole cache lines.
    block: Vec<Complex<f32>>,
    row_scratch: Vec<Complex<f32>>,
    col_scratch: Vec<Complex<f32>>,
}

/// Rows transformed before each transpose step: eight complex values are one 64-byte
/// cache line of a column.
const BLOCK: usize = 8;

fn fft_error(e: impl std::fmt::Display) -> RegistrationError {
    RegistrationError::Internal {
        reason: format!("FFT: {e}"),
    }
}

impl Fft2 {
    /// Plans the transforms of a `w x h` image (`w, h >= 1`).
    pub(crate) fn new(w: usize, h: usize) -> Self {
        let mut rp = RealFftPlanner::<f32>::new();
        let r2c = rp.plan_fft_forward(w);
        let c2r = rp.plan_fft_inverse(w);
        let mut cp = FftPlanner::<f32>::new();
        let col_fwd = cp.plan_fft_forward(h);
        let col_inv = cp.plan_fft_inverse(h);
        let row_scratch_len = r2c.get_scratch_len().max(c2r.get_scratch_len());
        let col_scratch_len = col_fwd
            .get_inplace_scratch_len()
            .max(col_inv.get_inplace_scratch_len());
        let wc = w / 2 + 1;
        Self {
            w,
            h,
            wc,
            r2c,
            c2r,
            col_fwd,
            col_inv,
            row_real: vec![0.0; w],
            block: vec![Complex::new(0.0, 0.0); BLOCK * wc],
            row_scratch: vec![Complex::new(0.0, 0.0); row_scratch_len],
            col_scratch: vec![Complex::new(0.0, 0.0); col_scratch_len],
        }
    }

    /// Number of complex values of a spectrum: `(w/2 + 1) * h`.
    pub(crate) fn spectrum_len(&self) -> usize {
        self.wc * self.h
    }

    /// Forward transform of the row-major `input` (`w * h`) into the column-major `out`.
    pub(crate) fn forward(
        &mut self,
        input: &[f32],
        out: &mut [Complex<f32>],
    ) -> Result<(), RegistrationError> {
        let (w, h, wc) = (self.w, self.h, self.wc);
        debug_assert_eq!(input.len(), w * h);
        debug_assert_eq!(out.len(), wc * h);
        for (b, rows) in input.chunks(BLOCK * w).enumerate() {
            let n = rows.len() / w;
            for (row, spec) in rows.chunks_exact(w).zip(self.block.chunks_exact_mut(wc)) {
                self.row_real.copy_from_slice(row);
                self.r2c
                    .process_with_scratch(&mut self.row_real, spec, &mut self.row_scratch)
                    .map_err(fft_error)?;
            }
            let y0 = b * BLOCK;
            for kx in 0..wc {
                let col = &mut out[kx * h + y0..][..n];
                for (j, v) in col.iter_mut().enumerate() {
                    *v = self.block[j * wc + kx];
                }
            }
        }
        // The buffer holds `wc` contiguous columns of length `h`: one batched call.
        self.col_fwd
            .process_with_scratch(out, &mut self.col_scratch);
        Ok(())
    }

    /// Inverse transform (unnormalised: the result is `w * h` times the signal) of the
    /// column-major `spec`, which is used as scratch, into the row-major `out`.
    pub(crate) fn inverse(
        &mut self,
        spec: &mut [Complex<f32>],
        out: &mut [f32],
    ) -> Result<(), RegistrationError> {
        let (w, h, wc) = (self.w, self.h, self.wc);
        debug_assert_eq!(spec.len(), wc * h);
        debug_assert_eq!(out.len(), w * h);
        self.col_inv
            .process_with_scratch(spec, &mut self.col_scratch);
        for (b, rows) in out.chunks_mut(BLOCK * w).enumerate() {
            let n = rows.len() / w;
            let y0 = b * BLOCK;
            for kx in 0..wc {
                let col = &spec[kx * h + y0..][..n];
                for (j, v) in col.iter().enumerate() {
                    self.block[j * wc + kx] = *v;
                }
            }
            for (row, rs) in rows
                .chunks_exact_mut(w)
                .zip(self.block.chunks_exact_mut(wc))
            {
                // A Hermitian spectrum has real DC and (even w) Nyquist columns after the
                // column transform; drop the rounding residue realfft would complain about.
                rs[0].im = 0.0;
                if w.is_multiple_of(2) {
                    rs[wc - 1].im = 0.0;
                }
                self.c2r
                    .process_with_scratch(rs, row, &mut self.row_scratch)
                    .map_err(fft_error)?;
            }
        }
        Ok(())
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn forward_matches_naive_dft_and_inverse_round_trips() {
        for &(w, h) in &[(8usize, 6usize), (7, 5), (16, 16), (10, 19)] {
            let input: Vec<f32> = (0..w * h).map(|i| ((i * 37) % 11) as f32 - 5.0).collect();
            let mut fft = Fft2::new(w, h);
            let mut spec = vec![Complex::new(0.0, 0.0); fft.spectrum_len()];
            fft.forward(&input, &mut spec).unwrap();
            for kx in 0..=w / 2 {
                for ky in 0..h {
                    let mut acc = Complex::new(0.0f64, 0.0);
                    for y in 0..h {
                        for x in 0..w {
                            let ph = -std::f64::consts::TAU
                                * (kx as f64 * x as f64 / w as f64
                                    + ky as f64 * y as f64 / h as f64);
                            acc += Complex::new(ph.cos(), ph.sin()) * input[y * w + x] as f64;
                        }
                    }
                    let got = spec[kx * h + ky];
                    assert!(
                        (got.re as f64 - acc.re).abs() < 1e-3
                            && (got.im as f64 - acc.im).abs() < 1e-3
                    );
                }
            }
            let mut back = vec![0.0; w * h];
            fft.inverse(&mut spec, &mut back).unwrap();
            for (b, a) in back.iter().zip(&input) {
                assert!((b / (w * h) as f32 - a).abs() < 1e-4);
            }
        }
    }
}
