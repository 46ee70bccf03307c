//! Loading robots: typed errors, mimic chains, package layouts, archives, caps and the
//! URDF pre-pass's warnings.

use super::package::*;
use super::*;
use nalgebra::Vector3;

const STL: &str = "solid t\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\n\
                   vertex 0 1 0\nendloop\nendfacet\nendsolid t\n";

fn urdf(body: &str) -> String {
    format!("<robot name=\"r\">{body}</robot>")
}

fn link(name: &str) -> String {
    format!("<link name=\"{name}\"/>")
}

fn joint(name: &str, kind: &str, parent: &str, child: &str, extra: &str) -> String {
    format!(
        "<joint name=\"{name}\" type=\"{kind}\"><parent link=\"{parent}\"/>\
         <child link=\"{child}\"/><axis xyz=\"0 0 1\"/>\
         <limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/>{extra}</joint>"
    )
}

fn load(xml: &str) -> Result<Robot, RobotError> {
    Robot::from_urdf_str(xml, None, &RobotConfig::default())
}

#[test]
fn malformed_and_invalid_descriptions_are_typed_errors() {
    let e = load("<robot name=\"r\"><link name=\"a\">").unwrap_err();
    assert!(matches!(e, RobotError::MalformedUrdf { .. }), "{e}");
    let e = load(&urdf(&(link("a") + &link("a")))).unwrap_err();
    assert_eq!(e, RobotError::DuplicateLink { name: "a".into() });
    let two = link("a") + &link("b") + &link("c");
    let e = load(&urdf(
        &(two.clone() + &joint("j", "fixed", "a", "b", "") + &joint("j", "fixed", "a", "c", "")),
    ))
    .unwrap_err();
    assert_eq!(e, RobotError::DuplicateJoint { name: "j".into() });
    let e = load(&urdf(&(link("a") + &joint("j", "fixed", "a", "ghost", "")))).unwrap_err();
    assert_eq!(
        e,
        RobotError::MissingLink {
            joint: "j".into(),
            link: "ghost".into()
        }
    );
    // A mimic of a joint that does not exist is ignored with a warning (urdfdom loads
    // such robots, e.g. alex_psyonic_hands): j2 is then a joint of its own.
    let r = load(&urdf(
        &(two.clone()
            + &joint("j1", "revolute", "a", "b", "")
            + &joint("j2", "revolute", "a", "c", "<mimic joint=\"nope\"/>")),
    ))
    .unwrap();
    assert!(
        r.warnings()
            .iter()
            .any(|w| w.contains("\"j2\" mimics \"nope\"")),
        "{:?}",
        r.warnings()
    );
    assert!(r.joints()[1].mimic.is_none());
    let e = load(&urdf(
        &(two.clone()
            + &joint("j1", "revolute", "a", "b", "<mimic joint=\"j2\"/>")
            + &joint("j2", "revolute", "a", "c", "<mimic joint=\"j1\"/>")),
    ))
    .unwrap_err();
    assert!(matches!(e, RobotError::MimicCycle { .. }), "{e}");
    let e = load(&urdf(
        &(two.clone() + &joint("j1", "fixed", "b", "c", "") + &joint("j2", "fixed", "c", "b", "")),
    ))
    .unwrap_err();
    assert!(matches!(
        e,
        RobotError::TwoParents { .. } | RobotError::KinematicCycle { .. }
    ));
    let e = load(&urdf(&(two + &joint("j1", "fixed", "a", "b", "")))).unwrap_err();
    assert!(matches!(e, RobotError::MultipleRoots { .. }), "{e}");
}

