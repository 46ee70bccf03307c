//! The MCAP conformance matrix, generated here: the MCAP project tests readers on six
//! small inputs (no data, one schemaless message, one message, one attachment, one
//! metadata record, ten messages out of log-time order) written in every sensible
//! combination of ten writer features (chunks, message indexes, statistics, repeated
//! schemas and channels in the summary, attachment, metadata and chunk indexes, summary
//! offsets, extra bytes at the end of records). Its files are produced by a TypeScript
//! generator that no package registry ships, so this module writes the same matrix with
//! its own record writer (from the MCAP specification), with payloads vamos can decode:
//! the messages are `sensor_msgs/msg/Image`s whose pixels carry their sequence number.
//! A seventh input is a short episode (images, joint states written out of order, an
//! attachment and metadata between them).
//!
//! Every variant must read as its plainest form does: the same frames, stamps, pixels and
//! joints, and the messages in log-time order (ties in file order), whatever optional
//! records the file holds. Inputs without an image topic give a clear error.

mod writer;

use vamos::episode::ros::{Header, ImageMsg, JointStateMsg, schema};

use super::*;
use writer::{Feature, Input, Rec, variants, write_variant};

const IMAGE_TOPIC: &str = "/camera/image_raw";
const JOINT_TOPIC: &str = "/joint_states";

/// A 4x3 `mono8` image stamped `stamp_ns` whose pixels all hold `value`.
fn image(stamp_ns: u64, value: u8) -> Vec<u8> {
    let pixels = [value; 12];
    ImageMsg {
        header: Header::from_stamp_ns(stamp_ns as i64, "camera"),
        height: 3,
        width: 4,
        encoding: "mono8".into(),
        is_bigendian: false,
        step: 4,
        data: &pixels,
    }
    .encode()
}

fn joints(stamp_ns: u64) -> Vec<u8> {
    let t = stamp_ns as f64 * 1e-9;
    JointStateMsg {
        header: Header::from_stamp_ns(stamp_ns as i64, ""),
        name: vec!["pan".into(), "tilt".into()],
        position: vec![t, -0.5 * t],
        velocity: vec![1.0, -0.5],
        effort: vec![],
    }
    .encode()
}

fn image_schema(id: u16) -> Rec {
    Rec::Schema {
        id,
        name: schema::IMAGE.into(),
        encoding: "ros2msg".into(),
        data: vamos::episode::ros::definition(schema::IMAGE)
            .unwrap()
            .into_bytes(),
    }
}

fn channel(id: u16, schema_id: u16, topic: &str) -> Rec {
    Rec::Channel {
        id,
        schema_id,
        topic: topic.into(),
        encoding: "cdr".into(),
        metadata: vec![("foo".into(), "bar".into())],
    }
}

fn image_message(sequence: u32, log_time: u64, publish_time: u64) -> Rec {
    Rec::Message {
        channel: 1,
        sequence,
        log_time,
        publish_time,
        data: image(log_time, sequence as u8),
    }
}

fn attachment() -> Rec {
    Rec::Attachment {
        log_time: 2,
        create_time: 1,
        name: "myFile".into(),
        media_type: "application/octet-stream".into(),
        data: vec![1, 2, 3],
    }
}

fn metadata() -> Rec {
    Rec::Metadata {
        name: "myMetadata".into(),
        entries: vec![("foo".into(), "bar".into())],
    }
}

