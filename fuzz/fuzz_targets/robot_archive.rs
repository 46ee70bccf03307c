//! Robot package archives (zip, tar.gz) as uploaded. See `vamos::fuzz::robot_archive`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::robot_archive(data));
