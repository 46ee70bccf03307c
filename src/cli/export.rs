//! `vamos export-dataset`: the flow predictor's training data, made by the same front end
//! the detector runs (docs/model-bundle.md).

use anyhow::{Context, Result, bail};
use std::path::{Path, PathBuf};
use vamos::config::Settings;
use vamos::episode::ImageSequence;
use vamos::pipeline::dataset::{DatasetWriter, FrameRecord, InputSpec, ProcessingSpec};
use vamos::pipeline::{FlowVariant, FrameProcessor};
use vamos::vision::GrayImage;
use vamos::vision::flow::FlowParams;

/// Options of `vamos export-dataset` beyond the settings.
pub struct ExportOptions {
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
}

/// Runs the export; returns the number of frames written.
pub fn run(settings: &Settings, opts: ExportOptions) -> Result<usize> {
    let mut frames_params = settings.pipeline.frames.clone();
    if let Some(v) = opts.variant {
        frames_params.variant = v;
    }
    if frames_params.variant.is_masked() {
        bail!(
            "flow variant {} needs the robot's body mask for every frame, which needs the \
             robot model and joint states; image-folder episodes carry neither: export \
             `plain` or `registered`",
            frames_params.variant
        );
    }
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
    for dir in &opts.episodes {
        let seq = ImageSequence::open(dir, period_ns)?;
        let (records, rows) = export_episode(&mut processor, &seq, stride)
            .with_context(|| format!("episode {}", dir.display()))?;
        tracing::info!(
            episode = %seq.name,
            images = seq.frames.len(),
            frames = records.len(),
            "episode exported"
        );
        eprintln!(
            "{}: {} images -> {} frames",
            seq.name,
            seq.frames.len(),
            records.len()
        );
        total += records.len();
        writer.add_episode(&seq.name, records, &rows)?;
    }
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
) -> Result<(Vec<FrameRecord>, Vec<f32>)> {
    processor.reset();
    let mut records = Vec::new();
    let mut rows = Vec::new();
    for (index, frame) in seq.frames.iter().enumerate().step_by(stride) {
        let image = load(&frame.path)?;
        if let Some(p) = processor.push(&image, None)? {
            records.push(FrameRecord {
                index,
                stamp_ns: frame.stamp_ns,
            });
            rows.extend_from_slice(&p.network_input);
        }
    }
    Ok((records, rows))
}

fn load(path: &Path) -> Result<GrayImage> {
    GrayImage::load(path).with_context(|| format!("image {}", path.display()))
}
