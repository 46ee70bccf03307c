//! A whole streamed session through the scorer. See `vamos::fuzz::stream_session`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::stream_session(data));
