//! Pairs each colour image with the depth image nearest its stamp, as a recorded bag's
//! frames are paired (`[episode] max_depth_gap_ms`, `vamos_core::episode`'s assembler):
//! a colour image takes the depth image whose header stamp is nearest its own if that is
//! at most the gap away, else it goes without one (the server then places the scene at
//! the profile's assumed depth). No DDS and no clock of its own: the caller passes the
//! arrival time, so every rule below is a unit test.
//!
//! - **Waiting.** Colour images wait in arrival order until one of: a depth image stamped
//!   at or after the image has arrived (depth images come in stamp order, so none nearer
//!   can follow; the rule of the recorded path), `hold` has passed since the image
//!   arrived (wall clock; the bridge uses twice the gap), or more than
//!   [`MAX_WAITING_IMAGES`] wait (the oldest goes). Then the image goes out with the
//!   nearest depth image held within the gap, or without one: an image is never dropped
//!   for want of depth.
//! - **Depth images** are held sorted by stamp (a late one is put in its place), at most
//!   [`MAX_HELD_DEPTHS`] (the oldest stamp goes first), and dropped once older than the
//!   gap before every colour image still to be paired and the newest one paired. One depth
//!   image may serve several colour images (a depth camera slower than the colour camera),
//!   as in recorded bags. A depth image that arrives after its colour image went out is
//!   not sent again.
//! - **Encodings** are not checked here: the depth image goes as it came, and the server
//!   refuses an unusable one (not `16UC1`/`32FC1`, another aspect ratio, a bad size) for
//!   that frame with a message naming why, and scores the frame at the assumed depth.

use std::collections::VecDeque;
use std::time::{Duration, Instant};
use vamos_proto as proto;

/// Colour images that wait for their depth image at most; one more releases the oldest.
pub const MAX_WAITING_IMAGES: usize = 8;

/// Depth images held at most (enough for a depth camera several times faster than the
/// colour camera over the hold); one more drops the oldest.
pub const MAX_HELD_DEPTHS: usize = 16;

/// A colour image waiting for its depth image.
#[derive(Debug)]
struct Waiting {
    image: proto::Image,
    since: Instant,
}

/// Colour images and depth images in, colour images with their depth image out.
#[derive(Debug)]
pub struct DepthPairer {
    max_gap_ns: u64,
    hold: Duration,
    waiting: VecDeque<Waiting>,
    /// `(stamp_ns, depth image)`, ascending stamps.
    depths: VecDeque<(i64, proto::DepthImage)>,
    latest_depth_ns: Option<i64>,
    /// The newest stamp of an image that went out.
    last_paired_ns: Option<i64>,
}

impl DepthPairer {
    /// A pairer taking depth images at most `max_gap` from a colour image's stamp, a
    /// colour image waiting at most `hold` after it arrived.
    pub fn new(max_gap: Duration, hold: Duration) -> Self {
        Self {
            max_gap_ns: u64::try_from(max_gap.as_nanos()).unwrap_or(u64::MAX),
            hold,
            waiting: VecDeque::new(),
            depths: VecDeque::new(),
            latest_depth_ns: None,
            last_paired_ns: None,
        }
    }

    /// A colour image arrived at `now`: the images that go out now, in arrival order.
    pub fn push_image(&mut self, image: proto::Image, now: Instant) -> Vec<proto::Image> {
        self.waiting.push_back(Waiting { image, since: now });
        self.release(now, false)
    }

    /// A depth image stamped `stamp_ns` arrived at `now`: the images that go out now.
    pub fn push_depth(
        &mut self,
        stamp_ns: i64,
        depth: proto::DepthImage,
        now: Instant,
    ) -> Vec<proto::Image> {
        let at = self.depths.partition_point(|(t, _)| *t <= stamp_ns);
        self.depths.insert(at, (stamp_ns, depth));
        if self.depths.len() > MAX_HELD_DEPTHS {
            self.depths.pop_front();
        }
        self.latest_depth_ns = Some(self.latest_depth_ns.map_or(stamp_ns, |l| l.max(stamp_ns)));
        self.release(now, false)
    }

    /// The images whose hold has ended by `now`.
    pub fn release_due(&mut self, now: Instant) -> Vec<proto::Image> {
        self.release(now, false)
    }

    /// Every waiting image, with the depth image it can have now (the bridge stops).
    pub fn drain(&mut self) -> Vec<proto::Image> {
        self.release(Instant::now(), true)
    }

    /// When the oldest waiting image's hold ends, if one waits.
    pub fn deadline(&self) -> Option<Instant> {
        self.waiting.front().map(|w| w.since + self.hold)
    }

    /// `(colour images waiting, depth images held)`.
    pub fn held(&self) -> (usize, usize) {
        (self.waiting.len(), self.depths.len())
    }

