use super::*;
use crate::cache::Cache;
use crate::codec::Value;
use crate::config::{Parity, SerialSettings};
use crate::drivers::modbus::{Bus, Modbus};
use crate::link::Connection;
use crate::link::rtu::RtuTransport;
use crate::link::rtu_frame::crc16;
use crate::link::timing::LineTiming;
use crate::profile::Catalog;
use crate::write_log::{Lookup, WriteStatus};
use std::sync::atomic::{AtomicU32, Ordering};
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

/// Slave 1 answers register reads with its request count; slave 2 never answers.
async fn devices(mut io: DuplexStream, asked: Arc<[AtomicU32; 3]>) {
    let mut request = [0u8; 8];
    while io.read_exact(&mut request).await.is_ok() {
        let slave = usize::from(request[0]).min(2);
        let n = asked[slave].fetch_add(1, Ordering::Relaxed) + 1;
        if slave == 1 {
            let mut answer = vec![1, request[1], 2];
            answer.extend_from_slice(&(n as u16).to_be_bytes());
            answer.extend_from_slice(&crc16(&answer).to_le_bytes());
            if io.write_all(&answer).await.is_err() {
                return;
            }
        }
    }
}

#[tokio::test(start_paused = true)]
async fn a_write_while_the_link_is_down_fails_at_once() {
    let config = crate::config::parse(
        "c.yaml",
        "links:\n  - { name: bus, serial: { port: /nonexistent/ttyIOGATE9, baud: 9600 } }\ndevices:\n  - { name: out, profile: Out, link: bus, slave_id: 1 }\n",
    )
    .expect("config");
    let profile = crate::profile::load_str(
        "out.yaml",
        "name: Out\nfields:\n  - { name: Q, type: BOOL, direction: output, register: { address: 0, kind: coil } }\n",
    )
    .expect("profile");
    let cache = Cache::new(&config, Catalog::new([profile]));
    let task = LinkTask::new(cache.links()[0].clone(), Arc::new(Metrics::new()));
    let token = CancellationToken::new();
    let running = tokio::spawn(task.run(token.clone()));
    // Long enough for the reopen wait to have grown to its 8 s maximum.
    tokio::time::sleep(Duration::from_secs(30)).await;
    let device = cache.device("out").expect("device");
    let generation = device
        .request_write(0, Value::Bool(true))
        .expect("accepted");
    tokio::time::sleep(Duration::from_millis(10)).await;
    let Lookup::Found(record) = cache.writes.get(generation) else {
        panic!("write not logged")
    };
    assert_eq!(record.status, WriteStatus::Failed);
    assert!(
        record
            .error
            .as_deref()
            .is_some_and(|e| e.contains("cannot open")),
        "{record:?}"
    );
    token.cancel();
    running.await.expect("task ends");
}

#[tokio::test(start_paused = true)]
async fn a_dead_device_costs_one_probe_per_backoff_period_and_the_other_keeps_its_rate() {
    let config = crate::config::parse(
        "c.yaml",
        "links:\n  - { name: bus, serial: { port: /dev/null, baud: 19200 } }\ndevices:\n  - { name: alive, profile: One, link: bus, slave_id: 1, refresh_rate: 100ms, timeout: 100ms, retries: 1 }\n  - { name: dead, profile: One, link: bus, slave_id: 2, refresh_rate: 100ms, timeout: 100ms, retries: 1 }\n",
    )
    .expect("config");
    let profile = crate::profile::load_str(
        "one.yaml",
        "name: One\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n",
    )
    .expect("profile");
    let cache = Cache::new(&config, Catalog::new([profile]));
    let metrics = Arc::new(Metrics::new());
    let link = cache.links()[0].clone();
    let mut task = Driven::<Modbus>::new(link, metrics.clone());

    let (gateway, device_end) = tokio::io::duplex(4096);
    let asked: Arc<[AtomicU32; 3]> = Arc::new(Default::default());
    tokio::spawn(devices(device_end, asked.clone()));
    let timing = LineTiming::new(&SerialSettings {
        port: String::new(),
        baud: 19_200,
        parity: Parity::None,
        data_bits: 8,
        stop_bits: 1,
        framing: Default::default(),
    });
    let conn = Connection::Rtu(RtuTransport::new(
        Box::new(gateway),
        Some(timing),
        Duration::ZERO,
    ));
    let bus = Bus::new(
        conn,
        metrics,
        "bus".into(),
        Default::default(),
        Default::default(),
    );
    let token = CancellationToken::new();
    let stop = token.clone();
    let opened = task.config.clone();
    let mut bus = bus;
    let serving = tokio::spawn(async move { task.serve(&mut bus, &stop, &opened).await });
    tokio::time::sleep(Duration::from_secs(10)).await;
    token.cancel();
    assert!(matches!(serving.await, Ok(Ended::Shutdown)));

    // The dead device: one cycle of two attempts, then probes 1, 2 and 4 s apart.
    let dead = asked[2].load(Ordering::Relaxed);
    println!("dead device: {dead} requests in 10 s");
    assert!(
        (5..=7).contains(&dead),
        "{dead} requests to the dead device"
    );
    let dead_device = cache.device("dead").expect("dead");
    assert_eq!(dead_device.diagnostics().error_code.code(), 10);
    assert!(!dead_device.diagnostics().connected);
    // Each costs about 150 ms (timeout and late-reply window): under a second in all,
    // so the live device keeps close to its 100 ms rate: at least 88 of 100 cycles.
    let alive = cache.device("alive").expect("alive").diagnostics();
    assert!(alive.connected);
    println!("live device: {} cycles in 10 s", alive.io_cycles);
    assert!(alive.io_cycles >= 88, "{} cycles in 10 s", alive.io_cycles);
}

