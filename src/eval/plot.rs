//! PNG plots of evaluation results with `plotters`: score over time per episode (the
//! anomalous intervals shaded, the threshold drawn), ROC curves and precision-recall
//! curves.
//!
//! Drawing happens in an in-memory RGB buffer that `image` encodes as PNG; text uses the
//! DejaVu Sans font embedded in the binary (`assets/fonts`, Bitstream Vera licence), so
//! nothing depends on system fonts, fontconfig or freetype.

use std::path::Path;
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::EvalError;
use super::metrics::{PrPoint, RocPoint};

/// DejaVu Sans 2.37, see `assets/fonts/LICENSE-DejaVu.txt`.
static FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// Fill of the anomalous intervals in [`plot_episode`].
pub const INTERVAL_SHADE: RGBColor = RGBColor(255, 205, 205);
const SCORE_COLOR: RGBColor = RGBColor(31, 119, 180);
const THRESHOLD_COLOR: RGBColor = RGBColor(214, 39, 40);
const GRAY: RGBColor = RGBColor(150, 150, 150);
/// Curve colours (matplotlib's tab10).
const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
];

/// Size and axis options of a plot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PlotOptions {
    /// Image width in pixels (at least 64).
    pub width_px: u32,
    /// Image height in pixels (at least 64).
    pub height_px: u32,
    /// [`plot_episode`] only: logarithmic score axis (scores <= 0 are drawn at a tenth
    /// of the smallest positive score). Useful because triggered scores sit at 1e6 and
    /// above (see [`super::fuse`]).
    pub log_y: bool,
}

impl Default for PlotOptions {
    /// 900 x 500 px, linear axes.
    fn default() -> Self {
        Self {
            width_px: 900,
            height_px: 500,
            log_y: false,
        }
    }
}

/// A named curve for [`plot_roc`] / [`plot_pr`]: label, points, area under it (shown in
/// the legend when given).
pub type Curve<'a, P> = (&'a str, &'a [P], Option<f64>);

/// Register the embedded font once; plotters looks fonts up by family name.
fn ensure_font() -> Result<(), String> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font("sans-serif", FontStyle::Normal, FONT).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err("the embedded DejaVu Sans font was rejected".to_string())
    }
}

type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Draw into an RGB buffer with `draw`, then write it to `path` as PNG.
fn render<F>(path: &Path, options: &PlotOptions, draw: F) -> Result<(), EvalError>
where
    F: FnOnce(&Area<'_>) -> Result<(), String>,
{
    let (w, h) = (options.width_px, options.height_px);
    if w < 64 || h < 64 || w > 16384 || h > 16384 {
        return Err(EvalError::PlotSize {
            width_px: w,
            height_px: h,
        });
    }
    let plot_error = |message: String| EvalError::Plot {
        path: path.to_path_buf(),
        message,
    };
    ensure_font().map_err(plot_error)?;
    let mut buffer = vec![0u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_error(e.to_string()))?;
        draw(&root).map_err(plot_error)?;
        root.present().map_err(|e| plot_error(e.to_string()))?;
    }
    let image = image::RgbImage::from_raw(w, h, buffer).ok_or_else(|| {
        plot_error("internal: the pixel buffer does not match the image size".into())
    })?;
    image
        .save_with_format(path, image::ImageFormat::Png)
        .map_err(|source| EvalError::Write {
            path: path.to_path_buf(),
            source,
        })
}

fn padded(lo: f64, hi: f64) -> (f64, f64) {
    if !(lo.is_finite() && hi.is_finite()) {
        return (0.0, 1.0);
    }
    if hi - lo < 1e-12 * lo.abs().max(1.0) {
        return (lo - 0.5, hi + 0.5);
    }
    let pad = 0.05 * (hi - lo);
    (lo - pad, hi + pad)
}