/// The six inputs of the MCAP conformance matrix (same records, log times and sequence
/// numbers; image payloads), and a short episode.
fn inputs() -> Vec<Input> {
    const MS: u64 = 1_000_000;
    let ten = [0u64, 2, 1, 3, 3, 5, 4, 7, 8, 9];
    let mut episode = vec![
        image_schema(1),
        Rec::Schema {
            id: 2,
            name: schema::JOINT_STATE.into(),
            encoding: "ros2msg".into(),
            data: vamos::episode::ros::definition(schema::JOINT_STATE)
                .unwrap()
                .into_bytes(),
        },
        channel(1, 1, IMAGE_TOPIC),
        channel(2, 2, JOINT_TOPIC),
        metadata(),
    ];
    // Joint states at 50 Hz from 0 to 500 ms, images at 10 Hz from 20 ms; each image's
    // message swapped with the joint state before it, and an attachment in the middle.
    let mut sequence = 0u32;
    for k in 0..=25u64 {
        let t = k * 20 * MS;
        let joint = Rec::Message {
            channel: 2,
            sequence: k as u32,
            log_time: t,
            publish_time: t,
            data: joints(t),
        };
        if k % 5 == 1 && k < 25 {
            let it = t + 10 * MS;
            episode.push(image_message(sequence, it, it));
            sequence += 1;
        }
        episode.push(joint);
        if k == 12 {
            episode.push(attachment());
        }
    }
    vec![
        Input {
            name: "NoData",
            records: vec![],
        },
        Input {
            name: "OneSchemalessMessage",
            records: vec![channel(1, 0, IMAGE_TOPIC), image_message(10, 2, 1)],
        },
        Input {
            name: "OneMessage",
            records: vec![
                image_schema(1),
                channel(1, 1, IMAGE_TOPIC),
                image_message(10, 2, 1),
            ],
        },
        Input {
            name: "OneAttachment",
            records: vec![attachment()],
        },
        Input {
            name: "OneMetadata",
            records: vec![metadata()],
        },
        Input {
            name: "TenMessages",
            records: [image_schema(1), channel(1, 1, IMAGE_TOPIC)]
                .into_iter()
                .chain(
                    ten.iter()
                        .enumerate()
                        .map(|(s, &t)| image_message(s as u32, t, t)),
                )
                .collect(),
        },
        Input {
            name: "Episode",
            records: episode,
        },
    ]
}

/// What vamos reads from a file: the image messages as `for_each_message` hands them
/// out, and the frames (stamp, first pixel, joint positions) or the error of opening.
#[derive(Debug, PartialEq)]
enum Read {
    Refused(String),
    Read {
        messages: Vec<(u64, Vec<u8>)>,
        frames: Vec<(i64, f32, Option<Vec<f64>>)>,
        errors: Vec<String>,
        skipped: usize,
    },
}

fn read(path: &Path) -> Read {
    let ep = match McapEpisode::open(path, &EpisodeConfig::default()) {
        Ok(ep) => ep,
        Err(e) => return Read::Refused(e.to_string().replace(&path.display().to_string(), "FILE")),
    };
    let mut messages = Vec::new();
    ep.for_each_message(&[IMAGE_TOPIC.to_string()], |_, _, t, data| {
        messages.push((t, data.to_vec()))
    })
    .unwrap();
    let (frames, errors) = read_all(&ep);
    Read::Read {
        messages,
        frames: frames
            .iter()
            .map(|f| {
                (
                    f.stamp_ns,
                    f.image.data()[0],
                    f.joints.as_ref().map(|j| j.positions.clone()),
                )
            })
            .collect(),
        errors: errors.iter().map(|e| e.to_string()).collect(),
        skipped: ep.info().skipped_backwards,
    }
}

/// The image messages of `input` in log-time order, ties in file order.
fn in_log_time_order(input: &Input) -> Vec<(u64, Vec<u8>)> {
    let mut messages: Vec<(u64, Vec<u8>)> = input
        .records
        .iter()
        .filter_map(|r| match r {
            Rec::Message {
                channel: 1,
                log_time,
                data,
                ..
            } => Some((*log_time, data.clone())),
            _ => None,
        })
        .collect();
    messages.sort_by_key(|(t, _)| *t);
    messages
}

