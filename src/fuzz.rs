//! Fuzzing entry points: one function per parser that takes outside bytes, called by the
//! `cargo fuzz` targets in `fuzz/` and, on the committed corpora, by
//! `tests/integration/fuzz_corpus.rs`.
//!
//! Each function feeds its bytes to the code the server runs on the same input and checks
//! what must hold whatever the bytes: no panic (the fuzzer's finding), no unbounded work,
//! and the invariants noted per function (finite pixels, round trips, bounded counts). A
//! violated invariant panics, which the fuzzer reports as a crash.
//!
//! Not part of the stable API (hidden from the documentation).

use crate::api::proto;
use crate::episode::ros::{
    CameraInfoMsg, CompressedImageMsg, ImageMsg, JointStateMsg, decode_bool, decode_f64,
    decode_string,
};
use crate::episode::{EpisodeConfig, McapEpisode};
use crate::model::bundle::{Bundle, Manifest};
use crate::robot::{Robot, RobotConfig, mesh::mesh_from_bytes};
use crate::store::{Store, StoreLimits, ThresholdsPatch};
use crate::vision::GrayImage;
use std::path::Path;
use std::sync::OnceLock;

/// Pixel cap for decoded images in the targets: big enough for every real camera, small
/// enough that one input cannot make the fuzzer spend seconds on one image.
const FUZZ_MAX_PIXELS: usize = 1 << 22;

/// A streamed image converted and decoded as the server does (no memory budget).
fn decode_streamed(
    image: &proto::Image,
) -> Result<(GrayImage, Option<crate::session::budget::Charge>), crate::session::worker::ImageRefused>
{
    let live = crate::api::grpc::convert::live_image(image.clone());
    crate::session::worker::decode_live_image(&live, FUZZ_MAX_PIXELS, None)
}

/// libfuzzer-sys's panic hook aborts on every panic, also on those the code catches on
/// purpose (a third-party mesh parser's, see `robot::mesh`). The default hook is put back:
/// a panic that escapes still aborts the run (libfuzzer-sys aborts when one reaches it).
fn harness() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| drop(std::panic::take_hook()));
}

fn assert_finite(img: &GrayImage, what: &str) {
    assert!(
        img.data().iter().all(|v| v.is_finite()),
        "{what}: a decoded pixel is not finite"
    );
    assert!(
        img.width() * img.height() <= FUZZ_MAX_PIXELS,
        "{what}: over the pixel cap"
    );
}

/// ROS 2 CDR messages (the payloads of a bag's or a ROS bridge's messages). The first byte
/// picks the message type; the rest is the payload. Invariants: a decoded image gives
/// finite pixels; what decodes re-encodes to bytes that decode to the same message.
pub fn cdr_message(data: &[u8]) {
    harness();
    let Some((&kind, payload)) = data.split_first() else {
        return;
    };
    match kind % 7 {
        0 => {
            if let Ok(m) = ImageMsg::decode(payload) {
                let again = m.encode();
                assert_eq!(
                    ImageMsg::decode(&again).ok().as_ref(),
                    Some(&m),
                    "Image round trip"
                );
                if let Ok(img) = m.to_gray(FUZZ_MAX_PIXELS) {
                    assert_finite(&img, "Image");
                }
            }
        }
        1 => {
            if let Ok(m) = CompressedImageMsg::decode(payload) {
                let again = m.encode();
                assert_eq!(
                    CompressedImageMsg::decode(&again).ok().as_ref(),
                    Some(&m),
                    "CompressedImage round trip"
                );
                if let Ok(img) = m.to_gray(FUZZ_MAX_PIXELS) {
                    assert_finite(&img, "CompressedImage");
                }
            }
        }
        2 => {
            if let Ok(m) = CameraInfoMsg::decode(payload) {
                let _ = m.intrinsics();
            }
        }
        3 => {
            if let Ok(m) = JointStateMsg::decode(payload) {
                assert!(
                    m.position.iter().all(|p| p.is_finite()),
                    "JointState: NaN kept"
                );
                let once = m.encode();
                let twice = JointStateMsg::decode(&once)
                    .map(|m| m.encode())
                    .unwrap_or_default();
                assert_eq!(once, twice, "JointState round trip");
            }
        }
        4 => {
            let _ = decode_string(payload);
        }
        5 => {
            let _ = decode_f64(payload);
        }
        _ => {
            let _ = decode_bool(payload);
        }
    }
}

