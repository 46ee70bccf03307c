//! `vamos profile init`: a starting profile for a new robot from one recorded bag (its
//! topics, its CameraInfo, the robot description it carries) and, optionally, a URDF or
//! robot package. The files are checked before anything is read, and the written profile
//! is loaded as `vamos score` would load it before the command says it is done.
//!
//! The robot's `package://NAME/...` meshes that are not beside its URDF are looked for in
//! the `--packages` folders, beside the episode, then in ROS's `ROS_PACKAGE_PATH` and
//! `AMENT_PREFIX_PATH`; the packages found are recorded in the profile
//! (`robot_packages`). Meshes still missing fail the command, naming them by package,
//! unless `--allow-missing-meshes`, which lists them in the notes.

use anyhow::{Context, Result, bail};
use serde_json::json;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use vamos::config::Settings;
use vamos::episode::McapEpisode;
use vamos::robot::description::find_package;
use vamos::robot::{CameraConvention, CameraSpec, MissingMesh, Robot};
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
    /// Where the robot's `package://NAME/...` meshes are: a ROS package folder, or a
    /// folder holding packages (a colcon workspace's `src/` or `install/`, searched four
    /// levels down); repeat for several. Searched first, then beside the episode
    /// (`NAME`, `src/`, `install/`, `share/` in its folder and the two above), then
    /// `ROS_PACKAGE_PATH` and `AMENT_PREFIX_PATH`.
    #[arg(long = "packages", value_name = "DIR")]
    pub packages: Vec<PathBuf>,
    /// Write the profile even when meshes of the robot stay missing (their links are then
    /// invisible to the camera: no body mask there, `e_b` blind to them); the JSON notes
    /// and `missing_meshes` list them. Without it, missing meshes fail the command.
    #[arg(long)]
    pub allow_missing_meshes: bool,
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

/// The files one run created: removed again when the run fails, so that the command can
/// be run again as it is (with `--packages`, say) without `--force`. Files that were
/// there before (replaced with `--force`) are not removed.
struct Written {
    created: Vec<PathBuf>,
    done: bool,
}

impl Written {
    fn write(&mut self, path: &Path, contents: &[u8]) -> Result<()> {
        let existed = path.exists();
        std::fs::write(path, contents)
            .with_context(|| format!("cannot write {}", path.display()))?;
        if !existed {
            self.created.push(path.to_path_buf());
        }
        Ok(())
    }
}

impl Drop for Written {
    fn drop(&mut self) {
        if !self.done {
            for f in &self.created {
                let _ = std::fs::remove_file(f);
            }
        }
    }
}

