//! Fourier-Mellin similarity registration (Reddy & Chatterji 1996): the *observed*
//! camera motion between two frames.
//!
//! Pipeline, per frame (see [`Registrar`]):
//! 1. subtract the weighted mean and multiply by the weights: a Hann apodisation window
//!    over [`RegistrationParams::apodization_fraction`] of each border times the
//!    feathered mask of unmasked pixels (masked pixels become 0);
//! 2. real-to-complex FFT; magnitude times the Reddy-Chatterji high-pass
//!    `(1 - X)(2 - X)`, `X = cos(pi fx) cos(pi fy)`;
//! 3. bilinear log-polar resampling of the magnitude: angles over 0..180 degrees (the
//!    magnitude of a real image's spectrum is point-symmetric), radii log-spaced from
//!    `f_min = 0.45 / max_scale^4` (at least two frequency bins) to 0.45 cycles per pixel;
//!    Hann taper along the radius; real FFT of that image.
//!
//! Per pair: phase correlation of the two log-polar spectra gives rotation (modulo 180
//! degrees) and scale; the previous frame's preprocessed image is warped by them about the
//! centre and phase-correlated with the current one, for both the rotation and the
//! rotation + 180 degrees (the latter is an exact point reflection of the former, done in
//! the Fourier domain); the candidate with the sharper translation peak wins. On images of
//! at least 128x128 the two candidates are compared on a 64x64 surface made of the lowest
//! frequencies only, and only the winner gets a full-size inverse FFT. All correlation surfaces are the inverse transform of the
//! normalised cross-power spectrum multiplied by a Gaussian of
//! [`RegistrationParams::peak_sigma`], so that the peak is a sampled Gaussian and its
//! sub-pixel position follows from a Gaussian fit on the 3-point neighbourhoods.
//!
//! # Convention
//! The result maps the first image A onto the second image B about the image centre
//! `c = ((w-1)/2, (h-1)/2)`: a point `p` of A lands at
//! `q = c + scale * R(rotation_deg) (p - c) + (tx, ty)` in B, rotation positive
//! counter-clockwise on screen (as OpenCV's `getRotationMatrix2D`), exactly
//! [`crate::synthetic::similarity_forward`].
//!
//! # Supported range
//! Tested (`tests/registration_accuracy.rs` and the property tests below) for
//! `|rotation| <= 45` degrees, `scale` in `0.8..=1.25` and translations up to 1/8 of the
//! image side on top of rotation and scale (up to 1/4 of the side for pure translation).
//! Rotations of any angle are representable (the 180 degree ambiguity is resolved);
//! scales outside `1/max_scale..=max_scale` are not searched. Large motions shrink the
//! overlap and so the confidence; beyond about 1/3 of the image side the estimate fails.
//!
//! # Confidence
//! [`Registration::confidence`] is the share of the translation correlation surface's
//! energy (sum of squares) that lies within `ceil(2 * peak_sigma)` pixels of its peak. It
//! is 1 for identical images, typically above 0.3 for a good match of textured images,
//! and near 0 (below 0.02 at 128x128 and larger) for unrelated images or textureless
//! ones: a random surface spreads its energy over the whole image.
//!
//! # Sizes
//! Any size from 16x16 up works; the FFTs run at the image size (no padding), so sizes
//! whose factors are 2, 3 and 5 are fastest. Non-square images are handled: the
//! log-polar grid samples physical frequencies (cycles per pixel), not FFT bins.
//!
//! This module imports only [`super::image`], `realfft`/`rustfft`, `serde` and
//! `thiserror`.

mod fft2;
mod kernels;

use realfft::num_complex::Complex;
use serde::{Deserialize, Serialize};

use self::fft2::Fft2;
use self::kernels::LogPolarMap;
use super::image::GrayImage;

/// Smallest accepted image side, pixels.
pub const MIN_SIDE_PX: usize = 16;

/// Smallest accepted share of unmasked pixels.
pub const MIN_UNMASKED_FRACTION: f64 = 1.0 / 16.0;

