//! Image decoding to [`GrayImage`], once for every source: images streamed live to the
//! service, `sensor_msgs/msg/Image` and `sensor_msgs/msg/CompressedImage` read from bags.
//!
//! One encoding table ([`Encoding::from_name`], any letter case) and one gray conversion:
//! 8-bit colour goes through [`gray_from_rgb`] (ITU-R BT.601 luma on 0..=255), 8-bit gray
//! is exact, 16-bit gray (`mono16`, `16UC1`) is scaled by 255/65535, `32FC1` is taken as
//! is (NaN and infinities become 0). A JPEG or PNG file with more than 8 bits of colour
//! (or alpha) is converted by [`GrayImage::from_unit_rgb`], the same BT.601 formula on
//! 0..=1 floats (as [`GrayImage::load`] reads colour files).

use super::ros::{MAX_IMAGE_SIDE, MessageError, check_image_size};
use vamos_vision::preprocess::gray_from_rgb;
use vamos_vision::{DepthImage, GrayImage};

/// An image encoding vamos decodes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// Interleaved 8-bit red, green, blue.
    Rgb8,
    /// Interleaved 8-bit blue, green, red.
    Bgr8,
    /// Interleaved 8-bit red, green, blue, alpha.
    Rgba8,
    /// Interleaved 8-bit blue, green, red, alpha.
    Bgra8,
    /// 8-bit gray (`mono8`, `8UC1`).
    Mono8,
    /// 16-bit gray (`mono16`, `16UC1`).
    Mono16,
    /// 32-bit float gray (`32FC1`).
    Float32,
    /// A JPEG file.
    Jpeg,
    /// A PNG file.
    Png,
}

impl Encoding {
    /// The encoding named `name`, in any letter case: the ROS raw encodings (`rgb8`,
    /// `bgr8`, `rgba8`, `bgra8`, `mono8`/`8UC1`, `mono16`/`16UC1`, `32FC1`) and the files
    /// `jpeg`/`jpg` and `png`.
    pub fn from_name(name: &str) -> Option<Self> {
        Some(match name.to_ascii_lowercase().as_str() {
            "rgb8" => Self::Rgb8,
            "bgr8" => Self::Bgr8,
            "rgba8" => Self::Rgba8,
            "bgra8" => Self::Bgra8,
            "mono8" | "8uc1" => Self::Mono8,
            "mono16" | "16uc1" => Self::Mono16,
            "32fc1" => Self::Float32,
            "jpeg" | "jpg" => Self::Jpeg,
            "png" => Self::Png,
            _ => return None,
        })
    }

    /// The file format a `CompressedImage` format string names (`jpeg`, `png`,
    /// `rgb8; jpeg compressed bgr8`, any letter case).
    pub fn from_compressed_format(format: &str) -> Option<Self> {
        let lower = format.to_ascii_lowercase();
        if lower.contains("jpeg") || lower.contains("jpg") {
            Some(Self::Jpeg)
        } else if lower.contains("png") {
            Some(Self::Png)
        } else {
            None
        }
    }

    /// Bytes per pixel of a raw encoding; `None` for files.
    pub fn bytes_per_pixel(self) -> Option<usize> {
        match self {
            Self::Rgb8 | Self::Bgr8 => Some(3),
            Self::Rgba8 | Self::Bgra8 | Self::Float32 => Some(4),
            Self::Mono8 => Some(1),
            Self::Mono16 => Some(2),
            Self::Jpeg | Self::Png => None,
        }
    }

    fn file_format(self) -> Option<image::ImageFormat> {
        match self {
            Self::Jpeg => Some(image::ImageFormat::Jpeg),
            Self::Png => Some(image::ImageFormat::Png),
            _ => None,
        }
    }
}

