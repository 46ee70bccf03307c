//! ROS 2 bags in MCAP, opened and read frame by frame. See `vamos::fuzz::mcap_episode`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::mcap_episode(data));
