//! Image and flow preprocessing: gray from RGB, histogram equalisation, resizing
//! (antialiased bilinear, area), centre crop, and the flow predictor's network input.
//!
//! Resizing is separable: a 1-D resampling plan (source taps and weights per output
//! sample) is built per axis and applied to rows, then to columns. Antialiased bilinear
//! widens the triangle kernel by the downscale factor (as PIL and PyTorch's
//! `antialias=True` do), so shrinking a flow field averages instead of aliasing; area
//! weights each source pixel by its overlap with the output pixel (OpenCV's `INTER_AREA`).
//!
//! Imports only [`super::image`].

use super::image::{FlowField, GrayImage, ImageError, gray_from_rgb_pixel};
use serde::{Deserialize, Serialize};

/// Errors of the preprocessing helpers.
#[derive(Debug, thiserror::Error)]
pub enum PreprocessError {
    /// The RGB buffer does not have `3 * width * height` bytes.
    #[error("RGB buffer has {actual} bytes but a {width}x{height} image needs {expected}")]
    RgbBufferSize {
        /// Width in pixels.
        width: usize,
        /// Height in pixels.
        height: usize,
        /// `3 * width * height`.
        expected: usize,
        /// Bytes given.
        actual: usize,
    },
    /// A requested output size is zero.
    #[error("target size {width}x{height} is empty")]
    EmptyTarget {
        /// Requested width.
        width: usize,
        /// Requested height.
        height: usize,
    },
    /// A crop larger than the image.
    #[error("cannot crop {crop_width}x{crop_height} from a {width}x{height} image")]
    CropTooLarge {
        /// Image width.
        width: usize,
        /// Image height.
        height: usize,
        /// Crop width.
        crop_width: usize,
        /// Crop height.
        crop_height: usize,
    },
    /// Invalid network-input parameters.
    #[error("invalid network input parameter {field}: {reason}")]
    InvalidParams {
        /// The field.
        field: &'static str,
        /// Why.
        reason: String,
    },
    /// The input image itself is unusable.
    #[error(transparent)]
    Image(#[from] ImageError),
}

/// Gray (ITU-R BT.601 luma, 0..=255) from interleaved 8-bit RGB: [`gray_from_rgb_pixel`]
/// on each pixel's values.
pub fn gray_from_rgb(
    rgb: &[u8],
    width: usize,
    height: usize,
) -> Result<GrayImage, PreprocessError> {
    let expected = 3 * width * height;
    if rgb.len() != expected {
        return Err(PreprocessError::RgbBufferSize {
            width,
            height,
            expected,
            actual: rgb.len(),
        });
    }
    let data = rgb
        .chunks_exact(3)
        .map(|p| gray_from_rgb_pixel([p[0], p[1], p[2]].map(f32::from)))
        .collect();
    Ok(GrayImage::new(width, height, data)?)
}

/// Histogram equalisation as OpenCV's `equalizeHist` on 8-bit images: values are rounded
/// and clamped to 0..=255, then mapped through the normalised cumulative histogram
/// (`round((cdf(v) - cdf_min) * 255 / (n - cdf_min))`). A constant image is returned
/// unchanged.
pub fn equalize_histogram(img: &GrayImage) -> Result<GrayImage, PreprocessError> {
    img.validate()?;
    let bins: Vec<u8> = img
        .data()
        .iter()
        .map(|v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    let mut hist = [0usize; 256];
    for &b in &bins {
        hist[b as usize] += 1;
    }
    let n = bins.len();
    let cdf_min = hist.iter().copied().find(|&c| c > 0).unwrap_or(0);
    if cdf_min == n {
        return Ok(img.clone());
    }
    let mut lut = [0f32; 256];
    let mut cdf = 0usize;
    let scale = 255.0 / (n - cdf_min) as f64;
    for (v, &h) in hist.iter().enumerate() {
        cdf += h;
        lut[v] = ((cdf.saturating_sub(cdf_min)) as f64 * scale).round() as f32;
    }
    let data = bins.iter().map(|&b| lut[b as usize]).collect();
    Ok(GrayImage::new(img.width(), img.height(), data)?)
}

/// Resampling filter of [`resize`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ResizeFilter {
    /// Bilinear; when shrinking, the triangle kernel is widened by the scale factor
    /// (antialiased), as PIL and PyTorch `antialias=True`.
    Bilinear,
    /// Area averaging (OpenCV `INTER_AREA`); when enlarging it equals bilinear.
    Area,
}

/// Per output sample: first source index and weights of the consecutive taps.
struct Plan {
    starts: Vec<usize>,
    taps: usize,
    weights: Vec<f32>,
}

fn plan(src: usize, dst: usize, filter: ResizeFilter) -> Plan {
    let scale = src as f64 / dst as f64;
    // Half-pixel-centre convention: output centre i maps to source (i + 0.5) * scale - 0.5.
    let support = match filter {
        ResizeFilter::Bilinear => scale.max(1.0),
        ResizeFilter::Area if scale > 1.0 => scale / 2.0,
        ResizeFilter::Area => 1.0,
    };
    let taps = (2.0 * support).ceil() as usize + 2;
    let mut starts = Vec::with_capacity(dst);
    let mut weights = vec![0f32; dst * taps];
    for i in 0..dst {
        let centre = (i as f64 + 0.5) * scale - 0.5;
        let lo = (centre - support).floor().max(0.0) as usize;
        let lo = lo.min(src.saturating_sub(1));
        let w = &mut weights[i * taps..(i + 1) * taps];
        let mut sum = 0.0f64;
        for (t, slot) in w.iter_mut().enumerate() {
            let j = lo + t;
            if j >= src {
                break;
            }
            let weight = match filter {
                ResizeFilter::Bilinear => (1.0 - ((j as f64 - centre) / support).abs()).max(0.0),
                ResizeFilter::Area if scale > 1.0 => {
                    // Overlap of source pixel [j, j+1) with output footprint
                    // [i*scale, (i+1)*scale), in source units.
                    let a = (i as f64 * scale).max(j as f64);
                    let b = ((i + 1) as f64 * scale).min(j as f64 + 1.0);
                    (b - a).max(0.0)
                }
                ResizeFilter::Area => (1.0 - (j as f64 - centre).abs()).max(0.0),
            };
            *slot = weight as f32;
            sum += weight;
        }
        if sum > 0.0 {
            w.iter_mut().for_each(|v| *v = (*v as f64 / sum) as f32);
        } else {
            // Invariant: only reached when the centre lies outside the source (border
            // clamping); take the nearest source sample.
            w.iter_mut().for_each(|v| *v = 0.0);
            w[0] = 1.0;
        }
        starts.push(lo);
    }
    Plan {
        starts,
        taps,
        weights,
    }
}

fn apply_rows(src: &[f32], width: usize, height: usize, p: &Plan) -> Vec<f32> {
    let dst_w = p.starts.len();
    let mut out = vec![0f32; dst_w * height];
    for y in 0..height {
        let row = &src[y * width..(y + 1) * width];
        for (x, o) in out[y * dst_w..(y + 1) * dst_w].iter_mut().enumerate() {
            let s = p.starts[x];
            let w = &p.weights[x * p.taps..(x + 1) * p.taps];
            *o = w
                .iter()
                .zip(&row[s..(s + p.taps).min(width)])
                .map(|(a, b)| a * b)
                .sum();
        }
    }
    out
}

fn apply_cols(src: &[f32], width: usize, height: usize, p: &Plan) -> Vec<f32> {
    let dst_h = p.starts.len();
    let mut out = vec![0f32; width * dst_h];
    for y in 0..dst_h {
        let s = p.starts[y];
        let w = &p.weights[y * p.taps..(y + 1) * p.taps];
        let o = &mut out[y * width..(y + 1) * width];
        for (t, &wt) in w.iter().enumerate() {
            let j = s + t;
            if j >= height || wt == 0.0 {
                continue;
            }
            let r = &src[j * width..(j + 1) * width];
            for (a, b) in o.iter_mut().zip(r) {
                *a += wt * b;
            }
        }
    }
    out
}

/// Area shrinking by whole factors (`kx x ky` source pixels per output pixel, e.g. a
/// 640x480 camera processed at 320x240): the mean of each block, which is what the
/// general area filter computes, in one pass (0.2 ms instead of 1.4 ms at 640x480).
fn shrink_blocks(
    src: &[f32],
    (width, height): (usize, usize),
    (new_w, new_h): (usize, usize),
) -> Vec<f32> {
    let (kx, ky) = (width / new_w, height / new_h);
    let norm = 1.0 / (kx * ky) as f32;
    let mut out = vec![0f32; new_w * new_h];
    for (y, o) in out.chunks_exact_mut(new_w).enumerate() {
        for r in 0..ky {
            let row = &src[(y * ky + r) * width..(y * ky + r + 1) * width];
            for (a, block) in o.iter_mut().zip(row.chunks_exact(kx)) {
                *a += block.iter().sum::<f32>();
            }
        }
        o.iter_mut().for_each(|a| *a *= norm);
    }
    out
}

fn resize_plane(
    src: &[f32],
    (width, height): (usize, usize),
    (new_w, new_h): (usize, usize),
    filter: ResizeFilter,
) -> Vec<f32> {
    if filter == ResizeFilter::Area
        && new_w <= width
        && new_h <= height
        && width.is_multiple_of(new_w)
        && height.is_multiple_of(new_h)
    {
        return shrink_blocks(src, (width, height), (new_w, new_h));
    }
    // The axis pass that leaves the smaller intermediate goes first, so memory depends
    // on the output size and not on the input's aspect ratio: a 1 x 6,000,000 image
    // resized rows first would need a 160 x 6,000,000 intermediate. The intermediate is
    // at most sqrt(width * height * new_w * new_h) samples. Ties (same aspect ratio)
    // resize rows first.
    let rows_plan = plan(width, new_w, filter);
    let cols_plan = plan(height, new_h, filter);
    if width.saturating_mul(new_h) < new_w.saturating_mul(height) {
        let cols = apply_cols(src, width, height, &cols_plan);
        apply_rows(&cols, width, new_h, &rows_plan)
    } else {
        let rows = apply_rows(src, width, height, &rows_plan);
        apply_cols(&rows, new_w, height, &cols_plan)
    }
}

/// Resizes `img` to `new_width x new_height` with `filter`.
pub fn resize(
    img: &GrayImage,
    new_width: usize,
    new_height: usize,
    filter: ResizeFilter,
) -> Result<GrayImage, PreprocessError> {
    img.validate()?;
    if new_width == 0 || new_height == 0 {
        return Err(PreprocessError::EmptyTarget {
            width: new_width,
            height: new_height,
        });
    }
    let data = resize_plane(img.data(), img.size(), (new_width, new_height), filter);
    Ok(GrayImage::new(new_width, new_height, data)?)
}

/// Resizes both components of a flow field. With `scale_vectors` the vectors are
/// multiplied by the resize factors (the flow stays in pixels of the new size); without,
/// the values are resampled unchanged.
pub fn resize_flow(
    flow: &FlowField,
    new_width: usize,
    new_height: usize,
    filter: ResizeFilter,
    scale_vectors: bool,
) -> Result<FlowField, PreprocessError> {
    if new_width == 0 || new_height == 0 {
        return Err(PreprocessError::EmptyTarget {
            width: new_width,
            height: new_height,
        });
    }
    if flow.width() == 0 || flow.height() == 0 {
        return Err(ImageError::Empty {
            width: flow.width(),
            height: flow.height(),
        }
        .into());
    }
    let (sx, sy) = if scale_vectors {
        (
            new_width as f32 / flow.width() as f32,
            new_height as f32 / flow.height() as f32,
        )
    } else {
        (1.0, 1.0)
    };
    let mut u = resize_plane(&flow.u, flow.size(), (new_width, new_height), filter);
    let mut v = resize_plane(&flow.v, flow.size(), (new_width, new_height), filter);
    u.iter_mut().for_each(|a| *a *= sx);
    v.iter_mut().for_each(|a| *a *= sy);
    Ok(FlowField::new(new_width, new_height, u, v)?)
}

fn crop_origin(
    (width, height): (usize, usize),
    (cw, ch): (usize, usize),
) -> Result<(usize, usize), PreprocessError> {
    if cw == 0 || ch == 0 {
        return Err(PreprocessError::EmptyTarget {
            width: cw,
            height: ch,
        });
    }
    if cw > width || ch > height {
        return Err(PreprocessError::CropTooLarge {
            width,
            height,
            crop_width: cw,
            crop_height: ch,
        });
    }
    Ok(((width - cw) / 2, (height - ch) / 2))
}

fn crop_plane(
    src: &[f32],
    width: usize,
    (x0, y0): (usize, usize),
    (cw, ch): (usize, usize),
) -> Vec<f32> {
    (y0..y0 + ch)
        .flat_map(|y| src[y * width + x0..y * width + x0 + cw].iter().copied())
        .collect()
}

/// The centred `crop_width x crop_height` window of `img` (left/top get the smaller
/// margin when the difference is odd).
pub fn centre_crop(
    img: &GrayImage,
    crop_width: usize,
    crop_height: usize,
) -> Result<GrayImage, PreprocessError> {
    let o = crop_origin(img.size(), (crop_width, crop_height))?;
    let data = crop_plane(img.data(), img.width(), o, (crop_width, crop_height));
    Ok(GrayImage::new(crop_width, crop_height, data)?)
}

/// How a flow field becomes the flow predictor's input (REFERENCE.md section 3).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, schemars::JsonSchema)]
#[serde(default, deny_unknown_fields)]
pub struct NetworkInputParams {
    /// Side of the square network input, pixels. Paper: 64.
    pub size_px: usize,
    /// Flow magnitude, in pixels of an image `reference_width_px` wide, that maps to
    /// +-0.5. Paper: 15 px at 640x480.
    pub clip_px: f32,
    /// Width of the image the clip bound refers to, pixels. Paper: 640.
    pub reference_width_px: usize,
}

impl Default for NetworkInputParams {
    fn default() -> Self {
        Self {
            size_px: 64,
            clip_px: 15.0,
            reference_width_px: 640,
        }
    }
}

/// The network input of a flow field: `[2, size, size]` row-major (channel u, then v).
///
/// Steps, as in the paper's reference pipeline: express the flow in pixels of a
/// `reference_width_px`-wide image, scale so that `clip_px` maps to 0.5 and clip to
/// [-0.5, 0.5] (the reference stored flow as 8-bit images with that bound); resize each
/// channel independently so the shorter side is `size_px` (antialiased bilinear); centre
/// crop to `size_px x size_px`. Values are not rescaled by the resize: they are
/// normalised displacements of the reference resolution.
pub fn network_input(
    flow: &FlowField,
    params: &NetworkInputParams,
) -> Result<Vec<f32>, PreprocessError> {
    if params.size_px == 0 {
        return Err(PreprocessError::InvalidParams {
            field: "size_px",
            reason: "must be positive".into(),
        });
    }
    if !(params.clip_px.is_finite() && params.clip_px > 0.0) {
        return Err(PreprocessError::InvalidParams {
            field: "clip_px",
            reason: format!("must be a positive number, got {}", params.clip_px),
        });
    }
    if params.reference_width_px == 0 {
        return Err(PreprocessError::InvalidParams {
            field: "reference_width_px",
            reason: "must be positive".into(),
        });
    }
    let (w, h) = flow.size();
    if w == 0 || h == 0 {
        return Err(ImageError::Empty {
            width: w,
            height: h,
        }
        .into());
    }
    let to_reference = params.reference_width_px as f32 / w as f32;
    let k = to_reference * 0.5 / params.clip_px;
    // NaN would survive clamp; a non-finite flow value is treated as "no motion known".
    let norm = |a: &f32| {
        let s = a * k;
        if s.is_finite() {
            s.clamp(-0.5, 0.5)
        } else if s.is_nan() {
            0.0
        } else {
            s.signum() * 0.5
        }
    };
    let scaled = FlowField::new(
        w,
        h,
        flow.u.iter().map(norm).collect(),
        flow.v.iter().map(norm).collect(),
    )?;
    let n = params.size_px;
    let (rw, rh) = network_resize((w, h), n);
    let resized = resize_flow(&scaled, rw, rh, ResizeFilter::Bilinear, false)?;
    let o = crop_origin((rw, rh), (n, n))?;
    let mut out = crop_plane(&resized.u, rw, o, (n, n));
    out.extend(crop_plane(&resized.v, rw, o, (n, n)));
    Ok(out)
}

/// Size of the resized image before the centre crop: the shorter side becomes `n`.
fn network_resize((w, h): (usize, usize), n: usize) -> (usize, usize) {
    if w <= h {
        (
            n,
            ((h as f64 * n as f64 / w as f64).round() as usize).max(n),
        )
    } else {
        (
            ((w as f64 * n as f64 / h as f64).round() as usize).max(n),
            n,
        )
    }
}

/// The pixels of the network input that a body mask leaves valid: `excluded` (true = robot
/// body, `width x height`, the flow's resolution) goes through the same resize and crop as
/// [`network_input`]; an input pixel is valid when less than half of its footprint is
/// excluded. Row-major `size_px x size_px`.
pub fn network_mask(
    excluded: &[bool],
    width: usize,
    height: usize,
    params: &NetworkInputParams,
) -> Result<Vec<bool>, PreprocessError> {
    let img = GrayImage::new(
        width,
        height,
        excluded
            .iter()
            .map(|&e| if e { 1.0 } else { 0.0 })
            .collect(),
    )?;
    if width == 0 || height == 0 {
        return Err(ImageError::Empty { width, height }.into());
    }
    if params.size_px == 0 {
        return Err(PreprocessError::InvalidParams {
            field: "size_px",
            reason: "must be positive".into(),
        });
    }
    let n = params.size_px;
    let (rw, rh) = network_resize((width, height), n);
    let resized = resize(&img, rw, rh, ResizeFilter::Bilinear)?;
    let cropped = centre_crop(&resized, n, n)?;
    Ok(cropped.data().iter().map(|&f| f < 0.5).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn network_mask_follows_the_input_geometry() {
        // 128x96 -> 85x64 -> crop 64x64 at x0 = 10. Excluding source columns < 50 puts the
        // edge at source x = 49.5, i.e. resized x = 50 * 85 / 128 - 0.5 = 32.7, so resized
        // columns >= 33 are mostly valid: input columns >= 23.
        let (w, h) = (128, 96);
        let excluded: Vec<bool> = (0..w * h).map(|i| i % w < 50).collect();
        let valid = network_mask(&excluded, w, h, &NetworkInputParams::default()).unwrap();
        assert_eq!(valid.len(), 64 * 64);
        let row: Vec<bool> = valid[10 * 64..11 * 64].to_vec();
        let first_valid = row.iter().position(|&v| v).unwrap();
        assert_eq!(first_valid, 23);
        assert!(row[first_valid..].iter().all(|&v| v));
        assert!(valid.chunks(64).all(|r| r == row.as_slice()));
        assert!(network_mask(&excluded[1..], w, h, &NetworkInputParams::default()).is_err());
    }

    #[test]
    fn one_gray_formula_keeps_both_roundings_bit_for_bit() {
        // The two expressions the callers wrote out before they shared
        // gray_from_rgb_pixel: on 8-bit values, and on 0..=1 floats scaled by 255.
        for r in (0..=255u8).step_by(3) {
            for g in (0..=255u8).step_by(5) {
                for b in (0..=255u8).step_by(7) {
                    let old_u8 = 0.299 * r as f32 + 0.587 * g as f32 + 0.114 * b as f32;
                    let got = gray_from_rgb(&[r, g, b], 1, 1).unwrap().data()[0];
                    assert_eq!(got.to_bits(), old_u8.to_bits(), "{r} {g} {b}");
                    let unit = [r, g, b].map(|v| f32::from(v) / 255.0);
                    let old_unit = 255.0 * (0.299 * unit[0] + 0.587 * unit[1] + 0.114 * unit[2]);
                    let got = GrayImage::from_unit_rgb(1, 1, &unit).unwrap().data()[0];
                    assert_eq!(got.to_bits(), old_unit.to_bits(), "{r} {g} {b}");
                }
            }
        }
        assert!(matches!(
            GrayImage::from_unit_rgb(2, 2, &[0.0; 11]),
            Err(ImageError::BufferSize { expected: 12, .. })
        ));
    }

    #[test]
    fn gray_from_rgb_uses_bt601_and_checks_size() {
        let g = gray_from_rgb(&[255, 0, 0, 0, 255, 0, 0, 0, 255, 10, 10, 10], 2, 2).unwrap();
        let expect = [0.299 * 255.0, 0.587 * 255.0, 0.114 * 255.0, 10.0];
        for (a, b) in g.data().iter().zip(expect) {
            assert!((a - b).abs() < 1e-3, "{a} vs {b}");
        }
        assert!(matches!(
            gray_from_rgb(&[0; 11], 2, 2),
            Err(PreprocessError::RgbBufferSize { expected: 12, .. })
        ));
    }

    #[test]
    fn equalisation_matches_opencv_formula() {
        // Values 10 (x2), 20 (x1), 30 (x1): cdf 2, 3, 4; cdf_min 2 -> 0, 128 (127.5), 255.
        let img = GrayImage::new(2, 2, vec![10.0, 10.0, 20.0, 30.0]).unwrap();
        let eq = equalize_histogram(&img).unwrap();
        assert_eq!(eq.data(), &[0.0, 0.0, 128.0, 255.0]);
        let flat = GrayImage::new(2, 1, vec![7.0, 7.0]).unwrap();
        assert_eq!(equalize_histogram(&flat).unwrap(), flat);
        let mut bad = GrayImage::zeros(2, 2);
        bad.data_mut()[0] = f32::INFINITY;
        assert!(equalize_histogram(&bad).is_err());
    }

    #[test]
    fn resize_preserves_constants_and_linear_ramps() {
        let c = GrayImage::from_fn(37, 23, |_, _| 42.0);
        for f in [ResizeFilter::Bilinear, ResizeFilter::Area] {
            for (w, h) in [(10, 7), (64, 64), (37, 23), (80, 50)] {
                let r = resize(&c, w, h, f).unwrap();
                assert!(
                    r.data().iter().all(|v| (v - 42.0).abs() < 1e-3),
                    "{f:?} {w}x{h}"
                );
            }
        }
        // A horizontal ramp halved in width stays a ramp through the same values at the
        // mapped centres (symmetric kernels reproduce linear functions away from borders).
        let ramp = GrayImage::from_fn(40, 4, |x, _| x as f32);
        let r = resize(&ramp, 20, 4, ResizeFilter::Bilinear).unwrap();
        for x in 2..18 {
            let expect = (x as f32 + 0.5) * 2.0 - 0.5;
            assert!(
                (r.get(x, 1) - expect).abs() < 1e-3,
                "x={x}: {}",
                r.get(x, 1)
            );
        }
    }

    #[test]
    fn area_downscale_by_two_averages_blocks() {
        let img = GrayImage::new(4, 2, vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0, 12.0, 14.0]).unwrap();
        let r = resize(&img, 2, 1, ResizeFilter::Area).unwrap();
        assert_eq!(r.data(), &[5.0, 9.0]);
    }

    #[test]
    fn whole_factor_shrinking_equals_the_general_area_filter() {
        let img = GrayImage::from_fn(24, 18, |x, y| ((x * 37 + y * 101) % 255) as f32);
        for (w, h) in [(12, 9), (8, 6), (24, 6), (6, 18)] {
            let fast = resize(&img, w, h, ResizeFilter::Area).unwrap();
            let p = (
                plan(24, w, ResizeFilter::Area),
                plan(18, h, ResizeFilter::Area),
            );
            let rows = apply_rows(img.data(), 24, 18, &p.0);
            let general = apply_cols(&rows, w, 18, &p.1);
            for (a, b) in fast.data().iter().zip(&general) {
                assert!((a - b).abs() < 1e-3, "{w}x{h}: {a} vs {b}");
            }
        }
    }

    #[test]
    fn antialiasing_suppresses_aliasing() {
        // A 1-px checkerboard has mean 127.5; antialiased downscaling by 4 must land near
        // it everywhere instead of sampling the pattern.
        let img = GrayImage::from_fn(64, 64, |x, y| if (x + y) % 2 == 0 { 255.0 } else { 0.0 });
        let r = resize(&img, 16, 16, ResizeFilter::Bilinear).unwrap();
        assert!(r.data().iter().all(|v| (v - 127.5).abs() < 20.0));
    }

    #[test]
    fn centre_crop_takes_the_middle() {
        let img = GrayImage::from_fn(6, 4, |x, y| (10 * y + x) as f32);
        let c = centre_crop(&img, 2, 2).unwrap();
        assert_eq!(c.data(), &[12.0, 13.0, 22.0, 23.0]);
        assert!(matches!(
            centre_crop(&img, 7, 2),
            Err(PreprocessError::CropTooLarge { .. })
        ));
        assert!(matches!(
            centre_crop(&img, 0, 2),
            Err(PreprocessError::EmptyTarget { .. })
        ));
    }

    #[test]
    fn flow_resize_scales_vectors_on_request() {
        let f = FlowField::from_fn(40, 30, |_, _| (2.0, -4.0));
        let half = resize_flow(&f, 20, 15, ResizeFilter::Area, true).unwrap();
        assert!(half.u.iter().all(|u| (u - 1.0).abs() < 1e-5));
        assert!(half.v.iter().all(|v| (v + 2.0).abs() < 1e-5));
        let same = resize_flow(&f, 20, 15, ResizeFilter::Area, false).unwrap();
        assert!(same.u.iter().all(|u| (u - 2.0).abs() < 1e-5));
    }

    #[test]
    fn network_input_scales_clips_and_crops() {
        let p = NetworkInputParams::default();
        // At 320x240, 7.5 px equals 15 px at 640 wide: maps to exactly 0.5. 3 px -> 0.2.
        let f = FlowField::from_fn(320, 240, |x, _| {
            if x < 160 {
                (3.0, -100.0)
            } else {
                (7.5, f32::NAN)
            }
        });
        let t = network_input(&f, &p).unwrap();
        assert_eq!(t.len(), 2 * 64 * 64);
        // Shorter side 240 -> 64, width 320 -> 85, centre crop keeps columns 10..74.
        assert!((t[0] - 0.2).abs() < 1e-5);
        assert!((t[63] - 0.5).abs() < 1e-5);
        let v = &t[64 * 64..];
        assert!((v[0] + 0.5).abs() < 1e-6, "clipped");
        assert!(v[63].abs() < 1e-6, "NaN becomes zero");
        assert!(t.iter().all(|a| (-0.5..=0.5).contains(a)));
        let bad = NetworkInputParams { clip_px: 0.0, ..p };
        assert!(matches!(
            network_input(&f, &bad),
            Err(PreprocessError::InvalidParams {
                field: "clip_px",
                ..
            })
        ));
    }
}