#[test]
fn mimic_chains_compose_and_limits_are_kept() {
    let r = load(&urdf(
        &(link("a")
            + &link("b")
            + &link("c")
            + &link("d")
            + &joint("j1", "revolute", "a", "b", "")
            + &joint(
                "j2",
                "revolute",
                "a",
                "c",
                "<mimic joint=\"j1\" multiplier=\"2\" offset=\"0.1\"/>",
            )
            + &joint(
                "j3",
                "continuous",
                "a",
                "d",
                "<mimic joint=\"j2\" multiplier=\"-1\" offset=\"0.5\"/>",
            )),
    ))
    .unwrap();
    let m = r.joints()[2].mimic.unwrap();
    // q3 = -(2 q1 + 0.1) + 0.5 = -2 q1 + 0.4
    assert_eq!((m.joint, m.multiplier), (0, -2.0));
    assert!((m.offset - 0.4).abs() < 1e-15);
    let q = r.positions(vec![0.25, 0.0, 0.0]).unwrap();
    let poses = r.forward(&q).unwrap();
    assert!((poses[3].rotation.scaled_axis().z - (-0.1)).abs() < 1e-12);
    assert_eq!(r.joints()[0].limits.unwrap().upper, 1.0);
    assert!(
        r.joints()[2].limits.is_none(),
        "continuous joints have no limits"
    );
}

fn write(dir: &Path, rel: &str, text: &str) {
    let p = dir.join(rel);
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, text).unwrap();
}

fn mesh_link(name: &str, uri: &str) -> String {
    format!(
        "<link name=\"{name}\"><visual><origin xyz=\"0 0 1\"/><geometry>\
         <mesh filename=\"{uri}\" scale=\"2 2 2\"/></geometry></visual></link>"
    )
}

#[test]
fn package_uris_resolve_in_every_supported_layout() {
    let tmp = tempfile::tempdir().unwrap();
    let ws = tmp.path();
    // ws/src/my_robot/urdf/r.urdf; meshes in several places.
    write(ws, "src/my_robot/meshes/a.stl", STL); // package://my_robot (ancestor named so)
    write(ws, "src/my_robot/urdf/meshes/b.stl", STL); // package://meshes beside the URDF
    write(ws, "src/other_pkg/meshes/c.stl", STL); // sibling package above
    write(ws, "src/my_robot/urdf/rel/d.stl", STL); // relative path
    write(ws, "src/my_robot/deep/third_pkg/e.stl", STL); // a folder named so inside
    let xml = urdf(
        &(mesh_link("a", "package://my_robot/meshes/a.stl")
            + &mesh_link("b", "package://meshes/b.stl")
            + &mesh_link("c", "package://other_pkg/meshes/c.stl")
            + &mesh_link("d", "rel/d.stl")
            + &mesh_link("e", "package://third_pkg/e.stl")
            + &mesh_link(
                "f",
                &format!("file://{}", ws.join("src/other_pkg/meshes/c.stl").display()),
            )
            + &mesh_link("g", "package://nowhere/g.stl")
            + &joint("j1", "fixed", "a", "b", "")
            + &joint("j2", "fixed", "a", "c", "")
            + &joint("j3", "fixed", "a", "d", "")
            + &joint("j4", "fixed", "a", "e", "")
            + &joint("j5", "fixed", "a", "f", "")
            + &joint("j6", "fixed", "a", "g", "")),
    );
    write(ws, "src/my_robot/urdf/r.urdf", &xml);
    let r = Robot::from_package_dir(&ws.join("src/my_robot"), &RobotConfig::default()).unwrap();
    let resolved: Vec<Option<String>> = (0..7)
        .map(|l| match &r.visuals(l)[0].geometry {
            VisualGeometry::Mesh { resolved, .. } => resolved.clone(),
            other => panic!("{other:?}"),
        })
        .collect();
    let real = std::fs::canonicalize(ws).unwrap();
    let want = |rel: &str| Some(real.join(rel).display().to_string());
    assert_eq!(resolved[0], want("src/my_robot/meshes/a.stl"));
    assert_eq!(resolved[1], want("src/my_robot/urdf/meshes/b.stl"));
    assert_eq!(resolved[2], want("src/other_pkg/meshes/c.stl"));
    assert_eq!(resolved[3], want("src/my_robot/urdf/rel/d.stl"));
    assert_eq!(resolved[4], want("src/my_robot/deep/third_pkg/e.stl"));
    assert!(resolved[5].is_some());
    assert_eq!(resolved[6], None);
    // The missing mesh is a warning naming it; the rest loaded, scaled and placed.
    assert_eq!(r.warnings().len(), 1);
    assert!(
        r.warnings()[0].contains("package://nowhere/g.stl"),
        "{:?}",
        r.warnings()
    );
    assert_eq!(r.link_meshes().len(), 6);
    let m = &r.link_meshes()[0].mesh;
    assert!(m.positions.contains(&nalgebra::Point3::new(2.0, 0.0, 1.0)));
}

