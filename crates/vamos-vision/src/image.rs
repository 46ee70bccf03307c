//! Image and flow-field containers shared by every vision kernel.
//!
//! Gray images are row-major `f32` in **intensity units of an 8-bit image (0..=255)**:
//! the TV-L1 data term (`lambda`) is tuned for that range, as in OpenCV. Flow fields are
//! planar (one `Vec<f32>` per component) so that the kernels can stream each component
//! through SIMD-friendly loops.
//!
//! This module may import only `std`, `image` (file decoding) and `thiserror`.

use std::path::Path;

/// ITU-R BT.601 luma of one RGB pixel, in the unit of its channels: vamos's one gray
/// formula. [`crate::preprocess::gray_from_rgb`] applies it to 8-bit values
/// (0..=255 in, 0..=255 out), [`GrayImage::from_unit_rgb`] to 0..=1 floats (scaled to
/// 0..=255 afterwards).
#[inline]
pub fn gray_from_rgb_pixel([r, g, b]: [f32; 3]) -> f32 {
    0.299 * r + 0.587 * g + 0.114 * b
}

/// Errors of image construction, validation and file I/O.
#[derive(Debug, thiserror::Error)]
pub enum ImageError {
    /// The pixel buffer does not have `width * height` elements.
    #[error("pixel buffer has {actual} values but a {width}x{height} image needs {expected}")]
    BufferSize {
        /// Image width in pixels.
        width: usize,
        /// Image height in pixels.
        height: usize,
        /// `width * height`.
        expected: usize,
        /// Length of the buffer that was given.
        actual: usize,
    },
    /// The image has no pixels.
    #[error("image is empty ({width}x{height})")]
    Empty {
        /// Image width in pixels.
        width: usize,
        /// Image height in pixels.
        height: usize,
    },
    /// A pixel is NaN or infinite.
    #[error("pixel ({x}, {y}) is not finite ({value})")]
    NonFinite {
        /// Column of the first offending pixel.
        x: usize,
        /// Row of the first offending pixel.
        y: usize,
        /// Its value.
        value: f32,
    },
    /// A file could not be read or decoded.
    #[error("cannot read image {path}: {reason}")]
    Read {
        /// The file.
        path: String,
        /// What went wrong.
        reason: String,
    },
    /// A file could not be encoded or written.
    #[error("cannot write image {path}: {reason}")]
    Write {
        /// The file.
        path: String,
        /// What went wrong.
        reason: String,
    },
}

/// A single-channel `f32` image, row-major, no padding.
#[derive(Clone, Debug, PartialEq)]
pub struct GrayImage {
    width: usize,
    height: usize,
    data: Vec<f32>,
}

impl GrayImage {
    /// Wraps a row-major buffer; fails when its length is not `width * height`.
    pub fn new(width: usize, height: usize, data: Vec<f32>) -> Result<Self, ImageError> {
        let expected = width * height;
        if data.len() != expected {
            return Err(ImageError::BufferSize {
                width,
                height,
                expected,
                actual: data.len(),
            });
        }
        Ok(Self {
            width,
            height,
            data,
        })
    }

