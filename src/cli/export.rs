//! `vamos export-dataset`: the flow predictor's training data, made by the same front end
//! the detector runs (docs/model-bundle.md).

use super::progress::{EpisodeProgress, Progress};
use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use vamos::config::Settings;
use vamos::episode::files::mcap_files_in;
use vamos::episode::{EpisodeError, ImageSequence, JointTrack, McapEpisode};
use vamos::pipeline::dataset::{DatasetWriter, FrameRecord, InputSpec, ProcessingSpec};
use vamos::pipeline::{FlowVariant, FrameProcessor};
use vamos::robot::render::{BodyRenderer, RenderFrame, RenderOutput, RobotView, create_renderer};
use vamos::robot::{CameraMount, CameraSpec, Intrinsics, JointMapper, Robot};
use vamos::vision::GrayImage;
use vamos::vision::flow::FlowParams;

/// Options of `vamos export-dataset` beyond the settings.
struct ExportOptions {
    /// Episode folders.
    pub episodes: Vec<PathBuf>,
    /// Output folder.
    pub out: PathBuf,
    /// Flow variant (default: settings).
    pub variant: Option<FlowVariant>,
    /// Frame stride (default: settings).
    pub stride: Option<usize>,
    /// Frame rate for folders without `frames.csv`.
    pub fps: f64,
    /// TV-L1 preset (default: settings).
    pub preset: Option<String>,
    /// Robot description: with `camera`, the body mask of every frame is rendered from
    /// each episode's `joints.csv` (needed by the masked variants; registration ignores
    /// the body in every variant).
    pub robot: Option<PathBuf>,
    /// Camera description (JSON, as `vamos render --camera`).
    pub camera: Option<PathBuf>,
    /// Joint samples further than this from an image stamp are reported.
    pub max_joint_gap_ms: f64,
    /// Where progress goes.
    pub progress: Progress,
}

/// What renders the body mask of each frame.
struct BodyMasker {
    robot: Robot,
    mount: CameraMount,
    intrinsics: Intrinsics,
    renderer: Box<dyn BodyRenderer>,
    out: RenderOutput,
}

impl BodyMasker {
    fn new(
        settings: &Settings,
        robot: &Path,
        camera: &Path,
        width: usize,
        height: usize,
    ) -> Result<Self> {
        let robot = Robot::load(robot, &settings.robot)
            .with_context(|| format!("cannot load robot {}", robot.display()))?;
        let text = std::fs::read_to_string(camera)
            .with_context(|| format!("cannot read {}", camera.display()))?;
        let spec: CameraSpec = serde_json::from_str(&text)
            .with_context(|| format!("{} must be a camera description", camera.display()))?;
        let intrinsics = spec.intrinsics()?.scaled_to(width as u32, height as u32)?;
        let mount = robot.camera_for(&spec)?;
        let mut renderer = create_renderer(&settings.render)?;
        renderer.prepare(robot.link_meshes())?;
        Ok(Self {
            robot,
            mount,
            intrinsics,
            renderer,
            out: RenderOutput::default(),
        })
    }