/// Errors of [`Registrar`] and [`register`].
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum RegistrationError {
    /// The two images (or a streamed frame and its predecessor) differ in size.
    #[error("image sizes differ: {first_width}x{first_height} vs {second_width}x{second_height}")]
    SizeMismatch {
        /// Width of the first (previous) image, pixels.
        first_width: usize,
        /// Height of the first (previous) image, pixels.
        first_height: usize,
        /// Width of the second (current) image, pixels.
        second_width: usize,
        /// Height of the second (current) image, pixels.
        second_height: usize,
    },
    /// An image has no pixels.
    #[error("image is empty ({width}x{height})")]
    Empty {
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
    },
    /// An image is smaller than [`MIN_SIDE_PX`] on a side.
    #[error("image is {width}x{height}, registration needs at least {min_side}x{min_side}")]
    TooSmall {
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
        /// The minimum side, pixels.
        min_side: usize,
    },
    /// A pixel is NaN or infinite.
    #[error("{image} image: pixel ({x}, {y}) is not finite ({value})")]
    NonFinite {
        /// `"first"` or `"second"` (`"frame"` for [`Registrar::push`]).
        image: &'static str,
        /// Column.
        x: usize,
        /// Row.
        y: usize,
        /// The value.
        value: f32,
    },
    /// The mask does not have one entry per pixel.
    #[error("mask has {actual} entries but the {width}x{height} image has {expected} pixels")]
    MaskSize {
        /// Width, pixels.
        width: usize,
        /// Height, pixels.
        height: usize,
        /// `width * height`.
        expected: usize,
        /// Length of the mask given.
        actual: usize,
    },
    /// Too few pixels are left once the mask is applied.
    #[error(
        "only {unmasked} of {total} pixels are unmasked; registration needs at least {required}"
    )]
    TooFewUnmasked {
        /// Unmasked pixels.
        unmasked: usize,
        /// All pixels.
        total: usize,
        /// The minimum ([`MIN_UNMASKED_FRACTION`] of `total`).
        required: usize,
    },
    /// A parameter is out of its documented range.
    #[error("invalid registration parameter {name} = {value}: {reason}")]
    InvalidParams {
        /// Field of [`RegistrationParams`].
        name: &'static str,
        /// Its value, printed.
        value: String,
        /// The accepted range.
        reason: &'static str,
    },
    /// An FFT call failed (a bug: buffer sizes are fixed by construction).
    #[error("internal registration error: {reason}")]
    Internal {
        /// What failed.
        reason: String,
    },
}

/// How the correlation peak is located between samples.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(rename_all = "snake_case")]
pub enum SubPixelMethod {
    /// Gaussian through the peak and its two neighbours, per axis (a parabola through
    /// their logarithms); exact for the Gaussian-smoothed peak. Recommended.
    Gaussian,
    /// Parabola through the peak and its two neighbours, per axis.
    Parabolic,
    /// Centroid of the positive values of the 3x3 neighbourhood.
    Centroid,
}

/// Knobs of the Fourier-Mellin registration. `Default` holds the recommended values.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct RegistrationParams {
    /// Share of each image side, per border, covered by the Hann taper of the
    /// apodisation window (unitless, `0..=0.5`; 0 = no window). Default 0.12.
    pub apodization_fraction: f32,
    /// Multiply the magnitude spectrum by the Reddy-Chatterji high-pass emphasis before
    /// the log-polar resampling. Default true.
    pub highpass: bool,
    /// Number of log-polar angle samples over 0..180 degrees (count, `16..=4096`).
    /// Default 128 (1.41 degrees per sample before sub-pixel refinement).
    pub log_polar_angles: usize,
    /// Number of log-polar radius samples (count, `16..=4096`). Default 128.
    pub log_polar_radii: usize,
    /// Largest scale factor searched (unitless, `1.05..=4`): scales in
    /// `1/max_scale..=max_scale`. It also sets the log-polar radius range. Default 2.
    pub max_scale: f32,
    /// Width of the soft edge of the mask, pixels (`0..=64`): weights rise from 0 on a
    /// masked pixel to 1 at this distance from the mask. Default 4.
    pub mask_feather_px: f32,
    /// Sub-pixel peak refinement. Default [`SubPixelMethod::Gaussian`].
    pub subpixel: SubPixelMethod,
    /// Standard deviation of the Gaussian that smooths the correlation peaks, pixels
    /// (or log-polar samples), `0.5..=4`. Default 1.
    pub peak_sigma: f32,
    /// Extra rotation/scale refinements (count, `0..=3`): each re-measures the residual
    /// rotation and scale on the warped previous frame (one more warp and two more
    /// FFTs of the image size, about +40 % time). Default 0: measured over 80 random
    /// similarities at 256x256 (`examples/registration_speed.rs acc`), 0 iterations give
    /// worst errors 0.10 px, 0.26 deg, 0.23 % scale against 0.10 px, 0.11 deg, 0.16 %
    /// with 1 (see `benches/registration_speed.md`).
    pub refine_iterations: u32,
}

