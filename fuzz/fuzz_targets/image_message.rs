//! gRPC `Image` messages: raw encodings with any size and step, PNG and JPEG. See `vamos::fuzz::image_message`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::image_message(data));
