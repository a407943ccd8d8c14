//! Latency of a one-shot raw transaction, on an idle line and on a line busy with polling.
//! The line is a pseudo-terminal with a bus of slaves that answer after the wire time of
//! request and answer at 19200 baud (10 bits per character), as a real line would. Goal: at
//! most the transaction in flight, plus its own wire time, plus 2 ms.
//!
//! `cargo bench -p iogate-tests --bench transactions`

use std::time::{Duration, Instant};

use iogate_tests::TestGateway;
use iogate_tests::devices::{RtuBus, pty_at, temp_dir};

const BAUD: u32 = 19_200;
const SAMPLES: usize = 60;

/// Wire time of `bytes` characters plus the 3.5-character silence before a frame.
fn wire(bytes: usize) -> Duration {
    let char_time = 10.0 / f64::from(BAUD);
    Duration::from_secs_f64((bytes as f64 + 3.5) * char_time)
}

async fn measure(busy: bool) -> anyhow::Result<Vec<Duration>> {
    let bus = RtuBus::at_baud(BAUD);
    bus.slave(1, |_| {});
    bus.slave(5, |s| s.tables.holding[10] = 77);
    let dir = temp_dir(if busy {
        "bench-tx-busy"
    } else {
        "bench-tx-idle"
    });
    let port = dir.join("ttyBENCH");
    let (device_end, _holder) = pty_at(&port)?;
    let task = bus.serve(device_end);
    let devices = if busy {
        // Eight input registers every millisecond: the line is always busy.
        "devices:\n  - { name: adc, profile: WaveshareAnalogInput, link: rs485, slave_id: 1, refresh_rate: 1ms }\n"
    } else {
        ""
    };
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: rs485, serial: {{ port: {}, baud: {BAUD} }} }}\n{devices}",
        port.display()
    ))
    .await?;
    let mut client = gw.client().await?;
    if busy {
        gw.until("/api/v1/devices/adc", "polling", |b| b["connected"] == true)
            .await?;
    }
    let request = iogate_client::proto::TransactRequest {
        link: "rs485".into(),
        function: 3,
        slave: 5,
        address: 10,
        value_type: "UNSIGNED_NUMBER16".into(),
        byte_order: "BigEndian".into(),
        timeout_ms: 500,
        ..Default::default()
    };
    let mut out = Vec::with_capacity(SAMPLES);
    for n in 0..SAMPLES {
        // Spread the requests over the poll cycle.
        tokio::time::sleep(Duration::from_micros(700 + (n as u64 * 331) % 5000)).await;
        let started = Instant::now();
        let outcome = client.transact(request.clone()).await?;
        anyhow::ensure!(outcome.value == Some(77.0), "{outcome:?}");
        out.push(started.elapsed());
    }
    gw.shutdown().await;
    task.abort();
    out.sort();
    Ok(out)
}

fn main() -> anyhow::Result<()> {
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()?;
    runtime.block_on(async {
        // FC03 x 1: 8-byte request, 7-byte answer. The polled read: FC04 x 8, 8 and 21 bytes.
        let own = wire(8) + wire(7);
        let in_flight = wire(8) + wire(21);
        let goal_idle = own + Duration::from_millis(2);
        let goal_busy = in_flight + own + Duration::from_millis(2);
        println!(
            "one-shot FC03 x 1 at {BAUD} baud (emulated wire time); {SAMPLES} samples, gRPC round trip included"
        );
        for (name, busy, goal) in [("idle", false, goal_idle), ("busy", true, goal_busy)] {
            let d = measure(busy).await?;
            let pick = |q: f64| d[((d.len() as f64 * q) as usize).min(d.len() - 1)];
            println!(
                "{name:<5} line: p50 {:>6.2} ms  p99 {:>6.2} ms  max {:>6.2} ms   goal {:>6.2} ms ({})",
                pick(0.5).as_secs_f64() * 1e3,
                pick(0.99).as_secs_f64() * 1e3,
                d[d.len() - 1].as_secs_f64() * 1e3,
                goal.as_secs_f64() * 1e3,
                if busy {
                    "the poll in flight + own wire time + 2 ms"
                } else {
                    "own wire time + 2 ms"
                }
            );
        }
        anyhow::Ok(())
    })
}
