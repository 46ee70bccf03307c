//! The `vamos` binary. (Being written.)

fn main() {}
