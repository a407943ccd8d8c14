//! Modbus TCP links on loopback: tokio-modbus's TCP server as the device, and RTU frames
//! over a TCP socket as a serial device server carries them.

use reqwest::Method;
use tokio::net::TcpListener;

use iogate_tests::devices::{ModbusDevice, RtuBus, modbus_tcp_server};
use iogate_tests::{TestGateway, eventually};

#[tokio::test]
async fn an_energy_meter_and_a_drive_over_modbus_tcp() {
    let device = ModbusDevice::default();
    {
        let mut t = device.tables.lock().expect("tables");
        for (address, value) in [
            (0usize, 230.1f32),
            (2, 231.2),
            (4, 229.8),
            (70, 50.02),
            (342, 12_345.6),
        ] {
            let bits = value.to_bits();
            t.input[address] = (bits >> 16) as u16;
            t.input[address + 1] = bits as u16;
        }
    }
    let (port, server) = modbus_tcp_server(device.clone()).await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\ndevices:\n  - {{ name: meter, profile: EastronSDM630, link: plant, slave_id: 1, refresh_rate: 50ms }}\n  - {{ name: vfd, profile: GenericVfd, link: plant, slave_id: 2, refresh_rate: 50ms }}\n"
    ))
    .await
    .expect("gateway");
    let meter = gw
        .until("/api/v1/devices/meter", "meter read", |b| {
            b["fields"]["Frequency"]["quality"] == "good"
        })
        .await
        .expect("meter");
    assert_eq!(meter["fields"]["L1_Voltage"]["value"], 230.1);
    assert_eq!(meter["fields"]["L3_Voltage"]["value"], 229.8);
    assert_eq!(meter["fields"]["Frequency"]["value"], 50.02);
    assert_eq!(meter["fields"]["Total_Energy"]["value"], 12_345.6);
    assert_eq!(meter["fields"]["Frequency"]["unit"], "Hz");

    let (status, _) = gw
        .send(
            Method::PUT,
            "/api/v1/devices/vfd/fields/FrequencySetpoint",
            "{\"value\": 35.5}",
        )
        .await
        .expect("put");
    assert_eq!(status, 202);
    eventually("setpoint on the device", || async {
        device.tables.lock().map(|t| t.holding[1]).ok() == Some(3550)
    })
    .await
    .expect("written");
    // Every metric family is exposed (exceptions once there is one: see the RTU tests).
    let metrics = gw.metrics().await.expect("metrics");
    use iogate::metrics::*;
    for name in [
        LINK_UP,
        LINK_ERROR_CODE,
        LINK_RECONNECTS,
        LINK_SENT_BYTES,
        LINK_RECEIVED_BYTES,
        LINK_DISCARDED_BYTES,
        LINK_UTILISATION,
        DEVICE_CONNECTED,
        DEVICE_ERROR_CODE,
        DEVICE_IO_CYCLES,
        DEVICE_RESPONSE_TIME,
        DEVICE_REQUESTS,
        DEVICE_TIMEOUTS,
        DEVICE_CRC_ERRORS,
        DEVICE_WRITES,
    ] {
        assert!(
            metrics.contains(&format!("# TYPE {name}")),
            "{name} missing:\n{metrics}"
        );
    }
    for sample in [
        "iogate_link_up{link=\"plant\"} 1",
        "iogate_device_connected{device=\"meter\"} 1",
        "iogate_device_requests_total{device=\"meter\",function=\"fc04\",outcome=\"ok\"}",
        "iogate_device_requests_total{device=\"vfd\",function=\"fc06\",outcome=\"ok\"}",
        "iogate_device_writes_total{device=\"vfd\",outcome=\"written\"} 1",
        "iogate_device_writes_total{device=\"vfd\",outcome=\"failed\"} 0",
        "iogate_link_reconnects_total{link=\"plant\"} 0",
        "iogate_device_timeouts_total{device=\"meter\"} 0",
        "iogate_device_response_time_seconds_bucket{le=",
    ] {
        assert!(metrics.contains(sample), "{sample} missing:\n{metrics}");
    }
    let link = gw.get("/api/v1/links/plant").await.expect("link").1;
    assert_eq!(
        (link["connected"].clone(), link["error_code"].clone()),
        (true.into(), 0.into())
    );
    gw.shutdown().await;
    server.abort();
}

#[tokio::test]
async fn rtu_frames_over_tcp_and_a_dropped_connection_is_reopened() {
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let bus = RtuBus::default();
    bus.slave(5, |s| s.counter = Some(0));
    let serving = bus.clone();
    let (dropped_tx, mut dropped_rx) = tokio::sync::mpsc::channel::<()>(1);
    let server = tokio::spawn(async move {
        // The first connection is cut after a moment; later ones are served.
        let mut first = true;
        while let Ok((stream, _)) = listener.accept().await {
            let task = serving.serve(stream);
            if first {
                first = false;
                tokio::time::sleep(std::time::Duration::from_millis(300)).await;
                task.abort();
                let _ = dropped_tx.send(()).await;
            }
        }
    });
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: server, tcp: {{ host: 127.0.0.1, port: {port}, framing: rtu }} }}\ndevices:\n  - {{ name: counter, profile: Counter, link: server, slave_id: 5, refresh_rate: 20ms, timeout: 100ms }}\nprofiles: {}\n",
        counter_profiles().display()
    ))
    .await
    .expect("gateway");
    gw.until("/api/v1/devices/counter", "counting", |b| {
        b["fields"]["Count"]["value"].as_u64() > Some(2)
    })
    .await
    .expect("counts");
    dropped_rx.recv().await.expect("connection cut");
    let (_, before) = gw.get("/api/v1/devices/counter").await.expect("get");
    let before = before["io_cycles"].as_u64().unwrap_or(0);
    gw.until("/api/v1/devices/counter", "counting again", |b| {
        b["connected"] == true && b["io_cycles"].as_u64() > Some(before + 5)
    })
    .await
    .expect("reconnected");
    let metrics = gw.metrics().await.expect("metrics");
    assert!(
        metrics.contains("iogate_link_reconnects_total{link=\"server\"} 1"),
        "{metrics}"
    );
    gw.shutdown().await;
    server.abort();
}

