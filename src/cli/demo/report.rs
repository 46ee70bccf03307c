//! The demo's report: `report.md`, `report.json` and the plots of every episode.

use super::{Streamed, fmt_score, fmt_threshold};
use crate::cli::eval::{
    DetectorPoint, DetectorSeries, Timeline, first_alarm, write_detector_plots, write_plots,
};
use crate::cli::percentile;
use anyhow::{Context, Result};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Duration;
use vamos::episode::{EpisodeConfig, McapEpisode};
use vamos::eval::alarm::Debounce;
use vamos::eval::{Detector, DetectorThresholds, EvalReport, ScoredFrame, evaluate};
use vamos::vision::GrayImage;

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// What the report is about, beside the streamed results.
pub(super) struct ReportContext<'a> {
    /// The report's folder.
    pub out: &'a Path,
    /// The profile's file and name.
    pub profile_path: &'a Path,
    pub profile_name: &'a str,
    /// The model, described (`None`: no flow predictor).
    pub model: Option<&'a str>,
    /// The alarm threshold and each detector's own.
    pub thresholds: DetectorThresholds,
    /// How flagged frames become alarms (the profile's).
    pub rule: Debounce,
    /// The streamed episodes' files (the frame at each first alarm is read from them).
    pub episodes: &'a [PathBuf],
    /// How they are read.
    pub episode_config: &'a EpisodeConfig,
}

