//! A rodbus Modbus TCP server for the `modbus_server` benchmark: 8192 holding registers
//! (register n holds n), unit id 1, on 127.0.0.1:PORT; prints `ready` once listening.
//! Usage: rodbus-peer PORT

use rodbus::server::*;
use rodbus::*;

struct Registers(Vec<u16>);

impl RequestHandler for Registers {
    fn read_holding_register(&self, address: u16) -> Result<u16, ExceptionCode> {
        self.0
            .get(usize::from(address))
            .copied()
            .ok_or(ExceptionCode::IllegalDataAddress)
    }
}

#[tokio::main]
async fn main() -> Result<(), Box<dyn std::error::Error>> {
    let port: u16 = std::env::args()
        .nth(1)
        .ok_or("usage: rodbus-peer PORT")?
        .parse()?;
    let registers = Registers((0..8192u16).collect()).wrap();
    let map = ServerHandlerMap::single(UnitId::new(1), registers);
    let _server = spawn_tcp_server_task(
        64,
        std::net::SocketAddr::from(([127, 0, 0, 1], port)),
        map,
        AddressFilter::Any,
        DecodeLevel::nothing(),
    )
    .await?;
    println!("ready");
    // Serves until killed.
    std::future::pending::<()>().await;
    Ok(())
}