/// An image as it was sent or recorded: raw pixel rows `step` bytes apart, or a JPEG/PNG
/// file (then `width`, `height` and `step` are unused: the file says).
#[derive(Debug, Clone, Copy)]
pub struct EncodedImage<'a> {
    /// The encoding or format as declared (for messages).
    pub name: &'a str,
    /// The encoding, when vamos decodes it.
    pub encoding: Option<Encoding>,
    /// Columns (raw).
    pub width: u32,
    /// Rows (raw).
    pub height: u32,
    /// Bytes per row (raw).
    pub step: u32,
    /// Whether multi-byte pixels are big endian (raw).
    pub big_endian: bool,
    /// The pixels or the file.
    pub data: &'a [u8],
}

/// A declared image size that was checked, and the memory its decoding holds at most.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct CheckedSize {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Bytes the decoding holds at its peak (decoded pixels, conversions, the gray f32).
    pub peak_bytes: u64,
}

impl<'a> EncodedImage<'a> {
    /// Raw pixels of encoding `name` (see [`Encoding::from_name`]).
    pub fn raw(
        name: &'a str,
        width: u32,
        height: u32,
        step: u32,
        big_endian: bool,
        data: &'a [u8],
    ) -> Self {
        Self {
            name,
            encoding: Encoding::from_name(name),
            width,
            height,
            step,
            big_endian,
            data,
        }
    }

    /// A compressed image of format string `format` (see
    /// [`Encoding::from_compressed_format`]).
    pub fn compressed(format: &'a str, data: &'a [u8]) -> Self {
        Self {
            name: format,
            encoding: Encoding::from_compressed_format(format),
            width: 0,
            height: 0,
            step: 0,
            big_endian: false,
            data,
        }
    }

    fn known(&self) -> Result<Encoding, MessageError> {
        self.encoding.ok_or_else(|| MessageError::UnknownEncoding {
            encoding: self.name.to_string(),
        })
    }

    fn decode_error(&self, reason: String) -> MessageError {
        MessageError::Decode {
            format: self.name.to_string(),
            reason,
        }
    }

    /// The declared size, checked (not empty, no side over [`MAX_IMAGE_SIDE`], at most
    /// `max_pixels`; raw rows against `step` and the data), nothing decoded.
    pub fn check(&self, max_pixels: usize) -> Result<CheckedSize, MessageError> {
        let encoding = self.known()?;
        let Some(bpp) = encoding.bytes_per_pixel() else {
            let (w, h) = self.file_dimensions(encoding)?;
            check_image_size(w, h, max_pixels)?;
            // Decoded pixels (up to 16-bit RGBA), a float conversion of colour, the gray f32.
            return Ok(CheckedSize {
                width: w,
                height: h,
                peak_bytes: (w * h) as u64 * 24,
            });
        };
        let (w, h, step) = (
            self.width as usize,
            self.height as usize,
            self.step as usize,
        );
        check_image_size(w, h, max_pixels)?;
        if step < w * bpp {
            return Err(MessageError::BadSize {
                reason: format!(
                    "step {step} is less than width {w} x {bpp} bytes of {}",
                    self.name
                ),
            });
        }
        // The last row needs only its pixels, not the full step.
        let needed = step * (h - 1) + w * bpp;
        if self.data.len() < needed {
            return Err(MessageError::BadSize {
                reason: format!(
                    "{} data bytes, {w}x{h} {} with step {step} needs {needed}",
                    self.data.len(),
                    self.name
                ),
            });
        }
        Ok(CheckedSize {
            width: w,
            height: h,
            peak_bytes: (w * h) as u64 * 4,
        })
    }

    /// Width and height of a file from its header, nothing decoded.
    pub fn dimensions(&self) -> Result<(usize, usize), MessageError> {
        let encoding = self.known()?;
        match encoding.bytes_per_pixel() {
            Some(_) => Ok((self.width as usize, self.height as usize)),
            None => self.file_dimensions(encoding),
        }
    }