/// Writes `report.md`, `report.json` and the plots; returns the report's path.
pub(super) fn write_report(
    ctx: &ReportContext<'_>,
    streamed: &[Streamed],
    elapsed: Duration,
) -> Result<PathBuf> {
    let ReportContext {
        out,
        profile_path,
        profile_name,
        model,
        thresholds,
        ..
    } = *ctx;
    let alarm = thresholds.alarm.unwrap_or(f64::INFINITY);
    let mut frames = Vec::new();
    for s in streamed {
        for f in &s.summary.scores {
            frames.push(ScoredFrame {
                episode: s.name.clone(),
                stamp_ns: f.stamp_ns,
                score: f.score,
                anomalous: s
                    .labels
                    .as_ref()
                    .is_some_and(|l| l.is_anomalous(f.stamp_ns)),
                anomaly_type: s.labels.as_ref().and_then(|l| l.anomaly_type.clone()),
                warming_up: f.warming_up,
            });
        }
    }
    let report: EvalReport = evaluate(&frames, alarm);
    let outcomes = vamos::eval::episode_outcomes(&frames, alarm);
    let plots_dir = out.join("plots");
    let timelines: Vec<Timeline<'_>> = streamed
        .iter()
        .map(|s| Timeline {
            name: &s.name,
            points: s
                .summary
                .scores
                .iter()
                .map(|f| (f.stamp_ns, f.score))
                .collect(),
            labels: s.labels.as_ref(),
        })
        .collect();
    write_plots(&plots_dir, &timelines, &frames, alarm)?;
    let series: Vec<DetectorSeries<'_>> = streamed
        .iter()
        .map(|s| DetectorSeries {
            name: &s.name,
            labels: s.labels.as_ref(),
            points: s.summary.scores.iter().map(DetectorPoint::from).collect(),
        })
        .collect();
    write_detector_plots(&plots_dir, &series, &thresholds, ctx.rule)?;
    let alarm_frames = write_alarm_frames(ctx, &plots_dir, streamed)?;

    let mut latencies: Vec<f64> = streamed
        .iter()
        .flat_map(|s| s.latencies_s.iter().copied())
        .collect();
    latencies.sort_by(f64::total_cmp);
    let mut compute: Vec<f64> = streamed
        .iter()
        .flat_map(|s| s.summary.scores.iter().map(|f| f.compute_s))
        .collect();
    compute.sort_by(f64::total_cmp);
    let scored: usize = streamed.iter().map(|s| s.summary.scores.len()).sum();
    let sent: u64 = streamed.iter().map(|s| s.summary.images_sent).sum();
    let dropped: u64 = streamed.iter().map(|s| s.summary.dropped).sum();
    let errors: usize = streamed
        .iter()
        .map(|s| s.summary.message_errors.len())
        .sum();
    let ms = |v: Option<f64>| v.map(|s| s * 1e3);

    let mut md = String::new();
    md.push_str("# vamos demo report\n\n");
    md.push_str(&format!(
        "vamos {} · profile `{profile_name}` ({}) · model {} · {} episode(s) streamed over \
         gRPC to an in-process server as concurrent robots · {:.1} s in all\n\n",
        env!("CARGO_PKG_VERSION"),
        profile_path.display(),
        model.unwrap_or("none (no flow predictor)"),
        streamed.len(),
        elapsed.as_secs_f64()
    ));
    md.push_str(&format!(
        "Alarm when the fused score reaches {}, i.e. when one detector alone reaches its own \
         threshold: e_c {}, e_b {}, e_o {}, e_r {}, e_k {} (-: it cannot alarm alone); an alarm \
         starts after {} flagged frames of {}.\n\n",
        fmt_threshold(alarm),
        opt(thresholds.detectors[Detector::Camera], 3),
        opt(thresholds.detectors[Detector::Body], 3),
        opt(thresholds.detectors[Detector::Flow], 4),
        opt(thresholds.detectors[Detector::Scene], 3),
        opt(thresholds.detectors[Detector::Kinematics], 3),
        ctx.rule.frames,
        ctx.rule.window,
    ));
    md.push_str("## Summary\n\n| figure | value |\n|---|---|\n");
    let timely_label = format!(
        "anomalous episodes found within the anomaly (+{} s)",
        report.alarm_tolerance_s
    );
    for (k, v) in [
        ("frames scored / images sent", format!("{scored} / {sent}")),
        ("frames dropped / refused", format!("{dropped} / {errors}")),
        ("frame-level AUC-ROC", opt(report.auc_roc, 3)),
        ("frame-level AUC-PR", opt(report.auc_pr, 3)),
        (
            "anomalous episodes detected",
            opt(report.detection_rate.map(|r| r * 100.0), 0) + " %",
        ),
        (
            timely_label.as_str(),
            opt(report.timely_detection_rate.map(|r| r * 100.0), 0) + " %",
        ),
        (
            "median detection delay",
            opt(report.median_detection_delay_s, 2) + " s",
        ),
        (
            "nominal episodes with a false alarm",
            opt(report.episode_false_alarm_rate.map(|r| r * 100.0), 0) + " %",
        ),
        (
            "score latency p50 / p99 (image sent -> score received; includes queueing)",
            format!(
                "{} / {} ms",
                opt(ms(percentile(&latencies, 0.5)), 1),
                opt(ms(percentile(&latencies, 0.99)), 1)
            ),
        ),
        (
            "server compute per frame p50 / p99",
            format!(
                "{} / {} ms",
                opt(ms(percentile(&compute, 0.5)), 1),
                opt(ms(percentile(&compute, 0.99)), 1)
            ),
        ),
    ] {
        md.push_str(&format!("| {k} | {v} |\n"));
    }
    md.push_str(
        "\n## Episodes\n\n| episode | anomaly | frames | max score | onset | first alarm | \
         delay | outcome |\n|---|---|---:|---:|---:|---:|---:|---|\n",
    );
    for o in &outcomes {
        let t0 = frames
            .iter()
            .filter(|f| f.episode == o.episode)
            .map(|f| f.stamp_ns)
            .min()
            .unwrap_or(0);
        let rel = |ns: Option<i64>| ns.map(|n| (n - t0) as f64 / 1e9);
        let outcome = match (o.anomalous, o.detection_delay_s, o.false_alarm) {
            (false, _, false) => "ok (no alarm)",
            (false, _, true) => "FALSE ALARM",
            (true, Some(_), false) => "detected",
            (true, Some(_), true) => "detected (alarm before onset too)",
            (true, None, _) => "MISSED",
        };
        md.push_str(&format!(
            "| {} | {} | {} | {} | {} | {} | {} | {} |\n",
            o.episode,
            o.anomaly_type.as_deref().unwrap_or("-"),
            o.frames,
            fmt_score(o.max_score),
            opt(rel(o.onset_ns), 1) + if o.onset_ns.is_some() { " s" } else { "" },
            opt(rel(o.first_alarm_ns), 1) + if o.first_alarm_ns.is_some() { " s" } else { "" },
            opt(o.detection_delay_s, 1)
                + if o.detection_delay_s.is_some() {
                    " s"
                } else {
                    ""
                },
            outcome
        ));
    }
    if !report.per_type.is_empty() {
        md.push_str(
            "\n## Per anomaly type (each type's episodes pooled with the nominal ones)\n\n\
             | type | episodes | AUC-ROC | AUC-PR | detected | median delay |\n\
             |---|---:|---:|---:|---:|---:|\n",
        );
        for (t, r) in &report.per_type {
            md.push_str(&format!(
                "| {t} | {} | {} | {} | {} % | {} |\n",
                r.episodes,
                opt(r.auc_roc, 3),
                opt(r.auc_pr, 3),
                opt(r.detection_rate.map(|v| v * 100.0), 0),
                opt(r.median_detection_delay_s, 2)
                    + if r.median_detection_delay_s.is_some() {
                        " s"
                    } else {
                        ""
                    }
            ));
        }
    }
    md.push_str("\n## Plots\n\n");
    if plots_dir.join("roc.png").is_file() {
        md.push_str("![ROC](plots/roc.png) ![PR](plots/pr.png)\n\n");
    }
    if plots_dir.join("roc_per_type.png").is_file() {
        md.push_str(
            "ROC per anomaly type (each type's episodes with every nominal one):\n\n\
             ![ROC per type](plots/roc_per_type.png)\n\n",
        );
    }
    md.push_str(
        "Score timelines (log scale; anomalous intervals shaded, the alarm threshold \
         dashed):\n\n",
    );
    for s in streamed {
        md.push_str(&format!("![{0}](plots/{0}.png)\n", s.name));
    }
    md.push_str(
        "\nEach detector against its own threshold (dashed), below the fused score; the \
         flow predictor's warm-up greyed, labelled anomalies shaded, the first alarm marked:\n\n",
    );
    for s in streamed {
        md.push_str(&format!(
            "![{0} detectors](plots/{0}.detectors.png)\n",
            s.name
        ));
    }
    if !alarm_frames.is_empty() {
        md.push_str(
            "\n## Where: the frame at each episode's first alarm\n\nThe camera image as \
             scored (left) and with the anomaly map over it (right; red: the scene moved \
             against its nominal statistics there).\n\n",
        );
        for (name, seconds, file) in &alarm_frames {
            md.push_str(&format!(
                "**{name}** at {seconds:.1} s:\n\n![{name} first alarm](plots/{file})\n\n"
            ));
        }
    }
    let path = out.join("report.md");
    std::fs::write(&path, md).with_context(|| format!("cannot write {}", path.display()))?;
    let json_path = out.join("report.json");
    let value = json!({
        "profile": profile_name,
        "model": model,
        "alarm_threshold": alarm.is_finite().then_some(alarm),
        "evaluation": report,
        "episodes": outcomes,
        "frames_scored": scored,
        "images_sent": sent,
        "frames_dropped": dropped,
        "message_errors": errors,
        "latency_ms": {
            "p50": ms(percentile(&latencies, 0.5)),
            "p99": ms(percentile(&latencies, 0.99)),
        },
        "compute_ms": {
            "p50": ms(percentile(&compute, 0.5)),
            "p99": ms(percentile(&compute, 0.99)),
        },
        "elapsed_s": elapsed.as_secs_f64(),
    });
    std::fs::write(&json_path, serde_json::to_string_pretty(&value)? + "\n")
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    Ok(path)
}

