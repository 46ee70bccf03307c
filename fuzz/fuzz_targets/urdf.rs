//! URDF text, parsed and its forward kinematics run. See `vamos::fuzz::urdf`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::urdf(data));
