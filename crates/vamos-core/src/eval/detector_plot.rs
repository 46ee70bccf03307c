//! Plots that explain a score: the fused score on top and, below it, each detector's
//! own value against its own threshold, on one time axis, with the flow predictor's
//! warm-up greyed out, the labelled anomalous intervals shaded and the first alarm
//! marked. A triggered camera or body detector pins the fused score at 1e6 and above;
//! its own panel shows how far past its threshold it went, and which one it was.

use super::EvalError;
use super::plot::{INTERVAL_SHADE, PlotOptions, THRESHOLD_COLOR, padded, render};
use plotters::prelude::*;
use std::path::Path;

/// One panel: a detector's values (NaN: undefined at that frame) and its threshold.
#[derive(Debug, Clone, Copy)]
pub struct Panel<'a> {
    /// Axis label (`fused score`, `e_c (px)`, ...).
    pub label: &'a str,
    /// One value per frame.
    pub values: &'a [f64],
    /// Its threshold, drawn dashed (none: not drawn).
    pub threshold: Option<f64>,
    /// Logarithmic axis (the fused score's trigger band sits at 1e6).
    pub log_y: bool,
}

const WARM_UP_SHADE: RGBColor = RGBColor(225, 225, 225);
const ALARM_COLOR: RGBColor = RGBColor(198, 40, 40);
const LINE_COLORS: [RGBColor; 5] = [
    RGBColor(29, 35, 42),
    RGBColor(21, 101, 192),
    RGBColor(106, 27, 154),
    RGBColor(239, 108, 0),
    RGBColor(0, 137, 123),
];

