//! `vamos profile init`: a starting profile for a new robot from one recorded bag (its
//! topics, its CameraInfo, the robot description it carries) and, optionally, a URDF or
//! robot package. The files are checked before anything is read, and the written profile
//! is loaded as `vamos score` would load it before the command says it is done.

use anyhow::{Context, Result, bail};
use serde_json::json;
use std::path::{Path, PathBuf};
use vamos::config::Settings;
use vamos::episode::McapEpisode;
use vamos::robot::{CameraConvention, CameraSpec, Robot};
use vamos::setup::Setup;

/// The processing width a new profile starts with (the benchmark's; an image narrower
/// than this keeps its own width).
const START_WIDTH: u32 = 320;

#[derive(clap::Subcommand, Debug)]
pub enum Command {
    /// Write a starting profile (profile.toml, camera.json and, from the bag's robot
    /// description, robot.urdf) into a folder from one recorded bag, then load it to check
    /// it; prints what it found and the next steps as JSON.
    Init(InitArgs),
}

#[derive(clap::Args, Debug)]
pub struct InitArgs {
    /// A recorded episode of the robot (ROS 2 bag in MCAP; topics found as `vamos
    /// episode inspect` finds them, or from `[episode.topics]`).
    #[arg(long)]
    pub episode: PathBuf,
    /// The robot (URDF file, package folder or archive); default: the URDF the bag carries
    /// on its robot-description topic, written to `robot.urdf`.
    #[arg(long)]
    pub robot: Option<PathBuf>,
    /// The URDF link of the camera; default: the CameraInfo's `frame_id`.
    #[arg(long)]
    pub camera_frame: Option<String>,
    /// Axis convention of that link; default: `optical` (z forward: the frame a ROS
    /// CameraInfo names, REP 103; `body` for a `camera_link`-style frame).
    #[arg(long, value_enum)]
    pub convention: Option<Convention>,
    /// The profile's name; default: the folder's name.
    #[arg(long)]
    pub name: Option<String>,
    /// Replace files already in the folder.
    #[arg(long)]
    pub force: bool,
    /// The folder to write (created if needed).
    pub dir: PathBuf,
}

/// `--convention`.
#[derive(clap::ValueEnum, Clone, Copy, Debug)]
pub enum Convention {
    /// z forward, x right, y down.
    Optical,
    /// x forward, y left, z up.
    Body,
}

/// Runs `vamos profile ...`.
pub fn run(settings: &Settings, command: Command) -> Result<()> {
    match command {
        Command::Init(args) => {
            let summary = init(settings, &args)?;
            println!("{}", serde_json::to_string_pretty(&summary)?);
            Ok(())
        }
    }
}

/// A TOML string literal.
fn quoted(s: &str) -> String {
    toml::Value::String(s.to_string()).to_string()
}

/// The processing size: at most [`START_WIDTH`] wide, the image's aspect kept, even sides.
fn processing_size(width: u32, height: u32) -> (u32, u32) {
    let w = width.min(START_WIDTH);
    let h = (f64::from(height) * f64::from(w) / f64::from(width)).round() as u32;
    ((w / 2 * 2).max(2), (h / 2 * 2).max(2))
}

