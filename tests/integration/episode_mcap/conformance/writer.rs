//! An MCAP writer for the conformance matrix, from the MCAP specification: records
//! written field by field, so that every optional record and padding can be switched on
//! and off, and the matrix of writer features (`variants`).

use std::collections::BTreeMap;

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// The writer features of the conformance matrix, by their short names.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Debug)]
pub(super) enum Feature {
    /// Messages (and their schemas and channels) in one chunk.
    Chunks,
    /// Message index records after the chunk.
    MessageIndex,
    /// A statistics record in the summary.
    Statistics,
    /// The schemas repeated in the summary.
    RepeatedSchemas,
    /// The channels repeated in the summary.
    RepeatedChannels,
    /// Attachment index records in the summary.
    AttachmentIndex,
    /// Metadata index records in the summary.
    MetadataIndex,
    /// A chunk index record in the summary.
    ChunkIndex,
    /// Summary offset records.
    SummaryOffsets,
    /// Extra bytes at the end of every record that has a defined end (readers skip them).
    Padding,
}

const FEATURES: [Feature; 10] = [
    Feature::Chunks,
    Feature::MessageIndex,
    Feature::Statistics,
    Feature::RepeatedSchemas,
    Feature::RepeatedChannels,
    Feature::AttachmentIndex,
    Feature::MetadataIndex,
    Feature::ChunkIndex,
    Feature::SummaryOffsets,
    Feature::Padding,
];

impl Feature {
    pub(super) fn short(self) -> &'static str {
        match self {
            Feature::Chunks => "ch",
            Feature::MessageIndex => "mx",
            Feature::Statistics => "st",
            Feature::RepeatedSchemas => "rsh",
            Feature::RepeatedChannels => "rch",
            Feature::AttachmentIndex => "ax",
            Feature::MetadataIndex => "mdx",
            Feature::ChunkIndex => "chx",
            Feature::SummaryOffsets => "sum",
            Feature::Padding => "pad",
        }
    }
}

#[derive(Clone, Debug)]
pub(super) enum Rec {
    Schema {
        id: u16,
        name: String,
        encoding: String,
        data: Vec<u8>,
    },
    Channel {
        id: u16,
        schema_id: u16,
        topic: String,
        encoding: String,
        metadata: Vec<(String, String)>,
    },
    Message {
        channel: u16,
        sequence: u32,
        log_time: u64,
        publish_time: u64,
        data: Vec<u8>,
    },
    Attachment {
        log_time: u64,
        create_time: u64,
        name: String,
        media_type: String,
        data: Vec<u8>,
    },
    Metadata {
        name: String,
        entries: Vec<(String, String)>,
    },
}

pub(super) struct Input {
    pub(super) name: &'static str,
    pub(super) records: Vec<Rec>,
}

/// The variants of the matrix: every combination of features that makes sense for the
/// input (indexes only of records it has, message indexes and chunk indexes only with
/// chunks, summary offsets only with a summary to point into).
pub(super) fn variants(input: &Input) -> Vec<Vec<Feature>> {
    let has = |f: fn(&Rec) -> bool| input.records.iter().any(f);
    let attachments = has(|r| matches!(r, Rec::Attachment { .. }));
    let metadata = has(|r| matches!(r, Rec::Metadata { .. }));
    let schemas = has(|r| matches!(r, Rec::Schema { .. }));
    let channels = has(|r| matches!(r, Rec::Channel { .. }));
    let chunkable = has(|r| {
        matches!(
            r,
            Rec::Message { .. } | Rec::Channel { .. } | Rec::Schema { .. }
        )
    });
    let mut out = Vec::new();
    for mask in 0u32..1 << FEATURES.len() {
        let set: Vec<Feature> = FEATURES
            .iter()
            .enumerate()
            .filter(|(i, _)| mask & (1 << i) != 0)
            .map(|(_, f)| *f)
            .collect();
        let on = |f: Feature| set.contains(&f);
        let summary_records = [
            Feature::ChunkIndex,
            Feature::RepeatedSchemas,
            Feature::RepeatedChannels,
            Feature::MetadataIndex,
            Feature::AttachmentIndex,
            Feature::Statistics,
        ]
        .into_iter()
        .any(on);
        let sensible = !(on(Feature::AttachmentIndex) && !attachments
            || on(Feature::MetadataIndex) && !metadata
            || on(Feature::RepeatedSchemas) && !schemas
            || on(Feature::RepeatedChannels) && !channels
            || !chunkable
                && (on(Feature::Chunks) || on(Feature::ChunkIndex) || on(Feature::MessageIndex))
            || on(Feature::SummaryOffsets) && !summary_records
            || (on(Feature::ChunkIndex) || on(Feature::MessageIndex)) && !on(Feature::Chunks));
        if sensible {
            out.push(set);
        }
    }
    out
}

