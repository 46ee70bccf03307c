//! What a linear scan needs to know before the MCAP reader sees a file, read from its
//! records' headers: the longest record the file can hold (the scan's record limit) and the
//! first chunk the reader must not be handed.

use super::*;
use std::io::BufReader;

/// Bytes of a record's opcode and length.
const RECORD_HEAD: u64 = 9;
/// Bytes of a chunk's start time, end time and uncompressed size.
const CHUNK_HEAD: u64 = 24;
/// Bytes of a chunk's CRC and compression string length, after [`CHUNK_HEAD`].
const CHUNK_CRC_COMPRESSION: u64 = 8;
/// Bytes of an uncompressed chunk's records length, after its (empty) compression string.
const CHUNK_RECORDS_LEN: u64 = 8;

/// The result of [`prescan`].
#[derive(Debug)]
pub(super) struct Prescan {
    /// The longest record the file can hold: no record in the data section is longer than
    /// the file, and none inside a chunk longer than the largest uncompressed size a chunk
    /// declares. A scan's record limit is lowered to it, because the MCAP reader reserves
    /// (and zeroes) the length a record inside a compressed chunk declares before it
    /// decompresses it: a corrupt length in a 10 KB file otherwise costs the whole limit
    /// (256 MiB or more) per scan.
    pub(super) longest_record: usize,
    /// The first uncompressed chunk with a record that runs past the chunk's end: its
    /// offset and why. The MCAP reader (0.26) subtracts such a record's length from what is
    /// left of the chunk without a check (a panic with overflow checks, records read from
    /// beyond the chunk without them), so the scan stops before it and reports the damage.
    pub(super) damage: Option<(u64, String)>,
}

/// Reads the headers of `file`'s records (and of the records inside uncompressed chunks,
/// also of a chunk cut off by the file's end); leaves `file` at its start. A chunk too short
/// for its own header is left for the scan to report.
pub(super) fn prescan(file: &mut File) -> std::io::Result<Prescan> {
    let len = file.metadata()?.len();
    let mut longest = len;
    let mut damage = None;
    let mut reader = BufReader::new(&mut *file);
    reader.seek(SeekFrom::Start(8))?;
    let mut pos = 8u64;
    let mut head = [0u8; (RECORD_HEAD + CHUNK_HEAD + CHUNK_CRC_COMPRESSION) as usize];
    while pos + RECORD_HEAD <= len {
        let (record_head, chunk_head) = head.split_at_mut(RECORD_HEAD as usize);
        reader.read_exact(record_head)?;
        let record = u64_at(record_head, 1);
        // Where the record ends as declared (past the file's end when it is cut off).
        let end = (pos + RECORD_HEAD).saturating_add(record);
        let mut read = RECORD_HEAD;
        let fits = |read: u64, more: u64| read + more <= end - pos && pos + read + more <= len;
        if record_head[0] == op::CHUNK && fits(read, CHUNK_HEAD + CHUNK_CRC_COMPRESSION) {
            reader.read_exact(chunk_head)?;
            read += CHUNK_HEAD + CHUNK_CRC_COMPRESSION;
            longest = longest.max(u64_at(chunk_head, 16));
            let compression_len = u32::from_le_bytes([
                chunk_head[28],
                chunk_head[29],
                chunk_head[30],
                chunk_head[31],
            ]);
            if compression_len == 0 && fits(read, CHUNK_RECORDS_LEN) {
                let mut records_len = [0u8; CHUNK_RECORDS_LEN as usize];
                reader.read_exact(&mut records_len)?;
                read += CHUNK_RECORDS_LEN;
                // At most what is left of the chunk record (the reader refuses more).
                let records = u64::from_le_bytes(records_len).min(end - pos - read);
                let (walked, overrun) = inner_records(&mut reader, records, len - pos - read)?;
                read += walked;
                if let Some(reason) = overrun {
                    damage = Some((pos, format!("chunk at byte {pos}: {reason}")));
                    break;
                }
            }
        }
        if end > len {
            break;
        }
        // `read` <= RECORD_HEAD + record: each part is read only when it fits.
        reader.seek_relative(i64::try_from(end - pos - read).unwrap_or(i64::MAX))?;
        pos = end;
    }
    drop(reader);
    file.seek(SeekFrom::Start(0))?;
    Ok(Prescan {
        longest_record: usize::try_from(longest).unwrap_or(usize::MAX),
        damage,
    })
}

