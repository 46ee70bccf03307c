//! Writes the seed corpora of the fuzz targets (`fuzz/corpus/<target>/`): small valid
//! inputs of every kind each parser takes, made with vamos's own encoders and writers
//! from the test fixtures, so the fuzzer starts from inputs that reach deep into each
//! parser. Run from the repository root:
//!
//! ```sh
//! cargo run --release --example make_fuzz_corpus
//! ```
//!
//! The corpora are committed; rerun this when a parser learns a new kind of input.

use anyhow::{Context, Result};
use prost::Message;
use std::io::Write;
use std::path::PathBuf;
use vamos::api::proto::{self, stream_request::Message as In};
use vamos::episode::cdr::CdrWriter;
use vamos::episode::ros::{
    CompressedImageMsg, Header, ImageMsg, JointStateMsg, encode_bool, encode_f64, encode_string,
};
use vamos::episode::synthetic::{SyntheticBag, write_bag};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

struct Corpus {
    dir: PathBuf,
    n: usize,
}

impl Corpus {
    fn new(target: &str) -> Result<Self> {
        let dir = root().join("fuzz/corpus").join(target);
        if dir.exists() {
            std::fs::remove_dir_all(&dir)?;
        }
        std::fs::create_dir_all(&dir)?;
        Ok(Self { dir, n: 0 })
    }

    /// One seed: `selector` (if any) followed by `bytes`, named `<n>-<label>`.
    fn add(&mut self, label: &str, selector: Option<u8>, bytes: &[u8]) -> Result<()> {
        let mut data = Vec::with_capacity(bytes.len() + 1);
        data.extend(selector);
        data.extend_from_slice(bytes);
        let path = self.dir.join(format!("{:02}-{label}", self.n));
        std::fs::write(&path, data).with_context(|| path.display().to_string())?;
        self.n += 1;
        Ok(())
    }
}

fn png(width: u32, height: u32) -> Result<Vec<u8>> {
    let img =
        image::GrayImage::from_fn(width, height, |x, y| image::Luma([(x * 40 + y * 7) as u8]));
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Png)?;
    Ok(out.into_inner())
}

fn jpeg(width: u32, height: u32) -> Result<Vec<u8>> {
    let img = image::RgbImage::from_fn(width, height, |x, y| {
        image::Rgb([(x * 30) as u8, (y * 30) as u8, 128])
    });
    let mut out = std::io::Cursor::new(Vec::new());
    img.write_to(&mut out, image::ImageFormat::Jpeg)?;
    Ok(out.into_inner())
}

fn image_msg<'a>(
    encoding: &str,
    width: u32,
    height: u32,
    bpp: u32,
    data: &'a [u8],
) -> ImageMsg<'a> {
    ImageMsg {
        header: Header::from_stamp_ns(1_500_000_000, "camera"),
        height,
        width,
        encoding: encoding.into(),
        is_bigendian: encoding == "mono16",
        step: width * bpp,
        data,
    }
}

fn camera_info(width: u32, height: u32) -> Vec<u8> {
    let mut w = CdrWriter::new();
    // header
    w.i32(1);
    w.u32(500_000_000);
    w.string("camera");
    w.u32(height);
    w.u32(width);
    w.string("plumb_bob");
    w.f64_seq(&[0.0; 5]);
    let (f, cx, cy) = (
        f64::from(width),
        f64::from(width) / 2.0,
        f64::from(height) / 2.0,
    );
    w.f64_array(&[f, 0.0, cx, 0.0, f, cy, 0.0, 0.0, 1.0]);
    w.f64_array(&[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]);
    w.f64_array(&[f, 0.0, cx, 0.0, 0.0, f, cy, 0.0, 0.0, 0.0, 1.0, 0.0]);
    for _ in 0..6 {
        w.u32(0);
    }
    w.bool(false);
    w.into_bytes()
}

fn joints(stamp_ns: i64, positions: &[f64]) -> JointStateMsg {
    JointStateMsg {
        header: Header::from_stamp_ns(stamp_ns, ""),
        name: (0..positions.len())
            .map(|i| format!("joint{}", i + 1))
            .collect(),
        position: positions.to_vec(),
        velocity: vec![0.0; positions.len()],
        effort: Vec::new(),
    }
}

