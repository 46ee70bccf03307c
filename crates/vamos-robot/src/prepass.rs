//! A tolerant pass over the URDF text before `urdf-rs` reads it: constructs urdfdom (the
//! ROS parser) accepts but `urdf-rs` refuses are dropped or fixed, one warning each naming
//! the element, instead of refusing the whole robot.
//!
//! The document is read with a real XML parser (`roxmltree`); the edits are applied to the
//! original text at the byte ranges that parser reports, so everything else reaches
//! `urdf-rs` unchanged. Only what `urdf-rs` reads is visited: the `<link>`, `<joint>` and
//! `<material>` children of `<robot>` (not `<gazebo>`, `<transmission>`, ...). Handled:
//! - `<texture>` without `filename` (vamos draws no textures): removed;
//! - a repeated element that URDF allows once (e.g. a second `<axis>` in a joint): removed,
//!   the first kept, as urdfdom reads only the first;
//! - a mesh `scale` of more than three numbers: the first three are used;
//! - a `<visual>` or `<collision>` whose geometry is not a box, cylinder, capsule, sphere
//!   or mesh (e.g. `<plane>`): removed;
//! - elements inside `<geometry>` after the shape (urdfdom reads the first only): removed.
//!
//! Text that is not well-formed XML goes to `urdf-rs` unchanged (its error is the one the
//! user sees).

use roxmltree::{Document, Node, ParsingOptions};
use std::borrow::Cow;
use std::ops::Range;

/// The geometry shapes `urdf-rs` reads.
const SHAPES: [&str; 5] = ["box", "cylinder", "capsule", "sphere", "mesh"];

/// Children URDF allows once per parent (urdfdom reads the first; `urdf-rs` refuses a
/// second as a duplicate field).
const SINGLE: &[(&str, &[&str])] = &[
    (
        "joint",
        &[
            "origin",
            "parent",
            "child",
            "axis",
            "limit",
            "calibration",
            "dynamics",
            "mimic",
            "safety_controller",
        ],
    ),
    ("link", &["inertial"]),
    ("inertial", &["origin", "mass", "inertia"]),
    ("visual", &["origin", "geometry", "material"]),
    ("collision", &["origin", "geometry"]),
    ("material", &["color", "texture"]),
];

/// One change to the text and the warning that reports it.
struct Edit {
    range: Range<usize>,
    replacement: String,
    warning: String,
}

/// The URDF text with the tolerated constructs dropped or fixed, and one warning per
/// change (in document order). Borrowed unchanged when there is nothing to change or the
/// text is not well-formed XML.
pub(crate) fn tolerate(xml: &str) -> (Cow<'_, str>, Vec<String>) {
    let opts = ParsingOptions {
        allow_dtd: true,
        ..ParsingOptions::default()
    };
    let Ok(doc) = Document::parse_with_options(xml, opts) else {
        return (Cow::Borrowed(xml), Vec::new());
    };
    let root = doc.root_element();
    if root.tag_name().name() != "robot" {
        return (Cow::Borrowed(xml), Vec::new());
    }
    let mut edits = Vec::new();
    for top in root.children().filter(Node::is_element) {
        if matches!(top.tag_name().name(), "link" | "joint" | "material") {
            for e in top.descendants().filter(Node::is_element) {
                check(e, xml, &mut edits);
            }
        }
    }
    if edits.is_empty() {
        return (Cow::Borrowed(xml), Vec::new());
    }
    // Outer elements first; an edit inside an element already removed is dropped with its
    // warning.
    edits.sort_by_key(|e| (e.range.start, std::cmp::Reverse(e.range.end)));
    let mut out = String::with_capacity(xml.len());
    let mut warnings = Vec::new();
    let mut at = 0;
    for e in edits {
        if e.range.start < at {
            continue;
        }
        let (Some(before), Some(_)) = (xml.get(at..e.range.start), xml.get(e.range.clone())) else {
            continue;
        };
        out.push_str(before);
        out.push_str(&e.replacement);
        at = e.range.end;
        warnings.push(e.warning);
    }
    out.push_str(xml.get(at..).unwrap_or_default());
    (Cow::Owned(out), warnings)
}

