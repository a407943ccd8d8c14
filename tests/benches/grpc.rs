//! gRPC unary read throughput: concurrent clients reading one field as fast as they can.
//! Run with `cargo bench -p iogate-tests --bench grpc`; it prints figures rather than
//! asserting them. The fan-out to 1,000 subscribers is in `cargo bench -p iogate --bench
//! suite`.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use iogate_client::Client;

async fn unary_reads(url: &str) -> anyhow::Result<()> {
    for clients in [1usize, 8, 32] {
        let count = Arc::new(AtomicU64::new(0));
        let deadline = Instant::now() + Duration::from_secs(3);
        let mut tasks = Vec::new();
        for _ in 0..clients {
            let mut c = Client::connect(url).await?;
            let count = count.clone();
            tasks.push(tokio::spawn(async move {
                while Instant::now() < deadline {
                    c.get("plant", "Level").await?;
                    count.fetch_add(1, Ordering::Relaxed);
                }
                anyhow::Ok(())
            }));
        }
        for t in tasks {
            t.await??;
        }
        let n = count.load(Ordering::Relaxed);
        println!(
            "unary Read of one field, {clients:>2} concurrent clients: {:>8.0} reads/s",
            n as f64 / 3.0
        );
    }
    Ok(())
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        let mut setup = iogate::app::Setup::demo_simulated().map_err(|p| anyhow::anyhow!("{p}"))?;
        setup.config.http = "127.0.0.1:0".parse()?;
        setup.config.grpc = "127.0.0.1:0".parse()?;
        if let Some(server) = setup.config.modbus_server.as_mut()
            && server.listen.is_some()
        {
            server.listen = Some("127.0.0.1:0".parse()?);
        }
        if let Some(opcua) = setup.config.sections.listen_mut("opcua") {
            *opcua = "127.0.0.1:0".parse()?;
        }
        let running = iogate::app::start(setup).await?;
        let url = format!("http://{}", running.grpc_addr);
        println!("gateway and clients share one process and 2 cores");
        unary_reads(&url).await?;
        running.shutdown().await;
        anyhow::Ok(())
    })
}