impl Default for RegistrationParams {
    fn default() -> Self {
        Self {
            apodization_fraction: 0.12,
            highpass: true,
            log_polar_angles: 128,
            log_polar_radii: 128,
            max_scale: 2.0,
            mask_feather_px: 4.0,
            subpixel: SubPixelMethod::Gaussian,
            peak_sigma: 1.0,
            refine_iterations: 0,
        }
    }
}

impl RegistrationParams {
    /// Checks every field against its documented range.
    pub fn validate(&self) -> Result<(), RegistrationError> {
        fn bad(
            name: &'static str,
            value: impl ToString,
            reason: &'static str,
        ) -> RegistrationError {
            RegistrationError::InvalidParams {
                name,
                value: value.to_string(),
                reason,
            }
        }
        let f = self.apodization_fraction;
        if !(0.0..=0.5).contains(&f) {
            return Err(bad("apodization_fraction", f, "must be in 0..=0.5"));
        }
        if !(16..=4096).contains(&self.log_polar_angles) {
            return Err(bad(
                "log_polar_angles",
                self.log_polar_angles,
                "must be in 16..=4096",
            ));
        }
        if !(16..=4096).contains(&self.log_polar_radii) {
            return Err(bad(
                "log_polar_radii",
                self.log_polar_radii,
                "must be in 16..=4096",
            ));
        }
        if !(1.05..=4.0).contains(&self.max_scale) {
            return Err(bad("max_scale", self.max_scale, "must be in 1.05..=4"));
        }
        if !(0.0..=64.0).contains(&self.mask_feather_px) {
            return Err(bad(
                "mask_feather_px",
                self.mask_feather_px,
                "must be in 0..=64 pixels",
            ));
        }
        if !(0.5..=4.0).contains(&self.peak_sigma) {
            return Err(bad("peak_sigma", self.peak_sigma, "must be in 0.5..=4"));
        }
        if self.refine_iterations > 3 {
            return Err(bad(
                "refine_iterations",
                self.refine_iterations,
                "must be in 0..=3",
            ));
        }
        Ok(())
    }
}

/// A 2-D similarity about the image centre; see the module docs for the convention.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Similarity {
    /// Translation to the right, pixels.
    pub tx_px: f64,
    /// Translation downwards, pixels.
    pub ty_px: f64,
    /// Scale factor (unitless, > 0); content grows when > 1.
    pub scale: f64,
    /// Rotation, degrees, counter-clockwise on screen, in `(-180, 180]`.
    pub rotation_deg: f64,
}

impl Similarity {
    /// The identity transform.
    pub const IDENTITY: Self = Self {
        tx_px: 0.0,
        ty_px: 0.0,
        scale: 1.0,
        rotation_deg: 0.0,
    };

    /// How far `self` is from `other`, per component: the larger absolute translation
    /// difference (pixels), the absolute rotation difference wrapped to `[0, 180]`
    /// (degrees), and the relative scale difference `|self.scale / other.scale - 1|`.
    pub fn difference(&self, other: &Similarity) -> (f64, f64, f64) {
        let rotation =
            ((self.rotation_deg - other.rotation_deg + 180.0).rem_euclid(360.0) - 180.0).abs();
        (
            (self.tx_px - other.tx_px)
                .abs()
                .max((self.ty_px - other.ty_px).abs()),
            rotation,
            (self.scale / other.scale - 1.0).abs(),
        )
    }
}

/// The result of registering two images.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Registration {
    /// Maps the first image onto the second.
    pub transform: Similarity,
    /// Peak sharpness of the translation correlation in `[0, 1]`: the share of the
    /// correlation energy around the peak (see the module docs). Near 0 for unrelated or
    /// textureless images, high (1 for identical images) for a good match.
    pub confidence: f32,
}

