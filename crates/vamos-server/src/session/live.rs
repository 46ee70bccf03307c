//! What the live view shows of a session: its recent frames as timeline points, the
//! latest camera frame as a small gray thumbnail, and the latest anomaly map, kept per
//! session and bounded; and an [`Overview`] of the whole session (at most
//! [`OVERVIEW_POINTS`] points, each the maximum of a run of frames), which outlives the
//! session in [`super::history`].
//!
//! The anomaly map of a frame is built from what the scorer returns: the scene residual
//! per cell normalised by the profile's nominal per-cell statistics when the profile is
//! calibrated for it (`z = (cell - median) / spread`, full scale at `z = 2`, twice the
//! nominal 99th-percentile excess), else the flow predictor's squared-error map (`S x S`)
//! scaled so that four times the alarm threshold is full scale (or, without an alarm
//! threshold, the frame's own maximum). Both are u8 images, 0 = nominal.

use std::collections::VecDeque;
use vamos_core::eval::{DetectorValues, Thresholds};
use vamos_core::pipeline::FrameScore;
use vamos_vision::GrayImage;

/// Timeline points kept per session (a minute at 10 Hz).
pub const HISTORY_FRAMES: usize = 600;

/// Points of a whole session's overview ([`Overview`]).
pub const OVERVIEW_POINTS: usize = 256;

/// A session is degraded while images were lost before any of its last this many
/// scored frames (about 10 s at 10 Hz), or lost images wait for the next frame.
pub const DEGRADED_FRAMES: usize = 100;

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

/// One scored frame on a live timeline (on an ended session's overview: a run of frames,
/// each value the run's largest, flags set when any frame of the run had them,
/// `warming_up` when every frame had it, `frames_lost` their sum).
#[derive(
    Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize, schemars::JsonSchema,
)]
pub struct FramePoint {
    /// Frame index among processed frames (of a run: its first).
    pub frame: u64,
    /// Image stamp, nanoseconds.
    pub stamp_ns: i64,
    /// Fused score (`None`: not finite).
    pub score: Option<f64>,
    /// Each detector's value (`None`: not computed or not finite), as the fields `e_c`
    /// .. `e_k`.
    #[serde(flatten)]
    pub values: DetectorValues,
    /// The frame's anomaly flag.
    pub anomaly: bool,
    /// The predictor was warming up.
    pub warming_up: bool,
    /// An alarm is on at this frame (debounced).
    pub alarm: bool,
    /// Server latency, seconds.
    pub latency_s: f64,
    /// Images lost (dropped by a full queue, refused) just before this frame: the
    /// session was degraded here.
    #[serde(default)]
    pub frames_lost: u64,
}

fn finite(v: Option<f64>) -> Option<f64> {
    v.filter(|x| x.is_finite())
}

impl FramePoint {
    /// The point of a scored frame, after `frames_lost` lost images.
    pub fn of(s: &FrameScore, alarm: bool, latency_s: f64, frames_lost: u64) -> Self {
        Self {
            frame: s.frame,
            stamp_ns: s.stamp_ns,
            score: finite(Some(s.score)),
            values: s.values.map(|_, v| finite(*v)),
            anomaly: s.anomaly,
            warming_up: s.warming_up,
            alarm,
            latency_s,
            frames_lost,
        }
    }

    /// `self` and the later run `next` as one run (see the type's docs).
    fn absorb(&mut self, next: &FramePoint) {
        fn max(a: Option<f64>, b: Option<f64>) -> Option<f64> {
            match (a, b) {
                (Some(x), Some(y)) => Some(x.max(y)),
                (x, y) => x.or(y),
            }
        }
        self.score = max(self.score, next.score);
        for (d, v) in self.values.iter_mut() {
            *v = max(*v, next.values[d]);
        }
        self.anomaly |= next.anomaly;
        self.warming_up &= next.warming_up;
        self.alarm |= next.alarm;
        self.latency_s = self.latency_s.max(next.latency_s);
        self.frames_lost += next.frames_lost;
    }
}

/// A whole session's timeline in at most [`OVERVIEW_POINTS`] points: each point a run of
/// `span` frames (see [`FramePoint`]); when the points are full, neighbours merge in
/// pairs and runs double, so the memory is fixed however long the session runs.
#[derive(Debug)]
pub struct Overview {
    points: Vec<FramePoint>,
    /// Frames per point.
    span: u64,
    /// The run being filled and its frames.
    open: Option<(FramePoint, u64)>,
}

impl Default for Overview {
    fn default() -> Self {
        Self {
            points: Vec::with_capacity(OVERVIEW_POINTS),
            span: 1,
            open: None,
        }
    }
}

