//! Where a bag's messages come from: its files ([`Part`]s) read through the summary's
//! chunk indexes, or by a linear scan put in log-time order within a window.

use super::*;

/// One MCAP file of an episode.
#[derive(Debug)]
pub(super) struct Part {
    /// The file read: the file itself, or a decompressed copy of a `.mcap.zstd` file.
    pub(super) read: PathBuf,
    /// The file as named (messages name it).
    pub(super) path: PathBuf,
    pub(super) reading: Reading,
    pub(super) damage: Option<(u64, String)>,
    /// The decompressed copy of a zstd-compressed file (removed when dropped).
    pub(super) _copy: Option<tempfile::NamedTempFile>,
}

/// How a [`Part`] is read.
#[derive(Debug)]
pub(super) enum Reading {
    /// Through its summary's indexes (complete: statistics, chunk indexes, channels).
    Indexed(Arc<Summary>),
    /// By linear scans, each starting from what its records' headers say (read once when
    /// the file is opened).
    Linear(Prescan),
}

pub(super) fn io_err(path: &Path, e: impl std::fmt::Display) -> EpisodeError {
    EpisodeError::Mcap {
        path: path.display().to_string(),
        reason: e.to_string(),
    }
}

/// Reads the summary section; `Ok(None)` when the file has none or it cannot be found
/// (a truncated file loses its footer).
pub(super) fn read_summary(file: &mut File, path: &Path) -> Result<Option<Summary>, EpisodeError> {
    let len = file.metadata().map_err(|e| io_err(path, e))?.len();
    let mut reader = SummaryReader::new_with_options(
        mcap::sans_io::summary_reader::SummaryReaderOptions::default().with_file_size(len),
    );
    while let Some(event) = reader.next_event() {
        match event {
            Ok(SummaryReadEvent::ReadRequest(n)) => {
                let n = n.min(8 << 20);
                let got = file.read(reader.insert(n)).map_err(|e| io_err(path, e))?;
                reader.notify_read(got);
            }
            Ok(SummaryReadEvent::SeekRequest(to)) => {
                let pos = file.seek(to).map_err(|e| io_err(path, e))?;
                reader.notify_seeked(pos);
            }
            Err(e) => {
                tracing::debug!(path = %path.display(), error = %e, "no usable MCAP summary");
                return Ok(None);
            }
        }
    }
    Ok(reader.finish())
}

/// A channel as the reader sees it.
#[derive(Debug, Clone)]
pub(super) struct ChannelMeta {
    pub(super) topic: Arc<str>,
    pub(super) schema: Arc<str>,
    pub(super) encoding: Arc<str>,
    pub(super) schema_id: u16,
}

/// One message handed to a consumer.
pub(super) struct RawMsg<'m> {
    pub(super) topic: &'m str,
    pub(super) schema: &'m str,
    pub(super) log_time: u64,
    pub(super) data: &'m [u8],
}

/// Streams messages of some topics in log-time order: indexed (the reader merges
/// chunks), by linear scan (file order, put in log-time order within a window), or the
/// files of a bag folder one after another.
pub(super) enum MessageSource {
    Indexed {
        /// The file as named (for errors).
        path: PathBuf,
        file: File,
        reader: Box<IndexedReader>,
        channels: HashMap<u16, ChannelMeta>,
        buf: Vec<u8>,
        file_len: u64,
        /// Offset of the chunk requested last (where an index-based read breaks).
        last_chunk: u64,
    },
    Linear {
        /// The file as named (for errors).
        path: PathBuf,
        scan: Box<LinearScan>,
        order: Reorder,
    },
    Chain(VecDeque<MessageSource>),
}

/// Messages a linear scan holds back to hand them out in log-time order: a recorder may
/// write messages out of order within a chunk, and a scan (unlike the indexed reader)
/// sees them in file order. Disorder within the window (by count and bytes) is undone;
/// beyond it, messages come in file order (and images whose stamps go back are skipped).
#[derive(Default)]
pub(super) struct Reorder {
    pub(super) held: std::collections::BinaryHeap<std::cmp::Reverse<Held>>,
    pub(super) bytes: usize,
    pub(super) seq: u64,
    pub(super) ended: bool,
    pub(super) error: Option<EpisodeError>,
}