#[test]
fn a_string_without_root_loads_only_absolute_meshes() {
    let tmp = tempfile::tempdir().unwrap();
    write(tmp.path(), "a.stl", STL);
    let abs = tmp.path().join("a.stl").display().to_string();
    let xml = urdf(
        &(mesh_link("a", &format!("file://{abs}"))
            + &mesh_link("b", "a.stl")
            + &joint("j", "fixed", "a", "b", "")),
    );
    let r = load(&xml).unwrap();
    assert_eq!(r.visuals(0)[0].triangles, 1);
    assert_eq!(r.visuals(1)[0].triangles, 0);
    assert_eq!(r.warnings().len(), 1);
    assert!(r.warnings()[0].contains("\"a.stl\""), "{:?}", r.warnings());
}

#[test]
fn the_package_root_stands_for_a_renamed_package() {
    let tmp = tempfile::tempdir().unwrap();
    write(tmp.path(), "meshes/a.stl", STL);
    let xml = urdf(&mesh_link("a", "package://robot_description/meshes/a.stl"));
    write(tmp.path(), "robot.urdf", &xml);
    let r = Robot::load(tmp.path(), &RobotConfig::default()).unwrap();
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
    assert_eq!(r.triangle_count(), 1);
}

#[test]
fn oversized_meshes_are_left_out_with_a_warning_and_robot_caps_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    write(tmp.path(), "a.stl", STL);
    let xml = urdf(&mesh_link("a", "a.stl"));
    write(tmp.path(), "r.urdf", &xml);
    let cfg = RobotConfig {
        max_mesh_file_bytes: 20,
        ..RobotConfig::default()
    };
    let r = Robot::load(&tmp.path().join("r.urdf"), &cfg).unwrap();
    assert_eq!(r.triangle_count(), 0);
    assert!(r.warnings()[0].contains("cap"), "{:?}", r.warnings());
    let cfg = RobotConfig {
        max_robot_triangles: 10,
        ..RobotConfig::default()
    };
    let xml =
        urdf("<link name=\"a\"><visual><geometry><box size=\"1 1 1\"/></geometry></visual></link>");
    let e = Robot::from_urdf_str(&xml, None, &cfg).unwrap_err();
    assert!(
        matches!(e, RobotError::TooManyTriangles { triangles: 12, .. }),
        "{e}"
    );
}

#[test]
fn primitives_are_tessellated_in_the_visual_frame() {
    let xml = urdf(
        "<link name=\"a\"><visual><origin xyz=\"1 0 0\" rpy=\"0 1.5707963267948966 0\"/>\
         <geometry><cylinder radius=\"0.1\" length=\"0.4\"/></geometry></visual>\
         <visual><geometry><sphere radius=\"0.05\"/></geometry></visual></link>",
    );
    let r = load(&xml).unwrap();
    assert_eq!(r.visuals(0)[0].triangles, 4 * 32);
    assert_eq!(r.visuals(0)[1].triangles, 2 * 24 * 11);
    let m = &r.link_meshes()[0].mesh;
    // The cylinder's axis (z) was turned onto x: it spans x in 1 +- 0.2.
    let max_x = m.positions.iter().map(|p| p.x).fold(f32::MIN, f32::max);
    let min_x = m.positions.iter().map(|p| p.x).fold(f32::MAX, f32::min);
    assert!(
        (max_x - 1.2).abs() < 1e-5 && (min_x + 0.05).abs() < 1e-5,
        "{min_x} {max_x}"
    );
}

/// Loads `xml`, asserting it loads, and returns it with its warnings.
fn load_with_warnings(xml: &str) -> (Robot, Vec<String>) {
    let r = load(xml).unwrap_or_else(|e| panic!("{e}\n{xml}"));
    let w = r.warnings().to_vec();
    (r, w)
}