/// IEEE CRC-32 (the one MCAP uses).
fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &b in bytes {
        crc ^= u32::from(b);
        for _ in 0..8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xEDB8_8320
            } else {
                crc >> 1
            };
        }
    }
    !crc
}

/// Little-endian field encoding of MCAP records.
#[derive(Default)]
struct Fields(Vec<u8>);

impl Fields {
    fn u8(&mut self, v: u8) -> &mut Self {
        self.0.push(v);
        self
    }
    fn u16(&mut self, v: u16) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn u32(&mut self, v: u32) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn u64(&mut self, v: u64) -> &mut Self {
        self.0.extend_from_slice(&v.to_le_bytes());
        self
    }
    fn str(&mut self, s: &str) -> &mut Self {
        self.u32(s.len() as u32);
        self.0.extend_from_slice(s.as_bytes());
        self
    }
    fn bytes32(&mut self, b: &[u8]) -> &mut Self {
        self.u32(b.len() as u32);
        self.0.extend_from_slice(b);
        self
    }
    fn bytes64(&mut self, b: &[u8]) -> &mut Self {
        self.u64(b.len() as u64);
        self.0.extend_from_slice(b);
        self
    }
    fn raw(&mut self, b: &[u8]) -> &mut Self {
        self.0.extend_from_slice(b);
        self
    }
    /// A map or array: its byte length, then its entries.
    fn sized(&mut self, entries: impl FnOnce(&mut Fields)) -> &mut Self {
        let mut inner = Fields::default();
        entries(&mut inner);
        self.bytes32(&inner.0)
    }
    fn string_map(&mut self, entries: &[(String, String)]) -> &mut Self {
        self.sized(|m| {
            for (k, v) in entries {
                m.str(k).str(v);
            }
        })
    }
}

mod op {
    pub const HEADER: u8 = 0x01;
    pub const FOOTER: u8 = 0x02;
    pub const SCHEMA: u8 = 0x03;
    pub const CHANNEL: u8 = 0x04;
    pub const MESSAGE: u8 = 0x05;
    pub const CHUNK: u8 = 0x06;
    pub const MESSAGE_INDEX: u8 = 0x07;
    pub const CHUNK_INDEX: u8 = 0x08;
    pub const ATTACHMENT: u8 = 0x09;
    pub const ATTACHMENT_INDEX: u8 = 0x0A;
    pub const STATISTICS: u8 = 0x0B;
    pub const METADATA: u8 = 0x0C;
    pub const METADATA_INDEX: u8 = 0x0D;
    pub const SUMMARY_OFFSET: u8 = 0x0E;
    pub const DATA_END: u8 = 0x0F;
}

/// Appends one record (opcode, length, content) to `out`, with extra bytes after the
/// content when padding (never for messages, whose data runs to the record's end, nor
/// for the footer, which sits at a fixed distance from the file's end).
fn record(out: &mut Vec<u8>, opcode: u8, content: &Fields, pad: bool) -> u64 {
    let pad = pad && opcode != op::MESSAGE && opcode != op::FOOTER;
    let extra: &[u8] = if pad { b"\x01\x02\x03" } else { b"" };
    let start = out.len();
    out.push(opcode);
    out.extend_from_slice(&((content.0.len() + extra.len()) as u64).to_le_bytes());
    out.extend_from_slice(&content.0);
    out.extend_from_slice(extra);
    (out.len() - start) as u64
}