/// One preprocessed frame: what a later pair needs of it.
struct Frame {
    /// The raw pixels, kept so the frame can be preprocessed again under a new mask.
    raw: Vec<f32>,
    /// Zero-mean, windowed and masked pixels.
    pre: Vec<f32>,
    /// Spectrum of `pre` (column-major half spectrum).
    spec: Vec<Complex<f32>>,
    /// Spectrum of the tapered log-polar magnitude image.
    lp_spec: Vec<Complex<f32>>,
    /// Generation of the weights `pre` was made with.
    weights_gen: u64,
}

impl Frame {
    fn new(n: usize, spec_len: usize, lp_spec_len: usize) -> Self {
        Self {
            raw: vec![0.0; n],
            pre: vec![0.0; n],
            spec: vec![Complex::new(0.0, 0.0); spec_len],
            lp_spec: vec![Complex::new(0.0, 0.0); lp_spec_len],
            weights_gen: u64::MAX,
        }
    }
}

/// Everything that depends only on the image size and the parameters, built once.
struct SizeCache {
    w: usize,
    h: usize,
    fft: Fft2,
    lp_fft: Fft2,
    lp_map: LogPolarMap,
    window: Vec<f32>,
    highpass: Vec<f32>,
    lp_taper: Vec<f32>,
    gauss: Vec<f32>,
    lp_gauss: Vec<f32>,
    half_turn: Vec<Complex<f32>>,
    /// Low-frequency choice between the two half-turn candidates (large images only).
    coarse: Option<CoarseChoice>,
    /// Window times feathered mask; generation counts mask changes.
    weights: Vec<f32>,
    weights_gen: u64,
    mask_key: Option<Vec<bool>>,
    feather: Vec<f32>,
    // Scratch.
    mag: Vec<f32>,
    lp: Vec<f32>,
    lp_cross: Vec<Complex<f32>>,
    lp_surface: Vec<f32>,
    warped: Vec<f32>,
    warped_spec: Vec<Complex<f32>>,
    cross: Vec<Complex<f32>>,
    surface: Vec<f32>,
    lp_tmp: Vec<Complex<f32>>,
    /// Streaming state and the two slots of a pair.
    prev: Option<Frame>,
    spare: Option<Frame>,
    pair: [Option<Frame>; 2],
}

impl SizeCache {
    fn new(w: usize, h: usize, p: &RegistrationParams) -> Self {
        let fft = Fft2::new(w, h);
        let (na, nr) = (p.log_polar_angles, p.log_polar_radii);
        let lp_fft = Fft2::new(nr, na);
        let lp_map = LogPolarMap::new(w, h, na, nr, p.max_scale as f64);
        let spec_len = fft.spectrum_len();
        let lp_spec_len = lp_fft.spectrum_len();
        let window = kernels::apodization_window(w, h, p.apodization_fraction);
        Self {
            w,
            h,
            highpass: kernels::highpass(w, h, p.highpass),
            lp_taper: kernels::taper_1d(nr, 0.1),
            gauss: kernels::gaussian_spectrum(w, h, p.peak_sigma),
            lp_gauss: kernels::gaussian_spectrum(nr, na, p.peak_sigma),
            half_turn: kernels::half_turn_ramp(w, h),
            coarse: CoarseChoice::new(w, h, p.peak_sigma),
            weights: window.clone(),
            window,
            weights_gen: 0,
            mask_key: None,
            feather: vec![0.0; w * h],
            mag: vec![0.0; spec_len],
            lp: vec![0.0; na * nr],
            lp_cross: vec![Complex::new(0.0, 0.0); lp_spec_len],
            lp_surface: vec![0.0; na * nr],
            warped: vec![0.0; w * h],
            warped_spec: vec![Complex::new(0.0, 0.0); spec_len],
            cross: vec![Complex::new(0.0, 0.0); spec_len],
            surface: vec![0.0; w * h],
            lp_tmp: vec![Complex::new(0.0, 0.0); lp_spec_len],
            prev: None,
            spare: None,
            pair: [None, None],
            fft,
            lp_fft,
            lp_map,
        }
    }

    fn new_frame(&self) -> Frame {
        Frame::new(
            self.w * self.h,
            self.fft.spectrum_len(),
            self.lp_fft.spectrum_len(),
        )
    }

