//! Memory bounds of image work, measured with a counting allocator: the peak of live
//! heap bytes while one call runs. A test binary of its own (its allocator counts every
//! allocation of the process), whose checks run one after another in one test.

#![allow(clippy::unwrap_used, clippy::expect_used)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};
use vamos::episode::ros::{CompressedImageMsg, Header, MAX_IMAGE_SIDE};
use vamos::vision::GrayImage;
use vamos::vision::preprocess::{ResizeFilter, resize};

struct Counting;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts bytes.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: same contract as the caller's.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let live = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(live, Ordering::Relaxed);
        }
        p
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
}

#[global_allocator]
static ALLOCATOR: Counting = Counting;

/// Runs `f` and returns its result and the peak of heap bytes it added.
fn peak_of<T>(f: impl FnOnce() -> T) -> (T, usize) {
    let base = LIVE.load(Ordering::Relaxed);
    PEAK.store(base, Ordering::Relaxed);
    let out = f();
    (out, PEAK.load(Ordering::Relaxed).saturating_sub(base))
}

/// A PNG of one grey level: it compresses to almost nothing (a decompression bomb).
fn png(width: u32, height: u32) -> Vec<u8> {
    use image::ImageEncoder;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let pixels = vec![90u8; width as usize * height as usize];
    let mut out = Vec::new();
    PngEncoder::new_with_quality(&mut out, CompressionType::Best, FilterType::NoFilter)
        .write_image(&pixels, width, height, image::ExtendedColorType::L8)
        .unwrap();
    out
}

const MIB: usize = 1 << 20;

