//! Handing memory the allocator holds but no longer uses back to the system.
//!
//! glibc's allocator keeps freed memory in its arenas (one per thread that allocated, up to
//! eight per core) for reuse; a burst (a model swap keeps two models alive for a moment,
//! many sessions close at once) leaves the process's resident memory at the burst's level
//! although the server no longer uses it. `malloc_trim(0)` returns the free pages of every
//! arena (with `madvise`, also from the middle of a heap). The server calls [`trim`] every
//! `[service] trim_memory_s` from a blocking thread; it takes milliseconds.

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

/// The process's resident memory, bytes (from `/proc/self/statm`).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn resident_bytes() -> Option<u64> {
    let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
    let pages: u64 = statm.split_whitespace().nth(1)?.parse().ok()?;
    // SAFETY: sysconf only reads a system constant.
    let page = unsafe { libc::sysconf(libc::_SC_PAGESIZE) };
    Some(pages * u64::try_from(page).ok()?)
}