#[test]
fn a_texture_without_filename_is_dropped_with_a_warning() {
    // iCub, romeo: `<texture/>` in a material (urdf-rs: "missing field `filename`").
    let xml = urdf(
        &("<material name=\"skin\"><color rgba=\"1 1 1 1\"/><texture/></material>\
         <link name=\"a\"><visual><geometry><box size=\"1 1 1\"/></geometry>\
         <material name=\"paint\"><texture/></material></visual></link>\
         <link name=\"b\"><visual><geometry><box size=\"1 1 1\"/></geometry>\
         <material name=\"img\"><texture filename=\"t.png\"/></material></visual></link>"
            .to_string()
            + &joint("j", "fixed", "a", "b", "")),
    );
    let (r, w) = load_with_warnings(&xml);
    assert_eq!(r.triangle_count(), 24);
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[0].contains("material \"skin\"") && w[0].contains("texture"));
    assert!(w[1].contains("material \"paint\" of link \"a\""), "{w:?}");
}

#[test]
fn a_duplicate_axis_keeps_the_first_with_a_warning() {
    let xml = urdf(
        &(link("a")
            + &link("b")
            + "<joint name=\"j\" type=\"revolute\"><parent link=\"a\"/><child link=\"b\"/>\
               <axis xyz=\"0 1 0\"/><axis xyz=\"1 0 0\"/>\
               <limit lower=\"-1\" upper=\"1\" effort=\"1\" velocity=\"1\"/>\
               <limit lower=\"-2\" upper=\"2\" effort=\"1\" velocity=\"1\"/></joint>"),
    );
    let (r, w) = load_with_warnings(&xml);
    assert_eq!(r.joints()[0].axis.into_inner(), Vector3::y());
    assert_eq!(r.joints()[0].limits.unwrap().upper, 1.0);
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(w[0].contains("joint \"j\" has 2 <axis> elements"), "{w:?}");
    assert!(w[1].contains("<limit>"), "{w:?}");
}

#[test]
fn a_four_value_mesh_scale_uses_the_first_three_with_a_warning() {
    let tmp = tempfile::tempdir().unwrap();
    write(tmp.path(), "a.stl", STL);
    let xml = urdf(
        "<link name=\"a\"><visual><geometry><mesh filename=\"a.stl\" scale=\" 2 3 4 1 \"/>\
         </geometry></visual><collision><geometry>\
         <mesh filename=\"a.stl\" scale=\"1 1 1 1\"/></geometry></collision></link>",
    );
    let r = Robot::from_urdf_str(&xml, Some(tmp.path()), &RobotConfig::default()).unwrap();
    let w = r.warnings();
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(
        w[0].contains("mesh \"a.stl\" in a visual of link \"a\"") && w[0].contains("first 3"),
        "{w:?}"
    );
    assert!(w[1].contains("in a collision of link \"a\""), "{w:?}");
    match &r.visuals(0)[0].geometry {
        VisualGeometry::Mesh { scale, .. } => assert_eq!(*scale, [2.0, 3.0, 4.0]),
        other => panic!("{other:?}"),
    }
    assert!(
        r.link_meshes()[0]
            .mesh
            .positions
            .contains(&nalgebra::Point3::new(0.0, 3.0, 0.0))
    );
    // Fewer than three values, or words, stay errors.
    let e = load(&urdf(
        "<link name=\"a\"><visual><geometry><mesh filename=\"a.stl\" scale=\"1 1\"/>\
         </geometry></visual></link>",
    ))
    .unwrap_err();
    assert!(matches!(e, RobotError::MalformedUrdf { .. }), "{e}");
}

#[test]
fn plane_geometry_drops_that_visual_with_a_warning() {
    let xml = urdf(
        "<link name=\"floor\"><visual name=\"ground\"><geometry><plane normal=\"0 0 1\"/>\
         </geometry></visual><visual><geometry><box size=\"1 1 1\"/></geometry></visual>\
         <collision><geometry><plane normal=\"0 0 1\"/></geometry></collision></link>",
    );
    let (r, w) = load_with_warnings(&xml);
    assert_eq!(r.visuals(0).len(), 1);
    assert_eq!(r.triangle_count(), 12);
    assert_eq!(w.len(), 2, "{w:?}");
    assert!(
        w[0].contains("a visual \"ground\" of link \"floor\"") && w[0].contains("<plane>"),
        "{w:?}"
    );
    assert!(w[1].contains("a collision of link \"floor\""), "{w:?}");
}