/// The edits element `e` needs.
fn check(e: Node<'_, '_>, xml: &str, edits: &mut Vec<Edit>) {
    let tag = e.tag_name().name();
    let remove = |node: Node<'_, '_>, warning: String| Edit {
        range: node.range(),
        replacement: String::new(),
        warning,
    };
    if tag == "texture" && e.attribute("filename").is_none() {
        edits.push(remove(
            e,
            format!(
                "{}: <texture> without a filename ignored",
                describe(e.parent_element())
            ),
        ));
    }
    if let Some((_, once)) = SINGLE.iter().find(|(parent, _)| *parent == tag) {
        for child in *once {
            let same: Vec<Node<'_, '_>> = e
                .children()
                .filter(|c| c.is_element() && c.tag_name().name() == *child)
                .collect();
            for extra in same.iter().skip(1) {
                edits.push(remove(
                    *extra,
                    format!(
                        "{} has {} <{child}> elements; only the first is used",
                        describe(Some(e)),
                        same.len()
                    ),
                ));
            }
        }
    }
    if tag == "geometry" {
        // urdfdom reads the first child element as the shape and ignores the rest (e.g. a
        // <material> put inside <geometry>, pybullet's racecar.urdf).
        for extra in e.children().filter(Node::is_element).skip(1) {
            edits.push(remove(
                extra,
                format!(
                    "{}: <{}> inside <geometry> after the shape ignored",
                    describe(e.parent_element()),
                    extra.tag_name().name()
                ),
            ));
        }
    }
    if tag == "geometry"
        && let Some(shape) = e.first_element_child()
        && let Some(owner) = e
            .parent_element()
            .filter(|p| matches!(p.tag_name().name(), "visual" | "collision"))
    {
        let name = shape.tag_name().name();
        if !SHAPES.contains(&name) {
            edits.push(remove(
                owner,
                format!(
                    "{} has <{name}> geometry, which vamos does not support; left out",
                    describe(Some(owner))
                ),
            ));
        }
    }
    if tag == "mesh"
        && let Some(attr) = e.attributes().find(|a| a.name() == "scale")
    {
        let value = attr.value();
        let numbers: Option<Vec<f64>> = value
            .split_whitespace()
            .map(|w| w.parse::<f64>().ok())
            .collect();
        let range = attr.range_value();
        // The value as written (no entity references), so the range is exactly it.
        if let Some(numbers) = numbers
            && numbers.len() > 3
            && xml.get(range.clone()) == Some(value)
        {
            let kept: Vec<&str> = value.split_whitespace().take(3).collect();
            edits.push(Edit {
                range,
                replacement: kept.join(" "),
                warning: format!(
                    "mesh {:?} in {} has a scale of {} values ({value:?}); the first 3 are used",
                    e.attribute("filename").unwrap_or_default(),
                    describe(e.ancestors().find(|a| {
                        a.has_tag_name("visual")
                            || a.has_tag_name("collision")
                            || a.has_tag_name("link")
                    })),
                    numbers.len()
                ),
            });
        }
    }
}

/// Names an element for a warning: `joint "j"`, `link "l"`, `a visual of link "l"`,
/// `material "m" of link "l"`, ...
fn describe(e: Option<Node<'_, '_>>) -> String {
    let Some(e) = e else {
        return "the robot".into();
    };
    let tag = e.tag_name().name();
    let link = || {
        e.ancestors()
            .find(|a| a.has_tag_name("link"))
            .map(|l| format!(" of link {:?}", l.attribute("name").unwrap_or_default()))
            .unwrap_or_default()
    };
    let named = |n: Option<&str>| n.map(|n| format!(" {n:?}")).unwrap_or_default();
    match tag {
        "link" | "joint" => format!("{tag} {:?}", e.attribute("name").unwrap_or_default()),
        "material" => format!("material{}{}", named(e.attribute("name")), link()),
        "visual" | "collision" => format!("a {tag}{}{}", named(e.attribute("name")), link()),
        _ => format!("<{tag}>{}", link()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn well_formed_urdf_without_quirks_is_borrowed_unchanged() {
        let xml = "<robot name=\"r\"><link name=\"a\"><visual><geometry>\
                   <mesh filename=\"a.stl\" scale=\"1 2 3\"/></geometry></visual></link>\
                   <gazebo><plane/></gazebo></robot>";
        let (out, warnings) = tolerate(xml);
        assert!(matches!(out, Cow::Borrowed(_)));
        assert!(warnings.is_empty(), "{warnings:?}");
        let (out, warnings) = tolerate("<robot name=\"r\"><link name=\"a\">");
        assert!(matches!(out, Cow::Borrowed(_)) && warnings.is_empty());
    }

    #[test]
    fn elements_after_the_shape_in_a_geometry_are_dropped() {
        let xml = "<robot name=\"r\"><link name=\"a\"><visual><geometry>\
                   <mesh filename=\"a.stl\"/><material name=\"grey\"/></geometry></visual>\
                   </link></robot>";
        let (out, warnings) = tolerate(xml);
        assert_eq!(
            out,
            "<robot name=\"r\"><link name=\"a\"><visual><geometry>\
             <mesh filename=\"a.stl\"/></geometry></visual></link></robot>"
        );
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("a visual of link \"a\": <material> inside <geometry>"),
            "{warnings:?}"
        );
    }

    #[test]
    fn edits_inside_a_removed_element_are_dropped_with_their_warnings() {
        let xml = "<robot name=\"r\"><link name=\"a\"><visual><geometry><plane/></geometry>\
                   <material name=\"m\"><texture/></material></visual>\
                   <visual><geometry><box size=\"1 1 1\"/></geometry></visual></link></robot>";
        let (out, warnings) = tolerate(xml);
        assert_eq!(
            out,
            "<robot name=\"r\"><link name=\"a\">\
             <visual><geometry><box size=\"1 1 1\"/></geometry></visual></link></robot>"
        );
        assert_eq!(warnings.len(), 1, "{warnings:?}");
        assert!(
            warnings[0].contains("a visual of link \"a\"") && warnings[0].contains("<plane>"),
            "{warnings:?}"
        );
    }
}
