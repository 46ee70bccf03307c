//! `vamos bridge`: a ROS 2 node, with no ROS installation, that streams a robot's camera
//! and joint states from the graph to a running vamos server and publishes the scores
//! back (crates/vamos-ros2). Stops on SIGTERM or Ctrl-C after the last scores.

use anyhow::{Context, Result};
use std::path::PathBuf;
use std::time::Duration;
use vamos::client::ClientOptions;
use vamos::ros2::BridgeOptions;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// gRPC URL of the server (`https://` needs --ca).
    #[arg(long, default_value = "http://127.0.0.1:8081")]
    pub server: String,
    /// The server's profile to score with.
    #[arg(long)]
    pub profile: String,
    /// Bearer token of a robot (default: $VAMOS_ROBOT_TOKEN).
    #[arg(long, env = "VAMOS_ROBOT_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// CA certificate (PEM) of an https:// server.
    #[arg(long)]
    pub ca: Option<PathBuf>,
    /// DDS domain of the ROS 2 graph.
    #[arg(long, env = "ROS_DOMAIN_ID", default_value_t = 0)]
    pub domain_id: u16,
    /// The node's namespace: relative topics resolve under it, so each robot's bridge
    /// runs in its own (`--namespace robot1` reads /robot1/camera/image_raw).
    #[arg(long, default_value = "")]
    pub namespace: String,
    /// The node's name.
    #[arg(long, default_value = "vamos_bridge")]
    pub node_name: String,
    /// The robot's id in the session (default: the namespace, or the node's name).
    #[arg(long)]
    pub robot_id: Option<String>,
    /// Session id (default: ROBOT_ID-<random>; a fixed one resumes after a restart).
    #[arg(long)]
    pub session_id: Option<String>,
    /// Task label recorded with the session.
    #[arg(long, default_value = "")]
    pub task: String,
    /// Camera images, sensor_msgs/Image (relative: under the namespace).
    #[arg(long, default_value = "camera/image_raw")]
    pub image_topic: String,
    /// The image topic carries sensor_msgs/CompressedImage (JPEG or PNG) instead.
    #[arg(long)]
    pub compressed: bool,
    /// Depth images registered to the camera images, sensor_msgs/Image 16UC1 (mm) or
    /// 32FC1 (m), e.g. camera/aligned_depth_to_color/image_raw (default: none). Each camera
    /// image is sent with the depth image nearest its stamp within --max-depth-gap-ms,
    /// waiting for it at most twice that long, else without one.
    #[arg(long)]
    pub depth_topic: Option<String>,
    /// Largest gap between a camera image's stamp and its depth image's, milliseconds.
    #[arg(long, default_value_t = 20.0, value_parser = depth_gap_ms)]
    pub max_depth_gap_ms: f64,
    /// sensor_msgs/CameraInfo of the camera (its first calibrated message is sent when
    /// the session opens; without one the profile's camera applies).
    #[arg(long, default_value = "camera/camera_info")]
    pub camera_info_topic: String,
    /// sensor_msgs/JointState topic; repeat for several.
    #[arg(long = "joint-states-topic", default_value = "joint_states")]
    pub joint_states_topics: Vec<String>,
    /// vamos_msgs/FrameScore output, stamped with the scored image's header.
    #[arg(long, default_value = "vamos/frame_score")]
    pub frame_score_topic: String,
    /// std_msgs/Float64 score output (unstamped, for plots).
    #[arg(long, default_value = "vamos/score")]
    pub score_topic: String,
    /// std_msgs/Bool anomaly output (unstamped).
    #[arg(long, default_value = "vamos/anomaly")]
    pub anomaly_topic: String,
    /// vamos_msgs/AlarmEvent output: each alarm's start and end, stamped with the image
    /// at which it happened (reliable, transient-local, keep last 10).
    #[arg(long, default_value = "vamos/alarm")]
    pub alarm_topic: String,
    /// Ask the server for each frame's anomaly map and publish it on --anomaly-map-topic
    /// (off by default: maps cost bandwidth).
    #[arg(long)]
    pub anomaly_maps: bool,
    /// sensor_msgs/Image output of the anomaly maps (mono8, 0 = nominal), stamped with
    /// the scored image's header; with --anomaly-maps only.
    #[arg(long, default_value = "vamos/anomaly_map", requires = "anomaly_maps")]
    pub anomaly_map_topic: String,
    /// Period of diagnostic_msgs/DiagnosticArray on /diagnostics, seconds.
    #[arg(long, default_value_t = 1.0, value_parser = positive_seconds)]
    pub diagnostics_period: f64,
}