#[test]
fn a_binary_stl_with_a_solid_header_loads_through_the_urdf() {
    let tmp = tempfile::tempdir().unwrap();
    let mut stl = b"solid foot (binary, SolidWorks)".to_vec();
    stl.resize(80, 0);
    stl.extend(1u32.to_le_bytes());
    for v in [
        [0f32, 0.0, 1.0],
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [0.0, 1.0, 0.0],
    ] {
        stl.extend(v.iter().flat_map(|c| c.to_le_bytes()));
    }
    stl.extend([0u8; 2]);
    std::fs::write(tmp.path().join("foot.stl"), &stl).unwrap();
    let xml = urdf(&mesh_link("foot", "foot.stl"));
    let r = Robot::from_urdf_str(&xml, Some(tmp.path()), &RobotConfig::default()).unwrap();
    assert!(r.warnings().is_empty(), "{:?}", r.warnings());
    assert_eq!(r.triangle_count(), 1);
}

#[test]
fn unknown_camera_link_is_an_error() {
    let r = load(&urdf(&link("a"))).unwrap();
    let e = r
        .camera_from_base(&r.zero_positions(), "cam", CameraConvention::Optical)
        .unwrap_err();
    assert_eq!(e, RobotError::UnknownCameraLink { name: "cam".into() });
}

#[test]
fn archive_paths_are_normalised_or_refused() {
    assert_eq!(
        normalize_relative(Path::new("a/./b/../c")),
        Some(PathBuf::from("a/c"))
    );
    assert_eq!(normalize_relative(Path::new("../x")), None);
    assert_eq!(normalize_relative(Path::new("/etc/passwd")), None);
    let e = Robot::from_archive_bytes(b"plain text", "x.zip", &RobotConfig::default()).unwrap_err();
    assert!(matches!(e, RobotError::Archive { .. }), "{e}");
}

fn package_xml(name: &str) -> String {
    format!(
        "<?xml version=\"1.0\"?>\n<package format=\"3\">\n  <name> {name} </name>\n</package>\n"
    )
}

#[test]
fn packages_are_found_by_package_xml_first_then_by_folder_name() {
    let tmp = tempfile::tempdir().unwrap();
    let ws = tmp.path().join("ws");
    // A colcon workspace: the source package (its folder named after its repository),
    // an isolated install, and another package that must not be searched inside.
    write(
        &ws,
        "src/arm_repo/arm_description/package.xml",
        &package_xml("arm_description"),
    );
    write(&ws, "src/other/package.xml", &package_xml("other"));
    write(&ws, "src/other/arm_description/meshes/x.stl", STL);
    write(
        &ws,
        "install/arm_description/share/arm_description/package.xml",
        &package_xml("arm_description"),
    );
    let src = ws.join("src");
    assert_eq!(
        find_package("arm_description", std::slice::from_ref(&src)),
        Some(src.join("arm_repo/arm_description"))
    );
    // `install/NAME` is only called NAME: the declared package below it wins.
    let install = ws.join("install");
    assert_eq!(
        find_package("arm_description", std::slice::from_ref(&install)),
        Some(install.join("arm_description/share/arm_description"))
    );
    // A root that is the package; roots are tried in order.
    let pkg = src.join("arm_repo/arm_description");
    assert_eq!(
        find_package("arm_description", &[pkg.clone(), install.clone()]),
        Some(pkg.clone())
    );
    // Without a package.xml, the folder name; nothing inside another package; none.
    write(tmp.path(), "copied/meshes_pkg/a.stl", STL);
    assert_eq!(
        find_package("meshes_pkg", &[tmp.path().join("copied")]),
        Some(tmp.path().join("copied/meshes_pkg"))
    );
    assert_eq!(find_package("arm_description", &[src.join("other")]), None);
    assert_eq!(
        find_package("absent", &[ws.clone(), tmp.path().join("nope")]),
        None
    );
    assert_eq!(package_xml_name(&pkg).as_deref(), Some("arm_description"));
    assert_eq!(package_of("package://p/m/a.stl"), Some(("p", "m/a.stl")));
    assert_eq!(package_of("meshes/a.stl"), None);
}

