//! The longest record an MCAP file can hold, read from its records' headers: the record
//! limit of a linear scan.

use super::*;

/// Bytes of a record's opcode and length.
const RECORD_HEAD: u64 = 9;
/// Bytes of a chunk's start time, end time and uncompressed size.
const CHUNK_HEAD: u64 = 24;

/// The longest record `file` can hold: no record in the data section is longer than the
/// file, and none inside a chunk longer than the largest uncompressed size a chunk
/// declares. A scan's record limit is lowered to it, because the MCAP reader reserves (and
/// zeroes) the length a record inside a compressed chunk declares before it decompresses
/// it: a corrupt length in a 10 KB file otherwise costs the whole limit (256 MiB or more)
/// per scan. Reads the records' headers only (a chunk too short for its own header is left
/// for the scan to report); leaves `file` at its start.
pub(super) fn longest_record(file: &mut File) -> std::io::Result<usize> {
    use std::io::BufReader;
    let len = file.metadata()?.len();
    let mut longest = len;
    let mut reader = BufReader::new(&mut *file);
    reader.seek(SeekFrom::Start(8))?;
    let mut pos = 8u64;
    let mut head = [0u8; (RECORD_HEAD + CHUNK_HEAD) as usize];
    while pos + RECORD_HEAD <= len {
        let (record_head, chunk_head) = head.split_at_mut(RECORD_HEAD as usize);
        reader.read_exact(record_head)?;
        let record = u64::from_le_bytes(record_head[1..].try_into().unwrap_or_default());
        let Some(next) = (pos + RECORD_HEAD).checked_add(record) else {
            break;
        };
        if next > len {
            break;
        }
        let mut read = RECORD_HEAD;
        if record_head[0] == op::CHUNK && record >= CHUNK_HEAD {
            reader.read_exact(chunk_head)?;
            read += CHUNK_HEAD;
            let uncompressed = u64::from_le_bytes(chunk_head[16..].try_into().unwrap_or_default());
            longest = longest.max(uncompressed);
        }
        // `read` <= RECORD_HEAD + record: a chunk's header is read only when it fits.
        reader.seek_relative(i64::try_from(next - pos - read).unwrap_or(i64::MAX))?;
        pos = next;
    }
    drop(reader);
    file.seek(SeekFrom::Start(0))?;
    Ok(usize::try_from(longest).unwrap_or(usize::MAX))
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

    fn longest_of(bytes: &[u8]) -> std::io::Result<(usize, u64)> {
        let mut file = tempfile::tempfile()?;
        file.write_all(bytes)?;
        let longest = longest_record(&mut file)?;
        Ok((longest, file.stream_position()?))
    }

    #[test]
    fn a_chunk_declares_the_longest_record_and_the_file_is_left_at_its_start() {
        let mut bytes = b"\x89MCAP0\r\n".to_vec();
        record(&mut bytes, op::HEADER, &[0; 8]);
        let mut chunk = Vec::new();
        for v in [0u64, 0, 5000] {
            chunk.extend_from_slice(&v.to_le_bytes());
        }
        chunk.extend_from_slice(&[0; 16]);
        record(&mut bytes, op::CHUNK, &chunk);
        let Ok((longest, at)) = longest_of(&bytes) else {
            panic!("the headers were not read");
        };
        assert_eq!(longest, 5000);
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
        let len = bytes.len();
        let Ok((longest, at)) = longest_of(&bytes) else {
            panic!("a short chunk stopped the headers' read");
        };
        // The next record's bytes were not taken for a chunk's uncompressed size.
        assert_eq!(longest, len);
        assert_eq!(at, 0);
    }
}
