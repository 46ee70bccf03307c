//! ROS 2 CDR message payloads (Image, CompressedImage, CameraInfo, JointState, ...). See `vamos::fuzz::cdr_message`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::cdr_message(data));