fn cdr_message() -> Result<()> {
    let mut c = Corpus::new("cdr_message")?;
    let rgb: Vec<u8> = (0..4 * 3 * 3).map(|i| (i * 7) as u8).collect();
    c.add("rgb8", Some(0), &image_msg("rgb8", 4, 3, 3, &rgb).encode())?;
    let mono16: Vec<u8> = (0..2 * 2 * 2).map(|i| (i * 31) as u8).collect();
    c.add(
        "mono16-be",
        Some(0),
        &image_msg("mono16", 2, 2, 2, &mono16).encode(),
    )?;
    let floats: Vec<u8> = [0.5f32, f32::NAN, 2.0, -1.0]
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect();
    c.add(
        "32fc1",
        Some(0),
        &image_msg("32FC1", 2, 2, 4, &floats).encode(),
    )?;
    for (format, data) in [("png", png(4, 4)?), ("jpeg", jpeg(8, 8)?)] {
        let msg = CompressedImageMsg {
            header: Header::from_stamp_ns(2_000_000_000, "camera"),
            format: format.into(),
            data: &data,
        };
        c.add(format, Some(1), &msg.encode())?;
    }
    c.add("camera-info", Some(2), &camera_info(16, 12))?;
    c.add(
        "joint-state",
        Some(3),
        &joints(3_000_000_000, &[0.1, -0.2]).encode(),
    )?;
    c.add("string", Some(4), &encode_string("<robot name=\"r\"/>"))?;
    c.add("f64", Some(5), &encode_f64(1.25))?;
    c.add("bool", Some(6), &encode_bool(true))?;
    Ok(())
}

fn mcap_episode() -> Result<()> {
    let mut c = Corpus::new("mcap_episode")?;
    let tmp = tempfile::tempdir()?;
    let bag = tmp.path().join("synthetic.mcap");
    write_bag(
        &bag,
        &SyntheticBag {
            frames: 3,
            width: 8,
            height: 6,
            image_period_ns: 100_000_000,
            joint_period_ns: 50_000_000,
            ..SyntheticBag::default()
        },
    )?;
    let bytes = std::fs::read(&bag)?;
    c.add("synthetic", None, &bytes)?;
    c.add("synthetic-truncated", None, &bytes[..bytes.len() * 2 / 3])?;
    // The small fixture bags of the episode tests (Python-written, several encodings).
    for name in [
        "cdr_be",
        "no_joints",
        "mono8_zero_stamps",
        "backwards",
        "png_label_topic",
        "unknown_encoding",
        "size_change",
    ] {
        let path = root()
            .join("tests/fixtures/episode")
            .join(format!("{name}.mcap"));
        c.add(
            name,
            None,
            &std::fs::read(&path).with_context(|| path.display().to_string())?,
        )?;
    }
    Ok(())
}

/// `image_message` layout: encoding selector, big-endian flag, width, height, step (u16
/// LE each), pixels.
fn image_seed(encoding: u8, big_endian: bool, w: u16, h: u16, step: u16, data: &[u8]) -> Vec<u8> {
    let mut out = vec![encoding, u8::from(big_endian)];
    for v in [w, h, step] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(data);
    out
}

fn image_message() -> Result<()> {
    let mut c = Corpus::new("image_message")?;
    let px: Vec<u8> = (0..64).map(|i| (i * 5) as u8).collect();
    // Selectors index `vamos::fuzz::image_message`'s encoding list.
    c.add("rgb8", None, &image_seed(0, false, 4, 3, 0, &px[..36]))?;
    c.add(
        "bgra8-padded",
        None,
        &image_seed(3, false, 2, 3, 10, &px[..30]),
    )?;
    c.add("mono8", None, &image_seed(4, false, 8, 8, 8, &px))?;
    c.add("mono16-be", None, &image_seed(6, true, 4, 4, 8, &px[..32]))?;
    c.add("32fc1", None, &image_seed(8, false, 2, 2, 8, &px[..16]))?;
    c.add("png", None, &image_seed(9, false, 0, 0, 0, &png(5, 3)?))?;
    c.add("jpeg", None, &image_seed(10, false, 0, 0, 0, &jpeg(8, 8)?))?;
    c.add("unknown", None, &image_seed(11, false, 2, 2, 4, &px[..8]))?;
    Ok(())
}

