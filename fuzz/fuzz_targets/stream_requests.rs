//! `Monitor.Stream` request sequences, decoded and converted. See `vamos::fuzz::stream_requests`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::stream_requests(data));