fn positive_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() && v > 0.0 && v < 1e6 => Ok(v),
        _ => Err(format!("{s:?} is not a period in seconds (> 0)")),
    }
}

fn depth_gap_ms(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(v) if v > 0.0 && v <= BridgeOptions::MAX_DEPTH_GAP_MS => Ok(v),
        _ => Err(format!(
            "{s:?} is not a gap in milliseconds (> 0, at most {})",
            BridgeOptions::MAX_DEPTH_GAP_MS
        )),
    }
}

/// `level` with the DDS crates' logs at warn (their discovery chatter is at info) and
/// ros2-client's ROS_DISTRO check at error, unless `level` names them itself.
pub fn quieter_dds(level: &str) -> String {
    let mut out = level.to_string();
    for (target, at) in [
        ("rustdds", "warn"),
        ("ros2_client", "warn"),
        ("ros2_client::distributions", "error"),
    ] {
        let named = level
            .split(',')
            .any(|d| d.trim().split(['=', '[']).next() == Some(target));
        if !named {
            out.push_str(&format!(",{target}={at}"));
        }
    }
    out
}

/// Runs the node until SIGTERM or Ctrl-C.
pub fn run(args: Args) -> Result<()> {
    let ca_pem = match &args.ca {
        Some(p) => Some(std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?),
        None => None,
    };
    let options = BridgeOptions {
        server: args.server,
        client: ClientOptions {
            token: args.token,
            ca_pem,
            ..ClientOptions::default()
        },
        profile: args.profile,
        domain_id: args.domain_id,
        namespace: args.namespace,
        node_name: args.node_name,
        robot_id: args.robot_id,
        session_id: args.session_id,
        task: args.task,
        image_topic: args.image_topic,
        compressed: args.compressed,
        depth_topic: args.depth_topic,
        max_depth_gap_ms: args.max_depth_gap_ms,
        camera_info_topic: args.camera_info_topic,
        joint_states_topics: args.joint_states_topics,
        frame_score_topic: args.frame_score_topic,
        score_topic: args.score_topic,
        anomaly_topic: args.anomaly_topic,
        alarm_topic: args.alarm_topic,
        anomaly_maps: args.anomaly_maps,
        anomaly_map_topic: args.anomaly_map_topic,
        diagnostics_period: Duration::from_secs_f64(args.diagnostics_period),
    };
    let report = super::async_runtime()?
        .block_on(vamos::ros2::run(options, vamos::service::wait_for_signal()))?;
    eprintln!(
        "vamos bridge: session {}, {} images sent, {} scores published, {} alarm events \
         published, {} anomaly maps published, {} dropped, {} refused, {} reconnects",
        report.session_id,
        report.images_sent,
        report.scores_published,
        report.alarm_events_published,
        report.anomaly_maps_published,
        report.dropped,
        report.refused,
        report.reconnects
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{depth_gap_ms, quieter_dds};

    #[test]
    fn the_depth_gap_is_positive_and_at_most_a_second() {
        assert_eq!(depth_gap_ms("20"), Ok(20.0));
        assert_eq!(depth_gap_ms("1000"), Ok(1000.0));
        for bad in ["0", "-5", "NaN", "inf", "1000.5", "x"] {
            assert!(depth_gap_ms(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn dds_logs_are_quieter_unless_named() {
        assert_eq!(
            quieter_dds("info"),
            "info,rustdds=warn,ros2_client=warn,ros2_client::distributions=error"
        );
        assert_eq!(
            quieter_dds("debug,rustdds=trace"),
            "debug,rustdds=trace,ros2_client=warn,ros2_client::distributions=error"
        );
    }
}
