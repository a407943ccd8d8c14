//! Link throughput and overhead. Run with `cargo bench -p iogate --bench link`; it prints
//! figures rather than asserting them.
//!
//! 1. Raw RTU transactions per second over a pseudo-terminal pair (no line timing), the
//!    device answering from its own thread.
//! 2. The same with 115200-baud line timing (the 1.75 ms inter-frame silence).
//! 3. The link task's own cost per transaction: the full poll path (scheduling, transaction,
//!    decoding, publishing to the cache) against bare transactions on the same TCP loopback
//!    socket with RTU framing.
//! 4. The timing model at 9600, 19200 and 115200 baud.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use iogate::config::{Parity, SerialSettings};
use iogate::link::frame::Request;
use iogate::link::rtu::RtuTransport;
use iogate::link::rtu_frame::crc16;
use iogate::link::timing::LineTiming;
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};

const REGISTERS: u16 = 10;

/// Answers every 8-byte read request with REGISTERS registers, counting answers.
async fn responder<S: AsyncRead + AsyncWrite + Unpin>(mut io: S, answered: Arc<AtomicU64>) {
    let mut request = [0u8; 8];
    while io.read_exact(&mut request).await.is_ok() {
        let mut answer = vec![request[0], request[1], (REGISTERS * 2) as u8];
        for i in 0..REGISTERS {
            answer.extend_from_slice(&i.to_be_bytes());
        }
        answer.extend_from_slice(&crc16(&answer).to_le_bytes());
        if io.write_all(&answer).await.is_err() {
            return;
        }
        answered.fetch_add(1, Ordering::Relaxed);
    }
}

fn read_request() -> Request {
    Request::ReadHoldingRegisters {
        address: 0,
        count: REGISTERS,
    }
}

async fn raw_transactions(mut t: RtuTransport, n: u32) -> Duration {
    let started = Instant::now();
    for _ in 0..n {
        t.transact(1, &read_request(), Duration::from_secs(1))
            .await
            .expect("transaction");
    }
    started.elapsed()
}

fn report(label: &str, n: u64, elapsed: Duration) -> f64 {
    let per = elapsed.as_secs_f64() / n as f64;
    println!(
        "{label:<58} {:>9.0} transactions/s {:>9.1} µs each",
        1.0 / per,
        per * 1e6
    );
    per
}

fn line(baud: u32, parity: Parity) -> LineTiming {
    LineTiming::new(&SerialSettings {
        port: String::new(),
        baud,
        parity,
        data_bits: 8,
        stop_bits: 1,
        framing: Default::default(),
    })
}

/// A device on its own thread (as a real device is elsewhere), answering on a new pty pair;
/// the gateway end is opened by its path, as a real port is.
fn pty_device() -> tokio_serial::SerialStream {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .expect("device runtime");
        runtime.block_on(async move {
            use tokio_serial::SerialPort;
            let (device, holder) = tokio_serial::SerialStream::pair().expect("pty pair");
            tx.send(holder.name().expect("pty name"))
                .expect("send name");
            responder(device, Arc::new(AtomicU64::new(0))).await;
            drop(holder);
        });
    });
    let path = rx.recv().expect("pty name");
    tokio_serial::SerialStream::open(&tokio_serial::new(path, 115_200)).expect("open pty")
}

async fn pty_benchmarks() {
    let n = 20_000;
    let t = RtuTransport::new(Box::new(pty_device()), None, Duration::ZERO);
    let elapsed = raw_transactions(t, n).await;
    report(
        "pty pair, RTU read of 10 registers, no line timing",
        u64::from(n),
        elapsed,
    );

    let n = 2_000;
    let timing = Some(line(115_200, Parity::None));
    let t = RtuTransport::new(Box::new(pty_device()), timing, Duration::ZERO);
    let elapsed = raw_transactions(t, n).await;
    report(
        "pty pair, same read, 115200-baud silences kept",
        u64::from(n),
        elapsed,
    );
}