/// A ROS 2 bag in MCAP: opened (summary or linear scan), then every frame, the camera
/// info, the labels and the robot description read, as `vamos score` does. The bytes are
/// written to a file first (the reader works on files). Invariant: frames carry finite
/// pixels and their count is bounded by the messages in the file.
pub fn mcap_episode(data: &[u8]) {
    harness();
    static DIR: OnceLock<Option<tempfile::TempDir>> = OnceLock::new();
    let Some(dir) = DIR.get_or_init(|| tempfile::tempdir().ok()).as_ref() else {
        return;
    };
    let path = dir.path().join("fuzz.mcap");
    if std::fs::write(&path, data).is_err() {
        return;
    }
    let cfg = EpisodeConfig::default();
    let Ok(ep) = McapEpisode::open(&path, &cfg) else {
        return;
    };
    let _ = ep.info();
    let _ = ep.camera_info();
    let _ = ep.labels();
    let _ = ep.robot_description();
    // Each frame is at least one record of a few bytes: more frames than bytes is a loop.
    let mut frames = 0usize;
    for frame in ep.frames() {
        frames += 1;
        assert!(frames <= data.len(), "more frames than bytes in the file");
        match frame {
            Ok(f) => assert_finite(&f.image, "MCAP frame"),
            Err(_) => break,
        }
    }
}

/// The image paths of a gRPC `Image` message as the server decodes them: raw encodings
/// (`rgb8`, `mono16`, `32FC1`, ...) with any width, height and step, and PNG or JPEG
/// files. Layout: encoding selector, big-endian flag, width (2 bytes), height (2 bytes),
/// step (2 bytes), then the pixel bytes. Invariant: finite pixels of the stated size.
pub fn image_message(data: &[u8]) {
    harness();
    const ENCODINGS: [&str; 12] = [
        "rgb8", "bgr8", "rgba8", "bgra8", "mono8", "8UC1", "mono16", "16UC1", "32FC1", "png",
        "jpeg", "yuv422",
    ];
    if data.len() < 8 {
        return;
    }
    let u16_at = |i: usize| u32::from(u16::from_le_bytes([data[i], data[i + 1]]));
    let image = proto::Image {
        stamp_ns: 1,
        encoding: ENCODINGS[usize::from(data[0]) % ENCODINGS.len()].into(),
        width: u16_at(2),
        height: u16_at(4),
        step: u16_at(6),
        big_endian: data[1] & 1 == 1,
        data: data[8..].to_vec(),
        depth: None,
    };
    // The same bytes as a depth image: only the depth encodings decode, at their size.
    let live = crate::api::grpc::convert::live_image(image.clone());
    if let Ok((depth, _)) = crate::session::worker::decode_live_depth(&live, FUZZ_MAX_PIXELS, None)
    {
        assert!(
            matches!(image.encoding.as_str(), "mono16" | "16UC1" | "32FC1"),
            "a depth image decoded from {}",
            image.encoding
        );
        assert_eq!(
            depth.size(),
            (image.width as usize, image.height as usize),
            "decoded depth size differs from the message's"
        );
    }
    if let Ok((img, _)) = decode_streamed(&image) {
        assert_finite(&img, "Image message");
        if !matches!(image.encoding.as_str(), "png" | "jpeg") {
            assert_eq!(
                (img.width(), img.height()),
                (image.width as usize, image.height as usize),
                "decoded size differs from the message's"
            );
        }
    }
}

fn robot_config() -> RobotConfig {
    RobotConfig {
        // Small caps: a fuzz input should not take seconds to build one mesh.
        max_mesh_triangles: 200_000,
        ..RobotConfig::default()
    }
}

fn exercise_robot(robot: &Robot) {
    let q = robot.zero_positions();
    if let Ok(poses) = robot.forward(&q) {
        assert_eq!(poses.len(), robot.links().len(), "one pose per link");
    }
    let _ = robot.out_of_limits(&q);
    let _ = robot.triangle_count();
}

/// URDF text as given to `vamos robot inspect`, a profile or `/robot_description`: parsed
/// (meshes without a root are reported, not read), then forward kinematics at zero.
/// Invariant: one pose per link.
pub fn urdf(data: &[u8]) {
    harness();
    let Ok(xml) = std::str::from_utf8(data) else {
        return;
    };
    if let Ok(robot) = Robot::from_urdf_str(xml, None, &robot_config()) {
        exercise_robot(&robot);
    }
}

/// A robot package archive (zip or tar.gz) as uploaded to `PUT /v1/robots/{name}`:
/// unpacked in memory within its caps, the URDF and its meshes loaded.
pub fn robot_archive(data: &[u8]) {
    harness();
    if let Ok(robot) = Robot::from_archive_bytes(data, "fuzz", &robot_config()) {
        exercise_robot(&robot);
    }
}

