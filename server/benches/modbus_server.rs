//! The Modbus TCP server under load: FC03 × 10 and × 125 registers from 1 and from 16
//! masters at once (tokio-modbus clients in this process), requests per second and latency
//! percentiles, against `iogate serve` on the demo's devices in its own process, and the
//! same clients in the same run against two peers, each in its own process: a libmodbus
//! server (a C program built here with `cc` and Debian's libmodbus-dev, when both are
//! installed) and a rodbus server (`benches/peer/rodbus`, built here by cargo from the
//! published crate; never a dependency of iogate).
//!
//! `cargo bench -p iogate --bench modbus_server`

mod common;
#[path = "parts/modbus_server.rs"]
mod modbus_server;

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let rows = modbus_server::run(&runtime)?;
    common::print_table(&rows);
    Ok(())
}