    /// Makes `weights` those of `mask` (window times feathered mask), recomputing only
    /// when the mask changed.
    fn set_mask(&mut self, mask: Option<&[bool]>, feather_px: f32) {
        let same = match (&self.mask_key, mask) {
            (None, None) => true,
            (Some(k), Some(m)) => k.as_slice() == m,
            _ => false,
        };
        if same {
            return;
        }
        match mask {
            None => {
                self.mask_key = None;
                self.weights.copy_from_slice(&self.window);
            }
            Some(m) => {
                let key = self.mask_key.get_or_insert_with(Vec::new);
                key.clear();
                key.extend_from_slice(m);
                kernels::feathered_mask(m, self.w, self.h, feather_px, &mut self.feather);
                for ((o, &a), &b) in self.weights.iter_mut().zip(&self.window).zip(&self.feather) {
                    *o = a * b;
                }
            }
        }
        self.weights_gen += 1;
    }

    /// Fills `frame.pre`, `frame.spec` and `frame.lp_spec` from `frame.raw`.
    fn preprocess(&mut self, frame: &mut Frame) -> Result<(), RegistrationError> {
        kernels::weighted_zero_mean(&frame.raw, &self.weights, &mut frame.pre);
        self.fft.forward(&frame.pre, &mut frame.spec)?;
        self.log_polar_spectrum(true, frame)?;
        frame.weights_gen = self.weights_gen;
        Ok(())
    }

    /// Log-polar magnitude spectrum of `frame.spec` (or of `warped_spec` when
    /// `from_frame` is false, result in `lp_tmp`).
    fn log_polar_spectrum(
        &mut self,
        from_frame: bool,
        frame: &mut Frame,
    ) -> Result<(), RegistrationError> {
        let spec = if from_frame {
            &frame.spec
        } else {
            &self.warped_spec
        };
        for ((m, s), &hp) in self.mag.iter_mut().zip(spec).zip(&self.highpass) {
            *m = s.norm_sqr().sqrt() * hp;
        }
        self.lp_map.sample(&self.mag, &mut self.lp);
        let mean = self.lp.iter().map(|&v| v as f64).sum::<f64>() / self.lp.len() as f64;
        let nr = self.lp_map.radii;
        for row in self.lp.chunks_exact_mut(nr) {
            for (v, &t) in row.iter_mut().zip(&self.lp_taper) {
                *v = (*v - mean as f32) * t;
            }
        }
        let out = if from_frame {
            &mut frame.lp_spec
        } else {
            &mut self.lp_tmp
        };
        self.lp_fft.forward(&self.lp, out)
    }

    /// Rotation (degrees, modulo 180, in `-90..90`) and log-scale taking the log-polar
    /// spectrum `a` to `b`.
    fn rotation_scale(
        &mut self,
        a: &[Complex<f32>],
        b: &[Complex<f32>],
        p: &RegistrationParams,
    ) -> Result<(f64, f64), RegistrationError> {
        kernels::cross_power(a, b, &self.lp_gauss, None, &mut self.lp_cross);
        self.lp_fft
            .inverse(&mut self.lp_cross, &mut self.lp_surface)?;
        let (na, nr) = (self.lp_map.angles, self.lp_map.radii);
        let max_dr = ((p.max_scale as f64).ln() / self.lp_map.log_step).ceil() as usize + 1;
        let radius = (2.0 * p.peak_sigma).ceil() as usize;
        let pk = kernels::find_peak(&self.lp_surface, nr, na, Some(max_dr), p.subpixel, radius);
        // |F_B(phi, f)| = |F_A(phi + theta, s f)| (image axes, y down): B's log-polar image
        // is A's shifted by (-theta, -ln s).
        let rotation_deg = -pk.dy * 180.0 / na as f64;
        let log_scale = -pk.dx * self.lp_map.log_step;
        Ok((rotation_deg, log_scale))
    }

