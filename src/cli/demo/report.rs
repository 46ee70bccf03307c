//! The demo's report: `report.md`, `report.json` and the plots of every episode.

use super::{Streamed, fmt_score, fmt_threshold};
use crate::cli::eval::{Timeline, write_plots};
use crate::cli::percentile;
use anyhow::{Context, Result};
use serde_json::json;
use std::path::{Path, PathBuf};
use std::time::Duration;
use vamos::eval::{EvalReport, ScoredFrame, evaluate};

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("-".into(), |v| format!("{v:.digits$}"))
}

/// Writes `report.md`, `report.json` and the plots; returns the report's path.
#[allow(clippy::too_many_arguments)]
pub(super) fn write_report(
    out: &Path,
    profile_path: &Path,
    profile_name: &str,
    model: Option<&str>,
    alarm: f64,
    thresholds: vamos::eval::Thresholds,
    streamed: &[Streamed],
    elapsed: Duration,
) -> Result<PathBuf> {
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
        "Thresholds: e_c {}, e_b {}; alarm when the fused score reaches {}.\n\n",
        opt(thresholds.e_c, 3),
        opt(thresholds.e_b, 3),
        fmt_threshold(alarm)
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
