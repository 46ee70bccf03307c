//! Frames assembled from messages: images decoded, held until the joint sample after
//! their stamp, joint states interpolated to them.

use super::*;

/// The zstd frame magic (rosbag2's message and file compression).
pub(super) const ZSTD_MAGIC: [u8; 4] = [0x28, 0xb5, 0x2f, 0xfd];

pub(super) fn is_zstd(data: &[u8]) -> bool {
    data.starts_with(&ZSTD_MAGIC)
}

/// Decompresses a zstd-compressed message payload, refusing more than `limit` bytes
/// (read in steps, so a bomb costs at most `limit`).
pub(super) fn decompress_payload(data: &[u8], limit: usize) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let decoder = zstd::stream::read::Decoder::new(data).map_err(|e| e.to_string())?;
    let read = decoder
        .take(limit as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("zstd-compressed message: {e}"))?;
    if read > limit {
        return Err(format!(
            "zstd-compressed message decompresses to more than {limit} bytes"
        ));
    }
    Ok(out)
}

/// A decoded image waiting for joint samples.
pub(super) struct PendingFrame {
    pub(super) index: usize,
    pub(super) stamp_ns: i64,
    pub(super) image: GrayImage,
    pub(super) camera_info: Option<CameraInfoMsg>,
    pub(super) warnings: Vec<String>,
    pub(super) source: SourceMessage,
    pub(super) reserved: Option<Arc<dyn Reserved>>,
}

/// Turns the message stream into frames.
pub(super) struct Assembler {
    pub(super) image_topic: String,
    pub(super) max_image_bytes: usize,
    pub(super) max_gap_ns: f64,
    pub(super) joints_expected: bool,
    pub(super) pending: VecDeque<Result<PendingFrame, EpisodeError>>,
    pub(super) ready: VecDeque<Result<EpisodeFrame, EpisodeError>>,
    pub(super) camera_info: Option<CameraInfoMsg>,
    pub(super) last_image_stamp: Option<i64>,
    pub(super) size: Option<(usize, usize)>,
    pub(super) carry_warnings: Vec<String>,
    pub(super) images_seen: usize,
    pub(super) joint_msgs_seen: usize,
    pub(super) camera_msgs_seen: usize,
    pub(super) skipped: usize,
    // Joint window: stamps sorted ascending, positions and velocities row-major.
    pub(super) joint_names: Option<Vec<String>>,
    pub(super) joint_stamps: Vec<i64>,
    pub(super) joint_pos: Vec<f64>,
    pub(super) joint_vel: Vec<f64>,
    pub(super) joint_has_vel: Vec<bool>,
    pub(super) joint_eff: Vec<f64>,
    pub(super) joint_has_eff: Vec<bool>,
    pub(super) latest_joint_ns: Option<i64>,
    // Depth images: the topic, the decoded ones not yet past (stamp, message index,
    // image or why not), the latest stamp read.
    pub(super) depth_topic: Option<String>,
    pub(super) max_depth_gap_ns: f64,
    pub(super) depths: VecDeque<(i64, usize, Result<HeldDepth, String>)>,
    pub(super) depth_msgs_seen: usize,
    pub(super) latest_depth_ns: Option<i64>,
    pub(super) budget: Option<Arc<dyn DecodeBudget>>,
}

/// A decoded depth image and its reservation in the episode's budget.
pub(super) type HeldDepth = (DepthImage, Option<Arc<dyn Reserved>>);

/// Depth images held for the images still waiting: enough for a depth camera a few times
/// faster than the colour camera.
const MAX_HELD_DEPTHS: usize = 4 * MAX_PENDING_IMAGES;

pub(super) fn stamp_or_log_time(stamp_ns: i64, log_time: u64) -> i64 {
    if stamp_ns == 0 {
        i64::try_from(log_time).unwrap_or(i64::MAX)
    } else {
        stamp_ns
    }
}