    /// Registers the preprocessed frames `a` (previous) and `b` (current).
    fn register_frames(
        &mut self,
        a: &Frame,
        b: &Frame,
        p: &RegistrationParams,
    ) -> Result<Registration, RegistrationError> {
        let (w, h) = (self.w, self.h);
        let (mut rot, mut log_s) = self.rotation_scale(&a.lp_spec, &b.lp_spec, p)?;
        for _ in 0..p.refine_iterations {
            kernels::warp_similarity(&a.pre, w, h, log_s.exp(), rot, &mut self.warped);
            self.fft.forward(&self.warped, &mut self.warped_spec)?;
            // The warped image's log-polar spectrum ends up in `lp_tmp`; `frame` is unused.
            let mut dummy = Frame::new(0, 0, 0);
            self.log_polar_spectrum(false, &mut dummy)?;
            let tmp = std::mem::take(&mut self.lp_tmp);
            let res = self.rotation_scale(&tmp, &b.lp_spec, p);
            self.lp_tmp = tmp;
            let (dr, dls) = res?;
            rot += dr;
            log_s += dls;
        }
        let scale = log_s.exp();
        kernels::warp_similarity(&a.pre, w, h, scale, rot, &mut self.warped);
        self.fft.forward(&self.warped, &mut self.warped_spec)?;
        let radius = (2.0 * p.peak_sigma).ceil() as usize;
        let mut best: Option<(kernels::Peak, f64)> = None;
        let choice = match self.coarse.as_mut() {
            Some(c) => c.prefers_half_turn(&self.warped_spec, &b.spec, &self.half_turn)?,
            None => None,
        };
        let candidates: &[bool] = match choice {
            Some(true) => &[true],
            Some(false) => &[false],
            None => &[false, true],
        };
        for &half_turn in candidates {
            let ramp = half_turn.then_some(self.half_turn.as_slice());
            kernels::cross_power(
                &self.warped_spec,
                &b.spec,
                &self.gauss,
                ramp,
                &mut self.cross,
            );
            self.fft.inverse(&mut self.cross, &mut self.surface)?;
            let pk = kernels::find_peak(&self.surface, w, h, None, p.subpixel, radius);
            let r = if half_turn { rot + 180.0 } else { rot };
            if best.is_none_or(|(bp, _)| pk.energy_fraction > bp.energy_fraction) {
                best = Some((pk, r));
            }
        }
        let Some((pk, r)) = best else {
            // Invariant: the loop above runs twice and always sets `best`.
            return Err(RegistrationError::Internal {
                reason: "no translation candidate".into(),
            });
        };
        let mut rotation_deg = r.rem_euclid(360.0);
        if rotation_deg > 180.0 {
            rotation_deg -= 360.0;
        }
        Ok(Registration {
            transform: Similarity {
                tx_px: pk.dx,
                ty_px: pk.dy,
                scale,
                rotation_deg,
            },
            confidence: pk.energy_fraction,
        })
    }
}

/// Side of the low-frequency correlation surface that picks the half-turn candidate.
const COARSE_SIDE: usize = 64;

/// Picks between the rotation and the rotation + 180 degrees on a `COARSE_SIDE` square
/// correlation surface made of the low frequencies only, so that only the winner needs a
/// full-size inverse FFT. Both candidates' normalised cross-power spectra have the same
/// magnitude (the half-turn ramp has modulus 1), hence the same surface energy: the
/// higher maximum is the sharper peak. When neither maximum is clearly higher (weak
/// overlap, e.g. large shifts) both candidates are evaluated at full size.
struct CoarseChoice {
    fft: Fft2,
    /// Full-spectrum index of each coarse-spectrum bin.
    idx: Vec<u32>,
    gauss: Vec<f32>,
    a: Vec<Complex<f32>>,
    b: Vec<Complex<f32>>,
    ramp: Vec<Complex<f32>>,
    cross: Vec<Complex<f32>>,
    surface: Vec<f32>,
}

impl CoarseChoice {
    /// `None` when the image is too small for the coarse surface to save work.
    fn new(w: usize, h: usize, peak_sigma: f32) -> Option<Self> {
        let n = COARSE_SIDE;
        if w < 2 * n || h < 2 * n {
            return None;
        }
        let fft = Fft2::new(n, n);
        let len = fft.spectrum_len();
        let mut idx = Vec::with_capacity(len);
        for kx in 0..=n / 2 {
            for ky in 0..n {
                let fy = kernels::signed_freq(ky, n).rem_euclid(h as isize) as usize;
                idx.push((kx * h + fy) as u32);
            }
        }
        // The smoothing Gaussian in full-size pixels, on the coarse bins.
        let full_gauss = kernels::gaussian_spectrum(w, h, peak_sigma);
        let gauss = idx.iter().map(|&i| full_gauss[i as usize]).collect();
        let zero = Complex::new(0.0, 0.0);
        Some(Self {
            fft,
            idx,
            gauss,
            a: vec![zero; len],
            b: vec![zero; len],
            ramp: vec![zero; len],
            cross: vec![zero; len],
            surface: vec![0.0; n * n],
        })
    }