    /// An image filled with zeros.
    pub fn zeros(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            data: vec![0.0; width * height],
        }
    }

    /// Builds an image from `f(x, y)`.
    pub fn from_fn(width: usize, height: usize, mut f: impl FnMut(usize, usize) -> f32) -> Self {
        let mut data = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                data.push(f(x, y));
            }
        }
        Self {
            width,
            height,
            data,
        }
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// `(width, height)`.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Row-major pixels.
    pub fn data(&self) -> &[f32] {
        &self.data
    }

    /// Row-major pixels, mutable.
    pub fn data_mut(&mut self) -> &mut [f32] {
        &mut self.data
    }

    /// Consumes the image and returns its buffer.
    pub fn into_data(self) -> Vec<f32> {
        self.data
    }

    /// Row `y`.
    pub fn row(&self, y: usize) -> &[f32] {
        &self.data[y * self.width..(y + 1) * self.width]
    }

    /// Pixel at `(x, y)`; panics when out of bounds (callers index inside the image).
    pub fn get(&self, x: usize, y: usize) -> f32 {
        self.data[y * self.width + x]
    }

    /// Fails with [`ImageError::Empty`] or [`ImageError::NonFinite`] on unusable input.
    pub fn validate(&self) -> Result<(), ImageError> {
        if self.width == 0 || self.height == 0 {
            return Err(ImageError::Empty {
                width: self.width,
                height: self.height,
            });
        }
        if let Some(i) = self.data.iter().position(|v| !v.is_finite()) {
            return Err(ImageError::NonFinite {
                x: i % self.width,
                y: i / self.width,
                value: self.data[i],
            });
        }
        Ok(())
    }

    /// Gray (ITU-R BT.601 luma, 0..=255) from interleaved RGB floats in 0..=1, as `image`
    /// decodes files with more than 8 bits or with alpha (`to_rgb32f`): `255 *`
    /// [`gray_from_rgb_pixel`]. On 8-bit values divided by 255 this can differ from
    /// [`crate::preprocess::gray_from_rgb`] in the last bits (the scaling rounds),
    /// so each caller keeps the path it had and results stay bit for bit as they were.
    pub fn from_unit_rgb(width: usize, height: usize, rgb: &[f32]) -> Result<Self, ImageError> {
        let expected = 3 * width * height;
        if rgb.len() != expected {
            return Err(ImageError::BufferSize {
                width,
                height,
                expected,
                actual: rgb.len(),
            });
        }
        let data = rgb
            .chunks_exact(3)
            .map(|p| 255.0 * gray_from_rgb_pixel([p[0], p[1], p[2]]))
            .collect();
        Self::new(width, height, data)
    }

    /// Reads any PNG/JPEG file as gray (ITU-R BT.601 luma, 0..=255; 16-bit files scaled).
    pub fn load(path: &Path) -> Result<Self, ImageError> {
        let img = image::open(path).map_err(|e| ImageError::Read {
            path: path.display().to_string(),
            reason: e.to_string(),
        })?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        let out = if img.color().has_color() {
            // Colour files, 8-bit ones included, go through 0..=1 floats (as they always
            // have: gray_from_rgb on the 8-bit values could differ in the last bit).
            Self::from_unit_rgb(w, h, img.to_rgb32f().as_raw())?
        } else {
            // Gray files keep their exact values (8-bit: integers 0..=255).
            let data = match img.as_luma8() {
                Some(l8) => l8.as_raw().iter().map(|&v| v as f32).collect(),
                None => img.to_luma32f().pixels().map(|p| 255.0 * p[0]).collect(),
            };
            Self::new(w, h, data)?
        };
        out.validate()?;
        Ok(out)
    }

    /// Writes the image as an 8-bit PNG (values rounded and clamped to 0..=255).
    pub fn save_png(&self, path: &Path) -> Result<(), ImageError> {
        let bytes: Vec<u8> = self
            .data
            .iter()
            .map(|v| v.round().clamp(0.0, 255.0) as u8)
            .collect();
        let buf = image::GrayImage::from_raw(self.width as u32, self.height as u32, bytes)
            .ok_or_else(|| ImageError::Write {
                path: path.display().to_string(),
                reason: "buffer size mismatch".into(),
            })?;
        buf.save(path).map_err(|e| ImageError::Write {
            path: path.display().to_string(),
            reason: e.to_string(),
        })
    }
}

/// A depth image registered to a camera image (the same field of view, any resolution of
/// the same aspect ratio): metres along the optical axis, row-major. A value that is not
/// finite or not positive means no depth at that pixel (what depth cameras report where
/// they see nothing).
#[derive(Clone, Debug, PartialEq)]
pub struct DepthImage {
    width: usize,
    height: usize,
    metres: Vec<f32>,
}

/// Largest relative difference between a depth image's aspect ratio and its camera
/// image's: a depth image of another shape is not registered to it.
pub const DEPTH_ASPECT_TOLERANCE: f64 = 0.01;

impl DepthImage {
    /// Wraps a row-major buffer of metres; fails when it is empty or its length is not
    /// `width * height`.
    pub fn new(width: usize, height: usize, metres: Vec<f32>) -> Result<Self, ImageError> {
        if width == 0 || height == 0 {
            return Err(ImageError::Empty { width, height });
        }
        if metres.len() != width * height {
            return Err(ImageError::BufferSize {
                width,
                height,
                expected: width * height,
                actual: metres.len(),
            });
        }
        Ok(Self {
            width,
            height,
            metres,
        })
    }

