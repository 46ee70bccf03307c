//! Flow fields on disk and on screen: Middlebury `.flo` files and the Middlebury colour
//! wheel (Baker et al., "A Database and Evaluation Methodology for Optical Flow").
//!
//! `.flo`: the float32 tag 202021.25, int32 width, int32 height, then `(u, v)` float32
//! pairs row-major, all little-endian. Colour coding: hue is the direction (the wheel's
//! 55 hues, red for flow pointing right... as Middlebury), saturation the magnitude
//! relative to the largest finite magnitude (or a given bound); beyond the bound the
//! colour darkens.
//!
//! Imports only [`super::image`].

use super::image::FlowField;
use std::io::{Read, Write};
use std::path::Path;

const FLO_TAG: f32 = 202_021.25;
/// Largest side accepted when reading a `.flo` file (guards against absurd headers).
const MAX_FLO_SIDE: usize = 1 << 15;

/// Errors of `.flo` reading and writing.
#[derive(Debug, thiserror::Error)]
pub enum FlowIoError {
    /// Opening, reading or writing failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not a `.flo` file.
    #[error("{path}: not a Middlebury .flo file (tag {tag}, expected 202021.25)")]
    BadTag {
        /// The file.
        path: String,
        /// The tag found.
        tag: f32,
    },
    /// The header's size is unusable.
    #[error("{path}: bad size {width}x{height} in header")]
    BadSize {
        /// The file.
        path: String,
        /// Width read.
        width: i64,
        /// Height read.
        height: i64,
    },
    /// Fewer bytes than the header promises.
    #[error("{path}: truncated: {actual} bytes of flow data, expected {expected}")]
    Truncated {
        /// The file.
        path: String,
        /// Bytes expected.
        expected: usize,
        /// Bytes found.
        actual: usize,
    },
    /// PNG encoding failed.
    #[error("{path}: cannot write PNG: {reason}")]
    Png {
        /// The file.
        path: String,
        /// What went wrong.
        reason: String,
    },
}

/// Encodes `flow` as `.flo` bytes.
pub fn encode_flo(flow: &FlowField) -> Vec<u8> {
    let (w, h) = flow.size();
    let mut out = Vec::with_capacity(12 + 8 * w * h);
    out.extend_from_slice(&FLO_TAG.to_le_bytes());
    out.extend_from_slice(&(w as i32).to_le_bytes());
    out.extend_from_slice(&(h as i32).to_le_bytes());
    for (u, v) in flow.u.iter().zip(&flow.v) {
        out.extend_from_slice(&u.to_le_bytes());
        out.extend_from_slice(&v.to_le_bytes());
    }
    out
}

/// Decodes `.flo` bytes; `name` labels errors.
pub fn decode_flo(bytes: &[u8], name: &str) -> Result<FlowField, FlowIoError> {
    let word = |i: usize| -> Option<[u8; 4]> { bytes.get(4 * i..4 * i + 4)?.try_into().ok() };
    let (Some(tag), Some(w), Some(h)) = (word(0), word(1), word(2)) else {
        return Err(FlowIoError::Truncated {
            path: name.into(),
            expected: 12,
            actual: bytes.len(),
        });
    };
    let tag = f32::from_le_bytes(tag);
    if tag != FLO_TAG {
        return Err(FlowIoError::BadTag {
            path: name.into(),
            tag,
        });
    }
    let (w, h) = (i32::from_le_bytes(w) as i64, i32::from_le_bytes(h) as i64);
    if w <= 0 || h <= 0 || w as usize > MAX_FLO_SIDE || h as usize > MAX_FLO_SIDE {
        return Err(FlowIoError::BadSize {
            path: name.into(),
            width: w,
            height: h,
        });
    }
    let n = (w * h) as usize;
    let body = &bytes[12..];
    if body.len() < 8 * n {
        return Err(FlowIoError::Truncated {
            path: name.into(),
            expected: 8 * n,
            actual: body.len(),
        });
    }
    let mut flow = FlowField::zeros(w as usize, h as usize);
    for (i, px) in body[..8 * n].chunks_exact(8).enumerate() {
        flow.u[i] = f32::from_le_bytes([px[0], px[1], px[2], px[3]]);
        flow.v[i] = f32::from_le_bytes([px[4], px[5], px[6], px[7]]);
    }
    Ok(flow)
}

/// Writes `flow` to `path` in `.flo` format.
pub fn write_flo(flow: &FlowField, path: &Path) -> Result<(), FlowIoError> {
    let io = |source| FlowIoError::Io {
        path: path.display().to_string(),
        source,
    };
    let mut f = std::fs::File::create(path).map_err(io)?;
    f.write_all(&encode_flo(flow)).map_err(io)
}

/// Reads a `.flo` file.
pub fn read_flo(path: &Path) -> Result<FlowField, FlowIoError> {
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|source| FlowIoError::Io {
            path: path.display().to_string(),
            source,
        })?;
    decode_flo(&bytes, &path.display().to_string())
}

/// The Middlebury colour wheel: 55 hues from red through yellow, green, cyan, blue and
/// magenta back to red, with the published segment lengths (15, 6, 4, 11, 13, 6).
fn colour_wheel() -> Vec<[f32; 3]> {
    let segments = [(15, 0), (6, 1), (4, 2), (11, 3), (13, 4), (6, 5)];
    let mut wheel = Vec::with_capacity(55);
    for (len, seg) in segments {
        for i in 0..len {
            let up = (255 * i / len) as f32;
            let down = 255.0 - up;
            wheel.push(match seg {
                0 => [255.0, up, 0.0],
                1 => [down, 255.0, 0.0],
                2 => [0.0, 255.0, up],
                3 => [0.0, down, 255.0],
                4 => [up, 0.0, 255.0],
                _ => [255.0, 0.0, down],
            });
        }
    }
    wheel
}