    /// `Some(true)` when the half-turned candidate `a` correlates clearly better with
    /// `b`, `Some(false)` when the plain one does, `None` when the coarse surfaces cannot
    /// tell.
    fn prefers_half_turn(
        &mut self,
        a: &[Complex<f32>],
        b: &[Complex<f32>],
        half_turn: &[Complex<f32>],
    ) -> Result<Option<bool>, RegistrationError> {
        for (k, &i) in self.idx.iter().enumerate() {
            let i = i as usize;
            self.a[k] = a[i];
            self.b[k] = b[i];
            self.ramp[k] = half_turn[i];
        }
        let mut peaks = [0.0f32; 2];
        for (half, peak) in peaks.iter_mut().enumerate() {
            let ramp = (half == 1).then_some(self.ramp.as_slice());
            kernels::cross_power(&self.a, &self.b, &self.gauss, ramp, &mut self.cross);
            self.fft.inverse(&mut self.cross, &mut self.surface)?;
            *peak = self
                .surface
                .iter()
                .copied()
                .fold(f32::NEG_INFINITY, f32::max);
        }
        // A clear winner has at least twice the other's maximum.
        let (lo, hi) = (peaks[0].min(peaks[1]), peaks[0].max(peaks[1]));
        Ok((hi > 0.0 && hi >= 2.0 * lo.max(0.0)).then_some(peaks[1] > peaks[0]))
    }
}

/// Fourier-Mellin registration with per-size caches (FFT plans, window, high-pass
/// filter, log-polar map, scratch buffers) and a streaming form that reuses the previous
/// frame's spectra.
///
/// After the first call at a given size nothing is allocated per call (unless the mask
/// changes to or from `None`). Changing the image size rebuilds the cache and, for
/// [`Registrar::push`], is an error until [`Registrar::reset`].
pub struct Registrar {
    params: RegistrationParams,
    cache: Option<SizeCache>,
}

impl std::fmt::Debug for Registrar {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Registrar")
            .field("params", &self.params)
            .field("size", &self.cache.as_ref().map(|c| (c.w, c.h)))
            .finish()
    }
}

impl Registrar {
    /// A registrar with validated `params`.
    pub fn new(params: RegistrationParams) -> Result<Self, RegistrationError> {
        params.validate()?;
        Ok(Self {
            params,
            cache: None,
        })
    }

    /// The parameters.
    pub fn params(&self) -> &RegistrationParams {
        &self.params
    }

    /// Forgets the previous frame of the stream (the caches stay).
    pub fn reset(&mut self) {
        if let Some(c) = self.cache.as_mut()
            && let Some(f) = c.prev.take()
        {
            c.spare = Some(f);
        }
    }

    fn cache_for(&mut self, w: usize, h: usize) -> &mut SizeCache {
        if self.cache.as_ref().is_none_or(|c| (c.w, c.h) != (w, h)) {
            self.cache = Some(SizeCache::new(w, h, &self.params));
        }
        // Invariant: the line above fills the cache when it is empty.
        #[allow(clippy::unwrap_used)]
        self.cache.as_mut().unwrap()
    }