    /// The body mask (true = robot) for the given joint names and positions.
    fn mask(
        &mut self,
        mapper: &mut JointMapper,
        names: &[String],
        positions: &[f64],
    ) -> Result<&[bool]> {
        let q = mapper.map(names, positions)?.positions;
        let base_from_link = self.robot.forward(&q)?;
        let camera_from_base = self
            .mount
            .camera_from_base(&base_from_link)
            .context("the camera link has no pose")?;
        self.renderer.render(
            &RenderFrame {
                intrinsics: &self.intrinsics,
                current: RobotView {
                    camera_from_base,
                    base_from_link: &base_from_link,
                },
                previous: None,
                shade: false,
            },
            &mut self.out,
        )?;
        Ok(&self.out.mask)
    }
}

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Episodes: ROS 2 bags (.mcap, or folders of them; topics from `[episode]`), or
    /// image folders: images (.png/.jpg) in name order, or listed with stamps in
    /// `frames.csv` (`file,stamp_ns`), joint states in `joints.csv`.
    #[arg(required = true)]
    pub episodes: Vec<PathBuf>,
    /// Output folder.
    #[arg(short, long)]
    pub out: PathBuf,
    /// Take the robot, camera, pipeline parameters, TV-L1 preset and topics from this
    /// profile (the flags below still override).
    #[arg(long)]
    pub profile: Option<PathBuf>,
    /// Flow variant: plain, registered, masked or masked_registered (default:
    /// `pipeline.frames.variant`). Masked variants need --robot and --camera.
    #[arg(long)]
    pub variant: Option<vamos::pipeline::FlowVariant>,
    /// Robot (URDF file, package folder or archive): with --camera, every frame's body
    /// mask is rendered from the episode's joints.csv (`stamp_ns,JOINT,...`).
    #[arg(long)]
    pub robot: Option<PathBuf>,
    /// Camera JSON (as `vamos render --camera`).
    #[arg(long)]
    pub camera: Option<PathBuf>,
    /// Report image stamps further than this from a joint sample, milliseconds.
    #[arg(long, default_value_t = 100.0)]
    pub max_joint_gap_ms: f64,
    /// Process every N-th image (default: `pipeline.stride`).
    #[arg(long)]
    pub stride: Option<usize>,
    /// Frame rate of folders without frames.csv.
    #[arg(long, default_value_t = 10.0)]
    pub fps: f64,
    /// TV-L1 preset (default: the settings' `[vision.flow]`).
    #[arg(long)]
    pub preset: Option<String>,
    /// Worker threads (0 = one per core; default from the settings).
    #[arg(long)]
    pub threads: Option<usize>,
    /// No progress bars (they are drawn on stderr only when it is a terminal).
    #[arg(long)]
    pub no_progress: bool,
}

/// Runs `vamos export-dataset`: a profile's robot, camera, pipeline, preset and topics
/// first, the flags over them, on a pool of `--threads` workers.
pub fn run(settings: &Settings, args: Args) -> Result<()> {
    super::check_output_dir("--out", &args.out)?;
    let Args {
        episodes,
        out,
        profile,
        variant,
        mut robot,
        mut camera,
        max_joint_gap_ms,
        stride,
        fps,
        preset,
        threads,
        no_progress,
    } = args;
    let threads = super::resolve_threads(threads.unwrap_or(settings.vision.threads));
    let mut settings = settings.clone();
    if let Some(path) = &profile {
        let p = vamos::pipeline::Profile::load(path)?;
        if let Some(pipeline) = p.file.pipeline {
            settings.pipeline = pipeline;
        }
        if let Some(preset) = &p.file.flow_preset {
            settings.vision.flow = vamos::vision::flow::FlowParams::preset(preset)?;
        }
        if let Some(topics) = p.file.topics {
            settings.episode.topics = topics;
        }
        robot = robot.or(p.file.robot);
        camera = camera.or(p.file.camera);
    }
    let opts = ExportOptions {
        episodes,
        out,
        variant,
        stride,
        fps,
        preset,
        robot,
        camera,
        max_joint_gap_ms,
        progress: Progress::new(no_progress),
    };
    super::pool(threads)?.install(|| export(&settings, opts))?;
    Ok(())
}