/// Every slave answers register reads with its request count.
async fn answering(mut io: DuplexStream, asked: Arc<[AtomicU32; 3]>) {
    let mut request = [0u8; 8];
    while io.read_exact(&mut request).await.is_ok() {
        let slave = usize::from(request[0]).min(2);
        let n = asked[slave].fetch_add(1, Ordering::Relaxed) + 1;
        let mut answer = vec![request[0], request[1], 2];
        answer.extend_from_slice(&(n as u16).to_be_bytes());
        answer.extend_from_slice(&crc16(&answer).to_le_bytes());
        if io.write_all(&answer).await.is_err() {
            return;
        }
    }
}

#[tokio::test(start_paused = true)]
async fn a_device_at_0ms_is_read_back_to_back_and_the_other_keeps_its_rate() {
    let config = crate::config::parse(
        "c.yaml",
        "links:\n  - { name: bus, serial: { port: /dev/null, baud: 19200 } }\ndevices:\n  - { name: fast, profile: One, link: bus, slave_id: 1, refresh_rate: 0ms }\n  - { name: slow, profile: One, link: bus, slave_id: 2, refresh_rate: 100ms }\n",
    )
    .expect("config");
    assert_eq!(config.devices[0].refresh_rate, Duration::ZERO);
    let profile = crate::profile::load_str(
        "one.yaml",
        "name: One\nfields:\n  - { name: N, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n",
    )
    .expect("profile");
    let cache = Cache::new(&config, Catalog::new([profile]));
    let metrics = Arc::new(Metrics::new());
    let mut task = Driven::<Modbus>::new(cache.links()[0].clone(), metrics.clone());
    let (gateway, device_end) = tokio::io::duplex(4096);
    let asked: Arc<[AtomicU32; 3]> = Arc::new(Default::default());
    tokio::spawn(answering(device_end, asked.clone()));
    let timing = LineTiming::new(&SerialSettings {
        port: String::new(),
        baud: 19_200,
        parity: Parity::None,
        data_bits: 8,
        stop_bits: 1,
        framing: Default::default(),
    });
    let conn = Connection::Rtu(RtuTransport::new(
        Box::new(gateway),
        Some(timing),
        Duration::ZERO,
    ));
    let mut bus = Bus::new(
        conn,
        metrics,
        "bus".into(),
        Default::default(),
        Default::default(),
    );
    let token = CancellationToken::new();
    let stop = token.clone();
    let opened = task.config.clone();
    let serving = tokio::spawn(async move { task.serve(&mut bus, &stop, &opened).await });
    tokio::time::sleep(Duration::from_secs(10)).await;
    token.cancel();
    assert!(matches!(serving.await, Ok(Ended::Shutdown)));
    // The slow device keeps its rate (100 cycles in 10 s); the fast one has the rest of
    // the line, cycle after cycle: hundreds of them, every one asked of the slave.
    let slow = cache.device("slow").expect("slow").diagnostics().io_cycles;
    let fast = cache.device("fast").expect("fast").diagnostics().io_cycles;
    println!("back to back: {fast} cycles in 10 s; at 100 ms: {slow}");
    assert!(slow >= 95, "{slow} cycles of the 100 ms device");
    assert!(fast >= 600, "{fast} cycles of the device at 0ms");
    assert_eq!(u64::from(asked[1].load(Ordering::Relaxed)), fast);
}
