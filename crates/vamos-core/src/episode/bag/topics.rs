//! Topic resolution: the image, camera-info and joint-state topics of a bag, by
//! configured name, default name or schema.

use super::*;

pub(super) fn record_limit(cfg: &EpisodeConfig) -> usize {
    cfg.max_image_bytes.saturating_mul(4).max(256 << 20)
}

pub(super) fn resolve_topics(
    topics: &[TopicInfo],
    wanted: &EpisodeTopics,
    path: &Path,
    warnings: &mut Vec<String>,
) -> Result<ChosenTopics, EpisodeError> {
    let err = |reason: String| EpisodeError::Topic {
        path: path.display().to_string(),
        reason,
    };
    let find = |name: &str| topics.iter().find(|t| t.name == name);
    let is_image =
        |t: &TopicInfo| t.schema == schema::IMAGE || t.schema == schema::COMPRESSED_IMAGE;
    let list = |v: &[&TopicInfo]| {
        v.iter()
            .map(|t| format!("{} ({})", t.name, t.schema))
            .collect::<Vec<_>>()
            .join(", ")
    };
    // A configured topic must exist with one of the schemas.
    let configured = |name: &str, schemas: &[&str]| -> Result<String, EpisodeError> {
        match find(name) {
            Some(t) if schemas.contains(&t.schema.as_str()) => Ok(t.name.clone()),
            Some(t) => Err(err(format!(
                "topic {name} has schema {}, expected {}",
                t.schema,
                schemas.join(" or ")
            ))),
            None => Err(err(format!(
                "topic {name} is not in the file (topics: {})",
                list(&topics.iter().collect::<Vec<_>>())
            ))),
        }
    };
    let image = match &wanted.image {
        Some(name) => configured(name, &[schema::IMAGE, schema::COMPRESSED_IMAGE])?,
        None => match find(default_topic::IMAGE).filter(|t| is_image(t)) {
            Some(t) => t.name.clone(),
            None => {
                let all: Vec<&TopicInfo> = topics.iter().filter(|t| is_image(t)).collect();
                let colour: Vec<&TopicInfo> = all
                    .iter()
                    .copied()
                    .filter(|t| !t.name.contains("depth"))
                    .collect();
                match (all.as_slice(), colour.as_slice()) {
                    ([], _) => {
                        return Err(err(
                            "no sensor_msgs/msg/Image or CompressedImage topic".into()
                        ));
                    }
                    ([one], _) | (_, [one]) => one.name.clone(),
                    _ => {
                        return Err(err(format!(
                            "several image topics, set [episode.topics] image: {}",
                            list(&all)
                        )));
                    }
                }
            }
        },
    };
    let image_schema = find(&image).map(|t| t.schema.clone()).unwrap_or_default();
    let image_ns = image.rsplit_once('/').map_or("", |(ns, _)| ns).to_string();
    // Optional topics: configured, default name, only one of the schema, or (several)
    // the one in the image topic's namespace.
    let optional = |configured_name: &Option<String>,
                    default: &str,
                    schema_name: &str,
                    name_filter: &dyn Fn(&str) -> bool,
                    warnings: &mut Vec<String>|
     -> Result<Option<String>, EpisodeError> {
        if let Some(name) = configured_name {
            return configured(name, &[schema_name]).map(Some);
        }
        if let Some(t) = find(default).filter(|t| t.schema == schema_name) {
            return Ok(Some(t.name.clone()));
        }
        let cands: Vec<&TopicInfo> = topics
            .iter()
            .filter(|t| t.schema == schema_name && name_filter(&t.name))
            .collect();
        match cands.as_slice() {
            [] => Ok(None),
            [one] => Ok(Some(one.name.clone())),
            many => {
                let same_ns: Vec<&&TopicInfo> = many
                    .iter()
                    .filter(|t| t.name.rsplit_once('/').map_or("", |(ns, _)| ns) == image_ns)
                    .collect();
                if let [one] = same_ns.as_slice() {
                    return Ok(Some(one.name.clone()));
                }
                warnings.push(format!(
                    "several {schema_name} topics, none used (set [episode.topics]): {}",
                    list(many)
                ));
                Ok(None)
            }
        }
    };
    let any = |_: &str| true;
    Ok(ChosenTopics {
        camera_info: optional(
            &wanted.camera_info,
            default_topic::CAMERA_INFO,
            schema::CAMERA_INFO,
            &any,
            warnings,
        )?,
        joint_states: optional(
            &wanted.joint_states,
            default_topic::JOINT_STATES,
            schema::JOINT_STATE,
            &any,
            warnings,
        )?,
        robot_description: optional(
            &wanted.robot_description,
            default_topic::ROBOT_DESCRIPTION,
            schema::STRING,
            &|n: &str| n.ends_with("robot_description"),
            warnings,
        )?,
        labels: optional(
            &wanted.labels,
            default_topic::LABELS,
            schema::STRING,
            &|_: &str| false,
            warnings,
        )?,
        depth: match wanted.depth.as_deref() {
            Some(name) if name == image => {
                return Err(err(format!(
                    "depth topic {name} is the image topic: set [episode.topics] depth to \
                     the depth images registered to it"
                )));
            }
            // A bag without usable depth is still scored, at the assumed depth.
            Some(name) => match find(name) {
                Some(t) if t.schema == schema::IMAGE => Some(t.name.clone()),
                Some(t) => {
                    warnings.push(format!(
                        "depth topic {name} has schema {}, expected {}: the assumed depth is \
                         used",
                        t.schema,
                        schema::IMAGE
                    ));
                    None
                }
                None => {
                    warnings.push(format!(
                        "depth topic {name} is not in the file: the assumed depth is used"
                    ));
                    None
                }
            },
            None => None,
        },
        image,
        image_schema,
    })
}
