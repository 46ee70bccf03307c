//! `service::memory::trim` gives freed heap memory back to the system. Its own test
//! binary: resident memory is a process-wide figure that other tests would move.

#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[test]
fn freed_memory_in_the_middle_of_the_heap_goes_back_to_the_system() {
    fn resident() -> u64 {
        let statm = std::fs::read_to_string("/proc/self/statm").unwrap();
        let pages: u64 = statm.split_whitespace().nth(1).unwrap().parse().unwrap();
        pages * 4096
    }
    const MIB: u64 = 1 << 20;
    // 128 MiB in blocks below the mmap threshold (so they live in the heap), written so
    // they are resident, then one small block after them that keeps the heap's top in use:
    // freeing the big ones leaves 128 MiB free in the middle, which free() keeps.
    let blocks: Vec<Vec<u8>> = (0..4096).map(|i| vec![i as u8 | 1; 32 << 10]).collect();
    let pin = Box::new([7u8; 64]);
    assert!(blocks.iter().all(|b| b[100] != 0));
    let full = resident();
    drop(blocks);
    let freed = resident();
    let given_back = vamos_server::service::memory::trim().expect("reported on glibc");
    let trimmed = resident();
    assert_eq!(pin[63], 7);
    assert!(
        full.saturating_sub(freed) < 64 * MIB,
        "free() kept most of it: {} MiB -> {} MiB",
        full / MIB,
        freed / MIB
    );
    assert!(
        freed.saturating_sub(trimmed) > 96 * MIB && given_back > 96 * MIB,
        "trim gave back {} MiB ({} MiB -> {} MiB)",
        given_back / MIB,
        freed / MIB,
        trimmed / MIB
    );
}
