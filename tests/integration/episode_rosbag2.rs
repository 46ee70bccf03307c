//! Bags as robots write them, beyond the tidy single MCAP file: what rosbag2 writes
//! (per-message and per-file zstd compression, bag folders of split files) and files
//! whose optional summary records are missing or incomplete. Each is made here from the
//! simulator's episode with the `mcap` crate and must read exactly as the original does.

use mcap::{Compression, Message, MessageStream, WriteOptions};
use std::borrow::Cow;
use std::path::{Path, PathBuf};
use vamos::episode::{EpisodeConfig, EpisodeFrame, McapEpisode};

fn original() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/sim/test/test_0000.mcap")
}

fn messages() -> Vec<Message<'static>> {
    let bytes = std::fs::read(original()).unwrap();
    MessageStream::new(&bytes)
        .unwrap()
        .map(|m| {
            let m = m.unwrap();
            Message {
                data: Cow::Owned(m.data.into_owned()),
                ..m
            }
        })
        .collect()
}

fn write(path: &Path, options: WriteOptions, messages: &[Message<'_>]) {
    let file = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    let mut w = options.create(file).unwrap();
    for m in messages {
        w.write(m).unwrap();
    }
    w.finish().unwrap();
}

/// Every frame (stamp, image, joints) and the count of errors.
fn frames(path: &Path) -> (Vec<EpisodeFrame>, usize, usize) {
    let ep = McapEpisode::open(path, &EpisodeConfig::default()).unwrap();
    let (mut ok, mut errors) = (Vec::new(), 0);
    for f in ep.frames() {
        match f {
            Ok(f) => ok.push(f),
            Err(e) => {
                eprintln!("{}: {e}", path.display());
                errors += 1;
            }
        }
    }
    (ok, errors, ep.info().skipped_backwards)
}

fn assert_same(what: &str, got: &(Vec<EpisodeFrame>, usize, usize), want: &[EpisodeFrame]) {
    assert_eq!((got.1, got.2), (0, 0), "{what}: errors, skipped");
    assert_eq!(got.0.len(), want.len(), "{what}: frames");
    for (g, w) in got.0.iter().zip(want) {
        assert_eq!(g.stamp_ns, w.stamp_ns, "{what}");
        assert_eq!(g.image.data(), w.image.data(), "{what}: frame {}", w.index);
        assert_eq!(
            g.joints.as_ref().map(|j| &j.positions),
            w.joints.as_ref().map(|j| &j.positions),
            "{what}: frame {}",
            w.index
        );
    }
}

#[test]
fn rosbag2_compression_folders_and_incomplete_summaries_read_as_the_original() {
    let dir = tempfile::tempdir().unwrap();
    let want = frames(&original());
    assert!(want.0.len() >= 20 && want.1 == 0, "{} frames", want.0.len());
    let all = messages();

    // 1. Per-message zstd (rosbag2 `--compression-mode message`): each payload a zstd
    //    frame ("unsupported CDR encapsulation 0x28b5" before).
    let compressed: Vec<Message<'_>> = all
        .iter()
        .map(|m| Message {
            data: Cow::Owned(zstd::bulk::compress(&m.data, 3).unwrap()),
            ..m.clone()
        })
        .collect();
    let path = dir.path().join("message_zstd.mcap");
    write(&path, WriteOptions::new().compression(None), &compressed);
    assert_same("message zstd", &frames(&path), &want.0);

    // 2. File compression (`--compression-mode file`): `<name>.mcap.zstd` ("Bad magic
    //    number" before). The episode keeps its name.
    let path = dir.path().join("file_zstd.mcap.zstd");
    let raw = std::fs::read(original()).unwrap();
    std::fs::write(&path, zstd::bulk::compress(&raw, 3).unwrap()).unwrap();
    assert_same("file zstd", &frames(&path), &want.0);
    let ep = McapEpisode::open(&path, &EpisodeConfig::default()).unwrap();
    assert_eq!(ep.name(), "file_zstd");

    // 3. A bag folder: metadata.yaml and three split files ("Is a directory" before).
    let bag = dir.path().join("rosbag2_2026_12_03");
    std::fs::create_dir(&bag).unwrap();
    let third = all.len() / 3;
    for (i, part) in [&all[..third], &all[third..2 * third], &all[2 * third..]]
        .iter()
        .enumerate()
    {
        let name = bag.join(format!("rosbag2_2026_12_03_{i}.mcap"));
        write(&name, WriteOptions::new(), part);
    }
    std::fs::write(
        bag.join("metadata.yaml"),
        "rosbag2_bagfile_information:\n  version: 5\n  storage_identifier: mcap\n  \
         relative_file_paths:\n    - rosbag2_2026_12_03_0.mcap\n    - \
         rosbag2_2026_12_03_1.mcap\n    - rosbag2_2026_12_03_2.mcap\n",
    )
    .unwrap();
    assert_same("bag folder", &frames(&bag), &want.0);
    let info = McapEpisode::open(&bag, &EpisodeConfig::default())
        .unwrap()
        .info();
    assert_eq!(info.name, "rosbag2_2026_12_03");
    assert_eq!(info.image_messages, want.0.len() as u64);

    // 4. A summary with statistics and chunk indexes but no channel records (refused
    //    with "no ... Image topic" before): read by a scan.
    let path = dir.path().join("no_summary_channels.mcap");
    write(
        &path,
        WriteOptions::new()
            .repeat_channels(false)
            .repeat_schemas(false),
        &all,
    );
    assert_same("summary without channels", &frames(&path), &want.0);

    // 5. Messages out of log-time order inside chunks: the same content reads the same
    //    with a complete summary (indexed reader) and with none (scan); the scan used to
    //    skip the images whose stamps went back.
    // (Reversed in runs of 16 messages: two or three images each, with their joints.)
    let mut shuffled = all.clone();
    for run in shuffled.chunks_mut(16) {
        run.reverse();
    }
    let indexed = dir.path().join("shuffled_indexed.mcap");
    write(
        &indexed,
        WriteOptions::new().compression(Some(Compression::Zstd)),
        &shuffled,
    );
    let scanned = dir.path().join("shuffled_scanned.mcap");
    write(
        &scanned,
        WriteOptions::new()
            .compression(Some(Compression::Zstd))
            .emit_summary_records(false)
            .emit_chunk_indexes(false)
            .emit_statistics(false),
        &shuffled,
    );
    assert!(
        McapEpisode::open(&indexed, &EpisodeConfig::default())
            .unwrap()
            .info()
            .indexed
    );
    assert!(
        !McapEpisode::open(&scanned, &EpisodeConfig::default())
            .unwrap()
            .info()
            .indexed
    );
    assert_same("out of order, indexed", &frames(&indexed), &want.0);
    assert_same("out of order, scanned", &frames(&scanned), &want.0);
}

#[test]
fn compressed_payload_bombs_are_refused_per_message() {
    let dir = tempfile::tempdir().unwrap();
    let all = messages();
    // Every image payload replaced by 256 MiB of zeros in a few KB of zstd: over
    // max_image_bytes (64 MiB), each image is refused on its own, the stream goes on.
    let bomb = zstd::bulk::compress(&vec![0u8; 256 << 20], 3).unwrap();
    assert!(bomb.len() < 64 << 10, "{}", bomb.len());
    let images = all
        .iter()
        .filter(|m| m.channel.topic.contains("image"))
        .count();
    let bombed: Vec<Message<'_>> = all
        .iter()
        .map(|m| {
            if m.channel.topic.contains("image") {
                Message {
                    data: Cow::Owned(bomb.clone()),
                    ..m.clone()
                }
            } else {
                m.clone()
            }
        })
        .collect();
    let path = dir.path().join("bombs.mcap");
    write(&path, WriteOptions::new(), &bombed);
    let (ok, errors, _) = frames(&path);
    assert!(ok.is_empty());
    assert_eq!(errors, images);
}

/// The MCAP conformance idea, generated here: the same messages written with every
/// combination of the writer's optional parts (chunking, chunk compression, summary
/// records, statistics, chunk and message indexes, summary offsets, repeated channels and
/// schemas) must read identically. The MCAP project's own conformance files come from a
/// generator in its repository that no package registry ships; these variants are made
/// with the `mcap` crate's writer instead.
#[test]
fn every_combination_of_optional_mcap_records_reads_the_same() {
    let dir = tempfile::tempdir().unwrap();
    let want = frames(&original());
    let all = messages();
    let mut variants = 0;
    for chunked in [true, false] {
        let compressions: &[Option<Compression>] = if chunked {
            &[None, Some(Compression::Zstd), Some(Compression::Lz4)]
        } else {
            &[None]
        };
        for &compression in compressions {
            // Each optional part off on its own, all of them off, none off.
            for off in 0..=7usize {
                let on = |i: usize| off != i && off != 7;
                let options = WriteOptions::new()
                    .use_chunks(chunked)
                    .compression(compression)
                    .chunk_size(Some(64 << 10))
                    .emit_summary_records(on(0))
                    .emit_statistics(on(1))
                    .emit_chunk_indexes(on(2))
                    .emit_message_indexes(on(3))
                    .emit_summary_offsets(on(4))
                    .repeat_channels(on(5))
                    .repeat_schemas(on(6));
                let name = format!("variant_{chunked}_{compression:?}_{off}.mcap");
                let path = dir.path().join(&name);
                write(&path, options, &all);
                assert_same(&name, &frames(&path), &want.0);
                variants += 1;
            }
        }
    }
    assert_eq!(variants, 32);
}