impl Assembler {
    pub(super) fn new(
        ep: &McapEpisode,
        joints_expected: bool,
        depth_topic: Option<String>,
    ) -> Self {
        Self {
            image_topic: ep.info.chosen.image.clone(),
            max_image_bytes: ep.cfg.max_image_bytes,
            max_gap_ns: ep.cfg.max_joint_gap_ms * 1e6,
            joints_expected,
            pending: VecDeque::new(),
            ready: VecDeque::new(),
            camera_info: None,
            last_image_stamp: None,
            size: None,
            carry_warnings: Vec::new(),
            images_seen: 0,
            joint_msgs_seen: 0,
            camera_msgs_seen: 0,
            skipped: 0,
            joint_names: None,
            joint_stamps: Vec::new(),
            joint_pos: Vec::new(),
            joint_vel: Vec::new(),
            joint_has_vel: Vec::new(),
            joint_eff: Vec::new(),
            joint_has_eff: Vec::new(),
            latest_joint_ns: None,
            depth_topic,
            max_depth_gap_ns: ep.cfg.max_depth_gap_ms * 1e6,
            depths: VecDeque::new(),
            depth_msgs_seen: 0,
            latest_depth_ns: None,
            budget: ep.budget.clone(),
        }
    }

    pub(super) fn push(&mut self, m: RawMsg<'_>) {
        // rosbag2's per-message compression: the payload is a zstd frame.
        if is_zstd(m.data) {
            match decompress_payload(m.data, self.max_image_bytes) {
                Ok(data) => self.dispatch(RawMsg { data: &data, ..m }),
                Err(reason) => {
                    let index = if m.topic == self.image_topic {
                        self.images_seen += 1;
                        self.images_seen - 1
                    } else {
                        0
                    };
                    if self.depth_topic.as_deref() == Some(m.topic) {
                        // A depth image lost: its frame gets the assumed depth, not an error.
                        self.depth(m, Err(reason));
                        self.release(false);
                        return;
                    }
                    self.pending.push_back(Err(EpisodeError::BadMessage {
                        topic: m.topic.into(),
                        index,
                        reason,
                    }));
                    self.release(false);
                }
            }
        } else {
            self.dispatch(m);
        }
    }

    pub(super) fn dispatch(&mut self, m: RawMsg<'_>) {
        if m.topic == self.image_topic {
            let index = self.images_seen;
            self.images_seen += 1;
            let item = self.image(m, index);
            if let Some(item) = item {
                self.pending.push_back(item);
            }
        } else if self.depth_topic.as_deref() == Some(m.topic) {
            let decoded = ImageMsg::decode(m.data)
                .and_then(|msg| {
                    let stamp = msg.header.stamp_ns();
                    let pixels = self.max_image_bytes;
                    let encoded = msg.encoded();
                    let reserved = match &self.budget {
                        Some(_) => self.reserve(encoded.check(pixels)?)?,
                        None => None,
                    };
                    let depth = encoded.to_depth(pixels)?;
                    if let Some(r) = &reserved {
                        r.resize(std::mem::size_of_val(depth.metres()) as u64);
                    }
                    Ok((stamp, (depth, reserved)))
                })
                .map_err(|e| e.to_string());
            self.depth(m, decoded);
        } else if m.schema == schema::CAMERA_INFO {
            let index = self.camera_msgs_seen;
            self.camera_msgs_seen += 1;
            match CameraInfoMsg::decode(m.data) {
                Ok(ci) => self.camera_info = Some(ci),
                Err(e) => self.pending.push_back(Err(bad(m.topic, index, e))),
            }
        } else if m.schema == schema::JOINT_STATE {
            let index = self.joint_msgs_seen;
            self.joint_msgs_seen += 1;
            if let Err(e) = self.joint(m.data, m.log_time) {
                self.pending.push_back(Err(EpisodeError::BadMessage {
                    topic: m.topic.into(),
                    index,
                    reason: e,
                }));
            }
        }
        self.release(false);
    }