fn init(settings: &Settings, args: &InitArgs) -> Result<serde_json::Value> {
    let dir = &args.dir;
    for p in &args.packages {
        if !p.is_dir() {
            bail!(
                "--packages {}: not a folder (give a ROS package folder or a folder holding \
                 packages)",
                p.display()
            );
        }
    }
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
    let mut written = Written {
        created: Vec::new(),
        done: false,
    };

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
            written.write(&urdf_path, urdf.as_bytes())?;
            urdf_path.clone()
        }
    };
    let robot = load_robot(settings, args, &robot_path)?;
    let missing = robot.robot.missing_meshes();
    if !missing.is_empty() && !args.allow_missing_meshes {
        bail!("{}", missing_meshes_error(&robot, &missing, &robot_path));
    }
    let packages = robot.packages;
    let robot = robot.robot;

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
    written.write(
        &camera_path,
        (serde_json::to_string_pretty(&camera)? + "\n").as_bytes(),
    )?;

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
         robot = {robot}\n{robot_packages}\
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
        robot_packages = if packages.is_empty() {
            String::new()
        } else {
            format!(
                "# Where the robot's package:// meshes are (found by `vamos profile init`).\n\
                 robot_packages = [{}]\n",
                packages
                    .iter()
                    .map(|p| quoted(&p.dir.display().to_string()))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        },
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
    written.write(&profile_path, text.as_bytes())?;

    // Loaded as every command loads a profile: what was written works.
    Setup::load(settings, &profile_path).with_context(|| {
        format!(
            "the written profile {} does not load",
            profile_path.display()
        )
    })?;
    let mut notes = missing_meshes_notes(&robot, &missing, &packages);
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
    let render_packages: String = packages
        .iter()
        .map(|p| format!(" --packages {}", p.dir.display()))
        .collect();
    written.done = true;
    Ok(json!({
        "profile": shown(&profile_path),
        "camera": shown(&camera_path),
        "robot": shown(&robot_path),
        "robot_links": robot.links().len(),
        "packages": packages.iter().map(|p| json!({
            "package": p.name,
            "path": shown(&p.dir),
            "found_by": p.found_by,
        })).collect::<Vec<_>>(),
        "missing_meshes": missing,
        "robot_warnings": robot.other_warnings().collect::<Vec<_>>(),
        "camera_frame": frame,
        "convention": camera.convention,
        "image": [info.width, info.height],
        "processing": [width, height],
        "topics": chosen,
        "notes": notes,
        "next": [
            format!(
                "vamos render --robot {}{render_packages} --camera {} --episode {} --frame 10 \
                 -o overlay.png",
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

/// A ROS package found for the robot's meshes.
struct FoundPackage {
    /// The package's name (`package://NAME/...`).
    name: String,
    /// Its folder.
    dir: PathBuf,
    /// Where it was found: `--packages`, `beside the episode`, `ROS_PACKAGE_PATH` or
    /// `AMENT_PREFIX_PATH`.
    found_by: &'static str,
}

/// The robot with the packages its missing meshes were found in.
struct LoadedRobot {
    robot: Robot,
    packages: Vec<FoundPackage>,
    /// The places searched, for the error of meshes still missing.
    searched: Vec<String>,
}

/// The folders where the package `name` is looked for, each group with its label, in
/// order: the `--packages` folders; beside the episode, in its folder and the two above
/// (for a bag folder: itself and the two above), a folder called `name` and the
/// `src/`, `install/` and `share/` folders (searched below, as every root is); then
/// `ROS_PACKAGE_PATH`'s folders and `AMENT_PREFIX_PATH`'s prefixes' `share/`.
fn search_places(args: &InitArgs, name: &str) -> Vec<(&'static str, Vec<PathBuf>)> {
    let episode = std::path::absolute(&args.episode).unwrap_or_else(|_| args.episode.clone());
    let base = if episode.is_dir() {
        Some(episode.as_path())
    } else {
        episode.parent()
    };
    let beside: Vec<PathBuf> = base
        .into_iter()
        .flat_map(Path::ancestors)
        .take(3)
        .flat_map(|a| {
            [name, "src", "install", "share"]
                .into_iter()
                .map(move |sub| a.join(sub))
        })
        .collect();
    let env = |var: &str| -> Vec<PathBuf> {
        std::env::var_os(var)
            .map(|v| {
                std::env::split_paths(&v)
                    .filter(|p| !p.as_os_str().is_empty())
                    .collect()
            })
            .unwrap_or_default()
    };
    let ament: Vec<PathBuf> = env("AMENT_PREFIX_PATH")
        .into_iter()
        .map(|prefix| prefix.join("share"))
        .collect();
    vec![
        ("--packages", args.packages.clone()),
        ("beside the episode", beside),
        ("ROS_PACKAGE_PATH", env("ROS_PACKAGE_PATH")),
        ("AMENT_PREFIX_PATH", ament),
    ]
}

/// Loads the robot; the packages of meshes not found beside its URDF are looked for in
/// [`search_places`], and the robot is loaded again with the ones found.
fn load_robot(settings: &Settings, args: &InitArgs, path: &Path) -> Result<LoadedRobot> {
    let load = |packages: &[PathBuf]| {
        Robot::load_with_packages(path, packages, &settings.robot)
            .with_context(|| format!("cannot load robot {}", path.display()))
    };
    let robot = load(&[])?;
    let mut names: Vec<String> = robot
        .missing_meshes()
        .into_iter()
        .filter_map(|m| m.package)
        .collect();
    names.sort();
    names.dedup();
    let mut packages = Vec::new();
    for name in &names {
        let found = search_places(args, name)
            .into_iter()
            .find_map(|(by, roots)| find_package(name, &roots).map(|dir| (by, dir)));
        if let Some((found_by, dir)) = found {
            let dir = std::fs::canonicalize(&dir).unwrap_or(dir);
            packages.push(FoundPackage {
                name: name.clone(),
                dir,
                found_by,
            });
        }
    }
    let searched = {
        let episode = args.episode.display();
        let mut s = vec![format!(
            "in and above the URDF's folder ({})",
            path.parent().unwrap_or(Path::new(".")).display()
        )];
        if !args.packages.is_empty() {
            s.push(format!(
                "--packages {}",
                args.packages
                    .iter()
                    .map(|p| p.display().to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ));
        }
        s.push(format!(
            "beside {episode} (a folder named like the package, src/, install/ and share/, \
             in its folder and the two above)"
        ));
        for var in ["ROS_PACKAGE_PATH", "AMENT_PREFIX_PATH"] {
            if std::env::var_os(var).is_some_and(|v| !v.is_empty()) {
                s.push(var.to_string());
            } else {
                s.push(format!("{var} (not set)"));
            }
        }
        s
    };
    if packages.is_empty() {
        // Nothing new to look in: the first load stands.
        return Ok(LoadedRobot {
            robot,
            packages,
            searched,
        });
    }
    let dirs: Vec<PathBuf> = packages.iter().map(|p| p.dir.clone()).collect();
    Ok(LoadedRobot {
        robot: load(&dirs)?,
        packages,
        searched,
    })
}

/// The missing meshes grouped by package (`None`: not in a package), in the order the
/// URDF names them.
fn by_package(missing: &[MissingMesh]) -> Vec<(Option<&str>, Vec<&MissingMesh>)> {
    let mut groups: Vec<(Option<&str>, Vec<&MissingMesh>)> = Vec::new();
    for m in missing {
        let key = m.package.as_deref();
        match groups.iter_mut().find(|(k, _)| *k == key) {
            Some((_, list)) => list.push(m),
            None => groups.push((key, vec![m])),
        }
    }
    groups
}

/// `a, b, c`.
fn listed<'a>(items: impl IntoIterator<Item = &'a str>) -> String {
    items.into_iter().collect::<Vec<_>>().join(", ")
}

/// The links of `meshes`, each once, in order.
fn links_of(meshes: &[&MissingMesh]) -> String {
    let mut links: Vec<&str> = Vec::new();
    for m in meshes {
        for l in &m.links {
            if !links.contains(&l.as_str()) {
                links.push(l);
            }
        }
    }
    listed(links)
}

/// The error of meshes that stay missing: each package with its meshes, where it was
/// looked for, and how to give it.
fn missing_meshes_error(
    loaded: &LoadedRobot,
    missing: &[MissingMesh],
    robot_path: &Path,
) -> String {
    let groups = by_package(missing);
    let mut text = format!(
        "robot {:?}: {} mesh file{} not found, so the links that use {} would be invisible \
         to the camera (no body mask there, e_b blind to them):",
        loaded.robot.name(),
        missing.len(),
        if missing.len() == 1 { "" } else { "s" },
        if missing.len() == 1 { "it" } else { "them" },
    );
    let by_name: BTreeMap<&str, &FoundPackage> = loaded
        .packages
        .iter()
        .map(|p| (p.name.as_str(), p))
        .collect();
    for (package, meshes) in &groups {
        let paths = listed(meshes.iter().map(|m| m.path.as_str()));
        let links = links_of(meshes);
        match package.and_then(|p| by_name.get(p).map(|f| (p, f))) {
            Some((p, found)) => text.push_str(&format!(
                "\n  package {p:?}, found at {} ({}), lacks {} of its meshes: {paths} (links: \
                 {links})",
                found.dir.display(),
                found.found_by,
                meshes.len()
            )),
            None => match package {
                Some(p) => text.push_str(&format!(
                    "\n  package {p:?} not found ({} mesh{}): {paths} (links: {links})",
                    meshes.len(),
                    if meshes.len() == 1 { "" } else { "es" }
                )),
                None => text.push_str(&format!(
                    "\n  not in a package, relative to {} ({} mesh{}): {paths} (links: {links})",
                    robot_path.parent().unwrap_or(Path::new(".")).display(),
                    meshes.len(),
                    if meshes.len() == 1 { "" } else { "es" }
                )),
            },
        }
    }
    text.push_str(&format!(
        "\nSearched for packages: {}.\nGive the folder of each package with --packages DIR \
         (the package itself, or a folder holding packages such as a colcon workspace's src/ \
         or install/; repeat for several), or pass --allow-missing-meshes to write the \
         profile without them.",
        loaded.searched.join("; ")
    ));
    text
}

/// The notes of meshes left out (with `--allow-missing-meshes`): one per package, with
/// what it costs and how to give them.
fn missing_meshes_notes(
    robot: &Robot,
    missing: &[MissingMesh],
    packages: &[FoundPackage],
) -> Vec<String> {
    by_package(missing)
        .into_iter()
        .map(|(package, meshes)| {
            let found = package.and_then(|p| packages.iter().find(|f| f.name == p));
            let (what, remedy) = match (package, found) {
                (Some(p), Some(f)) => (
                    format!("package {p:?} at {} lacks them", f.dir.display()),
                    "give the folder of a complete copy with --packages DIR",
                ),
                (Some(p), None) => (
                    format!("package {p:?} not found"),
                    "give the package's folder with --packages DIR",
                ),
                (None, _) => (
                    "not found relative to the URDF".to_string(),
                    "put them where the URDF names them",
                ),
            };
            format!(
                "robot {:?}: {} mesh{} left out ({what}): {}; links {} are invisible to the \
                 camera (no body mask there: e_b cannot see them and their motion counts as \
                 scene motion); {remedy} and run `vamos profile init` again with --force",
                robot.name(),
                meshes.len(),
                if meshes.len() == 1 { "" } else { "es" },
                listed(meshes.iter().map(|m| m.path.as_str())),
                links_of(&meshes)
            )
        })
        .collect()
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