    fn release(&mut self, now: Instant, all: bool) -> Vec<proto::Image> {
        let mut out = Vec::new();
        while let Some(front) = self.waiting.front() {
            let stamp = front.image.stamp_ns;
            let go = all
                || self.waiting.len() > MAX_WAITING_IMAGES
                || self.latest_depth_ns.is_some_and(|l| l >= stamp)
                || now.saturating_duration_since(front.since) >= self.hold;
            if !go {
                break;
            }
            let Some(Waiting { mut image, .. }) = self.waiting.pop_front() else {
                break;
            };
            image.depth = self.nearest(stamp);
            self.last_paired_ns = Some(self.last_paired_ns.map_or(stamp, |l| l.max(stamp)));
            out.push(image);
        }
        self.forget_old_depths();
        out
    }

    /// The held depth image nearest `stamp_ns` within the gap (the earlier of two as near).
    fn nearest(&self, stamp_ns: i64) -> Option<proto::DepthImage> {
        let gap = |t: i64| t.abs_diff(stamp_ns);
        self.depths
            .iter()
            .filter(|(t, _)| gap(*t) <= self.max_gap_ns)
            .min_by_key(|(t, _)| gap(*t))
            .map(|(_, d)| d.clone())
    }

    /// Drops the depth images older than the gap before every image still to be paired
    /// and the newest one paired: no image that can still be scored is near them (the
    /// server refuses stamps that go back).
    fn forget_old_depths(&mut self) {
        let oldest = self
            .waiting
            .iter()
            .map(|w| w.image.stamp_ns)
            .chain(self.last_paired_ns)
            .min();
        if let Some(oldest) = oldest {
            let gap = i64::try_from(self.max_gap_ns).unwrap_or(i64::MAX);
            let horizon = oldest.saturating_sub(gap);
            while self.depths.front().is_some_and(|(t, _)| *t < horizon) {
                self.depths.pop_front();
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: i64 = 1_000_000;
    const GAP: Duration = Duration::from_millis(20);
    const HOLD: Duration = Duration::from_millis(40);

    fn image(stamp_ns: i64) -> proto::Image {
        proto::Image {
            stamp_ns,
            encoding: "mono8".into(),
            width: 1,
            height: 1,
            data: vec![0],
            ..Default::default()
        }
    }

    /// A depth image that says which it is by its width.
    fn depth(tag: u32) -> proto::DepthImage {
        proto::DepthImage {
            encoding: "16UC1".into(),
            width: tag,
            height: 1,
            data: vec![0; 2 * tag as usize],
            ..Default::default()
        }
    }

    /// `(stamp, depth tag)` of images that went out.
    fn tags(images: &[proto::Image]) -> Vec<(i64, Option<u32>)> {
        images
            .iter()
            .map(|i| (i.stamp_ns, i.depth.as_ref().map(|d| d.width)))
            .collect()
    }

    fn at(t0: Instant, ms: u64) -> Instant {
        t0 + Duration::from_millis(ms)
    }

    #[test]
    fn each_image_takes_the_depth_image_nearest_its_stamp_within_the_gap() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        // Depth before the image: held; the image at 1000 ms waits for a depth image at
        // or after its stamp, then takes the nearer of 995 and 1012.
        assert!(p.push_depth(995 * MS, depth(1), t0).is_empty());
        assert!(p.push_image(image(1000 * MS), at(t0, 1)).is_empty());
        let out = p.push_depth(1012 * MS, depth(2), at(t0, 2));
        assert_eq!(tags(&out), [(1000 * MS, Some(1))]);
        // A depth image already at or after the next image's stamp: out at once, with the
        // nearest (1012 for 1010; 1012 is 2 ms away, 995 15 ms).
        let out = p.push_image(image(1010 * MS), at(t0, 3));
        assert_eq!(tags(&out), [(1010 * MS, Some(2))]);
        // As near on both sides: the earlier.
        assert!(p.push_image(image(1022 * MS), at(t0, 4)).is_empty());
        let out = p.push_depth(1032 * MS, depth(3), at(t0, 5));
        assert_eq!(tags(&out), [(1022 * MS, Some(2))]);
        assert_eq!(out[0].depth.as_ref().unwrap().data.len(), 4, "as it came");
    }

    #[test]
    fn an_image_with_no_depth_image_within_the_gap_goes_without_one() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        p.push_depth(970 * MS, depth(1), t0);
        assert!(p.push_image(image(1000 * MS), t0).is_empty());
        // 21 ms after: past the gap, but at or after the stamp, so the image is decided.
        let out = p.push_depth(1021 * MS, depth(2), at(t0, 1));
        assert_eq!(tags(&out), [(1000 * MS, None)]);
        // No depth image at or after it: it waits for its hold, then goes without one
        // (1021 is 21 ms before it).
        assert!(p.push_image(image(1042 * MS), at(t0, 2)).is_empty());
        assert!(p.release_due(at(t0, 41)).is_empty());
        assert_eq!(tags(&p.release_due(at(t0, 42))), [(1042 * MS, None)]);
    }

    #[test]
    fn a_depth_image_exactly_the_gap_away_is_taken() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        p.push_image(image(1000 * MS), t0);
        let out = p.push_depth(1020 * MS, depth(7), at(t0, 1));
        assert_eq!(tags(&out), [(1000 * MS, Some(7))]);
    }