/// Runs the export; returns the number of frames written.
fn export(settings: &Settings, opts: ExportOptions) -> Result<usize> {
    let mut frames_params = settings.pipeline.frames.clone();
    if let Some(v) = opts.variant {
        frames_params.variant = v;
    }
    let mut masker = match (&opts.robot, &opts.camera) {
        (Some(robot), Some(camera)) => Some(BodyMasker::new(
            settings,
            robot,
            camera,
            frames_params.width,
            frames_params.height,
        )?),
        (None, None) if frames_params.variant.is_masked() => bail!(
            "flow variant {} needs the robot's body mask for every frame: pass --robot and \
             --camera, with a joints.csv in every episode folder",
            frames_params.variant
        ),
        (None, None) => None,
        _ => bail!("--robot and --camera go together"),
    };
    let stride = opts.stride.unwrap_or(settings.pipeline.stride);
    if stride == 0 {
        bail!("--stride must be at least 1");
    }
    if !(opts.fps.is_finite() && opts.fps > 0.0) {
        bail!("--fps must be a positive number, got {}", opts.fps);
    }
    if opts.episodes.is_empty() {
        bail!("no episodes given");
    }
    let flow = match opts.preset.as_deref() {
        Some(name) => FlowParams::preset(name)?,
        None => settings.vision.flow.clone(),
    };
    let network = settings.vision.network_input.clone();
    let mut writer = DatasetWriter::create(
        &opts.out,
        InputSpec::from(&network),
        frames_params.variant,
        ProcessingSpec {
            width: frames_params.width,
            height: frames_params.height,
            stride,
        },
    )?;
    let mut processor = FrameProcessor::new(
        frames_params,
        flow,
        settings.vision.registration.clone(),
        network,
    )?;
    let period_ns = (1e9 / opts.fps).round() as i64;
    let mut total = 0;
    let max_gap_ns = (opts.max_joint_gap_ms * 1e6) as i64;
    let episodes = expand_bags(&opts.episodes)?;
    let progress = opts.progress.run("export", episodes.len());
    for dir in &episodes {
        if dir.extension().is_some_and(|x| x == "mcap") {
            let episode = McapEpisode::open(dir, &settings.episode)
                .with_context(|| format!("episode {}", dir.display()))?;
            let bar = progress.episode(episode.name(), episode.info().image_messages);
            let (records, rows, images) = export_bag(
                &mut processor,
                &episode,
                stride,
                masker.as_mut(),
                max_gap_ns,
                &bar,
            )
            .with_context(|| format!("episode {}", dir.display()))?;
            drop(bar);
            progress.finished(&format!(
                "{}: {} images -> {} frames",
                episode.name(),
                images,
                records.len()
            ));
            total += records.len();
            writer.add_episode(episode.name(), records, &rows)?;
            continue;
        }
        let seq = ImageSequence::open(dir, period_ns)?;
        let joints = match &masker {
            Some(_) => Some(JointTrack::read_csv(&dir.join("joints.csv"))?),
            None => None,
        };
        let body = match (masker.as_mut(), joints.as_ref()) {
            (Some(m), Some(j)) => Some((m, j)),
            _ => None,
        };
        let bar = progress.episode(&seq.name, seq.frames.len() as u64);
        let (records, rows) = export_episode(&mut processor, &seq, stride, body, max_gap_ns, &bar)
            .with_context(|| format!("episode {}", dir.display()))?;
        drop(bar);
        tracing::info!(
            episode = %seq.name,
            images = seq.frames.len(),
            frames = records.len(),
            "episode exported"
        );
        progress.finished(&format!(
            "{}: {} images -> {} frames",
            seq.name,
            seq.frames.len(),
            records.len()
        ));
        total += records.len();
        writer.add_episode(&seq.name, records, &rows)?;
    }
    drop(progress);
    let manifest = writer.finish()?;
    eprintln!(
        "wrote {} frames of {} episodes to {}",
        total,
        manifest.episodes.len(),
        opts.out.display()
    );
    Ok(total)
}