const SMALL_URDF: &str = r#"<?xml version="1.0"?>
<robot name="fuzz">
  <link name="base"><visual><geometry><box size="0.2 0.2 0.1"/></geometry></visual></link>
  <link name="arm"><visual><origin xyz="0 0 0.2" rpy="0 1.57 0"/><geometry><cylinder radius="0.05" length="0.4"/></geometry></visual></link>
  <link name="slider"><visual><geometry><sphere radius="0.03"/></geometry></visual></link>
  <link name="wheel"><visual><geometry><capsule radius="0.02" length="0.1"/></geometry></visual></link>
  <link name="camera"/>
  <link name="tool"><visual><geometry><mesh filename="package://fuzz/meshes/tool.stl" scale="0.5 0.5 0.5"/></geometry></visual></link>
  <joint name="shoulder" type="revolute"><parent link="base"/><child link="arm"/><origin xyz="0 0 0.1"/><axis xyz="0 1 0"/><limit lower="-1.5" upper="1.5" effort="10" velocity="1"/></joint>
  <joint name="slide" type="prismatic"><parent link="arm"/><child link="slider"/><origin xyz="0 0 0.4"/><axis xyz="0 0 1"/><limit lower="0" upper="0.2" effort="10" velocity="1"/></joint>
  <joint name="spin" type="continuous"><parent link="slider"/><child link="wheel"/><axis xyz="1 0 0"/></joint>
  <joint name="mimic" type="revolute"><parent link="slider"/><child link="tool"/><axis xyz="0 0 1"/><limit lower="-1" upper="1" effort="1" velocity="1"/><mimic joint="shoulder" multiplier="-1" offset="0.1"/></joint>
  <joint name="camera_joint" type="fixed"><parent link="base"/><child link="camera"/><origin xyz="0.1 0 0.3" rpy="0 0.5 0"/></joint>
</robot>
"#;

const STL_ASCII: &str = "solid tool\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\nendloop\nendfacet\nfacet normal 0 0 1\nouter loop\nvertex 1 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid tool\n";

const OBJ: &str = "# tetrahedron\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nvn 0 0 1\nf 1 3 2\nf 1 2 4\nf 2 3 4\nf 3 1 4\n";

const DAE: &str = r##"<?xml version="1.0" encoding="utf-8"?>
<COLLADA xmlns="http://www.collada.org/2005/11/COLLADASchema" version="1.4.1">
  <asset><unit meter="1"/><up_axis>Z_UP</up_axis></asset>
  <library_geometries>
    <geometry id="tri" name="tri"><mesh>
      <source id="tri-pos"><float_array id="tri-pos-array" count="9">0 0 0 1 0 0 0 1 0</float_array>
        <technique_common><accessor source="#tri-pos-array" count="3" stride="3">
          <param name="X" type="float"/><param name="Y" type="float"/><param name="Z" type="float"/>
        </accessor></technique_common></source>
      <vertices id="tri-vtx"><input semantic="POSITION" source="#tri-pos"/></vertices>
      <triangles count="1"><input semantic="VERTEX" source="#tri-vtx" offset="0"/><p>0 1 2</p></triangles>
    </mesh></geometry>
  </library_geometries>
  <library_visual_scenes><visual_scene id="s"><node id="n"><instance_geometry url="#tri"/></node></visual_scene></library_visual_scenes>
  <scene><instance_visual_scene url="#s"/></scene>
</COLLADA>
"##;

fn stl_binary() -> Vec<u8> {
    let mut out = vec![0u8; 80];
    out.extend_from_slice(&1u32.to_le_bytes());
    for v in [0f32, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&[0, 0]);
    out
}

fn urdf_and_meshes() -> Result<()> {
    let mut c = Corpus::new("urdf")?;
    c.add("small", None, SMALL_URDF.as_bytes())?;
    c.add(
        "sim-arm",
        None,
        &std::fs::read(root().join("tests/fixtures/sim/robot/vamos_arm.urdf"))?,
    )?;
    c.add(
        "empty-robot",
        None,
        b"<robot name=\"r\"><link name=\"a\"/></robot>",
    )?;

    let mut m = Corpus::new("mesh")?;
    m.add("ascii-stl", Some(0), STL_ASCII.as_bytes())?;
    m.add("binary-stl", Some(0), &stl_binary())?;
    m.add("obj", Some(1), OBJ.as_bytes())?;
    m.add("dae", Some(2), DAE.as_bytes())?;

    let mut a = Corpus::new("robot_archive")?;
    let files: [(&str, &[u8]); 2] = [
        ("fuzz/robot.urdf", SMALL_URDF.as_bytes()),
        ("fuzz/meshes/tool.stl", STL_ASCII.as_bytes()),
    ];
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    for (name, data) in files {
        zip.start_file(name, zip::write::SimpleFileOptions::default())?;
        zip.write_all(data)?;
    }
    a.add("zip", None, &zip.finish()?.into_inner())?;
    let mut tar = tar::Builder::new(flate2::write::GzEncoder::new(
        Vec::new(),
        flate2::Compression::default(),
    ));
    for (name, data) in files {
        let mut header = tar::Header::new_gnu();
        header.set_size(data.len() as u64);
        header.set_mode(0o644);
        header.set_cksum();
        tar.append_data(&mut header, name, data)?;
    }
    a.add("tar-gz", None, &tar.into_inner()?.finish()?)?;
    // No top folder, the sim arm's URDF alone (its meshes are primitives).
    let mut zip = zip::ZipWriter::new(std::io::Cursor::new(Vec::new()));
    zip.start_file("vamos_arm.urdf", zip::write::SimpleFileOptions::default())?;
    zip.write_all(&std::fs::read(
        root().join("tests/fixtures/sim/robot/vamos_arm.urdf"),
    )?)?;
    a.add("zip-flat", None, &zip.finish()?.into_inner())?;
    Ok(())
}

