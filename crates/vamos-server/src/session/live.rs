//! What the live view shows of a session: its recent frames as timeline points, the
//! latest camera frame as a small gray thumbnail, and the latest anomaly map. Kept per
//! session, bounded, and dropped with it.
//!
//! The anomaly map of a frame is built from what the scorer returns: the scene residual
//! per cell normalised by the profile's nominal per-cell statistics when the profile is
//! calibrated for it (`z = (cell - median) / spread`, full scale at `z = 2`, twice the
//! nominal 99th-percentile excess), else the flow predictor's squared-error map (`S x S`)
//! scaled so that four times the alarm threshold is full scale (or, without an alarm
//! threshold, the frame's own maximum). Both are u8 images, 0 = nominal.

use std::collections::VecDeque;
use vamos_core::eval::Thresholds;
use vamos_core::pipeline::FrameScore;
use vamos_vision::GrayImage;

/// Timeline points kept per session (a minute at 10 Hz).
pub const HISTORY_FRAMES: usize = 600;

/// Width of frame thumbnails, pixels (smaller frames keep their size).
pub const THUMB_WIDTH: usize = 160;

/// A small 8-bit gray image.
#[derive(Debug, Clone, PartialEq)]
pub struct Thumb {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Row-major pixels, `width * height`.
    pub pixels: Vec<u8>,
}

impl Thumb {
    /// The image as a PNG file (8-bit gray).
    pub fn to_png(&self) -> Vec<u8> {
        let mut out = Vec::new();
        let encoder = image::codecs::png::PngEncoder::new(&mut out);
        // Invariant: pixels.len() == width * height (every constructor here keeps it),
        // so the encoder cannot refuse the buffer; an empty PNG would be its only failure.
        if image::ImageEncoder::write_image(
            encoder,
            &self.pixels,
            self.width as u32,
            self.height as u32,
            image::ExtendedColorType::L8,
        )
        .is_err()
        {
            out.clear();
        }
        out
    }
}

/// `gray` (0..255 intensities) shrunk by area averaging to at most `max_width` columns.
pub fn thumbnail(gray: &GrayImage, max_width: usize) -> Thumb {
    let (w, h) = (gray.width(), gray.height());
    let f = w.div_ceil(max_width.max(1)).max(1);
    let (tw, th) = (w / f, h / f);
    let (tw, th) = (tw.max(1), th.max(1));
    let data = gray.data();
    let mut pixels = Vec::with_capacity(tw * th);
    for ty in 0..th {
        for tx in 0..tw {
            let mut sum = 0.0f32;
            let mut n = 0u32;
            for y in ty * f..((ty + 1) * f).min(h) {
                for x in tx * f..((tx + 1) * f).min(w) {
                    sum += data[y * w + x];
                    n += 1;
                }
            }
            let v = if n == 0 { 0.0 } else { sum / n as f32 };
            pixels.push(v.clamp(0.0, 255.0).round() as u8);
        }
    }
    Thumb {
        width: tw,
        height: th,
        pixels,
    }
}

fn to_u8(values: impl Iterator<Item = f64>, full_scale: f64) -> Vec<u8> {
    values
        .map(|v| {
            if v.is_nan() {
                255
            } else {
                (255.0 * (v / full_scale).clamp(0.0, 1.0)).round() as u8
            }
        })
        .collect()
}

/// The anomaly map of `score` (see the module docs), `None` when the scorer gave none.
pub fn anomaly_map(score: &FrameScore, thresholds: &Thresholds, alarm: f64) -> Option<Thumb> {
    let (columns, rows) = score.scene_grid;
    if let (Some(cells), Some(stats)) = (
        &score.scene_cells,
        thresholds.scene.as_ref().map(|s| s.at(Some(score.phase_s))),
    ) && stats.columns == columns
        && stats.rows == rows
        && cells.len() == columns * rows
        && stats.location.len() == cells.len()
        && stats.spread.len() == cells.len()
    {
        let z = cells.iter().enumerate().map(|(i, &v)| {
            let spread = stats.spread[i].max(1e-9);
            (f64::from(v) - stats.location[i]) / spread
        });
        return Some(Thumb {
            width: columns,
            height: rows,
            pixels: to_u8(z, 2.0),
        });
    }
    let map = score.heatmap.as_ref()?;
    let side = (map.len() as f64).sqrt().round() as usize;
    if side == 0 || side * side != map.len() {
        return None;
    }
    let full = if alarm.is_finite() && alarm > 0.0 {
        4.0 * alarm
    } else {
        map.iter()
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0f32, f32::max)
            .max(1e-9) as f64
    };
    Some(Thumb {
        width: side,
        height: side,
        pixels: to_u8(map.iter().map(|&v| f64::from(v)), full),
    })
}

/// One scored frame on a live timeline.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, schemars::JsonSchema)]
pub struct FramePoint {
    /// Frame index among processed frames.
    pub frame: u64,
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Fused score (`None`: not finite).
    pub score: Option<f64>,
    /// Camera-motion error.
    pub e_c: Option<f64>,
    /// Body-motion error.
    pub e_b: Option<f64>,
    /// Flow-prediction error.
    pub e_o: Option<f64>,
    /// Scene residual.
    pub e_r: Option<f64>,
    /// Kinematic novelty (nominal joint ranges; metres for `state = "links"`).
    pub e_k: Option<f64>,
    /// The frame's anomaly flag.
    pub anomaly: bool,
    /// The predictor was warming up.
    pub warming_up: bool,
    /// An alarm is on at this frame (debounced).
    pub alarm: bool,
    /// Server latency, seconds.
    pub latency_s: f64,
}