/// Walks the `records` bytes of an uncompressed chunk, of which `available` are in the
/// file (the reader just before them): the bytes walked past, and the first record that
/// runs past the records' end, described. A record cut off by the file's end ends the walk
/// without damage (the scan reports the truncation).
fn inner_records(
    reader: &mut BufReader<&mut File>,
    records: u64,
    available: u64,
) -> std::io::Result<(u64, Option<String>)> {
    let mut walked = 0u64;
    let mut record_head = [0u8; RECORD_HEAD as usize];
    while walked < records {
        let left = records - walked;
        if left < RECORD_HEAD {
            let reason = format!("{left} byte(s) at the end of its records, too few for a record");
            return Ok((walked, Some(reason)));
        }
        if walked + RECORD_HEAD > available {
            break;
        }
        reader.read_exact(&mut record_head)?;
        walked += RECORD_HEAD;
        let inner = u64_at(&record_head, 1);
        if inner > left - RECORD_HEAD {
            let reason = format!(
                "a record (opcode {:#04x}) declares {inner} bytes, {} are left in the chunk",
                record_head[0],
                left - RECORD_HEAD
            );
            return Ok((walked, Some(reason)));
        }
        if walked + inner > available {
            break;
        }
        reader.seek_relative(i64::try_from(inner).unwrap_or(i64::MAX))?;
        walked += inner;
    }
    Ok((walked, None))
}