    pub(super) fn image(
        &mut self,
        m: RawMsg<'_>,
        index: usize,
    ) -> Option<Result<PendingFrame, EpisodeError>> {
        if m.data.len() > self.max_image_bytes {
            return Some(Err(EpisodeError::BadMessage {
                topic: m.topic.into(),
                index,
                reason: format!(
                    "{} bytes exceed max_image_bytes {}",
                    m.data.len(),
                    self.max_image_bytes
                ),
            }));
        }
        let decoded = if m.schema == schema::COMPRESSED_IMAGE {
            CompressedImageMsg::decode(m.data).and_then(|c| {
                let (image, reserved) = self.decode_gray(&c.encoded())?;
                Ok((c.header.stamp_ns(), image, reserved))
            })
        } else {
            ImageMsg::decode(m.data).and_then(|c| {
                let (image, reserved) = self.decode_gray(&c.encoded())?;
                Ok((c.header.stamp_ns(), image, reserved))
            })
        };
        let (stamp, image, reserved) = match decoded {
            Ok(v) => v,
            Err(MessageError::UnknownEncoding { encoding }) => {
                return Some(Err(EpisodeError::UnknownEncoding {
                    topic: m.topic.into(),
                    index,
                    encoding,
                }));
            }
            Err(e) => return Some(Err(bad(m.topic, index, e))),
        };
        let stamp_ns = stamp_or_log_time(stamp, m.log_time);
        if let Some(prev) = self.last_image_stamp
            && stamp_ns <= prev
        {
            self.skipped += 1;
            self.carry_warnings.push(format!(
                "image {index} skipped: stamp {stamp_ns} ns does not increase (previous {prev} ns)"
            ));
            return None;
        }
        let (w, h) = image.size();
        match self.size {
            None => self.size = Some((w, h)),
            Some((ew, eh)) if (ew, eh) != (w, h) => {
                return Some(Err(EpisodeError::ImageSizeChanged {
                    index,
                    expected_width: ew,
                    expected_height: eh,
                    width: w,
                    height: h,
                }));
            }
            Some(_) => {}
        }
        self.last_image_stamp = Some(stamp_ns);
        Some(Ok(PendingFrame {
            index,
            stamp_ns,
            image,
            camera_info: self.camera_info.clone(),
            warnings: std::mem::take(&mut self.carry_warnings),
            source: SourceMessage {
                topic: m.topic.into(),
                schema: m.schema.into(),
                log_time_ns: m.log_time,
                cdr: m.data.to_vec(),
            },
            reserved,
        }))
    }

    /// Room in the episode's budget (when it has one) for a decoding of `size`: its peak
    /// reserved before a byte is decoded.
    fn reserve(&self, size: CheckedSize) -> Result<Option<Arc<dyn Reserved>>, MessageError> {
        self.budget
            .as_ref()
            .map(|b| {
                b.reserve(size.peak_bytes)
                    .map_err(|reason| MessageError::BadSize {
                        reason: format!(
                            "the {}x{} image is not decoded: {reason}",
                            size.width, size.height
                        ),
                    })
            })
            .transpose()
    }

    /// An image decoded to gray within the episode's budget: the reservation, shrunk to
    /// the gray image, goes with it.
    fn decode_gray(
        &self,
        encoded: &EncodedImage<'_>,
    ) -> Result<(GrayImage, Option<Arc<dyn Reserved>>), MessageError> {
        let reserved = match &self.budget {
            Some(_) => self.reserve(encoded.check(self.max_image_bytes)?)?,
            None => None,
        };
        let image = encoded.to_gray(self.max_image_bytes)?;
        if let Some(r) = &reserved {
            r.resize(std::mem::size_of_val(image.data()) as u64);
        }
        Ok((image, reserved))
    }

    /// Holds a depth message (decoded, or why it is not) for the frames near its stamp.
    fn depth(&mut self, m: RawMsg<'_>, decoded: Result<(i64, HeldDepth), String>) {
        let index = self.depth_msgs_seen;
        self.depth_msgs_seen += 1;
        let (stamp_ns, item) = match decoded {
            Ok((stamp, d)) => (stamp_or_log_time(stamp, m.log_time), Ok(d)),
            // Undecodable: placed at its log time, so the frame it was for says why.
            Err(reason) => (stamp_or_log_time(0, m.log_time), Err(reason)),
        };
        let at = self.depths.partition_point(|(t, _, _)| *t <= stamp_ns);
        self.depths.insert(at, (stamp_ns, index, item));
        if self.depths.len() > MAX_HELD_DEPTHS {
            self.depths.pop_front();
        }
        self.latest_depth_ns = Some(self.latest_depth_ns.map_or(stamp_ns, |l| l.max(stamp_ns)));
    }