#[test]
fn package_paths_resolve_meshes_the_urdf_folder_cannot() {
    let tmp = tempfile::tempdir().unwrap();
    let xml = urdf(
        &(mesh_link("a", "package://far_pkg/meshes/a.stl")
            + &mesh_link("b", "package://far_pkg/meshes/a.stl")
            + &mesh_link("c", "package://far_pkg/meshes/gone.stl")
            + &mesh_link("d", "meshes/local.stl")
            + &mesh_link("e", "meshes/bad.stl")
            + &joint("j1", "fixed", "a", "b", "")
            + &joint("j2", "fixed", "a", "c", "")
            + &joint("j3", "fixed", "a", "d", "")
            + &joint("j4", "fixed", "a", "e", "")),
    );
    write(tmp.path(), "robot/r.urdf", &xml);
    // Found but unreadable: a warning, not a missing mesh.
    write(tmp.path(), "robot/meshes/bad.stl", "not a mesh");
    let urdf_path = tmp.path().join("robot/r.urdf");
    let cfg = RobotConfig::default();
    // Without package paths: every mesh is missing, grouped per filename.
    let plain = Robot::load(&urdf_path, &cfg).unwrap();
    let missing = plain.missing_meshes();
    assert_eq!(missing.len(), 3, "{missing:?}");
    assert_eq!(missing[0].package.as_deref(), Some("far_pkg"));
    assert_eq!(missing[0].path, "meshes/a.stl");
    assert_eq!(missing[0].links, ["a", "b"]);
    assert_eq!(missing[1].links, ["c"]);
    assert_eq!(missing[2].package, None);
    assert_eq!(missing[2].path, "meshes/local.stl");
    assert_eq!(plain.triangle_count(), 0);
    assert_eq!(plain.warnings().len(), 4, "{:?}", plain.warnings());
    let other: Vec<&str> = plain.other_warnings().collect();
    assert_eq!(other.len(), 1, "{other:?}");
    assert!(other[0].contains("bad.stl"), "{other:?}");
    // The package elsewhere, given as the folder holding it.
    write(
        tmp.path(),
        "elsewhere/far_pkg/package.xml",
        &package_xml("far_pkg"),
    );
    write(tmp.path(), "elsewhere/far_pkg/meshes/a.stl", STL);
    let r = Robot::load_with_packages(&urdf_path, &[tmp.path().join("elsewhere")], &cfg).unwrap();
    assert_eq!(r.triangle_count(), 2, "links a and b");
    let missing = r.missing_meshes();
    assert_eq!(
        missing.iter().map(|m| m.uri.as_str()).collect::<Vec<_>>(),
        ["package://far_pkg/meshes/gone.stl", "meshes/local.stl"]
    );
    // The warning of a mesh the found package lacks says where the package is.
    assert!(
        r.warnings()
            .iter()
            .any(|w| w.contains("gone.stl") && w.contains("elsewhere/far_pkg")),
        "{:?}",
        r.warnings()
    );
    match &r.visuals(0)[0].geometry {
        VisualGeometry::Mesh { resolved, .. } => {
            assert!(
                resolved
                    .as_deref()
                    .unwrap()
                    .ends_with("elsewhere/far_pkg/meshes/a.stl")
            )
        }
        other => panic!("{other:?}"),
    }
    // Archives are sealed: package paths are not read for them.
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    zip.start_file("r.urdf", zip::write::SimpleFileOptions::default())
        .unwrap();
    std::io::Write::write_all(&mut zip, xml.as_bytes()).unwrap();
    let bytes = zip.finish().unwrap().into_inner();
    std::fs::write(tmp.path().join("r.zip"), bytes).unwrap();
    let sealed = Robot::load_with_packages(
        &tmp.path().join("r.zip"),
        &[tmp.path().join("elsewhere")],
        &cfg,
    )
    .unwrap();
    assert_eq!(sealed.triangle_count(), 0);
    let missing = sealed.missing_meshes();
    assert_eq!(missing.len(), 4, "the archive holds no mesh: {missing:?}");
    assert_eq!(missing[0].uri, "package://far_pkg/meshes/a.stl");
}