/// A mesh file (STL, OBJ or COLLADA, picked by the first byte) as a URDF's visual names
/// it. Invariant: every triangle's indices are in range and every vertex is finite.
pub fn mesh(data: &[u8]) {
    harness();
    let Some((&kind, bytes)) = data.split_first() else {
        return;
    };
    let name = ["m.stl", "m.obj", "m.dae"][usize::from(kind) % 3];
    if let Ok(m) = mesh_from_bytes(bytes, Path::new(name), [1.0, 1.0, 1.0], &robot_config()) {
        let n = m.positions.len();
        assert!(
            m.triangles.iter().flatten().all(|&i| (i as usize) < n),
            "triangle index out of range"
        );
        assert!(
            m.positions
                .iter()
                .all(|p| p.coords.iter().all(|c| c.is_finite())),
            "non-finite vertex"
        );
    }
}

/// A model bundle (`.vamos` zip) as uploaded to `POST /v1/models/{name}`, its
/// `manifest.json` alone, or an ONNX member's header and graph as the native head reads
/// them (picked by the first byte). Every check before ONNX Runtime sees the graph.
pub fn model_bundle(data: &[u8]) {
    harness();
    let Some((&kind, bytes)) = data.split_first() else {
        return;
    };
    match kind % 3 {
        0 => {
            if let Ok(b) = Bundle::from_bytes(bytes) {
                crate::model::onnx_proto::fuzz_header(&b.encoder);
                crate::model::onnx_proto::fuzz_header(&b.head);
            }
        }
        1 => {
            let _ = Manifest::parse(bytes);
        }
        _ => {
            crate::model::onnx_proto::fuzz_header(bytes);
            crate::model::onnx_proto::fuzz_native_head(bytes);
        }
    }
}

/// A gRPC `Monitor.Stream` request sequence: length-delimited `StreamRequest` messages,
/// each decoded by prost and converted as the server converts it (camera intrinsics of an
/// open, image decoding, the joint buffer's checks and interpolation at image stamps).
/// Invariant: interpolated joint positions are finite.
pub fn stream_requests(data: &[u8]) {
    harness();
    use prost::Message;
    use proto::stream_request::Message as In;
    let mut buf = data;
    let mut joints = crate::session::joints::JointBuffer::default();
    for _ in 0..64 {
        let Ok(req) = proto::StreamRequest::decode_length_delimited(&mut buf) else {
            return;
        };
        match req.message {
            Some(In::Open(o)) => {
                if let Some(c) = &o.camera_info {
                    let _ = crate::api::grpc::convert::intrinsics_of(c);
                }
            }
            Some(In::Image(img)) => {
                let stamp = img.stamp_ns;
                if let Ok((g, _)) = decode_streamed(&img) {
                    assert_finite(&g, "streamed image");
                }
                if let Some(j) = joints.at(stamp) {
                    assert_eq!(j.names.len(), j.positions.len(), "one position per name");
                    assert!(
                        j.efforts.is_empty() || j.efforts.len() == j.names.len(),
                        "one effort per name or none"
                    );
                    assert!(
                        j.positions.iter().chain(&j.efforts).all(|p| p.is_finite()),
                        "interpolated joint position or effort not finite"
                    );
                }
                joints.trim_before(stamp);
            }
            Some(In::Joints(j)) => {
                let _ = joints.push(j.stamp_ns, j.names, j.positions, j.efforts);
            }
            Some(In::Phase(_)) | None => {}
        }
    }
}

/// The simulator's arm, its camera and a profile at a tiny processing size (so a fuzz
/// input runs in milliseconds), loaded once; no flow predictor.
fn fuzz_setup() -> Option<&'static crate::setup::Setup> {
    static SETUP: OnceLock<Option<(tempfile::TempDir, crate::setup::Setup)>> = OnceLock::new();
    SETUP
        .get_or_init(|| {
            let fixture = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim");
            let dir = tempfile::tempdir().ok()?;
            let profile = format!(
                "name = \"fuzz\"\nrobot = {:?}\ncamera = {:?}\nflow_preset = \"realtime\"\n\
                 [pipeline]\nstride = 1\n[pipeline.frames]\nwidth = 32\nheight = 24\n\
                 variant = \"masked\"\n",
                fixture.join("robot/vamos_arm.urdf"),
                fixture.join("camera.json"),
            );
            let path = dir.path().join("fuzz.toml");
            std::fs::write(&path, profile).ok()?;
            let setup = crate::setup::Setup::load(&crate::config::Settings::default(), &path);
            Some((dir, setup.ok()?))
        })
        .as_ref()
        .map(|(_, s)| s)
}