    fn file_dimensions(&self, encoding: Encoding) -> Result<(usize, usize), MessageError> {
        let format = encoding
            .file_format()
            .ok_or_else(|| self.decode_error("".into()))?;
        image::ImageReader::with_format(std::io::Cursor::new(self.data), format)
            .into_dimensions()
            .map(|(w, h)| (w as usize, h as usize))
            .map_err(|e| self.decode_error(e.to_string()))
    }

    /// Decodes to gray (see the module docs); the declared size is checked against
    /// `max_pixels` before anything is decoded.
    pub fn to_gray(&self, max_pixels: usize) -> Result<GrayImage, MessageError> {
        let size = self.check(max_pixels)?;
        let encoding = self.known()?;
        match encoding.file_format() {
            Some(format) => self.file_to_gray(format, size, max_pixels),
            None => self.raw_to_gray(encoding, size),
        }
    }

    /// Decodes a depth image (REP 118): `16UC1`/`mono16` in millimetres or `32FC1` in
    /// metres, raw rows only; 0, NaN and infinities are "no depth". The declared size is
    /// checked against `max_pixels` before anything is decoded.
    pub fn to_depth(&self, max_pixels: usize) -> Result<DepthImage, MessageError> {
        let unsupported = || MessageError::Decode {
            format: self.name.to_string(),
            reason: "a depth image must be raw 16UC1 (millimetres) or 32FC1 (metres)".into(),
        };
        let encoding = self.encoding.ok_or_else(unsupported)?;
        if !matches!(encoding, Encoding::Mono16 | Encoding::Float32) {
            return Err(unsupported());
        }
        let size = self.check(max_pixels)?;
        let (w, h) = (size.width, size.height);
        let step = self.step as usize;
        let be = self.big_endian;
        let rows = (0..h).map(|y| &self.data[y * step..]);
        let metres: Vec<f32> = if encoding == Encoding::Mono16 {
            rows.flat_map(|r| {
                r[..2 * w].chunks_exact(2).map(|p| {
                    let mm = if be {
                        u16::from_be_bytes([p[0], p[1]])
                    } else {
                        u16::from_le_bytes([p[0], p[1]])
                    };
                    if mm == 0 {
                        f32::NAN
                    } else {
                        f32::from(mm) / 1000.0
                    }
                })
            })
            .collect()
        } else {
            rows.flat_map(|r| {
                r[..4 * w].chunks_exact(4).map(|p| {
                    let a = [p[0], p[1], p[2], p[3]];
                    if be {
                        f32::from_be_bytes(a)
                    } else {
                        f32::from_le_bytes(a)
                    }
                })
            })
            .collect()
        };
        DepthImage::new(w, h, metres).map_err(|e| MessageError::BadSize {
            reason: e.to_string(),
        })
    }