fn finite(v: Option<f64>) -> Option<f64> {
    v.filter(|x| x.is_finite())
}

impl FramePoint {
    /// The point of a scored frame.
    pub fn of(s: &FrameScore, alarm: bool, latency_s: f64) -> Self {
        Self {
            frame: s.frame,
            stamp_ns: s.stamp_ns,
            score: finite(Some(s.score)),
            e_c: finite(s.e_c),
            e_b: finite(s.e_b),
            e_o: finite(s.e_o),
            e_r: finite(s.e_r),
            e_k: finite(s.e_k),
            anomaly: s.anomaly,
            warming_up: s.warming_up,
            alarm,
            latency_s,
        }
    }
}

/// A session's live view: bounded timeline, latest frame and map.
#[derive(Debug, Default)]
pub struct LiveView {
    /// The last [`HISTORY_FRAMES`] frames.
    pub history: VecDeque<FramePoint>,
    /// The latest frame, shrunk.
    pub frame: Option<Thumb>,
    /// The latest anomaly map.
    pub map: Option<Thumb>,
}

impl LiveView {
    /// Records a frame.
    pub fn push(&mut self, point: FramePoint, frame: Option<Thumb>, map: Option<Thumb>) {
        if self.history.len() == HISTORY_FRAMES {
            self.history.pop_front();
        }
        self.history.push_back(point);
        if frame.is_some() {
            self.frame = frame;
        }
        if map.is_some() {
            self.map = map;
        }
    }

    /// Points after frame `after` (all when `None`).
    pub fn since(&self, after: Option<u64>) -> Vec<FramePoint> {
        self.history
            .iter()
            .filter(|p| after.is_none_or(|a| p.frame > a))
            .copied()
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vamos_core::eval::CellStats;

    #[test]
    fn thumbnails_average_blocks_and_encode_as_png() {
        let gray = GrayImage::from_fn(320, 240, |x, _| if x < 160 { 0.0 } else { 200.0 });
        let t = thumbnail(&gray, 160);
        assert_eq!((t.width, t.height), (160, 120));
        assert_eq!(t.pixels[0], 0);
        assert_eq!(t.pixels[159], 200);
        let png = t.to_png();
        let back = image::load_from_memory(&png).unwrap().to_luma8();
        assert_eq!(back.dimensions(), (160, 120));
        assert_eq!(back.as_raw(), &t.pixels);
        // Small frames keep their size.
        let small = thumbnail(&GrayImage::from_fn(64, 48, |_, _| 9.0), 160);
        assert_eq!((small.width, small.height, small.pixels[0]), (64, 48, 9));
    }

    fn score() -> FrameScore {
        FrameScore {
            index: 0,
            frame: 0,
            stamp_ns: 0,
            score: 0.0,
            e_c: None,
            e_b: None,
            e_o: None,
            e_r: None,
            e_k: None,
            anomaly: false,
            triggered: None,
            warming_up: false,
            best_offset: None,
            registration_confidence: None,
            body_pixels: 0,
            timings: Default::default(),
            heatmap: None,
            scene_cells: None,
            scene_grid: (0, 0),
            flow_cells: None,
            flow_grid: (0, 0),
            phase_s: 0.0,
            kinematic_state: None,
            depth_evidence: None,
        }
    }

    #[test]
    fn the_map_is_the_normalised_scene_when_calibrated_else_the_flow_error() {
        let mut s = score();
        assert_eq!(anomaly_map(&s, &Thresholds::default(), 1.0), None);
        // e_o map: 4 x the alarm threshold is full scale.
        s.heatmap = Some(vec![0.0, 0.5, 2.0, 8.0]);
        let m = anomaly_map(&s, &Thresholds::default(), 0.5).unwrap();
        assert_eq!((m.width, m.height), (2, 2));
        assert_eq!(m.pixels, vec![0, 64, 255, 255]);
        // Without an alarm threshold the frame's maximum is full scale.
        let m = anomaly_map(&s, &Thresholds::default(), f64::INFINITY).unwrap();
        assert_eq!(m.pixels, vec![0, 16, 64, 255]);
        // Scene cells win when the profile has their statistics.
        s.scene_cells = Some(vec![1.0, 3.0, 5.0]);
        s.scene_grid = (3, 1);
        let t = Thresholds {
            scene: Some(CellStats {
                columns: 3,
                rows: 1,
                location: vec![1.0, 1.0, 1.0],
                spread: vec![1.0, 1.0, 1.0],
                maps: 10,
                phases: None,
                photometric: true,
            }),
            ..Thresholds::default()
        };
        let m = anomaly_map(&s, &t, 0.5).unwrap();
        assert_eq!((m.width, m.height), (3, 1));
        assert_eq!(m.pixels, vec![0, 255, 255]);
        s.scene_cells = Some(vec![1.0, 2.0, 1.0]);
        assert_eq!(anomaly_map(&s, &t, 0.5).unwrap().pixels, vec![0, 128, 0]);
    }

    #[test]
    fn the_history_is_bounded_and_read_after_a_frame() {
        let mut v = LiveView::default();
        let mut s = score();
        for i in 0..(HISTORY_FRAMES as u64 + 10) {
            s.frame = i;
            v.push(FramePoint::of(&s, false, 0.0), None, None);
        }
        assert_eq!(v.history.len(), HISTORY_FRAMES);
        assert_eq!(v.since(None)[0].frame, 10);
        let tail = v.since(Some(HISTORY_FRAMES as u64 + 7));
        assert_eq!(
            tail.iter().map(|p| p.frame).collect::<Vec<_>>(),
            vec![608, 609]
        );
    }
}