fn model_bundle() -> Result<()> {
    let mut c = Corpus::new("model_bundle")?;
    let dir = root().join("tests/fixtures/model");
    for name in [
        "valid",
        "wrong_shape",
        "checksum",
        "missing_member",
        "future_version",
    ] {
        c.add(
            name,
            Some(0),
            &std::fs::read(dir.join(format!("{name}.vamos")))?,
        )?;
    }
    let mut zip = zip::ZipArchive::new(std::fs::File::open(dir.join("valid.vamos"))?)?;
    for (member, selector) in [("manifest.json", 1), ("encoder.onnx", 2), ("head.onnx", 2)] {
        let mut bytes = Vec::new();
        std::io::Read::read_to_end(&mut zip.by_name(member)?, &mut bytes)?;
        c.add(member, Some(selector), &bytes)?;
    }
    // A head exported by vamos-train: the fcomb shape the native head recognises.
    let mut zip = zip::ZipArchive::new(std::fs::File::open(dir.join("tiny_trained.vamos"))?)?;
    let mut bytes = Vec::new();
    std::io::Read::read_to_end(&mut zip.by_name("head.onnx")?, &mut bytes)?;
    c.add("fcomb_head.onnx", Some(2), &bytes)?;
    Ok(())
}

/// Request sequences for `stream_requests` and `stream_session`; the session target also
/// gets the first images of a real episode (its arm, its joint states), as PNG at 40x30.
fn stream_requests() -> Result<()> {
    let open = In::Open(proto::OpenSession {
        robot_id: "robot".into(),
        profile: "sim-arm".into(),
        camera_info: Some(proto::CameraInfo {
            width: 8,
            height: 6,
            fx: 8.0,
            fy: 8.0,
            cx: 4.0,
            cy: 3.0,
        }),
        task: "place_book".into(),
        session_id: "s1".into(),
        anomaly_maps: false,
        image_rate_hz: 0.0,
    });
    let joint = |stamp_ns: i64, p: f64| {
        In::Joints(proto::JointState {
            stamp_ns,
            names: vec!["joint1".into(), "joint2".into()],
            positions: vec![p, -p],
            ..Default::default()
        })
    };
    let image = |stamp_ns: i64, encoding: &str, width: u32, height: u32, data: Vec<u8>| {
        In::Image(proto::Image {
            stamp_ns,
            encoding: encoding.into(),
            width,
            height,
            step: 0,
            big_endian: false,
            data,
            depth: None,
        })
    };
    let phase = In::Phase(proto::PhaseMarker {
        stamp_ns: 3_000,
        phase: "grasp".into(),
    });
    let sequences = [
        (
            "session",
            vec![
                open.clone(),
                joint(900, 0.1),
                joint(1_100, 0.2),
                image(1_000, "mono8", 8, 6, (0..48).collect()),
                joint(2_100, 0.3),
                image(2_000, "png", 0, 0, png(8, 6)?),
                phase,
            ],
        ),
        (
            "bad-joints",
            vec![
                open,
                joint(2_000, 0.1),
                joint(1_000, 0.2),
                In::Joints(proto::JointState {
                    stamp_ns: 3_000,
                    names: vec!["a".into()],
                    positions: vec![f64::NAN],
                    ..Default::default()
                }),
                image(2_500, "rgb8", 2, 2, vec![9; 12]),
            ],
        ),
        (
            "images-only",
            vec![
                image(
                    10,
                    "32FC1",
                    2,
                    2,
                    [1.0f32, 2.0, 3.0, 4.0]
                        .iter()
                        .flat_map(|v| v.to_le_bytes())
                        .collect(),
                ),
                In::Image(proto::Image {
                    stamp_ns: 20,
                    encoding: "bgr8".into(),
                    width: 2,
                    height: 2,
                    step: 8,
                    big_endian: false,
                    data: vec![7; 16],
                    depth: None,
                }),
                image(30, "jpeg", 0, 0, jpeg(8, 8)?),
            ],
        ),
    ];
    let encode = |messages: Vec<In>| -> Result<Vec<u8>> {
        let mut bytes = Vec::new();
        for m in messages {
            proto::StreamRequest { message: Some(m) }.encode_length_delimited(&mut bytes)?;
        }
        Ok(bytes)
    };
    let mut requests = Corpus::new("stream_requests")?;
    let mut session = Corpus::new("stream_session")?;
    for (label, messages) in sequences {
        let bytes = encode(messages)?;
        requests.add(label, None, &bytes)?;
        session.add(label, None, &bytes)?;
    }
    session.add("episode", None, &encode(episode_requests(5)?)?)?;
    Ok(())
}