    /// The depth image for a frame at `stamp_ns`: the nearest held one within the gap,
    /// with a warning when there is none or it cannot be used. Depth images older than
    /// the gap before this stamp are dropped (later frames have later stamps).
    fn depth_for(
        &mut self,
        stamp_ns: i64,
        size: (usize, usize),
        warnings: &mut Vec<String>,
    ) -> Option<HeldDepth> {
        let topic = self.depth_topic.as_deref()?;
        let gap = |t: i64| (t.saturating_sub(stamp_ns)).unsigned_abs() as f64;
        let nearest = (0..self.depths.len())
            .min_by(|&a, &b| gap(self.depths[a].0).total_cmp(&gap(self.depths[b].0)));
        let found = match nearest {
            Some(i) if gap(self.depths[i].0) <= self.max_depth_gap_ns => {
                let (_, index, item) = &self.depths[i];
                match item {
                    Ok((d, reserved)) if d.fits(size.0, size.1) => {
                        Some((d.clone(), reserved.clone()))
                    }
                    Ok((d, _)) => {
                        let (w, h) = d.size();
                        warnings.push(format!(
                            "{topic} message {index}: depth image {w}x{h} does not fit the \
                             {}x{} image (another aspect ratio); assumed depth used",
                            size.0, size.1
                        ));
                        None
                    }
                    Err(reason) => {
                        warnings.push(format!(
                            "{topic} message {index}: {reason}; assumed depth used"
                        ));
                        None
                    }
                }
            }
            _ => {
                warnings.push(format!(
                    "no {topic} image within {:.0} ms; assumed depth used",
                    self.max_depth_gap_ns * 1e-6
                ));
                None
            }
        };
        let horizon = stamp_ns as f64 - self.max_depth_gap_ns;
        while self
            .depths
            .front()
            .is_some_and(|(t, _, _)| (*t as f64) < horizon)
        {
            self.depths.pop_front();
        }
        found
    }

    pub(super) fn joint(&mut self, data: &[u8], log_time: u64) -> Result<(), String> {
        let msg = JointStateMsg::decode(data).map_err(|e| e.to_string())?;
        let stamp = stamp_or_log_time(msg.header.stamp_ns(), log_time);
        let names = self.joint_names.get_or_insert_with(|| msg.name.clone());
        // Map the message's order onto the first message's names.
        let order: Vec<usize> = if *names == msg.name {
            (0..names.len()).collect()
        } else {
            names
                .iter()
                .map(|n| {
                    msg.name
                        .iter()
                        .position(|m| m == n)
                        .ok_or_else(|| format!("joint {n} missing (names {:?})", msg.name))
                })
                .collect::<Result<_, _>>()?
        };
        let at = self.joint_stamps.partition_point(|&t| t <= stamp);
        if at > 0 && self.joint_stamps[at - 1] == stamp {
            return Err(format!("duplicate joint stamp {stamp} ns"));
        }
        let n = order.len();
        let has_vel = !msg.velocity.is_empty();
        // Efforts are optional and not checked by the decoder: one per name, all finite,
        // or none at this sample.
        let has_eff =
            msg.effort.len() == msg.name.len() && msg.effort.iter().all(|e| e.is_finite());
        self.joint_stamps.insert(at, stamp);
        self.joint_has_vel.insert(at, has_vel);
        self.joint_has_eff.insert(at, has_eff);
        let pos: Vec<f64> = order.iter().map(|&i| msg.position[i]).collect();
        let column = |values: &[f64], has: bool| -> Vec<f64> {
            order
                .iter()
                .map(|&i| if has { values[i] } else { 0.0 })
                .collect()
        };
        let vel = column(&msg.velocity, has_vel);
        let eff = column(&msg.effort, has_eff);
        self.joint_pos.splice(at * n..at * n, pos);
        self.joint_vel.splice(at * n..at * n, vel);
        self.joint_eff.splice(at * n..at * n, eff);
        self.latest_joint_ns = Some(self.latest_joint_ns.map_or(stamp, |l| l.max(stamp)));
        Ok(())
    }

