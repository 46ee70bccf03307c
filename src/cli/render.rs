//! `vamos render`: draws the robot as the configured camera sees it (body mask, depth and
//! the expected body flow between two joint states), so users can check a robot set-up
//! (URDF, camera link and convention, intrinsics) against a real camera image.

use anyhow::{Context, Result, bail};
use serde_json::{Map, Value, json};
use std::path::{Path, PathBuf};
use vamos::config::Settings;
use vamos::episode::{EpisodeConfig, EpisodeFrame, McapEpisode};
use vamos::robot::render::{
    RenderConfig, RenderFrame, RenderOutput, RobotView, create_renderer, tvl1_body_flow,
};
use vamos::robot::{CameraSpec, Robot, RobotConfig};
use vamos::vision::GrayImage;
use vamos::vision::flow::FlowParams;
use vamos::vision::flowio::flow_to_rgb;
use vamos::vision::preprocess::{ResizeFilter, resize};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// URDF file, robot package folder, or .zip / .tar.gz package archive.
    #[arg(long)]
    pub robot: PathBuf,
    /// Where the robot's `package://NAME/...` meshes are: a ROS package folder or a
    /// folder holding packages (as a profile's `robot_packages`); repeat for several.
    #[arg(long = "packages", value_name = "DIR")]
    pub packages: Vec<PathBuf>,
    /// JSON object of joint name -> position at time t (or --episode and --frame).
    #[arg(long, required_unless_present = "episode")]
    pub joints: Option<PathBuf>,
    /// Joint positions at t-1: adds the expected body flow t-1 -> t.
    #[arg(long)]
    pub previous_joints: Option<PathBuf>,
    /// A recorded episode (ROS 2 bag in MCAP, topics from `[episode]`): take the joint
    /// states at image `--frame` (and at the image before it, for the expected flow) and
    /// draw over that image, to check the overlay on a real frame.
    #[arg(long, requires = "frame", conflicts_with_all = ["joints", "previous_joints"])]
    pub episode: Option<PathBuf>,
    /// The image of --episode to draw: its index on the image topic, from 0 (`vamos
    /// episode inspect --frames` counts them).
    #[arg(long, requires = "episode")]
    pub frame: Option<usize>,
    /// Camera JSON: {"frame": LINK, "convention": "optical"|"body", "width": W,
    /// "height": H, and "fx","fy","cx","cy" or "k" (CameraInfo) or "hfov_deg"}.
    #[arg(long)]
    pub camera: PathBuf,
    /// Output PNG.
    #[arg(short, long)]
    pub out: PathBuf,
    /// A real camera image to draw the mask over.
    #[arg(long)]
    pub background: Option<PathBuf>,
    /// Render width (intrinsics scaled; default: the camera's).
    #[arg(long)]
    pub width: Option<u32>,
    /// Render height (default: keeps the camera's aspect ratio).
    #[arg(long)]
    pub height: Option<u32>,
    /// The paper's expected flow (TV-L1 on two shaded renders) instead of the exact one.
    #[arg(long)]
    pub tvl1: bool,
}

/// Renders, writes the image and prints the JSON summary.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    super::check_output_file("--out", &args.out)?;
    let summary = render(&args, &settings.robot, &settings.render, &settings.episode)?;
    println!("{summary}");
    Ok(())
}