fn init(settings: &Settings, args: &InitArgs) -> Result<serde_json::Value> {
    let dir = &args.dir;
    let profile_path = dir.join("profile.toml");
    let camera_path = dir.join("camera.json");
    let urdf_path = dir.join("robot.urdf");
    // Outputs first: nothing is read when they cannot be written.
    let mut outputs = vec![&profile_path, &camera_path];
    if args.robot.is_none() {
        outputs.push(&urdf_path);
    }
    if !args.force
        && let Some(existing) = outputs.iter().find(|p| p.exists())
    {
        bail!(
            "{} exists; pass --force to replace the starting profile's files",
            existing.display()
        );
    }
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let probe = dir.join(".vamos-write-check");
    std::fs::write(&probe, b"").with_context(|| format!("cannot write into {}", dir.display()))?;
    let _ = std::fs::remove_file(&probe);

    let bag = McapEpisode::open(&args.episode, &settings.episode)?;
    let chosen = bag.info().chosen.clone();
    let info = bag.camera_info()?.with_context(|| {
        format!(
            "{} has no sensor_msgs/msg/CameraInfo topic: write camera.json by hand (README, \
             \"camera.json\") or name the topic in [episode.topics] camera_info",
            args.episode.display()
        )
    })?;
    if info.width == 0 || info.height == 0 || info.k[0] <= 0.0 || info.k[4] <= 0.0 {
        bail!(
            "the CameraInfo on {} is not calibrated (width {}, height {}, fx {}, fy {}): \
             write camera.json by hand",
            chosen.camera_info.as_deref().unwrap_or("?"),
            info.width,
            info.height,
            info.k[0],
            info.k[4]
        );
    }

    // The robot: the one given, else the bag's description.
    let robot_path = match &args.robot {
        Some(p) => std::path::absolute(p).with_context(|| format!("{}", p.display()))?,
        None => {
            let urdf = bag.robot_description()?.with_context(|| {
                format!(
                    "{} carries no robot description (std_msgs/msg/String on \
                     *robot_description): pass --robot URDF",
                    args.episode.display()
                )
            })?;
            std::fs::write(&urdf_path, urdf.as_bytes())
                .with_context(|| format!("cannot write {}", urdf_path.display()))?;
            urdf_path.clone()
        }
    };
    let robot = Robot::load(&robot_path, &settings.robot)
        .with_context(|| format!("cannot load robot {}", robot_path.display()))?;

    let frame = match &args.camera_frame {
        Some(f) => f.clone(),
        None if !info.header.frame_id.is_empty() => info.header.frame_id.clone(),
        None => bail!(
            "the CameraInfo has no frame_id: pass --camera-frame LINK (links with \"camera\" \
             in their name: {})",
            camera_links(&robot)
        ),
    };
    if !robot.links().contains(&frame) {
        bail!(
            "the camera frame {frame:?} is not a link of robot {:?}: pass --camera-frame LINK \
             (links with \"camera\" in their name: {})",
            robot.name(),
            camera_links(&robot)
        );
    }
    let convention = match args.convention {
        Some(Convention::Optical) => CameraConvention::Optical,
        Some(Convention::Body) => CameraConvention::Body,
        None => CameraConvention::Optical,
    };
    let camera = CameraSpec {
        frame: frame.clone(),
        convention,
        width: info.width,
        height: info.height,
        fx: Some(info.k[0]),
        fy: Some(info.k[4]),
        cx: Some(info.k[2]),
        cy: Some(info.k[5]),
        k: None,
        hfov_deg: None,
        offset_xyz: None,
        offset_rpy: None,
    };
    robot
        .camera_for(&camera)
        .with_context(|| format!("the camera on link {frame:?}"))?;
    std::fs::write(&camera_path, serde_json::to_string_pretty(&camera)? + "\n")
        .with_context(|| format!("cannot write {}", camera_path.display()))?;

    let name = match &args.name {
        Some(n) => n.clone(),
        None => std::path::absolute(dir)?
            .file_name()
            .map_or_else(|| "robot".into(), |n| n.to_string_lossy().into_owned()),
    };
    let (width, height) = processing_size(info.width, info.height);
    let robot_ref = if args.robot.is_some() {
        robot_path.display().to_string()
    } else {
        "robot.urdf".into()
    };
    let mut text = format!(
        "# Written by `vamos profile init --episode {episode}`: a starting point.\n\
         # Next: check the overlay (`vamos render`), calibrate on nominal runs (`vamos\n\
         # calibrate`), then score or serve. Every key: README, \"Detection: profiles\".\n\
         name = {name}\n\
         robot = {robot}\n\
         camera = \"camera.json\"\n\
         flow_preset = \"realtime\"\n\
         # The conformal threshold on held-out nominal runs (`vamos calibrate --holdout`).\n\
         alarm = \"conformal\"\n\n\
         [pipeline]\n\
         stride = 1\n\n\
         [pipeline.frames]\n\
         # Processing resolution: the image scaled to at most {START_WIDTH} pixels wide.\n\
         width = {width}\n\
         height = {height}\n\
         variant = \"masked\"\n\n\
         # The bag's topics (a live robot's stream names them itself).\n\
         [topics]\n\
         image = {image}\n",
        // One comment line whatever the path holds.
        episode = args
            .episode
            .display()
            .to_string()
            .replace(['\n', '\r'], " "),
        name = quoted(&name),
        robot = quoted(&robot_ref),
        image = quoted(&chosen.image),
    );
    for (key, topic) in [
        ("camera_info", &chosen.camera_info),
        ("joint_states", &chosen.joint_states),
        ("robot_description", &chosen.robot_description),
    ] {
        if let Some(t) = topic {
            text.push_str(&format!("{key} = {}\n", quoted(t)));
        }
    }
    std::fs::write(&profile_path, &text)
        .with_context(|| format!("cannot write {}", profile_path.display()))?;

    // Loaded as every command loads a profile: what was written works.
    Setup::load(settings, &profile_path).with_context(|| {
        format!(
            "the written profile {} does not load",
            profile_path.display()
        )
    })?;
    let mut notes = Vec::new();
    if chosen.joint_states.is_none() {
        notes.push(
            "the bag has no sensor_msgs/msg/JointState topic: without joint states only the \
             image detectors run"
                .to_string(),
        );
    }
    if !info.d.iter().all(|&d| d == 0.0) {
        notes.push(format!(
            "the camera has {} distortion ({} coefficients): vamos assumes rectified images; \
             stream image_rect where there is one",
            info.distortion_model,
            info.d.len()
        ));
    }
    let shown = |p: &Path| p.display().to_string();
    Ok(json!({
        "profile": shown(&profile_path),
        "camera": shown(&camera_path),
        "robot": shown(&robot_path),
        "robot_links": robot.links().len(),
        "camera_frame": frame,
        "convention": camera.convention,
        "image": [info.width, info.height],
        "processing": [width, height],
        "topics": chosen,
        "notes": notes,
        "next": [
            format!(
                "vamos render --robot {} --camera {} --episode {} --frame 10 -o overlay.png",
                shown(&robot_path),
                shown(&camera_path),
                args.episode.display()
            ),
            format!(
                "vamos calibrate --profile {} NOMINAL_RUNS/ --holdout HELD_OUT_NOMINAL_RUNS/",
                shown(&profile_path)
            ),
        ],
    }))
}

/// The robot's links whose name mentions a camera, for an error message.
fn camera_links(robot: &Robot) -> String {
    let found: Vec<&str> = robot
        .links()
        .iter()
        .filter(|l| {
            let l = l.to_ascii_lowercase();
            l.contains("camera") || l.contains("optical") || l.contains("cam_")
        })
        .map(String::as_str)
        .collect();
    if found.is_empty() {
        "none".into()
    } else {
        found.join(", ")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_processing_size_keeps_the_aspect_at_most_320_wide() {
        assert_eq!(processing_size(640, 480), (320, 240));
        assert_eq!(processing_size(1280, 720), (320, 180));
        assert_eq!(processing_size(160, 120), (160, 120));
        assert_eq!(processing_size(1920, 1200), (320, 200));
    }
}
