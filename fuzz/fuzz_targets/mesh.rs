//! STL, OBJ and COLLADA mesh files. See `vamos::fuzz::mesh`.
#![no_main]

libfuzzer_sys::fuzz_target!(|data: &[u8]| vamos::fuzz::mesh(data));
