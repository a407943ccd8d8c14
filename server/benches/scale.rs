//! 100,000 fields, two ways, each in `iogate serve` in its own process: 1,000 simulated
//! devices of 100 fields each refreshed every 100 ms; and 100 Modbus TCP devices of 1,000
//! holding registers each (tokio-modbus servers in this process, one per device) polled
//! every second. Prints the time from start to ready (`/readyz` 200), resident memory and
//! CPU (from /proc) once running, and how long `GET /api/v1/devices` and `GET
//! /api/v1/links` (what the web page's overview asks for) take.
//!
//! `cargo bench -p iogate --bench scale`

mod common;
#[path = "parts/scale.rs"]
mod scale;

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    let rows = scale::run(&runtime)?;
    common::print_table(&rows);
    Ok(())
}
