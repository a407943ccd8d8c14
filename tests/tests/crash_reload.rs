//! `kill -9` during a reload, a hundred times over one directory: the gateway (a process of
//! its own, on its own config file) is killed at a random moment after a reload that
//! restarts its MQTT front-end (whose store-and-forward buffer is being written, the broker
//! being away) and changes its Modbus server's map, and each next start must find its files
//! whole: it starts, its buffer opens, and the Modbus memory holds every value a master was
//! told was written.

use std::path::Path;
use std::time::Duration;

use iogate_tests::GatewayProcess;
use iogate_tests::devices::temp_dir;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

const BIN: &str = env!("CARGO_BIN_EXE_gateway");
const ROUNDS: u16 = 100;
/// `%MW0` in the linux address space.
const MEMORY: u16 = 1024;

/// The config of round `n`: odd and even rounds differ in a device (the Modbus map) and
/// the MQTT topics (the front-end restarts).
fn config(n: u16, broker_port: u16) -> String {
    let extra = if n.is_multiple_of(2) {
        "  - { name: sim, profile: SimIo, refresh_rate: 20ms }\n"
    } else {
        ""
    };
    format!(
        "listen: {{ http: 127.0.0.1:0, grpc: 127.0.0.1:0 }}\nprofiles: {profiles}\n\
         devices:\n  - {{ name: plant, profile: SimPlant, refresh_rate: 10ms }}\n{extra}\
         modbus_server: {{ listen: 127.0.0.1:0, auto: true, memory_file: memory.json }}\n\
         mqtt:\n  url: mqtt://127.0.0.1:{broker_port}\n  json: {{ prefix: round{parity} }}\n  \
         buffer: {{ dir: buffer, fsync: always }}\n  reconnect_max: 500ms\n",
        profiles = iogate_tests::profiles_dir().display(),
        parity = n % 2,
    )
}

/// Writes `text` to `path` as an editor that renames would: never half a file.
fn replace(path: &Path, text: &str) {
    let tmp = path.with_extension("yaml.new");
    std::fs::write(&tmp, text).expect("write");
    std::fs::rename(&tmp, path).expect("rename");
}

/// The Modbus server's address, from `GET /api/v1/config`.
async fn modbus_address(gw: &GatewayProcess) -> String {
    let (_, status) = gw.gateway.get("/api/v1/config").await.expect("config");
    status["listening"]
        .as_array()
        .and_then(|l| l.iter().find(|s| s["server"] == "modbus"))
        .and_then(|s| s["address"].as_str())
        .map(str::to_owned)
        .expect("the Modbus server listens")
}

/// One Modbus TCP request, its answer.
async fn modbus(addr: &str, pdu: &[u8]) -> Vec<u8> {
    let mut socket = TcpStream::connect(addr).await.expect("connect");
    let len = u16::try_from(pdu.len() + 1).expect("short");
    let mut frame = vec![0, 1, 0, 0];
    frame.extend_from_slice(&len.to_be_bytes());
    frame.push(1);
    frame.extend_from_slice(pdu);
    socket.write_all(&frame).await.expect("send");
    let mut head = [0u8; 7];
    socket.read_exact(&mut head).await.expect("head");
    let mut body = vec![0u8; usize::from(u16::from_be_bytes([head[4], head[5]])) - 1];
    socket.read_exact(&mut body).await.expect("body");
    body
}

/// The holding register at `address`.
async fn register(addr: &str, address: u16) -> u16 {
    let [hi, lo] = address.to_be_bytes();
    let answer = modbus(addr, &[3, hi, lo, 0, 1]).await;
    assert_eq!(answer.get(..2), Some(&[3u8, 2][..]), "{answer:?}");
    u16::from_be_bytes([answer[2], answer[3]])
}

#[tokio::test]
async fn a_gateway_killed_during_reloads_starts_whole_and_keeps_every_acknowledged_write() {
    let dir = temp_dir("crash-reload");
    let broker_port = std::net::TcpListener::bind("127.0.0.1:0")
        .and_then(|l| l.local_addr())
        .expect("a free port")
        .port();
    let path = dir.join("iogate.yaml");
    replace(&path, &config(0, broker_port));
    let mut acknowledged: Vec<(u16, u16)> = Vec::new();
    let mut seed = 0x2545_f491_u64;
    let (mut cut, mut buffered) = (0, 0u64);
    for round in 0..ROUNDS {
        let gw = GatewayProcess::start_file(BIN, &path)
            .await
            .unwrap_or_else(|e| panic!("round {round}: the gateway does not start: {e:#}"));
        let addr = modbus_address(&gw).await;
        for &(at, value) in &acknowledged {
            assert_eq!(
                register(&addr, at).await,
                value,
                "round {round}: %MW{}",
                at - MEMORY
            );
        }
        // Everything buffered before is still there (the broker never came: nothing left).
        let (before, seen) = (buffered, std::sync::atomic::AtomicU64::new(0));
        let (seen_ref, gateway) = (&seen, &gw.gateway);
        iogate_tests::eventually("the buffer whole", || async move {
            let (_, mqtt) = gateway.get("/api/v1/mqtt").await.expect("mqtt");
            let messages = mqtt["buffer"]["messages"].as_u64().unwrap_or(0);
            seen_ref.fetch_max(messages, std::sync::atomic::Ordering::Relaxed);
            mqtt["buffer"]["dir"].is_string() && messages >= before
        })
        .await
        .unwrap_or_else(|e| panic!("round {round}: fewer than {before} messages: {e}"));
        buffered = seen.into_inner();
        // A master writes a register of memory and is told it was written.
        let (at, value) = (MEMORY + round % 50, round + 1);
        let [hi, lo] = at.to_be_bytes();
        let [vh, vl] = value.to_be_bytes();
        assert_eq!(
            modbus(&addr, &[6, hi, lo, vh, vl]).await,
            [6, hi, lo, vh, vl]
        );
        acknowledged.retain(|&(a, _)| a != at);
        acknowledged.push((at, value));
        // Changes go to the buffer, the broker being away, until the kill.
        let (client, level) = (
            gw.gateway.client.clone(),
            gw.gateway
                .url("/api/v1/devices/plant/fields/Level/simulate"),
        );
        let changing = tokio::spawn(async move {
            for n in 0.. {
                let body = format!("{{\"value\": {n}.5}}");
                if client.put(&level).body(body).send().await.is_err() {
                    break;
                }
            }
        });
        // The next config, a reload asked for, and a kill at a random moment of it.
        replace(&path, &config(round + 1, broker_port));
        let reload = (gw.gateway.client).post(gw.gateway.url("/api/v1/config/reload"));
        let reloading = tokio::spawn(reload.send());
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        tokio::time::sleep(Duration::from_micros(seed % 60_000)).await;
        gw.kill().await.expect("killed");
        changing.abort();
        if !matches!(reloading.await, Ok(Ok(r)) if r.status().is_success()) {
            cut += 1;
        }
    }
    // The kills fell inside reloads, and the buffer was being written.
    println!("{cut} of {ROUNDS} reloads cut by the kill; up to {buffered} messages buffered");
    assert!(cut >= ROUNDS / 10, "only {cut} reloads were cut");
    assert!(buffered > 0, "nothing was buffered");
}