/// Colour-codes `flow` as interleaved RGB8. `max_magnitude_px` is the magnitude drawn
/// fully saturated; `None` uses the largest finite magnitude of the field. Non-finite
/// vectors are drawn black.
pub fn flow_to_rgb(flow: &FlowField, max_magnitude_px: Option<f32>) -> Vec<u8> {
    let wheel = colour_wheel();
    let ncols = wheel.len();
    let max = max_magnitude_px.unwrap_or_else(|| {
        flow.u
            .iter()
            .zip(&flow.v)
            .map(|(u, v)| (u * u + v * v).sqrt())
            .filter(|m| m.is_finite())
            .fold(0.0f32, f32::max)
    });
    let max = if max > 0.0 && max.is_finite() {
        max
    } else {
        1.0
    };
    let mut out = Vec::with_capacity(3 * flow.u.len());
    for (&u, &v) in flow.u.iter().zip(&flow.v) {
        if !(u.is_finite() && v.is_finite()) {
            out.extend_from_slice(&[0, 0, 0]);
            continue;
        }
        let rad = (u * u + v * v).sqrt() / max;
        let a = (-v).atan2(-u) / std::f32::consts::PI; // -1..1
        let fk = (a + 1.0) / 2.0 * (ncols - 1) as f32;
        let k0 = (fk.floor() as usize).min(ncols - 1);
        let k1 = (k0 + 1) % ncols;
        let f = fk - k0 as f32;
        for (c0, c1) in wheel[k0].iter().zip(&wheel[k1]) {
            let col = ((1.0 - f) * c0 + f * c1) / 255.0;
            let col = if rad <= 1.0 {
                1.0 - rad * (1.0 - col)
            } else {
                col * 0.75
            };
            out.push((255.0 * col).round().clamp(0.0, 255.0) as u8);
        }
    }
    out
}

/// Writes the colour-coded flow as an RGB PNG.
pub fn write_flow_png(
    flow: &FlowField,
    max_magnitude_px: Option<f32>,
    path: &Path,
) -> Result<(), FlowIoError> {
    let rgb = flow_to_rgb(flow, max_magnitude_px);
    let png_err = |reason: String| FlowIoError::Png {
        path: path.display().to_string(),
        reason,
    };
    let img = image::RgbImage::from_raw(flow.width() as u32, flow.height() as u32, rgb)
        .ok_or_else(|| png_err("buffer size mismatch".into()))?;
    img.save(path).map_err(|e| png_err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flo_round_trip_is_exact() {
        let f = FlowField::from_fn(5, 3, |x, y| (x as f32 * 0.25 - 1.0, -(y as f32) * 1.5));
        let back = decode_flo(&encode_flo(&f), "mem").unwrap();
        assert_eq!(back, f);
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("f.flo");
        write_flo(&f, &p).unwrap();
        assert_eq!(read_flo(&p).unwrap(), f);
        // Header layout: tag, width, height.
        let bytes = std::fs::read(&p).unwrap();
        assert_eq!(&bytes[0..4], &FLO_TAG.to_le_bytes());
        assert_eq!(i32::from_le_bytes(bytes[4..8].try_into().unwrap()), 5);
        assert_eq!(bytes.len(), 12 + 8 * 15);
    }

    #[test]
    fn bad_flo_files_are_reported() {
        let f = FlowField::zeros(4, 4);
        let mut bytes = encode_flo(&f);
        assert!(matches!(
            decode_flo(&bytes[..8], "x"),
            Err(FlowIoError::Truncated { .. })
        ));
        assert!(matches!(
            decode_flo(&bytes[..40], "x"),
            Err(FlowIoError::Truncated { expected: 128, .. })
        ));
        bytes[0] = 0;
        assert!(matches!(
            decode_flo(&bytes, "x"),
            Err(FlowIoError::BadTag { .. })
        ));
        let mut neg = encode_flo(&f);
        neg[4..8].copy_from_slice(&(-3i32).to_le_bytes());
        assert!(matches!(
            decode_flo(&neg, "x"),
            Err(FlowIoError::BadSize { width: -3, .. })
        ));
        assert!(matches!(
            read_flo(Path::new("/nonexistent/f.flo")),
            Err(FlowIoError::Io { .. })
        ));
    }

    #[test]
    fn colour_coding_follows_the_wheel() {
        // Right -> red-ish... Middlebury: flow pointing left (u<0, v=0) gives atan2(0, 1)=0
        // -> middle of the wheel (cyan-blue side); pointing right gives red/magenta.
        let f = FlowField::new(
            4,
            1,
            vec![1.0, -1.0, 0.0, f32::NAN],
            vec![0.0, 0.0, 0.0, 0.0],
        )
        .unwrap();
        let rgb = flow_to_rgb(&f, Some(1.0));
        let px = |i: usize| [rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]];
        assert_eq!(px(0), [255, 0, 0], "right is red at full saturation");
        assert!(
            px(1)[0] < 10 && px(1)[2] > 200,
            "left is blue-cyan: {:?}",
            px(1)
        );
        assert_eq!(px(2), [255, 255, 255], "zero flow is white");
        assert_eq!(px(3), [0, 0, 0], "NaN is black");
        let beyond = flow_to_rgb(
            &FlowField::new(1, 1, vec![2.0], vec![0.0]).unwrap(),
            Some(1.0),
        );
        assert_eq!(beyond, vec![191, 0, 0], "past the bound the colour darkens");
    }
}