/// Score over time for one episode: `scores` against `stamps_s` (seconds, any origin),
/// `intervals_s` (start, end) shaded as anomalous, `threshold` drawn as a dashed line.
/// Non-finite scores leave a gap in the line. Errors: different lengths of stamps and
/// scores, an unusable size, drawing or writing failures.
pub fn plot_episode(
    path: &Path,
    episode_name: &str,
    stamps_s: &[f64],
    scores: &[f64],
    intervals_s: &[(f64, f64)],
    threshold: Option<f64>,
    options: &PlotOptions,
) -> Result<(), EvalError> {
    if stamps_s.len() != scores.len() {
        return Err(EvalError::LengthMismatch {
            what: "plot_episode stamps_s and scores",
            left: stamps_s.len(),
            right: scores.len(),
        });
    }
    let mut points: Vec<(f64, f64)> = stamps_s
        .iter()
        .copied()
        .zip(scores.iter().copied())
        .filter(|(t, _)| t.is_finite())
        .collect();
    points.sort_by(|a, b| a.0.total_cmp(&b.0));

    let log_floor = scores
        .iter()
        .copied()
        .filter(|s| s.is_finite() && *s > 0.0)
        .fold(f64::INFINITY, f64::min);
    let log_floor = if log_floor.is_finite() {
        log_floor / 10.0
    } else {
        1e-6
    };
    let log_y = options.log_y;
    let y_of = move |v: f64| if log_y { v.max(log_floor).log10() } else { v };

    let (x_lo, x_hi) = match (points.first(), points.last()) {
        (Some(a), Some(b)) if b.0 > a.0 => (a.0, b.0),
        (Some(a), _) => (a.0 - 0.5, a.0 + 0.5),
        _ => (0.0, 1.0),
    };
    let visible: Vec<f64> = points
        .iter()
        .map(|p| p.1)
        .chain(threshold)
        .filter(|v| v.is_finite())
        .map(y_of)
        .collect();
    let (y_lo, y_hi) = padded(
        visible.iter().copied().fold(f64::INFINITY, f64::min),
        visible.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    );

    render(path, options, |root| {
        let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
        let mut chart = ChartBuilder::on(root)
            .caption(episode_name, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)
            .map_err(e)?;
        let mut labelled_shade = false;
        for &(a, b) in intervals_s {
            let (a, b) = (a.max(x_lo), b.min(x_hi));
            if !(a <= b) {
                continue;
            }
            let series = chart
                .draw_series(std::iter::once(Rectangle::new(
                    [(a, y_lo), (b, y_hi)],
                    INTERVAL_SHADE.filled(),
                )))
                .map_err(e)?;
            if !labelled_shade {
                series.label("anomalous").legend(|(x, y)| {
                    Rectangle::new([(x, y - 6), (x + 20, y + 6)], INTERVAL_SHADE.filled())
                });
                labelled_shade = true;
            }
        }
        let log_label = |v: &f64| format!("1e{v:.1}");
        let linear_label = |v: &f64| format!("{v:.3}");
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .y_desc(if log_y { "score (log10)" } else { "score" })
            .y_label_formatter(if log_y { &log_label } else { &linear_label })
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        let mut labelled_score = false;
        for segment in points.split(|p| !p.1.is_finite()) {
            if segment.is_empty() {
                continue;
            }
            let series = chart
                .draw_series(LineSeries::new(
                    segment.iter().map(|&(t, s)| (t, y_of(s))),
                    SCORE_COLOR.stroke_width(2),
                ))
                .map_err(e)?;
            if !labelled_score {
                series.label("score").legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], SCORE_COLOR.stroke_width(2))
                });
                labelled_score = true;
            }
        }
        if let Some(t) = threshold.filter(|t| t.is_finite()) {
            let y = y_of(t);
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(x_lo, y), (x_hi, y)],
                    8,
                    5,
                    THRESHOLD_COLOR.stroke_width(2),
                ))
                .map_err(e)?
                .label("threshold")
                .legend(|(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], THRESHOLD_COLOR.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
        Ok(())
    })
}

/// Shared frame of the ROC and PR plots: unit square axes, one coloured line per curve.
fn plot_curves(
    path: &Path,
    title: &str,
    axes: (&str, &str),
    curves: Vec<(String, Vec<(f64, f64)>)>,
    diagonal: bool,
    legend_at: SeriesLabelPosition,
    options: &PlotOptions,
) -> Result<(), EvalError> {
    render(path, options, |root| {
        let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
        let mut chart = ChartBuilder::on(root)
            .caption(title, ("sans-serif", 20))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(50)
            .build_cartesian_2d(-0.01..1.01, -0.01..1.01)
            .map_err(e)?;
        chart
            .configure_mesh()
            .x_desc(axes.0)
            .y_desc(axes.1)
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        if diagonal {
            chart
                .draw_series(DashedLineSeries::new(
                    vec![(0.0, 0.0), (1.0, 1.0)],
                    6,
                    6,
                    GRAY.stroke_width(1),
                ))
                .map_err(e)?;
        }
        for (i, (label, points)) in curves.into_iter().enumerate() {
            let color = PALETTE[i % PALETTE.len()];
            chart
                .draw_series(LineSeries::new(points, color.stroke_width(2)))
                .map_err(e)?
                .label(label)
                .legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
        }
        chart
            .configure_series_labels()
            .position(legend_at)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .draw()
            .map_err(e)?;
        Ok(())
    })
}

fn legend(label: &str, area_name: &str, area: Option<f64>) -> String {
    match area {
        Some(a) => format!("{label} ({area_name} {a:.3})"),
        None => label.to_string(),
    }
}

/// ROC curves (false-positive rate vs true-positive rate) with the chance diagonal;
/// each legend entry shows its AUC when given.
pub fn plot_roc(
    path: &Path,
    curves: &[Curve<'_, RocPoint>],
    options: &PlotOptions,
) -> Result<(), EvalError> {
    let lines = curves
        .iter()
        .map(|(label, points, auc)| {
            (
                legend(label, "AUC", *auc),
                points.iter().map(|p| (p.fpr, p.tpr)).collect(),
            )
        })
        .collect();
    plot_curves(
        path,
        "ROC",
        ("false-positive rate", "true-positive rate"),
        lines,
        true,
        SeriesLabelPosition::LowerRight,
        options,
    )
}

/// Precision-recall curves (recall vs precision), drawn as steps like scikit-learn's
/// display (precision holds until the next recall); each legend entry shows its average
/// precision when given.
pub fn plot_pr(
    path: &Path,
    curves: &[Curve<'_, PrPoint>],
    options: &PlotOptions,
) -> Result<(), EvalError> {
    let lines = curves
        .iter()
        .map(|(label, points, ap)| {
            let mut steps = Vec::with_capacity(points.len() * 2);
            for (i, p) in points.iter().enumerate() {
                steps.push((p.recall, p.precision));
                if let Some(next) = points.get(i + 1) {
                    steps.push((next.recall, p.precision));
                }
            }
            (legend(label, "AP", *ap), steps)
        })
        .collect();
    plot_curves(
        path,
        "Precision-recall",
        ("recall", "precision"),
        lines,
        false,
        SeriesLabelPosition::UpperRight,
        options,
    )
}