/// The little-endian u64 at `at` in `bytes` (0 when it does not fit).
fn u64_at(bytes: &[u8], at: usize) -> u64 {
    bytes
        .get(at..at + 8)
        .and_then(|b| b.try_into().ok())
        .map_or(0, u64::from_le_bytes)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn record(out: &mut Vec<u8>, opcode: u8, content: &[u8]) {
        out.push(opcode);
        out.extend_from_slice(&(content.len() as u64).to_le_bytes());
        out.extend_from_slice(content);
    }

    /// A chunk record: `uncompressed` declared, `compression`, then `records`.
    fn chunk(uncompressed: u64, compression: &str, records: &[u8]) -> Vec<u8> {
        let mut c = Vec::new();
        for v in [0u64, 0, uncompressed] {
            c.extend_from_slice(&v.to_le_bytes());
        }
        c.extend_from_slice(&0u32.to_le_bytes()); // no CRC
        c.extend_from_slice(&(compression.len() as u32).to_le_bytes());
        c.extend_from_slice(compression.as_bytes());
        c.extend_from_slice(&(records.len() as u64).to_le_bytes());
        c.extend_from_slice(records);
        c
    }

    fn prescan_of(bytes: &[u8]) -> std::io::Result<(Prescan, u64)> {
        let mut file = tempfile::tempfile()?;
        file.write_all(bytes)?;
        let found = prescan(&mut file)?;
        Ok((found, file.stream_position()?))
    }

    #[test]
    fn a_chunk_declares_the_longest_record_and_the_file_is_left_at_its_start() {
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        record(&mut bytes, op::HEADER, &[0; 8]);
        record(&mut bytes, op::CHUNK, &chunk(5000, "zstd", &[0; 16]));
        let (found, at) = prescan_of(&bytes).unwrap();
        assert_eq!(found.longest_record, 5000);
        assert!(found.damage.is_none(), "{:?}", found.damage);
        assert_eq!(at, 0);
    }

    /// Found by `mcap_episode` (`fuzz/regressions/mcap_episode/chunk-shorter-than-its-header`):
    /// a chunk record of 4 bytes with more records behind it. Its "header" was read from the
    /// next record and the distance to that record underflowed: a panic with overflow
    /// checks, a seek far past the end (and the whole file refused) without.
    #[test]
    fn a_chunk_shorter_than_its_header_is_skipped_as_a_record() {
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        record(&mut bytes, op::CHUNK, &[0; 4]);
        record(&mut bytes, op::HEADER, &[0xff; 40]);
        let (found, at) = prescan_of(&bytes).unwrap();
        // The next record's bytes were not taken for a chunk's uncompressed size.
        assert_eq!(found.longest_record, bytes.len());
        assert!(found.damage.is_none(), "{:?}", found.damage);
        assert_eq!(at, 0);
    }

    /// Found by `mcap_episode` (`fuzz/regressions/mcap_episode/record-past-its-chunk`): a
    /// record inside an uncompressed chunk longer than what is left of the chunk.
    #[test]
    fn an_uncompressed_chunk_whose_record_runs_past_its_end_is_damage() {
        let mut records = Vec::new();
        record(&mut records, op::SCHEMA, &[0; 6]);
        let good = chunk(records.len() as u64, "", &records);
        let mut bad_records = records.clone();
        bad_records.extend_from_slice(&[op::MESSAGE, 200, 0, 0, 0, 0, 0, 0, 0, 1, 2, 3]);
        let bad = chunk(bad_records.len() as u64, "", &bad_records);
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        record(&mut bytes, op::CHUNK, &good);
        let bad_at = bytes.len() as u64;
        record(&mut bytes, op::CHUNK, &bad);
        record(&mut bytes, op::DATA_END, &[0; 4]);
        let (found, at) = prescan_of(&bytes).unwrap();
        let Some((offset, reason)) = found.damage else {
            panic!("the overrunning record was not found");
        };
        assert_eq!(offset, bad_at);
        assert!(
            reason.contains("declares 200 bytes, 3 are left"),
            "{reason}"
        );
        assert_eq!(at, 0);

        // Fewer bytes than a record's head at the end of a chunk's records.
        let mut short = records;
        short.extend_from_slice(&[op::MESSAGE, 0, 0]);
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        record(
            &mut bytes,
            op::CHUNK,
            &chunk(short.len() as u64, "", &short),
        );
        let (found, _) = prescan_of(&bytes).unwrap();
        let reason = found.damage.map(|d| d.1).unwrap_or_default();
        assert!(reason.contains("3 byte(s) at the end"), "{reason}");
    }

    /// Found by `mcap_episode` (`fuzz/regressions/mcap_episode/record-past-a-cut-off-chunk`):
    /// the same in a chunk that the file's end cuts off; and a cut-off chunk whose records
    /// are sound up to the cut is left for the scan (a truncation, not this damage).
    #[test]
    fn a_chunk_cut_off_by_the_end_of_the_file_is_checked_up_to_the_cut() {
        let mut records = Vec::new();
        record(&mut records, op::SCHEMA, &[0; 6]);
        record(&mut records, op::MESSAGE, &[0; 40]);
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        record(
            &mut bytes,
            op::CHUNK,
            &chunk(records.len() as u64, "", &records),
        );
        let whole = bytes.clone();
        bytes.truncate(whole.len() - 20);
        let (found, at) = prescan_of(&bytes).unwrap();
        assert!(found.damage.is_none(), "{:?}", found.damage);
        assert_eq!(at, 0);

        // Records declared 1 byte long: the reader would read a record's head past them.
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        record(&mut bytes, op::CHUNK, &chunk(1, "", &[0; 40]));
        // The records length says 40; make it 1 and cut the file inside the chunk.
        let records_len_at = 8 + 9 + 32;
        bytes[records_len_at..records_len_at + 8].copy_from_slice(&1u64.to_le_bytes());
        bytes.truncate(bytes.len() - 10);
        let (found, _) = prescan_of(&bytes).unwrap();
        let reason = found.damage.map(|d| d.1).unwrap_or_default();
        assert!(reason.contains("1 byte(s) at the end"), "{reason}");
    }

    /// Found by `mcap_episode` (`fuzz/regressions/mcap_episode/chunk-of-the-largest-length`):
    /// a chunk declaring 2^64 - 1 bytes overflowed the check of what fits in it.
    #[test]
    fn a_chunk_of_the_largest_length_is_read_up_to_the_end_of_the_file() {
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        bytes.push(op::CHUNK);
        bytes.extend_from_slice(&u64::MAX.to_le_bytes());
        let mut records = Vec::new();
        record(&mut records, op::SCHEMA, &[0; 11]);
        bytes.extend_from_slice(&chunk(0, "", &records));
        let (found, at) = prescan_of(&bytes).unwrap();
        assert_eq!(found.longest_record, bytes.len());
        assert!(found.damage.is_none(), "{:?}", found.damage);
        assert_eq!(at, 0);
    }
}
