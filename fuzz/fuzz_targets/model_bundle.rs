//! Model bundles (`.vamos` zips), manifests and ONNX headers. See `vamos::fuzz::model_bundle`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::model_bundle(data));