/// Renders and writes the image; returns the JSON summary to print.
pub fn render(
    opts: &Args,
    robot_cfg: &RobotConfig,
    render_cfg: &RenderConfig,
    episode_cfg: &EpisodeConfig,
) -> Result<Value> {
    // The recorded frame first: a bad bag or frame number fails before any loading.
    let recorded = match (&opts.episode, opts.frame) {
        (Some(bag), Some(n)) => Some(recorded_frame(bag, n, episode_cfg)?),
        _ => None,
    };
    let robot = Robot::load_with_packages(&opts.robot, &opts.packages, robot_cfg)
        .with_context(|| format!("cannot load robot {}", opts.robot.display()))?;
    for w in robot.warnings() {
        tracing::warn!(robot = %opts.robot.display(), "{w}");
    }
    let spec: CameraSpec = read_json(&opts.camera, "a camera description")?;
    let mut k = spec.intrinsics()?;
    if opts.width.is_some() || opts.height.is_some() {
        let w = opts.width.unwrap_or(k.width);
        let h = opts.height.unwrap_or_else(|| {
            (f64::from(k.height) * f64::from(w) / f64::from(k.width)).round() as u32
        });
        k = k.scaled_to(w, h)?;
    }
    let mount = robot
        .camera_for(&spec)
        .with_context(|| format!("camera link {:?}", spec.frame))?;
    let mut mapper = robot.joint_mapper();
    let mut pose_of = |pairs: &[(String, f64)]| -> Result<_> {
        let q = mapper
            .map_pairs(pairs.iter().map(|(n, v)| (n.as_str(), *v)))?
            .positions;
        let base_from_link = robot.forward(&q)?;
        let camera_from_base = mount
            .camera_from_base(&base_from_link)
            .with_context(|| format!("camera link {:?} has no pose", spec.frame))?;
        Ok((base_from_link, camera_from_base))
    };
    let (now, before) = match &recorded {
        Some(r) => (r.now.clone(), r.previous.clone()),
        None => {
            let path = opts
                .joints
                .as_deref()
                .context("--joints or --episode is needed")?;
            let before = opts
                .previous_joints
                .as_deref()
                .map(joint_file)
                .transpose()?;
            (joint_file(path)?, before)
        }
    };
    let (links_t, camera_t) = pose_of(&now)?;
    let previous = before.as_deref().map(&mut pose_of).transpose()?;
    let unknown = mapper.unknown_total();

    let mut renderer = create_renderer(render_cfg)?;
    renderer.prepare(robot.link_meshes())?;
    let current = RobotView {
        camera_from_base: camera_t,
        base_from_link: &links_t,
    };
    let prev_view = previous.as_ref().map(|(l, c)| RobotView {
        camera_from_base: *c,
        base_from_link: l,
    });
    let mut out = RenderOutput::default();
    let flow = match (prev_view, opts.tvl1) {
        (Some(p), true) => {
            let mut scratch = RenderOutput::default();
            Some(tvl1_body_flow(
                renderer.as_mut(),
                &k,
                p,
                current,
                &FlowParams::default(),
                &mut scratch,
                &mut out,
            )?)
        }
        (p, _) => {
            renderer.render(
                &RenderFrame {
                    intrinsics: &k,
                    current,
                    previous: p,
                    shade: false,
                },
                &mut out,
            )?;
            p.map(|_| out.flow.clone())
        }
    };
    if opts.tvl1 && flow.is_none() {
        bail!("--tvl1 needs --previous-joints");
    }

    let background = match (&opts.background, &recorded) {
        (Some(path), _) => {
            let img = GrayImage::load(path)
                .with_context(|| format!("background image {}", path.display()))?;
            Some(resize(&img, out.width, out.height, ResizeFilter::Area)?)
        }
        (None, Some(r)) => Some(resize(&r.image, out.width, out.height, ResizeFilter::Area)?),
        (None, None) => None,
    };
    write_panels(&opts.out, &out, flow.as_ref(), background.as_ref())?;

    let finite_depth: Vec<f32> = out
        .depth_m
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    // Over the body mask, as e_b takes it (TV-L1's field also covers the background).
    let median = |v: &[f32]| -> Option<f64> {
        let mut f: Vec<f32> = v
            .iter()
            .zip(&out.mask)
            .filter(|&(x, &m)| m && x.is_finite())
            .map(|(&x, _)| x)
            .collect();
        if f.is_empty() {
            return None;
        }
        f.sort_by(f32::total_cmp);
        Some(f64::from(f[f.len() / 2]))
    };
    let mut warnings: Vec<String> = robot.warnings().to_vec();
    if unknown > 0 {
        warnings.push(format!(
            "{unknown} joint names are not in the robot and were ignored"
        ));
    }
    if out.covered_pixels() == 0 {
        warnings.push(format!(
            "the robot is not visible from camera {:?}: check the camera link, its \
             convention (optical: z forward; body: x forward) and the joint positions",
            spec.frame
        ));
    }
    let t = camera_t.translation.vector;
    let q = camera_t.rotation.coords;
    Ok(json!({
        "output": opts.out,
        "backend": renderer.name(),
        "width": out.width,
        "height": out.height,
        "triangles": robot.triangle_count(),
        "covered_px": out.covered_pixels(),
        "mask_px": out.mask_pixels(),
        "depth_m": {
            "min": finite_depth.iter().copied().reduce(f32::min),
            "max": finite_depth.iter().copied().reduce(f32::max),
        },
        "camera_from_base": {"translation": [t.x, t.y, t.z], "rotation_xyzw": [q.x, q.y, q.z, q.w]},
        "expected_flow_median_px": flow.as_ref().map(|f| [median(&f.u), median(&f.v)]),
        "expected_flow": if flow.is_none() { "none" } else if opts.tvl1 { "tvl1" } else { "exact" },
        "episode_frame": recorded.as_ref().map(|r| json!({
            "index": r.index,
            "stamp_ns": r.stamp_ns,
            "expected_flow_from_previous_frame": r.previous.is_some(),
        })),
        "warnings": warnings,
    }))
}

