//! A Foxglove layout for the scored bags of one profile ([`crate::episode::ScoreBagWriter`]): the
//! camera as the bag records it beside the anomaly map, the fused score and the alarm
//! flag, and one plot per detector the profile runs, each on its own scale (the
//! detectors' raw values differ by orders of magnitude).
//!
//! Written from the bag's chosen topics and the detectors in force, so that every panel
//! shows a topic the scored bag has. The format is Foxglove's layout JSON
//! (`configById` with `Type!id` panel keys, and a `layout` tree of splits).

use super::DetectorSwitches;
use crate::episode::bag::ChosenTopics;
use crate::eval::Detector;
use serde_json::{Value, json};

/// What a scored bag of the profile carries besides the input's topics.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScoredContent {
    /// The detectors that give values (see [`DetectorSwitches::in_force`]); `kinematics`
    /// only when the calibration holds nominal states (`e_k` needs them).
    pub detectors: DetectorSwitches,
    /// Frames carry `/vamos/anomaly_map` (calibrated scene statistics or a flow model).
    pub anomaly_map: bool,
}

fn plot(topic: &str, label: &str) -> Value {
    json!({
        "paths": [{
            "value": format!("{topic}.data"),
            "enabled": true,
            "timestampMethod": "receiveTime",
            "label": label,
        }],
        "showLegend": false,
        "foxglovePanelTitle": label,
    })
}

/// Panels side by side (`row`) or stacked (`column`), in equal shares.
fn split(panels: &[Value], direction: &str) -> Value {
    match panels {
        [] => Value::Null,
        [one] => one.clone(),
        _ => {
            let half = panels.len() / 2;
            json!({
                "direction": direction,
                "first": split(&panels[..half], direction),
                "second": split(&panels[half..], direction),
                "splitPercentage": 100.0 * half as f64 / panels.len() as f64,
            })
        }
    }
}

/// The Foxglove layout of a scored bag with `topics` (the input's chosen topics, which
/// the scored bag keeps) and `content` (a bag without joint states has no `e_c`, `e_b`,
/// `e_k`).
pub fn scored_bag_layout(topics: &ChosenTopics, content: &ScoredContent) -> Value {
    let mut config = serde_json::Map::new();
    let mut add = |id: String, value: Value| {
        config.insert(id.clone(), value);
        Value::String(id)
    };
    let mut camera = json!({ "imageTopic": topics.image });
    if let Some(info) = &topics.camera_info {
        camera["calibrationTopic"] = json!(info);
    }
    let mut images = vec![add(
        "Image!camera".into(),
        json!({ "imageMode": camera, "foxglovePanelTitle": format!("camera ({})", topics.image) }),
    )];
    if content.anomaly_map {
        images.push(add(
            "Image!map".into(),
            json!({
                "imageMode": {
                    "imageTopic": "/vamos/anomaly_map",
                    "colorMode": "colormap",
                    "colorMap": "turbo",
                },
                "foxglovePanelTitle": "anomaly map (0 = nominal)",
            }),
        ));
    }
    let overall = vec![
        add("Plot!score".into(), plot("/vamos/score", "fused score")),
        add("Plot!anomaly".into(), plot("/vamos/anomaly", "alarm")),
        add(
            "RawMessages!thresholds".into(),
            json!({
                "topicPath": "/vamos/thresholds.data",
                "foxglovePanelTitle": "thresholds in force",
            }),
        ),
    ];
    let joints = topics.joint_states.is_some();
    let detectors: Vec<Value> = Detector::ALL
        .into_iter()
        .filter(|&d| content.detectors.get(d) && (joints || !d.needs_robot()))
        .map(|d| add(format!("Plot!{}", d.key()), plot(d.topic(), &d.title())))
        .collect();
    let lower = if detectors.is_empty() {
        split(&overall, "column")
    } else {
        json!({
            "direction": "row",
            "first": split(&overall, "column"),
            "second": split(&detectors, "column"),
            "splitPercentage": 45,
        })
    };
    json!({
        "configById": config,
        "globalVariables": {},
        "userNodes": {},
        "playbackConfig": { "speed": 1 },
        "layout": {
            "direction": "column",
            "first": split(&images, "row"),
            "second": lower,
            "splitPercentage": 50,
        },
    })
}