#[test]
fn image_work_is_bounded_by_the_output_not_the_aspect_ratio() {
    // 1. Resizing a tall, thin image: rows first it needed a 160 x height intermediate
    //    (3.8 GB for 1 x 6,000,000); now the intermediate is tiny and the peak is the
    //    sampling plans (a few floats per source row) and the output.
    for (w, h) in [(1usize, 6_000_000usize), (6_000_000, 1), (3, 2_000_000)] {
        let img = GrayImage::new(w, h, vec![7.0; w * h]).unwrap();
        let (out, peak) = peak_of(|| resize(&img, 160, 120, ResizeFilter::Area).unwrap());
        assert_eq!((out.width(), out.height()), (160, 120));
        // (Each output sums 50,000 f32 products: rounding, not resampling, sets the error.)
        assert!(
            out.data().iter().all(|&v| (v - 7.0).abs() < 0.05),
            "{w}x{h}"
        );
        // The input itself is 24 MB; the work must not be a multiple of it.
        assert!(peak < 64 * MIB, "{w}x{h}: resize peak {} MiB", peak / MIB);
        let (_, peak) = peak_of(|| resize(&img, 160, 120, ResizeFilter::Bilinear).unwrap());
        assert!(peak < 64 * MIB, "{w}x{h} bilinear: peak {} MiB", peak / MIB);
    }

    // 2. A tiny PNG declaring a huge, thin image is refused from its header with a
    //    clear reason, before a pixel is decoded.
    let data = png(1, 6_000_000);
    assert!(data.len() < 64 << 10, "{} bytes", data.len());
    let msg = CompressedImageMsg {
        header: Header::from_stamp_ns(0, ""),
        format: "png".into(),
        data: &data,
    };
    let (result, peak) = peak_of(|| msg.to_gray(40 << 20));
    let err = result.unwrap_err().to_string();
    assert!(err.contains("1x6000000") && err.contains("side"), "{err}");
    assert!(peak < MIB, "refusal peak {} KiB", peak >> 10);

    // 3. The longest side accepted decodes and resizes within a small multiple of its
    //    own size (1 x 32768 gray: 128 KiB of f32).
    let data = png(1, MAX_IMAGE_SIDE as u32);
    let msg = CompressedImageMsg {
        header: Header::from_stamp_ns(0, ""),
        format: "png".into(),
        data: &data,
    };
    let (small, peak) = peak_of(|| {
        let g = msg.to_gray(40 << 20).unwrap();
        resize(&g, 160, 120, ResizeFilter::Area).unwrap()
    });
    assert_eq!(small.width(), 160);
    assert!(peak < 4 * MIB, "decode + resize peak {} KiB", peak >> 10);

    // 4. A 200-byte bag whose zstd chunk holds a record declaring 200 MiB (a corrupt
    //    length): the MCAP reader reserved and zeroed the declared length before
    //    decompressing it (up to the 256 MiB record limit, for every scan of the file).
    //    The scan's limit is now the file's longest possible record (here the chunk's
    //    declared 64 bytes): refused as damage, with little memory.
    let bag = bag_with_a_lying_chunk_record(200 * MIB as u64);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("lying.mcap");
    std::fs::write(&path, &bag).unwrap();
    let ((), peak) = peak_of(|| {
        let cfg = vamos::episode::EpisodeConfig::default();
        let err = vamos::episode::McapEpisode::open(&path, &cfg).unwrap_err();
        assert!(err.to_string().contains("exceeds limit"), "{err}");
    });
    assert!(peak < 4 * MIB, "scan peak {} KiB", peak >> 10);

    // 5. What a decoding is charged before it runs (the declared size's `peak_bytes`)
    //    covers what it takes: a 2048^2 16-bit RGBA PNG, the costliest file pixels.
    let side = 2048u32;
    let pixels = vec![0x5au8; side as usize * side as usize * 8];
    let mut data = Vec::new();
    {
        use image::ImageEncoder;
        use image::codecs::png::{CompressionType, FilterType, PngEncoder};
        PngEncoder::new_with_quality(&mut data, CompressionType::Best, FilterType::NoFilter)
            .write_image(&pixels, side, side, image::ExtendedColorType::Rgba16)
            .unwrap();
    }
    drop(pixels);
    let msg = CompressedImageMsg {
        header: Header::from_stamp_ns(0, ""),
        format: "png".into(),
        data: &data,
    };
    let charged = msg.encoded().check(1 << 24).unwrap().peak_bytes as usize;
    let (gray, peak) = peak_of(|| msg.to_gray(1 << 24).unwrap());
    assert_eq!(gray.width(), side as usize);
    eprintln!(
        "2048^2 RGBA16 PNG: decoding peak {} MiB, charged {} MiB",
        peak / MIB,
        charged / MIB
    );
    assert!(
        peak <= charged,
        "decoding peak {} MiB over the {} MiB charged",
        peak / MIB,
        charged / MIB
    );
}

/// An MCAP file (no summary) of a header and one zstd chunk whose first record declares
/// `declared` bytes but holds a few.
fn bag_with_a_lying_chunk_record(declared: u64) -> Vec<u8> {
    fn record(out: &mut Vec<u8>, opcode: u8, content: &[u8]) {
        out.push(opcode);
        out.extend_from_slice(&(content.len() as u64).to_le_bytes());
        out.extend_from_slice(content);
    }
    let mut inner = vec![0x05];
    inner.extend_from_slice(&declared.to_le_bytes());
    inner.extend_from_slice(&[0u8; 55]);
    let compressed = zstd::encode_all(&inner[..], 3).unwrap();
    let mut out = b"\x89MCAP0\r\n".to_vec();
    let mut header = Vec::new();
    header.extend_from_slice(&0u32.to_le_bytes());
    header.extend_from_slice(&0u32.to_le_bytes());
    record(&mut out, 0x01, &header);
    let mut chunk = Vec::new();
    for v in [0u64, 0, inner.len() as u64] {
        chunk.extend_from_slice(&v.to_le_bytes());
    }
    chunk.extend_from_slice(&0u32.to_le_bytes()); // no CRC
    chunk.extend_from_slice(&4u32.to_le_bytes());
    chunk.extend_from_slice(b"zstd");
    chunk.extend_from_slice(&(compressed.len() as u64).to_le_bytes());
    chunk.extend_from_slice(&compressed);
    record(&mut out, 0x06, &chunk);
    out
}
