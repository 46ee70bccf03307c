//! The generated gRPC types and services of `proto/vamos/v1` (package `vamos.v1`).

tonic::include_proto!("vamos.v1");

/// The encoded `FileDescriptorSet` of `vamos.v1`, served by gRPC reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/vamos_descriptor.bin"));