/// Every topic a layout's panels read (image topics, and plot or message paths without
/// their field).
pub fn layout_topics(layout: &Value) -> Vec<String> {
    let mut out = Vec::new();
    let Some(config) = layout["configById"].as_object() else {
        return out;
    };
    for panel in config.values() {
        let image = &panel["imageMode"];
        for key in ["imageTopic", "calibrationTopic"] {
            if let Some(t) = image[key].as_str() {
                out.push(t.to_string());
            }
        }
        let paths = panel["paths"].as_array().into_iter().flatten();
        let raw = panel["topicPath"].as_str();
        for path in paths.filter_map(|p| p["value"].as_str()).chain(raw) {
            out.push(path.split('.').next().unwrap_or(path).to_string());
        }
    }
    out.sort();
    out.dedup();
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn topics(camera_info: Option<&str>) -> ChosenTopics {
        ChosenTopics {
            image: "/head/rgb/compressed".into(),
            image_schema: "sensor_msgs/msg/CompressedImage".into(),
            camera_info: camera_info.map(Into::into),
            joint_states: Some("/joint_states".into()),
            robot_description: None,
            labels: None,
            depth: None,
        }
    }

    /// The panel ids the layout tree places, each once.
    fn placed(node: &Value, out: &mut Vec<String>) {
        match node {
            Value::String(id) => out.push(id.clone()),
            Value::Object(o) => {
                assert!(matches!(o["direction"].as_str(), Some("row" | "column")));
                let share = o["splitPercentage"].as_f64().unwrap();
                assert!(share > 0.0 && share < 100.0, "{share}");
                placed(&o["first"], out);
                placed(&o["second"], out);
            }
            other => panic!("not a panel or a split: {other}"),
        }
    }

    #[test]
    fn the_layout_shows_the_bags_camera_and_only_the_detectors_in_force() {
        let content = ScoredContent {
            detectors: DetectorSwitches {
                flow: false,
                kinematics: false,
                ..DetectorSwitches::default()
            },
            anomaly_map: true,
        };
        let layout = scored_bag_layout(&topics(Some("/head/rgb/camera_info")), &content);
        assert_eq!(
            layout_topics(&layout),
            [
                "/head/rgb/camera_info",
                "/head/rgb/compressed",
                "/vamos/anomaly",
                "/vamos/anomaly_map",
                "/vamos/e_b",
                "/vamos/e_c",
                "/vamos/e_r",
                "/vamos/score",
                "/vamos/thresholds",
            ]
        );
        let mut ids = Vec::new();
        placed(&layout["layout"], &mut ids);
        let mut configured: Vec<String> = layout["configById"]
            .as_object()
            .unwrap()
            .keys()
            .cloned()
            .collect();
        ids.sort();
        configured.sort();
        assert_eq!(ids, configured, "every configured panel placed once");
    }

    #[test]
    fn without_a_map_or_camera_info_or_detectors_the_panels_go() {
        let content = ScoredContent {
            detectors: DetectorSwitches {
                camera: false,
                body: false,
                flow: false,
                scene: false,
                kinematics: false,
            },
            anomaly_map: false,
        };
        let layout = scored_bag_layout(&topics(None), &content);
        let t = layout_topics(&layout);
        assert!(
            !t.iter()
                .any(|t| t.starts_with("/vamos/e_") || t == "/vamos/anomaly_map")
        );
        assert!(t.contains(&"/head/rgb/compressed".to_string()));
        let mut ids = Vec::new();
        placed(&layout["layout"], &mut ids);
        assert_eq!(ids.len(), 4, "{ids:?}");
    }
}