    /// Moves frames whose joints are known (or all, at the end) to `ready`.
    pub(super) fn release(&mut self, at_end: bool) {
        while let Some(front) = self.pending.front() {
            let go = match front {
                Err(_) => true,
                Ok(p) => {
                    let joints_known = !self.joints_expected
                        || self.latest_joint_ns.is_some_and(|l| l >= p.stamp_ns);
                    let depth_known = self.depth_topic.is_none()
                        || self.latest_depth_ns.is_some_and(|l| l >= p.stamp_ns);
                    at_end
                        || (joints_known && depth_known)
                        || self.pending.len() > MAX_PENDING_IMAGES
                }
            };
            if !go {
                break;
            }
            match self.pending.pop_front() {
                Some(Ok(p)) => {
                    let frame = self.finish_frame(p);
                    self.ready.push_back(Ok(frame));
                }
                Some(Err(e)) => self.ready.push_back(Err(e)),
                None => break,
            }
        }
    }

    pub(super) fn finish_frame(&mut self, p: PendingFrame) -> EpisodeFrame {
        let mut warnings = p.warnings;
        let (depth, depth_reserved) =
            match self.depth_for(p.stamp_ns, p.image.size(), &mut warnings) {
                Some((d, r)) => (Some(d), r),
                None => (None, None),
            };
        let joints = match &self.joint_names {
            Some(names) if !self.joint_stamps.is_empty() => {
                let n = names.len();
                let s = interpolate_rows(&self.joint_stamps, &self.joint_pos, n, p.stamp_ns);
                // Velocities and efforts only when both samples used carry them.
                let optional = |has: &[bool], values: &[f64]| {
                    interpolate_optional(&self.joint_stamps, values, has, n, p.stamp_ns)
                };
                let velocities = optional(&self.joint_has_vel, &self.joint_vel);
                let efforts = optional(&self.joint_has_eff, &self.joint_eff);
                let beyond_max_gap = s.gap_ns as f64 > self.max_gap_ns;
                if beyond_max_gap {
                    warnings.push(format!(
                        "nearest joint sample is {:.1} ms away",
                        s.gap_ns as f64 * 1e-6
                    ));
                }
                // Later images have later stamps: samples before the last one at or
                // before this stamp are no longer needed.
                let keep_from = self
                    .joint_stamps
                    .partition_point(|&t| t < p.stamp_ns)
                    .saturating_sub(1);
                if keep_from > 0 {
                    self.joint_stamps.drain(..keep_from);
                    self.joint_has_vel.drain(..keep_from);
                    self.joint_has_eff.drain(..keep_from);
                    self.joint_pos.drain(..keep_from * n);
                    self.joint_vel.drain(..keep_from * n);
                    self.joint_eff.drain(..keep_from * n);
                }
                Some(JointStateAt {
                    names: names.clone(),
                    positions: s.positions,
                    velocities,
                    efforts,
                    gap_ns: s.gap_ns,
                    extrapolated: s.extrapolated,
                    beyond_max_gap,
                })
            }
            _ => None,
        };
        EpisodeFrame {
            index: p.index,
            stamp_ns: p.stamp_ns,
            image: p.image,
            camera_info: p.camera_info,
            joints,
            depth,
            warnings,
            source: p.source,
            reserved: p.reserved.into_iter().chain(depth_reserved).collect(),
        }
    }
}

pub(super) fn bad(topic: &str, index: usize, e: MessageError) -> EpisodeError {
    EpisodeError::BadMessage {
        topic: topic.into(),
        index,
        reason: e.to_string(),
    }
}