/// A whole streamed session through the scorer, as a worker scores it: length-delimited
/// `StreamRequest`s (an open's camera, images of any shape and encoding, joint states,
/// stamps in any order) decoded, buffered and interpolated as the hub does, and every
/// decoded image pushed through a [`crate::pipeline::Scorer`] of the simulator's arm
/// (kinematics, body render, TV-L1, registration, `e_c`, `e_b`). Invariants: no panic;
/// frame indices of the scores increase; a refused frame leaves the scorer usable.
pub fn stream_session(data: &[u8]) {
    harness();
    use crate::pipeline::{FrameInput, JointInput};
    use prost::Message;
    use proto::stream_request::Message as In;
    let Some(setup) = fuzz_setup() else {
        return;
    };
    let Ok(mut scorer) = setup.calibrated_scorer("fuzz", false) else {
        return;
    };
    let mut buf = data;
    let mut joints = crate::session::joints::JointBuffer::default();
    let mut camera = None;
    let mut last_frame = None;
    for _ in 0..16 {
        let Ok(req) = proto::StreamRequest::decode_length_delimited(&mut buf) else {
            return;
        };
        match req.message {
            Some(In::Open(o)) => {
                camera = o
                    .camera_info
                    .as_ref()
                    .and_then(|c| crate::api::grpc::convert::intrinsics_of(c).ok());
            }
            Some(In::Image(img)) => {
                let stamp = img.stamp_ns;
                let Ok((image, _)) = decode_streamed(&img) else {
                    continue;
                };
                let at = joints.at(stamp);
                joints.trim_before(stamp);
                let intrinsics = camera.filter(|k: &crate::robot::Intrinsics| {
                    k.width as usize == image.width() && k.height as usize == image.height()
                });
                let input = FrameInput {
                    stamp_ns: stamp,
                    image: &image,
                    joints: at.as_ref().map(|j| JointInput {
                        names: &j.names,
                        positions: &j.positions,
                        efforts: &j.efforts,
                    }),
                    intrinsics: intrinsics.as_ref(),
                    depth: None,
                };
                if let Ok(Some(score)) = scorer.push(&input) {
                    assert!(
                        last_frame.is_none_or(|f| score.frame > f),
                        "frame index did not increase"
                    );
                    last_frame = Some(score.frame);
                }
            }
            Some(In::Joints(j)) => {
                let _ = joints.push(j.stamp_ns, j.names, j.positions, j.efforts);
            }
            Some(In::Phase(_)) | None => {}
        }
    }
}

/// The JSON bodies of the REST admin routes, parsed into their request types and applied
/// to a store in a temporary folder as the handlers do (the first byte picks the route):
/// a profile spec (`PUT /v1/profiles/{name}`, with a fuzzed name), a thresholds patch, an
/// active-version change and a calibration request.
pub fn rest_body(data: &[u8]) {
    harness();
    static STORE: OnceLock<Option<(tempfile::TempDir, Store)>> = OnceLock::new();
    let Some((&kind, body)) = data.split_first() else {
        return;
    };
    let Some((_, store)) = STORE
        .get_or_init(|| {
            let dir = tempfile::tempdir().ok()?;
            let store = Store::open(dir.path(), StoreLimits::default()).ok()?;
            Some((dir, store))
        })
        .as_ref()
    else {
        return;
    };
    match kind % 4 {
        0 => {
            // `name\0spec`: the name is a path segment of the URL.
            let (name, spec) = match body.iter().position(|&b| b == 0) {
                Some(i) => (&body[..i], &body[i + 1..]),
                None => (&b"fuzz"[..], body),
            };
            let Ok(name) = std::str::from_utf8(name) else {
                return;
            };
            if let Ok(spec) = serde_json::from_slice(spec)
                && let Ok(info) = store.put_profile(name, spec)
            {
                // A stored profile stays inside the store's folder and can be read back.
                assert!(
                    store.profile(&info.name).is_ok(),
                    "stored profile unreadable"
                );
            }
        }
        1 => {
            if let Ok(patch) = serde_json::from_slice::<ThresholdsPatch>(body) {
                let _ = store.patch_thresholds("fuzz", patch);
            }
        }
        2 => {
            let _ = crate::api::rest::parse_active_request(body);
        }
        _ => {
            let _ = crate::api::rest::parse_calibrate_request(body);
        }
    }
}