async fn link_task_overhead() {
    // Bare transactions on an RTU-over-TCP loopback socket.
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
        .await
        .expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let answered = Arc::new(AtomicU64::new(0));
    let counter = answered.clone();
    tokio::spawn(async move {
        while let Ok((stream, _)) = listener.accept().await {
            let _ = stream.set_nodelay(true);
            tokio::spawn(responder(stream, counter.clone()));
        }
    });
    let n = 20_000;
    let stream = tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .expect("connect");
    let _ = stream.set_nodelay(true);
    let raw = raw_transactions(RtuTransport::new(Box::new(stream), None, Duration::ZERO), n).await;
    let raw_per = report("TCP loopback, bare RTU transactions", u64::from(n), raw);

    // The full poll path: 64 devices at 1 ms, more than the bus can carry, so the link
    // never idles.
    let mut profile = String::from("name: Bench\nfields:\n");
    for i in 0..REGISTERS {
        profile.push_str(&format!(
            "  - {{ name: R{i}, type: UINT, direction: input, register: {{ address: {i}, kind: holding_register }} }}\n"
        ));
    }
    let mut config = format!(
        "listen: {{ http: 127.0.0.1:0 }}\nlinks:\n  - {{ name: bus, tcp: {{ host: 127.0.0.1, port: {port}, framing: rtu }} }}\ndevices:\n"
    );
    for slave in 1..=64 {
        config.push_str(&format!(
            "  - {{ name: d{slave}, profile: Bench, link: bus, slave_id: {slave}, refresh_rate: 1ms }}\n"
        ));
    }
    let config = iogate::config::parse("bench.yaml", &config).expect("config");
    let catalog =
        iogate::profile::Catalog::new([
            iogate::profile::load_str("bench.yaml", &profile).expect("profile")
        ]);
    let setup = iogate::app::Setup {
        config,
        catalog,
        profiles_dir: None,
        demo: false,
        map: None,
    };
    let running = iogate::app::start(setup).await.expect("gateway");
    tokio::time::sleep(Duration::from_millis(300)).await;
    let before = answered.load(Ordering::Relaxed);
    let started = Instant::now();
    tokio::time::sleep(Duration::from_secs(3)).await;
    let done = answered.load(Ordering::Relaxed) - before;
    let elapsed = started.elapsed();
    let task_per = report("TCP loopback, link task polling 64 devices", done, elapsed);
    println!(
        "{:<58} {:>9.1} µs per transaction (decode + publish 10 fields + scheduling)",
        "link task overhead over bare transactions",
        (task_per - raw_per) * 1e6
    );
    running.shutdown().await;
}

fn timing_model() {
    println!();
    println!("Timing model: read of 10 registers (8-byte request, 25-byte answer)");
    println!(
        "{:<10} {:>6} {:>12} {:>12} {:>16} {:>16}",
        "line", "bits", "char (ms)", "silence (ms)", "transaction (ms)", "max per second"
    );
    for (baud, parity) in [
        (9600, Parity::None),
        (9600, Parity::Even),
        (19_200, Parity::None),
        (19_200, Parity::Even),
        (115_200, Parity::None),
        (115_200, Parity::Even),
    ] {
        let t = line(baud, parity);
        let tx = t.transaction_time(8, 25);
        println!(
            "{:<10} {:>6} {:>12.3} {:>12.3} {:>16.3} {:>16.0}",
            format!(
                "{baud} 8{}1",
                if parity == Parity::None { 'N' } else { 'E' }
            ),
            t.bits_per_char,
            t.char_time().as_secs_f64() * 1e3,
            t.silence().as_secs_f64() * 1e3,
            tx.as_secs_f64() * 1e3,
            1.0 / tx.as_secs_f64()
        );
    }
}

fn main() {
    // One thread for gateway and devices alike, so that both paths of (3) pay the same
    // scheduling and system-call costs and their difference is the link task's own work.
    let runtime = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .expect("runtime");
    runtime.block_on(async {
        pty_benchmarks().await;
        link_task_overhead().await;
    });
    timing_model();
}
