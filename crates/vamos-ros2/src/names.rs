//! ROS 2 name resolution as rcl does it (no remapping): absolute names stay, `~` is the
//! node's own name, relative names go under the node's namespace. So several robots'
//! bridges share one graph: `--namespace robot1` reads `/robot1/camera/image_raw` and
//! writes `/robot1/vamos/frame_score`.

/// A name rcl would refuse.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{name:?} is not a valid ROS 2 {what} name: {why}")]
pub struct NameError {
    /// The name as given.
    pub name: String,
    /// `topic`, `namespace` or `node`.
    pub what: &'static str,
    /// What is wrong with it.
    pub why: &'static str,
}

fn token_ok(t: &str) -> bool {
    t.chars().all(|c| c.is_ascii_alphanumeric() || c == '_')
        && t.chars()
            .next()
            .is_some_and(|c| c.is_ascii_alphabetic() || c == '_')
        && !t.contains("__")
}

const TOKENS: &str = "tokens of letters, digits and single _, not starting with a digit, \
                      separated by single /";

/// `namespace` as rcl keeps it: `""` or `"/a/b"` (a leading `/` added, a trailing one
/// dropped).
pub fn normalise_namespace(namespace: &str) -> Result<String, NameError> {
    let body = namespace.trim_start_matches('/').trim_end_matches('/');
    if body.is_empty() {
        return Ok(String::new());
    }
    if !body.split('/').all(token_ok) {
        return Err(NameError {
            name: namespace.to_string(),
            what: "namespace",
            why: TOKENS,
        });
    }
    Ok(format!("/{body}"))
}

/// Checks a node's base name.
pub fn check_node_name(name: &str) -> Result<(), NameError> {
    if token_ok(name) {
        Ok(())
    } else {
        Err(NameError {
            name: name.to_string(),
            what: "node",
            why: "letters, digits and single _, not starting with a digit",
        })
    }
}

/// The fully qualified name of topic `name` for node `node` in `namespace` (already
/// normalised).
pub fn resolve_topic(name: &str, namespace: &str, node: &str) -> Result<String, NameError> {
    let err = |why| NameError {
        name: name.to_string(),
        what: "topic",
        why,
    };
    let (prefix, body) = if let Some(rest) = name.strip_prefix('~') {
        if !(rest.is_empty() || rest.starts_with('/')) {
            return Err(err("a private name starts with ~/"));
        }
        (format!("{namespace}/{node}"), rest.trim_start_matches('/'))
    } else if let Some(rest) = name.strip_prefix('/') {
        (String::new(), rest)
    } else {
        (namespace.to_string(), name)
    };
    if body.is_empty() {
        return if name.starts_with('~') {
            Ok(prefix)
        } else {
            Err(err("it is empty"))
        };
    }
    if !body.split('/').all(token_ok) {
        return Err(err(TOKENS));
    }
    Ok(format!("{prefix}/{body}"))
}

/// The robot's id when none is given: the namespace (`/robot1` -> `robot1`,
/// `/fleet/arm_3` -> `fleet-arm_3`), or the node's name in the root namespace.
pub fn default_robot_id(namespace: &str, node: &str) -> String {
    let ns = namespace.trim_matches('/');
    if ns.is_empty() {
        node.to_string()
    } else {
        ns.replace('/', "-")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn relative_private_and_absolute_names_resolve_as_rcl_resolves_them() {
        let ns = normalise_namespace("robot1/").unwrap();
        assert_eq!(ns, "/robot1");
        let r = |n: &str| resolve_topic(n, &ns, "vamos_bridge").unwrap();
        assert_eq!(r("camera/image_raw"), "/robot1/camera/image_raw");
        assert_eq!(r("/diagnostics"), "/diagnostics");
        assert_eq!(r("~/status"), "/robot1/vamos_bridge/status");
        assert_eq!(r("~"), "/robot1/vamos_bridge");
        assert_eq!(
            resolve_topic("vamos/score", "", "n").unwrap(),
            "/vamos/score"
        );
        assert_eq!(normalise_namespace("/").unwrap(), "");
    }

    #[test]
    fn invalid_names_are_refused_with_the_rule() {
        for bad in ["", "a//b", "a/", "1cam", "a b", "~x", "a__b"] {
            let e = resolve_topic(bad, "", "n").unwrap_err();
            assert_eq!(e.name, bad);
        }
        assert!(normalise_namespace("/ro bot").is_err());
        assert!(check_node_name("vamos-bridge").is_err());
        assert!(check_node_name("vamos_bridge").is_ok());
    }

    #[test]
    fn the_robot_id_defaults_to_the_namespace() {
        assert_eq!(default_robot_id("/robot1", "vamos_bridge"), "robot1");
        assert_eq!(
            default_robot_id("/fleet/arm_3", "vamos_bridge"),
            "fleet-arm_3"
        );
        assert_eq!(default_robot_id("", "vamos_bridge"), "vamos_bridge");
    }
}