    fn raw_to_gray(
        &self,
        encoding: Encoding,
        size: CheckedSize,
    ) -> Result<GrayImage, MessageError> {
        let (w, h) = (size.width, size.height);
        let step = self.step as usize;
        let be = self.big_endian;
        let rows = (0..h).map(|y| &self.data[y * step..]);
        let bad = |e: String| MessageError::BadSize { reason: e };
        // Colour: the rows as packed RGB, then the one gray conversion.
        let colour = |channels: usize, rgb_at: [usize; 3]| {
            let mut rgb = Vec::with_capacity(3 * w * h);
            for row in rows.clone() {
                for p in row[..channels * w].chunks_exact(channels) {
                    rgb.extend(rgb_at.map(|i| p[i]));
                }
            }
            gray_from_rgb(&rgb, w, h).map_err(|e| bad(e.to_string()))
        };
        let data: Vec<f32> = match encoding {
            Encoding::Rgb8 if step == 3 * w => {
                return gray_from_rgb(&self.data[..3 * w * h], w, h)
                    .map_err(|e| bad(e.to_string()));
            }
            Encoding::Rgb8 => return colour(3, [0, 1, 2]),
            Encoding::Bgr8 => return colour(3, [2, 1, 0]),
            Encoding::Rgba8 => return colour(4, [0, 1, 2]),
            Encoding::Bgra8 => return colour(4, [2, 1, 0]),
            Encoding::Mono8 => rows
                .flat_map(|r| r[..w].iter().map(|&v| f32::from(v)))
                .collect(),
            Encoding::Mono16 => rows
                .flat_map(|r| {
                    r[..2 * w].chunks_exact(2).map(|p| {
                        let v = if be {
                            u16::from_be_bytes([p[0], p[1]])
                        } else {
                            u16::from_le_bytes([p[0], p[1]])
                        };
                        f32::from(v) * (255.0 / 65535.0)
                    })
                })
                .collect(),
            Encoding::Float32 => rows
                .flat_map(|r| {
                    r[..4 * w].chunks_exact(4).map(|p| {
                        let a = [p[0], p[1], p[2], p[3]];
                        let v = if be {
                            f32::from_be_bytes(a)
                        } else {
                            f32::from_le_bytes(a)
                        };
                        if v.is_finite() { v } else { 0.0 }
                    })
                })
                .collect(),
            // Invariant: files are decoded by `file_to_gray`.
            Encoding::Jpeg | Encoding::Png => {
                return Err(MessageError::UnknownEncoding {
                    encoding: self.name.to_string(),
                });
            }
        };
        GrayImage::new(w, h, data).map_err(|e| bad(e.to_string()))
    }

    /// Decodes to packed 8-bit RGB (for re-encoding: `vamos episode copy --jpeg`): 8-bit
    /// raw colour and gray encodings and JPEG / PNG files; 16-bit and float images are
    /// refused (their scaling is not a colour image's). The declared size is checked
    /// against `max_pixels` first.
    pub fn to_rgb8(&self, max_pixels: usize) -> Result<(usize, usize, Vec<u8>), MessageError> {
        let size = self.check(max_pixels)?;
        let encoding = self.known()?;
        let (w, h) = (size.width, size.height);
        if let Some(format) = encoding.file_format() {
            let img = image::load_from_memory_with_format(self.data, format)
                .map_err(|e| self.decode_error(e.to_string()))?;
            let (fw, fh) = (img.width() as usize, img.height() as usize);
            check_image_size(fw, fh, max_pixels)?;
            return Ok((fw, fh, img.to_rgb8().into_raw()));
        }
        let step = self.step as usize;
        let order: (usize, [usize; 3]) = match encoding {
            Encoding::Rgb8 => (3, [0, 1, 2]),
            Encoding::Bgr8 => (3, [2, 1, 0]),
            Encoding::Rgba8 => (4, [0, 1, 2]),
            Encoding::Bgra8 => (4, [2, 1, 0]),
            Encoding::Mono8 => (1, [0, 0, 0]),
            _ => {
                return Err(self.decode_error(
                    "only 8-bit images (rgb8, bgr8, rgba8, bgra8, mono8, JPEG, PNG) convert to RGB"
                        .into(),
                ));
            }
        };
        let (channels, at) = order;
        let mut rgb = Vec::with_capacity(3 * w * h);
        for y in 0..h {
            let row = &self.data[y * step..y * step + channels * w];
            for p in row.chunks_exact(channels) {
                rgb.extend(at.map(|i| p[i]));
            }
        }
        Ok((w, h, rgb))
    }

