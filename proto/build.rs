//! Generates the Rust code and the descriptor set (for server reflection) from
//! `iogate/v1/*.proto`, and the Sparkplug B payload from `sparkplug/`, with protox: no `protoc` binary is needed.

use std::path::PathBuf;

use prost::Message;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let protos = ["iogate/v1/gateway.proto"];
    for p in protos {
        println!("cargo:rerun-if-changed={p}");
    }
    let fds = protox::compile(protos, ["."])?;
    let out = PathBuf::from(std::env::var("OUT_DIR")?);
    std::fs::write(out.join("iogate_descriptor.bin"), fds.encode_to_vec())?;
    tonic_prost_build::configure()
        .build_client(true)
        .build_server(true)
        .codec_path("crate::codec::StrictCodec")
        .compile_fds(fds)?;
    // The Sparkplug B payload: messages only, for the MQTT front-end.
    let sparkplug = "sparkplug/sparkplug_b.proto";
    println!("cargo:rerun-if-changed={sparkplug}");
    tonic_prost_build::configure()
        .build_client(false)
        .build_server(false)
        .compile_fds(protox::compile([sparkplug], ["."])?)?;
    Ok(())
}