    /// `(width, height)` in pixels.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Metres per pixel, row-major.
    pub fn metres(&self) -> &[f32] {
        &self.metres
    }

    /// Whether this depth image can be registered to a `width x height` camera image:
    /// the same aspect ratio within [`DEPTH_ASPECT_TOLERANCE`].
    pub fn fits(&self, width: usize, height: usize) -> bool {
        if width == 0 || height == 0 {
            return false;
        }
        let own = self.width as f64 / self.height as f64;
        let other = width as f64 / height as f64;
        (own / other - 1.0).abs() <= DEPTH_ASPECT_TOLERANCE
    }

    /// Samples the image at `width x height` (nearest pixel centre: depth is never
    /// blended across an object's edge) into `out`, with no depth (NaN) where the image
    /// has none. Memory is the output's, whatever the input's size.
    pub fn resample_into(&self, width: usize, height: usize, out: &mut Vec<f32>) {
        out.clear();
        out.reserve(width * height);
        let column = |x: usize| {
            (((x as f64 + 0.5) * self.width as f64 / width as f64) as usize).min(self.width - 1)
        };
        for y in 0..height {
            let sy = (((y as f64 + 0.5) * self.height as f64 / height as f64) as usize)
                .min(self.height - 1);
            let row = &self.metres[sy * self.width..(sy + 1) * self.width];
            out.extend((0..width).map(|x| {
                let d = row[column(x)];
                if d.is_finite() && d > 0.0 {
                    d
                } else {
                    f32::NAN
                }
            }));
        }
    }
}

/// A dense two-component flow field, planar.
///
/// `u[i]`, `v[i]` at pixel `i = y * width + x` are the **forward** displacement in
/// pixels of the content at `(x, y)` in the first image to `(x + u, y + v)` in the
/// second (x right, y down).
#[derive(Clone, Debug, PartialEq)]
pub struct FlowField {
    width: usize,
    height: usize,
    /// Horizontal component, pixels, positive to the right.
    pub u: Vec<f32>,
    /// Vertical component, pixels, positive downwards.
    pub v: Vec<f32>,
}

impl FlowField {
    /// A zero field.
    pub fn zeros(width: usize, height: usize) -> Self {
        Self {
            width,
            height,
            u: vec![0.0; width * height],
            v: vec![0.0; width * height],
        }
    }

    /// Wraps two planar buffers of `width * height` values each.
    pub fn new(width: usize, height: usize, u: Vec<f32>, v: Vec<f32>) -> Result<Self, ImageError> {
        let expected = width * height;
        for actual in [u.len(), v.len()] {
            if actual != expected {
                return Err(ImageError::BufferSize {
                    width,
                    height,
                    expected,
                    actual,
                });
            }
        }
        Ok(Self {
            width,
            height,
            u,
            v,
        })
    }

    /// Builds a field from `f(x, y) -> (u, v)`.
    pub fn from_fn(
        width: usize,
        height: usize,
        mut f: impl FnMut(usize, usize) -> (f32, f32),
    ) -> Self {
        let mut out = Self::zeros(width, height);
        for y in 0..height {
            for x in 0..width {
                let (a, b) = f(x, y);
                out.u[y * width + x] = a;
                out.v[y * width + x] = b;
            }
        }
        out
    }

    /// Width in pixels.
    pub fn width(&self) -> usize {
        self.width
    }

    /// Height in pixels.
    pub fn height(&self) -> usize {
        self.height
    }

    /// `(width, height)`.
    pub fn size(&self) -> (usize, usize) {
        (self.width, self.height)
    }

    /// Flow at `(x, y)`.
    pub fn get(&self, x: usize, y: usize) -> (f32, f32) {
        let i = y * self.width + x;
        (self.u[i], self.v[i])
    }

