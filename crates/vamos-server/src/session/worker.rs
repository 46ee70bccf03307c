//! The worker pool: threads that take one frame of the session at the head of the ready
//! queue, decode it, score it and deliver the score, then put the session back at the
//! tail if more frames wait. A panic while scoring fails that frame only (the session's
//! scorer is rebuilt); a panic outside a frame restarts the worker.

use super::budget::{BudgetSpent, ByteBudget, Charge};
use super::event::{EventKind, LiveImage, Output, ScoredFrame};
use super::hub::{Hub, event};
use super::live;
use super::state::{ImagePayload, LatestScore, ReadyFrame, Session, lock};
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};
use vamos_core::episode::image::EncodedImage;
use vamos_core::episode::ros::MessageError;
use vamos_core::eval::Detector;
use vamos_core::pipeline::{FrameInput, FrameScore, JointInput};
use vamos_vision::{DepthImage, GrayImage};

/// Why a live image was not decoded.
#[derive(Debug, thiserror::Error)]
pub enum ImageRefused {
    /// The image itself (encoding, sizes, a broken file).
    #[error(transparent)]
    Message(#[from] MessageError),
    /// The memory budget cannot hold its decoding.
    #[error("{width}x{height} image not decoded: {source}")]
    Budget {
        /// Columns.
        width: usize,
        /// Rows.
        height: usize,
        /// The budget's refusal.
        #[source]
        source: BudgetSpent,
    },
}

/// A streamed image decoded to gray (raw encodings and PNG / JPEG files, at most
/// `max_pixels`) by the one decoder of [`vamos_core::episode::image`]. With a `budget`, the
/// decoding's memory (estimated from the declared size, before anything is decoded) is
/// charged to it for as long as the returned charge lives, or the image is refused.
pub fn decode_live_image(
    image: &LiveImage,
    max_pixels: usize,
    budget: Option<&Arc<ByteBudget>>,
) -> Result<(GrayImage, Option<Charge>), ImageRefused> {
    decode_charged(
        image,
        max_pixels,
        budget,
        |e| e.to_gray(max_pixels),
        |g| g.data().len(),
    )
}

/// A streamed depth image decoded to metres (`16UC1`, `32FC1`), charged to the budget as
/// [`decode_live_image`] charges images.
pub fn decode_live_depth(
    depth: &LiveImage,
    max_pixels: usize,
    budget: Option<&Arc<ByteBudget>>,
) -> Result<(DepthImage, Option<Charge>), ImageRefused> {
    decode_charged(
        depth,
        max_pixels,
        budget,
        |e| e.to_depth(max_pixels),
        |d| d.metres().len(),
    )
}

/// Checks the declared size, charges the decoding's peak memory, decodes with `decode`,
/// then keeps charged only the `f32` values of the result (`values`).
fn decode_charged<T>(
    image: &LiveImage,
    max_pixels: usize,
    budget: Option<&Arc<ByteBudget>>,
    decode: impl FnOnce(&EncodedImage<'_>) -> Result<T, MessageError>,
    values: impl FnOnce(&T) -> usize,
) -> Result<(T, Option<Charge>), ImageRefused> {
    let encoded = image.encoded();
    let size = encoded.check(max_pixels)?;
    let mut held = match budget {
        Some(b) => Some(
            b.charge(size.peak_bytes)
                .map_err(|source| ImageRefused::Budget {
                    width: size.width,
                    height: size.height,
                    source,
                })?,
        ),
        None => None,
    };
    let decoded = decode(&encoded)?;
    // Decoded: only the result stays.
    if let Some(c) = held.as_mut() {
        let _ = c.resize(4 * values(&decoded) as u64);
    }
    Ok((decoded, held))
}

impl Hub {
    /// A worker thread: [`Self::worker`] restarted after any panic that escapes a frame,
    /// until the hub stops.
    pub(super) fn supervised_worker(self: &Arc<Self>, i: usize) {
        loop {
            match catch_unwind(AssertUnwindSafe(|| self.worker())) {
                Ok(()) => break,
                Err(panic) => {
                    self.metrics.worker_restarts.inc();
                    tracing::error!(
                        worker = i,
                        "scoring worker panicked ({}); restarted",
                        panic_message(panic.as_ref())
                    );
                }
            }
        }
        self.live_workers.fetch_sub(1, Ordering::SeqCst);
        self.metrics.workers_alive.dec();
    }

    fn worker(&self) {
        loop {
            if Self::take_injected(&self.injected_worker_panics) {
                panic!("injected worker panic");
            }
            let session = {
                let mut ready = lock(&self.ready);
                loop {
                    if let Some(s) = ready.pop_front() {
                        break s;
                    }
                    if self.stopping.load(Ordering::SeqCst) && self.session_count() == 0 {
                        return;
                    }
                    ready = self
                        .work
                        .wait_timeout(ready, Duration::from_millis(200))
                        .map_or_else(|e| e.into_inner().0, |r| r.0);
                    if self.stopping.load(Ordering::SeqCst) && ready.is_empty() {
                        return;
                    }
                }
            };
            let taken = Instant::now();
            let (frame, lost) = {
                let mut st = lock(&session.state);
                let f = st.queue.pop_front();
                if f.is_some() {
                    self.metrics.queue_depth.dec();
                }
                let lost = if f.is_some() {
                    std::mem::take(&mut st.lost)
                } else {
                    0
                };
                (f, lost)
            };
            session.space.notify_all();
            let scored = frame.is_some();
            if let Some(frame) = frame {
                let stamp = frame.stamp_ns;
                // One span per frame, named after its session and opening request.
                let span = tracing::debug_span!(
                    "frame",
                    session = %session.id,
                    request_id = %session.request_id,
                    stamp_ns = stamp,
                    kinematics_us = tracing::field::Empty,
                    render_us = tracing::field::Empty,
                    flow_us = tracing::field::Empty,
                    registration_us = tracing::field::Empty,
                    camera_us = tracing::field::Empty,
                    body_us = tracing::field::Empty,
                    model_us = tracing::field::Empty,
                    total_us = tracing::field::Empty,
                );
                let _entered = span.enter();
                if let Err(panic) =
                    catch_unwind(AssertUnwindSafe(|| self.score(&session, frame, lost)))
                {
                    self.recover(&session, stamp, panic_message(panic.as_ref()));
                }
            }
            let seconds = taken.elapsed().as_secs_f64();
            if scored {
                self.capacity.worked(seconds);
            }
            let mut st = lock(&session.state);
            if scored && !session.episode && !st.closed {
                st.load.scored(seconds);
                self.capacity
                    .scored(&session.profile_name, &session.share, &st.load, seconds);
                self.metrics.load_cores.set(self.capacity.load_cores());
            }
            if !st.queue.is_empty() && !st.closed {
                drop(st);
                lock(&self.ready).push_back(session);
                self.work.notify_one();
            } else {
                st.scheduled = false;
                let done = st.finishing && st.pending.is_empty() && !st.closed;
                drop(st);
                if done {
                    self.close(&session, None);
                }
            }
        }
    }

    /// After a panic while scoring frame `stamp` of `s`: the frame is reported failed,
    /// the session's scorer (whose state the panic may have left half-updated) is
    /// rebuilt from its profile, continuing its indices, and the session goes on.
    fn recover(&self, s: &Arc<Session>, stamp: i64, what: String) {
        self.metrics
            .scoring_panics
            .with_label_values(&[&s.profile_name])
            .inc();
        tracing::error!(session = %s.id, stamp_ns = stamp, "scoring panicked: {what}");
        let profile = s.profile();
        let rebuilt = match profile.setup.calibrated_scorer(&s.seed_key, s.maps) {
            Ok(mut fresh) => {
                let mut current = lock(&s.scorer);
                fresh.continue_after(&current);
                *current = fresh;
                "its scorer was rebuilt (the flow predictor warms up again)".to_string()
            }
            Err(e) => format!("its scorer could not be rebuilt ({e}) and goes on as it was"),
        };
        lock(&s.state).warm_reported = false;
        self.refuse(
            s,
            "internal",
            format!("frame failed: internal error while scoring it ({what}); {rebuilt}"),
            stamp,
        );
    }

    /// The depth image streamed with `msg`, decoded, if it fits `image`; one that cannot
    /// be used is reported to the client as a message error and the frame is scored with
    /// the assumed depth.
    fn live_depth(
        &self,
        s: &Session,
        msg: &LiveImage,
        image: &GrayImage,
        stamp: i64,
    ) -> (Option<DepthImage>, Option<Charge>) {
        let Some(depth) = msg.depth.as_deref() else {
            return (None, None);
        };
        let refused = |why: String| {
            self.message_error(
                s,
                "depth",
                format!("depth image refused: {why}; the frame is scored with the assumed depth"),
                stamp,
            );
        };
        match decode_live_depth(depth, self.config.max_image_pixels, Some(&self.budget)) {
            Ok((d, charge)) if d.fits(image.width(), image.height()) => (Some(d), charge),
            Ok((d, _)) => {
                let (w, h) = d.size();
                refused(format!(
                    "{w}x{h} does not fit the {}x{} image (another aspect ratio)",
                    image.width(),
                    image.height()
                ));
                (None, None)
            }
            Err(e) => {
                refused(e.to_string());
                (None, None)
            }
        }
    }

    /// Scores `frame`, `lost` images after the previous frame the worker took.
    fn score(&self, s: &Arc<Session>, frame: ReadyFrame, lost: u64) {
        let stamp = frame.stamp_ns;
        let started = Instant::now();
        // Held until the frame is scored: the buffered bytes, then the decoding's.
        let _buffered = frame.held;
        let decode_span = tracing::debug_span!("decode").entered();
        let (image, frame_camera, recorded_depth, _decoding, live) = match frame.image {
            ImagePayload::Decoded(img, k, depth) => (img, k, depth, None, None),
            ImagePayload::Live(msg) => {
                match decode_live_image(&msg, self.config.max_image_pixels, Some(&self.budget)) {
                    Ok((img, charge)) => (img, None, None, charge, Some(msg)),
                    Err(e) => {
                        lock(&s.state).lost += 1 + lost;
                        self.refuse(s, "image", format!("image refused: {e}"), stamp);
                        return;
                    }
                }
            }
        };
        let (depth, _depth_decoding) = match (recorded_depth, live.as_ref()) {
            (Some(d), _) => (Some(d), None),
            (None, Some(msg)) => self.live_depth(s, msg, &image, stamp),
            (None, None) => (None, None),
        };
        if Self::take_injected(&self.injected_frame_panics) {
            panic!("injected scoring panic");
        }
        drop(decode_span);
        let decode_s = started.elapsed().as_secs_f64();
        let intrinsics = frame_camera.or_else(|| {
            s.camera.and_then(|k| {
                // The open message's camera at the image's resolution.
                (k.width as usize == image.width() && k.height as usize == image.height())
                    .then_some(k)
            })
        });
        // The image as received goes to the session's recording, if it has one.
        let record_started = Instant::now();
        {
            let mut recorder = lock(&s.recorder);
            if let (Some(r), Some(msg)) = (recorder.as_mut(), live.as_ref())
                && let Err(e) = r.record(
                    msg,
                    frame.joints.as_ref().map(|j| {
                        (
                            j.names.as_slice(),
                            j.positions.as_slice(),
                            j.efforts.as_slice(),
                        )
                    }),
                    intrinsics.as_ref(),
                )
            {
                tracing::warn!(session = %s.id, "recording stopped: {e}");
                // What was recorded stays readable.
                if let Some(Err(e)) = recorder.take().map(super::recording::Recorder::finish) {
                    tracing::warn!(session = %s.id, "the session's recording is lost: {e}");
                }
            }
        }
        let record_s = record_started.elapsed().as_secs_f64();
        let joints = frame.joints.as_ref().map(|j| JointInput {
            names: &j.names,
            positions: &j.positions,
            efforts: &j.efforts,
        });
        let result = tracing::debug_span!("score").in_scope(|| {
            let mut scorer = lock(&s.scorer);
            if lost > 0 {
                scorer.restart_after_gap();
            }
            scorer.push(&FrameInput {
                stamp_ns: stamp,
                image: &image,
                joints,
                intrinsics: intrinsics.as_ref(),
                depth: depth.as_ref(),
            })
        });
        match result {
            Ok(Some(score)) => {
                let server = ServerStages {
                    decode_s,
                    record_s,
                    lost,
                };
                self.deliver(s, score, &image, frame.arrived, started, server);
            }
            Ok(None) => {}
            Err(e) => {
                // The scorer did not take the frame: the next one follows a gap.
                lock(&s.state).lost += 1;
                self.refuse(s, "frame", format!("frame refused: {e}"), stamp);
            }
        }
    }

    fn deliver(
        &self,
        s: &Arc<Session>,
        score: FrameScore,
        image: &GrayImage,
        arrived: Instant,
        started: Instant,
        server: ServerStages,
    ) {
        let m = &self.metrics;
        let profile = s.profile_name.as_str();
        m.frames.with_label_values(&[profile]).inc();
        s.frames_scored.fetch_add(1, Ordering::Relaxed);
        let t = &score.timings;
        // The pipeline's own stage timings, on the frame's span (the scorer's stages run
        // inside its `score` span; the pipeline itself opens no spans).
        let span = tracing::Span::current();
        for (field, v) in [
            ("kinematics_us", t.kinematics_us),
            ("render_us", t.render_us),
            ("flow_us", t.front_end.flow_us),
            ("registration_us", t.front_end.registration_us),
            ("camera_us", t.camera_us),
            ("body_us", t.body_us),
            ("model_us", t.model_us),
            ("total_us", t.total_us),
        ] {
            span.record(field, v);
        }
        let us = |v: u64| v as f64 * 1e-6;
        let f = &t.front_end;
        for (stage, v) in [
            ("decode", server.decode_s),
            ("record", server.record_s),
            ("kinematics", us(t.kinematics_us)),
            ("render", us(t.render_us)),
            ("prepare", us(f.prepare_us)),
            ("flow", us(f.flow_us)),
            ("registration", us(f.registration_us)),
            ("network_input", us(f.network_input_us)),
            ("camera", us(t.camera_us)),
            ("body", us(t.body_us)),
            ("scene", us(t.scene_us)),
            ("model", us(t.model_us)),
            ("total", us(t.total_us)),
        ] {
            m.stage_seconds.with_label_values(&[stage]).observe(v);
        }
        let live_started = Instant::now();
        let current = s.profile();
        if current.setup.model.is_some() {
            m.observe_inference(&current.model_label, us(t.model_us));
        }
        let detector = super::event::detector_of(&score);
        if score.anomaly {
            s.anomalies.fetch_add(1, Ordering::Relaxed);
            let label = detector.map_or("flow", Detector::name);
            m.anomalies.with_label_values(&[profile, label]).inc();
        }
        let warm_event = {
            let mut st = lock(&s.state);
            st.latest = Some(LatestScore {
                stamp_ns: score.stamp_ns,
                score: score.score,
                anomaly: score.anomaly,
            });
            let first = score.warming_up && !st.warm_reported;
            if first {
                st.warm_reported = true;
            }
            first
        };
        if warm_event {
            self.send(
                s,
                event(
                    &s.id,
                    EventKind::WarmingUp,
                    "the flow predictor is collecting its history: scores use e_c and e_b only",
                    score.stamp_ns,
                    0,
                ),
            );
        }
        // One clock reading for both, so compute time never exceeds latency.
        let now = Instant::now();
        let latency = now.saturating_duration_since(arrived).as_secs_f64();
        m.latency_seconds
            .with_label_values(&[profile])
            .observe(latency);
        // The live view: the frame shrunk, its anomaly map, the timeline point; then the
        // alarm tracker (an alarm's start keeps the frame's thumbnail).
        let thumb = live::thumbnail(image, live::THUMB_WIDTH);
        let map = live::anomaly_map(
            &score,
            &current.setup.profile.thresholds(),
            current.setup.profile.alarm_threshold(),
        );
        let alarm = self.track_alarm(s, &score, Some(&thumb));
        let anomaly_map = if s.maps { map.clone() } else { None };
        lock(&s.live).push(
            live::FramePoint::of(&score, s.alarm_on(), latency, server.lost),
            Some(thumb),
            map,
        );
        m.stage_seconds
            .with_label_values(&["live"])
            .observe(live_started.elapsed().as_secs_f64());
        let scored = ScoredFrame {
            score,
            latency_s: latency,
            compute_s: now.saturating_duration_since(started).as_secs_f64(),
            frames_lost: server.lost,
            anomaly_map,
        };
        self.send(s, Output::Score(scored));
        if let Some(a) = alarm {
            self.send(s, a);
        }
    }
}

/// What a frame spent in the worker outside the scorer, seconds.
struct ServerStages {
    /// Decoding the streamed image (and depth).
    decode_s: f64,
    /// Writing it to the session's recording.
    record_s: f64,
    /// Images lost before it.
    lost: u64,
}

/// The text of a caught panic's payload.
fn panic_message(panic: &(dyn std::any::Any + Send)) -> String {
    panic
        .downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| panic.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "a panic without a message".into())
}
