//! REST admin JSON bodies, parsed and applied to a store. See `vamos::fuzz::rest_body`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::rest_body(data));
