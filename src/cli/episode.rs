//! `vamos episode inspect|copy`: what a recorded ROS 2 bag (MCAP) holds, and a copy of it
//! through vamos's reader and writer.

use anyhow::{Context, Result};
use serde_json::{Value, json};
use std::path::Path;
use std::path::PathBuf;
use vamos::config::Settings;
use vamos::episode::{
    EpisodeConfig, EpisodeError, EpisodeFrame, ImageData, McapEpisode, ScoreBagWriter,
};

#[derive(clap::Subcommand, Debug)]
pub enum Command {
    /// Print what a bag holds (topics, chosen topics, counts, labels, camera info) as one
    /// JSON object.
    Inspect {
        /// The bag (.mcap).
        bag: PathBuf,
        /// Also read every frame: count frames, warnings and errors.
        #[arg(long)]
        frames: bool,
    },
    /// Copy a bag through vamos's reader and writer (images, camera info, joints, URDF,
    /// plus per-frame diagnostics); recovers the valid part of a damaged bag.
    Copy {
        /// The input bag.
        input: PathBuf,
        /// The output bag (replaced).
        output: PathBuf,
        /// Re-encode the images as JPEG files of this quality (1-100), written as
        /// `sensor_msgs/msg/CompressedImage` on the same topic: what most robots' cameras
        /// stream (load tests, smaller bags). 8-bit images only.
        #[arg(long, value_name = "QUALITY", value_parser = clap::value_parser!(u8).range(1..=100))]
        jpeg: Option<u8>,
    },
}

/// Runs `vamos episode ...`.
pub fn run(settings: &Settings, command: Command) -> Result<()> {
    let out = match command {
        Command::Inspect { bag, frames } => inspect(&bag, &settings.episode, frames)?,
        Command::Copy {
            input,
            output,
            jpeg,
        } => copy(&input, &output, &settings.episode, jpeg)?,
    };
    println!("{out}");
    Ok(())
}

/// Opens `bag` and returns one JSON object: `info` (topics, chosen topics, counts,
/// duration, damage), `labels` (sidecar or label topic, or null), `camera_info` (first K,
/// width, height, or null) and `robot_description_bytes`. With `frames`, also reads every
/// frame and adds `frames` (count), `frame_errors` (messages) and the final
/// `skipped_backwards`.
pub fn inspect(bag: &Path, cfg: &EpisodeConfig, frames: bool) -> Result<Value> {
    // The episode's errors name the file.
    let ep = McapEpisode::open(bag, cfg)?;
    let labels = ep.labels()?;
    let camera = ep.camera_info()?.map(|c| {
        json!({ "width": c.width, "height": c.height, "k": c.k, "distortion_model": c.distortion_model })
    });
    let urdf = ep.robot_description()?;
    let mut out = json!({
        "labels": labels,
        "camera_info": camera,
        "robot_description_bytes": urdf.map(|u| u.len()),
    });
    if frames {
        let (mut ok, mut errors) = (0usize, Vec::new());
        let mut warnings = 0usize;
        for f in ep.frames() {
            match f {
                Ok(f) => {
                    ok += 1;
                    warnings += f.warnings.len();
                }
                Err(e) => errors.push(e.to_string()),
            }
        }
        out["frames"] = json!(ok);
        out["frame_warnings"] = json!(warnings);
        out["frame_errors"] = json!(errors);
    }
    out["info"] = serde_json::to_value(ep.info())?;
    Ok(out)
}

/// Copies `input` to `output` through [`McapEpisode::frames`] and [`ScoreBagWriter`]: the
/// image messages unchanged, the camera-info, joint-state and robot-description messages
/// with their schemas, plus per-frame diagnostics `/vamos/joint_gap_ms` (Float64),
/// `/vamos/joints_extrapolated` (Bool) and `/vamos/gray` (the decoded image, mono8); with
/// `jpeg`, the images re-encoded as JPEG files of that quality and no diagnostics.
/// Frames that fail and a damaged tail are skipped (the valid part of a truncated bag is
/// recovered). Returns a JSON summary.
pub fn copy(input: &Path, output: &Path, cfg: &EpisodeConfig, jpeg: Option<u8>) -> Result<Value> {
    let ep = McapEpisode::open(input, cfg)?;
    let info = ep.info();
    let mut w = ScoreBagWriter::create(output, Some(&info))?;
    let c = &info.chosen;
    let other: Vec<String> = [
        &c.camera_info,
        &c.joint_states,
        &c.robot_description,
        &c.labels,
    ]
    .into_iter()
    .flatten()
    .cloned()
    .collect();
    let mut copied = 0usize;
    let mut damage = None;
    for topic in &other {
        let Some((name, enc, data)) = ep.schema_of(topic)? else {
            continue;
        };
        let mut result = Ok(());
        let r = ep.for_each_message(std::slice::from_ref(topic), |t, _, log_time, msg| {
            if result.is_ok() {
                result = w.copy_message(t, &name, &enc, &data, msg, log_time);
                copied += 1;
            }
        });
        result?;
        match r {
            Ok(()) => {}
            Err(e @ EpisodeError::Truncated { .. }) => damage = Some(e.to_string()),
            Err(e) => return Err(e.into()),
        }
    }
    let (mut frames, mut errors) = (0usize, Vec::new());
    for f in ep.frames() {
        let f = match f {
            Ok(f) => f,
            Err(e @ EpisodeError::Truncated { .. }) => {
                damage = Some(e.to_string());
                continue;
            }
            Err(e) => {
                errors.push(e.to_string());
                continue;
            }
        };
        let Some(quality) = jpeg else {
            w.write_image(&c.image, f.stamp_ns, ImageData::Source(&f.source))?;
            write_diagnostics(&mut w, &f)?;
            frames += 1;
            continue;
        };
        // Re-encoded: the bag holds what a robot's camera driver records, nothing more.
        let (width, height, rgb) = f
            .source
            .to_rgb8(usize::MAX)
            .with_context(|| format!("image {} of {}", f.index, input.display()))?;
        let mut file = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut file, quality)
            .encode(
                &rgb,
                u32::try_from(width)?,
                u32::try_from(height)?,
                image::ExtendedColorType::Rgb8,
            )
            .context("JPEG encoding")?;
        let image = ImageData::Compressed {
            format: "jpeg",
            data: &file,
        };
        w.write_image(&c.image, f.stamp_ns, image)?;
        frames += 1;
    }
    w.finish()?;
    Ok(json!({
        "input": input.display().to_string(),
        "output": output.display().to_string(),
        "frames": frames,
        "other_messages": copied,
        "frame_errors": errors,
        "damage": damage,
    }))
}

/// The per-frame diagnostics of a plain copy: the joint states' gap and extrapolation,
/// and the image as vamos decoded it.
fn write_diagnostics(w: &mut ScoreBagWriter, f: &EpisodeFrame) -> Result<()> {
    if let Some(j) = &f.joints {
        w.write_f64("/vamos/joint_gap_ms", f.stamp_ns, j.gap_ns as f64 * 1e-6)?;
        w.write_bool("/vamos/joints_extrapolated", f.stamp_ns, j.extrapolated)?;
    }
    let gray: Vec<u8> = f
        .image
        .data()
        .iter()
        .map(|&v| v.round().clamp(0.0, 255.0) as u8)
        .collect();
    w.write_image(
        "/vamos/gray",
        f.stamp_ns,
        ImageData::Raw {
            width: u32::try_from(f.image.width())?,
            height: u32::try_from(f.image.height())?,
            encoding: "mono8",
            data: &gray,
        },
    )?;
    Ok(())
}