/// Messages held by [`Reorder`] at most, and their bytes.
pub(super) const REORDER_MESSAGES: usize = 1024;
pub(super) const REORDER_BYTES: usize = 32 << 20;

/// A message held for reordering.
pub(super) struct Held {
    pub(super) log_time: u64,
    pub(super) seq: u64,
    pub(super) topic: Arc<str>,
    pub(super) schema: Arc<str>,
    pub(super) data: Vec<u8>,
}

impl PartialEq for Held {
    fn eq(&self, other: &Self) -> bool {
        (self.log_time, self.seq) == (other.log_time, other.seq)
    }
}

impl Eq for Held {}

impl PartialOrd for Held {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Held {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        (self.log_time, self.seq).cmp(&(other.log_time, other.seq))
    }
}

impl Reorder {
    pub(super) fn full(&self) -> bool {
        self.held.len() >= REORDER_MESSAGES || self.bytes >= REORDER_BYTES
    }

    /// The next message in log-time order from `scan`, handed to `f`.
    pub(super) fn next_with<R>(
        &mut self,
        path: &Path,
        scan: &mut LinearScan,
        f: impl FnOnce(RawMsg<'_>) -> R,
    ) -> Option<Result<R, EpisodeError>> {
        while !self.ended && !self.full() {
            let seq = self.seq;
            match scan.next_with(|m| Held {
                log_time: m.log_time,
                seq,
                topic: m.topic.into(),
                schema: m.schema.into(),
                data: m.data.to_vec(),
            }) {
                Some(Ok(h)) => {
                    self.seq += 1;
                    self.bytes += h.data.len();
                    self.held.push(std::cmp::Reverse(h));
                }
                Some(Err((offset, reason))) => {
                    self.ended = true;
                    self.error = Some(EpisodeError::Truncated {
                        path: path.display().to_string(),
                        offset,
                        reason,
                    });
                }
                None => self.ended = true,
            }
        }
        match self.held.pop() {
            Some(std::cmp::Reverse(h)) => {
                self.bytes -= h.data.len();
                Some(Ok(f(RawMsg {
                    topic: &h.topic,
                    schema: &h.schema,
                    log_time: h.log_time,
                    data: &h.data,
                })))
            }
            None => self.error.take().map(Err),
        }
    }
}

/// A linear scan of a file, tolerant of damage at the end.
pub(super) struct LinearScan {
    pub(super) file: File,
    pub(super) reader: LinearReader,
    pub(super) channels: HashMap<u16, ChannelMeta>,
    pub(super) schemas: HashMap<u16, (Arc<str>, Arc<str>)>,
    /// Bytes handed to the reader so far.
    pub(super) fed: u64,
    /// Where the reader must stop (a chunk it cannot read safely, [`Prescan::damage`]) and
    /// why, reported once when the scan gets there.
    stop_at: u64,
    stop_reason: Option<String>,
    pub(super) topics: Option<Vec<String>>,
    /// Whether to keep schema definitions (for [`McapEpisode::schema_of`]).
    pub(super) keep_schema_data: bool,
    pub(super) schema_data: HashMap<u16, (String, String, Vec<u8>)>,
}

impl LinearScan {
    /// A scan of the file at `path` whose records' headers say `found` ([`prescan`]).
    pub(super) fn new(
        path: &Path,
        found: &Prescan,
        record_limit: usize,
        topics: Option<Vec<String>>,
    ) -> Result<Self, EpisodeError> {
        let file = File::open(path).map_err(|e| io_err(path, e))?;
        let reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_validate_chunk_crcs(true)
                .with_record_length_limit(record_limit.min(found.longest_record)),
        );
        let (stop_at, stop_reason) = found
            .damage
            .clone()
            .map_or((u64::MAX, None), |(at, why)| (at, Some(why)));
        Ok(Self {
            file,
            reader,
            channels: HashMap::new(),
            schemas: HashMap::new(),
            fed: 0,
            stop_at,
            stop_reason,
            topics,
            keep_schema_data: false,
            schema_data: HashMap::new(),
        })
    }

