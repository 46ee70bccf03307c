//! What a live session receives: images, joint states and phase markers in, frames
//! released to the queue once their joint states are known (or waited for long enough),
//! the end of the stream and a broken link; episodes' decoded frames pushed with
//! backpressure.

use super::budget::SharedCharge;
use super::error::check_label;
use super::event::{EventKind, LiveImage, LiveJoints};
use super::hub::{Hub, event};
use super::state::{ImagePayload, ReadyFrame, Session, SessionState, lock};
use crate::config::QueuePolicy;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

/// Heap bytes a buffered image is charged beyond its pixel bytes (the frame's
/// bookkeeping).
const FRAME_OVERHEAD: u64 = 256;

impl Hub {
    /// An image of a live session.
    pub fn image(&self, s: &Arc<Session>, image: LiveImage) {
        let stamp = image.stamp_ns;
        let mut st = lock(&s.state);
        let now = Instant::now();
        st.last_activity = now;
        st.load.arrived(now);
        st.images += 1;
        if let Some(last) = st.last_image_ns
            && stamp <= last
        {
            drop(st);
            self.refuse(
                s,
                "stamp",
                format!("image stamp {stamp} ns is not after the previous image ({last} ns): image dropped"),
                stamp,
            );
            return;
        }
        let bytes = image.data.len() + image.depth.as_ref().map_or(0, |d| d.data.len());
        let charge = match self.budget.charge(bytes as u64 + FRAME_OVERHEAD) {
            Ok(c) => c,
            Err(e) => {
                st.lost += 1;
                drop(st);
                self.refuse_for_memory(s, format!("image at {stamp} ns dropped: {e}"), stamp);
                return;
            }
        };
        st.last_image_ns = Some(stamp);
        st.newest_ns = st.newest_ns.max(stamp);
        st.pending.push_back(ReadyFrame {
            stamp_ns: stamp,
            image: ImagePayload::Live(image),
            joints: None,
            arrived: Instant::now(),
            held: vec![SharedCharge::new(charge)],
        });
        let released = self.release(s, &mut st, false);
        drop(st);
        self.after_release(s, released);
    }

    /// A joint state of a live session.
    pub fn joints(&self, s: &Arc<Session>, j: LiveJoints) {
        let stamp = j.stamp_ns;
        let mut st = lock(&s.state);
        st.last_activity = Instant::now();
        if j.names.len() > self.config.max_joints {
            drop(st);
            let e = format!(
                "joint state refused: {} joints (at most {}, [service] max_joints)",
                j.names.len(),
                self.config.max_joints
            );
            self.message_error(s, "joints", e, stamp);
            return;
        }
        // The buffer's growth is checked against the session's cap and charged to the
        // server's budget before it happens.
        let g = &mut *st;
        let now = g.joints.bytes();
        let cost = g.joints.push_cost(&j.names);
        let limit = self.config.max_joint_buffer_bytes;
        let refused = if now + cost > limit {
            Some((
                "memory",
                format!(
                    "joint state refused: the session's joint buffer holds {now} bytes (at \
                     most {limit}, [service] max_joint_buffer_bytes); joint states run far \
                     ahead of the images"
                ),
            ))
        } else if let Err(e) = g.joint_charge.resize(now + cost) {
            Some(("memory", format!("joint state refused: {e}")))
        } else if let Err(e) = g.joints.push(stamp, j.names, j.positions, j.efforts) {
            Some(("joints", format!("joint state refused: {e}")))
        } else {
            None
        };
        if let Some((kind, detail)) = refused {
            let _ = g.joint_charge.resize(g.joints.bytes());
            drop(st);
            self.message_error(s, kind, detail, stamp);
            return;
        }
        // Samples no waiting image can need, beyond the window, are forgotten.
        let window_ns = (self.config.joint_buffer_s.max(0.0) * 1e9) as i64;
        let horizon = stamp.saturating_sub(window_ns);
        let keep = st
            .pending
            .front()
            .map_or(horizon, |f| f.stamp_ns.min(horizon));
        st.joints.trim_before(keep);
        let bytes = st.joints.bytes();
        let _ = st.joint_charge.resize(bytes);
        st.newest_ns = st.newest_ns.max(stamp);
        let released = self.release(s, &mut st, false);
        drop(st);
        self.after_release(s, released);
    }

    /// A phase marker of a live session.
    pub fn phase(&self, s: &Arc<Session>, stamp_ns: i64, phase: String) {
        if let Err(e) = check_label("phase", &phase) {
            self.refuse(s, "phase", format!("phase dropped: {e}"), stamp_ns);
            return;
        }
        {
            let mut st = lock(&s.state);
            st.last_activity = Instant::now();
            st.phase = Some(phase.clone());
        }
        tracing::info!(session = %s.id, phase = %phase, "phase");
        self.send(s, event(&s.id, EventKind::Phase, phase, stamp_ns, 0));
    }

