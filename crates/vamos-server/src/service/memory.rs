//! Handing memory the allocator holds but no longer uses back to the system.
//!
//! glibc's allocator keeps freed memory in its arenas (one per thread that allocated, up to
//! eight per core) for reuse; a burst (a model swap keeps two models alive for a moment,
//! many sessions close at once) leaves the process's resident memory at the burst's level
//! although the server no longer uses it. `malloc_trim(0)` returns the free pages of every
//! arena (with `madvise`, also from the middle of a heap). The server calls [`trim`] every
//! `[service] trim_memory_s` from a blocking thread; it takes milliseconds.
//!
//! Trimming cannot return a page that still holds one live allocation. glibc raises its
//! mmap threshold to the size of each large block freed, so after the first burst of large
//! frees (a swapped-out model, closed sessions' buffers) blocks of up to 32 MiB come from
//! the heaps, where the small allocations made beside them pin their pages. At start the
//! server fixes the threshold ([`fix_mmap_threshold`], `[service] mmap_threshold_kib`), so
//! large blocks keep pages of their own and go back to the system when freed.

/// Returns the allocator's unused memory to the system; the bytes of resident memory it
/// gave back when the platform says (`None` elsewhere, where it does nothing).
pub fn trim() -> Option<u64> {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let before = resident_bytes();
        // SAFETY: malloc_trim takes no pointers and may be called from any thread at any
        // time; it only changes what the allocator keeps mapped.
        unsafe {
            libc::malloc_trim(0);
        }
        let after = resident_bytes();
        before.zip(after).map(|(b, a)| b.saturating_sub(a))
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        None
    }
}

/// Fixes the allocator's mmap threshold at `bytes`: blocks at least this large are mapped
/// on their own and unmapped when freed, and the threshold no longer follows the frees.
/// `true` when the platform's allocator took it (Linux with glibc only).
pub fn fix_mmap_threshold(bytes: u64) -> bool {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        let Ok(bytes) = libc::c_int::try_from(bytes) else {
            return false;
        };
        // SAFETY: mallopt takes no pointers; glibc serialises it with its own locks and
        // it only changes where later allocations are placed.
        unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, bytes) == 1 }
    }
    #[cfg(not(all(target_os = "linux", target_env = "gnu")))]
    {
        let _ = bytes;
        false
    }
}

/// The process's resident memory, bytes (from `/proc/self/statm`).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf only reads a system constant.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    Some(pages * u64::try_from(page).ok()?)
}

#[cfg(all(test, target_os = "linux", target_env = "gnu"))]
mod tests {
    /// glibc places a block it maps on its own 16 bytes past a page boundary (the chunk
    /// header); a block from a heap lands anywhere on a 16-byte boundary.
    fn mapped_on_its_own(block: &[u8]) -> bool {
        // SAFETY: sysconf only reads a system constant.
        let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
        usize::try_from(page).is_ok_and(|page| block.as_ptr() as usize % page == 16)
    }

    #[test]
    fn a_fixed_threshold_keeps_large_blocks_mapped_after_a_large_free() {
        assert!(super::fix_mmap_threshold(128 << 10));
        // mallopt takes an int.
        assert!(!super::fix_mmap_threshold(4 << 30));
        // Freeing a 16 MiB block would raise a moving threshold to 16 MiB, and the 1 MiB
        // blocks after it would come from the heap.
        drop(std::hint::black_box(vec![1u8; 16 << 20]));
        let blocks: Vec<Vec<u8>> = (0..4).map(|i| vec![i; 1 << 20]).collect();
        for b in &blocks {
            assert!(mapped_on_its_own(b), "a 1 MiB block came from the heap");
        }
    }
}
