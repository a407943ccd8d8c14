//! iogate's gRPC API, package `iogate.v1`: messages and tonic client and server stubs.
#![forbid(unsafe_code)]
#![warn(missing_docs)]

pub mod codec;

/// The generated code of `iogate/v1/gateway.proto`.
pub mod pb {
    #![allow(clippy::all, clippy::too_many_lines, missing_docs)]
    tonic::include_proto!("iogate.v1");
}

/// The Sparkplug B payload (specification 3.0.0, package `org.eclipse.tahu.protobuf`).
pub mod sparkplug {
    #![allow(clippy::all, clippy::too_many_lines, missing_docs)]
    include!(concat!(env!("OUT_DIR"), "/org.eclipse.tahu.protobuf.rs"));
}

/// The encoded descriptor set of the API, for gRPC server reflection.
pub const FILE_DESCRIPTOR_SET: &[u8] =
    include_bytes!(concat!(env!("OUT_DIR"), "/iogate_descriptor.bin"));

/// The fully qualified name of the service, as health checks and reflection name it.
pub const SERVICE_NAME: &str = "iogate.v1.Gateway";