fn export_episode(
    processor: &mut FrameProcessor,
    seq: &ImageSequence,
    stride: usize,
    mut body: Option<(&mut BodyMasker, &JointTrack)>,
    max_gap_ns: i64,
    bar: &EpisodeProgress,
) -> Result<(Vec<FrameRecord>, Vec<f32>)> {
    processor.reset();
    let mut records = Vec::new();
    let mut rows = Vec::new();
    // One mapper per episode: its missing-joint warning is once per episode.
    let mut mapper = body.as_ref().map(|(m, _)| m.robot.joint_mapper());
    let mut gaps = 0usize;
    for (index, frame) in seq.frames.iter().enumerate().step_by(stride) {
        bar.set(index as u64 + 1);
        let image = load(&frame.path)?;
        let mask = match (body.as_mut(), mapper.as_mut()) {
            (Some((masker, track)), Some(mapper)) => {
                let sample = track.at(frame.stamp_ns);
                if sample.gap_ns > max_gap_ns {
                    gaps += 1;
                }
                Some(
                    masker
                        .mask(mapper, &track.names, &sample.positions)
                        .with_context(|| format!("body mask of {}", frame.path.display()))?
                        .to_vec(),
                )
            }
            _ => None,
        };
        if gaps == 1 {
            tracing::warn!(
                episode = %seq.name,
                max_gap_ms = max_gap_ns as f64 / 1e6,
                "image stamps far from any joint sample (joint states interpolated over a gap)"
            );
            gaps += 1;
        }
        if let Some(p) = processor.push(&image, mask.as_deref())? {
            records.push(FrameRecord {
                index,
                stamp_ns: frame.stamp_ns,
            });
            rows.extend_from_slice(&p.network_input);
        }
    }
    Ok((records, rows))
}

/// Folders that hold `.mcap` files expand into them (sorted); other paths pass through
/// (an image folder, a bag). Not [`vamos::episode::files::expand_episodes`]: that one
/// refuses a folder without `.mcap` files, which is what an image-sequence episode is
/// here; the listing itself is the shared [`mcap_files_in`].
fn expand_bags(paths: &[PathBuf]) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    for p in paths {
        let bags = if p.is_dir() {
            mcap_files_in(p)?
        } else {
            Vec::new()
        };
        if bags.is_empty() {
            out.push(p.clone());
        } else {
            out.extend(bags);
        }
    }
    Ok(out)
}

/// Exports one ROS 2 bag: its frames in stamp order, joint states interpolated to each
/// image stamp. Frames the reader refuses are skipped with a warning; a damaged file is
/// exported up to the damage. Returns the records, rows and the images read.
fn export_bag(
    processor: &mut FrameProcessor,
    episode: &McapEpisode,
    stride: usize,
    mut masker: Option<&mut BodyMasker>,
    max_gap_ns: i64,
    bar: &EpisodeProgress,
) -> Result<(Vec<FrameRecord>, Vec<f32>, usize)> {
    processor.reset();
    let mut records = Vec::new();
    let mut rows = Vec::new();
    let mut mapper = masker.as_ref().map(|m| m.robot.joint_mapper());
    let mut images = 0usize;
    let mut gap_warned = false;
    for item in episode.frames() {
        let frame = match item {
            Ok(f) => f,
            Err(e @ EpisodeError::Truncated { .. }) => {
                tracing::warn!(episode = %episode.name(), "{e}; exported up to there");
                break;
            }
            Err(e) => {
                tracing::warn!(episode = %episode.name(), "frame skipped: {e}");
                continue;
            }
        };
        images += 1;
        bar.set(frame.index as u64 + 1);
        if !(images - 1).is_multiple_of(stride) {
            continue;
        }
        let mask = match (masker.as_mut(), mapper.as_mut()) {
            (Some(masker), Some(mapper)) => {
                let Some(j) = &frame.joints else {
                    bail!(
                        "image {} has no joint states: the body mask needs them",
                        frame.index
                    );
                };
                if j.gap_ns > max_gap_ns && !gap_warned {
                    tracing::warn!(
                        episode = %episode.name(),
                        gap_ms = j.gap_ns as f64 / 1e6,
                        "image stamps far from any joint sample"
                    );
                    gap_warned = true;
                }
                Some(masker.mask(mapper, &j.names, &j.positions)?.to_vec())
            }
            _ => None,
        };
        if let Some(p) = processor.push(&frame.image, mask.as_deref())? {
            records.push(FrameRecord {
                index: frame.index,
                stamp_ns: frame.stamp_ns,
            });
            rows.extend_from_slice(&p.network_input);
        }
    }
    Ok((records, rows, images))
}

fn load(path: &Path) -> Result<GrayImage> {
    GrayImage::load(path).with_context(|| format!("image {}", path.display()))
}