    fn file_to_gray(
        &self,
        format: image::ImageFormat,
        size: CheckedSize,
        max_pixels: usize,
    ) -> Result<GrayImage, MessageError> {
        let mut reader = image::ImageReader::with_format(std::io::Cursor::new(self.data), format);
        let mut limits = image::Limits::default();
        // The header was checked; the limits hold the decoder to what it declared.
        let side = u32::try_from(MAX_IMAGE_SIDE).unwrap_or(u32::MAX);
        limits.max_image_width = Some(side);
        limits.max_image_height = Some(side);
        limits.max_alloc = Some((size.width * size.height) as u64 * 8 + (1 << 20));
        reader.limits(limits);
        let img = reader
            .decode()
            .map_err(|e| self.decode_error(e.to_string()))?;
        let (w, h) = (img.width() as usize, img.height() as usize);
        check_image_size(w, h, max_pixels)?;
        if img.color().has_color() {
            if let Some(rgb) = img.as_rgb8() {
                return gray_from_rgb(rgb.as_raw(), w, h)
                    .map_err(|e| self.decode_error(e.to_string()));
            }
            // More than 8 bits (or alpha): the same formula on 0..=1 floats.
            return GrayImage::from_unit_rgb(w, h, img.to_rgb32f().as_raw())
                .map_err(|e| self.decode_error(e.to_string()));
        }
        let data = match img.as_luma8() {
            Some(l8) => l8.as_raw().iter().map(|&v| f32::from(v)).collect(),
            None => img.to_luma32f().pixels().map(|p| 255.0 * p[0]).collect(),
        };
        GrayImage::new(w, h, data).map_err(|e| self.decode_error(e.to_string()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn one_table_in_any_case() {
        for name in ["8uc1", "8UC1", "MONO8", "mono8"] {
            assert_eq!(Encoding::from_name(name), Some(Encoding::Mono8), "{name}");
        }
        assert_eq!(Encoding::from_name("JPG"), Some(Encoding::Jpeg));
        assert_eq!(Encoding::from_name("yuv422"), None);
        assert_eq!(
            Encoding::from_compressed_format("rgb8; jpeg compressed bgr8"),
            Some(Encoding::Jpeg)
        );
    }

    #[test]
    fn depth_images_decode_millimetres_and_metres_and_refuse_other_encodings() {
        // 16UC1, big endian, padded rows: 1500 mm and a hole (0).
        let mm = [0x05u8, 0xdc, 0, 0, 9, 9];
        let d = EncodedImage::raw("16UC1", 2, 1, 6, true, &mm)
            .to_depth(100)
            .unwrap();
        assert_eq!(d.size(), (2, 1));
        assert_eq!(d.metres()[0], 1.5);
        assert!(d.metres()[1].is_nan());
        let m: Vec<u8> = [2.25f32, f32::INFINITY]
            .iter()
            .flat_map(|v| v.to_le_bytes())
            .collect();
        let d = EncodedImage::raw("32FC1", 1, 2, 4, false, &m)
            .to_depth(100)
            .unwrap();
        assert_eq!(d.metres()[0], 2.25);
        for name in ["rgb8", "mono8", "png", "yuv422"] {
            let err = EncodedImage::raw(name, 1, 1, 3, false, &[0, 0, 0])
                .to_depth(100)
                .unwrap_err();
            assert!(err.to_string().contains("16UC1"), "{name}: {err}");
        }
        // Sizes are checked before decoding.
        let err = EncodedImage::raw("32FC1", 4, 4, 16, false, &m)
            .to_depth(100)
            .unwrap_err();
        assert!(err.to_string().contains("needs"), "{err}");
        assert!(
            EncodedImage::raw("16UC1", 20, 20, 40, false, &[0; 800])
                .to_depth(100)
                .is_err()
        );
    }

    #[test]
    fn colour_orders_agree_with_gray_from_rgb() {
        let rgb = [10u8, 200, 30, 0, 0, 255];
        let want = gray_from_rgb(&rgb, 2, 1).unwrap();
        let bgra = [30u8, 200, 10, 1, 255, 0, 0, 1];
        let got = EncodedImage::raw("BGRA8", 2, 1, 8, false, &bgra)
            .to_gray(100)
            .unwrap();
        assert_eq!(got.data(), want.data());
        // Padded rows.
        let padded = [10u8, 200, 30, 0, 0, 255, 7, 7];
        let got = EncodedImage::raw("rgb8", 2, 1, 8, false, &padded)
            .to_gray(100)
            .unwrap();
        assert_eq!(got.data(), want.data());
    }
}