/// A profile directory with one profile: a single-register counter.
fn counter_profiles() -> std::path::PathBuf {
    let dir = iogate_tests::devices::temp_dir("tcp-profiles");
    std::fs::write(
        dir.join("counter.yaml"),
        "name: Counter\nfields:\n  - { name: Count, type: UINT, direction: input, register: { address: 0, kind: input_register } }\n",
    )
    .expect("profile");
    dir
}

/// A device that answers reads with zeros and ends the connection at every write; the
/// writes it was sent.
async fn dropping_device() -> (u16, std::sync::Arc<std::sync::atomic::AtomicUsize>) {
    use std::sync::atomic::{AtomicUsize, Ordering};
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    let listener = TcpListener::bind("127.0.0.1:0").await.expect("bind");
    let port = listener.local_addr().expect("addr").port();
    let writes = std::sync::Arc::new(AtomicUsize::new(0));
    let seen = writes.clone();
    tokio::spawn(async move {
        while let Ok((mut s, _)) = listener.accept().await {
            let seen = seen.clone();
            tokio::spawn(async move {
                let mut head = [0u8; 7];
                while s.read_exact(&mut head).await.is_ok() {
                    let len = usize::from(u16::from_be_bytes([head[4], head[5]]));
                    let mut pdu = vec![0u8; len.saturating_sub(1)];
                    if s.read_exact(&mut pdu).await.is_err() || pdu.len() < 5 {
                        return;
                    }
                    if matches!(pdu[0], 5 | 6 | 15 | 16) {
                        seen.fetch_add(1, Ordering::SeqCst);
                        return;
                    }
                    let count = usize::from(u16::from_be_bytes([pdu[3], pdu[4]]));
                    let bytes = if pdu[0] <= 2 {
                        count.div_ceil(8)
                    } else {
                        2 * count
                    };
                    let mut answer = head.to_vec();
                    answer[4..6].copy_from_slice(&((3 + bytes) as u16).to_be_bytes());
                    answer.extend_from_slice(&[pdu[0], bytes as u8]);
                    answer.resize(answer.len() + bytes, 0);
                    if s.write_all(&answer).await.is_err() {
                        return;
                    }
                }
            });
        }
    });
    (port, writes)
}

#[tokio::test]
async fn a_write_the_device_drops_the_connection_at_is_sent_three_times_then_no_more() {
    use std::sync::atomic::Ordering;
    let (port, writes) = dropping_device().await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\ndevices:\n  - {{ name: vfd, profile: GenericVfd, link: plant, slave_id: 2, refresh_rate: 50ms }}\n"
    ))
    .await
    .expect("gateway");
    gw.all_read("vfd").await.expect("read");
    let outcome = gw
        .write_outcome("vfd", "FrequencySetpoint", serde_json::json!(35.5))
        .await
        .expect("write")
        .expect("accepted");
    assert_eq!(outcome["status"], "failed", "{outcome}");
    // Sent again after two reconnects; the third loss gives it up and says so.
    let given_up = gw
        .until(
            "/api/v1/devices/vfd/fields/FrequencySetpoint",
            "given up",
            |f| {
                f["last_write"]["error"]
                    .as_str()
                    .is_some_and(|e| e.contains("not written again"))
            },
        )
        .await
        .expect("given up");
    assert_eq!(given_up["last_write"]["origin"], "replay", "{given_up}");
    // The link comes back and is read for a while: no write is sent any more.
    let (_, now) = gw.get("/api/v1/devices/vfd").await.expect("device");
    let cycles = now["io_cycles"].as_u64().unwrap_or(0);
    gw.until("/api/v1/devices/vfd", "more cycles read", |d| {
        d["connected"] == true && d["io_cycles"].as_u64() >= Some(cycles + 10)
    })
    .await
    .expect("cycles");
    assert_eq!(writes.load(Ordering::SeqCst), 3);
    gw.shutdown().await;
}

#[tokio::test]
async fn a_meter_holding_nan_or_an_infinity_says_so_as_a_string() {
    let device = ModbusDevice::default();
    let (port, server) = modbus_tcp_server(device.clone()).await;
    let gw = TestGateway::start(&format!(
        "links:\n  - {{ name: plant, tcp: {{ host: 127.0.0.1, port: {port} }} }}\ndevices:\n  - {{ name: meter, profile: EastronSDM630, link: plant, slave_id: 1, refresh_rate: 50ms }}\n"
    ))
    .await
    .expect("gateway");
    for (bits, said) in [
        (0x7FC0_0000u32, "NaN"),
        (0x7F80_0000, "Infinity"),
        (0xFF80_0000, "-Infinity"),
    ] {
        {
            let mut t = device.tables.lock().expect("tables");
            t.input[0] = (bits >> 16) as u16;
            t.input[1] = bits as u16;
        }
        let v = gw
            .until("/api/v1/devices/meter/fields/L1_Voltage", said, |f| {
                f["value"] == said
            })
            .await
            .expect("said");
        assert_eq!(v["quality"], "good", "{v}");
    }
    gw.shutdown().await;
    server.abort();
}