fn write_data_record(out: &mut Vec<u8>, r: &Rec, pad: bool) -> u64 {
    let mut f = Fields::default();
    let opcode = match r {
        Rec::Schema {
            id,
            name,
            encoding,
            data,
        } => {
            f.u16(*id).str(name).str(encoding).bytes32(data);
            op::SCHEMA
        }
        Rec::Channel {
            id,
            schema_id,
            topic,
            encoding,
            metadata,
        } => {
            f.u16(*id)
                .u16(*schema_id)
                .str(topic)
                .str(encoding)
                .string_map(metadata);
            op::CHANNEL
        }
        Rec::Message {
            channel,
            sequence,
            log_time,
            publish_time,
            data,
        } => {
            f.u16(*channel)
                .u32(*sequence)
                .u64(*log_time)
                .u64(*publish_time)
                .raw(data);
            op::MESSAGE
        }
        Rec::Attachment {
            log_time,
            create_time,
            name,
            media_type,
            data,
        } => {
            f.u64(*log_time)
                .u64(*create_time)
                .str(name)
                .str(media_type)
                .bytes64(data);
            let crc = crc32(&f.0);
            f.u32(crc);
            op::ATTACHMENT
        }
        Rec::Metadata { name, entries } => {
            f.str(name).string_map(entries);
            op::METADATA
        }
    };
    record(out, opcode, &f, pad)
}