impl Overview {
    /// Adds a frame.
    pub fn push(&mut self, point: FramePoint) {
        let (run, n) = match self.open.take() {
            Some((mut run, n)) => {
                run.absorb(&point);
                (run, n + 1)
            }
            None => (point, 1),
        };
        if n < self.span {
            self.open = Some((run, n));
            return;
        }
        self.points.push(run);
        if self.points.len() >= OVERVIEW_POINTS {
            let merged = self
                .points
                .chunks(2)
                .map(|pair| {
                    let mut run = pair[0];
                    if let Some(next) = pair.get(1) {
                        run.absorb(next);
                    }
                    run
                })
                .collect();
            self.points = merged;
            self.span *= 2;
        }
    }

    /// The points, oldest first (the run being filled last).
    pub fn points(&self) -> Vec<FramePoint> {
        let mut out = self.points.clone();
        out.extend(self.open.map(|(run, _)| run));
        out
    }
}

/// A session's live view: bounded timeline, latest frame and map, the whole session's
/// overview and totals.
#[derive(Debug, Default)]
pub struct LiveView {
    /// The last [`HISTORY_FRAMES`] frames.
    pub history: VecDeque<FramePoint>,
    /// The latest frame, shrunk.
    pub frame: Option<Thumb>,
    /// The latest anomaly map.
    pub map: Option<Thumb>,
    /// The whole session, downsampled.
    pub overview: Overview,
    /// The stamp of the session's first scored frame, nanoseconds.
    pub first_stamp_ns: Option<i64>,
    /// Frames recorded and the sum of their latencies, seconds.
    pub frames: u64,
    latency_sum_s: f64,
    /// Images lost before the frames recorded.
    pub frames_lost: u64,
}

impl LiveView {
    /// Records a frame.
    pub fn push(&mut self, point: FramePoint, frame: Option<Thumb>, map: Option<Thumb>) {
        if self.history.len() == HISTORY_FRAMES {
            self.history.pop_front();
        }
        self.history.push_back(point);
        self.overview.push(point);
        self.first_stamp_ns.get_or_insert(point.stamp_ns);
        self.frames += 1;
        self.latency_sum_s += point.latency_s;
        self.frames_lost += point.frames_lost;
        if frame.is_some() {
            self.frame = frame;
        }
        if map.is_some() {
            self.map = map;
        }
    }

    /// Mean latency of every frame recorded, seconds.
    pub fn mean_latency_s(&self) -> Option<f64> {
        (self.frames > 0).then(|| self.latency_sum_s / self.frames as f64)
    }

    /// Images lost before the last `frames` frames kept.
    pub fn recent_lost(&self, frames: usize) -> u64 {
        self.history
            .iter()
            .rev()
            .take(frames)
            .map(|p| p.frames_lost)
            .sum()
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
            values: Default::default(),
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
    fn the_overview_covers_the_whole_session_in_bounded_points() {
        let mut o = Overview::default();
        let mut s = score();
        let frames = 10 * OVERVIEW_POINTS as u64 + 3;
        for i in 0..frames {
            s.frame = i;
            s.stamp_ns = i as i64 * 1_000;
            s.score = if i == 777 { 50.0 } else { 1.0 };
            s.warming_up = i < 5;
            let alarm = (900..903).contains(&i);
            o.push(FramePoint::of(&s, alarm, 0.01, u64::from(i == 1500)));
        }
        let points = o.points();
        assert!(points.len() <= OVERVIEW_POINTS, "{}", points.len());
        assert!(points.len() > OVERVIEW_POINTS / 4, "{}", points.len());
        // Runs follow each other from the first frame; the last run is the open one.
        assert_eq!(points[0].frame, 0);
        assert!(points.windows(2).all(|w| w[0].frame < w[1].frame));
        assert!(points.last().unwrap().frame < frames);
        // Peaks, alarms and losses survive the merging; warm-up only where all warmed.
        let peak = points.iter().filter(|p| p.score == Some(50.0)).count();
        assert_eq!(peak, 1);
        assert_eq!(points.iter().filter(|p| p.alarm).count(), 1);
        assert_eq!(points.iter().map(|p| p.frames_lost).sum::<u64>(), 1);
        assert!(points.iter().all(|p| !p.warming_up));
        // A short session is kept frame by frame.
        let mut short = Overview::default();
        for i in 0..10 {
            s.frame = i;
            short.push(FramePoint::of(&s, false, 0.0, 0));
        }
        assert_eq!(short.points().len(), 10);
    }

    #[test]
    fn the_history_is_bounded_and_read_after_a_frame() {
        let mut v = LiveView::default();
        let mut s = score();
        for i in 0..(HISTORY_FRAMES as u64 + 10) {
            s.frame = i;
            v.push(FramePoint::of(&s, false, 0.0, 0), None, None);
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