/// For every episode with an alarm: `plots/<episode>.first_alarm.png`, the frame at the
/// first alarm's start beside the same frame with its anomaly map over it. Returns
/// (episode, seconds into it, file name) of each written.
fn write_alarm_frames(
    ctx: &ReportContext<'_>,
    dir: &Path,
    streamed: &[Streamed],
) -> Result<Vec<(String, f64, String)>> {
    let mut written = Vec::new();
    for s in streamed {
        let points: Vec<DetectorPoint> = s.summary.scores.iter().map(DetectorPoint::from).collect();
        let Some(i) = first_alarm(&points, ctx.rule)? else {
            continue;
        };
        let score = &s.summary.scores[i];
        let Some(path) = ctx
            .episodes
            .iter()
            .find(|p| p.file_stem().is_some_and(|n| n.to_string_lossy() == s.name))
        else {
            continue;
        };
        let episode = McapEpisode::open(path, ctx.episode_config)
            .with_context(|| format!("cannot reopen {}", path.display()))?;
        let Some(frame) = episode
            .frames()
            .filter_map(Result::ok)
            .find(|f| f.stamp_ns == score.stamp_ns)
        else {
            continue;
        };
        let map = (!score.anomaly_map.is_empty())
            .then(|| image::load_from_memory(&score.anomaly_map))
            .transpose()
            .with_context(|| format!("the anomaly map of {} is not an image", s.name))?
            .map(|m| m.to_luma8());
        let file = format!("{}.first_alarm.png", s.name);
        overlay(&frame.image, map.as_ref())
            .save(dir.join(&file))
            .with_context(|| format!("cannot write {}", dir.join(&file).display()))?;
        let t0 = s.summary.scores.first().map_or(0, |f| f.stamp_ns);
        written.push((s.name.clone(), (score.stamp_ns - t0) as f64 / 1e9, file));
    }
    Ok(written)
}