/// The open and the first `images` images (40x30 PNG) with their joint states of the
/// simulator's nominal episode, in log-time order.
fn episode_requests(images: usize) -> Result<Vec<In>> {
    use vamos::vision::preprocess::{ResizeFilter, resize};
    let path = root().join("tests/fixtures/sim/test/test_0000.mcap");
    let rec = vamos::client::replay::record(&path, &Default::default())?;
    let episode = vamos::episode::McapEpisode::open(&path, &Default::default())?;
    let grays: std::collections::HashMap<i64, vamos::vision::GrayImage> = episode
        .frames()
        .filter_map(|f| f.ok())
        .map(|f| (f.stamp_ns, f.image))
        .collect();
    let mut out = vec![In::Open(proto::OpenSession {
        robot_id: "robot".into(),
        profile: "fuzz".into(),
        camera_info: rec.camera,
        task: String::new(),
        session_id: String::new(),
        anomaly_maps: false,
        image_rate_hz: 0.0,
    })];
    let mut seen = 0;
    for (_, m) in rec.messages {
        if let In::Image(img) = &m {
            seen += 1;
            if seen > images {
                break;
            }
            let gray = grays
                .get(&img.stamp_ns)
                .context("an image without a frame")?;
            let small = resize(gray, 40, 30, ResizeFilter::Area)?;
            let px: Vec<u8> = small
                .data()
                .iter()
                .map(|v| v.clamp(0.0, 255.0) as u8)
                .collect();
            let mut data = Vec::new();
            image::ImageEncoder::write_image(
                image::codecs::png::PngEncoder::new(&mut data),
                &px,
                40,
                30,
                image::ExtendedColorType::L8,
            )?;
            out.push(In::Image(proto::Image {
                stamp_ns: img.stamp_ns,
                encoding: "png".into(),
                data,
                ..Default::default()
            }));
        } else {
            out.push(m);
        }
    }
    Ok(out)
}

fn rest_body() -> Result<()> {
    let mut c = Corpus::new("rest_body")?;
    let profile = serde_json::json!({
        "flow_preset": "realtime",
        "alarm": "conformal",
        "pipeline": {"stride": 1, "frames": {"width": 160, "height": 120, "variant": "masked"}},
        "thresholds": {"e_c": 2.0},
    });
    let mut named = b"arm-1\0".to_vec();
    named.extend(serde_json::to_vec(&profile)?);
    c.add("profile", Some(0), &named)?;
    c.add("profile-bad-name", Some(0), b"../etc\0{}")?;
    c.add(
        "thresholds",
        Some(1),
        br#"{"e_c": 2.5, "e_b": null, "alarm": 9.0}"#,
    )?;
    c.add(
        "active",
        Some(2),
        br#"{"version": 2, "reload_sessions": true}"#,
    )?;
    c.add(
        "calibrate",
        Some(3),
        br#"{"episodes": ["train/"], "holdout": ["val/a.mcap"], "alpha": 0.1}"#,
    )?;
    Ok(())
}

fn main() -> Result<()> {
    cdr_message()?;
    mcap_episode()?;
    image_message()?;
    urdf_and_meshes()?;
    model_bundle()?;
    stream_requests()?;
    rest_body()?;
    let corpus = root().join("fuzz/corpus");
    let mut seeds = 0;
    for target in std::fs::read_dir(&corpus)? {
        seeds += std::fs::read_dir(target?.path())?.count();
    }
    println!("{seeds} seeds in {}", corpus.display());
    Ok(())
}