    /// Average endpoint error against `other` over the pixels where `valid` is true
    /// (all pixels when `valid` is `None`). Returns `None` when no pixel counts or the
    /// sizes differ.
    pub fn average_endpoint_error(&self, other: &FlowField, valid: Option<&[bool]>) -> Option<f64> {
        if self.size() != other.size() {
            return None;
        }
        let mut sum = 0.0f64;
        let mut n = 0usize;
        for i in 0..self.u.len() {
            if valid.is_some_and(|m| !m[i]) {
                continue;
            }
            let du = (self.u[i] - other.u[i]) as f64;
            let dv = (self.v[i] - other.v[i]) as f64;
            sum += (du * du + dv * dv).sqrt();
            n += 1;
        }
        (n > 0).then(|| sum / n as f64)
    }

    /// The field with both components negated (backward <-> forward convention).
    pub fn negated(&self) -> Self {
        Self {
            width: self.width,
            height: self.height,
            u: self.u.iter().map(|a| -a).collect(),
            v: self.v.iter().map(|a| -a).collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn buffer_size_is_checked() {
        let err = GrayImage::new(3, 2, vec![0.0; 5]).unwrap_err();
        assert!(matches!(
            err,
            ImageError::BufferSize {
                expected: 6,
                actual: 5,
                ..
            }
        ));
        assert!(FlowField::new(2, 2, vec![0.0; 4], vec![0.0; 3]).is_err());
    }

    #[test]
    fn depth_images_resample_by_nearest_pixel_and_mark_missing_depth() {
        assert!(matches!(
            DepthImage::new(0, 2, vec![]),
            Err(ImageError::Empty { .. })
        ));
        assert!(matches!(
            DepthImage::new(2, 2, vec![1.0; 3]),
            Err(ImageError::BufferSize { .. })
        ));
        // 4x2 in metres, with a hole (0), a NaN and a negative value.
        let d = DepthImage::new(4, 2, vec![1.0, 2.0, 0.0, 4.0, 5.0, f32::NAN, -1.0, 8.0]).unwrap();
        assert!(d.fits(8, 4) && d.fits(640, 320) && !d.fits(4, 3) && !d.fits(0, 1));
        let mut out = vec![7.0; 3];
        d.resample_into(2, 1, &mut out);
        // Output pixel centres 0.5 and 1.5 of 2 sample input columns 1 and 3 of row 1.
        assert_eq!(out.len(), 2);
        assert!(out[0].is_nan(), "{out:?}");
        assert_eq!(out[1], 8.0);
        d.resample_into(8, 4, &mut out);
        let row0: Vec<String> = out[..8].iter().map(|v| format!("{v}")).collect();
        assert_eq!(row0, ["1", "1", "2", "2", "NaN", "NaN", "4", "4"]);
        let row3: Vec<String> = out[24..].iter().map(|v| format!("{v}")).collect();
        assert_eq!(row3, ["5", "5", "NaN", "NaN", "NaN", "NaN", "8", "8"]);
    }

    #[test]
    fn validate_reports_first_non_finite_pixel() {
        let mut img = GrayImage::zeros(4, 3);
        img.data_mut()[6] = f32::NAN;
        match img.validate() {
            Err(ImageError::NonFinite { x, y, .. }) => assert_eq!((x, y), (2, 1)),
            other => panic!("unexpected {other:?}"),
        }
        assert!(matches!(
            GrayImage::zeros(0, 3).validate(),
            Err(ImageError::Empty { .. })
        ));
    }

    #[test]
    fn endpoint_error_of_known_offset() {
        let a = FlowField::zeros(4, 4);
        let b = FlowField::from_fn(4, 4, |_, _| (3.0, 4.0));
        assert_eq!(a.average_endpoint_error(&b, None), Some(5.0));
        let mask: Vec<bool> = (0..16).map(|i| i < 8).collect();
        assert_eq!(a.average_endpoint_error(&b, Some(&mask)), Some(5.0));
        assert_eq!(
            a.average_endpoint_error(&FlowField::zeros(3, 4), None),
            None
        );
    }

    #[test]
    fn png_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.png");
        let img = GrayImage::from_fn(7, 5, |x, y| (x * 30 + y) as f32);
        img.save_png(&path).unwrap();
        assert_eq!(GrayImage::load(&path).unwrap(), img);
        let err = GrayImage::load(&dir.path().join("missing.png")).unwrap_err();
        assert!(err.to_string().contains("missing.png"));
    }
}