    /// The next message of the chosen topics, handed to `f`; `Err((offset, reason))` where
    /// the file breaks.
    pub(super) fn next_with<R>(
        &mut self,
        mut f: impl FnMut(RawMsg<'_>) -> R,
    ) -> Option<Result<R, (u64, String)>> {
        loop {
            let want = match self.reader.next_event()? {
                Err(e) => return Some(Err((self.fed, e.to_string()))),
                Ok(LinearReadEvent::ReadRequest(n)) => n.clamp(1, 4 << 20),
                Ok(LinearReadEvent::Record { data, opcode }) => {
                    if !matches!(opcode, op::SCHEMA | op::CHANNEL | op::MESSAGE) {
                        continue;
                    }
                    let record = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(e) => return Some(Err((self.fed, e.to_string()))),
                    };
                    match record {
                        mcap::records::Record::Schema { header, data } => {
                            if self.keep_schema_data {
                                self.schema_data.insert(
                                    header.id,
                                    (header.name.clone(), header.encoding.clone(), data.to_vec()),
                                );
                            }
                            self.schemas
                                .insert(header.id, (header.name.into(), header.encoding.into()));
                        }
                        mcap::records::Record::Channel(c) => {
                            let schema = self
                                .schemas
                                .get(&c.schema_id)
                                .map(|(n, _)| n.clone())
                                .unwrap_or_else(|| Arc::from(""));
                            self.channels.insert(
                                c.id,
                                ChannelMeta {
                                    topic: c.topic.into(),
                                    schema,
                                    encoding: c.message_encoding.into(),
                                    schema_id: c.schema_id,
                                },
                            );
                        }
                        mcap::records::Record::Message { header, data } => {
                            let Some(ch) = self.channels.get(&header.channel_id) else {
                                continue;
                            };
                            if let Some(t) = &self.topics
                                && !t.iter().any(|t| **t == *ch.topic)
                            {
                                continue;
                            }
                            return Some(Ok(f(RawMsg {
                                topic: &ch.topic,
                                schema: &ch.schema,
                                log_time: header.log_time,
                                data: &data,
                            })));
                        }
                        _ => {}
                    }
                    continue;
                }
            };
            if self.fed >= self.stop_at {
                return self.stop_reason.take().map(|why| Err((self.stop_at, why)));
            }
            let want = want.min(usize::try_from(self.stop_at - self.fed).unwrap_or(usize::MAX));
            match self.file.read(self.reader.insert(want)) {
                Ok(got) => {
                    self.fed += got as u64;
                    self.reader.notify_read(got);
                }
                Err(e) => return Some(Err((self.fed, e.to_string()))),
            }
        }
    }
}