/// Draws `panels` stacked over `stamps_s` (seconds) into `path` (PNG): `warming_up` per
/// frame greyed, `intervals_s` shaded, a vertical line at `first_alarm_s`. Panels whose
/// values are all undefined are left out. Errors: a values slice or `warming_up` of
/// another length than `stamps_s`, no panel, an unusable size, drawing or writing.
#[allow(clippy::too_many_arguments)]
pub fn plot_detectors(
    path: &Path,
    title: &str,
    stamps_s: &[f64],
    panels: &[Panel<'_>],
    warming_up: &[bool],
    intervals_s: &[(f64, f64)],
    first_alarm_s: Option<f64>,
    options: &PlotOptions,
) -> Result<(), EvalError> {
    for (what, n) in panels
        .iter()
        .map(|p| ("plot_detectors values", p.values.len()))
        .chain([("plot_detectors warming_up", warming_up.len())])
    {
        if n != stamps_s.len() {
            return Err(EvalError::LengthMismatch {
                what,
                left: stamps_s.len(),
                right: n,
            });
        }
    }
    let shown: Vec<&Panel<'_>> = panels
        .iter()
        .filter(|p| p.values.iter().any(|v| v.is_finite()))
        .collect();
    if shown.is_empty() {
        return Err(EvalError::LengthMismatch {
            what: "plot_detectors panels with a defined value",
            left: panels.len(),
            right: 0,
        });
    }
    let (x_lo, x_hi) = padded(
        stamps_s.iter().copied().fold(f64::INFINITY, f64::min),
        stamps_s.iter().copied().fold(f64::NEG_INFINITY, f64::max),
    );
    // Runs of warm-up frames as (start, end) seconds.
    let mut warm: Vec<(f64, f64)> = Vec::new();
    for (i, &w) in warming_up.iter().enumerate() {
        if !w {
            continue;
        }
        let next = stamps_s.get(i + 1).copied().unwrap_or(stamps_s[i]);
        match warm.last_mut() {
            Some(run) if i > 0 && warming_up[i - 1] => run.1 = next,
            _ => warm.push((stamps_s[i], next)),
        }
    }
    render(path, options, |root| {
        let e = |e: plotters::drawing::DrawingAreaErrorKind<_>| e.to_string();
        let root = root.titled(title, ("sans-serif", 20)).map_err(e)?;
        let areas = root.split_evenly((shown.len(), 1));
        for (k, (panel, area)) in shown.iter().zip(areas.iter()).enumerate() {
            let floor = panel
                .values
                .iter()
                .copied()
                .filter(|v| v.is_finite() && *v > 0.0)
                .fold(f64::INFINITY, f64::min);
            let floor = if floor.is_finite() {
                floor / 10.0
            } else {
                1e-6
            };
            let log_y = panel.log_y;
            let y_of = move |v: f64| if log_y { v.max(floor).log10() } else { v };
            let ys: Vec<f64> = panel
                .values
                .iter()
                .copied()
                .chain(panel.threshold)
                .filter(|v| v.is_finite())
                .map(y_of)
                .collect();
            let (y_lo, y_hi) = padded(
                ys.iter().copied().fold(f64::INFINITY, f64::min),
                ys.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            );
            let mut chart = ChartBuilder::on(area)
                .margin(6)
                .x_label_area_size(if k + 1 == shown.len() { 30 } else { 0 })
                .y_label_area_size(70)
                .build_cartesian_2d(x_lo..x_hi, y_lo..y_hi)
                .map_err(e)?;
            let log_label = |v: &f64| format!("{:.0e}", 10f64.powf(*v));
            let linear_label = |v: &f64| format!("{v:.3}");
            chart
                .configure_mesh()
                .y_desc(panel.label)
                .x_desc(if k + 1 == shown.len() { "time (s)" } else { "" })
                .y_labels(4)
                .y_label_formatter(if log_y { &log_label } else { &linear_label })
                .light_line_style(RGBColor(240, 240, 240))
                .draw()
                .map_err(e)?;
            for &(a, b) in &warm {
                chart
                    .draw_series(std::iter::once(Rectangle::new(
                        [(a, y_lo), (b, y_hi)],
                        WARM_UP_SHADE.filled(),
                    )))
                    .map_err(e)?;
            }
            for &(a, b) in intervals_s {
                let (a, b) = (a.max(x_lo), b.min(x_hi));
                if a < b {
                    chart
                        .draw_series(std::iter::once(Rectangle::new(
                            [(a, y_lo), (b, y_hi)],
                            INTERVAL_SHADE.filled(),
                        )))
                        .map_err(e)?;
                }
            }
            let color = LINE_COLORS[k % LINE_COLORS.len()];
            let points: Vec<(f64, f64)> = stamps_s
                .iter()
                .copied()
                .zip(panel.values.iter().copied())
                .collect();
            for segment in points.split(|p| !p.1.is_finite()) {
                if !segment.is_empty() {
                    chart
                        .draw_series(LineSeries::new(
                            segment.iter().map(|&(t, v)| (t, y_of(v))),
                            color.stroke_width(2),
                        ))
                        .map_err(e)?;
                }
            }
            if let Some(t) = panel.threshold.filter(|t| t.is_finite()) {
                let y = y_of(t);
                chart
                    .draw_series(DashedLineSeries::new(
                        vec![(x_lo, y), (x_hi, y)],
                        8,
                        5,
                        THRESHOLD_COLOR.stroke_width(2),
                    ))
                    .map_err(e)?;
            }
            if let Some(t) = first_alarm_s.filter(|t| t.is_finite()) {
                chart
                    .draw_series(std::iter::once(PathElement::new(
                        vec![(t, y_lo), (t, y_hi)],
                        ALARM_COLOR.stroke_width(2),
                    )))
                    .map_err(e)?;
            }
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn panels_are_drawn_with_warm_up_threshold_and_alarm_and_bad_lengths_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("d.png");
        let t: Vec<f64> = (0..40).map(|i| i as f64 * 0.1).collect();
        let score: Vec<f64> = (0..40).map(|i| if i > 25 { 1e6 } else { 0.01 }).collect();
        let e_c: Vec<f64> = (0..40).map(|i| if i > 25 { 4.0 } else { 0.5 }).collect();
        let undefined = vec![f64::NAN; 40];
        let warm: Vec<bool> = (0..40).map(|i| i < 9).collect();
        let panels = [
            Panel {
                label: "fused score",
                values: &score,
                threshold: Some(0.05),
                log_y: true,
            },
            Panel {
                label: "e_c (px)",
                values: &e_c,
                threshold: Some(2.0),
                log_y: false,
            },
            Panel {
                label: "e_o",
                values: &undefined,
                threshold: None,
                log_y: false,
            },
        ];
        let options = PlotOptions {
            width_px: 400,
            height_px: 300,
            log_y: false,
        };
        plot_detectors(
            &path,
            "ep",
            &t,
            &panels,
            &warm,
            &[(2.5, 4.0)],
            Some(2.6),
            &options,
        )
        .unwrap();
        let img = image::open(&path).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (400, 300));
        // The warm-up grey, the threshold red and the alarm red are all on the image.
        let has = |c: [u8; 3]| img.pixels().any(|p| p.0 == c);
        assert!(has([225, 225, 225]), "warm-up shading");
        assert!(has([198, 40, 40]), "first-alarm line");
        let short = [Panel {
            values: &e_c[..3],
            ..panels[1]
        }];
        assert!(matches!(
            plot_detectors(&path, "ep", &t, &short, &warm, &[], None, &options),
            Err(EvalError::LengthMismatch { .. })
        ));
        let none = [panels[2]];
        assert!(plot_detectors(&path, "ep", &t, &none, &warm, &[], None, &options).is_err());
    }
}
