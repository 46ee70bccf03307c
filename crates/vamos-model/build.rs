//! Build-time code generation: the ONNX schema (`proto/third_party/onnx/onnx.proto`,
//! vendored) as prost types for `src/onnx_proto.rs` (`OUT_DIR/onnx.rs`), with protox
//! (pure Rust, no system `protoc`).

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let proto = "proto/third_party/onnx/onnx.proto";
    println!("cargo:rerun-if-changed={proto}");
    let fds = protox::compile([proto], ["proto/third_party/onnx"])?;
    prost_build::Config::new().compile_fds(fds)?;
    Ok(())
}