    /// Moves pending images whose joint states are known (or waited for long enough in
    /// stamp time or in wall time, or `flush`) into the queue. Returns how many images the queue policy dropped and
    /// whether the session must be scheduled.
    pub(super) fn release(
        &self,
        s: &Session,
        st: &mut SessionState,
        flush: bool,
    ) -> (u64, u64, bool) {
        let wait_ns = (self.config.joint_wait_ms * 1e6) as i64;
        let wait = Duration::from_secs_f64(self.config.joint_wait_ms.max(0.0) * 1e-3);
        let mut dropped = 0;
        let mut rejected = 0;
        while let Some(front) = st.pending.front() {
            let t = front.stamp_ns;
            // A session may keep a few queues' worth of images waiting for joints; past
            // that the oldest goes on with the joint states known.
            let ready = !s.needs_joints()
                || flush
                || st.pending.len() > 4 * self.config.queue_depth.max(1)
                || st.joints.newest_ns().is_some_and(|n| n >= t)
                || st.newest_ns.saturating_sub(t) > wait_ns
                || front.arrived.elapsed() > wait;
            if !ready {
                break;
            }
            let Some(mut frame) = st.pending.pop_front() else {
                break;
            };
            if s.needs_joints() {
                frame.joints = st.joints.at(t);
                st.joints.trim_before(t);
                let _ = st.joint_charge.resize(st.joints.bytes());
            }
            if st.queue.len() >= self.config.queue_depth.max(1) {
                match self.config.queue_policy {
                    QueuePolicy::DropOldest => {
                        st.queue.pop_front();
                        self.metrics.queue_depth.dec();
                        dropped += 1;
                        st.lost += 1;
                    }
                    QueuePolicy::Reject => {
                        rejected += 1;
                        st.lost += 1;
                        continue;
                    }
                }
            }
            st.queue.push_back(frame);
            self.metrics.queue_depth.inc();
        }
        let schedule = !st.queue.is_empty() && !st.scheduled;
        if schedule {
            st.scheduled = true;
        }
        (dropped, rejected, schedule)
    }

    pub(super) fn after_release(
        &self,
        s: &Arc<Session>,
        (dropped, rejected, schedule): (u64, u64, bool),
    ) {
        for (n, reason) in [(dropped, "queue_full"), (rejected, "rejected")] {
            if n == 0 {
                continue;
            }
            let total = s.dropped.fetch_add(n, Ordering::Relaxed) + n;
            self.metrics
                .drops
                .with_label_values(&[&s.profile_name, reason])
                .inc_by(n);
            self.send(
                s,
                event(
                    &s.id,
                    EventKind::FramesDropped,
                    format!(
                        "{n} image(s) {}: the session queue ({} images) is full",
                        if reason == "rejected" {
                            "rejected"
                        } else {
                            "dropped (oldest first)"
                        },
                        self.config.queue_depth
                    ),
                    0,
                    total,
                ),
            );
        }
        if schedule {
            lock(&self.ready).push_back(s.clone());
            self.work.notify_one();
        }
    }

    /// Queues a decoded frame of an episode, waiting while the queue is full. Returns
    /// false when the session was closed.
    pub fn push_blocking(&self, s: &Arc<Session>, frame: ReadyFrame) -> bool {
        let mut st = lock(&s.state);
        while st.queue.len() >= self.config.queue_depth.max(1) && !st.closed {
            st = s.space.wait(st).unwrap_or_else(|e| e.into_inner());
        }
        if st.closed {
            return false;
        }
        st.images += 1;
        st.queue.push_back(frame);
        self.metrics.queue_depth.inc();
        let schedule = !st.scheduled;
        st.scheduled = true;
        drop(st);
        self.after_release(s, (0, 0, schedule));
        true
    }

    /// Whether the session is closed.
    pub fn is_closed(&self, s: &Session) -> bool {
        lock(&s.state).closed
    }

    /// Blocks until the session is closed.
    pub fn wait_closed(&self, s: &Session) {
        let mut st = lock(&s.state);
        while !st.closed {
            st = s
                .space
                .wait_timeout(st, Duration::from_millis(100))
                .map_or_else(|e| e.into_inner().0, |r| r.0);
        }
    }

    /// The client ended its stream: pending images are scored with the joint states
    /// known, then the stream closes.
    pub fn finish(&self, s: &Arc<Session>) {
        let mut st = lock(&s.state);
        st.finishing = true;
        let released = self.release(s, &mut st, true);
        let done = st.queue.is_empty() && !st.scheduled && !released.2;
        drop(st);
        self.after_release(s, released);
        if done {
            self.close(s, None);
        }
    }

    /// The client's stream broke: a resumable session waits `resume_window_s` for its
    /// client, others close.
    pub fn detach(&self, s: &Arc<Session>) {
        if s.resumable && !self.stopping.load(Ordering::SeqCst) {
            let mut st = lock(&s.state);
            st.detached_since = Some(Instant::now());
            st.out = None;
            tracing::info!(session = %s.id, "stream lost: session kept for resumption");
        } else {
            self.close(s, None);
        }
    }
}
