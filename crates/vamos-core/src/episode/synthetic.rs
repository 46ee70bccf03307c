//! Synthetic ROS 2 bags for tests, benches and demos: a textured rgb8 image stream, joint
//! states at their own rate, camera info and a robot description, written with
//! [`ScoreBagWriter`] in the layout a robot's recorder produces (the default topic names).

use super::EpisodeError;
use super::bag::default_topic;
use super::ros::{self, Header, JointStateMsg, schema};
use super::writer::{ImageData, ScoreBagWriter};
use std::path::Path;

/// What [`write_bag`] writes.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticBag {
    /// Images.
    pub frames: usize,
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Image period, ns.
    pub image_period_ns: i64,
    /// Joint-state period, ns (0 = no joint states).
    pub joint_period_ns: i64,
    /// Joint names; positions are `0.3 sin(t + i)` rad for joint `i` at `t` seconds.
    pub joints: Vec<String>,
    /// Stamp of the first image, ns.
    pub start_ns: i64,
}

impl Default for SyntheticBag {
    fn default() -> Self {
        Self {
            frames: 30,
            width: 640,
            height: 480,
            image_period_ns: 33_333_333,
            joint_period_ns: 10_000_000,
            joints: vec!["joint1".into(), "joint2".into()],
            start_ns: 1_000_000_000,
        }
    }
}

impl SyntheticBag {
    /// Joint positions at `stamp_ns`.
    pub fn positions_at(&self, stamp_ns: i64) -> Vec<f64> {
        let t = (stamp_ns - self.start_ns) as f64 * 1e-9;
        (0..self.joints.len())
            .map(|i| 0.3 * (t + i as f64).sin())
            .collect()
    }

    /// The rgb8 pixels of image `i`: a moving gradient with pseudo-random texture (so
    /// compression and flow behave as on camera images).
    pub fn pixels(&self, i: usize) -> Vec<u8> {
        let (w, h) = (self.width as usize, self.height as usize);
        let mut out = Vec::with_capacity(w * h * 3);
        let mut state = 0x9e37_79b9_7f4a_7c15u64 ^ i as u64;
        for y in 0..h {
            for x in 0..w {
                state ^= state << 13;
                state ^= state >> 7;
                state ^= state << 17;
                let noise = (state & 0x1f) as usize;
                let v = (x + 2 * i + y / 2 + noise) % 256;
                out.extend_from_slice(&[v as u8, ((y + i + noise) % 256) as u8, (v / 2) as u8]);
            }
        }
        out
    }
}

/// Writes the bag to `path`.
pub fn write_bag(path: &Path, spec: &SyntheticBag) -> Result<(), EpisodeError> {
    let mut w = ScoreBagWriter::create(path, None)?;
    let urdf = "<robot name=\"synthetic\"><link name=\"base\"/></robot>";
    w.write_string(default_topic::ROBOT_DESCRIPTION, spec.start_ns - 1, urdf)?;
    let end_ns = spec.start_ns + spec.image_period_ns * spec.frames as i64;
    let js_def = ros::definition(schema::JOINT_STATE).unwrap_or_default();
    let mut next_joint = spec.start_ns - spec.joint_period_ns / 2;
    for i in 0..spec.frames {
        let stamp = spec.start_ns + spec.image_period_ns * i as i64;
        while spec.joint_period_ns > 0 && next_joint <= stamp.min(end_ns) {
            let msg = JointStateMsg {
                header: Header::from_stamp_ns(next_joint, ""),
                name: spec.joints.clone(),
                position: spec.positions_at(next_joint),
                velocity: Vec::new(),
                effort: Vec::new(),
            };
            w.copy_message(
                default_topic::JOINT_STATES,
                schema::JOINT_STATE,
                "ros2msg",
                js_def.as_bytes(),
                &msg.encode(),
                u64::try_from(next_joint).unwrap_or(0),
            )?;
            next_joint += spec.joint_period_ns;
        }
        let pixels = spec.pixels(i);
        w.write_image(
            default_topic::IMAGE,
            stamp,
            ImageData::Raw {
                width: spec.width,
                height: spec.height,
                encoding: "rgb8",
                data: &pixels,
            },
        )?;
    }
    // One joint sample after the last image, so every frame is interpolated.
    if spec.joint_period_ns > 0 {
        let msg = JointStateMsg {
            header: Header::from_stamp_ns(next_joint, ""),
            name: spec.joints.clone(),
            position: spec.positions_at(next_joint),
            velocity: Vec::new(),
            effort: Vec::new(),
        };
        w.copy_message(
            default_topic::JOINT_STATES,
            schema::JOINT_STATE,
            "ros2msg",
            js_def.as_bytes(),
            &msg.encode(),
            u64::try_from(next_joint).unwrap_or(0),
        )?;
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::episode::{EpisodeConfig, McapEpisode};

    #[test]
    fn synthetic_bag_reads_back_with_interpolated_joints() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.mcap");
        let spec = SyntheticBag {
            frames: 5,
            width: 32,
            height: 24,
            ..SyntheticBag::default()
        };
        write_bag(&path, &spec).unwrap();
        let ep = McapEpisode::open(&path, &EpisodeConfig::default()).unwrap();
        assert_eq!(ep.info().image_messages, 5);
        assert!(
            ep.robot_description()
                .unwrap()
                .unwrap()
                .contains("synthetic")
        );
        let frames: Vec<_> = ep.frames().map(|f| f.unwrap()).collect();
        assert_eq!(frames.len(), 5);
        for f in &frames {
            let j = f.joints.as_ref().unwrap();
            assert!(!j.extrapolated);
            // Linear interpolation of a sine over 10 ms: error below 0.3 * (0.01)^2 / 8.
            for (a, b) in j.positions.iter().zip(spec.positions_at(f.stamp_ns)) {
                assert!((a - b).abs() < 4e-6, "{a} {b}");
            }
        }
        let px = spec.pixels(2);
        let want = 0.299 * f32::from(px[0]) + 0.587 * f32::from(px[1]) + 0.114 * f32::from(px[2]);
        assert!((frames[2].image.get(0, 0) - want).abs() < 1e-3);
    }
}