impl MessageSource {
    pub(super) fn next_with<R>(
        &mut self,
        mut f: impl FnMut(RawMsg<'_>) -> R,
    ) -> Option<Result<R, EpisodeError>> {
        self.next_dyn(&mut f)
    }

    pub(super) fn next_dyn<R>(
        &mut self,
        f: &mut dyn FnMut(RawMsg<'_>) -> R,
    ) -> Option<Result<R, EpisodeError>> {
        match self {
            MessageSource::Linear { path, scan, order } => order.next_with(path, scan, f),
            MessageSource::Chain(sources) => loop {
                let first = sources.front_mut()?;
                match first.next_dyn(f) {
                    Some(r) => return Some(r),
                    None => {
                        sources.pop_front();
                    }
                }
            },
            MessageSource::Indexed {
                path,
                file,
                reader,
                channels,
                buf,
                file_len,
                last_chunk,
            } => {
                loop {
                    let (offset, length) = match reader.next_event()? {
                        Err(e) => {
                            return Some(Err(EpisodeError::Truncated {
                                path: path.display().to_string(),
                                offset: *last_chunk,
                                reason: e.to_string(),
                            }));
                        }
                        Ok(IndexedReadEvent::Message { header, data }) => {
                            let Some(ch) = channels.get(&header.channel_id) else {
                                continue;
                            };
                            return Some(Ok(f(RawMsg {
                                topic: &ch.topic,
                                schema: &ch.schema,
                                log_time: header.log_time,
                                data,
                            })));
                        }
                        Ok(IndexedReadEvent::ReadChunkRequest { offset, length }) => {
                            (offset, length)
                        }
                    };
                    *last_chunk = offset;
                    let broken = |reason: String| {
                        Some(Err(EpisodeError::Truncated {
                            path: path.display().to_string(),
                            offset,
                            reason,
                        }))
                    };
                    // The index is data too: a chunk past the end must not size a buffer.
                    if offset.saturating_add(length as u64) > *file_len {
                        return broken(format!(
                            "chunk of {length} bytes at {offset} runs past the end ({file_len})"
                        ));
                    }
                    buf.resize(length, 0);
                    if let Err(e) = file
                        .seek(SeekFrom::Start(offset))
                        .and_then(|_| file.read_exact(buf))
                    {
                        return broken(e.to_string());
                    }
                    if let Err(e) = reader.insert_chunk_record_data(offset, buf) {
                        return broken(e.to_string());
                    }
                }
            }
        }
    }
}

/// The topics of one file, by name.
pub(super) type PartTopics = BTreeMap<String, TopicInfo>;

impl Part {
    /// Opens one file: its summary when complete, else a linear scan for the topics and
    /// the damage. Returns the part, its topics and its (first, last) log times.
    pub(super) fn open(
        path: &Path,
        cfg: &EpisodeConfig,
    ) -> Result<(Self, PartTopics, (u64, u64)), EpisodeError> {
        let mut file = File::open(path).map_err(|e| io_err(path, e))?;
        let mut magic = [0u8; 4];
        let compressed = file.read_exact(&mut magic).is_ok() && magic == ZSTD_MAGIC;
        let copy = if compressed {
            Some(decompress_file(path, cfg.max_decompressed_bytes)?)
        } else {
            None
        };
        let read = copy
            .as_ref()
            .map_or(path.to_path_buf(), |c| c.path().to_path_buf());
        let mut file = File::open(&read).map_err(|e| io_err(path, e))?;
        let summary = read_summary(&mut file, path)?.filter(|s| {
            // Index-based reading needs statistics (counts), chunk indexes and a channel
            // for every channel with messages; anything less is read by a scan.
            s.stats.as_ref().is_some_and(|st| {
                st.message_count == 0
                    || (!s.chunk_indexes.is_empty()
                        && !s.channels.is_empty()
                        && st
                            .channel_message_counts
                            .keys()
                            .all(|id| s.channels.contains_key(id)))
            })
        });
        let mut topics: BTreeMap<String, TopicInfo> = BTreeMap::new();
        let (span, damage, reading);
        if let Some(s) = summary {
            // Invariant: the filter above kept only summaries with statistics.
            let stats = s.stats.clone().unwrap_or_default();
            for (id, ch) in &s.channels {
                let t = topics.entry(ch.topic.clone()).or_insert_with(|| TopicInfo {
                    name: ch.topic.clone(),
                    schema: ch
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    message_encoding: ch.message_encoding.clone(),
                    message_count: 0,
                });
                t.message_count += stats.channel_message_counts.get(id).copied().unwrap_or(0);
            }
            (span, damage, reading) = (
                (stats.message_start_time, stats.message_end_time),
                None,
                Reading::Indexed(Arc::new(s)),
            );
        } else {
            let facts = prescan(&mut file).map_err(|e| io_err(path, e))?;
            let mut scan = LinearScan::new(&read, &facts, record_limit(cfg), None)?;
            let mut counts: HashMap<String, u64> = HashMap::new();
            let (mut lo, mut hi) = (u64::MAX, 0u64);
            let mut broke = None;
            while let Some(r) = scan.next_with(|m| {
                *counts.entry(m.topic.to_string()).or_default() += 1;
                (lo, hi) = (lo.min(m.log_time), hi.max(m.log_time));
            }) {
                if let Err(e) = r {
                    broke = Some(e);
                    break;
                }
            }
            for ch in scan.channels.values() {
                topics
                    .entry(ch.topic.to_string())
                    .or_insert_with(|| TopicInfo {
                        name: ch.topic.to_string(),
                        schema: ch.schema.to_string(),
                        message_encoding: ch.encoding.to_string(),
                        message_count: counts.get(&*ch.topic).copied().unwrap_or(0),
                    });
            }
            if lo == u64::MAX {
                lo = 0;
            }
            // Nothing readable at all: say where it broke rather than "no topics".
            if let (Some((offset, reason)), true) = (&broke, topics.is_empty()) {
                return Err(EpisodeError::Truncated {
                    path: path.display().to_string(),
                    offset: *offset,
                    reason: reason.clone(),
                });
            }
            (span, damage, reading) = ((lo, hi), broke, Reading::Linear(facts));
        }
        let part = Self {
            read,
            path: path.to_path_buf(),
            reading,
            damage,
            _copy: copy,
        };
        Ok((part, topics, span))
    }

    pub(super) fn source(
        &self,
        topics: &[String],
        cfg: &EpisodeConfig,
    ) -> Result<MessageSource, EpisodeError> {
        match &self.reading {
            Reading::Indexed(summary) => {
                let file = File::open(&self.read).map_err(|e| io_err(&self.path, e))?;
                let file_len = file.metadata().map_err(|e| io_err(&self.path, e))?.len();
                let reader = IndexedReader::new_with_options(
                    summary,
                    IndexedReaderOptions::new()
                        .with_order(ReadOrder::LogTime)
                        .include_topics(topics.iter().cloned())
                        .with_record_length_limit(record_limit(cfg)),
                )
                .map_err(|e| io_err(&self.path, e))?;
                let channels = summary
                    .channels
                    .iter()
                    .map(|(id, ch)| {
                        (
                            *id,
                            ChannelMeta {
                                topic: ch.topic.as_str().into(),
                                schema: ch
                                    .schema
                                    .as_ref()
                                    .map_or_else(|| Arc::from(""), |s| s.name.as_str().into()),
                                encoding: ch.message_encoding.as_str().into(),
                                schema_id: ch.schema.as_ref().map_or(0, |s| s.id),
                            },
                        )
                    })
                    .collect();
                Ok(MessageSource::Indexed {
                    path: self.path.clone(),
                    file,
                    reader: Box::new(reader),
                    channels,
                    buf: Vec::new(),
                    file_len,
                    last_chunk: 0,
                })
            }
            Reading::Linear(found) => Ok(MessageSource::Linear {
                path: self.path.clone(),
                scan: Box::new(LinearScan::new(
                    &self.read,
                    found,
                    record_limit(cfg),
                    Some(topics.to_vec()),
                )?),
                order: Reorder::default(),
            }),
        }
    }
}

impl Part {
    /// Whether the file is read through its summary's indexes.
    pub(super) fn indexed(&self) -> bool {
        matches!(self.reading, Reading::Indexed(_))
    }

    pub(super) fn schema_of(
        &self,
        topic: &str,
        cfg: &EpisodeConfig,
    ) -> Result<Option<(String, String, Vec<u8>)>, EpisodeError> {
        let found = match &self.reading {
            Reading::Indexed(summary) => {
                return Ok(summary
                    .channels
                    .values()
                    .find(|c| c.topic == topic)
                    .and_then(|c| c.schema.as_ref())
                    .map(|s| (s.name.clone(), s.encoding.clone(), s.data.to_vec())));
            }
            Reading::Linear(found) => found,
        };
        let mut scan = LinearScan::new(
            &self.read,
            found,
            record_limit(cfg),
            Some(vec![topic.into()]),
        )?;
        scan.keep_schema_data = true;
        while let Some(r) = scan.next_with(|_| ()) {
            if r.is_err() {
                break;
            }
            if scan.channels.values().any(|c| &*c.topic == topic) {
                break;
            }
        }
        Ok(scan
            .channels
            .iter()
            .find(|(_, c)| &*c.topic == topic)
            .and_then(|(_, c)| {
                scan.schema_data
                    .get(&c.schema_id)
                    .map(|(n, e, d)| (n.clone(), e.clone(), d.clone()))
            }))
    }
}