    #[test]
    fn without_depth_images_an_image_goes_out_when_its_hold_ends() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        assert!(p.push_image(image(1), t0).is_empty());
        assert!(p.push_image(image(2), at(t0, 30)).is_empty());
        assert_eq!(p.deadline(), Some(at(t0, 40)));
        assert!(p.release_due(at(t0, 39)).is_empty());
        assert_eq!(tags(&p.release_due(at(t0, 40))), [(1, None)]);
        assert_eq!(p.deadline(), Some(at(t0, 70)));
        assert_eq!(tags(&p.release_due(at(t0, 500))), [(2, None)]);
        assert_eq!(p.deadline(), None);
        // A camera faster than the hold: never more than MAX_WAITING_IMAGES wait, the
        // oldest goes first, none is lost.
        let mut out = Vec::new();
        for i in 0..100 {
            out.extend(p.push_image(image(1000 + i), t0));
            assert!(p.held().0 <= MAX_WAITING_IMAGES);
        }
        assert_eq!(out.len(), 100 - MAX_WAITING_IMAGES);
        out.extend(p.drain());
        let stamps: Vec<i64> = out.iter().map(|i| i.stamp_ns).collect();
        assert_eq!(stamps, (1000..1100).collect::<Vec<_>>());
        assert!(out.iter().all(|i| i.depth.is_none()));
    }

    #[test]
    fn depth_images_alone_are_held_in_a_bounded_window() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        for i in 0..1000 {
            assert!(
                p.push_depth(i * 33 * MS, depth(1), at(t0, i as u64))
                    .is_empty()
            );
            assert!(p.held().1 <= MAX_HELD_DEPTHS);
        }
        assert_eq!(p.held(), (0, MAX_HELD_DEPTHS));
        // The newest are kept: an image among them is paired at once.
        let out = p.push_image(image(999 * 33 * MS - 5 * MS), at(t0, 1000));
        assert_eq!(tags(&out), [(999 * 33 * MS - 5 * MS, Some(1))]);
        // Older than the gap before the last image paired: dropped.
        assert_eq!(p.held(), (0, 1));
    }

    #[test]
    fn late_depth_images_and_out_of_order_stamps() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        // Depth images out of order: put in their place, the nearest still found.
        p.push_depth(1030 * MS, depth(3), t0);
        p.push_depth(990 * MS, depth(1), t0);
        p.push_depth(1003 * MS, depth(2), t0);
        assert_eq!(
            tags(&p.push_image(image(1000 * MS), t0)),
            [(1000 * MS, Some(2))]
        );
        // Images out of order: an earlier stamp behind a later one waits behind it (arrival
        // order is kept) and still gets its own depth image, which the later image's
        // pairing does not forget.
        assert!(p.push_image(image(1100 * MS), at(t0, 1)).is_empty());
        let out = p.push_image(image(1040 * MS), at(t0, 2));
        assert_eq!(tags(&out), []);
        let out = p.push_depth(1101 * MS, depth(4), at(t0, 3));
        assert_eq!(
            tags(&out),
            [(1100 * MS, Some(4)), (1040 * MS, Some(3))],
            "1030 is 10 ms from 1040"
        );
        // A depth image for an image that already went out is not sent again: older than
        // the gap before the newest image paired, it is dropped.
        assert!(p.push_depth(1045 * MS, depth(5), at(t0, 4)).is_empty());
        assert_eq!(p.held(), (0, 1), "only 1101 is kept");
        let out = p.push_image(image(1200 * MS), at(t0, 5));
        assert_eq!(tags(&out), []);
        assert_eq!(tags(&p.release_due(at(t0, 45))), [(1200 * MS, None)]);
        assert_eq!(p.held(), (0, 0));
    }

    #[test]
    fn a_slow_depth_camera_serves_several_images() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        p.push_depth(1000 * MS, depth(1), t0);
        let mut out = p.push_image(image(995 * MS), t0);
        out.extend(p.push_image(image(1000 * MS), t0));
        out.extend(p.push_image(image(1010 * MS), t0));
        out.extend(p.release_due(at(t0, 40)));
        assert_eq!(
            tags(&out),
            [
                (995 * MS, Some(1)),
                (1000 * MS, Some(1)),
                (1010 * MS, Some(1))
            ]
        );
    }

    #[test]
    fn drain_sends_what_waits_with_the_depth_it_can_have() {
        let t0 = Instant::now();
        let mut p = DepthPairer::new(GAP, HOLD);
        p.push_depth(990 * MS, depth(1), t0);
        p.push_image(image(1000 * MS), t0);
        p.push_image(image(1100 * MS), t0);
        assert_eq!(tags(&p.drain()), [(1000 * MS, Some(1)), (1100 * MS, None)]);
        assert_eq!(p.held().0, 0);
    }
}