    /// Registers `a` (first, previous) onto `b` (second, current), ignoring the pixels
    /// where `mask` is true in both images. Independent of the stream of
    /// [`Registrar::push`] (which it leaves untouched).
    pub fn register(
        &mut self,
        a: &GrayImage,
        b: &GrayImage,
        mask: Option<&[bool]>,
    ) -> Result<Registration, RegistrationError> {
        validate_image(a, "first")?;
        validate_image(b, "second")?;
        if a.size() != b.size() {
            return Err(RegistrationError::SizeMismatch {
                first_width: a.width(),
                first_height: a.height(),
                second_width: b.width(),
                second_height: b.height(),
            });
        }
        let (w, h) = a.size();
        validate_mask(mask, w, h)?;
        let params = self.params.clone();
        let c = self.cache_for(w, h);
        c.set_mask(mask, params.mask_feather_px);
        let mut fa = c.pair[0].take().unwrap_or_else(|| c.new_frame());
        let mut fb = c.pair[1].take().unwrap_or_else(|| c.new_frame());
        fa.raw.copy_from_slice(a.data());
        fb.raw.copy_from_slice(b.data());
        let res = c
            .preprocess(&mut fa)
            .and_then(|_| c.preprocess(&mut fb))
            .and_then(|_| c.register_frames(&fa, &fb, &params));
        c.pair = [Some(fa), Some(fb)];
        res
    }

    /// Streaming form: registers the previous pushed frame onto `frame` (`None` for the
    /// first frame after construction or [`Registrar::reset`]). The previous frame's
    /// spectra are reused when the mask is the same as at the last push (or absent both
    /// times); otherwise the previous frame is preprocessed again under the new mask, so
    /// the result always equals [`Registrar::register`] on the same pair and mask.
    pub fn push(
        &mut self,
        frame: &GrayImage,
        mask: Option<&[bool]>,
    ) -> Result<Option<Registration>, RegistrationError> {
        validate_image(frame, "frame")?;
        let (w, h) = frame.size();
        if let Some(c) = self.cache.as_ref()
            && c.prev.is_some()
            && (c.w, c.h) != (w, h)
        {
            return Err(RegistrationError::SizeMismatch {
                first_width: c.w,
                first_height: c.h,
                second_width: w,
                second_height: h,
            });
        }
        validate_mask(mask, w, h)?;
        let params = self.params.clone();
        let c = self.cache_for(w, h);
        c.set_mask(mask, params.mask_feather_px);
        let mut cur = c.spare.take().unwrap_or_else(|| c.new_frame());
        cur.raw.copy_from_slice(frame.data());
        if let Err(e) = c.preprocess(&mut cur) {
            c.spare = Some(cur);
            return Err(e);
        }
        let Some(mut prev) = c.prev.take() else {
            c.prev = Some(cur);
            return Ok(None);
        };
        let mut res = Ok(());
        if prev.weights_gen != c.weights_gen {
            res = c.preprocess(&mut prev);
        }
        let out = res.and_then(|_| c.register_frames(&prev, &cur, &params));
        c.prev = Some(cur);
        c.spare = Some(prev);
        out.map(Some)
    }
}

/// Registers `a` onto `b` with a fresh [`Registrar`]; see [`Registrar::register`]. Use a
/// [`Registrar`] to reuse FFT plans and buffers across calls.
pub fn register(
    a: &GrayImage,
    b: &GrayImage,
    mask: Option<&[bool]>,
    params: &RegistrationParams,
) -> Result<Registration, RegistrationError> {
    Registrar::new(params.clone())?.register(a, b, mask)
}

fn validate_image(img: &GrayImage, image: &'static str) -> Result<(), RegistrationError> {
    let (width, height) = img.size();
    if width == 0 || height == 0 {
        return Err(RegistrationError::Empty { width, height });
    }
    if width < MIN_SIDE_PX || height < MIN_SIDE_PX {
        return Err(RegistrationError::TooSmall {
            width,
            height,
            min_side: MIN_SIDE_PX,
        });
    }
    if let Some(i) = img.data().iter().position(|v| !v.is_finite()) {
        return Err(RegistrationError::NonFinite {
            image,
            x: i % width,
            y: i / width,
            value: img.data()[i],
        });
    }
    Ok(())
}

fn validate_mask(
    mask: Option<&[bool]>,
    width: usize,
    height: usize,
) -> Result<(), RegistrationError> {
    let Some(m) = mask else { return Ok(()) };
    let total = width * height;
    if m.len() != total {
        return Err(RegistrationError::MaskSize {
            width,
            height,
            expected: total,
            actual: m.len(),
        });
    }
    let unmasked = m.iter().filter(|&&v| !v).count();
    let required = ((total as f64 * MIN_UNMASKED_FRACTION).ceil() as usize).max(1);
    if unmasked < required {
        return Err(RegistrationError::TooFewUnmasked {
            unmasked,
            total,
            required,
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests;
