//! Build-time code generation: the gRPC code of `proto/vamos/v1` (at the repository's top)
//! with protox (pure Rust, no system `protoc`), and the encoded descriptor set that server
//! reflection serves.

use prost::Message;
use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR")?).join("../../proto");
    let proto = root.join("vamos/v1/monitor.proto");
    println!("cargo:rerun-if-changed={}", proto.display());
    let fds = protox::compile([&proto], [&root])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("vamos_descriptor.bin"), fds.encode_to_vec())?;
    tonic_prost_build::configure()
        .type_attribute(".", "#[allow(clippy::all, missing_docs)]")
        .compile_fds(fds)?;
    Ok(())
}