/// Writes `input` with `features` into an MCAP file's bytes.
pub(super) fn write_variant(input: &Input, features: &[Feature]) -> Vec<u8> {
    let on = |f: Feature| features.contains(&f);
    let pad = on(Feature::Padding);
    let mut out = MAGIC.to_vec();
    let mut header = Fields::default();
    header.str("").str("vamos conformance");
    record(&mut out, op::HEADER, &header, pad);

    let mut chunk: Option<Vec<u8>> = on(Feature::Chunks).then(Vec::new);
    // Per channel: (log time, offset in the chunk's records) of its messages.
    let mut chunk_messages: BTreeMap<u16, Vec<(u64, u64)>> = BTreeMap::new();
    let mut metadata_indexes = Vec::new();
    let mut attachment_indexes = Vec::new();
    let mut counts: BTreeMap<u16, u64> = BTreeMap::new();
    let (mut start, mut end) = (u64::MAX, 0u64);
    let (mut schemas, mut channels, mut attachments, mut metadata) = (0u16, 0u32, 0u32, 0u32);
    for r in &input.records {
        match r {
            Rec::Schema { .. } | Rec::Channel { .. } | Rec::Message { .. } => {
                match r {
                    Rec::Schema { .. } => schemas += 1,
                    Rec::Channel { .. } => channels += 1,
                    Rec::Message {
                        channel, log_time, ..
                    } => {
                        *counts.entry(*channel).or_default() += 1;
                        (start, end) = (start.min(*log_time), end.max(*log_time));
                        if let Some(c) = &chunk {
                            chunk_messages
                                .entry(*channel)
                                .or_default()
                                .push((*log_time, c.len() as u64));
                        }
                    }
                    _ => {}
                }
                match &mut chunk {
                    Some(c) => write_data_record(c, r, pad),
                    None => write_data_record(&mut out, r, pad),
                };
            }
            Rec::Attachment {
                log_time,
                create_time,
                name,
                media_type,
                data,
            } => {
                attachments += 1;
                let offset = out.len() as u64;
                let length = write_data_record(&mut out, r, pad);
                let mut f = Fields::default();
                f.u64(offset)
                    .u64(length)
                    .u64(*log_time)
                    .u64(*create_time)
                    .u64(data.len() as u64)
                    .str(name)
                    .str(media_type);
                attachment_indexes.push(f);
            }
            Rec::Metadata { name, .. } => {
                metadata += 1;
                let offset = out.len() as u64;
                let length = write_data_record(&mut out, r, pad);
                let mut f = Fields::default();
                f.u64(offset).u64(length).str(name);
                metadata_indexes.push(f);
            }
        }
    }
    if start == u64::MAX {
        start = 0;
    }
    let mut chunk_index = None;
    if let Some(records) = &chunk {
        let chunk_start = out.len() as u64;
        let (lo, hi) = chunk_messages
            .values()
            .flatten()
            .fold((u64::MAX, 0), |(lo, hi), (t, _)| (lo.min(*t), hi.max(*t)));
        let lo = if lo == u64::MAX { 0 } else { lo };
        let mut f = Fields::default();
        f.u64(lo)
            .u64(hi)
            .u64(records.len() as u64)
            .u32(crc32(records))
            .str("")
            .bytes64(records);
        let chunk_length = record(&mut out, op::CHUNK, &f, pad);
        let mut index_offsets = Vec::new();
        let index_start = out.len() as u64;
        if on(Feature::MessageIndex) {
            for (channel, entries) in &chunk_messages {
                index_offsets.push((*channel, out.len() as u64));
                let mut f = Fields::default();
                f.u16(*channel).sized(|a| {
                    for (t, o) in entries {
                        a.u64(*t).u64(*o);
                    }
                });
                record(&mut out, op::MESSAGE_INDEX, &f, pad);
            }
        }
        let index_length = out.len() as u64 - index_start;
        let mut f = Fields::default();
        f.u64(lo)
            .u64(hi)
            .u64(chunk_start)
            .u64(chunk_length)
            .sized(|m| {
                for (channel, offset) in &index_offsets {
                    m.u16(*channel).u64(*offset);
                }
            })
            .u64(index_length)
            .str("")
            .u64(records.len() as u64)
            .u64(records.len() as u64);
        chunk_index = Some(f);
    }
    let data_crc = crc32(&out);
    let mut f = Fields::default();
    f.u32(data_crc);
    record(&mut out, op::DATA_END, &f, pad);

    // The summary: groups of records of one opcode, each with its offset record.
    let summary_start = out.len() as u64;
    let mut groups: Vec<(u8, u64, u64)> = Vec::new();
    let mut group = |out: &mut Vec<u8>, opcode: u8, records: Vec<Fields>| {
        if records.is_empty() {
            return;
        }
        let start = out.len() as u64;
        for f in &records {
            record(out, opcode, f, pad);
        }
        groups.push((opcode, start, out.len() as u64 - start));
    };
    // The summary's copies of the data records of one kind (their content: `group` adds
    // the opcode, length and padding).
    let repeated = |kind: fn(&Rec) -> bool| -> Vec<Fields> {
        let content = |r: &Rec| {
            let mut buf = Vec::new();
            write_data_record(&mut buf, r, false);
            Fields(buf[9..].to_vec())
        };
        input
            .records
            .iter()
            .filter(|r| kind(r))
            .map(content)
            .collect()
    };
    if on(Feature::RepeatedSchemas) {
        let records = repeated(|r| matches!(r, Rec::Schema { .. }));
        group(&mut out, op::SCHEMA, records);
    }
    if on(Feature::RepeatedChannels) {
        let records = repeated(|r| matches!(r, Rec::Channel { .. }));
        group(&mut out, op::CHANNEL, records);
    }
    if on(Feature::Statistics) {
        let mut f = Fields::default();
        f.u64(counts.values().sum())
            .u16(schemas)
            .u32(channels)
            .u32(attachments)
            .u32(metadata)
            .u32(u32::from(chunk.is_some()))
            .u64(start)
            .u64(end)
            .sized(|m| {
                for (channel, n) in &counts {
                    m.u16(*channel).u64(*n);
                }
            });
        group(&mut out, op::STATISTICS, vec![f]);
    }
    if on(Feature::MetadataIndex) {
        group(&mut out, op::METADATA_INDEX, metadata_indexes);
    }
    if on(Feature::AttachmentIndex) {
        group(&mut out, op::ATTACHMENT_INDEX, attachment_indexes);
    }
    if on(Feature::ChunkIndex) {
        group(&mut out, op::CHUNK_INDEX, chunk_index.into_iter().collect());
    }
    let offsets_start = out.len() as u64;
    if on(Feature::SummaryOffsets) {
        for (opcode, start, length) in &groups {
            let mut f = Fields::default();
            f.u8(*opcode).u64(*start).u64(*length);
            record(&mut out, op::SUMMARY_OFFSET, &f, pad);
        }
    }
    let has_summary = out.len() as u64 > summary_start;
    let has_offsets = out.len() as u64 > offsets_start;
    let footer_start = out.len();
    out.push(op::FOOTER);
    out.extend_from_slice(&20u64.to_le_bytes());
    out.extend_from_slice(&(if has_summary { summary_start } else { 0 }).to_le_bytes());
    out.extend_from_slice(&(if has_offsets { offsets_start } else { 0 }).to_le_bytes());
    let crc = if has_summary {
        crc32(&out[summary_start as usize..])
    } else {
        0
    };
    out.extend_from_slice(&crc.to_le_bytes());
    debug_assert_eq!(out.len() - footer_start, 29);
    out.extend_from_slice(MAGIC);
    out
}