#[test]
fn every_variant_of_the_mcap_conformance_matrix_reads_as_its_plainest_form() {
    let dir = tempfile::tempdir().unwrap();
    let mut files = 0;
    let mut conformance_files = 0;
    for input in inputs() {
        let variants = variants(&input);
        assert_eq!(variants[0], Vec::<Feature>::new());
        let mut plain = None;
        for features in &variants {
            let name = std::iter::once(input.name)
                .chain(features.iter().map(|f| f.short()))
                .collect::<Vec<_>>()
                .join("-");
            let path = dir.path().join(format!("{name}.mcap"));
            std::fs::write(&path, write_variant(&input, features)).unwrap();
            let got = read(&path);
            // A summary with statistics, the chunk index and every channel and schema is
            // read through the index (so its offsets and CRC were accepted); anything less
            // by a scan (a channel whose schema the summary lacks makes the MCAP crate
            // refuse the summary).
            if let Ok(ep) = McapEpisode::open(&path, &EpisodeConfig::default()) {
                let complete = [
                    Feature::Statistics,
                    Feature::ChunkIndex,
                    Feature::RepeatedChannels,
                    Feature::RepeatedSchemas,
                ]
                .iter()
                .all(|f| features.contains(f));
                assert_eq!(ep.info().indexed, complete, "{name}");
            }
            files += 1;
            conformance_files += usize::from(input.name != "Episode");
            match &plain {
                None => plain = Some(got),
                Some(want) => assert_eq!(&got, want, "{name} reads unlike {}", input.name),
            }
        }
        // What the plainest form reads as.
        let plain = plain.unwrap();
        let messages = in_log_time_order(&input);
        match (input.name, &plain) {
            // No image topic: a clear refusal.
            ("NoData" | "OneAttachment" | "OneMetadata", Read::Refused(e)) => {
                assert!(e.contains("Image"), "{}: {e}", input.name);
            }
            // A channel without a schema is no image topic either.
            ("OneSchemalessMessage", Read::Refused(e)) => {
                assert!(e.contains("Image"), "{}: {e}", input.name);
            }
            (
                "OneMessage" | "TenMessages" | "Episode",
                Read::Read {
                    messages: got,
                    frames,
                    errors,
                    skipped,
                },
            ) => {
                assert!(errors.is_empty(), "{}: {errors:?}", input.name);
                assert_eq!(got, &messages, "{}", input.name);
                let stamps: Vec<i64> = frames.iter().map(|f| f.0).collect();
                let mut sorted = stamps.clone();
                sorted.sort_unstable();
                assert_eq!(stamps, sorted, "{}", input.name);
                // Each frame's pixels carry its message's sequence number: ties in log
                // time keep their file order.
                let values: Vec<f32> = frames.iter().map(|f| f.1).collect();
                match input.name {
                    "OneMessage" => {
                        assert_eq!((stamps, values), (vec![2], vec![10.0]));
                        assert_eq!(*skipped, 0);
                    }
                    "TenMessages" => {
                        // The second image stamped 3 ns cannot follow the first (no time
                        // passes between them): skipped and counted, in every variant.
                        assert_eq!(stamps, [0, 1, 2, 3, 4, 5, 7, 8, 9]);
                        assert_eq!(*skipped, 1);
                        let want = [0.0, 2.0, 1.0, 3.0, 6.0, 5.0, 7.0, 8.0, 9.0];
                        assert_eq!(values, want);
                    }
                    _ => {
                        assert_eq!((frames.len(), *skipped), (5, 0));
                        for (i, (stamp, _, joints)) in frames.iter().enumerate() {
                            assert_eq!(*stamp, (i as i64 * 100 + 30) * 1_000_000);
                            let t = *stamp as f64 * 1e-9;
                            let j = joints.as_ref().expect("joints at every frame");
                            assert!((j[0] - t).abs() < 1e-9 && (j[1] + 0.5 * t).abs() < 1e-9);
                        }
                    }
                }
            }
            (name, got) => panic!("{name}: unexpected {got:?}"),
        }
    }
    // The MCAP project's matrix has 416 files of its six inputs.
    assert_eq!(conformance_files, 416);
    assert_eq!(files - conformance_files, 634);
}