/// `frame` (gray) beside itself with `map` (8-bit, 0 nominal, any size: stretched over
/// the frame) over it in red.
fn overlay(frame: &GrayImage, map: Option<&image::GrayImage>) -> image::RgbImage {
    let (w, h) = (frame.width() as u32, frame.height() as u32);
    let map = map.map(|m| image::imageops::resize(m, w, h, image::imageops::FilterType::Triangle));
    let mut out = image::RgbImage::new(2 * w, h);
    for y in 0..h {
        for x in 0..w {
            let g = frame.get(x as usize, y as usize).clamp(0.0, 255.0);
            out.put_pixel(x, y, image::Rgb([g as u8; 3]));
            let a = map
                .as_ref()
                .map_or(0.0, |m| f32::from(m.get_pixel(x, y)[0]) / 255.0);
            let a = (0.8 * a).min(0.8);
            let mix = |c: f32| ((1.0 - a) * g + a * c).round() as u8;
            out.put_pixel(w + x, y, image::Rgb([mix(255.0), mix(0.0), mix(0.0)]));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_overlay_is_the_frame_beside_the_frame_reddened_where_the_map_is_high() {
        let frame = GrayImage::new(4, 2, vec![100.0; 8]).unwrap();
        let mut map = image::GrayImage::new(2, 1);
        map.put_pixel(1, 0, image::Luma([255]));
        let out = overlay(&frame, Some(&map));
        assert_eq!(out.dimensions(), (8, 2));
        assert_eq!(out.get_pixel(0, 0).0, [100, 100, 100]);
        assert_eq!(out.get_pixel(3, 1).0, [100, 100, 100]);
        // Left half of the map is 0: unchanged; its right edge is 255: mostly red.
        assert_eq!(out.get_pixel(4, 0).0, [100, 100, 100]);
        let hot = out.get_pixel(7, 0).0;
        assert!(hot[0] > 200 && hot[1] < 40 && hot[2] < 40, "{hot:?}");
        // No map: both halves are the frame.
        let plain = overlay(&frame, None);
        assert_eq!(plain.get_pixel(6, 1).0, [100, 100, 100]);
    }
}