/// A JSON object of joint name -> position.
fn joint_file(path: &Path) -> Result<Vec<(String, f64)>> {
    let given: Map<String, Value> = read_json(path, "a JSON object of joint name -> position")?;
    given
        .iter()
        .map(|(name, v)| {
            let value = v.as_f64().with_context(|| {
                format!("{}: joint {name:?}: {v} is not a number", path.display())
            })?;
            Ok((name.clone(), value))
        })
        .collect()
}

/// Image `index` of a recorded episode with its joint states, and the joint states of
/// the image before it.
struct RecordedFrame {
    index: usize,
    stamp_ns: i64,
    image: GrayImage,
    now: Vec<(String, f64)>,
    previous: Option<Vec<(String, f64)>>,
}

fn recorded_frame(bag: &Path, index: usize, cfg: &EpisodeConfig) -> Result<RecordedFrame> {
    let episode = McapEpisode::open(bag, cfg)
        .with_context(|| format!("cannot open episode {}", bag.display()))?;
    let pairs = |f: &EpisodeFrame| {
        f.joints.as_ref().map(|j| {
            j.names
                .iter()
                .cloned()
                .zip(j.positions.iter().copied())
                .collect::<Vec<_>>()
        })
    };
    let mut previous = None;
    for frame in episode.frames() {
        let frame = frame.with_context(|| format!("{}: reading frames", bag.display()))?;
        if frame.index > index {
            break;
        }
        if frame.index == index {
            let now = pairs(&frame).with_context(|| {
                format!(
                    "{}: image {index} has no joint states (the bag has no joint-state topic)",
                    bag.display()
                )
            })?;
            return Ok(RecordedFrame {
                index,
                stamp_ns: frame.stamp_ns,
                image: frame.image,
                now,
                previous,
            });
        }
        previous = pairs(&frame);
    }
    bail!(
        "{}: no image {index} (images are numbered from 0 on their topic; `vamos episode \
         inspect --frames` counts them)",
        bag.display()
    )
}

fn read_json<T: serde::de::DeserializeOwned>(path: &Path, what: &str) -> Result<T> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} must be {what}", path.display()))
}

/// Three panels side by side: the mask (red, over the background when given), the depth
/// (near = bright, no robot = black) and the expected flow (colour wheel, no flow = gray).
fn write_panels(
    path: &Path,
    out: &RenderOutput,
    flow: Option<&vamos::vision::FlowField>,
    background: Option<&GrayImage>,
) -> Result<()> {
    let (w, h) = (out.width, out.height);
    let mut img = image::RgbImage::new(3 * w as u32, h as u32);
    let finite: Vec<f32> = out
        .depth_m
        .iter()
        .copied()
        .filter(|d| d.is_finite())
        .collect();
    let near = finite.iter().copied().fold(f32::INFINITY, f32::min);
    let far = finite.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let flow_rgb = flow.map(|f| flow_to_rgb(f, None));
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let base = background.map_or(0.0, |b| b.get(x, y));
            let mask_px = if out.mask[i] {
                let edge = out.mask[i] && !out.coverage[i];
                if edge {
                    [255, 255, 0]
                } else {
                    [
                        (0.5 * base + 127.0) as u8,
                        (0.5 * base) as u8,
                        (0.5 * base) as u8,
                    ]
                }
            } else {
                let b = base as u8;
                [b, b, b]
            };
            let d = out.depth_m[i];
            let depth_px = if d.is_finite() {
                let s = if far > near {
                    (far - d) / (far - near)
                } else {
                    1.0
                };
                let v = (55.0 + 200.0 * s) as u8;
                [v, v, v]
            } else {
                [0, 0, 0]
            };
            let flow_px = match &flow_rgb {
                Some(rgb) if out.coverage[i] && rgb[3 * i..3 * i + 3] != [0, 0, 0] => {
                    [rgb[3 * i], rgb[3 * i + 1], rgb[3 * i + 2]]
                }
                _ => [64, 64, 64],
            };
            for (panel, px) in [mask_px, depth_px, flow_px].into_iter().enumerate() {
                img.put_pixel((panel * w + x) as u32, y as u32, image::Rgb(px));
            }
        }
    }
    img.save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}
