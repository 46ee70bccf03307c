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
static FONT: &[u8] = include_bytes!("../../../../assets/fonts/DejaVuSans.ttf");

/// Fill of the anomalous intervals in [`plot_episode`].
pub const INTERVAL_SHADE: RGBColor = RGBColor(255, 205, 205);
const SCORE_COLOR: RGBColor = RGBColor(31, 119, 180);
pub(super) const THRESHOLD_COLOR: RGBColor = RGBColor(214, 39, 40);
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

pub(super) type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Draw into an RGB buffer with `draw`, then write it to `path` as PNG.
pub(super) fn render<F>(path: &Path, options: &PlotOptions, draw: F) -> Result<(), EvalError>
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

pub(super) fn padded(lo: f64, hi: f64) -> (f64, f64) {
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
        // Grid first: the opaque shading then hides it inside the intervals.
        let log_label = |v: &f64| format!("{:.0e}", 10f64.powf(*v));
        let linear_label = |v: &f64| format!("{v:.3}");
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .y_desc(if log_y { "score (log10)" } else { "score" })
            .y_label_formatter(if log_y { &log_label } else { &linear_label })
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(e)?;
        let mut labelled_shade = false;
        for &(a, b) in intervals_s {
            let (a, b) = (a.max(x_lo), b.min(x_hi));
            if a.is_nan() || b.is_nan() || a > b {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::{pr_curve, roc_curve};

    fn decode(path: &Path) -> image::RgbImage {
        image::open(path).unwrap().to_rgb8()
    }

    fn has_color(img: &image::RgbImage, c: RGBColor) -> usize {
        img.pixels().filter(|p| p.0 == [c.0, c.1, c.2]).count()
    }

    /// Runs of consecutive columns that contain the interval shade: (first, last).
    fn shaded_bands(img: &image::RgbImage) -> Vec<(u32, u32)> {
        let shade = [INTERVAL_SHADE.0, INTERVAL_SHADE.1, INTERVAL_SHADE.2];
        let mut bands: Vec<(u32, u32)> = Vec::new();
        for x in 0..img.width() {
            if (0..img.height()).any(|y| img.get_pixel(x, y).0 == shade) {
                match bands.last_mut() {
                    Some(band) if band.1 + 1 == x => band.1 = x,
                    _ => bands.push((x, x)),
                }
            }
        }
        bands
    }

    #[test]
    fn episode_plot_shades_intervals_and_draws_the_threshold() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("episode.png");
        let stamps: Vec<f64> = (0..=100).map(|i| i as f64 * 0.1).collect();
        let scores: Vec<f64> = stamps.iter().map(|t| 0.5 + 0.4 * (t * 1.3).sin()).collect();
        let options = PlotOptions {
            width_px: 800,
            height_px: 300,
            log_y: false,
        };
        let intervals = [(2.0, 4.0), (6.0, 8.0)];
        plot_episode(
            &path,
            "episode 7",
            &stamps,
            &scores,
            &intervals,
            Some(0.6),
            &options,
        )
        .unwrap();
        let img = decode(&path);
        assert_eq!(img.dimensions(), (800, 300));

        // Two bands of equal width (2 s each) separated by a gap of the same width (4..6
        // s): the shading sits where the time axis puts it.
        // (Narrow runs are the legend's swatch.)
        let bands: Vec<_> = shaded_bands(&img)
            .into_iter()
            .filter(|b| b.1 - b.0 > 40)
            .collect();
        assert_eq!(bands.len(), 2, "{bands:?}");
        let width = |b: (u32, u32)| f64::from(b.1 - b.0 + 1);
        let (w1, w2) = (width(bands[0]), width(bands[1]));
        let gap = f64::from(bands[1].0 - bands[0].1 - 1);
        assert!(
            w1 > 100.0 && (w1 - w2).abs() <= 2.0 && (gap - w1).abs() <= 3.0,
            "{bands:?}"
        );
        // Shaded pixels differ from the background: the band's middle column is mostly
        // shade, the gap's middle column has none.
        let column = |x: u32| {
            (0..img.height())
                .filter(|&y| img.get_pixel(x, y).0 == [255, 205, 205])
                .count()
        };
        assert!(column((bands[0].0 + bands[0].1) / 2) > 150);
        assert_eq!(column(bands[0].1 + (gap / 2.0) as u32), 0);
        assert!(has_color(&img, THRESHOLD_COLOR) > 100);
        assert!(has_color(&img, SCORE_COLOR) > 100);
        // The caption was drawn (text from the embedded font): dark pixels in the top rows.
        let caption_ink = (0..img.width())
            .flat_map(|x| (0..30).map(move |y| (x, y)))
            .filter(|&(x, y)| img.get_pixel(x, y).0.iter().all(|&c| c < 128))
            .count();
        assert!(caption_ink > 20, "caption ink {caption_ink}");
    }

    #[test]
    fn log_axis_copes_with_zero_and_triggered_scores() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("log.png");
        let stamps = [0.0, 0.1, 0.2, 0.3, 0.4, 0.5];
        let scores = [0.0, 0.01, f64::NAN, 0.2, 1.0e6 + 3.0, 0.05];
        let options = PlotOptions {
            log_y: true,
            ..PlotOptions::default()
        };
        plot_episode(
            &path,
            "triggered",
            &stamps,
            &scores,
            &[(0.3, 0.45)],
            Some(0.1),
            &options,
        )
        .unwrap();
        let img = decode(&path);
        assert_eq!(img.dimensions(), (900, 500));
        let bands: Vec<_> = shaded_bands(&img)
            .into_iter()
            .filter(|b| b.1 - b.0 > 40)
            .collect();
        assert_eq!(bands.len(), 1, "{bands:?}");
    }

    #[test]
    fn roc_and_pr_plots() {
        let dir = tempfile::tempdir().unwrap();
        let scores = [0.9, 0.8, 0.7, 0.6, 0.55, 0.5, 0.4, 0.3, 0.2, 0.1];
        let labels = [
            true, true, false, true, false, true, false, false, true, false,
        ];
        let roc = roc_curve(&scores, &labels).unwrap();
        let flipped: Vec<f64> = scores.iter().map(|s| 1.0 - s).collect();
        let roc2 = roc_curve(&flipped, &labels).unwrap();
        let options = PlotOptions {
            width_px: 500,
            height_px: 480,
            log_y: false,
        };
        let path = dir.path().join("roc.png");
        plot_roc(
            &path,
            &[("model", &roc, Some(0.7)), ("flipped", &roc2, None)],
            &options,
        )
        .unwrap();
        let img = decode(&path);
        assert_eq!(img.dimensions(), (500, 480));
        assert!(has_color(&img, PALETTE[0]) > 100);
        assert!(has_color(&img, PALETTE[1]) > 100);

        let pr = pr_curve(&scores, &labels).unwrap();
        let path = dir.path().join("pr.png");
        plot_pr(&path, &[("model", &pr, Some(0.6))], &options).unwrap();
        let img = decode(&path);
        assert_eq!(img.dimensions(), (500, 480));
        assert!(has_color(&img, PALETTE[0]) > 100);
    }

    #[test]
    fn bad_plot_inputs_are_errors() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("x.png");
        let options = PlotOptions::default();
        assert!(matches!(
            plot_episode(&path, "e", &[0.0, 1.0], &[0.5], &[], None, &options),
            Err(EvalError::LengthMismatch {
                left: 2,
                right: 1,
                ..
            })
        ));
        let tiny = PlotOptions {
            width_px: 10,
            ..options
        };
        assert!(matches!(
            plot_roc(&path, &[], &tiny),
            Err(EvalError::PlotSize { width_px: 10, .. })
        ));
        let missing_dir = dir.path().join("no/such/dir/x.png");
        assert!(matches!(
            plot_pr(&missing_dir, &[], &options),
            Err(EvalError::Write { .. })
        ));
    }
}
